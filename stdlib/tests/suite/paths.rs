use glam::DVec3;
use sdfl_stdlib::builtins::paths::*;
use sdfl_stdlib::camera::Camera;

/// Cameras on a tilted, uneven ring around `focus`, looking at it.
fn ring(n: usize, focus: DVec3) -> Vec<Camera> {
    (0..n)
        .map(|k| {
            let a = k as f64 / n as f64 * std::f64::consts::TAU + 0.3 * (k as f64).sin();
            let r = 3.0 + 0.4 * (2.0 * a).cos();
            let eye = focus + DVec3::new(r * a.cos(), 1.0 + 0.5 * (3.0 * a).sin(), r * a.sin());
            Camera::look_at(eye, focus, DVec3::Y, 1.5)
        })
        .collect()
}

#[test]
fn the_focus_is_where_the_axes_meet() {
    let f = DVec3::new(0.3, -0.2, 0.5);
    let cams = ring(7, f);
    assert!((common_focus(&cams) - f).length() < 1e-5);
    // Parallel axes still give a finite point.
    let par: Vec<Camera> = (0..3)
        .map(|k| {
            Camera::look_at(
                DVec3::new(k as f64, 0.0, 0.0),
                DVec3::new(k as f64, 0.0, -1.0),
                DVec3::Y,
                1.0,
            )
        })
        .collect();
    assert!(common_focus(&par).is_finite());
}

#[test]
fn a_loop_passes_through_its_cameras_and_is_smooth() {
    let f = DVec3::new(0.3, -0.2, 0.5);
    // Shuffled: the loop orders them by azimuth.
    let mut cams = ring(6, f);
    cams.swap(0, 3);
    cams.swap(1, 5);
    let frames = 6 * 20;
    let path = camera_loop(&cams, frames, 8).unwrap();
    assert_eq!(path.len(), frames);
    // Every 20th frame is a camera.
    for c in &cams {
        let nearest = path
            .iter()
            .map(|p| (p.eye - c.eye).length())
            .fold(f64::INFINITY, f64::min);
        assert!(nearest < 1e-9, "{} misses {}", nearest, c.eye);
    }
    // Every frame looks at the focus.
    for p in &path {
        assert!((p.at - f).length() < 1e-5);
        assert!((p.focal - 1.5).abs() < 1e-12);
    }
    // Smooth: steps of similar length, turning little between frames
    // (the closed loop included: the last frame leads to the first).
    let step = |k: usize| path[(k + 1) % frames].eye - path[k].eye;
    let lengths: Vec<f64> = (0..frames).map(|k| step(k).length()).collect();
    let mean = lengths.iter().sum::<f64>() / frames as f64;
    assert!(
        lengths.iter().all(|l| *l < 2.0 * mean && *l > 0.3 * mean),
        "{lengths:?}"
    );
    for k in 0..frames {
        let (a, b) = (step(k).normalize(), step((k + 1) % frames).normalize());
        assert!(a.dot(b) > 0.9, "frame {k} turns by {}", a.dot(b).acos());
    }
}

#[test]
fn keyframes_average_sectors_at_the_cameras_distance() {
    // A hemisphere of views at many elevations: 4 keyframes go round at
    // their mean distance, never inside it.
    let cams: Vec<Camera> = (0..40)
        .map(|k| {
            let a = k as f64 * 2.399;
            let el = 0.1 + 1.2 * (k as f64 / 40.0);
            let eye = DVec3::new(el.cos() * a.cos(), el.sin(), el.cos() * a.sin()) * 3.5;
            Camera::look_at(eye, DVec3::ZERO, DVec3::Y, 2.4)
        })
        .collect();
    let (controls, focus, up) = loop_controls(&cams, 4);
    assert_eq!(controls.len(), 4);
    assert!(focus.length() < 1e-3, "{focus}");
    assert!((up - DVec3::Y).length() < 1e-9);
    for c in &controls {
        assert!((c.length() - 3.5).abs() < 1e-6);
        assert!(c.y > 0.0, "above the equator: {c}");
    }
    let path = camera_loop(&cams, 30, 4).unwrap();
    assert!(path.iter().all(|p| p.eye.y > 0.0 && p.is_valid()));
}

