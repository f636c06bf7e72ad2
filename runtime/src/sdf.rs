//! Lowering of the shape IR to a fast f32 evaluator.
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
use sdfl_stdlib::num::V3;
use sdfl_stdlib::param::Arg;
use sdfl_stdlib::sdf;
use sdfl_stdlib::shape::{Aabb, Shape};

/// One lowered node: a signed distance (or bound) in world units.
pub trait Node: Send + Sync {
    fn dist(&self, p: Vec3A) -> f32;
    /// The distance and the id of the primitive attaining it.
    fn dist_id(&self, p: Vec3A) -> (f32, u32);
}

/// What a primitive id stands for, for shading.
#[derive(Debug, Clone)]
pub struct PrimInfo {
    /// World-space centre (the rainbow material's `c`).
    pub center: DVec3,
    /// The material painted on it, if any (else the render's material).
    pub material: Option<Arc<Material>>,
    pub kind: &'static str,
}

/// Options of lowering.
#[derive(Debug, Clone, Copy)]
pub struct LowerOptions {
    /// Build BVHs over large unions (otherwise a union is a plain minimum).
    pub cull: bool,
    /// Unions with at least this many bounded members get a BVH.
    pub bvh_threshold: usize,
}

impl Default for LowerOptions {
    fn default() -> Self {
        LowerOptions {
            cull: true,
            bvh_threshold: 16,
        }
    }
}

/// A lowered scene: evaluator, Lipschitz bound and primitive table.
pub struct Lowered {
    pub root: Box<dyn Node>,
    pub lipschitz: f32,
    pub prims: Vec<PrimInfo>,
    pub bvh_nodes: usize,
}

impl Lowered {
    pub fn new(shape: &Shape, options: LowerOptions) -> Self {
        let mut cx = Lowering {
            options,
            prims: Vec::new(),
            bvh_nodes: 0,
        };
        let root = cx.lower(shape, &Frame::identity());
        Lowered {
            root,
            lipschitz: shape.lipschitz().max(1.0) as f32,
            prims: cx.prims,
            bvh_nodes: cx.bvh_nodes,
        }
    }

    pub fn dist(&self, p: Vec3A) -> f32 {
        self.root.dist(p)
    }

    /// Distances of a batch of points.
    pub fn eval_batch(&self, points: &[Vec3A], out: &mut [f32]) {
        for (p, o) in points.iter().zip(out.iter_mut()) {
            *o = self.root.dist(*p);
        }
    }
}

/// The accumulated transform from world space to a node's local space.
#[derive(Clone)]
struct Frame {
    /// World → local.
    to_local: DAffine3,
    /// Local distances are multiplied by this to give world distances.
    scale: f64,
    material: Option<Arc<Material>>,
}

impl Frame {
    fn identity() -> Self {
        Frame {
            to_local: DAffine3::IDENTITY,
            scale: 1.0,
            material: None,
        }
    }
    fn then(&self, local_step: DAffine3, scale: f64) -> Frame {
        Frame {
            to_local: local_step * self.to_local,
            scale: self.scale * scale,
            material: self.material.clone(),
        }
    }
    fn xform(&self) -> Xform {
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
    fn world_box(&self, local: Aabb) -> Aabb {
        let to_world = self.to_local.inverse();
        local.transformed(|c| to_world.transform_point3(c))
    }
}

#[derive(Clone, Copy)]
enum Xform {
    Identity,
    Affine(Affine3A),
}

impl Xform {
    #[inline(always)]
    fn apply(&self, p: Vec3A) -> Vec3A {
        match self {
            Xform::Identity => p,
            Xform::Affine(a) => a.transform_point3a(p),
        }
    }
}

// ---------------------------------------------------------------- primitives

trait Prim: Send + Sync + 'static {
    fn local(&self, p: Vec3A) -> f32;
}

#[inline(always)]
fn v3(p: Vec3A) -> V3<f32> {
    V3::new(p.x, p.y, p.z)
}

// Each primitive evaluates the one formula in `sdfl_stdlib::sdf`, in f32.

struct Sphere {
    c: V3<f32>,
    r: f32,
}
impl Prim for Sphere {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::sphere(v3(p), self.c, self.r)
    }
}

struct BoxPrim {
    c: V3<f32>,
    size: V3<f32>,
}
impl Prim for BoxPrim {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::cuboid(v3(p), self.c, self.size)
    }
}

