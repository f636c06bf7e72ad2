//! The fused box-volume kernel as a single dfdx op: `(centre, sides) →
//! colours [rays, 3]`, so a graph (the language's losses, regularisers) can
//! use it at the fused kernel's speed. Its backward runs the hand-written
//! f32 backward in parallel; tests check it against the pure dfdx graph of
//! [`super::box_graph`] and finite differences.

use dfdx::prelude::*;

use super::TrainError;
use crate::volume::box_volume::{colour_backward_generic, Params};
use crate::volume::rays::{Ray, Stratified};
use crate::volume::{render_box_rays, BoxVolume};

type Traced<S> = Tensor<S, f32, Cpu, OwnedTape<f32, Cpu>>;

/// Composited rainbow colours `[rays, 3]` of the assignment's box volume for
/// traced `center` and `sides` (3 values each; their values are validated
/// like [`BoxVolume::new`]), with α and β fixed.
pub fn box_volume_colours(
    center: Traced<(usize,)>,
    sides: Traced<(usize,)>,
    alpha: f32,
    beta: f32,
    sampler: &Stratified,
    rays: &[Ray],
) -> Result<Traced<(usize, usize)>, TrainError> {
    let dev = center.device().clone();
    let cv = dev.tensor_to_vec(&center);
    let sv = dev.tensor_to_vec(&sides);
    if cv.len() != 3 || sv.len() != 3 {
        return Err(TrainError::Invalid(
            "centre and sides must have 3 values".into(),
        ));
    }
    if rays.is_empty() {
        return Err(TrainError::Invalid("no rays".into()));
    }
    let vol = BoxVolume::new([cv[0], cv[1], cv[2]], [sv[0], sv[1], sv[2]], alpha, beta)?;
    let colours = render_box_rays(&vol, sampler, rays)?;
    let flat: Vec<f32> = colours.iter().flat_map(|c| c.colour).collect();
    let out = dev.tensor_from_vec(flat, (rays.len(), 3usize));

    let (center, tape_c) = center.split_tape();
    let (sides, tape_s) = sides.split_tape();
    let mut tape = tape_c.merge(tape_s);
    let out_id = out.clone();
    let rays = rays.to_vec();
    let t = sampler.depths();
    let params = Params::<f32>::from_volume(&vol);
    tape.add_backward_op(move |grads| {
        let g_out: Vec<[f32; 3]> = grads
            .get_or_alloc_mut(&out_id)?
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let g = colour_backward_generic(&params, &t, &rays, &g_out);
        for (v, p) in [(g.center, &center), (g.sides, &sides)] {
            let dst = grads.get_or_alloc_mut(p)?;
            for i in 0..3 {
                dst[i] += v[i];
            }
        }
        Ok(())
    });
    Ok(out.put_tape(tape))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::box_graph::box_loss_graph;
    use crate::train::ParamStore;
    use crate::volume::box_volume::tests::{batch, reference_loss};

    #[test]
    fn op_gradients_match_graph_and_finite_differences() {
        let (rays, targets) = batch(150);
        let smp = Stratified::new(64, 0.0, 5.0).unwrap();
        let t = smp.depths();
        let c0 = [0.1f32, 0.05, -0.1];
        let s0 = [1.5f32, 1.4, 1.6];
        let mut store = ParamStore::new();
        let c = store.add("center", &c0, true).unwrap();
        let s = store.add("sides", &s0, true).unwrap();
        let dev = store.device().clone();
        let tgt: Vec<f32> = targets.iter().flatten().copied().collect();
        let rgb = box_volume_colours(
            store.tensor(c).leaky_trace(),
            store.tensor(s).leaky_trace(),
            1.0,
            0.05,
            &smp,
            &rays,
        )
        .unwrap();
        let loss = (rgb - dev.tensor_from_vec(tgt, (rays.len(), 3usize)))
            .square()
            .mean();
        let lv = loss.array();
        let grads = loss.backward();
        let (gl, ggrads) = box_loss_graph(&store, c, s, 1.0, 0.05, &t, &rays, &targets).unwrap();
        assert!(((lv - gl) / gl).abs() < 1e-4);
        let t64: Vec<f64> = t.iter().map(|&x| x as f64).collect();
        for (id, off) in [(c, 0), (s, 3)] {
            let a = grads.get(store.tensor(id)).as_vec();
            let b = ggrads.get(store.tensor(id)).as_vec();
            for i in 0..3 {
                let h = 1e-6;
                let eval = |dh: f64| {
                    let mut cc = c0.map(|x| x as f64);
                    let mut ss = s0.map(|x| x as f64);
                    if off == 0 {
                        cc[i] += dh
                    } else {
                        ss[i] += dh
                    }
                    reference_loss(cc, ss, 1.0, 0.05, &t64, &rays, &targets)
                };
                let fd = (eval(h) - eval(-h)) / (2.0 * h);
                let tol = 2e-3 * fd.abs() + 1e-6;
                assert!(
                    (a[i] as f64 - fd).abs() < tol,
                    "op {off}+{i}: {} vs {fd}",
                    a[i]
                );
                assert!((a[i] - b[i]).abs() as f64 <= tol, "op vs graph {off}+{i}");
            }
        }
    }

    #[test]
    fn op_rejects_bad_input() {
        let (rays, _) = batch(4);
        let smp = Stratified::new(8, 0.0, 5.0).unwrap();
        let dev = Cpu::default();
        let bad_alpha = box_volume_colours(
            dev.tensor_from_vec(vec![0.0; 3], (3,)).leaky_trace(),
            dev.tensor_from_vec(vec![1.0; 3], (3,)).leaky_trace(),
            2.0,
            0.05,
            &smp,
            &rays,
        );
        assert!(bad_alpha.is_err());
        let bad_len = box_volume_colours(
            dev.tensor_from_vec(vec![0.0; 2], (2,)).leaky_trace(),
            dev.tensor_from_vec(vec![1.0; 3], (3,)).leaky_trace(),
            1.0,
            0.05,
            &smp,
            &rays,
        );
        assert!(bad_len.is_err());
        let no_rays = box_volume_colours(
            dev.tensor_from_vec(vec![0.0; 3], (3,)).leaky_trace(),
            dev.tensor_from_vec(vec![1.0; 3], (3,)).leaky_trace(),
            1.0,
            0.05,
            &smp,
            &[],
        );
        assert!(no_rays.is_err());
    }
}
