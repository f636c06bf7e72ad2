//! One finished setting of a sweep on disk: its row file, written when the
//! setting finishes, and the fingerprint that says whether the row still
//! stands for the file and the setting.
//!
//! A setting `NAME=VALUE` runs in `OUT/NAME=VALUE/` and, once it has
//! finished, its row goes to `OUT/rows/NAME=VALUE.json` (atomically): the
//! seconds it took and each statement's report. The table and plots are
//! rebuilt from these files, so a sweep can stop and resume, and shards run
//! apart can be copied into one `--out` and collected.
//!
//! A row stands for its setting only as sdfl wrote it: its first line is a
//! check of every byte after it (value, seconds, measures, reports), so a
//! row edited by hand is refused, naming it. Its value must be the
//! setting's, its time and measures plausible, its outputs regular files in
//! its folder. Rows written before rows had a check are read (their values
//! checked the same way).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use sdfl_runtime::train::checkpoint::Fnv;

use super::metrics::Metrics;

/// The row file's format: a row of another format is run again. (Rows
/// gained `metrics` within format 1: one without them still stands.)
pub(super) const ROW_FORMAT: u32 = 1;

/// Largest row file read (reports of a few statements; a file this large
/// in `rows/` is not one sdfl wrote).
const MAX_ROW_BYTES: u64 = 64 << 20;

/// One finished setting.
#[derive(serde::Serialize, serde::Deserialize)]
pub(super) struct Row {
    /// [`ROW_FORMAT`].
    pub format: u32,
    /// The swept `let`.
    pub name: String,
    /// Its value in this setting.
    pub value: f64,
    /// [`fingerprint`] of the setting's program when it ran.
    pub fingerprint: String,
    /// Wall-clock seconds the setting's statements took.
    pub seconds: f64,
    /// Each statement's report, as `sdfl run --json` prints it (`report`).
    pub reports: Vec<serde_json::Value>,
    /// What the reports measure, read when the row was written; absent in
    /// rows written before rows kept them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metrics: Option<Metrics>,
}

impl Row {
    /// The setting's measures: as kept in the row, or, in a row written
    /// before rows kept them, read from its reports (kept whole); a
    /// measure no report gives is absent.
    pub fn metrics(&self) -> Metrics {
        self.metrics
            .unwrap_or_else(|| Metrics::of_reports(&self.reports))
    }
}

/// A setting's name: `NAME=VALUE`, also its folder's and its row's.
pub(super) fn label(name: &str, value: f64) -> String {
    format!("{name}={value}")
}

/// Where a setting's row is kept.
pub(super) fn row_path(out: &Path, label: &str) -> PathBuf {
    out.join("rows").join(format!("{label}.json"))
}

/// What a setting computes, as a hash: the evaluated program (every
/// statement, imported files spliced in, the swept value substituted; its
/// `Debug` form without source positions), the setting, `--size` and the
/// sdfl version. An edit that changes what the file evaluates to changes
/// it; one that only moves text (a comment, blank lines) does not, nor
/// does a change inside a data file the program reads when it runs
/// (delete the rows to rerun).
pub(super) fn fingerprint(
    program: &sdfl_stdlib::Program,
    name: &str,
    value: f64,
    size: Option<(u32, u32)>,
) -> String {
    let mut h = WithoutSpans::default();
    let _ = write!(
        h,
        "sdfl {} sweep row {ROW_FORMAT}\n{name}={:016x}\n{size:?}\n{program:?}",
        env!("CARGO_PKG_VERSION"),
        value.to_bits()
    );
    h.hash.finish()
}

/// A hash of `Debug` text that leaves out the offsets of every
/// `Span { start: N, end: M }` (where in the file a value was written),
/// streamed: the text of a large program is never held whole.
#[derive(Default)]
struct WithoutSpans {
    hash: Fnv,
    /// The last bytes hashed, to recognise where offsets follow.
    tail: Vec<u8>,
    /// Inside a span, between its start and its end.
    in_span: bool,
    /// Dropping the digits of an offset.
    skipping: bool,
}

impl std::fmt::Write for WithoutSpans {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        const START: &[u8] = b"Span { start: ";
        const END: &[u8] = b", end: ";
        for &b in s.as_bytes() {
            if self.skipping && b.is_ascii_digit() {
                continue;
            }
            self.skipping = false;
            self.hash.bytes(&[b]);
            self.tail.push(b);
            if self.tail.len() > 2 * START.len() {
                self.tail.drain(..START.len());
            }
            if self.tail.ends_with(START) {
                (self.in_span, self.skipping) = (true, true);
            } else if self.in_span && self.tail.ends_with(END) {
                (self.in_span, self.skipping) = (false, true);
            }
        }
        Ok(())
    }
}

