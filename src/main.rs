//! `sdfl`: run, check and inspect scene files.
#![warn(missing_docs)]

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::{CommandFactory, Parser, Subcommand};
use sdfl_lang::SourceFile;
use sdfl_runtime::{jobs, run_job, Plan, RunOptions};
use sdfl_stdlib::value::{Statement, StatementKind};

#[macro_use]
mod term;
mod completions;
mod fmt;
mod json;
mod plan;
mod progress;
mod sweep;
mod view;
mod watch;

use progress::Progress;
use sdfl_runtime::interrupt::{self, Stopped};
use sdfl_runtime::output::OutDir;
use sweep::sweep;
use term::say_raw;

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
        /// Print every file's diagnostics as JSON on stdout (for editors).
        #[arg(long)]
        json: bool,
    },
    /// Show what each statement of a file will compute, and why.
    Plan { file: PathBuf },
    /// Re-run a file over settings of a top-level `let` and tabulate time
    /// against error (PSNR against the last setting's images, or parameter
    /// distance for training); writes sweep.csv, sweep.md and sweep.png.
    /// Each setting runs in OUT/NAME=VALUE/ (emptied first, unless an
    /// interrupted run of the same setting is resumed); its row goes to
    /// OUT/rows/NAME=VALUE.json when it finishes, and a rerun skips the
    /// settings whose row stands for the same file and setting.
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
        /// I/N: run only shard I of N (from 0; setting k of `--set` is
        /// shard k mod N's) and write its rows, not the table.
        #[arg(long, value_parser = sweep::parse_shard)]
        shard: Option<sweep::Shard>,
        /// Run nothing: write the table and plots from the rows in OUT
        /// (every shard's, copied into one folder).
        #[arg(long, conflicts_with = "shard")]
        collect: bool,
        /// Run nothing: list the settings (of this shard) and whether each
        /// is done or to run.
        #[arg(long)]
        dry_run: bool,
    },
    /// Run a scene file, then again each time it is saved: only statements
    /// whose inputs changed run again (fingerprints kept in
    /// OUT/.sdfl-watch.json); diagnostics show at once.
    Watch {
        file: PathBuf,
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Override every render's image size, as WIDTHxHEIGHT.
        #[arg(long, value_parser = parse_size)]
        size: Option<(u32, u32)>,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Stop after this many runs (the first, then one per change).
        #[arg(long)]
        max_runs: Option<usize>,
    },
    /// Serve a local web viewer of a file on 127.0.0.1: orbit and zoom its
    /// render scenes and trained fields (from their checkpoints in OUT),
    /// reloaded on save; training curves and held-out views from OUT while
    /// a run (here or in another process) trains.
    View {
        file: PathBuf,
        /// Where training writes its metrics and held-out views.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Port on 127.0.0.1 (0 picks a free one and prints it).
        #[arg(long, default_value_t = 7878)]
        port: u16,
        /// Worker threads for tracing frames (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Seconds a response may make no progress before its connection
        /// is closed (a client that stops reading frees its slot).
        #[arg(long, default_value_t = view::WRITE_STALL.as_secs_f64(), value_parser = write_stall)]
        write_stall: f64,
    },
    /// The assignment's part 0: transmittance through three slabs; prints
    /// the four transmittances and writes the figure.
    Transmittance {
        #[arg(long, default_value = "out")]
        out: PathBuf,
    },
    /// List the built-in functions and statements, or describe one.
    Docs { name: Option<String> },
    /// Format files in place in the canonical layout (comments kept).
    Fmt(fmt::FmtArgs),
    /// Print the shell's completion script, e.g. `sdfl completions bash`.
    Completions { shell: clap_complete::Shell },
}

/// Most worker threads per core: more only spend time spawning and
/// switching (100 000 threads took a minute to start).
const THREADS_PER_CORE: usize = 4;

/// `--write-stall`: finite seconds from 0.1 to a day (a zero stall would
/// drop every connection at its first full socket buffer).
fn write_stall(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|e| format!("{e}"))?;
    if (0.1..=86_400.0).contains(&v) {
        Ok(v)
    } else {
        Err("seconds from 0.1 to 86400".into())
    }
}

fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |c| c.get())
}

