//! Unbounded scenes and backgrounds that agree (issue 22): a NeRF's
//! background is its data's unless written, a written one that disagrees
//! is a warning at `check`, a learned background and scene contraction are
//! declared once, and a scene with content far outside the inner box
//! trains with them.

use crate::common::{case_dir, sdfl};
use sdfl_lang::SourceFile;
use sdfl_stdlib::value::{Background, Field, LearnedBackground};

const MISMATCH: &str = "sdfl::warn::background-mismatch";

/// The program and its warnings.
fn load(src: &str) -> (sdfl_stdlib::value::Program, Vec<sdfl_lang::diag::Diag>) {
    let (p, d) = sdfl_stdlib::load_warned(&SourceFile::new("tests/data/unbounded.sdfl", src))
        .unwrap_or_else(|d| panic!("{:#?}", d.diags));
    (p, d.diags)
}

fn model_background(p: &sdfl_stdlib::value::Program) -> Background {
    let Field::Nerf(n) = &*p.trains[0].model else {
        panic!("a NeRF")
    };
    n.background
}

/// `nerf_fast.sdfl`'s model pointed at a NeRF-synthetic set (composited
/// over white): the model takes the data's white, with no warning. (It
/// used to keep black and train to an all-white 13.6 dB.)
#[test]
fn a_nerf_takes_its_nerf_synthetic_datas_white() {
    let (p, warnings) = load(
        r#"train t {
  model: nerf(position: hashgrid(levels: 4, log2_table: 12), layers: 1, width: 16, skips: [], density: "exp"),
  data: nerf_synthetic("nerf_synthetic_tiny"),
  iterations: 1,
}"#,
    );
    assert!(warnings.is_empty(), "{warnings:#?}");
    assert_eq!(model_background(&p), Background::Color([1.0; 3]));
}

/// A traced data set's `background` and a rendered field's own are the
/// data's background too.
#[test]
fn traced_and_rendered_data_give_their_background() {
    let (p, w) = load(
        r#"let cams = orbit(radius: 3, views: 3)
train t {
  model: nerf(layers: 1, width: 8, skips: []),
  data: render_views(sphere(0.5), cameras: cams, size: [8, 8], background: [0.2, 0.3, 0.4]),
  iterations: 1,
}"#,
    );
    assert!(w.is_empty(), "{w:#?}");
    assert_eq!(model_background(&p), Background::Color([0.2, 0.3, 0.4]));
    // Views rendered from a NeRF with a learned background: photographs of
    // a world, so the default is a learned background too.
    let (p, w) = load(
        r#"let cams = orbit(radius: 3, views: 3)
train t {
  model: nerf(layers: 1, width: 8, skips: []),
  data: render_views(nerf(layers: 1, width: 8, skips: [], background: learned_background()), cameras: cams, size: [8, 8]),
  iterations: 1,
}"#,
    );
    assert!(w.is_empty(), "{w:#?}");
    assert_eq!(
        model_background(&p),
        Background::Learned(LearnedBackground {
            freqs: 4,
            width: 32
        })
    );
}

/// The silent disagreement, said: a black model on white data is a
/// warning at the model's `background`, naming the data's colour; the
/// file still checks (exit 0). A learned background and an agreeing colour
/// are quiet.
#[test]
fn a_written_background_the_data_disagrees_with_is_a_warning() {
    let src = r#"train t {
  model: nerf(layers: 1, width: 8, skips: [], background: [0, 0, 0]),
  data: nerf_synthetic("nerf_synthetic_tiny"),
  iterations: 1,
}"#;
    let (p, w) = load(src);
    assert_eq!(w.len(), 1, "{w:#?}");
    assert_eq!(w[0].code, MISMATCH);
    let at = src.find("[0, 0, 0]").unwrap();
    assert_eq!(
        (w[0].span.start, w[0].span.end),
        (at, at + "[0, 0, 0]".len())
    );
    assert!(
        w[0].help.as_deref().unwrap().contains("[1, 1, 1]"),
        "{:?}",
        w[0].help
    );
    // The written colour is kept: the user asked for it.
    assert_eq!(model_background(&p), Background::Color([0.0; 3]));

    for quiet in ["[1, 1, 1]", "learned_background(freqs: 2, width: 8)"] {
        let (_, w) = load(&src.replace("[0, 0, 0]", quiet));
        assert!(w.is_empty(), "{quiet}: {w:#?}");
    }

    // Through the CLI: `check` passes and prints the warning.
    let dir = case_dir("unbounded_mismatch");
    std::fs::write(
        dir.join("m.sdfl"),
        r#"let cams = orbit(radius: 3, views: 3)
train t {
  model: nerf(layers: 1, width: 8, skips: [], background: [0, 0, 0]),
  data: render_views(sphere(0.5), cameras: cams, size: [8, 8], background: [1, 1, 1]),
  iterations: 1,
}"#,
    )
    .unwrap();
    let o = sdfl(&dir, &["check", dir.join("m.sdfl").to_str().unwrap()]);
    assert_eq!(o.code, Some(0), "{}", o.stderr);
    assert!(o.stderr.contains(MISMATCH), "{}", o.stderr);
    assert!(o.stderr.contains("[1, 1, 1]"), "{}", o.stderr);
}

