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
use crate::value::{Dataset, OutputKind, Program, RenderJob, TrainJob, VolumeJob};

/// Most SDF (or density) evaluations one statement is expected to take
/// unless [`MAX_EVALUATIONS_VAR`] says otherwise: about an hour of tracing
/// on a few cores. The examples need 1e7 to 1e11. A safety net against a
/// typo's cost, not a wall: the refusal names the override.
pub const MAX_EVALUATIONS: f64 = 1e12;
/// The environment variable that sets the limit on a statement's expected
/// evaluations in place of [`MAX_EVALUATIONS`] (a file's together: four
/// times it), for runs meant to take hours.
pub const MAX_EVALUATIONS_VAR: &str = "SDFL_MAX_EVALUATIONS";

/// The limit [`MAX_EVALUATIONS_VAR`] sets (`value`), or [`MAX_EVALUATIONS`]
/// without one; an error for a value that is no positive finite number.
pub fn max_evaluations_from(value: Option<&str>) -> Result<f64, String> {
    limit_from(
        value,
        MAX_EVALUATIONS,
        MAX_EVALUATIONS_VAR,
        "evaluations (such as 5e12)",
    )
}

/// A limit set by environment variable `var` (`value`), or `default`
/// without one; an error naming `var` and `what` for a value that is no
/// positive finite number.
fn limit_from(value: Option<&str>, default: f64, var: &str, what: &str) -> Result<f64, String> {
    let Some(v) = value else {
        return Ok(default);
    };
    match v.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        _ => Err(format!("{var}={v:?} is not a positive number of {what}")),
    }
}

/// The limit on one statement's expected evaluations in this process:
/// [`MAX_EVALUATIONS_VAR`]'s, read once (the CLI refuses a bad value at
/// start; here one falls back to [`MAX_EVALUATIONS`]).
pub fn max_evaluations() -> f64 {
    static LIMIT: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    *LIMIT.get_or_init(|| {
        let v = std::env::var(MAX_EVALUATIONS_VAR).ok();
        max_evaluations_from(v.as_deref()).unwrap_or(MAX_EVALUATIONS)
    })
}

/// Most evaluations of all statements of a file together.
pub fn max_file_evaluations() -> f64 {
    4.0 * max_evaluations()
}

/// The share of a ray's samples a NeRF's occupancy grid is expected to
/// pass to the networks over a run: the rest lie in empty space, or behind
/// an opaque surface where a ray has stopped. An expectation, not a bound:
/// the estimate's "at most" counts every sample, and `sdfl run` reports
/// the share it really kept (`samples: ... reached the network`): 10 % for
/// `examples/nerf_fast.sdfl` over its 2500 steps, 18 % over its first 600
/// (the grid empties as the field sharpens).
pub const OCCUPIED_SHARE: f64 = 0.1;
/// The same for a contracted (unbounded) NeRF: the world around the
/// cameras is occupied too, out to the horizon. 18 % over README's capture
/// recipe's 4000 steps on `examples/capture.sdfl`'s capture-like set
/// (2026-12-07), where 10 % made `plan` say 3 minutes for 11.
pub const CONTRACTED_OCCUPIED_SHARE: f64 = 0.2;
/// The same for a hash-grid surface that skips empty space (whole rays
/// that cross no occupied cell): 19 % for `examples/neus_fast.sdfl`.
pub const SURFACE_KEPT_SHARE: f64 = 0.2;
/// Largest estimated peak memory of one statement unless
/// [`MAX_MEMORY_VAR`] says otherwise. A safety net against a typo's size,
/// not a wall: the refusal names the override (a run still has to fit the
/// memory the machine has, which `sdfl run` checks).
pub const MAX_MEMORY: f64 = 8e9;
/// The environment variable that sets the limit on a statement's
/// estimated peak memory, in bytes, in place of [`MAX_MEMORY`].
pub const MAX_MEMORY_VAR: &str = "SDFL_MAX_MEMORY";

/// The limit [`MAX_MEMORY_VAR`] sets (`value`, in bytes), or
/// [`MAX_MEMORY`] without one; an error for a value that is no positive
/// finite number.
pub fn max_memory_from(value: Option<&str>) -> Result<f64, String> {
    limit_from(value, MAX_MEMORY, MAX_MEMORY_VAR, "bytes (such as 16e9)")
}

/// The limit on one statement's estimated peak memory in this process:
/// [`MAX_MEMORY_VAR`]'s, read once (the CLI refuses a bad value at start;
/// here one falls back to [`MAX_MEMORY`]).
pub fn max_memory() -> f64 {
    static LIMIT: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    *LIMIT.get_or_init(|| {
        let v = std::env::var(MAX_MEMORY_VAR).ok();
        max_memory_from(v.as_deref()).unwrap_or(MAX_MEMORY)
    })
}

