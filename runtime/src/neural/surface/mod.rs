//! A neural SDF seen as a volume and trained from images (VolSDF; NeuS):
//! samples along rays → the distance network with its exact gradient →
//! each sample's optical depth `τ(f)` (the density's one definition,
//! [`sdfl_stdlib::density`], through duals) and a colour network that sees
//! the encoded point, the gradient (the surface normal) and the encoded
//! view direction → compositing → MSE, plus the eikonal term `(‖∇f‖ − 1)²`
//! at the samples.
//!
//! Backward: compositing gives `∂L/∂τ` and `∂L/∂c`; the colour network turns
//! `∂L/∂c` into its weights' gradient and `∂L/∂∇f` (the normal is one of its
//! inputs); `∂L/∂f = ∂L/∂τ·τ'(f)`. The distance network takes both adjoints
//! at once ([`SurfaceSdf::backward`]: a second-order pass through the
//! tangents). It is the harmonic MLP or the hash-grid SDF ([`geometry`]),
//! the one place the two are told apart.

use rayon::prelude::*;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::num::{Dual, Real};
use sdfl_stdlib::value::{DensityKind, LastInterval, Loss, LossKind, NeuralSurface};

use super::composite::{composite, silhouette_backward, squared_error_backward};
use super::distance::{trace_field, TraceSettings};
use super::encoding::Harmonic;
use super::field::{fine_samples, NerfView, Samples};
use super::mlp::{Activation, Dense};
use super::sdf_net::eikonal_loss;
use crate::mesh::DistanceField;
use crate::train::field::{Description, Region, View};
use crate::train::fused::Batch;
use crate::train::{Objective, TensorSpec, TrainError, Trained, TrainedField};
use crate::volume::importance::Spacing;
use crate::volume::{camera_rays, ImageSize, Ray, SplitMix64, Stratified, VolumeError};
pub use geometry::{GeometryWork, HashSurface, Levels, SurfaceField, SurfaceSdf};
use skip::{Selection, SkipGrid};

/// A trained β is kept as `θ = ln β / BETA_RATE`: Adam's steps in θ are
/// about the learning rate whatever the gradient's scale, so this makes
/// `ln β` move this many times faster than a network weight (one shared
/// learning rate would leave it nearly where it started).
pub const BETA_RATE: f32 = 20.0;

/// Rays per block of the compositing pass.
const RAY_BLOCK: usize = 64;
/// Samples per pass when rendering (bounds the distance network's buffers).
const RENDER_ROWS: usize = 1 << 14;

/// The colour network: the encoded point, the normal and (when view
/// dependent) the encoded direction → ReLU layers → sigmoid colour.
#[derive(Debug, Clone)]
pub struct ColorNet {
    position: Harmonic,
    direction: Option<Harmonic>,
    layers: Vec<Dense>,
}

/// The colour network's buffers.
#[derive(Default)]
struct ColorWork {
    position: Vec<f32>,
    direction: Vec<f32>,
    /// Every layer's output.
    acts: Vec<Vec<f32>>,
    d_a: Vec<f32>,
    d_b: Vec<f32>,
}

impl ColorNet {
    fn new(spec: &NeuralSurface, offset: usize) -> Self {
        assert!(
            spec.color_layers >= 1,
            "a colour network has a hidden layer"
        );
        let position = Harmonic {
            dims: 3,
            freqs: spec.color_freqs,
            include_input: true,
        };
        let direction = spec.view_dependent.then_some(Harmonic {
            dims: 3,
            freqs: NeuralSurface::DIRECTION_FREQS,
            include_input: true,
        });
        let mut parts = vec![position.width(), 3];
        parts.extend(direction.map(|d| d.width()));
        let mut layers = Vec::new();
        let mut at = offset;
        for i in 0..spec.color_layers {
            let d = if i == 0 {
                Dense::new(&parts, spec.color_width, Activation::Relu, at)
            } else {
                Dense::new(&[spec.color_width], spec.color_width, Activation::Relu, at)
            };
            at = d.end();
            layers.push(d);
        }
        layers.push(Dense::new(&[spec.color_width], 3, Activation::Sigmoid, at));
        ColorNet {
            position,
            direction,
            layers,
        }
    }

    fn end(&self) -> usize {
        self.layers.last().expect("an output layer").end()
    }

