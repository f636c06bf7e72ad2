//! Neural fields: encodings (`harmonic`, `hashgrid`), the occupancy grid,
//! hidden layers (`mlp`), `neural_sdf` and `nerf` itself.

use super::*;
use crate::value::{Background, Contraction, LearnedBackground, Mlp, NeuralSdf, Unbounded};

/// The type of a NeRF's `background`: a colour or a background value.
pub(crate) const BACKGROUND: Type = Type::Named("background");
/// The type of a NeRF's `unbounded`.
pub(crate) const CONTRACTION: Type = Type::Named("contraction");
pub(crate) const NDC: Type = Type::Named("ndc");
/// The box a hash grid or occupancy grid covers by default (and the inner
/// box of a contraction).
const DEFAULT_BOX: ([f64; 3], [f64; 3]) = ([-1.5; 3], [1.5; 3]);

/// Most trainable numbers in a hash grid's tables (1 GiB with gradient and
/// Adam's moments).
const MAX_GRID_PARAMS: u64 = 1 << 26;

/// Most weights in a network's layers.
const MAX_NETWORK_WEIGHTS: usize = 1 << 26;

pub(crate) fn builtins() -> Vec<Builtin> {
    vec![
        func(
            "neural_sdf",
            "A neural signed distance function (IGR; the assignment's part 6): the encoded point, `layers` softplus layers of `width` (the encoding again at the `skips`), a linear distance, starting as the SDF of a sphere of `radius`. With a harmonic encoding the weights describe the sphere (geometric initialisation); with `encoding: hashgrid(...)` (NeuS2, instant-nsr) a small network adds a residual to the sphere's distance about the grid's centre, and without `network`, `layers`, `width` or `skips` it is one layer of 64 without skips. Trained from a point cloud with `surface()`, `eikonal()` and `inter()` losses; the eikonal term uses the exact input gradient (or, on a hash grid with `eikonal_step`, central differences).",
            vec![
                opt("encoding", ENCODING, "harmonic(freqs: 4)", "encoding of the point: harmonic, or a hash grid"),
                opt("layers", Type::Number, "6", "hidden layers (a hash grid's: 1)"),
                opt("width", Type::Number, "128", "width of the hidden layers (a hash grid's: 64)"),
                opt("skips", Type::list(Type::Number), "[3]", "hidden layers (counted from 0; 1 to `layers` − 1) that see the encoding again (a hash grid's: none)"),
                opt("beta", Type::Number, "100", "softplus sharpness (> 0): large is close to ReLU, with curvature"),
                opt("radius", Type::Number, "1", "radius of the sphere the weights start as (> 0)"),
                opt("seed", Type::Number, "0", "seed of the initial weights"),
                opt("network", NETWORK, "mlp()", "the hidden layers as one value, `mlp(...)` (instead of `layers`, `width`, `skips`)"),
                opt("level_every", Type::Number, "0", "a hash grid's levels switched on coarse to fine: a quarter of them at first, one more every this many steps (0: all from the start)"),
                opt("eikonal_step", Type::Number, "0", "a hash grid's eikonal term with ∇f by central differences of this step (Neuralangelo: seven values a point, no second derivatives); 0: the exact gradient"),
            ],
            FIELD,
            |a| {
                let encoding = match a.get("encoding").0 {
                    Value::Encoding(e) => *e,
                    other => return Err(type_error(a.get("encoding").1, "encoding", other)),
                };
                let hash = matches!(encoding, Encoding::HashGrid(_));
                let Mlp { layers, width, skips } = if hash { hash_sdf_layers(a)? } else { hidden_layers(a)? };
                let level_every = a.count("level_every", 0, 1 << 30)? as usize;
                let step = a.number("eikonal_step")?;
                if !(step >= 0.0 && step.is_finite()) {
                    return Err(value_error(
                        a.get("eikonal_step").1,
                        "the eikonal step must be a finite number ≥ 0",
                        "out of range",
                        "e.g. `eikonal_step: 0.005` (a fraction of the finest cell), or 0 for the exact gradient",
                    ));
                }
                if !hash {
                    if let Some(name) = ["level_every", "eikonal_step"].into_iter().find(|n| a.given(n)) {
                        return Err(value_error(
                            a.get(name).1,
                            format!("`{name}` applies to a hash-grid SDF"),
                            "not with a harmonic encoding",
                            format!("give `encoding: hashgrid(...)`, or leave `{name}` out"),
                        ));
                    }
                }
                Ok(Value::Field(Arc::new(Field::NeuralSdf(NeuralSdf {
                    encoding,
                    layers,
                    width,
                    skips,
                    beta: a.positive("beta")?,
                    radius: a.positive("radius")?,
                    seed: a.count("seed", 0, u32::MAX as u64)?,
                    level_every,
                    eikonal_step: (step > 0.0).then_some(step),
                }))))
            },
        ),
        func(
            "points",
            "A point cloud on a surface, to fit a distance field to: `.npz` (array `verts`), `.npy` (N × 3 float32), `.ply` (ASCII or binary) or `.xyz` text, relative to the scene file.",
            vec![
                req("path", Type::Str, "the point file"),
                opt("every", Type::Number, "1", "keep every `every`-th point (the assignment keeps every 2nd)"),
                opt("center", Type::Bool, "false", "move the points so their mean is the origin"),
            ],
            DATASET,
            |a| {
                let (path, span) = a.string("path")?;
                if path.is_empty() {
                    return Err(value_error(span, "no point file named", "empty", "name a .npz, .npy, .ply or .xyz file"));
                }
                check_input(a, std::path::Path::new(&*path), span, Input::File)?;
                Ok(Value::Dataset(Arc::new(Dataset::Points {
                    path: std::path::PathBuf::from(&*path),
                    every: a.count("every", 1, 1_000_000)? as usize,
                    center: matches!(a.get("center").0, Value::Bool(true)),
                })))
            },
        ),
        func(
            "surface",
            "Mean |f| of a distance field at the data's surface points, times `weight`.",
            vec![opt("weight", Type::Number, "1", "weight of this term (> 0)")],
            LOSS,
            |a| Ok(Value::Loss(Loss { kind: LossKind::Surface, weight: a.positive("weight")? })),
        ),
        func(
            "eikonal",
            "Mean (‖∇f‖ − 1)² at the surface and the random points, times `weight`: a distance field's gradient has unit length. The gradient is exact (forward-mode tangents), not a finite difference.",
            vec![opt("weight", Type::Number, "0.02", "weight of this term (> 0)")],
            LOSS,
            |a| Ok(Value::Loss(Loss { kind: LossKind::Eikonal, weight: a.positive("weight")? })),
        ),
        func(
            "inter",
            "Mean exp(−alpha·|f|) at random points, times `weight`: keeps the surface away from where there is no data.",
            vec![
                opt("weight", Type::Number, "0.1", "weight of this term (> 0)"),
                opt("alpha", Type::Number, "100", "sharpness (> 0)"),
            ],
            LOSS,
            |a| Ok(Value::Loss(Loss { kind: LossKind::Inter { alpha: a.positive("alpha")? }, weight: a.positive("weight")? })),
        ),
        func(
            "harmonic",
            "NeRF's harmonic embedding of a point or direction: `sin(2^k·x)` and `cos(2^k·x)` for `k < freqs`, and `x` itself when `include_input`.",
            vec![
                opt("freqs", Type::Number, "6", "frequencies 1, 2, 4, … 2^(freqs-1)"),
                opt("include_input", Type::Bool, "true", "append the input itself"),
            ],
            ENCODING,
            |a| {
                Ok(Value::Encoding(Encoding::Harmonic(Harmonic {
                    freqs: a.count("freqs", 0, 16)? as usize,
                    include_input: matches!(a.get("include_input").0, Value::Bool(true)),
                })))
            },
        ),
        func(
            "hashgrid",
            "A multiresolution hash encoding of positions (instant-ngp): `levels` grids from `min_res` to `max_res` cells a side over the box `min`..`max` (points outside are clamped onto it), each a table of at most 2^`log2_table` rows of `features` trainable numbers, trilinearly interpolated.",
            vec![
                opt("levels", Type::Number, "16", "resolution levels (1..64)"),
                opt("features", Type::Number, "2", "features per level (1..16)"),
                opt("log2_table", Type::Number, "17", "log2 of the largest table's rows (1..24)"),
                opt("min_res", Type::Number, "16", "cells a side of the coarsest level"),
                opt("max_res", Type::Number, "512", "cells a side of the finest level"),
                opt("min", Type::Vec3, "[-1.5, -1.5, -1.5]", "lower corner of the encoded box"),
                opt("max", Type::Vec3, "[1.5, 1.5, 1.5]", "upper corner of the encoded box"),
            ],
            ENCODING,
            |a| {
                let (min, max) = box_arg(a)?;
                let min_res = a.count("min_res", 1, 1 << 16)? as u32;
                let max_res = a.count("max_res", 1, 1 << 16)? as u32;
                if max_res < min_res {
                    return Err(value_error(
                        a.get("max_res").1,
                        "`max_res` is below `min_res`",
                        "coarser than the coarsest level",
                        "the finest level needs at least `min_res` cells a side",
                    ));
                }
                let spec = HashGridSpec {
                    levels: a.count("levels", 1, 64)? as u32,
                    features: a.count("features", 1, 16)? as u32,
                    log2_table: a.count("log2_table", 1, 24)? as u32,
                    min_res,
                    max_res,
                    min: min.to_array(),
                    max: max.to_array(),
                };
                // Tables, their gradient and Adam's two moments: 16 bytes each.
                if spec.param_count() > MAX_GRID_PARAMS {
                    return Err(value_error(
                        a.span,
                        format!(
                            "this hash grid holds {} trainable numbers (about {} MB with their gradient and Adam's moments), more than {}",
                            spec.param_count(),
                            (spec.param_count() * 16) >> 20,
                            MAX_GRID_PARAMS
                        ),
                        "too large",
                        "lower `log2_table`, `levels` or `features`",
                    ));
                }
                Ok(Value::Encoding(Encoding::HashGrid(spec)))
            },
        ),
        func(
            "occupancy_grid",
            "An occupancy grid that skips empty space (nerfacc-style) for `nerf(occupancy: ...)`: `resolution`³ cells over `min`..`max` keep a decaying maximum of the density, refreshed every `every` training steps; samples fall at a fixed step, (far − near)/samples, only inside cells whose density × step exceeds `threshold`, or the mean cell's where that is lower (as instant-ngp and nerfacc: a fine step never empties the grid of a field still near uniform). `resolution: 0` turns it off.",
            vec![
                opt("resolution", Type::Number, "64", "cells a side (0: no grid)"),
                opt("min", Type::Vec3, "[-1.5, -1.5, -1.5]", "lower corner of the box"),
                opt("max", Type::Vec3, "[1.5, 1.5, 1.5]", "upper corner of the box"),
                opt("threshold", Type::Number, "0.01", "occupied when density × step exceeds this (or the mean cell's density × step, where lower)"),
                opt("every", Type::Number, "16", "training steps between refreshes"),
            ],
            OCCUPANCY,
            |a| {
                let (min, max) = box_arg(a)?;
                let threshold = a.number("threshold")?;
                if !(threshold >= 0.0 && threshold.is_finite()) {
                    return Err(value_error(a.get("threshold").1, "the threshold must be a finite number ≥ 0", "out of range", "e.g. `threshold: 0.01`"));
                }
                Ok(Value::Occupancy(OccupancySpec {
                    resolution: a.count("resolution", 0, 512)? as u32,
                    min: min.to_array(),
                    max: max.to_array(),
                    threshold,
                    every: a.count("every", 1, 1_000_000)? as usize,
                }))
            },
        ),
        func(
            "data_background",
            "The training data's background, as a NeRF's `background` (the default): a `train` statement puts its data set's colour here (a NeRF-synthetic set's composite colour, `render_views`' `background` for a shape, a rendered field's own), so model and data agree. Black where the data holds no colour of its own, or outside a `train`.",
            vec![],
            BACKGROUND,
            |_| Ok(Value::Background(Background::Data)),
        ),
        func(
            "learned_background",
            "A background learned from the ray's direction, for images without alpha whose background is the world: the unit direction harmonically encoded (`freqs` frequencies and the direction itself) through one ReLU layer of `width` to a sigmoid colour, seen through each ray's remaining transmittance and trained with the field.",
            vec![
                opt("freqs", Type::Number, "4", "harmonic frequencies of the direction (0..8)"),
                opt("width", Type::Number, "32", "width of the hidden layer (1..256)"),
            ],
            BACKGROUND,
            |a| {
                Ok(Value::Background(Background::Learned(LearnedBackground {
                    freqs: a.count("freqs", 0, 8)? as usize,
                    width: a.count("width", 1, 256)? as usize,
                })))
            },
        ),
        func(
            "contraction",
            "Scene contraction for unbounded scenes (mip-NeRF 360, with the ∞-norm as nerfstudio and nerfacc use it, so the contracted scene fills a cube): the inner box `min`..`max` maps to [-1, 1]³ unchanged, and beyond it a point `x` with `m = max |x_i|` goes to `(2 − 1/m)·x/m`; all of space fits in [-2, 2]³, which the NeRF's hash grid and occupancy grid then cover. Samples beyond the inner box are spaced evenly in disparity (1/t) up to the sampler's `far`, so give it a large `far` (e.g. 1000).",
            vec![
                opt("min", Type::Vec3, "[-1.5, -1.5, -1.5]", "lower corner of the inner box"),
                opt("max", Type::Vec3, "[1.5, 1.5, 1.5]", "upper corner of the inner box"),
            ],
            CONTRACTION,
            |a| {
                let (min, max) = box_arg(a)?;
                Ok(Value::Contraction(Contraction { min: min.to_array(), max: max.to_array() }))
            },
        ),
        func(
            "ndc",
            "Normalised device coordinates for forward-facing captures (the original NeRF's LLFF scenes, such as `nerf_fern`): positions are mapped through the projection of the capture's reference camera (the average camera, which an LLFF capture's normalisation puts at the origin looking down −z), so all depths from its near plane to infinity fit in [-1, 1]; samples are spaced evenly in NDC depth (evenly in disparity) from the near plane to the sampler's `far`, so give it a large `far` (e.g. 1000). Density is integrated over world lengths, so depth outputs are lengths (in the data's units, as every depth export is). Needs `capture(..., format: \"llff\")` data.",
            vec![],
            NDC,
            |_| Ok(Value::Ndc),
        ),
        func(
            "mlp",
            "The hidden layers of a multilayer perceptron, as a value: `layers` of `width`, the layers in `skips` (counted from 0; 1 to `layers` − 1) seeing the network's input again. Define it once and give it to `nerf(network: ...)` or `neural_sdf(network: ...)`; the field decides the input (its encoding), the activation and the output heads.",
            vec![
                opt("layers", Type::Number, "6", "hidden layers"),
                opt("width", Type::Number, "128", "width of the hidden layers"),
                opt("skips", Type::list(Type::Number), "[3]", "hidden layers (counted from 0; 1 to `layers` − 1) that see the input again"),
            ],
            NETWORK,
            |a| {
                let (layers, width) = network_size(a)?;
                Ok(Value::Network(Arc::new(Mlp { layers, width, skips: skip_layers(a, layers)? })))
            },
        ),
        func(
            "nerf",
            "A neural radiance field (Mildenhall et al.): an MLP from the encoded position to density (ReLU) and colour (sigmoid). `view_dependent` adds a colour branch that sees the encoded view direction; density never does. Weights start as PyTorch's default initialisation, seeded. Trained as a `train` statement's model.",
            vec![
                opt("position", ENCODING, "harmonic(freqs: 6)", "encoding of the sample position"),
                opt("direction", ENCODING, "harmonic(freqs: 2)", "encoding of the view direction (used when `view_dependent`)"),
                opt("view_dependent", Type::Bool, "true", "whether colour depends on the view direction"),
                opt("layers", Type::Number, "6", "hidden layers of the trunk"),
                opt("width", Type::Number, "128", "width of the hidden layers"),
                opt("skips", Type::list(Type::Number), "[3]", "trunk layers (counted from 0; 1 to `layers` − 1) that see the encoded position again"),
                opt("color_width", Type::Number, "64", "width of the colour branch"),
                opt("fine", Type::Number, "0", "fine samples per ray, drawn by inverse CDF from the coarse network's weights for a second (fine) network of the same shape; 0: one network"),
                opt("background", Type::OneOf(vec![Type::Vec3, BACKGROUND]), "data_background()", "what a ray sees where it leaves the field: the training data's (`data_background()`), a colour `[r, g, b]`, or `learned_background()`"),
                opt("unbounded", Type::OneOf(vec![CONTRACTION, NDC, Type::Bool]), "false", "an unbounded scene: `contraction(min, max)` (or `true`: the default inner box) contracts positions so the hash grid and occupancy grid cover all of space; `ndc()` maps a forward-facing capture's positions into its reference camera's NDC; `false`: the grids' boxes bound the scene"),
                opt("seed", Type::Number, "0", "seed of the initial weights"),
                opt("occupancy", OCCUPANCY, "occupancy_grid(resolution: 0)", "skip empty space with an occupancy grid while training and rendering (resolution 0: none)"),
                opt("density", Type::Str, "\"relu\"", "density activation: \"relu\" (the NeRF paper; can die on dark scenes, every sample's gradient zero), \"softplus\" (Mip-NeRF: its gradient never vanishes) or \"exp\" (instant-ngp's truncated exponential, for hash grids)"),
                opt("precision", Type::Str, "\"fp32\"", "number format of the layers' matrix products: \"fp32\", or \"bf16\" (inputs rounded to bfloat16, sums in fp32: about twice the throughput where the CPU has AVX-512 BF16, fp32 elsewhere; weights and Adam stay fp32)"),
                opt("network", NETWORK, "mlp()", "the trunk's hidden layers as one value, `mlp(...)` (instead of `layers`, `width`, `skips`)"),
            ],
            FIELD,
            |a| {
                let encoding = |name: &str| match a.get(name).0 {
                    Value::Encoding(e) => Ok(*e),
                    other => Err(type_error(a.get(name).1, "encoding", other)),
                };
                let Mlp { layers, width, skips } = hidden_layers(a)?;
                let bg_span = a.get("background").1;
                let background = match a.get("background").0 {
                    Value::Background(b) => *b,
                    _ => Background::Color(colour(a.vec3("background")?, bg_span)?.to_array()),
                };
                let unbounded = match a.get("unbounded").0 {
                    Value::Contraction(c) => Some(Unbounded::Contract(*c)),
                    Value::Ndc => Some(Unbounded::Ndc(None)),
                    Value::Bool(true) => Some(Unbounded::Contract(Contraction { min: DEFAULT_BOX.0, max: DEFAULT_BOX.1 })),
                    Value::Bool(false) => None,
                    other => return Err(type_error(a.get("unbounded").1, "contraction", other)),
                };
                if let Some(u) = &unbounded {
                    unbounded_grids(a, u)?;
                }
                let view_dependent = matches!(a.get("view_dependent").0, Value::Bool(true));
                let direction = if view_dependent { Some(encoding("direction")?) } else { None };
                if matches!(a.get("occupancy").0, Value::Occupancy(o) if o.resolution > 0) && a.count("fine", 0, MAX_SAMPLES)? > 0 {
                    return Err(value_error(
                        a.get("fine").1,
                        "fine samples and an occupancy grid both decide where to sample",
                        "with an occupancy grid",
                        "use one: `fine: 0`, or `occupancy: occupancy_grid(resolution: 0)`",
                    ));
                }
                if let Some(Encoding::HashGrid(_)) = direction {
                    return Err(value_error(
                        a.get("direction").1,
                        "a hash grid encodes positions, not directions",
                        "a hash grid",
                        "encode the direction with `harmonic(freqs: 2)`",
                    ));
                }
                Ok(Value::Field(Arc::new(Field::Nerf(Nerf {
                    position: encoding("position")?,
                    direction,
                    layers,
                    width,
                    skips,
                    color_width: a.count("color_width", 1, 4096)? as usize,
                    fine: a.count("fine", 0, MAX_SAMPLES)? as usize,
                    background,
                    background_at: crate::value::WrittenAt(bg_span),
                    unbounded,
                    seed: a.count("seed", 0, u32::MAX as u64)?,
                    occupancy: match a.get("occupancy").0 {
                        Value::Occupancy(o) if o.resolution > 0 => Some(*o),
                        Value::Occupancy(_) => None,
                        other => return Err(type_error(a.get("occupancy").1, "occupancy grid", other)),
                    },
                    density: {
                        let (d, span) = a.string("density")?;
                        match &*d {
                            "relu" => DensityActivation::Relu,
                            "exp" => DensityActivation::Exp,
                            "softplus" => DensityActivation::Softplus,
                            other => {
                                return Err(value_error(
                                    span,
                                    format!("unknown density activation `{other}`"),
                                    "not a choice",
                                    "use \"relu\", \"softplus\" or \"exp\"",
                                ))
                            }
                        }
                    },
                    precision: {
                        let (p, span) = a.string("precision")?;
                        match &*p {
                            "fp32" => Precision::Fp32,
                            "bf16" => Precision::Bf16,
                            other => {
                                return Err(value_error(
                                    span,
                                    format!("unknown precision `{other}`"),
                                    "not a number format",
                                    "use \"fp32\" or \"bf16\"",
                                ))
                            }
                        }
                    },
                }))))
            },
        ),
    ]
}

