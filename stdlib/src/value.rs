//! Runtime values of the scene language and the scene IR they build.

use std::path::PathBuf;
use std::sync::Arc;

use glam::DVec3;

use crate::camera::Camera;
use crate::material::Material;
use crate::param::{Arg, ParamDecl};
use crate::shape::Shape;

#[derive(Debug, Clone)]
/// A value of the scene language: what an expression evaluates to.
pub enum Value {
    /// A number (f64 while evaluating; checked to fit f32 where the runtime uses it).
    Number(f64),
    /// `true` or `false`.
    Bool(bool),
    /// A string (paths, names, options such as `"bf16"`).
    Str(Arc<str>),
    /// A list; three numbers are also a vector.
    List(Arc<Vec<Value>>),
    /// A signed distance shape.
    Shape(Arc<Shape>),
    /// How a surface is shaded.
    Material(Arc<Material>),
    /// A directional light of a `phong` material.
    Light(crate::material::Light),
    /// Soft shadows of a lit material.
    Shadows(crate::effects::SoftShadows),
    /// Ambient occlusion of a lit material.
    Occlusion(crate::effects::AmbientOcclusion),
    /// Fog of a `render`.
    Fog(crate::effects::Fog),
    /// A camera (`look_at`, `orbit`'s items…).
    Camera(Camera),
    /// An output file a statement writes.
    Output(Arc<Output>),
    /// A number or vector marked trainable with `param(...)`.
    Param(Arc<ParamDecl>),
    /// A training objective term.
    Loss(Loss),
    /// A volume: an SDF seen as one, or a neural field.
    Field(Arc<Field>),
    /// Where samples fall along each ray.
    Sampler(Sampler),
    /// The images (or points) a `train` fits.
    Dataset(Arc<Dataset>),
    /// The optimiser of a `train`.
    Optimizer(Optimizer),
    /// A neural field's input encoding.
    Encoding(Encoding),
    /// An occupancy grid that skips empty space.
    Occupancy(OccupancySpec),
    /// The shape of a network's hidden layers, for `nerf(network: ...)` and
    /// `neural_sdf(network: ...)`.
    Network(Arc<Mlp>),
    /// What a NeRF's rays see behind the field: `data_background()`,
    /// `learned_background(...)` (a colour is a vector).
    Background(Background),
    /// Scene contraction for unbounded scenes: `contraction(...)`.
    Contraction(Contraction),
    /// Forward-facing scenes in normalised device coordinates: `ndc()`.
    Ndc,
    /// Cameras known only when a `train` runs (a loop through the training
    /// cameras of a data set read from files), as its `views`.
    ViewPath(ViewPath),
    /// A `fn` named as a value (`sdf(torus_d)`).
    Function(Arc<sdfl_lang::ast::FnDef>),
    /// The value of an expression that already produced a diagnostic.
    /// Anything computed from it is poison too, silently.
    Poison,
}

impl Value {
    /// The name of its type in messages ("a shape", "an output").
    pub fn type_name(&self) -> &'static str {
        match self {
            Value::Number(_) => "number",
            Value::Bool(_) => "bool",
            Value::Str(_) => "string",
            Value::List(_) => "list",
            Value::Shape(_) => "shape",
            Value::Material(_) => "material",
            Value::Light(_) => "light",
            Value::Shadows(_) => "soft shadow",
            Value::Occlusion(_) => "ambient occlusion",
            Value::Fog(_) => "fog",
            Value::Camera(_) => "camera",
            Value::Output(_) => "output",
            Value::Param(_) => "trainable parameter",
            Value::Loss(_) => "loss",
            Value::Field(_) => "field",
            Value::Sampler(_) => "sampler",
            Value::ViewPath(_) => "camera path",
            Value::Dataset(_) => "data set",
            Value::Optimizer(_) => "optimizer",
            Value::Encoding(_) => "encoding",
            Value::Occupancy(_) => "occupancy grid",
            Value::Network(_) => "network",
            Value::Background(_) => "background",
            Value::Contraction(_) => "contraction",
            Value::Ndc => "ndc",
            Value::Function(_) => "function",
            Value::Poison => "invalid value",
        }
    }

    /// Whether it is, or holds, [`Value::Poison`].
    pub fn is_poison(&self) -> bool {
        match self {
            Value::Poison => true,
            Value::List(items) => items.iter().any(Value::is_poison),
            _ => false,
        }
    }

    /// A vector from a list of three numbers.
    pub fn as_vec3(&self) -> Option<DVec3> {
        match self {
            Value::List(items) if items.len() == 3 => {
                let mut v = [0.0; 3];
                for (slot, item) in v.iter_mut().zip(items.iter()) {
                    match item {
                        Value::Number(x) => *slot = *x,
                        _ => return None,
                    }
                }
                Some(DVec3::from_array(v))
            }
            _ => None,
        }
    }

    /// A list of three numbers.
    pub fn from_vec3(v: DVec3) -> Value {
        Value::List(Arc::new(
            v.to_array().iter().map(|x| Value::Number(*x)).collect(),
        ))
    }
}

