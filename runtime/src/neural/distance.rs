//! A neural SDF as a model the trainer fits to a point cloud
//! ([`NeuralSdfObjective`]): each step's surface points come from the
//! batch, its random points are drawn in `[-bounds, bounds]³` from the
//! step's seed, and the loss (surface, eikonal with the exact input
//! gradient, off-surface) is [`SdfNet::loss_and_grad`]. After training,
//! [`fit`] measures how well the surface matches the points.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use sdfl_stdlib::value::{Loss, LossKind, NeuralSdf};
use sdfl_stdlib::work::{FIT_CHUNK, FIT_PROBES as PROBES, MESH_FIT_POINTS};

use super::sdf_net::{SdfLoss, SdfNet, SdfNetSpec, SdfWork};
use crate::mesh::DistanceField;
use crate::train::field::{Description, Region, View};
use crate::train::fused::Batch;
use crate::train::{Objective, TensorSpec, TrainError, Trained, TrainedField};
use crate::volume::SplitMix64;

/// The runtime network of a harmonic language spec (a hash grid's is a
/// [`super::hash_sdf::HashSdf`]: the trained field matches the encoding
/// before it asks for this).
pub fn sdf_net(spec: &NeuralSdf) -> SdfNet {
    let encoding = spec
        .harmonic()
        .expect("a harmonic neural SDF: the hash grid's network is built elsewhere");
    SdfNet::new(&SdfNetSpec {
        freqs: encoding.freqs,
        include_input: encoding.include_input,
        layers: spec.layers,
        width: spec.width,
        skips: spec.skips.clone(),
        beta: spec.beta as f32,
    })
}

/// The loss weights of a `train` statement's terms (summed per kind).
pub(crate) fn weights(losses: &[Loss]) -> SdfLoss {
    let mut w = SdfLoss {
        surface: 0.0,
        eikonal: 0.0,
        inter: 0.0,
        alpha: 100.0,
    };
    for l in losses {
        match l.kind {
            LossKind::Surface => w.surface += l.weight as f32,
            LossKind::Eikonal => w.eikonal += l.weight as f32,
            LossKind::Inter { alpha } => {
                w.inter += l.weight as f32;
                w.alpha = alpha as f32;
            }
            // The language keeps image terms off distance fields.
            LossKind::Mse | LossKind::Silhouette => {}
        }
    }
    w
}

/// A point fit's step: refuses a batch without points, else draws as many
/// random points as it has, from the step's seed, into `out`. Every neural
/// SDF's point fit draws here, so each sees the same points at a step.
pub fn step_random_points(
    batch: &Batch,
    bounds: f32,
    out: &mut Vec<f32>,
) -> Result<(), TrainError> {
    if batch.points.is_empty() {
        return Err(TrainError::Invalid(
            "a neural SDF trains on points, and the batch has none".into(),
        ));
    }
    let mut rng = SplitMix64::new(batch.seed ^ 0x7361_6d70_6c65);
    random_points(batch.points.len() / 3, bounds, &mut rng, out);
    Ok(())
}

/// `n` points uniform in `[-bounds, bounds]³`, rows of 3.
pub fn random_points(n: usize, bounds: f32, rng: &mut SplitMix64, out: &mut Vec<f32>) {
    out.clear();
    out.extend((0..3 * n).map(|_| (2.0 * rng.next_f32() - 1.0) * bounds));
}

/// A neural SDF being fitted to points.
pub struct NeuralSdfObjective {
    /// The network and where its parameters lie.
    pub net: SdfNet,
    spec: NeuralSdf,
    weights: SdfLoss,
    bounds: f32,
    work: SdfWork,
    random: Vec<f32>,
}

impl NeuralSdfObjective {
    /// An objective for `spec` with the `losses` terms, drawing random points
    /// in the cube of half-extent `bounds`.
    pub fn new(spec: &NeuralSdf, losses: &[Loss], bounds: f64) -> Self {
        NeuralSdfObjective {
            net: sdf_net(spec),
            spec: spec.clone(),
            weights: weights(losses),
            bounds: bounds as f32,
            work: SdfWork::default(),
            random: Vec::new(),
        }
    }
}

