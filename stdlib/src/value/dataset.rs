//! Data sets a `train` fits: rendered, traced, read from files or captures.

use std::sync::Arc;

use glam::DVec3;

use super::{Field, RenderJob, Sampler};
use crate::camera::Camera;

/// Training views: images with their cameras, some possibly held out as
/// test views.
#[derive(Debug, Clone)]
pub enum Dataset {
    /// Images read from files (`.npy` float32 H×W×3, or PNG).
    Files {
        /// The image files, one per camera.
        images: Vec<std::path::PathBuf>,
        /// The camera of each image.
        cameras: Vec<Camera>,
    },
    /// Views rendered by sdfl from a field: self-contained, with ground truth.
    Rendered {
        /// The field rendered.
        field: Arc<Field>,
        /// Every view, held-out ones included.
        cameras: Vec<Camera>,
        /// Image width in pixels.
        width: u32,
        /// Image height in pixels.
        height: u32,
        /// How the field is rendered.
        sampler: Sampler,
        /// Indices into `cameras` held out as test views (sorted).
        test: Vec<usize>,
    },
    /// Views of a shape sphere-traced by sdfl: the `render` statement's job
    /// (its cameras, size, material, background and tracing settings; no
    /// outputs), so the pixels are exactly what that `render` draws.
    Traced {
        /// The `render` job whose views are the data.
        job: Arc<RenderJob>,
        /// Indices into the job's cameras held out as test views (sorted).
        test: Vec<usize>,
    },
    /// A point cloud sampled on a surface (for distance fields), read from
    /// `path` (relative to the scene file); every `every`-th point kept,
    /// moved to their mean when `center`.
    Points {
        /// The file of points.
        path: std::path::PathBuf,
        /// Keep every `every`-th point.
        every: usize,
        /// Move the points to their mean.
        center: bool,
    },
    /// A NeRF-synthetic (Blender) data set: `transforms_<split>.json` and
    /// its RGBA images, composited over `background`. Cameras are known
    /// once the file is read.
    NerfSynthetic {
        /// The directory (relative to the scene file) or a `.json` file.
        path: std::path::PathBuf,
        /// The `path` argument, where errors reading the data set point.
        path_span: sdfl_lang::Span,
        /// The split trained on (`train`, `val`, `test`).
        split: String,
        /// The split read as test views, if any.
        test_split: Option<String>,
        /// The colour transparent pixels are composited over.
        background: DVec3,
        /// Every image box-filtered to 1/`downscale` of its size a side
        /// once composited (1: full size); the cameras see the same rays
        /// through the blocks' centres.
        downscale: u32,
        /// The `downscale` argument (the call's span where it is not
        /// given), where a factor the images' size refuses points.
        downscale_span: sdfl_lang::Span,
    },
    /// A real capture (`capture(...)`): nerfstudio's `transforms.json`,
    /// COLMAP's text model, LLFF's `poses_bounds.npy` or IDR's
    /// `cameras_sphere.npz`, normalised into the scene frame. Cameras are known once the files are read.
    Capture(Arc<CaptureSpec>),
}

impl Dataset {
    /// The background its images hold: a NeRF-synthetic set's composite
    /// colour, a traced set's `background`, a field's own when rendered
    /// from one (an analytic field's is black).
    pub fn background(&self) -> DataBackground {
        match self {
            Dataset::NerfSynthetic { background, .. } => DataBackground::Color(*background),
            Dataset::Traced { job, .. } => DataBackground::Color(job.background),
            Dataset::Rendered { field, .. } => field.model().data_background(),
            Dataset::Capture(c) => c
                .background
                .map_or(DataBackground::World, DataBackground::Color),
            Dataset::Files { .. } | Dataset::Points { .. } => DataBackground::Unknown,
        }
    }

    /// The cameras known before anything is read (none for NeRF-synthetic
    /// data, whose cameras are in its files), test views included.
    pub fn cameras(&self) -> &[Camera] {
        match self {
            Dataset::Files { cameras, .. } | Dataset::Rendered { cameras, .. } => cameras,
            Dataset::Traced { job, .. } => &job.cameras,
            Dataset::NerfSynthetic { .. } | Dataset::Capture(_) | Dataset::Points { .. } => &[],
        }
    }

    /// Indices of [`Self::cameras`] held out as test views.
    pub fn test_views(&self) -> &[usize] {
        match self {
            Dataset::Rendered { test, .. } | Dataset::Traced { test, .. } => test,
            Dataset::Files { .. }
            | Dataset::NerfSynthetic { .. }
            | Dataset::Capture(_)
            | Dataset::Points { .. } => &[],
        }
    }
}

