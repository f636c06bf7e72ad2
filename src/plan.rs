//! `sdfl plan`: what each statement will compute, and what it will not.

use super::*;

/// One line on what a field is and what it will compute.
fn describe_field(field: &sdfl_stdlib::value::Field) -> String {
    field.model().describe(&sdfl_runtime::describe::precision)
}

/// ", N held out as test views" (empty for none).
fn held_out(n: usize) -> String {
    match n {
        0 => String::new(),
        n => format!(", {n} held out as test views"),
    }
}

/// A line per `mesh` output: the grid it samples.
fn mesh_lines(o: &mut String, outputs: &[sdfl_stdlib::Output], default_region: &str) {
    use std::fmt::Write;
    for m in outputs {
        let sdfl_stdlib::OutputKind::Mesh { resolution, region } = m.kind else {
            continue;
        };
        let region = match region {
            sdfl_stdlib::value::MeshRegion::Auto => default_region.to_string(),
            sdfl_stdlib::value::MeshRegion::Box { min, max } => format!("{min:?}..{max:?}"),
        };
        let n = resolution as u64 + 5;
        let _ = writeln!(
            o,
            "  mesh           {}: surface nets, {resolution} cells along the longest side of {region}, at most {} grid evaluations, two planes in memory",
            m.path.display(),
            n * n * n
        );
    }
}

/// A line per field export: what it marches or samples.
fn export_lines(o: &mut String, outputs: &[sdfl_stdlib::Output], samples: usize, views: usize) {
    use sdfl_stdlib::OutputKind as K;
    use std::fmt::Write;
    for x in outputs {
        let p = x.path.display();
        let _ = match x.kind {
            K::DensityMesh {
                level, resolution, ..
            } => writeln!(
                o,
                "  density mesh   {p}: surface nets where the density reaches {level}, {resolution} cells along the longest side, at most {} grid evaluations, vertex colours",
                (resolution as u64 + 5).pow(3)
            ),
            K::PointCloud {
                points,
                min_opacity,
                crop,
            } => {
                let kept = match crop {
                    sdfl_stdlib::value::CloudCrop::Auto => "in the object's region".to_string(),
                    sdfl_stdlib::value::CloudCrop::None => "anywhere".to_string(),
                    sdfl_stdlib::value::CloudCrop::Box { min, max } => {
                        format!("in the box {min:?} to {max:?} of the data's frame")
                    }
                };
                writeln!(
                    o,
                    "  point cloud    {p}: up to {points} points where the training cameras' rays end (opacity ≥ {min_opacity}, {kept}), at most {} rays of {samples} samples, normals from each point's {} nearest",
                    points as u64 * sdfl_stdlib::work::CLOUD_RAYS_PER_POINT,
                    sdfl_stdlib::work::CLOUD_NORMAL_NEIGHBOURS,
                )
            }
            K::RawDepth { .. } | K::DepthMap { .. } => writeln!(
                o,
                "  depth export   {p}: expected depth over opacity, one march of {samples} samples a ray over {views} views"
            ),
            _ => Ok(()),
        };
    }
}

