//! Cameras end to end: square pixels on non-square images, and renders
//! through a real lens (`lens(...)`) landing where the lens's own forward
//! model puts them.

use sdfl_lang::SourceFile;
use sdfl_runtime::output::WrittenKind;
use sdfl_runtime::{run_job, RunOptions};

/// Renders the one `render` statement of `text` and returns its first
/// mask (true = hit), with the image size.
fn mask_of(name: &str, text: &str) -> (u32, u32, Vec<bool>) {
    let src = SourceFile::new(format!("{name}.sdfl"), text.to_string());
    let program = sdfl_stdlib::load(&src)
        .unwrap_or_else(|d| panic!("{}", sdfl_lang::render(&src, &d, false)));
    let out = std::env::temp_dir().join(format!("sdfl-cameras-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).unwrap();
    let job = &program.renders[0];
    let report = run_job(
        job,
        &out,
        RunOptions {
            size: None,
            no_cull: false,
            restart: false,
        },
        &|_| {},
    )
    .unwrap();
    let mask = report
        .written
        .iter()
        .find(|w| w.kind == WrittenKind::Mask)
        .unwrap();
    let img = image::open(out.join(&mask.path)).unwrap().to_luma8();
    let _ = std::fs::remove_dir_all(&out);
    let (w, h) = img.dimensions();
    (w, h, img.pixels().map(|p| p[0] > 127).collect())
}

/// The hit pixels' bounding box (width, height) and centroid.
fn blob(w: u32, mask: &[bool]) -> ((u32, u32), (f64, f64)) {
    let (mut x0, mut x1, mut y0, mut y1) = (u32::MAX, 0, u32::MAX, 0);
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
    for (k, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let (x, y) = (k as u32 % w, k as u32 / w);
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
        sx += x as f64 + 0.5;
        sy += y as f64 + 0.5;
        n += 1.0;
    }
    assert!(n > 0.0, "nothing hit");
    ((x1 - x0 + 1, y1 - y0 + 1), (sx / n, sy / n))
}

/// The report: a sphere on a 160×80 image rendered as a 26×14 px
/// ellipse. With square pixels it is round.
#[test]
fn a_sphere_on_a_wide_image_is_round() {
    for size in ["[160, 80]", "[60, 150]"] {
        let (w, _, m) = mask_of(
            "wide",
            &format!(
                "render wide {{ scene: sphere(0.5), camera: look_at(eye: [0, 0, -3]), size: {size}, outputs: [mask(\"m.png\")] }}"
            ),
        );
        let ((bw, bh), _) = blob(w, &m);
        assert!(bw.abs_diff(bh) <= 1, "{size}: {bw}x{bh} px");
    }
}

/// A small sphere seen through an off-centre, distorted lens lands where
/// the OpenCV model projects its centre (within a pixel: the blob's
/// centroid is not exactly the centre's image), and not where a pinhole
/// with the same focal lengths would put it.
#[test]
fn renders_through_a_lens_follow_its_forward_model() {
    let (k1, k2, p1, p2) = (-0.3, 0.05, 0.001, -0.0015);
    let (fx, fy, cx, cy) = (140.0, 138.0, 83.2, 57.9);
    let (w, _, m) = mask_of(
        "lens",
        &format!(
            "render lens {{ scene: sphere(0.06, center: [-1.3, 0.75, 0]), camera: lens(look_at(eye: [0, 0, -3]), size: [160, 120], focal: [{fx}, {fy}], center: [{cx}, {cy}], model: \"opencv\", distortion: [{k1}, {k2}, {p1}, {p2}]), size: [160, 120], outputs: [mask(\"m.png\")] }}"
        ),
    );
    let (_, (u, v)) = blob(w, &m);
    // The camera at -3z looks along +z with up +y, so its right (OpenCV
    // x) is world -x and its down (OpenCV y) world -y.
    let (x, y, z) = (1.3, -0.75, 3.0);
    let (xn, yn) = (x / z, y / z);
    let r2: f64 = xn * xn + yn * yn;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
    let xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn);
    let yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn;
    let (ue, ve) = (fx * xd + cx, fy * yd + cy);
    let (up, vp) = (fx * xn + cx, fy * yn + cy);
    assert!(
        (u - ue).abs() < 1.0 && (v - ve).abs() < 1.0,
        "({u}, {v}) against ({ue}, {ve})"
    );
    assert!(
        (up - ue).hypot(vp - ve) > 3.0,
        "the distortion must move the sphere visibly"
    );
}

/// nerfstudio's `camera_path.json` as cameras: each frame renders, looking
/// where its `camera_to_world` looks; a missing file is a diagnostic at the
/// argument.
#[test]
fn a_nerfstudio_camera_path_gives_the_cameras() {
    let dir = std::env::temp_dir().join(format!("sdfl-camera-path-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    // Three cameras on a circle of radius 3 about the origin, looking at it
    // (OpenGL: the camera looks down its −z, so +z points back at the eye).
    let frames: Vec<serde_json::Value> = (0..3)
        .map(|k| {
            let a = k as f64 * 2.0;
            let (eye, back) = ([3.0 * a.sin(), 0.0, 3.0 * a.cos()], [a.sin(), 0.0, a.cos()]);
            let right = [back[2], 0.0, -back[0]];
            let m = [
                right[0], 0.0, back[0], eye[0], right[1], 1.0, back[1], eye[1], right[2], 0.0,
                back[2], eye[2], 0.0, 0.0, 0.0, 1.0,
            ];
            serde_json::json!({ "camera_to_world": m, "fov": 40.0, "aspect": 1.0 })
        })
        .collect();
    let doc = serde_json::json!({
        "camera_type": "perspective", "render_width": 32, "render_height": 24,
        "fps": 24, "seconds": 1, "camera_path": frames,
    });
    std::fs::write(dir.join("cp.json"), doc.to_string()).unwrap();
    std::fs::write(
        dir.join("path.sdfl"),
        "render p { scene: sphere(0.5), camera: camera_path(\"cp.json\"), size: [32, 24], outputs: [mask(\"m.png\")] }\n",
    )
    .unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(["run", "path.sdfl", "--out", "out"])
        .current_dir(&dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for k in 0..3 {
        let img = image::open(dir.join(format!("out/m_{k:02}.png")))
            .unwrap()
            .to_luma8();
        let mask: Vec<bool> = img.pixels().map(|p| p[0] > 127).collect();
        let (_, (u, v)) = blob(32, &mask);
        // The sphere at the centre of every view.
        assert!(
            (u - 16.0).abs() < 1.0 && (v - 12.0).abs() < 1.0,
            "view {k}: ({u}, {v})"
        );
    }
    std::fs::remove_file(dir.join("cp.json")).unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(["check", "path.sdfl"])
        .current_dir(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("sdfl::io") && err.contains("cp.json"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
