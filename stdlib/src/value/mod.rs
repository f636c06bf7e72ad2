//! Runtime values of the scene language and the scene IR they build.

use std::sync::Arc;

use glam::DVec3;

use crate::camera::Camera;
use crate::material::Material;
use crate::param::ParamDecl;
use crate::shape::Shape;

mod dataset;
mod encoding;
mod field;
mod nerf;
mod outputs;
mod program;
mod render;
mod sampling;
mod train;
mod views;

pub use dataset::*;
pub use encoding::*;
pub use field::*;
pub use nerf::*;
pub use outputs::*;
pub use program::*;
pub use render::*;
pub use sampling::*;
pub use train::*;
pub use views::*;

#[derive(Debug, Clone)]
/// A value of the scene language: what an expression evaluates to.
pub enum Value {
    /// A number (f64 while evaluating; checked to fit f32 where the runtime uses it).
    Number(f64),
    /// `true` or `false`.
    Bool(bool),
    /// A string (paths, names, options such as `"bf16"`).
    Str(Arc<str>),
    /// A list; three numbers are also a vector.
    List(Arc<Vec<Value>>),
    /// A signed distance shape.
    Shape(Arc<Shape>),
    /// How a surface is shaded.
    Material(Arc<Material>),
    /// A directional light of a `phong` material.
    Light(crate::material::Light),
    /// Soft shadows of a lit material.
    Shadows(crate::effects::SoftShadows),
    /// Ambient occlusion of a lit material.
    Occlusion(crate::effects::AmbientOcclusion),
    /// Fog of a `render`.
    Fog(crate::effects::Fog),
    /// A camera (`look_at`, `orbit`'s items…).
    Camera(Camera),
    /// An output file a statement writes.
    Output(Arc<Output>),
    /// A number or vector marked trainable with `param(...)`.
    Param(Arc<ParamDecl>),
    /// A training objective term.
    Loss(Loss),
    /// A volume: an SDF seen as one, or a neural field.
    Field(Arc<Field>),
    /// Where samples fall along each ray.
    Sampler(Sampler),
    /// The images (or points) a `train` fits.
    Dataset(Arc<Dataset>),
    /// The optimiser of a `train`.
    Optimizer(Optimizer),
    /// A neural field's input encoding.
    Encoding(Encoding),
    /// An occupancy grid that skips empty space.
    Occupancy(OccupancySpec),
    /// The shape of a network's hidden layers, for `nerf(network: ...)` and
    /// `neural_sdf(network: ...)`.
    Network(Arc<Mlp>),
    /// What a NeRF's rays see behind the field: `data_background()`,
    /// `learned_background(...)` (a colour is a vector).
    Background(Background),
    /// Scene contraction for unbounded scenes: `contraction(...)`.
    Contraction(Contraction),
    /// Forward-facing scenes in normalised device coordinates: `ndc()`.
    Ndc,
    /// Cameras known only when a `train` runs (a loop through the training
    /// cameras of a data set read from files), as its `views`.
    ViewPath(ViewPath),
    /// A `fn` named as a value (`sdf(torus_d)`).
    Function(Arc<sdfl_lang::ast::FnDef>),
    /// The value of an expression that already produced a diagnostic.
    /// Anything computed from it is poison too, silently.
    Poison,
}

impl Value {
    /// The name of its type in messages ("a shape", "an output").
    pub fn type_name(&self) -> &'static str {
        match self {
            Value::Number(_) => "number",
            Value::Bool(_) => "bool",
            Value::Str(_) => "string",
            Value::List(_) => "list",
            Value::Shape(_) => "shape",
            Value::Material(_) => "material",
            Value::Light(_) => "light",
            Value::Shadows(_) => "soft shadow",
            Value::Occlusion(_) => "ambient occlusion",
            Value::Fog(_) => "fog",
            Value::Camera(_) => "camera",
            Value::Output(_) => "output",
            Value::Param(_) => "trainable parameter",
            Value::Loss(_) => "loss",
            Value::Field(_) => "field",
            Value::Sampler(_) => "sampler",
            Value::ViewPath(_) => "camera path",
            Value::Dataset(_) => "data set",
            Value::Optimizer(_) => "optimizer",
            Value::Encoding(_) => "encoding",
            Value::Occupancy(_) => "occupancy grid",
            Value::Network(_) => "network",
            Value::Background(_) => "background",
            Value::Contraction(_) => "contraction",
            Value::Ndc => "ndc",
            Value::Function(_) => "function",
            Value::Poison => "invalid value",
        }
    }

    /// Whether it is, or holds, [`Value::Poison`].
    pub fn is_poison(&self) -> bool {
        match self {
            Value::Poison => true,
            Value::List(items) => items.iter().any(Value::is_poison),
            _ => false,
        }
    }

    /// A vector from a list of three numbers.
    pub fn as_vec3(&self) -> Option<DVec3> {
        match self {
            Value::List(items) if items.len() == 3 => {
                let mut v = [0.0; 3];
                for (slot, item) in v.iter_mut().zip(items.iter()) {
                    match item {
                        Value::Number(x) => *slot = *x,
                        _ => return None,
                    }
                }
                Some(DVec3::from_array(v))
            }
            _ => None,
        }
    }

    /// A list of three numbers.
    pub fn from_vec3(v: DVec3) -> Value {
        Value::List(Arc::new(
            v.to_array().iter().map(|x| Value::Number(*x)).collect(),
        ))
    }
}

/// A short description of a value for messages ("number 2", "list of 3
/// items", "shape").
pub(crate) fn describe(v: &Value) -> String {
    match v {
        Value::Number(x) => format!("number {}", sdfl_lang::fmt_num(*x)),
        Value::List(items) => format!("list of {} items", items.len()),
        other => other.type_name().to_string(),
    }
}

pub use crate::density::DensityKind;
