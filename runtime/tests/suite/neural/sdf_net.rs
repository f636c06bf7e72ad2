//! The neural SDF against an f64 reference and finite differences, its
//! extreme inputs, geometric initialisation, thread-count invariance, a
//! short fit and the timing of a step.

use sdfl_runtime::neural::encoding::Harmonic;
use sdfl_runtime::neural::mlp::Dense;
use sdfl_runtime::neural::sdf_net::*;
use sdfl_runtime::volume::SplitMix64;

fn small(beta: f32) -> SdfNetSpec {
    SdfNetSpec {
        freqs: 2,
        include_input: true,
        layers: 3,
        width: 12,
        skips: vec![2],
        beta,
    }
}

fn points(n: usize, scale: f32, rng: &mut SplitMix64) -> Vec<f32> {
    (0..3 * n)
        .map(|_| scale * (2.0 * rng.next_f32() - 1.0))
        .collect()
}

fn to64(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

fn softplus64(z: f64, beta: f64) -> f64 {
    let x = beta * z;
    (x.max(0.0) + (-x.abs()).exp().ln_1p()) / beta
}

/// `f` and `∇f` at one point in f64, from the definitions: the encoding
/// and its Jacobian written out, each layer's tangents by the chain rule.
fn reference(net: &SdfNet, params: &[f64], x: [f64; 3]) -> (f64, [f64; 3]) {
    let h = net.encoding;
    let (f, e) = (h.freqs, h.width());
    let mut enc = vec![0.0; e];
    let mut jac = vec![[0.0; 3]; e];
    for i in 0..3 {
        for k in 0..f {
            let s = 2f64.powi(k as i32);
            enc[i * f + k] = (s * x[i]).sin();
            jac[i * f + k][i] = s * (s * x[i]).cos();
            enc[3 * f + i * f + k] = (s * x[i]).cos();
            jac[3 * f + i * f + k][i] = -s * (s * x[i]).sin();
        }
        if h.include_input {
            enc[6 * f + i] = x[i];
            jac[6 * f + i][i] = 1.0;
        }
    }
    let beta = net.beta as f64;
    let layer = |d: &Dense, v: &[f64], t: &[[f64; 3]], smooth: bool| {
        let (k, n) = (d.fan_in(), d.out);
        assert_eq!(v.len(), k);
        let mut nv = vec![0.0; n];
        let mut nt = vec![[0.0; 3]; n];
        for j in 0..n {
            let mut z = params[d.offset + k * n + j];
            let mut zt = [0.0; 3];
            for i in 0..k {
                let w = params[d.offset + i * n + j];
                z += v[i] * w;
                for a in 0..3 {
                    zt[a] += t[i][a] * w;
                }
            }
            let s = if smooth {
                1.0 / (1.0 + (-beta * z).exp())
            } else {
                1.0
            };
            nv[j] = if smooth { softplus64(z, beta) } else { z };
            for a in 0..3 {
                nt[j][a] = s * zt[a];
            }
        }
        (nv, nt)
    };
    let (mut v, mut t) = (enc.clone(), jac.clone());
    for d in &net.hidden {
        if d.parts.len() == 2 {
            v.extend_from_slice(&enc);
            t.extend_from_slice(&jac);
        }
        (v, t) = layer(d, &v, &t, true);
    }
    let (o, ot) = layer(&net.output, &v, &t, false);
    (o[0], ot[0])
}

fn at(p: &[f32]) -> [f64; 3] {
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

/// The loss of [`SdfNet::loss_and_grad`] in f64 through [`reference`].
fn reference_loss(
    net: &SdfNet,
    params: &[f64],
    surface: &[f32],
    random: &[f32],
    w: &SdfLoss,
) -> f64 {
    let eval = |pts: &[f32]| -> Vec<(f64, [f64; 3])> {
        pts.chunks(3)
            .map(|p| reference(net, params, at(p)))
            .collect()
    };
    let (s, r) = (eval(surface), eval(random));
    let (ns, nr) = (s.len() as f64, r.len() as f64);
    let eik = s
        .iter()
        .chain(&r)
        .map(|(_, g)| ((g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt() - 1.0).powi(2))
        .sum::<f64>()
        / (ns + nr);
    let alpha = w.alpha as f64;
    w.surface as f64 * s.iter().map(|(f, _)| f.abs()).sum::<f64>() / ns
        + w.inter as f64 * r.iter().map(|(f, _)| (-alpha * f.abs()).exp()).sum::<f64>() / nr
        + w.eikonal as f64 * eik
}

/// Specs and initial parameters covering the paths: skips, no raw
/// input, two skips, both initialisations.
fn cases() -> Vec<(SdfNet, Vec<f32>)> {
    let mut v = Vec::new();
    for spec in [
        small(100.0),
        SdfNetSpec {
            include_input: false,
            skips: vec![1, 2],
            ..small(30.0)
        },
        SdfNetSpec::default(),
    ] {
        let net = SdfNet::new(&spec);
        v.push((net.clone(), net.init_default(3)));
        if spec.include_input {
            v.push((net.clone(), net.init_geometric(4, 0.5)));
        }
    }
    v
}

#[test]
fn forward_matches_f64_reference() {
    let mut rng = SplitMix64::new(1);
    for (net, params) in cases() {
        // More points than a block, not a multiple of it.
        let rows = if net.width() > 32 { 300 } else { 600 };
        let pts = points(rows, 1.0, &mut rng);
        let mut work = SdfWork::default();
        net.forward(&params, &pts, &mut work);
        let p64 = to64(&params);
        let close = |a: f32, b: f64| (a as f64 - b).abs() <= 1e-4 * (1.0 + b.abs());
        for (r, p) in pts.chunks(3).enumerate() {
            let (f, g) = reference(&net, &p64, at(p));
            let got = work.distance()[r];
            assert!(close(got, f), "{:?} f at {p:?}: {got} vs {f}", net.encoding);
            for (j, &want) in g.iter().enumerate() {
                let got = work.gradient()[3 * r + j];
                assert!(close(got, want), "∇f_{j} at {p:?}: {got} vs {want}");
            }
        }
    }
}

#[test]
fn distance_alone_equals_forward() {
    let mut rng = SplitMix64::new(5);
    for (net, params) in cases() {
        let pts = points(1500, 1.0, &mut rng);
        let mut work = SdfWork::default();
        net.forward(&params, &pts, &mut work);
        let mut alone = vec![0.0; 1500];
        net.distance(&params, &pts, &mut alone);
        assert_eq!(alone, work.distance(), "same operations, same order");
    }
}

#[test]
fn input_gradient_matches_central_differences() {
    let mut rng = SplitMix64::new(2);
    for (net, params) in cases() {
        let pts = points(60, 1.0, &mut rng);
        let mut work = SdfWork::default();
        net.forward(&params, &pts, &mut work);
        let p64 = to64(&params);
        for (r, p) in pts.chunks(3).enumerate() {
            for j in 0..3 {
                let h = 1e-5;
                let (mut up, mut down) = (at(p), at(p));
                up[j] += h;
                down[j] -= h;
                let fd = (reference(&net, &p64, up).0 - reference(&net, &p64, down).0) / (2.0 * h);
                let got = work.gradient()[3 * r + j] as f64;
                assert!(
                    (got - fd).abs() <= 1e-3 * (1.0 + fd.abs()),
                    "∂f/∂x_{j} at {p:?}: {got} vs {fd}"
                );
            }
        }
    }
}

#[test]
fn encoding_pushforward_is_the_transpose_of_its_backward() {
    let h = Harmonic {
        dims: 3,
        freqs: 4,
        include_input: true,
    };
    let e = h.width();
    let mut rng = SplitMix64::new(3);
    let pts = points(5, 2.0, &mut rng);
    let g = points(5 * e, 1.0, &mut rng);
    let v = points(5, 1.0, &mut rng);
    let mut jv = vec![f32::NAN; 5 * e];
    encode_pushforward(&h, &pts, &v, &mut jv);
    let mut dx = vec![0.0; 15];
    h.backward(&pts, &g[..5 * e], &mut dx);
    // ⟨J·v, g⟩ = ⟨v, Jᵀ·g⟩ row by row.
    for r in 0..5 {
        let left: f32 = jv[r * e..(r + 1) * e]
            .iter()
            .zip(&g[r * e..])
            .map(|(a, b)| a * b)
            .sum();
        let right: f32 = (0..3).map(|j| v[3 * r + j] * dx[3 * r + j]).sum();
        assert!((left - right).abs() < 1e-4, "{left} vs {right}");
    }
}

/// The loss's gradient is a second derivative (of `∇f`); checked for
/// every parameter against central differences of the f64 loss.
#[test]
fn loss_gradient_matches_finite_differences() {
    let eikonal_only = SdfLoss {
        surface: 0.0,
        eikonal: 1.0,
        inter: 0.0,
        ..SdfLoss::default()
    };
    let strong_inter = SdfLoss {
        inter: 1.0,
        alpha: 5.0,
        ..SdfLoss::default()
    };
    let nets = [small(100.0), small(10.0)].map(|s| SdfNet::new(&s));
    let two_skips = SdfNet::new(&SdfNetSpec {
        skips: vec![1, 2],
        ..small(20.0)
    });
    let cases = [
        (&nets[0], nets[0].init_default(5), SdfLoss::default()),
        (&nets[1], nets[1].init_geometric(5, 0.5), strong_inter),
        (&nets[1], nets[1].init_default(6), eikonal_only),
        (&two_skips, two_skips.init_default(7), eikonal_only),
    ];
    let mut rng = SplitMix64::new(4);
    for (case, (net, params, weights)) in cases.into_iter().enumerate() {
        let surface = points(20, 0.8, &mut rng);
        let random = points(20, 1.0, &mut rng);
        let mut work = SdfWork::default();
        let mut grad = vec![f32::NAN; net.len];
        let loss = net.loss_and_grad(&params, &surface, &random, &weights, &mut work, &mut grad);
        let p64 = to64(&params);
        let want = reference_loss(net, &p64, &surface, &random, &weights);
        assert!((loss - want).abs() < 1e-4 * want.abs(), "{loss} vs {want}");
        let fd: Vec<f64> = (0..net.len)
            .map(|i| {
                let h = 1e-6;
                let mut p = p64.clone();
                p[i] += h;
                let up = reference_loss(net, &p, &surface, &random, &weights);
                p[i] -= 2.0 * h;
                let down = reference_loss(net, &p, &surface, &random, &weights);
                (up - down) / (2.0 * h)
            })
            .collect();
        let max = fd.iter().fold(0f64, |m, v| m.max(v.abs()));
        let mut worst = 0f64;
        for (name, d) in net.layers() {
            for i in d.offset..d.end() {
                let err = (grad[i] as f64 - fd[i]).abs();
                worst = worst.max(err / (fd[i].abs() + 1e-4 * max));
                assert!(
                    err <= 1e-2 * fd[i].abs() + 1e-5 * max,
                    "case {case}, {name} param {i}: {} vs {}",
                    grad[i],
                    fd[i]
                );
            }
        }
        println!("case {case}: worst relative error {worst:.1e}");
        if weights.surface == 0.0 && weights.inter == 0.0 {
            // ∇f reaches a hidden bias only through act'' (the slope
            // s(z) depends on it, the tangents z' do not), so these
            // gradients are wholly the act'' term: a wrong act'' fails
            // them. Make sure they are large enough to matter.
            for d in &net.hidden {
                let bias = &fd[d.offset + d.fan_in() * d.out..d.end()];
                let big = bias.iter().filter(|v| v.abs() > 1e-2 * max).count();
                assert!(
                    big * 3 >= bias.len(),
                    "case {case}: {big} of {}",
                    bias.len()
                );
            }
            // and not at all the output's bias.
            assert_eq!(grad[net.output.end() - 1], 0.0);
        }
    }
}

#[test]
fn losses_are_finite_at_zero_and_huge_values() {
    let g = [
        0.0,
        0.0,
        0.0,
        1e30,
        -1e30,
        1e30,
        f32::MAX,
        f32::MAX,
        -f32::MAX,
        0.6,
        0.8,
        0.0,
    ];
    let mut d = [f32::NAN; 12];
    let loss = eikonal_loss(&g, 1.0, &mut d);
    assert!(loss.is_finite() && loss >= 0.25, "{loss}");
    assert!(d.iter().all(|v| v.is_finite()), "{d:?}");
    assert_eq!(&d[..3], &[0.0; 3]);
    assert!(d[9..].iter().all(|v| v.abs() < 1e-6), "{d:?}");
    let f = [0.0, 1e-30, -1e30, f32::MAX, -f32::MAX, f32::MIN_POSITIVE];
    let mut d = [f32::NAN; 6];
    assert!(surface_loss(&f, 1.0, &mut d).is_finite());
    assert!(d.iter().all(|v| v.is_finite()) && d[0] == 0.0);
    let mut d = [f32::NAN; 6];
    assert!(off_surface_loss(&f, 1.0, 100.0, &mut d).is_finite());
    assert!(d.iter().all(|v| v.is_finite()) && d[0] == 0.0);
    // A whole step at far and tiny points.
    let net = SdfNet::new(&small(100.0));
    let params = net.init_geometric(1, 0.5);
    let surface = [1e30, -1e30, 1e30, 0.0, 0.0, 0.0, 1e-30, 0.0, -1e-30];
    let random = [-1e30, 0.0, 1e20, 0.5, 0.0, 0.0];
    let mut work = SdfWork::default();
    let mut grad = vec![f32::NAN; net.len];
    let loss = net.loss_and_grad(
        &params,
        &surface,
        &random,
        &SdfLoss::default(),
        &mut work,
        &mut grad,
    );
    assert!(loss.is_finite(), "{loss}");
    assert!(grad.iter().all(|v| v.is_finite()));
    // Empty batches are no loss at all.
    let loss = net.loss_and_grad(&params, &[], &[], &SdfLoss::default(), &mut work, &mut grad);
    assert_eq!(loss, 0.0);
    assert!(grad.iter().all(|&v| v == 0.0));
}

#[test]
fn identical_at_one_and_two_threads() {
    let net = SdfNet::new(&SdfNetSpec {
        freqs: 3,
        layers: 4,
        width: 40,
        skips: vec![2],
        ..SdfNetSpec::default()
    });
    let params = net.init_default(8);
    let mut rng = SplitMix64::new(5);
    let (surface, random) = (points(700, 0.8, &mut rng), points(650, 1.0, &mut rng));
    let (big_s, big_r) = (points(900, 0.8, &mut rng), points(900, 1.0, &mut rng));
    let run = |threads: usize, warm: bool| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut work = SdfWork::default();
            let mut grad = vec![0.0; net.len];
            let w = SdfLoss::default();
            if warm {
                // A reused work that held a larger batch leaves no trace.
                net.loss_and_grad(&params, &big_s, &big_r, &w, &mut work, &mut grad);
            }
            let loss = net.loss_and_grad(&params, &surface, &random, &w, &mut work, &mut grad);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            (
                loss.to_bits(),
                bits(&grad),
                bits(work.distance()),
                bits(work.gradient()),
            )
        })
    };
    let one = run(1, false);
    assert_eq!(one, run(2, false));
    assert_eq!(one, run(2, true));
}

