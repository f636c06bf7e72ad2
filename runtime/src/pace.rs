//! How fast this machine does sdfl's unit of work, so that `sdfl plan` can
//! put a wall time beside each stage's evaluations. An evaluation is a
//! primitive's distance or [`MULTIPLY_ADDS_PER_EVALUATION`] of a network's
//! multiply-adds; the machine's rate is measured once a process, on the
//! layer kernel the networks use, with every thread.

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use sdfl_stdlib::work::MULTIPLY_ADDS_PER_EVALUATION;

use crate::neural::mlp::{Activation, Dense};

/// The share of a dense layer's multiply-add rate that whole training
/// runs and renders reach per evaluation counted: their hash-grid gathers,
/// compositing, backward passes and narrow layers run slower than one
/// wide product. Measured by `plan` against `run` on this project's
/// examples (docs/results.md, "plan's times").
pub const RUN_EFFICIENCY: f64 = 0.4;

/// Rows of the calibration layer: enough to keep every thread busy, a
/// millisecond or two a pass.
const ROWS: usize = 16_384;
/// Width of the calibration layer, the examples' typical hidden width.
const WIDTH: usize = 64;
/// How long the calibration runs (after one warm-up pass): its fastest
/// pass counts, so that a moment's load elsewhere (a build) does not make
/// `plan` promise hours for minutes; the machine's own speed is what a
/// run gets once it is quiet.
const MEASURE: Duration = Duration::from_millis(60);

/// Multiply-adds a second of a `WIDTH`-wide dense layer on this machine
/// with every thread of the pool, measured once (its fastest pass).
pub fn layer_rate() -> f64 {
    static RATE: OnceLock<f64> = OnceLock::new();
    *RATE.get_or_init(measure_layer)
}

/// Evaluations a second on this machine, for whole runs: [`layer_rate`]
/// in evaluations, times [`RUN_EFFICIENCY`].
pub fn evaluation_rate() -> f64 {
    layer_rate() / MULTIPLY_ADDS_PER_EVALUATION * RUN_EFFICIENCY
}

fn measure_layer() -> f64 {
    let layer = Dense::new(&[WIDTH], WIDTH, Activation::Relu, 0);
    let params: Vec<f32> = (0..layer.len())
        .map(|i| ((i % 7) as f32 - 3.0) * 0.01)
        .collect();
    let input: Vec<f32> = (0..ROWS * WIDTH).map(|i| ((i % 11) as f32) * 0.1).collect();
    let mut out = vec![0.0f32; ROWS * WIDTH];
    layer.forward(&params, &[&input], &mut out);
    let start = Instant::now();
    let mut fastest = f64::INFINITY;
    while start.elapsed() < MEASURE {
        let t = Instant::now();
        layer.forward(&params, &[&input], &mut out);
        fastest = fastest.min(t.elapsed().as_secs_f64());
    }
    (ROWS * WIDTH * WIDTH) as f64 / fastest.max(1e-9)
}
