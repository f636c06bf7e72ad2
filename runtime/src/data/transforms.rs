//! `transforms.json` as nerfstudio (and instant-ngp, and NeRF-synthetic's
//! Blender files) write it: one camera-to-world `transform_matrix` per
//! frame in OpenGL axes, intrinsics global or per frame (`fl_x fl_y cx cy
//! w h`, or `camera_angle_x`/`camera_angle_y`), `camera_model` with its
//! distortion (`k1 k2 p1 p2`, fisheye `k1`–`k4`), `mask_path`, the split
//! lists `train_filenames`/`val_filenames`/`test_filenames` and
//! `applied_transform`. One reader serves the NeRF-synthetic and the
//! nerfstudio formats, so both read the same keys the same way.
//!
//! Hostile-input safe: the JSON is a capped regular file, every key is
//! checked, frames are capped, image paths stay inside the data set's
//! directory.

use std::io::{self, Read};
use std::path::{Path, PathBuf};

use sdfl_stdlib::builtins::MAX_VIEWS;
use serde_json::Value;

use super::camera::{check_rigid, CheckNamed, Distortion, Intrinsics, Keys};
use super::error::invalid;
use super::export::INCOMPLETE;
use super::image::{open_regular, MAX_SIDE};
use super::paths::{inside, relative};

/// Largest transforms file read: the 200-frame Blender files are ~0.1 MB,
/// 10 000 frames ~6 MB; parsed JSON takes up to ~16× its text.
pub const MAX_JSON_BYTES: u64 = 16 << 20;

/// `camera_model`: which lens the distortion keys describe.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraModel {
    /// `PINHOLE`, `SIMPLE_PINHOLE`, `SIMPLE_RADIAL`, `RADIAL`, `OPENCV` (and
    /// no `camera_model`): nerfstudio's perspective camera, with OpenCV
    /// distortion where `k1 k2 p1 p2` are nonzero.
    Perspective,
    /// `OPENCV_FISHEYE`: `k1`–`k4` of OpenCV's fisheye model.
    Fisheye,
}

impl CameraModel {
    fn parse(name: &str) -> Option<CameraModel> {
        match name {
            "PINHOLE" | "SIMPLE_PINHOLE" | "SIMPLE_RADIAL" | "RADIAL" | "OPENCV"
            | "PERSPECTIVE" => Some(CameraModel::Perspective),
            "OPENCV_FISHEYE" | "FISHEYE" => Some(CameraModel::Fisheye),
            _ => None,
        }
    }
}

/// The intrinsics keys of one object (the file's top level or a frame).
#[derive(Debug, Clone, Copy, Default)]
pub struct Lens {
    /// `fl_x`: horizontal focal length in pixels.
    pub fl_x: Option<f64>,
    /// `fl_y`: vertical focal length in pixels.
    pub fl_y: Option<f64>,
    /// `cx`: principal point's column in pixels.
    pub cx: Option<f64>,
    /// `cy`: principal point's row in pixels.
    pub cy: Option<f64>,
    /// `w`: image width in pixels the intrinsics are given at.
    pub w: Option<f64>,
    /// `h`: image height in pixels the intrinsics are given at.
    pub h: Option<f64>,
    /// `camera_angle_x`: horizontal field of view in radians (Blender files).
    pub camera_angle_x: Option<f64>,
    /// `camera_angle_y`: vertical field of view in radians.
    pub camera_angle_y: Option<f64>,
    /// `k1 k2 k3 k4 p1 p2`.
    pub k: [Option<f64>; 6],
}

const DISTORTION_KEYS: [&str; 6] = ["k1", "k2", "k3", "k4", "p1", "p2"];

fn number(v: &Value, key: &str) -> Result<Option<f64>, String> {
    match v.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Number(n)) => match n.as_f64() {
            Some(x) if x.is_finite() => Ok(Some(x)),
            _ => Err(format!("`{key}` is not a finite number")),
        },
        Some(_) => Err(format!("`{key}` is not a number")),
    }
}

