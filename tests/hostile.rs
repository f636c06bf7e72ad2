//! Hostile inputs through the real binary: `sdfl check FILE` and
//! `sdfl run FILE --out DIR --size 8x8` on garbage, enormous, deeply nested
//! and absurd files. Whatever the input, the process exits with 0 or 1
//! within a time bound (never a signal, a panic's 101 or a stack overflow),
//! and when it fails, stderr names a diagnostic code (`sdfl::...`).

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Longest any one command may take (the slowest cases need about a second).
const TIME_LIMIT: Duration = Duration::from_secs(20);

/// What a run of the binary did.
struct Outcome {
    code: Option<i32>,
    stderr: String,
    elapsed: Duration,
}

/// A fresh, empty directory for one case.
fn case_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("hostile")
        .join(name);
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).expect("temp dir is writable");
    dir
}

/// Runs `sdfl` with `args`, killing it after [`TIME_LIMIT`]. Output goes to
/// files (a pipe could fill up and block the child).
fn sdfl(dir: &Path, args: &[&str]) -> Outcome {
    let (out_path, err_path) = (dir.join("stdout.txt"), dir.join("stderr.txt"));
    let t0 = Instant::now();
    let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(fs::File::create(&out_path).expect("stdout file"))
        .stderr(fs::File::create(&err_path).expect("stderr file"))
        .spawn()
        .expect("the sdfl binary starts");
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for sdfl") {
            break status;
        }
        if t0.elapsed() > TIME_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            panic!("`sdfl {}` ran longer than {TIME_LIMIT:?}", args.join(" "));
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let stderr = String::from_utf8_lossy(&fs::read(&err_path).unwrap_or_default()).into_owned();
    Outcome {
        code: status.code(),
        stderr,
        elapsed: t0.elapsed(),
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Expect {
    /// Exit 0.
    Ok,
    /// Exit 1 with a diagnostic.
    Error,
}

/// The start of stderr, for failure messages (some are megabytes long).
fn head(s: &str) -> &str {
    let mut end = s.len().min(2000);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

fn assert_outcome(what: &str, o: &Outcome, expect: Expect) {
    assert!(
        matches!(o.code, Some(0 | 1)),
        "{what}: exit {:?} (a signal, panic or overflow), stderr:\n{}",
        o.code,
        head(&o.stderr)
    );
    assert!(
        !o.stderr.contains("panicked") && !o.stderr.contains("overflowed its stack"),
        "{what}: {}",
        head(&o.stderr)
    );
    match expect {
        Expect::Ok => assert_eq!(o.code, Some(0), "{what}: stderr:\n{}", head(&o.stderr)),
        Expect::Error => {
            assert_eq!(
                o.code,
                Some(1),
                "{what}: should fail; stderr:\n{}",
                head(&o.stderr)
            );
            assert!(
                o.stderr.contains("sdfl::"),
                "{what}: no diagnostic code in stderr:\n{}",
                head(&o.stderr)
            );
        }
    }
}

/// Writes `contents` to a file and runs both `check` and `run` on it.
fn hostile(name: &str, contents: impl AsRef<[u8]>, expect: Expect) -> Vec<Outcome> {
    let dir = case_dir(name);
    let file = dir.join(format!("{name}.sdfl"));
    fs::write(&file, contents).expect("case file is writable");
    let file = file.to_str().expect("temp paths are UTF-8");
    let out = dir.join("out");
    let out = out.to_str().expect("temp paths are UTF-8");
    let mut outcomes = Vec::new();
    for args in [
        vec!["check", file],
        vec!["run", file, "--out", out, "--size", "8x8"],
    ] {
        let o = sdfl(&dir, &args);
        assert_outcome(&format!("{name}: sdfl {}", args[0]), &o, expect);
        outcomes.push(o);
    }
    outcomes
}

/// Deterministic pseudo-random bytes (no dependency on a RNG crate).
fn noise(len: usize, mut seed: u64) -> Vec<u8> {
    (0..len)
        .map(|_| {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 56) as u8
        })
        .collect()
}

/// A render block around `scene` with extra `fields`: a file that would
/// render if the fields were sane.
fn render_with(fields: &str) -> String {
    format!(
        "render r {{\n  scene: sphere(),\n  camera: look_at(eye: [0, 0, -3]),\n  outputs: [image(\"r.png\")],\n{fields}\n}}\n"
    )
}

// ------------------------------------------------------------ garbage in

#[test]
fn binary_garbage() {
    let mut bytes = noise(64 * 1024, 1);
    bytes[100] = 0;
    bytes.extend_from_slice(&[0xff, 0xfe, 0x00, 0xc3, 0x28, 0xe2, 0x82]); // invalid UTF-8
    hostile("binary_garbage", bytes, Expect::Error);
}

#[test]
fn nul_bytes_and_invalid_utf8_in_a_valid_file() {
    let mut bytes = b"let a = 1\n".to_vec();
    bytes.extend_from_slice(b"let b = \"\x00\xff\xfe\"\n// \xc3\x28 in a comment\n");
    bytes.extend_from_slice(b"let c = 2 \x00\n");
    hostile("nul_and_invalid_utf8", bytes, Expect::Error);
}

#[test]
fn empty_file_is_fine() {
    let o = hostile("empty", "", Expect::Ok);
    assert!(o[0].stderr.contains("ok"), "{}", o[0].stderr);
}

#[test]
fn comments_only_file_is_fine() {
    let text = "// nothing here\n/* nor\n   here */\n\n   // indented\n/**/";
    hostile("comments_only", text, Expect::Ok);
}

#[test]
fn whitespace_only_file_is_fine() {
    hostile("whitespace_only", " \n\t\r\n".repeat(10_000), Expect::Ok);
}

#[test]
fn unterminated_string() {
    let o = hostile(
        "unterminated_string",
        "let a = \"abc\nlet b = 2\n",
        Expect::Error,
    );
    assert!(
        o[0].stderr.contains("string is not closed"),
        "{}",
        o[0].stderr
    );
}

#[test]
fn unterminated_block_comment() {
    let o = hostile(
        "unterminated_comment",
        "let a = 1\n/* never closed\nlet b = 2\n",
        Expect::Error,
    );
    assert!(
        o[0].stderr.contains("comment is not closed"),
        "{}",
        o[0].stderr
    );
}

#[test]
fn missing_file_is_an_io_error() {
    let dir = case_dir("missing_file");
    let missing = dir.join("nope.sdfl");
    let o = sdfl(&dir, &["check", missing.to_str().expect("UTF-8 path")]);
    assert_outcome("missing file", &o, Expect::Error);
    assert!(o.stderr.contains("sdfl::io"), "{}", o.stderr);
}

// ------------------------------------------------------------ enormous

#[test]
fn megabyte_line_of_numbers() {
    let items: Vec<String> = (0..200_000).map(|i| i.to_string()).collect();
    let text = format!("let a = [{}]\n", items.join(", "));
    assert!(text.len() > 1_000_000);
    hostile("megabyte_list", text, Expect::Ok);
}

#[test]
fn megabyte_sum_on_one_line() {
    let text = format!("let a = 1{}\n", "+1".repeat(500_000));
    let o = hostile("megabyte_sum", text, Expect::Error);
    assert!(
        o[0].stderr.contains("sdfl::syntax::nesting"),
        "{}",
        head(&o[0].stderr)
    );
    // The megabyte line is not quoted in the report.
    assert!(
        o[0].stderr.len() < 10_000,
        "{} bytes of stderr",
        o[0].stderr.len()
    );
}

#[test]
fn sum_over_half_a_million_lines() {
    let text = format!("let a = 1{}\n", "\n+ 1".repeat(500_000));
    let o = hostile("multiline_sum", text, Expect::Error);
    assert!(
        o[0].stderr.len() < 10_000,
        "{} bytes of stderr",
        o[0].stderr.len()
    );
}

#[test]
fn megabyte_name() {
    let text = format!("let a = {}\n", "x".repeat(1 << 20));
    hostile("megabyte_name", text, Expect::Error);
}

#[test]
fn megabyte_string() {
    let text = format!("let a = \"{}\"\n", "s".repeat(1 << 20));
    hostile("megabyte_string", text, Expect::Ok);
}

#[test]
fn hundred_thousand_errors() {
    // Every line an unknown name: all are found, the report stays bounded.
    let text: String = (0..100_000).map(|i| format!("let a{i} = b{i}\n")).collect();
    let o = hostile("many_errors", text, Expect::Error);
    assert!(
        o[0].stderr.len() < 1_000_000,
        "{} bytes of stderr",
        o[0].stderr.len()
    );
}

// ------------------------------------------------------------ deeply nested

#[test]
fn hundred_thousand_nested_brackets() {
    for (name, open, close) in [
        ("parens", "(", ")"),
        ("lists", "[", "]"),
        ("braces", "{", "}"),
    ] {
        let text = format!(
            "let a = {}1{}\n",
            open.repeat(100_000),
            close.repeat(100_000)
        );
        let o = hostile(&format!("nested_{name}"), text, Expect::Error);
        assert!(
            o[0].stderr.contains("sdfl::syntax::nesting"),
            "{name}: {}",
            head(&o[0].stderr)
        );
    }
}

#[test]
fn hundred_thousand_unclosed_brackets() {
    hostile(
        "unclosed_brackets",
        format!("let a = {}", "[(".repeat(50_000)),
        Expect::Error,
    );
}

/// `let a0 = 1`, then `let a1 = item("a0")`, `let a2 = item("a1")`, ...:
/// a chain of `n` lets, each built from the one before.
fn chained_lets(n: usize, item: impl Fn(&str) -> String) -> String {
    std::iter::once("let a0 = 1\n".to_string())
        .chain((1..n).map(|i| format!("let a{i} = {}\n", item(&format!("a{}", i - 1)))))
        .collect()
}

#[test]
fn hundred_thousand_chained_lets_of_numbers() {
    hostile(
        "chained_numbers",
        chained_lets(100_000, |a| format!("{a} + 1")),
        Expect::Ok,
    );
}

#[test]
fn hundred_thousand_chained_lets_of_shapes() {
    // Shapes nested 100k deep: stopped at 200 levels by the evaluator.
    let text = chained_lets(100_000, |a| format!("union({a}, sphere())")).replacen(
        "let a0 = 1",
        "let a0 = sphere()",
        1,
    );
    let o = hostile("chained_shapes", text, Expect::Error);
    assert!(
        o[0].stderr.contains("sdfl::limit::too-large"),
        "{}",
        head(&o[0].stderr)
    );
}

#[test]
fn hundred_thousand_chained_lets_of_lists() {
    // Values this deep overflowed the stack when dropped, and took
    // quadratic time to check; now the checker stops them.
    let text = chained_lets(100_000, |a| format!("[{a}]"));
    let o = hostile("chained_lists", text, Expect::Error);
    assert!(
        o[0].stderr.contains("sdfl::limit::too-large"),
        "{}",
        head(&o[0].stderr)
    );
}

#[test]
fn hundred_thousand_chained_lets_of_loops() {
    let text = chained_lets(100_000, |a| format!("for k in [1] {{ {a} }}"));
    let o = hostile("chained_loops", text, Expect::Error);
    assert!(
        o[0].stderr.contains("sdfl::limit::too-large"),
        "{}",
        head(&o[0].stderr)
    );
}

#[test]
fn hundred_thousand_chained_lets_of_mixed_lists() {
    hostile(
        "chained_mixed_lists",
        chained_lets(100_000, |a| format!("[{a}, \"x\"]")),
        Expect::Error,
    );
}

#[test]
fn hundred_thousand_chained_params() {
    hostile(
        "chained_params",
        chained_lets(100_000, |a| format!("param([{a}, 0, 0])")),
        Expect::Error,
    );
}

#[test]
fn hundred_thousand_long_chains() {
    let bindings: Vec<String> = (0..100_000).map(|i| format!("i{i} in [1]")).collect();
    let cases = [
        (
            "method_chain",
            format!("let a = sphere(){}\n", ".scale(1)".repeat(100_000)),
        ),
        (
            "member_chain",
            format!("let a = [1, 2, 3]{}\n", ".x".repeat(100_000)),
        ),
        (
            "loop_bindings",
            format!("let a = for {} {{ 1 }}\n", bindings.join(", ")),
        ),
        (
            "nested_loop_sources",
            format!(
                "let a = {}[1]{}\n",
                "for x in ".repeat(100_000),
                " {1}".repeat(100_000)
            ),
        ),
        (
            "minus_signs",
            format!("let a = {}1\n", "- ".repeat(100_000)),
        ),
        ("powers", format!("let a = {}1\n", "2^".repeat(100_000))),
    ];
    for (name, text) in cases {
        let o = hostile(name, text, Expect::Error);
        assert!(
            o[0].stderr.contains("sdfl::syntax::nesting"),
            "{name}: {}",
            head(&o[0].stderr)
        );
    }
}

#[test]
fn nested_loops_in_brackets_parse_in_linear_time() {
    // Each `for` once parsed its source twice: 2^30 steps for this file.
    let mut e = String::from("[1]");
    for i in 0..30 {
        e = format!("[for i{i} in {e} {{ 1 }}]");
    }
    let o = hostile("nested_loop_lists", format!("let a = {e}\n"), Expect::Ok);
    assert!(
        o[0].elapsed < Duration::from_secs(5),
        "took {:?}",
        o[0].elapsed
    );
}

// ------------------------------------------------------------ absurd numbers

#[test]
fn absurd_numbers() {
    let cases = [
        ("too_large_literal", "let a = 1e400\n".to_string(), "sdfl::syntax::number"),
        ("overflowing_product", "let a = 1e308 * 10\n".to_string(), "sdfl::value::arithmetic"),
        ("huge_integer_literal", format!("let a = {}\n", "9".repeat(400)), "sdfl::syntax::number"),
        ("huge_image", render_with("  size: [1e9, 1e9],"), "sdfl::value::range"),
        ("fractional_image", render_with("  size: [8.5, 8],"), "sdfl::value::range"),
        ("negative_image", render_with("  size: [-8, 8],"), "sdfl::value::range"),
        ("huge_iterations", render_with("  iterations: 1e12,"), "sdfl::value::range"),
        ("huge_epsilon_exponent", render_with("  epsilon: 1e-400,"), "sdfl::value::range"),
        ("huge_far", render_with("  far: 1e308,"), ""),
        (
            "huge_views",
            "render r {\n  scene: sphere(),\n  camera: orbit(views: 1e9),\n  outputs: [gif(\"r.gif\")],\n}\n".to_string(),
            "sdfl::value::range",
        ),
        ("huge_radius", render_with("").replace("sphere()", "sphere(1e308)"), ""),
        ("tiny_radius", render_with("").replace("sphere()", "sphere(1e-308)"), ""),
        ("huge_power", "let a = 10 ^ 1000\n".to_string(), "sdfl::value::arithmetic"),
        ("nan", "let a = 0 / 0 * 0\n".to_string(), "sdfl::value::arithmetic"),
    ];
    for (name, text, code) in cases {
        // An empty code: the file is fine or fails, but must not crash.
        if code.is_empty() {
            let dir = case_dir(name);
            let file = dir.join("f.sdfl");
            fs::write(&file, &text).expect("writable");
            let file = file.to_str().expect("UTF-8 path");
            let out = dir.join("out");
            for args in [
                vec!["check", file],
                vec![
                    "run",
                    file,
                    "--out",
                    out.to_str().expect("UTF-8"),
                    "--size",
                    "8x8",
                ],
            ] {
                let o = sdfl(&dir, &args);
                assert!(
                    matches!(o.code, Some(0 | 1)),
                    "{name}: {:?} {}",
                    o.code,
                    head(&o.stderr)
                );
                if o.code == Some(1) {
                    assert!(o.stderr.contains("sdfl::"), "{name}: {}", head(&o.stderr));
                }
            }
            continue;
        }
        let o = hostile(name, text, Expect::Error);
        assert!(
            o[0].stderr.contains(code),
            "{name}: expected {code} in {}",
            head(&o[0].stderr)
        );
    }
}

#[test]
fn billion_iteration_loops() {
    let cases = [
        ("billion_range", "let a = for i in 0..1e9 { sphere() }\n"),
        (
            "billion_inclusive_range",
            "let a = for i in 0..=1e9 { i }\n",
        ),
        ("endless_range", "let a = for i in 0..1e308 { i }\n"),
        (
            "nested_ranges",
            "let a = for i in 0..100000, j in 0..100000 { i * j }\n",
        ),
        (
            "loop_in_loop",
            "let a = for i in 0..1000 { for j in 0..1000 { for k in 0..1000 { k } } }\n",
        ),
    ];
    for (name, text) in cases {
        let o = hostile(name, text, Expect::Error);
        assert!(
            o[0].stderr.contains("sdfl::limit::too-large"),
            "{name}: {}",
            head(&o[0].stderr)
        );
    }
}