    fn forward(
        &self,
        params: &[f32],
        points: &[f32],
        normals: &[f32],
        dirs: &[f32],
        w: &mut ColorWork,
    ) {
        let rows = points.len() / 3;
        w.position.resize(rows * self.position.width(), 0.0);
        self.position.encode(points, &mut w.position);
        if let Some(d) = &self.direction {
            w.direction.resize(rows * d.width(), 0.0);
            d.encode(dirs, &mut w.direction);
        }
        w.acts.resize(self.layers.len(), Vec::new());
        for (i, d) in self.layers.iter().enumerate() {
            let (before, rest) = w.acts.split_at_mut(i);
            let out = &mut rest[0];
            out.resize(rows * d.out, 0.0);
            if i == 0 {
                let mut inputs: Vec<&[f32]> = vec![&w.position, normals];
                if self.direction.is_some() {
                    inputs.push(&w.direction);
                }
                d.forward(params, &inputs, out);
            } else {
                d.forward(params, &[&before[i - 1]], out);
            }
        }
    }

    /// The colour of the last [`Self::forward`].
    fn rgb<'w>(&self, w: &'w ColorWork) -> &'w [f32] {
        w.acts.last().expect("an output layer")
    }

    /// Adds the weights' gradient into `grad` and writes `∂L/∂normal` into
    /// `d_normal`, given `∂L/∂rgb` in `d_rgb`.
    fn backward(
        &self,
        params: &[f32],
        normals: &[f32],
        d_rgb: &mut [f32],
        d_normal: &mut [f32],
        w: &mut ColorWork,
        grad: &mut [f32],
    ) {
        let ColorWork {
            position,
            direction,
            acts,
            d_a,
            d_b,
        } = w;
        d_a.clear();
        d_a.extend_from_slice(d_rgb);
        for i in (0..self.layers.len()).rev() {
            let d = &self.layers[i];
            if i == 0 {
                let mut inputs: Vec<&[f32]> = vec![position.as_slice(), normals];
                let mut d_in: Vec<Option<&mut [f32]>> = vec![None, Some(&mut *d_normal)];
                if self.direction.is_some() {
                    inputs.push(direction.as_slice());
                    d_in.push(None);
                }
                d.backward(params, &inputs, &acts[0], d_a, &mut d_in, false, grad);
            } else {
                d_b.resize(acts[i - 1].len(), 0.0);
                d.backward(
                    params,
                    &[acts[i - 1].as_slice()],
                    &acts[i],
                    d_a,
                    &mut [Some(d_b.as_mut_slice())],
                    false,
                    grad,
                );
                std::mem::swap(d_a, d_b);
            }
        }
    }
}

/// What each sample absorbs, as an optical depth, for rays of `n` samples
/// with distances `f` and intervals `delta`: the density's one definition
/// ([`DensityKind::neural_depth`]; compositing then takes unit intervals),
/// its slopes by forward duals: `slope[k] = ∂τ_k/∂f_k`, `slope_next[k] =
/// ∂τ_k/∂f_{k+1}` (0 where τ_k does not see the next sample) and
/// `slope_beta[k] = ∂τ_k/∂β`.
#[allow(clippy::too_many_arguments)]
fn absorption(
    kind: DensityKind,
    f: &[f32],
    delta: &[f32],
    n: usize,
    alpha: f32,
    beta: f32,
    out: &mut [f32],
    slope: &mut [f32],
    slope_next: &mut [f32],
    slope_beta: &mut [f32],
) {
    let inv_beta = Dual::<f32, 3>::one() / Dual::seed(beta, 2);
    let alpha = Dual::lit(alpha as f64);
    out.par_chunks_mut(n)
        .zip(slope.par_chunks_mut(n))
        .zip(
            slope_next
                .par_chunks_mut(n)
                .zip(slope_beta.par_chunks_mut(n)),
        )
        .zip(f.par_chunks(n).zip(delta.par_chunks(n)))
        .for_each(|(((a, s), (s_next, s_beta)), (f, delta))| {
            for k in 0..n {
                let next = f.get(k + 1).map(|&x| Dual::seed(x, 1));
                let d = Dual::lit(delta[k] as f64);
                let tau = kind.neural_depth(Dual::seed(f[k], 0), next, alpha, inv_beta, d);
                (a[k], s[k], s_next[k], s_beta[k]) = (tau.v, tau.d[0], tau.d[1], tau.d[2]);
            }
        });
}

/// The buffers of the pass that places fine samples
/// ([`SurfaceObjective::upsample`]), kept from step to step.
#[derive(Default)]
#[doc(hidden)]
pub struct Placing {
    points: Vec<f32>,
    dirs: Vec<f32>,
    /// Per coarse sample: the distance, what it absorbs and its slopes,
    /// and its weight in the ray's colour.
    f: Vec<f32>,
    a: Vec<f32>,
    s: Vec<f32>,
    s_next: Vec<f32>,
    s_beta: Vec<f32>,
    weights: Vec<f32>,
    /// The fine depths and the merged ones ([`fine_samples`]).
    depths: Vec<f32>,
}

