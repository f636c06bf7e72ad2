//! The statements: `render` (sphere-traced or volume-rendered) and `train`.

use super::*;
use crate::value::{size_at_aspect, DATA_ASPECT_SHORT_SIDE};

// ------------------------------------------------------------ render block

pub(crate) fn render_sig() -> BlockSig {
    BlockSig {
        kind: "render",
        doc: "Sphere-traces `scene` from each camera and writes the requested outputs.",
        fields: vec![
            req(
                "scene",
                Type::OneOf(vec![SHAPE, FIELD]),
                "a shape (sphere-traced) or a field (volume-rendered)",
            ),
            req(
                "camera",
                Type::OneOf(vec![CAMERA, Type::list(CAMERA)]),
                "a camera or a list of cameras (views)",
            ),
            req(
                "outputs",
                Type::list(OUTPUT),
                "what to write: image, gif, depth, normal_map, mask",
            ),
            opt(
                "material",
                Type::OneOf(vec![MATERIAL, Type::Vec3]),
                "rainbow()",
                "how hit points are coloured",
            ),
            opt(
                "size",
                Type::list(Type::Number),
                "[256, 256]",
                "image width and height in pixels",
            ),
            opt("near", Type::Number, "0", "where rays start (≥ 0)"),
            opt("far", Type::Number, "5", "where rays give up (> near)"),
            opt(
                "iterations",
                Type::Number,
                "64",
                "most sphere-tracing steps per ray",
            ),
            opt(
                "epsilon",
                Type::Number,
                "1e-5",
                "a ray hits when the distance falls below this",
            ),
            opt(
                "hit_tolerance",
                Type::Str,
                "\"pixel\"",
                "\"pixel\": a hit within half a pixel's width (at least `epsilon`), over-relaxed steps, so grazing rays are decided; \"absolute\": within `epsilon`, plain steps (the reference assignment's tracer)",
            ),
            opt(
                "background",
                Type::Vec3,
                "[0, 0, 0]",
                "colour of rays that miss",
            ),
            opt(
                "sampler",
                SAMPLER,
                "stratified()",
                "depth samples along each ray (fields only)",
            ),
            opt(
                "fog",
                Type::OneOf(vec![FOG, Type::Bool]),
                "false",
                "`fog(color, density)`: exponential fog by distance (`false`: none; shapes only)",
            ),
            opt(
                "samples_per_pixel",
                Type::Number,
                "1",
                "rays per pixel whose colours are averaged: a square (1, 4, 9, 16, … 256), an m × m rotated grid in each pixel (shapes only; depth, normals and mask stay the pixel centre's)",
            ),
        ],
    }
}

/// A sphere tracer's `hit_tolerance`: "pixel" or "absolute".
pub(super) fn hit_tolerance(a: &Args) -> Result<HitTolerance, Diag> {
    let (mode, span) = a.string("hit_tolerance")?;
    match &*mode {
        "pixel" => Ok(HitTolerance::Pixel),
        "absolute" => Ok(HitTolerance::Absolute),
        other => Err(value_error(
            span,
            format!("unknown hit tolerance `{other}`"),
            "not a choice",
            "use \"pixel\" or \"absolute\"",
        )),
    }
}

/// A statement's job and the errors of its fields. With errors, the job
/// (when its outputs and views could be read) holds placeholders where
/// fields failed: it is only checked for output collisions, never run.
pub(crate) type Built<T> = (Option<T>, Vec<Diag>);

