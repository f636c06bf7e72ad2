//! IDR's and NeuS's layout of object captures (DTU and BlendedMVS as they
//! ship them, e.g. `dtu_scan24/`): the images in `image/`, optional object
//! masks in `mask/` (paired with the images by sorted file name; their
//! names may differ: `000000.png` against `000.png`), and
//! `cameras_sphere.npz` holding for image `i`
//!
//! - `world_mat_i`: a 4 × 4 whose first three rows are the projection
//!   `P = K[R | t]` (world to OpenCV pixels: x right, y down, z forward);
//! - `scale_mat_i`: `diag(s, s, s, 1)` with the translation `c`, which maps
//!   the unit sphere around the object into the world.
//!
//! NeuS projects with `P · scale_mat`, so that it trains in the frame where
//! the object is inside the unit sphere: that frame is the scene frame
//! here, `(x − c) / s`, and exports map back into the world's (NeuS's
//! `world_space`). Other arrays (`camera_mat_i`, the `*_inv` ones) are
//! ignored.
//!
//! Pixel centres: NeuS casts the ray of pixel `(i, j)` through
//! `K⁻¹ (i, j, 1)`, so its pixel centres sit at whole pixel coordinates;
//! sdfl's intrinsics put pixel `i`'s centre at `i + ½` (as Blender and
//! COLMAP do). The principal point therefore moves by +½ on each axis.

use std::io;
use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use sdfl_stdlib::value::CaptureFormat;

use crate::data::camera::{
    check_position, check_rotation, CheckNamed, Distortion, Intrinsics, Keys,
};
use crate::data::error::invalid;
use crate::data::format::{Format, FormatViews, PlannedView, Request};
use crate::data::frames::{held_out_every, load, planned_every_nth, Capture, CaptureFrame};
use crate::data::image::image_dimensions;
use crate::data::normalize::SceneFrame;
use crate::data::npy::{NpyError, Npz};
use crate::data::paths::{image_files, inside};

/// The cameras' file, whose presence marks the layout.
pub const CAMERAS: &str = "cameras_sphere.npz";

/// IDR's and NeuS's format.
pub struct Idr;

impl Format for Idr {
    fn name(&self) -> &'static str {
        "idr"
    }

    fn capture_format(&self) -> Option<CaptureFormat> {
        Some(CaptureFormat::Idr)
    }

    fn marker(&self) -> &'static str {
        CAMERAS
    }

    fn detect(&self, path: &Path) -> bool {
        path.join(CAMERAS).is_file()
    }

    fn own_frame(&self) -> Option<&'static str> {
        Some("scale_mat's unit sphere around the object (as NeuS does; exports in the world frame)")
    }

    /// The images of `image/`, without reading the cameras. Object masks
    /// are read only as coverage, which the budget counts by itself.
    fn plan(&self, request: &Request) -> io::Result<Vec<PlannedView>> {
        let images = images(&request.path, request.downscale)?;
        Ok(planned_every_nth(images, request.test_every()))
    }

    /// The unit sphere of `scale_mat` is the frame NeuS trains in: the
    /// cameras' own centring and `orient`/`extent` do not apply.
    fn read(&self, request: &Request) -> io::Result<FormatViews> {
        let (capture, frame) = read(&request.path, request.downscale, request.test_every())?;
        let mut views = load(&capture, request, Some(frame))?;
        if request.normalize.enabled {
            views.report.insert(
                1,
                "scene frame: cameras_sphere.npz's scale_mat, the object's bounding sphere is the unit sphere (exports map back to the world frame)".to_string(),
            );
        }
        Ok(views)
    }
}

/// Largest `cameras_sphere.npz` read: six 4 × 4 arrays an image take
/// about 2 KB, so 10 000 images fit many times over.
const MAX_CAMERAS_BYTES: u64 = 64 << 20;

/// Largest pixel shift that dropping a projection's skew may cause over
/// the image (sdfl's cameras have none). DTU's is about 5e-5 px
/// (`K[0][1]` ≈ −2.6e-4 with `fx` ≈ 2892 on 1600 × 1200 images).
pub const MAX_SKEW_SHIFT: f64 = 0.01;

/// How far (relative to the scale) a `scale_mat` may be from a uniform
/// scale plus a translation, and two images' from each other.
const SCALE_TOLERANCE: f64 = 1e-6;

