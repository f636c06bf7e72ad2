//! Input encodings of neural fields.

use rayon::prelude::*;

/// Rows per parallel block.
const ROW_BLOCK: usize = 1024;

/// The harmonic (Fourier) embedding of NeRF: for `x ∈ ℝ^d`, the features
/// `sin(2^k·x_i)` for every `i, k`, then `cos(2^k·x_i)`, then (when
/// `include_input`) `x` itself; `d·(2·freqs + 1)` numbers. The layout is
/// the reference implementation's (input dimension outer, frequency inner
/// within the sines, then the cosines).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Harmonic {
    /// Dimensions of the input (3 for positions and directions).
    pub dims: usize,
    /// Frequencies `2^0 … 2^(freqs−1)` per dimension.
    pub freqs: usize,
    /// Whether the input itself is a feature too.
    pub include_input: bool,
}

impl Harmonic {
    /// Features per input.
    pub fn width(&self) -> usize {
        self.dims * 2 * self.freqs + if self.include_input { self.dims } else { 0 }
    }

    /// Encodes `points` (rows of `dims`) into `out` (rows of `width`).
    pub fn encode(&self, points: &[f32], out: &mut [f32]) {
        let (d, w) = (self.dims, self.width());
        assert_eq!(points.len() / d * w, out.len());
        out.par_chunks_mut(ROW_BLOCK * w)
            .zip(points.par_chunks(ROW_BLOCK * d))
            .for_each(|(o, p)| {
                for (row, x) in o.chunks_mut(w).zip(p.chunks(d)) {
                    self.encode_one(x, row);
                }
            });
    }

    #[inline]
    /// Encodes one input `x` into `row`.
    pub fn encode_one(&self, x: &[f32], row: &mut [f32]) {
        let (d, f) = (self.dims, self.freqs);
        for i in 0..d {
            let mut scale = 1.0f32;
            for k in 0..f {
                let (s, c) = (x[i] * scale).sin_cos();
                row[i * f + k] = s;
                row[d * f + i * f + k] = c;
                scale *= 2.0;
            }
        }
        if self.include_input {
            row[2 * d * f..2 * d * f + d].copy_from_slice(&x[..d]);
        }
    }

    /// `∂L/∂x` from `∂L/∂features` (rows of `width`) at `points`: the
    /// chain rule through the sines and cosines (for fields whose input
    /// gradient matters, like a neural SDF's normal).
    pub fn backward(&self, points: &[f32], d_out: &[f32], d_points: &mut [f32]) {
        let (d, f, w) = (self.dims, self.freqs, self.width());
        d_points
            .par_chunks_mut(ROW_BLOCK * d)
            .zip(points.par_chunks(ROW_BLOCK * d))
            .zip(d_out.par_chunks(ROW_BLOCK * w))
            .for_each(|((dp, p), g)| {
                for ((dx, x), g) in dp.chunks_mut(d).zip(p.chunks(d)).zip(g.chunks(w)) {
                    for i in 0..d {
                        let mut acc = if self.include_input {
                            g[2 * d * f + i]
                        } else {
                            0.0
                        };
                        let mut scale = 1.0f32;
                        for k in 0..f {
                            let (s, c) = (x[i] * scale).sin_cos();
                            acc += scale * (c * g[i * f + k] - s * g[d * f + i * f + k]);
                            scale *= 2.0;
                        }
                        dx[i] = acc;
                    }
                }
            });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_matches_the_reference_embedding() {
        let h = Harmonic {
            dims: 3,
            freqs: 6,
            include_input: true,
        };
        assert_eq!(h.width(), 39);
        let x = [0.3f32, -1.2, 2.0];
        let mut row = vec![0.0; 39];
        h.encode_one(&x, &mut row);
        // Reference (f64): embed = x[..., None] * 2^k flattened, then sin, cos, x.
        let mut want = Vec::new();
        let embed: Vec<f64> = x
            .iter()
            .flat_map(|&v| (0..6).map(move |k| v as f64 * 2f64.powi(k)))
            .collect();
        want.extend(embed.iter().map(|e| e.sin()));
        want.extend(embed.iter().map(|e| e.cos()));
        want.extend(x.iter().map(|&v| v as f64));
        for (a, b) in row.iter().zip(&want) {
            assert!((*a as f64 - b).abs() < 1e-5, "{a} vs {b}");
        }
    }

    #[test]
    fn backward_matches_finite_differences() {
        let h = Harmonic {
            dims: 3,
            freqs: 4,
            include_input: true,
        };
        let x = [0.7f32, -0.4, 1.3];
        let g: Vec<f32> = (0..h.width())
            .map(|i| ((i * 7 % 11) as f32 - 5.0) / 5.0)
            .collect();
        let loss = |x: &[f32]| -> f64 {
            let mut row = vec![0.0; h.width()];
            h.encode_one(x, &mut row);
            row.iter().zip(&g).map(|(a, b)| *a as f64 * *b as f64).sum()
        };
        let mut dx = [0.0f32; 3];
        h.backward(&x, &g, &mut dx);
        for i in 0..3 {
            let e = 1e-3;
            let (mut up, mut down) = (x, x);
            up[i] += e;
            down[i] -= e;
            let fd = (loss(&up) - loss(&down)) / (2.0 * e as f64);
            assert!(
                (dx[i] as f64 - fd).abs() < 1e-2 * (1.0 + fd.abs()),
                "{i}: {} vs {fd}",
                dx[i]
            );
        }
    }

    #[test]
    fn huge_inputs_stay_finite() {
        let h = Harmonic {
            dims: 3,
            freqs: 10,
            include_input: false,
        };
        let x = [1e30f32, -1e30, 0.0];
        let mut row = vec![0.0; h.width()];
        h.encode_one(&x, &mut row);
        assert!(row.iter().all(|v| v.is_finite() && v.abs() <= 1.0));
    }
}
