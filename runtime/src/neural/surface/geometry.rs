//! The distance network of a surface trained from images: a closed choice
//! between the harmonic MLP ([`SdfNet`]) and the hash-grid SDF
//! ([`HashSdf`]), told apart here only. The objective sees one interface:
//! distances alone (placing fine samples, rendering), a forward giving `f`
//! and `∇f` per sample, and a backward taking `∂L/∂f` and `∂L/∂∇f` per
//! sample and adding `∂L/∂params`.

use sdfl_stdlib::value::{Encoding, NeuralSdf};

use crate::mesh::DistanceField;
use crate::neural::distance::{sdf_net, NetDistance};
use crate::neural::hash_sdf::objective::hash_sdf;
use crate::neural::hash_sdf::volume::VolumeWork;
use crate::neural::hash_sdf::{progressive_levels, Eikonal, HashSdf, HashSdfField};
use crate::neural::sdf_net::{SdfNet, SdfWork};
use crate::train::TensorSpec;

/// A surface's distance network.
#[derive(Debug, Clone)]
pub enum SurfaceSdf {
    /// The harmonic MLP (IDR, VolSDF, NeuS), geometrically initialised.
    Mlp(SdfNet),
    /// A hash grid and a small MLP adding a residual to a sphere (NeuS2).
    Hash(HashSurface),
}

/// The hash-grid SDF with how its `∇f` is taken and its levels grow.
#[derive(Debug, Clone)]
pub struct HashSurface {
    /// The network and its layout.
    pub net: HashSdf,
    /// Exact `∇f`, or central differences.
    pub eikonal: Eikonal,
    /// One more level every this many steps (0: all from the start).
    pub level_every: usize,
}

impl HashSurface {
    /// Levels on at `step`: a quarter (at least one) at first, as in the
    /// point fit.
    pub fn active(&self, step: usize) -> usize {
        let levels = self.net.levels();
        progressive_levels(
            step as u64,
            levels,
            levels.div_ceil(4),
            self.level_every as u64,
        )
    }
}

/// The buffers of [`SurfaceSdf`]'s passes.
#[derive(Debug, Default)]
pub struct GeometryWork {
    mlp: SdfWork,
    hash: VolumeWork,
    /// The levels of the last hash forward.
    active: usize,
}

/// Which levels a pass reads: those on at a training step, or all (a
/// trained field: levels not yet on are zero, so all give the same `f`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Levels {
    /// Those on at this step.
    AtStep(usize),
    /// Every level.
    All,
}

impl SurfaceSdf {
    /// The network of `spec`; refuses a bad hash grid.
    pub fn new(spec: &NeuralSdf) -> Result<Self, String> {
        Ok(match &spec.encoding {
            Encoding::Harmonic(_) => SurfaceSdf::Mlp(sdf_net(spec)),
            Encoding::HashGrid(g) => SurfaceSdf::Hash(HashSurface {
                net: hash_sdf(spec, g)?,
                eikonal: match spec.eikonal_step {
                    Some(step) if step > 0.0 => Eikonal::FiniteDifference { step: step as f32 },
                    _ => Eikonal::Exact,
                },
                level_every: spec.level_every,
            }),
        })
    }

    /// Trainable numbers.
    pub fn len(&self) -> usize {
        match self {
            SurfaceSdf::Mlp(n) => n.len,
            SurfaceSdf::Hash(h) => h.net.param_count(),
        }
    }