/// A network's multiply-adds that take about as long as one evaluation of
/// an analytic primitive, so that networks and SDFs are counted in one
/// unit. From BENCHMARKS.md, one core: the NeRF step runs about 46
/// multiply-adds a nanosecond (91 GFLOP/s), the batched evaluator 270–340
/// million primitive distances a second (about 3 ns each, so ~140
/// multiply-adds); rounded down, since narrow layers run slower.
pub const MULTIPLY_ADDS_PER_EVALUATION: f64 = 100.0;

/// A part of a statement's run. Stages run one after another, so their
/// evaluations add up and their memory does not.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Reading or rendering the training data.
    Data,
    /// Rendering a `render` or `volume` statement's views.
    Views,
    /// Optimiser steps.
    Training,
    /// Occupancy-grid refreshes during training.
    GridRefresh,
    /// Held-out views rendered and scored during and after training.
    HeldOut,
    /// Images, GIFs and plots written after (or before) training.
    Outputs,
    /// Meshes, the true surface they are measured against, and surface fits.
    Meshes,
}

impl Stage {
    /// Every stage, in the order a statement runs them.
    pub const ALL: [Stage; 7] = [
        Stage::Data,
        Stage::Views,
        Stage::Training,
        Stage::GridRefresh,
        Stage::HeldOut,
        Stage::Outputs,
        Stage::Meshes,
    ];

    /// The stage's name in `sdfl plan` and in refusals.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Data => "data",
            Stage::Views => "rendering",
            Stage::Training => "training",
            Stage::GridRefresh => "grid refreshes",
            Stage::HeldOut => "held-out evaluation",
            Stage::Outputs => "outputs",
            Stage::Meshes => "meshes and fits",
        }
    }
}

/// What one stage costs: evaluations, and the memory it holds while it runs
/// (on top of what the whole statement holds).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Cost {
    /// SDF (or network) evaluations, an upper bound.
    pub evaluations: f64,
    /// Of those, the ones expected once empty space is skipped (an
    /// occupancy grid's [`OCCUPIED_SHARE`]); the limit and the time are
    /// counted on these.
    pub expected: f64,
    /// Bytes held.
    pub memory: f64,
}

impl Cost {
    /// `evaluations`, every one expected, holding `memory`.
    pub fn all(evaluations: f64, memory: f64) -> Cost {
        Cost {
            evaluations,
            expected: evaluations,
            memory,
        }
    }
}

/// The estimated cost of one statement, stage by stage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Work {
    /// SDF or density evaluations of every stage, at most (every ray takes
    /// every step).
    pub evaluations: f64,
    /// Of those, the ones expected once empty space is skipped: what the
    /// limit ([`max_evaluations`]) and the time are counted on.
    pub expected: f64,
    /// Peak bytes: what is held throughout, plus the largest stage's own.
    pub memory: f64,
    /// Bytes held throughout: the lowered scene, the data, the weights with
    /// their gradients, moments and checkpoint copies, grids.
    pub resident: f64,
    /// Bytes each computing thread keeps for the run (a hash-grid
    /// surface's blocked scratch), counted by [`Work::memory_on`].
    pub per_thread: f64,
    /// Whether the run multiplies matrices through the dfdx graph, whose
    /// library keeps [`Host::matmul_scratch`] in each thread that has.
    pub matmul: bool,
    /// Time a training evaluation of this model takes, in evaluations of
    /// the machine's calibrated rate ([`crate::model::Model::training_pace`]): the count is of
    /// multiply-adds, and models spend their time differently.
    pub training_pace: f64,
    stages: [Cost; Stage::ALL.len()],
}

/// What a run's memory depends on besides its file: the machine's
/// threads and its matrix library's scratch (the runtime reads both;
/// neither is known to the file).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Host {
    /// Threads that may compute at once: the pool's workers and the
    /// thread that called them.
    pub threads: usize,
    /// Bytes the matrix library behind the dfdx graph keeps in each thread
    /// that has multiplied (sized from the CPU's L2 cache).
    pub matmul_scratch: f64,
}

impl Work {
    /// Nothing yet but `resident` bytes.
    pub fn new(resident: f64) -> Self {
        Work {
            evaluations: 0.0,
            expected: 0.0,
            memory: resident,
            resident,
            per_thread: 0.0,
            matmul: false,
            training_pace: 1.0,
            stages: [Cost::default(); Stage::ALL.len()],
        }
    }

    /// Peak bytes on `host`: [`Work::memory`] and what each of its threads
    /// keeps for the run.
    pub fn memory_on(&self, host: &Host) -> f64 {
        let matmul = if self.matmul {
            host.matmul_scratch
        } else {
            0.0
        };
        self.memory + host.threads as f64 * (self.per_thread + matmul)
    }