/// In an unbounded scene the grids cover the contracted cube [-2, 2]³
/// (NDC's box): a box given to the hash grid or the occupancy grid would
/// disagree with the contraction's inner box, so it is refused (one
/// setting, not three).
fn unbounded_grids(a: &Args, u: &Unbounded) -> Result<(), Diag> {
    let boxes = [
        (
            "position",
            match a.get("position").0 {
                Value::Encoding(Encoding::HashGrid(g)) => Some((g.min, g.max)),
                _ => None,
            },
        ),
        (
            "occupancy",
            match a.get("occupancy").0 {
                Value::Occupancy(o) if o.resolution > 0 => Some((o.min, o.max)),
                _ => None,
            },
        ),
    ];
    for (name, b) in boxes {
        if b.is_some_and(|b| b != DEFAULT_BOX) {
            return Err(value_error(
                a.get(name).1,
                match u {
                    Unbounded::Contract(_) => "in an unbounded scene the grids cover the contracted cube [-2, 2]³, not a box of their own",
                    Unbounded::Ndc(_) => "in NDC the grids cover the NDC box [-1.5, 1.5] x [-1.5, 1.5] x [-1, 1], not a box of their own",
                },
                "a box given here",
                match u {
                    Unbounded::Contract(_) => "drop `min` and `max` from this grid and give the inner box to `contraction(min: ..., max: ...)`",
                    Unbounded::Ndc(_) => "drop `min` and `max` from this grid",
                },
            ));
        }
    }
    Ok(())
}

