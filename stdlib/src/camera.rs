//! Cameras, exactly as in CONVENTIONS.md (PyTorch3D-style NDC): +x of the
//! image points left, +y up; the corner pixel centres sit at NDC ±1.

use glam::DVec3;
use serde::Serialize;

/// A perspective pinhole camera looking from `eye` towards `at`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Camera {
    pub eye: DVec3,
    pub at: DVec3,
    pub up: DVec3,
    /// Focal length in NDC units.
    pub focal: f64,
    pub pixel_centers: PixelCenters,
}

/// Where pixel centres sit in NDC.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelCenters {
    /// CONVENTIONS.md: `x = 1 - 2i/(W-1)`; the corner pixels' centres sit
    /// exactly at ±1.
    #[default]
    Corners,
    /// `x = 1 - (2i+1)/W`: pixels tile [-1, 1] and centres sit half a pixel
    /// in. The assignment's own `box_*.npy` renders were made this way.
    Half,
}

/// The up axis of an orbit: the two orbits of the conventions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OrbitUp {
    Y,
    Z,
}

impl Camera {
    pub fn look_at(eye: DVec3, at: DVec3, up: DVec3, focal: f64) -> Self {
        Camera {
            eye,
            at,
            up,
            focal,
            pixel_centers: PixelCenters::Corners,
        }
    }

    pub fn with_pixel_centers(mut self, pixel_centers: PixelCenters) -> Self {
        self.pixel_centers = pixel_centers;
        self
    }

    /// NDC of the centre of pixel `(i, j)` of a `w × h` image, by this
    /// camera's pixel-centre convention.
    pub fn pixel_ndc(&self, i: u32, j: u32, w: u32, h: u32) -> (f64, f64) {
        match self.pixel_centers {
            PixelCenters::Corners => pixel_ndc(i, j, w, h),
            PixelCenters::Half => {
                let axis = |k: u32, n: u32| 1.0 - (2.0 * k as f64 + 1.0) / n as f64;
                (axis(i, w), axis(j, h))
            }
        }
    }

    /// [`Self::pixel_ndc`] at fractional pixel coordinates `(x, y)` (pixel
    /// centres at whole numbers; `x + 0.5` is the pixel's right edge), for
    /// rays through a pixel off its centre (supersampling).
    pub fn pixel_ndc_at(&self, x: f64, y: f64, w: u32, h: u32) -> (f64, f64) {
        let axis = |k: f64, n: u32| match self.pixel_centers {
            PixelCenters::Corners if n > 1 => 1.0 - 2.0 * k / (n - 1) as f64,
            // One pixel spans the whole of -1..1.
            PixelCenters::Corners => -2.0 * k,
            PixelCenters::Half => 1.0 - (2.0 * k + 1.0) / n as f64,
        };
        (axis(x, w), axis(y, h))
    }

    /// The camera axes `(x, y, z)`: the columns of `R`.
    /// `z = normalize(at - eye)`, `x = normalize(cross(up, z))`, `y = cross(z, x)`.
    pub fn axes(&self) -> (DVec3, DVec3, DVec3) {
        let z = (self.at - self.eye).normalize();
        let x = self.up.cross(z).normalize();
        let y = z.cross(x);
        (x, y, z)
    }

    /// Whether the axes are well defined (eye ≠ at, up not parallel to the view).
    pub fn is_valid(&self) -> bool {
        let (x, y, z) = self.axes();
        self.focal.is_finite() && self.focal > 0.0 && [x, y, z].iter().all(|v| v.is_finite())
    }

    /// World-space unit direction of the ray through NDC point `(x_ndc, y_ndc)`:
    /// the point `[x/f, y/f, 1]` in camera space, taken back to world space,
    /// minus the eye. With `p_cam = p·R + T`, `T = -eye·R`, that point is
    /// `eye + (x/f)·X + (y/f)·Y + Z`.
    pub fn ray_direction(&self, x_ndc: f64, y_ndc: f64) -> DVec3 {
        let (x, y, z) = self.axes();
        (x * (x_ndc / self.focal) + y * (y_ndc / self.focal) + z).normalize()
    }

