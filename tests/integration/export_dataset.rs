//! `dataset(...)` writes a layout that nerfstudio's `blender-data` and
//! `nerfstudio-data` parsers, instant-ngp and sdfl's `nerf_synthetic`
//! read unchanged. Each parser is emulated here field by field, as its
//! source reads the files (nerfstudio 1.x `blender_dataparser.py`,
//! `nerfstudio_dataparser.py`; instant-ngp `src/nerf_loader.cu`), and what
//! it resolves (image files, poses, intrinsics, distortion, splits) is
//! checked against the cameras that wrote the set.
//!
//! Fields each parser reads:
//! * Blender: `transforms_{split}.json` → `camera_angle_x`; per frame
//!   `file_path` (`"./"` removed, `".png"` appended), `transform_matrix`
//!   (first 3 rows). Image size from the first image; `fx = fy = ½W /
//!   tan(½ camera_angle_x)`, `cx = W/2`, `cy = H/2`, no distortion.
//! * nerfstudio: `transforms.json` → `fl_x fl_y cx cy w h` and `k1 k2 k3
//!   k4 p1 p2` (or `distortion_params`) at the top, else per frame;
//!   `camera_model`; per frame `file_path` (opened as given, relative to
//!   the directory), `transform_matrix`; frames sorted by file name;
//!   `{train,val,test}_filenames` (all three needed once one is given).
//! * instant-ngp (given a JSON file): frames natural-sorted by
//!   `file_path`, resolved as given or, without extension and missing,
//!   with `.png`, `.jpg`, …; focal from `x_fov` (degrees), else `fl_x`,
//!   else `camera_angle_x` (radians), top level then per frame; `cx/w`,
//!   `cy/h` (`w`, `h` needed beside `cx`, `cy`); `k1 k2 k3 k4` and `p1 p2`
//!   (into the slots of `k3 k4`), OpenCV unless `is_fisheye`;
//!   `transform_matrix` (3 × 4).

use crate::common;
use std::cmp::Ordering;
use std::fs;
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde_json::Value;

use crate::common::{case_dir, run_into, Expect};
use sdfl_runtime::data::export::DatasetWriter;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::lens::{Distortion, Intrinsics};

/// What a parser resolves for one image.
#[derive(Debug, Clone)]
struct Parsed {
    image: PathBuf,
    /// Camera-to-world, first three rows.
    c2w: [[f64; 4]; 3],
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    /// `fisheye` or `perspective`.
    fisheye: bool,
    /// nerfstudio's order: k1, k2, k3, k4, p1, p2.
    dist: [f64; 6],
}

fn json(path: &Path) -> Value {
    serde_json::from_slice(&fs::read(path).unwrap()).unwrap()
}

fn pose(v: &Value) -> [[f64; 4]; 3] {
    std::array::from_fn(|r| std::array::from_fn(|c| v[r][c].as_f64().unwrap()))
}

fn size(image: &Path) -> (u32, u32) {
    image::image_dimensions(image).unwrap_or_else(|e| panic!("{}: {e}", image.display()))
}

/// nerfstudio's `blender-data` parser, one split: it reads
/// `camera_angle_x` unconditionally (a `KeyError` when missing).
fn blender(dir: &Path, split: &str) -> Result<Vec<Parsed>, String> {
    let meta = json(&dir.join(format!("transforms_{split}.json")));
    let Some(angle) = meta.get("camera_angle_x").and_then(Value::as_f64) else {
        return Err("KeyError: 'camera_angle_x'".into());
    };
    let frames = meta["frames"].as_array().unwrap();
    let images: Vec<PathBuf> = frames
        .iter()
        .map(|f| dir.join(f["file_path"].as_str().unwrap().replace("./", "") + ".png"))
        .collect();
    let (w, h) = size(&images[0]);
    let focal = 0.5 * w as f64 / (0.5 * angle).tan();
    Ok(frames
        .iter()
        .zip(images)
        .map(|(f, image)| Parsed {
            image,
            c2w: pose(&f["transform_matrix"]),
            fx: focal,
            fy: focal,
            cx: w as f64 / 2.0,
            cy: h as f64 / 2.0,
            fisheye: false,
            dist: [0.0; 6],
        })
        .collect())
}

