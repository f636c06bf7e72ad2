//! The hash SDF against an f64 reference (values, exact gradients by dual
//! numbers, both losses' parameter gradients by finite differences), hard
//! points, the sphere start, progressive levels, thread-count invariance
//! and a fit of a box.

#![allow(
    clippy::needless_range_loop,
    reason = "axis and entry indices address several arrays at once"
)]

mod objective;

use sdfl_runtime::mesh::{surface_nets, MeshGrid};
use sdfl_runtime::neural::distance::mean_nearest;
use sdfl_runtime::neural::hash_sdf::objective::{clearances, hash_sdf};
use sdfl_runtime::neural::hash_sdf::*;
use sdfl_runtime::neural::hashgrid::HashGridConfig;
use sdfl_runtime::neural::mlp::softplus_layer;
use sdfl_runtime::volume::SplitMix64;

fn spec(beta: f32) -> HashSdfSpec {
    HashSdfSpec {
        grid: HashGridConfig {
            levels: 4,
            features: 2,
            log2_table: 10,
            min_res: 2,
            max_res: 16,
            bbox_min: [-1.0; 3],
            bbox_max: [1.0; 3],
        },
        layers: 2,
        width: 8,
        beta,
        radius: 0.5,
    }
}

fn random_params(net: &HashSdf, seed: u64) -> Vec<f32> {
    let mut rng = SplitMix64::new(seed);
    (0..net.param_count())
        .map(|i| {
            let scale = if i < net.table_params() { 0.5 } else { 0.6 };
            (rng.next_f32() * 2.0 - 1.0) * scale
        })
        .collect()
}

fn random_points(n: usize, seed: u64, spread: f32) -> Vec<[f32; 3]> {
    let mut rng = SplitMix64::new(seed);
    (0..n)
        .map(|_| std::array::from_fn(|_| (rng.next_f32() * 2.0 - 1.0) * spread))
        .collect()
}

/// A value with its derivatives by x (forward mode, f64).
#[derive(Clone, Copy, Debug)]
struct Dual {
    v: f64,
    d: [f64; 3],
}

impl Dual {
    fn c(v: f64) -> Self {
        Dual { v, d: [0.0; 3] }
    }
    fn add(self, o: Dual) -> Dual {
        Dual {
            v: self.v + o.v,
            d: std::array::from_fn(|a| self.d[a] + o.d[a]),
        }
    }
    fn mul(self, o: Dual) -> Dual {
        Dual {
            v: self.v * o.v,
            d: std::array::from_fn(|a| self.d[a] * o.v + self.v * o.d[a]),
        }
    }
    fn scale(self, k: f64) -> Dual {
        Dual {
            v: self.v * k,
            d: self.d.map(|x| x * k),
        }
    }
    fn softplus(self, beta: f64) -> Dual {
        let t = beta * self.v;
        let sp = self.v.max(0.0) + (-t.abs()).exp().ln_1p() / beta;
        let s = 1.0 / (1.0 + (-t).exp());
        Dual {
            v: sp,
            d: self.d.map(|x| x * s),
        }
    }
}

/// `f` and its exact gradient in f64, written from the definition.
fn reference(net: &HashSdf, sp: &HashSdfSpec, params: &[f64], p: [f32; 3], active: usize) -> Dual {
    let c = &sp.grid;
    let f = c.features as usize;
    let mut feats = Vec::new();
    let offsets = net.grid().level_offsets();
    for (l, &res) in net.grid().resolutions().iter().enumerate() {
        if l >= active {
            feats.extend(std::iter::repeat_n(Dual::c(0.0), f));
            continue;
        }
        let side = res as u64 + 1;
        let dense = side.pow(3) <= 1 << c.log2_table;
        let mut idx = [0u32; 3];
        let mut t = [Dual::c(0.0); 3];
        for a in 0..3 {
            let ext = c.bbox_max[a] as f64 - c.bbox_min[a] as f64;
            let raw = (p[a] as f64 - c.bbox_min[a] as f64) / ext;
            let x = raw.clamp(0.0, 1.0) * res as f64;
            let i = (x.floor() as u32).min(res - 1);
            idx[a] = i;
            let mut d = [0.0; 3];
            if (0.0..=1.0).contains(&raw) {
                d[a] = res as f64 / ext;
            }
            t[a] = Dual { v: x - i as f64, d };
        }
        let mut acc = vec![Dual::c(0.0); f];
        for corner in 0..8 {
            let bit = [corner & 1, (corner >> 1) & 1, corner >> 2];
            let v: [u32; 3] = std::array::from_fn(|a| idx[a] + bit[a] as u32);
            let row = if dense {
                (v[0] as u64 + v[1] as u64 * side + v[2] as u64 * side * side) as usize
            } else {
                let h = v[0] ^ v[1].wrapping_mul(2_654_435_761) ^ v[2].wrapping_mul(805_459_861);
                (h & ((1u32 << c.log2_table) - 1)) as usize
            };
            let mut w = Dual::c(1.0);
            for a in 0..3 {
                let wa = if bit[a] == 1 {
                    t[a]
                } else {
                    Dual::c(1.0).add(t[a].scale(-1.0))
                };
                w = w.mul(wa);
            }
            for k in 0..f {
                acc[k] = acc[k].add(w.scale(params[offsets[l] + row * f + k]));
            }
        }
        feats.extend(acc);
    }
    let mut h = feats;
    let mut off = net.table_params();
    for _ in 0..sp.layers {
        let input = h.len();
        let mut next = Vec::new();
        for j in 0..sp.width {
            let mut z = Dual::c(params[off + input * sp.width + j]);
            for k in 0..input {
                z = z.add(h[k].scale(params[off + j * input + k]));
            }
            next.push(z.softplus(sp.beta as f64));
        }
        off += input * sp.width + sp.width;
        h = next;
    }
    let mut out = Dual::c(params[off + sp.width]);
    for j in 0..sp.width {
        out = out.add(h[j].scale(params[off + j]));
    }
    let d: [f64; 3] = std::array::from_fn(|a| p[a] as f64);
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    out.add(Dual {
        v: n - sp.radius as f64,
        d: d.map(|x| x / n),
    })
}

