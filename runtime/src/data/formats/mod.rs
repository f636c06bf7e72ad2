//! Every data format, one file each, each a [`Format`]: the registry that
//! `capture(format: "auto")` detects from and the tests iterate, and the
//! one path from a data statement to its format. A new format is a file
//! here and a line in the `formats!` list below (and, for `capture(...)`,
//! its name in `sdfl_stdlib::value::CaptureFormat`).

use std::io;
use std::path::Path;

use sdfl_stdlib::value::{CaptureFormat, CaptureOrient, CaptureSpec, Dataset, ObjectMasks};

use super::error::{at_argument, coded, invalid, DOWNSCALE};
use super::format::{Format, FormatViews, Normalize, PlannedView, Request, Split};
use super::normalize::Orient;
use super::view::{check_finite, opaque_alpha_warning, DataNeeds};

/// Declares each format's module and lists its parser in [`FORMATS`].
macro_rules! formats {
    ($($module:ident :: $parser:ident),* $(,)?) => {
        $(pub mod $module;)*

        /// Every data format, in the order `format: "auto"` tries them.
        pub const FORMATS: &[&dyn Format] = &[$(&$module::$parser),*];
    };
}

formats! {
    nerfstudio::Nerfstudio,
    colmap::Colmap,
    llff::Llff,
    idr::Idr,
    nerf_synthetic::NerfSynthetic,
}

/// The format `capture(format: ...)` names; `None` for `"auto"`.
pub fn named(format: CaptureFormat) -> Option<&'static dyn Format> {
    FORMATS
        .iter()
        .copied()
        .find(|f| f.capture_format() == Some(format))
}

/// The first capture format whose files the data set at `path` holds.
pub fn detect(path: &Path) -> Option<&'static dyn Format> {
    FORMATS
        .iter()
        .copied()
        .find(|f| f.capture_format().is_some() && f.detect(path))
}

/// The format of the capture at `path` (`spec.path` resolved): as given,
/// or detected.
pub fn of_capture(spec: &CaptureSpec, path: &Path) -> io::Result<&'static dyn Format> {
    let found = match spec.format {
        CaptureFormat::Auto => detect(path),
        given => named(given),
    };
    found.ok_or_else(|| {
        let markers: Vec<&str> = FORMATS
            .iter()
            .filter(|f| f.capture_format().is_some())
            .map(|f| f.marker())
            .collect();
        let (last, rest) = markers.split_last().unwrap_or((&"", &[]));
        invalid(path, format!("holds no {} or {last}", rest.join(", ")))
    })
}

/// What `capture(...)` asks of its format (`needs`: what the job reads
/// beyond colours), the capture at `path`.
pub fn capture_request(spec: &CaptureSpec, path: &Path, needs: DataNeeds) -> Request {
    Request {
        path: path.to_path_buf(),
        downscale: spec.downscale,
        split: Split::Every(spec.test_every),
        normalize: Normalize {
            enabled: spec.normalize,
            orient: match spec.orient {
                CaptureOrient::None => Orient::None,
                CaptureOrient::Up => Orient::Up,
            },
            extent: spec.extent,
        },
        background: spec.background.unwrap_or(glam::DVec3::ONE),
        object_masks: spec.object_masks,
        needs,
    }
}

/// A data set a format reads: the format, the request, and the arguments
/// that name its path and its downscale (where errors point).
struct Source {
    format: &'static dyn Format,
    request: Request,
    span: sdfl_lang::Span,
    downscale_span: sdfl_lang::Span,
}

impl Source {
    /// `e` at the argument it is about: a `downscale` the images refuse
    /// at `downscale`, anything else at the path.
    fn at(&self, e: io::Error) -> io::Error {
        let about_downscale = coded(&e).is_some_and(|c| c.code == DOWNSCALE);
        at_argument(
            if about_downscale {
                self.downscale_span
            } else {
                self.span
            },
            e,
        )
    }
}

/// The format and request of `data` (paths relative to `base`); `None`
/// where no format reads it (views traced, rendered or listed, points).
fn source(data: &Dataset, base: &Path, needs: DataNeeds) -> io::Result<Option<Source>> {
    Ok(Some(match data {
        Dataset::Capture(spec) => {
            let path = base.join(&spec.path);
            let format = of_capture(spec, &path).map_err(|e| at_argument(spec.path_span, e))?;
            Source {
                format,
                request: capture_request(spec, &path, needs),
                span: spec.path_span,
                downscale_span: spec.path_span,
            }
        }
        Dataset::NerfSynthetic {
            path,
            path_span,
            split,
            test_split,
            background,
            downscale,
            downscale_span,
        } => Source {
            format: &nerf_synthetic::NerfSynthetic,
            request: Request {
                path: base.join(path),
                downscale: *downscale,
                split: Split::Files {
                    train: split.clone(),
                    test: test_split.clone(),
                },
                normalize: Normalize::NONE,
                background: *background,
                object_masks: ObjectMasks::default(),
                needs,
            },
            span: *path_span,
            downscale_span: *downscale_span,
        },
        Dataset::Rendered { .. }
        | Dataset::Traced { .. }
        | Dataset::Files { .. }
        | Dataset::Points { .. } => return Ok(None),
    }))
}

/// The views of `data` (paths relative to `base`) where a format reads
/// them, whichever: read as `needs` asks, every pixel checked finite, with
/// a warning where coverage read from alpha is everywhere whole. Errors
/// point at the argument naming the data set's path. `None` where no
/// format reads the data.
pub fn read(data: &Dataset, base: &Path, needs: DataNeeds) -> io::Result<Option<FormatViews>> {
    let Some(source) = source(data, base, needs)? else {
        return Ok(None);
    };
    let at = |e| source.at(e);
    let mut views = source.format.read(&source.request).map_err(at)?;
    let names = views.names.iter().map(String::as_str);
    check_finite(views.train.iter().chain(&views.test).zip(names)).map_err(at)?;
    views.report.extend(opaque_alpha_warning(&views.train));
    Ok(Some(views))
}

/// The views `data` (paths relative to `base`) will read, without reading
/// an image; `None` where no format reads it.
pub fn plan(data: &Dataset, base: &Path) -> io::Result<Option<Vec<PlannedView>>> {
    match source(data, base, DataNeeds::default())? {
        Some(s) => s.format.plan(&s.request).map(Some).map_err(|e| s.at(e)),
        None => Ok(None),
    }
}
