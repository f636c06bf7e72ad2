//! `sdfl sweep`: a file re-run over values of one `let`, with quality and
//! time side by side.
//!
//! Each setting's row is written when it finishes (`rows.rs`), and the
//! table and plots are rebuilt from the rows on disk (`table.rs`): a rerun
//! skips the settings already done and resumes one that was interrupted
//! (training from its checkpoint), `--shard I/N` runs one slice of the
//! settings (for a scheduler's job array), and `--collect` merges the
//! slices' rows, copied into one `--out`, into the table. A row keeps what
//! the run measured (`metrics.rs`: held-out PSNR, Chamfer distance…) as
//! typed fields, each a column and a panel of the plots. Past one machine
//! sdfl runs on such an existing scheduler, not one of its own.

mod metrics;
mod rows;
mod table;

pub(crate) use rows::{parse_shard, Shard};

use super::*;
use rows::{Found, Row};

/// What `sdfl sweep` was asked.
pub(crate) struct SweepArgs<'a> {
    /// The scene file.
    pub file: &'a Path,
    /// The swept `let`.
    pub name: &'a str,
    /// Its values, the reference last.
    pub values: &'a [f64],
    /// The sweep's folder.
    pub out: &'a Path,
    /// `--size`.
    pub size: Option<(u32, u32)>,
    /// `--shard`: only this slice of the settings, no table.
    pub shard: Option<Shard>,
    /// `--collect`: only the table, from the rows on disk.
    pub collect: bool,
    /// `--dry-run`: only say which settings would run.
    pub dry_run: bool,
}

/// One setting, evaluated.
struct Setting {
    value: f64,
    /// `NAME=VALUE`: its folder's and its row's name.
    label: String,
    program: sdfl_stdlib::Program,
    fingerprint: String,
}

pub(crate) fn sweep(a: SweepArgs) -> ExitCode {
    if let Some(v) = a
        .values
        .iter()
        .enumerate()
        .find(|(i, v)| a.values[..*i].contains(v))
        .map(|(_, v)| v)
    {
        say!(
            "error: `--set` gives {}={v} twice\n  help: give each value once (each setting has one folder and one row)",
            a.name
        );
        return ExitCode::from(2);
    }
    let Ok(src) = read(a.file) else {
        return ExitCode::FAILURE;
    };
    // A dry run writes nothing, not even `--out`.
    let held = if a.dry_run {
        None
    } else {
        let Ok(held) = out_dir(a.out) else {
            return ExitCode::FAILURE;
        };
        Some(held)
    };
    let out = held.as_ref().map_or(a.out, |(out, _lock)| out.as_path());
    // Every setting this command needs, evaluated before anything runs.
    let mut settings = Vec::new();
    for (position, &value) in a.values.iter().enumerate() {
        if a.shard.is_some_and(|s| !s.owns(position)) {
            continue;
        }
        let program = match sdfl_stdlib::load_with(&src, &[(a.name.to_string(), value)]) {
            Ok(p) => p,
            Err(d) => {
                say_raw(&sdfl_lang::render(&src, &d, term::color()));
                return ExitCode::FAILURE;
            }
        };
        settings.push(Setting {
            value,
            label: rows::label(a.name, value),
            fingerprint: rows::fingerprint(&program, a.name, value, a.size),
            program,
        });
    }
    if a.dry_run {
        let mut stdout = Stdout::new();
        for s in &settings {
            let state = match rows::find(out, &s.label, a.name, s.value, &s.fingerprint) {
                Found::Done(_) => "done (skipped)".to_string(),
                Found::Missing => "to run".to_string(),
                Found::Stale(why) => format!("to run again: {why}"),
            };
            stdout.line(&format!("{}: {state}", s.label));
        }
        return ExitCode::SUCCESS;
    }
    if !a.collect {
        let mut skipped = 0;
        for s in &settings {
            match rows::find(out, &s.label, a.name, s.value, &s.fingerprint) {
                Found::Done(_) => {
                    say!("{}: skipped (done)", s.label);
                    skipped += 1;
                    continue;
                }
                Found::Stale(why) => say!("{}: running again: {why}", s.label),
                Found::Missing => {}
            }
            if let Err(code) = run_setting(&src, &a, out, s) {
                return code;
            }
        }
        if let Some(shard) = a.shard {
            say!(
                "shard {}/{}: {} of its {} settings run, {skipped} skipped (done); once every shard has finished (their `--out` folders copied into one), the same command with `--collect` in place of `--shard` writes the table",
                shard.index,
                shard.count,
                settings.len() - skipped,
                settings.len(),
            );
            return ExitCode::SUCCESS;
        }
    }
    collect(a.name, &settings, out)
}

