//! Diagnostics as files: every `tests/diagnostics/NAME.sdfl` is an error
//! (or warning) case. It is loaded with `sdfl_stdlib::load`, all its diagnostics are
//! rendered without colour, and the text must equal `NAME.txt` byte for
//! byte.
//!
//! To accept new or changed output on purpose, regenerate the expected files
//! and review the diff:
//!
//! ```text
//! SDFL_BLESS=1 cargo test --test integration diagnostics::
//! git diff tests/diagnostics
//! ```

use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

use sdfl_lang::SourceFile;

fn cases_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/diagnostics")
}

/// The `.sdfl` cases, sorted by name.
fn cases() -> Vec<PathBuf> {
    let mut cases: Vec<PathBuf> = fs::read_dir(cases_dir())
        .expect("tests/diagnostics exists")
        .map(|e| e.expect("readable directory entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "sdfl"))
        .collect();
    cases.sort();
    assert!(!cases.is_empty(), "no cases in {}", cases_dir().display());
    cases
}

fn bless() -> bool {
    std::env::var_os("SDFL_BLESS").is_some_and(|v| v == "1")
}

/// Files checked out with Windows line endings compare equal.
fn normalise(text: &str) -> String {
    text.replace("\r\n", "\n")
}

/// The rendered diagnostics of a case, or why there are none.
fn render_case(path: &Path) -> Result<String, String> {
    let name = path.file_name().expect("a file name").to_string_lossy();
    let text = normalise(&fs::read_to_string(path).map_err(|e| format!("{name}: {e}"))?);
    // Shown by name; imports are found next to the case.
    let src = SourceFile::new(name.to_string(), text).at(path);
    match sdfl_stdlib::load_warned(&src) {
        Ok((_, warnings)) if warnings.is_empty() => Err(format!(
            "{name}: loads without error or warning, but every case here must report something"
        )),
        Ok((_, warnings)) => Ok(sdfl_lang::render(&src, &warnings, false)),
        Err(diags) => Ok(sdfl_lang::render(&src, &diags, false)),
    }
}

/// Where two texts first differ, for the failure message.
fn first_difference(expected: &str, actual: &str) -> String {
    let (mut e, mut a) = (expected.lines(), actual.lines());
    for line in 1.. {
        match (e.next(), a.next()) {
            (Some(x), Some(y)) if x == y => continue,
            (None, None) => return "texts differ only in line endings".into(),
            (x, y) => {
                return format!(
                    "line {line}:\n  expected: {}\n  actual:   {}",
                    x.unwrap_or("<end of file>"),
                    y.unwrap_or("<end of file>")
                )
            }
        }
    }
    unreachable!()
}

#[test]
fn diagnostics_match_expected_files() {
    let mut failures = Vec::new();
    for case in cases() {
        let expected_path = case.with_extension("txt");
        let name = case
            .file_name()
            .expect("a file name")
            .to_string_lossy()
            .to_string();
        let actual = match render_case(&case) {
            Ok(text) => text,
            Err(why) => {
                failures.push(why);
                continue;
            }
        };
        if bless() {
            fs::write(&expected_path, &actual).expect("expected file is writable");
            continue;
        }
        match fs::read_to_string(&expected_path) {
            Ok(expected) if normalise(&expected) == actual => {}
            Ok(expected) => failures.push(format!(
                "{name}: output differs from {} at {}\n--- actual output:\n{actual}",
                expected_path.display(),
                first_difference(&normalise(&expected), &actual)
            )),
            Err(_) => failures.push(format!(
                "{name}: no {} (create it with SDFL_BLESS=1 and review it)\n--- actual output:\n{actual}",
                expected_path.display()
            )),
        }
    }
    // An expected file whose case is gone is a mistake too.
    for entry in fs::read_dir(cases_dir()).expect("tests/diagnostics exists") {
        let path = entry.expect("readable directory entry").path();
        if path.extension().is_some_and(|e| e == "txt") && !path.with_extension("sdfl").exists() {
            failures.push(format!("{}: no matching .sdfl case", path.display()));
        }
    }
    assert!(
        failures.is_empty(),
        "{} diagnostic case(s) failed{}:\n\n{}",
        failures.len(),
        if bless() {
            ""
        } else {
            " (SDFL_BLESS=1 regenerates the expected files)"
        },
        failures.join("\n\n")
    );
}

/// The stable codes of `lang::diag::codes`, read from its source so that a
/// new code is noticed here.
fn all_codes() -> Vec<String> {
    let source = include_str!("../../lang/src/diag.rs");
    let module = source
        .split("pub mod codes {")
        .nth(1)
        .and_then(|rest| rest.split('}').next())
        .expect("diag.rs has `pub mod codes { ... }`");
    let codes: Vec<String> = module
        .lines()
        .filter(|l| l.trim_start().starts_with("pub const"))
        .filter_map(|l| l.split('"').nth(1).map(str::to_string))
        .collect();
    assert!(codes.len() > 10, "could not read the codes: {codes:?}");
    codes
}

/// Every code that user input can reach appears in some expected output.
/// `sdfl::io` is the exception: only the CLI produces it (a file it cannot
/// read or write), never `load`.
#[test]
fn every_reachable_code_has_a_case() {
    let mut seen = BTreeSet::new();
    for case in cases() {
        let Ok(text) = fs::read_to_string(case.with_extension("txt")) else {
            continue; // reported by diagnostics_match_expected_files
        };
        for code in all_codes() {
            // Codes nest (`sdfl::syntax` is a prefix of `sdfl::syntax::number`):
            // match the code as a whole word inside the report.
            let delimited = [format!("{code}\n"), format!("{code} ")];
            if delimited.iter().any(|c| text.contains(c.as_str())) {
                seen.insert(code);
            }
        }
    }
    let missing: Vec<String> = all_codes()
        .into_iter()
        .filter(|c| c != "sdfl::io" && !seen.contains(c))
        .collect();
    assert!(
        missing.is_empty(),
        "no diagnostic case produces {missing:?}"
    );
}

/// Every diagnostic of every case has a label and a help text, and spans
/// inside the file.
#[test]
fn every_case_diagnostic_is_complete() {
    for case in cases() {
        let text = normalise(&fs::read_to_string(&case).expect("readable case"));
        let src = SourceFile::new(case.display().to_string(), text.as_str());
        let diags = match sdfl_stdlib::load_warned(&src) {
            Ok((_, warnings)) => warnings,
            Err(diags) => diags,
        };
        for d in &diags.diags {
            assert!(!d.message.is_empty(), "{}: {d:?}", case.display());
            assert!(!d.label.is_empty(), "{}: no label in {d:?}", case.display());
            assert!(
                d.help.as_deref().is_some_and(|h| !h.is_empty()),
                "{}: no help in {d:?}",
                case.display()
            );
            let (file, span) = diags.locate(d.span);
            let len = file.map_or(text.len(), |f| f.text.len());
            assert!(span.end <= len, "{}: {d:?}", case.display());
        }
    }
}