/// The plan of `program`, whose data paths are relative to `base` (the
/// scene file's directory): data sets read from files are sized from
/// their images' headers.
pub(crate) fn plan_text_in(program: &sdfl_stdlib::Program, base: &std::path::Path) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let row = |o: &mut String, what: &str, who: &[String]| {
        let _ = if who.is_empty() {
            writeln!(o, "  {what:<14} skipped (no output needs it)")
        } else {
            writeln!(o, "  {what:<14} computed for {}", who.join(", "))
        };
    };
    for job in &program.renders {
        let plan = Plan::of(job);
        let _ = writeln!(o, "render {} (sphere tracing)", job.name);
        let _ = writeln!(
            o,
            "  scene          {} primitives, {:?}, Lipschitz bound {}",
            job.scene.primitive_count(),
            job.scene.exactness(),
            job.scene.lipschitz()
        );
        let _ = writeln!(
            o,
            "  rays           {} views x {}x{}, near {} far {}, <= {} steps, epsilon {}",
            job.cameras.len(),
            job.width,
            job.height,
            job.near,
            job.far,
            job.iterations,
            job.epsilon
        );
        row(&mut o, "colour", &plan.color);
        row(&mut o, "depth", &plan.depth);
        let mut normals = plan.normals.clone();
        if plan.shading_normals {
            normals.push("shading (the material uses normals)".into());
        }
        row(&mut o, "normals", &normals);
        if plan.shading_view {
            let _ = writeln!(
                o,
                "  view direction used for shading (a specular material: colour depends on the view)"
            );
        }
        row(&mut o, "hit mask", &plan.mask);
        let effects = plan.effect_lines();
        if effects.is_empty() {
            let _ = writeln!(
                o,
                "  effects        none (no shadow rays, occlusion, fog or supersampling asked for)"
            );
        }
        for (what, cost) in effects {
            let _ = writeln!(o, "  {what:<14} {cost}");
        }
        for d in job
            .outputs
            .iter()
            .filter(|x| matches!(x.kind, sdfl_stdlib::OutputKind::Dataset { .. }))
        {
            let _ = writeln!(
                o,
                "  dataset        {}/transforms.json (nerfstudio) + transforms_{{train,val,test}}.json (Blender) + r_0..r_{}.png (OpenGL poses, RGBA, alpha = hit mask; {} held out)",
                d.path.display(),
                job.cameras.len() - 1,
                match d.kind {
                    sdfl_stdlib::OutputKind::Dataset { test_views, .. } => test_views,
                    _ => 0,
                }
            );
        }
        mesh_lines(&mut o, &job.outputs, "the scene's bounds");
        let _ = writeln!(o, "  gradient tape  none (not training)");
        work_lines(&mut o, &sdfl_stdlib::work::render_work(job, None));
    }
    for job in &program.volumes {
        let names = |pred: &dyn Fn(&sdfl_stdlib::OutputKind) -> bool| -> Vec<String> {
            job.outputs
                .iter()
                .filter(|x| pred(&x.kind))
                .map(|x| x.path.display().to_string())
                .collect()
        };
        use sdfl_stdlib::OutputKind as K;
        let _ = writeln!(o, "render {} (volume rendering)", job.name);
        let _ = writeln!(o, "  field          {}", describe_field(&job.field));
        let _ = writeln!(
            o,
            "  samples        {} per ray, stratified {}..{}, {} views x {}x{}",
            job.sampler.samples,
            job.sampler.near,
            job.sampler.far,
            job.cameras.len(),
            job.width,
            job.height
        );
        row(
            &mut o,
            "composite",
            &names(&|k| matches!(k, K::Image | K::Gif { .. } | K::Video { .. } | K::Depth)),
        );
        row(&mut o, "depth", &names(&|k| matches!(k, K::Depth)));
        row(&mut o, "view branch", &[]);
        row(
            &mut o,
            "visual checks",
            &names(&|k| matches!(k, K::Grid | K::Rays | K::SamplePoints)),
        );
        mesh_lines(&mut o, &job.outputs, "the field's bounds");
        export_lines(&mut o, &job.outputs, job.sampler.samples, job.cameras.len());
        let _ = writeln!(o, "  gradient tape  none (not training)");
        work_lines(&mut o, &sdfl_stdlib::work::volume_work(job, None));
    }
    for job in &program.trains {
        let _ = writeln!(o, "train {}", job.name);
        let _ = writeln!(o, "  model          {}", describe_field(&job.model));
        let described = sdfl_runtime::describe::train(job);
        let _ = writeln!(o, "  trainable      {}", described.trainable);
        let data = match &*job.data {
            sdfl_stdlib::value::Dataset::Points {
                path,
                every,
                center,
            } => format!(
                "points of {}{}{}",
                path.display(),
                if *every > 1 {
                    format!(", one in {every}")
                } else {
                    String::new()
                },
                if *center { ", centred" } else { "" }
            ),
            sdfl_stdlib::value::Dataset::Files { images, .. } => {
                format!("{} image files", images.len())
            }
            sdfl_stdlib::value::Dataset::Rendered {
                cameras,
                width,
                height,
                test,
                ..
            } => {
                format!(
                    "{} views volume-rendered by sdfl at {width}x{height}{}",
                    cameras.len(),
                    held_out(test.len())
                )
            }
            sdfl_stdlib::value::Dataset::Traced { job, test } => {
                let plan = Plan::of(&sdfl_stdlib::RenderJob {
                    outputs: vec![sdfl_stdlib::Output {
                        kind: sdfl_stdlib::OutputKind::Image,
                        path: "data".into(),
                        span: sdfl_lang::Span::default(),
                    }],
                    ..(**job).clone()
                });
                format!(
                    "{} views sphere-traced by sdfl at {}x{}, {} primitives{}{}{}",
                    job.cameras.len(),
                    job.width,
                    job.height,
                    job.scene.primitive_count(),
                    if plan.shading_normals {
                        ", shaded with normals"
                    } else {
                        ""
                    },
                    if plan.shading_view {
                        " and the view direction (view-dependent colour)"
                    } else {
                        ""
                    },
                    held_out(test.len())
                )
            }
            sdfl_stdlib::value::Dataset::NerfSynthetic {
                path,
                split,
                test_split,
                downscale,
                ..
            } => format!(
                "NeRF-synthetic data set {}, split `{split}`{}{}",
                path.display(),
                test_split
                    .as_ref()
                    .map(|t| format!(", test views from split `{t}`"))
                    .unwrap_or_default(),
                if *downscale > 1 {
                    format!(", every image box-filtered to 1/{downscale} a side")
                } else {
                    String::new()
                }
            ),
            sdfl_stdlib::value::Dataset::Capture(c) => format!(
                "capture {} ({}{}), {}{}; the scene frame is reported when read",
                c.path.display(),
                c.format.name(),
                if c.downscale > 1 {
                    format!(", images_{}", c.downscale)
                } else {
                    String::new()
                },
                if c.test_every > 0 {
                    format!("split lists, else every {}th frame held out", c.test_every)
                } else {
                    "split lists, else no test views".to_string()
                },
                // What `auto` finds decides the frame (LLFF's and IDR's
                // are their own); the files are read again when run.
                match (
                    c.normalize,
                    sdfl_runtime::data::capture::own_frame(c, base),
                    c.orient,
                ) {
                    (false, _, _) => ", the data's own frame".to_string(),
                    (true, Some(own), _) => format!(", {own}"),
                    (true, _, orient) => format!(
                        ", cameras centred into [-{e}, {e}]^3{}",
                        match orient {
                            sdfl_stdlib::value::CaptureOrient::Up => ", mean up turned to +z",
                            sdfl_stdlib::value::CaptureOrient::None => "",
                        },
                        e = sdfl_lang::fmt_num(c.extent)
                    ),
                }
            ),
        };
        let _ = writeln!(o, "  data           {data}");
        let estimate = data_lines(&mut o, job, base);
        let on_points = job.model.model().trains_on_points();
        let _ = writeln!(
            o,
            "  step           {}, {}, Adam lr {} ({}), {}",
            if on_points {
                format!(
                    "{0} surface points + {0} random points in [-{1}, {1}]^3",
                    job.rays, job.bounds
                )
            } else {
                format!(
                    "{} rays x {} samples{}{}",
                    job.rays,
                    job.sampler.samples,
                    if job.sampler.jitter {
                        " (jittered)"
                    } else {
                        ""
                    },
                    match &*job.model {
                        sdfl_stdlib::value::Field::NeuralSurface(n) if n.fine > 0 => format!(
                            " + {} placed near the surface by a distance-only pass over them",
                            n.fine
                        ),
                        _ => String::new(),
                    }
                )
            },
            job.losses
                .iter()
                .map(|l| {
                    let name = match l.kind {
                        sdfl_stdlib::value::LossKind::Mse => "MSE on colour".to_string(),
                        sdfl_stdlib::value::LossKind::Surface => "mean |f| at the points".into(),
                        sdfl_stdlib::value::LossKind::Eikonal => {
                            "eikonal (exact input gradient)".into()
                        }
                        sdfl_stdlib::value::LossKind::Inter { alpha } => {
                            format!("exp(-{alpha}|f|) at random points")
                        }
                        sdfl_stdlib::value::LossKind::Silhouette => {
                            "BCE of opacity against coverage".into()
                        }
                    };
                    if l.weight == 1.0 {
                        name
                    } else {
                        format!("{} x {name}", l.weight)
                    }
                })
                .collect::<Vec<_>>()
                .join(" + "),
            job.optimizer.lr,
            match job.optimizer.schedule {
                sdfl_stdlib::value::Schedule::Constant => "constant".to_string(),
                sdfl_stdlib::value::Schedule::Step { factor, every } => {
                    format!("x{factor} every {every} steps")
                }
                sdfl_stdlib::value::Schedule::Exponential { factor, every } => {
                    format!("x{factor} per {every} steps, smoothly")
                }
            },
            match job.epochs {
                Some(e) => format!("{e} epochs"),
                None => format!("{} iterations", job.iterations),
            }
        );
        let _ = writeln!(o, "  gradient tape  {}", described.gradient);
        if !on_points {
            let _ = writeln!(o, "  depth          skipped (the loss uses colour only)");
        }
        let _ = writeln!(
            o,
            "  outputs        {} before, {} after",
            job.before.len(),
            job.after.len()
        );
        let region = described.mesh_region;
        mesh_lines(&mut o, &job.before, &region);
        mesh_lines(&mut o, &job.after, &region);
        for outputs in [&job.before, &job.after] {
            export_lines(&mut o, outputs, job.sampler.samples, job.views.len());
        }
        let _ = writeln!(o, "  logs           {}", sdfl_runtime::describe::logs(job));
        let _ = writeln!(
            o,
            "  checkpoint     {}",
            sdfl_runtime::describe::checkpoint(job)
        );
        let work = sdfl_stdlib::work::train_work(job, None);
        work_lines(&mut o, &work);
        if let Some(e) = estimate {
            let b = e.budget;
            let _ = writeln!(
                o,
                "    {:<20} {:.1e} evaluations expected ({:.1e} scoring {} held-out views, {}), about {} of memory (limits {:.0e} and {}), as checked once read",
                "with the data",
                b.evaluations,
                b.held_out_evaluations,
                e.test_views,
                sdfl_stdlib::work::fmt_duration(
                    b.held_out_evaluations / sdfl_runtime::pace::evaluation_rate()
                ),
                sdfl_stdlib::size::fmt_bytes(b.memory),
                sdfl_stdlib::work::max_evaluations(),
                sdfl_stdlib::size::fmt_bytes(sdfl_stdlib::work::max_memory())
            );
        }
        output_time_lines(&mut o, job);
        host_line(&mut o, &work);
    }
    if o.is_empty() {
        // A file of `let`s and `fn`s only (one meant to be imported).
        o.push_str("no statements: nothing runs (a file of `let`s and `fn`s is for `import`)\n");
    }
    o
}

