//! NeRF-synthetic (Blender) data sets: `transforms_<split>.json` with one
//! camera-to-world `transform_matrix` per frame in OpenGL axes (the camera
//! looks down −z, +y up, +x right), `camera_angle_x` (the horizontal field
//! of view; `fl_x`/`fl_y` in pixels where given), and RGBA PNGs (alpha:
//! the object's coverage of each pixel, the target of `silhouette()`).
//!
//! Poses convert exactly to sdfl cameras (`Camera::from_opengl`): the same
//! ray through every pixel, pixel `i` centred at `i + ½` as Blender renders
//! (the original NeRF code's rays are half a pixel off that). Reading is
//! hostile-input safe: the JSON is a capped regular file, every key is
//! checked, frames are capped, image paths stay inside the data set's
//! directory and image sizes are checked before anything is decoded.

use std::io;
use std::path::{Path, PathBuf};

use glam::DVec3;

use super::capture::{camera_of, invalid};
use super::image::{check_dataset, read_view_images};
use super::{no_coverage, TrainView};

pub use super::nerfstudio::{read_transforms, Frame, Transforms, MAX_JSON_BYTES};

/// The transforms file of `split` under `path`: `path` itself when it is a
/// `.json` file; else `path/transforms_<split>.json`, or `path/transforms.json`
/// (one split, as sdfl's `dataset` output writes) when that is missing.
pub fn transforms_path(path: &Path, split: &str) -> PathBuf {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        return path.to_path_buf();
    }
    let named = path.join(format!("transforms_{split}.json"));
    let single = path.join("transforms.json");
    if !named.exists() && single.exists() {
        single
    } else {
        named
    }
}

/// Reads one split's views, composited over `background`: every image the
/// same size, checked before any is decoded.
pub fn read_split(path: &Path, split: &str, background: DVec3) -> io::Result<Vec<TrainView>> {
    read_splits(path, &[SplitRead::all(split)], background).map(|mut s| s.remove(0))
}

/// One split to read and what of it.
#[derive(Debug, Clone, Copy)]
pub struct SplitRead<'a> {
    /// The split's name (`transforms_<name>.json`).
    pub name: &'a str,
    /// Each view's coverage from its image's alpha (`silhouette()`), an
    /// error where an image has none.
    pub coverage: bool,
    /// How many frames, evenly spaced and the first included
    /// ([`crate::data::DataNeeds::keeps_held_out`]); `None`: every frame.
    /// The others are never decoded.
    pub frames: Option<usize>,
}

impl<'a> SplitRead<'a> {
    /// Every frame of split `name`, colours only.
    pub fn all(name: &'a str) -> Self {
        SplitRead {
            name,
            coverage: false,
            frames: None,
        }
    }
}

/// Reads several splits' views (one list each), every image's declared
/// size checked (all splits together within the data-set limit) before
/// any is decoded; see [`SplitRead`] for what of each is read.
pub fn read_splits(
    path: &Path,
    splits: &[SplitRead],
    background: DVec3,
) -> io::Result<Vec<Vec<TrainView>>> {
    let files: Vec<PathBuf> = splits
        .iter()
        .map(|s| transforms_path(path, s.name))
        .collect();
    let all = files
        .iter()
        .zip(splits)
        .map(|(f, s)| {
            let mut t = read_transforms(f)?;
            let needs = crate::data::DataNeeds {
                coverage: false,
                held_out: s.frames,
            };
            let keep = needs.keeps_held_out(t.frames.len());
            let mut k = 0;
            t.frames.retain(|_| {
                k += 1;
                keep[k - 1]
            });
            Ok(t)
        })
        .collect::<io::Result<Vec<_>>>()?;
    check_dataset(all.iter().flat_map(|t| t.frames.iter().map(|f| &f.image)))?;
    files
        .iter()
        .zip(&all)
        .zip(splits)
        .map(|((file, t), s)| read_frames(file, t, background, s.coverage))
        .collect()
}

fn read_frames(
    file: &Path,
    t: &Transforms,
    background: DVec3,
    coverage: bool,
) -> io::Result<Vec<TrainView>> {
    let mut views = Vec::with_capacity(t.frames.len());
    let mut size = None;
    // Decoded a batch at a time in parallel, kept in the frames' order.
    let images: Vec<&Path> = t.frames.iter().map(|f| f.image.as_path()).collect();
    read_view_images(&images, |k, rgba| {
        let f = &t.frames[k];
        let (w, h) = (rgba.width, rgba.height);
        match size {
            None => size = Some((w, h)),
            Some(s) if s != (w, h) => {
                return Err(invalid(
                    &f.image,
                    format!("{w}x{h} pixels, but the first frame has {}x{}", s.0, s.1),
                ))
            }
            Some(_) => {}
        }
        let named = |e: String| invalid(file, format!("frame {k}: {e}"));
        let intrinsics = t.intrinsics(k, (w, h), 1).map_err(named)?;
        let camera = camera_of(&f.pose, &intrinsics).map_err(named)?;
        let coverage = match (coverage, rgba.has_alpha) {
            (false, _) => None,
            (true, true) => Some(rgba.coverage()),
            (true, false) => return Err(no_coverage(&f.image)),
        };
        let bg = background.as_vec3().to_array();
        views.push(TrainView {
            camera,
            image: rgba.over(bg),
            mask: None,
            coverage,
        });
        Ok(())
    })?;
    Ok(views)
}
