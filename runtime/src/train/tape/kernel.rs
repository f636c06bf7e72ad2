//! A [`Tape`] run over a batch, a group of rays (about 256 samples) at a
//! time: the tape forward on every sample of the group, 16 lanes per
//! column; the compositing and loss ray by ray, in order, until each ray
//! is spent; the reverse sweep of the compositing (each sample's adjoints
//! of opacity, `ln(1 − opacity)` and colour); then the tape in reverse,
//! summing the adjoints of the uniform registers over the samples that
//! matter. One pass through the operations on parameters alone then gives
//! every parameter's gradient.
//!
//! Rays run in parallel in fixed blocks whose sums are added in order, so
//! a step is bit-identical whatever the thread count (the basis of exact
//! resumption). The loss is the scalar kernel's to the bit (same values,
//! same order); the gradient is the same derivative summed in another
//! order.

use rayon::prelude::*;

use super::{backward, forward, Op, Tape, COLOUR, KEEP, LOG_KEEP, OPACITY};
use sdfl_stdlib::num::Real;

use crate::lanes::F16;
use crate::train::fused::{Batch, LossGrad};
use crate::train::TrainModel;
use crate::volume::march::intervals_into;

/// Samples per chunk (the lanes of [`F16`]).
const W: usize = 16;
/// Rays per parallel block (the unit of the ordered reduction).
const BLOCK: usize = 64;
/// Samples whose seeds (the adjoints of their opacity, `ln(1 − opacity)`
/// and colour) are below this fraction of the ray's largest are left out
/// of the parameters' sums: their share is below f32's resolution of the
/// sum. (The scalar kernel judges by the adjoint of the distance instead;
/// the two agree to about 1e-6 of the gradient.)
const NEGLIGIBLE: f64 = 1e-7;

/// A thread's working storage, reused from group to group and block to
/// block (the uniform registers are filled once; everything else is
/// written before it is read, or masked).
struct Scratch {
    /// Forward values: register `r` of column `j` (chunk `c` of ray `g` of
    /// the group: `j = g·chunks + c`) at `r·cols + j`.
    values: Vec<F16>,
    /// Adjoints, laid out alike.
    adj: Vec<F16>,
    /// Which lanes of each column join the parameters' sums (1, else 0).
    active: Vec<F16>,
    delta: Vec<f32>,
    /// Transmittance before each sample of the ray being composited.
    trans: Vec<f32>,
    /// Each sample's adjoints of (opacity, ln keep, colour r, g, b), a run
    /// of `chunks·16` each.
    seeds: Vec<f32>,
    /// Each sample's adjoint size (whether it joins the sums).
    size: Vec<f64>,
}

impl Scratch {
    /// Room for a group of rays of `batch`, the uniform registers filled.
    fn new(tape: &Tape, batch: &Batch) -> Scratch {
        let chunks = batch.samples.div_ceil(W);
        let cols = group_size(batch.samples) * chunks;
        let zero = F16::splat(0.0);
        let mut s = Scratch {
            values: vec![zero; tape.registers * cols],
            adj: vec![zero; tape.registers * cols],
            active: vec![zero; cols],
            delta: Vec::with_capacity(batch.samples),
            trans: vec![0.0; batch.samples],
            seeds: vec![0.0; 5 * chunks * W],
            size: vec![0.0; batch.samples],
        };
        for u in &tape.uniforms {
            let r = u.register as usize * cols;
            s.values[r..r + cols].fill(F16::splat(u.value));
        }
        s
    }
}

/// The lanes of consecutive columns as one run.
fn flat(x: &[F16]) -> &[f32] {
    // SAFETY: `F16` is `repr(C)` around `[f32; 16]` (64 bytes, its
    // alignment: no padding), so `x` is `16·len` f32 in a row.
    unsafe { std::slice::from_raw_parts(x.as_ptr().cast::<f32>(), x.len() * W) }
}

/// [`flat`] for writing.
fn flat_mut(x: &mut [F16]) -> &mut [f32] {
    // SAFETY: as in `flat`; the borrow is unique.
    unsafe { std::slice::from_raw_parts_mut(x.as_mut_ptr().cast::<f32>(), x.len() * W) }
}