/// The loss of [`HashSdf::loss_and_grad`] in f64.
#[allow(clippy::too_many_arguments)]
fn reference_loss(
    net: &HashSdf,
    sp: &HashSdfSpec,
    params: &[f64],
    surface: &[[f32; 3]],
    random: &[[f32; 3]],
    w: &HashSdfLoss,
    clear: (f64, &[f32]),
    eik: Eikonal,
    active: usize,
) -> f64 {
    let (ns, n) = (surface.len(), surface.len() + random.len());
    let (k_s, k_e) = (w.surface as f64 / ns as f64, w.eikonal as f64 / n as f64);
    let k_i = w.inter as f64 / random.len() as f64;
    let k_c = clear.0 / random.len() as f64;
    let mut loss = 0.0;
    for (i, &p) in surface.iter().chain(random).enumerate() {
        let r = reference(net, sp, params, p, active);
        if i < ns {
            loss += k_s * r.v.abs();
        } else {
            loss += k_i * (-(w.alpha as f64) * r.v.abs()).exp();
            loss += k_c * (clear.1[i - ns] as f64 - r.v.abs()).max(0.0);
        }
        let g: [f64; 3] = match eik {
            Eikonal::Exact => r.d,
            Eikonal::FiniteDifference { step } => std::array::from_fn(|a| {
                let (mut hi, mut lo) = (p, p);
                hi[a] += step;
                lo[a] -= step;
                let span = (hi[a] - lo[a]) as f64;
                (reference(net, sp, params, hi, active).v
                    - reference(net, sp, params, lo, active).v)
                    / span
            }),
        };
        let norm = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        loss += k_e * (norm - 1.0) * (norm - 1.0);
    }
    loss
}

#[test]
fn hash_sdf_values_and_gradients_match_f64_reference() {
    let sp = spec(10.0);
    let net = HashSdf::new(&sp).unwrap();
    let params = random_params(&net, 1);
    let p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
    let pts = random_points(300, 2, 0.95);
    let mut f = vec![0.0; pts.len()];
    let mut g = vec![[0.0; 3]; pts.len()];
    let mut f_only = vec![0.0; pts.len()];
    for active in [4, 2] {
        net.gradients(&params, &pts, active, &mut f, &mut g);
        net.distances(&params, &pts, active, &mut f_only);
        for (i, &p) in pts.iter().enumerate() {
            let r = reference(&net, &sp, &p64, p, active);
            assert_eq!(f[i], f_only[i], "both passes give the same f");
            assert!(
                (f[i] as f64 - r.v).abs() < 1e-4 * (1.0 + r.v.abs()),
                "f at {p:?}"
            );
            // The dual numbers against central differences of the f64
            // value, where no cell face lies within the step.
            for a in 0..3 {
                let h = 1e-3f32;
                if let Some(fd) = central_difference(&net, &sp, &p64, p, a, h, active) {
                    assert!(
                        (r.d[a] - fd).abs() < 1e-3 * (1.0 + fd.abs()),
                        "reference ∇f {} vs differences {fd} at {p:?}",
                        r.d[a]
                    );
                }
                assert!(
                    (g[i][a] as f64 - r.d[a]).abs() < 2e-4 * (1.0 + r.d[a].abs()),
                    "∇f[{a}] {} vs reference {} at {p:?}",
                    g[i][a],
                    r.d[a]
                );
            }
        }
    }
}

/// Central difference of the reference along axis `a`, or None when a
/// cell face of some level lies within the step (the slope jumps there).
fn central_difference(
    net: &HashSdf,
    sp: &HashSdfSpec,
    p64: &[f64],
    p: [f32; 3],
    a: usize,
    h: f32,
    active: usize,
) -> Option<f64> {
    let (mut hi, mut lo) = (p, p);
    hi[a] += h;
    lo[a] -= h;
    let cell = |x: f32, res: u32| ((x as f64 + 1.0) * 0.5 * res as f64).floor();
    if net
        .grid()
        .resolutions()
        .iter()
        .any(|&r| cell(hi[a], r) != cell(lo[a], r))
    {
        return None;
    }
    let span = (hi[a] - lo[a]) as f64;
    Some((reference(net, sp, p64, hi, active).v - reference(net, sp, p64, lo, active).v) / span)
}

