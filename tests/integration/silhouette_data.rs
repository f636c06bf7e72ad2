//! `silhouette()` on people's data: a NeRF-synthetic set's (or a
//! capture's) alpha is each pixel's coverage by the object. sdfl's own
//! `dataset(...)` output reads back with the traced hit mask as coverage;
//! images without alpha are refused when read, under their own code; the
//! check lets the term train on such data and still refuses data that
//! cannot say; a short hash-grid NeuS run learns from a written set.

use crate::common::*;

use std::fs;
use std::path::Path;

use sdfl_lang::SourceFile;
use sdfl_runtime::data::{coded, DataNeeds, NO_COVERAGE};
use sdfl_runtime::jobs::{load_views_for, run_train_job, traced_views, TrainOptions};
use sdfl_runtime::render::{run_job, RunOptions};
use sdfl_runtime::train::checkpoint::Checkpoint;
use sdfl_stdlib::Program;

const COVERAGE: DataNeeds = DataNeeds {
    coverage: true,
    held_out: None,
};

fn load(src: &str) -> Program {
    sdfl_stdlib::load(&SourceFile::new("silhouette.sdfl", src)).unwrap_or_else(|e| panic!("{e:?}"))
}

/// A sphere off the orbit's axis (so that each view's outline differs)
/// seen from 8 orbiting cameras, written by `dataset(...)` into `set`
/// (`alpha` as given).
fn render(alpha: bool) -> String {
    format!(
        "render r {{\n  scene: sphere(0.6, center: [0.35, 0.1, 0]),\n  camera: orbit(radius: 3, up: [0, 1, 0], focal: 1.5, views: 8),\n  size: [16, 16],\n  material: lambert(albedo: [0.9, 0.5, 0.2]),\n  outputs: [dataset(\"set\", alpha: {alpha})],\n}}\n"
    )
}

/// A hash-grid NeuS trained on `data` with `losses`, `iterations` steps.
fn train(data: &str, losses: &str, iterations: usize) -> String {
    format!(
        r#"
let grid = hashgrid(levels: 4, log2_table: 10, min_res: 4, max_res: 24, min: [-1.2, -1.2, -1.2], max: [1.2, 1.2, 1.2])
train fit {{
  model: neus(neural_sdf(encoding: grid, network: mlp(layers: 1, width: 16, skips: []), radius: 0.4), beta: param(0.08), background: [1, 1, 1], view_dependent: false),
  data: {data},
  sampler: stratified(samples: 16, near: 1.8, far: 4.2, jitter: true),
  rays: 128,
  losses: {losses},
  optimizer: adam(lr: 1e-2),
  iterations: {iterations},
  bounds: 1.2,
  checkpoint: "fit.ckpt",
}}
"#
    )
}

/// Writes the set of [`render`] under `out`.
fn write_set(out: &Path, alpha: bool) -> Program {
    let p = load(&render(alpha));
    run_job(&p.renders[0], out, RunOptions::default(), &|_| {}).unwrap();
    p
}

#[test]
fn a_written_set_reads_back_with_the_hit_mask_as_coverage() {
    let out = temp_dir("silhouette", "hit-mask");
    let p = write_set(&out, true);
    let traced = traced_views(&p.renders[0]);
    let job = load(&train(
        "nerf_synthetic(\"set\")",
        "[mse(), silhouette()]",
        1,
    ));
    let views = load_views_for(&job.trains[0].data, &out, DataNeeds::of(&job.trains[0])).unwrap();
    assert_eq!(views.train.len(), traced.len());
    assert_ne!(
        traced[0].coverage, traced[2].coverage,
        "outlines differ by view"
    );
    for (k, (read, traced)) in views.train.iter().zip(&traced).enumerate() {
        let read = read.coverage.as_deref().expect("coverage read from alpha");
        let hits = traced
            .coverage
            .as_deref()
            .expect("a traced view's hit mask");
        // Alpha 255 / 0 → coverage 1 / 0, pixel for pixel.
        assert_eq!(read, hits, "view {k}");
        assert!(read.iter().all(|&c| c == 0 || c == 255), "view {k}");
        assert!(
            read.contains(&0) && read.contains(&255),
            "view {k}: both hit and missed"
        );
    }
    // Not asked for, not held: mse() alone reads no coverage.
    let job = load(&train("nerf_synthetic(\"set\")", "[mse()]", 1));
    let views = load_views_for(&job.trains[0].data, &out, DataNeeds::of(&job.trains[0])).unwrap();
    assert!(views.train.iter().all(|v| v.coverage.is_none()));
    assert!(views.scene_report.is_empty(), "{:?}", views.scene_report);
}

