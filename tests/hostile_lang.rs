//! Hostile and newcomer input for the language front end and evaluation
//! (issue 21): memory proportional to the source, every error of a file in
//! one run, units, and errors inside `fn`s reported once.

mod common;
use common::*;

use std::fs;
use std::path::Path;
use std::process::{Command, Stdio};

/// Runs `sdfl check FILE` and returns its stderr and the peak resident
/// memory of the process in bytes (`wait4`'s rusage of that one child: other
/// tests' children do not count).
fn check_peak_memory(file: &Path) -> (Option<i32>, String, u64) {
    let err_path = file.with_extension("stderr");
    let child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .arg("check")
        .arg(file)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(fs::File::create(&err_path).expect("stderr file"))
        .spawn()
        .expect("the sdfl binary starts");
    let mut status = 0;
    // SAFETY: a zeroed rusage is a valid value; wait4 fills it for the
    // child we spawned (and reaps it: `child` is not waited on again).
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = unsafe { libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as libc::pid_t, "wait4 failed");
    let code = libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status));
    let stderr = fs::read_to_string(&err_path).unwrap_or_default();
    // Linux reports ru_maxrss in KiB.
    (code, stderr, usage.ru_maxrss as u64 * 1024)
}

/// A 16 MB file of a million plain `let`s is checked in memory proportional
/// to its size. (Parsing the whole file at once kept pest's token queue for
/// all of it: 50 bytes per source byte, 5.1 GB for 59 MB. Items are parsed
/// one at a time now; what remains is the tree and the name tables, about
/// 29 bytes per byte here.)
#[test]
fn a_large_file_of_lets_is_checked_in_memory_proportional_to_it() {
    const BYTES_PER_SOURCE_BYTE: u64 = 40;
    const BASELINE: u64 = 32 << 20;
    let dir = case_dir("lang_many_lets");
    let file = dir.join("lets.sdfl");
    let mut text = String::with_capacity(17 << 20);
    let mut i = 0;
    while text.len() < 16 << 20 {
        use std::fmt::Write;
        let _ = writeln!(text, "let a{i} = {}", i % 10);
        i += 1;
    }
    fs::write(&file, &text).expect("case file is writable");
    let (code, stderr, peak) = check_peak_memory(&file);
    assert_eq!(code, Some(0), "{}", head(&stderr));
    let bound = BYTES_PER_SOURCE_BYTE * text.len() as u64 + BASELINE;
    assert!(
        peak <= bound,
        "checking {} bytes of source peaked at {} MB, over {} MB ({BYTES_PER_SOURCE_BYTE} bytes per byte)",
        text.len(),
        peak >> 20,
        bound >> 20
    );
}
