//! Checkpoints describe themselves (docs/checkpoints.md): a tiny NeRF
//! (harmonic, view-dependent with a skip; and a hash grid) trains a few
//! steps, and its checkpoint is read back as any safetensors reader would,
//! by tensor name and shape and the `__metadata__` only, with no sdfl code.
//! The network is evaluated in f64 from those tensors exactly as the
//! PyTorch snippet in docs/checkpoints.md does (spec from `model`, linear
//! layers `x @ W.T + b` with `W` as (out, in)), and must give sdfl's own
//! densities and colours to f32 rounding.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde_json::Value;

use sdfl_lang::SourceFile;
use sdfl_runtime::jobs::{run_train_job, TrainOptions};
use sdfl_runtime::neural::nerf::{NerfNet, NerfWork};
use sdfl_runtime::train::checkpoint::Checkpoint;

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
            let beta = m["softplus"]["beta"].as_f64().unwrap();
            (beta * z).exp().ln_1p() / beta
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

/// Density and colour at `x` seen along `d`, from the file alone.
fn evaluate(file: &File, x: [f64; 3], d: [f64; 3]) -> (f64, [f64; 3]) {
    let model: Value = serde_json::from_str(&file.meta["model"]).unwrap();
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
    for layer in model["layers"].as_array().unwrap() {
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
    let c = &values["color.1"];
    (values["density"][0], [c[0], c[1], c[2]])
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
        let (sigma, rgb) = evaluate(&file, p, d);
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
