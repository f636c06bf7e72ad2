use std::path::{Path, PathBuf};

use proptest::prelude::*;

use sdfl_lang::fmt::source::trivia;
use sdfl_lang::fmt::*;

/// Every `.sdfl` file under examples/, recursively, with its text.
fn examples() -> Vec<(PathBuf, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    let mut found = Vec::new();
    let mut dirs = vec![root];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).expect("examples/ is readable") {
            let path = entry.expect("a readable entry").path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "sdfl") {
                let text = std::fs::read_to_string(&path).expect("a readable example");
                found.push((path, text));
            }
        }
    }
    found.sort();
    assert!(found.len() >= 30, "only {} examples found", found.len());
    found
}

fn fmt(text: &str) -> String {
    match format(text) {
        Ok(t) => t,
        Err(FormatError::Syntax(d)) => panic!("does not parse: {d:?}\n{text}"),
        Err(FormatError::Unsafe(why)) => panic!("unsafe: {why}\n{text}"),
    }
}

/// Formatting keeps the meaning and the comments (`format` checks both)
/// and a second pass changes nothing.
fn assert_stable(text: &str) -> String {
    let once = fmt(text);
    let twice = fmt(&once);
    assert_eq!(once, twice, "not idempotent; from:\n{text}");
    let tree = |t: &str| spanless(sdfl_lang::parse::parse(t).expect("parses"));
    assert_eq!(tree(text), tree(&once));
    once
}

#[test]
fn every_example_is_in_the_canonical_layout() {
    let mut changed = Vec::new();
    for (path, text) in examples() {
        if assert_stable(&text) != text {
            changed.push(path.display().to_string());
        }
    }
    assert!(changed.is_empty(), "`sdfl fmt` would change {changed:?}");
}

#[test]
fn the_canonical_layout() {
    let cases = [
        (
            "let   a=1;let b =[1,2 ,3,]",
            "let a = 1\nlet b = [1, 2, 3]\n",
        ),
        (
            "render  x{scene:sphere(1),size:[64,64]}",
            "render x {\n  scene: sphere(1),\n  size: [64, 64],\n}\n",
        ),
        (
            "fn f(a,b:2){let c=a*b;c+1}",
            "fn f(a, b: 2) {\n  let c = a * b\n  c + 1\n}\n",
        ),
        (
            "let x = if a{1}else if b {2} else{3}",
            "let x = if a { 1 } else if b { 2 } else { 3 }\n",
        ),
        (
            "let x=for i in 0..=n,j in l{i}",
            "let x = for i in 0..=n, j in l { i }\n",
        ),
        ("let y = -(a+b)*c^(2).x", "let y = -(a + b) * c ^ (2).x\n"),
        (
            "let z = ((a)) [0] . f( 1 , k : 2 ).y",
            "let z = ((a))[0].f(1, k: 2).y\n",
        ),
        (
            "import \"a.sdfl\";\n\n\n\nlet a = !b && c",
            "import \"a.sdfl\"\n\nlet a = !b && c\n",
        ),
        ("let n = 1 .x", "let n = 1 .x\n"),
        ("let d = 45deg+1e-4+.5", "let d = 45deg + 1e-4 + .5\n"),
        ("empty {}", "empty {}\n"),
        ("", ""),
    ];
    for (input, expected) in cases {
        assert_eq!(assert_stable(input), expected, "from {input:?}");
    }
}

#[test]
fn long_calls_and_lists_are_broken_one_item_a_line() {
    let long = format!(
        "let a = f({}, g(b: [{}]))",
        "x".repeat(60),
        "1, ".repeat(20)
    );
    assert_eq!(
        assert_stable(&long),
        format!("let a = f(\n  {},\n  g(b: [{}]),\n)\n", "x".repeat(60), {
            let mut l = "1, ".repeat(20);
            l.truncate(l.len() - 2);
            l
        })
    );
    let longer = format!("let a = [{}]", "123456789, ".repeat(12));
    let out = assert_stable(&longer);
    assert_eq!(out.lines().count(), 14, "{out}");
    assert!(out.lines().all(|l| l.len() <= WIDTH));
}

