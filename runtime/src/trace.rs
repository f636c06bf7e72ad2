//! Sphere tracing and surface normals.

use glam::Vec3A;

use crate::lanes::{self, F8, LANES, P8};

/// What a ray marches: a signed distance (or bound) per point. Every
/// lowered scene node (`sdf::Node`) is one; a screen tile's candidate
/// members (`sdf::tiles::Tile`) are another. The tracer knows no scene
/// representation beyond these two traits.
pub trait Distance {
    /// The distance (or a lower bound on it) at `p`.
    fn dist(&self, p: Vec3A) -> f32;
}

/// A [`Distance`] that also evaluates whole packs of points at once, for
/// rays marched together ([`sphere_trace_packs`]).
pub trait PackedDistance: Distance {
    /// The distances at packs of [`LANES`] points, each lane equal to
    /// [`Distance::dist`] of its point.
    fn dist_packs(&self, p: &[P8], out: &mut [F8]);
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
///
/// The steps are those of [`March`], fed one distance at a time.
#[inline]
pub fn sphere_trace<D: Distance + ?Sized>(
    sdf: &D,
    origin: Vec3A,
    dir: Vec3A,
    s: &TraceSettings,
) -> Hit {
    let (mut march, mut step) = March::start(origin, dir, s);
    loop {
        match step {
            Step::At(p) => step = march.feed(sdf.dist(p)),
            Step::End(hit) => return hit,
        }
    }
}

/// What a [`March`] wants next.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Step {
    /// The distance at this point.
    At(Vec3A),
    /// Nothing: the ray ended here.
    End(Hit),
}

/// One ray's sphere trace (see [`sphere_trace`]) as a machine fed one
/// distance at a time: [`sphere_trace`] feeds it point by point, and
/// [`sphere_trace_packs`] feeds many rays' machines from one call of
/// [`PackedDistance::dist_packs`] per step. Both run these same steps on the same
/// distances, so they end alike.
#[derive(Debug, Clone, Copy)]
pub struct March {
    origin: Vec3A,
    dir: Vec3A,
    s: TraceSettings,
    inv_l: f32,
    scale: f32,
    omega: f32,
    t: f32,
    prev_t: f32,
    prev_r: f32,
    step_len: f32,
    /// The point that came closest relative to the pixel footprint.
    best_err: f32,
    best_t: f32,
    /// Steps of the march so far (the loop's counter).
    step: u32,
    /// Refining a hit (see [`March::refining`]): steps taken and distance.
    refine: Option<(u32, f32)>,
}

impl March {
    /// The march of the ray `origin + t·dir` with settings `s`, and its
    /// first step.
    #[inline(always)]
    pub fn start(origin: Vec3A, dir: Vec3A, s: &TraceSettings) -> (March, Step) {
        let t = s.near;
        let march = March {
            origin,
            dir,
            s: *s,
            inv_l: 1.0 / s.lipschitz,
            scale: origin.abs().max_element(),
            omega: if s.relax { OMEGA } else { 1.0 },
            t,
            prev_t: t,
            prev_r: 0.0,
            step_len: 0.0,
            best_err: f32::INFINITY,
            best_t: t,
            step: 0,
            refine: None,
        };
        let step = if s.max_steps == 0 {
            Step::End(march.out_of_steps())
        } else {
            Step::At(march.at_t())
        };
        (march, step)
    }

    #[inline(always)]
    fn at_t(&self) -> Vec3A {
        self.origin + self.dir * self.t
    }

