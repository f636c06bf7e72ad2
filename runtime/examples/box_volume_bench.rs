//! Benchmark of the assignment's box volume: one training step (4096 rays ×
//! 64 samples) with the fused kernel and with the dfdx graph, and one
//! 256×256 render. Compare with `bench/pytorch/box_volume_bench.py`.
//!
//! `cargo run --release -p sdfl-runtime --example box_volume_bench [reps]`

fn main() {
    let reps = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let t =
        sdfl_runtime::volume::bench::bench_box_volume(4096, 64, 256, reps).unwrap_or_else(|e| {
            eprintln!("benchmark failed: {e}");
            std::process::exit(1)
        });
    println!("threads                : {}", rayon::current_num_threads());
    let ms =
        |(med, min): (f64, f64)| format!("{:8.2} ms median {:8.2} ms min", med * 1e3, min * 1e3);
    println!("fused step (4096x64)   : {}", ms(t.fused_step_s));
    println!("dfdx graph step        : {}", ms(t.dfdx_step_s));
    println!("dfdx + fused op step   : {}", ms(t.fused_op_step_s));
    println!("render 256x256x64      : {}", ms(t.render_s));
}
