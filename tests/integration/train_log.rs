//! What a training run says as it goes, through the built binary: progress
//! lines on a piped stderr, the metrics CSV and TensorBoard events (valid
//! TFRecord framing and Event protobufs, read here independently of the
//! writer), a run killed with SIGKILL and resumed logging the same steps
//! as one never stopped (one stopped by SIGTERM at an evaluation step
//! too), and the `--json` reports (schema version,
//! checkpoint, diagnostics on failure, `check --json`).
#![cfg(unix)]

use crate::common::*;

use std::fs;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Instant;

use serde_json::Value;

/// A small fit scored on one held-out view every 10 steps.
fn training(iterations: u64) -> String {
    training_scored_every(iterations, 10)
}

/// A small fit scored on one held-out view every `eval_every` steps.
fn training_scored_every(iterations: u64, eval_every: u64) -> String {
    format!(
        "let cameras = [look_at(eye: [0, 0, -3]), look_at(eye: [3, 0, 0]), look_at(eye: [-3, 0, 0]), look_at(eye: [0, 0, 3])]
let sampler = stratified(samples: 16, near: 0, far: 6)
let target = sdf_volume(sphere(1, center: [-0.2, 0.1, 0.15]), color: [0.2, 0.6, 0.9])
train t {{
  model: sdf_volume(sphere(1, center: param([0.3, 0.2, 0])), color: param([0.3, 0.1, 0.1])),
  data: render_views(target, cameras: cameras, size: [16, 16], sampler: sampler, test_views: 1),
  sampler: sampler,
  rays: 64,
  optimizer: adam(lr: 1e-2, decay: 0.5, decay_every: 20, schedule: \"exponential\"),
  iterations: {iterations},
  eval_every: {eval_every},
  size: [16, 16],
  checkpoint: \"t.ckpt\",
}}
"
    )
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    fs::write(&p, text).unwrap();
    p
}

/// `sdfl ARGS` in `dir` with `env`, stdout and stderr captured (stderr is
/// a pipe, not a terminal).
fn sdfl_env(dir: &Path, args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_sdfl"));
    cmd.args(args).current_dir(dir).stdin(Stdio::null());
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("the sdfl binary runs")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// The CSV's rows as fields, after checking its header.
fn csv_rows(path: &Path) -> Vec<Vec<String>> {
    let t = fs::read_to_string(path).unwrap();
    let mut lines = t.lines();
    assert_eq!(lines.next(), Some("step,seconds,loss,lr,psnr,ssim"));
    lines
        .map(|l| l.split(',').map(str::to_string).collect::<Vec<_>>())
        .inspect(|r| assert_eq!(r.len(), 6, "{r:?}"))
        .collect()
}

// ---------------------------------------------------------- TensorBoard

/// CRC-32C bit by bit (reflected polynomial 0x82F63B78): independent of
/// the table-driven crate the writer uses.
fn crc32c(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0x82f6_3b78
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

fn masked(bytes: &[u8]) -> u32 {
    let c = crc32c(bytes);
    c.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// Every record of a TFRecord file, asserting whole records and checksums.
fn tfrecords(bytes: &[u8]) -> Vec<&[u8]> {
    let mut out = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        let len = &bytes[at..at + 8];
        let n = u64::from_le_bytes(len.try_into().unwrap()) as usize;
        assert_eq!(
            bytes[at + 8..at + 12],
            masked(len).to_le_bytes(),
            "length CRC at {at}"
        );
        let data = &bytes[at + 12..at + 12 + n];
        let crc = &bytes[at + 12 + n..at + 16 + n];
        assert_eq!(crc, masked(data).to_le_bytes(), "data CRC at {at}");
        out.push(data);
        at += 16 + n;
    }
    out
}

fn varint(b: &[u8], at: &mut usize) -> u64 {
    let mut v = 0;
    for shift in (0..64).step_by(7) {
        let x = b[*at];
        *at += 1;
        v |= ((x & 0x7f) as u64) << shift;
        if x < 0x80 {
            break;
        }
    }
    v
}

/// A protobuf message's fields: (number, wire type, payload bytes).
fn pb_fields(b: &[u8]) -> Vec<(u64, u64, &[u8])> {
    let mut out = Vec::new();
    let mut at = 0;
    while at < b.len() {
        let key = varint(b, &mut at);
        let start = at;
        let payload = match key & 7 {
            0 => {
                varint(b, &mut at);
                &b[start..at]
            }
            1 => {
                at += 8;
                &b[start..at]
            }
            2 => {
                let n = varint(b, &mut at) as usize;
                at += n;
                &b[at - n..at]
            }
            5 => {
                at += 4;
                &b[start..at]
            }
            w => panic!("wire type {w}"),
        };
        out.push((key >> 3, key & 7, payload));
    }
    out
}

/// (step, tag, value) of every scalar in an event file, after its
/// `file_version` event; checks each Event's fields against event.proto.
fn scalars(path: &Path) -> Vec<(u64, String, f32)> {
    let bytes = fs::read(path).unwrap();
    let records = tfrecords(&bytes);
    let first = pb_fields(records[0]);
    assert!(
        first
            .iter()
            .any(|f| f.0 == 3 && f.1 == 2 && f.2 == b"brain.Event:2"),
        "{first:?}"
    );
    let mut out = Vec::new();
    for r in &records[1..] {
        let f = pb_fields(r);
        assert!(
            f.iter().any(|x| x.0 == 1 && x.1 == 1),
            "wall_time, a double"
        );
        let step = f.iter().find(|x| x.0 == 2 && x.1 == 0).expect("a step");
        let step = varint(step.2, &mut 0);
        let summary = f.iter().find(|x| x.0 == 5 && x.1 == 2).expect("a summary");
        for value in pb_fields(summary.2) {
            assert_eq!((value.0, value.1), (1, 2), "Summary.value");
            let v = pb_fields(value.2);
            let tag = v.iter().find(|x| x.0 == 1 && x.1 == 2).expect("a tag");
            let simple = v
                .iter()
                .find(|x| x.0 == 2 && x.1 == 5)
                .expect("simple_value");
            out.push((
                step,
                text(tag.2),
                f32::from_le_bytes(simple.2.try_into().unwrap()),
            ));
        }
    }
    out
}

// ---------------------------------------------------------- tests

#[test]
fn a_piped_run_shows_progress_lines_and_writes_its_logs() {
    let dir = case_dir("log_progress");
    let file = write(&dir, "t.sdfl", &training(30));
    let o = sdfl_env(
        &dir,
        &["run", file.to_str().unwrap(), "--out", "out", "--json"],
        &[("SDFL_PROGRESS_SECS", "0")],
    );
    let stderr = text(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    // A line at every step (interval 0), with the last held-out score.
    for step in [1, 15, 30] {
        assert!(
            stderr.contains(&format!("t: step {step}/30, loss ")),
            "{stderr}"
        );
    }
    let line = stderr
        .lines()
        .find(|l| l.starts_with("t: step 25/30"))
        .unwrap();
    assert!(
        line.contains("held-out PSNR")
            && line.contains("(step 20)")
            && line.contains("steps/s")
            && line.contains("ETA"),
        "{line}"
    );
    // At the default interval (seconds), a run this short prints none.
    let o = sdfl_env(
        &dir,
        &["run", file.to_str().unwrap(), "--out", "again", "--json"],
        &[],
    );
    assert!(o.status.success());
    assert!(!text(&o.stderr).contains("t: step"), "{}", text(&o.stderr));

    let json: Value = serde_json::from_slice(&o.stdout).unwrap();
    let report = &json["jobs"][0]["report"];
    let rows = csv_rows(&dir.join("out/t.metrics.csv"));
    let steps: Vec<usize> = rows.iter().map(|r| r[0].parse().unwrap()).collect();
    assert_eq!(steps, (1..=30).collect::<Vec<_>>());
    // The rate of step k is the schedule's after k − 1 steps: 1e-2 · 0.5^((k − 1)/20).
    for r in &rows {
        let k: f64 = r[0].parse().unwrap();
        let lr: f64 = r[3].parse().unwrap();
        assert!(
            (lr - 1e-2 * 0.5f64.powf((k - 1.0) / 20.0)).abs() < 1e-12,
            "{r:?}"
        );
        let (loss, secs): (f32, f64) = (r[2].parse().unwrap(), r[1].parse().unwrap());
        assert!(loss >= 0.0 && secs >= 0.0, "{r:?}");
        // Scores exactly on the evaluated steps.
        assert_eq!(r[4].is_empty(), !(k as usize).is_multiple_of(10), "{r:?}");
    }
    let scored: Vec<(usize, f64)> = rows
        .iter()
        .filter(|r| !r[4].is_empty())
        .map(|r| (r[0].parse().unwrap(), r[4].parse().unwrap()))
        .collect();
    let held_out: Vec<(usize, f64)> = report["held_out"]
        .as_array()
        .unwrap()
        .iter()
        .map(|h| {
            (
                h["step"].as_u64().unwrap() as usize,
                h["psnr"].as_f64().unwrap(),
            )
        })
        .collect();
    assert_eq!(scored, held_out);
    // The held-out image: prediction beside truth, each 16 × 16.
    let png = image::open(dir.join("out/t.heldout.png")).unwrap();
    assert_eq!((png.width(), png.height()), (32, 16));
    // TensorBoard: loss and rate at every step, scores where evaluated.
    let events = scalars(&dir.join("out/tensorboard/t/events.out.tfevents.sdfl"));
    let loss_steps: Vec<u64> = events
        .iter()
        .filter(|e| e.1 == "train/loss")
        .map(|e| e.0)
        .collect();
    assert_eq!(loss_steps, (1..=30).collect::<Vec<_>>());
    let psnr: Vec<(u64, f32)> = events
        .iter()
        .filter(|e| e.1 == "held_out/psnr")
        .map(|e| (e.0, e.2))
        .collect();
    assert_eq!(
        psnr,
        held_out
            .iter()
            .map(|h| (h.0 as u64, h.1 as f32))
            .collect::<Vec<_>>()
    );
    let loss_20 = events
        .iter()
        .find(|e| e.1 == "train/loss" && e.0 == 20)
        .unwrap()
        .2;
    assert_eq!(loss_20, rows[19][2].parse::<f32>().unwrap());
}

/// The rows of a CSV without the seconds column (timing differs per run).
fn untimed(rows: &[Vec<String>]) -> Vec<Vec<String>> {
    rows.iter()
        .map(|r| {
            r.iter()
                .enumerate()
                .filter(|(i, _)| *i != 1)
                .map(|(_, s)| s.clone())
                .collect()
        })
        .collect()
}

fn held_out_scores(report: &Value) -> Vec<(u64, f64, f64)> {
    report["held_out"]
        .as_array()
        .unwrap()
        .iter()
        .map(|h| {
            (
                h["step"].as_u64().unwrap(),
                h["psnr"].as_f64().unwrap(),
                h["ssim"].as_f64().unwrap(),
            )
        })
        .collect()
}

#[test]
fn a_run_killed_and_resumed_logs_what_an_unstopped_run_logs() {
    let dir = case_dir("log_kill9");
    let file = write(&dir, "t.sdfl", &training(10_000_000));
    let out = dir.join("killed");
    let ckpt = out.join("t.ckpt");
    let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args([
            "run",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // The first checkpoint is written at the start; a new inode is one
    // that training wrote (at a step that is a multiple of 100).
    let t0 = Instant::now();
    let wait = |ready: &dyn Fn() -> bool| {
        while !ready() {
            assert!(t0.elapsed() < TIME_LIMIT, "no checkpoint");
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
    };
    wait(&|| ckpt.exists());
    let first = fs::metadata(&ckpt).map(|m| m.ino()).unwrap_or(0);
    wait(&|| fs::metadata(&ckpt).is_ok_and(|m| m.ino() != first));
    // A few more steps logged past it (rows the resume must drop; their
    // truncation is also unit-tested in `train::log`), then SIGKILL.
    std::thread::sleep(std::time::Duration::from_millis(30));
    child.kill().unwrap();
    child.wait().unwrap();
    let at = sdfl_runtime::train::checkpoint::Checkpoint::read(&ckpt)
        .unwrap()
        .step as u64;
    assert!(at >= 100 && at.is_multiple_of(100), "{at}");
    let rows_before = fs::read_to_string(out.join("t.metrics.csv"))
        .unwrap()
        .lines()
        .count();

    // Resumed to 25 steps past the checkpoint, against a run never stopped.
    let n = at + 25;
    let file = write(&dir, "t.sdfl", &training(n));
    let run = |out: &str| {
        let o = sdfl_env(
            &dir,
            &["run", file.to_str().unwrap(), "--out", out, "--json"],
            &[],
        );
        assert!(o.status.success(), "{}", text(&o.stderr));
        let v: Value = serde_json::from_slice(&o.stdout).unwrap();
        v["jobs"][0]["report"].clone()
    };
    let resumed = run("killed");
    assert_eq!(resumed["resumed_from"].as_u64(), Some(at));
    let whole = run("whole");
    assert_eq!(whole["resumed_from"], Value::Null);
    let (a, b) = (
        csv_rows(&dir.join("killed/t.metrics.csv")),
        csv_rows(&dir.join("whole/t.metrics.csv")),
    );
    assert_eq!(
        a.len() as u64,
        n,
        "killed with {rows_before} rows at step {at}"
    );
    assert_eq!(untimed(&a), untimed(&b));
    // Training time runs on across the resume.
    let secs: Vec<f64> = a.iter().map(|r| r[1].parse().unwrap()).collect();
    assert!(secs.windows(2).all(|w| w[0] <= w[1]), "{secs:?}");
    // The whole curve, scored before and after the kill.
    let scores = held_out_scores(&resumed);
    assert_eq!(
        scores.len() as u64,
        n / 10 + u64::from(!n.is_multiple_of(10))
    );
    assert_eq!(scores, held_out_scores(&whole));
    // TensorBoard: each step once, the same values.
    let tb = |d: &str| scalars(&dir.join(d).join("tensorboard/t/events.out.tfevents.sdfl"));
    let strip = |v: Vec<(u64, String, f32)>| -> Vec<(u64, String, u32)> {
        v.into_iter().map(|(s, t, x)| (s, t, x.to_bits())).collect()
    };
    assert_eq!(strip(tb("killed")), strip(tb("whole")));
}

#[test]
fn a_run_stopped_by_a_signal_at_an_evaluation_step_resumes_to_the_same_log() {
    // Scored at every step, so the signal lands on an evaluation step
    // whenever it comes: the stop (checked before that step's evaluation,
    // to stay prompt) leaves the evaluation to the resumed run.
    let dir = case_dir("log_sigterm_at_evaluation");
    let file = write(&dir, "t.sdfl", &training_scored_every(10_000_000, 1));
    let out = dir.join("stopped");
    let stderr_path = dir.join("stderr.txt");
    let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(["run", file.to_str().unwrap(), "--out"])
        .arg(&out)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(fs::File::create(&stderr_path).unwrap())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    let rows = || fs::read_to_string(out.join("t.metrics.csv")).map_or(0, |t| t.lines().count());
    while rows() < 20 {
        assert!(t0.elapsed() < TIME_LIMIT, "no steps logged");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    // SAFETY: kill(2) on a child we started and have not yet reaped.
    assert_eq!(
        unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) },
        0
    );
    assert_eq!(child.wait().unwrap().code(), Some(143));
    let stderr = fs::read_to_string(&stderr_path).unwrap();
    let at = sdfl_runtime::train::checkpoint::Checkpoint::read(&out.join("t.ckpt"))
        .unwrap()
        .step as u64;
    assert!(
        at >= 20 && stderr.contains(&format!("at step {at} ")),
        "step {at}: {stderr}"
    );

    // Resumed to 3 steps past the stop, against a run never stopped.
    let n = at + 3;
    let file = write(&dir, "t.sdfl", &training_scored_every(n, 1));
    let run = |out: &str| {
        let o = sdfl_env(
            &dir,
            &["run", file.to_str().unwrap(), "--out", out, "--json"],
            &[],
        );
        assert!(o.status.success(), "{}", text(&o.stderr));
        let v: Value = serde_json::from_slice(&o.stdout).unwrap();
        v["jobs"][0]["report"].clone()
    };
    let resumed = run("stopped");
    assert_eq!(resumed["resumed_from"].as_u64(), Some(at));
    let whole = run("whole");
    let (a, b) = (
        csv_rows(&dir.join("stopped/t.metrics.csv")),
        csv_rows(&dir.join("whole/t.metrics.csv")),
    );
    assert_eq!(a.len() as u64, n);
    // The stop's own step is scored, as every other one.
    let row = &a[at as usize - 1];
    assert!(!row[4].is_empty() && !row[5].is_empty(), "{row:?}");
    assert_eq!(untimed(&a), untimed(&b));
    let scores = held_out_scores(&resumed);
    assert_eq!(scores.len() as u64, n);
    assert_eq!(scores, held_out_scores(&whole));
    let tb = |d: &str| -> Vec<(u64, String, u32)> {
        scalars(&dir.join(d).join("tensorboard/t/events.out.tfevents.sdfl"))
            .into_iter()
            .map(|(s, t, x)| (s, t, x.to_bits()))
            .collect()
    };
    assert_eq!(tb("stopped"), tb("whole"));
    assert_eq!(
        fs::read(dir.join("stopped/t.heldout.png")).unwrap(),
        fs::read(dir.join("whole/t.heldout.png")).unwrap()
    );
}

#[test]
fn json_reports_carry_a_version_the_checkpoint_and_diagnostics() {
    let dir = case_dir("log_json");
    let good = write(&dir, "t.sdfl", &training(5));
    let o = sdfl_env(&dir, &["run", "t.sdfl", "--out", "out", "--json"], &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (v["schema_version"].as_u64(), v["ok"].as_bool()),
        (Some(1), Some(true))
    );
    let report = &v["jobs"][0]["report"];
    assert_eq!(report["checkpoint"], "t.ckpt");
    assert_eq!(report["logs"]["metrics_csv"], "t.metrics.csv");
    assert_eq!(report["logs"]["tensorboard"], "tensorboard/t");
    assert!(dir
        .join("out")
        .join(report["checkpoint"].as_str().unwrap())
        .exists());

    // A file with errors: every diagnostic, located, as JSON on stdout.
    let bad = write(
        &dir,
        "bad.sdfl",
        "let a = sphere(radius: -1)\nlet b = nope(1)\n",
    );
    let o = sdfl_env(&dir, &["run", "bad.sdfl", "--out", "out", "--json"], &[]);
    assert_eq!(o.status.code(), Some(1));
    let v: Value = serde_json::from_slice(&o.stdout).expect("JSON on failure");
    assert_eq!(
        (v["schema_version"].as_u64(), v["ok"].as_bool()),
        (Some(1), Some(false))
    );
    let diags = v["diagnostics"].as_array().unwrap();
    assert!(!diags.is_empty());
    let unknown = diags
        .iter()
        .find(|d| d["code"] == "sdfl::name::unknown-function")
        .unwrap_or_else(|| panic!("{v:#}"));
    assert_eq!(
        (unknown["line"].as_u64(), unknown["column"].as_u64()),
        (Some(2), Some(9))
    );
    assert_eq!(unknown["span"]["start"].as_u64(), Some(35));
    for key in ["message", "label", "help", "file", "severity"] {
        assert!(unknown[key].is_string(), "{key}: {unknown:#}");
    }
    // A failure with no place in the file: an output directory that is a file.
    fs::write(dir.join("taken"), "x").unwrap();
    let o = sdfl_env(&dir, &["run", "t.sdfl", "--out", "taken", "--json"], &[]);
    assert_eq!(o.status.code(), Some(1));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    let d = &v["diagnostics"][0];
    assert_eq!(d["code"], "sdfl::io");
    assert!(
        d["span"].is_null() && d["message"].as_str().unwrap().contains("taken"),
        "{d}"
    );

    // `check --json`: one entry per file, the same diagnostic objects.
    let warns = write(
        &dir,
        "warns.sdfl",
        "render r {\n  scene: sphere(),\n  camera: look_at(eye: [0, 0, -8]),\n  outputs: [image(\"r.png\")],\n}\n",
    );
    // Named as the run above named them, so the objects are the same.
    assert!(good.exists() && bad.exists() && warns.exists());
    let args = [
        "check",
        "--json",
        "t.sdfl",
        "bad.sdfl",
        "warns.sdfl",
        "missing.sdfl",
    ];
    let o = sdfl_env(&dir, &args, &[]);
    assert_eq!(o.status.code(), Some(1));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (v["schema_version"].as_u64(), v["ok"].as_bool()),
        (Some(1), Some(false))
    );
    let files = v["files"].as_array().unwrap();
    let ok: Vec<bool> = files.iter().map(|f| f["ok"].as_bool().unwrap()).collect();
    assert_eq!(ok, [true, false, true, false]);
    assert_eq!(
        files[1]["diagnostics"].as_array().unwrap().len(),
        diags.len()
    );
    assert_eq!(files[1]["diagnostics"][0], diags[0]);
    assert_eq!(files[2]["diagnostics"][0]["severity"], "warning", "{v:#}");
    assert_eq!(files[3]["diagnostics"][0]["code"], "sdfl::io");
    let o = sdfl_env(&dir, &["check", "--json", "t.sdfl"], &[]);
    assert!(o.status.success());
}

/// Where, in an event file's bytes, the record of `tag` at `step` starts.
fn record_offset(bytes: &[u8], step: u64, tag: &str) -> usize {
    let mut at = 0;
    while at < bytes.len() {
        let n = u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap()) as usize;
        let data = &bytes[at + 12..at + 12 + n];
        let f = pb_fields(data);
        let s = f
            .iter()
            .find(|x| x.0 == 2 && x.1 == 0)
            .map(|x| varint(x.2, &mut 0));
        let holds = f
            .iter()
            .find(|x| x.0 == 5)
            .is_some_and(|x| x.2.windows(tag.len()).any(|w| w == tag.as_bytes()));
        if s == Some(step) && holds {
            return at;
        }
        at += 16 + n;
    }
    panic!("no {tag} at step {step}");
}

#[test]
fn logs_cut_mid_record_are_whole_again_after_a_resume() {
    // Both logs cut in the middle of step 25's record (a disk that filled,
    // a copy cut short) while the checkpoint holds step 60: the resume
    // kept steps 1 to 24 and went on from 60, a gap in both curves. The
    // checkpoint holds every loss and held-out score: steps 25 to 59 are
    // written again from it, once each.
    let dir = case_dir("log_cut");
    let file = write(&dir, "t.sdfl", &training(60));
    let run = |out: &str| {
        let o = sdfl_env(
            &dir,
            &["run", file.to_str().unwrap(), "--out", out, "--json"],
            &[],
        );
        assert!(o.status.success(), "{}", text(&o.stderr));
        let v: Value = serde_json::from_slice(&o.stdout).unwrap();
        (v["jobs"][0]["report"].clone(), text(&o.stderr))
    };
    run("cut");
    let csv = dir.join("cut/t.metrics.csv");
    let t = fs::read_to_string(&csv).unwrap();
    let row25 = t.find("\n25,").unwrap() + 1;
    fs::write(&csv, &t[..row25 + 6]).unwrap();
    let events = dir.join("cut/tensorboard/t/events.out.tfevents.sdfl");
    let bytes = fs::read(&events).unwrap();
    let at = record_offset(&bytes, 25, "train/loss");
    fs::write(&events, &bytes[..at + 20]).unwrap();

    write(&dir, "t.sdfl", &training(80));
    let (resumed, stderr) = run("cut");
    assert_eq!(resumed["resumed_from"].as_u64(), Some(60));
    let (whole, _) = run("whole");
    let (a, b) = (
        csv_rows(&dir.join("cut/t.metrics.csv")),
        csv_rows(&dir.join("whole/t.metrics.csv")),
    );
    let steps: Vec<usize> = a.iter().map(|r| r[0].parse().unwrap()).collect();
    assert_eq!(steps, (1..=80).collect::<Vec<_>>());
    assert_eq!(untimed(&a), untimed(&b));
    assert!(
        stderr.contains("steps 25 to 59") && stderr.contains("t.metrics.csv"),
        "says what it wrote again: {stderr}"
    );
    // Seconds are kept where the checkpoint knows them (its step, each
    // evaluation) and left empty where it does not.
    for r in &a {
        let k: usize = r[0].parse().unwrap();
        let rebuilt = (25..60).contains(&k) && !k.is_multiple_of(10);
        assert_eq!(r[1].is_empty(), rebuilt, "{r:?}");
    }
    assert_eq!(held_out_scores(&resumed), held_out_scores(&whole));
    let tb = |d: &str| -> Vec<(u64, String, u32)> {
        scalars(&dir.join(d).join("tensorboard/t/events.out.tfevents.sdfl"))
            .into_iter()
            .map(|(s, t, x)| (s, t, x.to_bits()))
            .collect()
    };
    assert_eq!(tb("cut"), tb("whole"));
}

/// The peak resident memory of `child` in KiB once it ends, and its status.
fn wait_with_peak(child: std::process::Child) -> (i32, u64) {
    let mut status = 0;
    // SAFETY: wait4(2) on a child we started and have not reaped; the
    // rusage it fills is plain data.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = child.id() as libc::pid_t;
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    assert_eq!(r, pid);
    (status, usage.ru_maxrss as u64)
}

#[test]
fn huge_logs_in_out_are_streamed_not_read_whole() {
    // A 2 GB metrics CSV and event file (sparse: no disk used) were read
    // whole into memory when training opened its logs.
    let dir = case_dir("log_huge");
    let file = write(&dir, "t.sdfl", &training(5));
    let out = dir.join("out");
    fs::create_dir_all(out.join("tensorboard/t")).unwrap();
    for p in ["t.metrics.csv", "tensorboard/t/events.out.tfevents.sdfl"] {
        fs::File::create(out.join(p))
            .unwrap()
            .set_len(2_000_000_000)
            .unwrap();
    }
    let t0 = Instant::now();
    let child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(["run", file.to_str().unwrap(), "--out"])
        .arg(&out)
        .current_dir(&dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(fs::File::create(dir.join("stderr.txt")).unwrap())
        .spawn()
        .unwrap();
    let (status, peak_kib) = wait_with_peak(child);
    let stderr = fs::read_to_string(dir.join("stderr.txt")).unwrap();
    assert_eq!(status, 0, "{stderr}");
    assert!(t0.elapsed() < HANG_GUARD);
    assert!(peak_kib < 512 << 10, "peak {peak_kib} KiB: {stderr}");
    let rows = csv_rows(&out.join("t.metrics.csv"));
    assert_eq!(rows.len(), 5);
    assert_eq!(
        scalars(&out.join("tensorboard/t/events.out.tfevents.sdfl"))
            .iter()
            .filter(|e| e.1 == "train/loss")
            .count(),
        5
    );
}
