//! Training on dfdx 0.13 (CPU), for any field whose arguments are marked
//! `param(...)`:
//!
//! * [`model`]: a field's distinct parameters, their names, ranges and flat
//!   layout, read as forward-mode dual numbers.
//! * [`fused`]: the fused per-ray kernel (loss and exact gradient in one
//!   forward pass, ordered parallel reduction).
//! * [`tape`]: the model traced into a flat tape each step, run forward and
//!   in reverse on lanes of 16 samples (the fused kernel's fast path).
//! * [`trainer`]: seeded batches, the step (Adam through dfdx's kernel,
//!   projection into range), the loop.
//! * [`graph`]: the `dfdx` backend: the field as a custom dfdx op, the
//!   compositing and loss as a dfdx autodiff graph.
//! * [`field`]: the trained field as the job sees it (render a view, a
//!   distance for meshes, a density for exports, reported parameters).
//! * [`checkpoint`]: safetensors checkpoints with a fingerprint of the run.
//! * [`frame`]: where a checkpoint's model sits relative to its data (the
//!   data → model similarity, the warp, the background).
//! * [`log`]: what a run reports as it goes: events for an observer, a
//!   metrics CSV, TensorBoard events and the current held-out view.
//! * [`params`]: runtime-sized named parameters, Adam through dfdx's kernel.
//! * [`graph_ops`]: differentiable compositing as dfdx graph ops on
//!   `[rays, samples]` tensors (cumsum as a triangular matmul), for fields
//!   whose evaluation is itself a dfdx graph.

pub mod checkpoint;
pub mod export_names;
pub mod field;
pub mod frame;
pub mod fused;
pub mod graph;
pub mod graph_ops;
pub mod log;
pub mod model;
pub mod objective;
pub mod params;
pub mod tape;
pub mod trainer;

pub use field::{Trained, TrainedField, Viewing};
pub use model::TrainModel;
pub use objective::{FieldObjective, Objective, TensorSpec};
pub use params::{Adam, ParamId, ParamStore};
pub use trainer::{Run, TrainSetup, TrainView};

/// Training stopped because a loss, gradient or parameter became
/// non-finite (carried in an `io::Error` so that the CLI reports it as a
/// fit that diverged, not as a file problem).
#[derive(Debug)]
pub struct NonFinite(pub String);

impl std::fmt::Display for NonFinite {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for NonFinite {}

/// The stable code of a training run stopped by a non-finite number.
pub const NON_FINITE: &str = "sdfl::train::non-finite";

/// Whether `e` is a training run stopped by a non-finite number.
pub fn is_non_finite(e: &std::io::Error) -> bool {
    e.get_ref().is_some_and(|r| r.is::<NonFinite>())
}

/// Errors from training.
#[derive(Debug, Clone, PartialEq)]
pub enum TrainError {
    /// Invalid configuration or inputs.
    Invalid(String),
    /// An error reported by the tensor backend.
    Backend(String),
    /// A parameter received no gradient or a non-finite one.
    Gradient(String),
}

impl std::fmt::Display for TrainError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TrainError::Invalid(m) => write!(f, "invalid training setup: {m}"),
            TrainError::Backend(m) => write!(f, "tensor backend error: {m}"),
            TrainError::Gradient(m) => write!(f, "bad gradient: {m}"),
        }
    }
}

impl std::error::Error for TrainError {}

impl From<crate::volume::VolumeError> for TrainError {
    fn from(e: crate::volume::VolumeError) -> Self {
        TrainError::Invalid(e.to_string())
    }
}

impl From<dfdx::tensor::CpuError> for TrainError {
    fn from(e: dfdx::tensor::CpuError) -> Self {
        TrainError::Backend(e.to_string())
    }
}
