//! Exported names: each field's pieces cover its tensors.

use sdfl_runtime::neural::field::NerfObjective;
use sdfl_runtime::train::export_names::*;
use sdfl_runtime::train::{Objective, TensorSpec};
use sdfl_stdlib::value::{
    DensityActivation, Encoding, Field, Harmonic, HashGridSpec, LastInterval, Nerf, Precision,
    Sampler,
};

fn nerf(position: Encoding, fine: usize) -> Nerf {
    Nerf {
        position,
        direction: Some(Encoding::Harmonic(Harmonic {
            freqs: 2,
            include_input: true,
        })),
        layers: 3,
        width: 8,
        skips: vec![2],
        color_width: 4,
        fine,
        background: sdfl_stdlib::value::Background::Color([1.0; 3]),
        background_at: Default::default(),
        unbounded: None,
        seed: 1,
        density: DensityActivation::Softplus,
        occupancy: None,
        precision: Precision::Fp32,
    }
}

/// Every trainer tensor gets role-named pieces covering it exactly,
/// weights as (out, in); names are unique.
#[test]
fn nerf_pieces_cover_the_tensors() {
    let grid = Encoding::HashGrid(HashGridSpec {
        levels: 4,
        features: 2,
        log2_table: 6,
        min_res: 2,
        max_res: 16,
        min: [-1.0; 3],
        max: [1.0; 3],
    });
    for (enc, fine) in [
        (grid, 0),
        (
            Encoding::Harmonic(Harmonic {
                freqs: 3,
                include_input: true,
            }),
            4,
        ),
    ] {
        let mut spec = nerf(enc, fine);
        if fine > 0 {
            // A learned background's layers are named too (not a flat
            // fallback for the whole model).
            spec.background =
                sdfl_stdlib::value::Background::Learned(sdfl_stdlib::value::LearnedBackground {
                    freqs: 2,
                    width: 5,
                });
        }
        let tensors = NerfObjective::new(
            &spec,
            &Sampler {
                samples: 8,
                near: 1.0,
                far: 4.0,
                jitter: false,
                last_interval: LastInterval::Zero,
            },
        )
        .unwrap()
        .tensors();
        let layout = Layout::of(&Field::Nerf(spec.clone()), &tensors);
        assert_eq!(layout.model["kind"], "nerf", "{:?}", layout.model);
        assert_eq!(layout.params.len(), tensors.len());
        let mut names = Vec::new();
        for (t, pieces) in tensors.iter().zip(&layout.params) {
            let len: usize = pieces.iter().map(|p| p.len().unwrap()).sum();
            assert_eq!(len, t.len, "{}", t.name);
            names.extend(pieces.iter().map(|p| p.name.clone()));
        }
        let n = names.len();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), n);
        let pre = if fine > 0 { "coarse." } else { "" };
        for want in [
            "trunk.0.weight",
            "trunk.2.weight",
            "density.bias",
            "feature.weight",
            "color.0.weight",
            "color.1.bias",
        ] {
            assert!(names.contains(&format!("{pre}{want}")), "{want}: {names:?}");
        }
        let piece = |name: &str| {
            layout
                .params
                .iter()
                .flatten()
                .find(|p| p.name == name)
                .unwrap()
                .clone()
        };
        if fine > 0 {
            // 3 + 3·2·2 encoded direction → 5 → RGB, weights (out, in).
            assert_eq!(piece("background.hidden.weight").shape, vec![5, 15]);
            assert_eq!(piece("background.out.weight").shape, vec![3, 5]);
            assert_eq!(
                layout.model["background_layers"][1]["activation"],
                "sigmoid"
            );
        }
        let enc_w = if fine > 0 { 21 } else { 8 };
        // The skip layer reads the trunk's 8 and the encoding again.
        assert_eq!(
            piece(&format!("{pre}trunk.2.weight")).shape,
            vec![8, 8 + enc_w]
        );
        assert_eq!(
            piece(&format!("{pre}color.0.weight")).shape,
            vec![4, 8 + 15]
        );
        if fine == 0 {
            assert_eq!(piece("hashgrid.level0.table").shape, vec![27, 2]);
            assert_eq!(piece("hashgrid.level3.table").shape, vec![64, 2]);
        } else {
            assert!(names.contains(&"fine.color.1.weight".to_string()));
        }
    }
}

