//! Fuzzing the front end: whatever text `sdfl_stdlib::load` is given, it
//! returns (never panics, never hangs), and every diagnostic it returns is
//! well formed: a span inside the source on character boundaries, a
//! non-empty message, label and help, a stable `sdfl::` code, and a report
//! that renders.
//!
//! Four kinds of input:
//! - arbitrary strings (any Unicode, and bytes decoded lossily);
//! - token soups: random sequences of the grammar's tokens (keywords,
//!   built-in and parameter names, numbers, strings, punctuation);
//! - mutations (byte and token deletions, insertions, swaps) of the example
//!   scenes in `examples/`;
//! - well-typed programs generated from the built-ins' signatures (random
//!   calls, arguments, loops and blocks, with out-of-range values now and
//!   then), which get past the parser and checker to the evaluator's value
//!   checks.
//!
//! Each property runs 256 cases by default; set `PROPTEST_CASES` for more
//! (`PROPTEST_CASES=20000 cargo test -p sdfl-stdlib --test suite fuzz::`).

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use proptest::prelude::*;
use proptest::sample::{select, Index};
use proptest::test_runner::TestCaseError;
use sdfl_lang::types::Type;
use sdfl_lang::SourceFile;
use sdfl_stdlib::builtins::{MATERIAL, SHAPE};
use sdfl_stdlib::StdEnv;

/// No single input may take longer than this to load (the slowest legal
/// inputs, a million-iteration loop, take well under a second).
/// A hang guard: generous, so that only a hang trips it on a loaded machine.
const TIME_LIMIT: Duration = Duration::from_secs(60);

/// Loads `text` and checks the result. The failure message quotes the input
/// so that a shrunk counterexample can be turned into a regression test.
fn check_source(text: &str) -> Result<(), TestCaseError> {
    let src = SourceFile::new("fuzz.sdfl", text);
    let t0 = Instant::now();
    let result = sdfl_stdlib::load(&src);
    let elapsed = t0.elapsed();
    prop_assert!(elapsed < TIME_LIMIT, "load took {elapsed:?} on {text:?}");
    // `check` (parse and check only) must agree with `load` on every
    // syntax and name error: it may only accept more.
    let checked = sdfl_stdlib::check(&src);
    let Err(diags) = result else {
        prop_assert!(checked.is_ok(), "load accepted, check rejected {text:?}");
        return Ok(());
    };
    prop_assert!(!diags.is_empty(), "Err with no diagnostics for {text:?}");
    for d in &diags.diags {
        let spans =
            std::iter::once((d.span, "primary")).chain(d.notes.iter().map(|n| (n.0, "note")));
        for (span, what) in spans {
            prop_assert!(
                span.start <= span.end
                    && span.end <= text.len()
                    && text.is_char_boundary(span.start)
                    && text.is_char_boundary(span.end),
                "{what} span {span:?} of {d:?} is outside the {} bytes of {text:?}",
                text.len()
            );
        }
        prop_assert!(d.code.starts_with("sdfl::"), "bad code in {d:?}");
        prop_assert!(
            !d.message.trim().is_empty(),
            "empty message: {d:?} for {text:?}"
        );
        prop_assert!(
            !d.label.trim().is_empty(),
            "empty label: {d:?} for {text:?}"
        );
        prop_assert!(
            d.help.as_deref().is_some_and(|h| !h.trim().is_empty()),
            "no help: {d:?} for {text:?}"
        );
        for (_, note) in &d.notes {
            prop_assert!(!note.trim().is_empty(), "empty note: {d:?} for {text:?}");
        }
    }
    let rendered = sdfl_lang::render(&src, &diags, false);
    for d in &diags.diags {
        prop_assert!(
            rendered.contains(d.code),
            "rendered report lacks {}: {rendered}",
            d.code
        );
    }
    Ok(())
}

/// Default case count 256, or `PROPTEST_CASES`; no shrinking marathons.
fn config() -> ProptestConfig {
    ProptestConfig {
        max_shrink_iters: 2048,
        ..ProptestConfig::default()
    }
}

