//! Golden images: every example is rendered small (96×96) and the first
//! view of each output is compared with `tests/golden/EXAMPLE/FILE` within a
//! tolerance. Run with `SDFL_BLESS=1` to regenerate them, on purpose only.

use std::path::{Path, PathBuf};

use sdfl_lang::SourceFile;
use sdfl_runtime::output::WrittenKind;
use sdfl_runtime::{run_job, RunOptions};

const SIZE: (u32, u32) = (96, 96);

fn examples() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("examples/ exists")
        .map(|e| e.expect("readable").path())
        .filter(|p| p.extension().is_some_and(|e| e == "sdfl"))
        .collect();
    files.sort();
    files
}

/// Mean absolute channel difference and the fraction of pixels off by more
/// than 24/255 in some channel.
fn compare(a: &image::RgbImage, b: &image::RgbImage) -> (f64, f64) {
    assert_eq!(a.dimensions(), b.dimensions());
    let mut sum = 0u64;
    let mut bad = 0usize;
    for (p, q) in a.pixels().zip(b.pixels()) {
        let d: Vec<u8> = (0..3).map(|c| p[c].abs_diff(q[c])).collect();
        sum += d.iter().map(|x| *x as u64).sum::<u64>();
        bad += d.iter().any(|x| *x > 24) as usize;
    }
    let n = (a.width() * a.height()) as f64;
    (sum as f64 / (3.0 * n), bad as f64 / n)
}

fn is_first_view(name: &str) -> bool {
    let stem = name.trim_end_matches(".png");
    !stem.chars().last().is_some_and(|c| c.is_ascii_digit()) || stem.ends_with("_00")
}

#[test]
fn examples_match_their_golden_images() {
    let bless = std::env::var_os("SDFL_BLESS").is_some();
    let golden_root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    let mut compared = 0;
    let mut failures = Vec::new();
    for file in examples() {
        let name = file.file_stem().unwrap().to_string_lossy().into_owned();
        let src = SourceFile::new(
            file.display().to_string(),
            std::fs::read_to_string(&file).unwrap(),
        );
        let program = sdfl_stdlib::load(&src)
            .unwrap_or_else(|d| panic!("{}", sdfl_lang::render(&src, &d, false)));
        let out = std::env::temp_dir().join(format!("sdfl-golden-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        // Sphere-traced and volume renders (training is checked end to end
        // by tests/integration/train.rs).
        let mut reports = Vec::new();
        for job in &program.renders {
            let r = run_job(
                job,
                &out,
                RunOptions {
                    size: Some(SIZE),
                    no_cull: false,
                    restart: false,
                },
                &|_| {},
            )
            .unwrap();
            reports.push((r.written, job.cameras.len()));
        }
        for job in &program.volumes {
            let r = sdfl_runtime::jobs::run_volume_job(job, &out, Some(SIZE), &|_| {}).unwrap();
            reports.push((r.written, job.cameras.len()));
        }
        for (written, views) in reports {
            // Data sets are checked by runtime/tests/suite/views.rs, videos
            // by tests/integration/video.rs.
            let animated = |k: WrittenKind| matches!(k, WrittenKind::Gif | WrittenKind::Video);
            for w in written
                .iter()
                .filter(|w| !animated(w.kind) && w.kind != WrittenKind::Dataset)
            {
                let file_name = w.path.to_string_lossy().into_owned();
                if !is_first_view(&file_name) {
                    continue;
                }
                let produced = out.join(&w.path);
                let golden = golden_root.join(&name).join(&w.path);
                if bless {
                    std::fs::create_dir_all(golden.parent().unwrap()).unwrap();
                    std::fs::copy(&produced, &golden).unwrap();
                    continue;
                }
                let Ok(expected) = image::open(&golden) else {
                    failures.push(format!(
                        "{}: no golden image (run with SDFL_BLESS=1)",
                        golden.display()
                    ));
                    continue;
                };
                let got = image::open(&produced).unwrap().to_rgb8();
                let (mean, frac) = compare(&got, &expected.to_rgb8());
                compared += 1;
                if mean > 1.0 || frac > 0.01 {
                    failures.push(format!(
                        "{}: mean diff {mean:.3}, {:.2}% pixels differ",
                        golden.display(),
                        frac * 100.0
                    ));
                }
            }
            // Every GIF and video has one frame per view.
            for w in written.iter().filter(|w| animated(w.kind)) {
                assert_eq!(w.frames, views);
                assert!(out.join(&w.path).metadata().unwrap().len() > 0);
            }
        }
        let _ = std::fs::remove_dir_all(&out);
    }
    assert!(
        failures.is_empty(),
        "golden mismatches:\n{}",
        failures.join("\n")
    );
    assert!(bless || compared >= 8, "only {compared} images compared");
}