/// A short description of a value for messages ("number 2", "list of 3
/// items", "shape").
pub(crate) fn describe(v: &Value) -> String {
    match v {
        Value::Number(x) => format!("number {}", sdfl_lang::fmt_num(*x)),
        Value::List(items) => format!("list of {} items", items.len()),
        other => other.type_name().to_string(),
    }
}

impl Field {
    /// The region `bounds: "auto"` stands for in a `density_mesh`: a hash
    /// grid's box, else an occupancy grid's, else an SDF field's bounds
    /// (none for a harmonic NeRF without a grid, an unbounded shape, or a
    /// neural SDF, which has no density to mesh).
    pub fn export_region(&self) -> Option<([f64; 3], [f64; 3])> {
        match self {
            Field::Nerf(n) => match (&n.position, &n.occupancy) {
                (Encoding::HashGrid(g), _) => Some((g.min, g.max)),
                (_, Some(o)) => Some((o.min, o.max)),
                _ => None,
            },
            Field::Sdf(f) => f
                .shape
                .bounds()
                .map(|b| (b.min.to_array(), b.max.to_array())),
            Field::NeuralSdf(_) | Field::NeuralSurface(_) => None,
        }
    }
}

/// A `train`'s views resolved when it runs, from its training cameras.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewPath {
    /// `camera_loop` through the training cameras.
    TrainingLoop {
        /// Views made along the loop.
        frames: usize,
        /// Sectors of azimuth, one control point each.
        keyframes: usize,
    },
}

impl ViewPath {
    /// How many views it makes.
    pub fn frames(&self) -> usize {
        match self {
            ViewPath::TrainingLoop { frames, .. } => *frames,
        }
    }
}

/// What an output file holds.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputKind {
    /// Shaded colour, one PNG per view.
    Image,
    /// Shaded colour of all views as an animated GIF.
    Gif {
        /// Frames per second.
        fps: f64,
    },
    /// Depth of all views, colour-mapped as [`OutputKind::Depth`], as an
    /// animated GIF.
    DepthGif {
        /// Frames per second.
        fps: f64,
    },
    /// Hit depth normalised by its maximum and colour-mapped, PNG per view.
    Depth,
    /// Surface normals as colours, PNG per view.
    Normals,
    /// White where the ray hit, black where it missed, PNG per view.
    Mask,
    /// The assignment's visual check: NDC x, y as red and green.
    Grid,
    /// The assignment's visual check: |ray direction| as RGB.
    Rays,
    /// The sample points along one camera's rays, seen from the side.
    SamplePoints,
    /// The loss curve of a training run.
    LossCurve,
    /// Held-out PSNR of a training run against seconds.
    PsnrCurve,
    /// Each held-out view: truth | render | error, stacked.
    Comparison,
    /// A data set in a directory that NeRF codes read (see
    /// `runtime::data::export`): `r_<k>.png` per view (RGBA, alpha = the
    /// hit mask), `transforms_{train,val,test}.json` and `transforms.json`.
    Dataset {
        /// Views held out as the `val` and `test` splits (0: none).
        test_views: usize,
        /// Seed of the shuffle that picks them ([`held_out`]).
        seed: u64,
        /// Images keep the hit mask as alpha (`false`: RGB, as photographs).
        alpha: bool,
        /// Also LLFF's layout (`poses_bounds.npy`, `images/`), every frame
        /// with these depth bounds.
        llff_bounds: Option<[f64; 2]>,
    },
    /// A neural SDF's surface sphere-traced from every view (normals as
    /// colours) as an animated GIF: the geometry of a model whose `gif`
    /// shows its volume-rendered colour.
    GeometryGif {
        /// Frames per second.
        fps: f64,
    },
    /// The surface (zero level set) as a triangle mesh in a PLY file.
    Mesh {
        /// Grid cells along the region's longest side.
        resolution: u32,
        /// Where the grid lies.
        region: MeshRegion,
    },
    /// A radiance field's surface where its density (an opacity field's
    /// per-sample opacity) crosses `level`, as a PLY mesh with normals and
    /// vertex colours.
    DensityMesh {
        /// The density (or opacity) whose level set is the surface.
        level: f64,
        /// Grid cells along the region's longest side.
        resolution: u32,
        /// Where the grid lies.
        region: MeshRegion,
    },
    /// Where rays of the training cameras end (expected depth), coloured by
    /// the rendered colour, where the accumulated opacity reaches
    /// `min_opacity`: a PLY point cloud.
    PointCloud {
        /// Points kept (spread over the views).
        points: u32,
        /// Rays less opaque than this give no point.
        min_opacity: f64,
    },
    /// Expected depth over accumulated opacity per view as float32 `.npy`
    /// (rows × columns), NaN where the opacity is below `min_opacity`.
    RawDepth {
        /// Pixels less opaque than this are NaN.
        min_opacity: f64,
    },
    /// Depth per view colour-mapped, with a titled colour bar, as PNG.
    DepthMap {
        /// The colour map.
        colormap: Colormap,
        /// Depths at the colour map's ends; the views' own range when none.
        range: Option<[f64; 2]>,
        /// Pixels less opaque than this have no depth.
        min_opacity: f64,
    },
}

