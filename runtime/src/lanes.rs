//! Packs of [`LANES`] points evaluated together ([`F8`]): a lane type that
//! implements `sdfl_stdlib::num::Real`, so the batched evaluator calls the
//! same generic formula per primitive (`sdfl_stdlib::sdf`) as the per-point
//! one, with eight points in the lanes instead of one. [`F16`], the same
//! type sixteen wide (one AVX-512 register), carries the training tape's
//! samples (`train::tape`).
//!
//! Every operation is the f32 operation lane by lane (IEEE add, mul, div,
//! correctly rounded sqrt, `min`/`max` with `Real`'s tie and NaN rule), so a
//! lane's result is bit for bit the per-point result. The lanes are a plain
//! `[f32; 8]`: LLVM turns the fixed-size loops into vector instructions, and
//! [`has_avx2`] picks a kernel a second time with AVX2 enabled (picked at
//! run time), which a compile-time SIMD crate such as `wide` cannot do
//! without building the whole crate for one CPU.
//!
//! A branch on a value (`Real::val`) has no meaning for eight points at once;
//! it is defined for a pack whose lanes agree (a constant, such as a smooth
//! union's `k`) and panics otherwise, so formulas that branch on the point
//! are evaluated lane by lane through the per-point path instead.

use std::ops::{Add, Div, Mul, Neg, Sub};

use glam::Vec3A;
use sdfl_stdlib::num::{Real, V3};

/// Points per pack.
pub const LANES: usize = 8;

/// Eight points, one per lane.
pub type P8 = V3<F8>;

/// A pack of points from up to [`LANES`] points; missing lanes repeat the
/// last point (so they stay finite and cost nothing special).
#[inline(always)]
pub fn pack(points: &[Vec3A]) -> P8 {
    #[cfg(target_arch = "x86_64")]
    if let Some(full) = points.first_chunk::<LANES>() {
        return pack_whole(full);
    }
    let last = points.len().min(LANES) - 1;
    let (mut x, mut y, mut z) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
    for i in 0..LANES {
        let p = points[i.min(last)];
        x[i] = p.x;
        y[i] = p.y;
        z[i] = p.z;
    }
    V3::new(F8(x), F8(y), F8(z))
}

/// A whole pack, transposed four points at a time in SSE registers (the
/// baseline of x86-64; lane by lane, each coordinate would be stored
/// alone and read back as part of a pack).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn pack_whole(points: &[Vec3A; LANES]) -> P8 {
    use std::arch::x86_64::{
        __m128, _mm_movehl_ps, _mm_movelh_ps, _mm_unpackhi_ps, _mm_unpacklo_ps,
    };
    // Four points' x, y and z.
    let four = |q: &[Vec3A]| -> [[f32; 4]; 3] {
        let [a, b, c, d] = [0, 1, 2, 3].map(|i| __m128::from(q[i]));
        // SAFETY: SSE is part of x86-64's baseline: every such CPU runs it.
        let xyz = unsafe {
            let (ab_lo, cd_lo) = (_mm_unpacklo_ps(a, b), _mm_unpacklo_ps(c, d));
            let (ab_hi, cd_hi) = (_mm_unpackhi_ps(a, b), _mm_unpackhi_ps(c, d));
            [
                _mm_movelh_ps(ab_lo, cd_lo),
                _mm_movehl_ps(cd_lo, ab_lo),
                _mm_movelh_ps(ab_hi, cd_hi),
            ]
        };
        xyz.map(|v| Vec4Bits::from(v).0)
    };
    let (lo, hi) = (four(&points[..4]), four(&points[4..]));
    let join = |k: usize| {
        let mut r = [0.0; LANES];
        r[..4].copy_from_slice(&lo[k]);
        r[4..].copy_from_slice(&hi[k]);
        F8(r)
    };
    V3::new(join(0), join(1), join(2))
}

/// The four lanes of an SSE register.
#[cfg(target_arch = "x86_64")]
struct Vec4Bits([f32; 4]);

#[cfg(target_arch = "x86_64")]
impl From<std::arch::x86_64::__m128> for Vec4Bits {
    #[inline(always)]
    fn from(v: std::arch::x86_64::__m128) -> Self {
        Vec4Bits(glam::Vec4::from(v).to_array())
    }
}

/// Lane `i` of a pack of points.
#[inline(always)]
pub fn lane(p: &P8, i: usize) -> Vec3A {
    Vec3A::new(p.x.0[i], p.y.0[i], p.z.0[i])
}

/// A pack's point values with `f` applied lane by lane (the fallback of
/// nodes without a packed kernel).
#[inline(always)]
pub fn per_lane(p: &P8, f: impl Fn(Vec3A) -> f32) -> F8 {
    let mut r = [0.0; LANES];
    for (i, r) in r.iter_mut().enumerate() {
        *r = f(lane(p, i));
    }
    F8(r)
}

/// Whether the kernels may use AVX2 ([`crate::cpu::kernels`]): the packed
/// kernels then run a copy of themselves compiled with it
/// (`#[target_feature]`, the generic formula inlined into it and
/// vectorised 8 wide); else the baseline build.
#[inline(always)]
pub fn has_avx2() -> bool {
    crate::cpu::kernels().avx2
}

/// `$vis fn $name<P: Prim>(node: &$node, p: &[P8], out: &mut [F8])`
/// running the `#[inline(always)]` kernel `$kernel` with the same
/// signature, compiled with AVX2 when the CPU has it.
macro_rules! avx2_kernel {
    ($name:ident, $kernel:ident, $node:ident) => {
        fn $name<P: Prim>(node: &$node<P>, p: &[P8], out: &mut [F8]) {
            #[cfg(any(target_arch = "x86_64", target_arch = "x86"))]
            {
                #[target_feature(enable = "avx2")]
                unsafe fn avx2<P: Prim>(node: &$node<P>, p: &[P8], out: &mut [F8]) {
                    $kernel(node, p, out)
                }
                if lanes::has_avx2() {
                    // SAFETY: the CPU supports AVX2 (checked just above).
                    return unsafe { avx2(node, p, out) };
                }
            }
            $kernel(node, p, out)
        }
    };
}
pub(crate) use avx2_kernel;