pub(crate) fn render_block(name: &str, a: &Args) -> Built<RenderJob> {
    let mut e = Errors::new(a);
    let outputs = e.ok(outputs(a, "outputs", false).and_then(|outputs| {
        match outputs
            .iter()
            .find(|o| {
                o.kind == OutputKind::SamplePoints || o.kind.training_only() || o.kind.field_export()
            })
        {
            Some(o) if o.kind.field_export() => Err(value_error(
                a.get("outputs").1,
                format!(
                    "`{}` needs a radiance field's density and opacity",
                    o.path.display()
                ),
                "not a sphere-tracing output",
                "ask for it from a `volume` or a `train` of a field; a scene's surface is `mesh(...)`, its depth `depth(...)`",
            )),
            Some(o) => Err(value_error(
                a.get("outputs").1,
                format!(
                    "`{}` needs a volume render or a training run",
                    o.path.display()
                ),
                "not a sphere-tracing output",
                "sample points exist for fields; loss curves, PSNR curves and comparisons for `train`",
            )),
            None => Ok(outputs),
        }
    }));
    let scene = e.ok(a.shape("scene"));
    if let (Some(outputs), Some(scene)) = (&outputs, &scene) {
        e.ok(check_meshes(outputs, Some(scene)));
    }
    let size = e.ok(image_size(a, "size"));
    let (near, far) = (e.ok(a.number("near")), e.ok(a.number("far")));
    let range = match (near, far) {
        (Some(near), Some(far)) => e.ok(check_range(a, near, far).map(|()| (near, far))),
        _ => None,
    };
    let (bg_span, bg) = (a.get("background").1, a.vec3("background"));
    let background = e.ok(bg.and_then(|bg| colour(bg, bg_span)));
    let cameras = e.ok(camera_list(a, "camera"));
    let material = e.ok(a.material("material"));
    let iterations = e.ok(a.count("iterations", 1, MAX_ITERATIONS as u64));
    let epsilon = e.ok(a.positive("epsilon"));
    let hit_tolerance = e.ok(hit_tolerance(a));
    let fog = e.ok(fog_option(a));
    let samples_per_pixel = e.ok(samples_per_pixel(a));
    let (near, far) = range.unwrap_or((0.0, 1.0));
    let (width, height) = size.unwrap_or((1, 1));
    let job = (|| {
        Some(RenderJob {
            name: name.to_string(),
            scene: scene?,
            material: material?,
            cameras: cameras?,
            width,
            height,
            near,
            far,
            iterations: iterations.unwrap_or(1) as u32,
            epsilon: epsilon.unwrap_or(1.0),
            hit_tolerance: hit_tolerance.unwrap_or(HitTolerance::Pixel),
            background: background.unwrap_or(DVec3::ZERO),
            fog: fog.flatten(),
            samples_per_pixel: samples_per_pixel.unwrap_or(1),
            outputs: outputs?,
        })
    })();
    (job, e.diags)
}

// ------------------------------------------------- train and volume blocks

pub(crate) fn train_sig() -> BlockSig {
    BlockSig {
        kind: "train",
        doc: "Fits the trainable parameters (`param(...)`) of `model` to `data` with Adam on an MSE loss, then reports them.",
        fields: vec![
            req("model", FIELD, "the field to fit; its `param(...)` arguments are trained"),
            req("data", DATASET, "the training views"),
            opt("sampler", SAMPLER, "stratified()", "depth samples along each ray"),
            opt("rays", Type::Number, "4096", "rays per batch"),
            opt("optimizer", OPTIMIZER, "adam()", "the optimizer and its learning-rate schedule"),
            opt("losses", Type::list(LOSS), "[mse()]", "the weighted terms of the objective (a neural SDF's default: `[surface(), eikonal(weight: 0.02), inter(weight: 0.1)]`)"),
            opt("bounds", Type::Number, "4", "random points of a distance field's eikonal and inter terms are drawn in [-bounds, bounds]³"),
            opt("iterations", Type::Number, "1000", "optimizer steps (unless `epochs` is given)"),
            opt("epochs", Type::Number, "0", "passes over all training pixels (0: use `iterations`)"),
            opt("seed", Type::Number, "0", "seed of the ray batches and jitter"),
            opt("backend", Type::Str, "\"fused\"", "\"fused\" (one kernel per ray, hand-written backward) or \"dfdx\" (an autodiff graph)"),
            opt("views", Type::OneOf(vec![CAMERA, Type::list(CAMERA), super::paths::VIEW_PATH]), "training_path()", "cameras of the before/after outputs: a path through the training cameras made when the run starts (`training_path(...)`, `training_loop(...)`), or cameras (`orbit()`, `camera_path(\"camera_path.json\")`); data without cameras (`points(...)`) is seen from `orbit()` unless this is given"),
            opt("size", Type::list(Type::Number), "[128, 128]", "size of the before/after outputs; where not given and `views` is a path through the training cameras, 128 pixels on the shorter side at the training images' aspect (the longer side rounded to even)"),
            opt("before", Type::list(OUTPUT), "[]", "outputs rendered from the starting model"),
            opt("after", Type::list(OUTPUT), "[]", "outputs rendered from the trained model, and `loss_curve`, `psnr_curve` and `comparison` (the last two need held-out views)"),
            opt("eval_every", Type::Number, "0", "steps between held-out evaluations (PSNR, SSIM on the data's test views; 0: at the end only)"),
            opt("eval_views", Type::Number, "0", "held-out views each evaluation scores, evenly spaced over the data's test views and the first included (0: all); the others are never read"),
            opt("eval_downscale", Type::Number, "1", "held-out views are scored at 1/N of their size a side (each block of N×N pixels averaged, N dividing the width and height; NeuS validates at 4): a 1600×1200 view costs a sixteenth at 4"),
            opt("checkpoint", Type::Str, "\"\"", "file (in the output directory) to keep a resumable checkpoint in (safetensors)"),
        ],
    }
}

