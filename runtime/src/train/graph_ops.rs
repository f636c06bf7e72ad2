//! Differentiable volume-rendering building blocks as dfdx 0.13 graph ops on
//! `[rays, samples]` tensors, for the language lowering to compose.
//!
//! * dfdx has no cumsum: [`exclusive_cumsum`] multiplies by a strictly
//!   upper-triangular ones matrix (`[R, N] × [N, N]`).
//! * Sign-dependent formulas take the sign from the forward values as a
//!   constant tensor and blend only finite expressions built on one
//!   `exp(−|sdf|/β) ∈ [0, 1]`, so values and gradients stay finite for any
//!   β > 0 and |sdf| (no masked branch can overflow).
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
/// and `o` (see [`sdf_opacity`]); finite where `o` rounds to 1.
pub fn weights_from_log_keep(log_keep: Traced2, opacity: Traced2) -> Result<Traced2, TrainError> {
    same_shape(log_keep.shape(), opacity.shape())?;
    Ok(exclusive_cumsum(log_keep).exp() * opacity)
}

/// Constant sign tensors of `x`: (`+1` where `x ≥ 0` else `−1`, `[x < 0]`, `[x ≥ 0]`).
fn signs(x: &Traced2) -> [Tensor<(usize, usize), f32, Cpu>; 3] {
    let dev = x.device().clone();
    let v = dev.tensor_to_vec(x);
    let shape = *x.shape();
    let sg = v
        .iter()
        .map(|&a| if a >= 0.0 { 1.0 } else { -1.0 })
        .collect();
    let neg = v
        .iter()
        .map(|&a| if a >= 0.0 { 0.0 } else { 1.0 })
        .collect();
    let pos = v
        .iter()
        .map(|&a| if a >= 0.0 { 1.0 } else { 0.0 })
        .collect();
    [
        dev.tensor_from_vec(sg, shape),
        dev.tensor_from_vec(neg, shape),
        dev.tensor_from_vec(pos, shape),
    ]
}

/// The assignment's opacity `o = α·Ψ_β(−sdf)` and `ln(1 − o)`, for `0 < α ≤ 1`,
/// `β > 0` (callers validate). Inside with α = 1, `ln(1 − o) = ln ½ − |sdf|/β`
/// exactly, never `ln 0`.
///
/// The opacity carries the tape of `sdf`'s history; `ln(1 − o)` only its own
/// ops, so it must reach the loss together with the opacity (as in
/// [`weights_from_log_keep`]); the opacity alone is fine.
pub fn sdf_opacity(sdf: Traced2, alpha: f32, beta: f32) -> (Traced2, Traced2) {
    let [sg, neg, pos] = signs(&sdf);
    let abs_sdf = sdf * sg.clone();
    // Inside, α = 1: ln(e/2) = ln ½ − |sdf|/β (linear, no underflow).
    let l_in_exact = (alpha == 1.0).then(|| again(&abs_sdf) * (-1.0 / beta) + 0.5f32.ln());
    let e = (abs_sdf * (-1.0 / beta)).exp();
    // Outside: ln(1 − α e/2) ≥ ln ½.
    let l_out = (again(&e) * (-0.5 * alpha) + 1.0).ln();
    // Inside, α < 1: ln(1 − α + α e/2) ≥ ln(1 − α).
    let l_in = match l_in_exact {
        Some(l) => l,
        None => (again(&e) * (0.5 * alpha) + (1.0 - alpha)).ln(),
    };
    // α·e/2 outside, α·(1 − e/2) inside.
    let opacity = e * sg * (0.5 * alpha) + neg.clone() * alpha;
    (opacity, l_out * pos + l_in * neg)
}

/// VolSDF density `σ = α·Ψ_β(−sdf)` (α any positive scale).
pub fn volsdf_density(sdf: Traced2, alpha: f32, beta: f32) -> Traced2 {
    let [sg, neg, _] = signs(&sdf);
    let e = (sdf * sg.clone() * (-1.0 / beta)).exp();
    e * sg * (0.5 * alpha) + neg * alpha
}

