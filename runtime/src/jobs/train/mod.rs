//! Running `train` statements: the data read and checked, the trained
//! field built ([`field`]: the one place that tells model kinds apart),
//! resumed from its checkpoint ([`resume`]), trained with a held-out
//! evaluation every `eval_every` steps ([`evaluation`]), and its outputs
//! written ([`outputs`]); [`budget`] refuses runs too large before any
//! step.

use super::*;
use sdfl_stdlib::value::ViewPath;

mod budget;
pub mod evaluation;
mod field;
mod outputs;
mod record;
pub mod resume;
mod view;

use crate::train::log::{first_view, Observer, TrainEvent, TrainLog};
pub use evaluation::HeldOut;
pub use field::trained_field;
pub use resume::fingerprint;
pub use view::{checkpoint_path, CheckpointStamp, CheckpointedField, FieldUnavailable};

use evaluation::{evaluate, evaluate_into};
use record::Kept;
use resume::Checkpoints;
pub(crate) use resume::CHECKPOINT_EVERY;

/// The learned parameters and how training went.
#[derive(Debug, Clone, Serialize)]
pub struct TrainReport {
    /// The `train` statement's name, which its outputs and checkpoint carry.
    pub name: String,
    /// Steps done in all (a resumed run counts the earlier ones).
    pub iterations: usize,
    /// The checkpoint's step this run resumed from; `None` for a fresh start.
    pub resumed_from: Option<usize>,
    /// Loss of the last step.
    pub final_loss: f32,
    /// Mean wall-clock seconds per training step of this run.
    pub seconds_per_step: f64,
    /// Samples a ray that reached the network in this run's steps, of the
    /// sampler's (the rest skipped as empty space); `None` where the model
    /// does not count them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub samples_per_ray: Option<SamplesPerRay>,
    /// Learned values by parameter name (`box.center`, or a `let` name);
    /// empty for a neural field (its weights are in the checkpoint).
    pub params: Vec<(String, Vec<f32>)>,
    /// Weights of a neural field.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub network_weights: Option<usize>,
    /// Held-out quality during and after training (empty without test views).
    pub held_out: Vec<HeldOut>,
    /// A capture's normalisation: data frame → scene frame
    /// (`to_scene(p) = scale·R·(p − center)`), so results map back.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scene_frame: Option<crate::data::normalize::SceneFrame>,
    /// How well a distance field fits its points.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fit: Option<crate::neural::distance::SdfFit>,
    /// The first mesh written after training, against all the data's
    /// points, or against the true surface of a scene sdfl rendered.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh_fit: Option<crate::neural::distance::MeshFit>,
    /// Files written after training (images, meshes, exports), relative to `--out`.
    pub written: Vec<Written>,
    /// The outputs among `written` kept as they were: the run was already
    /// at their checkpoint step and nothing they are made from changed.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub kept_outputs: Vec<PathBuf>,
    /// Wall-clock seconds of each stage (load data, train, held-out evaluation…).
    pub stages: Vec<(String, f64)>,
    /// What looks wrong with the fit (code `sdfl::warn::diverged`): a loss
    /// that ended far above its lowest, parameters held at their range.
    pub warnings: Vec<String>,
}

/// What a training step really evaluated a ray, against what its sampler
/// places.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct SamplesPerRay {
    /// Mean samples a ray that the networks evaluated (a fine network's
    /// included).
    pub evaluated: f64,
    /// The sampler's samples a ray.
    pub sampled: usize,
}

/// Options of a training run that are not in the file.
#[derive(Debug, Clone, Copy, Default)]
pub struct TrainOptions {
    /// Start over instead of resuming an existing checkpoint.
    pub restart: bool,
}

