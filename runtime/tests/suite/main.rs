//! The runtime's tests in one test binary: against references (evaluators,
//! gradients, the tracer, volumes, views), one module per concern, and each
//! runtime module's own tests, in modules named and nested as in
//! `runtime/src` (the library itself builds no test binary).

mod cpu;
mod data;
mod evaluators;
mod export;
mod formats;
mod gradients;
mod interrupt;
mod jobs;
mod mesh;
mod metrics;
mod module_loops;
mod nerf_graph;
mod neural;
mod output;
mod pace;
mod plot;
mod sdf;
mod tiles;
mod trace;
mod tracer;
mod train;
mod user_shapes;
mod video;
mod views;
mod volume;