/// A neural SDF with a colour network, fitted to images.
pub struct SurfaceObjective {
    /// The signed-distance network whose zero set is the surface.
    pub sdf: SurfaceSdf,
    /// The colour of each sample from its point, normal and (when view dependent) direction.
    pub color: ColorNet,
    spec: NeuralSurface,
    /// Weight of the eikonal term (the trainer weighs the colour term).
    eikonal: f32,
    /// Weight of the silhouette term (0: none).
    silhouette: f32,
    /// The training's steps, over which a scheduled β falls to
    /// `spec.beta_end`.
    steps: usize,
    /// Empty space skipped (a hash-grid SDF): the grid, and each step's
    /// rays that cross it.
    #[doc(hidden)]
    pub skip: Option<SkipGrid>,
    selection: Selection,
    /// Samples the networks evaluated in this process's steps: counted,
    /// never read by a step.
    evaluated: u64,
    samples: Samples,
    /// The samples with the fine ones merged in.
    merged: Samples,
    placing: Placing,
    points: Vec<f32>,
    dirs: Vec<f32>,
    sdf_work: GeometryWork,
    color_work: ColorWork,
    /// Per sample: what it absorbs ([`absorption`]) and its slopes.
    sigma: Vec<f32>,
    slope: Vec<f32>,
    slope_next: Vec<f32>,
    slope_beta: Vec<f32>,
    /// Unit intervals: compositing takes optical depths.
    ones: Vec<f32>,
    d_sigma: Vec<f32>,
    d_rgb: Vec<f32>,
    d_f: Vec<f32>,
    d_g: Vec<f32>,
    d_normal: Vec<f32>,
}

impl SurfaceObjective {
    /// The objective of `spec`, weighing its eikonal term as `losses`
    /// says; refuses a hash grid the runtime cannot build.
    pub fn new(spec: &NeuralSurface, losses: &[Loss]) -> Result<Self, String> {
        let sdf = SurfaceSdf::new(&spec.sdf)?;
        let color = ColorNet::new(spec, sdf.len());
        Ok(SurfaceObjective {
            eikonal: losses
                .iter()
                .filter(|l| l.kind == LossKind::Eikonal)
                .map(|l| l.weight as f32)
                .sum(),
            silhouette: losses
                .iter()
                .filter(|l| l.kind == LossKind::Silhouette)
                .map(|l| l.weight as f32)
                .sum(),
            sdf,
            color,
            steps: 1,
            spec: spec.clone(),
            skip: SkipGrid::of(spec)?,
            selection: Selection::default(),
            evaluated: 0,
            samples: Samples::default(),
            merged: Samples::default(),
            placing: Placing::default(),
            points: Vec::new(),
            dirs: Vec::new(),
            sdf_work: GeometryWork::default(),
            color_work: ColorWork::default(),
            sigma: Vec::new(),
            slope: Vec::new(),
            slope_next: Vec::new(),
            slope_beta: Vec::new(),
            ones: Vec::new(),
            d_sigma: Vec::new(),
            d_rgb: Vec::new(),
            d_f: Vec::new(),
            d_g: Vec::new(),
            d_normal: Vec::new(),
        })
    }

    /// The grid that skips empty space, if any.
    pub fn skip_grid(&self) -> Option<&SkipGrid> {
        self.skip.as_ref()
    }

    /// Refreshes the skipping grid from the distance at `values` when
    /// `step` is due, and otherwise widens it to this step's β (see
    /// [`skip`]).
    #[doc(hidden)]
    pub fn refresh_skip(&mut self, values: &[f32], step: usize) {
        let (beta, alpha) = (self.beta(values), self.spec.alpha as f32);
        let (sdf, params, kind) = (&self.sdf, &values[..self.sdf.len()], self.spec.density);
        if let Some(g) = self.skip.as_mut() {
            let band = skip::band(kind, alpha, beta, g.diagonal());
            if g.due(step) {
                g.refresh(step, band, |points, out| {
                    sdf.distance(params, points.as_flattened(), Levels::AtStep(step), out)
                });
            } else {
                g.widen(band);
            }
        }
    }

    /// A run of `steps` steps: a scheduled β reaches `beta_end` at the last.
    pub fn with_steps(mut self, steps: usize) -> Self {
        self.steps = steps;
        self
    }

