//! Matrix products in fp32 with AVX-512 register tiles that read both
//! operands where they lie: no packing.
//!
//! A general product library (matrixmultiply) copies both operands into
//! panels on every call; at a network layer's shapes (an inner dimension
//! and a width of ~128) each copied number serves only ~128 multiply-adds,
//! so the copies cost a fifth of the products' time. Here a 12 × 32 tile of
//! `C` lives in 24 registers while the sum runs: a row of `B`'s 32 columns
//! is two vector loads (a layer's weights, or the adjoints' rows, read in
//! place, masked at the edges), an element of `A` one broadcast (at any
//! strides, so `Xᵀ` needs no transpose). The sum over `r` runs in chunks of
//! `KC` (a panel of `B` stays in L1), each element's products added in
//! order of `r`: the result depends only on the operands, not on how rows
//! are split among threads.
//!
//! [`available`] says whether the CPU runs it (AVX-512 F, checked at run
//! time); callers fall back to matrixmultiply elsewhere.

/// Columns per tile: two 16-lane vectors.
const NR: usize = 32;
/// Rows per tile: 12 × 2 accumulators, 2 for `B`, 1 broadcast.
const MR: usize = 12;
/// Steps of the sum per chunk: a 32-column panel of `B` is 16 KiB.
const KC: usize = 128;

/// Whether the kernel runs here: the CPU has AVX-512 F and
/// [`crate::cpu::kernels`] allows it.
#[inline]
pub fn available() -> bool {
    crate::cpu::kernels().avx512f
}

/// An operand read in place: element `(i, r)` at `data[i·rows + r·cols]`.
#[derive(Debug, Clone, Copy)]
pub struct Strided<'a> {
    /// The operand's numbers.
    pub data: &'a [f32],
    /// Distance between consecutive rows.
    pub rows: usize,
    /// Distance between consecutive columns.
    pub cols: usize,
}

impl<'a> Strided<'a> {
    /// Row-major with rows `ld` apart.
    pub fn row_major(data: &'a [f32], ld: usize) -> Self {
        Strided {
            data,
            rows: ld,
            cols: 1,
        }
    }

    /// The transpose of a row-major matrix with rows `ld` apart.
    pub fn transposed(data: &'a [f32], ld: usize) -> Self {
        Strided {
            data,
            rows: 1,
            cols: ld,
        }
    }

    /// Whether `(rows − 1, cols − 1)` lies in `data` (non-empty shapes;
    /// an index past `usize` does not).
    fn holds(&self, rows: usize, cols: usize) -> bool {
        rows == 0 || cols == 0 || last_index(rows, self.rows, cols, self.cols, self.data.len())
    }
}

/// Whether `(rows − 1)·row_step + (cols − 1)·col_step < len`, without
/// overflow (for `rows, cols ≥ 1`).
fn last_index(rows: usize, row_step: usize, cols: usize, col_step: usize, len: usize) -> bool {
    (rows - 1)
        .checked_mul(row_step)
        .zip((cols - 1).checked_mul(col_step))
        .and_then(|(a, b)| a.checked_add(b))
        .is_some_and(|last| last < len)
}

