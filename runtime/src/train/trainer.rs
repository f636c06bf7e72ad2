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
use sdfl_stdlib::value::{Backend, Loss, LossKind, Optimizer, Sampler};

use super::checkpoint::{Checkpoint, ParamState};
use super::fused::{loss_and_grad, Batch};
use super::model::TrainModel;
use super::{Adam, ParamId, ParamStore, TrainError};
use crate::data::npy::RgbImage;
use crate::volume::{random_rays, ImageSize, SplitMix64, Stratified};

/// One training view: a camera and the image it sees.
#[derive(Debug, Clone)]
pub struct TrainView {
    pub camera: Camera,
    pub image: RgbImage,
}

/// What a run needs besides the model.
#[derive(Debug, Clone)]
pub struct TrainSetup<'a> {
    pub views: &'a [TrainView],
    pub sampler: Sampler,
    pub rays: usize,
    pub optimizer: Optimizer,
    pub losses: &'a [Loss],
    pub seed: u64,
    pub backend: Backend,
}

impl<'a> TrainSetup<'a> {
    /// A `train` statement's setup over its loaded views.
    pub fn of(job: &'a sdfl_stdlib::value::TrainJob, views: &'a [TrainView]) -> Self {
        TrainSetup {
            views,
            sampler: job.sampler,
            rays: job.rays,
            optimizer: job.optimizer,
            losses: &job.losses,
            seed: job.seed,
            backend: job.backend,
        }
    }

    /// Steps of one pass over every training pixel.
    pub fn steps_per_epoch(&self) -> usize {
        let pixels: usize = self.views.iter().map(|v| v.image.pixels.len()).sum();
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
        let size = self.size()?;
        let cams: Vec<Camera> = self.views.iter().map(|v| v.camera).collect();
        let mut rng = SplitMix64::new(
            self.seed
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .wrapping_add(step as u64),
        );
        let total = size.pixels() * cams.len();
        let rays = random_rays(&cams, size, self.rays.min(total), &mut rng)?;
        let targets = rays
            .iter()
            .map(|r| self.views[r.view as usize].image.pixels[r.pixel as usize])
            .collect();
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
            depths,
            samples: s.samples,
            shared: !s.jitter,
            last_interval: s.last_interval,
        })
    }
}

/// The state of a run: parameters in the store, Adam, losses so far.
pub struct Run<'m> {
    pub model: &'m TrainModel,
    store: ParamStore,
    ids: Vec<ParamId>,
    adam: Adam,
    /// Steps done.
    pub step: usize,
    pub losses: Vec<f32>,
}

impl<'m> Run<'m> {
    /// A fresh run at the model's starting values.
    pub fn new(model: &'m TrainModel, lr: f64) -> Result<Self, TrainError> {
        let mut store = ParamStore::new();
        let init = model.initial_values();
        let ids = model
            .params
            .iter()
            .map(|p| {
                let v: Vec<f32> = init[p.offset..p.offset + p.len]
                    .iter()
                    .map(|&x| x as f32)
                    .collect();
                store.add(&p.name, &v, true)
            })
            .collect::<Result<_, _>>()?;
        Ok(Run {
            model,
            store,
            ids,
            adam: Adam::new(lr)?,
            step: 0,
            losses: Vec::new(),
        })
    }

    /// Continues from a checkpoint of the same model.
    pub fn resume(&mut self, ck: &Checkpoint) -> Result<(), TrainError> {
        let names: Vec<&str> = ck.params.iter().map(|p| p.name.as_str()).collect();
        let ours: Vec<&str> = self.model.params.iter().map(|p| p.name.as_str()).collect();
        if names != ours {
            return Err(TrainError::Invalid(format!(
                "the checkpoint holds parameters {names:?}, the model has {ours:?}"
            )));
        }
        for (id, p) in self.ids.iter().zip(&ck.params) {
            self.store.restore(*id, &p.values, &p.adam_m, &p.adam_v)?;
        }
        self.adam.set_steps(ck.adam_steps);
        self.step = ck.step;
        self.losses = ck.losses.clone();
        Ok(())
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
            losses: self.losses.clone(),
            fingerprint,
        }
    }

    /// One optimiser step; a non-finite loss or gradient changes nothing
    /// and is an error naming the parameter.
    pub fn advance(&mut self, setup: &TrainSetup) -> Result<f32, TrainError> {
        let batch = setup.batch(self.step)?;
        let weight: f64 = setup
            .losses
            .iter()
            .map(|l| match l.kind {
                LossKind::Mse => l.weight,
            })
            .sum();
        let values = self.values();
        let lg = match setup.backend {
            Backend::Fused => loss_and_grad::<f32>(self.model, &values, &batch, weight),
            Backend::Dfdx => {
                let dev = self.store.device().clone();
                super::graph::loss_and_grad(&dev, self.model, &values, &batch, weight)?
            }
        };
        if !lg.loss.is_finite() {
            return Err(TrainError::Gradient(format!(
                "the loss is {} at step {}",
                lg.loss,
                self.step + 1
            )));
        }
        let grads: Vec<Vec<f32>> = self
            .model
            .params
            .iter()
            .map(|p| {
                lg.grad[p.offset..p.offset + p.len]
                    .iter()
                    .map(|&g| g as f32)
                    .collect()
            })
            .collect();
        let pairs: Vec<(ParamId, &[f32])> = self
            .ids
            .iter()
            .zip(&grads)
            .map(|(id, g)| (*id, g.as_slice()))
            .collect();
        self.adam.cfg.lr = setup.optimizer.lr_at(self.step);
        self.adam.update_from_slices(&mut self.store, &pairs)?;
        // Back into range: a radius stays positive, a colour in 0..1.
        let mut v = self.values();
        self.model.project(&mut v);
        for (id, p) in self.ids.iter().zip(&self.model.params) {
            self.store.set_values(*id, &v[p.offset..p.offset + p.len])?;
        }
        if !v.iter().all(|x| x.is_finite()) {
            return Err(TrainError::Gradient(format!(
                "a parameter became non-finite at step {}",
                self.step + 1
            )));
        }
        self.step += 1;
        self.losses.push(lg.loss as f32);
        Ok(lg.loss as f32)
    }

    /// Steps until `steps` are done or `each` breaks; `each` sees every
    /// completed step.
    pub fn run_to(
        &mut self,
        setup: &TrainSetup,
        steps: usize,
        mut each: impl FnMut(&Run, f32) -> ControlFlow<()>,
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
