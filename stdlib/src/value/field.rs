//! Fields: volumes a ray marches through (analytic SDFs, neural SDFs and surfaces).

use std::sync::Arc;

use super::{Encoding, Harmonic, Nerf};
use crate::density::DensityKind;
use crate::material::Material;
use crate::param::Arg;
use crate::shape::Shape;

/// A field: something a ray marches through, with density and colour.
#[derive(Debug, Clone)]
#[allow(
    clippy::large_enum_variant,
    reason = "a program holds a few fields, built once and matched by reference"
)]
pub enum Field {
    /// An analytic SDF seen as a volume.
    Sdf(SdfField),
    /// A neural radiance field.
    Nerf(Nerf),
    /// A neural signed distance function.
    NeuralSdf(NeuralSdf),
    /// A neural SDF seen as a volume with a learned colour (VolSDF, NeuS).
    NeuralSurface(NeuralSurface),
}

impl Field {
    /// The region `bounds: "auto"` stands for in a `density_mesh`
    /// ([`crate::model::Model::export_region`]).
    pub fn export_region(&self) -> Option<([f64; 3], [f64; 3])> {
        self.model().export_region()
    }

    /// The object's region, where a point cloud with `crop: "auto"` keeps
    /// its points ([`crate::model::Model::object_region`]).
    pub fn object_region(&self) -> Option<([f64; 3], [f64; 3])> {
        self.model().object_region()
    }

    /// Every trainable `param(...)` argument of the field, in a fixed
    /// order; a parameter used twice appears twice. (A neural field's
    /// weights are not `param`s: they are trained whenever it is a model.)
    pub fn visit_params<'s>(&'s self, f: &mut dyn FnMut(&'s crate::param::ParamUse)) {
        if let Field::Sdf(s) = self {
            s.visit_params(f);
        }
    }

    /// The analytic SDF field, if it is one.
    pub fn as_sdf(&self) -> Option<&SdfField> {
        match self {
            Field::Sdf(s) => Some(s),
            Field::Nerf(_) | Field::NeuralSdf(_) | Field::NeuralSurface(_) => None,
        }
    }
}

/// An SDF seen as a volume with a colour.
#[derive(Debug, Clone)]
pub struct SdfField {
    /// The shape whose distance becomes density.
    pub shape: Arc<Shape>,
    /// How distance becomes density.
    pub density: DensityKind,
    /// Density scale α, possibly trained.
    pub alpha: Arg<f64>,
    /// Sharpness β (the density's falloff width), possibly trained.
    pub beta: Arg<f64>,
    /// The colour of samples whose primitive has no material of its own
    /// (an unlit material's colour at the point).
    pub color: Arc<Material>,
}

impl SdfField {
    /// Every trainable argument of the field (shape, colour, α, β), in a
    /// fixed order; a parameter used twice appears twice.
    pub fn visit_params<'s>(&'s self, f: &mut dyn FnMut(&'s crate::param::ParamUse)) {
        self.shape.visit_params(f);
        self.color.visit_params(f);
        for a in [&self.alpha, &self.beta] {
            if let Some(u) = &a.param {
                f(u);
            }
        }
    }
}

/// A neural signed distance function (IGR; the course assignment's part 6):
/// the encoded point, `layers` hidden softplus layers of `width` (the
/// encoding again at the skips), a linear distance; it starts as the SDF
/// of a sphere of `radius`. With a harmonic encoding the weights describe
/// the sphere (geometric initialisation); with a hash grid (NeuS2,
/// instant-nsr) the network adds a residual to the sphere's distance.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct NeuralSdf {
    /// The encoding of the point: harmonic, or a hash grid.
    pub encoding: Encoding,
    /// Hidden softplus layers.
    pub layers: usize,
    /// Units per hidden layer.
    pub width: usize,
    /// Layers (from 1) that see the encoding again.
    pub skips: Vec<usize>,
    /// Softplus sharpness: large is close to ReLU with smooth curvature.
    pub beta: f64,
    /// Radius of the sphere the initial weights describe.
    pub radius: f64,
    /// Seed of the initial weights.
    pub seed: u64,
    /// A hash grid's levels switched on coarse to fine: one more every
    /// this many steps from a quarter of them (0: all from the start).
    pub level_every: usize,
    /// The eikonal term's `∇f` on a hash grid by central differences of
    /// this step (Neuralangelo); `None`: exact.
    pub eikonal_step: Option<f64>,
}

impl NeuralSdf {
    /// Points a hash-grid network's blocked passes take at once.
    pub const BLOCK_ROWS: usize = 128;

    /// Bytes each thread keeps to take the exact gradient of a hash-grid
    /// network through a volume (its blocked scratch: the features with
    /// three tangents, each hidden layer's values, tangents and adjoints);
    /// 0 for a harmonic encoding or central differences, which keep none.
    pub fn thread_scratch(&self) -> usize {
        match (&self.encoding, self.eikonal_step) {
            (Encoding::HashGrid(_), None) => {
                let (e, w) = (self.encoding_width(), self.width);
                let values = 4 * e + 8 * w * self.layers + 4;
                let adjoints = 12 * e.max(w);
                4 * Self::BLOCK_ROWS * (values + adjoints)
            }
            _ => 0,
        }
    }