impl Lens {
    fn read(v: &Value) -> Result<Lens, String> {
        let angle = |key: &str| -> Result<Option<f64>, String> {
            let a = number(v, key)?;
            if let Some(a) = a {
                if !(a > 0.0 && a < std::f64::consts::PI) {
                    return Err(format!("`{key}` {a} is not a field of view in (0, π)"));
                }
            }
            Ok(a)
        };
        let size = |key: &str| -> Result<Option<f64>, String> {
            let s = number(v, key)?;
            if let Some(s) = s {
                let max = MAX_SIDE as f64;
                if !(s >= 1.0 && s <= max && s.fract() == 0.0) {
                    return Err(format!(
                        "`{key}` {s} is not an image side (1 to {max} pixels)"
                    ));
                }
            }
            Ok(s)
        };
        let mut k = [None; 6];
        for (slot, key) in k.iter_mut().zip(DISTORTION_KEYS) {
            *slot = number(v, key)?;
        }
        Ok(Lens {
            fl_x: number(v, "fl_x")?,
            fl_y: number(v, "fl_y")?,
            cx: number(v, "cx")?,
            cy: number(v, "cy")?,
            w: size("w")?,
            h: size("h")?,
            camera_angle_x: angle("camera_angle_x")?,
            camera_angle_y: angle("camera_angle_y")?,
            k,
        })
    }

    /// The file's keys where it gives them (nerfstudio: a top-level key
    /// applies to every frame), else the frame's; the distortion keys as
    /// one group.
    fn over(&self, frame: &Lens) -> Lens {
        let global_k = self.k.iter().any(Option::is_some);
        Lens {
            fl_x: self.fl_x.or(frame.fl_x),
            fl_y: self.fl_y.or(frame.fl_y),
            cx: self.cx.or(frame.cx),
            cy: self.cy.or(frame.cy),
            w: self.w.or(frame.w),
            h: self.h.or(frame.h),
            camera_angle_x: self.camera_angle_x.or(frame.camera_angle_x),
            camera_angle_y: self.camera_angle_y.or(frame.camera_angle_y),
            k: if global_k { self.k } else { frame.k },
        }
    }
}

/// One frame of a transforms file.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The image, resolved against the transforms file's directory.
    pub image: PathBuf,
    /// The image path as written, components normalised (for split lists
    /// and downscaled folders).
    pub rel: PathBuf,
    /// The frame's `mask_path`, resolved: pixels masked 0 are ignored.
    pub mask: Option<PathBuf>,
    /// `transform_matrix`: OpenGL camera-to-world.
    pub pose: [[f64; 4]; 4],
    /// This frame's intrinsics keys with the file's applied.
    pub lens: Lens,
}

/// A transforms file, checked (not its images).
#[derive(Debug, Clone)]
pub struct Transforms {
    /// The transforms file itself (for messages and resolving paths).
    pub file: PathBuf,
    /// `camera_model`: the lens model the distortion keys follow.
    pub model: CameraModel,
    /// Every frame, in the file's order.
    pub frames: Vec<Frame>,
    /// `train_filenames`, `val_filenames`, `test_filenames` where given.
    pub splits: [Option<Vec<PathBuf>>; 3],
    /// `applied_transform`: rows of the 3×4 map from the original (COLMAP) frame to the file's.
    pub applied: Option<[[f64; 4]; 3]>,
}

fn outside(file_path: &str) -> String {
    format!("frame image `{file_path}` is not a relative path to a file inside the data set")
}

/// A 3×4 or 4×4 matrix of finite numbers, as rows.
fn matrix(v: &Value, rows: &[usize]) -> Option<Vec<[f64; 4]>> {
    let r = v.as_array().filter(|r| rows.contains(&r.len()))?;
    r.iter()
        .map(|row| {
            let c = row.as_array().filter(|c| c.len() == 4)?;
            let mut out = [0.0; 4];
            for (o, x) in out.iter_mut().zip(c) {
                *o = x.as_f64().filter(|x| x.is_finite())?;
            }
            Some(out)
        })
        .collect()
}

