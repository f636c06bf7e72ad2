//! Checkpoints describe themselves (docs/checkpoints.md): a tiny NeRF
//! (harmonic, view-dependent with a skip; and a hash grid) trains a few
//! steps, and its checkpoint is read back as any safetensors reader would,
//! by tensor name and shape and the `__metadata__` only, with no sdfl code.
//! The network is evaluated in f64 from those tensors exactly as the
//! PyTorch snippets in docs/checkpoints.md do (spec from `model`, linear
//! layers `x @ W.T + b` with `W` as (out, in); points and directions in
//! the data's frame taken into the model's by `data_to_model`, then
//! through `warp`), and must give sdfl's own densities, colours and
//! distances to f32 rounding. Models trained on a normalised capture
//! (moved, turned and scaled) with scene contraction and a learned
//! background, and neural SDFs (a surface on that capture, a point fit
//! on centred points), are checked at points of the data's own frame.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde_json::Value;

use glam::DVec3;
use sdfl_lang::SourceFile;
use sdfl_runtime::data::normalize::SceneFrame;
use sdfl_runtime::jobs::{run_train_job, TrainOptions, TrainReport};
use sdfl_runtime::neural::background::{Backdrop, BackdropWork};
use sdfl_runtime::neural::nerf::{NerfNet, NerfWork};
use sdfl_runtime::neural::surface::{Levels, SurfaceSdf};
use sdfl_runtime::train::checkpoint::Checkpoint;
use sdfl_runtime::volume::Ray;
use sdfl_stdlib::value::{Field, Unbounded};

const SCENE: &str = r#"
let cams = orbit(radius: 2.5, up: [0, 1, 0], focal: 1, views: 6)
let truth = volsdf(sphere(radius: 0.6), alpha: 10, beta: 0.05)
train tiny {
  model: MODEL,
  data: render_views(truth, cameras: cams, size: [12, 12], sampler: stratified(samples: 24, near: 1, far: 4)),
  sampler: stratified(samples: 16, near: 1, far: 4, jitter: true),
  rays: 64,
  optimizer: adam(lr: 1e-2),
  iterations: 3,
  checkpoint: "tiny.ckpt",
}
"#;

/// A safetensors file as its format defines it: an 8-byte little-endian
/// header length, a JSON header (`dtype`, `shape`, `data_offsets` per
/// tensor, `__metadata__`), then the bytes.
struct File {
    tensors: HashMap<String, (Vec<usize>, Vec<f64>)>,
    meta: HashMap<String, String>,
}

fn read_safetensors(path: &Path) -> File {
    let bytes = std::fs::read(path).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Map<String, Value> = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let data = &bytes[8 + n..];
    let mut tensors = HashMap::new();
    let mut meta = HashMap::new();
    for (name, v) in header {
        if name == "__metadata__" {
            for (k, s) in v.as_object().unwrap() {
                meta.insert(k.clone(), s.as_str().unwrap().to_string());
            }
            continue;
        }
        assert_eq!(v["dtype"], "F32", "{name}");
        let shape: Vec<usize> = serde_json::from_value(v["shape"].clone()).unwrap();
        let [a, b]: [usize; 2] = serde_json::from_value(v["data_offsets"].clone()).unwrap();
        let values: Vec<f64> = data[a..b]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64)
            .collect();
        assert_eq!(values.len(), shape.iter().product::<usize>(), "{name}");
        tensors.insert(name, (shape, values));
    }
    File { tensors, meta }
}

fn activate(act: &Value, z: f64) -> f64 {
    match act {
        Value::String(s) if s == "relu" => z.max(0.0),
        Value::String(s) if s == "sigmoid" => 1.0 / (1.0 + (-z).exp()),
        Value::String(s) if s == "identity" => z,
        Value::Object(m) if m.contains_key("softplus") => {
            // ln(1 + e^(βz))/β without overflow far from the origin.
            let beta = m["softplus"]["beta"].as_f64().unwrap();
            let bz = beta * z;
            (bz.max(0.0) + (-bz.abs()).exp().ln_1p()) / beta
        }
        Value::Object(m) if m.contains_key("exp") => z.min(m["exp"]["cap"].as_f64().unwrap()).exp(),
        a => panic!("unknown activation {a}"),
    }
}