/// A capture's training views take their coverage from alpha too (here
/// the nerfstudio `transforms.json` that `dataset(...)` also writes); its
/// held-out views, only scored, read none. Without alpha: the same error.
#[test]
fn a_capture_reads_coverage_for_its_training_views() {
    let out = temp_dir("silhouette", "capture");
    let p = load(&render(true).replace(
        "dataset(\"set\", ",
        "dataset(\"set\", test_views: 2, seed: 3, ",
    ));
    run_job(&p.renders[0], &out, RunOptions::default(), &|_| {}).unwrap();
    let traced = traced_views(&p.renders[0]);
    let job = load(&train("capture(\"set\")", "[mse(), silhouette()]", 1));
    let views = load_views_for(&job.trains[0].data, &out, DataNeeds::of(&job.trains[0])).unwrap();
    assert_eq!((views.train.len(), views.test.len()), (6, 2));
    for v in &views.test {
        assert!(v.coverage.is_none());
    }
    let mut matched = 0;
    for v in &views.train {
        let c = v.coverage.as_deref().expect("coverage read from alpha");
        assert!(c.contains(&0) && c.contains(&255));
        // The view's own hit mask (the views are normalised into another
        // frame, so matched by content).
        matched += traced
            .iter()
            .filter(|t| t.coverage.as_deref() == Some(c))
            .count()
            .min(1);
    }
    assert_eq!(matched, 6);
    // Without alpha: refused under the same code.
    let rgb = temp_dir("silhouette", "capture-rgb");
    run_job(
        &load(&render(false).replace(
            "dataset(\"set\", ",
            "dataset(\"set\", test_views: 2, seed: 3, ",
        ))
        .renders[0],
        &rgb,
        RunOptions::default(),
        &|_| {},
    )
    .unwrap();
    let e = load_views_for(&job.trains[0].data, &rgb, COVERAGE).unwrap_err();
    assert_eq!(coded(&e).map(|c| c.code), Some(NO_COVERAGE), "{e}");
    load_views_for(&job.trains[0].data, &rgb, DataNeeds::default()).unwrap();
}

#[test]
fn images_without_alpha_are_refused_under_their_own_code() {
    let out = temp_dir("silhouette", "rgb");
    write_set(&out, false);
    let job = load(&train(
        "nerf_synthetic(\"set\")",
        "[mse(), silhouette()]",
        1,
    ));
    let e = load_views_for(&job.trains[0].data, &out, COVERAGE).unwrap_err();
    let c = coded(&e).expect("a coded data error");
    assert_eq!(c.code, NO_COVERAGE);
    assert!(
        c.message.contains("r_0.png") && c.message.contains("alpha"),
        "{}",
        c.message
    );
    assert!(
        c.help.contains("RGBA") && c.help.contains("silhouette()"),
        "{}",
        c.help
    );
    // The same images train without the term.
    let job = load(&train("nerf_synthetic(\"set\")", "[mse()]", 1));
    load_views_for(&job.trains[0].data, &out, DataNeeds::of(&job.trains[0])).unwrap();

    // Through the CLI: the code, at the data set's path argument, with its help.
    let dir = case_dir("silhouette_rgb");
    let (scene, file) = (dir.join("set.sdfl"), dir.join("fit.sdfl"));
    fs::write(&scene, render(false)).unwrap();
    fs::write(
        &file,
        train("nerf_synthetic(\"set\")", "[mse(), silhouette()]", 2),
    )
    .unwrap();
    assert_outcome(
        "writing the set",
        &run_into(&dir, &scene, &dir, &[]),
        Expect::Ok,
    );
    let o = run_into(&dir, &file, &dir.join("out"), &[]);
    assert_outcome("RGB set with silhouette", &o, Expect::Error);
    let err = &o.stderr;
    assert!(
        err.contains(NO_COVERAGE) && !err.contains("sdfl::io"),
        "{}",
        head(err)
    );
    assert!(
        err.contains("r_0.png") && err.contains("leave `silhouette()` out"),
        "{}",
        head(err)
    );
    assert!(
        err.contains("nerf_synthetic(\"set\")"),
        "points at the path argument: {}",
        head(err)
    );
}

