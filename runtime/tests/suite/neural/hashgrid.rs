//! The hash grid's layout, its values against an f64 reference and their
//! continuity, points outside the box, gradients against finite
//! differences, thread-count invariance, sparse Adam, throughput.

use sdfl_runtime::neural::hashgrid::*;
use sdfl_runtime::volume::SplitMix64;

fn small(levels: u32, log2_table: u32, min_res: u32, max_res: u32) -> HashGrid {
    HashGrid::new(HashGridConfig {
        levels,
        features: 2,
        log2_table,
        min_res,
        max_res,
        bbox_min: [-1.0, 0.0, 2.0],
        bbox_max: [1.0, 4.0, 3.0],
    })
    .unwrap()
}

fn random_params(g: &HashGrid, seed: u64) -> Vec<f32> {
    let mut rng = SplitMix64::new(seed);
    (0..g.param_count())
        .map(|_| rng.next_f32() * 2.0 - 1.0)
        .collect()
}

fn random_points(n: usize, seed: u64, spill: f32) -> Vec<[f32; 3]> {
    let mut rng = SplitMix64::new(seed);
    let (lo, hi) = ([-1.0f32, 0.0, 2.0], [1.0f32, 4.0, 3.0]);
    (0..n)
        .map(|_| {
            std::array::from_fn(|a| {
                let u = rng.next_f32() * (1.0 + 2.0 * spill) - spill;
                lo[a] + u * (hi[a] - lo[a])
            })
        })
        .collect()
}

/// The encoding in f64, written from the definition.
fn reference(g: &HashGrid, params: &[f64], p: [f32; 3]) -> Vec<f64> {
    let c = g.config();
    let f = c.features as usize;
    let mut out = Vec::new();
    for (l, &res) in g.resolutions().iter().enumerate() {
        let res64 = res as u64;
        let dense = (res64 + 1).pow(3) <= 1 << c.log2_table;
        let rows = if dense {
            (res64 + 1).pow(3)
        } else {
            1 << c.log2_table
        };
        let x: Vec<f64> = (0..3)
            .map(|a| {
                let u = (p[a] as f64 - c.bbox_min[a] as f64)
                    / (c.bbox_max[a] as f64 - c.bbox_min[a] as f64);
                u.clamp(0.0, 1.0) * res as f64
            })
            .collect();
        let base: Vec<u64> = x
            .iter()
            .map(|&v| (v.floor() as u64).min(res64 - 1))
            .collect();
        let mut feat = vec![0f64; f];
        for dz in 0..2u64 {
            for dy in 0..2u64 {
                for dx in 0..2u64 {
                    let v = [base[0] + dx, base[1] + dy, base[2] + dz];
                    let row = if dense {
                        v[0] + (res64 + 1) * v[1] + (res64 + 1) * (res64 + 1) * v[2]
                    } else {
                        (v[0] ^ (v[1] * 2_654_435_761) ^ (v[2] * 805_459_861)) % rows
                    };
                    let mut w = 1.0;
                    for (a, d) in [dx, dy, dz].into_iter().enumerate() {
                        let t = x[a] - base[a] as f64;
                        w *= if d == 1 { t } else { 1.0 - t };
                    }
                    let at = g.level_offsets()[l] + row as usize * f;
                    for k in 0..f {
                        feat[k] += w * params[at + k];
                    }
                }
            }
        }
        out.extend(feat);
    }
    out
}

#[test]
fn layout_follows_the_config() {
    let g = HashGrid::new(HashGridConfig::default()).unwrap();
    let res = g.resolutions();
    assert_eq!(res[0], 16);
    assert_eq!(res[15], 2048);
    assert!(res.windows(2).all(|r| r[0] < r[1]));
    // (N+1)³ ≤ 2^19 holds up to N = 79.
    let dense = g.dense_levels();
    for (r, d) in res.iter().zip(&dense) {
        assert_eq!(*d, (*r as u64 + 1).pow(3) <= 1 << 19);
    }
    assert_eq!(g.output_dim(), 32);
    let rows: usize = res
        .iter()
        .map(|&r| ((r as usize + 1).pow(3)).min(1 << 19))
        .sum();
    assert_eq!(g.param_count(), rows * 2);
    let p = g.init(3);
    assert_eq!(p.len(), g.param_count());
    assert!(p.iter().all(|v| v.abs() <= 1e-4));
    assert_eq!(p, g.init(3));
    assert_ne!(p, g.init(4));
    let bad = |f: &dyn Fn(&mut HashGridConfig)| {
        let mut c = HashGridConfig::default();
        f(&mut c);
        HashGrid::new(c).is_err()
    };
    assert!(bad(&|c| c.levels = 0));
    assert!(bad(&|c| c.features = 0));
    assert!(bad(&|c| c.log2_table = 40));
    assert!(bad(&|c| c.min_res = 0));
    assert!(bad(&|c| c.max_res = 8));
    assert!(bad(&|c| c.bbox_max[1] = -1.0));
    assert!(bad(&|c| c.bbox_min[2] = f32::NAN));
    assert!(bad(&|c| {
        c.levels = 64;
        c.features = 16;
        c.log2_table = 24;
    }));
    // One level: N_min only.
    assert_eq!(small(1, 10, 5, 9).resolutions(), vec![5]);
}