/// The position or direction encoding of `x` as the spec says.
fn encode(spec: &Value, x: [f64; 3], file: &File, prefix: &str) -> Vec<f64> {
    match spec["kind"].as_str().unwrap() {
        "harmonic" => {
            let f = spec["freqs"].as_u64().unwrap() as usize;
            let mut out = vec![0.0; 6 * f];
            for i in 0..3 {
                for k in 0..f {
                    let y = x[i] * (1u64 << k) as f64;
                    out[i * f + k] = y.sin();
                    out[3 * f + i * f + k] = y.cos();
                }
            }
            if spec["include_input"].as_bool().unwrap() {
                out.extend(x);
            }
            out
        }
        "hash_grid" => {
            let f = spec["features"].as_u64().unwrap() as usize;
            let (lo, hi): ([f64; 3], [f64; 3]) = (
                serde_json::from_value(spec["bounds"][0].clone()).unwrap(),
                serde_json::from_value(spec["bounds"][1].clone()).unwrap(),
            );
            let primes: Vec<u32> = serde_json::from_value(spec["primes"].clone()).unwrap();
            let u: Vec<f64> = (0..3)
                .map(|a| ((x[a] - lo[a]) / (hi[a] - lo[a])).clamp(0.0, 1.0))
                .collect();
            let mut out = Vec::new();
            for (l, res) in spec["resolutions"].as_array().unwrap().iter().enumerate() {
                let res = res.as_u64().unwrap() as u32;
                let dense = spec["dense"][l].as_bool().unwrap();
                let (shape, table) = &file.tensors[&format!("{prefix}hashgrid.level{l}.table")];
                assert_eq!(shape[1], f);
                let rows = shape[0] as u32;
                let mut cell = [0u32; 3];
                let mut frac = [0f64; 3];
                for a in 0..3 {
                    let p = u[a] * res as f64;
                    cell[a] = (p.floor() as u32).min(res - 1);
                    frac[a] = p - cell[a] as f64;
                }
                let mut acc = vec![0.0; f];
                for c in 0..8u32 {
                    let v: Vec<u32> = (0..3).map(|a| cell[a] + (c >> a & 1)).collect();
                    let row = if dense {
                        v[0] + v[1] * (res + 1) + v[2] * (res + 1) * (res + 1)
                    } else {
                        (v[0].wrapping_mul(primes[0])
                            ^ v[1].wrapping_mul(primes[1])
                            ^ v[2].wrapping_mul(primes[2]))
                            % rows
                    } as usize;
                    let w: f64 = (0..3)
                        .map(|a| {
                            if c >> a & 1 == 1 {
                                frac[a]
                            } else {
                                1.0 - frac[a]
                            }
                        })
                        .product();
                    for k in 0..f {
                        acc[k] += w * table[row * f + k];
                    }
                }
                out.extend(acc);
            }
            out
        }
        k => panic!("unknown encoding {k}"),
    }
}

/// What the file says about its frame: `x_model = scale·R·(x_data − c)`
/// and the warp into the encoding (identity and none when absent).
struct Placement {
    scale: f64,
    center: [f64; 3],
    rotation: [[f64; 3]; 3],
    warp: Value,
}

fn placement(file: &File) -> Placement {
    let json = |k: &str, default: &str| -> Value {
        serde_json::from_str(file.meta.get(k).map_or(default, String::as_str)).unwrap()
    };
    let m = json(
        "data_to_model",
        r#"{"scale": 1, "center": [0, 0, 0], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}"#,
    );
    Placement {
        scale: m["scale"].as_f64().unwrap(),
        center: serde_json::from_value(m["center"].clone()).unwrap(),
        rotation: serde_json::from_value(m["rotation"].clone()).unwrap(),
        warp: json("warp", r#"{"kind": "none"}"#),
    }
}

impl Placement {
    /// `R·v`, rows of `rotation`.
    fn turn(&self, v: [f64; 3]) -> [f64; 3] {
        self.rotation
            .map(|r| r[0] * v[0] + r[1] * v[1] + r[2] * v[2])
    }

    /// A data-frame point in the model's frame.
    fn point(&self, x: [f64; 3]) -> [f64; 3] {
        self.turn(std::array::from_fn(|a| x[a] - self.center[a]))
            .map(|v| self.scale * v)
    }

    /// A data-frame unit direction in the model's frame: turned only.
    fn direction(&self, d: [f64; 3]) -> [f64; 3] {
        let v = self.turn(d);
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|x| x / n)
    }

    /// A model-frame point as the encoding sees it.
    fn warped(&self, x: [f64; 3]) -> [f64; 3] {
        let w = &self.warp;
        let v3 = |k: &str| -> [f64; 3] { serde_json::from_value(w[k].clone()).unwrap() };
        let num = |k: &str| w[k].as_f64().unwrap();
        match w["kind"].as_str().unwrap() {
            "none" => x,
            "contraction" => {
                let (lo, hi) = (v3("min"), v3("max"));
                let y: [f64; 3] =
                    std::array::from_fn(|a| (x[a] - 0.5 * (lo[a] + hi[a])) * 2.0 / (hi[a] - lo[a]));
                let m = y.iter().fold(0f64, |m, v| m.max(v.abs())).max(1.0);
                y.map(|v| (2.0 - 1.0 / m) * v / m)
            }
            "ndc" => {
                let z = x[2].min(-1e-3 * num("near"));
                [
                    -2.0 * num("fx") / num("width") * x[0] / z,
                    -2.0 * num("fy") / num("height") * x[1] / z,
                    1.0 + 2.0 * num("near") / z,
                ]
            }
            k => panic!("unknown warp {k}"),
        }
    }
}

/// Which of the recipe's steps to take: the default (`DATA`) takes points
/// and directions in the data's frame; the others leave a step out, to
/// show that the comparison would notice.
#[derive(Clone, Copy)]
struct Steps {
    /// Apply `data_to_model` (and give densities and distances per unit
    /// of the data's length).
    transform: bool,
    /// Apply `warp`.
    warp: bool,
}

