//! bf16 kernels: rounding to nearest even, against f64 on rounded inputs
//! and against fp32, packing, extreme inputs.

use sdfl_runtime::neural::bf16::*;
use sdfl_runtime::volume::SplitMix64;

/// The kernels to check here: the portable one, and the native one
/// where this CPU has it.
/// `a · b` (row-major m×k and k×n) by `kernel`, into a fresh matrix.
fn product(kernel: Kernel, m: usize, k: usize, n: usize, a: &[f32], b: &[f32]) -> Vec<f32> {
    let mut c = vec![0.0; m * n];
    matmul(
        kernel,
        m,
        a,
        k,
        &Packed::new(b, k, n, n, 1),
        &mut c,
        n,
        false,
    );
    c
}

fn kernels() -> Vec<Kernel> {
    std::iter::once(Kernel::Emulated)
        .chain(Kernel::native())
        .collect()
}

fn random(n: usize, rng: &mut SplitMix64) -> Vec<f32> {
    (0..n).map(|_| 2.0 * rng.next_f32() - 1.0).collect()
}

/// `(Σ a·b, Σ |a·b|)` in f64 for every output, `A` rows `lda` apart and
/// `B` row-major; inputs passed through `f` first.
#[allow(clippy::too_many_arguments)]
fn reference(
    m: usize,
    k: usize,
    n: usize,
    a: &[f32],
    lda: usize,
    b: &[f32],
    f: impl Fn(f32) -> f32,
) -> Vec<(f64, f64)> {
    let mut out = vec![(0.0, 0.0); m * n];
    for i in 0..m {
        for j in 0..n {
            let (mut s, mut abs) = (0f64, 0f64);
            for c in 0..k {
                let p = f(a[i * lda + c]) as f64 * f(b[c * n + j]) as f64;
                s += p;
                abs += p.abs();
            }
            out[i * n + j] = (s, abs);
        }
    }
    out
}

/// Rows not a multiple of the 12-row tile, widths not multiples of
/// 16 or 32, odd inner sizes, and the NeRF's 128 × 128.
const SHAPES: [(usize, usize, usize); 8] = [
    (1, 1, 1),
    (13, 17, 19),
    (37, 33, 47),
    (25, 39, 64),
    (41, 255, 33),
    (12, 16, 16),
    (300, 128, 128),
    (1030, 128, 3),
];

#[test]
fn rounding_is_to_nearest_even() {
    let one = 1.0f32;
    let ulp = 2f32.powi(-7); // bf16's spacing just above 1
    assert_eq!(round(one + ulp / 2.0), one, "tie to even (down)");
    assert_eq!(round(one + 1.5 * ulp), one + 2.0 * ulp, "tie to even (up)");
    assert_eq!(round(one + 0.51 * ulp), one + ulp);
    assert_eq!(round(-(one + 0.49 * ulp)), -one);
    assert_eq!(round(f32::MAX), f32::INFINITY, "past the largest bf16");
    assert_eq!(round(1e-40).to_bits(), 0, "denormals flush");
    assert_eq!(round(-1e-40).to_bits(), (-0f32).to_bits());
    assert!(round(f32::NAN).is_nan());
    assert_eq!(round(f32::NEG_INFINITY), f32::NEG_INFINITY);
    let mut rng = SplitMix64::new(5);
    for x in random(10_000, &mut rng) {
        let r = round(x * 1e3);
        assert!((r - x * 1e3).abs() <= (x * 1e3).abs() * 2f32.powi(-8));
        assert_eq!(r.to_bits() & 0xffff, 0);
    }
}

/// With `B = 1` (k = 1) the kernel returns its rounding of `A`: the
/// native conversion matches [`round`] bit for bit, ties and denormals
/// included.
#[test]
fn kernels_round_like_round() {
    let mut a: Vec<f32> = vec![
        1.0 + 2f32.powi(-8),
        1.0 + 3.0 * 2f32.powi(-8),
        -1.0 - 2f32.powi(-8),
        1e-40,
        -1e-40,
        0.0,
        -0.0,
        f32::MIN_POSITIVE,
        3.3e38,
        1e30,
    ];
    let mut rng = SplitMix64::new(6);
    a.extend(random(500, &mut rng).iter().map(|x| x * 7.0));
    let b = Packed::new(&[1.0], 1, 1, 1, 1);
    for kernel in kernels() {
        let mut c = vec![f32::NAN; a.len()];
        matmul(kernel, a.len(), &a, 1, &b, &mut c, 1, false);
        for (x, y) in a.iter().zip(&c) {
            // A flushed denormal sums to +0 from a +0 accumulator.
            let want = round(*x) + 0.0;
            assert_eq!(
                y.to_bits(),
                want.to_bits(),
                "{kernel:?} rounds {x:e} to {y:e}"
            );
        }
    }
}

