//! Empty space skipped for a neural surface: an occupancy grid over the
//! hash SDF's box, refreshed from the current distance every
//! [`NeuralSurface::SKIP_EVERY`] steps, and each ray's samples placed over
//! the span of occupied cells it crosses.
//!
//! - **Occupied** when the distance at a cell's centre could reach the
//!   density's support anywhere in the cell before the next refresh:
//!   `f(centre) ≤ L·h + b + m` (inside included, below), with `h` the half-diagonal, `L` a
//!   Lipschitz allowance, `b` the density's band and `m` the drift.
//!   - `L = max(1.5, 1.5 · s)`, `s` the largest slope between neighbouring
//!     centres: a learned SDF is only about 1-Lipschitz (the eikonal term
//!     keeps `|∇f|` near 1, not at it), and where it is steeper than that
//!     the measured slope says so.
//!   - `b` ([`band`]): beyond it a ray's skipped part absorbs less than
//!     [`OPACITY_LOST`]: NeuS's opacity over a stretch where `f ≥ b` is at
//!     most `e^(−b/β)`, VolSDF's at most `α·ℓ/2·e^(−b/β)` over a length
//!     `ℓ` (the box's diagonal).
//!   - `m` = [`DRIFT_SAFETY`] × the most any centre moved over the last
//!     refresh interval: what the next interval may move, measured rather
//!     than assumed. The first refresh has nothing to compare with, so its
//!     grid is every cell (nothing skipped for the first interval).
//! - **Outside the box** the hash SDF's features are clamped, so there
//!   `f(x) = f(x̄) + ‖x − c‖ − ‖x̄ − c‖ ≥ f(x̄)` (`x̄` the nearest point of the
//!   box, `c` its centre): no surface lies outside while every cell on the
//!   box's faces has `f(centre) > L·h + m` (positive all over before the
//!   next refresh). Where one has not, the surface may continue outside,
//!   and no ray skips anything (the grid *leaks*). Outside the box only a
//!   density's tail is skipped, where the surface comes within `b` of a
//!   face: the box should leave the object that much room.
//!   - Every cell inside (`f(centre) < 0`) is occupied as well: a ray
//!     that starts or ends inside the object samples its interior, which
//!     is opaque (VolSDF's density there is about α; NeuS's opacity grows
//!     as `f` falls, as much going deeper as crossing the surface). A ray
//!     that passes through has the same span either way (the cells
//!     between its first and last occupied ones are in it).
//!   - A trained β that grows past the band's before the next refresh
//!     widens the threshold at once (the same distances, a wider `b`).
//! - **A ray's span** runs from the entry of the first occupied cell it
//!   crosses to the exit of the last (cells in between, occupied or not,
//!   included: deep inside an object VolSDF is still opaque), within the
//!   ray's own first and last depth. Its stratified depths are mapped
//!   affinely onto the span, so a ray keeps its count and its jitter, the
//!   first and last samples at the span's ends; a whole span leaves them
//!   as they were, bit for bit. A ray crossing no occupied cell has zero
//!   opacity: the background, at no network cost.
//!
//! The grid is the last refresh's centre distances and threshold (the
//! occupied bits follow from them), kept in checkpoints, so a resumed run
//! sees the grid the uninterrupted one did.

use rayon::prelude::*;
use sdfl_stdlib::value::{DensityKind, NeuralSurface};

use crate::neural::occupancy::{OccupancyConfig, OccupancyGrid};
use crate::volume::Ray;

/// Most opacity a ray may lose to the density's tail in skipped space.
pub const OPACITY_LOST: f32 = 1e-3;
/// The least Lipschitz allowance, and the factor on the measured slope.
pub const LIPSCHITZ_FLOOR: f32 = 1.5;
/// How much more than the last interval's drift the next may move.
pub const DRIFT_SAFETY: f32 = 2.0;

/// Which part of a ray's depths to sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Span {
    /// All of them, unchanged.
    Whole,
    /// Only `[a, b]`, strictly inside the ray's first and last depth.
    Part(f32, f32),
    /// None: the ray crosses no occupied cell.
    Empty,
}

