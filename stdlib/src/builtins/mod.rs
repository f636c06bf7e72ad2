//! The built-in functions and statements: signature, docs and evaluation of
//! each, in one table. Defaults are sdfl source text, evaluated by the
//! language itself.

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};
use std::sync::{Arc, OnceLock};

use glam::DVec3;
use sdfl_lang::diag::{codes, Diag};
use sdfl_lang::types::{BlockSig, Env, Param, Signature, Type};
use sdfl_lang::Span;

use crate::camera::{Camera, OrbitUp, PixelCenters};
use crate::effects::{AmbientOcclusion, Fog, SoftShadows, MAX_SAMPLES_PER_PIXEL};
use crate::material::{Effects, Light, Material};
use crate::param::{Arg, Bound, ParamDecl, ParamInit, ParamUse, MIN_BETA, MIN_LENGTH};
use crate::precision::{beta, f32_range};
use crate::shape::{
    ArgKind, ArgReader, Axis, CappedCone, Check, Cuboid, Declared, KindVisitor, Primitive, Shape,
};
use crate::value::{
    describe, Backend, CaptureFormat, CaptureOrient, CaptureSpec, CloudCrop, Colormap, Dataset,
    DensityActivation, DensityKind, Encoding, Field, Harmonic, HashGridSpec, HitTolerance,
    LastInterval, Loss, LossKind, MeshRegion, Moments, Nerf, NeuralSdf, NeuralSurface, ObjectMasks,
    OccupancySpec, Optimizer, Output, OutputKind, Precision, RenderJob, Sampler, Schedule,
    SdfField, TrainJob, Value, ViewPath, VolumeJob,
};

/// The checker's type of shapes ([`Value::Shape`]).
pub const SHAPE: Type = Type::Named("shape");
/// The checker's type of materials.
pub const MATERIAL: Type = Type::Named("material");
/// The checker's type of cameras.
pub const CAMERA: Type = Type::Named("camera");
/// The checker's type of output files.
pub const OUTPUT: Type = Type::Named("output");
/// The checker's type of fields (volumes, neural fields).
pub const FIELD: Type = Type::Named("field");
/// The checker's type of ray samplers.
pub const SAMPLER: Type = Type::Named("sampler");
/// The checker's type of training data.
pub const DATASET: Type = Type::Named("data set");
/// The checker's type of optimisers.
pub const OPTIMIZER: Type = Type::Named("optimizer");
/// The checker's type of loss terms.
pub const LOSS: Type = Type::Named("loss");
/// The checker's type of input encodings.
pub const ENCODING: Type = Type::Named("encoding");
/// The checker's type of occupancy grids.
pub const OCCUPANCY: Type = Type::Named("occupancy grid");
/// The checker's type of network layouts.
pub const NETWORK: Type = Type::Named("network");
/// The checker's type of lights.
pub const LIGHT: Type = Type::Named("light");
/// The checker's type of soft shadows.
pub const SHADOWS: Type = Type::Named("soft shadow");
/// The checker's type of ambient occlusion.
pub const OCCLUSION: Type = Type::Named("ambient occlusion");
/// The checker's type of fog.
pub const FOG: Type = Type::Named("fog");
pub use crate::limits::{MAX_DOWNSCALE, MAX_IMAGE_SIDE, MAX_ITERATIONS, MAX_SAMPLES, MAX_VIEWS};

/// Arguments bound to parameter names, each with the span it came from
/// (the call's span for defaults).
mod args;
mod blocks;
mod common;
mod data;
mod lens;
mod materials;
mod neural;
mod outputs;
pub mod paths;
mod shapes;
mod volumes;

pub use args::Args;
pub(crate) use args::*;
pub(crate) use blocks::{render_block, train_block, volume_block};
use blocks::{render_sig, train_sig};
use common::*;
pub(crate) use common::{not_a_volume, one_or_list, unit_warnings};
pub use common::{random, safe_output_path};
use data::render_views;
use data::{check_input, Input};
use materials::{effects, fog_option, phong, samples_per_pixel};

/// How a built-in computes its value from its checked arguments.
pub type EvalFn = fn(&Args) -> Result<Value, Diag>;

/// A built-in function: its signature (for the checker, help and docs) and
/// its evaluation.
pub struct Builtin {
    /// Parameters, types, defaults and docs.
    pub sig: Signature,
    /// Computes the value.
    pub eval: EvalFn,
}

/// The standard library as the checker and evaluator see it.
pub struct StdEnv {
    builtins: Vec<Builtin>,
    index: HashMap<&'static str, usize>,
    blocks: Vec<BlockSig>,
    constants: Vec<(&'static str, f64)>,
}

impl StdEnv {
    /// The one standard library, built on first use.
    pub fn get() -> &'static StdEnv {
        static ENV: OnceLock<StdEnv> = OnceLock::new();
        ENV.get_or_init(|| {
            let builtins = table();
            let index = builtins
                .iter()
                .enumerate()
                .map(|(i, b)| (b.sig.name, i))
                .collect();
            StdEnv {
                builtins,
                index,
                blocks: vec![render_sig(), train_sig()],
                constants: vec![("pi", std::f64::consts::PI), ("tau", std::f64::consts::TAU)],
            }
        })
    }

    /// The built-in function of that name.
    pub fn builtin(&self, name: &str) -> Option<&Builtin> {
        self.index.get(name).map(|i| &self.builtins[*i])
    }

    /// Every built-in function, in the order the reference lists them.
    pub fn builtins(&self) -> &[Builtin] {
        &self.builtins
    }

    /// The statement of that keyword.
    pub fn block_sig(&self, kind: &str) -> Option<&BlockSig> {
        self.blocks.iter().find(|b| b.kind == kind)
    }

