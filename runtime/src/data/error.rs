//! Errors reading data: the path-named error every reader gives, the
//! argument an error points at, and coded data errors (`sdfl::data::...`).

use std::io;
use std::path::Path;

use sdfl_lang::Span;

/// `path: m` as an invalid-data error: how every reader names the file at
/// fault.
pub fn invalid(path: &Path, m: impl std::fmt::Display) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("{}: {m}", path.display()),
    )
}

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

/// The stable code of a `downscale` factor that does not divide the data
/// set's image size.
pub const DOWNSCALE: &str = "sdfl::data::downscale";

/// The error of an image without alpha read for `silhouette()`.
pub fn no_coverage(path: &Path) -> io::Error {
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
