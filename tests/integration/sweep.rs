//! `sdfl sweep` that stops, resumes and spreads: a row per finished
//! setting, reruns that skip what is done (and redo what changed), shards
//! and `--collect`, and a sweep killed halfway. Every setting here is an
//! analytic volume render of a few pixels, not training.

use crate::common;
use sdfl_runtime::train::checkpoint::Checkpoint;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::common::run_sdfl as sdfl;

fn temp(name: &str) -> PathBuf {
    common::temp_dir("sweep", name)
}

fn ok(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    err
}

const SCENE: &str =
    "let samples = 8\nrender v { scene: sdf_volume(box(size: 1.5)), camera: look_at([0, 0, -3]),\n\
     sampler: stratified(samples: samples), outputs: [image(\"v.png\")], size: [12, 12] }\n";

/// A sweep's command line over `samples` into `out`, with `extra` flags.
fn sweep(scene: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "sweep",
        scene.to_str().unwrap(),
        "--set",
        "samples=4,8,16,32",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(extra);
    sdfl(&args)
}

/// The CSV without its seconds column (the one thing two runs differ in).
fn without_seconds(csv: &str) -> Vec<String> {
    csv.lines()
        .map(|l| {
            let mut cells: Vec<&str> = l.split(',').collect();
            cells.remove(1);
            cells.join(",")
        })
        .collect()
}

#[test]
fn reruns_skip_finished_settings_and_redo_edited_ones() {
    let tmp = temp("rerun");
    let scene = tmp.join("scene.sdfl");
    std::fs::write(&scene, SCENE).unwrap();
    let out = tmp.join("out");
    let first = ok(&sweep(&scene, &out, &[]));
    assert_eq!(first.matches(": done in").count(), 4, "{first}");
    let row = out.join("rows").join("samples=8.json");
    let before = std::fs::read(&row).unwrap();
    let csv = std::fs::read_to_string(out.join("sweep.csv")).unwrap();

    let again = ok(&sweep(&scene, &out, &[]));
    for v in [4, 8, 16, 32] {
        assert!(
            again.contains(&format!("samples={v}: skipped (done)")),
            "{again}"
        );
    }
    assert!(!again.contains("done in"), "{again}");
    assert_eq!(
        std::fs::read(&row).unwrap(),
        before,
        "a skipped row is not rewritten"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("sweep.csv")).unwrap(),
        csv,
        "the table is rebuilt from the same rows"
    );

    // A setting whose outputs were removed runs again; the others do not.
    std::fs::remove_file(out.join("samples=16").join("v.png")).unwrap();
    let partial = ok(&sweep(&scene, &out, &[]));
    assert!(
        partial.contains("samples=16: running again: its output samples=16/v.png is gone"),
        "{partial}"
    );
    assert_eq!(partial.matches("skipped (done)").count(), 3, "{partial}");

    // A comment changes nothing the file computes: still done.
    std::fs::write(&scene, format!("// the box, sampled\n{SCENE}")).unwrap();
    let commented = ok(&sweep(&scene, &out, &[]));
    assert_eq!(
        commented.matches("skipped (done)").count(),
        4,
        "{commented}"
    );

    // An edit to the file changes every setting's fingerprint: all rerun.
    std::fs::write(&scene, SCENE.replace("size: 1.5", "size: 1.2")).unwrap();
    let edited = ok(&sweep(&scene, &out, &[]));
    assert!(!edited.contains("skipped"), "{edited}");
    assert_eq!(
        edited
            .matches("running again: the file or the setting changed")
            .count(),
        4,
        "{edited}"
    );
    // So does another `--size`.
    let resized = ok(&sweep(&scene, &out, &["--size", "10x10"]));
    assert!(!resized.contains("skipped"), "{resized}");
}

