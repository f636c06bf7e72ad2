//! Limits on what one statement may ask of the runtime: samples per ray,
//! image size, views and tracing steps. The built-ins refuse arguments
//! beyond them, and so do the readers of files that make cameras.

/// Most samples per ray.
pub const MAX_SAMPLES: u64 = 4096;

/// Largest image side in pixels.
pub const MAX_IMAGE_SIDE: u32 = 16_384;
/// Most camera views of one render.
pub const MAX_VIEWS: usize = 10_000;
/// Most sphere-tracing iterations per ray.
pub const MAX_ITERATIONS: u32 = 100_000;
/// The largest factor images are box-filtered down by a side
/// (`nerf_synthetic(downscale:)`, `eval_downscale`).
pub const MAX_DOWNSCALE: u64 = 64;
