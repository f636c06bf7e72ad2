//! How a checkpoint names and shapes a model's tensors, and the model's
//! specification it carries, so that the file is usable without sdfl (see
//! docs/checkpoints.md).
//!
//! The trainer keeps each model's parameters as flat named tensors in its
//! own order (a dense layer's `W` row-major as `(in, out)`); a file stores
//! each as one or more *pieces*: named by role, shaped, a layer's weight in
//! PyTorch's `(out, in)` order. Moving between the two is a permutation, so
//! a resumed run reads back the same bits.

use serde_json::{json, Value};

use sdfl_stdlib::value::{DensityActivation, Encoding, Field, Nerf};

use super::TensorSpec;
use crate::neural::background::Backdrop;
use crate::neural::mlp::{Activation, Dense};
use crate::neural::nerf::{NerfNet, PositionEncoding};

/// One tensor of a checkpoint file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Piece {
    /// The tensor's name in the file.
    pub name: String,
    /// The tensor's dimensions as stored.
    pub shape: Vec<usize>,
    /// Stored as `(out, in)` = `shape`, held by the trainer as the
    /// row-major transpose `(in, out)`.
    pub transposed: bool,
}

impl Piece {
    /// A tensor stored whole, one-dimensional, under the trainer's name.
    pub fn flat(name: &str, len: usize) -> Piece {
        Piece {
            name: name.to_string(),
            shape: vec![len],
            transposed: false,
        }
    }

    /// Scalars in the piece (`None` on overflow: a hostile shape).
    pub fn len(&self) -> Option<usize> {
        self.shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d))
    }

    /// Whether the piece holds no scalars.
    pub fn is_empty(&self) -> bool {
        self.len() == Some(0)
    }
}

/// The pieces of each of a model's tensors (in the trainer's order) and
/// the model's specification.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// Each parameter tensor's pieces, in the trainer's order.
    pub params: Vec<Vec<Piece>>,
    /// The model's specification (JSON), stored in the file's metadata.
    pub model: Value,
}

impl Layout {
    /// Every tensor stored whole under its own name.
    pub fn flat(tensors: &[TensorSpec], model: Value) -> Layout {
        Layout {
            params: tensors
                .iter()
                .map(|t| vec![Piece::flat(&t.name, t.len)])
                .collect(),
            model,
        }
    }

    /// The layout of `field`'s tensors. A NeRF's are named by role and
    /// shaped; other models' are stored flat under their trainer names
    /// (their specification still says what they are).
    pub fn of(field: &Field, tensors: &[TensorSpec]) -> Layout {
        match field {
            Field::Nerf(n) => nerf_layout(n, tensors)
                .unwrap_or_else(|| Layout::flat(tensors, json!({ "kind": "nerf" }))),
            Field::Sdf(_) => Layout::flat(
                tensors,
                json!({ "kind": "sdf", "note": "analytic parameters, one tensor each, named as in the scene" }),
            ),
            Field::NeuralSdf(_) => Layout::flat(tensors, json!({ "kind": "neural_sdf" })),
            Field::NeuralSurface(_) => Layout::flat(tensors, json!({ "kind": "neural_surface" })),
        }
    }
}

/// A layer's role in the file: the trainer's `color_hidden` and
/// `color_out` are `color.0` and `color.1`, as in a PyTorch `Sequential`.
fn role(layer: &str) -> String {
    match layer {
        "color_hidden" => "color.0".into(),
        "color_out" => "color.1".into(),
        l => l.into(),
    }
}

fn activation(a: Activation) -> Value {
    match a {
        Activation::Identity => json!("identity"),
        Activation::Relu => json!("relu"),
        Activation::Sigmoid => json!("sigmoid"),
        Activation::Softplus { beta } => json!({ "softplus": { "beta": beta } }),
        Activation::Exp => json!({ "exp": { "cap": 15.0 } }),
    }
}

