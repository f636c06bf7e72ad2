//! Data sets written: complete or absent, with distortion and per-frame
//! intrinsics kept.

use sdfl_runtime::data::export::*;
use sdfl_runtime::data::nerf_synthetic::{read_transforms, transforms_path};
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::lens::{Distortion, Intrinsics};
use sdfl_stdlib::outputs::DATASET_JSON;
use serde_json::{json, Value};
use std::path::Path;

fn camera() -> Camera {
    Camera::look_at(
        glam::DVec3::new(0.0, 0.0, -3.0),
        glam::DVec3::ZERO,
        glam::DVec3::Y,
        1.0,
    )
}

/// A data set is moved into place only once complete: half-written,
/// nothing of it is where readers look, and an earlier set there still
/// loads. Each file moved over an earlier set while it is replaced says
/// so, and such a file refuses to load. Once finished every split loads
/// and nothing is left beside it.
#[test]
fn a_data_set_appears_only_once_complete() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    let set = out.join("set");
    let rgb = vec![128u8; 4 * 4 * 3];
    let mut w = DatasetWriter::new(out, Path::new("set"), (4, 4), 3, 1, 0);
    w.push(0, &camera(), &rgb, None).unwrap();
    for name in DATASET_JSON.iter().chain(&["r_0.png"]) {
        assert!(!set.join(name).exists(), "{name}");
    }
    w.push(1, &camera(), &rgb, None).unwrap();
    w.push(2, &camera(), &rgb, None).unwrap();
    w.finish().unwrap();
    let count = |split| {
        read_transforms(&transforms_path(&set, split))
            .unwrap()
            .frames
            .len()
    };
    assert_eq!((count("train"), count("val"), count("test")), (2, 1, 1));
    assert_eq!(
        read_transforms(&set.join("transforms.json"))
            .unwrap()
            .frames
            .len(),
        3
    );
    assert!(!set.join(STAGING).exists());
    // A rewrite stopped half-way (its writer dropped) leaves it loading.
    let mut w = DatasetWriter::new(out, Path::new("set"), (4, 4), 3, 1, 0);
    w.push(0, &camera(), &rgb, None).unwrap();
    assert!(set.join(STAGING).join("r_0.png").exists());
    drop(w);
    assert_eq!(count("train"), 2);
    assert!(!set.join(STAGING).exists());
    // What a stop during the moves leaves refuses to load.
    let marker = format!("{{\"{INCOMPLETE}\": true}}");
    std::fs::write(set.join("transforms.json"), marker).unwrap();
    let err = read_transforms(&set.join("transforms.json"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("stopped while it wrote"), "{err}");
}

fn doc<'a>(docs: &'a [(&str, Value)], name: &str) -> &'a Value {
    &docs.iter().find(|d| d.0 == name).unwrap().1
}

/// Distorted views write their model's keys only, at the top when the
/// views share them, per frame when they differ.
#[test]
fn distortion_and_per_frame_intrinsics() {
    let dir = tempfile::tempdir().unwrap();
    let rgb = vec![0u8; 6 * 4 * 3];
    let c2w = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 2.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let base = Intrinsics {
        width: 6,
        height: 4,
        fx: 5.0,
        fy: 5.5,
        cx: 3.25,
        cy: 1.75,
        distortion: Distortion::OpenCv {
            k1: -0.1,
            k2: 0.01,
            p1: 1e-3,
            p2: -2e-3,
        },
    };
    let mut w = DatasetWriter::new(dir.path(), Path::new("a"), (6, 4), 2, 0, 0);
    w.push_view(0, c2w, base, &rgb, None).unwrap();
    w.push_view(1, c2w, base, &rgb, None).unwrap();
    let docs = w.documents();
    let t = doc(&docs, "transforms.json");
    assert_eq!(t["camera_model"], "OPENCV");
    assert_eq!(
        (t["k1"].as_f64(), t["p2"].as_f64()),
        (Some(-0.1), Some(-2e-3))
    );
    assert!(t.get("k3").is_none() && t.get("is_fisheye").is_none());
    assert!(t["frames"][0].get("fl_x").is_none());
    // Nothing held out: val and test list every view.
    assert_eq!(t["val_filenames"], json!(["r_0.png", "r_1.png"]));
    assert_eq!(
        doc(&docs, "transforms_test.json")["frames"]
            .as_array()
            .unwrap()
            .len(),
        2
    );

    let fish = Intrinsics {
        distortion: Distortion::Fisheye {
            k1: 0.1,
            k2: 0.0,
            k3: -0.01,
            k4: 0.0,
        },
        ..base
    };
    let mut w = DatasetWriter::new(dir.path(), Path::new("b"), (6, 4), 2, 1, 7);
    w.push_view(0, c2w, fish, &rgb, None).unwrap();
    w.push_view(1, c2w, Intrinsics { fx: 6.0, ..fish }, &rgb, None)
        .unwrap();
    let docs = w.documents();
    let t = doc(&docs, "transforms.json");
    assert_eq!(t["camera_model"], "OPENCV_FISHEYE");
    assert!(t.get("fl_x").is_none() && t.get("k1").is_none());
    let f1 = &t["frames"][1];
    assert_eq!(
        (f1["fl_x"].as_f64(), f1["k3"].as_f64()),
        (Some(6.0), Some(-0.01))
    );
    assert_eq!(f1["is_fisheye"], true);
    assert!(f1.get("p1").is_none());
    // A mixed set is refused.
    let err = w.push_view(2, c2w, base, &rgb, None).unwrap_err();
    assert!(err.to_string().contains("one `camera_model`"), "{err}");
    // A pinhole view beside distorted ones gets zeros under OPENCV.
    let mut w = DatasetWriter::new(dir.path(), Path::new("c"), (6, 4), 2, 0, 0);
    w.push_view(0, c2w, base, &rgb, None).unwrap();
    w.push_view(
        1,
        c2w,
        Intrinsics {
            distortion: Distortion::None,
            ..base
        },
        &rgb,
        None,
    )
    .unwrap();
    let docs = w.documents();
    let f1 = &doc(&docs, "transforms.json")["frames"][1];
    assert_eq!(
        (f1["k1"].as_f64(), f1["p1"].as_f64()),
        (Some(0.0), Some(0.0))
    );
}