/// A colour map for depth images (from the `colorous` crate).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Colormap {
    /// Google's rainbow-like map, the default.
    Turbo,
    /// Perceptually uniform blue to yellow.
    Viridis,
    /// Perceptually uniform black to yellow through red.
    Inferno,
    /// Perceptually uniform black to white through purple.
    Magma,
    /// Perceptually uniform blue to yellow through magenta.
    Plasma,
    /// Viridis readable with colour-vision deficiencies.
    Cividis,
}

impl Colormap {
    /// Every colour map, in the order help texts list them.
    pub const ALL: [Colormap; 6] = [
        Colormap::Turbo,
        Colormap::Viridis,
        Colormap::Inferno,
        Colormap::Magma,
        Colormap::Plasma,
        Colormap::Cividis,
    ];

    /// The name written in scene files.
    pub fn name(self) -> &'static str {
        match self {
            Colormap::Turbo => "turbo",
            Colormap::Viridis => "viridis",
            Colormap::Inferno => "inferno",
            Colormap::Magma => "magma",
            Colormap::Plasma => "plasma",
            Colormap::Cividis => "cividis",
        }
    }
}

/// Where a mesh is extracted.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MeshRegion {
    /// The shape's bounds; for a neural SDF, its training points' (or the
    /// training `bounds`).
    Auto,
    /// An explicit box.
    Box {
        /// Its low corner.
        min: [f64; 3],
        /// Its high corner.
        max: [f64; 3],
    },
}

impl OutputKind {
    /// Whether it asks a radiance field for density and colour at points
    /// (a density mesh, a point cloud, depth with opacity): written for
    /// fields (`volume`, `train` of a NeRF or an SDF field), not scenes.
    pub fn field_export(&self) -> bool {
        matches!(
            self,
            OutputKind::DensityMesh { .. }
                | OutputKind::PointCloud { .. }
                | OutputKind::RawDepth { .. }
                | OutputKind::DepthMap { .. }
        )
    }

    /// Whether only a finished training run can write it.
    pub fn training_only(&self) -> bool {
        matches!(
            self,
            OutputKind::LossCurve | OutputKind::PsnrCurve | OutputKind::Comparison
        )
    }
}

/// A requested output file, relative to the output directory.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Output {
    /// What the file holds.
    pub kind: OutputKind,
    /// The file, relative to the output directory.
    pub path: PathBuf,
    /// The call that asked for it (for diagnostics about its files).
    #[serde(skip)]
    pub span: sdfl_lang::Span,
}

/// One `render` statement, fully evaluated and validated.
#[derive(Debug, Clone)]
pub struct RenderJob {
    /// The statement's name, the stem of its files.
    pub name: String,
    /// The shape traced.
    pub scene: Arc<Shape>,
    /// How hits are shaded.
    pub material: Arc<Material>,
    /// The views, one image (or frame) each.
    pub cameras: Vec<Camera>,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Where rays start (distance from the camera).
    pub near: f64,
    /// Where rays give up: farther is a miss.
    pub far: f64,
    /// Most sphere-tracing steps per ray.
    pub iterations: u32,
    /// A ray hits where the distance falls below this (see `hit_tolerance`).
    pub epsilon: f64,
    /// How `epsilon` is applied.
    pub hit_tolerance: HitTolerance,
    /// The colour of misses.
    pub background: DVec3,
    /// Exponential fog by distance, over hits and misses (at `far`).
    pub fog: Option<crate::effects::Fog>,
    /// Rays per pixel whose colours are averaged (a square: 1, 4, 9, …;
    /// see `effects::subpixel_offsets`). Depth, normals and the mask are
    /// the pixel centre's.
    pub samples_per_pixel: u32,
    /// The files it writes.
    pub outputs: Vec<Output>,
}

/// When a sphere-traced ray counts as a hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum HitTolerance {
    /// Below `max(epsilon, half a pixel's width at that distance)`, with
    /// over-relaxed steps: rays grazing a surface are decided at the
    /// image's resolution.
    Pixel,
    /// Below `epsilon`, with plain steps: exactly the reference
    /// assignment's tracer.
    Absolute,
}

