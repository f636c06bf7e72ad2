//! Compositing and the silhouette: forward against f64, backward against
//! finite differences, hard cases.

use sdfl_runtime::neural::composite::*;

fn reference(sigma: &[f64], rgb: &[f64], delta: &[f64], bg: [f64; 3]) -> [f64; 3] {
    let mut acc = 0.0f64;
    let mut c = [0.0f64; 3];
    for k in 0..sigma.len() {
        let w = (-acc).exp() * (1.0 - (-sigma[k] * delta[k]).exp());
        for i in 0..3 {
            c[i] += w * rgb[3 * k + i];
        }
        acc += sigma[k] * delta[k];
    }
    for i in 0..3 {
        c[i] += (-acc).exp() * bg[i];
    }
    c
}

fn case() -> (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>) {
    let n = 12;
    let t: Vec<f32> = (0..n).map(|k| 2.0 + 0.3 * k as f32).collect();
    let delta: Vec<f32> = (0..n).map(|k| if k + 1 < n { 0.3 } else { 0.0 }).collect();
    let sigma: Vec<f32> = (0..n).map(|k| ((k * 5 % 7) as f32) * 0.8).collect();
    let rgb: Vec<f32> = (0..3 * n).map(|i| ((i * 3 % 10) as f32) / 10.0).collect();
    (sigma, rgb, t, delta)
}

#[test]
fn forward_matches_f64_reference() {
    let (sigma, rgb, t, delta) = case();
    let bg = [0.2, 0.5, 1.0];
    let c = composite(&sigma, &rgb, &t, &delta, bg);
    let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
    let want = reference(&f(&sigma), &f(&rgb), &f(&delta), bg.map(|x| x as f64));
    for (c, want) in c.colour.iter().zip(want) {
        assert!((*c as f64 - want).abs() < 1e-6);
    }
}

#[test]
fn backward_matches_finite_differences() {
    let (sigma, rgb, _, delta) = case();
    let bg = [0.2f32, 0.5, 1.0];
    let g = [0.7f32, -1.1, 0.4];
    let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
    let loss = |s: &[f64], c: &[f64]| {
        let col = reference(s, c, &f(&delta), bg.map(|x| x as f64));
        (0..3).map(|i| col[i] * g[i] as f64).sum::<f64>()
    };
    let mut ds = vec![0.0; sigma.len()];
    let mut dc = vec![0.0; rgb.len()];
    composite_backward(
        &sigma,
        &rgb,
        &delta,
        bg,
        g,
        &mut ds,
        &mut dc,
        &mut Vec::new(),
    );
    let (s64, c64) = (f(&sigma), f(&rgb));
    let h = 1e-6;
    for k in 0..sigma.len() {
        let (mut up, mut down) = (s64.clone(), s64.clone());
        up[k] += h;
        down[k] -= h;
        let fd = (loss(&up, &c64) - loss(&down, &c64)) / (2.0 * h);
        assert!((ds[k] as f64 - fd).abs() < 1e-5, "σ{k}: {} vs {fd}", ds[k]);
    }
    for k in 0..rgb.len() {
        let (mut up, mut down) = (c64.clone(), c64.clone());
        up[k] += h;
        down[k] -= h;
        let fd = (loss(&s64, &up) - loss(&s64, &down)) / (2.0 * h);
        assert!((dc[k] as f64 - fd).abs() < 1e-5, "c{k}: {} vs {fd}", dc[k]);
    }
}

/// BCE of the opacity by its definition in f64.
fn silhouette_reference(sigma: &[f64], delta: &[f64], a: f64) -> f64 {
    let o = 1.0 - (-sigma.iter().zip(delta).map(|(s, d)| s * d).sum::<f64>()).exp();
    -(a * o.ln() + (1.0 - a) * (1.0 - o).ln())
}

