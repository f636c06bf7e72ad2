//! Self-rendered ground truth: Phong highlights, sphere-traced data sets
//! with held-out views, and NeRF-synthetic data sets written and read back.

use std::path::{Path, PathBuf};

use glam::DVec3;
use sdfl_lang::SourceFile;
use sdfl_runtime::data::nerf_synthetic::{read_split, read_transforms};
use sdfl_runtime::jobs::{load_views, Views};
use sdfl_runtime::render::{render_view, run_job, Needs, RunOptions};
use sdfl_runtime::Lowered;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::value::Dataset;
use sdfl_stdlib::Program;

fn load(src: &str) -> Program {
    sdfl_stdlib::load(&SourceFile::new("views.sdfl", src)).unwrap_or_else(|e| panic!("{e:?}"))
}

fn load_err(src: &str) -> String {
    match sdfl_stdlib::load(&SourceFile::new("views.sdfl", src)) {
        Ok(_) => panic!("expected diagnostics for {src}"),
        Err(e) => format!("{e:?}"),
    }
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-views-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The data set of the first `train` statement.
fn dataset(p: &Program) -> &Dataset {
    &p.trains[0].data
}

/// Every pixel's ray of `a` and `b` agree within `tol`.
fn assert_same_rays(a: &Camera, b: &Camera, (w, h): (u32, u32), tol: f64) {
    assert!((a.eye - b.eye).length() < tol, "{a:?} vs {b:?}");
    for j in 0..h {
        for i in 0..w {
            let (ax, ay) = a.pixel_ndc(i, j, w, h);
            let (bx, by) = b.pixel_ndc(i, j, w, h);
            let d = (a.ray_direction(ax, ay) - b.ray_direction(bx, by)).length();
            assert!(d < tol, "pixel ({i}, {j}): rays differ by {d}");
        }
    }
}

#[test]
fn a_phong_sphere_is_brightest_near_the_mirror_direction() {
    let src = |specular: f64| {
        format!(
            "render r {{ scene: sphere(1), camera: look_at(eye: [0, 0, -3], focal: 1.5), size: [64, 64], \
             material: phong(albedo: [0.2, 0.2, 0.2], lights: [light(direction: [1, 0.3, -1])], ambient: 0.1, specular: {specular}, shininess: 64), \
             outputs: [image(\"x.png\")] }}"
        )
    };
    let render = |specular: f64| {
        let p = load(&src(specular));
        let job = &p.renders[0];
        let scene = Lowered::new(&job.scene, Default::default());
        let needs = Needs {
            color: true,
            depth: false,
            normals: false,
            mask: false,
        };
        let v = render_view(&scene, job, &job.cameras[0], (64, 64), needs, &|_| {});
        (v.color.unwrap(), job.cameras[0])
    };
    // Unsaturated (0.2 + 0.5 < 1): one brightest pixel, not a clamped blob.
    let (shiny, cam) = render(0.5);
    let (matte, _) = render(0.0);
    // The highlight's surface point: the normal halfway between the light
    // and the direction back to the eye (a fixed point, as the view
    // direction depends on the point).
    let l = DVec3::new(1.0, 0.3, -1.0).normalize();
    let mut n = DVec3::new(0.0, 0.0, -1.0);
    for _ in 0..50 {
        let view = (n - cam.eye).normalize();
        n = (l - view).normalize();
    }
    let c = cam.to_camera(n);
    let (xn, yn) = (cam.focal * c.x / c.z, cam.focal * c.y / c.z);
    // Corner pixel centres: x = 1 - 2i/(W-1).
    let (ei, ej) = ((1.0 - xn) * 63.0 / 2.0, (1.0 - yn) * 63.0 / 2.0);
    let lum = |img: &[u8], k: usize| img[3 * k..3 * k + 3].iter().map(|x| *x as u32).sum::<u32>();
    let brightest = (0..64 * 64).max_by_key(|k| lum(&shiny, *k)).unwrap();
    let (bi, bj) = ((brightest % 64) as f64, (brightest / 64) as f64);
    assert!(
        (bi - ei).abs() <= 1.5 && (bj - ej).abs() <= 1.5,
        "brightest pixel ({bi}, {bj}), mirror direction at ({ei:.2}, {ej:.2})"
    );
    // The highlight is specular: it is absent without `specular`.
    assert!(lum(&shiny, brightest) > lum(&matte, brightest) + 3 * 100);
    // Off-centre towards the light, which is at world +x: NDC +x, the
    // image's left.
    assert!(ei < 29.0, "{ei}");
}

#[test]
fn held_out_views_are_seeded_disjoint_and_cover_the_cameras() {
    let src = |seed: u32| {
        format!(
            "let cams = sphere_views(views: 10, radius: 3)\n\
             train t {{ model: sdf_volume(sphere(param(0.8))), iterations: 1, \
             data: render_views(sphere(0.5), cameras: cams, size: [8, 8], test_views: 3, split_seed: {seed}) }}"
        )
    };
    let a = load(&src(7));
    let test = dataset(&a).test_views().to_vec();
    assert_eq!(test, dataset(&load(&src(7))).test_views(), "deterministic");
    assert_eq!(test.len(), 3);
    assert!(test.windows(2).all(|w| w[0] < w[1]) && test.iter().all(|k| *k < 10));
    let others: Vec<Vec<usize>> = (0..8)
        .map(|s| dataset(&load(&src(s))).test_views().to_vec())
        .collect();
    assert!(others.iter().any(|o| *o != test), "the seed matters");

    let views: Views = load_views(dataset(&a), Path::new(".")).unwrap();
    assert_eq!((views.train.len(), views.test.len()), (7, 3));
    let cams = dataset(&a).cameras();
    // Disjoint and covering: every camera is in exactly one of the two.
    for (k, c) in cams.iter().enumerate() {
        let in_test = views.test.iter().filter(|v| v.camera == *c).count();
        let in_train = views.train.iter().filter(|v| v.camera == *c).count();
        assert_eq!(in_test + in_train, 1, "camera {k}");
        assert_eq!(in_test == 1, test.contains(&k), "camera {k}");
    }
}

#[test]
fn held_out_views_are_refused_when_none_would_be_left() {
    let e = load_err(
        "train t { model: sdf_volume(sphere(param(0.8))), data: render_views(sphere(), cameras: orbit(views: 4), test_views: 4) }",
    );
    assert!(e.contains("leaves no training view"), "{e}");
    let e = load_err(
        "train t { model: sdf_volume(sphere(param(0.8))), data: render_views(sdf_volume(sphere()), cameras: orbit(views: 4), material: [1, 0, 0]) }",
    );
    assert!(e.contains("does not apply to a field"), "{e}");
}

#[test]
fn phong_arguments_are_checked() {
    for (args, says) in [
        ("lights: []", "no lights"),
        ("shininess: 0", "must be positive"),
        ("specular: 2", "in 0..1"),
        ("lights: [light(direction: [0, 0, 0])]", "nonzero direction"),
        ("lights: [light(color: [2, 1, 1])]", "in 0..1"),
        ("albedo: phong()", "cannot itself depend on the view"),
    ] {
        let e = load_err(&format!(
            "render r {{ scene: sphere(), camera: look_at([0, 0, -3]), material: phong({args}), outputs: [image(\"x.png\")] }}"
        ));
        assert!(e.contains(says), "{args}: {e}");
    }
    // Volumes cannot use it: it needs normals.
    let e = load_err(
        "render r { scene: sdf_volume(sphere(), color: phong()), camera: look_at([0, 0, -3]), outputs: [image(\"x.png\")] }",
    );
    assert!(e.contains("normals"), "{e}");
}

/// A traced data set's pixels against the analytic silhouette of a sphere:
/// with `hit_tolerance: "absolute"` a pixel is lit exactly where the thin
/// ray through its centre meets the sphere; with "pixel" (a `render`'s
/// tolerance) rays passing within half a pixel's width hit too, so the
/// silhouette grows.
#[test]
fn an_absolute_tolerance_data_set_shows_the_exact_silhouette() {
    let lit = |tolerance: &str| -> (usize, usize) {
        let p = load(&format!(
            "let cams = orbit(radius: 3, up: [0, 1, 0], focal: 1.2, views: 3)\n\
             train t {{ model: sdf_volume(sphere(param(0.8))), iterations: 1, \
             data: render_views(sphere(0.5, center: [0.1, 0, 0]), cameras: cams, size: [48, 48], material: [1, 1, 1], \
             iterations: 256, hit_tolerance: \"{tolerance}\") }}"
        ));
        let views = load_views(dataset(&p), Path::new(".")).unwrap();
        let (mut lit, mut exact) = (0, 0);
        for v in &views.train {
            let cam = &v.camera;
            for (k, px) in v.image.colours().enumerate() {
                let (i, j) = ((k % 48) as u32, (k / 48) as u32);
                let (x, y) = cam.pixel_ndc(i, j, 48, 48);
                let d = cam.ray_direction(x, y).normalize();
                // Distance from the centre to the ray's line.
                let to_c = DVec3::new(0.1, 0.0, 0.0) - cam.eye;
                let miss = (to_c - d * to_c.dot(d)).length();
                exact += (miss < 0.5) as usize;
                lit += (px[0] > 0.5) as usize;
            }
        }
        (lit, exact)
    };
    let (absolute, exact) = lit("absolute");
    assert!(exact > 150, "{exact}");
    assert_eq!(absolute, exact, "absolute: the exact silhouette");
    let (pixel, _) = lit("pixel");
    assert!(
        pixel > exact + exact / 20,
        "pixel: {pixel} vs exact {exact}"
    );
    let e = load_err(
        "train t { model: sdf_volume(sphere(param(0.8))), data: render_views(sphere(), cameras: orbit(views: 4), hit_tolerance: \"exact\") }",
    );
    assert!(e.contains("unknown hit tolerance"), "{e}");
}

const TRACED: &str = "\
let scene = union(sphere(0.7), box(size: 0.5, center: [0.6, 0.4, 0]))
let mat = phong(albedo: rainbow(), lights: [light(direction: [1, 1, -1]), light(direction: [-1, 0, -1], color: [0.2, 0.2, 0.4])])
let cams = sphere_views(views: 4, radius: 3, up: [0, 1, 0], focal: 1.5)
render r { scene: scene, material: mat, camera: cams, size: [24, 20], background: [0.1, 0.2, 0.3], far: 8, outputs: [image(\"v.png\"), dataset(\"set\")] }
train t { model: sdf_volume(sphere(param(0.8))), iterations: 1,
          data: render_views(scene, cameras: cams, material: mat, size: [24, 20], background: [0.1, 0.2, 0.3], far: 8) }
";

#[test]
fn a_traced_data_set_is_exactly_the_render() {
    let p = load(TRACED);
    let out = temp("traced");
    run_job(&p.renders[0], &out, RunOptions::default(), &|_| {}).unwrap();
    let views = load_views(dataset(&p), Path::new(".")).unwrap();
    assert!(views.test.is_empty());
    assert_eq!(views.train.len(), 4);
    for (k, v) in views.train.iter().enumerate() {
        let png = image::open(out.join(format!("v_{k:02}.png")))
            .unwrap()
            .to_rgb8();
        assert_eq!((png.width(), png.height()), (24, 20));
        for (a, b) in png.pixels().zip(v.image.colours()) {
            assert_eq!(a.0.map(|x| x as f32 / 255.0), b, "view {k}");
        }
    }
}

#[test]
fn a_written_nerf_synthetic_data_set_reads_back_as_the_render() {
    let p = load(TRACED);
    let job = &p.renders[0];
    let out = temp("dataset");
    run_job(job, &out, RunOptions::default(), &|_| {}).unwrap();
    let bg = DVec3::new(0.1, 0.2, 0.3);
    let views = read_split(&out.join("set"), "train", bg).unwrap();
    assert_eq!(views.len(), 4);
    for (k, v) in views.iter().enumerate() {
        assert_same_rays(&job.cameras[k], &v.camera, (24, 20), 1e-5);
        let png = image::open(out.join(format!("v_{k:02}.png")))
            .unwrap()
            .to_rgb8();
        for (a, b) in png.pixels().zip(v.image.colours()) {
            // Hits are the colour itself; misses the background composited
            // (within 8-bit rounding of the background the image holds).
            for (x, y) in a.0.iter().zip(&b) {
                assert!(
                    (*x as f32 / 255.0 - y).abs() <= 0.5 / 255.0 + 1e-6,
                    "view {k}"
                );
            }
        }
    }
    // The same through the built-in, relative to the scene file's directory.
    let data = load(
        "train t { model: sdf_volume(sphere(param(0.8))), iterations: 1, data: nerf_synthetic(\"set\", background: [0.1, 0.2, 0.3]) }",
    );
    let again = load_views(dataset(&data), &out).unwrap();
    assert_eq!(again.train.len(), 4);
    assert_eq!(again.train[2].image, views[2].image);
    // A test split comes from its own file, never from the lone
    // transforms.json that stands in for the training split. (`dataset`
    // writes `transforms_test.json`, every view when none is held out: a
    // set without one is made here.)
    std::fs::remove_file(out.join("set/transforms_test.json")).unwrap();
    std::fs::remove_file(out.join("set/transforms_train.json")).unwrap();
    let split = |test: &str| {
        load(&format!(
            "train t {{ model: sdf_volume(sphere(param(0.8))), iterations: 1, data: nerf_synthetic(\"set\", test_split: \"{test}\") }}"
        ))
    };
    let e = load_views(dataset(&split("test")), &out)
        .unwrap_err()
        .to_string();
    assert!(e.contains("transforms_test.json"), "{e}");
    std::fs::copy(
        out.join("set/transforms.json"),
        out.join("set/transforms_test.json"),
    )
    .unwrap();
    let both = load_views(dataset(&split("test")), &out).unwrap();
    assert_eq!((both.train.len(), both.test.len()), (4, 4));
    assert_eq!(both.test[1].camera, views[1].camera);
}

#[test]
fn the_checked_in_fixture_matches_its_scene() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data");
    let src = std::fs::read_to_string(root.join("nerf_synthetic_tiny.sdfl")).unwrap();
    let p = load(&src);
    let job = &p.renders[0];
    let views = read_split(&root.join("nerf_synthetic_tiny"), "train", job.background).unwrap();
    assert_eq!(views.len(), 3);
    let scene = Lowered::new(&job.scene, Default::default());
    let needs = Needs {
        color: true,
        depth: false,
        normals: false,
        mask: true,
    };
    for (k, v) in views.iter().enumerate() {
        assert_same_rays(&job.cameras[k], &v.camera, (16, 16), 1e-5);
        let now = render_view(&scene, job, &job.cameras[k], (16, 16), needs, &|_| {});
        let (rgb, mask) = (now.color.unwrap(), now.mask.unwrap());
        assert!(now.hits > 20, "view {k} shows the scene");
        for (i, px) in v.image.colours().enumerate() {
            let want = if mask[i] == 255 {
                [0, 1, 2].map(|c| rgb[3 * i + c] as f32 / 255.0)
            } else {
                job.background.as_vec3().to_array()
            };
            for c in 0..3 {
                assert!(
                    (px[c] - want[c]).abs() <= 1.0 / 255.0 + 1e-6,
                    "view {k} pixel {i}"
                );
            }
        }
    }
}

#[test]
fn hostile_transforms_files_are_errors() {
    let d = temp("hostile");
    let frame =
        r#"{"file_path": "./r_0", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}"#;
    let cases: Vec<(&str, String, &str)> = vec![
        ("not_json", "{ not json".into(), "not valid JSON"),
        ("array", "[1, 2]".into(), "not a JSON object"),
        ("no_angle", format!(r#"{{"frames": [{frame}]}}"#), "camera_angle_x"),
        ("bad_angle", format!(r#"{{"camera_angle_x": 4, "frames": [{frame}]}}"#), "field of view"),
        ("no_frames", r#"{"camera_angle_x": 0.7}"#.into(), "missing `frames`"),
        ("empty", r#"{"camera_angle_x": 0.7, "frames": []}"#.into(), "0 frames"),
        ("huge_number", r#"{"camera_angle_x": 1e999, "frames": []}"#.into(), "JSON"),
        (
            "short_matrix",
            r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "a", "transform_matrix": [[1,0,0]]}]}"#.into(),
            "4x4",
        ),
        (
            "string_entry",
            r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "a", "transform_matrix": [[1,0,0,"x"],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}"#.into(),
            "non-finite",
        ),
        (
            "escape",
            r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "../../etc/passwd", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}]}"#.into(),
            "inside the data set",
        ),
        (
            "absolute",
            r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "/etc/passwd", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}]}"#.into(),
            "inside the data set",
        ),
        (
            "no_path",
            r#"{"camera_angle_x": 0.7, "frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}]}"#.into(),
            "file_path",
        ),
    ];
    for (name, text, says) in &cases {
        let path = d.join(format!("{name}.json"));
        std::fs::write(&path, text).unwrap();
        let e = read_transforms(&path).unwrap_err().to_string();
        assert!(e.contains(says) && e.contains(name), "{name}: {e}");
    }
    // Too many frames.
    let many = format!(
        r#"{{"camera_angle_x": 0.7, "frames": [{}]}}"#,
        vec![frame; 10_001].join(",")
    );
    std::fs::write(d.join("many.json"), many).unwrap();
    let e = read_transforms(&d.join("many.json"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("10001 frames"), "{e}");
    // Deeply nested JSON is refused by the parser, not a stack overflow.
    std::fs::write(d.join("deep.json"), "[".repeat(100_000)).unwrap();
    assert!(read_transforms(&d.join("deep.json")).is_err());
    // A scaled pose, a missing image, and special files.
    std::fs::write(
        d.join("scaled.json"),
        r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "r_0", "transform_matrix": [[2,0,0,0],[0,2,0,0],[0,0,2,3],[0,0,0,1]]}]}"#,
    )
    .unwrap();
    image::RgbaImage::new(4, 4).save(d.join("r_0.png")).unwrap();
    let e = read_split(&d.join("scaled.json"), "train", DVec3::ONE)
        .unwrap_err()
        .to_string();
    assert!(e.contains("orthonormal"), "{e}");
    std::fs::write(
        d.join("missing.json"),
        r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "nope", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}]}"#,
    )
    .unwrap();
    let e = read_split(&d.join("missing.json"), "train", DVec3::ONE)
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope.png"), "{e}");
    let e = read_transforms(Path::new("/dev/zero"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("not a regular file"), "{e}");
}

