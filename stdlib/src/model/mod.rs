//! Model kinds: what a trainable field (an analytic SDF volume, a NeRF, a
//! neural SDF, a neural surface) says about itself to the plan and the
//! cost model. Each kind is one [`Model`] implementation in its own file;
//! [`Field::model`] is the one place that tells the kinds apart, so a new
//! kind is one file and one arm there, and the compiler asks for every
//! answer.

use crate::value::{Backend, DataBackground, Field, Precision};
use crate::work::Cost;

mod analytic;
mod nerf;
mod neural_sdf;
mod surface;

/// Samples a network render or grid refresh evaluates in one pass.
pub(crate) const NETWORK_PASS: f64 = 65_536.0;
/// Most samples one network pass of a NeRF's training step holds: a batch
/// with more (a fine step, or every cell occupied before the grid's first
/// refresh) is fitted in passes of whole rays whose gradients add up, so
/// a step's memory is bounded by this and not by rays × samples
/// (instant-ngp keeps 2^18 samples a step).
pub const TRAIN_PASS_SAMPLES: usize = 1 << 18;

/// What the plan and the cost model ask of a model kind. Costs are in
/// evaluations (one analytic primitive's distance, or
/// [`crate::work::MULTIPLY_ADDS_PER_EVALUATION`] of a network's
/// multiply-adds); memory in bytes.
pub trait Model {
    /// The plan's line on what the model is and computes;
    /// `layer_precision` says how this machine runs the layers' products
    /// at a precision asked for.
    fn describe(&self, layer_precision: &dyn Fn(Precision) -> String) -> String;

    /// What a data set rendered from this field composites over.
    fn data_background(&self) -> DataBackground;

    /// The region `bounds: "auto"` stands for in a `density_mesh`: a hash
    /// grid's box, else an occupancy grid's, else an analytic field's
    /// bounds; none where there is no density to mesh or no box.
    fn export_region(&self) -> Option<([f64; 3], [f64; 3])> {
        None
    }

    /// The object's region, where a point cloud with `crop: "auto"` keeps
    /// its points: an unbounded NeRF's inner box, else the export region.
    fn object_region(&self) -> Option<([f64; 3], [f64; 3])> {
        self.export_region()
    }

    /// Evaluations one sample of a volume render costs.
    fn volume_sample(&self) -> f64;

    /// Bytes a volume render of this field holds besides its images: a
    /// network's activations for a pass and its weights.
    fn volume_buffers(&self) -> f64;

    /// Evaluations one point of a geometry query (a mesh cell, a
    /// sphere-tracing step) costs: a distance with its gradient for a
    /// neural distance.
    fn geometry_point(&self) -> f64;

    /// Evaluations one ray sample of a field export (density meshes,
    /// point clouds, depth) costs.
    fn export_sample(&self) -> f64;

    /// Evaluations one pixel of a rendered view of the trained model costs
    /// with `samples` samples a ray.
    fn render_pixel(&self, samples: f64) -> f64;

    /// Bytes of the buffers a render of the trained model holds (one pass).
    fn render_buffers(&self) -> f64;

    /// Whether a trained model's depth exports come from its renders
    /// (skipping empty space, stopping opaque rays) rather than a march of
    /// every sample.
    fn renders_depth(&self) -> bool {
        false
    }

    /// Evaluations one training ray costs (forward and backward), with
    /// `samples` samples a ray and `params` trainable scalars of an
    /// analytic field.
    fn train_ray(&self, samples: f64, params: usize) -> f64;

    /// Bytes a training batch of `rays` rays of `samples` samples holds
    /// beyond the per-ray buffers every model keeps.
    fn batch_bytes(&self, rays: f64, samples: f64, backend: Backend) -> f64;

    /// Trainable numbers (an analytic field's `params` scalars).
    fn trained_numbers(&self, params: usize) -> f64;

    /// Cells of a grid the model keeps beside its weights (an occupancy
    /// grid, a surface's empty-space grid); 0 for none.
    fn grid_cells(&self) -> f64 {
        0.0
    }

    /// The work of refreshing that grid over `iterations` training steps.
    fn grid_refresh(&self, _iterations: f64) -> Cost {
        Cost::default()
    }

    /// The share of samples expected to reach the networks (the rest
    /// skipped as empty space).
    fn expected_share(&self) -> f64 {
        1.0
    }

    /// How long a training evaluation takes against the machine's
    /// calibrated rate: measured by `plan` against `run` on the examples
    /// (docs/results.md, "plan's times"). Hash grids spend their time
    /// gathering table rows, which a count of multiply-adds misses.
    fn training_pace(&self) -> f64;

    /// Bytes each training thread keeps as scratch.
    fn thread_scratch(&self) -> f64 {
        0.0
    }

    /// Whether training runs dense matrix products whose per-thread
    /// packing buffers count ([`crate::work::Host`]).
    fn uses_matmul(&self, _backend: Backend) -> bool {
        false
    }

    /// Whether training fits a point cloud (surface and random points)
    /// rather than rays.
    fn trains_on_points(&self) -> bool {
        false
    }

    /// The work after training of measuring the fit (a neural SDF's
    /// points projected onto its surface); none for most.
    fn fit_work(&self) -> Cost {
        Cost::default()
    }
}

impl Field {
    /// The field as a model kind: the one place the kinds are told apart.
    pub fn model(&self) -> &dyn Model {
        match self {
            Field::Sdf(f) => f,
            Field::Nerf(n) => n,
            Field::NeuralSdf(n) => n,
            Field::NeuralSurface(n) => n,
        }
    }
}

/// A network pass of `multiply_adds`, in evaluations (at least one).
pub(crate) fn network(multiply_adds: usize) -> f64 {
    (multiply_adds as f64 / crate::work::MULTIPLY_ADDS_PER_EVALUATION).max(1.0)
}

/// An encoding as the plan writes it.
pub(crate) fn describe_encoding(e: &crate::value::Encoding) -> String {
    use crate::value::Encoding;
    match e {
        Encoding::Harmonic(h) => format!(
            "harmonic({}{})",
            h.freqs,
            if h.include_input { "" } else { ", no input" }
        ),
        Encoding::HashGrid(g) => format!(
            "hashgrid({} levels x {} features, 2^{} rows, {}..{} cells a side)",
            g.levels, g.features, g.log2_table, g.min_res, g.max_res
        ),
    }
}
