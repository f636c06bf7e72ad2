//! Lowering of the shape IR to a fast f32 evaluator: `nodes` (the
//! primitives, each calling its one formula in `sdfl_stdlib::sdf`, and the
//! combinators), `bvh` (culled unions) and `lower` (the shape tree to
//! nodes, transforms pushed into leaves).
//!
//! A [`Shape`] is lowered once into a tree of trait objects (a closure tree
//! with two entry points: the distance, and the distance with the id of the
//! primitive that attains it). Transforms are pushed down into the leaves as
//! one world→local affine map each, nested unions are flattened, and a union
//! of many bounded members gets a BVH over their bounding boxes, traversed
//! branch-and-bound: a subtree is skipped when the signed distance to its box
//! is not below the best distance found so far. Because every shape's value
//! is at least the signed distance to its bounds (see `sdfl_stdlib::shape`),
//! a skipped member can never be the minimum: the culled union equals the
//! naive minimum. Tests check that against the f64 reference for every
//! evaluator.

use std::sync::Arc;

use glam::{Affine3A, DAffine3, DQuat, DVec3, Vec3A};
use sdfl_stdlib::material::Material;
use sdfl_stdlib::num::{Real, V3};
use sdfl_stdlib::param::Arg;
use sdfl_stdlib::sdf;
use sdfl_stdlib::shape::{
    cells, repeat_ranges, Aabb, Declared, Family, Ir, KindVisitor, Num, Plane, Primitive, Shape,
    WithDeclared,
};

mod bvh;
mod lower;
mod nodes;
pub mod tiles;
/// Shapes users write (`sdf(f, ...)`), as leaves of the lowered scene.
#[doc(hidden)]
pub mod user;

use crate::lanes::{self, per_lane, F8, LANES, P8};
use bvh::*;
use lower::*;
use nodes::*;
use user::UserLeaf;

/// One lowered node: a signed distance (or bound) in world units.
pub trait Node: Send + Sync + std::any::Any {
    /// The signed distance (or bound) at `p`, in the evaluator's coordinates.
    fn dist(&self, p: Vec3A) -> f32;
    /// The distance and the id of the primitive attaining it.
    fn dist_id(&self, p: Vec3A) -> (f32, u32);
    /// The distances of packs of [`LANES`] points (`out[i]` for `p[i]`),
    /// each lane equal to [`Node::dist`] of its point. The default is the
    /// per-point path lane by lane; unions, leaves and packed unions
    /// evaluate whole packs (one call per node per batch, not per point).
    fn dist_packs(&self, p: &[P8], out: &mut [F8]) {
        for (q, o) in p.iter().zip(out.iter_mut()) {
            *o = per_lane(q, |x| self.dist(x));
        }
    }
    /// Whether [`Node::dist_packs`] is so much cheaper per point than
    /// [`Node::dist`] that the tracer marches rays together
    /// (`trace::sphere_trace_packs`) rather than one by one: a user's
    /// shape, whose code runs column by column over packs but one
    /// instruction at a time for a point.
    fn traces_in_packs(&self) -> bool {
        false
    }
}

// The tracer marches any distance; a lowered node is one, by these two
// impls (kept here so that `trace` knows nothing of scenes).
impl<T: Node + ?Sized> crate::trace::Distance for T {
    #[inline(always)]
    fn dist(&self, p: Vec3A) -> f32 {
        Node::dist(self, p)
    }
}

impl<T: Node + ?Sized> crate::trace::PackedDistance for T {
    #[inline(always)]
    fn dist_packs(&self, p: &[P8], out: &mut [F8]) {
        Node::dist_packs(self, p, out)
    }
}

/// What a primitive id stands for, for shading.
#[derive(Debug, Clone)]
pub struct PrimInfo {
    /// World-space centre (the rainbow material's `c`).
    pub center: DVec3,
    /// The material painted on it, if any (else the render's material).
    pub material: Option<Arc<Material>>,
    /// The primitive's built-in name (`sphere`, `box`...), for reports.
    pub kind: &'static str,
}

/// Options of lowering.
#[derive(Debug, Clone, Copy)]
pub struct LowerOptions {
    /// Build BVHs over large unions (otherwise a union is a plain minimum).
    pub cull: bool,
    /// Unions with at least this many bounded members get a BVH.
    pub bvh_threshold: usize,
    /// Gather the primitives of each kind in a plain union into one packed
    /// node (evaluated without a call per member); off, every member is its own node (the
    /// evaluator before packing, kept for comparisons).
    pub pack: bool,
    /// Cull per screen tile when tracing (see [`tiles`]); off (or without
    /// `cull`), every ray marches the whole scene from `near`, as the
    /// tracer before tiles did (kept for comparisons).
    pub tiles: bool,
}

