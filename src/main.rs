//! `sdfl`: run, check and inspect scene files.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use sdfl_lang::SourceFile;
use sdfl_runtime::{run_job, JobReport, Plan, RunOptions};

/// The scene `sdfl run` renders when given no file.
const SHOWCASE: &str = include_str!("../examples/large_scene.sdfl");

#[derive(Parser)]
#[command(
    name = "sdfl",
    version,
    about = "A declarative language for SDF and neural rendering pipelines"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene file (or, with no file, the built-in showcase scene).
    Run {
        /// The `.sdfl` file.
        file: Option<PathBuf>,
        /// Directory for the outputs; the scene cannot write outside it.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Override every render's image size, as WIDTHxHEIGHT.
        #[arg(long, value_parser = parse_size)]
        size: Option<(u32, u32)>,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Print a machine-readable summary (outputs and stage times) as JSON.
        #[arg(long)]
        json: bool,
        /// Evaluate unions without BVH culling (for comparisons).
        #[arg(long)]
        no_cull: bool,
    },
    /// Check files for errors without running them; exits non-zero on error.
    Check {
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// Show what each statement of a file will compute, and why.
    Plan { file: PathBuf },
    /// List the built-in functions and statements, or describe one.
    Docs { name: Option<String> },
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or("expected WIDTHxHEIGHT, e.g. 128x128")?;
    let w: u32 = w.trim().parse().map_err(|_| format!("bad width `{w}`"))?;
    let h: u32 = h.trim().parse().map_err(|_| format!("bad height `{h}`"))?;
    let max = sdfl_stdlib::builtins::MAX_IMAGE_SIDE;
    if w == 0 || h == 0 || w > max || h > max {
        return Err(format!("width and height must be 1 to {max}"));
    }
    Ok((w, h))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Run {
            file,
            out,
            size,
            threads,
            json,
            no_cull,
        } => {
            if let Some(n) = threads {
                if let Err(e) = rayon::ThreadPoolBuilder::new()
                    .num_threads(n.max(1))
                    .build_global()
                {
                    eprintln!("error[sdfl::io]: cannot set up {n} threads: {e}");
                    return ExitCode::FAILURE;
                }
            }
            run(file.as_deref(), &out, RunOptions { size, no_cull }, json)
        }
        Command::Check { files } => {
            let mut ok = true;
            for f in &files {
                match read(f).and_then(|src| load(&src).map(|_| ())) {
                    Ok(()) => eprintln!("{}: ok", f.display()),
                    Err(()) => ok = false,
                }
            }
            if ok {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            }
        }
        Command::Plan { file } => {
            let Ok(program) = read(&file).and_then(|s| load(&s)) else {
                return ExitCode::FAILURE;
            };
            for job in &program.renders {
                print_plan(job);
            }
            ExitCode::SUCCESS
        }
        Command::Docs { name } => docs(name.as_deref()),
    }
}

fn read(path: &Path) -> Result<SourceFile, ()> {
    match std::fs::read(path) {
        Ok(bytes) => {
            let text = String::from_utf8_lossy(&bytes).into_owned();
            Ok(SourceFile::new(path.display().to_string(), text))
        }
        Err(e) => {
            eprintln!("error[sdfl::io]: cannot read {}: {e}", path.display());
            Err(())
        }
    }
}

fn load(src: &SourceFile) -> Result<sdfl_stdlib::Program, ()> {
    sdfl_stdlib::load(src).map_err(|diags| {
        eprint!(
            "{}",
            sdfl_lang::render(src, &diags, std::io::stderr().is_terminal())
        );
    })
}

