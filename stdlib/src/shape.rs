//! The shape IR: analytic SDF primitives, combinators and transforms, with
//! an f64 reference evaluator. Runtime evaluators are checked against
//! [`Shape::distance`].
//!
//! Invariant (relied on by BVH culling and tested by property tests): every
//! shape with bounds `B` satisfies `distance(p) ≥ signed_distance_to_box(B, p)`
//! for every point `p`. Bounds are chosen to keep that true, which is why an
//! intersection is bounded by its smallest child box and not by the
//! intersection of the boxes.

use std::sync::Arc;

use glam::{DQuat, DVec2, DVec3};

use crate::material::Material;

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
        center: DVec3,
        radius: f64,
    },
    /// `size` holds the full side lengths.
    Box {
        center: DVec3,
        size: DVec3,
    },
    BoxFrame {
        center: DVec3,
        size: DVec3,
        thickness: f64,
    },
    /// In the XY plane around the Z axis.
    Torus {
        center: DVec3,
        major: f64,
        minor: f64,
    },
    Capsule {
        a: DVec3,
        b: DVec3,
        radius: f64,
    },
    /// Capped, along the Z axis.
    Cylinder {
        center: DVec3,
        radius: f64,
        height: f64,
    },
    /// `dot(p, normal) - height`; `normal` is unit length.
    Plane {
        normal: DVec3,
        height: f64,
    },
    Union(Vec<Arc<Shape>>),
    Intersection(Vec<Arc<Shape>>),
    /// The first shape minus the second.
    Subtraction(Arc<Shape>, Arc<Shape>),
    SmoothUnion(Arc<Shape>, Arc<Shape>, f64),
    SmoothIntersection(Arc<Shape>, Arc<Shape>, f64),
    SmoothSubtraction(Arc<Shape>, Arc<Shape>, f64),
    Translate(Arc<Shape>, DVec3),
    /// Rotation of the shape (points are rotated back by the inverse).
    Rotate(Arc<Shape>, DQuat),
    Scale(Arc<Shape>, f64),
    /// Adds `amplitude·sin(fx)·sin(fy)·sin(fz)`: a bound, Lipschitz `1 + √3·a·f`.
    Displace {
        shape: Arc<Shape>,
        amplitude: f64,
        frequency: f64,
    },
    /// Gives its primitives a material.
    Paint(Arc<Shape>, Arc<Material>),
    /// A primitive some of whose arguments are trainable (`param(...)`).
    Trainable(Arc<Shape>, Vec<TrainParam>),
}

/// An argument marked trainable, and where.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainParam {
    pub name: &'static str,
    pub span: sdfl_lang::Span,
}

