//! Dense layers against f64 and finite differences (both product kernels),
//! thread-count invariance, bf16 against fp32, softplus against f64 and
//! its scalar formula, extremes, initialisation.

use sdfl_runtime::neural::mlp::*;
use sdfl_runtime::neural::{bf16, fp32};
use sdfl_runtime::volume::SplitMix64;
use sdfl_stdlib::value::Precision;

/// The layer in f64, textbook loops.
fn reference(layer: &Dense, params: &[f32], inputs: &[&[f32]], rows: usize) -> Vec<f64> {
    let n = layer.out;
    (0..rows * n)
        .map(|e| reference_at(layer, params, inputs, e / n, e % n))
        .collect()
}

/// Output `j` of row `r`, in f64.
fn reference_at(layer: &Dense, params: &[f32], inputs: &[&[f32]], r: usize, j: usize) -> f64 {
    let n = layer.out;
    let fan_in = layer.fan_in();
    let w = &params[layer.offset..];
    let mut z = params[layer.offset + fan_in * n + j] as f64;
    let mut i = 0;
    for (x, &k) in inputs.iter().zip(&layer.parts) {
        for c in 0..k {
            z += x[r * k + c] as f64 * w[(i + c) * n + j] as f64;
        }
        i += k;
    }
    match layer.act {
        Activation::Identity => z,
        Activation::Relu => z.max(0.0),
        Activation::Sigmoid => 1.0 / (1.0 + (-z).exp()),
        Activation::Exp => z.min(EXP_CAP as f64).exp(),
        Activation::Softplus { beta } => {
            let b = beta as f64;
            (1.0 + (b * z).exp()).ln() / b
        }
    }
}

fn random(n: usize, rng: &mut SplitMix64) -> Vec<f32> {
    (0..n).map(|_| 2.0 * rng.next_f32() - 1.0).collect()
}

/// Layers of every kind, their products run by each kernel this CPU
/// has (the portable one always).
fn layers() -> Vec<Dense> {
    let shapes = [
        Dense::new(&[7], 5, Activation::Relu, 3),
        Dense::new(&[6, 4], 9, Activation::Sigmoid, 0),
        Dense::new(&[33], 17, Activation::Softplus { beta: 10.0 }, 1),
        Dense::new(&[4], 3, Activation::Exp, 0),
        Dense::new(&[5, 2, 3], 1, Activation::Identity, 0),
        Dense::new(&[20, 13], 40, Activation::Softplus { beta: 100.0 }, 2),
    ];
    product_kinds()
        .into_iter()
        .flat_map(|p| shapes.iter().map(move |d| d.clone().with_products(p)))
        .collect()
}

/// The portable products, and the native ones where this CPU runs them.
fn product_kinds() -> Vec<Products> {
    let mut kinds = vec![Products::Portable];
    if fp32::available() {
        kinds.push(Products::Native);
    }
    kinds
}

#[test]
fn forward_matches_f64_reference() {
    let mut rng = SplitMix64::new(1);
    for layer in layers() {
        // More rows than one block, not a multiple of it.
        let rows = ROW_BLOCK * 2 + 37;
        let mut params = vec![0.0; layer.end()];
        layer.init(&mut params, &mut rng);
        let xs: Vec<Vec<f32>> = layer
            .parts
            .iter()
            .map(|&k| random(rows * k, &mut rng))
            .collect();
        let inputs: Vec<&[f32]> = xs.iter().map(|x| x.as_slice()).collect();
        let mut out = vec![0.0; rows * layer.out];
        layer.forward(&params, &inputs, &mut out);
        let want = reference(&layer, &params, &inputs, rows);
        for (a, b) in out.iter().zip(&want) {
            assert!((*a as f64 - b).abs() < 1e-5, "{layer:?}: {a} vs {b}");
        }
    }
}

/// The part of the loss `Σ c ⊙ out` (fixed random `c`, in f64) that
/// output column `j` holds: all a weight or bias of that column moves.
fn column_loss(
    layer: &Dense,
    params: &[f32],
    inputs: &[&[f32]],
    c: &[f32],
    rows: usize,
    j: usize,
) -> f64 {
    (0..rows)
        .map(|r| reference_at(layer, params, inputs, r, j) * c[r * layer.out + j] as f64)
        .sum()
}