fn run(file: Option<&Path>, out: &Path, options: RunOptions, json: bool) -> ExitCode {
    let t0 = Instant::now();
    let src = match file {
        Some(f) => match read(f) {
            Ok(s) => s,
            Err(()) => return ExitCode::FAILURE,
        },
        None => SourceFile::new("showcase.sdfl (built in)", SHOWCASE),
    };
    let Ok(program) = load(&src) else {
        return ExitCode::FAILURE;
    };
    let load_s = t0.elapsed().as_secs_f64();
    let total: u64 = program
        .renders
        .iter()
        .map(|j| {
            let (w, h) = options.size.unwrap_or((j.width, j.height));
            w as u64 * h as u64 * j.cameras.len() as u64
        })
        .sum();
    let bar = ProgressBar::new(total);
    if json || !std::io::stderr().is_terminal() {
        bar.set_draw_target(ProgressDrawTarget::hidden());
    }
    bar.set_style(
        ProgressStyle::with_template(
            "{msg:>12} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    let mut reports: Vec<JobReport> = Vec::new();
    for job in &program.renders {
        bar.set_message(job.name.clone());
        match run_job(job, out, options, &|n| bar.inc(n)) {
            Ok(r) => reports.push(r),
            Err(e) => {
                bar.abandon();
                eprintln!(
                    "error[sdfl::io]: writing the outputs of `{}` under {}: {e}",
                    job.name,
                    out.display()
                );
                return ExitCode::FAILURE;
            }
        }
    }
    bar.finish_and_clear();
    if json {
        let summary = serde_json::json!({
            "file": src.name,
            "out_dir": out,
            "load_seconds": load_s,
            "total_seconds": t0.elapsed().as_secs_f64(),
            "jobs": reports,
        });
        println!(
            "{}",
            serde_json::to_string_pretty(&summary).expect("serialisable")
        );
    } else {
        for r in &reports {
            let stages: Vec<String> = r
                .stages
                .iter()
                .map(|(n, s)| format!("{n} {:.3}s", s))
                .collect();
            eprintln!(
                "{}: {} primitives, {} views, {} rays ({:.1}% hit, {:.1} steps/ray); {}",
                r.name,
                r.primitives,
                r.views,
                r.rays,
                100.0 * r.hits as f64 / r.rays.max(1) as f64,
                r.steps as f64 / r.rays.max(1) as f64,
                stages.join(", ")
            );
            for w in &r.written {
                println!("{}", out.join(&w.path).display());
            }
        }
    }
    ExitCode::SUCCESS
}

fn print_plan(job: &sdfl_stdlib::RenderJob) {
    let plan = Plan::of(job);
    println!("render {}", job.name);
    println!(
        "  scene      {} primitives, {:?}, Lipschitz bound {}",
        job.scene.primitive_count(),
        job.scene.exactness(),
        job.scene.lipschitz()
    );
    println!(
        "  rays       {} views x {}x{}, sphere trace near {} far {}, <= {} steps, epsilon {}",
        job.cameras.len(),
        job.width,
        job.height,
        job.near,
        job.far,
        job.iterations,
        job.epsilon
    );
    let row = |what: &str, who: &[String]| {
        if who.is_empty() {
            println!("  {what:<10} skipped (no output needs it)");
        } else {
            println!("  {what:<10} computed for {}", who.join(", "));
        }
    };
    row("colour", &plan.color);
    row("depth", &plan.depth);
    row("normals", &plan.normals);
    row("hit mask", &plan.mask);
}

fn docs(name: Option<&str>) -> ExitCode {
    let env = sdfl_stdlib::StdEnv::get();
    match name {
        None => {
            for b in env.blocks() {
                println!("{:<20} statement: {}", b.kind, b.doc);
            }
            for b in env.builtins() {
                println!("{:<20} {}", b.sig.name, b.sig.doc);
            }
            ExitCode::SUCCESS
        }
        Some(n) => {
            if let Some(b) = env.builtin(n) {
                println!("{}\n\n{}\n", b.sig.synopsis(), b.sig.doc);
                for p in &b.sig.params {
                    println!("  {:<12} {}", p.name, p.doc);
                }
                return ExitCode::SUCCESS;
            }
            if let Some(b) = env.block_sig(n) {
                println!("{} name {{ ... }}\n\n{}\n", b.kind, b.doc);
                for p in &b.fields {
                    let d = p
                        .default
                        .map(|d| format!(" (default {d})"))
                        .unwrap_or_default();
                    println!("  {:<12} {}{d}", p.name, p.doc);
                }
                return ExitCode::SUCCESS;
            }
            eprintln!("error: no built-in named `{n}`; `sdfl docs` lists them");
            ExitCode::FAILURE
        }
    }
}
