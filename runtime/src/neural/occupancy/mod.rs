//! Occupancy grid (instant-ngp / nerfacc): a coarse `R³` grid over the
//! scene's box remembering where density was seen, so the fixed-step
//! sampler skips empty space.
//!
//! * Each cell holds an EMA of density; it is occupied when
//!   `ema · step_size > threshold`: the opacity one sample of the renderer's
//!   step would roughly get (`1 − e^{−σδ} ≈ σδ`) exceeds `threshold` (0.01),
//!   or the mean cell's opacity where that is lower (instant-ngp's rule: a
//!   grid never empties every cell of a field that is still uniform).
//! * Cells are half-open, `[min + i·h, min + (i+1)·h)` per axis, so a point
//!   belongs to exactly one cell; the box's max faces are outside.
//! * Until the first [`OccupancyGrid::update`] every cell is occupied.
//!   Refreshes during warm-up decay the EMA by [`WARMUP_DECAY`] rather
//!   than `decay`: the untrained network's density is about uniform, and
//!   kept with a decay of 0.95 it held every cell of Lego's box occupied
//!   for 11 refreshes.
//! * [`OccupancyGrid::march`] emits exactly the fixed-step samples
//!   `t_k = near + (k + ½)·step` ([`fixed_step`]) whose point (computed in
//!   f32) lies in an occupied cell ([`OccupancyGrid::cell_of`]); runs of
//!   samples in an empty cell are skipped by jumping to the cell's exit, less
//!   a slack that covers f32 rounding. So with every cell occupied it gives
//!   the plain sampler's samples inside the box, bit for bit. Empty 8³
//!   blocks are skipped whole the same way.
//! * [`OccupancyGrid::march_rays`] marches a batch in parallel into
//!   [`RaySamples`] (offsets per ray), identical for any thread count.

use rayon::prelude::*;

use crate::volume::{Ray, SplitMix64, VolumeError};

/// Most fixed-step samples a ray may have between near and far.
pub const MAX_SAMPLES: usize = 1 << 20;
/// Cells per side of a block.
const BLOCK: u32 = 8;
/// The EMA's decay per refresh before `warmup`: the network is changing
/// fastest then, so an untrained network's density is forgotten after a
/// refresh or two, while a cell seen dense at one jitter point stays
/// occupied for a few refreshes of others.
pub const WARMUP_DECAY: f32 = 0.5;
/// Points per call of the density function in [`OccupancyGrid::update`].
const UPDATE_CHUNK: usize = 1 << 16;

/// An occupancy grid's shape and update rule.
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyConfig {
    /// R, cells per axis (≤ 512).
    pub res: u32,
    /// The grid's low corner.
    pub bbox_min: [f32; 3],
    /// The grid's high corner.
    pub bbox_max: [f32; 3],
    /// Occupied when `ema · step_size > threshold` (capped at the mean
    /// cell's: [`OccupancyGrid::update`]).
    pub threshold: f32,
    /// The renderer's step, which makes the threshold an opacity.
    pub step_size: f32,
    /// EMA decay per update of a cell.
    pub decay: f32,
    /// Updates before `step = warmup` evaluate every cell; later ones only the
    /// cells with `index ≡ step / every (mod subsets)` (and decay only
    /// those), which spreads the cost. `subsets = 1`: every cell every
    /// update.
    pub warmup: u64,
    /// Cells are refreshed one subset in `subsets` per update after warm-up.
    pub subsets: u32,
    /// Steps between updates (≥ 1), so that consecutive updates take
    /// consecutive subsets: with `step` alone, updates every 16 steps took
    /// the same quarter of the cells forever.
    pub every: u64,
}

impl OccupancyConfig {
    /// Defaults over a box: R = 128, threshold 0.01, decay 0.95, the step
    /// instant-ngp uses (`√3·extent/1024`), every cell every update.
    pub fn new(bbox_min: [f32; 3], bbox_max: [f32; 3]) -> Self {
        let ext = (0..3)
            .map(|a| bbox_max[a] - bbox_min[a])
            .fold(0.0f32, f32::max);
        OccupancyConfig {
            res: 128,
            bbox_min,
            bbox_max,
            threshold: 0.01,
            step_size: 3f32.sqrt() * ext / 1024.0,
            decay: 0.95,
            warmup: 256,
            subsets: 1,
            every: 1,
        }
    }
}

