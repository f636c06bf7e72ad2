//! A signed distance function on a multiresolution hash grid (NeuS2,
//! instant-nsr): `f(x) = MLP(hash_encoding(x)) + ‖x − c‖ − r`, with `c` the
//! grid box's centre.
//!
//! - **Initialised as a sphere** by the fixed analytic term `‖x − c‖ − r`:
//!   the tables start at ±1e-4 (so the features are ≈ 0) and the output
//!   bias is set so that the network gives exactly 0 at zero features. `f`
//!   is then the sphere's distance to ~1e-5 and `‖∇f‖ = 1` from step 0,
//!   and the network learns the residual. A geometric (SAL) initialisation
//!   does not apply: the MLP sees no raw position, only hash features.
//!   Outside the box the features are clamped, so there `f` grows like the
//!   sphere's distance (a Lipschitz-friendly far field for tracing).
//! - **∇f exactly** by forward-mode tangents: each point carries its
//!   value and its three derivatives by `x` through the encoding
//!   (`∂feat/∂x = Σ_corners table[c] ⊗ ∇w_c(x)`) and the softplus layers
//!   (`ż = W·ḣ`, `ḣ = σ(βz)⊙ż`). The loss's backward is the reverse pass of
//!   that computation, so the eikonal term's gradient is exact, second
//!   order through the interpolation weights' derivatives and `softplus''`.
//! - **Or ∇f by central differences** of `f` with step `h` (Neuralangelo):
//!   seven value evaluations a point, the backward exact for that
//!   expression. No second derivatives are needed.
//! - **Progressive levels**: the `active` levels (coarse first) are read;
//!   finer ones give zero features and receive no gradient.
//! - Per step no allocation once [`HashSdfWork`] has grown; points go in
//!   fixed chunks of [`CHUNK`], the MLP's gradient is summed per chunk then
//!   over chunks in order, the tables' per level in point order: the result
//!   is bit-identical at any thread count.
//!
//! Params are flat: the grid's tables ([`HashGrid`]'s layout), then per
//! hidden layer `W` (out × in, row-major) and `b`, then the output's
//! weights and bias.

use rayon::prelude::*;

use self::block::BlockScratch;
use super::hashgrid::{HashGrid, HashGridConfig, Touched};
use super::mlp::softplus_layer;
use crate::mesh::DistanceField;
use crate::volume::SplitMix64;

/// Points per chunk: the unit of parallel work and of the MLP gradient's
/// partial sums (fixed, so the sums do not depend on the thread count).
pub const CHUNK: usize = 128;
/// Value evaluations a point in the finite-difference form.
const FD_PROBES: usize = 7;

/// The shape of a [`HashSdf`].
#[derive(Debug, Clone, PartialEq)]
pub struct HashSdfSpec {
    /// The hash encoding and the box it covers.
    pub grid: HashGridConfig,
    /// Hidden softplus layers (1 or 2 is usual).
    pub layers: usize,
    /// Units per hidden layer.
    pub width: usize,
    /// Softplus sharpness β.
    pub beta: f32,
    /// Radius of the starting sphere around the box's centre.
    pub radius: f32,
}

impl Default for HashSdfSpec {
    fn default() -> Self {
        HashSdfSpec {
            grid: HashGridConfig {
                levels: 16,
                features: 2,
                log2_table: 19,
                min_res: 16,
                max_res: 2048,
                bbox_min: [-1.0; 3],
                bbox_max: [1.0; 3],
            },
            layers: 1,
            width: 64,
            beta: 100.0,
            radius: 0.5,
        }
    }
}

/// How the eikonal term's `∇f` is computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Eikonal {
    /// Exactly, through the interpolation weights and the MLP.
    Exact,
    /// By central differences of `f` with this step (Neuralangelo).
    FiniteDifference {
        /// The step `h`; `∇f_a ≈ (f(x + h·e_a) − f(x − h·e_a)) / 2h`.
        step: f32,
    },
}

/// The weights of [`HashSdf::loss_and_grad`]'s terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HashSdfLoss {
    /// Of `mean|f|` over the surface points.
    pub surface: f32,
    /// λ, of `mean(‖∇f‖ − 1)²` over all points.
    pub eikonal: f32,
    /// Of `mean exp(−α|f|)` over the random points (keeps the surface
    /// away from where there is no data).
    pub inter: f32,
    /// α, the inter term's sharpness.
    pub alpha: f32,
}

impl Default for HashSdfLoss {
    fn default() -> Self {
        HashSdfLoss {
            surface: 1.0,
            eikonal: 0.1,
            inter: 0.0,
            alpha: 100.0,
        }
    }
}