fn encoding(e: &Encoding, net: Option<&PositionEncoding>) -> Value {
    match e {
        Encoding::Harmonic(h) => json!({
            "kind": "harmonic",
            "freqs": h.freqs,
            "include_input": h.include_input,
            "width": 3 * 2 * h.freqs + if h.include_input { 3 } else { 0 },
            "order": "sin(2^k x_i) for i in 0..3 (outer), k in 0..freqs (inner); then cos likewise; then x",
        }),
        Encoding::HashGrid(g) => {
            let (res, dense) = match net {
                Some(PositionEncoding::Grid { grid, .. }) => {
                    (grid.resolutions(), grid.dense_levels())
                }
                _ => (Vec::new(), Vec::new()),
            };
            json!({
                "kind": "hash_grid",
                "levels": g.levels,
                "features": g.features,
                "log2_table": g.log2_table,
                "min_res": g.min_res,
                "max_res": g.max_res,
                "bounds": [g.min, g.max],
                "resolutions": res,
                "dense": dense,
                "primes": [1u32, 2_654_435_761u32, 805_459_861u32],
                "width": g.levels * g.features,
                "order": "u = clamp((x - min)/(max - min), 0, 1); per level l (outer) its features (inner): trilinear over the cell of u·N_l (index min(floor(u·N_l), N_l - 1)); a vertex (i, j, k) is row i + j·(N_l+1) + k·(N_l+1)² of a dense level, else (i·1 ^ j·2654435761 ^ k·805459861) mod 2^32 mod rows",
            })
        }
    }
}

/// A NeRF's pieces and specification (`None` if the trainer's tensors are
/// not the network's, which would be a bug: the caller then stores flat).
fn nerf_layout(spec: &Nerf, tensors: &[TensorSpec]) -> Option<Layout> {
    let coarse = NerfNet::try_new_at(spec, 0).ok()?;
    let fine = match spec.fine {
        0 => None,
        _ => Some(NerfNet::try_new_at(spec, coarse.len).ok()?),
    };
    let nets: Vec<(&str, &NerfNet)> = match &fine {
        None => vec![("", &coarse)],
        Some(f) => vec![("coarse.", &coarse), ("fine.", f)],
    };
    let mut by_name: Vec<(String, Vec<Piece>)> = Vec::new();
    for (prefix, net) in &nets {
        if let PositionEncoding::Grid { grid, .. } = &net.position {
            let f = grid.config().features as usize;
            let mut ends = grid.level_offsets();
            ends.push(grid.param_count());
            let pieces = ends
                .windows(2)
                .enumerate()
                .map(|(l, w)| Piece {
                    name: format!("{prefix}hashgrid.level{l}.table"),
                    shape: vec![(w[1] - w[0]) / f, f],
                    transposed: false,
                })
                .collect();
            by_name.push((format!("{prefix}position.hashgrid"), pieces));
        }
        for (name, d) in net.layers() {
            let file = format!("{prefix}{}", role(&name));
            by_name.push((
                format!("{prefix}{name}.weight"),
                vec![Piece {
                    name: format!("{file}.weight"),
                    shape: vec![d.out, d.fan_in()],
                    transposed: true,
                }],
            ));
            by_name.push((
                format!("{prefix}{name}.bias"),
                vec![Piece {
                    name: format!("{file}.bias"),
                    shape: vec![d.out],
                    transposed: false,
                }],
            ));
        }
    }
    // A learned background's layers, after the networks' (as the trainer
    // lays them out).
    let backdrop = Backdrop::new(&spec.background, 0);
    for (name, d) in backdrop.layers() {
        by_name.push((
            format!("{name}.weight"),
            vec![Piece {
                name: format!("{name}.weight"),
                shape: vec![d.out, d.fan_in()],
                transposed: true,
            }],
        ));
        by_name.push((
            format!("{name}.bias"),
            vec![Piece {
                name: format!("{name}.bias"),
                shape: vec![d.out],
                transposed: false,
            }],
        ));
    }
    let params = tensors
        .iter()
        .map(|t| {
            let (_, pieces) = by_name.iter().find(|(n, _)| *n == t.name)?;
            let len: usize = pieces.iter().map(|p| p.len().unwrap_or(0)).sum();
            (len == t.len).then(|| pieces.clone())
        })
        .collect::<Option<Vec<_>>>()?;
    if params.len() != by_name.len() {
        return None;
    }
    let mut model = nerf_spec(spec, &coarse, fine.is_some());
    if let Value::Object(m) = &mut model {
        let background_layers: Vec<Value> = backdrop
            .layers()
            .iter()
            .zip([vec!["background_direction"], vec!["background.hidden"]])
            .map(|((name, d), inputs)| layer_spec(name, &inputs, d))
            .collect();
        if !background_layers.is_empty() {
            m.insert(
                "background_direction_encoding".into(),
                json!({
                    "kind": "harmonic",
                    "input": "the unit ray direction d (world axes)",
                    "freqs": match spec.background {
                        sdfl_stdlib::value::Background::Learned(l) => l.freqs,
                        _ => 0,
                    },
                    "include_input": true,
                    "order": "sin(2^k d_i) for i in 0..3 (outer), k in 0..freqs (inner); then cos likewise; then d",
                }),
            );
            m.insert("background_layers".into(), Value::Array(background_layers));
        }
        m.insert("unbounded".into(), json!(spec.unbounded));
    }
    Some(Layout { params, model })
}