// -------------------------------------------------------------------- tokens

/// Every name the standard library knows: functions, statements, their
/// parameters and fields, constants.
fn known_names() -> &'static [String] {
    static NAMES: OnceLock<Vec<String>> = OnceLock::new();
    NAMES.get_or_init(|| {
        let env = StdEnv::get();
        let mut names: Vec<String> = Vec::new();
        for b in env.builtins() {
            names.push(b.sig.name.to_string());
            names.extend(b.sig.params.iter().map(|p| p.name.to_string()));
        }
        for b in env.blocks() {
            names.push(b.kind.to_string());
            names.extend(b.fields.iter().map(|p| p.name.to_string()));
        }
        names.extend(
            [
                "pi", "tau", "x", "y", "z", "a", "i", "scene", "sphre", "_", "deg",
            ]
            .map(String::from),
        );
        names.sort();
        names.dedup();
        names
    })
}

const KEYWORDS: &[&str] = &[
    "let", "for", "in", "true", "false", "if", "else", "fn", "import",
];

const NUMBERS: &[&str] = &[
    "0",
    "1",
    "2",
    "3",
    "-1",
    "0.5",
    ".5",
    "2.",
    "1e-4",
    "1e400",
    "1e308",
    "30deg",
    "1deg",
    "256",
    "1000000",
    "1e9",
    "1e12",
    "0.0",
    "4294967296",
    "16384",
    "16385",
    "10000",
    "1.5e3",
    "9999999999999999999999",
];

const STRINGS: &[&str] = &[
    "\"x.png\"",
    "\"a.gif\"",
    "\"out/{view}.png\"",
    "\"../x.png\"",
    "\"/etc/x.png\"",
    "\"\"",
    "\"a\\qb\"",
    "\"\\\"\"",
    "\"x.npy\"",
    "\"fused\"",
    "\"dfdx\"",
    "\"ünïcødé.png\"",
    "\"unterminated",
];

const PUNCTUATION: &[&str] = &[
    "(", ")", "[", "]", "{", "}", ",", ":", ";", "=", ".", "+", "-", "*", "/", "%", "^", "..",
    "..=", "//", "/*", "*/", "\"", "\\", "\n", "<", "<=", ">", ">=", "==", "!=", "&&", "||", "!",
];

fn token() -> impl Strategy<Value = String> {
    prop_oneof![
        3 => select(known_names()),
        1 => select(KEYWORDS).prop_map(String::from),
        2 => select(NUMBERS).prop_map(String::from),
        1 => select(STRINGS).prop_map(String::from),
        4 => select(PUNCTUATION).prop_map(String::from),
    ]
}

fn separator() -> impl Strategy<Value = &'static str> {
    prop_oneof![4 => Just(" "), 2 => Just(""), 1 => Just("\n"), 1 => Just("\t")]
}

fn token_soup() -> impl Strategy<Value = String> {
    prop::collection::vec((token(), separator()), 0..80).prop_map(|tokens| {
        let mut s = String::new();
        for (t, sep) in tokens {
            s.push_str(&t);
            s.push_str(sep);
        }
        s
    })
}

// ----------------------------------------------------------------- mutations

fn examples() -> &'static [String] {
    static EXAMPLES: OnceLock<Vec<String>> = OnceLock::new();
    EXAMPLES.get_or_init(|| {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples");
        let mut paths: Vec<_> = std::fs::read_dir(dir)
            .expect("examples/ exists")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "sdfl"))
            .collect();
        paths.sort();
        let texts: Vec<String> = paths
            .iter()
            .map(|p| std::fs::read_to_string(p).expect("example is UTF-8"))
            .collect();
        assert!(!texts.is_empty(), "no examples in {dir}");
        texts
    })
}