/// Points in uniform directions at radii `r0..r1`.
pub(super) fn shell(n: usize, r0: f32, r1: f32, rng: &mut SplitMix64) -> Vec<f32> {
    let mut v = Vec::with_capacity(3 * n);
    for _ in 0..n {
        let d = [normal(rng), normal(rng), normal(rng)];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let r = (r0 + (r1 - r0) * rng.next_f32()) as f64;
        v.extend(d.iter().map(|c| (c / len * r) as f32));
    }
    v
}

#[test]
fn geometric_init_is_close_to_a_sphere() {
    let net = SdfNet::new(&SdfNetSpec::default());
    let radius = 0.5;
    let pts = shell(2000, 0.3, 0.7, &mut SplitMix64::new(6));
    // Over the shell: mean and largest |f − (|x| − r)|, mean |‖∇f‖ − 1|,
    // mean 1 − cos(∇f, x), and the share of points farther than 0.15
    // from the sphere on the wrong side of f's zero set.
    let errors = |params: &[f32]| {
        let mut work = SdfWork::default();
        net.forward(params, &pts, &mut work);
        let mut e = [0f32; 5];
        for (r, p) in pts.chunks(3).enumerate() {
            let len = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            let g = &work.gradient()[3 * r..3 * r + 3];
            let gl = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
            let cos = (g[0] * p[0] + g[1] * p[1] + g[2] * p[2]) / (gl * len);
            let (f, want) = (work.distance()[r], len - radius);
            e[0] += (f - want).abs();
            e[1] = e[1].max((f - want).abs());
            e[2] += (gl - 1.0).abs();
            e[3] += 1.0 - cos;
            e[4] += (want.abs() > 0.15 && f * want <= 0.0) as u8 as f32;
        }
        let n = (pts.len() / 3) as f32;
        [e[0] / n, e[1], e[2] / n, e[3] / n, e[4] / n]
    };
    for seed in 0..4 {
        let e = errors(&net.init_geometric(seed, radius));
        println!("geometric init, seed {seed}: {e:?}");
        assert!(
            e[0] < 0.12 && e[1] < 0.5 && e[2] < 0.35 && e[3] < 0.12 && e[4] < 0.05,
            "seed {seed}: {e:?}"
        );
    }
    let e = errors(&net.init_default(0));
    println!("default init: {e:?}");
    assert!(e[2] > 0.5 && e[3] > 0.5, "{e:?}");
}

