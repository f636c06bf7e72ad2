//! A neural signed distance function trained with an exact eikonal loss
//! (Gropp et al., *Implicit Geometric Regularization*, 2020).
//!
//! The network maps a harmonic encoding of `x` through softplus layers
//! (smooth, so `f` has useful second derivatives) to one number, `f(x)`.
//! The eikonal loss needs `∇f`, and its gradient needs `∂∇f/∂params`: a
//! second derivative. Both are computed exactly, without a tape:
//!
//! - Forward: the values, `z = x·W + b`, `y = act(z)`, keeping each layer's
//!   slope `s = act'(z)`; then, for `∇f`, one reverse pass from the output
//!   (`u = ∂f/∂y`, `δ = s ⊙ u`, `u_prev = δ·Wᵀ`) down to the encoding, and
//!   through the encoding's Jacobian to `x`.
//! - Backward (reverse over reverse): given `∂L/∂f` and `ḡ = ∂L/∂∇f`, the
//!   adjoint of that reverse pass runs forwards through the layers
//!   (`δ̄ = ū_prev·W`, `ū = s ⊙ δ̄`, `z̄ += u ⊙ δ̄ ⊙ act''(z)`), then the
//!   ordinary backward pass of the values carries `z̄` back. Each layer's
//!   weight gradient `yᵀ·z̄ + ū_prevᵀ·δ` is one product over the stacked
//!   rows `[y; ū_prev]`, `[z̄; δ]`; the bias saw only the values, so its
//!   gradient is put right afterwards. Six products of a layer's size per
//!   step (forward-mode tangents need twelve). Every reduction runs in a
//!   fixed order: bit-identical at any thread count.

use rayon::prelude::*;

use super::encoding::Harmonic;
use super::mlp::{softplus_layer, Activation, Dense};
use crate::volume::SplitMix64;

/// Points per parallel block of the elementwise passes and tangent products.
const ROW_BLOCK: usize = 256;
/// Columns per parallel block of the bias sums.
const COL_BLOCK: usize = 16;

/// The shape of an [`SdfNet`].
#[derive(Debug, Clone, PartialEq)]
pub struct SdfNetSpec {
    /// Octaves of the harmonic encoding of the position.
    pub freqs: usize,
    /// Whether the raw position follows the sines and cosines (the
    /// geometric initialisation needs it).
    pub include_input: bool,
    /// Hidden softplus layers, each `width` wide.
    pub layers: usize,
    /// Units per hidden layer.
    pub width: usize,
    /// Hidden layers (in `1..layers`) whose input has the encoding appended.
    pub skips: Vec<usize>,
    /// Softplus sharpness β: large is close to ReLU, still smooth.
    pub beta: f32,
}

impl Default for SdfNetSpec {
    /// IGR's network: 6 × 128, β = 100, the encoding again at layer 3.
    fn default() -> Self {
        SdfNetSpec {
            freqs: 4,
            include_input: true,
            layers: 6,
            width: 128,
            skips: vec![3],
            beta: 100.0,
        }
    }
}

/// The network's layers and where each lives in one flat parameter vector.
#[derive(Debug, Clone)]
pub struct SdfNet {
    /// Of the position: 3 → `encoding.width()` features.
    pub encoding: Harmonic,
    /// Softplus layers; a skip layer's input parts are `[width, encoding]`.
    pub hidden: Vec<Dense>,
    /// Linear, `width → 1`: the signed distance.
    pub output: Dense,
    /// Softplus sharpness of every hidden layer.
    pub beta: f32,
    /// Scalars in the flat parameters (they start at 0).
    pub len: usize,
    /// The hidden layers without activation: softplus and its slope are
    /// applied together from one exponential, and the backward pass forms
    /// the pre-activation adjoints itself; `Dense` does the products.
    linear: Vec<Dense>,
}

