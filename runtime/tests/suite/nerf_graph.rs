//! The fused NeRF kernels (the network's forward and backward passes, the
//! compositing and the MSE) against the same model written as a dfdx graph:
//! the same loss and the same gradient of every weight, for the
//! assignment's architecture in small (a skip layer, a view-dependent colour
//! branch, ReLU density, sigmoid colour) and over a background.

use dfdx::prelude::*;
use sdfl_runtime::neural::composite::squared_error_backward;
use sdfl_runtime::neural::mlp::{Activation, Dense};
use sdfl_runtime::neural::nerf::{NerfNet, NerfWork};
use sdfl_runtime::train::graph_ops::{again, weights_from_density, Traced2};
use sdfl_runtime::volume::SplitMix64;
use sdfl_stdlib::value::{DensityActivation, Encoding, Harmonic, Nerf};

type Flat = Tensor<(usize,), f32, Cpu, OwnedTape<f32, Cpu>>;

/// A `Dense` layer as graph ops on the flat parameter vector: each input
/// part times its rows of `W`, plus `b`, then the activation.
fn layer(params: &Flat, d: &Dense, inputs: Vec<Traced2>) -> Traced2 {
    let rows = inputs[0].shape().0;
    let n = d.out;
    let mut w_row = 0;
    let mut z: Option<Traced2> = None;
    for (x, &k) in inputs.into_iter().zip(&d.parts) {
        let at = d.offset + w_row * n;
        let w = again(params).slice((at..at + k * n,)).reshape_like(&(k, n));
        let term = x.matmul(w);
        z = Some(match z {
            None => term,
            Some(z) => z + term,
        });
        w_row += k;
    }
    let at = d.offset + d.fan_in() * n;
    let b = again(params)
        .slice((at..at + n,))
        .reshape_like(&(n,))
        .broadcast_like::<(usize, usize), Axis<0>>(&(rows, n));
    let z = z.expect("a layer has inputs") + b;
    match d.act {
        Activation::Identity => z,
        Activation::Relu => z.relu(),
        Activation::Sigmoid => z.sigmoid(),
        other => panic!("not in this test: {other:?}"),
    }
}

/// A constant input as a graph leaf (traced, so that it can meet traced
/// weights in a product; its own tape is empty).
fn leaf(dev: &Cpu, v: &[f32], cols: usize) -> Traced2 {
    dev.tensor_from_vec(v.to_vec(), (v.len() / cols, cols))
        .leaky_trace()
}