/// Lower bounds on `|f|` at the random points and the weight of the hinge
/// `mean_r max(0, at_least_r − |f|)`: SAL's unsigned distance to the data,
/// used one-sided. A surface lies no closer to a point than the data's
/// nearest sample less their spacing, so with `at_least` the distance to
/// the nearest sample less that margin the true SDF pays nothing, while a
/// zero crossing far from every sample (a leftover of the starting
/// sphere, a sheet across a concavity) does. A hash grid needs it where an
/// MLP does not: its features are local, so nothing else moves a surface
/// that no point touches.
#[derive(Debug, Clone, Copy)]
pub struct Clearance<'a> {
    /// Weight of the hinge's mean over the random points.
    pub weight: f32,
    /// Per random point, the least `|f|` allowed (or empty: none).
    pub at_least: &'a [f32],
}

/// A hash-grid SDF: the layout only; params live with the caller.
#[derive(Debug, Clone)]
pub struct HashSdf {
    grid: HashGrid,
    /// Per hidden layer (input width, offset of `W`); `b` follows `W`.
    hidden: Vec<(usize, usize)>,
    /// Offset of the output weights; the bias follows them.
    output: usize,
    width: usize,
    beta: f32,
    radius: f32,
    centre: [f64; 3],
    len: usize,
    /// First float of each level's table, then the tables' end.
    offsets: Vec<usize>,
}

/// Levels active at `step` when `start_levels` are on from the start and
/// one more every `every` steps, coarse to fine (all when `every = 0`).
pub fn progressive_levels(step: u64, levels: usize, start_levels: usize, every: u64) -> usize {
    let more = step.checked_div(every).unwrap_or(u64::MAX);
    (start_levels as u64)
        .saturating_add(more)
        .min(levels as u64) as usize
}

impl HashSdf {
    /// The layout of `spec`; refuses an empty network or a bad grid.
    pub fn new(spec: &HashSdfSpec) -> Result<Self, String> {
        if spec.layers == 0 || spec.width == 0 || spec.width > 4096 || spec.layers > 16 {
            return Err(format!(
                "hash SDF: {} layers of {} units; need 1..=16 layers of 1..=4096",
                spec.layers, spec.width
            ));
        }
        if !(spec.beta > 0.0 && spec.beta.is_finite() && spec.radius.is_finite()) {
            return Err("hash SDF: softplus β must be positive, the radius finite".into());
        }
        let grid = HashGrid::new(spec.grid.clone())?;
        let mut offset = grid.param_count();
        let mut hidden = Vec::with_capacity(spec.layers);
        let mut input = grid.output_dim();
        for _ in 0..spec.layers {
            hidden.push((input, offset));
            offset += input * spec.width + spec.width;
            input = spec.width;
        }
        let output = offset;
        let len = output + spec.width + 1;
        let c = &spec.grid;
        let centre = std::array::from_fn(|a| 0.5 * (c.bbox_min[a] as f64 + c.bbox_max[a] as f64));
        let mut offsets = grid.level_offsets();
        offsets.push(grid.param_count());
        Ok(HashSdf {
            offsets,
            grid,
            hidden,
            output,
            width: spec.width,
            beta: spec.beta,
            radius: spec.radius,
            centre,
            len,
        })
    }

    /// The encoding.
    pub fn grid(&self) -> &HashGrid {
        &self.grid
    }
    /// Trainable numbers: tables then MLP.
    pub fn param_count(&self) -> usize {
        self.len
    }
    /// Trainable numbers in the tables (the params' first part).
    pub fn table_params(&self) -> usize {
        self.grid.param_count()
    }
    /// The layers' parameter blocks after the tables, in order, named:
    /// per hidden layer `W` then `b`, then the output's.
    pub fn layer_sizes(&self) -> Vec<(String, usize)> {
        let w = self.width;
        let mut sizes = Vec::with_capacity(2 * self.hidden.len() + 2);
        for (i, &(input, _)) in self.hidden.iter().enumerate() {
            sizes.push((format!("layer{i}.weight"), input * w));
            sizes.push((format!("layer{i}.bias"), w));
        }
        sizes.push(("output.weight".into(), w));
        sizes.push(("output.bias".into(), 1));
        sizes
    }
    /// Number of levels (the most that can be active).
    pub fn levels(&self) -> usize {
        self.grid.config().levels as usize
    }