pub(crate) fn train_block(name: &str, a: &Args) -> Built<TrainJob> {
    let mut e = Errors::new(a);
    let (model_v, model_span) = a.get("model");
    let model = e.ok(match model_v {
        Value::Field(model) => Ok(model.clone()),
        v => Err(type_error(model_span, "field", v)),
    });
    if let Some(model) = &model {
        let mut trainable = 0;
        model.visit_params(&mut |_| trainable += 1);
        // A neural field's weights are always trained; an analytic one
        // needs something marked.
        if trainable == 0 && model.as_sdf().is_some() {
            e.ok::<()>(Err(value_error(
                model_span,
                "this model has nothing to train",
                "no `param(...)` in it",
                "mark the arguments to fit with `param(...)`, e.g. `sphere(radius: param(0.5))`",
            )));
        }
    }
    let (data_v, data_span) = a.get("data");
    let data = e.ok(match data_v {
        Value::Dataset(d) => Ok(d.clone()),
        v => Err(type_error(data_span, "data set", v)),
    });
    // The model's background is the data's unless written, and a written
    // one that disagrees is said.
    let model = match (model, &data) {
        (Some(m), Some(d)) => {
            let (m, warning) = backgrounds_agree(m, d, data_span);
            e.diags.extend(warning);
            e.diags.extend(spaces_agree(&m, d, data_span));
            Some(m)
        }
        (m, _) => m,
    };
    let sampler = e.ok(match a.get("sampler").0 {
        Value::Sampler(s) => Ok(*s),
        v => Err(type_error(a.get("sampler").1, "sampler", v)),
    });
    let optimizer = e.ok(match a.get("optimizer").0 {
        Value::Optimizer(o) => Ok(*o),
        v => Err(type_error(a.get("optimizer").1, "optimizer", v)),
    });
    let (losses_v, losses_span) = a.get("losses");
    // A list of losses (a single loss is a list of one too).
    let losses = e.ok(
        match one_or_list(losses_v, |v| match v {
            Value::Loss(l) => Some(*l),
            _ => None,
        }) {
            Some(l) if !l.is_empty() => Ok(l),
            Some(_) => Err(value_error(
                losses_span,
                "no loss terms",
                "empty",
                "train on at least `[mse()]`",
            )),
            None => Err(type_error(losses_span, "list of losses", losses_v)),
        },
    );
    let losses = match (&model, &data, losses) {
        (Some(model), Some(data), Some(losses)) => {
            e.ok(train_losses(a, model, data, losses, losses_span))
        }
        _ => None,
    };
    let backend = e.ok(a.string("backend").and_then(|(backend, span)| {
        let backend = match &*backend {
            "fused" => Backend::Fused,
            "dfdx" => Backend::Dfdx,
            other => {
                return Err(value_error(
                    span,
                    format!("unknown backend `{other}`"),
                    "not a backend",
                    "use \"fused\" or \"dfdx\"",
                ))
            }
        };
        if backend == Backend::Dfdx && model.as_ref().is_some_and(|m| m.as_sdf().is_none()) {
            return Err(value_error(
                span,
                "a neural field trains through its fused layer kernels only",
                "no dfdx graph for this model",
                "drop `backend`, or use \"fused\"",
            ));
        }
        Ok(backend)
    }));
    let checkpoint = e.ok(a.string("checkpoint").and_then(|(checkpoint, span)| {
        if checkpoint.is_empty() {
            Ok(None)
        } else {
            safe_output_path(&checkpoint, span).map(Some)
        }
    }));
    let before = e.ok(outputs(a, "before", true));
    let after = e.ok(outputs(a, "after", true));
    if let Some(model) = &model {
        for outputs in [&before, &after].into_iter().flatten() {
            e.ok(check_field_exports(outputs, model));
            e.ok(match &**model {
                Field::Sdf(f) => check_meshes(outputs, Some(&f.shape)),
                // Bounded by its points or the training `bounds`.
                Field::NeuralSdf(_) | Field::NeuralSurface(_) => geometry_gifs(outputs, true),
                Field::Nerf(_) => check_meshes(outputs, None),
            });
        }
    }
    if let (Some(data), Some(after)) = (&data, &after) {
        e.ok(held_out(a, data, after));
    }
    let size = e.ok(image_size(a, "size"));
    let epochs = e.ok(a.count("epochs", 0, 1_000_000));
    // Defaults carry the block's span: a different span was written.
    if epochs.is_some_and(|n| n > 0) && a.get("iterations").1 != a.span {
        e.ok::<()>(Err(value_error(
            a.get("epochs").1,
            "`epochs` and `iterations` both say how long to train",
            "and `iterations` is given too",
            "keep one of them: `epochs` counts passes over every training pixel",
        )));
    }
    let rays = e.ok(a.count("rays", 1, 1 << 20));
    let iterations = e.ok(a.count("iterations", 0, 10_000_000));
    let seed = e.ok(a.count("seed", 0, u32::MAX as u64));
    let view_path = match a.get("views").0 {
        Value::ViewPath(p) => Some(*p),
        _ => None,
    };
    let no_cameras = data
        .as_deref()
        .is_some_and(|d| matches!(d, Dataset::Points { .. }));
    let (view_path, default_views) = match view_path {
        // Points have no cameras to pass through: the default looks on
        // from the orbit, a written path is refused.
        Some(_) if no_cameras && !a.given("views") => {
            (None, Some(Camera::orbit(3.0, OrbitUp::Y, 1.0, 20)))
        }
        Some(_) if no_cameras => {
            e.ok::<()>(Err(value_error(
                a.get("views").1,
                "a point cloud has no cameras to make a path through",
                "no training cameras",
                "look at the fitted surface from cameras: `views: orbit()`",
            )));
            // Refused: no cameras to read from `views` either.
            (None, Some(Vec::new()))
        }
        p => (p, None),
    };
    // Where not written, the size of views along the data's own cameras
    // follows its images' aspect: known now for views sdfl renders, once
    // read for files.
    let mut size_at_data_aspect = view_path.is_some() && !a.given("size");
    let size = match (size, data.as_deref()) {
        (Some(_), Some(Dataset::Rendered { width, height, .. })) if size_at_data_aspect => {
            size_at_data_aspect = false;
            Some(size_at_aspect(*width, *height, DATA_ASPECT_SHORT_SIDE))
        }
        (Some(_), Some(Dataset::Traced { job, .. })) if size_at_data_aspect => {
            size_at_data_aspect = false;
            Some(size_at_aspect(
                job.width,
                job.height,
                DATA_ASPECT_SHORT_SIDE,
            ))
        }
        (size, _) => size,
    };
    let views = match view_path {
        // As many placeholders as the path will have cameras: files and
        // work are counted before the run makes them.
        Some(p) => Some(vec![
            Camera::look_at(
                DVec3::Z * 3.0,
                DVec3::ZERO,
                DVec3::Y,
                1.0
            );
            p.frames()
        ]),
        None if default_views.is_some() => default_views,
        None => e.ok(camera_list(a, "views")),
    };
    let eval_every = e.ok(a.count("eval_every", 0, 10_000_000));
    let eval_views = e.ok(a.count("eval_views", 0, crate::limits::MAX_VIEWS as u64));
    let eval_downscale = e.ok(a.count("eval_downscale", 1, MAX_DOWNSCALE));
    let bounds = e.ok(a.positive("bounds"));
    let (width, height) = size.unwrap_or((1, 1));
    let epochs = epochs.unwrap_or(0) as usize;
    let job = (|| {
        Some(TrainJob {
            name: name.to_string(),
            model: model?,
            data: data?,
            data_span: a.get("data").1,
            sampler: sampler?,
            rays: rays.unwrap_or(1) as usize,
            optimizer: optimizer?,
            losses: losses?,
            iterations: iterations.unwrap_or(0) as usize,
            epochs: (epochs > 0).then_some(epochs),
            seed: seed.unwrap_or(0),
            backend: backend.unwrap_or(Backend::Fused),
            views: views?,
            view_path,
            width,
            height,
            size_at_data_aspect,
            before: before?,
            after: after?,
            checkpoint: checkpoint?,
            eval_every: eval_every.unwrap_or(0) as usize,
            eval_views: eval_views.filter(|&n| n > 0).map(|n| n as usize),
            eval_downscale: eval_downscale.unwrap_or(1) as u32,
            bounds: bounds.unwrap_or(1.0),
        })
    })();
    (job, e.diags)
}

