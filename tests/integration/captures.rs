//! Real captures in: nerfstudio's `transforms.json`, COLMAP's text model
//! and LLFF's `poses_bounds.npy`, written here as small fixtures, read by
//! `capture(...)`'s readers and by the CLI.

use std::fs;
use std::path::{Path, PathBuf};

use crate::common::{assert_outcome, case_dir, head, run_into, sdfl, Expect};
use glam::{DMat3, DQuat, DVec3};
use sdfl_runtime::data::capture::{self, Distortion, Intrinsics};
use sdfl_runtime::data::nerfstudio::read_transforms_scaled;
use sdfl_runtime::data::normalize::SceneFrame;
use sdfl_stdlib::value::CaptureSpec;
use serde_json::{json, Value};

/// An OpenGL camera-to-world pose at `eye` looking at `at` (+y of the
/// camera towards `up`).
fn gl_pose(eye: DVec3, at: DVec3, up: DVec3) -> [[f64; 4]; 4] {
    let back = (eye - at).normalize();
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

fn pose_json(m: &[[f64; 4]; 4]) -> Value {
    json!(m.iter().map(|r| r.to_vec()).collect::<Vec<_>>())
}

fn png(path: &Path, w: u32, h: u32) {
    fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::RgbImage::from_fn(w, h, |i, j| {
        image::Rgb([(i * 20) as u8, (j * 20) as u8, 90])
    })
    .save(path)
    .unwrap();
}

/// Eyes on a ring of radius 4 about (10, −3, 5), height varying, all
/// looking at that centre: an arbitrary world frame.
fn ring(n: usize) -> Vec<[[f64; 4]; 4]> {
    let c = DVec3::new(10.0, -3.0, 5.0);
    (0..n)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / n as f64;
            gl_pose(
                c + DVec3::new(4.0 * a.cos(), 1.0 + 0.3 * k as f64, 4.0 * a.sin()),
                c,
                DVec3::Y,
            )
        })
        .collect()
}

/// A nerfstudio capture in `dir`: `frames` (each with its `file_path`
/// image written at `size`) and the top-level keys `top`.
fn nerfstudio(dir: &Path, top: Value, frames: Vec<Value>, size: (u32, u32)) {
    for f in &frames {
        png(&dir.join(f["file_path"].as_str().unwrap()), size.0, size.1);
    }
    let mut root = top;
    root["frames"] = json!(frames);
    fs::write(
        dir.join("transforms.json"),
        serde_json::to_string_pretty(&root).unwrap(),
    )
    .unwrap();
}

fn frame(k: usize, pose: &[[f64; 4]; 4]) -> Value {
    json!({"file_path": format!("images/frame_{k:05}.png"), "transform_matrix": pose_json(pose)})
}

fn spec(path: &Path) -> CaptureSpec {
    CaptureSpec {
        test_every: 0,
        background: Some(DVec3::ONE),
        ..CaptureSpec::at(path)
    }
}

/// The error of `r`, which must fail (without printing what it read).
fn err<T>(r: std::io::Result<T>) -> String {
    match r {
        Ok(_) => panic!("expected an error"),
        Err(e) => e.to_string(),
    }
}

fn eye(c: &sdfl_stdlib::camera::Camera) -> DVec3 {
    c.eye
}

#[test]
fn per_frame_intrinsics_and_split_lists() {
    let dir = case_dir("cap_per_frame");
    let poses = ring(6);
    let frames: Vec<Value> = poses
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let mut f = frame(k, p);
            // Each frame its own focal length; no camera_angle_x anywhere.
            let fl = 10.0 + k as f64;
            f["fl_x"] = json!(fl);
            f["fl_y"] = json!(fl * 8.0 / 12.0 * 1.5);
            f["cx"] = json!(6.0);
            f["cy"] = json!(4.0);
            f["w"] = json!(12);
            f["h"] = json!(8);
            f
        })
        .collect();
    let top = json!({
        "camera_model": "PINHOLE",
        "train_filenames": ["images/frame_00000.png", "images/frame_00001.png", "./images/frame_00002.png", "images/frame_00004.png"],
        "test_filenames": ["images/frame_00003.png"],
    });
    nerfstudio(&dir, top, frames, (12, 8));
    let t = read_transforms_scaled(&dir.join("transforms.json"), 1).unwrap();
    let c = t.capture(1, 8).unwrap();
    // Frame 5 is in no list: dropped. The test list wins over test_every.
    assert_eq!(c.frames.len(), 5);
    assert_eq!(c.test, vec![3]);
    for (f, want) in c.frames.iter().zip([10.0, 11.0, 12.0, 13.0, 14.0]) {
        assert_eq!(f.intrinsics.fx, want, "{}", f.label);
        assert_eq!(f.intrinsics.fy, want * 8.0 / 12.0 * 1.5);
        assert_eq!((f.intrinsics.width, f.intrinsics.height), (12, 8));
    }
    // A name in a list that no frame has is refused, naming it.
    let mut root: Value =
        serde_json::from_str(&fs::read_to_string(dir.join("transforms.json")).unwrap()).unwrap();
    root["test_filenames"] = json!(["images/nope.png"]);
    fs::write(dir.join("other.json"), root.to_string()).unwrap();
    let e = read_transforms_scaled(&dir.join("other.json"), 1)
        .and_then(|t| t.capture(1, 8))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("nope.png") && e.contains("test_filenames"),
        "{e}"
    );
}

