//! What a statement will cost to run, estimated when the file is evaluated:
//! point evaluations (rays × steps or samples) and peak memory. Absurd
//! estimates are refused before anything runs; `sdfl plan` prints them.
//! Also the warning for cameras that cannot reach the scene.

use glam::DVec3;
use sdfl_lang::diag::{codes, fmt_num, Diag};
use sdfl_lang::Span;

use crate::camera::Camera;
use crate::shape::Aabb;
use crate::size::{fmt_bytes, BYTES_PER_PRIMITIVE};
use crate::value::{Dataset, Field, OutputKind, Program, RenderJob, TrainJob, VolumeJob};

/// Most SDF (or density) evaluations one statement may ask for: about an
/// hour of tracing on a few cores. The examples need 1e7 to 1e9.
pub const MAX_EVALUATIONS: f64 = 1e12;
/// Largest estimated peak memory of one statement.
pub const MAX_MEMORY: f64 = 8e9;

/// The estimated cost of one statement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Work {
    /// SDF or density evaluations, at most (every ray takes every step).
    pub evaluations: f64,
    /// Peak bytes: the lowered scene and one view's buffers.
    pub memory: f64,
}

impl Work {
    pub fn describe(&self) -> String {
        format!(
            "at most {} SDF evaluations, about {} of memory",
            approx(self.evaluations),
            fmt_bytes(self.memory)
        )
    }
}

/// An estimate, to two significant figures past a billion.
fn approx(x: f64) -> String {
    if x < 1e9 {
        format!("{x:.0}")
    } else {
        format!("{x:.1e}")
    }
}

fn pixels(size: (u32, u32), override_size: Option<(u32, u32)>) -> f64 {
    let (w, h) = override_size.unwrap_or(size);
    w as f64 * h as f64
}

/// Bytes per pixel of the per-view buffers the outputs need, plus a GIF
/// frame (RGBA) while it is encoded.
fn bytes_per_pixel(kinds: impl Iterator<Item = OutputKind>, volume: bool) -> f64 {
    let mut b: f64 = if volume { 16.0 } else { 0.0 };
    for k in kinds {
        b += match k {
            OutputKind::Image => 3.0,
            OutputKind::Gif { .. } | OutputKind::DepthGif { .. } => 7.0,
            OutputKind::Depth => 7.0,
            OutputKind::Normals => 3.0,
            OutputKind::Mask => 4.0,
            // Colour, mask and the RGBA frame being encoded.
            OutputKind::Dataset => 8.0,
            _ => 3.0,
        };
    }
    b.max(3.0)
}

/// Most vertices a mesh may have: with its normals, quads, triangles and
/// the PLY bytes, about 100 bytes each at the peak (2 GB); a surface that
/// needs more stops with an error.
pub const MAX_MESH_VERTICES: usize = 20_000_000;

/// The grid evaluations and peak memory of the meshes among `outputs`, a
/// grid point costing `per_point` evaluations. A surface is assumed to cross
/// a few times the cells of one plane; [`MAX_MESH_VERTICES`] bounds the rest.
fn mesh_work<'a>(outputs: impl Iterator<Item = &'a OutputKind>, per_point: f64) -> Work {
    let mut w = Work {
        evaluations: 0.0,
        memory: 0.0,
    };
    for o in outputs {
        if let OutputKind::Mesh { resolution, .. } = o {
            // The grid is padded by two cells a side.
            let n = *resolution as f64 + 5.0;
            w.evaluations += n * n * n * per_point;
            // Two planes of points and values, two layers of vertex
            // numbers, and vertices, normals and triangles of the surface.
            let surface = (8.0 * n * n).min(MAX_MESH_VERTICES as f64);
            w.memory = w
                .memory
                .max(2.0 * n * n * 16.0 + 2.0 * n * n * 4.0 + surface * 100.0);
        }
    }
    w
}

pub fn render_work(j: &RenderJob, size: Option<(u32, u32)>) -> Work {
    render_work_of(j, size, j.scene.primitive_count() as u64)
}

/// [`render_work`] with the scene's expanded primitive count known.
pub fn render_work_of(j: &RenderJob, size: Option<(u32, u32)>, primitives: u64) -> Work {
    let px = pixels((j.width, j.height), size);
    let mesh = mesh_work(j.outputs.iter().map(|o| &o.kind), 1.0);
    // Supersampled colour traces `samples_per_pixel` rays, and the pixel
    // centre's too where depth, normals or a mask are asked for; each shaded
    // sample pays for its material's shadows and occlusion.
    let spp = j.samples_per_pixel as f64;
    let geometry = j.outputs.iter().any(|o| {
        matches!(
            o.kind,
            OutputKind::Depth
                | OutputKind::DepthGif { .. }
                | OutputKind::Normals
                | OutputKind::Mask
                | OutputKind::Dataset
        )
    });
    let rays = if spp > 1.0 && geometry {
        spp + 1.0
    } else {
        spp
    };
    let effects = j
        .material
        .effect_evaluations()
        .max(painted_effects(&j.scene)) as f64;
    Work {
        evaluations: px * j.cameras.len() as f64 * (j.iterations as f64 * rays + spp * effects)
            + mesh.evaluations,
        memory: primitives as f64 * BYTES_PER_PRIMITIVE as f64
            + (px * bytes_per_pixel(j.outputs.iter().map(|o| o.kind.clone()), false))
                .max(mesh.memory),
    }
}