pub use crate::density::DensityKind;

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

    /// Multiply-adds of one sample: the distance with its gradient (four
    /// passes' worth) and the colour.
    pub fn multiply_adds_per_sample(&self) -> usize {
        4 * self.sdf.multiply_adds() + self.color_multiply_adds()
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

impl Field {
    /// Every trainable `param(...)` argument of the field, in a fixed
    /// order; a parameter used twice appears twice. (A neural field's
    /// weights are not `param`s: they are trained whenever it is a model.)
    pub fn visit_params<'s>(&'s self, f: &mut dyn FnMut(&'s crate::param::ParamUse)) {
        match self {
            Field::Sdf(s) => s.visit_params(f),
            Field::Nerf(_) | Field::NeuralSdf(_) | Field::NeuralSurface(_) => {}
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

impl NeuralSdf {
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

/// NeRF's harmonic embedding: `sin(2^k·x)`, `cos(2^k·x)` for
/// `k < freqs`, and `x` itself when `include_input`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Harmonic {
    /// Frequencies `2^0 … 2^(freqs−1)` per coordinate.
    pub freqs: usize,
    /// Whether the coordinates themselves are features too.
    pub include_input: bool,
}

/// A multiresolution hash encoding (Müller et al. 2022): `levels` grids
/// from `min_res` to `max_res` cells a side over the box `min..max`, each
/// a table of at most `2^log2_table` rows of `features` trainable numbers,
/// trilinearly interpolated.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HashGridSpec {
    /// Number of grids.
    pub levels: u32,
    /// Trainable numbers per table row.
    pub features: u32,
    /// Each table holds at most `2^log2_table` rows.
    pub log2_table: u32,
    /// Cells a side of the coarsest grid.
    pub min_res: u32,
    /// Cells a side of the finest grid.
    pub max_res: u32,
    /// The box's low corner; positions outside it are clamped.
    pub min: [f64; 3],
    /// The box's high corner.
    pub max: [f64; 3],
}

/// Each level of a hash grid: its resolution (cells a side) and its table's
/// rows, dense (`(res + 1)³`) when that fits the table, else `2^log2_table`.
/// Resolutions grow geometrically from `min_res` to `max_res`, floored (with
/// 1e-9 forgiven so the top level is exactly `max_res`).
pub fn hash_grid_levels(
    levels: u32,
    min_res: u32,
    max_res: u32,
    log2_table: u32,
) -> Vec<(u32, u64)> {
    let (lmin, lmax) = ((min_res.max(1) as f64).ln(), (max_res.max(1) as f64).ln());
    let growth = if levels > 1 {
        (lmax - lmin) / (levels - 1) as f64
    } else {
        0.0
    };
    let table = 1u64 << log2_table.min(62);
    (0..levels)
        .map(|l| {
            let x = (lmin + l as f64 * growth).exp();
            let res = ((x * (1.0 + 1e-9)).floor() as u32).clamp(min_res, max_res);
            let verts = (res as u64 + 1).pow(3);
            (res, verts.min(table))
        })
        .collect()
}

impl HashGridSpec {
    /// Trainable numbers in all tables.
    pub fn param_count(&self) -> u64 {
        hash_grid_levels(self.levels, self.min_res, self.max_res, self.log2_table)
            .iter()
            .map(|(_, rows)| rows * self.features as u64)
            .sum()
    }
}

/// An input encoding of a neural field.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Encoding {
    /// Sines and cosines of the position (NeRF).
    Harmonic(Harmonic),
    /// A multiresolution hash grid (instant-ngp).
    HashGrid(HashGridSpec),
}

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
    /// statement replaces it by its data set's ([`Dataset::background`]);
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

/// The background a data set's images hold, for the model's to agree with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DataBackground {
    /// Composited over (or rendered on) this colour.
    Color(DVec3),
    /// Opaque photographs of the world: no one colour (a learned
    /// background fits them).
    World,
    /// Not known (image files as they are).
    Unknown,
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
    /// A cell is occupied where density × step exceeds this.
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

impl Encoding {
    /// Features of a 3-vector's encoding.
    pub fn width(&self) -> usize {
        match self {
            Encoding::Harmonic(h) => 3 * 2 * h.freqs + if h.include_input { 3 } else { 0 },
            Encoding::HashGrid(g) => (g.levels * g.features) as usize,
        }
    }
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
        let (w, enc) = (self.width, self.position.width());
        let mut macs = enc * w + (self.layers - 1) * w * w + self.skips.len() * enc * w + w;
        macs += match self.direction {
            Some(d) => w * w + (w + d.width()) * self.color_width,
            None => w * self.color_width,
        };
        macs + self.color_width * 3
    }
}

/// Stratified depth samples: `samples` evenly spaced from near to far
/// (inclusive), optionally jittered within each interval while training.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Sampler {
    /// Samples per ray.
    pub samples: usize,
    /// Depth of the first sample.
    pub near: f64,
    /// Depth of the last sample.
    pub far: f64,
    /// Whether training jitters each sample within its interval.
    pub jitter: bool,
    /// How long the last interval is.
    pub last_interval: LastInterval,
}

/// The length given to the last sample's interval, which has no next
/// sample to end it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LastInterval {
    /// Nothing beyond `far`: the last sample absorbs nothing, so images do
    /// not depend on where `far` is.
    Zero,
    /// 1e10, as the reference assignment's code does: a density of ~1e-8 at
    /// the far sample makes a pixel opaque. For reproducing its images.
    Infinite,
}