#[test]
fn backward_from_given_adjoints_is_loss_and_grads() {
    let net = SdfNet::new(&small(100.0));
    let params = net.init_default(10);
    let mut rng = SplitMix64::new(11);
    let (surface, random) = (points(30, 0.8, &mut rng), points(20, 1.0, &mut rng));
    let w = SdfLoss::default();
    let mut work = SdfWork::default();
    let mut want = vec![0.0; net.len];
    let loss = net.loss_and_grad(&params, &surface, &random, &w, &mut work, &mut want);
    let all: Vec<f32> = surface.iter().chain(&random).copied().collect();
    net.forward(&params, &all, &mut work);
    let (f, g) = (work.distance().to_vec(), work.gradient().to_vec());
    let (mut d_f, mut d_g) = (vec![0.0; 50], vec![0.0; 150]);
    let again = surface_loss(&f[..30], w.surface, &mut d_f[..30])
        + off_surface_loss(&f[30..], w.inter, w.alpha, &mut d_f[30..])
        + eikonal_loss(&g, w.eikonal, &mut d_g);
    assert_eq!(loss, again);
    // Added to what the gradient holds.
    let mut grad = vec![1.0; net.len];
    net.backward(&params, &d_f, &d_g, &mut work, &mut grad);
    for (a, b) in grad.iter().zip(&want) {
        assert_eq!(*a, 1.0 + b);
    }
}