/// A NeRF's background made one setting with its data's: `data_background()`
/// (the default) becomes the data's colour (a learned background for
/// photographs of the world, black where unknown, as before); a written
/// colour the data disagrees with gives a warning at it.
fn backgrounds_agree(
    model: Arc<Field>,
    data: &Dataset,
    data_span: Span,
) -> (Arc<Field>, Option<Diag>) {
    use crate::value::{Background, DataBackground, LearnedBackground};
    let Field::Nerf(n) = &*model else {
        return (model, None);
    };
    let theirs = data.background();
    let show = |c: [f64; 3]| {
        format!(
            "[{}, {}, {}]",
            sdfl_lang::fmt_num(c[0]),
            sdfl_lang::fmt_num(c[1]),
            sdfl_lang::fmt_num(c[2])
        )
    };
    match (n.background, theirs) {
        (Background::Data, _) => {
            let background = match theirs {
                DataBackground::Color(c) => Background::Color(c.to_array()),
                DataBackground::World => Background::Learned(LearnedBackground {
                    freqs: 4,
                    width: 32,
                }),
                DataBackground::Unknown => Background::Color([0.0; 3]),
            };
            let resolved = Nerf {
                background,
                ..n.clone()
            };
            (Arc::new(Field::Nerf(resolved)), None)
        }
        (Background::Color(mine), DataBackground::Color(d)) => {
            // Half a level of an 8-bit image is the same colour.
            let d = d.to_array();
            let same = (0..3).all(|i| (mine[i] - d[i]).abs() <= 0.5 / 255.0);
            let warning = (!same).then(|| {
                Diag::new(
                    codes::BACKGROUND_MISMATCH,
                    n.background_at.0,
                    format!(
                        "this NeRF's background {} is not its training data's, {}",
                        show(mine),
                        show(d)
                    ),
                )
                .label("the model's background")
                .note(
                    data_span,
                    format!("these images are composited over {}", show(d)),
                )
                .help(format!(
                    "drop `background` (a NeRF takes its data's), or write `background: {}`",
                    show(d)
                ))
            });
            (model, warning)
        }
        (Background::Color(mine), DataBackground::World) => {
            let warning = Diag::new(
                codes::BACKGROUND_MISMATCH,
                n.background_at.0,
                format!(
                    "this NeRF's background is one colour, {}, but its training images show the world behind the scene",
                    show(mine)
                ),
            )
            .label("the model's background")
            .note(data_span, "opaque photographs, no one background colour")
            .help("drop `background` (a learned one is then used), or write `background: learned_background()`");
            (model, Some(warning))
        }
        (Background::Color(_), DataBackground::Unknown) | (Background::Learned(_), _) => {
            (model, None)
        }
    }
}

