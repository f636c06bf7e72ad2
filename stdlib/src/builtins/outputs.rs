//! What statements write: images, GIFs, meshes, data sets, figures and
//! plots of training.

use super::*;

/// Finest mesh grid: a billion evaluations, planes of a million points.
pub const MAX_MESH_RESOLUTION: u32 = 1024;
/// Highest frame rate of a `video`.
pub const MAX_VIDEO_FPS: f64 = 1000.0;
/// Most points of a point cloud (16 bytes each in memory, 15 in the file).
pub const MAX_CLOUD_POINTS: u64 = 10_000_000;

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
        func(
            "video",
            "All views as an H.264 MP4 video that every player plays, encoded by `ffmpeg` (the one named by the environment variable `SDFL_FFMPEG`, else the first on `PATH`). Where none is found, or it fails, the views are written as the animated GIF of the same name (`.gif`) instead, and the run says so in a warning.",
            vec![
                req("path", Type::Str, "file name inside the output directory (.mp4; its .gif name is kept for the fallback)"),
                opt("fps", Type::Number, "24", "frames per second (above 0, at most 1000)"),
            ],
            OUTPUT,
            |a| {
                let fps = a.positive("fps")?;
                if fps > MAX_VIDEO_FPS {
                    return Err(value_error(
                        a.get("fps").1,
                        format!("{} frames per second is more than a video holds", sdfl_lang::fmt_num(fps)),
                        format!("above {}", sdfl_lang::fmt_num(MAX_VIDEO_FPS)),
                        "players show 24 to 60 frames a second; write e.g. `fps: 30`",
                    ));
                }
                out(a, OutputKind::Video { fps }, "mp4")
            },
        ),
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
                opt("alpha", Type::Bool, "true", "images keep the hit mask as alpha; `false` writes RGB images whose background is the scene's, as a camera records them"),
                opt("llff_bounds", Type::list(Type::Number), "[]", "`[near, far]`: also write LLFF's layout for forward-facing scenes (`poses_bounds.npy` with these depth bounds for every frame, and `images/` in view order), which `capture(..., format: \"llff\")` and the original NeRF's code read; needs one centred pinhole camera for all views"),
            ],
            OUTPUT,
            |a| {
                let (path, span) = a.string("path")?;
                let path = safe_output_path(&path, span)?;
                let test_views = a.count("test_views", 0, MAX_VIEWS as u64)? as usize;
                let seed = a.count("seed", 0, u32::MAX as u64)?;
                let alpha = !matches!(a.get("alpha").0, Value::Bool(false));
                let bounds: Vec<f64> = match a.get("llff_bounds").0 {
                    Value::List(items) => items.iter().map(|v| if let Value::Number(x) = v { *x } else { f64::NAN }).collect(),
                    _ => vec![f64::NAN],
                };
                let llff_bounds = match bounds.as_slice() {
                    [] => None,
                    &[near, far] if near > 0.0 && far > near && far.is_finite() => Some([near, far]),
                    _ => {
                        return Err(value_error(
                            a.get("llff_bounds").1,
                            "LLFF's depth bounds are two numbers, 0 < near < far",
                            "not [near, far]",
                            "write the nearest and farthest depth the cameras see, e.g. `llff_bounds: [2, 40]`",
                        ))
                    }
                };
                Ok(Value::Output(Arc::new(Output { kind: OutputKind::Dataset { test_views, seed, alpha, llff_bounds }, path, span: a.span })))
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
        func(
            "density_mesh",
            "A radiance field's surface where its density reaches `level` (for the opacity form, its per-sample opacity), as a binary PLY triangle mesh with normals (pointing to lower density) and vertex colours (the field's colour seen along the reversed normal): surface nets on a grid, as nerfstudio's `ns-export`. Of a `volume` field or a trained NeRF or SDF field.",
            vec![
                req("path", Type::Str, "file name inside the output directory (.ply)"),
                opt("level", Type::Number, "10", "the density (per unit length) the surface is drawn at (> 0)"),
                opt("resolution", Type::Number, "128", "grid cells along the region's longest side (8 to 1024)"),
                opt(
                    "bounds",
                    Type::OneOf(vec![Type::Str, Type::list(Type::Vec3)]),
                    "\"auto\"",
                    "the region: `[[x0, y0, z0], [x1, y1, z1]]`, or \"auto\": a hash grid's or occupancy grid's box, an SDF field's bounds",
                ),
            ],
            OUTPUT,
            |a| {
                let level = a.positive("level")?;
                f32_range(level, a.get("level").1, "level")?;
                let resolution = a.count("resolution", 8, MAX_MESH_RESOLUTION as u64)? as u32;
                let region = mesh_region(a)?;
                out(a, OutputKind::DensityMesh { level, resolution, region }, "ply")
            },
        ),
        func(
            "point_cloud",
            "Points where rays of the training cameras (a `volume`'s cameras) end: at the expected depth over the accumulated opacity, coloured by the rendered colour over the opacity, kept where the opacity reaches `min_opacity` inside `crop`; a binary PLY point cloud with normals (fitted to each point's 16 nearest, facing where the density falls) and colours, as nerfstudio's `ns-export pointcloud`. Rays go through seeded random pixels until `points` are kept or four times as many rays were cast (a tight crop may keep fewer).",
            vec![
                req("path", Type::Str, "file name inside the output directory (.ply)"),
                opt("points", Type::Number, "100000", "points to keep (1 to 10 000 000)"),
                opt("min_opacity", Type::Number, "0.5", "accumulated opacity a ray needs for its point (0 to 1)"),
                opt(
                    "crop",
                    Type::OneOf(vec![Type::Str, Type::list(Type::Vec3)]),
                    "\"auto\"",
                    "which points are kept by where they are: `[[x0, y0, z0], [x1, y1, z1]]` in the data's frame, \"none\", or \"auto\": the object's region (an unbounded scene's inner box, else the field's hash grid or occupancy grid box)",
                ),
            ],
            OUTPUT,
            |a| {
                let points = a.count("points", 1, MAX_CLOUD_POINTS)? as u32;
                let min_opacity = opacity(a)?;
                let crop = match a.get("crop").0 {
                    Value::Str(s) if &**s == "none" => CloudCrop::None,
                    _ => match region(a, "crop")? {
                        MeshRegion::Auto => CloudCrop::Auto,
                        MeshRegion::Box { min, max } => CloudCrop::Box { min, max },
                    },
                };
                out(a, OutputKind::PointCloud { points, min_opacity, crop }, "ply")
            },
        ),
        func(
            "raw_depth",
            "Depth per view as a float32 `.npy` array of rows × columns (numpy's `np.load`): the expected depth along the ray divided by the accumulated opacity (distance from the camera centre along the ray, in the data's units: a normalised capture's depths are scaled back, as its meshes are moved back), NaN where the opacity is below `min_opacity`.",
            vec![
                req("path", Type::Str, "file name inside the output directory (.npy)"),
                opt("min_opacity", Type::Number, "0.5", "accumulated opacity a pixel needs for a depth (0 to 1)"),
            ],
            OUTPUT,
            |a| {
                let min_opacity = opacity(a)?;
                out(a, OutputKind::RawDepth { min_opacity }, "npy")
            },
        ),
        func(
            "depth_map",
            "Depth per view (as `raw_depth`) colour-mapped, beside a colour bar whose axis is titled \"depth (data units)\", as PNG; `range` in the same units; pixels below `min_opacity` black.",
            vec![
                req("path", Type::Str, "file name inside the output directory (.png)"),
                opt("colormap", Type::Str, "\"turbo\"", "turbo, viridis, inferno, magma, plasma or cividis"),
                opt(
                    "range",
                    Type::OneOf(vec![Type::Str, Type::list(Type::Number)]),
                    "\"auto\"",
                    "`[near, far]`: the depths at the colour map's ends (fixed across views), or \"auto\": each view's own range",
                ),
                opt("min_opacity", Type::Number, "0.5", "accumulated opacity a pixel needs for a depth (0 to 1)"),
            ],
            OUTPUT,
            |a| {
                let colormap = colormap(a)?;
                let range = depth_range(a)?;
                let min_opacity = opacity(a)?;
                out(a, OutputKind::DepthMap { colormap, range, min_opacity }, "png")
            },
        ),
        output("grid_image", "The assignment's xy-grid visual check as PNG (NDC x, y as red, green).", |a| out(a, OutputKind::Grid, "png")),
        output("rays_image", "The assignment's ray-direction visual check as PNG (|direction| as RGB).", |a| out(a, OutputKind::Rays, "png")),
        output("sample_points", "The sample points along the first camera's rays (16 across the image, every depth), as a square PNG chart (twice the image's side, 256 to 1024 pixels): world axes, the frustum, the eye, points coloured by depth, turned so the rays are seen from the side.", |a| out(a, OutputKind::SamplePoints, "png")),
        output("loss_curve", "The training loss per iteration as a PNG plot.", |a| out(a, OutputKind::LossCurve, "png")),
        output("psnr_curve", "Held-out PSNR of a training run against seconds of training, as a PNG plot (needs test views).", |a| out(a, OutputKind::PsnrCurve, "png")),
        output("comparison", "The first held-out views (up to 8) after training: truth | render | error (×4), one row each, as a PNG (needs test views; every view is scored).", |a| out(a, OutputKind::Comparison, "png")),
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
    region(a, "bounds")
}

