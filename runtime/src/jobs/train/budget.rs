//! What a training run may hold and do, checked before any step: the
//! memory a step needs against what the system has, the work and memory
//! of data known only once it is read, and outputs that need held-out
//! views the data does not have.

use super::super::*;

/// Bytes a training step holds beyond the data: per ray its description,
/// target and (when jittered) its own depths; the dfdx graph also holds
/// every sample's intermediates and the samples × samples cumsum matrix.
pub fn step_memory(job: &TrainJob) -> u64 {
    let (rays, samples) = (job.rays as u64, job.sampler.samples as u64);
    let jitter = if job.sampler.jitter { 4 * samples } else { 0 };
    let graph = match (&*job.model, job.backend) {
        // Every layer's activations and two adjoint buffers per sample,
        // the sample points, and the optimiser's copies of the weights.
        (Field::Nerf(n), _) => {
            let net = NerfNet::new(&crate::neural::warp::for_layout(n));
            // The fine network sees the coarse and the fine samples.
            let per_ray = samples
                + if n.fine > 0 {
                    samples + n.fine as u64
                } else {
                    0
                };
            let weights = net.len as u64 * if n.fine > 0 { 2 } else { 1 };
            NerfWork::bytes_for(&net, (rays * per_ray) as usize)
                + rays * per_ray * 40
                + 24 * weights
        }
        // Values and three tangents per layer, forward and back, for a
        // surface and a random point per ray.
        (Field::NeuralSdf(n), _) => match &n.encoding {
            sdfl_stdlib::value::Encoding::Harmonic(_) => {
                let net = crate::neural::distance::sdf_net(n);
                crate::neural::sdf_net::SdfWork::bytes_for(&net, 2 * rays as usize)
                    + 24 * net.len as u64
            }
            // The network's buffers, the tables' gradient and the
            // optimiser's copies.
            sdfl_stdlib::value::Encoding::HashGrid(g) => {
                use crate::neural::hash_sdf::objective::HashSdfObjective;
                HashSdfObjective::new(n, g, &job.losses, job.bounds)
                    .map_or(0, |o| o.step_bytes(2 * rays as usize))
            }
        },
        // The distance network's values and reverse pass at every sample,
        // plus the colour network's activations and the adjoints.
        (Field::NeuralSurface(n), _) => {
            crate::neural::surface::SurfaceObjective::new(n, &job.losses)
                .map_or(0, |o| o.step_bytes(rays as usize, samples as usize))
        }
        (Field::Sdf(_), Backend::Fused) => 0,
        (Field::Sdf(_), Backend::Dfdx) => {
            rays * samples * crate::train::graph::BYTES_PER_SAMPLE + 4 * samples * samples
        }
    };
    rays * (48 + jitter) + graph
}

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

/// Refuses a run whose step would hold more than half the memory available.
pub(super) fn step_fits_in_memory(job: &TrainJob) -> io::Result<()> {
    let need = step_memory(job);
    let have = available_memory();
    if need > have / 2 {
        return Err(invalid(format!(
            "training `{}` would hold about {:.1} GiB per step ({} rays × {} samples), more than half of the {:.1} GiB available: use fewer `rays` or samples (or, for an analytic field, no jitter or the fused backend)",
            job.name,
            need as f64 / (1u64 << 30) as f64,
            job.rays,
            job.sampler.samples,
            have as f64 / (1u64 << 30) as f64
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
    use sdfl_stdlib::work::{max_evaluations, MAX_EVALUATIONS_VAR, MAX_MEMORY};
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
    if budget.memory > MAX_MEMORY {
        return Err(invalid(format!(
            "training `{}` would hold about {:.1} GB ({:.1} GB of it the data set's {} views): use fewer or smaller views",
            job.name,
            budget.memory / 1e9,
            data / 1e9,
            views.len() + test_views.len()
        )));
    }
    Ok(())
}