const DATA: Steps = Steps {
    transform: true,
    warp: true,
};

/// The layers of `layers` from `values` (the encoded inputs), weights
/// `{prefix}{name}.weight` (out, in) and biases from the file.
fn run_layers(file: &File, prefix: &str, layers: &Value, values: &mut HashMap<String, Vec<f64>>) {
    for layer in layers.as_array().unwrap() {
        let name = layer["name"].as_str().unwrap();
        let input: Vec<f64> = layer["inputs"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|i| values[i.as_str().unwrap()].clone())
            .collect();
        let (ws, w) = &file.tensors[&format!("{prefix}{name}.weight")];
        let (_, b) = &file.tensors[&format!("{prefix}{name}.bias")];
        let (out, inp) = (ws[0], ws[1]);
        assert_eq!(inp, input.len(), "{name}");
        let y = (0..out)
            .map(|o| {
                let z: f64 = (0..inp).map(|i| w[o * inp + i] * input[i]).sum::<f64>() + b[o];
                activate(&layer["activation"], z)
            })
            .collect();
        values.insert(name.to_string(), y);
    }
}

/// Density and colour at `x` seen along `d` (the data's frame unless
/// `steps` leaves the transform out), from the file alone.
fn evaluate(file: &File, x: [f64; 3], d: [f64; 3], steps: Steps) -> (f64, [f64; 3]) {
    let model: Value = serde_json::from_str(&file.meta["model"]).unwrap();
    let at = placement(file);
    let (mut x, mut d, mut per_length) = (x, d, 1.0);
    if steps.transform {
        (x, d, per_length) = (at.point(x), at.direction(d), at.scale);
    }
    if steps.warp {
        x = at.warped(x);
    }
    let prefix = if model["networks"][0] == "" {
        ""
    } else {
        "coarse."
    };
    let mut values: HashMap<String, Vec<f64>> = HashMap::new();
    values.insert(
        "position".into(),
        encode(&model["position_encoding"], x, file, prefix),
    );
    if !model["direction_encoding"].is_null() {
        values.insert(
            "direction".into(),
            encode(&model["direction_encoding"], d, file, prefix),
        );
    }
    run_layers(file, prefix, &model["layers"], &mut values);
    let c = &values["color.1"];
    // A density is per unit length: one of the model's is `scale` of the data's.
    (values["density"][0] * per_length, [c[0], c[1], c[2]])
}

/// A learned background's colour for a ray along `d` (the data's frame).
fn background(file: &File, d: [f64; 3]) -> [f64; 3] {
    let model: Value = serde_json::from_str(&file.meta["model"]).unwrap();
    let record: Value = serde_json::from_str(&file.meta["background"]).unwrap();
    assert_eq!(record["kind"], "learned");
    let d = placement(file).direction(d);
    let mut values = HashMap::new();
    values.insert(
        "background_direction".to_string(),
        encode(&model["background_direction_encoding"], d, file, ""),
    );
    run_layers(file, "", &model["background_layers"], &mut values);
    let c = &values["background.out"];
    [c[0], c[1], c[2]]
}

