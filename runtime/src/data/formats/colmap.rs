//! COLMAP's text model, read directly: `cameras.txt` (`CAMERA_ID MODEL
//! WIDTH HEIGHT PARAMS...`), `images.txt` (`IMAGE_ID QW QX QY QZ TX TY TZ
//! CAMERA_ID NAME`, world to camera in COLMAP's axes: x right, y down,
//! z forward; every such line followed by one line of 2-D points, which
//! is skipped) and `points3D.txt` (`POINT3D_ID X Y Z R G B ERROR TRACK...`,
//! for the scene's bounds). Images are `images/NAME` beside `sparse/`.
//!
//! Files are read line by line with every line and the total capped, so
//! a hostile file cannot exhaust memory; every number is checked and an
//! error names the file and line.

use std::collections::HashMap;
use std::io::{self, BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use sdfl_stdlib::builtins::MAX_VIEWS;
use sdfl_stdlib::value::CaptureFormat;

use crate::data::camera::{check_position, CheckNamed, Distortion, Intrinsics, Keys};
use crate::data::error::invalid;
use crate::data::format::{Format, FormatViews, PlannedView, Request};
use crate::data::frames::{held_out_every, load, planned_every_nth, Capture, CaptureFrame};
use crate::data::image::{image_dimensions, open_regular, MAX_SIDE};
use crate::data::paths::{images_folder, inside};

/// Longest line read (a 2-D point line of a 50-megapixel image's features
/// is a few megabytes).
const MAX_LINE: usize = 64 << 20;
/// Most bytes of one model file.
const MAX_FILE: u64 = 4 << 30;
/// Most 3-D points kept for the bounds (every n-th beyond).
pub const MAX_POINTS: usize = 1 << 20;
/// Most cameras in `cameras.txt`.
const MAX_CAMERAS: usize = MAX_VIEWS;

/// The directory holding the model: `sparse/0`, `sparse` or the capture's
/// own, whichever has `cameras.txt` and `images.txt`.
pub fn model_dir(dir: &Path) -> Option<PathBuf> {
    [dir.join("sparse/0"), dir.join("sparse"), dir.to_path_buf()]
        .into_iter()
        .find(|d| d.join("cameras.txt").is_file() && d.join("images.txt").is_file())
}

/// The COLMAP format.
pub struct Colmap;

impl Format for Colmap {
    fn name(&self) -> &'static str {
        "colmap"
    }

    fn capture_format(&self) -> Option<CaptureFormat> {
        Some(CaptureFormat::Colmap)
    }

    fn marker(&self) -> &'static str {
        "COLMAP model (sparse/0/cameras.txt)"
    }

    fn detect(&self, path: &Path) -> bool {
        model_dir(path).is_some()
    }

    /// The images `images.txt` names, without reading the cameras.
    fn plan(&self, request: &Request) -> io::Result<Vec<PlannedView>> {
        let path = &request.path;
        let model = model_dir(path).ok_or_else(|| invalid(path, NO_MODEL))?;
        let mut names: Vec<String> = read_images(&model.join("images.txt"))?
            .into_iter()
            .map(|i| i.name)
            .collect();
        names.sort();
        let folder = PathBuf::from(images_folder(request.downscale));
        let images = names
            .iter()
            .map(|n| inside(path, &folder.join(n), n).map_err(|e| invalid(path, e)))
            .collect::<io::Result<Vec<_>>>()?;
        Ok(planned_every_nth(images, request.test_every()))
    }

    fn read(&self, request: &Request) -> io::Result<FormatViews> {
        let capture = read(&request.path, request.downscale, request.test_every())?;
        load(&capture, request, None)
    }
}

/// Why a directory is no COLMAP capture.
const NO_MODEL: &str = "holds no COLMAP text model (sparse/0/cameras.txt and images.txt)";

