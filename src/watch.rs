//! `sdfl watch`: re-run a scene file whenever it is saved, running again
//! only the statements whose inputs changed.
//!
//! Changes are found by polling (portable, no watcher thread or inotify
//! limits): the scene file and the `.sdfl` files beside it (where its
//! imports live) every [`POLL`]. A spurious trigger costs only a reload,
//! since every statement is then skipped.
//!
//! Each statement is fingerprinted by what it depends on: its evaluated
//! job (the stdlib's plain data, hashed in its `Debug` form with source
//! spans left out, so a comment or an edit elsewhere in the file changes
//! nothing), the run's options and the content of the files it reads. A
//! statement whose fingerprint matches the last run's, and whose outputs
//! are still as that run left them, is skipped. The fingerprints live in
//! `--out` ([`STORE`], written atomically), so a new `sdfl watch` on the
//! same directory skips what the last one ran. A `train` that does run
//! again resumes from its checkpoint, as `sdfl run` does.

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, SystemTime};

use sdfl_runtime::train::checkpoint::Fnv;
use sdfl_runtime::RunOptions;
use sdfl_stdlib::value::{Dataset, Statement};
use sdfl_stdlib::Program;
use serde::{Deserialize, Serialize};

use crate::Stdout;

/// How often the scene file is looked at.
pub const POLL: Duration = Duration::from_millis(250);

/// The fingerprints of the last run, in the output directory.
pub const STORE: &str = ".sdfl-watch.json";

/// Bumped when what a fingerprint covers changes: older stores are ignored.
const STORE_VERSION: u32 = 1;

/// Files read at most this large are hashed whole for the change check;
/// larger ones by size and modification time.
const MAX_HASHED_SOURCE: u64 = 1 << 20;

/// Largest fingerprint store read (a few hundred bytes a statement and
/// input file).
const MAX_STORE_BYTES: u64 = 64 << 20;

/// Most files of one data directory fingerprinted (the readers cap frames
/// at 10 000; more is not a data set).
const MAX_INPUT_FILES: usize = 100_000;

/// What `sdfl watch` was asked to do.
pub struct Watch {
    /// The scene file.
    pub file: PathBuf,
    /// The output directory.
    pub out: PathBuf,
    /// Options as for `sdfl run`.
    pub options: RunOptions,
    /// Stop after this many runs (for scripts and tests); `None`: until
    /// interrupted.
    pub max_runs: Option<usize>,
}

/// Runs `w.file` now and after every change, until `max_runs` runs (or a
/// signal). Exits non-zero when the last run failed.
pub fn watch(w: Watch) -> ExitCode {
    let Ok((out, _lock)) = crate::out_dir(&w.out) else {
        return ExitCode::FAILURE;
    };
    let base = crate::base_dir(Some(&w.file));
    let mut runs = 0;
    let mut stdout = Stdout::new();
    loop {
        // Taken before reading: a save during the run triggers another.
        let seen = sources_stamp(&w.file);
        let ok = match run_once(&w, &out, &base, &mut stdout) {
            Ok(ok) => ok,
            // Stopped by a signal: the watch ends as a run would.
            Err(code) => return code,
        };
        runs += 1;
        if w.max_runs.is_some_and(|m| runs >= m) {
            return if ok {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            };
        }
        say!(
            "watch: waiting for {} to change (Ctrl-C stops)",
            w.file.display()
        );
        next_change(&w.file, seen);
    }
}

/// Waits until the sources' stamp differs from `seen` and has settled
/// (unchanged for one more poll, so that a save written in several steps,
/// truncated then filled, is read whole); returns the new stamp.
pub fn next_change(file: &Path, seen: String) -> String {
    let mut now = sources_stamp(file);
    while seen == now {
        std::thread::sleep(POLL);
        now = sources_stamp(file);
    }
    loop {
        std::thread::sleep(POLL);
        let later = sources_stamp(file);
        if later == now {
            return now;
        }
        now = later;
    }
}

