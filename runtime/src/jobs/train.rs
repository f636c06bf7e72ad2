//! Running `train` statements: the objective for the model, checkpoints
//! (refused when from another run), held-out evaluation, reports and the
//! outputs of the trained model.

use super::*;
use crate::neural::distance::NeuralSdfObjective;
use crate::neural::surface::SurfaceObjective;
use crate::output::write_bytes;
use crate::plot::{self, Axis, Chart, Scale, Series};
use sdfl_stdlib::value::ViewPath;

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
    /// Wall-clock seconds of each stage (load data, train, held-out evaluation…).
    pub stages: Vec<(String, f64)>,
    /// What looks wrong with the fit (code `sdfl::warn::diverged`): a loss
    /// that ended far above its lowest, parameters held at their range.
    pub warnings: Vec<String>,
}

pub use crate::train::log::HeldOut;
use crate::train::log::{first_view, History, Observer, TrainEvent, TrainLog};

/// Each held-out view as a row: truth | render | |error|×4.
fn comparison_image(views: &[TrainView], renders: &[Vec<[f32; 3]>]) -> (u32, u32, Vec<u8>) {
    let w = views.iter().map(|v| v.image.width).max().unwrap_or(1);
    let h: u32 = views.iter().map(|v| v.image.height).sum::<u32>().max(1);
    let mut out = vec![0u8; (3 * w * h * 3) as usize];
    let mut y0 = 0;
    for (v, r) in views.iter().zip(renders) {
        let (vw, vh) = (v.image.width, v.image.height);
        for y in 0..vh {
            for x in 0..vw {
                let i = (y * vw + x) as usize;
                let (t, c) = (v.image.pixels[i], r[i]);
                let err = [0, 1, 2].map(|k| (4.0 * (t[k] - c[k]).abs()).min(1.0));
                for (panel, px) in [t, c, err].iter().enumerate() {
                    let o = 3 * (((y0 + y) * 3 * w) + panel as u32 * w + x) as usize;
                    for k in 0..3 {
                        out[o + k] = to_u8(px[k] as f64);
                    }
                }
            }
        }
        y0 += vh;
    }
    (3 * w, h, out)
}

/// Held-out mean PSNR, mean SSIM, and each view's render.
type Evaluation = (f64, f64, Vec<Vec<[f32; 3]>>);

