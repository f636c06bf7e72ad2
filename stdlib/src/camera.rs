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
}
