//! The machine-readable reports: `sdfl run --json` (a summary of the run,
//! or on failure its diagnostics) and `sdfl check --json`. Every report
//! carries [`SCHEMA_VERSION`]; a diagnostic is the same object wherever it
//! appears, so editors and scripts read one shape.

use serde_json::{json, Value};

use sdfl_lang::{Diag, Diagnostics, SourceFile, Span};

/// The version of these reports' layout: raised when a field changes
/// meaning or goes away (new fields do not raise it).
pub const SCHEMA_VERSION: u32 = 1;

/// Where a span is, for a reader: the file and 1-based line and column of
/// its start and end (columns in characters).
fn location(file: &SourceFile, span: Span) -> Value {
    let (line, column) = file.line_col(span.start);
    let (end_line, end_column) = file.line_col(span.end);
    json!({
        "file": file.name,
        "span": { "start": span.start, "end": span.end },
        "line": line,
        "column": column,
        "end_line": end_line,
        "end_column": end_column,
    })
}

/// One diagnostic of `src` (whose imports `all` knows) as JSON: severity,
/// code, message, label, help, where it is, and its notes, each located
/// in the file it points into.
pub fn diagnostic(src: &SourceFile, all: &Diagnostics, d: &Diag) -> Value {
    let locate = |span: Span| {
        let (file, local) = all.locate(span);
        location(file.unwrap_or(src), local)
    };
    let mut v = json!({
        "severity": match d.severity() {
            sdfl_lang::Severity::Error => "error",
            sdfl_lang::Severity::Warning => "warning",
        },
        "code": d.code,
        "message": d.message,
        "label": d.label,
        "help": d.help,
        "notes": d.notes.iter().map(|(span, text)| {
            let mut n = locate(*span);
            n["message"] = json!(text);
            n
        }).collect::<Vec<_>>(),
    });
    merge(&mut v, locate(d.span));
    v
}

/// A diagnostic with no place in the source (a file that cannot be read,
/// an output directory that cannot be used): its location fields are null,
/// and so is an empty `help`.
pub fn unplaced(file: &str, code: &str, message: &str, help: &str) -> Value {
    let help = (!help.is_empty()).then_some(help);
    json!({
        "severity": "error",
        "code": code,
        "message": message,
        "label": "",
        "help": help,
        "notes": [],
        "file": file,
        "span": null,
        "line": null,
        "column": null,
        "end_line": null,
        "end_column": null,
    })
}

fn merge(into: &mut Value, from: Value) {
    if let (Some(a), Value::Object(b)) = (into.as_object_mut(), from) {
        a.extend(b);
    }
}

/// Every diagnostic of `all`, in order.
pub fn diagnostics(src: &SourceFile, all: &Diagnostics) -> Vec<Value> {
    all.diags.iter().map(|d| diagnostic(src, all, d)).collect()
}

/// `sdfl run --json` when the run failed: what stopped it.
pub fn run_failed(file: &str, diagnostics: Vec<Value>, stopped: Option<Value>) -> Value {
    let mut v = json!({
        "schema_version": SCHEMA_VERSION,
        "ok": false,
        "file": file,
        "diagnostics": diagnostics,
    });
    if let Some(s) = stopped {
        v["stopped"] = s;
    }
    v
}

/// `sdfl run --json` when the run succeeded: `summary` (file, times,
/// jobs) with the schema version and the load's warnings.
pub fn run_succeeded(mut summary: Value, warnings: Vec<Value>) -> Value {
    merge(
        &mut summary,
        json!({ "schema_version": SCHEMA_VERSION, "ok": true, "warnings": warnings }),
    );
    summary
}

/// What a `train` statement leaves beside its outputs, relative to
/// `--out`: its checkpoint (null when it names none) and its logs.
pub fn train_files(job: &sdfl_stdlib::value::TrainJob) -> Value {
    let (csv, events, heldout) =
        sdfl_runtime::train::log::paths(std::path::Path::new(""), &job.name);
    let s = |p: &std::path::Path| p.to_string_lossy().into_owned();
    json!({
        "checkpoint": job.checkpoint.as_ref().map(|c| s(c)),
        "logs": {
            "metrics_csv": s(&csv),
            "tensorboard": events.parent().map(s),
            "held_out_image": s(&heldout),
        },
    })
}

/// One file's entry in `sdfl check --json`.
pub fn checked(file: &str, diagnostics: Vec<Value>) -> Value {
    let ok = !diagnostics.iter().any(|d| d["severity"] == "error");
    json!({ "file": file, "ok": ok, "diagnostics": diagnostics })
}

/// `sdfl check --json`: every file's entry.
pub fn check_report(files: Vec<Value>) -> Value {
    let ok = files.iter().all(|f| f["ok"] == true);
    json!({ "schema_version": SCHEMA_VERSION, "ok": ok, "files": files })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_diagnostic_names_its_place_in_lines_and_columns() {
        let src = SourceFile::new("a.sdfl", "let x = 1\nlet y = zz\n");
        let at = src.text.find("zz").unwrap();
        let d = Diag::new(
            sdfl_lang::codes::UNKNOWN_NAME,
            Span::new(at, at + 2),
            "no `zz`",
        )
        .label("not defined")
        .help("define it")
        .note(Span::new(4, 5), "x is here");
        let mut all = Diagnostics::default();
        all.push(d.clone());
        let v = diagnostic(&src, &all, &d);
        assert_eq!(v["severity"], "error");
        assert_eq!(v["code"], "sdfl::name::unknown");
        assert_eq!(
            (v["line"].as_u64(), v["column"].as_u64()),
            (Some(2), Some(9))
        );
        assert_eq!(v["end_column"], 11);
        assert_eq!(v["span"]["start"], at);
        assert_eq!(
            (v["label"].as_str(), v["help"].as_str()),
            (Some("not defined"), Some("define it"))
        );
        assert_eq!(v["notes"][0]["message"], "x is here");
        assert_eq!(v["notes"][0]["line"], 1);
        let u = unplaced("a.sdfl", "sdfl::io", "cannot read", "check it");
        assert!(u["span"].is_null() && u["line"].is_null());
        assert_eq!(u.as_object().unwrap().len(), v.as_object().unwrap().len());
        let report = check_report(vec![checked("a.sdfl", vec![v]), checked("b.sdfl", vec![])]);
        assert_eq!(report["schema_version"], SCHEMA_VERSION);
        assert_eq!(report["ok"], false);
        assert_eq!(report["files"][1]["ok"], true);
    }
}
