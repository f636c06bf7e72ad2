//! Tests of the occupancy grid and its march.

use sdfl_runtime::neural::occupancy::*;
use sdfl_runtime::volume::{Ray, SplitMix64};

fn grid(res: u32) -> OccupancyGrid {
    let mut c = OccupancyConfig::new([-1.0, -0.5, 0.0], [1.0, 1.5, 3.0]);
    c.res = res;
    OccupancyGrid::new(c).unwrap()
}

fn random_ray(rng: &mut SplitMix64) -> ([f32; 3], [f32; 3]) {
    let o = std::array::from_fn(|_| rng.next_f32() * 8.0 - 4.0);
    let target: [f32; 3] = [
        rng.next_f32() * 2.0 - 1.0,
        rng.next_f32() * 2.0 - 0.5,
        rng.next_f32() * 3.0,
    ];
    let d: [f32; 3] = std::array::from_fn(|a| target[a] - o[a]);
    let n = d.iter().map(|v| v * v).sum::<f32>().sqrt();
    (o, d.map(|v| v / n))
}

/// `n` rays of [`random_ray`], numbered as pixels.
fn random_rays(n: u32, rng: &mut SplitMix64) -> Vec<Ray> {
    (0..n)
        .map(|k| {
            let (origin, dir) = random_ray(rng);
            Ray {
                origin,
                dir,
                view: 0,
                pixel: k,
            }
        })
        .collect()
}

/// Fixed-step samples kept by `keep(cell)`, testing every sample.
fn brute(
    g: &OccupancyGrid,
    o: [f32; 3],
    d: [f32; 3],
    near: f32,
    far: f32,
    step: f32,
    keep: impl Fn(Option<[u32; 3]>) -> bool,
) -> Vec<f32> {
    let (mut t, mut dt) = (Vec::new(), Vec::new());
    fixed_step(near, far, step, &mut t, &mut dt).unwrap();
    t.into_iter()
        .filter(|&tk| keep(g.cell_of(std::array::from_fn(|a| o[a] + tk * d[a]))))
        .collect()
}

#[test]
fn all_occupied_equals_fixed_step() {
    let mut g = grid(16);
    let mut rng = SplitMix64::new(1);
    let (mut t, mut dt) = (Vec::new(), Vec::new());
    let (mut ft, mut fdt) = (Vec::new(), Vec::new());
    for i in 0..300 {
        let (o, d) = random_ray(&mut rng);
        let step = [0.01, 0.0371, 0.3][i % 3];
        // Inside the box: exactly the plain sampler's samples.
        let o_in = [0.1, 0.2, 1.5];
        g.march(o_in, d, 0.0, 0.45, step, &mut t, &mut dt).unwrap();
        fixed_step(0.0, 0.45, step, &mut ft, &mut fdt).unwrap();
        assert_eq!((&t, &dt), (&ft, &fdt));
        // Through the box: the plain samples inside it.
        g.march(o, d, 0.5, 12.0, step, &mut t, &mut dt).unwrap();
        let want = brute(&g, o, d, 0.5, 12.0, step, |c| c.is_some());
        assert_eq!(t, want);
        assert!(!t.is_empty());
        assert!(dt.iter().all(|&v| v == step));
        // Disabled: the plain sampler, box or not.
        g.set_enabled(false);
        g.march(o, d, 0.5, 12.0, step, &mut t, &mut dt).unwrap();
        fixed_step(0.5, 12.0, step, &mut ft, &mut fdt).unwrap();
        assert_eq!((&t, &dt), (&ft, &fdt));
        g.set_enabled(true);
    }
}

