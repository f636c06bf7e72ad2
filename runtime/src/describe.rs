//! Descriptions of what the runtime will do for a statement, for
//! `sdfl plan`: the CLI asks here instead of reaching into the runtime's
//! modules.

use sdfl_stdlib::value::TrainJob;

pub use crate::train::field::Description;

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

/// What a `train` statement trains and how, from the trained field the
/// runtime would build; what cannot be built (a NeRF whose grid does not
/// fit) says why.
pub fn train(job: &TrainJob) -> Description {
    match crate::jobs::trained_field(job, job.iterations, &[]) {
        Ok(field) => field.describe(),
        Err(e) => Description {
            trainable: format!("none: {e}"),
            gradient: "none: the model cannot be built".into(),
            mesh_region: "none".into(),
        },
    }
}
