//! Every stage of a statement is in its work estimate: training, occupancy
//! grid refreshes, held-out evaluation, outputs and meshes with their fits.
//! What the budget refuses names the stage that makes it too large.

use sdfl_lang::SourceFile;
use sdfl_stdlib::load;
use sdfl_stdlib::work::{train_work, Stage, MAX_EVALUATIONS};

/// A hash-grid NeRF trained on rendered views, with `model` and `train`
/// settings spliced in.
fn nerf(occupancy: &str, data: &str, fields: &str) -> String {
    format!(
        r#"
let truth = volsdf(sphere(0.6), alpha: 10, beta: 0.05)
train t {{
  model: nerf(position: hashgrid(levels: 8, log2_table: 14), layers: 1, width: 64, skips: [], density: "exp"{occupancy}),
  data: render_views(truth, cameras: orbit(radius: 3, views: 20), size: [32, 32], {data}),
  sampler: stratified(samples: 64, near: 1, far: 5),
  rays: 256,
  iterations: 1000,
{fields}
}}
"#
    )
}

fn codes_and_messages(src: &str) -> Vec<(String, String)> {
    match load(&SourceFile::new("work.sdfl", src)) {
        Ok(_) => Vec::new(),
        Err(d) => d
            .diags
            .iter()
            .map(|d| (d.code.to_string(), d.message.clone()))
            .collect(),
    }
}

#[test]
fn a_plain_run_has_its_stages_and_fits_the_budget() {
    let src = nerf(
        ", occupancy: occupancy_grid(resolution: 32, every: 16)",
        "test_views: 2",
        "  eval_every: 250,\n  views: orbit(radius: 3, views: 4),\n  after: [gif(\"a.gif\"), psnr_curve(\"p.png\")],",
    );
    let p = load(&SourceFile::new("ok.sdfl", src)).unwrap_or_else(|e| panic!("{e:?}"));
    let w = train_work(&p.trains[0], None);
    for stage in [
        Stage::Data,
        Stage::Training,
        Stage::GridRefresh,
        Stage::HeldOut,
        Stage::Outputs,
    ] {
        assert!(w.stage(stage).evaluations > 0.0, "{stage:?}: {w:?}");
    }
    // Stages are stored by their discriminant, in the order of `ALL`.
    for (i, s) in Stage::ALL.iter().enumerate() {
        assert_eq!(*s as usize, i, "{s:?}");
    }
    let sum: f64 = w.stages().map(|(_, c)| c.evaluations).sum();
    assert_eq!(sum, w.evaluations);
    assert_eq!(w.largest(), Stage::Training);
    // 32³ cells, 1000 / 16 refreshes.
    let refresh = w.stage(Stage::GridRefresh).evaluations;
    assert!(refresh >= 32f64.powi(3) * 63.0, "{refresh}");
    // Five evaluations (steps 250 to 1000, and the end) of 2 views of 32².
    let held_out = w.stage(Stage::HeldOut).evaluations;
    assert!(held_out >= 5.0 * 2.0 * 1024.0 * 64.0, "{held_out}");
    // The grid's copies are held throughout.
    assert!(w.resident >= 32f64.powi(3) * 4.0 * 2.0, "{}", w.resident);
    assert!(w
        .stage_lines()
        .iter()
        .any(|l| l.starts_with("grid refreshes")));
}

/// A 512³ grid refreshed every step took 183 s a step while the plan showed
/// 2e8 evaluations: it is refused, naming the grid.
#[test]
fn an_occupancy_grid_refreshed_every_step_is_refused() {
    let src = nerf(
        ", occupancy: occupancy_grid(resolution: 512, every: 1)",
        "test_views: 1",
        "",
    );
    let found = codes_and_messages(&src);
    assert!(
        found
            .iter()
            .any(|(c, m)| c == "sdfl::limit::work" && m.contains("grid refreshes")),
        "{found:?}"
    );
    // Every 64 steps, the same grid is fine.
    let src = nerf(
        ", occupancy: occupancy_grid(resolution: 512, every: 64)",
        "test_views: 1",
        "",
    );
    let p = load(&SourceFile::new("ok.sdfl", src)).unwrap_or_else(|e| panic!("{e:?}"));
    let w = train_work(&p.trains[0], None);
    assert!(w.evaluations < MAX_EVALUATIONS, "{w:?}");
    // Its cells are held several times over: half a gigabyte each copy.
    assert!(w.memory > 2e9, "{w:?}");
}