    /// β at `step` of a schedule from `spec.beta` to `spec.beta_end`,
    /// geometric (`ln β` falls linearly) and `beta_end` from the last step
    /// on; `spec.beta` without a schedule.
    pub fn scheduled_beta(&self, step: usize) -> f64 {
        match self.spec.beta_end {
            Some(end) => {
                let s = (step as f64 / self.steps.saturating_sub(1).max(1) as f64).min(1.0);
                self.spec.beta * (end / self.spec.beta).powf(s)
            }
            None => self.spec.beta,
        }
    }

    /// The distance network's share of the parameters.
    pub fn sdf_params<'p>(&self, params: &'p [f32]) -> &'p [f32] {
        &params[..self.sdf.len()]
    }

    /// Where `log β` is kept when β is trained or scheduled (after the
    /// colour network).
    #[doc(hidden)]
    pub fn beta_at(&self) -> Option<usize> {
        (self.spec.train_beta || self.spec.beta_end.is_some()).then(|| self.color.end())
    }

    /// β at `params`: trained (`e^(BETA_RATE·θ)`, kept in range by
    /// [`Objective::project`]), scheduled (kept in the same form, set by
    /// [`Objective::at_step`]; its gradient is not taken) or fixed.
    pub fn beta(&self, params: &[f32]) -> f32 {
        match self.beta_at() {
            Some(i) => (BETA_RATE * params[i]).exp(),
            None => self.spec.beta as f32,
        }
    }

    fn background(&self) -> [f32; 3] {
        self.spec.background.map(|x| x as f32)
    }

    fn densities(&mut self, n: usize, b: f32) {
        let (a, kind) = (self.spec.alpha as f32, self.spec.density);
        let f = self.sdf.distances(&self.sdf_work);
        for v in [
            &mut self.sigma,
            &mut self.slope,
            &mut self.slope_next,
            &mut self.slope_beta,
        ] {
            v.resize(f.len(), 0.0);
        }
        absorption(
            kind,
            f,
            &self.samples.delta,
            n,
            a,
            b,
            &mut self.sigma,
            &mut self.slope,
            &mut self.slope_next,
            &mut self.slope_beta,
        );
    }

    /// Adds `spec.fine` samples per ray where the surface is: a
    /// distance-only pass over the `n` samples of each ray in `coarse`
    /// weighs them, with β widened to half the mean coarse interval so that
    /// no surface between two samples goes unseen; the fine depths come by
    /// inverse CDF, merged in (`n + fine` a ray into `out`). Where samples
    /// go is a constant to the gradient.
    #[allow(clippy::too_many_arguments)]
    #[doc(hidden)]
    pub fn upsample(
        &self,
        params: &[f32],
        levels: Levels,
        beta: f32,
        rays: &[Ray],
        coarse: &Samples,
        n: usize,
        spacing: Spacing,
        last: LastInterval,
        work: &mut Placing,
        out: &mut Samples,
    ) -> Result<(), VolumeError> {
        let Placing {
            points,
            dirs,
            f,
            a,
            s,
            s_next,
            s_beta,
            weights,
            depths,
        } = work;
        coarse.points(rays, points, dirs);
        let rows = points.len() / 3;
        for v in [
            &mut *f,
            &mut *a,
            &mut *s,
            &mut *s_next,
            &mut *s_beta,
            &mut *weights,
        ] {
            v.resize(rows, 0.0);
        }
        self.sdf
            .distance(&params[..self.sdf.len()], points, levels, f);
        let span: f32 = coarse.t.chunks(n).map(|t| t[n - 1] - t[0]).sum::<f32>()
            / (coarse.rays().max(1) * (n - 1).max(1)) as f32;
        absorption(
            self.spec.density,
            f,
            &coarse.delta,
            n,
            self.spec.alpha as f32,
            beta.max(0.5 * span),
            a,
            s,
            s_next,
            s_beta,
        );
        weights
            .par_chunks_mut(n)
            .zip(a.par_chunks(n))
            .for_each(|(w, a)| {
                let mut trans = 1.0f32;
                for k in 0..n {
                    let tau = a[k];
                    w[k] = trans * -(-tau).exp_m1();
                    trans *= (-tau).exp();
                }
            });
        fine_samples(
            coarse,
            n,
            weights,
            self.spec.fine,
            spacing,
            last,
            depths,
            out,
        )
    }

    /// Renders one view: colour and expected depth per pixel.
    pub fn render_view(
        &self,
        params: &[f32],
        sampler: &Stratified,
        last: LastInterval,
        cam: &Camera,
        size: ImageSize,
    ) -> Result<NerfView, VolumeError> {
        sampler.validate()?;
        let rays = camera_rays(cam, size)?;
        let t = sampler.depths();
        let n = t.len().max(1) + self.spec.fine;
        let mut view = NerfView {
            colour: vec![[0.0; 3]; rays.len()],
            depth: vec![0.0; rays.len()],
            opacity: Vec::new(),
            evaluated: 0,
        };
        let per_pass = (RENDER_ROWS / n).max(1);
        let (mut samples, mut points, mut dirs) = (Samples::default(), Vec::new(), Vec::new());
        let (mut coarse, mut placing) = (Samples::default(), Placing::default());
        let (mut sdf_work, mut color_work) = (GeometryWork::default(), ColorWork::default());
        let mut selection = Selection::default();
        let (a, b) = (self.spec.alpha as f32, self.beta(params));
        // Where β has grown past the band the grid was marked with (by the
        // last step's update), a copy widened as the next step would widen it.
        let widened;
        let grid = match skipping(self.skip.as_ref(), last) {
            Some(g) => {
                let band = skip::band(self.spec.density, a, b, g.diagonal());
                if g.covers(band) {
                    Some(g)
                } else {
                    let mut wide = g.clone();
                    wide.widen(band);
                    widened = wide;
                    Some(&widened)
                }
            }
            None => None,
        };
        let mut shaded = Vec::new();
        for (all, (colour, depth)) in rays.chunks(per_pass).zip(
            view.colour
                .chunks_mut(per_pass)
                .zip(view.depth.chunks_mut(per_pass)),
        ) {
            // Rays crossing no occupied cell see the background.
            selection.select(grid, all, t.len(), |_| &t, |_| false);
            for &r in &selection.misses {
                (colour[r], depth[r]) = (self.background(), 0.0);
            }
            if selection.hits.is_empty() {
                continue;
            }
            let (chunk, depths) = (&selection.rays, &selection.depths);
            let m = t.len();
            if self.spec.fine > 0 {
                coarse.fixed(chunk.len(), m, |r| &depths[r * m..(r + 1) * m], last);
                view.evaluated += coarse.t.len();
                self.upsample(
                    params,
                    Levels::All,
                    b,
                    chunk,
                    &coarse,
                    t.len(),
                    Spacing::Even,
                    last,
                    &mut placing,
                    &mut samples,
                )?;
            } else {
                samples.fixed(chunk.len(), m, |r| &depths[r * m..(r + 1) * m], last);
            }
            samples.points(chunk, &mut points, &mut dirs);
            self.sdf.forward(
                &params[..self.sdf.len()],
                &points,
                Levels::All,
                &mut sdf_work,
            );
            view.evaluated += points.len() / 3;
            let f = self.sdf.distances(&sdf_work);
            let mut sigma = vec![0.0; f.len()];
            let (mut slope, mut slope_next, mut slope_beta) =
                (vec![0.0; f.len()], vec![0.0; f.len()], vec![0.0; f.len()]);
            absorption(
                self.spec.density,
                f,
                &samples.delta,
                n,
                a,
                b,
                &mut sigma,
                &mut slope,
                &mut slope_next,
                &mut slope_beta,
            );
            let delta = vec![1.0; f.len()];
            self.color.forward(
                params,
                &points,
                self.sdf.gradients(&sdf_work),
                &dirs,
                &mut color_work,
            );
            let rgb = self.color.rgb(&color_work);
            shaded.resize(chunk.len(), ([0.0; 3], 0.0));
            shaded.par_iter_mut().enumerate().for_each(|(r, out)| {
                let k = r * n..(r + 1) * n;
                let c = composite(
                    &sigma[k.clone()],
                    &rgb[3 * k.start..3 * k.end],
                    &samples.t[k.clone()],
                    &delta[k.clone()],
                    self.background(),
                );
                *out = (c.colour, c.depth);
            });
            for (&r, &(c, d)) in selection.hits.iter().zip(&shaded) {
                (colour[r], depth[r]) = (c, d);
            }
        }
        Ok(view)
    }
}