#[test]
fn dataset_files_are_claimed_before_anything_runs() {
    let e = load_err(
        "render r { scene: sphere(), camera: look_at([0, 0, -3]), outputs: [dataset(\"set\"), image(\"set/r_0.png\")] }",
    );
    assert!(e.contains("written twice"), "{e}");
    let e = load_err(
        "render r { scene: sphere(), camera: look_at([0, 0, -3]), outputs: [image(\"a.png\"), dataset(\"a.png\")] }",
    );
    assert!(e.contains("directory"), "{e}");
}

/// Cameras of different focal lengths write their intrinsics per frame
/// (nerfstudio's layout), each frame's its own.
#[test]
fn a_dataset_of_two_focal_lengths_writes_them_per_frame() {
    let p = load(
        "render r { scene: sphere(), camera: [look_at([0, 0, -3]), look_at([0, 0, 3], focal: 2)], size: [8, 6], outputs: [dataset(\"set\")] }",
    );
    let out = temp("two-focals");
    run_job(&p.renders[0], &out, RunOptions::default(), &|_| {}).unwrap();
    let doc: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("set/transforms.json")).unwrap()).unwrap();
    let fl: Vec<f64> = doc["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["fl_x"].as_f64().expect("per-frame fl_x"))
        .collect();
    // Corner centres on 6 rows: fl = focal·(6 − 1)/2.
    assert_eq!(fl, vec![2.5, 5.0]);
}