/// The part of the loss that row `r` holds: all its inputs move.
fn row_loss(layer: &Dense, params: &[f32], inputs: &[&[f32]], c: &[f32], r: usize) -> f64 {
    (0..layer.out)
        .map(|j| reference_at(layer, params, inputs, r, j) * c[r * layer.out + j] as f64)
        .sum()
}

#[test]
fn backward_matches_finite_differences() {
    let mut rng = SplitMix64::new(2);
    for layer in layers() {
        // Few rows for ReLU, so that most columns keep clear of the kink.
        let rows = if layer.act == Activation::Relu {
            6
        } else {
            300
        };
        let mut params = vec![0.0; layer.end()];
        layer.init(&mut params, &mut rng);
        let mut xs: Vec<Vec<f32>> = layer
            .parts
            .iter()
            .map(|&k| random(rows * k, &mut rng))
            .collect();
        let c = random(rows * layer.out, &mut rng);
        let inputs: Vec<&[f32]> = xs.iter().map(|x| x.as_slice()).collect();
        let mut out = vec![0.0; rows * layer.out];
        layer.forward(&params, &inputs, &mut out);
        // Pre-activations, for the kink test below.
        let pre: Vec<f32> = reference(
            &Dense {
                act: Activation::Identity,
                ..layer.clone()
            },
            &params,
            &inputs,
            rows,
        )
        .iter()
        .map(|&z| z as f32)
        .collect();
        let mut d_out = c.clone();
        let mut dxs: Vec<Vec<f32>> = xs.iter().map(|x| vec![0.5; x.len()]).collect();
        let mut grad = vec![0.25; params.len()];
        {
            let mut d_in: Vec<Option<&mut [f32]>> =
                dxs.iter_mut().map(|d| Some(d.as_mut_slice())).collect();
            layer.backward(
                &params, &inputs, &out, &mut d_out, &mut d_in, true, &mut grad,
            );
        }
        let h = 1e-3f32;
        // A ReLU's kink inside ±h makes the difference quotient
        // meaningless: skip entries whose pre-activations come that
        // close to 0 (they are few; the rest must match).
        let n = layer.out;
        let fan_in = layer.fan_in();
        let margin = |zs: Vec<f32>, scale: f32| {
            layer.act != Activation::Relu || zs.iter().all(|z| z.abs() > 4.0 * h * scale)
        };
        let max_x = xs.iter().flatten().fold(0f32, |m, v| m.max(v.abs())) + 1.0;
        let max_w = params.iter().fold(0f32, |m, v| m.max(v.abs()));
        let mut checked = 0;
        // Every parameter of this layer; those before its offset untouched.
        // A weight or bias moves only its own column's outputs, so the
        // difference quotient is taken on that column's part of the loss.
        for i in 0..params.len() {
            if i < layer.offset {
                assert_eq!(grad[i], 0.25, "{layer:?} param {i} is not the layer's");
                checked += 1;
                continue;
            }
            let col = if i < layer.offset + fan_in * n {
                (i - layer.offset) % n
            } else {
                i - layer.offset - fan_in * n
            };
            if !margin((0..rows).map(|r| pre[r * n + col]).collect(), max_x) {
                continue;
            }
            checked += 1;
            let fd = {
                let mut p = params.clone();
                p[i] += h;
                let up = column_loss(&layer, &p, &inputs, &c, rows, col);
                p[i] -= 2.0 * h;
                let down = column_loss(&layer, &p, &inputs, &c, rows, col);
                (up - down) / (2.0 * h as f64)
            };
            let got = grad[i] as f64 - 0.25;
            assert!(
                (got - fd).abs() < 2e-3 * (1.0 + fd.abs()),
                "{layer:?} param {i}: {got} vs {fd}"
            );
        }
        assert!(
            checked * 10 > params.len() * 8,
            "{layer:?}: {checked} of {}",
            params.len()
        );
        // A sample of input entries, accumulated onto 0.5.
        for p in 0..xs.len() {
            let k = layer.parts[p];
            for i in (0..xs[p].len()).step_by(37) {
                let r = i / k;
                if !margin(
                    (0..n).map(|j| pre[r * n + j]).collect(),
                    max_w * fan_in as f32,
                ) {
                    continue;
                }
                let orig = xs[p][i];
                // An input moves only its own row's outputs.
                xs[p][i] = orig + h;
                let up = row_loss(
                    &layer,
                    &params,
                    &xs.iter().map(|x| x.as_slice()).collect::<Vec<_>>(),
                    &c,
                    r,
                );
                xs[p][i] = orig - h;
                let down = row_loss(
                    &layer,
                    &params,
                    &xs.iter().map(|x| x.as_slice()).collect::<Vec<_>>(),
                    &c,
                    r,
                );
                xs[p][i] = orig;
                let fd = (up - down) / (2.0 * h as f64);
                let got = dxs[p][i] as f64 - 0.5;
                assert!(
                    (got - fd).abs() < 2e-3 * (1.0 + fd.abs()),
                    "{layer:?} x{p}[{i}]: {got} vs {fd}"
                );
            }
        }
    }
}

