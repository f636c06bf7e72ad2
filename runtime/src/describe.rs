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
/// from the model the runtime would build.
pub fn trainable(job: &TrainJob) -> String {
    match &*job.model {
        sdfl_stdlib::value::Field::NeuralSdf(n) => {
            format!(
                "all {} weights, starting as a sphere of radius {}",
                crate::neural::distance::sdf_net(n).len,
                n.radius
            )
        }
        sdfl_stdlib::value::Field::NeuralSurface(n) => {
            use crate::train::Objective;
            let m = crate::neural::surface::SurfaceObjective::new(n, &job.losses);
            let beta = usize::from(n.train_beta || n.beta_end.is_some());
            format!(
                "all {} weights (distance network {}, colour network {}){}, the distance starting as a sphere of radius {}",
                m.initial().len() - beta,
                m.sdf.len,
                m.initial().len() - m.sdf.len - beta,
                match (n.train_beta, n.beta_end) {
                    (true, _) => format!(", and beta from {} (as ln(beta)/20: it moves 20 times faster than a weight; kept in 1e-4..10)", n.beta),
                    (false, Some(end)) => format!(" (beta is not trained: it falls geometrically from {} to {end} over the steps)", n.beta),
                    (false, None) => String::new(),
                },
                n.sdf.radius
            )
        }
        sdfl_stdlib::value::Field::Sdf(f) => {
            let model = crate::train::TrainModel::new(f);
            let params: Vec<String> = model
                .params
                .iter()
                .map(|p| format!("{} ({})", p.name, p.len))
                .collect();
            format!("{} (gradients only for these)", params.join(", "))
        }
        sdfl_stdlib::value::Field::Nerf(n) => {
            use crate::train::Objective;
            match crate::neural::field::NerfObjective::new(
                &crate::neural::warp::for_layout(n),
                &job.sampler,
            ) {
                Ok(m) => format!(
                    "all {} weights in {} tensors{}",
                    m.initial().len(),
                    m.tensors().len(),
                    if m.fine.is_some() {
                        " (coarse and fine networks)"
                    } else {
                        ""
                    }
                ),
                Err(e) => format!("none: {e}"),
            }
        }
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
