//! Adam against dfdx's kernel and references, Instant-NGP's moments,
//! input checked.

use dfdx::prelude::*;
use sdfl_runtime::train::params::*;
use sdfl_runtime::train::TrainError;
use sdfl_stdlib::value::Moments as AdamMoments;

/// Plain f64 Adam for reference, with dfdx's default moments.
fn adam_ref(p: &mut [f64], m: &mut [f64], v: &mut [f64], g: &[f64], t: i32, lr: f64) {
    adam_ref_with(p, m, v, g, t, lr, AdamMoments::default())
}

/// Plain f64 Adam for reference.
fn adam_ref_with(
    p: &mut [f64],
    m: &mut [f64],
    v: &mut [f64],
    g: &[f64],
    t: i32,
    lr: f64,
    moments: AdamMoments,
) {
    let AdamMoments { beta1, beta2, eps } = moments;
    for i in 0..p.len() {
        m[i] = beta1 * m[i] + (1.0 - beta1) * g[i];
        v[i] = beta2 * v[i] + (1.0 - beta2) * g[i] * g[i];
        let mh = m[i] / (1.0 - beta1.powi(t));
        let vh = v[i] / (1.0 - beta2.powi(t));
        p[i] -= lr * mh / (vh.sqrt() + eps);
    }
}

#[test]
fn adam_in_place_gives_dfdx_kernel_bits() {
    // Two trainable parameters and a frozen one, over several steps of
    // varied gradients, against dfdx's kernel in another store.
    let sizes = [40_000usize, 3, 5];
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 40) as f32 / (1u64 << 24) as f32 - 0.5
    };
    let init: Vec<Vec<f32>> = sizes
        .iter()
        .map(|&n| (0..n).map(|_| next()).collect())
        .collect();
    let moments = AdamMoments {
        beta1: 0.9,
        beta2: 0.99,
        eps: 1e-15,
    };
    let (mut a, mut b) = (ParamStore::new(), ParamStore::new());
    let mut parts = Vec::new();
    let mut offset = 0;
    for (k, v) in init.iter().enumerate() {
        let trainable = k != 2;
        let id = a.add(&format!("p{k}"), v, trainable).unwrap();
        b.add(&format!("p{k}"), v, trainable).unwrap();
        parts.push((id, offset..offset + v.len()));
        offset += v.len();
    }
    let (mut opt_a, mut opt_b) = (
        Adam::with_moments(1e-2, moments).unwrap(),
        Adam::with_moments(1e-2, moments).unwrap(),
    );
    let mut values: Vec<f32> = init.concat();
    let mut grads = vec![0.0f32; offset];
    for step in 0..4 {
        let g: Vec<f32> = (0..offset)
            .map(|i| {
                if i % 7 == step {
                    0.0
                } else {
                    next() * 10f32.powi(-((i % 9) as i32))
                }
            })
            .collect();
        grads.copy_from_slice(&g);
        opt_a.cfg.lr = 1e-2 * 0.5f64.powi(step as i32);
        opt_b.cfg.lr = opt_a.cfg.lr;
        opt_a
            .update_in_place(&mut a, &parts, &mut values, &mut grads)
            .unwrap();
        let slices: Vec<(ParamId, &[f32])> =
            parts.iter().map(|(id, r)| (*id, &g[r.clone()])).collect();
        opt_b.update_from_slices(&mut b, &slices).unwrap();
        assert!(
            grads.iter().all(|&g| g == 0.0),
            "the gradient is left zeroed"
        );
        for (id, r) in &parts {
            let (want, got) = (b.values(*id), &values[r.clone()]);
            assert!(
                want.iter()
                    .zip(got)
                    .all(|(w, g)| w.to_bits() == g.to_bits()),
                "step {step}: {:?}",
                b.name(*id)
            );
            assert_eq!(a.moments(*id), b.moments(*id));
        }
    }
    // A non-finite gradient changes nothing.
    let before = (values.clone(), a.moments(parts[0].0));
    grads[17] = f32::INFINITY;
    let err = opt_a.update_in_place(&mut a, &parts, &mut values, &mut grads);
    assert!(matches!(err, Err(TrainError::Gradient(_))), "{err:?}");
    assert_eq!((values.clone(), a.moments(parts[0].0)), before);
    assert_eq!(grads[17], f32::INFINITY);
    let short = [(parts[0].0, 0..3)];
    assert!(opt_a
        .update_in_place(&mut a, &short, &mut values, &mut grads)
        .is_err());
}