/// nerfstudio's `nerfstudio-data` parser, one split (poses before its
/// orientation and scaling, which it applies to whatever it reads).
fn nerfstudio(dir: &Path, split: &str) -> Result<Vec<Parsed>, String> {
    let meta = json(&dir.join("transforms.json"));
    let fixed = |k: &str| meta.get(k).is_some();
    let distort_fixed = ["k1", "k2", "k3", "p1", "p2", "distortion_params"]
        .iter()
        .any(|k| fixed(k));
    let mut frames: Vec<&Value> = meta["frames"].as_array().unwrap().iter().collect();
    let fname = |f: &Value| dir.join(f["file_path"].as_str().unwrap());
    frames.sort_by_key(|f| fname(f));
    let num = |f: &Value, k: &str| -> f64 {
        let src = if fixed(k) { &meta } else { f };
        src.get(k)
            .unwrap_or_else(|| panic!("{k} not specified in frame"))
            .as_f64()
            .unwrap()
    };
    let dist = |f: &Value| -> [f64; 6] {
        let src = if distort_fixed { &meta } else { f };
        let g = |k: &str| src.get(k).map_or(0.0, |v| v.as_f64().unwrap());
        [g("k1"), g("k2"), g("k3"), g("k4"), g("p1"), g("p2")]
    };
    let fisheye = match meta.get("camera_model").and_then(Value::as_str) {
        None | Some("PINHOLE" | "SIMPLE_PINHOLE" | "OPENCV") => false,
        Some("OPENCV_FISHEYE") => true,
        Some(m) => return Err(format!("camera model {m}")),
    };
    let any_split = ["train", "val", "test"]
        .iter()
        .any(|s| meta.get(format!("{s}_filenames")).is_some());
    let keep: Vec<PathBuf> = match meta.get(format!("{split}_filenames")) {
        Some(list) => {
            let wanted: Vec<PathBuf> = list
                .as_array()
                .unwrap()
                .iter()
                .map(|x| dir.join(x.as_str().unwrap()))
                .collect();
            let all: Vec<PathBuf> = frames.iter().map(|f| fname(f)).collect();
            if let Some(m) = wanted.iter().find(|w| !all.contains(w)) {
                return Err(format!(
                    "Some filenames for split {split} were not found: {m:?}"
                ));
            }
            wanted
        }
        None if any_split => {
            return Err(format!(
                "The dataset's list of filenames for split {split} is missing."
            ))
        }
        None => return Err("no split lists: nerfstudio would split by fraction".into()),
    };
    Ok(frames
        .into_iter()
        .filter(|f| keep.contains(&fname(f)))
        .map(|f| {
            // The image must open as named.
            let image = fname(f);
            let (w, h) = size(&image);
            assert_eq!(
                (num(f, "w"), num(f, "h")),
                (w as f64, h as f64),
                "{}",
                image.display()
            );
            Parsed {
                c2w: pose(&f["transform_matrix"]),
                fx: num(f, "fl_x"),
                fy: num(f, "fl_y"),
                cx: num(f, "cx"),
                cy: num(f, "cy"),
                fisheye,
                dist: dist(f),
                image,
            }
        })
        .collect())
}

/// instant-ngp's comparison of file names: digit runs as numbers.
fn natural(a: &str, b: &str) -> Ordering {
    let chunks = |s: &str| {
        let mut v: Vec<(bool, String)> = Vec::new();
        for c in s.chars() {
            let d = c.is_ascii_digit();
            match v.last_mut() {
                Some((kd, t)) if *kd == d => t.push(c),
                _ => v.push((d, c.to_string())),
            }
        }
        v
    };
    let (x, y) = (chunks(a), chunks(b));
    for (p, q) in x.iter().zip(&y) {
        let o = if p.0 && q.0 {
            p.1.parse::<u64>()
                .unwrap()
                .cmp(&q.1.parse::<u64>().unwrap())
        } else {
            p.1.cmp(&q.1)
        };
        if o != Ordering::Equal {
            return o;
        }
    }
    x.len().cmp(&y.len())
}