    /// World → camera space: `p·R + T`.
    pub fn to_camera(&self, p: DVec3) -> DVec3 {
        let (x, y, z) = self.axes();
        let d = p - self.eye;
        DVec3::new(d.dot(x), d.dot(y), d.dot(z))
    }

    /// `n` orbit ("surround") cameras looking at the origin.
    pub fn orbit(radius: f64, up: OrbitUp, focal: f64, views: usize) -> Vec<Camera> {
        (0..views)
            .map(|k| {
                let theta = std::f64::consts::TAU * k as f64 / views as f64;
                let a = theta + std::f64::consts::FRAC_PI_2;
                let (eye, upv) = match up {
                    OrbitUp::Y => (
                        DVec3::new(radius * a.cos(), 0.0, -radius * a.sin()),
                        DVec3::Y,
                    ),
                    OrbitUp::Z => (
                        DVec3::new(radius * a.cos(), radius * a.sin(), 2.0),
                        DVec3::Z,
                    ),
                };
                Camera::look_at(eye, DVec3::ZERO, upv, focal)
            })
            .collect()
    }
}

/// A camera-to-world pose in OpenGL/Blender axes (NeRF-synthetic's
/// `transform_matrix`): the camera looks down its −z, +y is up, +x right;
/// row-major, columns = right, up, back, position. With pixel focal
/// lengths and the principal point at the image centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GlPose {
    pub c2w: [[f64; 4]; 4],
    /// Focal lengths in pixels (`fl_x`, `fl_y`).
    pub fl_x: f64,
    pub fl_y: f64,
}

impl Camera {
    /// `views` cameras on a Fibonacci lattice over the sphere (or the
    /// hemisphere above `up`) of `radius`, looking at the origin with `up`
    /// (unit). Heights along `up` are `1 - (2k+1)/views` (hemisphere:
    /// `1 - (k+½)/views`), so no camera sits on the pole, where `up` would
    /// be parallel to the view.
    pub fn sphere(
        views: usize,
        radius: f64,
        up: DVec3,
        focal: f64,
        hemisphere: bool,
    ) -> Vec<Camera> {
        let helper = if up.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
        let e1 = up.cross(helper).normalize();
        let e2 = up.cross(e1);
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        (0..views)
            .map(|k| {
                let f = (k as f64 + 0.5) / views as f64;
                let h = if hemisphere { 1.0 - f } else { 1.0 - 2.0 * f };
                let r = (1.0 - h * h).max(0.0).sqrt();
                let phi = golden * k as f64;
                let dir = up * h + (e1 * phi.cos() + e2 * phi.sin()) * r;
                Camera::look_at(dir * radius, DVec3::ZERO, up, focal)
            })
            .collect()
    }

    /// This camera as an OpenGL pose for a `w × h` image. sdfl's camera
    /// axes are (left, up, forward) (NDC +x points left), so right = −x,
    /// up = y, back = −z. Pixel focal lengths follow the pixel-centre
    /// convention: corner centres span `w - 1` pixels between NDC ±1, half
    /// centres `w`; either way pixel `i` has OpenGL centre `i + ½`.
    pub fn to_opengl(&self, w: u32, h: u32) -> GlPose {
        let (x, y, z) = self.axes();
        let cols = [-x, y, -z, self.eye];
        let mut c2w = [[0.0; 4]; 4];
        for (r, row) in c2w.iter_mut().take(3).enumerate() {
            for (c, col) in cols.iter().enumerate() {
                row[c] = col[r];
            }
        }
        c2w[3] = [0.0, 0.0, 0.0, 1.0];
        let span = |n: u32| match self.pixel_centers {
            PixelCenters::Corners => (n.max(2) - 1) as f64,
            PixelCenters::Half => n as f64,
        };
        GlPose {
            c2w,
            fl_x: self.focal * span(w) / 2.0,
            fl_y: self.focal * span(h) / 2.0,
        }
    }

