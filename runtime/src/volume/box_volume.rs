//! The assignment's SDF-as-volume box ("sdf_volume"): box SDF → opacity
//! `α·Ψ_β(−sdf)` → compositing → rainbow colour, with a hand-written fused
//! forward/backward pass parallelised over rays with rayon.
//!
//! This is the fast path of the box fit. [`crate::train::box_graph`] builds the
//! same computation as a dfdx graph; tests check the two against each other and
//! against finite differences of an f64 reference.

use num_traits::Float;
use rayon::prelude::*;
use sdfl_stdlib::camera::Camera;

use super::composite::Composite;
use super::density::sdf_opacity_parts_inv;
use super::rays::{for_each_ray_chunk, ImageSize, Ray, Stratified};
use super::shapes::{box_sdf_grad, rainbow_grad};
use super::VolumeError;

/// A box rendered as the assignment's SDF volume.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxVolume {
    pub center: [f32; 3],
    /// Full side lengths.
    pub sides: [f32; 3],
    /// Opacity scale, `0 < α ≤ 1`.
    pub alpha: f32,
    /// Laplace scale β > 0.
    pub beta: f32,
}

impl BoxVolume {
    /// Validates the parameters (finite, `sides > 0`, `0 < α ≤ 1`, `β > 0`).
    pub fn new(
        center: [f32; 3],
        sides: [f32; 3],
        alpha: f32,
        beta: f32,
    ) -> Result<Self, VolumeError> {
        let v = BoxVolume {
            center,
            sides,
            alpha,
            beta,
        };
        v.validate()?;
        Ok(v)
    }

    pub fn validate(&self) -> Result<(), VolumeError> {
        if !self.center.iter().chain(&self.sides).all(|v| v.is_finite()) {
            return Err(VolumeError::Invalid("box parameters must be finite".into()));
        }
        if !self.sides.iter().all(|&s| s > 0.0) {
            return Err(VolumeError::Invalid("box sides must be positive".into()));
        }
        if !(self.alpha > 0.0 && self.alpha <= 1.0) {
            return Err(VolumeError::Invalid(format!(
                "opacity scale α must be in (0, 1], got {}",
                self.alpha
            )));
        }
        if !(self.beta > 0.0 && self.beta.is_finite()) {
            return Err(VolumeError::Invalid(format!(
                "β must be positive, got {}",
                self.beta
            )));
        }
        Ok(())
    }
}

/// Gradient of a loss with respect to the box's centre and sides.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BoxGrad<F> {
    pub center: [F; 3],
    pub sides: [F; 3],
}

/// Per-sample values the backward pass reuses.
#[derive(Debug, Clone, Copy, Default)]
struct SampleCache<F> {
    trans: F,
    w: F,
    col: [F; 3],
    dcol_dc: [F; 3],
    dsdf_dp: [F; 3],
    dsdf_ds: [F; 3],
    do_dsdf: F,
    dl_dsdf: F,
}

/// Box volume parameters in the working precision of the generic kernel.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Params<F> {
    pub center: [F; 3],
    pub sides: [F; 3],
    pub alpha: F,
    pub beta: F,
}

impl<F: Float> Params<F> {
    pub(crate) fn from_volume(v: &BoxVolume) -> Self {
        let c = |x: f32| F::from(x).unwrap();
        Params {
            center: v.center.map(c),
            sides: v.sides.map(c),
            alpha: c(v.alpha),
            beta: c(v.beta),
        }
    }
}

