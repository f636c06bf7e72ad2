//! The fused training kernel for analytic fields, per ray: a plain march
//! (the field in f32, the absorption with derivatives in sdf, α and β), a
//! reverse sweep of the compositing in scalars (the adjoint of every
//! sample's sdf and colour), then forward-mode [`Dual`] tangents through
//! the field, whose definition is the one every evaluator shares, at the
//! samples whose adjoints matter. Nothing per sample outlives its ray.
//!
//! Tangents come in chunks of up to [`CHUNK`] parameters (more parameters,
//! more passes over the batch). Rays run in parallel in fixed blocks whose
//! partial sums are added in order, so a step is bit-identical whatever the
//! thread count or scheduling: the basis of exact resumption.

use rayon::prelude::*;
use sdfl_stdlib::num::{Dual, Real, V3};
use sdfl_stdlib::value::LastInterval;

use super::model::TrainModel;
use crate::volume::march::{absorption, intervals_into, log_keep, march, Depths, RayColour};
use crate::volume::Ray;

/// Most tangents carried per pass.
pub const CHUNK: usize = 16;
/// Rays per parallel block (the unit of the ordered reduction).
const BLOCK: usize = 64;

/// A batch of rays with their target colours and sample depths.
#[derive(Debug, Clone)]
pub struct Batch {
    pub rays: Vec<Ray>,
    pub targets: Vec<[f32; 3]>,
    /// `samples` depths per ray, all rays alike (`shared`) or one row each.
    pub depths: Vec<f32>,
    pub samples: usize,
    pub shared: bool,
    pub last_interval: LastInterval,
    /// The step's seed, for anything else a model draws at random (fine
    /// samples), so a step stays a function of (seed, step).
    pub seed: u64,
    /// The step (from 0) this batch is for.
    pub step: usize,
    /// Surface points of a point-cloud batch (rows of 3; no rays then).
    pub points: Vec<f32>,
}