/// Reads and checks a transforms file (not its images), which lies in the
/// data set's directory. With `downscale` > 1 each image is read from
/// `images_<downscale>/` (and each mask from `masks_<downscale>/`) beside
/// the file, by its file name, as nerfstudio does.
pub fn read_transforms_scaled(path: &Path, downscale: u32) -> io::Result<Transforms> {
    let mut bytes = Vec::new();
    open_regular(path)?
        .take(MAX_JSON_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| invalid(path, e))?;
    if bytes.len() as u64 > MAX_JSON_BYTES {
        return Err(invalid(path, format!("larger than {MAX_JSON_BYTES} bytes")));
    }
    // serde_json limits nesting (128 levels), so hostile files cannot
    // overflow the stack.
    let root: Value = serde_json::from_slice(&bytes)
        .map_err(|e| invalid(path, format!("not valid JSON: {e}")))?;
    if !root.is_object() {
        return Err(invalid(path, "not a JSON object"));
    }
    if root.get(INCOMPLETE).is_some() {
        return Err(invalid(
            path,
            "sdfl was stopped while it wrote this data set, so its images may be a mix of two runs: run the statement that writes it again",
        ));
    }
    let model = match root.get("camera_model") {
        None => CameraModel::Perspective,
        Some(Value::String(s)) => CameraModel::parse(s).ok_or_else(|| {
            invalid(
                path,
                format!(
                    "`camera_model` \"{}\" is not one sdfl reads (PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE)",
                    s.chars().take(40).collect::<String>()
                ),
            )
        })?,
        Some(_) => return Err(invalid(path, "`camera_model` is not a string")),
    };
    let global = Lens::read(&root).map_err(|e| invalid(path, e))?;
    let frames_v = match root.get("frames") {
        Some(Value::Array(f)) => f,
        Some(_) => return Err(invalid(path, "`frames` is not a list")),
        None => return Err(invalid(path, "missing `frames`")),
    };
    if frames_v.is_empty() || frames_v.len() > MAX_VIEWS {
        return Err(invalid(
            path,
            format!("{} frames (1 to {MAX_VIEWS})", frames_v.len()),
        ));
    }
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    // Images in a downscaled folder, by file name.
    let scaled = |rel: &Path, prefix: &str| -> PathBuf {
        if downscale > 1 {
            let mut p = PathBuf::from(format!("{prefix}{downscale}"));
            p.push(rel.file_name().unwrap_or_default());
            p
        } else {
            rel.to_path_buf()
        }
    };
    let mut frames = Vec::with_capacity(frames_v.len());
    for (k, f) in frames_v.iter().enumerate() {
        let at = |m: &str| invalid(path, format!("frame {k}: {m}"));
        let file_path = f
            .get("file_path")
            .and_then(Value::as_str)
            .ok_or_else(|| at("missing `file_path` (a string)"))?;
        let pose = matrix(f.get("transform_matrix").unwrap_or(&Value::Null), &[4])
            .ok_or_else(|| {
                at("`transform_matrix` is not a 4x4 list of numbers (a non-finite or non-number entry)")
            })?;
        // A rigid pose's last row is [0, 0, 0, 1]; anything else is not a
        // camera-to-world matrix (the reader would silently ignore it).
        if pose[3]
            .iter()
            .zip([0.0, 0.0, 0.0, 1.0])
            .any(|(a, b)| (a - b).abs() > 1e-6)
        {
            return Err(at(&format!(
                "`transform_matrix`'s last row is {:?}, not [0, 0, 0, 1]",
                pose[3]
            )));
        }
        // Bounded here, before any normalisation: cameras at 1e300 would
        // be scaled into the unit cube and train, and exports mapped back
        // would not be finite.
        check_rigid("camera position", &[pose[0], pose[1], pose[2]])
            .map_err(|e| at(&format!("`transform_matrix`: {e}")))?;
        let lens = global.over(&Lens::read(f).map_err(|e| at(&e))?);
        if lens.fl_x.is_none() && lens.camera_angle_x.is_none() {
            return Err(at(
                "no focal length: give `fl_x` (pixels) or `camera_angle_x`",
            ));
        }
        let rel = relative(file_path, true).ok_or_else(|| at(&outside(file_path)))?;
        let image = inside(dir, &scaled(&rel, "images_"), file_path).map_err(|e| at(&e))?;
        let mask = match f.get("mask_path") {
            None | Some(Value::Null) => None,
            Some(Value::String(m)) => {
                let r = relative(m, false).ok_or_else(|| at(&outside(m)))?;
                Some(inside(dir, &scaled(&r, "masks_"), m).map_err(|e| at(&e))?)
            }
            Some(_) => return Err(at("`mask_path` is not a string")),
        };
        frames.push(Frame {
            image,
            rel,
            mask,
            pose: [pose[0], pose[1], pose[2], pose[3]],
            lens,
        });
    }
    // nerfstudio: masks on every frame or none.
    let masked = frames.iter().filter(|f| f.mask.is_some()).count();
    if masked != 0 && masked != frames.len() {
        return Err(invalid(
            path,
            format!(
                "{masked} of {} frames have a `mask_path`: give one for every frame or none",
                frames.len()
            ),
        ));
    }
    let mut splits: [Option<Vec<PathBuf>>; 3] = Default::default();
    for (slot, key) in splits
        .iter_mut()
        .zip(["train_filenames", "val_filenames", "test_filenames"])
    {
        *slot = match root.get(key) {
            None | Some(Value::Null) => None,
            Some(Value::Array(names)) => Some(
                names
                    .iter()
                    .map(|n| {
                        n.as_str()
                            .and_then(|s| relative(s, true))
                            .ok_or_else(|| {
                                invalid(path, format!("`{key}` holds an entry that is not a relative path inside the data set"))
                            })
                    })
                    .collect::<io::Result<_>>()?,
            ),
            Some(_) => return Err(invalid(path, format!("`{key}` is not a list"))),
        };
    }
    let applied = match root.get("applied_transform") {
        None | Some(Value::Null) => None,
        Some(v) => {
            let m = matrix(v, &[3, 4]).ok_or_else(|| {
                invalid(
                    path,
                    "`applied_transform` is not a 3x4 list of finite numbers",
                )
            })?;
            let m = [m[0], m[1], m[2]];
            check_rigid("translation", &m)
                .map_err(|e| invalid(path, format!("`applied_transform`: {e}")))?;
            Some(m)
        }
    };
    Ok(Transforms {
        file: path.to_path_buf(),
        model,
        frames,
        splits,
        applied,
    })
}