/// Samples of many rays: ray `r`'s depths are `t[offsets[r]..offsets[r + 1]]`,
/// each with its interval in `dt`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RaySamples {
    /// Ray `r`'s samples are `offsets[r]..offsets[r + 1]` (one entry more than rays).
    pub offsets: Vec<usize>,
    /// Sample depths along each ray.
    pub t: Vec<f32>,
    /// Each sample's interval.
    pub dt: Vec<f32>,
}

/// Densities at points, written into the second slice (one per point).
pub type DensityFn<'a> = dyn FnMut(&[[f32; 3]], &mut [f32]) + 'a;

/// Rays per parallel task of [`OccupancyGrid::march_rays`].
const RAY_CHUNK: usize = 256;

/// The grid: EMA per cell and the occupied bits derived from it.
#[derive(Debug, Clone)]
pub struct OccupancyGrid {
    /// The grid's box, resolution and update settings.
    #[doc(hidden)]
    pub cfg: OccupancyConfig,
    enabled: bool,
    ema: Vec<f32>,
    bits: Vec<u64>,
    /// Occupied cells per block of `BLOCK³` cells: march skips an empty
    /// block at once instead of cell by cell.
    #[doc(hidden)]
    pub blocks: Vec<u32>,
    /// `R / extent` per axis (f32: the cell test), cell size in f64 (exits).
    scale: [f32; 3],
    cell: [f64; 3],
    points: Vec<[f32; 3]>,
    density: Vec<f32>,
    /// Whether every cell has been evaluated (or restored) once: until
    /// then an update evaluates them all, so no cell is emptied unseen.
    refreshed: bool,
}

/// The plain fixed-step sampler: `t_k = near + (k + ½)·step` (in f32, this
/// exact expression) for every `k` with `t_k < far`, each with interval
/// `step`. Appends to `t` and `dt` after clearing them.
pub fn fixed_step(
    near: f32,
    far: f32,
    step: f32,
    t: &mut Vec<f32>,
    dt: &mut Vec<f32>,
) -> Result<(), VolumeError> {
    let count = check_range(near, far, step)?;
    t.clear();
    dt.clear();
    for k in 0..count {
        let tk = sample_t(near, step, k);
        if tk >= far {
            break;
        }
        t.push(tk);
        dt.push(step);
    }
    Ok(())
}

#[inline(always)]
fn sample_t(near: f32, step: f32, k: usize) -> f32 {
    near + (k as f32 + 0.5) * step
}

/// An upper bound on the samples of `[near, far)`, or an error for a bad range.
fn check_range(near: f32, far: f32, step: f32) -> Result<usize, VolumeError> {
    if !(near.is_finite() && far.is_finite() && near <= far && step > 0.0 && step.is_finite()) {
        return Err(VolumeError::Invalid(format!(
            "fixed-step sampling needs finite near ≤ far and step > 0 (got {near}, {far}, {step})"
        )));
    }
    let n = ((far as f64 - near as f64) / step as f64).ceil() + 2.0;
    if n > MAX_SAMPLES as f64 {
        return Err(VolumeError::Invalid(format!(
            "fixed-step sampling: more than {MAX_SAMPLES} samples per ray (step {step})"
        )));
    }
    Ok(n as usize)
}

