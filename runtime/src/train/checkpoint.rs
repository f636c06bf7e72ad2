//! Resumable training state as a safetensors file: every parameter, Adam's
//! moments and step count, the loss history, the step reached, and a
//! fingerprint of what the run depends on (model, data, sampler, optimiser
//! and objective). A resumed run continues the same run; a checkpoint whose
//! fingerprint differs is refused, naming what changed.

use std::collections::HashMap;
use std::io;
use std::path::Path;

use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde_json::Value;

use super::export_names::Piece;
use super::frame::ModelFrame;
use super::log::{HeldOut, History};

use crate::output::Atomic;

/// What changed between a checkpoint and the current run, part by part.
pub const PARTS: [&str; 4] = ["model", "data", "sampler", "optimizer and objective"];

/// This format: tensors named by role and shaped, the model's
/// specification in the metadata (docs/checkpoints.md).
pub const FORMAT: &str = "sdfl-checkpoint-2";
/// The first format (flat `value.N`, `adam_m.N`, `adam_v.N` tensors),
/// still read.
pub const FORMAT_1: &str = "sdfl-train-checkpoint-1";
/// The metadata entry of the run's [`History`].
pub const HISTORY: &str = "history";

/// The history as the metadata holds it: JSON whose numbers are strings
/// as Rust prints an f64 (exact when read back, and `inf` for the PSNR of
/// a perfect render, which JSON numbers cannot hold):
/// `{"seconds": "12.5", "held_out": [[100, "3.2", "27.31", "0.91", 200, "24.5" or null], ...]}`
/// (step, seconds, PSNR, SSIM, views scored, PSNR inside the object masks).
fn stored_history(h: &History) -> String {
    let rows: Vec<Value> = h
        .held_out
        .iter()
        .map(|e| {
            serde_json::json!([
                e.step,
                e.seconds.to_string(),
                e.psnr.to_string(),
                e.ssim.to_string(),
                e.views,
                e.psnr_in_mask.map(|p| p.to_string())
            ])
        })
        .collect();
    serde_json::json!({ "seconds": h.seconds.to_string(), "held_out": rows }).to_string()
}

/// [`stored_history`] read back; `None` if malformed.
fn read_history(text: &str) -> Option<History> {
    let v: Value = serde_json::from_str(text).ok()?;
    let num = |v: &Value| v.as_str()?.parse::<f64>().ok();
    let held_out = v["held_out"]
        .as_array()?
        .iter()
        .map(|r| {
            Some(HeldOut {
                step: usize::try_from(r.get(0)?.as_u64()?).ok()?,
                seconds: num(r.get(1)?)?,
                psnr: num(r.get(2)?)?,
                ssim: num(r.get(3)?)?,
                // Absent from checkpoints written before it was kept.
                views: match r.get(4) {
                    None => 0,
                    Some(v) => usize::try_from(v.as_u64()?).ok()?,
                },
                psnr_in_mask: match r.get(5) {
                    None | Some(Value::Null) => None,
                    Some(v) => Some(num(v)?),
                },
            })
        })
        .collect::<Option<Vec<_>>>()?;
    Some(History {
        seconds: num(&v["seconds"])?,
        held_out,
    })
}

/// A 64-bit FNV-1a hash: stable across platforms, versions and runs.
#[derive(Debug, Clone, Copy)]
pub struct Fnv(u64);

impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    /// Hashes raw bytes.
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        for &x in b {
            self.0 ^= x as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }
    /// Hashes a string and a terminator, so that consecutive strings cannot run together.
    pub fn str(&mut self, s: &str) -> &mut Self {
        self.bytes(s.as_bytes()).bytes(&[0xff])
    }
    /// Hashes floats by their exact bits (little-endian), so any change of value changes the hash.
    pub fn f32s(&mut self, v: &[f32]) -> &mut Self {
        for x in v {
            self.bytes(&x.to_bits().to_le_bytes());
        }
        self
    }
    /// The hash as 16 hex digits.
    pub fn finish(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// Formatting straight into the hash, so a large value's description is
/// never held in memory.
impl std::fmt::Write for Fnv {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        self.bytes(s.as_bytes());
        Ok(())
    }
}