/// instant-ngp's `load_nerf` given one JSON file.
fn instant_ngp(file: &Path) -> Vec<Parsed> {
    let meta = json(file);
    let base = file.parent().unwrap();
    let mut frames: Vec<Value> = meta["frames"].as_array().unwrap().clone();
    frames.sort_by(|a, b| {
        natural(
            a["file_path"].as_str().unwrap(),
            b["file_path"].as_str().unwrap(),
        )
    });
    let resolve = |p: &str| {
        let path = base.join(p);
        if path.extension().is_none() && !path.exists() {
            for ext in [
                "png", "jpg", "jpeg", "bmp", "gif", "tga", "pic", "pnm", "psd", "exr",
            ] {
                if path.with_extension(ext).exists() {
                    return path.with_extension(ext);
                }
            }
        }
        path
    };
    // read_focal_length: x_fov (degrees), fl_x, camera_angle_x (radians).
    let focal = |j: &Value, (w, h): (u32, u32), f: &mut (f64, f64)| -> bool {
        let axis = |res: u32, a: &str| -> f64 {
            let fov = |deg: f64| 0.5 * res as f64 / (0.5 * deg.to_radians()).tan();
            if let Some(v) = j.get(format!("{a}_fov")) {
                fov(v.as_f64().unwrap())
            } else if let Some(v) = j.get(format!("fl_{a}")) {
                v.as_f64().unwrap()
            } else if let Some(v) = j.get(format!("camera_angle_{a}")) {
                fov(v.as_f64().unwrap().to_degrees())
            } else {
                0.0
            }
        };
        let (x, y) = (axis(w, "x"), axis(h, "y"));
        if x != 0.0 {
            *f = (x, if y != 0.0 { y } else { x });
        } else if y != 0.0 {
            *f = (y, y);
        } else {
            return false;
        }
        true
    };
    // read_lens: params[0..4] and the principal point as fractions.
    let lens = |j: &Value,
                params: &mut [f64; 4],
                fisheye: &mut Option<bool>,
                pp: &mut (f64, f64)| {
        let opencv_fisheye = j
            .get("is_fisheye")
            .and_then(Value::as_bool)
            .unwrap_or(false);
        for (k, i) in [
            ("k1", 0),
            ("k2", 1),
            ("k3", 2),
            ("k4", 3),
            ("p1", 2),
            ("p2", 3),
        ] {
            if let Some(v) = j.get(k) {
                params[i] = v.as_f64().unwrap();
                if params[i] != 0.0 {
                    *fisheye = Some(opencv_fisheye);
                }
            }
        }
        if let Some(cx) = j.get("cx") {
            pp.0 = cx.as_f64().unwrap() / j.get("w").expect("`w` beside `cx`").as_f64().unwrap();
        }
        if let Some(cy) = j.get("cy") {
            pp.1 = cy.as_f64().unwrap() / j.get("h").expect("`h` beside `cy`").as_f64().unwrap();
        }
    };
    let (mut top_params, mut top_mode, mut top_pp) = ([0.0; 4], None, (0.5, 0.5));
    lens(&meta, &mut top_params, &mut top_mode, &mut top_pp);
    frames
        .iter()
        .map(|f| {
            let image = resolve(f["file_path"].as_str().unwrap());
            assert!(
                image.exists(),
                "Could not find image file '{}'",
                image.display()
            );
            let (w, h) = size(&image);
            let mut fl = (0.0, 0.0);
            let got = focal(&meta, (w, h), &mut fl) | focal(f, (w, h), &mut fl);
            assert!(got, "Couldn't read fov.");
            let (mut params, mut mode, mut pp) = (top_params, top_mode, top_pp);
            lens(f, &mut params, &mut mode, &mut pp);
            let fisheye = mode == Some(true);
            let dist = match mode {
                None => [0.0; 6],
                Some(true) => [params[0], params[1], params[2], params[3], 0.0, 0.0],
                Some(false) => [params[0], params[1], 0.0, 0.0, params[2], params[3]],
            };
            Parsed {
                c2w: pose(&f["transform_matrix"]),
                fx: fl.0,
                fy: fl.1,
                cx: pp.0 * w as f64,
                cy: pp.1 * h as f64,
                fisheye,
                dist,
                image,
            }
        })
        .collect()
}

/// What wrote view `k`.
#[derive(Debug, Clone, Copy)]
struct Truth {
    c2w: [[f64; 4]; 4],
    i: Intrinsics,
}

