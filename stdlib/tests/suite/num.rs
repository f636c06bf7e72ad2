use sdfl_stdlib::num::*;

/// Central differences of an f64 function against the dual tangent.
fn check(f: impl Fn(Dual<f64, 1>) -> Dual<f64, 1>, x: f64) {
    let h = 1e-6;
    let g = f(Dual::seed(x, 0)).d[0];
    let fd = (f(Dual::constant(x + h)).v - f(Dual::constant(x - h)).v) / (2.0 * h);
    assert!(
        (g - fd).abs() < 1e-6 * (1.0 + fd.abs()),
        "x {x}: {g} vs {fd}"
    );
}

#[test]
fn dual_derivatives_match_finite_differences() {
    for x in [0.3, 1.7, 2.5] {
        check(|v| v * v * v - v / (v + Dual::lit(1.0)), x);
        check(|v| v.sqrt() + v.ln() + v.ln_1p(), x);
        check(|v| v.sin() * v.cos() + (-v).exp() + v.exp_m1(), x);
        check(|v| (v - Dual::lit(1.0)).abs().max(Dual::lit(0.5)), x);
    }
}

/// Distance in units in the last place between two finite f32 of one sign.
fn ulps(a: f32, b: f32) -> u32 {
    (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs() as u32
}

#[test]
fn exp_f32_is_within_one_ulp_of_f64() {
    // Every 997th f32 in the range that has a finite, nonzero result,
    // plus both ends.
    let (lo, hi) = (-104.0f32, 89.0f32);
    let mut worst = 0;
    let mut check = |x: f32| {
        let got = exp_f32(x);
        let want = (x as f64).exp() as f32;
        if want.is_infinite() || want == 0.0 {
            assert_eq!(got, want, "exp({x})");
        } else {
            // Finite first: ∞ is one ulp above f32::MAX. Subnormal
            // results count in the same units (the last bit, 2^-149).
            assert!(got.is_finite(), "exp({x}) = {got}, f64 says {want}");
            worst = worst.max(ulps(got, want));
        }
    };
    // The magnitudes up to |lo|, negated (lo's own bits have the sign set).
    for bits in (0..=(-lo).to_bits()).step_by(997) {
        check(f32::from_bits(bits | 0x8000_0000));
    }
    for bits in (0..=hi.to_bits()).step_by(997) {
        check(f32::from_bits(bits));
    }
    for x in [lo, hi, 88.72, 88.73, -87.33, -103.9, 1e-30, -1e-30] {
        check(x);
    }
    assert!(worst <= 1, "worst error {worst} ulp");
}

#[test]
fn exp_f32_hard_cases() {
    assert_eq!(exp_f32(0.0), 1.0);
    assert_eq!(exp_f32(-0.0), 1.0);
    assert_eq!(exp_f32(f32::INFINITY), f32::INFINITY);
    assert_eq!(exp_f32(f32::NEG_INFINITY), 0.0);
    assert_eq!(exp_f32(1000.0), f32::INFINITY);
    assert_eq!(exp_f32(-1000.0), 0.0);
    assert!(exp_f32(f32::NAN).is_nan());
    assert!(exp_f32(88.72).is_finite());
    assert_eq!(<f32 as Real>::exp(0.5), exp_f32(0.5));
}

#[test]
fn ln_1p_unit_f32_is_within_two_ulp_of_f64() {
    let mut worst = 0;
    let mut check = |e: f32| {
        let got = ln_1p_unit_f32(e);
        let want = (e as f64).ln_1p() as f32;
        worst = worst.max(ulps(got, want));
    };
    for bits in (0..=1.0f32.to_bits()).step_by(97) {
        check(f32::from_bits(bits));
    }
    for e in [1.0, 0.414_213_57, 0.414_213_6, 1e-30, 5.9e-8, 6e-8, 0.5] {
        check(e);
    }
    assert!(worst <= 2, "worst error {worst} ulp");
}

#[test]
fn ln_1p_unit_f32_hard_cases() {
    assert_eq!(ln_1p_unit_f32(0.0).to_bits(), 0.0f32.to_bits());
    // Below 2^-24 the result is e itself.
    for e in [5.9e-8f32, 1e-20, f32::MIN_POSITIVE] {
        assert_eq!(ln_1p_unit_f32(e), e, "ln_1p({e})");
    }
    assert_eq!(ln_1p_unit_f32(1.0), std::f32::consts::LN_2);
    assert!(ln_1p_unit_f32(f32::NAN).is_nan());
    let tiny = f32::from_bits(1);
    assert!(ln_1p_unit_f32(tiny) <= tiny);
}

#[test]
fn non_smooth_points_have_finite_derivatives() {
    let z = Dual::<f64, 2>::seed(0.0, 0);
    assert_eq!(z.sqrt().d, [0.0, 0.0]);
    assert_eq!(z.abs().d, [1.0, 0.0]);
    let v = V3::new(z, Dual::seed(0.0, 1), Dual::lit(0.0));
    assert!(v.length().d.iter().all(|d| d.is_finite()));
}