struct BoxFrame {
    c: V3<f32>,
    size: V3<f32>,
    thickness: f32,
}
impl Prim for BoxFrame {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::box_frame(v3(p), self.c, self.size, self.thickness)
    }
}

struct Octahedron {
    c: V3<f32>,
    size: f32,
}
impl Prim for Octahedron {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::octahedron(v3(p), self.c, self.size)
    }
}

struct CappedCone {
    c: V3<f32>,
    height: f32,
    bottom: f32,
    top: f32,
}
impl Prim for CappedCone {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::capped_cone(v3(p), self.c, self.height, self.bottom, self.top)
    }
}

struct Ellipsoid {
    c: V3<f32>,
    radii: V3<f32>,
}
impl Prim for Ellipsoid {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::ellipsoid(v3(p), self.c, self.radii)
    }
}

struct Torus {
    c: V3<f32>,
    major: f32,
    minor: f32,
}
impl Prim for Torus {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::torus(v3(p), self.c, self.major, self.minor)
    }
}

struct Capsule {
    a: V3<f32>,
    b: V3<f32>,
    r: f32,
}
impl Prim for Capsule {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::capsule(v3(p), self.a, self.b, self.r)
    }
}

struct Cylinder {
    c: V3<f32>,
    r: f32,
    height: f32,
}
impl Prim for Cylinder {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::cylinder(v3(p), self.c, self.r, self.height)
    }
}

struct Plane {
    n: V3<f32>,
    h: f32,
}
impl Prim for Plane {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::plane(v3(p), self.n, self.h)
    }
}

/// A primitive placed in the world.
struct Leaf<P> {
    prim: P,
    xform: Xform,
    scale: f32,
    id: u32,
}

impl<P: Prim> Node for Leaf<P> {
    #[inline(always)]
    fn dist(&self, p: Vec3A) -> f32 {
        self.prim.local(self.xform.apply(p)) * self.scale
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        (self.dist(p), self.id)
    }
}

// ---------------------------------------------------------------- combinators

struct Union(Vec<Box<dyn Node>>);
impl Node for Union {
    fn dist(&self, p: Vec3A) -> f32 {
        self.0.iter().fold(f32::INFINITY, |m, c| m.min(c.dist(p)))
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        self.0.iter().fold((f32::INFINITY, u32::MAX), |best, c| {
            let d = c.dist_id(p);
            if d.0 < best.0 {
                d
            } else {
                best
            }
        })
    }
}

struct Intersection(Vec<Box<dyn Node>>);
impl Node for Intersection {
    fn dist(&self, p: Vec3A) -> f32 {
        self.0
            .iter()
            .fold(f32::NEG_INFINITY, |m, c| m.max(c.dist(p)))
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        self.0
            .iter()
            .fold((f32::NEG_INFINITY, u32::MAX), |best, c| {
                let d = c.dist_id(p);
                if d.0 > best.0 {
                    d
                } else {
                    best
                }
            })
    }
}

#[derive(Clone, Copy)]
enum SmoothOp {
    Union,
    Intersection,
    Subtraction,
}

/// `Subtraction` with `k = 0` is the sharp `max(a, -b)`.
struct Binary {
    a: Box<dyn Node>,
    b: Box<dyn Node>,
    op: SmoothOp,
    k: f32,
}

impl Binary {
    #[inline(always)]
    fn combine(&self, a: f32, b: f32) -> f32 {
        match self.op {
            SmoothOp::Union => sdf::smooth_min(a, b, self.k),
            SmoothOp::Intersection => sdf::smooth_max(a, b, self.k),
            SmoothOp::Subtraction => sdf::smooth_max(a, -b, self.k),
        }
    }
}

impl Node for Binary {
    fn dist(&self, p: Vec3A) -> f32 {
        self.combine(self.a.dist(p), self.b.dist(p))
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        let (a, ia) = self.a.dist_id(p);
        let (b, ib) = self.b.dist_id(p);
        let id = match self.op {
            SmoothOp::Union => {
                if a <= b {
                    ia
                } else {
                    ib
                }
            }
            SmoothOp::Intersection => {
                if a >= b {
                    ia
                } else {
                    ib
                }
            }
            // The cut surface belongs to the shape being cut.
            SmoothOp::Subtraction => ia,
        };
        (self.combine(a, b), id)
    }
}