/// Compares sampled entries of `loss_and_grad`'s gradient with central
/// differences of the f64 reference loss.
fn check_param_gradient(eik: Eikonal, active: usize, beta: f32, seed: u64) {
    let sp = spec(beta);
    let net = HashSdf::new(&sp).unwrap();
    let params = random_params(&net, seed);
    let surface = random_points(40, seed + 1, 0.9);
    let random = random_points(50, seed + 2, 0.9);
    let w = HashSdfLoss {
        surface: 1.0,
        eikonal: 0.7,
        inter: 0.5,
        alpha: 3.0,
    };
    // Clearances from 0 to 1.2 (|f| is at most about 1 here): the hinge
    // active at some random points, not at others.
    let mut rng = SplitMix64::new(seed + 4);
    let at_least: Vec<f32> = random.iter().map(|_| rng.next_f32() * 1.2).collect();
    let clearance = Clearance {
        weight: 0.8,
        at_least: &at_least,
    };
    let clear = (clearance.weight as f64, &at_least[..]);
    let mut work = HashSdfWork::default();
    let mut touched = net.grid().touched_set();
    let mut grad = vec![0.0; net.param_count()];
    let loss = net.loss_and_grad_clear(
        &params,
        &surface,
        &random,
        &w,
        clearance,
        eik,
        active,
        &mut work,
        &mut grad,
        &mut touched,
    );
    let f = work.distance();
    let hinged = (0..random.len())
        .filter(|&i| at_least[i] > f[surface.len() + i].abs())
        .count();
    assert!(
        hinged > 5 && hinged < random.len() - 5,
        "{hinged} of the random points under their clearance"
    );
    let mut p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
    let ref_loss = reference_loss(&net, &sp, &p64, &surface, &random, &w, clear, eik, active);
    assert!(
        (loss - ref_loss).abs() < 1e-4 * (1.0 + ref_loss.abs()),
        "{loss} vs {ref_loss}"
    );
    // Touched table entries, some untouched ones, and MLP weights.
    let tables = net.table_params();
    let f = sp.grid.features as usize;
    let offsets = net.grid().level_offsets();
    for i in 0..tables {
        let l = offsets.iter().rposition(|&o| o <= i).unwrap();
        if grad[i] != 0.0 {
            assert!(
                touched.is_touched(l, (i - offsets[l]) / f),
                "row of entry {i} marked"
            );
        }
    }
    let touched: Vec<usize> = (0..tables).filter(|&i| grad[i] != 0.0).collect();
    assert!(touched.len() > 50, "the points reach the tables");
    let mut rng = SplitMix64::new(seed + 3);
    let mut pick = |n: usize| (rng.next_u64() % n as u64) as usize;
    let mut entries: Vec<usize> = (0..25).map(|_| touched[pick(touched.len())]).collect();
    entries.extend((0..10).map(|_| pick(tables)));
    let mlp = net.param_count() - tables;
    entries.extend((0..40).map(|_| tables + pick(mlp)));
    let scale = grad.iter().fold(0f32, |m, g| m.max(g.abs())) as f64;
    for &i in &entries {
        let h = 1e-6;
        let v = p64[i];
        p64[i] = v + h;
        let up = reference_loss(&net, &sp, &p64, &surface, &random, &w, clear, eik, active);
        p64[i] = v - h;
        let down = reference_loss(&net, &sp, &p64, &surface, &random, &w, clear, eik, active);
        p64[i] = v;
        let fd = (up - down) / (2.0 * h);
        let got = grad[i] as f64;
        assert!(
            (got - fd).abs() < 2e-3 * fd.abs() + 1e-5 * scale.max(1.0),
            "∂L/∂param[{i}] ({}) = {got}, differences {fd} ({eik:?}, {active} levels)",
            if i < tables { "table" } else { "mlp" }
        );
    }
}

#[test]
fn hash_sdf_exact_eikonal_param_gradients_match_differences() {
    check_param_gradient(Eikonal::Exact, 4, 10.0, 10);
    check_param_gradient(Eikonal::Exact, 4, 100.0, 20);
}

#[test]
fn hash_sdf_fd_eikonal_param_gradients_match_differences() {
    check_param_gradient(Eikonal::FiniteDifference { step: 0.01 }, 4, 10.0, 30);
}

#[test]
fn hash_sdf_progressive_levels_leave_fine_tables_alone() {
    check_param_gradient(Eikonal::Exact, 2, 10.0, 40);
    let sp = spec(10.0);
    let net = HashSdf::new(&sp).unwrap();
    let params = random_params(&net, 41);
    let pts = random_points(100, 42, 0.9);
    let mut work = HashSdfWork::default();
    let mut touched = net.grid().touched_set();
    let mut grad = vec![0.0; net.param_count()];
    let w = HashSdfLoss::default();
    net.loss_and_grad(
        &params,
        &pts,
        &pts,
        &w,
        Eikonal::Exact,
        2,
        &mut work,
        &mut grad,
        &mut touched,
    );
    let offsets = net.grid().level_offsets();
    assert!(grad[offsets[2]..net.table_params()]
        .iter()
        .all(|&g| g == 0.0));
    assert!(grad[..offsets[2]].iter().any(|&g| g != 0.0));
    assert_eq!(progressive_levels(0, 16, 4, 100), 4);
    assert_eq!(progressive_levels(250, 16, 4, 100), 6);
    assert_eq!(progressive_levels(1 << 40, 16, 4, 100), 16);
    assert_eq!(progressive_levels(3, 16, 4, 0), 16);
}

