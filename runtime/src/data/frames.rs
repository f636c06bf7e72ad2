//! A capture's frames (an image, an optional mask, an OpenGL
//! camera-to-world pose and pixel intrinsics) as the capture formats
//! (nerfstudio, COLMAP, LLFF, IDR) read them, and what they share once
//! read: image sizes checked before decoding, the scene frame, splits,
//! alpha over a background, masks and object masks, turned into training
//! views.

use std::io;
use std::path::{Path, PathBuf};

use glam::DVec3;
use sdfl_stdlib::value::ObjectMasks;

use super::camera::{camera_of, Intrinsics};
use super::error::{invalid, no_coverage};
use super::format::{FormatViews, PlannedView, Request};
use super::image::{check_dataset, read_rgba_image, read_view_images, RgbaImage};
use super::normalize::SceneFrame;
use super::view::TrainView;

/// One frame of a capture, checked.
#[derive(Debug, Clone)]
pub struct CaptureFrame {
    /// The frame as its file names it (`frame 3`, `image a.jpg`), for
    /// messages.
    pub label: String,
    /// The frame's image file, resolved against the capture's directory.
    pub image: PathBuf,
    /// Pixels whose mask is 0 are neither trained on nor scored.
    pub mask: Option<PathBuf>,
    /// The object's mask (IDR's `mask/`): where it is white the object
    /// covers the pixel. Read only for `silhouette()`, as each pixel's
    /// coverage in place of alpha; every pixel is still trained on.
    pub object_mask: Option<PathBuf>,
    /// Camera to world in OpenGL axes, in the data's own frame.
    pub c2w: [[f64; 4]; 4],
    /// Pixel intrinsics and distortion at the image's full resolution.
    pub intrinsics: Intrinsics,
}

/// A capture's frames, their split, and the file they came from.
#[derive(Debug, Clone)]
pub struct Capture {
    /// The file that describes the frames (for messages).
    pub source: PathBuf,
    /// Every registered frame, in the file's order.
    pub frames: Vec<CaptureFrame>,
    /// Indices into `frames` held out as test views (sorted).
    pub test: Vec<usize>,
    /// nerfstudio's `applied_transform`: from the original (COLMAP) frame
    /// to the file's, as rows of a 3×4 matrix.
    pub applied: Option<[[f64; 4]; 3]>,
    /// Sparse points of the reconstruction (COLMAP's `points3D.txt`), in
    /// the data's frame, for the scene's bounds.
    pub points: Vec<DVec3>,
    /// The depth bounds of the frames (LLFF), in the data's units.
    pub bounds: Option<(f64, f64)>,
}

/// Views held out: every `every`-th frame from the first (nerfstudio's
/// "interval" split, LLFF's `llffhold`); none for 0.
pub fn every_nth(n: usize, every: usize) -> Vec<usize> {
    if every == 0 || n < 2 {
        return Vec::new();
    }
    (0..n).step_by(every).collect()
}

/// `images` as a run will read them, without masks, every `every`-th
/// held out ([`every_nth`]): what formats that list images plan.
pub fn planned_every_nth(images: Vec<PathBuf>, every: usize) -> Vec<PlannedView> {
    let test = every_nth(images.len(), every);
    images
        .into_iter()
        .enumerate()
        .map(|(k, image)| PlannedView {
            image,
            mask: false,
            held_out: test.binary_search(&k).is_ok(),
            downscale: 1,
        })
        .collect()
}

/// [`every_nth`] of a capture's `n` frames, refused where it would hold
/// every one out (`what`: the file's word for them, "images", "frames").
pub fn held_out_every(n: usize, every: usize, file: &Path, what: &str) -> io::Result<Vec<usize>> {
    let test = every_nth(n, every);
    if test.len() == n {
        return Err(invalid(
            file,
            format!("no training {what} (every one is held out)"),
        ));
    }
    Ok(test)
}

