//! Multiresolution hash encoding (instant-ngp): per level a grid of
//! trainable feature vectors, trilinearly interpolated at a point; the
//! levels' features side by side are the encoding.
//!
//! * Points are normalised into `[0, 1]³` by the scene's box and clamped
//!   there (a point outside reads the box's nearest face; a NaN coordinate
//!   reads the min face), so any input gives finite features.
//! * Level `l` has resolution `N_l = ⌊N_min·b^l⌋`, `b = exp((ln N_max − ln
//!   N_min)/(L − 1))` (the floor forgives 1e-9 relative rounding, so the top
//!   level is `N_max` exactly), and `(N_l + 1)³` vertices. A level whose
//!   vertices fit the table (`(N_l+1)³ ≤ 2^T`) indexes them densely;
//!   others hash `(x·1 ⊕ y·2654435761 ⊕ z·805459861) mod 2^T`.
//! * Params are flat: level tables one after another, each `rows × F`
//!   floats with `rows = min(2^T, (N_l+1)³)`.
//! * The encoding is linear in the params. [`HashGrid::backward`] gives
//!   `∂loss/∂params` only (not `∂/∂points`), in parallel over levels (their
//!   tables are disjoint) and in point order within a level, so the sums
//!   are bit-identical whatever the thread count. It marks the rows it
//!   touched, for [`HashGrid::sparse_adam_update`].

use rayon::prelude::*;

use crate::volume::SplitMix64;

/// Largest parameter count accepted (1 GiB of f32).
pub const MAX_PARAMS: usize = 1 << 28;
const PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];
/// A level, the points, their output gradient, the level's gradient and bits.
type LevelArgs<'a> = (
    &'a Level,
    &'a [[f32; 3]],
    &'a [f32],
    &'a mut [f32],
    &'a mut [u64],
);
/// Points per parallel task of [`HashGrid::encode`].
const CHUNK: usize = 512;

/// The shape of a hash grid and the box it covers.
#[derive(Debug, Clone, PartialEq)]
pub struct HashGridConfig {
    /// L, number of levels.
    pub levels: u32,
    /// F, features per level.
    pub features: u32,
    /// T, log2 of the largest table's rows.
    pub log2_table: u32,
    /// N_min, resolution of the coarsest level.
    pub min_res: u32,
    /// N_max, resolution of the finest level.
    pub max_res: u32,
    /// The box's low corner; positions outside are clamped into it.
    pub bbox_min: [f32; 3],
    /// The box's high corner.
    pub bbox_max: [f32; 3],
}

impl Default for HashGridConfig {
    fn default() -> Self {
        HashGridConfig {
            levels: 16,
            features: 2,
            log2_table: 19,
            min_res: 16,
            max_res: 2048,
            bbox_min: [-1.0; 3],
            bbox_max: [1.0; 3],
        }
    }
}

#[derive(Debug, Clone)]
struct Level {
    res: u32,
    dense: bool,
    rows: usize,
    /// First float of the level's table.
    offset: usize,
}

/// A hash encoding: the layout only; params live with the caller.
#[derive(Debug, Clone)]
pub struct HashGrid {
    cfg: HashGridConfig,
    levels: Vec<Level>,
    params: usize,
    inv_extent: [f32; 3],
}

/// Which table rows a backward pass touched: one bit per row, each level's
/// bits starting on a fresh word so levels can be written in parallel.
#[derive(Debug, Clone)]
pub struct Touched {
    /// One bit per row, set where touched.
    #[doc(hidden)]
    pub bits: Vec<u64>,
    /// Per level its first word; one more entry at the end.
    words: Vec<usize>,
}

