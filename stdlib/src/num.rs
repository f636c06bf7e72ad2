//! The small numeric trait every distance function is written against, so
//! one definition serves the f64 reference, the f32 tracer and forward-mode
//! gradients ([`Dual`]) for training.
//!
//! Non-smooth points take a fixed one-sided derivative (`abs` at 0 is `+1`,
//! `max`/`min` follow the first argument on ties, `sqrt` at 0 has derivative
//! 0), so gradients are finite everywhere, including exactly on a box edge.

use std::ops::{Add, Div, Mul, Neg, Sub};

/// A real number type: `f32`, `f64` or a [`Dual`] over one of them.
pub trait Real:
    Copy
    + Send
    + Sync
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// A constant (no derivative).
    fn lit(x: f64) -> Self;
    /// The value, for comparisons and branches.
    fn val(self) -> f64;
    /// √x.
    fn sqrt(self) -> Self;
    /// |x|.
    fn abs(self) -> Self;
    /// eˣ.
    fn exp(self) -> Self;
    /// The natural logarithm.
    fn ln(self) -> Self;
    /// `ln(1 + x)` without cancellation near 0.
    fn ln_1p(self) -> Self;
    /// `exp(x) − 1` without cancellation near 0.
    fn exp_m1(self) -> Self;
    /// sin x (radians).
    fn sin(self) -> Self;
    /// cos x (radians).
    fn cos(self) -> Self;
    /// The largest whole number ≤ x, derivative 0 (piecewise constant).
    /// The default reads the value: types that record a computation
    /// (the training tape) then treat it as a branch on the value, and fall
    /// back to a path that evaluates each sample.
    #[inline(always)]
    fn floor(self) -> Self {
        Self::lit(self.val().floor())
    }
    /// The larger of the two (the first on ties).
    fn max(self, o: Self) -> Self;
    /// The smaller of the two (the first on ties).
    fn min(self, o: Self) -> Self;
    /// `then` where `a > b`, else `otherwise` (NaN compares false). A
    /// select, not a branch: lane types choose lane by lane, so formulas
    /// built on it (the derivatives of `max`, `min`, `abs`, `sqrt`) run on
    /// packs of points whose lanes disagree.
    fn if_gt(a: Self, b: Self, then: Self, otherwise: Self) -> Self;
    #[inline(always)]
    /// `x` limited to `lo..=hi`.
    fn clamp(self, lo: f64, hi: f64) -> Self {
        self.max(Self::lit(lo)).min(Self::lit(hi))
    }
    #[inline(always)]
    /// The constant 0.
    fn zero() -> Self {
        Self::lit(0.0)
    }
    #[inline(always)]
    /// The constant 1.
    fn one() -> Self {
        Self::lit(1.0)
    }
}