/// Reads a capture's images (sizes checked before any is decoded), moves
/// its cameras into the scene frame (the format's `own_frame` where it
/// has one and `request` normalises, else one from the cameras by
/// `request.normalize`) and composites images with alpha over
/// `request.background`. With `request.needs.coverage`, each training
/// view's coverage is its object mask where it has one, else its image's
/// alpha (an error where an image has none); masks keep their own meaning
/// (which pixels are trained on and scored).
pub fn load(
    c: &Capture,
    request: &Request,
    own_frame: Option<SceneFrame>,
) -> io::Result<FormatViews> {
    let (normalize, needs, masks) = (request.normalize, request.needs, request.object_masks);
    let frame = own_frame.filter(|_| normalize.enabled);
    if masks == ObjectMasks::Alpha {
        if let Some(f) = c.frames.iter().find(|f| f.object_mask.is_none()) {
            return Err(invalid(
                &c.source,
                format!("{}: no object mask to composite by (`object_masks: \"alpha\"` needs IDR's mask/ for every image)", f.label),
            ));
        }
    }
    check_dataset(c.frames.iter().flat_map(|f| {
        let object = f.object_mask.as_ref().filter(|_| needs.coverage);
        std::iter::once(&f.image).chain(&f.mask).chain(object)
    }))?;
    let frame = frame.unwrap_or_else(|| {
        if normalize.enabled {
            let poses: Vec<_> = c.frames.iter().map(|f| f.c2w).collect();
            SceneFrame::from_cameras(&poses, normalize.orient, normalize.extent)
        } else {
            SceneFrame::IDENTITY
        }
    });
    let frame = SceneFrame {
        applied: c.applied,
        ..frame
    };
    let cameras = c
        .frames
        .iter()
        .map(|f| {
            camera_of(&frame.pose_to_scene(&f.c2w), &f.intrinsics)
                .map_err(|e| invalid(&c.source, format!("{}: {e}", f.label)))
        })
        .collect::<io::Result<Vec<_>>>()?;
    let bg = request.background.as_vec3().to_array();
    let (mut train, mut test, mut names) = (Vec::new(), Vec::new(), Vec::new());
    let mut test_names = Vec::new();
    // Held-out frames no evaluation scores are never decoded.
    let keep = needs.keeps_held_out(c.test.len());
    let read: Vec<usize> = (0..c.frames.len())
        .filter(|k| c.test.binary_search(k).map_or(true, |i| keep[i]))
        .collect();
    // Decoded a batch at a time in parallel, kept in the frames' order.
    let images: Vec<&Path> = read.iter().map(|&k| c.frames[k].image.as_path()).collect();
    read_view_images(&images, |i, rgba| {
        let k = read[i];
        let (f, camera) = (&c.frames[k], cameras[k]);
        let (w, h) = (rgba.width, rgba.height);
        if (w, h) != (f.intrinsics.width, f.intrinsics.height) {
            return Err(invalid(
                &f.image,
                format!(
                    "{w}x{h} pixels, but {} of {} says {}x{}",
                    f.label,
                    c.source.display(),
                    f.intrinsics.width,
                    f.intrinsics.height
                ),
            ));
        }
        // Training batches draw from views of one size.
        let first = &c.frames[0];
        if (w, h) != (first.intrinsics.width, first.intrinsics.height) {
            return Err(invalid(
                &f.image,
                format!(
                    "{w}x{h} pixels, but {} has {}x{}: sdfl trains on images of one size (resize them, or downscale them alike)",
                    first.label, first.intrinsics.width, first.intrinsics.height
                ),
            ));
        }
        let held_out = c.test.binary_search(&k).is_ok();
        // An object mask is read where training's silhouette, the
        // compositing or a held-out view's PSNR inside it needs it.
        let object = match &f.object_mask {
            Some(m) if needs.coverage || held_out || masks == ObjectMasks::Alpha => {
                Some(read_object_mask(m, (w, h), f, &c.source)?)
            }
            _ => None,
        };
        let rgba = match (&object, masks) {
            (Some(m), ObjectMasks::Alpha) => rgba.with_alpha(m),
            _ => rgba,
        };
        // A held-out view keeps its object mask, for PSNR inside it;
        // otherwise held-out views are only scored.
        let coverage = match (needs.coverage && !held_out, object) {
            (false, object) => object.filter(|_| held_out),
            (true, Some(m)) => Some(m),
            (true, None) if rgba.has_alpha => Some(rgba.coverage()),
            (true, None) => return Err(no_coverage(&f.image)),
        };
        let mask = match &f.mask {
            None => None,
            Some(m) => Some(read_mask(m, (w, h), f, &c.source)?),
        };
        let view = TrainView {
            camera,
            image: rgba.over(bg),
            mask,
            coverage,
        };
        let name = format!("{} {}", c.source.display(), f.label);
        if held_out {
            test.push(view);
            test_names.push(name);
        } else {
            train.push(view);
            names.push(name);
        }
        Ok(())
    })?;
    names.extend(test_names);
    let mut report = vec![frame.describe()];
    if let Some((lo, hi)) = points_extent(&c.points, &frame) {
        report.push(format!(
            "scene frame: the middle 98% of {} sparse points span [{}, {}] x [{}, {}] x [{}, {}]",
            c.points.len(),
            short(lo.x),
            short(hi.x),
            short(lo.y),
            short(hi.y),
            short(lo.z),
            short(hi.z)
        ));
    }
    if let Some((near, far)) = c.bounds {
        report.push(format!(
            "scene frame: depth bounds {} to {} (NDC rays start at depth 1)",
            short(near * frame.scale),
            short(far * frame.scale)
        ));
    }
    Ok(FormatViews {
        train,
        test,
        names,
        frame: Some(frame),
        report,
        forward_facing: None,
    })
}

