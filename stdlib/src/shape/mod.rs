//! The shape IR: analytic SDF primitives, combinators and transforms, with
//! an f64 reference evaluator. Runtime evaluators are checked against
//! [`Shape::distance`]. Every formula lives once in [`crate::sdf`]; this
//! file knows the tree: how combinators and transforms compose them.
//!
//! Invariant (relied on by BVH culling and tested by property tests): every
//! shape with bounds `B` satisfies `distance(p) ≥ signed_distance_to_box(B, p)`
//! for every point `p`. Bounds are chosen to keep that true, which is why an
//! intersection is bounded by its smallest child box and not by the
//! intersection of the boxes.

use std::sync::Arc;

use glam::DVec3;

use crate::material::Material;
use crate::num::{Real, V3};
use crate::param::{Arg, ParamUse};
use crate::sdf;
pub use crate::sdf::Axis;

mod bounds;
pub mod declare;
mod primitives;
pub mod user;
pub use bounds::Aabb;
pub use declare::{
    ArgKind, ArgReader, ArgSpec, ArgValue, Check, Declared, Family, Invalid, Ir, KindVisitor, Num,
    PrimSpec, Val, WithDeclared,
};
pub use primitives::*;
pub use user::UserShape;

/// Whether a shape's value is the exact Euclidean distance to its surface or
/// only a bound on it (still safe for sphere tracing with its Lipschitz bound).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Exactness {
    /// The value is the Euclidean distance to the surface.
    Exact,
    /// The value only bounds the distance (never overshoots it, up to the
    /// Lipschitz bound), so sphere tracing stays safe but steps shorter.
    Bound,
}

/// A shape tree: primitives at the leaves, combinators and transforms
/// above them; children are shared (`Arc`) so a scene can reuse a part.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// An analytic primitive (declared in `primitives.rs`).
    Prim(Primitive),
    /// A shape the user wrote as a `fn` of the point (`sdf(f, ...)`).
    User(Arc<UserShape>),
    /// Inside any of the shapes: the minimum of their distances (a bound).
    Union(Vec<Arc<Shape>>),
    /// Inside all of the shapes: the maximum of their distances (a bound).
    Intersection(Vec<Arc<Shape>>),
    /// The first shape minus the second.
    Subtraction(Arc<Shape>, Arc<Shape>),
    /// Union blended over radius `k` (polynomial smooth minimum; a bound).
    SmoothUnion(Arc<Shape>, Arc<Shape>, Arg<f64>),
    /// Intersection blended over radius `k` (smooth maximum; a bound).
    SmoothIntersection(Arc<Shape>, Arc<Shape>, Arg<f64>),
    /// The first shape minus the second, blended over radius `k` (a bound).
    SmoothSubtraction(Arc<Shape>, Arc<Shape>, Arg<f64>),
    /// The shape moved by an offset (distances unchanged: exact stays exact).
    Translate(Arc<Shape>, Arg<DVec3>),
    /// Rotation of the shape by `angle` around the unit `axis` through the
    /// origin (points are rotated back by `-angle`).
    Rotate {
        /// The shape rotated.
        shape: Arc<Shape>,
        /// Unit rotation axis (fixed, not trainable).
        axis: DVec3,
        /// Rotation angle in radians.
        angle: Arg<f64>,
    },
    /// Uniform scale about the origin by `s > 0`: `s·d(p/s)`, exact when
    /// the shape is.
    Scale(Arc<Shape>, Arg<f64>),
    /// Adds `amplitude·sin(fx)·sin(fy)·sin(fz)`: a bound, Lipschitz `1 + √3·a·f`.
    Displace {
        /// The shape whose surface is rippled.
        shape: Arc<Shape>,
        /// Height `a` of the ripples, in world units.
        amplitude: Arg<f64>,
        /// Angular frequency `f` of the ripples, per world unit.
        frequency: Arg<f64>,
    },
    /// Gives its primitives a material.
    Paint(Arc<Shape>, Arc<Material>),
    /// The shape grown by `radius` (`d − r`): rounded edges.
    Round(Arc<Shape>, Arg<f64>),
    /// A shell of `thickness` around the surface (`|d| − t`).
    Onion(Arc<Shape>, Arg<f64>),
    /// Inside exactly one of the two shapes.
    Xor(Arc<Shape>, Arc<Shape>),
    /// Cut at the coordinate planes through the origin and pulled `h` apart
    /// each way (the gap filled with the section): a bound (exact outside a
    /// sphere or box centred at the origin, not in general: a part off the
    /// origin moves away from points across the planes).
    Elongate(Arc<Shape>, Arg<DVec3>),
    /// Copies `spacing` apart (a zero component: not repeated on that axis),
    /// `count` per axis centred on the origin (0: infinitely many).
    Repeat {
        /// The shape copied.
        shape: Arc<Shape>,
        /// Distance between neighbouring copies per axis (0: not repeated).
        spacing: Arg<DVec3>,
        /// Copies per axis (0: infinitely many, the shape unbounded there).
        count: [u32; 3],
    },
    /// The shape's half on the positive side of `axis`, reflected to the other.
    Mirror(Arc<Shape>, Axis),
    /// Each slice across Z turned by `rate·z` (a bound, see [`Shape::lipschitz`]).
    Twist(Arc<Shape>, Arg<f64>),
    /// Each slice across X turned about Z by `rate·x` (a bound).
    Bend(Arc<Shape>, Arg<f64>),
    /// Non-uniform scale: `max(min(s)·d(p/s), box)`, a bound.
    ScaleXyz(Arc<Shape>, Arg<DVec3>),
}