#[test]
fn nerf_synthetic_without_camera_angle_x_loads_with_fl_x() {
    let dir = case_dir("cap_synthetic_fl");
    let pose = gl_pose(DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO, DVec3::Y);
    png(&dir.join("r_0.png"), 8, 8);
    fs::write(
        dir.join("transforms_train.json"),
        json!({"fl_x": 10.0, "frames": [{"file_path": "./r_0", "transform_matrix": pose_json(&pose)}]}).to_string(),
    )
    .unwrap();
    let views = sdfl_runtime::data::nerf_synthetic::read_split(&dir, "train", DVec3::ONE).unwrap();
    assert_eq!(views.len(), 1);
    // fl_x = 10 px over 8 px with half-pixel centres: NDC focal 2·10/8.
    assert!(
        (views[0].camera.focal - 2.5).abs() < 1e-12,
        "{:?}",
        views[0].camera
    );
}

#[test]
fn camera_models_are_read_as_written() {
    let dir = case_dir("cap_models");
    let poses = ring(2);
    let f0 = frame(0, &poses[0]);
    let f1 = frame(1, &poses[1]);
    // OPENCV with an off-centre principal point on a non-square image.
    nerfstudio(
        &dir,
        json!({"camera_model": "OPENCV", "fl_x": 20.0, "fl_y": 21.0, "cx": 7.3, "cy": 3.9, "w": 16, "h": 10,
               "k1": -0.1, "k2": 0.02, "p1": 0.001, "p2": -0.002}),
        vec![f0.clone(), f1.clone()],
        (16, 10),
    );
    let c = read_transforms_scaled(&dir.join("transforms.json"), 1)
        .unwrap()
        .capture(1, 0)
        .unwrap();
    let want = Intrinsics {
        width: 16,
        height: 10,
        fx: 20.0,
        fy: 21.0,
        cx: 7.3,
        cy: 3.9,
        distortion: Distortion::OpenCv {
            k1: -0.1,
            k2: 0.02,
            p1: 0.001,
            p2: -0.002,
        },
    };
    assert_eq!(c.frames[0].intrinsics, want);
    assert!(c.test.is_empty());
    // OPENCV_FISHEYE: k1..k4.
    nerfstudio(
        &dir,
        json!({"camera_model": "OPENCV_FISHEYE", "fl_x": 20.0, "fl_y": 20.0, "cx": 8.0, "cy": 5.0, "w": 16, "h": 10,
               "k1": 0.05, "k2": -0.01, "k3": 0.002, "k4": -0.0005}),
        vec![f0.clone(), f1.clone()],
        (16, 10),
    );
    let c = read_transforms_scaled(&dir.join("transforms.json"), 1)
        .unwrap()
        .capture(1, 0)
        .unwrap();
    assert_eq!(
        c.frames[1].intrinsics.distortion,
        Distortion::Fisheye {
            k1: 0.05,
            k2: -0.01,
            k3: 0.002,
            k4: -0.0005
        }
    );
    // Refused: k3 on a perspective camera (not silently dropped), an
    // unknown model, p1 on a fisheye.
    for (top, says) in [
        (
            json!({"camera_model": "OPENCV", "fl_x": 20.0, "k1": 0.1, "k3": 0.01}),
            "`k3`",
        ),
        (
            json!({"camera_model": "EQUIRECTANGULAR", "fl_x": 20.0}),
            "EQUIRECTANGULAR",
        ),
        (
            json!({"camera_model": "OPENCV_FISHEYE", "fl_x": 20.0, "p1": 0.01}),
            "p1",
        ),
    ] {
        nerfstudio(&dir, top, vec![f0.clone(), f1.clone()], (16, 10));
        let e = read_transforms_scaled(&dir.join("transforms.json"), 1)
            .and_then(|t| t.capture(1, 0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(says) && e.contains("transforms.json"),
            "{says}: {e}"
        );
    }
}

#[test]
fn downscaled_folders_scale_the_intrinsics() {
    let dir = case_dir("cap_downscale");
    let poses = ring(3);
    let frames: Vec<Value> = (0..3)
        .map(|k| {
            let mut f = frame(k, &poses[k]);
            f["mask_path"] = json!(format!("masks/frame_{k:05}.png"));
            png(&dir.join(format!("images_2/frame_{k:05}.png")), 8, 5);
            png(&dir.join(format!("masks_2/frame_{k:05}.png")), 8, 5);
            png(&dir.join(format!("masks/frame_{k:05}.png")), 16, 10);
            f
        })
        .collect();
    nerfstudio(
        &dir,
        json!({"fl_x": 20.0, "fl_y": 22.0, "cx": 8.0, "cy": 5.0, "w": 16, "h": 10}),
        frames,
        (16, 10),
    );
    let c = read_transforms_scaled(&dir.join("transforms.json"), 2)
        .unwrap()
        .capture(2, 0)
        .unwrap();
    let k = c.frames[2].intrinsics;
    assert_eq!(
        (k.width, k.height, k.fx, k.fy, k.cx, k.cy),
        (8, 5, 10.0, 11.0, 4.0, 2.5)
    );
    assert!(c.frames[2].image.ends_with("images_2/frame_00002.png"));
    assert!(c.frames[2]
        .mask
        .as_ref()
        .unwrap()
        .ends_with("masks_2/frame_00002.png"));
    // Read at full size, the same file gives the full intrinsics.
    let c = read_transforms_scaled(&dir.join("transforms.json"), 1)
        .unwrap()
        .capture(1, 0)
        .unwrap();
    assert_eq!(c.frames[0].intrinsics.fx, 20.0);
    // A folder whose images are not half the size is refused, naming the frame.
    png(&dir.join("images_4/frame_00001.png"), 8, 5);
    png(&dir.join("images_4/frame_00000.png"), 4, 2);
    png(&dir.join("images_4/frame_00002.png"), 4, 2);
    png(&dir.join("masks_4/frame_00000.png"), 4, 2);
    png(&dir.join("masks_4/frame_00001.png"), 4, 2);
    png(&dir.join("masks_4/frame_00002.png"), 4, 2);
    let e = read_transforms_scaled(&dir.join("transforms.json"), 4)
        .and_then(|t| t.capture(4, 0))
        .unwrap_err()
        .to_string();
    assert!(e.contains("frame 1") && e.contains("`w`"), "{e}");
}

/// A test case: its name, how it spoils the frames, and what the error names.
type Spoil<'a> = (&'a str, Box<dyn Fn(&mut Vec<Value>)>, &'a str);

#[test]
fn garbage_numbers_name_the_frame() {
    let dir = case_dir("cap_garbage");
    let poses = ring(3);
    let base = || -> Vec<Value> { (0..3).map(|k| frame(k, &poses[k])).collect() };
    let cases: Vec<Spoil> = vec![
        (
            "negative focal",
            Box::new(|f: &mut Vec<Value>| f[2]["fl_x"] = json!(-5.0)),
            "`fl_x`",
        ),
        (
            "huge focal",
            Box::new(|f: &mut Vec<Value>| f[2]["fl_x"] = json!(1e300)),
            "focal length",
        ),
        (
            "tiny fl_y",
            Box::new(|f: &mut Vec<Value>| f[2]["fl_y"] = json!(1e-300)),
            "`fl_y`",
        ),
        (
            "not a rigid pose's last row",
            Box::new(|f: &mut Vec<Value>| f[2]["transform_matrix"][3] = json!([0, 0, 0, 5])),
            "last row",
        ),
        (
            "cx outside",
            Box::new(|f: &mut Vec<Value>| f[2]["cx"] = json!(1e6)),
            "principal point",
        ),
        (
            "k1 absurd",
            Box::new(|f: &mut Vec<Value>| f[2]["k1"] = json!(1e6)),
            "`k1`",
        ),
        (
            "string focal",
            Box::new(|f: &mut Vec<Value>| f[2]["fl_x"] = json!("10")),
            "not a number",
        ),
        (
            "size mismatch",
            Box::new(|f: &mut Vec<Value>| f[2]["w"] = json!(99)),
            "`w` is 99",
        ),
        (
            "fractional size",
            Box::new(|f: &mut Vec<Value>| f[2]["h"] = json!(9.5)),
            "`h`",
        ),
        (
            "angle",
            Box::new(|f: &mut Vec<Value>| f[2]["camera_angle_x"] = json!(7.0)),
            "field of view",
        ),
    ];
    for (what, change, says) in cases {
        let mut frames = base();
        for f in frames.iter_mut() {
            f["fl_x"] = json!(10.0);
        }
        change(&mut frames);
        nerfstudio(&dir, json!({}), frames, (12, 8));
        let e = read_transforms_scaled(&dir.join("transforms.json"), 1)
            .and_then(|t| t.capture(1, 0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("frame 2") && e.contains(says) && e.contains("transforms.json"),
            "{what}: {e}"
        );
    }
    // A scaled (non-rigid) pose: refused when the cameras are made.
    let mut frames = base();
    let mut scaled = poses[1];
    for row in scaled.iter_mut().take(3) {
        for x in row.iter_mut().take(3) {
            *x *= 2.0;
        }
    }
    frames[1]["transform_matrix"] = pose_json(&scaled);
    nerfstudio(&dir, json!({"fl_x": 10.0}), frames, (12, 8));
    let e = err(capture::read(&spec(&dir), Path::new("/")));
    assert!(e.contains("frame 1") && e.contains("orthonormal"), "{e}");
}

#[test]
fn hostile_paths_stay_inside_the_capture() {
    let dir = case_dir("cap_paths");
    png(&dir.join("outside.png"), 4, 4);
    let set = dir.join("set");
    let pose = pose_json(&ring(1)[0]);
    png(&set.join("images/a.png"), 4, 4);
    #[cfg(unix)]
    std::os::unix::fs::symlink("../../outside.png", set.join("images/link.png")).unwrap();
    for (what, f, says) in [
        (
            "dot-dot",
            json!({"file_path": "../outside.png", "transform_matrix": pose}),
            "inside the data set",
        ),
        (
            "absolute",
            json!({"file_path": "/etc/passwd", "transform_matrix": pose}),
            "inside the data set",
        ),
        (
            "link",
            json!({"file_path": "images/link.png", "transform_matrix": pose}),
            "leads outside",
        ),
        (
            "mask",
            json!({"file_path": "images/a.png", "mask_path": "../outside.png", "transform_matrix": pose}),
            "inside the data set",
        ),
        (
            "nul",
            json!({"file_path": "images/a\u{0}.png", "transform_matrix": pose}),
            "inside the data set",
        ),
    ] {
        let root = json!({"fl_x": 5.0, "frames": [{"file_path": "images/a.png", "transform_matrix": pose}, f]});
        fs::write(set.join("transforms.json"), root.to_string()).unwrap();
        let e = read_transforms_scaled(&set.join("transforms.json"), 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("frame 1") && e.contains(says), "{what}: {e}");
    }
    // A split list naming a path outside.
    let root = json!({"fl_x": 5.0, "train_filenames": ["../outside.png"],
                      "frames": [{"file_path": "images/a.png", "transform_matrix": pose}]});
    fs::write(set.join("transforms.json"), root.to_string()).unwrap();
    let e = read_transforms_scaled(&set.join("transforms.json"), 1)
        .unwrap_err()
        .to_string();
    assert!(e.contains("train_filenames"), "{e}");
}

#[test]
fn normalisation_puts_the_cameras_in_the_unit_cube() {
    let dir = case_dir("cap_normalise");
    let poses = ring(8);
    let frames: Vec<Value> = (0..8).map(|k| frame(k, &poses[k])).collect();
    nerfstudio(&dir, json!({"fl_x": 10.0}), frames, (12, 8));
    let mut s = spec(&dir);
    s.test_every = 4;
    let v = capture::read(&s, Path::new("/")).unwrap();
    // Frames 0 and 4 (in file-name order) held out.
    assert_eq!((v.train.len(), v.test.len()), (6, 2));
    let reach = v
        .train
        .iter()
        .chain(&v.test)
        .map(|t| eye(&t.camera).abs().max_element())
        .fold(0.0, f64::max);
    assert!((reach - 1.0).abs() < 1e-9, "{reach}");
    // The scene frame maps each camera back to where the file put it.
    let f: SceneFrame = v.frame;
    let back = f.to_data(eye(&v.test[0].camera));
    let want = DVec3::new(poses[0][0][3], poses[0][1][3], poses[0][2][3]);
    assert!((back - want).length() < 1e-9, "{back} vs {want}");
    // Mean up turned to +z (each ring camera tilts down at the centre).
    let up: DVec3 = v
        .train
        .iter()
        .chain(&v.test)
        .map(|t| t.camera.up.normalize())
        .sum();
    assert!(up.normalize().z > 0.99, "{up}");
    assert!(v.report[0].contains("scene frame"), "{:?}", v.report);
    // normalize: false keeps the data's frame.
    s.normalize = false;
    let v = capture::read(&s, Path::new("/")).unwrap();
    assert!((eye(&v.test[0].camera) - want).length() < 1e-12);
    assert_eq!(v.frame, SceneFrame::IDENTITY);
}

/// COLMAP's world-to-camera rotation (x right, y down, z forward) of a
/// camera at `eye` looking at `at` with `up`.
fn colmap_pose(eye: DVec3, at: DVec3, up: DVec3) -> (DQuat, DVec3) {
    let z = (at - eye).normalize();
    let x = z.cross(up).normalize();
    let y = z.cross(x);
    // Rows of R are the camera axes in world coordinates.
    let r = DMat3::from_cols(x, y, z).transpose();
    (DQuat::from_mat3(&r), -(r * eye))
}

fn colmap_capture(dir: &Path, camera_line: &str, poses: &[(DQuat, DVec3)], size: (u32, u32)) {
    let model = dir.join("sparse/0");
    fs::create_dir_all(&model).unwrap();
    fs::write(
        model.join("cameras.txt"),
        format!("# Camera list\n{camera_line}\n"),
    )
    .unwrap();
    let mut images = String::from("# Image list with two lines of data per image:\n");
    for (k, (q, t)) in poses.iter().enumerate() {
        images += &format!(
            "{} {} {} {} {} {} {} {} 1 img_{k}.png\n{}\n",
            k + 1,
            q.w,
            q.x,
            q.y,
            q.z,
            t.x,
            t.y,
            t.z,
            if k == 0 {
                ""
            } else {
                "12.5 3.5 7 100.0 20.0 -1"
            }
        );
        png(&dir.join(format!("images/img_{k}.png")), size.0, size.1);
    }
    fs::write(model.join("images.txt"), images).unwrap();
    fs::write(
        model.join("points3D.txt"),
        "# 3D point list\n1 0.5 0.5 0.5 255 0 0 0.1 1 0\n2 -0.5 -0.5 -0.5 0 255 0 0.1 1 0\n",
    )
    .unwrap();
}

#[test]
fn colmap_text_model_round_trips_a_known_pose() {
    let dir = case_dir("cap_colmap");
    let eyes = [
        DVec3::new(3.0, 1.0, -2.0),
        DVec3::new(-2.0, 0.5, -3.0),
        DVec3::new(0.0, 3.0, 1.0),
    ];
    let poses: Vec<_> = eyes
        .iter()
        .map(|e| colmap_pose(*e, DVec3::new(0.1, 0.2, 0.0), DVec3::Y))
        .collect();
    colmap_capture(&dir, "1 PINHOLE 16 10 12.0 12.0 8.0 5.0", &poses, (16, 10));
    let mut s = spec(&dir);
    s.normalize = false;
    let v = capture::read(&s, Path::new("/")).unwrap();
    assert_eq!(v.train.len(), 3);
    for (t, e) in v.train.iter().zip(eyes) {
        assert!(
            (t.camera.eye - e).length() < 1e-9,
            "{:?} vs {e}",
            t.camera.eye
        );
        // Looking at the target, with COLMAP's −y as up.
        let fwd = (t.camera.at - t.camera.eye).normalize();
        assert!((fwd - (DVec3::new(0.1, 0.2, 0.0) - e).normalize()).length() < 1e-9);
        assert!(t.camera.up.normalize().y > 0.0);
    }
    // Points give the bounds in the report.
    let v = capture::read(&spec(&dir), Path::new("/")).unwrap();
    assert!(
        v.report.iter().any(|l| l.contains("2 sparse points")),
        "{:?}",
        v.report
    );
    // Refused: a model sdfl does not read, a bad quaternion, a missing image.
    for (what, cam, says) in [
        (
            "model",
            "1 FULL_OPENCV 16 10 12 12 8 5 0 0 0 0 0 0 0 0",
            "FULL_OPENCV",
        ),
        ("params", "1 PINHOLE 16 10 12 12 8", "4 parameters"),
        ("focal", "1 PINHOLE 16 10 -12 12 8 5", "`fx`"),
        ("nan", "1 PINHOLE 16 10 nan 12 8 5", "not a finite number"),
    ] {
        colmap_capture(&dir, cam, &poses, (16, 10));
        let e = err(capture::read(&s, Path::new("/")));
        assert!(
            e.contains(says) && e.contains("cameras.txt") && e.contains("line 2"),
            "{what}: {e}"
        );
    }
    let mut bad = poses.clone();
    bad[1].0 = DQuat::from_xyzw(0.0, 0.0, 0.0, 2.0);
    colmap_capture(&dir, "1 PINHOLE 16 10 12.0 12.0 8.0 5.0", &bad, (16, 10));
    let e = err(capture::read(&s, Path::new("/")));
    assert!(e.contains("quaternion") && e.contains("line 4"), "{e}");
}

fn npy_f64(path: &Path, rows: &[[f64; 17]]) {
    let mut header = format!(
        "{{'descr': '<f8', 'fortran_order': False, 'shape': ({}, 17), }}",
        rows.len()
    );
    while (10 + header.len() + 1) % 16 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend((header.len() as u16).to_le_bytes());
    bytes.extend(header.as_bytes());
    for r in rows {
        for v in r {
            bytes.extend(v.to_le_bytes());
        }
    }
    fs::write(path, bytes).unwrap();
}

/// An LLFF row for an OpenGL pose: rotation columns (down, right, back).
fn llff_row(m: &[[f64; 4]; 4], hwf: [f64; 3], near: f64, far: f64) -> [f64; 17] {
    let mut r = [0.0; 17];
    for row in 0..3 {
        let (right, up, back, t) = (m[row][0], m[row][1], m[row][2], m[row][3]);
        r[row * 5..row * 5 + 5].copy_from_slice(&[-up, right, back, t, hwf[row]]);
    }
    r[15] = near;
    r[16] = far;
    r
}

#[test]
fn llff_forward_facing_scenes_are_recentred() {
    let dir = case_dir("cap_llff");
    // Forward-facing: cameras on a small grid, all looking down world −z.
    let poses: Vec<_> = (0..4)
        .map(|k| {
            let e = DVec3::new(5.0 + 0.2 * (k % 2) as f64, 1.0 + 0.2 * (k / 2) as f64, 8.0);
            gl_pose(e, e - DVec3::Z, DVec3::Y)
        })
        .collect();
    let rows: Vec<_> = poses
        .iter()
        .map(|p| llff_row(p, [20.0, 30.0, 25.0], 2.0, 10.0))
        .collect();
    npy_f64(&dir.join("poses_bounds.npy"), &rows);
    for k in 0..4 {
        png(&dir.join(format!("images/IMG_{k}.JPG.png")), 30, 20);
        png(&dir.join(format!("images_2/IMG_{k}.png")), 15, 10);
    }
    let mut s = spec(&dir);
    s.downscale = 2;
    s.test_every = 8;
    let v = capture::read(&s, Path::new("/")).unwrap();
    assert_eq!((v.train.len(), v.test.len()), (3, 1));
    // Scale: nearest bound 2 → 4/3.
    assert!((v.frame.scale - 1.0 / 1.5).abs() < 1e-12);
    // The mean camera at the origin, every camera looking down −z.
    let mean = v
        .train
        .iter()
        .chain(&v.test)
        .map(|t| t.camera.eye)
        .sum::<DVec3>()
        / 4.0;
    assert!(mean.length() < 1e-9, "{mean}");
    for t in v.train.iter().chain(&v.test) {
        assert!(((t.camera.at - t.camera.eye).normalize() + DVec3::Z).length() < 1e-9);
        // 25 px focal, read at half size: NDC 2·12.5 over the shorter 10 px.
        assert!((t.camera.focal - 2.5).abs() < 1e-9, "{}", t.camera.focal);
    }
    assert!(
        v.report.iter().any(|l| l.contains("depth bounds")),
        "{:?}",
        v.report
    );
    // Garbage: a scaled rotation, near ≥ far, the wrong shape.
    let mut bad = rows.clone();
    bad[2][1] *= 3.0;
    npy_f64(&dir.join("poses_bounds.npy"), &bad);
    let e = err(capture::read(&s, Path::new("/")));
    assert!(e.contains("frame 2") && e.contains("orthonormal"), "{e}");
    let mut bad = rows.clone();
    bad[3][16] = 1.0;
    npy_f64(&dir.join("poses_bounds.npy"), &bad);
    let e = err(capture::read(&s, Path::new("/")));
    assert!(e.contains("frame 3") && e.contains("near < far"), "{e}");
    npy_f64(&dir.join("poses_bounds.npy"), &rows[..3]);
    let e = err(capture::read(&s, Path::new("/")));
    assert!(e.contains("3 poses but 4 images"), "{e}");
}

fn scene(dir: &Path, text: &str) -> PathBuf {
    let f = dir.join("scene.sdfl");
    fs::write(&f, text).unwrap();
    f
}

#[test]
fn the_capture_built_in_checks_its_arguments_and_trains() {
    let dir = case_dir("cap_cli");
    let poses = ring(4);
    let frames: Vec<Value> = (0..4).map(|k| frame(k, &poses[k])).collect();
    nerfstudio(&dir.join("cap"), json!({"fl_x": 6.0}), frames, (8, 8));
    for (what, call, says) in [
        ("missing", "capture(\"nope\")", "not found"),
        (
            "format",
            "capture(\"cap\", format: \"blender\")",
            "`format`",
        ),
        ("downscale", "capture(\"cap\", downscale: 3)", "`downscale`"),
        ("orient", "capture(\"cap\", orient: \"pca\")", "`orient`"),
        (
            "json",
            "capture(\"cap/transforms.json\", format: \"colmap\")",
            "nerfstudio",
        ),
    ] {
        let f = scene(
            &dir,
            &format!("train t {{\n  model: sdf_volume(sphere(param(0.8))),\n  data: {call},\n  iterations: 1,\n  size: [8, 8],\n}}\n"),
        );
        let o = sdfl(&dir, &["check", f.to_str().unwrap()]);
        assert_outcome(what, &o, Expect::Error);
        assert!(o.stderr.contains(says), "{what}: {}", head(&o.stderr));
    }
    let f = scene(
        &dir,
        "train t {\n  model: sdf_volume(sphere(param(0.8))),\n  data: capture(\"cap\", test_every: 2),\n  iterations: 1,\n  size: [8, 8],\n}\n",
    );
    let o = sdfl(&dir, &["plan", f.to_str().unwrap()]);
    assert_outcome("plan", &o, Expect::Ok);
    let plan = fs::read_to_string(dir.join("stdout.txt")).unwrap();
    assert!(plan.contains("capture cap (auto"), "{plan}");
    let out = dir.join("out");
    let o = run_into(&dir, &f, &out, &["--json"]);
    assert_outcome("run", &o, Expect::Ok);
    let report: Value =
        serde_json::from_str(&fs::read_to_string(dir.join("stdout.txt")).unwrap()).unwrap();
    let text = report.to_string();
    assert!(
        text.contains("scene_frame") && text.contains("\"scale\""),
        "{text}"
    );
}

/// The file's own forward model, written out here: a data-frame point
/// through an OpenGL camera-to-world pose and OpenCV intrinsics to the
/// pixel position (centres at i + ½).
fn project(c2w: &[[f64; 4]; 4], k: &Intrinsics, p: DVec3) -> (f64, f64) {
    let col = |c: usize| DVec3::new(c2w[0][c], c2w[1][c], c2w[2][c]);
    let d = p - col(3);
    // OpenCV camera axes: x right, y down, z forward.
    let (x, y, z) = (d.dot(col(0)), -d.dot(col(1)), -d.dot(col(2)));
    assert!(z > 0.0);
    let (x, y) = (x / z, y / z);
    let (xd, yd) = match k.distortion {
        Distortion::None => (x, y),
        Distortion::OpenCv { k1, k2, p1, p2 } => {
            let r2 = x * x + y * y;
            let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
            (
                x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
            )
        }
        Distortion::Fisheye { k1, k2, k3, k4 } => {
            let r = (x * x + y * y).sqrt();
            let t = r.atan();
            let t2 = t * t;
            let rd = t * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))));
            if r > 0.0 {
                (x * rd / r, y * rd / r)
            } else {
                (0.0, 0.0)
            }
        }
    };
    (k.fx * xd + k.cx, k.fy * yd + k.cy)
}

