//! The assignment's figures: grids, rays, sample points, transmittances.

use glam::DVec3;
use sdfl_runtime::volume::figures::*;
use sdfl_runtime::volume::rays::Stratified;
use sdfl_stdlib::camera::Camera;

fn pixel(img: &[u8], w: u32, i: u32, j: u32) -> [u8; 3] {
    let k = (j * w + i) as usize * 3;
    [img[k], img[k + 1], img[k + 2]]
}

fn colours(img: &[u8]) -> std::collections::HashSet<[u8; 3]> {
    img.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect()
}

#[test]
fn xy_grid_corners() {
    let img = xy_grid_image(64, 48);
    assert_eq!(img.len(), 64 * 48 * 3);
    assert_eq!(pixel(&img, 64, 0, 0), [255, 255, 0]);
    assert_eq!(pixel(&img, 64, 63, 47), [0, 0, 0]);
    // Top-right: x_ndc = -1, y_ndc = 1 → green; bottom-left red.
    assert_eq!(pixel(&img, 64, 63, 0), [0, 255, 0]);
    assert_eq!(pixel(&img, 64, 0, 47), [255, 0, 0]);
    assert!(xy_grid_image(0, 5).is_empty());
    assert_eq!(xy_grid_image(1, 1), vec![127, 127, 0]);
}

#[test]
fn rays_image_matches_hand_computation() {
    // Eye on -x looking at the origin, up +y: z = (1,0,0),
    // x = cross(y, z) = (0,0,-1), y = (0,1,0). Pixels are square, so on
    // a 5×3 image the top-left pixel is at NDC (2, 1) (the 3-pixel side
    // spans ±1). With f = 2 it looks along x + y/2 + z = (1, 0.5, -1),
    // whose unit vector is (2/3, 1/3, 2/3) → (170, 85, 170).
    let cam = Camera::look_at(DVec3::new(-2.5, 0.0, 0.0), DVec3::ZERO, DVec3::Y, 2.0);
    let img = rays_image(&cam, 5, 3);
    assert_eq!(img.len(), 5 * 3 * 3);
    assert_eq!(pixel(&img, 5, 0, 0), [170, 85, 170]);
    // A square image's corner keeps the conventions' NDC (1, 1):
    // x/2 + y/2 + z = (1, 0.5, -0.5) → (208, 104, 104).
    assert_eq!(pixel(&rays_image(&cam, 3, 3), 3, 0, 0), [208, 104, 104]);
    // The centre pixel looks straight at the target, along +x.
    assert_eq!(pixel(&img, 5, 2, 1), [255, 0, 0]);
    let bad = Camera::look_at(DVec3::ZERO, DVec3::ZERO, DVec3::Y, 1.0);
    assert_eq!(rays_image(&bad, 4, 4), vec![0; 48]);
    assert!(rays_image(&cam, 0, 4).is_empty());
}

fn nerf_cam() -> Camera {
    Camera::look_at(DVec3::new(0.0, 4.0, 2.0), DVec3::ZERO, DVec3::Z, 2.0)
}

/// Pixels that are not white.
fn inked(img: &[u8]) -> usize {
    img.chunks_exact(3)
        .filter(|p| p != &[255, 255, 255])
        .count()
}

#[test]
fn sample_points_show_near_and_far() {
    let s = Stratified::new(32, 2.0, 6.0).unwrap();
    let img = sample_points_image(&nerf_cam(), &s, 32, 32, 8, 400, 300);
    assert_eq!(img.len(), 400 * 300 * 3);
    let cs = colours(&img);
    let (near, far) = (depth_colour(2.0, 2.0, 6.0), depth_colour(6.0, 2.0, 6.0));
    assert_ne!(near, far);
    assert!(cs.contains(&near) && cs.contains(&far), "{cs:?}");
    let eye = [EYE.0, EYE.1, EYE.2];
    assert!(cs.contains(&eye), "the eye is drawn");
    // Every depth colour is there, not only the legend's two.
    for t in s.depths() {
        assert!(cs.contains(&depth_colour(t as f64, 2.0, 6.0)), "t = {t}");
    }
}

#[test]
fn sample_points_of_a_camera_looking_down_an_axis() {
    // The camera's forward along a chart axis is the case where a turn
    // of the chart is needed to see the depths apart.
    let cam = Camera::look_at(DVec3::new(0.0, 0.0, 4.0), DVec3::ZERO, DVec3::Y, 1.0);
    let s = Stratified::new(64, 1.0, 7.0).unwrap();
    let img = sample_points_image(&cam, &s, 3, 3, 1, 400, 400);
    let cs = colours(&img);
    for t in s.depths() {
        assert!(cs.contains(&depth_colour(t as f64, 1.0, 7.0)), "t = {t}");
    }
}

