//! SDF → density/opacity transforms of CONVENTIONS.md, written so that values
//! *and* derivatives stay finite for tiny β and huge |sdf|.
//!
//! Every transform evaluates a single `exp(-|sdf|/β) ∈ [0, 1]` and combines it
//! per branch; no branch ever evaluates an exponential that can overflow, so a
//! masked-out branch can never poison a gradient with `inf·0`.
//!
//! Functions named `*_grad` return `(value, d value / d sdf)`.

use num_traits::Float;

#[inline]
fn half<F: Float>() -> F {
    F::from(0.5).unwrap()
}

/// Laplace CDF `Ψ_β(s)`: `0.5·exp(s/β)` for `s ≤ 0`, `1 − 0.5·exp(−s/β)` otherwise.
#[inline]
pub fn laplace_cdf<F: Float>(s: F, beta: F) -> F {
    laplace_cdf_grad(s, beta).0
}

/// `Ψ_β(s)` and its derivative `0.5·exp(−|s|/β)/β` (the Laplace pdf).
#[inline]
pub fn laplace_cdf_grad<F: Float>(s: F, beta: F) -> (F, F) {
    let e = (-s.abs() / beta).exp();
    let v = if s <= F::zero() {
        half::<F>() * e
    } else {
        F::one() - half::<F>() * e
    };
    (v, half::<F>() * e / beta)
}

/// The assignment's per-sample opacity `α·Ψ_β(−sdf)` (needs `0 < α ≤ 1`).
#[inline]
pub fn sdf_opacity<F: Float>(sdf: F, alpha: F, beta: F) -> F {
    sdf_opacity_grad(sdf, alpha, beta).0
}

/// Opacity `α·Ψ_β(−sdf)` and its derivative `−α·0.5·exp(−|sdf|/β)/β`.
#[inline]
pub fn sdf_opacity_grad<F: Float>(sdf: F, alpha: F, beta: F) -> (F, F) {
    let (v, d) = laplace_cdf_grad(-sdf, beta);
    (alpha * v, -alpha * d)
}

/// `ln(1 − opacity)` of the assignment's form, i.e. `−σΔ` of the equivalent
/// density. With α = 1 deep inside a shape the opacity rounds to exactly 1,
/// yet `ln(1 − α·Ψ_β(−sdf)) = ln Ψ_β(sdf) = ln 0.5 + sdf/β` stays finite, so
/// compositing in log space never meets `ln 0`. Needs `0 < α ≤ 1`.
#[inline]
pub fn sdf_log_keep<F: Float>(sdf: F, alpha: F, beta: F) -> F {
    sdf_log_keep_grad(sdf, alpha, beta).0
}

/// `ln(1 − opacity)` and its derivative with respect to `sdf`.
#[inline]
pub fn sdf_log_keep_grad<F: Float>(sdf: F, alpha: F, beta: F) -> (F, F) {
    let h = half::<F>();
    let e = (-sdf.abs() / beta).exp();
    // d(opacity)/d sdf = −α·e/(2β); d ln(keep) = −d(opacity)/keep.
    let num = alpha * h * e / beta;
    if sdf >= F::zero() {
        // keep = 1 − α·e/2 ≥ 1/2.
        let keep = F::one() - alpha * h * e;
        ((-alpha * h * e).ln_1p(), num / keep)
    } else if alpha == F::one() {
        // keep = e/2 exactly: linear in sdf, no underflow possible.
        (h.ln() + sdf / beta, F::one() / beta)
    } else {
        // keep = 1 − α + α·e/2 ≥ 1 − α > 0.
        let keep = F::one() - alpha + alpha * h * e;
        (keep.ln(), num / keep)
    }
}

