//! The hash-grid SDF end to end through the language: fitted to points on
//! a sphere it finds them (Chamfer distance from the report, a mesh on the
//! sphere), and a resumed run is the same run, bit for bit.

use crate::common::write_sphere_points;

use std::path::{Path, PathBuf};

use sdfl_lang::SourceFile;
use sdfl_runtime::jobs::{run_train_job, TrainOptions, TrainReport};
use sdfl_runtime::train::checkpoint::Checkpoint;

const SPHERE: &str = r#"
train fit {
  model: neural_sdf(encoding: hashgrid(levels: 8, log2_table: 14, min_res: 4, max_res: 64, min: [-1.5, -1.5, -1.5], max: [1.5, 1.5, 1.5]), network: mlp(layers: 1, width: 32, skips: []), radius: 0.5, level_every: LEVEL_EVERY),
  data: points("sphere.xyz"),
  rays: 512,
  optimizer: adam(lr: 5e-3),
  iterations: ITERATIONS,
  bounds: 1.5,
  views: look_at(eye: [0, 0, -3]),
  size: [17, 17],
  after: [image("fit.png"), mesh("fit.ply", resolution: 40)],
  checkpoint: "fit.ckpt",
}
"#;

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-hsdf-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run(iterations: usize, level_every: usize, dir: &Path) -> TrainReport {
    let src = SPHERE
        .replace("ITERATIONS", &iterations.to_string())
        .replace("LEVEL_EVERY", &level_every.to_string());
    let job = sdfl_stdlib::load(&SourceFile::new("fit.sdfl", src))
        .unwrap()
        .trains[0]
        .clone();
    let out = dir.join("out");
    let opts = TrainOptions { restart: false };
    run_train_job(&job, &out, dir, None, opts, &|_| {}).unwrap()
}

#[test]
fn a_hash_grid_sdf_finds_the_sphere_of_its_points() {
    let dir = temp("sphere");
    write_sphere_points(&dir, 2000);
    let start = run(0, 0, &dir).fit.expect("a fit report");
    let _ = std::fs::remove_dir_all(dir.join("out"));
    let report = run(150, 0, &dir);
    let end = report.fit.expect("a fit report");
    // Sphere-traced: the centre pixel hits (a normal as a colour), the
    // corners miss (black).
    let png = image::open(dir.join("out/fit.png")).unwrap().to_rgb8();
    assert_eq!(png.get_pixel(0, 0).0, [0, 0, 0]);
    assert!(png.get_pixel(8, 8).0 != [0, 0, 0]);
    // It starts as a sphere of radius 0.5 (0.3 from every point) and ends
    // on the points.
    assert!(start.chamfer > 0.2, "{start:?}");
    assert!(end.chamfer < 0.03, "{end:?}");
    assert!(end.surface_mean_abs < 0.02, "{end:?}");
    assert!(end.eikonal < 0.1, "{end:?}");
    let mesh_fit = report.mesh_fit.expect("a mesh fit");
    assert!(mesh_fit.chamfer < 0.05, "{mesh_fit:?}");
    assert_eq!(mesh_fit.against, "data");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_resumed_hash_grid_sdf_run_is_the_same_run() {
    // Levels switched on during the run, before and after the break.
    let (whole, parts) = (temp("whole"), temp("parts"));
    write_sphere_points(&whole, 2000);
    write_sphere_points(&parts, 2000);
    run(30, 4, &whole);
    run(13, 4, &parts);
    // Steps 0..=12 read 2 + 12/4 = 5 levels: the finer three are still
    // at their zero start (no gradient, so Adam left them), the coarser
    // ones trained.
    let early = Checkpoint::read(&parts.join("out/fit.ckpt")).unwrap();
    for p in &early.params {
        if let Some(l) = p.name.strip_prefix("grid.level") {
            let level: usize = l.parse().unwrap();
            assert_eq!(
                p.values.iter().all(|&v| v == 0.0),
                level >= 5,
                "{} at step 13",
                p.name
            );
        }
    }
    let resumed = run(30, 4, &parts);
    assert_eq!(resumed.resumed_from, Some(13));
    let a = Checkpoint::read(&whole.join("out/fit.ckpt")).unwrap();
    let b = Checkpoint::read(&parts.join("out/fit.ckpt")).unwrap();
    assert_eq!(a.losses, b.losses);
    assert!(a.params.iter().any(|p| p.name == "grid.level7"));
    for (p, q) in a.params.iter().zip(&b.params) {
        assert!(
            p.values == q.values && p.adam_m == q.adam_m && p.adam_v == q.adam_v,
            "{} differs",
            p.name
        );
    }
    let _ = std::fs::remove_dir_all(&whole);
    let _ = std::fs::remove_dir_all(&parts);
}
