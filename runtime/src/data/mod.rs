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
    /// How much of each pixel the object covers, 0..1 (row-major; the
    /// target of [`sdfl_stdlib::value::LossKind::Silhouette`]); `None`:
    /// not known.
    pub coverage: Option<std::sync::Arc<[f32]>>,
}