/// Everything the fused compositing kernels need from one `exp`: the
/// opacity `o = α·Ψ_β(−sdf)`, the kept fraction `1 − o` computed without
/// cancellation (inside with α = 1 it is `e/2` exactly, not `1 − (1 − e/2)`),
/// `do/dsdf`, and `d ln(1 − o)/dsdf`. Needs `0 < α ≤ 1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpacityParts<F> {
    pub opacity: F,
    pub keep: F,
    pub d_opacity: F,
    pub d_log_keep: F,
}

/// See [`OpacityParts`].
#[inline]
pub fn sdf_opacity_parts<F: Float>(sdf: F, alpha: F, beta: F) -> OpacityParts<F> {
    sdf_opacity_parts_inv(sdf, alpha, F::one() / beta)
}

/// [`sdf_opacity_parts`] with `1/β` precomputed (hot loops avoid divisions).
#[inline]
pub fn sdf_opacity_parts_inv<F: Float>(sdf: F, alpha: F, inv_beta: F) -> OpacityParts<F> {
    let h = half::<F>();
    let e = (-sdf.abs() * inv_beta).exp();
    let ae = alpha * h * e;
    let num = ae * inv_beta;
    if sdf >= F::zero() {
        let keep = F::one() - ae;
        OpacityParts {
            opacity: ae,
            keep,
            d_opacity: -num,
            d_log_keep: num / keep,
        }
    } else if alpha == F::one() {
        OpacityParts {
            opacity: F::one() - ae,
            keep: ae,
            d_opacity: -num,
            // num/keep = 1/β, also where e underflows to 0.
            d_log_keep: inv_beta,
        }
    } else {
        let keep = F::one() - alpha + ae;
        OpacityParts {
            opacity: alpha - ae,
            keep,
            d_opacity: -num,
            d_log_keep: num / keep,
        }
    }
}

/// VolSDF density `σ = α·Ψ_β(−sdf)` (α is a density scale here, any α > 0).
#[inline]
pub fn volsdf_density<F: Float>(sdf: F, alpha: F, beta: F) -> F {
    sdf_opacity(sdf, alpha, beta)
}

/// VolSDF density and its derivative with respect to `sdf`.
#[inline]
pub fn volsdf_density_grad<F: Float>(sdf: F, alpha: F, beta: F) -> (F, F) {
    sdf_opacity_grad(sdf, alpha, beta)
}

/// NeuS logistic density `α·(1/β)·sigmoid(x)·(1 − sigmoid(x))`, `x = −sdf/β`.
#[inline]
pub fn neus_density<F: Float>(sdf: F, alpha: F, beta: F) -> F {
    neus_density_grad(sdf, alpha, beta).0
}

/// NeuS density and its derivative with respect to `sdf`.
///
/// With `e = exp(−|x|)`, `sigmoid(x)(1 − sigmoid(x)) = e/(1+e)²` (even in x)
/// and its x-derivative is `−sign(x)·e(1−e)/(1+e)³`; both are bounded.
#[inline]
pub fn neus_density_grad<F: Float>(sdf: F, alpha: F, beta: F) -> (F, F) {
    let x = -sdf / beta;
    let e = (-x.abs()).exp();
    let one_e = F::one() + e;
    let s = e / (one_e * one_e);
    let ds_dx = -x.signum() * e * (F::one() - e) / (one_e * one_e * one_e);
    let scale = alpha / beta;
    // dx/dsdf = −1/β.
    (scale * s, -scale * ds_dx / beta)
}