/// `d − by` (grown), or `|d| − by` (a shell).
struct Offset {
    inner: Box<dyn Node>,
    by: f32,
    shell: bool,
}
impl Offset {
    #[inline(always)]
    fn apply(&self, d: f32) -> f32 {
        if self.shell {
            d.abs() - self.by
        } else {
            d - self.by
        }
    }
}
impl Node for Offset {
    fn dist(&self, p: Vec3A) -> f32 {
        self.apply(self.inner.dist(p))
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        let (d, id) = self.inner.dist_id(p);
        (self.apply(d), id)
    }
}

/// Inside exactly one of the two; the nearer surface owns the point.
struct Xor(Box<dyn Node>, Box<dyn Node>);
impl Node for Xor {
    fn dist(&self, p: Vec3A) -> f32 {
        sdf::xor(self.0.dist(p), self.1.dist(p))
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        let ((a, ia), (b, ib)) = (self.0.dist_id(p), self.1.dist_id(p));
        (sdf::xor(a, b), if a.abs() <= b.abs() { ia } else { ib })
    }
}

struct Displace {
    inner: Box<dyn Node>,
    xform: Xform,
    amplitude: f32,
    frequency: f32,
}
impl Displace {
    #[inline(always)]
    fn offset(&self, p: Vec3A) -> f32 {
        sdf::displacement(v3(self.xform.apply(p)), self.amplitude, self.frequency)
    }
}
impl Node for Displace {
    fn dist(&self, p: Vec3A) -> f32 {
        self.inner.dist(p) + self.offset(p)
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        let (d, id) = self.inner.dist_id(p);
        (d + self.offset(p), id)
    }
}

// ----------------------------------------------------------------------- BVH

/// Signed distance to an axis-aligned box (centre offset `q`, half extents
/// `half`): the culling bound, in SIMD lanes.
#[inline(always)]
fn box_sd(q: Vec3A, half: Vec3A) -> f32 {
    let q = q.abs() - half;
    q.max(Vec3A::ZERO).length() + q.max_element().min(0.0)
}

#[derive(Clone, Copy)]
struct BvhNode {
    center: Vec3A,
    half: Vec3A,
    /// Leaf: `count > 0`, members `first..first + count`. Inner: children
    /// at `first` and `first + 1`.
    first: u32,
    count: u32,
}

/// A union culled with a bounding volume hierarchy, and a grid of cells
/// each listing the only members that can attain the minimum inside it.
struct BvhUnion {
    nodes: Vec<BvhNode>,
    members: Vec<Box<dyn Node>>,
    /// Each member's world box as (centre, half extents).
    boxes: Vec<(Vec3A, Vec3A)>,
    /// Members without bounds (planes): always evaluated.
    unbounded: Vec<Box<dyn Node>>,
    grid: Option<CellGrid>,
}

const LEAF_SIZE: usize = 4;
const STACK: usize = 64;

/// Candidate lists per cell of a regular grid over the union's bounds.
///
/// For a cell with centre `c` and half-diagonal `r`, the minimum over the
/// members anywhere in the cell is at most `m + L·r`, where `m` is the
/// minimum at `c` and `L` the largest member Lipschitz bound. A member whose
/// box is farther than that from the cell is never below the minimum there
/// (its value is at least the distance to its box), so only the others are
/// listed, and the union evaluated over a point's list is exact.
struct CellGrid {
    min: Vec3A,
    inv_size: Vec3A,
    res: [usize; 3],
    /// (start, count) into `candidates`; `count == FALLBACK`: use the BVH.
    cells: Vec<(u32, u32)>,
    candidates: Vec<u32>,
}

const FALLBACK: u32 = u32::MAX;
/// Longest candidate list kept; cells needing more fall back to the BVH.
const MAX_CANDIDATES: usize = 32;
/// Most BVH nodes visited to list one cell's candidates.
const MAX_CANDIDATE_VISITS: usize = 16 * MAX_CANDIDATES;
/// Members evaluated for a cell's upper bound.
const UPPER_BOUND_MEMBERS: usize = 8;
/// How far the grid extends past the union's bounds, per side, as a
/// fraction of their size.
const GRID_MARGIN: f32 = 0.5;
/// Most grid cells.
const MAX_CELLS: usize = 262_144;