fn dist_of(l: Distortion) -> [f64; 6] {
    match l {
        Distortion::None => [0.0; 6],
        Distortion::OpenCv { k1, k2, p1, p2 } => [k1, k2, 0.0, 0.0, p1, p2],
        Distortion::Fisheye { k1, k2, k3, k4 } => [k1, k2, k3, k4, 0.0, 0.0],
    }
}

/// Every parsed view is the right file with its camera; the views are
/// exactly `want` (indices), in any order.
fn agrees(what: &str, parsed: &[Parsed], truth: &[Truth], want: &[usize], intrinsics: bool) {
    let mut got: Vec<usize> = parsed
        .iter()
        .map(|p| {
            let name = p.image.file_name().unwrap().to_str().unwrap();
            name.strip_prefix("r_")
                .and_then(|s| s.strip_suffix(".png"))
                .unwrap()
                .parse()
                .unwrap()
        })
        .collect();
    for (p, &k) in parsed.iter().zip(&got) {
        let t = &truth[k];
        for r in 0..3 {
            for c in 0..4 {
                assert!(
                    (p.c2w[r][c] - t.c2w[r][c]).abs() < 1e-12,
                    "{what}: view {k} pose"
                );
            }
        }
        if intrinsics {
            let close = |a: f64, b: f64| (a - b).abs() < 1e-9 * b.abs().max(1.0);
            assert!(
                close(p.fx, t.i.fx)
                    && close(p.fy, t.i.fy)
                    && close(p.cx, t.i.cx)
                    && close(p.cy, t.i.cy),
                "{what}: view {k}: {p:?} vs {:?}",
                t.i
            );
            assert_eq!(
                p.fisheye,
                matches!(t.i.distortion, Distortion::Fisheye { .. }),
                "{what}: view {k}"
            );
            assert_eq!(p.dist, dist_of(t.i.distortion), "{what}: view {k}");
        }
    }
    got.sort_unstable();
    assert_eq!(got, want, "{what}: views");
}

fn c2w(k: usize) -> [[f64; 4]; 4] {
    let cam = Camera::look_at(
        DVec3::new(
            (k as f64).cos() * 3.0,
            0.5 + k as f64 * 0.1,
            (k as f64).sin() * 3.0,
        ),
        DVec3::ZERO,
        DVec3::Y,
        1.2,
    );
    cam.to_opengl_intrinsics(8, 6).0
}

/// Writes 12 views of 8 × 6 (so that `r_10` sorts before `r_2` as text)
/// with `intrinsics(k)`, 3 held out; returns the truth and held-out views,
/// and the code of the writer's warning, if any.
fn write_set(
    out: &Path,
    name: &str,
    intrinsics: impl Fn(usize) -> Intrinsics,
) -> (Vec<Truth>, Vec<usize>, Option<String>) {
    let n = 12;
    let mut w = DatasetWriter::new(out, Path::new(name), (8, 6), n, 3, 5);
    let mut truth = Vec::new();
    for k in 0..n {
        let t = Truth {
            c2w: c2w(k),
            i: intrinsics(k),
        };
        let rgb = vec![k as u8; 8 * 6 * 3];
        w.push_view(k, t.c2w, t.i, &rgb, None).unwrap();
        truth.push(t);
    }
    let warning = w.finish().unwrap().warning.map(|w| w.code);
    let held = sdfl_stdlib::value::held_out(n, 3, 5);
    (truth, held, warning)
}

/// A centred pinhole set: every parser resolves every split to the
/// writing cameras, intrinsics included; sdfl reads its splits back.
#[test]
fn every_parser_reads_a_pinhole_set() {
    let out = case_dir("export_pinhole");
    let pin = |_| Intrinsics {
        width: 8,
        height: 6,
        fx: 4.8,
        fy: 4.8,
        cx: 4.0,
        cy: 3.0,
        distortion: Distortion::None,
    };
    let (truth, held, warning) = write_set(&out, "set", pin);
    assert_eq!(warning, None);
    let dir = out.join("set");
    let train: Vec<usize> = (0..12).filter(|k| !held.contains(k)).collect();
    let all: Vec<usize> = (0..12).collect();
    for (split, want) in [("train", &train), ("val", &held), ("test", &held)] {
        agrees(
            &format!("blender {split}"),
            &blender(&dir, split).unwrap(),
            &truth,
            want,
            true,
        );
        agrees(
            &format!("nerfstudio {split}"),
            &nerfstudio(&dir, split).unwrap(),
            &truth,
            want,
            true,
        );
        agrees(
            &format!("instant-ngp transforms_{split}.json"),
            &instant_ngp(&dir.join(format!("transforms_{split}.json"))),
            &truth,
            want,
            true,
        );
    }
    agrees(
        "instant-ngp transforms.json",
        &instant_ngp(&dir.join("transforms.json")),
        &truth,
        &all,
        true,
    );
    // sdfl's own reader: the Blender files, and the images they name.
    let read =
        |split| sdfl_runtime::data::nerf_synthetic::read_split(&dir, split, DVec3::ONE).unwrap();
    assert_eq!((read("train").len(), read("test").len()), (9, 3));
    assert_eq!(nerfstudio(&dir, "val").unwrap().len(), 3);
}

