//! The output files a statement writes and what each holds.

use std::path::PathBuf;

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

impl Output {
    /// Where a `video` writes its GIF when no `ffmpeg` encodes the MP4:
    /// its path with the extension `.gif` (claimed with the MP4, so no
    /// other output may write it). `None` for other kinds.
    pub fn fallback(&self) -> Option<PathBuf> {
        matches!(self.kind, OutputKind::Video { .. }).then(|| self.path.with_extension("gif"))
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
    /// Shaded colour of all views as an H.264 MP4 video, encoded by an
    /// `ffmpeg` found on the system; where none is found or it fails, the
    /// animated GIF at [`Output::fallback`] instead.
    Video {
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
        /// Seed of the shuffle that picks them ([`held_out`](super::held_out)).
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
    /// `min_opacity` inside `crop`: a PLY point cloud with normals.
    PointCloud {
        /// Points kept (spread over the views).
        points: u32,
        /// Rays less opaque than this give no point.
        min_opacity: f64,
        /// Which points are kept by where they are.
        crop: CloudCrop,
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

    /// Whether it is a depth export (raw or colour-mapped): the field
    /// exports one march, or one render, a view serves together.
    pub fn depth_export(&self) -> bool {
        matches!(
            self,
            OutputKind::RawDepth { .. } | OutputKind::DepthMap { .. }
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

/// Which of a point cloud's points are kept by where they are.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CloudCrop {
    /// The object's region: a contraction's inner box, else the field's
    /// bounds (its hash grid's or occupancy grid's box); every point when
    /// the field has neither.
    Auto,
    /// Every point.
    None,
    /// Points inside a box of the data's frame (the cloud's own).
    Box {
        /// Its low corner.
        min: [f64; 3],
        /// Its high corner.
        max: [f64; 3],
    },
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