#[test]
fn adam_with_instant_ngp_moments_matches_reference() {
    // β₂ = 0.99 and ε = 1e-15: a tiny gradient still moves its value
    // by about the learning rate, where ε = 1e-8 would mute it.
    let moments = AdamMoments {
        beta1: 0.8,
        beta2: 0.99,
        eps: 1e-15,
    };
    let mut store = ParamStore::new();
    let x = store.add("x", &[1.0, 2.0], true).unwrap();
    let mut opt = Adam::with_moments(0.01, moments).unwrap();
    let mut p = [1.0f64, 2.0];
    let (mut m, mut v) = ([0.0; 2], [0.0; 2]);
    for t in 1..=6 {
        let g = [1e-9f32 * t as f32, -0.5];
        opt.update_from_slices(&mut store, &[(x, &g)]).unwrap();
        adam_ref_with(
            &mut p,
            &mut m,
            &mut v,
            &[g[0] as f64, -0.5],
            t,
            0.01,
            moments,
        );
    }
    let got = store.values(x);
    assert!((got[0] as f64 - p[0]).abs() < 1e-5, "{got:?} vs {p:?}");
    assert!((got[1] as f64 - p[1]).abs() < 1e-5, "{got:?} vs {p:?}");
    assert!(
        got[0] < 0.95,
        "the tiny gradient moved it by {}",
        1.0 - got[0]
    );
    for bad in [
        AdamMoments {
            beta1: 1.0,
            ..moments
        },
        AdamMoments {
            beta2: -0.1,
            ..moments
        },
        AdamMoments {
            eps: 0.0,
            ..moments
        },
        AdamMoments {
            eps: f64::NAN,
            ..moments
        },
    ] {
        assert!(Adam::with_moments(0.01, bad).is_err(), "{bad:?}");
    }
}

#[test]
fn adam_on_graph_gradients_matches_reference() {
    // Minimise Σ (x − target)² through a dfdx graph.
    let mut store = ParamStore::new();
    let x = store.add("x", &[1.0, -2.0, 0.5], true).unwrap();
    let fixed = store.add("fixed", &[3.0], false).unwrap();
    let mut opt = Adam::new(0.1).unwrap();
    let target = [0.3f64, 0.7, -0.2];
    let mut p = [1.0f64, -2.0, 0.5];
    let (mut m, mut v) = ([0.0; 3], [0.0; 3]);
    for t in 1..=20 {
        let dev = store.device().clone();
        let tgt = dev.tensor_from_vec(target.iter().map(|&v| v as f32).collect(), (3,));
        let loss = (store.tensor(x).leaky_trace() - tgt).square().sum();
        let mut grads = loss.backward();
        opt.update(&mut store, &mut grads).unwrap();
        let g: Vec<f64> = (0..3).map(|i| 2.0 * (p[i] - target[i])).collect();
        adam_ref(&mut p, &mut m, &mut v, &g, t, 0.1);
    }
    let got = store.values(x);
    for i in 0..3 {
        assert!((got[i] as f64 - p[i]).abs() < 1e-4, "{got:?} vs {p:?}");
    }
    assert_eq!(store.values(fixed), vec![3.0]);
    assert_eq!(store.find("fixed"), Some(fixed));
    assert!(store.add("x", &[0.0], true).is_err());
    assert!(store.add("nan", &[f32::NAN], true).is_err());
}

#[test]
fn adam_from_slices_matches_reference_and_checks_input() {
    let mut store = ParamStore::new();
    let x = store.add("x", &[1.0, 2.0], true).unwrap();
    let mut opt = Adam::new(0.01).unwrap();
    let mut p = [1.0f64, 2.0];
    let (mut m, mut v) = ([0.0; 2], [0.0; 2]);
    for t in 1..=5 {
        let g = [0.5f32 * t as f32, -1.0];
        opt.update_from_slices(&mut store, &[(x, &g)]).unwrap();
        adam_ref(&mut p, &mut m, &mut v, &[0.5 * t as f64, -1.0], t, 0.01);
    }
    let got = store.values(x);
    assert!((got[0] as f64 - p[0]).abs() < 1e-6 && (got[1] as f64 - p[1]).abs() < 1e-6);
    let before = store.values(x);
    assert!(opt.update_from_slices(&mut store, &[(x, &[1.0])]).is_err());
    assert!(opt
        .update_from_slices(&mut store, &[(ParamId(7), &[1.0])])
        .is_err());
    assert_eq!(store.values(x), before);
    assert!(opt
        .update_from_slices(&mut store, &[(x, &[f32::NAN, 0.0])])
        .is_err());
    assert!(Adam::new(-1.0).is_err());
}