/// For points seen by each loaded camera: the ray through the pixel where
/// the file's model projects the point passes through it (to 1e-4 px,
/// measured by projecting the ray's point at the same distance back).
fn rays_hit_their_points(
    v: &capture::CaptureViews,
    files: &[([[f64; 4]; 4], Intrinsics)],
    target: DVec3,
) {
    let views: Vec<_> = v.train.iter().chain(&v.test).collect();
    assert_eq!(views.len(), files.len());
    let mut worst: f64 = 0.0;
    for (view, (c2w, k)) in views.iter().zip(files) {
        let col = |c: usize| DVec3::new(c2w[0][c], c2w[1][c], c2w[2][c]);
        let (right, up) = (col(0), col(1));
        for (a, b) in [(0.0, 0.0), (0.9, 0.4), (-1.1, -0.6), (0.3, -0.9)] {
            let p = target + right * a + up * b;
            let (u, vv) = project(c2w, k, p);
            assert!(
                u > 0.0 && u < k.width as f64 && vv > 0.0 && vv < k.height as f64,
                "{u} {vv}"
            );
            let cam = &view.camera;
            let d = cam.pixel_direction(u - 0.5, vv - 0.5, k.width, k.height);
            let ps = v.frame.to_scene(p);
            let q = cam.eye + d * (ps - cam.eye).length();
            let (u2, v2) = project(c2w, k, v.frame.to_data(q));
            worst = worst.max((u2 - u).abs().max((v2 - vv).abs()));
        }
    }
    assert!(worst < 1e-4, "{worst} px");
}

