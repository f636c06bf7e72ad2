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

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: DVec3,
    pub max: DVec3,
}

impl Aabb {
    pub fn new(min: DVec3, max: DVec3) -> Self {
        Aabb { min, max }
    }
    pub fn around(center: DVec3, half: DVec3) -> Self {
        Aabb::new(center - half, center + half)
    }
    pub fn union(self, o: Aabb) -> Aabb {
        Aabb::new(self.min.min(o.min), self.max.max(o.max))
    }
    pub fn expand(self, by: f64) -> Aabb {
        Aabb::new(self.min - DVec3::splat(by), self.max + DVec3::splat(by))
    }
    pub fn center(self) -> DVec3 {
        (self.min + self.max) * 0.5
    }
    pub fn volume(self) -> f64 {
        let e = (self.max - self.min).max(DVec3::ZERO);
        e.x * e.y * e.z
    }
    /// Exact signed distance from `p` to the box.
    pub fn signed_distance(self, p: DVec3) -> f64 {
        let q = (p - self.center()).abs() - (self.max - self.min) * 0.5;
        q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
    }
    /// The box of the 8 corners under a transform.
    pub fn transformed(self, f: impl Fn(DVec3) -> DVec3) -> Aabb {
        let mut out = Aabb::new(DVec3::INFINITY, DVec3::NEG_INFINITY);
        for i in 0..8 {
            let c = DVec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            );
            let t = f(c);
            out = Aabb::new(out.min.min(t), out.max.max(t));
        }
        out
    }
}

/// Whether a shape's value is the exact Euclidean distance to its surface or
/// only a bound on it (still safe for sphere tracing with its Lipschitz bound).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Exactness {
    Exact,
    Bound,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    Sphere {
        center: Arg<DVec3>,
        radius: Arg<f64>,
    },
    /// `size` holds the full side lengths.
    Box {
        center: Arg<DVec3>,
        size: Arg<DVec3>,
    },
    BoxFrame {
        center: Arg<DVec3>,
        size: Arg<DVec3>,
        thickness: Arg<f64>,
    },
    /// Vertices at `±size` on each axis (a bound).
    Octahedron {
        center: Arg<DVec3>,
        size: Arg<f64>,
    },
    /// Along Z: full `height`, radius `bottom` at the lower cap, `top` at the upper.
    CappedCone {
        center: Arg<DVec3>,
        height: Arg<f64>,
        bottom: Arg<f64>,
        top: Arg<f64>,
    },
    /// Semi-axes `radii` (a bound).
    Ellipsoid {
        center: Arg<DVec3>,
        radii: Arg<DVec3>,
    },
    /// In the XY plane around the Z axis.
    Torus {
        center: Arg<DVec3>,
        major: Arg<f64>,
        minor: Arg<f64>,
    },
    Capsule {
        a: Arg<DVec3>,
        b: Arg<DVec3>,
        radius: Arg<f64>,
    },
    /// Capped, along the Z axis.
    Cylinder {
        center: Arg<DVec3>,
        radius: Arg<f64>,
        height: Arg<f64>,
    },
    /// `dot(p, normal) - height`; `normal` is unit length.
    Plane {
        normal: DVec3,
        height: Arg<f64>,
    },
    Union(Vec<Arc<Shape>>),
    Intersection(Vec<Arc<Shape>>),
    /// The first shape minus the second.
    Subtraction(Arc<Shape>, Arc<Shape>),
    SmoothUnion(Arc<Shape>, Arc<Shape>, Arg<f64>),
    SmoothIntersection(Arc<Shape>, Arc<Shape>, Arg<f64>),
    SmoothSubtraction(Arc<Shape>, Arc<Shape>, Arg<f64>),
    Translate(Arc<Shape>, Arg<DVec3>),
    /// Rotation of the shape by `angle` around the unit `axis` through the
    /// origin (points are rotated back by `-angle`).
    Rotate {
        shape: Arc<Shape>,
        axis: DVec3,
        angle: Arg<f64>,
    },
    Scale(Arc<Shape>, Arg<f64>),
    /// Adds `amplitude·sin(fx)·sin(fy)·sin(fz)`: a bound, Lipschitz `1 + √3·a·f`.
    Displace {
        shape: Arc<Shape>,
        amplitude: Arg<f64>,
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
}

/// Where the numeric arguments of a shape come from when it is evaluated:
/// their fixed values ([`Fixed`]), or trainable values with tangents.
pub trait ArgSource<T: Real> {
    fn scalar(&self, a: &Arg<f64>) -> T;
    fn vector(&self, a: &Arg<DVec3>) -> V3<T>;
}

