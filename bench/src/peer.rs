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

impl FidgetScene {
    /// Builds `min_i (|p - c_i| - r_i)` and JIT-compiles it; the time taken
    /// is kept as the second number of [`throughput`](Self::throughput).
    pub fn new(spheres: &[(DVec3, f64)]) -> Self {
        assert!(
            !spheres.is_empty(),
            "fidget scene needs at least one sphere"
        );
        let start = Instant::now();
        let mut ctx = Context::new();
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
        let root = min_tree(&mut ctx, &dists);
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

/// Array-of-structs points to x, y and z slices.
fn split(points: &[Vec3A]) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    (
        points.iter().map(|p| p.x).collect(),
        points.iter().map(|p| p.y).collect(),
        points.iter().map(|p| p.z).collect(),
    )
}