#[test]
fn rays_through_pixels_hit_what_the_file_projects_there() {
    let dir = case_dir("cap_rays");
    let poses = ring(4);
    let target = DVec3::new(10.0, -3.0, 5.0);
    // Per frame: OPENCV on frames 0, 1 (off-centre, non-square), fisheye
    // is file-wide, so a second capture below.
    let ks: Vec<Intrinsics> = (0..4)
        .map(|k| Intrinsics {
            width: 40,
            height: 24,
            fx: 30.0 + k as f64,
            fy: 31.5,
            cx: 18.3 + k as f64,
            cy: 13.1,
            distortion: Distortion::OpenCv {
                k1: -0.12,
                k2: 0.03,
                p1: 0.002,
                p2: -0.001,
            },
        })
        .collect();
    let frames: Vec<Value> = (0..4)
        .map(|k| {
            let mut f = frame(k, &poses[k]);
            let i = &ks[k];
            for (key, val) in [
                ("fl_x", i.fx),
                ("fl_y", i.fy),
                ("cx", i.cx),
                ("cy", i.cy),
                ("w", 40.0),
                ("h", 24.0),
            ] {
                f[key] = json!(val);
            }
            for (key, val) in [("k1", -0.12), ("k2", 0.03), ("p1", 0.002), ("p2", -0.001)] {
                f[key] = json!(val);
            }
            f
        })
        .collect();
    nerfstudio(&dir, json!({"camera_model": "OPENCV"}), frames, (40, 24));
    let mut s = spec(&dir);
    s.test_every = 3;
    let v = capture::read(&s, Path::new("/")).unwrap();
    // Views come train then test: frames 1, 2 then 0, 3.
    let order = [1, 2, 0, 3];
    let files: Vec<_> = order.iter().map(|&k| (poses[k], ks[k])).collect();
    rays_hit_their_points(&v, &files, target);

    // Fisheye, file-wide, normalisation off.
    let k = Intrinsics {
        width: 40,
        height: 24,
        fx: 24.0,
        fy: 24.5,
        cx: 21.0,
        cy: 11.2,
        distortion: Distortion::Fisheye {
            k1: 0.04,
            k2: -0.01,
            k3: 0.003,
            k4: -0.0004,
        },
    };
    let frames: Vec<Value> = (0..4).map(|i| frame(i, &poses[i])).collect();
    nerfstudio(
        &dir,
        json!({"camera_model": "OPENCV_FISHEYE", "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy,
               "k1": 0.04, "k2": -0.01, "k3": 0.003, "k4": -0.0004}),
        frames,
        (40, 24),
    );
    s.normalize = false;
    s.test_every = 0;
    let v = capture::read(&s, Path::new("/")).unwrap();
    let files: Vec<_> = (0..4).map(|i| (poses[i], k)).collect();
    rays_hit_their_points(&v, &files, target);
}