impl From<Primitive> for Shape {
    fn from(p: Primitive) -> Shape {
        Shape::Prim(p)
    }
}

pub use crate::param::{ArgSource, Fixed};

/// A shape evaluated at a point: the distance, and the centre and material
/// of the primitive that attains it (what the rainbow colour needs).
#[derive(Debug, Clone, Copy)]
pub struct Sample<'s, T> {
    /// Signed distance (or bound) from the point to the shape's surface.
    pub d: T,
    /// World-space centre of the attaining primitive.
    pub center: V3<T>,
    /// The innermost `paint` over that primitive, if any.
    pub material: Option<&'s Arc<Material>>,
}

impl<'s, T: Real> Sample<'s, T> {
    fn prim(d: T, center: V3<T>) -> Self {
        Sample {
            d,
            center,
            material: None,
        }
    }
    fn with_d(self, d: T) -> Self {
        Sample { d, ..self }
    }
    /// `then` where `a > b`, else `otherwise`: a select (lane by lane, no
    /// branch on the point) when both have the same material, a branch on
    /// the values when they differ (a material is not a number).
    fn if_gt(a: T, b: T, then: Self, otherwise: Self) -> Self {
        let same = match (then.material, otherwise.material) {
            (None, None) => true,
            (Some(x), Some(y)) => Arc::ptr_eq(x, y),
            _ => false,
        };
        if !same {
            return if a.val() > b.val() { then } else { otherwise };
        }
        let pick = |x: T, y: T| T::if_gt(a, b, x, y);
        Sample {
            d: pick(then.d, otherwise.d),
            center: V3::new(
                pick(then.center.x, otherwise.center.x),
                pick(then.center.y, otherwise.center.y),
                pick(then.center.z, otherwise.center.z),
            ),
            material: then.material,
        }
    }
}

/// Rotation by `angle` about `axis` for the generic evaluator.
fn rot<T: Real>(p: V3<T>, axis: DVec3, angle: T) -> V3<T> {
    sdf::rotate(p, V3::lit(axis.to_array()), angle)
}

impl Shape {
    /// The signed distance (or bound) at `p`, evaluated directly in f64.
    pub fn distance(&self, p: DVec3) -> f64 {
        self.sample(p.into(), &Fixed).d
    }

