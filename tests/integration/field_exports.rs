//! Exports from radiance fields through the language and the binary:
//! density meshes at a level, coloured point clouds, raw depth (.npy) and
//! colour-mapped depth, from a volume render of an analytic field and from
//! trained models; their diagnostics.

use std::fs;

use crate::common::*;

/// A VolSDF sphere of radius 0.6 (sharp: β = 0.01) seen from four sides.
const SPHERE: &str = r#"
let ball = paint(sphere(0.6), constant([0.2, 0.6, 0.9]))
render field {
  scene: volsdf(ball, alpha: 100, beta: 0.01),
  camera: [look_at([0, 0, 3], focal: 4), look_at([3, 0, 0], focal: 4), look_at([0, 3, 0.1], focal: 4), look_at([-2, -2, 1], focal: 4)],
  size: [32, 24],
  sampler: stratified(samples: 256, near: 1, far: 5),
  outputs: [
    density_mesh("level.ply", level: 50, resolution: 48),
    point_cloud("cloud.ply", points: 2000, min_opacity: 0.9),
    raw_depth("depth.npy"),
    depth_map("depth.png", colormap: "viridis", range: [2, 3]),
  ],
}
"#;

/// The header of a PLY file and the offset of its body.
fn ply_header(bytes: &[u8]) -> (String, usize) {
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .expect("a PLY header")
        + 11;
    (String::from_utf8(bytes[..end].to_vec()).unwrap(), end)
}

fn count(header: &str, element: &str) -> usize {
    header
        .lines()
        .find_map(|l| l.strip_prefix(&format!("element {element} ")))
        .expect("the element is declared")
        .parse()
        .unwrap()
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn radius(b: &[u8], at: usize) -> f32 {
    (0..3)
        .map(|a| f32_at(b, at + 4 * a).powi(2))
        .sum::<f32>()
        .sqrt()
}

#[test]
fn a_field_exports_its_surface_points_and_depth() {
    let dir = case_dir("field_exports_sphere");
    let file = dir.join("sphere.sdfl");
    fs::write(&file, SPHERE).unwrap();
    let out = dir.join("out");
    let o = run_into(&dir, &file, &out, &[]);
    assert_outcome("sphere exports", &o, Expect::Ok);

    // The mesh: float x y z nx ny nz, uchar r g b; vertices on the sphere
    // (σ = α/2 at the surface), coloured by the paint.
    let b = fs::read(out.join("level.ply")).unwrap();
    let (h, body) = ply_header(&b);
    assert!(h.contains("format binary_little_endian 1.0"));
    assert!(h.contains("property uchar red"));
    let (nv, nf) = (count(&h, "vertex"), count(&h, "face"));
    assert!(nv > 1000 && nf > 2000, "{nv} vertices, {nf} faces");
    assert_eq!(b.len() - body, nv * 27 + nf * 13);
    for k in 0..nv {
        let at = body + 27 * k;
        let r = radius(&b, at);
        assert!((r - 0.6).abs() < 3e-3, "vertex {k} at radius {r}");
        let c = &b[at + 24..at + 27];
        assert_eq!(c, [51, 153, 230], "vertex {k} colour");
    }
    // Meshes read back by the data reader (the PLY any tool reads).
    let pts = sdfl_runtime::data::points::read_points(&out.join("level.ply")).unwrap();
    assert_eq!(pts.len(), nv);

    // The cloud: float x y z, float nx ny nz, uchar r g b; on the surface,
    // its colour, the outward normal.
    let b = fs::read(out.join("cloud.ply")).unwrap();
    let (h, body) = ply_header(&b);
    let n = count(&h, "vertex");
    assert_eq!(n, 2000);
    assert_eq!(b.len() - body, n * 27);
    let mut mean_along = 0.0;
    for k in 0..n {
        let at = body + 27 * k;
        let r = radius(&b, at);
        assert!((r - 0.6).abs() < 0.02, "point {k} at radius {r}");
        let f = |i: usize| f32::from_le_bytes(b[at + 4 * i..at + 4 * i + 4].try_into().unwrap());
        let along = (0..3).map(|a| f(a) * f(3 + a)).sum::<f32>() / r;
        // Fitted to 16 random neighbours: within 30° everywhere (0.997 on
        // average here), and never inwards.
        assert!(along > 0.85, "point {k}: normal along the radius {along}");
        mean_along += along as f64 / n as f64;
        let c = &b[at + 24..at + 27];
        assert!(
            c.iter()
                .zip([51u8, 153, 230])
                .all(|(a, b)| a.abs_diff(b) <= 1),
            "point {k} colour {c:?}"
        );
    }
    assert!(
        mean_along > 0.99,
        "mean normal along the radius {mean_along}"
    );

    // Raw depth: one .npy of rows × columns per view, round trip through
    // the reader; the centre pixel of the first view looks at the sphere
    // head on from 3: depth 2.4; corners miss: NaN.
    for k in 0..4 {
        let p = out.join(format!("depth_{k:02}.npy"));
        let a = sdfl_runtime::data::npy::parse_f32(&fs::read(&p).unwrap()).unwrap();
        assert_eq!(a.shape, vec![24, 32]);
        assert!(a.data[0].is_nan(), "a corner misses");
        let finite: Vec<f32> = a.data.iter().copied().filter(|d| d.is_finite()).collect();
        assert!(finite.len() > 100);
        assert!(finite.iter().all(|d| (2.3..3.0).contains(d)));
    }
    let a =
        sdfl_runtime::data::npy::parse_f32(&fs::read(out.join("depth_00.npy")).unwrap()).unwrap();
    let centre = [
        a.data[11 * 32 + 15],
        a.data[11 * 32 + 16],
        a.data[12 * 32 + 15],
        a.data[12 * 32 + 16],
    ];
    for d in centre {
        assert!((d - 2.4).abs() < 0.02, "centre depth {d}");
    }

    // Colour-mapped depth: the image beside its colour bar.
    let img = image::open(out.join("depth_00.png")).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (32 + 150, 200));
    assert_eq!(img.get_pixel(0, 0).0, [0, 0, 0], "no depth: black");
    let c = img.get_pixel(16, 12).0;
    // Depth 2.4 in [2, 3] on viridis: blue-green, not an end colour.
    assert!(c[2] > c[0] && c != [68, 1, 84], "{c:?}");
}

