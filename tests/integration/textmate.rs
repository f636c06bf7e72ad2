//! The TextMate grammar in editors/ (VS Code and other editors) against
//! the language: its built-in and statement lists are the standard
//! library's (`SDFL_BLESS=1` rewrites them), and a small TextMate-style
//! tokenizer run over every example gives each keyword, built-in, number,
//! string, comment, statement, name and operator the expected scope.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use regress::Regex;
use sdfl_lang::ast::{Body, Expr, ExprKind, Item, Source};
use serde_json::Value;

const GRAMMAR: &str = "editors/vscode/syntaxes/sdfl.tmLanguage.json";

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn grammar_text() -> String {
    std::fs::read_to_string(root().join(GRAMMAR)).expect("the grammar exists")
}

fn grammar() -> Value {
    serde_json::from_str(&grammar_text()).expect("the grammar is JSON")
}

// ------------------------------------------------------------ the lists

/// The `|`-separated names inside `\b(` … `)\b` of the first pattern of
/// repository entry `key`.
fn alternation(g: &Value, key: &str) -> String {
    let m = g["repository"][key]["patterns"][0]["match"]
        .as_str()
        .unwrap_or_else(|| panic!("repository.{key} has a match"));
    let start = m.find(r"\b(").expect(r"an alternation `\b(...)`") + 3;
    let end = start + m[start..].find(r")\b").expect("closed");
    m[start..end].to_string()
}

fn registry_builtins() -> Vec<String> {
    let env = sdfl_stdlib::StdEnv::get();
    let names: BTreeSet<String> = env
        .builtins()
        .iter()
        .map(|b| b.sig.name.to_string())
        .collect();
    names.into_iter().collect()
}

fn registry_statements() -> Vec<String> {
    let env = sdfl_stdlib::StdEnv::get();
    let kinds: BTreeSet<String> = env.blocks().iter().map(|b| b.kind.to_string()).collect();
    kinds.into_iter().collect()
}

#[test]
fn the_grammar_lists_exactly_the_standard_librarys_builtins_and_statements() {
    let g = grammar();
    let mut text = grammar_text();
    let mut stale = Vec::new();
    for (key, wanted) in [
        ("builtins", registry_builtins()),
        ("statements", registry_statements()),
    ] {
        let written = alternation(&g, key);
        let wanted = wanted.join("|");
        if written != wanted {
            let have: BTreeSet<&str> = written.split('|').collect();
            let want: BTreeSet<&str> = wanted.split('|').collect();
            stale.push(format!(
                "{key}: missing {:?}, unknown {:?}",
                want.difference(&have).collect::<Vec<_>>(),
                have.difference(&want).collect::<Vec<_>>()
            ));
            text = text.replacen(&written, &wanted, 1);
        }
    }
    if !stale.is_empty() && std::env::var_os("SDFL_BLESS").is_some() {
        std::fs::write(root().join(GRAMMAR), text).expect("the grammar is writable");
        return;
    }
    assert!(
        stale.is_empty(),
        "{GRAMMAR} is stale (rewrite it with SDFL_BLESS=1 cargo test --release --test integration textmate::): {stale:?}"
    );
}

#[test]
fn the_vscode_manifest_points_at_the_grammar() {
    let manifest: Value = serde_json::from_str(
        &std::fs::read_to_string(root().join("editors/vscode/package.json")).unwrap(),
    )
    .unwrap();
    let g = &manifest["contributes"]["grammars"][0];
    assert_eq!(g["scopeName"], grammar()["scopeName"]);
    let path = root()
        .join("editors/vscode")
        .join(g["path"].as_str().unwrap());
    assert!(path.is_file(), "{}", path.display());
    let lang = &manifest["contributes"]["languages"][0];
    assert_eq!(lang["extensions"][0], ".sdfl");
    let config = root()
        .join("editors/vscode")
        .join(lang["configuration"].as_str().unwrap());
    let config: Value = serde_json::from_str(&std::fs::read_to_string(config).unwrap()).unwrap();
    assert_eq!(config["comments"]["lineComment"], "//");
}

// ------------------------------------------------------------ the tokenizer

/// A grammar rule with its includes resolved.
enum Rule {
    Match {
        regex: Regex,
        name: Option<String>,
        captures: BTreeMap<usize, String>,
    },
    Region {
        begin: Regex,
        end: Regex,
        name: Option<String>,
        inner: Vec<Rule>,
    },
}

fn compile(pattern: &str) -> Regex {
    Regex::new(pattern).unwrap_or_else(|e| panic!("`{pattern}` does not compile: {e}"))
}

