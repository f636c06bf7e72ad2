//! What every format checks of the cameras it reads, and how a checked
//! pose and lens become an sdfl camera: poses rigid and within range,
//! intrinsics and distortion within what sdfl renders, messages naming
//! the keys the file used.

use sdfl_stdlib::camera::Camera;

pub use sdfl_stdlib::lens::{Distortion, Intrinsics};

/// Farthest a data file may put a camera from its origin, on any axis and
/// in its own units: as far as a number a program may write, so that the
/// scene frame, and exports mapped back into the data's frame, stay finite.
pub const MAX_POSITION: f64 = sdfl_stdlib::precision::F32_SAFE.1;

/// Checks a position read from a data file (`what`: "camera position",
/// "translation") against [`MAX_POSITION`]: one check for every reader
/// (nerfstudio and NeRF-synthetic, COLMAP, LLFF).
pub fn check_position(what: &str, p: glam::DVec3) -> Result<(), String> {
    if p.is_finite() && p.abs().max_element() <= MAX_POSITION {
        return Ok(());
    }
    Err(format!(
        "the {what} [{}, {}, {}] is out of range (at most {} from the origin on each axis)",
        sdfl_lang::fmt_num(p.x),
        sdfl_lang::fmt_num(p.y),
        sdfl_lang::fmt_num(p.z),
        sdfl_lang::fmt_num(MAX_POSITION)
    ))
}

/// Checks that `r` is a rotation (orthonormal within 1e-3, not mirrored):
/// a scaled, sheared or mirrored pose is no camera, and a huge entry would
/// overflow once normalised.
pub fn check_rotation(r: glam::DMat3) -> Result<(), String> {
    let e = r.transpose() * r - glam::DMat3::IDENTITY;
    if e.to_cols_array().iter().all(|x| x.abs() <= 1e-3) && r.determinant() > 0.0 {
        return Ok(());
    }
    Err("the rotation is not orthonormal (a scaled, sheared or mirrored pose)".into())
}

/// Checks a rigid map given as rows (the first three rows of a 4 × 4 or a
/// 3 × 4 matrix): its rotation, and its translation (`what`) in range.
pub fn check_rigid(what: &str, rows: &[[f64; 4]; 3]) -> Result<(), String> {
    let col = |c: usize| glam::DVec3::new(rows[0][c], rows[1][c], rows[2][c]);
    check_rotation(glam::DMat3::from_cols(col(0), col(1), col(2)))?;
    check_position(what, col(3))
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
