//! The budget covers what is known only once data are read: a NeRF-synthetic
//! test split scored every step is refused after loading, before any step;
//! `sdfl plan` estimates the same from the images' headers.

use crate::common::*;

use sdfl_runtime::data::nerf_synthetic::SplitRead;
use std::fs;
use std::path::Path;

fn data_set(dir: &Path) {
    let from = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/nerf_synthetic_tiny");
    let to = dir.join("set");
    fs::create_dir_all(&to).unwrap();
    for f in ["r_0.png", "r_1.png", "r_2.png"] {
        fs::copy(from.join(f), to.join(f)).unwrap();
    }
    for split in ["train", "test"] {
        fs::copy(
            from.join("transforms.json"),
            to.join(format!("transforms_{split}.json")),
        )
        .unwrap();
    }
}

fn scene(eval_every: usize) -> String {
    format!(
        r#"
train t {{
  model: nerf(layers: 4, width: 128, skips: []),
  data: nerf_synthetic("set", test_split: "test"),
  sampler: stratified(samples: 4096, near: 1, far: 5),
  rays: 1,
  iterations: 20000,
  eval_every: {eval_every},
  checkpoint: "t.ckpt",
}}
"#
    )
}

#[test]
fn a_test_split_scored_every_step_is_refused_before_training() {
    let dir = case_dir("held_out_split");
    data_set(&dir);
    let file = dir.join("t.sdfl");
    // A sixteenth of the samples a ray and 16 times the steps: the same
    // held-out work scored every step, and the accepted run below scores
    // its views once with a sixteenth of the samples.
    let scene = |every| {
        scene(every)
            .replace("samples: 4096", "samples: 256")
            .replace("iterations: 20000", "iterations: 320000")
    };
    fs::write(&file, scene(1)).unwrap();
    let out = dir.join("out");
    let (file, out_s) = (file.to_str().unwrap(), out.to_str().unwrap());
    let o = sdfl(&dir, &["run", file, "--out", out_s]);
    assert_outcome("held-out split every step", &o, Expect::Error);
    assert!(
        o.stderr.contains("held-out views") && o.stderr.contains("eval_every"),
        "{}",
        head(&o.stderr)
    );
    // Refused before the first step: no checkpoint was written.
    assert!(!out.join("t.ckpt").exists());
    // The same run scoring at the end only is within the budget.
    let file2 = dir.join("t2.sdfl");
    fs::write(
        &file2,
        scene(0).replace("iterations: 320000", "iterations: 2"),
    )
    .unwrap();
    let o = sdfl(&dir, &["run", file2.to_str().unwrap(), "--out", out_s]);
    assert_outcome("held-out split at the end", &o, Expect::Ok);
}

/// The limit is a safety net with a named override: the refusal states
/// `SDFL_MAX_EVALUATIONS`, and with it raised the same file is accepted
/// (and `run` refuses the data's scoring only past the raised limit); a
/// value that is not a number is refused, not ignored.
#[test]
fn the_evaluation_limit_is_raised_by_its_variable() {
    let dir = case_dir("limit_override");
    data_set(&dir);
    let file = dir.join("t.sdfl");
    // Every sample counted (no occupancy grid): 1.2e12 evaluations.
    fs::write(
        &file,
        scene(0)
            .replace("rays: 1,", "rays: 48,")
            .replace("iterations: 20000", "iterations: 3000"),
    )
    .unwrap();
    let file = file.to_str().unwrap();
    let check = |limit: Option<&str>| {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_sdfl"));
        c.args(["check", file]).current_dir(&dir);
        match limit {
            Some(v) => c.env("SDFL_MAX_EVALUATIONS", v),
            None => c.env_remove("SDFL_MAX_EVALUATIONS"),
        };
        let o = c.output().expect("sdfl runs");
        (
            o.status.code(),
            unwrapped(&String::from_utf8_lossy(&o.stderr)),
        )
    };
    let (code, err) = check(None);
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("sdfl::limit::work") && err.contains("SDFL_MAX_EVALUATIONS=2e12"),
        "{err}"
    );
    let (code, err) = check(Some("2e12"));
    assert_eq!(code, Some(0), "{err}");
    for bad in ["many", "-5", "0"] {
        let (code, err) = check(Some(bad));
        assert_eq!(code, Some(1), "{bad}: {err}");
        assert!(err.contains("sdfl::arg::max_evaluations"), "{bad}: {err}");
    }
}