/// The most SDF evaluations a painted material's effects take per shaded
/// point.
fn painted_effects(s: &crate::shape::Shape) -> u64 {
    let own = match s {
        crate::shape::Shape::Paint(_, m) => m.effect_evaluations(),
        _ => 0,
    };
    s.children()
        .into_iter()
        .map(|c| painted_effects(c))
        .fold(own, u64::max)
}

/// Most evaluations of all statements of a file together.
pub const MAX_FILE_EVALUATIONS: f64 = 4.0 * MAX_EVALUATIONS;
/// Most primitives lowered by all statements of a file together (each
/// statement lowers its scene again).
pub const MAX_FILE_PRIMITIVES: u64 = 10 * crate::size::MAX_PRIMITIVES;

/// The diagnostic for a statement that takes a file's totals past the
/// limits.
pub fn refuse_total(evaluations: f64, primitives: u64, span: Span) -> Option<Diag> {
    let (what, help) = if evaluations > MAX_FILE_EVALUATIONS {
        (
            format!(
                "{} SDF evaluations (at most {})",
                approx(evaluations),
                fmt_num(MAX_FILE_EVALUATIONS)
            ),
            "lower image sizes, views or steps, or split the file",
        )
    } else if primitives > MAX_FILE_PRIMITIVES {
        (
            format!(
                "{} primitives to lower (at most {})",
                approx(primitives as f64),
                approx(MAX_FILE_PRIMITIVES as f64)
            ),
            "render large scenes in fewer statements (several cameras make several views), or split the file",
        )
    } else {
        return None;
    };
    Some(
        Diag::new(
            codes::WORK,
            span,
            format!("with this statement the file would need {what}"),
        )
        .label("the statements up to here add up to too much")
        .help(help),
    )
}

pub fn volume_work(j: &VolumeJob, size: Option<(u32, u32)>) -> Work {
    let px = pixels((j.width, j.height), size);
    // A network's sample costs its multiply-adds (in units of about 10 000)
    // and holds its activations for one pass of 65 536 samples.
    let (per_sample, network) = match &*j.field {
        Field::Sdf(_) => (1.0, 0.0),
        Field::Nerf(n) => (
            (n.multiply_adds_per_sample() as f64 / 10_000.0).max(1.0),
            65_536.0 * 4.0 * ((n.layers + 4) * n.width + n.position.width()) as f64
                + 4.0 * n.weights() as f64,
        ),
        // Refused as a volume when evaluated; counted like a network.
        Field::NeuralSdf(n) => ((n.multiply_adds() as f64 / 10_000.0).max(1.0), 0.0),
        Field::NeuralSurface(n) => (
            (n.multiply_adds_per_sample() as f64 / 10_000.0).max(1.0),
            0.0,
        ),
    };
    let mesh = mesh_work(j.outputs.iter().map(|o| &o.kind), per_sample);
    Work {
        evaluations: px * j.cameras.len() as f64 * j.sampler.samples as f64 * per_sample
            + mesh.evaluations,
        memory: (px * bytes_per_pixel(j.outputs.iter().map(|o| o.kind.clone()), true))
            .max(mesh.memory)
            + network,
    }
}

