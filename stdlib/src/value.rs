//! Runtime values of the scene language and the scene IR they build.

use std::path::PathBuf;
use std::sync::Arc;

use glam::DVec3;

use crate::camera::Camera;
use crate::material::Material;
use crate::shape::Shape;

#[derive(Debug, Clone)]
pub enum Value {
    Number(f64),
    Bool(bool),
    Str(Arc<str>),
    List(Arc<Vec<Value>>),
    Shape(Arc<Shape>),
    Material(Arc<Material>),
    Camera(Camera),
    Output(Arc<Output>),
    /// The value of an expression that already produced a diagnostic.
    /// Anything computed from it is poison too, silently.
    Poison,
}

impl Value {
    pub fn type_name(&self) -> &'static str {
        match self {
            Value::Number(_) => "number",
            Value::Bool(_) => "bool",
            Value::Str(_) => "string",
            Value::List(_) => "list",
            Value::Shape(_) => "shape",
            Value::Material(_) => "material",
            Value::Camera(_) => "camera",
            Value::Output(_) => "output",
            Value::Poison => "invalid value",
        }
    }

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

    pub fn from_vec3(v: DVec3) -> Value {
        Value::List(Arc::new(
            v.to_array().iter().map(|x| Value::Number(*x)).collect(),
        ))
    }
}

/// What an output file holds.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputKind {
    /// Shaded colour, one PNG per view.
    Image,
    /// Shaded colour of all views as an animated GIF.
    Gif { fps: f64 },
    /// Hit depth normalised by its maximum and colour-mapped, PNG per view.
    Depth,
    /// Surface normals as colours, PNG per view.
    Normals,
    /// White where the ray hit, black where it missed, PNG per view.
    Mask,
}

/// A requested output file, relative to the output directory.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Output {
    pub kind: OutputKind,
    pub path: PathBuf,
}

/// One `render` statement, fully evaluated and validated.
#[derive(Debug, Clone)]
pub struct RenderJob {
    pub name: String,
    pub scene: Arc<Shape>,
    pub material: Arc<Material>,
    pub cameras: Vec<Camera>,
    pub width: u32,
    pub height: u32,
    pub near: f64,
    pub far: f64,
    pub iterations: u32,
    pub epsilon: f64,
    pub background: DVec3,
    pub outputs: Vec<Output>,
}

/// Everything a scene file asks for, in file order.
#[derive(Debug, Clone, Default)]
pub struct Program {
    pub renders: Vec<RenderJob>,
}
