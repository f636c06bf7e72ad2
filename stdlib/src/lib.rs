//! The sdfl standard library: the built-ins' signatures and docs, the values
//! a scene file evaluates to, and the scene IR handed to the runtime.

pub mod camera;
