//! The field-agnostic training loop: seeded ray batches over all views →
//! samples → field → density → compositing → weighted losses → Adam
//! (dfdx's kernel) → projection into each parameter's range.
//!
//! A step depends only on (seed, step, parameters, Adam state): its batch
//! and jitter are drawn from a generator seeded by the step, and the kernel
//! reduces in a fixed order. So a run stopped at step k and resumed from its
//! checkpoint ends bit-identical to one that never stopped.

use std::ops::ControlFlow;

use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::value::{Loss, Moments, Optimizer, Sampler};

use super::checkpoint::{Checkpoint, ParamState};
use super::export_names::{Layout, Piece};
use super::fused::Batch;
use super::objective::{Objective, TensorSpec};
use super::{Adam, ParamId, ParamStore, TrainError};
use crate::volume::{random_rays, ImageSize, SplitMix64, Stratified};

pub use crate::data::TrainView;

/// What a run needs besides the model.
#[derive(Debug, Clone)]
pub struct TrainSetup<'a> {
    /// The views whose pixels the rays are drawn from (empty for a point cloud).
    pub views: &'a [TrainView],
    /// A point cloud: batches are `rays` of its points instead of rays.
    pub points: &'a [[f32; 3]],
    /// Where along each ray samples are placed.
    pub sampler: Sampler,
    /// Rays (or points) per step.
    pub rays: usize,
    /// The optimiser and its learning rate schedule.
    pub optimizer: Optimizer,
    /// The weighted loss terms.
    pub losses: &'a [Loss],
    /// Seed of every random draw: a run is a function of (seed, step).
    pub seed: u64,
}

impl<'a> TrainSetup<'a> {
    /// A `train` statement's setup over its loaded views.
    pub fn of(job: &'a sdfl_stdlib::value::TrainJob, views: &'a [TrainView]) -> Self {
        TrainSetup {
            views,
            points: &[],
            sampler: job.sampler,
            rays: job.rays,
            optimizer: job.optimizer,
            losses: &job.losses,
            seed: job.seed,
        }
    }

    /// Steps of one pass over every training pixel.
    pub fn steps_per_epoch(&self) -> usize {
        let pixels: usize =
            self.views.iter().map(|v| v.image.len()).sum::<usize>() + self.points.len();
        pixels.div_ceil(self.rays.max(1)).max(1)
    }

    fn size(&self) -> Result<ImageSize, TrainError> {
        let first = self
            .views
            .first()
            .ok_or_else(|| TrainError::Invalid("no training views".into()))?;
        let (w, h) = (first.image.width, first.image.height);
        if let Some(v) = self
            .views
            .iter()
            .find(|v| (v.image.width, v.image.height) != (w, h))
        {
            return Err(TrainError::Invalid(format!(
                "training views differ in size ({w}×{h} and {}×{})",
                v.image.width, v.image.height
            )));
        }
        Ok(ImageSize {
            width: w,
            height: h,
        })
    }

    /// The batch of step `step`: a function of the seed and the step only.
    pub fn batch(&self, step: usize) -> Result<Batch, TrainError> {
        if !self.points.is_empty() {
            return Ok(self.point_batch(step));
        }
        let size = self.size()?;
        let cams: Vec<Camera> = self.views.iter().map(|v| v.camera).collect();
        let step_seed = self.step_seed(step);
        let mut rng = SplitMix64::new(step_seed);
        let total = size.pixels() * cams.len();
        let mut rays = random_rays(&cams, size, self.rays.min(total), &mut rng)?;
        // Masked pixels are drawn and dropped: the batch stays a function
        // of (seed, step), a little smaller where masks cover the views.
        if self.views.iter().any(|v| v.mask.is_some()) {
            rays.retain(|r| {
                self.views[r.view as usize]
                    .mask
                    .as_ref()
                    .is_none_or(|m| m.get(r.pixel as usize).copied().unwrap_or(false))
            });
            if rays.is_empty() {
                return Err(TrainError::Invalid(format!(
                    "every ray of step {step}'s batch fell on masked pixels: the masks leave too little of the views"
                )));
            }
        }
        let targets = rays
            .iter()
            .map(|r| self.views[r.view as usize].image.pixel(r.pixel as usize))
            .collect();
        // Each ray's pixel coverage where every view knows it (else none:
        // the language allows `silhouette()` only on such data).
        let coverage = if self.views.iter().all(|v| v.coverage.is_some()) {
            rays.iter()
                .map(|r| {
                    self.views[r.view as usize]
                        .coverage
                        .as_ref()
                        .and_then(|c| c.get(r.pixel as usize))
                        // 255ths: 0 and 255 give exactly 0 and 1.
                        .map_or(0.0, |&c| f32::from(c) / 255.0)
                })
                .collect()
        } else {
            Vec::new()
        };
        let s = &self.sampler;
        let strat = Stratified::new(s.samples, s.near as f32, s.far as f32)?;
        let depths = if s.jitter {
            let mut d = vec![0f32; rays.len() * s.samples];
            for row in d.chunks_mut(s.samples) {
                strat.jittered_into(&mut rng, row)?;
            }
            d
        } else {
            strat.depths()
        };
        Ok(Batch {
            rays,
            targets,
            coverage,
            depths,
            samples: s.samples,
            shared: !s.jitter,
            last_interval: s.last_interval,
            seed: step_seed,
            step,
            points: Vec::new(),
        })
    }