/// `sdfl plan FILE` run in `dir` (so that the data's relative paths are
/// found whether the CLI resolves them against the scene file's directory
/// or the current one): its stdout.
fn plan_in(dir: &Path, file: &str) -> String {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(["plan", file])
        .current_dir(dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

/// The line of `plan` that starts with `start` (after its indent).
fn line<'a>(plan: &'a str, start: &str) -> &'a str {
    plan.lines()
        .find(|l| l.trim_start().starts_with(start))
        .unwrap_or_else(|| panic!("no `{start}` line in\n{plan}"))
}

/// `sdfl plan` showed no memory for data read from files: it reads the
/// images' headers and says the views, their pixels and the bytes they
/// hold (8-bit files as 8-bit RGBA, 4 bytes a pixel, where they were f32
/// RGB's 12), the same count `run` checks once it has read them, and
/// the peak while one image decodes. A large set is sampled, and says so.
#[test]
fn plan_sizes_file_data_from_the_image_headers() {
    let dir = case_dir("plan_file_data");
    data_set(&dir);
    fs::write(dir.join("t.sdfl"), scene(100)).unwrap();
    let plan = plan_in(&dir, "t.sdfl");
    // Three 16×16 views a split: 1536 pixels.
    let data = line(&plan, "data memory");
    assert!(
        data.contains("6 views of 16x16, 3 held out as test views, 1536 pixels")
            && data.contains("from 6 image headers"),
        "{data}"
    );
    // The bytes `run` counts once the views are read.
    assert_plan_holds_what_run_reads(&dir, data, 1, 1536.0 * 4.0);
    // Decoding holds more than the views: at least twice an image's f32.
    let reading = line(&plan, "reading");
    assert!(reading.contains("at most"), "{reading}");
    assert!(
        line(&plan, "with the data").contains("scoring 3 held-out views"),
        "{plan}"
    );
    // `silhouette()` keeps a byte of coverage a training pixel.
    let silhouette = r#"
train s {
  model: neus(neural_sdf(encoding: hashgrid(levels: 4, log2_table: 10, min_res: 4, max_res: 24, min: [-1, -1, -1], max: [1, 1, 1]), network: mlp(layers: 1, width: 16, skips: []), radius: 0.4), background: [1, 1, 1], view_dependent: false),
  data: nerf_synthetic("set", test_split: "test"),
  sampler: stratified(samples: 16, near: 1, far: 5),
  losses: [mse(), silhouette()],
  iterations: 2,
}
"#;
    fs::write(dir.join("s.sdfl"), silhouette).unwrap();
    let plan = plan_in(&dir, "s.sdfl");
    let want = sdfl_stdlib::size::fmt_bytes(1536.0 * 4.0 + 768.0);
    assert!(line(&plan, "data memory").contains(&want), "{plan}");

    // 10 000 frames: a sample of the headers, and plan stays quick.
    let frames: Vec<String> = (0..10_000)
        .map(|k| format!("{{\"file_path\": \"./r_{}\", \"transform_matrix\": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}}", k % 3))
        .collect();
    fs::write(
        dir.join("set/transforms_big.json"),
        format!(
            "{{\"camera_angle_x\": 0.7, \"frames\": [{}]}}",
            frames.join(",")
        ),
    )
    .unwrap();
    fs::write(
        dir.join("big.sdfl"),
        scene(100).replace("test_split: \"test\"", "split: \"big\""),
    )
    .unwrap();
    let t0 = std::time::Instant::now();
    let plan = plan_in(&dir, "big.sdfl");
    let data = line(&plan, "data memory");
    assert!(
        data.contains("10000 views of 16x16, 2560000 pixels")
            && data.contains("64 of 10000 image headers read"),
        "{data}"
    );
    assert!(t0.elapsed().as_secs_f64() < 20.0, "{:?}", t0.elapsed());

    // Data not found here: the plan still prints, saying so.
    fs::remove_file(dir.join("set/r_1.png")).unwrap();
    let plan = plan_in(&dir, "t.sdfl");
    assert!(
        line(&plan, "data memory").contains("known once read"),
        "{plan}"
    );
}