impl OccupancyGrid {
    /// An enabled grid with every cell occupied.
    pub fn new(cfg: OccupancyConfig) -> Result<Self, String> {
        if !(1..=512).contains(&cfg.res) {
            return Err(format!(
                "occupancy grid: resolution {} not in 1..=512",
                cfg.res
            ));
        }
        let ok = |v: f32| v.is_finite() && v >= 0.0;
        if !(ok(cfg.threshold) && ok(cfg.step_size) && (0.0..=1.0).contains(&cfg.decay))
            || cfg.subsets == 0
            || cfg.every == 0
        {
            return Err(
                "occupancy grid: threshold, step size ≥ 0, decay in [0, 1], subsets and every ≥ 1"
                    .into(),
            );
        }
        let mut scale = [0f32; 3];
        let mut cell = [0f64; 3];
        for a in 0..3 {
            let (lo, hi) = (cfg.bbox_min[a], cfg.bbox_max[a]);
            let ext = hi - lo;
            if !(lo.is_finite() && hi.is_finite() && ext > 0.0 && ext.is_finite()) {
                return Err(format!(
                    "occupancy grid: box axis {a} is empty or not finite"
                ));
            }
            scale[a] = cfg.res as f32 / ext;
            cell[a] = (hi as f64 - lo as f64) / cfg.res as f64;
        }
        let cells = (cfg.res as usize).pow(3);
        let mut grid = OccupancyGrid {
            enabled: true,
            ema: vec![0.0; cells],
            bits: vec![0; cells.div_ceil(64)],
            blocks: vec![0; (cfg.res.div_ceil(BLOCK) as usize).pow(3)],
            scale,
            cell,
            cfg,
            points: Vec::new(),
            density: Vec::new(),
            refreshed: false,
        };
        grid.fill(true);
        Ok(grid)
    }

    /// Its resolution, box and thresholds.
    pub fn config(&self) -> &OccupancyConfig {
        &self.cfg
    }
    /// A disabled grid skips nothing: [`Self::march`] is [`fixed_step`].
    pub fn set_enabled(&mut self, on: bool) {
        self.enabled = on;
    }
    /// Whether it skips empty cells (else it samples at every step).
    pub fn is_enabled(&self) -> bool {
        self.enabled
    }
    /// Cells in the grid (`res³`).
    pub fn cells(&self) -> usize {
        self.ema.len()
    }
    /// Each cell's decaying maximum of density.
    pub fn ema(&self) -> &[f32] {
        &self.ema
    }
    /// Cell index `x + R·(y + R·z)`.
    pub fn index(&self, cell: [u32; 3]) -> usize {
        let r = self.cfg.res as usize;
        cell[0] as usize + r * (cell[1] as usize + r * cell[2] as usize)
    }
    /// Whether the cell at `index` (see [`Self::index`]) is occupied.
    pub fn is_occupied(&self, index: usize) -> bool {
        self.bits[index / 64] >> (index % 64) & 1 == 1
    }
    /// Sets a cell's bit directly (its EMA is left alone).
    pub fn set_occupied(&mut self, index: usize, on: bool) {
        let (w, b) = (index / 64, 1u64 << (index % 64));
        if (self.bits[w] & b != 0) == on {
            return;
        }
        self.bits[w] ^= b;
        let r = self.cfg.res as usize;
        let block = self.block_of([index % r, index / r % r, index / (r * r)].map(|v| v as u32));
        if on {
            self.blocks[block] += 1;
        } else {
            self.blocks[block] -= 1;
        }
    }
    /// Sets every cell's EMA and bit at once (from a checkpoint), refusing
    /// lists of another length.
    pub fn restore(&mut self, ema: &[f32], occupied: &[bool]) -> Result<(), String> {
        if ema.len() != self.cells() || occupied.len() != self.cells() {
            return Err(format!(
                "occupancy grid of {} cells given {} and {} values",
                self.cells(),
                ema.len(),
                occupied.len()
            ));
        }
        self.ema.copy_from_slice(ema);
        self.refreshed = true;
        self.fill(false);
        for (i, &on) in occupied.iter().enumerate() {
            if on {
                self.set_occupied(i, true);
            }
        }
        Ok(())
    }

    /// Every bit at once.
    pub fn fill(&mut self, on: bool) {
        let cells = self.cells();
        for (k, w) in self.bits.iter_mut().enumerate() {
            // No bits past the last cell, so counts stay popcounts.
            let valid = (cells - 64 * k).min(64);
            *w = if on { u64::MAX >> (64 - valid) } else { 0 };
        }
        let (r, nb) = (self.cfg.res, self.cfg.res.div_ceil(BLOCK));
        let side = |b: u32| (r - b * BLOCK).min(BLOCK);
        for (i, n) in self.blocks.iter_mut().enumerate() {
            let i = i as u32;
            *n = if on {
                side(i % nb) * side(i / nb % nb) * side(i / (nb * nb))
            } else {
                0
            };
        }
    }
    /// The block of cell `c`: its index in `blocks`.
    #[doc(hidden)]
    pub fn block_of(&self, c: [u32; 3]) -> usize {
        let nb = self.cfg.res.div_ceil(BLOCK) as usize;
        let b = c.map(|v| (v / BLOCK) as usize);
        b[0] + nb * (b[1] + nb * b[2])
    }
    /// Occupied cells.
    pub fn occupied_count(&self) -> usize {
        self.blocks.iter().map(|&n| n as usize).sum()
    }

