//! The hash SDF's clearances: brute-force distances less the margin.

use sdfl_runtime::neural::hash_sdf::objective::*;
use sdfl_runtime::volume::SplitMix64;

fn brute_nearest(p: [f32; 3], set: &[[f32; 3]], skip: Option<usize>) -> f64 {
    set.iter()
        .enumerate()
        .filter(|&(i, _)| Some(i) != skip)
        .map(|(_, q)| {
            (0..3)
                .map(|a| (p[a] as f64 - q[a] as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn clearances_are_brute_force_distances_less_the_margin() {
    let mut rng = SplitMix64::new(5);
    let mut cloud = |n: usize, s: f32| -> Vec<[f32; 3]> {
        (0..n)
            .map(|_| std::array::from_fn(|_| (rng.next_f32() * 2.0 - 1.0) * s))
            .collect()
    };
    let mut surface = cloud(300, 0.5);
    // A repeated sample: spacing 0 for both copies.
    surface.push(surface[0]);
    let random = cloud(200, 1.5);
    let mut out = Vec::new();
    clearances(&surface, &random, 2.0, &mut out);
    let spacing = (0..surface.len())
        .map(|i| brute_nearest(surface[i], &surface, Some(i)))
        .sum::<f64>()
        / surface.len() as f64;
    assert_eq!(out.len(), random.len());
    for (o, &p) in out.iter().zip(&random) {
        let want = brute_nearest(p, &surface, None) - 2.0 * spacing;
        assert!((*o as f64 - want).abs() < 1e-5, "{o} vs {want}");
    }
    // Too few samples to have a spacing: no bound anywhere.
    clearances(&surface[..1], &random, 2.0, &mut out);
    assert!(out.len() == random.len() && out.iter().all(|&o| o == f32::NEG_INFINITY));
    clearances(&[], &random, 2.0, &mut out);
    assert!(out.iter().all(|&o| o == f32::NEG_INFINITY));
}
