//! The optimiser's share of a NeRF step at instant-ngp's size: dfdx's Adam
//! kernel through `update_from_slices` (the route every fused step took
//! before) against `update_in_place`, with the values read and written
//! back as a step does. Both give the same bits (a runtime test checks).

use std::time::Instant;

use sdfl_runtime::train::{Adam, ParamId, ParamStore};
use sdfl_stdlib::value::Moments;

use crate::stats::{load, median_min};

/// Times both routes `reps` times each, interleaved, on a store shaped like
/// `examples/benchmarks/nerf_synthetic.sdfl`'s model.
pub fn main(reps: usize) {
    // 16 levels × 2^19 rows × 2 features, then the two small networks.
    let sizes = [16usize << 20, 32 * 64 + 64 * 16, 32 * 64 + 64 * 64 + 64 * 3];
    let total: usize = sizes.iter().sum();
    let moments = Moments {
        beta1: 0.9,
        beta2: 0.99,
        eps: 1e-15,
    };
    let mut store = ParamStore::new();
    let mut parts = Vec::new();
    let mut offset = 0;
    for (k, &n) in sizes.iter().enumerate() {
        let init: Vec<f32> = (0..n).map(|i| ((i % 97) as f32 - 48.0) * 1e-4).collect();
        let id = store.add(&format!("p{k}"), &init, true).expect("finite");
        parts.push((id, offset..offset + n));
        offset += n;
    }
    let gradient: Vec<f32> = (0..total)
        .map(|i| ((i % 31) as f32 - 15.0) * 1e-3)
        .collect();
    let mut values = vec![0.0f32; total];
    let mut grads = vec![0.0f32; total];
    let mut adam = Adam::with_moments(1e-2, moments).expect("valid");
    let (mut dfdx_ms, mut fused_ms) = (Vec::new(), Vec::new());
    let read = |store: &ParamStore, values: &mut [f32]| {
        for (id, r) in &parts {
            store.copy_values(*id, &mut values[r.clone()]);
        }
    };
    for _ in 0..reps {
        // As a step did: values read, gradient zeroed, the dfdx update,
        // values read again and set back.
        grads.copy_from_slice(&gradient);
        let t = Instant::now();
        read(&store, &mut values);
        let slices: Vec<(ParamId, &[f32])> = parts
            .iter()
            .map(|(id, r)| (*id, &grads[r.clone()]))
            .collect();
        adam.update_from_slices(&mut store, &slices)
            .expect("finite");
        read(&store, &mut values);
        for (id, r) in &parts {
            store.set_values(*id, &values[r.clone()]).expect("length");
        }
        grads.fill(0.0);
        dfdx_ms.push(t.elapsed().as_secs_f64() * 1e3);
        // As a step does now.
        grads.copy_from_slice(&gradient);
        let t = Instant::now();
        read(&store, &mut values);
        adam.update_in_place(&mut store, &parts, &mut values, &mut grads)
            .expect("finite");
        for (id, r) in &parts {
            store.set_values(*id, &values[r.clone()]).expect("length");
        }
        fused_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let (d, dmin) = median_min(dfdx_ms);
    let (f, fmin) = median_min(fused_ms);
    println!(
        "Adam over {total} parameters, {} threads, load {}:",
        rayon::current_num_threads(),
        load()
    );
    println!("| route | median ms | min ms |");
    println!("|---|---:|---:|");
    println!("| dfdx kernel (update_from_slices) | {d:.1} | {dmin:.1} |");
    println!("| update_in_place | {f:.1} | {fmin:.1} |");
    println!("in place / dfdx: {:.2}", f / d);
}
