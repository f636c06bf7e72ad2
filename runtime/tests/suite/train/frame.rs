//! The model frame: round trips, defaults, bad values refused.

use glam::{DMat3, DVec3};
use sdfl_runtime::data::normalize::SceneFrame;
use sdfl_runtime::train::frame::*;
use sdfl_stdlib::value::{Contraction, LearnedBackground, NdcFrame, Unbounded};
use serde_json::Value;
use std::collections::HashMap;

fn frames() -> Vec<ModelFrame> {
    let turn = DMat3::from_rotation_y(0.7) * DMat3::from_rotation_x(-1.2);
    vec![
        ModelFrame::default(),
        ModelFrame {
            data_to_model: SceneFrame::new(0.2857, DVec3::new(3.0, -2.5, 1e-3), turn),
            warp: Some(Unbounded::Contract(Contraction {
                min: [-1.5, -1.0, -2.0],
                max: [1.5, 1.25, 2.0],
            })),
            background: Behind::Learned(LearnedBackground {
                freqs: 4,
                width: 32,
            }),
            cameras: vec![
                TrainingCamera {
                    eye: DVec3::new(0.1, 2.0, -3.5),
                    at: DVec3::new(0.0, 0.25, 0.0),
                    up: DVec3::Y,
                    focal: 1.5,
                },
                TrainingCamera {
                    eye: DVec3::new(-4.0, 0.5, 1e-3),
                    at: DVec3::new(-3.0, 0.5, 1e-3),
                    up: DVec3::new(0.0, 0.0, 1.0),
                    focal: 0.71,
                },
            ],
        },
        ModelFrame {
            data_to_model: SceneFrame::new(1.0 / 3.0, DVec3::new(-7.0, 0.5, 2.0), turn),
            warp: Some(Unbounded::Ndc(Some(NdcFrame {
                width: 504.0,
                height: 378.0,
                fx: 407.5,
                fy: 407.25,
                near: 1.0,
            }))),
            background: Behind::Color([1.0, 0.5, 0.0]),
            cameras: Vec::new(),
        },
    ]
}

fn read(meta: &HashMap<String, String>) -> Result<ModelFrame, String> {
    ModelFrame::from_metadata(|k| meta.get(k).map(String::as_str))
}

/// Every value reads back exactly; a file without the keys is the
/// identity with nothing around it.
#[test]
fn round_trips_and_defaults() {
    for f in frames() {
        let meta: HashMap<String, String> = f.metadata().into_iter().collect();
        let back = read(&meta).unwrap();
        assert_eq!((back.warp, back.background), (f.warp, f.background));
        // The cameras' numbers are printed shortest-exact: they read back.
        assert_eq!(back.cameras, f.cameras);
        // serde_json parses a printed f64 to within an ulp (Python's
        // json exactly).
        let (a, b) = (&back.data_to_model, &f.data_to_model);
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-15 * y.abs().max(1.0);
        assert!(close(a.scale, b.scale), "{a:?} vs {b:?}");
        for i in 0..3 {
            assert!(close(a.center[i], b.center[i]), "{a:?} vs {b:?}");
            for j in 0..3 {
                assert!(close(a.rotation[i][j], b.rotation[i][j]), "{a:?} vs {b:?}");
            }
        }
    }
    assert_eq!(read(&HashMap::new()).unwrap(), ModelFrame::default());
    // The recorded map is the loader's: x_model = scale·R·(x − c).
    let f = &frames()[1].data_to_model;
    let meta: HashMap<String, String> = frames()[1].metadata().into_iter().collect();
    let v: Value = serde_json::from_str(&meta[DATA_TO_MODEL]).unwrap();
    let rows: [[f64; 3]; 3] = serde_json::from_value(v["rotation"].clone()).unwrap();
    let p = DVec3::new(0.3, -4.0, 2.5);
    let c = DVec3::from_array(vec3(&v, "center").unwrap());
    let q = p - c;
    let by_rows =
        DVec3::from_array(rows.map(|r| DVec3::from_array(r).dot(q))) * v["scale"].as_f64().unwrap();
    assert!((by_rows - f.to_scene(p)).length() < 1e-12);
}

