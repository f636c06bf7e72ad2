//! Hostile and newcomer input for the language front end and evaluation
//! (issue 21): memory proportional to the source, every error of a file in
//! one run, units, and errors inside `fn`s reported once.

use crate::common::*;

use std::fs;
use std::path::Path;
use std::process::{Command, Stdio};

/// Runs `sdfl check FILE` and returns its stderr and the peak resident
/// memory of the process in bytes (`wait4`'s rusage of that one child: other
/// tests' children do not count).
#[allow(
    clippy::zombie_processes,
    reason = "reaped by wait4 below, which also reads its peak memory"
)]
fn check_peak_memory(file: &Path) -> (Option<i32>, String, u64) {
    let err_path = file.with_extension("stderr");
    let child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .arg("check")
        .arg(file)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(fs::File::create(&err_path).expect("stderr file"))
        .spawn()
        .expect("the sdfl binary starts");
    let mut status = 0;
    // SAFETY: a zeroed rusage is a valid value; wait4 fills it for the
    // child we spawned (and reaps it: `child` is not waited on again).
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = unsafe { libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as libc::pid_t, "wait4 failed");
    let code = libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status));
    let stderr = fs::read_to_string(&err_path).unwrap_or_default();
    // Linux reports ru_maxrss in KiB.
    (code, stderr, usage.ru_maxrss as u64 * 1024)
}

/// A 16 MB file of a million plain `let`s is checked in memory proportional
/// to its size. (Parsing the whole file at once kept pest's token queue for
/// all of it: 50 bytes per source byte, 5.1 GB for 59 MB. Items are parsed
/// one at a time now; what remains is the tree and the name tables, about
/// 29 bytes per byte here.)
#[test]
fn a_large_file_of_lets_is_checked_in_memory_proportional_to_it() {
    const BYTES_PER_SOURCE_BYTE: u64 = 40;
    const BASELINE: u64 = 32 << 20;
    let dir = case_dir("lang_many_lets");
    let file = dir.join("lets.sdfl");
    let mut text = String::with_capacity(17 << 20);
    let mut i = 0;
    while text.len() < 16 << 20 {
        use std::fmt::Write;
        let _ = writeln!(text, "let a{i} = {}", i % 10);
        i += 1;
    }
    fs::write(&file, &text).expect("case file is writable");
    let (code, stderr, peak) = check_peak_memory(&file);
    assert_eq!(code, Some(0), "{}", head(&stderr));
    let bound = BYTES_PER_SOURCE_BYTE * text.len() as u64 + BASELINE;
    assert!(
        peak <= bound,
        "checking {} bytes of source peaked at {} MB, over {} MB ({BYTES_PER_SOURCE_BYTE} bytes per byte)",
        text.len(),
        peak >> 20,
        bound >> 20
    );
}

/// Writes `text` and runs `sdfl check` on it.
fn check_text(name: &str, text: &str) -> Outcome {
    let dir = case_dir(name);
    let file = dir.join(format!("{name}.sdfl"));
    fs::write(&file, text).expect("case file is writable");
    sdfl(
        &dir,
        &["check", file.to_str().expect("temp paths are UTF-8")],
    )
}

/// How many times `needle` occurs in the report.
fn count(o: &Outcome, needle: &str) -> usize {
    o.stderr.matches(needle).count()
}

/// Every error of a file in one `check` run: lets that fail (and what uses
/// them stays quiet), and every field of a statement, not only the first
/// that fails; output collisions are found in a statement whose other
/// fields fail too.
#[test]
fn one_check_reports_every_error_of_every_statement() {
    let text = r#"let ball = sphere(radius: -1)
let cam = look_at(eye: [0, 0, 0], at: [0, 0, 0])
let good = box(size: 1)
render scene {
  scene: good,
  camera: look_at(eye: [0, 0, -3]),
  samples_per_pixel: 3,
  iterations: 0.5,
  epsilon: 0,
  near: 3,
  far: 1,
  outputs: [image("a.png"), image("a.png")],
}
render other {
  scene: ball,
  camera: cam,
  background: [2, 0, 0],
  outputs: [image("b.png")],
}
render volume {
  scene: sdf_volume(good),
  camera: look_at(eye: [0, 0, -3]),
  samples_per_pixel: 4,
  size: [0, 8],
  outputs: [image("v.png"), image("v.png")],
}
train fit {
  model: sdf_volume(sphere(param(0.5))),
  data: render_views(sdf_volume(good), cameras: [look_at(eye: [0, 0, -3])]),
  rays: 0,
  iterations: 1.5,
  backend: "gpu",
  seed: -1,
  after: [loss_curve("l.png"), loss_curve("l.png")],
}
"#;
    let o = check_text("lang_every_error", text);
    assert_outcome("every error", &o, Expect::Error);
    for (what, needle) in [
        ("the bad radius", "`radius` must be positive"),
        (
            "the camera without orientation",
            "no well-defined orientation",
        ),
        ("the non-square samples", "must be a square"),
        (
            "the fractional iterations",
            "`iterations` must be a whole number",
        ),
        ("the zero epsilon", "`epsilon` must be positive"),
        ("near beyond far", "`near`"),
        ("the colour", "colour components must be in 0..1"),
        (
            "the volume's samples_per_pixel",
            "is an effect of sphere-traced shapes",
        ),
        ("the volume's size", "`size`"),
        ("the rays", "`rays` must be a whole number"),
        ("the backend", "unknown backend `gpu`"),
        ("the seed", "`seed` must be a whole number"),
    ] {
        assert!(
            o.stderr.contains(needle),
            "{what} ({needle}) is not reported:\n{}",
            head(&o.stderr)
        );
    }
    assert_eq!(count(&o, "sdfl::path::collision"), 3, "{}", o.stderr);
    // The render of the failed `ball` adds nothing about its scene.
    assert_eq!(count(&o, "`radius` must be positive"), 1, "{}", o.stderr);
}