#[test]
fn two_shards_and_a_collect_give_the_table_of_one_run() {
    let tmp = temp("shards");
    let scene = tmp.join("scene.sdfl");
    std::fs::write(&scene, SCENE).unwrap();
    let whole = tmp.join("whole");
    ok(&sweep(&scene, &whole, &[]));

    // Each shard on its own "machine" (folder), then copied together.
    let merged = tmp.join("merged");
    for i in 0..2 {
        let dir = tmp.join(format!("shard{i}"));
        let shard = format!("{i}/2");
        let err = ok(&sweep(&scene, &dir, &["--shard", &shard]));
        assert!(
            err.contains(&format!("shard {i}/2: 2 of its 2 settings run")),
            "{err}"
        );
        assert!(
            !dir.join("sweep.csv").exists(),
            "a shard writes rows, not the table"
        );
        // Round-robin: shard 0 has the 1st and 3rd settings.
        let mine = if i == 0 { ["4", "16"] } else { ["8", "32"] };
        for v in mine {
            assert!(dir.join("rows").join(format!("samples={v}.json")).is_file());
        }
        copy_tree(&dir, &merged);
    }
    // A collect before every shard's rows are in says which are missing.
    let early = sweep(&scene, &tmp.join("shard0"), &["--collect"]);
    assert_eq!(early.status.code(), Some(1));
    let err = String::from_utf8_lossy(&early.stderr);
    assert!(
        err.contains("samples=8: no row yet") && err.contains("samples=32: no row yet"),
        "{err}"
    );

    let collected = sweep(&scene, &merged, &["--collect"]);
    let err = ok(&collected);
    assert!(!err.contains("done in"), "collect runs nothing: {err}");
    let read = |d: &Path| std::fs::read_to_string(d.join("sweep.csv")).unwrap();
    assert_eq!(
        without_seconds(&read(&merged)),
        without_seconds(&read(&whole))
    );
    assert_eq!(read(&merged).lines().count(), 5);
    assert!(merged.join("sweep.png").is_file() && merged.join("sweep_value.png").is_file());
    // The table printed is the one written.
    assert_eq!(
        String::from_utf8_lossy(&collected.stdout),
        std::fs::read_to_string(merged.join("sweep.md")).unwrap()
    );
    // `--shard` is checked: 0-based, below the count.
    let bad = sweep(&scene, &merged, &["--shard", "2/2"]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("below the count"));
}

fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dest = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &dest);
        } else {
            std::fs::copy(e.path(), dest).unwrap();
        }
    }
}

/// A sweep stopped by SIGTERM after its first setting finished resumes
/// without redoing it.
#[cfg(unix)]
#[test]
fn a_sweep_killed_halfway_resumes_without_redoing_finished_settings() {
    let tmp = temp("killed");
    let scene = tmp.join("scene.sdfl");
    // The first setting is tiny; the next ones take seconds, so the stop
    // lands inside the second.
    std::fs::write(
        &scene,
        "let n = 8\nrender v { scene: sdf_volume(box(size: 1.5)), camera: look_at([0, 0, -3]),\n\
         sampler: stratified(samples: 256), outputs: [image(\"v.png\")], size: [n, n] }\n",
    )
    .unwrap();
    let out = tmp.join("out");
    let args = |out: &Path| {
        vec![
            "sweep".to_string(),
            scene.display().to_string(),
            "--set".into(),
            "n=8,700,24".into(),
            "--out".into(),
            out.display().to_string(),
        ]
    };
    let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(args(&out))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let first = out.join("rows").join("n=8.json");
    let t = Instant::now();
    while !first.exists() {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "the first setting never finished"
        );
        assert!(
            child.try_wait().unwrap().is_none(),
            "the sweep ended before its first row"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    // SAFETY: signalling our own child by its id.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    let stopped = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&stopped.stderr);
    assert_eq!(stopped.status.code(), Some(143), "{err}");
    assert!(
        !out.join("rows").join("n=700.json").exists(),
        "the stop landed after the second setting: {err}"
    );
    let kept = std::fs::read(&first).unwrap();

    let resumed = sdfl(&args(&out).iter().map(String::as_str).collect::<Vec<_>>());
    let err = ok(&resumed);
    assert!(err.contains("n=8: skipped (done)"), "{err}");
    assert!(
        err.contains("n=700: done in") && err.contains("n=24: done in"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(&first).unwrap(),
        kept,
        "the finished setting was not redone"
    );
    let csv = std::fs::read_to_string(out.join("sweep.csv")).unwrap();
    assert_eq!(csv.lines().count(), 4, "{csv}");
    // No half-written file is left behind.
    let mut stack = vec![out.clone()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(d).unwrap() {
            let p = e.unwrap().path();
            assert!(!p.to_string_lossy().ends_with(".tmp"), "{}", p.display());
            if p.is_dir() {
                stack.push(p);
            }
        }
    }
}

/// The `sdfl sweep` command lines of a cluster example, in file order
/// (the text from `sdfl sweep` to the end of its line or quote).
fn sweep_commands(text: &str) -> Vec<Vec<String>> {
    text.lines()
        .filter_map(|l| l.find("sdfl sweep").map(|at| &l[at..]))
        .map(|c| {
            c.split('"')
                .next()
                .unwrap()
                .split_whitespace()
                .map(str::to_string)
                .collect()
        })
        .collect()
}

/// The value of flag `--name` in a command line.
fn flag<'a>(command: &'a [String], name: &str) -> &'a str {
    let at = command
        .iter()
        .position(|a| a == name)
        .unwrap_or_else(|| panic!("{name} in {command:?}"));
    &command[at + 1]
}