/// End to end: Adam on the loss fits a cube's surface from a sphere.
#[test]
fn training_fits_a_cube() {
    let net = SdfNet::new(&SdfNetSpec {
        freqs: 2,
        layers: 3,
        width: 32,
        skips: vec![2],
        ..SdfNetSpec::default()
    });
    let mut params = net.init_geometric(1, 0.4);
    let mut rng = SplitMix64::new(12);
    // Points on the faces of [-0.4, 0.4]³.
    let surface: Vec<f32> = (0..512)
        .flat_map(|i| {
            let mut p = [0.8 * rng.next_f32() - 0.4, 0.8 * rng.next_f32() - 0.4, 0.0];
            p[2] = if i % 2 == 0 { 0.4 } else { -0.4 };
            p.rotate_left(i % 3);
            p
        })
        .collect();
    let random = points(512, 1.0, &mut rng);
    let w = SdfLoss::default();
    let mut work = SdfWork::default();
    let mut grad = vec![0.0; net.len];
    let (mut m, mut v) = (vec![0.0f32; net.len], vec![0.0f32; net.len]);
    let (lr, b1, b2) = (1e-3f32, 0.9f32, 0.999f32);
    let mut losses = Vec::new();
    for step in 1..=300 {
        let loss = net.loss_and_grad(&params, &surface, &random, &w, &mut work, &mut grad);
        losses.push(loss);
        let (c1, c2) = (1.0 - b1.powi(step), 1.0 - b2.powi(step));
        for i in 0..net.len {
            m[i] = b1 * m[i] + (1.0 - b1) * grad[i];
            v[i] = b2 * v[i] + (1.0 - b2) * grad[i] * grad[i];
            params[i] -= lr * (m[i] / c1) / ((v[i] / c2).sqrt() + 1e-8);
        }
    }
    // Mean |f| on the surface after training.
    net.forward(&params, &surface, &mut work);
    let on = work.distance().iter().map(|f| f.abs()).sum::<f32>() / 512.0;
    println!(
        "loss {:.4} → {:.4}, mean |f| on the cube {on:.4}",
        losses[0], losses[299]
    );
    assert!(
        losses[299] < 0.3 * losses[0],
        "{} → {}",
        losses[0],
        losses[299]
    );
    assert!(on < 0.02, "{on}");
}

/// Not a benchmark (no timed asserts): run with `--nocapture` to see it.
#[test]
fn time_a_step_of_the_default_network() {
    let net = SdfNet::new(&SdfNetSpec::default());
    let params = net.init_geometric(1, 0.5);
    let mut rng = SplitMix64::new(9);
    let surface = shell(4096, 0.5, 0.5, &mut rng);
    let random = points(4096, 1.0, &mut rng);
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut work = SdfWork::default();
            let mut grad = vec![0.0; net.len];
            let w = SdfLoss::default();
            net.loss_and_grad(&params, &surface, &random, &w, &mut work, &mut grad);
            let mut best = f64::INFINITY;
            for _ in 0..3 {
                let t = std::time::Instant::now();
                net.loss_and_grad(&params, &surface, &random, &w, &mut work, &mut grad);
                best = best.min(t.elapsed().as_secs_f64());
            }
            println!(
                "sdf_net loss_and_grad, 4096 + 4096 points, 6 × 128, {threads} thread(s): {:.1} ms",
                best * 1e3
            );
        });
    }
}
