//! `sdfl`: run, check and inspect scene files.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use sdfl_lang::SourceFile;
use sdfl_runtime::{jobs, run_job, Plan, RunOptions};
use sdfl_stdlib::value::Statement;

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
        /// Start training over instead of resuming a checkpoint.
        #[arg(long)]
        restart: bool,
    },
    /// Check files for errors without running them; exits non-zero on error.
    Check {
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// Show what each statement of a file will compute, and why.
    Plan { file: PathBuf },
    /// Re-run a file over settings of a top-level `let` and tabulate time
    /// against error (PSNR against the last setting's images, or parameter
    /// distance for training); writes sweep.csv, sweep.md and sweep.png.
    /// Each setting runs from scratch in OUT/NAME=VALUE/, emptied first.
    Sweep {
        file: PathBuf,
        /// NAME=V1,V2,...: the values of `let NAME`; the last is the reference.
        #[arg(long, value_parser = parse_set)]
        set: (String, Vec<f64>),
        #[arg(long, default_value = "out/sweep")]
        out: PathBuf,
        /// Override every image size, as WIDTHxHEIGHT.
        #[arg(long, value_parser = parse_size)]
        size: Option<(u32, u32)>,
    },
    /// The assignment's part 0: transmittance through three slabs; prints
    /// the four transmittances and writes the figure.
    Transmittance {
        #[arg(long, default_value = "out")]
        out: PathBuf,
    },
    /// List the built-in functions and statements, or describe one.
    Docs { name: Option<String> },
}

/// Most worker threads per core: more only spend time spawning and
/// switching (100 000 threads took a minute to start).
const THREADS_PER_CORE: usize = 4;

/// `--threads`, clamped to 1..=THREADS_PER_CORE × cores with a warning.
fn clamp_threads(n: usize) -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
    let max = cores * THREADS_PER_CORE;
    if n == 0 || n > max {
        let to = n.clamp(1, max);
        eprintln!(
            "warning[sdfl::arg::threads]: --threads {n} is outside 1..={max} ({THREADS_PER_CORE} per core on {cores} cores); using {to}"
        );
        to
    } else {
        n
    }
}

/// Lines on stdout. A closed pipe (`sdfl run | head -0`) is a normal end:
/// the reader wants no more, so the rest is dropped and sdfl exits 0.
struct Stdout {
    closed: bool,
}

