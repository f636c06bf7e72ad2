//! Differentiable volume rendering of analytic SDF volumes (CONVENTIONS.md,
//! "Volume rendering").
//!
//! * [`rays`]: per-pixel and seeded random rays ([`Ray`] knows its view and
//!   pixel), the linspace/jittered [`Stratified`] sampler, chunked iteration.
//! * [`composite`]: weights from densities (log-space transmittance), from
//!   opacities (may be exactly 1) or from `ln(1 − o)`; colour/depth aggregation.
//! * [`density`]: Laplace CDF, the assignment's opacity and its `ln(1 − o)`,
//!   VolSDF, NeuS, softplus — values and derivatives finite for β ≥ 1e-4 and
//!   any |sdf|.
//! * [`shapes`]: box SDF and rainbow colour with derivatives.
//! * [`box_volume`]: the assignment's box volume with a fused f32
//!   forward/backward kernel (rayon over rays) and image rendering.
//! * [`render`]: forward rendering of any `point → (sdf, colour)` field.
//! * [`mod@bench`]: timings for a `bench` subcommand.
//!
//! The dfdx side (parameter store, Adam, graph ops, box fit) is in
//! [`crate::train`].

pub mod bench;
pub mod box_volume;
pub mod composite;
pub mod density;
pub mod figures;
pub mod rays;
pub mod render;
pub mod shapes;

pub use box_volume::{
    box_loss_and_grad, render_box_image, render_box_rays, BoxGrad, BoxVolume, RenderedImage,
};
pub use composite::Composite;
pub use rays::{camera_rays, random_rays, ImageSize, Ray, SplitMix64, Stratified};
pub use render::{render_field_image, DensityModel};

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