/// A tiny NeRF trained briefly, then exported (its GIF's renders serve
/// its depth outputs too).
const NERF: &str = r#"
let cams = orbit(radius: 2.5, up: [0, 1, 0], focal: 1, views: 6)
let truth = volsdf(sphere(radius: 0.6), alpha: 10, beta: 0.05)
train tiny {
  model: nerf(layers: 1, width: 16, skips: [], color_width: 16, density: "exp", position: hashgrid(levels: 4, features: 2, log2_table: 10, min_res: 4, max_res: 32, min: [-1, -1, -1], max: [1, 1, 1])),
  data: render_views(truth, cameras: cams, size: [16, 16], sampler: stratified(samples: 32, near: 1, far: 5)),
  sampler: stratified(samples: 24, near: 1, far: 5),
  rays: 128,
  iterations: 20,
  views: orbit(radius: 2.5, up: [0, 1, 0], focal: 1, views: 2),
  size: [12, 10],
  after: [density_mesh("nerf.ply", level: 1, resolution: 16), point_cloud("nerf_cloud.ply", points: 50, min_opacity: 0), gif("nerf.gif"), raw_depth("nerf_depth.npy", min_opacity: 0), depth_map("nerf_depth.png")],
}
"#;

#[test]
fn a_trained_nerf_writes_its_exports() {
    let dir = case_dir("field_exports_nerf");
    let file = dir.join("nerf.sdfl");
    fs::write(&file, NERF).unwrap();
    let out = dir.join("out");
    let o = run_into(&dir, &file, &out, &[]);
    assert_outcome("nerf exports", &o, Expect::Ok);
    let b = fs::read(out.join("nerf.ply")).unwrap();
    let (h, body) = ply_header(&b);
    assert_eq!(
        b.len() - body,
        count(&h, "vertex") * 27 + count(&h, "face") * 13
    );
    let b = fs::read(out.join("nerf_cloud.ply")).unwrap();
    let (h, body) = ply_header(&b);
    // Every ray keeps a point at opacity 0 (unless it has none at all).
    let n = count(&h, "vertex");
    assert!(n <= 50);
    assert_eq!(b.len() - body, n * 27);
    for k in 0..2 {
        let a = sdfl_runtime::data::npy::parse_f32(
            &fs::read(out.join(format!("nerf_depth_{k:02}.npy"))).unwrap(),
        )
        .unwrap();
        assert_eq!(a.shape, vec![10, 12]);
        // Depth lies within the sampled range wherever it is defined.
        assert!(a
            .data
            .iter()
            .filter(|d| d.is_finite())
            .all(|d| (1.0..=5.0).contains(d)));
        let img = image::open(out.join(format!("nerf_depth_{k:02}.png"))).unwrap();
        assert_eq!((img.width(), img.height()), (12 + 150, 200));
    }
}

fn refused(name: &str, src: &str, says: &str) {
    let dir = case_dir(name);
    let file = dir.join(format!("{name}.sdfl"));
    fs::write(&file, src).unwrap();
    let o = sdfl(&dir, &["check", file.to_str().unwrap()]);
    assert_outcome(name, &o, Expect::Error);
    assert!(o.stderr.contains(says), "{name}: {}", head(&o.stderr));
}