/// Calls `each(line_number, line)` for every line of `path`, lines and
/// the file capped.
fn lines(path: &Path, mut each: impl FnMut(usize, &str) -> io::Result<()>) -> io::Result<()> {
    let mut r = BufReader::new(open_regular(path)?.take(MAX_FILE + 1));
    let mut buf = Vec::new();
    let mut total = 0u64;
    for n in 1.. {
        buf.clear();
        let got = (&mut r)
            .take(MAX_LINE as u64 + 1)
            .read_until(b'\n', &mut buf)
            .map_err(|e| invalid(path, e))?;
        if got == 0 {
            break;
        }
        total += got as u64;
        if total > MAX_FILE {
            return Err(invalid(path, format!("larger than {MAX_FILE} bytes")));
        }
        if buf.len() > MAX_LINE {
            return Err(invalid(
                path,
                format!("line {n} is longer than {MAX_LINE} bytes"),
            ));
        }
        let line = std::str::from_utf8(&buf)
            .map_err(|_| invalid(path, format!("line {n} is not UTF-8 text")))?;
        each(n, line.trim_end_matches(['\n', '\r']))?;
    }
    Ok(())
}

fn numbers(fields: &[&str], path: &Path, n: usize) -> io::Result<Vec<f64>> {
    fields
        .iter()
        .map(|f| {
            f.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    invalid(
                        path,
                        format!(
                            "line {n}: `{}` is not a finite number",
                            f.chars().take(32).collect::<String>()
                        ),
                    )
                })
        })
        .collect()
}

/// One camera of `cameras.txt`: its size and intrinsics at that size.
#[derive(Debug, Clone, Copy)]
pub struct ColmapCamera {
    /// Image width in pixels the intrinsics are given at.
    pub width: u32,
    /// Image height in pixels the intrinsics are given at.
    pub height: u32,
    /// Focal lengths, principal point and distortion at that size.
    pub intrinsics: Intrinsics,
    keys: Keys,
}

/// The models sdfl reads, their parameter count, and how the parameters
/// become intrinsics.
fn camera(model: &str, p: &[f64], (w, h): (u32, u32)) -> Result<(Intrinsics, Keys), String> {
    let want = match model {
        "SIMPLE_PINHOLE" => 3,
        "PINHOLE" => 4,
        "SIMPLE_RADIAL" => 4,
        "RADIAL" => 5,
        "OPENCV" | "OPENCV_FISHEYE" => 8,
        _ => {
            return Err(format!(
                "camera model {} is not one sdfl reads (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE): undistort the images with `colmap image_undistorter` first",
                model.chars().take(32).collect::<String>()
            ))
        }
    };
    if p.len() != want {
        return Err(format!(
            "{model} has {want} parameters, this line {}",
            p.len()
        ));
    }
    let single = Keys { fx: "f", fy: "f" };
    let pair = Keys { fx: "fx", fy: "fy" };
    let (fx, fy, cx, cy, distortion, keys) = match model {
        "SIMPLE_PINHOLE" => (p[0], p[0], p[1], p[2], Distortion::None, single),
        "PINHOLE" => (p[0], p[1], p[2], p[3], Distortion::None, pair),
        "SIMPLE_RADIAL" => (
            p[0],
            p[0],
            p[1],
            p[2],
            Distortion::OpenCv {
                k1: p[3],
                k2: 0.0,
                p1: 0.0,
                p2: 0.0,
            },
            single,
        ),
        "RADIAL" => (
            p[0],
            p[0],
            p[1],
            p[2],
            Distortion::OpenCv {
                k1: p[3],
                k2: p[4],
                p1: 0.0,
                p2: 0.0,
            },
            single,
        ),
        "OPENCV" => (
            p[0],
            p[1],
            p[2],
            p[3],
            Distortion::OpenCv {
                k1: p[4],
                k2: p[5],
                p1: p[6],
                p2: p[7],
            },
            pair,
        ),
        _ => (
            p[0],
            p[1],
            p[2],
            p[3],
            Distortion::Fisheye {
                k1: p[4],
                k2: p[5],
                k3: p[6],
                k4: p[7],
            },
            pair,
        ),
    };
    let k = Intrinsics {
        width: w,
        height: h,
        fx,
        fy,
        cx,
        cy,
        distortion,
    };
    k.check_named(keys, (fx, fy))?;
    Ok((k, keys))
}