    /// The cell holding `p` (f32 arithmetic, the one test [`Self::march`]
    /// uses), or `None` outside the box (or NaN).
    #[inline(always)]
    pub fn cell_of(&self, p: [f32; 3]) -> Option<[u32; 3]> {
        let r = self.cfg.res as f32;
        let mut c = [0u32; 3];
        for a in 0..3 {
            let u = (p[a] - self.cfg.bbox_min[a]) * self.scale[a];
            if !(u >= 0.0 && u < r) {
                return None;
            }
            c[a] = (u as u32).min(self.cfg.res - 1);
        }
        Some(c)
    }

    /// Re-evaluates density at one jittered point per cell (all cells, or one
    /// subset after warm-up, see [`OccupancyConfig`]; the first update
    /// evaluates all, whatever its step), in order, in calls of
    /// at most 65 536 points; each evaluated cell gets
    /// `ema = max(decay·ema, σ)`, then every cell its bit from its EMA
    /// (the threshold capped at the mean cell's). NaN densities count as 0,
    /// +∞ as `f32::MAX`. The jitter comes from one draw of `rng`, so the
    /// result depends only on the grid, `step`, the draw and the densities.
    pub fn update(&mut self, step: u64, density: &mut DensityFn, rng: &mut SplitMix64) {
        let key = rng.next_u64();
        // Every cell until each has been seen once: the bits below are
        // derived from every cell's EMA, and an unseen cell's 0 would empty
        // it (were a grid first refreshed after its warm-up).
        let every = step < self.cfg.warmup || self.cfg.subsets == 1 || !self.refreshed;
        self.refreshed = true;
        let (first, stride) = if every {
            (0, 1)
        } else {
            let s = self.cfg.subsets as u64;
            ((step / self.cfg.every % s) as usize, s as usize)
        };
        let r = self.cfg.res as usize;
        let cells = self.cells();
        let mut start = first;
        while start < cells {
            let n = (cells - start).div_ceil(stride).min(UPDATE_CHUNK);
            self.points.resize(n, [0.0; 3]);
            self.density.resize(n, 0.0);
            let (min, cell) = (self.cfg.bbox_min, self.cell);
            self.points.par_iter_mut().enumerate().for_each(|(i, p)| {
                let c = start + i * stride;
                // Hashed per cell: consecutive SplitMix64 seeds would share draws.
                let mut g = SplitMix64::new(SplitMix64::new(key ^ c as u64).next_u64());
                let ijk = [c % r, c / r % r, c / (r * r)];
                *p = std::array::from_fn(|a| {
                    let x = ijk[a] as f64 + g.next_f32() as f64;
                    (min[a] as f64 + x * cell[a]) as f32
                });
            });
            density(&self.points, &mut self.density);
            let decay = if step < self.cfg.warmup {
                WARMUP_DECAY.min(self.cfg.decay)
            } else {
                self.cfg.decay
            };
            for i in 0..n {
                let c = start + i * stride;
                self.ema[c] = (self.ema[c] * decay).max(self.density[i].min(f32::MAX));
            }
            start += n * stride;
        }
        // The threshold is capped at the mean cell's opacity (instant-ngp's
        // and nerfacc's rule): with a fine step an untrained network's
        // density is below an absolute threshold everywhere, and a grid that
        // emptied every cell would stop all training. Where the cap binds,
        // cells at least the mean stay (a uniform field keeps them all). A
        // sequential f64 sum: the same bits for any thread count.
        let dt = self.cfg.step_size as f64;
        let mean = self.ema.iter().map(|&e| e as f64).sum::<f64>() / cells as f64;
        let capped = mean * dt < self.cfg.threshold as f64;
        for c in 0..cells {
            let e = self.ema[c] as f64;
            let on = if capped {
                e >= mean
            } else {
                e * dt > self.cfg.threshold as f64
            };
            self.set_occupied(c, on);
        }
    }

