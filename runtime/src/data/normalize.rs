//! Scene normalisation: the similarity that takes a capture's own world
//! frame (COLMAP's, or whatever a `transforms.json` was saved in) to the
//! frame sdfl trains in, as nerfstudio's `auto_orient_and_center_poses`
//! (orientation "up" or "none", centre "poses") and `auto_scale_poses` do.
//!
//! `to_scene(p) = scale · R · (p − center)`; `to_data` is its inverse, so
//! exports (meshes, points, cameras) map back into the data's frame.

use glam::{DMat3, DQuat, DVec3};
use serde::Serialize;

/// How the cameras are turned before centring and scaling.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Orient {
    /// Keep the data's axes.
    None,
    /// Turn the cameras' mean up vector onto +z (nerfstudio's "up").
    Up,
}

/// The similarity from the data's frame to sdfl's scene frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SceneFrame {
    /// Multiplies lengths in the data's frame (after rotating).
    pub scale: f64,
    /// The data-frame point that becomes the origin.
    pub center: [f64; 3],
    /// Row-major rotation applied after subtracting `center`.
    pub rotation: [[f64; 3]; 3],
    /// nerfstudio's `applied_transform` where the file has one: rows of the
    /// 3×4 rigid map from the original (COLMAP) frame to the data's frame.
    pub applied: Option<[[f64; 4]; 3]>,
}

impl SceneFrame {
    /// No change: the scene frame is the data's frame.
    pub const IDENTITY: SceneFrame = SceneFrame {
        scale: 1.0,
        center: [0.0; 3],
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        applied: None,
    };

    fn r(&self) -> DMat3 {
        DMat3::from_cols_array_2d(&self.rotation).transpose()
    }

    /// The frame that subtracts `center`, rotates by `rotation` and scales by `scale`.
    pub fn new(scale: f64, center: DVec3, rotation: DMat3) -> SceneFrame {
        SceneFrame {
            scale,
            center: center.to_array(),
            rotation: rotation.transpose().to_cols_array_2d(),
            applied: None,
        }
    }

    /// A data-frame point in the scene frame.
    pub fn to_scene(&self, p: DVec3) -> DVec3 {
        self.r() * (p - DVec3::from_array(self.center)) * self.scale
    }

    /// A scene-frame point in the data's frame.
    pub fn to_data(&self, q: DVec3) -> DVec3 {
        self.r().transpose() * (q / self.scale) + DVec3::from_array(self.center)
    }

    /// [`Self::to_data`] as an affine map (for exports' positions and,
    /// by its inverse transpose, normals).
    pub fn to_data_affine(&self) -> glam::DAffine3 {
        glam::DAffine3::from_mat3_translation(
            self.r().transpose() * (1.0 / self.scale),
            DVec3::from_array(self.center),
        )
    }

    /// A data-frame point in the original frame the data's was made from
    /// (nerfstudio's `applied_transform` undone; the data's frame without).
    pub fn data_to_original(&self, p: DVec3) -> DVec3 {
        let Some(a) = self.applied else { return p };
        let row = |r: usize| DVec3::new(a[r][0], a[r][1], a[r][2]);
        let t = DVec3::new(a[0][3], a[1][3], a[2][3]);
        // Rigid: the inverse rotation is the transpose.
        let d = p - t;
        row(0) * d.x + row(1) * d.y + row(2) * d.z
    }

    /// A camera-to-world pose (rows, any axis convention) moved into the
    /// scene frame: the rotation turned, the position mapped; still rigid.
    pub fn pose_to_scene(&self, c2w: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
        let r = self.r();
        let col = |c: usize| DVec3::new(c2w[0][c], c2w[1][c], c2w[2][c]);
        let cols = [r * col(0), r * col(1), r * col(2), self.to_scene(col(3))];
        let mut m = [[0.0; 4]; 4];
        for (row, out) in m.iter_mut().take(3).enumerate() {
            for (c, v) in cols.iter().enumerate() {
                out[c] = v[row];
            }
        }
        m[3] = [0.0, 0.0, 0.0, 1.0];
        m
    }