/// NeuS's opacity of the interval between consecutive samples `a` → `b`
/// along a ray, as an optical depth: with `Φ(f) = sigmoid(f/β)`, the
/// interval's opacity is `max(0, (Φ(f_a) − Φ(f_b))/Φ(f_a))` (Wang et al.,
/// 2021), so `τ = −ln(1 − opacity) = max(0, ln Φ(f_a) − ln Φ(f_b))`.
/// Weights built from it peak where the ray enters the zero level set,
/// without the logistic density's bias, and a ray leaving a surface
/// (`f` rising) absorbs nothing.
///
/// Returns `(τ, ∂τ/∂f_a, ∂τ/∂f_b)`. `τ` is homogeneous in `f/β`, so
/// `∂τ/∂β = −(f_a·∂τ/∂f_a + f_b·∂τ/∂f_b)/β`.
#[inline]
pub fn neus_interval_depth<F: Float>(f_a: F, f_b: F, beta: F) -> (F, F, F) {
    let (x_a, x_b) = (f_a / beta, f_b / beta);
    // ln Φ(x) = −softplus(−x). Both inside: ln Φ(x) = x − ln(1 + eˣ), and
    // x_a − x_b is taken from the distances so that deep inside (|x| huge)
    // nothing cancels.
    let tau = if x_a <= F::zero() && x_b <= F::zero() {
        (f_a - f_b) / beta - (x_a.exp().ln_1p() - x_b.exp().ln_1p())
    } else {
        softplus(-x_b) - softplus(-x_a)
    };
    if tau > F::zero() {
        // d ln Φ(x)/dx = sigmoid(−x).
        (tau, sigmoid(-x_a) / beta, -sigmoid(-x_b) / beta)
    } else {
        (F::zero(), F::zero(), F::zero())
    }
}

/// Numerically stable `softplus(x) = ln(1 + eˣ) = max(x, 0) + ln(1 + e^{−|x|})`.
#[inline]
pub fn softplus<F: Float>(x: F) -> F {
    x.max(F::zero()) + (-x.abs()).exp().ln_1p()
}

/// Derivative of softplus: `sigmoid(x)`, evaluated without overflow.
#[inline]
pub fn softplus_grad<F: Float>(x: F) -> F {
    sigmoid(x)
}

