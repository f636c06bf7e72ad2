//! Readers for input data sets.

pub mod image;
pub mod npy;