/// Byte ranges of the tokens of `text`: runs of name characters, strings,
/// `//` comments, single other characters (whitespace excluded).
fn tokens_of(text: &str) -> Vec<(usize, usize)> {
    let b = text.as_bytes();
    let is_word = |c: u8| c.is_ascii_alphanumeric() || c == b'_' || c >= 0x80;
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let start = i;
        match b[i] {
            c if c.is_ascii_whitespace() => {
                i += 1;
                continue;
            }
            b'"' => {
                i += 1;
                while i < b.len() && b[i] != b'"' && b[i] != b'\n' {
                    i += 1;
                }
                i = (i + 1).min(b.len());
            }
            b'/' if b.get(i + 1) == Some(&b'/') => {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
            }
            c if is_word(c) => {
                while i < b.len() && is_word(b[i]) {
                    i += 1;
                }
            }
            _ => i += 1,
        }
        out.push((start, i));
    }
    out
}

#[derive(Debug, Clone)]
enum Mutation {
    DeleteByte(Index),
    InsertByte(Index, u8),
    SwapBytes(Index, Index),
    DeleteToken(Index),
    InsertToken(Index, String),
    ReplaceToken(Index, String),
    SwapTokens(Index, Index),
    DuplicateToken(Index),
    DuplicateLine(Index),
    /// A number token replaced by another number: the file still parses.
    ReplaceNumber(Index, &'static str),
    /// A name replaced by another known name.
    ReplaceName(Index, String),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let interesting_byte = prop_oneof![
        any::<u8>(),
        select(b"()[]{},:;=.+-*/%^\"\\\n 0123456789eE_x".to_vec()),
    ];
    prop_oneof![
        1 => any::<Index>().prop_map(Mutation::DeleteByte),
        1 => (any::<Index>(), interesting_byte).prop_map(|(i, b)| Mutation::InsertByte(i, b)),
        1 => (any::<Index>(), any::<Index>()).prop_map(|(i, j)| Mutation::SwapBytes(i, j)),
        2 => any::<Index>().prop_map(Mutation::DeleteToken),
        2 => (any::<Index>(), token()).prop_map(|(i, t)| Mutation::InsertToken(i, t)),
        2 => (any::<Index>(), token()).prop_map(|(i, t)| Mutation::ReplaceToken(i, t)),
        1 => (any::<Index>(), any::<Index>()).prop_map(|(i, j)| Mutation::SwapTokens(i, j)),
        1 => any::<Index>().prop_map(Mutation::DuplicateToken),
        1 => any::<Index>().prop_map(Mutation::DuplicateLine),
        4 => (any::<Index>(), select(NUMBERS)).prop_map(|(i, n)| Mutation::ReplaceNumber(i, n)),
        3 => (any::<Index>(), select(known_names())).prop_map(|(i, n)| Mutation::ReplaceName(i, n)),
    ]
}

fn apply(text: &[u8], m: &Mutation) -> Vec<u8> {
    let mut b = text.to_vec();
    if b.is_empty() {
        return b;
    }
    // Token positions are computed on a lossy decoding: after a byte
    // mutation the text may not be UTF-8 any more.
    let s = String::from_utf8_lossy(text).into_owned();
    let toks = tokens_of(&s);
    let sb = s.as_bytes();
    match m {
        Mutation::DeleteByte(i) => {
            b.remove(i.index(b.len()));
        }
        Mutation::InsertByte(i, c) => b.insert(i.index(b.len() + 1), *c),
        Mutation::SwapBytes(i, j) => {
            let (i, j) = (i.index(b.len()), j.index(b.len()));
            b.swap(i, j);
        }
        _ if toks.is_empty() => {}
        Mutation::DeleteToken(i) => {
            let (s0, e0) = toks[i.index(toks.len())];
            b = [&sb[..s0], &sb[e0..]].concat();
        }
        Mutation::InsertToken(i, t) => {
            let (s0, _) = toks[i.index(toks.len())];
            b = [&sb[..s0], t.as_bytes(), b" ", &sb[s0..]].concat();
        }
        Mutation::ReplaceToken(i, t) => {
            let (s0, e0) = toks[i.index(toks.len())];
            b = [&sb[..s0], t.as_bytes(), &sb[e0..]].concat();
        }
        Mutation::SwapTokens(i, j) => {
            let (mut x, mut y) = (toks[i.index(toks.len())], toks[j.index(toks.len())]);
            if x.0 > y.0 {
                std::mem::swap(&mut x, &mut y);
            }
            if x.1 <= y.0 {
                b = [
                    &sb[..x.0],
                    &sb[y.0..y.1],
                    &sb[x.1..y.0],
                    &sb[x.0..x.1],
                    &sb[y.1..],
                ]
                .concat();
            }
        }
        Mutation::DuplicateToken(i) => {
            let (s0, e0) = toks[i.index(toks.len())];
            b = [&sb[..e0], b" ", &sb[s0..e0], &sb[e0..]].concat();
        }
        Mutation::ReplaceNumber(i, n) => {
            let numbers: Vec<_> = toks
                .iter()
                .filter(|(s0, _)| sb[*s0].is_ascii_digit())
                .collect();
            if !numbers.is_empty() {
                let (s0, e0) = *numbers[i.index(numbers.len())];
                b = [&sb[..s0], n.as_bytes(), &sb[e0..]].concat();
            }
        }
        Mutation::ReplaceName(i, n) => {
            let names: Vec<_> = toks
                .iter()
                .filter(|(s0, _)| sb[*s0].is_ascii_alphabetic())
                .collect();
            if !names.is_empty() {
                let (s0, e0) = *names[i.index(names.len())];
                b = [&sb[..s0], n.as_bytes(), &sb[e0..]].concat();
            }
        }
        Mutation::DuplicateLine(i) => {
            let lines: Vec<&str> = s.split_inclusive('\n').collect();
            let k = i.index(lines.len());
            let mut out = String::new();
            for (n, l) in lines.iter().enumerate() {
                out.push_str(l);
                if n == k {
                    out.push_str(l);
                }
            }
            b = out.into_bytes();
        }
    }
    b
}

fn mutated_example() -> impl Strategy<Value = String> {
    (any::<Index>(), prop::collection::vec(mutation(), 1..6)).prop_map(|(which, muts)| {
        let ex = examples();
        let mut b = ex[which.index(ex.len())].clone().into_bytes();
        for m in &muts {
            b = apply(&b, m);
        }
        String::from_utf8_lossy(&b).into_owned()
    })
}

// ------------------------------------------------------ well-typed programs

/// A tape of random choices from which a program is generated: proptest
/// shrinks the tape (shorter, smaller numbers), which shrinks the program
/// towards first choices and shallow expressions.
struct Tape<'a> {
    choices: &'a [u32],
    at: usize,
}

