//! Differentiable compositing as dfdx 0.13 graph ops on `[rays, samples]`
//! tensors. Per-sample opacities and `ln(1 − o)` come from the densities'
//! one definition ([`sdfl_stdlib::density`]) through the field op
//! (`train::graph`), not from graph ops of their own.
//!
//! * dfdx has no cumsum: [`exclusive_cumsum`] multiplies by a strictly
//!   upper-triangular ones matrix (`[R, N] × [N, N]`).
//! * A traced tensor used twice is re-used through [`again`] (same id, empty
//!   tape); its own tape must still reach the loss exactly once.

use dfdx::prelude::*;

use super::TrainError;

/// A `[rays, samples]` tensor on the CPU that records gradients.
pub type Traced2 = Tensor<(usize, usize), f32, Cpu, OwnedTape<f32, Cpu>>;

/// A second handle to a traced tensor: same id, empty tape. Gradients of all
/// uses accumulate into the same entry once the tapes merge.
pub fn again<S: Shape>(
    t: &Tensor<S, f32, Cpu, OwnedTape<f32, Cpu>>,
) -> Tensor<S, f32, Cpu, OwnedTape<f32, Cpu>> {
    t.retaped::<OwnedTape<f32, Cpu>>()
}

/// `y_k = Σ_{j<k} x_j` along the samples axis, as `x · U` with `U[j, k] = [j < k]`.
pub fn exclusive_cumsum(x: Traced2) -> Traced2 {
    let n = x.shape().1;
    let mut u = vec![0f32; n * n];
    for j in 0..n {
        for k in (j + 1)..n {
            u[j * n + k] = 1.0;
        }
    }
    let u = x.device().tensor_from_vec(u, (n, n));
    x.matmul(u)
}

/// Weights `T_k·(1 − exp(−σ_kΔ_k))`, `T_k = exp(−Σ_{j<k} σ_jΔ_j)`, from
/// densities and (constant) intervals. `σΔ` is clamped to `[0, 1e30]`, so
/// even infinite densities give finite weights and gradients.
pub fn weights_from_density(
    sigma: Traced2,
    delta: &Tensor<(usize, usize), f32, Cpu>,
) -> Result<Traced2, TrainError> {
    same_shape(sigma.shape(), delta.shape())?;
    let tau = (sigma * delta.clone()).clamp(0.0, 1e30);
    let trans = (-exclusive_cumsum(again(&tau))).exp();
    // 1 − exp(−τ): its derivative exp(−τ) is bounded.
    Ok(trans * (-(-tau).exp() + 1.0))
}

fn same_shape(a: &(usize, usize), b: &(usize, usize)) -> Result<(), TrainError> {
    if a == b {
        Ok(())
    } else {
        Err(TrainError::Invalid(format!(
            "shapes differ: {a:?} vs {b:?}"
        )))
    }
}

/// Weights `T_k·o_k` with `T_k = exp(Σ_{j<k} ln(1 − o_j))` from `ln(1 − o)`
/// and `o` ([`sdfl_stdlib::density::Density::log_keep`]); finite where `o`
/// rounds to 1.
pub fn weights_from_log_keep(log_keep: Traced2, opacity: Traced2) -> Result<Traced2, TrainError> {
    same_shape(log_keep.shape(), opacity.shape())?;
    Ok(exclusive_cumsum(log_keep).exp() * opacity)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::composite;

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
}
