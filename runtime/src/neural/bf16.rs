//! Matrix products in bfloat16 with fp32 accumulation, for the layers of
//! a network trained with `precision: "bf16"`.
//!
//! Both operands are rounded to bf16 (8 significant bits) by
//! round-to-nearest-even, as `vcvtne2ps2bf16` does: a NaN stays a (quiet)
//! NaN, a denormal flushes to a zero of its sign, and a value past the
//! largest bf16 (≈ 3.39e38) becomes infinity. Products of two bf16 are exact
//! in fp32; they are summed in fp32 by `vdpbf16ps`, two along the inner
//! dimension per instruction, which is what doubles the throughput of an
//! fp32 FMA. Master weights, gradients and Adam stay fp32.
//!
//! [`Kernel::native`] is the AVX-512 BF16 kernel where the CPU has it
//! (checked at run time); [`Kernel::Emulated`] computes the same sums in
//! portable code (slowly: tests, and CPUs without it compare against it).
//! Callers without a native kernel use their fp32 path.

/// bf16 products run here.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kernel {
    /// `vdpbf16ps`; only where [`Kernel::native`] returned it.
    Avx512,
    /// Portable code: the same rounding, the same pairs, fp32 sums.
    Emulated,
}

impl Kernel {
    /// The AVX-512 BF16 kernel, where this CPU has AVX-512 F and BF16
    /// and [`crate::cpu::kernels`] allows them.
    pub fn native() -> Option<Kernel> {
        crate::cpu::kernels().avx512bf16.then_some(Kernel::Avx512)
    }
}

/// Whether this CPU runs bf16 products natively.
pub fn available() -> bool {
    Kernel::native().is_some()
}

/// The bf16 nearest to `x` (ties to even), as its 16 bits: the upper half
/// of an f32's. Denormals flush to signed zero and NaNs stay NaN, as in
/// `vcvtne2ps2bf16`.
pub fn to_bits(x: f32) -> u16 {
    let b = x.to_bits();
    if x.is_nan() {
        return ((b >> 16) | 0x40) as u16;
    }
    if b & 0x7f80_0000 == 0 {
        return ((b >> 16) & 0x8000) as u16;
    }
    let lsb = (b >> 16) & 1;
    (b.wrapping_add(0x7fff + lsb) >> 16) as u16
}

/// `x` rounded to bf16 ([`to_bits`]), as an f32.
pub fn round(x: f32) -> f32 {
    f32::from_bits((to_bits(x) as u32) << 16)
}

/// Columns per panel of a packed operand: two 16-lane vectors.
const NR: usize = 32;
/// Rows per register tile: 12 × 2 accumulators, 2 for `B`, 1 broadcast.
const MR: usize = 12;
/// Row pairs per chunk of a transposed product (`matmul_tn`): 256 pairs of
/// both packed operands, 32 columns each, are 2 × 32 KiB a panel.
const KC: usize = 256;

/// The right operand `B` (`k × n`), rounded to bf16 and laid out for the
/// kernel: panels of `NR` columns; in each, for every pair of rows
/// `2p, 2p + 1`, one 32-bit word per column holding `B[2p][j]` in its low
/// half and `B[2p + 1][j]` in its high half (zeros past `k` and `n`).
#[derive(Debug, Clone)]
pub struct Packed {
    k: usize,
    n: usize,
    /// Row pairs, `⌈k/2⌉`.
    kp: usize,
    /// The words, panel by panel.
    #[doc(hidden)]
    pub words: Vec<u32>,
}

impl Packed {
    /// Packs `B[i][j] = b[i·row_stride + j·col_stride]` (`k × n`).
    pub fn new(b: &[f32], k: usize, n: usize, row_stride: usize, col_stride: usize) -> Self {
        let kp = k.div_ceil(2);
        let panels = n.div_ceil(NR);
        // MR words of slack: a tile reading `A` from a packed operand (see
        // `matmul_tn`) may read past its panel's last column.
        let mut words = vec![0u32; panels * kp * NR + MR];
        #[cfg(target_arch = "x86_64")]
        if col_stride == 1 && available() {
            assert!(
                k == 0 || b.len() >= (k - 1) * row_stride + n,
                "B holds k × n"
            );
            // SAFETY: `available()` checked AVX-512 F and BF16 at run time;
            // B's bounds were asserted, `words` is sized for the panels.
            unsafe { avx512::pack_rows(b, k, n, row_stride, kp, &mut words) };
            return Packed { k, n, kp, words };
        }
        let at = |i: usize, j: usize| {
            if i < k {
                to_bits(b[i * row_stride + j * col_stride]) as u32
            } else {
                0
            }
        };
        for q in 0..panels {
            for p in 0..kp {
                let row = &mut words[(q * kp + p) * NR..][..NR];
                for (c, w) in row.iter_mut().enumerate() {
                    let j = q * NR + c;
                    if j < n {
                        *w = at(2 * p, j) | at(2 * p + 1, j) << 16;
                    }
                }
            }
        }
        Packed { k, n, kp, words }
    }

