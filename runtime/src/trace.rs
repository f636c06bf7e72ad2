//! Sphere tracing and surface normals.

use glam::Vec3A;

use crate::sdf::Node;

/// What a ray marches: a signed distance (or bound) per point. Every
/// lowered [`Node`] is one; a screen tile's candidate members
/// (`sdf::tiles::Tile`) are another.
pub trait Distance {
    /// The distance (or a lower bound on it) at `p`.
    fn dist(&self, p: Vec3A) -> f32;
}

impl<T: Node + ?Sized> Distance for T {
    #[inline(always)]
    fn dist(&self, p: Vec3A) -> f32 {
        Node::dist(self, p)
    }
}

/// Settings of one trace.
#[derive(Debug, Clone, Copy)]
pub struct TraceSettings {
    /// Where rays start.
    pub near: f32,
    /// Where rays give up: farther is a miss.
    pub far: f32,
    /// Most steps per ray.
    pub max_steps: u32,
    /// A ray hits where the distance falls below `max(epsilon, footprint·t)`.
    pub epsilon: f32,
    /// Half a pixel's width per unit of distance (0: the absolute `epsilon`
    /// only): a hit is decided at the resolution of the image, so rays
    /// grazing a surface end instead of creeping along it.
    pub footprint: f32,
    /// Over-relaxed steps (ω = 1.6), falling back to plain steps where the
    /// bounding spheres of two steps stop overlapping.
    pub relax: bool,
    /// Lipschitz bound of the SDF: steps are `d / lipschitz`, so bound SDFs
    /// with a steeper gradient never step through thin parts.
    pub lipschitz: f32,
}

/// Where a ray ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter at the end (finite).
    pub t: f32,
    /// Whether the ray hit a surface.
    pub hit: bool,
    /// Steps taken.
    pub steps: u32,
    /// The steps ran out before the ray hit or passed `far`.
    pub undecided: bool,
}

/// The over-relaxation factor of relaxed tracing.
const OMEGA: f32 = 1.6;

/// The smallest hit tolerance per unit of coordinate size (2⁻²¹, 4 to 8
/// ulps): an f32 distance at coordinates of size `m` is rounded by a few
/// ulps of `m`, and a step below an ulp of `t` does not move the ray, so a
/// tolerance below `m·2⁻²¹` would be met only by chance (the ray stalls
/// and its steps run out). Below `m` = 20 it is under the default
/// `epsilon` (1e-5), so scenes near the origin trace as before.
pub(crate) const PRECISION_TOLERANCE: f32 = 1.0 / 2_097_152.0;

/// March from `near` until the distance is below the hit tolerance (a hit,
/// also when the ray starts inside a shape; the tolerance is
/// `max(epsilon, footprint·t)`, and at least what f32 resolves at the
/// point's coordinates, `PRECISION_TOLERANCE`), `t` passes `far`, or the steps
/// run out: then, with a pixel footprint, a ray that came within two
/// footprints of a surface hits where it came closest, and any other is an
/// undecided miss. Always returns finite values within `max_steps` steps.
///
/// Relaxed steps are `ω·d`; where the sphere of radius `d` around the new
/// point and the previous one do not overlap, the step may have skipped a
/// surface, so the trace returns to the previous point and steps `d` from
/// there, unrelaxed for the rest of the ray (enhanced sphere tracing).
#[inline]
#[allow(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "a NaN distance must end the ray as a miss"
)]
pub fn sphere_trace<D: Distance + ?Sized>(
    sdf: &D,
    origin: Vec3A,
    dir: Vec3A,
    s: &TraceSettings,
) -> Hit {
    let inv_l = 1.0 / s.lipschitz;
    let scale = origin.abs().max_element();
    let mut omega = if s.relax { OMEGA } else { 1.0 };
    let mut t = s.near;
    let (mut prev_t, mut prev_r, mut step_len) = (t, 0.0f32, 0.0f32);
    // The point that came closest relative to the pixel footprint.
    let (mut best_err, mut best_t) = (f32::INFINITY, t);
    for step in 0..s.max_steps {
        let r = sdf.dist(origin + dir * t) * inv_l;
        // A NaN or infinite distance (which valid scenes never produce)
        // ends as a miss rather than poisoning t.
        if !r.is_finite() && !(r < 0.0) {
            return Hit {
                t: t.min(s.far),
                hit: false,
                steps: step + 1,
                undecided: false,
            };
        }
        if omega > 1.0 && step > 0 && r.abs() + prev_r < step_len {
            omega = 1.0;
            step_len = prev_r;
            t = prev_t + prev_r;
            continue;
        }
        let tolerance = s
            .epsilon
            .max(s.footprint * t)
            .max((scale + t) * PRECISION_TOLERANCE);
        if r < tolerance {
            let (t, extra) = refine(sdf, origin, dir, t, r, inv_l, s.epsilon);
            return Hit {
                t,
                hit: true,
                steps: step + 1 + extra,
                undecided: false,
            };
        }
        if s.footprint > 0.0 && r < best_err * t {
            (best_err, best_t) = (r / t.max(f32::MIN_POSITIVE), t);
        }
        (prev_t, prev_r) = (t, r);
        step_len = omega * r;
        t += step_len;
        if t > s.far {
            // A relaxed step past `far` may have leapt over a surface just
            // before it: take the plain step instead, unrelaxed from here.
            if omega > 1.0 && prev_t + prev_r <= s.far {
                omega = 1.0;
                (t, step_len) = (prev_t + prev_r, prev_r);
                continue;
            }
            return Hit {
                t: s.far,
                hit: false,
                steps: step + 1,
                undecided: false,
            };
        }
    }
    // Out of steps: a ray that came within two footprints of a surface
    // (creeping along it at a grazing angle) is decided at pixel resolution
    // as a hit there; any other is undecided.
    if best_err < 2.0 * s.footprint {
        return Hit {
            t: best_t,
            hit: true,
            steps: s.max_steps,
            undecided: false,
        };
    }
    Hit {
        t: t.min(s.far),
        hit: false,
        steps: s.max_steps,
        undecided: true,
    }
}

