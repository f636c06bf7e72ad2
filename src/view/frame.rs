//! One frame of a `render` statement's scene from any camera, traced by
//! the same `render_view` as `sdfl run`, encoded as PNG.

use std::sync::Arc;

use glam::DVec3;
use sdfl_runtime::render::{render_view, Needs, RELATIVE_BEYOND};
use sdfl_runtime::{LowerOptions, Lowered};
use sdfl_stdlib::camera::{Camera, Lens};
use sdfl_stdlib::RenderJob;

use super::request::Refusal;

/// What the page asks for.
#[derive(Debug, Clone, Copy)]
pub struct FrameCamera {
    /// Where the camera is.
    pub eye: DVec3,
    /// What it looks at.
    pub at: DVec3,
    /// Roughly up.
    pub up: DVec3,
    /// Focal length in NDC units.
    pub focal: f64,
    /// Image size.
    pub size: (u32, u32),
    /// One ray per pixel however many the statement asks for (frames
    /// while the camera moves).
    pub draft: bool,
}

/// A statement's camera for the page: its first view's.
pub fn initial_camera(job: &RenderJob) -> Option<Camera> {
    job.cameras.first().copied()
}

/// The scene lowered in world coordinates, once per reload and scene (a
/// camera far from the origin lowers it again relative to its eye, as
/// `sdfl run` does).
pub fn lower(job: &RenderJob) -> Lowered {
    Lowered::relative_to(&job.scene, LowerOptions::default(), DVec3::ZERO)
}

/// The frame as PNG bytes.
pub fn render(job: &RenderJob, world: &Arc<Lowered>, c: FrameCamera) -> Result<Vec<u8>, Refusal> {
    let first = job.cameras.first();
    let mut cam = Camera::look_at(c.eye, c.at, c.up, c.focal);
    if let Some(f) = first {
        cam = cam.with_pixel_centers(f.pixel_centers);
    }
    cam.lens = Lens::Ndc;
    if !cam.is_valid() {
        return Err(Refusal::bad(
            "the camera is degenerate: `eye` equals `at`, or `up` is parallel to the view",
        ));
    }
    let mut job = job.clone();
    if c.draft {
        job.samples_per_pixel = 1;
    }
    let relative;
    let scene: &Lowered = if (cam.eye - world.origin).length() > RELATIVE_BEYOND {
        relative = Lowered::relative_to(&job.scene, LowerOptions::default(), cam.eye);
        &relative
    } else {
        world
    };
    let needs = Needs {
        color: true,
        depth: false,
        normals: false,
        mask: false,
    };
    let view = render_view(scene, &job, &cam, c.size, needs, &|_| {});
    let rgb = view.color.expect("colour was asked for");
    png(c.size, &rgb)
}

/// RGB8 as PNG (fast compression: frames are seen once).
pub fn png((w, h): (u32, u32), rgb: &[u8]) -> Result<Vec<u8>, Refusal> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    let mut bytes = Vec::new();
    PngEncoder::new_with_quality(&mut bytes, CompressionType::Fast, FilterType::Sub)
        .write_image(rgb, w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| Refusal {
            status: 500,
            message: format!("cannot encode the frame: {e}"),
        })?;
    Ok(bytes)
}
