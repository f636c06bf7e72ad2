//! Forward volume rendering of any SDF field with a colour (e.g. one the
//! language lowers to a culled closure), under the three density models,
//! through the same generic ray march the trainer differentiates.
//! Chunked and parallel over rays; forward only.

use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::num::V3;
use sdfl_stdlib::value::{DensityKind, LastInterval};

use super::march::{intervals_into, march, Depths};
use super::rays::{for_each_ray_chunk, ImageSize, Stratified};
use super::{Composite, VolumeError};

/// How an SDF becomes absorption, with its constants.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DensityModel {
    /// How distance becomes density (or opacity).
    pub kind: DensityKind,
    /// An opacity scale `0 < α ≤ 1` for [`DensityKind::Opacity`], a density
    /// scale `α > 0` otherwise.
    pub alpha: f32,
    /// The width of the surface's transition `β > 0`, in scene units.
    pub beta: f32,
    /// How much the last sample of a ray absorbs.
    pub last_interval: LastInterval,
}

impl DensityModel {
    /// Checks `α` against the kind's range and `β > 0`, both finite.
    pub fn validate(&self) -> Result<(), VolumeError> {
        let alpha = self.alpha;
        if !(alpha > 0.0 && alpha as f64 <= self.kind.alpha_max() && alpha.is_finite()) {
            return Err(VolumeError::Invalid(format!(
                "α = {alpha} out of range for {:?}",
                self.kind
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

/// A rendered image: row-major from the top-left pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedImage {
    /// The image's size.
    pub size: ImageSize,
    /// Each pixel's colour.
    pub colour: Vec<[f32; 3]>,
    /// Each pixel's expected depth along its ray.
    pub depth: Vec<f32>,
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
    let mut delta = Vec::new();
    intervals_into(&t, model.last_interval, &mut delta);
    let zero = Composite {
        colour: [0f32; 3],
        depth: 0.0,
        opacity: 0.0,
    };
    let mut out = vec![zero; size.pixels()];
    for_each_ray_chunk(cam, size, 1024, &mut out, |rays, o| {
        for (r, c) in rays.iter().zip(o) {
            let m = march::<f32>(
                |p: V3<f32>| {
                    let (d, col) = field(p.to_array());
                    (d, V3::from_array(col))
                },
                model.kind,
                model.alpha,
                model.beta,
                r.origin,
                r.dir,
                Depths {
                    t: &t,
                    delta: &delta,
                },
                want_depth,
            );
            *c = Composite {
                colour: m.colour.to_array(),
                depth: m.depth,
                opacity: m.opacity,
            };
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
    use sdfl_stdlib::camera::OrbitUp;

    fn model(kind: DensityKind, alpha: f32, beta: f32) -> DensityModel {
        DensityModel {
            kind,
            alpha,
            beta,
            last_interval: LastInterval::Zero,
        }
    }

    #[test]
    fn depth_is_computed_only_when_asked() {
        let cam = Camera::orbit(3.0, OrbitUp::Y, 1.0, 1)[0];
        let s = Stratified::new(32, 0.0, 5.0).unwrap();
        let size = ImageSize {
            width: 16,
            height: 16,
        };
        let field = |p: [f32; 3]| {
            let d = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 1.0;
            (d, [0.5, 0.2, 0.9])
        };
        let m = model(DensityKind::Opacity, 1.0, 0.05);
        let with = render_field_image_with(field, m, &s, &cam, size, true).unwrap();
        let without = render_field_image_with(field, m, &s, &cam, size, false).unwrap();
        assert_eq!(with.colour, without.colour);
        assert_eq!(with.depth.len(), 256);
        assert!(without.depth.is_empty());
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
        for &kind in DensityKind::ALL {
            // The centre ray hits the unit sphere at depth 2 (within `tol`).
            // NeuS's symmetric density with plain compositing absorbs
            // mostly in front of the surface (the bias NeuS's own weighting
            // removes); ∫σ across a surface is α: large enough to be opaque.
            let (alpha, beta, tol) = match kind {
                DensityKind::Opacity => (1.0, 1e-4, 0.1),
                DensityKind::VolSdf => (10.0, 0.05, 0.1),
                DensityKind::Neus => (50.0, 0.05, 0.3),
            };
            let m = model(kind, alpha, beta);
            let img = render_field_image(sphere, m, &s, &cam, size).unwrap();
            let centre = 8 * 17 + 8;
            assert!(img
                .colour
                .iter()
                .flatten()
                .all(|x| x.is_finite() && (0.0..=0.5 + 1e-5).contains(x)));
            // A corner misses.
            assert!(
                (img.depth[centre] - 2.0).abs() < tol,
                "{m:?}: {}",
                img.depth[centre]
            );
            assert!(img.colour[centre][0] > 0.45);
            assert!(img.depth[0] < 1e-3);
        }
        let bad = model(DensityKind::Opacity, 2.0, 0.05);
        assert!(render_field_image(sphere, bad, &s, &cam, size).is_err());
        let bad_sampler = Stratified {
            n: 1,
            near: 0.0,
            far: 1.0,
        };
        let neus = model(DensityKind::Neus, 1.0, 0.1);
        assert!(render_field_image(sphere, neus, &bad_sampler, &cam, size).is_err());
    }
}