macro_rules! real_float {
    ($t:ty, $exp:path) => {
        impl Real for $t {
            #[inline(always)]
            fn lit(x: f64) -> Self {
                x as $t
            }
            #[inline(always)]
            fn val(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn floor(self) -> Self {
                <$t>::floor(self)
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn exp(self) -> Self {
                $exp(self)
            }
            #[inline(always)]
            fn ln(self) -> Self {
                <$t>::ln(self)
            }
            #[inline(always)]
            fn ln_1p(self) -> Self {
                <$t>::ln_1p(self)
            }
            #[inline(always)]
            fn exp_m1(self) -> Self {
                <$t>::exp_m1(self)
            }
            #[inline(always)]
            fn sin(self) -> Self {
                <$t>::sin(self)
            }
            #[inline(always)]
            fn cos(self) -> Self {
                <$t>::cos(self)
            }
            #[inline(always)]
            fn max(self, o: Self) -> Self {
                if o > self {
                    o
                } else {
                    self
                }
            }
            #[inline(always)]
            fn min(self, o: Self) -> Self {
                if o < self {
                    o
                } else {
                    self
                }
            }
            #[inline(always)]
            fn if_gt(a: Self, b: Self, then: Self, otherwise: Self) -> Self {
                if a > b {
                    then
                } else {
                    otherwise
                }
            }
        }
    };
}
real_float!(f32, exp_f32);
real_float!(f64, f64::exp);

/// `e^x` in f32 without a branch or a library call, so that a loop over
/// lanes of it vectorises (the lane types map it lane by lane and so stay
/// bit-identical to the scalar path, which uses it too). Within 1 ulp of
/// the exact value (the test checks every 997th f32 of the range against
/// f64; a review checked every f32 once); exactly 1 at 0; overflows to +∞,
/// underflows through the subnormals to 0; NaN stays NaN.
///
/// `x = n·ln 2 + r` with `|r| ≤ ln 2 / 2` (ln 2 in two parts, so `r` is
/// exact), a degree-7 polynomial for `e^r` (Cephes' expf coefficients), and
/// `2^n` applied as two factors so neither leaves the normal range.
#[inline(always)]
pub fn exp_f32(x: f32) -> f32 {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Past these the result is ∞ or 0 whatever the polynomial says (NaN
    // passes through the clamp and the rest).
    let x = x.clamp(-104.0, 89.0);
    // Round to nearest by adding and removing 1.5·2^23.
    const ROUND: f32 = 12_582_912.0;
    let shifted = x * LOG2_E + ROUND;
    let n = shifted - ROUND;
    // n as an integer from the same bits (its low mantissa bits hold it):
    // a bit cast vectorises where a saturating `as i32` goes lane by lane.
    let n_int = (shifted.to_bits() as i32).wrapping_sub(ROUND.to_bits() as i32);
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let p = 1.987_569_1e-4;
    let p = p * r + 1.398_199_9e-3;
    let p = p * r + 8.333_452e-3;
    let p = p * r + 4.166_579_6e-2;
    let p = p * r + 1.666_666_5e-1;
    let p = p * r + 0.5; // the fit's 0.500_000_01, as f32 rounds it
    let e_r = (p * r * r + r) + 1.0;
    let half = n_int >> 1;
    let scale = |k: i32| f32::from_bits((k.wrapping_add(127) as u32) << 23);
    e_r * scale(half) * scale(n_int.wrapping_sub(half))
}

/// `ln(1 + e)` for `0 ≤ e ≤ 1` (as softplus needs it, `e = e^{−|x|}`) in
/// f32, without a branch or a library call, so that a loop of it
/// vectorises. Within 2 ulp of the exact value (the test checks every 97th
/// f32 of the range against f64); exactly `e` for a normal `e < 2^-24`
/// (there `ln(1 + e)` rounds to `e`; a subnormal may lose its last bit),
/// exactly 0 at 0; NaN stays NaN.
///
/// `ln(1 + e) = 2·atanh(s)` with `s = e/(2 + e)`: no cancellation for small
/// `e`. Past `e = √2 − 1` the argument is halved first, `ln(1 + e) = ln 2 +
/// 2·atanh((e − 1)/(e + 3))`, so `|s| ≤ 0.1716` either way and six terms of
/// `atanh`'s series (`s^{2k}/(2k + 1)`, k ≤ 5) leave under 2^-28 of `s`.
#[inline(always)]
pub fn ln_1p_unit_f32(e: f32) -> f32 {
    const SQRT2_M1: f32 = 0.414_213_57;
    let halved = e > SQRT2_M1;
    let (num, den, base) = if halved {
        (e - 1.0, e + 3.0, std::f32::consts::LN_2)
    } else {
        (e, e + 2.0, 0.0)
    };
    let s = num / den;
    let s2 = s * s;
    let p = 1.0 / 11.0;
    let p = p * s2 + 1.0 / 9.0;
    let p = p * s2 + 1.0 / 7.0;
    let p = p * s2 + 1.0 / 5.0;
    let p = p * s2 + 1.0 / 3.0;
    let t = 2.0 * s;
    base + (t + t * s2 * p)
}

/// A value with `N` forward-mode tangents over the base type `F`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dual<F, const N: usize> {
    /// The value.
    pub v: F,
    /// Its derivatives with respect to `N` chosen inputs.
    pub d: [F; N],
}

impl<F: Real, const N: usize> Dual<F, N> {
    /// A constant.
    #[inline(always)]
    pub fn constant(v: F) -> Self {
        Dual {
            v,
            d: [F::zero(); N],
        }
    }
    /// An input seeded with tangent `e_i` (no tangent if `i ≥ N`).
    #[inline(always)]
    pub fn seed(v: F, i: usize) -> Self {
        let mut d = [F::zero(); N];
        if i < N {
            d[i] = F::one();
        }
        Dual { v, d }
    }
    /// `f(v)` with derivative `df` (chain rule on every tangent).
    #[inline(always)]
    fn chain(self, v: F, df: F) -> Self {
        let mut d = self.d;
        for x in d.iter_mut() {
            *x = *x * df;
        }
        Dual { v, d }
    }
}

impl<F: Real, const N: usize> Add for Dual<F, N> {
    type Output = Self;
    #[inline(always)]
    #[allow(
        clippy::needless_range_loop,
        reason = "one index over self, o and the result keeps the per-lane formula readable; hot in training"
    )]
    fn add(self, o: Self) -> Self {
        let mut d = self.d;
        for i in 0..N {
            d[i] = d[i] + o.d[i];
        }
        Dual { v: self.v + o.v, d }
    }
}
impl<F: Real, const N: usize> Sub for Dual<F, N> {
    type Output = Self;
    #[inline(always)]
    #[allow(
        clippy::needless_range_loop,
        reason = "one index over self, o and the result keeps the per-lane formula readable; hot in training"
    )]
    fn sub(self, o: Self) -> Self {
        let mut d = self.d;
        for i in 0..N {
            d[i] = d[i] - o.d[i];
        }
        Dual { v: self.v - o.v, d }
    }
}
impl<F: Real, const N: usize> Mul for Dual<F, N> {
    type Output = Self;
    #[inline(always)]
    #[allow(
        clippy::needless_range_loop,
        reason = "one index over self, o and the result keeps the per-lane formula readable; hot in training"
    )]
    fn mul(self, o: Self) -> Self {
        let mut d = self.d;
        for i in 0..N {
            d[i] = d[i] * o.v + self.v * o.d[i];
        }
        Dual { v: self.v * o.v, d }
    }
}
impl<F: Real, const N: usize> Div for Dual<F, N> {
    type Output = Self;
    #[inline(always)]
    #[allow(
        clippy::needless_range_loop,
        reason = "one index over self, o and the result keeps the per-lane formula readable; hot in training"
    )]
    fn div(self, o: Self) -> Self {
        let inv = F::one() / o.v;
        let q = self.v * inv;
        let mut d = self.d;
        for i in 0..N {
            d[i] = (d[i] - q * o.d[i]) * inv;
        }
        Dual { v: q, d }
    }
}
impl<F: Real, const N: usize> Neg for Dual<F, N> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        let mut d = self.d;
        for x in d.iter_mut() {
            *x = -*x;
        }
        Dual { v: -self.v, d }
    }
}