/// Against f64 on bf16-rounded inputs only fp32 summation differs:
/// within `(k + 2)·2⁻²⁴·Σ|a·b|`. Accumulating onto `C` adds one
/// rounding of the sum.
#[test]
fn kernels_match_f64_on_rounded_inputs() {
    let mut rng = SplitMix64::new(7);
    for kernel in kernels() {
        for &(m, k, n) in &SHAPES {
            // Rows of A wider than k: a view into a wider matrix.
            let lda = k + 3;
            let a = random(m * lda, &mut rng);
            let b = random(k * n, &mut rng);
            let want = reference(m, k, n, &a, lda, &b, round);
            let packed = Packed::new(&b, k, n, n, 1);
            let init = random(m * n, &mut rng);
            for accumulate in [false, true] {
                let mut c = init.clone();
                matmul(kernel, m, &a, lda, &packed, &mut c, n, accumulate);
                for (idx, (got, &(s, abs))) in c.iter().zip(&want).enumerate() {
                    let base = if accumulate { init[idx] as f64 } else { 0.0 };
                    let tol = (k as f64 + 2.0) * 2f64.powi(-24) * (abs + base.abs());
                    assert!(
                        (*got as f64 - base - s).abs() <= tol + 1e-30,
                        "{kernel:?} {m}×{k}×{n} [{idx}]: {got} vs {}",
                        base + s
                    );
                }
            }
        }
    }
}

/// Against the product of the unrounded inputs: each input moves by
/// at most 2⁻⁸ relative (half of bf16's 2⁻⁷ spacing), so each product
/// by at most ≈ 2⁻⁷; the sum stays within `2⁻⁶·Σ|a·b|` (loose: the
/// errors are random, so typical ones are far smaller).
#[test]
fn kernels_are_close_to_fp32() {
    let mut rng = SplitMix64::new(8);
    for kernel in kernels() {
        for &(m, k, n) in &SHAPES {
            let a = random(m * k, &mut rng);
            let b = random(k * n, &mut rng);
            let want = reference(m, k, n, &a, k, &b, |x| x);
            let c = product(kernel, m, k, n, &a, &b);
            for (got, &(s, abs)) in c.iter().zip(&want) {
                assert!((*got as f64 - s).abs() <= 2f64.powi(-6) * abs + 1e-30);
            }
        }
    }
}

/// `Xᵀ·B` (a weight gradient: sums over rows) against f64 on rounded
/// inputs, with the same bound.
#[test]
fn transposed_products_match_f64_on_rounded_inputs() {
    let mut rng = SplitMix64::new(10);
    for kernel in kernels() {
        for &(rows, k, n) in &SHAPES {
            let x = random(rows * k, &mut rng);
            let b = random(rows * n, &mut rng);
            let xt: Vec<f32> = (0..k * rows)
                .map(|i| x[(i % rows) * k + i / rows])
                .collect();
            let want = reference(k, rows, n, &xt, rows, &b, round);
            let mut c = vec![f32::NAN; k * n];
            matmul_tn(kernel, &x, k, &Packed::new(&b, rows, n, n, 1), &mut c, n);
            for (idx, (got, &(s, abs))) in c.iter().zip(&want).enumerate() {
                let tol = (rows as f64 + 2.0) * 2f64.powi(-24) * abs;
                assert!(
                    (*got as f64 - s).abs() <= tol + 1e-30,
                    "{kernel:?} {rows}×{k}×{n} [{idx}]: {got} vs {s}"
                );
            }
        }
    }
}

/// A transposed right operand (`B[i][j] = b[j·k + i]`, the input
/// adjoint's `Wᵀ`) packs the same as its row-major copy.
#[test]
fn strided_packing_equals_row_major() {
    let (k, n) = (37, 21);
    let mut rng = SplitMix64::new(9);
    let bt = random(n * k, &mut rng); // n × k: B transposed
    let b: Vec<f32> = (0..k * n).map(|x| bt[(x % n) * k + x / n]).collect();
    assert_eq!(
        Packed::new(&bt, k, n, 1, k).words,
        Packed::new(&b, k, n, n, 1).words
    );
}

/// Huge, tiny, denormal and zero inputs whose products fit in fp32
/// give finite sums.
#[test]
fn extreme_inputs_stay_finite() {
    let (m, k, n) = (29, 40, 35);
    let vals = [
        1e18f32, -1e18, 1e-30, -1e-38, 1e-42, 0.0, -0.0, 3.0e-39, 1.0,
    ];
    let a: Vec<f32> = (0..m * k).map(|i| vals[i % vals.len()]).collect();
    let b: Vec<f32> = (0..k * n).map(|i| vals[(i * 7 + 3) % vals.len()]).collect();
    let want = reference(m, k, n, &a, k, &b, round);
    for kernel in kernels() {
        let c = product(kernel, m, k, n, &a, &b);
        for (got, &(s, abs)) in c.iter().zip(&want) {
            assert!(got.is_finite(), "{kernel:?}: {got}");
            assert!((*got as f64 - s).abs() <= 1e-5 * abs + 1e-30);
        }
    }
}
