//! The sdfl runtime: lowering of scenes to fast evaluators, sphere tracing,
//! rendering jobs and writing their outputs.

pub mod output;
pub mod render;
pub mod sdf;
pub mod trace;

pub use render::{run_job, JobReport, Plan, RunOptions};
pub use sdf::{LowerOptions, Lowered};
