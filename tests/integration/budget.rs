//! The budget covers what is known only once data are read: a NeRF-synthetic
//! test split scored every step is refused after loading, before any step.

use crate::common::*;

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
        scene(0).replace("iterations: 20000", "iterations: 2"),
    )
    .unwrap();
    let o = sdfl(&dir, &["run", file2.to_str().unwrap(), "--out", out_s]);
    assert_outcome("held-out split at the end", &o, Expect::Ok);
}
