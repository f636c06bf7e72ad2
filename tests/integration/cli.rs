//! The `sdfl` binary end to end: check, run (with --json), plan, sweep and
//! transmittance, as a user calls them.

use crate::common;
use std::path::{Path, PathBuf};

use crate::common::run_sdfl as sdfl;

fn temp(name: &str) -> PathBuf {
    common::temp_dir("cli", name)
}

fn example(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples")
        .join(name)
        .display()
        .to_string()
}

#[test]
fn check_accepts_every_example_and_rejects_mistakes() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let mut files: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path().display().to_string())
        .collect();
    files.retain(|f| f.ends_with(".sdfl"));
    let mut args = vec!["check"];
    args.extend(files.iter().map(String::as_str));
    let out = sdfl(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let tmp = temp("check");
    let bad = tmp.join("bad.sdfl");
    std::fs::write(
        &bad,
        "let s = sphre(1)\nrender r { scene: s, camera: look_at([0, 0, 3]), outputs: [] }\n",
    )
    .unwrap();
    let out = sdfl(&["check", bad.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("sdfl::name::unknown-function") && err.contains("did you mean `sphere`?"),
        "{err}"
    );
}

#[test]
fn run_writes_outputs_and_a_json_summary() {
    let tmp = temp("run");
    let out = sdfl(&[
        "run",
        "--size",
        "16x16",
        "--json",
        "--out",
        tmp.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("valid JSON");
    let job = &json["jobs"][0];
    assert_eq!(job["kind"], "render");
    let written = job["report"]["written"].as_array().unwrap();
    assert!(!written.is_empty());
    for w in written {
        assert!(tmp.join(w["path"].as_str().unwrap()).is_file(), "{w}");
    }
    let stages: Vec<&str> = job["report"]["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s[0].as_str().unwrap())
        .collect();
    assert_eq!(stages, ["lower", "trace", "encode"]);
    // No temporary files are left behind.
    assert!(std::fs::read_dir(&tmp).unwrap().all(|e| !e
        .unwrap()
        .file_name()
        .to_string_lossy()
        .ends_with(".tmp")));
}

#[test]
fn plan_names_what_each_output_needs() {
    let out = sdfl(&["plan", &example("volume_box.sdfl")]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("render volume_box (volume rendering)"),
        "{text}"
    );
    assert!(
        text.contains("depth          computed for volume_box_depth.png"),
        "{text}"
    );
    assert!(text.contains("gradient tape  none"), "{text}");
    // Training says which kernel runs: the traced tape for the box fit.
    let out = sdfl(&["plan", &example("train_box.sdfl")]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("gradient tape  traced each step:")
            && text.contains("one reverse pass for all 6 scalars"),
        "{text}"
    );
    let out = sdfl(&["plan", &example("torus.sdfl")]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("depth          skipped"), "{text}");
    assert!(text.contains("normals        skipped"), "{text}");
    assert!(
        text.contains("effects        none (no shadow rays, occlusion, fog or supersampling"),
        "{text}"
    );
    // Each effect asked for, with its cost.
    let out = sdfl(&["plan", &example("effects.sdfl")]);
    let text = String::from_utf8_lossy(&out.stdout);
    for line in [
        "soft shadows   k 8: up to 32 SDF evaluations per shaded sample per light facing it (2 lights)",
        "occlusion      5 SDF evaluations per shaded sample along the normal, within 0.5",
        "fog            exponential, density 0.08",
        "supersampling  4 samples per pixel (2x2 rotated grid): 4x primary rays",
    ] {
        assert!(text.contains(line), "{line}\n{text}");
    }
    assert!(!text.contains("effects        none"), "{text}");
    let out = sdfl(&["plan", &example("train_box.sdfl")]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("trainable      box.center (3), box.size (3)"),
        "{text}"
    );
}

#[test]
fn sweep_tabulates_time_and_error() {
    let tmp = temp("sweep");
    let scene = tmp.join("scene.sdfl");
    std::fs::write(
        &scene,
        "let samples = 8\nrender v { scene: sdf_volume(box(size: 1.5)), camera: look_at([0, 0, -3]),\n\
         sampler: stratified(samples: samples), outputs: [image(\"v.png\")] }\n",
    )
    .unwrap();
    let out_dir = tmp.join("out");
    let out = sdfl(&[
        "sweep",
        scene.to_str().unwrap(),
        "--set",
        "samples=4,8,32",
        "--size",
        "12x12",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = std::fs::read_to_string(out_dir.join("sweep.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 4, "{csv}");
    assert!(
        rows[3].contains(",inf,"),
        "the last setting is the reference: {csv}"
    );
    assert!(out_dir.join("sweep.png").is_file() && out_dir.join("sweep_value.png").is_file());
    // Setting a name no `let` binds is a diagnostic.
    let out = sdfl(&[
        "sweep",
        scene.to_str().unwrap(),
        "--set",
        "nope=1,2",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no top-level `let nope`"));
}

#[test]
fn transmittance_prints_the_four_values() {
    let tmp = temp("transmittance");
    let out = sdfl(&["transmittance", "--out", tmp.to_str().unwrap()]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for v in ["1.3534e-1", "5.6757e-14", "7.6812e-15", "8.2085e-2"] {
        assert!(text.contains(v), "{text}");
    }
    assert!(tmp.join("transmittance.png").is_file());
}

#[test]
fn statements_run_in_file_order() {
    let tmp = temp("order");
    std::fs::create_dir_all(&tmp).unwrap();
    let file = tmp.join("order.sdfl");
    std::fs::write(
        &file,
        "let cams = [look_at(eye: [0, 0, -3])]\n\
         render first { scene: sphere(), camera: cams, outputs: [image(\"a.png\")], size: [8, 8] }\n\
         train fit { model: sdf_volume(sphere(param(0.8))), data: render_views(sdf_volume(sphere()), cameras: cams, size: [4, 4]), iterations: 2 }\n\
         render last { scene: sphere(), camera: cams, outputs: [image(\"b.png\")], size: [8, 8] }\n",
    )
    .unwrap();
    let out = sdfl(&[
        "run",
        file.to_str().unwrap(),
        "--json",
        "--out",
        tmp.join("out").to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("valid JSON");
    let names: Vec<&str> = json["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["report"]["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["first", "fit", "last"]);
}

#[test]
fn meshes_of_a_scene_and_a_field_are_written_with_their_statistics() {
    let tmp = temp("mesh");
    let file = tmp.join("mesh.sdfl");
    std::fs::write(
        &file,
        r#"
let ball = sphere(0.7, center: [0.2, 0, 0])
render scene {
  scene: ball,
  camera: look_at(eye: [0, 0, -3]),
  size: [8, 8],
  outputs: [mesh("ball.ply", resolution: 48)],
}
render field {
  scene: volsdf(ball),
  camera: look_at(eye: [0, 0, -3]),
  size: [8, 8],
  outputs: [mesh("field.ply", resolution: 24, bounds: [[-1, -1, -1], [1, 1, 1]])],
}
"#,
    )
    .unwrap();
    let out_dir = tmp.join("out");
    let out = sdfl(&[
        "run",
        file.to_str().unwrap(),
        "--json",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("valid JSON");
    let mesh = |job: usize| json["jobs"][job]["report"]["written"][0].clone();
    let ball = mesh(0);
    assert_eq!(ball["kind"], "mesh");
    assert!(out_dir.join("ball.ply").is_file());
    // The sphere's area, 4πr², within 2 %.
    let area = ball["mesh"]["area"].as_f64().unwrap();
    let exact = 4.0 * std::f64::consts::PI * 0.49;
    assert!((area / exact - 1.0).abs() < 0.02, "{area} vs {exact}");
    assert!(ball["mesh"]["triangles"].as_u64().unwrap() > 1000);
    let field = mesh(1);
    assert_eq!(field["mesh"]["resolution"], 24);
    assert!(out_dir.join("field.ply").is_file());
    // `plan` says what the mesh samples.
    let plan = sdfl(&["plan", file.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&plan.stdout);
    assert!(text.contains("ball.ply: surface nets, 48 cells"), "{text}");
}

#[test]
fn plan_says_which_precision_runs() {
    let dir = temp("precision");
    let file = dir.join("bf16.sdfl");
    std::fs::write(
        &file,
        r#"
let cams = orbit(views: 3)
train t { model: nerf(precision: "bf16"), data: render_views(volsdf(sphere(0.5)), cameras: cams, size: [8, 8]) }
train f { model: nerf(), data: render_views(volsdf(sphere(0.5)), cameras: cams, size: [8, 8]) }
"#,
    )
    .unwrap();
    let plan = sdfl(&["plan", file.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&plan.stdout);
    let bf16 = if sdfl_runtime::neural::bf16::available() {
        "layer products in bf16 with fp32 sums (this CPU has AVX-512 BF16"
    } else {
        "layer products in fp32: bf16 asked for, but this CPU lacks AVX-512 BF16"
    };
    assert!(text.contains(bf16), "{text}");
    assert!(
        text.contains("layer products in fp32\n") || text.contains("layer products in fp32;"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn plan_lists_each_trainings_logs_and_checkpoint() {
    let dir = temp("plan_logs");
    let file = dir.join("logs.sdfl");
    std::fs::write(
        &file,
        r#"
let cams = orbit(views: 4)
let data = render_views(volsdf(sphere(0.5)), cameras: cams, size: [8, 8], test_views: 1)
train fit { model: volsdf(sphere(param(0.4))), data: data, eval_every: 25, checkpoint: "ck/fit.ckpt" }
train quiet { model: volsdf(sphere(param(0.4))), data: render_views(volsdf(sphere(0.5)), cameras: cams, size: [8, 8]), eval_every: 0 }
"#,
    )
    .unwrap();
    let plan = sdfl(&["plan", file.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&plan.stdout);
    assert!(plan.status.success(), "{text}");
    for line in [
        "  logs           fit.metrics.csv and tensorboard/fit/ (every step), fit.heldout.png (each held-out evaluation: every 25 steps and at the end)\n",
        "  checkpoint     ck/fit.ckpt every 100 steps, when stopped by a signal, and at the end\n",
        "  logs           quiet.metrics.csv and tensorboard/quiet/ (every step), no quiet.heldout.png (no views held out)\n",
        "  checkpoint     none (no `checkpoint` named: a stopped run starts over)\n",
    ] {
        assert!(text.contains(line), "{line}{text}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn docs_describe_the_syntax_and_the_new_builtins() {
    for (name, wants) in [
        ("if", "else if"),
        ("fn", "defined above"),
        ("import", ".sdfl"),
        ("random", "SplitMix64"),
        ("min", "lists are flattened"),
    ] {
        let out = sdfl(&["docs", name]);
        assert!(out.status.success(), "docs {name}");
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(text.contains(wants), "docs {name}: {text}");
    }
    let all = String::from_utf8_lossy(&sdfl(&["docs"]).stdout).into_owned();
    assert!(all.contains("syntax:") && all.contains("len"), "{all}");
}

#[test]
fn a_mesh_finer_than_f32_resolves_is_refused() {
    let tmp = temp("mesh-precision");
    let file = tmp.join("far.sdfl");
    std::fs::write(
        &file,
        r#"render far {
  scene: sphere(0.5),
  camera: look_at(eye: [0, 0, -3]),
  size: [4, 4],
  outputs: [mesh("far.ply", resolution: 512, bounds: [[100000, 0, 0], [100000.01, 0.01, 0.01]])],
}
"#,
    )
    .unwrap();
    let out = sdfl(&[
        "run",
        file.to_str().unwrap(),
        "--out",
        tmp.join("out").to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("below f32 precision"), "{err}");
    assert!(!tmp.join("out/far.ply").exists());
}

/// A file with no statement (one meant for `import`) says so rather than
/// printing nothing.
#[test]
fn plan_of_a_file_without_statements_says_so() {
    let o = sdfl(&["plan", "examples/fewer_views_scene.sdfl"]);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.starts_with("no statements"), "{text}");
}

/// `plan` shows the background a NeRF trains with (the data's, resolved)
/// and its contraction.
#[test]
fn plan_shows_the_background_and_the_contraction() {
    let dir = temp("background");
    let file = dir.join("bg.sdfl");
    std::fs::write(
        &file,
        r#"
let cams = orbit(views: 3)
train t {
  model: nerf(position: hashgrid(levels: 2, log2_table: 8), unbounded: contraction(min: [-2, -2, -2], max: [2, 2, 2])),
  data: render_views(sphere(0.5), cameras: cams, size: [8, 8], background: [0.25, 0.5, 1]),
}
train l { model: nerf(background: learned_background(freqs: 3, width: 16)), data: render_views(sphere(0.5), cameras: cams, size: [8, 8]) }
"#,
    )
    .unwrap();
    let plan = sdfl(&["plan", file.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&plan.stdout);
    assert!(text.contains("background [0.25, 0.5, 1]"), "{text}");
    assert!(
        text.contains("unbounded: positions outside [-2, -2, -2]..[2, 2, 2] contracted"),
        "{text}"
    );
    assert!(
        text.contains("background learned from the ray direction (harmonic(3), 16 wide)"),
        "{text}"
    );
}

/// `sdfl view --write-stall` takes seconds from 0.1 to a day; others are
/// refused before anything is served.
#[test]
fn a_write_stall_out_of_range_is_refused() {
    for bad in ["0", "-1", "NaN", "inf", "1e9", "soon"] {
        let stall = format!("--write-stall={bad}");
        let o = sdfl(&["view", "scene.sdfl", "--port", "0", &stall]);
        assert!(!o.status.success(), "--write-stall {bad} was accepted");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--write-stall"), "{bad}: {err}");
    }
}