/// A constant colour against photographs of the world (views of a NeRF
/// with a learned background) is said too.
#[test]
fn one_colour_against_the_world_is_a_warning() {
    let (_, w) = load(
        r#"let cams = orbit(radius: 3, views: 3)
train t {
  model: nerf(layers: 1, width: 8, skips: [], background: [1, 1, 1]),
  data: render_views(nerf(layers: 1, width: 8, skips: [], background: learned_background()), cameras: cams, size: [8, 8]),
  iterations: 1,
}"#,
    );
    assert_eq!(w.iter().map(|d| d.code).collect::<Vec<_>>(), [MISMATCH]);
    assert!(w[0].help.as_deref().unwrap().contains("learned_background"));
}

/// One setting for an unbounded scene: a grid given its own box beside a
/// contraction is refused (it would disagree with the inner box); the
/// defaults are taken as the contracted cube.
#[test]
fn unbounded_scenes_refuse_a_second_box() {
    let bad = r#"let cams = orbit(radius: 3, views: 3)
train t {
  model: nerf(layers: 1, width: 8, skips: [], unbounded: contraction(min: [-1, -1, -1], max: [1, 1, 1]),
              position: hashgrid(levels: 2, log2_table: 10, min: [-1, -1, -1], max: [1, 1, 1])),
  data: render_views(sphere(0.5), cameras: cams, size: [8, 8]),
  iterations: 1,
}"#;
    let e = sdfl_stdlib::load(&SourceFile::new("u.sdfl", bad)).unwrap_err();
    assert!(
        e.diags
            .iter()
            .any(|d| d.code == sdfl_lang::diag::codes::VALUE
                && d.message.contains("contracted cube")),
        "{:#?}",
        e.diags
    );
    let good = bad.replace(", min: [-1, -1, -1], max: [1, 1, 1])),", ")),");
    let (p, _) = load(&good);
    let Field::Nerf(n) = &*p.trains[0].model else {
        panic!()
    };
    assert_eq!(n.unbounded.unwrap().contraction().unwrap().min, [-1.0; 3]);
    let (p, _) = load(&good.replace("contraction(min: [-1, -1, -1], max: [1, 1, 1])", "true"));
    let Field::Nerf(n) = &*p.trains[0].model else {
        panic!()
    };
    assert_eq!(n.unbounded.unwrap().contraction().unwrap().max, [1.5; 3]);
}