/// OPENCV with an off-centre principal point, and OPENCV_FISHEYE with
/// intrinsics that differ per view: nerfstudio and instant-ngp resolve
/// each view's own; the Blender parser (one centred pinhole by design)
/// stops at the missing `camera_angle_x`, and the writer warns.
#[test]
fn distorted_and_per_view_intrinsics() {
    let out = case_dir("export_distorted");
    let opencv = |_| Intrinsics {
        width: 8,
        height: 6,
        fx: 5.0,
        fy: 5.1,
        cx: 4.3,
        cy: 2.8,
        distortion: Distortion::OpenCv {
            k1: -0.12,
            k2: 0.02,
            p1: 1e-3,
            p2: -5e-4,
        },
    };
    let (truth, held, warning) = write_set(&out, "cv", opencv);
    assert_eq!(warning.as_deref(), Some(sdfl_lang::codes::BLENDER_LENS));
    let train: Vec<usize> = (0..12).filter(|k| !held.contains(k)).collect();
    let dir = out.join("cv");
    for (split, want) in [("train", &train), ("test", &held)] {
        agrees(
            &format!("nerfstudio {split}"),
            &nerfstudio(&dir, split).unwrap(),
            &truth,
            want,
            true,
        );
        agrees(
            &format!("instant-ngp {split}"),
            &instant_ngp(&dir.join(format!("transforms_{split}.json"))),
            &truth,
            want,
            true,
        );
        // One centred pinhole is all the Blender form states: its parser
        // stops at the missing field of view rather than read these wrong.
        assert!(blender(&dir, split).is_err(), "blender {split}");
    }
    let t = json(&dir.join("transforms.json"));
    assert_eq!(t["camera_model"], "OPENCV");

    let fisheye = |k: usize| Intrinsics {
        width: 8,
        height: 6,
        fx: 4.0 + k as f64 * 0.1,
        fy: 4.0 + k as f64 * 0.1,
        cx: 4.0,
        cy: 3.0,
        distortion: Distortion::Fisheye {
            k1: 0.05,
            k2: -0.01,
            k3: 0.002,
            k4: -1e-4 * k as f64,
        },
    };
    let (truth, held, warning) = write_set(&out, "fish", fisheye);
    assert_eq!(warning.as_deref(), Some(sdfl_lang::codes::BLENDER_LENS));
    let dir = out.join("fish");
    let all: Vec<usize> = (0..12).collect();
    agrees(
        "nerfstudio fisheye test",
        &nerfstudio(&dir, "test").unwrap(),
        &truth,
        &held,
        true,
    );
    agrees(
        "instant-ngp fisheye",
        &instant_ngp(&dir.join("transforms.json")),
        &truth,
        &all,
        true,
    );
    let t = json(&dir.join("transforms.json"));
    assert_eq!(t["camera_model"], "OPENCV_FISHEYE");
    assert!(
        t.get("fl_x").is_none(),
        "intrinsics per frame, not at the top"
    );
}

/// The cameras of a statement as written for `w × h` images.
fn truths(cameras: &[Camera], (w, h): (u32, u32)) -> Vec<Truth> {
    cameras
        .iter()
        .map(|c| {
            let (c2w, i) = c.to_opengl_intrinsics(w, h);
            Truth { c2w, i }
        })
        .collect()
}

