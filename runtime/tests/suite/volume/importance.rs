//! Importance sampling: the inverse CDF against f64, histograms, zero
//! weights, batches at any thread count, merging.

use sdfl_runtime::volume::importance::*;
use sdfl_runtime::volume::SplitMix64;

/// The CDF in f64, written from its definition (mass of every bin up to
/// `x`, linear inside a bin, a step for a zero-width bin).
fn cdf(t: &[f64], w: &[f64], x: f64) -> f64 {
    let mass: Vec<f64> = w[..t.len() - 1]
        .iter()
        .map(|&v| v.max(0.0) + WEIGHT_EPS)
        .collect();
    let total: f64 = mass.iter().sum();
    let mut f = 0.0;
    for k in 0..t.len() - 1 {
        let part = if t[k + 1] > t[k] {
            ((x - t[k]) / (t[k + 1] - t[k])).clamp(0.0, 1.0)
        } else if x >= t[k] {
            1.0
        } else {
            0.0
        };
        f += mass[k] * part;
    }
    f / total
}

/// The smallest `x` with `cdf(x) ≥ u`, by bisection.
fn inverse(t: &[f64], w: &[f64], u: f64) -> f64 {
    let (mut lo, mut hi) = (t[0], t[t.len() - 1]);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if cdf(t, w, mid) >= u {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

fn random_ray(rng: &mut SplitMix64, n: usize, zero_widths: bool) -> (Vec<f32>, Vec<f32>) {
    let mut t = vec![0.5f32 + rng.next_f32()];
    for _ in 1..n {
        let gap = if zero_widths && rng.next_f32() < 0.3 {
            0.0
        } else {
            0.01 + rng.next_f32()
        };
        t.push(t[t.len() - 1] + gap);
    }
    let w = (0..n)
        .map(|_| {
            let r = rng.next_f32();
            if r < 0.3 {
                0.0
            } else {
                r * r * r
            }
        })
        .collect();
    (t, w)
}

#[test]
fn matches_f64_inverse_cdf() {
    let mut rng = SplitMix64::new(11);
    for case in 0..60 {
        let n = 2 + case % 17;
        let m = 1 + (case * 7) % 40;
        let (t, w) = random_ray(&mut rng, n, case % 3 == 0);
        let t64: Vec<f64> = t.iter().map(|&v| v as f64).collect();
        let w64: Vec<f64> = w.iter().map(|&v| v as f64).collect();
        let scale = t64[n - 1] - t64[0] + 1.0;
        for jitter in [None, Some(case as u64)] {
            let mut out = vec![0f32; m];
            let mut r = jitter.map(SplitMix64::new);
            sample_pdf_ray(&t, &w, r.as_mut(), &mut out).unwrap();
            let mut r = jitter.map(SplitMix64::new);
            for (i, &o) in out.iter().enumerate() {
                let xi = r.as_mut().map_or(0.5, |r| r.next_f32() as f64);
                let want = inverse(&t64, &w64, (i as f64 + xi) / m as f64);
                assert!(
                    (o as f64 - want).abs() <= 1e-5 * scale,
                    "case {case} i {i}: {o} vs {want}"
                );
            }
            assert!(out.windows(2).all(|p| p[0] <= p[1]));
        }
    }
}

#[test]
fn histogram_matches_weights() {
    let t: Vec<f32> = (0..9).map(|k| k as f32 * 0.5).collect();
    let w = [0.0f32, 0.1, 0.5, 2.0, 0.0, 0.3, 0.05, 1.0, 7.0];
    let mass: Vec<f64> = w[..8].iter().map(|&v| v as f64 + WEIGHT_EPS).collect();
    let total: f64 = mass.iter().sum();
    let bin_of = |x: f32| ((x / 0.5) as usize).min(7);
    // One ray, many stratified samples: every count within one of m·p.
    let m = 100_000;
    let mut out = vec![0f32; m];
    sample_pdf_ray(&t, &w, Some(&mut SplitMix64::new(5)), &mut out).unwrap();
    let mut count = [0f64; 8];
    out.iter().for_each(|&x| count[bin_of(x)] += 1.0);
    for k in 0..8 {
        assert!(
            (count[k] - m as f64 * mass[k] / total).abs() <= 2.0,
            "bin {k}"
        );
    }
    // Many rays, few jittered samples each: the pooled histogram within
    // 4σ of the weights.
    let rays = 20_000;
    let (m, n) = (3, 9);
    let tt: Vec<f32> = t.iter().copied().cycle().take(rays * n).collect();
    let ww: Vec<f32> = w.iter().copied().cycle().take(rays * n).collect();
    let mut out = vec![0f32; rays * m];
    sample_pdf(&tt, &ww, n, m, Spacing::Jittered(9), &mut out).unwrap();
    let mut count = [0f64; 8];
    out.iter().for_each(|&x| count[bin_of(x)] += 1.0);
    let all = (rays * m) as f64;
    for k in 0..8 {
        let p = mass[k] / total;
        let sigma = (all * p * (1.0 - p)).sqrt().max(1.0);
        assert!((count[k] - all * p).abs() <= 4.0 * sigma, "bin {k}");
    }
}

#[test]
fn zero_weights_are_uniform() {
    let n = 11;
    let t: Vec<f32> = (0..n).map(|k| 2.0 + k as f32 * 0.25).collect();
    let m = 40;
    let mut out = vec![0f32; m];
    sample_pdf_ray(&t, &[0.0; 11], None, &mut out).unwrap();
    for (i, &o) in out.iter().enumerate() {
        let want = 2.0 + (i as f64 + 0.5) / m as f64 * 2.5;
        assert!((o as f64 - want).abs() < 1e-6, "{i}: {o} vs {want}");
    }
}

#[test]
fn hard_cases_stay_finite_sorted_and_in_range() {
    let big = [f32::MAX, f32::INFINITY, f32::NAN, -1.0, 1e38, 0.0, f32::MAX];
    let t: Vec<f32> = (0..7).map(|k| k as f32).collect();
    let mut out = vec![0f32; 64];
    for jitter in [None, Some(SplitMix64::new(1))] {
        let mut j = jitter;
        sample_pdf_ray(&t, &big, j.as_mut(), &mut out).unwrap();
        assert!(out.iter().all(|v| v.is_finite() && (0.0..=6.0).contains(v)));
        assert!(out.windows(2).all(|p| p[0] <= p[1]));
        // NaN, negative and 0 weights get (almost) nothing.
        assert!(out.iter().all(|&v| !(2.0..4.0).contains(&v) || v == 2.0));
    }
    // Coincident depths: every sample is that depth.
    sample_pdf_ray(&[3.0; 5], &[1.0, 0.0, 5.0, 2.0, 1.0], None, &mut out).unwrap();
    assert!(out.iter().all(|&v| v == 3.0));
    // Zero-width bins holding most of the weight put samples on them.
    let t = [0.0, 1.0, 1.0, 2.0];
    sample_pdf_ray(&t, &[0.0, 1e6, 0.0, 0.0], None, &mut out).unwrap();
    assert!(out.iter().all(|&v| v == 1.0));
    // n = 2, m = 1 and m = 0.
    let mut one = [0f32];
    sample_pdf_ray(&[1.0, 3.0], &[0.0, 0.0], None, &mut one).unwrap();
    assert_eq!(one[0], 2.0);
    sample_pdf_ray(&[1.0, 3.0], &[0.0, 0.0], None, &mut []).unwrap();
    // Refused: too few depths, unsorted or NaN depths, mismatched sizes.
    assert!(sample_pdf_ray(&[1.0], &[1.0], None, &mut one).is_err());
    assert!(sample_pdf_ray(&[2.0, 1.0], &[1.0, 1.0], None, &mut one).is_err());
    assert!(sample_pdf_ray(&[0.0, f32::NAN], &[1.0, 1.0], None, &mut one).is_err());
    assert!(sample_pdf_ray(&[0.0, 1.0], &[1.0], None, &mut one).is_err());
    assert!(sample_pdf(&[0.0, 1.0, 2.0], &[1.0; 3], 2, 1, Spacing::Even, &mut one).is_err());
    assert!(sample_pdf(&[0.0, 1.0], &[1.0; 2], 2, 2, Spacing::Even, &mut one).is_err());
    assert!(sample_pdf(&[1.0, 0.0], &[1.0; 2], 2, 1, Spacing::Even, &mut one).is_err());
}

#[test]
fn batches_match_single_rays_for_any_thread_count() {
    let mut rng = SplitMix64::new(3);
    let (rays, n, m) = (500, 12, 20);
    let (mut t, mut w) = (Vec::new(), Vec::new());
    for _ in 0..rays {
        let (a, b) = random_ray(&mut rng, n, true);
        t.extend(a);
        w.extend(b);
    }
    let run = |threads: usize, spacing: Spacing| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut out = vec![0f32; rays * m];
        pool.install(|| sample_pdf(&t, &w, n, m, spacing, &mut out).unwrap());
        out
    };
    for spacing in [Spacing::Even, Spacing::Jittered(77)] {
        let one = run(1, spacing);
        assert_eq!(one, run(2, spacing));
        assert_eq!(one, run(3, spacing));
        for r in 0..rays {
            let mut o = vec![0f32; m];
            let mut g = ray_rng(77, r as u64);
            let g = matches!(spacing, Spacing::Jittered(_)).then_some(&mut g);
            sample_pdf_ray(&t[r * n..][..n], &w[r * n..][..n], g, &mut o).unwrap();
            assert_eq!(o, one[r * m..][..m]);
        }
    }
    // Jitter differs between rays with identical inputs.
    let tt: Vec<f32> = t[..n].iter().copied().cycle().take(2 * n).collect();
    let ww: Vec<f32> = w[..n].iter().copied().cycle().take(2 * n).collect();
    let mut out = vec![0f32; 2 * m];
    sample_pdf(&tt, &ww, n, m, Spacing::Jittered(1), &mut out).unwrap();
    assert_ne!(out[..m], out[m..]);
}

#[test]
fn throughput() {
    // Unoptimised builds time a smaller batch, so `cargo test` stays quick.
    let rays = if cfg!(debug_assertions) { 2048 } else { 65536 };
    let (n, m) = (64, 128);
    let mut rng = SplitMix64::new(4);
    let (mut t, mut w) = (Vec::new(), Vec::new());
    for _ in 0..rays {
        let (a, b) = random_ray(&mut rng, n, false);
        t.extend(a);
        w.extend(b);
    }
    let mut fine = vec![0f32; rays * m];
    let mut merged = vec![0f32; rays * (n + m)];
    let best = |f: &mut dyn FnMut()| {
        (0..5)
            .map(|_| {
                let start = std::time::Instant::now();
                f();
                start.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min)
    };
    let sample = best(&mut || sample_pdf(&t, &w, n, m, Spacing::Jittered(1), &mut fine).unwrap());
    let merge = best(&mut || merge_depths(&t, n, &fine, m, &mut merged).unwrap());
    println!(
        "importance sampling, {rays} rays, n={n} → m={m}, {} threads: sample_pdf {:.2} M rays/s, merge {:.2} M rays/s",
        rayon::current_num_threads(),
        rays as f64 / sample / 1e6,
        rays as f64 / merge / 1e6
    );
}

#[test]
fn merge_is_the_sorted_union() {
    let mut rng = SplitMix64::new(8);
    let (rays, n, m) = (50, 9, 14);
    let mut coarse = Vec::new();
    let mut fine = vec![0f32; rays * m];
    let mut w = Vec::new();
    for _ in 0..rays {
        let (a, b) = random_ray(&mut rng, n, true);
        coarse.extend(a);
        w.extend(b);
    }
    sample_pdf(&coarse, &w, n, m, Spacing::Jittered(2), &mut fine).unwrap();
    let mut out = vec![0f32; rays * (n + m)];
    merge_depths(&coarse, n, &fine, m, &mut out).unwrap();
    for r in 0..rays {
        let mut want: Vec<f32> = coarse[r * n..][..n].to_vec();
        want.extend(&fine[r * m..][..m]);
        want.sort_by(f32::total_cmp);
        assert_eq!(want, out[r * (n + m)..][..n + m]);
    }
    assert!(merge_depths(&coarse, n, &fine[1..], m, &mut out).is_err());
    assert!(merge_depths(&coarse, 0, &fine, m, &mut out).is_err());
    let mut o = [0f32; 3];
    merge_depths(&[1.0, 2.0, 3.0], 3, &[], 0, &mut o).unwrap();
    assert_eq!(o, [1.0, 2.0, 3.0]);
}