impl Objective for SurfaceObjective {
    fn tensors(&self) -> Vec<TensorSpec> {
        let sdf = self.sdf.tensors();
        let n = self.color.layers.len();
        let color = self
            .color
            .layers
            .iter()
            .enumerate()
            .flat_map(move |(i, d)| {
                let name = if i + 1 == n {
                    "color.out".to_string()
                } else {
                    format!("color.{i}")
                };
                d.tensors(&name)
            });
        let beta = self.beta_at().map(|offset| TensorSpec {
            name: "log_beta".into(),
            offset,
            len: 1,
        });
        sdf.into_iter().chain(color).chain(beta).collect()
    }

    fn project(&self, values: &mut [f32]) {
        // β from 1e-4 (where f32 densities still resolve) to 10.
        if let (Some(i), true) = (self.beta_at(), self.spec.train_beta) {
            values[i] = values[i].clamp((1e-4f32).ln() / BETA_RATE, (10f32).ln() / BETA_RATE);
        }
    }

    fn initial(&self) -> Vec<f32> {
        let mut v = self
            .sdf
            .initial(self.spec.sdf.seed, self.spec.sdf.radius as f32);
        v.resize(self.color.end(), 0.0);
        let mut rng = SplitMix64::new(self.spec.sdf.seed ^ 0x0063_6f6c_6f72);
        for d in &self.color.layers {
            d.init(&mut v, &mut rng);
        }
        if self.beta_at().is_some() {
            v.push((self.scheduled_beta(0) as f32).ln() / BETA_RATE);
        }
        v
    }