/// A thread count from `source` (`--threads N`), clamped to
/// 1..=THREADS_PER_CORE × cores with a warning.
fn clamp_threads(n: usize, source: &str) -> usize {
    let cores = cores();
    let max = cores * THREADS_PER_CORE;
    if n == 0 || n > max {
        let to = n.clamp(1, max);
        say!(
            "warning[sdfl::arg::threads]: {source} is outside 1..={max} ({THREADS_PER_CORE} per core on {cores} cores); using {to}"
        );
        to
    } else {
        n
    }
}

/// The worker threads: `--threads`, else `RAYON_NUM_THREADS` (which rayon
/// would read itself, unbounded: 100 000 left sdfl asleep), clamped alike;
/// neither given, rayon's default (one per core).
fn set_up_threads(flag: Option<usize>, env: Option<&OsStr>) -> Result<(), ()> {
    let n = match (flag, env) {
        (Some(n), _) => clamp_threads(n, &format!("--threads {n}")),
        (None, Some(v)) => match v.to_str().map(|v| v.trim().parse::<usize>()) {
            // Rayon's meaning of 0: one per core.
            Some(Ok(0)) => cores(),
            Some(Ok(n)) => clamp_threads(n, &format!("RAYON_NUM_THREADS={n}")),
            _ => {
                say!(
                    "warning[sdfl::arg::threads]: RAYON_NUM_THREADS={} is not a number; using {} (one per core)",
                    v.to_string_lossy(),
                    cores()
                );
                cores()
            }
        },
        (None, None) => return Ok(()),
    };
    // An explicit count: rayon then ignores RAYON_NUM_THREADS.
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build_global()
        .map_err(|e| say!("error[sdfl::io]: cannot set up {n} threads: {e}"))
}

/// Handles SIGINT and SIGTERM for commands that write (a failure to is
/// only a warning: the default handling still stops the process).
fn handle_signals() {
    if let Err(e) = interrupt::install() {
        say!("warning[sdfl::io]: cannot handle signals ({e}); an interrupted run may leave `.sdfl-*.tmp` files, removed by the next run");
    }
}

/// Lines on stdout. A closed pipe (`sdfl run | head -0`) is a normal end:
/// the reader wants no more, so the rest is dropped and sdfl exits 0. Any
/// other error (a full disk) loses what a script reads: exit 1.
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
                // A full disk or an I/O error lost what a script reads
                // (the `--json` report): that is a failure, not a success.
                say!("error[sdfl::io]: cannot write to stdout: {e}\n  help: free space on (or fix) the device stdout goes to");
                std::process::exit(1);
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