    /// The shape at `p` in any number type, its arguments read from `args`:
    /// the one walk of the tree that every non-culled evaluator shares.
    pub fn sample<'s, T: Real, A: ArgSource<T>>(&'s self, p: V3<T>, args: &A) -> Sample<'s, T> {
        match self {
            Shape::Prim(x) => {
                let (d, c) = x.sample(p, args);
                Sample::prim(d, c)
            }
            Shape::User(u) => Sample::prim(u.sample(p, args), V3::lit(u.bound.center().to_array())),
            // Ties go to the first child, as in the lowered evaluators.
            Shape::Union(children) => children
                .iter()
                .map(|c| c.sample(p, args))
                .reduce(|best, s| Sample::if_gt(best.d, s.d, s, best))
                .expect("unions have children"),
            Shape::Intersection(children) => children
                .iter()
                .map(|c| c.sample(p, args))
                .reduce(|best, s| Sample::if_gt(s.d, best.d, s, best))
                .expect("intersections have children"),
            Shape::Subtraction(a, b) => {
                let (sa, sb) = (a.sample(p, args), b.sample(p, args));
                // The cut surface belongs to the shape being cut.
                sa.with_d(sa.d.max(-sb.d))
            }
            Shape::SmoothUnion(a, b, k) => {
                let (sa, sb) = (a.sample(p, args), b.sample(p, args));
                let d = sdf::smooth_min(sa.d, sb.d, args.scalar(k));
                // The colour of the nearer (the first on ties).
                Sample::if_gt(sa.d, sb.d, sb, sa).with_d(d)
            }
            Shape::SmoothIntersection(a, b, k) => {
                let (sa, sb) = (a.sample(p, args), b.sample(p, args));
                let d = sdf::smooth_max(sa.d, sb.d, args.scalar(k));
                Sample::if_gt(sb.d, sa.d, sb, sa).with_d(d)
            }
            Shape::SmoothSubtraction(a, b, k) => {
                let (sa, sb) = (a.sample(p, args), b.sample(p, args));
                sa.with_d(sdf::smooth_max(sa.d, -sb.d, args.scalar(k)))
            }
            Shape::Translate(s, by) => {
                let by = args.vector(by);
                let inner = s.sample(p - by, args);
                Sample {
                    center: inner.center + by,
                    ..inner
                }
            }
            Shape::Rotate { shape, axis, angle } => {
                let angle = args.scalar(angle);
                let inner = shape.sample(rot(p, *axis, -angle), args);
                Sample {
                    center: rot(inner.center, *axis, angle),
                    ..inner
                }
            }
            Shape::Scale(s, f) => {
                let f = args.scalar(f);
                let inner = s.sample(p * (T::one() / f), args);
                Sample {
                    d: inner.d * f,
                    center: inner.center * f,
                    ..inner
                }
            }
            Shape::Displace {
                shape,
                amplitude,
                frequency,
            } => {
                let inner = shape.sample(p, args);
                let off = sdf::displacement(p, args.scalar(amplitude), args.scalar(frequency));
                inner.with_d(inner.d + off)
            }
            Shape::Paint(s, m) => {
                let inner = s.sample(p, args);
                Sample {
                    material: inner.material.or(Some(m)),
                    ..inner
                }
            }
            Shape::Round(s, r) => {
                let inner = s.sample(p, args);
                inner.with_d(inner.d - args.scalar(r))
            }
            Shape::Onion(s, t) => {
                let inner = s.sample(p, args);
                inner.with_d(inner.d.abs() - args.scalar(t))
            }
            Shape::Xor(a, b) => {
                let (sa, sb) = (a.sample(p, args), b.sample(p, args));
                // The surface nearer the point owns it.
                let d = sdf::xor(sa.d, sb.d);
                if sa.d.abs().val() <= sb.d.abs().val() {
                    sa
                } else {
                    sb
                }
                .with_d(d)
            }
            Shape::Elongate(s, h) => s.sample(sdf::elongate(p, args.vector(h)), args),
            Shape::Repeat {
                shape,
                spacing,
                count,
            } => {
                let s = args.vector(spacing);
                let extent = shape.extent();
                let ranges = repeat_ranges(p, s, extent, *count);
                let bound = shape
                    .repeated_as_bound()
                    .map(|b| (V3::lit(b.min.to_array()), V3::lit(b.max.to_array())));
                let mut best: Option<Sample<'s, T>> = None;
                for kx in cells(ranges[0]) {
                    for ky in cells(ranges[1]) {
                        for kz in cells(ranges[2]) {
                            let off = V3::new(s.x * T::lit(kx), s.y * T::lit(ky), s.z * T::lit(kz));
                            let mut inner = shape.sample(p - off, args);
                            if let Some((lo, hi)) = bound {
                                inner.d = sdf::repeat_bound_term(inner.d, p - off, s, lo, hi);
                            }
                            if best.is_none_or(|b| inner.d.val() < b.d.val()) {
                                best = Some(Sample {
                                    center: inner.center + off,
                                    ..inner
                                });
                            }
                        }
                    }
                }
                let mut best = best.expect("every range holds a copy");
                if let Some(b) = bound {
                    if let Some(d) = sdf::repeat_beyond(p, s, b, *count, ranges) {
                        best.d = best.d.min(d);
                    }
                }
                best
            }
            Shape::Mirror(s, axis) => {
                let mut a = p.to_array();
                a[axis.index()] = a[axis.index()].abs();
                s.sample(V3::from_array(a), args)
            }
            Shape::Twist(s, rate) | Shape::Bend(s, rate) => {
                let (radius, lo, hi) = s.turn_region();
                let (q, e) = sdf::into_cylinder(p, radius, lo, hi);
                let k = args.scalar(rate);
                let w = if matches!(self, Shape::Twist(..)) {
                    sdf::twist(q, k)
                } else {
                    sdf::bend(q, k)
                };
                let inner = s.sample(w, args);
                inner.with_d(sdf::beyond(e, inner.d))
            }
            Shape::ScaleXyz(s, f) => {
                let f = args.vector(f);
                let mul = |a: V3<T>| a.zip(f, |x, y| x * y);
                let inner = s.sample(p.zip(f, |x, y| x / y), args);
                let mut d = inner.d * f.min_element();
                // Scaled distances fall behind along the stretched axes: the
                // scaled box's distance (also a bound) keeps culling exact.
                if let Some(b) = s.bounds() {
                    let (c, size) = (
                        V3::lit(b.center().to_array()),
                        V3::lit((b.max - b.min).to_array()),
                    );
                    d = d.max(sdf::cuboid(p, mul(c), mul(size)));
                }
                Sample {
                    d,
                    center: mul(inner.center),
                    ..inner
                }
            }
        }
    }

    /// Every trainable argument in the tree (materials of `paint` included),
    /// in a fixed order: children after their parent, left to right.
    pub fn visit_params<'s>(&'s self, f: &mut dyn FnMut(&'s ParamUse)) {
        let mut s1 = |a: &'s Arg<f64>| {
            if let Some(u) = &a.param {
                f(u)
            }
        };
        match self {
            Shape::Prim(x) => x.visit_params(f),
            Shape::User(u) => u.visit_params(f),
            Shape::Twist(_, k) | Shape::Bend(_, k) => s1(k),
            Shape::SmoothUnion(_, _, k)
            | Shape::SmoothIntersection(_, _, k)
            | Shape::SmoothSubtraction(_, _, k) => s1(k),
            Shape::Rotate { angle, .. } => s1(angle),
            Shape::Scale(_, f) | Shape::Round(_, f) | Shape::Onion(_, f) => s1(f),
            Shape::Displace {
                amplitude,
                frequency,
                ..
            } => {
                s1(amplitude);
                s1(frequency)
            }
            Shape::Elongate(_, v) | Shape::ScaleXyz(_, v) | Shape::Translate(_, v) => {
                if let Some(u) = &v.param {
                    f(u)
                }
            }
            Shape::Repeat { spacing, .. } => {
                if let Some(u) = &spacing.param {
                    f(u)
                }
            }
            Shape::Paint(_, m) => m.visit_params(f),
            Shape::Union(_)
            | Shape::Intersection(_)
            | Shape::Subtraction(..)
            | Shape::Xor(..)
            | Shape::Mirror(..) => {}
        }
        for c in self.children() {
            c.visit_params(f);
        }
    }

    /// The shapes this one is built from (none for primitives): the one
    /// place that knows the tree's structure, for walks over it.
    pub fn children(&self) -> Vec<&Arc<Shape>> {
        match self {
            Shape::Union(c) | Shape::Intersection(c) => c.iter().collect(),
            Shape::Subtraction(a, b)
            | Shape::SmoothUnion(a, b, _)
            | Shape::SmoothIntersection(a, b, _)
            | Shape::SmoothSubtraction(a, b, _)
            | Shape::Xor(a, b) => vec![a, b],
            Shape::Translate(s, _)
            | Shape::Rotate { shape: s, .. }
            | Shape::Scale(s, _)
            | Shape::Paint(s, _)
            | Shape::Round(s, _)
            | Shape::Onion(s, _)
            | Shape::Displace { shape: s, .. }
            | Shape::Elongate(s, _)
            | Shape::Repeat { shape: s, .. }
            | Shape::Mirror(s, _)
            | Shape::Twist(s, _)
            | Shape::Bend(s, _)
            | Shape::ScaleXyz(s, _) => vec![s],
            Shape::Prim(_) | Shape::User(_) => Vec::new(),
        }
    }

    /// The centre used by the rainbow material, for primitives (in the
    /// primitive's own frame).
    pub fn primitive_center(&self) -> Option<DVec3> {
        match self {
            Shape::Prim(x) => Some(x.center()),
            Shape::User(u) => Some(u.bound.center()),
            _ => None,
        }
    }

    /// Primitive evaluations per point without culling (what training
    /// pays): a repetition evaluates its child in every copy that may be
    /// nearest, at most [`Shape::copies_per_point`].
    pub fn evaluation_cost(&self) -> f64 {
        let children = self.children();
        if children.is_empty() {
            return self.leaf_cost();
        }
        let sum: f64 = children.iter().map(|s| s.evaluation_cost()).sum();
        sum * self.copies_per_point() as f64
    }

    /// What one evaluation of a leaf counts: 1 for a primitive, a user
    /// function's instructions in primitive distances.
    fn leaf_cost(&self) -> f64 {
        match self {
            Shape::User(u) => u.evaluation_cost(),
            _ => 1.0,
        }
    }

    /// For a repetition, the most copies evaluated at one point (the
    /// product over axes of the copies within reach); 1 otherwise.
    pub fn copies_per_point(&self) -> u64 {
        let Shape::Repeat {
            shape,
            spacing,
            count,
        } = self
        else {
            return 1;
        };
        let e = shape.extent();
        // In f64: tiny spacings make huge counts, refused by `repeat`.
        let n: f64 = (0..3)
            .map(|i| {
                let s = spacing.value[i];
                if s <= 0.0 {
                    return 1.0;
                }
                let within = (2.0 * reach(e[i], s)).floor() + 1.0;
                if count[i] == 0 {
                    within
                } else {
                    within.min(count[i] as f64)
                }
            })
            .product();
        n.min(u64::MAX as f64) as u64
    }

    /// Per axis, how far the shape reaches from its origin (`max(|min|,
    /// |max|)` of its bounds; infinite when unbounded).
    pub fn extent(&self) -> DVec3 {
        match self.bounds() {
            Some(b) => b.min.abs().max(b.max.abs()),
            None => DVec3::INFINITY,
        }
    }

    /// The cylinder about Z that holds the shape however it is turned
    /// about Z: its radius and its Z range (twists and bends).
    pub fn turn_region(&self) -> (f64, f64, f64) {
        match self.bounds() {
            Some(b) => {
                let (x, y) = (
                    b.min.x.abs().max(b.max.x.abs()),
                    b.min.y.abs().max(b.max.y.abs()),
                );
                ((x * x + y * y).sqrt(), b.min.z, b.max.z)
            }
            None => (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY),
        }
    }

    /// Number of primitives (leaves).
    pub fn primitive_count(&self) -> usize {
        let children = self.children();
        if children.is_empty() {
            1
        } else {
            children.iter().map(|s| s.primitive_count()).sum()
        }
    }

    /// The built-in that makes this node (a primitive's own name): its kind
    /// in reports and the primitive table.
    pub fn name(&self) -> &'static str {
        match self {
            Shape::Prim(x) => x.spec().name,
            Shape::User(_) => user::BUILTIN,
            Shape::Union(_) => "union",
            Shape::Intersection(_) => "intersection",
            Shape::Subtraction(..) => "subtraction",
            Shape::SmoothUnion(..) => "smooth_union",
            Shape::SmoothIntersection(..) => "smooth_intersection",
            Shape::SmoothSubtraction(..) => "smooth_subtraction",
            Shape::Translate(..) => "translate",
            Shape::Rotate { .. } => "rotate",
            Shape::Scale(..) => "scale",
            Shape::Displace { .. } => "displace",
            Shape::Paint(..) => "paint",
            Shape::Round(..) => "round",
            Shape::Onion(..) => "onion",
            Shape::Xor(..) => "xor",
            Shape::Elongate(..) => "elongate",
            Shape::Repeat { .. } => "repeat",
            Shape::Mirror(..) => "mirror",
            Shape::Twist(..) => "twist",
            Shape::Bend(..) => "bend",
            Shape::ScaleXyz(..) => "scale",
        }
    }
}

/// How many cells from a point a repetition must look (see
/// [`sdf::repeat_range`]); an unbounded child is refused by `repeat`, and
/// gets its nearest two copies here.
pub fn reach(extent: f64, spacing: f64) -> f64 {
    if extent.is_finite() {
        0.5 + extent / spacing
    } else {
        1.0
    }
}

/// The copy ranges of a repetition at `p` (a single copy on axes with no spacing).
pub fn repeat_ranges<T: Real>(
    p: V3<T>,
    spacing: V3<T>,
    extent: DVec3,
    count: [u32; 3],
) -> [(f64, f64); 3] {
    let (p, s) = (p.to_array(), spacing.to_array());
    std::array::from_fn(|i| {
        let s = s[i].val();
        if s > 0.0 {
            sdf::repeat_range(
                p[i].val() / s,
                reach(extent[i], s),
                (count[i] > 0).then_some(count[i]),
            )
        } else {
            (0.0, 0.0)
        }
    })
}

/// The copy indices of a closed range, one apart.
pub fn cells((lo, hi): (f64, f64)) -> impl Iterator<Item = f64> {
    (0..=((hi - lo).round().max(0.0) as i64)).map(move |j| lo + j as f64)
}
