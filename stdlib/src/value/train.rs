//! `train` statements: optimiser, schedule, losses and gradient backend.

use std::sync::Arc;

use super::{Dataset, Field, Output, Sampler, ViewPath};
use crate::camera::Camera;

/// A `train` statement.
#[derive(Debug, Clone)]
pub struct TrainJob {
    /// The statement's name, the stem of its files.
    pub name: String,
    /// The field trained.
    pub model: Arc<Field>,
    /// What it is fitted to.
    pub data: Arc<Dataset>,
    /// The `data` argument, where errors reading the data set point.
    pub data_span: sdfl_lang::Span,
    /// Where samples fall along each training ray.
    pub sampler: Sampler,
    /// Rays per step.
    pub rays: usize,
    /// The optimiser and its learning-rate schedule.
    pub optimizer: Optimizer,
    /// The objective's terms.
    pub losses: Vec<Loss>,
    /// Optimiser steps, unless `epochs` is given.
    pub iterations: usize,
    /// Passes over all training pixels: steps = epochs × ⌈pixels / rays⌉.
    pub epochs: Option<usize>,
    /// Seed of the batches (a step's rays are a function of seed and step).
    pub seed: u64,
    /// How gradients are computed.
    pub backend: Backend,
    /// Cameras and size for the before/after outputs (placeholders, as
    /// many as it will have, where `view_path` makes them at run time).
    pub views: Vec<Camera>,
    /// Views made from the training cameras when the run has read them.
    pub view_path: Option<ViewPath>,
    /// Width of the before/after images.
    pub width: u32,
    /// Height of the before/after images.
    pub height: u32,
    /// `width` × `height` are placeholders (the square default) for views
    /// along the training cameras of a data set read from files: the run
    /// makes them the training images' aspect
    /// ([`size_at_aspect`](super::size_at_aspect)) once it has read them.
    pub size_at_data_aspect: bool,
    /// Outputs of the model as it starts.
    pub before: Vec<Output>,
    /// Outputs of the trained model.
    pub after: Vec<Output>,
    /// Where to keep a resumable checkpoint (relative to the output dir).
    pub checkpoint: Option<std::path::PathBuf>,
    /// Steps between held-out evaluations (0: at the end only).
    pub eval_every: usize,
    /// Held-out views each evaluation scores, evenly spaced over the
    /// data's (the first included); `None`: all of them.
    pub eval_views: Option<usize>,
    /// Held-out views are scored at 1/`eval_downscale` of their size a
    /// side (blocks averaged); 1: full size.
    pub eval_downscale: u32,
    /// Half-extent of the cube random points are drawn in (distance fields).
    pub bounds: f64,
}

/// Adam with a learning-rate schedule.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Optimizer {
    /// The base learning rate.
    pub lr: f64,
    /// How it changes with the step.
    pub schedule: Schedule,
    /// Adam's moment decays and ε.
    pub moments: Moments,
}

/// Adam's decay rates of its two moment estimates and the ε added to the
/// second's root. The defaults are dfdx's (and PyTorch's); instant-ngp
/// trains its hash tables with β₂ = 0.99 and ε = 1e-15, since a table row
/// seen rarely has small gradients that a larger ε would mute.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Moments {
    /// Decay of the gradient's running mean, in `[0, 1)`.
    pub beta1: f64,
    /// Decay of the squared gradient's running mean, in `[0, 1)`.
    pub beta2: f64,
    /// Added to the root of the second moment (> 0).
    pub eps: f64,
}

impl Default for Moments {
    fn default() -> Self {
        Moments {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// How the learning rate changes with the step.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Schedule {
    /// The same learning rate throughout.
    Constant,
    /// Multiplied by `factor` every `every` steps.
    Step {
        /// Multiplier applied each time.
        factor: f64,
        /// Steps between multiplications.
        every: usize,
    },
    /// `lr·factor^(step/every)`: the same decay as `Step`, spread smoothly.
    Exponential {
        /// Multiplier over `every` steps.
        factor: f64,
        /// Steps over which the rate is multiplied by `factor`.
        every: usize,
    },
}

impl Optimizer {
    /// The learning rate of step `step` (counted from 0).
    pub fn lr_at(&self, step: usize) -> f64 {
        match self.schedule {
            Schedule::Constant => self.lr,
            Schedule::Step { factor, every } if every > 0 => {
                self.lr * factor.powi((step / every) as i32)
            }
            Schedule::Step { .. } => self.lr,
            Schedule::Exponential { factor, every } => {
                self.lr * factor.powf(step as f64 / every.max(1) as f64)
            }
        }
    }
}

/// A term of a training objective.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LossKind {
    /// Mean squared error of rendered against true pixel colours.
    Mse,
    /// Mean |f| of a distance field at the surface points.
    Surface,
    /// Mean (‖∇f‖ − 1)² at the surface and the random points, the gradient
    /// exact (no finite differences).
    Eikonal,
    /// Mean exp(−alpha·|f|) at random points: no surface away from the data.
    Inter {
        /// How fast the penalty falls with |f|.
        alpha: f64,
    },
    /// Mean binary cross-entropy of each ray's opacity against its pixel's
    /// coverage by the object (NeuS's mask loss): a missed silhouette
    /// costs as much on a dark side as on a lit one.
    Silhouette,
}

impl LossKind {
    /// Whether the term compares rendered colours (else it is a distance
    /// field's term on points, or [`LossKind::Silhouette`], which the
    /// surface objective weighs itself).
    pub fn on_images(&self) -> bool {
        matches!(self, LossKind::Mse)
    }
}

/// A weighted loss term.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Loss {
    /// Which term.
    pub kind: LossKind,
    /// Its weight in the sum.
    pub weight: f64,
}

/// How a training step computes its gradient.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Backend {
    /// One fused kernel per ray: forward-mode parameter tangents through the
    /// field, a hand-written backward through compositing.
    Fused,
    /// A dfdx autodiff graph over `[rays, samples]` tensors, the field as a
    /// custom op.
    Dfdx,
}