/// The region argument `name`: "auto" or two corners.
fn region(a: &Args, name: &str) -> Result<MeshRegion, Diag> {
    let (v, span) = a.get(name);
    let wrong = || {
        let none = if name == "crop" { ", \"none\"" } else { "" };
        value_error(
            span,
            format!("`{name}` is \"auto\"{none} or two corners"),
            "not a region",
            format!("write `{name}: [[-1, -1, -1], [1, 1, 1]]` (lower and upper corner) or leave it out"),
        )
    };
    match v {
        Value::Str(s) if &**s == "auto" => Ok(MeshRegion::Auto),
        Value::List(items) if items.len() == 2 => {
            let corner = |v: &Value| -> Result<[f64; 3], Diag> {
                let p = v.as_vec3().ok_or_else(wrong)?.to_array();
                for x in p {
                    f32_range(x, span, name)?;
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

/// `min_opacity`: an accumulated opacity in [0, 1].
fn opacity(a: &Args) -> Result<f64, Diag> {
    let x = a.number("min_opacity")?;
    if !(0.0..=1.0).contains(&x) {
        return Err(value_error(
            a.get("min_opacity").1,
            format!(
                "`min_opacity` is an accumulated opacity from 0 to 1, got {}",
                sdfl_lang::fmt_num(x)
            ),
            "out of range",
            "use e.g. `min_opacity: 0.5` (0 keeps every ray)",
        ));
    }
    Ok(x)
}

fn colormap(a: &Args) -> Result<Colormap, Diag> {
    let (name, span) = a.string("colormap")?;
    Colormap::ALL
        .into_iter()
        .find(|c| c.name() == &*name)
        .ok_or_else(|| {
            value_error(
                span,
                format!("unknown colour map `{name}`"),
                "not a colour map",
                "use \"turbo\", \"viridis\", \"inferno\", \"magma\", \"plasma\" or \"cividis\"",
            )
        })
}

fn depth_range(a: &Args) -> Result<Option<[f64; 2]>, Diag> {
    let (v, span) = a.get("range");
    let wrong = || {
        value_error(
            span,
            "`range` is \"auto\" or `[near, far]` with 0 ≤ near < far",
            "not a depth range",
            "write `range: [2, 6]` (depths at the colour map's ends) or leave it out",
        )
    };
    match v {
        Value::Str(s) if &**s == "auto" => Ok(None),
        Value::List(items) if items.len() == 2 => {
            let n = |v: &Value| match v {
                Value::Number(x) => Ok(*x),
                _ => Err(wrong()),
            };
            let (lo, hi) = (n(&items[0])?, n(&items[1])?);
            f32_range(lo, span, "range")?;
            f32_range(hi, span, "range")?;
            if !(lo >= 0.0 && lo < hi) {
                return Err(wrong());
            }
            Ok(Some([lo, hi]))
        }
        _ => Err(wrong()),
    }
}
