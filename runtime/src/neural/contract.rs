//! Scene contraction for unbounded scenes (mip-NeRF 360), in the ∞-norm
//! as nerfstudio's `SceneContraction(order=inf)` and nerfacc use it: with
//! the inner box mapped to [-1, 1]³ and `m = max |x_i|`,
//! `contract(x) = x` for `m ≤ 1`, else `(2 − 1/m)·x/m`. The ∞-norm (not
//! the 2-norm of the paper) because the contracted scene then fills the
//! cube [-2, 2]³ that the hash grid and occupancy grid tile, instead of a
//! ball leaving their corners unused. The map is C¹ across `m = 1`.
//!
//! Samples beyond the inner box are spaced evenly in disparity (1/t), as
//! nerfstudio's `UniformLinDispPiecewiseSampler`: half the depths evenly
//! from `near` to where the ray leaves the inner box, half evenly in 1/t
//! from there to `far`, so far content (which contracts to a thin shell)
//! gets about as many samples as its contracted size.

use sdfl_stdlib::value::Contraction;

/// A contraction as the runtime computes it (f32).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contract {
    /// The inner box's centre.
    pub center: [f32; 3],
    /// 2 / (max − min) per axis: the inner box to [-1, 1]³.
    pub inv_half: [f32; 3],
    /// The inner box in world coordinates (f64: the rays' exits).
    pub min: [f64; 3],
    /// The inner box's high corner in world coordinates.
    pub max: [f64; 3],
}

impl Contract {
    /// The runtime's form of a scene file's `contraction(...)`.
    pub fn new(c: &Contraction) -> Self {
        Contract {
            center: std::array::from_fn(|a| (0.5 * (c.min[a] + c.max[a])) as f32),
            inv_half: std::array::from_fn(|a| (2.0 / (c.max[a] - c.min[a])) as f32),
            min: c.min,
            max: c.max,
        }
    }

    /// A world point in the contracted cube [-2, 2]³.
    #[inline]
    pub fn apply(&self, p: [f32; 3]) -> [f32; 3] {
        let x = std::array::from_fn(|a| (p[a] - self.center[a]) * self.inv_half[a]);
        contract_f32(x)
    }

    /// World length per unit of contracted length at a contracted point
    /// `y`, along the radius (the inverse map's largest stretch): the inner
    /// box's half extent inside it, growing as `1/(2 − m)²` beyond (`m`
    /// the ∞-norm of `y`, held below 2 so the cube's faces stay finite).
    pub fn world_per_contracted(&self, y: [f32; 3]) -> f32 {
        let h = self.inv_half.iter().fold(0.0f32, |a, &v| a.max(1.0 / v));
        let m = y[0].abs().max(y[1].abs()).max(y[2].abs());
        if m <= 1.0 {
            h
        } else {
            let gap = (2.0 - m).max(1e-3);
            h / (gap * gap)
        }
    }

    /// Where the ray `o + t·d` leaves the inner box, within `[near, far]`
    /// (`near` where it misses the box or has left it).
    pub fn exit(&self, o: [f32; 3], d: [f32; 3], near: f64, far: f64) -> f64 {
        let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
        for a in 0..3 {
            let (oa, da) = (o[a] as f64, d[a] as f64);
            if da == 0.0 {
                if oa < self.min[a] || oa > self.max[a] {
                    return near;
                }
                continue;
            }
            let (u, v) = ((self.min[a] - oa) / da, (self.max[a] - oa) / da);
            t0 = t0.max(u.min(v));
            t1 = t1.min(u.max(v));
        }
        if t0 > t1 || !t1.is_finite() {
            near
        } else {
            t1.clamp(near, far)
        }
    }