/// Runs one setting in its folder and writes its row: from scratch, or,
/// where an interrupted run of the same fingerprint left it, resumed
/// (training from its checkpoint; the rest again).
fn run_setting(src: &SourceFile, a: &SweepArgs, out: &Path, s: &Setting) -> Result<(), ExitCode> {
    let dir = out.join(&s.label);
    let io_error = |what: &str, e: std::io::Error| {
        interrupt::wait_if_exiting();
        say!("error[sdfl::io]: {what} {}: {e}", s.label);
        ExitCode::FAILURE
    };
    let earlier = rows::started(out, &s.label, &s.fingerprint).filter(|_| dir.is_dir());
    let before = match &earlier {
        Some(mark) => {
            say!("{}: resuming where an interrupted run stopped", s.label);
            mark.seconds
        }
        None => {
            // The folder (made by sdfl) is emptied first, so no checkpoint
            // of another version of the file is resumed.
            if dir.exists() {
                if let Err(e) = std::fs::remove_dir_all(&dir) {
                    return Err(io_error("cannot clear the folder of", e));
                }
            }
            0.0
        }
    };
    let mark = |seconds| rows::Started {
        fingerprint: s.fingerprint.clone(),
        seconds,
    };
    if let Err(e) = rows::mark_started(out, &s.label, &mark(before)) {
        return Err(io_error("cannot mark the start of", e));
    }
    say!("{}", s.label);
    let every = crate::progress::interval(std::env::var_os("SDFL_PROGRESS_SECS").as_deref());
    let bar = crate::progress::Progress::new(false, every);
    let t = Instant::now();
    let reports = match execute(
        &s.program,
        &dir,
        RunOptions {
            size: a.size,
            no_cull: false,
            restart: earlier.is_none(),
        },
        &base_dir(Some(a.file)),
        &bar,
    ) {
        Ok(r) => r,
        Err((job, e)) => {
            bar.finish();
            if Stopped::of(&e).is_some() {
                // Stopped by a signal after a training step: the time so
                // far counts towards the resumed run's.
                let seconds = before + t.elapsed().as_secs_f64();
                let _ = rows::mark_started(out, &s.label, &mark(seconds));
            }
            return Err(failed(src, &job, &e));
        }
    };
    bar.finish();
    let reports: Vec<serde_json::Value> = reports.into_iter().map(|r| r.report).collect();
    let row = Row {
        format: rows::ROW_FORMAT,
        name: a.name.to_string(),
        value: s.value,
        fingerprint: s.fingerprint.clone(),
        seconds: before + t.elapsed().as_secs_f64(),
        metrics: Some(metrics::Metrics::of_reports(&reports)),
        reports,
    };
    if let Err(e) = rows::write(out, &s.label, &row) {
        return Err(io_error("writing the row of", e));
    }
    if let Err(e) = rows::unmark(out, &s.label) {
        return Err(io_error("cannot remove the start mark of", e));
    }
    say!("{}: done in {:.1} s", s.label, row.seconds);
    Ok(())
}

/// Writes the table and plots from the rows of `settings` on disk; every
/// setting must have a row that stands for it.
fn collect(name: &str, settings: &[Setting], out: &Path) -> ExitCode {
    let mut found = Vec::new();
    let mut absent = Vec::new();
    let mut stale = false;
    for s in settings {
        match rows::find(out, &s.label, name, s.value, &s.fingerprint) {
            Found::Done(row) => found.push((row, out.join(&s.label))),
            Found::Missing => absent.push(format!("{}: no row yet", s.label)),
            Found::Stale(why) => {
                stale = true;
                absent.push(format!("{}: {why}", s.label))
            }
        }
    }
    if !absent.is_empty() {
        // A row that no longer stands (edited, its outputs gone) is run
        // again by the sweep itself.
        let again = if stale {
            "; a setting whose row no longer stands runs again with this command without `--collect`"
        } else {
            ""
        };
        say!(
            "error[{}]: {} of the sweep's {} settings have no finished row under {}:\n  {}\n  help: run the shards that hold them (setting k of `--set`, from 0, is shard k mod N's) and copy their `--out` folders into this one, then `--collect` again{again}",
            sdfl_lang::codes::IO,
            absent.len(),
            settings.len(),
            out.join("rows").display(),
            absent.join("\n  ")
        );
        return ExitCode::FAILURE;
    }
    let write = |rel: &str, bytes: &[u8]| sdfl_runtime::output::write_bytes(&out.join(rel), bytes);
    let result = table::tables(name, &found).and_then(|t| {
        Stdout::new().print(&t.markdown);
        write("sweep.csv", t.csv.as_bytes())?;
        write("sweep.md", t.markdown.as_bytes())?;
        write("sweep.png", &t.against_time)?;
        write("sweep_value.png", &t.against_value)
    });
    match result {
        Ok(()) => {
            say!(
                "wrote {0}/sweep.csv, {0}/sweep.md, {0}/sweep.png (against seconds) and {0}/sweep_value.png (against the value)",
                out.display()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            interrupt::wait_if_exiting();
            say!(
                "error[sdfl::io]: writing the sweep results under {}: {e}",
                out.display()
            );
            ExitCode::FAILURE
        }
    }
}
