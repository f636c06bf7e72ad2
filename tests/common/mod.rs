//! The hostile-input runner shared by the test files that drive the real
//! binary: each case runs in its own directory with a time bound, and its
//! outcome is checked for a clean exit and a diagnostic code.
#![allow(dead_code)]

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Longest any one command may take before it is killed (the slowest
/// cases need about a second).
pub const TIME_LIMIT: Duration = Duration::from_secs(90);

/// What a case that once hung may take: generous, so that only a hang
/// trips it, however loaded the machine.
pub const HANG_GUARD: Duration = Duration::from_secs(60);

/// What a run of the binary did.
pub struct Outcome {
    pub code: Option<i32>,
    pub stderr: String,
    pub elapsed: Duration,
}

/// A fresh, empty directory for one case, under the calling file's name
/// (the suites share one test binary: two files' cases of the same name
/// run at once).
#[track_caller]
pub fn case_dir(name: &str) -> PathBuf {
    let file = Path::new(std::panic::Location::caller().file());
    let suite = file.file_stem().unwrap_or_default();
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("hostile")
        .join(suite)
        .join(name);
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).expect("temp dir is writable");
    dir
}

/// Runs `sdfl` with `args`, killing it after [`TIME_LIMIT`]. Output goes to
/// files (a pipe could fill up and block the child).
pub fn sdfl(dir: &Path, args: &[&str]) -> Outcome {
    let (out_path, err_path) = (dir.join("stdout.txt"), dir.join("stderr.txt"));
    let t0 = Instant::now();
    let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(fs::File::create(&out_path).expect("stdout file"))
        .stderr(fs::File::create(&err_path).expect("stderr file"))
        .spawn()
        .expect("the sdfl binary starts");
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for sdfl") {
            break status;
        }
        if t0.elapsed() > TIME_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            panic!("`sdfl {}` ran longer than {TIME_LIMIT:?}", args.join(" "));
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let stderr = String::from_utf8_lossy(&fs::read(&err_path).unwrap_or_default()).into_owned();
    Outcome {
        code: status.code(),
        stderr,
        elapsed: t0.elapsed(),
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Expect {
    /// Exit 0.
    Ok,
    /// Exit 1 with a diagnostic.
    Error,
}

/// The start of stderr, for failure messages (some are megabytes long).
pub fn head(s: &str) -> &str {
    let mut end = s.len().min(2000);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

/// A rendered diagnostic with miette's line wrapping undone: words joined by
/// single spaces, the gutter's `│` dropped. Where a message wraps depends on
/// the length of the paths in it, so on where the tests run.
pub fn unwrapped(s: &str) -> String {
    s.split_whitespace()
        .filter(|w| *w != "│")
        .collect::<Vec<_>>()
        .join(" ")
}

pub fn assert_outcome(what: &str, o: &Outcome, expect: Expect) {
    assert!(
        matches!(o.code, Some(0 | 1)),
        "{what}: exit {:?} (a signal, panic or overflow), stderr:\n{}",
        o.code,
        head(&o.stderr)
    );
    assert!(
        !o.stderr.contains("panicked") && !o.stderr.contains("overflowed its stack"),
        "{what}: {}",
        head(&o.stderr)
    );
    match expect {
        Expect::Ok => assert_eq!(o.code, Some(0), "{what}: stderr:\n{}", head(&o.stderr)),
        Expect::Error => {
            assert_eq!(
                o.code,
                Some(1),
                "{what}: should fail; stderr:\n{}",
                head(&o.stderr)
            );
            assert!(
                o.stderr.contains("sdfl::"),
                "{what}: no diagnostic code in stderr:\n{}",
                head(&o.stderr)
            );
        }
    }
}

/// Writes `contents` to a file and runs both `check` and `run` on it.
#[track_caller]
pub fn hostile(name: &str, contents: impl AsRef<[u8]>, expect: Expect) -> Vec<Outcome> {
    let dir = case_dir(name);
    let file = dir.join(format!("{name}.sdfl"));
    fs::write(&file, contents).expect("case file is writable");
    let file = file.to_str().expect("temp paths are UTF-8");
    let out = dir.join("out");
    let out = out.to_str().expect("temp paths are UTF-8");
    let mut outcomes = Vec::new();
    for args in [
        vec!["check", file],
        vec!["run", file, "--out", out, "--size", "8x8"],
    ] {
        let o = sdfl(&dir, &args);
        assert_outcome(&format!("{name}: sdfl {}", args[0]), &o, expect);
        outcomes.push(o);
    }
    outcomes
}

/// `n` points on the sphere of radius 0.8 about the origin (a Fibonacci
/// lattice), as `sphere.xyz` in `dir`: data for neural SDF fits.
pub fn write_sphere_points(dir: &Path, n: usize) {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let text: String = (0..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - y * y).sqrt();
            let t = golden * i as f64;
            format!("{} {} {}\n", 0.8 * r * t.cos(), 0.8 * y, 0.8 * r * t.sin())
        })
        .collect();
    fs::write(dir.join("sphere.xyz"), text).expect("the case directory is writable");
}

/// `sdfl run FILE --out OUT` in `dir` (see [`sdfl`]), extra arguments after.
pub fn run_into(dir: &Path, file: &Path, out: &Path, extra: &[&str]) -> Outcome {
    let (file, out) = (
        file.to_str().expect("test paths are UTF-8"),
        out.to_str().expect("test paths are UTF-8"),
    );
    let mut args = vec!["run", file, "--out", out];
    args.extend_from_slice(extra);
    sdfl(dir, &args)
}

/// `sdfl run FILE --out out --json` in `dir` without the hang guard (for
/// training runs longer than [`TIME_LIMIT`]): the JSON report of its first
/// statement, after asserting that the run succeeded.
pub fn run_report(dir: &Path, file: &str) -> serde_json::Value {
    let o = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(["run", file, "--out", "out", "--json"])
        .current_dir(dir)
        .output()
        .expect("the sdfl binary runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).expect("--json prints JSON");
    report["jobs"][0]["report"].clone()
}

/// Runs `sdfl` with `args` and waits for it, output captured: for commands
/// that end quickly by design (the hostile runner above bounds the time).
pub fn run_sdfl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(args)
        .output()
        .expect("sdfl runs")
}

/// A fresh, empty directory `sdfl-<suite>-<pid>-<name>` in the system's
/// temporary directory.
pub fn temp_dir(suite: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-{suite}-{}-{name}", std::process::id()));
    let _ = fs::remove_dir_all(&d);
    fs::create_dir_all(&d).expect("temp dir is writable");
    d
}