/// A projection matrix split into intrinsics and pose: `P ∝ K [R | t]`
/// with `K`'s diagonal positive and `K[2][2] = 1`, `R` a rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projection {
    /// Horizontal focal length in pixels.
    pub fx: f64,
    /// Vertical focal length in pixels.
    pub fy: f64,
    /// `K[0][1]`: how far x moves per unit of y at depth one.
    pub skew: f64,
    /// Principal point, OpenCV pixels (centres at whole numbers).
    pub cx: f64,
    /// Principal point's y.
    pub cy: f64,
    /// World to camera (OpenCV axes), rows.
    pub rotation: DMat3,
    /// World to camera translation: `x_cam = R x + t`.
    pub translation: DVec3,
}

impl Projection {
    /// The camera's position in the projection's world frame.
    pub fn eye(&self) -> DVec3 {
        -(self.rotation.transpose() * self.translation)
    }

    /// The OpenGL camera-to-world pose (columns right, up, back, eye): the
    /// camera's OpenCV axes (x right, y down, z forward) are the rows of
    /// `R`.
    pub fn opengl_c2w(&self) -> [[f64; 4]; 4] {
        let r = self.rotation;
        let row = |i: usize| r.row(i);
        let cols = [row(0), -row(1), -row(2), self.eye()];
        let mut m = [[0.0; 4]; 4];
        for (i, out) in m.iter_mut().take(3).enumerate() {
            for (c, v) in cols.iter().enumerate() {
                out[c] = v[i];
            }
        }
        m[3][3] = 1.0;
        m
    }

    /// How far dropping the skew moves a pixel of an image `height` pixels
    /// tall, at most: x moves by `skew` times the depth-one y.
    pub fn skew_shift(&self, height: f64) -> f64 {
        self.skew.abs() * self.cy.abs().max((height - self.cy).abs()) / self.fy
    }
}

/// Splits the projection `p` (3 × 4, rows) by an RQ decomposition of its
/// left 3 × 3 `M = K R`: Gram–Schmidt on `M`'s rows from the last, so that
/// `K`'s diagonal comes out positive; `P` is first negated where
/// `det M < 0` (the same projective map), which makes `det R = +1`: the
/// camera looks towards the points `P` gives positive depth (Hartley and
/// Zisserman's sign rule).
#[allow(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "a NaN determinant (from huge entries) must take the refusing branch"
)]
pub fn decompose(p: &[[f64; 4]; 3]) -> Result<Projection, String> {
    if !p.iter().flatten().all(|v| v.is_finite()) {
        return Err("the projection holds a non-finite number".into());
    }
    let row = |i: usize| DVec3::new(p[i][0], p[i][1], p[i][2]);
    let (mut m0, mut m1, mut m2) = (row(0), row(1), row(2));
    let mut last = DVec3::new(p[0][3], p[1][3], p[2][3]);
    let det = DMat3::from_cols(m0, m1, m2).determinant();
    // Relative to the rows' lengths, so that units do not matter.
    let size = m0.length() * m1.length() * m2.length();
    if !(det.abs() > 1e-9 * size) {
        return Err("the projection's left 3x3 part is singular (no camera has it)".into());
    }
    if det < 0.0 {
        (m0, m1, m2, last) = (-m0, -m1, -m2, -last);
    }
    let k22 = m2.length();
    let r2 = m2 / k22;
    let k12 = m1.dot(r2);
    let u1 = m1 - r2 * k12;
    let k11 = u1.length();
    let r1 = u1 / k11;
    // Right-handed by construction; k00 = det M / (k11 k22) > 0.
    let r0 = r1.cross(r2);
    let (k00, k01, k02) = (m0.dot(r0), m0.dot(r1), m0.dot(r2));
    // t = K⁻¹ p₄, by back-substitution (K upper triangular).
    let t2 = last.z / k22;
    let t1 = (last.y - k12 * t2) / k11;
    let t0 = (last.x - k01 * t1 - k02 * t2) / k00;
    let out = Projection {
        fx: k00 / k22,
        fy: k11 / k22,
        skew: k01 / k22,
        cx: k02 / k22,
        cy: k12 / k22,
        rotation: DMat3::from_cols(r0, r1, r2).transpose(),
        translation: DVec3::new(t0, t1, t2),
    };
    let finite = [out.fx, out.fy, out.skew, out.cx, out.cy]
        .iter()
        .all(|v| v.is_finite())
        && out.translation.is_finite();
    if !(finite && out.fx > 0.0 && out.fy > 0.0) {
        return Err("the projection does not split into a camera".into());
    }
    check_rotation(out.rotation)?;
    Ok(out)
}