/// Runs a cluster example's shard command for every index the scheduler
/// gives (with `--dry-run`: nothing runs) and its collect command, from the
/// repository's root as the examples say: every flag is one sdfl knows,
/// the file loads with every setting, and the shards cover each setting
/// exactly once.
fn check_cluster_example(file: &str, index_var: &str, tasks: usize) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("examples/cluster").join(file)).unwrap();
    let commands = sweep_commands(&text);
    let shard: Vec<&Vec<String>> = commands
        .iter()
        .filter(|c| c.contains(&"--shard".to_string()))
        .collect();
    let collect: Vec<&Vec<String>> = commands
        .iter()
        .filter(|c| c.contains(&"--collect".to_string()))
        .collect();
    assert_eq!(shard.len(), 1, "{file}: one shard command: {commands:?}");
    let shard = shard[0];
    assert_eq!(
        flag(shard, "--shard"),
        format!("${index_var}/{tasks}"),
        "{file}"
    );
    let dry = |args: &[String]| {
        let out = Command::new(env!("CARGO_BIN_EXE_sdfl"))
            .current_dir(root)
            .args(&args[1..])
            .arg("--dry-run")
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{file}: {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .map(|l| l.split(':').next().unwrap().to_string())
            .collect::<Vec<String>>()
    };
    let set = flag(shard, "--set");
    let (name, values) = set.split_once('=').unwrap();
    let mut covered: Vec<String> = Vec::new();
    for i in 0..tasks {
        let with_index: Vec<String> = shard
            .iter()
            .map(|a| a.replace(&format!("${index_var}"), &i.to_string()))
            .collect();
        covered.extend(dry(&with_index));
    }
    let all: Vec<String> = values.split(',').map(|v| format!("{name}={v}")).collect();
    covered.sort();
    let mut want = all.clone();
    want.sort();
    assert_eq!(covered, want, "{file}: the shards cover every setting once");
    // The collect step: the same file, settings and folder.
    // (Kubernetes keeps it in its own Job file.)
    if let Some(collect) = collect.first() {
        for f in ["--set", "--out"] {
            assert_eq!(flag(collect, f), flag(shard, f), "{file}: {f}");
        }
        assert_eq!(collect[2], shard[2], "{file}: the same scene file");
        assert_eq!(dry(collect), all, "{file}");
    }
}

#[test]
fn the_cluster_examples_name_real_flags_and_cover_every_setting() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/cluster");
    let slurm = std::fs::read_to_string(root.join("sweep.slurm")).unwrap();
    assert!(slurm.lines().any(|l| l == "#SBATCH --array=0-3"), "{slurm}");
    assert!(slurm.contains("--collect"), "the collect step is shown");
    check_cluster_example("sweep.slurm", "SLURM_ARRAY_TASK_ID", 4);

    let job = std::fs::read_to_string(root.join("sweep-job.yaml")).unwrap();
    for key in [
        "completionMode: Indexed",
        "completions: 4",
        "parallelism: 4",
    ] {
        assert!(job.lines().any(|l| l.trim() == key), "{key}");
    }
    check_cluster_example("sweep-job.yaml", "JOB_COMPLETION_INDEX", 4);
    // Its collect Job: the same sweep, with `--collect`.
    let collect =
        sweep_commands(&std::fs::read_to_string(root.join("sweep-collect-job.yaml")).unwrap());
    let shard = &sweep_commands(&job)[0];
    assert_eq!(collect.len(), 1);
    let mut want = shard.clone();
    let at = want.iter().position(|a| a == "--shard").unwrap();
    want.splice(at..at + 2, ["--collect".to_string()]);
    assert_eq!(collect[0], want);
}