/// The `dataset(...)` built-in end to end: `test_views` holds views out,
/// every parser finds the CLI's files and cameras, sdfl reads the splits
/// back, and holding out every view is refused when checked.
#[test]
fn the_dataset_output_from_the_cli() {
    let dir = case_dir("export_cli");
    let scene = "render r {\n  scene: sphere(0.5),\n  camera: orbit(radius: 3, up: [0, 1, 0], focal: 1.5, views: 6),\n  size: [10, 8],\n  outputs: [dataset(\"set\", test_views: 2, seed: 3)],\n}\n";
    let file = dir.join("scene.sdfl");
    fs::write(&file, scene).unwrap();
    let o = run_into(&dir, &file, &dir.join("out"), &[]);
    common::assert_outcome("render a data set", &o, Expect::Ok);
    assert!(
        !o.stderr.contains("blender-lens"),
        "{}",
        common::head(&o.stderr)
    );
    let program = sdfl_stdlib::load(&sdfl_lang::SourceFile::new("scene.sdfl", scene)).unwrap();
    let job = &program.renders[0];
    let truth = truths(&job.cameras, (10, 8));
    let held = sdfl_stdlib::value::held_out(6, 2, 3);
    let train: Vec<usize> = (0..6).filter(|k| !held.contains(k)).collect();
    let set = dir.join("out/set");
    for (split, want) in [("train", &train), ("val", &held), ("test", &held)] {
        agrees(
            &format!("cli nerfstudio {split}"),
            &nerfstudio(&set, split).unwrap(),
            &truth,
            want,
            true,
        );
        agrees(
            &format!("cli instant-ngp {split}"),
            &instant_ngp(&set.join(format!("transforms_{split}.json"))),
            &truth,
            want,
            true,
        );
        // Square pixels, centred: the Blender parser's one focal is exact.
        agrees(
            &format!("cli blender {split}"),
            &blender(&set, split).unwrap(),
            &truth,
            want,
            true,
        );
    }
    let read = |split| {
        sdfl_runtime::data::nerf_synthetic::read_split(&set, split, DVec3::ONE)
            .unwrap()
            .len()
    };
    assert_eq!((read("train"), read("test")), (4, 2));
    // Every view is an RGBA PNG whose alpha is the hit mask.
    let img = image::open(set.join("r_0.png")).unwrap().to_rgba8();
    assert_eq!(img.dimensions(), (10, 8));
    assert!(img.pixels().any(|p| p[3] == 255) && img.pixels().any(|p| p[3] == 0));

    // Held out to the last view: refused before anything runs.
    let bad = scene.replace("test_views: 2", "test_views: 6");
    fs::write(&file, &bad).unwrap();
    let o = run_into(&dir, &file, &dir.join("out2"), &[]);
    common::assert_outcome("every view held out", &o, Expect::Error);
    assert!(
        o.stderr.contains("leaving none to train on"),
        "{}",
        common::head(&o.stderr)
    );
    assert!(!dir.join("out2/set").exists());
}

/// Views through a real lens (`lens(...)`: off-centre principal point,
/// fx ≠ fy, OpenCV distortion) write `camera_model` OPENCV with their
/// coefficients; nerfstudio and instant-ngp resolve them exactly.
#[test]
fn a_lens_data_set_from_the_cli() {
    let dir = case_dir("export_cli_lens");
    let scene = "render r {\n  scene: sphere(0.5),\n  camera: lens([look_at(eye: [0, 0, -3]), look_at(eye: [3, 0, 0]), look_at(eye: [0, 3, 0.1])], size: [10, 8], focal: [9, 9.5], center: [5.4, 3.7], model: \"opencv\", distortion: [-0.1, 0.01, 0.001, -0.002]),\n  size: [10, 8],\n  outputs: [dataset(\"set\", test_views: 1)],\n}\n";
    let file = dir.join("scene.sdfl");
    fs::write(&file, scene).unwrap();
    let o = run_into(&dir, &file, &dir.join("out"), &[]);
    common::assert_outcome("render through a lens", &o, Expect::Ok);
    // Said when checked, with the statement's span, and by the writer.
    let warned = o.stderr.matches(sdfl_lang::codes::BLENDER_LENS).count();
    assert!(warned >= 2, "{}", common::head(&o.stderr));
    let program = sdfl_stdlib::load(&sdfl_lang::SourceFile::new("scene.sdfl", scene)).unwrap();
    let truth = truths(&program.renders[0].cameras, (10, 8));
    assert!(matches!(truth[0].i.distortion, Distortion::OpenCv { k1, .. } if k1 == -0.1));
    let held = sdfl_stdlib::value::held_out(3, 1, 0);
    let train: Vec<usize> = (0..3).filter(|k| !held.contains(k)).collect();
    let set = dir.join("out/set");
    assert_eq!(json(&set.join("transforms.json"))["camera_model"], "OPENCV");
    for (split, want) in [("train", &train), ("test", &held)] {
        agrees(
            &format!("lens nerfstudio {split}"),
            &nerfstudio(&set, split).unwrap(),
            &truth,
            want,
            true,
        );
        agrees(
            &format!("lens instant-ngp {split}"),
            &instant_ngp(&set.join(format!("transforms_{split}.json"))),
            &truth,
            want,
            true,
        );
        assert!(blender(&set, split).is_err(), "lens blender {split}");
    }
}