/// NeuS logistic density `(α/β)·e/(1 + e)²` with `e = exp(−|sdf|/β)`
/// (= `(α/β)·sigmoid(−sdf/β)·(1 − sigmoid(−sdf/β))`).
pub fn neus_density(sdf: Traced2, alpha: f32, beta: f32) -> Traced2 {
    let [sg, _, _] = signs(&sdf);
    let e = (sdf * sg * (-1.0 / beta)).exp();
    let d = (again(&e) + 1.0).square();
    e / d * (alpha / beta)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::composite;
    use crate::volume::density;

    fn dev() -> Cpu {
        let d = Cpu::default();
        d.enable_cache();
        d
    }

    const R: usize = 3;
    const N: usize = 7;

    fn sdf_values() -> Vec<f32> {
        (0..R * N)
            .map(|k| 0.45 - 0.13 * k as f32 + 0.011 * (k * k % 7) as f32)
            .collect()
    }

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

    fn psi(s: f64, beta: f64) -> f64 {
        if s <= 0.0 {
            0.5 * (s / beta).exp()
        } else {
            1.0 - 0.5 * (-s / beta).exp()
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
    fn opacity_and_log_keep_weights_match_reference() {
        for (alpha, beta) in [(1.0f32, 0.1f32), (0.7, 0.2)] {
            let (a, b) = (alpha as f64, beta as f64);
            let reference = |s: &[f64]| {
                let mut out = vec![0.0; R * N];
                for r in 0..R {
                    let mut t = 1.0;
                    for k in 0..N {
                        let o = a * psi(-s[r * N + k], b);
                        out[r * N + k] = t * o;
                        t *= 1.0 - o;
                    }
                }
                out
            };
            check_grad(
                &sdf_values(),
                |s| {
                    let (o, l) = sdf_opacity(s, alpha, beta);
                    weights_from_log_keep(l, o).unwrap()
                },
                reference,
                2e-4,
            );
            check_grad(
                &sdf_values(),
                |s| sdf_opacity(s, alpha, beta).0,
                |s| s.iter().map(|&x| a * psi(-x, b)).collect(),
                1e-4,
            );
        }
    }

    #[test]
    fn densities_match_reference() {
        check_grad(
            &sdf_values(),
            |s| volsdf_density(s, 10.0, 0.1),
            |s| s.iter().map(|&x| 10.0 * psi(-x, 0.1)).collect(),
            2e-4,
        );
        let neus = |x: f64| {
            let sg = 1.0 / (1.0 + (x / 0.2).exp());
            2.0 / 0.2 * sg * (1.0 - sg)
        };
        check_grad(
            &sdf_values(),
            |s| neus_density(s, 2.0, 0.2),
            |s| s.iter().map(|&x| neus(x)).collect(),
            2e-4,
        );
        // Matches the scalar versions.
        let v = dev().tensor_to_vec(&neus_density(
            dev().tensor_from_vec(sdf_values(), (R, N)).leaky_trace(),
            2.0,
            0.2,
        ));
        for (k, &x) in sdf_values().iter().enumerate() {
            assert!((v[k] - density::neus_density(x, 2.0, 0.2)).abs() < 1e-5);
        }
    }

    #[test]
    fn hard_cases_have_finite_values_and_gradients() {
        let dev = dev();
        let x: Vec<f32> = (0..R * N)
            .map(|k| [-1e3f32, -5.0, -1e-3, 0.0, 1e-3, 5.0, 1e3][k % N])
            .collect();
        for beta in [1e-4f32, 0.05] {
            for alpha in [1.0f32, 0.5] {
                let xt = dev.tensor_from_vec(x.clone(), (R, N));
                let (o, l) = sdf_opacity(xt.leaky_trace(), alpha, beta);
                let w = weights_from_log_keep(l, o).unwrap();
                let wv = dev.tensor_to_vec(&w);
                assert!(wv.iter().all(|v| v.is_finite()));
                for r in 0..R {
                    assert!(wv[r * N..(r + 1) * N].iter().sum::<f32>() <= 1.0 + 1e-6);
                }
                let g = w.sum().backward().get(&xt).as_vec();
                assert!(g.iter().all(|v| v.is_finite()), "α {alpha} β {beta}: {g:?}");
                for f in [volsdf_density, neus_density] {
                    let y = f(xt.leaky_trace(), 10.0 * alpha, beta);
                    assert!(dev.tensor_to_vec(&y).iter().all(|v| v.is_finite()));
                    let g = y.sum().backward().get(&xt).as_vec();
                    assert!(g.iter().all(|v| v.is_finite()));
                }
            }
        }
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
