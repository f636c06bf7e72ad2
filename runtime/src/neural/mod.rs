//! Neural fields on the CPU: fused dense layers ([`mlp`]), their fp32
//! products without packing ([`fp32`]) and bf16 products ([`bf16`]), input
//! encodings ([`encoding`], the multiresolution hash grid [`hashgrid`]),
//! the NeRF network ([`nerf`]), compositing of densities with its reverse
//! sweep ([`composite`]), the NeRF as a trainable model and a renderable
//! field ([`field`]), the occupancy grid that skips empty space
//! ([`occupancy`]); the neural SDF with its exact input gradient
//! ([`sdf_net`]) and on a hash grid ([`hash_sdf`]), as a model fitted to points ([`distance`]) and as a
//! volume with a colour network fitted to images ([`surface`]).

pub mod background;
pub mod bf16;
pub mod composite;
pub mod contract;
pub mod distance;
pub mod encoding;
pub mod field;
pub mod fp32;
pub mod hash_sdf;
pub mod hashgrid;
pub mod layout;
pub mod mlp;
pub mod nerf;
pub mod occupancy;
pub mod sdf_net;
pub mod surface;
pub mod warp;
