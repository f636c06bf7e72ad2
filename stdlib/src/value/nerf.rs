//! Neural radiance fields and their parts: background, unbounded scenes, occupancy, precision.

use super::Encoding;

/// A neural radiance field: an MLP from the encoded position to density
/// (ReLU) and colour (sigmoid); with a direction encoding, colour also
/// sees the view direction through a narrower branch, density never does.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Nerf {
    /// The encoding of the sample position.
    pub position: Encoding,
    /// `Some` for a view-dependent colour.
    pub direction: Option<Encoding>,
    /// Hidden layers of the trunk and their width.
    pub layers: usize,
    /// Units per trunk layer.
    pub width: usize,
    /// Trunk layers whose input is the previous layer and the encoded
    /// position again.
    pub skips: Vec<usize>,
    /// Width of the colour branch.
    pub color_width: usize,
    /// Fine samples per ray drawn from the coarse network's weights and
    /// evaluated by a second network (0: no fine network).
    pub fine: usize,
    /// What a ray sees where it leaves the field.
    pub background: Background,
    /// Where `background` was written (the call's span when defaulted), for
    /// the `train` statement's agreement check.
    #[serde(skip)]
    pub background_at: WrittenAt,
    /// How positions of an unbounded scene reach the encoding: contracted
    /// (mip-NeRF 360) or in a forward-facing capture's NDC.
    pub unbounded: Option<Unbounded>,
    /// Seed of the initial weights.
    pub seed: u64,
    /// How the density head's output becomes a density.
    pub density: DensityActivation,
    /// Empty space skipped by an occupancy grid (coarse network only).
    pub occupancy: Option<OccupancySpec>,
    /// Number format of the layers' matrix products.
    pub precision: Precision,
}

impl Nerf {
    /// Trainable numbers of one network (the fine one doubles them):
    /// weights, biases and hash-grid tables.
    pub fn weights(&self) -> u64 {
        let grid = match &self.position {
            Encoding::HashGrid(g) => g.param_count(),
            Encoding::Harmonic(_) => 0,
        };
        let biases = self.layers * self.width + 1 + 2 * self.color_width + 3;
        grid + (self.multiply_adds_per_sample() + biases) as u64
    }

    /// Trainable numbers of the learned background (0 for a colour).
    pub fn background_weights(&self) -> u64 {
        match self.background {
            Background::Learned(l) => l.weights(),
            Background::Data | Background::Color(_) => 0,
        }
    }

    /// Multiply-adds of one sample's forward pass.
    pub fn multiply_adds_per_sample(&self) -> usize {
        let w = self.width;
        let mut macs = self.density_multiply_adds();
        macs += match self.direction {
            Some(d) => w * w + (w + d.width()) * self.color_width,
            None => w * self.color_width,
        };
        macs + self.color_width * 3
    }

    /// Multiply-adds of the density alone at a sample (the trunk and the
    /// density head, no colour): what an occupancy-grid refresh runs.
    pub fn density_multiply_adds(&self) -> usize {
        let (w, enc) = (self.width, self.position.width());
        enc * w + (self.layers - 1) * w * w + self.skips.len() * enc * w + w
    }
}

/// Training steps during which an occupancy grid's refreshes evaluate
/// every cell (and forget at the warm-up decay); after them a refresh
/// evaluates [`OCCUPANCY_SUBSETS`]'s share, as instant-ngp's does.
pub const OCCUPANCY_WARMUP: u64 = 256;
/// After warm-up a refresh evaluates one cell in this many (each cell
/// every this many refreshes): instant-ngp refreshes a quarter too. At
/// 128³ cells a full refresh every 16 steps was a third of a NeRF's
/// training time on Lego.
pub const OCCUPANCY_SUBSETS: u32 = 4;

/// Training steps before an unbounded scene's occupancy grid is first
/// refreshed: the field starts transparent, and the grid waits until it
/// has grown some density rather than emptying every cell at once. The
/// grid's warm-up ([`OCCUPANCY_WARMUP`]) counts from that first refresh.
pub const UNBOUNDED_GRID_START: u64 = 256;

/// The cells an occupancy grid of `cells` cells evaluates over
/// `iterations` training steps refreshed every `every` (at the steps that
/// are multiples of it), the first refresh at step `start` or after:
/// every cell during the [`OCCUPANCY_WARMUP`] steps from the first, a
/// share after.
pub fn occupancy_refresh_cells(cells: f64, iterations: f64, every: usize, start: u64) -> f64 {
    let every = every.max(1) as f64;
    let start = start as f64;
    // Refreshes are the steps k·every with first ≤ k < last.
    let first = (start / every).ceil();
    let last = (iterations / every).ceil().max(first);
    let warm_end = ((start + OCCUPANCY_WARMUP as f64) / every).ceil().min(last);
    let early = (warm_end - first).max(0.0);
    let late = last - first - early;
    (early + late / OCCUPANCY_SUBSETS as f64) * cells
}

/// Where a value was written in the source. Not part of the value: two
/// equal values written in different places are equal.
#[derive(Debug, Clone, Copy, Default)]
pub struct WrittenAt(pub sdfl_lang::Span);

impl PartialEq for WrittenAt {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// What a NeRF's rays see where they leave the field (their remaining
/// transmittance times this colour).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Background {
    /// The training data's (`data_background()`, the default): a `train`
    /// statement replaces it by its data set's ([`Dataset::background`](super::Dataset::background));
    /// black where nothing says otherwise (a field rendered outside a
    /// `train`, image files of unknown background).
    Data,
    /// A fixed colour.
    Color([f64; 3]),
    /// A colour learned from the ray's direction (for images without
    /// alpha, whose background is the world).
    Learned(LearnedBackground),
}

