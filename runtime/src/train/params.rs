//! A runtime-sized parameter store for dfdx 0.13.
//!
//! dfdx's `nn` layers and its `Optimizer` impls need compile-time shapes
//! (`TensorCollection` is only implemented for `ConstShape` tensors), while
//! sdfl's parameters are sized by the scene. So parameters live here as named
//! rank-1 `Tensor<(usize,), f32, Cpu>`s (callers reshape views of them in
//! their graphs), and [`Adam`] applies dfdx's own Adam kernel
//! (`AdamConfig::try_update`, the same code `dfdx::optim::Adam` runs) to each
//! trainable one with moment buffers kept per parameter.

use dfdx::optim::AdamConfig;
use dfdx::prelude::{Cpu, Gradients, Tensor, TensorFromVec};
use dfdx::tensor::Storage;

use super::TrainError;

/// Handle of a parameter in a [`ParamStore`]. Only the store that issued it
/// accepts it: the accessors index with it and panic on a foreign handle (a
/// programming error, like an out-of-range slice index); the Adam updates
/// check it and return an error.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ParamId(usize);

type Moments = <Cpu as Storage<f32>>::Vec;

struct Param {
    name: String,
    tensor: Tensor<(usize,), f32, Cpu>,
    trainable: bool,
    m: Moments,
    v: Moments,
    /// The gradient in the device's storage, as dfdx's Adam kernel takes
    /// it: allocated on the first update from slices, then reused.
    grad: Option<Moments>,
}

/// Named, runtime-sized f32 parameters on a dfdx CPU device.
pub struct ParamStore {
    dev: Cpu,
    params: Vec<Param>,
}

impl Default for ParamStore {
    fn default() -> Self {
        Self::new()
    }
}

impl ParamStore {
    /// A store on a fresh CPU device. dfdx's allocation cache stays off:
    /// it keeps every dropped buffer forever and hands one back only to an
    /// allocation of the same length, so a tensor replaced each step (or a
    /// batch of another size) grew the heap by a parameter's size a step.
    pub fn new() -> Self {
        let dev = Cpu::default();
        ParamStore {
            dev,
            params: Vec::new(),
        }
    }

    /// The dfdx device the parameters live on.
    pub fn device(&self) -> &Cpu {
        &self.dev
    }

    /// Adds a parameter; names must be unique and values finite.
    pub fn add(
        &mut self,
        name: &str,
        values: &[f32],
        trainable: bool,
    ) -> Result<ParamId, TrainError> {
        if self.find(name).is_some() {
            return Err(TrainError::Invalid(format!("duplicate parameter '{name}'")));
        }
        if values.is_empty() || !values.iter().all(|v| v.is_finite()) {
            return Err(TrainError::Invalid(format!(
                "parameter '{name}' must be non-empty and finite"
            )));
        }
        let n = values.len();
        let tensor = self.dev.tensor_from_vec(values.to_vec(), (n,));
        let m = self.dev.try_alloc_len(n)?;
        let v = self.dev.try_alloc_len(n)?;
        self.params.push(Param {
            name: name.to_string(),
            tensor,
            trainable,
            m,
            v,
            grad: None,
        });
        Ok(ParamId(self.params.len() - 1))
    }

    /// Looks a parameter up by name.
    pub fn find(&self, name: &str) -> Option<ParamId> {
        self.params.iter().position(|p| p.name == name).map(ParamId)
    }

    /// The parameter's tensor (clone it, or `.leaky_trace()` it, into a graph).
    pub fn tensor(&self, id: ParamId) -> &Tensor<(usize,), f32, Cpu> {
        &self.params[id.0].tensor
    }

    /// Current values.
    pub fn values(&self, id: ParamId) -> Vec<f32> {
        self.dev.tensor_to_vec(&self.params[id.0].tensor)
    }

    /// Copies the current values into `out` (the parameter's length), so
    /// a step reads them without allocating.
    pub fn copy_values(&self, id: ParamId, out: &mut [f32]) {
        self.params[id.0].tensor.copy_into(out);
    }

    /// The parameter's name, as reports and checkpoints show it.
    pub fn name(&self, id: ParamId) -> &str {
        &self.params[id.0].name
    }

    /// Whether the optimiser updates this parameter (a frozen one keeps its values).
    pub fn is_trainable(&self, id: ParamId) -> bool {
        self.params[id.0].trainable
    }