    /// Tables U(−1e-4, 1e-4), hidden weights U(−1/√in, 1/√in) with zero
    /// biases, output weights U(−1/√width, 1/√width) and the output bias
    /// that makes the network 0 at zero features: `f` starts as the sphere.
    pub fn init(&self, seed: u64) -> Vec<f32> {
        let mut params = self.grid.init(seed);
        params.resize(self.len, 0.0);
        let mut rng = SplitMix64::new(seed ^ 0x6873_6466);
        let mut uniform = |n: usize, bound: f32, out: &mut [f32]| {
            for v in &mut out[..n] {
                *v = (rng.next_f32() * 2.0 - 1.0) * bound;
            }
        };
        for &(input, off) in &self.hidden {
            let n = input * self.width;
            uniform(n, 1.0 / (input as f32).sqrt(), &mut params[off..]);
        }
        let w = self.width;
        uniform(w, 1.0 / (w as f32).sqrt(), &mut params[self.output..]);
        let e = self.grid.output_dim();
        let mut s = Scratch::new(self, 0);
        s.buf[..e].fill(0.0);
        let at_zero = self.mlp_forward::<0>(&params, &mut s.buf);
        params[self.output + w] = -at_zero;
        params
    }

    /// `‖x − c‖ − r` and its gradient (0 at the centre), in f64 and
    /// saturated at the f32 range so huge coordinates stay finite.
    #[doc(hidden)]
    pub fn sphere(&self, p: [f32; 3]) -> (f32, [f32; 3]) {
        let d: [f64; 3] = std::array::from_fn(|a| p[a] as f64 - self.centre[a]);
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let g = if n > 0.0 {
            std::array::from_fn(|a| (d[a] / n) as f32)
        } else {
            [0.0; 3]
        };
        (to_f32(n - self.radius as f64), g)
    }

    /// Features (and with `NT = 3` their derivatives by `x`) of `p` into
    /// `e`: `(1 + NT) × E`, value first; levels from `active` on are 0.
    #[inline(always)]
    fn encode<const NT: usize>(&self, params: &[f32], p: [f32; 3], active: usize, e: &mut [f32]) {
        let f = self.grid.config().features as usize;
        let dim = self.grid.output_dim();
        e[..(1 + NT) * dim].fill(0.0);
        let levels = self.offsets.len() - 1;
        for (l, &off) in self.offsets[..levels].iter().enumerate().take(active) {
            let table = &params[off..];
            if NT == 0 {
                let (rows, w) = self.grid.corners_at(l, p);
                for c in 0..8 {
                    let row = &table[rows[c] as usize * f..][..f];
                    for k in 0..f {
                        e[l * f + k] += w[c] * row[k];
                    }
                }
            } else {
                let (rows, w, dw) = self.grid.corners_dx(l, p);
                for c in 0..8 {
                    let row = &table[rows[c] as usize * f..][..f];
                    for k in 0..f {
                        e[l * f + k] += w[c] * row[k];
                        for a in 0..NT {
                            e[(1 + a) * dim + l * f + k] += dw[c][a] * row[k];
                        }
                    }
                }
            }
        }
    }

    /// The MLP on the features at the start of `buf` (see [`Scratch`]):
    /// returns the network's value and leaves the layers' values,
    /// tangents and slopes in `buf`; with `NT = 3` the output's tangents
    /// follow in `buf[tangent_out..]`.
    #[inline(always)]
    fn mlp_forward<const NT: usize>(&self, params: &[f32], buf: &mut [f32]) -> f32 {
        let w = self.width;
        let beta = self.beta;
        for (i, &(input, off)) in self.hidden.iter().enumerate() {
            let (lo, block) = buf.split_at_mut(self.input_at::<NT>(i + 1));
            let x = &lo[self.input_at::<NT>(i)..][..(1 + NT) * input];
            let weights = &params[off..][..input * w];
            let bias = &params[off + input * w..][..w];
            let (h, rest) = block.split_at_mut((1 + NT) * w);
            let (zt, rest) = rest.split_at_mut(NT * w);
            let s = &mut rest[..w];
            for j in 0..w {
                let row = &weights[j * input..][..input];
                let mut z = bias[j];
                let mut t = [0f32; 3];
                for k in 0..input {
                    z += row[k] * x[k];
                    for (a, t) in t.iter_mut().enumerate().take(NT) {
                        *t += row[k] * x[(1 + a) * input + k];
                    }
                }
                h[j] = z;
                for a in 0..NT {
                    zt[a * w + j] = t[a];
                }
            }
            // The one softplus kernel of every path (the blocked ones too).
            let (h, ht) = h.split_at_mut(w);
            softplus_layer(h, Some(s), beta);
            for a in 0..NT {
                for j in 0..w {
                    ht[a * w + j] = s[j] * zt[a * w + j];
                }
            }
        }
        let at = self.input_at::<NT>(self.hidden.len());
        let h = &buf[at..];
        let wo = &params[self.output..][..w];
        let mut out = params[self.output + w];
        for j in 0..w {
            out += wo[j] * h[j];
        }
        let mut tangents = [0f32; 3];
        for (a, t) in tangents.iter_mut().enumerate().take(NT) {
            for j in 0..w {
                *t += wo[j] * h[(1 + a) * w + j];
            }
        }
        let tangents_at = self.tangent_out::<NT>();
        buf[tangents_at..][..NT].copy_from_slice(&tangents[..NT]);
        out
    }