impl Tape<'_> {
    /// A choice in `0..n` (0 once the tape is used up).
    fn pick(&mut self, n: usize) -> usize {
        let c = self.choices.get(self.at).copied().unwrap_or(0);
        self.at += 1;
        c as usize % n.max(1)
    }
    /// True with probability about `1/n`.
    fn one_in(&mut self, n: usize) -> bool {
        self.pick(n) == n - 1
    }
    fn choose<'b, T>(&mut self, items: &'b [T]) -> &'b T {
        &items[self.pick(items.len())]
    }
}

/// Strings a scene plausibly uses (no escapes: those are syntax errors).
const PLAIN_STRINGS: &[&str] = &[
    "\"x.png\"",
    "\"a.gif\"",
    "\"out/{view}.png\"",
    "\"x.npy\"",
    "\"fused\"",
    "\"dfdx\"",
    "\"\"",
    "\"../x.png\"",
];

/// Numbers a scene plausibly uses, then ones that break limits.
const SANE_NUMBERS: &[&str] = &[
    "1", "0.5", "2", "0.25", "3", "0", "-1", "10", "8", "1e-4", "45deg",
];

fn gen_number(t: &mut Tape) -> String {
    if t.one_in(30) {
        t.choose(NUMBERS).to_string()
    } else {
        t.choose(SANE_NUMBERS).to_string()
    }
}