/// Runs one `train` statement: loads its data, resumes from its checkpoint
/// if any, trains, scores the held-out views and writes its outputs under
/// `out_dir`.
#[allow(clippy::too_many_arguments)]
pub fn run_train_job(
    job: &TrainJob,
    out_dir: &Path,
    base: &Path,
    size: Option<(u32, u32)>,
    options: TrainOptions,
    observer: &Observer,
) -> io::Result<TrainReport> {
    let status = |m: &str| observer(&TrainEvent::Note(m));
    budget::fits_in_memory(job)?;
    let mut stages = Vec::new();
    let t = Instant::now();
    let Views {
        train: views,
        test: test_views,
        points,
        all_points,
        scene_report,
        scene_frame,
        forward_facing,
        points_mean,
    } = load_views_for(&job.data, base, DataNeeds::of(job))
        .map_err(|e| crate::data::at_argument(job.data_span, e))?;
    for line in &scene_report {
        status(line);
    }
    let resolved;
    let job = match field::with_ndc_frame(job, forward_facing, &status)? {
        Some(j) => {
            resolved = j;
            &resolved
        }
        None => job,
    };
    stages.push(("load data".to_string(), t.elapsed().as_secs_f64()));
    let size = size.or_else(|| output_size_at_data_aspect(job, &views));
    budget::within_budget_once_read(job, size, &views, &test_views)?;
    budget::held_out_views_present(job, &test_views)?;
    // The budget counted them at full size, and the cost at the scored one.
    let test_views = scored_at_size(job, test_views)?;
    let outputs = outputs::Outputs {
        job,
        out_dir,
        cameras: output_cameras(job, &views)?,
        size: size.unwrap_or((job.width, job.height)),
        ray_views: views
            .iter()
            .map(|v| {
                let (width, height) = (v.image.width, v.image.height);
                (v.camera, ImageSize { width, height })
            })
            .collect(),
        to_data: scene_frame
            .as_ref()
            .map_or(glam::DAffine3::IDENTITY, |f| f.to_data_affine()),
        observer,
    };

    let mut setup = TrainSetup::of(job, &views);
    setup.points = &points;
    let steps = match job.epochs {
        Some(e) => e.saturating_mul(setup.steps_per_epoch()),
        None => job.iterations,
    };
    let field = trained_field(job, steps, &points).map_err(invalid)?;
    let network = field.is_network();
    let fail = |e: TrainError| io::Error::other(format!("training `{}`: {e}", job.name));
    let mut run = Run::for_optimizer(field, &job.optimizer).map_err(fail)?;
    // Checkpoints name and shape the tensors by role and carry the model
    // and its place relative to the data: a capture's normalisation, or
    // the point cloud's centring (a translation).
    let tensors = run.objective.tensors();
    let data_frame = scene_frame.or_else(|| {
        points_mean.map(|m| {
            crate::data::normalize::SceneFrame::new(
                1.0,
                glam::DVec3::from_array(m),
                glam::DMat3::IDENTITY,
            )
        })
    });
    // ... and where its views were taken from, for a viewer to start there.
    run.describe(
        crate::train::export_names::Layout::of(&job.model, &tensors)
            .in_data_frame(data_frame)
            .with_cameras(views.iter().map(|v| &v.camera)),
    );
    let checkpoints = Checkpoints::of(job, &views, out_dir);
    let (resumed_from, history) = checkpoints.resume_or_start(&mut run, steps, options.restart)?;
    // Run again at the step its outputs were made at, a run keeps those
    // unchanged since and renders the rest.
    let record = resumed_from.and_then(|step| {
        checkpoints.path.as_ref()?;
        record::OutputsRecord::read(job, out_dir, step, &checkpoints.fingerprint)
    });
    let mut kept = Kept::new(
        job,
        (&outputs.cameras, outputs.size),
        record.as_ref(),
        out_dir,
    );
    let mut written = Vec::new();
    let before = kept.needing_render(&job.before, false);
    if !before.is_empty() {
        written.extend(outputs.before(&*run.objective, &run.values(), &before)?);
    }

    let mut log = TrainLog::open(
        out_dir,
        &job.name,
        job.optimizer,
        &run.losses,
        history,
        steps,
        observer,
    )?;
    let t = Instant::now();
    let done_before = run.step;
    let mut last_good = checkpoints.of_run(&run, log.history());
    let mut io_error = None;
    // Seconds spent evaluating, left out of the training time.
    let mut eval_s = 0.0;
    // A stop by signal comes before its step's evaluation (stopping stays
    // prompt): the resumed run scores that step first, as an unstopped run did.
    let scored = |log: &TrainLog| log.held_out().last().map(|h| h.step) == Some(run.step);
    if resumed_from.is_some() && evaluation::due(job, run.step, &test_views) && !scored(&log) {
        let te = Instant::now();
        evaluate_into(
            &mut log,
            run.step,
            &*run.objective,
            &run.values(),
            &test_views,
            (&job.name, observer),
        )?;
        eval_s += te.elapsed().as_secs_f64();
    }
    // A signal stops training after a step, with a checkpoint of it.
    let graceful = crate::interrupt::Graceful::begin();
    let result = run.run_to(&setup, steps, |r, loss| {
        // Each step.
        log.step(r.step, loss);
        if let Some(signal) = crate::interrupt::stop_requested() {
            let kept = match &checkpoints.path {
                Some(cp) => match checkpoints.write(r, log.history()) {
                    Ok(()) => format!("; {} holds it: run again to resume", cp.display()),
                    Err(e) => format!(
                        "; its checkpoint failed ({e}), {} holds step {}",
                        cp.display(),
                        last_good.step
                    ),
                },
                None => "; no `checkpoint` is named, so it is lost".to_string(),
            };
            io_error = Some(crate::interrupt::Stopped::error(
                signal,
                format!(
                    "training `{}` at step {} of {steps}{kept}",
                    job.name, r.step
                ),
            ));
            return ControlFlow::Break(());
        }
        // Each held-out evaluation.
        if evaluation::due(job, r.step, &test_views) {
            let te = Instant::now();
            let scored = evaluate_into(
                &mut log,
                r.step,
                &*r.objective,
                &r.values(),
                &test_views,
                (&job.name, observer),
            );
            if let Err(e) = scored {
                io_error = Some(e);
                return ControlFlow::Break(());
            }
            eval_s += te.elapsed().as_secs_f64();
        }
        if r.step % 10 == 0 {
            // The same names as the report, the JSON and the checkpoint.
            let mut line = format!("{} loss {loss:.3e}", job.name);
            if let Some(h) = log.held_out().last() {
                line += &format!("  held-out PSNR {:.2} dB (step {})", h.psnr, h.step);
            }
            let shown = if network { 0 } else { 4 };
            for (name, v) in r.named_values().iter().take(shown) {
                let v: Vec<String> = v.iter().map(|x| format!("{x:.3}")).collect();
                line += &format!("  {name} {}", v.join(","));
            }
            observer(&TrainEvent::Status(&line));
        }
        // Each checkpoint.
        if let Some(path) = checkpoints
            .path
            .as_ref()
            .filter(|_| r.step % CHECKPOINT_EVERY == 0)
        {
            last_good = checkpoints.of_run(r, log.history());
            if let Err(e) = last_good.write(path) {
                io_error = Some(e);
                return ControlFlow::Break(());
            }
        }
        ControlFlow::Continue(())
    });
    drop(graceful);
    let train_s = t.elapsed().as_secs_f64() - eval_s;
    stages.push(("train".to_string(), train_s));
    if eval_s > 0.0 {
        stages.push(("held-out evaluation".to_string(), eval_s));
    }
    if let Some(e) = io_error {
        return Err(e);
    }
    if let Err(e) = result {
        let kept = checkpoints
            .path
            .as_ref()
            .map(|p| {
                format!(
                    "; the last good checkpoint (step {}) is kept at {}",
                    last_good.step,
                    p.display()
                )
            })
            .unwrap_or_default();
        let message = format!(
            "training `{}` stopped at step {}: {e}{kept}",
            job.name,
            run.step + 1
        );
        return Err(match e {
            // Not an I/O error: the numbers went bad.
            TrainError::Gradient(_) => io::Error::other(crate::train::NonFinite(message)),
            _ => io::Error::other(message),
        });
    }
    checkpoints.write(&run, log.history())?;

    let t = Instant::now();
    let (field, values) = (&*run.objective, run.values());
    // Steps ran since the record's step: its `after` outputs and scores
    // are of other values.
    if run.step != done_before {
        kept.forget_record();
    }
    let after = kept.needing_render(&job.after, true);
    let (rendered, mesh_fit) = outputs.after(field, &values, &all_points, &after)?;
    let mesh_fit = kept.mesh_fit().or(mesh_fit);
    written.extend(rendered);
    written.extend(outputs.loss_curves(&run.losses, &after)?);
    let comparison = after.iter().any(|o| o.kind == OutputKind::Comparison);
    let mut final_scores = None;
    if !test_views.is_empty() {
        // Scored at this step already, and no comparison to redraw: the
        // scores stand and only the curves are drawn again.
        if let Some(h) = kept.held_out(&test_views).filter(|_| !comparison) {
            final_scores = Some(log.evaluated(run.step, record::scores(&h), 0.0, None));
            written.extend(outputs.held_out(log.held_out(), &test_views, &[], &after)?);
        } else {
            let scored = evaluation::announce(&job.name, run.step, &test_views, observer);
            let keep = sdfl_stdlib::work::COMPARISON_VIEWS;
            let e = evaluate(field, &values, &test_views, keep, &scored)?;
            let first = first_view(&test_views, &e.renders);
            let scores = e.scores(test_views.len());
            final_scores = Some(log.evaluated(run.step, scores, 0.0, first));
            written.extend(outputs.held_out(log.held_out(), &test_views, &e.renders, &after)?);
        }
    }
    let kept_outputs = kept.paths();
    written.extend(kept.written());
    if checkpoints.path.is_some() {
        record::OutputsRecord {
            step: run.step,
            fingerprint: checkpoints.fingerprint.clone(),
            outputs: kept.record(&written),
            held_out: final_scores,
            held_out_key: record::held_out_key(job, &test_views),
            mesh_fit: mesh_fit.as_ref().map(Into::into),
        }
        .write(job, out_dir)?;
    }
    let held_out = log.finish()?;
    let fit = field.fit_to_points(&values, &points, job.seed);
    stages.push(("outputs".to_string(), t.elapsed().as_secs_f64()));
    let steps_run = (run.step - done_before).max(1);
    let mut warnings =
        crate::train::trainer::fit_warnings(&run.losses, &field.held_at_bounds(&values));
    let scored: Vec<(usize, f64)> = held_out.iter().map(|h| (h.step, h.psnr)).collect();
    warnings.extend(crate::train::trainer::held_out_warning(
        &run.losses,
        &scored,
    ));
    Ok(TrainReport {
        scene_frame,
        name: job.name.clone(),
        iterations: run.step,
        resumed_from,
        final_loss: run.losses.last().copied().unwrap_or(f32::NAN),
        seconds_per_step: train_s / steps_run as f64,
        // Only steps run now count samples (a finished run run again has none).
        samples_per_ray: field
            .samples_evaluated()
            .filter(|_| run.step > done_before)
            .map(|n| SamplesPerRay {
                evaluated: n as f64 / (steps_run as f64 * job.rays.max(1) as f64),
                sampled: job.sampler.samples,
            }),
        params: field.reported(&values),
        network_weights: network.then_some(values.len()),
        held_out,
        fit,
        mesh_fit,
        written,
        kept_outputs,
        stages,
        warnings,
    })
}

