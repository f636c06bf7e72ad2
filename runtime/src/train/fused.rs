//! The fused training kernel for analytic fields. Fields that trace run
//! through their [`Tape`] (see [`super::tape`]); the rest, and the f64
//! reference every path is tested against, run here, per ray: a plain march
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

use super::model::field_at;
use rayon::prelude::*;
use sdfl_stdlib::num::{Dual, Real, V3};
use sdfl_stdlib::shape::ArgSource;
use sdfl_stdlib::value::{DensityKind, LastInterval};

use super::model::TrainModel;
use super::tape::{self, Tape};
use crate::volume::march::{intervals_into, march, Depths, RayColour};
use crate::volume::Ray;

/// Most tangents carried per pass.
pub const CHUNK: usize = 16;
/// Rays per parallel block (the unit of the ordered reduction).
const BLOCK: usize = 64;

/// A batch of rays with their target colours and sample depths.
#[derive(Debug, Clone)]
pub struct Batch {
    /// The camera rays of the batch, in the scene frame.
    pub rays: Vec<Ray>,
    /// The colour each ray's pixel should have.
    pub targets: Vec<[f32; 3]>,
    /// How much of each ray's pixel the object covers (empty: not known).
    pub coverage: Vec<f32>,
    /// `samples` depths per ray, all rays alike (`shared`) or one row each.
    pub depths: Vec<f32>,
    /// Samples per ray.
    pub samples: usize,
    /// Whether every ray uses the same row of depths.
    pub shared: bool,
    /// How much the last sample of a ray absorbs.
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
    /// The sample depths along ray `ray`.
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
    /// The batch's loss.
    pub loss: f64,
    /// ∂loss/∂scalar, in the model's flat order.
    pub grad: Vec<f64>,
}

/// Samples whose adjoints are below this fraction of the ray's largest are
/// not differentiated through the field (their share of the gradient is
/// below f32's resolution of the sum).
const NEGLIGIBLE: f64 = 1e-7;

/// The plain pass's samples, a column per quantity: each sample's colour
/// (3), opacity,
/// the transmittance before it, and the derivatives of its opacity (3) and
/// of `ln(1 − opacity)` (3) with respect to (sdf, α, β).
#[derive(Debug, Clone)]
struct PlainSamples<F> {
    /// `COLUMNS` columns of `cap` values each.
    data: Vec<F>,
    cap: usize,
    len: usize,
}

const COLUMNS: usize = 11;
const OPACITY: usize = 3;
const TRANS: usize = 4;
const D_OPACITY: usize = 5;
const D_LOG_KEEP: usize = 8;

impl<F: Real> PlainSamples<F> {
    /// Room for `samples` samples.
    fn new(samples: usize) -> Self {
        let cap = samples;
        PlainSamples {
            data: vec![F::zero(); COLUMNS * cap],
            cap,
            len: 0,
        }
    }
    fn clear(&mut self) {
        self.len = 0;
    }
    fn len(&self) -> usize {
        self.len
    }
    fn column(&self, c: usize) -> &[F] {
        &self.data[c * self.cap..c * self.cap + self.len]
    }
    fn push(&mut self, values: [F; COLUMNS]) {
        debug_assert!(self.len < self.cap, "more samples than the batch has");
        for (c, v) in values.into_iter().enumerate() {
            self.data[c * self.cap + self.len] = v;
        }
        self.len += 1;
    }
}

/// What one ray gives: its loss, the gradient chunk through the field, and
/// the adjoints of α and β.
struct RayGrad<F, const N: usize> {
    loss: F,
    field: [F; N],
    alpha: F,
    beta: F,
}

/// The plain pass's state along one ray.
struct PlainMarch<F: Real> {
    alpha: Dual<F, 3>,
    inv_beta: Dual<F, 3>,
    trans: F,
    colour: [F; 3],
}