impl Stdout {
    fn new() -> Self {
        Stdout { closed: false }
    }
    fn print(&mut self, text: &str) {
        use std::io::Write;
        if self.closed {
            return;
        }
        let mut out = std::io::stdout().lock();
        if let Err(e) = out.write_all(text.as_bytes()).and_then(|_| out.flush()) {
            if e.kind() != std::io::ErrorKind::BrokenPipe {
                eprintln!("warning[sdfl::io]: cannot write to stdout: {e}");
            }
            self.closed = true;
        }
    }
    fn line(&mut self, text: &str) {
        self.print(&format!("{text}\n"));
    }
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

fn parse_set(s: &str) -> Result<(String, Vec<f64>), String> {
    let (name, values) = s.split_once('=').ok_or("expected NAME=V1,V2,...")?;
    let values: Result<Vec<f64>, _> = values.split(',').map(|v| v.trim().parse::<f64>()).collect();
    let values = values.map_err(|e| format!("bad value: {e}"))?;
    if values.len() < 2 || values.iter().any(|v| !v.is_finite()) {
        return Err("give at least two finite values".into());
    }
    Ok((name.trim().to_string(), values))
}

/// One line on what a field is and what it will compute.
fn describe_field(field: &sdfl_stdlib::value::Field) -> String {
    use sdfl_stdlib::value::{Encoding, Field};
    let enc = |e: &Encoding| match e {
        Encoding::Harmonic(h) => format!(
            "harmonic({}{})",
            h.freqs,
            if h.include_input { "" } else { ", no input" }
        ),
        Encoding::HashGrid(g) => format!(
            "hashgrid({} levels x {} features, 2^{} rows, {}..{} cells a side)",
            g.levels, g.features, g.log2_table, g.min_res, g.max_res
        ),
    };
    match field {
        Field::NeuralSdf(n) => format!(
            "neural SDF: harmonic({}) position, {}x{} softplus(beta {}) layers{}; {} multiply-adds per point and 3x that for its exact gradient",
            n.encoding.freqs,
            n.layers,
            n.width,
            n.beta,
            if n.skips.is_empty() {
                String::new()
            } else {
                format!(" (position again at layers {:?})", n.skips)
            },
            n.multiply_adds()
        ),
        Field::Sdf(f) => format!(
            "{:?} density, alpha {}, beta {}, {} primitives",
            f.density,
            f.alpha.value,
            f.beta.value,
            f.shape.primitive_count()
        ),
        Field::Nerf(n) => format!(
            "NeRF: {} position, {}x{} ReLU trunk{}, {:?} density, {}; {} multiply-adds per sample{}; {}",
            enc(&n.position),
            n.layers,
            n.width,
            if n.skips.is_empty() {
                String::new()
            } else {
                format!(" (position again at layers {:?})", n.skips)
            },
            n.density,
            match &n.direction {
                Some(d) => format!(
                    "view-dependent colour ({} direction, {}-wide branch)",
                    enc(d),
                    n.color_width
                ),
                None => "colour without the view direction (no direction branch built)".into(),
            },
            n.multiply_adds_per_sample(),
            match n.fine {
                0 => " (one network)".to_string(),
                m => format!(", twice: coarse, and fine on the coarse samples + {m} by inverse CDF"),
            },
            match &n.occupancy {
                Some(o) => format!(
                    "occupancy grid {}^3 refreshed every {} steps: samples only in occupied cells",
                    o.resolution, o.every
                ),
                None => "every sample evaluated (no occupancy grid)".into(),
            }
        ),
    }
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
            restart,
        } => {
            if let Some(n) = threads {
                let n = clamp_threads(n);
                if let Err(e) = rayon::ThreadPoolBuilder::new()
                    .num_threads(n)
                    .build_global()
                {
                    eprintln!("error[sdfl::io]: cannot set up {n} threads: {e}");
                    return ExitCode::FAILURE;
                }
            }
            run(
                file.as_deref(),
                &out,
                RunOptions {
                    size,
                    no_cull,
                    restart,
                },
                json,
            )
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
            Stdout::new().print(&plan_text(&program));
            ExitCode::SUCCESS
        }
        Command::Sweep {
            file,
            set,
            out,
            size,
        } => sweep(&file, &set.0, &set.1, &out, size),
        Command::Docs { name } => docs(name.as_deref()),
        Command::Transmittance { out } => {
            let (w, h) = (640, 360);
            let (rgb, t) = sdfl_runtime::volume::figures::transmittance_figure(w, h);
            let names = ["T(y1, y2)", "T(y2, y4)", "T(x, y4)", "T(x, y3)"];
            let exact = [
                (-2.0f64).exp(),
                (-30.5f64).exp(),
                (-32.5f64).exp(),
                (-2.5f64).exp(),
            ];
            let mut stdout = Stdout::new();
            for ((n, v), e) in names.iter().zip(t).zip(exact) {
                stdout.line(&format!(
                    "{n:<10} = {v:.4e}   (exact {e:.4e}, relative error {:.1e})",
                    (v - e).abs() / e
                ));
            }
            let Ok(out) = out_dir(&out) else {
                return ExitCode::FAILURE;
            };
            let path = out.join("transmittance.png");
            match sdfl_runtime::output::write_png(&path, w, h, &rgb) {
                Ok(()) => {
                    stdout.line(&path.display().to_string());
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("error[sdfl::io]: {e}");
                    ExitCode::FAILURE
                }
            }
        }
    }
}

/// Largest scene file read (a megabyte of source is already extreme).
const MAX_SOURCE_BYTES: u64 = 64 << 20;

/// Reads a scene file: a regular file (not a FIFO or `/dev/zero`, which
/// would block or never end) of at most [`MAX_SOURCE_BYTES`].
fn read(path: &Path) -> Result<SourceFile, ()> {
    use std::io::Read;
    let bytes = sdfl_runtime::data::image::open_regular(path).and_then(|f| {
        let mut bytes = Vec::new();
        f.take(MAX_SOURCE_BYTES + 1).read_to_end(&mut bytes)?;
        if bytes.len() as u64 > MAX_SOURCE_BYTES {
            return Err(std::io::Error::other(format!(
                "{}: larger than {MAX_SOURCE_BYTES} bytes",
                path.display()
            )));
        }
        Ok(bytes)
    });
    match bytes {
        Ok(bytes) => {
            let text = String::from_utf8_lossy(&bytes).into_owned();
            Ok(SourceFile::new(path.display().to_string(), text))
        }
        Err(e) => {
            eprintln!("error[sdfl::io]: cannot read the scene file: {e}\n  help: give the path of a .sdfl file");
            Err(())
        }
    }
}

/// Loads a file, printing its diagnostics: errors fail, warnings do not.
fn load(src: &SourceFile) -> Result<sdfl_stdlib::Program, ()> {
    let color = std::io::stderr().is_terminal();
    match sdfl_stdlib::load_warned(src) {
        Ok((program, warnings)) => {
            if !warnings.is_empty() {
                eprint!("{}", sdfl_lang::render(src, &warnings, color));
            }
            Ok(program)
        }
        Err(diags) => {
            eprint!("{}", sdfl_lang::render(src, &diags, color));
            Err(())
        }
    }
}

