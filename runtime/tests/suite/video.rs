//! Video: odd sides padded, ffmpeg searched on the path, the documented
//! command.

use sdfl_runtime::video::*;
use std::path::Path;

#[test]
fn odd_sides_are_padded_with_their_last_pixels() {
    assert_eq!(even_size(4, 6), (4, 6));
    assert_eq!(even_size(3, 5), (4, 6));
    assert_eq!(even_size(1, 1), (2, 2));
    // 3 × 1: pixels a b c (one channel value each, repeated).
    let rgb: Vec<u8> = [1u8, 2, 3].iter().flat_map(|&v| [v; 3]).collect();
    let p = padded(&rgb, 3, 1);
    let got: Vec<u8> = p.chunks(3).map(|c| c[0]).collect();
    assert_eq!(got, [1, 2, 3, 3, 1, 2, 3, 3]);
    let even = vec![7u8; 2 * 2 * 3];
    assert!(matches!(padded(&even, 2, 2), std::borrow::Cow::Borrowed(_)));
}

#[test]
fn ffmpeg_is_searched_on_the_path() {
    let dir = std::env::temp_dir().join(format!("sdfl-video-path-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("a")).unwrap();
    std::fs::create_dir_all(dir.join("b")).unwrap();
    // Not executable in a, executable in b: b's is found.
    std::fs::write(dir.join("a/ffmpeg"), "").unwrap();
    std::fs::write(dir.join("b/ffmpeg"), "#!/bin/sh\n").unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let exe = std::fs::Permissions::from_mode(0o755);
        std::fs::set_permissions(dir.join("b/ffmpeg"), exe).unwrap();
    }
    let path = std::env::join_paths([dir.join("a"), dir.join("b")]).unwrap();
    assert_eq!(
        search_path("ffmpeg".as_ref(), Some(&path)),
        Some(dir.join("b/ffmpeg"))
    );
    assert_eq!(search_path("ffmpeg".as_ref(), None), None);
    // A directory is no program.
    assert_eq!(search_path("a".as_ref(), Some(dir.as_os_str())), None);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_command_is_the_documented_one() {
    let args: Vec<String> = ffmpeg_args(64, 48, 24.0, "mp4", Path::new("out/.sdfl-x.tmp"))
        .iter()
        .map(|a| a.to_string_lossy().into_owned())
        .collect();
    let line = args.join(" ");
    assert!(
        line.contains("-f rawvideo -pix_fmt rgb24 -s 64x48 -r 24 -i - -c:v libx264 -pix_fmt yuv420p -crf 18 -f mp4"),
        "{line}"
    );
    assert!(line.ends_with("out/.sdfl-x.tmp"), "{line}");
    let fractional = ffmpeg_args(2, 2, 29.97, "null", Path::new("-"));
    assert!(fractional.iter().any(|a| a == "29.97"));
}