/// The occupancy grid of a surface's distance (see the module doc).
#[derive(Debug, Clone)]
pub struct SkipGrid {
    /// The occupied bits (the NeRF's grid, its cells and indexing).
    bits: OccupancyGrid,
    res: usize,
    min: [f64; 3],
    cell: [f64; 3],
    /// Cell centres, in index order.
    centres: Vec<[f32; 3]>,
    /// The distance at each centre at the last refresh.
    distance: Vec<f32>,
    /// This refresh's distances before they replace `distance`.
    fresh: Vec<f32>,
    /// The step of the last refresh.
    refreshed_at: Option<usize>,
    /// Occupied when `|f| ≤ threshold` (`f32::MAX`: every cell).
    threshold: f32,
    /// The grid leaks when a cell on a face has `f ≤ crossing`.
    crossing: f32,
    /// No ray skips anything: every cell occupied, or the grid leaks.
    whole: bool,
}

impl SkipGrid {
    /// A grid of `res`³ cells over `min..max`, every cell occupied.
    pub fn new(min: [f32; 3], max: [f32; 3], res: u32) -> Result<Self, String> {
        let bits = OccupancyGrid::new(OccupancyConfig {
            res,
            ..OccupancyConfig::new(min, max)
        })?;
        let r = res as usize;
        let cell: [f64; 3] = std::array::from_fn(|a| (max[a] as f64 - min[a] as f64) / r as f64);
        let min = min.map(f64::from);
        let centres: Vec<[f32; 3]> = (0..r * r * r)
            .map(|i| {
                let ijk = [i % r, i / r % r, i / (r * r)];
                std::array::from_fn(|a| (min[a] + (ijk[a] as f64 + 0.5) * cell[a]) as f32)
            })
            .collect();
        Ok(SkipGrid {
            bits,
            res: r,
            min,
            cell,
            distance: vec![0.0; centres.len()],
            centres,
            fresh: Vec::new(),
            refreshed_at: None,
            threshold: f32::MAX,
            crossing: f32::MAX,
            whole: true,
        })
    }

    /// The grid of `spec`'s hash SDF over its box; `None` for the harmonic
    /// MLP, which has no box to tile, and for the per-sample `Opacity`
    /// density, whose opacity depends on how many samples fall in the
    /// surface's band (so moving them would change the image, not only
    /// its cost).
    pub fn of(spec: &NeuralSurface) -> Result<Option<Self>, String> {
        if spec.density == DensityKind::Opacity {
            return Ok(None);
        }
        match &spec.sdf.encoding {
            sdfl_stdlib::value::Encoding::HashGrid(g) => Self::new(
                g.min.map(|x| x as f32),
                g.max.map(|x| x as f32),
                NeuralSurface::SKIP_CELLS,
            )
            .map(Some),
            sdfl_stdlib::value::Encoding::Harmonic(_) => Ok(None),
        }
    }

    /// Cells in the grid.
    pub fn cells(&self) -> usize {
        self.centres.len()
    }

    /// Whether `step` is one the grid is refreshed at and has not been.
    pub fn due(&self, step: usize) -> bool {
        step.is_multiple_of(NeuralSurface::SKIP_EVERY) && self.refreshed_at != Some(step)
    }

    /// Whether cell `index` is occupied.
    pub fn is_occupied(&self, index: usize) -> bool {
        self.whole || self.bits.is_occupied(index)
    }

    /// Occupied cells (all of them while the grid is whole).
    pub fn occupied_count(&self) -> usize {
        if self.whole {
            self.cells()
        } else {
            self.bits.occupied_count()
        }
    }

    /// Whether no ray skips anything.
    pub fn is_whole(&self) -> bool {
        self.whole
    }

    /// The cell holding `p`, as an index, or `None` outside the box.
    pub fn cell_of(&self, p: [f32; 3]) -> Option<usize> {
        let mut c = [0usize; 3];
        for a in 0..3 {
            let u = ((p[a] as f64 - self.min[a]) / self.cell[a]).floor();
            if !(u >= 0.0 && u < self.res as f64) {
                return None;
            }
            c[a] = u as usize;
        }
        Some(c[0] + self.res * (c[1] + self.res * c[2]))
    }

    /// The box's diagonal.
    pub fn diagonal(&self) -> f32 {
        let r = self.res as f64;
        self.cell.iter().map(|c| c * c * r * r).sum::<f64>().sqrt() as f32
    }