impl Touched {
    /// Forgets every touched row (after a step's update).
    pub fn clear(&mut self) {
        self.bits.iter_mut().for_each(|w| *w = 0);
    }
    /// Whether a step's forward pass read `row` of `level`.
    pub fn is_touched(&self, level: usize, row: usize) -> bool {
        self.bits[self.words[level] + row / 64] >> (row % 64) & 1 == 1
    }
    /// Number of touched rows over all levels.
    pub fn count(&self) -> usize {
        self.bits.iter().map(|w| w.count_ones() as usize).sum()
    }
    /// The touched rows of `level`, ascending.
    pub fn rows(&self, level: usize) -> impl Iterator<Item = usize> + '_ {
        let words = &self.bits[self.words[level]..self.words[level + 1]];
        set_bits(words)
    }
    /// Each level's first word (one more entry at the end) and the bits,
    /// for callers that mark rows themselves.
    pub(crate) fn words_mut(&mut self) -> (&[usize], &mut [u64]) {
        (&self.words, &mut self.bits)
    }
    fn split_mut(&mut self) -> Vec<&mut [u64]> {
        let mut rest = &mut self.bits[..];
        let mut out = Vec::with_capacity(self.words.len() - 1);
        for w in self.words.windows(2) {
            let (a, b) = std::mem::take(&mut rest).split_at_mut(w[1] - w[0]);
            out.push(a);
            rest = b;
        }
        out
    }
}

fn set_bits(words: &[u64]) -> impl Iterator<Item = usize> + '_ {
    words.iter().enumerate().flat_map(|(k, &w)| {
        let mut w = w;
        std::iter::from_fn(move || {
            (w != 0).then(|| {
                let b = w.trailing_zeros() as usize;
                w &= w - 1;
                k * 64 + b
            })
        })
    })
}

/// Adam's hyper-parameters for [`HashGrid::sparse_adam_update`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Adam {
    /// Learning rate.
    pub lr: f32,
    /// Decay of the first moment.
    pub beta1: f32,
    /// Decay of the second moment.
    pub beta2: f32,
    /// Added to the second moment's root, against division by zero.
    pub eps: f32,
}

impl Default for Adam {
    /// instant-ngp's settings for the encoding.
    fn default() -> Self {
        Adam {
            lr: 1e-2,
            beta1: 0.9,
            beta2: 0.99,
            eps: 1e-15,
        }
    }
}

