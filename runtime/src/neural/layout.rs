//! How a checkpoint names and shapes each model kind's tensors, and the
//! model's specification it carries (docs/checkpoints.md): `Layout::of`,
//! beside the models whose tensors it names; the generic pieces and
//! layouts are `train::export_names`'.

use serde_json::{json, Value};

use sdfl_stdlib::value::{DensityActivation, Encoding, Field, Nerf, NeuralSdf, NeuralSurface};

use super::background::Backdrop;
use super::hashgrid::HashGrid;
use super::mlp::{Activation, Dense};
use super::nerf::{NerfNet, PositionEncoding};
use crate::train::export_names::{Layout, Piece};
use crate::train::frame::ModelFrame;
use crate::train::TensorSpec;

impl Layout {
    /// The layout of `field`'s tensors. A NeRF's and a neural SDF's (or
    /// surface's) are named by role and shaped; an analytic field's are
    /// stored flat under their trainer names. The frame records the
    /// field's warp and background, in the data's frame until
    /// [`Layout::in_data_frame`].
    pub fn of(field: &Field, tensors: &[TensorSpec]) -> Layout {
        // A layout that does not match the trainer's tensors would be a
        // bug: the model is then stored flat, still loadable.
        let layout = match field {
            Field::Nerf(n) => nerf_layout(n, tensors)
                .unwrap_or_else(|| Layout::flat(tensors, json!({ "kind": "nerf" }))),
            Field::Sdf(_) => Layout::flat(
                tensors,
                json!({ "kind": "sdf", "note": "analytic parameters, one tensor each, named as in the scene" }),
            ),
            Field::NeuralSdf(n) => neural_sdf_layout(n, tensors)
                .unwrap_or_else(|| Layout::flat(tensors, json!({ "kind": "neural_sdf" }))),
            Field::NeuralSurface(n) => surface_layout(n, tensors)
                .unwrap_or_else(|| Layout::flat(tensors, json!({ "kind": "neural_surface" }))),
        };
        Layout {
            frame: ModelFrame::of(field),
            ..layout
        }
    }
}

/// Trainer tensor names and the pieces each is stored as.
type ByName = Vec<(String, Vec<Piece>)>;

/// The pieces of each trainer tensor in `tensors`, looked up by name in
/// `by_name`, which must name every one of them exactly once with the
/// tensor's length (`None` otherwise).
fn cover(by_name: &[(String, Vec<Piece>)], tensors: &[TensorSpec]) -> Option<Vec<Vec<Piece>>> {
    let params = tensors
        .iter()
        .map(|t| {
            let (_, pieces) = by_name.iter().find(|(n, _)| *n == t.name)?;
            let len: usize = pieces.iter().map(|p| p.len().unwrap_or(0)).sum();
            (len == t.len).then(|| pieces.clone())
        })
        .collect::<Option<Vec<_>>>()?;
    (params.len() == by_name.len()).then_some(params)
}

/// A dense layer's weight `(out, in)` and bias, stored under `file`
/// (`transposed`: held `(in, out)` by the trainer, as [`Dense`] does).
fn dense_pieces(
    trainer: &str,
    file: &str,
    out: usize,
    fan_in: usize,
    transposed: bool,
) -> [(String, Vec<Piece>); 2] {
    [
        (
            format!("{trainer}.weight"),
            vec![Piece {
                name: format!("{file}.weight"),
                shape: vec![out, fan_in],
                transposed,
            }],
        ),
        (
            format!("{trainer}.bias"),
            vec![Piece::flat(&format!("{file}.bias"), out)],
        ),
    ]
}