/// `nerf_synthetic(downscale: 4)`: `plan` counts the views at their small
/// size, held as f32 RGB (the blocks' means): the same bytes `run` counts
/// once it has read them.
#[test]
fn plan_counts_a_downscaled_set_at_its_small_size() {
    let dir = case_dir("plan_downscaled");
    data_set(&dir);
    let text = scene(100).replace("test_split: \"test\"", "test_split: \"test\", downscale: 4");
    fs::write(dir.join("t.sdfl"), text).unwrap();
    let plan = plan_in(&dir, "t.sdfl");
    // Six 16×16 views at 4×4: 96 pixels of 12 bytes.
    let data = line(&plan, "data memory");
    assert!(
        data.contains("6 views of 4x4, 3 held out as test views, 96 pixels"),
        "{data}"
    );
    assert!(
        line(&plan, "data ").contains("box-filtered to 1/4 a side"),
        "{plan}"
    );
    assert_plan_holds_what_run_reads(&dir, data, 4, 96.0 * 12.0);
}

/// The views of the set in `dir` read as `run` reads them (at 1/`downscale`
/// a side) hold `bytes`, and the plan's `data` line says so.
fn assert_plan_holds_what_run_reads(dir: &Path, data: &str, downscale: u32, bytes: f64) {
    let views: Vec<_> = sdfl_runtime::data::nerf_synthetic::read_splits(
        &dir.join("set"),
        &["train", "test"].map(|s| SplitRead {
            downscale,
            ..SplitRead::all(s)
        }),
        glam::DVec3::ONE,
    )
    .unwrap()
    .into_iter()
    .flatten()
    .collect();
    let held = sdfl_runtime::data::views_bytes(&views);
    assert_eq!(held, bytes);
    let shown = sdfl_stdlib::size::fmt_bytes(held);
    assert!(
        data.contains(&format!(": {shown} held through training")),
        "{data}"
    );
}

/// `eval_views` scores fewer held-out views, evenly spaced with the first
/// included, and the others are never read: `plan` counts only those
/// (their bytes and their scoring), `run` scores only those, and a view
/// left out may even be unreadable.
#[test]
fn eval_views_reads_and_scores_only_the_views_it_names() {
    let dir = case_dir("eval_views");
    data_set(&dir);
    let set = dir.join("set");
    // Six held-out frames: r_0, r_1, r_2, then three that do not decode.
    fs::write(set.join("broken.png"), b"not a png").unwrap();
    let frames: Vec<String> = ["r_0", "r_1", "r_2", "broken", "broken", "broken"]
        .iter()
        .map(|f| format!("{{\"file_path\": \"./{f}\", \"transform_matrix\": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}}"))
        .collect();
    fs::write(
        set.join("transforms_test.json"),
        format!(
            "{{\"camera_angle_x\": 0.7, \"frames\": [{}]}}",
            frames.join(",")
        ),
    )
    .unwrap();
    let small = scene(0)
        .replace("layers: 4, width: 128", "layers: 1, width: 16")
        .replace("samples: 4096", "samples: 16")
        .replace("iterations: 20000", "iterations: 2");
    // Two of six: positions 0 and 3 (a broken one): read, so refused.
    fs::write(
        dir.join("two.sdfl"),
        small.replace("eval_every: 0,", "eval_every: 0, eval_views: 2,"),
    )
    .unwrap();
    let two = dir.join("two.sdfl");
    let o = sdfl(
        &dir,
        &[
            "run",
            two.to_str().unwrap(),
            "--out",
            dir.join("out2").to_str().unwrap(),
        ],
    );
    assert_outcome("eval_views 2 reads a broken view", &o, Expect::Error);
    assert!(o.stderr.contains("broken"), "{}", head(&o.stderr));
    // Only the first of six: the broken ones are never read.
    fs::write(
        dir.join("one.sdfl"),
        small.replace("eval_every: 0,", "eval_every: 0, eval_views: 1,"),
    )
    .unwrap();
    let plan = plan_in(&dir, "one.sdfl");
    let data = line(&plan, "data memory");
    assert!(
        data.contains("4 views of 16x16, 1 of its 6 held-out views read and scored (`eval_views`), 1024 pixels"),
        "{data}"
    );
    assert!(
        line(&plan, "with the data").contains("scoring 1 held-out views"),
        "{plan}"
    );
    let r = run_report(&dir, "one.sdfl");
    assert_eq!(r["held_out"][0]["views"].as_u64(), Some(1), "{r}");
}

