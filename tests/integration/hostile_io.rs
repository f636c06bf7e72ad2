//! Hostile surroundings rather than hostile files: closed and full streams,
//! paths that are not UTF-8, absurd environment variables, signals in the
//! middle of a write, unwritable output directories, colour settings and
//! the umask. Whatever happens, sdfl exits with its real outcome (0, 1, or
//! 128 + the signal), never a panic's 101, and leaves no temporary file.
#![cfg(unix)]

use crate::common::*;

use std::ffi::OsStr;
use std::fs;
use std::io::Read;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

/// A file that runs and warns (its camera is beyond `far`).
const WARNS: &str = "render r {\n  scene: sphere(),\n  camera: look_at(eye: [0, 0, -8]),\n  outputs: [image(\"r.png\")],\n}\n";
/// A file with a syntax error.
const FAILS: &str = "let x = sphere(\n";
/// A render long enough to be interrupted while its GIF is being written.
const LONG_GIF: &str = "render spin {\n  scene: torus(major: 1.0, minor: 0.25),\n  material: rainbow(),\n  camera: orbit(radius: 3, up: [0, 0, 1], views: 5000),\n  size: [128, 128],\n  outputs: [gif(\"spin.gif\")],\n}\n";

/// A training run of `iterations` steps that checkpoints, then writes an
/// image and a GIF.
fn training(iterations: u64) -> String {
    format!(
        "let cameras = [look_at(eye: [0, 0, -3]), look_at(eye: [3, 0, 0])]
let sampler = stratified(samples: 16, near: 0, far: 6)
let target = sdf_volume(sphere(1, center: [-0.2, 0.1, 0.15]), color: [0.2, 0.6, 0.9])
train t {{
  model: sdf_volume(sphere(1, center: param([0.3, 0.2, 0])), color: param([0.3, 0.1, 0.1])),
  data: render_views(target, cameras: cameras, size: [16, 16], sampler: sampler),
  sampler: sampler,
  rays: 64,
  iterations: {iterations},
  after: [gif(\"t.gif\"), loss_curve(\"loss.png\")],
  size: [16, 16],
  checkpoint: \"t.ckpt\",
}}
"
    )
}

/// Spawns sdfl in `dir` with stdout and stderr to files, unless `setup`
/// redirects them.
fn spawn(dir: &Path, args: &[&OsStr], setup: impl FnOnce(&mut Command)) -> Child {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_sdfl"));
    cmd.args(args)
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(fs::File::create(dir.join("stdout.txt")).expect("stdout file"))
        .stderr(fs::File::create(dir.join("stderr.txt")).expect("stderr file"));
    setup(&mut cmd);
    cmd.spawn().expect("the sdfl binary starts")
}

/// Waits for `child`, killing it (and failing) after [`TIME_LIMIT`].
fn wait(child: &mut Child, what: &str) -> ExitStatus {
    let t0 = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait for sdfl") {
            return status;
        }
        if t0.elapsed() > TIME_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what}: ran longer than {TIME_LIMIT:?}");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Polls until `ready` holds, failing after [`TIME_LIMIT`].
fn until(what: &str, mut ready: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !ready() {
        assert!(t0.elapsed() < TIME_LIMIT, "never happened: {what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn read(path: &Path) -> String {
    String::from_utf8_lossy(&fs::read(path).unwrap_or_default()).into_owned()
}

fn os(s: &str) -> &OsStr {
    OsStr::new(s)
}

/// Every sdfl temporary file under `dir`, however deep.
fn temporaries(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    for e in fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = e.path();
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            found.extend(temporaries(&p));
        } else if e.file_name().to_string_lossy().starts_with(".sdfl-") {
            found.push(p);
        }
    }
    found
}

fn write_case(dir: &Path, name: &str, text: &str) -> PathBuf {
    let file = dir.join(name);
    fs::write(&file, text).expect("writable");
    file
}

// ------------------------------------------------------------ streams

#[test]
fn a_closed_or_full_stderr_is_ignored() {
    // `sdfl run warn.sdfl 2>&1 | head -1`, `sdfl check bad.sdfl 2>/dev/full`:
    // eprintln! panicked (exit 101) when stderr could not be written.
    let dir = case_dir("closed_stderr");
    let warns = write_case(&dir, "warns.sdfl", WARNS);
    let fails = write_case(&dir, "fails.sdfl", FAILS);
    let out = dir.join("out");
    for (file, expect) in [(&warns, 0), (&fails, 1)] {
        for args in [
            vec![os("check"), file.as_os_str()],
            vec![
                os("run"),
                file.as_os_str(),
                os("--out"),
                out.as_os_str(),
                os("--size"),
                os("8x8"),
            ],
        ] {
            let what = format!("sdfl {:?}", args);
            // stderr to a full device.
            let mut child = spawn(&dir, &args, |c| {
                c.stderr(fs::File::options().write(true).open("/dev/full").unwrap());
            });
            let status = wait(&mut child, &what);
            assert_eq!(status.code(), Some(expect), "{what} 2>/dev/full");
            // stderr (and stdout) to a pipe whose reader has gone.
            let mut child = spawn(&dir, &args, |c| {
                c.stdout(Stdio::piped()).stderr(Stdio::piped());
            });
            drop(child.stderr.take());
            drop(child.stdout.take());
            let status = wait(&mut child, &what);
            assert_eq!(status.code(), Some(expect), "{what} 2>&1 | head -0");
        }
    }
}

#[test]
fn a_path_that_is_not_utf8_is_reported_lossily_in_json() {
    // `--out $'o\xff' --json` panicked serialising the path.
    let dir = case_dir("non_utf8_out");
    let file = write_case(&dir, "f.sdfl", WARNS);
    let out = dir.join(OsStr::from_bytes(b"o\xff"));
    let args = [
        os("run"),
        file.as_os_str(),
        os("--out"),
        out.as_os_str(),
        os("--size"),
        os("8x8"),
        os("--json"),
    ];
    let status = wait(&mut spawn(&dir, &args, |_| {}), "run --json");
    let stderr = read(&dir.join("stderr.txt"));
    assert_eq!(status.code(), Some(0), "{}", head(&stderr));
    let json: serde_json::Value =
        serde_json::from_str(&read(&dir.join("stdout.txt"))).expect("stdout is JSON");
    let shown = json["out_dir"].as_str().expect("out_dir is a string");
    assert!(shown.ends_with("o\u{FFFD}"), "{shown}");
    assert!(out.join("r.png").is_file());
}

#[test]
fn rayon_num_threads_is_bounded() {
    // RAYON_NUM_THREADS=100000 left sdfl asleep on a futex until killed.
    let dir = case_dir("rayon_threads");
    let file = write_case(&dir, "f.sdfl", WARNS);
    let out = dir.join("out");
    let args = [
        os("run"),
        file.as_os_str(),
        os("--out"),
        out.as_os_str(),
        os("--size"),
        os("8x8"),
    ];
    let mut child = spawn(&dir, &args, |c| {
        c.env("RAYON_NUM_THREADS", "100000");
    });
    let status = wait(&mut child, "RAYON_NUM_THREADS=100000");
    let stderr = read(&dir.join("stderr.txt"));
    assert_eq!(status.code(), Some(0), "{}", head(&stderr));
    assert!(
        stderr.contains("warning[sdfl::arg::threads]") && stderr.contains("RAYON_NUM_THREADS"),
        "{}",
        head(&stderr)
    );
}

// ------------------------------------------------------------ signals

fn signal(child: &Child, sig: i32) {
    // SAFETY: kill(2) on a child we started and have not yet reaped.
    let r = unsafe { libc::kill(child.id() as libc::pid_t, sig) };
    assert_eq!(r, 0, "kill {}", child.id());
}

#[test]
fn a_signal_while_a_gif_is_written_leaves_no_temporary_file() {
    for (sig, code, name) in [
        (libc::SIGTERM, 143, "sigterm"),
        (libc::SIGINT, 130, "sigint"),
        // A closed terminal or ssh session.
        (libc::SIGHUP, 129, "sighup"),
    ] {
        let dir = case_dir(&format!("gif_{name}"));
        let file = write_case(&dir, "spin.sdfl", LONG_GIF);
        let quick = write_case(&dir, "quick.sdfl", WARNS);
        let out = dir.join("out");
        let args = [os("run"), file.as_os_str(), os("--out"), out.as_os_str()];
        let mut child = spawn(&dir, &args, |_| {});
        // The GIF's temporary file, once frames are in it (the empty one
        // that checks --out is writable comes and goes first).
        let frames_in = || {
            temporaries(&out)
                .into_iter()
                .filter(|t| fs::metadata(t).is_ok_and(|m| m.len() > 0))
                .collect::<Vec<_>>()
        };
        until("the GIF's temporary file fills", || !frames_in().is_empty());
        let tmp = frames_in();
        // Another run on the same --out leaves a running one's files alone.
        let quick_dir = dir.join("quick");
        fs::create_dir_all(&quick_dir).unwrap();
        let o = sdfl(
            &quick_dir,
            &[
                "run",
                quick.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--size",
                "8x8",
            ],
        );
        assert_outcome("a second run beside a running one", &o, Expect::Ok);
        assert!(tmp.iter().all(|t| t.exists()), "{tmp:?} removed");
        signal(&child, sig);
        let status = wait(&mut child, name);
        let stderr = read(&dir.join("stderr.txt"));
        assert_eq!(status.code(), Some(code), "{name}: {}", head(&stderr));
        assert!(
            temporaries(&out).is_empty(),
            "{name}: {:?} left",
            temporaries(&out)
        );
        assert!(!out.join("spin.gif").exists(), "a half GIF was renamed in");
        // It says where it stopped.
        assert!(stderr.contains("`spin`"), "{name}: {}", head(&stderr));
        assert!(!stderr.contains("panicked"), "{}", head(&stderr));
    }
}

/// The step a stopped training run reports (`... at step N ...`).
fn stopped_step(stderr: &str) -> u64 {
    let at = stderr.find("at step ").expect("says the step") + "at step ".len();
    let digits: String = stderr[at..]
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    digits.parse().expect("a step number")
}

#[test]
fn a_signal_while_training_keeps_a_resumable_checkpoint() {
    for (sig, code, name) in [
        (libc::SIGINT, 130, "sigint"),
        (libc::SIGTERM, 143, "sigterm"),
    ] {
        let dir = case_dir(&format!("train_{name}"));
        let file = write_case(&dir, "t.sdfl", &training(10_000_000));
        let out = dir.join("out");
        let ckpt = out.join("t.ckpt");
        let args = [os("run"), file.as_os_str(), os("--out"), out.as_os_str()];
        let mut child = spawn(&dir, &args, |_| {});
        // The checkpoint is written at the start and every 100 steps (each
        // time a new file renamed in): a new inode means training is under way.
        until("the first checkpoint", || ckpt.exists());
        let first = fs::metadata(&ckpt).map(|m| m.ino()).unwrap_or(0);
        until("a checkpoint written by training", || {
            fs::metadata(&ckpt).is_ok_and(|m| m.ino() != first)
        });
        signal(&child, sig);
        let status = wait(&mut child, name);
        let stderr = read(&dir.join("stderr.txt"));
        assert_eq!(status.code(), Some(code), "{name}: {}", head(&stderr));
        assert!(temporaries(&out).is_empty(), "{:?}", temporaries(&out));
        assert!(stderr.contains("`t`"), "{}", head(&stderr));
        let step = stopped_step(&stderr);
        assert!(step >= 100, "{}", head(&stderr));
        // The checkpoint holds that step: a run of `step + 3` iterations
        // resumes there and trains three more.
        let file = write_case(&dir, "t.sdfl", &training(step + 3));
        let args = [
            os("run"),
            file.as_os_str(),
            os("--out"),
            out.as_os_str(),
            os("--json"),
        ];
        let status = wait(&mut spawn(&dir, &args, |_| {}), "resume");
        let stderr = read(&dir.join("stderr.txt"));
        assert_eq!(status.code(), Some(0), "{}", head(&stderr));
        let json: serde_json::Value =
            serde_json::from_str(&read(&dir.join("stdout.txt"))).expect("JSON");
        let report = &json["jobs"][0]["report"];
        assert_eq!(report["resumed_from"].as_u64(), Some(step), "{report}");
    }
}

#[test]
fn a_later_run_removes_stale_temporaries_and_nothing_else() {
    // kill -9 cannot be caught: what it leaves, the next run removes.
    let dir = case_dir("stale_tmp");
    let file = write_case(&dir, "f.sdfl", WARNS);
    let out = dir.join("out");
    fs::create_dir_all(out.join("sub")).unwrap();
    let stale = [
        out.join(".sdfl-abc123.tmp"),
        out.join("sub/.sdfl-XyZ789.tmp"),
    ];
    // Not of sdfl's naming, a directory, a link (to a file outside --out
    // with a stale name), or outside --out: all kept.
    let kept = [
        out.join(".sdfl-abc123.tmp.keep"),
        out.join(".sdfl-abc12.tmp"),
        out.join(".sdfl-abc1234.tmp"),
        out.join("sdfl-abc123.tmp"),
        out.join(".sdfl-ab-123.tmp"),
        out.join("mine.tmp"),
        dir.join(".sdfl-out123.tmp"),
    ];
    for p in stale.iter().chain(&kept) {
        fs::write(p, "x").unwrap();
    }
    fs::create_dir_all(out.join(".sdfl-dir123.tmp")).unwrap();
    std::os::unix::fs::symlink(dir.join(".sdfl-out123.tmp"), out.join(".sdfl-lnk123.tmp")).unwrap();
    let o = sdfl(
        &dir,
        &[
            "run",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--size",
            "8x8",
        ],
    );
    assert_outcome("a run over stale temporaries", &o, Expect::Ok);
    for p in &stale {
        assert!(!p.exists(), "{} is left", p.display());
    }
    for p in &kept {
        assert!(p.exists(), "{} was removed", p.display());
    }
    assert!(out.join(".sdfl-dir123.tmp").is_dir());
    assert!(out.join(".sdfl-lnk123.tmp").is_symlink());
    assert_eq!(read(&dir.join(".sdfl-out123.tmp")), "x");
}

// ------------------------------------------------------------ the output directory

#[test]
fn an_unwritable_out_is_refused_before_any_work() {
    let dir = case_dir("unwritable_out");
    let file = write_case(&dir, "t.sdfl", &training(100));
    let mut outs = Vec::new();
    // A read-only directory stops everyone but root (the tests may run as
    // root, whom permissions do not stop), so it is checked only when it
    // does stop this user; /proc/self refuses new files even to root.
    let ro = dir.join("ro");
    fs::create_dir_all(&ro).unwrap();
    fs::set_permissions(&ro, fs::Permissions::from_mode(0o555)).unwrap();
    if fs::write(ro.join("probe"), "x").is_err() {
        outs.push(ro.clone());
    }
    if Path::new("/proc/self").is_dir() {
        outs.push(PathBuf::from("/proc/self"));
    }
    assert!(!outs.is_empty(), "no unwritable directory to test with");
    for out in outs {
        let o = run_into(&dir, &file, &out, &[]);
        assert_outcome(&format!("--out {}", out.display()), &o, Expect::Error);
        assert!(
            o.stderr.contains("sdfl::io")
                && o.stderr.contains("output directory")
                && o.stderr.contains("help:"),
            "{}",
            head(&o.stderr)
        );
        // Names the directory, not the probe's temporary file.
        assert!(!o.stderr.contains(".sdfl-"), "{}", head(&o.stderr));
        // Refused before the training ran, not at its first write.
        assert!(!o.stderr.contains("while running"), "{}", head(&o.stderr));
    }
    fs::set_permissions(&ro, fs::Permissions::from_mode(0o755)).unwrap();
}

#[test]
fn outputs_and_checkpoints_follow_the_umask() {
    // Files were created 0600 whatever the umask (tempfile's default).
    for (umask, mode) in [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)] {
        let dir = case_dir(&format!("umask_{umask:o}"));
        let file = write_case(&dir, "t.sdfl", &training(5));
        let out = dir.join("out");
        let args = [os("run"), file.as_os_str(), os("--out"), out.as_os_str()];
        let mut child = spawn(&dir, &args, |c| {
            // SAFETY: umask(2) is async-signal-safe.
            unsafe {
                c.pre_exec(move || {
                    libc::umask(umask);
                    Ok(())
                });
            }
        });
        let status = wait(&mut child, "umask");
        assert_eq!(
            status.code(),
            Some(0),
            "{}",
            head(&read(&dir.join("stderr.txt")))
        );
        for name in ["t.ckpt", "t.gif", "loss.png"] {
            let m = fs::metadata(out.join(name)).expect(name).mode() & 0o777;
            assert_eq!(m, mode, "{name} under umask {umask:o}: {m:o}");
        }
    }
}