/// One parameter's state.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamState {
    /// The trainer's name of the parameter.
    pub name: String,
    /// Its current values, flat.
    pub values: Vec<f32>,
    /// Adam's first-moment estimate, one per value.
    pub adam_m: Vec<f32>,
    /// Adam's second-moment estimate, one per value.
    pub adam_v: Vec<f32>,
}

/// Everything needed to continue a run exactly.
#[derive(Debug, Clone, PartialEq)]
pub struct Checkpoint {
    /// Steps done.
    pub step: usize,
    /// Adam's update count (its bias correction).
    pub adam_steps: i32,
    /// Every parameter's values and Adam moments, in the trainer's order.
    pub params: Vec<ParamState>,
    /// How each parameter is stored (parallel to `params`; a missing or
    /// empty entry is stored whole, flat, under its name). Empty when read
    /// from a first-format file.
    pub pieces: Vec<Vec<Piece>>,
    /// The model's specification (JSON; `Null` when unknown).
    pub model: Value,
    /// Where the model sits relative to its data (identity, no warp and
    /// no background when read from a file written before it was kept).
    pub frame: ModelFrame,
    /// The loss of every step done, so a resumed run's history is whole.
    pub losses: Vec<f32>,
    /// A model's state beyond its parameters (an occupancy grid), by name.
    pub state: Vec<(String, Vec<f32>)>,
    /// One hash per entry of [`PARTS`].
    pub fingerprint: [String; 4],
    /// Held-out scores and training time so far, so a resumed run's report
    /// and plots show the whole run. Empty when read from a checkpoint
    /// written before sdfl kept it: such a file still resumes (its
    /// parameters are what matter; only the earlier scores are unknown).
    pub history: History,
}

/// `v` as little-endian bytes.
#[doc(hidden)]
pub fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn invalid(path: &Path, what: impl std::fmt::Display) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("checkpoint {}: {what}", path.display()),
    )
}

/// `(rows, cols)` row-major → `(cols, rows)` row-major.
fn transpose(v: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut out = vec![0.0; v.len()];
    for r in 0..rows {
        for c in 0..cols {
            out[c * rows + r] = v[r * cols + c];
        }
    }
    out
}

/// The layout entry of one parameter in the metadata.
#[derive(serde::Serialize, serde::Deserialize)]
struct StoredParam {
    param: String,
    tensors: Vec<StoredPiece>,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct StoredPiece {
    name: String,
    shape: Vec<usize>,
    #[serde(default)]
    transposed: bool,
}

impl Checkpoint {
    /// The pieces parameter `i` is stored as.
    fn pieces_of(&self, i: usize) -> Vec<Piece> {
        match self.pieces.get(i) {
            Some(p) if !p.is_empty() => p.clone(),
            _ => {
                let p = &self.params[i];
                vec![Piece::flat(&p.name, p.values.len())]
            }
        }
    }