#[test]
fn comments_stay_where_they_were_written() {
    let cases = [
        (
            "// head\n\n\n// second\nlet a = 1   // trailing\n/* block */ let b = 2\n",
            "// head\n\n// second\nlet a = 1 // trailing\n/* block */ let b = 2\n",
        ),
        (
            "render r { scene: s, // the scene\n  // before size\n  size: [1, 2] /* inline */, far: 3 }",
            "render r {\n  scene: s, // the scene\n  // before size\n  size: [1, 2] /* inline */,\n  far: 3,\n}\n",
        ),
        (
            "let a = f(1, // one\n2)",
            "let a = f(\n  1, // one\n  2,\n)\n",
        ),
        (
            "let a = f(1,\n// own line\n2,\n// at the end\n)",
            "let a = f(\n  1,\n  // own line\n  2,\n  // at the end\n)\n",
        ),
        (
            "let a = f(/* x */ 1) // t\n// end of file",
            "let a = f(/* x */ 1) // t\n// end of file\n",
        ),
        (
            "fn f() { // why\n  1 }",
            "fn f() { // why\n  1\n}\n",
        ),
        (
            "let a = 1 + // odd\n  2",
            "let a = 1 + // odd\n2\n",
        ),
        (
            "let a = if b { 1 } else { 2 } // after\nlet c = [1, 2 // two\n]",
            "let a = if b { 1 } else { 2 } // after\nlet c = [\n  1,\n  2, // two\n]\n",
        ),
    ];
    for (input, expected) in cases {
        assert_eq!(assert_stable(input), expected, "from {input:?}");
    }
}

/// Odd spacing, comments in every gap, long lines: each formats to a fixed
/// point with the same tree and comments.
#[test]
fn messy_inputs_reach_a_fixed_point() {
    let messy = [
        "let/*a*/x/*b*/=/*c*/f/*d*/(/*e*/1/*f*/,/*g*/k/*h*/:/*i*/2/*j*/)/*k*/",
        "let//a\nx//b\n=//c\nf//d\n(//e\n1//f\n,//g\nk//h\n://i\n2//j\n)//k\n",
        "render\tr\n{\n\n\n  scene :\n sphere ( 1 )\n\n ,\n\n\n size : [ 1 , 2 , ] , } ",
        "fn f ( a , b : [ 1 , 2 ] , ) { let c = a ; let d = b ; if c > d { c } else if c < d { d } else { 0 } }",
        "let x = for a in [ 1 , 2 ] , b in 0 .. 3 , c in 0 ..= 4 { let y = a ; [ y , b , c ] [ 0 ] . x }",
        "let y = - - 1 - ! ! true - ( ( 1 ) ) ^ ( 2 ) ^ 3 % 4 / 5 * 6 <= 7 == ( 8 != 9 ) || a >= b && c",
        "let s = \"a // not a comment /* nor this */ \\\" (\" // but this is\n",
        "let long = union(sphere(1, center: [1, 2, 3]), sphere(2, center: [4, 5, 6]), box(size: [1, 2, 3], center: [7, 8, 9]), torus(major: 1, minor: 0.25))",
        "let chain = box(size: 1.5 * r).rotate(45deg, axis: [0, 1, 0]).translate(top).rotate(45deg, axis: [0, 1, 0]).scale(2)",
        "let deep = f(g(h(i(j(k(l(m(n(o(p(q(r(s(t(u(v(w(x(y(z(1000000000, 2000000000, 3000000000)))))))))))))))))))))",
        "let c = if a { // why a\n 1 } else { /* b */ 2 }\n",
        "t n { a: [\n// only a comment\n], b: f(\n/* only */\n), c: g() }",
        "let a = [1, 2, 3 // last\n]\nlet b = f(x // first\n, y)",
        "/* a\n   multi-line\n      block */ let a = 1 /* b\n c */\nlet b = 2",
        "let a = f(x)// no space\n\n\n\n\n// many blank lines\n\n\n\nlet b = 1",
        "fn g(x) { let a = x\n\n\n  // spaced\n\n  let b = a\n  b }",
    ];
    for text in messy {
        let out = assert_stable(text);
        assert!(!out.contains("\n\n\n"), "two empty lines in:\n{out}");
        assert!(
            out.lines().all(|l| l == l.trim_end()),
            "trailing spaces in:\n{out}"
        );
    }
}

