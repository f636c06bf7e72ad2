//! Readers for input data sets.
//!
//! This module only declares the others and re-exports what the rest of
//! sdfl uses; they import each other by name, never through here, so the
//! test of import loops sees the real arrows. The data formats are
//! [`formats`], one file each behind [`format::Format`].

pub mod budget;
pub mod camera;
pub mod capture;
pub mod error;
pub mod export;
pub mod format;
pub mod formats;
pub mod frames;
pub mod image;
pub mod normalize;
pub mod npy;
pub mod paths;
pub mod points;
pub mod transforms;
pub mod view;
pub mod view_image;

/// Each format's module by its own name too (`data::llff`).
pub use formats::{colmap, idr, llff, nerf_synthetic, nerfstudio};

pub use budget::{
    decode_bytes, estimate, view_bytes, views_bytes, Estimate, OnceRead, MAX_HEADERS,
};
pub use camera::{check_position, check_rigid, check_rotation, MAX_POSITION};
pub use error::{
    argument_span, at_argument, coded, no_coverage, AtArgument, Coded, DOWNSCALE, NO_COVERAGE,
};
pub use view::{coverage_from_alpha, downscale_size_of, downscaled_size, DataNeeds, TrainView};
