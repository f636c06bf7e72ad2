//! Checkpoints: round trips, foreign files, disagreeing shapes, the first
//! format, what a run never writes.

use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use sdfl_runtime::train::checkpoint::*;
use sdfl_runtime::train::export_names::Piece;
use sdfl_runtime::train::frame::ModelFrame;
use sdfl_runtime::train::log::{HeldOut, History};
use serde_json::Value;
use std::collections::HashMap;
use std::path::Path;

#[test]
fn checks_what_a_run_never_writes() {
    let good = Checkpoint {
        step: 2,
        adam_steps: 2,
        params: vec![ParamState {
            name: "torus.major".into(),
            values: vec![1.0, 2.0],
            adam_m: vec![0.1, -0.2],
            adam_v: vec![1e-3, 0.0],
        }],
        pieces: Vec::new(),
        model: Value::Null,
        frame: ModelFrame::default(),
        losses: vec![0.5, 0.25],
        state: vec![("occupancy.ema".into(), vec![0.0, 3.5])],
        fingerprint: Default::default(),
        history: History {
            seconds: 2.0,
            held_out: vec![HeldOut {
                step: 2,
                seconds: 1.5,
                psnr: f64::INFINITY,
                ssim: 1.0,
                views: 1,
                psnr_in_mask: Some(24.25),
            }],
        },
    };
    good.check(2).unwrap();
    type Tamper = fn(&mut Checkpoint);
    let cases: Vec<(Tamper, &str)> = vec![
        (
            |c| c.params[0].values[1] = f32::NAN,
            "`torus.major`[1] is NaN",
        ),
        (
            |c| c.params[0].adam_m[0] = f32::INFINITY,
            "first moment) is inf",
        ),
        (
            |c| c.params[0].adam_v[0] = -1e-3,
            "second moment) is -0.001",
        ),
        (
            |c| c.params[0].adam_v.pop().map(drop).unwrap_or(()),
            "holds 2 values but 2 and 1 Adam moments",
        ),
        (
            |c| c.params[0].values.pop().map(drop).unwrap_or(()),
            "holds 1 values but 2 and 2 Adam moments",
        ),
        (|c| c.losses[0] = f32::NAN, "loss of step 1 is NaN"),
        (|c| c.losses[1] = -1.0, "loss of step 2 is -1"),
        (|c| c.step = 1 << 62, "past this run's 2 steps"),
        (|c| c.step = 1, "2 losses for 1 steps"),
        (|c| c.adam_steps = -1, "Adam's step count -1"),
        (|c| c.state[0].1[1] = f32::NAN, "`occupancy.ema`[1] is NaN"),
        (|c| c.history.seconds = -1.0, "training time is -1 s"),
        (|c| c.history.held_out[0].step = 3, "score of step 3"),
        (|c| c.history.held_out[0].psnr = f64::NAN, "PSNR NaN"),
        (|c| c.history.held_out[0].seconds = 9.0, "9 s"),
        (
            |c| c.history.held_out[0].psnr_in_mask = Some(f64::NAN),
            "held-out score of step",
        ),
    ];
    for (tamper, says) in cases {
        let mut c = good.clone();
        tamper(&mut c);
        let e = c.check(2).unwrap_err();
        assert!(e.contains(says), "{says}: {e}");
    }
}