impl SdfNet {
    /// Panics on a shape no caller should build (no layers, zero width,
    /// a skip outside `1..layers`, β not positive).
    pub fn new(spec: &SdfNetSpec) -> Self {
        assert!(spec.layers >= 1 && spec.width >= 1, "an empty network");
        assert!(spec.beta > 0.0 && spec.beta.is_finite(), "softplus β > 0");
        assert!(
            spec.skips.iter().all(|&s| (1..spec.layers).contains(&s)),
            "skips name hidden layers 1..{}",
            spec.layers
        );
        let encoding = Harmonic {
            dims: 3,
            freqs: spec.freqs,
            include_input: spec.include_input,
        };
        assert!(encoding.width() > 0, "an empty encoding");
        let (e, w) = (encoding.width(), spec.width);
        let act = Activation::Softplus { beta: spec.beta };
        let mut offset = 0;
        let mut layer = |parts: &[usize], out: usize, act: Activation| {
            let d = Dense::new(parts, out, act, offset);
            offset = d.end();
            d
        };
        let hidden: Vec<Dense> = (0..spec.layers)
            .map(|i| {
                if i == 0 {
                    layer(&[e], w, act)
                } else if spec.skips.contains(&i) {
                    layer(&[w, e], w, act)
                } else {
                    layer(&[w], w, act)
                }
            })
            .collect();
        let output = layer(&[w], 1, Activation::Identity);
        let linear = hidden
            .iter()
            .map(|d| Dense {
                act: Activation::Identity,
                ..d.clone()
            })
            .collect();
        SdfNet {
            encoding,
            hidden,
            output,
            beta: spec.beta,
            len: offset,
            linear,
        }
    }

    /// Units per hidden layer.
    pub fn width(&self) -> usize {
        self.hidden[0].out
    }

    /// Every layer with a stable name.
    pub fn layers(&self) -> Vec<(String, &Dense)> {
        let mut v: Vec<(String, &Dense)> = self
            .hidden
            .iter()
            .enumerate()
            .map(|(i, d)| (format!("hidden.{i}"), d))
            .collect();
        v.push(("output".into(), &self.output));
        v
    }

    /// PyTorch's default initialisation, layer by layer from one seed.
    pub fn init_default(&self, seed: u64) -> Vec<f32> {
        let mut params = vec![0.0; self.len];
        let mut rng = SplitMix64::new(seed ^ 0x7364_666E);
        for (_, d) in self.layers() {
            d.init(&mut params, &mut rng);
        }
        params
    }

    /// The geometric initialisation of Atzmon & Lipman (SAL), as IGR and
    /// IDR use it with a positional encoding, so that `f(x) ≈ |x| − radius`:
    ///
    /// - hidden weights `N(0, 2/width)`, biases 0: with β large, softplus
    ///   is nearly ReLU, and a ReLU network with He-scaled Gaussian weights
    ///   and no biases is positively homogeneous and keeps `‖h(x)‖ ≈ |x|`;
    /// - layer 0 sees only the raw position: the weights of the sines and
    ///   cosines are 0 (training opens them);
    /// - a skip layer's encoding part is 0 as a whole, raw position
    ///   included: IGR divides the concatenation by √2 to keep its norm,
    ///   these layers do not, so they start as plain hidden layers;
    /// - output weights `√π/√width` (± `N(0, 1e-5²)`), bias `−radius`: a
    ///   rectified `N(0, σ²)` unit has mean `σ/√(2π)`, so
    ///   `Σ_i h_i·√π/√width ≈ ‖h_prev‖ ≈ |x|`;
    /// - then, beyond SAL, the output layer's scale and bias are fitted to
    ///   the sphere (`calibrate_sphere`); the hidden layers stay as drawn.
    ///
    /// At 6 × 128 the result is a lumpy sphere: `f` within ≈ 0.06–0.09 of
    /// `|x| − r` on average over `|x| ∈ 0.3..0.7` (r = 0.5), `‖∇f‖` within
    /// ≈ 0.15–0.25 of 1 (finite width: each layer's gain varies with the
    /// direction by ~1/√width).
    ///
    /// Panics without `include_input` (no raw position to start from) or
    /// unless `radius > 0`.
    pub fn init_geometric(&self, seed: u64, radius: f32) -> Vec<f32> {
        assert!(
            self.encoding.include_input,
            "the geometric initialisation needs the raw position in the encoding"
        );
        let mut params = vec![0.0; self.len];
        let mut rng = SplitMix64::new(seed ^ 0x7361_6C69);
        let raw = 2 * 3 * self.encoding.freqs;
        for (i, d) in self.hidden.iter().enumerate() {
            let n = d.out;
            let std = (2.0 / n as f64).sqrt();
            let (w, b) = params[d.offset..d.end()].split_at_mut(d.fan_in() * n);
            for (row, ws) in w.chunks_mut(n).enumerate() {
                // Rows of the encoding: layer 0's sin/cos, a skip's whole part.
                let zero = if i == 0 { row < raw } else { row >= d.parts[0] };
                for v in ws {
                    *v = if zero {
                        0.0
                    } else {
                        (std * normal(&mut rng)) as f32
                    };
                }
            }
            b.fill(0.0);
        }
        let d = &self.output;
        let mean = (std::f64::consts::PI / d.fan_in() as f64).sqrt();
        let (w, b) = params[d.offset..d.end()].split_at_mut(d.fan_in());
        for v in w {
            *v = (mean + 1e-5 * normal(&mut rng)) as f32;
        }
        b[0] = 0.0;
        self.calibrate_sphere(&mut params, radius);
        params
    }

