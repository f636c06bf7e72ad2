//! Neural fields on the CPU: fused dense layers ([`mlp`]), input
//! encodings ([`encoding`]), the NeRF network ([`nerf`]), compositing of
//! densities with its reverse sweep ([`composite`]), and the NeRF as a
//! trainable model and a renderable field ([`field`]).

pub mod composite;
pub mod encoding;
pub mod field;
pub mod mlp;
pub mod nerf;