    /// Rows of `B`.
    pub fn k(&self) -> usize {
        self.k
    }

    /// Columns of `B`.
    pub fn n(&self) -> usize {
        self.n
    }
}

/// `C = A·B` (or `C += A·B` when `accumulate`) for `m` rows: `A` is `m × k`
/// row-major with rows `lda` apart, `C` is `m × n` with rows `ldc` apart.
/// One thread; callers split rows. The result depends only on the operands
/// (each row's sums run in the same order whatever the split).
#[allow(clippy::too_many_arguments)]
pub fn matmul(
    kernel: Kernel,
    m: usize,
    a: &[f32],
    lda: usize,
    b: &Packed,
    c: &mut [f32],
    ldc: usize,
    accumulate: bool,
) {
    let (k, n) = (b.k, b.n);
    if m == 0 || n == 0 {
        return;
    }
    assert!(a.len() >= (m - 1) * lda + k, "A holds m × k");
    assert!(c.len() >= (m - 1) * ldc + n, "C holds m × n");
    match kernel {
        Kernel::Emulated => emulated(m, a, lda, b, c, ldc, accumulate),
        Kernel::Avx512 => {
            #[cfg(target_arch = "x86_64")]
            {
                assert!(available(), "AVX-512 BF16 kernel on a CPU without it");
                // SAFETY: `available()` just checked AVX-512 F and BF16 at
                // run time; the bounds of A and C were asserted above.
                unsafe { avx512::matmul(m, a, lda, b, c, ldc, accumulate) }
            }
            #[cfg(not(target_arch = "x86_64"))]
            unreachable!("no AVX-512 kernel off x86-64")
        }
    }
}

/// `C = Xᵀ·B` (`k × n`, rows `ldc` apart; overwritten) for `X` of
/// `B.k()` rows × `k`, row-major: a weight gradient `xᵀ·dZ`, its sums
/// running over rows. One thread; the result depends only on the operands.
pub fn matmul_tn(kernel: Kernel, x: &[f32], k: usize, b: &Packed, c: &mut [f32], ldc: usize) {
    let (rows, n) = (b.k, b.n);
    if k == 0 || n == 0 {
        return;
    }
    assert!(x.len() >= rows * k, "X holds rows × k");
    assert!(c.len() >= (k - 1) * ldc + n, "C holds k × n");
    match kernel {
        Kernel::Emulated => {
            let xt: Vec<f32> = (0..k * rows)
                .map(|i| x[(i % rows) * k + i / rows])
                .collect();
            emulated(k, &xt, rows, b, c, ldc, false)
        }
        Kernel::Avx512 => {
            #[cfg(target_arch = "x86_64")]
            {
                assert!(available(), "AVX-512 BF16 kernel on a CPU without it");
                // Xᵀ's rows are X's columns: packed as a right operand, its
                // words for column i and row pair p lie at p·NR + i.
                let xp = Packed::new(x, rows, k, k, 1);
                // SAFETY: `available()` just checked AVX-512 F and BF16 at
                // run time; C's bounds were asserted above, the packed
                // operands are sized by `Packed::new` (with slack).
                unsafe { avx512::matmul_tn(&xp, b, c, ldc) }
            }
            #[cfg(not(target_arch = "x86_64"))]
            unreachable!("no AVX-512 kernel off x86-64")
        }
    }
}