    /// The sdfl camera of an OpenGL pose for a `w × h` image (principal
    /// point at the centre): the same ray through every pixel. The rotation
    /// must be orthonormal and right-handed (within 1e-3) and the pixels
    /// square in sdfl's NDC (one focal for both axes): `fl_x/w = fl_y/h`
    /// (half-pixel centres, preferred) or `fl_x/(w-1) = fl_y/(h-1)`
    /// (corner centres). The result's `at` is one unit ahead of the eye
    /// and its `up` the pose's up axis.
    pub fn from_opengl(pose: &GlPose, w: u32, h: u32) -> Result<Camera, String> {
        let m = &pose.c2w;
        if !m.iter().flatten().all(|v| v.is_finite()) {
            return Err("the matrix holds a non-finite number".into());
        }
        if !(pose.fl_x.is_finite() && pose.fl_x > 0.0 && pose.fl_y.is_finite() && pose.fl_y > 0.0) {
            return Err("the focal length is not a positive finite number".into());
        }
        let bottom = [0.0, 0.0, 0.0, 1.0];
        if m[3].iter().zip(bottom).any(|(a, b)| (a - b).abs() > 1e-6) {
            return Err(format!("the last row is {:?}, not [0, 0, 0, 1]", m[3]));
        }
        let col = |c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
        let (right, up, back, eye) = (col(0), col(1), col(2), col(3));
        let tol = 1e-3;
        let unit = [right, up, back]
            .iter()
            .all(|v| (v.length() - 1.0).abs() < tol);
        let orthogonal =
            right.dot(up).abs() < tol && up.dot(back).abs() < tol && back.dot(right).abs() < tol;
        if !(unit && orthogonal) {
            return Err("the rotation is not orthonormal (scaled or sheared pose)".into());
        }
        if right.cross(up).dot(back) < 0.0 {
            return Err("the rotation is a reflection (left-handed axes)".into());
        }
        if eye.abs().max_element() > 1e18 {
            return Err("the camera position is out of range".into());
        }
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * a.abs().max(b.abs());
        let (wf, hf) = (w as f64, h as f64);
        let (focal, centers) = if w == 1 || h == 1 {
            // A one-pixel side's rays sit at NDC 0 whatever its focal: the
            // other side alone decides (half centres fit any pixel focal).
            let (fl, n) = if w == 1 {
                (pose.fl_y, hf)
            } else {
                (pose.fl_x, wf)
            };
            (2.0 * fl / n, PixelCenters::Half)
        } else if close(pose.fl_x / wf, pose.fl_y / hf) {
            (2.0 * pose.fl_x / wf, PixelCenters::Half)
        } else if w > 1 && h > 1 && close(pose.fl_x / (wf - 1.0), pose.fl_y / (hf - 1.0)) {
            (2.0 * pose.fl_x / (wf - 1.0), PixelCenters::Corners)
        } else {
            return Err(format!(
                "focal lengths {} and {} pixels for {w}x{h} images: sdfl cameras have one focal length for both NDC axes, so pixels must be square in NDC",
                pose.fl_x, pose.fl_y
            ));
        };
        let cam = Camera::look_at(eye, eye - back, up, focal).with_pixel_centers(centers);
        if !cam.is_valid() {
            return Err("the pose has no well-defined orientation".into());
        }
        Ok(cam)
    }
}

