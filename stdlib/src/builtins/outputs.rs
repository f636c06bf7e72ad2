//! What statements write: images, GIFs, meshes, data sets, figures and
//! plots of training.

use super::*;

/// Finest mesh grid: a billion evaluations, planes of a million points.
pub const MAX_MESH_RESOLUTION: u32 = 1024;

pub(crate) fn builtins() -> Vec<Builtin> {
    // An animated GIF of all views: a path and a frame rate.
    let animation = |name: &'static str, doc: &'static str, eval: EvalFn| {
        func(
            name,
            doc,
            vec![
                req("path", Type::Str, "file name inside the output directory"),
                opt("fps", Type::Number, "10", "frames per second (> 0)"),
            ],
            OUTPUT,
            eval,
        )
    };
    let output = |name: &'static str, doc: &'static str, eval: EvalFn| {
        func(
            name,
            doc,
            vec![req(
                "path",
                Type::Str,
                "file name inside the output directory",
            )],
            OUTPUT,
            eval,
        )
    };
    vec![
        output("image", "Shaded colour as PNG; one file per view (`{view}` in the name, or `_NN` added).", |a| {
            out(a, OutputKind::Image, "png")
        }),
        animation("gif", "All views as an animated GIF.", |a| out(a, OutputKind::Gif { fps: a.positive("fps")? }, "gif")),
        animation("depth_gif", "Depth of all views (colour-mapped as `depth`) as an animated GIF.", |a| out(a, OutputKind::DepthGif { fps: a.positive("fps")? }, "gif")),
        output("depth", "Hit depth normalised by its maximum, colour-mapped, as PNG per view; misses black.", |a| {
            out(a, OutputKind::Depth, "png")
        }),
        output("normal_map", "Surface normals `(n + 1)/2` as PNG per view; misses black.", |a| {
            out(a, OutputKind::Normals, "png")
        }),
        output("mask", "Hit mask as PNG per view: white hit, black miss.", |a| out(a, OutputKind::Mask, "png")),
        func(
            "dataset",
            "Every view as a data set in directory `path` that nerfstudio (its `blender-data` and `nerfstudio-data` parsers), instant-ngp and `nerf_synthetic(...)` read unchanged: `r_<k>.png` per view (RGBA, alpha = hit mask, opaque for fields); `transforms_train.json`, `transforms_val.json`, `transforms_test.json` (Blender form: `camera_angle_x`, `file_path` without extension, OpenGL camera-to-world `transform_matrix`); and `transforms.json` (nerfstudio form: `camera_model`, `fl_x fl_y cx cy w h` and distortion, globally or per frame, `file_path` with extension, `train_filenames`/`val_filenames`/`test_filenames`). `test_views` views, picked by a seeded shuffle, form the val and test splits; with none, val and test list every view.",
            vec![
                req("path", Type::Str, "directory inside the output directory"),
                opt("test_views", Type::Number, "0", "views held out as the val and test splits (fewer than the views)"),
                opt("seed", Type::Number, "0", "seed of the shuffle that picks the held-out views"),
            ],
            OUTPUT,
            |a| {
                let (path, span) = a.string("path")?;
                let path = safe_output_path(&path, span)?;
                let test_views = a.count("test_views", 0, MAX_VIEWS as u64)? as usize;
                let seed = a.count("seed", 0, u32::MAX as u64)?;
                Ok(Value::Output(Arc::new(Output { kind: OutputKind::Dataset { test_views, seed }, path, span: a.span })))
            },
        ),
        animation("geometry_gif", "A neural SDF's surface, sphere-traced from every view with normals as colours, as an animated GIF (after `train`): the geometry of a `volsdf(neural_sdf(...))` whose `gif` shows its volume-rendered colour.", |a| out(a, OutputKind::GeometryGif { fps: a.positive("fps")? }, "gif")),
        func(
            "mesh",
            "The surface (where the distance is 0) as a triangle mesh in a binary PLY file with normals, for Blender or MeshLab: surface nets on a grid with `resolution` cells along the longest side, vertices projected onto the surface. Of a render's scene, an SDF field, or a trained SDF or neural SDF.",
            vec![
                req("path", Type::Str, "file name inside the output directory (.ply)"),
                opt("resolution", Type::Number, "128", "grid cells along the region's longest side (8 to 1024)"),
                opt(
                    "bounds",
                    Type::OneOf(vec![Type::Str, Type::list(Type::Vec3)]),
                    "\"auto\"",
                    "the region: `[[x0, y0, z0], [x1, y1, z1]]`, or \"auto\" for the shape's bounds (a neural SDF's: its training points', else the training `bounds`)",
                ),
            ],
            OUTPUT,
            |a| {
                let resolution = a.count("resolution", 8, MAX_MESH_RESOLUTION as u64)? as u32;
                let region = mesh_region(a)?;
                out(a, OutputKind::Mesh { resolution, region }, "ply")
            },
        ),
        output("grid_image", "The assignment's xy-grid visual check as PNG (NDC x, y as red, green).", |a| out(a, OutputKind::Grid, "png")),
        output("rays_image", "The assignment's ray-direction visual check as PNG (|direction| as RGB).", |a| out(a, OutputKind::Rays, "png")),
        output("sample_points", "The sample points along the first camera's rays, seen from the side, as PNG.", |a| out(a, OutputKind::SamplePoints, "png")),
        output("loss_curve", "The training loss per iteration as a PNG plot.", |a| out(a, OutputKind::LossCurve, "png")),
        output("psnr_curve", "Held-out PSNR of a training run against seconds of training, as a PNG plot (needs test views).", |a| out(a, OutputKind::PsnrCurve, "png")),
        output("comparison", "Every held-out view after training: truth | render | error (×4), one row each, as a PNG (needs test views).", |a| out(a, OutputKind::Comparison, "png")),
    ]
}

fn out(a: &Args, kind: OutputKind, ext: &str) -> Result<Value, Diag> {
    let (path, span) = a.string("path")?;
    let path = safe_output_path(&path, span)?;
    if path.extension().and_then(|e| e.to_str()) != Some(ext) {
        return Err(value_error(
            span,
            format!("this output is written as .{ext}"),
            format!("not a .{ext} name"),
            format!("name the file `something.{ext}`"),
        ));
    }
    Ok(Value::Output(Arc::new(Output {
        kind,
        path,
        span: a.span,
    })))
}

fn mesh_region(a: &Args) -> Result<MeshRegion, Diag> {
    let (v, span) = a.get("bounds");
    let wrong = || {
        value_error(
            span,
            "`bounds` is \"auto\" or two corners",
            "not a region",
            "write `bounds: [[-1, -1, -1], [1, 1, 1]]` (lower and upper corner) or leave it out",
        )
    };
    match v {
        Value::Str(s) if &**s == "auto" => Ok(MeshRegion::Auto),
        Value::List(items) if items.len() == 2 => {
            let corner = |v: &Value| -> Result<[f64; 3], Diag> {
                let p = v.as_vec3().ok_or_else(wrong)?.to_array();
                for x in p {
                    f32_range(x, span, "bounds")?;
                }
                Ok(p)
            };
            let (min, max) = (corner(&items[0])?, corner(&items[1])?);
            if (0..3).any(|k| min[k] >= max[k]) {
                return Err(value_error(
                    span,
                    "the region is empty",
                    "the second corner is not above the first on every axis",
                    "give the lower corner first: `[[x0, y0, z0], [x1, y1, z1]]` with x0 < x1, y0 < y1, z0 < z1",
                ));
            }
            Ok(MeshRegion::Box { min, max })
        }
        _ => Err(wrong()),
    }
}
