//! A hash-grid SDF learnt from images through NeuS (exact ∇f) and VolSDF
//! (∇f by central differences), end to end through the language and small
//! enough for CI: after a short training the held-out PSNR has risen and
//! the mesh lies near the true sphere; a run stopped and resumed across a
//! level switch is the same run, bit for bit.

use std::path::{Path, PathBuf};

use sdfl_lang::SourceFile;
use sdfl_runtime::jobs::{run_train_job, TrainOptions, TrainReport};
use sdfl_runtime::train::checkpoint::Checkpoint;

const SCENE: &str = r#"
let cams = orbit(radius: 3, up: [0, 1, 0], focal: 1.5, views: 12)
let grid = hashgrid(levels: 8, log2_table: 12, min_res: 4, max_res: 48, min: [-1.2, -1.2, -1.2], max: [1.2, 1.2, 1.2])
train fit {
  model: DENSITY(neural_sdf(encoding: grid, network: mlp(layers: 1, width: 16, skips: []), radius: 0.4, level_every: LEVEL_EVERYSTEP), ALPHAbeta: BETA, view_dependent: false, fine: 8),
  data: render_views(sphere(0.7), cameras: cams, size: [16, 16], material: lambert(albedo: [0.9, 0.5, 0.2]), test_views: 2, split_seed: 3, hit_tolerance: "absolute"),
  sampler: stratified(samples: 16, near: 1.8, far: 4.2, jitter: true),
  rays: 256,
  optimizer: adam(lr: 1e-2),
  iterations: ITERATIONS,
  bounds: 1.2,
  views: look_at(eye: [0, 0, -3]),
  size: [8, 8],
  after: [MESH],
  checkpoint: "fit.ckpt",
}
"#;

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-hsurf-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// NeuS trains β and takes the exact ∇f; VolSDF anneals β and takes
/// central differences.
fn run(
    density: &str,
    iterations: usize,
    level_every: usize,
    mesh: bool,
    out: &Path,
) -> TrainReport {
    let (alpha, beta, step) = if density == "volsdf" {
        (
            "alpha: 12, ",
            "0.08, beta_end: 0.02",
            ", eikonal_step: 0.01",
        )
    } else {
        ("", "param(0.08)", "")
    };
    // A schedule spans the run's steps: a shorter run has another, so the
    // resumed runs keep β fixed.
    let beta = if mesh {
        beta.to_string()
    } else {
        beta.replace(", beta_end: 0.02", "")
    };
    let src = SCENE
        .replace("DENSITY", density)
        .replace("ALPHA", alpha)
        .replace("BETA", &beta)
        .replace("STEP", step)
        .replace("LEVEL_EVERY", &level_every.to_string())
        .replace("ITERATIONS", &iterations.to_string())
        .replace(
            "MESH",
            if mesh {
                r#"mesh("fit.ply", resolution: 32)"#
            } else {
                ""
            },
        );
    let job = sdfl_stdlib::load(&SourceFile::new("fit.sdfl", src))
        .unwrap()
        .trains[0]
        .clone();
    let opts = TrainOptions { restart: false };
    run_train_job(&job, out, out, None, opts, &|_| {}).unwrap()
}

#[test]
fn a_hash_surface_learns_the_sphere_from_its_views() {
    for density in ["neus", "volsdf"] {
        let dir = temp(density);
        let start = run(density, 0, 10, false, &dir);
        let _ = std::fs::remove_dir_all(&dir);
        let report = run(density, 150, 10, true, &dir);
        let (p0, p1) = (start.held_out[0].psnr, report.held_out.last().unwrap().psnr);
        assert!(
            p1 > p0 + 5.0 && p1 > 22.0,
            "{density}: held-out PSNR {p0:.2} → {p1:.2}"
        );
        let fit = report.mesh_fit.expect("measured against the true surface");
        // It starts as a sphere of radius 0.4, 0.3 inside the truth.
        assert!(fit.chamfer < 0.05, "{density}: {fit:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[test]
fn a_resumed_hash_surface_run_is_the_same_run() {
    for density in ["neus", "volsdf"] {
        let (whole, parts) = (
            temp(&format!("{density}-whole")),
            temp(&format!("{density}-parts")),
        );
        // 8 levels, 2 on at first and one more every 3 steps: the break at
        // step 7 falls between switches at 6 and 9.
        run(density, 16, 3, false, &whole);
        run(density, 7, 3, false, &parts);
        let early = Checkpoint::read(&parts.join("fit.ckpt")).unwrap();
        for p in &early.params {
            if let Some(l) = p.name.strip_prefix("sdf.grid.level") {
                let level: usize = l.parse().unwrap();
                assert_eq!(
                    p.values.iter().all(|&v| v == 0.0),
                    level >= 4,
                    "{density}: {} at step 7",
                    p.name
                );
            }
        }
        let resumed = run(density, 16, 3, false, &parts);
        assert_eq!(resumed.resumed_from, Some(7));
        let a = Checkpoint::read(&whole.join("fit.ckpt")).unwrap();
        let b = Checkpoint::read(&parts.join("fit.ckpt")).unwrap();
        assert_eq!(a.losses, b.losses, "{density}");
        assert!(a.params.iter().any(|p| p.name == "sdf.grid.level7"));
        for (p, q) in a.params.iter().zip(&b.params) {
            assert!(
                p.values == q.values && p.adam_m == q.adam_m && p.adam_v == q.adam_v,
                "{density}: {} differs",
                p.name
            );
        }
        let _ = std::fs::remove_dir_all(&whole);
        let _ = std::fs::remove_dir_all(&parts);
    }
}