#[test]
fn one_occupied_cell_emits_only_inside_it() {
    let mut g = grid(8);
    g.fill(false);
    let target = [3u32, 4, 2];
    g.set_occupied(g.index(target), true);
    let (lo, hi) = ([-1.0f64, -0.5, 0.0], [1.0f64, 1.5, 3.0]);
    let cell: [(f64, f64); 3] = std::array::from_fn(|a| {
        let h = (hi[a] - lo[a]) / 8.0;
        (
            lo[a] + target[a] as f64 * h,
            lo[a] + (target[a] + 1) as f64 * h,
        )
    });
    let inside = |p: [f64; 3], margin: f64| {
        (0..3).all(|a| p[a] >= cell[a].0 - margin && p[a] < cell[a].1 + margin)
    };
    let mut rng = SplitMix64::new(2);
    let (mut t, mut dt) = (Vec::new(), Vec::new());
    let mut hits = 0;
    for i in 0..2000 {
        // Aim at the cell half the time.
        let (mut o, mut d) = random_ray(&mut rng);
        if i % 2 == 0 {
            let c: [f64; 3] = std::array::from_fn(|a| {
                cell[a].0 + rng.next_f32() as f64 * (cell[a].1 - cell[a].0)
            });
            let v: [f32; 3] = std::array::from_fn(|a| (c[a] - o[a] as f64) as f32);
            let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            d = v.map(|x| x / n);
        }
        if i % 7 == 0 {
            o = [0.0, 0.0, 1.0];
        }
        let step = [0.003, 0.02, 0.11][i % 3];
        g.march(o, d, 0.0, 10.0, step, &mut t, &mut dt).unwrap();
        let want = brute(&g, o, d, 0.0, 10.0, step, |c| c == Some(target));
        assert_eq!(t, want, "ray {i}");
        hits += t.len();
        for &tk in &t {
            let p = std::array::from_fn(|a| o[a] as f64 + tk as f64 * d[a] as f64);
            assert!(inside(p, 1e-5), "{p:?}");
        }
        // Brute force in f64: samples clearly inside are all emitted.
        let (mut all, mut adt) = (Vec::new(), Vec::new());
        fixed_step(0.0, 10.0, step, &mut all, &mut adt).unwrap();
        for &tk in &all {
            let p = std::array::from_fn(|a| o[a] as f64 + tk as f64 * d[a] as f64);
            if inside(p, -1e-5) {
                assert!(t.contains(&tk));
            }
        }
    }
    assert!(hits > 1000, "{hits}");
}

#[test]
fn sparse_grids_match_brute_force() {
    // Dense and sparse occupancy (empty blocks), R a multiple of the
    // block or not, occupied cells scattered or in one clump.
    let mut rng = SplitMix64::new(3);
    let mut kept = 0;
    for (res, p, clump) in [(32, 0.08, false), (37, 0.002, false), (64, 0.3, true)] {
        let mut g = grid(res);
        for c in 0..g.cells() {
            let r = res as usize;
            let near_centre = [c % r, c / r % r, c / (r * r)]
                .iter()
                .all(|&v| v.abs_diff(r / 2) < 4);
            let on = rng.next_f32() < p && (!clump || near_centre);
            g.set_occupied(c, on);
        }
        check_blocks(&g);
        let mut full = g.clone();
        full.fill(true);
        check_blocks(&full);
        assert_eq!(full.occupied_count(), full.cells());
        full.fill(false);
        check_blocks(&full);
        let (mut t, mut dt) = (Vec::new(), Vec::new());
        for i in 0..1000 {
            let (o, d) = random_ray(&mut rng);
            let step = [0.001, 0.013, 0.2][i % 3];
            g.march(o, d, 0.2, 11.0, step, &mut t, &mut dt).unwrap();
            let want = brute(&g, o, d, 0.2, 11.0, step, |c| {
                c.is_some_and(|c| g.is_occupied(g.index(c)))
            });
            assert_eq!(t, want, "R {res} ray {i}");
            kept += t.len();
        }
    }
    assert!(kept > 10_000, "{kept}");
}

/// The block counts agree with the bits.
fn check_blocks(g: &OccupancyGrid) {
    let mut want = vec![0u32; g.blocks.len()];
    let r = g.cfg.res as usize;
    for c in 0..g.cells() {
        if g.is_occupied(c) {
            want[g.block_of([c % r, c / r % r, c / (r * r)].map(|v| v as u32))] += 1;
        }
    }
    assert_eq!(want, g.blocks);
}

