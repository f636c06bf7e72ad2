//! Tests of the neural fields, their encodings and their kernels.

mod background;
mod bf16;
mod composite;
mod contract;
mod distance;
mod encoding;
mod field;
mod fp32;
mod hash_sdf;
mod hashgrid;
mod mlp;
mod nerf;
mod occupancy;
mod sdf_net;
mod surface;
mod warp;
