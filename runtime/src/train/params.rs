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
use sdfl_stdlib::value::Moments as AdamMoments;

/// Handle of a parameter in a [`ParamStore`]. Only the store that issued it
/// accepts it: the accessors index with it and panic on a foreign handle (a
/// programming error, like an out-of-range slice index); the Adam updates
/// check it and return an error.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ParamId(#[doc(hidden)] pub usize);

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
        Self::with_moments(lr, AdamMoments::default())
    }

    /// Adam with learning rate `lr` and the given moment decays and ε.
    pub fn with_moments(lr: f64, moments: AdamMoments) -> Result<Self, TrainError> {
        if !(lr > 0.0 && lr.is_finite()) {
            return Err(TrainError::Invalid(format!(
                "learning rate must be positive, got {lr}"
            )));
        }
        let AdamMoments { beta1, beta2, eps } = moments;
        if !((0.0..1.0).contains(&beta1) && (0.0..1.0).contains(&beta2) && eps > 0.0) {
            return Err(TrainError::Invalid(format!(
                "Adam needs β in [0, 1) and ε > 0, got β = ({beta1}, {beta2}), ε = {eps}"
            )));
        }
        Ok(Adam {
            cfg: AdamConfig {
                lr,
                betas: [beta1, beta2],
                eps,
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

    /// One update of every trainable parameter in place in the step's own
    /// flat buffers: `values` holds each parameter's current values (its
    /// range in `parts`) and takes the updated ones; `grads` holds the
    /// step's gradient and is left zeroed for the next step. The formula and
    /// its order of operations are dfdx's kernel's ([`Self::update_from_slices`]
    /// runs that kernel: the same bits), but in parallel chunks and one pass
    /// over values, moments and gradient, where the dfdx route copies the
    /// gradient in and the values out single-threaded: for a hash grid of
    /// 2^19 rows × 16 levels that was a sixth of a NeRF step. The store's
    /// values are not written (the caller projects `values` and sets them).
    /// A non-finite gradient is an error, and then nothing changes.
    pub fn update_in_place(
        &mut self,
        store: &mut ParamStore,
        parts: &[(ParamId, std::ops::Range<usize>)],
        values: &mut [f32],
        grads: &mut [f32],
    ) -> Result<(), TrainError> {
        use rayon::prelude::*;
        if values.len() != grads.len() {
            return Err(TrainError::Invalid(
                "values and gradient of different lengths".into(),
            ));
        }
        for (id, range) in parts {
            let p = store
                .params
                .get(id.0)
                .ok_or_else(|| TrainError::Invalid(format!("no parameter #{}", id.0)))?;
            let n = store.dev.len(&p.m);
            if range.len() != n || range.end > values.len() {
                return Err(TrainError::Invalid(format!(
                    "'{}' has {n} values, its range {range:?} in a step of {}",
                    p.name,
                    values.len()
                )));
            }
            if let Some(k) = first_non_finite(&grads[range.clone()]) {
                return Err(TrainError::Gradient(format!(
                    "'{}' has a non-finite gradient ({} at {k})",
                    p.name,
                    grads[range.start + k]
                )));
            }
        }
        self.step += 1;
        let cfg = &self.cfg;
        // As dfdx converts its f64 settings (`E::from_f64`).
        let (b1, b2) = (cfg.betas[0] as f32, cfg.betas[1] as f32);
        let (lr, eps) = (cfg.lr as f32, cfg.eps as f32);
        let (c1, c2) = (
            (1.0 - b1.powi(self.step)).recip(),
            (1.0 - b2.powi(self.step)).recip(),
        );
        const CHUNK: usize = 1 << 14;
        for (id, range) in parts {
            let p = &mut store.params[id.0];
            let g = &mut grads[range.clone()];
            if !p.trainable {
                g.fill(0.0);
                continue;
            }
            values[range.clone()]
                .par_chunks_mut(CHUNK)
                .zip(g.par_chunks_mut(CHUNK))
                .zip(p.m.par_chunks_mut(CHUNK).zip(p.v.par_chunks_mut(CHUNK)))
                .for_each(|((x, g), (m, v))| {
                    for (((x, g), m), v) in x.iter_mut().zip(g).zip(m).zip(v) {
                        *m = *m * b1 + *g * (1.0 - b1);
                        *v = *v * b2 + *g * *g * (1.0 - b2);
                        let (m_hat, v_hat) = (*m * c1, *v * c2);
                        *x -= lr * m_hat / (v_hat.sqrt() + eps);
                        *g = 0.0;
                    }
                });
        }
        Ok(())
    }
}

/// Where `xs` first holds a value that is not finite. Whole chunks are
/// checked in parallel with a branch-free fold the compiler vectorises
/// (rayon's `position_first` item by item took longer than an Adam step);
/// only a failing chunk is searched.
pub fn first_non_finite(xs: &[f32]) -> Option<usize> {
    use rayon::prelude::*;
    const CHUNK: usize = 1 << 14;
    let chunk = xs
        .par_chunks(CHUNK)
        .position_first(|c| !c.iter().fold(true, |all, x| all & x.is_finite()))?;
    let start = chunk * CHUNK;
    xs[start..]
        .iter()
        .position(|x| !x.is_finite())
        .map(|k| start + k)
}