    fn step_seed(&self, step: usize) -> u64 {
        self.seed
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(step as u64)
    }

    /// `rays` points of the cloud drawn with replacement: a function of the
    /// seed and the step only.
    fn point_batch(&self, step: usize) -> Batch {
        let seed = self.step_seed(step);
        let mut rng = SplitMix64::new(seed);
        let n = self.points.len() as u64;
        let points = (0..self.rays)
            .flat_map(|_| self.points[rng.below(n) as usize])
            .collect();
        Batch {
            rays: Vec::new(),
            targets: Vec::new(),
            coverage: Vec::new(),
            depths: Vec::new(),
            samples: 0,
            shared: true,
            last_interval: self.sampler.last_interval,
            seed,
            step,
            points,
        }
    }
}

/// The state of a run: the model, its parameters in the store, Adam,
/// losses so far. The model is any [`Objective`]; a job's is a
/// [`super::TrainedField`], which it renders and meshes between steps.
pub struct Run<O: Objective + ?Sized = dyn Objective> {
    /// The model's loss and gradient.
    pub objective: Box<O>,
    /// The objective's tensors, in order.
    #[doc(hidden)]
    pub tensors: Vec<TensorSpec>,
    store: ParamStore,
    ids: Vec<ParamId>,
    adam: Adam,
    /// Reused each step.
    grad: Vec<f32>,
    /// The values a step reads, refreshed in place from the store.
    step_values: Vec<f32>,
    /// Steps done.
    pub step: usize,
    /// The loss of every step done.
    pub losses: Vec<f32>,
    /// How checkpoints store the tensors (flat under their names until
    /// [`Run::describe`]).
    #[doc(hidden)]
    pub layout: Layout,
}

impl<O: Objective + ?Sized> Run<O> {
    /// A fresh run of any model at its starting values, with Adam's
    /// default moments.
    pub fn of(objective: Box<O>, lr: f64) -> Result<Self, TrainError> {
        Self::with(objective, lr, Moments::default())
    }

    /// A fresh run of a `train` statement's model under its optimizer.
    pub fn for_optimizer(objective: Box<O>, optimizer: &Optimizer) -> Result<Self, TrainError> {
        Self::with(objective, optimizer.lr, optimizer.moments)
    }

    /// A fresh run of any model at its starting values.
    fn with(objective: Box<O>, lr: f64, moments: Moments) -> Result<Self, TrainError> {
        let mut store = ParamStore::new();
        let init = objective.initial();
        let tensors = objective.tensors();
        let ids = tensors
            .iter()
            .map(|p| store.add(&p.name, &init[p.offset..p.offset + p.len], true))
            .collect::<Result<_, _>>()?;
        let layout = Layout::flat(&tensors, serde_json::Value::Null);
        Ok(Run {
            layout,
            grad: vec![0.0; init.len()],
            step_values: vec![0.0; init.len()],
            objective,
            tensors,
            store,
            ids,
            adam: Adam::with_moments(lr, moments)?,
            step: 0,
            losses: Vec::new(),
        })
    }