#[test]
fn hash_sdf_is_bit_identical_at_any_thread_count() {
    let sp = spec(100.0);
    let net = HashSdf::new(&sp).unwrap();
    let params = random_params(&net, 5);
    // Not a multiple of the chunk size.
    let surface = random_points(301, 6, 1.2);
    let random = random_points(333, 7, 1.2);
    for eik in [Eikonal::Exact, Eikonal::FiniteDifference { step: 0.01 }] {
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut work = HashSdfWork::default();
                let mut touched = net.grid().touched_set();
                let mut grad = vec![0.0; net.param_count()];
                let w = HashSdfLoss::default();
                // Twice on one workspace: a grown workspace gives the same.
                net.loss_and_grad(
                    &params,
                    &surface,
                    &random,
                    &w,
                    eik,
                    4,
                    &mut work,
                    &mut grad,
                    &mut touched,
                );
                grad.fill(0.0);
                let l = net.loss_and_grad(
                    &params,
                    &surface,
                    &random,
                    &w,
                    eik,
                    4,
                    &mut work,
                    &mut grad,
                    &mut touched,
                );
                grad.fill(0.0);
                (
                    l.to_bits(),
                    grad.iter().map(|g| g.to_bits()).collect::<Vec<_>>(),
                )
            })
        };
        let one = run(1);
        assert_eq!(one, run(2), "{eik:?}");
        assert_eq!(one, run(3), "{eik:?}");
    }
}

#[test]
fn hash_sdf_hard_points_stay_finite() {
    let sp = spec(100.0);
    let net = HashSdf::new(&sp).unwrap();
    let params = random_params(&net, 8);
    let p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
    // Every level's resolution is even: 0 and ±0.5 are vertices of all.
    let hard = vec![
        [0.0, 0.0, 0.5],
        [0.5, -0.5, 0.0],
        [1.0, 1.0, 1.0],
        [-1.0, 0.25, -1.0],
        [3.0, -7.0, 0.1],
        [1e30, -1e30, 1e30],
        [f32::MAX, 0.0, -f32::MAX],
        [0.0, 0.0, 0.0],
        [-1e-30, 1e-30, 0.0],
    ];
    let mut f = vec![0.0; hard.len()];
    let mut g = vec![[0.0; 3]; hard.len()];
    net.gradients(&params, &hard, 4, &mut f, &mut g);
    for (i, p) in hard.iter().enumerate() {
        assert!(
            f[i].is_finite() && g[i].iter().all(|v| v.is_finite()),
            "{p:?}: {} {:?}",
            f[i],
            g[i]
        );
    }
    // On vertices the derivative is the one-sided one of the cell above.
    for &p in &hard[..2] {
        let r = reference(&net, &sp, &p64, p, 4);
        for a in 0..3 {
            let mut q = p;
            q[a] += 1e-3;
            let fwd = (reference(&net, &sp, &p64, q, 4).v - r.v) / (q[a] - p[a]) as f64;
            let i = hard.iter().position(|h| *h == p).unwrap();
            assert!((g[i][a] as f64 - r.d[a]).abs() < 2e-4 * (1.0 + r.d[a].abs()));
            // Second-order error of a one-sided difference; softplus is
            // sharp at β = 100, so a loose bound.
            assert!(
                (fwd - r.d[a]).abs() < 0.05 * (1.0 + fwd.abs()),
                "{p:?} axis {a}: {fwd} vs {}",
                r.d[a]
            );
        }
    }
    // Outside the box the encoding is constant along clamped axes: ∇f is
    // the sphere's direction there (plus nothing from the network).
    let (_, sphere) = net.sphere([3.0, -7.0, 0.1]);
    for a in 0..2 {
        assert!((g[4][a] - sphere[a]).abs() < 1e-6);
    }
    // The losses at all of them, with ∇f = 0 at the centre when the
    // network is silent: no NaN anywhere.
    let mut silent = params.clone();
    let out = net.table_params() + (net.grid().output_dim() * 8 + 8) + (8 * 8 + 8);
    silent[out..out + 8].fill(0.0);
    for eik in [Eikonal::Exact, Eikonal::FiniteDifference { step: 1e-3 }] {
        for params in [&params, &silent] {
            let mut work = HashSdfWork::default();
            let mut touched = net.grid().touched_set();
            let mut grad = vec![0.0; net.param_count()];
            let w = HashSdfLoss::default();
            let l = net.loss_and_grad(
                params,
                &hard,
                &hard,
                &w,
                eik,
                4,
                &mut work,
                &mut grad,
                &mut touched,
            );
            assert!(l.is_finite(), "{eik:?}: loss {l}");
            assert!(grad.iter().all(|g| g.is_finite()), "{eik:?}");
        }
    }
    let mut f = [0.0];
    let mut g = [[1.0; 3]];
    net.gradients(&silent, &[[0.0; 3]], 4, &mut f, &mut g);
    assert_eq!(g[0], [0.0; 3], "∇f = 0 at the centre of a silent network");
}

#[test]
fn hash_sdf_starts_as_the_sphere() {
    let mut sp = spec(100.0);
    sp.grid.levels = 8;
    sp.grid.max_res = 128;
    sp.grid.log2_table = 14;
    sp.layers = 1;
    sp.width = 32;
    sp.radius = 0.4;
    let net = HashSdf::new(&sp).unwrap();
    let params = net.init(3);
    let pts = random_points(2000, 4, 1.0);
    let mut f = vec![0.0; pts.len()];
    let mut g = vec![[0.0; 3]; pts.len()];
    net.gradients(&params, &pts, net.levels(), &mut f, &mut g);
    for (i, p) in pts.iter().enumerate() {
        let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        if n < 0.05 {
            continue;
        }
        assert!((f[i] - (n - 0.4)).abs() < 1e-3, "f {} at |x| = {n}", f[i]);
        let gn = (g[i][0] * g[i][0] + g[i][1] * g[i][1] + g[i][2] * g[i][2]).sqrt();
        assert!((gn - 1.0).abs() < 2e-2, "‖∇f‖ = {gn}");
    }
}

