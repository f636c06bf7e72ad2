//! Every registered density against textbook f64 formulas, finite
//! differences and hard cases. The references match on [`DensityKind`]
//! without a wildcard, so a new density does not compile until it has one,
//! and the tests iterate [`visit_densities`], so none is left out.

use sdfl_stdlib::density::*;
use sdfl_stdlib::num::Dual;
use sdfl_stdlib::num::Real;

/// The Laplace CDF `Ψ_β(s)`, two-branch, where it is safe.
fn psi(s: f64, beta: f64) -> f64 {
    if s <= 0.0 {
        0.5 * (s / beta).exp()
    } else {
        1.0 - 0.5 * (-s / beta).exp()
    }
}

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// σ straight from each paper's definition.
fn sigma_ref(kind: DensityKind, sdf: f64, alpha: f64, beta: f64) -> f64 {
    match kind {
        DensityKind::Opacity | DensityKind::VolSdf => alpha * psi(-sdf, beta),
        DensityKind::Neus => {
            let s = sigmoid(-sdf / beta);
            alpha / beta * s * (1.0 - s)
        }
    }
}

/// `(opacity, ln(1 − opacity))` of one sample over `delta`.
fn absorption_ref(kind: DensityKind, sdf: f64, alpha: f64, beta: f64, delta: f64) -> (f64, f64) {
    match kind {
        DensityKind::Opacity => {
            assert!(kind.per_sample_opacity());
            let o = alpha * psi(-sdf, beta);
            (o, (1.0 - o).ln())
        }
        DensityKind::VolSdf | DensityKind::Neus => {
            let tau = sigma_ref(kind, sdf, alpha, beta) * delta;
            (1.0 - (-tau).exp(), -tau)
        }
    }
}

/// The optical depth a neural SDF's sample adds.
fn neural_ref(
    kind: DensityKind,
    f: f64,
    next: Option<f64>,
    alpha: f64,
    beta: f64,
    delta: f64,
) -> f64 {
    match kind {
        DensityKind::Opacity | DensityKind::VolSdf => {
            -absorption_ref(kind, f, alpha, beta, delta).1
        }
        DensityKind::Neus => match next {
            Some(b) => {
                let phi = |f: f64| sigmoid(f / beta);
                (phi(f).ln() - phi(b).ln()).max(0.0)
            }
            None => 0.0,
        },
    }
}

fn close(a: f64, b: f64, rel: f64, abs: f64) -> bool {
    (a - b).abs() <= abs + rel * a.abs().max(b.abs())
}

const SDFS: [f64; 9] = [-0.31, -0.07, -0.011, -0.002, 0.003, 0.013, 0.05, 0.2, 0.7];

/// Moderate α: an opacity's below and at 1, a density scale's above too.
fn alphas<D: Density>() -> Vec<f64> {
    let mut a = vec![0.6, 1.0];
    if D::ALPHA_MAX > 1.0 {
        a.push(7.0);
    }
    a
}

/// Runs a generic check on every density.
fn every(check: impl FnMut(DensityKind, &dyn Fn() -> Vec<f64>)) {
    struct V<C>(C, Vec<DensityKind>);
    impl<C: FnMut(DensityKind, &dyn Fn() -> Vec<f64>)> DensityVisitor for V<C> {
        fn visit<D: Density>(&mut self) {
            self.1.push(D::KIND);
            (self.0)(D::KIND, &alphas::<D>);
        }
    }
    let mut v = V(check, Vec::new());
    visit_densities(&mut v);
    assert_eq!(
        v.1,
        DensityKind::ALL,
        "every density visited once, in order"
    );
}

#[test]
fn registry_lists_every_density_with_its_own_answers() {
    struct Names(Vec<&'static str>);
    impl DensityVisitor for Names {
        fn visit<D: Density>(&mut self) {
            let k = D::KIND;
            assert_eq!(k.name(), D::NAME);
            assert_eq!(k.title(), D::TITLE);
            assert_eq!(k.alpha_max(), D::ALPHA_MAX);
            assert_eq!(k.neural(), D::NEURAL);
            assert_eq!(k.per_sample_opacity(), D::PER_SAMPLE_OPACITY);
            // A per-sample opacity ignores the interval; a density does not.
            let o = |d: f64| D::absorption(-0.01f64, 0.5, 20.0, d).opacity;
            assert_eq!(o(0.1) == o(0.2), D::PER_SAMPLE_OPACITY, "{}", D::NAME);
            assert!(D::ALPHA_MAX >= 1.0 && !D::DOC.is_empty());
            let a: f64 = D::ALPHA_DEFAULT.parse().expect("a number");
            assert!(a >= ALPHA_MIN && a <= D::ALPHA_MAX, "{}", D::NAME);
            // The enum's dispatch reaches this density's formulas.
            let (s, al, ib, d) = (-0.03f64, 0.8, 20.0, 0.1);
            assert_eq!(k.sigma(s, al, ib), D::sigma(s, al, ib));
            assert_eq!(k.log_keep(s, al, ib, d), D::log_keep(s, al, ib, d));
            assert_eq!(
                k.absorption(s, al, ib, d).opacity,
                D::absorption(s, al, ib, d).opacity
            );
            assert_eq!(
                k.neural_depth(s, Some(-0.05), al, ib, d),
                D::neural_depth(s, Some(-0.05), al, ib, d)
            );
            self.0.push(D::NAME);
        }
    }
    let mut n = Names(Vec::new());
    visit_densities(&mut n);
    let mut unique = n.0.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), n.0.len(), "built-in names are distinct");
}