/// The uniform scale `s` and translation `c` of a `scale_mat` (4 × 4,
/// rows), refusing anything else: a rotation, a non-uniform or
/// non-positive scale, a projective last row.
pub fn scale_of(m: &[[f64; 4]; 4]) -> Result<(f64, DVec3), String> {
    if !m.iter().flatten().all(|v| v.is_finite()) {
        return Err("it holds a non-finite number".into());
    }
    let s = m[0][0];
    let (lo, hi) = sdfl_stdlib::precision::F32_SAFE;
    if !(lo..=hi).contains(&s) {
        return Err(format!(
            "its scale {} is not a positive number from {lo:e} to {hi:e}",
            sdfl_lang::fmt_num(s)
        ));
    }
    let tol = SCALE_TOLERANCE * s;
    for (i, row) in m.iter().take(3).enumerate() {
        for (j, v) in row.iter().take(3).enumerate() {
            let want = if i == j { s } else { 0.0 };
            if (v - want).abs() > tol {
                return Err(format!(
                    "it is not a uniform scale plus a translation: entry [{i}][{j}] is {}, not {}",
                    sdfl_lang::fmt_num(*v),
                    sdfl_lang::fmt_num(want)
                ));
            }
        }
    }
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(format!(
            "its last row is {:?}, not [0, 0, 0, 1]",
            m[3].map(sdfl_lang::fmt_num)
        ));
    }
    let c = DVec3::new(m[0][3], m[1][3], m[2][3]);
    check_position("sphere centre", c)?;
    Ok((s, c))
}

/// The image files of `dir/image/`, sorted by name: IDR's layout has no
/// downscaled copies, so `downscale` must be 1.
pub fn images(dir: &Path, downscale: u32) -> io::Result<Vec<PathBuf>> {
    if downscale > 1 {
        return Err(invalid(
            dir,
            format!("IDR's layout keeps full-size images only (image/), not images_{downscale}/: leave `downscale` out"),
        ));
    }
    let folder = dir.join("image");
    let files = image_files(&folder)?;
    if files.is_empty() {
        return Err(invalid(&folder, "holds no PNG or JPEG images"));
    }
    Ok(files)
}

/// The object masks of `dir/mask/`, sorted by name, one for each of
/// `images` images; `None` without the folder.
fn object_masks(dir: &Path, images: usize) -> io::Result<Option<Vec<PathBuf>>> {
    let folder = dir.join("mask");
    if !folder.is_dir() {
        return Ok(None);
    }
    let files = image_files(&folder)?;
    if files.len() != images {
        return Err(invalid(
            &folder,
            format!(
                "{} masks for {images} images in image/ (they pair by sorted name)",
                files.len()
            ),
        ));
    }
    Ok(Some(files))
}

/// `name` of the archive as a 4 × 4 of finite numbers (rows).
fn matrix4(npz: &mut Npz, name: &str) -> Result<[[f64; 4]; 4], String> {
    let (shape, v) = npz.read_f64(name, 16).map_err(|e| match e {
        NpyError::MissingKey(_) => format!("it has no `{name}`"),
        e => format!("`{name}`: {e}"),
    })?;
    if shape != [4, 4] {
        return Err(format!("`{name}` has shape {shape:?}, not (4, 4)"));
    }
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(format!(
            "`{name}`[{}][{}] is not a finite number",
            i / 4,
            i % 4
        ));
    }
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        row.copy_from_slice(&v[i * 4..i * 4 + 4]);
    }
    Ok(m)
}

/// `world_mat_k` of the archive is `world_mat_<digits>`: counts the cameras.
#[doc(hidden)]
pub fn is_world_mat(key: &str) -> bool {
    key.strip_prefix("world_mat_")
        .is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
}