/// The cameras of the before and after outputs: the statement's, or a
/// loop through the training cameras now that they are read.
fn output_cameras(job: &TrainJob, views: &[TrainView]) -> io::Result<Vec<Camera>> {
    match job.view_path {
        None => Ok(job.views.clone()),
        Some(ViewPath::TrainingPath { frames }) => {
            let train_cams: Vec<Camera> = views.iter().map(|v| v.camera).collect();
            sdfl_stdlib::builtins::paths::training_path(&train_cams, frames).map_err(|e| {
                invalid(format!(
                    "training `{}`: no path through its training cameras: {e}",
                    job.name
                ))
            })
        }
        Some(ViewPath::TrainingLoop { frames, keyframes }) => {
            let train_cams: Vec<Camera> = views.iter().map(|v| v.camera).collect();
            sdfl_stdlib::builtins::paths::camera_loop(&train_cams, frames, keyframes).map_err(|e| {
                invalid(format!(
                    "training `{}`: no loop through its training cameras: {e}",
                    job.name
                ))
            })
        }
    }
}

/// The size of the before/after views at the training images' aspect
/// (the first view's), where the statement leaves it to the data read
/// from files; `None` where it is the statement's.
fn output_size_at_data_aspect(job: &TrainJob, views: &[TrainView]) -> Option<(u32, u32)> {
    use sdfl_stdlib::value::{size_at_aspect, DATA_ASPECT_SHORT_SIDE};
    let first = views.first().filter(|_| job.size_at_data_aspect)?;
    let (w, h) = (first.image.width, first.image.height);
    Some(size_at_aspect(w, h, DATA_ASPECT_SHORT_SIDE))
}

/// The held-out views at the size they are scored (`eval_downscale`).
fn scored_at_size(job: &TrainJob, views: Vec<TrainView>) -> io::Result<Vec<TrainView>> {
    if job.eval_downscale <= 1 {
        return Ok(views);
    }
    views
        .iter()
        .map(|v| v.downscaled(job.eval_downscale))
        .collect::<Result<_, _>>()
        .map_err(|e| {
            crate::data::at_argument(
                job.data_span,
                invalid(format!("`eval_downscale: {}`: {e}", job.eval_downscale)),
            )
        })
}