    /// Refreshes the grid at `step` from `distance` (the field at points,
    /// written into the second slice) with the density's `band`.
    pub fn refresh(
        &mut self,
        step: usize,
        band: f32,
        distance: impl FnOnce(&[[f32; 3]], &mut [f32]),
    ) {
        self.fresh.resize(self.cells(), 0.0);
        distance(&self.centres, &mut self.fresh);
        // A NaN distance says nothing: 0, occupied. Infinities are kept
        // finite, as checkpoints keep them.
        for f in &mut self.fresh {
            *f = if f.is_nan() {
                0.0
            } else {
                f.clamp(-f32::MAX, f32::MAX)
            };
        }
        let first = self.refreshed_at.is_none();
        let drift = if first {
            f32::MAX
        } else {
            self.fresh
                .par_iter()
                .zip(&self.distance)
                .map(|(a, b)| (a - b).abs())
                .reduce(|| 0.0, f32::max)
        };
        std::mem::swap(&mut self.distance, &mut self.fresh);
        self.refreshed_at = Some(step);
        (self.crossing, self.threshold) =
            if first || !drift.is_finite() || band.is_nan() || band < 0.0 {
                (f32::MAX, f32::MAX)
            } else {
                let half_diagonal =
                    0.5 * self.cell.iter().map(|c| c * c).sum::<f64>().sqrt() as f32;
                let lipschitz = LIPSCHITZ_FLOOR.max(LIPSCHITZ_FLOOR * self.steepest_slope());
                let crossing = lipschitz * half_diagonal + DRIFT_SAFETY * drift;
                (crossing, crossing + band)
            };
        self.mark();
    }

    /// Widens the grid to the density's `band` at this step, when that is
    /// wider than the one it was marked with: a trained β may grow between
    /// refreshes (Adam moves ln β by about 20·lr a step: 2.2-fold over 8
    /// steps at lr 5e-3), and the skipped space must stay beyond the band
    /// of the β a step uses. The distances are those of the last refresh;
    /// it never narrows.
    pub fn widen(&mut self, band: f32) {
        if !(self.threshold < f32::MAX && self.crossing < f32::MAX) {
            return;
        }
        let threshold = if band >= 0.0 {
            self.crossing + band
        } else {
            // NaN: the band is unknown, nothing is skipped.
            f32::MAX
        };
        if threshold > self.threshold {
            self.threshold = threshold;
            self.mark();
        }
    }

    /// Whether the grid skips only space beyond `band` (see [`Self::widen`]).
    pub fn covers(&self, band: f32) -> bool {
        self.whole || self.threshold == f32::MAX || self.crossing + band <= self.threshold
    }

    /// The largest `|f(i) − f(j)| / |i − j|` over neighbouring centres.
    fn steepest_slope(&self) -> f32 {
        let r = self.res;
        let f = &self.distance;
        let cell = self.cell;
        (0..self.cells())
            .into_par_iter()
            .map(|i| {
                let ijk = [i % r, i / r % r, i / (r * r)];
                let mut s = 0f32;
                for (a, stride) in [1, r, r * r].into_iter().enumerate() {
                    if ijk[a] + 1 < r {
                        s = s.max((f[i + stride] - f[i]).abs() / cell[a] as f32);
                    }
                }
                s
            })
            .reduce(|| 0.0, f32::max)
    }

    /// The bits from the distances and the threshold.
    fn mark(&mut self) {
        let (r, thr, crossing) = (self.res, self.threshold, self.crossing);
        // Not finite (an infinite band or drift): every cell, as a restore
        // of its saved `f32::MAX` gives.
        if !(thr < f32::MAX && crossing < f32::MAX) {
            self.bits.fill(true);
            self.whole = true;
            return;
        }
        self.bits.fill(false);
        let mut leaks = false;
        for (i, &f) in self.distance.iter().enumerate() {
            let ijk = [i % r, i / r % r, i / (r * r)];
            let on_face = ijk.iter().any(|&c| c == 0 || c + 1 == r);
            if f <= thr {
                self.bits.set_occupied(i, true);
            }
            leaks |= on_face && f <= crossing;
        }
        self.whole = leaks;
    }