/// Bad values are errors naming their key, never panics.
#[test]
fn refuses_bad_values() {
    let good: HashMap<String, String> = frames()[1].metadata().into_iter().collect();
    let cases = [
        (
            DATA_TO_MODEL,
            r#"{"scale": -1, "center": [0,0,0], "rotation": [[1,0,0],[0,1,0],[0,0,1]]}"#,
            "scale is -1",
        ),
        (
            DATA_TO_MODEL,
            r#"{"scale": 0, "center": [0,0,0], "rotation": [[1,0,0],[0,1,0],[0,0,1]]}"#,
            "scale is 0",
        ),
        (
            DATA_TO_MODEL,
            r#"{"scale": 1e300, "center": [0,0,0], "rotation": [[1,0,0],[0,1,0],[0,0,1]]}"#,
            "scale",
        ),
        (
            DATA_TO_MODEL,
            r#"{"scale": 1, "center": [0,null,0], "rotation": [[1,0,0],[0,1,0],[0,0,1]]}"#,
            "`center`",
        ),
        (
            DATA_TO_MODEL,
            r#"{"scale": 1, "center": [0,1e19,0], "rotation": [[1,0,0],[0,1,0],[0,0,1]]}"#,
            "beyond",
        ),
        (
            DATA_TO_MODEL,
            r#"{"scale": 1, "center": [0,0,0], "rotation": [[2,0,0],[0,1,0],[0,0,1]]}"#,
            "not a rotation",
        ),
        (
            DATA_TO_MODEL,
            r#"{"scale": 1, "center": [0,0,0], "rotation": [[1,0],[0,1]]}"#,
            "rotation",
        ),
        (DATA_TO_MODEL, "[1, 2", "not JSON"),
        (
            WARP,
            r#"{"kind": "contraction", "min": [1,0,0], "max": [0,1,1]}"#,
            "empty",
        ),
        (
            WARP,
            r#"{"kind": "ndc", "width": 10, "height": 10, "fx": -5, "fy": 5, "near": 1}"#,
            "fx -5",
        ),
        (
            WARP,
            r#"{"kind": "ndc", "width": 10, "height": 10, "fx": 5, "fy": 5}"#,
            "`near`",
        ),
        (WARP, r#"{"kind": "spherical"}"#, "unknown kind"),
        (
            BACKGROUND,
            r#"{"kind": "color", "color": [0, 2, 0]}"#,
            "within 0..1",
        ),
        (
            BACKGROUND,
            r#"{"kind": "learned", "freqs": 4, "width": 0}"#,
            "`width`",
        ),
        (BACKGROUND, r#"{"color": [0, 0, 0]}"#, "no `kind`"),
        (TRAINING_CAMERAS, r#"{"cameras": 3}"#, "not a list"),
        (
            TRAINING_CAMERAS,
            r#"{"cameras": [{"eye": [0,0,0], "at": [0,0,1], "up": [0,1,0], "focal": 0}]}"#,
            "camera 0: its focal length 0",
        ),
        (
            TRAINING_CAMERAS,
            r#"{"cameras": [{"eye": [1,2,3], "at": [1,2,3], "up": [0,1,0], "focal": 1}]}"#,
            "looks nowhere",
        ),
        (
            TRAINING_CAMERAS,
            r#"{"cameras": [{"eye": [0,0,0], "at": [0,2,0], "up": [0,1,0], "focal": 1}]}"#,
            "up along its view",
        ),
        (
            TRAINING_CAMERAS,
            r#"{"cameras": [{"eye": [0,0,0], "at": [0,0,1], "up": [0,0,0], "focal": 1}]}"#,
            "up along its view",
        ),
        (
            TRAINING_CAMERAS,
            r#"{"cameras": [{"eye": [0,1e300,0], "at": [0,0,1], "up": [0,1,0], "focal": 1}]}"#,
            "camera 0: `eye`",
        ),
        (
            TRAINING_CAMERAS,
            r#"{"cameras": [{"eye": [0,0,0], "up": [0,1,0], "focal": 1}]}"#,
            "`at`",
        ),
    ];
    for (key, value, says) in cases {
        let mut meta = good.clone();
        meta.insert(key.to_string(), value.to_string());
        let e = read(&meta).unwrap_err();
        assert!(
            e.contains(&format!("bad `{key}`")) && e.contains(says),
            "{key} {value}: {e}"
        );
    }
}

/// A run's views are recorded evenly spaced, at most
/// [`RECORDED_CAMERAS`], the first always; more in a file are refused.
#[test]
fn training_cameras_are_bounded() {
    let camera = |i: usize| {
        sdfl_stdlib::camera::Camera::look_at(
            DVec3::new(i as f64, 0.0, -3.0),
            DVec3::ZERO,
            DVec3::Y,
            1.2,
        )
    };
    for n in [0, 1, 7, RECORDED_CAMERAS, RECORDED_CAMERAS + 1, 1000] {
        let cams: Vec<_> = (0..n).map(camera).collect();
        let f = ModelFrame::default().with_cameras(cams.iter());
        assert!(
            f.cameras.len() <= RECORDED_CAMERAS,
            "{n}: {}",
            f.cameras.len()
        );
        assert!(
            n == 0 || f.cameras.len() * 4 >= RECORDED_CAMERAS.min(n) * 2,
            "{n}: {}",
            f.cameras.len()
        );
        if n > 0 {
            assert_eq!(f.cameras[0], TrainingCamera::of(&cams[0]));
        }
    }
    let one = r#"{"eye": [0,0,-3], "at": [0,0,0], "up": [0,1,0], "focal": 1}"#;
    let many = format!(
        r#"{{"cameras": [{}]}}"#,
        vec![one; RECORDED_CAMERAS + 1].join(",")
    );
    let meta: HashMap<String, String> = [(TRAINING_CAMERAS.to_string(), many)].into();
    let e = read(&meta).unwrap_err();
    assert!(e.contains("at most"), "{e}");
}
