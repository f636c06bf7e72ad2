//! The scene contraction: its Jacobian, f32 against the reference, its
//! inverse's stretch, depths even in disparity, hard cases.

use sdfl_runtime::neural::contract::*;
use sdfl_stdlib::value::Contraction;

fn points() -> Vec<[f64; 3]> {
    let mut v = vec![
        [0.3, -0.2, 0.9],
        [1.7, 0.4, -0.3],
        [-0.2, -5.0, 2.0],
        [30.0, -12.0, 7.5],
        [0.5, 0.25, -1.25],
        [1e4, 3.0, -2.0],
    ];
    let mut g = sdfl_runtime::volume::SplitMix64::new(3);
    for _ in 0..50 {
        let s = 10f64.powf(3.0 * g.next_f32() as f64 - 1.0);
        v.push(std::array::from_fn(|_| {
            s * (2.0 * g.next_f32() as f64 - 1.0)
        }));
    }
    v
}

/// The Jacobian against central differences of the f64 map, away
/// from the kinks where two axes tie.
#[test]
fn jacobian_matches_finite_differences() {
    for x in points() {
        let m = x.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let mut sorted = x.map(f64::abs);
        sorted.sort_by(f64::total_cmp);
        if sorted[2] - sorted[1] < 1e-3 * m || (m - 1.0).abs() < 1e-4 {
            continue;
        }
        let j = jacobian_f64(x);
        let h = 1e-6 * m.max(1.0);
        for c in 0..3 {
            let (mut up, mut down) = (x, x);
            up[c] += h;
            down[c] -= h;
            let (fu, fd) = (contract_f64(up), contract_f64(down));
            for i in 0..3 {
                let fdiff = (fu[i] - fd[i]) / (2.0 * h);
                assert!(
                    (fdiff - j[i][c]).abs() < 1e-6 * (1.0 + fdiff.abs()) / m.min(1.0),
                    "x {x:?}: J[{i}][{c}] {} vs {fdiff}",
                    j[i][c]
                );
            }
        }
    }
}

/// f32 against the f64 reference, and the contracted cube.
#[test]
fn f32_agrees_with_the_reference_and_stays_in_the_cube() {
    for x in points() {
        let want = contract_f64(x);
        let got = contract_f32(x.map(|v| v as f32));
        for i in 0..3 {
            assert!(
                (got[i] as f64 - want[i]).abs() < 1e-6 * (1.0 + want[i].abs()),
                "{x:?}: {got:?} vs {want:?}"
            );
            assert!(got[i].abs() <= 2.0);
        }
    }
}

/// Hard cases: the origin, exactly on the box (continuous and C¹
/// there: both sides' Jacobians agree), huge and infinite |x|.
#[test]
fn hard_cases_are_finite() {
    assert_eq!(contract_f32([0.0; 3]), [0.0; 3]);
    assert_eq!(
        jacobian_f64([0.0; 3]),
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    );
    let on = [1.0, 0.5, -0.25];
    assert_eq!(contract_f64(on), on);
    let out = jacobian_f64([1.0 + 1e-12, 0.5, -0.25]);
    let inside = jacobian_f64(on);
    for i in 0..3 {
        for c in 0..3 {
            assert!(
                (out[i][c] - inside[i][c]).abs() < 1e-9,
                "C¹ at the box: {out:?} vs {inside:?}"
            );
        }
    }
    for big in [1e30f32, f32::MAX, -f32::MAX] {
        let c = contract_f32([big, 1.0, -3.0]);
        assert!(c.iter().all(|v| v.is_finite() && v.abs() <= 2.0), "{c:?}");
        assert!((c[0].abs() - 2.0).abs() < 1e-6);
        let j = jacobian_f64([big as f64, 1.0, -3.0]);
        assert!(j.iter().flatten().all(|v| v.is_finite()), "{j:?}");
    }
    let inf = contract_f32([f32::INFINITY, 1.0, 0.0]);
    assert!(inf.iter().all(|v| v.is_finite()), "{inf:?}");
}

/// The stretch against differences of the inverse map along a radius.
#[test]
fn world_per_contracted_is_the_inverse_maps_radial_stretch() {
    let c = Contract::new(&Contraction {
        min: [-2.0; 3],
        max: [2.0; 3],
    });
    assert_eq!(c.world_per_contracted([0.5, 0.0, 0.0]), 2.0);
    // Inverse along +x: y = 2 − 1/x (x ≥ 1) ⇒ x = 1/(2 − y); world = 2·x.
    for y in [1.2f64, 1.5, 1.9] {
        let inv = |y: f64| 2.0 / (2.0 - y);
        let h = 1e-6;
        let fd = (inv(y + h) - inv(y - h)) / (2.0 * h);
        let got = c.world_per_contracted([y as f32, 0.3, -0.2]) as f64;
        assert!((got - fd).abs() < 1e-4 * fd, "{y}: {got} vs {fd}");
    }
    assert!(c.world_per_contracted([2.0, 0.0, 0.0]).is_finite());
}

/// Piecewise depths: in order, from near, through the box exit at the
/// middle sample, to far; disparity steps equal beyond the box.
#[test]
fn depths_are_linear_then_even_in_disparity() {
    let c = Contract::new(&Contraction {
        min: [-1.0; 3],
        max: [1.0; 3],
    });
    let t: Vec<f32> = (0..=8)
        .map(|k| 0.5 + k as f32 * (1000.0 - 0.5) / 8.0)
        .collect();
    let mut out = Vec::new();
    c.depths([0.0, 0.0, -4.0], [0.0, 0.0, 1.0], 0.5, 1000.0, &t, &mut out);
    assert!(out.windows(2).all(|w| w[0] <= w[1]), "{out:?}");
    assert!(
        (out[4] - 5.0).abs() < 1e-5,
        "the box is left at t = 5: {out:?}"
    );
    assert!((out[8] - 1000.0).abs() < 1e-2);
    let disp: Vec<f64> = out[4..].iter().map(|&t| 1.0 / t as f64).collect();
    let step = disp[0] - disp[1];
    for w in disp.windows(2) {
        assert!(((w[0] - w[1]) - step).abs() < 1e-6, "{disp:?}");
    }
    // A ray missing the box: every depth stays finite and ordered.
    out.clear();
    c.depths([5.0, 5.0, -4.0], [0.0, 0.0, 1.0], 0.5, 1000.0, &t, &mut out);
    assert!(out.iter().all(|t| t.is_finite()) && out.windows(2).all(|w| w[0] <= w[1]));
}