    /// The frame that centres the cameras on their mean position, turns
    /// their mean up (OpenGL +y, the pose's second column) onto +z when
    /// `orient` is `Up`, and scales so that the farthest camera coordinate
    /// is `extent` (nerfstudio: 1, the cameras inside [−1, 1]³). Cameras
    /// all at one point keep scale 1.
    pub fn from_cameras(poses: &[[[f64; 4]; 4]], orient: Orient, extent: f64) -> SceneFrame {
        let n = poses.len().max(1) as f64;
        let col = |m: &[[f64; 4]; 4], c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
        let center = poses.iter().map(|m| col(m, 3)).sum::<DVec3>() / n;
        let rotation = match orient {
            Orient::None => DMat3::IDENTITY,
            Orient::Up => {
                let up = poses.iter().map(|m| col(m, 1)).sum::<DVec3>();
                if up.length() > 1e-9 {
                    // The shortest turn taking `up` to +z (glam handles the
                    // opposite case with a half turn about a perpendicular).
                    DMat3::from_quat(DQuat::from_rotation_arc(up.normalize(), DVec3::Z))
                } else {
                    DMat3::IDENTITY
                }
            }
        };
        let reach = poses
            .iter()
            .map(|m| (rotation * (col(m, 3) - center)).abs().max_element())
            .fold(0.0, f64::max);
        let scale = if reach > 1e-12 { extent / reach } else { 1.0 };
        SceneFrame::new(scale, center, rotation)
    }

    /// One line for people: what was done to the data's frame.
    pub fn describe(&self) -> String {
        let c = self.center;
        let turned = self.r() != DMat3::IDENTITY;
        format!(
            "scene frame: data centred at ({}, {}, {}), scaled by {}{}",
            sdfl_lang::fmt_num(c[0]),
            sdfl_lang::fmt_num(c[1]),
            sdfl_lang::fmt_num(c[2]),
            sdfl_lang::fmt_num(self.scale),
            if turned {
                ", turned so the cameras' mean up is +z"
            } else {
                ""
            }
        )
    }
}

/// NeRF's normalised device coordinates for forward-facing scenes: the ray
/// `o + t·d` (camera looking down −z in a frame centred on the mean
/// camera) moved to the `near` plane and mapped into the NDC cube, for a
/// `w × h` image with pixel focal `focal`. Returns the NDC origin and
/// (unnormalised) direction; `t' ∈ [0, 1)` spans `near` to infinity.
/// None for a ray parallel to the near plane or starting behind it.
pub fn ndc_ray(
    w: f64,
    h: f64,
    focal: f64,
    near: f64,
    o: DVec3,
    d: DVec3,
) -> Option<(DVec3, DVec3)> {
    if d.z.abs() < 1e-12 {
        return None;
    }
    let t = -(near + o.z) / d.z;
    let o = o + d * t;
    if o.z.abs() < 1e-12 {
        return None;
    }
    let (ax, ay) = (-2.0 * focal / w, -2.0 * focal / h);
    let origin = DVec3::new(ax * o.x / o.z, ay * o.y / o.z, 1.0 + 2.0 * near / o.z);
    let dir = DVec3::new(
        ax * (d.x / d.z - o.x / o.z),
        ay * (d.y / d.z - o.y / o.z),
        -2.0 * near / o.z,
    );
    Some((origin, dir))
}

