//! Running volume renders and training statements: loading data,
//! checkpoints (refused when from another run), reports and outputs.

use std::io;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3A;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::material::Material;
use sdfl_stdlib::num::V3;
use sdfl_stdlib::shape::Fixed;
use sdfl_stdlib::value::{Dataset, Field, Output, Sampler, SdfField, TrainJob, VolumeJob};
use sdfl_stdlib::OutputKind;
use sdfl_stdlib::RenderJob;
use serde::Serialize;

use crate::data::export::DatasetWriter;
use crate::data::view::check_finite;
use crate::data::view_image::ViewImage;
use crate::data::DataNeeds;
use crate::metrics;
use crate::neural::field::NerfObjective;
use crate::output::{to_u8, write_png, Written, WrittenKind};
use crate::render::{render_view, view_path, Gifs, Needs, ViewScenes};
use crate::sdf::{LowerOptions, Lowered};
use crate::train::checkpoint::{Checkpoint, Fnv};
use crate::train::{Objective, Run, TrainError, TrainModel, TrainSetup, TrainView};
use crate::volume::figures;
use crate::volume::render::{render_field_image_with, DensityModel};
use crate::volume::{ImageSize, Stratified};

fn invalid(e: impl std::fmt::Display) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, e.to_string())
}

fn stratified(s: &Sampler) -> io::Result<Stratified> {
    Stratified::new(s.samples, s.near as f32, s.far as f32).map_err(invalid)
}

/// A field's density at its arguments' values.
fn density_model(f: &SdfField, sampler: &Sampler) -> DensityModel {
    DensityModel {
        kind: f.density,
        alpha: f.alpha.value as f32,
        beta: f.beta.value as f32,
        last_interval: sampler.last_interval,
    }
}

/// A field lowered for rendering: the culled SDF evaluator and the colour.
struct LoweredField {
    sdf: Lowered,
    color: Material,
}

impl LoweredField {
    fn new(field: &SdfField) -> Self {
        LoweredField {
            sdf: Lowered::new(&field.shape, LowerOptions::point_queries()),
            color: (*field.color).clone(),
        }
    }

    #[inline]
    fn eval(&self, p: [f32; 3]) -> (f32, [f32; 3]) {
        let pv = Vec3A::from(p);
        let (d, id) = self.sdf.root.dist_id(pv);
        let info = self.sdf.prims.get(id as usize);
        let material = info
            .and_then(|i| i.material.as_deref())
            .unwrap_or(&self.color);
        let c = info.map_or(V3::splat(0.0), |i| V3::lit(i.center.to_array()));
        // Fields refuse materials that need normals (painted ones too).
        let rgb = material
            .unlit_color(V3::from_array(p), c, &Fixed)
            .unwrap_or(V3::splat(0.5));
        (d, rgb.to_array())
    }
}

/// A field to render: point → (signed distance, colour).
pub type FieldFn<'a> = &'a (dyn Fn([f32; 3]) -> (f32, [f32; 3]) + Sync);

/// Renders one view of a field: colour and, when asked, depth per pixel.
pub type ViewFn<'a> =
    &'a (dyn Fn(&Camera, (u32, u32), bool) -> io::Result<(Vec<[f32; 3]>, Vec<f32>)> + Sync);

/// Renders one camera's view at a size (`true`: with depth): colours and
/// depths, row by row.
type ViewRenderer<'a> =
    Box<dyn Fn(&Camera, (u32, u32), bool) -> io::Result<(Vec<[f32; 3]>, Vec<f32>)> + Sync + 'a>;

