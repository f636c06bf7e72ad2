//! `render` statements: a shape sphere-traced, a field volume-rendered.

use std::sync::Arc;

use glam::DVec3;

use super::{Field, Output, Sampler};
use crate::camera::Camera;
use crate::material::Material;
use crate::shape::Shape;

/// One `render` statement, fully evaluated and validated.
#[derive(Debug, Clone)]
pub struct RenderJob {
    /// The statement's name, the stem of its files.
    pub name: String,
    /// The shape traced.
    pub scene: Arc<Shape>,
    /// How hits are shaded.
    pub material: Arc<Material>,
    /// The views, one image (or frame) each.
    pub cameras: Vec<Camera>,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Where rays start (distance from the camera).
    pub near: f64,
    /// Where rays give up: farther is a miss.
    pub far: f64,
    /// Most sphere-tracing steps per ray.
    pub iterations: u32,
    /// A ray hits where the distance falls below this (see `hit_tolerance`).
    pub epsilon: f64,
    /// How `epsilon` is applied.
    pub hit_tolerance: HitTolerance,
    /// The colour of misses.
    pub background: DVec3,
    /// Exponential fog by distance, over hits and misses (at `far`).
    pub fog: Option<crate::effects::Fog>,
    /// Rays per pixel whose colours are averaged (a square: 1, 4, 9, …;
    /// see `effects::subpixel_offsets`). Depth, normals and the mask are
    /// the pixel centre's.
    pub samples_per_pixel: u32,
    /// The files it writes.
    pub outputs: Vec<Output>,
}

/// When a sphere-traced ray counts as a hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum HitTolerance {
    /// Below `max(epsilon, half a pixel's width at that distance)`, with
    /// over-relaxed steps: rays grazing a surface are decided at the
    /// image's resolution.
    Pixel,
    /// Below `epsilon`, with plain steps: exactly the reference
    /// assignment's tracer.
    Absolute,
}

/// A `render` statement whose scene is a field: volume rendering.
#[derive(Debug, Clone)]
pub struct VolumeJob {
    /// The statement's name, the stem of its files.
    pub name: String,
    /// The volume rendered.
    pub field: Arc<Field>,
    /// The views, one image (or frame) each.
    pub cameras: Vec<Camera>,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Where samples fall along each ray.
    pub sampler: Sampler,
    /// The files it writes.
    pub outputs: Vec<Output>,
}