/// Every argument at its value (no parameters): the reference evaluator.
pub struct Fixed;

impl<T: Real> ArgSource<T> for Fixed {
    #[inline(always)]
    fn scalar(&self, a: &Arg<f64>) -> T {
        T::lit(a.value)
    }
    #[inline(always)]
    fn vector(&self, a: &Arg<DVec3>) -> V3<T> {
        V3::lit(a.value.to_array())
    }
}

/// A shape evaluated at a point: the distance, and the centre and material
/// of the primitive that attains it (what the rainbow colour needs).
#[derive(Debug, Clone, Copy)]
pub struct Sample<'s, T> {
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
            Shape::Sphere { center, radius } => {
                let c = args.vector(center);
                Sample::prim(sdf::sphere(p, c, args.scalar(radius)), c)
            }
            Shape::Box { center, size } => {
                let c = args.vector(center);
                Sample::prim(sdf::cuboid(p, c, args.vector(size)), c)
            }
            Shape::BoxFrame {
                center,
                size,
                thickness,
            } => {
                let c = args.vector(center);
                let d = sdf::box_frame(p, c, args.vector(size), args.scalar(thickness));
                Sample::prim(d, c)
            }
            Shape::Ellipsoid { center, radii } => {
                let c = args.vector(center);
                Sample::prim(sdf::ellipsoid(p, c, args.vector(radii)), c)
            }
            Shape::Octahedron { center, size } => {
                let c = args.vector(center);
                Sample::prim(sdf::octahedron(p, c, args.scalar(size)), c)
            }
            Shape::CappedCone {
                center,
                height,
                bottom,
                top,
            } => {
                let c = args.vector(center);
                let (h, b, t) = (args.scalar(height), args.scalar(bottom), args.scalar(top));
                Sample::prim(sdf::capped_cone(p, c, h, b, t), c)
            }
            Shape::Torus {
                center,
                major,
                minor,
            } => {
                let c = args.vector(center);
                let d = sdf::torus(p, c, args.scalar(major), args.scalar(minor));
                Sample::prim(d, c)
            }
            Shape::Capsule { a, b, radius } => {
                let (a, b) = (args.vector(a), args.vector(b));
                let d = sdf::capsule(p, a, b, args.scalar(radius));
                Sample::prim(d, (a + b) * T::lit(0.5))
            }
            Shape::Cylinder {
                center,
                radius,
                height,
            } => {
                let c = args.vector(center);
                let d = sdf::cylinder(p, c, args.scalar(radius), args.scalar(height));
                Sample::prim(d, c)
            }
            Shape::Plane { normal, height } => {
                let n = V3::lit(normal.to_array());
                let h = args.scalar(height);
                Sample::prim(sdf::plane(p, n, h), n * h)
            }
            // Ties go to the first child, as in the lowered evaluators.
            Shape::Union(children) => children
                .iter()
                .map(|c| c.sample(p, args))
                .reduce(|best, s| if s.d.val() < best.d.val() { s } else { best })
                .expect("unions have children"),
            Shape::Intersection(children) => children
                .iter()
                .map(|c| c.sample(p, args))
                .reduce(|best, s| if s.d.val() > best.d.val() { s } else { best })
                .expect("intersections have children"),
            Shape::Subtraction(a, b) => {
                let (sa, sb) = (a.sample(p, args), b.sample(p, args));
                // The cut surface belongs to the shape being cut.
                sa.with_d(sa.d.max(-sb.d))
            }
            Shape::SmoothUnion(a, b, k) => {
                let (sa, sb) = (a.sample(p, args), b.sample(p, args));
                let d = sdf::smooth_min(sa.d, sb.d, args.scalar(k));
                if sa.d.val() <= sb.d.val() { sa } else { sb }.with_d(d)
            }
            Shape::SmoothIntersection(a, b, k) => {
                let (sa, sb) = (a.sample(p, args), b.sample(p, args));
                let d = sdf::smooth_max(sa.d, sb.d, args.scalar(k));
                if sa.d.val() >= sb.d.val() { sa } else { sb }.with_d(d)
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
            Shape::Sphere { radius, .. } => s1(radius),
            Shape::BoxFrame { thickness, .. } => s1(thickness),
            Shape::Torus { major, minor, .. } => {
                s1(major);
                s1(minor)
            }
            Shape::Capsule { radius, .. } => s1(radius),
            Shape::Cylinder { radius, height, .. } => {
                s1(radius);
                s1(height)
            }
            Shape::Plane { height, .. } => s1(height),
            Shape::Octahedron { size, .. } => s1(size),
            Shape::CappedCone {
                height,
                bottom,
                top,
                ..
            } => {
                s1(height);
                s1(bottom);
                s1(top)
            }
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
            _ => {}
        }
        let mut v3 = |a: &'s Arg<DVec3>| {
            if let Some(u) = &a.param {
                f(u)
            }
        };
        match self {
            Shape::Sphere { center, .. }
            | Shape::Torus { center, .. }
            | Shape::Cylinder { center, .. }
            | Shape::Octahedron { center, .. }
            | Shape::CappedCone { center, .. } => v3(center),
            Shape::Box { center, size } | Shape::BoxFrame { center, size, .. } => {
                v3(center);
                v3(size)
            }
            Shape::Ellipsoid { center, radii } => {
                v3(center);
                v3(radii)
            }
            Shape::Capsule { a, b, .. } => {
                v3(a);
                v3(b)
            }
            Shape::Translate(_, by) => v3(by),
            Shape::Paint(_, m) => m.visit_params(f),
            _ => {}
        }
        for c in self.children() {
            c.visit_params(f);
        }
    }

    pub fn exactness(&self) -> Exactness {
        match self {
            Shape::Sphere { .. }
            | Shape::Box { .. }
            | Shape::BoxFrame { .. }
            | Shape::Torus { .. }
            | Shape::Capsule { .. }
            | Shape::Cylinder { .. }
            | Shape::CappedCone { .. }
            | Shape::Plane { .. } => Exactness::Exact,
            // Offsets of exact distances are exact outside; inside (and
            // for a shell, on both sides) only a bound in general.
            Shape::Ellipsoid { .. }
            | Shape::Octahedron { .. }
            | Shape::Round(..)
            | Shape::Onion(..)
            | Shape::Xor(..) => Exactness::Bound,
            // A union of exact SDFs is exact outside but only a bound inside.
            Shape::Union(c) if c.len() == 1 => c[0].exactness(),
            Shape::Intersection(c) if c.len() == 1 => c[0].exactness(),
            Shape::Union(_)
            | Shape::Intersection(_)
            | Shape::Subtraction(..)
            | Shape::SmoothUnion(..)
            | Shape::SmoothIntersection(..)
            | Shape::SmoothSubtraction(..)
            | Shape::Displace { .. } => Exactness::Bound,
            Shape::Translate(s, _)
            | Shape::Rotate { shape: s, .. }
            | Shape::Scale(s, _)
            | Shape::Paint(s, _) => s.exactness(),
        }
    }

    /// A bound `L` on the gradient norm: sphere tracing steps `d / L`.
    pub fn lipschitz(&self) -> f64 {
        match self {
            Shape::Union(c) | Shape::Intersection(c) => {
                c.iter().map(|s| s.lipschitz()).fold(1.0, f64::max)
            }
            Shape::Subtraction(a, b)
            | Shape::SmoothUnion(a, b, _)
            | Shape::SmoothIntersection(a, b, _)
            | Shape::SmoothSubtraction(a, b, _)
            | Shape::Xor(a, b) => a.lipschitz().max(b.lipschitz()),
            Shape::Translate(s, _)
            | Shape::Rotate { shape: s, .. }
            | Shape::Scale(s, _)
            | Shape::Paint(s, _)
            | Shape::Round(s, _)
            | Shape::Onion(s, _) => s.lipschitz(),
            Shape::Displace {
                shape,
                amplitude,
                frequency,
            } => shape.lipschitz() + 3f64.sqrt() * amplitude.value.abs() * frequency.value.abs(),
            _ => 1.0,
        }
    }

    /// A box `B` with `distance(p) ≥ B.signed_distance(p)` everywhere, or
    /// `None` for unbounded shapes (planes).
    pub fn bounds(&self) -> Option<Aabb> {
        match self {
            Shape::Sphere { center, radius } => {
                Some(Aabb::around(center.value, DVec3::splat(radius.value)))
            }
            Shape::Box { center, size } | Shape::BoxFrame { center, size, .. } => {
                Some(Aabb::around(center.value, size.value * 0.5))
            }
            // The circumscribed sphere's cube: the bound grows like a
            // distance only beyond that sphere.
            Shape::Ellipsoid { center, radii } => Some(Aabb::around(
                center.value,
                DVec3::splat(radii.value.max_element()),
            )),
            Shape::Torus {
                center,
                major,
                minor,
            } => {
                let (r, m) = (major.value, minor.value);
                Some(Aabb::around(center.value, DVec3::new(r + m, r + m, m)))
            }
            Shape::Capsule { a, b, radius } => {
                Some(Aabb::new(a.value.min(b.value), a.value.max(b.value)).expand(radius.value))
            }
            Shape::Cylinder {
                center,
                radius,
                height,
            } => Some(Aabb::around(
                center.value,
                DVec3::new(radius.value, radius.value, height.value * 0.5),
            )),
            Shape::Octahedron { center, size } => {
                Some(Aabb::around(center.value, DVec3::splat(size.value)))
            }
            Shape::CappedCone {
                center,
                height,
                bottom,
                top,
            } => {
                let r = bottom.value.max(top.value);
                Some(Aabb::around(
                    center.value,
                    DVec3::new(r, r, height.value * 0.5),
                ))
            }
            Shape::Plane { .. } => None,
            Shape::Union(children) => {
                let mut acc: Option<Aabb> = None;
                for c in children {
                    let b = c.bounds()?;
                    acc = Some(acc.map_or(b, |a| a.union(b)));
                }
                acc
            }
            Shape::Intersection(children) => smallest(children.iter().filter_map(|c| c.bounds())),
            Shape::SmoothIntersection(a, b, _) => {
                smallest([a.bounds(), b.bounds()].into_iter().flatten())
            }
            Shape::Subtraction(a, _) | Shape::SmoothSubtraction(a, _, _) => a.bounds(),
            Shape::SmoothUnion(a, b, k) => {
                Some(a.bounds()?.union(b.bounds()?).expand(k.value * 0.25))
            }
            Shape::Translate(s, v) => {
                let v = v.value;
                s.bounds().map(|b| Aabb::new(b.min + v, b.max + v))
            }
            Shape::Rotate { shape, axis, angle } => {
                let q = glam::DQuat::from_axis_angle(*axis, angle.value);
                shape.bounds().map(|b| b.transformed(|c| q * c))
            }
            Shape::Scale(s, f) => {
                let f = f.value;
                s.bounds().map(|b| Aabb::new(b.min * f, b.max * f))
            }
            Shape::Displace {
                shape, amplitude, ..
            } => shape.bounds().map(|b| b.expand(amplitude.value.abs())),
            Shape::Paint(s, _) => s.bounds(),
            // Growing by r moves the surface out by at most r/L ≤ r.
            Shape::Round(s, r) => s.bounds().map(|b| b.expand(r.value)),
            Shape::Onion(s, t) => s.bounds().map(|b| b.expand(t.value)),
            Shape::Xor(a, b) => Some(a.bounds()?.union(b.bounds()?)),
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
            | Shape::Displace { shape: s, .. } => vec![s],
            Shape::Sphere { .. }
            | Shape::Ellipsoid { .. }
            | Shape::Octahedron { .. }
            | Shape::CappedCone { .. }
            | Shape::Box { .. }
            | Shape::BoxFrame { .. }
            | Shape::Torus { .. }
            | Shape::Capsule { .. }
            | Shape::Cylinder { .. }
            | Shape::Plane { .. } => Vec::new(),
        }
    }

    /// The centre used by the rainbow material, for primitives (in the
    /// primitive's own frame).
    pub fn primitive_center(&self) -> Option<DVec3> {
        match self {
            Shape::Sphere { center, .. }
            | Shape::Box { center, .. }
            | Shape::BoxFrame { center, .. }
            | Shape::Torus { center, .. }
            | Shape::Cylinder { center, .. }
            | Shape::Ellipsoid { center, .. }
            | Shape::Octahedron { center, .. }
            | Shape::CappedCone { center, .. } => Some(center.value),
            Shape::Capsule { a, b, .. } => Some((a.value + b.value) * 0.5),
            Shape::Plane { normal, height } => Some(*normal * height.value),
            _ => None,
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

    pub fn name(&self) -> &'static str {
        match self {
            Shape::Sphere { .. } => "sphere",
            Shape::Box { .. } => "box",
            Shape::BoxFrame { .. } => "box_frame",
            Shape::Torus { .. } => "torus",
            Shape::Capsule { .. } => "capsule",
            Shape::Cylinder { .. } => "cylinder",
            Shape::Plane { .. } => "plane",
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
            Shape::Ellipsoid { .. } => "ellipsoid",
            Shape::Octahedron { .. } => "octahedron",
            Shape::CappedCone { .. } => "capped_cone",
            Shape::Round(..) => "round",
            Shape::Onion(..) => "onion",
            Shape::Xor(..) => "xor",
        }
    }
}

fn smallest(boxes: impl Iterator<Item = Aabb>) -> Option<Aabb> {
    boxes.min_by(|a, b| a.volume().total_cmp(&b.volume()))
}