impl HashGrid {
    /// The layout of `cfg`; refuses empty or absurd configurations (more
    /// than [`MAX_PARAMS`] params, resolutions beyond 2²⁰, an empty box).
    #[allow(
        clippy::needless_range_loop,
        reason = "one axis index over the box's two corners and the result"
    )]
    pub fn new(cfg: HashGridConfig) -> Result<Self, String> {
        let c = &cfg;
        if !(1..=64).contains(&c.levels) || !(1..=16).contains(&c.features) {
            return Err(format!(
                "hash grid: levels {} must be in 1..=64 and features {} in 1..=16",
                c.levels, c.features
            ));
        }
        if !(1..=30).contains(&c.log2_table) {
            return Err(format!(
                "hash grid: log2 table size {} must be in 1..=30",
                c.log2_table
            ));
        }
        if c.min_res < 1 || c.max_res < c.min_res || c.max_res > 1 << 20 {
            return Err(format!(
                "hash grid: resolutions need 1 ≤ min {} ≤ max {} ≤ 2^20",
                c.min_res, c.max_res
            ));
        }
        let mut inv_extent = [0f32; 3];
        for a in 0..3 {
            let (lo, hi) = (c.bbox_min[a], c.bbox_max[a]);
            let ext = hi - lo;
            if !(lo.is_finite() && hi.is_finite() && ext > 0.0 && ext.is_finite()) {
                return Err(format!(
                    "hash grid: box axis {a} is empty or not finite ({lo}..{hi})"
                ));
            }
            inv_extent[a] = 1.0 / ext;
        }
        let table = 1u64 << c.log2_table;
        let mut levels = Vec::with_capacity(c.levels as usize);
        let mut offset = 0usize;
        // The layout is the language's (it checks sizes with the same function).
        for (res, rows) in
            sdfl_stdlib::value::hash_grid_levels(c.levels, c.min_res, c.max_res, c.log2_table)
        {
            let verts = (res as u64 + 1).pow(3);
            let dense = verts <= table;
            let rows = rows as usize;
            levels.push(Level {
                res,
                dense,
                rows,
                offset,
            });
            offset += rows * c.features as usize;
            if offset > MAX_PARAMS {
                return Err(format!(
                    "hash grid: more than {MAX_PARAMS} params; lower the table size or levels"
                ));
            }
        }
        Ok(HashGrid {
            cfg,
            levels,
            params: offset,
            inv_extent,
        })
    }

    /// Its levels, features and box.
    pub fn config(&self) -> &HashGridConfig {
        &self.cfg
    }
    /// Trainable numbers in all tables.
    pub fn param_count(&self) -> usize {
        self.params
    }
    /// `L·F` features per point.
    pub fn output_dim(&self) -> usize {
        (self.cfg.levels * self.cfg.features) as usize
    }
    /// Resolution of each level.
    pub fn resolutions(&self) -> Vec<u32> {
        self.levels.iter().map(|l| l.res).collect()
    }
    /// Whether each level is indexed densely (else hashed).
    pub fn dense_levels(&self) -> Vec<bool> {
        self.levels.iter().map(|l| l.dense).collect()
    }
    /// Float offset of each level's table in the params.
    pub fn level_offsets(&self) -> Vec<usize> {
        self.levels.iter().map(|l| l.offset).collect()
    }

    /// Params drawn U(−1e-4, 1e-4) from `SplitMix64(seed)`, in layout order.
    pub fn init(&self, seed: u64) -> Vec<f32> {
        let mut rng = SplitMix64::new(seed);
        (0..self.params)
            .map(|_| (rng.next_f32() * 2.0 - 1.0) * 1e-4)
            .collect()
    }

    /// An empty set of touched rows sized for this grid.
    pub fn touched_set(&self) -> Touched {
        let mut words = Vec::with_capacity(self.levels.len() + 1);
        let mut w = 0;
        for l in &self.levels {
            words.push(w);
            w += l.rows.div_ceil(64);
        }
        words.push(w);
        Touched {
            bits: vec![0; w],
            words,
        }
    }

    #[inline(always)]
    #[allow(clippy::manual_clamp)]
    fn normalise(&self, p: [f32; 3]) -> [f32; 3] {
        // `max` then `min`, not `clamp`: `max` maps NaN to 0.
        std::array::from_fn(|a| {
            ((p[a] - self.cfg.bbox_min[a]) * self.inv_extent[a])
                .max(0.0)
                .min(1.0)
        })
    }

    /// Rows and trilinear weights of the 8 corners around normalised `u`.
    #[inline(always)]
    fn corners(level: &Level, u: [f32; 3]) -> ([u32; 8], [f32; 8]) {
        let res = level.res;
        let side = res + 1;
        // Per axis the two vertex coordinates already multiplied by the
        // axis' stride (dense) or prime (hashed), and their weights.
        let mul = if level.dense {
            [1, side, side * side]
        } else {
            PRIMES
        };
        let mut term = [[0u32; 2]; 3];
        let mut wt = [[0f32; 2]; 3];
        for a in 0..3 {
            let x = u[a] * res as f32;
            // u = 1 lands in the last cell with fraction 1.
            let i = (x as u32).min(res - 1);
            let frac = x - i as f32;
            term[a] = [i.wrapping_mul(mul[a]), (i + 1).wrapping_mul(mul[a])];
            wt[a] = [1.0 - frac, frac];
        }
        let mask = level.rows as u32 - 1;
        let mut rows = [0u32; 8];
        let mut weights = [0f32; 8];
        for c in 0..8 {
            let (x, y, z) = (c & 1, (c >> 1) & 1, c >> 2);
            rows[c] = if level.dense {
                term[0][x] + term[1][y] + term[2][z]
            } else {
                (term[0][x] ^ term[1][y] ^ term[2][z]) & mask
            };
            weights[c] = wt[0][x] * wt[1][y] * wt[2][z];
        }
        (rows, weights)
    }

    /// Rows and trilinear weights of the 8 corners of level `l` around
    /// point `p` (unnormalised): what [`Self::encode`] reads.
    #[inline(always)]
    pub(crate) fn corners_at(&self, l: usize, p: [f32; 3]) -> ([u32; 8], [f32; 8]) {
        Self::corners(&self.levels[l], self.normalise(p))
    }

    /// As [`Self::corners_at`], with each weight's derivative by `p`. An
    /// axis clamped to the box (outside it, or NaN) has derivative 0; on
    /// the box's faces and at interior cell faces the derivative is the
    /// one-sided one of the cell the point is assigned to (always finite).
    #[inline(always)]
    #[allow(
        clippy::type_complexity,
        clippy::needless_range_loop,
        reason = "rows, weights and their gradients per corner; one axis index"
    )]
    pub(crate) fn corners_dx(&self, l: usize, p: [f32; 3]) -> ([u32; 8], [f32; 8], [[f32; 3]; 8]) {
        let level = &self.levels[l];
        let u = self.normalise(p);
        let (rows, weights) = Self::corners(level, u);
        let res = level.res;
        let mut wt = [[0f32; 2]; 3];
        let mut slope = [0f32; 3];
        for a in 0..3 {
            let x = u[a] * res as f32;
            let i = (x as u32).min(res - 1);
            let frac = x - i as f32;
            wt[a] = [1.0 - frac, frac];
            let raw = (p[a] - self.cfg.bbox_min[a]) * self.inv_extent[a];
            if (0.0..=1.0).contains(&raw) {
                slope[a] = res as f32 * self.inv_extent[a];
            }
        }
        let mut dw = [[0f32; 3]; 8];
        for c in 0..8 {
            let bit = [c & 1, (c >> 1) & 1, c >> 2];
            for a in 0..3 {
                let (b0, b1) = ((a + 1) % 3, (a + 2) % 3);
                let sign = if bit[a] == 1 { 1.0 } else { -1.0 };
                dw[c][a] = sign * slope[a] * wt[b0][bit[b0]] * wt[b1][bit[b1]];
            }
        }
        (rows, weights, dw)
    }

    fn check(&self, what: &str, got: usize, want: usize) {
        assert!(
            got == want,
            "hash grid {what}: {got} values where {want} are needed"
        );
    }

    /// Encodes `points` into `out` (`output_dim` per point, level-major).
    /// Panics when the slice sizes disagree (a caller bug, not user input).
    pub fn encode(&self, params: &[f32], points: &[[f32; 3]], out: &mut [f32]) {
        let dim = self.output_dim();
        self.check("params", params.len(), self.params);
        self.check("output", out.len(), points.len() * dim);
        out.par_chunks_mut(CHUNK * dim)
            .zip(points.par_chunks(CHUNK))
            .for_each(|(out, pts)| match self.cfg.features {
                // Constant feature counts unroll the inner loops.
                1 => self.encode_chunk(params, pts, out, 1),
                2 => self.encode_chunk(params, pts, out, 2),
                4 => self.encode_chunk(params, pts, out, 4),
                8 => self.encode_chunk(params, pts, out, 8),
                f => self.encode_chunk(params, pts, out, f as usize),
            });
    }

    /// One chunk of points, each through every level.
    #[inline(always)]
    fn encode_chunk(&self, params: &[f32], pts: &[[f32; 3]], out: &mut [f32], f: usize) {
        let dim = self.levels.len() * f;
        for (o, &p) in out.chunks_exact_mut(dim).zip(pts) {
            let u = self.normalise(p);
            for (level, o) in self.levels.iter().zip(o.chunks_exact_mut(f)) {
                let table = &params[level.offset..][..level.rows * f];
                let (rows, w) = Self::corners(level, u);
                let mut acc = [0f32; 16];
                for c in 0..8 {
                    let row = &table[rows[c] as usize * f..][..f];
                    for k in 0..f {
                        acc[k] += w[c] * row[k];
                    }
                }
                o.copy_from_slice(&acc[..f]);
            }
        }
    }

    /// Adds `∂loss/∂params` to `grad`, given `d_out = ∂loss/∂encode(points)`,
    /// and marks the rows it wrote in `touched` (which it does not clear).
    /// Panics when the slice sizes disagree.
    pub fn backward(
        &self,
        points: &[[f32; 3]],
        d_out: &[f32],
        grad: &mut [f32],
        touched: &mut Touched,
    ) {
        let dim = self.output_dim();
        self.check("gradient", grad.len(), self.params);
        self.check("output gradient", d_out.len(), points.len() * dim);
        self.check("touched set", touched.words.len(), self.levels.len() + 1);
        let grads = self.split_levels(grad);
        let bits = touched.split_mut();
        self.levels
            .par_iter()
            .zip(grads)
            .zip(bits)
            .enumerate()
            .for_each(|(l, ((level, g), bits))| {
                let args = (level, points, d_out, g, bits);
                match self.cfg.features {
                    1 => self.backward_level(l, args, 1),
                    2 => self.backward_level(l, args, 2),
                    4 => self.backward_level(l, args, 4),
                    8 => self.backward_level(l, args, 8),
                    f => self.backward_level(l, args, f as usize),
                }
            });
    }

    /// One level's share of [`Self::backward`], points in order.
    #[inline(always)]
    fn backward_level(&self, l: usize, args: LevelArgs, f: usize) {
        let (level, points, d_out, g, bits) = args;
        let dim = self.levels.len() * f;
        for (p, d) in points.iter().zip(d_out.chunks_exact(dim)) {
            let d = &d[l * f..][..f];
            let (rows, w) = Self::corners(level, self.normalise(*p));
            for c in 0..8 {
                let r = rows[c] as usize;
                bits[r / 64] |= 1 << (r % 64);
                let g = &mut g[r * f..][..f];
                for k in 0..f {
                    g[k] += w[c] * d[k];
                }
            }
        }
    }

    fn split_levels<'a>(&self, mut rest: &'a mut [f32]) -> Vec<&'a mut [f32]> {
        let f = self.cfg.features as usize;
        let mut out = Vec::with_capacity(self.levels.len());
        for level in &self.levels {
            let (a, b) = std::mem::take(&mut rest).split_at_mut(level.rows * f);
            out.push(a);
            rest = b;
        }
        out
    }

    /// One Adam step (`step ≥ 1`, bias-corrected) on the touched rows only,
    /// then clears their gradient and `touched`, ready for the next
    /// backward. Untouched rows keep their params *and* moments (no decay
    /// while unseen; instant-ngp's optimiser likewise skips entries without
    /// gradient), and the work is O(touched rows). A touched row whose
    /// gradient summed to 0 still takes a step (its moments decay).
    #[allow(clippy::too_many_arguments)] // the optimiser state is what it is
    pub fn sparse_adam_update(
        &self,
        params: &mut [f32],
        grad: &mut [f32],
        m: &mut [f32],
        v: &mut [f32],
        touched: &mut Touched,
        step: u64,
        adam: Adam,
    ) -> Result<(), String> {
        let n = self.params;
        if params.len() != n || grad.len() != n || m.len() != n || v.len() != n {
            return Err(format!(
                "sparse Adam: params, gradient and moments need {n} values"
            ));
        }
        if step == 0 || touched.words.len() != self.levels.len() + 1 {
            return Err("sparse Adam: steps count from 1, touched set of another grid".into());
        }
        let f = self.cfg.features as usize;
        let bc1 = 1.0 - (adam.beta1 as f64).powf(step as f64);
        let bc2 = 1.0 - (adam.beta2 as f64).powf(step as f64);
        let (lr_t, sqrt_bc2) = ((adam.lr as f64 / bc1) as f32, bc2.sqrt() as f32);
        let parts = self
            .split_levels(params)
            .into_iter()
            .zip(self.split_levels(grad))
            .zip(self.split_levels(m))
            .zip(self.split_levels(v))
            .zip(touched.split_mut());
        parts
            .collect::<Vec<_>>()
            .into_par_iter()
            .for_each(|((((p, g), m), v), bits)| {
                for r in set_bits(bits) {
                    for k in r * f..(r + 1) * f {
                        let gk = g[k];
                        m[k] = adam.beta1 * m[k] + (1.0 - adam.beta1) * gk;
                        v[k] = adam.beta2 * v[k] + (1.0 - adam.beta2) * gk * gk;
                        p[k] -= lr_t * m[k] / (v[k].sqrt() / sqrt_bc2 + adam.eps);
                        g[k] = 0.0;
                    }
                }
                bits.iter_mut().for_each(|w| *w = 0);
            });
        Ok(())
    }
}