    /// Floats a layer block takes in [`Scratch`] beyond its input.
    fn layer_block<const NT: usize>(&self) -> usize {
        (1 + NT) * self.width + NT * self.width + self.width
    }

    /// Where the output's tangents sit in the scratch.
    #[doc(hidden)]
    pub fn tangent_out<const NT: usize>(&self) -> usize {
        // The features, then per layer its h, zt and s.
        (1 + NT) * self.grid.output_dim() + self.hidden.len() * self.layer_block::<NT>()
    }

    /// Start of layer `i`'s input in the scratch (layer `i − 1`'s block,
    /// whose `h` comes first).
    fn input_at<const NT: usize>(&self, i: usize) -> usize {
        let e = self.grid.output_dim();
        if i == 0 {
            0
        } else {
            (1 + NT) * e + (i - 1) * self.layer_block::<NT>()
        }
    }

    /// Floats of one point's forward scratch.
    fn scratch_len<const NT: usize>(&self) -> usize {
        self.tangent_out::<NT>() + NT
    }

    /// The reverse pass of [`Self::mlp_forward`] for one point: given
    /// `∂L/∂out` and `∂L/∂(out's tangents)`, adds the MLP's gradient to
    /// `d_mlp` (indexed from the first MLP param) and writes the features'
    /// adjoints (`(1 + NT) × E`) into `d_feat`. `adj` holds two buffers of
    /// `(1 + NT)·max(E, width)`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    #[doc(hidden)]
    pub fn mlp_backward<const NT: usize>(
        &self,
        params: &[f32],
        buf: &[f32],
        d_out: f32,
        d_tan: [f32; 3],
        d_mlp: &mut [f32],
        adj: &mut [f32],
        d_feat: &mut [f32],
    ) {
        let (w, e, beta) = (self.width, self.grid.output_dim(), self.beta);
        let tables = self.table_params();
        let half = adj.len() / 2;
        let (mut cur, mut prev) = adj.split_at_mut(half);
        // Output layer.
        let last_h = self.input_at::<NT>(self.hidden.len());
        let h = &buf[last_h..][..(1 + NT) * w];
        let wo = &params[self.output..][..w];
        {
            let dwo = &mut d_mlp[self.output - tables..][..w + 1];
            for j in 0..w {
                let mut g = d_out * h[j];
                for a in 0..NT {
                    g += d_tan[a] * h[(1 + a) * w + j];
                }
                dwo[j] += g;
                cur[j] = d_out * wo[j];
                for a in 0..NT {
                    cur[(1 + a) * w + j] = d_tan[a] * wo[j];
                }
            }
            dwo[w] += d_out;
        }
        for (i, &(input, off)) in self.hidden.iter().enumerate().rev() {
            let x_at = self.input_at::<NT>(i);
            let x = &buf[x_at..][..(1 + NT) * input];
            let block = &buf[self.input_at::<NT>(i + 1)..];
            let zt = &block[(1 + NT) * w..][..NT * w];
            let s = &block[(1 + NT) * w + NT * w..][..w];
            let weights = &params[off..][..input * w];
            let dw = &mut d_mlp[off - tables..][..input * w + w];
            let (dweights, dbias) = dw.split_at_mut(input * w);
            let xbar = &mut prev[..(1 + NT) * input];
            xbar.fill(0.0);
            for j in 0..w {
                let sl = s[j];
                let curv = beta * sl * (1.0 - sl);
                let mut zbar = cur[j] * sl;
                let mut ztbar = [0f32; 3];
                for a in 0..NT {
                    let hb = cur[(1 + a) * w + j];
                    zbar += hb * zt[a * w + j] * curv;
                    ztbar[a] = hb * sl;
                }
                dbias[j] += zbar;
                let row = &weights[j * input..][..input];
                let drow = &mut dweights[j * input..][..input];
                for k in 0..input {
                    let mut g = zbar * x[k];
                    xbar[k] += row[k] * zbar;
                    for a in 0..NT {
                        g += ztbar[a] * x[(1 + a) * input + k];
                        xbar[(1 + a) * input + k] += row[k] * ztbar[a];
                    }
                    drow[k] += g;
                }
            }
            std::mem::swap(&mut cur, &mut prev);
        }
        d_feat[..(1 + NT) * e].copy_from_slice(&cur[..(1 + NT) * e]);
    }

    /// `f` at one point (value only), scratch in `buf`.
    #[inline(always)]
    #[doc(hidden)]
    pub fn value(&self, params: &[f32], p: [f32; 3], active: usize, buf: &mut [f32]) -> f32 {
        self.encode::<0>(params, p, active, buf);
        self.mlp_forward::<0>(params, buf) + self.sphere(p).0
    }