impl Objective for NeuralSdfObjective {
    fn tensors(&self) -> Vec<TensorSpec> {
        self.net
            .layers()
            .into_iter()
            .flat_map(|(name, d)| d.tensors(&name))
            .collect()
    }

    fn initial(&self) -> Vec<f32> {
        self.net
            .init_geometric(self.spec.seed, self.spec.radius as f32)
    }

    fn loss_and_grad(
        &mut self,
        values: &[f32],
        batch: &Batch,
        weight: f64,
        grad: &mut [f32],
    ) -> Result<f64, TrainError> {
        step_random_points(batch, self.bounds, &mut self.random)?;
        let w = self.weights;
        let scale = weight as f32;
        let scaled = SdfLoss {
            surface: w.surface * scale,
            eikonal: w.eikonal * scale,
            inter: w.inter * scale,
            alpha: w.alpha,
        };
        // The trainer weighs image terms by their sum; here each term
        // carries its own weight, so `weight` is 1 unless scaled on purpose.
        Ok(self.net.loss_and_grad(
            values,
            &batch.points,
            &self.random,
            &scaled,
            &mut self.work,
            grad,
        ))
    }
}

pub use crate::metrics::SdfFit;

/// Measures `net` at `params` against `points`: |f| and the eikonal term
/// there, and the Chamfer distance to surface samples found by projecting
/// random points in `[-bounds, bounds]³` along the gradient
/// (`p ← p − f(p)·∇f(p)/‖∇f(p)‖²`, a few times), keeping those that land
/// within 1e-3 of the surface.
pub fn fit(net: &SdfNet, params: &[f32], points: &[[f32; 3]], bounds: f32, seed: u64) -> SdfFit {
    let mut work = SdfWork::default();
    fit_with(
        &mut |flat| distances_and_gradients(net, params, flat, &mut work),
        points,
        bounds,
        seed,
    )
}

/// `f` and `∇f` (three a point) at flat points (rows of 3).
pub type DistanceGradients<'a> = dyn FnMut(&[f32]) -> (Vec<f32>, Vec<f32>) + 'a;

/// [`fit`] for any field whose `f` and `∇f` at flat points `eval` gives.
pub fn fit_with(
    eval: &mut DistanceGradients<'_>,
    points: &[[f32; 3]],
    bounds: f32,
    seed: u64,
) -> SdfFit {
    let flat: Vec<f32> = points.iter().flatten().copied().collect();
    let (f, g) = eval(&flat);
    let n = points.len().max(1) as f64;
    let surface_mean_abs = f.iter().map(|f| f.abs() as f64).sum::<f64>() / n;
    let eik = |g: &[f32]| {
        g.chunks(3)
            .map(|g| {
                let len = ((g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) as f64).sqrt();
                (len - 1.0).powi(2)
            })
            .sum::<f64>()
    };
    let mut eikonal = eik(&g);
    let mut rng = SplitMix64::new(seed ^ 0x6368_616d);
    let mut probe = Vec::new();
    random_points(points.len(), bounds, &mut rng, &mut probe);
    let (_, g) = eval(&probe);
    eikonal = (eikonal + eik(&g)) / (2.0 * n);
    // Many probes, so the surface samples are dense next to the points
    // (sparse samples would bias the Chamfer distance upwards).
    random_points(PROBES.max(points.len()), bounds, &mut rng, &mut probe);
    let (mut f, mut g) = eval(&probe);
    for _ in 0..8 {
        for (i, p) in probe.chunks_mut(3).enumerate() {
            let gi = &g[3 * i..3 * i + 3];
            let len2 = (gi[0] * gi[0] + gi[1] * gi[1] + gi[2] * gi[2]).max(1e-12);
            for k in 0..3 {
                p[k] -= f[i] * gi[k] / len2;
            }
        }
        (f, g) = eval(&probe);
    }
    let found: Vec<[f32; 3]> = probe
        .chunks(3)
        .zip(&f)
        .filter(|(p, f)| f.abs() < 1e-3 && p.iter().all(|x| x.is_finite() && x.abs() <= bounds))
        .map(|(p, _)| [p[0], p[1], p[2]])
        .collect();
    let chamfer = if found.is_empty() {
        f64::INFINITY
    } else {
        0.5 * (mean_nearest(&found, points) + mean_nearest(points, &found))
    };
    SdfFit {
        surface_mean_abs,
        eikonal,
        chamfer,
        surface_samples: found.len(),
    }
}

