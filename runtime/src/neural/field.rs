//! A NeRF as a model the trainer fits ([`NerfObjective`]) and as a field to
//! render ([`render_nerf_view`]): samples along rays → the network over the
//! whole batch → compositing per ray → MSE, and back. With `fine` samples,
//! a coarse network's compositing weights place the fine samples by inverse
//! CDF (not differentiated, as in NeRF) and a second network evaluates the
//! union of both; the loss is the sum of both networks' losses.
//!
//! Samples are ragged (each ray has its own count) so that samplers which
//! skip empty space plug in unchanged.

use rayon::prelude::*;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::model::TRAIN_PASS_SAMPLES;
use sdfl_stdlib::value::{LastInterval, Nerf, OccupancySpec, Sampler, UNBOUNDED_GRID_START};

use super::background::{Backdrop, BackdropWork};
use super::composite::squared_error_backward_bg;
use super::nerf::{NerfNet, NerfWork, PositionEncoding};
use super::occupancy::{OccupancyConfig, OccupancyGrid, RaySamples};
use super::warp::Warp;
use crate::train::field::{Description, Region, View};
use crate::train::fused::Batch;
use crate::train::{Objective, TensorSpec, TrainError, Trained, TrainedField};
use crate::volume::importance::{merge_depths, sample_pdf, Spacing};
use crate::volume::march::intervals_into;
use crate::volume::{camera_rays, ImageSize, Ray, SplitMix64, Stratified, VolumeError};

/// Rays per block of the compositing pass (the unit of the ordered loss
/// reduction).
const RAY_BLOCK: usize = 64;
/// Samples per network pass when rendering (bounds the buffers).
const RENDER_ROWS: usize = 1 << 16;
/// Rendering stops a ray once its transmittance falls below this: what lies
/// behind could change its colour by at most this much.
pub const EARLY_STOP: f32 = 1e-4;
/// Samples per ray per network pass of early-stopping rendering.
const SEGMENT: usize = 16;
/// Most sample depths a rendering pass places before its network passes
/// (their depths and intervals: 32 MB).
const MARCHED_DEPTHS: usize = 1 << 22;

/// The samples of a batch of rays: ray `r`'s depths are
/// `t[offsets[r]..offsets[r + 1]]`, each with its interval in `delta`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Samples {
    /// Ray `r`'s samples are `offsets[r]..offsets[r + 1]` (one entry more than rays).
    pub offsets: Vec<usize>,
    /// Sample depths along each ray.
    pub t: Vec<f32>,
    /// Each sample's interval.
    pub delta: Vec<f32>,
}

impl Samples {
    /// `n` depths per ray from `depth_of(ray)`, intervals per `last`.
    pub fn fixed<'d>(
        &mut self,
        rays: usize,
        n: usize,
        depth_of: impl Fn(usize) -> &'d [f32],
        last: LastInterval,
    ) {
        self.offsets.clear();
        self.offsets.extend((0..=rays).map(|r| r * n));
        self.t.clear();
        self.delta.clear();
        let mut d = Vec::with_capacity(n);
        for r in 0..rays {
            let t = depth_of(r);
            intervals_into(t, last, &mut d);
            self.t.extend_from_slice(t);
            self.delta.extend_from_slice(&d);
        }
    }

    /// Rays in the batch.
    pub fn rays(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Ray `r`'s samples: indices into `t` and `delta`.
    pub fn range(&self, r: usize) -> std::ops::Range<usize> {
        self.offsets[r]..self.offsets[r + 1]
    }

    /// The samples of rays `span` alone, into `out` (offsets from 0).
    pub fn rays_into(&self, span: std::ops::Range<usize>, out: &mut Samples) {
        let (first, last) = (self.offsets[span.start], self.offsets[span.end]);
        out.offsets.clear();
        out.offsets.extend(
            self.offsets[span.start..=span.end]
                .iter()
                .map(|&o| o - first),
        );
        out.t.clear();
        out.t.extend_from_slice(&self.t[first..last]);
        out.delta.clear();
        out.delta.extend_from_slice(&self.delta[first..last]);
    }

    /// Positions and directions of every sample.
    pub fn points(&self, rays: &[Ray], points: &mut Vec<f32>, dirs: &mut Vec<f32>) {
        let n = self.t.len();
        points.resize(n * 3, 0.0);
        dirs.resize(n * 3, 0.0);
        // Fixed chunks of samples, each finding its rays: parallel whatever
        // the counts per ray.
        let ray_of = |k: usize| self.offsets.partition_point(|&o| o <= k) - 1;
        points
            .par_chunks_mut(3 * 1024)
            .zip(dirs.par_chunks_mut(3 * 1024))
            .enumerate()
            .for_each(|(c, (p, d))| {
                let k0 = c * 1024;
                let mut r = ray_of(k0);
                for (j, (p, d)) in p.chunks_mut(3).zip(d.chunks_mut(3)).enumerate() {
                    let k = k0 + j;
                    while self.offsets[r + 1] <= k {
                        r += 1;
                    }
                    let ray = &rays[r];
                    for i in 0..3 {
                        p[i] = ray.origin[i] + self.t[k] * ray.dir[i];
                        d[i] = ray.dir[i];
                    }
                }
            });
    }
}

