//! The sdfl runtime: lowering of scenes to fast evaluators, sphere tracing,
//! volume rendering, dfdx training, data sets, and writing outputs.
#![warn(missing_docs)]

pub mod cpu;
pub mod data;
pub mod describe;
pub mod effects;
pub mod export;
pub mod interrupt;
pub mod jobs;
pub mod lanes;
pub mod mesh;
pub mod metrics;
pub mod neural;
pub mod output;
pub mod pace;
pub mod plot;
pub mod render;
pub mod sdf;
pub mod trace;
pub mod train;
pub mod video;
pub mod volume;

pub use render::{run_job, JobReport, Plan, RunOptions};
pub use sdf::{LowerOptions, Lowered};
