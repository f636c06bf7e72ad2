//! `nerf_synthetic(..., downscale: N)`: a small NeRF-synthetic set written
//! here (RGBA images of 12×8 with every alpha, one split whose lens is
//! `camera_angle_x`'s centred pinhole, one with `fl_x`, `fl_y`, `cx`, `cy`
//! off centre) read at 1/N a side. Against f64 references: each pixel is
//! its block's mean with alpha premultiplied, composited over the
//! background, and the ray through a small pixel's centre is the ray
//! through its block's centre in the full image. Factors the images refuse
//! are diagnostics at the argument, naming the factors that do.

use std::fs;
use std::path::Path;

use crate::common::{assert_outcome, case_dir, head, run_into, unwrapped, Expect};
use glam::DVec3;
use sdfl_lang::SourceFile;
use sdfl_runtime::data::{DataNeeds, TrainView};
use serde_json::{json, Value};

const BACKGROUND: [f64; 3] = [0.25, 0.5, 1.0];

/// An OpenGL camera-to-world pose at `eye` looking at the origin, +y up.
fn gl_pose(eye: DVec3) -> [[f64; 4]; 4] {
    let back = eye.normalize();
    let right = DVec3::Y.cross(back).normalize();
    let up = back.cross(right);
    let mut m = [[0.0; 4]; 4];
    for (c, v) in [right, up, back, eye].iter().enumerate() {
        for r in 0..3 {
            m[r][c] = v[r];
        }
    }
    m[3][3] = 1.0;
    m
}

/// An RGBA image whose every pixel differs (alpha from 0 to 255 included),
/// from `seed`.
fn rgba_png(path: &Path, w: u32, h: u32, seed: u32) {
    let mut s = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
    image::RgbaImage::from_fn(w, h, |i, j| {
        let mut next = || {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (s >> 24) as u8
        };
        let a = match (i + j) % 5 {
            0 => 0,
            1 => 255,
            _ => next(),
        };
        image::Rgba([next(), next(), next(), a])
    })
    .save(path)
    .unwrap();
}

/// A split file of `frames` (name, eye) with the top-level `lens` keys;
/// each frame's image written at `size`.
fn split(dir: &Path, name: &str, lens: Value, frames: &[(&str, DVec3)], size: (u32, u32)) {
    let mut root = lens;
    root["frames"] = frames
        .iter()
        .enumerate()
        .map(|(k, (file, eye))| {
            rgba_png(&dir.join(format!("{file}.png")), size.0, size.1, k as u32 + 7);
            let m = gl_pose(*eye);
            json!({"file_path": format!("./{file}"), "transform_matrix": m.iter().map(|r| r.to_vec()).collect::<Vec<_>>()})
        })
        .collect();
    fs::write(
        dir.join(format!("transforms_{name}.json")),
        root.to_string(),
    )
    .unwrap();
}

/// The set: `train` (two frames, `camera_angle_x`) and `test` (one frame,
/// pixel intrinsics off centre, `fx ≠ fy`), every image `size`.
fn data_set(dir: &Path, size: (u32, u32), test_size: (u32, u32)) {
    let set = dir.join("set");
    fs::create_dir_all(&set).unwrap();
    split(
        &set,
        "train",
        json!({"camera_angle_x": 0.9}),
        &[
            ("r_0", DVec3::new(0.3, 0.5, 3.0)),
            ("r_1", DVec3::new(-2.0, 1.0, 2.0)),
        ],
        size,
    );
    split(
        &set,
        "test",
        json!({"fl_x": 10.0, "fl_y": 12.0, "cx": 5.25, "cy": 3.5}),
        &[("t_0", DVec3::new(1.0, -0.5, 2.5))],
        test_size,
    );
}

fn scene(downscale: &str) -> String {
    format!(
        r#"train t {{
  model: nerf(layers: 1, width: 16, skips: []),
  data: nerf_synthetic("set", test_split: "test", background: [0.25, 0.5, 1], downscale: {downscale}),
  sampler: stratified(samples: 8, near: 1, far: 5),
  rays: 16,
  iterations: 2,
}}
"#
    )
}

/// The views of `dir/t.sdfl`'s data set, read as a run reads them (with
/// coverage, every held-out view).
fn read_views(dir: &Path, text: &str) -> std::io::Result<(Vec<TrainView>, Vec<TrainView>)> {
    let file = dir.join("t.sdfl");
    fs::write(&file, text).unwrap();
    let src = SourceFile::new("t.sdfl".to_string(), text.to_string()).at(&file);
    let program = sdfl_stdlib::load(&src)
        .unwrap_or_else(|d| panic!("{}", sdfl_lang::render(&src, &d, false)));
    let job = &program.trains[0];
    let needs = DataNeeds {
        coverage: true,
        held_out: None,
    };
    let views = sdfl_runtime::data::formats::read(&job.data, dir, needs)?.expect("read from files");
    Ok((views.train, views.test))
}