/// The box `|x| ≤ half` as a signed distance (f64).
fn box_sdf(p: [f32; 3], half: [f64; 3]) -> f64 {
    let q: [f64; 3] = std::array::from_fn(|a| (p[a] as f64).abs() - half[a]);
    let out = q.map(|v| v.max(0.0));
    (out[0] * out[0] + out[1] * out[1] + out[2] * out[2]).sqrt() + q[0].max(q[1]).max(q[2]).min(0.0)
}

/// `n` points on the box's faces, area-weighted.
fn box_surface(n: usize, half: [f64; 3], rng: &mut SplitMix64) -> Vec<[f32; 3]> {
    let area = [half[1] * half[2], half[0] * half[2], half[0] * half[1]];
    let total: f64 = area.iter().sum();
    (0..n)
        .map(|_| {
            let mut r = rng.next_f32() as f64 * total;
            let mut axis = 0;
            while axis < 2 && r > area[axis] {
                r -= area[axis];
                axis += 1;
            }
            let sign = if rng.next_f32() < 0.5 { -1.0 } else { 1.0 };
            std::array::from_fn(|a| {
                if a == axis {
                    (sign * half[a]) as f32
                } else {
                    ((rng.next_f32() as f64 * 2.0 - 1.0) * half[a]) as f32
                }
            })
        })
        .collect()
}

#[test]
fn hash_sdf_fits_a_box_in_a_few_hundred_steps() {
    let sp = HashSdfSpec {
        grid: HashGridConfig {
            levels: 8,
            features: 2,
            log2_table: 15,
            min_res: 4,
            max_res: 64,
            bbox_min: [-1.0; 3],
            bbox_max: [1.0; 3],
        },
        layers: 1,
        width: 32,
        beta: 100.0,
        radius: 0.5,
    };
    let half = [0.55, 0.35, 0.45];
    let net = HashSdf::new(&sp).unwrap();
    let mut params = net.init(11);
    let n = params.len();
    let (mut m, mut v, mut grad) = (vec![0f32; n], vec![0f32; n], vec![0f32; n]);
    let mut work = HashSdfWork::default();
    let mut touched = net.grid().touched_set();
    let mut rng = SplitMix64::new(12);
    let w = HashSdfLoss {
        surface: 1.0,
        eikonal: 0.1,
        ..HashSdfLoss::default()
    };
    let (b1, b2, lr) = (0.9f32, 0.99f32, 5e-3f32);
    let steps = 300;
    let mut surface = Vec::new();
    let mut random = Vec::new();
    for step in 1..=steps {
        surface.clear();
        surface.extend(box_surface(512, half, &mut rng));
        random.clear();
        random.extend((0..512).map(|_| std::array::from_fn(|_| rng.next_f32() * 2.0 - 1.0)));
        let active = progressive_levels(step, 8, 4, 25);
        net.loss_and_grad(
            &params,
            &surface,
            &random,
            &w,
            Eikonal::Exact,
            active,
            &mut work,
            &mut grad,
            &mut touched,
        );
        let bc1 = 1.0 - b1.powi(step as i32);
        let bc2 = 1.0 - b2.powi(step as i32);
        for i in 0..n {
            m[i] = b1 * m[i] + (1.0 - b1) * grad[i];
            v[i] = b2 * v[i] + (1.0 - b2) * grad[i] * grad[i];
            params[i] -= lr * (m[i] / bc1) / ((v[i] / bc2).sqrt() + 1e-15);
            grad[i] = 0.0;
        }
    }
    let test = box_surface(4000, half, &mut SplitMix64::new(99));
    let mut f = vec![0.0; test.len()];
    net.distances(&params, &test, 8, &mut f);
    let mean_abs = f.iter().map(|v| v.abs() as f64).sum::<f64>() / f.len() as f64;
    let field = HashSdfField {
        net: &net,
        params: &params,
        active: 8,
    };
    let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], 48);
    let mesh = surface_nets(&field, &grid, 1 << 22, &|_| {}).unwrap();
    let to_box = mesh
        .vertices
        .iter()
        .map(|&p| box_sdf(p, half).abs())
        .sum::<f64>()
        / mesh.vertices.len().max(1) as f64;
    let to_mesh = mean_nearest(&test, &mesh.vertices);
    eprintln!("box fit: mean |f| {mean_abs:.4}, mesh→box {to_box:.4}, box→mesh {to_mesh:.4}");
    assert!(mean_abs < 0.005, "mean |f| on the surface {mean_abs}");
    // Mesh vertices lie on the box; the samples are within about half a
    // cell (0.04) of a vertex.
    assert!(
        to_box < 0.006 && to_mesh < 0.025,
        "Chamfer {to_box} + {to_mesh}"
    );
}

