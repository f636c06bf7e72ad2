//! A fit that went wrong says so: a huge learning rate used to end with
//! the radius at 6e10, the loss forty times a normal fit's and exit code 0.
//! It now warns (`sdfl::warn::diverged`) on stderr and in `--json`, and a
//! sound fit of the same scene does not.

use crate::common::*;

use std::fs;

fn fit(lr: &str) -> String {
    format!(
        r#"
let cameras = [look_at(eye: [0, 0, -3]), look_at(eye: [2, 0, -2]), look_at(eye: [3, 0, 0])]
let sampler = stratified(samples: 32, near: 0, far: 6)
let target = sdf_volume(sphere(1, center: [-0.2, 0.1, 0.15]), color: [0.2, 0.6, 0.9])
train t {{
  model: sdf_volume(sphere(param(1), center: param([0.3, 0.2, 0])), color: param([0.3, 0.1, 0.1])),
  data: render_views(target, cameras: cameras, size: [32, 32], sampler: sampler),
  sampler: sampler,
  rays: 256,
  optimizer: adam(lr: {lr}),
  iterations: 200,
}}
"#
    )
}

/// Runs the fit with `--json`: its stderr and the report's warnings.
fn run(name: &str, lr: &str) -> (String, Vec<String>) {
    let dir = case_dir(name);
    let file = dir.join("fit.sdfl");
    fs::write(&file, fit(lr)).unwrap();
    let out = dir.join("out");
    let o = run_into(&dir, &file, &out, &["--json"]);
    assert_outcome(name, &o, Expect::Ok);
    let json: serde_json::Value =
        serde_json::from_slice(&fs::read(dir.join("stdout.txt")).unwrap()).unwrap();
    let warnings = json["jobs"][0]["report"]["warnings"]
        .as_array()
        .expect("a warnings list")
        .iter()
        .map(|w| w.as_str().unwrap().to_string())
        .collect();
    (o.stderr, warnings)
}

#[test]
fn a_diverging_fit_warns_and_a_sound_one_does_not() {
    let (stderr, warnings) = run("diverging_fit", "1e10");
    assert!(
        stderr.contains("warning[sdfl::warn::diverged]"),
        "{}",
        head(&stderr)
    );
    assert!(
        warnings.iter().any(|w| w.contains("sphere.radius")),
        "{warnings:?}"
    );
    let (stderr, warnings) = run("sound_fit", "1e-2");
    assert!(warnings.is_empty(), "{warnings:?}");
    assert!(!stderr.contains("warning["), "{}", head(&stderr));
}

/// A fit whose numbers go non-finite stops with its own code and a help
/// about the learning rate, not as an I/O error about files.
#[test]
fn a_non_finite_fit_is_not_an_io_error() {
    let dir = case_dir("non_finite_fit");
    write_sphere_points(&dir, 500);
    let file = dir.join("fit.sdfl");
    fs::write(
        &file,
        "train fit {\n  model: neural_sdf(layers: 2, width: 16, skips: [], radius: 0.5),\n  data: points(\"sphere.xyz\"),\n  rays: 128,\n  optimizer: adam(lr: 1e6),\n  iterations: 200,\n  checkpoint: \"fit.ckpt\",\n}\n",
    )
    .unwrap();
    let out = dir.join("out");
    let o = run_into(&dir, &file, &out, &[]);
    assert_outcome("non-finite fit", &o, Expect::Error);
    assert!(
        o.stderr.contains("sdfl::train::non-finite") && !o.stderr.contains("sdfl::io"),
        "{}",
        head(&o.stderr)
    );
    assert!(o.stderr.contains("learning rate"), "{}", head(&o.stderr));
}