#[test]
fn colmap_opencv_rays_hit_what_colmap_projects() {
    let dir = case_dir("cap_colmap_rays");
    let target = DVec3::new(0.1, 0.2, 0.0);
    let eyes = [
        DVec3::new(3.0, 1.0, -2.0),
        DVec3::new(-2.0, 0.5, -3.0),
        DVec3::new(0.5, 2.0, 3.0),
    ];
    let poses: Vec<_> = eyes
        .iter()
        .map(|e| colmap_pose(*e, target, DVec3::Y))
        .collect();
    colmap_capture(
        &dir,
        "1 OPENCV 40 24 30 31 18.5 12.7 -0.1 0.02 0.001 -0.002",
        &poses,
        (40, 24),
    );
    let v = capture::read(&spec(&dir), Path::new("/")).unwrap();
    let k = Intrinsics {
        width: 40,
        height: 24,
        fx: 30.0,
        fy: 31.0,
        cx: 18.5,
        cy: 12.7,
        distortion: Distortion::OpenCv {
            k1: -0.1,
            k2: 0.02,
            p1: 0.001,
            p2: -0.002,
        },
    };
    // COLMAP's pose as an OpenGL camera-to-world, built here from the
    // eye and target (not from the reader's conversion).
    let files: Vec<_> = eyes
        .iter()
        .map(|e| (gl_pose(*e, target, DVec3::Y), k))
        .collect();
    rays_hit_their_points(&v, &files, target);
}