/// The NDC image of a world point (the same map as [`ndc_ray`]).
pub fn ndc_point(w: f64, h: f64, focal: f64, near: f64, p: DVec3) -> DVec3 {
    let (ax, ay) = (-2.0 * focal / w, -2.0 * focal / h);
    DVec3::new(ax * p.x / p.z, ay * p.y / p.z, 1.0 + 2.0 * near / p.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(eye: DVec3, up: DVec3) -> [[f64; 4]; 4] {
        // Looking at the origin, OpenGL axes (right, up, back).
        let back = eye.normalize();
        let right = up.cross(back).normalize();
        let upv = back.cross(right);
        let mut m = [[0.0; 4]; 4];
        for (c, v) in [right, upv, back, eye].iter().enumerate() {
            for r in 0..3 {
                m[r][c] = v[r];
            }
        }
        m[3][3] = 1.0;
        m
    }

    #[test]
    fn cameras_end_inside_the_unit_cube_and_map_back() {
        let up = DVec3::new(0.2, 1.0, -0.3).normalize();
        let off = DVec3::new(10.0, -4.0, 7.0);
        let poses: Vec<_> = (0..12)
            .map(|k| {
                let a = k as f64 * 0.5;
                let side = up.any_orthonormal_vector();
                let side2 = up.cross(side);
                pose(
                    (side * a.cos() + side2 * a.sin()) * 25.0 + up * 5.0 + off,
                    up,
                )
            })
            .collect();
        for orient in [Orient::None, Orient::Up] {
            let f = SceneFrame::from_cameras(&poses, orient, 1.0);
            let mut reach: f64 = 0.0;
            for p in &poses {
                let q = f.to_scene(DVec3::new(p[0][3], p[1][3], p[2][3]));
                reach = reach.max(q.abs().max_element());
                let back = f.to_data(q);
                assert!((back - DVec3::new(p[0][3], p[1][3], p[2][3])).length() < 1e-9);
                // The affine map that exports use is the same map.
                assert!((f.to_data_affine().transform_point3(q) - back).length() < 1e-9);
                // The moved pose is rigid and puts the eye where to_scene does.
                let m = f.pose_to_scene(p);
                assert!((DVec3::new(m[0][3], m[1][3], m[2][3]) - q).length() < 1e-12);
                let r = DMat3::from_cols(
                    DVec3::new(m[0][0], m[1][0], m[2][0]),
                    DVec3::new(m[0][1], m[1][1], m[2][1]),
                    DVec3::new(m[0][2], m[1][2], m[2][2]),
                );
                assert!((r.transpose() * r - DMat3::IDENTITY)
                    .abs()
                    .to_cols_array()
                    .iter()
                    .all(|e| *e < 1e-12));
            }
            assert!((reach - 1.0).abs() < 1e-12, "{reach}");
            if orient == Orient::Up {
                // The mean up now points along +z.
                let mean: DVec3 = poses
                    .iter()
                    .map(|p| {
                        let m = f.pose_to_scene(p);
                        DVec3::new(m[0][1], m[1][1], m[2][1])
                    })
                    .sum();
                assert!((mean.normalize() - DVec3::Z).length() < 1e-9, "{mean}");
            }
        }
        // A known case: two cameras at x = 1 and x = 5 → centre 3, scale ½.
        let f = SceneFrame::from_cameras(
            &[
                pose(DVec3::new(1.0, 0.0, 0.0), DVec3::Z),
                pose(DVec3::new(5.0, 0.0, 0.0), DVec3::Z),
            ],
            Orient::None,
            1.0,
        );
        assert_eq!(f.center, [3.0, 0.0, 0.0]);
        assert!((f.scale - 0.5).abs() < 1e-15);
    }

    #[test]
    fn applied_transform_is_undone() {
        // nerfstudio's usual one from COLMAP: swap x and y, flip z; moved.
        let a = [
            [0.0, 1.0, 0.0, 0.5],
            [1.0, 0.0, 0.0, -2.0],
            [0.0, 0.0, -1.0, 3.0],
        ];
        let f = SceneFrame {
            applied: Some(a),
            ..SceneFrame::IDENTITY
        };
        let p = DVec3::new(0.3, -1.2, 4.0);
        let in_data = DVec3::new(p.y + 0.5, p.x - 2.0, -p.z + 3.0);
        assert!((f.data_to_original(in_data) - p).length() < 1e-12);
        assert_eq!(SceneFrame::IDENTITY.data_to_original(p), p);
    }

    #[test]
    fn up_opposite_to_z_is_a_half_turn() {
        let poses = [
            pose(DVec3::new(0.0, 0.0, 3.0), -DVec3::Y),
            pose(DVec3::new(1.0, 0.0, 3.0), -DVec3::Y),
        ];
        // Mean up here is -y: turned onto +z, still a rotation.
        let f = SceneFrame::from_cameras(&poses, Orient::Up, 1.0);
        assert!(f.r().determinant() > 0.999);
        let m = f.pose_to_scene(&poses[0]);
        assert!((DVec3::new(m[0][1], m[1][1], m[2][1]) - DVec3::Z).length() < 1e-9);
    }

    #[test]
    fn ndc_rays_pass_through_the_ndc_image_of_their_points() {
        // A point on the ray maps to a point on the NDC ray (reference:
        // the projective map applied to the point directly).
        let (w, h, f, near) = (40.0, 30.0, 35.0, 1.0);
        for (o, d) in [
            (DVec3::ZERO, DVec3::new(0.1, -0.2, -1.0)),
            (
                DVec3::new(0.3, 0.1, 0.2),
                DVec3::new(-0.3, 0.05, -1.0).normalize(),
            ),
        ] {
            let (no, nd) = ndc_ray(w, h, f, near, o, d).unwrap();
            // The origin sits on the near plane: NDC z = -1.
            assert!((no.z + 1.0).abs() < 1e-12, "{no}");
            for t in [1.5, 3.0, 40.0] {
                let p = o + d * t;
                let q = ndc_point(w, h, f, near, p);
                // q = no + s·nd for some s in (0, 1).
                let s = (q.z - no.z) / nd.z;
                assert!(s > 0.0 && s < 1.0);
                assert!(
                    (no + nd * s - q).length() < 1e-9,
                    "{t}: {q} vs {}",
                    no + nd * s
                );
            }
        }
        // Hard case: a ray parallel to the near plane has no NDC image.
        assert!(ndc_ray(w, h, f, near, DVec3::ZERO, DVec3::X).is_none());
    }
}