/// An error inside a `fn` is reported once, at the definition, with every
/// call that met it as a label (it was printed once per call, without the
/// call). A call with other values that fails otherwise is its own error.
#[test]
fn an_error_inside_a_fn_is_reported_once_with_its_calls() {
    let text = "fn ball(r) {
  sphere(radius: r - 2)
}
fn pair(r) {
  union(ball(r), ball(r))
}
let a = ball(1)
let b = ball(1)
let c = ball(0.5)
let d = pair(1)
let e = for i in 0..3 { sphere(radius: -1) }
";
    let o = check_text("lang_fn_error_once", text);
    assert_outcome("fn error once", &o, Expect::Error);
    assert_eq!(count(&o, "got -1\n"), 2, "{}", o.stderr);
    assert_eq!(count(&o, "got -1.5"), 1, "{}", o.stderr);
    assert!(o.stderr.contains("3 errors in"), "{}", o.stderr);
    // Every call site is labelled: lines 7, 8 and 10 (and 5, inside `pair`).
    let first = o
        .stderr
        .split("sdfl::value::range")
        .nth(1)
        .expect("a first report");
    for line in [" 5 │", " 7 │", " 8 │", "10 │"] {
        assert!(first.contains(line), "line{line} is not shown:\n{first}");
    }
    assert!(first.contains("`ball` called here"), "{first}");
    assert!(first.contains("`pair` called here"), "{first}");
}