/// The batch's MSE (times `weight`) and its gradient through `tape` (traced
/// from `model` at `values`).
pub fn loss_and_grad(tape: &Tape, model: &TrainModel, batch: &Batch, weight: f64) -> LossGrad {
    let scale = (weight / (3 * batch.rays.len().max(1)) as f64) as f32;
    let blocks: Vec<(f32, Vec<f32>)> = (0..batch.rays.len())
        .collect::<Vec<_>>()
        .par_chunks(BLOCK)
        .map_init(
            || Scratch::new(tape, batch),
            |s, rays| run_block(tape, batch, rays, scale, s),
        )
        .collect();
    let mut loss = 0.0f64;
    let mut adjoints = vec![0.0f64; tape.uniforms.len()];
    for (l, a) in blocks {
        loss += l as f64;
        for (s, x) in adjoints.iter_mut().zip(a) {
            *s += x as f64;
        }
    }
    LossGrad {
        loss,
        grad: tape.parameter_gradient(&adjoints, model.scalars),
    }
}

crate::lanes::widest_simd!(
    /// [`block`] compiled for the widest vectors the CPU has.
    fn run_block(
        tape: &Tape,
        batch: &Batch,
        rays: &[usize],
        scale: f32,
        s: &mut Scratch,
    ) -> (f32, Vec<f32>) = block
);

/// Lanes (of 16 samples) a thread keeps per register, values and adjoints
/// each: the tape's memory is `64 B × registers ×` this, twice.
pub fn lanes_per_register(samples: usize) -> usize {
    group_size(samples) * samples.div_ceil(W)
}

/// Rays evaluated together: about 256 samples a group, so that each
/// instruction runs on 16 columns of lanes.
fn group_size(samples: usize) -> usize {
    (256 / samples.max(1)).clamp(1, BLOCK)
}

/// The loss of `rays` and the adjoints of the tape's uniform registers.
#[inline(always)]
fn block(
    tape: &Tape,
    batch: &Batch,
    rays: &[usize],
    scale: f32,
    s: &mut Scratch,
) -> (f32, Vec<f32>) {
    let cols = s.active.len();
    let group = group_size(batch.samples);
    let zero = F16::splat(0.0);
    let mut loss = 0.0f32;
    // Lane by lane over the block, added across the lanes at its end.
    let mut sums = vec![zero; tape.uniforms.len()];
    for rays in rays.chunks(group) {
        rays_of_group(tape, batch, rays, scale, cols, s, &mut loss, &mut sums);
    }
    let adjoints = sums
        .iter()
        .map(|x| x.0.iter().fold(0.0f32, |a, &b| a + b))
        .collect();
    (loss, adjoints)
}

