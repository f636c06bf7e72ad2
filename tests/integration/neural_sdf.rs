//! Neural SDFs end to end through the language, small enough for CI: a
//! small network fitted to points on a sphere finds it (Chamfer distance
//! and eikonal term measured by the report), and a resumed run is the same
//! run.

use crate::common::write_sphere_points;

use std::path::{Path, PathBuf};

use sdfl_lang::SourceFile;
use sdfl_runtime::jobs::{run_train_job, TrainOptions, TrainReport};
use sdfl_runtime::train::checkpoint::Checkpoint;

const SPHERE: &str = r#"
train fit {
  model: neural_sdf(encoding: harmonic(freqs: 2), layers: 3, width: 32, skips: [], radius: 0.5),
  data: points("sphere.xyz"),
  rays: 512,
  optimizer: adam(lr: 2e-3),
  iterations: ITERATIONS,
  bounds: 1.5,
  views: look_at(eye: [0, 0, -3]),
  size: [17, 17],
  after: [image("fit.png"), mesh("fit.ply", resolution: 40)],
  checkpoint: "fit.ckpt",
}
"#;

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-nsdf-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run(iterations: usize, dir: &Path) -> TrainReport {
    let src = SPHERE.replace("ITERATIONS", &iterations.to_string());
    let job = sdfl_stdlib::load(&SourceFile::new("fit.sdfl", src))
        .unwrap()
        .trains[0]
        .clone();
    let out = dir.join("out");
    let opts = TrainOptions { restart: false };
    run_train_job(&job, &out, dir, None, opts, &|_| {}).unwrap()
}

#[test]
fn a_small_neural_sdf_finds_the_sphere_of_its_points() {
    let dir = temp("sphere");
    write_sphere_points(&dir, 2000);
    let start = run(0, &dir).fit.expect("a fit report");
    let _ = std::fs::remove_dir_all(dir.join("out"));
    let report = run(300, &dir);
    let end = report.fit.expect("a fit report");
    // Its surface is sphere-traced: the centre pixel hits (a normal as a
    // colour, facing the camera), the corners miss (black).
    let png = image::open(dir.join("out/fit.png")).unwrap().to_rgb8();
    assert_eq!(png.get_pixel(0, 0).0, [0, 0, 0]);
    assert!(
        png.get_pixel(8, 8).0 != [0, 0, 0],
        "{:?}",
        png.get_pixel(8, 8)
    );
    // It starts as a sphere of radius 0.5 (0.3 from every point) and ends
    // on the points.
    assert!(start.chamfer > 0.2, "{start:?}");
    assert!(
        end.chamfer < 0.05 && end.chamfer < start.chamfer / 5.0,
        "{end:?}"
    );
    assert!(end.surface_mean_abs < 0.02, "{end:?}");
    assert!(end.eikonal < 0.1, "{end:?}");
    // Its mesh: on the sphere of the points, measured against them.
    let mesh_fit = report.mesh_fit.expect("a mesh fit");
    assert!(mesh_fit.chamfer < 0.05, "{mesh_fit:?}");
    assert_eq!(mesh_fit.points, 2000);
    assert_eq!(mesh_fit.against, "data");
    let vertices = ply_vertices(&dir.join("out/fit.ply"));
    assert!(vertices.len() > 500);
    let radii: Vec<f32> = vertices
        .iter()
        .map(|v| v.iter().map(|x| x * x).sum::<f32>().sqrt())
        .collect();
    let mean = radii.iter().sum::<f32>() / radii.len() as f32;
    assert!((mean - 0.8).abs() < 0.03, "mean radius {mean}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_resumed_neural_sdf_run_is_the_same_run() {
    let (whole, parts) = (temp("whole"), temp("parts"));
    write_sphere_points(&whole, 2000);
    write_sphere_points(&parts, 2000);
    run(30, &whole);
    run(13, &parts);
    let resumed = run(30, &parts);
    assert_eq!(resumed.resumed_from, Some(13));
    let a = Checkpoint::read(&whole.join("out/fit.ckpt")).unwrap();
    let b = Checkpoint::read(&parts.join("out/fit.ckpt")).unwrap();
    assert_eq!(a.losses, b.losses);
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

/// The vertex positions of a binary PLY file as sdfl writes it (x y z nx ny
/// nz floats per vertex).
fn ply_vertices(path: &Path) -> Vec<[f32; 3]> {
    let bytes = std::fs::read(path).unwrap();
    let end = b"end_header\n";
    let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
    let header = std::str::from_utf8(&bytes[..at]).unwrap();
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
    let count: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .unwrap()
        .parse()
        .unwrap();
    let float =
        |i: usize| f32::from_le_bytes(bytes[at + 4 * i..at + 4 * i + 4].try_into().unwrap());
    (0..count)
        .map(|v| [float(6 * v), float(6 * v + 1), float(6 * v + 2)])
        .collect()
}
