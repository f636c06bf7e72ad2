//! `render_views(...)`: a data set of views that sdfl renders of any scene,
//! with held-out test views.

use super::*;

pub(super) fn render_views(a: &Args) -> Result<Value, Diag> {
    let cameras = camera_list(a, "cameras")?;
    let (width, height) = image_size(a, "size")?;
    // Settings of the other kind of scene, given explicitly, would be
    // silently ignored: refuse them (defaults carry the call's span).
    let given = |name: &str| a.get(name).1 != a.span;
    let refuse = |names: &[&str], scene: &str, help: &str| -> Result<(), Diag> {
        match names.iter().find(|n| given(n)) {
            Some(n) => Err(value_error(
                a.get(n).1,
                format!("`{n}` does not apply to a {scene}"),
                format!("ignored for a {scene}"),
                help.to_string(),
            )),
            None => Ok(()),
        }
    };
    let tests = a.count("test_views", 0, MAX_VIEWS as u64)? as usize;
    if tests >= cameras.len() {
        return Err(value_error(
            a.get("test_views").1,
            format!(
                "holding out {tests} of {} cameras leaves no training view",
                cameras.len()
            ),
            "as many as the cameras",
            "hold out fewer views than there are cameras",
        ));
    }
    let test = crate::value::held_out(
        cameras.len(),
        tests,
        a.count("split_seed", 0, u32::MAX as u64)?,
    );
    let (cameras, test) = training_subset(a, cameras, test)?;
    let (scene, scene_span) = a.get("scene");
    let data = match scene {
        Value::Field(field) if matches!(**field, Field::NeuralSdf(_)) => {
            return Err(not_a_volume(scene_span));
        }
        Value::Field(field) => {
            super::common::ndc_outside_training(field, scene_span)?;
            refuse(
                &[
                    "material",
                    "background",
                    "near",
                    "far",
                    "iterations",
                    "hit_tolerance",
                ],
                "field",
                "a field's colour is its `color`; its depth range is the `sampler`'s",
            )?;
            let Value::Sampler(sampler) = a.get("sampler").0 else {
                return Err(type_error(
                    a.get("sampler").1,
                    "sampler",
                    a.get("sampler").0,
                ));
            };
            Dataset::Rendered {
                field: field.clone(),
                cameras,
                width,
                height,
                sampler: *sampler,
                test,
            }
        }
        Value::Shape(shape) => {
            refuse(
                &["sampler"],
                "shape",
                "shapes are sphere-traced: set `near`, `far` and `iterations` instead",
            )?;
            let (near, far) = (a.number("near")?, a.number("far")?);
            check_range(a, near, far)?;
            let (bg, bg_span) = (a.vec3("background")?, a.get("background").1);
            // The `render` statement's defaults for what is not asked here.
            Dataset::Traced {
                job: Arc::new(RenderJob {
                    name: "render_views".to_string(),
                    scene: shape.clone(),
                    material: a.material("material")?,
                    cameras,
                    width,
                    height,
                    near,
                    far,
                    iterations: a.count("iterations", 1, MAX_ITERATIONS as u64)? as u32,
                    epsilon: 1e-5,
                    hit_tolerance: blocks::hit_tolerance(a)?,
                    background: colour(bg, bg_span)?,
                    fog: None,
                    samples_per_pixel: 1,
                    outputs: Vec::new(),
                }),
                test,
            }
        }
        other => return Err(type_error(scene_span, "shape or field", other)),
    };
    Ok(Value::Dataset(Arc::new(data)))
}