    /// Writes the checkpoint as a safetensors file, atomically: a crash never leaves half a file at `path`.
    pub fn write(&self, path: &Path) -> io::Result<()> {
        let mut buffers: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
        let mut layout = Vec::new();
        for (i, p) in self.params.iter().enumerate() {
            let pieces = self.pieces_of(i);
            let mut at = 0;
            for piece in &pieces {
                let n = piece.len().unwrap_or(usize::MAX);
                if at + n > p.values.len() {
                    return Err(invalid(
                        path,
                        format!("`{}` is not {} values", piece.name, n),
                    ));
                }
                for (prefix, v) in [
                    ("", &p.values),
                    ("adam.m.", &p.adam_m),
                    ("adam.v.", &p.adam_v),
                ] {
                    let part = &v[at..at + n];
                    let stored = if piece.transposed {
                        // Held (in, out), stored (out, in) = shape.
                        transpose(part, piece.shape[1], piece.shape[0])
                    } else {
                        part.to_vec()
                    };
                    buffers.push((
                        format!("{prefix}{}", piece.name),
                        piece.shape.clone(),
                        f32_bytes(&stored),
                    ));
                }
                at += n;
            }
            if at != p.values.len() {
                return Err(invalid(
                    path,
                    format!("`{}`'s pieces do not cover it", p.name),
                ));
            }
            layout.push(StoredParam {
                param: p.name.clone(),
                tensors: pieces
                    .into_iter()
                    .map(|q| StoredPiece {
                        name: q.name,
                        shape: q.shape,
                        transposed: q.transposed,
                    })
                    .collect(),
            });
        }
        buffers.push((
            "train.losses".into(),
            vec![self.losses.len()],
            f32_bytes(&self.losses),
        ));
        for (name, v) in &self.state {
            buffers.push((format!("state.{name}"), vec![v.len()], f32_bytes(v)));
        }
        let mut seen = std::collections::HashSet::new();
        if let Some((n, _, _)) = buffers.iter().find(|(n, _, _)| !seen.insert(n.as_str())) {
            return Err(invalid(path, format!("two tensors named `{n}`")));
        }
        let views = buffers
            .iter()
            .map(|(n, shape, b)| Ok((n.clone(), TensorView::new(Dtype::F32, shape.clone(), b)?)))
            .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()
            .map_err(|e| invalid(path, e))?;
        let mut meta = HashMap::new();
        meta.insert("format".to_string(), FORMAT.to_string());
        meta.insert(
            "sdfl_version".to_string(),
            env!("CARGO_PKG_VERSION").to_string(),
        );
        meta.insert("model".to_string(), self.model.to_string());
        meta.extend(self.frame.metadata());
        meta.insert("step".to_string(), self.step.to_string());
        meta.insert("adam_steps".to_string(), self.adam_steps.to_string());
        meta.insert(
            "layout".to_string(),
            serde_json::to_string(&layout).map_err(|e| invalid(path, e))?,
        );
        let state: Vec<&str> = self.state.iter().map(|s| s.0.as_str()).collect();
        meta.insert(
            "state".to_string(),
            serde_json::to_string(&state).unwrap_or_default(),
        );
        for (part, fp) in PARTS.iter().zip(&self.fingerprint) {
            meta.insert(format!("fingerprint.{part}"), fp.clone());
        }
        meta.insert(HISTORY.to_string(), stored_history(&self.history));
        let bytes = safetensors::serialize(views, &Some(meta)).map_err(|e| invalid(path, e))?;
        let mut f = Atomic::create(path)?;
        io::Write::write_all(f.writer(), &bytes)?;
        f.commit()
    }

    /// The model frame a checkpoint's header records (its training
    /// cameras among it), reading the header only: a viewer asks for it
    /// often, and the tensors behind it may be hundreds of megabytes.
    pub fn read_frame(path: &Path) -> io::Result<ModelFrame> {
        use std::io::Read;
        // safetensors' own bound on a header.
        const MAX_HEADER: u64 = 100_000_000;
        let mut file = crate::data::image::open_checkpoint(path)?;
        let mut len = [0u8; 8];
        file.read_exact(&mut len).map_err(|e| invalid(path, e))?;
        let len = u64::from_le_bytes(len);
        if len > MAX_HEADER {
            return Err(invalid(
                path,
                format!("a header of {len} bytes: not a checkpoint"),
            ));
        }
        let mut header = Vec::new();
        file.take(len)
            .read_to_end(&mut header)
            .map_err(|e| invalid(path, e))?;
        if header.len() as u64 != len {
            return Err(invalid(path, "its header is cut short"));
        }
        let header: Value = serde_json::from_slice(&header)
            .map_err(|_| invalid(path, "its header is not JSON: not a checkpoint"))?;
        let meta = header
            .get("__metadata__")
            .ok_or_else(|| invalid(path, "no metadata: not an sdfl checkpoint"))?;
        ModelFrame::from_metadata(|k| meta.get(k).and_then(Value::as_str))
            .map_err(|e| invalid(path, e))
    }

