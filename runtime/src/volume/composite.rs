//! Emission–absorption compositing along one ray (CONVENTIONS.md "Volume
//! rendering"). Three entry points produce the same weights
//! `w_k = T_k·(1 − exp(−σ_k Δ_k))` from different per-sample inputs:
//!
//! * [`weights_from_density`]: densities and intervals; transmittance is
//!   accumulated in log space and `σΔ = ∞` (or 1e10·σ) is fine.
//! * [`weights_from_opacity`]: the assignment's per-sample opacity, which may
//!   be exactly 1; composited as a running product, so no `ln 0` appears.
//! * [`weights_from_log_keep`]: `ln(1 − opacity)` together with the opacity
//!   (see [`sdfl_stdlib::density::Density::log_keep`]); the form the trainers
//!   differentiate.
//!
//! All write into caller-provided slices so the hot loops do not allocate;
//! slices of different lengths are an error.

use num_traits::Float;

use super::VolumeError;

fn same_len(what: &str, lens: &[usize]) -> Result<(), VolumeError> {
    if lens.windows(2).all(|w| w[0] == w[1]) {
        Ok(())
    } else {
        Err(VolumeError::Invalid(format!(
            "{what}: slice lengths differ {lens:?}"
        )))
    }
}

/// The value of the last interval `Δ_{n−1}` (the conventions' "1e10").
pub const LAST_INTERVAL: f64 = 1e10;

/// Intervals `Δ_k = t_{k+1} − t_k`, the last one [`LAST_INTERVAL`].
pub fn intervals<F: Float>(t: &[F], out: &mut [F]) -> Result<(), VolumeError> {
    same_len("intervals", &[t.len(), out.len()])?;
    for k in 0..t.len() {
        out[k] = if k + 1 < t.len() {
            t[k + 1] - t[k]
        } else {
            F::from(LAST_INTERVAL).unwrap()
        };
    }
    Ok(())
}

/// Optical thickness `σΔ` of one interval; `σ ≤ 0`, `Δ ≤ 0` or NaN give 0 so
/// that `∞·0` never happens (an infinite density over an empty interval
/// absorbs nothing).
#[inline]
pub fn optical_thickness<F: Float>(sigma: F, delta: F) -> F {
    if sigma > F::zero() && delta > F::zero() {
        sigma * delta
    } else {
        F::zero()
    }
}

/// Weights from densities: `T_k = exp(−Σ_{j<k} σ_jΔ_j)` accumulated in log
/// space, `w_k = T_k·(−expm1(−σ_kΔ_k))`. Returns the final transmittance.
pub fn weights_from_density<F: Float>(
    sigma: &[F],
    delta: &[F],
    w: &mut [F],
) -> Result<F, VolumeError> {
    same_len("weights_from_density", &[sigma.len(), delta.len(), w.len()])?;
    let mut tau = F::zero();
    for k in 0..sigma.len() {
        let st = optical_thickness(sigma[k], delta[k]);
        // exp(−∞) = 0 and −expm1(−∞) = 1: finite for any st ≥ 0.
        w[k] = (-tau).exp() * -(-st).exp_m1();
        tau = tau + st;
    }
    Ok((-tau).exp())
}

/// Weights from per-sample opacities `o_k ∈ [0, 1]` (values outside are
/// clamped): `T_k = Π_{j<k}(1 − o_j)`, `w_k = T_k·o_k`. Opacity exactly 1
/// simply zeroes the transmittance behind it. Returns the final transmittance.
pub fn weights_from_opacity<F: Float>(opacity: &[F], w: &mut [F]) -> Result<F, VolumeError> {
    same_len("weights_from_opacity", &[opacity.len(), w.len()])?;
    let mut t = F::one();
    for k in 0..opacity.len() {
        let o = opacity[k].max(F::zero()).min(F::one());
        w[k] = t * o;
        t = t * (F::one() - o);
    }
    Ok(t)
}

/// Weights from `ln(1 − o_k)` and `o_k`: `T_k = exp(Σ_{j<k} ln(1 − o_j))`,
/// `w_k = T_k·o_k`. Both inputs are finite even where `o_k` rounds to 1.
/// Returns the final transmittance.
pub fn weights_from_log_keep<F: Float>(
    log_keep: &[F],
    opacity: &[F],
    w: &mut [F],
) -> Result<F, VolumeError> {
    same_len(
        "weights_from_log_keep",
        &[log_keep.len(), opacity.len(), w.len()],
    )?;
    let mut lt = F::zero();
    for k in 0..opacity.len() {
        w[k] = lt.exp() * opacity[k];
        lt = lt + log_keep[k];
    }
    Ok(lt.exp())
}