/// Alpha opaque everywhere says nothing of the outline: legal, but warned
/// about when read (the term would pull every ray opaque).
#[test]
fn an_everywhere_opaque_alpha_is_warned_about() {
    let out = temp_dir("silhouette", "opaque");
    write_set(&out, true);
    for k in 0..8 {
        let path = out.join(format!("set/r_{k}.png"));
        let mut img = image::open(&path).unwrap().to_rgba8();
        img.pixels_mut().for_each(|p| p.0[3] = 255);
        img.save(&path).unwrap();
    }
    let job = load(&train(
        "nerf_synthetic(\"set\")",
        "[mse(), silhouette()]",
        1,
    ));
    let views = load_views_for(&job.trains[0].data, &out, COVERAGE).unwrap();
    assert!(views.train.iter().all(|v| v
        .coverage
        .as_deref()
        .is_some_and(|c| c.iter().all(|&a| a == 255))));
    assert!(
        views
            .scene_report
            .iter()
            .any(|l| l.starts_with("warning:") && l.contains("opaque")),
        "{:?}",
        views.scene_report
    );
}

#[test]
fn a_hash_neus_trains_with_silhouette_on_a_written_set() {
    let out = temp_dir("silhouette", "train");
    write_set(&out, true);
    let run = |losses: &str, dir: &str| {
        let dir = out.join(dir);
        fs::create_dir_all(&dir).unwrap();
        let job = load(&train("nerf_synthetic(\"../set\")", losses, 6));
        let report = run_train_job(
            &job.trains[0],
            &dir,
            &dir,
            None,
            TrainOptions::default(),
            &|_| {},
        )
        .unwrap();
        assert!(
            report.final_loss.is_finite(),
            "{losses}: {}",
            report.final_loss
        );
        Checkpoint::read(&dir.join("fit.ckpt")).unwrap().losses
    };
    let with = run(
        "[mse(), eikonal(weight: 0.02), silhouette(weight: 0.5)]",
        "with",
    );
    let without = run("[mse(), eikonal(weight: 0.02)]", "without");
    assert_eq!(with.len(), 6);
    assert!(with.iter().all(|l| l.is_finite()), "{with:?}");
    // Step 0 is the same batch at the same start: the difference is the
    // silhouette term itself, a cross-entropy, so positive.
    assert!(with[0] > without[0] + 1e-4, "{with:?} against {without:?}");
}

/// The check lets `silhouette()` train on data that can give coverage
/// (read when the files are), and refuses data that cannot.
#[test]
fn the_check_allows_silhouette_on_image_sets_with_alpha_only() {
    let losses = "[mse(), silhouette()]";
    for data in [
        "nerf_synthetic(\"set\")",
        "capture(\"photos\")",
        "render_views(sphere(0.5), cameras: orbit(radius: 3, views: 3), size: [8, 8])",
    ] {
        let src = train(data, losses, 1);
        if let Err(e) = sdfl_stdlib::load(&SourceFile::new("ok.sdfl", src.as_str())) {
            panic!("{data}: {e:?}");
        }
    }
    for data in [
        "render_views(nerf(layers: 1, width: 8, skips: []), cameras: orbit(radius: 3, views: 3), size: [8, 8])",
        "views(images: [\"a.png\"], cameras: [look_at(eye: [0, 0, -3])])",
    ] {
        let src = train(data, losses, 1);
        let e = match sdfl_stdlib::load(&SourceFile::new("refused.sdfl", src.as_str())) {
            Ok(_) => panic!("{data}: silhouette() accepted"),
            Err(e) => format!("{e:?}"),
        };
        assert!(e.contains("needs each pixel's coverage"), "{data}: {e}");
    }
}