/// One group of rays: their losses added to `loss` one by one (the scalar
/// kernel's order), their share of the uniform registers' adjoints to
/// `sums`, lane by lane.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn rays_of_group(
    tape: &Tape,
    batch: &Batch,
    rays: &[usize],
    scale: f32,
    cols: usize,
    s: &mut Scratch,
    loss: &mut f32,
    sums: &mut [F16],
) {
    let n = batch.samples;
    let chunks = n.div_ceil(W);
    let used = rays.len() * chunks;
    if n == 0 {
        for &r in rays {
            *loss += ray_loss(batch, r, [0.0; 3], scale).0;
        }
        return;
    }
    // Inputs: the sample points and intervals (lanes past a ray's end
    // repeat its last sample: finite, unused).
    for (g, &r) in rays.iter().enumerate() {
        let t = batch.depths_of(r);
        intervals_into(t, batch.last_interval, &mut s.delta);
        let (o, d) = (batch.rays[r].origin, batch.rays[r].dir);
        for c in 0..chunks {
            let col = g * chunks + c;
            let mut x = [[0.0f32; W]; 4];
            #[allow(
                clippy::needless_range_loop,
                reason = "lane `i` picks the sample and addresses every coordinate's row"
            )]
            for i in 0..W {
                let k = (c * W + i).min(n - 1);
                for a in 0..3 {
                    x[a][i] = o[a] + d[a] * t[k];
                }
                x[3][i] = s.delta[k];
            }
            for (reg, x) in tape.inputs.iter().zip(x) {
                if let Some(reg) = reg {
                    s.values[*reg as usize * cols + col] = F16(x);
                }
            }
        }
    }
    run_forward(tape, &mut s.values, cols, used);
    // Compositing, loss and the reverse sweep of the compositing, ray by
    // ray; the seeds go to the outputs' adjoints.
    let out = tape.outputs.map(|x| x as usize * cols);
    for &r in &tape.adjoint_registers {
        let r = r as usize * cols;
        s.adj[r..r + used].fill(F16::splat(0.0));
    }
    let seeded = [OPACITY, LOG_KEEP, COLOUR, COLOUR + 1, COLOUR + 2];
    let lanes = chunks * W;
    let mut any = false;
    for (g, &r) in rays.iter().enumerate() {
        let at = g * chunks;
        let ray = |reg: usize| &flat(&s.values[reg + at..reg + at + chunks])[..n];
        let (opacity, keep) = (ray(out[OPACITY]), ray(out[KEEP]));
        let c = [ray(out[COLOUR]), ray(out[COLOUR + 1]), ray(out[COLOUR + 2])];
        let trans = &mut s.trans[..n];
        let (mut t, mut colour, mut kept) = (1.0f32, [0.0f32; 3], 0);
        while kept < n && t != 0.0 {
            let k = kept;
            for (j, colour) in colour.iter_mut().enumerate() {
                *colour += t * opacity[k] * c[j][k];
            }
            trans[k] = t;
            t *= keep[k];
            kept += 1;
        }
        let (l, g_colour) = ray_loss(batch, r, colour, scale);
        *loss += l;
        // ∂L/∂ln(1 − o_k) is the suffix sum Σ_{j>k} (g·c_j)·w_j.
        let mut suffix = 0.0f32;
        let mut largest = 0.0f64;
        let (seeds, size) = (&mut s.seeds, &mut s.size[..n]);
        for k in (0..kept).rev() {
            let gc = g_colour[0] * c[0][k] + g_colour[1] * c[1][k] + g_colour[2] * c[2][k];
            let w = trans[k] * opacity[k];
            let seed = [
                trans[k] * gc,
                suffix,
                g_colour[0] * w,
                g_colour[1] * w,
                g_colour[2] * w,
            ];
            // In f64, so that finite adjoints never sum to ∞.
            let sz: f64 = seed.iter().map(|x| x.abs() as f64).sum();
            largest = largest.max(sz);
            size[k] = sz;
            for (j, x) in seed.into_iter().enumerate() {
                seeds[j * lanes + k] = x;
            }
            suffix += gc * w;
        }
        // Samples past the spent point and negligible ones are left out:
        // their seeds are not added and their lanes not summed, so nothing
        // of theirs (not even a NaN) reaches a parameter.
        let threshold = NEGLIGIBLE * largest;
        let active = flat_mut(&mut s.active[at..at + chunks]);
        for (k, a) in active.iter_mut().enumerate() {
            let on = k < kept && largest > 0.0 && size[k.min(n - 1)] > threshold;
            *a = if on { 1.0 } else { 0.0 };
            any |= on;
        }
        for (j, &o) in seeded.iter().enumerate() {
            if tape.output_grads[o] {
                let adj = flat_mut(&mut s.adj[out[o] + at..out[o] + at + chunks]);
                let seeds = &s.seeds[j * lanes..(j + 1) * lanes];
                let first = tape.seed_first[o];
                for ((a, &x), &on) in adj.iter_mut().zip(seeds).zip(active.iter()) {
                    let x = if on > 0.5 { x } else { 0.0 };
                    *a = if first { x } else { *a + x };
                }
            }
        }
    }
    if !any {
        return;
    }
    let half = F16::splat(0.5);
    let keep = |active: F16, x: F16| F16::if_gt(active, half, x, F16::splat(0.0));
    run_reverse(tape, &s.values, &mut s.adj, cols, used);
    for (u, sum) in tape.uniforms.iter().zip(sums.iter_mut()) {
        if u.grad {
            let r = u.register as usize * cols;
            for col in 0..used {
                *sum = *sum + keep(s.active[col], s.adj[r + col]);
            }
        }
    }
}

/// A ray's squared error times `scale` and its gradient in the colour, in
/// the scalar kernel's order.
#[inline(always)]
fn ray_loss(batch: &Batch, r: usize, colour: [f32; 3], scale: f32) -> (f32, [f32; 3]) {
    let target = batch.targets[r];
    let mut loss = 0.0f32;
    let mut g = [0.0f32; 3];
    for i in 0..3 {
        let e = colour[i] - target[i];
        loss += e * e * scale;
        g[i] = 2.0 * e * scale;
    }
    (loss, g)
}

