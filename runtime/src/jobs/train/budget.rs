//! What a training run may hold and do, checked before any step: its
//! estimated peak memory against what the system has, the work and memory
//! of data known only once it is read, and outputs that need held-out
//! views the data does not have.

use super::super::*;

/// Memory this process may use: what the system says is available, or
/// 8 GiB where it cannot tell.
fn available_memory() -> u64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| {
            m.lines()
                .find(|l| l.starts_with("MemAvailable:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        })
        .map_or(8 << 30, |kib| kib * 1024)
}

/// Refuses a run whose estimated peak (the plan's, one estimate for both:
/// [`sdfl_stdlib::work::train_work`] on this machine) is more than the
/// memory available. Data read from files joins it once read
/// ([`within_budget_once_read`]).
pub(super) fn fits_in_memory(job: &TrainJob) -> io::Result<()> {
    let need = sdfl_stdlib::work::train_work(job, None).memory_on(&crate::cpu::host());
    let have = available_memory() as f64;
    if need > have {
        let gib = |b: f64| b / (1u64 << 30) as f64;
        return Err(invalid(format!(
            "training `{}` would hold about {:.1} GiB at its peak ({} rays × {} samples a step), more than the {:.1} GiB available: use fewer `rays` or samples (or, for an analytic field, no jitter or the fused backend); `sdfl plan` shows the estimate by stage",
            job.name,
            gib(need),
            job.rays,
            job.sampler.samples,
            gib(have)
        )));
    }
    Ok(())
}

/// Data read from files may hold no views out (a capture whose split
/// lists name none): refused now, not after training, when an output
/// needs them.
pub(super) fn held_out_views_present(job: &TrainJob, test_views: &[TrainView]) -> io::Result<()> {
    if let Some(o) = job
        .after
        .iter()
        .find(|o| matches!(o.kind, OutputKind::PsnrCurve | OutputKind::Comparison))
        .filter(|_| test_views.is_empty())
    {
        return Err(crate::data::at_argument(
            job.data_span,
            invalid(format!(
                "`{}` needs held-out views, and the data set read holds none out (its split lists name no test view, or `test_every: 0`)",
                o.path.display()
            )),
        ));
    }
    Ok(())
}

/// What a data set read from files holds is known only once it is read (a
/// NeRF-synthetic test split, its images' sizes): its held-out evaluation
/// and its pixels join the statement's budget then, before any step runs.
/// The numbers are those `sdfl plan` estimates from the images' headers
/// ([`crate::data::OnceRead`], [`crate::data::view_bytes`]).
pub(super) fn within_budget_once_read(
    job: &TrainJob,
    size: Option<(u32, u32)>,
    views: &[TrainView],
    test_views: &[TrainView],
) -> io::Result<()> {
    use sdfl_stdlib::work::{
        max_evaluations, max_memory, raised_limit, MAX_EVALUATIONS_VAR, MAX_MEMORY_VAR,
    };
    if matches!(*job.data, Dataset::Rendered { .. } | Dataset::Traced { .. }) {
        // Rendered by sdfl: counted when the file was evaluated.
        return Ok(());
    }
    let pixels = |v: &TrainView| v.image.width as f64 * v.image.height as f64;
    let largest = test_views.iter().map(pixels).fold(0.0, f64::max);
    let data = crate::data::views_bytes(views.iter().chain(test_views));
    let budget = crate::data::OnceRead::of(job, size, test_views.len(), largest, data);
    let limit = max_evaluations();
    if budget.evaluations > limit {
        return Err(invalid(format!(
            "training `{}` is expected to need {:.1e} evaluations (the limit is {limit:.0e}), {:.1e} of them scoring its {} held-out views: score less often (`eval_every`), with fewer views or samples; a run meant to take hours may raise the limit with {MAX_EVALUATIONS_VAR}",
            job.name,
            budget.evaluations,
            budget.held_out_evaluations,
            test_views.len()
        )));
    }
    if budget.memory > max_memory() {
        // The help names the larger part: the views, or the step itself.
        let fix = if data > budget.memory / 2.0 {
            "use fewer or smaller views (`downscale`, `eval_views`)"
        } else {
            "use fewer `rays` or samples; `sdfl plan` shows the estimate by stage"
        };
        return Err(invalid(format!(
            "training `{}` would hold about {:.1} GB ({:.1} GB of it the data set's {} views; the limit is {:.1} GB): {fix}; a machine with the memory may raise the limit: {MAX_MEMORY_VAR}={:.0e}",
            job.name,
            budget.memory / 1e9,
            data / 1e9,
            views.len() + test_views.len(),
            max_memory() / 1e9,
            raised_limit(budget.memory)
        )));
    }
    Ok(())
}