#[test]
#[allow(
    clippy::needless_range_loop,
    reason = "r picks the ray's slices of several buffers"
)]
fn fused_nerf_equals_the_dfdx_graph() {
    let spec = Nerf {
        position: Encoding::Harmonic(Harmonic {
            freqs: 3,
            include_input: true,
        }),
        direction: Some(Encoding::Harmonic(Harmonic {
            freqs: 2,
            include_input: true,
        })),
        layers: 3,
        width: 16,
        skips: vec![2],
        color_width: 8,
        fine: 0,
        background: sdfl_stdlib::value::Background::Color([0.2, 0.5, 0.9]),
        background_at: Default::default(),
        unbounded: None,
        seed: 4,
        density: DensityActivation::Relu,
        occupancy: None,
        precision: Default::default(),
    };
    let net = NerfNet::new(&spec);
    let mut params = net.init(spec.seed);
    // Lift the density head's bias so most samples are inside the ReLU's
    // live side and the opacities span 0..1.
    let db = net.density.offset + net.density.fan_in();
    params[db] = 0.6;
    let (rays, samples) = (6usize, 12usize);
    let mut rng = SplitMix64::new(21);
    let (mut points, mut dirs, mut t, mut delta, mut targets) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for _ in 0..rays {
        let d = [
            0.4 * (rng.next_f32() - 0.5),
            0.4 * (rng.next_f32() - 0.5),
            1.0,
        ];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let d = d.map(|x| x / len);
        for k in 0..samples {
            let tk = 1.0 + 2.0 * (k as f32 + rng.next_f32()) / samples as f32;
            t.push(tk);
            points.extend([d[0] * tk, d[1] * tk, -2.0 + d[2] * tk]);
            dirs.extend(d);
        }
        for k in 0..samples {
            let i = t.len() - samples + k;
            delta.push(if k + 1 < samples {
                t[i + 1] - t[i]
            } else {
                0.0
            });
        }
        targets.push([rng.next_f32(), rng.next_f32(), rng.next_f32()]);
    }
    let bg = spec.background.color().expect("a colour").map(|x| x as f32);

    // Fused: network forward, per-ray compositing and MSE backward,
    // network backward.
    let mut work = NerfWork::default();
    net.forward(&params, &points, &dirs, &mut work);
    let (mut d_sigma, mut d_rgb) = (vec![0.0; rays * samples], vec![0.0; 3 * rays * samples]);
    let scale = 1.0 / (3 * rays) as f32;
    let mut trans = Vec::new();
    let mut fused_loss = 0.0;
    for r in 0..rays {
        let k = r * samples..(r + 1) * samples;
        fused_loss += squared_error_backward(
            &work.sigma[k.clone()],
            &work.rgb[3 * k.start..3 * k.end],
            &t[k.clone()],
            &delta[k.clone()],
            bg,
            targets[r],
            scale,
            &mut d_sigma[k.clone()],
            &mut d_rgb[3 * k.start..3 * k.end],
            &mut trans,
        );
    }
    let live = work.sigma.iter().filter(|&&s| s > 0.0).count();
    assert!(
        live > rays * samples / 2,
        "most samples have density: {live}"
    );
    let mut fused = vec![0.0; params.len()];
    net.backward(
        &params,
        &points,
        &mut work,
        &mut d_sigma,
        &mut d_rgb,
        &mut fused,
    );

    // The graph: the same network, weights from densities (triangular
    // matmul for the cumulative sum), the background through what is left.
    let dev = Cpu::default();
    let x = dev.tensor_from_vec(params.clone(), (params.len(),));
    let flat: Flat = x.leaky_trace();
    let enc = leaf(&dev, &work.enc, net.position.width());
    let dir_width = net.direction.expect("view dependent").width();
    let dir_enc = leaf(&dev, &work.dir_enc, dir_width);
    let mut h: Option<Traced2> = None;
    for d in &net.trunk {
        let mut inputs = vec![h.take().unwrap_or_else(|| again(&enc))];
        if d.parts.len() == 2 {
            inputs.push(again(&enc));
        }
        h = Some(layer(&flat, d, inputs));
    }
    let h = h.expect("a trunk");
    let sigma = layer(&flat, &net.density, vec![again(&h)]).reshape_like(&(rays, samples));
    let feature = layer(
        &flat,
        net.feature.as_ref().expect("view dependent"),
        vec![h],
    );
    let hidden = layer(&flat, &net.color_hidden, vec![feature, dir_enc]);
    let rgb = layer(&flat, &net.color_out, vec![hidden]).reshape_like(&(rays, samples, 3usize));
    let delta_t = dev.tensor_from_vec(delta.clone(), (rays, samples));
    let left = (-(again(&sigma) * delta_t.clone()).sum::<(usize,), Axis<1>>()).exp();
    let w = weights_from_density(sigma, &delta_t).unwrap();
    let colour = (w.broadcast_like::<(usize, usize, usize), Axis<2>>(&(rays, samples, 3)) * rgb)
        .sum::<(usize, usize), Axis<1>>()
        + left.broadcast_like::<(usize, usize), Axis<1>>(&(rays, 3))
            * dev
                .tensor_from_vec(bg.to_vec(), (3usize,))
                .broadcast_like::<(usize, usize), Axis<0>>(&(rays, 3));
    let target: Vec<f32> = targets.iter().flatten().copied().collect();
    let loss = (colour - dev.tensor_from_vec(target, (rays, 3usize)))
        .square()
        .mean();
    let graph_loss = loss.array() as f64;
    let grads = loss.backward();
    let graph = grads.get(&x).as_vec();

    assert!(
        (fused_loss - graph_loss).abs() <= 1e-5 * graph_loss.abs(),
        "loss: fused {fused_loss} vs graph {graph_loss}"
    );
    let biggest = graph.iter().fold(0f32, |m, g| m.max(g.abs()));
    assert!(biggest > 1e-3, "the gradient is not trivial: {biggest}");
    let mut checked = 0;
    for (name, d) in net.layers() {
        for i in d.offset..d.end() {
            let (a, b) = (fused[i], graph[i]);
            assert!(
                (a - b).abs() <= 1e-6 * biggest + 1e-3 * b.abs(),
                "{name} parameter {}: fused {a} vs graph {b}",
                i - d.offset
            );
            checked += (b.abs() > 1e-6) as usize;
        }
    }
    assert!(checked > params.len() / 2, "{checked} of {}", params.len());
}