#[test]
fn masks_mark_the_pixels_to_leave_out() {
    let dir = case_dir("cap_masks");
    let poses = ring(2);
    let mask = |path: &Path, w: u32, h: u32, keep: u32| {
        fs::create_dir_all(path.parent().unwrap()).unwrap();
        image::GrayImage::from_fn(w, h, |i, _| image::Luma([if i < keep { 255 } else { 0 }]))
            .save(path)
            .unwrap();
    };
    let frames: Vec<Value> = (0..2)
        .map(|k| {
            let mut f = frame(k, &poses[k]);
            f["mask_path"] = json!(format!("masks/m_{k}.png"));
            mask(&dir.join(format!("masks/m_{k}.png")), 8, 6, 3);
            f
        })
        .collect();
    nerfstudio(&dir, json!({"fl_x": 8.0}), frames.clone(), (8, 6));
    let v = capture::read(&spec(&dir), Path::new("/")).unwrap();
    let m = v.train[0].mask.as_ref().expect("a mask");
    assert_eq!(m.len(), 48);
    assert!(m.iter().enumerate().all(|(p, k)| *k == (p % 8 < 3)));
    // A mask of the wrong size, and one that leaves nothing.
    mask(&dir.join("masks/m_1.png"), 4, 6, 3);
    let e = err(capture::read(&spec(&dir), Path::new("/")));
    assert!(
        e.contains("m_1.png") && e.contains("frame 1") && e.contains("4x6"),
        "{e}"
    );
    mask(&dir.join("masks/m_1.png"), 8, 6, 0);
    let e = err(capture::read(&spec(&dir), Path::new("/")));
    assert!(e.contains("masks every pixel"), "{e}");
    // Masks on some frames only: refused as nerfstudio does.
    let mut some = frames;
    some[1].as_object_mut().unwrap().remove("mask_path");
    nerfstudio(&dir, json!({"fl_x": 8.0}), some, (8, 6));
    let e = err(capture::read(&spec(&dir), Path::new("/")));
    assert!(e.contains("1 of 2 frames have a `mask_path`"), "{e}");
}

