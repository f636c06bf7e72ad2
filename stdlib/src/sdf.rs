//! Every distance formula, written once over [`Real`]: the f64 reference
//! ([`crate::shape::Shape::distance`]), the f32 tracer and the forward-mode
//! gradients of training all call these.
//!
//! Points are in the primitive's own frame unless a `center` is taken.

use crate::num::{Real, V3};

#[inline(always)]
pub fn sphere<T: Real>(p: V3<T>, center: V3<T>, radius: T) -> T {
    (p - center).length() - radius
}

/// Box with full side lengths `size`.
#[inline(always)]
pub fn cuboid<T: Real>(p: V3<T>, center: V3<T>, size: V3<T>) -> T {
    let q = (p - center).abs() - size * T::lit(0.5);
    q.max_s(T::zero()).length() + q.max_element().min(T::zero())
}

/// Inigo Quilez's exact box frame: side lengths `size`, edges of full width
/// `thickness` (his formula's `e` is half the edge width).
#[inline(always)]
pub fn box_frame<T: Real>(p: V3<T>, center: V3<T>, size: V3<T>, thickness: T) -> T {
    let e = thickness * T::lit(0.5);
    let p = (p - center).abs() - size * T::lit(0.5);
    let q = (p + V3::splat(e)).abs() - V3::splat(e);
    let part = |v: V3<T>| v.max_s(T::zero()).length() + v.max_element().min(T::zero());
    part(V3::new(p.x, q.y, q.z))
        .min(part(V3::new(q.x, p.y, q.z)))
        .min(part(V3::new(q.x, q.y, p.z)))
}

/// Ellipsoid with semi-axes `radii`: a bound, the larger of
/// `(|q/r| − 1)·min(r)` (gradient at most 1) and the distance to its
/// circumscribed sphere `|q| − max(r)`, so far away it grows like a true
/// distance (which keeps culling by bounding boxes exact).
#[inline(always)]
pub fn ellipsoid<T: Real>(p: V3<T>, center: V3<T>, radii: V3<T>) -> T {
    let q = p - center;
    let scaled = V3::new(q.x / radii.x, q.y / radii.y, q.z / radii.z);
    let inner = (scaled.length() - T::one()) * radii.min_element();
    inner.max(q.length() - radii.max_element())
}

/// Octahedron with vertices at `±size` on each axis: a bound, the larger of
/// the distance to its face planes `(|x| + |y| + |z| − s)/√3` and to its
/// circumscribed sphere.
#[inline(always)]
pub fn octahedron<T: Real>(p: V3<T>, center: V3<T>, size: T) -> T {
    let q = (p - center).abs();
    let faces = (q.x + q.y + q.z - size) * T::lit(1.0 / 3f64.sqrt());
    faces.max(q.length() - size)
}

/// Capped cone along Z, full `height`, radius `bottom` at `z = −height/2`
/// and `top` at `+height/2` (Inigo Quilez's exact formula).
#[inline(always)]
pub fn capped_cone<T: Real>(p: V3<T>, center: V3<T>, height: T, bottom: T, top: T) -> T {
    let d = p - center;
    let h = height * T::lit(0.5);
    let (qx, qy) = ((d.x * d.x + d.y * d.y).sqrt(), d.z);
    // The nearer cap's radius, and the slanted side as a segment.
    let cap = if qy.val() < 0.0 { bottom } else { top };
    let ca = (qx - qx.min(cap), qy.abs() - h);
    let (k1x, k1y) = (top, h);
    let (k2x, k2y) = (top - bottom, h * T::lit(2.0));
    let t = (((k1x - qx) * k2x + (k1y - qy) * k2y) / (k2x * k2x + k2y * k2y)).clamp(0.0, 1.0);
    let cb = (qx - k1x + k2x * t, qy - k1y + k2y * t);
    let inside = cb.0.val() < 0.0 && ca.1.val() < 0.0;
    let d2 = (ca.0 * ca.0 + ca.1 * ca.1).min(cb.0 * cb.0 + cb.1 * cb.1);
    let dist = d2.sqrt();
    if inside {
        -dist
    } else {
        dist
    }
}

/// Torus in the XY plane around the Z axis.
#[inline(always)]
pub fn torus<T: Real>(p: V3<T>, center: V3<T>, major: T, minor: T) -> T {
    let q = p - center;
    let a = (q.x * q.x + q.y * q.y).sqrt() - major;
    (a * a + q.z * q.z).sqrt() - minor
}

/// Segment `a`–`b` thickened by `radius`.
#[inline(always)]
pub fn capsule<T: Real>(p: V3<T>, a: V3<T>, b: V3<T>, radius: T) -> T {
    let pa = p - a;
    let ba = b - a;
    let len2 = ba.dot(ba);
    let h = if len2.val() > 0.0 {
        (pa.dot(ba) / len2).clamp(0.0, 1.0)
    } else {
        T::zero()
    };
    (pa - ba * h).length() - radius
}

/// Capped cylinder along the Z axis with full `height`.
#[inline(always)]
pub fn cylinder<T: Real>(p: V3<T>, center: V3<T>, radius: T, height: T) -> T {
    let q = p - center;
    let dx = (q.x * q.x + q.y * q.y).sqrt() - radius;
    let dz = q.z.abs() - height * T::lit(0.5);
    let (ox, oz) = (dx.max(T::zero()), dz.max(T::zero()));
    dx.max(dz).min(T::zero()) + (ox * ox + oz * oz).sqrt()
}

/// `dot(p, normal) − height`, `normal` unit length.
#[inline(always)]
pub fn plane<T: Real>(p: V3<T>, normal: V3<T>, height: T) -> T {
    p.dot(normal) - height
}

/// Polynomial smooth minimum; deviates from `min` by at most `k/4`
/// (`k ≤ 0`: the sharp minimum).
#[inline(always)]
pub fn smooth_min<T: Real>(a: T, b: T, k: T) -> T {
    if k.val() <= 0.0 {
        return a.min(b);
    }
    let h = (k - (a - b).abs()).max(T::zero()) / k;
    a.min(b) - h * h * k * T::lit(0.25)
}

#[inline(always)]
pub fn smooth_max<T: Real>(a: T, b: T, k: T) -> T {
    -smooth_min(-a, -b, k)
}

/// Exclusive or: inside exactly one of the two.
#[inline(always)]
pub fn xor<T: Real>(a: T, b: T) -> T {
    a.min(b).max(-a.max(b))
}

/// `amplitude·sin(f·x)·sin(f·y)·sin(f·z)`.
#[inline(always)]
pub fn displacement<T: Real>(p: V3<T>, amplitude: T, frequency: T) -> T {
    amplitude * (frequency * p.x).sin() * (frequency * p.y).sin() * (frequency * p.z).sin()
}

/// The rainbow colour `clamp(|p − c|, 0.02, 0.98)` componentwise, `c` the
/// primitive's centre.
#[inline(always)]
pub fn rainbow<T: Real>(p: V3<T>, center: V3<T>) -> V3<T> {
    (p - center).abs().map(|v| v.clamp(0.02, 0.98))
}

/// `p` rotated by `angle` around the unit `axis` (Rodrigues' formula).
#[inline(always)]
pub fn rotate<T: Real>(p: V3<T>, axis: V3<T>, angle: T) -> V3<T> {
    let (s, c) = (angle.sin(), angle.cos());
    let kdp = axis.dot(p);
    p * c + axis.cross(p) * s + axis * (kdp * (T::one() - c))
}
