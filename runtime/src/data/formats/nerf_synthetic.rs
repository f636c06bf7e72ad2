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

use crate::data::camera::camera_of;
use crate::data::error::{invalid, no_coverage};
use crate::data::format::{Format, FormatViews, PlannedView, Request, Split};
use crate::data::image::{check_dataset_downscaled, image_dimensions, read_view_images};
use crate::data::view::{downscale_size_of, DataNeeds, TrainView};

pub use crate::data::transforms::{read_transforms, Frame, Transforms, MAX_JSON_BYTES};

/// The NeRF-synthetic format, read by `nerf_synthetic(...)`.
pub struct NerfSynthetic;

impl Format for NerfSynthetic {
    fn name(&self) -> &'static str {
        "nerf_synthetic"
    }

    fn capture_format(&self) -> Option<sdfl_stdlib::value::CaptureFormat> {
        None
    }

    fn marker(&self) -> &'static str {
        "transforms_train.json"
    }

    fn detect(&self, path: &Path) -> bool {
        transforms_path(path, "train").is_file()
    }

    /// Every frame of the split files, those of a test split that is the
    /// training split's file read once.
    fn plan(&self, request: &Request) -> io::Result<Vec<PlannedView>> {
        let (split, test_split) = splits(request)?;
        let train = transforms_path(&request.path, split);
        let mut files = vec![(train.clone(), false)];
        if let Some(t) = test_split {
            let test = transforms_path(&request.path, t);
            if test != train {
                files.push((test, true));
            }
        }
        let mut views = Vec::new();
        for (file, held_out) in files {
            let t = read_transforms(&file)?;
            views.extend(t.frames.into_iter().map(|f| PlannedView {
                image: f.image,
                mask: false,
                held_out,
                downscale: request.downscale,
            }));
        }
        Ok(views)
    }

    /// The training split's views with coverage where asked (held-out
    /// views are only scored), and those of the test split that the job
    /// scores.
    fn read(&self, request: &Request) -> io::Result<FormatViews> {
        let (split, test_split) = splits(request)?;
        let dir = &request.path;
        let mut splits = vec![SplitRead {
            coverage: request.needs.coverage,
            downscale: request.downscale,
            ..SplitRead::all(split)
        }];
        if let Some(t) = test_split {
            // The lone transforms.json stands in for the training split
            // only: it never doubles as the test views.
            if transforms_path(dir, t) == transforms_path(dir, split) {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!(
                        "{}: no transforms_{t}.json for the test split `{t}`",
                        dir.display()
                    ),
                ));
            }
            splits.push(SplitRead {
                frames: request.needs.held_out,
                downscale: request.downscale,
                ..SplitRead::all(t)
            });
        }
        let mut read = read_splits(dir, &splits, request.background)?;
        let test = if read.len() > 1 {
            read.pop().unwrap_or_default()
        } else {
            Vec::new()
        };
        let train = read.pop().unwrap_or_default();
        let named = |split: &str, n: usize| {
            let file = transforms_path(dir, split).display().to_string();
            (0..n).map(move |k| format!("{file} frame {k}"))
        };
        let names = named(split, train.len())
            .chain(named(test_split.unwrap_or(""), test.len()))
            .collect();
        Ok(FormatViews {
            train,
            test,
            names,
            frame: None,
            report: Vec::new(),
            forward_facing: None,
        })
    }
}

/// The training split and the held-out one that `request` names.
fn splits(request: &Request) -> io::Result<(&str, Option<&str>)> {
    match &request.split {
        Split::Files { train, test } => Ok((train, test.as_deref())),
        Split::Every(_) => Err(invalid(
            &request.path,
            "a NeRF-synthetic set is split by its files (transforms_<split>.json), not every n-th frame",
        )),
    }
}

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
    /// ([`DataNeeds::keeps_held_out`]); `None`: every frame.
    /// The others are never decoded.
    pub frames: Option<usize>,
    /// Each image box-filtered to 1/`downscale` a side once composited
    /// ([`TrainView::downscaled`]; 1: as decoded). Refused, before any
    /// image is decoded, where it does not divide the first frame's size
    /// (every frame has that size).
    pub downscale: u32,
}

impl<'a> SplitRead<'a> {
    /// Every frame of split `name`, colours only.
    pub fn all(name: &'a str) -> Self {
        SplitRead {
            name,
            coverage: false,
            frames: None,
            downscale: 1,
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
            let needs = DataNeeds {
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
    check_dataset_downscaled(all.iter().zip(splits).flat_map(|(t, s)| {
        t.frames.iter().map(move |f| (&f.image, s.downscale))
    }))?;
    for (t, s) in all.iter().zip(splits) {
        if let Some(f) = t.frames.first() {
            downscale_size_of(&f.image, image_dimensions(&f.image)?, s.downscale)?;
        }
    }
    files
        .iter()
        .zip(&all)
        .zip(splits)
        .map(|((file, t), s)| read_frames(file, t, background, s))
        .collect()
}

/// The frames of `t` (read from `file`) over `background`, with coverage
/// and at the size `split` asks. Each image is box-filtered as soon as it
/// is decoded, so that only one batch of full-size images is ever held.
fn read_frames(
    file: &Path,
    t: &Transforms,
    background: DVec3,
    split: &SplitRead,
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
        let coverage = match (split.coverage, rgba.has_alpha) {
            (false, _) => None,
            (true, true) => Some(rgba.coverage()),
            (true, false) => return Err(no_coverage(&f.image)),
        };
        let bg = background.as_vec3().to_array();
        let view = TrainView {
            camera,
            image: rgba.over(bg),
            mask: None,
            coverage,
        };
        views.push(if split.downscale > 1 {
            downscale_size_of(&f.image, (w, h), split.downscale)?;
            view.downscaled(split.downscale)
                .map_err(|e| invalid(&f.image, e))?
        } else {
            view
        });
        Ok(())
    })?;
    Ok(views)
}