#[test]
fn vertices_read_their_own_features() {
    // Level 0 dense (5³ rows), level 2 hashed (2^8 rows < 17³).
    let g = small(3, 8, 4, 16);
    assert_eq!(g.dense_levels(), vec![true, false, false]);
    let params = random_params(&g, 1);
    let off = g.level_offsets();
    let (lo, hi) = ([-1.0f32, 0.0, 2.0], [1.0f32, 4.0, 3.0]);
    let mut out = vec![0f32; 6];
    for v in [[0u32, 0, 0], [4, 4, 4], [1, 3, 2], [4, 0, 3]] {
        let p: [f32; 3] = std::array::from_fn(|a| lo[a] + (hi[a] - lo[a]) * v[a] as f32 / 4.0);
        g.encode(&params, &[p], &mut out);
        let row = (v[0] + 5 * v[1] + 25 * v[2]) as usize;
        assert_eq!(out[..2], params[off[0] + 2 * row..][..2], "{v:?}");
        // Level 2 (N = 16): vertex 4v, hashed.
        let w = v.map(|c| c * 4);
        let h = (w[0] ^ w[1].wrapping_mul(2_654_435_761) ^ w[2].wrapping_mul(805_459_861)) % 256;
        assert_eq!(out[4..], params[off[2] + 2 * h as usize..][..2], "{v:?}");
    }
}

#[test]
fn matches_f64_reference_and_is_continuous() {
    let g = small(6, 12, 3, 40);
    let params = random_params(&g, 2);
    let p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
    let pts = random_points(300, 3, 0.1);
    let dim = g.output_dim();
    let mut out = vec![0f32; pts.len() * dim];
    g.encode(&params, &pts, &mut out);
    for (p, o) in pts.iter().zip(out.chunks(dim)) {
        let want = reference(&g, &p64, *p);
        for k in 0..dim {
            assert!((o[k] as f64 - want[k]).abs() < 1e-5, "{p:?} {k}");
        }
    }
    // Every feature count (1, 2, 4, 8 take unrolled paths), forward and
    // backward: the gradient of Σ c·out is Σ c·(trilinear weight), which
    // the reference gives as the encoding of one-hot params.
    for features in [1, 3, 4, 8, 16] {
        let g = HashGrid::new(HashGridConfig {
            features,
            ..g.config().clone()
        })
        .unwrap();
        let params = random_params(&g, features as u64);
        let p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
        let dim = g.output_dim();
        let pts = &pts[..20];
        let mut out = vec![0f32; pts.len() * dim];
        g.encode(&params, pts, &mut out);
        for (p, o) in pts.iter().zip(out.chunks(dim)) {
            let want = reference(&g, &p64, *p);
            for k in 0..dim {
                assert!((o[k] as f64 - want[k]).abs() < 1e-5, "F={features} {k}");
            }
        }
        let c: Vec<f32> = (0..out.len()).map(|k| (k % 7) as f32 - 3.0).collect();
        let mut grad = vec![0f32; g.param_count()];
        let mut touched = g.touched_set();
        g.backward(pts, &c, &mut grad, &mut touched);
        // Touched entries of every level, and a few others (gradient 0).
        let f = features as usize;
        let mut entries: Vec<usize> = (0..6)
            .flat_map(|l| {
                let off = g.level_offsets()[l];
                let rows: Vec<usize> = touched.rows(l).step_by(5).collect();
                rows.into_iter().map(move |r| off + r * f + r % f)
            })
            .collect();
        entries.extend([0, g.param_count() / 2, g.param_count() - 1]);
        for j in entries {
            let mut onehot = vec![0f64; g.param_count()];
            onehot[j] = 1.0;
            let want: f64 = pts
                .iter()
                .enumerate()
                .map(|(i, &p)| {
                    let e = reference(&g, &onehot, p);
                    (0..dim).map(|k| c[i * dim + k] as f64 * e[k]).sum::<f64>()
                })
                .sum();
            assert!((grad[j] as f64 - want).abs() < 1e-5, "F={features} {j}");
        }
    }
    // Across a cell face of each level: values on either side of it
    // approach each other (|∂/∂x| ≤ 2·N/extent·max|param| ≤ 40 here).
    let mut a = vec![0f32; dim];
    let mut b = vec![0f32; dim];
    for &res in &g.resolutions() {
        let x = -1.0 + 2.0 * (res / 2) as f32 / res as f32;
        let e = 1e-4;
        g.encode(&params, &[[x - e, 1.3, 2.7]], &mut a);
        g.encode(&params, &[[x + e, 1.3, 2.7]], &mut b);
        for k in 0..dim {
            assert!((a[k] - b[k]).abs() < 2.0 * e * 40.0 + 1e-6, "{x} {k}");
        }
    }
}