/// What `OUT/rows/` holds for a setting.
pub(super) enum Found {
    /// A row that still stands for the setting.
    Done(Row),
    /// No row: the setting has not finished.
    Missing,
    /// A row that no longer stands for the setting, and why.
    Stale(String),
}

/// What a row file starts with when sdfl wrote it with a check: the key of
/// the check, whose value covers every byte after its line.
const CHECK_START: &str = "{\n  \"check\": \"";

/// The check of a row's JSON as written without its check line.
fn check_of(body: &[u8]) -> String {
    let mut h = Fnv::default();
    h.str("sdfl sweep row check").bytes(body);
    h.finish()
}

/// A row file split into its check and the row without the check's line
/// (as it was hashed); `None` for a row written before rows had a check.
fn split_check(bytes: &[u8]) -> Option<(&[u8], Vec<u8>)> {
    let rest = bytes.strip_prefix(CHECK_START.as_bytes())?;
    let end = rest.iter().position(|&b| b == b'"')?;
    let body = rest[end..].strip_prefix(b"\",\n")?;
    Some((&rest[..end], [b"{\n", body].concat()))
}

/// Longest time a setting may have taken: a row claiming more (about 30
/// years) was not measured.
const MAX_SECONDS: f64 = 1e9;

/// What is wrong with a row's values, if anything: what it measured must
/// be plausible (non-finite measures are kept as such, see `metrics.rs`),
/// its time finite, and what it wrote inside its setting's folder.
fn implausible(row: &Row) -> Option<String> {
    if !(row.seconds.is_finite() && (0.0..=MAX_SECONDS).contains(&row.seconds)) {
        return Some(format!(
            "an implausible time of {} seconds",
            sdfl_lang::fmt_num(row.seconds)
        ));
    }
    let m = row.metrics();
    // (measure, value, least, most, whether +∞ is one sdfl writes: a
    // Chamfer distance to an empty mesh).
    let ranges = [
        ("held-out PSNR", m.held_out_psnr_db, -1e3, 1e3, false),
        ("held-out SSIM", m.held_out_ssim, -1.001, 1.001, false),
        ("mesh Chamfer distance", m.mesh_chamfer, 0.0, 1e18, true),
        ("field Chamfer distance", m.field_chamfer, 0.0, 1e18, true),
    ];
    for (what, v, least, most, infinite) in ranges {
        let ok =
            |v: f64| v.is_nan() || (least..=most).contains(&v) || (infinite && v == f64::INFINITY);
        if let Some(v) = v.filter(|v| !ok(*v)) {
            return Some(format!(
                "an implausible {what} of {}",
                sdfl_lang::fmt_num(v)
            ));
        }
    }
    let outside = written(&row.reports).into_iter().find(|rel| {
        let p = Path::new(rel);
        rel.is_empty()
            || !p
                .components()
                .all(|c| matches!(c, std::path::Component::Normal(_)))
    });
    outside.map(|rel| format!("an output `{rel}` outside its setting's folder"))
}

/// Whether two readings of one value agree: a row's value went through
/// JSON, whose reader may round the last bit.
fn same_value(a: f64, b: f64) -> bool {
    a == b || (a - b).abs() <= 4.0 * f64::EPSILON * a.abs().max(b.abs())
}