impl Background {
    /// The fixed colour: `Data` unresolved is black.
    pub fn color(&self) -> Option<[f64; 3]> {
        match self {
            Background::Data => Some([0.0; 3]),
            Background::Color(c) => Some(*c),
            Background::Learned(_) => None,
        }
    }
}

/// A learned background: the ray's unit direction, harmonically encoded
/// (`freqs` frequencies and the direction itself), through one ReLU layer
/// of `width` to a sigmoid colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct LearnedBackground {
    /// Frequencies of the direction's encoding.
    pub freqs: usize,
    /// Units of the hidden layer.
    pub width: usize,
}

impl LearnedBackground {
    /// Width of the encoded direction.
    pub fn input(&self) -> usize {
        3 * (2 * self.freqs + 1)
    }

    /// Multiply-adds per ray.
    pub fn multiply_adds(&self) -> usize {
        self.input() * self.width + self.width * 3
    }

    /// Trainable numbers.
    pub fn weights(&self) -> u64 {
        (self.multiply_adds() + self.width + 3) as u64
    }
}

/// Scene contraction (mip-NeRF 360, ∞-norm as nerfstudio and nerfacc use
/// it): the inner box `min`..`max` maps to [-1, 1]³, and with
/// `m = max |x_i|` every point beyond it to `(2 − 1/m)·x/m`, so all of
/// space fits in the cube [-2, 2]³ that the hash grid and the occupancy
/// grid then cover.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Contraction {
    /// The inner box's low corner.
    pub min: [f64; 3],
    /// The inner box's high corner.
    pub max: [f64; 3],
}

/// How a NeRF covers an unbounded scene. Serialised untagged: a
/// contraction's record is its box, as before NDC existed.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(untagged)]
pub enum Unbounded {
    /// Scene contraction (mip-NeRF 360).
    Contract(Contraction),
    /// Normalised device coordinates of a forward-facing capture's
    /// reference camera (NeRF's LLFF scenes): known once the capture is
    /// read (`None` until then).
    Ndc(Option<NdcFrame>),
}

impl Unbounded {
    /// The contraction, if this is one.
    pub fn contraction(&self) -> Option<&Contraction> {
        match self {
            Unbounded::Contract(c) => Some(c),
            Unbounded::Ndc(_) => None,
        }
    }
}

/// The camera NDC is taken from: a forward-facing capture's, in the scene
/// frame its normalisation made (the reference camera at the origin,
/// looking down −z), with its images' size and focal lengths in pixels.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct NdcFrame {
    /// Image width in pixels.
    pub width: f64,
    /// Image height in pixels.
    pub height: f64,
    /// Horizontal focal length in pixels.
    pub fx: f64,
    /// Vertical focal length in pixels.
    pub fy: f64,
    /// The depth of the near plane (NDC z = −1), in scene units.
    pub near: f64,
}

impl NdcFrame {
    /// The map's scales of x and y (`−2·fx/width`, `−2·fy/height`); an
    /// error for a degenerate focal length, image size or near plane. The
    /// one check of a frame, from a capture or a checkpoint alike.
    pub fn scales(&self) -> Result<(f64, f64), String> {
        let ax = -2.0 * self.fx / self.width;
        let ay = -2.0 * self.fy / self.height;
        let ok = |v: f64| v.is_finite() && v.abs() > 1e-6 && v.abs() < 1e6;
        if !(ok(ax) && ok(ay) && ok(self.near) && self.near > 0.0) {
            return Err(format!(
                "NDC needs positive focal lengths, image size and near plane (got fx {}, fy {}, {}x{}, near {})",
                self.fx, self.fy, self.width, self.height, self.near
            ));
        }
        Ok((ax, ay))
    }
}

/// Number format of a network's matrix products (weights, gradients and
/// the optimizer stay fp32 either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Precision {
    /// fp32 products.
    #[default]
    Fp32,
    /// Operands rounded to bfloat16 (round-to-nearest-even), sums in fp32;
    /// fp32 where the CPU lacks AVX-512 BF16.
    Bf16,
}

/// An occupancy grid (nerfacc-style): `resolution`³ cells over `min..max`
/// holding a decaying maximum of the field's density, refreshed every
/// `every` steps; samples fall at a fixed step only inside cells whose
/// density times the step exceeds `threshold`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct OccupancySpec {
    /// Cells a side.
    pub resolution: u32,
    /// The grid's low corner.
    pub min: [f64; 3],
    /// The grid's high corner.
    pub max: [f64; 3],
    /// A cell is occupied where density × step exceeds this (capped at
    /// the mean cell's where that is lower).
    pub threshold: f64,
    /// Training steps between refreshes.
    pub every: usize,
}

/// The density head's activation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DensityActivation {
    /// `max(x, 0)`, as the NeRF paper.
    Relu,
    /// `e^min(x, 15)`, as instant-ngp: never zero, so no sample starts dead.
    Exp,
    /// `ln(1 + e^x)`, as Mip-NeRF: smooth, and its gradient never vanishes.
    Softplus,
}

impl DensityActivation {
    /// The activation's usual name, for reports.
    pub fn name(self) -> &'static str {
        match self {
            DensityActivation::Relu => "ReLU",
            DensityActivation::Exp => "exponential",
            DensityActivation::Softplus => "softplus",
        }
    }
}