/// Forward pass of one ray; fills `cache` and returns the composite and the
/// number of samples used. Transmittance is the running product of the kept
/// fractions `1 − o` (computed without cancellation, see
/// [`crate::volume::density::sdf_opacity_parts`]); once it is exactly 0 every later weight and every
/// later gradient term is exactly 0 too, so the march stops there.
/// With `CACHE = false` (rendering) nothing is stored.
fn ray_forward<F: Float + Default, const CACHE: bool>(
    p: &Params<F>,
    t: &[F],
    o: [F; 3],
    d: [F; 3],
    cache: &mut [SampleCache<F>],
) -> (Composite<F>, usize) {
    let mut trans = F::one();
    let mut colour = [F::zero(); 3];
    let mut depth = F::zero();
    let mut acc = F::zero();
    let mut used = 0;
    let inv_beta = F::one() / p.beta;
    for (k, &tk) in t.iter().enumerate() {
        if trans == F::zero() {
            break;
        }
        let x = [o[0] + tk * d[0], o[1] + tk * d[1], o[2] + tk * d[2]];
        let g = box_sdf_grad(x, p.center, p.sides);
        let op = sdf_opacity_parts_inv(g.sdf, p.alpha, inv_beta);
        let (col, dcol_dc) = rainbow_grad(x, p.center);
        let w = trans * op.opacity;
        for i in 0..3 {
            colour[i] = colour[i] + w * col[i];
        }
        depth = depth + w * tk;
        acc = acc + w;
        if CACHE {
            cache[k] = SampleCache {
                trans,
                w,
                col,
                dcol_dc,
                dsdf_dp: g.d_p,
                dsdf_ds: g.d_s,
                do_dsdf: op.d_opacity,
                dl_dsdf: op.d_log_keep,
            };
        }
        trans = trans * op.keep;
        used = k + 1;
    }
    (
        Composite {
            colour,
            depth,
            opacity: acc,
        },
        used,
    )
}

/// Backward pass of one ray given `g = ∂L/∂colour`; accumulates into `grad`.
///
/// With `a_k = g·c_k`: `∂L/∂o_j = T_j a_j`, `∂L/∂ln(1−o_j) = Σ_{k>j} a_k w_k`
/// (every later weight carries the factor `exp(ln(1−o_j))`), and
/// `∂L/∂c_j = g w_j`; the chain then goes through the SDF and the colour.
#[allow(clippy::needless_range_loop)] // indexes five arrays in step
fn ray_backward<F: Float>(g: [F; 3], cache: &[SampleCache<F>], grad: &mut BoxGrad<F>) {
    let mut suffix = F::zero();
    for s in cache.iter().rev() {
        let a = g[0] * s.col[0] + g[1] * s.col[1] + g[2] * s.col[2];
        let dloss_dsdf = s.trans * a * s.do_dsdf + suffix * s.dl_dsdf;
        for i in 0..3 {
            grad.center[i] = grad.center[i] - dloss_dsdf * s.dsdf_dp[i] + s.w * g[i] * s.dcol_dc[i];
            grad.sides[i] = grad.sides[i] + dloss_dsdf * s.dsdf_ds[i];
        }
        suffix = suffix + a * s.w;
    }
}

/// MSE loss (mean over rays and channels) and its gradient for a batch of
/// rays with target colours, all rays sampled at the same depths `t`.
pub(crate) fn loss_and_grad_generic<F: Float + Default + Send + Sync>(
    p: &Params<F>,
    t: &[F],
    rays: &[Ray],
    targets: &[[f32; 3]],
) -> (F, BoxGrad<F>) {
    const CHUNK: usize = 64;
    let n = rays.len();
    let scale = F::one() / F::from(3 * n.max(1)).unwrap();
    let two = F::from(2.0).unwrap();
    let cv = |x: f32| F::from(x).unwrap();
    rays.par_chunks(CHUNK)
        .zip(targets.par_chunks(CHUNK))
        .map(|(rs, ts)| {
            let mut cache = vec![SampleCache::default(); t.len()];
            let mut grad = BoxGrad::default();
            let mut loss = F::zero();
            for (r, tgt) in rs.iter().zip(ts) {
                let (c, used) =
                    ray_forward::<F, true>(p, t, r.origin.map(cv), r.dir.map(cv), &mut cache);
                let mut g = [F::zero(); 3];
                for i in 0..3 {
                    let e = c.colour[i] - cv(tgt[i]);
                    loss = loss + e * e * scale;
                    g[i] = two * e * scale;
                }
                ray_backward(g, &cache[..used], &mut grad);
            }
            (loss, grad)
        })
        .reduce(
            || (F::zero(), BoxGrad::default()),
            |(la, ga), (lb, gb)| {
                let mut g = ga;
                for i in 0..3 {
                    g.center[i] = g.center[i] + gb.center[i];
                    g.sides[i] = g.sides[i] + gb.sides[i];
                }
                (la + lb, g)
            },
        )
}