/// Training views: images with their cameras, some possibly held out as
/// test views.
#[derive(Debug, Clone)]
pub enum Dataset {
    /// Images read from files (`.npy` float32 H×W×3, or PNG).
    Files {
        /// The image files, one per camera.
        images: Vec<std::path::PathBuf>,
        /// The camera of each image.
        cameras: Vec<Camera>,
    },
    /// Views rendered by sdfl from a field: self-contained, with ground truth.
    Rendered {
        /// The field rendered.
        field: Arc<Field>,
        /// Every view, held-out ones included.
        cameras: Vec<Camera>,
        /// Image width in pixels.
        width: u32,
        /// Image height in pixels.
        height: u32,
        /// How the field is rendered.
        sampler: Sampler,
        /// Indices into `cameras` held out as test views (sorted).
        test: Vec<usize>,
    },
    /// Views of a shape sphere-traced by sdfl: the `render` statement's job
    /// (its cameras, size, material, background and tracing settings; no
    /// outputs), so the pixels are exactly what that `render` draws.
    Traced {
        /// The `render` job whose views are the data.
        job: Arc<RenderJob>,
        /// Indices into the job's cameras held out as test views (sorted).
        test: Vec<usize>,
    },
    /// A point cloud sampled on a surface (for distance fields), read from
    /// `path` (relative to the scene file); every `every`-th point kept,
    /// moved to their mean when `center`.
    Points {
        /// The file of points.
        path: std::path::PathBuf,
        /// Keep every `every`-th point.
        every: usize,
        /// Move the points to their mean.
        center: bool,
    },
    /// A NeRF-synthetic (Blender) data set: `transforms_<split>.json` and
    /// its RGBA images, composited over `background`. Cameras are known
    /// once the file is read.
    NerfSynthetic {
        /// The directory (relative to the scene file) or a `.json` file.
        path: std::path::PathBuf,
        /// The `path` argument, where errors reading the data set point.
        path_span: sdfl_lang::Span,
        /// The split trained on (`train`, `val`, `test`).
        split: String,
        /// The split read as test views, if any.
        test_split: Option<String>,
        /// The colour transparent pixels are composited over.
        background: DVec3,
    },
    /// A real capture (`capture(...)`): nerfstudio's `transforms.json`,
    /// COLMAP's text model or LLFF's `poses_bounds.npy`, normalised into
    /// the scene frame. Cameras are known once the files are read.
    Capture(Arc<CaptureSpec>),
}

/// The layout of a capture's files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CaptureFormat {
    /// Decided by what the directory holds: `transforms.json`, then a
    /// COLMAP model (`sparse/0/cameras.txt`, `sparse/cameras.txt` or
    /// `cameras.txt`), then `poses_bounds.npy`.
    Auto,
    /// nerfstudio's `transforms.json`.
    Nerfstudio,
    /// A COLMAP text model.
    Colmap,
    /// LLFF's `poses_bounds.npy`.
    Llff,
}

impl CaptureFormat {
    /// Each format with the name scene files write.
    pub const NAMES: [(&'static str, CaptureFormat); 4] = [
        ("auto", CaptureFormat::Auto),
        ("nerfstudio", CaptureFormat::Nerfstudio),
        ("colmap", CaptureFormat::Colmap),
        ("llff", CaptureFormat::Llff),
    ];

    /// The name scene files write.
    pub fn name(self) -> &'static str {
        Self::NAMES
            .iter()
            .find(|(_, f)| *f == self)
            .map_or("auto", |(n, _)| n)
    }
}

/// How a capture's cameras are turned when it is normalised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CaptureOrient {
    /// The data's axes kept.
    None,
    /// The cameras' mean up turned onto +z (nerfstudio's "up").
    Up,
}

/// What `capture(...)` reads, and how.
#[derive(Debug, Clone)]
pub struct CaptureSpec {
    /// The directory (relative to the scene file), or a `transforms.json`.
    pub path: std::path::PathBuf,
    /// The `path` argument, where errors reading the capture point.
    pub path_span: sdfl_lang::Span,
    /// The layout of its files.
    pub format: CaptureFormat,
    /// Images read from `images_<downscale>` (1: `images`), intrinsics
    /// scaled to match.
    pub downscale: u32,
    /// Without split lists in the data, every `test_every`-th frame is
    /// held out (0: none).
    pub test_every: usize,
    /// Centre on the cameras and scale them into [−extent, extent]³
    /// (`false`: the data's own frame).
    pub normalize: bool,
    /// How the cameras are turned when normalising.
    pub orient: CaptureOrient,
    /// The farthest camera coordinate after normalising.
    pub extent: f64,
    /// The colour behind transparent pixels of images with alpha; `None`
    /// (not given): white there, and the world behind (a model on the
    /// data's background learns it).
    pub background: Option<DVec3>,
}