impl CellGrid {
    #[inline(always)]
    fn lookup(&self, p: Vec3A) -> Option<&[u32]> {
        let q = (p - self.min) * self.inv_size;
        // NaN or outside: no cell.
        if !(q.cmpge(Vec3A::ZERO).all()) {
            return None;
        }
        let (i, j, k) = (q.x as usize, q.y as usize, q.z as usize);
        if i >= self.res[0] || j >= self.res[1] || k >= self.res[2] {
            return None;
        }
        let (start, count) = self.cells[(k * self.res[1] + j) * self.res[0] + i];
        (count != FALLBACK).then(|| &self.candidates[start as usize..(start + count) as usize])
    }
}

/// Euclidean gap between two boxes given as (centre, half extents); 0 when
/// they overlap.
#[inline(always)]
fn box_gap(ca: Vec3A, ha: Vec3A, cb: Vec3A, hb: Vec3A) -> f32 {
    ((ca - cb).abs() - ha - hb).max(Vec3A::ZERO).length()
}

impl BvhUnion {
    fn build(items: Vec<(Box<dyn Node>, Aabb, f32)>, unbounded: Vec<Box<dyn Node>>) -> Self {
        let lipschitz = items.iter().map(|i| i.2).fold(1.0f32, f32::max);
        let mut items: Vec<(Box<dyn Node>, Aabb, DVec3)> = items
            .into_iter()
            .map(|(n, b, _)| (n, b, b.center()))
            .collect();
        let mut nodes = vec![BvhNode {
            center: Vec3A::ZERO,
            half: Vec3A::ZERO,
            first: 0,
            count: 0,
        }];
        // Work list of (node index, range of items); items are reordered in
        // place so each leaf's members are contiguous.
        let mut work = vec![(0usize, 0usize, items.len())];
        while let Some((ni, lo, hi)) = work.pop() {
            let bounds = items[lo..hi]
                .iter()
                .map(|i| i.1)
                .reduce(Aabb::union)
                .expect("nonempty range");
            let (center, half) = padded(bounds);
            nodes[ni].center = center;
            nodes[ni].half = half;
            if hi - lo <= LEAF_SIZE {
                nodes[ni].first = lo as u32;
                nodes[ni].count = (hi - lo) as u32;
                continue;
            }
            // Median split along the widest axis of the member centres.
            let (cmin, cmax) = items[lo..hi]
                .iter()
                .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), i| {
                    (a.min(i.2), b.max(i.2))
                });
            let ext = cmax - cmin;
            let axis = if ext.x >= ext.y && ext.x >= ext.z {
                0
            } else if ext.y >= ext.z {
                1
            } else {
                2
            };
            let mid = (lo + hi) / 2;
            items[lo..hi].select_nth_unstable_by(mid - lo, |a, b| a.2[axis].total_cmp(&b.2[axis]));
            let left = nodes.len();
            nodes.push(BvhNode {
                center: Vec3A::ZERO,
                half: Vec3A::ZERO,
                first: 0,
                count: 0,
            });
            nodes.push(BvhNode {
                center: Vec3A::ZERO,
                half: Vec3A::ZERO,
                first: 0,
                count: 0,
            });
            nodes[ni].first = left as u32;
            work.push((left, lo, mid));
            work.push((left + 1, mid, hi));
        }
        let boxes = items.iter().map(|i| padded(i.1)).collect();
        let mut union = BvhUnion {
            nodes,
            members: items.into_iter().map(|i| i.0).collect(),
            boxes,
            unbounded,
            grid: None,
        };
        union.grid = Some(union.build_grid(lipschitz));
        union
    }

    fn build_grid(&self, lipschitz: f32) -> CellGrid {
        use rayon::prelude::*;
        // The grid reaches past the bounds by half their size on each side,
        // where rays approaching the scene spend most of their steps.
        let root = self.nodes[0];
        let half_ext = root.half.max(Vec3A::splat(1e-6)) * (1.0 + 2.0 * GRID_MARGIN);
        let (lo, ext) = (root.center - half_ext, half_ext * 2.0);
        let target = (self.members.len() * 32).clamp(4096, MAX_CELLS) as f32;
        let size = (ext.x * ext.y * ext.z / target).cbrt().max(1e-6);
        let res = [ext.x, ext.y, ext.z].map(|e| ((e / size).ceil() as usize).clamp(1, 128));
        let cell = ext / Vec3A::new(res[0] as f32, res[1] as f32, res[2] as f32);
        let half = cell * 0.5;
        let radius = half.length();
        let lists: Vec<Option<Vec<u32>>> = (0..res[0] * res[1] * res[2])
            .into_par_iter()
            .map(|idx| {
                let (i, j, k) = (
                    idx % res[0],
                    (idx / res[0]) % res[1],
                    idx / (res[0] * res[1]),
                );
                let c = lo + cell * Vec3A::new(i as f32 + 0.5, j as f32 + 0.5, k as f32 + 0.5);
                let m = self.upper_bound(c);
                // Slack for f32 rounding of the member values.
                let bound = m + lipschitz * radius + 1e-4 * (1.0 + m.abs());
                self.candidates(c, half, bound)
            })
            .collect();
        let mut cells = Vec::with_capacity(lists.len());
        let mut candidates = Vec::new();
        for list in lists {
            match list {
                Some(l) => {
                    cells.push((candidates.len() as u32, l.len() as u32));
                    candidates.extend(l);
                }
                None => cells.push((0, FALLBACK)),
            }
        }
        CellGrid {
            min: lo,
            inv_size: Vec3A::ONE / cell,
            res,
            cells,
            candidates,
        }
    }

    /// An upper bound on the union's minimum at `p`: the least value of the
    /// members in the first few leaves nearest `p`. The exact minimum (a
    /// full branch-and-bound search) costs O(n) per cell when members
    /// overlap (coincident primitives prune nothing), and any upper bound
    /// keeps the candidate lists exact: it only makes them longer.
    fn upper_bound(&self, p: Vec3A) -> f32 {
        let mut best = f32::INFINITY;
        let mut leaves = 0;
        let mut n = 0usize;
        // Descend to the nearer child, then scan a few leaves in order.
        loop {
            let node = self.nodes[n];
            if node.count > 0 {
                break;
            }
            let (l, r) = (node.first as usize, node.first as usize + 1);
            n = if self.lower_bound(l, p) <= self.lower_bound(r, p) {
                l
            } else {
                r
            };
        }
        let start = self.nodes[n].first as usize;
        for m in start..self.members.len() {
            best = best.min(self.members[m].dist(p));
            leaves += 1;
            if leaves >= UPPER_BOUND_MEMBERS {
                break;
            }
        }
        best
    }

    /// Members that may be below `bound` somewhere in the cell: those whose
    /// box overlaps it or lies within `bound` of it. `None` past the limit,
    /// or when the search visits too many nodes (the BVH is then used for
    /// the cell, which is exact too): each cell costs O(log n) at most.
    fn candidates(&self, c: Vec3A, h: Vec3A, bound: f32) -> Option<Vec<u32>> {
        let mut out = Vec::new();
        let mut stack = vec![0usize];
        let mut visited = 0;
        while let Some(n) = stack.pop() {
            visited += 1;
            if visited > MAX_CANDIDATE_VISITS {
                return None;
            }
            let node = self.nodes[n];
            let gap = box_gap(c, h, node.center, node.half);
            if gap > 0.0 && gap > bound {
                continue;
            }
            if node.count == 0 {
                stack.push(node.first as usize);
                stack.push(node.first as usize + 1);
                continue;
            }
            for m in node.first..node.first + node.count {
                let (bc, bh) = self.boxes[m as usize];
                let gap = box_gap(c, h, bc, bh);
                if gap == 0.0 || gap <= bound {
                    out.push(m);
                    if out.len() > MAX_CANDIDATES {
                        return None;
                    }
                }
            }
        }
        Some(out)
    }

    #[inline(always)]
    fn lower_bound(&self, n: usize, p: Vec3A) -> f32 {
        box_sd(p - self.nodes[n].center, self.nodes[n].half)
    }

    /// Branch-and-bound minimum; `visit` evaluates a member, returning its
    /// distance, and may record more (the id).
    #[inline(always)]
    fn search(&self, p: Vec3A, mut best: f32, mut visit: impl FnMut(usize, f32) -> f32) -> f32 {
        let mut stack = [0u32; STACK];
        let mut top = 0;
        if self.lower_bound(0, p) < best {
            stack[0] = 0;
            top = 1;
        }
        while top > 0 {
            top -= 1;
            let node = self.nodes[stack[top] as usize];
            if node.count > 0 {
                for m in node.first..node.first + node.count {
                    let (bc, bh) = self.boxes[m as usize];
                    if box_sd(p - bc, bh) < best {
                        best = visit(m as usize, best);
                    }
                }
                continue;
            }
            let (l, r) = (node.first as usize, node.first as usize + 1);
            let (dl, dr) = (self.lower_bound(l, p), self.lower_bound(r, p));
            // Visit the nearer child first: push it last.
            let (near, dn, far, df) = if dl <= dr {
                (l, dl, r, dr)
            } else {
                (r, dr, l, dl)
            };
            if df < best && top < STACK {
                stack[top] = far as u32;
                top += 1;
            }
            if dn < best && top < STACK {
                stack[top] = near as u32;
                top += 1;
            }
        }
        best
    }
}

