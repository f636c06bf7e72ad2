//! What a data format is to the rest of sdfl: one parser behind
//! [`Format`], listed once in [`super::formats::FORMATS`]. A format
//! recognises its files, reads its cameras, images and split (checked as
//! hostile input), says which images a run will decode before any is, and
//! declares how it frames the scene. What formats share (camera and lens
//! checks, paths kept inside the data set, capture frames and their
//! loading, the scene frame) lives beside this module, never in another
//! format's file.

use std::io;
use std::path::PathBuf;

use glam::DVec3;
use sdfl_stdlib::value::{CaptureFormat, ObjectMasks};

use super::normalize::{Orient, SceneFrame};
use super::view::{DataNeeds, TrainView};

/// One data format's parser.
pub trait Format: Sync {
    /// Its name, as `capture(format: ...)` writes it where it is a capture
    /// format.
    fn name(&self) -> &'static str;

    /// The `capture(format: ...)` value that asks for it; `None` for a
    /// format read by a built-in of its own (`nerf_synthetic(...)`), which
    /// `format: "auto"` never picks.
    fn capture_format(&self) -> Option<CaptureFormat>;

    /// What marks the format in a data set's directory, for messages
    /// ("poses_bounds.npy").
    fn marker(&self) -> &'static str;

    /// Whether the data set at `path` is in this format, by the files it
    /// holds (nothing is parsed): `format: "auto"` asks each capture
    /// format in turn.
    fn detect(&self, path: &std::path::Path) -> bool;

    /// How `normalize: true` frames the scene where the format has a
    /// frame of its own (LLFF's recentring, IDR's unit sphere), for `sdfl
    /// plan`; `None`: the cameras are centred and scaled (see
    /// [`Normalize`]).
    fn own_frame(&self) -> Option<&'static str> {
        None
    }

    /// The views `request` may read, held-out ones marked (a job's
    /// `eval_views` picks among those), without decoding an image: what
    /// `sdfl plan` reads the headers of. It reads no more than it needs,
    /// so it may accept files that [`Format::read`] refuses.
    fn plan(&self, request: &Request) -> io::Result<Vec<PlannedView>>;

    /// Reads the views `request` asks for: cameras checked, image sizes
    /// checked before any is decoded, split into training and held-out
    /// views, in the scene frame.
    fn read(&self, request: &Request) -> io::Result<FormatViews>;
}

/// What a data statement asks of its data set, whatever the format.
#[derive(Debug, Clone)]
pub struct Request {
    /// The data set: its directory, or a format's own file (a `.json`),
    /// resolved against the program's directory.
    pub path: PathBuf,
    /// Images read at `1/downscale` of their size (1: full size): a
    /// capture's from its format's downscaled folders (`images_<n>/`), a
    /// NeRF-synthetic set's (which has none) decoded whole and
    /// box-filtered ([`super::view::TrainView::downscaled`]).
    pub downscale: u32,
    /// Which views are held out.
    pub split: Split,
    /// How the cameras are moved into the scene frame.
    pub normalize: Normalize,
    /// The colour behind transparent pixels.
    pub background: DVec3,
    /// What object masks are used for, where the data set has them.
    pub object_masks: ObjectMasks,
    /// What the job reads beyond colours.
    pub needs: DataNeeds,
}

impl Request {
    /// Every `n`-th frame held out where the data set has no split lists
    /// (0: none): [`Split::Every`]'s `n`; 0 for split files, which hold
    /// out a file's frames instead.
    pub fn test_every(&self) -> usize {
        match self.split {
            Split::Every(n) => n,
            Split::Files { .. } => 0,
        }
    }
}

/// How a data set's views are split into training and held-out views.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Split {
    /// The data set's own split lists where it has them (nerfstudio's
    /// `train_filenames`), else every `n`-th frame from the first (0:
    /// none held out).
    Every(usize),
    /// A file of frames per split (NeRF-synthetic's
    /// `transforms_<split>.json`): `train`'s frames trained on, `test`'s
    /// held out.
    Files {
        /// The split trained on.
        train: String,
        /// The split held out, if any.
        test: Option<String>,
    },
}

/// How a capture is normalised into the scene frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Normalize {
    /// Centre and scale from the cameras (or the format's own frame);
    /// `false` keeps the data's frame.
    pub enabled: bool,
    /// Which way the scene frame's up axis is chosen.
    pub orient: Orient,
    /// The farthest camera coordinate after scaling (nerfstudio: 1).
    pub extent: f64,
}

impl Normalize {
    /// The data's own frame kept.
    pub const NONE: Normalize = Normalize {
        enabled: false,
        orient: Orient::None,
        extent: 1.0,
    };
}

/// One view a data set will read: its image, whether it has a mask, and
/// whether it is held out.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedView {
    /// The image file.
    pub image: PathBuf,
    /// Whether a mask is read with it (a byte a pixel held).
    pub mask: bool,
    /// Whether it is held out (only scored).
    pub held_out: bool,
    /// The factor it is box-filtered down by a side once decoded (1:
    /// kept as decoded; a capture's downscaled folders hold small files).
    pub downscale: u32,
}

/// A data set's views as its format read them.
#[derive(Debug, Clone)]
pub struct FormatViews {
    /// Views trained on.
    pub train: Vec<TrainView>,
    /// Views held out and only scored.
    pub test: Vec<TrainView>,
    /// Where each view came from (file and frame), train then test, for
    /// messages.
    pub names: Vec<String>,
    /// From the data's frame into the scene frame; exporters map back
    /// with [`SceneFrame::to_data`]. `None` where the data's frame is the
    /// scene frame and nothing maps back (NeRF-synthetic).
    pub frame: Option<SceneFrame>,
    /// Lines for people: the scene frame, the points' and depths' extent
    /// in it.
    pub report: Vec<String>,
    /// A forward-facing capture's reference camera for NDC (LLFF,
    /// normalised): `None` for other data sets.
    pub forward_facing: Option<ForwardFacing>,
}

/// A forward-facing capture (LLFF) as NDC needs it: the reference
/// camera's frame, and the farthest depth bound in scene units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForwardFacing {
    /// The reference camera's frame that NDC rays are warped into.
    pub ndc: sdfl_stdlib::value::NdcFrame,
    /// The farthest depth bound, in scene units: NDC's far plane.
    pub far: f64,
}