/// What the f64 reference reads of a frame: its pose and pixel intrinsics
/// `(fx, fy, cx, cy)` at full size.
struct Frame {
    image: image::RgbaImage,
    c2w: [[f64; 4]; 4],
    k: (f64, f64, f64, f64),
}

fn frames(set: &Path, name: &str) -> Vec<Frame> {
    let t: Value = serde_json::from_str(
        &fs::read_to_string(set.join(format!("transforms_{name}.json"))).unwrap(),
    )
    .unwrap();
    t["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            let file = f["file_path"].as_str().unwrap().trim_start_matches("./");
            let image = image::open(set.join(format!("{file}.png")))
                .unwrap()
                .to_rgba8();
            let (w, h) = (image.width() as f64, image.height() as f64);
            let k = match t["camera_angle_x"].as_f64() {
                Some(a) => {
                    let f = 0.5 * w / (0.5 * a).tan();
                    (f, f, 0.5 * w, 0.5 * h)
                }
                None => (
                    t["fl_x"].as_f64().unwrap(),
                    t["fl_y"].as_f64().unwrap(),
                    t["cx"].as_f64().unwrap(),
                    t["cy"].as_f64().unwrap(),
                ),
            };
            let mut c2w = [[0.0; 4]; 4];
            for (r, row) in f["transform_matrix"].as_array().unwrap().iter().enumerate() {
                for (c, v) in row.as_array().unwrap().iter().enumerate() {
                    c2w[r][c] = v.as_f64().unwrap();
                }
            }
            Frame { image, c2w, k }
        })
        .collect()
}

/// Checks `view` (read at 1/`n`) against `frame` in f64: colours, coverage
/// where read, and the ray through every pixel's centre.
fn assert_reference(view: &TrainView, frame: &Frame, n: u32, what: &str) {
    let (w, h) = (frame.image.width(), frame.image.height());
    let (sw, sh) = (w / n, h / n);
    assert_eq!((view.image.width, view.image.height), (sw, sh), "{what}");
    let (fx, fy, cx, cy) = frame.k;
    let col = |c: usize| DVec3::new(frame.c2w[0][c], frame.c2w[1][c], frame.c2w[2][c]);
    let (right, up, back, eye) = (col(0), col(1), col(2), col(3));
    assert!((view.camera.eye - eye).length() < 1e-12, "{what}");
    let nn = (n * n) as f64;
    for j in 0..sh {
        for i in 0..sw {
            // The block's mean with alpha premultiplied, over the background.
            let (mut premultiplied, mut alpha, mut alpha_bytes) = ([0.0f64; 3], 0.0, 0u32);
            for y in j * n..(j + 1) * n {
                for x in i * n..(i + 1) * n {
                    let p = frame.image.get_pixel(x, y).0;
                    let a = p[3] as f64 / 255.0;
                    for c in 0..3 {
                        premultiplied[c] += p[c] as f64 / 255.0 * a;
                    }
                    alpha += a;
                    alpha_bytes += p[3] as u32;
                }
            }
            let a = alpha / nn;
            let want: Vec<f64> = (0..3)
                .map(|c| premultiplied[c] / nn + BACKGROUND[c] * (1.0 - a))
                .collect();
            let k = (j * sw + i) as usize;
            let got = view.image.pixel(k);
            for c in 0..3 {
                assert!(
                    (got[c] as f64 - want[c]).abs() < 2e-6,
                    "{what}: pixel ({i}, {j}) channel {c}: {} against {}",
                    got[c],
                    want[c]
                );
            }
            if let Some(coverage) = &view.coverage {
                let mean = alpha_bytes as f64 / nn;
                assert!(
                    (coverage[k] as f64 - mean).abs() <= 0.5 + 1e-9,
                    "{what}: coverage ({i}, {j}): {} against {mean}",
                    coverage[k]
                );
            }
            // The ray through the block's centre in the full image: OpenCV
            // pixel coordinates (pixel x covers [x, x + 1)), the camera
            // looking down −z with +y up.
            let (u, v) = ((i as f64 + 0.5) * n as f64, (j as f64 + 0.5) * n as f64);
            let want = (right * ((u - cx) / fx) - up * ((v - cy) / fy) - back).normalize();
            let got = view.camera.pixel_direction(i as f64, j as f64, sw, sh);
            assert!(
                (got - want).length() < 1e-12,
                "{what}: ray ({i}, {j}): {got} against {want}"
            );
        }
    }
    // The lens at the small size: focal lengths and principal point / n,
    // exactly (n is a power of two here).
    let (_, k) = view.camera.to_opengl_intrinsics(sw, sh);
    let d = n as f64;
    for (got, want) in [
        (k.fx, fx / d),
        (k.fy, fy / d),
        (k.cx, cx / d),
        (k.cy, cy / d),
    ] {
        assert!((got - want).abs() <= 1e-12 * want.abs(), "{what}: {k:?}");
    }
}