/// A dense layer: what it reads (names of earlier values, concatenated in
/// order), its width and activation.
fn layer_spec(name: &str, inputs: &[&str], d: &Dense) -> Value {
    json!({
        "name": role(name),
        "inputs": inputs,
        "input_widths": d.parts,
        "in": d.fan_in(),
        "out": d.out,
        "activation": activation(d.act),
    })
}

fn nerf_spec(spec: &Nerf, net: &NerfNet, fine: bool) -> Value {
    let mut layers = Vec::new();
    for (i, d) in net.trunk.iter().enumerate() {
        let prev = if i == 0 {
            String::new()
        } else {
            format!("trunk.{}", i - 1)
        };
        let inputs: Vec<&str> = if i == 0 {
            vec!["position"]
        } else if d.parts.len() == 2 {
            vec![&prev, "position"]
        } else {
            vec![&prev]
        };
        layers.push(layer_spec(&format!("trunk.{i}"), &inputs, d));
    }
    let last = format!("trunk.{}", net.trunk.len() - 1);
    layers.push(layer_spec("density", &[&last], &net.density));
    match &net.feature {
        Some(f) => {
            layers.push(layer_spec("feature", &[&last], f));
            layers.push(layer_spec(
                "color_hidden",
                &["feature", "direction"],
                &net.color_hidden,
            ));
        }
        None => layers.push(layer_spec("color_hidden", &[&last], &net.color_hidden)),
    }
    layers.push(layer_spec("color_out", &["color.0"], &net.color_out));
    json!({
        "kind": "nerf",
        "networks": if fine { json!(["coarse", "fine"]) } else { json!([""]) },
        "position_encoding": encoding(&spec.position, Some(&net.position)),
        "direction_encoding": spec.direction.as_ref().map(|e| encoding(e, None)),
        "direction": "the unit direction of the ray (from the camera into the scene), world axes",
        "layers": layers,
        "width": spec.width,
        "depth": spec.layers,
        "skips": spec.skips,
        "color_width": spec.color_width,
        "density": match spec.density {
            DensityActivation::Relu => "relu",
            DensityActivation::Exp => "exp",
            DensityActivation::Softplus => "softplus",
        },
        "outputs": { "density": "density", "color": "color.1 (sigmoid, linear RGB in 0..1)" },
        "background": spec.background,
        "fine_samples": spec.fine,
        "precision": spec.precision,
        "linear": "y = x @ weight.T + bias (weight is (out, in), as torch.nn.Linear)",
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::neural::field::NerfObjective;
    use crate::train::Objective;
    use sdfl_stdlib::value::{Harmonic, HashGridSpec, LastInterval, Precision, Sampler};

    fn nerf(position: Encoding, fine: usize) -> Nerf {
        Nerf {
            position,
            direction: Some(Encoding::Harmonic(Harmonic {
                freqs: 2,
                include_input: true,
            })),
            layers: 3,
            width: 8,
            skips: vec![2],
            color_width: 4,
            fine,
            background: sdfl_stdlib::value::Background::Color([1.0; 3]),
            background_at: Default::default(),
            unbounded: None,
            seed: 1,
            density: DensityActivation::Softplus,
            occupancy: None,
            precision: Precision::Fp32,
        }
    }

    /// Every trainer tensor gets role-named pieces covering it exactly,
    /// weights as (out, in); names are unique.
    #[test]
    fn nerf_pieces_cover_the_tensors() {
        let grid = Encoding::HashGrid(HashGridSpec {
            levels: 4,
            features: 2,
            log2_table: 6,
            min_res: 2,
            max_res: 16,
            min: [-1.0; 3],
            max: [1.0; 3],
        });
        for (enc, fine) in [
            (grid, 0),
            (
                Encoding::Harmonic(Harmonic {
                    freqs: 3,
                    include_input: true,
                }),
                4,
            ),
        ] {
            let mut spec = nerf(enc, fine);
            if fine > 0 {
                // A learned background's layers are named too (not a flat
                // fallback for the whole model).
                spec.background = sdfl_stdlib::value::Background::Learned(
                    sdfl_stdlib::value::LearnedBackground { freqs: 2, width: 5 },
                );
            }
            let tensors = NerfObjective::new(
                &spec,
                &Sampler {
                    samples: 8,
                    near: 1.0,
                    far: 4.0,
                    jitter: false,
                    last_interval: LastInterval::Zero,
                },
            )
            .unwrap()
            .tensors();
            let layout = Layout::of(&Field::Nerf(spec.clone()), &tensors);
            assert_eq!(layout.model["kind"], "nerf", "{:?}", layout.model);
            assert_eq!(layout.params.len(), tensors.len());
            let mut names = Vec::new();
            for (t, pieces) in tensors.iter().zip(&layout.params) {
                let len: usize = pieces.iter().map(|p| p.len().unwrap()).sum();
                assert_eq!(len, t.len, "{}", t.name);
                names.extend(pieces.iter().map(|p| p.name.clone()));
            }
            let n = names.len();
            names.sort();
            names.dedup();
            assert_eq!(names.len(), n);
            let pre = if fine > 0 { "coarse." } else { "" };
            for want in [
                "trunk.0.weight",
                "trunk.2.weight",
                "density.bias",
                "feature.weight",
                "color.0.weight",
                "color.1.bias",
            ] {
                assert!(names.contains(&format!("{pre}{want}")), "{want}: {names:?}");
            }
            let piece = |name: &str| {
                layout
                    .params
                    .iter()
                    .flatten()
                    .find(|p| p.name == name)
                    .unwrap()
                    .clone()
            };
            if fine > 0 {
                // 3 + 3·2·2 encoded direction → 5 → RGB, weights (out, in).
                assert_eq!(piece("background.hidden.weight").shape, vec![5, 15]);
                assert_eq!(piece("background.out.weight").shape, vec![3, 5]);
                assert_eq!(
                    layout.model["background_layers"][1]["activation"],
                    "sigmoid"
                );
            }
            let enc_w = if fine > 0 { 21 } else { 8 };
            // The skip layer reads the trunk's 8 and the encoding again.
            assert_eq!(
                piece(&format!("{pre}trunk.2.weight")).shape,
                vec![8, 8 + enc_w]
            );
            assert_eq!(
                piece(&format!("{pre}color.0.weight")).shape,
                vec![4, 8 + 15]
            );
            if fine == 0 {
                assert_eq!(piece("hashgrid.level0.table").shape, vec![27, 2]);
                assert_eq!(piece("hashgrid.level3.table").shape, vec![64, 2]);
            } else {
                assert!(names.contains(&"fine.color.1.weight".to_string()));
            }
        }
    }
}
