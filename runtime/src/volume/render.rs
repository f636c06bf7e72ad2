//! Forward volume rendering of any SDF field with a colour (e.g. one the
//! language lowers to a closure), under the conventions' three density
//! models. Chunked and parallel over rays; forward only.

use sdfl_stdlib::camera::Camera;

use super::box_volume::RenderedImage;
use super::composite::{aggregate, intervals, weights_from_density};
use super::density::{neus_density, sdf_opacity_parts, volsdf_density};
use super::rays::{for_each_ray_chunk, ImageSize, Ray, Stratified};
use super::{Composite, VolumeError};

/// How an SDF becomes absorption.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DensityModel {
    /// The assignment's per-sample opacity `α·Ψ_β(−sdf)` (parts 1–2), `0 < α ≤ 1`.
    SdfOpacity { alpha: f32, beta: f32 },
    /// VolSDF density `σ = α·Ψ_β(−sdf)` with the sample intervals (part 7).
    VolSdf { alpha: f32, beta: f32 },
    /// NeuS logistic density `(α/β)·s(1 − s)`, `s = sigmoid(−sdf/β)` (part 8.3).
    Neus { alpha: f32, beta: f32 },
}

impl DensityModel {
    pub fn validate(&self) -> Result<(), VolumeError> {
        let (alpha, beta, max_alpha) = match *self {
            DensityModel::SdfOpacity { alpha, beta } => (alpha, beta, 1.0),
            DensityModel::VolSdf { alpha, beta } | DensityModel::Neus { alpha, beta } => {
                (alpha, beta, f32::INFINITY)
            }
        };
        if !(alpha > 0.0 && alpha <= max_alpha && alpha.is_finite()) {
            return Err(VolumeError::Invalid(format!(
                "α = {alpha} out of range for {self:?}"
            )));
        }
        if !(beta > 0.0 && beta.is_finite()) {
            return Err(VolumeError::Invalid(format!(
                "β must be positive, got {beta}"
            )));
        }
        Ok(())
    }
}

/// Renders one ray of `field` (point → (sdf, colour)) at depths `t` with
/// intervals `delta`, using the scratch buffers `w`, `sigma`, `cols` (one
/// entry per depth).
#[allow(clippy::too_many_arguments)]
fn render_ray<Fld: Fn([f32; 3]) -> (f32, [f32; 3])>(
    field: &Fld,
    model: DensityModel,
    t: &[f32],
    delta: &[f32],
    ray: &Ray,
    w: &mut [f32],
    sigma: &mut [f32],
    cols: &mut [[f32; 3]],
    want_depth: bool,
) -> Result<Composite<f32>, VolumeError> {
    let mut trans = 1.0f32;
    for (k, &tk) in t.iter().enumerate() {
        let x = [0, 1, 2].map(|i| ray.origin[i] + tk * ray.dir[i]);
        let (sdf, col) = field(x);
        cols[k] = col;
        match model {
            // Opacity per sample; transmittance as the running product of
            // kept fractions (exact where the opacity rounds to 1).
            DensityModel::SdfOpacity { alpha, beta } => {
                let p = sdf_opacity_parts(sdf, alpha, beta);
                w[k] = trans * p.opacity;
                trans *= p.keep;
            }
            DensityModel::VolSdf { alpha, beta } => sigma[k] = volsdf_density(sdf, alpha, beta),
            DensityModel::Neus { alpha, beta } => sigma[k] = neus_density(sdf, alpha, beta),
        }
    }
    if !matches!(model, DensityModel::SdfOpacity { .. }) {
        weights_from_density(sigma, delta, w)?;
    }
    if want_depth {
        return aggregate(w, cols, t);
    }
    // Colour and opacity only: no output asked for depth.
    let mut colour = [0f32; 3];
    let mut opacity = 0f32;
    for (wk, ck) in w.iter().zip(cols.iter()) {
        for i in 0..3 {
            colour[i] += wk * ck[i];
        }
        opacity += wk;
    }
    Ok(Composite {
        colour,
        depth: 0.0,
        opacity,
    })
}

/// Renders a full image of an SDF field with colour under `model`,
/// with depth.
pub fn render_field_image<Fld>(
    field: Fld,
    model: DensityModel,
    sampler: &Stratified,
    cam: &Camera,
    size: ImageSize,
) -> Result<RenderedImage, VolumeError>
where
    Fld: Fn([f32; 3]) -> (f32, [f32; 3]) + Sync,
{
    render_field_image_with(field, model, sampler, cam, size, true)
}