// ------------------------------------------------------------ colour

/// Runs `sdfl check FILE` with stderr on a terminal, returning what it
/// printed there.
fn check_on_a_terminal(dir: &Path, file: &Path, env: &[(&str, &str)]) -> String {
    let (mut master, mut slave) = (0, 0);
    // SAFETY: openpty fills in two descriptors, which we then own.
    let r = unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    assert_eq!(r, 0, "openpty");
    use std::os::fd::FromRawFd;
    // SAFETY: both descriptors are fresh and owned here.
    let (master, slave) = unsafe { (fs::File::from_raw_fd(master), fs::File::from_raw_fd(slave)) };
    let mut reader = master;
    let collect = std::thread::spawn(move || {
        let mut bytes = Vec::new();
        let mut buf = [0u8; 4096];
        // EIO once the last writer has gone: the end.
        while let Ok(n) = reader.read(&mut buf) {
            if n == 0 {
                break;
            }
            bytes.extend_from_slice(&buf[..n]);
        }
        bytes
    });
    let mut child = spawn(dir, &[os("check"), file.as_os_str()], |c| {
        c.stderr(slave.try_clone().unwrap())
            .env_remove("NO_COLOR")
            .env_remove("CLICOLOR")
            .env_remove("CLICOLOR_FORCE");
        for (k, v) in env {
            c.env(k, v);
        }
    });
    drop(slave);
    let status = wait(&mut child, "check on a terminal");
    assert_eq!(status.code(), Some(1));
    String::from_utf8_lossy(&collect.join().unwrap()).into_owned()
}

