//! Fully connected layers as fused CPU kernels over row-major batches.
//!
//! A [`Dense`] layer maps `rows × Σ parts` inputs to `rows × out` outputs,
//! `y = act(Σ_p x_p·W_p + b)`: its input may come in several parts (a skip
//! connection appends the encoded position to a hidden layer) without
//! copying them into one matrix. The forward pass runs the matrix product
//! and the bias and activation per block of rows while the block is in
//! cache; the backward pass turns the output's adjoint into the
//! pre-activation adjoint in place, then computes the inputs' adjoints per
//! block of rows and the weight gradient as partial `Xᵀ·dZ` products over
//! fixed blocks of rows added in order, so every gradient is reduced in a
//! fixed order:
//! results are bit-identical whatever the thread count.
//!
//! With [`Precision::Bf16`] the forward product and the input adjoints'
//! `dZ·Wᵀ` run in bf16 with fp32 sums ([`super::bf16`]) where the CPU has
//! AVX-512 BF16 and the part is at least [`BF16_MIN`] wide both ways (a
//! narrower product gains nothing from the packing), and so does the
//! weight gradient's `Xᵀ·dZ` (bf16 products summed in fp32 over each
//! block of rows; the blocks are still added in f64, in order).
//!
//! Weights are stored `in × out` (row `i` holds input `i`'s weights), so
//! `x·W` needs no transpose; PyTorch's `out × in` is the same numbers
//! transposed.

use rayon::prelude::*;

use sdfl_stdlib::value::Precision;

use super::bf16::{self, Kernel, Packed};
use super::fp32::{self, Strided};
use crate::volume::SplitMix64;

/// Rows per block of the forward and input-adjoint passes.
pub const ROW_BLOCK: usize = 1024;
/// Rows per block of the weight-gradient pass (each block's partial sums
/// are added in block order, so the result does not depend on threads).
const GRAD_ROWS: usize = 4096;
/// Narrowest input part and output of a product run in bf16.
pub const BF16_MIN: usize = 16;

/// A pointwise nonlinearity after a layer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Activation {
    /// `x`: a linear layer.
    Identity,
    /// `max(x, 0)`.
    Relu,
    /// `1 / (1 + e^−x)`.
    Sigmoid,
    /// `ln(1 + e^(βx))/β`, computed without overflow.
    Softplus {
        /// Sharpness: large is close to ReLU.
        beta: f32,
    },
    /// `e^min(x, 15)`: a density that never dies at initialisation
    /// (instant-ngp's truncated exponential); no gradient above the cap.
    Exp,
}

/// The cap of [`Activation::Exp`]'s argument.
pub const EXP_CAP: f32 = 15.0;

impl Activation {
    /// The activation at `z`.
    #[inline(always)]
    pub fn apply(self, z: f32) -> f32 {
        match self {
            Activation::Identity => z,
            Activation::Relu => z.max(0.0),
            Activation::Sigmoid => sigmoid(z),
            Activation::Softplus { beta } => softplus(z, beta),
            Activation::Exp => z.min(EXP_CAP).exp(),
        }
    }

    /// `act'(z)` from the output `y = act(z)` alone, so the backward pass
    /// needs no pre-activations: for softplus `σ(βz) = 1 − e^{−βy}`
    /// (through `exp_m1`, exact for tiny `y`).
    #[inline(always)]
    pub fn slope(self, y: f32) -> f32 {
        match self {
            Activation::Identity => 1.0,
            Activation::Relu => {
                if y > 0.0 {
                    1.0
                } else {
                    0.0
                }
            }
            Activation::Sigmoid => y * (1.0 - y),
            Activation::Softplus { beta } => -(-beta * y).exp_m1(),
            Activation::Exp => {
                if y < EXP_CAP.exp() {
                    y
                } else {
                    0.0
                }
            }
        }
    }
}

/// The logistic function, exact to f32 rounding for every input.
#[inline(always)]
pub fn sigmoid(z: f32) -> f32 {
    if z >= 0.0 {
        1.0 / (1.0 + (-z).exp())
    } else {
        let e = z.exp();
        e / (1.0 + e)
    }
}

/// `ln(1 + e^(βz))/β` without overflow for large `βz`.
#[inline(always)]
pub fn softplus(z: f32, beta: f32) -> f32 {
    softplus_and_slope(z, beta).0
}