#[test]
fn the_training_path_goes_through_every_camera_in_the_data_order() {
    let f = DVec3::new(0.3, -0.2, 0.5);
    // Out of azimuth order on purpose: the path keeps the data's.
    let mut cams = ring(5, f);
    cams.swap(1, 3);
    cams[2].focal = 2.5;
    let per = 12;
    let frames = (cams.len() - 1) * per + 1;
    let path = training_path(&cams, frames).unwrap();
    assert_eq!(path.len(), frames);
    for (i, c) in cams.iter().enumerate() {
        let p = path[i * per];
        assert!(
            (p.eye - c.eye).length() < 1e-9,
            "camera {i}: {} vs {}",
            p.eye,
            c.eye
        );
        let ((px, py, pz), (cx, cy, cz)) = (p.axes(), c.axes());
        assert!(
            (px - cx).length() < 1e-9 && (py - cy).length() < 1e-9 && (pz - cz).length() < 1e-9,
            "camera {i} turned"
        );
        assert!((p.focal - c.focal).abs() < 1e-12);
        assert!(p.is_valid());
    }
    // Halfway between two cameras, the orientation is the slerp's
    // midpoint: half the turn from one to the other, on the way.
    let (a, b) = (orientation(&cams[0]), orientation(&cams[1]));
    let mid = orientation(&path[per / 2]);
    let (ab, am, mb) = (
        a.angle_between(b),
        a.angle_between(mid),
        mid.angle_between(b),
    );
    assert!(ab > 0.1, "the cameras turn: {ab}");
    assert!(
        (am - ab / 2.0).abs() < 1e-9 && (mb - ab / 2.0).abs() < 1e-9,
        "{am} {mb} of {ab}"
    );
    assert!((path[per / 2].focal - (cams[0].focal + cams[1].focal) / 2.0).abs() < 1e-12);
    // Smooth: no corner where the spline passes a camera (consecutive
    // steps turn little), and the forward axis changes gradually.
    let step = |k: usize| path[k + 1].eye - path[k].eye;
    for k in 0..frames - 2 {
        let (s, t) = (step(k), step(k + 1));
        assert!(
            s.normalize().dot(t.normalize()) > 0.8,
            "frame {k} turns by {}",
            s.normalize().dot(t.normalize()).acos()
        );
        let (z0, z1) = (path[k].axes().2, path[k + 1].axes().2);
        assert!(z0.dot(z1) > 0.95, "frame {k}");
    }
}

#[test]
fn a_training_path_of_few_cameras_or_frames() {
    let cams = ring(3, DVec3::ZERO);
    let one = training_path(&cams, 1).unwrap();
    assert_eq!(one.len(), 1);
    assert!((one[0].eye - cams[0].eye).length() < 1e-9);
    let two = training_path(&cams, 2).unwrap();
    assert!((two[1].eye - cams[2].eye).length() < 1e-9);
    let alone = training_path(&cams[..1], 4).unwrap();
    assert!(alone
        .iter()
        .all(|c| (c.eye - cams[0].eye).length() < 1e-12 && c.is_valid()));
    assert!(training_path(&[], 4).is_err());
    // Two cameras at one place looking opposite ways: the path turns
    // on the spot, never through a degenerate orientation.
    let here = DVec3::new(1.0, 2.0, 3.0);
    let back = [
        Camera::look_at(here, here + DVec3::Z, DVec3::Y, 1.0),
        Camera::look_at(here, here - DVec3::Z, DVec3::Y, 1.0),
    ];
    for c in training_path(&back, 9).unwrap() {
        assert!(c.is_valid() && (c.eye - here).length() < 1e-6, "{c:?}");
    }
}

#[test]
fn degenerate_cameras_are_refused_or_handled() {
    assert!(camera_loop(&[], 10, 8).is_err());
    let one = [Camera::look_at(
        DVec3::new(0.0, 0.0, 3.0),
        DVec3::ZERO,
        DVec3::Y,
        1.0,
    )];
    let path = camera_loop(&one, 5, 8).unwrap();
    assert!(path.iter().all(|p| (p.eye - one[0].eye).length() < 1e-9));
    // Cameras looking straight down the up axis still get an up vector.
    let down: Vec<Camera> = (0..3)
        .map(|k| {
            Camera::look_at(
                DVec3::new(0.01 * k as f64, 3.0, 0.0),
                DVec3::ZERO,
                DVec3::Z,
                1.0,
            )
        })
        .collect();
    for p in camera_loop(&down, 9, 8).unwrap() {
        assert!(p.is_valid());
    }
}