/// Gradient of `Σ_r g_r · colour_r` with respect to centre and sides, given
/// `g_r = ∂L/∂colour_r` for each ray (the backward of a colour op inside a
/// larger graph). Recomputes each ray's forward pass, so no per-sample state
/// outlives a ray.
pub(crate) fn colour_backward_generic<F: Float + Default + Send + Sync>(
    p: &Params<F>,
    t: &[F],
    rays: &[Ray],
    g: &[[F; 3]],
) -> BoxGrad<F> {
    const CHUNK: usize = 64;
    let cv = |x: f32| F::from(x).unwrap();
    rays.par_chunks(CHUNK)
        .zip(g.par_chunks(CHUNK))
        .map(|(rs, gs)| {
            let mut cache = vec![SampleCache::default(); t.len()];
            let mut grad = BoxGrad::default();
            for (r, gr) in rs.iter().zip(gs) {
                let (_, used) =
                    ray_forward::<F, true>(p, t, r.origin.map(cv), r.dir.map(cv), &mut cache);
                ray_backward(*gr, &cache[..used], &mut grad);
            }
            grad
        })
        .reduce(BoxGrad::default, |a, b| {
            let mut g = a;
            for i in 0..3 {
                g.center[i] = g.center[i] + b.center[i];
                g.sides[i] = g.sides[i] + b.sides[i];
            }
            g
        })
}

/// MSE loss and its exact gradient with respect to centre and sides, for
/// `rays` with `targets` (one colour per ray), sampled at `sampler`'s
/// linspace depths. Fused f32 kernel, parallel over rays.
pub fn box_loss_and_grad(
    vol: &BoxVolume,
    sampler: &Stratified,
    rays: &[Ray],
    targets: &[[f32; 3]],
) -> Result<(f32, BoxGrad<f32>), VolumeError> {
    vol.validate()?;
    sampler.validate()?;
    if rays.len() != targets.len() {
        return Err(VolumeError::Invalid(format!(
            "{} rays but {} target colours",
            rays.len(),
            targets.len()
        )));
    }
    let t = sampler.depths();
    Ok(loss_and_grad_generic(
        &Params::from_volume(vol),
        &t,
        rays,
        targets,
    ))
}

/// Composite (colour, depth, accumulated opacity) of each ray.
pub fn render_box_rays(
    vol: &BoxVolume,
    sampler: &Stratified,
    rays: &[Ray],
) -> Result<Vec<Composite<f32>>, VolumeError> {
    vol.validate()?;
    sampler.validate()?;
    let t = sampler.depths();
    let p = Params::from_volume(vol);
    Ok(rays
        .par_chunks(256)
        .flat_map_iter(|rs| {
            rs.iter()
                .map(|r| ray_forward::<f32, false>(&p, &t, r.origin, r.dir, &mut []).0)
                .collect::<Vec<_>>()
        })
        .collect())
}

/// A rendered image: row-major from the top-left pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedImage {
    pub size: ImageSize,
    pub colour: Vec<[f32; 3]>,
    pub depth: Vec<f32>,
}