#[test]
fn field_exports_are_refused_where_there_is_no_density() {
    refused(
        "export_of_a_scene",
        r#"render s { scene: sphere(0.5), camera: look_at([0, 0, 3]), outputs: [point_cloud("c.ply")] }"#,
        "needs a radiance field's density",
    );
    refused(
        "export_unbounded_nerf",
        r#"let cams = orbit(radius: 2.5, up: [0, 1, 0], focal: 1, views: 4)
train t { model: nerf(position: harmonic(freqs: 2)), data: render_views(volsdf(sphere(0.5)), cameras: cams, size: [8, 8]), iterations: 1, after: [density_mesh("m.ply")] }"#,
        "no bounds of its own",
    );
    refused(
        "export_bad_colormap",
        r#"render s { scene: volsdf(sphere(0.5)), camera: look_at([0, 0, 3]), outputs: [depth_map("d.png", colormap: "jet")] }"#,
        "unknown colour map `jet`",
    );
    refused(
        "export_bad_opacity",
        r#"render s { scene: volsdf(sphere(0.5)), camera: look_at([0, 0, 3]), outputs: [raw_depth("d.npy", min_opacity: 1.5)] }"#,
        "`min_opacity` is an accumulated opacity",
    );
    refused(
        "export_bad_range",
        r#"render s { scene: volsdf(sphere(0.5)), camera: look_at([0, 0, 3]), outputs: [depth_map("d.png", range: [3, 2])] }"#,
        "`range` is",
    );
    refused(
        "export_wrong_extension",
        r#"render s { scene: volsdf(sphere(0.5)), camera: look_at([0, 0, 3]), outputs: [raw_depth("d.png")] }"#,
        "written as .npy",
    );
    refused(
        "export_too_many_points",
        r#"render s { scene: volsdf(sphere(0.5)), camera: look_at([0, 0, 3]), outputs: [point_cloud("c.ply", points: 1e9)] }"#,
        "`points` must be a whole number",
    );
}

#[test]
fn the_plan_counts_field_exports() {
    let dir = case_dir("field_exports_plan");
    let file = dir.join("plan.sdfl");
    let small = SPHERE.replace("points: 2000", "points: 10");
    let big = SPHERE.replace("points: 2000", "points: 10000000");
    let total = |src: &str| -> (f64, String) {
        fs::write(&file, src).unwrap();
        let o = sdfl(&dir, &["plan", file.to_str().unwrap()]);
        assert_outcome("plan", &o, Expect::Ok);
        let text = fs::read_to_string(dir.join("stdout.txt")).unwrap();
        let n = text
            .lines()
            .find_map(|l| l.trim().strip_prefix("work           at most "))
            .and_then(|l| l.split_whitespace().next())
            .and_then(|n| n.parse().ok())
            .expect("the plan says its evaluations");
        (n, text)
    };
    let ((a, text), (b, _)) = (total(&small), total(&big));
    // Ten million points cast up to forty million rays of 256 samples.
    assert!(b - a > 0.9 * 4e7 * 256.0, "{a:e} → {b:e}");
    for line in [
        "density mesh   level.ply",
        "point cloud    cloud.ply",
        "depth export   depth.npy",
        "depth export   depth.png",
    ] {
        assert!(text.contains(line), "{line} in\n{text}");
    }
}