fn rules(g: &Value, patterns: &Value, out: &mut Vec<Rule>) {
    for p in patterns.as_array().expect("patterns are a list") {
        let name = p["name"].as_str().map(str::to_string);
        if let Some(inc) = p["include"].as_str() {
            let key = inc.strip_prefix('#').expect("includes are local");
            rules(g, &g["repository"][key]["patterns"], out);
        } else if let Some(m) = p["match"].as_str() {
            let captures = p["captures"]
                .as_object()
                .map(|c| {
                    c.iter()
                        .map(|(k, v)| (k.parse().unwrap(), v["name"].as_str().unwrap().to_string()))
                        .collect()
                })
                .unwrap_or_default();
            out.push(Rule::Match {
                regex: compile(m),
                name,
                captures,
            });
        } else {
            let mut inner = Vec::new();
            if p["patterns"].is_array() {
                rules(g, &p["patterns"], &mut inner);
            }
            out.push(Rule::Region {
                begin: compile(p["begin"].as_str().expect("begin")),
                end: compile(p["end"].as_str().expect("end")),
                name,
                inner,
            });
        }
    }
}

/// The scope of every byte of `text`, innermost only ("" outside every
/// rule), as TextMate finds them: line by line, the leftmost match of the
/// rules in force wins (the first rule on a tie; a region's end first),
/// and a region's name covers it from its begin to its end.
fn scopes(rules: &[Rule], text: &str) -> Vec<String> {
    fn set(scope: &mut [String], from: usize, to: usize, name: &Option<String>, all: bool) {
        if let Some(n) = name {
            for s in &mut scope[from..to] {
                if all || s.is_empty() {
                    *s = n.clone();
                }
            }
        }
    }
    let mut scope = vec![String::new(); text.len()];
    // The regions open, innermost last, with where each began.
    let mut open: Vec<(&Rule, usize)> = Vec::new();
    let mut line_start = 0;
    for line in text.split_inclusive('\n') {
        let line = line.strip_suffix('\n').unwrap_or(line);
        let mut pos = 0;
        while pos <= line.len() {
            let (current, end) = match open.last() {
                Some((Rule::Region { inner, end, .. }, _)) => (inner.as_slice(), Some(end)),
                _ => (rules, None),
            };
            // (start, end, rule): no rule for the region's end.
            let mut best: Option<(usize, usize, Option<usize>)> = None;
            if let Some(end) = end {
                if let Some(m) = end.find_from(line, pos).next() {
                    best = Some((m.start(), m.end(), None));
                }
            }
            for (i, r) in current.iter().enumerate() {
                let re = match r {
                    Rule::Match { regex, .. } => regex,
                    Rule::Region { begin, .. } => begin,
                };
                if let Some(m) = re.find_from(line, pos).next() {
                    if best.is_none_or(|b| m.start() < b.0) {
                        best = Some((m.start(), m.end(), Some(i)));
                    }
                }
            }
            let Some((s, e, which)) = best else { break };
            let (fs, fe) = (line_start + s, line_start + e);
            match which.map(|i| &current[i]) {
                None => {
                    if let Some((Rule::Region { name, .. }, began)) = open.pop() {
                        set(&mut scope, began, fe, name, false);
                    }
                }
                Some(Rule::Match {
                    regex,
                    name,
                    captures,
                }) => {
                    set(&mut scope, fs, fe, name, true);
                    let caps = regex.find_from(line, pos).next().expect("it matched");
                    for (k, cname) in captures {
                        if let Some(c) = caps.group(*k) {
                            let (cs, ce) = (line_start + c.start, line_start + c.end);
                            set(&mut scope, cs, ce, &Some(cname.clone()), true);
                        }
                    }
                }
                Some(r @ Rule::Region { .. }) => open.push((r, fs)),
            }
            // An empty match moves on by a byte.
            pos = if e > s { e } else { e + 1 };
        }
        line_start += line.len() + 1;
    }
    while let Some((Rule::Region { name, .. }, began)) = open.pop() {
        set(&mut scope, began, text.len(), name, false);
    }
    scope
}

fn tokenizer() -> Vec<Rule> {
    let g = grammar();
    let mut out = Vec::new();
    rules(&g, &g["patterns"], &mut out);
    out
}

fn scopes_of(text: &str) -> Vec<String> {
    scopes(&tokenizer(), text)
}

// ------------------------------------------------------------ expectations

/// Every `.sdfl` file under examples/.
fn examples() -> Vec<(PathBuf, String)> {
    let mut found = Vec::new();
    let mut dirs = vec![root().join("examples")];
    while let Some(dir) = dirs.pop() {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.extension().is_some_and(|x| x == "sdfl") {
                let text = std::fs::read_to_string(&p).unwrap();
                found.push((p, text));
            }
        }
    }
    found.sort();
    found
}

