//! Running volume renders and training statements.

use std::io;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3A;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::material::Material;
use sdfl_stdlib::shape::Shape;
use sdfl_stdlib::value::{Dataset, DensityKind, Field, Output, Sampler, TrainJob, VolumeJob};
use sdfl_stdlib::OutputKind;
use serde::{Deserialize, Serialize};

use crate::data::npy::RgbImage;
use crate::output::{to_u8, write_png, Atomic};
use crate::render::{view_path, Gifs, Written};
use crate::sdf::{LowerOptions, Lowered};
use crate::train::box_fit::{fit_box_with, BoxFitConfig, FitBackend, FitView};
use crate::volume::figures;
use crate::volume::render::{render_field_image_with, DensityModel};
use crate::volume::{BoxVolume, ImageSize, Stratified};

fn invalid(e: impl std::fmt::Display) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, e.to_string())
}

fn stratified(s: &Sampler) -> io::Result<Stratified> {
    Stratified::new(s.samples, s.near as f32, s.far as f32).map_err(invalid)
}

fn density_model(f: &Field) -> DensityModel {
    let (alpha, beta) = (f.alpha as f32, f.beta as f32);
    match f.density {
        DensityKind::Opacity => DensityModel::SdfOpacity { alpha, beta },
        DensityKind::VolSdf => DensityModel::VolSdf { alpha, beta },
        DensityKind::Neus => DensityModel::Neus { alpha, beta },
    }
}

/// A field lowered for rendering: the SDF evaluator and the colour rule.
struct LoweredField {
    sdf: Lowered,
    color: Material,
}

impl LoweredField {
    fn new(field: &Field) -> Self {
        LoweredField {
            sdf: Lowered::new(&field.shape, LowerOptions::default()),
            color: (*field.color).clone(),
        }
    }

    #[inline]
    fn eval(&self, p: [f32; 3]) -> (f32, [f32; 3]) {
        let pv = Vec3A::from(p);
        match &self.color {
            // Rainbow needs the centre of the primitive attaining the minimum.
            Material::Rainbow => {
                let (d, id) = self.sdf.root.dist_id(pv);
                let c = self
                    .sdf
                    .prims
                    .get(id as usize)
                    .map_or(Vec3A::ZERO, |i| i.center.as_vec3().into());
                let rgb = (pv - c).abs().clamp(Vec3A::splat(0.02), Vec3A::splat(0.98));
                (d, rgb.to_array())
            }
            Material::Constant(c) => (self.sdf.dist(pv), c.as_vec3().to_array()),
            // Fields reject materials that need normals when evaluated.
            _ => (self.sdf.dist(pv), [0.5; 3]),
        }
    }
}

/// Colour (and depth) of one view of a field.
fn render_field(
    field: &LoweredField,
    model: DensityModel,
    sampler: &Stratified,
    cam: &Camera,
    (w, h): (u32, u32),
    want_depth: bool,
) -> io::Result<(Vec<[f32; 3]>, Vec<f32>)> {
    let size = ImageSize {
        width: w,
        height: h,
    };
    let img = render_field_image_with(|p| field.eval(p), model, sampler, cam, size, want_depth)
        .map_err(invalid)?;
    Ok((img.colour, img.depth))
}

fn rgb8(colour: &[[f32; 3]]) -> Vec<u8> {
    colour
        .iter()
        .flat_map(|c| c.map(|x| to_u8(x as f64)))
        .collect()
}

/// What a volume or training job did.
#[derive(Debug, Clone, Serialize)]
pub struct VolumeReport {
    pub name: String,
    pub views: usize,
    pub samples_per_ray: usize,
    pub written: Vec<Written>,
    pub stages: Vec<(String, f64)>,
}

