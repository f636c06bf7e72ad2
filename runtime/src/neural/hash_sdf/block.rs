//! The hash SDF over a chunk of up to [`CHUNK`] points at once: every
//! quantity feature-major, a row of [`CHUNK`] lanes (one a point), so each
//! layer's sums run across the points in vector lanes.
//!
//! - **Forward** (`f`, or `f` and its exact `∇f`): each point's sums in
//!   [`HashSdf::mlp_forward`]'s order and the same softplus kernel, so a
//!   point gets the bits it gets alone ([`HashSdf::value`],
//!   [`HashSdf::value_grad`]). The scratch has the point-at-a-time
//!   layout with every float widened to a row.
//! - **Backward** (the exact form's reverse pass): the adjoints per point
//!   as [`HashSdf::mlp_backward`] forms them; the weights' gradient and the
//!   inputs' adjoints as matrix products over the chunk (fp32's AVX-512
//!   register tiles, or lane loops on other CPUs), a fixed order, so the
//!   result does not depend on the thread count.
//!
//! Lanes past the chunk's points hold zero features and zero adjoints, so
//! they add nothing and stay finite.

use super::{HashSdf, CHUNK};
use crate::neural::fp32::{self, Strided};
use crate::neural::mlp::softplus_layer;

/// Lanes of a partial sum across points (four AVX-512 registers).
const LANES: usize = 64;
// A chunk is whole lane groups: the last group's `[..LANES]` must fit.
const _: () = assert!(CHUNK.is_multiple_of(LANES));

/// One chunk's forward (features, each layer's values, tangents and
/// slopes, the output's value and tangents) and the backward's two adjoint
/// buffers, feature-major.
#[derive(Debug, Default)]
pub struct BlockScratch {
    /// The forward's values, a row each.
    pub forward: Vec<f32>,
    /// The backward's two adjoint buffers.
    pub adjoint: Vec<f32>,
    /// A layer's input point-major (the weight gradient's product reads
    /// it so), `(1 + NT) × CHUNK × max(E, width)`.
    pub transposed: Vec<f32>,
}

impl BlockScratch {
    /// The forward's buffer alone, for `net` with `NT` tangents (a pass
    /// with no backward: normals; distances keep theirs per thread).
    pub(super) fn forward_only<const NT: usize>(net: &HashSdf) -> Self {
        BlockScratch {
            forward: vec![0.0; net.block_len::<NT>()],
            ..Default::default()
        }
    }

    /// Grows to `net`'s size with `NT` tangents, the backward's buffers
    /// too (no allocation once grown).
    pub fn fit<const NT: usize>(&mut self, net: &HashSdf) {
        let forward = net.block_len::<NT>();
        if self.forward.len() < forward {
            self.forward.resize(forward, 0.0);
        }
        let adjoint = 2 * (1 + NT) * net.grid.output_dim().max(net.width) * CHUNK;
        if self.adjoint.len() < adjoint {
            self.adjoint.resize(adjoint, 0.0);
        }
        if NT > 0 && self.transposed.len() < adjoint / 2 {
            self.transposed.resize(adjoint / 2, 0.0);
        }
    }

    /// Bytes of a scratch of `net` with `NT` tangents: what the plan's
    /// per-thread estimate (`NeuralSdf::thread_scratch`) must equal.
    pub fn bytes<const NT: usize>(net: &HashSdf) -> u64 {
        let adjoint = 2 * (1 + NT) * net.grid.output_dim().max(net.width) * CHUNK;
        let transposed = if NT > 0 { adjoint / 2 } else { 0 };
        4 * (net.block_len::<NT>() + adjoint + transposed) as u64
    }
}

/// The sum of `acc`'s lanes, folded pairwise (a fixed order).
#[inline(always)]
fn fold(mut acc: [f32; LANES]) -> f32 {
    let mut len = LANES;
    while len > 1 {
        len /= 2;
        for q in 0..len {
            acc[q] += acc[q + len];
        }
    }
    acc[0]
}

