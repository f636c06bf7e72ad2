//! Bounds of shapes: axis-aligned boxes, whether a shape's value is an
//! exact distance, its Lipschitz bound. Every shape with bounds `B`
//! satisfies `distance(p) ≥ signed_distance_to_box(B, p)` (see the module
//! above), which BVH culling relies on.

use super::*;

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// The corner with the smallest coordinates.
    pub min: DVec3,
    /// The corner with the largest coordinates.
    pub max: DVec3,
}

impl Aabb {
    /// The box between two corners (`min ≤ max` per axis for a non-empty box).
    pub fn new(min: DVec3, max: DVec3) -> Self {
        Aabb { min, max }
    }
    /// The box centred on `center` with half extents `half`.
    pub fn around(center: DVec3, half: DVec3) -> Self {
        Aabb::new(center - half, center + half)
    }
    /// The smallest box holding both: the bounds of a union.
    pub fn union(self, o: Aabb) -> Aabb {
        Aabb::new(self.min.min(o.min), self.max.max(o.max))
    }
    /// The box grown by `by` on every side (a shape rounded or displaced).
    pub fn expand(self, by: f64) -> Aabb {
        Aabb::new(self.min - DVec3::splat(by), self.max + DVec3::splat(by))
    }
    /// The box's centre point.
    pub fn center(self) -> DVec3 {
        (self.min + self.max) * 0.5
    }
    /// The box's volume (0 when empty or flat): a BVH split's cost.
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

impl Shape {
    /// Whether the shape's value is the exact distance or only a bound.
    pub fn exactness(&self) -> Exactness {
        match self {
            Shape::Prim(x) => x.spec().exactness,
            // Clipped to its box and scaled by its Lipschitz bound.
            Shape::User(_) => Exactness::Bound,
            // Disjoint copies of an exact shape: their union is exact.
            Shape::Repeat {
                shape,
                spacing,
                count,
            } => {
                let (e, s) = (shape.extent(), spacing.value);
                let apart = (0..3).all(|i| s[i] <= 0.0 || count[i] == 1 || e[i] <= s[i] * 0.5);
                if apart {
                    shape.exactness()
                } else {
                    Exactness::Bound
                }
            }
            // Reflecting a shape that lies on the kept side adds a copy
            // never nearer than the original.
            Shape::Mirror(s, axis) => match s.bounds() {
                Some(b) if b.min[axis.index()] >= 0.0 => s.exactness(),
                _ => Exactness::Bound,
            },
            Shape::Elongate(..) | Shape::Twist(..) | Shape::Bend(..) | Shape::ScaleXyz(..) => {
                Exactness::Bound
            }
            // Offsets of exact distances are exact outside; inside (and
            // for a shell, on both sides) only a bound in general.
            Shape::Round(..) | Shape::Onion(..) | Shape::Xor(..) => Exactness::Bound,
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

    /// Whether the value is the exact distance wherever it is positive
    /// (outside the shape): exact shapes, unions of such shapes (and
    /// repetitions, which equal the union of their copies), and offsets
    /// and rigid moves of them. A repetition needs this of its
    /// child to take the least value over the copies near the point (a
    /// farther copy's value is then its distance, never below a nearer
    /// copy's); see [`Shape::repeated_as_bound`].
    pub fn exact_outside(&self) -> bool {
        if self.exactness() == Exactness::Exact {
            return true;
        }
        match self {
            Shape::Union(c) => c.iter().all(|s| s.exact_outside()),
            Shape::Round(s, _)
            | Shape::Repeat { shape: s, .. }
            | Shape::Translate(s, _)
            | Shape::Rotate { shape: s, .. }
            | Shape::Scale(s, _)
            | Shape::Paint(s, _) => s.exact_outside(),
            Shape::Mirror(s, axis) => {
                matches!(s.bounds(), Some(b) if b.min[axis.index()] >= 0.0) && s.exact_outside()
            }
            // Not elongations: pulling a shape apart at the origin's planes
            // moves its parts away from points across them.
            _ => false,
        }
    }

    /// As the child of a repetition: its bounds when it has them and its
    /// value may fall below its distance outside it (not
    /// [`exact_outside`](Self::exact_outside)). The repetition then
    /// evaluates copies through [`sdf::repeat_bound_term`] and
    /// [`sdf::repeat_beyond`], so its value stays continuous where copies
    /// join or leave the window.
    pub fn repeated_as_bound(&self) -> Option<Aabb> {
        if self.exact_outside() {
            None
        } else {
            self.bounds()
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
            | Shape::Onion(s, _)
            | Shape::Elongate(s, _)
            | Shape::Mirror(s, _) => s.lipschitz(),
            // A bounded child's bound meets 1-Lipschitz box distances
            // (`sdf::repeat_bound_term`).
            Shape::Repeat { shape: s, .. } => match s.repeated_as_bound() {
                Some(_) => s.lipschitz().max(1.0),
                None => s.lipschitz(),
            },
            Shape::ScaleXyz(s, _) => s.lipschitz().max(1.0),
            // Turning by an angle that changes at `rate` per unit moves a
            // point at radius r by up to `rate·r` more: within the region
            // (radius R) the Jacobian's norm is at most `1 + |rate|·R`.
            Shape::Twist(s, k) | Shape::Bend(s, k) => {
                s.lipschitz() * (1.0 + k.value.abs() * s.turn_region().0)
            }
            Shape::Displace {
                shape,
                amplitude,
                frequency,
            } => shape.lipschitz() + 3f64.sqrt() * amplitude.value.abs() * frequency.value.abs(),
            Shape::Prim(x) => x.spec().lipschitz,
            // Divided by its own bound (see `user`).
            Shape::User(_) => 1.0,
        }
    }

    /// A box `B` with `distance(p) ≥ B.signed_distance(p)` everywhere, or
    /// `None` for unbounded shapes (planes).
    pub fn bounds(&self) -> Option<Aabb> {
        match self {
            Shape::Prim(x) => x.bounds(),
            Shape::User(u) => Some(u.bound),
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
            // The clamp moves a point by at most `h` per axis.
            Shape::Elongate(s, h) => s
                .bounds()
                .map(|b| Aabb::new(b.min - h.value, b.max + h.value)),
            Shape::Repeat {
                shape,
                spacing,
                count,
            } => {
                let b = shape.bounds()?;
                let s = spacing.value;
                let mut reach = DVec3::ZERO;
                for i in 0..3 {
                    if s[i] > 0.0 {
                        if count[i] == 0 {
                            return None;
                        }
                        reach[i] = s[i] * (count[i] as f64 - 1.0) * 0.5;
                    }
                }
                Some(Aabb::new(b.min - reach, b.max + reach))
            }
            Shape::Mirror(s, axis) => s.bounds().map(|b| {
                let i = axis.index();
                let e = b.min[i].abs().max(b.max[i].abs());
                let (mut lo, mut hi) = (b.min, b.max);
                lo[i] = -e;
                hi[i] = e;
                Aabb::new(lo, hi)
            }),
            Shape::Twist(s, _) | Shape::Bend(s, _) => {
                s.bounds()?;
                let (r, lo, hi) = s.turn_region();
                Some(Aabb::new(DVec3::new(-r, -r, lo), DVec3::new(r, r, hi)))
            }
            Shape::ScaleXyz(s, f) => s
                .bounds()
                .map(|b| Aabb::new(b.min * f.value, b.max * f.value)),
        }
    }
}

fn smallest(boxes: impl Iterator<Item = Aabb>) -> Option<Aabb> {
    boxes.min_by(|a, b| a.volume().total_cmp(&b.volume()))
}
