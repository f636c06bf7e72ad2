//! The standard library's tests (evaluation, bounds, primitives, the
//! registry, user shapes, work estimates, fuzzing, and each module's own:
//! cameras, lenses, densities, numbers...), one module per concern in one
//! test binary, against the public API: the library builds no unit-test
//! binary (`[lib] test = false`), which would compile it a second time.

mod bounds;
mod camera;
mod camera_path;
mod density;
mod effects;
mod eval;
mod files;
mod fuzz;
mod lens;
mod material;
mod models;
mod module_loops;
mod num;
mod param;
mod paths;
mod primitives;
mod program;
mod registry;
mod user_shapes;
mod views;
mod work;