#[test]
fn batches_match_single_rays_for_any_thread_count() {
    let mut g = grid(40);
    let mut rng = SplitMix64::new(6);
    for c in 0..g.cells() {
        g.set_occupied(c, rng.next_f32() < 0.05);
    }
    let rays = random_rays(3000, &mut rng);
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut out = RaySamples::default();
        pool.install(|| g.march_rays(&rays, 0.1, 12.0, 0.01, None, &mut out))
            .unwrap();
        out
    };
    let one = run(1);
    assert_eq!(one, run(3));
    assert_eq!(one.offsets.len(), rays.len() + 1);
    let (mut t, mut dt) = (Vec::new(), Vec::new());
    for (r, ray) in rays.iter().enumerate() {
        g.march(ray.origin, ray.dir, 0.1, 12.0, 0.01, &mut t, &mut dt)
            .unwrap();
        assert_eq!(t, one.t[one.offsets[r]..one.offsets[r + 1]]);
        assert_eq!(dt, one.dt[one.offsets[r]..one.offsets[r + 1]]);
    }
    let mut bad = rays.clone();
    bad[2000].dir = [0.0; 3];
    let mut out = RaySamples::default();
    assert!(g.march_rays(&bad, 0.1, 12.0, 0.01, None, &mut out).is_err());
}

#[test]
fn grazing_rays_and_misses() {
    let mut g = grid(8);
    let mut rng = SplitMix64::new(4);
    for c in 0..g.cells() {
        g.set_occupied(c, rng.next_f32() < 0.3);
    }
    let (mut t, mut dt) = (Vec::new(), Vec::new());
    let occupied = |c: Option<[u32; 3]>| c.is_some_and(|c| g.is_occupied(g.index(c)));
    // Rays in the planes of cell faces (y = −0.5 + j/4, z = 3k/8),
    // along axes and diagonals within the plane, and along edges.
    let mut n = 0;
    for j in 0..=8 {
        for k in 0..=8 {
            let y = -0.5 + j as f32 * 0.25;
            let z = k as f32 * 0.375;
            for d in [
                [1.0, 0.0, 0.0],
                [-1.0, 0.0, 0.0],
                [0.6, 0.0, 0.8],
                [0.0, 0.0, -1.0],
            ] {
                let o = [
                    -3.0 * d[0],
                    y,
                    if d[2] == 0.0 { z } else { 1.5 - 3.0 * d[2] },
                ];
                for step in [0.01, 0.25] {
                    g.march(o, d, 0.0, 8.0, step, &mut t, &mut dt).unwrap();
                    assert_eq!(t, brute(&g, o, d, 0.0, 8.0, step, occupied));
                    n += t.len();
                }
            }
        }
    }
    assert!(n > 0);
    // The max faces are outside: a ray along y = 1.5 gets nothing.
    g.fill(true);
    g.march(
        [-2.0, 1.5, 1.0],
        [1.0, 0.0, 0.0],
        0.0,
        5.0,
        0.01,
        &mut t,
        &mut dt,
    )
    .unwrap();
    assert!(t.is_empty());
    g.march(
        [-2.0, -0.5, 0.0],
        [1.0, 0.0, 0.0],
        0.0,
        5.0,
        0.01,
        &mut t,
        &mut dt,
    )
    .unwrap();
    assert_eq!(t.len(), 200);
    // Misses: beside the box, pointing away, parallel outside.
    for (o, d) in [
        ([-2.0, 5.0, 1.0], [1.0, 0.0, 0.0]),
        ([0.0, 0.0, -1.0], [0.0, 0.0, -1.0]),
        ([3.0, 3.0, 5.0], [0.577, 0.577, 0.577]),
    ] {
        g.march(o, d, 0.0, 50.0, 0.01, &mut t, &mut dt).unwrap();
        assert!(t.is_empty() && dt.is_empty());
    }
    // Refused: NaN, zero direction, reversed range, zero step, too many.
    let o = [0.0; 3];
    let x = [1.0, 0.0, 0.0];
    assert!(g
        .march([f32::NAN, 0.0, 0.0], x, 0.0, 1.0, 0.1, &mut t, &mut dt)
        .is_err());
    assert!(g
        .march(o, [0.0; 3], 0.0, 1.0, 0.1, &mut t, &mut dt)
        .is_err());
    assert!(g.march(o, x, 1.0, 0.5, 0.1, &mut t, &mut dt).is_err());
    assert!(g.march(o, x, 0.0, 1.0, 0.0, &mut t, &mut dt).is_err());
    assert!(g.march(o, x, 0.0, 1e6, 1e-3, &mut t, &mut dt).is_err());
    assert!(g
        .march(o, x, 0.0, f32::INFINITY, 0.1, &mut t, &mut dt)
        .is_err());
    g.march(o, x, 1.0, 1.0, 0.1, &mut t, &mut dt).unwrap();
    assert!(t.is_empty());
}