    /// `f` and exact `∇f` at one point, scratch in `buf`.
    #[inline(always)]
    #[doc(hidden)]
    pub fn value_grad(
        &self,
        params: &[f32],
        p: [f32; 3],
        active: usize,
        buf: &mut [f32],
    ) -> (f32, [f32; 3]) {
        self.encode::<3>(params, p, active, buf);
        let net = self.mlp_forward::<3>(params, buf);
        let (d, g) = self.sphere(p);
        let t = self.tangent_out::<3>();
        (net + d, std::array::from_fn(|a| buf[t + a] + g[a]))
    }

    fn check_params(&self, params: &[f32]) {
        assert_eq!(params.len(), self.len, "hash SDF params");
    }

    /// `f` at `points` into `out`, with the first `active` levels.
    pub fn distances(&self, params: &[f32], points: &[[f32; 3]], active: usize, out: &mut [f32]) {
        self.check_params(params);
        assert_eq!(points.len(), out.len(), "one distance a point");
        let len = self.block_len::<0>();
        out.par_chunks_mut(CHUNK)
            .zip(points.par_chunks(CHUNK))
            .for_each(|(out, pts)| {
                // One buffer a worker thread, kept between calls: the
                // placing pass runs every step.
                DISTANCE_SCRATCH.with_borrow_mut(|buf| {
                    if buf.len() < len {
                        buf.resize(len, 0.0);
                    }
                    block::values_block(self, params, pts, active, &mut buf[..len], out)
                })
            });
    }

    /// [`Self::distances`] one point at a time through `value`:
    /// the reference that the blocked pass is tested and benchmarked
    /// against (the same bits, slower).
    pub fn distances_pointwise(
        &self,
        params: &[f32],
        points: &[[f32; 3]],
        active: usize,
        out: &mut [f32],
    ) {
        self.check_params(params);
        assert_eq!(points.len(), out.len(), "one distance a point");
        out.par_chunks_mut(CHUNK)
            .zip(points.par_chunks(CHUNK))
            .for_each_init(
                || Scratch::new(self, 0),
                |s, (out, pts)| {
                    for (o, &p) in out.iter_mut().zip(pts) {
                        *o = self.value(params, p, active, &mut s.buf);
                    }
                },
            );
    }

    /// `f` and the exact `∇f` at `points`, with the first `active` levels.
    pub fn gradients(
        &self,
        params: &[f32],
        points: &[[f32; 3]],
        active: usize,
        f: &mut [f32],
        g: &mut [[f32; 3]],
    ) {
        self.check_params(params);
        assert_eq!((points.len(), points.len()), (f.len(), g.len()));
        f.par_chunks_mut(CHUNK)
            .zip(g.par_chunks_mut(CHUNK))
            .zip(points.par_chunks(CHUNK))
            .for_each_init(
                || BlockScratch::forward_only::<3>(self),
                |s, ((f, g), pts)| {
                    block::value_grads_block(self, params, pts, active, &mut s.forward, f, g)
                },
            );
    }

    /// The loss `surface·mean_s|f| + eikonal·mean(‖∇f‖ − 1)² +
    /// inter·mean_r exp(−α|f|)` at `surface` points (the shape's) and
    /// `random` points (in the volume), the eikonal mean over both sets, with `∇f` as `eikonal` says and the
    /// first `active` levels. *Adds* `∂L/∂params` to `grad` and marks the
    /// table rows it wrote in `touched` (a set of [`Self::grid`]'s), so a
    /// step costs O(touched rows), not O(tables): [`HashGrid::sparse_adam_update`]
    /// on the tables' part clears exactly those. `f` and `∇f` stay in
    /// `work` (surface points first). At `∇f = 0` the
    /// eikonal adjoint is 0 (the least-norm subgradient), at `f = 0` the
    /// surface one.
    #[allow(clippy::too_many_arguments)]
    pub fn loss_and_grad(
        &self,
        params: &[f32],
        surface: &[[f32; 3]],
        random: &[[f32; 3]],
        weights: &HashSdfLoss,
        eikonal: Eikonal,
        active: usize,
        work: &mut HashSdfWork,
        grad: &mut [f32],
        touched: &mut Touched,
    ) -> f64 {
        let none = Clearance {
            weight: 0.0,
            at_least: &[],
        };
        self.loss_and_grad_clear(
            params, surface, random, weights, none, eikonal, active, work, grad, touched,
        )
    }

