//! Graph operations: weights from density against the reference, hard
//! cases finite.

use dfdx::prelude::*;
use sdfl_runtime::train::graph_ops::*;
use sdfl_runtime::volume::composite;

fn dev() -> Cpu {
    let d = Cpu::default();
    d.enable_cache();
    d
}

const R: usize = 3;
const N: usize = 7;

/// ∂(Σ_k c_k y_k)/∂x by the graph vs central differences of an f64 function.
fn check_grad(
    x: &[f32],
    graph: impl Fn(Traced2) -> Traced2,
    reference: impl Fn(&[f64]) -> Vec<f64>,
    tol: f64,
) {
    let dev = dev();
    let coef: Vec<f32> = (0..R * N).map(|k| 0.3 + 0.1 * (k % 5) as f32).collect();
    let xt = dev.tensor_from_vec(x.to_vec(), (R, N));
    let y = graph(xt.leaky_trace());
    let yv = dev.tensor_to_vec(&y);
    let x64: Vec<f64> = x.iter().map(|&v| v as f64).collect();
    let r = reference(&x64);
    for k in 0..R * N {
        assert!(
            (yv[k] as f64 - r[k]).abs() < tol * (1.0 + r[k].abs()),
            "value {k}: {} vs {}",
            yv[k],
            r[k]
        );
    }
    let loss = (y * dev.tensor_from_vec(coef.clone(), (R, N))).sum();
    let g = loss.backward().get(&xt).as_vec();
    let h = 1e-6;
    for k in 0..R * N {
        let f = |dh: f64| {
            let mut xx = x64.clone();
            xx[k] += dh;
            reference(&xx)
                .iter()
                .zip(&coef)
                .map(|(a, &c)| a * c as f64)
                .sum::<f64>()
        };
        let fd = (f(h) - f(-h)) / (2.0 * h);
        assert!(
            (g[k] as f64 - fd).abs() < tol * (1.0 + fd.abs()),
            "grad {k}: {} vs {fd}",
            g[k]
        );
    }
}

#[test]
fn weights_from_density_match_reference() {
    let delta: Vec<f32> = (0..R * N)
        .map(|k| if k % N == N - 1 { 1e10 } else { 0.2 })
        .collect();
    let sigma: Vec<f32> = (0..R * N)
        .map(|k| 0.1 + 0.5 * ((k * 3) % 5) as f32)
        .collect();
    let dt = dev().tensor_from_vec(delta.clone(), (R, N));
    let reference = |s: &[f64]| {
        let mut out = vec![0.0; R * N];
        for r in 0..R {
            let mut t = 1.0;
            for k in 0..N {
                let x = s[r * N + k] * delta[r * N + k] as f64;
                out[r * N + k] = t * (1.0 - (-x).exp());
                t *= (-x).exp();
            }
        }
        out
    };
    check_grad(
        &sigma,
        |s| weights_from_density(s, &dt).unwrap(),
        reference,
        2e-4,
    );
    // Same as the f32 slice implementation.
    let w = dev().tensor_to_vec(
        &weights_from_density(
            dev().tensor_from_vec(sigma.clone(), (R, N)).leaky_trace(),
            &dt,
        )
        .unwrap(),
    );
    let mut w2 = vec![0f32; N];
    composite::weights_from_density(&sigma[..N], &delta[..N], &mut w2).unwrap();
    for k in 0..N {
        assert!((w[k] - w2[k]).abs() < 1e-6);
    }
}

#[test]
fn log_keep_weights_match_reference() {
    // Opacities in (0, 1) with ln(1 − o) formed in the graph.
    let o: Vec<f32> = (0..R * N)
        .map(|k| 0.05 + 0.9 * ((k * 7) % 11) as f32 / 10.0)
        .collect();
    let reference = |o: &[f64]| {
        let mut out = vec![0.0; R * N];
        for r in 0..R {
            let mut t = 1.0;
            for k in 0..N {
                out[r * N + k] = t * o[r * N + k];
                t *= 1.0 - o[r * N + k];
            }
        }
        out
    };
    check_grad(
        &o,
        |o| {
            let l = (-again(&o) + 1.0).ln();
            weights_from_log_keep(l, o).unwrap()
        },
        reference,
        2e-4,
    );
}

#[test]
fn hard_cases_have_finite_values_and_gradients() {
    let dev = dev();
    // An opaque sample (o = 1, ln(1 − o) exact at −1e7 as the opacity
    // form gives it deep inside), empty ones and the clamp's −1e4.
    let o: Vec<f32> = (0..R * N)
        .map(|k| [0.0f32, 1.0, 0.5, 1e-30, 1.0, 0.0, 0.25][k % N])
        .collect();
    let l: Vec<f32> = (0..R * N)
        .map(|k| [0.0f32, -1e7, 0.5f32.ln(), -1e-30, -1e4, 0.0, 0.75f32.ln()][k % N])
        .collect();
    let (ot, lt) = (
        dev.tensor_from_vec(o, (R, N)),
        dev.tensor_from_vec(l, (R, N)),
    );
    let w = weights_from_log_keep(lt.leaky_trace(), ot.leaky_trace()).unwrap();
    let wv = dev.tensor_to_vec(&w);
    assert!(wv.iter().all(|v| v.is_finite()));
    for r in 0..R {
        let s: f32 = wv[r * N..(r + 1) * N].iter().sum();
        assert!(
            (1.0 - 1e-6..=1.0 + 1e-6).contains(&s),
            "an opaque sample stops the ray: {s}"
        );
    }
    let g = w.sum().backward();
    assert!(g.get(&ot).as_vec().iter().all(|v| v.is_finite()));
    assert!(g.get(&lt).as_vec().iter().all(|v| v.is_finite()));
    // σΔ up to 1e10·1e10 and infinite σ.
    let s: Vec<f32> = (0..R * N)
        .map(|k| [0.0, 1e10, f32::INFINITY, 1.0, 0.0, 3.0, 1e10][k % N])
        .collect();
    let d = dev.tensor_from_vec(
        (0..R * N)
            .map(|k| if k % N == N - 1 { 1e10 } else { 0.5 })
            .collect::<Vec<f32>>(),
        (R, N),
    );
    let st = dev.tensor_from_vec(s, (R, N));
    let w = weights_from_density(st.leaky_trace(), &d).unwrap();
    let short = dev.tensor_from_vec(vec![1.0f32; R * (N - 1)], (R, N - 1));
    assert!(weights_from_density(st.leaky_trace(), &short).is_err());
    let wv = dev.tensor_to_vec(&w);
    assert!(wv.iter().all(|v| v.is_finite()) && wv[..N].iter().sum::<f32>() <= 1.0 + 1e-6);
    let g = w.sum().backward().get(&st).as_vec();
    assert!(g.iter().all(|v| v.is_finite()));
}