#[test]
fn a_file_that_does_not_parse_gives_its_diagnostics() {
    match format("let a = (\nlet b = ]") {
        Err(FormatError::Syntax(d)) => assert!(!d.is_empty()),
        other => panic!("{other:?}"),
    }
}

/// Hostile inputs within the parser's limits format without overflowing
/// the stack or taking quadratic time; those beyond are syntax errors.
#[test]
fn hostile_inputs_do_not_crash() {
    let nested_lists = format!("let a = {}1{}", "[".repeat(60), "]".repeat(60));
    let nested_calls = format!("let a = {}1{}", "f(".repeat(60), ")".repeat(60));
    let parens = format!("let a = {}1{}", "(".repeat(60), ")".repeat(60));
    let operators = format!("let a = 1{}", " + 1".repeat(500));
    let powers = format!("let a = 1{}", "^1".repeat(500));
    let methods = format!("let a = x{}", ".f()".repeat(600));
    let chain = format!("let a = {}{{ 0 }}", "if c { 1 } else ".repeat(600));
    let huge_line = format!("let a = [{}]", "0.5, ".repeat(100_000));
    let huge_string = format!("let a = \"{}\"", "x".repeat(1_000_000));
    let comments = "// c\n".repeat(100_000) + &"/* c */".repeat(100_000);
    for text in [
        nested_lists,
        nested_calls,
        parens,
        operators,
        powers,
        methods,
        chain,
        huge_line,
        huge_string,
        comments,
    ] {
        let first = text.chars().take(40).collect::<String>();
        let out = assert_stable(&text);
        assert!(!out.is_empty(), "{first}");
    }
    let too_deep = format!("let a = {}1{}", "[".repeat(100), "]".repeat(100));
    assert!(matches!(format(&too_deep), Err(FormatError::Syntax(_))));
}

// ---------------------------------------------------------------- property

/// The pieces of a file: code tokens (their text whole), comments and the
/// whitespace between.
#[derive(Debug, Clone, PartialEq)]
enum Piece {
    Code(String),
    Comment(String),
    Space(String),
}

fn pieces(text: &str) -> Vec<Piece> {
    let mut out = Vec::new();
    let mut pos = 0;
    let b = text.as_bytes();
    let word = |c: u8| c.is_ascii_alphanumeric() || c == b'_' || c == b'.';
    let op = |c: u8| b"<>=!&|".contains(&c);
    while pos < b.len() {
        let start = pos;
        let c = b[pos];
        let piece = if c.is_ascii_whitespace() {
            while pos < b.len() && b[pos].is_ascii_whitespace() {
                pos += 1;
            }
            Piece::Space(text[start..pos].into())
        } else if text[pos..].starts_with("//") || text[pos..].starts_with("/*") {
            let (comments, _, _) = trivia(text, pos);
            pos = comments[0].end;
            Piece::Comment(text[start..pos].into())
        } else if c == b'"' {
            pos += 1;
            while b[pos] != b'"' {
                pos += if b[pos] == b'\\' { 2 } else { 1 };
            }
            pos += 1;
            Piece::Code(text[start..pos].into())
        } else if word(c) || op(c) {
            let class = if word(c) { word } else { op };
            while pos < b.len() && class(b[pos]) {
                pos += 1;
                // The sign of a number's exponent (`1e-4`).
                if c.is_ascii_digit()
                    && matches!(b[pos - 1], b'e' | b'E')
                    && matches!(b.get(pos), Some(b'-' | b'+'))
                {
                    pos += 1;
                }
            }
            Piece::Code(text[start..pos].into())
        } else {
            pos += text[pos..].chars().next().map_or(1, char::len_utf8);
            Piece::Code(text[start..pos].into())
        };
        out.push(piece);
    }
    out
}

