//! The box volume as a dfdx graph: points → box SDF → opacity
//! `α·Ψ_β(−sdf)` (and `ln(1 − opacity)`) → weights → rainbow colour → MSE.
//!
//! It is the reference autodiff path (and the template for the language's
//! lowering), composed from [`super::graph_ops`]; the fused kernel in
//! [`crate::volume::box_volume`] is checked against it.

use dfdx::prelude::*;

use super::graph_ops::{again, sdf_opacity, weights_from_log_keep};
use super::params::{ParamId, ParamStore};
use super::TrainError;
use crate::volume::rays::Ray;
use crate::volume::shapes::{RAINBOW_HI, RAINBOW_LO};

type Traced<S> = Tensor<S, f32, Cpu, OwnedTape<f32, Cpu>>;

/// The box volume's MSE loss over `rays` (targets one colour each), sampled
/// at depths `t`, with gradients for the `center` and `sides` parameters
/// (each 3 values) in `store`. `0 < α ≤ 1`, `β > 0`.
#[allow(clippy::too_many_arguments)]
pub fn box_loss_graph(
    store: &ParamStore,
    center: ParamId,
    sides: ParamId,
    alpha: f32,
    beta: f32,
    t: &[f32],
    rays: &[Ray],
    targets: &[[f32; 3]],
) -> Result<(f32, Gradients<f32, Cpu>), TrainError> {
    let (r, n) = (rays.len(), t.len());
    if r == 0 || n == 0 || targets.len() != r {
        return Err(TrainError::Invalid(format!(
            "box graph needs rays, depths and one target per ray (rays {r}, depths {n}, targets {})",
            targets.len()
        )));
    }
    if !(alpha > 0.0 && alpha <= 1.0 && beta > 0.0 && beta.is_finite()) {
        return Err(TrainError::Invalid(format!(
            "need 0 < α ≤ 1 and β > 0 (α {alpha}, β {beta})"
        )));
    }
    let dev = store.device().clone();
    if store.values(center).len() != 3 || store.values(sides).len() != 3 {
        return Err(TrainError::Invalid(
            "centre and sides must have 3 values".into(),
        ));
    }
    let shape3 = (r, n, 3usize);
    let mut pts = Vec::with_capacity(r * n * 3);
    for ray in rays {
        for &tk in t {
            for i in 0..3 {
                pts.push(ray.origin[i] + tk * ray.dir[i]);
            }
        }
    }
    let pts = dev.tensor_from_vec(pts, shape3);

    let c = store.tensor(center).leaky_trace();
    let s = store.tensor(sides).leaky_trace();
    let c3: Traced<(usize, usize, usize)> = c.broadcast_like::<_, Axes2<0, 1>>(&shape3);
    let s3: Traced<(usize, usize, usize)> = s.broadcast_like::<_, Axes2<0, 1>>(&shape3);
    let d = -c3 + pts;
    // |p − c| as (p − c)·sign: the exact derivative everywhere (abs would
    // give 0 at the kink); the sign is a constant.
    let sign: Vec<f32> = dev
        .tensor_to_vec(&d)
        .iter()
        .map(|&v| if v < 0.0 { -1.0 } else { 1.0 })
        .collect();
    let a = d * dev.tensor_from_vec(sign, shape3);
    let q = again(&a) - s3 * 0.5;
    // |max(q, 0)|: sqrt(x + 1e-30) keeps the derivative finite (and 0 after
    // the chain rule) where all q ≤ 0; the value changes by 1e-15.
    let outside = (again(&q).relu().square().sum::<(usize, usize), Axis<2>>() + 1e-30).sqrt();
    let inside = -(-q.max::<(usize, usize), Axis<2>>()).relu();
    let sdf = outside + inside;

    let (opacity, log_keep) = sdf_opacity(sdf, alpha, beta);
    let w = weights_from_log_keep(log_keep, opacity)?;

    let col = a.clamp(RAINBOW_LO as f32, RAINBOW_HI as f32);
    let rgb = (w.broadcast_like::<_, Axis<2>>(&shape3) * col).sum::<(usize, usize), Axis<1>>();
    let tgt: Vec<f32> = targets.iter().flatten().copied().collect();
    let loss = (rgb - dev.tensor_from_vec(tgt, (r, 3usize)))
        .square()
        .mean();
    let value = loss.array();
    Ok((value, loss.backward()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::box_volume::tests::{batch, reference_loss};
    use crate::volume::{box_loss_and_grad, BoxVolume, Stratified};

    #[test]
    fn graph_matches_fused_kernel_and_finite_differences() {
        let (rays, targets) = batch(200);
        let smp = Stratified::new(64, 0.0, 5.0).unwrap();
        let t = smp.depths();
        let t64: Vec<f64> = t.iter().map(|&x| x as f64).collect();
        let c0 = [0.1f32, 0.05, -0.1];
        let s0 = [1.5f32, 1.4, 1.6];
        for (alpha, beta) in [(1.0f32, 0.05f32), (0.7, 0.1)] {
            let mut store = ParamStore::new();
            let c = store.add("center", &c0, true).unwrap();
            let s = store.add("sides", &s0, true).unwrap();
            let (loss, grads) =
                box_loss_graph(&store, c, s, alpha, beta, &t, &rays, &targets).unwrap();
            let gc = grads.get(store.tensor(c)).as_vec();
            let gs = grads.get(store.tensor(s)).as_vec();
            let vol = BoxVolume::new(c0, s0, alpha, beta).unwrap();
            let (fl, fg) = box_loss_and_grad(&vol, &smp, &rays, &targets).unwrap();
            assert!(((loss - fl) / fl).abs() < 1e-4, "{loss} vs {fl}");
            let c64 = c0.map(|x| x as f64);
            let s64 = s0.map(|x| x as f64);
            let r = reference_loss(c64, s64, alpha as f64, beta as f64, &t64, &rays, &targets);
            assert!(((loss as f64 - r) / r).abs() < 1e-4, "{loss} vs f64 {r}");
            let h = 1e-6;
            for k in 0..6 {
                let eval = |dh: f64| {
                    let (mut cc, mut ss) = (c64, s64);
                    if k < 3 {
                        cc[k] += dh
                    } else {
                        ss[k - 3] += dh
                    }
                    reference_loss(cc, ss, alpha as f64, beta as f64, &t64, &rays, &targets)
                };
                let fd = (eval(h) - eval(-h)) / (2.0 * h);
                let (g, f) = if k < 3 {
                    (gc[k], fg.center[k])
                } else {
                    (gs[k - 3], fg.sides[k - 3])
                };
                let tol = 2e-3 * fd.abs() + 1e-6;
                assert!(
                    (g as f64 - fd).abs() < tol,
                    "α {alpha} param {k}: graph {g} vs fd {fd}"
                );
                assert!(
                    (f as f64 - fd).abs() < tol,
                    "α {alpha} param {k}: fused {f} vs fd {fd}"
                );
            }
        }
    }

    #[test]
    fn graph_gradients_finite_in_hard_cases() {
        let (rays, targets) = batch(32);
        let t = Stratified::new(64, 0.0, 5.0).unwrap().depths();
        for (sides, beta) in [([1.5f32; 3], 1e-4f32), ([2e3; 3], 1e-4), ([1.5; 3], 1e-3)] {
            let mut store = ParamStore::new();
            let c = store.add("center", &[0.0; 3], true).unwrap();
            let s = store.add("sides", &sides, true).unwrap();
            let (loss, grads) =
                box_loss_graph(&store, c, s, 1.0, beta, &t, &rays, &targets).unwrap();
            assert!(loss.is_finite());
            let g = grads.get(store.tensor(c)).as_vec();
            let h = grads.get(store.tensor(s)).as_vec();
            assert!(g.iter().chain(&h).all(|x| x.is_finite()), "{g:?} {h:?}");
        }
        let mut store = ParamStore::new();
        let c = store.add("center", &[0.0; 3], true).unwrap();
        let s = store.add("sides", &[1.0; 3], true).unwrap();
        assert!(box_loss_graph(&store, c, s, 1.5, 0.05, &t, &rays, &targets).is_err());
        assert!(box_loss_graph(&store, c, s, 1.0, 0.05, &t, &rays, &targets[1..]).is_err());
    }
}