impl Dataset {
    /// The background its images hold: a NeRF-synthetic set's composite
    /// colour, a traced set's `background`, a field's own when rendered
    /// from one (an analytic field's is black).
    pub fn background(&self) -> DataBackground {
        match self {
            Dataset::NerfSynthetic { background, .. } => DataBackground::Color(*background),
            Dataset::Traced { job, .. } => DataBackground::Color(job.background),
            Dataset::Rendered { field, .. } => match &**field {
                Field::Nerf(n) => match n.background.color() {
                    Some(c) => DataBackground::Color(DVec3::from_array(c)),
                    None => DataBackground::World,
                },
                Field::NeuralSurface(s) => DataBackground::Color(DVec3::from_array(s.background)),
                Field::Sdf(_) | Field::NeuralSdf(_) => DataBackground::Color(DVec3::ZERO),
            },
            Dataset::Capture(c) => c
                .background
                .map_or(DataBackground::World, DataBackground::Color),
            Dataset::Files { .. } | Dataset::Points { .. } => DataBackground::Unknown,
        }
    }

    /// The cameras known before anything is read (none for NeRF-synthetic
    /// data, whose cameras are in its files), test views included.
    pub fn cameras(&self) -> &[Camera] {
        match self {
            Dataset::Files { cameras, .. } | Dataset::Rendered { cameras, .. } => cameras,
            Dataset::Traced { job, .. } => &job.cameras,
            Dataset::NerfSynthetic { .. } | Dataset::Capture(_) | Dataset::Points { .. } => &[],
        }
    }

    /// Indices of [`Self::cameras`] held out as test views.
    pub fn test_views(&self) -> &[usize] {
        match self {
            Dataset::Rendered { test, .. } | Dataset::Traced { test, .. } => test,
            Dataset::Files { .. }
            | Dataset::NerfSynthetic { .. }
            | Dataset::Capture(_)
            | Dataset::Points { .. } => &[],
        }
    }
}

/// The `test` of `n` views held out, by a seeded shuffle (SplitMix64 and
/// Fisher-Yates): the same for the same `(n, test, seed)` on every machine.
/// Sorted; `test` is at most `n`.
pub fn held_out(n: usize, test: usize, seed: u64) -> Vec<usize> {
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    };
    let mut order: Vec<usize> = (0..n).collect();
    for i in (1..n).rev() {
        // Modulo bias is below 2^-40 for n ≤ 10 000 views.
        let j = (next() % (i as u64 + 1)) as usize;
        order.swap(i, j);
    }
    let mut test: Vec<usize> = order.into_iter().take(test.min(n)).collect();
    test.sort_unstable();
    test
}

/// `k` training views among `eyes` (camera positions) that are not in
/// `held` (sorted indices held out), spread out: the first view not held
/// out, then each next the one farthest from those picked (ties to the
/// lowest index). Deterministic, and nested: the views for `k` are among
/// those for any larger `k`, so a fewer-views sweep only ever takes views
/// away, and never changes what it is scored on. Sorted; `k` is at most
/// the views not held out.
pub fn spread_views(eyes: &[DVec3], held: &[usize], k: usize) -> Vec<usize> {
    let mut free: Vec<usize> = (0..eyes.len())
        .filter(|i| held.binary_search(i).is_err())
        .collect();
    let mut picked = Vec::with_capacity(k.min(free.len()));
    // Squared distance of each free view to the nearest picked one.
    let mut nearest = vec![f64::INFINITY; free.len()];
    while picked.len() < k && !free.is_empty() {
        // The first free view while none is picked (all at ∞), then the farthest.
        let (at, _) = nearest
            .iter()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |best, (j, &d)| {
                if d > best.1 {
                    (j, d)
                } else {
                    best
                }
            });
        // `remove` keeps `free` in index order, for the tie rule.
        let view = free.remove(at);
        nearest.remove(at);
        for (j, &f) in free.iter().enumerate() {
            nearest[j] = nearest[j].min(eyes[f].distance_squared(eyes[view]));
        }
        picked.push(view);
    }
    picked.sort_unstable();
    picked
}

/// Adam with a learning-rate schedule.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Optimizer {
    /// The base learning rate.
    pub lr: f64,
    /// How it changes with the step.
    pub schedule: Schedule,
}

/// How the learning rate changes with the step.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Schedule {
    /// The same learning rate throughout.
    Constant,
    /// Multiplied by `factor` every `every` steps.
    Step {
        /// Multiplier applied each time.
        factor: f64,
        /// Steps between multiplications.
        every: usize,
    },
    /// `lr·factor^(step/every)`: the same decay as `Step`, spread smoothly.
    Exponential {
        /// Multiplier over `every` steps.
        factor: f64,
        /// Steps over which the rate is multiplied by `factor`.
        every: usize,
    },
}