/// Every instruction on the first `used` columns, each arm one operation so
/// that the rule inlined into its loop is that operation's alone. Operands
/// precede their results (registers in the order of the trace), so an
/// instruction reads below its result's register and writes at it.
#[inline(always)]
fn run_forward(tape: &Tape, v: &mut [F16], cols: usize, used: usize) {
    let z = F16::splat(0.0);
    for &(op, dst) in &tape.forward {
        let d = dst as usize * cols;
        let (lo, hi) = v.split_at_mut(d);
        let out = &mut hi[..used];
        let column = |a: u32| &lo[a as usize * cols..a as usize * cols + used];
        macro_rules! unary {
            ($a:expr) => {{
                for (o, &x) in out.iter_mut().zip(column($a)) {
                    *o = forward(op, [x, z, z, z]);
                }
            }};
        }
        macro_rules! binary {
            ($a:expr, $b:expr) => {{
                for ((o, &x), &y) in out.iter_mut().zip(column($a)).zip(column($b)) {
                    *o = forward(op, [x, y, z, z]);
                }
            }};
        }
        match op {
            Op::Input(_) | Op::Const(_) | Op::Param(_) => {}
            Op::Add(a, b) => binary!(a, b),
            Op::Sub(a, b) => binary!(a, b),
            Op::Mul(a, b) => binary!(a, b),
            Op::Div(a, b) => binary!(a, b),
            Op::Max(a, b) => binary!(a, b),
            Op::Min(a, b) => binary!(a, b),
            Op::Neg(a) => unary!(a),
            Op::Sqrt(a) => unary!(a),
            Op::Abs(a) => unary!(a),
            Op::Exp(a) => unary!(a),
            Op::Ln(a) => unary!(a),
            Op::Ln1p(a) => unary!(a),
            Op::ExpM1(a) => unary!(a),
            Op::Sin(a) => unary!(a),
            Op::Cos(a) => unary!(a),
            Op::IfGt(a, b, c, e) => {
                let (a, b, c, e) = (column(a), column(b), column(c), column(e));
                for (j, o) in out.iter_mut().enumerate() {
                    *o = forward(op, [a[j], b[j], c[j], e[j]]);
                }
            }
        }
    }
}

/// The tape in reverse on the first `used` columns, adjoints seeded: each
/// operand that wants it gets its share of the result's adjoint (an operand
/// used twice, `x·x`, gets both, one after the other).
#[inline(always)]
fn run_reverse(tape: &Tape, v: &[F16], adj: &mut [F16], cols: usize, used: usize) {
    let z = F16::splat(0.0);
    assert!(tape.registers * cols <= v.len().min(adj.len()) && used <= cols);
    for &(op, dst, wants, first) in &tape.reverse {
        let d = dst as usize * cols;
        let (lo, hi) = adj.split_at_mut(d);
        let (g, y) = (&hi[..used], &v[d..d + used]);
        macro_rules! back {
            ($($q:literal: $a:expr),*) => {{
                let at = [$($a as usize * cols),*];
                // Operands' registers lie below the result's (`lo`): with
                // this known, the loop's indexing needs no checks.
                $(assert!(at[$q] + used <= lo.len());)*
                for j in 0..used {
                    let mut x = [z; 4];
                    $(x[$q] = v[at[$q] + j];)*
                    let share = backward(op, x, y[j], g[j]);
                    $(
                        if first & (1 << $q) != 0 {
                            lo[at[$q] + j] = share[$q];
                        } else if wants & (1 << $q) != 0 {
                            lo[at[$q] + j] = lo[at[$q] + j] + share[$q];
                        }
                    )*
                }
            }};
        }
        match op {
            Op::Input(_) | Op::Const(_) | Op::Param(_) => {}
            Op::Add(a, b) => back!(0: a, 1: b),
            Op::Sub(a, b) => back!(0: a, 1: b),
            Op::Mul(a, b) => back!(0: a, 1: b),
            Op::Div(a, b) => back!(0: a, 1: b),
            Op::Max(a, b) => back!(0: a, 1: b),
            Op::Min(a, b) => back!(0: a, 1: b),
            Op::Neg(a) => back!(0: a),
            Op::Sqrt(a) => back!(0: a),
            Op::Abs(a) => back!(0: a),
            Op::Exp(a) => back!(0: a),
            Op::Ln(a) => back!(0: a),
            Op::Ln1p(a) => back!(0: a),
            Op::ExpM1(a) => back!(0: a),
            Op::Sin(a) => back!(0: a),
            Op::Cos(a) => back!(0: a),
            Op::IfGt(a, b, c, e) => back!(0: a, 1: b, 2: c, 3: e),
        }
    }
}