/// How often a checkpoint is written.
const CHECKPOINT_EVERY: usize = 100;

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
        (Field::NeuralSdf(n), _) => {
            let net = crate::neural::distance::sdf_net(n);
            crate::neural::sdf_net::SdfWork::bytes_for(&net, 2 * rays as usize)
                + 24 * net.len as u64
        }
        // The distance network's values and reverse pass at every sample,
        // plus the colour network's activations and the adjoints.
        (Field::NeuralSurface(n), _) => {
            let net = crate::neural::distance::sdf_net(&n.sdf);
            let rows = rays * (samples + n.fine as u64);
            // Fine samples: a distance-only pass over the stratified ones
            // (points, the encoding, two layers' values, the weights).
            let placing = if n.fine > 0 {
                rays * samples * 4 * (net.encoding.width() as u64 + 2 * net.width() as u64 + 16)
            } else {
                0
            };
            crate::neural::sdf_net::SdfWork::bytes_for(&net, rows as usize)
                + rows
                    * 4
                    * (3 * n.color_input() as u64
                        + 3 * n.color_layers as u64 * n.color_width as u64
                        + 24)
                + 24 * (net.len + n.color_multiply_adds()) as u64
                + placing
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

/// The fingerprint of what a run depends on: one hash per
/// [`crate::train::checkpoint::PARTS`] entry (not the step count, so a run can be
/// continued for longer).
pub fn fingerprint(job: &TrainJob, views: &[TrainView]) -> [String; 4] {
    use std::fmt::Write;
    let mut data = Fnv::default();
    for v in views {
        data.str(&format!("{:?}", v.camera))
            .f32s(&[v.image.width as f32, v.image.height as f32]);
        for p in &v.image.pixels {
            data.f32s(p);
        }
    }
    let hash = |value: &dyn std::fmt::Debug| {
        let mut h = Fnv::default();
        let _ = write!(h, "{value:?}");
        h.finish()
    };
    [
        hash(&job.model),
        data.finish(),
        hash(&job.sampler),
        hash(&(job.optimizer, &job.losses, job.rays, job.seed, job.backend)),
    ]
}

/// What a data set read from files holds is known only once it is read (a
/// NeRF-synthetic test split, its images' sizes): its held-out evaluation
/// and its pixels join the statement's budget then, before any step runs.
fn within_budget_once_read(
    job: &TrainJob,
    size: Option<(u32, u32)>,
    views: &[TrainView],
    test_views: &[TrainView],
) -> io::Result<()> {
    use sdfl_stdlib::work::{held_out_cost, train_work, MAX_EVALUATIONS, MAX_MEMORY};
    if matches!(*job.data, Dataset::Rendered { .. } | Dataset::Traced { .. }) {
        // Rendered by sdfl: counted when the file was evaluated.
        return Ok(());
    }
    let pixels = |v: &TrainView| v.image.width as f64 * v.image.height as f64;
    let largest = test_views.iter().map(pixels).fold(0.0, f64::max);
    let held_out = held_out_cost(job, test_views.len(), largest);
    let work = train_work(job, size);
    let total = work.evaluations + held_out.evaluations;
    if total > MAX_EVALUATIONS {
        return Err(invalid(format!(
            "training `{}` would need {total:.1e} SDF evaluations (at most {MAX_EVALUATIONS:.0e}), {:.1e} of them scoring its {} held-out views: score less often (`eval_every`), with fewer views or samples",
            job.name,
            held_out.evaluations,
            test_views.len()
        )));
    }
    // Pixels as f32 colours, as read.
    let data: f64 = views.iter().chain(test_views).map(pixels).sum::<f64>() * 12.0;
    let memory = work.memory + data + held_out.memory;
    if memory > MAX_MEMORY {
        return Err(invalid(format!(
            "training `{}` would hold about {:.1} GB ({:.1} GB of it the data set's {} views): use fewer or smaller views",
            job.name,
            memory / 1e9,
            data / 1e9,
            views.len() + test_views.len()
        )));
    }
    Ok(())
}

/// Options of a training run that are not in the file.
#[derive(Debug, Clone, Copy, Default)]
pub struct TrainOptions {
    /// Start over instead of resuming an existing checkpoint.
    pub restart: bool,
}

/// A NeRF in NDC (`unbounded: ndc()`) takes its camera from the
/// forward-facing capture just read: the job with it filled in, `None`
/// when the model is not one.
fn with_ndc_frame(
    job: &TrainJob,
    forward_facing: Option<crate::data::capture::ForwardFacing>,
    status: &dyn Fn(&str),
) -> io::Result<Option<TrainJob>> {
    use sdfl_stdlib::value::Unbounded;
    let Field::Nerf(n) = &*job.model else {
        return Ok(None);
    };
    if n.unbounded != Some(Unbounded::Ndc(None)) {
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
    let wh = size.unwrap_or((job.width, job.height));
    let mut written = Vec::new();
    let mut stages = Vec::new();
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

    let t = Instant::now();
    let Views {
        train: views,
        test: test_views,
        points,
        all_points,
        scene_report,
        scene_frame,
        forward_facing,
    } = load_views(&job.data, base).map_err(|e| crate::data::at_argument(job.data_span, e))?;
    for line in &scene_report {
        status(line);
    }
    let resolved;
    let job = match with_ndc_frame(job, forward_facing, &status)? {
        Some(j) => {
            resolved = j;
            &resolved
        }
        None => job,
    };
    stages.push(("load data".to_string(), t.elapsed().as_secs_f64()));
    within_budget_once_read(job, size, &views, &test_views)?;
    // Data read from files may hold no views out (a capture whose split
    // lists name none): say so now, not after training.
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
    // The before/after outputs' cameras: the statement's, or a path made
    // from the training cameras now that they are read.
    let out_views: Vec<Camera> = match job.view_path {
        None => job.views.clone(),
        Some(ViewPath::TrainingLoop { frames, keyframes }) => {
            let train_cams: Vec<Camera> = views.iter().map(|v| v.camera).collect();
            sdfl_stdlib::builtins::paths::camera_loop(&train_cams, frames, keyframes).map_err(
                |e| {
                    invalid(format!(
                        "training `{}`: no loop through its training cameras: {e}",
                        job.name
                    ))
                },
            )?
        }
    };

    // The analytic model outlives the run that borrows it.
    let analytic = job.model.as_sdf().map(TrainModel::new);
    // A second copy of a neural model, for rendering; its state (an
    // occupancy grid) is copied from the run's before each use.
    let nerf_model = match &*job.model {
        Field::Nerf(n) => Some(NerfObjective::new(n, &job.sampler).map_err(invalid)?),
        Field::Sdf(_) | Field::NeuralSdf(_) | Field::NeuralSurface(_) => None,
    };
    let nerf_model = std::sync::Mutex::new(nerf_model);
    let mut setup = TrainSetup::of(job, &views);
    setup.points = &points;
    let steps = match job.epochs {
        Some(e) => e.saturating_mul(setup.steps_per_epoch()),
        None => job.iterations,
    };
    // A copy of a neural surface's model for rendering (it holds buffers).
    let surface_model = match &*job.model {
        Field::NeuralSurface(n) => Some(SurfaceObjective::new(n, &job.losses).with_steps(steps)),
        _ => None,
    };
    let objective: Box<dyn Objective> = match (&*job.model, &analytic) {
        (Field::Nerf(n), _) => Box::new(NerfObjective::new(n, &job.sampler).map_err(invalid)?),
        (Field::Sdf(_), Some(model)) => Box::new(FieldObjective::new(model, job.backend)),
        (Field::NeuralSdf(n), _) => Box::new(NeuralSdfObjective::new(n, &job.losses, job.bounds)),
        (Field::NeuralSurface(n), _) => {
            Box::new(SurfaceObjective::new(n, &job.losses).with_steps(steps))
        }
        (Field::Sdf(_), None) => unreachable!("an analytic field has a model"),
    };
    let fail = |e: TrainError| io::Error::other(format!("training `{}`: {e}", job.name));
    let mut run = Run::of(objective, job.optimizer.lr).map_err(fail)?;
    // Checkpoints name and shape the tensors by role and carry the model.
    let tensors = run.objective.tensors();
    run.describe(crate::train::export_names::Layout::of(&job.model, &tensors));
    // Only a checkpoint needs the fingerprint (it walks the whole model).
    let fp = if job.checkpoint.is_some() {
        fingerprint(job, &views)
    } else {
        Default::default()
    };
    let checkpoint_path: Option<PathBuf> = job.checkpoint.as_ref().map(|c| out_dir.join(c));
    let mut resumed_from = None;
    let mut history = History::default();
    if let Some(cp) = checkpoint_path
        .as_ref()
        .filter(|p| p.exists() && !options.restart)
    {
        let refused = |e: &dyn std::fmt::Display| {
            invalid(format!(
                "checkpoint {}: {e}; run with --restart to start over",
                cp.display()
            ))
        };
        let ck = Checkpoint::read(cp).map_err(|e| {
            // Read errors name the checkpoint already.
            let m = e.to_string();
            let prefix = format!("checkpoint {}: ", cp.display());
            refused(&m.strip_prefix(&prefix).unwrap_or(&m))
        })?;
        ck.check(steps).map_err(|e| refused(&e))?;
        let differs = ck.differences(&fp);
        if !differs.is_empty() {
            return Err(invalid(format!(
                "checkpoint {} is from another run: its {} differ{}; run with --restart to start over, or name another `checkpoint`",
                cp.display(),
                differs.join(", "),
                if differs.len() == 1 { "s" } else { "" }
            )));
        }
        run.resume(&ck).map_err(|e| match e {
            TrainError::Invalid(m) => refused(&m),
            e => refused(&e),
        })?;
        resumed_from = Some(run.step);
        history = ck.history;
    }
    // A checkpoint exists from the start, so a run that diverges at once
    // still leaves a good state to resume from.
    if let (Some(cp), None) = (&checkpoint_path, resumed_from) {
        run.checkpoint(fp.clone()).write(cp)?;
    }

    let strat = stratified(&job.sampler)?;
    // One view of the model at `values`, however it is defined.
    let render_view = |values: &[f32], cam: &Camera, wh: (u32, u32), want_depth: bool| match (
        &*job.model,
        &analytic,
    ) {
        (Field::NeuralSdf(n), _) => {
            let settings = crate::neural::distance::TraceSettings {
                far: job.sampler.far as f32,
                ..Default::default()
            };
            let size = ImageSize {
                width: wh.0,
                height: wh.1,
            };
            let _ = want_depth;
            crate::neural::distance::trace_view(
                &crate::neural::distance::sdf_net(n),
                values,
                cam,
                size,
                settings,
            )
            .map(|v| (v.colour, v.depth))
            .map_err(invalid)
        }
        (Field::NeuralSurface(_), _) => {
            let _ = want_depth;
            let size = ImageSize {
                width: wh.0,
                height: wh.1,
            };
            surface_model
                .as_ref()
                .expect("a surface model")
                .render_view(values, &strat, job.sampler.last_interval, cam, size)
                .map(|v| (v.colour, v.depth))
                .map_err(invalid)
        }
        (Field::Nerf(_), _) => nerf_view(
            nerf_model
                .lock()
                .expect("not poisoned")
                .as_ref()
                .expect("a neural model"),
            values,
            &strat,
            &job.sampler,
            cam,
            wh,
        ),
        (Field::Sdf(f), Some(model)) => {
            let args = model.plain(values);
            let density = DensityModel {
                kind: f.density,
                alpha: args.scalar(&f.alpha).v,
                beta: args.scalar(&f.beta).v,
                last_interval: job.sampler.last_interval,
            };
            let eval = |p: [f32; 3]| {
                let q = V3::from_array(p.map(Dual::constant));
                let (d, c) = field_at(model, &args, q);
                (d.v, [c.x.v, c.y.v, c.z.v])
            };
            render_field(&eval, density, &strat, cam, wh, want_depth)
        }
        (Field::Sdf(_), None) => unreachable!("an analytic field has a model"),
    };
    let render_at = |values: &[f32], outputs: &[Output]| -> io::Result<Vec<Written>> {
        let view = |cam: &Camera, wh: (u32, u32), want_depth: bool| {
            render_view(values, cam, wh, want_depth)
        };
        let r = write_volume_outputs(
            &job.name,
            &view,
            &out_views,
            wh,
            &job.sampler,
            outputs,
            out_dir,
            &|_| {},
        )?;
        Ok(r.written)
    };
    // The `mesh` outputs among `outputs` of the model at `values`.
    let write_meshes =
        |values: &[f32], outputs: &[Output]| -> io::Result<Vec<(Written, crate::mesh::Mesh)>> {
            let meshes: Vec<&Output> = outputs
                .iter()
                .filter(|o| matches!(o.kind, OutputKind::Mesh { .. }))
                .collect();
            if meshes.is_empty() {
                return Ok(Vec::new());
            }
            let write = |field: &dyn crate::mesh::DistanceField, auto| {
                meshes
                    .iter()
                    .map(|o| crate::mesh::write_mesh(out_dir, o, field, auto))
                    .collect::<io::Result<Vec<_>>>()
            };
            match (&*job.model, &analytic) {
                (Field::NeuralSdf(n), _) => {
                    let net = crate::neural::distance::sdf_net(n);
                    // Trained with the eikonal term, not bounded: a margin of 2.
                    let field = crate::mesh::Lipschitz(
                        crate::neural::distance::NetDistance {
                            net: &net,
                            params: values,
                        },
                        2.0,
                    );
                    write(&field, Some(mesh_region(&points, job.bounds)))
                }
                (Field::NeuralSurface(n), _) => {
                    let net = crate::neural::distance::sdf_net(&n.sdf);
                    let field = crate::mesh::Lipschitz(
                        crate::neural::distance::NetDistance {
                            net: &net,
                            params: &values[..net.len],
                        },
                        2.0,
                    );
                    write(&field, Some(mesh_region(&[], job.bounds)))
                }
                (Field::Sdf(f), Some(model)) => {
                    let args = model.plain(values);
                    let field = |p: &[[f32; 3]], out: &mut [f32]| {
                        for (p, o) in p.iter().zip(out) {
                            let q = V3::from_array(p.map(Dual::constant));
                            *o = field_at(model, &args, q).0.v;
                        }
                    };
                    // The starting bounds, grown: the fit moves the shape.
                    let auto = f.shape.bounds().map(|b| {
                        let b = b.expand(0.5 * (b.max - b.min).max_element());
                        (b.min.to_array(), b.max.to_array())
                    });
                    write(&field, auto)
                }
                _ => Err(invalid("only a distance field has a surface to mesh")),
            }
        };
    // Field exports (density meshes, point clouds, depth with opacity) of
    // the model at `values`: rays of the training views for point clouds.
    let ray_views: Vec<(Camera, ImageSize)> = views
        .iter()
        .map(|v| {
            (
                v.camera,
                ImageSize {
                    width: v.image.width,
                    height: v.image.height,
                },
            )
        })
        .collect();
    let write_exports = |values: &[f32], outputs: &[Output]| -> io::Result<Vec<Written>> {
        if !outputs.iter().any(|o| o.kind.field_export()) {
            return Ok(Vec::new());
        }
        let cx = crate::export::write::ExportContext {
            out_dir,
            sampler: &job.sampler,
            cameras: &out_views,
            size: wh,
            ray_views: &ray_views,
            auto_region: export_region(job),
            seed: job.seed,
            // Meshes and points in the data's own frame (its file's), not
            // the normalised one training ran in.
            to_data: scene_frame
                .as_ref()
                .map_or(glam::DAffine3::IDENTITY, |f| f.to_data_affine()),
        };
        match (&*job.model, &analytic) {
            (Field::Nerf(_), _) => {
                let guard = nerf_model.lock().expect("not poisoned");
                let m = guard.as_ref().expect("a neural model");
                // The network that renders: the fine one where there is one.
                let net = m.fine.as_ref().map_or(&m.net, |(f, _)| f);
                let field = crate::export::NerfField {
                    net,
                    params: values,
                };
                crate::export::write::write_field_exports(&field, outputs, &cx)
            }
            (Field::Sdf(f), Some(model)) => {
                let args = model.plain(values);
                let field = crate::export::Analytic {
                    field: |p: [f32; 3]| {
                        let q = V3::from_array(p.map(Dual::constant));
                        let (d, c) = field_at(model, &args, q);
                        (d.v, [c.x.v, c.y.v, c.z.v])
                    },
                    model: DensityModel {
                        kind: f.density,
                        alpha: args.scalar(&f.alpha).v,
                        beta: args.scalar(&f.beta).v,
                        last_interval: job.sampler.last_interval,
                    },
                };
                crate::export::write::write_field_exports(&field, outputs, &cx)
            }
            _ => Err(invalid("only a radiance field has a density to export")),
        }
    };
    // The held-out views rendered at `values`, with their mean PSNR and SSIM.
    let evaluate = |values: &[f32]| -> io::Result<Evaluation> {
        let (mut psnr, mut ssim, mut renders) = (0.0, 0.0, Vec::new());
        for v in &test_views {
            let (w, h) = (v.image.width, v.image.height);
            let (colour, _) = render_view(values, &v.camera, (w, h), false)?;
            // Masked pixels are not scored: left out of PSNR, and the
            // render's own colour in the target for SSIM's windows.
            let target: std::borrow::Cow<[[f32; 3]]> = match &v.mask {
                None => (&v.image.pixels[..]).into(),
                Some(m) => v
                    .image
                    .pixels
                    .iter()
                    .zip(&colour)
                    .zip(m.iter())
                    .map(|((t, c), keep)| if *keep { *t } else { *c })
                    .collect::<Vec<_>>()
                    .into(),
            };
            psnr += match &v.mask {
                None => metrics::psnr(&colour, &target),
                Some(m) => {
                    let kept = |img: &[[f32; 3]]| -> Vec<[f32; 3]> {
                        img.iter()
                            .zip(m.iter())
                            .filter(|(_, k)| **k)
                            .map(|(p, _)| *p)
                            .collect()
                    };
                    metrics::psnr(&kept(&colour), &kept(&target))
                }
            };
            ssim += metrics::ssim(&colour, &target, w as usize, h as usize);
            renders.push(colour);
        }
        let n = test_views.len().max(1) as f64;
        Ok((psnr / n, ssim / n, renders))
    };
    // The rendering copy takes the run's state (an occupancy grid).
    let sync = |state: Vec<(String, Vec<f32>)>| -> io::Result<()> {
        match nerf_model.lock().expect("not poisoned").as_mut() {
            Some(m) => m.restore_state(&state).map_err(invalid),
            None => Ok(()),
        }
    };
    if !job.before.is_empty() {
        sync(run.objective.state())?;
        written.extend(render_at(&run.values(), &job.before)?);
        written.extend(
            write_meshes(&run.values(), &job.before)?
                .into_iter()
                .map(|m| m.0),
        );
        written.extend(write_geometry_gifs(
            job,
            &out_views,
            &job.before,
            &run.values(),
            wh,
            out_dir,
        )?);
        written.extend(write_exports(&run.values(), &job.before)?);
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
    let mut last_good = run.checkpoint(fp.clone());
    let mut io_error = None;
    // Seconds spent evaluating, left out of the training time.
    let mut eval_s = 0.0;
    // A signal stops training after a step, with a checkpoint of it.
    let graceful = crate::interrupt::Graceful::begin();
    let result = run.run_to(&setup, steps, |r, loss| {
        log.step(r.step, loss);
        if let Some(signal) = crate::interrupt::stop_requested() {
            let kept = match &checkpoint_path {
                Some(cp) => match r
                    .checkpoint(fp.clone())
                    .with_history(log.history())
                    .write(cp)
                {
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
        if job.eval_every > 0 && !test_views.is_empty() && r.step % job.eval_every == 0 {
            let te = Instant::now();
            match sync(r.objective.state()).and_then(|_| evaluate(&r.values())) {
                Ok((psnr, ssim, renders)) => {
                    let took = te.elapsed().as_secs_f64();
                    log.evaluated(r.step, psnr, ssim, took, first_view(&test_views, &renders));
                }
                Err(e) => {
                    io_error = Some(e);
                    return ControlFlow::Break(());
                }
            }
            eval_s += te.elapsed().as_secs_f64();
        }
        if r.step % 10 == 0 {
            // The same names as the report, the JSON and the checkpoint.
            let mut line = format!("{} loss {loss:.3e}", job.name);
            if let Some(h) = log.held_out().last() {
                line += &format!("  held-out PSNR {:.2} dB (step {})", h.psnr, h.step);
            }
            let shown = if analytic.is_some() { 4 } else { 0 };
            for (name, v) in r.named_values().iter().take(shown) {
                let v: Vec<String> = v.iter().map(|x| format!("{x:.3}")).collect();
                line += &format!("  {name} {}", v.join(","));
            }
            observer(&TrainEvent::Status(&line));
        }
        if let Some(path) = checkpoint_path
            .as_ref()
            .filter(|_| r.step % CHECKPOINT_EVERY == 0)
        {
            last_good = r.checkpoint(fp.clone()).with_history(log.history());
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
        let kept = checkpoint_path
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
    if let Some(cp) = &checkpoint_path {
        run.checkpoint(fp.clone())
            .with_history(log.history())
            .write(cp)?;
    }

    let t = Instant::now();
    sync(run.objective.state())?;
    let volume_outputs: Vec<Output> = job
        .after
        .iter()
        .filter(|o| {
            !matches!(
                o.kind,
                OutputKind::LossCurve | OutputKind::Mesh { .. } | OutputKind::GeometryGif { .. }
            ) && !o.kind.field_export()
        })
        .cloned()
        .collect();
    if !volume_outputs.is_empty() {
        written.extend(render_at(&run.values(), &volume_outputs)?);
    }
    written.extend(write_geometry_gifs(
        job,
        &out_views,
        &job.after,
        &run.values(),
        wh,
        out_dir,
    )?);
    written.extend(write_exports(&run.values(), &job.after)?);
    let mut mesh_fit = None;
    for (w, mesh) in write_meshes(&run.values(), &job.after)? {
        // The first mesh against the data's points, or against the true
        // surface where sdfl rendered the data itself.
        if mesh_fit.is_none() {
            use crate::neural::distance::{mesh_fit as fit, Reference};
            mesh_fit = if all_points.is_empty() {
                true_surface(&job.data)
                    .map(|t| fit(&mesh, Reference::Surface(&t), "true surface", job.seed))
            } else {
                Some(fit(&mesh, Reference::Points(&all_points), "data", job.seed))
            };
        }
        written.push(w);
    }
    for o in job.after.iter().filter(|o| o.kind == OutputKind::LossCurve) {
        let pts = run
            .losses
            .iter()
            .enumerate()
            .map(|(i, l)| ((i + 1) as f64, *l as f64));
        let chart = Chart {
            title: format!("Training loss of `{}`", job.name),
            x: Axis::new("step").scale(Scale::Linear),
            y: Axis::new(loss_title(&job.losses)),
            series: vec![Series::new("loss", pts)],
        };
        let (pw, ph) = (640, 400);
        write_bytes(
            &out_dir.join(&o.path),
            &plot::render(&chart, pw, ph)?.png()?,
        )?;
        written.push(Written {
            path: o.path.clone(),
            kind: "loss_curve",
            width: pw,
            height: ph,
            frames: 1,
            mesh: None,
        });
    }
    if !test_views.is_empty() {
        let values = run.values();
        let (psnr, ssim, renders) = evaluate(&values)?;
        log.evaluated(run.step, psnr, ssim, 0.0, first_view(&test_views, &renders));
        let held_out = log.held_out();
        for o in &job.after {
            let (pw, ph) = match o.kind {
                OutputKind::PsnrCurve => {
                    let chart = Chart {
                        title: format!("Held-out PSNR of `{}` during training", job.name),
                        x: Axis::new("training time (s)").scale(Scale::Linear),
                        y: Axis::new(format!("PSNR on {} held-out views (dB)", test_views.len()))
                            .scale(Scale::Linear),
                        series: vec![Series::labelled(
                            "held-out PSNR",
                            held_out
                                .iter()
                                .map(|h| (h.seconds, h.psnr, format!("step {}", h.step))),
                        )],
                    };
                    let plot = plot::render(&chart, 640, 400)?;
                    write_bytes(&out_dir.join(&o.path), &plot.png()?)?;
                    (plot.width, plot.height)
                }
                OutputKind::Comparison => {
                    let (pw, ph, rgb) = comparison_image(&test_views, &renders);
                    write_png(&out_dir.join(&o.path), pw, ph, &rgb)?;
                    (pw, ph)
                }
                _ => continue,
            };
            written.push(Written {
                path: o.path.clone(),
                kind: sdfl_stdlib::outputs::kind_name(&o.kind),
                width: pw,
                height: ph,
                frames: 1,
                mesh: None,
            });
        }
    }
    let held_out = log.finish()?;
    let fit = match &*job.model {
        Field::NeuralSdf(n) => Some(crate::neural::distance::fit(
            &crate::neural::distance::sdf_net(n),
            &run.values(),
            &points,
            job.bounds as f32,
            job.seed,
        )),
        _ => None,
    };
    stages.push(("outputs".to_string(), t.elapsed().as_secs_f64()));
    let steps_run = (run.step - done_before).max(1);
    // Parameters the projection holds at an edge they did not start at.
    let at_bounds: Vec<String> = analytic
        .as_ref()
        .map(|model| {
            let values = run.values();
            let start = model.initial_values();
            model
                .params
                .iter()
                .filter(|p| {
                    let (lo, hi) = p.bound.limits();
                    (p.offset..p.offset + p.len).any(|i| {
                        let (v, s) = (values[i] as f64, start[i]);
                        [lo, hi]
                            .iter()
                            .any(|&b| b.is_finite() && v == b as f32 as f64 && s != b)
                    })
                })
                .map(|p| p.name.clone())
                .collect()
        })
        .unwrap_or_default();
    let warnings = crate::train::trainer::fit_warnings(&run.losses, &at_bounds);
    Ok(TrainReport {
        scene_frame,
        name: job.name.clone(),
        iterations: run.step,
        resumed_from,
        final_loss: run.losses.last().copied().unwrap_or(f32::NAN),
        seconds_per_step: train_s / steps_run as f64,
        params: if analytic.is_some() {
            run.named_values()
        } else {
            // A neural surface's trained β, by its value.
            run.named_values()
                .into_iter()
                .filter(|(name, _)| name == "log_beta")
                .map(|(_, v)| {
                    let rate = crate::neural::surface::BETA_RATE;
                    (
                        "beta".to_string(),
                        v.iter().map(|x| (rate * x).exp()).collect(),
                    )
                })
                .collect()
        },
        network_weights: analytic.is_none().then(|| run.values().len()),
        held_out,
        fit,
        mesh_fit,
        written,
        stages,
        warnings,
    })
}

/// The region a `density_mesh` with `bounds: "auto"` covers: the
/// field's own (a hash grid's box); for an analytic field, its starting
/// bounds grown by half their size, as the fit moves the shape.
fn export_region(job: &TrainJob) -> Option<([f64; 3], [f64; 3])> {
    match &*job.model {
        Field::Sdf(f) => f.shape.bounds().map(|b| {
            let b = b.expand(0.5 * (b.max - b.min).max_element());
            (b.min.to_array(), b.max.to_array())
        }),
        field => field.export_region(),
    }
}

/// The `geometry_gif`s of a neural SDF model at `values`: its surface
/// sphere-traced from every view, normals as colours.
fn write_geometry_gifs(
    job: &TrainJob,
    cameras: &[Camera],
    outputs: &[Output],
    values: &[f32],
    (w, h): (u32, u32),
    out_dir: &Path,
) -> io::Result<Vec<Written>> {
    let sdf = match &*job.model {
        Field::NeuralSdf(n) => n,
        Field::NeuralSurface(n) => &n.sdf,
        _ => return Ok(Vec::new()),
    };
    let net = crate::neural::distance::sdf_net(sdf);
    let settings = crate::neural::distance::TraceSettings {
        far: job.sampler.far as f32,
        ..Default::default()
    };
    let mut written = Vec::new();
    for o in outputs {
        let OutputKind::GeometryGif { fps } = o.kind else {
            continue;
        };
        let mut gif = crate::output::GifWriter::create(&out_dir.join(&o.path), fps)?;
        for cam in cameras {
            let size = ImageSize {
                width: w,
                height: h,
            };
            let view =
                crate::neural::distance::trace_view(&net, &values[..net.len], cam, size, settings)
                    .map_err(invalid)?;
            gif.push(w, h, &rgb8(&view.colour))?;
        }
        let frames = gif.frames;
        gif.finish()?;
        written.push(Written {
            path: o.path.clone(),
            kind: "geometry_gif",
            width: w,
            height: h,
            frames,
            mesh: None,
        });
    }
    Ok(written)
}

/// The true surface of data that sdfl rendered from a shape: the shape's
/// mesh at a fine grid; none for data read from files, an unbounded shape
/// or an empty mesh.
fn true_surface(data: &Dataset) -> Option<crate::mesh::Mesh> {
    let shape = match data {
        Dataset::Traced { job, .. } => job.scene.clone(),
        Dataset::Rendered { field, .. } => field.as_sdf()?.shape.clone(),
        _ => return None,
    };
    let b = shape.bounds()?;
    let sdf = Lowered::new(&shape, LowerOptions::point_queries());
    let distance = |p: &[[f32; 3]], out: &mut [f32]| {
        for (p, o) in p.iter().zip(out) {
            *o = sdf.dist(Vec3A::from(*p));
        }
    };
    let grid = crate::mesh::MeshGrid::covering(
        b.min.to_array(),
        b.max.to_array(),
        sdfl_stdlib::work::TRUE_SURFACE_RESOLUTION,
    );
    crate::mesh::surface_nets(
        &distance,
        &grid,
        sdfl_stdlib::work::MAX_MESH_VERTICES,
        &|_| {},
    )
    .ok()
    .filter(|m| !m.triangles.is_empty())
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

/// The loss axis's title: what the loss is made of, e.g. "loss (MSE of
/// pixel colours)" or "loss (|f| + 0.1·eikonal)".
fn loss_title(losses: &[sdfl_stdlib::value::Loss]) -> String {
    use sdfl_stdlib::value::LossKind;
    let term = |k: &LossKind| match k {
        LossKind::Mse => "MSE".to_string(),
        LossKind::Surface => "|f|".to_string(),
        LossKind::Eikonal => "eikonal".to_string(),
        LossKind::Inter { alpha } => format!("exp(−{}·|f|)", short_num(*alpha)),
    };
    match losses {
        [] => "loss".to_string(),
        [l] if l.kind == LossKind::Mse && l.weight == 1.0 => {
            "loss (MSE of pixel colours)".to_string()
        }
        _ => {
            let terms: Vec<String> = losses
                .iter()
                .map(|l| {
                    if l.weight == 1.0 {
                        term(&l.kind)
                    } else {
                        format!("{}·{}", short_num(l.weight), term(&l.kind))
                    }
                })
                .collect();
            format!("loss ({})", terms.join(" + "))
        }
    }
}

/// A number in a title as `sdfl_lang::fmt_num` writes it: `0.1`, `3e-5`.
fn short_num(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-4..1e9).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}