/// The fewer-views examples score every setting on the same held-out
/// views (the same camera poses), and train on fewer views as a subset of
/// more; a setting past the fixed camera set is refused.
#[test]
fn fewer_views_examples_hold_out_the_same_views_for_every_count() {
    use sdfl_stdlib::camera::Camera;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for (file, counts, held) in [
        ("fewer_views_nerf.sdfl", &[5, 10, 20][..], 4),
        ("fewer_views_volsdf.sdfl", &[5, 10, 20][..], 4),
        ("nerf_views.sdfl", &[5, 10, 20, 50, 90][..], 10),
    ] {
        let path = root.join("examples").join(file);
        let src = sdfl_lang::SourceFile::new(
            path.display().to_string(),
            std::fs::read_to_string(&path).unwrap(),
        );
        let split = |k: usize| -> Result<(Vec<Camera>, Vec<Camera>), String> {
            let program = sdfl_stdlib::load_with(&src, &[("train_views".to_string(), k as f64)])
                .map_err(|d| format!("{d:?}"))?;
            let data = &program.trains[0].data;
            let test = data.test_views();
            let (held, train): (Vec<_>, Vec<_>) = data
                .cameras()
                .iter()
                .enumerate()
                .partition(|(i, _)| test.contains(i));
            let cams = |v: Vec<(usize, &Camera)>| v.into_iter().map(|(_, c)| *c).collect();
            Ok((cams(held), cams(train)))
        };
        let (first_held, first_train) = split(counts[0]).unwrap();
        assert_eq!(first_held.len(), held, "{file}");
        let mut fewer = first_train;
        for &k in &counts[1..] {
            let (held_k, train_k) = split(k).unwrap();
            assert_eq!(
                held_k, first_held,
                "{file}: the held-out poses for {k} views"
            );
            assert_eq!(train_k.len(), k, "{file}");
            assert!(
                train_k.iter().all(|c| !held_k.contains(c)),
                "{file}: no test view is trained on"
            );
            assert!(
                fewer.iter().all(|c| train_k.contains(c)),
                "{file}: fewer views are a subset of {k}"
            );
            fewer = train_k;
        }
        let too_many = split(counts[counts.len() - 1] + 1).unwrap_err();
        assert!(too_many.contains("are not held out"), "{file}: {too_many}");
    }
}

/// A training setting stopped by SIGTERM resumes from its checkpoint when
/// the sweep is run again, and ends where an uninterrupted run ends.
#[cfg(unix)]
#[test]
fn an_interrupted_training_setting_resumes_from_its_checkpoint() {
    let tmp = temp("resume");
    let scene = tmp.join("fit.sdfl");
    std::fs::write(
        &scene,
        "let n = 2\nlet cams = orbit(views: 2)\n\
         train fit { model: sdf_volume(sphere(param(0.8))), data: render_views(sdf_volume(sphere()), cameras: cams, size: [8, 8]), rays: 64, iterations: n, checkpoint: \"fit.ckpt\" }\n",
    )
    .unwrap();
    let args = |out: &Path| {
        vec![
            "sweep".to_string(),
            scene.display().to_string(),
            "--set".into(),
            "n=2,12000".into(),
            "--out".into(),
            out.display().to_string(),
        ]
    };
    let run = |out: &Path| sdfl(&args(out).iter().map(String::as_str).collect::<Vec<_>>());
    let out = tmp.join("out");
    let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(args(&out))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Past the first setting and a checkpoint of the second after its
    // first step (they are written every 100 steps, atomically).
    let checkpoint = out.join("n=12000").join("fit.ckpt");
    let t = Instant::now();
    while !Checkpoint::read(&checkpoint).is_ok_and(|c| c.step > 0) {
        assert!(t.elapsed() < Duration::from_secs(60), "no checkpoint");
        assert!(
            child.try_wait().unwrap().is_none(),
            "the sweep ended before its checkpoint"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    // SAFETY: signalling our own child by its id.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    let stopped = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&stopped.stderr);
    assert_eq!(stopped.status.code(), Some(143), "{err}");
    assert!(!out.join("rows").join("n=12000.json").exists(), "{err}");

    let err = ok(&run(&out));
    assert!(err.contains("n=2: skipped (done)"), "{err}");
    assert!(
        err.contains("n=12000: resuming where an interrupted run stopped"),
        "{err}"
    );
    let row = |out: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(out.join("rows").join("n=12000.json")).unwrap())
            .unwrap()
    };
    let resumed = row(&out);
    let from = resumed["reports"][0]["resumed_from"].as_u64();
    assert!(from.is_some_and(|k| k > 0 && k < 12000), "{resumed}");
    assert!(!out.join("rows").join("n=12000.started.json").exists());
    // Bit-identical to a sweep that was never stopped.
    let whole = tmp.join("whole");
    ok(&run(&whole));
    assert_eq!(
        resumed["reports"][0]["params"],
        row(&whole)["reports"][0]["params"]
    );
}