/// [`render_field_image`], computing depth only when `want_depth`; without
/// it the returned depth is empty.
pub fn render_field_image_with<Fld>(
    field: Fld,
    model: DensityModel,
    sampler: &Stratified,
    cam: &Camera,
    size: ImageSize,
    want_depth: bool,
) -> Result<RenderedImage, VolumeError>
where
    Fld: Fn([f32; 3]) -> (f32, [f32; 3]) + Sync,
{
    model.validate()?;
    sampler.validate()?;
    let t = sampler.depths();
    let mut delta = vec![0f32; t.len()];
    intervals(&t, &mut delta)?;
    let zero = Composite {
        colour: [0f32; 3],
        depth: 0.0,
        opacity: 0.0,
    };
    let mut out = vec![zero; size.pixels()];
    for_each_ray_chunk(cam, size, 1024, &mut out, |rays, o| {
        let n = t.len();
        let (mut w, mut sigma, mut cols) = (vec![0f32; n], vec![0f32; n], vec![[0f32; 3]; n]);
        for (r, c) in rays.iter().zip(o) {
            *c = render_ray(
                &field, model, &t, &delta, r, &mut w, &mut sigma, &mut cols, want_depth,
            )?;
        }
        Ok(())
    })?;
    Ok(RenderedImage {
        size,
        colour: out.iter().map(|c| c.colour).collect(),
        depth: if want_depth {
            out.iter().map(|c| c.depth).collect()
        } else {
            Vec::new()
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_is_computed_only_when_asked() {
        let cam = Camera::orbit(3.0, sdfl_stdlib::camera::OrbitUp::Y, 1.0, 1)[0];
        let s = Stratified::new(32, 0.0, 5.0).unwrap();
        let size = ImageSize {
            width: 16,
            height: 16,
        };
        let field = |p: [f32; 3]| {
            (
                crate::volume::shapes::box_sdf(p, [0.0; 3], [1.75; 3]),
                [0.5, 0.2, 0.9],
            )
        };
        let model = DensityModel::SdfOpacity {
            alpha: 1.0,
            beta: 0.05,
        };
        let with = render_field_image_with(field, model, &s, &cam, size, true).unwrap();
        let without = render_field_image_with(field, model, &s, &cam, size, false).unwrap();
        assert_eq!(with.colour, without.colour);
        assert_eq!(with.depth.len(), 256);
        assert!(without.depth.is_empty());
    }
    use crate::volume::shapes::{box_sdf, rainbow};
    use crate::volume::{render_box_image, BoxVolume};
    use sdfl_stdlib::camera::OrbitUp;

    #[test]
    fn field_render_matches_box_kernel() {
        // The assignment's part 1 setup: box side 1.75, orbit r = 3, up +y.
        let cams = Camera::orbit(3.0, OrbitUp::Y, 1.0, 20);
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        let size = ImageSize {
            width: 48,
            height: 48,
        };
        let c = [0.0f32; 3];
        let sides = [1.75f32; 3];
        let field = |p: [f32; 3]| (box_sdf(p, c, sides), rainbow(p, c));
        let model = DensityModel::SdfOpacity {
            alpha: 1.0,
            beta: 0.05,
        };
        let vol = BoxVolume::new(c, sides, 1.0, 0.05).unwrap();
        for cam in [cams[0], cams[3]] {
            let a = render_field_image(field, model, &s, &cam, size).unwrap();
            let b = render_box_image(&vol, &s, &cam, size).unwrap();
            for k in 0..size.pixels() {
                for i in 0..3 {
                    assert!((a.colour[k][i] - b.colour[k][i]).abs() < 1e-5);
                }
                assert!((a.depth[k] - b.depth[k]).abs() < 1e-4);
            }
        }
    }

    #[test]
    fn density_models_render_finite_images() {
        let cam = Camera::orbit(3.0, OrbitUp::Y, 1.0, 4)[1];
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        let size = ImageSize {
            width: 17,
            height: 17,
        };
        let sphere = |p: [f32; 3]| {
            (
                (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 1.0,
                [0.5; 3],
            )
        };
        for model in [
            DensityModel::VolSdf {
                alpha: 10.0,
                beta: 0.05,
            },
            // ∫σ across a surface is α: large enough to be opaque.
            DensityModel::Neus {
                alpha: 50.0,
                beta: 0.05,
            },
            DensityModel::SdfOpacity {
                alpha: 1.0,
                beta: 1e-4,
            },
        ] {
            let img = render_field_image(sphere, model, &s, &cam, size).unwrap();
            let centre = 8 * 17 + 8;
            assert!(img
                .colour
                .iter()
                .flatten()
                .all(|x| x.is_finite() && (0.0..=0.5 + 1e-5).contains(x)));
            // The centre ray hits the unit sphere at depth 2; a corner misses.
            // NeuS's symmetric density with plain compositing absorbs mostly in
            // front of the surface (the bias NeuS's own weighting removes).
            let tol = if matches!(model, DensityModel::Neus { .. }) {
                0.3
            } else {
                0.1
            };
            assert!(
                (img.depth[centre] - 2.0).abs() < tol,
                "{model:?}: {}",
                img.depth[centre]
            );
            assert!(img.colour[centre][0] > 0.45);
            assert!(img.depth[0] < 1e-3);
        }
        let bad = DensityModel::SdfOpacity {
            alpha: 2.0,
            beta: 0.05,
        };
        assert!(render_field_image(sphere, bad, &s, &cam, size).is_err());
        let bad_sampler = Stratified {
            n: 1,
            near: 0.0,
            far: 1.0,
        };
        assert!(render_field_image(
            sphere,
            DensityModel::Neus {
                alpha: 1.0,
                beta: 0.1
            },
            &bad_sampler,
            &cam,
            size
        )
        .is_err());
    }
}