#[test]
fn update_tracks_a_moving_sphere() {
    let mut cfg = OccupancyConfig::new([-1.0; 3], [1.0; 3]);
    cfg.res = 16;
    // Density threshold 1 (0.01 / 0.01), below the mean cell's density (the
    // sphere's 100 over ~7 % of the box), so the cap at the mean never
    // binds; the EMA's decay from the first update on (warm-up is tested on
    // its own).
    cfg.step_size = 0.01;
    cfg.warmup = 1;
    let mut g = OccupancyGrid::new(cfg).unwrap();
    assert_eq!(g.occupied_count(), g.cells());
    let sphere = |c: [f32; 3], r: f32| {
        move |p: &[[f32; 3]], out: &mut [f32]| {
            for (q, o) in p.iter().zip(out.iter_mut()) {
                let d2: f32 = (0..3).map(|a| (q[a] - c[a]).powi(2)).sum();
                *o = if d2 < r * r { 100.0 } else { 0.0 };
            }
        }
    };
    let h = 2.0 / 16.0;
    let centre =
        |ijk: [usize; 3]| -> [f32; 3] { std::array::from_fn(|a| -1.0 + (ijk[a] as f32 + 0.5) * h) };
    // Distance from a cell's centre to the sphere's centre, and the cell's
    // half-diagonal: fully inside or fully outside decides its bit.
    let half_diag = 3f32.sqrt() * h / 2.0;
    let classify = |g: &OccupancyGrid, c: [f32; 3], r: f32| {
        let (mut inside, mut outside) = (0, 0);
        for z in 0..16 {
            for y in 0..16 {
                for x in 0..16 {
                    let p = centre([x, y, z]);
                    let d = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum::<f32>().sqrt();
                    let occ = g.is_occupied(g.index([x as u32, y as u32, z as u32]));
                    if d + half_diag < r {
                        assert!(occ, "{x} {y} {z} inside");
                        inside += 1;
                    } else if d - half_diag > r {
                        assert!(!occ, "{x} {y} {z} outside");
                        outside += 1;
                    }
                }
            }
        }
        assert!(inside > 10 && outside > 100);
    };
    let mut rng = SplitMix64::new(5);
    let a = [-0.4, 0.0, 0.0];
    g.update(0, &mut sphere(a, 0.5), &mut rng);
    classify(&g, a, 0.5);
    let first = g.ema().to_vec();
    // The sphere moves: new cells at once, old ones after decaying below
    // the threshold (100·0.95^k ≤ 1 from k = 90 on).
    let b = [0.4, 0.0, 0.0];
    let only_a = g.index([3, 8, 8]); // centre −0.5625: in a, not in b.
    assert!(g.is_occupied(only_a));
    for k in 1..=90 {
        g.update(k, &mut sphere(b, 0.5), &mut rng);
        assert_eq!(g.is_occupied(only_a), k < 90, "update {k}");
    }
    classify(&g, b, 0.5);
    check_blocks(&g);
    // Same draws, same grid.
    let mut again = OccupancyGrid::new(g.config().clone()).unwrap();
    again.update(0, &mut sphere(a, 0.5), &mut SplitMix64::new(5));
    assert_eq!(again.ema(), &first[..]);
    // NaN and infinite densities stay finite / occupied.
    again.update(
        1,
        &mut |_: &[[f32; 3]], o: &mut [f32]| o.fill(f32::NAN),
        &mut rng,
    );
    assert!(again.ema().iter().all(|v| v.is_finite()));
    again.update(
        2,
        &mut |_: &[[f32; 3]], o: &mut [f32]| o.fill(f32::INFINITY),
        &mut rng,
    );
    assert!(again.ema().iter().all(|v| v.is_finite()));
    assert_eq!(again.occupied_count(), again.cells());
}