impl<F: Real, const N: usize> Real for Dual<F, N> {
    #[inline(always)]
    fn lit(x: f64) -> Self {
        Dual::constant(F::lit(x))
    }
    #[inline(always)]
    fn val(self) -> f64 {
        self.v.val()
    }
    #[inline(always)]
    fn floor(self) -> Self {
        Dual::constant(self.v.floor())
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        // The subgradient 0 at 0 (e.g. the outside length of a box at a
        // point inside it): finite, and exact where the value stays 0.
        let df = F::if_gt(s, F::zero(), F::lit(0.5) / s, F::zero());
        self.chain(s, df)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        Self::if_gt(Self::zero(), self, -self, self)
    }
    #[inline(always)]
    fn exp(self) -> Self {
        let e = self.v.exp();
        self.chain(e, e)
    }
    #[inline(always)]
    fn ln(self) -> Self {
        self.chain(self.v.ln(), F::one() / self.v)
    }
    #[inline(always)]
    fn ln_1p(self) -> Self {
        self.chain(self.v.ln_1p(), F::one() / (F::one() + self.v))
    }
    #[inline(always)]
    fn exp_m1(self) -> Self {
        self.chain(self.v.exp_m1(), self.v.exp())
    }
    #[inline(always)]
    fn sin(self) -> Self {
        self.chain(self.v.sin(), self.v.cos())
    }
    #[inline(always)]
    fn cos(self) -> Self {
        self.chain(self.v.cos(), -self.v.sin())
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        Self::if_gt(o, self, o, self)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        Self::if_gt(self, o, o, self)
    }
    /// Selects value and tangents together, by the values.
    #[inline(always)]
    #[allow(
        clippy::needless_range_loop,
        reason = "one index over self, o and the result keeps the per-lane formula readable; hot in training"
    )]
    fn if_gt(a: Self, b: Self, then: Self, otherwise: Self) -> Self {
        let mut d = otherwise.d;
        for i in 0..N {
            d[i] = F::if_gt(a.v, b.v, then.d[i], d[i]);
        }
        Dual {
            v: F::if_gt(a.v, b.v, then.v, otherwise.v),
            d,
        }
    }
}