/// A field's hidden layers: its `network` argument, or its `layers`,
/// `width` and `skips` (one or the other, not both).
fn hidden_layers(a: &Args) -> Result<Mlp, Diag> {
    if !a.given("network") {
        let (layers, width) = network_size(a)?;
        return Ok(Mlp {
            layers,
            width,
            skips: skip_layers(a, layers)?,
        });
    }
    if let Some(name) = ["layers", "width", "skips"]
        .into_iter()
        .find(|n| a.given(n))
    {
        return Err(value_error(
            a.get(name).1,
            format!("`{name}` and `network` both give the hidden layers"),
            "also set by `network`",
            format!("give one: move `{name}` into `mlp(...)`, or drop `network`"),
        ));
    }
    match a.get("network") {
        (Value::Network(m), _) => Ok((**m).clone()),
        (other, span) => Err(type_error(span, "network", other)),
    }
}

/// A hash-grid SDF's hidden layers: as [`hidden_layers`], but one layer
/// of 64 where none is given, and no skips (the network sees features,
/// not the point, so repeating them adds nothing).
fn hash_sdf_layers(a: &Args) -> Result<Mlp, Diag> {
    let given = ["network", "layers", "width", "skips"]
        .into_iter()
        .any(|n| a.given(n));
    let mlp = if !given {
        Mlp {
            layers: 1,
            width: 64,
            skips: Vec::new(),
        }
    } else if a.given("network") {
        hidden_layers(a)?
    } else {
        let layers = if a.given("layers") {
            a.count("layers", 1, 32)? as usize
        } else {
            1
        };
        let width = if a.given("width") {
            a.count("width", 1, 4096)? as usize
        } else {
            64
        };
        if layers * width * width > MAX_NETWORK_WEIGHTS {
            return Err(value_error(
                a.get("width").1,
                format!("{layers} layers of {width} hold more than {MAX_NETWORK_WEIGHTS} weights"),
                "too wide for its depth",
                "use fewer or narrower layers",
            ));
        }
        let skips = if a.given("skips") {
            skip_layers(a, layers)?
        } else {
            Vec::new()
        };
        Mlp {
            layers,
            width,
            skips,
        }
    };
    if !mlp.skips.is_empty() {
        let name = if a.given("network") {
            "network"
        } else {
            "skips"
        };
        return Err(value_error(
            a.get(name).1,
            "a hash-grid SDF's network has no skips",
            "skips with a hash grid",
            "give `skips: []` (e.g. `mlp(layers: 1, width: 64, skips: [])`)",
        ));
    }
    Ok(mlp)
}