/// One network's buffers.
#[derive(Default)]
struct Pass {
    work: NerfWork,
    points: Vec<f32>,
    dirs: Vec<f32>,
    d_sigma: Vec<f32>,
    d_rgb: Vec<f32>,
    /// The samples kept up to where each ray turns opaque.
    kept: Samples,
    keep: Vec<usize>,
}

/// The weighted MSE of `net` on `samples` of `rays` against `targets`,
/// its gradient added into `grad`; `weights` (when given) receives each
/// sample's compositing weight. With `stop`, each ray's samples end at
/// the one where its transmittance falls below `stop`: the density of
/// every sample is computed, and the colour and the backward pass only of
/// those kept (what lies behind changes the ray's colour by less than
/// `stop`, and rendering stops there too). Returns the loss and the
/// samples fitted.
#[allow(clippy::too_many_arguments)]
fn fit_pass(
    net: &NerfNet,
    values: &[f32],
    rays: &[Ray],
    targets: &[[f32; 3]],
    samples: &Samples,
    backgrounds: &[[f32; 3]],
    d_backgrounds: &mut [[f32; 3]],
    scale: f32,
    pass: &mut Pass,
    grad: &mut [f32],
    mut weights: Option<&mut Vec<f32>>,
    stop: Option<f32>,
) -> (f64, usize) {
    samples.points(rays, &mut pass.points, &mut pass.dirs);
    let samples = match stop {
        None => {
            net.forward(values, &pass.points, &pass.dirs, &mut pass.work);
            samples
        }
        Some(stop) => {
            net.density(values, &pass.points, &mut pass.work);
            let (kept, keep, sigma) = (&mut pass.kept, &mut pass.keep, &pass.work.sigma);
            kept.offsets.clear();
            kept.t.clear();
            kept.delta.clear();
            kept.offsets.push(0);
            keep.clear();
            for r in 0..samples.rays() {
                let mut trans = 1.0f32;
                for k in samples.range(r) {
                    keep.push(k);
                    trans *= (-(sigma[k] * samples.delta[k])).exp();
                    if trans < stop {
                        break;
                    }
                }
                kept.offsets.push(keep.len());
            }
            if keep.len() < samples.t.len() {
                for (to, &from) in keep.iter().enumerate() {
                    kept.t.push(samples.t[from]);
                    kept.delta.push(samples.delta[from]);
                    pass.points.copy_within(3 * from..3 * from + 3, 3 * to);
                    pass.dirs.copy_within(3 * from..3 * from + 3, 3 * to);
                }
                pass.points.truncate(3 * keep.len());
                pass.dirs.truncate(3 * keep.len());
                pass.work.keep_rows(net, keep);
                net.colour(values, &pass.dirs, &mut pass.work);
                &pass.kept
            } else {
                net.colour(values, &pass.dirs, &mut pass.work);
                samples
            }
        }
    };
    let n = samples.t.len();
    pass.d_sigma.resize(n, 0.0);
    pass.d_rgb.resize(3 * n, 0.0);
    if let Some(w) = weights.as_deref_mut() {
        w.resize(n, 0.0);
    }
    let (sigma, rgb) = (&pass.work.sigma, &pass.work.rgb);
    // Each block of rays owns its samples' slices of the adjoints.
    let blocks: Vec<usize> = (0..rays.len()).step_by(RAY_BLOCK).collect();
    let d_sigma = SharedSlice(pass.d_sigma.as_mut_ptr());
    let d_rgb = SharedSlice(pass.d_rgb.as_mut_ptr());
    let w_out = weights.map(|w| SharedSlice(w.as_mut_ptr()));
    let d_bg = SharedSlice(d_backgrounds.as_mut_ptr().cast());
    let losses: Vec<f64> = blocks
        .par_iter()
        .map(|&r0| {
            let (d_sigma, d_rgb, w_out, d_bg) = (d_sigma, d_rgb, w_out, d_bg);
            let mut trans = Vec::new();
            let mut loss = 0f64;
            for r in r0..(r0 + RAY_BLOCK).min(rays.len()) {
                let k = samples.range(r);
                let (sg, c) = (&sigma[k.clone()], &rgb[3 * k.start..3 * k.end]);
                let (t, delta) = (&samples.t[k.clone()], &samples.delta[k.clone()]);
                // SAFETY: ray r's samples k belong to this block alone.
                let (ds, dc) = unsafe {
                    (
                        std::slice::from_raw_parts_mut(d_sigma.0.add(k.start), k.len()),
                        std::slice::from_raw_parts_mut(d_rgb.0.add(3 * k.start), 3 * k.len()),
                    )
                };
                let mut d_background = [0.0; 3];
                loss += squared_error_backward_bg(
                    sg,
                    c,
                    t,
                    delta,
                    backgrounds[r],
                    targets[r],
                    scale,
                    ds,
                    dc,
                    &mut d_background,
                    &mut trans,
                );
                // SAFETY: ray r's background adjoint belongs to this block;
                // added to, since a fine pass sees the same background.
                let db = unsafe { std::slice::from_raw_parts_mut(d_bg.0.add(3 * r), 3) };
                for j in 0..3 {
                    db[j] += d_background[j];
                }
                if let Some(w) = w_out {
                    // SAFETY: as above.
                    let w = unsafe { std::slice::from_raw_parts_mut(w.0.add(k.start), k.len()) };
                    // trans[j] is the transmittance before sample j.
                    for (j, wj) in w.iter_mut().enumerate() {
                        *wj = trans[j] * -(-(sg[j] * delta[j])).exp_m1();
                    }
                }
            }
            loss
        })
        .collect();
    net.backward(
        values,
        &pass.points,
        &mut pass.work,
        &mut pass.d_sigma,
        &mut pass.d_rgb,
        grad,
    );
    (losses.iter().sum(), n)
}

