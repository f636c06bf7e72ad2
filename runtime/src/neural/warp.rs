//! How positions of an unbounded scene reach a NeRF's encoding: contracted
//! (mip-NeRF 360, [`super::contract`]) or in a forward-facing capture's
//! normalised device coordinates (the original NeRF's LLFF scenes).
//!
//! NDC here warps sample *positions*, with rays and depths kept in the
//! world: the field sees the NDC point of each sample, samples are spaced
//! evenly in NDC depth (evenly in disparity) as NeRF's NDC rays space
//! them, and density is integrated over world lengths. NeRF instead
//! integrates over the NDC ray's parameter; the two differ by a smooth
//! positive factor per point, which the learned density absorbs, and
//! world lengths keep depth outputs lengths along the ray (written in the
//! data's units, as every export is).

use sdfl_stdlib::value::{NdcFrame, Unbounded};

use super::contract::Contract;

/// An unbounded scene's map from world positions to the encoding's box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Warp {
    /// Scene contraction: the unbounded outside squashed into a shell.
    Contract(Contract),
    /// Forward-facing NDC of a reference camera.
    Ndc(Ndc),
}

impl Warp {
    /// The runtime's map for a spec; NDC needs its frame resolved from the
    /// capture first.
    pub fn new(u: &Unbounded) -> Result<Self, String> {
        match u {
            Unbounded::Contract(c) => Ok(Warp::Contract(Contract::new(c))),
            Unbounded::Ndc(Some(f)) => Ndc::new(f).map(Warp::Ndc),
            Unbounded::Ndc(None) => Err(
                "`unbounded: ndc()` takes its camera from a forward-facing capture, and none was read for this model"
                    .into(),
            ),
        }
    }

    /// A world point in the encoding's box.
    #[inline]
    pub fn apply(&self, p: [f32; 3]) -> [f32; 3] {
        match self {
            Warp::Contract(c) => c.apply(p),
            Warp::Ndc(n) => n.apply(p),
        }
    }

    /// Every row of 3 of `points` mapped into `out` (resized).
    pub fn apply_all(&self, points: &[f32], out: &mut Vec<f32>) {
        out.resize(points.len(), 0.0);
        for (o, p) in out.chunks_mut(3).zip(points.chunks(3)) {
            o.copy_from_slice(&self.apply([p[0], p[1], p[2]]));
        }
    }

    /// The box the hash grid and the occupancy grid cover.
    pub fn cube(&self) -> ([f64; 3], [f64; 3]) {
        match self {
            Warp::Contract(_) => ([-2.0; 3], [2.0; 3]),
            Warp::Ndc(_) => NDC_BOX,
        }
    }

    /// About how many units of the box a ray's samples span.
    pub fn span(&self) -> f64 {
        match self {
            Warp::Contract(_) => 3.0,
            Warp::Ndc(_) => 2.0,
        }
    }

    /// World length per unit of the box at a mapped point `y` (the inverse
    /// map's largest stretch), for an occupancy cell's opacity.
    pub fn world_per_unit(&self, y: [f32; 3]) -> f32 {
        match self {
            Warp::Contract(c) => c.world_per_contracted(y),
            Warp::Ndc(n) => n.world_per_unit(y),
        }
    }

    /// Stratified depths `t` on `[near, far]` moved to this map's spacing
    /// along the ray `o + t·d`, in order, appended to `out`.
    pub fn depths(
        &self,
        o: [f32; 3],
        d: [f32; 3],
        near: f64,
        far: f64,
        t: &[f32],
        out: &mut Vec<f32>,
    ) {
        match self {
            Warp::Contract(c) => c.depths(o, d, near, far, t, out),
            Warp::Ndc(n) => n.depths(o, d, near, far, t, out),
        }
    }
}