/// A unit written apart from its number, or one sdfl does not have, is
/// named as such with what to write (the help said to separate arguments
/// with `,`).
#[test]
fn units_apart_from_their_number_or_unknown_say_what_to_write() {
    let text = "let a = rotate(box(size: 1), 30 deg)
let b = rotate(box(size: 1), 45degrees)
let c = 30 deg
let d = rotate(box(size: 1), 0.5 rad)
render r {
  scene: a,
  camera: look_at(eye: [0, 0, -3], focal: 50mm),
  outputs: [image(\"r.png\")],
}
let e = translate(box(size: 1), [2 cm, 0, 0])
";
    let o = check_text("lang_units", text);
    assert_outcome("units", &o, Expect::Error);
    assert_eq!(count(&o, "sdfl::syntax::unit"), 6, "{}", o.stderr);
    assert!(!o.stderr.contains("separate arguments"), "{}", o.stderr);
    for needle in [
        "write `30deg`",
        "write `45deg`",
        "write `0.5`",
        "`focal: 2.78`",
        "write `2`",
    ] {
        assert!(o.stderr.contains(needle), "no {needle}:\n{}", o.stderr);
    }
    // Line 3's `deg` is reported there, not as a block on line 4.
    assert!(o.stderr.contains("lang_units.sdfl:3:12]"), "{}", o.stderr);
}

/// Numbers that are likely in the wrong unit run, with a warning: a whole
/// angle of 7 or more (degrees written as radians) and a focal length far
/// beyond NDC's (a lens's millimetres).
#[test]
fn angles_in_degrees_and_focal_lengths_in_millimetres_are_warned_about() {
    let render = |camera: &str, angle: &str| {
        format!(
            "render r {{
  scene: rotate(box(size: 1), {angle}),
  camera: {camera},
  outputs: [image(\"r.png\")],
}}
"
        )
    };
    let warned = [
        ("look_at(eye: [0, 0, -3])", "45", "sdfl::warn::degrees"),
        ("look_at(eye: [0, 0, -3])", "-90", "sdfl::warn::degrees"),
        (
            "look_at(eye: [0, 0, -3], focal: 50)",
            "0.5",
            "sdfl::warn::focal",
        ),
        ("orbit(focal: 35, views: 2)", "1", "sdfl::warn::focal"),
    ];
    for (i, (camera, angle, code)) in warned.into_iter().enumerate() {
        let o = check_text(&format!("lang_unit_warning_{i}"), &render(camera, angle));
        assert_outcome(code, &o, Expect::Ok);
        assert_eq!(count(&o, code), 1, "{camera} {angle}: {}", o.stderr);
    }
    let o = check_text(
        "lang_unit_warning_help",
        &render("look_at(eye: [0, 0, -3], focal: 50)", "45"),
    );
    assert!(o.stderr.contains("`45deg`"), "{}", o.stderr);
    assert!(o.stderr.contains("NDC units"), "{}", o.stderr);
    assert!(o.stderr.contains("f/18"), "{}", o.stderr);
    for (i, (camera, angle)) in [
        ("look_at(eye: [0, 0, -3], focal: 2.5)", "3"),
        ("look_at(eye: [0, 0, -3], focal: 20)", "45deg"),
        ("look_at(eye: [0, 0, -3])", "6"),
        ("look_at(eye: [0, 0, -3])", "7.5"),
    ]
    .into_iter()
    .enumerate()
    {
        let o = check_text(&format!("lang_unit_quiet_{i}"), &render(camera, angle));
        assert_outcome("no warning", &o, Expect::Ok);
        assert!(
            !o.stderr.contains("sdfl::warn"),
            "{camera} {angle}: {}",
            o.stderr
        );
    }
}

/// One statement of 8 MB (a list literal) is refused as too large to
/// parse, in bounded memory: parsing it whole took 1.3 GB (pest's tree of
/// one statement is held while it is built).
#[test]
fn one_huge_statement_is_refused_in_bounded_memory() {
    const BOUND: u64 = 400 << 20;
    let dir = case_dir("lang_huge_statement");
    let file = dir.join("list.sdfl");
    let items = vec!["1"; 8 << 20 >> 1];
    fs::write(&file, format!("let a = [{}]\n", items.join(","))).expect("case file is writable");
    let (code, stderr, peak) = check_peak_memory(&file);
    assert_eq!(code, Some(1), "{}", head(&stderr));
    assert!(
        stderr.contains("sdfl::limit::too-large"),
        "{}",
        head(&stderr)
    );
    assert!(
        stderr.contains("statement too large to parse"),
        "{}",
        head(&stderr)
    );
    assert!(
        peak <= BOUND,
        "peaked at {} MB, over {} MB",
        peak >> 20,
        BOUND >> 20
    );
}

/// Name and type errors do not hide value errors elsewhere: statements the
/// checker found wrong are left out of evaluation (what uses them stays
/// quiet), the others are evaluated and their errors reported too.
#[test]
fn check_errors_and_value_errors_are_reported_together() {
    let text = r#"let a = sphere(radius: "big")
let b = box(size: -1)
let c = sphere(radius: a)
fn f(r) { sphere(radius: r, colour: 1) }
let d = f(1)
render r {
  scene: torus(major: -2),
  camera: look_at(eye: [0, 0, -3]),
  iterations: 0.5,
  outputs: [image("r.png")],
}
render s {
  scene: b,
  camera: look_at(eye: [0, 0, -3]),
  outputs: [image("s.png")],
  colour: 1,
}
"#;
    let o = check_text("lang_check_and_values", text);
    assert_outcome("check and values", &o, Expect::Error);
    for needle in [
        "sdfl::type::mismatch",
        "`size` must be positive",
        "sdfl::arg::unknown",
        "`major` must be positive",
        "`iterations` must be a whole number",
        "sdfl::field::unknown",
    ] {
        assert!(o.stderr.contains(needle), "no {needle}:\n{}", o.stderr);
    }
    // Four from the checker (`c` passes a shape as a radius), three values.
    assert!(o.stderr.contains("7 errors in"), "{}", o.stderr);
}

/// Past six labelled calls, the others are counted in the help.
#[test]
fn calls_past_the_labelled_ones_are_counted() {
    let mut text = String::from("fn ball(r) {\n  sphere(radius: r - 2)\n}\n");
    for i in 0..9 {
        text.push_str(&format!("let a{i} = ball(1)\n"));
    }
    let o = check_text("lang_fn_many_calls", &text);
    assert_outcome("many calls", &o, Expect::Error);
    assert_eq!(count(&o, "`ball` called here"), 6, "{}", o.stderr);
    assert!(o.stderr.contains("(and 3 more calls)"), "{}", o.stderr);
    assert!(o.stderr.contains("1 error in"), "{}", o.stderr);
}
