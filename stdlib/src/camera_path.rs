//! nerfstudio's `camera_path.json` (what its viewer exports and
//! `ns-render camera-path` reads), read as hostile input: `render_width`,
//! `render_height`, optional `fps`, `seconds` and `camera_type` (only
//! "perspective"), and `camera_path[]` with `camera_to_world` (a 4×4
//! OpenGL camera-to-world matrix flattened row by row: the camera looks
//! down −z, +y up) and `fov` (the vertical field of view in degrees: focal
//! length `(render_height / 2) / tan(fov / 2)` pixels, principal point at
//! the centre). Every number is checked; errors name the frame and key.

use std::io::{self, Read};
use std::path::Path;

use crate::camera::{Camera, Intrinsics};
use serde_json::Value;

/// Largest camera path file read.
pub const MAX_BYTES: u64 = 64 << 20;
/// Most cameras on a path (the most views of a statement).
pub const MAX_CAMERAS: usize = crate::limits::MAX_VIEWS;
/// Largest image side.
pub const MAX_SIDE: u64 = crate::limits::MAX_IMAGE_SIDE as u64;

/// A camera path: its cameras for `width × height` images, and its frame
/// rate.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraPath {
    /// Its cameras in order, one per frame.
    pub cameras: Vec<Camera>,
    /// Image width the path was made for, in pixels.
    pub width: u32,
    /// Image height the path was made for, in pixels.
    pub height: u32,
    /// Frames per second.
    pub fps: f64,
}

/// Reads a `camera_path.json`: a regular file of at most [`MAX_BYTES`].
pub fn read_camera_path(path: &Path) -> io::Result<CameraPath> {
    // A regular file only (not a FIFO or a device, which could block).
    let meta = std::fs::metadata(path)
        .map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", path.display())))?;
    if !meta.is_file() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{}: not a regular file", path.display()),
        ));
    }
    let file = std::fs::File::open(path)?;
    let mut bytes = Vec::new();
    file.take(MAX_BYTES + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > MAX_BYTES {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!("{}: larger than {} MiB", path.display(), MAX_BYTES >> 20),
        ));
    }
    parse_camera_path(&bytes).map_err(|e| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!("{}: {e}", path.display()),
        )
    })
}

fn side(v: &Value, key: &str) -> Result<u32, String> {
    match v.get(key) {
        None => Err(format!("`{key}` is missing")),
        Some(x) => x
            .as_u64()
            .filter(|n| (1..=MAX_SIDE).contains(n))
            .map(|n| n as u32)
            .ok_or_else(|| {
                format!("`{key}` is {x}, not a whole number of pixels from 1 to {MAX_SIDE}")
            }),
    }
}

/// Parses the bytes of a `camera_path.json`.
pub fn parse_camera_path(bytes: &[u8]) -> Result<CameraPath, String> {
    let v: Value = serde_json::from_slice(bytes).map_err(|e| format!("not JSON: {e}"))?;
    if !v.is_object() {
        return Err("the file is not a JSON object".into());
    }
    if let Some(t) = v.get("camera_type") {
        if t.as_str().map(str::to_ascii_lowercase).as_deref() != Some("perspective") {
            return Err(format!(
                "`camera_type` is {t}: only \"perspective\" paths are read"
            ));
        }
    }
    let (width, height) = (side(&v, "render_width")?, side(&v, "render_height")?);
    let fps = match v.get("fps") {
        None => 24.0,
        Some(x) => x
            .as_f64()
            .filter(|f| f.is_finite() && *f > 0.0 && *f <= 1000.0)
            .ok_or_else(|| format!("`fps` is {x}, not a frame rate above 0 and at most 1000"))?,
    };
    if let Some(x) = v.get("seconds") {
        if !x.as_f64().is_some_and(|s| s.is_finite() && s >= 0.0) {
            return Err(format!("`seconds` is {x}, not a duration"));
        }
    }
    let frames = v
        .get("camera_path")
        .ok_or("`camera_path` is missing")?
        .as_array()
        .ok_or("`camera_path` is not a list")?;
    if frames.is_empty() {
        return Err("`camera_path` has no cameras".into());
    }
    if frames.len() > MAX_CAMERAS {
        return Err(format!(
            "`camera_path` has {} cameras (at most {MAX_CAMERAS})",
            frames.len()
        ));
    }
    let cameras = frames
        .iter()
        .enumerate()
        .map(|(k, f)| frame_camera(f, width, height).map_err(|e| format!("camera_path[{k}]: {e}")))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(CameraPath {
        cameras,
        width,
        height,
        fps,
    })
}

fn frame_camera(f: &Value, width: u32, height: u32) -> Result<Camera, String> {
    let m = f
        .get("camera_to_world")
        .ok_or("`camera_to_world` is missing")?
        .as_array()
        .ok_or("`camera_to_world` is not a list")?;
    if m.len() != 16 {
        return Err(format!(
            "`camera_to_world` has {} numbers, not 16 (a 4×4 matrix row by row)",
            m.len()
        ));
    }
    let mut c2w = [[0.0; 4]; 4];
    for (i, x) in m.iter().enumerate() {
        c2w[i / 4][i % 4] = x
            .as_f64()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("`camera_to_world[{i}]` is {x}, not a number"))?;
    }
    let fov = f.get("fov").ok_or("`fov` is missing")?;
    let deg = fov
        .as_f64()
        .filter(|d| d.is_finite() && *d > 0.01 && *d < 179.0)
        .ok_or_else(|| {
            format!("`fov` is {fov}, not a vertical field of view in degrees between 0.01 and 179")
        })?;
    if let Some(a) = f.get("aspect") {
        if !a.as_f64().is_some_and(|a| a.is_finite() && a > 0.0) {
            return Err(format!("`aspect` is {a}, not a positive ratio"));
        }
    }
    let focal = height as f64 / 2.0 / (deg.to_radians() / 2.0).tan();
    Camera::from_opengl_intrinsics(&c2w, Intrinsics::centred(width, height, focal, focal))
}