/// An expression of type `ty` (deliberately, one of another type now and
/// then). `depth` bounds the nesting of calls.
fn gen_typed(t: &mut Tape, ty: &Type, depth: u32) -> String {
    if t.one_in(150) {
        // A type error, or a value from elsewhere: the checker's business.
        let other = [Type::Number, Type::Str, Type::Vec3, SHAPE, Type::Bool];
        let ty = t.choose(&other).clone();
        return gen_typed(t, &ty, depth.saturating_sub(1));
    }
    match ty {
        Type::Any => {
            let options = [Type::Number, Type::Vec3];
            let ty = t.choose(&options).clone();
            gen_typed(t, &ty, depth)
        }
        Type::Number => match t.pick(10) {
            8 if depth > 0 => {
                let c = gen_typed(t, &Type::Bool, depth - 1);
                let (a, b) = (gen_typed(t, ty, depth - 1), gen_typed(t, ty, depth - 1));
                format!("if {c} {{ {a} }} else {{ {b} }}")
            }
            9 if depth > 0 => {
                let items = gen_typed(t, &Type::list(Type::Number), depth - 1);
                let i = t.choose(&["0", "1", "2", "-1", "0.5"]).to_string();
                format!("({items})[{i}]")
            }
            5 if depth > 0 => {
                let op = t.choose(&["+", "-", "*", "/", "%", "^"]).to_string();
                let (a, b) = (gen_typed(t, ty, depth - 1), gen_typed(t, ty, depth - 1));
                format!("({a} {op} {b})")
            }
            6 if depth > 0 => {
                let f = t
                    .choose(&["sin", "cos", "sqrt", "abs", "floor", "min", "max", "atan2"])
                    .to_string();
                gen_call(t, &f, depth - 1)
            }
            7 => format!(
                "{}.{}",
                gen_typed(t, &Type::Vec3, 0),
                t.choose(&["x", "y", "z"])
            ),
            _ => gen_number(t),
        },
        Type::Bool => match t.pick(4) {
            0 if depth > 0 => {
                let op = t.choose(&["<", "<=", ">", ">=", "==", "!="]).to_string();
                let (a, b) = (
                    gen_typed(t, &Type::Number, depth - 1),
                    gen_typed(t, &Type::Number, depth - 1),
                );
                format!("({a} {op} {b})")
            }
            1 if depth > 0 => {
                let op = t.choose(&["&&", "||"]).to_string();
                let (a, b) = (gen_typed(t, ty, depth - 1), gen_typed(t, ty, depth - 1));
                format!("(!{a} {op} {b})")
            }
            _ => t.choose(&["true", "false"]).to_string(),
        },
        Type::Str => t.choose(PLAIN_STRINGS).to_string(),
        Type::Vec3 => match t.pick(5) {
            4 if depth > 0 => {
                let (a, b) = (
                    gen_typed(t, ty, depth - 1),
                    gen_typed(t, &Type::Number, depth - 1),
                );
                format!("({a} * {b})")
            }
            _ => format!("[{}, {}, {}]", gen_number(t), gen_number(t), gen_number(t)),
        },
        Type::List(elem) => match t.pick(4) {
            3 if depth > 0 => {
                let range = t
                    .choose(&["0..3", "0..=2", "[1, 2]", "0..0", "-1..2", "0..1e7"])
                    .to_string();
                let body = gen_typed(t, elem, depth - 1);
                format!("for i in {range} {{ {body} }}")
            }
            _ => {
                let n = 1 + t.pick(3);
                let items: Vec<String> = (0..n)
                    .map(|_| gen_typed(t, elem, depth.saturating_sub(1)))
                    .collect();
                format!("[{}]", items.join(", "))
            }
        },
        Type::OneOf(options) => {
            let ty = t.choose(options).clone();
            gen_typed(t, &ty, depth)
        }
        Type::Named(_) => {
            let env = StdEnv::get();
            let makers: Vec<&'static str> = env
                .builtins()
                .iter()
                .filter(|b| b.sig.returns != Type::Any && ty.accepts(&b.sig.returns))
                .filter(|b| {
                    depth > 0
                        || !b
                            .sig
                            .params
                            .iter()
                            .any(|p| p.default.is_none() && matches!(p.ty, Type::Named(_)))
                })
                .map(|b| b.sig.name)
                .collect();
            if makers.is_empty() {
                return gen_number(t);
            }
            let f = t.choose(&makers).to_string();
            gen_call(t, &f, depth.saturating_sub(1))
        }
    }
}