    /// The skipping grid: a resumed run sees the grid the uninterrupted
    /// one did.
    fn state(&self) -> Vec<(String, Vec<f32>)> {
        self.skip.as_ref().map_or_else(Vec::new, SkipGrid::state)
    }

    fn restore_state(&mut self, state: &[(String, Vec<f32>)]) -> Result<(), TrainError> {
        let names: Vec<&str> = state.iter().map(|s| s.0.as_str()).collect();
        match (&mut self.skip, names.as_slice()) {
            // A checkpoint from before skipping: as if never refreshed
            // (the first interval skips nothing), as safe as a fresh start.
            (None, []) | (Some(_), []) => Ok(()),
            (Some(g), ["skip.distance", "skip.refresh"]) => g
                .restore(&state[0].1, &state[1].1)
                .map_err(TrainError::Invalid),
            _ => Err(TrainError::Invalid(format!(
                "the checkpoint holds state {names:?}, which this model does not have"
            ))),
        }
    }

    fn at_step(&self, step: usize, values: &mut [f32]) {
        if let (Some(i), Some(_)) = (self.beta_at(), self.spec.beta_end) {
            values[i] = (self.scheduled_beta(step) as f32).ln() / BETA_RATE;
        }
    }

    fn samples_evaluated(&self) -> Option<u64> {
        Some(self.evaluated)
    }

    fn loss_and_grad(
        &mut self,
        values: &[f32],
        batch: &Batch,
        weight: f64,
        grad: &mut [f32],
    ) -> Result<f64, TrainError> {
        let rays: &[Ray] = &batch.rays;
        let n = batch.samples;
        if rays.is_empty() || n == 0 {
            return Err(TrainError::Invalid(
                "a neural SDF's volume trains on rays, and the batch has none".into(),
            ));
        }
        if self.silhouette > 0.0 && batch.coverage.len() != rays.len() {
            return Err(TrainError::Invalid(
                "`silhouette()` needs each pixel's coverage, and these views do not give it".into(),
            ));
        }
        self.refresh_skip(values, batch.step);
        // The rays that cross occupied cells, their depths on their spans;
        // taken out of `self` for the step, put back at its end.
        let mut selection = std::mem::take(&mut self.selection);
        let grid = skipping(self.skip.as_ref(), batch.last_interval);
        let pulled = self.silhouette > 0.0;
        selection.select(
            grid,
            rays,
            n,
            |r| batch.depths_of(r),
            |r| pulled && batch.coverage[r] > 0.0,
        );
        let result = self.fit_selected(values, batch, weight, &selection, grad);
        self.evaluated += selection.depths.len() as u64;
        self.selection = selection;
        result
    }
}

/// The grid to skip by, if any: none with an infinite last interval, where
/// the last sample's absorption beyond a cut span's end would make a ray
/// that passes near the surface opaque.
#[doc(hidden)]
pub fn skipping(grid: Option<&SkipGrid>, last: LastInterval) -> Option<&SkipGrid> {
    grid.filter(|_| last != LastInterval::Infinite)
}