/// A NeRF in NDC needs a forward-facing capture; an LLFF capture under a
/// bounded NeRF gets a warning (NeRF trains these scenes in NDC).
fn spaces_agree(model: &Field, data: &Dataset, data_span: Span) -> Option<Diag> {
    use crate::value::{CaptureFormat, Unbounded};
    let Field::Nerf(n) = model else {
        return None;
    };
    let format = match data {
        Dataset::Capture(c) => Some(c.format),
        _ => None,
    };
    match (&n.unbounded, format) {
        (Some(Unbounded::Ndc(_)), Some(CaptureFormat::Llff | CaptureFormat::Auto)) => None,
        (Some(Unbounded::Ndc(_)), _) => Some(
            Diag::new(
                codes::VALUE,
                data_span,
                "`unbounded: ndc()` maps positions through a forward-facing capture's camera, and this data is not one",
            )
            .label("not an LLFF capture")
            .help("train on `capture(..., format: \"llff\")`, or use `unbounded: contraction()` for other unbounded scenes"),
        ),
        (None, Some(CaptureFormat::Llff)) => Some(
            Diag::new(
                codes::FORWARD_FACING,
                data_span,
                "a forward-facing capture trained with ordinary rays: content far behind the near bound has no bounded box to live in",
            )
            .label("an LLFF capture")
            .help("give the NeRF `unbounded: ndc()` (the original NeRF's configuration for these scenes)"),
        ),
        _ => None,
    }
}