/// Creates the output directory and returns its canonical path: outputs
/// are confined to it (no link inside it is followed; see
/// `sdfl_runtime::output`).
fn out_dir(out: &Path) -> Result<PathBuf, ()> {
    let made = sdfl_runtime::output::ensure_dir(out).or_else(|e| {
        // `--out` itself may be a link the user chose; follow that one.
        if out.is_dir() {
            Ok(())
        } else {
            Err(e)
        }
    });
    match made.and_then(|()| std::fs::canonicalize(out)) {
        Ok(p) => Ok(p),
        Err(e) => {
            eprintln!(
                "error[sdfl::io]: cannot use {} as the output directory: {e}\n  help: give `--out` a directory that can be created and written",
                out.display()
            );
            Err(())
        }
    }
}

/// A run-time error as a diagnostic at the statement that failed.
fn runtime_error(src: &SourceFile, job: &str, e: &std::io::Error) -> String {
    use std::io::ErrorKind as K;
    let help = match e.kind() {
        K::PermissionDenied => {
            "check that the output directory (`--out`) is writable and holds no symbolic links"
        }
        K::AlreadyExists => "something else is in the way: choose another `--out`, or move it",
        K::InvalidData | K::InvalidInput => "check the files this statement reads",
        K::NotFound => {
            "check that the files this statement reads exist (paths are relative to the scene file)"
        }
        _ => "the message names the file concerned",
    };
    let span = statement_span(src, job);
    let diag = sdfl_lang::Diag::new(
        sdfl_lang::codes::IO,
        span.unwrap_or_default(),
        e.to_string(),
    )
    .label(format!("while running `{job}`"))
    .help(help);
    let mut diags = sdfl_lang::Diagnostics::default();
    diags.push(diag);
    if span.is_some() {
        sdfl_lang::render(src, &diags, std::io::stderr().is_terminal())
    } else {
        format!(
            "error[{}]: `{job}`: {e}\n  help: {help}\n",
            sdfl_lang::codes::IO
        )
    }
}

/// The span of the statement named `job` (as `stdlib::eval` names them:
/// its name, or its kind and index).
fn statement_span(src: &SourceFile, job: &str) -> Option<sdfl_lang::Span> {
    let file = sdfl_lang::parse::parse(&src.text).ok()?;
    file.items
        .iter()
        .filter_map(|i| match i {
            sdfl_lang::ast::Item::Block(b) => Some(b),
            _ => None,
        })
        .enumerate()
        .find(|(k, b)| {
            b.name
                .as_ref()
                .map_or_else(|| format!("{}{k}", b.kind.name) == job, |n| n.name == job)
        })
        .map(|(_, b)| {
            b.name
                .as_ref()
                .map_or(b.kind.span, |n| b.kind.span.to(n.span))
        })
}

/// Run every statement of a program, returning one JSON report per job.
fn execute(
    program: &sdfl_stdlib::Program,
    out: &Path,
    options: RunOptions,
    base: &Path,
    bar: &ProgressBar,
) -> Result<Vec<serde_json::Value>, (String, std::io::Error)> {
    let mut reports = Vec::new();
    let io = |name: &str, e: std::io::Error| (name.to_string(), e);
    // In file order: a render after a `train` may read what it wrote.
    for statement in &program.order {
        match *statement {
            Statement::Render(i) => {
                let job = &program.renders[i];
                bar.set_message(job.name.clone());
                let r =
                    run_job(job, out, options, &|n| bar.inc(n)).map_err(|e| io(&job.name, e))?;
                reports.push(serde_json::json!({"kind": "render", "report": r}));
            }
            Statement::Volume(i) => {
                let job = &program.volumes[i];
                bar.set_message(job.name.clone());
                let r = jobs::run_volume_job(job, out, options.size, &|n| bar.inc(n))
                    .map_err(|e| io(&job.name, e))?;
                reports.push(serde_json::json!({"kind": "volume", "report": r}));
            }
            Statement::Train(i) => {
                let job = &program.trains[i];
                bar.set_message(job.name.clone());
                let train = jobs::TrainOptions {
                    restart: options.restart,
                };
                let r = jobs::run_train_job(
                    job,
                    out,
                    base,
                    options.size,
                    train,
                    &|n| bar.inc(n),
                    &|m| bar.set_message(m.to_string()),
                )
                .map_err(|e| io(&job.name, e))?;
                reports.push(serde_json::json!({"kind": "train", "report": r}));
            }
        }
    }
    Ok(reports)
}

/// Pixels and iterations of a program, for the progress bar.
fn work(program: &sdfl_stdlib::Program, size: Option<(u32, u32)>) -> u64 {
    let px = |w: u32, h: u32, n: usize| {
        let (w, h) = size.unwrap_or((w, h));
        w as u64 * h as u64 * n as u64
    };
    program
        .renders
        .iter()
        .map(|j| px(j.width, j.height, j.cameras.len()))
        .sum::<u64>()
        + program
            .volumes
            .iter()
            .map(|j| px(j.width, j.height, j.cameras.len()))
            .sum::<u64>()
        + program
            .trains
            .iter()
            .map(|j| j.iterations as u64)
            .sum::<u64>()
}