#[test]
fn no_color_and_clicolor_turn_colour_off() {
    let dir = case_dir("no_color");
    let file = write_case(&dir, "bad.sdfl", FAILS);
    // On a terminal, diagnostics are coloured (so the test can fail)...
    let coloured = check_on_a_terminal(&dir, &file, &[]);
    assert!(coloured.contains("\x1b["), "{coloured}");
    // ...unless NO_COLOR (any non-empty value) or CLICOLOR=0 says not to.
    for env in [[("NO_COLOR", "1")], [("CLICOLOR", "0")]] {
        let plain = check_on_a_terminal(&dir, &file, &env);
        assert!(plain.contains("sdfl::"), "{env:?}: {plain}");
        assert!(!plain.contains('\x1b'), "{env:?}: {plain:?}");
    }
    // An empty NO_COLOR is as if unset (no-color.org).
    let coloured = check_on_a_terminal(&dir, &file, &[("NO_COLOR", "")]);
    assert!(coloured.contains("\x1b["), "{coloured}");
    // Not a terminal: never colour.
    let o = sdfl(&dir, &["check", file.to_str().unwrap()]);
    assert!(!o.stderr.contains('\x1b'), "{}", o.stderr);
}

/// A report written to a full device is lost: the run fails (exit 1 with
/// a diagnostic), where a script reading `--json` used to see success. A
/// closed pipe stays a normal end.
#[test]
fn a_full_stdout_is_a_failure() {
    let dir = case_dir("stdout_full");
    let file = write_case(&dir, "quick.sdfl", WARNS);
    for args in [
        vec![os("plan"), file.as_os_str()],
        vec![
            os("run"),
            file.as_os_str(),
            os("--out"),
            dir.join("out").into_os_string().leak(),
            os("--json"),
        ],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_sdfl"))
            .args(&args)
            .stdin(Stdio::null())
            .stdout(
                fs::OpenOptions::new()
                    .write(true)
                    .open("/dev/full")
                    .unwrap(),
            )
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(
            stderr.contains("error[sdfl::io]: cannot write to stdout"),
            "{stderr}"
        );
    }
}