/// `f` and `∇f` (three a point) at the flat `points`, [`FIT_CHUNK`] rows
/// at a time (rows are independent, so the values are those of one pass).
fn distances_and_gradients(
    net: &SdfNet,
    params: &[f32],
    points: &[f32],
    work: &mut SdfWork,
) -> (Vec<f32>, Vec<f32>) {
    let rows = points.len() / 3;
    let (mut f, mut g) = (Vec::with_capacity(rows), Vec::with_capacity(3 * rows));
    for chunk in points.chunks(3 * FIT_CHUNK) {
        net.forward(params, chunk, work);
        f.extend_from_slice(work.distance());
        g.extend_from_slice(work.gradient());
    }
    (f, g)
}

/// A mesh against the points it should pass through.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MeshFit {
    /// Symmetric Chamfer distance: the mean of both directions' mean
    /// distance to the other side.
    pub chamfer: f64,
    /// Mean distance from a reference point to the mesh, and back.
    pub points_to_mesh: f64,
    /// Mean distance from a mesh sample to the reference: to its nearest
    /// point, or to the reference surface.
    pub mesh_to_points: f64,
    /// What the points are from: "data" or "true surface".
    pub against: &'static str,
    /// Points and mesh samples compared.
    pub points: usize,
    /// Mesh samples compared.
    pub samples: usize,
}

