//! Analytic box SDF and the "rainbow" colour of CONVENTIONS.md, with the
//! partial derivatives the fused training kernel needs.

use num_traits::Float;

/// Lower and upper clamp of the rainbow colour.
pub const RAINBOW_LO: f64 = 0.02;
/// Upper clamp of the rainbow colour.
pub const RAINBOW_HI: f64 = 0.98;

/// Exact SDF of an axis-aligned box with centre `c` and *full* side lengths
/// `s`: `q = |p − c| − s/2`, `|max(q, 0)| + min(max(qx, qy, qz), 0)`.
#[inline]
pub fn box_sdf<F: Float>(p: [F; 3], c: [F; 3], s: [F; 3]) -> F {
    box_sdf_grad(p, c, s).sdf
}

/// A box SDF value with its partial derivatives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxSdfGrad<F> {
    pub sdf: F,
    /// `∂sdf/∂p` (equals `−∂sdf/∂c`).
    pub d_p: [F; 3],
    /// `∂sdf/∂s` (full side lengths).
    pub d_s: [F; 3],
}

/// Box SDF and its gradient. Where the formula is not differentiable (on the
/// symmetry planes `p = c`, on faces/edges inside) it returns one of the
/// one-sided derivatives; those sets have measure zero.
#[inline]
pub fn box_sdf_grad<F: Float>(p: [F; 3], c: [F; 3], s: [F; 3]) -> BoxSdfGrad<F> {
    let h = F::from(0.5).unwrap();
    let mut q = [F::zero(); 3];
    let mut sign = [F::one(); 3];
    for i in 0..3 {
        let d = p[i] - c[i];
        if d < F::zero() {
            sign[i] = -F::one();
        }
        q[i] = d.abs() - h * s[i];
    }
    let mut d_q = [F::zero(); 3];
    let r2 = (0..3).fold(F::zero(), |a, i| a + q[i].max(F::zero()).powi(2));
    let sdf = if r2 > F::zero() {
        // Outside: max(q) > 0 so the interior term is zero.
        let r = r2.sqrt();
        for i in 0..3 {
            d_q[i] = q[i].max(F::zero()) / r;
        }
        r
    } else {
        let mut k = 0;
        for i in 1..3 {
            if q[i] > q[k] {
                k = i;
            }
        }
        d_q[k] = F::one();
        q[k].min(F::zero())
    };
    BoxSdfGrad {
        sdf,
        d_p: [d_q[0] * sign[0], d_q[1] * sign[1], d_q[2] * sign[2]],
        d_s: [-h * d_q[0], -h * d_q[1], -h * d_q[2]],
    }
}

/// Rainbow colour `clamp(|p − c|, 0.02, 0.98)` componentwise.
#[inline]
pub fn rainbow<F: Float>(p: [F; 3], c: [F; 3]) -> [F; 3] {
    rainbow_grad(p, c).0
}

/// Rainbow colour and `∂colour_i/∂c_i` (the Jacobian is diagonal): `−sign(p−c)`
/// strictly inside the clamp range, 0 where clamped.
#[inline]
pub fn rainbow_grad<F: Float>(p: [F; 3], c: [F; 3]) -> ([F; 3], [F; 3]) {
    let lo = F::from(RAINBOW_LO).unwrap();
    let hi = F::from(RAINBOW_HI).unwrap();
    let mut col = [F::zero(); 3];
    let mut d_c = [F::zero(); 3];
    for i in 0..3 {
        let d = p[i] - c[i];
        let a = d.abs();
        col[i] = a.max(lo).min(hi);
        if a > lo && a < hi {
            d_c[i] = if d < F::zero() { F::one() } else { -F::one() };
        }
    }
    (col, d_c)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Straight transcription of the formula in f64.
    fn reference(p: [f64; 3], c: [f64; 3], s: [f64; 3]) -> f64 {
        let q: Vec<f64> = (0..3).map(|i| (p[i] - c[i]).abs() - s[i] / 2.0).collect();
        let outside = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt();
        outside + q[0].max(q[1]).max(q[2]).min(0.0)
    }

    fn points() -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        for &x in &[-1.7, -0.61, 0.13, 0.52, 1.9] {
            for &y in &[-1.1, 0.07, 0.44, 2.3] {
                for &z in &[-0.9, 0.21, 0.83] {
                    v.push([x, y, z]);
                }
            }
        }
        v
    }

    #[test]
    fn box_matches_reference_f32_and_f64() {
        let c = [0.25, 0.25, 0.0];
        let s = [2.0, 1.5, 1.5];
        for p in points() {
            let r = reference(p, c, s);
            assert!((box_sdf(p, c, s) - r).abs() < 1e-14);
            let f = |a: [f64; 3]| a.map(|v| v as f32);
            assert!((box_sdf(f(p), f(c), f(s)) as f64 - r).abs() < 1e-6);
        }
        // Known values: centre is −min(s)/2 inside; a corner point.
        assert!((box_sdf([0.25, 0.25, 0.0], c, s) + 0.75).abs() < 1e-12);
        assert!((box_sdf([2.25, 2.0, 1.75], c, s) - 3f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn box_gradient_matches_finite_differences() {
        // Chosen so no test point sits on a kink (tied q components).
        let c = [0.1, -0.05, 0.03];
        let s = [1.5, 1.2, 1.7];
        let h = 1e-6;
        for p in points() {
            let g = box_sdf_grad(p, c, s);
            for i in 0..3 {
                let mut cp = c;
                let mut cm = c;
                cp[i] += h;
                cm[i] -= h;
                let fd_c = (reference(p, cp, s) - reference(p, cm, s)) / (2.0 * h);
                assert!((-g.d_p[i] - fd_c).abs() < 1e-6, "c{i} at {p:?}");
                let mut sp = s;
                let mut sm = s;
                sp[i] += h;
                sm[i] -= h;
                let fd_s = (reference(p, c, sp) - reference(p, c, sm)) / (2.0 * h);
                assert!((g.d_s[i] - fd_s).abs() < 1e-6, "s{i} at {p:?}");
            }
        }
    }

    #[test]
    fn rainbow_gradient_matches_finite_differences() {
        let c = [0.1, -0.05, 0.02];
        let h = 1e-6;
        for p in points() {
            let (col, d_c) = rainbow_grad(p, c);
            for i in 0..3 {
                assert!((RAINBOW_LO..=RAINBOW_HI).contains(&col[i]));
                let mut cp = c;
                let mut cm = c;
                cp[i] += h;
                cm[i] -= h;
                let fd = (rainbow(p, cp)[i] - rainbow(p, cm)[i]) / (2.0 * h);
                assert!((d_c[i] - fd).abs() < 1e-6);
            }
        }
    }
}
