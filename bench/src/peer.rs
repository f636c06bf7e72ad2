//! The peer in the comparison: the same union of spheres evaluated by the
//! [fidget](https://github.com/mkeeter/fidget) crate's JIT (fidget 0.5).
//!
//! The expression is `min_i (sqrt((x-cx)^2 + (y-cy)^2 + (z-cz)^2) - r_i)`,
//! built directly in a `fidget::Context` with the `min`s as a balanced binary
//! tree (depth ⌈log2 N⌉ rather than a chain of N), compiled once with
//! `JitShape::new` + `float_slice_tape`, and evaluated with fidget's bulk
//! `f32` slice evaluator, which takes structure-of-arrays x/y/z slices.
//!
//! Fairness notes, matching how sdfl is timed in `main.rs`:
//! - one thread, the same points, best of 3 runs;
//! - building the expression and JIT-compiling it happen once in
//!   [`FidgetScene::new`] and are excluded from throughput (they are reported
//!   as the second number of [`FidgetScene::throughput`]);
//! - the array-of-structs `Vec3A` points are split into x/y/z slices before
//!   timing (that is fidget's native input layout, as `&[Vec3A]` is sdfl's);
//!   the copy `ShapeBulkEval::eval` makes of its inputs is inside the timing,
//!   since it is part of fidget's public bulk API;
//! - every output value is summed, so the evaluation cannot be dropped.

use std::time::Instant;

use fidget::context::{Context, Node};
use fidget::jit::{JitBulkFn, JitShape};
use fidget::shape::{EzShape, ShapeTape};
use glam::{DVec3, Vec3A};
use sdfl_runtime::Lowered;

/// Points per call of the bulk evaluator. fidget's JIT slice evaluator has
/// no maximum length; chunking only keeps its input/output scratch buffers
/// cache-resident (4096 points = 64 KiB across x, y, z and the output).
const CHUNK: usize = 4096;

/// A union of spheres compiled by fidget's JIT for bulk `f32` evaluation.
pub struct FidgetScene {
    tape: ShapeTape<JitBulkFn<f32>>,
    /// Seconds spent building the expression and JIT-compiling it.
    build_secs: f64,
}

/// Balanced binary tree of `min`s over `nodes` (which must not be empty).
fn min_tree(ctx: &mut Context, nodes: &[Node]) -> Node {
    match nodes {
        [one] => *one,
        _ => {
            let (a, b) = nodes.split_at(nodes.len() / 2);
            let (a, b) = (min_tree(ctx, a), min_tree(ctx, b));
            ctx.min(a, b).expect("min of valid nodes")
        }
    }
}

/// `min_i (|p - c_i| - r_i)` in `ctx`.
fn sphere_union(ctx: &mut Context, spheres: &[(DVec3, f64)]) -> Node {
    let (x, y, z) = (ctx.x(), ctx.y(), ctx.z());
    let dists: Vec<Node> = spheres
        .iter()
        .map(|(c, r)| {
            let mut sq = |axis: Node, c: f64| {
                let d = ctx.sub(axis, c as f32).unwrap();
                ctx.square(d).unwrap()
            };
            let (dx, dy, dz) = (sq(x, c.x), sq(y, c.y), sq(z, c.z));
            let sum = ctx.add(dx, dy).unwrap();
            let sum = ctx.add(sum, dz).unwrap();
            let len = ctx.sqrt(sum).unwrap();
            ctx.sub(len, *r as f32).unwrap()
        })
        .collect();
    min_tree(ctx, &dists)
}

impl FidgetScene {
    /// Builds `min_i (|p - c_i| - r_i)` and JIT-compiles it; the time taken
    /// is kept as the second number of [`throughput`](Self::throughput).
    pub fn new(spheres: &[(DVec3, f64)]) -> Self {
        assert!(
            !spheres.is_empty(),
            "fidget scene needs at least one sphere"
        );
        Self::build(|ctx| sphere_union(ctx, spheres))
    }