/// The loss terms a model trains on: the defaults of its kind unless
/// given, each one a term of that kind, and a fitting data set.
fn train_losses(
    a: &Args,
    model: &Field,
    data: &Dataset,
    losses: Vec<Loss>,
    losses_span: Span,
) -> Result<Vec<Loss>, Diag> {
    // A distance field learns from points with point terms; the others
    // from images with image terms.
    let on_points = matches!(model, Field::NeuralSdf(_));
    let surface_volume = matches!(model, Field::NeuralSurface(_));
    let (data_v, data_span) = a.get("data");
    if on_points != matches!(data, Dataset::Points { .. }) {
        return Err(value_error(
            data_span,
            if on_points {
                "a neural SDF learns from a point cloud"
            } else {
                "this model learns from images, not points"
            },
            format!("a {}", data_v.type_name()),
            if on_points {
                "give `data: points(\"cloud.npz\")`, or train `volsdf(neural_sdf(...))` on images"
            } else {
                "render or read views: `render_views(...)`, `views(...)`, `nerf_synthetic(...)`"
            },
        ));
    }
    // Unless given, a distance field trains on the assignment's three terms.
    let losses = if on_points && a.get("losses").1 == a.span {
        vec![
            Loss {
                kind: LossKind::Surface,
                weight: 1.0,
            },
            Loss {
                kind: LossKind::Eikonal,
                weight: 0.02,
            },
            Loss {
                kind: LossKind::Inter { alpha: 100.0 },
                weight: 0.1,
            },
        ]
    } else if surface_volume && a.get("losses").1 == a.span {
        // A neural SDF seen through images: colour, and unit gradients at
        // the samples so that it stays a distance.
        vec![
            Loss {
                kind: LossKind::Mse,
                weight: 1.0,
            },
            Loss {
                kind: LossKind::Eikonal,
                weight: 0.02,
            },
        ]
    } else {
        losses
    };
    if surface_volume && !losses.iter().any(|l| l.kind == LossKind::Mse) {
        return Err(value_error(
            losses_span,
            "a neural SDF's volume learns from images, and these terms have no image term",
            "no `mse()`",
            "add `mse()`: `losses: [mse(), eikonal()]`",
        ));
    }
    let applies = |k: LossKind| match k {
        LossKind::Silhouette => surface_volume,
        LossKind::Eikonal => on_points || surface_volume,
        _ => k.on_images() != on_points,
    };
    if let Some(l) = losses.iter().find(|l| !applies(l.kind)) {
        return Err(value_error(
            losses_span,
            format!("`{}` does not apply to this model", loss_name(l.kind)),
            "not a term of this model",
            if on_points {
                "a neural SDF trains on `surface()`, `eikonal()` and `inter()`"
            } else if surface_volume {
                "a neural SDF's volume trains on `mse()`, `eikonal()` and `silhouette()`"
            } else {
                "a field rendered to images trains on `mse()`"
            },
        ));
    }
    // Absorption past `far` is not geometry: an infinite last interval would
    // make every background ray opaque to the silhouette term.
    if losses.iter().any(|l| l.kind == LossKind::Silhouette)
        && matches!(a.get("sampler").0, Value::Sampler(s) if s.last_interval == LastInterval::Infinite)
    {
        return Err(value_error(
            a.get("sampler").1,
            "`silhouette()` counts what a ray absorbs as the object covering its pixel, and an infinite last interval absorbs beyond `far` on every ray",
            "last_interval: \"infinite\"",
            "leave `last_interval` at \"zero\" (the default), or leave `silhouette()` out",
        ));
    }
    // A shape's own views know how much of each pixel it covers (the
    // tracer's hit mask), and so do images whose alpha is the object's
    // coverage (NeRF-synthetic sets, captures with alpha: whether the files
    // have alpha is known only once they are read, and checked then).
    if losses.iter().any(|l| l.kind == LossKind::Silhouette)
        && !matches!(
            data,
            Dataset::Traced { .. } | Dataset::NerfSynthetic { .. } | Dataset::Capture(_)
        )
    {
        return Err(value_error(
            losses_span,
            "`silhouette()` compares each pixel's opacity with how much of it the object covers, and this data set does not say",
            "needs each pixel's coverage",
            "train on the views of a shape (`render_views(shape, ...)`), on images whose alpha is the object's coverage (`nerf_synthetic(...)`, `capture(...)`), or leave `silhouette()` out",
        ));
    }
    // A neural SDF is sphere-traced (normals as colours, depth): volume
    // figures do not apply.
    if on_points {
        for field in ["before", "after"] {
            if let Value::List(items) = a.get(field).0 {
                if items.iter().any(|o| {
                    matches!(o, Value::Output(o) if matches!(o.kind, OutputKind::SamplePoints | OutputKind::Dataset { .. }))
                }) {
                    return Err(value_error(
                        a.get(field).1,
                        "a neural SDF is sphere-traced: it has no volume samples or data set to write",
                        "not an output of a neural SDF",
                        "write `image`, `gif`, `video`, `depth`, `depth_gif` or `loss_curve`",
                    ));
                }
            }
        }
    }
    Ok(losses)
}

