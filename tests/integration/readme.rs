//! The README and docs/ as a user reads them cannot rot: every ```sdfl
//! block loads (parse, check, evaluate) without an error or warning; every
//! built-in a code span calls exists and takes the arguments it names;
//! every repository path and link resolves; every example is mentioned;
//! and the README's test command is the one CI runs.

use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

use sdfl_lang::{codes, SourceFile};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn read(rel: &str) -> String {
    fs::read_to_string(root().join(rel))
        .unwrap_or_else(|e| panic!("{rel}: {e}"))
        .replace("\r\n", "\n")
}

/// The README and every Markdown file in docs/, as (path, text).
fn documents() -> Vec<(String, String)> {
    let mut docs = vec![("README.md".to_string(), read("README.md"))];
    let mut names: Vec<String> = fs::read_dir(root().join("docs"))
        .expect("docs/ exists")
        .map(|e| {
            e.expect("readable entry")
                .file_name()
                .to_string_lossy()
                .into_owned()
        })
        .filter(|n| n.ends_with(".md"))
        .collect();
    names.sort();
    for n in names {
        let rel = format!("docs/{n}");
        let text = read(&rel);
        docs.push((rel, text));
    }
    docs
}

/// A fenced block: its info string, first line number (1-based) and text.
struct Fence {
    info: String,
    line: usize,
    text: String,
}

/// The fenced blocks of a Markdown text, and the text outside them (fenced
/// lines blanked, so line numbers stay).
fn split_fences(md: &str) -> (Vec<Fence>, String) {
    let (mut fences, mut prose) = (Vec::new(), String::new());
    let mut open: Option<Fence> = None;
    for (i, line) in md.lines().enumerate() {
        let fence = line.trim_start().starts_with("```");
        match (&mut open, fence) {
            (None, true) => {
                open = Some(Fence {
                    info: line.trim_start().trim_start_matches('`').trim().to_string(),
                    line: i + 2,
                    text: String::new(),
                });
            }
            (Some(_), true) => fences.push(open.take().expect("open fence")),
            (Some(f), false) => {
                f.text.push_str(line);
                f.text.push('\n');
            }
            (None, false) => prose.push_str(line),
        }
        prose.push('\n');
    }
    assert!(open.is_none(), "a fenced block is never closed");
    (fences, prose)
}

/// Inline code spans of prose (single backticks), with their line.
fn code_spans(prose: &str) -> Vec<(usize, String)> {
    let mut spans = Vec::new();
    for (i, line) in prose.lines().enumerate() {
        let mut parts = line.split('`');
        parts.next();
        while let (Some(code), Some(_)) = (parts.next(), parts.next()) {
            spans.push((i + 1, code.to_string()));
        }
    }
    spans
}

/// Identifiers directly followed by `(`: the calls a piece of code makes.
fn called_names(code: &str) -> Vec<String> {
    let b = code.as_bytes();
    let ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    let mut names = Vec::new();
    for (i, &c) in b.iter().enumerate() {
        if c != b'(' || i == 0 || !ident(b[i - 1]) {
            continue;
        }
        let start = (0..i)
            .rev()
            .take_while(|&j| ident(b[j]))
            .last()
            .unwrap_or(i);
        let name = &code[start..i];
        if name.as_bytes()[0].is_ascii_alphabetic() || name.starts_with('_') {
            names.push(name.to_string());
        }
    }
    names
}

fn load(name: &str, text: &str) -> Result<(), String> {
    let src = SourceFile::new(name.to_string(), text.to_string());
    match sdfl_stdlib::load_warned(&src) {
        Ok((_, w)) if w.is_empty() => Ok(()),
        Ok((_, w)) => Err(sdfl_lang::render(&src, &w, false)),
        Err(d) => Err(sdfl_lang::render(&src, &d, false)),
    }
}

