//! The integration tests of the `sdfl` binary and the crates together, one
//! module per concern, in one test binary: each binary links the whole
//! runtime, so one binary builds once (`tests/memory.rs` stays apart: it
//! counts every allocation of its process).

#[path = "../common/mod.rs"]
mod common;

mod budget;
mod cameras;
mod capture_fixture;
mod captures;
mod checkpoint_format;
mod cli;
mod conventions;
mod diagnostics;
mod editors;
mod effects;
mod export_dataset;
mod field_exports;
mod fit_health;
mod forward_facing;
mod golden;
mod hash_sdf;
mod hash_surface;
mod hostile;
mod hostile_data;
mod hostile_io;
mod hostile_lang;
mod idr;
mod module_loops;
mod nerf;
mod nerf_synthetic_downscale;
mod neural_sdf;
mod neural_surface;
mod readme;
mod silhouette_data;
mod sweep;
mod textmate;
mod train;
mod train_log;
mod unbounded;
mod video;
mod view_api;
mod view_browser;
mod view_load;
mod view_watch;
