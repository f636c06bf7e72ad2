//! The runtime's tests against references (evaluators, gradients, the
//! tracer, volumes, views), one module per concern in one test binary.

mod evaluators;
mod formats;
mod gradients;
mod module_loops;
mod nerf_graph;
mod tiles;
mod tracer;
mod user_shapes;
mod views;
mod volume;
