//! Training: a runtime-sized parameter store updated with dfdx's Adam kernel,
//! the box volume as a dfdx graph, and the assignment's box fit.

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