/// The memory of a data set read from files, from its images' headers
/// (a sample of a large set): what `run` checks once it has read them.
/// Returns the estimate, `None` where the data are not files or cannot be
/// read here.
fn data_lines(
    o: &mut String,
    job: &sdfl_stdlib::value::TrainJob,
    base: &std::path::Path,
) -> Option<sdfl_runtime::data::Estimate> {
    use sdfl_stdlib::size::fmt_bytes;
    use std::fmt::Write;
    let e = match sdfl_runtime::data::estimate(job, base) {
        Ok(e) => e?,
        Err(err) => {
            let _ = writeln!(o, "  data memory    known once read ({err})");
            return None;
        }
    };
    let views = match e.size {
        Some((w, h)) => format!("{} views of {w}x{h}", e.views),
        None => format!("{} views", e.views),
    };
    let read = if e.headers < e.views {
        format!(
            "{} of {} image headers read, the others taken as their mean",
            e.headers, e.views
        )
    } else {
        format!("from {} image headers", e.headers)
    };
    let _ = writeln!(
        o,
        "  data memory    {views}{}, {:.0} pixels: {} held through training (8-bit files as 8-bit RGBA, others and box-filtered ones as f32 RGB, and a byte a pixel of coverage or mask where kept; {read})",
        match (e.test_views, e.test_views_in_data) {
            (n, all) if n < all => format!(", {n} of its {all} held-out views read and scored (`eval_views`)"),
            (n, _) => held_out(n),
        },
        e.pixels,
        fmt_bytes(e.held)
    );
    let _ = writeln!(
        o,
        "    {:<20} at most {} (the views read so far and an image decoding on each thread: its file, its pixels, two f32 copies)",
        "reading",
        fmt_bytes(e.reading)
    );
    Some(e)
}

