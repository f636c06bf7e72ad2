//! Every model kind answers the plan and the cost model through one
//! trait (`sdfl_stdlib::model::Model`): iterated here over the examples
//! that train each kind, so a kind whose answers are missing or absurd
//! fails by name.

use sdfl_lang::SourceFile;
use sdfl_stdlib::value::{Field, TrainJob};
use sdfl_stdlib::work::{train_work, Stage};

/// The examples, one a model kind.
const EXAMPLES: [&str; 4] = [
    "train_box.sdfl",
    "nerf_fast.sdfl",
    "neural_sdf_fast.sdfl",
    "neus_fast.sdfl",
];

/// Which kind a field is, as an index: exhaustive, so a new kind must be
/// given an example here.
fn kind(f: &Field) -> usize {
    match f {
        Field::Sdf(_) => 0,
        Field::Nerf(_) => 1,
        Field::NeuralSdf(_) => 2,
        Field::NeuralSurface(_) => 3,
    }
}

fn trains() -> Vec<(String, TrainJob)> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    EXAMPLES
        .iter()
        .flat_map(|name| {
            let path = dir.join(name);
            let src = std::fs::read_to_string(&path).unwrap();
            let p = sdfl_stdlib::load(&SourceFile::new(path.to_str().unwrap(), src))
                .unwrap_or_else(|e| panic!("{name}: {e:?}"));
            p.trains.into_iter().map(|t| (name.to_string(), t))
        })
        .collect()
}

#[test]
fn every_model_kind_has_an_example_and_sane_costs() {
    let mut seen = [false; 4];
    for (name, job) in trains() {
        seen[kind(&job.model)] = true;
        let m = job.model.model();
        let describe = m.describe(&|p| format!("{p:?}"));
        assert!(describe.len() > 20, "{name}: {describe}");
        let samples = job.sampler.samples as f64;
        for (what, v) in [
            ("train_ray", m.train_ray(samples, 3)),
            ("render_pixel", m.render_pixel(samples)),
            ("geometry_point", m.geometry_point()),
            ("export_sample", m.export_sample()),
            ("volume_sample", m.volume_sample()),
            ("training_pace", m.training_pace()),
            ("trained_numbers", m.trained_numbers(3)),
        ] {
            assert!(v.is_finite() && v > 0.0, "{name}: {what} = {v}");
        }
        let share = m.expected_share();
        assert!(share > 0.0 && share <= 1.0, "{name}: share {share}");
        // A grid kept is refreshed, and one refreshed is kept.
        let refresh = m.grid_refresh(1000.0);
        assert_eq!(
            m.grid_cells() > 0.0,
            refresh.evaluations > 0.0,
            "{name}: {} cells, {refresh:?}",
            m.grid_cells()
        );
        let w = train_work(&job, None);
        let training = w.stage(Stage::Training);
        assert!(
            training.evaluations > 0.0 && training.memory > 0.0,
            "{name}: {w:?}"
        );
        assert!(
            w.memory.is_finite() && w.memory > training.memory,
            "{name}: {w:?}"
        );
    }
    assert_eq!(seen, [true; 4], "a model kind without an example: {seen:?}");
}

/// Each kind's plan line says what it is; a NeRF's carries the layer
/// precision the runtime reports for this machine.
#[test]
fn the_description_names_what_the_kind_computes() {
    for (name, job) in trains() {
        let d = job.model.model().describe(&|_| "PRECISION".into());
        let expected = match &*job.model {
            Field::Sdf(_) => "primitives",
            Field::Nerf(_) => "PRECISION",
            Field::NeuralSdf(_) => "neural SDF:",
            Field::NeuralSurface(_) => "neural SDF as a",
        };
        assert!(d.contains(expected), "{name}: {d}");
    }
}