/// examples/benchmarks/nerf_synthetic.sdfl, its data path pointed at a
/// small set of the same layout and its steps cut to 2: `plan` reads the
/// set, and `run` trains, scores the test views and writes its outputs.
#[test]
fn the_nerf_synthetic_benchmark_runs_on_a_set_of_its_layout() {
    let dir = case_dir("benchmark_nerf_synthetic");
    data_set(&dir);
    let example =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/benchmarks/nerf_synthetic.sdfl");
    let text = fs::read_to_string(example).unwrap();
    for line in ["let data = \"nerf_synthetic/lego\"", "let steps = 5000"] {
        assert!(text.contains(line), "the example's `{line}` moved");
    }
    let text = text
        .replace("let data = \"nerf_synthetic/lego\"", "let data = \"set\"")
        .replace("let steps = 5000", "let steps = 2");
    fs::write(dir.join("lego.sdfl"), text).unwrap();
    let plan = plan_in(&dir, "lego.sdfl");
    assert!(
        line(&plan, "data memory").contains("3 held out as test views"),
        "{plan}"
    );
    let r = run_report(&dir, "lego.sdfl");
    assert_eq!(r["held_out"][0]["views"].as_u64(), Some(3), "{r}");
    for f in ["lego_psnr.png", "lego_test.png", "lego.ckpt"] {
        assert!(dir.join("out").join(f).is_file(), "{f}");
    }
}

/// examples/benchmarks/nerf_synthetic_small.sdfl on a small set of its
/// layout (16² read at 4²), its steps cut to 2: `plan` reads the set at
/// the small size, and `run` trains, scores the test views and writes its
/// outputs.
#[test]
fn the_small_nerf_synthetic_benchmark_runs_on_a_set_of_its_layout() {
    let dir = case_dir("benchmark_nerf_synthetic_small");
    data_set(&dir);
    let example =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/benchmarks/nerf_synthetic_small.sdfl");
    let text = fs::read_to_string(example).unwrap();
    let (data, steps) = ("let data = \"nerf_synthetic/lego\"", "let steps = ");
    assert!(
        text.contains(data) && text.contains(steps),
        "the example's settings moved"
    );
    let text: String = text
        .replace(data, "let data = \"set\"")
        .lines()
        .map(|l| {
            if l.starts_with(steps) {
                "let steps = 2"
            } else {
                l
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    fs::write(dir.join("lego.sdfl"), text).unwrap();
    let plan = plan_in(&dir, "lego.sdfl");
    assert!(
        line(&plan, "data memory").contains("6 views of 4x4, 3 held out as test views"),
        "{plan}"
    );
    let r = run_report(&dir, "lego.sdfl");
    assert_eq!(r["held_out"][0]["views"].as_u64(), Some(3), "{r}");
    for f in [
        "lego_small_psnr.png",
        "lego_small_test.png",
        "lego_small.ckpt",
    ] {
        assert!(dir.join("out").join(f).is_file(), "{f}");
    }
}