/// An IDR capture in `dir`: its frames (cameras in the world frame, as
/// OpenGL poses), and the scene frame that `scale_mat` gives (the unit
/// sphere around the object).
pub fn read(dir: &Path, downscale: u32, test_every: usize) -> io::Result<(Capture, SceneFrame)> {
    let file = dir.join(CAMERAS);
    let images = images(dir, downscale)?;
    let masks = object_masks(dir, images.len())?;
    let mut npz = Npz::read(&file, MAX_CAMERAS_BYTES).map_err(|e| invalid(&file, e))?;
    let cameras = npz.keys().into_iter().filter(|k| is_world_mat(k)).count();
    if cameras != images.len() {
        return Err(invalid(
            &file,
            format!(
                "{cameras} cameras (world_mat_<i>) for {} images in image/",
                images.len()
            ),
        ));
    }
    // Each file checked to stay inside the capture (a link may lead out),
    // named as listed.
    let inside_as = |folder: &str, p: &Path| {
        let leaf = p.file_name().unwrap_or_default();
        let name = leaf.to_string_lossy();
        inside(dir, &Path::new(folder).join(leaf), &name).map(|q| (q, name.into_owned()))
    };
    let mut sphere: Option<(f64, DVec3, [[f64; 4]; 4])> = None;
    let mut frames = Vec::with_capacity(images.len());
    for (k, path) in images.iter().enumerate() {
        let (image, name) =
            inside_as("image", path).map_err(|e| invalid(&file, format!("image {k}: {e}")))?;
        let at = |m: String| invalid(&file, format!("image {k} ({name}): {m}"));
        let object_mask = match &masks {
            None => None,
            Some(m) => Some(inside_as("mask", &m[k]).map_err(at)?.0),
        };
        let world = matrix4(&mut npz, &format!("world_mat_{k}")).map_err(at)?;
        let scale = matrix4(&mut npz, &format!("scale_mat_{k}")).map_err(at)?;
        let (s, c) = scale_of(&scale).map_err(|e| at(format!("`scale_mat_{k}`: {e}")))?;
        // One sphere for every image: each NeuS camera is projected with
        // its own, so images with different ones would not agree.
        let (s0, c0, scale0) = *sphere.get_or_insert((s, c, scale));
        if (s - s0).abs() > SCALE_TOLERANCE * s0 || (c - c0).length() > SCALE_TOLERANCE * s0 {
            return Err(at(format!(
                "`scale_mat_{k}` (scale {}, centre {c}) differs from scale_mat_0's (scale {}, centre {c0}): the images disagree on the object's sphere",
                sdfl_lang::fmt_num(s),
                sdfl_lang::fmt_num(s0)
            )));
        }
        if world[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(at(format!(
                "`world_mat_{k}`'s last row is {:?}, not [0, 0, 0, 1]",
                world[3].map(sdfl_lang::fmt_num)
            )));
        }
        // As NeuS: P · scale_mat, the camera in the unit sphere's frame.
        let mut p = [[0.0; 4]; 3];
        for (i, out) in p.iter_mut().enumerate() {
            for (j, v) in out.iter_mut().enumerate() {
                *v = (0..4).map(|n| world[i][n] * scale0[n][j]).sum();
            }
        }
        let cam = decompose(&p).map_err(|e| at(format!("`world_mat_{k}`: {e}")))?;
        let (w, h) = image_dimensions(&image)?;
        let shift = cam.skew_shift(h as f64);
        if shift > MAX_SKEW_SHIFT {
            return Err(at(format!(
                "`world_mat_{k}` has a skew of {:.3} px (K[0][1], against fx {:.1}): dropping it would move pixels by up to {shift:.3} px (at most {MAX_SKEW_SHIFT}), and sdfl's cameras have none (a sheared pose, or a skewed sensor)",
                cam.skew, cam.fx
            )));
        }
        let intrinsics = Intrinsics {
            width: w,
            height: h,
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx + 0.5,
            cy: cam.cy + 0.5,
            distortion: Distortion::None,
        };
        intrinsics
            .check_named(Keys { fx: "fx", fy: "fy" }, (cam.fx, cam.fy))
            .map_err(|e| at(format!("`world_mat_{k}`: {e}")))?;
        let unit_eye = cam.eye();
        check_position("camera position in the unit sphere's frame", unit_eye)
            .map_err(|e| at(format!("`world_mat_{k}`: {e}")))?;
        // Kept in the world frame, as the other readers keep the data's:
        // the scene frame maps it back to the unit sphere's.
        let eye = unit_eye * s0 + c0;
        check_position("camera position", eye)
            .map_err(|e| at(format!("`world_mat_{k}`: {e}")))?;
        let mut c2w = cam.opengl_c2w();
        for (row, e) in c2w.iter_mut().zip(eye.to_array()) {
            row[3] = e;
        }
        frames.push(CaptureFrame {
            label: format!("image {k} ({name})"),
            image,
            mask: None,
            object_mask,
            c2w,
            intrinsics,
        });
    }
    let test = held_out_every(frames.len(), test_every, &file, "images")?;
    // Images exist, so the sphere was read.
    let (s, c, _) = sphere.ok_or_else(|| invalid(&file, "no cameras"))?;
    Ok((
        Capture {
            source: file,
            frames,
            test,
            applied: None,
            points: Vec::new(),
            bounds: None,
        },
        SceneFrame::new(1.0 / s, c, DMat3::IDENTITY),
    ))
}