/// `C = A·B` (or `C += A·B` when `accumulate`) for `A` `m × k` (any
/// strides), `B` `k × n` row-major with rows `ldb` apart, `C` `m × n` with
/// rows `ldc` apart. One thread; callers split rows. Panics unless
/// [`available`] or if an operand is too short for its shape.
#[allow(clippy::too_many_arguments)]
pub fn matmul(
    m: usize,
    k: usize,
    n: usize,
    a: Strided,
    b: &[f32],
    ldb: usize,
    c: &mut [f32],
    ldc: usize,
    accumulate: bool,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(a.holds(m, k), "A holds m × k");
    assert!(k == 0 || last_index(k, ldb, n, 1, b.len()), "B holds k × n");
    assert!(m == 1 || ldc >= n, "rows of C do not overlap");
    assert!(last_index(m, ldc, n, 1, c.len()), "C holds m × n");
    if k == 0 {
        if !accumulate {
            for i in 0..m {
                c[i * ldc..i * ldc + n].fill(0.0);
            }
        }
        return;
    }
    #[cfg(target_arch = "x86_64")]
    {
        assert!(available(), "the AVX-512 fp32 kernel on a CPU without it");
        // SAFETY: AVX-512 F checked just above; every index the kernel
        // forms is below the bounds asserted above (rows < m, columns < n
        // by masks, sum steps < k).
        unsafe { avx512::matmul(m, k, n, a, b, ldb, c, ldc, accumulate) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!("no AVX-512 kernel off x86-64")
}

#[cfg(target_arch = "x86_64")]
pub(super) mod avx512 {
    use super::{Strided, KC, MR, NR};
    use std::arch::x86_64::*;

    /// Lanes `0..len.min(16)` set (also for the bf16 kernel's edges).
    #[inline(always)]
    pub(in crate::neural) fn mask(len: usize) -> __mmask16 {
        if len >= 16 {
            0xffff
        } else {
            ((1u32 << len) - 1) as __mmask16
        }
    }

    #[target_feature(enable = "avx512f")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn matmul(
        m: usize,
        k: usize,
        n: usize,
        a: Strided,
        b: &[f32],
        ldb: usize,
        c: &mut [f32],
        ldc: usize,
        accumulate: bool,
    ) {
        let (a_ptr, b_ptr, c_ptr) = (a.data.as_ptr(), b.as_ptr(), c.as_mut_ptr());
        for r0 in (0..k).step_by(KC) {
            let steps = KC.min(k - r0);
            // The first chunk starts from C (accumulating) or from zero.
            let load = r0 > 0 || accumulate;
            for j0 in (0..n).step_by(NR) {
                let cols = n - j0;
                let masks = [mask(cols), mask(cols.saturating_sub(16))];
                let panel = b_ptr.add(r0 * ldb + j0);
                for i0 in (0..m).step_by(MR) {
                    let tile = Tile {
                        a: a_ptr.add(i0 * a.rows + r0 * a.cols),
                        a_rows: a.rows,
                        a_cols: a.cols,
                        b: panel,
                        ldb,
                        c: c_ptr.add(i0 * ldc + j0),
                        ldc,
                        steps,
                        masks,
                        load,
                    };
                    match m - i0 {
                        1 => tile.run::<1>(),
                        2 => tile.run::<2>(),
                        3 => tile.run::<3>(),
                        4 => tile.run::<4>(),
                        5 => tile.run::<5>(),
                        6 => tile.run::<6>(),
                        7 => tile.run::<7>(),
                        8 => tile.run::<8>(),
                        9 => tile.run::<9>(),
                        10 => tile.run::<10>(),
                        11 => tile.run::<11>(),
                        _ => tile.run::<MR>(),
                    }
                }
            }
        }
    }

    /// One tile of `C` (up to `MR` rows, up to `NR` columns by `masks`)
    /// over one chunk of the sum.
    struct Tile {
        a: *const f32,
        a_rows: usize,
        a_cols: usize,
        b: *const f32,
        ldb: usize,
        c: *mut f32,
        ldc: usize,
        steps: usize,
        masks: [__mmask16; 2],
        load: bool,
    }

    impl Tile {
        #[target_feature(enable = "avx512f")]
        #[inline]
        unsafe fn run<const R: usize>(&self) {
            let [m0, m1] = self.masks;
            let mut acc = [[_mm512_setzero_ps(); 2]; R];
            if self.load {
                for (i, acc) in acc.iter_mut().enumerate() {
                    let row = self.c.add(i * self.ldc);
                    acc[0] = _mm512_maskz_loadu_ps(m0, row);
                    acc[1] = _mm512_maskz_loadu_ps(m1, row.wrapping_add(16));
                }
            }
            for r in 0..self.steps {
                let brow = self.b.add(r * self.ldb);
                let b0 = _mm512_maskz_loadu_ps(m0, brow);
                // Past n the mask is empty and nothing is read (hence a
                // wrapping pointer: it may point past the operand).
                let b1 = _mm512_maskz_loadu_ps(m1, brow.wrapping_add(16));
                let a = self.a.add(r * self.a_cols);
                for (i, acc) in acc.iter_mut().enumerate() {
                    let x = _mm512_set1_ps(*a.add(i * self.a_rows));
                    acc[0] = _mm512_fmadd_ps(x, b0, acc[0]);
                    acc[1] = _mm512_fmadd_ps(x, b1, acc[1]);
                }
            }
            for (i, acc) in acc.iter().enumerate() {
                let row = self.c.add(i * self.ldc);
                _mm512_mask_storeu_ps(row, m0, acc[0]);
                _mm512_mask_storeu_ps(row.wrapping_add(16), m1, acc[1]);
            }
        }
    }
}
