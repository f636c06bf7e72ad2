//! Real cameras' lenses: pixel intrinsics and the distortion models of
//! OpenCV (and so of COLMAP and nerfstudio), forward and inverse.
//!
//! Coordinates follow OpenCV: pixel `(i, j)` has its centre at
//! `(i + ½, j + ½)`; camera space has x right, y down, z forward. A point
//! `(x, y, 1)` on the plane at depth one (an undistorted "normalised"
//! point) distorts to `(xd, yd)` and lands on pixel `(fx·xd + cx, fy·yd + cy)`.

use serde::Serialize;

/// A lens distortion model, in OpenCV's / COLMAP's parameters.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum Distortion {
    /// A pinhole.
    #[default]
    None,
    /// OpenCV's (COLMAP `OPENCV`): two radial and two tangential terms.
    OpenCv {
        /// Radial term in r².
        k1: f64,
        /// Radial term in r⁴.
        k2: f64,
        /// First tangential term.
        p1: f64,
        /// Second tangential term.
        p2: f64,
    },
    /// OpenCV's fisheye (COLMAP `OPENCV_FISHEYE`): the angle from the axis
    /// `θ` maps to the image radius `θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸)`.
    Fisheye {
        /// Term in θ².
        k1: f64,
        /// Term in θ⁴.
        k2: f64,
        /// Term in θ⁶.
        k3: f64,
        /// Term in θ⁸.
        k4: f64,
    },
}

/// Largest angle from the optical axis a fisheye lens may see: rays are
/// taken through the plane at depth one, which a ray at 90° never meets.
pub const FISHEYE_MAX_ANGLE: f64 = 85.0 * std::f64::consts::PI / 180.0;

impl Distortion {
    /// The lens is a pinhole (a fisheye never is: with no coefficients it
    /// is the equidistant projection).
    pub fn is_none(&self) -> bool {
        match *self {
            Distortion::None => true,
            Distortion::OpenCv { k1, k2, p1, p2 } => [k1, k2, p1, p2] == [0.0; 4],
            Distortion::Fisheye { .. } => false,
        }
    }

    fn coefficients(&self) -> [f64; 4] {
        match *self {
            Distortion::None => [0.0; 4],
            Distortion::OpenCv { k1, k2, p1, p2 } => [k1, k2, p1, p2],
            Distortion::Fisheye { k1, k2, k3, k4 } => [k1, k2, k3, k4],
        }
    }

