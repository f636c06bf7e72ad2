//! Real captures: frames (an image, an optional mask, an OpenGL
//! camera-to-world pose and pixel intrinsics) read from nerfstudio's
//! `transforms.json`, COLMAP's text model, LLFF's `poses_bounds.npy` or
//! IDR's `cameras_sphere.npz`, normalised into sdfl's scene frame and
//! turned into training views.
//!
//! The four readers only parse; what they share (image sizes checked
//! before decoding, the scene frame, splits, alpha over a background,
//! masks) is done here once.

use std::io;
use std::path::{Path, PathBuf};

use glam::DVec3;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::value::{CaptureFormat, CaptureOrient, CaptureSpec, ObjectMasks};

use super::image::{check_dataset, read_rgba_image, read_view_images};
use super::normalize::{Orient, SceneFrame};
use super::{no_coverage, DataNeeds, TrainView};

pub use sdfl_stdlib::lens::{Distortion, Intrinsics};

pub(crate) fn invalid(path: &Path, m: impl std::fmt::Display) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("{}: {m}", path.display()),
    )
}

/// Largest distortion coefficient accepted: real lenses stay well below 1;
/// larger ones are garbage that would fold the image over.
pub const MAX_DISTORTION: f64 = 10.0;

/// Where each number of a frame's intrinsics came from, for messages.
#[derive(Debug, Clone, Copy)]
pub struct Keys {
    /// The key that gave the horizontal focal length.
    pub fx: &'static str,
    /// The key that gave the vertical focal length.
    pub fy: &'static str,
}

/// Checks of intrinsics read from a file, by the keys it used.
pub trait CheckNamed {
    /// Checks what a file gave: finite positive focal lengths in the range
    /// `look_at(focal: ...)` allows (in its NDC units), a principal point
    /// inside the image, distortion coefficients finite and small.
    fn check_named(&self, keys: Keys, given: (f64, f64)) -> Result<(), String>;
}

impl CheckNamed for Intrinsics {
    fn check_named(&self, keys: Keys, given: (f64, f64)) -> Result<(), String> {
        let (w, h) = (self.width as f64, self.height as f64);
        let (lo, hi) = sdfl_stdlib::precision::F32_SAFE;
        for (fl, side, key, g) in [
            (self.fx, w, keys.fx, given.0),
            (self.fy, h, keys.fy, given.1),
        ] {
            let ndc = 2.0 * fl / side;
            if !(fl.is_finite() && (lo..=hi).contains(&ndc)) {
                return Err(format!(
                    "`{key}` {} gives a focal length of {ndc:e} (in `look_at`'s units) for {}x{} images, outside {lo:e} to {hi:e}",
                    sdfl_lang::fmt_num(g),
                    self.width,
                    self.height
                ));
            }
        }
        // The range `lens(...)` allows (an image away from the image), so
        // what sdfl writes reads back.
        for (key, c, side) in [("cx", self.cx, w), ("cy", self.cy, h)] {
            if !(c.is_finite() && c > -side && c < 2.0 * side) {
                return Err(format!(
                    "`{key}` {} puts the principal point more than an image away from the {}x{} image",
                    sdfl_lang::fmt_num(c),
                    self.width,
                    self.height
                ));
            }
        }
        let ks: Vec<(&str, f64)> = match self.distortion {
            Distortion::None => Vec::new(),
            Distortion::OpenCv { k1, k2, p1, p2 } => {
                vec![("k1", k1), ("k2", k2), ("p1", p1), ("p2", p2)]
            }
            Distortion::Fisheye { k1, k2, k3, k4 } => {
                vec![("k1", k1), ("k2", k2), ("k3", k3), ("k4", k4)]
            }
        };
        for (key, k) in ks {
            if !(k.is_finite() && k.abs() <= MAX_DISTORTION) {
                return Err(format!(
                    "distortion `{key}` {} is out of range (|{key}| ≤ {MAX_DISTORTION})",
                    sdfl_lang::fmt_num(k)
                ));
            }
        }
        // Then sdfl's own: the distortion one-to-one over the image.
        self.check()
    }
}

/// The sdfl camera of an OpenGL camera-to-world pose (camera looks down
/// −z, +y up, +x right) with pixel intrinsics.
pub fn camera_of(c2w: &[[f64; 4]; 4], k: &Intrinsics) -> Result<Camera, String> {
    Camera::from_opengl_intrinsics(c2w, *k)
}

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

/// How a capture is normalised into the scene frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Normalize {
    /// Centre and scale from the cameras; `false` keeps the data's frame.
    pub enabled: bool,
    /// Which way the scene frame's up axis is chosen.
    pub orient: Orient,
    /// The farthest camera coordinate after scaling (nerfstudio: 1).
    pub extent: f64,
}

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

/// A forward-facing capture (LLFF) as NDC needs it: the reference
/// camera's frame, and the farthest depth bound in scene units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForwardFacing {
    /// The reference camera's frame that NDC rays are warped into.
    pub ndc: sdfl_stdlib::value::NdcFrame,
    /// The farthest depth bound, in scene units: NDC's far plane.
    pub far: f64,
}