/// Consecutive spans of rays (by their sample `offsets`) of at most `limit`
/// samples each; a ray with more is a span of its own. No rays: one empty
/// span.
#[doc(hidden)]
pub fn ray_passes(offsets: &[usize], limit: usize) -> Vec<std::ops::Range<usize>> {
    let rays = offsets.len().saturating_sub(1);
    let mut spans = Vec::new();
    let mut start = 0;
    for r in 0..rays {
        if r > start && offsets[r + 1] - offsets[start] > limit {
            spans.push(start..r);
            start = r;
        }
    }
    spans.push(start..rays);
    spans
}

#[derive(Clone, Copy)]
struct SharedSlice(*mut f32);
// SAFETY: only ever used to write disjoint ranges from parallel tasks.
unsafe impl Send for SharedSlice {}
unsafe impl Sync for SharedSlice {}

/// An occupancy grid in use: the grid, how often it is refreshed, and the
/// fixed-step range its samples cover.
pub struct Occupancy {
    /// The grid.
    pub grid: OccupancyGrid,
    /// In an unbounded scene the grid covers the contracted cube (or NDC's
    /// box) and filters the sampler's own depths (rays are curves there).
    warp: Option<Warp>,
    every: usize,
    near: f32,
    far: f32,
    step: f32,
    work: NerfWork,
    marched: RaySamples,
}

impl Occupancy {
    /// The grid `spec` asks for, its fixed step from `sampler`'s range and
    /// count; with `warp`, over the contracted (or NDC) box.
    pub fn new(
        spec: &OccupancySpec,
        sampler: &Sampler,
        warp: Option<Warp>,
    ) -> Result<Self, String> {
        let (step, min, max) = match &warp {
            None => (
                ((sampler.far - sampler.near) / sampler.samples.max(1) as f64) as f32,
                spec.min.map(|x| x as f32),
                spec.max.map(|x| x as f32),
            ),
            // The threshold's step in the box's units: a ray's samples
            // span about `span` of them (contracted: across the inner box
            // and the shell; NDC: from the near plane to infinity).
            Some(w) => {
                let (min, max) = w.cube();
                (
                    (w.span() / sampler.samples.max(1) as f64) as f32,
                    min.map(|x| x as f32),
                    max.map(|x| x as f32),
                )
            }
        };
        let mut cfg = OccupancyConfig::new(min, max);
        cfg.warmup = sdfl_stdlib::value::OCCUPANCY_WARMUP;
        cfg.subsets = sdfl_stdlib::value::OCCUPANCY_SUBSETS;
        cfg.every = spec.every.max(1) as u64;
        cfg.res = spec.resolution;
        cfg.threshold = spec.threshold as f32;
        cfg.step_size = step;
        Ok(Occupancy {
            grid: OccupancyGrid::new(cfg)?,
            warp,
            every: spec.every.max(1),
            near: sampler.near as f32,
            far: sampler.far as f32,
            step,
            work: NerfWork::default(),
            marched: RaySamples::default(),
        })
    }

    /// The samples of `rays` in occupied cells: the grid's fixed steps
    /// (each ray's moved by an offset drawn from `jitter`, when given), or
    /// in an unbounded scene `candidates` (the sampler's, jittered by it)
    /// kept where their contracted point's cell is occupied.
    pub fn march(
        &mut self,
        rays: &[Ray],
        candidates: &Samples,
        jitter: Option<u64>,
        out: &mut Samples,
    ) -> Result<(), VolumeError> {
        if let Some(c) = self.warp {
            keep_occupied(&self.grid, &c, rays, candidates, out);
            return Ok(());
        }
        self.grid.march_rays(
            rays,
            self.near,
            self.far,
            self.step,
            jitter,
            &mut self.marched,
        )?;
        // Swapped, not copied (a batch's depths are megabytes): the next
        // march overwrites `marched` whole.
        std::mem::swap(&mut out.offsets, &mut self.marched.offsets);
        std::mem::swap(&mut out.t, &mut self.marched.t);
        std::mem::swap(&mut out.delta, &mut self.marched.dt);
        Ok(())
    }