    /// Adds a stage's evaluations (every one expected) and its own memory.
    pub fn add(&mut self, stage: Stage, evaluations: f64, memory: f64) {
        self.add_skipping(stage, evaluations, 1.0, memory);
    }

    /// Adds a stage's evaluations of which `share` is expected (the rest
    /// skipped as empty space), and its own memory.
    pub fn add_skipping(&mut self, stage: Stage, evaluations: f64, share: f64, memory: f64) {
        let c = &mut self.stages[stage as usize];
        c.evaluations += evaluations;
        c.expected += evaluations * share.clamp(0.0, 1.0);
        c.memory = c.memory.max(memory);
        self.evaluations = self.stages.iter().map(|c| c.evaluations).sum();
        self.expected = self.stages.iter().map(|c| c.expected).sum();
        self.memory = self.resident + self.stages.iter().map(|c| c.memory).fold(0.0, f64::max);
    }

    /// Seconds `stage` is expected to take at `rate` calibrated
    /// evaluations a second.
    pub fn seconds(&self, stage: Stage, rate: f64) -> f64 {
        let pace = match stage {
            Stage::Training | Stage::GridRefresh => self.training_pace,
            _ => 1.0,
        };
        self.stage(stage).expected * pace / rate
    }

    /// Seconds the whole statement is expected to take at `rate`.
    pub fn total_seconds(&self, rate: f64) -> f64 {
        Stage::ALL.iter().map(|s| self.seconds(*s, rate)).sum()
    }

    /// Whether some evaluations are expected to be skipped.
    pub fn skips(&self) -> bool {
        self.expected < self.evaluations
    }

    /// The cost of one stage.
    pub fn stage(&self, stage: Stage) -> Cost {
        self.stages[stage as usize]
    }

    /// The stages that cost anything, in the order they run.
    pub fn stages(&self) -> impl Iterator<Item = (Stage, Cost)> + '_ {
        Stage::ALL
            .into_iter()
            .map(|s| (s, self.stage(s)))
            .filter(|(_, c)| c.evaluations > 0.0 || c.memory > 0.0)
    }

    /// The stage with the most expected evaluations.
    pub fn largest(&self) -> Stage {
        Stage::ALL
            .into_iter()
            .max_by(|a, b| self.stage(*a).expected.total_cmp(&self.stage(*b).expected))
            .unwrap_or(Stage::Training)
    }

    /// The evaluations in one phrase: expected, and at most where
    /// skipping makes them differ.
    pub fn describe_evaluations(&self) -> String {
        if self.skips() {
            format!(
                "{} evaluations expected with empty space skipped (at most {})",
                approx(self.expected),
                approx(self.evaluations)
            )
        } else {
            format!("at most {} evaluations", approx(self.evaluations))
        }
    }

    /// The whole statement in one phrase, for messages.
    pub fn describe(&self) -> String {
        format!(
            "{}, about {} of memory",
            self.describe_evaluations(),
            fmt_bytes(self.memory)
        )
    }

    /// Each stage's share of the evaluations and its memory, on one line
    /// (a refused statement's breakdown, which `sdfl plan` cannot print).
    pub fn stage_shares(&self) -> String {
        let total = self.expected.max(1.0);
        let shares: Vec<String> = self
            .stages()
            .map(|(s, c)| {
                format!(
                    "{} {} ({:.0} %, {})",
                    s.name(),
                    approx(c.expected),
                    100.0 * c.expected / total,
                    fmt_bytes(c.memory)
                )
            })
            .collect();
        if self.resident > 0.0 {
            format!(
                "{}; {} held throughout",
                shares.join(", "),
                fmt_bytes(self.resident)
            )
        } else {
            shares.join(", ")
        }
    }

    /// One line per stage, as `sdfl plan` prints them: expected
    /// evaluations, share of the whole, the time they take at `rate`
    /// evaluations a second (where the machine's is known), and the
    /// stage's own memory.
    pub fn stage_lines(&self, rate: Option<f64>) -> Vec<String> {
        let total = self.expected.max(1.0);
        let mut lines: Vec<String> = self
            .stages()
            .map(|(s, c)| {
                let time = rate
                    .map(|r| format!(", {}", fmt_duration(self.seconds(s, r))))
                    .unwrap_or_default();
                let memory = if c.memory > 0.0 {
                    format!(", {} while it runs", fmt_bytes(c.memory))
                } else {
                    String::new()
                };
                format!(
                    "{:<20} {:>8} evaluations ({:>3.0} %){time}{memory}",
                    s.name(),
                    approx(c.expected),
                    100.0 * c.expected / total,
                )
            })
            .collect();
        if self.resident > 0.0 {
            lines.push(format!(
                "{:<20} {} held throughout",
                "resident",
                fmt_bytes(self.resident)
            ));
        }
        lines
    }
}