fn main() -> ExitCode {
    let cli = Cli::parse();
    // The limit every statement's estimate is checked against: a bad
    // value is refused, not silently replaced by the default.
    let limit = std::env::var(sdfl_stdlib::work::MAX_EVALUATIONS_VAR).ok();
    if let Err(e) = sdfl_stdlib::work::max_evaluations_from(limit.as_deref()) {
        say!("error[sdfl::arg::max_evaluations]: {e}");
        return ExitCode::FAILURE;
    }
    let memory = std::env::var(sdfl_stdlib::work::MAX_MEMORY_VAR).ok();
    if let Err(e) = sdfl_stdlib::work::max_memory_from(memory.as_deref()) {
        say!("error[sdfl::arg::max_memory]: {e}");
        return ExitCode::FAILURE;
    }
    let threads = match cli.command {
        Command::Run { threads, .. }
        | Command::Watch { threads, .. }
        | Command::View { threads, .. } => threads,
        _ => None,
    };
    if matches!(
        cli.command,
        Command::Run { .. }
            | Command::Sweep { .. }
            | Command::Transmittance { .. }
            | Command::Watch { .. }
            | Command::View { .. }
            | Command::Fmt(_)
    ) {
        if set_up_threads(threads, std::env::var_os("RAYON_NUM_THREADS").as_deref()).is_err() {
            return ExitCode::FAILURE;
        }
        handle_signals();
    }
    match cli.command {
        Command::Run {
            file,
            out,
            size,
            threads: _,
            json,
            no_cull,
            restart,
        } => run(
            file.as_deref(),
            &out,
            RunOptions {
                size,
                no_cull,
                restart,
            },
            json,
        ),
        Command::Check { files, json: true } => check_json(&files),
        Command::Check { files, json: false } => {
            let mut ok = true;
            for f in &files {
                match read(f).and_then(|src| load(&src).map(|_| ())) {
                    Ok(()) => say!("{}: ok", f.display()),
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
            Stdout::new().print(&plan::plan_text_in(&program, &base_dir(Some(&file))));
            ExitCode::SUCCESS
        }
        Command::Sweep {
            file,
            set,
            out,
            size,
            shard,
            collect,
            dry_run,
        } => sweep(sweep::SweepArgs {
            file: &file,
            name: &set.0,
            values: &set.1,
            out: &out,
            size,
            shard,
            collect,
            dry_run,
        }),
        Command::Docs { name } => docs(name.as_deref()),
        Command::Watch {
            file,
            out,
            size,
            threads: _,
            max_runs,
        } => watch::watch(watch::Watch {
            file,
            out,
            options: RunOptions {
                size,
                ..RunOptions::default()
            },
            max_runs,
        }),
        Command::View {
            file,
            out,
            port,
            threads: _,
            write_stall,
        } => view::view(view::View {
            file,
            out,
            port,
            write_stall: std::time::Duration::from_secs_f64(write_stall),
        }),
        Command::Fmt(args) => fmt::fmt(&args),
        Command::Completions { shell } => {
            Stdout::new().print(&completions::completion_script(shell, &mut Cli::command()));
            ExitCode::SUCCESS
        }
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
            let Ok((out, _lock)) = out_dir(&out) else {
                return ExitCode::FAILURE;
            };
            let path = out.join("transmittance.png");
            match sdfl_runtime::output::write_png(&path, w, h, &rgb) {
                Ok(()) => {
                    stdout.line(&path.display().to_string());
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    say!("error[sdfl::io]: {e}");
                    ExitCode::FAILURE
                }
            }
        }
    }
}

/// Largest scene file read (a megabyte of source is already extreme).
const MAX_SOURCE_BYTES: u64 = 64 << 20;

/// Reads a scene file: a regular file (not a FIFO or `/dev/zero`, which
/// would block or never end) of at most [`MAX_SOURCE_BYTES`], in UTF-8.
fn read(path: &Path) -> Result<SourceFile, ()> {
    read_source(path).map_err(|e| match e {
        Unread::Io(e) => say!("error[sdfl::io]: {e}\n  help: {READ_HELP}"),
        Unread::Encoding(src, diags) => say_raw(&sdfl_lang::render(&src, &diags, term::color())),
    })
}

/// What to do when a scene file cannot be read.
const READ_HELP: &str = "give the path of a .sdfl file";

/// Why a scene file was not read.
enum Unread {
    /// It cannot be read (the message names it).
    Io(String),
    /// It is not UTF-8: its diagnostic, placed in the text as decoded
    /// lossily (only to show where).
    Encoding(SourceFile, sdfl_lang::Diagnostics),
}

/// Reads a scene file, or says why it cannot.
fn read_source(path: &Path) -> Result<SourceFile, Unread> {
    let bytes = sdfl_stdlib::files::read_capped(path, MAX_SOURCE_BYTES)
        .map_err(|e| Unread::Io(format!("cannot read the scene file: {e}")))?;
    let name = path.display().to_string();
    sdfl_stdlib::files::utf8(bytes)
        .map(|text| SourceFile::new(name.clone(), text))
        .map_err(|bad| {
            let mut diags = sdfl_lang::Diagnostics::default();
            diags.push(bad.diag());
            Unread::Encoding(SourceFile::new(name, bad.lossy), diags)
        })
}

/// Loads a file, printing its diagnostics: errors fail, warnings do not.
fn load(src: &SourceFile) -> Result<sdfl_stdlib::Program, ()> {
    load_diagnosed(src).map(|p| p.0).map_err(drop)
}

/// [`load`], also returning the diagnostics (the warnings on success).
fn load_diagnosed(
    src: &SourceFile,
) -> Result<(sdfl_stdlib::Program, sdfl_lang::Diagnostics), sdfl_lang::Diagnostics> {
    let color = term::color();
    match sdfl_stdlib::load_warned(src) {
        Ok((program, warnings)) => {
            if !warnings.is_empty() {
                say_raw(&sdfl_lang::render(src, &warnings, color));
            }
            Ok((program, warnings))
        }
        Err(diags) => {
            say_raw(&sdfl_lang::render(src, &diags, color));
            Err(diags)
        }
    }
}

/// `sdfl check --json`: each file's diagnostics (also rendered on stderr).
fn check_json(files: &[PathBuf]) -> ExitCode {
    let entries = files
        .iter()
        .map(|f| {
            let name = f.display().to_string();
            let diags = match read_source(f) {
                Err(Unread::Io(e)) => {
                    vec![json::unplaced(&name, sdfl_lang::codes::IO, &e, READ_HELP)]
                }
                Err(Unread::Encoding(src, diags)) => {
                    say_raw(&sdfl_lang::render(&src, &diags, term::color()));
                    json::diagnostics(&src, &diags)
                }
                Ok(src) => match load_diagnosed(&src) {
                    Ok((_, warnings)) => json::diagnostics(&src, &warnings),
                    Err(errors) => json::diagnostics(&src, &errors),
                },
            };
            json::checked(&name, diags)
        })
        .collect();
    let report = json::check_report(entries);
    Stdout::new().line(&serde_json::to_string_pretty(&report).expect("serialisable"));
    if report["ok"] == true {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

/// Creates the output directory and returns its canonical path: outputs
/// are confined to it (no link inside it is followed; see
/// `sdfl_runtime::output`). It is checked to be writable now, before any
/// work, and held (the lock) so that a run starting there meanwhile does
/// not take this one's temporary files for stale ones.
fn out_dir(out: &Path) -> Result<(PathBuf, OutDir), ()> {
    open_out_dir(out).map_err(|e| say!("error[sdfl::io]: {e}\n  help: {OUT_DIR_HELP}"))
}

/// What to do when `--out` cannot be used.
const OUT_DIR_HELP: &str = "give `--out` a directory that can be created and written";

/// [`out_dir`], saying why not instead of printing it.
fn open_out_dir(out: &Path) -> Result<(PathBuf, OutDir), String> {
    let made = sdfl_runtime::output::ensure_dir(out).or_else(|e| {
        // `--out` itself may be a link the user chose; follow that one.
        if out.is_dir() {
            Ok(())
        } else {
            Err(e)
        }
    });
    let opened = made
        .and_then(|()| std::fs::canonicalize(out))
        .and_then(|p| OutDir::open(&p).map(|o| (p, o)));
    match opened {
        Ok((p, (lock, stale))) => {
            if stale > 0 {
                say!(
                    "note: removed {stale} unfinished `.sdfl-*.tmp` file{} that an interrupted run left in {}",
                    if stale == 1 { "" } else { "s" },
                    out.display()
                );
            }
            Ok((p, lock))
        }
        Err(e) => Err(format!(
            "cannot use {} as the output directory: {e}",
            out.display()
        )),
    }
}

/// Reports a run that failed in `job` and returns the exit status: a
/// diagnostic and 1, or, for a stop by a signal, where it stopped and
/// 128 + the signal.
fn failed(src: &SourceFile, job: &str, e: &std::io::Error) -> ExitCode {
    failed_as(src, job, e, false)
}

/// [`failed`], also printing the failure as JSON on stdout with `json`.
fn failed_as(src: &SourceFile, job: &str, e: &std::io::Error, json: bool) -> ExitCode {
    // Refused because a signal is stopping the process: that thread
    // reports and exits (130 or 143); returning 1 first would race it.
    interrupt::wait_if_exiting();
    if let Some(stop) = Stopped::of(e) {
        say!("sdfl: {stop}");
        if json {
            let stopped = serde_json::json!({ "signal": stop.signal, "message": stop.to_string() });
            print_json(&json::run_failed(&src.name, Vec::new(), Some(stopped)));
        }
        return ExitCode::from(interrupt::exit_code(stop.signal));
    }
    let (diag, placed) = runtime_diag(src, job, e);
    let mut diags = sdfl_lang::Diagnostics::default();
    diags.push(diag);
    if json {
        let d = &diags.diags[0];
        let d = if placed {
            json::diagnostic(src, &diags, d)
        } else {
            json::unplaced(
                &src.name,
                d.code,
                &d.message,
                d.help.as_deref().unwrap_or(""),
            )
        };
        print_json(&json::run_failed(&src.name, vec![d], None));
    }
    say_raw(&if placed {
        sdfl_lang::render(src, &diags, term::color())
    } else {
        let d = &diags.diags[0];
        format!(
            "error[{}]: `{job}`: {e}\n  help: {}\n",
            d.code,
            d.help.as_deref().unwrap_or("")
        )
    });
    ExitCode::FAILURE
}

/// A report on stdout as pretty JSON.
fn print_json(v: &serde_json::Value) {
    Stdout::new().line(&serde_json::to_string_pretty(v).expect("serialisable"));
}

/// A failure before any statement ran, as `error[code]: message` and
/// help on stderr, and with `json` as a JSON report on stdout.
fn failed_early(file: &str, code: &str, message: &str, help: &str, json: bool) -> ExitCode {
    if help.is_empty() {
        say!("error[{code}]: {message}");
    } else {
        say!("error[{code}]: {message}\n  help: {help}");
    }
    if json {
        print_json(&json::run_failed(
            file,
            vec![json::unplaced(file, code, message, help)],
            None,
        ));
    }
    ExitCode::FAILURE
}

/// A run-time error as a diagnostic at the statement that failed, and
/// whether it has a place in the file.
fn runtime_diag(src: &SourceFile, job: &str, e: &std::io::Error) -> (sdfl_lang::Diag, bool) {
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
    // At the argument that named the input, where the error carries it
    // (and it is in this file, not an imported one).
    let argument = sdfl_runtime::data::argument_span(e).filter(|s| s.end <= src.text.len());
    let span = argument.or_else(|| statement_span(src, job));
    let label = match argument {
        Some(_) => format!("read while running `{job}`"),
        None => format!("while running `{job}`"),
    };
    let non_finite = sdfl_runtime::train::is_non_finite(e);
    let (code, help) = if non_finite {
        (
            sdfl_runtime::train::NON_FINITE,
            "the fit diverged: lower the learning rate (`adam(lr: ...)`), then run again (it resumes from the kept checkpoint; `--restart` starts over)",
        )
    } else if let Some(c) = sdfl_runtime::data::coded(e) {
        (c.code, c.help)
    } else {
        (sdfl_lang::codes::IO, help)
    };
    let diag = sdfl_lang::Diag::new(code, span.unwrap_or_default(), e.to_string())
        .label(label)
        .help(help);
    (diag, span.is_some())
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
    progress: &Progress,
) -> Result<Vec<Report>, (String, std::io::Error)> {
    let mut reports = Vec::new();
    let io = |name: &str, e: std::io::Error| (name.to_string(), e);
    let size = options.size;
    let inc = |n| progress.inc(n);
    // In file order: a render after a `train` may read what it wrote.
    for statement in &program.order {
        match *statement {
            Statement::Render(i) => {
                let job = &program.renders[i];
                interrupt::running(&job.name);
                let px = progress::pixels(job.width, job.height, job.cameras.len(), size);
                progress.start(&job.name, px, false);
                let r = run_job(job, out, options, &inc).map_err(|e| io(&job.name, e))?;
                reports.push(Report::new(statement.kind(), &r));
            }
            Statement::Volume(i) => {
                let job = &program.volumes[i];
                interrupt::running(&job.name);
                let px = progress::pixels(job.width, job.height, job.cameras.len(), size);
                progress.start(&job.name, px, false);
                let r = jobs::run_volume_job(job, out, size, &inc).map_err(|e| io(&job.name, e))?;
                reports.push(Report::new(statement.kind(), &r));
            }
            Statement::Train(i) => {
                let job = &program.trains[i];
                interrupt::running(&job.name);
                progress.start(&job.name, job.iterations as u64, true);
                let train = jobs::TrainOptions {
                    restart: options.restart,
                };
                let r =
                    jobs::run_train_job(job, out, base, size, train, &|e| progress.train_event(e))
                        .map_err(|e| io(&job.name, e))?;
                let mut report = Report::new(statement.kind(), &r);
                if let (Some(o), serde_json::Value::Object(files)) =
                    (report.report.as_object_mut(), json::train_files(job))
                {
                    o.extend(files);
                }
                reports.push(report);
            }
        }
    }
    Ok(reports)
}

fn base_dir(file: Option<&Path>) -> PathBuf {
    file.and_then(Path::parent)
        .map(Path::to_path_buf)
        .unwrap_or_default()
}

fn run(file: Option<&Path>, out: &Path, options: RunOptions, json: bool) -> ExitCode {
    let t0 = Instant::now();
    let src = match file {
        Some(f) => match read_source(f) {
            Ok(s) => s,
            Err(Unread::Io(e)) => {
                let name = f.display().to_string();
                return failed_early(&name, sdfl_lang::codes::IO, &e, READ_HELP, json);
            }
            Err(Unread::Encoding(src, diags)) => {
                say_raw(&sdfl_lang::render(&src, &diags, term::color()));
                if json {
                    let found = json::diagnostics(&src, &diags);
                    print_json(&json::run_failed(&src.name, found, None));
                }
                return ExitCode::FAILURE;
            }
        },
        None => SourceFile::new("showcase.sdfl (built in)", SHOWCASE),
    };
    let (program, warnings) = match load_diagnosed(&src) {
        Ok(p) => p,
        Err(diags) => {
            if json {
                print_json(&json::run_failed(
                    &src.name,
                    json::diagnostics(&src, &diags),
                    None,
                ));
            }
            return ExitCode::FAILURE;
        }
    };
    let early =
        |code: &str, message: &str, help: &str| failed_early(&src.name, code, message, help, json);
    if let Err(e) = sdfl_stdlib::work::check_program(&program, options.size) {
        // The message says what to lower.
        return early(sdfl_lang::codes::WORK, &e.to_string(), "");
    }
    // Written under the canonical directory, reported as the user named it.
    let shown = out;
    let (out, _lock) = match open_out_dir(out) {
        Ok(o) => o,
        Err(e) => return early(sdfl_lang::codes::IO, &e, OUT_DIR_HELP),
    };
    let out = out.as_path();
    // Every directory outputs go to, before any work.
    let dirs = sdfl_stdlib::outputs::output_dirs(&program);
    if let Err(e) = sdfl_runtime::output::check_output_dirs(out, &dirs) {
        let message = format!("cannot write the outputs: {e}");
        let help = "move what is in the way, or choose another `--out`";
        return early(sdfl_lang::codes::IO, &message, help);
    }
    let load_s = t0.elapsed().as_secs_f64();
    let every = progress::interval(std::env::var_os("SDFL_PROGRESS_SECS").as_deref());
    let progress = Progress::new(json, every);
    let result = execute(&program, out, options, &base_dir(file), &progress);
    progress.finish();
    let reports = match result {
        Ok(r) => r,
        Err((job, e)) => return failed_as(&src, &job, &e, json),
    };
    print_fit_warnings(&reports);
    if json {
        let summary = serde_json::json!({
            "file": src.name,
            // Paths need not be UTF-8; JSON strings must be.
            "out_dir": shown.to_string_lossy(),
            "load_seconds": load_s,
            "total_seconds": t0.elapsed().as_secs_f64(),
            "jobs": reports,
        });
        let warnings = json::diagnostics(&src, &warnings);
        print_json(&json::run_succeeded(summary, warnings));
        return ExitCode::SUCCESS;
    }
    let mut stdout = Stdout::new();
    for r in &reports {
        summarise(r, shown, &mut stdout);
    }
    ExitCode::SUCCESS
}

/// A fit's warnings on stderr, with `--json` too (where they are also in
/// each report's `warnings`), and each written file's (in the report as
/// that file's `warning`: a video written as its GIF fallback, a data set
/// the Blender form cannot state).
fn print_fit_warnings(reports: &[Report]) {
    for r in reports {
        let name = r.report["name"].as_str().unwrap_or("?");
        for w in r.report["written"].as_array().into_iter().flatten() {
            let warning = &w["warning"];
            if let (Some(code), Some(why)) = (warning["code"].as_str(), warning["message"].as_str())
            {
                say!("warning[{code}]: `{name}`: {why}");
            }
        }
        for w in r.report["warnings"].as_array().into_iter().flatten() {
            say!(
                "warning[{}]: `{name}`: {}",
                sdfl_runtime::train::trainer::DIVERGED,
                w.as_str().unwrap_or("?")
            );
        }
    }
}

/// What one statement's job reports, as `--json` prints it.
#[derive(serde::Serialize)]
struct Report {
    kind: StatementKind,
    report: serde_json::Value,
}

impl Report {
    fn new(kind: StatementKind, report: &impl serde::Serialize) -> Report {
        Report {
            kind,
            report: serde_json::to_value(report).expect("reports are serialisable"),
        }
    }
}

/// A human summary of one job's JSON report on stderr; written paths on stdout.
fn summarise(r: &Report, out: &Path, stdout: &mut Stdout) {
    let rep = &r.report;
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
    match r.kind {
        StatementKind::Render => {
            let rays = rep["rays"].as_f64().unwrap_or(0.0).max(1.0);
            say!(
                "{name}: {} primitives, {} views, {rays} rays ({:.1}% hit, {:.1} steps/ray); {}",
                rep["primitives"],
                rep["views"],
                100.0 * rep["hits"].as_f64().unwrap_or(0.0) / rays,
                rep["steps"].as_f64().unwrap_or(0.0) / rays,
                stages.join(", ")
            );
            let fx = &rep["effects"];
            let (shadow_rays, occlusion) = (
                fx["shadow_rays"].as_u64().unwrap_or(0),
                fx["occlusion_samples"].as_u64().unwrap_or(0),
            );
            if shadow_rays + occlusion > 0 {
                say!(
                    "  effects: {shadow_rays} shadow rays ({} SDF evaluations), {occlusion} occlusion samples",
                    fx["shadow_steps"].as_u64().unwrap_or(0)
                );
            }
            let undecided = rep["undecided"].as_u64().unwrap_or(0);
            if undecided > 0 {
                say!(
                    "  {undecided} rays ran out of steps before they hit or passed `far` and are drawn as misses: raise `iterations` (with `hit_tolerance: \"absolute\"`, rays grazing a surface need many)"
                );
            }
        }
        StatementKind::Volume => say!(
            "{name}: volume, {} views, {} samples/ray; {}",
            rep["views"],
            rep["samples_per_ray"],
            stages.join(", ")
        ),
        StatementKind::Train => {
            // A run resumed at its last step trains nothing: no step time.
            let resumed = rep["resumed_from"].as_u64();
            let pace = if resumed.is_some() && resumed == rep["iterations"].as_u64() {
                "already trained".to_string()
            } else {
                format!(
                    "{:.2} ms/step",
                    rep["seconds_per_step"].as_f64().unwrap_or(0.0) * 1e3
                )
            };
            say!(
                "{name}: {} iterations{}, final loss {:.3e}, {pace}; {}",
                rep["iterations"],
                resumed
                    .map(|k| format!(" (resumed at {k})"))
                    .unwrap_or_default(),
                rep["final_loss"].as_f64().unwrap_or(f64::NAN),
                stages.join(", ")
            );
            if let Some(n) = rep["samples_per_ray"]["evaluated"].as_f64() {
                let of = rep["samples_per_ray"]["sampled"].as_f64().unwrap_or(0.0);
                say!(
                    "  samples: {n:.1} a ray reached the network, of {of:.0} placed ({:.0} %; the rest skipped as empty space)",
                    100.0 * n / of.max(1.0)
                );
            }
            if let Some(h) = rep["held_out"].as_array().and_then(|h| h.last()) {
                let views = match h["views"].as_u64() {
                    Some(n) if n > 0 => {
                        format!("{n} held-out view{}", if n == 1 { "" } else { "s" })
                    }
                    _ => "held-out views".into(),
                };
                let in_mask = h["psnr_in_mask"]
                    .as_f64()
                    .map(|p| format!(" ({p:.2} dB inside the object masks)"))
                    .unwrap_or_default();
                say!(
                    "  {views} at step {}: PSNR {:.2} dB{in_mask}, SSIM {:.3}",
                    h["step"],
                    h["psnr"].as_f64().unwrap_or(f64::NAN),
                    h["ssim"].as_f64().unwrap_or(f64::NAN)
                );
            }
            if let Some(fit) = rep.get("fit").filter(|f| f.is_object()) {
                let num = |k: &str| fit[k].as_f64().unwrap_or(f64::NAN);
                say!(
                    "  fit: mean |f| at the points {:.2e}, eikonal {:.2e}, Chamfer {:.4} ({} surface samples)",
                    num("surface_mean_abs"),
                    num("eikonal"),
                    num("chamfer"),
                    fit["surface_samples"]
                );
            }
            if rep
                .get("mesh_fit")
                .is_some_and(|f| f.is_object() && f["chamfer"].is_null())
            {
                say!("  the mesh is empty: the trained field has no surface in its region");
            } else if let Some(fit) = rep.get("mesh_fit").filter(|f| f.is_object()) {
                let num = |k: &str| fit[k].as_f64().unwrap_or(f64::NAN);
                say!(
                    "  mesh vs {} points of the {}: Chamfer {:.4} (points → mesh {:.4}, mesh → points {:.4})",
                    fit["points"],
                    fit["against"].as_str().unwrap_or("?"),
                    num("chamfer"),
                    num("points_to_mesh"),
                    num("mesh_to_points")
                );
            }
            for p in rep["params"].as_array().into_iter().flatten() {
                let vals: Vec<String> = p[1]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|v| format!("{:.4}", v.as_f64().unwrap_or(f64::NAN)))
                    .collect();
                say!(
                    "  {:<12} ({})",
                    p[0].as_str().unwrap_or("?"),
                    vals.join(", ")
                );
            }
        }
    }
    if let Some(kept) = rep["kept_outputs"].as_array().filter(|k| !k.is_empty()) {
        let names: Vec<&str> = kept.iter().filter_map(|k| k.as_str()).collect();
        say!(
            "  kept as they were (made at this checkpoint step from the same declarations): {}",
            names.join(", ")
        );
    }
    for w in rep["written"].as_array().into_iter().flatten() {
        let cloud = w["kind"].as_str() == Some("point_cloud");
        if let Some(m) = w.get("mesh").filter(|m| m.is_object() && cloud) {
            // A point cloud: points, no surface.
            say!(
                "  {}: {} points, {:.2}s",
                w["path"].as_str().unwrap_or("?"),
                m["vertices"],
                m["seconds"].as_f64().unwrap_or(0.0)
            );
        } else if let Some(m) = w.get("mesh").filter(|m| m.is_object()) {
            say!(
                "  {}: {} vertices, {} triangles, area {:.4}, cell {:.4} ({} cells a side), {:.2}s",
                w["path"].as_str().unwrap_or("?"),
                m["vertices"],
                m["triangles"],
                m["area"].as_f64().unwrap_or(f64::NAN) + 0.0,
                m["cell"].as_f64().unwrap_or(f64::NAN),
                m["resolution"],
                m["seconds"].as_f64().unwrap_or(0.0)
            );
        }
        stdout.line(
            &out.join(w["path"].as_str().unwrap_or(""))
                .display()
                .to_string(),
        );
    }
}

/// The language's own constructs, for `sdfl docs` (the built-ins document
/// themselves in their table).
const SYNTAX: &[(&str, &str)] = &[
    ("let", "`let name = value` binds a name, at top level or at the start of a `{ ... }` body."),
    ("for", "`for i in 0..n, x in list { let ...; value }`: a list, one value per combination (the last binding varies fastest)."),
    ("if", "`if cond { a } else if other { b } else { c }`: the value of the branch taken (the others are not evaluated); conditions are bools, from `< <= > >= == !=`, `&&`, `||` and `!`."),
    ("fn", "`fn name(a, b: default) { let ...; value }` at top level: a function called like a built-in (positional, named, default arguments); it sees its parameters and the names above it, and calls only functions defined above it."),
    ("import", "`import \"path.sdfl\"`: the `let`s and `fn`s of another file (which may hold nothing else), relative to this one and inside the main file's directory."),
];

fn docs(name: Option<&str>) -> ExitCode {
    let env = sdfl_stdlib::StdEnv::get();
    let mut o = Stdout::new();
    match name {
        None => {
            for (kw, doc) in SYNTAX {
                o.line(&format!("{kw:<20} syntax: {doc}"));
            }
            for b in env.blocks() {
                o.line(&format!("{:<20} statement: {}", b.kind, b.doc));
            }
            for b in env.builtins() {
                o.line(&format!("{:<20} {}", b.sig.name, b.sig.doc));
            }
            ExitCode::SUCCESS
        }
        Some(n) => {
            if let Some((_, doc)) = SYNTAX.iter().find(|(kw, _)| *kw == n) {
                o.line(doc);
                return ExitCode::SUCCESS;
            }
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
            say!("error: no built-in named `{n}`; `sdfl docs` lists them");
            ExitCode::FAILURE
        }
    }
}