/// A call of the built-in `f`: its required arguments (positional or
/// named), some optional ones, rest arguments for variadics; as a method
/// call now and then.
fn gen_call(t: &mut Tape, f: &str, depth: u32) -> String {
    let sig = StdEnv::get().builtin(f).expect("a built-in").sig.clone();
    let mut args = Vec::new();
    let mut named = false;
    for p in &sig.params {
        if p.default.is_some() && t.pick(3) != 0 {
            continue;
        }
        let v = gen_typed(t, &p.ty, depth);
        named |= p.default.is_some() || t.one_in(2);
        args.push(if named { format!("{}: {v}", p.name) } else { v });
    }
    if let Some(rest) = &sig.rest {
        for _ in 0..1 + t.pick(3) {
            args.push(gen_typed(t, &rest.ty, depth));
        }
    }
    if !args.is_empty() && !args[0].contains(':') && t.one_in(4) {
        let recv = args.remove(0);
        return format!("({recv}).{f}({})", args.join(", "));
    }
    format!("{f}({})", args.join(", "))
}

/// A file of `let`s and blocks with their required fields and some optional
/// ones, generated from `choices`.
fn gen_program(choices: &[u32]) -> String {
    let t = &mut Tape { choices, at: 0 };
    let env = StdEnv::get();
    let mut out = String::new();
    // Names are distinct, but for one in twenty (a duplicate-name error).
    for n in 0..t.pick(3) {
        let ty = t
            .choose(&[SHAPE, Type::Number, Type::Vec3, MATERIAL])
            .clone();
        let name = if t.one_in(20) { 0 } else { n };
        out.push_str(&format!("let v{name} = {}\n", gen_typed(t, &ty, 3)));
    }
    for n in 0..1 + t.pick(2) {
        let sig = t.choose(env.blocks()).clone();
        let name = if t.one_in(20) { 0 } else { n };
        out.push_str(&format!("{} b{name} {{\n", sig.kind));
        for p in &sig.fields {
            if p.default.is_some() && t.pick(3) != 0 {
                continue;
            }
            out.push_str(&format!("  {}: {},\n", p.name, gen_typed(t, &p.ty, 3)));
        }
        out.push_str("}\n");
    }
    out
}

fn program() -> impl Strategy<Value = String> {
    prop::collection::vec(any::<u32>(), 0..2000).prop_map(|c| gen_program(&c))
}

// ------------------------------------------------- sharing and loop bombs

/// A chain of `let`s where each value uses earlier ones several times
/// (`let a5 = union(a4, a4, a2)`): tiny files whose values expand
/// exponentially, which evaluation must measure without expanding.
fn sharing_program() -> impl Strategy<Value = String> {
    (
        1usize..70,
        0usize..4,
        prop::collection::vec((0usize..6, 0usize..3, 1usize..4), 70),
        any::<bool>(),
    )
        .prop_map(|(n, base, steps, render)| {
            let mut text = format!(
                "let a0 = {}\n",
                ["sphere(0.1)", "[1, 2, 3]", "box()", "[sphere(), box()]"][base]
            );
            for (k, (op, back, copies)) in steps.iter().take(n).enumerate() {
                let k = k + 1;
                let prev = format!("a{}", k - 1);
                let older = format!("a{}", (k - 1).saturating_sub(*back));
                let mut args = vec![prev.clone(); *copies];
                args.push(older);
                let args = args.join(", ");
                let expr = match op {
                    0 => format!("union({args})"),
                    1 => format!("[{args}]"),
                    2 => format!("for i in 0..{copies} {{ {prev} }}"),
                    3 => format!("smooth_union({prev}, {prev}, k: 0.1)"),
                    4 => format!("{prev}.translate([1, 0, 0])"),
                    _ => format!("intersection({args})"),
                };
                text += &format!("let a{k} = {expr}\n");
            }
            if render {
                text += &format!(
                    "render r {{ scene: a{n}, camera: look_at([0, 0, -3]), outputs: [image(\"r.png\")] }}\n"
                );
            }
            text
        })
}