/// `psnr_curve` and `comparison` compare against held-out views.
fn held_out(a: &Args, data: &Dataset, after: &[Output]) -> Result<(), Diag> {
    let has_test = !data.test_views().is_empty()
        || matches!(
            data,
            Dataset::NerfSynthetic {
                test_split: Some(_),
                ..
            }
        )
        // A capture holds out its split list's test views, or every
        // `test_every`-th frame.
        || matches!(data, Dataset::Capture(c) if c.test_every > 0);
    match after
        .iter()
        .find(|o| matches!(o.kind, OutputKind::PsnrCurve | OutputKind::Comparison))
        .filter(|_| !has_test)
    {
        Some(o) => Err(value_error(
            a.get("after").1,
            format!(
                "`{}` needs held-out views, and the data set has none",
                o.path.display()
            ),
            "compares against test views",
            match data {
                // Only where the data set has a test split to read: one
                // written by `dataset(...)` holds `transforms.json` alone.
                Dataset::NerfSynthetic { path, .. }
                    if a
                        .base
                        .as_ref()
                        .is_none_or(|b| b.join(path).join("transforms_test.json").is_file()) =>
                {
                    "read the data set's test views too: `nerf_synthetic(..., test_split: \"test\")`"
                }
                Dataset::NerfSynthetic { .. } => {
                    "this data set has no `transforms_test.json` to hold views out: drop this output, or train on data with held-out views (`render_views(..., test_views: 5)`)"
                }
                _ => "hold some views out: `render_views(..., test_views: 5)`",
            },
        )),
        None => Ok(()),
    }
}

pub(crate) fn volume_block(name: &str, a: &Args, field: Arc<Field>) -> Built<VolumeJob> {
    let mut e = Errors::new(a);
    if matches!(*field, Field::NeuralSdf(_) | Field::NeuralSurface(_)) {
        e.ok::<()>(Err(super::not_a_volume(a.get("scene").1)));
    }
    e.ok(super::common::ndc_outside_training(
        &field,
        a.get("scene").1,
    ));
    let size = e.ok(image_size(a, "size"));
    // Sphere tracing's effects: asked of a volume, say so.
    let spp = e.ok(samples_per_pixel(a));
    for (name, asked) in [
        ("fog", !matches!(a.get("fog").0, Value::Bool(false))),
        ("samples_per_pixel", spp.is_some_and(|n| n != 1)),
    ] {
        if asked {
            e.ok::<()>(Err(value_error(
                a.get(name).1,
                format!(
                    "`{name}` is an effect of sphere-traced shapes; this render's scene is a field"
                ),
                "not for volume renders",
                "remove it, or render a shape: volume renders composite samples along each ray",
            )));
        }
    }
    let sampler = e.ok(match a.get("sampler").0 {
        Value::Sampler(s) => Ok(*s),
        v => Err(type_error(a.get("sampler").1, "sampler", v)),
    });
    let outputs = e.ok(outputs(a, "outputs", false).and_then(|outputs| {
        match outputs.iter().find(|o| {
            matches!(o.kind, OutputKind::Normals | OutputKind::Mask) || o.kind.training_only()
        }) {
            Some(o) => Err(value_error(
                a.get("outputs").1,
                format!("`{}` cannot be made by volume rendering", o.path.display()),
                "not a volume output",
                "volume renders write image, gif, depth, grid_image, rays_image and sample_points",
            )),
            None => Ok(outputs),
        }
    }));
    if let Some(outputs) = &outputs {
        e.ok(check_field_exports(outputs, &field));
        e.ok(check_meshes(outputs, field.as_sdf().map(|f| &*f.shape)));
    }
    let cameras = e.ok(camera_list(a, "camera"));
    let (width, height) = size.unwrap_or((1, 1));
    let job = (|| {
        Some(VolumeJob {
            name: name.to_string(),
            field,
            cameras: cameras?,
            width,
            height,
            sampler: sampler?,
            outputs: outputs?,
        })
    })();
    (job, e.diags)
}