#[test]
fn every_sdfl_block_loads_without_error_or_warning() {
    let mut failures = Vec::new();
    let mut blocks = 0;
    for (doc, text) in documents() {
        for f in split_fences(&text).0 {
            if f.info != "sdfl" {
                continue;
            }
            blocks += 1;
            if let Err(e) = load(&format!("{doc}:{}", f.line), &f.text) {
                failures.push(e);
            }
        }
    }
    assert!(
        blocks >= 8,
        "only {blocks} ```sdfl blocks found: is the fence syntax still ```sdfl?"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Names that code spans call and that are not sdfl's: none so far. A name
/// here must be explained.
const NOT_SDFL: &[&str] = &[];

/// The syntax words `sdfl docs` lists beside the built-ins.
const KEYWORDS: &[&str] = &[
    "let", "for", "if", "else", "fn", "import", "render", "train",
];

#[test]
fn every_call_in_a_code_span_names_a_builtin_and_its_arguments() {
    let env = sdfl_stdlib::StdEnv::get();
    let mut failures = Vec::new();
    let docs = documents();
    // Functions the documents define themselves (`fn name(...)`).
    let mut defined = BTreeSet::new();
    for (_, text) in &docs {
        for f in split_fences(text).0 {
            for line in f.text.lines() {
                if let Some(rest) = line.trim_start().strip_prefix("fn ") {
                    defined.insert(rest.split('(').next().unwrap_or("").trim().to_string());
                }
            }
        }
    }
    let mut checked = 0;
    // The README only: docs/ write formulas (`sigmoid(f/β)`) in code spans.
    for (doc, text) in docs.iter().filter(|(d, _)| d == "README.md") {
        for (line, span) in code_spans(&split_fences(text).1) {
            let names = called_names(&span);
            if names.is_empty() {
                continue;
            }
            for n in &names {
                let known = env.builtin(n).is_some()
                    || KEYWORDS.contains(&n.as_str())
                    || defined.contains(n)
                    || NOT_SDFL.contains(&n.as_str());
                if !known {
                    failures.push(format!(
                        "{doc}:{line}: `{span}` calls `{n}`, which is no built-in"
                    ));
                }
            }
            if names.iter().any(|n| defined.contains(n)) {
                continue;
            }
            // A span that is a whole expression is checked as one: its
            // arguments' names and count, whatever its free names are.
            let src = SourceFile::new("span.sdfl", format!("let readme_span = {span}\n"));
            let Err(diags) = sdfl_stdlib::load(&src) else {
                checked += 1;
                continue;
            };
            if diags
                .diags
                .iter()
                .any(|d| d.code.starts_with(codes::SYNTAX))
            {
                continue;
            }
            checked += 1;
            let wrong = [
                codes::UNKNOWN_FUNCTION,
                codes::UNKNOWN_ARG,
                codes::DUPLICATE_ARG,
                codes::TOO_MANY_ARGS,
                codes::POSITIONAL_AFTER_NAMED,
            ];
            for d in diags.diags.iter().filter(|d| wrong.contains(&d.code)) {
                failures.push(format!(
                    "{doc}:{line}: `{span}`: {} ({})",
                    d.message, d.code
                ));
            }
        }
    }
    assert!(
        checked >= 20,
        "only {checked} code spans were whole expressions: is the span extraction broken?"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Repository paths named in the text: a known top-level folder, then a
/// path (globs and placeholders skipped).
fn repo_paths(text: &str) -> BTreeSet<String> {
    const TOP: &[&str] = &[
        "examples/",
        "docs/",
        "tests/",
        "runtime/",
        "stdlib/",
        "lang/",
        "bench/",
        "src/",
        ".ci/",
    ];
    let ok = |c: char| c.is_ascii_alphanumeric() || "_./-".contains(c);
    let mut paths = BTreeSet::new();
    for (i, _) in text.char_indices() {
        let rest = &text[i..];
        let Some(top) = TOP.iter().find(|t| rest.starts_with(**t)) else {
            continue;
        };
        let before = text[..i].chars().next_back();
        if before.is_some_and(|c| ok(c) && c != '(') {
            continue; // part of a longer path (`../shared/data/...`, `runtime/src/...`)
        }
        let end = rest.find(|c: char| !ok(c)).unwrap_or(rest.len());
        let after = rest[end..].chars().next();
        if after.is_some_and(|c| "*<{".contains(c)) {
            continue;
        }
        let path = rest[..end].trim_end_matches(['.', ',']);
        if path.len() > top.len() {
            paths.insert(path.to_string());
        }
    }
    paths
}

/// Every bare name in a code span of a README table (the built-ins at a
/// glance) is a built-in, a statement or a syntax word.
#[test]
fn every_name_in_a_readme_table_is_sdfls() {
    let env = sdfl_stdlib::StdEnv::get();
    let prose = split_fences(&read("README.md")).1;
    let rows: String = prose
        .lines()
        .filter(|l| l.starts_with('|'))
        .map(|l| format!("{l}\n"))
        .collect();
    let mut names = 0;
    let mut failures = Vec::new();
    for (line, word) in code_spans(&rows) {
        // Single lower-case words only: `sdfl run FILE` is a command, not a name.
        let bare = word
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
            && word.starts_with(|c: char| c.is_ascii_lowercase());
        if !bare {
            continue;
        }
        names += 1;
        if env.builtin(&word).is_none() && !KEYWORDS.contains(&word.as_str()) {
            failures.push(format!("table row {line}: `{word}` is no built-in"));
        }
    }
    assert!(
        names >= 50,
        "only {names} names in the README's tables: is the built-ins table gone?"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn every_path_and_link_resolves() {
    let mut failures = Vec::new();
    let docs = documents();
    let headings = |text: &str| -> BTreeSet<String> {
        let fences_out = split_fences(text).1;
        fences_out
            .lines()
            .filter_map(|l| l.strip_prefix('#'))
            .map(|h| slug(h.trim_start_matches('#').trim()))
            .collect()
    };
    for (doc, text) in &docs {
        let dir = Path::new(doc).parent().unwrap_or(Path::new(""));
        for p in repo_paths(text) {
            if !root().join(&p).exists() {
                failures.push(format!("{doc}: `{p}` does not exist"));
            }
        }
        // Markdown links and images: [text](target) outside code blocks.
        let prose = split_fences(text).1;
        for (i, _) in prose.match_indices("](") {
            let target = &prose[i + 2..];
            let Some(end) = target.find(')') else {
                continue;
            };
            let target = &target[..end];
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            let (file, anchor) = target.split_once('#').unwrap_or((target, ""));
            let file_path: PathBuf = if file.is_empty() {
                PathBuf::from(doc)
            } else {
                dir.join(file)
            };
            if !root().join(&file_path).exists() {
                failures.push(format!(
                    "{doc}: link to `{target}`: no file {}",
                    file_path.display()
                ));
                continue;
            }
            if !anchor.is_empty() {
                let target_text = read(&file_path.to_string_lossy());
                if !headings(&target_text).contains(anchor) {
                    failures.push(format!("{doc}: link to `{target}`: no such heading"));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// GitHub's anchor for a heading: lower case, punctuation dropped, spaces
/// as hyphens.
fn slug(heading: &str) -> String {
    heading
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || *c == ' ' || *c == '-' || *c == '_')
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

#[test]
fn every_example_is_in_the_readme() {
    let readme = read("README.md");
    let mut missing = Vec::new();
    let mut stack = vec![root().join("examples")];
    while let Some(dir) = stack.pop() {
        for e in fs::read_dir(&dir).expect("examples/ is readable") {
            let p = e.expect("readable entry").path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "sdfl") {
                let rel = p
                    .strip_prefix(root().join("examples"))
                    .expect("under examples/");
                let rel = rel.to_string_lossy().replace('\\', "/");
                // A whole name: `sphere.sdfl` is not mentioned by `train_sphere.sdfl`.
                let whole = readme.match_indices(rel.as_str()).any(|(i, _)| {
                    readme[..i]
                        .chars()
                        .next_back()
                        .is_none_or(|c| !(c.is_alphanumeric() || c == '_'))
                });
                if !whole {
                    missing.push(rel);
                }
            }
        }
    }
    missing.sort();
    assert!(
        missing.is_empty(),
        "examples the README never mentions: {missing:?}"
    );
}

#[test]
fn the_readme_test_command_is_the_one_ci_runs() {
    let ci = read(".ci/run");
    let readme = read("README.md");
    let command = ci
        .lines()
        .map(str::trim)
        .find(|l| l.starts_with("cargo test"))
        .expect(".ci/run runs `cargo test`")
        // CI shows every failure; a user's run may stop at the first.
        .replace(" --no-fail-fast", "");
    assert!(
        readme.contains(&command),
        "the README should show `{command}`, the test command of .ci/run"
    );
}

#[test]
fn the_helpers_find_what_they_should() {
    let md = "a `sphere(1)` b\n```sdfl\nlet x = 1\n```\n`box(size: 1)` see docs/conventions.md, examples/*.sdfl\n";
    let (fences, prose) = split_fences(md);
    assert_eq!(fences.len(), 1);
    assert_eq!((fences[0].info.as_str(), fences[0].line), ("sdfl", 3));
    assert_eq!(fences[0].text, "let x = 1\n");
    let spans: Vec<_> = code_spans(&prose).into_iter().map(|(_, s)| s).collect();
    assert_eq!(spans, ["sphere(1)", "box(size: 1)"]);
    assert_eq!(
        called_names("a.rotate(1) + max(b, len(c)) ( x"),
        ["rotate", "max", "len"]
    );
    let paths: Vec<_> = repo_paths(md).into_iter().collect();
    assert_eq!(paths, ["docs/conventions.md"]);
    assert_eq!(slug("Effects only when asked"), "effects-only-when-asked");
    assert_eq!(
        slug("What accuracy costs: `sdfl sweep`"),
        "what-accuracy-costs-sdfl-sweep"
    );
    // The loader used for blocks refuses what it should.
    assert!(load("bad.sdfl", "let s = sphre(1)\n").is_err());
    assert!(load("good.sdfl", "let s = sphere(1)\n").is_ok());
}