    /// Width of the encoded point.
    pub fn encoding_width(&self) -> usize {
        self.encoding.width()
    }

    /// The harmonic encoding, where it is one.
    pub fn harmonic(&self) -> Option<Harmonic> {
        match self.encoding {
            Encoding::Harmonic(h) => Some(h),
            Encoding::HashGrid(_) => None,
        }
    }

    /// Multiply-adds of one point's distance (its gradient costs three
    /// more); a hash grid interpolates eight corners a level.
    pub fn multiply_adds(&self) -> usize {
        let (e, w) = (self.encoding_width(), self.width);
        let lookups = match &self.encoding {
            Encoding::HashGrid(g) => (g.levels * 8 * (g.features + 4)) as usize,
            Encoding::Harmonic(_) => 0,
        };
        lookups + e * w + (self.layers - 1) * w * w + self.skips.len() * e * w + w
    }

    /// Trainable numbers: the layers' weights and biases, and a hash
    /// grid's tables.
    pub fn weights(&self) -> u64 {
        let (e, w) = (self.encoding_width(), self.width);
        let layers = e * w + (self.layers - 1) * w * w + self.skips.len() * e * w + w;
        let biases = self.layers * w + 1;
        let grid = match &self.encoding {
            Encoding::HashGrid(g) => g.param_count(),
            Encoding::Harmonic(_) => 0,
        };
        grid + (layers + biases) as u64
    }
}

/// The hidden layers of a multilayer perceptron: `layers` of `width`, the
/// layers in `skips` (from 1) seeing the network's input again. The field
/// that holds it decides the input, the activation and the heads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Mlp {
    /// Hidden layers.
    pub layers: usize,
    /// Units per hidden layer.
    pub width: usize,
    /// Layers (from 1) that see the input again.
    pub skips: Vec<usize>,
}

/// A neural SDF rendered as a volume, trained from images (VolSDF, Yariv et
/// al. 2021; NeuS-style density): density from the distance as for analytic
/// fields, colour from a small network that sees the encoded point, the
/// SDF's gradient (the surface normal) and, when `view_dependent`, the
/// encoded view direction.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct NeuralSurface {
    /// The distance network.
    pub sdf: NeuralSdf,
    /// A density that takes a neural SDF ([`DensityKind::neural`]).
    pub density: DensityKind,
    /// Density scale α (the density inside, far from the surface).
    pub alpha: f64,
    /// The starting β when `train_beta`.
    pub beta: f64,
    /// β is trained with the networks (as `log β`, so it stays positive).
    pub train_beta: bool,
    /// A fixed β that falls geometrically from `beta` at the first step to
    /// this at the last (`None`: β stays `beta`, or is trained).
    pub beta_end: Option<f64>,
    /// The colour network: `color_layers` hidden ReLU layers of
    /// `color_width`, sigmoid colour; the point encoded with
    /// `color_freqs` harmonics, the direction with 2.
    pub color_layers: usize,
    /// Width of the colour network's hidden layers.
    pub color_width: usize,
    /// Harmonic frequencies of the point the colour network sees.
    pub color_freqs: usize,
    /// Whether colour also sees the view direction.
    pub view_dependent: bool,
    /// Seen through wherever the volume is not opaque.
    pub background: [f64; 3],
    /// Samples per ray added near the surface by inverse CDF on the
    /// weights of a distance-only pass (0: the stratified samples alone).
    pub fine: usize,
}

impl NeuralSurface {
    /// Harmonic frequencies of the view direction.
    pub const DIRECTION_FREQS: usize = 2;
    /// Cells a side of the grid that skips empty space over a hash-grid
    /// SDF's box.
    pub const SKIP_CELLS: u32 = 32;
    /// Training steps between refreshes of that grid.
    pub const SKIP_EVERY: usize = 8;

    /// Whether empty space is skipped (a hash-grid SDF, whose box the grid
    /// tiles).
    pub fn skips_empty_space(&self) -> bool {
        matches!(self.sdf.encoding, Encoding::HashGrid(_))
    }

    /// Width of the colour network's input.
    pub fn color_input(&self) -> usize {
        let dir = if self.view_dependent {
            3 + 6 * Self::DIRECTION_FREQS
        } else {
            0
        };
        3 + 6 * self.color_freqs + 3 + dir
    }

    /// Multiply-adds of the colour network per sample.
    pub fn color_multiply_adds(&self) -> usize {
        let w = self.color_width;
        self.color_input() * w + (self.color_layers - 1) * w * w + 3 * w
    }

    /// Trainable numbers: the distance network's (its hash tables
    /// included), the colour network's and a trained β.
    pub fn weights(&self) -> u64 {
        let colour = self.color_multiply_adds() + self.color_layers * self.color_width + 3;
        self.sdf.weights() + colour as u64 + u64::from(self.train_beta)
    }

    /// Multiply-adds of one sample: the distance with its gradient (four
    /// passes' worth) and the colour.
    pub fn multiply_adds_per_sample(&self) -> usize {
        4 * self.sdf.multiply_adds() + self.color_multiply_adds()
    }
}
