//! Hash-grid surface step benchmark: `cargo run --release -p sdfl-bench --
//! hash-surface [reps]`.
//!
//! One NeuS training step of `examples/neus_fast.sdfl` (16 levels of 2^16
//! rows, 16 to 256 cells, one softplus layer of 64; 512 rays, 16
//! stratified + 32 fine samples a ray) through the real training loop,
//! every level on (`level_every: 0`, as from step 240 of the example);
//! then its hash-SDF parts alone on the same shapes: the distance-only
//! pass over the 16 coarse samples a ray that places the fine ones, the
//! forward of `f` and `∇f` at all 48 samples a ray, and its backward. The
//! parts run on a field with bumps in every level's tables (as trained),
//! at the samples of one real batch, the fine ones gathered about the
//! starting sphere.
//!
//! Then the softplus kernels side by side on a layer's pre-activations:
//! libm's `ln_1p` per unit (the hash SDF's before) against the vectorised
//! [`softplus_layer`] (now used everywhere the hash SDF is evaluated).
//!
//! All timings are in turns so load falls on each alike; compare two
//! builds by running their binaries alternately (A B A B).

use std::hint::black_box;
use std::time::Instant;

use crate::stats::{load, median_min};
use sdfl_runtime::neural::hash_sdf::volume::VolumeWork;
use sdfl_runtime::neural::hash_sdf::Eikonal;
use sdfl_runtime::neural::mlp::softplus_layer;
use sdfl_runtime::neural::surface::{SurfaceObjective, SurfaceSdf};
use sdfl_runtime::train::{Run, TrainSetup};
use sdfl_runtime::volume::SplitMix64;
use sdfl_stdlib::value::Field;

/// Milliseconds `f` takes.
fn ms(f: impl FnOnce()) -> f64 {
    let t = Instant::now();
    f();
    t.elapsed().as_secs_f64() * 1e3
}

/// The softplus as the hash SDF computed it before: libm's `ln_1p` per
/// unit (the baseline of the kernel comparison).
#[inline(never)]
fn softplus_libm(z: &mut [f32], slope: &mut [f32], beta: f32) {
    for (z, s) in z.iter_mut().zip(slope) {
        let t = beta * *z;
        let e = (-t.abs()).exp();
        let sp = z.max(0.0) + e.ln_1p() / beta;
        *s = if t >= 0.0 { 1.0 } else { e } / (1.0 + e);
        *z = sp;
    }
}