    /// Refreshes the grid from `net`'s density at `values`.
    fn update(&mut self, net: &NerfNet, values: &[f32], step: usize, seed: u64) {
        // An unbounded field starts transparent: its grid waits.
        let start = match self.warp {
            Some(_) => UNBOUNDED_GRID_START as usize,
            None => 0,
        };
        if step < start {
            return;
        }
        let work = &mut self.work;
        let warp = self.warp;
        let mut density = |points: &[[f32; 3]], out: &mut [f32]| {
            let flat: Vec<f32> = points.iter().flatten().copied().collect();
            // The grid's points are in the encoding's space already; only
            // their density is read.
            net.density_encoded(values, &flat, work);
            out.copy_from_slice(&work.sigma);
            // In a warped box a cell's opacity is its density times the
            // world length a step of the box spans there.
            if let Some(c) = &warp {
                for (o, p) in out.iter_mut().zip(points) {
                    *o *= c.world_per_unit(*p);
                }
            }
        };
        let mut rng = SplitMix64::new(seed ^ 0x6F63_6375);
        // The grid's own warm-up (every cell each refresh, a quick decay)
        // counts from its first refresh.
        let clock = step - start;
        self.grid.update(clock as u64, &mut density, &mut rng);
    }
}

/// The samples of `candidates` whose contracted point lies in an occupied
/// cell of `grid` (over the contracted cube), each keeping its interval.
fn keep_occupied(
    grid: &OccupancyGrid,
    c: &Warp,
    rays: &[Ray],
    candidates: &Samples,
    out: &mut Samples,
) {
    if !grid.is_enabled() {
        // A disabled grid skips nothing.
        out.clone_from(candidates);
        return;
    }
    out.offsets.clear();
    out.t.clear();
    out.delta.clear();
    out.offsets.push(0);
    for (r, ray) in rays.iter().enumerate() {
        for k in candidates.range(r) {
            let t = candidates.t[k];
            let p = std::array::from_fn(|a| ray.origin[a] + t * ray.dir[a]);
            if let Some(cell) = grid.cell_of(c.apply(p)) {
                if grid.is_occupied(grid.index(cell)) {
                    out.t.push(t);
                    out.delta.push(candidates.delta[k]);
                }
            }
        }
        out.offsets.push(out.t.len());
    }
}

/// Per ray, stratified depths `depth_of(r)` on `[near, far]` moved to the
/// contraction's linear-then-disparity spacing, into `out` (`n` a ray).
#[doc(hidden)]
pub fn unbounded_depths<'d>(
    c: &Warp,
    rays: &[Ray],
    near: f64,
    far: f64,
    depth_of: impl Fn(usize) -> &'d [f32],
    out: &mut Vec<f32>,
) {
    out.clear();
    for (r, ray) in rays.iter().enumerate() {
        c.depths(ray.origin, ray.dir, near, far, depth_of(r), out);
    }
}

/// A NeRF being trained: the coarse network, and the fine one with its
/// sample count when hierarchical.
pub struct NerfObjective {
    /// The coarse network.
    pub net: NerfNet,
    /// The fine network and its samples per ray, when hierarchical.
    pub fine: Option<(NerfNet, usize)>,
    /// An occupancy grid that skips empty space, if any.
    pub occupancy: Option<Occupancy>,
    seed: u64,
    /// Behind the field: a colour, or learned (parameters after the
    /// networks').
    pub backdrop: Backdrop,
    /// The sampler's range (unbounded depths are spaced within it).
    near: f64,
    far: f64,
    backdrop_work: BackdropWork,
    backgrounds: Vec<[f32; 3]>,
    d_backgrounds: Vec<[f32; 3]>,
    mapped: Vec<f32>,
    candidates: Samples,
    coarse_pass: Pass,
    fine_pass: Pass,
    samples: Samples,
    /// Most samples a network pass of a step holds.
    pass_samples: usize,
    /// A ray's fitted samples end where its transmittance falls below this
    /// (with an occupancy grid; 0: never).
    train_stop: f32,
    /// One pass's rays' samples when a step takes several.
    part: Samples,
    fine_samples: Samples,
    weights: Vec<f32>,
    /// The fine and the merged depths ([`fine_samples`]'s scratch).
    fine_depths: Vec<f32>,
    /// Samples the networks evaluated in this process's steps: counted,
    /// never read by a step.
    evaluated: u64,
}

impl NerfObjective {
    /// The model of `spec` sampled with `sampler` (whose range and count
    /// set an occupancy grid's fixed step).
    pub fn new(spec: &Nerf, sampler: &Sampler) -> Result<Self, String> {
        let net = NerfNet::try_new_at(spec, 0)?;
        let fine = match spec.fine {
            0 => None,
            m => Some((NerfNet::try_new_at(spec, net.len)?, m)),
        };
        let occupancy = spec
            .occupancy
            .as_ref()
            .map(|o| Occupancy::new(o, sampler, net.warp))
            .transpose()?;
        let first = net.len + fine.as_ref().map_or(0, |(f, _)| f.len);
        Ok(NerfObjective {
            backdrop: Backdrop::new(&spec.background, first),
            near: sampler.near,
            far: sampler.far,
            backdrop_work: BackdropWork::default(),
            backgrounds: Vec::new(),
            d_backgrounds: Vec::new(),
            mapped: Vec::new(),
            candidates: Samples::default(),
            net,
            fine,
            occupancy,
            seed: spec.seed,
            coarse_pass: Pass::default(),
            fine_pass: Pass::default(),
            samples: Samples::default(),
            pass_samples: TRAIN_PASS_SAMPLES,
            train_stop: EARLY_STOP,
            part: Samples::default(),
            fine_samples: Samples::default(),
            weights: Vec::new(),
            fine_depths: Vec::new(),
            evaluated: 0,
        })
    }

