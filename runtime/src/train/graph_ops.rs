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