    /// [`Self::loss_and_grad`] plus the clearance hinge
    /// `clearance.weight · mean_r max(0, at_least_r − |f|)` over the random
    /// points (see [`Clearance`]).
    #[allow(clippy::too_many_arguments)]
    pub fn loss_and_grad_clear(
        &self,
        params: &[f32],
        surface: &[[f32; 3]],
        random: &[[f32; 3]],
        weights: &HashSdfLoss,
        clearance: Clearance<'_>,
        eikonal: Eikonal,
        active: usize,
        work: &mut HashSdfWork,
        grad: &mut [f32],
        touched: &mut Touched,
    ) -> f64 {
        self.check_params(params);
        assert!(
            clearance.at_least.is_empty() || clearance.at_least.len() == random.len(),
            "one clearance a random point"
        );
        assert_eq!(grad.len(), self.len, "gradient");
        let (ns, n) = (surface.len(), surface.len() + random.len());
        let probes = match eikonal {
            Eikonal::Exact => 1,
            Eikonal::FiniteDifference { .. } => FD_PROBES,
        };
        let nt = if probes == 1 { 3 } else { 0 };
        work.resize(self, n, probes, nt);
        let e = self.grid.output_dim();
        let feat = (1 + nt) * e;
        let mlp = self.len - self.table_params();
        let k_s = weights.surface as f64 / ns.max(1) as f64;
        let k_e = weights.eikonal as f64 / n.max(1) as f64;
        let inter = Inter {
            k: weights.inter as f64 / random.len().max(1) as f64,
            alpha: weights.alpha as f64,
            k_clear: clearance.weight as f64 / random.len().max(1) as f64,
        };
        let role = |i: usize| {
            if i < ns {
                Role::Surface
            } else {
                let at_least = clearance.at_least.get(i - ns);
                Role::Random {
                    at_least: at_least.copied().unwrap_or(f32::NEG_INFINITY),
                }
            }
        };
        let point = |i: usize| if i < ns { surface[i] } else { random[i - ns] };
        let HashSdfWork {
            chunks,
            probes: at,
            d_feat,
            f: out_f,
            g: out_g,
            ..
        } = work;
        let nchunks = n.div_ceil(CHUNK);
        chunks[..nchunks]
            .par_iter_mut()
            .zip(at[..n * probes].par_chunks_mut(CHUNK * probes))
            .zip(d_feat[..n * probes * feat].par_chunks_mut(CHUNK * probes * feat))
            .zip(out_f[..n].par_chunks_mut(CHUNK))
            .zip(out_g[..n].par_chunks_mut(CHUNK))
            .enumerate()
            .for_each(|(ci, ((((cw, at), d_feat), out_f), out_g))| {
                cw.d_mlp[..mlp].fill(0.0);
                let mut loss = 0f64;
                for (j, (of, og)) in out_f.iter_mut().zip(out_g.iter_mut()).enumerate() {
                    let i = ci * CHUNK + j;
                    let p = point(i);
                    let at = &mut at[j * probes..][..probes];
                    let d_feat = &mut d_feat[j * probes * feat..][..probes * feat];
                    match eikonal {
                        Eikonal::Exact => {
                            let (f, g) = self.value_grad(params, p, active, &mut cw.buf);
                            let (l, df, dg) = point_loss(f, g, role(i), k_s, k_e, inter);
                            loss += l;
                            let t = self.tangent_out::<3>();
                            let buf = &cw.buf[..t + 3];
                            self.mlp_backward::<3>(
                                params,
                                buf,
                                df,
                                dg,
                                &mut cw.d_mlp,
                                &mut cw.adj,
                                d_feat,
                            );
                            at[0] = p;
                            (*of, *og) = (f, g);
                        }
                        Eikonal::FiniteDifference { step } => {
                            let (f, g) = self.fd_point_forward(params, p, step, active, cw);
                            volume::fd_probes(p, step, at);
                            let (l, df, dg) = point_loss(f, g, role(i), k_s, k_e, inter);
                            loss += l;
                            self.fd_probes_backward(params, at, df, dg, cw, d_feat);
                            (*of, *og) = (f, g);
                        }
                    }
                }
                cw.loss = loss;
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
        chunks[..nchunks].iter().map(|c| c.loss).sum()
    }

    /// *Adds* to `grad` the MLP's gradient, the chunks' partials (`d_mlp`) summed in
    /// chunk order (so the sum does not depend on the thread count), and
    /// the tables' from the probes' feature adjoints.
    #[allow(clippy::too_many_arguments)]
    fn add_partials<C: Sync>(
        &self,
        chunks: &[C],
        d_mlp: impl Fn(&C) -> &[f32] + Sync,
        probes: &[[f32; 3]],
        d_feat: &[f32],
        nt: usize,
        active: usize,
        grad: &mut [f32],
        touched: &mut Touched,
    ) {
        let (g_tables, g_mlp) = grad.split_at_mut(self.table_params());
        g_mlp.par_chunks_mut(256).enumerate().for_each(|(b, g)| {
            for cw in chunks {
                for (g, d) in g.iter_mut().zip(&d_mlp(cw)[b * 256..]) {
                    *g += d;
                }
            }
        });
        self.tables_backward(probes, d_feat, nt, active, g_tables, touched);
    }

    /// Adds the tables' gradient given each probe's feature adjoints
    /// (`(1 + nt) × E` a probe), in parallel over levels, probes in order.
    #[doc(hidden)]
    pub fn tables_backward(
        &self,
        probes: &[[f32; 3]],
        d_feat: &[f32],
        nt: usize,
        active: usize,
        grad: &mut [f32],
        touched: &mut Touched,
    ) {
        let f = self.grid.config().features as usize;
        let e = self.grid.output_dim();
        let feat = (1 + nt) * e;
        let levels = self.offsets.len() - 1;
        // Each level's slice of `grad`, on the stack (at most 64 levels).
        let mut parts: [&mut [f32]; 64] = std::array::from_fn(|_| Default::default());
        let mut rest = grad;
        for (l, o) in self.offsets.windows(2).enumerate() {
            let (a, b) = std::mem::take(&mut rest).split_at_mut(o[1] - o[0]);
            parts[l] = a;
            rest = b;
        }
        let (words, bits) = touched.words_mut();
        assert_eq!(words.len(), levels + 1, "a touched set of this grid");
        let mut marks: [&mut [u64]; 64] = std::array::from_fn(|_| Default::default());
        let mut rest = bits;
        for (l, w) in words.windows(2).enumerate() {
            let (a, b) = std::mem::take(&mut rest).split_at_mut(w[1] - w[0]);
            marks[l] = a;
            rest = b;
        }
        let active = active.min(levels);
        parts[..active]
            .par_iter_mut()
            .zip(marks[..active].par_iter_mut())
            .enumerate()
            .for_each(|(l, (g, bits))| {
                // A batch of probes' corners first, then their adds in
                // probe order: the reads of `g` then do not wait on the
                // hashing, and the sums' order is the probes'.
                let mut rows = [[0u32; 8]; CHUNK];
                let mut w = [[0f32; 8]; CHUNK];
                let mut dw = [[[0f32; 3]; 8]; CHUNK];
                for (probes, d_feat) in probes.chunks(CHUNK).zip(d_feat.chunks(CHUNK * feat)) {
                    for (i, &p) in probes.iter().enumerate() {
                        if nt == 0 {
                            (rows[i], w[i]) = self.grid.corners_at(l, p);
                        } else {
                            (rows[i], w[i], dw[i]) = self.grid.corners_dx(l, p);
                        }
                    }
                    for (i, d) in d_feat.chunks_exact(feat).enumerate() {
                        let dv = &d[l * f..][..f];
                        if nt == 0 {
                            if dv.iter().all(|&v| v == 0.0) {
                                continue;
                            }
                            for c in 0..8 {
                                let r = rows[i][c] as usize;
                                bits[r / 64] |= 1 << (r % 64);
                                let g = &mut g[r * f..][..f];
                                for k in 0..f {
                                    g[k] += w[i][c] * dv[k];
                                }
                            }
                        } else {
                            for c in 0..8 {
                                let r = rows[i][c] as usize;
                                bits[r / 64] |= 1 << (r % 64);
                                let g = &mut g[r * f..][..f];
                                for k in 0..f {
                                    let mut s = w[i][c] * dv[k];
                                    for a in 0..3 {
                                        s += dw[i][c][a] * d[(1 + a) * e + l * f + k];
                                    }
                                    g[k] += s;
                                }
                            }
                        }
                    }
                }
            });
    }
}

/// The random points' terms: the inter term's weight a point and its
/// sharpness, and the clearance hinge's weight a point.
#[derive(Clone, Copy)]
struct Inter {
    k: f64,
    alpha: f64,
    k_clear: f64,
}

/// Which set a point belongs to: a surface point, or a random one with its
/// lower bound on `|f|` (the clearance; `−∞` where there is none).
#[derive(Clone, Copy)]
enum Role {
    Surface,
    Random { at_least: f32 },
}

/// One point's loss and its adjoints of `f` and `∇f`.
#[inline(always)]
fn point_loss(
    f: f32,
    g: [f32; 3],
    role: Role,
    k_s: f64,
    k_e: f64,
    inter: Inter,
) -> (f64, f32, [f32; 3]) {
    let mut loss = 0.0;
    let v = f as f64;
    let df = match role {
        Role::Surface => {
            loss += k_s * v.abs();
            (k_s * sign(v)) as f32
        }
        Role::Random { at_least } => {
            let mut d = 0.0;
            if inter.k != 0.0 {
                let e = (-inter.alpha * v.abs()).exp();
                loss += inter.k * e;
                d = -inter.k * inter.alpha * sign(v) * e;
            }
            let gap = at_least as f64 - v.abs();
            if inter.k_clear != 0.0 && gap > 0.0 {
                loss += inter.k_clear * gap;
                d -= inter.k_clear * sign(v);
            }
            to_f32(d)
        }
    };
    let v = g.map(|x| x as f64);
    let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    loss += k_e * (norm - 1.0) * (norm - 1.0);
    let scale = if norm > 0.0 {
        2.0 * k_e * (1.0 - 1.0 / norm)
    } else {
        0.0
    };
    let dg = v.map(|x| to_f32(scale * x));
    (loss, df, dg)
}

fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// Saturates at the f32 range: a finite loss gives finite adjoints.
fn to_f32(x: f64) -> f32 {
    x.clamp(-f32::MAX as f64, f32::MAX as f64) as f32
}

/// One point's forward scratch (or seven, for the finite differences).
#[doc(hidden)]
pub struct Scratch {
    /// The floats of the forward (and its tangents).
    pub buf: Vec<f32>,
}

impl Scratch {
    /// A point's scratch for `net` with `nt` tangents (0 or 3).
    pub fn new(net: &HashSdf, nt: usize) -> Self {
        let len = if nt == 0 {
            net.scratch_len::<0>()
        } else {
            net.scratch_len::<3>()
        };
        Scratch {
            buf: vec![0.0; len],
        }
    }
}

/// One chunk's buffers (the volume passes leave `loss` unused).
#[derive(Debug, Default)]
struct ChunkWork {
    /// The forward scratch of one point (or its seven probes).
    buf: Vec<f32>,
    /// Two adjoint buffers of the MLP's backward.
    adj: Vec<f32>,
    /// This chunk's share of the MLP's gradient.
    d_mlp: Vec<f32>,
    loss: f64,
}

/// Buffers of [`HashSdf::loss_and_grad`], grown to the largest batch seen
/// (no allocation once grown).
#[derive(Debug, Default)]
pub struct HashSdfWork {
    chunks: Vec<ChunkWork>,
    /// Where each probe was evaluated.
    probes: Vec<[f32; 3]>,
    /// Each probe's feature adjoints, `(1 + tangents) × E`.
    d_feat: Vec<f32>,
    f: Vec<f32>,
    g: Vec<[f32; 3]>,
    rows: usize,
}

impl HashSdfWork {
    fn resize(&mut self, net: &HashSdf, rows: usize, probes: usize, nt: usize) {
        let nchunks = rows.div_ceil(CHUNK);
        let e = net.grid.output_dim();
        let w = net.width;
        let buf = if nt == 0 {
            probes * net.scratch_len::<0>()
        } else {
            net.scratch_len::<3>()
        };
        let adj = 2 * (1 + nt) * e.max(w);
        let mlp = net.len - net.table_params();
        if self.chunks.len() < nchunks {
            self.chunks.resize_with(nchunks, ChunkWork::default);
        }
        for c in &mut self.chunks[..nchunks] {
            grow(&mut c.buf, buf);
            grow(&mut c.adj, adj);
            grow(&mut c.d_mlp, mlp);
        }
        let cap = nchunks * CHUNK;
        if self.probes.len() < cap * probes {
            self.probes.resize(cap * probes, [0.0; 3]);
        }
        grow(&mut self.d_feat, cap * probes * (1 + nt) * e);
        grow(&mut self.f, cap);
        if self.g.len() < cap {
            self.g.resize(cap, [0.0; 3]);
        }
        self.rows = rows;
    }

    /// `f` at the last loss's points (surface points first).
    pub fn distance(&self) -> &[f32] {
        &self.f[..self.rows]
    }
    /// `∇f` as the last loss computed it (exact or by differences).
    pub fn gradient(&self) -> &[[f32; 3]] {
        &self.g[..self.rows]
    }
}

thread_local! {
    /// [`HashSdf::distances`]'s block buffer on this thread.
    static DISTANCE_SCRATCH: std::cell::RefCell<Vec<f32>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

fn grow(v: &mut Vec<f32>, n: usize) {
    if v.len() < n {
        v.resize(n, 0.0);
    }
}

/// A trained hash SDF as a field to mesh or trace (exact gradients).
pub struct HashSdfField<'a> {
    /// The network.
    pub net: &'a HashSdf,
    /// Its params.
    pub params: &'a [f32],
    /// Levels read.
    pub active: usize,
}

impl DistanceField for HashSdfField<'_> {
    fn distances(&self, points: &[[f32; 3]], out: &mut [f32]) {
        self.net.distances(self.params, points, self.active, out)
    }
    fn gradients(&self, points: &[[f32; 3]], _h: f32, f: &mut [f32], g: &mut [[f32; 3]]) {
        self.net.gradients(self.params, points, self.active, f, g)
    }
}

/// Chunks of points through the network at once, lane by lane.
#[doc(hidden)]
pub mod block;
pub mod objective;
pub mod volume;