/// A box as (centre, half extents) in f32, padded by a relative epsilon so
/// rounding never makes the box distance exceed a member's distance.
fn padded(b: Aabb) -> (Vec3A, Vec3A) {
    let pad = 1e-5
        * (b.max - b.min)
            .max_element()
            .max(b.center().abs().max_element())
            .max(1.0);
    let b = b.expand(pad);
    (
        b.center().as_vec3().into(),
        ((b.max - b.min) * 0.5).as_vec3().into(),
    )
}

impl Node for BvhUnion {
    fn dist(&self, p: Vec3A) -> f32 {
        let best = self
            .unbounded
            .iter()
            .fold(f32::INFINITY, |m, c| m.min(c.dist(p)));
        if let Some(list) = self.grid.as_ref().and_then(|g| g.lookup(p)) {
            return list
                .iter()
                .fold(best, |m, i| m.min(self.members[*i as usize].dist(p)));
        }
        self.search(p, best, |m, best| best.min(self.members[m].dist(p)))
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        let mut best = (f32::INFINITY, u32::MAX);
        for c in &self.unbounded {
            let d = c.dist_id(p);
            if d.0 < best.0 {
                best = d;
            }
        }
        if let Some(list) = self.grid.as_ref().and_then(|g| g.lookup(p)) {
            for i in list {
                let d = self.members[*i as usize].dist_id(p);
                if d.0 < best.0 {
                    best = d;
                }
            }
            return best;
        }
        let mut id = best.1;
        let d = self.search(p, best.0, |m, cur| {
            let (d, i) = self.members[m].dist_id(p);
            if d < cur {
                id = i;
                d
            } else {
                cur
            }
        });
        (d, id)
    }
}

