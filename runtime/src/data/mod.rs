//! Readers for input data sets.

pub mod capture;
pub mod colmap;
pub mod export;
pub mod image;
pub mod llff;
pub mod nerf_synthetic;
pub mod nerfstudio;
pub mod normalize;
pub mod npy;
pub mod points;

use std::io;

use sdfl_lang::Span;

/// An error reading an input that an argument of the program names (a
/// data set's path): the argument's span travels with it, so that the
/// diagnostic points at the argument rather than the statement.
#[derive(Debug)]
pub struct AtArgument {
    /// The argument that named the input.
    pub span: Span,
    /// What went wrong reading it.
    pub error: io::Error,
}

impl std::fmt::Display for AtArgument {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.error.fmt(f)
    }
}

impl std::error::Error for AtArgument {}

/// `e`, pointing at `span` unless it already points at an argument.
pub fn at_argument(span: Span, e: io::Error) -> io::Error {
    if e.get_ref().is_some_and(|r| r.is::<AtArgument>()) {
        return e;
    }
    io::Error::new(e.kind(), AtArgument { span, error: e })
}

/// The argument an error points at, if any.
pub fn argument_span(e: &io::Error) -> Option<Span> {
    e.get_ref()
        .and_then(|r| r.downcast_ref::<AtArgument>())
        .map(|a| a.span)
}

/// One training view: a camera and the image it sees.
#[derive(Debug, Clone)]
pub struct TrainView {
    /// The camera the image was taken with, in the scene frame.
    pub camera: sdfl_stdlib::camera::Camera,
    /// The image the camera sees: the training target.
    pub image: npy::RgbImage,
    /// Pixels to train on and score (row-major, `false`: masked out, as a
    /// capture's `mask_path` says); `None`: every pixel.
    pub mask: Option<std::sync::Arc<[bool]>>,
    /// How much of each pixel the object covers, in 255ths (row-major; the
    /// target of [`sdfl_stdlib::value::LossKind::Silhouette`]); `None`:
    /// not known, or not asked for. A byte a pixel, as it comes (8-bit
    /// alpha, the tracer's hit or miss), beside the image's twelve: a
    /// batch converts only its rays' to f32.
    pub coverage: Option<std::sync::Arc<[u8]>>,
}

/// Each pixel's coverage from its alpha (clamped to 0..1), in 255ths: 8-bit
/// alpha exactly, 16-bit to the nearest 255th.
pub fn coverage_from_alpha(rgba: &[[f32; 4]]) -> std::sync::Arc<[u8]> {
    rgba.iter()
        .map(|p| (p[3].clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect()
}

/// What a job reads of its data beyond each view's camera and colours.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DataNeeds {
    /// Each training view's coverage by the object, from its image's alpha
    /// (`silhouette()`), which the images must then have. Read only when
    /// asked: a 100-view 800² set holds 64 MB more with it. (A shape's
    /// traced views always carry theirs: the hit mask comes with the
    /// trace.)
    pub coverage: bool,
}

impl DataNeeds {
    /// What `job`'s loss terms read of its data.
    pub fn of(job: &sdfl_stdlib::value::TrainJob) -> Self {
        DataNeeds {
            coverage: job
                .losses
                .iter()
                .any(|l| l.kind == sdfl_stdlib::value::LossKind::Silhouette),
        }
    }
}

/// The stable code of images that cannot give `silhouette()` each pixel's
/// coverage: they have no alpha channel.
pub const NO_COVERAGE: &str = "sdfl::data::no-coverage";

/// A data error with its own stable code and help, carried in an
/// `io::Error` so that the CLI reports it under that code rather than as
/// an unreadable file.
#[derive(Debug)]
pub struct Coded {
    /// The diagnostic code.
    pub code: &'static str,
    /// What is wrong, naming the file.
    pub message: String,
    /// What to do about it.
    pub help: &'static str,
}

impl std::fmt::Display for Coded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Coded {}

impl Coded {
    /// `self` as an `io::Error` (invalid data).
    pub fn into_io(self) -> io::Error {
        io::Error::new(io::ErrorKind::InvalidData, self)
    }
}

/// The coded data error `e` carries, if any (also under the argument that
/// named the data).
pub fn coded(e: &io::Error) -> Option<&Coded> {
    let inner = e.get_ref()?;
    match inner.downcast_ref::<AtArgument>() {
        Some(a) => coded(&a.error),
        None => inner.downcast_ref::<Coded>(),
    }
}

/// The error of an image without alpha read for `silhouette()`.
pub fn no_coverage(path: &std::path::Path) -> io::Error {
    Coded {
        code: NO_COVERAGE,
        message: format!(
            "{}: the image has no alpha channel, and `silhouette()` takes each pixel's coverage by the object from it",
            path.display()
        ),
        help: "give RGBA PNGs whose alpha is the object's coverage (as Blender's NeRF-synthetic sets and sdfl's `dataset(...)` are), or leave `silhouette()` out",
    }
    .into_io()
}