/// The row of setting `name` = `value` (named `label`) under `out`,
/// checked against `fingerprint`, against its own check (a row edited
/// since it was written is refused, naming it), against its value being
/// the setting's and its measures plausible, and against its outputs
/// still being on disk (in `OUT/label/`) as regular files.
pub(super) fn find(out: &Path, label: &str, name: &str, value: f64, fingerprint: &str) -> Found {
    let path = row_path(out, label);
    let bytes = match sdfl_stdlib::files::read_capped(&path, MAX_ROW_BYTES) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Found::Missing,
        Err(e) if e.kind() == std::io::ErrorKind::FileTooLarge => {
            return Found::Stale("its row file is too large to be one sdfl wrote".into())
        }
        Err(e) => return Found::Stale(format!("its row file cannot be read ({e})")),
    };
    let shown = path.display();
    // Rows written before rows had a check are read as they are.
    let body = match split_check(&bytes) {
        Some((check, body)) if check == check_of(&body).as_bytes() => body,
        Some(_) => {
            return Found::Stale(format!(
                "its row {shown} was edited after sdfl wrote it (its check does not match)"
            ))
        }
        None => bytes,
    };
    let mut row: Row = match serde_json::from_slice(&body) {
        Ok(r) => r,
        Err(_) => return Found::Stale("its row file is not a sweep row".into()),
    };
    if row.format != ROW_FORMAT {
        return Found::Stale("its row was written by another version of sdfl".into());
    }
    if row.fingerprint != fingerprint {
        return Found::Stale("the file or the setting changed since it ran".into());
    }
    // The fingerprint covers the setting, so the row must say the same.
    if row.name != name || !same_value(row.value, value) {
        return Found::Stale(format!(
            "its row {shown} holds {}={}, not the setting's value",
            row.name,
            sdfl_lang::fmt_num(row.value)
        ));
    }
    row.value = value;
    if let Some(why) = implausible(&row) {
        return Found::Stale(format!("its row {shown} holds {why}"));
    }
    let dir = out.join(label);
    for rel in written(&row.reports) {
        match std::fs::metadata(dir.join(&rel)) {
            Ok(m) if m.is_file() => {}
            Ok(_) => {
                return Found::Stale(format!("its output {label}/{rel} is not a regular file"))
            }
            Err(_) => return Found::Stale(format!("its output {label}/{rel} is gone")),
        }
    }
    Found::Done(row)
}

/// Paths (relative to the setting's folder) of what a setting's
/// statements wrote.
pub(super) fn written(reports: &[serde_json::Value]) -> Vec<String> {
    reports
        .iter()
        .flat_map(|r| r["written"].as_array().cloned().unwrap_or_default())
        .filter_map(|w| w["path"].as_str().map(str::to_string))
        .collect()
}

/// Writes a finished setting's row (atomically: a sweep stopped while
/// writing it leaves no row, and the setting runs again).
pub(super) fn write(out: &Path, label: &str, row: &Row) -> std::io::Result<()> {
    let body = serde_json::to_vec_pretty(row).map_err(std::io::Error::other)?;
    // The check goes first, on a line of its own, covering every byte after.
    let rest = body
        .strip_prefix(b"{\n")
        .ok_or_else(|| std::io::Error::other("a row is a JSON object"))?;
    let bytes = [
        format!("{CHECK_START}{}\",\n", check_of(&body)).as_bytes(),
        rest,
    ]
    .concat();
    sdfl_runtime::output::write_bytes(&row_path(out, label), &bytes)
}

/// A setting that has started and not finished: written before it runs,
/// removed once its row is written. A rerun that finds one for the same
/// fingerprint resumes the setting where it stopped (training from its
/// checkpoint) rather than from scratch.
#[derive(serde::Serialize, serde::Deserialize)]
pub(super) struct Started {
    /// [`fingerprint`] of the setting's program.
    pub fingerprint: String,
    /// Seconds spent in earlier attempts that stopped on a signal (a
    /// `kill -9` leaves no time to count them).
    pub seconds: f64,
}

fn started_path(out: &Path, label: &str) -> PathBuf {
    out.join("rows").join(format!("{label}.started.json"))
}

/// The mark of an unfinished setting, if it is for `fingerprint`.
pub(super) fn started(out: &Path, label: &str, fingerprint: &str) -> Option<Started> {
    let bytes = sdfl_stdlib::files::read_capped(&started_path(out, label), 1 << 16).ok()?;
    serde_json::from_slice::<Started>(&bytes)
        .ok()
        .filter(|s| s.fingerprint == fingerprint)
}

/// Marks a setting as started (atomically).
pub(super) fn mark_started(out: &Path, label: &str, mark: &Started) -> std::io::Result<()> {
    let json = serde_json::to_vec(mark).map_err(std::io::Error::other)?;
    sdfl_runtime::output::write_bytes(&started_path(out, label), &json)
}

/// Removes a finished setting's mark.
pub(super) fn unmark(out: &Path, label: &str) -> std::io::Result<()> {
    match std::fs::remove_file(started_path(out, label)) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e),
        _ => Ok(()),
    }
}

/// A slice of a sweep's settings: shard `index` of `count`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Shard {
    /// 0-based, as Slurm's `SLURM_ARRAY_TASK_ID` (with `--array=0-…`)
    /// and Kubernetes' `JOB_COMPLETION_INDEX` count.
    pub index: usize,
    /// How many shards the settings are spread over.
    pub count: usize,
}

impl Shard {
    /// Whether the setting at `position` in `--set` is this shard's:
    /// round-robin over the settings in order, so every shard gets a
    /// share of cheap and costly settings when they are listed by cost.
    pub fn owns(&self, position: usize) -> bool {
        position % self.count == self.index
    }
}