    /// Every statement's signature.
    pub fn blocks(&self) -> &[BlockSig] {
        &self.blocks
    }

    /// The value of the built-in constant of that name (`pi`, `tau`).
    pub fn constant_value(&self, name: &str) -> Option<Value> {
        self.constants
            .iter()
            .find(|c| c.0 == name)
            .map(|c| Value::Number(c.1))
    }
}

impl Env for StdEnv {
    fn function(&self, name: &str) -> Option<&Signature> {
        self.builtin(name).map(|b| &b.sig)
    }
    fn block(&self, kind: &str) -> Option<&BlockSig> {
        self.block_sig(kind)
    }
    fn constant(&self, name: &str) -> Option<Type> {
        self.constant_value(name).map(|_| Type::Number)
    }
    fn function_names(&self) -> Vec<&'static str> {
        self.builtins.iter().map(|b| b.sig.name).collect()
    }
    fn block_names(&self) -> Vec<&'static str> {
        self.blocks.iter().map(|b| b.kind).collect()
    }
    fn constant_names(&self) -> Vec<&'static str> {
        self.constants.iter().map(|c| c.0).collect()
    }
}

// ------------------------------------------------------------------ the table

fn req(name: &'static str, ty: Type, doc: &'static str) -> Param {
    Param::required(name, ty, doc)
}
fn opt(name: &'static str, ty: Type, default: &'static str, doc: &'static str) -> Param {
    Param::optional(name, ty, default, doc)
}
fn num_or_vec() -> Type {
    Type::OneOf(vec![Type::Number, Type::Vec3])
}

fn func(
    name: &'static str,
    doc: &'static str,
    params: Vec<Param>,
    returns: Type,
    eval: EvalFn,
) -> Builtin {
    Builtin {
        sig: Signature {
            name,
            params,
            rest: None,
            named_rest: None,
            returns,
            doc,
        },
        eval,
    }
}

fn variadic(
    name: &'static str,
    doc: &'static str,
    rest: Param,
    returns: Type,
    eval: EvalFn,
) -> Builtin {
    Builtin {
        sig: Signature {
            name,
            params: Vec::new(),
            rest: Some(rest),
            named_rest: None,
            returns,
            doc,
        },
        eval,
    }
}

fn shape(s: Shape) -> Result<Value, Diag> {
    Ok(Value::Shape(Arc::new(s)))
}

fn math1(name: &'static str, doc: &'static str, eval: EvalFn) -> Builtin {
    func(
        name,
        doc,
        vec![req("x", Type::Number, "the argument")],
        Type::Number,
        eval,
    )
}

/// A number or a vector: the componentwise math built-ins' argument.
fn num_or_list() -> Type {
    Type::OneOf(vec![Type::Number, Type::list(Type::Number)])
}

/// A math built-in of one number, or of each component of a vector.
fn each(name: &'static str, doc: &'static str, eval: EvalFn) -> Builtin {
    func(
        name,
        doc,
        vec![req("x", num_or_list(), "a number or a vector")],
        Type::Any,
        eval,
    )
}

/// The numbers of a number (one) or a list of numbers, and whether it was
/// a list.
pub(crate) fn numbers_of(v: &Value) -> Option<(Vec<f64>, bool)> {
    match v {
        Value::Number(x) => Some((vec![*x], false)),
        Value::List(items) => items
            .iter()
            .map(|i| match i {
                Value::Number(x) => Some(*x),
                _ => None,
            })
            .collect::<Option<Vec<f64>>>()
            .map(|xs| (xs, true)),
        _ => None,
    }
}

/// A number, or a list of the numbers.
fn numbers_value(xs: Vec<f64>, scalar: bool) -> Value {
    if scalar {
        Value::Number(xs[0])
    } else {
        Value::List(Arc::new(xs.into_iter().map(Value::Number).collect()))
    }
}

/// `f` of `x`, or of each of its components.
fn map_each(a: &Args, name: &str, f: impl Fn(f64) -> f64) -> Result<Value, Diag> {
    let (v, span) = a.get("x");
    let Some((xs, list)) = numbers_of(v) else {
        return Err(type_error(span, "number or a vector", v));
    };
    let ys: Vec<f64> = xs.into_iter().map(f).collect();
    if let Some(bad) = ys.iter().find(|y| !y.is_finite()) {
        return finite(*bad, a, name);
    }
    Ok(numbers_value(ys, !list))
}

/// `f` of `x` and `y` (numbers broadcast over the other's components).
fn zip_each(a: &Args, name: &str, f: impl Fn(f64, f64) -> f64) -> Result<Value, Diag> {
    let (vx, sx) = a.get("x");
    let (vy, sy) = a.get("y");
    let (Some((xs, lx)), Some((ys, ly))) = (numbers_of(vx), numbers_of(vy)) else {
        let (v, s) = if numbers_of(vx).is_none() {
            (vx, sx)
        } else {
            (vy, sy)
        };
        return Err(type_error(s, "number or a vector", v));
    };
    let n = xs.len().max(ys.len());
    if (lx && ly && xs.len() != ys.len()) || n == 0 {
        return Err(value_error(
            a.span,
            format!(
                "`{name}` of vectors of {} and {} numbers",
                xs.len(),
                ys.len()
            ),
            "lengths differ",
            "give vectors of the same length, or a number",
        ));
    }
    let pick = |v: &[f64], i: usize| if v.len() == 1 { v[0] } else { v[i] };
    let zs: Vec<f64> = (0..n).map(|i| f(pick(&xs, i), pick(&ys, i))).collect();
    if let Some(bad) = zs.iter().find(|z| !z.is_finite()) {
        return finite(*bad, a, name);
    }
    Ok(numbers_value(zs, !(lx || ly)))
}

