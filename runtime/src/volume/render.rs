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
