//! The harmonic encoding: the reference layout, its backward, huge
//! inputs.

use sdfl_runtime::neural::encoding::*;

#[test]
fn layout_matches_the_reference_embedding() {
    let h = Harmonic {
        dims: 3,
        freqs: 6,
        include_input: true,
    };
    assert_eq!(h.width(), 39);
    let x = [0.3f32, -1.2, 2.0];
    let mut row = vec![0.0; 39];
    h.encode_one(&x, &mut row);
    // Reference (f64): embed = x[..., None] * 2^k flattened, then sin, cos, x.
    let mut want = Vec::new();
    let embed: Vec<f64> = x
        .iter()
        .flat_map(|&v| (0..6).map(move |k| v as f64 * 2f64.powi(k)))
        .collect();
    want.extend(embed.iter().map(|e| e.sin()));
    want.extend(embed.iter().map(|e| e.cos()));
    want.extend(x.iter().map(|&v| v as f64));
    for (a, b) in row.iter().zip(&want) {
        assert!((*a as f64 - b).abs() < 1e-5, "{a} vs {b}");
    }
}

#[test]
fn backward_matches_finite_differences() {
    let h = Harmonic {
        dims: 3,
        freqs: 4,
        include_input: true,
    };
    let x = [0.7f32, -0.4, 1.3];
    let g: Vec<f32> = (0..h.width())
        .map(|i| ((i * 7 % 11) as f32 - 5.0) / 5.0)
        .collect();
    let loss = |x: &[f32]| -> f64 {
        let mut row = vec![0.0; h.width()];
        h.encode_one(x, &mut row);
        row.iter().zip(&g).map(|(a, b)| *a as f64 * *b as f64).sum()
    };
    let mut dx = [0.0f32; 3];
    h.backward(&x, &g, &mut dx);
    for i in 0..3 {
        let e = 1e-3;
        let (mut up, mut down) = (x, x);
        up[i] += e;
        down[i] -= e;
        let fd = (loss(&up) - loss(&down)) / (2.0 * e as f64);
        assert!(
            (dx[i] as f64 - fd).abs() < 1e-2 * (1.0 + fd.abs()),
            "{i}: {} vs {fd}",
            dx[i]
        );
    }
}

#[test]
fn huge_inputs_stay_finite() {
    let h = Harmonic {
        dims: 3,
        freqs: 10,
        include_input: false,
    };
    let x = [1e30f32, -1e30, 0.0];
    let mut row = vec![0.0; h.width()];
    h.encode_one(&x, &mut row);
    assert!(row.iter().all(|v| v.is_finite() && v.abs() <= 1.0));
}