/// One reload and run of the statements that changed: whether it
/// succeeded, or the exit status of a run stopped by a signal.
fn run_once(w: &Watch, out: &Path, base: &Path, stdout: &mut Stdout) -> Result<bool, ExitCode> {
    let Ok(src) = crate::read(&w.file) else {
        return Ok(false);
    };
    // Diagnostics are printed here, at once, before anything runs.
    let Ok(program) = crate::load(&src) else {
        say!("watch: not run: the file has errors");
        return Ok(false);
    };
    if let Err(e) = sdfl_stdlib::work::check_program(&program, w.options.size) {
        say!("error[{}]: {e}", sdfl_lang::codes::WORK);
        return Ok(false);
    }
    let dirs = sdfl_stdlib::outputs::output_dirs(&program);
    if let Err(e) = sdfl_runtime::output::check_output_dirs(out, &dirs) {
        say!(
            "error[{}]: cannot write the outputs: {e}\n  help: move what is in the way, or choose another `--out`",
            sdfl_lang::codes::IO
        );
        return Ok(false);
    }
    let mut store = Store::load(out);
    let names: HashSet<String> = program
        .order
        .iter()
        .map(|s| statement_name(&program, *s).to_string())
        .collect();
    store.statements.retain(|name, _| names.contains(name));
    let mut ok = true;
    for &statement in &program.order {
        let name = statement_name(&program, statement).to_string();
        // Hashed now, after the statements above ran: a statement reading
        // what an earlier one wrote sees its new content.
        let print = fingerprint(&program, statement, w.options, base, &mut store.inputs);
        let unchanged = store
            .statements
            .get(&name)
            .is_some_and(|e| e.fingerprint == print && e.outputs_intact(out));
        if unchanged {
            stdout.line(&format!("skipped {name} (unchanged)"));
            continue;
        }
        store.statements.remove(&name);
        let one = Program {
            order: vec![statement],
            ..program.clone()
        };
        let every = crate::progress::interval(std::env::var_os("SDFL_PROGRESS_SECS").as_deref());
        let bar = crate::progress::Progress::new(false, every);
        let t = std::time::Instant::now();
        match crate::execute(&one, out, w.options, base, &bar) {
            Ok(reports) => {
                bar.finish();
                stdout.line(&format!("ran {name} ({:.2} s)", t.elapsed().as_secs_f64()));
                crate::print_fit_warnings(&reports);
                let mut outputs = Vec::new();
                for r in &reports {
                    crate::summarise(r, &w.out, stdout);
                    outputs.extend(written_paths(&r.report));
                }
                if let Statement::Train(i) = statement {
                    outputs.extend(program.trains[i].checkpoint.clone());
                }
                store.statements.insert(
                    name,
                    Entry {
                        fingerprint: print,
                        outputs: outputs
                            .iter()
                            .filter_map(|p| FileStamp::of(out, p))
                            .collect(),
                    },
                );
            }
            Err((job, e)) => {
                bar.finish();
                store.save(out);
                let code = crate::failed(&src, &job, &e);
                if sdfl_runtime::interrupt::Stopped::of(&e).is_some() {
                    return Err(code);
                }
                ok = false;
                break;
            }
        }
        // Kept after each statement: an interrupted watch skips what ran.
        store.save(out);
    }
    store.save(out);
    Ok(ok)
}

/// The statement's name, as reports and files know it.
fn statement_name(program: &Program, s: Statement) -> &str {
    match s {
        Statement::Render(i) => &program.renders[i].name,
        Statement::Volume(i) => &program.volumes[i].name,
        Statement::Train(i) => &program.trains[i].name,
    }
}

/// The paths of a report's `written` files, relative to the output directory.
fn written_paths(report: &serde_json::Value) -> Vec<PathBuf> {
    report["written"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|w| w["path"].as_str().map(PathBuf::from))
        .collect()
}

/// The fingerprint of one statement: its job with spans left out, the
/// run's options and the content of the files it reads.
fn fingerprint(
    program: &Program,
    statement: Statement,
    options: RunOptions,
    base: &Path,
    inputs: &mut BTreeMap<String, InputStamp>,
) -> String {
    let mut h = Fnv::default();
    h.str(env!("CARGO_PKG_VERSION"));
    h.str(&format!(
        "{:?} {:?} {}",
        options.size, options.no_cull, options.restart
    ));
    let (job, reads) = match statement {
        Statement::Render(i) => (format!("{:?}", program.renders[i]), Vec::new()),
        Statement::Volume(i) => (format!("{:?}", program.volumes[i]), Vec::new()),
        Statement::Train(i) => {
            let job = &program.trains[i];
            (format!("{job:?}"), data_paths(&job.data))
        }
    };
    h.str(&without_spans(&job));
    for p in reads {
        let p = base.join(p);
        for file in files_under(&p) {
            h.str(&file.to_string_lossy());
            h.str(&content_hash(&file, inputs));
        }
    }
    h.finish()
}