/// Output directories are checked before any work: a file where an
/// output's directory should be, or a link on the way, used to be found
/// only after a whole training run.
#[test]
fn output_directories_are_checked_before_any_work() {
    let dir = case_dir("output_dirs_first");
    let scene = "let cams = [look_at(eye: [0, 0, -3])]\n\
                 train t {\n  model: sdf_volume(sphere(param(0.8))),\n  \
                 data: render_views(sdf_volume(sphere(1)), cameras: cams, size: [8, 8]),\n  \
                 iterations: 1000000,\n  views: cams,\n  size: [8, 8],\n  \
                 after: [image(\"x/t.png\")],\n  checkpoint: \"t.ckpt\",\n}\n";
    let file = write_case(&dir, "t.sdfl", scene);
    let out = dir.join("out");
    fs::create_dir_all(&out).unwrap();
    fs::write(out.join("x"), "a file in the way").unwrap();
    let o = run_into(&dir, &file, &out, &[]);
    assert_outcome("a file in the way", &o, Expect::Error);
    assert!(o.stderr.contains("not a directory"), "{}", head(&o.stderr));
    // Refused before training: no checkpoint, and at once.
    assert!(!out.join("t.ckpt").exists());
    assert!(o.elapsed < HANG_GUARD, "{:?}", o.elapsed);
    fs::remove_file(out.join("x")).unwrap();
    std::os::unix::fs::symlink(&dir, out.join("x")).unwrap();
    let o = run_into(&dir, &file, &out, &[]);
    assert_outcome("a link in the way", &o, Expect::Error);
    assert!(o.stderr.contains("symbolic link"), "{}", head(&o.stderr));
    assert!(!out.join("t.ckpt").exists());
}