/// Parses `--shard I/N` (0 ≤ I < N).
pub(crate) fn parse_shard(s: &str) -> Result<Shard, String> {
    let (i, n) = s
        .split_once('/')
        .ok_or("expected I/N, e.g. 0/4 (shard I of N, counted from 0)")?;
    let index: usize = i
        .trim()
        .parse()
        .map_err(|_| format!("bad shard index `{i}`"))?;
    let count: usize = n
        .trim()
        .parse()
        .map_err(|_| format!("bad shard count `{n}`"))?;
    if count == 0 || index >= count {
        return Err(format!(
            "shard {index} of {count}: the index counts from 0 and must be below the count"
        ));
    }
    Ok(Shard { index, count })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_split_the_settings_round_robin() {
        let shards: Vec<Shard> = (0..3)
            .map(|i| parse_shard(&format!("{i}/3")).unwrap())
            .collect();
        for position in 0..10 {
            let owners = shards.iter().filter(|s| s.owns(position)).count();
            assert_eq!(owners, 1, "setting {position} belongs to exactly one shard");
        }
        assert!(shards[1].owns(4) && shards[0].owns(3));
        for bad in ["3/3", "1/0", "x/2", "1", "-1/2", "1/2/3"] {
            assert!(parse_shard(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_shard(" 2 / 4").unwrap(), Shard { index: 2, count: 4 });
    }

    #[test]
    fn the_fingerprint_follows_the_program_and_the_setting() {
        let src = |text: &str| sdfl_lang::SourceFile::new("s.sdfl", text);
        let text = "let n = 8\nrender v { scene: sphere(), camera: look_at([0, 0, -3]), outputs: [image(\"a.png\")], size: [n, n] }\n";
        let load =
            |t: &str, v: f64| sdfl_stdlib::load_with(&src(t), &[("n".to_string(), v)]).unwrap();
        let a = fingerprint(&load(text, 8.0), "n", 8.0, None);
        assert_eq!(a, fingerprint(&load(text, 8.0), "n", 8.0, None));
        assert_ne!(a, fingerprint(&load(text, 9.0), "n", 9.0, None));
        assert_ne!(a, fingerprint(&load(text, 8.0), "n", 8.0, Some((4, 4))));
        let edited = text.replace("sphere()", "sphere(0.9)");
        assert_ne!(a, fingerprint(&load(&edited, 8.0), "n", 8.0, None));
        // Moving the text (a comment above) changes no value: the same.
        let moved = format!("// a comment\n\n{text}");
        assert_ne!(
            format!("{:?}", load(&moved, 8.0)),
            format!("{:?}", load(text, 8.0)),
            "the spans moved"
        );
        assert_eq!(a, fingerprint(&load(&moved, 8.0), "n", 8.0, None));
    }

    fn temp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("sdfl-rows-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("steps=400")).unwrap();
        std::fs::write(d.join("steps=400").join("fit.ply"), b"ply").unwrap();
        d
    }

    const LABEL: &str = "steps=400";

    /// A NeuS training report with a mesh measured against the truth.
    fn report() -> serde_json::Value {
        serde_json::json!({
            "iterations": 400,
            "held_out": [{"step": 400, "seconds": 2.0, "psnr": 27.5, "ssim": 0.875}],
            "mesh_fit": {"chamfer": 0.0125, "against": "true surface"},
            "written": [{"path": "fit.ply", "kind": "mesh"}],
        })
    }

    #[test]
    fn a_row_with_chamfer_round_trips() {
        let out = temp("round-trip");
        let reports = vec![report()];
        let row = Row {
            format: ROW_FORMAT,
            name: "steps".into(),
            value: 400.0,
            fingerprint: "f".into(),
            seconds: 12.5,
            metrics: Some(Metrics::of_reports(&reports)),
            reports,
        };
        write(&out, LABEL, &row).unwrap();
        let text = std::fs::read_to_string(row_path(&out, LABEL)).unwrap();
        assert!(text.contains(r#""mesh_chamfer": 0.0125"#), "{text}");
        let Found::Done(back) = find(&out, LABEL, "steps", 400.0, "f") else {
            panic!("the row stands")
        };
        assert_eq!(back.metrics, row.metrics);
        let m = back.metrics();
        assert_eq!(m.mesh_chamfer, Some(0.0125));
        assert_eq!(m.held_out_psnr_db, Some(27.5));
        // The kept measures are the row's, whatever its reports say.
        let kept = Row {
            metrics: Some(Metrics {
                mesh_chamfer: Some(0.5),
                ..Metrics::default()
            }),
            ..back
        };
        assert_eq!(kept.metrics().mesh_chamfer, Some(0.5));
        assert_eq!(kept.metrics().held_out_psnr_db, None);
    }

    #[test]
    fn an_old_row_without_metrics_loads() {
        let out = temp("old");
        // As sdfl wrote rows before they kept measures: a render's report.
        let old = r#"{
  "format": 1,
  "name": "steps",
  "value": 400.0,
  "fingerprint": "f",
  "seconds": 3.25,
  "reports": [{"views": 1, "written": [{"path": "fit.ply", "kind": "image"}]}]
}"#;
        std::fs::create_dir_all(out.join("rows")).unwrap();
        std::fs::write(row_path(&out, LABEL), old).unwrap();
        let Found::Done(row) = find(&out, LABEL, "steps", 400.0, "f") else {
            panic!("an old row still stands")
        };
        assert_eq!(row.metrics, None);
        // Nothing reported: every measure absent (not zero).
        assert_eq!(row.metrics(), Metrics::default());
        // An old training row: the measures its reports hold, the others absent.
        let mut trained: serde_json::Value = serde_json::from_str(old).unwrap();
        trained["reports"] = serde_json::json!([report()]);
        std::fs::write(row_path(&out, LABEL), trained.to_string()).unwrap();
        let Found::Done(row) = find(&out, LABEL, "steps", 400.0, "f") else {
            panic!("{trained}")
        };
        let m = row.metrics();
        assert_eq!(m.mesh_chamfer, Some(0.0125));
        assert_eq!(m.field_chamfer, None);
    }

    #[test]
    fn a_row_s_check_covers_every_value() {
        let out = temp("check");
        let row = Row {
            format: ROW_FORMAT,
            name: "steps".into(),
            value: 400.0,
            fingerprint: "f".into(),
            seconds: 12.5,
            metrics: None,
            reports: vec![report()],
        };
        write(&out, LABEL, &row).unwrap();
        let path = row_path(&out, LABEL);
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with(CHECK_START), "{text}");
        let stands = || matches!(find(&out, LABEL, "steps", 400.0, "f"), Found::Done(_));
        assert!(stands());
        let stale = |text: &str| {
            std::fs::write(&path, text).unwrap();
            match find(&out, LABEL, "steps", 400.0, "f") {
                Found::Stale(why) => why,
                _ => panic!("{text}"),
            }
        };
        for edit in [("12.5", "1.5"), ("0.0125", "0.0126"), ("400.0", "1e308")] {
            let why = stale(&text.replace(edit.0, edit.1));
            assert!(
                why.contains("edited") && why.contains("steps=400.json"),
                "{why}"
            );
        }
        // Without the check (as before rows had one), values are checked.
        let old: Vec<&str> = text
            .lines()
            .filter(|l| !l.starts_with("  \"check\""))
            .collect();
        let old = old.join("\n");
        std::fs::write(&path, &old).unwrap();
        assert!(stands());
        for (edit, says) in [
            (("400.0", "1e308"), "not the setting's value"),
            (("12.5", "1e308"), "implausible time"),
            (("12.5", "-1.0"), "implausible time"),
            (("0.875", "7.5"), "implausible held-out SSIM"),
            (
                ("\"fit.ply\"", "\"../fit.ply\""),
                "outside its setting's folder",
            ),
        ] {
            let mut forged: serde_json::Value = serde_json::from_str(&old).unwrap();
            forged["metrics"] = serde_json::json!(null);
            let forged = serde_json::to_string_pretty(&forged)
                .unwrap()
                .replace(edit.0, edit.1);
            let why = stale(&forged);
            assert!(why.contains(says), "{edit:?}: {why}");
        }
    }

    #[test]
    fn only_span_offsets_are_left_out_of_the_hash() {
        let hash = |text: &str| {
            let mut h = WithoutSpans::default();
            // In pieces, as `Debug` writes.
            for piece in text.split_inclusive(' ') {
                h.write_str(piece).unwrap();
            }
            h.hash.finish()
        };
        let a = hash("Job { span: Span { start: 12, end: 30 }, n: 5 }");
        assert_eq!(a, hash("Job { span: Span { start: 7, end: 1234 }, n: 5 }"));
        assert_ne!(a, hash("Job { span: Span { start: 12, end: 30 }, n: 6 }"));
        assert_ne!(
            hash("Other { start: 1, end: 2 }"),
            hash("Other { start: 1, end: 3 }")
        );
    }
}
