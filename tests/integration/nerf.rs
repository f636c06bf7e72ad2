//! NeRF end to end through the language, small enough for CI: a tiny
//! network learns a self-rendered scene (its loss falls fourfold); a hash
//! grid with an occupancy grid passes 28 dB on held-out views and empties
//! cells; resumed runs are the same run (weights, Adam moments and the
//! occupancy grid bit-identical); a checkpoint of another architecture is
//! refused.

use std::path::{Path, PathBuf};

use sdfl_lang::SourceFile;
use sdfl_runtime::jobs::{run_train_job, TrainOptions, TrainReport};
use sdfl_runtime::train::checkpoint::Checkpoint;

const RESUME: TrainOptions = TrainOptions { restart: false };

const TINY: &str = r#"
let cams = orbit(radius: 2.5, up: [0, 1, 0], focal: 1, views: 10)
let truth = volsdf(union(sphere(radius: 0.6, center: [0.3, 0, 0]), box(size: [0.6, 0.6, 0.6], center: [-0.4, 0.1, 0])), alpha: 10, beta: 0.05)
train tiny {
  model: nerf(layers: LAYERS, width: 32, skips: [], view_dependent: false, position: harmonic(freqs: 4)),
  data: render_views(truth, cameras: cams, size: [24, 24], sampler: stratified(samples: 48, near: 1, far: 5)),
  sampler: stratified(samples: 24, near: 1, far: 5, jitter: true),
  rays: 256,
  optimizer: adam(lr: 1e-3),
  iterations: ITERATIONS,
  checkpoint: "tiny.ckpt",
}
"#;

fn job(iterations: usize, layers: usize) -> sdfl_stdlib::value::TrainJob {
    let src = TINY
        .replace("ITERATIONS", &iterations.to_string())
        .replace("LAYERS", &layers.to_string());
    let program = sdfl_stdlib::load(&SourceFile::new("tiny.sdfl", src)).unwrap();
    program.trains[0].clone()
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-nerf-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn run(job: &sdfl_stdlib::value::TrainJob, out: &Path) -> std::io::Result<TrainReport> {
    run_train_job(job, out, Path::new("."), None, RESUME, &|_| {})
}

#[test]
fn a_tiny_nerf_learns_its_scene() {
    let out = temp("learns");
    let r = run(&job(200, 2), &out).unwrap();
    assert_eq!(r.iterations, 200);
    assert!(r.params.is_empty(), "weights stay in the checkpoint");
    assert_eq!(
        r.network_weights,
        Some((27 + 1) * 32 + 33 * 32 + 33 + 33 * 64 + 65 * 3)
    );
    let ck = Checkpoint::read(&out.join("tiny.ckpt")).unwrap();
    let first: f32 = ck.losses[..10].iter().sum::<f32>() / 10.0;
    let last: f32 = ck.losses[190..].iter().sum::<f32>() / 10.0;
    assert!(last < first / 4.0, "loss {first} → {last}");
    let _ = std::fs::remove_dir_all(&out);
}

/// The tiny run again with bf16 layer products (fp32 where the CPU lacks
/// AVX-512 BF16): it learns as well, its loss within 1.5× of fp32's.
#[test]
fn a_tiny_bf16_nerf_learns_its_scene() {
    let (out, out32) = (temp("learns-bf16"), temp("learns-fp32"));
    let mut bf16 = job(200, 2);
    let sdfl_stdlib::value::Field::Nerf(spec) = &*bf16.model else {
        panic!("a nerf")
    };
    bf16.model = std::sync::Arc::new(sdfl_stdlib::value::Field::Nerf(sdfl_stdlib::value::Nerf {
        precision: sdfl_stdlib::value::Precision::Bf16,
        ..spec.clone()
    }));
    run(&bf16, &out).unwrap();
    run(&job(200, 2), &out32).unwrap();
    let losses = |dir: &Path| Checkpoint::read(&dir.join("tiny.ckpt")).unwrap().losses;
    let (l, l32) = (losses(&out), losses(&out32));
    let first: f32 = l[..10].iter().sum::<f32>() / 10.0;
    let last: f32 = l[190..].iter().sum::<f32>() / 10.0;
    let last32: f32 = l32[190..].iter().sum::<f32>() / 10.0;
    assert!(last < first / 4.0, "loss {first} → {last}");
    assert!(last < 1.5 * last32, "bf16 {last} vs fp32 {last32}");
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&out32);
}

#[test]
fn a_resumed_nerf_run_is_the_same_run() {
    let (whole, parts) = (temp("whole"), temp("parts"));
    run(&job(30, 2), &whole).unwrap();
    run(&job(12, 2), &parts).unwrap();
    let resumed = run(&job(30, 2), &parts).unwrap();
    assert_eq!(resumed.resumed_from, Some(12));
    let a = Checkpoint::read(&whole.join("tiny.ckpt")).unwrap();
    let b = Checkpoint::read(&parts.join("tiny.ckpt")).unwrap();
    assert_eq!(a.step, b.step);
    assert_eq!(a.losses, b.losses);
    for (p, q) in a.params.iter().zip(&b.params) {
        assert_eq!(p.name, q.name);
        assert!(
            p.values == q.values && p.adam_m == q.adam_m && p.adam_v == q.adam_v,
            "{} differs",
            p.name
        );
    }
    let _ = std::fs::remove_dir_all(&whole);
    let _ = std::fs::remove_dir_all(&parts);
}