    /// Whether it has no parameters (never: both kinds have layers).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn levels(&self, levels: Levels) -> usize {
        match (self, levels) {
            (SurfaceSdf::Hash(h), Levels::AtStep(s)) => h.active(s),
            _ => usize::MAX,
        }
    }

    /// The tensors, named under `sdf.`.
    pub fn tensors(&self) -> Vec<TensorSpec> {
        match self {
            SurfaceSdf::Mlp(n) => n
                .layers()
                .into_iter()
                .flat_map(|(name, d)| d.tensors(&format!("sdf.{name}")))
                .collect(),
            SurfaceSdf::Hash(h) => {
                let offsets = h.net.grid().level_offsets();
                let tables = h.net.table_params();
                let mut t: Vec<TensorSpec> = offsets
                    .iter()
                    .enumerate()
                    .map(|(l, &offset)| TensorSpec {
                        name: format!("sdf.grid.level{l}"),
                        offset,
                        len: offsets.get(l + 1).copied().unwrap_or(tables) - offset,
                    })
                    .collect();
                let mut offset = tables;
                for (name, len) in h.net.layer_sizes() {
                    t.push(TensorSpec {
                        name: format!("sdf.{name}"),
                        offset,
                        len,
                    });
                    offset += len;
                }
                t
            }
        }
    }

    /// The starting values: a sphere of `radius` (the MLP's geometric
    /// initialisation; the hash SDF's analytic sphere with its levels not
    /// yet on at zero).
    pub fn initial(&self, seed: u64, radius: f32) -> Vec<f32> {
        match self {
            SurfaceSdf::Mlp(n) => n.init_geometric(seed, radius),
            SurfaceSdf::Hash(h) => {
                let mut v = h.net.init(seed);
                let offsets = h.net.grid().level_offsets();
                if let Some(&from) = offsets.get(h.active(0)) {
                    v[from..h.net.table_params()].fill(0.0);
                }
                v
            }
        }
    }

    /// `f` at flat `points` into `out`.
    pub fn distance(&self, params: &[f32], points: &[f32], levels: Levels, out: &mut [f32]) {
        match self {
            SurfaceSdf::Mlp(n) => n.distance(params, points, out),
            SurfaceSdf::Hash(h) => {
                let active = self.levels(levels);
                h.net
                    .distances(params, points.as_chunks::<3>().0, active, out)
            }
        }
    }

    /// `f` and `∇f` at flat `points`, kept in `work` for
    /// [`Self::backward`] ([`Self::distances`], [`Self::gradients`]).
    pub fn forward(&self, params: &[f32], points: &[f32], levels: Levels, work: &mut GeometryWork) {
        match self {
            SurfaceSdf::Mlp(n) => n.forward(params, points, &mut work.mlp),
            SurfaceSdf::Hash(h) => {
                work.active = self.levels(levels);
                h.net.volume_forward(
                    params,
                    points.as_chunks::<3>().0,
                    h.eikonal,
                    work.active,
                    &mut work.hash,
                )
            }
        }
    }

    /// `f` of the last forward.
    pub fn distances<'w>(&self, work: &'w GeometryWork) -> &'w [f32] {
        match self {
            SurfaceSdf::Mlp(_) => work.mlp.distance(),
            SurfaceSdf::Hash(_) => work.hash.distance(),
        }
    }

    /// `∇f` (rows × 3, flat) of the last forward.
    pub fn gradients<'w>(&self, work: &'w GeometryWork) -> &'w [f32] {
        match self {
            SurfaceSdf::Mlp(_) => work.mlp.gradient(),
            SurfaceSdf::Hash(_) => work.hash.gradient(),
        }
    }

    /// *Adds* `∂L/∂params` to `grad` given `∂L/∂f` and `∂L/∂∇f` at the
    /// last forward's `points` (the hash SDF recomputes its forward).
    pub fn backward(
        &self,
        params: &[f32],
        points: &[f32],
        d_f: &[f32],
        d_g: &[f32],
        work: &mut GeometryWork,
        grad: &mut [f32],
    ) {
        match self {
            SurfaceSdf::Mlp(n) => n.backward(params, d_f, d_g, &mut work.mlp, grad),
            SurfaceSdf::Hash(h) => h.net.volume_backward(
                params,
                points.as_chunks::<3>().0,
                d_f,
                d_g,
                h.eikonal,
                work.active,
                &mut work.hash,
                grad,
            ),
        }
    }

    /// The trained field at `params`, every level read.
    pub fn field<'a>(&'a self, params: &'a [f32]) -> SurfaceField<'a> {
        match self {
            SurfaceSdf::Mlp(net) => SurfaceField::Mlp(NetDistance { net, params }),
            SurfaceSdf::Hash(h) => SurfaceField::Hash(HashSdfField {
                net: &h.net,
                params,
                active: h.net.levels(),
            }),
        }
    }

    /// What is trained, in words, for `sdfl plan`.
    pub fn describe(&self) -> String {
        match self {
            SurfaceSdf::Mlp(n) => format!("distance network {}", n.len),
            SurfaceSdf::Hash(h) => {
                let c = h.net.grid().config();
                let growth = if h.level_every > 0 {
                    format!(
                        ", levels on coarse to fine ({} at first, one more every {} steps)",
                        h.active(0),
                        h.level_every
                    )
                } else {
                    String::new()
                };
                format!(
                    "hash-grid distance {} ({} in {} levels' tables of at most 2^{} rows x {} features, {} to {} cells a side{growth})",
                    h.net.param_count(),
                    h.net.table_params(),
                    c.levels,
                    c.log2_table,
                    c.features,
                    c.min_res,
                    c.max_res
                )
            }
        }
    }

    /// How `∇f` and the gradient are computed, for `sdfl plan`.
    pub fn gradient_words(&self) -> String {
        match self {
            SurfaceSdf::Mlp(_) => "the distance network's exact gradient by a reverse pass in the forward".into(),
            SurfaceSdf::Hash(h) => match h.eikonal {
                Eikonal::Exact => "the hash SDF's exact gradient by forward-mode tangents, its second-order reverse pass recomputing each sample's forward in blocks".into(),
                Eikonal::FiniteDifference { step } => format!(
                    "the hash SDF's gradient by central differences of step {step} (seven values a sample, also the colour network's normal), its reverse pass exact for that expression"
                ),
            },
        }
    }
}

/// A trained surface's distance as a field to mesh or trace (both kinds
/// with their exact gradient).
pub enum SurfaceField<'a> {
    /// The harmonic MLP.
    Mlp(NetDistance<'a>),
    /// The hash-grid SDF, every level read.
    Hash(HashSdfField<'a>),
}

impl DistanceField for SurfaceField<'_> {
    fn distances(&self, points: &[[f32; 3]], out: &mut [f32]) {
        match self {
            SurfaceField::Mlp(f) => f.distances(points, out),
            SurfaceField::Hash(f) => f.distances(points, out),
        }
    }
    fn gradients(&self, points: &[[f32; 3]], h: f32, f: &mut [f32], g: &mut [[f32; 3]]) {
        match self {
            SurfaceField::Mlp(d) => d.gradients(points, h, f, g),
            SurfaceField::Hash(d) => d.gradients(points, h, f, g),
        }
    }
}