#[test]
fn sample_points_edge_cases() {
    let s = Stratified::new(16, 0.0, 5.0).unwrap();
    let cam = nerf_cam();
    for stride in [0, 1, 3, u32::MAX] {
        let img = sample_points_image(&cam, &s, 20, 10, stride, 256, 256);
        assert_eq!(img.len(), 256 * 256 * 3);
        assert!(inked(&img) > 1000, "stride {stride}");
    }
    // Stride 1 on a large image is thinned, not slow or huge.
    let big = Stratified::new(128, 2.0, 6.0).unwrap();
    let img = sample_points_image(&cam, &big, 1024, 1024, 1, 256, 256);
    assert_eq!(img.len(), 256 * 256 * 3);
    // Too small for a chart: white, of the right size.
    for (w, h) in [(0, 40), (1, 1), (64, 40), (199, 400)] {
        let img = sample_points_image(&cam, &s, 20, 10, 1, w, h);
        assert_eq!(img.len(), (w * h * 3) as usize);
        assert_eq!(inked(&img), 0, "{w}×{h}");
    }
    assert!(inked(&sample_points_image(&cam, &s, 0, 0, 1, 256, 256)) > 0);
    let bad = Camera::look_at(DVec3::ZERO, DVec3::ZERO, DVec3::Y, 1.0);
    assert_eq!(inked(&sample_points_image(&bad, &s, 8, 8, 1, 256, 256)), 0);
    let invalid = Stratified {
        n: 1,
        near: 3.0,
        far: 1.0,
    };
    let img = sample_points_image(&cam, &invalid, 8, 8, 1, 256, 256);
    assert!(inked(&img) > 0, "the frustum to depth 1");
    // Extreme depths stay finite work.
    let huge = Stratified::new(8, 0.0, 3e38).unwrap();
    let img = sample_points_image(&cam, &huge, 8, 8, 1, 256, 256);
    assert_eq!(img.len(), 256 * 256 * 3);
}

#[test]
fn transmittance_values_match_assignment() {
    let (img, t) = transmittance_figure(480, 320);
    assert_eq!(img.len(), 480 * 320 * 3);
    let want = [-2.0f64, -30.5, -32.5, -2.5].map(f64::exp);
    for (got, want) in t.iter().zip(want) {
        assert!(((got - want) / want).abs() < 1e-3, "{got} vs {want}");
    }
    let cs = colours(&img);
    assert!(cs.contains(&[200, 30, 30]), "the curve is drawn");
    assert!(cs.len() > 5, "bands, axes and curve");
    for (w, h) in [(0, 0), (1, 1), (10, 7), (2000, 40)] {
        let (img, v) = transmittance_figure(w, h);
        assert_eq!(img.len(), (w * h * 3) as usize);
        assert_eq!(v, t);
    }
}

/// Writes the figures as PNGs for a look: `SDFL_WRITE_FIGURES=1 cargo test -p sdfl-runtime
/// figures`; they land in `$TMPDIR/sdfl-figures`.
#[test]
fn write_figures_for_inspection() {
    if std::env::var_os("SDFL_WRITE_FIGURES").is_none() {
        return;
    }
    use sdfl_runtime::output::write_png;
    let dir = std::env::temp_dir().join("sdfl-figures");
    let cam = Camera::look_at(DVec3::new(-1.0, 0.0, -2.2), DVec3::ZERO, DVec3::Y, 1.0);
    write_png(&dir.join("xy_grid.png"), 256, 256, &xy_grid_image(256, 256)).unwrap();
    write_png(&dir.join("rays.png"), 256, 256, &rays_image(&cam, 256, 256)).unwrap();
    let s = Stratified::new(64, 0.0, 5.0).unwrap();
    let img = sample_points_image(&cam, &s, 256, 256, 32, 512, 512);
    write_png(&dir.join("sample_points.png"), 512, 512, &img).unwrap();
    let s = Stratified::new(128, 2.0, 6.0).unwrap();
    let img = sample_points_image(&nerf_cam(), &s, 128, 128, 16, 400, 300);
    write_png(&dir.join("sample_points_nerf.png"), 400, 300, &img).unwrap();
    let (img, _) = transmittance_figure(640, 400);
    write_png(&dir.join("transmittance.png"), 640, 400, &img).unwrap();
    eprintln!("figures in {}", dir.display());
}