// ------------------------------------------------------------------ lowering

struct Lowering {
    options: LowerOptions,
    prims: Vec<PrimInfo>,
    bvh_nodes: usize,
}

impl Lowering {
    fn leaf<P: Prim>(&mut self, prim: P, shape: &Shape, frame: &Frame) -> Box<dyn Node> {
        let id = self.prims.len() as u32;
        let local_center = shape.primitive_center().unwrap_or(DVec3::ZERO);
        self.prims.push(PrimInfo {
            center: frame.to_local.inverse().transform_point3(local_center),
            material: frame.material.clone(),
            kind: shape.name(),
        });
        Box::new(Leaf {
            prim,
            xform: frame.xform(),
            scale: frame.scale as f32,
            id,
        })
    }

    fn lower(&mut self, shape: &Shape, frame: &Frame) -> Box<dyn Node> {
        let f = |a: &Arg<f64>| a.value as f32;
        let c = |a: &Arg<DVec3>| V3::lit(a.value.to_array());
        match shape {
            Shape::Sphere { center, radius } => self.leaf(
                Sphere {
                    c: c(center),
                    r: f(radius),
                },
                shape,
                frame,
            ),
            Shape::Box { center, size } => self.leaf(
                BoxPrim {
                    c: c(center),
                    size: c(size),
                },
                shape,
                frame,
            ),
            Shape::BoxFrame {
                center,
                size,
                thickness,
            } => self.leaf(
                BoxFrame {
                    c: c(center),
                    size: c(size),
                    thickness: f(thickness),
                },
                shape,
                frame,
            ),
            Shape::Torus {
                center,
                major,
                minor,
            } => self.leaf(
                Torus {
                    c: c(center),
                    major: f(major),
                    minor: f(minor),
                },
                shape,
                frame,
            ),
            Shape::Capsule { a, b, radius } => self.leaf(
                Capsule {
                    a: c(a),
                    b: c(b),
                    r: f(radius),
                },
                shape,
                frame,
            ),
            Shape::Cylinder {
                center,
                radius,
                height,
            } => self.leaf(
                Cylinder {
                    c: c(center),
                    r: f(radius),
                    height: f(height),
                },
                shape,
                frame,
            ),
            Shape::Plane { normal, height } => self.leaf(
                Plane {
                    n: V3::lit(normal.to_array()),
                    h: f(height),
                },
                shape,
                frame,
            ),
            Shape::Union(_) => {
                let mut members = Vec::new();
                self.union_members(shape, frame, &mut members);
                self.union(members)
            }
            Shape::Intersection(children) => Box::new(Intersection(
                children.iter().map(|c| self.lower(c, frame)).collect(),
            )),
            Shape::Subtraction(a, b) => self.binary(a, b, SmoothOp::Subtraction, 0.0, frame),
            Shape::SmoothUnion(a, b, k) => self.binary(a, b, SmoothOp::Union, k.value, frame),
            Shape::SmoothIntersection(a, b, k) => {
                self.binary(a, b, SmoothOp::Intersection, k.value, frame)
            }
            Shape::SmoothSubtraction(a, b, k) => {
                self.binary(a, b, SmoothOp::Subtraction, k.value, frame)
            }
            Shape::Translate(..) | Shape::Rotate { .. } | Shape::Scale(..) => {
                let (s, step, scale) = transform(shape).expect("a transform");
                self.lower(s, &frame.then(step, scale))
            }
            Shape::Displace {
                shape: s,
                amplitude,
                frequency,
            } => Box::new(Displace {
                inner: self.lower(s, frame),
                xform: frame.xform(),
                amplitude: (amplitude.value * frame.scale) as f32,
                frequency: frequency.value as f32,
            }),
            Shape::Paint(s, m) => {
                let mut painted = frame.clone();
                painted.material = Some(m.clone());
                self.lower(s, &painted)
            }
            Shape::Octahedron { center, size } => self.leaf(
                Octahedron {
                    c: c(center),
                    size: f(size),
                },
                shape,
                frame,
            ),
            Shape::CappedCone {
                center,
                height,
                bottom,
                top,
            } => self.leaf(
                CappedCone {
                    c: c(center),
                    height: f(height),
                    bottom: f(bottom),
                    top: f(top),
                },
                shape,
                frame,
            ),
            Shape::Ellipsoid { center, radii } => self.leaf(
                Ellipsoid {
                    c: c(center),
                    radii: c(radii),
                },
                shape,
                frame,
            ),
            // Offsets are in the shape's units: scaled like its distances.
            Shape::Round(s, r) => Box::new(Offset {
                inner: self.lower(s, frame),
                by: (r.value * frame.scale) as f32,
                shell: false,
            }),
            Shape::Onion(s, t) => Box::new(Offset {
                inner: self.lower(s, frame),
                by: (t.value * frame.scale) as f32,
                shell: true,
            }),
            Shape::Xor(a, b) => Box::new(Xor(self.lower(a, frame), self.lower(b, frame))),
        }
    }