/// A time estimate to the unit that matters: `about 40 s`, `about
/// 12 min`, `about 3.5 h`, `under a second`.
pub fn fmt_duration(seconds: f64) -> String {
    if !seconds.is_finite() {
        return "an unbounded time".into();
    }
    let about = |t: String| format!("about {t}");
    if seconds < 1.0 {
        "under a second".into()
    } else if seconds < 90.0 {
        about(format!("{seconds:.0} s"))
    } else if seconds < 90.0 * 60.0 {
        about(format!("{:.0} min", seconds / 60.0))
    } else {
        about(format!("{:.1} h", seconds / 3600.0))
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
            // The RGB frame piped to ffmpeg (or the fallback GIF's frame).
            OutputKind::Video { .. } => 7.0,
            OutputKind::Depth => 7.0,
            OutputKind::Normals => 3.0,
            OutputKind::Mask => 4.0,
            // Colour, mask and the RGBA frame being encoded.
            OutputKind::Dataset { .. } => 8.0,
            _ => 3.0,
        };
    }
    b.max(3.0)
}

/// Most vertices a mesh may have: with its normals, quads, triangles and
/// the PLY bytes, about 100 bytes each at the peak (2 GB); a surface that
/// needs more stops with an error.
pub const MAX_MESH_VERTICES: usize = 20_000_000;

/// Cells a side of the grid the true surface is meshed on, where a mesh is
/// measured against the shape sdfl rendered its data from.
pub const TRUE_SURFACE_RESOLUTION: u32 = 192;
/// Query samples on each side of a mesh's Chamfer distance (the runtime's
/// Chamfer distances use these, so the estimate and the work cannot drift
/// apart).
pub const MESH_FIT_POINTS: usize = 50_000;
/// Random points a neural SDF's fit projects onto its surface.
pub const FIT_PROBES: usize = 65_536;
/// Rows a neural SDF's fit evaluates at a time (a pass holds every layer's
/// values and tangents per row).
pub const FIT_CHUNK: usize = 4096;

/// The cost of one surface-nets mesh at `resolution` cells a side, a grid
/// point costing `per_point` evaluations. A surface is assumed to cross a
/// few times the cells of one plane; [`MAX_MESH_VERTICES`] bounds the rest.
fn mesh_cost(resolution: u32, per_point: f64) -> Cost {
    // The grid is padded by two cells a side.
    let n = resolution as f64 + 5.0;
    // Two planes of points and values, two layers of vertex numbers, and
    // vertices, normals and triangles of the surface.
    let surface = (8.0 * n * n).min(MAX_MESH_VERTICES as f64);
    Cost::all(
        n * n * n * per_point,
        2.0 * n * n * 16.0 + 2.0 * n * n * 4.0 + surface * 100.0,
    )
}

/// The grid evaluations and peak memory of the meshes among `outputs`.
fn mesh_work<'a>(outputs: impl Iterator<Item = &'a OutputKind>, per_point: f64) -> Cost {
    let mut w = Cost::default();
    for o in outputs {
        if let OutputKind::Mesh { resolution, .. } = o {
            let c = mesh_cost(*resolution, per_point);
            w.evaluations += c.evaluations;
            w.expected += c.expected;
            w.memory = w.memory.max(c.memory);
        }
    }
    w
}

/// Rays a point cloud casts at most per point it keeps (it stops once it
/// has its points; rays whose opacity is too low keep none).
pub const CLOUD_RAYS_PER_POINT: u64 = 4;
/// Nearest points a point cloud's normal is fitted to (the point's own
/// included).
pub const CLOUD_NORMAL_NEIGHBOURS: usize = 16;
/// Rays a field export marches at a time (colour, depth, opacity and the
/// samples' densities and colours of each).
pub const EXPORT_RAY_CHUNK: usize = 4096;