/// Nested loops over unions and lists with counts from 1 to beyond the
/// limits: a few calls that ask for up to 10^18 primitives.
fn loop_program() -> impl Strategy<Value = String> {
    let count = select(vec![1u64, 3, 10, 100, 1000, 3000, 100_000, 2_000_000]);
    (prop::collection::vec((count, 0usize..3), 1..4), any::<bool>()).prop_map(|(levels, render)| {
        let mut text = String::from("let l0 = sphere(0.1)\n");
        for (k, (n, wrap)) in levels.iter().enumerate() {
            let prev = format!("l{k}");
            let body = match wrap {
                0 => format!("union({prev})"),
                1 => format!("{prev}.translate([i, 0, 0])"),
                _ => format!("[{prev}, {prev}]"),
            };
            text += &format!("let l{} = for i in 0..{n} {{ {body} }}\n", k + 1);
        }
        if render {
            text += &format!(
                "render r {{ scene: union(l{}), camera: look_at([0, 0, -3]), outputs: [image(\"r.png\")] }}\n",
                levels.len()
            );
        }
        text
    })
}

/// Loads a bomb: well formed as any input, quick, and when accepted every
/// statement's scene is within the primitive budget once expanded.
fn check_bomb(text: &str) -> Result<(), TestCaseError> {
    let t0 = Instant::now();
    check_source(text)?;
    let src = SourceFile::new("bomb.sdfl", text);
    if let Ok(program) = sdfl_stdlib::load(&src) {
        for job in &program.renders {
            let n = job.scene.primitive_count() as u64;
            prop_assert!(
                n <= sdfl_stdlib::size::MAX_PRIMITIVES,
                "{n} primitives accepted in {text:?}"
            );
        }
    }
    let elapsed = t0.elapsed();
    prop_assert!(elapsed < TIME_LIMIT, "{elapsed:?} on {text:?}");
    Ok(())
}

proptest! {
    // Few cases: the largest accepted loops take a second each.
    #![proptest_config(ProptestConfig { cases: 24, ..config() })]

    #[test]
    fn sharing_bombs(text in sharing_program()) {
        check_bomb(&text)?;
    }

    #[test]
    fn loop_bombs(text in loop_program()) {
        check_bomb(&text)?;
    }
}

// ---------------------------------------------------------------- properties

proptest! {
    #![proptest_config(config())]

    #[test]
    fn arbitrary_unicode_strings(text in any::<String>()) {
        check_source(&text)?;
    }

    #[test]
    fn arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        check_source(&String::from_utf8_lossy(&bytes))?;
    }

    #[test]
    fn strings_of_grammar_characters(
        text in "[a-z0-9_ \n\t(){}\\[\\],:;=.+*/%^\"\\\\-]{0,200}"
    ) {
        check_source(&text)?;
    }

    #[test]
    fn token_soups(text in token_soup()) {
        check_source(&text)?;
    }

    #[test]
    fn token_soups_after_a_let(text in token_soup()) {
        check_source(&format!("let a = {text}"))?;
    }

    #[test]
    fn mutated_examples(text in mutated_example()) {
        check_source(&text)?;
    }

    #[test]
    fn random_programs(text in program()) {
        check_source(&text)?;
    }
}

/// The unmutated examples load from where they are (so the mutations start
/// from valid files, and their imports resolve).
#[test]
fn examples_load() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples");
    for e in std::fs::read_dir(dir).expect("examples/ exists") {
        let path = e.expect("a directory entry").path();
        if path.extension().is_none_or(|e| e != "sdfl") {
            continue;
        }
        let text = std::fs::read_to_string(&path).expect("example is UTF-8");
        let src = SourceFile::new("example.sdfl", text).at(&path);
        if let Err(d) = sdfl_stdlib::load(&src) {
            panic!("{}", sdfl_lang::render(&src, &d, false));
        }
    }
}