    /// Renders one view at `params` through the fine network when there is
    /// one, sampling with the occupancy grid when there is one (as trained)
    /// and stratified depths otherwise.
    pub fn render_view(
        &self,
        params: &[f32],
        sampler: &Stratified,
        last: LastInterval,
        cam: &Camera,
        size: ImageSize,
    ) -> Result<NerfView, VolumeError> {
        render_nerf_view(
            &self.net,
            self.fine.as_ref().map(|(f, m)| (f, *m)),
            self.occupancy.as_ref(),
            params,
            &self.backdrop,
            sampler,
            last,
            cam,
            size,
            EARLY_STOP,
        )
    }

    /// Sets the most samples a network pass of a step holds (tests: several
    /// passes on a small batch).
    #[doc(hidden)]
    pub fn set_pass_samples(&mut self, samples: usize) {
        self.pass_samples = samples.max(1);
    }

    /// Sets where training stops a ray (tests: 0 fits every sample).
    #[doc(hidden)]
    pub fn set_train_stop(&mut self, stop: f32) {
        self.train_stop = stop;
    }

    fn networks(&self) -> Vec<(&'static str, &NerfNet)> {
        match &self.fine {
            None => vec![("", &self.net)],
            Some((f, _)) => vec![("coarse.", &self.net), ("fine.", f)],
        }
    }
}

/// Fine samples for rays with `n` coarse samples each and their weights:
/// `m` depths by inverse CDF merged with the coarse ones (`n + m` per ray).
/// `scratch` holds the fine and the merged depths between calls.
#[allow(clippy::too_many_arguments)]
pub fn fine_samples(
    coarse: &Samples,
    n: usize,
    weights: &[f32],
    m: usize,
    spacing: Spacing,
    last: LastInterval,
    scratch: &mut Vec<f32>,
    out: &mut Samples,
) -> Result<(), VolumeError> {
    let rays = coarse.rays();
    scratch.resize(rays * m + rays * (n + m), 0.0);
    let (fine_t, merged) = scratch.split_at_mut(rays * m);
    sample_pdf(&coarse.t, weights, n, m, spacing, fine_t)?;
    merge_depths(&coarse.t, n, fine_t, m, merged)?;
    out.fixed(
        rays,
        n + m,
        |r| &merged[r * (n + m)..(r + 1) * (n + m)],
        last,
    );
    Ok(())
}

impl Objective for NerfObjective {
    fn tensors(&self) -> Vec<TensorSpec> {
        self.networks()
            .into_iter()
            .flat_map(|(prefix, net)| {
                let grid = match &net.position {
                    PositionEncoding::Grid { grid, offset } => Some(TensorSpec {
                        name: format!("{prefix}position.hashgrid"),
                        offset: *offset,
                        len: grid.param_count(),
                    }),
                    PositionEncoding::Harmonic(_) => None,
                };
                grid.into_iter().chain(
                    net.layers()
                        .into_iter()
                        .flat_map(move |(name, d)| d.tensors(&format!("{prefix}{name}"))),
                )
            })
            .chain(
                self.backdrop
                    .layers()
                    .into_iter()
                    .flat_map(|(name, d)| d.tensors(&name)),
            )
            .collect()
    }

    fn samples_evaluated(&self) -> Option<u64> {
        Some(self.evaluated)
    }

    fn state(&self) -> Vec<(String, Vec<f32>)> {
        match &self.occupancy {
            None => Vec::new(),
            Some(o) => {
                let occupied = (0..o.grid.cells())
                    .map(|i| if o.grid.is_occupied(i) { 1.0 } else { 0.0 })
                    .collect();
                vec![
                    ("occupancy.ema".into(), o.grid.ema().to_vec()),
                    ("occupancy.occupied".into(), occupied),
                ]
            }
        }
    }

    fn restore_state(&mut self, state: &[(String, Vec<f32>)]) -> Result<(), TrainError> {
        let names: Vec<&str> = state.iter().map(|s| s.0.as_str()).collect();
        match (&mut self.occupancy, names.as_slice()) {
            (None, []) => Ok(()),
            (Some(o), ["occupancy.ema", "occupancy.occupied"]) => {
                // Checked like any input: densities are never negative,
                // and a cell is occupied or not.
                if let Some(k) = state[0]
                    .1
                    .iter()
                    .position(|&x| !(x >= 0.0 && x.is_finite()))
                {
                    return Err(TrainError::Invalid(format!(
                        "occupancy cell {k} has density {}, not a finite number ≥ 0",
                        state[0].1[k]
                    )));
                }
                if let Some(k) = state[1].1.iter().position(|&x| x != 0.0 && x != 1.0) {
                    return Err(TrainError::Invalid(format!(
                        "occupancy cell {k} is marked {}, neither 0 nor 1",
                        state[1].1[k]
                    )));
                }
                let occupied: Vec<bool> = state[1].1.iter().map(|&x| x != 0.0).collect();
                o.grid
                    .restore(&state[0].1, &occupied)
                    .map_err(TrainError::Invalid)
            }
            _ => Err(TrainError::Invalid(format!(
                "the checkpoint holds state {names:?}, which this model does not have"
            ))),
        }
    }