    /// The distorted normalised point of the undistorted point `(x, y)`.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        match *self {
            Distortion::None => (x, y),
            Distortion::OpenCv { k1, k2, p1, p2 } => {
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (k1 + r2 * k2);
                (
                    x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
                )
            }
            Distortion::Fisheye { .. } => {
                let r = (x * x + y * y).sqrt();
                if r < 1e-12 {
                    // θ ≈ r there, so the factor θd/r → 1.
                    return (x, y);
                }
                let s = self.fisheye_radius(r.atan()) / r;
                (x * s, y * s)
            }
        }
    }

    /// `θ(1 + k1θ² + …)`: the fisheye's distorted radius at angle `θ`.
    fn fisheye_radius(&self, theta: f64) -> f64 {
        let [k1, k2, k3, k4] = self.coefficients();
        let t2 = theta * theta;
        theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    }

    fn fisheye_slope(&self, theta: f64) -> f64 {
        let [k1, k2, k3, k4] = self.coefficients();
        let t2 = theta * theta;
        1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    }

    /// The undistorted point whose distortion is `(xd, yd)`, by Newton's
    /// method from the distorted point; `None` where it does not converge
    /// (outside where the model is one-to-one).
    #[allow(
        clippy::neg_cmp_op_on_partial_ord,
        reason = "a NaN must take the refusing branch, which !(x > t) says and x <= t does not"
    )]
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        if !(xd.is_finite() && yd.is_finite()) {
            return None;
        }
        match *self {
            Distortion::None => Some((xd, yd)),
            Distortion::OpenCv { k1, k2, p1, p2 } => {
                let (mut x, mut y) = (xd, yd);
                for _ in 0..50 {
                    let (fx, fy) = self.distort(x, y);
                    let (ex, ey) = (fx - xd, fy - yd);
                    if ex.abs().max(ey.abs()) < 1e-14 * (1.0 + xd.abs().max(yd.abs())) {
                        return Some((x, y));
                    }
                    // The Jacobian of `distort`.
                    let r2 = x * x + y * y;
                    let radial = 1.0 + r2 * (k1 + r2 * k2);
                    let dradial = 2.0 * (k1 + 2.0 * k2 * r2);
                    let a = radial + x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x;
                    let b = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y;
                    let c = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y;
                    let d = radial + y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x;
                    let det = a * d - b * c;
                    if !(det.abs() > 1e-12) {
                        return None;
                    }
                    x -= (d * ex - b * ey) / det;
                    y -= (a * ey - c * ex) / det;
                    if !(x.is_finite() && y.is_finite()) {
                        return None;
                    }
                }
                let (fx, fy) = self.distort(x, y);
                ((fx - xd).abs().max((fy - yd).abs()) < 1e-10).then_some((x, y))
            }
            Distortion::Fisheye { .. } => {
                let rd = (xd * xd + yd * yd).sqrt();
                if rd < 1e-12 {
                    return Some((xd, yd));
                }
                let mut theta = rd.min(FISHEYE_MAX_ANGLE);
                for _ in 0..50 {
                    let e = self.fisheye_radius(theta) - rd;
                    if e.abs() < 1e-14 * (1.0 + rd) {
                        break;
                    }
                    let slope = self.fisheye_slope(theta);
                    if !(slope > 1e-9) {
                        return None;
                    }
                    theta = (theta - e / slope).clamp(0.0, FISHEYE_MAX_ANGLE);
                }
                if (self.fisheye_radius(theta) - rd).abs() > 1e-10 || theta >= FISHEYE_MAX_ANGLE {
                    return None;
                }
                let s = theta.tan() / rd;
                Some((xd * s, yd * s))
            }
        }
    }
}

/// Pixel intrinsics of a real camera for a `width × height` image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Horizontal focal length in pixels.
    pub fx: f64,
    /// Vertical focal length in pixels.
    pub fy: f64,
    /// The principal point's x in pixels (the image centre is `(w/2, h/2)`).
    pub cx: f64,
    /// The principal point's y in pixels.
    pub cy: f64,
    /// How the lens bends rays away from a pinhole's.
    pub distortion: Distortion,
}

/// Focal lengths a lens may have, in pixels per unit of the depth-one
/// plane: wide enough for any real camera, narrow enough that every ray
/// stays finite in f32.
pub const FOCAL_PIXELS: (f64, f64) = (1e-3, 1e7);

impl Intrinsics {
    /// A pinhole with its principal point at the image centre.
    pub fn centred(width: u32, height: u32, fx: f64, fy: f64) -> Self {
        Intrinsics {
            width,
            height,
            fx,
            fy,
            cx: width as f64 / 2.0,
            cy: height as f64 / 2.0,
            distortion: Distortion::None,
        }
    }

    /// The same lens for `width × height` images (a downscaled copy):
    /// focal lengths and principal point scale with each side.
    pub fn scaled(&self, width: u32, height: u32) -> Intrinsics {
        if (width, height) == (self.width, self.height) {
            return *self;
        }
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Intrinsics {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            distortion: self.distortion,
        }
    }

