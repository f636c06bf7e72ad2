//! nerfstudio captures: a `transforms.json` (read by
//! [`crate::data::transforms`], the reader NeRF-synthetic shares) beside
//! its images, or the file itself; frames in file-name order, held out by
//! the file's split lists, else every `test_every`-th; downscaled images
//! from `images_<d>/`, masks from `masks_<d>/`. Cameras are centred and
//! scaled from their positions (nerfstudio's `auto_scale_poses`), and
//! `applied_transform` is kept so exports map back to the original frame.

use std::io;
use std::path::{Path, PathBuf};

use sdfl_stdlib::value::CaptureFormat;

use crate::data::error::invalid;
use crate::data::format::{Format, FormatViews, PlannedView, Request};
use crate::data::frames::{load, Capture, CaptureFrame};
use crate::data::image::image_dimensions;

pub use crate::data::transforms::{read_transforms_scaled, Transforms};

/// The nerfstudio format.
pub struct Nerfstudio;

impl Format for Nerfstudio {
    fn name(&self) -> &'static str {
        "nerfstudio"
    }

    fn capture_format(&self) -> Option<CaptureFormat> {
        Some(CaptureFormat::Nerfstudio)
    }

    fn marker(&self) -> &'static str {
        "transforms.json"
    }

    fn detect(&self, path: &Path) -> bool {
        is_json(path) || path.join("transforms.json").is_file()
    }

    fn plan(&self, request: &Request) -> io::Result<Vec<PlannedView>> {
        let t = read_transforms_scaled(&transforms_file(&request.path), request.downscale)?;
        Ok(t.selection(request.test_every())?
            .into_iter()
            .map(|(k, held_out)| PlannedView {
                image: t.frames[k].image.clone(),
                mask: t.frames[k].mask.is_some(),
                held_out,
                downscale: 1,
            })
            .collect())
    }

    fn read(&self, request: &Request) -> io::Result<FormatViews> {
        let t = read_transforms_scaled(&transforms_file(&request.path), request.downscale)?;
        let capture = t.capture(request.downscale, request.test_every())?;
        load(&capture, request, None)
    }
}

fn is_json(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
}

/// A nerfstudio capture's transforms file: `path` itself when it is a
/// `.json` file, else `path/transforms.json`.
pub fn transforms_file(path: &Path) -> PathBuf {
    if is_json(path) {
        path.to_path_buf()
    } else {
        path.join("transforms.json")
    }
}

/// A transforms file read as a nerfstudio capture: its split lists and
/// frames.
impl Transforms {
    /// The indices of the frames named by split list `names`.
    fn named(&self, key: &str, names: &[PathBuf]) -> io::Result<Vec<usize>> {
        // By a map: 10 000 names against 10 000 frames one by one is 1e8
        // comparisons. The first frame of a path, as a search would find.
        let mut index = std::collections::HashMap::with_capacity(self.frames.len());
        for (k, f) in self.frames.iter().enumerate().rev() {
            index.insert(&f.rel, k);
        }
        names
            .iter()
            .map(|n| {
                index.get(n).copied().ok_or_else(|| {
                    invalid(
                        &self.file,
                        format!("`{key}` names {}, which no frame has", n.display()),
                    )
                })
            })
            .collect()
    }

    /// The frames a capture keeps, in file-name order (nerfstudio sorts
    /// frames by file name), each with whether it is held out: test views
    /// from `test_filenames` (else `val_filenames`) with the rest of
    /// `train_filenames` (frames in neither list dropped), else every
    /// `test_every`-th frame. Reads no image.
    pub fn selection(&self, test_every: usize) -> io::Result<Vec<(usize, bool)>> {
        let mut order: Vec<usize> = (0..self.frames.len()).collect();
        order.sort_by(|a, b| self.frames[*a].rel.cmp(&self.frames[*b].rel));
        let [train, val, test] = &self.splits;
        let any = train.is_some() || val.is_some() || test.is_some();
        // Per frame: in the train list, in the test list.
        let lists = if any {
            let train = train.as_ref().ok_or_else(|| {
                invalid(
                    &self.file,
                    "the file has split lists but no `train_filenames`",
                )
            })?;
            let train = self.named("train_filenames", train)?;
            let test = match (test, val) {
                (Some(t), _) => self.named("test_filenames", t)?,
                (None, Some(v)) => self.named("val_filenames", v)?,
                (None, None) => Vec::new(),
            };
            let mut is = vec![(false, false); self.frames.len()];
            train.iter().for_each(|&k| is[k].0 = true);
            test.iter().for_each(|&k| is[k].1 = true);
            Some(is)
        } else {
            None
        };
        let mut chosen = Vec::with_capacity(order.len());
        for (pos, &k) in order.iter().enumerate() {
            // A frame in the train list trains, even when the test list
            // names it too (sdfl's `dataset` with nothing held out lists
            // every view in all three, for parsers that need the splits).
            let (is_train, is_test) = match &lists {
                Some(is) => is[k],
                None => {
                    let held = test_every > 0 && pos % test_every == 0 && order.len() > 1;
                    (!held, held)
                }
            };
            if is_train || is_test {
                chosen.push((k, !is_train));
            }
        }
        if chosen.iter().all(|(_, held)| *held) {
            return Err(invalid(
                &self.file,
                "no training frames (every frame is held out)",
            ));
        }
        Ok(chosen)
    }

    /// The frames as a capture ([`Transforms::selection`]): image sizes
    /// read from their headers, intrinsics resolved and checked (errors
    /// name the frame).
    pub fn capture(&self, downscale: u32, test_every: usize) -> io::Result<Capture> {
        let chosen = self.selection(test_every)?;
        let mut frames = Vec::with_capacity(chosen.len());
        let mut test = Vec::new();
        for (pos, &(k, held)) in chosen.iter().enumerate() {
            let f = &self.frames[k];
            let size = image_dimensions(&f.image)?;
            let intrinsics = self
                .intrinsics(k, size, downscale)
                .map_err(|e| invalid(&self.file, format!("frame {k}: {e}")))?;
            frames.push(CaptureFrame {
                label: format!("frame {k}"),
                image: f.image.clone(),
                mask: f.mask.clone(),
                object_mask: None,
                c2w: f.pose,
                intrinsics,
            });
            if held {
                test.push(pos);
            }
        }
        Ok(Capture {
            source: self.file.clone(),
            frames,
            test,
            applied: self.applied,
            points: Vec::new(),
            bounds: None,
        })
    }
}

