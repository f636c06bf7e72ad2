//! Shading effects that cost extra work, each computed only when a material
//! or a `render` asks for it: soft shadows and ambient occlusion (options of
//! the lit materials), fog and supersampling (options of a `render`).
//!
//! The formulas are written here once; the runtime marches the scene for
//! them (`runtime::effects`) through [`Surroundings`], which a material
//! calls only for the effects it has.

use glam::DVec3;

/// Soft shadows of a lit material: the classic penumbra estimate
/// `min over the shadow ray of k·h/t` (`h` the scene's distance at `t`
/// along the ray towards the light), clamped to 0..1.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SoftShadows {
    /// Hardness: larger is a narrower penumbra (`k·h/t`; > 0).
    pub k: f64,
    /// Most SDF evaluations of one shadow ray (≥ 1).
    pub steps: u32,
}

/// Ambient occlusion of a lit material: how much of the space along the
/// normal the scene fills, within `distance`. See [`occlusion`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct AmbientOcclusion {
    /// SDF evaluations along the normal (≥ 1).
    pub samples: u32,
    /// How far from the surface occluders count (> 0).
    pub distance: f64,
}

/// Exponential fog by distance along the ray: see [`Fog::apply`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Fog {
    /// The colour a ray fades to (linear RGB, 0..1).
    pub color: DVec3,
    /// Extinction per unit of distance (> 0): a ray keeps `exp(-density·t)`
    /// of the surface's colour.
    pub density: f64,
}

impl Fog {
    /// `fog + (c - fog)·exp(-density·t)`: the colour `c` seen through `t`
    /// units of fog. Misses are fogged as at the render's `far`.
    pub fn apply(&self, c: DVec3, t: f64) -> DVec3 {
        let keep = (-self.density * t.max(0.0)).exp();
        self.color + (c - self.color) * keep
    }
}

/// What shading may ask about the scene around the point being shaded. A
/// material asks only for the effects it has, so a scene without shadows
/// never marches a shadow ray.
pub trait Surroundings {
    /// The fraction (0..1) of a directional light reaching the point from
    /// unit direction `towards_light`, which faces the surface
    /// (`n·towards_light > 0`).
    fn light_visibility(&self, towards_light: DVec3, shadows: &SoftShadows) -> f64;
    /// The fraction (0..1) of ambient light reaching the point.
    fn ambient_visibility(&self, ao: &AmbientOcclusion) -> f64;
}

/// Nothing around: every light and all ambient light reach the point.
pub struct Open;

impl Surroundings for Open {
    fn light_visibility(&self, _: DVec3, _: &SoftShadows) -> f64 {
        1.0
    }
    fn ambient_visibility(&self, _: &AmbientOcclusion) -> f64 {
        1.0
    }
}

/// The height above the surface of sample `i` (from 0) of `ao`, and its
/// weight: `h_i = distance·(i + ½)/samples`, `w_i = 1 - h_i/distance`
/// (nearer occluders count more). Midpoints of equal slices, so more
/// samples converge to the integral of the same weighted occlusion.
pub fn occlusion_sample(ao: &AmbientOcclusion, i: u32) -> (f64, f64) {
    let h = ao.distance * (i as f64 + 0.5) / ao.samples as f64;
    (h, 1.0 - h / ao.distance)
}

/// Ambient visibility from the scene's distances `d_i` at `p + n·h_i`
/// ([`occlusion_sample`]): `1 - Σ w_i·clamp((h_i - d_i)/h_i, 0, 1) / Σ w_i`.
/// 1 where nothing is nearer than the surface itself (an open plane, any
/// convex shape), down to 0 where the space along the normal is filled.
pub fn occlusion(ao: &AmbientOcclusion, mut distance_at: impl FnMut(f64) -> f64) -> f64 {
    let (mut occluded, mut total) = (0.0, 0.0);
    for i in 0..ao.samples {
        let (h, w) = occlusion_sample(ao, i);
        let d = distance_at(h);
        // A NaN distance counts as open space.
        let o = ((h - d) / h).clamp(0.0, 1.0);
        if o.is_finite() {
            occluded += w * o;
        }
        total += w;
    }
    (1.0 - occluded / total).clamp(0.0, 1.0)
}

/// Most samples per pixel (16 × 16).
pub const MAX_SAMPLES_PER_PIXEL: u32 = 256;

/// Where the rays of a pixel pass, in pixel units from its centre (each
/// coordinate in -½..½), for `n = m²` samples: the `m × m` strata of the
/// pixel, stratum `(a, b)` holding the point `((a·m + b + ½)/n, (b·m + a +
/// ½)/n) - ½`. Every row and every column of the `n × n` fine grid holds
/// exactly one sample (a rotated grid, as RGSS for `n = 4`), so edges near
/// horizontal or vertical get `n` levels of coverage. Deterministic; one
/// sample is the pixel's centre.
pub fn subpixel_offsets(n: u32) -> Vec<(f64, f64)> {
    let m = (n as f64).sqrt().round() as u32;
    debug_assert_eq!(m * m, n, "samples per pixel must be a square");
    if m <= 1 {
        return vec![(0.0, 0.0)];
    }
    let nf = (m * m) as f64;
    let mut v = Vec::with_capacity(n as usize);
    for a in 0..m {
        for b in 0..m {
            let x = ((a * m + b) as f64 + 0.5) / nf - 0.5;
            let y = ((b * m + a) as f64 + 0.5) / nf - 0.5;
            v.push((x, y));
        }
    }
    v
}