/// Renders a full image of the box volume, chunked over rays (memory beyond
/// the image is O(chunk)).
pub fn render_box_image(
    vol: &BoxVolume,
    sampler: &Stratified,
    cam: &Camera,
    size: ImageSize,
) -> Result<RenderedImage, VolumeError> {
    vol.validate()?;
    sampler.validate()?;
    let t = sampler.depths();
    let p = Params::from_volume(vol);
    let mut out = vec![
        Composite {
            colour: [0f32; 3],
            depth: 0.0,
            opacity: 0.0
        };
        size.pixels()
    ];
    for_each_ray_chunk(cam, size, 1024, &mut out, |rays, o| {
        for (r, c) in rays.iter().zip(o) {
            *c = ray_forward::<f32, false>(&p, &t, r.origin, r.dir, &mut []).0;
        }
        Ok(())
    })?;
    Ok(RenderedImage {
        size,
        colour: out.iter().map(|c| c.colour).collect(),
        depth: out.iter().map(|c| c.depth).collect(),
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::volume::rays::{random_rays, SplitMix64};
    use glam::DVec3;

    /// Independent f64 reference of the MSE loss: textbook two-branch Ψ,
    /// product-form transmittance, formula-transcribed box SDF.
    pub(crate) fn reference_loss(
        c: [f64; 3],
        s: [f64; 3],
        alpha: f64,
        beta: f64,
        t: &[f64],
        rays: &[Ray],
        targets: &[[f32; 3]],
    ) -> f64 {
        let mut loss = 0.0;
        for (r, tgt) in rays.iter().zip(targets) {
            let mut trans = 1.0;
            let mut col = [0.0; 3];
            for &tk in t {
                let x: Vec<f64> = (0..3)
                    .map(|i| r.origin[i] as f64 + tk * r.dir[i] as f64)
                    .collect();
                let q: Vec<f64> = (0..3).map(|i| (x[i] - c[i]).abs() - s[i] / 2.0).collect();
                let sdf = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt()
                    + q[0].max(q[1]).max(q[2]).min(0.0);
                let psi = if -sdf <= 0.0 {
                    0.5 * (-sdf / beta).exp()
                } else {
                    1.0 - 0.5 * (sdf / beta).exp()
                };
                let o = alpha * psi;
                for i in 0..3 {
                    col[i] += trans * o * (x[i] - c[i]).abs().clamp(0.02, 0.98);
                }
                trans *= 1.0 - o;
            }
            for i in 0..3 {
                loss += (col[i] - tgt[i] as f64).powi(2);
            }
        }
        loss / (3 * rays.len()) as f64
    }

    pub(crate) fn target_cams() -> Vec<Camera> {
        crate::train::box_fit::assignment_cameras()
    }

    /// A small batch of rays with targets rendered from a different box.
    pub(crate) fn batch(count: usize) -> (Vec<Ray>, Vec<[f32; 3]>) {
        let size = ImageSize {
            width: 32,
            height: 32,
        };
        let rays = random_rays(&target_cams(), size, count, &mut SplitMix64::new(11)).unwrap();
        let target = BoxVolume::new([0.25, 0.25, 0.0], [2.0, 1.5, 1.5], 1.0, 0.05).unwrap();
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        let tg = render_box_rays(&target, &s, &rays).unwrap();
        (rays, tg.iter().map(|c| c.colour).collect())
    }

    #[test]
    fn forward_matches_f64_reference() {
        let (rays, targets) = batch(200);
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        for (alpha, beta) in [(1.0f32, 0.05f32), (0.8, 0.2)] {
            let v = BoxVolume::new([0.1, 0.05, -0.1], [1.5, 1.4, 1.6], alpha, beta).unwrap();
            let (l, _) = box_loss_and_grad(&v, &s, &rays, &targets).unwrap();
            let t: Vec<f64> = s.depths().iter().map(|&x| x as f64).collect();
            let r = reference_loss(
                [0.1, 0.05, -0.1],
                [1.5, 1.4, 1.6],
                alpha as f64,
                beta as f64,
                &t,
                &rays,
                &targets,
            );
            assert!(((l as f64 - r) / r).abs() < 1e-4, "{l} vs {r}");
        }
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let (rays, targets) = batch(300);
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        let t64: Vec<f64> = s.depths().iter().map(|&x| x as f64).collect();
        let c0 = [0.1, 0.05, -0.1];
        let s0 = [1.5, 1.4, 1.6];
        let p64 = Params {
            center: c0,
            sides: s0,
            alpha: 1.0,
            beta: 0.05,
        };
        let (_, g64) = loss_and_grad_generic(&p64, &t64, &rays, &targets);
        let v = BoxVolume::new(c0.map(|x| x as f32), s0.map(|x| x as f32), 1.0, 0.05).unwrap();
        let (_, g32) = box_loss_and_grad(&v, &s, &rays, &targets).unwrap();
        let h = 1e-6;
        for k in 0..6 {
            let eval = |dh: f64| {
                let (mut c, mut sd) = (c0, s0);
                if k < 3 {
                    c[k] += dh
                } else {
                    sd[k - 3] += dh
                }
                reference_loss(c, sd, 1.0, 0.05, &t64, &rays, &targets)
            };
            let fd = (eval(h) - eval(-h)) / (2.0 * h);
            let (a64, a32) = if k < 3 {
                (g64.center[k], g32.center[k] as f64)
            } else {
                (g64.sides[k - 3], g32.sides[k - 3] as f64)
            };
            let tol = 1e-4 * fd.abs() + 1e-7;
            assert!((a64 - fd).abs() < tol, "param {k}: f64 {a64} vs fd {fd}");
            assert!(
                (a32 - fd).abs() < 1e-3 * fd.abs() + 1e-6,
                "param {k}: f32 {a32} vs fd {fd}"
            );
            assert!(fd.abs() > 1e-5, "param {k} should matter: {fd}");
        }
    }

    #[test]
    fn hard_parameters_give_finite_gradients() {
        let (rays, targets) = batch(64);
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        for beta in [1e-4f32, 1e-3] {
            let v = BoxVolume::new([0.0; 3], [1.5; 3], 1.0, beta).unwrap();
            let (l, g) = box_loss_and_grad(&v, &s, &rays, &targets).unwrap();
            assert!(l.is_finite());
            assert!(g.center.iter().chain(&g.sides).all(|x| x.is_finite()));
        }
        // Huge box: every sample deep inside (|sdf| ~ 1e3).
        let v = BoxVolume::new([0.0; 3], [2e3; 3], 1.0, 1e-4).unwrap();
        let (l, g) = box_loss_and_grad(&v, &s, &rays, &targets).unwrap();
        assert!(l.is_finite() && g.center.iter().chain(&g.sides).all(|x| x.is_finite()));
        assert!(BoxVolume::new([0.0; 3], [1.0; 3], 1.5, 0.05).is_err());
        assert!(BoxVolume::new([0.0; 3], [-1.0, 1.0, 1.0], 1.0, 0.05).is_err());
        assert!(box_loss_and_grad(&v, &s, &rays, &targets[1..]).is_err());
    }

    #[test]
    fn image_render_is_sane() {
        let v = BoxVolume::new([0.0; 3], [1.75; 3], 1.0, 0.05).unwrap();
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        let cam = Camera::look_at(DVec3::new(0.0, 0.0, -3.0), DVec3::ZERO, DVec3::Y, 1.0);
        let size = ImageSize {
            width: 33,
            height: 33,
        };
        let img = render_box_image(&v, &s, &cam, size).unwrap();
        // Centre pixel hits the front face at depth 3 − 0.875; corners miss.
        let c = 16 * 33 + 16;
        assert!((img.depth[c] - 2.125).abs() < 0.1, "{}", img.depth[c]);
        assert!(img.depth[0] < 1e-3 && img.colour[0].iter().all(|&x| x < 1e-3));
        assert!(img
            .colour
            .iter()
            .flatten()
            .all(|x| x.is_finite() && *x >= 0.0 && *x <= 1.0));
    }
}