/// What the machine's threads add to the statement's memory: the scratch
/// each keeps (a hash-grid surface's blocks, the dfdx graph's matrix
/// library), where there is any.
fn host_line(o: &mut String, work: &sdfl_stdlib::work::Work) {
    use std::fmt::Write;
    let host = sdfl_runtime::cpu::host();
    let on_host = work.memory_on(&host);
    if on_host > work.memory {
        let _ = writeln!(
            o,
            "    {:<20} {} with this machine's {} threads' scratch (kernels: {})",
            "on this machine",
            sdfl_stdlib::size::fmt_bytes(on_host),
            host.threads,
            sdfl_runtime::cpu::kernels().describe()
        );
    }
}

/// Each output's expected time on this machine, longest first (the views
/// of a phase, rendered once for all its view outputs, as one).
fn output_time_lines(o: &mut String, job: &sdfl_stdlib::value::TrainJob) {
    use std::fmt::Write;
    let rate = sdfl_runtime::pace::evaluation_rate();
    let mut parts = sdfl_stdlib::work::train_output_costs(job, None);
    if parts.is_empty() {
        return;
    }
    parts.sort_by(|a, b| b.seconds(rate).total_cmp(&a.seconds(rate)));
    let _ = writeln!(o, "  output times");
    for p in parts {
        let _ = writeln!(
            o,
            "    {:<20} {}",
            p.what,
            sdfl_stdlib::work::fmt_duration(p.seconds(rate))
        );
    }
}

/// The statement's estimated work and time on this machine, then each
/// stage's share, time and memory.
fn work_lines(o: &mut String, work: &sdfl_stdlib::work::Work) {
    use std::fmt::Write;
    let rate = sdfl_runtime::pace::evaluation_rate();
    let _ = writeln!(
        o,
        "  work           {}; {} on this machine",
        work.describe(),
        sdfl_stdlib::work::fmt_duration(work.total_seconds(rate))
    );
    for line in work.stage_lines(Some(rate)) {
        let _ = writeln!(o, "    {line}");
    }
}