/// A vector of 1 to 4 numbers.
fn small_vector(a: &Args, name: &str) -> Result<Vec<f64>, Diag> {
    let (v, span) = a.get(name);
    match numbers_of(v) {
        Some((xs, true)) if (1..=4).contains(&xs.len()) => Ok(xs),
        _ => Err(type_error(span, "vector of up to 4 numbers", v)),
    }
}

fn finite(x: f64, args: &Args, what: &str) -> Result<Value, Diag> {
    if x.is_finite() {
        Ok(Value::Number(x))
    } else {
        Err(Diag::new(
            codes::ARITHMETIC,
            args.span,
            format!("{what} is not a finite number"),
        )
        .label(format!("gives {x}"))
        .help("check the argument's domain"))
    }
}

fn table() -> Vec<Builtin> {
    shapes::builtins()
        .into_iter()
        .chain(vec![
        // ---- materials
        func("rainbow", "Colour `clamp(|p - c|, 0.02, 0.98)`, `c` the primitive's centre.", vec![], MATERIAL, |_| {
            Ok(Value::Material(Arc::new(Material::Rainbow)))
        }),
        func(
            "constant",
            "One colour everywhere.",
            vec![req("color", Type::Vec3, "linear RGB in 0..1")],
            MATERIAL,
            |a| Ok(Value::Material(Arc::new(Material::Constant(a.color_arg("color")?)))),
        ),
        func(
            "lambert",
            "Diffuse shading under a directional light: `albedo·(ambient·ao + (1 - ambient)·max(0, n·light)·shadow)`; `shadow` and `ao` are 1 unless asked for.",
            vec![
                opt("albedo", Type::OneOf(vec![MATERIAL, Type::Vec3]), "rainbow()", "base colour or material"),
                opt("light", Type::Vec3, "[1, 1, 1]", "direction towards the light"),
                opt("ambient", Type::Number, "0.2", "light reaching surfaces facing away (0..1)"),
                opt("shadows", Type::OneOf(vec![SHADOWS, Type::Bool]), "false", "`soft(...)`: the scene blocks the light, with penumbrae (`false`: none, no shadow rays)"),
                opt("ao", Type::OneOf(vec![OCCLUSION, Type::Bool]), "false", "`ao(...)`: ambient occlusion darkens the ambient term (`false`: none)"),
            ],
            MATERIAL,
            |a| {
                let ambient = a.number("ambient")?;
                if !(0.0..=1.0).contains(&ambient) {
                    return Err(value_error(a.get("ambient").1, format!("`ambient` must be in 0..1, got {ambient}"), "out of 0..1", "use a fraction such as 0.2"));
                }
                Ok(Value::Material(Arc::new(Material::Lambert {
                    albedo: Box::new((*a.material("albedo")?).clone()),
                    light: a.direction("light")?,
                    ambient,
                    effects: effects(a)?,
                })))
            },
        ),
        func(
            "phong",
            "Blinn-Phong shading under directional lights: `albedo·ambient + Σ color·(albedo·(1 - ambient)·max(0, n·l) + specular·max(0, n·h)^shininess)`, `h = normalize(l - ray direction)`, clamped to 0..1. Depends on the view: highlights move with the camera.",
            vec![
                opt("albedo", Type::OneOf(vec![MATERIAL, Type::Vec3]), "rainbow()", "base colour or material (one that needs no view direction)"),
                opt("lights", Type::list(LIGHT), "[light()]", "directional lights (at least one)"),
                opt("ambient", Type::Number, "0.1", "light reaching surfaces facing away (0..1)"),
                opt("specular", Type::Number, "0.5", "strength of the highlight (0..1)"),
                opt("shininess", Type::Number, "32", "highlight exponent (> 0; larger is a smaller, sharper highlight)"),
                opt("shadows", Type::OneOf(vec![SHADOWS, Type::Bool]), "false", "`soft(...)`: the scene blocks each light, with penumbrae (`false`: none, no shadow rays)"),
                opt("ao", Type::OneOf(vec![OCCLUSION, Type::Bool]), "false", "`ao(...)`: ambient occlusion darkens the ambient term (`false`: none)"),
            ],
            MATERIAL,
            phong,
        ),
        func(
            "soft",
            "Soft shadows for `lambert`/`phong` (`shadows: soft(...)`): a ray is marched from the surface towards each light, and the light's visible fraction is `clamp(min over the ray of k·h/t, 0, 1)` (`h` the scene's distance at `t` along it; the classic penumbra estimate). Costs up to `steps` SDF evaluations per shaded pixel and light; a surface facing away from a light is in its own shadow (no ray).",
            vec![
                opt("k", Type::Number, "8", "hardness (> 0): larger is a narrower penumbra; 2..32 is usual"),
                opt("steps", Type::Number, "32", "most SDF evaluations of one shadow ray (1..4096); rays stop early in full shadow or past the render's `far`"),
            ],
            SHADOWS,
            |a| Ok(Value::Shadows(SoftShadows { k: a.positive("k")?, steps: a.count("steps", 1, MAX_SAMPLES)? as u32 })),
        ),
        func(
            "ao",
            "Ambient occlusion for `lambert`/`phong` (`ao: ao(...)`): the scene's distance at `samples` heights `h_i = distance·(i + 1/2)/samples` along the normal gives `ao = 1 - Σ w_i·clamp((h_i - d_i)/h_i, 0, 1) / Σ w_i`, `w_i = 1 - h_i/distance`; it multiplies the ambient term. 1 in the open, 0 where the space along the normal is filled. Costs `samples` SDF evaluations per shaded pixel.",
            vec![
                opt("samples", Type::Number, "5", "SDF evaluations along the normal (1..4096)"),
                opt("distance", Type::Number, "0.5", "how far from the surface occluders count (> 0, in scene units)"),
            ],
            OCCLUSION,
            |a| Ok(Value::Occlusion(AmbientOcclusion { samples: a.count("samples", 1, MAX_SAMPLES)? as u32, distance: a.positive("distance")? })),
        ),
        func(
            "fog",
            "Exponential fog for a `render` (`fog: fog(...)`): a point `t` along the ray shows `color + (surface - color)·exp(-density·t)`; misses are fogged as at `far`. No SDF evaluations.",
            vec![
                opt("color", Type::Vec3, "[0.7, 0.75, 0.8]", "the colour far things fade to (linear RGB in 0..1)"),
                opt("density", Type::Number, "0.2", "extinction per unit of distance (> 0): half the colour is left after ln(2)/density"),
            ],
            FOG,
            |a| {
                let (color, span) = (a.vec3("color")?, a.get("color").1);
                Ok(Value::Fog(Fog { color: colour(color, span)?, density: a.positive("density")? }))
            },
        ),
        func(
            "light",
            "A directional light for `phong`.",
            vec![
                opt("direction", Type::Vec3, "[1, 1, 1]", "direction from the surface towards the light (nonzero)"),
                opt("color", Type::Vec3, "[1, 1, 1]", "linear RGB intensity in 0..1"),
            ],
            LIGHT,
            |a| {
                let (color, span) = (a.vec3("color")?, a.get("color").1);
                Ok(Value::Light(Light { direction: a.direction("direction")?, color: colour(color, span)? }))
            },
        ),
        func("normals", "The surface normal as a colour, `(n + 1)/2`.", vec![], MATERIAL, |_| {
            Ok(Value::Material(Arc::new(Material::Normals)))
        }),
        // ---- cameras
        func(
            "look_at",
            "A camera at `eye` looking at `at` (PyTorch3D conventions, see docs/conventions.md).",
            vec![
                req("eye", Type::Vec3, "camera position"),
                opt("at", Type::Vec3, "[0, 0, 0]", "point looked at"),
                opt("up", Type::Vec3, "[0, 1, 0]", "up direction"),
                opt("focal", Type::Number, "1", "focal length in NDC units (> 0)"),
                opt("pixel_centers", Type::Str, "\"corners\"", "\"corners\" (docs/conventions.md: corner pixel centres at ±1) or \"half\" (centres half a pixel in, as the assignment's box_*.npy were rendered)"),
            ],
            CAMERA,
            |a| {
                let (centers, centers_span) = a.string("pixel_centers")?;
                let centers = match &*centers {
                    "corners" => PixelCenters::Corners,
                    "half" => PixelCenters::Half,
                    other => {
                        return Err(value_error(centers_span, format!("unknown pixel-centre convention `{other}`"), "not a convention", "use \"corners\" or \"half\""))
                    }
                };
                let cam = Camera::look_at(a.vec3("eye")?, a.vec3("at")?, a.vec3("up")?, a.positive("focal")?)
                    .with_pixel_centers(centers);
                if !cam.is_valid() {
                    return Err(value_error(a.span, "camera has no well-defined orientation", "eye equals `at`, or `up` is parallel to the view", "move `eye` away from `at` and pick an `up` not along the view direction"));
                }
                Ok(Value::Camera(cam))
            },
        ),
        func(
            "lens",
            "The same cameras seen through a real camera's lens: pixel focal lengths, principal point and distortion (OpenCV's models, as COLMAP and nerfstudio name them), for `size` images (scaled to other sizes). Renders through these cameras are what such a camera records, and `dataset` outputs write them as its intrinsics.",
            vec![
                req("cameras", Type::OneOf(vec![CAMERA, Type::list(CAMERA)]), "the cameras (their poses are kept)"),
                req("size", Type::list(Type::Number), "the image [width, height] the intrinsics are for"),
                req("focal", Type::list(Type::Number), "[fx, fy] in pixels"),
                opt("center", Type::list(Type::Number), "[]", "the principal point [cx, cy] in pixels (default: the image centre)"),
                opt("model", Type::Str, "\"pinhole\"", "\"pinhole\", \"opencv\" (distortion [k1, k2, p1, p2]) or \"opencv_fisheye\" ([k1, k2, k3, k4])"),
                opt("distortion", Type::list(Type::Number), "[]", "the model's coefficients"),
            ],
            Type::list(CAMERA),
            lens::lens,
        ),
        func(
            "orbit",
            "`views` cameras around the origin for a spiral GIF: θ = 2πk/views; up [0,1,0]: eye (r·cos(θ+π/2), 0, -r·sin(θ+π/2)); up [0,0,1]: eye (r·cos(θ+π/2), r·sin(θ+π/2), 2).",
            vec![
                opt("radius", Type::Number, "3", "distance from the axis (> 0)"),
                opt("up", Type::Vec3, "[0, 1, 0]", "[0, 1, 0] or [0, 0, 1]"),
                opt("focal", Type::Number, "1", "focal length in NDC units (> 0)"),
                opt("views", Type::Number, "20", "number of cameras"),
            ],
            Type::list(CAMERA),
            |a| {
                let up = match a.vec3("up")? {
                    v if v == DVec3::Y => OrbitUp::Y,
                    v if v == DVec3::Z => OrbitUp::Z,
                    v => {
                        return Err(value_error(
                            a.get("up").1,
                            format!("orbits go around [0, 1, 0] or [0, 0, 1], not [{}, {}, {}]", v.x, v.y, v.z),
                            "unsupported axis",
                            "use `up: [0, 1, 0]` or `up: [0, 0, 1]`, or build cameras with `look_at` in a `for`",
                        ))
                    }
                };
                let views = a.count("views", 1, MAX_VIEWS as u64)? as usize;
                let cams = Camera::orbit(a.positive("radius")?, up, a.positive("focal")?, views);
                Ok(Value::List(Arc::new(cams.into_iter().map(Value::Camera).collect())))
            },
        ),
        // ---- volumes, sampling, data, training
        func(
            "param",
            "Marks a number or vector as trainable: `train` fits it wherever it is used (shape, transform and blend arguments, colours, a field's `alpha` and `beta`). One `param` bound to a `let` and used twice is one parameter.",
            vec![req("value", Type::OneOf(vec![Type::Number, Type::Vec3]), "the initial value")],
            Type::Any,
            |a| {
                let (v, span) = a.get("value");
                // Only plain numbers and vectors are trainable values.
                if !matches!(v, Value::Number(_)) && v.as_vec3().is_none() {
                    return Err(type_error(span, "number or vector [x, y, z]", v));
                }
                let init = match v {
                    Value::Number(x) => ParamInit::Scalar(*x),
                    _ => ParamInit::Vec3(v.as_vec3().expect("checked above")),
                };
                // The evaluator numbers it.
                Ok(Value::Param(Arc::new(ParamDecl { id: 0, init, span, binding: None })))
            },
        ),
        func(
            "stratified",
            "`samples` depths evenly spaced from `near` to `far` inclusive; `jitter` moves each within its interval while training (with a NeRF's bounded occupancy grid, which marches fixed steps of (far − near)/samples, it moves each ray's steps by one offset of up to half a step).",
            vec![
                opt("samples", Type::Number, "64", "samples per ray"),
                opt("near", Type::Number, "0", "first depth (≥ 0)"),
                opt("far", Type::Number, "5", "last depth (> near)"),
                opt("jitter", Type::Bool, "false", "jitter samples during training (a seeded, resumable stream)"),
                opt("last_interval", Type::Str, "\"zero\"", "\"zero\": nothing absorbs beyond `far`; \"infinite\": the last sample's interval is 1e10, as the reference assignment's code (its images then depend on `far`)"),
            ],
            SAMPLER,
            |a| {
                let samples = a.count("samples", 2, MAX_SAMPLES)? as usize;
                let (near, far) = (a.number("near")?, a.number("far")?);
                check_range(a, near, far)?;
                let jitter = matches!(a.get("jitter").0, Value::Bool(true));
                let (last, last_span) = a.string("last_interval")?;
                let last_interval = match &*last {
                    "zero" => LastInterval::Zero,
                    "infinite" => LastInterval::Infinite,
                    other => {
                        return Err(value_error(last_span, format!("unknown last interval `{other}`"), "not a choice", "use \"zero\" or \"infinite\""))
                    }
                };
                Ok(Value::Sampler(Sampler { samples, near, far, jitter, last_interval }))
            },
        ),
        func(
            "views",
            "Training views from image files (`.npy` float32 H×W×3, or PNG), paths relative to the scene file, one camera each.",
            vec![
                req("images", Type::list(Type::Str), "image files"),
                req("cameras", Type::list(CAMERA), "the camera of each image"),
            ],
            DATASET,
            |a| {
                let (images_v, images_span) = a.get("images");
                let cameras = camera_list(a, "cameras")?;
                let Value::List(items) = images_v else { return Err(type_error(images_span, "list of file names", images_v)) };
                let mut images = Vec::new();
                for item in items.iter() {
                    match item {
                        Value::Str(p) => {
                            data::check_input(a, Path::new(p.as_ref()), images_span, data::Input::File)?;
                            images.push(std::path::PathBuf::from(p.as_ref()))
                        }
                        other => return Err(type_error(images_span, "list of file names", other)),
                    }
                }
                if images.len() != cameras.len() || images.is_empty() {
                    return Err(value_error(
                        images_span,
                        format!("{} images but {} cameras", images.len(), cameras.len()),
                        "counts differ",
                        "give one camera per image, in the same order",
                    ));
                }
                Ok(Value::Dataset(Arc::new(Dataset::Files { images, cameras })))
            },
        ),
        func(
            "render_views",
            "Views rendered by sdfl itself, with known ground truth: a field is volume-rendered (with `sampler`), a shape sphere-traced exactly as a `render` statement draws it (with `material`, `background`, `near`, `far`, `iterations`). `test_views` of the cameras, picked by a seeded shuffle, are held out as test views; `train_views` trains on fewer of the rest.",
            vec![
                req("scene", Type::OneOf(vec![SHAPE, FIELD]), "a field (volume-rendered) or a shape (sphere-traced)"),
                req("cameras", Type::list(CAMERA), "one camera per view"),
                opt("size", Type::list(Type::Number), "[128, 128]", "image width and height"),
                opt("sampler", SAMPLER, "stratified()", "depth samples (fields only)"),
                opt("material", Type::OneOf(vec![MATERIAL, Type::Vec3]), "rainbow()", "how hit points are coloured (shapes only)"),
                opt("background", Type::Vec3, "[0, 0, 0]", "colour of rays that miss (shapes only)"),
                opt("near", Type::Number, "0", "where rays start (shapes only, ≥ 0)"),
                opt("far", Type::Number, "5", "where rays give up (shapes only, > near)"),
                opt("iterations", Type::Number, "64", "most sphere-tracing steps per ray (shapes only)"),
                opt("hit_tolerance", Type::Str, "\"pixel\"", "shapes only: \"pixel\", a ray hits within half a pixel's width of the surface (silhouettes grow by up to that), as a `render` draws; \"absolute\", within 1e-5 with plain steps: each pixel shows what the thin ray through its centre meets, as training rays are cast (raise `iterations` for grazing rays)"),
                opt("test_views", Type::Number, "0", "how many cameras to hold out as test views (fewer than the cameras)"),
                opt("split_seed", Type::Number, "0", "seed of the shuffle that picks the test views"),
                opt("train_views", Type::Number, "0", "train on only this many of the cameras not held out (0: all), spread out: the first, then each next the farthest from those taken. The test views are held out of all the cameras first, so a fewer-views sweep over a fixed camera set scores every setting on the same views, and fewer views are a subset of more"),
            ],
            DATASET,
            render_views,
        ),
        func(
            "sphere_views",
            "`views` cameras spread evenly over a sphere (or the hemisphere above `up`) of `radius` around the origin, looking at it (a Fibonacci lattice: deterministic, no two alike): the usual NeRF camera set.",
            vec![
                opt("views", Type::Number, "100", "number of cameras"),
                opt("radius", Type::Number, "4", "distance from the origin (> 0)"),
                opt("up", Type::Vec3, "[0, 0, 1]", "the up direction of every camera, and the hemisphere's pole (nonzero)"),
                opt("focal", Type::Number, "1", "focal length in NDC units (> 0)"),
                opt("hemisphere", Type::Bool, "false", "only the half above the origin along `up`"),
            ],
            Type::list(CAMERA),
            |a| {
                let views = a.count("views", 1, MAX_VIEWS as u64)? as usize;
                let hemisphere = matches!(a.get("hemisphere").0, Value::Bool(true));
                let cams = Camera::sphere(views, a.positive("radius")?, a.direction("up")?, a.positive("focal")?, hemisphere);
                Ok(Value::List(Arc::new(cams.into_iter().map(Value::Camera).collect())))
            },
        ),
        func(
            "nerf_synthetic",
            "A NeRF-synthetic (Blender) data set: `transforms_<split>.json` (camera-to-world poses in OpenGL axes, `camera_angle_x`) and its RGBA images composited over `background`. `path` is the directory (relative to the scene file; a lone `transforms.json`, as sdfl's `dataset` output writes, is read when the split's file is missing) or a `.json` file.",
            vec![
                req("path", Type::Str, "the data set's directory, or its transforms .json file"),
                opt("split", Type::Str, "\"train\"", "which transforms file holds the training views"),
                opt("test_split", Type::Str, "\"\"", "which transforms file holds the test views (\"\": none), e.g. \"test\""),
                opt("background", Type::Vec3, "[1, 1, 1]", "colour behind transparent pixels"),
                opt("downscale", Type::Number, "1", "train and score at 1/N of the images' size a side (1 to 64, N dividing the width and height): each block of N×N pixels averaged once composited over `background` (alpha premultiplied), focal lengths and principal point scaled to match; Lego's 800² at 4 is 200²"),
            ],
            DATASET,
            |a| {
                let (path, path_span) = a.string("path")?;
                if path.is_empty() || path.contains('\0') {
                    return Err(Diag::new(codes::PATH, path_span, "not a usable path").label("empty or holds a NUL byte").help("name the data set's directory, e.g. \"data/lego\""));
                }
                let split_name = |name: &str| -> Result<Option<String>, Diag> {
                    let (v, span) = a.string(name)?;
                    if v.is_empty() {
                        return Ok(None);
                    }
                    if v.len() > 64 || !v.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
                        return Err(value_error(span, format!("`{name}` must be a plain name such as \"train\""), "not a plain name", "use letters, digits, `_` and `-` only (it names transforms_<split>.json)"));
                    }
                    Ok(Some(v.to_string()))
                };
                let Some(split) = split_name("split")? else {
                    return Err(value_error(a.get("split").1, "`split` is empty", "no split", "name the training split, e.g. \"train\""));
                };
                let test_split = split_name("test_split")?;
                data::check_nerf_synthetic(a, Path::new(path.as_ref()), &split, test_split.as_deref())?;
                let (bg, bg_span) = (a.vec3("background")?, a.get("background").1);
                let downscale = a.count("downscale", 1, MAX_DOWNSCALE)? as u32;
                Ok(Value::Dataset(Arc::new(Dataset::NerfSynthetic {
                    path: PathBuf::from(path.as_ref()),
                    path_span,
                    split,
                    test_split,
                    background: colour(bg, bg_span)?,
                    downscale,
                    downscale_span: a.get("downscale").1,
                })))
            },
        ),
        func(
            "capture",
            "A real capture: nerfstudio's `transforms.json` (as `ns-process-data` writes it: intrinsics global or per frame, `camera_model` PINHOLE / SIMPLE_PINHOLE / OPENCV / OPENCV_FISHEYE with its distortion, `mask_path`, split lists), COLMAP's text model (`sparse/0/cameras.txt`, `images.txt`, images in `images/`), LLFF's `poses_bounds.npy` (forward-facing) or IDR's and NeuS's layout (DTU, BlendedMVS: `image/`, object masks in `mask/` paired by sorted name, `cameras_sphere.npz` with `world_mat_i` and `scale_mat_i`). Cameras are centred and scaled into the unit cube as nerfstudio does (IDR: `scale_mat`'s unit sphere around the object, and exports come back in the world frame; the scene frame is reported); images with alpha are composited over `background`. An IDR capture's masks are what `silhouette()` trains on.",
            vec![
                req("path", Type::Str, "the capture's directory (relative to the scene file), or its transforms .json file"),
                opt("format", Type::Str, "\"auto\"", "\"auto\" (by the files present: transforms.json, a COLMAP model, poses_bounds.npy, cameras_sphere.npz), \"nerfstudio\", \"colmap\", \"llff\" or \"idr\""),
                opt("downscale", Type::Number, "1", "read images from `images_<downscale>` (1, 2, 4 or 8), intrinsics scaled to match (IDR: 1 only)"),
                opt("test_every", Type::Number, "8", "hold out every n-th frame (in file-name order) as a test view, where the data has no split lists (0: none)"),
                opt("normalize", Type::Bool, "true", "centre the cameras and scale them into [-1, 1]^3 (LLFF: its own recentring, nearest bound at 4/3; IDR: `scale_mat`'s unit sphere); false keeps the data's frame"),
                opt("orient", Type::Str, "\"up\"", "\"up\": turn the cameras' mean up onto +z; \"none\": keep the data's axes (LLFF and IDR keep their own)"),
                opt("background", Type::Vec3, "[1, 1, 1]", "colour behind transparent pixels of images with alpha; when given, also the model's background (not given: white there, and a model on the data's background learns the world behind)"),
                opt("object_masks", Type::Str, "\"coverage\"", "what IDR's object masks are for: \"coverage\" (what `silhouette()` trains on; held-out PSNR is also given inside them as `psnr_in_mask`) or \"alpha\" (also each photograph's alpha, composited over `background`, which must be given: outside the object the model learns the background, NeuS's \"with mask\" setting)"),
            ],
            DATASET,
            data::capture,
        ),
        func(
            "adam",
            "The Adam optimizer; the learning rate is multiplied by `decay` every `decay_every` steps (`schedule: \"step\"`), or smoothly, `lr·decay^(step/decay_every)` (`\"exponential\"`).",
            vec![
                opt("lr", Type::Number, "5e-4", "learning rate (> 0)"),
                opt("decay", Type::Number, "1", "learning-rate factor (0 < decay ≤ 1)"),
                opt("decay_every", Type::Number, "0", "steps between decays (0: never)"),
                opt("schedule", Type::Str, "\"step\"", "\"step\" or \"exponential\""),
                opt("beta1", Type::Number, "0.9", "decay of the gradient's running mean, in [0, 1)"),
                opt("beta2", Type::Number, "0.999", "decay of the squared gradient's running mean, in [0, 1) (instant-ngp: 0.99)"),
                opt("eps", Type::Number, "1e-8", "added to the root of the second moment (> 0; instant-ngp: 1e-15, so that rarely seen hash-table rows still move)"),
            ],
            OPTIMIZER,
            |a| {
                let decay = a.positive("decay")?;
                if decay > 1.0 {
                    return Err(value_error(a.get("decay").1, format!("`decay` must be at most 1, got {decay}"), "grows the rate", "use a factor such as 0.8"));
                }
                let every = a.count("decay_every", 0, u32::MAX as u64)? as usize;
                let (kind, kind_span) = a.string("schedule")?;
                let schedule = match (&*kind, every) {
                    (_, 0) => Schedule::Constant,
                    _ if decay == 1.0 => Schedule::Constant,
                    ("step", _) => Schedule::Step { factor: decay, every },
                    ("exponential", _) => Schedule::Exponential { factor: decay, every },
                    (other, _) => {
                        return Err(value_error(kind_span, format!("unknown schedule `{other}`"), "not a schedule", "use \"step\" or \"exponential\""))
                    }
                };
                let decay_rate = |name: &str| -> Result<f64, Diag> {
                    let b = a.number(name)?;
                    if (0.0..1.0).contains(&b) {
                        Ok(b)
                    } else {
                        Err(value_error(a.get(name).1, format!("`{name}` must be in [0, 1), got {b}"), "not a decay rate", "use a rate such as 0.9 or 0.99"))
                    }
                };
                let moments = Moments { beta1: decay_rate("beta1")?, beta2: decay_rate("beta2")?, eps: a.positive("eps")? };
                Ok(Value::Optimizer(Optimizer { lr: a.positive("lr")?, schedule, moments }))
            },
        ),
        func(
            "mse",
            "Mean squared error of rendered against true pixel colours, times `weight`.",
            vec![opt("weight", Type::Number, "1", "weight of this term (> 0)")],
            LOSS,
            |a| Ok(Value::Loss(Loss { kind: LossKind::Mse, weight: a.positive("weight")? })),
        ),
        func(
            "silhouette",
            "Binary cross-entropy of each ray's opacity against its pixel's coverage by the object (NeuS's mask loss), times `weight`. A neural SDF's volume only, on data that give each pixel's coverage: the views of a shape by `render_views` (whether each pixel's ray hits), or `nerf_synthetic(...)` and `capture(...)` images whose alpha is the coverage (an image without alpha is an error when read), or an IDR capture's masks. Unlike the colour error, it does not fade where the object is dark against the background.",
            vec![opt("weight", Type::Number, "0.1", "weight of this term (> 0)")],
            LOSS,
            |a| Ok(Value::Loss(Loss { kind: LossKind::Silhouette, weight: a.positive("weight")? })),
        ),
        // ---- math
        each("sin", "Sine (radians); of each component of a vector.", |a| map_each(a, "sin", f64::sin)),
        each("cos", "Cosine (radians); of each component of a vector.", |a| map_each(a, "cos", f64::cos)),
        math1("tan", "Tangent (radians).", |a| finite(a.number("x")?.tan(), a, "tan")),
        each("sqrt", "Square root (of a number ≥ 0); of each component of a vector.", |a| map_each(a, "sqrt", f64::sqrt)),
        each("abs", "Absolute value; of each component of a vector.", |a| map_each(a, "abs", f64::abs)),
        each("floor", "Largest whole number ≤ x; of each component of a vector.", |a| map_each(a, "floor", f64::floor)),
        each("fract", "The fractional part `x - floor(x)`; of each component of a vector.", |a| map_each(a, "fract", |x| x - x.floor())),
        each("sign", "-1, 0 or 1 as x is negative, zero or positive; of each component of a vector.", |a| {
            map_each(a, "sign", |x| if x > 0.0 { 1.0 } else if x < 0.0 { -1.0 } else { 0.0 })
        }),
        each("exp", "e to the power x; of each component of a vector.", |a| map_each(a, "exp", f64::exp)),
        func(
            "mod",
            "GLSL's `mod`: `x - y·floor(x/y)` (the sign of `y`); of each component when either is a vector.",
            vec![req("x", num_or_list(), "the dividend"), req("y", num_or_list(), "the divisor (nonzero)")],
            Type::Any,
            |a| zip_each(a, "mod", |x, y| x - y * (x / y).floor()),
        ),
        math1("log", "Natural logarithm (of a number > 0).", |a| finite(a.number("x")?.ln(), a, "log")),
        func(
            "clamp",
            "`x` limited to `lo..hi`.",
            vec![req("x", Type::Number, "the value"), req("lo", Type::Number, "lower limit"), req("hi", Type::Number, "upper limit (≥ lo)")],
            Type::Number,
            |a| {
                let (x, lo, hi) = (a.number("x")?, a.number("lo")?, a.number("hi")?);
                if lo > hi {
                    return Err(value_error(a.get("hi").1, format!("`hi` ({hi}) is below `lo` ({lo})"), "below lo", "give the limits in order"));
                }
                Ok(Value::Number(x.clamp(lo, hi)))
            },
        ),
        func(
            "mix",
            "Linear interpolation `a + (b - a)·t` of numbers or vectors (a number with a vector means that number in every component).",
            vec![req("a", num_or_vec(), "value at t = 0"), req("b", num_or_vec(), "value at t = 1"), req("t", Type::Number, "the fraction")],
            // A number or a vector, known from the arguments' values.
            Type::Any,
            |a| {
                let t = a.number("t")?;
                match (a.get("a").0, a.get("b").0) {
                    (Value::Number(_), Value::Number(_)) => {
                        let (x, y) = (a.number("a")?, a.number("b")?);
                        finite(x + (y - x) * t, a, "mix")
                    }
                    _ => {
                        let (x, y) = (a.vec3("a")?, a.vec3("b")?);
                        let v = x + (y - x) * t;
                        if !v.is_finite() {
                            return finite(f64::INFINITY, a, "mix");
                        }
                        Ok(Value::from_vec3(v))
                    }
                }
            },
        ),
        func("length", "Length of a vector (of 2, 3 or 4 numbers).", vec![req("v", Type::list(Type::Number), "the vector")], Type::Number, |a| {
            let v = small_vector(a, "v")?;
            finite(v.iter().map(|x| x * x).sum::<f64>().sqrt(), a, "length")
        }),
        func(
            "dot",
            "Dot product of two vectors (of the same length).",
            vec![req("a", Type::list(Type::Number), "first vector"), req("b", Type::list(Type::Number), "second vector")],
            Type::Number,
            |a| {
                let (x, y) = (small_vector(a, "a")?, small_vector(a, "b")?);
                if x.len() != y.len() {
                    return Err(value_error(a.span, format!("`dot` of vectors of {} and {} numbers", x.len(), y.len()), "lengths differ", "give vectors of the same length"));
                }
                finite(x.iter().zip(&y).map(|(x, y)| x * y).sum(), a, "dot")
            },
        ),
        func(
            "cross",
            "Cross product of two vectors.",
            vec![req("a", Type::Vec3, "first vector"), req("b", Type::Vec3, "second vector")],
            Type::Vec3,
            |a| Ok(Value::from_vec3(a.vec3("a")?.cross(a.vec3("b")?))),
        ),
        func("normalize", "The vector (of 2, 3 or 4 numbers) scaled to length 1 (nonzero).", vec![req("v", Type::list(Type::Number), "the vector")], Type::Any, |a| {
            let v = small_vector(a, "v")?;
            let len = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if len <= 1e-12 {
                return Err(value_error(a.get("v").1, "`v` must be a nonzero vector", "zero vector", "give a direction such as [0, 0, 1]"));
            }
            Ok(numbers_value(v.iter().map(|x| x / len).collect(), false))
        }),
        math1("radians", "Degrees to radians.", |a| finite(a.number("x")?.to_radians(), a, "radians")),
        func(
            "atan2",
            "Angle of the point (x, y) in radians.",
            vec![req("y", Type::Number, "y"), req("x", Type::Number, "x")],
            Type::Number,
            |a| finite(a.number("y")?.atan2(a.number("x")?), a, "atan2"),
        ),
        variadic(
            "min",
            "The smallest of one or more numbers; lists are flattened: `min(a, b, c)`, `min(xs)`.",
            req("x", Type::Number, "numbers or lists of numbers"),
            Type::Any,
            |a| extreme(a, "min", f64::min),
        ),
        variadic(
            "max",
            "The largest of one or more numbers; lists are flattened: `max(a, b, c)`, `max(xs)`.",
            req("x", Type::Number, "numbers or lists of numbers"),
            Type::Any,
            |a| extreme(a, "max", f64::max),
        ),
        func(
            "len",
            "The number of items of a list (3 for a vector).",
            vec![req("list", Type::list(Type::Any), "the list")],
            Type::Number,
            |a| match a.get("list") {
                (Value::List(items), _) => Ok(Value::Number(items.len() as f64)),
                (v, s) => Err(type_error(s, "list", v)),
            },
        ),
        func(
            "random",
            "A pseudo-random number in [0, 1), the same for the same `seed` and `i` on every machine: \
             SplitMix64 of the two numbers' bits. Vary `i` (a loop index) for a sequence, `seed` for another sequence.",
            vec![req("seed", Type::Number, "selects the sequence"), opt("i", Type::Number, "0", "position in the sequence")],
            Type::Number,
            |a| Ok(Value::Number(random(a.number("seed")?, a.number("i")?))),
        ),
        ])
        .chain(volumes::builtins())
        .chain(neural::builtins())
        .chain(outputs::builtins())
        .chain(paths::builtins())
        .collect()
}