    /// Sample depths of the ray `origin + t·dir` in `[near, far)` at fixed
    /// `step` that fall in occupied cells (see the module doc), each with
    /// interval `step`, into `t` and `dt` (cleared first). A ray missing the
    /// box gives none. Errors: non-finite or zero `dir`, bad range, more
    /// than [`MAX_SAMPLES`] candidates.
    #[allow(clippy::too_many_arguments)] // a ray, its range, and two outputs
    pub fn march(
        &self,
        origin: [f32; 3],
        dir: [f32; 3],
        near: f32,
        far: f32,
        step: f32,
        t: &mut Vec<f32>,
        dt: &mut Vec<f32>,
    ) -> Result<(), VolumeError> {
        if !self.enabled {
            return fixed_step(near, far, step, t, dt);
        }
        let count = check_range(near, far, step)?;
        let finite = origin.iter().chain(&dir).all(|v| v.is_finite());
        if !finite || dir == [0.0; 3] {
            return Err(VolumeError::Invalid(format!(
                "occupancy march: origin {origin:?} and direction {dir:?} must be finite, direction non-zero"
            )));
        }
        t.clear();
        dt.clear();
        let ray = RayCtx::new(self, origin, dir);
        let Some((enter, exit)) = ray.box_span(self) else {
            return Ok(());
        };
        let (near64, step64) = (near as f64, step as f64);
        let k_of = |tt: f64| ((tt - near64) / step64 - 0.5).floor();
        let mut k = k_of(enter).max(0.0) as usize;
        let mut inside = false;
        while k < count {
            let tk = sample_t(near, step, k);
            if tk >= far || tk as f64 > exit {
                break;
            }
            let p: [f32; 3] = std::array::from_fn(|a| origin[a] + tk * dir[a]);
            let Some(c) = self.cell_of(p) else {
                // Each coordinate moves monotonically with k (rounding is
                // monotone), so once out of the box, out for good.
                if inside {
                    break;
                }
                k += 1;
                continue;
            };
            inside = true;
            if self.is_occupied(self.index(c)) {
                t.push(tk);
                dt.push(step);
                k += 1;
                continue;
            }
            // The samples in an empty cell (or block) are consecutive: jump
            // to the first that may be past its exit.
            let leave = if self.blocks[self.block_of(c)] == 0 {
                ray.exit(self, c.map(|v| v / BLOCK * BLOCK), BLOCK)
            } else {
                ray.exit(self, c, 1)
            };
            k = (k + 1).max((k_of(leave) + 1.0).max(0.0) as usize);
        }
        Ok(())
    }
}

impl OccupancyGrid {
    /// [`Self::march`] for every ray, in parallel over chunks of rays and
    /// concatenated in ray order (so the same whatever the thread count);
    /// the first failing ray's error. With `jitter` (a seed), ray `r`'s
    /// samples are moved by one offset in `[-½, ½)` of a step drawn from
    /// the seed and `r` (training: the field is seen between the fixed
    /// steps too, as nerfacc's stratified marching; the first sample stays
    /// at or after `near`).
    pub fn march_rays(
        &self,
        rays: &[Ray],
        near: f32,
        far: f32,
        step: f32,
        jitter: Option<u64>,
        out: &mut RaySamples,
    ) -> Result<(), VolumeError> {
        // Per chunk: sample counts per ray and the depths.
        type Part = Result<(Vec<usize>, Vec<f32>), VolumeError>;
        let parts: Vec<Part> = rays
            .par_chunks(RAY_CHUNK)
            .enumerate()
            .map(|(c, chunk)| {
                let (mut counts, mut all) = (Vec::with_capacity(chunk.len()), Vec::new());
                let (mut t, mut dt) = (Vec::new(), Vec::new());
                for (i, r) in chunk.iter().enumerate() {
                    let near = match jitter {
                        None => near,
                        Some(seed) => {
                            let ray = (c * RAY_CHUNK + i) as u64;
                            let u = SplitMix64::new(seed ^ ray.wrapping_mul(0x9E37_79B9_7F4A_7C15))
                                .next_f32();
                            near + (u - 0.5) * step
                        }
                    };
                    self.march(r.origin, r.dir, near, far, step, &mut t, &mut dt)?;
                    counts.push(t.len());
                    all.extend_from_slice(&t);
                }
                Ok((counts, all))
            })
            .collect();
        out.offsets.clear();
        out.t.clear();
        out.offsets.push(0);
        for part in parts {
            let (counts, t) = part?;
            let mut at = out.t.len();
            for n in counts {
                at += n;
                out.offsets.push(at);
            }
            out.t.extend(t);
        }
        out.dt.clear();
        out.dt.resize(out.t.len(), step);
        Ok(())
    }
}