/// Reads `cameras.txt`.
pub fn read_cameras(path: &Path) -> io::Result<HashMap<u64, ColmapCamera>> {
    let mut cams = HashMap::new();
    lines(path, |n, line| {
        // No model has more than 12 parameters: more fields than that are
        // refused below without collecting a long line whole.
        let f: Vec<&str> = line.split_whitespace().take(32).collect();
        if f.is_empty() || f[0].starts_with('#') {
            return Ok(());
        }
        let at = |m: String| invalid(path, format!("line {n}: {m}"));
        if f.len() < 5 {
            return Err(at("expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...".into()));
        }
        let id: u64 = f[0]
            .parse()
            .map_err(|_| at("CAMERA_ID is not a whole number".into()))?;
        let side = |s: &str| -> io::Result<u32> {
            s.parse::<u32>()
                .ok()
                .filter(|v| (1..=MAX_SIDE).contains(v))
                .ok_or_else(|| {
                    at(format!(
                        "image side `{s}` is not 1 to {} pixels",
                        MAX_SIDE
                    ))
                })
        };
        let (w, h) = (side(f[2])?, side(f[3])?);
        let p = numbers(&f[4..f.len().min(20)], path, n)?;
        let (intrinsics, keys) =
            camera(f[1], &p, (w, h)).map_err(|e| at(format!("camera {id}: {e}")))?;
        if cams.len() >= MAX_CAMERAS {
            return Err(at(format!("more than {MAX_CAMERAS} cameras")));
        }
        if cams
            .insert(
                id,
                ColmapCamera {
                    width: w,
                    height: h,
                    intrinsics,
                    keys,
                },
            )
            .is_some()
        {
            return Err(at(format!("camera {id} is defined twice")));
        }
        Ok(())
    })?;
    if cams.is_empty() {
        return Err(invalid(path, "no cameras"));
    }
    Ok(cams)
}

/// One registered image of `images.txt`.
#[derive(Debug, Clone)]
pub struct ColmapImage {
    /// Line of `images.txt`, for messages.
    pub line: usize,
    /// `CAMERA_ID` of the camera in `cameras.txt` that took this image.
    pub camera: u64,
    /// The image's file name, relative to the images folder.
    pub name: String,
    /// OpenGL camera-to-world (camera looks down −z, +y up).
    pub c2w: [[f64; 4]; 4],
}

/// COLMAP's world-to-camera quaternion and translation as an OpenGL
/// camera-to-world matrix: the camera centre is `−Rᵀt`, and OpenGL's y and
/// z axes are COLMAP's negated.
pub fn opengl_c2w(q: DQuat, t: DVec3) -> [[f64; 4]; 4] {
    let r = DMat3::from_quat(q);
    let rt = r.transpose();
    let eye = -(rt * t);
    let cols = [rt.x_axis, -rt.y_axis, -rt.z_axis, eye];
    let mut m = [[0.0; 4]; 4];
    for (row, out) in m.iter_mut().take(3).enumerate() {
        for (c, v) in cols.iter().enumerate() {
            out[c] = v[row];
        }
    }
    m[3] = [0.0, 0.0, 0.0, 1.0];
    m
}

/// Reads `images.txt`.
pub fn read_images(path: &Path) -> io::Result<Vec<ColmapImage>> {
    let mut images = Vec::new();
    let mut points_next = false;
    lines(path, |n, line| {
        if line.starts_with('#') {
            return Ok(());
        }
        if points_next {
            // The 2-D points of the image above (possibly empty).
            points_next = false;
            return Ok(());
        }
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.is_empty() {
            return Ok(());
        }
        let at = |m: String| invalid(path, format!("line {n}: {m}"));
        if f.len() < 10 {
            return Err(at(
                "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME".into()
            ));
        }
        let v = numbers(&f[1..8], path, n)?;
        let q = DQuat::from_xyzw(v[1], v[2], v[3], v[0]);
        let len = q.length();
        if (len - 1.0).abs() > 1e-3 {
            return Err(at(format!(
                "the rotation quaternion has length {} (a rotation's is 1)",
                sdfl_lang::fmt_num(len)
            )));
        }
        let t = DVec3::new(v[4], v[5], v[6]);
        check_position("translation", t).map_err(&at)?;
        let camera: u64 = f[8]
            .parse()
            .map_err(|_| at("CAMERA_ID is not a whole number".into()))?;
        if images.len() >= MAX_VIEWS {
            return Err(at(format!("more than {MAX_VIEWS} images")));
        }
        // Names may hold spaces: the rest of the line.
        let name = f[9..].join(" ");
        if name.len() > 4096 || name.contains('\0') {
            return Err(at(
                "the image name is not a file name (longer than 4096 bytes)".into(),
            ));
        }
        images.push(ColmapImage {
            line: n,
            camera,
            name,
            c2w: opengl_c2w(q / len, t),
        });
        points_next = true;
        Ok(())
    })?;
    if images.is_empty() {
        return Err(invalid(path, "no registered images"));
    }
    Ok(images)
}