/// An 8³ grid over [-1, 1]³ with a step of 0.01, refreshed by quarters
/// after `warmup`, every `every` steps.
fn quartered(warmup: u64, every: u64) -> OccupancyGrid {
    let mut cfg = OccupancyConfig::new([-1.0; 3], [1.0; 3]);
    cfg.res = 8;
    cfg.warmup = warmup;
    cfg.subsets = 4;
    cfg.every = every;
    cfg.step_size = 0.01;
    OccupancyGrid::new(cfg).unwrap()
}

#[test]
fn subsets_after_warmup_update_a_stride() {
    let mut g = quartered(2, 1);
    let mut rng = SplitMix64::new(1);
    let mut one = |_: &[[f32; 3]], o: &mut [f32]| o.fill(1.0);
    g.update(0, &mut one, &mut rng);
    assert!(g.ema().iter().all(|&v| v == 1.0));
    let mut zero = |_: &[[f32; 3]], o: &mut [f32]| o.fill(0.0);
    g.update(6, &mut zero, &mut rng);
    for (c, &v) in g.ema().iter().enumerate() {
        assert_eq!(v, if c % 4 == 2 { 0.95 } else { 1.0 });
    }
}

#[test]
fn march_throughput() {
    let mut cfg = OccupancyConfig::new([-1.0; 3], [1.0; 3]);
    cfg.step_size = 0.01;
    let mut g = OccupancyGrid::new(cfg).unwrap();
    let start = std::time::Instant::now();
    g.update(
        0,
        &mut |p: &[[f32; 3]], o: &mut [f32]| {
            for (q, o) in p.iter().zip(o.iter_mut()) {
                let r = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
                *o = if (r - 0.5).abs() < 0.05 { 10.0 } else { 0.0 };
            }
        },
        &mut SplitMix64::new(1),
    );
    let update = start.elapsed().as_secs_f64();
    let mut rng = SplitMix64::new(2);
    let n = if cfg!(debug_assertions) { 1000 } else { 20_000 };
    let rays: Vec<_> = (0..n).map(|_| random_ray(&mut rng)).collect();
    let step = 3f32.sqrt() * 2.0 / 1024.0;
    let (mut t, mut dt) = (Vec::new(), Vec::new());
    let time = |g: &OccupancyGrid, t: &mut Vec<f32>, dt: &mut Vec<f32>| {
        let start = std::time::Instant::now();
        let mut n = 0;
        for (o, d) in &rays {
            g.march(*o, *d, 0.0, 12.0, step, t, dt).unwrap();
            n += t.len();
        }
        (start.elapsed().as_secs_f64(), n)
    };
    let (skip, n) = time(&g, &mut t, &mut dt);
    g.set_enabled(false);
    let (plain, m) = time(&g, &mut t, &mut dt);
    println!(
        "occupancy march (R=128, shell, step {step:.4}, one thread): {:.2} M rays/s, {n} samples kept of {m}; plain sampler {:.2} M rays/s; update of 128³ cells {:.0} ms",
        rays.len() as f64 / skip / 1e6,
        rays.len() as f64 / plain / 1e6,
        update * 1e3
    );
}