impl Default for LowerOptions {
    fn default() -> Self {
        LowerOptions {
            cull: true,
            bvh_threshold: 16,
            pack: true,
            tiles: true,
        }
    }
}

impl LowerOptions {
    /// For evaluators that only answer distance queries (volumes, meshes,
    /// geometric error) and never trace: no union lowered a second time for
    /// culling per screen tile.
    pub fn point_queries() -> Self {
        LowerOptions {
            tiles: false,
            ..LowerOptions::default()
        }
    }
}

/// A lowered scene: evaluator, Lipschitz bound and primitive table.
///
/// The evaluator takes points relative to `origin` (world = origin + p):
/// lowered relative to a point near the camera, a scene far from the world
/// origin is evaluated in f32 on coordinates as small as those near it.
pub struct Lowered {
    /// The evaluator: the root of the lowered node tree.
    pub root: Box<dyn Node>,
    /// The world point the evaluator's coordinates are relative to (zero:
    /// world coordinates, exactly as lowered without an origin).
    pub origin: DVec3,
    /// A bound on the gradient's norm: the tracer steps `d / lipschitz`.
    pub lipschitz: f32,
    /// Shading data per primitive, indexed by the id [`Node::dist_id`] returns.
    pub prims: Vec<PrimInfo>,
    /// How many BVH nodes culling built (0: none), for reports and benches.
    pub bvh_nodes: usize,
    /// The top-level union's members with their boxes, for culling per
    /// screen tile, when the root is not already such a union (small
    /// unions are lowered without one).
    #[doc(hidden)]
    pub tile_union: Option<Box<BvhUnion>>,
    /// The scene's box in the evaluator's coordinates (centre, half
    /// extents), when bounded.
    bounds: Option<(Vec3A, Vec3A)>,
    /// Tiles cull (`LowerOptions::cull` and `tiles`).
    #[doc(hidden)]
    pub tiles: bool,
}

impl Lowered {
    /// The scene in world coordinates.
    pub fn new(shape: &Shape, options: LowerOptions) -> Self {
        Self::relative_to(shape, options, DVec3::ZERO)
    }

    /// The scene in coordinates relative to `origin`: the translation to it
    /// is composed with every transform in f64, and each primitive is
    /// lowered at its own anchor (`lower::anchored`), so no f32 value
    /// holds a coordinate of the size of `origin`.
    pub fn relative_to(shape: &Shape, options: LowerOptions, origin: DVec3) -> Self {
        let relative = origin != DVec3::ZERO;
        let to_origin = DAffine3::from_translation(origin);
        let mut cx = Lowering {
            options,
            prims: Vec::new(),
            bvh_nodes: 0,
            warp_to_world: to_origin,
            relative,
        };
        let mut frame = Frame::identity();
        frame.to_local = to_origin;
        let root = cx.lower(shape, &frame);
        let tiles = options.cull && options.tiles;
        let tile_union = if tiles
            && (root.as_ref() as &dyn std::any::Any)
                .downcast_ref::<BvhUnion>()
                .is_none()
        {
            // Lowered again member by member (leaves only: no grid), with
            // the same ids as in `root`.
            let mut again = Lowering {
                options,
                prims: Vec::new(),
                bvh_nodes: 0,
                warp_to_world: to_origin,
                relative,
            };
            again.tile_union(shape, &frame).map(Box::new)
        } else {
            None
        };
        Lowered {
            root,
            origin,
            lipschitz: shape.lipschitz().max(1.0) as f32,
            prims: cx.prims,
            bvh_nodes: cx.bvh_nodes,
            tile_union,
            bounds: shape.bounds().map(|b| padded(frame.world_box(b))),
            tiles,
        }
    }

    /// The distance at a world point.
    pub fn dist(&self, p: Vec3A) -> f32 {
        self.root.dist(self.from_world(p))
    }

    /// A world point in the evaluator's coordinates (itself when the
    /// origin is the world's).
    #[inline]
    pub fn from_world(&self, p: Vec3A) -> Vec3A {
        if self.origin == DVec3::ZERO {
            p
        } else {
            (p.as_dvec3() - self.origin).as_vec3().into()
        }
    }