pub fn train_work(j: &TrainJob, size: Option<(u32, u32)>) -> Work {
    let samples = j.sampler.samples as f64;
    let pixels_of_data = match &*j.data {
        Dataset::Rendered {
            cameras,
            width,
            height,
            ..
        } => Some(*width as f64 * *height as f64 * cameras.len() as f64),
        Dataset::Traced { job, .. } => {
            Some(job.width as f64 * job.height as f64 * job.cameras.len() as f64)
        }
        Dataset::Files { .. } | Dataset::NerfSynthetic { .. } | Dataset::Points { .. } => None,
    };
    let iterations = match (j.epochs, pixels_of_data) {
        (Some(e), Some(px)) => e as f64 * (px / j.rays.max(1) as f64).ceil(),
        // Read files' sizes are known only when read; a 16 384² view each.
        (Some(e), None) => {
            let px = match &*j.data {
                // Cameras unknown until read: as many pixels as a data set
                // may decode to (12 bytes each).
                Dataset::NerfSynthetic { .. } => 2e9 / 12.0,
                _ => j.data.cameras().len() as f64 * 16_384.0 * 16_384.0,
            };
            e as f64 * (px / j.rays.max(1) as f64).ceil()
        }
        (None, _) => j.iterations as f64,
    };
    // Training walks the whole model at every sample (no culling), once for
    // values and once per 16 parameters for tangents.
    let mut scalars = 0usize;
    j.model.visit_params(&mut |u| scalars += u.decl.init.len());
    let per_sample = match &*j.model {
        Field::Sdf(f) => f.shape.evaluation_cost() * (1.0 + scalars.div_ceil(16) as f64),
        // Forward and backward through the network, in units of about
        // 10 000 multiply-adds (a few hundred primitive evaluations).
        Field::Nerf(n) => 3.0 * n.multiply_adds_per_sample() as f64 / 10_000.0,
        // A distance and its three tangents, forward and backward, at a
        // surface and a random point per ray of the batch (not per sample).
        Field::NeuralSdf(n) => 2.0 * 12.0 * n.multiply_adds() as f64 / 10_000.0 / samples.max(1.0),
        Field::NeuralSurface(n) => 3.0 * n.multiply_adds_per_sample() as f64 / 10_000.0,
    };
    let steps = iterations * j.rays as f64 * samples * per_sample;
    let (data_evals, data_bytes) = match &*j.data {
        Dataset::Rendered {
            cameras,
            width,
            height,
            sampler,
            ..
        } => {
            let px = *width as f64 * *height as f64 * cameras.len() as f64;
            (px * sampler.samples as f64, px * 12.0)
        }
        Dataset::Traced { job, .. } => {
            let w = render_work(job, None);
            let px = job.width as f64 * job.height as f64 * job.cameras.len() as f64;
            (w.evaluations, w.memory + px * 12.0)
        }
        // Files are checked against their declared sizes when read.
        Dataset::Files { .. } | Dataset::NerfSynthetic { .. } | Dataset::Points { .. } => {
            (0.0, 0.0)
        }
    };
    let px = pixels((j.width, j.height), size);
    let views = j.views.len() as f64;
    let outputs = (j.before.len() + j.after.len()) as f64;
    let per_point = match &*j.model {
        Field::Sdf(f) => f.shape.primitive_count() as f64,
        Field::Nerf(n) => (n.multiply_adds_per_sample() as f64 / 10_000.0).max(1.0),
        // A distance and its gradient.
        Field::NeuralSdf(n) => (4.0 * n.multiply_adds() as f64 / 10_000.0).max(1.0),
        Field::NeuralSurface(n) => (4.0 * n.sdf.multiply_adds() as f64 / 10_000.0).max(1.0),
    };
    let mesh = mesh_work(j.before.iter().chain(&j.after).map(|o| &o.kind), per_point);
    // Rendering a network's views costs its passes; a geometry GIF traces
    // each view with up to 96 steps.
    let network = match &*j.model {
        Field::Sdf(_) => 1.0,
        _ => per_point,
    };
    let geometry_gifs = j
        .before
        .iter()
        .chain(&j.after)
        .filter(|o| matches!(o.kind, OutputKind::GeometryGif { .. }))
        .count() as f64;
    Work {
        evaluations: steps
            + data_evals
            + outputs.min(1.0) * 2.0 * px * views * samples * network
            + geometry_gifs * px * views * 96.0 * per_point
            + mesh.evaluations,
        // Per-ray buffers of a batch (samples, weights, gradients); a
        // network keeps every layer's activations per sample, twice with a
        // fine network (which sees the coarse samples too).
        memory: data_bytes
            + j.rays as f64 * samples * 64.0
            + (px * 16.0).max(mesh.memory)
            + match &*j.model {
                Field::Sdf(_) => 0.0,
                // Every layer's values and three tangents, forward and back,
                // for 2 points a ray; weights with gradient and moments.
                Field::NeuralSdf(n) => {
                    j.rays as f64
                        * 2.0
                        * 8.0
                        * 4.0
                        * ((n.layers + 1) * n.width + 4 * n.encoding_width()) as f64
                        + 16.0 * n.multiply_adds() as f64
                }
                // Per sample: every SDF layer's values, three tangents and
                // their slopes, and the colour network's activations.
                Field::NeuralSurface(n) => {
                    let s = &n.sdf;
                    let per_sample = 4
                        * (3 * 4 * (s.layers + 1) * s.width
                            + 4 * s.encoding_width()
                            + 2 * n.color_layers * n.color_width
                            + n.color_input()
                            + 16);
                    j.rays as f64 * samples * per_sample as f64
                        + 16.0 * (s.multiply_adds() + n.color_multiply_adds()) as f64
                }
                Field::Nerf(n) => {
                    let per_sample = 4
                        * (2 * n.position.width()
                            + (n.layers + 4) * n.width
                            + 2 * n.color_width
                            + 16);
                    let fine = if n.fine > 0 {
                        2.0 + n.fine as f64 / samples.max(1.0)
                    } else {
                        0.0
                    };
                    let networks = if n.fine > 0 { 2.0 } else { 1.0 };
                    // Values, gradient and Adam's two moments of every weight.
                    j.rays as f64 * samples * per_sample as f64 * (1.0 + fine)
                        + networks * n.weights() as f64 * 16.0
                }
            },
    }
}