/// `softplus(z) = (max(βz, 0) + ln(1 + e^{−|βz|}))/β` (no overflow) and its
/// slope `σ(βz)`, from one exponential. Branch-free, with sdfl's own `exp`
/// and `ln(1 + e)`, so a loop over a layer's outputs vectorises.
#[inline(always)]
pub fn softplus_and_slope(z: f32, beta: f32) -> (f32, f32) {
    softplus_scaled(z, beta, 1.0 / beta)
}

/// [`softplus_and_slope`] given `1/β` too (a product instead of a
/// division in a loop over a layer).
#[inline(always)]
fn softplus_scaled(z: f32, beta: f32, inv_beta: f32) -> (f32, f32) {
    use sdfl_stdlib::num::{exp_f32, ln_1p_unit_f32};
    let t = beta * z;
    let e = exp_f32(-t.abs());
    let s = if t >= 0.0 { 1.0 } else { e } / (1.0 + e);
    ((t.max(0.0) + ln_1p_unit_f32(e)) * inv_beta, s)
}

crate::lanes::widest_simd!(
    /// [`softplus_and_slope`] of every `y` in place, its slope into `slope`
    /// where given (as long as `y`). Compiled with AVX-512 or AVX2 where the
    /// CPU has them (16 or 8 lanes instead of SSE's 4; the same operations,
    /// so the same bits).
    pub fn softplus_layer(y: &mut [f32], slope: Option<&mut [f32]>, beta: f32) -> () = softplus_lanes
);

/// The loop of [`softplus_layer`].
#[inline(always)]
fn softplus_lanes(y: &mut [f32], slope: Option<&mut [f32]>, beta: f32) {
    let inv_beta = 1.0 / beta;
    match slope {
        Some(s) => {
            assert_eq!(s.len(), y.len(), "one slope a value");
            for (y, s) in y.iter_mut().zip(s) {
                (*y, *s) = softplus_scaled(*y, beta, inv_beta);
            }
        }
        None => {
            for y in y {
                *y = softplus_scaled(*y, beta, inv_beta).0;
            }
        }
    }
}

/// One layer's shape and where its weights live in the flat parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Dense {
    /// Widths of the input parts, in order.
    pub parts: Vec<usize>,
    /// Output width.
    pub out: usize,
    /// The nonlinearity after the products.
    pub act: Activation,
    /// Offset of `W` (`Σ parts × out`) in the flat parameters; `b` follows.
    pub offset: usize,
    /// Number format of the layer's matrix products.
    pub precision: Precision,
    /// Where its fp32 products run.
    pub products: Products,
}

/// Where a layer's fp32 products run: both give the same sums up to
/// rounding, each the same bits at any thread count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Products {
    /// [`fp32`]'s AVX-512 register tiles, reading the operands in place.
    Native,
    /// matrixmultiply (packs both operands; any CPU).
    Portable,
}

impl Products {
    /// The native kernel where this CPU runs it.
    pub fn detect() -> Self {
        if fp32::available() {
            Products::Native
        } else {
            Products::Portable
        }
    }
}

impl Dense {
    /// A layer from inputs of widths `parts` to `out` units, its parameters
    /// at `offset` in the flat vector.
    pub fn new(parts: &[usize], out: usize, act: Activation, offset: usize) -> Self {
        Dense {
            parts: parts.to_vec(),
            out,
            act,
            offset,
            precision: Precision::Fp32,
            products: Products::detect(),
        }
    }

    /// The layer with its products in `precision`.
    pub fn with_precision(self, precision: Precision) -> Self {
        Dense { precision, ..self }
    }

    /// The layer with its fp32 products run by `products`.
    pub fn with_products(self, products: Products) -> Self {
        Dense { products, ..self }
    }

    /// Whether the fp32 products run natively.
    fn native(&self) -> bool {
        self.products == Products::Native
    }

    /// The bf16 kernel for a product of width `k` into `n`, if it runs in
    /// bf16 here (see the module docs).
    fn bf16_kernel(&self, k: usize, n: usize) -> Option<Kernel> {
        if self.precision == Precision::Bf16 && k >= BF16_MIN && n >= BF16_MIN {
            Kernel::native()
        } else {
            None
        }
    }