    /// SAL's argument holds in expectation over the weights; one draw at
    /// width 128 leaves `f + r ≈ a + b·|x|` with `b` off by up to ±30 %
    /// and an offset `a` from softplus at small pre-activations (β times
    /// the spread of `z` is only ≈ 4 near `|x| = 0.5`). So the output
    /// layer (bias 0 on entry)
    /// is made affine-exact: `a`, `b` are the least-squares line of `f`
    /// against `|x|` at 512 points (Fibonacci directions, radii
    /// `0.5r..1.5r`), then `w ← w/b`, `bias ← −a/b − r`. What remains is
    /// the draw's variation with direction.
    fn calibrate_sphere(&self, params: &mut [f32], radius: f32) {
        assert!(radius > 0.0 && radius.is_finite(), "a sphere of radius > 0");
        let n = 512;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let mut pts = Vec::with_capacity(3 * n);
        let mut t = Vec::with_capacity(n);
        for i in 0..n {
            let z = 1.0 - (2 * i + 1) as f64 / n as f64;
            let (rho, phi) = ((1.0 - z * z).sqrt(), golden * i as f64);
            let r = radius as f64 * (0.5 + (i % 8) as f64 / 7.0);
            pts.extend([r * rho * phi.cos(), r * rho * phi.sin(), r * z].map(|c| c as f32));
            t.push(r);
        }
        let mut work = SdfWork::default();
        self.forward(params, &pts, &mut work);
        let u = work.distance();
        let nf = n as f64;
        let (mt, mu) = (
            t.iter().sum::<f64>() / nf,
            u.iter().map(|&v| v as f64).sum::<f64>() / nf,
        );
        let (mut cov, mut var) = (0.0, 0.0);
        for (&ti, &ui) in t.iter().zip(u) {
            cov += (ti - mt) * (ui as f64 - mu);
            var += (ti - mt) * (ti - mt);
        }
        let b = cov / var;
        let a = mu - b * mt;
        let d = &self.output;
        let (w, bias) = params[d.offset..d.end()].split_at_mut(d.fan_in());
        if !(b > 0.0 && b.is_finite() && a.is_finite()) {
            // A degenerate draw: leave SAL's output as it is.
            bias[0] = -radius;
            return;
        }
        for v in w {
            *v = (*v as f64 / b) as f32;
        }
        bias[0] = (-a / b - radius as f64) as f32;
    }

    /// `f` alone at `points` (rows of 3) into `out`: a quarter of
    /// [`Self::forward`]'s work (no tangents), for meshing and tracing.
    pub fn distance(&self, params: &[f32], points: &[f32], out: &mut [f32]) {
        assert_eq!(params.len(), self.len, "parameters");
        let rows = points.len() / 3;
        assert_eq!(out.len(), rows, "one distance a point");
        let (e, w, beta) = (self.encoding.width(), self.width(), self.beta);
        let mut enc = vec![0.0; rows * e];
        self.encoding.encode(points, &mut enc);
        let (mut prev, mut next) = (vec![0.0; rows * w], vec![0.0; rows * w]);
        for (i, d) in self.hidden.iter().enumerate() {
            let input: &[f32] = if i == 0 { &enc } else { &prev };
            let lin = &self.linear[i];
            if d.parts.len() == 2 {
                lin.forward(params, &[input, &enc], &mut next);
            } else {
                lin.forward(params, &[input], &mut next);
            }
            next.par_chunks_mut(ROW_BLOCK * w)
                .for_each(|y| softplus_layer(y, None, beta));
            std::mem::swap(&mut prev, &mut next);
        }
        self.output.forward(params, &[&prev], out);
    }