#[test]
fn f64_and_f32_match_the_reference() {
    every(|kind, alphas| {
        for beta in [0.05f64, 0.1, 0.5] {
            for alpha in alphas() {
                for sdf in SDFS {
                    for delta in [0.02f64, 0.3] {
                        let ib = 1.0 / beta;
                        let want_s = sigma_ref(kind, sdf, alpha, beta);
                        let (want_o, want_l) = absorption_ref(kind, sdf, alpha, beta, delta);
                        let a = kind.absorption(sdf, alpha, ib, delta);
                        let l = kind.log_keep(sdf, alpha, ib, delta);
                        let s = kind.sigma(sdf, alpha, ib);
                        let at = format!("{kind:?} sdf {sdf} α {alpha} β {beta} Δ {delta}");
                        assert!(close(s, want_s, 1e-12, 1e-14), "σ {at}: {s} vs {want_s}");
                        assert!(close(a.opacity, want_o, 1e-12, 1e-14), "o {at}");
                        assert!(close(a.keep, 1.0 - want_o, 1e-12, 1e-14), "keep {at}");
                        assert!(close(l, want_l, 1e-12, 1e-14), "ln keep {at}");
                        let (f, a32) = (sdf as f32, alpha as f32);
                        let (ib32, d32) = (1.0 / beta as f32, delta as f32);
                        let s32 = kind.sigma(f, a32, ib32) as f64;
                        let o32 = kind.absorption(f, a32, ib32, d32).opacity as f64;
                        let l32 = kind.log_keep(f, a32, ib32, d32) as f64;
                        assert!(close(s32, want_s, 1e-5, 1e-7), "f32 σ {at}");
                        assert!(close(o32, want_o, 1e-5, 1e-7), "f32 o {at}");
                        assert!(close(l32, want_l, 1e-4, 1e-6), "f32 ln keep {at}");
                        for next in [None, Some(sdf - 0.03), Some(sdf + 0.03), Some(-sdf)] {
                            let want = neural_ref(kind, sdf, next, alpha, beta, delta);
                            let got = kind.neural_depth(sdf, next, alpha, ib, delta);
                            assert!(close(got, want, 1e-9, 1e-12), "τ {at} next {next:?}");
                            let got = kind.neural_depth(f, next.map(|x| x as f32), a32, ib32, d32);
                            assert!(close(got as f64, want, 1e-4, 1e-6), "f32 τ {at} {next:?}");
                        }
                    }
                }
            }
        }
    });
}

/// Central differences of `f` at `x` in each coordinate.
fn fd<const N: usize>(f: impl Fn([f64; N]) -> f64, x: [f64; N]) -> [f64; N] {
    std::array::from_fn(|i| {
        let h = 1e-6 * x[i].abs().max(1e-2);
        let (mut a, mut b) = (x, x);
        a[i] += h;
        b[i] -= h;
        (f(a) - f(b)) / (2.0 * h)
    })
}

fn seeds<const N: usize>(x: [f64; N]) -> [Dual<f64, N>; N] {
    std::array::from_fn(|i| Dual::seed(x[i], i))
}

