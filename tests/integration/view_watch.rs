//! `sdfl watch`: a statement runs again only when what it depends on
//! changed; the fingerprints survive the process; diagnostics show at once.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

/// Saved as editors do: written beside, then renamed into place.
fn save(file: &Path, text: &str) {
    let tmp = file.with_extension("sdfl~");
    std::fs::write(&tmp, text).unwrap();
    std::fs::rename(&tmp, file).unwrap();
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-watch-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Two renders of one shared sphere, the second from `eye_b`.
fn scene(eye_b: f64) -> String {
    format!(
        "let s = sphere(1)\n\
         render near {{ scene: s, camera: look_at(eye: [0, 0, 4], at: [0, 0, 0], up: [0, 1, 0], focal: 1.5), size: [24, 24], far: 9, outputs: [image(\"near.png\")] }}\n\
         render far {{ scene: s, camera: look_at(eye: [0, 0, {eye_b}], at: [0, 0, 0], up: [0, 1, 0], focal: 1.5), size: [24, 24], far: 9, outputs: [image(\"far.png\")] }}\n"
    )
}

/// `sdfl watch FILE --out OUT --max-runs 1`: (success, stdout lines).
fn watch_once(file: &Path, out: &Path) -> (bool, Vec<String>, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args([
            "watch",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .args(["--max-runs", "1"])
        .output()
        .unwrap();
    let lines = String::from_utf8_lossy(&o.stdout)
        .lines()
        .filter(|l| l.starts_with("ran ") || l.starts_with("skipped "))
        .map(|l| l.split(" (").next().unwrap().to_string())
        .collect();
    (
        o.status.success(),
        lines,
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn only_the_changed_render_runs_again_across_watches() {
    let dir = temp("across");
    let (file, out) = (dir.join("scene.sdfl"), dir.join("out"));
    std::fs::write(&file, scene(5.0)).unwrap();
    let (ok, lines, err) = watch_once(&file, &out);
    assert!(ok, "{err}");
    assert_eq!(lines, ["ran near", "ran far"]);
    let near = std::fs::read(out.join("near.png")).unwrap();

    // Nothing changed: nothing runs.
    let (_, lines, _) = watch_once(&file, &out);
    assert_eq!(lines, ["skipped near", "skipped far"]);

    // A comment above both and a new camera for `far` only.
    std::fs::write(&file, format!("// moved\n{}", scene(6.0))).unwrap();
    let (ok, lines, err) = watch_once(&file, &out);
    assert!(ok, "{err}");
    assert_eq!(lines, ["skipped near", "ran far"]);
    assert_eq!(std::fs::read(out.join("near.png")).unwrap(), near);

    // An output deleted is written again, though its statement is unchanged.
    std::fs::remove_file(out.join("near.png")).unwrap();
    let (_, lines, _) = watch_once(&file, &out);
    assert_eq!(lines, ["ran near", "skipped far"]);
    assert_eq!(std::fs::read(out.join("near.png")).unwrap(), near);

    // Another size on the command line is another input.
    let o = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args([
            "watch",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .args(["--max-runs", "1", "--size", "16x16"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("ran near") && text.contains("ran far"),
        "{text}"
    );
}

#[test]
fn a_save_runs_the_changed_statement_and_diagnostics_show_at_once() {
    let dir = temp("loop");
    let (file, out) = (dir.join("scene.sdfl"), dir.join("out"));
    std::fs::write(&file, scene(5.0)).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args([
            "watch",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .args(["--max-runs", "3"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Every line of both streams, in order per stream, through one channel.
    let (tx, rx) = mpsc::channel::<String>();
    let err_tx = tx.clone();
    let stderr = child.stderr.take().unwrap();
    let stdout = child.stdout.take().unwrap();
    std::thread::spawn(move || {
        for l in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = err_tx.send(format!("err: {l}"));
        }
    });
    std::thread::spawn(move || {
        for l in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    // A guard against a hang, not a timing assertion.
    let next = |seen: &mut Vec<String>| {
        let l = rx
            .recv_timeout(Duration::from_secs(120))
            .unwrap_or_else(|_| panic!("sdfl watch went silent; so far: {seen:#?}"));
        seen.push(l.clone());
        l
    };
    let mut seen = Vec::new();
    let wait_for = |want: &str, seen: &mut Vec<String>| {
        while !next(seen).contains(want) {}
        seen.len()
    };
    wait_for("watch: waiting", &mut seen);
    // A mistake: its diagnostic comes at once, and nothing runs.
    save(&file, &scene(5.0).replace("sphere(1)", "sphere(1"));
    let first_wait = seen.len();
    wait_for("watch: waiting", &mut seen);
    let broken = seen[first_wait..].join("\n");
    assert!(broken.contains("error"), "{broken}");
    assert!(!broken.contains("ran "), "{broken}");
    // Fixed, with `far` moved: only `far` runs.
    save(&file, &scene(7.0));
    let status = child.wait().unwrap();
    while let Ok(l) = rx.recv_timeout(Duration::from_secs(5)) {
        seen.push(l);
    }
    assert!(status.success(), "{seen:#?}");
    let runs: Vec<&String> = seen
        .iter()
        .filter(|l| l.starts_with("ran ") || l.starts_with("skipped "))
        .collect();
    let names: Vec<&str> = runs.iter().map(|l| l.split(" (").next().unwrap()).collect();
    assert_eq!(
        names,
        ["ran near", "ran far", "skipped near", "ran far"],
        "{seen:#?}"
    );
}

#[test]
fn a_longer_training_run_resumes_from_its_checkpoint() {
    let dir = temp("train");
    let (file, out) = (dir.join("scene.sdfl"), dir.join("out"));
    let train = |iterations: usize| {
        format!(
            "let target = sdf_volume(sphere(1), color: [0.2, 0.6, 0.9])\n\
             let sampler = stratified(samples: 8, near: 0, far: 6)\n\
             train fit {{\n\
               model: sdf_volume(sphere(1, center: param([0.3, 0.2, 0])), color: param([0.3, 0.1, 0.1])),\n\
               data: render_views(target, cameras: [look_at(eye: [0, 0, -3])], size: [16, 16], sampler: sampler),\n\
               sampler: sampler, rays: 64, optimizer: adam(lr: 1e-2), iterations: {iterations},\n\
               checkpoint: \"fit.ckpt\",\n\
             }}\n"
        )
    };
    std::fs::write(&file, train(10)).unwrap();
    let (ok, lines, err) = watch_once(&file, &out);
    assert!(ok, "{err}");
    assert_eq!(lines, ["ran fit"]);
    let (_, lines, _) = watch_once(&file, &out);
    assert_eq!(lines, ["skipped fit"]);
    // More steps: the statement runs again, from the kept checkpoint.
    std::fs::write(&file, train(20)).unwrap();
    let (ok, lines, err) = watch_once(&file, &out);
    assert!(ok, "{err}");
    assert_eq!(lines, ["ran fit"]);
    assert!(err.contains("resumed at 10"), "{err}");
}

#[test]
fn a_changed_data_file_runs_its_training_again() {
    let dir = temp("data");
    let (file, out) = (dir.join("scene.sdfl"), dir.join("out"));
    let view = |g: u8| {
        image::RgbImage::from_pixel(16, 16, image::Rgb([20, g, 200]))
            .save(dir.join("view.png"))
            .unwrap()
    };
    view(100);
    std::fs::write(
        &file,
        "let sampler = stratified(samples: 8, near: 0, far: 6)\n\
         train fit {\n\
           model: sdf_volume(sphere(1, center: param([0.3, 0.2, 0])), color: param([0.3, 0.1, 0.1])),\n\
           data: views([\"view.png\"], cameras: [look_at(eye: [0, 0, -3])]),\n\
           sampler: sampler, rays: 64, optimizer: adam(lr: 1e-2), iterations: 5,\n\
         }\n",
    )
    .unwrap();
    let (ok, lines, err) = watch_once(&file, &out);
    assert!(ok, "{err}");
    assert_eq!(lines, ["ran fit"]);
    let (_, lines, _) = watch_once(&file, &out);
    assert_eq!(lines, ["skipped fit"]);
    // The same size, other pixels: the scene file is unchanged, its input is not.
    view(101);
    let (ok, lines, err) = watch_once(&file, &out);
    assert!(ok, "{err}");
    assert_eq!(lines, ["ran fit"]);
}

/// The fingerprint store in `--out` replaced by a FIFO or a link to
/// `/dev/zero`: watch read it with `fs::read`, so it blocked or read
/// without end. Now it is ignored (everything runs) and replaced.
#[cfg(unix)]
#[test]
fn a_special_fingerprint_store_is_ignored_not_read() {
    use std::time::Instant;
    let dir = temp("special_store");
    let (file, out) = (dir.join("scene.sdfl"), dir.join("out"));
    std::fs::write(&file, scene(5.0)).unwrap();
    std::fs::create_dir_all(&out).unwrap();
    let store = out.join(".sdfl-watch.json");
    let fifo = Command::new("mkfifo")
        .arg(&store)
        .status()
        .is_ok_and(|s| s.success());
    for special in ["fifo", "zero"] {
        if special == "fifo" && !fifo {
            continue;
        }
        if special == "zero" {
            let _ = std::fs::remove_file(&store);
            std::os::unix::fs::symlink("/dev/zero", &store).unwrap();
        }
        let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
            .args(["watch", file.to_str().unwrap(), "--out"])
            .arg(&out)
            .args(["--max-runs", "1"])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let t0 = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            if t0.elapsed() > crate::common::HANG_GUARD {
                let _ = child.kill();
                let _ = child.wait();
                panic!("{special}: watch hung on its store");
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        assert!(status.success(), "{special}: {status}");
        assert!(out.join("near.png").is_file());
        // Replaced by a store sdfl wrote: the next watch skips both.
        let (ok, lines, err) = watch_once(&file, &out);
        assert!(ok, "{err}");
        assert_eq!(lines, ["skipped near", "skipped far"], "{special}");
    }
}