    /// A point in the evaluator's coordinates as a world point.
    #[inline]
    pub fn to_world(&self, p: Vec3A) -> DVec3 {
        if self.origin == DVec3::ZERO {
            p.as_dvec3()
        } else {
            self.origin + p.as_dvec3()
        }
    }

    /// Distances of a batch of world points, equal to [`Lowered::dist`] of
    /// each: evaluated in packs of [`LANES`] points, [`BATCH_PACKS`] packs
    /// per pass through the node tree.
    pub fn eval_batch(&self, points: &[Vec3A], out: &mut [f32]) {
        let n = points.len().min(out.len());
        let mut packs = [P8::splat(F8::splat(0.0)); BATCH_PACKS];
        let mut dists = [F8::splat(0.0); BATCH_PACKS];
        let mut local = [Vec3A::ZERO; LANES];
        let relative = self.origin != DVec3::ZERO;
        for (points, out) in points[..n]
            .chunks(LANES * BATCH_PACKS)
            .zip(out[..n].chunks_mut(LANES * BATCH_PACKS))
        {
            let count = points.len().div_ceil(LANES);
            for (pack, pts) in packs.iter_mut().zip(points.chunks(LANES)) {
                *pack = if relative {
                    for (l, p) in local.iter_mut().zip(pts) {
                        *l = self.from_world(*p);
                    }
                    lanes::pack(&local[..pts.len()])
                } else {
                    lanes::pack(pts)
                };
            }
            self.root.dist_packs(&packs[..count], &mut dists[..count]);
            for (o, d) in out.chunks_mut(LANES).zip(&dists) {
                match o.first_chunk_mut::<LANES>() {
                    // A whole pack: a copy of fixed size (no call).
                    Some(o) => *o = d.0,
                    None => o.copy_from_slice(&d.0[..o.len()]),
                }
            }
        }
    }
}

/// Packs per pass of [`Lowered::eval_batch`] (256 points: the packs and
/// each node's partial results stay in the L1 cache).
pub const BATCH_PACKS: usize = 32;

/// The accumulated transform from world space to a node's local space.
#[derive(Clone)]
#[doc(hidden)]
pub struct Frame {
    /// World → local.
    pub(super) to_local: DAffine3,
    /// Local distances are multiplied by this to give world distances.
    pub(super) scale: f64,
    pub(super) material: Option<Arc<Material>>,
}

impl Frame {
    /// World space itself.
    pub fn identity() -> Self {
        Frame {
            to_local: DAffine3::IDENTITY,
            scale: 1.0,
            material: None,
        }
    }
    pub(super) fn then(&self, local_step: DAffine3, scale: f64) -> Frame {
        Frame {
            to_local: local_step * self.to_local,
            scale: self.scale * scale,
            material: self.material.clone(),
        }
    }
    /// World → local as the leaves apply it.
    pub fn xform(&self) -> Xform {
        if self.to_local == DAffine3::IDENTITY {
            Xform::Identity
        } else {
            Xform::Affine(Affine3A::from_cols(
                self.to_local.matrix3.x_axis.as_vec3().into(),
                self.to_local.matrix3.y_axis.as_vec3().into(),
                self.to_local.matrix3.z_axis.as_vec3().into(),
                self.to_local.translation.as_vec3().into(),
            ))
        }
    }
    /// World-space box of a local-space box.
    pub(super) fn world_box(&self, local: Aabb) -> Aabb {
        let to_world = self.to_local.inverse();
        local.transformed(|c| to_world.transform_point3(c))
    }
}

/// A leaf's world → local transform.
#[derive(Clone, Copy)]
#[doc(hidden)]
pub enum Xform {
    Identity,
    Affine(Affine3A),
}

impl Xform {
    #[inline(always)]
    pub(super) fn apply(&self, p: Vec3A) -> Vec3A {
        match self {
            Xform::Identity => p,
            Xform::Affine(a) => a.transform_point3a(p),
        }
    }
    /// [`Xform::apply`] on a pack, with glam's order of operations
    /// (`((x·px + y·py) + z·pz) + t`), so each lane is rounded alike.
    #[inline(always)]
    pub(super) fn apply8(&self, p: P8) -> P8 {
        match self {
            Xform::Identity => p,
            Xform::Affine(a) => {
                let (m, t) = (a.matrix3, a.translation);
                let row = |x: f32, y: f32, z: f32, t: f32| {
                    p.x * F8::splat(x) + p.y * F8::splat(y) + p.z * F8::splat(z) + F8::splat(t)
                };
                V3::new(
                    row(m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x),
                    row(m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y),
                    row(m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z),
                )
            }
        }
    }
}