#[test]
fn backward_is_identical_at_any_thread_count() {
    for products in product_kinds() {
        let layer = Dense::new(&[40, 8], 24, Activation::Relu, 0).with_products(products);
        backward_is_identical_at_1_and_3_threads(&layer);
    }
}

fn backward_is_identical_at_1_and_3_threads(layer: &Dense) {
    let rows = 3000;
    let mut rng = SplitMix64::new(3);
    let mut params = vec![0.0; layer.end()];
    layer.init(&mut params, &mut rng);
    let xs: Vec<Vec<f32>> = layer
        .parts
        .iter()
        .map(|&k| random(rows * k, &mut rng))
        .collect();
    let c = random(rows * layer.out, &mut rng);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let inputs: Vec<&[f32]> = xs.iter().map(|x| x.as_slice()).collect();
            let mut out = vec![0.0; rows * layer.out];
            layer.forward(&params, &inputs, &mut out);
            let mut d_out = c.clone();
            let mut dx = vec![0.0; rows * 40];
            let mut grad = vec![0.0; params.len()];
            let mut d_in = vec![Some(dx.as_mut_slice()), None];
            layer.backward(
                &params, &inputs, &out, &mut d_out, &mut d_in, false, &mut grad,
            );
            (out, dx, grad)
        })
    };
    assert_eq!(run(1), run(3));
}

/// A bf16 layer: its forward, input adjoints and weight gradient close
/// to fp32's (the kernel's own bounds are tested in `bf16`), and
/// bit-identical at 1 and 2 threads. Without
/// AVX-512 BF16 it is the fp32 layer, bit for bit.
#[test]
fn bf16_layer_is_near_fp32_at_any_thread_count() {
    // A 40-wide part in bf16, an 8-wide one in fp32; 3000 rows and 24
    // outputs, multiples of neither the tile nor the block.
    let fp32 = Dense::new(&[40, 8], 24, Activation::Relu, 0);
    let bf = fp32.clone().with_precision(Precision::Bf16);
    let rows = 3000;
    let mut rng = SplitMix64::new(4);
    let mut params = vec![0.0; fp32.end()];
    fp32.init(&mut params, &mut rng);
    let xs: Vec<Vec<f32>> = [40, 8]
        .iter()
        .map(|&k| random(rows * k, &mut rng))
        .collect();
    let c = random(rows * 24, &mut rng);
    let run = |layer: &Dense, threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let inputs: Vec<&[f32]> = xs.iter().map(|x| x.as_slice()).collect();
            let mut out = vec![0.0; rows * 24];
            layer.forward(&params, &inputs, &mut out);
            // The adjoint is fixed, so that the gradients compare.
            let dz = c.clone();
            let mut dx = vec![0.0; rows * 40];
            let mut grad = vec![0.0; params.len()];
            layer.pull_back(&params, &dz, &mut [Some(dx.as_mut_slice()), None], false);
            layer.weight_gradient(&inputs, &dz, &mut grad);
            (out, dx, grad)
        })
    };
    let (want, got) = (run(&fp32, 1), run(&bf, 1));
    assert_eq!(got, run(&bf, 2));
    if !bf16::available() {
        assert_eq!(got, want);
    }
    let near = |a: &[f32], b: &[f32], what: &str| {
        let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-2 * scale, "{what}: {x} vs {y}");
        }
    };
    near(&got.0, &want.0, "forward");
    near(&got.1, &want.1, "input adjoint");
    near(&got.2, &want.2, "weight gradient");
}