    /// The pixel `(u, v)` (OpenCV: centres at `i + ½`) where the camera-space
    /// point `p` (x right, y down, z forward) lands; `None` behind the camera.
    #[allow(
        clippy::neg_cmp_op_on_partial_ord,
        reason = "a NaN must take the refusing branch, which !(x > t) says and x <= t does not"
    )]
    pub fn project(&self, p: [f64; 3]) -> Option<(f64, f64)> {
        if !(p[2] > 0.0) {
            return None;
        }
        let (xd, yd) = self.distortion.distort(p[0] / p[2], p[1] / p[2]);
        Some((self.fx * xd + self.cx, self.fy * yd + self.cy))
    }

    /// The undistorted point at depth one (x right, y down) seen at pixel
    /// position `(u, v)`.
    pub fn unproject(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        self.distortion
            .undistort((u - self.cx) / self.fx, (v - self.cy) / self.fy)
    }

    /// Refuses intrinsics no real lens has, with the reason: non-finite or
    /// out-of-range numbers, a principal point far outside the image, and
    /// distortion that does not map the image one-to-one (checked over a
    /// grid of the image: each point undistorts and distorts back within
    /// 1e-4 px, and the radial profile keeps increasing out to the corners).
    #[allow(
        clippy::neg_cmp_op_on_partial_ord,
        reason = "a NaN must take the refusing branch, which !(x > t) says and x <= t does not"
    )]
    pub fn check(&self) -> Result<(), String> {
        let (lo, hi) = FOCAL_PIXELS;
        if self.width == 0 || self.height == 0 {
            return Err(format!(
                "the image size {}x{} is empty",
                self.width, self.height
            ));
        }
        for (name, f) in [("fl_x", self.fx), ("fl_y", self.fy)] {
            if !(f.is_finite() && (lo..=hi).contains(&f)) {
                return Err(format!(
                    "`{name}` {f} is not a focal length in pixels ({lo:e} to {hi:e})"
                ));
            }
        }
        let (w, h) = (self.width as f64, self.height as f64);
        for (name, c, n) in [("cx", self.cx, w), ("cy", self.cy, h)] {
            if !(c.is_finite() && c > -n && c < 2.0 * n) {
                return Err(format!(
                    "`{name}` {c} puts the principal point more than an image away from a {}x{} image",
                    self.width, self.height
                ));
            }
        }
        let k = self.distortion.coefficients();
        if let Some(bad) = k.iter().find(|v| !(v.is_finite() && v.abs() <= 1e3)) {
            return Err(format!(
                "a distortion coefficient ({bad}) is not a finite number within ±1000"
            ));
        }
        if self.distortion.is_none() {
            return Ok(());
        }
        // One-to-one along every radius out to the farthest corner: the
        // distorted radius keeps growing with the undistorted one.
        let corners = [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)];
        let reach = corners
            .iter()
            .map(|&(u, v)| {
                (((u - self.cx) / self.fx).powi(2) + ((v - self.cy) / self.fy).powi(2)).sqrt()
            })
            .fold(0.0, f64::max);
        if let Distortion::Fisheye { .. } = self.distortion {
            let max_rd = self.distortion.fisheye_radius(FISHEYE_MAX_ANGLE);
            let steps = 512;
            for s in 0..=steps {
                let theta = FISHEYE_MAX_ANGLE * s as f64 / steps as f64;
                if self.distortion.fisheye_slope(theta) <= 0.0
                    && self.distortion.fisheye_radius(theta) <= reach
                {
                    return Err("the fisheye distortion folds over inside the image (its radius stops growing with the angle)".into());
                }
            }
            if max_rd < reach {
                return Err(format!(
                    "the image reaches farther than {}° from the optical axis, wider than sdfl's rays through the depth-one plane allow",
                    FISHEYE_MAX_ANGLE.to_degrees()
                ));
            }
        }
        let mut worst: f64 = 0.0;
        let n = 16;
        for a in 0..=n {
            for b in 0..=n {
                let (u, v) = (w * a as f64 / n as f64, h * b as f64 / n as f64);
                let Some((x, y)) = self.unproject(u, v) else {
                    return Err(format!(
                        "the distortion cannot be undone at pixel ({u}, {v}): the model folds over inside the image"
                    ));
                };
                let (xd, yd) = self.distortion.distort(x, y);
                let (u2, v2) = (self.fx * xd + self.cx, self.fy * yd + self.cy);
                worst = worst.max((u2 - u).abs().max((v2 - v).abs()));
            }
        }
        if !(worst <= 1e-4) {
            return Err(format!(
                "undoing the distortion misses by {worst:e} px inside the image: the model folds over"
            ));
        }
        if let Distortion::OpenCv { k1, k2, .. } = self.distortion {
            // Radial monotonicity: d/dr r(1 + k1r² + k2r⁴) > 0 up to the reach
            // found (a fold the grid could step over).
            let steps = 512;
            for s in 0..=steps {
                let r = reach * 1.5 * s as f64 / steps as f64;
                let r2 = r * r;
                if 1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2 <= 0.0 {
                    return Err(format!(
                        "the radial distortion (k1 {k1}, k2 {k2}) folds over at radius {r:.3} inside the image"
                    ));
                }
            }
        }
        Ok(())
    }
}