/// `train_views: k`: the test views are held out of all the cameras first
/// (so they do not depend on `k`), then `k` training views are taken from
/// the rest, spread out ([`crate::value::spread_views`]); the other
/// cameras are dropped. Returns the cameras kept, in their order, and the
/// test views' indices among them. `0` keeps every camera.
fn training_subset(
    a: &Args,
    cameras: Vec<Camera>,
    test: Vec<usize>,
) -> Result<(Vec<Camera>, Vec<usize>), Diag> {
    let rest = cameras.len() - test.len();
    let k = a.count("train_views", 0, MAX_VIEWS as u64)? as usize;
    if k == 0 || k == rest {
        return Ok((cameras, test));
    }
    if k > rest {
        return Err(value_error(
            a.get("train_views").1,
            format!(
                "{k} training views asked for, but {rest} of the {} cameras are not held out",
                cameras.len()
            ),
            "more than the cameras left",
            format!("give at most {rest}, or more cameras (a fixed set, larger than any `train_views` a sweep asks for)"),
        ));
    }
    let eyes: Vec<DVec3> = cameras.iter().map(|c| c.eye).collect();
    let train = crate::value::spread_views(&eyes, &test, k);
    let mut kept = Vec::with_capacity(k + test.len());
    let mut test_at = Vec::with_capacity(test.len());
    for (i, camera) in cameras.into_iter().enumerate() {
        if test.binary_search(&i).is_ok() {
            test_at.push(kept.len());
            kept.push(camera);
        } else if train.binary_search(&i).is_ok() {
            kept.push(camera);
        }
    }
    Ok((kept, test_at))
}

/// What an input path must name.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum Input {
    File,
    Dir,
}

/// Refuses an input that does not exist (relative to the scene file's
/// directory) as a diagnostic at the argument naming it, so `check` finds
/// it before anything runs. A program without a file on disk has no base
/// directory: its inputs are checked when run.
pub(super) fn check_input(a: &Args, rel: &Path, span: Span, kind: Input) -> Result<(), Diag> {
    let Some(base) = &a.base else {
        return Ok(());
    };
    let full = base.join(rel);
    // Links followed, as the runtime reads them.
    let (ok, what, kind) = match kind {
        Input::File => (full.is_file(), "file", "regular file"),
        Input::Dir => (full.is_dir(), "directory", "directory"),
    };
    if ok {
        return Ok(());
    }
    let found = if full.exists() {
        format!("not a {kind}")
    } else {
        "not found".to_string()
    };
    Err(Diag::new(
        codes::IO,
        span,
        format!("input {what} `{}` {found}", full.display()),
    )
    .label(found)
    .help("input paths are relative to the scene file's directory: check the path"))
}

/// A NeRF-synthetic data set's files exist: the `.json` file named, or the
/// directory with the training split's transforms file (or a lone
/// `transforms.json`) and the test split's.
pub(super) fn check_nerf_synthetic(
    a: &Args,
    path: &Path,
    split: &str,
    test_split: Option<&str>,
) -> Result<(), Diag> {
    let span = a.get("path").1;
    let is_json = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if is_json {
        return check_input(a, path, span, Input::File);
    }
    check_input(a, path, span, Input::Dir)?;
    let Some(base) = &a.base else {
        return Ok(());
    };
    let dir = base.join(path);
    let has = |name: &str| dir.join(name).is_file();
    let train = format!("transforms_{split}.json");
    if !has(&train) && !has("transforms.json") {
        return Err(Diag::new(
            codes::IO,
            span,
            format!("the data set `{}` has no {train} (nor transforms.json)", dir.display()),
        )
        .label("no transforms file")
        .help("name a NeRF-synthetic directory (with transforms_train.json), or the split's .json file"));
    }
    if let Some(t) = test_split {
        let test = format!("transforms_{t}.json");
        if !has(&test) {
            return Err(Diag::new(
                codes::IO,
                a.get("test_split").1,
                format!("the data set `{}` has no {test}", dir.display()),
            )
            .label("no such split")
            .help("name a split the data set has, or leave `test_split` out"));
        }
    }
    Ok(())
}