#[test]
fn points_outside_read_the_nearest_face() {
    let g = small(4, 10, 2, 20);
    let params = random_params(&g, 4);
    let dim = g.output_dim();
    let mut a = vec![0f32; dim];
    let mut b = vec![0f32; dim];
    let pairs = [
        ([-5.0, 2.0, 2.5], [-1.0, 2.0, 2.5]),
        ([0.3, 1e30, 1.0], [0.3, 4.0, 2.0]),
        ([f32::INFINITY, -f32::INFINITY, 9.0], [1.0, 0.0, 3.0]),
        ([f32::NAN, 1.0, 2.5], [-1.0, 1.0, 2.5]),
    ];
    for (out, clamped) in pairs {
        g.encode(&params, &[out], &mut a);
        g.encode(&params, &[clamped], &mut b);
        assert_eq!(a, b, "{out:?}");
        assert!(a.iter().all(|v| v.is_finite()));
    }
}

#[test]
fn gradient_matches_finite_differences() {
    let g = small(5, 9, 2, 24);
    let params = random_params(&g, 5);
    let pts = random_points(40, 6, 0.05);
    let dim = g.output_dim();
    let mut rng = SplitMix64::new(7);
    let c: Vec<f32> = (0..pts.len() * dim)
        .map(|_| rng.next_f32() * 2.0 - 1.0)
        .collect();
    let mut grad = vec![0f32; g.param_count()];
    let mut touched = g.touched_set();
    g.backward(&pts, &c, &mut grad, &mut touched);
    // loss(θ) = Σ c·encode(θ), in f64 through the reference.
    let loss = |p: &[f64]| -> f64 {
        pts.iter()
            .enumerate()
            .map(|(i, &x)| {
                let e = reference(&g, p, x);
                (0..dim).map(|k| c[i * dim + k] as f64 * e[k]).sum::<f64>()
            })
            .sum()
    };
    let mut p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
    let f = 2;
    let offs = g.level_offsets();
    let mut checked = 0;
    for j in (0..g.param_count()).step_by(7) {
        let l = offs.iter().rposition(|&o| o <= j).unwrap();
        let row = (j - offs[l]) / f;
        if !touched.is_touched(l, row) {
            assert_eq!(grad[j], 0.0);
            continue;
        }
        let h = 1e-3;
        p64[j] += h;
        let up = loss(&p64);
        p64[j] -= 2.0 * h;
        let down = loss(&p64);
        p64[j] += h;
        let fd = (up - down) / (2.0 * h);
        assert!((grad[j] as f64 - fd).abs() < 1e-4 * (1.0 + fd.abs()), "{j}");
        checked += 1;
    }
    assert!(checked > 20, "{checked}");
    // The same in f32 through encode itself, for a few touched entries.
    let mut out = vec![0f32; pts.len() * dim];
    let f32_loss = |p: &[f32], out: &mut Vec<f32>| -> f64 {
        g.encode(p, &pts, out);
        out.iter().zip(&c).map(|(&a, &b)| a as f64 * b as f64).sum()
    };
    let mut p = params.clone();
    for (l, &off) in offs.iter().enumerate().take(5) {
        for row in touched.rows(l).take(3) {
            let j = off + row * f;
            let h = 1e-2;
            p[j] += h;
            let up = f32_loss(&p, &mut out);
            p[j] -= 2.0 * h;
            let down = f32_loss(&p, &mut out);
            p[j] = params[j];
            let fd = (up - down) / (2.0 * h as f64);
            assert!((grad[j] as f64 - fd).abs() < 2e-3 * (1.0 + fd.abs()), "{j}");
        }
    }
    // A second backward accumulates.
    let mut twice = grad.clone();
    g.backward(&pts, &c, &mut twice, &mut touched);
    for (a, b) in twice.iter().zip(&grad) {
        assert!((a - 2.0 * b).abs() <= 1e-6 * b.abs().max(1.0));
    }
}

