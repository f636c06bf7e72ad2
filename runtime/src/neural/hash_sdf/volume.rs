//! The hash SDF as the geometry of a volume trained from images (NeuS2,
//! Neuralangelo): the objective asks for `f` and `∇f` at every sample,
//! composites, and hands back `∂L/∂f` and `∂L/∂∇f` per sample; this adds
//! `∂L/∂params`.
//!
//! Memory stays flat in the number of samples: the forward keeps only `f`
//! and `∇f` (four floats a sample); the backward recomputes each point's
//! forward (the layers' values and tangents) in [`BLOCK`]s of points,
//! parallel over [`CHUNK`]s, and folds each block into the gradient before
//! the next: the MLP's share as chunk partials in chunk order, the tables'
//! per level in point order. The sums' order never depends on the thread
//! count, so the gradient is bit-identical at any.
//!
//! The exact form runs a chunk at a time through the blocked kernels
//! (`block.rs`: each layer's sums across the chunk's points in vector
//! lanes), its scratch one per thread; the differences' form a point at a
//! time.
//!
//! `∇f` is exact ([`Eikonal::Exact`]: forward-mode tangents, the backward
//! second order) or by central differences ([`Eikonal::FiniteDifference`]:
//! seven values a point, the backward exact for that expression); either
//! way it is the `∇f` the colour network sees as the normal.

use std::sync::Mutex;

use rayon::prelude::*;

use super::block::{grads_backward_block, value_grads_block, BlockScratch};
use super::{grow, ChunkWork, Eikonal, HashSdf, CHUNK, FD_PROBES};
use crate::neural::hashgrid::Touched;

/// Points whose feature adjoints the backward holds at once: the memory
/// bound (64 chunks keep two cores, or sixteen, busy).
pub const BLOCK: usize = 64 * CHUNK;

/// Buffers of [`HashSdf::volume_forward`] and [`HashSdf::volume_backward`],
/// grown to the largest batch seen (no allocation once grown).
#[derive(Debug, Default)]
pub struct VolumeWork {
    rows: usize,
    /// `f` per point.
    f: Vec<f32>,
    /// `∇f` per point, flat (rows × 3).
    g: Vec<f32>,
    chunks: Vec<ChunkWork>,
    /// Where each probe of a block was evaluated.
    probes: Vec<[f32; 3]>,
    /// Each probe's feature adjoints in a block, `(1 + tangents) × E`.
    d_feat: Vec<f32>,
    /// Table rows the last backward wrote (the trainer's Adam is dense).
    touched: Option<Touched>,
    /// The exact form's chunk scratch, one a worker thread (and one for a
    /// caller outside the pool); each lock is only ever taken by the task
    /// running on its thread, so it never waits.
    blocks: Vec<Mutex<BlockScratch>>,
}

/// Runs `f` on the calling thread's blocked scratch.
fn with_block<R>(blocks: &[Mutex<BlockScratch>], f: impl FnOnce(&mut BlockScratch) -> R) -> R {
    let i = rayon::current_thread_index().map_or(blocks.len() - 1, |i| i % blocks.len());
    let mut s = blocks[i].lock().unwrap_or_else(|e| e.into_inner());
    f(&mut s)
}

/// Probes a point and tangents a probe of `eikonal`'s form.
fn form(eikonal: Eikonal) -> (usize, usize) {
    match eikonal {
        Eikonal::Exact => (1, 3),
        Eikonal::FiniteDifference { .. } => (FD_PROBES, 0),
    }
}

impl VolumeWork {
    fn resize(&mut self, net: &HashSdf, rows: usize, eikonal: Eikonal) {
        let (probes, nt) = form(eikonal);
        self.rows = rows;
        grow(&mut self.f, rows);
        grow(&mut self.g, 3 * rows);
        let (e, w) = (net.grid.output_dim(), net.width);
        let nchunks = BLOCK / CHUNK;
        if self.chunks.len() < nchunks {
            self.chunks.resize_with(nchunks, ChunkWork::default);
        }
        for c in &mut self.chunks {
            if nt == 0 {
                grow(&mut c.buf, probes * net.scratch_len::<0>());
                grow(&mut c.adj, 2 * e.max(w));
            }
            grow(&mut c.d_mlp, net.len - net.table_params());
        }
        if nt > 0 {
            let threads = rayon::current_num_threads() + 1;
            if self.blocks.len() < threads {
                self.blocks.resize_with(threads, Default::default);
            }
            for b in &mut self.blocks {
                b.get_mut().unwrap_or_else(|e| e.into_inner()).fit::<3>(net);
            }
        }
        if self.probes.len() < BLOCK * probes {
            self.probes.resize(BLOCK * probes, [0.0; 3]);
        }
        grow(&mut self.d_feat, BLOCK * probes * (1 + nt) * e);
        if self.touched.is_none() {
            self.touched = Some(net.grid.touched_set());
        }
    }