impl Batch {
    pub fn depths_of(&self, ray: usize) -> &[f32] {
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
    // Fields refuse materials that need normals (painted ones too).
    let c = material
        .unlit_color(p, s.center, args)
        .unwrap_or(V3::splat(T::lit(0.5)));
    (s.d, c)
}

/// Samples whose adjoints are below this fraction of the ray's largest are
/// not differentiated through the field (their share of the gradient is
/// below f32's resolution of the sum).
const NEGLIGIBLE: f64 = 1e-7;

/// One sample of the plain pass: its colour, absorption, and the
/// derivatives of its opacity and `ln(1 − opacity)` with respect to (sdf,
/// α, β).
#[derive(Debug, Clone, Copy)]
struct PlainSample<F> {
    colour: [F; 3],
    opacity: F,
    trans: F,
    d_opacity: [F; 3],
    d_log_keep: [F; 3],
}

/// What one ray gives: its loss, the gradient chunk through the field, and
/// the adjoints of α and β.
struct RayGrad<F, const N: usize> {
    loss: F,
    field: [F; N],
    alpha: F,
    beta: F,
}

/// One ray's squared error times `scale` and its gradient, in three passes:
///
/// 1. plain: the field at every sample up to where the ray is spent, and
///    the absorption with derivatives in (sdf, α, β) only;
/// 2. a reverse sweep of the compositing in scalars: the adjoint of each
///    sample's sdf and colour, and of α and β (`∂L/∂ln(1 − o_k)` is the
///    suffix sum `Σ_{j>k} (g·c_j)·w_j`, so an opaque sample needs no division);
/// 3. forward-mode tangents through the field only, at the samples whose
///    adjoints matter, dotted with those adjoints.
#[allow(clippy::too_many_arguments)]
fn ray_grad<F: Real, const N: usize>(
    model: &TrainModel,
    values: &[F],
    first: usize,
    ray: &Ray,
    t: &[f32],
    delta: &[f32],
    target: [f32; 3],
    scale: F,
    plain: &mut Vec<PlainSample<F>>,
    adjoint: &mut Vec<(F, [F; 3])>,
) -> RayGrad<F, N> {
    let f = &model.field;
    let (origin, dir) = (ray.origin.map(f64::from), ray.dir.map(f64::from));
    let flat = model.plain(values);
    let (o, d) = (V3::lit(origin), V3::lit(dir));
    let alpha = Dual::<F, 3>::seed(flat.scalar(&f.alpha).v, 1);
    let inv_beta = Dual::<F, 3>::one() / Dual::seed(flat.scalar(&f.beta).v, 2);
    plain.clear();
    let mut trans = F::one();
    let mut colour = [F::zero(); 3];
    for (&tk, &dk) in t.iter().zip(delta) {
        if trans.val() == 0.0 {
            break;
        }
        let (sdf, c) = field_at(model, &flat, o + d * Dual::lit(tk as f64));
        let sdf = Dual::<F, 3>::seed(sdf.v, 0);
        let dk = Dual::lit(dk as f64);
        let a = absorption(f.density, sdf, alpha, inv_beta, dk);
        let lk = log_keep(f.density, sdf, alpha, inv_beta, dk);
        let c = [c.x.v, c.y.v, c.z.v];
        for i in 0..3 {
            colour[i] = colour[i] + trans * a.opacity.v * c[i];
        }
        plain.push(PlainSample {
            colour: c,
            opacity: a.opacity.v,
            trans,
            d_opacity: a.opacity.d,
            d_log_keep: lk.d,
        });
        trans = trans * a.keep.v;
    }
    let mut loss = F::zero();
    let mut g = [F::zero(); 3];
    for i in 0..3 {
        let e = colour[i] - F::lit(target[i] as f64);
        loss = loss + e * e * scale;
        g[i] = F::lit(2.0) * e * scale;
    }
    // The reverse sweep.
    adjoint.clear();
    adjoint.resize(plain.len(), (F::zero(), [F::zero(); 3]));
    let (mut d_alpha, mut d_beta) = (F::zero(), F::zero());
    let mut suffix = F::zero();
    let mut largest = 0.0f64;
    for (k, s) in plain.iter().enumerate().rev() {
        let gc = g[0] * s.colour[0] + g[1] * s.colour[1] + g[2] * s.colour[2];
        let w = s.trans * s.opacity;
        let d_opacity = s.trans * gc;
        d_alpha = d_alpha + d_opacity * s.d_opacity[1] + suffix * s.d_log_keep[1];
        d_beta = d_beta + d_opacity * s.d_opacity[2] + suffix * s.d_log_keep[2];
        let d_sdf = d_opacity * s.d_opacity[0] + suffix * s.d_log_keep[0];
        let d_colour = g.map(|x| x * w);
        largest =
            largest.max(d_sdf.val().abs() + d_colour.iter().map(|x| x.val().abs()).sum::<f64>());
        adjoint[k] = (d_sdf, d_colour);
        suffix = suffix + gc * w;
    }
    // Tangents through the field where the adjoints matter.
    let mut field = [F::zero(); N];
    if N > 0 && largest > 0.0 {
        let args = model.args::<F, N>(values, first);
        let (o, d) = (V3::<Dual<F, N>>::lit(origin), V3::<Dual<F, N>>::lit(dir));
        for (k, &(d_sdf, d_colour)) in adjoint.iter().enumerate() {
            let size = d_sdf.val().abs() + d_colour.iter().map(|x| x.val().abs()).sum::<f64>();
            if size <= NEGLIGIBLE * largest {
                continue;
            }
            let (sdf, c) = field_at(model, &args, o + d * Dual::lit(t[k] as f64));
            for i in 0..N {
                field[i] = field[i]
                    + d_sdf * sdf.d[i]
                    + d_colour[0] * c.x.d[i]
                    + d_colour[1] * c.y.d[i]
                    + d_colour[2] * c.z.d[i];
            }
        }
    }
    RayGrad {
        loss,
        field,
        alpha: d_alpha,
        beta: d_beta,
    }
}

use sdfl_stdlib::shape::ArgSource;

/// `N` tangents from scalar `first`: (loss, d loss / d scalar for the `N`
/// scalars, d loss / d α, d loss / d β) for the batch under MSE with `weight`.
fn pass<F: Real, const N: usize>(
    model: &TrainModel,
    values: &[F],
    first: usize,
    batch: &Batch,
    weight: f64,
) -> (f64, [f64; N], f64, f64) {
    let last = batch.last_interval;
    let scale = F::lit(weight / (3 * batch.rays.len().max(1)) as f64);
    let blocks: Vec<(f64, [f64; N], f64, f64)> = (0..batch.rays.len())
        .collect::<Vec<_>>()
        .par_chunks(BLOCK)
        .map(|idx| {
            let mut delta = Vec::with_capacity(batch.samples);
            let mut plain = Vec::with_capacity(batch.samples);
            let mut adjoint = Vec::with_capacity(batch.samples);
            let mut acc = (F::zero(), [F::zero(); N], F::zero(), F::zero());
            for &r in idx {
                let t = batch.depths_of(r);
                intervals_into(t, last, &mut delta);
                let g = ray_grad::<F, N>(
                    model,
                    values,
                    first,
                    &batch.rays[r],
                    t,
                    &delta,
                    batch.targets[r],
                    scale,
                    &mut plain,
                    &mut adjoint,
                );
                acc.0 = acc.0 + g.loss;
                for i in 0..N {
                    acc.1[i] = acc.1[i] + g.field[i];
                }
                acc.2 = acc.2 + g.alpha;
                acc.3 = acc.3 + g.beta;
            }
            (
                acc.0.val(),
                acc.1.map(|x| x.val()),
                acc.2.val(),
                acc.3.val(),
            )
        })
        .collect();
    let mut total = (0.0, [0.0; N], 0.0, 0.0);
    for (l, g, a, b) in blocks {
        total.0 += l;
        for i in 0..N {
            total.1[i] += g[i];
        }
        total.2 += a;
        total.3 += b;
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
        let (l, g, d_alpha, d_beta) = match p - first {
            0 => with_n::<F, 0>(model, values, first, batch, weight),
            1 => with_n::<F, 1>(model, values, first, batch, weight),
            2 => with_n::<F, 2>(model, values, first, batch, weight),
            3 | 4 => with_n::<F, 4>(model, values, first, batch, weight),
            5..=8 => with_n::<F, 8>(model, values, first, batch, weight),
            9..=12 => with_n::<F, 12>(model, values, first, batch, weight),
            _ => with_n::<F, CHUNK>(model, values, first, batch, weight),
        };
        for (i, gi) in g.into_iter().enumerate() {
            if first + i < p {
                grad[first + i] += gi;
            }
        }
        if first == 0 {
            loss = l;
            // α and β reach the loss through the density, not the field.
            let f = &model.field;
            for (a, d) in [(&f.alpha, d_alpha), (&f.beta, d_beta)] {
                if let Some(i) = model.scalar_index(a) {
                    grad[i] += d;
                }
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
) -> (f64, Vec<f64>, f64, f64) {
    let (l, g, a, b) = pass::<F, N>(model, values, first, batch, weight);
    (l, g.to_vec(), a, b)
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