    fn binary(
        &mut self,
        a: &Shape,
        b: &Shape,
        op: SmoothOp,
        k: f64,
        frame: &Frame,
    ) -> Box<dyn Node> {
        Box::new(Binary {
            a: self.lower(a, frame),
            b: self.lower(b, frame),
            op,
            k: (k * frame.scale) as f32,
        })
    }

    /// Flatten nested unions (through transforms and paint, which do not
    /// change the minimum's structure) into one list of (shape, frame).
    fn union_members<'s>(
        &mut self,
        shape: &'s Shape,
        frame: &Frame,
        out: &mut Vec<(&'s Shape, Frame)>,
    ) {
        match shape {
            Shape::Union(children) => {
                for c in children {
                    self.union_members(c, frame, out);
                }
            }
            Shape::Translate(..) | Shape::Rotate { .. } | Shape::Scale(..)
                if matches!(transform(shape), Some((Shape::Union(_), ..))) =>
            {
                let (s, step, scale) = transform(shape).expect("a transform");
                self.union_members(s, &frame.then(step, scale), out)
            }
            Shape::Paint(s, m) if matches!(**s, Shape::Union(_)) => {
                let mut painted = frame.clone();
                painted.material = Some(m.clone());
                self.union_members(s, &painted, out)
            }
            other => out.push((other, frame.clone())),
        }
    }

