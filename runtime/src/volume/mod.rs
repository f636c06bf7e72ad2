//! Differentiable volume rendering of analytic SDF volumes (CONVENTIONS.md,
//! "Volume rendering"): rays and stratified samples, compositing, SDF →
//! density transforms, and the assignment's box volume with a fused
//! forward/backward kernel.

pub mod bench;
pub mod box_volume;
pub mod composite;
pub mod density;
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
