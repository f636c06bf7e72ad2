//! Training end to end through the language: the box fits of the
//! assignment's part 2 recover centre and sides within 0.01; the sphere,
//! torus, blend and VolSDF examples recover their known truth within 1e-3;
//! a run stopped and resumed ends bit-identical to one that never stopped;
//! a checkpoint from another run is refused; divergence stops with a clear
//! error and a kept checkpoint.

use std::path::{Path, PathBuf};

use sdfl_lang::SourceFile;
use sdfl_runtime::jobs::{run_train_job, TrainOptions};
use sdfl_runtime::output::WrittenKind;
use sdfl_runtime::train::checkpoint::Checkpoint;

const WANT: [f32; 6] = [0.25, 0.25, 0.0, 2.0, 1.5, 1.5];
const RESUME: TrainOptions = TrainOptions { restart: false };

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

/// An example with `fewer` rays a step than its `rays`: for the fits here,
/// the same recovery (within 1e-4) in a third of the time or less.
fn example_with_rays(name: &str, rays: usize, fewer: usize) -> (SourceFile, PathBuf) {
    let (src, base) = example(name);
    let from = format!("rays: {rays},");
    assert!(src.text.contains(&from), "{name}");
    let text = src.text.replace(&from, &format!("rays: {fewer},"));
    (SourceFile::new(src.name, text), base)
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
    let (src, base) = example_with_rays("train_box.sdfl", 4096, 512);
    let program = sdfl_stdlib::load(&src).unwrap();
    let job = &program.trains[0];
    let out = temp("box");
    let r = run_train_job(job, &out, &base, Some((32, 32)), RESUME, &|_| {}).unwrap();
    assert_eq!(r.iterations, job.iterations);
    assert!(max_error(&r.params) < 0.01, "{:?}", r.params);
    assert!(r.written.iter().any(|w| w.kind == WrittenKind::LossCurve));
    assert!(r.written.iter().any(|w| w.kind == WrittenKind::Gif));
    // The checkpoint holds the final state; a second run resumes from it.
    let cp = Checkpoint::read(&out.join("train_box.ckpt")).unwrap();
    assert_eq!(cp.step, job.iterations);
    let again = run_train_job(job, &out, &base, Some((16, 16)), RESUME, &|_| {}).unwrap();
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
    let (src, base) = example_with_rays("train_box_assignment.sdfl", 4096, 512);
    let program = sdfl_stdlib::load(&src).unwrap();
    let out = temp("assignment");
    let r = run_train_job(
        &program.trains[0],
        &out,
        &base,
        Some((16, 16)),
        RESUME,
        &|_| {},
    )
    .unwrap();
    assert!(max_error(&r.params) < 0.01, "{:?}", r.params);
    let _ = std::fs::remove_dir_all(&out);
}