/// An untrained network's density is about uniform (Lego at 800²: 1.1
/// everywhere, above the 0.64 the threshold asks). With the EMA's decay
/// of 0.95 that stale value kept every cell occupied for 11 refreshes
/// (176 steps, each evaluating 71 % of the samples); warm-up refreshes
/// forget at [`WARMUP_DECAY`] a refresh, so the grid follows the network
/// from the second refresh, while a cell seen dense once stays occupied
/// for a few refreshes of other jitter points.
#[test]
fn warm_up_forgets_an_untrained_networks_density() {
    let mut cfg = OccupancyConfig::new([-1.0; 3], [1.0; 3]);
    cfg.res = 8;
    cfg.warmup = 64;
    // Density threshold 0.64.
    cfg.step_size = 0.015625;
    let mut g = OccupancyGrid::new(cfg).unwrap();
    let mut rng = SplitMix64::new(3);
    let mut uniform = |_: &[[f32; 3]], o: &mut [f32]| o.fill(1.1);
    g.update(0, &mut uniform, &mut rng);
    assert_eq!(g.occupied_count(), g.cells());
    // The network learns the space is empty, but for one cell.
    let dense = g.index([2, 3, 4]);
    let mut empty = |p: &[[f32; 3]], o: &mut [f32]| {
        for (q, o) in p.iter().zip(o.iter_mut()) {
            let inside = (-0.5..-0.25).contains(&q[0])
                && (-0.25..0.0).contains(&q[1])
                && (0.0..0.25).contains(&q[2]);
            *o = if inside { 8.0 } else { 0.0 };
        }
    };
    g.update(16, &mut empty, &mut rng);
    assert_eq!(g.occupied_count(), 1);
    assert!(g.is_occupied(dense));
    // Seen once at 8, it stays for refreshes that miss it (8·0.5^k > 0.64
    // for k ≤ 3), then goes.
    let mut zero = |_: &[[f32; 3]], o: &mut [f32]| o.fill(0.0);
    for (k, step) in [32u64, 48, 60].into_iter().enumerate() {
        g.update(step, &mut zero, &mut rng);
        assert!(g.is_occupied(dense), "refresh {k}");
    }
    // At 0.5 its opacity is below the threshold (0.5 · 0.015625 < 0.01),
    // but it is the field's only density, far above the mean cell's, and the
    // threshold is capped at the mean: it stays, and only it.
    g.update(63, &mut zero, &mut rng);
    assert_eq!(g.occupied_count(), 1);
    assert!(g.is_occupied(dense));
    // After warm-up the EMA decays at `decay`.
    g.update(
        64,
        &mut |_: &[[f32; 3]], o: &mut [f32]| o.fill(10.0),
        &mut rng,
    );
    g.update(80, &mut zero, &mut rng);
    assert!(g.ema().iter().all(|&v| v == 9.5));
}

/// With a fine step (768 samples over Lego's [2, 6]: 0.0052) the absolute
/// threshold asks a density of 1.9, above an untrained network's ~1.1 in
/// every cell: the first refresh emptied the grid and training stopped
/// dead (a constant loss, no samples reaching the network). The threshold
/// is capped at the mean cell's, as instant-ngp and nerfacc cap it.
#[test]
fn a_fine_step_keeps_an_untrained_field_occupied() {
    let mut cfg = OccupancyConfig::new([-1.5; 3], [1.5; 3]);
    cfg.res = 16;
    cfg.step_size = 4.0 / 768.0;
    let mut g = OccupancyGrid::new(cfg).unwrap();
    let mut rng = SplitMix64::new(9);
    // About uniform: 1.1 with a ripple of ±5 %.
    let mut untrained = |p: &[[f32; 3]], o: &mut [f32]| {
        for (q, o) in p.iter().zip(o.iter_mut()) {
            *o = 1.1 * (1.0 + 0.05 * (7.0 * q[0] + 3.0 * q[1] - 5.0 * q[2]).sin());
        }
    };
    g.update(0, &mut untrained, &mut rng);
    let share = g.occupied_count() as f64 / g.cells() as f64;
    assert!((0.3..0.7).contains(&share), "{share}");
    // Exactly uniform: every cell is at the mean, and all stay.
    let mut g = OccupancyGrid::new(g.config().clone()).unwrap();
    g.update(
        0,
        &mut |_: &[[f32; 3]], o: &mut [f32]| o.fill(1.1),
        &mut rng,
    );
    assert_eq!(g.occupied_count(), g.cells());
    // A trained field dense in a corner: the absolute threshold rules, as
    // the mean is above it.
    let mut corner = |p: &[[f32; 3]], o: &mut [f32]| {
        for (q, o) in p.iter().zip(o.iter_mut()) {
            *o = if q.iter().all(|&x| x < -0.75) {
                4000.0
            } else {
                1.0
            };
        }
    };
    for step in 1..4 {
        g.update(step, &mut corner, &mut rng);
    }
    let corner_cells = 4usize.pow(3);
    assert!(g.occupied_count() >= corner_cells && g.occupied_count() < 2 * corner_cells);
}

