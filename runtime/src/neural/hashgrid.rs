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
    pub bbox_min: [f32; 3],
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
    bits: Vec<u64>,
    /// Per level its first word; one more entry at the end.
    words: Vec<usize>,
}

impl Touched {
    pub fn clear(&mut self) {
        self.bits.iter_mut().for_each(|w| *w = 0);
    }
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
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
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

    pub fn config(&self) -> &HashGridConfig {
        &self.cfg
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn small(levels: u32, log2_table: u32, min_res: u32, max_res: u32) -> HashGrid {
        HashGrid::new(HashGridConfig {
            levels,
            features: 2,
            log2_table,
            min_res,
            max_res,
            bbox_min: [-1.0, 0.0, 2.0],
            bbox_max: [1.0, 4.0, 3.0],
        })
        .unwrap()
    }

    fn random_params(g: &HashGrid, seed: u64) -> Vec<f32> {
        let mut rng = SplitMix64::new(seed);
        (0..g.param_count())
            .map(|_| rng.next_f32() * 2.0 - 1.0)
            .collect()
    }

    fn random_points(n: usize, seed: u64, spill: f32) -> Vec<[f32; 3]> {
        let mut rng = SplitMix64::new(seed);
        let (lo, hi) = ([-1.0f32, 0.0, 2.0], [1.0f32, 4.0, 3.0]);
        (0..n)
            .map(|_| {
                std::array::from_fn(|a| {
                    let u = rng.next_f32() * (1.0 + 2.0 * spill) - spill;
                    lo[a] + u * (hi[a] - lo[a])
                })
            })
            .collect()
    }

    /// The encoding in f64, written from the definition.
    fn reference(g: &HashGrid, params: &[f64], p: [f32; 3]) -> Vec<f64> {
        let c = g.config();
        let f = c.features as usize;
        let mut out = Vec::new();
        for (l, &res) in g.resolutions().iter().enumerate() {
            let res64 = res as u64;
            let dense = (res64 + 1).pow(3) <= 1 << c.log2_table;
            let rows = if dense {
                (res64 + 1).pow(3)
            } else {
                1 << c.log2_table
            };
            let x: Vec<f64> = (0..3)
                .map(|a| {
                    let u = (p[a] as f64 - c.bbox_min[a] as f64)
                        / (c.bbox_max[a] as f64 - c.bbox_min[a] as f64);
                    u.clamp(0.0, 1.0) * res as f64
                })
                .collect();
            let base: Vec<u64> = x
                .iter()
                .map(|&v| (v.floor() as u64).min(res64 - 1))
                .collect();
            let mut feat = vec![0f64; f];
            for dz in 0..2u64 {
                for dy in 0..2u64 {
                    for dx in 0..2u64 {
                        let v = [base[0] + dx, base[1] + dy, base[2] + dz];
                        let row = if dense {
                            v[0] + (res64 + 1) * v[1] + (res64 + 1) * (res64 + 1) * v[2]
                        } else {
                            (v[0] ^ (v[1] * 2_654_435_761) ^ (v[2] * 805_459_861)) % rows
                        };
                        let mut w = 1.0;
                        for (a, d) in [dx, dy, dz].into_iter().enumerate() {
                            let t = x[a] - base[a] as f64;
                            w *= if d == 1 { t } else { 1.0 - t };
                        }
                        let at = g.level_offsets()[l] + row as usize * f;
                        for k in 0..f {
                            feat[k] += w * params[at + k];
                        }
                    }
                }
            }
            out.extend(feat);
        }
        out
    }

    #[test]
    fn layout_follows_the_config() {
        let g = HashGrid::new(HashGridConfig::default()).unwrap();
        let res = g.resolutions();
        assert_eq!(res[0], 16);
        assert_eq!(res[15], 2048);
        assert!(res.windows(2).all(|r| r[0] < r[1]));
        // (N+1)³ ≤ 2^19 holds up to N = 79.
        let dense = g.dense_levels();
        for (r, d) in res.iter().zip(&dense) {
            assert_eq!(*d, (*r as u64 + 1).pow(3) <= 1 << 19);
        }
        assert_eq!(g.output_dim(), 32);
        let rows: usize = res
            .iter()
            .map(|&r| ((r as usize + 1).pow(3)).min(1 << 19))
            .sum();
        assert_eq!(g.param_count(), rows * 2);
        let p = g.init(3);
        assert_eq!(p.len(), g.param_count());
        assert!(p.iter().all(|v| v.abs() <= 1e-4));
        assert_eq!(p, g.init(3));
        assert_ne!(p, g.init(4));
        let bad = |f: &dyn Fn(&mut HashGridConfig)| {
            let mut c = HashGridConfig::default();
            f(&mut c);
            HashGrid::new(c).is_err()
        };
        assert!(bad(&|c| c.levels = 0));
        assert!(bad(&|c| c.features = 0));
        assert!(bad(&|c| c.log2_table = 40));
        assert!(bad(&|c| c.min_res = 0));
        assert!(bad(&|c| c.max_res = 8));
        assert!(bad(&|c| c.bbox_max[1] = -1.0));
        assert!(bad(&|c| c.bbox_min[2] = f32::NAN));
        assert!(bad(&|c| {
            c.levels = 64;
            c.features = 16;
            c.log2_table = 24;
        }));
        // One level: N_min only.
        assert_eq!(small(1, 10, 5, 9).resolutions(), vec![5]);
    }

    #[test]
    fn vertices_read_their_own_features() {
        // Level 0 dense (5³ rows), level 2 hashed (2^8 rows < 17³).
        let g = small(3, 8, 4, 16);
        assert_eq!(g.dense_levels(), vec![true, false, false]);
        let params = random_params(&g, 1);
        let off = g.level_offsets();
        let (lo, hi) = ([-1.0f32, 0.0, 2.0], [1.0f32, 4.0, 3.0]);
        let mut out = vec![0f32; 6];
        for v in [[0u32, 0, 0], [4, 4, 4], [1, 3, 2], [4, 0, 3]] {
            let p: [f32; 3] = std::array::from_fn(|a| lo[a] + (hi[a] - lo[a]) * v[a] as f32 / 4.0);
            g.encode(&params, &[p], &mut out);
            let row = (v[0] + 5 * v[1] + 25 * v[2]) as usize;
            assert_eq!(out[..2], params[off[0] + 2 * row..][..2], "{v:?}");
            // Level 2 (N = 16): vertex 4v, hashed.
            let w = v.map(|c| c * 4);
            let h =
                (w[0] ^ w[1].wrapping_mul(2_654_435_761) ^ w[2].wrapping_mul(805_459_861)) % 256;
            assert_eq!(out[4..], params[off[2] + 2 * h as usize..][..2], "{v:?}");
        }
    }

    #[test]
    fn matches_f64_reference_and_is_continuous() {
        let g = small(6, 12, 3, 40);
        let params = random_params(&g, 2);
        let p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
        let pts = random_points(300, 3, 0.1);
        let dim = g.output_dim();
        let mut out = vec![0f32; pts.len() * dim];
        g.encode(&params, &pts, &mut out);
        for (p, o) in pts.iter().zip(out.chunks(dim)) {
            let want = reference(&g, &p64, *p);
            for k in 0..dim {
                assert!((o[k] as f64 - want[k]).abs() < 1e-5, "{p:?} {k}");
            }
        }
        // Every feature count (1, 2, 4, 8 take unrolled paths), forward and
        // backward: the gradient of Σ c·out is Σ c·(trilinear weight), which
        // the reference gives as the encoding of one-hot params.
        for features in [1, 3, 4, 8, 16] {
            let g = HashGrid::new(HashGridConfig {
                features,
                ..g.config().clone()
            })
            .unwrap();
            let params = random_params(&g, features as u64);
            let p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
            let dim = g.output_dim();
            let pts = &pts[..20];
            let mut out = vec![0f32; pts.len() * dim];
            g.encode(&params, pts, &mut out);
            for (p, o) in pts.iter().zip(out.chunks(dim)) {
                let want = reference(&g, &p64, *p);
                for k in 0..dim {
                    assert!((o[k] as f64 - want[k]).abs() < 1e-5, "F={features} {k}");
                }
            }
            let c: Vec<f32> = (0..out.len()).map(|k| (k % 7) as f32 - 3.0).collect();
            let mut grad = vec![0f32; g.param_count()];
            let mut touched = g.touched_set();
            g.backward(pts, &c, &mut grad, &mut touched);
            // Touched entries of every level, and a few others (gradient 0).
            let f = features as usize;
            let mut entries: Vec<usize> = (0..6)
                .flat_map(|l| {
                    let off = g.level_offsets()[l];
                    let rows: Vec<usize> = touched.rows(l).step_by(5).collect();
                    rows.into_iter().map(move |r| off + r * f + r % f)
                })
                .collect();
            entries.extend([0, g.param_count() / 2, g.param_count() - 1]);
            for j in entries {
                let mut onehot = vec![0f64; g.param_count()];
                onehot[j] = 1.0;
                let want: f64 = pts
                    .iter()
                    .enumerate()
                    .map(|(i, &p)| {
                        let e = reference(&g, &onehot, p);
                        (0..dim).map(|k| c[i * dim + k] as f64 * e[k]).sum::<f64>()
                    })
                    .sum();
                assert!((grad[j] as f64 - want).abs() < 1e-5, "F={features} {j}");
            }
        }
        // Across a cell face of each level: values on either side of it
        // approach each other (|∂/∂x| ≤ 2·N/extent·max|param| ≤ 40 here).
        let mut a = vec![0f32; dim];
        let mut b = vec![0f32; dim];
        for &res in &g.resolutions() {
            let x = -1.0 + 2.0 * (res / 2) as f32 / res as f32;
            let e = 1e-4;
            g.encode(&params, &[[x - e, 1.3, 2.7]], &mut a);
            g.encode(&params, &[[x + e, 1.3, 2.7]], &mut b);
            for k in 0..dim {
                assert!((a[k] - b[k]).abs() < 2.0 * e * 40.0 + 1e-6, "{x} {k}");
            }
        }
    }

    #[test]
    fn points_outside_read_the_nearest_face() {
        let g = small(4, 10, 2, 20);
        let params = random_params(&g, 4);
        let dim = g.output_dim();
        let mut a = vec![0f32; dim];
        let mut b = vec![0f32; dim];
        let pairs = [
            ([-5.0, 2.0, 2.5], [-1.0, 2.0, 2.5]),
            ([0.3, 1e30, 1.0], [0.3, 4.0, 2.0]),
            ([f32::INFINITY, -f32::INFINITY, 9.0], [1.0, 0.0, 3.0]),
            ([f32::NAN, 1.0, 2.5], [-1.0, 1.0, 2.5]),
        ];
        for (out, clamped) in pairs {
            g.encode(&params, &[out], &mut a);
            g.encode(&params, &[clamped], &mut b);
            assert_eq!(a, b, "{out:?}");
            assert!(a.iter().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let g = small(5, 9, 2, 24);
        let params = random_params(&g, 5);
        let pts = random_points(40, 6, 0.05);
        let dim = g.output_dim();
        let mut rng = SplitMix64::new(7);
        let c: Vec<f32> = (0..pts.len() * dim)
            .map(|_| rng.next_f32() * 2.0 - 1.0)
            .collect();
        let mut grad = vec![0f32; g.param_count()];
        let mut touched = g.touched_set();
        g.backward(&pts, &c, &mut grad, &mut touched);
        // loss(θ) = Σ c·encode(θ), in f64 through the reference.
        let loss = |p: &[f64]| -> f64 {
            pts.iter()
                .enumerate()
                .map(|(i, &x)| {
                    let e = reference(&g, p, x);
                    (0..dim).map(|k| c[i * dim + k] as f64 * e[k]).sum::<f64>()
                })
                .sum()
        };
        let mut p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
        let f = 2;
        let offs = g.level_offsets();
        let mut checked = 0;
        for j in (0..g.param_count()).step_by(7) {
            let l = offs.iter().rposition(|&o| o <= j).unwrap();
            let row = (j - offs[l]) / f;
            if !touched.is_touched(l, row) {
                assert_eq!(grad[j], 0.0);
                continue;
            }
            let h = 1e-3;
            p64[j] += h;
            let up = loss(&p64);
            p64[j] -= 2.0 * h;
            let down = loss(&p64);
            p64[j] += h;
            let fd = (up - down) / (2.0 * h);
            assert!((grad[j] as f64 - fd).abs() < 1e-4 * (1.0 + fd.abs()), "{j}");
            checked += 1;
        }
        assert!(checked > 20, "{checked}");
        // The same in f32 through encode itself, for a few touched entries.
        let mut out = vec![0f32; pts.len() * dim];
        let f32_loss = |p: &[f32], out: &mut Vec<f32>| -> f64 {
            g.encode(p, &pts, out);
            out.iter().zip(&c).map(|(&a, &b)| a as f64 * b as f64).sum()
        };
        let mut p = params.clone();
        for l in 0..5 {
            for row in touched.rows(l).take(3) {
                let j = offs[l] + row * f;
                let h = 1e-2;
                p[j] += h;
                let up = f32_loss(&p, &mut out);
                p[j] -= 2.0 * h;
                let down = f32_loss(&p, &mut out);
                p[j] = params[j];
                let fd = (up - down) / (2.0 * h as f64);
                assert!((grad[j] as f64 - fd).abs() < 2e-3 * (1.0 + fd.abs()), "{j}");
            }
        }
        // A second backward accumulates.
        let mut twice = grad.clone();
        g.backward(&pts, &c, &mut twice, &mut touched);
        for (a, b) in twice.iter().zip(&grad) {
            assert!((a - 2.0 * b).abs() <= 1e-6 * b.abs().max(1.0));
        }
    }

    #[test]
    fn backward_is_bit_identical_across_thread_counts() {
        let g = small(8, 10, 4, 64);
        let pts = random_points(5000, 8, 0.0);
        let mut rng = SplitMix64::new(9);
        let d: Vec<f32> = (0..pts.len() * g.output_dim())
            .map(|_| rng.next_f32() - 0.5)
            .collect();
        let params = random_params(&g, 1);
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut grad = vec![0f32; g.param_count()];
            let mut t = g.touched_set();
            let mut out = vec![0f32; d.len()];
            pool.install(|| {
                g.backward(&pts, &d, &mut grad, &mut t);
                g.encode(&params, &pts, &mut out);
            });
            (
                grad.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                t.bits,
                out,
            )
        };
        let one = run(1);
        assert!(one == run(2));
        assert!(one == run(5));
    }

    #[test]
    fn sparse_adam_updates_only_touched_rows() {
        let g = small(3, 8, 2, 12);
        let mut params = random_params(&g, 2);
        let before = params.clone();
        let n = g.param_count();
        let mut grad = vec![0f32; n];
        let mut m = vec![0.5f32; n];
        let mut v = vec![0.25f32; n];
        let mut touched = g.touched_set();
        let pts = random_points(10, 3, 0.0);
        let d = vec![1.0f32; pts.len() * g.output_dim()];
        g.backward(&pts, &d, &mut grad, &mut touched);
        let g0 = grad.clone();
        let rows = touched.clone();
        let adam = Adam {
            lr: 0.1,
            beta1: 0.9,
            beta2: 0.99,
            eps: 1e-8,
        };
        let step = 3;
        g.sparse_adam_update(
            &mut params,
            &mut grad,
            &mut m,
            &mut v,
            &mut touched,
            step,
            adam,
        )
        .unwrap();
        assert_eq!(touched.count(), 0);
        assert!(grad.iter().all(|&x| x == 0.0));
        let offs = g.level_offsets();
        for j in 0..n {
            let l = offs.iter().rposition(|&o| o <= j).unwrap();
            if rows.is_touched(l, (j - offs[l]) / 2) {
                // Adam in f64 from its definition.
                let gj = g0[j] as f64;
                let mj = 0.9 * 0.5 + 0.1 * gj;
                let vj = 0.99 * 0.25 + 0.01 * gj * gj;
                let mh = mj / (1.0 - 0.9f64.powi(3));
                let vh = vj / (1.0 - 0.99f64.powi(3));
                let want = before[j] as f64 - 0.1 * mh / (vh.sqrt() + 1e-8);
                assert!((params[j] as f64 - want).abs() < 1e-5, "{j}");
                assert!((m[j] as f64 - mj).abs() < 1e-6);
            } else {
                assert_eq!((params[j], m[j], v[j]), (before[j], 0.5, 0.25));
            }
        }
        let mut short = vec![0f32; n - 1];
        assert!(g
            .sparse_adam_update(&mut short, &mut grad, &mut m, &mut v, &mut touched, 1, adam)
            .is_err());
        assert!(g
            .sparse_adam_update(
                &mut params,
                &mut grad,
                &mut m,
                &mut v,
                &mut touched,
                0,
                adam
            )
            .is_err());
    }

    #[test]
    fn throughput() {
        let g = HashGrid::new(HashGridConfig::default()).unwrap();
        let params = g.init(1);
        // Unoptimised builds time a smaller batch, so `cargo test` stays quick.
        let n = if cfg!(debug_assertions) { 4096 } else { 65536 };
        let pts = random_points(n, 1, 0.0);
        let mut out = vec![0f32; pts.len() * g.output_dim()];
        let mut grad = vec![0f32; g.param_count()];
        let mut touched = g.touched_set();
        // Best of several runs: the machine is shared, the minimum is the
        // least disturbed.
        let best = |f: &mut dyn FnMut()| {
            (0..if cfg!(debug_assertions) { 1 } else { 7 })
                .map(|_| {
                    let t = std::time::Instant::now();
                    f();
                    t.elapsed().as_secs_f64()
                })
                .fold(f64::INFINITY, f64::min)
        };
        let enc = best(&mut || g.encode(&params, &pts, &mut out));
        let back = best(&mut || g.backward(&pts, &out, &mut grad, &mut touched));
        let mut m = vec![1e-3f32; g.param_count()];
        let mut v = vec![1e-3f32; g.param_count()];
        let mut p = params.clone();
        let touched_rows = touched.count();
        let t = std::time::Instant::now();
        g.sparse_adam_update(
            &mut p,
            &mut grad,
            &mut m,
            &mut v,
            &mut touched,
            1,
            Adam::default(),
        )
        .unwrap();
        let adam = t.elapsed().as_secs_f64();
        println!(
            "hash grid (L=16, F=2, T=19, 16..2048), {n} points, {} threads: encode {:.2} M points/s, backward {:.2} M points/s, sparse Adam {:.1} ms ({touched_rows} rows)",
            rayon::current_num_threads(),
            n as f64 / enc / 1e6,
            n as f64 / back / 1e6,
            adam * 1e3
        );
    }
}