    /// `f` and `∇f` at `points` (rows of 3): in `work.distance()` and
    /// `work.gradient()` (rows × 3); the intermediates stay in `work` for
    /// [`Self::backward`].
    pub fn forward(&self, params: &[f32], points: &[f32], work: &mut SdfWork) {
        assert_eq!(params.len(), self.len, "parameters");
        assert_eq!(points.len() % 3, 0, "rows of 3");
        let rows = points.len() / 3;
        work.resize(self, rows);
        let (e, w, beta, layers) = (
            self.encoding.width(),
            self.width(),
            self.beta,
            self.hidden.len(),
        );
        let SdfWork {
            at,
            enc,
            g_enc,
            act,
            slope,
            up,
            adj,
            out,
            ..
        } = work;
        at.copy_from_slice(points);
        let enc_v = &mut enc[..rows * e];
        self.encoding.encode(points, enc_v);
        let enc_v = &*enc_v;
        // Values: y = softplus(z) and s = σ(βz) from one exponential.
        for (i, d) in self.hidden.iter().enumerate() {
            let (before, rest) = act.split_at_mut(i);
            let y = &mut rest[0][..rows * w];
            let prev: &[f32] = if i == 0 {
                enc_v
            } else {
                &before[i - 1][..rows * w]
            };
            let lin = &self.linear[i];
            if d.parts.len() == 2 {
                lin.forward(params, &[prev, enc_v], y);
            } else {
                lin.forward(params, &[prev], y);
            }
            y.par_chunks_mut(ROW_BLOCK * w)
                .zip(slope[i].par_chunks_mut(ROW_BLOCK * w))
                .for_each(|(y, s)| softplus_layer(y, Some(s), beta));
        }
        let (f, g) = out.split_at_mut(rows);
        self.output
            .forward(params, &[&act[layers - 1][..rows * w]], f);
        // ∇f: u = ∂f/∂y is the output's weights in every row of the last
        // layer; δ = s ⊙ u; u_prev = δ·Wᵀ, the skip layers' and the first
        // layer's encoding parts adding up in g_enc = ∂f/∂enc.
        let w_out = &params[self.output.offset..self.output.offset + w];
        up[layers - 1][..rows * w]
            .par_chunks_mut(w)
            .for_each(|u| u.copy_from_slice(w_out));
        g_enc.fill(0.0);
        for i in (0..layers).rev() {
            let delta = &mut adj[i][rows * w..];
            delta
                .par_chunks_mut(ROW_BLOCK * w)
                .zip(slope[i].par_chunks(ROW_BLOCK * w))
                .zip(up[i].par_chunks(ROW_BLOCK * w))
                .for_each(|((d, s), u)| {
                    for ((d, s), u) in d.iter_mut().zip(s).zip(u) {
                        *d = s * u;
                    }
                });
            let delta = &adj[i][rows * w..];
            let lin = &self.linear[i];
            let (below, _) = up.split_at_mut(i);
            if i == 0 {
                lin.pull_back(params, delta, &mut [Some(g_enc.as_mut_slice())], true);
            } else if lin.parts.len() == 2 {
                let u_prev = &mut below[i - 1];
                u_prev.fill(0.0);
                let mut d_in = [Some(u_prev.as_mut_slice()), Some(g_enc.as_mut_slice())];
                lin.pull_back(params, delta, &mut d_in, true);
            } else {
                let mut d_in = [Some(below[i - 1].as_mut_slice())];
                lin.pull_back(params, delta, &mut d_in, false);
            }
        }
        self.encoding.backward(points, g_enc, g);
    }

