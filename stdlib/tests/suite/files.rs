use std::io;

use sdfl_lang::codes;
use sdfl_stdlib::files::*;

fn dir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-files-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn regular_files_are_read_within_their_cap() {
    let d = dir("cap");
    let p = d.join("f.txt");
    std::fs::write(&p, b"hello").unwrap();
    assert_eq!(read_capped(&p, 5).unwrap(), b"hello");
    let e = read_capped(&p, 4).unwrap_err();
    assert_eq!(e.kind(), io::ErrorKind::FileTooLarge);
    assert!(e.to_string().contains("f.txt"), "{e}");
    assert!(read_capped(&d.join("missing"), 5).is_err());
    assert!(read_capped(&d, 5).is_err(), "a directory");
}

#[cfg(unix)]
#[test]
fn devices_fifos_and_links_are_refused_without_blocking() {
    let d = dir("special");
    let zero = d.join("zero");
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    let e = read_capped(&zero, 1 << 20).unwrap_err();
    assert!(e.to_string().contains("not a regular file"), "{e}");
    let fifo = d.join("fifo");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .is_ok_and(|s| s.success());
    if made {
        assert!(open_regular(&fifo).is_err());
        assert!(open_regular_unlinked(&fifo).is_err());
        // Opened without waiting for a writer, then refused.
        assert!(open_nonblocking(&fifo).is_ok());
    }
    let file = d.join("f");
    std::fs::write(&file, b"x").unwrap();
    let link = d.join("link");
    std::os::unix::fs::symlink(&file, &link).unwrap();
    assert!(open_regular(&link).is_ok());
    assert!(open_regular_unlinked(&link).is_err());
    assert!(open_regular_unlinked(&file).is_ok());
}

#[test]
fn the_first_bad_byte_is_found() {
    assert_eq!(utf8(b"ok".to_vec()).ok().as_deref(), Some("ok"));
    let e = utf8(b"ab\xffcd\xfe".to_vec()).err().unwrap();
    assert_eq!((e.at, e.byte), (2, 0xff));
    assert_eq!(e.lossy, "ab\u{fffd}cd\u{fffd}");
    assert_eq!(&e.lossy[..e.at], "ab");
    let e = utf8("é\nlet b = \u{1}".bytes().chain([0xe9]).collect())
        .err()
        .unwrap();
    assert_eq!(e.line_col(), (2, 10));
    assert_eq!(e.place(), "byte 12 (0xe9, line 2, column 10)");
    let d = e.diag();
    assert_eq!(d.code, codes::SOURCE_ENCODING);
    assert_eq!(&e.lossy[d.span.start..d.span.end], "\u{fffd}");
}
