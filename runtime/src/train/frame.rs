//! Where a trained model sits relative to the data it was trained on, as a
//! checkpoint's metadata records it (docs/checkpoints.md), so that the
//! file can be evaluated at points of the data's own frame without sdfl:
//!
//! * `data_to_model`: the similarity the data loader applied (a capture's
//!   normalisation, IDR's `scale_mat`, a point cloud's centring):
//!   `x_model = scale · R · (x_data − center)`;
//! * `warp`: how model-frame positions reach the encoding (none, scene
//!   contraction, or a forward-facing capture's NDC);
//! * `background`: what a ray sees behind the field;
//! * `training_cameras`: where the training views were taken from, in the
//!   model's frame (a viewer starts beside them).
//!
//! Files written before these keys load as identity, no warp and no
//! background; a present value is checked like any input.

use glam::{DMat3, DVec3};
use serde_json::{json, Value};

use sdfl_stdlib::value::{Background, Contraction, Field, LearnedBackground, NdcFrame, Unbounded};

use crate::data::normalize::SceneFrame;

/// The metadata key of the data → model similarity.
pub const DATA_TO_MODEL: &str = "data_to_model";
/// The metadata key of the warp.
pub const WARP: &str = "warp";
/// The metadata key of the background.
pub const BACKGROUND: &str = "background";
/// The metadata key of the training cameras.
pub const TRAINING_CAMERAS: &str = "training_cameras";
/// At most this many training cameras are recorded (evenly spaced over
/// the views): a viewer needs where they are, not every one of thousands,
/// and the checkpoint's header stays small (about 100 bytes each).
pub const RECORDED_CAMERAS: usize = 256;

/// Positions and lengths sdfl reads are within this magnitude (and above
/// its inverse where not zero), so a recorded frame is too.
const MAGNITUDE: f64 = 1e18;
/// How far a recorded rotation may be from orthonormal (f64 rounding of a
/// rotation built from f64 axes is far below it).
const ORTHONORMAL: f64 = 1e-6;

/// What a ray sees where it leaves the field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Behind {
    /// Nothing: the model is never rendered against one (a point fit).
    None,
    /// A fixed linear RGB colour.
    Color([f64; 3]),
    /// A colour learned from the ray's direction (the model's
    /// `background_layers`).
    Learned(LearnedBackground),
}

/// Where a training view was taken from, in the model's frame: a pinhole
/// looking from `eye` at `at` (its lens's `fy` as [`Camera::focal`]).
///
/// [`Camera::focal`]: sdfl_stdlib::camera::Camera::focal
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrainingCamera {
    /// The camera's position.
    pub eye: DVec3,
    /// A point on its optical axis.
    pub at: DVec3,
    /// Roughly up.
    pub up: DVec3,
    /// Focal length in NDC units of the image's shorter side.
    pub focal: f64,
}

impl TrainingCamera {
    /// Where `camera` stands and looks.
    pub fn of(camera: &sdfl_stdlib::camera::Camera) -> TrainingCamera {
        TrainingCamera {
            eye: camera.eye,
            at: camera.at,
            up: camera.up,
            focal: camera.focal,
        }
    }
}

/// A model's place relative to its data.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelFrame {
    /// Data frame → model frame: `x_model = scale·R·(x_data − center)`
    /// (`applied` is not recorded).
    pub data_to_model: SceneFrame,
    /// Model frame → the encoding's input (`None`: the model frame itself);
    /// never an NDC whose camera is unknown.
    pub warp: Option<Unbounded>,
    /// What its rays see behind it.
    pub background: Behind,
    /// Where its training views were taken from (at most
    /// [`RECORDED_CAMERAS`], evenly spaced); empty where unknown.
    pub cameras: Vec<TrainingCamera>,
}

impl Default for ModelFrame {
    /// What a file without the keys means: the data's frame, no warp, no
    /// background.
    fn default() -> Self {
        ModelFrame {
            data_to_model: SceneFrame::IDENTITY,
            warp: None,
            background: Behind::None,
            cameras: Vec::new(),
        }
    }
}