/// Render a field from each camera and write the outputs.
pub fn write_volume_outputs(
    name: &str,
    field: &Field,
    cameras: &[Camera],
    (w, h): (u32, u32),
    sampler: &Sampler,
    outputs: &[Output],
    out_dir: &Path,
    progress: &(dyn Fn(u64) + Sync),
) -> io::Result<VolumeReport> {
    let lowered = LoweredField::new(field);
    let model = density_model(field);
    let strat = stratified(sampler)?;
    let mut written = Vec::new();
    let mut gifs = Gifs::open(outputs, out_dir)?;
    let wants_depth = outputs.iter().any(|o| o.kind == OutputKind::Depth);
    let needs_render = outputs.iter().any(|o| {
        matches!(
            o.kind,
            OutputKind::Image | OutputKind::Gif { .. } | OutputKind::Depth
        )
    });
    let (mut render_s, mut encode_s) = (0.0, 0.0);
    for (k, cam) in cameras.iter().enumerate() {
        let t = Instant::now();
        let (colour, depth) = if needs_render {
            render_field(&lowered, model, &strat, cam, (w, h), wants_depth)?
        } else {
            (Vec::new(), Vec::new())
        };
        render_s += t.elapsed().as_secs_f64();
        progress(w as u64 * h as u64);
        let t = Instant::now();
        for o in outputs {
            let rel = view_path(&o.path, k, cameras.len());
            // View-independent checks are written once.
            let once = matches!(
                o.kind,
                OutputKind::Grid | OutputKind::Rays | OutputKind::SamplePoints
            );
            if once && k > 0 {
                continue;
            }
            let rel = if once { o.path.clone() } else { rel };
            let (kind, rgb, (pw, ph)) = match o.kind {
                OutputKind::Gif { .. }
                | OutputKind::LossCurve
                | OutputKind::Normals
                | OutputKind::Mask => continue,
                OutputKind::Image => ("image", rgb8(&colour), (w, h)),
                OutputKind::Depth => ("depth", crate::render::depth_image(&depth), (w, h)),
                OutputKind::Grid => ("grid_image", figures::xy_grid_image(w, h), (w, h)),
                OutputKind::Rays => ("rays_image", figures::rays_image(cam, w, h), (w, h)),
                OutputKind::SamplePoints => {
                    let stride = (w.max(h) / 16).max(1);
                    (
                        "sample_points",
                        figures::sample_points_image(cam, &strat, w, h, stride, 256, 256),
                        (256, 256),
                    )
                }
            };
            write_png(&out_dir.join(&rel), pw, ph, &rgb)?;
            written.push(Written {
                path: rel,
                kind,
                width: pw,
                height: ph,
                frames: 1,
            });
        }
        if !gifs.is_empty() {
            gifs.push(w, h, &rgb8(&colour))?;
        }
        encode_s += t.elapsed().as_secs_f64();
    }
    written.extend(gifs.finish(w, h)?);
    Ok(VolumeReport {
        name: name.to_string(),
        views: cameras.len(),
        samples_per_ray: sampler.samples,
        written,
        stages: vec![
            ("volume render".into(), render_s),
            ("encode".into(), encode_s),
        ],
    })
}

pub fn run_volume_job(
    job: &VolumeJob,
    out_dir: &Path,
    size: Option<(u32, u32)>,
    progress: &(dyn Fn(u64) + Sync),
) -> io::Result<VolumeReport> {
    let wh = size.unwrap_or((job.width, job.height));
    write_volume_outputs(
        &job.name,
        &job.field,
        &job.cameras,
        wh,
        &job.sampler,
        &job.outputs,
        out_dir,
        progress,
    )
}

// ------------------------------------------------------------------ training

/// A resumable training state, written atomically as JSON.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Checkpoint {
    pub iteration: usize,
    pub center: [f32; 3],
    pub sides: [f32; 3],
    pub losses: Vec<f32>,
}

impl Checkpoint {
    pub fn write(&self, path: &Path) -> io::Result<()> {
        let mut f = Atomic::create(path)?;
        serde_json::to_writer_pretty(f.writer(), self).map_err(io::Error::other)?;
        f.commit()
    }
    pub fn read(path: &Path) -> io::Result<Checkpoint> {
        crate::data::image::read_checkpoint(path)
    }
}

/// The learned parameters and how training went.
#[derive(Debug, Clone, Serialize)]
pub struct TrainReport {
    pub name: String,
    pub iterations: usize,
    pub resumed_from: Option<usize>,
    pub final_loss: f32,
    pub seconds_per_step: f64,
    /// Learned values by parameter name (`box.center`, `box.size`).
    pub params: Vec<(String, Vec<f32>)>,
    pub written: Vec<Written>,
    pub stages: Vec<(String, f64)>,
}