/// A render writing an LLFF set of `cameras` to `set` (8×6 images).
fn llff_scene(cameras: &str) -> String {
    format!("render r {{\n  scene: sphere(0.5),\n  camera: {cameras},\n  size: [8, 6],\n  outputs: [dataset(\"set\", llff_bounds: [1, 10])],\n}}\n")
}

/// Three pinhole cameras side by side, looking down −z.
const PINHOLES: &str =
    "[look_at(eye: [-0.2, 0, 3]), look_at(eye: [0, 0, 3]), look_at(eye: [0.2, 0, 3])]";

/// The same cameras through a distorted lens.
fn distorted() -> String {
    format!("lens({PINHOLES}, size: [8, 6], focal: [7, 7], center: [4, 3], model: \"opencv\", distortion: [-0.1, 0.01, 0, 0])")
}

/// Whether `set` holds a complete LLFF set of three views that every
/// reader loads: `poses_bounds.npy` with its images, and the transforms
/// files.
fn loads(set: &Path) -> Result<(), String> {
    let e = |e: std::io::Error| e.to_string();
    let (shape, _) = sdfl_runtime::data::npy::read_f64(set.join("poses_bounds.npy"))
        .map_err(|x| x.to_string())?;
    if shape != [3, 17] {
        return Err(format!("poses_bounds.npy is {shape:?}"));
    }
    for k in 0..3 {
        image::open(set.join(format!("images/{k:04}.png"))).map_err(|x| x.to_string())?;
    }
    let n = sdfl_runtime::data::nerf_synthetic::read_split(set, "train", DVec3::ONE)
        .map_err(e)?
        .len();
    if n != 3 {
        return Err(format!("{n} training views"));
    }
    let spec = sdfl_stdlib::value::CaptureSpec {
        format: sdfl_stdlib::value::CaptureFormat::Llff,
        test_every: 0,
        orient: sdfl_stdlib::value::CaptureOrient::None,
        ..sdfl_stdlib::value::CaptureSpec::at(set)
    };
    sdfl_runtime::data::capture::read(&spec, Path::new("/")).map_err(e)?;
    Ok(())
}

/// `dataset(llff_bounds: ...)` through a distorted lens passed `check`;
/// `run` refused it only after it had marked an earlier complete LLFF set
/// incomplete and overwritten its images. It is refused when checked, at
/// the `dataset` output, and the earlier set is untouched.
#[test]
fn an_llff_set_through_a_distorted_lens_is_refused_when_checked() {
    let dir = case_dir("export_llff_lens");
    let file = dir.join("scene.sdfl");
    let out = dir.join("out");
    fs::write(&file, llff_scene(PINHOLES)).unwrap();
    let o = run_into(&dir, &file, &out, &[]);
    common::assert_outcome("a pinhole LLFF set", &o, Expect::Ok);
    let set = out.join("set");
    assert_eq!(loads(&set), Ok(()));
    let before: Vec<Vec<u8>> = ["poses_bounds.npy", "images/0000.png", "transforms.json"]
        .iter()
        .map(|f| fs::read(set.join(f)).unwrap())
        .collect();

    fs::write(&file, llff_scene(&distorted())).unwrap();
    let o = common::sdfl(&dir, &["check", file.to_str().unwrap()]);
    common::assert_outcome("check", &o, Expect::Error);
    assert!(
        o.stderr.contains("sdfl::value::range")
            && o.stderr.contains("centred pinhole")
            && o.stderr.contains("llff_bounds"),
        "{}",
        common::head(&o.stderr)
    );
    let o = run_into(&dir, &file, &out, &[]);
    common::assert_outcome("run", &o, Expect::Error);
    assert_eq!(loads(&set), Ok(()));
    let after: Vec<Vec<u8>> = ["poses_bounds.npy", "images/0000.png", "transforms.json"]
        .iter()
        .map(|f| fs::read(set.join(f)).unwrap())
        .collect();
    assert!(before == after, "the earlier set changed");
}