    /// Adds `∂L/∂params` to `grad` given `∂L/∂f` (rows) and `∂L/∂∇f`
    /// (rows × 3), after [`Self::forward`] on `work`.
    pub fn backward(
        &self,
        params: &[f32],
        d_f: &[f32],
        d_grad: &[f32],
        work: &mut SdfWork,
        grad: &mut [f32],
    ) {
        let rows = work.rows;
        assert_eq!((d_f.len(), d_grad.len()), (rows, 3 * rows), "adjoints");
        work.d_out[..rows].copy_from_slice(d_f);
        work.d_out[rows..].copy_from_slice(d_grad);
        self.backward_from_work(params, work, grad);
    }

    /// The backward pass from the adjoints in `work.d_out`.
    fn backward_from_work(&self, params: &[f32], work: &mut SdfWork, grad: &mut [f32]) {
        assert_eq!(grad.len(), self.len, "gradient");
        let (rows, e, w, beta, layers) = (
            work.rows,
            self.encoding.width(),
            self.width(),
            self.beta,
            self.hidden.len(),
        );
        if rows == 0 {
            return;
        }
        let SdfWork {
            at,
            enc,
            act,
            slope,
            up,
            adj,
            d_out,
            d_last,
            tmp,
            bias_keep,
            bias_sum,
            ..
        } = work;
        let (d_f, d_g) = d_out.split_at(rows);
        // The adjoint of ∇f's reverse pass, forwards: ḡ_enc = J·ḡ, then per
        // layer δ̄ = ū_prev·W (the encoding part: ḡ_enc), ū = s ⊙ δ̄ and
        // z̄ = u ⊙ δ̄ ⊙ β·s·(1 − s).
        encode_pushforward(&self.encoding, at, d_g, &mut enc[rows * e..]);
        let enc_bar = &enc[rows * e..];
        for i in 0..layers {
            let lin = &self.linear[i];
            let (before, rest) = act.split_at_mut(i);
            if i == 0 {
                lin.linear(params, &[enc_bar], tmp);
            } else if lin.parts.len() == 2 {
                lin.linear(params, &[&before[i - 1][rows * w..], enc_bar], tmp);
            } else {
                lin.linear(params, &[&before[i - 1][rows * w..]], tmp);
            }
            let u_bar = &mut rest[0][rows * w..];
            let z_bar = &mut adj[i][..rows * w];
            u_bar
                .par_chunks_mut(ROW_BLOCK * w)
                .zip(z_bar.par_chunks_mut(ROW_BLOCK * w))
                .zip(slope[i].par_chunks(ROW_BLOCK * w))
                .zip(
                    up[i]
                        .par_chunks(ROW_BLOCK * w)
                        .zip(tmp.par_chunks(ROW_BLOCK * w)),
                )
                .for_each(|(((ub, zb), s), (u, t))| {
                    for c in 0..ub.len() {
                        let s = s[c];
                        ub[c] = s * t[c];
                        zb[c] = u[c] * t[c] * beta * s * (1.0 - s);
                    }
                });
        }
        // The output layer: ∂L/∂w_out = yᵀ·∂L/∂f + Σ_rows ū (u = w_out in
        // every row of the last layer), one product over the stacked rows
        // [y; ū] and [∂L/∂f; 1]; ∂L/∂b; and ā = ∂L/∂y (in tmp).
        let last = &act[layers - 1];
        d_last[..rows].copy_from_slice(d_f);
        d_last[rows..].fill(1.0);
        let out_bias = self.output.offset + w;
        bias_keep.clear();
        bias_keep.extend_from_slice(&grad[out_bias..out_bias + 1]);
        self.output
            .weight_gradient(&[last.as_slice()], d_last, grad);
        value_bias(&self.output, d_last, rows, bias_keep, bias_sum, grad);
        self.output
            .pull_back(params, d_f, &mut [Some(tmp.as_mut_slice())], false);
        // The values' backward pass, carrying z̄: per layer z̄ += ā ⊙ s, one
        // weight gradient over the stacked rows, then ā_prev = z̄·Wᵀ.
        for i in (0..layers).rev() {
            let lin = &self.linear[i];
            let z_bar = &mut adj[i][..rows * w];
            z_bar
                .par_chunks_mut(ROW_BLOCK * w)
                .zip(tmp.par_chunks(ROW_BLOCK * w))
                .zip(slope[i].par_chunks(ROW_BLOCK * w))
                .for_each(|((zb, a), s)| {
                    for ((zb, a), s) in zb.iter_mut().zip(a).zip(s) {
                        *zb += a * s;
                    }
                });
            let stacked = &adj[i];
            bias_keep.clear();
            bias_keep.extend_from_slice(&grad[lin.offset + lin.fan_in() * w..lin.end()]);
            if i == 0 {
                lin.weight_gradient(&[enc.as_slice()], stacked, grad);
            } else if lin.parts.len() == 2 {
                lin.weight_gradient(&[act[i - 1].as_slice(), enc.as_slice()], stacked, grad);
            } else {
                lin.weight_gradient(&[act[i - 1].as_slice()], stacked, grad);
            }
            value_bias(lin, stacked, rows, bias_keep, bias_sum, grad);
            if i > 0 {
                let z_bar = &adj[i][..rows * w];
                let mut d_in: Vec<Option<&mut [f32]>> = vec![Some(tmp.as_mut_slice())];
                if lin.parts.len() == 2 {
                    d_in.push(None);
                }
                lin.pull_back(params, z_bar, &mut d_in, false);
            }
        }
    }