/// 999 held-out views scored every step at 1024 samples ran for hours on a
/// plan of 6e8 evaluations: refused, naming the held-out evaluation.
#[test]
fn held_out_views_scored_every_step_are_refused() {
    let src = r#"
let truth = volsdf(sphere(0.6), alpha: 10, beta: 0.05)
train t {
  model: nerf(layers: 2, width: 64, skips: []),
  data: render_views(truth, cameras: orbit(radius: 3, views: 1000), size: [32, 32], test_views: 999),
  sampler: stratified(samples: 1024, near: 1, far: 5),
  rays: 64,
  iterations: 1000,
  eval_every: 1,
}
"#;
    let found = codes_and_messages(src);
    assert!(
        found
            .iter()
            .any(|(c, m)| c == "sdfl::limit::work" && m.contains("held-out evaluation")),
        "{found:?}"
    );
}

/// A mesh of a field fitted to data sdfl rendered from a shape is measured
/// against that shape's surface, meshed finely: that work is in the plan.
#[test]
fn the_true_surface_and_the_fit_are_counted() {
    let with_mesh = |after: &str| {
        let src = format!(
            r#"
let truth = volsdf(sphere(0.6), alpha: 10, beta: 0.05)
train t {{
  model: volsdf(neural_sdf(layers: 2, width: 32, skips: [])),
  data: render_views(truth, cameras: orbit(radius: 3, views: 8), size: [16, 16]),
  sampler: stratified(samples: 32, near: 1, far: 5),
  rays: 64,
  iterations: 10,
  after: [{after}],
}}
"#
        );
        let p = load(&SourceFile::new("m.sdfl", src)).unwrap_or_else(|e| panic!("{e:?}"));
        train_work(&p.trains[0], None).stage(Stage::Meshes)
    };
    let image_only = with_mesh("image(\"i.png\")");
    let meshed = with_mesh("mesh(\"m.ply\", resolution: 16)");
    assert_eq!(image_only.evaluations, 0.0);
    // More than the 16³ grid itself: the truth at 192³ and the Chamfer.
    assert!(meshed.evaluations > 197f64.powi(3), "{meshed:?}");
    assert!(meshed.memory > 1e6 * 12.0, "{meshed:?}");
}

/// A user function's instructions are in the estimate: a render of a
/// function of about 2 000 instructions counts about 170 times the
/// evaluations of one of a few (each step near it pays them all).
#[test]
fn a_user_functions_size_is_in_its_renders_estimate() {
    let render = |body: &str| {
        let src = format!(
            "fn f(p) {{ {body} }}\nlet s = sdf(f, bound: 1)\nrender r {{ scene: s, camera: look_at(eye: [0, 0, -3]), size: [32, 32], outputs: [image(\"r.png\")] }}\n"
        );
        let p = load(&SourceFile::new("user.sdfl", src)).unwrap_or_else(|e| panic!("{e:?}"));
        sdfl_stdlib::work::render_work(&p.renders[0], None).evaluations
    };
    let small = render("length(p) - 0.5");
    // Four parts of 100 terms (an expression holds at most 512 operators),
    // each term about five instructions.
    let parts: Vec<String> = (0..4)
        .map(|i| {
            let terms: Vec<String> = (1..=100)
                .map(|k| format!("0.0001 * sin(p.x * {}.5)", 100 * i + k))
                .collect();
            format!("let t{i} = {};", terms.join(" + "))
        })
        .collect();
    let large = render(&format!(
        "{} length(p) - 0.5 + t0 + t1 + t2 + t3",
        parts.join(" ")
    ));
    let ratio = large / small;
    assert!(
        (120.0..=200.0).contains(&ratio),
        "{large} / {small} = {ratio}"
    );
}