/// Polynomial smooth minimum; deviates from `min` by at most `k/4`.
pub fn smooth_min(a: f64, b: f64, k: f64) -> f64 {
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

pub fn smooth_max(a: f64, b: f64, k: f64) -> f64 {
    -smooth_min(-a, -b, k)
}

pub fn box_distance(p: DVec3, half: DVec3) -> f64 {
    let q = p.abs() - half;
    q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
}

/// Inigo Quilez's exact box frame with `half` extents and edges of full
/// width `thickness` (his formula's `e` is half the edge width).
pub fn box_frame_distance(p: DVec3, half: DVec3, thickness: f64) -> f64 {
    let e = thickness * 0.5;
    let p = p.abs() - half;
    let q = (p + DVec3::splat(e)).abs() - DVec3::splat(e);
    let part = |v: DVec3| v.max(DVec3::ZERO).length() + v.max_element().min(0.0);
    part(DVec3::new(p.x, q.y, q.z))
        .min(part(DVec3::new(q.x, p.y, q.z)))
        .min(part(DVec3::new(q.x, q.y, p.z)))
}

pub fn torus_distance(p: DVec3, major: f64, minor: f64) -> f64 {
    DVec2::new(DVec2::new(p.x, p.y).length() - major, p.z).length() - minor
}

pub fn capsule_distance(p: DVec3, a: DVec3, b: DVec3, r: f64) -> f64 {
    let pa = p - a;
    let ba = b - a;
    let len2 = ba.length_squared();
    let h = if len2 > 0.0 {
        (pa.dot(ba) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (pa - ba * h).length() - r
}

pub fn cylinder_distance(p: DVec3, radius: f64, height: f64) -> f64 {
    let d = DVec2::new(DVec2::new(p.x, p.y).length(), p.z).abs() - DVec2::new(radius, height * 0.5);
    d.x.max(d.y).min(0.0) + d.max(DVec2::ZERO).length()
}

pub fn displacement(p: DVec3, amplitude: f64, frequency: f64) -> f64 {
    amplitude * (frequency * p.x).sin() * (frequency * p.y).sin() * (frequency * p.z).sin()
}

impl Shape {
    /// The signed distance (or bound) at `p`, evaluated directly in f64.
    pub fn distance(&self, p: DVec3) -> f64 {
        match self {
            Shape::Sphere { center, radius } => (p - *center).length() - radius,
            Shape::Box { center, size } => box_distance(p - *center, *size * 0.5),
            Shape::BoxFrame {
                center,
                size,
                thickness,
            } => box_frame_distance(p - *center, *size * 0.5, *thickness),
            Shape::Torus {
                center,
                major,
                minor,
            } => torus_distance(p - *center, *major, *minor),
            Shape::Capsule { a, b, radius } => capsule_distance(p, *a, *b, *radius),
            Shape::Cylinder {
                center,
                radius,
                height,
            } => cylinder_distance(p - *center, *radius, *height),
            Shape::Plane { normal, height } => p.dot(*normal) - height,
            Shape::Union(children) => children
                .iter()
                .map(|c| c.distance(p))
                .fold(f64::INFINITY, f64::min),
            Shape::Intersection(children) => children
                .iter()
                .map(|c| c.distance(p))
                .fold(f64::NEG_INFINITY, f64::max),
            Shape::Subtraction(a, b) => a.distance(p).max(-b.distance(p)),
            Shape::SmoothUnion(a, b, k) => smooth_min(a.distance(p), b.distance(p), *k),
            Shape::SmoothIntersection(a, b, k) => smooth_max(a.distance(p), b.distance(p), *k),
            Shape::SmoothSubtraction(a, b, k) => smooth_max(a.distance(p), -b.distance(p), *k),
            Shape::Translate(s, v) => s.distance(p - *v),
            Shape::Rotate(s, q) => s.distance(q.inverse() * p),
            Shape::Scale(s, f) => s.distance(p / *f) * f,
            Shape::Displace {
                shape,
                amplitude,
                frequency,
            } => shape.distance(p) + displacement(p, *amplitude, *frequency),
            Shape::Paint(s, _) | Shape::Trainable(s, _) => s.distance(p),
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
            | Shape::Plane { .. } => Exactness::Exact,
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
            | Shape::Rotate(s, _)
            | Shape::Scale(s, _)
            | Shape::Paint(s, _)
            | Shape::Trainable(s, _) => s.exactness(),
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
            | Shape::SmoothSubtraction(a, b, _) => a.lipschitz().max(b.lipschitz()),
            Shape::Translate(s, _)
            | Shape::Rotate(s, _)
            | Shape::Scale(s, _)
            | Shape::Paint(s, _)
            | Shape::Trainable(s, _) => s.lipschitz(),
            Shape::Displace {
                shape,
                amplitude,
                frequency,
            } => shape.lipschitz() + 3f64.sqrt() * amplitude.abs() * frequency.abs(),
            _ => 1.0,
        }
    }

    /// A box `B` with `distance(p) ≥ B.signed_distance(p)` everywhere, or
    /// `None` for unbounded shapes (planes).
    pub fn bounds(&self) -> Option<Aabb> {
        match self {
            Shape::Sphere { center, radius } => Some(Aabb::around(*center, DVec3::splat(*radius))),
            Shape::Box { center, size } | Shape::BoxFrame { center, size, .. } => {
                Some(Aabb::around(*center, *size * 0.5))
            }
            Shape::Torus {
                center,
                major,
                minor,
            } => Some(Aabb::around(
                *center,
                DVec3::new(major + minor, major + minor, *minor),
            )),
            Shape::Capsule { a, b, radius } => {
                Some(Aabb::new(a.min(*b), a.max(*b)).expand(*radius))
            }
            Shape::Cylinder {
                center,
                radius,
                height,
            } => Some(Aabb::around(
                *center,
                DVec3::new(*radius, *radius, height * 0.5),
            )),
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
            Shape::SmoothUnion(a, b, k) => Some(a.bounds()?.union(b.bounds()?).expand(k * 0.25)),
            Shape::Translate(s, v) => s.bounds().map(|b| Aabb::new(b.min + *v, b.max + *v)),
            Shape::Rotate(s, q) => s.bounds().map(|b| b.transformed(|c| *q * c)),
            Shape::Scale(s, f) => s.bounds().map(|b| Aabb::new(b.min * *f, b.max * *f)),
            Shape::Displace {
                shape, amplitude, ..
            } => shape.bounds().map(|b| b.expand(amplitude.abs())),
            Shape::Paint(s, _) | Shape::Trainable(s, _) => s.bounds(),
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
            | Shape::SmoothSubtraction(a, b, _) => vec![a, b],
            Shape::Translate(s, _)
            | Shape::Rotate(s, _)
            | Shape::Scale(s, _)
            | Shape::Paint(s, _)
            | Shape::Trainable(s, _)
            | Shape::Displace { shape: s, .. } => vec![s],
            Shape::Sphere { .. }
            | Shape::Box { .. }
            | Shape::BoxFrame { .. }
            | Shape::Torus { .. }
            | Shape::Capsule { .. }
            | Shape::Cylinder { .. }
            | Shape::Plane { .. } => Vec::new(),
        }
    }

    /// The centre used by the rainbow material, for primitives.
    pub fn primitive_center(&self) -> Option<DVec3> {
        match self {
            Shape::Trainable(s, _) => s.primitive_center(),
            Shape::Sphere { center, .. }
            | Shape::Box { center, .. }
            | Shape::BoxFrame { center, .. }
            | Shape::Torus { center, .. }
            | Shape::Cylinder { center, .. } => Some(*center),
            Shape::Capsule { a, b, .. } => Some((*a + *b) * 0.5),
            Shape::Plane { normal, height } => Some(*normal * *height),
            _ => None,
        }
    }

    /// Number of primitives (leaves).
    pub fn primitive_count(&self) -> usize {
        match self {
            Shape::Union(c) | Shape::Intersection(c) => c.iter().map(|s| s.primitive_count()).sum(),
            Shape::Subtraction(a, b)
            | Shape::SmoothUnion(a, b, _)
            | Shape::SmoothIntersection(a, b, _)
            | Shape::SmoothSubtraction(a, b, _) => a.primitive_count() + b.primitive_count(),
            Shape::Translate(s, _)
            | Shape::Rotate(s, _)
            | Shape::Scale(s, _)
            | Shape::Paint(s, _)
            | Shape::Trainable(s, _) => s.primitive_count(),
            Shape::Displace { shape, .. } => shape.primitive_count(),
            _ => 1,
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
            Shape::Rotate(..) => "rotate",
            Shape::Scale(..) => "scale",
            Shape::Displace { .. } => "displace",
            Shape::Paint(..) => "paint",
            Shape::Trainable(s, _) => s.name(),
        }
    }
}

fn smallest(boxes: impl Iterator<Item = Aabb>) -> Option<Aabb> {
    boxes.min_by(|a, b| a.volume().total_cmp(&b.volume()))
}
