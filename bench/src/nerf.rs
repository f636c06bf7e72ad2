//! NeRF step benchmark: `cargo run --release -p sdfl-bench -- nerf [reps]`.
//!
//! One optimiser step of `nerf()` with its defaults (the network
//! `bench/pytorch/nerf_bench.py` builds in PyTorch): 1024 random rays × 64
//! samples on [2, 6], compositing, MSE, backward, Adam, through the real
//! training loop (`Run` over a `TrainSetup`). Prints the step's GFLOP/s
//! (3 × 2 × multiply-adds per sample × samples) and this machine's dense
//! throughput through the same layer kernel (65536 × 128 × 128), at 1 thread
//! and at all threads, in fp32 and in bf16 (`nerf(precision: "bf16")`: the
//! forward and input-adjoint products in bf16, fp32 where the CPU lacks
//! AVX-512 BF16).

use std::time::Instant;

use crate::stats::median_min;
use sdfl_runtime::neural::field::NerfObjective;
use sdfl_runtime::neural::mlp::{Activation, Dense};
use sdfl_runtime::train::{Run, TrainSetup};
use sdfl_runtime::volume::SplitMix64;
use sdfl_stdlib::value::{Field, Precision};

const SCENE: &str = r#"
let sampler = stratified(samples: 64, near: 2, far: 6)
let cameras = orbit(radius: 4, up: [0, 0, 1], focal: 2, views: 16)
train nerf_step {
  model: nerf(),
  data: render_views(volsdf(sphere(radius: 1)), cameras: cameras, size: [64, 64], sampler: sampler),
  sampler: sampler, rays: 1024, optimizer: adam(lr: 5e-4),
}
"#;

/// Times `f` for fp32 and bf16 alternately (`reps` each, after one warm-up
/// call), so that load from other work falls on both alike: the medians
/// and minima in ms, fp32 first.
fn alternate(reps: usize, mut f: impl FnMut(Precision)) -> [(f64, f64); 2] {
    let precisions = [Precision::Fp32, Precision::Bf16];
    let mut ms = [Vec::new(), Vec::new()];
    for p in precisions {
        f(p);
    }
    for _ in 0..reps {
        for (i, p) in precisions.into_iter().enumerate() {
            let t = Instant::now();
            f(p);
            ms[i].push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    ms.map(median_min)
}

/// GFLOP/s of a 65536 × 128 × 128 product through [`Dense::forward`], in
/// fp32 and in bf16, timed alternately.
fn dense_throughput(reps: usize) -> [f64; 2] {
    let (rows, k, n) = (65536, 128, 128);
    let layer = Dense::new(&[k], n, Activation::Identity, 0);
    let mut params = vec![0.0; layer.end()];
    layer.init(&mut params, &mut SplitMix64::new(1));
    let mut rng = SplitMix64::new(2);
    let x: Vec<f32> = (0..rows * k).map(|_| rng.next_f32()).collect();
    let mut y = vec![0.0; rows * n];
    let times = alternate(reps.max(5) * 2, |p| {
        let layer = layer.clone().with_precision(p);
        layer.forward(&params, &[&x], &mut y);
    });
    times.map(|(med, _)| 2.0 * (rows * k * n) as f64 / (med * 1e-3) / 1e9)
}

pub fn main(reps: usize) {
    let (job, views) = crate::train::prepare(SCENE);
    let Field::Nerf(spec) = &*job.model else {
        panic!("not a nerf")
    };
    let setup = TrainSetup::of(&job, &views);
    let macs = sdfl_runtime::neural::nerf::NerfNet::new(spec).multiply_adds();
    let flop = 3.0 * 2.0 * macs as f64 * 1024.0 * 64.0;
    println!(
        "AVX-512 BF16 on this CPU: {}; fp32 and bf16 steps alternate",
        if sdfl_runtime::neural::bf16::available() {
            "yes"
        } else {
            "no (bf16 runs fp32)"
        }
    );
    println!("| implementation | precision | threads | step ms (median) | step ms (min) | step GFLOP/s | dense GFLOP/s | step / dense |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    let all = rayon::current_num_threads();
    for threads in [1, all] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        pool.install(|| {
            let gemm = dense_throughput(reps);
            let mut runs = [Precision::Fp32, Precision::Bf16].map(|precision| {
                let spec = sdfl_stdlib::value::Nerf {
                    precision,
                    ..spec.clone()
                };
                let model = NerfObjective::new(&spec, &job.sampler).expect("model");
                Run::of(Box::new(model), 5e-4).expect("run")
            });
            let times = alternate(reps, |p| {
                runs[(p == Precision::Bf16) as usize]
                    .advance(&setup)
                    .expect("step");
            });
            for (i, p) in [Precision::Fp32, Precision::Bf16].iter().enumerate() {
                let (med, min) = times[i];
                let gflops = flop / (med * 1e-3) / 1e9;
                println!(
                    "| sdfl (fused layers) | {p:?} | {threads} | {med:.1} | {min:.1} | {gflops:.1} | {:.1} | {:.0}% |",
                    gemm[i],
                    100.0 * gflops / gemm[i]
                );
            }
            println!(
                "bf16 / fp32 at {threads} thread(s): step {:.2}× faster, dense {:.2}×",
                times[0].0 / times[1].0,
                gemm[1] / gemm[0]
            );
        });
    }
}

const NEURAL_SDF: &str = r#"
train neural_sdf_step {
  model: neural_sdf(),
  data: points("unused.xyz"),
  rays: 4096, optimizer: adam(lr: 1e-4),
}
"#;

/// One step of the assignment's neural SDF (`neural_sdf()` defaults: 4096
/// surface + 4096 random points, exact eikonal) through the training loop;
/// compare `bench/pytorch/neural_sdf_bench.py`.
pub fn neural_sdf_main(reps: usize) {
    let program = sdfl_stdlib::load(&sdfl_lang::SourceFile::new("bench.sdfl", NEURAL_SDF))
        .expect("bench scene");
    let job = program.trains[0].clone();
    let Field::NeuralSdf(spec) = &*job.model else {
        panic!("not a neural SDF")
    };
    // 10 000 points on a sphere stand in for a scan.
    let mut rng = SplitMix64::new(4);
    let points: Vec<[f32; 3]> = (0..10_000)
        .map(|_| {
            let v = [0, 1, 2].map(|_| 2.0 * rng.next_f32() - 1.0);
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-6);
            v.map(|x| 0.6 * x / l)
        })
        .collect();
    let mut setup = TrainSetup::of(&job, &[]);
    setup.points = &points;
    println!("| implementation | threads | step ms (median) | step ms (min) |");
    println!("|---|---:|---:|---:|");
    for threads in [1, rayon::current_num_threads()] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        pool.install(|| {
            let model = sdfl_runtime::neural::distance::NeuralSdfObjective::new(
                spec,
                &job.losses,
                job.bounds,
            );
            let mut run = Run::of(Box::new(model), 1e-4).expect("run");
            for _ in 0..2 {
                run.advance(&setup).expect("step");
            }
            let ms: Vec<f64> = (0..reps)
                .map(|_| {
                    let t = Instant::now();
                    run.advance(&setup).expect("step");
                    t.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            let (med, min) = median_min(ms);
            println!("| sdfl (exact eikonal, fused) | {threads} | {med:.1} | {min:.1} |");
        });
    }
}
