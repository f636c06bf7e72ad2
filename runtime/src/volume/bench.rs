//! Timings of the box volume for benchmarks (never asserted in tests):
//! one training step of the box fit and one full-image render.
//!
//! Measured on the 2-core dev VM (AMD EPYC; another engineer's builds
//! running, so minima of 10–15 runs), PyTorch 2.15 CPU running
//! `bench/pytorch/box_volume_bench.py` (same computation, stable log-keep form):
//!
//! | 4096×64 step / 256×256×64 render | 2 threads      | 1 thread       |
//! |----------------------------------|----------------|----------------|
//! | sdfl fused kernel                | 3.8 / 30 ms    | 7.3 / 60 ms    |
//! | sdfl dfdx graph + fused op       | ≈ 11 ms        | 11 ms          |
//! | sdfl pure dfdx graph             | 48 ms          | 48 ms          |
//! | PyTorch                          | 19 / 200 ms    | 29 / 345 ms    |

use std::time::Instant;

use super::rays::{random_rays, ImageSize, SplitMix64, Stratified};
use super::{box_loss_and_grad, render_box_image, BoxVolume, VolumeError};
use crate::train::box_fit::assignment_cameras;
use dfdx::prelude::*;

use crate::train::box_graph::box_loss_graph;
use crate::train::box_op::box_volume_colours;
use crate::train::{Adam, ParamStore, TrainError};

/// `(median, minimum)` seconds of each measured operation.
#[derive(Debug, Clone, Copy)]
pub struct BoxBenchTimes {
    /// Fused kernel: loss + gradient + Adam update for one batch.
    pub fused_step_s: (f64, f64),
    /// dfdx graph: forward + backward + Adam update for one batch.
    pub dfdx_step_s: (f64, f64),
    /// dfdx graph around the fused colour op (MSE and Adam through dfdx).
    pub fused_op_step_s: (f64, f64),
    /// Full image render (forward only, fused kernel).
    pub render_s: (f64, f64),
}

fn median(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(|a, b| a.total_cmp(b));
    (v[v.len() / 2], v[0])
}

/// Times the box fit step (`rays` rays × `samples` samples on [0, 5], the
/// assignment's cameras and box) and a `res`×`res` render, `reps` times each
/// after one warm-up; returns medians and minima.
pub fn bench_box_volume(
    rays: usize,
    samples: usize,
    res: u32,
    reps: usize,
) -> Result<BoxBenchTimes, TrainError> {
    let reps = reps.max(1);
    let sampler = Stratified::new(samples, 0.0, 5.0)?;
    let target = BoxVolume::new([0.25, 0.25, 0.0], [2.0, 1.5, 1.5], 1.0, 0.05)?;
    let start = BoxVolume::new([0.0; 3], [1.5; 3], 1.0, 0.05)?;
    let cams = assignment_cameras();
    let size = ImageSize {
        width: res,
        height: res,
    };
    let mut rng = SplitMix64::new(1);
    let batch = random_rays(&cams, size, rays, &mut rng)?;
    let targets: Vec<[f32; 3]> = super::render_box_rays(&target, &sampler, &batch)?
        .iter()
        .map(|c| c.colour)
        .collect();
    let t = sampler.depths();

    let mut store = ParamStore::new();
    let c = store.add("center", &start.center, true)?;
    let s = store.add("sides", &start.sides, true)?;
    let mut opt = Adam::new(5e-4)?;
    let mut fused = Vec::new();
    for k in 0..=reps {
        let t0 = Instant::now();
        let cv = store.values(c);
        let sv = store.values(s);
        let vol = BoxVolume::new([cv[0], cv[1], cv[2]], [sv[0], sv[1], sv[2]], 1.0, 0.05)?;
        let (_, g) = box_loss_and_grad(&vol, &sampler, &batch, &targets)?;
        opt.update_from_slices(&mut store, &[(c, &g.center), (s, &g.sides)])?;
        if k > 0 {
            fused.push(t0.elapsed().as_secs_f64());
        }
    }
    let mut graph = Vec::new();
    for k in 0..=reps {
        let t0 = Instant::now();
        let (_, mut grads) = box_loss_graph(&store, c, s, 1.0, 0.05, &t, &batch, &targets)?;
        opt.update(&mut store, &mut grads)?;
        if k > 0 {
            graph.push(t0.elapsed().as_secs_f64());
        }
    }
    let mut op = Vec::new();
    let tgt: Vec<f32> = targets.iter().flatten().copied().collect();
    for k in 0..=reps {
        let t0 = Instant::now();
        let rgb = box_volume_colours(
            store.tensor(c).leaky_trace(),
            store.tensor(s).leaky_trace(),
            1.0,
            0.05,
            &sampler,
            &batch,
        )?;
        let target = store.device().tensor_from_vec(tgt.clone(), (rays, 3usize));
        let loss = (rgb - target).square().mean();
        opt.update(&mut store, &mut loss.backward())?;
        if k > 0 {
            op.push(t0.elapsed().as_secs_f64());
        }
    }
    let mut render = Vec::new();
    for k in 0..=reps {
        let t0 = Instant::now();
        let img =
            render_box_image(&target, &sampler, &cams[0], size).map_err(VolumeError::into_train)?;
        std::hint::black_box(&img);
        if k > 0 {
            render.push(t0.elapsed().as_secs_f64());
        }
    }
    Ok(BoxBenchTimes {
        fused_step_s: median(fused),
        dfdx_step_s: median(graph),
        fused_op_step_s: median(op),
        render_s: median(render),
    })
}

impl VolumeError {
    fn into_train(self) -> TrainError {
        self.into()
    }
}
