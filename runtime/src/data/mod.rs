//! Readers for input data sets.

pub mod npy;