/// The diagnostic for a statement whose estimate is beyond the limits.
pub fn refuse(work: Work, span: Span, what: &str) -> Option<Diag> {
    let (too, fix) = if work.evaluations > MAX_EVALUATIONS {
        (
            format!(
                "{} SDF evaluations (at most {})",
                approx(work.evaluations),
                fmt_num(MAX_EVALUATIONS)
            ),
            format!("lower the image size, the number of views or the {what}"),
        )
    } else if work.memory > MAX_MEMORY {
        (
            format!(
                "about {} of memory (at most {})",
                fmt_bytes(work.memory),
                fmt_bytes(MAX_MEMORY)
            ),
            "lower the image size or the number of primitives".to_string(),
        )
    } else {
        return None;
    };
    Some(
        Diag::new(
            codes::WORK,
            span,
            format!("this statement would need {too}"),
        )
        .label(work.describe())
        .help(format!(
            "{fix}; `sdfl plan` prints the estimate (sizes can also be lowered with `--size`)"
        )),
    )
}

/// Distance from `p` to the box (0 inside) and to its farthest corner.
fn box_distances(b: &Aabb, p: DVec3) -> (f64, f64) {
    let near = (b.min - p).max(p - b.max).max(DVec3::ZERO).length();
    let far = (b.min - p).abs().max((b.max - p).abs()).length();
    (near, far)
}

/// A warning when no ray of some views can reach the scene: the camera is
/// farther from the scene's bounds than `far`, or the whole scene is
/// nearer than `near`. Such views are the background colour only.
pub fn reach_warning(
    bounds: Option<Aabb>,
    cameras: &[Camera],
    near: f64,
    far: f64,
    span: Span,
    (far_span, far_note): (Span, &str),
) -> Option<Diag> {
    let b = bounds?;
    if !(b.min.is_finite() && b.max.is_finite()) {
        return None;
    }
    let dists: Vec<(f64, f64)> = cameras.iter().map(|c| box_distances(&b, c.eye)).collect();
    let missing: Vec<&(f64, f64)> = dists
        .iter()
        .filter(|(d, farthest)| *d >= far || *farthest <= near)
        .collect();
    let first = missing.first()?;
    let needed = dists.iter().map(|d| d.1).fold(0.0, f64::max);
    let views = if missing.len() == cameras.len() {
        if cameras.len() == 1 {
            "the camera".to_string()
        } else {
            format!("all {} views", cameras.len())
        }
    } else {
        format!("{} of {} views", missing.len(), cameras.len())
    };
    let (message, help) = if first.0 >= far {
        (
            format!(
                "{views} cannot reach the scene: it is {} away, beyond `far` = {}",
                fmt_num(round3(first.0)),
                fmt_num(far)
            ),
            format!(
                "set `far` to at least {} (the farthest corner of the scene's bounds) to see all of it",
                fmt_num(round3(needed * 1.01))
            ),
        )
    } else {
        (
            format!(
                "{views} cannot reach the scene: all of it is nearer than `near` = {}",
                fmt_num(near)
            ),
            "lower `near`".to_string(),
        )
    };
    Some(
        Diag::new(codes::MISSES_SCENE, span, message)
            .label("these views see only the background")
            .note(far_span, far_note)
            .help(help),
    )
}

fn round3(x: f64) -> f64 {
    (x * 1000.0).round() / 1000.0
}

/// Estimates for every statement of a program with a size override (the
/// CLI's `--size`): the first refusal, as a message without a span.
pub fn check_program(program: &Program, size: Option<(u32, u32)>) -> Result<(), String> {
    let works = program
        .renders
        .iter()
        .map(|j| (&j.name, render_work(j, size), "steps"))
        .chain(
            program
                .volumes
                .iter()
                .map(|j| (&j.name, volume_work(j, size), "samples")),
        )
        .chain(
            program
                .trains
                .iter()
                .map(|j| (&j.name, train_work(j, size), "iterations")),
        );
    for (name, w, what) in works {
        if let Some(d) = refuse(w, Span::default(), what) {
            return Err(format!(
                "`{name}`: {} with this --size; {}",
                d.message,
                d.help.unwrap_or_default()
            ));
        }
    }
    Ok(())
}