impl SurfaceObjective {
    /// The loss of [`Objective::loss_and_grad`] over the selected rays
    /// (their samples) and the missed ones (the background, opacity 0).
    fn fit_selected(
        &mut self,
        values: &[f32],
        batch: &Batch,
        weight: f64,
        selection: &Selection,
        grad: &mut [f32],
    ) -> Result<f64, TrainError> {
        let all = batch.rays.len();
        // `weight` scales the image terms as the trainer weighs them; the
        // MSE is a mean over rays and channels.
        let scale = (weight / (3 * all) as f64) as f32;
        // The silhouette term is a mean over rays.
        let silhouette = self.silhouette / all as f32;
        let background = self.background();
        // A missed ray: the same terms through no samples (in ray order,
        // summed after the sampled rays').
        let mut missed = 0f64;
        let mut trans = Vec::new();
        for &r in &selection.misses {
            missed += squared_error_backward(
                &[],
                &[],
                &[],
                &[],
                background,
                batch.targets[r],
                scale,
                &mut [],
                &mut [],
                &mut trans,
            );
            if silhouette > 0.0 {
                missed += silhouette_backward(&[], &[], batch.coverage[r], silhouette, &mut []);
            }
        }
        let rays: &[Ray] = &selection.rays;
        if rays.is_empty() {
            return Ok(missed);
        }
        let n = batch.samples;
        let depths = &selection.depths;
        self.samples.fixed(
            rays.len(),
            n,
            |r| &depths[r * n..(r + 1) * n],
            batch.last_interval,
        );
        let n = if self.spec.fine > 0 {
            let spacing = if batch.shared {
                Spacing::Even
            } else {
                Spacing::Jittered(batch.seed)
            };
            let (mut merged, mut placing) = (
                std::mem::take(&mut self.merged),
                std::mem::take(&mut self.placing),
            );
            let placed = self.upsample(
                values,
                Levels::AtStep(batch.step),
                self.beta(values),
                rays,
                &self.samples,
                n,
                spacing,
                batch.last_interval,
                &mut placing,
                &mut merged,
            );
            self.placing = placing;
            placed.map_err(|e| TrainError::Invalid(e.to_string()))?;
            std::mem::swap(&mut self.samples, &mut merged);
            self.merged = merged;
            n + self.spec.fine
        } else {
            n
        };
        self.samples.points(rays, &mut self.points, &mut self.dirs);
        let sdf_params = &values[..self.sdf.len()];
        self.sdf.forward(
            sdf_params,
            &self.points,
            Levels::AtStep(batch.step),
            &mut self.sdf_work,
        );
        let beta = self.beta(values);
        self.densities(n, beta);
        self.color.forward(
            values,
            &self.points,
            self.sdf.gradients(&self.sdf_work),
            &self.dirs,
            &mut self.color_work,
        );
        let rows = self.points.len() / 3;
        self.d_sigma.resize(rows, 0.0);
        self.d_rgb.resize(3 * rows, 0.0);
        self.ones.resize(rows, 1.0);
        let (sigma, rgb) = (&self.sigma, self.color.rgb(&self.color_work));
        let (t, delta) = (&self.samples.t, &self.ones);
        let losses: Vec<f64> = self
            .d_sigma
            .par_chunks_mut(RAY_BLOCK * n)
            .zip(self.d_rgb.par_chunks_mut(3 * RAY_BLOCK * n))
            .enumerate()
            .map(|(blk, (d_sigma, d_rgb))| {
                let mut trans = Vec::new();
                let mut loss = 0f64;
                for (j, (ds, dc)) in d_sigma
                    .chunks_mut(n)
                    .zip(d_rgb.chunks_mut(3 * n))
                    .enumerate()
                {
                    let r = blk * RAY_BLOCK + j;
                    let k = r * n..(r + 1) * n;
                    // The ray's index in the batch.
                    let b = selection.hits[r];
                    let (sg, c) = (&sigma[k.clone()], &rgb[3 * k.start..3 * k.end]);
                    loss += squared_error_backward(
                        sg,
                        c,
                        &t[k.clone()],
                        &delta[k.clone()],
                        background,
                        batch.targets[b],
                        scale,
                        ds,
                        dc,
                        &mut trans,
                    );
                    if silhouette > 0.0 {
                        loss += silhouette_backward(
                            sg,
                            &delta[k.clone()],
                            batch.coverage[b],
                            silhouette,
                            ds,
                        );
                    }
                }
                loss
            })
            .collect();
        let mut loss: f64 = losses.iter().sum::<f64>() + missed;
        // The colour network: its weights, and the normal's adjoint.
        self.d_normal.resize(3 * rows, 0.0);
        self.color.backward(
            values,
            self.sdf.gradients(&self.sdf_work),
            &mut self.d_rgb,
            &mut self.d_normal,
            &mut self.color_work,
            grad,
        );
        // A trained β: ∂τ_k/∂β from [`absorption`]'s duals; through
        // β = e^(rate·θ), times rate·β.
        let (slope, slope_next, d_sigma) = (&self.slope, &self.slope_next, &self.d_sigma);
        if let (Some(i), true) = (self.beta_at(), self.spec.train_beta) {
            let slope_beta = &self.slope_beta;
            // Sums of fixed chunks, added in order: the same bits at any
            // thread count (rayon's own sum splits by the pool).
            let sums: Vec<f64> = d_sigma[..rows]
                .par_chunks(4096)
                .zip(slope_beta[..rows].par_chunks(4096))
                .map(|(d, s)| d.iter().zip(s).map(|(d, s)| (d * s) as f64).sum())
                .collect();
            let d_beta: f64 = sums.iter().sum();
            grad[i] += (d_beta * beta as f64 * BETA_RATE as f64) as f32;
        }
        // ∂L/∂f_k through what sample k absorbs and (NeuS) what the
        // interval before it absorbs; ∂L/∂∇f from the colour and the
        // eikonal term at every sample.
        self.d_f.resize(rows, 0.0);
        self.d_f
            .par_chunks_mut(n)
            .zip(d_sigma.par_chunks(n))
            .zip(slope.par_chunks(n).zip(slope_next.par_chunks(n)))
            .for_each(|((d, ds), (s, s_next))| {
                for k in 0..n {
                    d[k] = ds[k] * s[k];
                    if k > 0 {
                        d[k] += ds[k - 1] * s_next[k - 1];
                    }
                }
            });
        self.d_g.resize(3 * rows, 0.0);
        if self.eikonal > 0.0 {
            loss += eikonal_loss(
                self.sdf.gradients(&self.sdf_work),
                self.eikonal,
                &mut self.d_g,
            );
        } else {
            self.d_g.fill(0.0);
        }
        for (d, n) in self.d_g.iter_mut().zip(&self.d_normal) {
            *d += n;
        }
        self.sdf.backward(
            sdf_params,
            &self.points,
            &self.d_f,
            &self.d_g,
            &mut self.sdf_work,
            &mut grad[..self.sdf.len()],
        );
        Ok(loss)
    }
}