/// Stable logistic sigmoid.
#[inline]
pub fn sigmoid<F: Float>(x: F) -> F {
    let e = (-x.abs()).exp();
    if x >= F::zero() {
        F::one() / (F::one() + e)
    } else {
        e / (F::one() + e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Textbook two-branch formulas in f64, only evaluated where they are safe.
    fn naive_psi(s: f64, beta: f64) -> f64 {
        if s <= 0.0 {
            0.5 * (s / beta).exp()
        } else {
            1.0 - 0.5 * (-s / beta).exp()
        }
    }
    fn naive_neus(sdf: f64, alpha: f64, beta: f64) -> f64 {
        let sg = 1.0 / (1.0 + (sdf / beta).exp());
        alpha / beta * sg * (1.0 - sg)
    }

    fn fd<Fn_: Fn(f64) -> f64>(f: Fn_, x: f64, h: f64) -> f64 {
        (f(x + h) - f(x - h)) / (2.0 * h)
    }

    fn close(a: f64, b: f64, rel: f64, abs: f64) -> bool {
        (a - b).abs() <= abs + rel * a.abs().max(b.abs())
    }

    const SDFS: [f64; 9] = [-0.31, -0.07, -0.011, -0.002, 0.003, 0.013, 0.05, 0.2, 0.7];

    #[test]
    fn f32_matches_f64_reference() {
        for &beta in &[0.05f64, 0.1, 0.5] {
            for &sdf in &SDFS {
                let r = naive_psi(-sdf, beta);
                let v = sdf_opacity(sdf as f32, 1.0, beta as f32) as f64;
                assert!(close(v, r, 1e-5, 1e-7), "opacity {sdf} {beta}: {v} vs {r}");
                let lk = sdf_log_keep(sdf as f32, 1.0, beta as f32) as f64;
                assert!(close(lk, (1.0 - r).ln(), 1e-4, 1e-6), "log keep {sdf}");
                let lk = sdf_log_keep(sdf as f32, 0.7, beta as f32) as f64;
                assert!(close(lk, (1.0 - 0.7 * r).ln(), 1e-4, 1e-6));
                let n = neus_density(sdf as f32, 2.0, beta as f32) as f64;
                assert!(close(n, naive_neus(sdf, 2.0, beta), 1e-5, 1e-6));
            }
        }
        for &x in &[-30.0f64, -2.0, 0.0, 1.5, 40.0] {
            let r = (1.0 + x.exp()).ln();
            assert!(close(softplus(x as f32) as f64, r, 1e-6, 1e-7));
            assert!(close(softplus(x), r, 1e-12, 1e-14));
        }
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let h = 1e-6;
        for &beta in &[0.05f64, 0.3] {
            for &alpha in &[1.0f64, 0.6] {
                for &sdf in &SDFS {
                    let (_, d) = laplace_cdf_grad(sdf, beta);
                    assert!(close(d, fd(|s| naive_psi(s, beta), sdf, h), 1e-5, 1e-7));
                    let (_, d) = sdf_opacity_grad(sdf, alpha, beta);
                    let f = |s: f64| alpha * naive_psi(-s, beta);
                    assert!(close(d, fd(f, sdf, h), 1e-5, 1e-7));
                    let (_, d) = sdf_log_keep_grad(sdf, alpha, beta);
                    let f = |s: f64| (1.0 - alpha * naive_psi(-s, beta)).ln();
                    assert!(close(d, fd(f, sdf, h), 1e-5, 1e-6), "{sdf} {alpha} {beta}");
                    let (_, d) = neus_density_grad(sdf, alpha, beta);
                    assert!(close(
                        d,
                        fd(|s| naive_neus(s, alpha, beta), sdf, h),
                        1e-5,
                        1e-6
                    ));
                }
            }
        }
        for &x in &[-3.0f64, 0.2, 5.0] {
            let r = fd(|x| (1.0 + x.exp()).ln(), x, h);
            assert!(close(softplus_grad(x), r, 1e-6, 1e-9));
        }
    }

    /// ln Φ(f_a) − ln Φ(f_b) in f64 straight from the definition.
    fn naive_neus_depth(f_a: f64, f_b: f64, beta: f64) -> f64 {
        let phi = |f: f64| 1.0 / (1.0 + (-f / beta).exp());
        (phi(f_a).ln() - phi(f_b).ln()).max(0.0)
    }

    #[test]
    fn neus_interval_depth_matches_reference_and_differences() {
        let h = 1e-7;
        for &beta in &[0.02f64, 0.1, 0.5] {
            for &f_a in &SDFS {
                for &f_b in &SDFS {
                    let r = naive_neus_depth(f_a, f_b, beta);
                    let (t, d_a, d_b) = neus_interval_depth(f_a, f_b, beta);
                    assert!(close(t, r, 1e-9, 1e-12), "{f_a} {f_b} {beta}: {t} vs {r}");
                    let (t32, ..) = neus_interval_depth(f_a as f32, f_b as f32, beta as f32);
                    assert!(
                        close(t32 as f64, r, 1e-4, 1e-6),
                        "f32 {f_a} {f_b}: {t32} vs {r}"
                    );
                    if r > 1e-6 {
                        let fa = fd(|x| naive_neus_depth(x, f_b, beta), f_a, h);
                        let fb = fd(|x| naive_neus_depth(f_a, x, beta), f_b, h);
                        assert!(close(d_a, fa, 1e-5, 1e-6), "{f_a} {f_b}: {d_a} vs {fa}");
                        assert!(close(d_b, fb, 1e-5, 1e-6), "{f_a} {f_b}: {d_b} vs {fb}");
                        let fbeta = fd(|b| naive_neus_depth(f_a, f_b, b), beta, h);
                        let d_beta = -(f_a * d_a + f_b * d_b) / beta;
                        assert!(close(d_beta, fbeta, 1e-5, 1e-6), "β: {d_beta} vs {fbeta}");
                    } else {
                        // Leaving a surface or level: nothing absorbed.
                        assert!(f_b >= f_a - 1e-12 && t == 0.0);
                    }
                }
            }
        }
        // Across a whole surface the interval is opaque: τ ≈ (f_a − f_b)/β
        // once inside; crossing far outside → far inside absorbs all.
        let (t, ..) = neus_interval_depth(0.5f64, -0.5, 0.01);
        assert!(close(t, 50.0, 1e-9, 1e-9), "{t}");
    }

    #[test]
    fn hard_cases_finite_in_f32() {
        for &beta in &[1e-4f32, 1e-3, 0.05] {
            for &sdf in &[-1e3f32, -10.0, -1e-6, 0.0, 1e-6, 10.0, 1e3] {
                for &alpha in &[1.0f32, 0.5] {
                    let (o, d_o) = sdf_opacity_grad(sdf, alpha, beta);
                    let (l, d_l) = sdf_log_keep_grad(sdf, alpha, beta);
                    let (n, d_n) = neus_density_grad(sdf, alpha, beta);
                    let (v, d_v) = volsdf_density_grad(sdf, 10.0 * alpha, beta);
                    for x in [o, d_o, l, d_l, n, d_n, v, d_v] {
                        assert!(x.is_finite(), "sdf {sdf} beta {beta} alpha {alpha}: {x}");
                    }
                    assert!((0.0..=1.0).contains(&o));
                    assert!(l <= 0.0);
                }
            }
        }
        // Deep inside with α = 1 the opacity is exactly 1, yet ln(1 − o) is exact.
        assert_eq!(sdf_opacity(-1e3f32, 1.0, 1e-4), 1.0);
        let l = sdf_log_keep(-1e3f32, 1.0, 1e-4);
        assert!((l / (-1e7) - 1.0).abs() < 1e-5);
        for &sdf in &[-1e3f32, -0.3, -1e-3, 0.0, 2e-3, 0.4, 1e3] {
            for &(alpha, beta) in &[(1.0f32, 1e-4f32), (1.0, 0.05), (0.6, 0.05), (0.6, 1e-4)] {
                let p = sdf_opacity_parts(sdf, alpha, beta);
                let (o, d_o) = sdf_opacity_grad(sdf, alpha, beta);
                let (l, d_l) = sdf_log_keep_grad(sdf, alpha, beta);
                // Same values up to rounding (1/β is premultiplied).
                assert!((p.opacity - o).abs() <= 1e-6);
                assert!((p.d_opacity - d_o).abs() <= 1e-5 * d_o.abs());
                assert!((p.d_log_keep - d_l).abs() <= 1e-5 * d_l.abs());
                assert!(p.keep.is_finite() && p.d_log_keep.is_finite());
                if l > -80.0 {
                    assert!(
                        (p.keep.ln() - l).abs() <= 1e-6 + 1e-5 * l.abs(),
                        "{sdf} {alpha}"
                    );
                }
            }
        }
        // NeuS intervals: deep inside with tiny β (no cancellation to
        // garbage), far outside (τ underflows to 0 smoothly), equal
        // distances (grazing: 0), all finite.
        for &beta in &[1e-4f32, 1e-2] {
            for &(a, b) in &[
                (-1e3f32, -1e3 - 1e-2),
                (1e3, 1e3 - 0.01),
                (0.0, 0.0),
                (1e-6, -1e-6),
                (-5.0, 5.0),
                (5.0, -5.0),
            ] {
                let (t, d_a, d_b) = neus_interval_depth(a, b, beta);
                assert!(
                    [t, d_a, d_b].iter().all(|x| x.is_finite()),
                    "{a} {b} {beta}"
                );
                assert!(t >= 0.0 && d_a >= 0.0 && d_b <= 0.0);
            }
        }
        let (t, ..) = neus_interval_depth(-10f32, -10.01, 1e-4);
        assert!((t - 100.0).abs() < 0.05, "{t}");
        for &x in &[-1e30f32, -100.0, 100.0, 1e30] {
            assert!(softplus(x).is_finite() && softplus_grad(x).is_finite());
        }
    }
}
