//! Backgrounds: a constant colour, a fit of a direction-dependent one.

use sdfl_runtime::neural::background::*;
use sdfl_runtime::volume::{Ray, SplitMix64};
use sdfl_stdlib::value::{Background, LearnedBackground};

fn rays(n: usize, seed: u64) -> Vec<Ray> {
    let mut g = SplitMix64::new(seed);
    (0..n)
        .map(|k| Ray {
            origin: [0.0; 3],
            // Not unit: the colour is the direction's, whatever its length.
            dir: std::array::from_fn(|_| 3.0 * (2.0 * g.next_f32() - 1.0)),
            view: 0,
            pixel: k as u32,
        })
        .collect()
}

/// A sky: bright above, warm towards +x, as a function of direction.
fn sky(d: [f32; 3]) -> [f32; 3] {
    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let (x, y) = (d[0] / l, d[1] / l);
    [0.5 + 0.35 * x, 0.45 + 0.4 * y, 0.6 - 0.3 * x * y]
}

/// Fitted alone (Adam by hand), a learned background reproduces a
/// direction-dependent sky on held-out directions far better than the
/// best single colour could.
#[test]
fn fits_a_direction_dependent_background() {
    let b = Backdrop::new(
        &Background::Learned(LearnedBackground {
            freqs: 2,
            width: 16,
        }),
        0,
    );
    let mut params = vec![0.0; b.len()];
    b.init_into(1, &mut params);
    let (train, test) = (rays(512, 2), rays(256, 3));
    let (mut work, mut out) = (BackdropWork::default(), Vec::new());
    let (mut m, mut v) = (vec![0.0f32; b.len()], vec![0.0f32; b.len()]);
    let mse = |b: &Backdrop, p: &[f32], rays: &[Ray], work: &mut BackdropWork| {
        let mut out = Vec::new();
        b.colours(p, rays, work, &mut out);
        let e: f32 = rays
            .iter()
            .zip(&out)
            .map(|(r, c)| (0..3).map(|j| (c[j] - sky(r.dir)[j]).powi(2)).sum::<f32>())
            .sum();
        e / (3 * rays.len()) as f32
    };
    let before = mse(&b, &params, &test, &mut work);
    for step in 1..=600 {
        b.colours(&params, &train, &mut work, &mut out);
        let d: Vec<[f32; 3]> = train
            .iter()
            .zip(&out)
            .map(|(r, c)| {
                let s = sky(r.dir);
                std::array::from_fn(|j| 2.0 * (c[j] - s[j]) / (3 * train.len()) as f32)
            })
            .collect();
        let mut grad = vec![0.0; b.len()];
        b.backward(&params, &mut work, &d, &mut grad);
        let (b1, b2, lr) = (0.9f32, 0.999f32, 1e-2f32);
        for i in 0..params.len() {
            m[i] = b1 * m[i] + (1.0 - b1) * grad[i];
            v[i] = b2 * v[i] + (1.0 - b2) * grad[i] * grad[i];
            let mh = m[i] / (1.0 - b1.powi(step));
            let vh = v[i] / (1.0 - b2.powi(step));
            params[i] -= lr * mh / (vh.sqrt() + 1e-8);
        }
    }
    let after = mse(&b, &params, &test, &mut work);
    // The best constant colour's error: the sky's variance.
    let cols: Vec<[f32; 3]> = test.iter().map(|r| sky(r.dir)).collect();
    let variance: f32 = (0..3)
        .map(|j| {
            let mean = cols.iter().map(|c| c[j]).sum::<f32>() / cols.len() as f32;
            cols.iter().map(|c| (c[j] - mean).powi(2)).sum::<f32>()
        })
        .sum::<f32>()
        / (3 * cols.len()) as f32;
    assert!(
        after < variance / 20.0,
        "held-out MSE {before} → {after}; a constant: {variance}"
    );
}

/// A colour is the same for every ray and has nothing to train.
#[test]
fn a_colour_is_constant() {
    let b = Backdrop::new(&Background::Color([0.1, 0.2, 0.3]), 0);
    let mut out = Vec::new();
    b.colours(&[], &rays(5, 1), &mut BackdropWork::default(), &mut out);
    assert_eq!(out, vec![[0.1, 0.2, 0.3]; 5]);
    assert!(b.is_empty());
    let data = Backdrop::new(&Background::Data, 0);
    assert!(matches!(data, Backdrop::Color(c) if c == [0.0; 3]));
}