/// A hash grid's tables: one `[rows, features]` piece a level, named
/// `{file}level<l>.table`.
fn grid_pieces(grid: &HashGrid, file: &str) -> Vec<Piece> {
    let f = grid.config().features as usize;
    let mut ends = grid.level_offsets();
    ends.push(grid.param_count());
    ends.windows(2)
        .enumerate()
        .map(|(l, w)| Piece {
            name: format!("{file}level{l}.table"),
            shape: vec![(w[1] - w[0]) / f, f],
            transposed: false,
        })
        .collect()
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

fn harmonic_spec(freqs: usize, include_input: bool) -> Value {
    json!({
        "kind": "harmonic",
        "freqs": freqs,
        "include_input": include_input,
        "width": 3 * 2 * freqs + if include_input { 3 } else { 0 },
        "order": "sin(2^k x_i) for i in 0..3 (outer), k in 0..freqs (inner); then cos likewise; then x",
    })
}

/// An encoding as the file describes it; a hash grid's from the runtime's
/// grid (`grid`), whose box is the warp's cube where the model has one.
fn encoding(e: &Encoding, grid: Option<&HashGrid>) -> Value {
    match e {
        Encoding::Harmonic(h) => harmonic_spec(h.freqs, h.include_input),
        Encoding::HashGrid(g) => {
            let (res, dense, bounds) = match grid {
                Some(grid) => {
                    let c = grid.config();
                    let (lo, hi) = (c.bbox_min.map(f64::from), c.bbox_max.map(f64::from));
                    (grid.resolutions(), grid.dense_levels(), [lo, hi])
                }
                None => (Vec::new(), Vec::new(), [g.min, g.max]),
            };
            json!({
                "kind": "hash_grid",
                "levels": g.levels,
                "features": g.features,
                "log2_table": g.log2_table,
                "min_res": g.min_res,
                "max_res": g.max_res,
                "bounds": bounds,
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
            by_name.push((
                format!("{prefix}position.hashgrid"),
                grid_pieces(grid, &format!("{prefix}hashgrid.")),
            ));
        }
        for (name, d) in net.layers() {
            let file = format!("{prefix}{}", role(&name));
            by_name.extend(dense_pieces(
                &format!("{prefix}{name}"),
                &file,
                d.out,
                d.fan_in(),
                true,
            ));
        }
    }
    // A learned background's layers, after the networks' (as the trainer
    // lays them out).
    let backdrop = Backdrop::new(&spec.background, 0);
    for (name, d) in backdrop.layers() {
        by_name.extend(dense_pieces(&name, &name, d.out, d.fan_in(), true));
    }
    let params = cover(&by_name, tensors)?;
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
                    "input": "the unit ray direction d in the model's frame (rotation @ d_data, see data_to_model)",
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
    Some(Layout {
        params,
        model,
        frame: ModelFrame::default(),
    })
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
        "position_encoding": encoding(
            &spec.position,
            match &net.position {
                PositionEncoding::Grid { grid, .. } => Some(grid),
                PositionEncoding::Harmonic(_) => None,
            },
        ),
        "direction_encoding": spec.direction.as_ref().map(|e| encoding(e, None)),
        "direction": "the unit direction of the ray (from the camera into the scene) in the model's frame (rotation @ d_data, see data_to_model); never warped",
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

/// A neural SDF's pieces (trainer names after `trainer`, file names after
/// `file`) and its specification: the distance in the model's frame.
fn sdf_parts(spec: &NeuralSdf, trainer: &str, file: &str) -> Option<(ByName, Value)> {
    let mut by_name = Vec::new();
    let mut layers = Vec::new();
    // Layers are named without `file` in the specification (as a NeRF's
    // are without `coarse.`); its `prefix` gives it.
    let hidden = |i: usize| format!("hidden.{i}");
    let (position, sphere) = match &spec.encoding {
        Encoding::Harmonic(h) => {
            let net = super::distance::sdf_net(spec);
            for (i, d) in net.hidden.iter().enumerate() {
                let prev = if i == 0 { String::new() } else { hidden(i - 1) };
                let inputs: Vec<&str> = match (i, d.parts.len()) {
                    (0, _) => vec!["position"],
                    (_, 2) => vec![&prev, "position"],
                    _ => vec![&prev],
                };
                by_name.extend(dense_pieces(
                    &format!("{trainer}hidden.{i}"),
                    &format!("{file}hidden.{i}"),
                    d.out,
                    d.fan_in(),
                    true,
                ));
                layers.push(layer_spec(&hidden(i), &inputs, d));
            }
            let d = &net.output;
            by_name.extend(dense_pieces(
                &format!("{trainer}output"),
                &format!("{file}output"),
                d.out,
                d.fan_in(),
                true,
            ));
            let last = hidden(net.hidden.len() - 1);
            layers.push(layer_spec("output", &[&last], d));
            (harmonic_spec(h.freqs, h.include_input), Value::Null)
        }
        Encoding::HashGrid(g) => {
            let net = super::hash_sdf::objective::hash_sdf(spec, g).ok()?;
            let grid = net.grid();
            for (l, piece) in grid_pieces(grid, &format!("{file}hashgrid."))
                .into_iter()
                .enumerate()
            {
                by_name.push((format!("{trainer}grid.level{l}"), vec![piece]));
            }
            // Its layers hold W as (out, in) already.
            let act = Activation::Softplus {
                beta: spec.beta as f32,
            };
            let mut fan_in = grid.output_dim();
            for i in 0..spec.layers {
                let prev = if i == 0 {
                    "position".to_string()
                } else {
                    hidden(i - 1)
                };
                let d = Dense::new(&[fan_in], spec.width, act, 0);
                by_name.extend(dense_pieces(
                    &format!("{trainer}layer{i}"),
                    &format!("{file}hidden.{i}"),
                    spec.width,
                    fan_in,
                    false,
                ));
                layers.push(layer_spec(&hidden(i), &[&prev], &d));
                fan_in = spec.width;
            }
            let d = Dense::new(&[fan_in], 1, Activation::Identity, 0);
            by_name.extend(dense_pieces(
                &format!("{trainer}output"),
                &format!("{file}output"),
                1,
                fan_in,
                false,
            ));
            layers.push(layer_spec("output", &[&hidden(spec.layers - 1)], &d));
            // As `HashSdf` places it: the grid box's centre (of its f32
            // corners), the f32 radius.
            let c = grid.config();
            let centre: [f64; 3] =
                std::array::from_fn(|a| 0.5 * (c.bbox_min[a] as f64 + c.bbox_max[a] as f64));
            (
                encoding(&spec.encoding, Some(grid)),
                json!({ "center": centre, "radius": spec.radius as f32 as f64 }),
            )
        }
    };
    let mut model = json!({
        "kind": "neural_sdf",
        "prefix": file,
        "position_encoding": position,
        "layers": layers,
        "distance": "output (plus the sphere term where given), in the model's frame: divide by data_to_model's scale for the data's units",
        "linear": "y = x @ weight.T + bias (weight is (out, in), as torch.nn.Linear)",
    });
    if !sphere.is_null() {
        model["sphere"] = sphere;
        model["sphere_term"] = json!("|x - center| - radius, added to the output");
    }
    Some((by_name, model))
}

/// A neural SDF fitted to points: its layers named `hidden.<i>` and
/// `output` (a hash grid's tables `hashgrid.level<l>.table`).
fn neural_sdf_layout(spec: &NeuralSdf, tensors: &[TensorSpec]) -> Option<Layout> {
    let (by_name, model) = sdf_parts(spec, "", "")?;
    Some(Layout {
        params: cover(&by_name, tensors)?,
        model,
        frame: ModelFrame::default(),
    })
}

/// A neural surface: its distance network as a neural SDF's under `sdf.`,
/// its colour network `color.<i>` … `color.out`, a trained β flat as
/// `log_beta`.
fn surface_layout(spec: &NeuralSurface, tensors: &[TensorSpec]) -> Option<Layout> {
    let (mut by_name, sdf) = sdf_parts(&spec.sdf, "sdf.", "sdf.")?;
    let colours: Vec<&TensorSpec> = tensors
        .iter()
        .filter(|t| t.name.starts_with("color.") && t.name.ends_with(".weight"))
        .collect();
    let mut color_layers = Vec::new();
    let mut fan_in = spec.color_input();
    for (i, t) in colours.iter().enumerate() {
        let name = t.name.strip_suffix(".weight")?;
        let last = i + 1 == colours.len();
        let out = if last { 3 } else { spec.color_width };
        by_name.extend(dense_pieces(name, name, out, fan_in, true));
        let inputs: Vec<String> = if i == 0 {
            let mut v = vec!["color_position".to_string(), "normal".into()];
            if spec.view_dependent {
                v.push("direction".into());
            }
            v
        } else {
            vec![colours[i - 1].name.strip_suffix(".weight")?.to_string()]
        };
        color_layers.push(json!({
            "name": name,
            "inputs": inputs,
            "in": fan_in,
            "out": out,
            "activation": if last { "sigmoid" } else { "relu" },
        }));
        fan_in = out;
    }
    if let Some(b) = tensors.iter().find(|t| t.name == "log_beta") {
        by_name.push((b.name.clone(), vec![Piece::flat(&b.name, b.len)]));
    }
    let model = json!({
        "kind": "neural_surface",
        "sdf": sdf,
        "density": spec.density.name(),
        "alpha": spec.alpha,
        "beta": spec.beta,
        "color_layers": color_layers,
        "color_position_encoding": harmonic_spec(spec.color_freqs, true),
        "normal": "the distance's gradient at the point in the model's frame, not normalised",
        "direction_encoding": spec.view_dependent.then(|| harmonic_spec(NeuralSurface::DIRECTION_FREQS, true)),
    });
    Some(Layout {
        params: cover(&by_name, tensors)?,
        model,
        frame: ModelFrame::default(),
    })
}