/// The blocked passes give the point-at-a-time bits at every point (`f`
/// from `value`, `f` and `∇f` from `value_grad`), and the value-only form
/// gives the form with tangents' `f`: partial blocks, both network depths,
/// some levels off, and hard points.
#[test]
fn hash_sdf_blocked_distances_are_the_pointwise_values() {
    for (layers, width, active, seed) in [(2, 8, 4, 50), (1, 16, 3, 51), (2, 5, 1, 52)] {
        let sp = HashSdfSpec {
            layers,
            width,
            ..spec(100.0)
        };
        let net = HashSdf::new(&sp).unwrap();
        let params = random_params(&net, seed);
        let mut pts = random_points(300, seed + 1, 1.3);
        pts.extend([
            [0.0, 0.0, 0.5],
            [1.0, 1.0, 1.0],
            [3.0, -7.0, 0.1],
            [1e30, -1e30, 1e30],
            [f32::MAX, 0.0, -f32::MAX],
            [0.0; 3],
        ]);
        for n in [1, CHUNK - 1, CHUNK, CHUNK + 1, pts.len()] {
            let pts = &pts[..n];
            let mut blocked = vec![f32::NAN; n];
            let mut pointwise = vec![0.0; n];
            net.distances(&params, pts, active, &mut blocked);
            net.distances_pointwise(&params, pts, active, &mut pointwise);
            let (mut f, mut g) = (vec![f32::NAN; n], vec![[f32::NAN; 3]; n]);
            net.gradients(&params, pts, active, &mut f, &mut g);
            let mut s = Scratch::new(&net, 0);
            let mut s3 = Scratch::new(&net, 3);
            for (i, &p) in pts.iter().enumerate() {
                let v = net.value(&params, p, active, &mut s.buf);
                assert!(v.is_finite(), "{p:?}");
                assert_eq!(blocked[i].to_bits(), v.to_bits(), "{p:?}, {n} points");
                assert_eq!(pointwise[i].to_bits(), v.to_bits(), "{p:?}");
                let (fv, gv) = net.value_grad(&params, p, active, &mut s3.buf);
                assert_eq!(fv.to_bits(), v.to_bits(), "value_grad's f at {p:?}");
                assert_eq!(f[i].to_bits(), v.to_bits(), "blocked f at {p:?}");
                assert_eq!(g[i].map(f32::to_bits), gv.map(f32::to_bits), "∇f at {p:?}");
            }
        }
    }
}

/// `n` points on two spheres of radius 0.25 at x = ±0.5, and the distance
/// to them.
fn two_spheres(n: usize, rng: &mut SplitMix64) -> Vec<[f32; 3]> {
    (0..n)
        .map(|i| {
            let v: [f32; 3] = std::array::from_fn(|_| rng.next_f32() * 2.0 - 1.0);
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-6);
            let c = if i % 2 == 0 { 0.5 } else { -0.5 };
            [c + 0.25 * v[0] / l, 0.25 * v[1] / l, 0.25 * v[2] / l]
        })
        .collect()
}

fn two_spheres_distance(p: [f32; 3]) -> f64 {
    [0.5f64, -0.5]
        .iter()
        .map(|&c| {
            let d = [p[0] as f64 - c, p[1] as f64, p[2] as f64];
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 0.25
        })
        .fold(f64::INFINITY, f64::min)
}

/// Fits two small spheres that sit across the starting sphere (radius 0.5)
/// and returns the mesh vertices farther than 0.1 from them, and all.
fn fit_two_spheres(clearance: f32) -> (usize, usize) {
    let sp = HashSdfSpec {
        grid: HashGridConfig {
            levels: 8,
            features: 2,
            log2_table: 15,
            min_res: 4,
            max_res: 64,
            bbox_min: [-1.0; 3],
            bbox_max: [1.0; 3],
        },
        layers: 1,
        width: 32,
        beta: 100.0,
        radius: 0.5,
    };
    let net = HashSdf::new(&sp).unwrap();
    let mut params = net.init(21);
    let n = params.len();
    let (mut m, mut v, mut grad) = (vec![0f32; n], vec![0f32; n], vec![0f32; n]);
    let mut work = HashSdfWork::default();
    let mut touched = net.grid().touched_set();
    let mut rng = SplitMix64::new(22);
    let data = two_spheres(1500, &mut rng);
    let w = HashSdfLoss {
        surface: 1.0,
        eikonal: 0.02,
        inter: 0.1,
        alpha: 100.0,
    };
    let (b1, b2, lr) = (0.9f32, 0.99f32, 5e-3f32);
    let (mut surface, mut random, mut at_least) = (Vec::new(), Vec::new(), Vec::new());
    for step in 1..=300 {
        surface.clear();
        surface.extend((0..512).map(|_| data[(rng.next_u64() % data.len() as u64) as usize]));
        random.clear();
        random.extend((0..512).map(|_| std::array::from_fn(|_| rng.next_f32() * 2.0 - 1.0)));
        clearances(&surface, &random, 2.0, &mut at_least);
        let clear = Clearance {
            weight: clearance,
            at_least: &at_least,
        };
        let active = progressive_levels(step, 8, 2, 25);
        net.loss_and_grad_clear(
            &params,
            &surface,
            &random,
            &w,
            clear,
            Eikonal::Exact,
            active,
            &mut work,
            &mut grad,
            &mut touched,
        );
        let bc1 = 1.0 - b1.powi(step as i32);
        let bc2 = 1.0 - b2.powi(step as i32);
        for i in 0..n {
            m[i] = b1 * m[i] + (1.0 - b1) * grad[i];
            v[i] = b2 * v[i] + (1.0 - b2) * grad[i] * grad[i];
            params[i] -= lr * (m[i] / bc1) / ((v[i] / bc2).sqrt() + 1e-15);
            grad[i] = 0.0;
        }
    }
    let field = HashSdfField {
        net: &net,
        params: &params,
        active: 8,
    };
    let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], 48);
    let mesh = surface_nets(&field, &grid, 1 << 22, &|_| {}).unwrap();
    let stray = mesh
        .vertices
        .iter()
        .filter(|&&p| two_spheres_distance(p) > 0.1)
        .count();
    eprintln!(
        "two spheres, clearance {clearance}: {stray} of {} vertices stray",
        mesh.vertices.len()
    );
    (stray, mesh.vertices.len())
}