impl ModelFrame {
    /// The warp and background `field` declares, in the data's frame until
    /// [`Self::in_data_frame`] says otherwise. An NDC whose camera is not
    /// yet known (before the capture is read) is recorded as no warp.
    pub fn of(field: &Field) -> ModelFrame {
        let (warp, background) = match field {
            Field::Nerf(n) => (
                n.unbounded.filter(|u| *u != Unbounded::Ndc(None)),
                match n.background {
                    Background::Learned(l) => Behind::Learned(l),
                    b => Behind::Color(b.color().unwrap_or([0.0; 3])),
                },
            ),
            Field::NeuralSurface(s) => (None, Behind::Color(s.background)),
            // An analytic field composites over nothing: black.
            Field::Sdf(_) => (None, Behind::Color([0.0; 3])),
            Field::NeuralSdf(_) => (None, Behind::None),
        };
        ModelFrame {
            data_to_model: SceneFrame::IDENTITY,
            warp,
            background,
            cameras: Vec::new(),
        }
    }

    /// This frame with the training views' `cameras` (in the model's
    /// frame), at most [`RECORDED_CAMERAS`] of them evenly spaced.
    pub fn with_cameras<'c>(
        self,
        cameras: impl ExactSizeIterator<Item = &'c sdfl_stdlib::camera::Camera>,
    ) -> ModelFrame {
        let n = cameras.len();
        let every = n.div_ceil(RECORDED_CAMERAS).max(1);
        ModelFrame {
            cameras: cameras.step_by(every).map(TrainingCamera::of).collect(),
            ..self
        }
    }

    /// This frame with the data loader's similarity (`None`: the data's
    /// own frame).
    pub fn in_data_frame(self, frame: Option<SceneFrame>) -> ModelFrame {
        ModelFrame {
            data_to_model: SceneFrame {
                applied: None,
                ..frame.unwrap_or(SceneFrame::IDENTITY)
            },
            ..self
        }
    }

    /// The four metadata entries.
    pub fn metadata(&self) -> [(String, String); 4] {
        let f = &self.data_to_model;
        let data_to_model = json!({
            "scale": f.scale,
            "center": f.center,
            "rotation": f.rotation,
            "map": "x_model = scale * rotation @ (x_data - center); a direction d_model = rotation @ d_data; a length or distance in the model is scale times the data's",
        });
        let warp = match &self.warp {
            None => json!({ "kind": "none" }),
            Some(Unbounded::Contract(c)) => json!({
                "kind": "contraction",
                "min": c.min,
                "max": c.max,
                "map": "y = (x - (min + max)/2) * 2/(max - min); m = max_i |y_i|; the encoding sees y where m <= 1, else (2 - 1/m) * y/m",
            }),
            Some(Unbounded::Ndc(Some(f))) => json!({
                "kind": "ndc",
                "width": f.width,
                "height": f.height,
                "fx": f.fx,
                "fy": f.fy,
                "near": f.near,
                "map": "z = min(x_2, -0.001 * near); the encoding sees (-2 fx/width * x_0/z, -2 fy/height * x_1/z, 1 + 2 near/z); directions are not warped",
            }),
            // Not a frame `of` records (its camera is unknown).
            Some(Unbounded::Ndc(None)) => json!({ "kind": "none" }),
        };
        let background = match self.background {
            Behind::None => json!({ "kind": "none" }),
            Behind::Color(c) => json!({ "kind": "color", "color": c }),
            Behind::Learned(l) => json!({
                "kind": "learned",
                "freqs": l.freqs,
                "width": l.width,
                "layers": ["background.hidden", "background.out"],
                "input": "the ray's unit direction in the model's frame",
            }),
        };
        let cameras: Vec<Value> = self
            .cameras
            .iter()
            .map(|c| {
                json!({
                    "eye": c.eye.to_array(),
                    "at": c.at.to_array(),
                    "up": c.up.to_array(),
                    "focal": c.focal,
                })
            })
            .collect();
        let cameras = json!({
            "frame": "model",
            "cameras": cameras,
            "map": "each looks from eye at at, up roughly up, focal in NDC units of the image's shorter side; divide by data_to_model for the data's frame",
        });
        [
            (DATA_TO_MODEL.to_string(), data_to_model.to_string()),
            (WARP.to_string(), warp.to_string()),
            (BACKGROUND.to_string(), background.to_string()),
            (TRAINING_CAMERAS.to_string(), cameras.to_string()),
        ]
    }

    /// The frame a file's metadata records (`get` its entries), each key
    /// missing meaning identity, no warp, no background. A present value
    /// that is malformed, not finite or out of range is an error naming
    /// its key.
    pub fn from_metadata<'m>(get: impl Fn(&str) -> Option<&'m str>) -> Result<ModelFrame, String> {
        let parse = |key: &str| -> Result<Option<Value>, String> {
            get(key)
                .map(|s| serde_json::from_str(s).map_err(|_| format!("bad `{key}`: not JSON")))
                .transpose()
        };
        let bad = |key: &str, e: String| format!("bad `{key}`: {e}");
        let mut frame = ModelFrame::default();
        if let Some(v) = parse(DATA_TO_MODEL)? {
            frame.data_to_model = similarity(&v).map_err(|e| bad(DATA_TO_MODEL, e))?;
        }
        if let Some(v) = parse(WARP)? {
            frame.warp = warp(&v).map_err(|e| bad(WARP, e))?;
        }
        if let Some(v) = parse(BACKGROUND)? {
            frame.background = background(&v).map_err(|e| bad(BACKGROUND, e))?;
        }
        if let Some(v) = parse(TRAINING_CAMERAS)? {
            frame.cameras = training_cameras(&v).map_err(|e| bad(TRAINING_CAMERAS, e))?;
        }
        Ok(frame)
    }
}

