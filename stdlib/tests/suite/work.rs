//! Every stage of a statement is in its work estimate: training, occupancy
//! grid refreshes, held-out evaluation, outputs and meshes with their fits.
//! What the budget refuses names the stage that makes it too large.

use sdfl_lang::SourceFile;
use sdfl_stdlib::load;
use sdfl_stdlib::work::{
    max_evaluations_from, max_memory_from, raised_limit, train_work, Stage,
    CONTRACTED_OCCUPIED_SHARE, MAX_EVALUATIONS, MAX_EVALUATIONS_VAR, MAX_MEMORY, MAX_MEMORY_VAR,
    OCCUPIED_SHARE,
};

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
        .stage_lines(None)
        .iter()
        .any(|l| l.starts_with("grid refreshes")));
    // At 1e6 evaluations a second, each stage's time beside it.
    let lines = w.stage_lines(Some(1e6));
    let training = lines.iter().find(|l| l.starts_with("training")).unwrap();
    assert!(
        training.contains("min") || training.contains(" h"),
        "{training}"
    );
}

/// instant-ngp's own settings on a NeRF-synthetic scene (16 levels × 2
/// features, 2^19 rows, 16..2048 cells, a 128³ occupancy grid, 4096 rays ×
/// 256 samples) were refused at 1.2e12 evaluations counting every sample,
/// where the grid skips most of them. Counted with the grid's expected
/// share, they are accepted; the same model without a grid still counts
/// every sample.
#[test]
fn an_occupancy_grid_counts_the_samples_it_keeps() {
    let run = |occupancy: &str| {
        format!(
            r#"
train lego {{
  model: nerf(position: hashgrid(levels: 16, features: 2, log2_table: 19, min_res: 16, max_res: 2048), layers: 1, width: 64, skips: [], density: "exp"{occupancy}),
  data: nerf_synthetic("lego"),
  sampler: stratified(samples: 256, near: 2, far: 6),
  rays: 4096,
  iterations: 3000,
  eval_every: 0,
}}
"#
        )
    };
    let grid = run(", occupancy: occupancy_grid(resolution: 128, min: [-1.5, -1.5, -1.5], max: [1.5, 1.5, 1.5], every: 16)");
    let p = load(&SourceFile::new("lego.sdfl", grid)).unwrap_or_else(|e| panic!("{e:?}"));
    let w = train_work(&p.trains[0], None);
    let t = w.stage(Stage::Training);
    assert!(t.evaluations > MAX_EVALUATIONS, "counted as before: {t:?}");
    assert!(
        (t.expected / t.evaluations - OCCUPIED_SHARE).abs() < 1e-9,
        "{t:?}"
    );
    assert!(w.expected < MAX_EVALUATIONS && w.skips(), "{w:?}");
    // A contracted scene's grid is expected to keep more: its world.
    let contracted =
        run(", occupancy: occupancy_grid(resolution: 128, every: 16), unbounded: contraction()");
    let p = load(&SourceFile::new("lego.sdfl", contracted)).unwrap_or_else(|e| panic!("{e:?}"));
    let t = train_work(&p.trains[0], None).stage(Stage::Training);
    assert!(
        (t.expected / t.evaluations - CONTRACTED_OCCUPIED_SHARE).abs() < 1e-9,
        "{t:?}"
    );
    assert!(
        w.describe().contains("expected with empty space skipped"),
        "{}",
        w.describe()
    );
    // Without a grid every sample is expected: refused, with the override.
    let found = codes_and_messages(&run(""));
    let (_, m) = found
        .iter()
        .find(|(c, _)| c == "sdfl::limit::work")
        .unwrap_or_else(|| panic!("{found:?}"));
    assert!(m.contains("the limit is 1e12"), "{m}");
    let p = load(&SourceFile::new("lego.sdfl", run(""))).err().unwrap();
    let help = p.diags[0].help.clone().unwrap_or_default();
    assert!(help.contains(&format!("{MAX_EVALUATIONS_VAR}=")), "{help}");
}

/// The override is a positive number; anything else is refused, not
/// replaced by the default in silence.
#[test]
fn the_evaluation_limit_is_set_by_its_variable() {
    assert_eq!(max_evaluations_from(None), Ok(MAX_EVALUATIONS));
    assert_eq!(max_evaluations_from(Some("5e12")), Ok(5e12));
    assert_eq!(max_evaluations_from(Some(" 2000000 ")), Ok(2e6));
    for bad in ["", "lots", "-1", "0", "inf", "NaN", "1e400"] {
        let e = max_evaluations_from(Some(bad)).unwrap_err();
        assert!(e.contains(MAX_EVALUATIONS_VAR), "{bad}: {e}");
    }
}

