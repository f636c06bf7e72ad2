//! IDR's and NeuS's cameras: projections split into intrinsics and a pose
//! (signs, skew, degenerate and non-finite input), scale matrices, the
//! keys counted.

use glam::{DMat3, DVec3};
use sdfl_runtime::data::camera::{Distortion, Intrinsics};
use sdfl_runtime::data::capture::camera_of;
use sdfl_runtime::data::formats::idr::*;
use sdfl_runtime::data::normalize::SceneFrame;

/// A small deterministic generator (SplitMix64) for random cameras.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }

    /// A uniformly random rotation (a unit quaternion from four normals
    /// would do; Shoemake's three uniforms are exact).
    fn rotation(&mut self) -> DMat3 {
        let (u1, u2, u3) = (self.next(), self.next(), self.next());
        let tau = std::f64::consts::TAU;
        let q = glam::DQuat::from_xyzw(
            (1.0 - u1).sqrt() * (tau * u2).sin(),
            (1.0 - u1).sqrt() * (tau * u2).cos(),
            u1.sqrt() * (tau * u3).sin(),
            u1.sqrt() * (tau * u3).cos(),
        );
        DMat3::from_quat(q.normalize())
    }
}

/// `K [R | t]` as rows, `K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]`.
fn projection(k: [f64; 5], r: DMat3, t: DVec3) -> [[f64; 4]; 3] {
    let [fx, skew, cx, fy, cy] = k;
    let kk =
        DMat3::from_cols_array_2d(&[[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]).transpose();
    let m = kk * r;
    let p4 = kk * t;
    let mut p = [[0.0; 4]; 3];
    for (i, row) in p.iter_mut().enumerate() {
        let mr = m.row(i);
        *row = [mr.x, mr.y, mr.z, p4[i]];
    }
    p
}

fn max_diff(a: DMat3, b: DMat3) -> f64 {
    (a - b)
        .to_cols_array()
        .iter()
        .fold(0.0, |m, v| m.max(v.abs()))
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * a.abs().max(b.abs()).max(1.0)
}

#[test]
fn decomposition_recovers_random_cameras_looking_every_way() {
    let mut rng = Rng(7);
    for n in 0..2000 {
        let k = [
            rng.range(50.0, 5000.0),
            0.0,
            rng.range(-100.0, 1700.0),
            rng.range(50.0, 5000.0),
            rng.range(-100.0, 1300.0),
        ];
        let r = rng.rotation();
        let t = DVec3::new(
            rng.range(-500.0, 500.0),
            rng.range(-500.0, 500.0),
            rng.range(-500.0, 500.0),
        );
        // Any overall scale of P, of either sign, is the same camera.
        let scale = rng.range(1e-3, 1e3) * if n % 2 == 0 { 1.0 } else { -1.0 };
        let mut p = projection(k, r, t);
        for v in p.iter_mut().flatten() {
            *v *= scale;
        }
        let d = decompose(&p).unwrap();
        let tol = 1e-9;
        assert!(
            close(d.fx, k[0], tol) && close(d.fy, k[3], tol),
            "{n}: {d:?}"
        );
        assert!(
            close(d.cx, k[2], tol) && close(d.cy, k[4], tol),
            "{n}: {d:?}"
        );
        assert!(d.skew.abs() < 1e-9 * k[0], "{n}: {d:?}");
        assert!(max_diff(d.rotation, r) < 1e-12, "{n}");
        assert!(
            (d.translation - t).length() < 1e-9 * t.length().max(1.0),
            "{n}"
        );
        assert!((d.rotation.determinant() - 1.0).abs() < 1e-12);
    }
    // Skew survives the round trip too (it is refused later, by size).
    let r = rng.rotation();
    let d = decompose(&projection(
        [800.0, 3.0, 400.0, 790.0, 300.0],
        r,
        DVec3::new(1.0, 2.0, 3.0),
    ))
    .unwrap();
    assert!(close(d.skew, 3.0, 1e-9), "{d:?}");
}

#[test]
fn signs_are_fixed_so_focal_lengths_are_positive_and_r_is_a_rotation() {
    let r = DMat3::from_rotation_y(0.4) * DMat3::from_rotation_x(-0.2);
    let t = DVec3::new(0.1, -0.3, 4.0);
    let k = [500.0, 0.0, 320.0, 480.0, 240.0];
    let p = projection(k, r, t);
    let neg = p.map(|row| row.map(|v| -v));
    // A factorisation with negative focal lengths, K·D and D·R with
    // D = diag(-1, -1, 1), is the same matrix: the decomposition picks
    // the positive one.
    for q in [p, neg] {
        let d = decompose(&q).unwrap();
        assert!(d.fx > 0.0 && d.fy > 0.0, "{d:?}");
        assert!((d.rotation.determinant() - 1.0).abs() < 1e-12);
        assert!(max_diff(d.rotation, r) < 1e-12);
        assert!((d.translation - t).length() < 1e-12);
        // The point straight ahead is in front of the camera.
        let ahead = d.eye() + d.rotation.row(2) * 2.0;
        assert!((d.rotation * ahead + d.translation).z > 0.0);
    }
    // The OpenGL pose looks down −z of its own axes: back = −forward.
    let d = decompose(&p).unwrap();
    let m = d.opengl_c2w();
    let back = DVec3::new(m[0][2], m[1][2], m[2][2]);
    assert!((back + r.row(2)).length() < 1e-12);
    let up = DVec3::new(m[0][1], m[1][1], m[2][1]);
    assert!((up + r.row(1)).length() < 1e-12);
}

#[test]
fn degenerate_and_non_finite_projections_are_refused() {
    let zero = [[0.0; 4]; 3];
    assert!(decompose(&zero).unwrap_err().contains("singular"));
    // Rank 2: two equal rows.
    let p = [
        [1.0, 2.0, 3.0, 4.0],
        [1.0, 2.0, 3.0, 5.0],
        [0.0, 0.0, 1.0, 1.0],
    ];
    assert!(decompose(&p).unwrap_err().contains("singular"));
    let mut p = projection([500.0, 0.0, 320.0, 500.0, 240.0], DMat3::IDENTITY, DVec3::Z);
    p[1][2] = f64::NAN;
    assert!(decompose(&p).unwrap_err().contains("non-finite"));
    p[1][2] = f64::INFINITY;
    assert!(decompose(&p).unwrap_err().contains("non-finite"));
}

#[test]
fn skew_and_sheared_poses_are_measured_in_pixels() {
    // A sheared pose (R times a shear) is no rigid camera: it shows
    // as skew in K, which moves pixels by far more than the limit.
    let shear = DMat3::from_cols_array_2d(&[[1.0, 0.0, 0.0], [0.2, 1.0, 0.0], [0.0, 0.0, 1.0]]);
    let p = projection(
        [1000.0, 0.0, 400.0, 1000.0, 300.0],
        shear * DMat3::from_rotation_z(0.3),
        DVec3::new(0.0, 0.0, 5.0),
    );
    let d = decompose(&p).unwrap();
    assert!(d.skew_shift(600.0) > 10.0, "{d:?}");
    // DTU's own (scan24, image 0): K[0][1] ≈ -2.6e-4 against fx 2892
    // on 1600 x 1200: about 5e-5 px, far inside the limit.
    let dtu = projection(
        [2892.33, -2.586e-4, 823.205, 2883.18, 619.071],
        DMat3::from_rotation_y(0.24),
        DVec3::new(-0.5, 0.1, 2.7),
    );
    let d = decompose(&dtu).unwrap();
    let shift = d.skew_shift(1200.0);
    assert!(shift < 1e-4 && shift > 1e-5, "{shift}");
    assert!(shift < MAX_SKEW_SHIFT);
}

#[test]
fn scale_mats_must_be_a_uniform_scale_and_a_translation() {
    let good = [
        [2.5, 0.0, 0.0, 10.0],
        [0.0, 2.5, 0.0, -3.0],
        [0.0, 0.0, 2.5, 600.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    assert_eq!(
        scale_of(&good).unwrap(),
        (2.5, DVec3::new(10.0, -3.0, 600.0))
    );
    type Spoil = fn(&mut [[f64; 4]; 4]);
    let cases: [(&str, Spoil, &str); 6] = [
        ("non-uniform", |m| m[1][1] = 2.6, "[1][1]"),
        ("rotated", |m| m[0][1] = 0.3, "[0][1]"),
        (
            "negative",
            |m| {
                for (i, row) in m.iter_mut().take(3).enumerate() {
                    row[i] = -2.5
                }
            },
            "positive",
        ),
        (
            "zero",
            |m| {
                for (i, row) in m.iter_mut().take(3).enumerate() {
                    row[i] = 0.0
                }
            },
            "positive",
        ),
        ("projective", |m| m[3][2] = 0.1, "last row"),
        ("far", |m| m[0][3] = 1e300, "out of range"),
    ];
    for (what, spoil, says) in cases {
        let mut m = good;
        spoil(&mut m);
        let e = scale_of(&m).unwrap_err();
        assert!(e.contains(says), "{what}: {e}");
    }
    let mut m = good;
    m[2][3] = f64::NAN;
    assert!(scale_of(&m).unwrap_err().contains("non-finite"));
}

/// NeuS's pixel of a world point: `P · X`, divided through. Its pixel
/// centres are whole numbers.
fn neus_pixel(p: &[[f64; 4]; 3], x: DVec3) -> (f64, f64) {
    let h = [x.x, x.y, x.z, 1.0];
    let row = |i: usize| (0..4).map(|n| p[i][n] * h[n]).sum::<f64>();
    let w = row(2);
    (row(0) / w, row(1) / w)
}

#[test]
fn the_ray_through_neus_pixel_position_passes_through_the_point() {
    // NeuS casts pixel (i, j)'s ray through K⁻¹(i, j, 1); sdfl's pixel
    // (i, j) is at OpenCV (i + ½, j + ½). With the reader's +½ on the
    // principal point, sdfl's ray through pixel position (u, v) (the
    // NeuS pixel P·X lands on) passes through X. Two lenses: an
    // off-centre one (sdfl keeps pixel intrinsics) and one whose
    // NeuS principal point is (W−1)/2, (H−1)/2 (centred once moved by
    // ½: sdfl's NDC pinhole with half-pixel centres).
    let (w, h) = (64u32, 48u32);
    let c = DVec3::new(120.0, -40.0, 650.0);
    let s = 210.0;
    let frame = SceneFrame::new(1.0 / s, c, DMat3::IDENTITY);
    let mut rng = Rng(11);
    for k in [[70.0, 0.0, 30.2, 72.5, 21.7], [60.0, 0.0, 31.5, 60.0, 23.5]] {
        for _ in 0..50 {
            let r = rng.rotation();
            // A camera in the world ~3 sphere radii from the centre,
            // looking near it.
            let eye = c + r.row(2) * (-3.0 * s);
            let t = -(r * eye);
            let p = projection(k, r, t);
            let d = decompose(&p).unwrap();
            let intrinsics = Intrinsics {
                width: w,
                height: h,
                fx: d.fx,
                fy: d.fy,
                cx: d.cx + 0.5,
                cy: d.cy + 0.5,
                distortion: Distortion::None,
            };
            let cam = camera_of(&frame.pose_to_scene(&d.opengl_c2w()), &intrinsics).unwrap();
            let centred = k[2] == (w as f64 - 1.0) / 2.0;
            assert_eq!(
                cam.lens == sdfl_stdlib::camera::Lens::Ndc,
                centred,
                "{:?}",
                cam.lens
            );
            for _ in 0..10 {
                // A world point inside the sphere that lands in the image.
                let x = c + DVec3::new(
                    rng.range(-0.5, 0.5),
                    rng.range(-0.5, 0.5),
                    rng.range(-0.5, 0.5),
                ) * s;
                let (u, v) = neus_pixel(&p, x);
                let ray = cam.pixel_direction(u, v, w, h);
                let to = frame.to_scene(x) - cam.eye;
                let off = ray.cross(to).length() / to.length();
                assert!(off < 1e-9, "{off} at ({u}, {v})");
                // Without the half-pixel move, it misses by ~½ px.
                let wrong = Intrinsics {
                    cx: d.cx,
                    cy: d.cy,
                    ..intrinsics
                };
                let cam2 = camera_of(&frame.pose_to_scene(&d.opengl_c2w()), &wrong).unwrap();
                let off2 = cam2.pixel_direction(u, v, w, h).cross(to).length() / to.length();
                assert!(off2 > 0.3 / k[0], "{off2}");
            }
        }
    }
}

#[test]
fn world_mat_keys_are_counted_exactly() {
    assert!(is_world_mat("world_mat_0") && is_world_mat("world_mat_48"));
    for k in [
        "world_mat_inv_0",
        "world_mat_",
        "world_mat_1a",
        "scale_mat_0",
        "camera_mat_0",
    ] {
        assert!(!is_world_mat(k), "{k}");
    }
}