    fn initial(&self) -> Vec<f32> {
        let mut v = self.net.init(self.seed);
        if let Some((f, _)) = &self.fine {
            v.resize(v.len() + f.len, 0.0);
            // The fine network starts from its own draw.
            f.init_into(self.seed.wrapping_add(1), &mut v);
        }
        v.resize(v.len() + self.backdrop.len(), 0.0);
        self.backdrop.init_into(self.seed, &mut v);
        v
    }

    fn loss_and_grad(
        &mut self,
        values: &[f32],
        batch: &Batch,
        weight: f64,
        grad: &mut [f32],
    ) -> Result<f64, TrainError> {
        let rays = batch.rays.len();
        let scale = (weight / (3 * rays.max(1)) as f64) as f32;
        let n = batch.samples;
        // The sampler's depths, spaced for an unbounded scene when it is one.
        match &self.net.warp {
            Some(c) => {
                unbounded_depths(
                    c,
                    &batch.rays,
                    self.near,
                    self.far,
                    |r| batch.depths_of(r),
                    &mut self.mapped,
                );
                let mapped = &self.mapped;
                self.candidates.fixed(
                    rays,
                    n,
                    |r| &mapped[r * n..(r + 1) * n],
                    batch.last_interval,
                );
            }
            // A bounded grid marches its own fixed steps: the sampler's
            // depths (a million a Lego batch) are not copied for it.
            None if self.occupancy.is_some() => {}
            None => self
                .candidates
                .fixed(rays, n, |r| batch.depths_of(r), batch.last_interval),
        }
        match &mut self.occupancy {
            Some(occ) => {
                if batch.step.is_multiple_of(occ.every) {
                    occ.update(&self.net, values, batch.step, batch.seed);
                }
                // A jittering sampler's rays see the field between the
                // grid's fixed steps too.
                let jitter = (!batch.shared).then_some(batch.seed ^ 0x6A69_7474);
                occ.march(&batch.rays, &self.candidates, jitter, &mut self.samples)?;
            }
            None => std::mem::swap(&mut self.samples, &mut self.candidates),
        }
        self.backdrop.colours(
            values,
            &batch.rays,
            &mut self.backdrop_work,
            &mut self.backgrounds,
        );
        self.d_backgrounds.clear();
        self.d_backgrounds.resize(rays, [0.0; 3]);
        // Passes of whole rays, each of at most TRAIN_PASS_SAMPLES samples:
        // a step's buffers are bounded whatever rays × samples is. One pass
        // (the usual case) fits the step's samples in place.
        let passes = ray_passes(&self.samples.offsets, self.pass_samples);
        let mut loss = 0.0;
        for (p, span) in passes.iter().enumerate() {
            let part = if passes.len() == 1 {
                &self.samples
            } else {
                self.samples.rays_into(span.clone(), &mut self.part);
                &self.part
            };
            let want_weights = self.fine.is_some().then_some(&mut self.weights);
            // With an occupancy grid (never with a fine network) each ray's
            // samples end where it turns opaque, as nerfacc trains.
            let stop = (self.occupancy.is_some() && self.fine.is_none() && self.train_stop > 0.0)
                .then_some(self.train_stop);
            let (l, fitted) = fit_pass(
                &self.net,
                values,
                &batch.rays[span.clone()],
                &batch.targets[span.clone()],
                part,
                &self.backgrounds[span.clone()],
                &mut self.d_backgrounds[span.clone()],
                scale,
                &mut self.coarse_pass,
                grad,
                want_weights,
                stop,
            );
            loss += l;
            self.evaluated += fitted as u64;
            if let Some((fine, m)) = &self.fine {
                // Jittered like the coarse samples, from the batch's own
                // seed (and the pass's, so passes draw apart).
                let spacing = if batch.shared {
                    Spacing::Even
                } else if p == 0 {
                    Spacing::Jittered(batch.seed)
                } else {
                    Spacing::Jittered(SplitMix64::new(batch.seed ^ span.start as u64).next_u64())
                };
                fine_samples(
                    part,
                    batch.samples,
                    &self.weights,
                    *m,
                    spacing,
                    batch.last_interval,
                    &mut self.fine_depths,
                    &mut self.fine_samples,
                )?;
                let (l, fitted) = fit_pass(
                    fine,
                    values,
                    &batch.rays[span.clone()],
                    &batch.targets[span.clone()],
                    &self.fine_samples,
                    &self.backgrounds[span.clone()],
                    &mut self.d_backgrounds[span.clone()],
                    scale,
                    &mut self.fine_pass,
                    grad,
                    None,
                    None,
                );
                loss += l;
                self.evaluated += fitted as u64;
            }
        }
        self.backdrop
            .backward(values, &mut self.backdrop_work, &self.d_backgrounds, grad);
        Ok(loss)
    }
}

/// A rendered view: colour and expected depth per pixel.
pub struct NerfView {
    /// Colour per pixel, row by row.
    pub colour: Vec<[f32; 3]>,
    /// Expected depth per pixel (`Σ wᵢtᵢ`).
    pub depth: Vec<f32>,
    /// Accumulated opacity per pixel (`Σ wᵢ`).
    pub opacity: Vec<f32>,
    /// Network evaluations it took.
    pub evaluated: usize,
}

