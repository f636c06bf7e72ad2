//! What the trainer fits: any model whose parameters are named tensors in
//! one flat vector, with a loss and its exact gradient on a batch of rays.
//! The loop ([`super::Run`]), Adam, checkpoints and resumption are written
//! once over this trait; analytic fields and neural fields implement it.

use sdfl_stdlib::value::Backend;

use super::fused::{loss_and_grad_f32, Batch};
use super::model::TrainModel;
use super::TrainError;

/// One named tensor of a model's flat parameter vector.
#[derive(Debug, Clone, PartialEq)]
pub struct TensorSpec {
    /// The tensor's name, as reports and checkpoints show it.
    pub name: String,
    /// First scalar in the flat parameter vector.
    pub offset: usize,
    /// Number of scalars.
    pub len: usize,
}

/// A trainable model.
pub trait Objective {
    /// The tensors, in order, covering the flat vector.
    fn tensors(&self) -> Vec<TensorSpec>;
    /// The starting values.
    fn initial(&self) -> Vec<f32>;
    /// The weighted loss of `batch` at `values`; `grad` (zeroed, as long as
    /// `values`) receives its gradient. Must be a function of its inputs
    /// only (no state that changes results between calls), so that
    /// resumed runs are the same run.
    fn loss_and_grad(
        &mut self,
        values: &[f32],
        batch: &Batch,
        weight: f64,
        grad: &mut [f32],
    ) -> Result<f64, TrainError>;
    /// Puts values back into their ranges after a step.
    fn project(&self, _values: &mut [f32]) {}
    /// Sets values that follow a schedule rather than the gradient (an
    /// annealed β) to what they are at `step` (from 0); called after
    /// each step with the step the values are now at, so that a run's values are a
    /// function of its step and resumed runs stay the same run.
    /// [`Self::initial`] gives step 0's.
    fn at_step(&self, _step: usize, _values: &mut [f32]) {}
    /// Samples along rays that reached the network in this process's steps
    /// (those an occupancy grid skipped not counted), for the report of
    /// the work really done; `None` where the model does not count them.
    fn samples_evaluated(&self) -> Option<u64> {
        None
    }
    /// State that changes with training besides the parameters (an
    /// occupancy grid), kept in checkpoints.
    fn state(&self) -> Vec<(String, Vec<f32>)> {
        Vec::new()
    }
    /// Restores what [`Self::state`] gave; refuses state of another shape.
    fn restore_state(&mut self, state: &[(String, Vec<f32>)]) -> Result<(), TrainError> {
        if state.is_empty() {
            Ok(())
        } else {
            Err(TrainError::Invalid(
                "the checkpoint holds state this model does not have".into(),
            ))
        }
    }
}

/// An analytic field's `param(...)` arguments, fitted through the fused
/// kernel or the dfdx graph.
pub struct FieldObjective<'m> {
    /// The field and its parameters' layout (borrowed, or owned by a
    /// trained field).
    pub model: std::borrow::Cow<'m, TrainModel>,
    /// Which differentiation computes the gradient: the fused kernel or the dfdx graph.
    pub backend: Backend,
    dev: dfdx::prelude::Cpu,
}

impl<'m> FieldObjective<'m> {
    /// The objective of `model`, differentiated by `backend`.
    pub fn new(model: &'m TrainModel, backend: Backend) -> Self {
        // No allocation cache: dfdx's keeps every dropped buffer for good
        // (5 MB a step on a box fit).
        let dev = dfdx::prelude::Cpu::default();
        FieldObjective {
            model: std::borrow::Cow::Borrowed(model),
            backend,
            dev,
        }
    }

    /// The objective of `model`, which it keeps.
    pub fn owning(model: TrainModel, backend: Backend) -> FieldObjective<'static> {
        FieldObjective {
            model: std::borrow::Cow::Owned(model),
            backend,
            dev: dfdx::prelude::Cpu::default(),
        }
    }
}

impl Objective for FieldObjective<'_> {
    fn tensors(&self) -> Vec<TensorSpec> {
        self.model
            .params
            .iter()
            .map(|p| TensorSpec {
                name: p.name.clone(),
                offset: p.offset,
                len: p.len,
            })
            .collect()
    }

    fn initial(&self) -> Vec<f32> {
        self.model
            .initial_values()
            .iter()
            .map(|&x| x as f32)
            .collect()
    }

    fn loss_and_grad(
        &mut self,
        values: &[f32],
        batch: &Batch,
        weight: f64,
        grad: &mut [f32],
    ) -> Result<f64, TrainError> {
        let lg = match self.backend {
            Backend::Fused => loss_and_grad_f32(&self.model, values, batch, weight),
            Backend::Dfdx => {
                super::graph::loss_and_grad(&self.dev, &self.model, values, batch, weight)?
            }
        };
        for (g, v) in grad.iter_mut().zip(&lg.grad) {
            *g = *v as f32;
        }
        Ok(lg.loss)
    }

    fn project(&self, values: &mut [f32]) {
        self.model.project(values);
    }
}