/// The files and directories a data set reads (relative to the scene file).
/// Exhaustive: a new kind of data set must say what it reads.
fn data_paths(data: &Dataset) -> Vec<PathBuf> {
    match data {
        Dataset::Files { images, .. } => images.clone(),
        Dataset::Points { path, .. } => vec![path.clone()],
        Dataset::NerfSynthetic { path, .. } => vec![path.clone()],
        Dataset::Capture(spec) => vec![spec.path.clone()],
        Dataset::Rendered { .. } | Dataset::Traced { .. } => Vec::new(),
    }
}

/// A `Debug` form with every `Span { start: .., end: .. }` replaced by
/// `Span`: where a value was written is not what it is.
fn without_spans(debug: &str) -> String {
    const OPEN: &str = "Span { start: ";
    let mut out = String::with_capacity(debug.len());
    let mut rest = debug;
    while let Some(at) = rest.find(OPEN) {
        out.push_str(&rest[..at]);
        out.push_str("Span");
        let tail = &rest[at + OPEN.len()..];
        rest = match tail.find('}') {
            Some(end) => &tail[end + 1..],
            None => "",
        };
    }
    out.push_str(rest);
    out
}

/// A file, or every file under a directory (sorted, links to directories
/// not followed), at most [`MAX_INPUT_FILES`]; a path that does not exist
/// is listed itself (its absence is part of the fingerprint).
fn files_under(path: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    let mut stack = vec![path.to_path_buf()];
    while let Some(p) = stack.pop() {
        if files.len() >= MAX_INPUT_FILES {
            break;
        }
        let is_dir = std::fs::symlink_metadata(&p).is_ok_and(|m| m.is_dir());
        if !is_dir {
            files.push(p);
            continue;
        }
        let Ok(entries) = std::fs::read_dir(&p) else {
            files.push(p);
            continue;
        };
        let mut children: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
        children.sort();
        stack.extend(children.into_iter().rev());
    }
    files
}

/// The hash of a file's content, reused from `cache` while its size and
/// modification time are unchanged; `missing` for a file that cannot be read.
fn content_hash(path: &Path, cache: &mut BTreeMap<String, InputStamp>) -> String {
    use std::io::Read;
    let key = path.to_string_lossy().into_owned();
    let Some((len, modified_ns)) = stamp(path) else {
        cache.remove(&key);
        return "missing".into();
    };
    if let Some(c) = cache.get(&key) {
        if c.len == len && c.modified_ns == modified_ns {
            return c.hash.clone();
        }
    }
    let mut h = Fnv::default();
    let Ok(mut f) = sdfl_stdlib::files::open_regular(path) else {
        return "unreadable".into();
    };
    let mut buf = vec![0u8; 1 << 16];
    loop {
        match f.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => {
                h.bytes(&buf[..n]);
            }
            Err(_) => return "unreadable".into(),
        }
    }
    let hash = h.finish();
    cache.insert(
        key,
        InputStamp {
            len,
            modified_ns,
            hash: hash.clone(),
        },
    );
    hash
}

/// A file's size and modification time (nanoseconds since the epoch).
fn stamp(path: &Path) -> Option<(u64, u64)> {
    let m = std::fs::metadata(path).ok()?;
    let modified = m
        .modified()
        .ok()?
        .duration_since(SystemTime::UNIX_EPOCH)
        .ok()?;
    Some((m.len(), modified.as_nanos() as u64))
}

/// What changes when the scene file or a `.sdfl` file beside it (an
/// import) is saved: their names, sizes and modification times, and the
/// content of the small ones (an edit within the file system's time
/// resolution keeps the time).
pub fn sources_stamp(file: &Path) -> String {
    let mut h = Fnv::default();
    let mut files = vec![file.to_path_buf()];
    let dir = match file.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if let Ok(entries) = std::fs::read_dir(&dir) {
        let mut beside: Vec<PathBuf> = entries
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|e| e == "sdfl"))
            .collect();
        beside.sort();
        files.extend(beside);
    }
    for f in files {
        h.str(&f.to_string_lossy());
        match stamp(&f) {
            Some((len, modified)) => {
                h.str(&format!("{len} {modified}"));
                // A FIFO or device named `.sdfl` is refused, never read.
                if len <= MAX_HASHED_SOURCE {
                    match sdfl_stdlib::files::read_capped(&f, MAX_HASHED_SOURCE) {
                        Ok(bytes) => h.bytes(&bytes),
                        Err(_) => h.str("unreadable"),
                    };
                }
            }
            None => {
                h.str("missing");
            }
        }
    }
    h.finish()
}

