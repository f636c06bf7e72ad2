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