impl TrainedField for Trained<SurfaceObjective> {
    fn render_view(
        &self,
        values: &[f32],
        cam: &Camera,
        size: ImageSize,
        _want_depth: bool,
    ) -> Result<View, String> {
        let (strat, last) = (&self.viewing.strat, self.viewing.sampler.last_interval);
        let v = self
            .objective
            .render_view(values, strat, last, cam, size)
            .map_err(|e| e.to_string())?;
        Ok(View {
            colour: v.colour,
            depth: v.depth,
            opacity: Vec::new(),
        })
    }

    fn surface<'a>(&'a self, values: &'a [f32]) -> Option<Box<dyn DistanceField + 'a>> {
        let field = self.objective.sdf.field(self.objective.sdf_params(values));
        Some(Box::new(crate::mesh::Lipschitz(field, 2.0)))
    }

    fn region(&self) -> Option<Region> {
        self.viewing.region
    }

    fn geometry_view(
        &self,
        values: &[f32],
        cam: &Camera,
        size: ImageSize,
    ) -> Option<Result<Vec<[f32; 3]>, String>> {
        let settings = TraceSettings {
            far: self.viewing.sampler.far as f32,
            ..Default::default()
        };
        let field = self.objective.sdf.field(self.objective.sdf_params(values));
        Some(
            trace_field(&field, cam, size, settings)
                .map(|v| v.colour)
                .map_err(|e| e.to_string()),
        )
    }

    /// A trained or scheduled β, by its value (it is kept as `ln β / BETA_RATE`).
    fn reported(&self, values: &[f32]) -> Vec<(String, Vec<f32>)> {
        let o = &self.objective;
        o.beta_at()
            .map(|_| ("beta".to_string(), vec![o.beta(values)]))
            .into_iter()
            .collect()
    }

    fn is_network(&self) -> bool {
        true
    }

    fn describe(&self) -> Description {
        let (o, n) = (&self.objective, &self.objective.spec);
        let beta = usize::from(o.beta_at().is_some());
        let weights = o.tensors().iter().map(|t| t.len).sum::<usize>() - beta;
        let bounds = self.viewing.region.map_or(0.0, |r| r.1[0]);
        Description {
            trainable: format!(
                "all {weights} weights ({}, colour network {}){}, the distance starting as a sphere of radius {}",
                o.sdf.describe(),
                weights - o.sdf.len(),
                match (n.train_beta, n.beta_end) {
                    (true, _) => format!(", and beta from {} (as ln(beta)/{BETA_RATE}: it moves {BETA_RATE} times faster than a weight; kept in 1e-4..10)", n.beta),
                    (false, Some(end)) => format!(" (beta is not trained: it falls geometrically from {} to {end} over the steps)", n.beta),
                    (false, None) => String::new(),
                },
                n.sdf.radius
            ),
            gradient: format!(
                "none: {}; colour network, density and compositing by hand-written backward passes",
                o.sdf.gradient_words()
            ),
            mesh_region: format!("[-{bounds}, {bounds}]^3"),
        }
    }
}

pub mod geometry;
pub mod skip;