/// Views held out: every `every`-th frame from the first (nerfstudio's
/// "interval" split, LLFF's `llffhold`); none for 0.
pub fn every_nth(n: usize, every: usize) -> Vec<usize> {
    if every == 0 || n < 2 {
        return Vec::new();
    }
    (0..n).step_by(every).collect()
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
/// its cameras into the scene frame (`frame`, or one from the cameras by
/// `normalize`) and composites images with alpha over `background`. With
/// `needs.coverage`, each training view's coverage is its object mask
/// where it has one, else its image's alpha (an error where an image has
/// none); masks keep their own meaning (which pixels are trained on and
/// scored).
pub fn load(
    c: &Capture,
    normalize: Normalize,
    frame: Option<SceneFrame>,
    background: DVec3,
    needs: DataNeeds,
    masks: ObjectMasks,
) -> io::Result<CaptureViews> {
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
    let bg = background.as_vec3().to_array();
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
    Ok(CaptureViews {
        train,
        test,
        names,
        frame,
        report,
        forward_facing: None,
    })
}

/// The format a capture directory holds: `transforms.json`, then a COLMAP
/// text model, then `poses_bounds.npy`, then `cameras_sphere.npz`.
pub fn detect(dir: &Path) -> Option<CaptureFormat> {
    if dir
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
        || dir.join("transforms.json").is_file()
    {
        Some(CaptureFormat::Nerfstudio)
    } else if super::colmap::model_dir(dir).is_some() {
        Some(CaptureFormat::Colmap)
    } else if dir.join("poses_bounds.npy").is_file() {
        Some(CaptureFormat::Llff)
    } else if dir.join(super::idr::CAMERAS).is_file() {
        Some(CaptureFormat::Idr)
    } else {
        None
    }
}

/// The format of the capture at `path` (`spec.path` resolved): as given,
/// or detected.
pub fn format_of(spec: &CaptureSpec, path: &Path) -> io::Result<CaptureFormat> {
    match spec.format {
        CaptureFormat::Auto => detect(path).ok_or_else(|| {
            invalid(
                path,
                "holds no transforms.json, COLMAP model (sparse/0/cameras.txt), poses_bounds.npy or cameras_sphere.npz",
            )
        }),
        f => Ok(f),
    }
}

/// A nerfstudio capture's transforms file: `path` itself when it is a
/// `.json` file, else `path/transforms.json`.
pub fn nerfstudio_file(path: &Path) -> PathBuf {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        path.to_path_buf()
    } else {
        path.join("transforms.json")
    }
}

/// Reads the capture `spec` names (relative to `base`): its frames, split,
/// scene frame and images.
pub fn read(spec: &CaptureSpec, base: &Path) -> io::Result<CaptureViews> {
    read_for(spec, base, DataNeeds::default())
}

/// [`read`], with what the job reads beyond colours (`needs`).
pub fn read_for(spec: &CaptureSpec, base: &Path, needs: DataNeeds) -> io::Result<CaptureViews> {
    let path = base.join(&spec.path);
    let format = format_of(spec, &path)?;
    let normalize = Normalize {
        enabled: spec.normalize,
        orient: match spec.orient {
            CaptureOrient::None => Orient::None,
            CaptureOrient::Up => Orient::Up,
        },
        extent: spec.extent,
    };
    let (capture, frame) = match format {
        CaptureFormat::Nerfstudio | CaptureFormat::Auto => {
            let file = nerfstudio_file(&path);
            let t = super::nerfstudio::read_transforms_scaled(&file, spec.downscale)?;
            (t.capture(spec.downscale, spec.test_every)?, None)
        }
        CaptureFormat::Colmap => (
            super::colmap::read(&path, spec.downscale, spec.test_every)?,
            None,
        ),
        CaptureFormat::Llff => {
            let (c, frame) = super::llff::read(&path, spec.downscale, spec.test_every)?;
            (c, spec.normalize.then_some(frame))
        }
        // The unit sphere of `scale_mat` is the frame NeuS trains in; the
        // cameras' own centring and `orient`/`extent` do not apply.
        CaptureFormat::Idr => {
            let (c, frame) = super::idr::read(&path, spec.downscale, spec.test_every)?;
            (c, spec.normalize.then_some(frame))
        }
    };
    let llff = format == CaptureFormat::Llff && spec.normalize;
    let mut views = load(
        &capture,
        normalize,
        frame,
        spec.background.unwrap_or(glam::DVec3::ONE),
        needs,
        spec.object_masks,
    )?;
    if format == CaptureFormat::Idr && spec.normalize {
        views.report.insert(
            1,
            "scene frame: cameras_sphere.npz's scale_mat, the object's bounding sphere is the unit sphere (exports map back to the world frame)".to_string(),
        );
    }
    // LLFF's normalisation puts the average camera at the origin looking
    // down −z and the nearest bound at 1/BD_FACTOR: NDC's near plane is 1,
    // as NeRF's. Every frame shares one camera (poses_bounds.npy's hwf).
    if let (true, Some(first), Some((_, far))) = (llff, capture.frames.first(), capture.bounds) {
        let i = &first.intrinsics;
        views.forward_facing = Some(ForwardFacing {
            ndc: sdfl_stdlib::value::NdcFrame {
                width: i.width as f64,
                height: i.height as f64,
                fx: i.fx,
                fy: i.fy,
                near: 1.0,
            },
            far: far * views.frame.scale,
        });
    }
    Ok(views)
}

/// A frame's mask image (`what`: "mask", "object mask"), which must be
/// its image's size.
fn read_mask_image(
    path: &Path,
    what: &str,
    size: (u32, u32),
    f: &CaptureFrame,
    source: &Path,
) -> io::Result<super::image::RgbaImage> {
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
