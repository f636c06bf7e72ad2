use glam::DVec3;
use sdfl_stdlib::camera::*;

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
            let (c2w, k) = cam.to_opengl_intrinsics(w, h);
            let back = Camera::from_opengl_intrinsics(&c2w, k).unwrap();
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
    let (m, k) = cam.to_opengl_intrinsics(w, h);
    let col = |c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
    for p in [DVec3::new(0.3, -0.2, 0.5), DVec3::new(-0.4, 0.6, 0.0)] {
        // OpenGL: camera coordinates, looking down −z; pixel centres at
        // i + ½ with rows going down.
        let d = p - col(3);
        let (xc, yc, zc) = (d.dot(col(0)), d.dot(col(1)), d.dot(col(2)));
        let u = w as f64 / 2.0 + k.fx * xc / -zc;
        let v = h as f64 / 2.0 - k.fy * yc / -zc;
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
    let good = Camera::look_at(DVec3::new(0.0, 0.0, -3.0), DVec3::ZERO, DVec3::Y, 1.0)
        .to_opengl_intrinsics(8, 8);
    let mut nan = good;
    nan.0[0][1] = f64::NAN;
    let mut scaled = good;
    for r in 0..3 {
        scaled.0[r][0] *= 2.0;
    }
    let mut mirrored = good;
    for r in 0..3 {
        mirrored.0[r][0] *= -1.0;
    }
    let mut negative = good;
    negative.1.fy = -negative.1.fy;
    for (c2w, k) in [nan, scaled, mirrored, negative] {
        assert!(Camera::from_opengl_intrinsics(&c2w, k).is_err());
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

/// Non-square images have square pixels (CONVENTIONS.md): neighbouring
/// pixels are the same angle apart across and down at the centre, the
/// shorter side spans [-1, 1], and square images keep the formula.
#[test]
fn non_square_images_have_square_pixels() {
    for centers in [PixelCenters::Corners, PixelCenters::Half] {
        let cam = Camera::look_at(DVec3::new(0.0, 0.0, -3.0), DVec3::ZERO, DVec3::Y, 1.3)
            .with_pixel_centers(centers);
        for (w, h) in [(160, 80), (81, 161), (64, 64)] {
            let (x0, y0) = cam.pixel_ndc(w / 2, h / 2, w, h);
            let (x1, _) = cam.pixel_ndc(w / 2 + 1, h / 2, w, h);
            let (_, y1) = cam.pixel_ndc(w / 2, h / 2 + 1, w, h);
            assert!(((x0 - x1) - (y0 - y1)).abs() < 1e-12, "{centers:?} {w}x{h}");
            // The shorter side's outer pixels at ±1 (corners) or half a
            // pixel inside (half centres).
            let short_end = if w <= h {
                cam.pixel_ndc(0, h / 2, w, h).0
            } else {
                cam.pixel_ndc(w / 2, 0, w, h).1
            };
            let want = match centers {
                PixelCenters::Corners => 1.0,
                PixelCenters::Half => 1.0 - 1.0 / w.min(h) as f64,
            };
            assert!(
                (short_end - want).abs() < 1e-12,
                "{centers:?} {w}x{h}: {short_end}"
            );
        }
        assert_eq!(
            cam.pixel_ndc(0, 0, 64, 64),
            cam.pixel_ndc_at(0.0, 0.0, 64, 64)
        );
    }
    assert_eq!(pixel_ndc(0, 0, 256, 256), (1.0, 1.0));
    let (x, y) = pixel_ndc(0, 0, 160, 80);
    assert!((x - 159.0 / 79.0).abs() < 1e-12 && y == 1.0);
}

fn capture_lens() -> Intrinsics {
    Intrinsics {
        width: 96,
        height: 64,
        fx: 80.0,
        fy: 78.5,
        cx: 50.3,
        cy: 30.1,
        distortion: Distortion::OpenCv {
            k1: -0.08,
            k2: 0.01,
            p1: 0.002,
            p2: -0.001,
        },
    }
}

/// The ray through each pixel of a distorted, off-centre camera meets
/// points that the camera's own forward model (OpenCV, from the pose)
/// projects back onto that pixel, within 1e-4 px; at half the size the
/// same holds with the intrinsics scaled.
#[test]
fn lens_rays_project_back_to_their_pixels() {
    let pose = Camera::look_at(
        DVec3::new(1.0, 0.7, -2.5),
        DVec3::new(0.1, 0.0, 0.2),
        DVec3::Y,
        1.0,
    )
    .to_opengl_intrinsics(8, 8)
    .0;
    let k = capture_lens();
    let cam = Camera::from_opengl_intrinsics(&pose, k).unwrap();
    assert!(matches!(cam.lens, Lens::Pixels(_)) && !cam.is_rectilinear());
    let col = |c: usize| DVec3::new(pose[0][c], pose[1][c], pose[2][c]);
    for (w, h) in [(96, 64), (48, 32)] {
        let ks = k.scaled(w, h);
        let mut worst: f64 = 0.0;
        for j in 0..h {
            for i in 0..w {
                let d = cam.pixel_direction(i as f64, j as f64, w, h);
                let p = cam.eye + d * 3.7;
                // OpenCV camera space: x right, y down, z forward.
                let q = p - col(3);
                let pc = [q.dot(col(0)), -q.dot(col(1)), -q.dot(col(2))];
                let (u, v) = ks.project(pc).unwrap();
                worst = worst.max(
                    (u - (i as f64 + 0.5))
                        .abs()
                        .max((v - (j as f64 + 0.5)).abs()),
                );
            }
        }
        assert!(worst < 1e-4, "{w}x{h}: {worst:e} px");
    }
    // And back: the pose and intrinsics written are the ones read.
    let (c2w, k2) = cam.to_opengl_intrinsics(96, 64);
    assert_eq!(k2, k);
    for r in 0..4 {
        for c in 0..4 {
            assert!((c2w[r][c] - pose[r][c]).abs() < 1e-12);
        }
    }
}

/// A centred pinhole with square pixels stays the conventions' camera;
/// an off-centre or non-square-pixel pinhole keeps its intrinsics and
/// still casts rectilinear rays through the tiles' rectangles.
#[test]
fn pinholes_pick_their_lens() {
    let pose = Camera::look_at(DVec3::new(0.0, 0.0, -3.0), DVec3::ZERO, DVec3::Y, 1.0)
        .to_opengl_intrinsics(8, 8)
        .0;
    let centred =
        Camera::from_opengl_intrinsics(&pose, Intrinsics::centred(40, 30, 35.0, 35.0)).unwrap();
    assert_eq!(centred.lens, Lens::Ndc);
    assert_eq!(centred.pixel_centers, PixelCenters::Half);
    let off = Intrinsics {
        cx: 22.0,
        ..Intrinsics::centred(40, 30, 35.0, 34.0)
    };
    let cam = Camera::from_opengl_intrinsics(&pose, off).unwrap();
    assert!(cam.is_rectilinear() && matches!(cam.lens, Lens::Pixels(_)));
    // The rectangle of a block of pixels holds each of its rays.
    let ((x0, x1), (y0, y1)) = cam.tangent_bounds((3.5, 4.5), (11.5, 12.5), 40, 30);
    for (i, j) in [(4.0, 5.0), (11.0, 12.0), (7.3, 9.9)] {
        let (tx, ty) = cam.tangent_at(i, j, 40, 30);
        assert!(tx >= x0.min(x1) && tx <= x0.max(x1) && ty >= y0.min(y1) && ty <= y0.max(y1));
    }
    // A distorted lens's rectangle also holds its rays.
    let bent = Camera::from_opengl_intrinsics(&pose, capture_lens()).unwrap();
    let ((x0, x1), (y0, y1)) = bent.tangent_bounds((-0.5, -0.5), (7.5, 7.5), 96, 64);
    for a in 0..=16 {
        for b in 0..=16 {
            let (tx, ty) = bent.tangent_at(-0.5 + a as f64 / 2.0, -0.5 + b as f64 / 2.0, 96, 64);
            assert!(tx >= x0.min(x1) && tx <= x0.max(x1) && ty >= y0.min(y1) && ty <= y0.max(y1));
        }
    }
}