/// `$vis fn $name(args) -> $ret` running the `#[inline(always)]` function
/// `$body` on the same arguments, compiled twice more, for AVX-512 F and
/// for AVX2, and the widest copy the CPU runs picked at run time (the same
/// operations in each, so the same bits; wider lanes where loops
/// vectorise).
macro_rules! widest_simd {
    ($(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) -> $ret:ty = $body:path) => {
        $(#[$meta])*
        $vis fn $name($($arg: $ty),*) -> $ret {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f")]
                unsafe fn avx512($($arg: $ty),*) -> $ret {
                    $body($($arg),*)
                }
                if $crate::cpu::kernels().avx512f {
                    // SAFETY: the CPU supports AVX-512 F (checked just above).
                    return unsafe { avx512($($arg),*) };
                }
            }
            #[cfg(any(target_arch = "x86_64", target_arch = "x86"))]
            {
                #[target_feature(enable = "avx2")]
                unsafe fn avx2($($arg: $ty),*) -> $ret {
                    $body($($arg),*)
                }
                if $crate::lanes::has_avx2() {
                    // SAFETY: the CPU supports AVX2 (checked just above).
                    return unsafe { avx2($($arg),*) };
                }
            }
            $body($($arg),*)
        }
    };
}
pub(crate) use widest_simd;

/// Defines a lane type: `$n` f32 lanes aligned to `$align` bytes, each
/// operation the f32 operation lane by lane.
macro_rules! lane_type {
    ($(#[$meta:meta])* $name:ident, $n:literal, $align:literal) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq)]
        #[repr(C, align($align))]
        pub struct $name(pub [f32; $n]);

        impl $name {
            /// Every lane set to `x`.
            #[inline(always)]
            pub fn splat(x: f32) -> Self {
                $name([x; $n])
            }
            #[inline(always)]
            fn map(self, f: impl Fn(f32) -> f32) -> Self {
                let mut r = self.0;
                for x in r.iter_mut() {
                    *x = f(*x);
                }
                $name(r)
            }
            #[inline(always)]
            fn zip(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self {
                let mut r = self.0;
                for (a, b) in r.iter_mut().zip(o.0) {
                    *a = f(*a, b);
                }
                $name(r)
            }
        }

        impl Add for $name {
            type Output = $name;
            #[inline(always)]
            fn add(self, o: $name) -> $name {
                self.zip(o, |a, b| a + b)
            }
        }
        impl Sub for $name {
            type Output = $name;
            #[inline(always)]
            fn sub(self, o: $name) -> $name {
                self.zip(o, |a, b| a - b)
            }
        }
        impl Mul for $name {
            type Output = $name;
            #[inline(always)]
            fn mul(self, o: $name) -> $name {
                self.zip(o, |a, b| a * b)
            }
        }
        impl Div for $name {
            type Output = $name;
            #[inline(always)]
            fn div(self, o: $name) -> $name {
                self.zip(o, |a, b| a / b)
            }
        }
        impl Neg for $name {
            type Output = $name;
            #[inline(always)]
            fn neg(self) -> $name {
                self.map(|a| -a)
            }
        }

        impl Real for $name {
            #[inline(always)]
            fn lit(x: f64) -> Self {
                $name::splat(<f32 as Real>::lit(x))
            }
            /// The common value of the lanes; panics when they differ (a branch on
            /// the point itself, which a pack cannot take).
            #[inline(always)]
            fn val(self) -> f64 {
                let v = self.0[0];
                assert!(
                    self.0.iter().all(|x| x.to_bits() == v.to_bits()),
                    "a branch on a per-point value in a packed formula: evaluate it lane by lane"
                );
                v as f64
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                self.map(f32::sqrt)
            }
            #[inline(always)]
            fn floor(self) -> Self {
                self.map(f32::floor)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                self.map(f32::abs)
            }
            #[inline(always)]
            fn exp(self) -> Self {
                self.map(sdfl_stdlib::num::exp_f32)
            }
            #[inline(always)]
            fn ln(self) -> Self {
                self.map(f32::ln)
            }
            #[inline(always)]
            fn ln_1p(self) -> Self {
                self.map(f32::ln_1p)
            }
            #[inline(always)]
            fn exp_m1(self) -> Self {
                self.map(f32::exp_m1)
            }
            #[inline(always)]
            fn sin(self) -> Self {
                self.map(f32::sin)
            }
            #[inline(always)]
            fn cos(self) -> Self {
                self.map(f32::cos)
            }
            #[inline(always)]
            fn max(self, o: Self) -> Self {
                self.zip(o, <f32 as Real>::max)
            }
            #[inline(always)]
            fn min(self, o: Self) -> Self {
                self.zip(o, <f32 as Real>::min)
            }
            #[inline(always)]
            fn if_gt(a: Self, b: Self, then: Self, otherwise: Self) -> Self {
                let mut r = otherwise.0;
                for i in 0..$n {
                    if a.0[i] > b.0[i] {
                        r[i] = then.0[i];
                    }
                }
                $name(r)
            }
        }
    };
}

lane_type!(
    /// Eight f32 lanes.
    F8, 8, 32
);
lane_type!(
    /// Sixteen f32 lanes (one AVX-512 register): the training tape's unit.
    F16, 16, 64
);