/// A number of `v[key]`.
fn number(v: &Value, key: &str) -> Result<f64, String> {
    v.get(key)
        .and_then(Value::as_f64)
        .ok_or_else(|| format!("no number `{key}`"))
}

/// Three numbers of `v[key]`, each finite and within [`MAGNITUDE`].
#[doc(hidden)]
pub fn vec3(v: &Value, key: &str) -> Result<[f64; 3], String> {
    let a: [f64; 3] = v
        .get(key)
        .and_then(|x| serde_json::from_value(x.clone()).ok())
        .ok_or_else(|| format!("`{key}` is not three numbers"))?;
    if let Some(x) = a.iter().find(|x| x.is_nan() || x.abs() > MAGNITUDE) {
        return Err(format!("`{key}` holds {x}, beyond ±1e18"));
    }
    Ok(a)
}

/// The kind of a warp or background record.
fn kind(v: &Value) -> Result<&str, String> {
    v.get("kind")
        .and_then(Value::as_str)
        .ok_or_else(|| "no `kind`".to_string())
}

fn similarity(v: &Value) -> Result<SceneFrame, String> {
    let scale = number(v, "scale")?;
    if !(scale.is_finite() && (1.0 / MAGNITUDE..=MAGNITUDE).contains(&scale)) {
        return Err(format!("its scale is {scale}, not a number in 1e-18..1e18"));
    }
    let center = vec3(v, "center")?;
    let rows: [[f64; 3]; 3] = v
        .get("rotation")
        .and_then(|x| serde_json::from_value(x.clone()).ok())
        .ok_or("`rotation` is not 3 rows of 3 numbers")?;
    let r = DMat3::from_cols_array_2d(&rows).transpose();
    // Rows of a rotation are orthonormal (a reflection would still map
    // points, but sdfl never makes one; either way lengths are kept).
    let gram = r * r.transpose() - DMat3::IDENTITY;
    if !gram.to_cols_array().iter().all(|e| e.abs() <= ORTHONORMAL) {
        return Err(format!("`rotation` {rows:?} is not a rotation"));
    }
    Ok(SceneFrame::new(scale, DVec3::from_array(center), r))
}

