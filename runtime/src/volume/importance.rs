//! Hierarchical (importance) sampling by inverse CDF, as the NeRF paper's
//! `sample_pdf`: fine depths drawn where the coarse pass found weight.
//!
//! * Bins are the coarse *intervals* `[t_k, t_{k+1}]` (n − 1 bins), bin `k`
//!   weighted by `w_k + WEIGHT_EPS`. That is the interval sample `k`'s
//!   compositing weight stands for (`Δ_k = t_{k+1} − t_k`), and it works for
//!   n = 2, where NeRF's midpoint bins would leave no interior weight. The
//!   last weight (its interval has no far end) is unused.
//! * The PDF is constant within a bin, so the CDF is piecewise linear and is
//!   inverted exactly. The epsilon gives every bin some mass: all-zero
//!   weights sample each bin equally (uniform in depth for even bins).
//! * `u` is stratified, `u_i = (i + ξ_i)/m`: `ξ = ½` for rendering, `ξ`
//!   uniform from a [`SplitMix64`] for training. Stratified `u` are sorted,
//!   so the depths come out sorted without a sort, and the count in a bin
//!   of probability `p` is within 2 of `m·p` (only the strata at its two
//!   ends are shared).
//! * Masses are summed in f64 (weights up to `f32::MAX` cannot overflow);
//!   NaN and negative weights count as 0, +∞ as `f32::MAX`.
//! * The fine depths are not differentiated (stop-gradient, as in NeRF), so
//!   there is no backward pass.
//!
//! Batches are flat slices, `n` coarse and `m` fine depths per ray, in
//! parallel over rays; the jitter of ray `r` comes from [`ray_rng`] of
//! `(seed, r)`, so results do not depend on the thread count.

use rayon::prelude::*;

use super::{SplitMix64, VolumeError};

/// Added to every bin's weight (NeRF's 1e-5).
pub const WEIGHT_EPS: f64 = 1e-5;

/// How the `u` of the inverse CDF are placed in their strata.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Spacing {
    /// Stratum midpoints `(i + ½)/m` (rendering).
    Even,
    /// Uniform in each stratum, from [`ray_rng`]`(seed, ray)` (training).
    Jittered(u64),
}

/// The generator of ray `ray` of a batch drawn with `seed`: the seed is
/// hashed with the ray index, since consecutive SplitMix64 seeds would give
/// shifted copies of one stream.
pub fn ray_rng(seed: u64, ray: u64) -> SplitMix64 {
    let k = SplitMix64::new(ray ^ 0xD1B5_4A32_D192_ED03).next_u64();
    SplitMix64::new(SplitMix64::new(seed ^ k).next_u64())
}

#[inline]
fn clean(w: f32) -> f64 {
    // `w > 0` is false for NaN.
    if w > 0.0 {
        w.min(f32::MAX) as f64
    } else {
        0.0
    }
}

fn check_depths(t: &[f32]) -> bool {
    t.iter().all(|v| v.is_finite()) && t.windows(2).all(|p| p[0] <= p[1])
}

/// Fine depths of one ray into `out` (`m = out.len()`, sorted), from coarse
/// depths `t` (finite, non-decreasing, n ≥ 2) and their weights `w`;
/// `rng = None` gives even spacing.
pub fn sample_pdf_ray(
    t: &[f32],
    w: &[f32],
    rng: Option<&mut SplitMix64>,
    out: &mut [f32],
) -> Result<(), VolumeError> {
    if t.len() < 2 || w.len() != t.len() || !check_depths(t) {
        return Err(VolumeError::Invalid(format!(
            "sample_pdf: needs ≥ 2 finite sorted depths and as many weights (got {} and {})",
            t.len(),
            w.len()
        )));
    }
    sample_unchecked(t, w, rng, out);
    Ok(())
}