/// The `layers` and `width` of a network, refused past
/// [`MAX_NETWORK_WEIGHTS`].
fn network_size(a: &Args) -> Result<(usize, usize), Diag> {
    let layers = a.count("layers", 1, 32)? as usize;
    let width = a.count("width", 1, 4096)? as usize;
    if layers * width * width > MAX_NETWORK_WEIGHTS {
        return Err(value_error(
            a.get("width").1,
            format!(
                "{layers} layers of {width} hold about {} weights, more than {MAX_NETWORK_WEIGHTS}",
                layers * width * width
            ),
            "too wide for its depth",
            "use fewer or narrower layers",
        ));
    }
    Ok((layers, width))
}

/// The `skips` argument: distinct later layers (1 ≤ k < layers), sorted.
fn skip_layers(a: &Args, layers: usize) -> Result<Vec<usize>, Diag> {
    let (skips_v, skips_span) = a.get("skips");
    let mut skips = Vec::new();
    if let Value::List(items) = skips_v {
        for item in items.iter() {
            match item {
                Value::Number(x) if x.fract() == 0.0 && *x >= 1.0 && (*x as usize) < layers => {
                    skips.push(*x as usize)
                }
                _ => {
                    return Err(value_error(
                        skips_span,
                        format!("a skip must name a hidden layer from 1 to {}", layers - 1),
                        "not a later hidden layer",
                        "layer 0 sees the input already; e.g. `skips: [3]` for 6 layers",
                    ))
                }
            }
        }
    }
    skips.sort_unstable();
    skips.dedup();
    Ok(skips)
}

/// The box of a grid from its `min` and `max` arguments: non-empty on
/// every axis.
fn box_arg(a: &Args) -> Result<(DVec3, DVec3), Diag> {
    let (min, max) = (a.vec3("min")?, a.vec3("max")?);
    if !min.cmplt(max).all() {
        return Err(value_error(
            a.get("max").1,
            "the box is empty",
            "not above `min` on every axis",
            "give `max` larger than `min` in x, y and z",
        ));
    }
    Ok((min, max))
}