    /// Freezes or unfreezes a parameter for the optimiser.
    pub fn set_trainable(&mut self, id: ParamId, trainable: bool) {
        self.params[id.0].trainable = trainable;
    }

    /// Replaces a parameter's values (e.g. projected back into range).
    pub fn set_values(&mut self, id: ParamId, values: &[f32]) -> Result<(), TrainError> {
        let p = &mut self.params[id.0];
        if values.len() != self.dev.len(&p.m) {
            return Err(TrainError::Invalid(format!("'{}': wrong length", p.name)));
        }
        // In place: the buffer is the parameter's for the whole run.
        p.tensor.copy_from(values);
        Ok(())
    }

    /// Adam's first and second moments of a parameter.
    pub fn moments(&self, id: ParamId) -> (Vec<f32>, Vec<f32>) {
        let p = &self.params[id.0];
        (p.m.to_vec(), p.v.to_vec())
    }

    /// Restores a parameter's values and Adam moments (resuming a run).
    pub fn restore(
        &mut self,
        id: ParamId,
        values: &[f32],
        m: &[f32],
        v: &[f32],
    ) -> Result<(), TrainError> {
        let n = self.dev.len(&self.params[id.0].m);
        if values.len() != n {
            return Err(TrainError::Invalid(format!(
                "'{}' has {} values, the model {n}",
                self.params[id.0].name,
                values.len()
            )));
        }
        if m.len() != n || v.len() != n {
            return Err(TrainError::Invalid(format!(
                "'{}': moments of the wrong length",
                self.params[id.0].name
            )));
        }
        self.set_values(id, values)?;
        let p = &mut self.params[id.0];
        p.m.copy_from_slice(m);
        p.v.copy_from_slice(v);
        Ok(())
    }

    /// All parameter handles in insertion order.
    pub fn ids(&self) -> impl Iterator<Item = ParamId> {
        (0..self.params.len()).map(ParamId)
    }
}

/// Adam over a [`ParamStore`], using dfdx's Adam kernel.
#[derive(Debug, Clone)]
pub struct Adam {
    /// dfdx's settings: learning rate, moment decays, ε.
    pub cfg: AdamConfig,
    step: i32,
}

impl Adam {
    /// Adam with learning rate `lr` and dfdx's defaults (β = 0.9, 0.999, ε = 1e-8).
    pub fn new(lr: f64) -> Result<Self, TrainError> {
        if !(lr > 0.0 && lr.is_finite()) {
            return Err(TrainError::Invalid(format!(
                "learning rate must be positive, got {lr}"
            )));
        }
        Ok(Adam {
            cfg: AdamConfig {
                lr,
                ..Default::default()
            },
            step: 0,
        })
    }

    /// Number of updates applied so far.
    pub fn steps(&self) -> i32 {
        self.step
    }

    /// Continues from `steps` updates (resuming a run).
    pub fn set_steps(&mut self, steps: i32) {
        self.step = steps;
    }

    /// One update from dfdx gradients (as returned by `backward()`). A
    /// trainable parameter absent from `grads` counts as a zero gradient
    /// (dfdx's public API cannot tell the two apart; its moments still
    /// decay). Any non-finite gradient is an error and then nothing changes.
    pub fn update(
        &mut self,
        store: &mut ParamStore,
        grads: &mut Gradients<f32, Cpu>,
    ) -> Result<(), TrainError> {
        for p in store.params.iter().filter(|p| p.trainable) {
            if !grads
                .get_or_alloc_mut(&p.tensor)?
                .iter()
                .all(|x| x.is_finite())
            {
                return Err(TrainError::Gradient(format!(
                    "'{}' has a non-finite gradient",
                    p.name
                )));
            }
        }
        self.step += 1;
        for p in store.params.iter_mut().filter(|p| p.trainable) {
            let g = grads.get_or_alloc_mut(&p.tensor)?;
            self.cfg
                .try_update(self.step, &mut p.tensor, &mut p.m, &mut p.v, g)?;
        }
        Ok(())
    }

