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