/// The box a model trains, as (centre, size).
fn model_box(field: &Field) -> io::Result<([f32; 3], [f32; 3])> {
    match &*field.shape {
        Shape::Trainable(inner, _) => match &**inner {
            Shape::Box { center, size } => {
                Ok((center.as_vec3().to_array(), size.as_vec3().to_array()))
            }
            _ => Err(invalid("the model's trainable shape is not a box")),
        },
        _ => Err(invalid("the model has no trainable parameters")),
    }
}

fn with_box(field: &Field, center: [f32; 3], sides: [f32; 3]) -> Field {
    let b = Shape::Box {
        center: glam::Vec3::from(center).as_dvec3(),
        size: glam::Vec3::from(sides).as_dvec3(),
    };
    Field {
        shape: std::sync::Arc::new(b),
        ..field.clone()
    }
}

fn load_image(path: &Path) -> io::Result<RgbImage> {
    crate::data::image::read_rgb_image(path)
}

/// The training views: read from files (relative to `base`) or rendered.
pub fn load_views(data: &Dataset, base: &Path) -> io::Result<Vec<FitView>> {
    match data {
        Dataset::Files { images, cameras } => {
            crate::data::image::check_dataset(images.iter().map(|p| base.join(p)))?;
            images
                .iter()
                .zip(cameras)
                .map(|(p, c)| {
                    Ok(FitView {
                        camera: *c,
                        image: load_image(&base.join(p))?,
                    })
                })
                .collect()
        }
        Dataset::Rendered {
            field,
            cameras,
            width,
            height,
            sampler,
        } => {
            let lowered = LoweredField::new(field);
            let strat = stratified(sampler)?;
            cameras
                .iter()
                .map(|c| {
                    let (colour, _) = render_field(
                        &lowered,
                        density_model(field),
                        &strat,
                        c,
                        (*width, *height),
                        false,
                    )?;
                    Ok(FitView {
                        camera: *c,
                        image: RgbImage {
                            width: *width,
                            height: *height,
                            pixels: colour,
                        },
                    })
                })
                .collect()
        }
    }
}

/// How often a checkpoint is written.
const CHECKPOINT_EVERY: usize = 100;

