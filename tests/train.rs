//! Training end to end through the language: the box fits of the
//! assignment's part 2 recover centre and sides within 0.01, checkpoints
//! resume, and divergence stops with a clear error and a kept checkpoint.

use std::path::{Path, PathBuf};

use sdfl_lang::SourceFile;
use sdfl_runtime::jobs::{run_train_job, Checkpoint};

const WANT: [f32; 6] = [0.25, 0.25, 0.0, 2.0, 1.5, 1.5];

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn example(name: &str) -> (SourceFile, PathBuf) {
    let path = root().join("examples").join(name);
    (
        SourceFile::new(
            path.display().to_string(),
            std::fs::read_to_string(&path).unwrap(),
        ),
        root().join("examples"),
    )
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-train-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Largest distance of the learned (centre, size) from the expected box.
fn max_error(params: &[(String, Vec<f32>)]) -> f32 {
    assert_eq!(
        params.iter().map(|p| p.0.as_str()).collect::<Vec<_>>(),
        ["box.center", "box.size"]
    );
    let got = params.iter().flat_map(|p| p.1.iter().copied());
    got.zip(WANT)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max)
}

#[test]
fn train_box_recovers_the_box_and_resumes() {
    let (src, base) = example("train_box.sdfl");
    let program = sdfl_stdlib::load(&src).unwrap();
    let job = &program.trains[0];
    let out = temp("box");
    let r = run_train_job(job, &out, &base, Some((32, 32)), &|_| {}, &|_| {}).unwrap();
    assert_eq!(r.iterations, job.iterations);
    assert!(max_error(&r.params) < 0.01, "{:?}", r.params);
    assert!(r.written.iter().any(|w| w.kind == "loss_curve"));
    assert!(r.written.iter().any(|w| w.kind == "gif"));
    // The checkpoint holds the final state; a second run resumes from it.
    let cp = Checkpoint::read(&out.join("train_box.checkpoint.json")).unwrap();
    assert_eq!(cp.iteration, job.iterations);
    let again = run_train_job(job, &out, &base, Some((16, 16)), &|_| {}, &|_| {}).unwrap();
    assert_eq!(again.resumed_from, Some(job.iterations));
    assert_eq!(again.params, r.params);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn train_box_from_the_assignment_data() {
    let data = root().join("../shared/data/assignment3");
    if !data.join("box_0.npy").exists() {
        eprintln!("note: {} is absent; the assignment-data fit is skipped (train_box covers the same fit)", data.display());
        return;
    }
    let (src, base) = example("train_box_assignment.sdfl");
    let program = sdfl_stdlib::load(&src).unwrap();
    let out = temp("assignment");
    let r = run_train_job(
        &program.trains[0],
        &out,
        &base,
        Some((16, 16)),
        &|_| {},
        &|_| {},
    )
    .unwrap();
    assert!(max_error(&r.params) < 0.01, "{:?}", r.params);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn divergence_stops_with_the_checkpoint_kept() {
    let src = r#"
        let cams = [look_at(eye: [-2.5, 0, 0]), look_at(eye: [0, 0, -2.5])]
        let target = sdf_volume(box(size: [2, 1.5, 1.5], center: [0.25, 0.25, 0]))
        train blowup {
          model: sdf_volume(box(size: param([1.5, 1.5, 1.5]), center: param([0, 0, 0]))),
          data: render_views(target, cameras: cams, size: [16, 16]),
          optimizer: adam(lr: 1e6),
          rays: 64,
          iterations: 50,
          checkpoint: "blowup.json",
        }
    "#;
    let program = sdfl_stdlib::load(&SourceFile::new("blowup.sdfl", src)).unwrap();
    let out = temp("blowup");
    let err = run_train_job(
        &program.trains[0],
        &out,
        Path::new("."),
        None,
        &|_| {},
        &|_| {},
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("blowup") && err.contains("checkpoint is kept"),
        "{err}"
    );
    let cp = Checkpoint::read(&out.join("blowup.json")).unwrap();
    assert!(cp.center.iter().chain(&cp.sides).all(|x| x.is_finite()));
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn png_views_load_as_linear_floats() {
    let dir = temp("png");
    std::fs::create_dir_all(&dir).unwrap();
    let mut img = image::RgbImage::new(3, 2);
    for (i, p) in img.pixels_mut().enumerate() {
        *p = image::Rgb([(i * 40) as u8, 255 - (i * 40) as u8, 128]);
    }
    img.save(dir.join("view.png")).unwrap();
    let cam = sdfl_stdlib::camera::Camera::look_at(
        glam::DVec3::new(0.0, 0.0, -3.0),
        glam::DVec3::ZERO,
        glam::DVec3::Y,
        1.0,
    );
    let data = sdfl_stdlib::value::Dataset::Files {
        images: vec!["view.png".into()],
        cameras: vec![cam],
    };
    let views = sdfl_runtime::jobs::load_views(&data, &dir).unwrap();
    assert_eq!((views[0].image.width, views[0].image.height), (3, 2));
    for (i, p) in views[0].image.pixels.iter().enumerate() {
        let want = [
            (i * 40) as f32 / 255.0,
            (255 - i * 40) as f32 / 255.0,
            128.0 / 255.0,
        ];
        for c in 0..3 {
            assert!(
                (p[c] - want[c]).abs() < 1e-6,
                "pixel {i}: {p:?} vs {want:?}"
            );
        }
    }
    // A missing file is an error naming it, not a panic.
    let missing = sdfl_stdlib::value::Dataset::Files {
        images: vec!["nope.npy".into()],
        cameras: vec![cam],
    };
    let err = sdfl_runtime::jobs::load_views(&missing, &dir)
        .err()
        .expect("missing file fails")
        .to_string();
    assert!(err.contains("nope.npy"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