/// `text` with the whitespace between code tokens replaced by `spaces`
/// (taken in turn): gaps next to comments, and empty lines, are kept (they
/// are what the layout keeps), and two words are never joined.
fn respace(text: &str, spaces: &[&str]) -> String {
    let ps = pieces(text);
    let mut out = String::new();
    let mut k = 0;
    let is_word = |p: Option<&Piece>| matches!(p, Some(Piece::Code(t)) if t.bytes().all(|c| c.is_ascii_alphanumeric() || c == b'_' || c == b'.'));
    for i in 0..ps.len() {
        let before = i.checked_sub(1).and_then(|j| ps.get(j));
        let after = ps.get(i + 1);
        match &ps[i] {
            Piece::Code(t) | Piece::Comment(t) => out.push_str(t),
            Piece::Space(s) => {
                let fixed = s.matches('\n').count() > 1
                    || !matches!(before, Some(Piece::Code(_)))
                    || !matches!(after, Some(Piece::Code(_)));
                if fixed {
                    out.push_str(s);
                    continue;
                }
                let mut new = spaces[k % spaces.len()];
                k += 1;
                if new.is_empty() && is_word(before) && is_word(after) {
                    new = " ";
                }
                out.push_str(new);
            }
        }
        if i + 1 < ps.len() {
            // Adjacent code pieces (`f(`): a gap may be opened between them.
            if let (Piece::Code(_), Some(Piece::Code(_))) = (&ps[i], after) {
                let ends_op = matches!(&ps[i], Piece::Code(t) if t == "-");
                let new = spaces[k % spaces.len()];
                k += 1;
                if !ends_op && !new.contains('\n') {
                    out.push_str(new);
                }
            }
        }
    }
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Respacing an example between its tokens formats back to the example.
    #[test]
    fn respaced_examples_format_to_the_canonical_layout(
        which in 0usize..1000,
        spaces in prop::collection::vec(prop::sample::select(vec!["", " ", "   ", "\t", "\n", " \n\t "]), 1..40),
    ) {
        let all = examples();
        let (path, text) = &all[which % all.len()];
        let messy = respace(text, &spaces);
        prop_assert_eq!(&fmt(&messy), text, "{} respaced:\n{}", path.display(), messy);
    }
}

/// Small statements as tokens, every construct a comment can sit between.
const STATEMENTS: &[&[&str]] = &[
    &["import", "\"lib.sdfl\"", ";"],
    &["let", "a", "=", "1", ";"],
    &[
        "let", "s", "=", "sphere", "(", "radius", ":", "-", "0.5", ")",
    ],
    &[
        "fn", "f", "(", "p", ",", "k", ":", "2", ")", "{", "length", "(", "p", ")", "*", "k", "}",
    ],
    &[
        "render",
        "r",
        "{",
        "scene",
        ":",
        "s",
        ",",
        "outputs",
        ":",
        "[",
        "image",
        "(",
        "\"r.png\"",
        ")",
        ",",
        "]",
        "}",
    ],
];

/// What may stand between two tokens: spaces, line breaks, and comments of
/// both kinds, alone or together on a line.
const GAPS: &[&str] = &[
    " ",
    "\n",
    "\n\n",
    " /* c */ ",
    " // c\n",
    "\n// own\n",
    " /* a */ // b\n",
    " /* a */ /* b */ ",
    "\n/* own */\n",
];

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Formatting is idempotent wherever comments stand: a file of small
    /// statements with a comment or a line break in any gap formats, and
    /// formats again to the same text.
    #[test]
    fn formatting_twice_changes_nothing(
        order in prop::collection::vec(0..STATEMENTS.len(), 1..4),
        gaps in prop::collection::vec(prop::sample::select(GAPS), 64),
    ) {
        let mut src = String::new();
        let mut k = 0;
        for &i in &order {
            for t in STATEMENTS[i] {
                src.push_str(t);
                src.push_str(gaps[k % gaps.len()]);
                k += 1;
            }
            src.push('\n');
        }
        let once = fmt(&src);
        let twice = fmt(&once);
        prop_assert_eq!(&twice, &once, "formatted from:\n{}", src);
    }
}
