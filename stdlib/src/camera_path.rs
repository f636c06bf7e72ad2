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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn path(frames: &str) -> String {
        format!(
            r#"{{"camera_type": "perspective", "render_width": 64, "render_height": 48, "fps": 24, "seconds": 1,
                "camera_path": [{frames}]}}"#
        )
    }

    const AT_Z3: &str =
        r#"{"camera_to_world": [1,0,0,0, 0,1,0,0, 0,0,1,3, 0,0,0,1], "fov": 50, "aspect": 1.333}"#;

    #[test]
    fn a_path_reads_back_its_poses_and_field_of_view() {
        // Second camera: at x = 3 looking down −x (turned 90° about y).
        let turned = r#"{"camera_to_world": [0,0,1,3, 0,1,0,0, -1,0,0,0, 0,0,0,1], "fov": 50}"#;
        let p = parse_camera_path(path(&format!("{AT_Z3}, {turned}")).as_bytes()).unwrap();
        assert_eq!((p.width, p.height, p.fps), (64, 48, 24.0));
        assert_eq!(p.cameras.len(), 2);
        let c = p.cameras[0];
        assert!((c.eye - DVec3::new(0.0, 0.0, 3.0)).length() < 1e-12);
        // Looks down −z with +y up: the centre ray goes to the origin.
        let d = c.pixel_direction(31.5, 23.5, 64, 48);
        assert!((d - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-9, "{d}");
        // The top row is 25° above the axis (fov 50, vertical).
        let top = c.pixel_direction(31.5, -0.5, 64, 48);
        assert!(
            (top.y.atan2(-top.z).to_degrees() - 25.0).abs() < 1e-6,
            "{top}"
        );
        let d = p.cameras[1].pixel_direction(31.5, 23.5, 64, 48);
        assert!((d - DVec3::new(-1.0, 0.0, 0.0)).length() < 1e-9, "{d}");
    }

    #[test]
    fn hostile_paths_are_refused_with_the_frame_named() {
        let cases: Vec<(String, &str)> = vec![
            ("[1, 2]".into(), "not a JSON object"),
            ("{".into(), "not JSON"),
            (
                r#"{"render_height": 4, "camera_path": []}"#.into(),
                "`render_width` is missing",
            ),
            (path("").replace("64", "0"), "`render_width` is 0"),
            (path("").replace("64", "100000"), "`render_width` is 100000"),
            (path("").replace("48", "4.5"), "`render_height` is 4.5"),
            (path(""), "no cameras"),
            (
                path(AT_Z3).replace("perspective", "fisheye"),
                "only \"perspective\"",
            ),
            (
                path(AT_Z3).replace("\"fps\": 24", "\"fps\": -1"),
                "`fps` is -1",
            ),
            (
                path(AT_Z3).replace("\"seconds\": 1", "\"seconds\": \"x\""),
                "`seconds`",
            ),
            (
                path(&format!("{AT_Z3}, {}", AT_Z3.replace("0,0,0,1]", "0,0,1]"))),
                "camera_path[1]: `camera_to_world` has 15 numbers",
            ),
            (
                path(&AT_Z3.replace("\"fov\": 50", "\"fov\": 0")),
                "camera_path[0]: `fov` is 0",
            ),
            (
                path(&AT_Z3.replace("\"fov\": 50", "\"fov\": 180")),
                "`fov` is 180",
            ),
            (
                path(&AT_Z3.replace("\"fov\": 50", "\"fov\": null")),
                "`fov` is null",
            ),
            (
                path(&AT_Z3.replace(", \"fov\": 50", "")),
                "`fov` is missing",
            ),
            (path(&AT_Z3.replace("1.333", "-1")), "`aspect` is -1"),
            (
                path(&AT_Z3.replace("[1,0,0,0,", "[2,0,0,0,")),
                "not orthonormal",
            ),
            (
                path(&AT_Z3.replace("[1,0,0,0,", "[-1,0,0,0,")),
                "reflection",
            ),
            (
                path(&AT_Z3.replace("[1,0,0,0,", "[\"1\",0,0,0,")),
                "`camera_to_world[0]` is \"1\"",
            ),
            (path(&AT_Z3.replace("0,0,0,1]", "0,0,0,2]")), "last row"),
            (
                path(&AT_Z3.replace("0,0,1,3,", "0,0,1,1e300,")),
                "out of range",
            ),
            (
                path(&AT_Z3.replace("[1,0,0,0,", "[1e999,0,0,0,")),
                "not JSON",
            ),
            (
                format!("{}1{}", "[".repeat(100_000), "]".repeat(100_000)),
                "not JSON",
            ),
        ];
        for (src, says) in cases {
            let e = parse_camera_path(src.as_bytes()).unwrap_err();
            assert!(e.contains(says), "{says:?} not in {e:?}");
        }
        let many = vec![AT_Z3; MAX_CAMERAS + 1].join(",");
        let e = parse_camera_path(path(&many).as_bytes()).unwrap_err();
        assert!(e.contains("at most"), "{e}");
    }

    #[test]
    fn files_are_capped_and_regular() {
        let dir = std::env::temp_dir().join(format!("sdfl-camera-path-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&dir);
        let f = dir.join("camera_path.json");
        std::fs::write(&f, path(AT_Z3)).unwrap();
        assert_eq!(read_camera_path(&f).unwrap().cameras.len(), 1);
        assert!(read_camera_path(&dir).is_err(), "a directory is no file");
        let big = dir.join("big.json");
        let file = std::fs::File::create(&big).unwrap();
        file.set_len(MAX_BYTES + 1).unwrap();
        let e = read_camera_path(&big).unwrap_err().to_string();
        assert!(e.contains("larger than"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