fn push_body<'a>(b: &'a Body, exprs: &mut Vec<&'a Expr>) {
    exprs.extend(b.lets.iter().map(|l| &l.value));
    exprs.push(&b.value);
}

/// What the parser says is at each place: (byte offset, expected scope
/// prefix, what it is).
fn expectations(text: &str) -> Vec<(usize, &'static str, String)> {
    let file = sdfl_lang::parse::parse(text).expect("examples parse");
    let env = sdfl_stdlib::StdEnv::get();
    let mut want = Vec::new();
    let user_fns: BTreeSet<&str> = file
        .items
        .iter()
        .filter_map(|i| match i {
            Item::Fn(f) => Some(f.name.name.as_str()),
            _ => None,
        })
        .collect();
    let mut exprs: Vec<&Expr> = Vec::new();
    for item in &file.items {
        match item {
            Item::Let(l) => exprs.push(&l.value),
            Item::Block(b) => {
                want.push((
                    b.kind.span.start,
                    "keyword.other.statement",
                    b.kind.name.clone(),
                ));
                if let Some(n) = &b.name {
                    want.push((n.span.start, "entity.name.section", n.name.clone()));
                }
                for f in &b.fields {
                    want.push((f.name.span.start, "variable.parameter", f.name.name.clone()));
                    exprs.push(&f.value);
                }
            }
            Item::Fn(f) => {
                want.push((
                    f.name.span.start,
                    "entity.name.function",
                    f.name.name.clone(),
                ));
                for p in &f.params {
                    if let Some(d) = &p.default {
                        want.push((p.name.span.start, "variable.parameter", p.name.name.clone()));
                        exprs.push(d);
                    }
                }
                push_body(&f.body, &mut exprs);
            }
            Item::Import(i) => want.push((i.path_span.start, "string.quoted", "import".into())),
        }
    }
    while let Some(e) = exprs.pop() {
        let at = e.span.start;
        match &e.kind {
            ExprKind::Number(_) => want.push((at, "constant.numeric", "number".into())),
            ExprKind::Bool(_) => want.push((at, "constant.language.boolean", "bool".into())),
            ExprKind::Str(_) => want.push((at, "string.quoted", "string".into())),
            ExprKind::Var(id) => {
                if env.constant_value(&id.name).is_some() {
                    want.push((id.span.start, "support.constant", id.name.clone()));
                }
            }
            ExprKind::List(items) => exprs.extend(items),
            ExprKind::Call { callee, args, .. } => {
                let scope = if env.builtin(&callee.name).is_some()
                    && !user_fns.contains(callee.name.as_str())
                {
                    "support.function.builtin"
                } else {
                    "entity.name.function.call"
                };
                want.push((callee.span.start, scope, callee.name.clone()));
                for a in args {
                    if let Some(n) = &a.name {
                        want.push((n.span.start, "variable.parameter", n.name.clone()));
                    }
                    exprs.push(&a.value);
                }
            }
            ExprKind::Member(v, _) | ExprKind::Neg(v) | ExprKind::Not(v) => exprs.push(v),
            ExprKind::Index(a, b) | ExprKind::Binary(_, a, b) => {
                exprs.push(a);
                exprs.push(b);
            }
            ExprKind::If {
                cond,
                then,
                otherwise,
            } => {
                exprs.push(cond);
                push_body(then, &mut exprs);
                push_body(otherwise, &mut exprs);
            }
            ExprKind::For { bindings, body } => {
                for b in bindings {
                    match &b.source {
                        Source::Range { start, end, .. } => {
                            exprs.push(start);
                            exprs.push(end);
                        }
                        Source::List(l) => exprs.push(l),
                    }
                }
                push_body(body, &mut exprs);
            }
        }
    }
    // Keywords, operators and comments, from the text outside strings
    // and comments.
    let b = text.as_bytes();
    let mut i = 0;
    while i < b.len() {
        let rest = &text[i..];
        if rest.starts_with("//") || rest.starts_with("/*") {
            want.push((i, "comment", "comment".into()));
            let len = if rest.starts_with("//") {
                rest.find('\n').unwrap_or(rest.len())
            } else {
                rest.find("*/").unwrap() + 2
            };
            // Every byte of a comment is in it.
            want.push((i + len - 1, "comment", "comment's end".into()));
            i += len;
        } else if b[i] == b'"' {
            let mut j = i + 1;
            while b[j] != b'"' {
                j += if b[j] == b'\\' { 2 } else { 1 };
            }
            want.push((j, "string.quoted", "string's end".into()));
            i = j + 1;
        } else if b[i].is_ascii_alphabetic() || b[i] == b'_' {
            let len = rest
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .unwrap_or(rest.len());
            let word = &rest[..len];
            let scope = match word {
                "if" | "else" | "for" | "in" => Some("keyword.control"),
                "let" | "import" => Some("keyword.other"),
                "fn" => Some("storage.type.function"),
                _ => None,
            };
            if let Some(s) = scope {
                want.push((i, s, word.to_string()));
            }
            i += len;
        } else if b[i].is_ascii_digit()
            || b[i] == b'.'
                && b.get(i + 1).is_some_and(u8::is_ascii_digit)
                && (i == 0 || !b[i - 1].is_ascii_alphanumeric())
        {
            // Numbers are checked from the tree; skip their text.
            let mut len = rest
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '.' || c == '_'))
                .unwrap_or(rest.len());
            // An exponent's sign (`1e-4`).
            if rest[..len].ends_with(['e', 'E']) && rest[len..].starts_with(['-', '+']) {
                len += 1 + rest[len + 1..]
                    .find(|c: char| !c.is_ascii_digit())
                    .unwrap_or(rest.len() - len - 1);
            }
            // `0..n`: the range operator after a whole number.
            if let Some(dots) = rest[..len].find("..") {
                want.push((i + dots, "keyword.operator.range", "..".into()));
            }
            i += len;
        } else {
            let op = ["..=", "..", "<=", ">=", "==", "!=", "&&", "||"]
                .into_iter()
                .find(|o| rest.starts_with(o))
                .map(|o| o.len())
                .or_else(|| "<>!=+-*/%^".contains(b[i] as char).then_some(1));
            if let Some(len) = op {
                want.push((i, "keyword.operator", rest[..len].to_string()));
                i += len;
            } else {
                i += rest.chars().next().unwrap().len_utf8();
            }
        }
    }
    want
}