    /// Names, shapes and the specification checkpoints give the model's
    /// tensors ([`Layout::of`] its field); a layout that does not cover
    /// the tensors is ignored (they stay flat).
    pub fn describe(&mut self, layout: Layout) {
        let covers = layout.params.len() == self.tensors.len()
            && layout.params.iter().zip(&self.tensors).all(|(pieces, t)| {
                pieces
                    .iter()
                    .map(|p| p.len().unwrap_or(usize::MAX))
                    .try_fold(0usize, |a, n| a.checked_add(n))
                    == Some(t.len)
            });
        if covers {
            self.layout = layout;
        }
    }

    /// Continues from a checkpoint of the same model.
    pub fn resume(&mut self, ck: &Checkpoint) -> Result<(), TrainError> {
        let theirs: Vec<(&str, usize)> = ck
            .params
            .iter()
            .map(|p| (p.name.as_str(), p.values.len()))
            .collect();
        let ours: Vec<(&str, usize)> = self
            .tensors
            .iter()
            .map(|p| (p.name.as_str(), p.len))
            .collect();
        if theirs != ours {
            let names = |v: &[(&str, usize)]| {
                let mut s: Vec<String> = v
                    .iter()
                    .take(8)
                    .map(|(n, l)| format!("{n} ({l})"))
                    .collect();
                if v.len() > 8 {
                    s.push(format!("… {} more", v.len() - 8));
                }
                s.join(", ")
            };
            return Err(TrainError::Invalid(format!(
                "the checkpoint holds parameters [{}], the model has [{}]",
                names(&theirs),
                names(&ours)
            )));
        }
        // A file of this format stores each tensor as the model does (a
        // first-format file has no pieces and is flat), or whole and flat
        // under its trainer name, as files did before neural SDFs' tensors
        // were named and shaped (the values read back in the trainer's
        // order either way).
        if !ck.pieces.is_empty() {
            for (i, ours) in self.layout.params.iter().enumerate() {
                let theirs = ck.pieces.get(i).map_or(&[][..], |p| &p[..]);
                let t = &self.tensors[i];
                let flat = theirs == [Piece::flat(&t.name, t.len)];
                if theirs != &ours[..] && !flat {
                    let show = |p: &[Piece]| {
                        p.iter()
                            .map(|q| {
                                format!(
                                    "`{}` {:?}{}",
                                    q.name,
                                    q.shape,
                                    if q.transposed { " (out, in)" } else { "" }
                                )
                            })
                            .collect::<Vec<_>>()
                            .join(", ")
                    };
                    return Err(TrainError::Invalid(format!(
                        "the checkpoint stores `{}` as {}, the model as {}",
                        self.tensors[i].name,
                        show(theirs),
                        show(ours)
                    )));
                }
            }
        }
        // Every value finite and in its parameter's range (what projection
        // keeps).
        let mut flat: Vec<f32> = ck.params.iter().flat_map(|p| p.values.clone()).collect();
        let read = flat.clone();
        self.objective.project(&mut flat);
        if let Some(k) = (0..flat.len())
            .find(|&k| !read[k].is_finite() || flat[k].to_bits() != read[k].to_bits())
        {
            let name = &self.tensors[self.tensor_at(k)].name;
            return Err(TrainError::Invalid(if read[k].is_finite() {
                format!(
                    "`{name}` is {}, outside its range (nearest allowed: {})",
                    read[k], flat[k]
                )
            } else {
                format!("`{name}` is {}, outside its range (not finite)", read[k])
            }));
        }
        for (id, p) in self.ids.iter().zip(&ck.params) {
            self.store.restore(*id, &p.values, &p.adam_m, &p.adam_v)?;
        }
        self.objective.restore_state(&ck.state)?;
        self.adam.set_steps(ck.adam_steps);
        self.step = ck.step;
        self.losses = ck.losses.clone();
        Ok(())
    }

    /// The tensor that flat index `k` lies in.
    fn tensor_at(&self, k: usize) -> usize {
        self.tensors
            .iter()
            .position(|t| (t.offset..t.offset + t.len).contains(&k))
            .unwrap_or(0)
    }

    /// The current values, flat in the model's order.
    pub fn values(&self) -> Vec<f32> {
        self.ids
            .iter()
            .flat_map(|id| self.store.values(*id))
            .collect()
    }

