//! The standard library's tests (evaluation, bounds, primitives, the
//! registry, user shapes, work estimates, fuzzing), one module per concern
//! in one test binary.

mod bounds;
mod eval;
mod fuzz;
mod models;
mod module_loops;
mod primitives;
mod registry;
mod user_shapes;
mod work;