/// What a mesh is measured against.
pub enum Reference<'a> {
    /// Data points (the Chamfer distance to a point set: the mesh side's
    /// distances are to the nearest point).
    Points(&'a [[f32; 3]]),
    /// Another surface (the true one), as a mesh.
    Surface(&'a crate::mesh::Mesh),
}

/// How well `mesh` passes through `reference`: the chamfer distance both
/// ways (`against` names the reference in reports; `seed` picks samples).
/// Distances to a mesh are exact (to its triangles); distances to points
/// are to the nearest point.
pub fn mesh_fit(
    mesh: &crate::mesh::Mesh,
    reference: Reference,
    against: &'static str,
    seed: u64,
) -> MeshFit {
    use crate::mesh::MeshDistance;
    let queries: Vec<[f32; 3]> = match reference {
        Reference::Points(p) => {
            let every = p.len().div_ceil(MESH_FIT_POINTS).max(1);
            p.iter().step_by(every).copied().collect()
        }
        Reference::Surface(m) => m.sample_surface(MESH_FIT_POINTS, seed ^ 0x0074_7275_7468),
    };
    let samples = mesh.sample_surface(MESH_FIT_POINTS.min(4 * queries.len()).max(1000), seed);
    let to_mesh = MeshDistance::new(mesh).map_or(f64::INFINITY, |m| m.mean_distance(&queries));
    let to_points = if samples.is_empty() {
        f64::INFINITY
    } else {
        match reference {
            Reference::Points(p) => mean_nearest(&samples, p),
            Reference::Surface(m) => {
                MeshDistance::new(m).map_or(f64::INFINITY, |m| m.mean_distance(&samples))
            }
        }
    };
    MeshFit {
        chamfer: 0.5 * (to_mesh + to_points),
        points_to_mesh: to_mesh,
        mesh_to_points: to_points,
        against,
        points: queries.len(),
        samples: samples.len(),
    }
}

/// Mean over `a` of the distance to the nearest point of `b` (exact, by a
/// k-d tree over `b`; infinite when `b` is empty).
pub fn mean_nearest(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    if b.is_empty() {
        return f64::INFINITY;
    }
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(b);
    // Sums of fixed chunks, added in order: the same at any thread count.
    let sums: Vec<f64> = a
        .par_chunks(4096)
        .map(|c| {
            c.iter()
                .map(|p| (tree.nearest_one::<SquaredEuclidean>(p).distance as f64).sqrt())
                .sum()
        })
        .collect();
    sums.iter().sum::<f64>() / a.len().max(1) as f64
}

/// The surface of `net` at `params` traced from `cam` out to `far`,
/// normals as colours.
pub fn geometry_view(
    net: &SdfNet,
    params: &[f32],
    cam: &sdfl_stdlib::camera::Camera,
    size: crate::volume::ImageSize,
    far: f64,
) -> Result<TracedView, String> {
    let settings = TraceSettings {
        far: far as f32,
        ..Default::default()
    };
    trace_view(net, params, cam, size, settings).map_err(|e| e.to_string())
}

impl TrainedField for Trained<NeuralSdfObjective> {
    fn render_view(
        &self,
        values: &[f32],
        cam: &sdfl_stdlib::camera::Camera,
        size: crate::volume::ImageSize,
        _want_depth: bool,
    ) -> Result<View, String> {
        let far = self.viewing.sampler.far;
        let v = geometry_view(&self.objective.net, values, cam, size, far)?;
        Ok(View {
            colour: v.colour,
            depth: v.depth,
            opacity: Vec::new(),
        })
    }

    fn surface<'a>(&'a self, values: &'a [f32]) -> Option<Box<dyn DistanceField + 'a>> {
        let net = &self.objective.net;
        // Trained with the eikonal term, not bounded: a margin of 2.
        let field = NetDistance {
            net,
            params: values,
        };
        Some(Box::new(crate::mesh::Lipschitz(field, 2.0)))
    }

    fn region(&self) -> Option<Region> {
        self.viewing.region
    }

    fn geometry_view(
        &self,
        values: &[f32],
        cam: &sdfl_stdlib::camera::Camera,
        size: crate::volume::ImageSize,
    ) -> Option<Result<Vec<[f32; 3]>, String>> {
        let net = &self.objective.net;
        let far = self.viewing.sampler.far;
        Some(geometry_view(net, &values[..net.len], cam, size, far).map(|v| v.colour))
    }

    fn reported(&self, _values: &[f32]) -> Vec<(String, Vec<f32>)> {
        Vec::new()
    }

    fn fit_to_points(&self, values: &[f32], points: &[[f32; 3]], seed: u64) -> Option<SdfFit> {
        let o = &self.objective;
        Some(fit(&o.net, values, points, o.bounds, seed))
    }

    fn is_network(&self) -> bool {
        true
    }

    fn describe(&self) -> Description {
        Description {
            trainable: format!(
                "all {} weights, starting as a sphere of radius {}",
                self.objective.net.len, self.objective.spec.radius
            ),
            gradient: "none: the exact gradient of f by a reverse pass in the forward; a hand-written reverse-over-reverse backward".into(),
            mesh_region: "the points' box grown by a tenth of its diagonal".into(),
        }
    }
}

/// A network at `params` as a distance field: values alone, or with the
/// exact gradient.
pub struct NetDistance<'a> {
    /// The network.
    pub net: &'a SdfNet,
    /// Its parameters.
    pub params: &'a [f32],
}

impl crate::mesh::DistanceField for NetDistance<'_> {
    fn distances(&self, points: &[[f32; 3]], out: &mut [f32]) {
        self.net.distance(self.params, points.as_flattened(), out);
    }

    fn gradients(&self, points: &[[f32; 3]], _h: f32, f: &mut [f32], g: &mut [[f32; 3]]) {
        let mut work = SdfWork::default();
        self.net
            .forward(self.params, points.as_flattened(), &mut work);
        f.copy_from_slice(work.distance());
        g.as_flattened_mut().copy_from_slice(work.gradient());
    }
}