#[test]
fn a_checkpoint_of_another_network_is_refused() {
    let out = temp("other");
    run(&job(5, 2), &out).unwrap();
    let err = run(&job(5, 3), &out).unwrap_err().to_string();
    assert!(
        err.contains("another run") && err.contains("--restart"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&out);
}

const FAST: &str = r#"
let cams = orbit(radius: 2.5, up: [0, 1, 0], focal: 1, views: 12)
let truth = volsdf(union(sphere(radius: 0.6, center: [0.3, 0, 0]), box(size: [0.6, 0.6, 0.6], center: [-0.4, 0.1, 0])), alpha: 10, beta: 0.05)
train fast {
  model: nerf(
    position: hashgrid(levels: 6, log2_table: 12, max_res: 64, min: [-1.2, -1.2, -1.2], max: [1.2, 1.2, 1.2]),
    layers: 1, width: 32, skips: [], view_dependent: false, density: "exp",
    occupancy: occupancy_grid(resolution: 16, min: [-1.2, -1.2, -1.2], max: [1.2, 1.2, 1.2], every: 4),
  ),
  data: render_views(truth, cameras: cams, size: [24, 24], sampler: stratified(samples: 48, near: 1, far: 4), test_views: 2),
  sampler: stratified(samples: 48, near: 1, far: 4),
  rays: 512,
  optimizer: adam(lr: 1e-2),
  iterations: ITERATIONS,
  eval_every: 50,
  checkpoint: "fast.ckpt",
}
"#;

fn fast(iterations: usize) -> sdfl_stdlib::value::TrainJob {
    let src = FAST.replace("ITERATIONS", &iterations.to_string());
    sdfl_stdlib::load(&SourceFile::new("fast.sdfl", src))
        .unwrap()
        .trains[0]
        .clone()
}

#[test]
fn hash_grid_with_occupancy_learns_and_skips_empty_space() {
    let out = temp("fast");
    let r = run(&fast(300), &out).unwrap();
    let (first, last) = (r.held_out[0], *r.held_out.last().unwrap());
    assert!(
        last.step == 300 && last.psnr > 28.0,
        "held-out PSNR {:?}",
        r.held_out
    );
    assert!(last.psnr > first.psnr, "{:?}", r.held_out);
    // The grid is in the checkpoint and has emptied cells (those the views
    // never see keep whatever the network says there).
    let ck = Checkpoint::read(&out.join("fast.ckpt")).unwrap();
    let names: Vec<&str> = ck.state.iter().map(|s| s.0.as_str()).collect();
    assert_eq!(names, ["occupancy.ema", "occupancy.occupied"]);
    let occupied = ck.state[1].1.iter().filter(|&&x| x != 0.0).count();
    assert!(occupied * 3 < 4096 * 2, "{occupied} of 4096 cells occupied");
    // The report counts the samples that reached the network: fewer than
    // the sampler placed, since the grid skipped some (the work really
    // done, which `plan`'s expected share stands for).
    let s = r.samples_per_ray.expect("a NeRF counts its samples");
    assert_eq!(s.sampled, 48);
    assert!(s.evaluated > 0.5 && s.evaluated < 0.9 * 48.0, "{s:?}");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_resumed_run_keeps_its_occupancy_grid() {
    let (whole, parts) = (temp("occ-whole"), temp("occ-parts"));
    run(&fast(40), &whole).unwrap();
    run(&fast(21), &parts).unwrap();
    let resumed = run(&fast(40), &parts).unwrap();
    assert_eq!(resumed.resumed_from, Some(21));
    let a = Checkpoint::read(&whole.join("fast.ckpt")).unwrap();
    let b = Checkpoint::read(&parts.join("fast.ckpt")).unwrap();
    assert_eq!(a.losses, b.losses);
    assert_eq!(a.state, b.state);
    for (p, q) in a.params.iter().zip(&b.params) {
        assert!(
            p.values == q.values && p.adam_m == q.adam_m,
            "{} differs",
            p.name
        );
    }
    let _ = std::fs::remove_dir_all(&whole);
    let _ = std::fs::remove_dir_all(&parts);
}

/// An occupancy grid read from a checkpoint is checked like any input: a
/// negative density or a cell marked neither 0 nor 1 is refused.
#[test]
fn a_tampered_occupancy_grid_is_refused() {
    type Tamper = fn(&mut Vec<(String, Vec<f32>)>);
    let cases: [(Tamper, &str); 2] = [
        (|s| s[0].1[3] = -5.0, "occupancy cell 3 has density -5"),
        (|s| s[1].1[3] = 0.5, "occupancy cell 3 is marked 0.5"),
    ];
    for (k, (tamper, says)) in cases.into_iter().enumerate() {
        let out = temp(&format!("occ-tampered-{k}"));
        run(&fast(5), &out).unwrap();
        let path = out.join("fast.ckpt");
        let mut ck = Checkpoint::read(&path).unwrap();
        assert_eq!(ck.state[0].0, "occupancy.ema");
        tamper(&mut ck.state);
        ck.write(&path).unwrap();
        let err = run(&fast(10), &out).unwrap_err().to_string();
        assert!(err.contains(says) && err.contains("--restart"), "{err}");
        let _ = std::fs::remove_dir_all(&out);
    }
}