impl<F: Real> PlainMarch<F> {
    fn new(model: &TrainModel, values: &[F]) -> Self {
        let f = &model.field;
        let flat = model.plain(values);
        PlainMarch {
            alpha: Dual::seed(flat.scalar(&f.alpha).v, 1),
            inv_beta: Dual::<F, 3>::one() / Dual::seed(flat.scalar(&f.beta).v, 2),
            trans: F::one(),
            colour: [F::zero(); 3],
        }
    }

    /// Whether the ray is spent (every later weight and derivative is 0).
    #[inline(always)]
    fn spent(&self) -> bool {
        self.trans.val() == 0.0
    }

    /// Composites one sample of distance `sdf` and colour `c` over interval
    /// `dk`, keeping what the reverse sweep needs.
    #[inline(always)]
    fn add(&mut self, kind: DensityKind, sdf: F, c: [F; 3], dk: f32, plain: &mut PlainSamples<F>) {
        let sdf = Dual::<F, 3>::seed(sdf, 0);
        let dk = Dual::lit(dk as f64);
        let a = kind.absorption(sdf, self.alpha, self.inv_beta, dk);
        let lk = kind.log_keep(sdf, self.alpha, self.inv_beta, dk);
        for (colour, c) in self.colour.iter_mut().zip(c) {
            *colour = *colour + self.trans * a.opacity.v * c;
        }
        let values = [
            c[0],
            c[1],
            c[2],
            a.opacity.v,
            self.trans,
            a.opacity.d[0],
            a.opacity.d[1],
            a.opacity.d[2],
            lk.d[0],
            lk.d[1],
            lk.d[2],
        ];
        plain.push(values);
        self.trans = self.trans * a.keep.v;
    }
}

/// The loss of a ray's colour and the reverse sweep of its compositing:
/// fills `adjoint` (each sample's sdf and colour) and returns (loss, ∂L/∂α,
/// ∂L/∂β, the largest adjoint). `∂L/∂ln(1 − o_k)` is the suffix sum
/// `Σ_{j>k} (g·c_j)·w_j`, so an opaque sample needs no division.
///
/// `FIELD`: whether the samples' adjoints are wanted (tangents follow);
/// `DENSITY`: whether α's and β's are (either is a parameter). What is not
/// wanted is not computed and comes back as zero.
fn reverse_sweep<F: Real, const FIELD: bool, const DENSITY: bool>(
    colour: [F; 3],
    target: [f32; 3],
    scale: F,
    plain: &PlainSamples<F>,
    adjoint: &mut Vec<(F, [F; 3])>,
) -> (F, F, F, f64) {
    let mut loss = F::zero();
    let mut g = [F::zero(); 3];
    for i in 0..3 {
        let e = colour[i] - F::lit(target[i] as f64);
        loss = loss + e * e * scale;
        g[i] = F::lit(2.0) * e * scale;
    }
    adjoint.clear();
    if FIELD {
        adjoint.resize(plain.len(), (F::zero(), [F::zero(); 3]));
    }
    let (mut d_alpha, mut d_beta) = (F::zero(), F::zero());
    let mut suffix = F::zero();
    let mut largest = 0.0f64;
    let n = plain.len();
    let col = |c: usize| plain.column(c);
    let (c, o, tr) = ([col(0), col(1), col(2)], col(OPACITY), col(TRANS));
    let dop = [col(D_OPACITY), col(D_OPACITY + 1), col(D_OPACITY + 2)];
    let dlk = [col(D_LOG_KEEP), col(D_LOG_KEEP + 1), col(D_LOG_KEEP + 2)];
    for k in (0..n).rev() {
        let gc = g[0] * c[0][k] + g[1] * c[1][k] + g[2] * c[2][k];
        let w = tr[k] * o[k];
        let d_opacity = tr[k] * gc;
        // One add a sample on each running sum.
        if DENSITY {
            d_alpha = d_alpha + (d_opacity * dop[1][k] + suffix * dlk[1][k]);
            d_beta = d_beta + (d_opacity * dop[2][k] + suffix * dlk[2][k]);
        }
        if FIELD {
            let d_sdf = d_opacity * dop[0][k] + suffix * dlk[0][k];
            let d_colour = g.map(|x| x * w);
            largest = largest.max(adjoint_size(d_sdf, d_colour));
            adjoint[k] = (d_sdf, d_colour);
        }
        suffix = suffix + gc * w;
    }
    (loss, d_alpha, d_beta, largest)
}

