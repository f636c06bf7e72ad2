//! NeRF-synthetic (Blender) data sets: `transforms_<split>.json` with one
//! camera-to-world `transform_matrix` per frame in OpenGL axes (the camera
//! looks down −z, +y up, +x right), `camera_angle_x` (the horizontal field
//! of view; `fl_x`/`fl_y` in pixels where given), and RGBA PNGs.
//!
//! Poses convert exactly to sdfl cameras (`Camera::from_opengl`): the same
//! ray through every pixel, pixel `i` centred at `i + ½` as Blender renders
//! (the original NeRF code's rays are half a pixel off that). Reading is
//! hostile-input safe: the JSON is a capped regular file, every key is
//! checked, frames are capped, image paths stay inside the data set's
//! directory and image sizes are checked before anything is decoded.

use std::io::{self, Read};
use std::path::{Component, Path, PathBuf};

use glam::DVec3;
use sdfl_stdlib::builtins::MAX_VIEWS;
use sdfl_stdlib::camera::{Camera, GlPose};
use serde_json::Value;

use super::export::INCOMPLETE;
use super::image::{check_dataset, open_regular, read_rgba_image};
use super::npy::RgbImage;
use crate::train::TrainView;

/// Largest transforms file read: the 200-frame Blender files are ~0.1 MB,
/// 10 000 frames ~6 MB; parsed JSON takes up to ~16× its text.
pub const MAX_JSON_BYTES: u64 = 16 << 20;

fn invalid(path: &Path, m: impl std::fmt::Display) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("{}: {m}", path.display()),
    )
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

/// One frame of a transforms file.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The image, resolved against the transforms file's directory.
    pub image: PathBuf,
    pub pose: [[f64; 4]; 4],
}

/// A transforms file, checked.
#[derive(Debug, Clone)]
pub struct Transforms {
    pub camera_angle_x: f64,
    /// Pixel focal lengths and image size, where the file gives them.
    pub fl_x: Option<f64>,
    pub fl_y: Option<f64>,
    pub cx: Option<f64>,
    pub cy: Option<f64>,
    pub w: Option<f64>,
    pub h: Option<f64>,
    pub frames: Vec<Frame>,
}

fn number(v: &Value, key: &str, at: &Path) -> io::Result<Option<f64>> {
    match v.get(key) {
        None => Ok(None),
        Some(Value::Number(n)) => match n.as_f64() {
            Some(x) if x.is_finite() => Ok(Some(x)),
            _ => Err(invalid(at, format!("`{key}` is not a finite number"))),
        },
        Some(_) => Err(invalid(at, format!("`{key}` is not a number"))),
    }
}

/// An image path of a frame: relative, naming a file strictly inside the
/// data set (no `..`, no root, not `.` itself), `.png` added when it has no
/// extension (as Blender's files omit it), and, links followed, still
/// inside the data set's directory.
fn frame_image(dir: &Path, file_path: &str, at: &Path) -> io::Result<PathBuf> {
    let outside = || {
        invalid(
            at,
            format!(
                "frame image `{file_path}` is not a relative path to a file inside the data set"
            ),
        )
    };
    if file_path.contains('\0') {
        return Err(outside());
    }
    // Only named components: `./r_0` is `r_0`, and `.` or `./` name the
    // directory itself (whose `.png` would lie beside it).
    let mut rel = PathBuf::new();
    for c in Path::new(file_path).components() {
        match c {
            Component::Normal(n) => rel.push(n),
            Component::CurDir => {}
            _ => return Err(outside()),
        }
    }
    if rel.as_os_str().is_empty() {
        return Err(outside());
    }
    let mut image = dir.join(rel);
    if image.extension().is_none() {
        image.set_extension("png");
    }
    let named = |e: io::Error| invalid(&image, e);
    let (real, real_dir) = (
        image.canonicalize().map_err(named)?,
        dir.canonicalize().map_err(|e| invalid(dir, e))?,
    );
    if !real.starts_with(&real_dir) || real == real_dir {
        return Err(invalid(
            at,
            format!(
                "frame image `{file_path}` leads outside the data set (to {})",
                real.display()
            ),
        ));
    }
    Ok(image)
}

/// Reads and checks a transforms file (not its images).
pub fn read_transforms(path: &Path) -> io::Result<Transforms> {
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
    let camera_angle_x = number(&root, "camera_angle_x", path)?
        .ok_or_else(|| invalid(path, "missing `camera_angle_x`"))?;
    if !(camera_angle_x > 0.0 && camera_angle_x < std::f64::consts::PI) {
        return Err(invalid(
            path,
            format!("`camera_angle_x` {camera_angle_x} is not a field of view in (0, π)"),
        ));
    }
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
    let mut frames = Vec::with_capacity(frames_v.len());
    for (k, f) in frames_v.iter().enumerate() {
        let at = |m: &str| invalid(path, format!("frame {k}: {m}"));
        let file_path = f
            .get("file_path")
            .and_then(Value::as_str)
            .ok_or_else(|| at("missing `file_path` (a string)"))?;
        let rows = f
            .get("transform_matrix")
            .and_then(Value::as_array)
            .filter(|r| r.len() == 4)
            .ok_or_else(|| at("`transform_matrix` is not a 4x4 list of numbers"))?;
        let mut pose = [[0.0; 4]; 4];
        for (r, row) in rows.iter().enumerate() {
            let row = row
                .as_array()
                .filter(|c| c.len() == 4)
                .ok_or_else(|| at("`transform_matrix` is not a 4x4 list of numbers"))?;
            for (c, v) in row.iter().enumerate() {
                pose[r][c] = v.as_f64().filter(|x| x.is_finite()).ok_or_else(|| {
                    at("`transform_matrix` holds a non-finite or non-number entry")
                })?;
            }
        }
        frames.push(Frame {
            image: frame_image(dir, file_path, path).map_err(|e| {
                // Not the path twice.
                let m = e.to_string();
                at(m.strip_prefix(&format!("{}: ", path.display()))
                    .unwrap_or(&m))
            })?,
            pose,
        });
    }
    Ok(Transforms {
        camera_angle_x,
        fl_x: number(&root, "fl_x", path)?,
        fl_y: number(&root, "fl_y", path)?,
        cx: number(&root, "cx", path)?,
        cy: number(&root, "cy", path)?,
        w: number(&root, "w", path)?,
        h: number(&root, "h", path)?,
        frames,
    })
}