/// The layer pass (AVX-512, AVX2 or SSE, whichever runs here) is the
/// scalar formula bit for bit, with or without slopes, and both are
/// within a few ulp of f64.
#[test]
fn softplus_layer_is_the_scalar_formula_and_near_f64() {
    let beta = 100.0f32;
    let z: Vec<f32> = (-3000..=3000)
        .map(|i| i as f32 * 7e-4)
        .chain([0.0, -0.0, 1e-30, -1e-30, 1e30, -1e30, 3e36, -3e36])
        .collect();
    let (mut y, mut s) = (z.clone(), vec![0.0; z.len()]);
    softplus_layer(&mut y, Some(&mut s), beta);
    let mut y_alone = z.clone();
    softplus_layer(&mut y_alone, None, beta);
    for (i, &zi) in z.iter().enumerate() {
        let (ys, ss) = softplus_and_slope(zi, beta);
        assert_eq!(
            (y[i].to_bits(), s[i].to_bits(), y_alone[i].to_bits()),
            (ys.to_bits(), ss.to_bits(), ys.to_bits()),
            "at {zi}"
        );
        // βz as the kernel forms it: its f32 rounding moves e^{−|βz|}
        // by up to |βz|·2^-24 relative, which no formula after can undo.
        let x = (beta * zi) as f64;
        let want = (x.max(0.0) + (-x.abs()).exp().ln_1p()) / beta as f64;
        let slope = 1.0 / (1.0 + (-x).exp());
        assert!(
            // Below f32's normal range the value underflows, as it should.
            (y[i] as f64 - want).abs() <= 4.0 * f32::EPSILON as f64 * want + 1.2e-38,
            "softplus({zi}) = {} vs {want}",
            y[i]
        );
        assert!(
            (s[i] as f64 - slope).abs() <= 2.0 * f32::EPSILON as f64 * slope + 1.2e-38,
            "slope({zi}) = {} vs {slope}",
            s[i]
        );
    }
}

#[test]
fn activations_are_finite_at_extremes() {
    for z in [-1e30f32, -100.0, -1e-30, 0.0, 1e-30, 100.0, 1e30] {
        for act in [
            Activation::Relu,
            Activation::Sigmoid,
            Activation::Softplus { beta: 100.0 },
        ] {
            let y = act.apply(z);
            let s = act.slope(y);
            assert!(y.is_finite() && s.is_finite(), "{act:?} at {z}: {y}, {s}");
            assert!((0.0..=1.0).contains(&s));
        }
    }
    assert_eq!(sigmoid(-1e30), 0.0);
    assert_eq!(sigmoid(1e30), 1.0);
    assert!((softplus(0.0, 100.0) - std::f32::consts::LN_2 / 100.0).abs() < 1e-9);
}

#[test]
fn init_is_pytorchs_bound_and_seeded() {
    let layer = Dense::new(&[100], 50, Activation::Relu, 0);
    let mut a = vec![0.0; layer.end()];
    let mut b = vec![0.0; layer.end()];
    layer.init(&mut a, &mut SplitMix64::new(9));
    layer.init(&mut b, &mut SplitMix64::new(9));
    assert_eq!(a, b);
    assert!(a.iter().all(|v| v.abs() <= 0.1));
    assert!(a.iter().any(|v| v.abs() > 0.09));
}