    /// The next step of the march after the distance `d` at the point of
    /// its last step.
    #[inline(always)]
    #[allow(
        clippy::neg_cmp_op_on_partial_ord,
        reason = "a NaN distance must end the ray as a miss"
    )]
    pub fn feed(&mut self, d: f32) -> Step {
        if let Some((steps, r)) = self.refine {
            return self.refining(d, steps, r);
        }
        let s = &self.s;
        let (t, step) = (self.t, self.step);
        let r = d * self.inv_l;
        // A NaN or infinite distance (which valid scenes never produce)
        // ends as a miss rather than poisoning t.
        if !r.is_finite() && !(r < 0.0) {
            return Step::End(Hit {
                t: t.min(s.far),
                hit: false,
                steps: step + 1,
                undecided: false,
            });
        }
        if self.omega > 1.0 && step > 0 && r.abs() + self.prev_r < self.step_len {
            self.omega = 1.0;
            self.step_len = self.prev_r;
            self.t = self.prev_t + self.prev_r;
            return self.next_step();
        }
        let tolerance = s
            .epsilon
            .max(s.footprint * t)
            .max((self.scale + t) * PRECISION_TOLERANCE);
        if r < tolerance {
            // Plain steps from a hit decided at the pixel footprint towards
            // the surface, so depth and normals are as accurate as with the
            // absolute ε (see `March::refining`).
            return self.refine_from(0, r);
        }
        if s.footprint > 0.0 && r < self.best_err * t {
            (self.best_err, self.best_t) = (r / t.max(f32::MIN_POSITIVE), t);
        }
        (self.prev_t, self.prev_r) = (t, r);
        self.step_len = self.omega * r;
        self.t += self.step_len;
        if self.t > s.far {
            // A relaxed step past `far` may have leapt over a surface just
            // before it: take the plain step instead, unrelaxed from here.
            if self.omega > 1.0 && self.prev_t + self.prev_r <= s.far {
                self.omega = 1.0;
                (self.t, self.step_len) = (self.prev_t + self.prev_r, self.prev_r);
                return self.next_step();
            }
            return Step::End(Hit {
                t: s.far,
                hit: false,
                steps: step + 1,
                undecided: false,
            });
        }
        self.next_step()
    }

    /// The march's next step, or its end when its steps ran out.
    #[inline(always)]
    fn next_step(&mut self) -> Step {
        self.step += 1;
        if self.step < self.s.max_steps {
            Step::At(self.at_t())
        } else {
            Step::End(self.out_of_steps())
        }
    }

    /// Out of steps: a ray that came within two footprints of a surface
    /// (creeping along it at a grazing angle) is decided at pixel
    /// resolution as a hit there; any other is undecided.
    #[inline(always)]
    fn out_of_steps(&self) -> Hit {
        let s = &self.s;
        if self.best_err < 2.0 * s.footprint {
            return Hit {
                t: self.best_t,
                hit: true,
                steps: s.max_steps,
                undecided: false,
            };
        }
        Hit {
            t: self.t.min(s.far),
            hit: false,
            steps: s.max_steps,
            undecided: true,
        }
    }

    /// The refinement of a hit at `t` with distance `r` after `steps` of
    /// its steps: another step towards the surface while `r ≥ epsilon` and
    /// fewer than [`REFINE_STEPS`] were taken, else the hit.
    #[inline(always)]
    fn refine_from(&mut self, steps: u32, r: f32) -> Step {
        if r >= self.s.epsilon && steps < REFINE_STEPS {
            self.refine = Some((steps, r));
            Step::At(self.origin + self.dir * (self.t + r))
        } else {
            Step::End(Hit {
                t: self.t,
                hit: true,
                steps: self.step + 1 + steps,
                undecided: false,
            })
        }
    }

    /// A refinement step's distance `d`: it stops where the distance stops
    /// shrinking (a ray grazing past keeps its footprint hit), at most
    /// [`REFINE_STEPS`] steps, below `epsilon`.
    #[inline(always)]
    #[allow(
        clippy::neg_cmp_op_on_partial_ord,
        reason = "a NaN distance must stop the refinement"
    )]
    fn refining(&mut self, d: f32, steps: u32, r: f32) -> Step {
        let next = d * self.inv_l;
        let steps = steps + 1;
        if !(next < r) {
            return Step::End(Hit {
                t: self.t,
                hit: true,
                steps: self.step + 1 + steps,
                undecided: false,
            });
        }
        self.t += r;
        self.refine_from(steps, next)
    }
}

/// Rays marched together: `rays` are started marches ([`March::start`]);
/// each step gathers the points of the rays still marching into packs and
/// takes their distances from one [`PackedDistance::dist_packs`] call
/// (each lane equal to [`Distance::dist`] of its point, so every ray ends
/// as [`sphere_trace`] ends it). Returns each ray's end, in order.
pub fn sphere_trace_packs<N: PackedDistance + ?Sized>(
    sdf: &N,
    rays: Vec<(March, Step)>,
) -> Vec<Hit> {
    let mut hits = vec![
        Hit {
            t: 0.0,
            hit: false,
            steps: 0,
            undecided: false,
        };
        rays.len()
    ];
    // The marching rays: their index, machine and next point.
    let mut live = Vec::with_capacity(rays.len());
    for (k, (march, step)) in rays.into_iter().enumerate() {
        match step {
            Step::At(p) => live.push((k, march, p)),
            Step::End(h) => hits[k] = h,
        }
    }
    let mut packs = Vec::with_capacity(live.len().div_ceil(LANES));
    let mut dists = Vec::with_capacity(packs.capacity());
    let mut points = [Vec3A::ZERO; LANES];
    while !live.is_empty() {
        packs.clear();
        for chunk in live.chunks(LANES) {
            for (q, (_, _, p)) in points.iter_mut().zip(chunk) {
                *q = *p;
            }
            packs.push(lanes::pack(&points[..chunk.len()]));
        }
        dists.resize(packs.len(), F8::splat(0.0));
        sdf.dist_packs(&packs, &mut dists);
        let mut j = 0;
        live.retain_mut(|(k, march, p)| {
            let d = dists[j / LANES].0[j % LANES];
            j += 1;
            match march.feed(d) {
                Step::At(q) => {
                    *p = q;
                    true
                }
                Step::End(h) => {
                    hits[*k] = h;
                    false
                }
            }
        });
    }
    hits
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