/// `row(k)` for the rows `k` of a layer's input, weighted by `weight(k)`
/// and summed on `start`, at lanes `from..from + LANES`, in `k`'s order.
#[inline(always)]
fn weighted_rows(
    start: f32,
    count: usize,
    weight: impl Fn(usize) -> f32,
    rows: &[f32],
    first: usize,
    from: usize,
) -> [f32; LANES] {
    let mut acc = [start; LANES];
    for k in 0..count {
        let wk = weight(k);
        let x = &rows[(first + k) * CHUNK + from..][..LANES];
        for q in 0..LANES {
            acc[q] += wk * x[q];
        }
    }
    acc
}

impl HashSdf {
    /// Floats of a chunk's forward scratch: the point-at-a-time layout's,
    /// a row each, and the output's value and tangents.
    pub(super) fn block_len<const NT: usize>(&self) -> usize {
        (self.tangent_out::<NT>() + 1 + NT) * CHUNK
    }

    /// The features (and their derivatives) of `pts` into `x`'s rows in
    /// [`Self::encode`]'s order: level `l`'s feature `k` in row `l·f + k`,
    /// its derivative by axis `a` in row `(1 + a)·E + l·f + k`. A level at
    /// a time: first every point's corners, then the tables' reads, which
    /// then do not wait on one another.
    #[inline(always)]
    fn encode_block<const NT: usize>(
        &self,
        params: &[f32],
        pts: &[[f32; 3]],
        active: usize,
        x: &mut [f32],
    ) {
        let f = self.grid.config().features as usize;
        let dim = self.grid.output_dim();
        let n = pts.len();
        x[..(1 + NT) * dim * CHUNK].fill(0.0);
        let mut rows = [[0u32; 8]; CHUNK];
        let mut w = [[0f32; 8]; CHUNK];
        let mut dw = [[[0f32; 3]; 8]; CHUNK];
        let levels = self.offsets.len() - 1;
        for (l, &off) in self.offsets[..levels].iter().enumerate().take(active) {
            let table = &params[off..self.offsets[l + 1]];
            for (i, &p) in pts.iter().enumerate() {
                if NT == 0 {
                    (rows[i], w[i]) = self.grid.corners_at(l, p);
                } else {
                    (rows[i], w[i], dw[i]) = self.grid.corners_dx(l, p);
                }
            }
            // Per point and feature the corners in order from 0, as
            // `encode` sums them.
            for i in 0..n {
                for k in 0..f {
                    let (mut v, mut t) = (0f32, [0f32; 3]);
                    for c in 0..8 {
                        let row = table[rows[i][c] as usize * f + k];
                        v += w[i][c] * row;
                        for a in 0..NT {
                            t[a] += dw[i][c][a] * row;
                        }
                    }
                    x[(l * f + k) * CHUNK + i] = v;
                    for a in 0..NT {
                        x[((1 + a) * dim + l * f + k) * CHUNK + i] = t[a];
                    }
                }
            }
        }
    }

