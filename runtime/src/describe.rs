//! Descriptions of what the runtime will do for a statement, for
//! `sdfl plan`: the CLI asks here instead of reaching into the runtime's
//! modules.

use sdfl_stdlib::value::TrainJob;

/// Which number format a network's layer products run in, here.
pub fn precision(p: sdfl_stdlib::value::Precision) -> String {
    use sdfl_stdlib::value::Precision;
    let min = crate::neural::mlp::BF16_MIN;
    match (p, crate::neural::bf16::available()) {
        (Precision::Fp32, _) => "layer products in fp32".into(),
        (Precision::Bf16, true) => format!(
            "layer products in bf16 with fp32 sums (this CPU has AVX-512 BF16; layers narrower than {min} stay fp32)"
        ),
        (Precision::Bf16, false) => {
            "layer products in fp32: bf16 asked for, but this CPU lacks AVX-512 BF16".into()
        }
    }
}

/// What a `train` statement trains: its parameters or weights, counted
/// from the trained field the runtime would build.
pub fn trainable(job: &TrainJob) -> String {
    match crate::jobs::trained_field(job, job.iterations, &[]) {
        Ok(field) => field.describe().trainable,
        Err(e) => format!("none: {e}"),
    }
}

/// What the fused kernel runs for an analytic field: its traced tape (at
/// the starting values) or, where the field branches on the sample,
/// forward-mode tangents.
pub fn fused_kernel(field: &sdfl_stdlib::value::Field, samples: usize) -> String {
    let Some(sdf) = field.as_sdf() else {
        return "fused per-ray kernel".into();
    };
    let model = crate::train::TrainModel::new(sdf);
    let values: Vec<f32> = model.initial_values().iter().map(|&x| x as f32).collect();
    match crate::train::fused::tape_for(&model, &values, samples) {
        Ok(tape) => format!(
            "traced each step: {} operations a sample forward, {} in reverse on 16 samples at a time, one reverse pass for all {} scalars",
            tape.len(),
            tape.reverse_len(),
            model.scalars
        ),
        Err(why) => format!(
            "fused per-ray kernel: forward-mode tangents for each parameter (not traced: {why})"
        ),
    }
}
