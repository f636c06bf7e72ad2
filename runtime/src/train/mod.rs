//! Training on dfdx 0.13 (CPU):
//!
//! * [`params`]: runtime-sized named parameters, Adam through dfdx's kernel.
//! * [`graph_ops`]: differentiable compositing and SDF densities on
//!   `[rays, samples]` tensors (cumsum as a triangular matmul).
//! * [`box_graph`]: the assignment's box volume as a pure dfdx graph.
//! * [`box_op`]: the same as one dfdx op backed by the fused kernel.
//! * [`box_fit`]: the assignment's part 2 fit.

pub mod box_fit;
pub mod box_graph;
pub mod box_op;
pub mod graph_ops;
pub mod params;

pub use box_fit::{
    assignment_cameras, fit_box, fit_box_with, BoxFitConfig, BoxFitResult, FitBackend, FitView,
};

pub use params::{Adam, ParamId, ParamStore};

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