    /// Reads a checkpoint of either format, refusing a malformed or hostile file with an error (never a panic).
    pub fn read(path: &Path) -> io::Result<Checkpoint> {
        let bytes = crate::data::image::read_checkpoint_bytes(path)?;
        let (_, header) = SafeTensors::read_metadata(&bytes).map_err(|e| invalid(path, e))?;
        let meta = header
            .metadata()
            .clone()
            .ok_or_else(|| invalid(path, "no metadata: not an sdfl checkpoint"))?;
        let get = |k: &str| {
            meta.get(k)
                .cloned()
                .ok_or_else(|| invalid(path, format!("no `{k}`: not an sdfl checkpoint")))
        };
        let format = get("format")?;
        if format != FORMAT && format != FORMAT_1 {
            return Err(invalid(
                path,
                format!("its format `{format}` is not one this sdfl reads ({FORMAT}, {FORMAT_1}): written by another version of sdfl"),
            ));
        }
        let num = |k: &str| -> io::Result<i64> {
            get(k)?
                .parse()
                .map_err(|_| invalid(path, format!("bad `{k}`")))
        };
        let tensors = SafeTensors::deserialize(&bytes).map_err(|e| invalid(path, e))?;
        // A tensor's values, its shape checked against `shape` when given.
        let read = |name: &str, shape: Option<&[usize]>| -> io::Result<Vec<f32>> {
            let t = tensors.tensor(name).map_err(|e| invalid(path, e))?;
            if t.dtype() != Dtype::F32 {
                return Err(invalid(path, format!("`{name}` is not f32")));
            }
            if let Some(s) = shape {
                if t.shape() != s {
                    return Err(invalid(
                        path,
                        format!("`{name}` has shape {:?}, its layout says {s:?}", t.shape()),
                    ));
                }
            }
            Ok(t.data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect())
        };
        let mut params = Vec::new();
        let mut pieces = Vec::new();
        if format == FORMAT_1 {
            let names: Vec<String> =
                serde_json::from_str(&get("names")?).map_err(|_| invalid(path, "bad `names`"))?;
            for (i, name) in names.into_iter().enumerate() {
                params.push(ParamState {
                    name,
                    values: read(&format!("value.{i}"), None)?,
                    adam_m: read(&format!("adam_m.{i}"), None)?,
                    adam_v: read(&format!("adam_v.{i}"), None)?,
                });
            }
        } else {
            let layout: Vec<StoredParam> =
                serde_json::from_str(&get("layout")?).map_err(|_| invalid(path, "bad `layout`"))?;
            for p in layout {
                let mut state = ParamState {
                    name: p.param,
                    values: Vec::new(),
                    adam_m: Vec::new(),
                    adam_v: Vec::new(),
                };
                let mut mine = Vec::new();
                for q in p.tensors {
                    let piece = Piece {
                        name: q.name,
                        shape: q.shape,
                        transposed: q.transposed,
                    };
                    if piece.len().is_none() || (piece.transposed && piece.shape.len() != 2) {
                        return Err(invalid(
                            path,
                            format!("`{}` has a bad shape {:?}", piece.name, piece.shape),
                        ));
                    }
                    for (prefix, out) in [
                        ("", &mut state.values),
                        ("adam.m.", &mut state.adam_m),
                        ("adam.v.", &mut state.adam_v),
                    ] {
                        let v = read(&format!("{prefix}{}", piece.name), Some(&piece.shape))?;
                        if piece.transposed {
                            out.extend(transpose(&v, piece.shape[0], piece.shape[1]));
                        } else {
                            out.extend(v);
                        }
                    }
                    mine.push(piece);
                }
                params.push(state);
                pieces.push(mine);
            }
        }
        let model = match meta.get("model") {
            Some(m) => serde_json::from_str(m).map_err(|_| invalid(path, "bad `model`"))?,
            None => Value::Null,
        };
        // Checkpoints of models without state may have no list.
        let state_names: Vec<String> = match meta.get("state") {
            Some(s) => serde_json::from_str(s).map_err(|_| invalid(path, "bad `state`"))?,
            None => Vec::new(),
        };
        let losses = read(
            if format == FORMAT_1 {
                "losses"
            } else {
                "train.losses"
            },
            None,
        )?;
        let mut state = Vec::new();
        for (i, name) in state_names.into_iter().enumerate() {
            let stored = if format == FORMAT_1 {
                format!("state.{i}")
            } else {
                format!("state.{name}")
            };
            state.push((name, read(&stored, None)?));
        }
        let frame = ModelFrame::from_metadata(|k| meta.get(k).map(String::as_str))
            .map_err(|e| invalid(path, e))?;
        let fp = |i: usize| get(&format!("fingerprint.{}", PARTS[i]));
        // Written by sdfl before it kept the history: none.
        let history = match meta.get(HISTORY) {
            None => History::default(),
            Some(h) => read_history(h).ok_or_else(|| invalid(path, format!("bad `{HISTORY}`")))?,
        };
        Ok(Checkpoint {
            step: usize::try_from(num("step")?).map_err(|_| invalid(path, "bad step"))?,
            adam_steps: i32::try_from(num("adam_steps")?).map_err(|_| invalid(path, "bad step"))?,
            params,
            pieces,
            model,
            frame,
            losses,
            state,
            fingerprint: [fp(0)?, fp(1)?, fp(2)?, fp(3)?],
            history,
        })
    }