    /// The part of the ray `origin + t·dir` between `lo` and `hi` that
    /// crosses occupied cells (see the module doc).
    pub fn span(&self, origin: [f32; 3], dir: [f32; 3], lo: f32, hi: f32) -> Span {
        if self.whole || lo.is_nan() || hi.is_nan() || lo >= hi {
            return Span::Whole;
        }
        let (o, d) = (origin.map(f64::from), dir.map(f64::from));
        let (mut enter, mut exit) = (lo as f64, hi as f64);
        for a in 0..3 {
            let (x0, x1) = (self.min[a], self.min[a] + self.cell[a] * self.res as f64);
            if d[a] == 0.0 {
                if !(o[a] >= x0 && o[a] < x1) {
                    return Span::Empty;
                }
                continue;
            }
            let (t0, t1) = ((x0 - o[a]) / d[a], (x1 - o[a]) / d[a]);
            enter = enter.max(t0.min(t1));
            exit = exit.min(t0.max(t1));
        }
        if enter.is_nan() || exit.is_nan() || enter >= exit {
            return Span::Empty;
        }
        // Amanatides–Woo through the cells from `enter` to `exit`.
        let r = self.res;
        let mut c = [0usize; 3];
        let (mut next, mut step) = ([f64::INFINITY; 3], [0f64; 3]);
        for a in 0..3 {
            let p = o[a] + enter * d[a];
            let u = ((p - self.min[a]) / self.cell[a]).floor();
            c[a] = u.clamp(0.0, (r - 1) as f64) as usize;
            if d[a] != 0.0 {
                let face = c[a] as f64 + if d[a] > 0.0 { 1.0 } else { 0.0 };
                next[a] = (self.min[a] + face * self.cell[a] - o[a]) / d[a];
                step[a] = self.cell[a] / d[a].abs();
            }
        }
        let (mut first, mut last) = (None, 0f64);
        let mut t_in = enter;
        loop {
            let a = (0..3)
                .min_by(|&i, &j| next[i].total_cmp(&next[j]))
                .unwrap_or(0);
            let t_out = next[a].min(exit);
            if self.bits.is_occupied(c[0] + r * (c[1] + r * c[2])) {
                first.get_or_insert(t_in);
                last = t_out;
            }
            if t_out >= exit {
                break;
            }
            let moved = if d[a] > 0.0 {
                c[a] + 1
            } else {
                c[a].wrapping_sub(1)
            };
            if moved >= r {
                break;
            }
            c[a] = moved;
            t_in = t_out;
            next[a] += step[a];
        }
        match first {
            None => Span::Empty,
            Some(a) if a <= lo as f64 && last >= hi as f64 => Span::Whole,
            Some(a) => {
                let a = (a as f32).max(lo);
                let b = (last as f32).min(hi);
                if a >= b {
                    // A span thinner than f32 resolves: one point of the
                    // ray; its neighbourhood is cheap to keep whole.
                    Span::Part(
                        (a - 1e-4 * (1.0 + a.abs())).max(lo),
                        (b + 1e-4 * (1.0 + b.abs())).min(hi),
                    )
                } else {
                    Span::Part(a, b)
                }
            }
        }
    }

    /// The grid as checkpoint state: the centre distances of the last
    /// refresh, and `[step + 1 (0: never), threshold, crossing]`.
    pub fn state(&self) -> Vec<(String, Vec<f32>)> {
        let at = self.refreshed_at.map_or(0.0, |s| (s + 1) as f32);
        // A threshold that overflowed (a diverging field) marks every cell,
        // as f32::MAX does: saved so, the checkpoint stays resumable.
        let finite = |x: f32| if x.is_finite() { x } else { f32::MAX };
        let (threshold, crossing) = (finite(self.threshold), finite(self.crossing));
        vec![
            ("skip.distance".into(), self.distance.clone()),
            ("skip.refresh".into(), vec![at, threshold, crossing]),
        ]
    }