    /// `f` (and with `NT = 3` the exact `∇f`) at `pts` into `f` and `g`
    /// (`g` empty when `NT = 0`), leaving the forward in `buf` for
    /// [`Self::backward_block`]: [`Self::value`]'s and
    /// [`Self::value_grad`]'s bits.
    #[inline(always)]
    pub fn forward_block<const NT: usize>(
        &self,
        params: &[f32],
        pts: &[[f32; 3]],
        active: usize,
        buf: &mut [f32],
        f: &mut [f32],
        g: &mut [[f32; 3]],
    ) {
        let n = pts.len();
        debug_assert!(n <= CHUNK && f.len() == n && g.len() == if NT == 0 { 0 } else { n });
        self.encode_block::<NT>(params, pts, active, buf);
        let (w, beta) = (self.width, self.beta);
        for (i, &(input, off)) in self.hidden.iter().enumerate() {
            let (lo, block) = buf.split_at_mut(self.input_at::<NT>(i + 1) * CHUNK);
            let x = &lo[self.input_at::<NT>(i) * CHUNK..][..(1 + NT) * input * CHUNK];
            let weights = &params[off..][..input * w];
            let bias = &params[off + input * w..][..w];
            let (h, rest) = block.split_at_mut((1 + NT) * w * CHUNK);
            let (zt, rest) = rest.split_at_mut(NT * w * CHUNK);
            let s = &mut rest[..w * CHUNK];
            for j in 0..w {
                let row = &weights[j * input..][..input];
                for from in (0..CHUNK).step_by(LANES) {
                    let z = weighted_rows(bias[j], input, |k| row[k], x, 0, from);
                    h[j * CHUNK + from..][..LANES].copy_from_slice(&z);
                    for a in 0..NT {
                        let t = weighted_rows(0.0, input, |k| row[k], x, (1 + a) * input, from);
                        zt[(a * w + j) * CHUNK + from..][..LANES].copy_from_slice(&t);
                    }
                }
            }
            if NT == 0 {
                softplus_layer(&mut h[..w * CHUNK], None, beta);
            } else {
                let (h, ht) = h.split_at_mut(w * CHUNK);
                softplus_layer(h, Some(s), beta);
                for (ht, zt) in ht
                    .chunks_exact_mut(w * CHUNK)
                    .zip(zt.chunks_exact(w * CHUNK))
                {
                    for ((ht, &zt), &s) in ht.iter_mut().zip(zt).zip(&*s) {
                        *ht = s * zt;
                    }
                }
            }
        }
        let at = self.input_at::<NT>(self.hidden.len());
        let out_at = self.tangent_out::<NT>() * CHUNK;
        let (h, out) = buf.split_at_mut(out_at);
        let wo = &params[self.output..][..w];
        let b = params[self.output + w];
        for from in (0..CHUNK).step_by(LANES) {
            let v = weighted_rows(b, w, |j| wo[j], h, at, from);
            out[from..][..LANES].copy_from_slice(&v);
            for a in 0..NT {
                let t = weighted_rows(0.0, w, |j| wo[j], h, at + (1 + a) * w, from);
                out[(1 + a) * CHUNK + from..][..LANES].copy_from_slice(&t);
            }
        }
        for (i, (f, &p)) in f.iter_mut().zip(pts).enumerate() {
            let (d, sg) = self.sphere(p);
            *f = out[i] + d;
            if NT > 0 {
                g[i] = std::array::from_fn(|a| out[(1 + a) * CHUNK + i] + sg[a]);
            }
        }
    }