/// Without the clearance term the starting sphere survives where no point
/// pulls it (stray surface between and around the two spheres); with it,
/// the mesh is the two spheres.
#[test]
fn hash_sdf_clearance_removes_the_stray_surface() {
    let (stray, all) = fit_two_spheres(0.0);
    assert!(stray > all / 20, "the hard case: {stray} of {all} stray");
    let (stray, all) = fit_two_spheres(1.0);
    assert!(all > 500 && stray == 0, "{stray} of {all} stray");
}

/// The hash SDF's one softplus kernel ([`softplus_layer`]): its value-only
/// form is the form with slopes' value bit for bit (the distance passes
/// and the training passes see the same `f`), over a dense range, every
/// f32 about saturation and extremes; near the f64 formula; NaN-free and
/// finite at ±1e30 for every β used.
#[test]
fn hash_sdf_softplus_value_is_the_softplus() {
    let mut z: Vec<f32> = (-40000..=40000).map(|i| i as f32 * 1e-5).collect();
    // βz about ln(2^24) ≈ 16.64 (where ln(1 + e) starts to round to e),
    // every f32 near it.
    let edge = (2f32.powi(24)).ln() / 100.0;
    for s in [edge, -edge] {
        let mut v = s * 0.999;
        while v.abs() < edge.abs() * 1.001 {
            z.push(v);
            v = f32::from_bits(v.to_bits() + 1);
        }
    }
    let extremes = [
        0.0,
        -0.0,
        1e-30,
        -1e-30,
        1.04,
        -1.04,
        1.05,
        -1.05,
        1e30,
        -1e30,
        f32::MAX,
        -f32::MAX,
    ];
    z.extend(extremes);
    let mut rng = SplitMix64::new(9);
    z.extend((0..200_000).map(|_| (rng.next_f32() * 2.0 - 1.0) * 0.5));
    for beta in [100.0f32, 10.0, 1.0] {
        let (mut with_slope, mut slope) = (z.clone(), vec![0.0; z.len()]);
        softplus_layer(&mut with_slope, Some(&mut slope), beta);
        let mut alone = z.clone();
        softplus_layer(&mut alone, None, beta);
        for (i, &zi) in z.iter().enumerate() {
            assert_eq!(
                alone[i].to_bits(),
                with_slope[i].to_bits(),
                "softplus_{beta}({zi})"
            );
            assert!(
                !alone[i].is_nan() && !slope[i].is_nan(),
                "softplus_{beta}({zi})"
            );
            if zi.abs() <= 1e30 {
                assert!(alone[i].is_finite() && (0.0..=1.0).contains(&slope[i]));
                // βz as the kernel forms it: its f32 rounding moves
                // e^{−|βz|} by up to |βz|·2^-24 relative, which no formula
                // after it can undo.
                let x = (beta * zi) as f64;
                let want = (x.max(0.0) + (-x.abs()).exp().ln_1p()) / beta as f64;
                assert!(
                    (alone[i] as f64 - want).abs() <= 6.0 * f32::EPSILON as f64 * want + 1.2e-38,
                    "softplus_{beta}({zi}) = {} vs {want}",
                    alone[i]
                );
            }
        }
    }
}