/// Plain steps from a hit decided at the pixel footprint towards the
/// surface, so depth and normals are as accurate as with the absolute ε:
/// at most [`REFINE_STEPS`], stopping below `epsilon` or where the distance
/// stops shrinking (a ray grazing past keeps its footprint hit). Returns the
/// refined `t` and the steps taken.
#[allow(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "a NaN distance must stop the refinement"
)]
fn refine<D: Distance + ?Sized>(
    sdf: &D,
    origin: Vec3A,
    dir: Vec3A,
    mut t: f32,
    mut r: f32,
    inv_l: f32,
    epsilon: f32,
) -> (f32, u32) {
    let mut steps = 0;
    while r >= epsilon && steps < REFINE_STEPS {
        let next = sdf.dist(origin + dir * (t + r)) * inv_l;
        steps += 1;
        if !(next < r) {
            break;
        }
        (t, r) = (t + r, next);
    }
    (t, steps)
}

/// Most refinement steps after a footprint hit.
const REFINE_STEPS: u32 = 16;

/// The finite-difference step of [`normal`] at `p`: 5e-4, or more where
/// coordinates are so large that f32 rounds the distance by more than a
/// small fraction of the step (`|p|·2⁻¹⁴`, about 4 000 ulps of `|p|`: the
/// rounding of each sample tilts the normal by at most ~1e-3). Below
/// |p| ≈ 8 it is the fixed step the images have always used.
#[inline]
pub fn normal_step(p: Vec3A) -> f32 {
    NORMAL_STEP.max(p.abs().max_element() * NORMAL_STEP_PER_UNIT)
}

/// The finite-difference step of normals near the origin.
pub const NORMAL_STEP: f32 = 5e-4;
/// The step's growth with the coordinates' size (2⁻¹⁴).
const NORMAL_STEP_PER_UNIT: f32 = 1.0 / 16384.0;

/// Unit surface normal at `p` by tetrahedral central differences. Where the
/// gradient vanishes or is undefined (a sphere's centre, symmetric points
/// inside a box) it returns `fallback`, so it is never NaN.
pub fn normal<D: Distance + ?Sized>(sdf: &D, p: Vec3A, h: f32, fallback: Vec3A) -> Vec3A {
    const K: [Vec3A; 4] = [
        Vec3A::new(1.0, -1.0, -1.0),
        Vec3A::new(-1.0, -1.0, 1.0),
        Vec3A::new(-1.0, 1.0, -1.0),
        Vec3A::new(1.0, 1.0, 1.0),
    ];
    let g = K
        .iter()
        .fold(Vec3A::ZERO, |acc, k| acc + *k * sdf.dist(p + *k * h));
    let len = g.length();
    if len.is_finite() && len > 1e-12 {
        g / len
    } else {
        fallback
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sdf::{LowerOptions, Lowered};
    use sdfl_stdlib::param::Arg;
    use sdfl_stdlib::shape::Shape;

    /// A relaxed step from the camera can pass `far` although the surface is
    /// nearer: the ray must still find it (it was a miss once).
    #[test]
    fn relaxed_steps_never_leap_past_far_over_a_surface() {
        let torus: Shape = sdfl_stdlib::shape::Torus {
            center: Arg::fixed(glam::DVec3::ZERO),
            major: Arg::fixed(1.0),
            minor: Arg::fixed(0.3),
            axis: sdfl_stdlib::sdf::Axis::Z,
        }
        .into();
        let scene = Lowered::new(&torus, LowerOptions::default());
        let origin = Vec3A::new(0.0, 0.0, -4.0);
        for far in [4.0f32, 5.0, 10.0] {
            for relax in [false, true] {
                let s = TraceSettings {
                    near: 0.0,
                    far,
                    max_steps: 64,
                    epsilon: 1e-5,
                    footprint: 1e-3,
                    relax,
                    lipschitz: 1.0,
                };
                // Towards the ring: it is 3.7 to 4.3 away.
                let dir = Vec3A::new(1.0, 0.0, 4.0).normalize();
                let hit = sphere_trace(&*scene.root, origin, dir, &s);
                assert!(hit.hit, "far {far}, relaxed {relax}: {hit:?}");
                let p = origin + dir * hit.t;
                assert!(scene.dist(p).abs() < 1e-3, "far {far}: off the surface");
                // Through the hole: a miss, decided.
                let hit = sphere_trace(&*scene.root, origin, Vec3A::Z, &s);
                assert!(!hit.hit && !hit.undecided && hit.t.is_finite());
            }
        }
    }
}