/// The fingerprints of the last run, by statement name, and the content
/// hashes of the input files (reused while a file's stamp is unchanged).
#[derive(Serialize, Deserialize, Default)]
struct Store {
    version: u32,
    statements: BTreeMap<String, Entry>,
    inputs: BTreeMap<String, InputStamp>,
}

/// What a statement's last run depended on and wrote.
#[derive(Serialize, Deserialize)]
struct Entry {
    fingerprint: String,
    outputs: Vec<FileStamp>,
}

/// An input file's stamp and content hash.
#[derive(Serialize, Deserialize)]
struct InputStamp {
    len: u64,
    modified_ns: u64,
    hash: String,
}

/// An output as it was left: path (relative to `--out`), size and time.
#[derive(Serialize, Deserialize, PartialEq)]
struct FileStamp {
    path: PathBuf,
    len: u64,
    modified_ns: u64,
}

impl FileStamp {
    fn of(out: &Path, rel: &Path) -> Option<FileStamp> {
        let (len, modified_ns) = stamp(&out.join(rel))?;
        Some(FileStamp {
            path: rel.to_path_buf(),
            len,
            modified_ns,
        })
    }
}

impl Entry {
    /// Whether every output is still as the run left it (not deleted,
    /// not overwritten by another run).
    fn outputs_intact(&self, out: &Path) -> bool {
        self.outputs
            .iter()
            .all(|o| FileStamp::of(out, &o.path).as_ref() == Some(o))
    }
}

impl Store {
    /// The store in `out`; empty when missing, unreadable or of another
    /// version (everything then runs).
    fn load(out: &Path) -> Store {
        let path = out.join(STORE);
        // Only the file sdfl wrote: a FIFO there would block, a link lead
        // anywhere.
        sdfl_stdlib::files::open_regular_unlinked(&path)
            .and_then(|f| sdfl_stdlib::files::read_to_cap(f, &path, MAX_STORE_BYTES))
            .ok()
            .and_then(|b| serde_json::from_slice::<Store>(&b).ok())
            .filter(|s| s.version == STORE_VERSION)
            .unwrap_or_else(|| Store {
                version: STORE_VERSION,
                ..Store::default()
            })
    }

    /// Written atomically; a failure only costs re-running next time.
    fn save(&self, out: &Path) {
        let bytes = serde_json::to_vec_pretty(self).expect("serialisable");
        if let Err(e) = sdfl_runtime::output::write_bytes(&out.join(STORE), &bytes) {
            say!("warning[sdfl::io]: cannot keep the watch fingerprints: {e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spans_are_left_out_and_the_rest_kept() {
        let d = "Output { kind: Image, path: \"a.png\", span: Span { start: 12, end: 40 } }, x";
        assert_eq!(
            without_spans(d),
            "Output { kind: Image, path: \"a.png\", span: Span }, x"
        );
        assert_eq!(without_spans("no spans"), "no spans");
        // Truncated input never panics.
        assert_eq!(without_spans("a Span { start: 1"), "a Span");
    }

    #[test]
    fn an_edit_elsewhere_in_the_file_keeps_a_statement_s_fingerprint() {
        let one = "let s = sphere(1)\nrender a { scene: s, camera: look_at(eye: [0, 0, 4], at: [0, 0, 0], up: [0, 1, 0], focal: 1.5), size: [8, 8], outputs: [image(\"a.png\")] }\n";
        let two = format!(
            "// a comment moving every span\nlet unused = 3\n{one}render b {{ scene: s, camera: look_at(eye: [0, 0, 5], at: [0, 0, 0], up: [0, 1, 0], focal: 1.5), size: [8, 8], outputs: [image(\"b.png\")] }}\n"
        );
        let load = |t: &str| {
            sdfl_stdlib::load(&sdfl_lang::SourceFile::new("t.sdfl", t.to_string())).unwrap()
        };
        let (p1, p2) = (load(one), load(&two));
        let fp = |p: &Program, s| {
            fingerprint(
                p,
                s,
                RunOptions::default(),
                Path::new("."),
                &mut BTreeMap::new(),
            )
        };
        assert_eq!(fp(&p1, p1.order[0]), fp(&p2, p2.order[0]));
        assert_ne!(fp(&p2, p2.order[0]), fp(&p2, p2.order[1]));
        let sized = RunOptions {
            size: Some((4, 4)),
            ..RunOptions::default()
        };
        assert_ne!(
            fp(&p1, p1.order[0]),
            fingerprint(
                &p1,
                p1.order[0],
                sized,
                Path::new("."),
                &mut BTreeMap::new()
            )
        );
    }
}