    /// The reverse pass of [`Self::forward_block`] with the exact `∇f`
    /// (its forward in `buf`), given `∂L/∂f` (`d_f`) and `∂L/∂∇f` (`d_g`,
    /// three a point) at its `n` points: *adds* the MLP's gradient to
    /// `d_mlp` (from the first MLP param) and writes each point's feature
    /// adjoints (`4 × E`, point-major) into `d_feat`. The weights' products
    /// run as [`fp32::matmul`]'s register tiles when `tiles` (AVX-512 only),
    /// else as lane loops.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub fn backward_block(
        &self,
        params: &[f32],
        buf: &[f32],
        d_f: &[f32],
        d_g: &[f32],
        adj: &mut [f32],
        transposed: &mut [f32],
        d_mlp: &mut [f32],
        d_feat: &mut [f32],
        tiles: bool,
    ) {
        const NT: usize = 3;
        let n = d_f.len();
        let (w, e, beta) = (self.width, self.grid.output_dim(), self.beta);
        let tables = self.table_params();
        let rows = (1 + NT) * e.max(w);
        let (cur, prev) = adj[..2 * rows * CHUNK].split_at_mut(rows * CHUNK);
        let (mut cur, mut prev) = (cur, prev);
        // ∂L/∂out and its tangents' adjoints, zero past the points.
        let mut d_out = [[0f32; CHUNK]; 1 + NT];
        for i in 0..n {
            d_out[0][i] = d_f[i];
            for a in 0..NT {
                d_out[1 + a][i] = d_g[3 * i + a];
            }
        }
        // Output layer.
        let last = self.input_at::<NT>(self.hidden.len()) * CHUNK;
        let h = &buf[last..][..(1 + NT) * w * CHUNK];
        let wo = &params[self.output..][..w];
        let dwo = &mut d_mlp[self.output - tables..][..w + 1];
        for j in 0..w {
            let mut acc = [0f32; LANES];
            for from in (0..CHUNK).step_by(LANES) {
                for (r, d) in d_out.iter().enumerate() {
                    let h = &h[(r * w + j) * CHUNK + from..][..LANES];
                    for q in 0..LANES {
                        acc[q] += d[from + q] * h[q];
                    }
                }
            }
            dwo[j] += fold(acc);
            for (r, d) in d_out.iter().enumerate() {
                for (c, &d) in cur[(r * w + j) * CHUNK..][..CHUNK].iter_mut().zip(d) {
                    *c = d * wo[j];
                }
            }
        }
        let mut acc = [0f32; LANES];
        for from in (0..CHUNK).step_by(LANES) {
            for q in 0..LANES {
                acc[q] += d_out[0][from + q];
            }
        }
        dwo[w] += fold(acc);
        for (i, &(input, off)) in self.hidden.iter().enumerate().rev() {
            let x = &buf[self.input_at::<NT>(i) * CHUNK..][..(1 + NT) * input * CHUNK];
            let block = &buf[self.input_at::<NT>(i + 1) * CHUNK..];
            let zt = &block[(1 + NT) * w * CHUNK..][..NT * w * CHUNK];
            let s = &block[(1 + 2 * NT) * w * CHUNK..][..w * CHUNK];
            // The adjoints of h (value and tangents) in `cur` become those
            // of z and its tangents, in place.
            {
                let (zbar, ztbar) = cur[..(1 + NT) * w * CHUNK].split_at_mut(w * CHUNK);
                for (q, (zb, &sl)) in zbar.iter_mut().zip(s).enumerate() {
                    let curv = beta * sl * (1.0 - sl);
                    let mut v = *zb * sl;
                    for a in 0..NT {
                        let hb = &mut ztbar[a * w * CHUNK + q];
                        v += *hb * zt[a * w * CHUNK + q] * curv;
                        *hb *= sl;
                    }
                    *zb = v;
                }
            }
            let weights = &params[off..][..input * w];
            let dw = &mut d_mlp[off - tables..][..input * w + w];
            let (dweights, dbias) = dw.split_at_mut(input * w);
            for j in 0..w {
                let mut acc = [0f32; LANES];
                for from in (0..CHUNK).step_by(LANES) {
                    let zb = &cur[j * CHUNK + from..][..LANES];
                    for q in 0..LANES {
                        acc[q] += zb[q];
                    }
                }
                dbias[j] += fold(acc);
            }
            if tiles {
                // dW += Σ_r Z̄_r · X_rᵀ (w × CHUNK by CHUNK × input), the
                // input point-major first.
                let xt = &mut transposed[..(1 + NT) * CHUNK * input];
                for (r, xt) in xt.chunks_exact_mut(CHUNK * input).enumerate() {
                    for k in 0..input {
                        let row = &x[(r * input + k) * CHUNK..][..CHUNK];
                        for (i, &v) in row.iter().enumerate() {
                            xt[i * input + k] = v;
                        }
                    }
                }
                for r in 0..1 + NT {
                    let zbar = Strided::row_major(&cur[r * w * CHUNK..][..w * CHUNK], CHUNK);
                    let xt = &xt[r * CHUNK * input..][..CHUNK * input];
                    fp32::matmul(w, CHUNK, input, zbar, xt, input, dweights, input, true);
                }
                // X̄_r = Wᵀ · Z̄_r (input × w by w × CHUNK).
                for r in 0..1 + NT {
                    let zbar = &cur[r * w * CHUNK..][..w * CHUNK];
                    let xbar = &mut prev[r * input * CHUNK..][..input * CHUNK];
                    let wt = Strided::transposed(weights, input);
                    fp32::matmul(input, w, CHUNK, wt, zbar, CHUNK, xbar, CHUNK, false);
                }
            } else {
                for j in 0..w {
                    for k in 0..input {
                        let mut acc = [0f32; LANES];
                        for from in (0..CHUNK).step_by(LANES) {
                            for r in 0..1 + NT {
                                let zb = &cur[(r * w + j) * CHUNK + from..][..LANES];
                                let xk = &x[(r * input + k) * CHUNK + from..][..LANES];
                                for q in 0..LANES {
                                    acc[q] += zb[q] * xk[q];
                                }
                            }
                        }
                        dweights[j * input + k] += fold(acc);
                    }
                }
                // The input's adjoints: Wᵀ·z̄ (and for each tangent).
                for r in 0..1 + NT {
                    for k in 0..input {
                        for from in (0..CHUNK).step_by(LANES) {
                            let v =
                                weighted_rows(0.0, w, |j| weights[j * input + k], cur, r * w, from);
                            prev[(r * input + k) * CHUNK + from..][..LANES].copy_from_slice(&v);
                        }
                    }
                }
            }
            std::mem::swap(&mut cur, &mut prev);
        }
        let feat = (1 + NT) * e;
        for (i, d) in d_feat[..n * feat].chunks_exact_mut(feat).enumerate() {
            for (r, d) in d.iter_mut().enumerate() {
                *d = cur[r * CHUNK + i];
            }
        }
    }
}