/// A frame's mask image (`what`: "mask", "object mask"), which must be
/// its image's size.
fn read_mask_image(
    path: &Path,
    what: &str,
    size: (u32, u32),
    f: &CaptureFrame,
    source: &Path,
) -> io::Result<RgbaImage> {
    let mask = read_rgba_image(path)?;
    let (w, h) = (mask.width, mask.height);
    if (w, h) != size {
        return Err(invalid(
            path,
            format!(
                "the {what} of {} of {} is {w}x{h} pixels, its image {}x{}",
                f.label,
                source.display(),
                size.0,
                size.1
            ),
        ));
    }
    Ok(mask)
}

/// A frame's mask: a pixel is kept where the mask image is not black (as
/// nerfstudio reads `mask_path`: nonzero keeps), the image's size.
fn read_mask(
    path: &Path,
    size: (u32, u32),
    f: &CaptureFrame,
    source: &Path,
) -> io::Result<std::sync::Arc<[bool]>> {
    let keep: std::sync::Arc<[bool]> = read_mask_image(path, "mask", size, f, source)?
        .pixels
        .iter()
        .map(|p| p[0].max(p[1]).max(p[2]) > 0.0)
        .collect();
    if !keep.iter().any(|k| *k) {
        return Err(invalid(
            path,
            format!(
                "the mask of {} of {} masks every pixel",
                f.label,
                source.display()
            ),
        ));
    }
    Ok(keep)
}

/// A frame's object mask as each pixel's coverage in 255ths: covered
/// (255) where the mask is brighter than half, as NeuS binarises
/// `mask > 0.5`; the image's size.
fn read_object_mask(
    path: &Path,
    size: (u32, u32),
    f: &CaptureFrame,
    source: &Path,
) -> io::Result<std::sync::Arc<[u8]>> {
    Ok(read_mask_image(path, "object mask", size, f, source)?
        .pixels
        .iter()
        .map(|p| {
            if p[0].max(p[1]).max(p[2]) > 0.5 {
                255
            } else {
                0
            }
        })
        .collect())
}

fn short(x: f64) -> String {
    sdfl_lang::fmt_num((x * 1000.0).round() / 1000.0)
}

/// The box of the middle 98% of `points` along each axis, in the scene
/// frame (outliers of a sparse reconstruction left out).
pub fn points_extent(points: &[DVec3], frame: &SceneFrame) -> Option<(DVec3, DVec3)> {
    if points.is_empty() {
        return None;
    }
    let moved: Vec<DVec3> = points.iter().map(|p| frame.to_scene(*p)).collect();
    let n = moved.len();
    let (lo_k, hi_k) = (n / 100, (n - 1) - n / 100);
    let mut lo = DVec3::ZERO;
    let mut hi = DVec3::ZERO;
    for axis in 0..3 {
        let mut v: Vec<f64> = moved.iter().map(|p| p[axis]).collect();
        v.sort_by(f64::total_cmp);
        lo[axis] = v[lo_k];
        hi[axis] = v[hi_k];
    }
    Some((lo, hi))
}
