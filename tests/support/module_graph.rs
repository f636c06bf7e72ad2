//! Which modules of a crate's source import which, read from the source
//! text, and the loops among them: shared by every crate's module-loop
//! test (`module_loops.rs` in `lang/`, `stdlib/` and `runtime/tests/suite/`
//! and in `tests/integration/` for the command line and `bench/`), each
//! including this file. A
//! module uses another where its code (comments and `#[cfg(test)]`
//! modules left out: tests may reach anywhere) writes a path into it.

#![allow(dead_code, reason = "each test crate including this uses part of it")]

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

pub type Graph = BTreeMap<String, BTreeSet<String>>;

pub fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in fs::read_dir(dir).expect("source directory") {
        let path = entry.expect("directory entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// `text` without comments and without what follows its first
/// `#[cfg(test)]` module (test modules close the files that have them).
pub fn code(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(i) = rest.find("/*") {
        out.push_str(&rest[..i]);
        rest = rest[i..].find("*/").map_or("", |j| &rest[i + j + 2..]);
    }
    out.push_str(rest);
    let out: String = out
        .lines()
        .map(|l| l.find("//").map_or(l, |i| &l[..i]))
        .collect::<Vec<_>>()
        .join("\n");
    let mut from = 0;
    while let Some(i) = out[from..].find("#[cfg(test)]").map(|i| from + i) {
        let item = out[i + "#[cfg(test)]".len()..].trim_start();
        let item = item.strip_prefix("pub(crate)").unwrap_or(item).trim_start();
        if item.starts_with("mod ") {
            return out[..i].to_string();
        }
        from = i + 1;
    }
    out
}

fn is_ident(c: u8) -> bool {
    c.is_ascii_alphanumeric() || c == b'_'
}

fn skip_space(s: &[u8], mut i: usize) -> usize {
    while i < s.len() && s[i].is_ascii_whitespace() {
        i += 1;
    }
    i
}

/// The paths of the use tree or path starting at `s[i]`, each as its
/// segments: `a::{b, c::{d, e}}` gives `a::b`, `a::c::d` and `a::c::e`.
fn tree(s: &[u8], i: usize) -> (Vec<Vec<String>>, usize) {
    let mut i = skip_space(s, i);
    if s.get(i) == Some(&b'{') {
        let mut paths = Vec::new();
        i += 1;
        loop {
            i = skip_space(s, i);
            match s.get(i) {
                None => return (paths, i),
                Some(b'}') => return (paths, i + 1),
                Some(b',') => i += 1,
                Some(_) => {
                    let (sub, j) = tree(s, i);
                    paths.extend(sub);
                    // Past what the item leaves (`as name`), to `,` or `}`.
                    i = j.max(i + 1);
                    while i < s.len() && !matches!(s[i], b',' | b'}') {
                        i += 1;
                    }
                }
            }
        }
    }
    let start = i;
    while i < s.len() && is_ident(s[i]) {
        i += 1;
    }
    if i == start {
        return (vec![Vec::new()], i + 1);
    }
    let ident = String::from_utf8_lossy(&s[start..i]).into_owned();
    let after = skip_space(s, i);
    if s[after..].starts_with(b"::") {
        let (sub, j) = tree(s, after + 2);
        let paths = sub
            .into_iter()
            .map(|p| std::iter::once(ident.clone()).chain(p).collect())
            .collect();
        return (paths, j);
    }
    (vec![vec![ident]], i)
}

/// Every path in `code` whose first segment `starts` accepts, whole (use
/// groups expanded).
pub fn paths(code: &str, starts: impl Fn(&str) -> bool) -> Vec<Vec<String>> {
    let s = code.as_bytes();
    let mut found = Vec::new();
    let mut i = 0;
    while i < s.len() {
        let boundary = i == 0 || !(is_ident(s[i - 1]) || s[i - 1] == b':');
        if !(boundary && is_ident(s[i])) {
            i += 1;
            continue;
        }
        let mut j = i;
        while j < s.len() && is_ident(s[j]) {
            j += 1;
        }
        let ident = &code[i..j];
        if starts(ident) && s[skip_space(s, j)..].starts_with(b"::") {
            let (sub, end) = tree(s, i);
            found.extend(sub);
            i = end.max(j);
        } else {
            i = j;
        }
    }
    found
}

/// Each top-level module of the crate at `src` and the top-level modules
/// its files name by `crate::` paths.
pub fn crate_graph(src: &Path) -> Graph {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let module_of = |p: &Path| -> Option<String> {
        let rel = p.strip_prefix(src).ok()?;
        let first = rel.components().next()?.as_os_str().to_str()?;
        let name = first.strip_suffix(".rs").unwrap_or(first);
        (name != "lib" && name != "main").then(|| name.to_string())
    };
    let mut graph: Graph = files
        .iter()
        .filter_map(|p| module_of(p))
        .map(|m| (m, BTreeSet::new()))
        .collect();
    for path in &files {
        let Some(module) = module_of(path) else {
            continue;
        };
        let text = fs::read_to_string(path).expect("readable source");
        for p in paths(&code(&text), |s| s == "crate") {
            if let Some(used) = p.get(1) {
                if *used != module && graph.contains_key(used) {
                    graph.get_mut(&module).expect("listed").insert(used.clone());
                }
            }
        }
    }
    graph
}

/// A module's path inside the folder `root` (`formats::llff` for
/// `formats/llff.rs`, `formats` for `formats/mod.rs`, none for `mod.rs`).
pub fn module_path(root: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(root).expect("inside the folder");
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().expect("a file");
    if last != "mod.rs" {
        parts.push(last.trim_end_matches(".rs").to_string());
    }
    parts
}

/// Each module of the folder `root` (crate path `prefix`, as
/// `crate::data`), every file one, and the modules of the folder its
/// files name: by `crate::` paths through `prefix`, by `super::` and
/// `self::`, and (in a `mod.rs`) by its children's names. A path names
/// the deepest module it passes through; the folder's `mod.rs` is `mod`.
pub fn folder_graph(root: &Path, prefix: &[&str]) -> Graph {
    let mut files = Vec::new();
    rust_files(root, &mut files);
    let modules: BTreeSet<Vec<String>> = files.iter().map(|f| module_path(root, f)).collect();
    // The folder's own `mod.rs` is `mod` (a name no module can have).
    let name = |m: &[String]| {
        if m.is_empty() {
            "mod".to_string()
        } else {
            m.join("::")
        }
    };
    let mut graph: Graph = modules.iter().map(|m| (name(m), BTreeSet::new())).collect();
    for file in &files {
        let module = module_path(root, file);
        let is_dir_module = file.ends_with("mod.rs");
        let child = |s: &str| {
            let mut c = module.clone();
            c.push(s.to_string());
            is_dir_module && modules.contains(&c)
        };
        let text = fs::read_to_string(file).expect("readable source");
        let starts = |s: &str| matches!(s, "crate" | "super" | "self") || child(s);
        for p in paths(&code(&text), starts) {
            let (mut at, rest): (Vec<String>, &[String]) = match p[0].as_str() {
                "crate" if p.len() > prefix.len() && p[1..=prefix.len()] == *prefix => {
                    (Vec::new(), &p[prefix.len() + 1..])
                }
                "crate" => continue,
                "self" => (module.clone(), &p[1..]),
                "super" => {
                    // Each `super` one module up; past the folder's
                    // `mod.rs`, out of the folder.
                    let mut at = module.clone();
                    let mut k = 0;
                    while p.get(k).is_some_and(|s| s == "super") && !at.is_empty() {
                        at.pop();
                        k += 1;
                    }
                    if p.get(k).is_some_and(|s| s == "super") {
                        continue;
                    }
                    (at, &p[k..])
                }
                _ => (module.clone(), &p[..]),
            };
            for s in rest {
                let mut next = at.clone();
                next.push(s.clone());
                if !modules.contains(&next) {
                    break;
                }
                at = next;
            }
            if at != module {
                graph
                    .get_mut(&name(&module))
                    .expect("listed")
                    .insert(name(&at));
            }
        }
    }
    graph
}

/// Groups of two or more modules that reach each other.
pub fn loops(graph: &Graph) -> Vec<Vec<String>> {
    let reach = |from: &str| -> BTreeSet<String> {
        let mut seen = BTreeSet::new();
        let mut todo = vec![from.to_string()];
        while let Some(m) = todo.pop() {
            for n in graph.get(&m).into_iter().flatten() {
                if seen.insert(n.clone()) {
                    todo.push(n.clone());
                }
            }
        }
        seen
    };
    let reached: BTreeMap<&String, BTreeSet<String>> =
        graph.keys().map(|m| (m, reach(m))).collect();
    let mut groups: BTreeSet<Vec<String>> = BTreeSet::new();
    for m in graph.keys() {
        let group: Vec<String> = graph
            .keys()
            .filter(|n| *n == m || (reached[m].contains(*n) && reached[n].contains(m)))
            .cloned()
            .collect();
        if group.len() > 1 {
            groups.insert(group);
        }
    }
    groups.into_iter().collect()
}

/// Each loop of `graph`, as the arrows that close it (none: no loop).
pub fn loops_found(graph: &Graph) -> Vec<String> {
    loops(graph)
        .iter()
        .map(|group| arrows(graph, group).join(", "))
        .collect()
}

/// The arrows inside `group`, for messages.
pub fn arrows(graph: &Graph, group: &[String]) -> Vec<String> {
    group
        .iter()
        .flat_map(|a| {
            graph[a]
                .iter()
                .filter(|b| group.contains(b))
                .map(move |b| format!("{a} -> {b}"))
        })
        .collect()
}

#[test]
fn paths_are_read_from_uses_groups_and_code() {
    let text =
        "use crate::{a::B, c, d::{e, f::{G, H as I}}};\nfn g() { crate::h::i(); x::crate::j(); }";
    let found: Vec<String> = paths(text, |s| s == "crate")
        .iter()
        .map(|p| p.join("::"))
        .collect();
    assert_eq!(
        found,
        [
            "crate::a::B",
            "crate::c",
            "crate::d::e",
            "crate::d::f::G",
            "crate::d::f::H",
            "crate::h::i"
        ]
    );
    let kept = code("a // crate::x\n/* crate::y */ b\n#[cfg(test)]\nmod tests { crate::z }");
    assert_eq!(kept.trim(), "a \n b");
}

#[test]
fn a_loop_is_found() {
    let graph: Graph = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a"]),
        ("d", vec!["a"]),
    ]
    .into_iter()
    .map(|(m, uses)| (m.to_string(), uses.into_iter().map(String::from).collect()))
    .collect();
    assert_eq!(loops(&graph), [["a", "b", "c"]]);
}

#[test]
fn folder_paths_resolve_to_the_deepest_module() {
    let dir = std::env::temp_dir().join(format!("sdfl-module-graph-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    let root = dir.as_path();
    let write = |rel: &str, text: &str| {
        let p = root.join(rel);
        fs::create_dir_all(p.parent().unwrap()).unwrap();
        fs::write(p, text).unwrap();
    };
    write(
        "mod.rs",
        "pub mod a; pub mod sub;\npub use sub::{b::Thing, c};\n",
    );
    write(
        "a.rs",
        "use super::sub::b::Thing;\nfn f() { crate::data::a::g(); }\n",
    );
    write(
        "sub/mod.rs",
        "pub mod b; pub mod c;\nconst X: &[u8] = &[b::N];\n",
    );
    write(
        "sub/b.rs",
        "use crate::data::{a, sub::c::D};\nuse crate::other::E;\n",
    );
    write("sub/c.rs", "use super::super::a::F;\nuse super::b;\n");
    let graph = folder_graph(root, &["data"]);
    let uses = |m: &str| graph[m].iter().cloned().collect::<Vec<_>>();
    assert_eq!(uses("mod"), ["sub::b", "sub::c"]);
    assert_eq!(uses("a"), ["sub::b"]);
    assert_eq!(uses("sub"), ["sub::b"]);
    assert_eq!(uses("sub::b"), ["a", "sub::c"]);
    assert_eq!(uses("sub::c"), ["a", "sub::b"]);
    assert_eq!(loops(&graph), [["a", "sub::b", "sub::c"]]);
    let _ = fs::remove_dir_all(&dir);
}