fn progress_bar(total: u64, hidden: bool) -> ProgressBar {
    let bar = ProgressBar::new(total);
    if hidden || !std::io::stderr().is_terminal() {
        bar.set_draw_target(ProgressDrawTarget::hidden());
    }
    bar.set_style(
        ProgressStyle::with_template(
            "{msg:>12} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar
}

fn base_dir(file: Option<&Path>) -> PathBuf {
    file.and_then(Path::parent)
        .map(Path::to_path_buf)
        .unwrap_or_default()
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
    if let Err(e) = sdfl_stdlib::work::check_program(&program, options.size) {
        eprintln!("error[{}]: {e}", sdfl_lang::codes::WORK);
        return ExitCode::FAILURE;
    }
    // Written under the canonical directory, reported as the user named it.
    let shown = out;
    let Ok(out) = out_dir(out) else {
        return ExitCode::FAILURE;
    };
    let out = out.as_path();
    let load_s = t0.elapsed().as_secs_f64();
    let bar = progress_bar(work(&program, options.size), json);
    let reports = match execute(&program, out, options, &base_dir(file), &bar) {
        Ok(r) => r,
        Err((job, e)) => {
            bar.abandon();
            eprint!("{}", runtime_error(&src, &job, &e));
            return ExitCode::FAILURE;
        }
    };
    bar.finish_and_clear();
    if json {
        let summary = serde_json::json!({
            "file": src.name,
            "out_dir": shown,
            "load_seconds": load_s,
            "total_seconds": t0.elapsed().as_secs_f64(),
            "jobs": reports,
        });
        Stdout::new().line(&serde_json::to_string_pretty(&summary).expect("serialisable"));
        return ExitCode::SUCCESS;
    }
    let mut stdout = Stdout::new();
    for r in &reports {
        summarise(r, shown, &mut stdout);
    }
    ExitCode::SUCCESS
}

/// A human summary of one job's JSON report on stderr; written paths on stdout.
fn summarise(r: &serde_json::Value, out: &Path, stdout: &mut Stdout) {
    let rep = &r["report"];
    let stages: Vec<String> = rep["stages"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|s| {
                    format!(
                        "{} {:.3}s",
                        s[0].as_str().unwrap_or("?"),
                        s[1].as_f64().unwrap_or(0.0)
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    let name = rep["name"].as_str().unwrap_or("?");
    match r["kind"].as_str() {
        Some("render") => {
            let rays = rep["rays"].as_f64().unwrap_or(0.0).max(1.0);
            eprintln!(
                "{name}: {} primitives, {} views, {rays} rays ({:.1}% hit, {:.1} steps/ray); {}",
                rep["primitives"],
                rep["views"],
                100.0 * rep["hits"].as_f64().unwrap_or(0.0) / rays,
                rep["steps"].as_f64().unwrap_or(0.0) / rays,
                stages.join(", ")
            );
            let undecided = rep["undecided"].as_u64().unwrap_or(0);
            if undecided > 0 {
                eprintln!(
                    "  {undecided} rays ran out of steps before they hit or passed `far` and are drawn as misses: raise `iterations` (with `hit_tolerance: \"absolute\"`, rays grazing a surface need many)"
                );
            }
        }
        Some("volume") => eprintln!(
            "{name}: volume, {} views, {} samples/ray; {}",
            rep["views"],
            rep["samples_per_ray"],
            stages.join(", ")
        ),
        Some("train") => {
            eprintln!(
                "{name}: {} iterations{}, final loss {:.3e}, {:.2} ms/step; {}",
                rep["iterations"],
                rep["resumed_from"]
                    .as_u64()
                    .map(|k| format!(" (resumed at {k})"))
                    .unwrap_or_default(),
                rep["final_loss"].as_f64().unwrap_or(f64::NAN),
                rep["seconds_per_step"].as_f64().unwrap_or(0.0) * 1e3,
                stages.join(", ")
            );
            if let Some(fit) = rep.get("fit").filter(|f| f.is_object()) {
                let num = |k: &str| fit[k].as_f64().unwrap_or(f64::NAN);
                eprintln!(
                    "  fit: mean |f| at the points {:.2e}, eikonal {:.2e}, Chamfer {:.4} ({} surface samples)",
                    num("surface_mean_abs"),
                    num("eikonal"),
                    num("chamfer"),
                    fit["surface_samples"]
                );
            }
            for p in rep["params"].as_array().into_iter().flatten() {
                let vals: Vec<String> = p[1]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|v| format!("{:.4}", v.as_f64().unwrap_or(f64::NAN)))
                    .collect();
                eprintln!(
                    "  {:<12} ({})",
                    p[0].as_str().unwrap_or("?"),
                    vals.join(", ")
                );
            }
        }
        _ => {}
    }
    for w in rep["written"].as_array().into_iter().flatten() {
        stdout.line(
            &out.join(w["path"].as_str().unwrap_or(""))
                .display()
                .to_string(),
        );
    }
}

/// ", N held out as test views" (empty for none).
fn held_out(n: usize) -> String {
    match n {
        0 => String::new(),
        n => format!(", {n} held out as test views"),
    }
}

fn plan_text(program: &sdfl_stdlib::Program) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let row = |o: &mut String, what: &str, who: &[String]| {
        let _ = if who.is_empty() {
            writeln!(o, "  {what:<14} skipped (no output needs it)")
        } else {
            writeln!(o, "  {what:<14} computed for {}", who.join(", "))
        };
    };
    for job in &program.renders {
        let plan = Plan::of(job);
        let _ = writeln!(o, "render {} (sphere tracing)", job.name);
        let _ = writeln!(
            o,
            "  scene          {} primitives, {:?}, Lipschitz bound {}",
            job.scene.primitive_count(),
            job.scene.exactness(),
            job.scene.lipschitz()
        );
        let _ = writeln!(
            o,
            "  rays           {} views x {}x{}, near {} far {}, <= {} steps, epsilon {}",
            job.cameras.len(),
            job.width,
            job.height,
            job.near,
            job.far,
            job.iterations,
            job.epsilon
        );
        row(&mut o, "colour", &plan.color);
        row(&mut o, "depth", &plan.depth);
        let mut normals = plan.normals.clone();
        if plan.shading_normals {
            normals.push("shading (the material uses normals)".into());
        }
        row(&mut o, "normals", &normals);
        if plan.shading_view {
            let _ = writeln!(
                o,
                "  view direction used for shading (a specular material: colour depends on the view)"
            );
        }
        row(&mut o, "hit mask", &plan.mask);
        for d in job
            .outputs
            .iter()
            .filter(|x| x.kind == sdfl_stdlib::OutputKind::Dataset)
        {
            let _ = writeln!(
                o,
                "  dataset        {}/transforms.json + r_0..r_{}.png (NeRF-synthetic: OpenGL poses, RGBA, alpha = hit mask)",
                d.path.display(),
                job.cameras.len() - 1
            );
        }
        let _ = writeln!(o, "  gradient tape  none (not training)");
        let _ = writeln!(
            o,
            "  work           {}",
            sdfl_stdlib::work::render_work(job, None).describe()
        );
    }
    for job in &program.volumes {
        let names = |pred: &dyn Fn(&sdfl_stdlib::OutputKind) -> bool| -> Vec<String> {
            job.outputs
                .iter()
                .filter(|x| pred(&x.kind))
                .map(|x| x.path.display().to_string())
                .collect()
        };
        use sdfl_stdlib::OutputKind as K;
        let _ = writeln!(o, "render {} (volume rendering)", job.name);
        let _ = writeln!(o, "  field          {}", describe_field(&job.field));
        let _ = writeln!(
            o,
            "  samples        {} per ray, stratified {}..{}, {} views x {}x{}",
            job.sampler.samples,
            job.sampler.near,
            job.sampler.far,
            job.cameras.len(),
            job.width,
            job.height
        );
        row(
            &mut o,
            "composite",
            &names(&|k| matches!(k, K::Image | K::Gif { .. } | K::Depth)),
        );
        row(&mut o, "depth", &names(&|k| matches!(k, K::Depth)));
        row(&mut o, "view branch", &[]);
        row(
            &mut o,
            "visual checks",
            &names(&|k| matches!(k, K::Grid | K::Rays | K::SamplePoints)),
        );
        let _ = writeln!(o, "  gradient tape  none (not training)");
        let _ = writeln!(
            o,
            "  work           {}",
            sdfl_stdlib::work::volume_work(job, None).describe()
        );
    }
    for job in &program.trains {
        let _ = writeln!(o, "train {}", job.name);
        let _ = writeln!(o, "  model          {}", describe_field(&job.model));
        let trainable = match &*job.model {
            sdfl_stdlib::value::Field::NeuralSdf(n) => {
                format!(
                    "all {} weights, starting as a sphere of radius {}",
                    sdfl_runtime::neural::distance::sdf_net(n).len,
                    n.radius
                )
            }
            sdfl_stdlib::value::Field::Sdf(f) => {
                let model = sdfl_runtime::train::TrainModel::new(f);
                let params: Vec<String> = model
                    .params
                    .iter()
                    .map(|p| format!("{} ({})", p.name, p.len))
                    .collect();
                format!("{} (gradients only for these)", params.join(", "))
            }
            sdfl_stdlib::value::Field::Nerf(n) => {
                use sdfl_runtime::train::Objective;
                match sdfl_runtime::neural::field::NerfObjective::new(n, &job.sampler) {
                    Ok(m) => format!(
                        "all {} weights in {} tensors{}",
                        m.initial().len(),
                        m.tensors().len(),
                        if m.fine.is_some() {
                            " (coarse and fine networks)"
                        } else {
                            ""
                        }
                    ),
                    Err(e) => format!("none: {e}"),
                }
            }
        };
        let _ = writeln!(o, "  trainable      {trainable}");
        let data = match &*job.data {
            sdfl_stdlib::value::Dataset::Points {
                path,
                every,
                center,
            } => format!(
                "points of {}{}{}",
                path.display(),
                if *every > 1 {
                    format!(", one in {every}")
                } else {
                    String::new()
                },
                if *center { ", centred" } else { "" }
            ),
            sdfl_stdlib::value::Dataset::Files { images, .. } => {
                format!("{} image files", images.len())
            }
            sdfl_stdlib::value::Dataset::Rendered {
                cameras,
                width,
                height,
                test,
                ..
            } => {
                format!(
                    "{} views volume-rendered by sdfl at {width}x{height}{}",
                    cameras.len(),
                    held_out(test.len())
                )
            }
            sdfl_stdlib::value::Dataset::Traced { job, test } => {
                let plan = Plan::of(&sdfl_stdlib::RenderJob {
                    outputs: vec![sdfl_stdlib::Output {
                        kind: sdfl_stdlib::OutputKind::Image,
                        path: "data".into(),
                        span: sdfl_lang::Span::default(),
                    }],
                    ..(**job).clone()
                });
                format!(
                    "{} views sphere-traced by sdfl at {}x{}, {} primitives{}{}{}",
                    job.cameras.len(),
                    job.width,
                    job.height,
                    job.scene.primitive_count(),
                    if plan.shading_normals {
                        ", shaded with normals"
                    } else {
                        ""
                    },
                    if plan.shading_view {
                        " and the view direction (view-dependent colour)"
                    } else {
                        ""
                    },
                    held_out(test.len())
                )
            }
            sdfl_stdlib::value::Dataset::NerfSynthetic {
                path,
                split,
                test_split,
                ..
            } => format!(
                "NeRF-synthetic data set {}, split `{split}`{}",
                path.display(),
                test_split
                    .as_ref()
                    .map(|t| format!(", test views from split `{t}`"))
                    .unwrap_or_default()
            ),
        };
        let _ = writeln!(o, "  data           {data}");
        let on_points = matches!(&*job.model, sdfl_stdlib::value::Field::NeuralSdf(_));
        let _ = writeln!(
            o,
            "  step           {}, {}, Adam lr {} ({}), {}",
            if on_points {
                format!(
                    "{0} surface points + {0} random points in [-{1}, {1}]^3",
                    job.rays, job.bounds
                )
            } else {
                format!(
                    "{} rays x {} samples{}",
                    job.rays,
                    job.sampler.samples,
                    if job.sampler.jitter {
                        " (jittered)"
                    } else {
                        ""
                    }
                )
            },
            job.losses
                .iter()
                .map(|l| {
                    let name = match l.kind {
                        sdfl_stdlib::value::LossKind::Mse => "MSE on colour".to_string(),
                        sdfl_stdlib::value::LossKind::Surface => "mean |f| at the points".into(),
                        sdfl_stdlib::value::LossKind::Eikonal => {
                            "eikonal (exact input gradient)".into()
                        }
                        sdfl_stdlib::value::LossKind::Inter { alpha } => {
                            format!("exp(-{alpha}|f|) at random points")
                        }
                    };
                    if l.weight == 1.0 {
                        name
                    } else {
                        format!("{} x {name}", l.weight)
                    }
                })
                .collect::<Vec<_>>()
                .join(" + "),
            job.optimizer.lr,
            match job.optimizer.schedule {
                sdfl_stdlib::value::Schedule::Constant => "constant".to_string(),
                sdfl_stdlib::value::Schedule::Step { factor, every } => {
                    format!("x{factor} every {every} steps")
                }
                sdfl_stdlib::value::Schedule::Exponential { factor, every } => {
                    format!("x{factor} per {every} steps, smoothly")
                }
            },
            match job.epochs {
                Some(e) => format!("{e} epochs"),
                None => format!("{} iterations", job.iterations),
            }
        );
        let _ = writeln!(
            o,
            "  gradient tape  {}",
            match (&*job.model, job.backend) {
                (sdfl_stdlib::value::Field::NeuralSdf(_), _) =>
                    "none: forward-mode tangents give the exact gradient of f; a hand-written second-order backward",
                (sdfl_stdlib::value::Field::Nerf(_), _) =>
                    "none: fused layer kernels with a hand-written backward through the network and the compositing",
                (_, sdfl_stdlib::value::Backend::Dfdx) =>
                    "dfdx autodiff graph over [rays, samples], the field as a custom op",
                (_, sdfl_stdlib::value::Backend::Fused) =>
                    "fused per-ray kernel: forward-mode tangents for each parameter, no tape",
            }
        );
        if !on_points {
            let _ = writeln!(o, "  depth          skipped (the loss uses colour only)");
        }
        let _ = writeln!(
            o,
            "  outputs        {} before, {} after",
            job.before.len(),
            job.after.len()
        );
        let _ = writeln!(
            o,
            "  work           {}",
            sdfl_stdlib::work::train_work(job, None).describe()
        );
    }
    o
}

/// Mean squared error of two 8-bit images of the same size.
fn mse(a: &Path, b: &Path) -> Option<f64> {
    let (a, b) = (
        image::open(a).ok()?.to_rgb8(),
        image::open(b).ok()?.to_rgb8(),
    );
    if a.dimensions() != b.dimensions() {
        return None;
    }
    let n = a.as_raw().len() as f64;
    Some(
        a.as_raw()
            .iter()
            .zip(b.as_raw())
            .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
            .sum::<f64>()
            / n,
    )
}

/// Peak signal-to-noise ratio in dB of a mean squared error on 0..255.
fn psnr(mse: f64) -> f64 {
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

/// Written colour images of a report set, by relative path.
fn images_of(reports: &[serde_json::Value]) -> Vec<String> {
    reports
        .iter()
        .flat_map(|r| {
            r["report"]["written"]
                .as_array()
                .cloned()
                .unwrap_or_default()
        })
        .filter(|w| w["kind"] == "image")
        .filter_map(|w| w["path"].as_str().map(str::to_string))
        .collect()
}

fn params_of(reports: &[serde_json::Value]) -> Vec<f64> {
    reports
        .iter()
        .flat_map(|r| {
            r["report"]["params"]
                .as_array()
                .cloned()
                .unwrap_or_default()
        })
        .flat_map(|p| p[1].as_array().cloned().unwrap_or_default())
        .filter_map(|v| v.as_f64())
        .collect()
}

/// The mean over a run's training statements of their last held-out PSNR.
fn held_out_psnr(reports: &[serde_json::Value]) -> Option<f64> {
    let last: Vec<f64> = reports
        .iter()
        .filter_map(|r| r["report"]["held_out"].as_array()?.last()?["psnr"].as_f64())
        .collect();
    (!last.is_empty()).then(|| last.iter().sum::<f64>() / last.len() as f64)
}

fn sweep(
    file: &Path,
    name: &str,
    values: &[f64],
    out: &Path,
    size: Option<(u32, u32)>,
) -> ExitCode {
    let Ok(src) = read(file) else {
        return ExitCode::FAILURE;
    };
    let Ok(out) = out_dir(out) else {
        return ExitCode::FAILURE;
    };
    let out = out.as_path();
    let mut rows = Vec::new();
    for v in values {
        let program = match sdfl_stdlib::load_with(&src, &[(name.to_string(), *v)]) {
            Ok(p) => p,
            Err(d) => {
                eprint!(
                    "{}",
                    sdfl_lang::render(&src, &d, std::io::stderr().is_terminal())
                );
                return ExitCode::FAILURE;
            }
        };
        // Each setting runs from scratch: its folder (made by sdfl) is
        // emptied first, so no checkpoint of an earlier sweep is resumed.
        let dir = out.join(format!("{name}={v}"));
        if dir.exists() {
            if let Err(e) = std::fs::remove_dir_all(&dir) {
                eprintln!("error[sdfl::io]: cannot clear {}: {e}", dir.display());
                return ExitCode::FAILURE;
            }
        }
        let bar = progress_bar(work(&program, size), false);
        bar.set_message(format!("{name}={v}"));
        let t = Instant::now();
        match execute(
            &program,
            &dir,
            RunOptions {
                size,
                no_cull: false,
                restart: true,
            },
            &base_dir(Some(file)),
            &bar,
        ) {
            Ok(reports) => {
                bar.finish_and_clear();
                rows.push((*v, t.elapsed().as_secs_f64(), dir, reports));
            }
            Err((job, e)) => {
                bar.abandon();
                eprint!("{}", runtime_error(&src, &job, &e));
                return ExitCode::FAILURE;
            }
        }
    }
    let (_, _, ref_dir, ref_reports) = rows.last().expect("at least two settings");
    let ref_images = images_of(ref_reports);
    let ref_params = params_of(ref_reports);
    let mut table = format!("| {name} | seconds | PSNR vs {name}={} (dB) | max parameter error | held-out PSNR (dB) |\n|---:|---:|---:|---:|---:|\n", values[values.len() - 1]);
    let mut csv = format!("{name},seconds,psnr_db,param_error,held_out_psnr_db\n");
    let held_out_any = rows.iter().any(|r| held_out_psnr(&r.3).is_some());
    let mut points = Vec::new();
    // The same quality against the swept value (time may hardly change).
    let mut by_value = Vec::new();
    for (row, (v, secs, dir, reports)) in rows.iter().enumerate() {
        let is_ref = row + 1 == rows.len();
        // PSNR of the mean squared error over all images of the run.
        let errors: Vec<f64> = ref_images
            .iter()
            .filter_map(|rel| mse(&dir.join(rel), &ref_dir.join(rel)))
            .collect();
        let mean_psnr =
            (!errors.is_empty()).then(|| psnr(errors.iter().sum::<f64>() / errors.len() as f64));
        let params = params_of(reports);
        let perr = (!params.is_empty() && params.len() == ref_params.len()).then(|| {
            params
                .iter()
                .zip(&ref_params)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        });
        // Only the reference row is "ref"; another run whose images equal
        // the reference's has an infinite PSNR and says so.
        let fmt = |x: Option<f64>, prec: usize| {
            x.map_or("-".to_string(), |x| {
                if is_ref {
                    "ref".into()
                } else if x.is_infinite() {
                    "identical (∞)".into()
                } else {
                    format!("{x:.prec$}")
                }
            })
        };
        let held = held_out_psnr(reports);
        table.push_str(&format!(
            "| {v} | {secs:.3} | {} | {} | {} |\n",
            fmt(mean_psnr, 2),
            fmt(perr, 5),
            held.map_or("-".to_string(), |x| format!("{x:.2}"))
        ));
        csv.push_str(&format!(
            "{v},{secs},{},{},{}\n",
            mean_psnr.map_or(String::new(), |x| x.to_string()),
            perr.map_or(String::new(), |x| x.to_string()),
            held.map_or(String::new(), |x| x.to_string())
        ));
        // The plot: quality against time: held-out PSNR where training
        // held views out, else PSNR against the reference, else parameter error.
        let y = if held_out_any {
            held
        } else {
            mean_psnr.filter(|p| p.is_finite()).or(perr)
        };
        if let Some(y) = y {
            points.push((*secs, y));
            by_value.push((*v, y));
        }
    }
    Stdout::new().print(&table);
    let write = |rel: &str, bytes: &[u8]| -> std::io::Result<()> {
        let mut f = sdfl_runtime::output::Atomic::create(&out.join(rel))?;
        std::io::Write::write_all(f.writer(), bytes)?;
        f.commit()
    };
    let log_y = ref_images.is_empty() && !held_out_any;
    let png = sdfl_runtime::volume::figures::line_plot(
        640,
        400,
        &[(
            if held_out_any {
                "held-out PSNR (dB) vs seconds"
            } else {
                "error vs seconds"
            },
            &points,
        )],
        log_y,
    );
    let value_label = format!(
        "{} vs {name}",
        if held_out_any {
            "held-out PSNR (dB)"
        } else {
            "error"
        }
    );
    let value_png = sdfl_runtime::volume::figures::line_plot(
        640,
        400,
        &[(value_label.as_str(), &by_value)],
        log_y,
    );
    let result = write("sweep.csv", csv.as_bytes())
        .and_then(|_| write("sweep.md", table.as_bytes()))
        .and_then(|_| sdfl_runtime::output::write_png(&out.join("sweep.png"), 640, 400, &png))
        .and_then(|_| {
            sdfl_runtime::output::write_png(&out.join("sweep_value.png"), 640, 400, &value_png)
        });
    match result {
        Ok(()) => {
            eprintln!(
                "wrote {0}/sweep.csv, {0}/sweep.md, {0}/sweep.png (against seconds) and {0}/sweep_value.png (against the value)",
                out.display()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!(
                "error[sdfl::io]: writing the sweep results under {}: {e}",
                out.display()
            );
            ExitCode::FAILURE
        }
    }
}

fn docs(name: Option<&str>) -> ExitCode {
    let env = sdfl_stdlib::StdEnv::get();
    let mut o = Stdout::new();
    match name {
        None => {
            for b in env.blocks() {
                o.line(&format!("{:<20} statement: {}", b.kind, b.doc));
            }
            for b in env.builtins() {
                o.line(&format!("{:<20} {}", b.sig.name, b.sig.doc));
            }
            ExitCode::SUCCESS
        }
        Some(n) => {
            if let Some(b) = env.builtin(n) {
                o.line(&format!("{}\n\n{}\n", b.sig.synopsis(), b.sig.doc));
                for p in &b.sig.params {
                    o.line(&format!("  {:<12} {}", p.name, p.doc));
                }
                return ExitCode::SUCCESS;
            }
            if let Some(b) = env.block_sig(n) {
                o.line(&format!("{} name {{ ... }}\n\n{}\n", b.kind, b.doc));
                for p in &b.fields {
                    let d = p
                        .default
                        .map(|d| format!(" (default {d})"))
                        .unwrap_or_default();
                    o.line(&format!("  {:<12} {}{d}", p.name, p.doc));
                }
                return ExitCode::SUCCESS;
            }
            eprintln!("error: no built-in named `{n}`; `sdfl docs` lists them");
            ExitCode::FAILURE
        }
    }
}