/// Renders one view of a NeRF with stratified (unjittered) samples, through
/// the fine network when there is one, or with an occupancy grid's samples;
/// each ray stops once its transmittance is below `stop` ([`EARLY_STOP`];
/// 0: every sample evaluated).
#[allow(clippy::too_many_arguments)]
pub fn render_nerf_view(
    net: &NerfNet,
    fine: Option<(&NerfNet, usize)>,
    occupancy: Option<&Occupancy>,
    params: &[f32],
    backdrop: &Backdrop,
    sampler: &Stratified,
    last: LastInterval,
    cam: &Camera,
    size: ImageSize,
    stop: f32,
) -> Result<NerfView, VolumeError> {
    sampler.validate()?;
    let rays = camera_rays(cam, size)?;
    let t = sampler.depths();
    let n = t.len();
    let mut view = NerfView {
        colour: vec![[0.0; 3]; rays.len()],
        depth: vec![0.0; rays.len()],
        opacity: vec![0.0; rays.len()],
        evaluated: 0,
    };
    // A pass's rays: the coarse network of a two-network NeRF sees every
    // sample of its rays at once; otherwise the network sees a segment of
    // each ray at a time, so a pass takes as many rays as a segment's rows
    // allow (256 rays a pass made 800² views of Lego spend their time in
    // 5000 small network passes), its depths bounded by `MARCHED_DEPTHS`.
    let per_pass = match fine.filter(|_| occupancy.is_none()) {
        Some((_, m)) => RENDER_ROWS / (2 * n + m).max(1),
        None => (RENDER_ROWS / SEGMENT).min(MARCHED_DEPTHS / n.max(1)),
    }
    .max(1);
    let (mut pass, mut samples, mut fine_s) =
        (Pass::default(), Samples::default(), Samples::default());
    let (mut weights, mut fine_depths) = (Vec::new(), Vec::new());
    let (mut backgrounds, mut backdrop_work) = (Vec::new(), BackdropWork::default());
    let (mut mapped, mut candidates) = (Vec::new(), Samples::default());
    for (chunk, ((colour, depth), opacity)) in rays.chunks(per_pass).zip(
        view.colour
            .chunks_mut(per_pass)
            .zip(view.depth.chunks_mut(per_pass))
            .zip(view.opacity.chunks_mut(per_pass)),
    ) {
        // Unbounded: the stratified depths spaced linearly through the
        // inner box, in disparity beyond it.
        let contract = net.warp;
        if let Some(c) = &contract {
            unbounded_depths(c, chunk, t[0] as f64, t[n - 1] as f64, |_| &t, &mut mapped);
        }
        match occupancy {
            Some(o) if o.warp.is_some() => {
                let c = o.warp.as_ref().expect("just matched");
                candidates.fixed(chunk.len(), n, |r| &mapped[r * n..(r + 1) * n], last);
                keep_occupied(&o.grid, c, chunk, &candidates, &mut samples);
            }
            Some(o) => {
                let mut marched = RaySamples::default();
                o.grid
                    .march_rays(chunk, o.near, o.far, o.step, None, &mut marched)?;
                samples.offsets = marched.offsets;
                samples.t = marched.t;
                samples.delta = marched.dt;
            }
            None if contract.is_some() => {
                samples.fixed(chunk.len(), n, |r| &mapped[r * n..(r + 1) * n], last)
            }
            None => samples.fixed(chunk.len(), n, |_| &t, last),
        }
        backdrop.colours(params, chunk, &mut backdrop_work, &mut backgrounds);
        let used = match fine.filter(|_| occupancy.is_none()) {
            None => &samples,
            Some((_, m)) => {
                // The coarse network sees every sample: its weights place
                // the fine ones.
                samples.points(chunk, &mut pass.points, &mut pass.dirs);
                net.forward(params, &pass.points, &pass.dirs, &mut pass.work);
                view.evaluated += samples.t.len();
                weights.resize(samples.t.len(), 0.0);
                let (sigma, delta) = (&pass.work.sigma, &samples.delta);
                weights.par_chunks_mut(n).enumerate().for_each(|(r, w)| {
                    let mut trans = 1.0f32;
                    for (j, wj) in w.iter_mut().enumerate() {
                        let keep = (-(sigma[r * n + j] * delta[r * n + j])).exp();
                        *wj = trans * (1.0 - keep);
                        trans *= keep;
                    }
                });
                fine_samples(
                    &samples,
                    n,
                    &weights,
                    m,
                    Spacing::Even,
                    last,
                    &mut fine_depths,
                    &mut fine_s,
                )?;
                &fine_s
            }
        };
        view.evaluated += composite_until_opaque(
            fine.filter(|_| occupancy.is_none()).map_or(net, |(f, _)| f),
            params,
            chunk,
            used,
            &backgrounds,
            stop,
            &mut pass,
            colour,
            (depth, opacity),
        );
    }
    Ok(view)
}

