//! Marching: textbook compositing, hard cases, the infinite last interval.

use sdfl_runtime::volume::march::*;
use sdfl_stdlib::num::{Dual, Real, V3};
use sdfl_stdlib::value::{DensityKind, LastInterval};

/// Textbook compositing in f64: `w_k = Π_{j<k}(1 − o_j)·o_k`.
fn reference(opacity: &[f64], c: &[f64]) -> f64 {
    let mut trans = 1.0;
    let mut out = 0.0;
    for k in 0..opacity.len() {
        out += trans * opacity[k] * c[k];
        trans *= 1.0 - opacity[k];
    }
    out
}

#[test]
fn march_matches_textbook_compositing() {
    let t: Vec<f32> = (0..16).map(|k| 0.25 * k as f32).collect();
    let mut delta = Vec::new();
    intervals_into(&t, LastInterval::Zero, &mut delta);
    // A sphere of radius 1 at distance 2 along the ray, colour = t.
    let sdf = |z: f64| (z - 2.0).abs() - 1.0;
    for &kind in DensityKind::ALL {
        let (alpha, beta) = (4.0f64.min(kind.alpha_max()), 0.2);
        let r = march::<f64>(
            |p| (sdf(p.z), V3::splat(p.z / 4.0)),
            kind,
            alpha,
            beta,
            [0.0; 3],
            [0.0, 0.0, 1.0],
            Depths {
                t: &t,
                delta: &delta,
            },
            true,
        );
        let opacity: Vec<f64> = t
            .iter()
            .zip(&delta)
            .map(|(&z, &d)| {
                let s = kind.sigma(sdf(z as f64), alpha, 1.0 / beta);
                if kind.per_sample_opacity() {
                    s
                } else {
                    1.0 - (-s * d as f64).exp()
                }
            })
            .collect();
        let c: Vec<f64> = t.iter().map(|&z| z as f64 / 4.0).collect();
        let want = reference(&opacity, &c);
        assert!(
            (r.colour.x - want).abs() < 1e-6,
            "{kind:?}: {} vs {want}",
            r.colour.x
        );
    }
}

#[test]
fn hard_cases_are_finite() {
    let t: Vec<f32> = (0..8).map(|k| k as f32).collect();
    for last in [LastInterval::Zero, LastInterval::Infinite] {
        let mut delta = Vec::new();
        intervals_into(&t, last, &mut delta);
        for &kind in DensityKind::ALL {
            for (beta, sdf0) in [(1e-4, -1e3), (1e-4, 0.0), (0.05, 1e6), (1e-4, 1e-9)] {
                let alpha = 1e4f64.min(kind.alpha_max());
                let r = march::<Dual<f32, 3>>(
                    |p| {
                        let s = Dual::seed(sdf0 as f32, 0) + p.z * Dual::lit(0.0);
                        (s, V3::splat(Dual::lit(0.5)))
                    },
                    kind,
                    Dual::seed(alpha as f32, 1),
                    Dual::seed(beta as f32, 2),
                    [0.0; 3],
                    [0.0, 0.0, 1.0],
                    Depths {
                        t: &t,
                        delta: &delta,
                    },
                    true,
                );
                for x in [r.colour.x, r.depth, r.opacity] {
                    assert!(
                        x.v.is_finite() && x.d.iter().all(|d| d.is_finite()),
                        "{kind:?} β {beta} sdf {sdf0}: {x:?}"
                    );
                }
                assert!(r.opacity.v <= 1.0 + 1e-6);
            }
        }
    }
}

#[test]
fn only_the_infinite_last_interval_makes_far_haze_opaque() {
    // The last interval absorbs nothing, so extending `far` through empty
    // space leaves the colour unchanged.
    let ray = |far: f32, last| {
        let t: Vec<f32> = (0..=20).map(|k| far * k as f32 / 20.0).collect();
        let mut delta = Vec::new();
        intervals_into(&t, last, &mut delta);
        march::<f64>(
            |p| (p.z * 0.0 + 0.5, V3::splat(1.0)),
            DensityKind::VolSdf,
            10.0,
            0.05,
            [0.0; 3],
            [0.0, 0.0, 1.0],
            Depths {
                t: &t,
                delta: &delta,
            },
            false,
        )
        .opacity
    };
    // A thin haze: density 10·e^(−10)/2 ≈ 2.3e-4 everywhere.
    let (a, b) = (ray(5.0, LastInterval::Zero), ray(8.0, LastInterval::Zero));
    assert!(a < 2e-3 && b < 2e-3);
    assert!(
        ray(5.0, LastInterval::Infinite) > 0.99,
        "the quirk makes the far sample opaque"
    );
}