impl Optimizer {
    /// The learning rate of step `step` (counted from 0).
    pub fn lr_at(&self, step: usize) -> f64 {
        match self.schedule {
            Schedule::Constant => self.lr,
            Schedule::Step { factor, every } if every > 0 => {
                self.lr * factor.powi((step / every) as i32)
            }
            Schedule::Step { .. } => self.lr,
            Schedule::Exponential { factor, every } => {
                self.lr * factor.powf(step as f64 / every.max(1) as f64)
            }
        }
    }
}

/// A term of a training objective.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LossKind {
    /// Mean squared error of rendered against true pixel colours.
    Mse,
    /// Mean |f| of a distance field at the surface points.
    Surface,
    /// Mean (‖∇f‖ − 1)² at the surface and the random points, the gradient
    /// exact (no finite differences).
    Eikonal,
    /// Mean exp(−alpha·|f|) at random points: no surface away from the data.
    Inter {
        /// How fast the penalty falls with |f|.
        alpha: f64,
    },
}

impl LossKind {
    /// Whether the term compares rendered colours (else it is a distance
    /// field's term on points).
    pub fn on_images(&self) -> bool {
        matches!(self, LossKind::Mse)
    }
}

/// A weighted loss term.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Loss {
    /// Which term.
    pub kind: LossKind,
    /// Its weight in the sum.
    pub weight: f64,
}

/// How a training step computes its gradient.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Backend {
    /// One fused kernel per ray: forward-mode parameter tangents through the
    /// field, a hand-written backward through compositing.
    Fused,
    /// A dfdx autodiff graph over `[rays, samples]` tensors, the field as a
    /// custom op.
    Dfdx,
}

/// A `render` statement whose scene is a field: volume rendering.
#[derive(Debug, Clone)]
pub struct VolumeJob {
    /// The statement's name, the stem of its files.
    pub name: String,
    /// The volume rendered.
    pub field: Arc<Field>,
    /// The views, one image (or frame) each.
    pub cameras: Vec<Camera>,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Where samples fall along each ray.
    pub sampler: Sampler,
    /// The files it writes.
    pub outputs: Vec<Output>,
}

/// A `train` statement.
#[derive(Debug, Clone)]
pub struct TrainJob {
    /// The statement's name, the stem of its files.
    pub name: String,
    /// The field trained.
    pub model: Arc<Field>,
    /// What it is fitted to.
    pub data: Arc<Dataset>,
    /// The `data` argument, where errors reading the data set point.
    pub data_span: sdfl_lang::Span,
    /// Where samples fall along each training ray.
    pub sampler: Sampler,
    /// Rays per step.
    pub rays: usize,
    /// The optimiser and its learning-rate schedule.
    pub optimizer: Optimizer,
    /// The objective's terms.
    pub losses: Vec<Loss>,
    /// Optimiser steps, unless `epochs` is given.
    pub iterations: usize,
    /// Passes over all training pixels: steps = epochs × ⌈pixels / rays⌉.
    pub epochs: Option<usize>,
    /// Seed of the batches (a step's rays are a function of seed and step).
    pub seed: u64,
    /// How gradients are computed.
    pub backend: Backend,
    /// Cameras and size for the before/after outputs (placeholders, as
    /// many as it will have, where `view_path` makes them at run time).
    pub views: Vec<Camera>,
    /// Views made from the training cameras when the run has read them.
    pub view_path: Option<ViewPath>,
    /// Width of the before/after images.
    pub width: u32,
    /// Height of the before/after images.
    pub height: u32,
    /// Outputs of the model as it starts.
    pub before: Vec<Output>,
    /// Outputs of the trained model.
    pub after: Vec<Output>,
    /// Where to keep a resumable checkpoint (relative to the output dir).
    pub checkpoint: Option<std::path::PathBuf>,
    /// Steps between held-out evaluations (0: at the end only).
    pub eval_every: usize,
    /// Half-extent of the cube random points are drawn in (distance fields).
    pub bounds: f64,
}

/// Everything a scene file asks for, by kind, each in file order.
#[derive(Debug, Clone, Default)]
pub struct Program {
    /// `render` statements of shapes.
    pub renders: Vec<RenderJob>,
    /// `render` statements of fields (volume rendering).
    pub volumes: Vec<VolumeJob>,
    /// `train` statements.
    pub trains: Vec<TrainJob>,
    /// Every statement in file order (statements run in this order).
    pub order: Vec<Statement>,
}

/// What a statement runs: a `render` of a shape, a `render` of a field
/// (volume rendering) or a `train`. Named in reports as `render`, `volume`
/// and `train`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StatementKind {
    /// A shape sphere-traced.
    Render,
    /// A field volume-rendered.
    Volume,
    /// A field trained.
    Train,
}

impl StatementKind {
    /// The kind of a statement written with `keyword` (`render`, `train`),
    /// whose `scene` field (if any) holds a field.
    pub fn of(keyword: &str, scene_is_field: bool) -> StatementKind {
        match (keyword, scene_is_field) {
            ("train", _) => StatementKind::Train,
            (_, true) => StatementKind::Volume,
            _ => StatementKind::Render,
        }
    }