/// What `check` cannot see (views made at run time) is refused by the
/// writer: before it touches an earlier set, which stays loadable whether
/// the new set is refused at its first view or its writer fails half-way.
/// Its views are written beside the set and moved in only once complete.
#[test]
fn an_earlier_set_survives_a_refused_or_failed_rewrite() {
    let dir = case_dir("export_llff_keep");
    let out = dir.join("out");
    fs::create_dir_all(&out).unwrap();
    let rgb = vec![90u8; 8 * 6 * 3];
    let cams: Vec<Camera> = [-0.2, 0.0, 0.2]
        .iter()
        .map(|x| {
            Camera::look_at(
                DVec3::new(*x, 0.0, 3.0),
                DVec3::new(*x, 0.0, 0.0),
                DVec3::Y,
                1.5,
            )
        })
        .collect();
    let write = |cams: &[Camera]| {
        let mut w =
            DatasetWriter::new(&out, Path::new("set"), (8, 6), 3, 0, 0).with_llff([1.0, 10.0]);
        for (k, c) in cams.iter().enumerate() {
            w.push(k, c, &rgb, None)?;
        }
        w.finish()
    };
    write(&cams).unwrap();
    let set = out.join("set");
    assert_eq!(loads(&set), Ok(()));
    let listing = || {
        let mut l: Vec<String> = walk(&out);
        l.sort();
        l
    };
    let files = listing();

    // A distorted view: refused at that view, the earlier set as it was.
    let lens = Intrinsics {
        width: 8,
        height: 6,
        fx: 7.0,
        fy: 7.0,
        cx: 4.0,
        cy: 3.0,
        distortion: Distortion::OpenCv {
            k1: -0.1,
            k2: 0.01,
            p1: 0.0,
            p2: 0.0,
        },
    };
    let mut w = DatasetWriter::new(&out, Path::new("set"), (8, 6), 3, 0, 0).with_llff([1.0, 10.0]);
    w.push(0, &cams[0], &rgb, None).unwrap();
    let (c2w, _) = cams[1].to_opengl_intrinsics(8, 6);
    let e = w
        .push_view(1, c2w, lens, &rgb, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("centred pinhole"), "{e}");
    drop(w);
    assert_eq!(loads(&set), Ok(()));
    assert_eq!(listing(), files, "nothing left beside the set");

    // A writer dropped half-way (its job failed): the same.
    let mut w = DatasetWriter::new(&out, Path::new("set"), (8, 6), 3, 0, 0).with_llff([1.0, 10.0]);
    w.push(0, &cams[0], &rgb, None).unwrap();
    w.push(1, &cams[1], &rgb, None).unwrap();
    drop(w);
    assert_eq!(loads(&set), Ok(()));
    assert_eq!(listing(), files);

    // A complete rewrite replaces it.
    let brighter = vec![200u8; 8 * 6 * 3];
    let mut w = DatasetWriter::new(&out, Path::new("set"), (8, 6), 3, 0, 0).with_llff([1.0, 10.0]);
    for (k, c) in cams.iter().enumerate() {
        w.push(k, c, &brighter, None).unwrap();
    }
    w.finish().unwrap();
    assert_eq!(loads(&set), Ok(()));
    assert_eq!(listing(), files);
    let img = image::open(set.join("images/0002.png")).unwrap().to_rgba8();
    assert_eq!(img.get_pixel(0, 0)[0], 200);
}

/// Every file under `dir`, relative to it.
fn walk(dir: &Path) -> Vec<String> {
    let mut out = Vec::new();
    for e in fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(
                walk(&p)
                    .into_iter()
                    .map(|f| format!("{}/{f}", p.file_name().unwrap().to_string_lossy())),
            );
        } else {
            out.push(p.file_name().unwrap().to_string_lossy().into_owned());
        }
    }
    out
}