impl Transforms {
    /// The pixel focal lengths for `w × h` images: `fl_x`/`fl_y` where
    /// given, else from `camera_angle_x` with square pixels. A principal
    /// point or size the file states must match the images.
    pub fn focal_pixels(&self, w: u32, h: u32, at: &Path) -> io::Result<(f64, f64)> {
        let (wf, hf) = (w as f64, h as f64);
        for (key, given, want) in [
            ("w", self.w, wf),
            ("h", self.h, hf),
            ("cx", self.cx, wf / 2.0),
            ("cy", self.cy, hf / 2.0),
        ] {
            if let Some(g) = given {
                if (g - want).abs() > 1e-6 * want.max(1.0) {
                    return Err(invalid(
                        at,
                        format!("`{key}` is {g} but the {w}x{h} images need {want} (sdfl cameras have a centred principal point)"),
                    ));
                }
            }
        }
        let from_angle = wf / 2.0 / (self.camera_angle_x / 2.0).tan();
        let fl_x = self.fl_x.unwrap_or(from_angle);
        let fl_y = self.fl_y.unwrap_or(fl_x);
        // The range `look_at(focal: ...)` allows, in the same NDC units.
        let (lo, hi) = sdfl_stdlib::precision::F32_SAFE;
        for (fl, side, key) in [
            (
                fl_x,
                wf,
                if self.fl_x.is_some() {
                    "fl_x"
                } else {
                    "camera_angle_x"
                },
            ),
            (
                fl_y,
                hf,
                if self.fl_y.is_some() {
                    "fl_y"
                } else if self.fl_x.is_some() {
                    "fl_x"
                } else {
                    "camera_angle_x"
                },
            ),
        ] {
            let ndc = 2.0 * fl / side;
            if !(lo..=hi).contains(&ndc) {
                let given = match key {
                    "fl_x" => self.fl_x,
                    "fl_y" => self.fl_y,
                    _ => Some(self.camera_angle_x),
                };
                return Err(invalid(
                    at,
                    format!(
                        "`{key}` {} gives a focal length of {ndc:e} (in `look_at`'s units) for {w}x{h} images, outside {lo:e} to {hi:e}",
                        sdfl_lang::fmt_num(given.unwrap_or(f64::NAN))
                    ),
                ));
            }
        }
        Ok((fl_x, fl_y))
    }
}

/// Reads one split's views, composited over `background`: every image the
/// same size, checked before any is decoded.
pub fn read_split(path: &Path, split: &str, background: DVec3) -> io::Result<Vec<TrainView>> {
    read_splits(path, &[split], background).map(|mut s| s.remove(0))
}

/// Reads several splits' views (one list each), every image's declared
/// size checked (all splits together within the data-set limit) before
/// any is decoded.
pub fn read_splits(
    path: &Path,
    splits: &[&str],
    background: DVec3,
) -> io::Result<Vec<Vec<TrainView>>> {
    let files: Vec<PathBuf> = splits.iter().map(|s| transforms_path(path, s)).collect();
    let all = files
        .iter()
        .map(|f| read_transforms(f))
        .collect::<io::Result<Vec<_>>>()?;
    check_dataset(all.iter().flat_map(|t| t.frames.iter().map(|f| &f.image)))?;
    files
        .iter()
        .zip(&all)
        .map(|(file, t)| read_frames(file, t, background))
        .collect()
}

fn read_frames(file: &Path, t: &Transforms, background: DVec3) -> io::Result<Vec<TrainView>> {
    let mut views = Vec::with_capacity(t.frames.len());
    let mut size = None;
    for (k, f) in t.frames.iter().enumerate() {
        let (w, h, rgba) = read_rgba_image(&f.image)?;
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
        let (fl_x, fl_y) = t.focal_pixels(w, h, file)?;
        let camera = Camera::from_opengl(
            &GlPose {
                c2w: f.pose,
                fl_x,
                fl_y,
            },
            w,
            h,
        )
        .map_err(|e| invalid(file, format!("frame {k}: {e}")))?;
        let bg = background.as_vec3().to_array();
        let pixels = rgba
            .iter()
            .map(|p| {
                let a = p[3].clamp(0.0, 1.0);
                [0, 1, 2].map(|c| p[c] * a + bg[c] * (1.0 - a))
            })
            .collect();
        views.push(TrainView {
            camera,
            image: RgbImage {
                width: w,
                height: h,
                pixels,
            },
        });
    }
    Ok(views)
}
