//! Shadow rays and ambient occlusion marched through the lowered scene, for
//! the materials that ask for them (`stdlib::effects` holds the formulas
//! and the [`Surroundings`] a material asks), with counters that show what
//! was computed.

use std::cell::Cell;

use glam::{DVec3, Vec3A};
use sdfl_stdlib::effects::{occlusion, AmbientOcclusion, SoftShadows, Surroundings};
use serde::Serialize;

use crate::sdf::Node;

/// What the effects cost in one render: counted, so tests can prove that a
/// scene without shadows never marches a shadow ray.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct EffectStats {
    /// Shadow rays marched (one per shaded sample and light facing it).
    pub shadow_rays: u64,
    /// SDF evaluations along shadow rays.
    pub shadow_steps: u64,
    /// SDF evaluations for ambient occlusion.
    pub occlusion_samples: u64,
}

impl std::ops::AddAssign for EffectStats {
    fn add_assign(&mut self, o: Self) {
        self.shadow_rays += o.shadow_rays;
        self.shadow_steps += o.shadow_steps;
        self.occlusion_samples += o.occlusion_samples;
    }
}

/// The counters of one thread's work.
#[derive(Default)]
pub struct Counters {
    shadow_rays: Cell<u64>,
    shadow_steps: Cell<u64>,
    occlusion_samples: Cell<u64>,
}

impl Counters {
    /// The totals so far.
    pub fn stats(&self) -> EffectStats {
        EffectStats {
            shadow_rays: self.shadow_rays.get(),
            shadow_steps: self.shadow_steps.get(),
            occlusion_samples: self.occlusion_samples.get(),
        }
    }
}

/// The scene around one shaded surface point.
pub struct SurfacePoint<'a> {
    /// The scene's distance field.
    pub sdf: &'a dyn Node,
    /// `1 / L`, `L` the scene's Lipschitz bound: distances are scaled by it,
    /// so bound SDFs never overstate the free space.
    pub inv_lipschitz: f32,
    /// The hit point and its unit normal.
    pub p: Vec3A,
    /// The unit normal at `p`.
    pub n: Vec3A,
    /// Where shadow rays give up (the render's `far`).
    pub far: f32,
    /// The hit tolerance of the primary ray (its `epsilon`).
    pub epsilon: f32,
    /// Half a pixel's width at the point (0 with an absolute hit
    /// tolerance): shadow rays start and step at least this far, since
    /// finer detail is not resolved in the image.
    pub pixel: f32,
    /// Where the work is counted.
    pub counters: &'a Counters,
}

impl SurfacePoint<'_> {
    /// How far above the surface shadow rays start, along the normal: a few
    /// times the hit tolerance and f32's resolution at `p`, so a ray
    /// starting on a surface never finds that surface (no acne), at any
    /// distance from the origin.
    pub fn bias(&self) -> f32 {
        let scale = 1.0 + self.p.abs().max_element();
        (16.0 * self.epsilon).max(16.0 * f32::EPSILON * scale)
    }
}

/// The classic soft shadow: from `origin`, march towards the light at
/// `t = min_step, …` (steps `max(h, min_step)`, `h` the distance scaled by
/// `inv_l`), keeping `min(k·h/t)`; stop in full shadow (≤ 1e-3), past
/// `far`, or after `steps` evaluations. Returns the visible fraction in
/// 0..1 (never NaN) and the evaluations made.
#[allow(clippy::too_many_arguments)]
pub fn soft_shadow(
    sdf: &dyn Node,
    inv_l: f32,
    origin: Vec3A,
    towards_light: Vec3A,
    min_step: f32,
    far: f32,
    s: &SoftShadows,
) -> (f32, u32) {
    let k = s.k as f32;
    let mut t = min_step;
    let mut visible = 1.0f32;
    for step in 0..s.steps {
        let h = sdf.dist(origin + towards_light * t) * inv_l;
        if h.is_nan() {
            return (visible.clamp(0.0, 1.0), step + 1);
        }
        visible = visible.min(k * h / t);
        if visible <= 1e-3 {
            return (0.0, step + 1);
        }
        t += h.max(min_step);
        if t > far {
            return (visible.clamp(0.0, 1.0), step + 1);
        }
    }
    (visible.clamp(0.0, 1.0), s.steps)
}

impl Surroundings for SurfacePoint<'_> {
    fn light_visibility(&self, towards_light: DVec3, s: &SoftShadows) -> f64 {
        let bias = self.bias();
        let origin = self.p + self.n * bias;
        let l: Vec3A = towards_light.as_vec3().into();
        let (v, steps) = soft_shadow(
            self.sdf,
            self.inv_lipschitz,
            origin,
            l,
            bias.max(self.pixel),
            self.far,
            s,
        );
        let c = self.counters;
        c.shadow_rays.set(c.shadow_rays.get() + 1);
        c.shadow_steps.set(c.shadow_steps.get() + steps as u64);
        v as f64
    }

    fn ambient_visibility(&self, ao: &AmbientOcclusion) -> f64 {
        let c = self.counters;
        c.occlusion_samples
            .set(c.occlusion_samples.get() + ao.samples as u64);
        occlusion(ao, |h| {
            (self.sdf.dist(self.p + self.n * h as f32) * self.inv_lipschitz) as f64
        })
    }
}