pub fn run_train_job(
    job: &TrainJob,
    out_dir: &Path,
    base: &Path,
    size: Option<(u32, u32)>,
    progress: &(dyn Fn(u64) + Sync),
    status: &dyn Fn(&str),
) -> io::Result<TrainReport> {
    let wh = size.unwrap_or((job.width, job.height));
    let mut written = Vec::new();
    let mut stages = Vec::new();

    let t = Instant::now();
    let views = load_views(&job.data, base)?;
    stages.push(("load data".to_string(), t.elapsed().as_secs_f64()));

    let (mut center, mut sides) = model_box(&job.model)?;
    let checkpoint_path: Option<PathBuf> = job.checkpoint.as_ref().map(|c| out_dir.join(c));
    let mut losses = Vec::new();
    let mut resumed_from = None;
    if let Some(cp) = checkpoint_path.as_ref().filter(|p| p.exists()) {
        let state = Checkpoint::read(cp)?;
        (center, sides, losses) = (state.center, state.sides, state.losses);
        resumed_from = Some(state.iteration);
    }
    let done = resumed_from.unwrap_or(0).min(job.iterations);
    // A checkpoint exists from the start, so a run that diverges at once
    // still leaves a good state to resume from.
    if let (Some(cp), None) = (&checkpoint_path, resumed_from) {
        Checkpoint {
            iteration: 0,
            center,
            sides,
            losses: Vec::new(),
        }
        .write(cp)?;
    }

    if !job.before.is_empty() {
        let start = with_box(&job.model, center, sides);
        let r = write_volume_outputs(
            &job.name,
            &start,
            &job.views,
            wh,
            &job.sampler,
            &job.before,
            out_dir,
            &|_| {},
        )?;
        written.extend(r.written);
    }

    let cfg = BoxFitConfig {
        start: BoxVolume::new(center, sides, job.model.alpha as f32, job.model.beta as f32)
            .map_err(invalid)?,
        sampler: stratified(&job.sampler)?,
        batch_rays: job.rays,
        lr: job.optimizer.lr
            * job.optimizer.decay.powi(if job.optimizer.decay_every > 0 {
                (done / job.optimizer.decay_every) as i32
            } else {
                0
            }),
        lr_decay: job.optimizer.decay,
        decay_every: job.optimizer.decay_every,
        iterations: job.iterations - done,
        // A different stream after a resume, so batches are not repeated.
        seed: job.seed.wrapping_add(done as u64),
        backend: if job.backend == "dfdx" {
            FitBackend::Dfdx
        } else {
            FitBackend::Fused
        },
    };
    let t = Instant::now();
    let mut last_good = Checkpoint {
        iteration: done,
        center,
        sides,
        losses: losses.clone(),
    };
    let mut diverged = None;
    let mut io_error = None;
    let result = fit_box_with(&views, &cfg, |it, vol, loss| {
        progress(1);
        let iteration = done + it;
        if iteration % 10 == 0 {
            status(&format!("{} loss {loss:.3e}", job.name));
        }
        if !loss.is_finite() || !vol.center.iter().chain(&vol.sides).all(|x| x.is_finite()) {
            diverged = Some(iteration);
            return ControlFlow::Break(());
        }
        last_good.losses.push(loss);
        last_good.iteration = iteration;
        last_good.center = vol.center;
        last_good.sides = vol.sides;
        if let Some(cp) = &checkpoint_path {
            if iteration % CHECKPOINT_EVERY == 0 {
                if let Err(e) = last_good.write(cp) {
                    io_error = Some(e);
                    return ControlFlow::Break(());
                }
            }
        }
        ControlFlow::Continue(())
    });
    let train_s = t.elapsed().as_secs_f64();
    stages.push(("train".to_string(), train_s));
    if let Some(e) = io_error {
        return Err(e);
    }
    let kept = checkpoint_path
        .as_ref()
        .map(|p| format!("; the last good checkpoint is kept at {}", p.display()))
        .unwrap_or_default();
    if let Some(it) = diverged {
        return Err(io::Error::other(format!(
            "training `{}` diverged at iteration {it}: the loss or a parameter is not finite{kept}",
            job.name
        )));
    }
    let result = result
        .map_err(|e| io::Error::other(format!("training `{}` failed: {e}{kept}", job.name)))?;
    if let Some(cp) = &checkpoint_path {
        last_good.write(cp)?;
    }
    let (center, sides) = (result.volume.center, result.volume.sides);
    let all_losses = last_good.losses.clone();

    let t = Instant::now();
    let trained = with_box(&job.model, center, sides);
    let volume_outputs: Vec<Output> = job
        .after
        .iter()
        .filter(|o| o.kind != OutputKind::LossCurve)
        .cloned()
        .collect();
    if !volume_outputs.is_empty() {
        let r = write_volume_outputs(
            &job.name,
            &trained,
            &job.views,
            wh,
            &job.sampler,
            &volume_outputs,
            out_dir,
            &|_| {},
        )?;
        written.extend(r.written);
    }
    for o in job.after.iter().filter(|o| o.kind == OutputKind::LossCurve) {
        let pts: Vec<(f64, f64)> = all_losses
            .iter()
            .enumerate()
            .map(|(i, l)| ((i + 1) as f64, *l as f64))
            .collect();
        let (pw, ph) = (512, 320);
        write_png(
            &out_dir.join(&o.path),
            pw,
            ph,
            &figures::line_plot(pw, ph, &[("loss", &pts)], true),
        )?;
        written.push(Written {
            path: o.path.clone(),
            kind: "loss_curve",
            width: pw,
            height: ph,
            frames: 1,
        });
    }
    stages.push(("outputs".to_string(), t.elapsed().as_secs_f64()));
    let steps = result.iterations.max(1);
    Ok(TrainReport {
        name: job.name.clone(),
        iterations: done + result.iterations,
        resumed_from,
        final_loss: all_losses.last().copied().unwrap_or(f32::NAN),
        seconds_per_step: train_s / steps as f64,
        params: vec![
            ("box.center".into(), center.to_vec()),
            ("box.size".into(), sides.to_vec()),
        ],
        written,
        stages,
    })
}