/// A field as it is rendered from its file's values (a NeRF from its
/// initial weights).
fn field_view<'a>(field: &'a Field, sampler: &'a Sampler) -> io::Result<ViewRenderer<'a>> {
    let strat = stratified(sampler)?;
    Ok(match field {
        // The language refuses to render these; say so if one gets here.
        Field::NeuralSdf(_) | Field::NeuralSurface(_) => {
            return Err(invalid("a neural SDF cannot be rendered yet"));
        }
        Field::Sdf(f) => {
            let lowered = LoweredField::new(f);
            let model = density_model(f, sampler);
            Box::new(move |cam: &Camera, wh, want_depth| {
                render_field(&|p| lowered.eval(p), model, &strat, cam, wh, want_depth)
            })
        }
        Field::Nerf(n) => {
            let model = NerfObjective::new(n, sampler).map_err(invalid)?;
            let params = model.initial();
            Box::new(move |cam: &Camera, wh, _| {
                nerf_view(&model, &params, &strat, sampler, cam, wh)
            })
        }
    })
}

fn nerf_view(
    model: &NerfObjective,
    params: &[f32],
    strat: &Stratified,
    sampler: &Sampler,
    cam: &Camera,
    (w, h): (u32, u32),
) -> io::Result<(Vec<[f32; 3]>, Vec<f32>)> {
    let size = ImageSize {
        width: w,
        height: h,
    };
    let v = model
        .render_view(params, strat, sampler.last_interval, cam, size)
        .map_err(invalid)?;
    Ok((v.colour, v.depth))
}

/// Colour (and depth) of one view of a field.
fn render_field(
    field: FieldFn,
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
    let img =
        render_field_image_with(field, model, sampler, cam, size, want_depth).map_err(invalid)?;
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
    /// The statement's name.
    pub name: String,
    /// Views rendered.
    pub views: usize,
    /// Samples per ray.
    pub samples_per_ray: usize,
    /// The files written.
    pub written: Vec<Written>,
    /// (stage, seconds)
    pub stages: Vec<(String, f64)>,
}

