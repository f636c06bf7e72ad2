//! Training-step benchmark: `cargo run --release -p sdfl-bench -- train [reps]`.
//!
//! One optimiser step (4096 random rays × 64 samples, MSE, Adam) of the box
//! fit (the assignment's part 2: four cameras, 128² views) and of a torus
//! fit (centre and both radii, six views at 96²), with the fused kernel and
//! the dfdx graph backend, at 1 thread and at all threads. Compare with
//! `bench/pytorch/torus_fit_bench.py` (same computation) run right after.

use std::time::Instant;

use sdfl_lang::SourceFile;
use sdfl_runtime::jobs::load_views;
use sdfl_runtime::train::{FieldObjective, Run, TrainModel, TrainSetup, TrainView};
use sdfl_stdlib::value::{Backend, TrainJob};

const BOX: &str = r#"
let cameras = [look_at(eye: [-2.5, 0, 0]), look_at(eye: [-1.0, 0, -2.2]), look_at(eye: [0, 0, -2.5]), look_at(eye: [1.0, 0, -2.2])]
let sampler = stratified(samples: 64, near: 0, far: 5)
train box_fit {
  model: sdf_volume(box(size: param([1.5, 1.5, 1.5]), center: param([0, 0, 0]))),
  data: render_views(sdf_volume(box(size: [2, 1.5, 1.5], center: [0.25, 0.25, 0])), cameras: cameras, size: [128, 128], sampler: sampler),
  sampler: sampler, rays: 4096, optimizer: adam(lr: 5e-4),
}
"#;

const TORUS: &str = r#"
let cameras = for eye in [[0, 0, -3], [2.6, 0, -1.5], [0, 2.6, -1.5], [-2.6, 0, 1.5], [0, -2.6, 1.5], [0, 0, 3]] { look_at(eye: eye) }
let sampler = stratified(samples: 64, near: 0, far: 6)
train torus_fit {
  model: sdf_volume(torus(major: param(0.8), minor: param(0.35), center: param([0.1, 0, 0])), color: [0.9, 0.5, 0.2]),
  data: render_views(sdf_volume(torus(major: 1.0, minor: 0.25, center: [0, 0.1, -0.1]), color: [0.9, 0.5, 0.2]), cameras: cameras, size: [96, 96], sampler: sampler),
  sampler: sampler, rays: 4096, optimizer: adam(lr: 5e-3),
}
"#;

/// A benchmark scene's training job and its views.
pub(crate) fn prepare(src: &str) -> (TrainJob, Vec<TrainView>) {
    let program = sdfl_stdlib::load(&SourceFile::new("bench.sdfl", src)).expect("bench scene");
    let job = program.trains[0].clone();
    let views = load_views(&job.data, std::path::Path::new("."))
        .expect("views")
        .train;
    (job, views)
}

/// (median, minimum) of `reps` timings of `f`, in milliseconds.
fn timed(reps: usize, mut f: impl FnMut(usize)) -> (f64, f64) {
    let mut ms: Vec<f64> = (0..reps)
        .map(|k| {
            let t = Instant::now();
            f(k);
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    ms.sort_by(f64::total_cmp);
    (ms[ms.len() / 2], ms[0])
}

/// Milliseconds of `reps` optimiser steps after two warm-up steps.
fn time_steps(src: &str, backend: Backend, reps: usize) -> (f64, f64) {
    let (mut job, views) = prepare(src);
    job.backend = backend;
    let model = TrainModel::new(job.model.as_sdf().expect("an analytic field"));
    let setup = TrainSetup::of(&job, &views);
    let objective = Box::new(FieldObjective::new(&model, job.backend));
    let mut run = Run::for_optimizer(objective, &job.optimizer).expect("run");
    for _ in 0..2 {
        run.advance(&setup).expect("step");
    }
    timed(reps, |_| {
        run.advance(&setup).expect("step");
    })
}

/// Milliseconds of a forward-only pass over one batch; prints the time to
/// draw a batch.
fn time_forward(name: &str, src: &str, reps: usize) -> (f64, f64) {
    let (job, views) = prepare(src);
    let model = TrainModel::new(job.model.as_sdf().expect("an analytic field"));
    let setup = TrainSetup::of(&job, &views);
    let (med, min) = timed(reps, |k| {
        std::hint::black_box(setup.batch(k).expect("batch"));
    });
    let threads = rayon::current_num_threads();
    println!("| {name} | drawing the batch only | {threads} | {med:.2} | {min:.2} |");
    let batch = setup.batch(0).expect("batch");
    let values: Vec<f32> = model.initial_values().iter().map(|&x| x as f32).collect();
    timed(reps, |_| {
        std::hint::black_box(sdfl_runtime::train::fused::render_rays(
            &model,
            &values,
            &batch.rays,
            &batch.depths,
            job.sampler.last_interval,
        ));
    })
}

/// Milliseconds of the fused kernel alone (loss and gradient of one batch).
fn time_kernel(src: &str, reps: usize) -> (f64, f64) {
    let (job, views) = prepare(src);
    let model = TrainModel::new(job.model.as_sdf().expect("an analytic field"));
    let setup = TrainSetup::of(&job, &views);
    let batch = setup.batch(0).expect("batch");
    let values: Vec<f32> = model.initial_values().iter().map(|&x| x as f32).collect();
    timed(reps, |_| {
        std::hint::black_box(sdfl_runtime::train::fused::loss_and_grad_f32(
            &model, &values, &batch, 1.0,
        ));
    })
}

/// `only_fused`: skip the dfdx backend and the forward-only rows (for
/// profiling the fused kernel).
pub fn main(reps: usize, only_fused: bool) {
    let all = rayon::current_num_threads();
    println!("| fit | backend | threads | step ms (median) | step ms (min) |");
    println!("|---|---|---:|---:|---:|");
    for (name, src) in [("box", BOX), ("torus", TORUS)] {
        for threads in [1, all] {
            if only_fused {
                break;
            }
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("thread pool");
            let (med, min) = pool.install(|| time_forward(name, src, reps));
            println!("| {name} | forward only | {threads} | {med:.2} | {min:.2} |");
        }
        for threads in [1, all] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("thread pool");
            let (med, min) = pool.install(|| time_kernel(src, reps));
            println!("| {name} | fused kernel alone (loss and gradient) | {threads} | {med:.2} | {min:.2} |");
        }
        for backend in [Backend::Fused, Backend::Dfdx] {
            if only_fused && backend != Backend::Fused {
                continue;
            }
            for threads in [1, all] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("thread pool");
                let (med, min) = pool.install(|| time_steps(src, backend, reps));
                println!("| {name} | {backend:?} | {threads} | {med:.2} | {min:.2} |");
            }
        }
    }
}