/// `mesh` outputs need a distance (`shape`; none for a radiance field) and,
/// for `bounds: "auto"`, a bounded one.
fn check_meshes(outputs: &[Output], shape: Option<&Shape>) -> Result<(), Diag> {
    geometry_gifs(outputs, false)?;
    for o in outputs {
        let OutputKind::Mesh { region, .. } = o.kind else {
            continue;
        };
        let Some(shape) = shape else {
            return Err(value_error(
                o.span,
                "a radiance field has density, not distance: it has no surface to mesh",
                "no zero level set",
                "mesh a shape, an SDF field or a neural SDF",
            ));
        };
        if region == MeshRegion::Auto && shape.bounds().is_none() {
            return Err(value_error(
                o.span,
                "the shape is unbounded (a plane, or an infinite repetition), so `bounds: \"auto\"` has no region",
                "needs a region",
                "give the region: `mesh(\"scene.ply\", bounds: [[-2, -2, -2], [2, 2, 2]])`",
            ));
        }
    }
    Ok(())
}

/// Density meshes, point clouds and depth with opacity ask a radiance
/// field (a NeRF or an SDF field) for density and colour; a density mesh
/// with `bounds: "auto"` needs a region the field knows.
fn check_field_exports(outputs: &[Output], field: &Field) -> Result<(), Diag> {
    let Some(o) = outputs.iter().find(|o| o.kind.field_export()) else {
        return Ok(());
    };
    if matches!(field, Field::NeuralSdf(_) | Field::NeuralSurface(_)) {
        return Err(value_error(
            o.span,
            format!(
                "`{}` asks a radiance field for its density",
                crate::outputs::kind_name(&o.kind)
            ),
            "not an output of a neural SDF",
            "a neural SDF's surface is `mesh(...)`; its depth `depth(...)`",
        ));
    }
    for o in outputs {
        if let OutputKind::DensityMesh {
            region: MeshRegion::Auto,
            ..
        } = o.kind
        {
            if field.export_region().is_none() {
                return Err(value_error(
                    o.span,
                    "the field has no bounds of its own, so `bounds: \"auto\"` has no region",
                    "needs a region",
                    "give the region: `density_mesh(\"field.ply\", bounds: [[-1, -1, -1], [1, 1, 1]])`",
                ));
            }
        }
    }
    Ok(())
}

/// `geometry_gif` sphere-traces a neural SDF: only a training statement of
/// one (`neural` true) writes it.
fn geometry_gifs(outputs: &[Output], neural: bool) -> Result<(), Diag> {
    match outputs
        .iter()
        .find(|o| matches!(o.kind, OutputKind::GeometryGif { .. }))
    {
        Some(o) if !neural => Err(value_error(
            o.span,
            "`geometry_gif` shows a trained neural SDF's surface",
            "not an output of this statement",
            "ask for it in the `after` of a `train` whose model is a neural SDF; a shape's surface is what `render` draws",
        )),
        _ => Ok(()),
    }
}

/// The built-in that makes a loss term.
fn loss_name(kind: LossKind) -> &'static str {
    match kind {
        LossKind::Mse => "mse",
        LossKind::Surface => "surface",
        LossKind::Eikonal => "eikonal",
        LossKind::Inter { .. } => "inter",
        LossKind::Silhouette => "silhouette",
    }
}