    /// The expression `expr` builds, JIT-compiled (timed as in [`Self::new`]).
    pub fn build(expr: impl FnOnce(&mut Context) -> Node) -> Self {
        let start = Instant::now();
        let mut ctx = Context::new();
        let root = expr(&mut ctx);
        let shape = JitShape::new(&ctx, root).expect("fidget shape");
        let tape = shape.ez_float_slice_tape();
        FidgetScene {
            tape,
            build_secs: start.elapsed().as_secs_f64(),
        }
    }

    /// Evaluates `points` (as x/y/z slices) in chunks, calling `f` with each
    /// chunk's starting index and output values.
    fn eval_soa(&self, xs: &[f32], ys: &[f32], zs: &[f32], mut f: impl FnMut(usize, &[f32])) {
        let mut eval = JitShape::new_float_slice_eval();
        for start in (0..xs.len()).step_by(CHUNK) {
            let end = (start + CHUNK).min(xs.len());
            let out = eval
                .eval(
                    &self.tape,
                    &xs[start..end],
                    &ys[start..end],
                    &zs[start..end],
                )
                .expect("fidget bulk eval");
            f(start, out);
        }
    }

    /// Asserts fidget's values match sdfl's `lowered.dist(p)` (f32) within
    /// 1e-4, relative to the magnitude for values beyond 1.
    pub fn check_against(&self, lowered: &Lowered, points: &[Vec3A]) {
        let (xs, ys, zs) = split(points);
        let mut checked = 0;
        self.eval_soa(&xs, &ys, &zs, |start, out| {
            assert_eq!(out.len(), (xs.len() - start).min(CHUNK));
            for (i, &v) in out.iter().enumerate() {
                let p = points[start + i];
                let d = lowered.dist(p);
                assert!(
                    (v - d).abs() <= 1e-4 * d.abs().max(1.0),
                    "fidget {v} != sdfl {d} at {p}"
                );
                checked += 1;
            }
        });
        assert_eq!(checked, points.len());
    }

    /// Single-threaded throughput of fidget's JIT bulk `f32` evaluator, in
    /// points per second (best of 3 runs over `points`, or over the first
    /// 20 000 of them when `n >= 1000`, as main.rs does for sdfl's naive
    /// evaluator), and the seconds `new` took to build and JIT-compile the
    /// expression (excluded from the throughput).
    pub fn throughput(&self, points: &[Vec3A], n: usize) -> (f64, f64) {
        let points = if n >= 1000 {
            &points[..points.len().min(20_000)]
        } else {
            points
        };
        let (xs, ys, zs) = split(points);
        let mut best = f64::INFINITY;
        let mut checksum = 0.0f64;
        for _ in 0..3 {
            let mut sum = 0.0f32;
            let t = Instant::now();
            self.eval_soa(&xs, &ys, &zs, |_, out| sum += out.iter().sum::<f32>());
            best = best.min(t.elapsed().as_secs_f64());
            checksum += std::hint::black_box(sum) as f64;
        }
        assert!(checksum.is_finite(), "fidget produced non-finite distances");
        (points.len() as f64 / best, self.build_secs)
    }
}

/// IQ's torus about Z, `|(|p.xy| - major, p.z)| - minor`, in `ctx`.
pub fn torus(ctx: &mut Context, major: f64, minor: f64) -> Node {
    let (x, y, z) = (ctx.x(), ctx.y(), ctx.z());
    let (x2, y2, z2) = (
        ctx.square(x).unwrap(),
        ctx.square(y).unwrap(),
        ctx.square(z).unwrap(),
    );
    let xy = ctx.add(x2, y2).unwrap();
    let ring = ctx.sqrt(xy).unwrap();
    let across = ctx.sub(ring, major as f32).unwrap();
    let a2 = ctx.square(across).unwrap();
    let sum = ctx.add(a2, z2).unwrap();
    let len = ctx.sqrt(sum).unwrap();
    ctx.sub(len, minor as f32).unwrap()
}