/// How a neural SDF is sphere-traced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceSettings {
    /// Where rays start.
    pub near: f32,
    /// Where rays give up: farther is a miss.
    pub far: f32,
    /// Most steps per ray.
    pub iterations: usize,
    /// A ray hits when |f| falls below this.
    pub epsilon: f32,
    /// Steps are `safety·f`: a trained network is only roughly 1-Lipschitz.
    pub safety: f32,
}

impl Default for TraceSettings {
    fn default() -> Self {
        TraceSettings {
            near: 0.0,
            far: 8.0,
            iterations: 96,
            epsilon: 1e-3,
            safety: 0.9,
        }
    }
}

/// A sphere-traced view of a neural SDF: normals shaded as colours
/// (`(n + 1)/2`, black where rays miss) and hit depth (0 on misses).
pub struct TracedView {
    /// Colour per pixel, row by row.
    pub colour: Vec<[f32; 3]>,
    /// Hit depth per pixel (0 on misses).
    pub depth: Vec<f32>,
}

/// Rays per network pass when tracing (bounds the buffers).
const TRACE_ROWS: usize = 1 << 14;

/// Sphere-traces `net` at `params` from `cam`: a wavefront, every step
/// evaluating the distance at all rays still marching, in bounded batches;
/// the exact gradient (the normal) only where rays hit.
pub fn trace_view(
    net: &SdfNet,
    params: &[f32],
    cam: &sdfl_stdlib::camera::Camera,
    size: crate::volume::ImageSize,
    s: TraceSettings,
) -> Result<TracedView, crate::volume::VolumeError> {
    trace_field(&NetDistance { net, params }, cam, size, s)
}

/// [`trace_view`] for any distance field with an exact gradient.
pub fn trace_field(
    field: &dyn DistanceField,
    cam: &sdfl_stdlib::camera::Camera,
    size: crate::volume::ImageSize,
    s: TraceSettings,
) -> Result<TracedView, crate::volume::VolumeError> {
    let rays = crate::volume::camera_rays(cam, size)?;
    let n = rays.len();
    let mut t = vec![s.near; n];
    let mut view = TracedView {
        colour: vec![[0.0; 3]; n],
        depth: vec![0.0; n],
    };
    let mut active: Vec<usize> = (0..n).collect();
    let (mut points, mut f, mut hits): (Vec<[f32; 3]>, _, _) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..s.iterations {
        if active.is_empty() {
            break;
        }
        points.clear();
        for &r in &active {
            let ray = &rays[r];
            points.push(std::array::from_fn(|k| ray.origin[k] + t[r] * ray.dir[k]));
        }
        // Distances alone (no tangents), a bounded batch at a time.
        f.resize(active.len(), 0.0);
        for (p, f) in points.chunks(TRACE_ROWS).zip(f.chunks_mut(TRACE_ROWS)) {
            field.distances(p, f);
        }
        let mut still = Vec::with_capacity(active.len());
        for (i, &r) in active.iter().enumerate() {
            if f[i].abs() < s.epsilon {
                hits.push(r);
            } else {
                t[r] += s.safety * f[i];
                if t[r] < s.far && t[r].is_finite() {
                    still.push(r);
                }
            }
        }
        active = still;
    }
    // Normals where the rays hit: the exact gradient there.
    let mut g = Vec::new();
    for block in hits.chunks(TRACE_ROWS) {
        points.clear();
        for &r in block {
            let ray = &rays[r];
            points.push(std::array::from_fn(|k| ray.origin[k] + t[r] * ray.dir[k]));
        }
        f.resize(block.len(), 0.0);
        g.resize(block.len(), [0.0; 3]);
        field.gradients(&points, 0.0, &mut f, &mut g);
        for (&r, g) in block.iter().zip(&g) {
            let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt().max(1e-12);
            view.colour[r] = [0, 1, 2].map(|k| 0.5 * (g[k] / len + 1.0));
            view.depth[r] = t[r];
        }
    }
    Ok(view)
}