    /// One update from plain gradient slices (e.g. from a fused kernel), one
    /// per trainable parameter; parameters not listed are left unchanged.
    pub fn update_from_slices(
        &mut self,
        store: &mut ParamStore,
        grads: &[(ParamId, &[f32])],
    ) -> Result<(), TrainError> {
        // Validate everything first so that an error changes nothing.
        for &(id, g) in grads {
            let p = store
                .params
                .get(id.0)
                .ok_or_else(|| TrainError::Invalid(format!("no parameter #{}", id.0)))?;
            let n = store.dev.len(&p.m);
            if g.len() != n {
                return Err(TrainError::Invalid(format!(
                    "gradient of '{}' has {} values, parameter has {n}",
                    p.name,
                    g.len()
                )));
            }
            if !g.iter().all(|x| x.is_finite()) {
                return Err(TrainError::Gradient(format!(
                    "'{}' has a non-finite gradient",
                    p.name
                )));
            }
        }
        self.step += 1;
        for &(id, g) in grads {
            let p = &mut store.params[id.0];
            if p.trainable {
                let buf = match &mut p.grad {
                    Some(buf) => buf,
                    empty => empty.insert(store.dev.try_alloc_len(g.len())?),
                };
                buf.copy_from_slice(g);
                self.cfg
                    .try_update(self.step, &mut p.tensor, &mut p.m, &mut p.v, buf)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dfdx::prelude::*;

    /// Plain f64 Adam for reference.
    fn adam_ref(p: &mut [f64], m: &mut [f64], v: &mut [f64], g: &[f64], t: i32, lr: f64) {
        for i in 0..p.len() {
            m[i] = 0.9 * m[i] + 0.1 * g[i];
            v[i] = 0.999 * v[i] + 0.001 * g[i] * g[i];
            let mh = m[i] / (1.0 - 0.9f64.powi(t));
            let vh = v[i] / (1.0 - 0.999f64.powi(t));
            p[i] -= lr * mh / (vh.sqrt() + 1e-8);
        }
    }

    #[test]
    fn adam_on_graph_gradients_matches_reference() {
        // Minimise Σ (x − target)² through a dfdx graph.
        let mut store = ParamStore::new();
        let x = store.add("x", &[1.0, -2.0, 0.5], true).unwrap();
        let fixed = store.add("fixed", &[3.0], false).unwrap();
        let mut opt = Adam::new(0.1).unwrap();
        let target = [0.3f64, 0.7, -0.2];
        let mut p = [1.0f64, -2.0, 0.5];
        let (mut m, mut v) = ([0.0; 3], [0.0; 3]);
        for t in 1..=20 {
            let dev = store.device().clone();
            let tgt = dev.tensor_from_vec(target.iter().map(|&v| v as f32).collect(), (3,));
            let loss = (store.tensor(x).leaky_trace() - tgt).square().sum();
            let mut grads = loss.backward();
            opt.update(&mut store, &mut grads).unwrap();
            let g: Vec<f64> = (0..3).map(|i| 2.0 * (p[i] - target[i])).collect();
            adam_ref(&mut p, &mut m, &mut v, &g, t, 0.1);
        }
        let got = store.values(x);
        for i in 0..3 {
            assert!((got[i] as f64 - p[i]).abs() < 1e-4, "{got:?} vs {p:?}");
        }
        assert_eq!(store.values(fixed), vec![3.0]);
        assert_eq!(store.find("fixed"), Some(fixed));
        assert!(store.add("x", &[0.0], true).is_err());
        assert!(store.add("nan", &[f32::NAN], true).is_err());
    }

    #[test]
    fn adam_from_slices_matches_reference_and_checks_input() {
        let mut store = ParamStore::new();
        let x = store.add("x", &[1.0, 2.0], true).unwrap();
        let mut opt = Adam::new(0.01).unwrap();
        let mut p = [1.0f64, 2.0];
        let (mut m, mut v) = ([0.0; 2], [0.0; 2]);
        for t in 1..=5 {
            let g = [0.5f32 * t as f32, -1.0];
            opt.update_from_slices(&mut store, &[(x, &g)]).unwrap();
            adam_ref(&mut p, &mut m, &mut v, &[0.5 * t as f64, -1.0], t, 0.01);
        }
        let got = store.values(x);
        assert!((got[0] as f64 - p[0]).abs() < 1e-6 && (got[1] as f64 - p[1]).abs() < 1e-6);
        let before = store.values(x);
        assert!(opt.update_from_slices(&mut store, &[(x, &[1.0])]).is_err());
        assert!(opt
            .update_from_slices(&mut store, &[(ParamId(7), &[1.0])])
            .is_err());
        assert_eq!(store.values(x), before);
        assert!(opt
            .update_from_slices(&mut store, &[(x, &[f32::NAN, 0.0])])
            .is_err());
        assert!(Adam::new(-1.0).is_err());
    }
}
