//! Readers for input data sets.

pub mod image;
pub mod nerf_synthetic;
pub mod npy;
pub mod points;