/// Composites `samples` of `rays` through `net`, a segment of
/// [`SEGMENT`] samples per ray at a time, dropping each ray once its
/// transmittance is below `stop` (its remainder is the background). With
/// `stop = 0` every sample is evaluated and the colours equal
/// [`super::composite::composite`]'s bit for bit. Returns the samples evaluated.
#[allow(clippy::too_many_arguments)]
#[allow(
    clippy::needless_range_loop,
    reason = "c[j] pairs with rgb[3k + j]; per-sample hot path"
)]
fn composite_until_opaque(
    net: &NerfNet,
    params: &[f32],
    rays: &[Ray],
    samples: &Samples,
    backgrounds: &[[f32; 3]],
    stop: f32,
    pass: &mut Pass,
    colour: &mut [[f32; 3]],
    (depth, opacity): (&mut [f32], &mut [f32]),
) -> usize {
    // Per ray: transmittance, colour and depth so far.
    let mut state = vec![(1.0f32, [0.0f32; 3], 0.0f32); samples.rays()];
    let mut alive: Vec<usize> = (0..samples.rays())
        .filter(|&r| !samples.range(r).is_empty())
        .collect();
    let (mut seg, mut seg_rays, mut evaluated) = (Samples::default(), Vec::new(), 0);
    let mut start = 0;
    while !alive.is_empty() {
        seg.offsets.clear();
        seg.t.clear();
        seg.delta.clear();
        seg.offsets.push(0);
        seg_rays.clear();
        for &r in &alive {
            let k = samples.range(r);
            let a = (k.start + start).min(k.end);
            let b = (a + SEGMENT).min(k.end);
            seg.t.extend_from_slice(&samples.t[a..b]);
            seg.delta.extend_from_slice(&samples.delta[a..b]);
            seg.offsets.push(seg.t.len());
            seg_rays.push(rays[r]);
        }
        seg.points(&seg_rays, &mut pass.points, &mut pass.dirs);
        net.forward(params, &pass.points, &pass.dirs, &mut pass.work);
        evaluated += seg.t.len();
        let work = &pass.work;
        // The same operations in the same order as `composite`.
        let next: Vec<(f32, [f32; 3], f32)> = alive
            .par_iter()
            .enumerate()
            .map(|(i, &r)| {
                let (mut trans, mut c, mut d) = state[r];
                for k in seg.range(i) {
                    let tau = work.sigma[k] * seg.delta[k];
                    let w = trans * -(-tau).exp_m1();
                    for j in 0..3 {
                        c[j] += w * work.rgb[3 * k + j];
                    }
                    d += w * seg.t[k];
                    trans *= (-tau).exp();
                }
                (trans, c, d)
            })
            .collect();
        for (&r, s) in alive.iter().zip(next) {
            state[r] = s;
        }
        start += SEGMENT;
        alive.retain(|&r| state[r].0 >= stop && start < samples.range(r).len());
    }
    for ((((c, d), o), (trans, sum, dep)), bg) in colour
        .iter_mut()
        .zip(depth.iter_mut())
        .zip(opacity.iter_mut())
        .zip(state)
        .zip(backgrounds)
    {
        for j in 0..3 {
            c[j] = sum[j] + trans * bg[j];
        }
        *d = dep;
        *o = 1.0 - trans;
    }
    evaluated
}

impl TrainedField for Trained<NerfObjective> {
    fn render_view(
        &self,
        values: &[f32],
        cam: &Camera,
        size: ImageSize,
        _want_depth: bool,
    ) -> Result<View, String> {
        let (strat, last) = (&self.viewing.strat, self.viewing.sampler.last_interval);
        let v = self
            .objective
            .render_view(values, strat, last, cam, size)
            .map_err(|e| e.to_string())?;
        Ok(View {
            colour: v.colour,
            depth: v.depth,
            opacity: v.opacity,
        })
    }

    fn renders_opacity(&self) -> bool {
        true
    }

    fn radiance<'a>(
        &'a self,
        values: &'a [f32],
    ) -> Option<Box<dyn crate::export::RadianceField + 'a>> {
        let o = &self.objective;
        // The network that renders: the fine one where there is one.
        let net = o.fine.as_ref().map_or(&o.net, |(f, _)| f);
        Some(Box::new(crate::neural::nerf::NerfField {
            net,
            params: values,
        }))
    }

    fn region(&self) -> Option<Region> {
        self.viewing.region
    }

    fn reported(&self, _values: &[f32]) -> Vec<(String, Vec<f32>)> {
        Vec::new()
    }

    fn is_network(&self) -> bool {
        true
    }

    fn describe(&self) -> Description {
        let tensors = self.objective.tensors();
        Description {
            trainable: format!(
                "all {} weights in {} tensors{}",
                tensors.iter().map(|t| t.len).sum::<usize>(),
                tensors.len(),
                if self.objective.fine.is_some() {
                    " (coarse and fine networks)"
                } else {
                    ""
                }
            ),
            gradient: format!(
                "none: fused layer kernels with a hand-written backward through the network and the compositing; renders{} stop each ray once less than 1e-4 of its light is left",
                if self.objective.occupancy.is_some() {
                    " and training steps"
                } else {
                    ""
                }
            ),
            mesh_region: "the starting bounds grown by half".into(),
        }
    }
}