/// A jittered march moves each ray's fixed steps by one offset of at most
/// half a step, drawn from the seed and the ray: the same samples for the
/// same seed, others for another, every sample within `[near, far)` and
/// spaced by the step; with every cell occupied, as many as the plain
/// march to within one.
#[test]
fn a_jittered_march_moves_each_ray_by_one_offset() {
    let g = grid(16);
    let mut rng = SplitMix64::new(4);
    let rays = random_rays(64, &mut rng);
    let (near, far, step) = (0.1, 6.0, 0.05);
    let march = |jitter| {
        let mut out = RaySamples::default();
        g.march_rays(&rays, near, far, step, jitter, &mut out)
            .unwrap();
        out
    };
    let (plain, a, again, b) = (march(None), march(Some(1)), march(Some(1)), march(Some(2)));
    assert_eq!(a.t, again.t);
    assert_ne!(a.t, b.t);
    let mut moved = 0;
    for r in 0..rays.len() {
        let (p, j) = (
            &plain.t[plain.offsets[r]..plain.offsets[r + 1]],
            &a.t[a.offsets[r]..a.offsets[r + 1]],
        );
        assert!(
            p.len().abs_diff(j.len()) <= 1,
            "ray {r}: {} and {}",
            p.len(),
            j.len()
        );
        assert!(j.iter().all(|&t| (near..far).contains(&t)), "ray {r}");
        for w in j.windows(2) {
            assert!((w[1] - w[0] - step).abs() < 1e-4, "ray {r}: {w:?}");
        }
        // Each sample's offset from the plain lattice, in steps: one per
        // ray, at most a half.
        let offset = |t: f32| {
            let x = (t - near) / step - 0.5;
            x - x.round()
        };
        assert!(p.iter().all(|&t| offset(t).abs() < 1e-3), "ray {r}");
        if let Some(&first) = j.first() {
            let d = offset(first);
            assert!(j.iter().all(|&t| (offset(t) - d).abs() < 1e-3), "ray {r}");
            moved += usize::from(d.abs() > 1e-3);
        }
    }
    assert!(moved > 10, "{moved}");
}

/// A grid's first refresh evaluates every cell, whatever its step: one
/// first refreshed after warm-up (an unbounded field's grid waits for
/// density to grow) must not empty the cells outside that step's subset,
/// which it has never evaluated. (Three quarters of an unbounded capture's
/// grid went empty at its first refresh, and held-out PSNR fell from 26.7
/// to 19.4 dB.)
#[test]
fn a_first_refresh_after_warm_up_evaluates_every_cell() {
    let mut g = quartered(4, 1);
    let mut rng = SplitMix64::new(3);
    let mut dense = |_: &[[f32; 3]], o: &mut [f32]| o.fill(10.0);
    g.update(300, &mut dense, &mut rng);
    assert!(g.ema().iter().all(|&v| v == 10.0));
    assert_eq!(g.occupied_count(), g.cells());
    // Later refreshes take their subset again.
    let mut zero = |_: &[[f32; 3]], o: &mut [f32]| o.fill(0.0);
    g.update(301, &mut zero, &mut rng);
    for (c, &v) in g.ema().iter().enumerate() {
        assert_eq!(v, if c % 4 == 1 { 9.5 } else { 10.0 });
    }
    // A grid restored from a checkpoint has been refreshed: its next
    // refresh takes a subset.
    let mut r = OccupancyGrid::new(g.config().clone()).unwrap();
    r.restore(g.ema(), &vec![true; g.cells()]).unwrap();
    r.update(302, &mut zero, &mut rng);
    for (c, &v) in r.ema().iter().enumerate() {
        assert_eq!(v, [10.0, 9.5, 9.5, 10.0][c % 4]);
    }
}

/// After warm-up, refreshes every `every` steps take the subsets in turn:
/// `subsets` consecutive refreshes evaluate every cell once. (Chosen by
/// `step mod subsets`, refreshes every 16 steps took the same quarter of
/// the cells forever, and the rest kept their warm-up state.)
#[test]
fn refreshes_every_few_steps_take_every_subset_in_turn() {
    let mut g = quartered(256, 16);
    let mut rng = SplitMix64::new(5);
    g.update(
        0,
        &mut |_: &[[f32; 3]], o: &mut [f32]| o.fill(10.0),
        &mut rng,
    );
    let mut zero = |_: &[[f32; 3]], o: &mut [f32]| o.fill(0.0);
    for k in 0..4u64 {
        g.update(256 + 16 * k, &mut zero, &mut rng);
    }
    assert!(
        g.ema().iter().all(|&v| v == 9.5),
        "some cell was never refreshed"
    );
}