/// The kernel's sums in portable code: per output, fp32 accumulators over
/// the row pairs, the odd product then the even one added (as
/// `vdpbf16ps` is specified), then added to `C`.
fn emulated(m: usize, a: &[f32], lda: usize, b: &Packed, c: &mut [f32], ldc: usize, acc: bool) {
    let (k, n, kp) = (b.k, b.n, b.kp);
    let lo = |w: u32| f32::from_bits(w << 16);
    let hi = |w: u32| f32::from_bits(w & 0xffff_0000);
    for i in 0..m {
        let row = &a[i * lda..i * lda + k];
        let pairs: Vec<u32> = (0..kp)
            .map(|p| {
                let even = to_bits(row[2 * p]) as u32;
                let odd = row.get(2 * p + 1).map_or(0, |&v| to_bits(v) as u32);
                even | odd << 16
            })
            .collect();
        for j in 0..n {
            let (q, col) = (j / NR, j % NR);
            let mut s = 0f32;
            for (p, &aw) in pairs.iter().enumerate() {
                let bw = b.words[(q * kp + p) * NR + col];
                s += hi(aw) * hi(bw);
                s += lo(aw) * lo(bw);
            }
            let y = &mut c[i * ldc + j];
            *y = if acc { *y + s } else { s };
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{Packed, KC, MR, NR};
    use crate::neural::fp32::avx512::mask;
    use std::arch::x86_64::*;
    use std::cell::RefCell;

    thread_local! {
        /// One strip of `A` in bf16 pairs, reused across calls.
        static STRIP: RefCell<Vec<u32>> = const { RefCell::new(Vec::new()) };
    }

    /// See [`super::matmul`]; the caller checked AVX-512 F + BF16 and the
    /// operand bounds.
    #[target_feature(enable = "avx512f,avx512bf16")]
    pub(super) unsafe fn matmul(
        m: usize,
        a: &[f32],
        lda: usize,
        b: &Packed,
        c: &mut [f32],
        ldc: usize,
        accumulate: bool,
    ) {
        let (k, n, kp) = (b.k, b.n, b.kp);
        // Words per strip row: whole vectors of 16 words (32 bf16).
        let ks = k.div_ceil(32) * 16;
        STRIP.with_borrow_mut(|strip| {
            strip.clear();
            strip.resize(MR * ks, 0);
            for r0 in (0..m).step_by(MR) {
                let rows = MR.min(m - r0);
                // The activations stream from memory: ask for the next
                // strip's rows while this one computes.
                for r in r0 + MR..(r0 + 2 * MR).min(m) {
                    let row = a[r * lda..].as_ptr();
                    for c0 in (0..k).step_by(16) {
                        _mm_prefetch::<_MM_HINT_T0>(row.add(c0) as *const i8);
                    }
                }
                for r in 0..MR {
                    let dst = strip[r * ks..].as_mut_ptr();
                    if r >= rows {
                        std::ptr::write_bytes(dst, 0, ks);
                        continue;
                    }
                    let src = a[(r0 + r) * lda..].as_ptr();
                    for c0 in (0..k).step_by(32) {
                        // Masked loads: nothing read past the row's k.
                        let lo = _mm512_maskz_loadu_ps(mask(k - c0), src.add(c0));
                        let hi = _mm512_maskz_loadu_ps(
                            mask(k.saturating_sub(c0 + 16)),
                            src.add(c0 + 16),
                        );
                        let v: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(hi, lo));
                        _mm512_storeu_si512(dst.add(c0 / 2) as *mut _, v);
                    }
                }
                for q in 0..n.div_ceil(NR) {
                    let cols = NR.min(n - q * NR);
                    tile(
                        strip.as_ptr(),
                        ks,
                        1,
                        kp,
                        b.words[q * kp * NR..].as_ptr(),
                        c[r0 * ldc + q * NR..].as_mut_ptr(),
                        ldc,
                        rows,
                        cols,
                        accumulate,
                    );
                }
            }
        });
    }

    /// Packs row-major `B` (rows `ld` apart) as [`Packed::new`] does: per
    /// row pair and 16 columns, both rows converted and their halves
    /// interleaved into words. The caller checked the features and bounds.
    #[target_feature(enable = "avx512f,avx512bf16")]
    pub(super) unsafe fn pack_rows(
        b: &[f32],
        k: usize,
        n: usize,
        ld: usize,
        kp: usize,
        words: &mut [u32],
    ) {
        let src = b.as_ptr();
        // Row pairs outermost: each row is read once, in order.
        for p in 0..kp {
            for q in 0..n.div_ceil(NR) {
                for half in 0..2 {
                    let j0 = q * NR + half * 16;
                    if j0 >= n {
                        break;
                    }
                    let msk = mask(n - j0);
                    let even = _mm512_maskz_loadu_ps(msk, src.add(2 * p * ld + j0));
                    let odd = if 2 * p + 1 < k {
                        _mm512_maskz_loadu_ps(msk, src.add((2 * p + 1) * ld + j0))
                    } else {
                        _mm512_setzero_ps()
                    };
                    // Lanes 0..16 hold the even row's bf16, 16..32 the odd's.
                    let both: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(odd, even));
                    let lo = _mm512_cvtepu16_epi32(_mm512_castsi512_si256(both));
                    let hi = _mm512_cvtepu16_epi32(_mm512_extracti64x4_epi64::<1>(both));
                    let w = _mm512_or_si512(lo, _mm512_slli_epi32::<16>(hi));
                    _mm512_storeu_si512(
                        words.as_mut_ptr().add((q * kp + p) * NR + half * 16) as *mut _,
                        w,
                    );
                }
            }
        }
    }

    /// See [`super::matmul_tn`]: `xp` is `X` packed (its columns, the
    /// rows of `Xᵀ`, in panels of 32, read 12 at a time). The caller
    /// checked AVX-512 F + BF16 and C's bounds.
    #[target_feature(enable = "avx512f,avx512bf16")]
    pub(super) unsafe fn matmul_tn(xp: &Packed, b: &Packed, c: &mut [f32], ldc: usize) {
        let (k, n, kp) = (xp.n, b.n, b.kp);
        // Row pairs in chunks whose operands stay in L2, each chunk's sums
        // added to C in chunk order.
        for p0 in (0..kp).step_by(KC) {
            let pairs = KC.min(kp - p0);
            for qa in 0..k.div_ceil(NR) {
                let width = NR.min(k - qa * NR);
                for r0 in (0..width).step_by(MR) {
                    let a = xp.words[(qa * kp + p0) * NR + r0..].as_ptr();
                    let i0 = qa * NR + r0;
                    for q in 0..n.div_ceil(NR) {
                        tile(
                            a,
                            1,
                            NR,
                            pairs,
                            b.words[(q * kp + p0) * NR..].as_ptr(),
                            c[i0 * ldc + q * NR..].as_mut_ptr(),
                            ldc,
                            MR.min(width - r0),
                            NR.min(n - q * NR),
                            p0 > 0,
                        );
                    }
                }
            }
        }
    }

    /// One `MR × NR` tile: registers accumulate over `kp` row pairs, then
    /// `rows × cols` of it are written (or added) to `c`. Callers (above)
    /// hold AVX-512 F + BF16 and pass pointers valid for `MR` rows of `a`
    /// (zero rows or slack past the last), `kp` pairs of `b`, `rows × cols`
    /// of `c`.
    #[target_feature(enable = "avx512f,avx512bf16")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn tile(
        a: *const u32,
        a_row: usize,
        a_pair: usize,
        kp: usize,
        b: *const u32,
        c: *mut f32,
        ldc: usize,
        rows: usize,
        cols: usize,
        accumulate: bool,
    ) {
        let mut acc = [[_mm512_setzero_ps(); 2]; MR];
        for p in 0..kp {
            let b0: __m512bh = std::mem::transmute(_mm512_loadu_si512(b.add(p * NR) as *const _));
            let b1: __m512bh =
                std::mem::transmute(_mm512_loadu_si512(b.add(p * NR + 16) as *const _));
            for (r, acc) in acc.iter_mut().enumerate() {
                let av: __m512bh =
                    std::mem::transmute(_mm512_set1_epi32(*a.add(r * a_row + p * a_pair) as i32));
                acc[0] = _mm512_dpbf16_ps(acc[0], av, b0);
                acc[1] = _mm512_dpbf16_ps(acc[1], av, b1);
            }
        }
        let (m0, m1) = (mask(cols), mask(cols.saturating_sub(16)));
        for (r, acc) in acc.iter().enumerate().take(rows) {
            let y = c.add(r * ldc);
            let (mut v0, mut v1) = (acc[0], acc[1]);
            if accumulate {
                v0 = _mm512_add_ps(v0, _mm512_maskz_loadu_ps(m0, y));
                v1 = _mm512_add_ps(v1, _mm512_maskz_loadu_ps(m1, y.add(16)));
            }
            _mm512_mask_storeu_ps(y, m0, v0);
            if m1 != 0 {
                _mm512_mask_storeu_ps(y.add(16), m1, v1);
            }
        }
    }
}
