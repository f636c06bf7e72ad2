//! Differentiable volume rendering of analytic SDF volumes (CONVENTIONS.md,
//! "Volume rendering").
//!
//! * [`rays`]: per-pixel and seeded random rays ([`Ray`] knows its view and
//!   pixel), the linspace/jittered [`Stratified`] sampler, chunked iteration.
//! * [`composite`]: weights from densities (log-space transmittance), from
//!   opacities (may be exactly 1) or from `ln(1 − o)`; colour/depth aggregation.
//! * densities (the assignment's opacity, VolSDF, NeuS) are defined once in
//!   [`sdfl_stdlib::density`], generic over the number type.
//! * [`march`]: one ray through a field, generic over the number type: f32
//!   rendering and forward-mode training gradients share it.
//! * [`render`]: forward rendering of any `point → (sdf, colour)` field.
//!
//! Training (parameters, the fused kernel, Adam) is in [`crate::train`].

pub mod composite;
pub mod figures;
pub mod importance;
pub mod march;
pub mod rays;
pub mod render;

pub use composite::Composite;
pub use rays::{camera_rays, random_rays, ImageSize, Ray, SplitMix64, Stratified};
pub use render::{render_field_image, DensityModel, RenderedImage};

/// Errors from invalid volume-rendering inputs.
#[derive(Debug, Clone, PartialEq)]
pub enum VolumeError {
    /// A camera whose axes are undefined (eye = at, up ∥ view) or whose focal
    /// length is not positive.
    InvalidCamera,
    /// Any other invalid argument, with a message saying which.
    Invalid(String),
}

impl std::fmt::Display for VolumeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            VolumeError::InvalidCamera => {
                write!(f, "invalid camera (degenerate axes or focal length)")
            }
            VolumeError::Invalid(m) => write!(f, "{m}"),
        }
    }
}

impl std::error::Error for VolumeError {}