/// A sweep of a tiny NeuS training (a hash-grid SDF from 8 × 8 images of a
/// sphere, a few steps) whose mesh is measured against the true surface:
/// the table has the Chamfer distance beside held-out PSNR, the row keeps
/// it as a number, and the plot has a panel for each measure.
#[test]
fn a_surface_training_sweep_tabulates_chamfer_to_the_truth() {
    let tmp = temp("chamfer");
    let scene = tmp.join("tiny_neus.sdfl");
    std::fs::write(
        &scene,
        r#"let steps = 4
let cams = orbit(radius: 3, up: [0, 1, 0], focal: 1.5, views: 8)
let grid = hashgrid(levels: 4, log2_table: 10, min_res: 4, max_res: 16, min: [-1.2, -1.2, -1.2], max: [1.2, 1.2, 1.2])
train fit {
  model: neus(neural_sdf(encoding: grid, network: mlp(layers: 1, width: 8, skips: []), radius: 0.5), beta: param(0.08), view_dependent: false, fine: 4),
  data: render_views(sphere(0.7), cameras: cams, size: [8, 8], material: lambert(albedo: [0.9, 0.5, 0.2]), test_views: 2, split_seed: 3, hit_tolerance: "absolute"),
  sampler: stratified(samples: 8, near: 1.8, far: 4.2, jitter: true),
  rays: 32,
  optimizer: adam(lr: 1e-2),
  iterations: steps,
  bounds: 1.2,
  views: look_at(eye: [0, 0, -3]),
  size: [8, 8],
  after: [mesh("fit.ply", resolution: 16)],
}
"#,
    )
    .unwrap();
    let out = tmp.join("out");
    let args = [
        "sweep",
        scene.to_str().unwrap(),
        "--set",
        "steps=2,4",
        "--out",
        out.to_str().unwrap(),
    ];
    ok(&sdfl(&args));
    let csv = std::fs::read_to_string(out.join("sweep.csv")).unwrap();
    let lines: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    assert_eq!(lines.len(), 3, "{csv}");
    let column = |name: &str| {
        lines[0]
            .iter()
            .position(|c| *c == name)
            .unwrap_or_else(|| panic!("no {name} column: {csv}"))
    };
    let (chamfer, psnr) = (column("mesh_chamfer"), column("held_out_psnr_db"));
    for row in &lines[1..] {
        let c: f64 = row[chamfer].parse().unwrap();
        // A sphere of radius 0.7 after a few steps: near, not on it.
        assert!(c.is_finite() && c > 0.0 && c < 1.0, "{csv}");
        let p: f64 = row[psnr].parse().unwrap();
        assert!(p.is_finite() && p > 0.0, "{csv}");
    }
    // The row keeps it as a number (what `--collect` and reruns read).
    let row: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("rows").join("steps=4.json")).unwrap())
            .unwrap();
    assert_eq!(
        row["metrics"]["mesh_chamfer"]
            .as_f64()
            .map(|c| c.to_string()),
        Some(lines[2][chamfer].to_string()),
        "{row}"
    );
    assert_eq!(row["metrics"]["mesh_chamfer_to"], "true_surface", "{row}");
    let md = std::fs::read_to_string(out.join("sweep.md")).unwrap();
    let header = md.lines().next().unwrap();
    assert!(
        header.contains("| held-out PSNR (dB) |")
            && header.contains("| mesh Chamfer to the true surface (scene units) |"),
        "{md}"
    );
    // A panel (640 × 400) per measure: PSNR, SSIM and Chamfer.
    for plot in ["sweep.png", "sweep_value.png"] {
        let img = image::open(out.join(plot)).unwrap();
        assert_eq!((img.width(), img.height()), (640, 1200), "{plot}");
    }
    // Collected again from the rows alone: the same table.
    let collect: Vec<&str> = args.iter().copied().chain(["--collect"]).collect();
    ok(&sdfl(&collect));
    assert_eq!(std::fs::read_to_string(out.join("sweep.csv")).unwrap(), csv);
}

