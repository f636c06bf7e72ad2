//! fp32 products: against f64 sums, row splits, non-finite operands.

use sdfl_runtime::neural::fp32::*;

fn numbers(len: usize, seed: u32) -> Vec<f32> {
    let mut s = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
    (0..len)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            (s % 2001) as f32 / 1000.0 - 1.0
        })
        .collect()
}

/// The kernel against f64 sums, over shapes with every kind of edge
/// (partial tiles, partial panels, several chunks of the sum), both
/// layouts of `A` and both modes.
#[test]
fn products_match_f64_sums() {
    if !available() {
        eprintln!("no AVX-512 F here: the kernel is not run");
        return;
    }
    for (m, k, n) in [
        (1, 1, 1),
        (13, 7, 33),
        (12, 128, 32),
        (25, 129, 17),
        (5, 300, 64),
        (40, 27, 128),
        (3, 256, 100),
    ] {
        for transposed in [false, true] {
            for accumulate in [false, true] {
                let (lda, ldb, ldc) = (if transposed { m + 2 } else { k + 3 }, n + 1, n + 5);
                let a_data = numbers(if transposed { k * lda } else { m * lda }, 1);
                let b = numbers(k * ldb, 2);
                let c0 = numbers(m * ldc, 3);
                let a = if transposed {
                    Strided::transposed(&a_data, lda)
                } else {
                    Strided::row_major(&a_data, lda)
                };
                let mut c = c0.clone();
                matmul(m, k, n, a, &b, ldb, &mut c, ldc, accumulate);
                for i in 0..m {
                    for j in 0..ldc {
                        let got = c[i * ldc + j];
                        if j >= n {
                            assert_eq!(got, c0[i * ldc + j], "outside C touched");
                            continue;
                        }
                        let at = |r: usize| a.data[i * a.rows + r * a.cols] as f64;
                        let mut want = if accumulate {
                            c0[i * ldc + j] as f64
                        } else {
                            0.0
                        };
                        let mut size = want.abs();
                        for r in 0..k {
                            let p = at(r) * b[r * ldb + j] as f64;
                            want += p;
                            size += p.abs();
                        }
                        let tol = (k as f64 + 1.0) * f32::EPSILON as f64 * size;
                        assert!(
                            (got as f64 - want).abs() <= tol,
                            "{m}×{k}×{n} ({transposed}, {accumulate}) at ({i}, {j}): {got} vs {want}"
                        );
                    }
                }
            }
        }
    }
}

/// How rows are split among calls does not change a bit.
#[test]
fn splitting_rows_changes_nothing() {
    if !available() {
        return;
    }
    let (m, k, n) = (37, 200, 70);
    let (a, b) = (numbers(m * k, 4), numbers(k * n, 5));
    let mut whole = vec![0.0; m * n];
    matmul(
        m,
        k,
        n,
        Strided::row_major(&a, k),
        &b,
        n,
        &mut whole,
        n,
        false,
    );
    let mut split = vec![0.0; m * n];
    for (r0, rows) in [(0, 5), (5, 13), (18, 19)] {
        let a = Strided::row_major(&a[r0 * k..], k);
        matmul(rows, k, n, a, &b, n, &mut split[r0 * n..], n, false);
    }
    assert_eq!(whole, split);
}

/// Strides whose last index passes `usize` are refused, not wrapped.
#[test]
#[should_panic(expected = "A holds m × k")]
fn overflowing_strides_are_refused() {
    let data = [1.0f32; 3];
    let a = Strided {
        data: &data,
        rows: (usize::MAX / 3) + 1,
        cols: 0,
    };
    let mut c = [0.0f32; 4];
    matmul(4, 1, 1, a, &[1.0], 1, &mut c, 1, false);
}

/// Non-finite operands reach the sums as IEEE arithmetic says (no
/// masked-off lane or skipped step hides them).
#[test]
fn non_finite_operands_propagate() {
    if !available() {
        return;
    }
    let (m, k, n) = (2, 3, 2);
    let a = [1.0, f32::NAN, 0.0, 1.0, 1.0, f32::INFINITY];
    let b = [1.0; 6];
    let mut c = [0.0; 4];
    matmul(m, k, n, Strided::row_major(&a, k), &b, n, &mut c, n, false);
    assert!(c[0].is_nan() && c[1].is_nan());
    assert_eq!(c[2], f32::INFINITY);
}