#[test]
fn backward_is_bit_identical_across_thread_counts() {
    let g = small(8, 10, 4, 64);
    let pts = random_points(5000, 8, 0.0);
    let mut rng = SplitMix64::new(9);
    let d: Vec<f32> = (0..pts.len() * g.output_dim())
        .map(|_| rng.next_f32() - 0.5)
        .collect();
    let params = random_params(&g, 1);
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut grad = vec![0f32; g.param_count()];
        let mut t = g.touched_set();
        let mut out = vec![0f32; d.len()];
        pool.install(|| {
            g.backward(&pts, &d, &mut grad, &mut t);
            g.encode(&params, &pts, &mut out);
        });
        (
            grad.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            t.bits,
            out,
        )
    };
    let one = run(1);
    assert!(one == run(2));
    assert!(one == run(5));
}

#[test]
fn sparse_adam_updates_only_touched_rows() {
    let g = small(3, 8, 2, 12);
    let mut params = random_params(&g, 2);
    let before = params.clone();
    let n = g.param_count();
    let mut grad = vec![0f32; n];
    let mut m = vec![0.5f32; n];
    let mut v = vec![0.25f32; n];
    let mut touched = g.touched_set();
    let pts = random_points(10, 3, 0.0);
    let d = vec![1.0f32; pts.len() * g.output_dim()];
    g.backward(&pts, &d, &mut grad, &mut touched);
    let g0 = grad.clone();
    let rows = touched.clone();
    let adam = Adam {
        lr: 0.1,
        beta1: 0.9,
        beta2: 0.99,
        eps: 1e-8,
    };
    let step = 3;
    g.sparse_adam_update(
        &mut params,
        &mut grad,
        &mut m,
        &mut v,
        &mut touched,
        step,
        adam,
    )
    .unwrap();
    assert_eq!(touched.count(), 0);
    assert!(grad.iter().all(|&x| x == 0.0));
    let offs = g.level_offsets();
    for j in 0..n {
        let l = offs.iter().rposition(|&o| o <= j).unwrap();
        if rows.is_touched(l, (j - offs[l]) / 2) {
            // Adam in f64 from its definition.
            let gj = g0[j] as f64;
            let mj = 0.9 * 0.5 + 0.1 * gj;
            let vj = 0.99 * 0.25 + 0.01 * gj * gj;
            let mh = mj / (1.0 - 0.9f64.powi(3));
            let vh = vj / (1.0 - 0.99f64.powi(3));
            let want = before[j] as f64 - 0.1 * mh / (vh.sqrt() + 1e-8);
            assert!((params[j] as f64 - want).abs() < 1e-5, "{j}");
            assert!((m[j] as f64 - mj).abs() < 1e-6);
        } else {
            assert_eq!((params[j], m[j], v[j]), (before[j], 0.5, 0.25));
        }
    }
    let mut short = vec![0f32; n - 1];
    assert!(g
        .sparse_adam_update(&mut short, &mut grad, &mut m, &mut v, &mut touched, 1, adam)
        .is_err());
    assert!(g
        .sparse_adam_update(
            &mut params,
            &mut grad,
            &mut m,
            &mut v,
            &mut touched,
            0,
            adam
        )
        .is_err());
}

#[test]
fn throughput() {
    let g = HashGrid::new(HashGridConfig::default()).unwrap();
    let params = g.init(1);
    // Unoptimised builds time a smaller batch, so `cargo test` stays quick.
    let n = if cfg!(debug_assertions) { 4096 } else { 65536 };
    let pts = random_points(n, 1, 0.0);
    let mut out = vec![0f32; pts.len() * g.output_dim()];
    let mut grad = vec![0f32; g.param_count()];
    let mut touched = g.touched_set();
    // Best of several runs: the machine is shared, the minimum is the
    // least disturbed.
    let best = |f: &mut dyn FnMut()| {
        (0..if cfg!(debug_assertions) { 1 } else { 7 })
            .map(|_| {
                let t = std::time::Instant::now();
                f();
                t.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min)
    };
    let enc = best(&mut || g.encode(&params, &pts, &mut out));
    let back = best(&mut || g.backward(&pts, &out, &mut grad, &mut touched));
    let mut m = vec![1e-3f32; g.param_count()];
    let mut v = vec![1e-3f32; g.param_count()];
    let mut p = params.clone();
    let touched_rows = touched.count();
    let t = std::time::Instant::now();
    g.sparse_adam_update(
        &mut p,
        &mut grad,
        &mut m,
        &mut v,
        &mut touched,
        1,
        Adam::default(),
    )
    .unwrap();
    let adam = t.elapsed().as_secs_f64();
    println!(
        "hash grid (L=16, F=2, T=19, 16..2048), {n} points, {} threads: encode {:.2} M points/s, backward {:.2} M points/s, sparse Adam {:.1} ms ({touched_rows} rows)",
        rayon::current_num_threads(),
        n as f64 / enc / 1e6,
        n as f64 / back / 1e6,
        adam * 1e3
    );
}