/// A neural SDF's and a neural surface's tensors are named and shaped
/// (not the flat fallback), the MLP's weights (out, in) from the
/// trainer's (in, out), the hash SDF's stored as held; the surface's
/// frame records its background.
#[test]
fn neural_sdf_pieces_cover_the_tensors() {
    use sdfl_runtime::neural::distance::NeuralSdfObjective;
    use sdfl_runtime::neural::hash_sdf::objective::HashSdfObjective;
    use sdfl_runtime::neural::surface::SurfaceObjective;
    use sdfl_stdlib::value::{DensityKind, NeuralSdf, NeuralSurface};
    let sdf = |encoding| NeuralSdf {
        encoding,
        layers: 2,
        width: 8,
        skips: vec![1],
        beta: 20.0,
        radius: 0.5,
        seed: 3,
        level_every: 0,
        eikonal_step: None,
    };
    let harmonic = sdf(Encoding::Harmonic(Harmonic {
        freqs: 2,
        include_input: true,
    }));
    let grid = HashGridSpec {
        levels: 3,
        features: 2,
        log2_table: 6,
        min_res: 2,
        max_res: 8,
        min: [-1.0; 3],
        max: [1.0; 3],
    };
    let hash = NeuralSdf {
        skips: vec![],
        ..sdf(Encoding::HashGrid(grid))
    };
    let surface = NeuralSurface {
        sdf: harmonic.clone(),
        density: DensityKind::VolSdf,
        alpha: 10.0,
        beta: 0.1,
        train_beta: true,
        beta_end: None,
        color_layers: 2,
        color_width: 8,
        color_freqs: 2,
        view_dependent: true,
        background: [0.2, 0.3, 0.4],
        fine: 0,
    };
    let cases: Vec<(Field, Vec<TensorSpec>)> = vec![
        (
            Field::NeuralSdf(harmonic.clone()),
            NeuralSdfObjective::new(&harmonic, &[], 1.0).tensors(),
        ),
        (
            Field::NeuralSdf(hash.clone()),
            HashSdfObjective::new(&hash, &grid, &[], 1.0)
                .unwrap()
                .tensors(),
        ),
        (
            Field::NeuralSurface(surface.clone()),
            SurfaceObjective::new(&surface, &[]).unwrap().tensors(),
        ),
    ];
    for (field, tensors) in cases {
        let layout = Layout::of(&field, &tensors);
        let kind = layout.model["kind"].as_str().unwrap().to_string();
        let piece = |name: &str| {
            layout
                .params
                .iter()
                .flatten()
                .find(|p| p.name == name)
                .unwrap_or_else(|| panic!("{kind}: no {name}"))
                .clone()
        };
        assert_eq!(layout.params.len(), tensors.len());
        match &field {
            Field::NeuralSdf(n) if n == &harmonic => {
                // 3 + 12 encoded; the skip layer reads 8 + 15.
                assert_eq!(piece("hidden.0.weight").shape, vec![8, 15]);
                assert!(piece("hidden.0.weight").transposed);
                assert_eq!(piece("hidden.1.weight").shape, vec![8, 23]);
                assert_eq!(piece("output.weight").shape, vec![1, 8]);
                assert_eq!(layout.model["layers"][1]["inputs"][1], "position");
                assert_eq!(
                    layout.frame.background,
                    sdfl_runtime::train::frame::Behind::None
                );
            }
            Field::NeuralSdf(_) => {
                assert_eq!(piece("hashgrid.level0.table").shape, vec![27, 2]);
                assert_eq!(piece("hidden.0.weight").shape, vec![8, 6]);
                assert!(!piece("hidden.0.weight").transposed);
                assert_eq!(piece("hidden.1.weight").shape, vec![8, 8]);
                assert_eq!(layout.model["sphere"]["radius"], 0.5);
                assert_eq!(layout.model["position_encoding"]["bounds"][1][2], 1.0);
            }
            _ => {
                assert_eq!(kind, "neural_surface");
                assert_eq!(layout.model["sdf"]["prefix"], "sdf.");
                assert_eq!(piece("sdf.hidden.1.weight").shape, vec![8, 23]);
                // Point (15), normal (3), direction (15).
                assert_eq!(piece("color.0.weight").shape, vec![8, 33]);
                assert_eq!(piece("color.out.weight").shape, vec![3, 8]);
                assert_eq!(piece("log_beta").shape, vec![1]);
                assert_eq!(
                    layout.frame.background,
                    sdfl_runtime::train::frame::Behind::Color([0.2, 0.3, 0.4])
                );
            }
        }
    }
}