/// The toy of the report, small: a little object in a world that reaches
/// far outside the inner box (a lit shell at 15, pillars at 6 to 9). With
/// the data's black background and a bounded box the field can only fit
/// each view with fog (held-out ~10 dB); a learned background and scene
/// contraction learn it (the full-size toy: 10.4 → 24.7 → 28.8 dB).
#[test]
fn contraction_and_a_learned_background_learn_a_world_beyond_the_box() {
    const SCENE: &str = r#"
let sun = [light(direction: [0.4, 1, -0.3], color: [1, 0.95, 0.85]), light(direction: [-0.6, -0.3, 0.5], color: [0.35, 0.4, 0.5])]
let object = union(
  paint(sphere(0.45, center: [0, 0.1, 0]), phong(albedo: [0.85, 0.25, 0.2], lights: sun)),
  paint(box(size: [0.5, 0.5, 0.5], center: [0.55, -0.2, 0.3]), phong(albedo: [0.2, 0.5, 0.85], lights: sun)),
)
let world = union(
  paint(onion(sphere(15), thickness: 0.5), phong(albedo: [0.55, 0.7, 0.9], lights: sun)),
  paint(box(size: [1.2, 6, 1.2], center: [7, 0, 0]), phong(albedo: [0.9, 0.8, 0.2], lights: sun)),
  paint(box(size: [1.2, 5, 1.2], center: [-5, 0, 6]), phong(albedo: [0.3, 0.85, 0.35], lights: sun)),
  paint(box(size: [1.5, 4, 1.5], center: [-4, 0, -7]), phong(albedo: [0.8, 0.3, 0.75], lights: sun)),
)
train toy {
  model: nerf(
    position: hashgrid(levels: 6, features: 2, log2_table: 12, min_res: 4, max_res: 48),
    layers: 1, width: 16, skips: [], color_width: 16, density: "exp", view_dependent: false,
    MODEL
  ),
  data: render_views(union(object, world), cameras: sphere_views(views: 80, radius: 3, up: [0, 1, 0], focal: 1.2),
                     size: [24, 24], far: 40, iterations: 256, test_views: 8),
  sampler: stratified(samples: 48, near: 0.5, far: FAR, jitter: true),
  rays: 512,
  optimizer: adam(lr: 1e-2),
  iterations: 180,
}
"#;
    let psnr = |model: &str, far: &str| {
        let src = SCENE.replace("MODEL", model).replace("FAR", far);
        let (p, w) = load(&src);
        assert!(w.is_empty(), "{w:#?}");
        let out = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join("unbounded")
            .join(far);
        let _ = std::fs::remove_dir_all(&out);
        let r = sdfl_runtime::jobs::run_train_job(
            &p.trains[0],
            &out,
            std::path::Path::new("."),
            None,
            sdfl_runtime::jobs::TrainOptions { restart: true },
            &|_| {},
        )
        .unwrap();
        r.held_out.last().expect("held-out views").psnr
    };
    let bounded = psnr("", "6");
    let unbounded = psnr(
        "background: learned_background(freqs: 2, width: 16), unbounded: contraction(),",
        "1000",
    );
    eprintln!("held-out PSNR: bounded {bounded:.2} dB, unbounded {unbounded:.2} dB");
    assert!(
        unbounded > bounded + 8.0 && unbounded > 20.0,
        "held-out PSNR: bounded {bounded} dB, unbounded with a learned background {unbounded} dB"
    );
}

/// A resumed unbounded run (learned background, contracted hash grid and
/// occupancy grid, past the grid's warm-up) is the same run: weights, Adam
/// moments, losses and the grid bit-identical.
#[test]
fn a_resumed_unbounded_run_is_the_same_run() {
    const SRC: &str = r#"
train u {
  model: nerf(
    position: hashgrid(levels: 4, features: 2, log2_table: 10, min_res: 4, max_res: 16),
    layers: 1, width: 8, skips: [], color_width: 8, density: "exp", view_dependent: false,
    background: learned_background(freqs: 1, width: 4), unbounded: contraction(min: [-1, -1, -1], max: [1, 1, 1]),
    occupancy: occupancy_grid(resolution: 8, every: 8),
  ),
  data: render_views(union(sphere(0.5), onion(sphere(8), thickness: 0.5)), cameras: orbit(radius: 3, views: 6), size: [8, 8], far: 20),
  sampler: stratified(samples: 16, near: 0.5, far: 100, jitter: true),
  rays: 32,
  optimizer: adam(lr: 1e-2),
  iterations: STEPS,
  checkpoint: "u.ckpt",
}
"#;
    use sdfl_runtime::train::checkpoint::Checkpoint;
    let run = |steps: usize, out: &std::path::Path| {
        let (p, _) = load(&SRC.replace("STEPS", &steps.to_string()));
        sdfl_runtime::jobs::run_train_job(
            &p.trains[0],
            out,
            std::path::Path::new("."),
            None,
            sdfl_runtime::jobs::TrainOptions { restart: false },
            &|_| {},
        )
        .unwrap()
    };
    let base = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("unbounded-resume");
    let (whole, parts) = (base.join("whole"), base.join("parts"));
    let _ = std::fs::remove_dir_all(&base);
    run(300, &whole);
    run(270, &parts);
    assert_eq!(run(300, &parts).resumed_from, Some(270));
    let a = Checkpoint::read(&whole.join("u.ckpt")).unwrap();
    let b = Checkpoint::read(&parts.join("u.ckpt")).unwrap();
    assert_eq!(a.losses, b.losses);
    assert_eq!(a.state, b.state);
    assert!(a.params.iter().any(|p| p.name.starts_with("background.")));
    for (p, q) in a.params.iter().zip(&b.params) {
        assert!(
            p.values == q.values && p.adam_m == q.adam_m && p.adam_v == q.adam_v,
            "{} differs",
            p.name
        );
    }
    // The grid was refreshed after its warm-up (it starts at zero).
    let ema = &a
        .state
        .iter()
        .find(|s| s.0 == "occupancy.ema")
        .expect("a grid")
        .1;
    assert!(ema.iter().any(|&x| x > 0.0), "never refreshed");
}
