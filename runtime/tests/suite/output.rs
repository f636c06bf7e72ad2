//! Writing outputs: temporary names, refused paths, a full disk, files in
//! flight abandoned, streamed GIFs.

use sdfl_runtime::output::*;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::{fs, io};
use tempfile::TempPath;

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-output-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&d);
    fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn temporary_names_are_unpredictable_and_cleaned_up() {
    let d = dir("tmp");
    let a = Atomic::create(&d.join("x.png")).unwrap();
    let b = Atomic::create(&d.join("x.png")).unwrap();
    let names = |d: &Path| -> Vec<String> {
        fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect()
    };
    let tmp = names(&d);
    assert_eq!(tmp.len(), 2, "{tmp:?}");
    // Named as the stale-file cleanup recognises, and only so.
    assert!(tmp.iter().all(|n| is_temporary_name(n.as_ref())), "{tmp:?}");
    for n in [
        ".sdfl-abc12.tmp",
        ".sdfl-abc1234.tmp",
        ".sdfl-ab-12.tmp",
        "sdfl-abc123.tmp",
        ".sdfl-abc123.tmpx",
        ".sdfl-abc123.tm",
    ] {
        assert!(!is_temporary_name(n.as_ref()), "{n}");
    }
    assert!(tmp
        .iter()
        .all(|n| !n.contains(&std::process::id().to_string())));
    drop((a, b));
    assert!(names(&d).is_empty());
}

#[cfg(unix)]
#[test]
fn links_and_non_directories_on_the_way_are_refused() {
    let d = dir("links");
    let elsewhere = d.join("elsewhere");
    fs::create_dir_all(&elsewhere).unwrap();
    std::os::unix::fs::symlink(&elsewhere, d.join("sub")).unwrap();
    let e = write_png(&d.join("sub/deeper/x.png"), 1, 1, &[0, 0, 0]).unwrap_err();
    assert!(e.to_string().contains("symbolic link"), "{e}");
    assert!(!elsewhere.join("deeper").exists());
    fs::write(d.join("file"), "x").unwrap();
    let e = write_png(&d.join("file/x.png"), 1, 1, &[0, 0, 0]).unwrap_err();
    assert!(e.to_string().contains("not a directory"), "{e}");
    // A link at the destination is replaced, not written through.
    fs::write(d.join("victim"), "keep").unwrap();
    std::os::unix::fs::symlink(d.join("victim"), d.join("y.png")).unwrap();
    write_png(&d.join("y.png"), 1, 1, &[0, 0, 0]).unwrap();
    assert_eq!(fs::read_to_string(d.join("victim")).unwrap(), "keep");
    // A directory at the destination, or a name ending in `/`, is an
    // error naming the path, and leaves no temporary file.
    fs::create_dir_all(d.join("z.png")).unwrap();
    let e = write_png(&d.join("z.png"), 1, 1, &[0, 0, 0]).unwrap_err();
    assert!(e.to_string().contains("z.png"), "{e}");
    assert!(Atomic::create(Path::new(&format!("{}/w.png/", d.display()))).is_err());
    assert!(fs::read_dir(&d).unwrap().all(|e| !e
        .unwrap()
        .file_name()
        .to_string_lossy()
        .ends_with(".tmp")));
}

#[cfg(target_os = "linux")]
#[test]
fn a_full_disk_names_the_destination_not_the_temporary_file() {
    // The message named `…/.sdfl-c2R2vx.tmp`. /dev/full stands in for
    // the temporary file on a full disk.
    let d = dir("full");
    let dest = d.join("x.png");
    let full = || {
        let tmp = temporary_in(&d).unwrap().into_temp_path();
        in_flight().paths.insert(tmp.to_path_buf());
        let file = fs::File::options().write(true).open("/dev/full").unwrap();
        Atomic::of(&dest, file, tmp)
    };
    let check = |e: io::Error| {
        let msg = e.to_string();
        assert!(msg.starts_with(&format!("{}: ", dest.display())), "{msg}");
        assert!(!msg.contains(".sdfl-"), "{msg}");
        assert!(msg.contains("No space left"), "{msg}");
    };
    // A write larger than the buffer fails at once...
    let mut a = full();
    check(a.writer().write_all(&vec![0u8; 1 << 20]).unwrap_err());
    drop(a);
    // ...a small one when it is flushed, at the commit.
    let mut a = full();
    a.writer().write_all(b"short").unwrap();
    check(a.commit().unwrap_err());
    // Named once, however many layers name it.
    let e = with_path(&dest, io::Error::other("disk full"));
    assert_eq!(
        with_path(&dest, e).to_string(),
        format!("{}: disk full", dest.display())
    );
    // Nothing is left behind, and nothing is registered.
    assert!(fs::read_dir(&d).unwrap().next().is_none());
    assert!(!in_flight().paths.iter().any(|p| p.starts_with(&d)));
}

#[test]
fn abandoning_removes_the_files_in_flight_and_refuses_new_ones() {
    // On a set of this test's own (the process-wide one is shared by
    // the tests running beside it).
    let d = dir("abandon");
    let mut set = InFlight::default();
    let tmps: Vec<TempPath> = (0..2)
        .map(|_| temporary_in(&d).unwrap().into_temp_path())
        .collect();
    for t in &tmps {
        set.paths.insert(t.to_path_buf());
    }
    assert_eq!(set.abandon(), 2);
    assert!(set.closed && set.paths.is_empty());
    assert_eq!(fs::read_dir(&d).unwrap().count(), 0);
    // A file no longer registered (removed by a signal) is not renamed
    // into place: the process is exiting.
    let tmp = temporary_in(&d).unwrap().into_temp_path();
    let file = fs::File::options().write(true).open(&tmp).unwrap();
    let e = Atomic::of(&d.join("a.png"), file, tmp)
        .commit()
        .unwrap_err();
    assert_eq!(e.kind(), io::ErrorKind::Interrupted, "{e}");
    assert_eq!(fs::read_dir(&d).unwrap().count(), 0);
}

#[test]
fn gifs_stream_to_their_file() {
    let d = dir("gif");
    let mut g = GifWriter::create(&d.join("a.gif"), 10.0).unwrap();
    // Noise, so the frames compress to more than the write buffer.
    let mut seed = 1u32;
    for _ in 0..3 {
        let rgb: Vec<u8> = (0..128 * 128 * 3)
            .map(|_| {
                seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (seed >> 24) as u8
            })
            .collect();
        g.push(128, 128, &rgb).unwrap();
    }
    // Frames are in the temporary file already, not in memory.
    let tmp_len: u64 = fs::read_dir(&d)
        .unwrap()
        .map(|e| e.unwrap().metadata().unwrap().len())
        .sum();
    assert!(tmp_len > 0);
    g.finish().unwrap();
    let img = image::open(d.join("a.gif")).unwrap();
    assert_eq!((img.width(), img.height()), (128, 128));
}
