//! One ray through a field, written once over [`Real`] (each density's
//! formulas are in [`sdfl_stdlib::density`]): rendering runs it in
//! f32, training in [`sdfl_stdlib::num::Dual`] numbers whose tangents are
//! the derivatives with respect to every trainable parameter, and the
//! reference tests in f64.
//!
//! Transmittance is the running product of the kept fractions `1 − a_k`,
//! each computed without cancellation (inside a shape with α = 1 the kept
//! fraction of the assignment's opacity form is `e/2` exactly, never
//! `1 − (1 − e/2)`), so an opaque sample gives transmittance exactly 0 and
//! finite derivatives, and the march stops there.

pub use sdfl_stdlib::density::Absorption;
use sdfl_stdlib::num::{Real, V3};
use sdfl_stdlib::value::{DensityKind, LastInterval};

/// The sample depths and intervals of a ray.
#[derive(Debug, Clone, Copy)]
pub struct Depths<'a> {
    /// The sample depths along the ray, ascending.
    pub t: &'a [f32],
    /// `t[k+1] − t[k]`, the last one per [`LastInterval`].
    pub delta: &'a [f32],
}

/// Intervals of sorted depths `t`, the last one per `last`.
pub fn intervals_into(t: &[f32], last: LastInterval, out: &mut Vec<f32>) {
    out.clear();
    out.extend(t.windows(2).map(|w| w[1] - w[0]));
    if !t.is_empty() {
        out.push(match last {
            LastInterval::Zero => 0.0,
            LastInterval::Infinite => 1e10,
        });
    }
}

/// The composite of one ray.
#[derive(Debug, Clone, Copy)]
pub struct RayColour<T> {
    /// `Σ w_k c_k`.
    pub colour: V3<T>,
    /// `Σ w_k t_k` (0 unless asked for).
    pub depth: T,
    /// `Σ w_k`.
    pub opacity: T,
}

/// Marches one ray: `field(p)` gives the signed distance and colour at `p`.
#[inline(always)]
#[allow(
    clippy::too_many_arguments,
    reason = "the hot loop's inputs, passed apart so each monomorphises and inlines"
)]
pub fn march<T: Real>(
    field: impl Fn(V3<T>) -> (T, V3<T>),
    kind: DensityKind,
    alpha: T,
    beta: T,
    origin: [f32; 3],
    dir: [f32; 3],
    depths: Depths,
    want_depth: bool,
) -> RayColour<T> {
    let o = V3::lit(origin.map(f64::from));
    let d = V3::lit(dir.map(f64::from));
    let mut trans = T::one();
    let mut colour = V3::splat(T::zero());
    let mut depth = T::zero();
    let mut acc = T::zero();
    let inv_beta = T::one() / beta;
    for (&tk, &dk) in depths.t.iter().zip(depths.delta) {
        // Every later weight is exactly 0 from here on, and so is every
        // later derivative (each is a multiple of the transmittance's).
        if trans.val() == 0.0 {
            break;
        }
        let t = T::lit(tk as f64);
        let (sdf, c) = field(o + d * t);
        let a = kind.absorption(sdf, alpha, inv_beta, T::lit(dk as f64));
        let w = trans * a.opacity;
        colour = colour + c * w;
        acc = acc + w;
        if want_depth {
            depth = depth + w * t;
        }
        trans = trans * a.keep;
    }
    RayColour {
        colour,
        depth,
        opacity: acc,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sdfl_stdlib::num::Dual;

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
}