fn warp(v: &Value) -> Result<Option<Unbounded>, String> {
    match kind(v)? {
        "none" => Ok(None),
        "contraction" => {
            let (min, max) = (vec3(v, "min")?, vec3(v, "max")?);
            // Finite (`vec3`), so no NaN slips through.
            if (0..3).any(|a| min[a] >= max[a]) {
                return Err(format!("its box {min:?}..{max:?} is empty"));
            }
            Ok(Some(Unbounded::Contract(Contraction { min, max })))
        }
        "ndc" => {
            let f = NdcFrame {
                width: number(v, "width")?,
                height: number(v, "height")?,
                fx: number(v, "fx")?,
                fy: number(v, "fy")?,
                near: number(v, "near")?,
            };
            let positive = |x: f64| x.is_finite() && x > 0.0 && x <= MAGNITUDE;
            if ![f.width, f.height, f.fx, f.fy, f.near]
                .into_iter()
                .all(positive)
            {
                return Err(format!(
                    "NDC needs positive image size, focal lengths and near plane (got {}x{}, fx {}, fy {}, near {})",
                    f.width, f.height, f.fx, f.fy, f.near
                ));
            }
            // The map's own check (its scales in range).
            f.scales()?;
            Ok(Some(Unbounded::Ndc(Some(f))))
        }
        k => Err(format!("unknown kind `{k}`")),
    }
}

fn training_cameras(v: &Value) -> Result<Vec<TrainingCamera>, String> {
    let list = v
        .get("cameras")
        .and_then(Value::as_array)
        .ok_or("`cameras` is not a list")?;
    if list.len() > RECORDED_CAMERAS {
        return Err(format!(
            "{} cameras, where sdfl records at most {RECORDED_CAMERAS}",
            list.len()
        ));
    }
    list.iter()
        .enumerate()
        .map(|(i, c)| {
            let at = |e: String| format!("camera {i}: {e}");
            let eye = DVec3::from_array(vec3(c, "eye").map_err(at)?);
            let look = DVec3::from_array(vec3(c, "at").map_err(at)?);
            let up = DVec3::from_array(vec3(c, "up").map_err(at)?);
            let focal = number(c, "focal").map_err(at)?;
            if !(focal.is_finite() && focal > 0.0 && focal <= MAGNITUDE) {
                return Err(at(format!("its focal length {focal} is not positive")));
            }
            // A camera must look somewhere, with an up not along the view.
            let forward = (look - eye).normalize_or_zero();
            if forward == DVec3::ZERO || forward.cross(up).length() <= 1e-9 * up.length() {
                return Err(at("it looks nowhere, or up along its view".to_string()));
            }
            Ok(TrainingCamera {
                eye,
                at: look,
                up,
                focal,
            })
        })
        .collect()
}

fn background(v: &Value) -> Result<Behind, String> {
    match kind(v)? {
        "none" => Ok(Behind::None),
        "color" => {
            let c = vec3(v, "color")?;
            if c.iter().any(|x| !(0.0..=1.0).contains(x)) {
                return Err(format!("its colour {c:?} is not within 0..1"));
            }
            Ok(Behind::Color(c))
        }
        "learned" => {
            // The ranges `learned_background(...)` accepts.
            let count = |key: &str, lo: u64, hi: u64| -> Result<usize, String> {
                match v.get(key).and_then(Value::as_u64) {
                    Some(n) if (lo..=hi).contains(&n) => Ok(n as usize),
                    _ => Err(format!("`{key}` is not a whole number in {lo}..{hi}")),
                }
            };
            Ok(Behind::Learned(LearnedBackground {
                freqs: count("freqs", 0, 8)?,
                width: count("width", 1, 256)?,
            }))
        }
        k => Err(format!("unknown kind `{k}`")),
    }
}