    /// The training loss at `surface` points (on the shape) and `random`
    /// points (in the volume), both rows of 3:
    /// `surface·mean|f| + eikonal·mean(‖∇f‖ − 1)² + inter·mean e^{−α|f|}`,
    /// with the eikonal mean over both sets together and the other two over
    /// their own set. Overwrites `grad` with `∂L/∂params`.
    pub fn loss_and_grad(
        &self,
        params: &[f32],
        surface: &[f32],
        random: &[f32],
        weights: &SdfLoss,
        work: &mut SdfWork,
        grad: &mut [f32],
    ) -> f64 {
        assert_eq!(grad.len(), self.len, "gradient");
        assert_eq!((surface.len() % 3, random.len() % 3), (0, 0), "rows of 3");
        let ns = surface.len() / 3;
        // One pass over both sets.
        let mut points = std::mem::take(&mut work.points);
        points.clear();
        points.extend_from_slice(surface);
        points.extend_from_slice(random);
        self.forward(params, &points, work);
        work.points = points;
        let rows = work.rows;
        let (f, g) = work.out.split_at(rows);
        let (d_f, d_g) = work.d_out.split_at_mut(rows);
        let (d_fs, d_fr) = d_f.split_at_mut(ns);
        let loss = surface_loss(&f[..ns], weights.surface, d_fs)
            + off_surface_loss(&f[ns..], weights.inter, weights.alpha, d_fr)
            + eikonal_loss(g, weights.eikonal, d_g);
        grad.fill(0.0);
        self.backward_from_work(params, work, grad);
        loss
    }
}

/// The weights of [`SdfNet::loss_and_grad`]'s terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SdfLoss {
    /// Of `mean|f|` at the surface points.
    pub surface: f32,
    /// Of `mean(‖∇f‖ − 1)²` at all points.
    pub eikonal: f32,
    /// Of the off-surface term `e^{−α|f|}`, which keeps `f` away from 0
    /// off the shape.
    pub inter: f32,
    /// The off-surface term's falloff.
    pub alpha: f32,
}

impl Default for SdfLoss {
    fn default() -> Self {
        SdfLoss {
            surface: 1.0,
            eikonal: 0.02,
            inter: 0.1,
            alpha: 100.0,
        }
    }
}