/// NDC coordinates of the centre of pixel `(i, j)` (column, row from the top)
/// of a `w × h` image: `x = 1 - 2i/(w-1)`, `y = 1 - 2j/(h-1)`. A dimension of
/// one pixel sits at 0.
pub fn pixel_ndc(i: u32, j: u32, w: u32, h: u32) -> (f64, f64) {
    let axis = |k: u32, n: u32| {
        if n > 1 {
            1.0 - 2.0 * k as f64 / (n - 1) as f64
        } else {
            0.0
        }
    };
    (axis(i, w), axis(j, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corner_pixels_are_at_plus_minus_one() {
        assert_eq!(pixel_ndc(0, 0, 256, 256), (1.0, 1.0));
        assert_eq!(pixel_ndc(255, 255, 256, 256), (-1.0, -1.0));
    }

    #[test]
    fn fractional_pixels_agree_with_whole_ones() {
        for centers in [PixelCenters::Corners, PixelCenters::Half] {
            let cam = Camera {
                pixel_centers: centers,
                ..Camera::look_at(DVec3::new(0.0, 0.0, -3.0), DVec3::ZERO, DVec3::Y, 1.0)
            };
            for (i, j, w, h) in [(0, 0, 8, 6), (7, 5, 8, 6), (3, 2, 8, 6), (0, 0, 1, 1)] {
                let (x, y) = cam.pixel_ndc_at(i as f64, j as f64, w, h);
                let (xw, yw) = cam.pixel_ndc(i, j, w, h);
                assert!((x - xw).abs() < 1e-15 && (y - yw).abs() < 1e-15);
                // Half a pixel right is half a pixel's width further in NDC.
                let (xr, _) = cam.pixel_ndc_at(i as f64 + 0.5, j as f64, w, h);
                let (xn, _) = cam.pixel_ndc_at(i as f64 + 1.0, j as f64, w, h);
                assert!(((x - xr) - 0.5 * (x - xn)).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn projection_inverts_ray_direction() {
        // A point along the ray through an NDC point projects back onto it:
        // x_ndc = f·X/Z, y_ndc = f·Y/Z.
        let cam = Camera::look_at(DVec3::new(1.0, 0.5, -2.2), DVec3::ZERO, DVec3::Y, 1.7);
        for (xn, yn) in [(0.3, -0.7), (1.0, 1.0), (-1.0, 0.2)] {
            let p = cam.eye + cam.ray_direction(xn, yn) * 3.1;
            let c = cam.to_camera(p);
            assert!((cam.focal * c.x / c.z - xn).abs() < 1e-12);
            assert!((cam.focal * c.y / c.z - yn).abs() < 1e-12);
        }
    }

    #[test]
    fn ndc_x_points_left_and_y_up() {
        // From +z looking at the origin with up +y, world +x is on the
        // viewer's right. Camera x = cross(up, z) = cross(+y, -z) = -x, so
        // world +x gets a negative x_ndc: the right, as NDC +x points left.
        let cam = Camera::look_at(DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO, DVec3::Y, 1.0);
        let c = cam.to_camera(DVec3::new(0.5, 0.0, 0.0));
        assert!(c.x < 0.0);
        let d = cam.to_camera(DVec3::new(0.0, 0.5, 0.0));
        assert!(d.y > 0.0);
    }

    #[test]
    fn orbit_matches_conventions() {
        let cams = Camera::orbit(3.0, OrbitUp::Z, 1.0, 20);
        assert_eq!(cams.len(), 20);
        // θ0 = 0 → eye = (r cos(π/2), r sin(π/2), 2) = (0, 3, 2).
        assert!((cams[0].eye - DVec3::new(0.0, 3.0, 2.0)).length() < 1e-12);
        let cams = Camera::orbit(3.0, OrbitUp::Y, 1.0, 4);
        // θ0 = 0 → eye = (0, 0, -3); θ1 = π/2 → eye = (r cos π, 0, -r sin π) = (-3, 0, 0).
        assert!((cams[0].eye - DVec3::new(0.0, 0.0, -3.0)).length() < 1e-12);
        assert!((cams[1].eye - DVec3::new(-3.0, 0.0, 0.0)).length() < 1e-12);
    }

    fn same_rays(a: &Camera, b: &Camera, w: u32, h: u32) -> f64 {
        let mut worst: f64 = 0.0;
        for j in 0..h {
            for i in 0..w {
                let (ax, ay) = a.pixel_ndc(i, j, w, h);
                let (bx, by) = b.pixel_ndc(i, j, w, h);
                let da = a.ray_direction(ax, ay);
                let db = b.ray_direction(bx, by);
                worst = worst.max((da - db).length()).max((a.eye - b.eye).length());
            }
        }
        worst
    }

    #[test]
    fn opengl_poses_round_trip_to_the_same_rays() {
        let cams = [
            Camera::look_at(DVec3::new(1.0, 0.5, -2.2), DVec3::ZERO, DVec3::Y, 1.7),
            Camera::look_at(
                DVec3::new(0.0, -3.0, 2.0),
                DVec3::new(0.1, 0.2, 0.0),
                DVec3::Z,
                1.0,
            )
            .with_pixel_centers(PixelCenters::Half),
            Camera::look_at(
                DVec3::new(-2.0, 1.0, 0.3),
                DVec3::ZERO,
                DVec3::new(0.3, 1.0, 0.1),
                2.5,
            ),
        ];
        for cam in cams {
            for (w, h) in [(16, 16), (33, 20), (1, 7)] {
                let back = Camera::from_opengl(&cam.to_opengl(w, h), w, h).unwrap();
                let err = same_rays(&cam, &back, w, h);
                assert!(err < 1e-12, "{cam:?} {w}x{h}: {err}");
            }
        }
    }

    #[test]
    fn a_point_lands_on_the_same_pixel_in_both_conventions() {
        let cam = Camera::look_at(
            DVec3::new(1.0, 2.0, -3.0),
            DVec3::new(0.2, 0.0, 0.1),
            DVec3::Y,
            1.4,
        )
        .with_pixel_centers(PixelCenters::Half);
        let (w, h) = (40u32, 40u32);
        let pose = cam.to_opengl(w, h);
        let m = pose.c2w;
        let col = |c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
        for p in [DVec3::new(0.3, -0.2, 0.5), DVec3::new(-0.4, 0.6, 0.0)] {
            // OpenGL: camera coordinates, looking down −z; pixel centres at
            // i + ½ with rows going down.
            let d = p - col(3);
            let (xc, yc, zc) = (d.dot(col(0)), d.dot(col(1)), d.dot(col(2)));
            let u = w as f64 / 2.0 + pose.fl_x * xc / -zc;
            let v = h as f64 / 2.0 - pose.fl_y * yc / -zc;
            // sdfl: NDC by x = f·X/Z, half-pixel centres x = 1 - (2i+1)/W.
            let c = cam.to_camera(p);
            let (xn, yn) = (cam.focal * c.x / c.z, cam.focal * c.y / c.z);
            let i = (1.0 - xn) * w as f64 / 2.0 - 0.5;
            let j = (1.0 - yn) * h as f64 / 2.0 - 0.5;
            assert!(
                (u - 0.5 - i).abs() < 1e-9 && (v - 0.5 - j).abs() < 1e-9,
                "{u} {v} vs {i} {j}"
            );
        }
    }

    #[test]
    fn hostile_poses_are_refused() {
        let good =
            Camera::look_at(DVec3::new(0.0, 0.0, -3.0), DVec3::ZERO, DVec3::Y, 1.0).to_opengl(8, 8);
        let mut nan = good;
        nan.c2w[0][1] = f64::NAN;
        let mut scaled = good;
        for r in 0..3 {
            scaled.c2w[r][0] *= 2.0;
        }
        let mut mirrored = good;
        for r in 0..3 {
            mirrored.c2w[r][0] *= -1.0;
        }
        let mut stretched = good;
        stretched.fl_y *= 1.5;
        for bad in [nan, scaled, mirrored, stretched] {
            assert!(Camera::from_opengl(&bad, 8, 8).is_err());
        }
    }

    #[test]
    fn sphere_views_surround_the_origin() {
        let cams = Camera::sphere(100, 4.0, DVec3::Z, 1.0, false);
        assert_eq!(cams.len(), 100);
        assert!(cams
            .iter()
            .all(|c| c.is_valid() && (c.eye.length() - 4.0).abs() < 1e-9));
        // Balanced: the mean position is near the centre.
        let mean = cams.iter().fold(DVec3::ZERO, |a, c| a + c.eye) / 100.0;
        assert!(mean.length() < 0.1, "{mean}");
        let upper = Camera::sphere(50, 4.0, DVec3::Y, 1.0, true);
        assert!(upper.iter().all(|c| c.eye.y > 0.0 && c.is_valid()));
    }
}