/// A 3-vector over any [`Real`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct V3<T> {
    /// The first coordinate.
    pub x: T,
    /// The second coordinate.
    pub y: T,
    /// The third coordinate.
    pub z: T,
}

impl<T: Real> V3<T> {
    #[inline(always)]
    /// A vector of three coordinates.
    pub fn new(x: T, y: T, z: T) -> Self {
        V3 { x, y, z }
    }
    #[inline(always)]
    /// All three coordinates `v`.
    pub fn splat(v: T) -> Self {
        V3 { x: v, y: v, z: v }
    }
    #[inline(always)]
    /// A constant vector (no derivatives).
    pub fn lit(v: [f64; 3]) -> Self {
        V3::new(T::lit(v[0]), T::lit(v[1]), T::lit(v[2]))
    }
    #[inline(always)]
    /// `f` of each coordinate.
    pub fn map(self, f: impl Fn(T) -> T) -> Self {
        V3::new(f(self.x), f(self.y), f(self.z))
    }
    #[inline(always)]
    /// `f` of each pair of coordinates.
    pub fn zip(self, o: Self, f: impl Fn(T, T) -> T) -> Self {
        V3::new(f(self.x, o.x), f(self.y, o.y), f(self.z, o.z))
    }
    #[inline(always)]
    /// The dot product.
    pub fn dot(self, o: Self) -> T {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    #[inline(always)]
    /// The Euclidean length.
    pub fn length(self) -> T {
        self.dot(self).sqrt()
    }
    #[inline(always)]
    /// Componentwise |v|.
    pub fn abs(self) -> Self {
        V3::new(self.x.abs(), self.y.abs(), self.z.abs())
    }
    /// Componentwise `max(v, s)`.
    #[inline(always)]
    pub fn max_s(self, s: T) -> Self {
        V3::new(self.x.max(s), self.y.max(s), self.z.max(s))
    }
    #[inline(always)]
    /// The largest coordinate.
    pub fn max_element(self) -> T {
        self.x.max(self.y).max(self.z)
    }
    #[inline(always)]
    /// The smallest coordinate.
    pub fn min_element(self) -> T {
        self.x.min(self.y).min(self.z)
    }
    #[inline(always)]
    /// The cross product.
    pub fn cross(self, o: Self) -> Self {
        V3::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    #[inline(always)]
    /// The coordinates as an array.
    pub fn to_array(self) -> [T; 3] {
        [self.x, self.y, self.z]
    }
    #[inline(always)]
    /// A vector from an array of coordinates.
    pub fn from_array(a: [T; 3]) -> Self {
        V3::new(a[0], a[1], a[2])
    }
}

// The operators spell out their components (no closures): with wide lane
// or dual types LLVM would otherwise leave the closures as calls.
impl<T: Real> Add for V3<T> {
    type Output = Self;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        V3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}
impl<T: Real> Sub for V3<T> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        V3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
impl<T: Real> Mul<T> for V3<T> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, s: T) -> Self {
        V3::new(self.x * s, self.y * s, self.z * s)
    }
}
impl<T: Real> Neg for V3<T> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        V3::new(-self.x, -self.y, -self.z)
    }
}

impl From<glam::DVec3> for V3<f64> {
    fn from(v: glam::DVec3) -> Self {
        V3::new(v.x, v.y, v.z)
    }
}
impl From<V3<f64>> for glam::DVec3 {
    fn from(v: V3<f64>) -> Self {
        glam::DVec3::new(v.x, v.y, v.z)
    }
}
