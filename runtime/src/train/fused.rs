//! The fused training kernel for analytic fields: per ray, one forward
//! march in [`Dual`] numbers whose tangents are the derivatives with respect
//! to the model's parameters, through the field's SDF and colour, the
//! density, the compositing and the loss. Nothing per sample outlives its
//! ray, and no backward pass is needed.
//!
//! Tangents come in chunks of up to [`CHUNK`] parameters (more parameters,
//! more passes over the batch). Rays run in parallel in fixed blocks whose
//! partial sums are added in order, so a step is bit-identical whatever the
//! thread count or scheduling: the basis of exact resumption.

use rayon::prelude::*;
use sdfl_stdlib::num::{Dual, Real, V3};
use sdfl_stdlib::value::LastInterval;

use super::model::{DualArgs, TrainModel};
use crate::volume::march::{intervals_into, march, Depths, RayColour};
use crate::volume::Ray;

/// Most tangents carried per pass.
pub const CHUNK: usize = 16;
/// Rays per parallel block (the unit of the ordered reduction).
const BLOCK: usize = 64;

/// A batch of rays with their target colours and sample depths.
#[derive(Debug, Clone, Default)]
pub struct Batch {
    pub rays: Vec<Ray>,
    pub targets: Vec<[f32; 3]>,
    /// `samples` depths per ray, all rays alike (`shared`) or one row each.
    pub depths: Vec<f32>,
    pub samples: usize,
    pub shared: bool,
    pub last_interval: Option<LastInterval>,
}

impl Batch {
    fn depths_of(&self, ray: usize) -> &[f32] {
        if self.shared {
            &self.depths[..self.samples]
        } else {
            &self.depths[ray * self.samples..(ray + 1) * self.samples]
        }
    }
}

/// The loss and its gradient with respect to every scalar of the model.
#[derive(Debug, Clone, PartialEq)]
pub struct LossGrad {
    pub loss: f64,
    pub grad: Vec<f64>,
}

/// The field of `model` at `p`: signed distance and colour.
#[inline(always)]
pub fn field_at<T: Real, A: sdfl_stdlib::shape::ArgSource<T>>(
    model: &TrainModel,
    args: &A,
    p: V3<T>,
) -> (T, V3<T>) {
    let s = model.field.shape.sample(p, args);
    let material = s.material.unwrap_or(&model.field.color);
    // Fields refuse materials that need normals; a painted one shades grey.
    let c = material
        .unlit_color(p, s.center, args)
        .unwrap_or(V3::splat(T::lit(0.5)));
    (s.d, c)
}

fn ray_colour<F: Real, const N: usize>(
    model: &TrainModel,
    args: &DualArgs<F, N>,
    ray: &Ray,
    t: &[f32],
    delta: &[f32],
) -> RayColour<Dual<F, N>> {
    let f = &model.field;
    let alpha = args.scalar(&f.alpha);
    let beta = args.scalar(&f.beta);
    march(
        |p| field_at(model, args, p),
        f.density,
        alpha,
        beta,
        ray.origin,
        ray.dir,
        Depths { t, delta },
        false,
    )
}

use sdfl_stdlib::shape::ArgSource;

/// `N` tangents from scalar `first`: (loss, d loss / d scalar) for the batch
/// under MSE with `weight`.
fn pass<F: Real, const N: usize>(
    model: &TrainModel,
    values: &[F],
    first: usize,
    batch: &Batch,
    weight: f64,
) -> (f64, [f64; N]) {
    let last = batch.last_interval.unwrap_or(LastInterval::Zero);
    let scale = F::lit(weight / (3 * batch.rays.len().max(1)) as f64);
    let blocks: Vec<(f64, [f64; N])> = (0..batch.rays.len())
        .collect::<Vec<_>>()
        .par_chunks(BLOCK)
        .map(|idx| {
            let args = model.args::<F, N>(values, first);
            let mut delta = Vec::with_capacity(batch.samples);
            let mut loss = Dual::<F, N>::lit(0.0);
            for &r in idx {
                let t = batch.depths_of(r);
                intervals_into(t, last, &mut delta);
                let c = ray_colour(model, &args, &batch.rays[r], t, &delta);
                let tgt = batch.targets[r];
                for (ci, ti) in c.colour.to_array().into_iter().zip(tgt) {
                    let e = ci - Dual::lit(ti as f64);
                    loss = loss + e * e * Dual::constant(scale);
                }
            }
            (loss.v.val(), loss.d.map(|d| d.val()))
        })
        .collect();
    let mut total = (0.0, [0.0; N]);
    for (l, g) in blocks {
        total.0 += l;
        for i in 0..N {
            total.1[i] += g[i];
        }
    }
    total
}

/// The batch's MSE (times `weight`) and its gradient, in base type `F`
/// (f32 for training, f64 for reference tests).
pub fn loss_and_grad<F: Real>(
    model: &TrainModel,
    values: &[F],
    batch: &Batch,
    weight: f64,
) -> LossGrad {
    let p = model.scalars;
    let mut grad = vec![0.0; p];
    let mut loss = 0.0;
    let mut first = 0;
    loop {
        let left = p - first;
        let (l, g): (f64, Vec<f64>) = match left {
            0 | 1 => with_n::<F, 1>(model, values, first, batch, weight),
            2 => with_n::<F, 2>(model, values, first, batch, weight),
            3 | 4 => with_n::<F, 4>(model, values, first, batch, weight),
            5..=8 => with_n::<F, 8>(model, values, first, batch, weight),
            _ => with_n::<F, CHUNK>(model, values, first, batch, weight),
        };
        if first == 0 {
            loss = l;
        }
        for (i, gi) in g.into_iter().enumerate() {
            if first + i < p {
                grad[first + i] = gi;
            }
        }
        first += CHUNK;
        if first >= p {
            break;
        }
    }
    LossGrad { loss, grad }
}

fn with_n<F: Real, const N: usize>(
    model: &TrainModel,
    values: &[F],
    first: usize,
    batch: &Batch,
    weight: f64,
) -> (f64, Vec<f64>) {
    let (l, g) = pass::<F, N>(model, values, first, batch, weight);
    (l, g.to_vec())
}

/// Forward colours (and depths) of rays of the model at `values`: the
/// renderer of a model mid-training, sharing the trainer's code path.
pub fn render_rays(
    model: &TrainModel,
    values: &[f32],
    rays: &[Ray],
    t: &[f32],
    last: LastInterval,
) -> Vec<RayColour<f32>> {
    let mut delta = Vec::new();
    intervals_into(t, last, &mut delta);
    rays.par_iter()
        .map(|r| {
            let args = model.plain(values);
            let f = &model.field;
            let (alpha, beta) = (args.scalar(&f.alpha).v, args.scalar(&f.beta).v);
            let c = march(
                |p: V3<f32>| {
                    let q = V3::new(
                        Dual::constant(p.x),
                        Dual::constant(p.y),
                        Dual::constant(p.z),
                    );
                    let (d, c) = field_at(model, &args, q);
                    (d.v, V3::new(c.x.v, c.y.v, c.z.v))
                },
                f.density,
                alpha,
                beta,
                r.origin,
                r.dir,
                Depths { t, delta: &delta },
                true,
            );
            c
        })
        .collect()
}