/// The field exports among `outputs` (density meshes, point clouds, depth
/// with opacity): meshes on their grids and a colour query per vertex;
/// each point cloud's rays; and one more pass over the `views` views of
/// `px` pixels for the depth outputs. A sample costs `per_sample`
/// evaluations, a ray `samples` samples.
fn field_export_work(
    outputs: &[crate::value::Output],
    views: f64,
    px: f64,
    samples: f64,
    per_sample: f64,
) -> (Cost, Cost) {
    let mut meshes = Cost::default();
    let chunk = EXPORT_RAY_CHUNK as f64 * samples * 16.0;
    for o in outputs {
        let c = match o.kind {
            OutputKind::DensityMesh { resolution, .. } => {
                let c = mesh_cost(resolution, per_sample);
                let n = resolution as f64 + 5.0;
                let surface = (8.0 * n * n).min(MAX_MESH_VERTICES as f64);
                Cost::all(
                    c.evaluations + surface * per_sample,
                    c.memory + surface * 16.0,
                )
            }
            OutputKind::PointCloud { points, .. } => {
                let rays = points as f64 * CLOUD_RAYS_PER_POINT as f64;
                // A point, its normal, colour and ray origin, a k-d tree
                // over the points and the normals' neighbour lists.
                let points = points as f64;
                Cost::all(
                    rays * samples * per_sample + points * CLOUD_NORMAL_NEIGHBOURS as f64 * 30.0,
                    points * 80.0 + chunk,
                )
            }
            _ => continue,
        };
        meshes.evaluations += c.evaluations;
        meshes.expected += c.expected;
        meshes.memory = meshes.memory.max(c.memory);
    }
    let depth = if outputs.iter().any(|o| o.kind.depth_export()) {
        Cost::all(
            views * px * samples * per_sample,
            // Colour, depth and opacity per pixel, the PNG's bytes and a chunk.
            px * 24.0 + chunk,
        )
    } else {
        Cost::default()
    };
    (meshes, depth)
}

/// A Chamfer distance between a mesh and a reference: samples on both
/// sides, each measured exactly to the other mesh through a hierarchy of
/// its triangles (the true surface's mesh at [`TRUE_SURFACE_RESOLUTION`]
/// is the larger: about 2π·res² triangles, 80 bytes each with the
/// hierarchy), or to the nearest data point by a k-d tree.
pub(crate) fn chamfer_cost() -> Cost {
    let res = TRUE_SURFACE_RESOLUTION as f64;
    let triangles = 2.0 * std::f64::consts::PI * res * res;
    Cost::all(
        // Each query visits a few dozen boxes and triangles.
        2.0 * MESH_FIT_POINTS as f64 * 40.0,
        triangles * 80.0 + 2.0 * MESH_FIT_POINTS as f64 * 12.0,
    )
}

/// What a `render` of a shape costs (at `size` when `--size` overrides it).
pub fn render_work(j: &RenderJob, size: Option<(u32, u32)>) -> Work {
    render_work_of(j, size, &crate::size::Sizes::default().shape(&j.scene, 0))
}

