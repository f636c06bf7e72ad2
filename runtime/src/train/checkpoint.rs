//! Resumable training state as a safetensors file: every parameter, Adam's
//! moments and step count, the loss history, the step reached, and a
//! fingerprint of what the run depends on (model, data, sampler, optimiser
//! and objective). A resumed run continues the same run; a checkpoint whose
//! fingerprint differs is refused, naming what changed.

use std::collections::HashMap;
use std::io;
use std::path::Path;

use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use crate::output::Atomic;

/// What changed between a checkpoint and the current run, part by part.
pub const PARTS: [&str; 4] = ["model", "data", "sampler", "optimizer and objective"];

const FORMAT: &str = "sdfl-train-checkpoint-1";

/// A 64-bit FNV-1a hash: stable across platforms, versions and runs.
#[derive(Debug, Clone, Copy)]
pub struct Fnv(u64);

impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        for &x in b {
            self.0 ^= x as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }
    pub fn str(&mut self, s: &str) -> &mut Self {
        self.bytes(s.as_bytes()).bytes(&[0xff])
    }
    pub fn f32s(&mut self, v: &[f32]) -> &mut Self {
        for x in v {
            self.bytes(&x.to_bits().to_le_bytes());
        }
        self
    }
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
    pub name: String,
    pub values: Vec<f32>,
    pub adam_m: Vec<f32>,
    pub adam_v: Vec<f32>,
}

/// Everything needed to continue a run exactly.
#[derive(Debug, Clone, PartialEq)]
pub struct Checkpoint {
    /// Steps done.
    pub step: usize,
    /// Adam's update count (its bias correction).
    pub adam_steps: i32,
    pub params: Vec<ParamState>,
    pub losses: Vec<f32>,
    /// A model's state beyond its parameters (an occupancy grid), by name.
    pub state: Vec<(String, Vec<f32>)>,
    /// One hash per entry of [`PARTS`].
    pub fingerprint: [String; 4],
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn invalid(path: &Path, what: impl std::fmt::Display) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("checkpoint {}: {what}", path.display()),
    )
}