/// The background a data set's images hold, for the model's to agree with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DataBackground {
    /// Composited over (or rendered on) this colour.
    Color(DVec3),
    /// Opaque photographs of the world: no one colour (a learned
    /// background fits them).
    World,
    /// Not known (image files as they are).
    Unknown,
}

/// The layout of a capture's files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CaptureFormat {
    /// Decided by what the directory holds: `transforms.json`, then a
    /// COLMAP model (`sparse/0/cameras.txt`, `sparse/cameras.txt` or
    /// `cameras.txt`), then `poses_bounds.npy`, then `cameras_sphere.npz`.
    Auto,
    /// nerfstudio's `transforms.json`.
    Nerfstudio,
    /// A COLMAP text model.
    Colmap,
    /// LLFF's `poses_bounds.npy`.
    Llff,
    /// IDR's and NeuS's `cameras_sphere.npz` with `image/` and `mask/`
    /// (DTU, BlendedMVS).
    Idr,
}

impl CaptureFormat {
    /// Each format with the name scene files write.
    pub const NAMES: [(&'static str, CaptureFormat); 5] = [
        ("auto", CaptureFormat::Auto),
        ("nerfstudio", CaptureFormat::Nerfstudio),
        ("colmap", CaptureFormat::Colmap),
        ("llff", CaptureFormat::Llff),
        ("idr", CaptureFormat::Idr),
    ];

    /// The name scene files write.
    pub fn name(self) -> &'static str {
        Self::NAMES
            .iter()
            .find(|(_, f)| *f == self)
            .map_or("auto", |(n, _)| n)
    }
}

/// How a capture's cameras are turned when it is normalised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CaptureOrient {
    /// The data's axes kept.
    None,
    /// The cameras' mean up turned onto +z (nerfstudio's "up").
    Up,
}

/// What a capture's object masks (IDR's `mask/`) are used for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ObjectMasks {
    /// Each training pixel's coverage for `silhouette()`, and the pixels
    /// held-out PSNR is also given inside; the photographs stay whole.
    #[default]
    Coverage,
    /// Also each image's alpha: photographs are composited over the
    /// capture's `background` through their masks, so outside the object
    /// the model learns the background (NeuS's "with mask" setting).
    Alpha,
}

impl ObjectMasks {
    /// Each use with the name scene files write.
    pub const NAMES: [(&'static str, ObjectMasks); 2] = [
        ("coverage", ObjectMasks::Coverage),
        ("alpha", ObjectMasks::Alpha),
    ];
}

/// What `capture(...)` reads, and how.
#[derive(Debug, Clone)]
pub struct CaptureSpec {
    /// The directory (relative to the scene file), or a `transforms.json`.
    pub path: std::path::PathBuf,
    /// The `path` argument, where errors reading the capture point.
    pub path_span: sdfl_lang::Span,
    /// The layout of its files.
    pub format: CaptureFormat,
    /// Images read from `images_<downscale>` (1: `images`), intrinsics
    /// scaled to match.
    pub downscale: u32,
    /// Without split lists in the data, every `test_every`-th frame is
    /// held out (0: none).
    pub test_every: usize,
    /// Centre on the cameras and scale them into [−extent, extent]³ (LLFF
    /// and IDR: their own normalisation; `false`: the data's own frame).
    pub normalize: bool,
    /// How the cameras are turned when normalising.
    pub orient: CaptureOrient,
    /// The farthest camera coordinate after normalising.
    pub extent: f64,
    /// The colour behind transparent pixels of images with alpha; `None`
    /// (not given): white there, and the world behind (a model on the
    /// data's background learns it).
    pub background: Option<DVec3>,
    /// What its object masks are used for, where it has them.
    pub object_masks: ObjectMasks,
}

impl CaptureSpec {
    /// The capture at `path` with `capture(...)`'s defaults: format found
    /// from the files, full-size images, every 8th frame held out,
    /// normalised with its up turned onto +z, no background named, object
    /// masks as coverage.
    pub fn at(path: impl Into<std::path::PathBuf>) -> Self {
        CaptureSpec {
            path: path.into(),
            path_span: sdfl_lang::Span::default(),
            format: CaptureFormat::Auto,
            downscale: 1,
            test_every: 8,
            normalize: true,
            orient: CaptureOrient::Up,
            extent: 1.0,
            background: None,
            object_masks: ObjectMasks::Coverage,
        }
    }
}