    /// `f` at the points of the last forward.
    pub fn distance(&self) -> &[f32] {
        &self.f[..self.rows]
    }

    /// `∇f` (rows × 3, flat) at the points of the last forward: the
    /// exact gradient or the central differences, as asked.
    pub fn gradient(&self) -> &[f32] {
        &self.g[..3 * self.rows]
    }
}

/// The six probes about `p` (±step on each axis, `2a + 1` then `2a + 2`)
/// after `p` itself.
pub(super) fn fd_probes(p: [f32; 3], step: f32, at: &mut [[f32; 3]]) {
    at[0] = p;
    for a in 0..3 {
        for (s, sign) in [(1, step), (2, -step)] {
            let mut q = p;
            q[a] += sign;
            at[2 * a + s] = q;
        }
    }
}

/// The realised span of axis `a`'s probes (so the difference quotient is
/// exact in f32); 0 where the step vanished in rounding.
fn span(at: &[[f32; 3]], a: usize) -> f32 {
    (at[2 * a + 1][a] - at[2 * a + 2][a]).max(0.0)
}

impl HashSdf {
    /// `f` and `∇f` at `points` with the first `active` levels, kept in
    /// `work` ([`VolumeWork::distance`], [`VolumeWork::gradient`]).
    pub fn volume_forward(
        &self,
        params: &[f32],
        points: &[[f32; 3]],
        eikonal: Eikonal,
        active: usize,
        work: &mut VolumeWork,
    ) {
        self.check_params(params);
        work.resize(self, points.len(), eikonal);
        let VolumeWork {
            f,
            g,
            chunks,
            blocks,
            ..
        } = work;
        let Eikonal::FiniteDifference { step } = eikonal else {
            f[..points.len()]
                .par_chunks_mut(CHUNK)
                .zip(g[..3 * points.len()].par_chunks_mut(3 * CHUNK))
                .zip(points.par_chunks(CHUNK))
                .for_each(|((f, g), pts)| {
                    with_block(blocks, |s| {
                        let g = g.as_chunks_mut::<3>().0;
                        value_grads_block(self, params, pts, active, &mut s.forward, f, g)
                    })
                });
            return;
        };
        for ((f, g), pts) in f[..points.len()]
            .chunks_mut(BLOCK)
            .zip(g[..3 * points.len()].chunks_mut(3 * BLOCK))
            .zip(points.chunks(BLOCK))
        {
            f.par_chunks_mut(CHUNK)
                .zip(g.par_chunks_mut(3 * CHUNK))
                .zip(pts.par_chunks(CHUNK))
                .zip(chunks.par_iter_mut())
                .for_each(|(((f, g), pts), cw)| {
                    for ((f, g), &p) in f.iter_mut().zip(g.chunks_exact_mut(3)).zip(pts) {
                        let (v, grad) = self.fd_point_forward(params, p, step, active, cw);
                        *f = v;
                        g.copy_from_slice(&grad);
                    }
                });
        }
    }

    /// One point's `f` and `∇f` by central differences of `step`; leaves
    /// its probes' forwards in `cw.buf` for the backward.
    #[inline(always)]
    pub(super) fn fd_point_forward(
        &self,
        params: &[f32],
        p: [f32; 3],
        step: f32,
        active: usize,
        cw: &mut ChunkWork,
    ) -> (f32, [f32; 3]) {
        let mut at = [[0f32; 3]; FD_PROBES];
        fd_probes(p, step, &mut at);
        let len = self.scratch_len::<0>();
        let mut fv = [0f32; FD_PROBES];
        for (k, &q) in at.iter().enumerate() {
            fv[k] = self.value(params, q, active, &mut cw.buf[k * len..][..len]);
        }
        let g = std::array::from_fn(|a| {
            let s = span(&at, a);
            if s > 0.0 {
                (fv[2 * a + 1] - fv[2 * a + 2]) / s
            } else {
                0.0
            }
        });
        (fv[0], g)
    }

