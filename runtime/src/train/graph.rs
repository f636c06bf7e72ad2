//! The `dfdx` backend: a training step as a dfdx autodiff graph over
//! `[rays, samples]` tensors. The field is one custom op (parameters →
//! per-sample opacity, `ln(1 − opacity)` and colour), whose backward
//! pushes the upstream gradient through forward-mode tangents of the same
//! generic field code the fused kernel runs; compositing (cumsum as a
//! triangular matmul), the colour sum and the loss are ordinary dfdx ops.
//!
//! It is an independent differentiation of the compositing and the loss,
//! and the shape fields that are themselves dfdx graphs (MLPs) will take;
//! tests check it against the fused kernel. It holds about
//! [`BYTES_PER_SAMPLE`] per sample, so the trainer refuses batches that
//! would not fit.

use dfdx::prelude::*;
use rayon::prelude::*;
use sdfl_stdlib::num::{Dual, Real, V3};
use sdfl_stdlib::shape::ArgSource;

use super::fused::{Batch, LossGrad, CHUNK};
use super::graph_ops::weights_from_log_keep;
use super::model::field_at;
use super::model::TrainModel;
use super::TrainError;
use crate::volume::march::intervals_into;

/// Values per sample of the field op: opacity, `ln(1 − opacity)`, RGB.
const OUT: usize = 5;

/// A generous bound on the bytes the graph holds per sample (the op's
/// output and its gradient, compositing intermediates, dfdx's cache).
pub const BYTES_PER_SAMPLE: u64 = 160;

/// The five per-sample outputs of the field at every sample of `batch`, as
/// [`Dual`]s with tangents for scalars `first..first + N`; `each(ray, k,
/// outputs)` sees them in order.
fn for_each_sample<F: Real, const N: usize>(
    model: &TrainModel,
    values: &[F],
    first: usize,
    batch: &Batch,
    ray: usize,
    mut each: impl FnMut(usize, [Dual<F, N>; OUT]),
) {
    let args = model.args::<F, N>(values, first);
    let f = &model.field;
    let alpha = args.scalar(&f.alpha);
    let inv_beta = Dual::one() / args.scalar(&f.beta);
    let r = &batch.rays[ray];
    let t = if batch.shared {
        &batch.depths[..batch.samples]
    } else {
        &batch.depths[ray * batch.samples..(ray + 1) * batch.samples]
    };
    let mut delta = Vec::with_capacity(t.len());
    intervals_into(t, batch.last_interval, &mut delta);
    let o = V3::lit(r.origin.map(f64::from));
    let d = V3::lit(r.dir.map(f64::from));
    for (k, (&tk, &dk)) in t.iter().zip(&delta).enumerate() {
        let p = o + d * Dual::lit(tk as f64);
        let (sdf, c) = field_at(model, &args, p);
        let dk = Dual::lit(dk as f64);
        let a = f.density.absorption(sdf, alpha, inv_beta, dk);
        // Clamped so that exp(cumsum) never meets −∞·0 in the matmul.
        let lk = f
            .density
            .log_keep(sdf, alpha, inv_beta, dk)
            .max(Dual::lit(-1e4));
        each(k, [a.opacity, lk, c.x, c.y, c.z]);
    }
}

/// Parameters `[P]` → field outputs `[rays · samples, 5]`, with a backward
/// through forward-mode tangents (chunks of [`CHUNK`] parameters).
fn field_op(
    x: Tensor<(usize,), f32, Cpu, OwnedTape<f32, Cpu>>,
    model: &TrainModel,
    batch: &Batch,
) -> Tensor<(usize, usize), f32, Cpu, OwnedTape<f32, Cpu>> {
    let dev = x.device().clone();
    let values = dev.tensor_to_vec(&x);
    let (rays, n) = (batch.rays.len(), batch.samples);
    let mut out = vec![0f32; rays * n * OUT];
    out.par_chunks_mut(n * OUT)
        .enumerate()
        .for_each(|(r, row)| {
            for_each_sample::<f32, 0>(model, &values, 0, batch, r, |k, v| {
                for (j, x) in v.iter().enumerate() {
                    row[k * OUT + j] = x.v;
                }
            });
        });
    let out = dev.tensor_from_vec(out, (rays * n, OUT));
    let (x, tape) = x.split_tape();
    let out_id = out.clone();
    let (model, batch) = (model.clone(), batch.clone());
    let mut tape = tape;
    tape.add_backward_op(move |grads| {
        let g: Vec<f32> = grads.get_or_alloc_mut(&out_id)?.to_vec();
        let p = model.scalars;
        let mut total = vec![0f32; p];
        let mut first = 0;
        while first < p {
            let chunk: Vec<[f32; CHUNK]> = (0..batch.rays.len())
                .into_par_iter()
                .map(|r| {
                    let mut acc = [0f32; CHUNK];
                    let row = &g[r * n * OUT..(r + 1) * n * OUT];
                    for_each_sample::<f32, CHUNK>(&model, &values, first, &batch, r, |k, v| {
                        for (j, x) in v.iter().enumerate() {
                            let gk = row[k * OUT + j];
                            for (a, &d) in acc.iter_mut().zip(&x.d) {
                                *a += gk * d;
                            }
                        }
                    });
                    acc
                })
                .collect();
            for acc in chunk {
                for i in 0..CHUNK.min(p - first) {
                    total[first + i] += acc[i];
                }
            }
            first += CHUNK;
        }
        let dst = grads.get_or_alloc_mut(&x)?;
        for (d, t) in dst.iter_mut().zip(&total) {
            *d += t;
        }
        Ok(())
    });
    out.put_tape(tape)
}

fn selector(dev: &Cpu, cols: &[usize]) -> Tensor<(usize, usize), f32, Cpu> {
    let mut m = vec![0f32; OUT * cols.len()];
    for (j, &c) in cols.iter().enumerate() {
        m[c * cols.len() + j] = 1.0;
    }
    dev.tensor_from_vec(m, (OUT, cols.len()))
}

/// The batch's MSE (times `weight`) and its gradient through the dfdx graph.
pub fn loss_and_grad(
    dev: &Cpu,
    model: &TrainModel,
    values: &[f32],
    batch: &Batch,
    weight: f64,
) -> Result<LossGrad, TrainError> {
    let (r, n) = (batch.rays.len(), batch.samples);
    if r == 0 || n == 0 {
        return Err(TrainError::Invalid("an empty batch".into()));
    }
    let x = dev.tensor_from_vec(values.to_vec(), (values.len(),));
    let f = field_op(x.leaky_trace(), model, batch);
    let again = super::graph_ops::again;
    let opacity = again(&f).matmul(selector(dev, &[0])).reshape_like(&(r, n));
    let lk = again(&f).matmul(selector(dev, &[1])).reshape_like(&(r, n));
    let rgb = f
        .matmul(selector(dev, &[2, 3, 4]))
        .reshape_like(&(r, n, 3usize));
    let w = weights_from_log_keep(lk, opacity)?;
    let colour =
        (w.broadcast_like::<(usize, usize, usize), Axis<2>>(&(r, n, 3)) * rgb)
            .sum::<(usize, usize), Axis<1>>();
    let target: Vec<f32> = batch.targets.iter().flatten().copied().collect();
    let loss = (colour - dev.tensor_from_vec(target, (r, 3usize)))
        .square()
        .mean()
        * weight as f32;
    let value = loss.array();
    let grads = loss.backward();
    Ok(LossGrad {
        loss: value as f64,
        grad: grads.get(&x).as_vec().into_iter().map(f64::from).collect(),
    })
}
