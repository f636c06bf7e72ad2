//! Neural-surface step benchmark against PyTorch:
//! `cargo run --release -p sdfl-bench -- surface [reps] [threads,...]`.
//!
//! One training step of the textbook network that `examples/neus.sdfl`
//! and `examples/volsdf.sdfl` train (a 4 × 64 softplus SDF with its exact
//! gradient, a 2 × 64 colour network that sees the normal; 1024 rays × 48
//! jittered samples, MSE + 0.02 · eikonal, Adam) through the real training
//! loop, on the examples' own views; and the same step in PyTorch with
//! autograd's double backward for the eikonal term
//! (`bench/pytorch/neus_bench.py`, run as a child process with the same
//! thread count). Each pair is timed in the order sdfl, PyTorch, PyTorch,
//! sdfl, so that load on a shared machine falls on both alike; the ratio
//! is of the means of the two medians each. Without PyTorch (or Python)
//! the sdfl rows are printed alone, with a line saying why.
//!
//! `-- surface check DIR` writes sdfl's parameters, one batch and its loss
//! and gradient for `neus_bench.py --check` to compare ([`check`]).

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use crate::stats::{load, median_min};
use sdfl_runtime::neural::surface::SurfaceObjective;
use sdfl_runtime::train::{Run, TrainSetup, TrainView};
use sdfl_stdlib::value::{Field, TrainJob};

/// The peer script, beside this crate.
const SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/pytorch/neus_bench.py");