/// A trained model rendered again from other cameras: the checkpoint is
/// complete, so the run resumes at its last step, trains nothing and
/// writes the outputs of the new views (views are not part of the run's
/// fingerprint: the same model, data, sampler and optimiser).
#[test]
fn a_finished_run_renders_new_views_without_training() {
    use sdfl_runtime::jobs::{run_train_job, TrainOptions};
    let src = |views: &str| {
        NERF.replace(
            "views: orbit(radius: 2.5, up: [0, 1, 0], focal: 1, views: 2)",
            views,
        )
        .replace(
            "after: [",
            "checkpoint: \"tiny.ckpt\",\n  after: [gif(\"tiny.gif\"), ",
        )
    };
    let job = |views: &str| {
        let p = sdfl_stdlib::load(&sdfl_lang::SourceFile::new("t.sdfl", src(views))).unwrap();
        p.trains[0].clone()
    };
    let out = case_dir("field_exports_rerender");
    let run = |j: &sdfl_stdlib::value::TrainJob| {
        run_train_job(
            j,
            &out,
            &out,
            None,
            TrainOptions { restart: false },
            &|_| {},
        )
        .unwrap()
    };
    let first = run(&job(
        "views: orbit(radius: 2.5, up: [0, 1, 0], focal: 1, views: 2)",
    ));
    assert_eq!((first.iterations, first.resumed_from), (20, None));
    let read =
        || sdfl_runtime::train::checkpoint::Checkpoint::read(&out.join("tiny.ckpt")).unwrap();
    let ck = read();
    let depth0 = fs::read(out.join("nerf_depth_00.npy")).unwrap();

    // Three new cameras, higher up: rendered, not trained.
    let again = run(&job(
        "views: [look_at([0, 2, 2], focal: 1.2), look_at([2, 1, 0], focal: 1.2), look_at([-1, 1, 2], focal: 1.2)]",
    ));
    assert_eq!((again.iterations, again.resumed_from), (20, Some(20)));
    // A NeRF counts the samples its steps evaluate; no step ran now.
    assert!(first.samples_per_ray.is_some());
    assert!(
        again.samples_per_ray.is_none(),
        "{:?}",
        again.samples_per_ray
    );
    // The same weights and steps: nothing was trained.
    let after = read();
    assert_eq!(after.step, ck.step);
    assert_eq!(after.losses, ck.losses);
    assert_eq!(format!("{:?}", after.params), format!("{:?}", ck.params));
    for k in 0..3 {
        assert!(out.join(format!("nerf_depth_{k:02}.npy")).exists());
        assert!(out.join(format!("nerf_depth_{k:02}.png")).exists());
    }
    // The new first view is another camera: another depth image.
    assert_ne!(fs::read(out.join("nerf_depth_00.npy")).unwrap(), depth0);
    let gif = image::codecs::gif::GifDecoder::new(std::io::Cursor::new(
        fs::read(out.join("tiny.gif")).unwrap(),
    ))
    .unwrap();
    use image::AnimationDecoder;
    assert_eq!(gif.into_frames().count(), 3);
}

/// `training_loop(...)` as `views` is made from the training cameras when
/// the run has read them: the same cameras as `camera_loop` through them
/// written out in the file.
#[test]
fn a_training_loop_is_the_loop_through_the_training_cameras() {
    let depth = |views: &str, name: &str| {
        let dir = case_dir(name);
        let file = dir.join("t.sdfl");
        let src = NERF.replace(
            "views: orbit(radius: 2.5, up: [0, 1, 0], focal: 1, views: 2)",
            views,
        );
        fs::write(&file, src).unwrap();
        let out = dir.join("out");
        let o = run_into(&dir, &file, &out, &[]);
        assert_outcome(name, &o, Expect::Ok);
        (0..5)
            .map(|k| fs::read(out.join(format!("nerf_depth_{k:02}.npy"))).unwrap())
            .collect::<Vec<_>>()
    };
    let at_run = depth(
        "views: training_loop(frames: 5, keyframes: 3)",
        "field_exports_loop_run",
    );
    let in_file = depth(
        "views: camera_loop(cams, frames: 5, keyframes: 3)",
        "field_exports_loop_file",
    );
    assert_eq!(at_run, in_file);
    // Another path gives other pictures (the comparison can fail).
    let other = depth(
        "views: camera_loop(cams, frames: 5, keyframes: 2)",
        "field_exports_loop_other",
    );
    assert_ne!(at_run, other);
}

/// A trained NeRF's depth exports come from its renders (empty space
/// skipped, opaque rays stopped), and agree with a march of every sample:
/// the same depths and opacities, to the early stop's 1e-4 of light.
#[test]
fn a_nerfs_rendered_ray_ends_match_a_march_of_every_sample() {
    use sdfl_runtime::export::render_ends;
    use sdfl_runtime::volume::{ImageSize, Stratified};
    let program =
        sdfl_stdlib::load(&sdfl_lang::SourceFile::new("nerf.sdfl", NERF.to_string())).unwrap();
    let job = &program.trains[0];
    let field = sdfl_runtime::jobs::trained_field(job, job.iterations, &[]).unwrap();
    let values = field.initial();
    let s = &job.sampler;
    let strat = Stratified::new(s.samples, s.near as f32, s.far as f32).unwrap();
    let size = ImageSize {
        width: 12,
        height: 10,
    };
    let radiance = field.radiance(&values).unwrap();
    for cam in &job.views {
        assert!(field.renders_opacity());
        let view = field.render_view(&values, cam, size, true).unwrap();
        let rendered = view.ray_ends().expect("a NeRF renders opacity");
        let marched = render_ends(&*radiance, cam, size, &strat, s.last_interval).unwrap();
        assert_eq!(rendered.len(), marched.len());
        for (r, m) in rendered.iter().zip(&marched) {
            assert!((r.opacity - m.opacity).abs() <= 2e-4, "{r:?} {m:?}");
            assert!(
                (r.depth - m.depth).abs() <= 2e-3 * m.depth.max(1.0),
                "{r:?} {m:?}"
            );
        }
        // Not all empty: the comparison has something to compare.
        assert!(marched.iter().any(|m| m.opacity > 0.01));
    }
}