/// A row edited after it was written: `--collect` took a `value` of
/// 1e308 (or any seconds) as long as the fingerprint was intact. The row's
/// check covers its values now, its value must be the setting's, and what
/// it measured must be plausible; a refusal names the row file. Rows
/// written before rows had a check still load (their values checked).
#[test]
fn forged_rows_are_refused_on_collect_naming_the_row() {
    let tmp = temp("forged");
    let scene = tmp.join("scene.sdfl");
    std::fs::write(&scene, SCENE).unwrap();
    let out = tmp.join("out");
    ok(&sweep(&scene, &out, &[]));
    let row = out.join("rows").join("samples=8.json");
    let written = std::fs::read_to_string(&row).unwrap();
    assert!(written.contains("\"value\": 8.0"), "{written}");
    let refused = |what: &str, text: &str| {
        std::fs::write(&row, text).unwrap();
        let o = sweep(&scene, &out, &["--collect"]);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(o.status.code(), Some(1), "{what}: {err}");
        assert!(
            err.contains("sdfl::") && err.contains("rows/samples=8.json"),
            "{what}: {err}"
        );
        err
    };
    // The value, with the fingerprint intact.
    let err = refused(
        "value 1e308",
        &written.replace("\"value\": 8.0", "\"value\": 1e308"),
    );
    assert!(err.contains("edited"), "{err}");
    // A plausible time, edited by hand, is caught by the check alone.
    let seconds = written
        .lines()
        .find(|l| l.trim_start().starts_with("\"seconds\""))
        .unwrap();
    let err = refused(
        "seconds edited",
        &written.replace(seconds, "  \"seconds\": 2.5,"),
    );
    assert!(err.contains("edited"), "{err}");

    // A row as sdfl wrote them before rows had a check: still read...
    let old: String = written
        .lines()
        .filter(|l| !l.trim_start().starts_with("\"check\""))
        .collect::<Vec<_>>()
        .join("\n");
    assert_ne!(old, written.trim_end(), "new rows carry a check");
    std::fs::write(&row, &old).unwrap();
    ok(&sweep(&scene, &out, &["--collect"]));
    // ... with its values checked: the setting's value, a time that is
    // finite and plausible.
    for (what, text) in [
        (
            "old value 1e308",
            old.replace("\"value\": 8.0", "\"value\": 1e308"),
        ),
        (
            "old value 9",
            old.replace("\"value\": 8.0", "\"value\": 9.0"),
        ),
        (
            "old seconds 1e308",
            old.replace(seconds, "  \"seconds\": 1e308,"),
        ),
        (
            "old seconds -1",
            old.replace(seconds, "  \"seconds\": -1.0,"),
        ),
    ] {
        let err = refused(what, &text);
        assert!(
            err.contains("implausible") || err.contains("not the setting's"),
            "{what}: {err}"
        );
    }
    // A run (not a collect) writes the forged setting's row again.
    let again = ok(&sweep(&scene, &out, &[]));
    assert!(again.contains("samples=8: running again"), "{again}");
    ok(&sweep(&scene, &out, &["--collect"]));
    let csv = std::fs::read_to_string(out.join("sweep.csv")).unwrap();
    assert!(!csv.contains("e308"), "{csv}");
}