/// Reads and checks a transforms file (not its images).
pub fn read_transforms(path: &Path) -> io::Result<Transforms> {
    read_transforms_scaled(path, 1)
}

impl Transforms {
    /// Frame `k`'s intrinsics for its `w × h` image, read at `1/downscale`
    /// of the size the file describes: `fl_x` or `camera_angle_x` (the
    /// file's `w` or the image's), `fl_y` or `camera_angle_y` or `fl_x`,
    /// `cx`/`cy` or the centre, distortion by `camera_model`; all scaled
    /// by `1/downscale` as nerfstudio does. Checked: a size the file
    /// states must match the image.
    pub fn intrinsics(
        &self,
        k: usize,
        (w, h): (u32, u32),
        downscale: u32,
    ) -> Result<Intrinsics, String> {
        let l = &self.frames[k].lens;
        let d = downscale.max(1) as f64;
        let (wi, hi) = (w as f64, h as f64);
        // The file's size, at full resolution.
        for (key, given, img) in [("w", l.w, wi), ("h", l.h, hi)] {
            if let Some(g) = given {
                let ok = if d == 1.0 {
                    g == img
                } else {
                    (g / d - img).abs() < 1.0
                };
                if !ok {
                    return Err(format!(
                        "`{key}` is {g} but the image is {w}x{h} pixels{}",
                        if d > 1.0 {
                            format!(" (read at 1/{d} of the size)")
                        } else {
                            String::new()
                        }
                    ));
                }
            }
        }
        let (wf, hf) = (l.w.unwrap_or(wi * d), l.h.unwrap_or(hi * d));
        let (fx, fx_key, fx_given) = match (l.fl_x, l.camera_angle_x) {
            (Some(f), _) => (f, "fl_x", f),
            (None, Some(a)) => (wf / 2.0 / (a / 2.0).tan(), "camera_angle_x", a),
            (None, None) => {
                return Err("no focal length: give `fl_x` (pixels) or `camera_angle_x`".into())
            }
        };
        let (fy, fy_key, fy_given) = match (l.fl_y, l.camera_angle_y) {
            (Some(f), _) => (f, "fl_y", f),
            (None, Some(a)) => (hf / 2.0 / (a / 2.0).tan(), "camera_angle_y", a),
            (None, None) => (fx, fx_key, fx_given),
        };
        let [k1, k2, k3, k4, p1, p2] = l.k.map(|x| x.unwrap_or(0.0));
        let distortion = match self.model {
            CameraModel::Perspective => {
                if k3 != 0.0 || k4 != 0.0 {
                    return Err(format!(
                        "distortion `{}` is not read for a perspective camera (only k1, k2, p1, p2: OpenCV's four-parameter model)",
                        if k3 != 0.0 { "k3" } else { "k4" }
                    ));
                }
                if [k1, k2, p1, p2].iter().all(|x| *x == 0.0) {
                    Distortion::None
                } else {
                    Distortion::OpenCv { k1, k2, p1, p2 }
                }
            }
            CameraModel::Fisheye => {
                if p1 != 0.0 || p2 != 0.0 {
                    return Err("`p1`/`p2` do not belong to the OPENCV_FISHEYE model".into());
                }
                Distortion::Fisheye { k1, k2, k3, k4 }
            }
        };
        let k = Intrinsics {
            width: w,
            height: h,
            fx: fx / d,
            fy: fy / d,
            cx: l.cx.unwrap_or(wf / 2.0) / d,
            cy: l.cy.unwrap_or(hf / 2.0) / d,
            distortion,
        };
        k.check_named(
            Keys {
                fx: fx_key,
                fy: fy_key,
            },
            (fx_given, fy_given),
        )?;
        Ok(k)
    }
}