/// [`render_work`] with the scene's expanded size known (its primitives,
/// its costliest leaf).
pub fn render_work_of(j: &RenderJob, size: Option<(u32, u32)>, scene: &crate::size::Size) -> Work {
    let primitives = scene.primitives;
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
                | OutputKind::Dataset { .. }
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
    let mut w = Work::new(primitives as f64 * BYTES_PER_PRIMITIVE as f64);
    // A step near a user function pays its instructions.
    let leaf = scene.leaf_cost();
    w.add(
        Stage::Views,
        px * j.cameras.len() as f64 * (j.iterations as f64 * rays + spp * effects) * leaf,
        px * bytes_per_pixel(j.outputs.iter().map(|o| o.kind.clone()), false),
    );
    w.add(Stage::Meshes, mesh.evaluations, mesh.memory);
    w
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

/// Most primitives lowered by all statements of a file together (each
/// statement lowers its scene again).
pub const MAX_FILE_PRIMITIVES: u64 = 10 * crate::size::MAX_PRIMITIVES;

/// The diagnostic for a statement that takes a file's totals past the
/// limits.
pub fn refuse_total(evaluations: f64, primitives: u64, span: Span) -> Option<Diag> {
    let (what, help) = if evaluations > max_file_evaluations() {
        (
            format!(
                "{} evaluations expected (at most {})",
                approx(evaluations),
                fmt_num(max_file_evaluations())
            ),
            "lower image sizes, views or steps, or split the file; a file meant to run for hours may raise the limit (a quarter of it for one statement) with SDFL_MAX_EVALUATIONS",
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

/// What a volume `render` costs (at `size` when `--size` overrides it).
pub fn volume_work(j: &VolumeJob, size: Option<(u32, u32)>) -> Work {
    let px = pixels((j.width, j.height), size);
    let model = j.field.model();
    let per_sample = model.volume_sample();
    let mesh = mesh_work(j.outputs.iter().map(|o| &o.kind), per_sample);
    let mut w = Work::new(model.volume_buffers());
    w.add(
        Stage::Views,
        px * j.cameras.len() as f64 * j.sampler.samples as f64 * per_sample,
        px * bytes_per_pixel(j.outputs.iter().map(|o| o.kind.clone()), true),
    );
    w.add(Stage::Meshes, mesh.evaluations, mesh.memory);
    let (meshes, depth) = field_export_work(
        &j.outputs,
        j.cameras.len() as f64,
        px,
        j.sampler.samples as f64,
        model.export_sample(),
    );
    w.add(Stage::Meshes, meshes.evaluations, meshes.memory);
    w.add(Stage::Views, depth.evaluations, depth.memory);
    w
}

/// Bytes a trained model holds per trainable number: its value, gradient
/// and two Adam moments, the step's copies, the last good checkpoint and
/// the checkpoint being written (values and moments, then serialised).
pub const BYTES_PER_WEIGHT: f64 = 64.0;
/// Copies of an occupancy grid's cells (f32 each) a run holds at its
/// peak: the trained model's and the rendering copy's, and its state (two
/// f32 arrays: densities and marks) copied between them, in the last good
/// checkpoint, in the one being made and serialised. Measured: a 384³
/// grid peaked at about nine copies.
const GRID_COPIES: f64 = 10.0;

/// Training steps a run takes (epochs through known data, or iterations).
fn training_steps(j: &TrainJob) -> f64 {
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
        Dataset::Files { .. }
        | Dataset::NerfSynthetic { .. }
        | Dataset::Capture(_)
        | Dataset::Points { .. } => None,
    };
    match (j.epochs, pixels_of_data) {
        (Some(e), Some(px)) => e as f64 * (px / j.rays.max(1) as f64).ceil(),
        // Read files' sizes are known only when read; a 16 384² view each.
        (Some(e), None) => {
            let px = match &*j.data {
                // Cameras unknown until read: as many pixels as a data set
                // may decode to (12 bytes each).
                Dataset::NerfSynthetic { .. } | Dataset::Capture(_) => 2e9 / 12.0,
                _ => j.data.cameras().len() as f64 * 16_384.0 * 16_384.0,
            };
            e as f64 * (px / j.rays.max(1) as f64).ceil()
        }
        (None, _) => j.iterations as f64,
    }
}

/// How many of a data set's `held_out` views each evaluation of `j`
/// scores: `eval_views`, at most all of them.
pub fn scored_views(j: &TrainJob, held_out: usize) -> usize {
    j.eval_views.map_or(held_out, |n| n.min(held_out))
}

/// Which of a data set's `held_out` views each evaluation of `j` scores
/// (positions among the held-out views): [`scored_views`] of them, evenly
/// spaced and the first included, so a comparison still shows view 0.
pub fn scored_view_positions(j: &TrainJob, held_out: usize) -> Vec<usize> {
    let n = scored_views(j, held_out);
    (0..n).map(|i| i * held_out / n).collect()
}

/// Held-out views a `comparison` output shows, the first ones: their
/// renders are all an evaluation keeps (200 views of 800² kept whole were
/// 3 GB, and a PNG 160 000 rows tall).
pub const COMPARISON_VIEWS: usize = 8;

/// The held-out evaluation of a training run with `views` held-out views
/// of `pixels` each: every `eval_every` steps and once at the end; the
/// last one's renders of the first [`COMPARISON_VIEWS`] kept for the
/// comparison image.
pub fn held_out_cost(j: &TrainJob, views: usize, pixels: f64) -> Cost {
    let views = scored_views(j, views);
    // Scored at 1/eval_downscale a side.
    let pixels = pixels / (j.eval_downscale.max(1) as f64).powi(2);
    if views == 0 {
        return Cost::default();
    }
    let steps = training_steps(j);
    let times = if j.eval_every > 0 {
        (steps / j.eval_every as f64).floor()
    } else {
        0.0
    } + 1.0;
    let model = j.model.model();
    let evaluations = times * views as f64 * pixels * model.render_pixel(j.sampler.samples as f64);
    Cost {
        evaluations,
        expected: evaluations * model.expected_share(),
        memory: views.min(COMPARISON_VIEWS) as f64 * pixels * 24.0
            + pixels * 16.0
            + model.render_buffers(),
    }
}

/// What a `train` costs (at `size` when `--size` overrides its images).
pub fn train_work(j: &TrainJob, size: Option<(u32, u32)>) -> Work {
    let samples = j.sampler.samples as f64;
    let iterations = training_steps(j);
    let rays = j.rays as f64;
    let model = j.model.model();
    let mut scalars = 0usize;
    j.model.visit_params(&mut |u| scalars += u.decl.init.len());
    let per_ray = model.train_ray(samples, scalars);
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
        Dataset::Files { .. }
        | Dataset::NerfSynthetic { .. }
        | Dataset::Capture(_)
        | Dataset::Points { .. } => (0.0, 0.0),
    };
    let weights = model.trained_numbers(scalars);
    let cells = model.grid_cells();
    let mut w = Work::new(data_bytes + weights * BYTES_PER_WEIGHT + cells * 4.0 * GRID_COPIES);
    w.add(Stage::Data, data_evals, 0.0);

    // Per-ray buffers of a batch (samples, weights, gradients), and the
    // model's own (a network's activations, the dfdx graph).
    let batch = rays * samples * 64.0 + model.batch_bytes(rays, samples, j.backend);
    w.add_skipping(
        Stage::Training,
        iterations * rays * per_ray,
        model.expected_share(),
        batch,
    );
    w.matmul = model.uses_matmul(j.backend);
    w.training_pace = model.training_pace();
    w.per_thread = model.thread_scratch();
    let refresh = model.grid_refresh(iterations);
    w.add(Stage::GridRefresh, refresh.evaluations, refresh.memory);

    let (test_views, test_pixels) = match &*j.data {
        Dataset::Rendered {
            test,
            width,
            height,
            ..
        } => (test.len(), *width as f64 * *height as f64),
        Dataset::Traced { job, test } => (test.len(), job.width as f64 * job.height as f64),
        // A NeRF-synthetic test split is counted when it is read.
        Dataset::Files { .. }
        | Dataset::NerfSynthetic { .. }
        | Dataset::Capture(_)
        | Dataset::Points { .. } => (0, 0.0),
    };
    let held_out = held_out_cost(j, test_views, test_pixels);
    w.add_skipping(
        Stage::HeldOut,
        held_out.evaluations,
        model.expected_share(),
        held_out.memory,
    );

    for part in train_output_costs(j, size) {
        w.add_skipping(
            part.stage,
            part.cost.evaluations,
            part.share,
            part.cost.memory,
        );
    }
    w
}

/// Most bytes of a phase's renders a training keeps for its depth outputs,
/// so that each view is rendered once for its view outputs and its depth.
pub const SHARED_RENDER_BYTES: usize = 512 << 20;
/// Bytes of one pixel's kept render (colour, depth sum, opacity).
const RAY_END_BYTES: f64 = 20.0;

/// What one of a training's outputs (or a group that shares its work)
/// costs after (or before) training: the parts of the estimate's outputs
/// and meshes stages, which `sdfl plan` times one by one.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputCost {
    /// The files, or what is measured.
    pub what: String,
    /// The stage it is counted in.
    pub stage: Stage,
    /// Its evaluations (every sample counted) and memory.
    pub cost: Cost,
    /// The share of its evaluations expected once empty space is skipped.
    pub share: f64,
}

impl OutputCost {
    /// Seconds it is expected to take at `rate` calibrated evaluations a
    /// second.
    pub fn seconds(&self, rate: f64) -> f64 {
        self.cost.evaluations * self.share / rate
    }
}

/// The outputs of a `train` one by one (at `size` when `--size` overrides
/// its images): each phase's views rendered once for all its view
/// outputs; each geometry GIF sphere-traced with up to 96 steps; each
/// field export marching its own rays (the depth outputs one march for
/// all); each mesh; and the first mesh's and a point fit's measurements.
pub fn train_output_costs(j: &TrainJob, size: Option<(u32, u32)>) -> Vec<OutputCost> {
    use crate::value::Output;
    let model = j.model.model();
    let samples = j.sampler.samples as f64;
    let px = pixels((j.width, j.height), size);
    let views = j.views.len() as f64;
    let per_point = model.geometry_point();
    let names = |os: &[&Output]| {
        let names: Vec<String> = os.iter().map(|o| o.path.display().to_string()).collect();
        names.join(", ")
    };
    let part = |what: String, stage: Stage, cost: Cost, share: f64| OutputCost {
        what,
        stage,
        cost,
        share,
    };
    let mut parts = Vec::new();
    for outputs in [&j.before, &j.after] {
        let rendered: Vec<&Output> = outputs
            .iter()
            .filter(|o| {
                !matches!(
                    o.kind,
                    OutputKind::LossCurve
                        | OutputKind::PsnrCurve
                        | OutputKind::Comparison
                        | OutputKind::Mesh { .. }
                        | OutputKind::GeometryGif { .. }
                ) && !o.kind.field_export()
            })
            .collect();
        let mut depth: Vec<&Output> = outputs.iter().filter(|o| o.kind.depth_export()).collect();
        // A renderer's depth outputs are served by the views' renders
        // while those fit ([`SHARED_RENDER_BYTES`]).
        let shared = model.renders_depth()
            && !rendered.is_empty()
            && px * views * RAY_END_BYTES <= SHARED_RENDER_BYTES as f64;
        // Views rendered once for the outputs they serve.
        let renders = |served: &[&Output], bytes_per_pixel: f64| {
            let cost = Cost::all(
                px * views * model.render_pixel(samples),
                px * bytes_per_pixel + model.render_buffers(),
            );
            part(names(served), Stage::Outputs, cost, model.expected_share())
        };
        if !rendered.is_empty() {
            let mut served = rendered.clone();
            if shared {
                served.append(&mut depth);
            }
            parts.push(renders(&served, 16.0));
        }
        if !depth.is_empty() && model.renders_depth() {
            parts.push(renders(&depth, 24.0));
        } else if !depth.is_empty() {
            let all: Vec<Output> = depth.iter().map(|o| (*o).clone()).collect();
            let (_, cost) = field_export_work(&all, views, px, samples, model.export_sample());
            parts.push(part(names(&depth), Stage::Outputs, cost, 1.0));
        }
        for o in outputs {
            let one = std::slice::from_ref(o);
            let (stage, cost) = match o.kind {
                OutputKind::GeometryGif { .. } => (
                    Stage::Outputs,
                    Cost::all(px * views * 96.0 * per_point, 0.0),
                ),
                OutputKind::DensityMesh { .. } | OutputKind::PointCloud { .. } => {
                    let e = field_export_work(one, views, px, samples, model.export_sample());
                    (Stage::Meshes, e.0)
                }
                OutputKind::Mesh { .. } => (
                    Stage::Meshes,
                    mesh_work(std::iter::once(&o.kind), per_point),
                ),
                _ => continue,
            };
            parts.push(part(o.path.display().to_string(), stage, cost, 1.0));
        }
    }
    // The first mesh after training is measured against the true surface
    // (meshed finely) where sdfl rendered the data from a shape, or
    // against the data's points.
    if j.after
        .iter()
        .any(|o| matches!(o.kind, OutputKind::Mesh { .. }))
    {
        let truth = match &*j.data {
            Dataset::Traced { job, .. } => Some(job.scene.primitive_count() as f64),
            Dataset::Rendered { field, .. } => {
                field.as_sdf().map(|f| f.shape.primitive_count() as f64)
            }
            _ => None,
        };
        let mut cost = chamfer_cost();
        if let Some(primitives) = truth {
            let t = mesh_cost(TRUE_SURFACE_RESOLUTION, primitives);
            cost.evaluations += t.evaluations;
            cost.expected += t.expected;
            cost.memory = cost.memory.max(t.memory);
        }
        parts.push(part(
            "the first mesh's fit".into(),
            Stage::Meshes,
            cost,
            1.0,
        ));
    }
    // A neural SDF's fit: random points projected onto its surface.
    let fit = model.fit_work();
    if fit.evaluations > 0.0 {
        parts.push(part(
            "the fit to the points".into(),
            Stage::Meshes,
            fit,
            1.0,
        ));
    }
    parts
}

/// The diagnostic for a statement whose estimate is beyond the limits.
pub fn refuse(work: Work, span: Span, what: &str) -> Option<Diag> {
    let limit = max_evaluations();
    let (too, fix, over) = if work.expected > limit {
        let largest = work.largest();
        let share = work.stage(largest).expected / work.expected;
        let fix = match largest {
            Stage::GridRefresh => {
                "refresh the occupancy grid less often (`every`) or lower its `resolution`"
                    .to_string()
            }
            Stage::HeldOut => {
                "score fewer held-out views, less often (`eval_every`), or with fewer samples"
                    .to_string()
            }
            Stage::Outputs => "render fewer or smaller output views".to_string(),
            Stage::Meshes => "lower the meshes' `resolution`".to_string(),
            _ => format!("lower the image size, the number of views or the {what}"),
        };
        (
            format!(
                "{} evaluations{} (the limit is {}), {:.0} % of them for {}",
                approx(work.expected),
                if work.skips() {
                    format!(
                        " with empty space skipped, {} counting every sample",
                        approx(work.evaluations)
                    )
                } else {
                    String::new()
                },
                fmt_num(limit),
                100.0 * share,
                largest.name()
            ),
            fix,
            // Past a hundred times the limit (days of work) it is a
            // mistake, not a long run: no override is offered.
            if work.expected <= 100.0 * limit {
                format!(
                    "; a run meant to take hours may raise the limit: {MAX_EVALUATIONS_VAR}={}",
                    fmt_num(raised_limit(work.expected))
                )
            } else {
                String::new()
            },
        )
    } else if work.memory > max_memory() {
        (
            format!(
                "about {} of memory (at most {})",
                fmt_bytes(work.memory),
                fmt_bytes(max_memory())
            ),
            "lower the image size or the number of primitives".to_string(),
            format!(
                "; a machine with the memory may raise the limit: {MAX_MEMORY_VAR}={}",
                fmt_num(raised_limit(work.memory))
            ),
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
            "{fix} (sizes can also be lowered with `--size`){over}; by stage: {}",
            work.stage_shares()
        )),
    )
}

/// A round limit above `expected` (evaluations or bytes), for an
/// override's hint.
pub fn raised_limit(expected: f64) -> f64 {
    let e = 10f64.powf(expected.log10().floor());
    (expected / e).ceil() * e
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
                d.help.as_deref().unwrap_or_default()
            ));
        }
    }
    Ok(())
}