impl Checkpoint {
    pub fn write(&self, path: &Path) -> io::Result<()> {
        let mut buffers: Vec<(String, Vec<u8>, usize)> = Vec::new();
        for (i, p) in self.params.iter().enumerate() {
            for (kind, v) in [
                ("value", &p.values),
                ("adam_m", &p.adam_m),
                ("adam_v", &p.adam_v),
            ] {
                buffers.push((format!("{kind}.{i}"), f32_bytes(v), v.len()));
            }
        }
        buffers.push(("losses".into(), f32_bytes(&self.losses), self.losses.len()));
        for (i, (_, v)) in self.state.iter().enumerate() {
            buffers.push((format!("state.{i}"), f32_bytes(v), v.len()));
        }
        let views = buffers
            .iter()
            .map(|(n, b, len)| Ok((n.clone(), TensorView::new(Dtype::F32, vec![*len], b)?)))
            .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()
            .map_err(|e| invalid(path, e))?;
        let mut meta = HashMap::new();
        meta.insert("format".to_string(), FORMAT.to_string());
        meta.insert("step".to_string(), self.step.to_string());
        meta.insert("adam_steps".to_string(), self.adam_steps.to_string());
        let names: Vec<&str> = self.params.iter().map(|p| p.name.as_str()).collect();
        meta.insert(
            "names".to_string(),
            serde_json::to_string(&names).unwrap_or_default(),
        );
        let state: Vec<&str> = self.state.iter().map(|s| s.0.as_str()).collect();
        meta.insert(
            "state".to_string(),
            serde_json::to_string(&state).unwrap_or_default(),
        );
        for (part, fp) in PARTS.iter().zip(&self.fingerprint) {
            meta.insert(format!("fingerprint.{part}"), fp.clone());
        }
        let bytes = safetensors::serialize(views, &Some(meta)).map_err(|e| invalid(path, e))?;
        let mut f = Atomic::create(path)?;
        io::Write::write_all(f.writer(), &bytes)?;
        f.commit()
    }

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
        if get("format")? != FORMAT {
            return Err(invalid(path, "written by another version of sdfl"));
        }
        let num = |k: &str| -> io::Result<i64> {
            get(k)?
                .parse()
                .map_err(|_| invalid(path, format!("bad `{k}`")))
        };
        let names: Vec<String> =
            serde_json::from_str(&get("names")?).map_err(|_| invalid(path, "bad `names`"))?;
        let tensors = SafeTensors::deserialize(&bytes).map_err(|e| invalid(path, e))?;
        let read = |name: &str| -> io::Result<Vec<f32>> {
            let t = tensors.tensor(name).map_err(|e| invalid(path, e))?;
            if t.dtype() != Dtype::F32 {
                return Err(invalid(path, format!("`{name}` is not f32")));
            }
            Ok(t.data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect())
        };
        let mut params = Vec::new();
        for (i, name) in names.into_iter().enumerate() {
            params.push(ParamState {
                name,
                values: read(&format!("value.{i}"))?,
                adam_m: read(&format!("adam_m.{i}"))?,
                adam_v: read(&format!("adam_v.{i}"))?,
            });
        }
        // Checkpoints of models without state may have no list.
        let state_names: Vec<String> = match meta.get("state") {
            Some(s) => serde_json::from_str(s).map_err(|_| invalid(path, "bad `state`"))?,
            None => Vec::new(),
        };
        let mut state = Vec::new();
        for (i, name) in state_names.into_iter().enumerate() {
            state.push((name, read(&format!("state.{i}"))?));
        }
        let fp = |i: usize| get(&format!("fingerprint.{}", PARTS[i]));
        Ok(Checkpoint {
            step: usize::try_from(num("step")?).map_err(|_| invalid(path, "bad step"))?,
            adam_steps: i32::try_from(num("adam_steps")?).map_err(|_| invalid(path, "bad step"))?,
            params,
            losses: read("losses")?,
            state,
            fingerprint: [fp(0)?, fp(1)?, fp(2)?, fp(3)?],
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
        Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checks_what_a_run_never_writes() {
        let good = Checkpoint {
            step: 2,
            adam_steps: 2,
            params: vec![ParamState {
                name: "torus.major".into(),
                values: vec![1.0, 2.0],
                adam_m: vec![0.1, -0.2],
                adam_v: vec![1e-3, 0.0],
            }],
            losses: vec![0.5, 0.25],
            state: vec![("occupancy.ema".into(), vec![0.0, 3.5])],
            fingerprint: Default::default(),
        };
        good.check(2).unwrap();
        type Tamper = fn(&mut Checkpoint);
        let cases: Vec<(Tamper, &str)> = vec![
            (
                |c| c.params[0].values[1] = f32::NAN,
                "`torus.major`[1] is NaN",
            ),
            (
                |c| c.params[0].adam_m[0] = f32::INFINITY,
                "first moment) is inf",
            ),
            (
                |c| c.params[0].adam_v[0] = -1e-3,
                "second moment) is -0.001",
            ),
            (
                |c| c.params[0].adam_v.pop().map(drop).unwrap_or(()),
                "holds 2 values but 2 and 1 Adam moments",
            ),
            (
                |c| c.params[0].values.pop().map(drop).unwrap_or(()),
                "holds 1 values but 2 and 2 Adam moments",
            ),
            (|c| c.losses[0] = f32::NAN, "loss of step 1 is NaN"),
            (|c| c.losses[1] = -1.0, "loss of step 2 is -1"),
            (|c| c.step = 1 << 62, "past this run's 2 steps"),
            (|c| c.step = 1, "2 losses for 1 steps"),
            (|c| c.adam_steps = -1, "Adam's step count -1"),
            (|c| c.state[0].1[1] = f32::NAN, "`occupancy.ema`[1] is NaN"),
        ];
        for (tamper, says) in cases {
            let mut c = good.clone();
            tamper(&mut c);
            let e = c.check(2).unwrap_err();
            assert!(e.contains(says), "{says}: {e}");
        }
    }

    #[test]
    fn round_trips_and_rejects_foreign_files() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ck.safetensors");
        let ck = Checkpoint {
            step: 200,
            adam_steps: 200,
            params: vec![ParamState {
                name: "torus.major".into(),
                values: vec![1.0, 2.0],
                adam_m: vec![0.1, -0.2],
                adam_v: vec![1e-3, 2e-3],
            }],
            losses: vec![0.5, 0.25],
            state: vec![("occupancy.ema".into(), vec![0.0, 3.5, 1e-30])],
            fingerprint: ["a".into(), "b".into(), "c".into(), "d".into()],
        };
        ck.write(&path).unwrap();
        let back = Checkpoint::read(&path).unwrap();
        assert_eq!(back, ck);
        let other = ["a".to_string(), "x".into(), "c".into(), "y".into()];
        assert_eq!(
            back.differences(&other),
            vec!["data", "optimizer and objective"]
        );
        std::fs::write(&path, b"{\"iteration\": 3}").unwrap();
        let e = Checkpoint::read(&path).unwrap_err().to_string();
        assert!(e.contains("ck.safetensors"), "{e}");
    }
}