    /// Restores [`Self::state`], checked like any input.
    pub fn restore(&mut self, distance: &[f32], refresh: &[f32]) -> Result<(), String> {
        let &[at, threshold, crossing] = refresh else {
            return Err(format!(
                "the skip grid's refresh holds {} values, not 3",
                refresh.len()
            ));
        };
        if !(at >= 0.0 && at.fract() == 0.0 && at < 16_777_216.0) {
            return Err(format!("the skip grid's refresh step {at} is not a step"));
        }
        if !(crossing >= 0.0 && threshold >= crossing && threshold.is_finite()) {
            return Err(format!(
                "the skip grid's thresholds {threshold} and {crossing} are not 0 ≤ crossing ≤ threshold"
            ));
        }
        if let Some(k) = distance.iter().position(|f| !f.is_finite()) {
            return Err(format!(
                "the skip grid's cell {k} has distance {}, not a finite number",
                distance[k]
            ));
        }
        if distance.len() != self.cells() {
            return Err(format!(
                "a skip grid of {} cells given {} distances",
                self.cells(),
                distance.len()
            ));
        }
        self.distance.clear();
        self.distance.extend_from_slice(distance);
        self.refreshed_at = (at > 0.0).then(|| at as usize - 1);
        (self.threshold, self.crossing) = (threshold, crossing);
        self.mark();
        Ok(())
    }
}

/// Depths `t` (sorted) mapped affinely so their first and last fall on
/// `a` and `b`, into `out` (appended).
pub fn map_depths(t: &[f32], a: f32, b: f32, out: &mut Vec<f32>) {
    let (t0, t1) = (t[0] as f64, t[t.len() - 1] as f64);
    let scale = if t1 > t0 {
        (b as f64 - a as f64) / (t1 - t0)
    } else {
        0.0
    };
    out.extend(
        t.iter()
            .map(|&x| ((a as f64 + (x as f64 - t0) * scale) as f32).clamp(a, b)),
    );
}

/// The rays of a batch that cross occupied cells, with their depths mapped
/// onto their spans, and those that cross none. Kept between steps, so
/// that selecting allocates nothing once grown.
#[derive(Debug, Default)]
pub struct Selection {
    /// Index in the batch of each ray sampled.
    pub hits: Vec<usize>,
    /// Index in the batch of each ray that crosses no occupied cell.
    pub misses: Vec<usize>,
    /// The rays sampled, in batch order.
    pub rays: Vec<Ray>,
    /// `n` depths a ray sampled.
    pub depths: Vec<f32>,
}

impl Selection {
    /// Selects among `rays` of `n` depths each (`depth_of(r)`, sorted) by
    /// `grid` (none: every ray whole). A ray for which `keep(r)` holds is
    /// sampled whole where it would be dropped: a covered pixel's ray far
    /// from the surface is what the silhouette term grows the surface
    /// towards, and its pull (`a/β` however far) needs its samples.
    pub fn select<'d>(
        &mut self,
        grid: Option<&SkipGrid>,
        rays: &[Ray],
        n: usize,
        depth_of: impl Fn(usize) -> &'d [f32],
        keep: impl Fn(usize) -> bool,
    ) {
        self.hits.clear();
        self.misses.clear();
        self.rays.clear();
        self.depths.clear();
        for (r, ray) in rays.iter().enumerate() {
            let t = depth_of(r);
            let span = match (grid, t) {
                (Some(g), [lo, .., hi]) => g.span(ray.origin, ray.dir, *lo, *hi),
                _ => Span::Whole,
            };
            match span {
                Span::Empty if !keep(r) => {
                    self.misses.push(r);
                    continue;
                }
                Span::Empty => self.depths.extend_from_slice(&t[..n]),
                Span::Whole => self.depths.extend_from_slice(&t[..n]),
                Span::Part(a, b) => map_depths(&t[..n], a, b, &mut self.depths),
            }
            self.hits.push(r);
            self.rays.push(*ray);
        }
    }
}

/// How far from the surface (`b` of the module doc) a `kind` density with
/// `alpha` and `beta` still absorbs [`OPACITY_LOST`] over `length`.
pub fn band(kind: DensityKind, alpha: f32, beta: f32, length: f32) -> f32 {
    let tail = match kind {
        DensityKind::Neus => 1.0,
        // A density per length (and the per-sample form, bounded alike).
        DensityKind::VolSdf | DensityKind::Opacity => 0.5 * alpha * length,
    };
    beta * (tail / OPACITY_LOST).max(1.0).ln()
}