// ------------------------------------------------------------ special files

/// Makes a FIFO at `path`; false where there is no `mkfifo`.
fn mkfifo(path: &Path) -> bool {
    Command::new("mkfifo")
        .arg(path)
        .status()
        .is_ok_and(|s| s.success())
}

/// The resident memory of process `pid` in KiB, where `/proc` tells it.
fn resident_kib(pid: u32) -> Option<u64> {
    let status = fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Spawns `sdfl watch` with `args` in `dir` and waits until its stderr holds
/// each of `wanted` (it then waits for a change: killed here). Fails when
/// that takes [`HANG_GUARD`], or when it grows past 1 GiB (a read without
/// limit, stopped before it fills the machine). Returns its stderr.
fn watch_until(dir: &Path, args: &[&OsStr], wanted: &[&str]) -> String {
    let mut child = spawn(dir, args, |_| {});
    let t0 = Instant::now();
    let stderr = loop {
        let stderr = read(&dir.join("stderr.txt"));
        if wanted.iter().all(|w| stderr.contains(w)) {
            break stderr;
        }
        let exited = child.try_wait().expect("wait for sdfl");
        let big = resident_kib(child.id()).is_some_and(|k| k > 1 << 20);
        if exited.is_some() || big || t0.elapsed() > HANG_GUARD {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "sdfl {args:?}: {} before saying {wanted:?}; stderr:\n{}",
                if big {
                    "grew past 1 GiB".to_string()
                } else if let Some(s) = exited {
                    format!("ended ({s})")
                } else {
                    format!("still silent after {HANG_GUARD:?}")
                },
                head(&stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let _ = child.kill();
    let _ = child.wait();
    assert!(!stderr.contains("panicked"), "{}", head(&stderr));
    stderr
}

/// A FIFO or a link to `/dev/zero` where a scene file, an import's
/// neighbour or a sweep's image should be: `watch` hung on the FIFO and
/// read the device without limit, `sweep --collect` hung on a FIFO image.
/// Every command ends with a diagnostic (watch says so and waits) at once.
#[test]
fn every_command_refuses_fifos_and_devices_without_hanging() {
    let dir = case_dir("special_files");
    let good = write_case(&dir, "good.sdfl", WARNS);
    let zero = dir.join("zero.sdfl");
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    let mut specials = vec![zero];
    let fifo = dir.join("fifo.sdfl");
    if mkfifo(&fifo) {
        specials.push(fifo);
    }
    let out = dir.join("out");
    for special in &specials {
        let s = special.to_str().unwrap();
        let o = out.to_str().unwrap();
        for args in [
            vec!["check", s],
            vec!["check", "--json", s],
            vec!["run", s, "--out", o, "--size", "8x8"],
            vec!["run", s, "--out", o, "--json"],
            vec!["fmt", s],
            vec!["plan", s],
            vec!["sweep", s, "--set", "x=1,2", "--out", o, "--collect"],
        ] {
            let what = format!("sdfl {}", args.join(" "));
            let r = sdfl(&dir, &args);
            assert!(r.elapsed < HANG_GUARD, "{what}: {:?}", r.elapsed);
            // With `--json` the diagnostic may be on stdout alone.
            let said = format!("{}{}", r.stderr, read(&dir.join("stdout.txt")));
            assert_eq!(r.code, Some(1), "{what}: {}", head(&said));
            assert!(
                said.contains("sdfl::io") && said.contains("not a regular file"),
                "{what}: {}",
                head(&said)
            );
            assert!(!said.contains("panicked"), "{what}: {}", head(&said));
        }
        let args = [
            os("watch"),
            special.as_os_str(),
            os("--out"),
            out.as_os_str(),
        ];
        let stderr = watch_until(&dir, &args, &["not a regular file", "watch: waiting"]);
        assert!(stderr.contains("sdfl::io"), "{}", head(&stderr));
    }
    // A watched file beside them: the FIFO and the device are looked at
    // for changes (they end in `.sdfl`), never read.
    let args = [os("watch"), good.as_os_str(), os("--out"), out.as_os_str()];
    watch_until(&dir, &args, &["watch: waiting"]);
    assert!(out.join("r.png").is_file());
}

/// `sweep --collect` where a finished setting's image is a FIFO, or a link
/// to `/dev/zero`: the row no longer stands (its output is not the file
/// it wrote), said with the setting, never read.
#[test]
fn a_sweep_whose_image_is_special_is_refused_on_collect() {
    let dir = case_dir("special_sweep");
    let scene = write_case(
        &dir,
        "scene.sdfl",
        "let samples = 4\nrender v { scene: sdf_volume(box(size: 1.5)), camera: look_at([0, 0, -3]),\n\
         sampler: stratified(samples: samples), outputs: [image(\"v.png\")], size: [8, 8] }\n",
    );
    let out = dir.join("out");
    let (s, o) = (scene.to_str().unwrap(), out.to_str().unwrap());
    let sweep = ["sweep", s, "--set", "samples=4,8", "--out", o];
    assert_outcome("the sweep", &sdfl(&dir, &sweep), Expect::Ok);
    let collect = ["sweep", s, "--set", "samples=4,8", "--out", o, "--collect"];
    assert_outcome("a collect", &sdfl(&dir, &collect), Expect::Ok);
    let image = out.join("samples=4").join("v.png");
    for what in ["a link to /dev/zero", "a FIFO"] {
        fs::remove_file(&image).unwrap();
        if what == "a FIFO" {
            if !mkfifo(&image) {
                continue;
            }
        } else {
            std::os::unix::fs::symlink("/dev/zero", &image).unwrap();
        }
        let r = sdfl(&dir, &collect);
        assert!(r.elapsed < HANG_GUARD, "{what}: {:?}", r.elapsed);
        assert_outcome(what, &r, Expect::Error);
        assert!(
            r.stderr.contains("samples=4/v.png") && r.stderr.contains("not a regular file"),
            "{what}: {}",
            head(&r.stderr)
        );
    }
}

// ------------------------------------------------------------ encodings

/// A scene file with a byte that is not UTF-8 (Latin-1 `é`): `check` and
/// `run` replaced it silently; now refused at that byte, as are imports.
#[test]
fn a_scene_that_is_not_utf8_is_refused_at_its_first_bad_byte() {
    let dir = case_dir("not_utf8");
    // `\xe9` at byte 25: line 2, column 9 (after `let b = `).
    let text = b"let a = sphere()\nlet b = \xe9\nlet c = \xff\n";
    let file = dir.join("latin1.sdfl");
    fs::write(&file, text).unwrap();
    let f = file.to_str().unwrap();
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    for args in [
        vec!["check", f],
        vec!["run", f, "--out", o, "--size", "8x8"],
    ] {
        let r = sdfl(&dir, &args);
        assert_outcome(args[0], &r, Expect::Error);
        assert!(
            r.stderr.contains("sdfl::source::encoding"),
            "{}",
            head(&r.stderr)
        );
        assert!(r.stderr.contains("UTF-8"), "{}", head(&r.stderr));
        assert!(r.stderr.contains("latin1.sdfl:2:9"), "{}", head(&r.stderr));
    }
    for args in [
        vec!["check", "--json", f],
        vec!["run", f, "--out", o, "--json"],
    ] {
        let r = sdfl(&dir, &args);
        assert_eq!(r.code, Some(1), "{}", head(&r.stderr));
        let json: serde_json::Value =
            serde_json::from_str(&read(&dir.join("stdout.txt"))).expect("JSON");
        let d = if args[0] == "check" {
            &json["files"][0]["diagnostics"][0]
        } else {
            &json["diagnostics"][0]
        };
        assert_eq!(d["code"], "sdfl::source::encoding", "{json:#}");
        assert_eq!(d["span"]["start"], 25, "{json:#}");
        assert_eq!(
            (d["line"].as_u64(), d["column"].as_u64()),
            (Some(2), Some(9))
        );
        assert!(d["help"].as_str().unwrap().contains("UTF-8"), "{d}");
    }
    // An import that is not UTF-8: refused at the `import`, with the byte.
    let main = write_case(&dir, "main.sdfl", "import \"latin1.sdfl\"\nlet x = 1\n");
    let r = sdfl(&dir, &["check", main.to_str().unwrap()]);
    assert_outcome("import", &r, Expect::Error);
    assert!(
        r.stderr.contains("sdfl::source::encoding"),
        "{}",
        head(&r.stderr)
    );
    let text = unwrapped(&r.stderr);
    assert!(
        text.contains("byte 25") && text.contains("main.sdfl:1:8"),
        "{}",
        head(&r.stderr)
    );
}