    /// Per part, `W_p` packed for the bf16 kernel where it runs in bf16.
    fn packed_forward(&self, w: &[f32]) -> Vec<Option<(Kernel, Packed)>> {
        let n = self.out;
        let mut w_row = 0;
        self.parts
            .iter()
            .map(|&k| {
                let p = self
                    .bf16_kernel(k, n)
                    .map(|kern| (kern, Packed::new(&w[w_row * n..], k, n, n, 1)));
                w_row += k;
                p
            })
            .collect()
    }

    /// Input width: the parts together.
    pub fn fan_in(&self) -> usize {
        self.parts.iter().sum()
    }

    /// Scalars of `W` and `b`.
    pub fn len(&self) -> usize {
        (self.fan_in() + 1) * self.out
    }

    /// Whether it has no parameters.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Offset just past this layer's parameters.
    pub fn end(&self) -> usize {
        self.offset + self.len()
    }

    /// `W` and `b` as the trainer's named tensors (`name.weight`, `name.bias`).
    pub fn tensors(&self, name: &str) -> [crate::train::TensorSpec; 2] {
        let w = self.fan_in() * self.out;
        [
            crate::train::TensorSpec {
                name: format!("{name}.weight"),
                offset: self.offset,
                len: w,
            },
            crate::train::TensorSpec {
                name: format!("{name}.bias"),
                offset: self.offset + w,
                len: self.out,
            },
        ]
    }

