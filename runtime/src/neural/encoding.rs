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