/// A fine step (nerfacc's 0.005 over Lego's [2, 6]: 768 samples a ray)
/// was refused at 8.3 GB, every sample's activations counted at once; a
/// step is fitted in passes of at most `TRAIN_PASS_SAMPLES` samples, so
/// its memory does not grow with the samples a ray.
#[test]
fn a_steps_memory_is_bounded_by_its_pass() {
    let at = |samples: u32| {
        let src = format!(
            r#"
train lego {{
  model: nerf(position: hashgrid(levels: 16, features: 2, log2_table: 19, min_res: 16, max_res: 2048), layers: 1, width: 64, skips: [], density: "exp", occupancy: occupancy_grid(resolution: 128, min: [-1.5, -1.5, -1.5], max: [1.5, 1.5, 1.5], every: 16)),
  data: nerf_synthetic("lego"),
  sampler: stratified(samples: {samples}, near: 2, far: 6),
  rays: 4096,
  iterations: 3000,
  eval_every: 0,
}}
"#
        );
        let p = load(&SourceFile::new("lego.sdfl", src)).unwrap_or_else(|e| panic!("{e:?}"));
        train_work(&p.trains[0], None).memory
    };
    let (coarse, fine) = (at(256), at(1024));
    assert!(fine < 2e9, "{fine}");
    // Only the depths grow (64 bytes a sample), not the network's buffers.
    assert!(
        fine - coarse <= 4096.0 * 768.0 * 64.0 * 1.01,
        "{coarse} {fine}"
    );
}

/// The memory limit's override the same way, in bytes.
#[test]
fn the_memory_limit_is_set_by_its_variable() {
    assert_eq!(max_memory_from(None), Ok(MAX_MEMORY));
    assert_eq!(max_memory_from(Some("16e9")), Ok(16e9));
    for bad in ["", "lots", "-1", "0", "inf", "NaN"] {
        let e = max_memory_from(Some(bad)).unwrap_err();
        assert!(e.contains(MAX_MEMORY_VAR), "{bad}: {e}");
    }
    assert_eq!(raised_limit(8.3e9), 9e9);
}

/// A 512³ grid refreshed every step took 183 s a step while the plan showed
/// 2e8 evaluations: it is refused, naming the grid.
#[test]
fn an_occupancy_grid_refreshed_every_step_is_refused() {
    // After warm-up a refresh evaluates a quarter of the cells.
    let src = nerf(
        ", occupancy: occupancy_grid(resolution: 512, every: 1)",
        "test_views: 1",
        "",
    )
    .replace("iterations: 1000", "iterations: 3000");
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

/// An occupancy grid refreshes every cell during warm-up and a quarter
/// after it, as plan counts: 16 full refreshes in the first 256 steps of
/// 1000 at every 16, then 47 of a quarter each. An unbounded scene's grid
/// first refreshes at step 256 and warms up from there: none before, 16
/// full ones in steps 256 to 511, then 31 of a quarter.
#[test]
fn grid_refreshes_count_a_quarter_of_the_cells_after_warm_up() {
    use sdfl_stdlib::value::{occupancy_refresh_cells, UNBOUNDED_GRID_START};
    assert_eq!(
        occupancy_refresh_cells(100.0, 1000.0, 16, 0),
        (16.0 + 47.0 / 4.0) * 100.0
    );
    assert_eq!(occupancy_refresh_cells(100.0, 200.0, 16, 0), 13.0 * 100.0);
    assert_eq!(occupancy_refresh_cells(100.0, 0.0, 16, 0), 0.0);
    let start = UNBOUNDED_GRID_START;
    assert_eq!(start, 256);
    assert_eq!(
        occupancy_refresh_cells(100.0, 1000.0, 16, start),
        (16.0 + 31.0 / 4.0) * 100.0
    );
    assert_eq!(occupancy_refresh_cells(100.0, 200.0, 16, start), 0.0);
    // Steps 256 to 299: refreshes at 256, 272 and 288, all full.
    assert_eq!(
        occupancy_refresh_cells(100.0, 300.0, 16, start),
        3.0 * 100.0
    );
}

/// `plan`'s output times are the estimate's parts: every output is named
/// (the views of a phase together, with the depth outputs their renders
/// serve), and the parts add up to the outputs and meshes stages.
#[test]
fn output_costs_name_every_output_and_add_up_to_their_stages() {
    use sdfl_stdlib::work::train_output_costs;
    let src = nerf(
        ", occupancy: occupancy_grid(resolution: 32, every: 16)",
        "test_views: 2",
        "  views: orbit(radius: 3, views: 4),\n  after: [gif(\"a.gif\"), image(\"v.png\"), raw_depth(\"d.npy\"), depth_map(\"d.png\"), point_cloud(\"p.ply\", points: 1000), density_mesh(\"m.ply\", level: 5, bounds: [[-1, -1, -1], [1, 1, 1]]), loss_curve(\"l.png\")],",
    );
    let p = load(&SourceFile::new("ok.sdfl", src)).unwrap_or_else(|e| panic!("{e:?}"));
    let job = &p.trains[0];
    let parts = train_output_costs(job, None);
    let what: Vec<&str> = parts.iter().map(|p| p.what.as_str()).collect();
    // A NeRF's depth outputs are served by its views' renders.
    assert_eq!(what, ["a.gif, v.png, d.npy, d.png", "p.ply", "m.ply"]);
    let w = train_work(job, None);
    for stage in [Stage::Outputs, Stage::Meshes] {
        let sum: f64 = parts
            .iter()
            .filter(|p| p.stage == stage)
            .map(|p| p.cost.evaluations * p.share)
            .sum();
        let expected = w.stage(stage).expected;
        assert!(
            (sum - expected).abs() <= 1e-9 * expected && expected > 0.0,
            "{stage:?}: {sum} against {expected}"
        );
    }
}
