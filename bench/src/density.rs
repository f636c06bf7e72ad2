//! Density benchmark: `cargo run --release -p sdfl-bench -- density [reps]`.
//!
//! What every density runs through, per registered density: a 256² volume render of a torus (64 samples a ray, f32, all
//! threads); the fused training kernel's loss and gradient on one batch of
//! the torus fit (4096 rays × 64 samples); and, for the densities that take
//! a neural SDF, one training step of a neural SDF seen as a volume (512
//! rays × 64 samples). Medians and minima in ms, one thread and all.

use std::time::Instant;

use glam::DVec3;
use sdfl_runtime::neural::surface::SurfaceObjective;
use sdfl_runtime::train::{Run, TrainModel, TrainSetup};
use sdfl_runtime::volume::{render_field_image, DensityModel, ImageSize, Stratified};
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::density::NeuralUse;
use sdfl_stdlib::num::V3;
use sdfl_stdlib::value::{DensityKind, Field, LastInterval};

fn fit(volume: &str) -> String {
    format!(
        r#"
let cameras = for eye in [[0, 0, -3], [2.6, 0, -1.5], [0, 2.6, -1.5], [-2.6, 0, 1.5], [0, -2.6, 1.5], [0, 0, 3]] {{ look_at(eye: eye) }}
let sampler = stratified(samples: 64, near: 0, far: 6)
train torus_fit {{
  model: {volume}(torus(major: param(0.8), minor: param(0.35), center: param([0.1, 0, 0])), color: [0.9, 0.5, 0.2]),
  data: render_views({volume}(torus(major: 1.0, minor: 0.25, center: [0, 0.1, -0.1]), color: [0.9, 0.5, 0.2]), cameras: cameras, size: [96, 96], sampler: sampler),
  sampler: sampler, rays: 4096, optimizer: adam(lr: 5e-3),
}}
"#
    )
}

fn surface(volume: &str) -> String {
    format!(
        r#"
let cameras = for eye in [[0, 0, -3], [2.6, 0, -1.5], [0, 2.6, -1.5], [-2.6, 0, 1.5]] {{ look_at(eye: eye) }}
let sampler = stratified(samples: 64, near: 1, far: 5)
train surface_fit {{
  model: {volume}(neural_sdf(layers: 4, width: 64), beta: param(0.05)),
  data: render_views(volsdf(torus(major: 1.0, minor: 0.25), color: [0.9, 0.5, 0.2]), cameras: cameras, size: [64, 64], sampler: sampler),
  sampler: sampler, rays: 512, optimizer: adam(lr: 5e-4),
}}
"#
    )
}

/// (median, minimum) of `reps` timings of `f`, in milliseconds.
fn timed(reps: usize, mut f: impl FnMut()) -> (f64, f64) {
    let mut ms: Vec<f64> = (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    ms.sort_by(f64::total_cmp);
    (ms[ms.len() / 2], ms[0])
}

fn render(kind: DensityKind, reps: usize) -> (f64, f64) {
    let alpha = kind.alpha_max().min(20.0) as f32;
    let model = DensityModel {
        kind,
        alpha,
        beta: 0.05,
        last_interval: LastInterval::Zero,
    };
    let sampler = Stratified::new(64, 1.0, 5.0).expect("sampler");
    let cam = Camera::look_at(DVec3::new(0.3, 1.5, -2.5), DVec3::ZERO, DVec3::Y, 1.5);
    let size = ImageSize {
        width: 256,
        height: 256,
    };
    let field = |p: [f32; 3]| {
        let q = V3::new(p[0], p[1], p[2]);
        (sdfl_stdlib::sdf::torus(q, 1.0, 0.3), [0.9, 0.5, 0.2])
    };
    timed(reps, || {
        std::hint::black_box(
            render_field_image(field, model, &sampler, &cam, size).expect("render"),
        );
    })
}

fn kernel(kind: &str, reps: usize) -> (f64, f64) {
    let (job, views) = crate::train::prepare(&fit(kind));
    let model = TrainModel::new(job.model.as_sdf().expect("an analytic field"));
    let setup = TrainSetup::of(&job, &views);
    let batch = setup.batch(0).expect("batch");
    let values: Vec<f32> = model.initial_values().iter().map(|&x| x as f32).collect();
    timed(reps, || {
        std::hint::black_box(sdfl_runtime::train::fused::loss_and_grad_f32(
            &model, &values, &batch, 1.0,
        ));
    })
}

fn surface_step(kind: &str, reps: usize) -> (f64, f64) {
    let (job, views) = crate::train::prepare(&surface(kind));
    let Field::NeuralSurface(spec) = &*job.model else {
        panic!("not a neural SDF's volume")
    };
    let setup = TrainSetup::of(&job, &views);
    let model = SurfaceObjective::new(spec, &job.losses)
        .expect("a harmonic surface builds")
        .with_steps(1000);
    let mut run = Run::of(Box::new(model), 5e-4).expect("run");
    for _ in 0..2 {
        run.advance(&setup).expect("step");
    }
    timed(reps, || {
        run.advance(&setup).expect("step");
    })
}

pub fn main(reps: usize) {
    println!("| what | density | threads | ms (median) | ms (min) |");
    println!("|---|---|---:|---:|---:|");
    let all = rayon::current_num_threads();
    for threads in [1, all] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        pool.install(|| {
            for &kind in DensityKind::ALL {
                let name = kind.name();
                let (med, min) = render(kind, reps);
                println!("| render 256² | {name} | {threads} | {med:.2} | {min:.2} |");
                let (med, min) = kernel(name, reps);
                println!("| fused kernel | {name} | {threads} | {med:.2} | {min:.2} |");
                if kind.neural() != NeuralUse::Refused {
                    let (med, min) = surface_step(name, reps);
                    println!("| neural surface step | {name} | {threads} | {med:.2} | {min:.2} |");
                }
            }
        });
    }
}