    /// Depths `t` of a stratified sampler on `[near, far]` moved to the
    /// piecewise linear / disparity spacing of the ray `o + t·d`, in
    /// order, into `out` (appended).
    pub fn depths(
        &self,
        o: [f32; 3],
        d: [f32; 3],
        near: f64,
        far: f64,
        t: &[f32],
        out: &mut Vec<f32>,
    ) {
        let exit = self.exit(o, d, near, far);
        out.extend(
            t.iter()
                .map(|&tk| piecewise(tk as f64, near, far, exit) as f32),
        );
    }
}

/// `u = (t − near)/(far − near)` below ½ evenly from `near` to `exit`,
/// above it evenly in 1/t from `exit` to `far`.
pub fn piecewise(t: f64, near: f64, far: f64, exit: f64) -> f64 {
    let u = ((t - near) / (far - near)).clamp(0.0, 1.0);
    if u <= 0.5 {
        near + 2.0 * u * (exit - near)
    } else {
        let s = 2.0 * u - 1.0;
        let exit = exit.max(1e-6 * far).max(f64::MIN_POSITIVE);
        1.0 / ((1.0 - s) / exit + s / far)
    }
}

/// The contraction of a point in inner-box coordinates (f32).
#[inline]
#[allow(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "a NaN must take the identity branch"
)]
pub fn contract_f32(x: [f32; 3]) -> [f32; 3] {
    let m = x[0].abs().max(x[1].abs()).max(x[2].abs());
    if m.is_infinite() {
        // The limit along the infinite axes.
        return x.map(|v| {
            if v.is_infinite() {
                2f32.copysign(v)
            } else {
                0.0
            }
        });
    }
    if !(m > 1.0) {
        // Inside the box (or NaN, which callers refuse as a sample).
        return x;
    }
    // (2 − 1/m)·(x/m): no m² formed, so no overflow at any finite m.
    let s = 2.0 - 1.0 / m;
    x.map(|v| s * (v / m))
}

/// The contraction in f64 (the reference).
pub fn contract_f64(x: [f64; 3]) -> [f64; 3] {
    let m = x[0].abs().max(x[1].abs()).max(x[2].abs());
    if m <= 1.0 {
        return x;
    }
    let s = 2.0 - 1.0 / m;
    x.map(|v| s * (v / m))
}

/// The Jacobian `∂contract_i/∂x_j` (rows i) in f64. Beyond the box, with
/// `k` the axis of the largest |x_k| and `σ` its sign:
/// `J = (2/m − 1/m²)·I + x·(2/m³ − 2/m²)·σ·e_kᵀ`. (Where two axes tie for
/// the largest, the map has a kink; the first such axis is used.)
pub fn jacobian_f64(x: [f64; 3]) -> [[f64; 3]; 3] {
    let mut k = 0;
    for a in 1..3 {
        if x[a].abs() > x[k].abs() {
            k = a;
        }
    }
    let m = x[k].abs();
    let mut j = [[0.0; 3]; 3];
    if m <= 1.0 {
        for (a, row) in j.iter_mut().enumerate() {
            row[a] = 1.0;
        }
        return j;
    }
    let (inv, sigma) = (1.0 / m, x[k].signum());
    // (2/m − 1/m²) and (2/m³ − 2/m²) = (2/m)·(1/m)·(1/m − 1), written
    // with x/m so that nothing overflows.
    let diag = inv * (2.0 - inv);
    for i in 0..3 {
        j[i][i] = diag;
        j[i][k] += (x[i] * inv) * 2.0 * inv * (inv - 1.0) * sigma;
    }
    j
}

#[cfg(test)]
mod tests {
    use super::*;

    fn points() -> Vec<[f64; 3]> {
        let mut v = vec![
            [0.3, -0.2, 0.9],
            [1.7, 0.4, -0.3],
            [-0.2, -5.0, 2.0],
            [30.0, -12.0, 7.5],
            [0.5, 0.25, -1.25],
            [1e4, 3.0, -2.0],
        ];
        let mut g = crate::volume::SplitMix64::new(3);
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
}