    /// Checks what a file may hold but a run of `steps` steps never writes:
    /// every number finite, Adam's second moments at least 0, the step
    /// within the run with one loss per step. (Each value's range is the
    /// model's to check: [`super::Run::resume`].)
    pub fn check(&self, steps: usize) -> Result<(), String> {
        if self.step > steps {
            return Err(format!(
                "it is at step {}, past this run's {steps} steps (raise `iterations` to continue it)",
                self.step
            ));
        }
        if self.losses.len() != self.step {
            return Err(format!(
                "it holds {} losses for {} steps",
                self.losses.len(),
                self.step
            ));
        }
        if !(0..=self.step as i64).contains(&(self.adam_steps as i64)) {
            return Err(format!(
                "Adam's step count {} is not within its {} steps",
                self.adam_steps, self.step
            ));
        }
        let bad = |v: &[f32], ok: fn(f32) -> bool| v.iter().position(|&x| !ok(x));
        // Every loss sdfl fits is a sum of squares and magnitudes: ≥ 0.
        if let Some(k) = bad(&self.losses, |x| x.is_finite() && x >= 0.0) {
            return Err(format!("the loss of step {} is {}", k + 1, self.losses[k]));
        }
        for p in &self.params {
            let n = p.values.len();
            if p.adam_m.len() != n || p.adam_v.len() != n {
                return Err(format!(
                    "`{}` holds {n} values but {} and {} Adam moments",
                    p.name,
                    p.adam_m.len(),
                    p.adam_v.len()
                ));
            }
            for (what, v, ok) in [
                ("", &p.values, f32::is_finite as fn(f32) -> bool),
                (" (Adam's first moment)", &p.adam_m, f32::is_finite),
                (" (Adam's second moment)", &p.adam_v, |x: f32| {
                    x.is_finite() && x >= 0.0
                }),
            ] {
                if let Some(k) = bad(v, ok) {
                    let at = if n > 1 {
                        format!("[{k}]")
                    } else {
                        String::new()
                    };
                    return Err(format!("`{}`{at}{what} is {}", p.name, v[k]));
                }
            }
        }
        for (name, v) in &self.state {
            if let Some(k) = bad(v, f32::is_finite) {
                return Err(format!("`{name}`[{k}] is {}", v[k]));
            }
        }
        let h = &self.history;
        if !(h.seconds.is_finite() && h.seconds >= 0.0) {
            return Err(format!("its training time is {} s", h.seconds));
        }
        let mut last = 0;
        for e in &h.held_out {
            // PSNR is +∞ for a perfect render.
            let fine = e.seconds.is_finite()
                && (0.0..=h.seconds).contains(&e.seconds)
                && !e.psnr.is_nan()
                && e.psnr > f64::NEG_INFINITY
                && e.ssim.is_finite()
                && e.psnr_in_mask
                    .is_none_or(|p| !p.is_nan() && p > f64::NEG_INFINITY);
            if e.step <= last && last > 0 || e.step > self.step || !fine {
                return Err(format!(
                    "its held-out score of step {} (PSNR {}, {} s) is out of order or out of range",
                    e.step, e.psnr, e.seconds
                ));
            }
            last = e.step;
        }
        Ok(())
    }

    /// The checkpoint carrying `history`.
    pub fn with_history(self, history: History) -> Checkpoint {
        Checkpoint { history, ..self }
    }

    /// The parts of the run that differ from `fingerprint` (empty: same run).
    pub fn differences(&self, fingerprint: &[String; 4]) -> Vec<&'static str> {
        PARTS
            .iter()
            .zip(self.fingerprint.iter().zip(fingerprint))
            .filter(|(_, (a, b))| a != b)
            .map(|(p, _)| *p)
            .collect()
    }
}