/// Array-of-structs points to x, y and z slices.
fn split(points: &[Vec3A]) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    (
        points.iter().map(|p| p.x).collect(),
        points.iter().map(|p| p.y).collect(),
        points.iter().map(|p| p.z).collect(),
    )
}

/// fidget's own renderer on the same union of spheres: its voxel raster
/// (`fidget::raster::voxel`, interval pruning over tiles of 64, 16, 8
/// voxels, then the JIT's bulk and gradient evaluators), depth and normals
/// of a `size`² image × `size` depth voxels, on rayon's global pool (the
/// threads sdfl's frames use).
///
/// The voxel cube is mapped onto the frustum of sdfl's bench camera (eye
/// at z = −3.5 looking along +z, focal 1, the image's left edge towards
/// +x) between the planes z = −1.5 and z = 1.5, which hold the scene: a
/// projective `world_to_model`, as fidget's own perspective views use, so
/// both renderers see the same scene in the same pixels.
pub struct FidgetFrame {
    shape: JitShape,
    cfg: fidget::raster::voxel::RenderConfig,
}

impl FidgetFrame {
    pub fn new(spheres: &[(DVec3, f64)], size: u32) -> Self {
        Self::build(|ctx| sphere_union(ctx, spheres), size)
    }

    /// fidget's renderer on the expression `expr` builds.
    pub fn build(expr: impl FnOnce(&mut Context) -> Node, size: u32) -> Self {
        let mut ctx = Context::new();
        let root = expr(&mut ctx);
        let shape = JitShape::new(&ctx, root).expect("fidget shape");
        // Screen NDC (x, y, z) in [-1, 1]³ (z = 1 nearest) → model. The
        // distance along z from the eye is 1/w with w = P + Q·z: 2 at the
        // near plane (z = 1), 5 at the far one (z = -1).
        let (p, q) = (0.35f32, 0.15f32);
        #[rustfmt::skip]
        let m = nalgebra::Matrix4::new(
            -1.0, 0.0, 0.0, 0.0,
            0.0, 1.0, 0.0, 0.0,
            0.0, 0.0, -3.5 * q, 1.0 - 3.5 * p,
            0.0, 0.0, q, p,
        );
        let cfg = fidget::raster::voxel::RenderConfig {
            image_size: fidget::render::VoxelSize::new(size, size, size),
            world_to_model: m,
        };
        FidgetFrame { shape, cfg }
    }

    /// Renders once: the seconds taken and, per pixel (row-major, top
    /// first), the distance along the ray to the hit (`None`: a miss),
    /// converted from the voxel depth for comparing hit masks with sdfl.
    pub fn render(&self) -> (f64, Vec<Option<f32>>) {
        let shape = fidget::shape::BoundShape::try_from(self.shape.clone()).expect("no vars");
        let t = Instant::now();
        let image = self.cfg.run(shape);
        let secs = t.elapsed().as_secs_f64();
        let n = self.cfg.image_size.width() as usize;
        let d = self.cfg.image_size.depth() as f32;
        let (p, q) = (0.35f32, 0.15f32);
        let hits = image
            .as_slice()
            .iter()
            .enumerate()
            .map(|(k, px)| {
                (px.depth > 0).then(|| {
                    // Voxel index → screen z → distance along z → along the ray.
                    let z = (px.depth as f32 - 0.5) * 2.0 / d - 1.0;
                    let along_z = 1.0 / (p + q * z);
                    let (i, j) = (k % n, k / n);
                    let ndc = |i: usize| (i as f32 + 0.5) * 2.0 / n as f32 - 1.0;
                    along_z * (ndc(i).powi(2) + ndc(j).powi(2) + 1.0).sqrt()
                })
            })
            .collect();
        (secs, hits)
    }
}
