//! The scene frame: cameras brought inside the unit cube and back, the
//! up axis, NDC rays.

use glam::{DMat3, DVec3};
use sdfl_runtime::data::normalize::*;

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