/// A float32 `.npy` image of `h × w × 3` values.
fn write_npy(path: &Path, h: usize, w: usize, value: impl Fn(usize) -> f32) {
    let header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({h}, {w}, 3), }}");
    let mut hdr = header;
    while (10 + hdr.len() + 1) % 64 != 0 {
        hdr.push(' ');
    }
    hdr.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend((hdr.len() as u16).to_le_bytes());
    bytes.extend(hdr.as_bytes());
    for k in 0..h * w * 3 {
        bytes.extend(value(k).to_le_bytes());
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn divergence_stops_with_the_checkpoint_kept() {
    // Finite pixels whose squared error overflows f32: the loss becomes
    // infinite at the first step.
    let out = temp("blowup");
    std::fs::create_dir_all(&out).unwrap();
    write_npy(&out.join("huge.npy"), 8, 8, |_| 1e30);
    let src = r#"
        train blowup {
          model: sdf_volume(box(size: param([1.5, 1.5, 1.5]), center: param([0, 0, 0]))),
          data: views(images: ["huge.npy"], cameras: [look_at(eye: [-2.5, 0, 0])]),
          rays: 64,
          iterations: 50,
          checkpoint: "blowup.ckpt",
        }
    "#;
    let program = sdfl_stdlib::load(&SourceFile::new("blowup.sdfl", src)).unwrap();
    let err = run_train_job(&program.trains[0], &out, &out, None, RESUME, &|_| {})
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("blowup")
            && err.contains("loss is inf")
            && err.contains("checkpoint (step 0) is kept"),
        "{err}"
    );
    let cp = Checkpoint::read(&out.join("blowup.ckpt")).unwrap();
    assert!(cp
        .params
        .iter()
        .flat_map(|p| &p.values)
        .all(|x| x.is_finite()));
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
    let views = sdfl_runtime::jobs::load_views(&data, &dir).unwrap().train;
    assert_eq!((views[0].image.width, views[0].image.height), (3, 2));
    for (i, p) in views[0].image.colours().enumerate() {
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
        .expect_err("missing file fails")
        .to_string();
    assert!(err.contains("nope.npy"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Runs an example and returns its learned values by name.
fn run_source((src, base): (SourceFile, PathBuf), out: &Path) -> Vec<(String, Vec<f32>)> {
    let program = sdfl_stdlib::load(&src).unwrap();
    let r = run_train_job(
        &program.trains[0],
        out,
        &base,
        Some((8, 8)),
        RESUME,
        &|_| {},
    )
    .unwrap();
    r.params
}

fn assert_close(got: &[(String, Vec<f32>)], want: &[(&str, &[f32])], tol: f32) {
    assert_eq!(got.len(), want.len(), "{got:?}");
    for ((n, v), (wn, wv)) in got.iter().zip(want) {
        assert_eq!(n, wn);
        for (a, b) in v.iter().zip(wv.iter()) {
            assert!((a - b).abs() <= tol, "{n}: {v:?}, want {wv:?}");
        }
    }
}

#[test]
fn examples_recover_their_known_truth() {
    let out = temp("examples");
    let sphere = run_source(example_with_rays("train_sphere.sdfl", 1024, 256), &out);
    assert_close(
        &sphere,
        &[
            ("sphere.center", &[-0.2, 0.1, 0.15]),
            ("sdf_volume.color", &[0.2, 0.6, 0.9]),
        ],
        1e-3,
    );
    let torus = run_source(example_with_rays("train_torus.sdfl", 1024, 256), &out);
    assert_close(
        &torus,
        &[
            ("torus.major", &[1.0]),
            ("torus.minor", &[0.25]),
            ("torus.center", &[0.0, 0.1, -0.1]),
        ],
        1e-3,
    );
    let blend = run_source(example_with_rays("train_blend.sdfl", 1024, 256), &out);
    assert_close(
        &blend,
        &[
            ("k", &[0.4]),
            ("sphere.center", &[-0.6, 0.0, 0.0]),
            ("sphere.center#2", &[0.6, 0.0, 0.0]),
            ("sphere.center#3", &[0.0, 0.55, 0.1]),
        ],
        1e-3,
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn volsdf_density_is_recovered() {
    let out = temp("volsdf");
    let v = run_source(example_with_rays("train_volsdf.sdfl", 2048, 512), &out);
    assert_close(
        &v,
        &[("volsdf.alpha", &[10.0]), ("volsdf.beta", &[0.05])],
        1e-3,
    );
    let _ = std::fs::remove_dir_all(&out);
}

const SMALL_FIT: &str = r#"
    let cams = [look_at(eye: [-2.5, 0, 0]), look_at(eye: [0, 0, -2.5]), look_at(eye: [1.5, 1.5, -1.5])]
    let target = volsdf(torus(major: 0.9, minor: 0.3, center: [0.1, 0, 0]), alpha: 10, beta: 0.05, color: [0.8, 0.3, 0.2])
    train small {
      model: volsdf(torus(major: param(0.7), minor: param(0.35), center: param([0, 0.1, 0])), alpha: 10, beta: param(0.08), color: param([0.5, 0.5, 0.5])),
      data: render_views(target, cameras: cams, size: [24, 24], sampler: stratified(samples: 32, near: 1, far: 4.5)),
      sampler: stratified(samples: 32, near: 1, far: 4.5, jitter: true),
      rays: 256,
      optimizer: adam(lr: 1e-2, decay: 0.5, decay_every: 20, schedule: "exponential"),
      iterations: ITERATIONS,
      seed: 7,
      checkpoint: "small.ckpt",
    }
"#;

fn small_fit(iterations: usize, target_minor: f64) -> sdfl_stdlib::value::TrainJob {
    let src = SMALL_FIT
        .replace("ITERATIONS", &iterations.to_string())
        .replace("minor: 0.3,", &format!("minor: {target_minor},"));
    let program = sdfl_stdlib::load(&SourceFile::new("small.sdfl", src)).unwrap();
    program.trains[0].clone()
}

#[test]
fn a_resumed_run_is_the_same_run() {
    // Jittered samples, a decaying rate and Adam's moments all carry over.
    let whole = temp("whole");
    let parts = temp("parts");
    let run = |job: &sdfl_stdlib::value::TrainJob, out: &Path| {
        run_train_job(job, out, Path::new("."), None, RESUME, &|_| {}).unwrap()
    };
    let uninterrupted = run(&small_fit(40, 0.3), &whole);
    let first = run(&small_fit(25, 0.3), &parts);
    assert_eq!(first.iterations, 25);
    let resumed = run(&small_fit(40, 0.3), &parts);
    assert_eq!(resumed.resumed_from, Some(25));
    assert_eq!(resumed.iterations, 40);
    assert_eq!(
        resumed.params, uninterrupted.params,
        "stop-and-resume differs"
    );
    assert_eq!(resumed.final_loss, uninterrupted.final_loss);
    let _ = std::fs::remove_dir_all(&whole);
    let _ = std::fs::remove_dir_all(&parts);
}

#[test]
fn a_checkpoint_from_another_run_is_refused() {
    let out = temp("stale");
    let run = |job: &sdfl_stdlib::value::TrainJob, restart| {
        run_train_job(
            job,
            &out,
            Path::new("."),
            None,
            TrainOptions { restart },
            &|_| {},
        )
    };
    run(&small_fit(5, 0.3), false).unwrap();
    // Another target: the data differ.
    let err = run(&small_fit(5, 0.25), false).unwrap_err().to_string();
    assert!(
        err.contains("small.ckpt") && err.contains("data") && err.contains("--restart"),
        "{err}"
    );
    // Another starting point: the model differs.
    let other_start = SMALL_FIT
        .replace("ITERATIONS", "5")
        .replace("param(0.7)", "param(0.6)");
    let program = sdfl_stdlib::load(&SourceFile::new("small.sdfl", other_start)).unwrap();
    let err = run(&program.trains[0], false).unwrap_err().to_string();
    assert!(err.contains("model") && !err.contains("data"), "{err}");
    // `--restart` starts over and overwrites it.
    let r = run(&small_fit(5, 0.25), true).unwrap();
    assert_eq!(r.resumed_from, None);
    assert!(run(&small_fit(6, 0.25), false).unwrap().resumed_from == Some(5));
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_non_finite_pixel_is_named_with_its_file() {
    let dir = temp("nanpixel");
    std::fs::create_dir_all(&dir).unwrap();
    // A 2×2 image with a NaN at row 1, column 0.
    write_npy(&dir.join("bad.npy"), 2, 2, |k| {
        if k == 6 {
            f32::NAN
        } else {
            0.5
        }
    });
    let cam = sdfl_stdlib::camera::Camera::look_at(
        glam::DVec3::new(0.0, 0.0, -3.0),
        glam::DVec3::ZERO,
        glam::DVec3::Y,
        1.0,
    );
    let data = sdfl_stdlib::value::Dataset::Files {
        images: vec!["bad.npy".into()],
        cameras: vec![cam],
    };
    let err = sdfl_runtime::jobs::load_views(&data, &dir)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("bad.npy") && err.contains("column 0, row 1"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn edits_that_do_not_change_the_run_still_resume() {
    // A comment above the model and a longer `iterations` shift every span
    // below them; the run is the same run.
    let out = temp("edits");
    let run = |src: String| {
        let program = sdfl_stdlib::load(&SourceFile::new("small.sdfl", src)).unwrap();
        run_train_job(
            &program.trains[0],
            &out,
            Path::new("."),
            None,
            RESUME,
            &|_| {},
        )
        .unwrap()
    };
    run(SMALL_FIT.replace("ITERATIONS", "5"));
    let edited = format!(
        "// tuned by hand\n\n{}",
        SMALL_FIT.replace("ITERATIONS", "12")
    );
    let r = run(edited);
    assert_eq!(r.resumed_from, Some(5));
    assert_eq!(r.iterations, 12);
    let _ = std::fs::remove_dir_all(&out);
}

/// Every held-out view is scored, and the comparison shows the first
/// [`COMPARISON_VIEWS`](sdfl_stdlib::work::COMPARISON_VIEWS): with 12 held
/// out, 8 rows (200 views of 800² kept whole were 3 GB of renders and a
/// PNG 160 000 rows tall).
#[test]
fn the_comparison_shows_the_first_views_and_all_are_scored() {
    let src = r#"
let target = sdf_volume(sphere(0.8), color: [0.2, 0.6, 0.9])
let sampler = stratified(samples: 8, near: 1, far: 5)
train t {
  model: sdf_volume(sphere(param(0.6)), color: [0.2, 0.6, 0.9]),
  data: render_views(target, cameras: orbit(radius: 3, views: 16), size: [8, 6], sampler: sampler, test_views: 12),
  sampler: sampler,
  rays: 16,
  iterations: 2,
  after: [comparison("c.png")],
}
"#;
    let program = sdfl_stdlib::load(&SourceFile::new("c.sdfl", src)).unwrap();
    let out = temp("comparison");
    let r = run_train_job(&program.trains[0], &out, &out, None, RESUME, &|_| {}).unwrap();
    let kept = sdfl_stdlib::work::COMPARISON_VIEWS as u32;
    assert!(kept < 12);
    let png = image::open(out.join("c.png")).unwrap();
    assert_eq!((png.width(), png.height()), (3 * 8, kept * 6));
    // Scored once, at the end.
    assert_eq!(r.held_out.len(), 1, "{:?}", r.held_out);
    assert!(r.held_out[0].psnr.is_finite());
    let _ = std::fs::remove_dir_all(&out);
}

/// A small fit with held-out views, its `after` outputs spliced in.
fn outputs_fit(after: &str, iterations: usize) -> sdfl_stdlib::value::TrainJob {
    let src = format!(
        r#"
    let sampler = stratified(samples: 24, near: 1, far: 5)
    let target = sdf_volume(sphere(0.8, center: [-0.2, 0.1, 0.15]), color: [0.2, 0.6, 0.9])
    train kept {{
      model: sdf_volume(sphere(0.8, center: param([0.1, 0, 0])), color: param([0.3, 0.1, 0.1])),
      data: render_views(target, cameras: orbit(radius: 3, views: 6), size: [16, 16], sampler: sampler, test_views: 2),
      sampler: sampler,
      rays: 128,
      iterations: {iterations},
      views: orbit(radius: 3, views: 3),
      size: [16, 16],
      after: [{after}],
      checkpoint: "kept.ckpt",
    }}
"#
    );
    let program = sdfl_stdlib::load(&SourceFile::new("kept.sdfl", src)).unwrap();
    program.trains[0].clone()
}

/// Run again at its last step with one output added, a finished run
/// renders only that output: the others' files are left as they were,
/// the held-out views are not scored again (the report keeps their
/// scores), and the record follows what was written.
#[test]
fn an_output_added_to_a_finished_run_is_the_only_one_rendered() {
    use sdfl_runtime::train::log::TrainEvent;
    use std::sync::atomic::{AtomicUsize, Ordering};
    let out = temp("kept-outputs");
    let first =
        r#"gif("views.gif"), image("view.png"), psnr_curve("psnr.png"), loss_curve("loss.png")"#;
    let scorings = AtomicUsize::new(0);
    let observe = |e: &TrainEvent| {
        if let TrainEvent::Status(n) = e {
            if n.contains("scored held-out view") {
                scorings.fetch_add(1, Ordering::Relaxed);
            }
        }
    };
    let run_for = |after: &str, iterations: usize| {
        let job = outputs_fit(after, iterations);
        run_train_job(&job, &out, Path::new("."), None, RESUME, &observe).unwrap()
    };
    let run = |after: &str| run_for(after, 10);
    let a = run(first);
    assert!(a.kept_outputs.is_empty(), "{:?}", a.kept_outputs);
    let scored_once = scorings.load(Ordering::Relaxed);
    let stamp = |p: &str| std::fs::metadata(out.join(p)).unwrap().modified().unwrap();
    let files = [
        "views.gif",
        "view_00.png",
        "view_02.png",
        "psnr.png",
        "loss.png",
    ];
    let before: Vec<_> = files.iter().map(|p| stamp(p)).collect();
    std::thread::sleep(std::time::Duration::from_millis(20));

    let b = run(&format!(r#"{first}, depth("depth.png")"#));
    assert_eq!(b.resumed_from, Some(10));
    let kept: Vec<&str> = b.kept_outputs.iter().map(|p| p.to_str().unwrap()).collect();
    assert_eq!(
        kept,
        ["views.gif", "view.png", "psnr.png", "loss.png"],
        "{kept:?}"
    );
    for (p, t) in files.iter().zip(&before) {
        assert_eq!(stamp(p), *t, "{p} was written again");
    }
    assert!(out.join("depth_00.png").is_file());
    assert_eq!(
        scorings.load(Ordering::Relaxed),
        scored_once,
        "the held-out views were scored again"
    );
    assert_eq!(
        b.held_out.last().map(|h| h.psnr),
        a.held_out.last().map(|h| h.psnr)
    );
    // Every file is still in the report, kept or new.
    for p in [
        "views.gif",
        "view_01.png",
        "psnr.png",
        "loss.png",
        "depth_02.png",
    ] {
        assert!(
            b.written.iter().any(|w| w.path == Path::new(p)),
            "{p} not reported"
        );
    }

    // A changed output or a deleted file: rendered again.
    std::fs::remove_file(out.join("view_01.png")).unwrap();
    let c = run(
        r#"gif("views.gif", fps: 5), image("view.png"), psnr_curve("psnr.png"), loss_curve("loss.png"), depth("depth.png")"#,
    );
    let kept: Vec<&str> = c.kept_outputs.iter().map(|p| p.to_str().unwrap()).collect();
    assert_eq!(kept, ["psnr.png", "loss.png", "depth.png"], "{kept:?}");
    assert!(out.join("view_01.png").is_file());

    // Trained on: every output is of new values.
    let d = run_for(first, 12);
    assert_eq!(d.resumed_from, Some(10));
    assert!(d.kept_outputs.is_empty(), "{:?}", d.kept_outputs);
    let _ = std::fs::remove_dir_all(&out);
}