/// A neural SDF's (or a neural surface's) distance at `x`, in the data's
/// units and frame unless `steps` leaves the transform out.
fn distance(file: &File, x: [f64; 3], steps: Steps) -> f64 {
    let model: Value = serde_json::from_str(&file.meta["model"]).unwrap();
    let spec = if model["kind"] == "neural_surface" {
        &model["sdf"]
    } else {
        &model
    };
    assert_eq!(spec["kind"], "neural_sdf");
    let prefix = spec["prefix"].as_str().unwrap();
    let at = placement(file);
    assert_eq!(at.warp["kind"], "none", "neural SDFs are not warped");
    let y = if steps.transform { at.point(x) } else { x };
    let mut values = HashMap::new();
    values.insert(
        "position".to_string(),
        encode(&spec["position_encoding"], y, file, prefix),
    );
    run_layers(file, prefix, &spec["layers"], &mut values);
    let mut f = values["output"][0];
    if let Some(s) = spec.get("sphere") {
        let c: [f64; 3] = serde_json::from_value(s["center"].clone()).unwrap();
        let r = s["radius"].as_f64().unwrap();
        f += (0..3).map(|a| (y[a] - c[a]).powi(2)).sum::<f64>().sqrt() - r;
    }
    // One unit of the model's length is 1/scale of the data's.
    if steps.transform {
        f / at.scale
    } else {
        f
    }
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-ckfmt-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Trains `model` 3 steps; checks the file's names, shapes and metadata,
/// and the f64 evaluation against sdfl's forward pass at 64 points.
fn check(name: &str, model: &str, expect: &[(&str, Vec<usize>)]) {
    let src = SCENE.replace("MODEL", model);
    let job = sdfl_stdlib::load(&SourceFile::new("tiny.sdfl", src))
        .unwrap()
        .trains[0]
        .clone();
    let out = temp(name);
    let opts = TrainOptions { restart: false };
    run_train_job(&job, &out, Path::new("."), None, opts, &|_| {}).unwrap();
    let path = out.join("tiny.ckpt");
    let file = read_safetensors(&path);
    assert_eq!(file.meta["format"], "sdfl-checkpoint-2");
    assert_eq!(file.meta["sdfl_version"], env!("CARGO_PKG_VERSION"));
    for (n, shape) in expect {
        let got = file.tensors.get(*n).map(|t| t.0.clone());
        assert_eq!(got.as_ref(), Some(shape), "{name}: tensor {n}");
        let adam = format!("adam.m.{n}");
        assert_eq!(
            file.tensors.get(&adam).map(|t| t.0.clone()).as_ref(),
            Some(shape),
            "{adam}"
        );
    }
    assert_eq!(file.tensors["train.losses"].0, vec![3]);
    // Rendered data: the model's frame is the data's, nothing warps it.
    let at = placement(&file);
    assert_eq!((at.scale, at.center), (1.0, [0.0; 3]));
    assert_eq!(at.warp["kind"], "none");

    // sdfl's own forward pass at the same weights.
    let sdfl_stdlib::value::Field::Nerf(spec) = &*job.model else {
        panic!("a NeRF")
    };
    let flat: Vec<f32> = Checkpoint::read(&path)
        .unwrap()
        .params
        .iter()
        .flat_map(|p| p.values.clone())
        .collect();
    let net = NerfNet::new(spec);
    let mut rng = 0x1234_5678u64;
    let mut next = || {
        rng = rng
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let n = 64;
    let mut points = Vec::new();
    let mut dirs = Vec::new();
    for _ in 0..n {
        let p: [f64; 3] = [next() * 2.4 - 1.2, next() * 2.4 - 1.2, next() * 2.4 - 1.2];
        let d = [next() - 0.5, next() - 0.5, next() - 0.5];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-3);
        points.extend(p.map(|v| v as f32));
        dirs.extend(d.map(|v| (v / len) as f32));
    }
    let mut work = NerfWork::default();
    net.forward(&flat, &points, &dirs, &mut work);
    let mut worst = 0f64;
    for s in 0..n {
        let p = std::array::from_fn(|a| points[3 * s + a] as f64);
        let d = std::array::from_fn(|a| dirs[3 * s + a] as f64);
        let (sigma, rgb) = evaluate(&file, p, d, DATA);
        let ours = work.sigma[s] as f64;
        let err = (sigma - ours).abs() / ours.abs().max(1.0);
        worst = worst.max(err);
        assert!(
            err < 1e-4,
            "{name} sample {s}: density {sigma} from the file, sdfl {ours}"
        );
        for c in 0..3 {
            let ours = work.rgb[3 * s + c] as f64;
            assert!(
                (rgb[c] - ours).abs() < 1e-5,
                "{name} sample {s}: colour {rgb:?} vs sdfl {ours}"
            );
        }
    }
    // Some densities are not zero, so the comparison saw the network.
    assert!(
        work.sigma.iter().any(|&s| s > 1e-3),
        "{name}: all densities ~0"
    );
    eprintln!("{name}: worst relative density difference {worst:e}");
    // For running the PyTorch snippet of docs/checkpoints.md by hand: the
    // file, and the points with sdfl's densities and colours.
    if let Some(dump) = std::env::var_os("SDFL_CHECKPOINT_DUMP") {
        let dump = Path::new(&dump);
        std::fs::create_dir_all(dump).unwrap();
        std::fs::copy(&path, dump.join(format!("{name}.ckpt"))).unwrap();
        let doc = serde_json::json!({
            "points": points, "dirs": dirs, "sigma": work.sigma[..n], "rgb": work.rgb[..3 * n],
        });
        std::fs::write(dump.join(format!("{name}.json")), doc.to_string()).unwrap();
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_harmonic_nerf_checkpoint_evaluates_from_its_tensors() {
    check(
        "harmonic",
        "nerf(position: harmonic(freqs: 3), direction: harmonic(freqs: 2), layers: 3, width: 16, skips: [2], color_width: 8, density: \"softplus\")",
        &[
            ("trunk.0.weight", vec![16, 21]),
            ("trunk.0.bias", vec![16]),
            ("trunk.2.weight", vec![16, 16 + 21]),
            ("density.weight", vec![1, 16]),
            ("feature.weight", vec![16, 16]),
            ("color.0.weight", vec![8, 16 + 15]),
            ("color.1.weight", vec![3, 8]),
            ("color.1.bias", vec![3]),
        ],
    );
}

#[test]
fn a_hash_grid_nerf_checkpoint_evaluates_from_its_tensors() {
    check(
        "hashgrid",
        "nerf(position: hashgrid(levels: 4, log2_table: 8, min_res: 4, max_res: 32, min: [-1.2, -1.2, -1.2], max: [1.2, 1.2, 1.2]), layers: 1, width: 16, skips: [], color_width: 8, view_dependent: false, density: \"exp\")",
        &[
            // 5³ = 125 vertices fit 256 rows: dense; 32 + 1 cubed do not.
            ("hashgrid.level0.table", vec![125, 2]),
            ("hashgrid.level3.table", vec![256, 2]),
            ("trunk.0.weight", vec![16, 8]),
            ("density.weight", vec![1, 16]),
            ("color.0.weight", vec![8, 16]),
        ],
    );
}

/// A data set written by a `render` statement, read back by `capture(...)`.
struct Set {
    /// The statement writing it.
    scene: &'static str,
    /// The `data` that reads it.
    data: &'static str,
    /// A NeRF's sampler on it.
    sampler: &'static str,
    /// Its ball's centre in the data's frame.
    ball: [f64; 3],
    /// The NeRFs' warp and its kind in the metadata.
    warp: (&'static str, &'static str),
    /// Points are checked in front of this plane (`z = −ahead`).
    ahead: Option<f64>,
}

/// A ball far from the origin, seen by cameras around it at about four
/// times its radius, written in nerfstudio's layout: `capture(...)` reads
/// it centred on the cameras, turned (their mean up, +y, onto +z) and
/// scaled about eightfold down, so model and data frames differ in all
/// three ways.
const AROUND: Set = Set {
    scene: r#"
let c = [10, -4, 6]
render set {
  scene: sphere(2, center: c),
  camera: [look_at(eye: [18, -4, 6], at: c, focal: 3), look_at(eye: [10, -4, 14], at: c, focal: 3), look_at(eye: [2, -3, 6], at: c, focal: 3), look_at(eye: [10, -5, -2], at: c, focal: 3), look_at(eye: [15, 1, 9], at: c, focal: 3), look_at(eye: [5, 2, 2], at: c, focal: 3)],
  size: [16, 12],
  far: 20,
  material: lambert(albedo: [0.9, 0.5, 0.2]),
  outputs: [dataset("capture")],
}
"#,
    data: "capture(\"capture\", test_every: 0)",
    sampler: "stratified(samples: 16, near: 0.05, far: 20, jitter: true)",
    ball: [10.0, -4.0, 6.0],
    warp: ("contraction()", "contraction"),
    ahead: None,
};

/// A ball in front of a 2 × 2 grid of cameras looking down −z, written in
/// LLFF's layout with depth bounds 4 to 20: `capture(..., format:
/// "llff")` centres it on the mean camera and scales it by 1/(4·0.75), and
/// a NeRF sees it in that camera's NDC.
const FORWARD: Set = Set {
    scene: r#"
render set {
  scene: sphere(1.5, center: [3, -2, -8]),
  camera: [look_at(eye: [2, -3, 0], at: [2, -3, -1], focal: 2), look_at(eye: [4, -3, 0], at: [4, -3, -1], focal: 2), look_at(eye: [2, -1, 0], at: [2, -1, -1], focal: 2), look_at(eye: [4, -1, 0], at: [4, -1, -1], focal: 2)],
  size: [16, 12],
  far: 30,
  material: lambert(albedo: [0.9, 0.5, 0.2]),
  outputs: [dataset("capture", llff_bounds: [4, 20])],
}
"#,
    data: "capture(\"capture\", format: \"llff\", test_every: 0)",
    sampler: "stratified(samples: 16, near: 0, far: 1000, jitter: true)",
    ball: [3.0, -2.0, -8.0],
    warp: ("ndc()", "ndc"),
    // The near bound.
    ahead: Some(4.0),
};

/// `set` written under a fresh directory named after `name`.
fn capture_set(name: &str, set: &Set) -> PathBuf {
    let dir = temp(name);
    std::fs::create_dir_all(&dir).unwrap();
    let p = sdfl_stdlib::load(&SourceFile::new("set.sdfl", set.scene)).unwrap();
    sdfl_runtime::run_job(&p.renders[0], &dir, Default::default(), &|_| {}).unwrap();
    dir
}

/// Trains `model` on `data` (relative to `dir`) for `iterations` steps
/// into `dir/out/t.ckpt`; the job (as run) and the report.
fn train_on(
    dir: &Path,
    model: &str,
    data: &str,
    sampler: Option<&str>,
    iterations: usize,
) -> (sdfl_stdlib::value::TrainJob, TrainReport) {
    let sampler = sampler.map_or(String::new(), |s| format!("  sampler: {s},\n"));
    let src = format!(
        "train t {{\n  model: {model},\n  data: {data},\n{sampler}  rays: 64,\n  optimizer: adam(lr: 1e-2),\n  iterations: {iterations},\n  bounds: 1.2,\n  checkpoint: \"t.ckpt\",\n}}\n"
    );
    let job = sdfl_stdlib::load(&SourceFile::new("t.sdfl", src))
        .unwrap_or_else(|e| panic!("{e:?}"))
        .trains[0]
        .clone();
    let opts = TrainOptions { restart: false };
    let report = run_train_job(&job, &dir.join("out"), dir, None, opts, &|_| {}).unwrap();
    (job, report)
}

/// Every parameter of the checkpoint, flat in the trainer's order.
fn flat_params(path: &Path) -> Vec<f32> {
    Checkpoint::read(path)
        .unwrap()
        .params
        .iter()
        .flat_map(|p| p.values.clone())
        .collect()
}

/// Points and unit directions in the data's frame: on the surface of the
/// ball of radius 2 around `ball`, among the cameras (where training rays
/// went), and out to five times their distance (beyond a contraction's
/// inner box). With `ahead`, those behind the plane `z = −ahead` are
/// mirrored in front of it: NDC maps points near the cameras' plane to
/// huge coordinates, where f32 and f64 encodings part.
fn data_points(ball: [f64; 3], ahead: Option<f64>, n: usize) -> Vec<([f64; 3], [f64; 3])> {
    let mut rng = 0x9e37_79b9u64;
    let mut next = || {
        rng = rng
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (rng >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    (0..n)
        .map(|k| {
            let u = DVec3::new(next(), next(), next());
            let reach = match k % 4 {
                0 => 2.0 / u.length().max(1e-3),
                1 => 40.0,
                _ => 8.0,
            };
            let mut p = DVec3::from_array(ball) + u * reach;
            if let Some(near) = ahead.filter(|&near| p.z > -near) {
                p.z = -2.0 * near - p.z;
            }
            let d = DVec3::new(next(), next(), next()).normalize_or(DVec3::X);
            (p.to_array(), d.to_array())
        })
        .collect()
}

/// sdfl's own map of data-frame points and directions into the model's
/// frame (the capture reader's `SceneFrame`), as f32 rows.
fn to_model_rows(frame: &SceneFrame, pts: &[([f64; 3], [f64; 3])]) -> (Vec<f32>, Vec<f32>) {
    let (mut points, mut dirs) = (Vec::new(), Vec::new());
    for (p, d) in pts {
        let (p, d) = (DVec3::from_array(*p), DVec3::from_array(*d));
        let q = frame.to_scene(p);
        let e = (frame.to_scene(p + d) - q).normalize();
        points.extend(q.to_array().map(|v| v as f32));
        dirs.extend(e.to_array().map(|v| v as f32));
    }
    (points, dirs)
}

/// How far `pairs` (file, sdfl) are apart: `‖file − sdfl‖ / ‖sdfl‖` over
/// all of them.
fn gap(pairs: &[(f64, f64)]) -> f64 {
    let d: f64 = pairs.iter().map(|(a, b)| (a - b).powi(2)).sum();
    let n: f64 = pairs.iter().map(|(_, b)| b * b).sum();
    (d / n).sqrt()
}

/// A NeRF trained on the capture with contraction: evaluated from the
/// file at data-frame points as docs/checkpoints.md says, it is sdfl's own
/// field there; leaving out the normalisation or the warp is not.
fn check_capture_nerf(name: &str, set: &Set, model: &str, learned: bool, iterations: usize) {
    let dir = capture_set(name, set);
    let model = model.replace("WARP", set.warp.0);
    let (job, report) = train_on(&dir, &model, set.data, Some(set.sampler), iterations);
    let frame = report.scene_frame.expect("a capture's frame");
    // Moved and scaled (and for `AROUND`, turned).
    assert!(frame.scale < 0.5, "{frame:?}");
    assert!(DVec3::from_array(frame.center).length() > 3.0, "{frame:?}");
    let path = dir.join("out/t.ckpt");
    let file = read_safetensors(&path);
    let at = placement(&file);
    // As sdfl's capture reader made it (JSON numbers, to an ulp).
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-14 * y.abs().max(1.0);
    assert!(close(at.scale, frame.scale), "{} vs {frame:?}", at.scale);
    for i in 0..3 {
        assert!(
            close(at.center[i], frame.center[i]),
            "{:?} vs {frame:?}",
            at.center
        );
        for j in 0..3 {
            assert!(
                close(at.rotation[i][j], frame.rotation[i][j]),
                "{:?}",
                at.rotation
            );
        }
    }
    assert_eq!(at.warp["kind"], set.warp.1);
    let Field::Nerf(spec) = &*job.model else {
        panic!("a NeRF")
    };
    let mut spec = spec.clone();
    if spec.unbounded == Some(Unbounded::Ndc(None)) {
        // NDC's camera, as sdfl's LLFF reader gives it to the run.
        let ff = sdfl_runtime::jobs::load_views(&job.data, &dir)
            .unwrap()
            .forward_facing
            .expect("a forward-facing capture");
        spec.unbounded = Some(Unbounded::Ndc(Some(ff.ndc)));
    }
    let spec = &spec;
    let flat = flat_params(&path);
    let net = NerfNet::new(spec);
    let pts = data_points(set.ball, set.ahead, 96);
    let (points, dirs) = to_model_rows(&frame, &pts);
    let mut work = NerfWork::default();
    net.forward(&flat, &points, &dirs, &mut work);
    // sdfl's densities are per unit of the model's length; the file's
    // recipe gives them per unit of the data's.
    let ours: Vec<f64> = work.sigma[..pts.len()]
        .iter()
        .map(|&s| s as f64 * frame.scale)
        .collect();
    let mut worst = 0f64;
    let (mut naive, mut unwarped) = (Vec::new(), Vec::new());
    for (s, &(p, d)) in pts.iter().enumerate() {
        let (sigma, rgb) = evaluate(&file, p, d, DATA);
        let err = (sigma - ours[s]).abs() / ours[s].abs().max(1e-3);
        worst = worst.max(err);
        assert!(
            err < 1e-4,
            "{name} point {p:?}: density {sigma} from the file, sdfl {}",
            ours[s]
        );
        for c in 0..3 {
            let o = work.rgb[3 * s + c] as f64;
            assert!(
                (rgb[c] - o).abs() < 1e-5,
                "{name} point {p:?}: colour {rgb:?} vs sdfl {o}"
            );
        }
        let skip = |steps| evaluate(&file, p, d, steps).0;
        naive.push((
            skip(Steps {
                transform: false,
                warp: true,
            }),
            work.sigma[s] as f64,
        ));
        unwarped.push((
            skip(Steps {
                transform: true,
                warp: false,
            }),
            ours[s],
        ));
    }
    let most = ours.iter().fold(0f64, |m, &s| m.max(s));
    assert!(most > 1e-4, "{name}: densities at most {most}");
    // The old recipe (points taken as the model's) and one without the
    // contraction are far off: by more than a quarter of sdfl's
    // densities' size (against 1e-7 when right).
    let (a, b) = (gap(&naive), gap(&unwarped));
    assert!(
        a > 0.25 && b > 0.25,
        "{name}: off by {a} without the transform, {b} without the warp"
    );
    eprintln!(
        "{name}: worst density difference {worst:e}; off by {a} / {b} without transform / warp"
    );
    if learned {
        // The learned background, seen along data-frame directions.
        let offset = net.len;
        let backdrop = Backdrop::new(&spec.background, offset);
        let rays: Vec<Ray> = dirs
            .chunks(3)
            .map(|d| Ray {
                origin: [0.0; 3],
                dir: [d[0], d[1], d[2]],
                view: 0,
                pixel: 0,
            })
            .collect();
        let mut colours = Vec::new();
        backdrop.colours(&flat, &rays, &mut BackdropWork::default(), &mut colours);
        for (k, &(_, d)) in pts.iter().enumerate() {
            let c = background(&file, d);
            for a in 0..3 {
                assert!(
                    (c[a] - colours[k][a] as f64).abs() < 1e-5,
                    "{name}: background {c:?} vs sdfl {:?}",
                    colours[k]
                );
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_normalised_contracted_nerf_evaluates_in_the_datas_frame() {
    check_capture_nerf(
        "capture-harmonic",
        &AROUND,
        "nerf(position: harmonic(freqs: 3), direction: harmonic(freqs: 2), layers: 2, width: 16, skips: [1], color_width: 8, density: \"softplus\", unbounded: WARP, background: learned_background(freqs: 2, width: 8))",
        true,
        20,
    );
}

#[test]
fn a_normalised_contracted_hash_grid_nerf_evaluates_in_the_datas_frame() {
    // The grid covers the contracted cube [-2, 2]³ whatever `min`/`max`
    // say. Its tables start at ±1e-4, so the field varies with position
    // only where training rays have been: more steps.
    check_capture_nerf(
        "capture-hashgrid",
        &AROUND,
        "nerf(position: hashgrid(levels: 4, log2_table: 8, min_res: 4, max_res: 32), layers: 1, width: 16, skips: [], color_width: 8, view_dependent: false, density: \"exp\", unbounded: WARP)",
        false,
        200,
    );
}

#[test]
fn a_forward_facing_nerf_in_ndc_evaluates_in_the_datas_frame() {
    check_capture_nerf(
        "capture-ndc",
        &FORWARD,
        "nerf(position: harmonic(freqs: 3), direction: harmonic(freqs: 2), layers: 2, width: 16, skips: [1], color_width: 8, density: \"softplus\", unbounded: WARP)",
        false,
        20,
    );
}

/// A neural surface trained on the capture: its distance from the file,
/// in the data's units at data-frame points, is sdfl's own distance there
/// divided by the scale; with `start_radius`, untrained, also its
/// starting sphere's distance in the data's units.
fn check_capture_surface(name: &str, sdf: &str, start_radius: Option<f64>) {
    let dir = capture_set(name, &AROUND);
    // Untrained where it is checked against its starting sphere.
    let (job, report) = train_on(
        &dir,
        &format!("neus({sdf}, background: [1, 1, 1])"),
        AROUND.data,
        Some("stratified(samples: 16, near: 0.05, far: 2.5, jitter: true)"),
        if start_radius.is_some() { 0 } else { 3 },
    );
    let frame = report.scene_frame.expect("a capture's frame");
    let path = dir.join("out/t.ckpt");
    let file = read_safetensors(&path);
    let model: Value = serde_json::from_str(&file.meta["model"]).unwrap();
    assert_eq!(model["kind"], "neural_surface");
    assert!((placement(&file).scale / frame.scale - 1.0).abs() < 1e-14);
    let Field::NeuralSurface(spec) = &*job.model else {
        panic!("a neural surface")
    };
    let sdf = SurfaceSdf::new(&spec.sdf).unwrap();
    let flat = flat_params(&path);
    let pts = data_points(AROUND.ball, None, 64);
    let (points, _) = to_model_rows(&frame, &pts);
    let mut out = vec![0.0; pts.len()];
    sdf.distance(&flat[..sdf.len()], &points, Levels::All, &mut out);
    let mut naive = Vec::new();
    for (k, &(p, _)) in pts.iter().enumerate() {
        let ours = out[k] as f64 / frame.scale;
        let f = distance(&file, p, DATA);
        assert!(
            (f - ours).abs() < 1e-4 * ours.abs().max(1.0),
            "{name} point {p:?}: distance {f} from the file, sdfl {ours}"
        );
        naive.push((
            distance(
                &file,
                p,
                Steps {
                    transform: false,
                    warp: false,
                },
            ),
            ours,
        ));
        if let Some(r) = start_radius {
            // The sphere of radius r (model units) around the model's
            // origin, measured in the data's units and frame.
            let want =
                DVec3::from_array(p).distance(DVec3::from_array(frame.center)) - r / frame.scale;
            assert!(
                (f - want).abs() < 1e-2 * r / frame.scale,
                "{name} point {p:?}: distance {f}, its starting sphere's {want}"
            );
        }
    }
    // Off by more than an eighth of the ball's radius.
    let apart =
        naive.iter().filter(|(a, b)| (a - b).abs() > 0.25).count() as f64 / naive.len() as f64;
    assert!(
        apart > 0.75,
        "{name}: apart at {apart} without the transform"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_neural_surface_on_a_capture_gives_distances_in_the_datas_units() {
    check_capture_surface(
        "surface-mlp",
        "neural_sdf(encoding: harmonic(freqs: 2), network: mlp(layers: 2, width: 16, skips: [1]), radius: 0.3)",
        None,
    );
    let hash = "neural_sdf(encoding: hashgrid(levels: 4, log2_table: 10, min_res: 4, max_res: 24, min: [-1.2, -1.2, -1.2], max: [1.2, 1.2, 1.2]), network: mlp(layers: 1, width: 16, skips: []), radius: 0.3)";
    check_capture_surface("surface-hash", hash, None);
    // Before any step it is the sphere of radius 0.3 (model units) around
    // the model's origin: 2.4 data units around the cameras' centre.
    check_capture_surface("surface-hash-start", hash, Some(0.3));
}

/// A neural SDF fitted to points moved to their mean (`center: true`):
/// the file records that translation, and its distances at the points'
/// own coordinates are sdfl's at the centred ones.
#[test]
fn a_point_fit_on_centred_points_records_their_mean() {
    let dir = temp("points");
    std::fs::create_dir_all(&dir).unwrap();
    let centre = DVec3::new(5.0, -3.0, 2.0);
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let text: String = (0..400)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f64 + 0.5) / 400.0;
            let (r, t) = ((1.0 - y * y).sqrt(), golden * i as f64);
            let p = centre + DVec3::new(r * t.cos(), y, r * t.sin()) * 0.5;
            format!("{} {} {}\n", p.x, p.y, p.z)
        })
        .collect();
    std::fs::write(dir.join("ball.xyz"), text).unwrap();
    let data = "points(\"ball.xyz\", center: true)";
    let (job, _) = train_on(
        &dir,
        "neural_sdf(encoding: harmonic(freqs: 2), layers: 2, width: 16, skips: [], radius: 0.4)",
        data,
        None,
        2,
    );
    let mean = sdfl_runtime::jobs::load_views(&job.data, &dir)
        .unwrap()
        .points_mean
        .expect("centred");
    let path = dir.join("out/t.ckpt");
    let file = read_safetensors(&path);
    let at = placement(&file);
    assert_eq!(at.scale, 1.0);
    assert!(
        (0..3).all(|a| (at.center[a] - mean[a]).abs() < 1e-12),
        "{:?} vs {mean:?}",
        at.center
    );
    let Field::NeuralSdf(spec) = &*job.model else {
        panic!("a neural SDF")
    };
    let net = sdfl_runtime::neural::distance::sdf_net(spec);
    let flat = flat_params(&path);
    let pts = data_points(AROUND.ball, None, 32);
    let moved: Vec<f32> = pts
        .iter()
        .flat_map(|(p, _)| (0..3).map(move |a| (p[a] - mean[a]) as f32))
        .collect();
    let mut out = vec![0.0; pts.len()];
    net.distance(&flat, &moved, &mut out);
    for (k, &(p, _)) in pts.iter().enumerate() {
        let f = distance(&file, p, DATA);
        let ours = out[k] as f64;
        assert!(
            (f - ours).abs() < 1e-4 * ours.abs().max(1.0),
            "point {p:?}: distance {f} from the file, sdfl {ours}"
        );
        let naive = distance(
            &file,
            p,
            Steps {
                transform: false,
                warp: false,
            },
        );
        assert!(
            (naive - ours).abs() > 1e-2,
            "point {p:?}: {naive} without the mean"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