/// Prints the step's and the parts' medians, `reps` turns each.
pub fn main(reps: usize) {
    let src =
        include_str!("../../examples/neus_fast.sdfl").replace("level_every: 20", "level_every: 0");
    let (job, views) = crate::train::prepare(&src);
    let Field::NeuralSurface(spec) = &*job.model else {
        panic!("neus_fast.sdfl trains a neural surface")
    };
    let setup = TrainSetup::of(&job, &views);
    let model = SurfaceObjective::new(spec, &job.losses)
        .expect("the hash surface builds")
        .with_steps(job.iterations);
    let mut run = Run::for_optimizer(Box::new(model), &job.optimizer).expect("run");

    // The parts: the hash SDF alone at one batch's samples.
    let SurfaceSdf::Hash(hash) = SurfaceSdf::new(&spec.sdf).expect("hash SDF") else {
        panic!("neus_fast.sdfl's SDF is a hash grid")
    };
    let net = &hash.net;
    let mut params = net.init(1);
    let mut rng = SplitMix64::new(4);
    for v in &mut params[..net.table_params()] {
        *v = (2.0 * rng.next_f32() - 1.0) * 0.05;
    }
    let batch = setup.batch(0).expect("batch");
    let (fine, radius) = (spec.fine, spec.sdf.radius as f32);
    let mut coarse = Vec::new();
    let mut all = Vec::new();
    for (r, ray) in batch.rays.iter().enumerate() {
        let at = |t: f32| std::array::from_fn::<f32, 3, _>(|a| ray.origin[a] + t * ray.dir[a]);
        let depths = batch.depths_of(r);
        for &t in depths {
            coarse.push(at(t));
            all.push(at(t));
        }
        // Fine samples 0.1 deep about where the ray meets the starting
        // sphere (the middle of its depths where it misses).
        let o = ray.origin;
        let b: f32 = (0..3).map(|a| o[a] * ray.dir[a]).sum();
        let c: f32 = (0..3).map(|a| o[a] * o[a]).sum::<f32>() - radius * radius;
        let hit = if b * b > c {
            -b - (b * b - c).sqrt()
        } else {
            0.5 * (depths[0] + depths[depths.len() - 1])
        };
        for k in 0..fine {
            all.push(at(hit + 0.1 * (k as f32 / fine as f32 - 0.5)));
        }
    }
    let active = net.levels();
    let mut f_coarse = vec![0.0; coarse.len()];
    let mut work = VolumeWork::default();
    let d_f: Vec<f32> = (0..all.len())
        .map(|_| 1e-3 * (2.0 * rng.next_f32() - 1.0))
        .collect();
    let d_g: Vec<f32> = (0..3 * all.len())
        .map(|_| 1e-3 * (2.0 * rng.next_f32() - 1.0))
        .collect();
    let mut grad = vec![0.0; params.len()];
    let eik = Eikonal::Exact;

    // The kernels: a layer of 64 units over a chunk of 128 points.
    let z0: Vec<f32> = (0..64 * 128)
        .map(|_| 0.05 * (2.0 * rng.next_f32() - 1.0))
        .collect();
    let (mut z, mut slope) = (z0.clone(), vec![0.0; z0.len()]);
    let kernel_reps = 200;

    println!(
        "neus_fast.sdfl, every level on: {} rays × ({} + {fine}) samples, {} params in the hash SDF",
        batch.rays.len(),
        batch.samples,
        net.param_count()
    );
    println!(
        "load before: {}; threads {}",
        load(),
        rayon::current_num_threads()
    );
    // Warm-up (grows the workspaces).
    for _ in 0..2 {
        run.advance(&setup).expect("step");
    }
    net.volume_forward(&params, &all, eik, active, &mut work);
    net.volume_backward(&params, &all, &d_f, &d_g, eik, active, &mut work, &mut grad);
    let mut t = [(); 6].map(|_| Vec::new());
    for _ in 0..reps {
        t[0].push(ms(|| {
            run.advance(&setup).expect("step");
        }));
        t[1].push(ms(|| {
            net.distances(&params, &coarse, active, &mut f_coarse)
        }));
        t[2].push(ms(|| {
            net.volume_forward(&params, &all, eik, active, &mut work)
        }));
        t[3].push(ms(|| {
            net.volume_backward(&params, &all, &d_f, &d_g, eik, active, &mut work, &mut grad)
        }));
        t[4].push(ms(|| {
            for _ in 0..kernel_reps {
                z.copy_from_slice(&z0);
                softplus_libm(black_box(&mut z), &mut slope, 100.0);
            }
        }));
        t[5].push(ms(|| {
            for _ in 0..kernel_reps {
                z.copy_from_slice(&z0);
                softplus_layer(black_box(&mut z), Some(&mut slope), 100.0);
            }
        }));
    }
    let [step, upsample, forward, backward, libm, lanes] = t.map(median_min);
    println!("| neus_fast part | ms (median) | ms (min) | / step (median) |");
    println!("|---|---:|---:|---:|");
    for (name, (med, min)) in [
        ("training step (run.advance)", step),
        (
            &*format!("distance-only pass, {} coarse samples", coarse.len()),
            upsample,
        ),
        (&*format!("forward f, ∇f, {} samples", all.len()), forward),
        (&*format!("backward, {} samples", all.len()), backward),
    ] {
        println!("| {name} | {med:.2} | {min:.2} | {:.2} |", med / step.0);
    }
    println!(
        "| softplus with slope, 64 × 128 units × {kernel_reps} | ms (median) | ms (min) | libm / this (median) |"
    );
    println!("|---|---:|---:|---:|");
    for (name, (med, min)) in [
        ("libm ln_1p per unit (before)", libm),
        ("softplus_layer (vectorised)", lanes),
    ] {
        println!("| {name} | {med:.2} | {min:.2} | {:.2} |", libm.0 / med);
    }
    println!("load after: {}", load());
}