    /// Each parameter's name and values.
    pub fn named_values(&self) -> Vec<(String, Vec<f32>)> {
        self.ids
            .iter()
            .map(|id| (self.store.name(*id).to_string(), self.store.values(*id)))
            .collect()
    }

    /// A checkpoint of the run now, stamped with `fingerprint` (one hash per part of the setup) so a resume can check it continues the same run.
    pub fn checkpoint(&self, fingerprint: [String; 4]) -> Checkpoint {
        Checkpoint {
            step: self.step,
            adam_steps: self.adam.steps(),
            params: self
                .ids
                .iter()
                .map(|id| {
                    let (m, v) = self.store.moments(*id);
                    ParamState {
                        name: self.store.name(*id).to_string(),
                        values: self.store.values(*id),
                        adam_m: m,
                        adam_v: v,
                    }
                })
                .collect(),
            pieces: self.layout.params.clone(),
            model: self.layout.model.clone(),
            frame: self.layout.frame.clone(),
            losses: self.losses.clone(),
            state: self.objective.state(),
            fingerprint,
            history: Default::default(),
        }
    }

    /// One optimiser step; a non-finite loss or gradient changes nothing
    /// and is an error naming the parameter.
    pub fn advance(&mut self, setup: &TrainSetup) -> Result<f32, TrainError> {
        let batch = setup.batch(self.step)?;
        // Image terms scale the colour loss; point terms (a distance
        // field's) are weighed by their objective, so theirs is 1.
        let image_terms = setup.losses.iter().filter(|l| l.kind.on_images());
        let weight: f64 = if setup.losses.iter().any(|l| l.kind.on_images()) {
            image_terms.map(|l| l.weight).sum()
        } else {
            1.0
        };
        self.read_step_values();
        // The gradient is zero here: a finished step's update leaves it so,
        // and a failed one zeroes it below.
        let loss = self
            .objective
            .loss_and_grad(&self.step_values, &batch, weight, &mut self.grad)
            .and_then(|loss| {
                if loss.is_finite() {
                    Ok(loss)
                } else {
                    Err(TrainError::Gradient(format!(
                        "the loss is {loss} at step {}",
                        self.step + 1
                    )))
                }
            });
        let parts: Vec<(ParamId, std::ops::Range<usize>)> = self
            .ids
            .iter()
            .zip(&self.tensors)
            .map(|(id, p)| (*id, p.offset..p.offset + p.len))
            .collect();
        self.adam.cfg.lr = setup.optimizer.lr_at(self.step);
        let updated = loss.and_then(|loss| {
            self.adam
                .update_in_place(
                    &mut self.store,
                    &parts,
                    &mut self.step_values,
                    &mut self.grad,
                )
                .map(|()| loss)
        });
        let loss = match updated {
            Ok(loss) => loss,
            Err(e) => {
                self.grad.fill(0.0);
                return Err(e);
            }
        };
        // Back into range: a radius stays positive, a colour in 0..1.
        self.objective.project(&mut self.step_values);
        self.objective.at_step(self.step + 1, &mut self.step_values);
        let v = &self.step_values;
        if let Some(k) = super::params::first_non_finite(v) {
            return Err(TrainError::Gradient(format!(
                "`{}` became {} at step {}",
                self.tensors[self.tensor_at(k)].name,
                v[k],
                self.step + 1
            )));
        }
        for (id, p) in self.ids.iter().zip(&self.tensors) {
            self.store.set_values(*id, &v[p.offset..p.offset + p.len])?;
        }
        self.step += 1;
        self.losses.push(loss as f32);
        Ok(loss as f32)
    }

    /// Copies the current values into `step_values`, a buffer kept for the
    /// run: a step allocates nothing the size of the model.
    fn read_step_values(&mut self) {
        for (id, t) in self.ids.iter().zip(&self.tensors) {
            self.store
                .copy_values(*id, &mut self.step_values[t.offset..t.offset + t.len]);
        }
    }

    /// Steps until `steps` are done or `each` breaks; `each` sees every
    /// completed step.
    pub fn run_to(
        &mut self,
        setup: &TrainSetup,
        steps: usize,
        mut each: impl FnMut(&Self, f32) -> ControlFlow<()>,
    ) -> Result<(), TrainError> {
        while self.step < steps {
            let loss = self.advance(setup)?;
            if each(self, loss).is_break() {
                break;
            }
        }
        Ok(())
    }
}