#[test]
fn dual_derivatives_match_finite_differences_of_the_reference() {
    every(|kind, alphas| {
        for beta in [0.05f64, 0.3] {
            for alpha in alphas() {
                for sdf in SDFS {
                    let delta = 0.1;
                    let x = [sdf, alpha, beta, delta];
                    let [s, a, b, d] = seeds(x);
                    let ib = Dual::one() / b;
                    let at = format!("{kind:?} sdf {sdf} α {alpha} β {beta}");
                    let check = |what: &str, got: Dual<f64, 4>, want: [f64; 4]| {
                        for (i, (&g, &w)) in got.d.iter().zip(&want).enumerate() {
                            assert!(close(g, w, 1e-5, 1e-7), "∂{what}/∂x{i} {at}: {g} vs {w}");
                        }
                    };
                    check(
                        "σ",
                        kind.sigma(s, a, ib),
                        fd(|[s, a, b, _]| sigma_ref(kind, s, a, b), x),
                    );
                    check(
                        "o",
                        kind.absorption(s, a, ib, d).opacity,
                        fd(|[s, a, b, d]| absorption_ref(kind, s, a, b, d).0, x),
                    );
                    check(
                        "keep",
                        kind.absorption(s, a, ib, d).keep,
                        fd(|[s, a, b, d]| 1.0 - absorption_ref(kind, s, a, b, d).0, x),
                    );
                    check(
                        "ln keep",
                        kind.log_keep(s, a, ib, d),
                        fd(|[s, a, b, d]| absorption_ref(kind, s, a, b, d).1, x),
                    );
                    for next in SDFS {
                        let y = [sdf, next, alpha, beta, delta];
                        let want_v = neural_ref(kind, sdf, Some(next), alpha, beta, delta);
                        // The interval form has a kink where it starts to absorb.
                        if kind.neural() == NeuralUse::PerInterval && want_v < 1e-6 {
                            continue;
                        }
                        let [f, n, a, b, d] = seeds(y);
                        let got = kind.neural_depth(f, Some(n), a, Dual::one() / b, d);
                        let want = fd(|[f, n, a, b, d]| neural_ref(kind, f, Some(n), a, b, d), y);
                        for (i, (&g, &w)) in got.d.iter().zip(&want).enumerate() {
                            assert!(
                                close(g, w, 1e-5, 1e-7),
                                "∂τ/∂x{i} {at} next {next}: {g} vs {w}"
                            );
                        }
                    }
                }
            }
        }
    });
}

#[test]
fn hard_cases_give_finite_values_and_derivatives() {
    let sdfs = [-1e6f32, -1e3, -10.0, -1e-6, 0.0, 1e-6, 10.0, 1e3, 1e6];
    every(|kind, alphas| {
        let mut alphas: Vec<f32> = alphas().into_iter().map(|a| a as f32).collect();
        alphas.push(ALPHA_MIN as f32);
        if kind.alpha_max() > 1.0 {
            alphas.push(1e4);
        }
        // β → tiny is s = 1/β → large.
        for beta in [1e-4f32, 1e-3, 0.05, 10.0] {
            for &alpha in &alphas {
                for sdf in sdfs {
                    for delta in [0.0f32, 1e-3, 1.0, 1e10] {
                        let s = Dual::<f32, 4>::seed(sdf, 0);
                        let a = Dual::seed(alpha, 1);
                        let ib = Dual::one() / Dual::seed(beta, 2);
                        let d = Dual::seed(delta, 3);
                        let at = format!("{kind:?} sdf {sdf} α {alpha} β {beta} Δ {delta}");
                        let ab = kind.absorption(s, a, ib, d);
                        let l = kind.log_keep(s, a, ib, d);
                        let sg = kind.sigma(s, a, ib);
                        for x in [ab.opacity, ab.keep, l, sg] {
                            assert!(
                                x.v.is_finite() && x.d.iter().all(|d| d.is_finite()),
                                "{at}: {x:?}"
                            );
                        }
                        assert!((0.0..=1.0).contains(&ab.opacity.v), "{at}");
                        assert!((0.0..=1.0).contains(&ab.keep.v), "{at}");
                        assert!(l.v <= 0.0 && sg.v >= 0.0, "{at}");
                        for next in sdfs.iter().map(|&n| Some(n)).chain([None]) {
                            let n = next.map(|n| Dual::seed(n, 1));
                            let t = kind.neural_depth(s, n, a, ib, d);
                            assert!(
                                t.v.is_finite() && t.v >= 0.0 && t.d.iter().all(|d| d.is_finite()),
                                "τ {at} next {next:?}: {t:?}"
                            );
                        }
                    }
                }
            }
        }
    });
    // Deep inside an opaque shape: the opacity is exactly 1 and ln(1 − o)
    // exact, not ln 0.
    let (o, l) = (
        DensityKind::Opacity.absorption(-1e3f32, 1.0, 1e4, 0.1),
        DensityKind::Opacity.log_keep(-1e3f32, 1.0, 1e4, 0.1),
    );
    assert_eq!((o.opacity, o.keep), (1.0, 0.0));
    assert!((l / -1e7 - 1.0).abs() < 1e-5, "{l}");
    // NeuS across a whole surface with tiny β is opaque, τ ≈ Δf/β, and deep
    // inside nothing cancels.
    let t = DensityKind::Neus.neural_depth(0.5f64, Some(-0.5), 1.0, 100.0, 0.1);
    assert!(close(t, 50.0, 1e-9, 1e-9), "{t}");
    let t = DensityKind::Neus.neural_depth(-10f32, Some(-10.01), 1.0, 1e4, 0.1);
    assert!((t - 100.0).abs() < 0.05, "{t}");
}
