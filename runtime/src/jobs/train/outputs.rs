//! What a training run writes besides its checkpoint: the statement's
//! outputs of the trained field before and after training (views, GIFs,
//! meshes, field exports, a neural SDF's geometry), its loss curve, and
//! its held-out PSNR curve and comparison.

use super::super::*;
use super::evaluation::{comparison_image, HeldOut};
use crate::neural::distance::MeshFit;
use crate::output::write_bytes;
use crate::plot::{self, Axis, Chart, Scale, Series};
use crate::train::TrainedField;

/// Where and how a training run's outputs are written.
pub(super) struct Outputs<'a> {
    /// The statement.
    pub job: &'a TrainJob,
    /// `--out`.
    pub out_dir: &'a Path,
    /// The views the outputs are rendered from.
    pub cameras: Vec<Camera>,
    /// Their size.
    pub size: (u32, u32),
    /// The training views, whose rays a point cloud casts.
    pub ray_views: Vec<(Camera, ImageSize)>,
    /// From the training frame into the data's own: meshes and points are
    /// written in the frame of the data's file, not the normalised one.
    pub to_data: glam::DAffine3,
    /// Told what is being written (a status line: on a terminal the
    /// bar's, piped a line every few seconds).
    pub observer: &'a crate::train::log::Observer<'a>,
}

impl Outputs<'_> {
    /// Tells the observer `what` is being written.
    fn status(&self, what: &str) {
        let line = format!("{}: {what}", self.job.name);
        (self.observer)(&crate::train::log::TrainEvent::Status(&line));
    }
}

