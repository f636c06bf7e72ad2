//! The box volume as a dfdx graph: points → box SDF → opacity
//! `α·Ψ_β(−sdf)` (and `ln(1 − opacity)`) → weights → rainbow colour → MSE.
//!
//! It is the reference autodiff path (and the template for the language's
//! lowering); the fused kernel in [`crate::volume::box_volume`] is checked
//! against it. dfdx has no cumsum, so the exclusive prefix sum of
//! `ln(1 − o)` is a matmul with a strictly upper-triangular ones matrix.
//! Where a quantity has a sign-dependent formula, the sign is taken from the
//! forward values as a constant tensor and only finite expressions built on
//! the single `exp(−|sdf|/β)` are blended, so no masked branch can overflow.

use dfdx::prelude::*;

use super::params::{ParamId, ParamStore};
use super::TrainError;
use crate::volume::rays::Ray;
use crate::volume::shapes::{RAINBOW_HI, RAINBOW_LO};

type Traced<S> = Tensor<S, f32, Cpu, OwnedTape<f32, Cpu>>;

fn again<S: Shape>(t: &Traced<S>) -> Traced<S> {
    // Same tensor id with an empty tape: a second use whose gradient the
    // merged tape accumulates into the same entry.
    t.retaped::<OwnedTape<f32, Cpu>>()
}

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

    let sdf_v = dev.tensor_to_vec(&sdf);
    let sg: Vec<f32> = sdf_v
        .iter()
        .map(|&v| if v >= 0.0 { 1.0 } else { -1.0 })
        .collect();
    let neg: Vec<f32> = sdf_v
        .iter()
        .map(|&v| if v >= 0.0 { 0.0 } else { 1.0 })
        .collect();
    let pos: Vec<f32> = neg.iter().map(|v| 1.0 - v).collect();
    let sg = dev.tensor_from_vec(sg, (r, n));
    let neg = dev.tensor_from_vec(neg, (r, n));
    let pos = dev.tensor_from_vec(pos, (r, n));

    let abs_sdf = sdf * sg.clone();
    let e = (again(&abs_sdf) * (-1.0 / beta)).exp();
    // Each traced tensor's own tape must reach the loss exactly once (`e` via
    // the opacity, `abs_sdf` via l_in); further uses go through `again`.
    // ln(1 − opacity): outside ln(1 − α e/2) ≥ ln ½; inside, for α = 1,
    // ln(e/2) = ln ½ − |sdf|/β, otherwise ln(1 − α + α e/2) ≥ ln(1 − α).
    let l_out = (again(&e) * (-0.5 * alpha) + 1.0).ln();
    let l_in = if alpha == 1.0 {
        abs_sdf * (-1.0 / beta) + 0.5f32.ln()
    } else {
        // abs_sdf's tape still has to reach the loss: fold it in with weight 0.
        (again(&e) * (0.5 * alpha) + (1.0 - alpha)).ln() + abs_sdf * 0.0
    };
    // opacity = α·e/2 outside, α·(1 − e/2) inside.
    let opacity = e * sg * (0.5 * alpha) + neg.clone() * alpha;
    let log_keep = l_out * pos + l_in * neg;

    // Exclusive prefix sum along samples: U[j, k] = 1 for j < k.
    let mut u = vec![0f32; n * n];
    for j in 0..n {
        for k in (j + 1)..n {
            u[j * n + k] = 1.0;
        }
    }
    let u = dev.tensor_from_vec(u, (n, n));
    let trans = log_keep.matmul(u).exp();
    let w = trans * opacity;

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
