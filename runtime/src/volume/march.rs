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