crate::lanes::widest_simd!(
    /// [`HashSdf::forward_block`] of `f` alone, compiled for the widest
    /// vectors this CPU has (the same operations, so the same bits).
    pub(super) fn values_block(net: &HashSdf, params: &[f32], pts: &[[f32; 3]], active: usize, buf: &mut [f32], f: &mut [f32]) -> () = values_lanes
);

#[inline(always)]
fn values_lanes(
    net: &HashSdf,
    params: &[f32],
    pts: &[[f32; 3]],
    active: usize,
    buf: &mut [f32],
    f: &mut [f32],
) {
    net.forward_block::<0>(params, pts, active, buf, f, &mut []);
}

crate::lanes::widest_simd!(
    /// [`HashSdf::forward_block`] of `f` and the exact `∇f`, compiled for
    /// the widest vectors this CPU has.
    pub(super) fn value_grads_block(net: &HashSdf, params: &[f32], pts: &[[f32; 3]], active: usize, buf: &mut [f32], f: &mut [f32], g: &mut [[f32; 3]]) -> () = value_grads_lanes
);

#[inline(always)]
fn value_grads_lanes(
    net: &HashSdf,
    params: &[f32],
    pts: &[[f32; 3]],
    active: usize,
    buf: &mut [f32],
    f: &mut [f32],
    g: &mut [[f32; 3]],
) {
    net.forward_block::<3>(params, pts, active, buf, f, g);
}

crate::lanes::widest_simd!(
    /// [`HashSdf::backward_block`] on the forward and adjoint buffers of
    /// `scratch`, compiled for the widest vectors this CPU has.
    pub(super) fn grads_backward_block(net: &HashSdf, params: &[f32], scratch: &mut BlockScratch, d_f: &[f32], d_g: &[f32], d_mlp: &mut [f32], d_feat: &mut [f32]) -> () = grads_backward_lanes
);

#[inline(always)]
fn grads_backward_lanes(
    net: &HashSdf,
    params: &[f32],
    scratch: &mut BlockScratch,
    d_f: &[f32],
    d_g: &[f32],
    d_mlp: &mut [f32],
    d_feat: &mut [f32],
) {
    let BlockScratch {
        forward,
        adjoint,
        transposed,
    } = scratch;
    // The products as fp32's register tiles where the CPU has them
    // (AVX-512), else lane loops; either sums in a fixed order.
    let tiles = fp32::available();
    net.backward_block(
        params, forward, d_f, d_g, adjoint, transposed, d_mlp, d_feat, tiles,
    );
}