    fn weights<'p>(&self, params: &'p [f32]) -> &'p [f32] {
        &params[self.offset..self.offset + self.fan_in() * self.out]
    }

    fn bias<'p>(&self, params: &'p [f32]) -> &'p [f32] {
        &params[self.offset + self.fan_in() * self.out..self.end()]
    }

    /// PyTorch's default initialisation of `nn.Linear`: `W` and `b` uniform
    /// in `±1/√fan_in`, written into `params`.
    pub fn init(&self, params: &mut [f32], rng: &mut SplitMix64) {
        let bound = 1.0 / (self.fan_in().max(1) as f32).sqrt();
        for p in &mut params[self.offset..self.end()] {
            *p = (2.0 * rng.next_f32() - 1.0) * bound;
        }
    }

    /// `out = act(Σ x_p·W_p + b)` for `rows` rows; `inputs[p]` is
    /// `rows × parts[p]`.
    pub fn forward(&self, params: &[f32], inputs: &[&[f32]], out: &mut [f32]) {
        let n = self.out;
        let rows = out.len() / n;
        self.check(inputs, rows);
        let (w, b) = (self.weights(params), self.bias(params));
        let packed = self.packed_forward(w);
        out.par_chunks_mut(ROW_BLOCK * n)
            .enumerate()
            .for_each(|(blk, y)| {
                self.product_block(w, &packed, inputs, blk * ROW_BLOCK, y);
                for yr in y.chunks_mut(n) {
                    for (yv, bv) in yr.iter_mut().zip(b) {
                        *yv = self.act.apply(*yv + bv);
                    }
                }
            });
    }

    /// `out = Σ_p x_p·W_p`: the layer without bias or activation (the
    /// pushforward of tangents through it).
    pub fn linear(&self, params: &[f32], inputs: &[&[f32]], out: &mut [f32]) {
        let rows = out.len() / self.out;
        self.check(inputs, rows);
        let w = self.weights(params);
        let packed = self.packed_forward(w);
        out.par_chunks_mut(ROW_BLOCK * self.out)
            .enumerate()
            .for_each(|(blk, y)| self.product_block(w, &packed, inputs, blk * ROW_BLOCK, y));
    }

    /// `y = Σ_p x_p·W_p` for the block of rows from `r0` (`y` holds them).
    #[inline]
    fn product_block(
        &self,
        w: &[f32],
        packed: &[Option<(Kernel, Packed)>],
        inputs: &[&[f32]],
        r0: usize,
        y: &mut [f32],
    ) {
        let n = self.out;
        let m = y.len() / n;
        let mut w_row = 0;
        for (p, (&k, x)) in self.parts.iter().zip(inputs).enumerate() {
            if let Some((kernel, wp)) = &packed[p] {
                bf16::matmul(*kernel, m, &x[r0 * k..], k, wp, y, n, p > 0);
                w_row += k;
                continue;
            }
            if self.native() {
                let a = Strided::row_major(&x[r0 * k..], k);
                fp32::matmul(m, k, n, a, &w[w_row * n..], n, y, n, p > 0);
                w_row += k;
                continue;
            }
            // SAFETY: x holds rows × k (checked by the caller), w rows
            // w_row..w_row+k of n columns, y m × n; all row-major.
            unsafe {
                matrixmultiply::sgemm(
                    m,
                    k,
                    n,
                    1.0,
                    x[r0 * k..].as_ptr(),
                    k as isize,
                    1,
                    w[w_row * n..].as_ptr(),
                    n as isize,
                    1,
                    if p == 0 { 0.0 } else { 1.0 },
                    y.as_mut_ptr(),
                    n as isize,
                    1,
                );
            }
            w_row += k;
        }
    }

    fn check(&self, inputs: &[&[f32]], rows: usize) {
        assert_eq!(inputs.len(), self.parts.len(), "input parts");
        for (x, &k) in inputs.iter().zip(&self.parts) {
            assert_eq!(x.len(), rows * k, "input part of width {k}");
        }
    }

    /// The backward pass. `d_out` holds `∂L/∂out` and is overwritten with
    /// the pre-activation adjoint; `out` is the forward pass's. Each `d_inputs[p]` that is given
    /// receives `∂L/∂x_p`, added to what it holds when `accumulate`; `grad`
    /// (the flat gradient of all parameters) gets this layer's `∂L/∂W`,
    /// `∂L/∂b` added.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        params: &[f32],
        inputs: &[&[f32]],
        out: &[f32],
        d_out: &mut [f32],
        d_inputs: &mut [Option<&mut [f32]>],
        accumulate: bool,
        grad: &mut [f32],
    ) {
        let n = self.out;
        let rows = out.len() / n;
        self.check(inputs, rows);
        assert_eq!(d_out.len(), out.len());
        assert_eq!(d_inputs.len(), self.parts.len());
        let act = self.act;
        // dZ = dY ⊙ act'(z), in place.
        if act != Activation::Identity {
            d_out
                .par_chunks_mut(ROW_BLOCK * n)
                .zip(out.par_chunks(ROW_BLOCK * n))
                .for_each(|(dz, y)| {
                    for (d, &yv) in dz.iter_mut().zip(y) {
                        *d *= act.slope(yv);
                    }
                });
        }
        self.pull_back(params, d_out, d_inputs, accumulate);
        self.weight_gradient(inputs, d_out, grad);
    }

    /// `∂L/∂x_p = dZ·W_pᵀ` into each given `d_inputs[p]` (added to what it
    /// holds when `accumulate`), from the pre-activation adjoint `dz`
    /// (rows × out); per block of rows.
    pub fn pull_back(
        &self,
        params: &[f32],
        dz: &[f32],
        d_inputs: &mut [Option<&mut [f32]>],
        accumulate: bool,
    ) {
        let n = self.out;
        let rows = dz.len() / n;
        assert_eq!(d_inputs.len(), self.parts.len());
        let w = self.weights(params);
        // ∂L/∂x_p = dZ·W_pᵀ, per block of rows.
        let mut w_row = 0;
        for (p, &k) in self.parts.iter().enumerate() {
            if let Some(dx) = d_inputs[p].as_deref_mut() {
                assert_eq!(dx.len(), rows * k);
                let wp = &w[w_row * n..(w_row + k) * n];
                // Wᵀ (n × k) for the bf16 kernel: W_p read by columns.
                let packed = self
                    .bf16_kernel(n, k)
                    .map(|kern| (kern, Packed::new(wp, n, k, 1, n)));
                // Wᵀ (n × k) row-major for the fp32 kernel.
                let wt: Vec<f32> = if packed.is_none() && self.native() {
                    (0..n * k).map(|i| wp[(i % k) * n + i / k]).collect()
                } else {
                    Vec::new()
                };
                dx.par_chunks_mut(ROW_BLOCK * k)
                    .enumerate()
                    .for_each(|(blk, dxb)| {
                        let m = dxb.len() / k;
                        if let Some((kernel, wt)) = &packed {
                            let a = &dz[blk * ROW_BLOCK * n..];
                            bf16::matmul(*kernel, m, a, n, wt, dxb, k, accumulate);
                            return;
                        }
                        if !wt.is_empty() {
                            let a = Strided::row_major(&dz[blk * ROW_BLOCK * n..], n);
                            fp32::matmul(m, n, k, a, &wt, k, dxb, k, accumulate);
                            return;
                        }
                        // SAFETY: dz rows from blk·ROW_BLOCK, m × n; wp is
                        // k × n read transposed (n × k); dxb m × k.
                        unsafe {
                            matrixmultiply::sgemm(
                                m,
                                n,
                                k,
                                1.0,
                                dz[blk * ROW_BLOCK * n..].as_ptr(),
                                n as isize,
                                1,
                                wp.as_ptr(),
                                1,
                                n as isize,
                                if accumulate { 1.0 } else { 0.0 },
                                dxb.as_mut_ptr(),
                                k as isize,
                                1,
                            );
                        }
                    });
            }
            w_row += k;
        }
    }

    /// Adds `∂L/∂W_p = x_pᵀ·dZ` and `∂L/∂b = Σ_rows dZ` to `grad`, from the
    /// pre-activation adjoint `dz` (rows × out) and the layer's inputs.
    pub fn weight_gradient(&self, inputs: &[&[f32]], dz: &[f32], grad: &mut [f32]) {
        let n = self.out;
        let rows = dz.len() / n;
        self.check(inputs, rows);
        // ∂L/∂W_p = x_pᵀ·dZ and ∂L/∂b = Σ_rows dZ: partial sums over fixed
        // blocks of rows (each operand packed once), added in block order.
        let fan_in = self.fan_in();
        let len = (fan_in + 1) * n;
        let partials: Vec<Vec<f32>> = (0..rows.div_ceil(GRAD_ROWS))
            .into_par_iter()
            .map(|blk| {
                let r0 = blk * GRAD_ROWS;
                let m = GRAD_ROWS.min(rows - r0);
                let mut part = vec![0f32; len];
                // dZ's rows packed for the bf16 kernel, once for all parts.
                let dz_block = &dz[r0 * n..(r0 + m) * n];
                let mut dz_packed: Option<Packed> = None;
                let mut w_row = 0;
                for (&k, x) in self.parts.iter().zip(inputs) {
                    if let Some(kernel) = self.bf16_kernel(k, n) {
                        let dzp =
                            dz_packed.get_or_insert_with(|| Packed::new(dz_block, m, n, n, 1));
                        let xb = &x[r0 * k..(r0 + m) * k];
                        bf16::matmul_tn(kernel, xb, k, dzp, &mut part[w_row * n..], n);
                        w_row += k;
                        continue;
                    }
                    if self.native() {
                        let xt = Strided::transposed(&x[r0 * k..], k);
                        fp32::matmul(k, m, n, xt, dz_block, n, &mut part[w_row * n..], n, false);
                        w_row += k;
                        continue;
                    }
                    // SAFETY: x rows r0..r0+m (k wide) read transposed
                    // (k × m); dz rows r0..r0+m of n; part's rows
                    // w_row..w_row+k of n columns.
                    unsafe {
                        matrixmultiply::sgemm(
                            k,
                            m,
                            n,
                            1.0,
                            x[r0 * k..].as_ptr(),
                            1,
                            k as isize,
                            dz[r0 * n..].as_ptr(),
                            n as isize,
                            1,
                            0.0,
                            part[w_row * n..].as_mut_ptr(),
                            n as isize,
                            1,
                        );
                    }
                    w_row += k;
                }
                let bias = &mut part[fan_in * n..];
                for r in dz[r0 * n..(r0 + m) * n].chunks(n) {
                    for (s, &v) in bias.iter_mut().zip(r) {
                        *s += v;
                    }
                }
                part
            })
            .collect();
        grad[self.offset..self.end()]
            .par_chunks_mut(4096)
            .enumerate()
            .for_each(|(c, g)| {
                for (i, gi) in g.iter_mut().enumerate() {
                    let at = c * 4096 + i;
                    let sum: f64 = partials.iter().map(|p| p[at] as f64).sum();
                    *gi += sum as f32;
                }
            });
    }
}