    /// *Adds* `∂L/∂params` to `grad` given `∂L/∂f` (`d_f`, one a point)
    /// and `∂L/∂∇f` (`d_g`, three a point) at `points`, for the `∇f` of
    /// [`Self::volume_forward`] with the same `eikonal` and `active`
    /// levels. Each point's forward is recomputed here; see the module's
    /// note on memory and the order of the sums.
    #[allow(clippy::too_many_arguments)]
    pub fn volume_backward(
        &self,
        params: &[f32],
        points: &[[f32; 3]],
        d_f: &[f32],
        d_g: &[f32],
        eikonal: Eikonal,
        active: usize,
        work: &mut VolumeWork,
        grad: &mut [f32],
    ) {
        self.check_params(params);
        assert_eq!(grad.len(), self.len, "gradient");
        assert_eq!((d_f.len(), d_g.len()), (points.len(), 3 * points.len()));
        work.resize(self, points.len(), eikonal);
        let (probes, nt) = form(eikonal);
        let feat = (1 + nt) * self.grid.output_dim();
        let mlp = self.len - self.table_params();
        let VolumeWork {
            chunks,
            probes: at,
            d_feat,
            touched,
            blocks,
            ..
        } = work;
        let touched = touched.as_mut().expect("sized by resize");
        touched.clear();
        for ((pts, d_f), d_g) in points
            .chunks(BLOCK)
            .zip(d_f.chunks(BLOCK))
            .zip(d_g.chunks(3 * BLOCK))
        {
            let n = pts.len();
            let nchunks = n.div_ceil(CHUNK);
            chunks[..nchunks]
                .par_iter_mut()
                .zip(at[..n * probes].par_chunks_mut(CHUNK * probes))
                .zip(d_feat[..n * probes * feat].par_chunks_mut(CHUNK * probes * feat))
                .enumerate()
                .for_each(|(ci, ((cw, at), d_feat))| {
                    cw.d_mlp[..mlp].fill(0.0);
                    let (from, to) = (ci * CHUNK, (ci * CHUNK + CHUNK).min(n));
                    let Eikonal::FiniteDifference { step } = eikonal else {
                        at.copy_from_slice(&pts[from..to]);
                        with_block(blocks, |s| {
                            let (mut f, mut g) = ([0f32; CHUNK], [[0f32; 3]; CHUNK]);
                            let m = to - from;
                            let (pts, f, g) = (&pts[from..to], &mut f[..m], &mut g[..m]);
                            value_grads_block(self, params, pts, active, &mut s.forward, f, g);
                            let (d_f, d_g) = (&d_f[from..to], &d_g[3 * from..3 * to]);
                            grads_backward_block(self, params, s, d_f, d_g, &mut cw.d_mlp, d_feat);
                        });
                        return;
                    };
                    for (j, &p) in pts[from..to].iter().enumerate() {
                        let (df, dg) = (d_f[from + j], &d_g[3 * (from + j)..][..3]);
                        let at = &mut at[j * probes..][..probes];
                        let d_feat = &mut d_feat[j * probes * feat..][..probes * feat];
                        self.fd_point_backward(
                            params,
                            p,
                            df,
                            [dg[0], dg[1], dg[2]],
                            step,
                            active,
                            cw,
                            at,
                            d_feat,
                        );
                    }
                });
            self.add_partials(
                &chunks[..nchunks],
                |c| &c.d_mlp,
                &at[..n * probes],
                &d_feat[..n * probes * feat],
                nt,
                active,
                grad,
                touched,
            );
        }
    }

    /// One point's reverse pass with `∇f` by central differences of
    /// `step`: its probes' forwards recomputed, then the MLP's gradient
    /// into `cw.d_mlp` and each probe's position and feature adjoints into
    /// `at` and `d_feat` (the tables' share, summed later).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn fd_point_backward(
        &self,
        params: &[f32],
        p: [f32; 3],
        d_f: f32,
        d_g: [f32; 3],
        step: f32,
        active: usize,
        cw: &mut ChunkWork,
        at: &mut [[f32; 3]],
        d_feat: &mut [f32],
    ) {
        if d_f == 0.0 && d_g == [0.0; 3] {
            at.fill(p);
            d_feat.fill(0.0);
            return;
        }
        self.fd_point_forward(params, p, step, active, cw);
        fd_probes(p, step, at);
        self.fd_probes_backward(params, at, d_f, d_g, cw, d_feat);
    }

    /// The reverse pass of one point's central differences, its probes'
    /// forwards in `cw.buf` and their positions in `at`: the MLP's
    /// gradient into `cw.d_mlp` and each probe's feature adjoints into
    /// `d_feat`.
    #[inline(always)]
    pub(super) fn fd_probes_backward(
        &self,
        params: &[f32],
        at: &[[f32; 3]],
        d_f: f32,
        d_g: [f32; 3],
        cw: &mut ChunkWork,
        d_feat: &mut [f32],
    ) {
        // f is probe 0; ∇f_a = (f(2a+1) − f(2a+2)) / span_a.
        let mut d = [0f32; FD_PROBES];
        d[0] = d_f;
        for a in 0..3 {
            let s = span(at, a);
            if s > 0.0 {
                d[2 * a + 1] = d_g[a] / s;
                d[2 * a + 2] = -d_g[a] / s;
            }
        }
        let (len, feat) = (self.scratch_len::<0>(), self.grid.output_dim());
        for k in 0..FD_PROBES {
            let df = &mut d_feat[k * feat..][..feat];
            if d[k] == 0.0 {
                df.fill(0.0);
                continue;
            }
            self.mlp_backward::<0>(
                params,
                &cw.buf[k * len..][..len],
                d[k],
                [0.0; 3],
                &mut cw.d_mlp,
                &mut cw.adj,
                df,
            );
        }
    }
}