/// The blocked exact backward (`volume_backward`) against the point at a
/// time reverse pass (`mlp_backward` per point, the same tables'
/// pass): the same gradient up to the order of the sums, at partial
/// chunks, both depths, some levels off, and with zero adjoints mixed in.
#[test]
fn hash_sdf_blocked_backward_is_the_pointwise_backward() {
    use sdfl_runtime::neural::hash_sdf::volume::VolumeWork;
    for (layers, width, active, seed) in [(2, 8, 4, 60), (1, 16, 3, 61)] {
        let sp = HashSdfSpec {
            layers,
            width,
            ..spec(100.0)
        };
        let net = HashSdf::new(&sp).unwrap();
        let params = random_params(&net, seed);
        let n = 2 * CHUNK + 37;
        let pts = random_points(n, seed + 1, 1.2);
        let mut rng = SplitMix64::new(seed + 2);
        let mut d = |k: usize| -> f32 {
            if k.is_multiple_of(5) {
                0.0
            } else {
                rng.next_f32() * 2.0 - 1.0
            }
        };
        let d_f: Vec<f32> = (0..n).map(&mut d).collect();
        let d_g: Vec<f32> = (0..3 * n)
            .map(|k| if k % 15 < 3 { 0.0 } else { d(k + 1) })
            .collect();
        let mut work = VolumeWork::default();
        net.volume_forward(&params, &pts, Eikonal::Exact, active, &mut work);
        let mut blocked = vec![0.0; net.param_count()];
        net.volume_backward(
            &params,
            &pts,
            &d_f,
            &d_g,
            Eikonal::Exact,
            active,
            &mut work,
            &mut blocked,
        );
        // The reference, one point at a time.
        let mut reference = vec![0.0; net.param_count()];
        let tables = net.table_params();
        let feat = 4 * net.grid().output_dim();
        let mut d_feat = vec![0.0; n * feat];
        let mut s = Scratch::new(&net, 3);
        let mut adj = vec![0.0; 2 * 4 * net.grid().output_dim().max(width)];
        let mut d_mlp = vec![0.0; net.param_count() - tables];
        for (i, &p) in pts.iter().enumerate() {
            let (f, g) = net.value_grad(&params, p, active, &mut s.buf);
            assert_eq!(work.distance()[i].to_bits(), f.to_bits());
            assert_eq!(&work.gradient()[3 * i..3 * i + 3], &g);
            let t = net.tangent_out::<3>();
            let dg = [d_g[3 * i], d_g[3 * i + 1], d_g[3 * i + 2]];
            let df = &mut d_feat[i * feat..][..feat];
            net.mlp_backward::<3>(
                &params,
                &s.buf[..t + 3],
                d_f[i],
                dg,
                &mut d_mlp,
                &mut adj,
                df,
            );
        }
        reference[tables..].copy_from_slice(&d_mlp);
        let mut touched = net.grid().touched_set();
        net.tables_backward(
            &pts,
            &d_feat,
            3,
            active,
            &mut reference[..tables],
            &mut touched,
        );
        let scale = reference.iter().fold(0f32, |m, v| m.max(v.abs()));
        for (i, (b, r)) in blocked.iter().zip(&reference).enumerate() {
            assert!(
                (b - r).abs() <= 1e-5 * scale,
                "param {i} of {}: {b} vs {r}",
                blocked.len()
            );
        }
        assert!(scale > 0.1);
    }
}

/// The blocked backward's two ways to run its products (fp32's register
/// tiles where AVX-512 runs, the lane loops elsewhere) agree, at a full
/// chunk and a partial one.
#[test]
fn hash_sdf_blocked_backward_tiles_are_the_lane_loops() {
    use sdfl_runtime::neural::hash_sdf::block::BlockScratch;
    let sp = HashSdfSpec {
        layers: 2,
        width: 16,
        ..spec(100.0)
    };
    let net = HashSdf::new(&sp).unwrap();
    let params = random_params(&net, 70);
    let feat = 4 * net.grid().output_dim();
    for n in [CHUNK, 45] {
        let pts = random_points(n, 71, 1.1);
        let mut rng = SplitMix64::new(72);
        let d_f: Vec<f32> = (0..n).map(|_| rng.next_f32() - 0.5).collect();
        let d_g: Vec<f32> = (0..3 * n).map(|_| rng.next_f32() - 0.5).collect();
        let run = |tiles: bool| {
            let mut s = BlockScratch::default();
            s.fit::<3>(&net);
            let (mut f, mut g) = (vec![0.0; n], vec![[0.0; 3]; n]);
            net.forward_block::<3>(&params, &pts, 4, &mut s.forward, &mut f, &mut g);
            let mut d_mlp = vec![0.0; net.param_count() - net.table_params()];
            let mut d_feat = vec![0.0; n * feat];
            let BlockScratch {
                forward,
                adjoint,
                transposed,
            } = &mut s;
            net.backward_block(
                &params,
                forward,
                &d_f,
                &d_g,
                adjoint,
                transposed,
                &mut d_mlp,
                &mut d_feat,
                tiles,
            );
            (d_mlp, d_feat)
        };
        let (lanes_mlp, lanes_feat) = run(false);
        let (tiles_mlp, tiles_feat) = run(sdfl_runtime::neural::fp32::available());
        let close = |a: &[f32], b: &[f32]| {
            let scale = a.iter().fold(0f32, |m, v| m.max(v.abs()));
            assert!(scale > 0.01);
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() <= 1e-5 * scale, "{x} vs {y}");
            }
        };
        close(&lanes_mlp, &tiles_mlp);
        close(&lanes_feat, &tiles_feat);
    }
}

/// The plan's per-thread bytes (`NeuralSdf::thread_scratch`, summed over
/// the host's threads) are the blocked scratch each thread keeps: a change
/// to either shows here.
#[test]
fn the_estimates_thread_scratch_is_the_blocks() {
    use sdfl_stdlib::value::{Encoding, HashGridSpec, NeuralSdf};
    assert_eq!(CHUNK, NeuralSdf::BLOCK_ROWS);
    for (levels, features, layers, width) in
        [(4, 2, 1, 16), (16, 2, 2, 64), (8, 4, 3, 32), (2, 1, 1, 128)]
    {
        let g = HashGridSpec {
            levels,
            features,
            log2_table: 12,
            min_res: 4,
            max_res: 64,
            min: [-1.0; 3],
            max: [1.0; 3],
        };
        let n = NeuralSdf {
            encoding: Encoding::HashGrid(g),
            layers,
            width,
            skips: vec![],
            beta: 100.0,
            radius: 0.5,
            seed: 0,
            level_every: 0,
            eikonal_step: None,
        };
        let net = hash_sdf(&n, &g).unwrap();
        assert_eq!(
            block::BlockScratch::bytes::<3>(&net) as usize,
            n.thread_scratch(),
            "{levels} levels × {features}, {layers} × {width}"
        );
        let central = NeuralSdf {
            eikonal_step: Some(1e-3),
            ..n
        };
        assert_eq!(central.thread_scratch(), 0);
    }
}