/// Held-out PSNR that fell while the training loss fell: from its best
/// evaluation (`(step, PSNR)` pairs, in order) to the last by at least
/// [`HELD_OUT_DROP_DB`], with the mean training loss of the steps before
/// the last evaluation below that before the best. The field fits its
/// training views and not the others: overfitting, floaters in front of
/// the cameras (NeRF's recipe on DTU's raw photos fell to 12.5 dB this
/// way, with no word). Losses are per step, from step 1.
pub fn held_out_warning(losses: &[f32], held_out: &[(usize, f64)]) -> Option<String> {
    let &(last_step, last) = held_out.last()?;
    let &(best_step, best) = held_out[..held_out.len() - 1]
        .iter()
        .filter(|h| h.1.is_finite())
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    // A NaN score is no fall.
    let drop = best - last;
    if drop.is_nan() || drop < HELD_OUT_DROP_DB {
        return None;
    }
    // Mean loss over the steps just before `step` (a twentieth of the run).
    let window = (losses.len() / 20).max(1);
    let before = |step: usize| {
        let end = step.min(losses.len());
        let part = &losses[end.saturating_sub(window)..end];
        (!part.is_empty()).then(|| part.iter().map(|&x| x as f64).sum::<f64>() / part.len() as f64)
    };
    let (at_best, at_last) = (before(best_step)?, before(last_step)?);
    (at_last < at_best).then(|| {
        format!(
            "held-out PSNR fell from {best:.2} dB (step {best_step}) to {last:.2} dB (step {last_step}) while the training loss fell from {at_best:.3e} to {at_last:.3e}: the field fits its training views but not the held-out ones (overfitting, or floaters in front of the cameras); stop earlier, train on more views, or check the held-out views' poses"
        )
    })
}

/// How far held-out PSNR must fall below its best for
/// [`held_out_warning`]: more than evaluations on a few views wander.
pub const HELD_OUT_DROP_DB: f64 = 1.0;

/// The stable code of the warnings [`fit_warnings`] gives.
pub const DIVERGED: &str = "sdfl::warn::diverged";

/// Warnings on a finished fit: a loss that ended far above its lowest (the
/// fit diverged or oscillates; a huge learning rate ended at 40× its best
/// with exit code 0), and parameters left at the edge of their range (the
/// optimiser pushed them out and the projection held them there). Losses
/// are compared as means over twentieths of the run, so one noisy batch
/// is not a divergence.
pub fn fit_warnings(losses: &[f32], at_bounds: &[String]) -> Vec<String> {
    let mut warnings = Vec::new();
    if losses.len() >= 20 {
        let w = losses.len() / 20;
        let means: Vec<(usize, f64)> = losses
            .chunks(w)
            .enumerate()
            .map(|(i, c)| {
                let mean = c.iter().map(|&x| x as f64).sum::<f64>() / c.len() as f64;
                (i * w + c.len(), mean)
            })
            .collect();
        let (best_step, best) = means
            .iter()
            .copied()
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((0, 0.0));
        let last = means.last().map_or(0.0, |m| m.1);
        let first = means.first().map_or(0.0, |m| m.1);
        if last > 4.0 * best && last - best > 1e-9 {
            warnings.push(format!(
                "the loss ended at {last:.3e}, {}× its lowest ({best:.3e}, by step {best_step}): the fit diverged or oscillates; lower the learning rate (`adam(lr: ...)`)",
                sdfl_lang::fmt_num((last / best.max(f64::MIN_POSITIVE)).round())
            ));
        } else if last >= 0.9 * first && last > 1e-6 {
            warnings.push(format!(
                "the loss did not fall: {first:.3e} over the first twentieth of the steps, {last:.3e} over the last; lower the learning rate (`adam(lr: ...)`), or check that the model can reach the data"
            ));
        }
    }
    if !at_bounds.is_empty() {
        warnings.push(format!(
            "{} ended at the edge of {} range ({}): the optimiser pushed past it; check the starting values and the learning rate",
            if at_bounds.len() == 1 {
                "a parameter".to_string()
            } else {
                format!("{} parameters", at_bounds.len())
            },
            if at_bounds.len() == 1 { "its" } else { "their" },
            at_bounds.join(", ")
        ));
    }
    warnings
}