    fn union(&mut self, members: Vec<(&Shape, Frame)>) -> Box<dyn Node> {
        let members = if self.options.cull {
            dedup_primitives(members)
        } else {
            members
        };
        let bounded = members.iter().filter(|(s, _)| s.bounds().is_some()).count();
        if !self.options.cull || bounded < self.options.bvh_threshold {
            return Box::new(Union(
                members.iter().map(|(s, f)| self.lower(s, f)).collect(),
            ));
        }
        let mut items = Vec::with_capacity(bounded);
        let mut unbounded = Vec::new();
        for (s, f) in &members {
            let node = self.lower(s, f);
            match s.bounds() {
                Some(b) => items.push((node, f.world_box(b), s.lipschitz() as f32)),
                None => unbounded.push(node),
            }
        }
        let bvh = BvhUnion::build(items, unbounded);
        self.bvh_nodes += bvh.nodes.len();
        Box::new(bvh)
    }
}

/// A transform's child, its world → local step and its distance scale.
fn transform(shape: &Shape) -> Option<(&Shape, DAffine3, f64)> {
    match shape {
        Shape::Translate(s, by) => Some((s, DAffine3::from_translation(-by.value), 1.0)),
        Shape::Rotate { shape, axis, angle } => Some((
            shape,
            DAffine3::from_quat(DQuat::from_axis_angle(*axis, -angle.value)),
            1.0,
        )),
        Shape::Scale(s, f) => Some((
            s,
            DAffine3::from_scale(DVec3::splat(1.0 / f.value)),
            f.value,
        )),
        _ => None,
    }
}

/// The members of a union without exact repeats (same shape, transform
/// and material), keeping the first of each. Only members with equal keys
/// (kind, transform, bounds) are compared, at most 8 per key, and the
/// shapes compared are within the expanded-size budget, so this is
/// O(n log n) plus a bounded number of comparisons. The minimum
/// of equal values is that value, and the first attains it, so the union
/// and the ids it reports are unchanged; coincident copies would otherwise
/// defeat every bound (none is ever below another) and make each
/// evaluation visit all of them. O(n log n).
fn dedup_primitives(members: Vec<(&Shape, Frame)>) -> Vec<(&Shape, Frame)> {
    if members.len() < 2 {
        return members;
    }
    // A cheap key (kind and transform bits) sorts candidates together;
    // equality is then decided exactly.
    let key = |(s, f): &(&Shape, Frame)| {
        let mut k: Vec<u64> = f
            .to_local
            .to_cols_array()
            .iter()
            .map(|x| x.to_bits())
            .collect();
        k.push(f.scale.to_bits());
        k.push(
            f.material
                .as_ref()
                .map_or(0, |m| Arc::as_ptr(m) as usize as u64),
        );
        if let Some(b) = s.bounds() {
            k.extend(
                b.min
                    .to_array()
                    .iter()
                    .chain(&b.max.to_array())
                    .map(|x| x.to_bits()),
            );
        }
        (s.name(), k)
    };
    let mut order: Vec<(usize, (&'static str, Vec<u64>))> = members
        .iter()
        .enumerate()
        .map(|(i, m)| (i, key(m)))
        .collect();
    order.sort_by(|a, b| a.1.cmp(&b.1).then(a.0.cmp(&b.0)));
    let mut drop = vec![false; members.len()];
    let mut kept: Vec<usize> = Vec::new();
    for w in 0..order.len() {
        if w > 0 && order[w].1 != order[w - 1].1 {
            kept.clear();
        }
        let i = order[w].0;
        let same = |j: &usize| {
            let (a, fa) = &members[*j];
            let (b, fb) = &members[i];
            (std::ptr::eq(*a, *b) || a == b)
                && fa.to_local == fb.to_local
                && fa.scale == fb.scale
                && match (&fa.material, &fb.material) {
                    (None, None) => true,
                    (Some(x), Some(y)) => Arc::ptr_eq(x, y),
                    _ => false,
                }
        };
        if kept.iter().any(same) {
            drop[i] = true;
        } else if kept.len() < 8 {
            kept.push(i);
        }
    }
    members
        .into_iter()
        .zip(drop)
        .filter_map(|(m, d)| (!d).then_some(m))
        .collect()
}
