//! Volume compositing: f32 weights against f64, the assignment's part 0,
//! hard cases.

use sdfl_runtime::volume::composite::*;

/// Straightforward f64 reference: products of per-interval exponentials.
fn reference_weights(sigma: &[f64], delta: &[f64]) -> Vec<f64> {
    let mut out = Vec::new();
    for k in 0..sigma.len() {
        let t: f64 = (0..k).map(|j| (-sigma[j] * delta[j]).exp()).product();
        out.push(t * (1.0 - (-sigma[k] * delta[k]).exp()));
    }
    out
}

fn linspace(n: usize, a: f64, b: f64) -> Vec<f64> {
    (0..n)
        .map(|k| a + (b - a) * k as f64 / (n - 1) as f64)
        .collect()
}

fn profile(n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| {
            let x = k as f64 / n as f64;
            3.0 * (-(x - 0.5).powi(2) * 40.0).exp() + 0.1 * x
        })
        .collect()
}

#[test]
fn f32_weights_match_f64_reference() {
    let n = 64;
    let t = linspace(n, 0.0, 5.0);
    let mut d = vec![0.0; n];
    intervals(&t, &mut d).unwrap();
    let sigma = profile(n);
    let r = reference_weights(&sigma, &d);
    let s32: Vec<f32> = sigma.iter().map(|&v| v as f32).collect();
    let d32: Vec<f32> = d.iter().map(|&v| v as f32).collect();
    let mut w = vec![0f32; n];
    weights_from_density(&s32, &d32, &mut w).unwrap();
    for k in 0..n {
        assert!(
            (w[k] as f64 - r[k]).abs() < 1e-6,
            "{k}: {} vs {}",
            w[k],
            r[k]
        );
    }
    // The opacity and log-keep forms give the same weights.
    let o: Vec<f32> = (0..n)
        .map(|k| (1.0 - (-sigma[k] * d[k]).exp()) as f32)
        .collect();
    let lk: Vec<f32> = (0..n).map(|k| (-sigma[k] * d[k]) as f32).collect();
    let mut w2 = vec![0f32; n];
    let mut w3 = vec![0f32; n];
    weights_from_opacity(&o, &mut w2).unwrap();
    weights_from_log_keep(&lk, &o, &mut w3).unwrap();
    for k in 0..n {
        assert!((w2[k] as f64 - r[k]).abs() < 1e-6);
        assert!((w3[k] as f64 - r[k]).abs() < 1e-6);
    }
    // Aggregation against a direct f64 sum.
    let cols: Vec<[f64; 3]> = (0..n).map(|k| [k as f64 / n as f64, 0.5, 0.2]).collect();
    let cols32: Vec<[f32; 3]> = cols.iter().map(|c| c.map(|v| v as f32)).collect();
    let t32: Vec<f32> = t.iter().map(|&v| v as f32).collect();
    let a = aggregate(&w, &cols32, &t32).unwrap();
    let depth: f64 = (0..n).map(|k| r[k] * t[k]).sum();
    let red: f64 = (0..n).map(|k| r[k] * cols[k][0]).sum();
    assert!((a.depth as f64 - depth).abs() < 1e-5);
    assert!((a.colour[0] as f64 - red).abs() < 1e-6);
    assert!((a.opacity as f64 - r.iter().sum::<f64>()).abs() < 1e-6);
}

#[test]
fn assignment_part0_transmittances() {
    // x–y1 empty (length arbitrary), y1–y2 2 m σ=1, y2–y3 1 m σ=0.5, y3–y4 3 m σ=10.
    let sigma = [0.0f32, 1.0, 0.5, 10.0];
    let delta = [1.7f32, 2.0, 1.0, 3.0];
    let cases: [(&[f32], &[f32], f64); 4] = [
        (&sigma[1..2], &delta[1..2], (-2.0f64).exp()),
        (&sigma[2..4], &delta[2..4], (-30.5f64).exp()),
        (&sigma[..], &delta[..], (-32.5f64).exp()),
        (&sigma[..3], &delta[..3], (-2.5f64).exp()),
    ];
    for (s, d, want) in cases {
        let got = transmittance(s, d).unwrap() as f64;
        assert!(((got - want) / want).abs() < 1e-3, "{got} vs {want}");
        // The compositing code agrees: its final transmittance.
        let mut w = vec![0f32; s.len()];
        let tf = weights_from_density(s, d, &mut w).unwrap() as f64;
        assert!(((tf - want) / want).abs() < 1e-3);
    }
    assert!((transmittance(&sigma[1..2], &delta[1..2]).unwrap() - 0.1353).abs() < 1e-4);
}

#[test]
fn hard_cases_stay_finite_and_normalised() {
    // Huge σΔ, infinite σ, the 1e10 last interval, zero intervals.
    let sigma = [0.0f32, 1e10, f32::INFINITY, 3.0, f32::INFINITY, 5.0];
    let delta = [0.1f32, 0.1, 0.1, 0.0, 0.0, 1e10];
    let mut w = [0f32; 6];
    let t = weights_from_density(&sigma, &delta, &mut w).unwrap();
    assert!(w.iter().all(|v| v.is_finite() && *v >= 0.0) && t.is_finite());
    assert!(w.iter().sum::<f32>() <= 1.0 + 1e-6);
    assert_eq!(w[1], 1.0);
    // Opacity exactly one, first and in the middle.
    for o in [[1.0f32, 0.3, 1.0, 0.2], [0.2, 1.0, 1.0, 0.9], [1.0; 4]] {
        let mut w = [0f32; 4];
        let t = weights_from_opacity(&o, &mut w).unwrap();
        assert!(w.iter().all(|v| v.is_finite()) && t == 0.0);
        assert!(w.iter().sum::<f32>() <= 1.0 + 1e-6);
    }
    // Log-keep form with a keep of e^{-1e7} (β = 1e-4, sdf = −1e3).
    let lk = [-0.1f32, -1e7, -1e7];
    let o = [0.095f32, 1.0, 1.0];
    let mut w = [0f32; 3];
    let t = weights_from_log_keep(&lk, &o, &mut w).unwrap();
    assert!(w.iter().all(|v| v.is_finite()) && t == 0.0);
    assert!(w.iter().sum::<f32>() <= 1.0 + 1e-6);
    // Mismatched lengths are errors, not panics.
    assert!(weights_from_density(&[1.0f32], &[1.0, 2.0], &mut [0.0]).is_err());
    assert!(weights_from_opacity(&[1.0f32], &mut [0.0; 2]).is_err());
    assert!(weights_from_log_keep(&[1.0f32], &[1.0], &mut [0.0; 2]).is_err());
    assert!(transmittance(&[1.0f32], &[]).is_err());
    assert!(aggregate(&[1.0f32], &[], &[1.0]).is_err());
    assert!(intervals(&[1.0f32], &mut []).is_err());
    // An empty ray has depth 0 and colour 0.
    let w = [0f32; 5];
    let a = aggregate(&w, &[[0.5; 3]; 5], &[1.0, 2.0, 3.0, 4.0, 5.0]).unwrap();
    assert_eq!(a.depth, 0.0);
    assert_eq!(a.colour, [0.0; 3]);
    let mut w = [0f32; 3];
    weights_from_density(&[0.0f32; 3], &[1.0, 1.0, 1e10], &mut w).unwrap();
    assert_eq!(w, [0.0; 3]);
}