/// Saturates at the f32 range: a finite loss gives finite adjoints.
fn to_f32(x: f64) -> f32 {
    x.clamp(-f32::MAX as f64, f32::MAX as f64) as f32
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

/// `weight·mean|f|`; writes `∂/∂f = weight·sign(f)/n` (0 at `f = 0`).
pub fn surface_loss(f: &[f32], weight: f32, d_f: &mut [f32]) -> f64 {
    assert_eq!(f.len(), d_f.len());
    let n = f.len().max(1) as f64;
    let k = weight as f64 / n;
    let mut sum = 0.0;
    for (d, &v) in d_f.iter_mut().zip(f) {
        sum += (v as f64).abs();
        *d = to_f32(k * sign(v as f64));
    }
    k * sum
}

/// `weight·mean e^{−α|f|}`; writes `∂/∂f = −α·sign(f)·e^{−α|f|}·weight/n`.
pub fn off_surface_loss(f: &[f32], weight: f32, alpha: f32, d_f: &mut [f32]) -> f64 {
    assert_eq!(f.len(), d_f.len());
    let n = f.len().max(1) as f64;
    let (k, a) = (weight as f64 / n, alpha as f64);
    let mut sum = 0.0;
    for (d, &v) in d_f.iter_mut().zip(f) {
        let v = v as f64;
        let e = (-a * v.abs()).exp();
        sum += e;
        *d = to_f32(-k * a * sign(v) * e);
    }
    k * sum
}

/// `weight·mean(‖g‖ − 1)²` over rows of 3; writes
/// `∂/∂g = 2·(‖g‖ − 1)·g/‖g‖·weight/n`. Norms in f64, so no f32 input
/// overflows. At `g = 0` the direction is undefined and the adjoint is 0:
/// the least-norm element of the Clarke subdifferential there (the ball of
/// radius 2); the loss is still 1 per row. Adjoints saturate at ±f32::MAX
/// (for `‖g‖` near it), so a finite loss never writes an infinite one.
pub fn eikonal_loss(g: &[f32], weight: f32, d_g: &mut [f32]) -> f64 {
    assert_eq!(g.len(), d_g.len());
    assert_eq!(g.len() % 3, 0, "rows of 3");
    let n = (g.len() / 3).max(1) as f64;
    let k = weight as f64 / n;
    let mut sum = 0.0;
    for (d, g) in d_g.chunks_mut(3).zip(g.chunks(3)) {
        let v = [g[0] as f64, g[1] as f64, g[2] as f64];
        let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        sum += (norm - 1.0) * (norm - 1.0);
        let scale = if norm > 0.0 {
            2.0 * k * (1.0 - 1.0 / norm)
        } else {
            0.0
        };
        for (d, v) in d.iter_mut().zip(v) {
            *d = to_f32(scale * v);
        }
    }
    k * sum
}

/// `out = J(x)·v` per row: the encoding's Jacobian (width × 3) applied to
/// `v` (rows × 3), the transpose of [`Harmonic::backward`]. Only the
/// features of `x_j` move with it: `2^k cos`, `−2^k sin`, and 1 for the raw
/// input.
#[doc(hidden)]
pub fn encode_pushforward(h: &Harmonic, points: &[f32], v: &[f32], out: &mut [f32]) {
    let (f, e) = (h.freqs, h.width());
    assert_eq!(out.len(), points.len() / 3 * e);
    out.par_chunks_mut(ROW_BLOCK * e)
        .zip(points.par_chunks(ROW_BLOCK * 3))
        .zip(v.par_chunks(ROW_BLOCK * 3))
        .for_each(|((o, p), v)| {
            for ((row, x), v) in o.chunks_mut(e).zip(p.chunks(3)).zip(v.chunks(3)) {
                for j in 0..3 {
                    let mut scale = 1.0f32;
                    for k in 0..f {
                        let (s, c) = (x[j] * scale).sin_cos();
                        row[j * f + k] = v[j] * scale * c;
                        row[3 * f + j * f + k] = -v[j] * scale * s;
                        scale *= 2.0;
                    }
                    if h.include_input {
                        row[6 * f + j] = v[j];
                    }
                }
            }
        });
}

/// Column sums of `m` (rows of `cols`) in f64, rows in order, per block of
/// columns (the same at any thread count).
fn column_sums(m: &[f32], cols: usize, sums: &mut Vec<f64>) {
    sums.clear();
    sums.resize(cols, 0.0);
    sums.par_chunks_mut(COL_BLOCK)
        .enumerate()
        .for_each(|(blk, s)| {
            let c0 = blk * COL_BLOCK;
            for r in m.chunks(cols) {
                for (s, &v) in s.iter_mut().zip(&r[c0..]) {
                    *s += v as f64;
                }
            }
        });
}

/// [`Dense::weight_gradient`] over the stacked rows added the
/// second-order rows' `δ` to `∂L/∂b` too; the bias reaches only the values:
/// `∂L/∂b` becomes what it held before (`keep`) plus the sum of the value
/// rows' `z̄` (the first `rows`).
fn value_bias(
    d: &Dense,
    dz: &[f32],
    rows: usize,
    keep: &[f32],
    sums: &mut Vec<f64>,
    grad: &mut [f32],
) {
    let n = d.out;
    column_sums(&dz[..rows * n], n, sums);
    let gb = &mut grad[d.offset + d.fan_in() * n..d.end()];
    for ((g, &k), &s) in gb.iter_mut().zip(keep).zip(sums.iter()) {
        *g = k + s as f32;
    }
}

/// A standard normal sample (Box–Muller).
#[doc(hidden)]
pub fn normal(rng: &mut SplitMix64) -> f64 {
    let unit = |rng: &mut SplitMix64| (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
    let u = 1.0 - unit(rng); // in (0, 1]: ln stays finite
    let v = unit(rng);
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// Buffers of a forward and backward pass, grown to the largest batch seen
/// (no allocation once grown).
#[derive(Debug, Default)]
pub struct SdfWork {
    rows: usize,
    /// Both point sets of a loss, one after the other.
    points: Vec<f32>,
    /// The points of the last forward pass.
    at: Vec<f32>,
    /// The encoding (rows × e), then `ḡ_enc = J·ḡ` (rows × e).
    enc: Vec<f32>,
    /// `∂f/∂enc` (rows × e).
    g_enc: Vec<f32>,
    /// Per hidden layer: values `y` (rows × w), then `ū` (rows × w).
    act: Vec<Vec<f32>>,
    /// Per hidden layer: the slopes `σ(βz)` (rows × w).
    slope: Vec<Vec<f32>>,
    /// Per hidden layer: `u = ∂f/∂y` (rows × w).
    up: Vec<Vec<f32>>,
    /// Per hidden layer: `z̄` (rows × w), then `δ = ∂f/∂z` (rows × w).
    adj: Vec<Vec<f32>>,
    /// `f` (rows) then `∇f` (rows × 3).
    out: Vec<f32>,
    /// `∂L/∂f` (rows) then `∂L/∂∇f` (rows × 3).
    d_out: Vec<f32>,
    /// `∂L/∂f` (rows), then ones (rows): the output layer's stacked `dz`.
    d_last: Vec<f32>,
    /// `δ̄`, then `ā`, of one layer (rows × w).
    tmp: Vec<f32>,
    bias_keep: Vec<f32>,
    bias_sum: Vec<f64>,
}

impl SdfWork {
    fn resize(&mut self, net: &SdfNet, rows: usize) {
        let (e, w, l) = (net.encoding.width(), net.width(), net.hidden.len());
        self.rows = rows;
        let set = |v: &mut Vec<f32>, n: usize| v.resize(n, 0.0);
        set(&mut self.at, 3 * rows);
        set(&mut self.enc, 2 * rows * e);
        set(&mut self.g_enc, rows * e);
        for v in [&mut self.act, &mut self.slope, &mut self.up, &mut self.adj] {
            v.resize_with(l, Vec::new);
        }
        for i in 0..l {
            set(&mut self.act[i], 2 * rows * w);
            set(&mut self.slope[i], rows * w);
            set(&mut self.up[i], rows * w);
            set(&mut self.adj[i], 2 * rows * w);
        }
        set(&mut self.out, 4 * rows);
        set(&mut self.d_out, 4 * rows);
        set(&mut self.d_last, 2 * rows);
        set(&mut self.tmp, rows * w);
    }

    /// `f` at the points of the last forward pass.
    pub fn distance(&self) -> &[f32] {
        &self.out[..self.rows]
    }

    /// `∇f` (rows × 3) at the points of the last forward pass.
    pub fn gradient(&self) -> &[f32] {
        &self.out[self.rows..4 * self.rows]
    }
}