#[test]
fn every_token_of_every_example_gets_its_scope() {
    let mut failures = Vec::new();
    let mut seen: BTreeMap<&'static str, usize> = BTreeMap::new();
    for (path, text) in examples() {
        let scope = scopes_of(&text);
        for (at, prefix, what) in expectations(&text) {
            *seen.entry(prefix).or_default() += 1;
            if !scope[at].starts_with(prefix) {
                let line = text[..at].matches('\n').count() + 1;
                failures.push(format!(
                    "{}:{line}: `{what}` has scope `{}`, not `{prefix}`",
                    path.display(),
                    scope[at]
                ));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} tokens scoped wrongly:\n{}",
        failures.len(),
        failures[..failures.len().min(40)].join("\n")
    );
    // The examples exercise every kind of token checked.
    for kind in [
        "keyword.control",
        "keyword.other",
        "keyword.other.statement",
        "storage.type.function",
        "entity.name.function",
        "support.function.builtin",
        "support.constant",
        "constant.numeric",
        "constant.language.boolean",
        "string.quoted",
        "comment",
        "variable.parameter",
        "keyword.operator",
        "keyword.operator.range",
    ] {
        assert!(
            seen.get(kind).copied().unwrap_or(0) > 0,
            "no `{kind}` in the examples"
        );
    }
}

#[test]
fn the_tokenizer_separates_what_looks_alike() {
    let text = "let a = b.x + 1.5e-3 + .5 + 45deg // pi(\n\
                let s = \"if \\\" // no\" /* let\n fn */ fn f(k: 2) { sin(tau) <= -k && !true }\n";
    let scope = scopes_of(text);
    let at = |needle: &str, nth: usize| {
        let i = text.match_indices(needle).nth(nth).unwrap().0;
        scope[i].clone()
    };
    assert_eq!(at("x", 0), "", "a member is no keyword");
    assert!(at("1.5e-3", 0).starts_with("constant.numeric"));
    assert!(
        at(".5", 1).starts_with("constant.numeric"),
        "{}",
        at(".5", 1)
    );
    assert!(at("deg", 0).starts_with("keyword.other.unit"));
    assert!(at("pi(", 0).starts_with("comment"));
    assert!(at("if", 0).starts_with("string"));
    assert!(at("\\\"", 0).starts_with("constant.character.escape"));
    assert!(at("// no", 0).starts_with("string"));
    assert!(at("let\n", 0).starts_with("comment.block"));
    assert!(at("fn */", 0).starts_with("comment.block"));
    assert!(at("fn f", 0).starts_with("storage.type.function"));
    assert!(at("f(k", 0).starts_with("entity.name.function"));
    assert!(at("k:", 0).starts_with("variable.parameter"));
    assert!(at("sin", 0).starts_with("support.function.builtin"));
    assert!(at("tau", 0).starts_with("support.constant"));
    assert!(at("<=", 0).starts_with("keyword.operator.comparison"));
    assert!(at("&&", 0).starts_with("keyword.operator.logical"));
    assert!(at("!true", 0).starts_with("keyword.operator.logical"));
    assert!(at("true", 0).starts_with("constant.language.boolean"));
}
