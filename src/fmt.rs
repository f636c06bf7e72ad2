//! `sdfl fmt`: rewrites files in the canonical layout (`sdfl_lang::fmt`).
//!
//! Only files that change are written, atomically and keeping their
//! permissions; a file that does not parse is reported and left alone.
//! The paths of files changed (or, with `--check`, that would change) are
//! printed on stdout, one a line.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use sdfl_lang::fmt::{format, FormatError};
use sdfl_lang::SourceFile;
use sdfl_runtime::output::Atomic;

use crate::term::{self, say_raw};
use crate::Stdout;

/// Arguments of `sdfl fmt`.
#[derive(clap::Args)]
pub struct FmtArgs {
    /// `.sdfl` files, or directories (searched for `.sdfl` files); `-`
    /// formats stdin to stdout.
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Write nothing: list the files that would change and exit 1 if any.
    #[arg(long)]
    check: bool,
}

/// What became of one file.
enum Outcome {
    Unchanged,
    Changed,
    Failed,
}

/// Runs `sdfl fmt`.
pub fn fmt(args: &FmtArgs) -> ExitCode {
    let mut stdout = Stdout::new();
    let mut failed = false;
    let mut changed = false;
    for path in expand(&args.files, &mut failed) {
        let outcome = if path.as_os_str() == "-" {
            format_stdin(args.check, &mut stdout)
        } else {
            format_file(&path, args.check)
        };
        match outcome {
            Outcome::Unchanged => {}
            Outcome::Changed => {
                changed = true;
                if path.as_os_str() != "-" {
                    stdout.line(&path.display().to_string());
                }
            }
            Outcome::Failed => failed = true,
        }
    }
    if failed || (args.check && changed) {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}

/// The files named, with directories replaced by the `.sdfl` files under
/// them (sorted; links are not followed into).
fn expand(paths: &[PathBuf], failed: &mut bool) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for p in paths {
        if p.as_os_str() != "-" && p.is_dir() {
            let mut found = Vec::new();
            let mut dirs = vec![p.clone()];
            while let Some(dir) = dirs.pop() {
                let entries = match std::fs::read_dir(&dir) {
                    Ok(e) => e,
                    Err(e) => {
                        say!("error[sdfl::io]: cannot read {}: {e}", dir.display());
                        *failed = true;
                        continue;
                    }
                };
                for entry in entries.flatten() {
                    let Ok(kind) = entry.file_type() else {
                        continue;
                    };
                    let path = entry.path();
                    if kind.is_dir() {
                        dirs.push(path);
                    } else if kind.is_file() && path.extension().is_some_and(|e| e == "sdfl") {
                        found.push(path);
                    }
                }
            }
            found.sort();
            files.extend(found);
        } else {
            files.push(p.clone());
        }
    }
    files
}

/// Reads a scene file whole: a regular file of at most
/// [`crate::MAX_SOURCE_BYTES`], in UTF-8 (a lossy conversion would be
/// written back).
fn read_text(path: &Path) -> Result<String, String> {
    // The reader's errors name the path.
    let bytes = sdfl_stdlib::files::read_capped(path, crate::MAX_SOURCE_BYTES)
        .map_err(|e| e.to_string())?;
    sdfl_stdlib::files::utf8(bytes).map_err(|e| {
        format!(
            "{}: not UTF-8 text (byte {}, 0x{:02x})",
            path.display(),
            e.at,
            e.byte
        )
    })
}

/// The formatted text, or the diagnostics printed.
fn formatted(name: &str, text: &str) -> Option<String> {
    match format(text) {
        Ok(t) => Some(t),
        Err(FormatError::Syntax(diags)) => {
            let src = SourceFile::new(name.to_string(), text.to_string());
            say_raw(&sdfl_lang::render(&src, &diags, term::color()));
            None
        }
        Err(FormatError::Unsafe(why)) => {
            say!(
                "error[sdfl::fmt]: {name}: left unchanged: formatting it would not be safe ({why})\n  help: this is a bug in `sdfl fmt`; please report it with the file"
            );
            None
        }
    }
}

fn format_file(path: &Path, check: bool) -> Outcome {
    let text = match read_text(path) {
        Ok(t) => t,
        Err(e) => {
            say!("error[sdfl::io]: cannot read {e}\n  help: give the path of a .sdfl file");
            return Outcome::Failed;
        }
    };
    let Some(new) = formatted(&path.display().to_string(), &text) else {
        return Outcome::Failed;
    };
    if new == text {
        return Outcome::Unchanged;
    }
    if !check {
        if let Err(e) = write_in_place(path, &new) {
            say!("error[sdfl::io]: cannot write {}: {e}", path.display());
            return Outcome::Failed;
        }
    }
    Outcome::Changed
}

/// Replaces the file (the one a link leads to) atomically, keeping its
/// permissions.
fn write_in_place(path: &Path, text: &str) -> std::io::Result<()> {
    use std::io::Write;
    let target = std::fs::canonicalize(path)?;
    let permissions = std::fs::metadata(&target)?.permissions();
    let mut file = Atomic::create(&target)?;
    file.writer().write_all(text.as_bytes())?;
    file.set_permissions(permissions)?;
    file.commit()
}

fn format_stdin(check: bool, stdout: &mut Stdout) -> Outcome {
    let mut bytes = Vec::new();
    let read = std::io::stdin()
        .take(crate::MAX_SOURCE_BYTES + 1)
        .read_to_end(&mut bytes);
    let text = match read.map(|_| String::from_utf8(bytes)) {
        Ok(Ok(t)) if t.len() as u64 <= crate::MAX_SOURCE_BYTES => t,
        _ => {
            say!(
                "error[sdfl::io]: cannot read stdin as UTF-8 text of at most {} bytes",
                crate::MAX_SOURCE_BYTES
            );
            return Outcome::Failed;
        }
    };
    let Some(new) = formatted("<stdin>", &text) else {
        return Outcome::Failed;
    };
    if !check {
        stdout.print(&new);
    }
    if new == text {
        Outcome::Unchanged
    } else {
        Outcome::Changed
    }
}