    /// The statement of this kind at `index` of its list in a [`Program`].
    pub fn at(self, index: usize) -> Statement {
        match self {
            StatementKind::Render => Statement::Render(index),
            StatementKind::Volume => Statement::Volume(index),
            StatementKind::Train => Statement::Train(index),
        }
    }
}

/// A statement of a [`Program`]: which list, and where in it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Statement {
    /// The `render` of a shape at this index of [`Program::renders`].
    Render(usize),
    /// The volume render at this index of [`Program::volumes`].
    Volume(usize),
    /// The `train` at this index of [`Program::trains`].
    Train(usize),
}

impl Statement {
    /// What it runs.
    pub fn kind(self) -> StatementKind {
        match self {
            Statement::Render(_) => StatementKind::Render,
            Statement::Volume(_) => StatementKind::Volume,
            Statement::Train(_) => StatementKind::Train,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{held_out, spread_views, StatementKind};
    use glam::DVec3;

    #[test]
    fn statement_kinds_round_trip_and_read_their_keyword() {
        use StatementKind::*;
        for k in [Render, Volume, Train] {
            assert_eq!(k.at(3).kind(), k);
        }
        assert_eq!(StatementKind::of("train", true), Train);
        assert_eq!(StatementKind::of("render", true), Volume);
        assert_eq!(StatementKind::of("render", false), Render);
        let names = [Render, Volume, Train].map(|k| serde_json::to_string(&k).unwrap());
        assert_eq!(names, ["\"render\"", "\"volume\"", "\"train\""]);
    }

    #[test]
    fn held_out_views_are_a_seeded_sorted_subset() {
        let a = held_out(100, 10, 3);
        assert_eq!(a, held_out(100, 10, 3));
        assert_eq!(a.len(), 10);
        assert!(a.windows(2).all(|w| w[0] < w[1]) && a[9] < 100);
        assert_ne!(a, held_out(100, 10, 4));
        // Not simply the first or last views.
        assert_ne!(a, (0..10).collect::<Vec<_>>());
        assert_ne!(a, (90..100).collect::<Vec<_>>());
        assert!(held_out(5, 0, 1).is_empty());
        assert_eq!(held_out(3, 3, 9), vec![0, 1, 2]);
        assert!(held_out(0, 2, 0).is_empty());
    }

    #[test]
    fn spread_views_are_nested_far_apart_and_never_held_out() {
        // On a line: the first, the far end, then the middle.
        let line: Vec<DVec3> = (0..=10).map(|x| DVec3::new(x as f64, 0.0, 0.0)).collect();
        assert_eq!(spread_views(&line, &[], 3), [0, 5, 10]);
        assert_eq!(spread_views(&line, &[0, 10], 2), [1, 9]);
        // Hard case: every camera at one place: ties go to the lowest index.
        let same = vec![DVec3::ONE; 6];
        assert_eq!(spread_views(&same, &[1], 3), [0, 2, 3]);
        // Asking for more than there are gives every view not held out.
        assert_eq!(spread_views(&same, &[1], 9), [0, 2, 3, 4, 5]);
        assert!(spread_views(&[], &[], 3).is_empty());

        // On a Fibonacci sphere: nested, and within the greedy rule's
        // factor of 2 of the best smallest gap (brute force over subsets).
        let eyes: Vec<DVec3> = crate::camera::Camera::sphere(16, 3.0, DVec3::Y, 1.0, false)
            .iter()
            .map(|c| c.eye)
            .collect();
        let held = held_out(eyes.len(), 4, 7);
        let gap = |set: &[usize]| {
            let mut g = f64::INFINITY;
            for (i, &a) in set.iter().enumerate() {
                for &b in &set[i + 1..] {
                    g = g.min(eyes[a].distance(eyes[b]));
                }
            }
            g
        };
        let free: Vec<usize> = (0..eyes.len()).filter(|i| !held.contains(i)).collect();
        let mut before: Vec<usize> = Vec::new();
        for k in 1..=free.len() {
            let picked = spread_views(&eyes, &held, k);
            assert_eq!(picked.len(), k);
            assert!(picked.iter().all(|p| !held.contains(p)));
            assert!(before.iter().all(|b| picked.contains(b)), "k = {k}: nested");
            if (2..=4).contains(&k) {
                let mut best = 0.0f64;
                let n = free.len();
                for mask in 0u32..1 << n {
                    if mask.count_ones() as usize == k {
                        let set: Vec<usize> = (0..n)
                            .filter(|j| mask >> j & 1 == 1)
                            .map(|j| free[j])
                            .collect();
                        best = best.max(gap(&set));
                    }
                }
                assert!(
                    gap(&picked) >= 0.5 * best - 1e-12,
                    "k = {k}: {} vs best {best}",
                    gap(&picked)
                );
            }
            before = picked;
        }
    }
}