/// Render a field from each camera and write the outputs.
#[allow(clippy::too_many_arguments)]
pub fn write_volume_outputs(
    name: &str,
    render: ViewFn,
    cameras: &[Camera],
    (w, h): (u32, u32),
    sampler: &Sampler,
    outputs: &[Output],
    out_dir: &Path,
    progress: &(dyn Fn(u64) + Sync),
) -> io::Result<VolumeReport> {
    let strat = stratified(sampler)?;
    let mut written = Vec::new();
    let mut gifs = Gifs::open(outputs, out_dir)?;
    let mut datasets: Vec<DatasetWriter> = outputs
        .iter()
        .filter_map(|o| DatasetWriter::for_output(out_dir, o, (w, h), cameras.len()))
        .collect();
    let wants_depth = outputs
        .iter()
        .any(|o| matches!(o.kind, OutputKind::Depth | OutputKind::DepthGif { .. }));
    let needs_render = outputs.iter().any(|o| {
        matches!(
            o.kind,
            OutputKind::Image
                | OutputKind::Gif { .. }
                | OutputKind::Video { .. }
                | OutputKind::DepthGif { .. }
                | OutputKind::Depth
                | OutputKind::Dataset { .. }
        )
    });
    let (mut render_s, mut encode_s) = (0.0, 0.0);
    for (k, cam) in cameras.iter().enumerate() {
        let t = Instant::now();
        let (colour, depth) = if needs_render {
            render(cam, (w, h), wants_depth)?
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
                | OutputKind::Video { .. }
                | OutputKind::DepthGif { .. }
                | OutputKind::Dataset { .. }
                | OutputKind::LossCurve
                | OutputKind::PsnrCurve
                | OutputKind::Comparison
                | OutputKind::Normals
                | OutputKind::Mask
                // Written by the job, which knows the field's distance.
                | OutputKind::Mesh { .. }
                | OutputKind::GeometryGif { .. }
                // Written by `export::write` from the field's density.
                | OutputKind::DensityMesh { .. }
                | OutputKind::PointCloud { .. }
                | OutputKind::RawDepth { .. }
                | OutputKind::DepthMap { .. } => continue,
                OutputKind::Image => (WrittenKind::Image, rgb8(&colour), (w, h)),
                OutputKind::Depth => (WrittenKind::Depth, crate::render::depth_image(&depth), (w, h)),
                OutputKind::Grid => (WrittenKind::GridImage, figures::xy_grid_image(w, h), (w, h)),
                OutputKind::Rays => (WrittenKind::RaysImage, figures::rays_image(cam, w, h), (w, h)),
                OutputKind::SamplePoints => {
                    let stride = (w.max(h) / 16).max(1);
                    // A chart needs room for its text: twice the image's side.
                    let side = w.max(h).saturating_mul(2).clamp(256, 1024);
                    (
                        WrittenKind::SamplePoints,
                        figures::sample_points_image(cam, &strat, w, h, stride, side, side),
                        (side, side),
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
                mesh: None,
                warning: None,
            });
        }
        if !gifs.is_empty() {
            let depth = gifs
                .wants_depth()
                .then(|| crate::render::depth_image(&depth));
            gifs.push(w, h, Some(&rgb8(&colour)), depth.as_deref())?;
        }
        // Volumes have no hit mask: their views are written opaque.
        for d in &mut datasets {
            written.push(d.push(k, cam, &rgb8(&colour), None)?);
        }
        encode_s += t.elapsed().as_secs_f64();
    }
    written.extend(gifs.finish(w, h)?);
    for d in datasets {
        written.push(d.finish()?);
    }
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

/// Renders a volume `render` statement's views and writes its outputs into
/// `out_dir` (at `size` when `--size` overrides it); `progress` counts views.
pub fn run_volume_job(
    job: &VolumeJob,
    out_dir: &Path,
    size: Option<(u32, u32)>,
    progress: &(dyn Fn(u64) + Sync),
) -> io::Result<VolumeReport> {
    let wh = size.unwrap_or((job.width, job.height));
    let render = field_view(&job.field, &job.sampler)?;
    let mut report = write_volume_outputs(
        &job.name,
        &*render,
        &job.cameras,
        wh,
        &job.sampler,
        &job.outputs,
        out_dir,
        progress,
    )?;
    if job.outputs.iter().any(|o| o.kind.field_export()) {
        let t = Instant::now();
        let ray_views: Vec<(Camera, ImageSize)> = job
            .cameras
            .iter()
            .map(|c| {
                (
                    *c,
                    ImageSize {
                        width: wh.0,
                        height: wh.1,
                    },
                )
            })
            .collect();
        let cx = crate::export::write::ExportContext {
            out_dir,
            sampler: &job.sampler,
            cameras: &job.cameras,
            size: wh,
            ray_views: &ray_views,
            auto_region: job.field.export_region(),
            object_region: job.field.object_region(),
            seed: 0,
            to_data: glam::DAffine3::IDENTITY,
            status: &|_| {},
            ray_ends: None,
        };
        let written = match &*job.field {
            Field::Sdf(f) => {
                let lowered = LoweredField::new(f);
                let field = crate::export::Analytic {
                    field: |p: [f32; 3]| lowered.eval(p),
                    model: density_model(f, &job.sampler),
                };
                crate::export::write::write_field_exports(&field, &job.outputs, &cx)?
            }
            Field::Nerf(n) => {
                let model = NerfObjective::new(n, &job.sampler).map_err(invalid)?;
                let params = model.initial();
                let net = model.fine.as_ref().map_or(&model.net, |(f, _)| f);
                let field = crate::neural::nerf::NerfField {
                    net,
                    params: &params,
                };
                crate::export::write::write_field_exports(&field, &job.outputs, &cx)?
            }
            Field::NeuralSdf(_) | Field::NeuralSurface(_) => {
                return Err(invalid("a neural SDF has no density to export"));
            }
        };
        report.written.extend(written);
        report
            .stages
            .push(("field exports".into(), t.elapsed().as_secs_f64()));
    }
    let meshes: Vec<&Output> = job
        .outputs
        .iter()
        .filter(|o| matches!(o.kind, OutputKind::Mesh { .. }))
        .collect();
    if !meshes.is_empty() {
        let t = Instant::now();
        // Evaluation allows meshes of analytic fields only.
        let Field::Sdf(f) = &*job.field else {
            return Err(invalid("only a distance field has a surface to mesh"));
        };
        let sdf = Lowered::new(&f.shape, LowerOptions::point_queries());
        let distance = |p: &[[f32; 3]], out: &mut [f32]| {
            for (p, o) in p.iter().zip(out) {
                *o = sdf.dist(Vec3A::from(*p));
            }
        };
        let bounds = f
            .shape
            .bounds()
            .map(|b| (b.min.to_array(), b.max.to_array()));
        let field = crate::mesh::Lipschitz(&distance, sdf.lipschitz);
        for o in meshes {
            report
                .written
                .push(crate::mesh::write_mesh(out_dir, o, &field, bounds)?.0);
        }
        report
            .stages
            .push(("mesh".into(), t.elapsed().as_secs_f64()));
    }
    Ok(report)
}

fn load_image(path: &Path) -> io::Result<ViewImage> {
    crate::data::image::read_rgb_image(path).map(ViewImage::from)
}

/// A data set's views: those to train on and those held out for testing.
#[derive(Debug, Clone)]
pub struct Views {
    /// Views trained on.
    pub train: Vec<TrainView>,
    /// Views held out for testing.
    pub test: Vec<TrainView>,
    /// A point cloud's points (no views then).
    pub points: Vec<[f32; 3]>,
    /// All of the file's points in the same frame (`points` may keep only
    /// every n-th): what a trained surface is measured against.
    pub all_points: Vec<[f32; 3]>,
    /// A capture's normalisation (data frame → scene frame) and the lines
    /// that report it; exports map back with `SceneFrame::to_data`.
    pub scene_frame: Option<crate::data::normalize::SceneFrame>,
    /// Lines for people about the data as read (a capture's
    /// normalisation, a warning about its alpha), for the run's report.
    pub scene_report: Vec<String>,
    /// A forward-facing capture's camera for NDC (LLFF).
    pub forward_facing: Option<crate::data::format::ForwardFacing>,
    /// The mean a point cloud's points were moved by (`center: true`):
    /// the model sees `p − mean`. Exports stay in that centred frame (as
    /// the assignment's meshes are); checkpoints record it.
    pub points_mean: Option<[f64; 3]>,
}

/// The views of a data set: read from files (relative to `base`),
/// volume-rendered, sphere-traced (exactly as `render` draws them) or read
/// from a NeRF-synthetic data set; split into training and test views.
/// Every pixel must be a finite colour; the first that is not is named.
/// Coverage is read from no image's alpha (see [`load_views_for`]).
pub fn load_views(data: &Dataset, base: &Path) -> io::Result<Views> {
    load_views_for(data, base, DataNeeds::default())
}

/// [`load_views`], reading what `needs` asks beyond colours: each training
/// view's coverage from its image's alpha (a NeRF-synthetic set, a
/// capture) when `silhouette()` trains on it.
pub fn load_views_for(data: &Dataset, base: &Path, needs: DataNeeds) -> io::Result<Views> {
    let views: Vec<(TrainView, String)> = match data {
        Dataset::Points {
            path,
            every,
            center,
        } => return load_points(&base.join(path), *every, *center),
        Dataset::Files { images, cameras } => {
            crate::data::image::check_dataset(images.iter().map(|p| base.join(p)))?;
            images
                .iter()
                .zip(cameras)
                .map(|(p, c)| {
                    let path = base.join(p);
                    Ok((
                        TrainView {
                            camera: *c,
                            image: load_image(&path)?,
                            mask: None,
                            coverage: None,
                        },
                        path.display().to_string(),
                    ))
                })
                .collect::<io::Result<_>>()?
        }
        Dataset::Rendered {
            field,
            cameras,
            width,
            height,
            sampler,
            ..
        } => {
            let render = field_view(field, sampler)?;
            cameras
                .iter()
                .enumerate()
                .map(|(k, c)| {
                    let (colour, _) = render(c, (*width, *height), false)?;
                    let image = ViewImage::rgb32(*width, *height, colour);
                    Ok((
                        TrainView {
                            camera: *c,
                            image,
                            mask: None,
                            coverage: None,
                        },
                        format!("rendered view {k}"),
                    ))
                })
                .collect::<io::Result<_>>()?
        }
        Dataset::Traced { job, .. } => traced_views(job)
            .into_iter()
            .enumerate()
            .map(|(k, v)| (v, format!("traced view {k}")))
            .collect(),
        // Read by their format, whichever it is.
        Dataset::NerfSynthetic { .. } | Dataset::Capture(_) => {
            let read = crate::data::formats::read(data, base, needs)?
                .ok_or_else(|| invalid("no data format reads this data set"))?;
            return Ok(Views {
                train: read.train,
                test: read.test,
                points: Vec::new(),
                all_points: Vec::new(),
                scene_frame: read.frame,
                scene_report: read.report,
                forward_facing: read.forward_facing,
                points_mean: None,
            });
        }
    };
    check_finite(views.iter().map(|(v, origin)| (v, origin.as_str())))?;
    let held = data.test_views();
    let (mut train, mut test) = (Vec::new(), Vec::new());
    for (k, (v, _)) in views.into_iter().enumerate() {
        if held.binary_search(&k).is_ok() {
            test.push(v);
        } else {
            train.push(v);
        }
    }
    Ok(Views {
        train,
        test,
        points: Vec::new(),
        all_points: Vec::new(),
        scene_frame: None,
        scene_report: Vec::new(),
        forward_facing: None,
        points_mean: None,
    })
}

/// A point cloud: every `every`-th point of the file, moved to their mean
/// when `center`.
fn load_points(path: &Path, every: usize, center: bool) -> io::Result<Views> {
    let mut all = crate::data::points::read_points(path)?;
    let mut points: Vec<[f32; 3]> = all.iter().step_by(every.max(1)).copied().collect();
    let mut points_mean = None;
    if center {
        let n = points.len().max(1) as f64;
        let mean = [0, 1, 2].map(|k| points.iter().map(|p| p[k] as f64).sum::<f64>() / n);
        for p in points.iter_mut().chain(&mut all) {
            for k in 0..3 {
                p[k] = (p[k] as f64 - mean[k]) as f32;
            }
        }
        points_mean = Some(mean);
    }
    Ok(Views {
        train: Vec::new(),
        test: Vec::new(),
        points,
        all_points: all,
        scene_frame: None,
        scene_report: Vec::new(),
        forward_facing: None,
        points_mean,
    })
}

/// Every view of a sphere-traced data set: the tracer of `render` with the
/// job's settings, colour quantised to 8 bits as its `image` output writes.
pub fn traced_views(job: &RenderJob) -> Vec<TrainView> {
    let mut scenes = ViewScenes::new(&job.scene, LowerOptions::default(), &job.cameras);
    let needs = Needs {
        color: true,
        depth: false,
        normals: false,
        mask: true,
    };
    job.cameras
        .iter()
        .map(|c| {
            let view = render_view(
                scenes.for_view(c),
                job,
                c,
                (job.width, job.height),
                needs,
                &|_| {},
            );
            let rgb = view.color.expect("colour is asked for");
            let hits = view.mask.expect("the hit mask is asked for");
            TrainView {
                camera: *c,
                // The trace's 8-bit colours, opaque: read as `x / 255`.
                image: ViewImage::rgba8(
                    job.width,
                    job.height,
                    rgb.chunks_exact(3)
                        .map(|p| [p[0], p[1], p[2], 255])
                        .collect(),
                    [0.0; 3],
                ),
                mask: None,
                // Each pixel is its centre's thin ray: hit or missed. Kept
                // whether or not `silhouette()` asks: it comes with the
                // trace, a byte a pixel.
                coverage: Some(hits.iter().map(|&h| if h > 0 { 255 } else { 0 }).collect()),
            }
        })
        .collect()
}

/// Running `train` statements (public for the test suite; the jobs
/// re-export what callers use).
#[doc(hidden)]
pub mod train;

pub(crate) use train::CHECKPOINT_EVERY;

pub use train::{
    checkpoint_path, fingerprint, run_train_job, trained_field, CheckpointStamp, CheckpointedField,
    FieldUnavailable, HeldOut, TrainOptions, TrainReport,
};