fn sample() -> Checkpoint {
    Checkpoint {
        step: 2,
        adam_steps: 2,
        params: vec![
            ParamState {
                name: "torus.major".into(),
                values: vec![1.0, 2.0],
                adam_m: vec![0.1, -0.2],
                adam_v: vec![1e-3, 2e-3],
            },
            // A 3 × 2 (in, out) weight stored (out, in), and a bias.
            ParamState {
                name: "trunk.0.weight".into(),
                values: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
                adam_m: vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5],
                adam_v: vec![6.0, 5.0, 4.0, 3.0, 2.0, 1.0],
            },
        ],
        pieces: vec![
            Vec::new(),
            vec![Piece {
                name: "layer.weight".into(),
                shape: vec![2, 3],
                transposed: true,
            }],
        ],
        model: serde_json::json!({ "kind": "test" }),
        frame: ModelFrame {
            data_to_model: sdfl_runtime::data::normalize::SceneFrame::new(
                0.25,
                glam::DVec3::new(3.0, -1.0, 0.5),
                // A quarter turn about z: exact in JSON.
                glam::DMat3::from_cols_array(&[0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
            ),
            warp: Some(sdfl_stdlib::value::Unbounded::Contract(
                sdfl_stdlib::value::Contraction {
                    min: [-1.0; 3],
                    max: [1.0; 3],
                },
            )),
            background: sdfl_runtime::train::frame::Behind::Color([1.0, 1.0, 1.0]),
            cameras: vec![sdfl_runtime::train::frame::TrainingCamera {
                eye: glam::DVec3::new(0.5, 1.0, -3.0),
                at: glam::DVec3::ZERO,
                up: glam::DVec3::Y,
                focal: 1.25,
            }],
        },
        losses: vec![0.5, 0.25],
        state: vec![("occupancy.ema".into(), vec![0.0, 3.5, 1e-30])],
        fingerprint: ["a".into(), "b".into(), "c".into(), "d".into()],
        history: History {
            seconds: 12.25,
            held_out: vec![
                HeldOut {
                    step: 1,
                    seconds: 0.5,
                    psnr: 21.5,
                    ssim: 0.75,
                    views: 3,
                    psnr_in_mask: Some(31.5),
                },
                HeldOut {
                    step: 2,
                    seconds: 12.0,
                    psnr: f64::INFINITY,
                    ssim: 1.0,
                    views: 200,
                    psnr_in_mask: None,
                },
            ],
        },
    }
}

/// The tensors by name with their shapes, as any safetensors reader
/// sees them.
fn stored(path: &Path) -> Vec<(String, Vec<usize>, Vec<f32>)> {
    let bytes = std::fs::read(path).unwrap();
    let t = SafeTensors::deserialize(&bytes).unwrap();
    let mut v: Vec<_> = t
        .tensors()
        .into_iter()
        .map(|(n, x)| {
            let f = x
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            (n, x.shape().to_vec(), f)
        })
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

#[test]
fn round_trips_and_rejects_foreign_files() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ck.safetensors");
    let ck = sample();
    ck.write(&path).unwrap();
    let back = Checkpoint::read(&path).unwrap();
    let mut want = ck.clone();
    want.pieces[0] = vec![Piece::flat("torus.major", 2)];
    assert_eq!(back, want);
    // The header alone gives the same frame, training cameras and all.
    assert_eq!(Checkpoint::read_frame(&path).unwrap(), ck.frame);
    assert_eq!(ck.frame.cameras.len(), 1);
    // Weights as (out, in): row o holds the inputs' weights of output o.
    let t = stored(&path);
    let find = |n: &str| t.iter().find(|x| x.0 == n).unwrap().clone();
    assert_eq!(find("layer.weight").1, vec![2, 3]);
    assert_eq!(find("layer.weight").2, vec![1.0, 3.0, 5.0, 2.0, 4.0, 6.0]);
    assert_eq!(
        find("adam.m.layer.weight").2,
        vec![0.0, 1.0, 2.0, 0.5, 1.5, 2.5]
    );
    assert_eq!(find("adam.v.torus.major").2, vec![1e-3, 2e-3]);
    assert_eq!(find("train.losses").2, vec![0.5, 0.25]);
    assert_eq!(find("state.occupancy.ema").1, vec![3]);
    let other = ["a".to_string(), "x".into(), "c".into(), "y".into()];
    assert_eq!(
        back.differences(&other),
        vec!["data", "optimizer and objective"]
    );
    std::fs::write(&path, b"{\"iteration\": 3}").unwrap();
    let e = Checkpoint::read(&path).unwrap_err().to_string();
    assert!(e.contains("ck.safetensors"), "{e}");
}

/// A file whose tensor disagrees with its stated shape, or whose names
/// collide, is refused with the tensor named.
#[test]
fn refuses_shapes_that_disagree() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ck.safetensors");
    let mut ck = sample();
    ck.pieces[1][0].shape = vec![3, 2];
    ck.pieces[1][0].transposed = false;
    ck.write(&path).unwrap();
    // Rewrite the layout to claim (2, 3) over a (3, 2) tensor.
    let bytes = std::fs::read(&path).unwrap();
    let (_, header) = SafeTensors::read_metadata(&bytes).unwrap();
    let mut meta = header.metadata().clone().unwrap();
    let layout = meta["layout"].replace("[3,2],\"transposed\":false", "[2,3],\"transposed\":true");
    assert_ne!(layout, meta["layout"]);
    meta.insert("layout".into(), layout);
    let t = SafeTensors::deserialize(&bytes).unwrap();
    let bytes = safetensors::serialize(t.tensors(), &Some(meta)).unwrap();
    std::fs::write(&path, bytes).unwrap();
    let e = Checkpoint::read(&path).unwrap_err().to_string();
    assert!(
        e.contains("`layer.weight` has shape [3, 2], its layout says [2, 3]"),
        "{e}"
    );
    // A history that is not the stored form is refused by name.
    // The sample checkpoint written with one metadata key rewritten.
    let rewritten = |key: &str, edit: &dyn Fn(&str) -> String| {
        sample().write(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let (_, header) = SafeTensors::read_metadata(&bytes).unwrap();
        let mut meta = header.metadata().clone().unwrap();
        let value = edit(&meta[key]);
        assert_ne!(value, meta[key], "the edit changes `{key}`");
        meta.insert(key.into(), value);
        let t = SafeTensors::deserialize(&bytes).unwrap();
        std::fs::write(
            &path,
            safetensors::serialize(t.tensors(), &Some(meta)).unwrap(),
        )
        .unwrap();
    };
    rewritten(HISTORY, &|h| {
        assert!(h.contains("\"inf\""), "{h}");
        "{\"seconds\": 1}".into()
    });
    let e = Checkpoint::read(&path).unwrap_err().to_string();
    assert!(e.contains("bad `history`"), "{e}");
    // So is a frame that is no similarity (every key's checks are
    // frame.rs's): an error naming the file and the key.
    rewritten("data_to_model", &|f| {
        f.replace("\"scale\":0.25", "\"scale\":-0.25")
    });
    let e = Checkpoint::read(&path).unwrap_err().to_string();
    assert!(
        e.contains("ck.safetensors") && e.contains("bad `data_to_model`: its scale is -0.25"),
        "{e}"
    );
    let mut ck = sample();
    ck.pieces[1][0].name = "torus.major".into();
    let e = ck.write(&path).unwrap_err().to_string();
    assert!(e.contains("two tensors named `torus.major`"), "{e}");
}

/// A first-format file (flat `value.N` tensors) still resumes.
#[test]
fn reads_the_first_format() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("old.safetensors");
    let f = |v: &[f32]| f32_bytes(v);
    let bufs = [
        ("value.0", f(&[1.0, 2.0])),
        ("adam_m.0", f(&[0.1, 0.2])),
        ("adam_v.0", f(&[0.3, 0.4])),
        ("losses", f(&[0.5])),
        ("state.0", f(&[7.0])),
    ];
    let views: Vec<_> = bufs
        .iter()
        .map(|(n, b)| {
            (
                n.to_string(),
                TensorView::new(Dtype::F32, vec![b.len() / 4], b).unwrap(),
            )
        })
        .collect();
    let mut meta = HashMap::new();
    for (k, v) in [
        ("format", FORMAT_1),
        ("step", "1"),
        ("adam_steps", "1"),
        ("names", "[\"sphere.radius\"]"),
        ("state", "[\"occupancy.ema\"]"),
    ] {
        meta.insert(k.to_string(), v.to_string());
    }
    for p in PARTS {
        meta.insert(format!("fingerprint.{p}"), "f".into());
    }
    std::fs::write(&path, safetensors::serialize(views, &Some(meta)).unwrap()).unwrap();
    let ck = Checkpoint::read(&path).unwrap();
    assert_eq!(ck.params[0].name, "sphere.radius");
    assert_eq!(ck.params[0].adam_v, vec![0.3, 0.4]);
    assert_eq!(
        (ck.losses.clone(), ck.state.clone()),
        (vec![0.5], vec![("occupancy.ema".to_string(), vec![7.0])])
    );
    assert!(ck.pieces.is_empty());
    // Written before checkpoints kept a history: an empty one.
    assert_eq!(ck.history, History::default());
    // Written before checkpoints kept the model's frame: the data's.
    assert_eq!(ck.frame, ModelFrame::default());
}

/// The header-only read refuses what is no checkpoint, never panicking:
/// an empty or short file, a header longer than the file or than
/// safetensors allows, a header that is not JSON or has no metadata.
#[test]
fn the_frame_alone_is_read_from_a_header_checked_like_any_input() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.safetensors");
    let with_len = |len: u64, rest: &[u8]| {
        let mut b = len.to_le_bytes().to_vec();
        b.extend_from_slice(rest);
        b
    };
    let header = |rest: &[u8]| with_len(rest.len() as u64, rest);
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (Vec::new(), ""),
        (vec![1, 2, 3], ""),
        (with_len(64, b"{}"), "cut short"),
        (with_len(u64::MAX, b"{}"), "not a checkpoint"),
        (header(b"[1, 2"), "not JSON"),
        (header(b"{}"), "no metadata"),
        (
            header(br#"{"__metadata__": {"training_cameras": "{\"cameras\": 1}"}}"#),
            "bad `training_cameras`",
        ),
    ];
    for (bytes, says) in cases {
        std::fs::write(&path, &bytes).unwrap();
        let e = Checkpoint::read_frame(&path).unwrap_err().to_string();
        assert!(e.contains(says), "{bytes:?}: {e}");
    }
}