/// One pass over bins and sorted `u` together: no CDF buffer.
fn sample_unchecked(t: &[f32], w: &[f32], mut rng: Option<&mut SplitMix64>, out: &mut [f32]) {
    let bins = t.len() - 1;
    let mass = |k: usize| clean(w[k]) + WEIGHT_EPS;
    let total: f64 = (0..bins).map(mass).sum();
    let per_stratum = total / out.len() as f64;
    // Bin `j` holds cumulative mass `[below, below + mj)`; mj ≥ ε > 0.
    let (mut j, mut below, mut mj) = (0, 0.0f64, mass(0));
    let mut inv_mj = 1.0 / mj;
    for (i, o) in out.iter_mut().enumerate() {
        let xi = match rng.as_deref_mut() {
            Some(r) => r.next_f32() as f64,
            None => 0.5,
        };
        let target = (i as f64 + xi) * per_stratum;
        while j + 1 < bins && below + mj <= target {
            below += mj;
            j += 1;
            mj = mass(j);
            inv_mj = 1.0 / mj;
        }
        let frac = ((target - below) * inv_mj).clamp(0.0, 1.0);
        let (a, b) = (t[j] as f64, t[j + 1] as f64);
        // The clamp keeps rounding from crossing into the next bin, so the
        // output stays sorted.
        *o = (a + frac * (b - a)).clamp(a, b) as f32;
    }
}

/// Fine depths for a batch: `t` and `w` hold `n` coarse depths and weights
/// per ray, `out` receives `m` sorted fine depths per ray.
pub fn sample_pdf(
    t: &[f32],
    w: &[f32],
    n: usize,
    m: usize,
    spacing: Spacing,
    out: &mut [f32],
) -> Result<(), VolumeError> {
    if n < 2 || t.len() != w.len() || !t.len().is_multiple_of(n) || out.len() != t.len() / n * m {
        return Err(VolumeError::Invalid(format!(
            "sample_pdf: n={n} ≥ 2 coarse depths per ray, {} depths, {} weights, {} slots for m={m}",
            t.len(),
            w.len(),
            out.len()
        )));
    }
    if !t.par_chunks(n).all(check_depths) {
        return Err(VolumeError::Invalid(
            "sample_pdf: coarse depths must be finite and sorted per ray".into(),
        ));
    }
    if m == 0 {
        return Ok(());
    }
    out.par_chunks_mut(m)
        .zip(t.par_chunks(n).zip(w.par_chunks(n)))
        .enumerate()
        .with_min_len(64)
        .for_each(|(r, (o, (t, w)))| match spacing {
            Spacing::Even => sample_unchecked(t, w, None, o),
            Spacing::Jittered(seed) => {
                sample_unchecked(t, w, Some(&mut ray_rng(seed, r as u64)), o)
            }
        });
    Ok(())
}

/// Merges one ray's sorted `coarse` and `fine` depths into `out` (sorted;
/// on ties the coarse depth comes first). Panics unless `out` holds exactly
/// both (a caller bug; [`merge_depths`] checks its sizes).
pub fn merge_ray(coarse: &[f32], fine: &[f32], out: &mut [f32]) {
    assert_eq!(
        out.len(),
        coarse.len() + fine.len(),
        "merge_ray: output size"
    );
    let (mut i, mut j) = (0, 0);
    for o in out.iter_mut() {
        let take_coarse = j == fine.len() || (i < coarse.len() && coarse[i] <= fine[j]);
        if take_coarse {
            *o = coarse[i];
            i += 1;
        } else {
            *o = fine[j];
            j += 1;
        }
    }
}

/// The union of each ray's `n` coarse and `m` fine depths (both sorted per
/// ray), `n + m` sorted depths per ray into `out`: what the fine network
/// evaluates.
pub fn merge_depths(
    coarse: &[f32],
    n: usize,
    fine: &[f32],
    m: usize,
    out: &mut [f32],
) -> Result<(), VolumeError> {
    let rays = coarse.len().checked_div(n).unwrap_or(0);
    let ok = n > 0
        && coarse.len().is_multiple_of(n)
        && fine.len() == rays * m
        && out.len() == rays * (n + m);
    if !ok {
        return Err(VolumeError::Invalid(format!(
            "merge_depths: {} coarse (n={n}), {} fine (m={m}), {} slots",
            coarse.len(),
            fine.len(),
            out.len()
        )));
    }
    out.par_chunks_mut(n + m)
        .enumerate()
        .with_min_len(64)
        .for_each(|(r, o)| merge_ray(&coarse[r * n..][..n], &fine[r * m..][..m], o));
    Ok(())
}
