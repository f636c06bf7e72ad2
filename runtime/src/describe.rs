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

/// The logs a `train` statement writes as it goes and how often, named as
/// [`crate::train::log`] writes them; the held-out image's renders are the
/// held-out evaluation's (costed with the statement's work).
pub fn logs(job: &TrainJob) -> String {
    use sdfl_stdlib::value::Dataset;
    let logs = sdfl_stdlib::outputs::TrainingLogs::of(&job.name);
    let image = logs.held_out_image.display();
    let when = match job.eval_every {
        0 => "at the end".to_string(),
        n => format!("every {n} steps and at the end"),
    };
    // Read data sets hold views out or not once read.
    let held_out = match &*job.data {
        Dataset::Rendered { test, .. } | Dataset::Traced { test, .. } if test.is_empty() => {
            format!("no {image} (no views held out)")
        }
        Dataset::Points { .. } => format!("no {image} (no views held out)"),
        Dataset::Rendered { .. } | Dataset::Traced { .. } => {
            format!("{image} (each held-out evaluation: {when})")
        }
        Dataset::Files { .. } | Dataset::NerfSynthetic { .. } | Dataset::Capture(_) => {
            format!("{image} (each held-out evaluation, if the data holds views out: {when})")
        }
    };
    format!(
        "{} and {}/ (every step), {held_out}",
        logs.metrics_csv.display(),
        logs.tensorboard.display()
    )
}

/// When a `train` statement writes its checkpoint.
pub fn checkpoint(job: &TrainJob) -> String {
    match &job.checkpoint {
        Some(path) => format!(
            "{} every {} steps, when stopped by a signal, and at the end",
            path.display(),
            crate::jobs::CHECKPOINT_EVERY
        ),
        None => "none (no `checkpoint` named: a stopped run starts over)".into(),
    }
}