/// Reads the positions of `points3D.txt`, every n-th beyond [`MAX_POINTS`].
pub fn read_points(path: &Path) -> io::Result<Vec<DVec3>> {
    let mut points = Vec::new();
    let (mut seen, mut stride) = (0usize, 1usize);
    lines(path, |n, line| {
        // Only the id and position are read: a long line costs no memory.
        let f: Vec<&str> = line.split_whitespace().take(4).collect();
        if f.is_empty() || f[0].starts_with('#') {
            return Ok(());
        }
        if f.len() < 4 {
            return Err(invalid(
                path,
                format!("line {n}: expected POINT3D_ID X Y Z ..."),
            ));
        }
        let v = numbers(&f[1..4], path, n)?;
        // Every `stride`-th point; when the sample is full, every other
        // one is dropped and the stride doubles: bounded and even.
        if seen.is_multiple_of(stride) {
            points.push(DVec3::new(v[0], v[1], v[2]));
            if points.len() >= MAX_POINTS {
                let mut k = 0;
                points.retain(|_| {
                    k += 1;
                    k % 2 == 1
                });
                stride *= 2;
            }
        }
        seen += 1;
        Ok(())
    })?;
    Ok(points)
}

/// A COLMAP capture in `dir`: its model, images from `images/` (or
/// `images_<downscale>/`, intrinsics scaled by 1/downscale), sorted by
/// name; every `test_every`-th held out.
pub fn read(dir: &Path, downscale: u32, test_every: usize) -> io::Result<Capture> {
    let model = model_dir(dir).ok_or_else(|| invalid(dir, NO_MODEL))?;
    let cams = read_cameras(&model.join("cameras.txt"))?;
    let images_txt = model.join("images.txt");
    let mut images = read_images(&images_txt)?;
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let folder = images_folder(downscale);
    let d = downscale.max(1) as f64;
    let mut frames = Vec::with_capacity(images.len());
    for im in &images {
        let at = |m: String| {
            invalid(
                &images_txt,
                format!("line {} (image {}): {m}", im.line, im.name),
            )
        };
        let cam = cams
            .get(&im.camera)
            .ok_or_else(|| at(format!("camera {} is not in cameras.txt", im.camera)))?;
        let rel = Path::new(&im.name);
        if rel
            .components()
            .any(|c| !matches!(c, std::path::Component::Normal(_)))
        {
            return Err(at(
                "the name is not a relative path inside the images folder".into(),
            ));
        }
        let image = inside(dir, &Path::new(&folder).join(rel), &im.name).map_err(at)?;
        let (w, h) = image_dimensions(&image)?;
        let ok = |img: u32, full: u32| {
            if d == 1.0 {
                img == full
            } else {
                (full as f64 / d - img as f64).abs() < 1.0
            }
        };
        if !(ok(w, cam.width) && ok(h, cam.height)) {
            return Err(at(format!(
                "the image is {w}x{h} pixels but its camera is {}x{}{}",
                cam.width,
                cam.height,
                if d > 1.0 {
                    format!(" (read at 1/{downscale})")
                } else {
                    String::new()
                }
            )));
        }
        let c = cam.intrinsics;
        let intrinsics = Intrinsics {
            width: w,
            height: h,
            fx: c.fx / d,
            fy: c.fy / d,
            cx: c.cx / d,
            cy: c.cy / d,
            distortion: c.distortion,
        };
        intrinsics.check_named(cam.keys, (c.fx, c.fy)).map_err(at)?;
        frames.push(CaptureFrame {
            label: format!("image {} (line {} of images.txt)", im.name, im.line),
            image,
            mask: None,
            object_mask: None,
            c2w: im.c2w,
            intrinsics,
        });
    }
    let test = held_out_every(frames.len(), test_every, &images_txt, "images")?;
    let points_txt = model.join("points3D.txt");
    let points = if points_txt.is_file() {
        read_points(&points_txt)?
    } else {
        Vec::new()
    };
    Ok(Capture {
        source: images_txt,
        frames,
        test,
        applied: None,
        points,
        bounds: None,
    })
}