/// A ray's constants for exits, in f64.
struct RayCtx {
    o: [f64; 3],
    d: [f64; 3],
    inv: [f64; 3],
    /// `|o| + |box min| + extent` per axis: the magnitudes the f32 point
    /// and cell test round, besides `|t·d|`.
    mag: [f64; 3],
}

impl RayCtx {
    fn new(g: &OccupancyGrid, origin: [f32; 3], dir: [f32; 3]) -> Self {
        let o = origin.map(f64::from);
        let d = dir.map(f64::from);
        RayCtx {
            o,
            d,
            inv: d.map(|v| 1.0 / v),
            mag: std::array::from_fn(|a| {
                o[a].abs() + (g.cfg.bbox_min[a] as f64).abs() + g.cell[a] * g.cfg.res as f64
            }),
        }
    }

    /// Bound on how far (in t) the f32 sample point and cell test may stray
    /// from exact arithmetic at a face of axis `a` crossed at `tt`: 8× a few
    /// ulps of every term, over the speed along `a`.
    #[inline(always)]
    fn slack(&self, a: usize, tt: f64) -> f64 {
        1e-6 * (tt.abs() + (self.mag[a] + (tt * self.d[a]).abs()) * self.inv[a].abs())
    }

    /// The widened `[enter, exit]` of the ray in the box, or `None` when it
    /// misses (an axis with zero direction is decided by the exact f32 test).
    fn box_span(&self, g: &OccupancyGrid) -> Option<(f64, f64)> {
        let (mut enter, mut exit) = (f64::NEG_INFINITY, f64::INFINITY);
        let r = g.cfg.res as f32;
        for a in 0..3 {
            if self.d[a] == 0.0 {
                let u = (self.o[a] as f32 - g.cfg.bbox_min[a]) * g.scale[a];
                if !(u >= 0.0 && u < r) {
                    return None;
                }
                continue;
            }
            let lo = g.cfg.bbox_min[a] as f64;
            let hi = lo + g.cell[a] * g.cfg.res as f64;
            let (t0, t1) = (
                (lo - self.o[a]) * self.inv[a],
                (hi - self.o[a]) * self.inv[a],
            );
            let (t0, t1) = (t0.min(t1), t0.max(t1));
            enter = enter.max(t0 - self.slack(a, t0));
            exit = exit.min(t1 + self.slack(a, t1));
        }
        (enter <= exit).then_some((enter, exit))
    }

    /// Where the ray leaves the cube of `size` cells from cell `lo`, less the
    /// slack: no sample before it can lie beyond the cube.
    #[inline(always)]
    #[allow(
        clippy::needless_range_loop,
        reason = "one axis index over the ray, the cell and the grid; per-sample hot path"
    )]
    fn exit(&self, g: &OccupancyGrid, lo: [u32; 3], size: u32) -> f64 {
        let mut best = f64::INFINITY;
        for a in 0..3 {
            if self.d[a] == 0.0 {
                continue;
            }
            let face = lo[a] + if self.d[a] > 0.0 { size } else { 0 };
            let x = g.cfg.bbox_min[a] as f64 + face as f64 * g.cell[a];
            let ta = (x - self.o[a]) * self.inv[a];
            best = best.min(ta - self.slack(a, ta));
        }
        best
    }
}
