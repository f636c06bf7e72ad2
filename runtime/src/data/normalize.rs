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

    /// `rotation` as a matrix.
    pub fn r(&self) -> DMat3 {
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
