//! The neural SDF's distances: Chamfer sets, the k-d tree against brute
//! force, a sphere-initialised network traced.

use sdfl_runtime::neural::distance::*;
use sdfl_runtime::train::Objective;
use sdfl_runtime::volume::SplitMix64;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::value::{Encoding, Harmonic, NeuralSdf};

#[test]
fn chamfer_of_known_sets() {
    let a = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
    let b = [[0.0, 0.5, 0.0]];
    assert!((mean_nearest(&a, &b) - (0.5 + 1.25f64.sqrt()) / 2.0).abs() < 1e-6);
    assert!((mean_nearest(&b, &a) - 0.5).abs() < 1e-6);
    assert_eq!(mean_nearest(&a, &[]), f64::INFINITY);
}

/// The k-d tree's nearest distances equal brute force, duplicates and
/// all.
#[test]
fn nearest_matches_brute_force() {
    let mut rng = SplitMix64::new(3);
    let mut b: Vec<[f32; 3]> = (0..5000)
        .map(|_| [rng.next_f32(), rng.next_f32(), rng.next_f32()])
        .collect();
    b.extend(std::iter::repeat_n([0.5; 3], 300));
    let a: Vec<[f32; 3]> = (0..700)
        .map(|_| [2.0 * rng.next_f32() - 0.5, rng.next_f32(), rng.next_f32()])
        .collect();
    let brute: f64 = a
        .iter()
        .map(|p| {
            b.iter()
                .map(|q| (0..3).map(|k| ((p[k] - q[k]) as f64).powi(2)).sum::<f64>())
                .fold(f64::INFINITY, f64::min)
                .sqrt()
        })
        .sum::<f64>()
        / a.len() as f64;
    assert!((mean_nearest(&a, &b) - brute).abs() < 1e-6 * brute);
}

#[test]
fn a_sphere_initialised_network_traces_as_a_sphere() {
    let spec = NeuralSdf {
        encoding: Encoding::Harmonic(Harmonic {
            freqs: 2,
            include_input: true,
        }),
        level_every: 0,
        eikonal_step: None,
        layers: 3,
        width: 32,
        skips: vec![],
        beta: 100.0,
        radius: 0.8,
        seed: 0,
    };
    let net = sdf_net(&spec);
    let params = NeuralSdfObjective::new(&spec, &[], 2.0).initial();
    let cam = Camera::look_at(
        glam::DVec3::new(0.0, 0.0, -3.0),
        glam::DVec3::ZERO,
        glam::DVec3::Y,
        1.0,
    );
    let size = sdfl_runtime::volume::ImageSize {
        width: 33,
        height: 33,
    };
    let v = trace_view(&net, &params, &cam, size, TraceSettings::default()).unwrap();
    // The centre pixel hits in front of the origin with a normal
    // facing the camera (the initialisation is a rough sphere of
    // radius 0.8 at this width); a corner misses.
    let c = 16 * 33 + 16;
    assert!(v.depth[c] > 1.8 && v.depth[c] < 3.0, "{}", v.depth[c]);
    assert!(v.colour[c][2] < 0.3, "{:?}", v.colour[c]);
    assert_eq!(v.depth[0], 0.0);
    assert!(v.colour.iter().flatten().all(|x| x.is_finite()));
}