/// `capture(...)`: a real capture's directory (or transforms file), read
/// when run; its path is checked here so `check` finds a missing one.
pub(super) fn capture(a: &Args) -> Result<Value, Diag> {
    let (path, path_span) = a.string("path")?;
    if path.is_empty() || path.contains('\0') {
        return Err(Diag::new(codes::PATH, path_span, "not a usable path")
            .label("empty or holds a NUL byte")
            .help("name the capture's directory, e.g. \"data/garden\""));
    }
    let choice = |name: &str, options: &[&str]| -> Result<usize, Diag> {
        let (v, span) = a.string(name)?;
        options.iter().position(|o| **o == *v).ok_or_else(|| {
            value_error(
                span,
                format!("`{name}` must be one of {}", options.join(", ")),
                "not an option",
                format!(
                    "use one of {}",
                    options
                        .iter()
                        .map(|o| format!("\"{o}\""))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            )
        })
    };
    let names: Vec<&str> = CaptureFormat::NAMES.iter().map(|(n, _)| *n).collect();
    let format = CaptureFormat::NAMES[choice("format", &names)?].1;
    let orient = [CaptureOrient::Up, CaptureOrient::None][choice("orient", &["up", "none"])?];
    let downscale = a.count("downscale", 1, 8)? as u32;
    if !downscale.is_power_of_two() {
        return Err(value_error(
            a.get("downscale").1,
            format!("`downscale` must be 1, 2, 4 or 8, got {downscale}"),
            "no such image folder",
            "nerfstudio writes images_2, images_4 and images_8",
        ));
    }
    let test_every = a.count("test_every", 0, MAX_VIEWS as u64)? as usize;
    let is_json = Path::new(path.as_ref())
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if is_json && !matches!(format, CaptureFormat::Auto | CaptureFormat::Nerfstudio) {
        return Err(value_error(
            a.get("format").1,
            format!("a .json file is nerfstudio's format, not {}", format.name()),
            "does not match the path",
            "name the capture's directory, or use format: \"nerfstudio\"",
        ));
    }
    if format == CaptureFormat::Idr && downscale > 1 {
        return Err(value_error(
            a.get("downscale").1,
            format!("IDR's layout keeps full-size images only (image/), not images_{downscale}"),
            "no such image folder",
            "leave `downscale` out",
        ));
    }
    check_input(
        a,
        Path::new(path.as_ref()),
        path_span,
        if is_json { Input::File } else { Input::Dir },
    )?;
    let masks: Vec<&str> = ObjectMasks::NAMES.iter().map(|(n, _)| *n).collect();
    let object_masks = ObjectMasks::NAMES[choice("object_masks", &masks)?].1;
    if object_masks == ObjectMasks::Alpha
        && !matches!(format, CaptureFormat::Auto | CaptureFormat::Idr)
    {
        return Err(value_error(
            a.get("object_masks").1,
            format!("{} captures have no object masks", format.name()),
            "no masks to composite by",
            "object masks come with IDR's layout (mask/); nerfstudio's `mask_path` marks pixels to ignore",
        ));
    }
    if object_masks == ObjectMasks::Alpha && !a.given("background") {
        return Err(value_error(
            a.get("object_masks").1,
            "compositing by the object masks needs the colour to composite over",
            "no `background` given",
            "add background: [0, 0, 0] (it is also the model's background)",
        ));
    }
    // Photographs have no alpha: unless the user names a colour, the
    // background is the world, learned by a model left on the data's.
    let background = if a.given("background") {
        let (bg, bg_span) = (a.vec3("background")?, a.get("background").1);
        Some(colour(bg, bg_span)?)
    } else {
        None
    };
    Ok(Value::Dataset(Arc::new(Dataset::Capture(Arc::new(
        CaptureSpec {
            path: PathBuf::from(path.as_ref()),
            path_span,
            format,
            downscale,
            test_every,
            normalize: !matches!(a.get("normalize").0, Value::Bool(false)),
            orient,
            extent: 1.0,
            background,
            object_masks,
        },
    )))))
}