/// [`reverse_sweep`] computing only what is wanted.
#[inline(always)]
fn sweep<F: Real>(
    field: bool,
    density: bool,
    colour: [F; 3],
    target: [f32; 3],
    scale: F,
    plain: &PlainSamples<F>,
    adjoint: &mut Vec<(F, [F; 3])>,
) -> (F, F, F, f64) {
    let a = (colour, target, scale, plain, adjoint);
    match (field, density) {
        (true, true) => reverse_sweep::<F, true, true>(a.0, a.1, a.2, a.3, a.4),
        (true, false) => reverse_sweep::<F, true, false>(a.0, a.1, a.2, a.3, a.4),
        (false, true) => reverse_sweep::<F, false, true>(a.0, a.1, a.2, a.3, a.4),
        (false, false) => reverse_sweep::<F, false, false>(a.0, a.1, a.2, a.3, a.4),
    }
}

/// In f64, so that finite adjoints never sum to infinity.
#[inline(always)]
fn adjoint_size<F: Real>(d_sdf: F, d_colour: [F; 3]) -> f64 {
    d_sdf.val().abs() + d_colour.iter().map(|x| x.val().abs()).sum::<f64>()
}

/// One ray's squared error times `scale` and its gradient, in three passes:
///
/// 1. plain: the field at every sample up to where the ray is spent, and
///    the absorption with derivatives in (sdf, α, β) only;
/// 2. a reverse sweep of the compositing in scalars: the adjoint of each
///    sample's sdf and colour, and of α and β;
/// 3. forward-mode tangents through the field only, at the samples whose
///    adjoints matter, dotted with those adjoints.
fn ray_grad<F: Real, const N: usize>(
    model: &TrainModel,
    values: &[F],
    first: usize,
    task: &RayTask,
    scale: F,
    scratch: &mut Scratch<F>,
) -> RayGrad<F, N> {
    let RayTask {
        ray,
        t,
        delta,
        target,
        ..
    } = *task;
    let Scratch { plain, adjoint } = scratch;
    let f = &model.field;
    let (origin, dir) = (ray.origin.map(f64::from), ray.dir.map(f64::from));
    let flat = model.plain(values);
    let (o, d) = (V3::lit(origin), V3::lit(dir));
    let mut m = PlainMarch::new(model, values);
    plain.clear();
    for (&tk, &dk) in t.iter().zip(delta) {
        if m.spent() {
            break;
        }
        let (sdf, c) = field_at(model, &flat, o + d * Dual::lit(tk as f64));
        m.add(f.density, sdf.v, [c.x.v, c.y.v, c.z.v], dk, plain);
    }
    let (loss, alpha, beta, largest) = sweep(
        N > 0,
        task.density_adjoints,
        m.colour,
        target,
        scale,
        plain,
        adjoint,
    );
    let mut field = [F::zero(); N];
    if N > 0 && largest > 0.0 {
        let args = model.args::<F, N>(values, first);
        let (o, d) = (V3::<Dual<F, N>>::lit(origin), V3::<Dual<F, N>>::lit(dir));
        for (k, &adj) in adjoint.iter().enumerate() {
            if adjoint_size(adj.0, adj.1) <= NEGLIGIBLE * largest {
                continue;
            }
            let (sdf, c) = field_at(model, &args, o + d * Dual::lit(t[k] as f64));
            let c = [c.x, c.y, c.z];
            // field += adjoint · tangents.
            let (d_sdf, d_colour) = adj;
            #[allow(
                clippy::needless_range_loop,
                reason = "`i` is the tangent index of the field and of every dual"
            )]
            for i in 0..N {
                field[i] = field[i]
                    + d_sdf * sdf.d[i]
                    + d_colour[0] * c[0].d[i]
                    + d_colour[1] * c[1].d[i]
                    + d_colour[2] * c[2].d[i];
            }
        }
    }
    RayGrad {
        loss,
        field,
        alpha,
        beta,
    }
}