/// `spec` for its layout alone (parameter counts, tensors, memory), before
/// its data is read: an NDC camera not yet known stands in as a unit one,
/// which changes no size.
pub fn for_layout(
    spec: &sdfl_stdlib::value::Nerf,
) -> std::borrow::Cow<'_, sdfl_stdlib::value::Nerf> {
    match spec.unbounded {
        Some(Unbounded::Ndc(None)) => std::borrow::Cow::Owned(sdfl_stdlib::value::Nerf {
            unbounded: Some(Unbounded::Ndc(Some(NdcFrame {
                width: 2.0,
                height: 2.0,
                fx: 1.0,
                fy: 1.0,
                near: 1.0,
            }))),
            ..spec.clone()
        }),
        _ => std::borrow::Cow::Borrowed(spec),
    }
}

/// The box NDC's grids cover: depth from the near plane to infinity in z,
/// and half the image again around it in x and y, for the other cameras
/// of the capture, which see a little beyond the reference camera.
pub const NDC_BOX: ([f64; 3], [f64; 3]) = ([-1.5, -1.5, -1.0], [1.5, 1.5, 1.0]);

/// NDC of a reference camera at the origin looking down −z:
/// `(ax·x/z, ay·y/z, 1 + 2n/z)` with `ax = −2·fx/W`, `ay = −2·fy/H`, `n`
/// the near plane's depth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ndc {
    ax: f32,
    ay: f32,
    near: f32,
}

impl Ndc {
    /// The warp of `f`'s reference camera; an error for a degenerate focal length, image size or near plane.
    pub fn new(f: &NdcFrame) -> Result<Self, String> {
        let (ax, ay) = f.scales()?;
        Ok(Ndc {
            ax: ax as f32,
            ay: ay as f32,
            near: f.near as f32,
        })
    }

    /// The depth a point's z is held behind (NDC is singular at z = 0;
    /// points there, behind the reference camera's plane, map far outside
    /// the box, where the grids see nothing).
    fn z_of(&self, z: f32) -> f32 {
        z.min(-1e-3 * self.near)
    }

    /// The NDC of world point `p`.
    #[inline]
    pub fn apply(&self, p: [f32; 3]) -> [f32; 3] {
        let z = self.z_of(p[2]);
        [
            self.ax * p[0] / z,
            self.ay * p[1] / z,
            1.0 + 2.0 * self.near / z,
        ]
    }

    /// `∂(world)/∂(NDC)` at `y`, the largest of the three axes: along z
    /// `2n/(1 − z')²`, across `2n/((1 − z')·|a|)`; `1 − z'` held above 1e-3
    /// so the far face stays finite.
    pub fn world_per_unit(&self, y: [f32; 3]) -> f32 {
        let gap = (1.0 - y[2]).max(1e-3);
        let depth = 2.0 * self.near / gap;
        (depth / gap)
            .max(depth / self.ax.abs())
            .max(depth / self.ay.abs())
    }

    /// Depths along `o + t·d` whose points' NDC depth `z'` runs evenly
    /// from −1 (the near plane) to that of depth `far` (the sampler's
    /// `far`, as a distance in front of the reference camera), as the
    /// stratified `t` run from `near` to `far`; never behind the ray's
    /// origin. A ray not heading into the scene (`d.z ≥ 0`) gets every
    /// depth 0: its samples have no length and it sees the background.
    pub fn depths(
        &self,
        o: [f32; 3],
        d: [f32; 3],
        near: f64,
        far: f64,
        t: &[f32],
        out: &mut Vec<f32>,
    ) {
        let n = self.near as f64;
        let (oz, dz) = (o[2] as f64, d[2] as f64);
        // NaN directions too: they head nowhere.
        if dz.is_nan() || dz >= -1e-9 {
            out.extend(t.iter().map(|_| 0.0));
            return;
        }
        let z_far = 1.0 - 2.0 * n / far.max(n * (1.0 + 1e-6));
        let span = (far - near).max(f64::MIN_POSITIVE);
        out.extend(t.iter().map(|&tk| {
            let u = ((tk as f64 - near) / span).clamp(0.0, 1.0);
            let zn = -1.0 + u * (z_far + 1.0);
            let z = -2.0 * n / (1.0 - zn);
            ((z - oz) / dz).max(0.0) as f32
        }));
    }
}