/// Transmittance `exp(−Σ σ_kΔ_k)` through a set of intervals.
pub fn transmittance<F: Float>(sigma: &[F], delta: &[F]) -> Result<F, VolumeError> {
    same_len("transmittance", &[sigma.len(), delta.len()])?;
    let tau = sigma
        .iter()
        .zip(delta)
        .fold(F::zero(), |a, (&s, &d)| a + optical_thickness(s, d));
    Ok((-tau).exp())
}

/// Colour `Σ w_k c_k`, depth `Σ w_k t_k` and accumulated opacity `Σ w_k` of a
/// ray. A ray with all-zero weights (empty space) has depth 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Composite<F> {
    /// `Σ w_k c_k`: the colour the ray gathers.
    pub colour: [F; 3],
    /// `Σ w_k t_k`: the expected depth of what the ray hits.
    pub depth: F,
    /// `Σ w_k`: how much of the ray is absorbed (1 − final transmittance).
    pub opacity: F,
}

/// Aggregates colours and depths with the weights.
pub fn aggregate<F: Float>(
    w: &[F],
    colours: &[[F; 3]],
    t: &[F],
) -> Result<Composite<F>, VolumeError> {
    same_len("aggregate", &[w.len(), colours.len(), t.len()])?;
    let mut c = [F::zero(); 3];
    let mut depth = F::zero();
    let mut acc = F::zero();
    for k in 0..w.len() {
        for i in 0..3 {
            c[i] = c[i] + w[k] * colours[k][i];
        }
        depth = depth + w[k] * t[k];
        acc = acc + w[k];
    }
    Ok(Composite {
        colour: c,
        depth,
        opacity: acc,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Straightforward f64 reference: products of per-interval exponentials.
    fn reference_weights(sigma: &[f64], delta: &[f64]) -> Vec<f64> {
        let mut out = Vec::new();
        for k in 0..sigma.len() {
            let t: f64 = (0..k).map(|j| (-sigma[j] * delta[j]).exp()).product();
            out.push(t * (1.0 - (-sigma[k] * delta[k]).exp()));
        }
        out
    }

    fn linspace(n: usize, a: f64, b: f64) -> Vec<f64> {
        (0..n)
            .map(|k| a + (b - a) * k as f64 / (n - 1) as f64)
            .collect()
    }

    fn profile(n: usize) -> Vec<f64> {
        (0..n)
            .map(|k| {
                let x = k as f64 / n as f64;
                3.0 * (-(x - 0.5).powi(2) * 40.0).exp() + 0.1 * x
            })
            .collect()
    }

    #[test]
    fn f32_weights_match_f64_reference() {
        let n = 64;
        let t = linspace(n, 0.0, 5.0);
        let mut d = vec![0.0; n];
        intervals(&t, &mut d).unwrap();
        let sigma = profile(n);
        let r = reference_weights(&sigma, &d);
        let s32: Vec<f32> = sigma.iter().map(|&v| v as f32).collect();
        let d32: Vec<f32> = d.iter().map(|&v| v as f32).collect();
        let mut w = vec![0f32; n];
        weights_from_density(&s32, &d32, &mut w).unwrap();
        for k in 0..n {
            assert!(
                (w[k] as f64 - r[k]).abs() < 1e-6,
                "{k}: {} vs {}",
                w[k],
                r[k]
            );
        }
        // The opacity and log-keep forms give the same weights.
        let o: Vec<f32> = (0..n)
            .map(|k| (1.0 - (-sigma[k] * d[k]).exp()) as f32)
            .collect();
        let lk: Vec<f32> = (0..n).map(|k| (-sigma[k] * d[k]) as f32).collect();
        let mut w2 = vec![0f32; n];
        let mut w3 = vec![0f32; n];
        weights_from_opacity(&o, &mut w2).unwrap();
        weights_from_log_keep(&lk, &o, &mut w3).unwrap();
        for k in 0..n {
            assert!((w2[k] as f64 - r[k]).abs() < 1e-6);
            assert!((w3[k] as f64 - r[k]).abs() < 1e-6);
        }
        // Aggregation against a direct f64 sum.
        let cols: Vec<[f64; 3]> = (0..n).map(|k| [k as f64 / n as f64, 0.5, 0.2]).collect();
        let cols32: Vec<[f32; 3]> = cols.iter().map(|c| c.map(|v| v as f32)).collect();
        let t32: Vec<f32> = t.iter().map(|&v| v as f32).collect();
        let a = aggregate(&w, &cols32, &t32).unwrap();
        let depth: f64 = (0..n).map(|k| r[k] * t[k]).sum();
        let red: f64 = (0..n).map(|k| r[k] * cols[k][0]).sum();
        assert!((a.depth as f64 - depth).abs() < 1e-5);
        assert!((a.colour[0] as f64 - red).abs() < 1e-6);
        assert!((a.opacity as f64 - r.iter().sum::<f64>()).abs() < 1e-6);
    }

    #[test]
    fn assignment_part0_transmittances() {
        // x–y1 empty (length arbitrary), y1–y2 2 m σ=1, y2–y3 1 m σ=0.5, y3–y4 3 m σ=10.
        let sigma = [0.0f32, 1.0, 0.5, 10.0];
        let delta = [1.7f32, 2.0, 1.0, 3.0];
        let cases: [(&[f32], &[f32], f64); 4] = [
            (&sigma[1..2], &delta[1..2], (-2.0f64).exp()),
            (&sigma[2..4], &delta[2..4], (-30.5f64).exp()),
            (&sigma[..], &delta[..], (-32.5f64).exp()),
            (&sigma[..3], &delta[..3], (-2.5f64).exp()),
        ];
        for (s, d, want) in cases {
            let got = transmittance(s, d).unwrap() as f64;
            assert!(((got - want) / want).abs() < 1e-3, "{got} vs {want}");
            // The compositing code agrees: its final transmittance.
            let mut w = vec![0f32; s.len()];
            let tf = weights_from_density(s, d, &mut w).unwrap() as f64;
            assert!(((tf - want) / want).abs() < 1e-3);
        }
        assert!((transmittance(&sigma[1..2], &delta[1..2]).unwrap() - 0.1353).abs() < 1e-4);
    }

    #[test]
    fn hard_cases_stay_finite_and_normalised() {
        // Huge σΔ, infinite σ, the 1e10 last interval, zero intervals.
        let sigma = [0.0f32, 1e10, f32::INFINITY, 3.0, f32::INFINITY, 5.0];
        let delta = [0.1f32, 0.1, 0.1, 0.0, 0.0, 1e10];
        let mut w = [0f32; 6];
        let t = weights_from_density(&sigma, &delta, &mut w).unwrap();
        assert!(w.iter().all(|v| v.is_finite() && *v >= 0.0) && t.is_finite());
        assert!(w.iter().sum::<f32>() <= 1.0 + 1e-6);
        assert_eq!(w[1], 1.0);
        // Opacity exactly one, first and in the middle.
        for o in [[1.0f32, 0.3, 1.0, 0.2], [0.2, 1.0, 1.0, 0.9], [1.0; 4]] {
            let mut w = [0f32; 4];
            let t = weights_from_opacity(&o, &mut w).unwrap();
            assert!(w.iter().all(|v| v.is_finite()) && t == 0.0);
            assert!(w.iter().sum::<f32>() <= 1.0 + 1e-6);
        }
        // Log-keep form with a keep of e^{-1e7} (β = 1e-4, sdf = −1e3).
        let lk = [-0.1f32, -1e7, -1e7];
        let o = [0.095f32, 1.0, 1.0];
        let mut w = [0f32; 3];
        let t = weights_from_log_keep(&lk, &o, &mut w).unwrap();
        assert!(w.iter().all(|v| v.is_finite()) && t == 0.0);
        assert!(w.iter().sum::<f32>() <= 1.0 + 1e-6);
        // Mismatched lengths are errors, not panics.
        assert!(weights_from_density(&[1.0f32], &[1.0, 2.0], &mut [0.0]).is_err());
        assert!(weights_from_opacity(&[1.0f32], &mut [0.0; 2]).is_err());
        assert!(weights_from_log_keep(&[1.0f32], &[1.0], &mut [0.0; 2]).is_err());
        assert!(transmittance(&[1.0f32], &[]).is_err());
        assert!(aggregate(&[1.0f32], &[], &[1.0]).is_err());
        assert!(intervals(&[1.0f32], &mut []).is_err());
        // An empty ray has depth 0 and colour 0.
        let w = [0f32; 5];
        let a = aggregate(&w, &[[0.5; 3]; 5], &[1.0, 2.0, 3.0, 4.0, 5.0]).unwrap();
        assert_eq!(a.depth, 0.0);
        assert_eq!(a.colour, [0.0; 3]);
        let mut w = [0f32; 3];
        weights_from_density(&[0.0f32; 3], &[1.0, 1.0, 1e10], &mut w).unwrap();
        assert_eq!(w, [0.0; 3]);
    }
}