/// Regression inputs: each once crashed or hung the front end.
#[test]
fn regressions() {
    let nested_for_sources = {
        let mut e = String::from("[1]");
        for i in 0..30 {
            e = format!("[for i{i} in {e} {{1}}]");
        }
        format!("let a = {e}")
    };
    let cases = [
        // Exponential backtracking: each nested `for` parsed its source twice.
        nested_for_sources,
        // `for` nested in `for` sources, unbounded by brackets.
        format!(
            "let a = {}[1]{}",
            "for x in ".repeat(5000),
            " {1}".repeat(5000)
        ),
        // Method, member and binding chains build trees as tall as they are long.
        format!("let a = sphere(){}", ".scale(1)".repeat(5000)),
        format!("let a = [1, 2, 3]{}", ".x".repeat(5000)),
        format!(
            "let a = for {} {{ 1 }}",
            (0..5000)
                .map(|i| format!("i{i} in [1]"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        // 60 brackets of 500 `^` each: the Pratt parser's recursion nested.
        format!(
            "let a = {}1{}",
            "(1^".repeat(60).replace('^', &"1^".repeat(500)),
            ")".repeat(60)
        ),
        // Quadratic checking: every `let` cloned the ever deeper list type.
        format!(
            "let a0 = 1\n{}",
            (1..20_000)
                .map(|i| format!("let a{i} = [a{}]\n", i - 1))
                .collect::<String>()
        ),
    ];
    for text in &cases {
        check_source(text).unwrap_or_else(|e| panic!("{e}"));
    }
}

/// The generators are worth their time: well-typed programs get past the
/// parser and checker to the built-ins' value checks most of the time, and
/// mutated examples reach many different diagnostics, not only syntax
/// errors. (`FUZZ_SHOW=1` prints the sampled programs; `--nocapture` shows
/// the statistics.)
#[test]
fn generators_reach_the_evaluator() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::TestRunner;
    use std::collections::{BTreeMap, BTreeSet};
    let mut runner = TestRunner::deterministic();
    let mut stats: BTreeMap<(&str, &str), usize> = BTreeMap::new();
    let n = 300;
    for (kind, strategy) in [
        ("program", program().boxed()),
        ("mutant", mutated_example().boxed()),
        ("soup", token_soup().boxed()),
    ] {
        for _ in 0..n {
            let text = strategy.new_tree(&mut runner).expect("a value").current();
            let outcome = match sdfl_stdlib::load(&SourceFile::new("t", text.as_str())) {
                Ok(_) => "ok",
                Err(d) => d.diags[0].code,
            };
            if kind == "program" && std::env::var_os("FUZZ_SHOW").is_some() {
                eprintln!("----- {outcome}\n{text}");
            }
            *stats.entry((kind, outcome)).or_default() += 1;
        }
    }
    eprintln!("{stats:#?}");
    let count = |kind: &str, codes: &[&str]| -> usize {
        codes
            .iter()
            .map(|c| stats.get(&(kind, *c)).copied().unwrap_or(0))
            .sum()
    };
    let evaluated = count(
        "program",
        &[
            "ok",
            "sdfl::value::range",
            "sdfl::value::arithmetic",
            "sdfl::path::escape",
            "sdfl::limit::too-large",
        ],
    );
    assert!(
        evaluated * 2 > n,
        "only {evaluated} of {n} programs were evaluated: {stats:#?}"
    );
    let mutant_codes: BTreeSet<&str> = stats
        .keys()
        .filter(|k| k.0 == "mutant")
        .map(|k| k.1)
        .collect();
    assert!(
        mutant_codes.len() >= 8,
        "mutants reach only {mutant_codes:?}"
    );
    assert!(mutant_codes.contains("ok"), "no mutant loads: {stats:#?}");
}