impl Outputs<'_> {
    /// The `before` outputs among `before`, of `field` at its starting
    /// `values`.
    pub fn before(
        &self,
        field: &dyn TrainedField,
        values: &[f32],
        before: &[Output],
    ) -> io::Result<Vec<Written>> {
        let shared = SharedRenders::for_outputs(before);
        let mut written = self.views(field, values, before, &shared)?;
        written.extend(self.meshes(field, values, before)?.into_iter().map(|m| m.0));
        written.extend(self.geometry_gifs(field, values, before)?);
        written.extend(self.exports(field, values, before, &shared)?);
        Ok(written)
    }

    /// The `after` outputs among `after` of the trained `field` at
    /// `values` (but the curves and comparisons, written by their own),
    /// and the first mesh's fit: against `all_points`, the data's, or
    /// against the true surface where sdfl rendered the data itself.
    pub fn after(
        &self,
        field: &dyn TrainedField,
        values: &[f32],
        all_points: &[[f32; 3]],
        after: &[Output],
    ) -> io::Result<(Vec<Written>, Option<MeshFit>)> {
        let views: Vec<Output> = after
            .iter()
            .filter(|o| {
                !matches!(
                    o.kind,
                    OutputKind::LossCurve
                        | OutputKind::Mesh { .. }
                        | OutputKind::GeometryGif { .. }
                ) && !o.kind.field_export()
            })
            .cloned()
            .collect();
        let mut written = Vec::new();
        let shared = SharedRenders::for_outputs(after);
        if !views.is_empty() {
            written.extend(self.views(field, values, &views, &shared)?);
        }
        written.extend(self.geometry_gifs(field, values, after)?);
        written.extend(self.exports(field, values, after, &shared)?);
        let mut mesh_fit = None;
        for (w, mesh) in self.meshes(field, values, after)? {
            if mesh_fit.is_none() {
                use crate::neural::distance::{mesh_fit as fit, Reference};
                let seed = self.job.seed;
                mesh_fit = if all_points.is_empty() {
                    true_surface(&self.job.data)
                        .map(|t| fit(&mesh, Reference::Surface(&t), "true surface", seed))
                } else {
                    Some(fit(&mesh, Reference::Points(all_points), "data", seed))
                };
            }
            written.push(w);
        }
        Ok((written, mesh_fit))
    }

    /// The views, GIFs and data sets among `outputs`.
    fn views(
        &self,
        field: &dyn TrainedField,
        values: &[f32],
        outputs: &[Output],
        shared: &SharedRenders,
    ) -> io::Result<Vec<Written>> {
        let view = |cam: &Camera, (width, height): (u32, u32), want_depth: bool| {
            let size = ImageSize { width, height };
            let v = field
                .render_view(values, cam, size, want_depth || shared.wanted)
                .map_err(invalid)?;
            if (width, height) == self.size {
                if let Some(k) = self.cameras.iter().position(|c| std::ptr::eq(c, cam)) {
                    shared.keep(k, &v);
                }
            }
            Ok((v.colour, v.depth))
        };
        let job = self.job;
        let names: Vec<String> = outputs
            .iter()
            .map(|o| o.path.display().to_string())
            .collect();
        let (done, n) = (std::sync::atomic::AtomicUsize::new(0), self.cameras.len());
        let r = write_volume_outputs(
            &job.name,
            &view,
            &self.cameras,
            self.size,
            &job.sampler,
            outputs,
            self.out_dir,
            &|_| {
                let k = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                self.status(&format!(
                    "rendered view {k} of {n} for {}",
                    names.join(", ")
                ));
            },
        )?;
        Ok(r.written)
    }

    /// The `mesh` outputs among `outputs`, with the meshes written (in the
    /// data's frame, as the field exports).
    fn meshes(
        &self,
        field: &dyn TrainedField,
        values: &[f32],
        outputs: &[Output],
    ) -> io::Result<Vec<(Written, crate::mesh::Mesh)>> {
        let meshes: Vec<&Output> = outputs
            .iter()
            .filter(|o| matches!(o.kind, OutputKind::Mesh { .. }))
            .collect();
        if meshes.is_empty() {
            return Ok(Vec::new());
        }
        let surface = field
            .surface(values)
            .ok_or_else(|| invalid("only a distance field has a surface to mesh"))?;
        meshes
            .iter()
            .map(|o| {
                self.status(&format!("writing {}", o.path.display()));
                let region = field.region();
                crate::mesh::write_mesh_to(self.out_dir, o, &*surface, region, &self.to_data)
            })
            .collect()
    }

    /// The field exports among `outputs` (density meshes, point clouds,
    /// depth with opacity).
    fn exports(
        &self,
        field: &dyn TrainedField,
        values: &[f32],
        outputs: &[Output],
        shared: &SharedRenders,
    ) -> io::Result<Vec<Written>> {
        if !outputs.iter().any(|o| o.kind.field_export()) {
            return Ok(Vec::new());
        }
        let rendered = |cam: &Camera, size: ImageSize| {
            let k = self.cameras.iter().position(|c| std::ptr::eq(c, cam));
            if let Some(ends) = k.and_then(|k| shared.take(k)) {
                return Ok(ends);
            }
            let v = field.render_view(values, cam, size, true)?;
            v.ray_ends()
                .ok_or_else(|| "the render gave no opacity".into())
        };
        let cx = crate::export::write::ExportContext {
            out_dir: self.out_dir,
            sampler: &self.job.sampler,
            cameras: &self.cameras,
            size: self.size,
            ray_views: &self.ray_views,
            auto_region: field.region(),
            object_region: super::field::object_region(self.job, field),
            seed: self.job.seed,
            to_data: self.to_data,
            status: &|what| self.status(what),
            ray_ends: field
                .renders_opacity()
                .then_some(&rendered as &crate::export::write::RayEnds),
        };
        let radiance = field
            .radiance(values)
            .ok_or_else(|| invalid("only a radiance field has a density to export"))?;
        crate::export::write::write_field_exports(&*radiance, outputs, &cx)
    }

    /// The `geometry_gif`s among `outputs`: a distance network's surface
    /// sphere-traced from every view, normals as colours (none for other
    /// fields, which evaluation refuses them for).
    fn geometry_gifs(
        &self,
        field: &dyn TrainedField,
        values: &[f32],
        outputs: &[Output],
    ) -> io::Result<Vec<Written>> {
        let (w, h) = self.size;
        let size = ImageSize {
            width: w,
            height: h,
        };
        let mut written = Vec::new();
        for o in outputs {
            let OutputKind::GeometryGif { fps } = o.kind else {
                continue;
            };
            let mut gif = None;
            for (k, cam) in self.cameras.iter().enumerate() {
                let n = self.cameras.len();
                self.status(&format!(
                    "traced view {} of {n} for {}",
                    k + 1,
                    o.path.display()
                ));
                let Some(view) = field.geometry_view(values, cam, size) else {
                    break;
                };
                let colour = view.map_err(invalid)?;
                let gif = match &mut gif {
                    Some(g) => g,
                    None => gif.insert(crate::output::GifWriter::create(
                        &self.out_dir.join(&o.path),
                        fps,
                    )?),
                };
                gif.push(w, h, &rgb8(&colour))?;
            }
            let Some(gif) = gif else { continue };
            let frames = gif.frames;
            gif.finish()?;
            written.push(Written {
                path: o.path.clone(),
                kind: WrittenKind::GeometryGif,
                width: w,
                height: h,
                frames,
                mesh: None,
                warning: None,
            });
        }
        Ok(written)
    }

    /// The `loss_curve` outputs among `outputs`: `losses` (one a step)
    /// over the steps.
    pub fn loss_curves(&self, losses: &[f32], outputs: &[Output]) -> io::Result<Vec<Written>> {
        let job = self.job;
        let mut written = Vec::new();
        for o in outputs.iter().filter(|o| o.kind == OutputKind::LossCurve) {
            let pts = losses
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
                &self.out_dir.join(&o.path),
                &plot::render(&chart, pw, ph)?.png()?,
            )?;
            written.push(Written {
                path: o.path.clone(),
                kind: WrittenKind::LossCurve,
                width: pw,
                height: ph,
                frames: 1,
                mesh: None,
                warning: None,
            });
        }
        Ok(written)
    }

    /// The held-out outputs among `outputs`: the PSNR curve over
    /// `held_out` and the comparison of `test_views` with their final
    /// `renders`.
    pub fn held_out(
        &self,
        held_out: &[HeldOut],
        test_views: &[TrainView],
        renders: &[Vec<[f32; 3]>],
        outputs: &[Output],
    ) -> io::Result<Vec<Written>> {
        let job = self.job;
        let mut written = Vec::new();
        for o in outputs {
            let path = self.out_dir.join(&o.path);
            let (kind, pw, ph) = match o.kind {
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
                    write_bytes(&path, &plot.png()?)?;
                    (WrittenKind::PsnrCurve, plot.width, plot.height)
                }
                OutputKind::Comparison => {
                    let (pw, ph, rgb) = comparison_image(test_views, renders);
                    write_png(&path, pw, ph, &rgb)?;
                    (WrittenKind::Comparison, pw, ph)
                }
                _ => continue,
            };
            written.push(Written {
                path: o.path.clone(),
                kind,
                width: pw,
                height: ph,
                frames: 1,
                mesh: None,
                warning: None,
            });
        }
        Ok(written)
    }
}