/// Cameras at ±1e300 in a `transforms.json` were read (COLMAP and LLFF
/// refuse positions past 1e18): normalised into the unit cube they
/// trained, and exports mapped back into the data's frame held
/// non-finite vertices. The nerfstudio reader (and so NeRF-synthetic's)
/// refuses them, as it does a huge rotation entry and a huge
/// `applied_transform`, naming the frame.
#[test]
fn far_away_cameras_are_refused_by_the_nerfstudio_reader() {
    let dir = case_dir("cap_far_cameras");
    let poses = ring(3);
    let base = || -> Vec<Value> {
        (0..3)
            .map(|k| {
                let mut f = frame(k, &poses[k]);
                f["fl_x"] = json!(10.0);
                f
            })
            .collect()
    };
    let cases: Vec<Spoil> = vec![
        (
            "position 1e300",
            Box::new(|f: &mut Vec<Value>| {
                for (row, x) in [1e300, -1e300, 1e300].iter().enumerate() {
                    f[2]["transform_matrix"][row][3] = json!(x);
                }
            }),
            "out of range (at most 1e18",
        ),
        (
            "position 1e19",
            Box::new(|f: &mut Vec<Value>| f[2]["transform_matrix"][1][3] = json!(-1e19)),
            "out of range (at most 1e18",
        ),
        (
            "rotation entry 1e300",
            Box::new(|f: &mut Vec<Value>| f[2]["transform_matrix"][0][1] = json!(1e300)),
            "orthonormal",
        ),
    ];
    for (what, change, says) in cases {
        let mut frames = base();
        change(&mut frames);
        nerfstudio(&dir, json!({}), frames, (12, 8));
        // The reader itself refuses: before any normalisation or camera.
        let e = err(read_transforms_scaled(&dir.join("transforms.json"), 1));
        assert!(e.contains("frame 2") && e.contains(says), "{what}: {e}");
        // NeRF-synthetic's files go through the same reader.
        fs::copy(
            dir.join("transforms.json"),
            dir.join("transforms_train.json"),
        )
        .unwrap();
        let e = err(sdfl_runtime::data::nerf_synthetic::read_transforms(
            &dir.join("transforms_train.json"),
        ));
        assert!(e.contains("frame 2") && e.contains(says), "{what}: {e}");
        fs::remove_file(dir.join("transforms_train.json")).unwrap();
    }
    // `applied_transform` moves every camera: its translation is bounded alike.
    nerfstudio(
        &dir,
        json!({"applied_transform": [[1, 0, 0, 1e300], [0, 1, 0, 0], [0, 0, 1, 0]]}),
        base(),
        (12, 8),
    );
    let e = err(read_transforms_scaled(&dir.join("transforms.json"), 1));
    assert!(
        e.contains("applied_transform") && e.contains("out of range"),
        "{e}"
    );
    // Positions up to 1e18 still read.
    let mut frames = base();
    frames[2]["transform_matrix"][0][3] = json!(1e18);
    nerfstudio(&dir, json!({}), frames, (12, 8));
    read_transforms_scaled(&dir.join("transforms.json"), 1).unwrap();

    // Through the CLI: cameras at ±1e300 trained and exported a mesh of
    // non-finite vertices; now the run stops at the data, naming it.
    let mut frames = base();
    for (k, x) in [(0, 1e300), (1, -1e300)] {
        frames[k]["transform_matrix"][0][3] = json!(x);
    }
    let cap = dir.join("cli");
    nerfstudio(&cap, json!({}), frames, (8, 8));
    let f = scene(
        &dir,
        "train t {\n  model: sdf_volume(sphere(param(0.8))),\n  data: capture(\"cli\"),\n  iterations: 1,\n  size: [8, 8],\n  after: [mesh(\"m.ply\", resolution: 8)],\n}\n",
    );
    let out = dir.join("out");
    let o = run_into(&dir, &f, &out, &[]);
    assert_outcome("cameras at 1e300", &o, Expect::Error);
    assert!(
        o.stderr.contains("frame 0") && o.stderr.contains("out of range"),
        "{}",
        head(&o.stderr)
    );
    assert!(!out.join("m.ply").exists());
}