#[test]
fn a_downscaled_set_is_the_box_average_seen_through_the_blocks_centres() {
    let dir = case_dir("reference");
    data_set(&dir, (12, 8), (12, 8));
    let set = dir.join("set");
    let (train, test) = (frames(&set, "train"), frames(&set, "test"));
    for n in [1, 2, 4] {
        let (views, held_out) = read_views(&dir, &scene(&n.to_string())).unwrap();
        assert_eq!((views.len(), held_out.len()), (2, 1));
        for (k, (v, f)) in views.iter().zip(&train).enumerate() {
            assert_reference(v, f, n, &format!("train {k} at 1/{n}"));
        }
        // Held-out views are only scored: no coverage is read for them.
        assert!(held_out[0].coverage.is_none());
        assert_reference(&held_out[0], &test[0], n, &format!("test at 1/{n}"));
    }
    // The run trains and scores at the small size.
    let o = run_into(&dir, &dir.join("t.sdfl"), &dir.join("out"), &["--json"]);
    assert_outcome("a run at downscale 4", &o, Expect::Ok);
}

#[test]
fn factors_the_images_refuse_are_diagnostics_at_the_argument() {
    let dir = case_dir("refused");
    // The training split 12×8, the held-out one 10×10.
    data_set(&dir, (12, 8), (10, 10));
    // 3 divides 12, not 8; 4 divides the training images, not the test's.
    for (n, factors, image) in [
        (
            "3",
            "3 does not divide its 12x8 images (factors that do: 2, 4)",
            "r_0.png",
        ),
        (
            "4",
            "4 does not divide its 10x10 images (factors that do: 2, 5, 10)",
            "t_0.png",
        ),
    ] {
        let text = scene(n);
        let e = read_views(&dir, &text).unwrap_err();
        assert_eq!(
            sdfl_runtime::data::coded(&e).map(|c| c.code),
            Some(sdfl_runtime::data::DOWNSCALE),
            "{e}"
        );
        // At the argument: its value's span in the file.
        let span = sdfl_runtime::data::argument_span(&e).expect("at an argument");
        let at = text.find(&format!("downscale: {n}")).unwrap() + "downscale: ".len();
        assert_eq!((span.start, span.end), (at, at + 1), "{e}");
        let o = run_into(&dir, &dir.join("t.sdfl"), &dir.join("out"), &[]);
        assert_outcome(&format!("downscale {n}"), &o, Expect::Error);
        let err = unwrapped(&o.stderr);
        assert!(
            err.contains("sdfl::data::downscale")
                && err.contains(factors)
                && err.contains(image)
                && err.contains("leave `downscale` out"),
            "{}",
            head(&o.stderr)
        );
        // `plan` says so too, and still prints.
        let plan = crate::common::sdfl(&dir, &["plan", dir.join("t.sdfl").to_str().unwrap()]);
        assert_outcome("plan", &plan, Expect::Ok);
        let stdout = fs::read_to_string(dir.join("stdout.txt")).unwrap();
        assert!(
            stdout.contains("known once read") && stdout.contains(factors),
            "{stdout}"
        );
    }
    // Out of range, with another bad argument of the same call: both
    // reported, each at its argument.
    for n in ["0", "65", "2.5", "-4"] {
        let text = scene(n).replace("test_split: \"test\"", "test_split: \"a/b\"");
        let src = SourceFile::new("t.sdfl".to_string(), text.clone()).at(dir.join("t.sdfl"));
        let diags = sdfl_stdlib::load(&src).unwrap_err();
        let rendered = sdfl_lang::render(&src, &diags, false);
        assert_eq!(diags.diags.len(), 2, "{rendered}");
        assert!(
            rendered.contains("`downscale` must be a whole number from 1 to 64")
                && rendered.contains("`test_split` must be a plain name"),
            "{rendered}"
        );
        let d = diags
            .diags
            .iter()
            .find(|d| d.message.contains("downscale"))
            .unwrap();
        assert_eq!(d.code, sdfl_lang::codes::VALUE);
        assert_eq!(&text[d.span.start..d.span.end], n, "{rendered}");
    }
}