#[test]
fn silhouette_matches_f64_reference_and_finite_differences() {
    let (sigma, _, _, delta) = case();
    // Scaled down so that the opacity is neither 0 nor 1.
    let sigma: Vec<f32> = sigma.iter().map(|s| 0.05 * s).collect();
    let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
    for a in [0.0f32, 0.3, 1.0] {
        let mut ds = vec![0.25; sigma.len()];
        let loss = silhouette_backward(&sigma, &delta, a, 2.0, &mut ds);
        let want = 2.0 * silhouette_reference(&f(&sigma), &f(&delta), a as f64);
        assert!(
            (loss - want).abs() < 1e-5 * want.abs().max(1.0),
            "{loss} vs {want}"
        );
        let s64 = f(&sigma);
        let h = 1e-6;
        for k in 0..sigma.len() {
            let (mut up, mut down) = (s64.clone(), s64.clone());
            up[k] += h;
            down[k] -= h;
            let fd = 2.0
                * (silhouette_reference(&up, &f(&delta), a as f64)
                    - silhouette_reference(&down, &f(&delta), a as f64))
                / (2.0 * h);
            // Added to what `d_sigma` held.
            let got = ds[k] as f64 - 0.25;
            assert!(
                (got - fd).abs() < 1e-4 * fd.abs().max(1.0),
                "a {a}, σ{k}: {got} vs {fd}"
            );
        }
    }
}

#[test]
fn silhouette_hard_cases_are_finite() {
    // Nothing on a covered pixel, opaque rays on covered and uncovered
    // ones, huge and zero densities, no samples.
    for (sigma, delta, a) in [
        (vec![0.0f32; 4], vec![0.5f32; 4], 1.0f32),
        (vec![1e30, 1e30], vec![1.0, 1.0], 1.0),
        (vec![1e30, 1e30], vec![1.0, 1.0], 0.0),
        (vec![1e-30, 3.0], vec![0.0, 1.0], 1.0),
        (vec![], vec![], 1.0),
    ] {
        let mut ds = vec![0.0; sigma.len()];
        let loss = silhouette_backward(&sigma, &delta, a, 1.0, &mut ds);
        assert!(loss.is_finite() && loss >= 0.0, "{loss}");
        if a == 1.0 {
            // The floor bounds the cost of a ray that sees nothing.
            assert!(loss <= -(OPACITY_FLOOR as f64).ln() + 1e-3, "{loss}");
        }
        assert!(ds.iter().all(|x| x.is_finite()), "{ds:?}");
    }
    // An uncovered pixel pushes an opaque ray's density down at full
    // strength: the gradient does not saturate with the opacity.
    let mut ds = vec![0.0; 2];
    silhouette_backward(&[40.0, 40.0], &[1.0, 1.0], 0.0, 1.0, &mut ds);
    assert_eq!(ds, [1.0, 1.0]);
}

#[test]
fn hard_cases_are_finite() {
    // Huge densities, an infinite last interval, empty rays, zero-width bins.
    for (sigma, delta) in [
        (vec![1e30f32, 1e30, 0.0], vec![1.0f32, 1e10, 1e10]),
        (vec![0.0; 4], vec![0.5, 0.5, 0.5, 1e10]),
        (vec![3.0, 1e-30, 5.0], vec![0.0, 0.0, 0.0]),
        (vec![], vec![]),
    ] {
        let n = sigma.len();
        let rgb = vec![0.5; 3 * n];
        let t = vec![1.0; n];
        let c = composite(&sigma, &rgb, &t, &delta, [1.0; 3]);
        assert!(c.colour.iter().all(|x| x.is_finite() && *x <= 1.0 + 1e-6));
        let mut ds = vec![0.0; n];
        let mut dc = vec![0.0; 3 * n];
        composite_backward(
            &sigma,
            &rgb,
            &delta,
            [1.0; 3],
            [1.0; 3],
            &mut ds,
            &mut dc,
            &mut Vec::new(),
        );
        assert!(ds.iter().chain(&dc).all(|x| x.is_finite()), "{ds:?} {dc:?}");
    }
}