/// The interpreter (`SDFL_PYTHON`, else `python3`) when it imports torch:
/// its version, or why the peer is skipped.
fn python() -> Result<(String, String), String> {
    let exe = std::env::var("SDFL_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = Command::new(&exe)
        .args(["-c", "import torch; print(torch.__version__)"])
        .output()
        .map_err(|e| format!("{exe} did not start ({e})"))?;
    if !out.status.success() {
        return Err(format!("{exe} cannot import torch"));
    }
    let version = String::from_utf8_lossy(&out.stdout).trim().to_string();
    Ok((exe, version))
}

/// Median and minimum step ms of `reps` PyTorch steps (after two warm-up
/// steps) at `threads`, parsed from the script's Markdown row.
fn pytorch_step(
    exe: &str,
    reps: usize,
    threads: usize,
    volsdf: bool,
) -> Result<(f64, f64), String> {
    let mut cmd = Command::new(exe);
    cmd.arg(SCRIPT)
        .arg(reps.to_string())
        .arg(threads.to_string());
    if volsdf {
        cmd.arg("--volsdf");
    }
    let out = cmd.output().map_err(|e| e.to_string())?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(format!(
            "{SCRIPT} failed: {}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    // | implementation | model | threads | median | min |
    let cells: Vec<&str> = text
        .lines()
        .last()
        .unwrap_or("")
        .split('|')
        .map(str::trim)
        .collect();
    let num = |i: usize| cells.get(i).and_then(|c| c.parse::<f64>().ok());
    match (num(4), num(5)) {
        (Some(med), Some(min)) => Ok((med, min)),
        _ => Err(format!("unexpected output of {SCRIPT}: {text}")),
    }
}

/// Median and minimum ms of `reps` sdfl steps after two warm-up steps,
/// on a fresh model (as the script builds one).
fn sdfl_step(job: &TrainJob, views: &[TrainView], reps: usize) -> (f64, f64) {
    let Field::NeuralSurface(spec) = &*job.model else {
        panic!("not a neural surface")
    };
    let setup = TrainSetup::of(job, views);
    let model = SurfaceObjective::new(spec, &job.losses)
        .expect("a harmonic surface builds")
        .with_steps(job.iterations);
    let mut run = Run::for_optimizer(Box::new(model), &job.optimizer).expect("run");
    for _ in 0..2 {
        run.advance(&setup).expect("step");
    }
    median_min(
        (0..reps)
            .map(|_| {
                let t = Instant::now();
                run.advance(&setup).expect("step");
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect(),
    )
}

/// Prints the step times of both models at each of `threads`, sdfl and
/// PyTorch in turns.
pub fn main(reps: usize, threads: &[usize]) {
    let examples = [
        ("NeuS", include_str!("../../examples/neus.sdfl"), false),
        ("VolSDF", include_str!("../../examples/volsdf.sdfl"), true),
    ];
    let peer = python();
    match &peer {
        Ok((exe, version)) => println!("peer: {SCRIPT} under {exe}, PyTorch {version}"),
        Err(why) => println!("peer skipped: {why}; sdfl alone"),
    }
    println!(
        "load average before: {} ({} steps a timing, order sdfl, PyTorch, PyTorch, sdfl)",
        load(),
        reps
    );
    println!("| model | threads | sdfl step ms (median; 1st, 2nd) | PyTorch step ms (median; 1st, 2nd) | **PyTorch / sdfl** |");
    println!("|---|---:|---:|---:|---:|");
    let prepared: Vec<_> = examples
        .iter()
        .map(|(name, src, volsdf)| {
            let (job, views) = crate::train::prepare(src);
            (*name, job, views, *volsdf)
        })
        .collect();
    assert!(Path::new(SCRIPT).exists(), "{SCRIPT} is missing");
    for &t in threads {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .expect("thread pool");
        for (name, job, views, volsdf) in &prepared {
            let a1 = pool.install(|| sdfl_step(job, views, reps)).0;
            let (b1, b2) = match &peer {
                Ok((exe, _)) => {
                    let b1 = pytorch_step(exe, reps, t, *volsdf);
                    let b2 = pytorch_step(exe, reps, t, *volsdf);
                    (b1.map(|b| b.0), b2.map(|b| b.0))
                }
                Err(why) => (Err(why.clone()), Err(why.clone())),
            };
            let a2 = pool.install(|| sdfl_step(job, views, reps)).0;
            let a = 0.5 * (a1 + a2);
            match (b1, b2) {
                (Ok(b1), Ok(b2)) => {
                    let b = 0.5 * (b1 + b2);
                    println!(
                        "| {name} | {t} | {a:.1} ({a1:.1}, {a2:.1}) | {b:.1} ({b1:.1}, {b2:.1}) | **{:.2}×** |",
                        b / a
                    );
                }
                (Err(e), _) | (_, Err(e)) => {
                    println!("| {name} | {t} | {a:.1} ({a1:.1}, {a2:.1}) | – | – |");
                    eprintln!("PyTorch peer: {e}");
                }
            }
        }
    }
    println!("load average after: {}", load());
}

/// Writes, for each example's model, what it takes to check that the
/// PyTorch peer computes the same step (`neus_bench.py --check FILE`):
/// the initial parameters by tensor name (sdfl's layout: a layer's
/// weights input-major), one batch of 64 rays (origins, directions,
/// depths, targets) and sdfl's loss and gradient on it, as lines of
/// `name value value ...`, into `dir/neus.txt` and `dir/volsdf.txt`.
pub fn check(dir: &Path) {
    use sdfl_runtime::train::Objective;
    use std::fmt::Write as _;
    std::fs::create_dir_all(dir).expect("output directory");
    let examples = [
        ("neus", include_str!("../../examples/neus.sdfl")),
        ("volsdf", include_str!("../../examples/volsdf.sdfl")),
    ];
    for (name, src) in examples {
        // The examples with neus_fast.sdfl's silhouette term added.
        let src = src.replacen(
            "  optimizer:",
            "  losses: [mse(), eikonal(weight: 0.02), silhouette(weight: 0.1)],\n  optimizer:",
            1,
        );
        let (job, views) = crate::train::prepare(&src);
        let Field::NeuralSurface(spec) = &*job.model else {
            panic!("not a neural surface")
        };
        let mut setup = TrainSetup::of(&job, &views);
        setup.rays = 64;
        let batch = setup.batch(0).expect("batch");
        let mut model = SurfaceObjective::new(spec, &job.losses)
            .expect("a harmonic surface builds")
            .with_steps(job.iterations);
        let values = model.initial();
        let mut grad = vec![0.0; values.len()];
        let loss = model
            .loss_and_grad(&values, &batch, 1.0, &mut grad)
            .expect("loss");
        let mut text = String::new();
        let mut line = |key: &str, xs: &mut dyn Iterator<Item = f64>| {
            text.push_str(key);
            for x in xs {
                write!(text, " {x:e}").expect("string");
            }
            text.push('\n');
        };
        line("loss", &mut std::iter::once(loss));
        line("samples", &mut std::iter::once(batch.samples as f64));
        line(
            "origins",
            &mut batch.rays.iter().flat_map(|r| r.origin.map(f64::from)),
        );
        line(
            "dirs",
            &mut batch.rays.iter().flat_map(|r| r.dir.map(f64::from)),
        );
        line(
            "depths",
            &mut (0..batch.rays.len()).flat_map(|r| batch.depths_of(r).iter().map(|&t| t as f64)),
        );
        line(
            "targets",
            &mut batch.targets.iter().flat_map(|t| t.map(f64::from)),
        );
        line("silhouette", &mut std::iter::once(0.1));
        line("coverage", &mut batch.coverage.iter().map(|&c| c as f64));
        if name == "neus" {
            // Every training pixel once: the views the examples train on.
            let mut all = TrainSetup::of(&job, &views);
            all.rays = views.iter().map(|v| v.image.len()).sum();
            let b = all.batch(0).expect("batch");
            let mut t = String::new();
            for ((r, c), a) in b.rays.iter().zip(&b.targets).zip(&b.coverage) {
                writeln!(
                    t,
                    "{} {} {:e} {:e} {:e} {:e} {:e} {:e} {:e} {:e} {:e} {:e}",
                    r.view,
                    r.pixel,
                    r.origin[0],
                    r.origin[1],
                    r.origin[2],
                    r.dir[0],
                    r.dir[1],
                    r.dir[2],
                    c[0],
                    c[1],
                    c[2],
                    a
                )
                .expect("string");
            }
            std::fs::write(dir.join("views.txt"), t).expect("write");
        }
        for t in model.tensors() {
            let range = t.offset..t.offset + t.len;
            line(
                &format!("param {}", t.name),
                &mut values[range.clone()].iter().map(|&v| v as f64),
            );
            line(
                &format!("grad {}", t.name),
                &mut grad[range].iter().map(|&v| v as f64),
            );
        }
        let path = dir.join(format!("{name}.txt"));
        std::fs::write(&path, text).expect("write");
        println!("{}: sdfl's loss {loss:.6e} on 64 rays", path.display());
    }
}
