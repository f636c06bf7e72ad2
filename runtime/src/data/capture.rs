//! `capture(...)`: a real capture read by its format, as given or found
//! from the files (`format: "auto"`), normalised into sdfl's scene frame
//! and turned into training views.

use std::io;
use std::path::Path;

use sdfl_stdlib::value::{CaptureFormat, CaptureSpec};

use super::formats;
use super::normalize::SceneFrame;
use super::view::{DataNeeds, TrainView};

pub use super::camera::{camera_of, Distortion, Intrinsics};
pub use super::format::ForwardFacing;

/// A capture's views, in the scene frame.
#[derive(Debug, Clone)]
pub struct CaptureViews {
    /// Views trained on.
    pub train: Vec<TrainView>,
    /// Views held out and only scored.
    pub test: Vec<TrainView>,
    /// The file name of each view, train then test (for messages).
    pub names: Vec<String>,
    /// From the data's frame into the scene frame; exporters map back
    /// with [`SceneFrame::to_data`].
    pub frame: SceneFrame,
    /// Lines for people: the scene frame, the points' and depths' extent
    /// in it.
    pub report: Vec<String>,
    /// A forward-facing capture's reference camera for NDC (LLFF,
    /// normalised): `None` for other captures.
    pub forward_facing: Option<ForwardFacing>,
}

/// The format a capture directory holds, the first of the capture
/// formats in [`formats::FORMATS`] whose files it has: `transforms.json`,
/// then a COLMAP text model, then `poses_bounds.npy`, then
/// `cameras_sphere.npz`.
pub fn detect(dir: &Path) -> Option<CaptureFormat> {
    formats::detect(dir).and_then(|f| f.capture_format())
}

/// How `spec` frames its scene when normalised where its format (as
/// given, or found in `base.join(spec.path)`) has a frame of its own (for
/// `sdfl plan`); `None`: from the cameras, or no format found.
pub fn own_frame(spec: &CaptureSpec, base: &Path) -> Option<&'static str> {
    formats::of_capture(spec, &base.join(&spec.path))
        .ok()?
        .own_frame()
}

/// Reads the capture `spec` names (relative to `base`): its frames, split,
/// scene frame and images.
pub fn read(spec: &CaptureSpec, base: &Path) -> io::Result<CaptureViews> {
    read_for(spec, base, DataNeeds::default())
}

/// [`read`], with what the job reads beyond colours (`needs`).
pub fn read_for(spec: &CaptureSpec, base: &Path, needs: DataNeeds) -> io::Result<CaptureViews> {
    let path = base.join(&spec.path);
    let format = formats::of_capture(spec, &path)?;
    let views = format.read(&formats::capture_request(spec, &path, needs))?;
    Ok(CaptureViews {
        train: views.train,
        test: views.test,
        names: views.names,
        // Every capture format maps back from its scene frame.
        frame: views.frame.unwrap_or(SceneFrame::IDENTITY),
        report: views.report,
        forward_facing: views.forward_facing,
    })
}