/// One ray of a batch: its depths, their intervals and its target colour.
#[derive(Clone, Copy)]
struct RayTask<'a> {
    ray: &'a Ray,
    t: &'a [f32],
    delta: &'a [f32],
    target: [f32; 3],
    /// Whether α or β is a parameter (their adjoints are wanted).
    density_adjoints: bool,
}

/// A ray's working storage, reused from ray to ray.
struct Scratch<F> {
    plain: PlainSamples<F>,
    adjoint: Vec<(F, [F; 3])>,
}

/// `N` tangents from scalar `first`: (loss, d loss / d scalar for the `N`
/// scalars, d loss / d α, d loss / d β) for the batch under MSE with `weight`.
fn pass<F: Real, const N: usize>(
    model: &TrainModel,
    values: &[F],
    first: usize,
    batch: &Batch,
    weight: f64,
) -> (f64, Vec<f64>, f64, f64) {
    let last = batch.last_interval;
    let scale = F::lit(weight / (3 * batch.rays.len().max(1)) as f64);
    let f = &model.field;
    let density_adjoints = first == 0
        && (model.scalar_index(&f.alpha).is_some() || model.scalar_index(&f.beta).is_some());
    let blocks: Vec<(f64, [f64; N], f64, f64)> = (0..batch.rays.len())
        .collect::<Vec<_>>()
        .par_chunks(BLOCK)
        .map(|idx| {
            let mut delta = Vec::with_capacity(batch.samples);
            let mut scratch = Scratch {
                plain: PlainSamples::new(batch.samples),
                adjoint: Vec::with_capacity(batch.samples),
            };
            let mut acc = (F::zero(), [F::zero(); N], F::zero(), F::zero());
            for &r in idx {
                let t = batch.depths_of(r);
                intervals_into(t, last, &mut delta);
                let task = RayTask {
                    ray: &batch.rays[r],
                    t,
                    delta: &delta,
                    target: batch.targets[r],
                    density_adjoints,
                };
                let g = ray_grad::<F, N>(model, values, first, &task, scale, &mut scratch);
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
    let mut total = (0.0, vec![0.0; N], 0.0, 0.0);
    for (l, g, a, b) in blocks {
        total.0 += l;
        for (t, g) in total.1.iter_mut().zip(&g) {
            *t += g;
        }
        total.2 += a;
        total.3 += b;
    }
    total
}

/// The batch's MSE (times `weight`) and its gradient in f64, one sample at
/// a time: the reference the f32 paths are tested against. Compiled here,
/// with one width of tangents, so that tests calling it do not instantiate
/// the field's evaluator again.
pub fn loss_and_grad_f64(
    model: &TrainModel,
    values: &[f64],
    batch: &Batch,
    weight: f64,
) -> LossGrad {
    loss_and_grad_by::<_, Wide>(model, values, batch, weight)
}

/// [`loss_and_grad_f64`] in f32, one sample at a time: the path of fields
/// that branch on the point.
pub fn loss_and_grad_scalar_f32(
    model: &TrainModel,
    values: &[f32],
    batch: &Batch,
    weight: f64,
) -> LossGrad {
    loss_and_grad_by::<_, Narrow>(model, values, batch, weight)
}

/// The batch's loss and gradient in f32: through the model's [`Tape`]
/// (the field, absorption and colour traced once, run on lanes of samples
/// forward and in reverse) where it can be traced (no branch on a
/// per-sample value) and is small enough; else [`loss_and_grad_scalar_f32`]
/// (whose loss the tape's equals to the bit).
pub fn loss_and_grad_f32(
    model: &TrainModel,
    values: &[f32],
    batch: &Batch,
    weight: f64,
) -> LossGrad {
    match traced(model, values, batch) {
        Some(tape) => tape::loss_and_grad(&tape, model, batch, weight),
        None => loss_and_grad_scalar_f32(model, values, batch, weight),
    }
}

/// Lanes of 16 samples the tape kernel may keep per thread: 16 MiB of
/// values and as much of adjoints.
const TAPE_LANES: usize = 1 << 18;

/// The model's tape at `values` for batches of `samples` samples a ray, or
/// why the forward-mode kernel runs instead.
pub fn tape_for(model: &TrainModel, values: &[f32], samples: usize) -> Result<Tape, &'static str> {
    let tape = Tape::trace(model, values)?;
    if tape.registers() * tape::lanes_per_register(samples) > TAPE_LANES {
        return Err("too large for the tape's lanes");
    }
    Ok(tape)
}

/// The model's tape at `values`, if it traces and fits.
pub fn traced(model: &TrainModel, values: &[f32], batch: &Batch) -> Option<Tape> {
    tape_for(model, values, batch.samples).ok()
}

/// How many tangents a pass carries for the parameters left.
trait Widths {
    fn pass<F: Real>(
        left: usize,
        model: &TrainModel,
        values: &[F],
        first: usize,
        batch: &Batch,
        weight: f64,
    ) -> (f64, Vec<f64>, f64, f64);
}

/// The fewest lanes that hold the parameters left (training: less work).
struct Narrow;

impl Widths for Narrow {
    fn pass<F: Real>(
        left: usize,
        model: &TrainModel,
        values: &[F],
        first: usize,
        batch: &Batch,
        weight: f64,
    ) -> (f64, Vec<f64>, f64, f64) {
        match left {
            0 => pass::<F, 0>(model, values, first, batch, weight),
            1 => pass::<F, 1>(model, values, first, batch, weight),
            2 => pass::<F, 2>(model, values, first, batch, weight),
            3 => pass::<F, 3>(model, values, first, batch, weight),
            4 => pass::<F, 4>(model, values, first, batch, weight),
            5 | 6 => pass::<F, 6>(model, values, first, batch, weight),
            7 | 8 => pass::<F, 8>(model, values, first, batch, weight),
            9..=12 => pass::<F, 12>(model, values, first, batch, weight),
            _ => pass::<F, CHUNK>(model, values, first, batch, weight),
        }
    }
}

/// Always [`CHUNK`] (the reference: one instance of the evaluator; unused
/// tangents are zero and change nothing).
struct Wide;

impl Widths for Wide {
    fn pass<F: Real>(
        _left: usize,
        model: &TrainModel,
        values: &[F],
        first: usize,
        batch: &Batch,
        weight: f64,
    ) -> (f64, Vec<f64>, f64, f64) {
        pass::<F, CHUNK>(model, values, first, batch, weight)
    }
}

fn loss_and_grad_by<F: Real, W: Widths>(
    model: &TrainModel,
    values: &[F],
    batch: &Batch,
    weight: f64,
) -> LossGrad {
    // Tangents through the field only for the scalars it depends on (α and
    // β alone reach the loss through the density: no field tangents).
    let p = model.field_scalars;
    let mut grad = vec![0.0; model.scalars];
    let mut loss = 0.0;
    let mut first = 0;
    loop {
        let (l, g, d_alpha, d_beta) = W::pass(p - first, model, values, first, batch, weight);
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
            march(
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
            )
        })
        .collect()
}