/// A phase's renders kept for its depth outputs, so that each view is
/// rendered once for its view outputs (images, GIFs, video) and its depth
/// exports, while they fit in [`sdfl_stdlib::work::SHARED_RENDER_BYTES`] (past that, a depth
/// export renders its view again).
struct SharedRenders {
    /// Whether the phase has depth exports (else nothing is kept).
    wanted: bool,
    /// Ray ends by view, and their bytes.
    kept: std::sync::Mutex<(
        std::collections::HashMap<usize, Vec<crate::export::RayEnd>>,
        usize,
    )>,
}

impl SharedRenders {
    fn for_outputs(outputs: &[Output]) -> Self {
        let wanted = outputs.iter().any(|o| o.kind.depth_export());
        SharedRenders {
            wanted,
            kept: Default::default(),
        }
    }

    /// Keeps view `k`'s render, if it has opacities and fits.
    fn keep(&self, k: usize, v: &crate::train::field::View) {
        if !self.wanted {
            return;
        }
        let bytes = v.colour.len() * std::mem::size_of::<crate::export::RayEnd>();
        let mut kept = self.kept.lock().unwrap_or_else(|p| p.into_inner());
        if kept.1 + bytes > sdfl_stdlib::work::SHARED_RENDER_BYTES {
            return;
        }
        let Some(ends) = v.ray_ends() else {
            return;
        };
        kept.1 += bytes;
        kept.0.insert(k, ends);
    }

    /// View `k`'s kept render, given up.
    fn take(&self, k: usize) -> Option<Vec<crate::export::RayEnd>> {
        let mut kept = self.kept.lock().unwrap_or_else(|p| p.into_inner());
        let ends = kept.0.remove(&k)?;
        kept.1 -= ends.len() * std::mem::size_of::<crate::export::RayEnd>();
        Some(ends)
    }
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

/// The loss axis's title: what the loss is made of, e.g. "loss (MSE of
/// pixel colours)" or "loss (|f| + 0.1·eikonal)".
fn loss_title(losses: &[sdfl_stdlib::value::Loss]) -> String {
    use sdfl_stdlib::value::LossKind;
    let term = |k: &LossKind| match k {
        LossKind::Mse => "MSE".to_string(),
        LossKind::Surface => "|f|".to_string(),
        LossKind::Eikonal => "eikonal".to_string(),
        LossKind::Inter { alpha } => format!("exp(−{}·|f|)", short_num(*alpha)),
        LossKind::Silhouette => "silhouette BCE".to_string(),
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
