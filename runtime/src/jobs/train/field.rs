//! The trained field a `train` statement fits, built from its model: the
//! one place the job tells the model kinds apart. Everything after goes
//! through [`TrainedField`]; what is particular to a kind (a NeRF's
//! networks, a surface's β schedule) lives with its model.

use super::super::*;
use crate::neural::distance::NeuralSdfObjective;
use crate::neural::hash_sdf::objective::HashSdfObjective;
use crate::neural::surface::SurfaceObjective;
use crate::train::field::{analytic, Region, Viewing};
use crate::train::{Trained, TrainedField};
use sdfl_stdlib::value::{Encoding, Unbounded};

/// The field `job` trains over `steps` steps (a scheduled β reaches its
/// end at the last), on `points` where it fits a point cloud. An NDC
/// camera not yet known (`sdfl plan`, before the data is read) stands in
/// as a unit one, which changes no size; the job fills it in first.
pub fn trained_field(
    job: &TrainJob,
    steps: usize,
    points: &[[f32; 3]],
) -> Result<Box<dyn TrainedField>, String> {
    let viewing = |region: Option<Region>| Viewing::new(&job.sampler, region);
    Ok(match &*job.model {
        Field::Sdf(f) => Box::new(analytic(TrainModel::new(f), job.backend, &job.sampler)?),
        Field::Nerf(n) => Box::new(Trained {
            objective: NerfObjective::new(&crate::neural::warp::for_layout(n), &job.sampler)?,
            viewing: viewing(job.model.export_region())?,
        }),
        Field::NeuralSdf(n) => {
            let viewing = viewing(Some(mesh_region(points, job.bounds)))?;
            match &n.encoding {
                Encoding::Harmonic(_) => Box::new(Trained {
                    objective: NeuralSdfObjective::new(n, &job.losses, job.bounds),
                    viewing,
                }),
                Encoding::HashGrid(g) => Box::new(Trained {
                    objective: HashSdfObjective::new(n, g, &job.losses, job.bounds)?,
                    viewing,
                }),
            }
        }
        Field::NeuralSurface(n) => Box::new(Trained {
            objective: SurfaceObjective::new(n, &job.losses)?.with_steps(steps),
            viewing: viewing(Some(mesh_region(&[], job.bounds)))?,
        }),
    })
}

/// A NeRF in NDC (`unbounded: ndc()`) takes its camera from the
/// forward-facing capture just read: the job with it filled in, `None`
/// when the model is not one.
pub(super) fn with_ndc_frame(
    job: &TrainJob,
    forward_facing: Option<crate::data::capture::ForwardFacing>,
    status: &dyn Fn(&str),
) -> io::Result<Option<TrainJob>> {
    let Field::Nerf(n) = &*job.model else {
        return Ok(None);
    };
    if !needs_ndc_frame(job) {
        return Ok(None);
    }
    let Some(ff) = forward_facing else {
        return Err(crate::data::at_argument(
            job.data_span,
            invalid(format!(
                "training `{}`: `unbounded: ndc()` needs a forward-facing capture, read and normalised (`capture(..., format: \"llff\")`); this data is not one, or `normalize: false` kept the data's frame",
                job.name
            )),
        ));
    };
    if job.sampler.far < ff.far {
        status(&format!(
            "warning: NDC samples reach depth {} (the sampler's `far`), short of the capture's farthest bound {}: content beyond is cut off (give the sampler a larger `far`, e.g. 1000)",
            sdfl_lang::fmt_num(job.sampler.far),
            sdfl_lang::fmt_num((ff.far * 1000.0).round() / 1000.0)
        ));
    }
    let model = sdfl_stdlib::value::Nerf {
        unbounded: Some(Unbounded::Ndc(Some(ff.ndc))),
        ..n.clone()
    };
    Ok(Some(TrainJob {
        model: std::sync::Arc::new(Field::Nerf(model)),
        ..job.clone()
    }))
}

/// The object's region in the trained field's frame, where a point cloud
/// with `crop: "auto"` keeps its points: the model's own
/// ([`sdfl_stdlib::model::Model::object_region`]), else the region the
/// trained field covers (a neural surface's training bounds), but for a
/// NeRF, whose region where it has none (NDC) is everywhere.
pub(super) fn object_region(job: &TrainJob, field: &dyn TrainedField) -> Option<Region> {
    match &*job.model {
        Field::Nerf(_) => job.model.object_region(),
        other => other.object_region().or(field.region()),
    }
}

/// Whether `job`'s model waits for the forward-facing capture's NDC frame
/// (`unbounded: ndc()`, filled in once the data is read).
pub(super) fn needs_ndc_frame(job: &TrainJob) -> bool {
    matches!(&*job.model, Field::Nerf(n) if n.unbounded == Some(Unbounded::Ndc(None)))
}

/// The region a neural SDF's mesh covers by default: its points' box grown
/// by a tenth of its diagonal, or without points the training `bounds`.
fn mesh_region(points: &[[f32; 3]], bounds: f64) -> ([f64; 3], [f64; 3]) {
    if points.is_empty() {
        return ([-bounds; 3], [bounds; 3]);
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    let diagonal = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let grow = 0.1 * diagonal.max(1e-3);
    (lo.map(|x| x - grow), hi.map(|x| x + grow))
}
