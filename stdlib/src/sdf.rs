//! Every distance formula, written once over [`Real`]: the f64 reference
//! ([`crate::shape::Shape::distance`]), the f32 tracer and the forward-mode
//! gradients of training all call these.
//!
//! Points are in the primitive's own frame unless a `center` is taken.

use crate::num::{Real, V3};

/// Sphere of `radius` around `center` (exact).
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
/// and `top` at `+height/2` (Inigo Quilez's exact formula). `d` is the point
/// in the cone's frame ([`along`]).
#[inline(always)]
pub fn capped_cone<T: Real>(d: V3<T>, height: T, bottom: T, top: T) -> T {
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

/// Torus in the XY plane around the Z axis (`q` in its frame, [`along`]).
#[inline(always)]
pub fn torus<T: Real>(q: V3<T>, major: T, minor: T) -> T {
    let a = (q.x * q.x + q.y * q.y).sqrt() - major;
    (a * a + q.z * q.z).sqrt() - minor
}

/// Inigo Quilez's capped torus: the arc of the torus (`major`, `minor`) in
/// the XY plane within `angle` of +Y on either side (`q` in its frame,
/// [`along`]); exact. The nearest point of the arc's centre circle is the
/// point's own direction inside the arc, else the arc's end.
#[inline(always)]
pub fn capped_torus<T: Real>(q: V3<T>, angle: T, major: T, minor: T) -> T {
    let (s, c) = (angle.sin(), angle.cos());
    let x = q.x.abs();
    // `q·e` for the nearest point `major·e` of the centre circle's arc.
    let k = T::if_gt(c * x, s * q.y, x * s + q.y * c, (x * x + q.y * q.y).sqrt());
    let sq = q.dot(q) + major * major - T::lit(2.0) * major * k;
    sq.max(T::zero()).sqrt() - minor
}

/// A pointed cone along Z whose side makes `angle` with the axis: tip at
/// `z = +height/2`, base of radius `height·tan(angle)` at `−height/2` (`q`
/// in its frame, [`along`]); exact (Inigo Quilez's cone, in this frame).
/// In its section (`r`, `y` from the tip) the nearest point is on the side
/// (tip to base rim) or on the base.
#[inline(always)]
pub fn cone<T: Real>(q: V3<T>, angle: T, height: T) -> T {
    let rim = height * angle.sin() / angle.cos();
    let r = (q.x * q.x + q.y * q.y).sqrt();
    let y = q.z - height * T::lit(0.5);
    // Side: the segment from the tip (0, 0) to the rim (rim, −height).
    let t = ((r * rim - y * height) / (rim * rim + height * height)).clamp(0.0, 1.0);
    let (ax, ay) = (r - rim * t, y + height * t);
    // Base: the segment from the axis to the rim at y = −height.
    let bx = r - r.min(rim);
    let by = y + height;
    let d = (ax * ax + ay * ay).min(bx * bx + by * by).sqrt();
    // Inside: below the side and above the base.
    let s = (r * height + y * rim).max(-by);
    T::if_gt(s, T::zero(), d, -d)
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

/// Capped cylinder along the Z axis with full `height` (`q` in its frame).
#[inline(always)]
pub fn cylinder<T: Real>(q: V3<T>, radius: T, height: T) -> T {
    extrude(
        (q.x * q.x + q.y * q.y).sqrt() - radius,
        q.z,
        height * T::lit(0.5),
    )
}

/// The exact distance to a 2D shape with distance `d2` extruded over
/// `|z| ≤ half`.
#[inline(always)]
pub fn extrude<T: Real>(d2: T, z: T, half: T) -> T {
    let dz = z.abs() - half;
    let (ox, oz) = (d2.max(T::zero()), dz.max(T::zero()));
    d2.max(dz).min(T::zero()) + (ox * ox + oz * oz).sqrt()
}

/// Which world axis a shape built along Z is laid along.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Axis {
    /// The world X axis.
    X,
    /// The world Y axis.
    Y,
    /// The world Z axis (a shape's own frame unchanged).
    Z,
}

impl Axis {
    /// The axis's component index in a vector (X 0, Y 1, Z 2).
    pub fn index(self) -> usize {
        self as usize
    }
    /// A vector of the shape's frame (its own Z along `self`) in world axes.
    pub fn to_world(self, v: glam::DVec3) -> glam::DVec3 {
        match self {
            Axis::Z => v,
            Axis::X => glam::DVec3::new(v.z, v.x, v.y),
            Axis::Y => glam::DVec3::new(v.y, v.z, v.x),
        }
    }
}

/// `p − center` in the frame of a shape built along Z and laid along `axis`:
/// a cyclic permutation of the coordinates, i.e. a rotation, so an exact
/// distance stays exact.
#[inline(always)]
pub fn along<T: Real>(p: V3<T>, center: V3<T>, axis: Axis) -> V3<T> {
    let q = p - center;
    match axis {
        Axis::Z => q,
        Axis::X => V3::new(q.y, q.z, q.x),
        Axis::Y => V3::new(q.z, q.x, q.y),
    }
}

/// Two spheres along Z, radius `bottom` at `z = −height/2` and `top` at
/// `+height/2`, and the cone tangent to both (their convex hull): exact.
/// Needs `|bottom − top| < height` (else one sphere holds the other).
#[inline(always)]
pub fn round_cone<T: Real>(q: V3<T>, bottom: T, top: T, height: T) -> T {
    // Sine and cosine of the side's slope; the clamp keeps trained values finite.
    let b = ((bottom - top) / height).clamp(-0.999, 0.999);
    let a = (T::one() - b * b).sqrt();
    let (x, z) = ((q.x * q.x + q.y * q.y).sqrt(), q.z + height * T::lit(0.5));
    // Where the point projects along the side: below, on or above it.
    let k = a * z - b * x;
    if k.val() < 0.0 {
        (x * x + z * z).sqrt() - bottom
    } else if k.val() > (a * height).val() {
        let zt = z - height;
        (x * x + zt * zt).sqrt() - top
    } else {
        x * a + z * b - bottom
    }
}

/// Hexagonal prism along Z: flat sides at distance `radius` from the axis
/// (two of them parallel to X), full `height`; exact.
#[inline(always)]
pub fn hex_prism<T: Real>(q: V3<T>, radius: T, height: T) -> T {
    let (kx, ky) = (T::lit(-(3f64.sqrt()) / 2.0), T::lit(0.5));
    let (mut x, mut y) = (q.x.abs(), q.y.abs());
    // Fold the slanted sides onto the top one.
    let t = (kx * x + ky * y).min(T::zero()) * T::lit(2.0);
    x = x - t * kx;
    y = y - t * ky;
    // The top side runs over |x| ≤ radius/√3.
    let half = radius * T::lit(1.0 / 3f64.sqrt());
    let (ex, ey) = (x - x.max(-half).min(half), y - radius);
    let len = (ex * ex + ey * ey).sqrt();
    let d2 = if ey.val() < 0.0 { -len } else { len };
    extrude(d2, q.z, height * T::lit(0.5))
}

/// Prism along Z over an equilateral triangle of side `side` centred on
/// its centroid, one vertex towards +Y, full `height`; exact.
#[inline(always)]
pub fn tri_prism<T: Real>(q: V3<T>, side: T, height: T) -> T {
    let k = T::lit(3f64.sqrt());
    let r = side * T::lit(0.5);
    let (mut x, mut y) = (q.x.abs() - r, q.y + r / k);
    // Reflect across the right side's normal onto the base's frame.
    if (x + k * y).val() > 0.0 {
        let (nx, ny) = ((x - k * y) * T::lit(0.5), (-k * x - y) * T::lit(0.5));
        x = nx;
        y = ny;
    }
    x = x - x.max(-(r + r)).min(T::zero());
    let len = (x * x + y * y).sqrt();
    let d2 = if y.val() < 0.0 { len } else { -len };
    extrude(d2, q.z, height * T::lit(0.5))
}

/// A chain link in the XY plane: a torus (`major`, `minor`) cut across Y
/// and pulled apart by straight parts of full `length`; exact.
#[inline(always)]
pub fn link<T: Real>(q: V3<T>, length: T, major: T, minor: T) -> T {
    let y = (q.y.abs() - length * T::lit(0.5)).max(T::zero());
    let a = (q.x * q.x + y * y).sqrt() - major;
    (a * a + q.z * q.z).sqrt() - minor
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

/// Polynomial smooth maximum over radius `k` (`max` when `k ≤ 0`): smooth
/// intersection and subtraction.
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

/// `p − clamp(p, −h, h)`: a shape elongated by `h` on each side (the
/// shape is cut at its centre planes and the gap filled with its section).
#[inline(always)]
pub fn elongate<T: Real>(p: V3<T>, h: V3<T>) -> V3<T> {
    p.zip(h, |x, h| x - x.max(-h).min(h))
}

/// `p` with its XY part rotated by `angle` about Z.
#[inline(always)]
fn spin<T: Real>(p: V3<T>, angle: T) -> V3<T> {
    let (s, c) = (angle.sin(), angle.cos());
    V3::new(c * p.x - s * p.y, s * p.x + c * p.y, p.z)
}

/// Twist about Z: each slice turned by `rate·z`.
#[inline(always)]
pub fn twist<T: Real>(p: V3<T>, rate: T) -> V3<T> {
    spin(p, rate * p.z)
}

/// Bend in the XY plane: each slice across X turned by `rate·x`.
#[inline(always)]
pub fn bend<T: Real>(p: V3<T>, rate: T) -> V3<T> {
    spin(p, rate * p.x)
}

/// The nearest point to `p` of the cylinder `|xy| ≤ radius`,
/// `lo ≤ z ≤ hi`, and the distance to it (0 inside). Twists and bends turn
/// points about Z, so a shape inside this cylinder stays inside it; they
/// are evaluated at the nearest point and bounded below by the distance
/// to the cylinder, which keeps their Lipschitz constant finite everywhere.
#[inline(always)]
pub fn into_cylinder<T: Real>(p: V3<T>, radius: f64, lo: f64, hi: f64) -> (V3<T>, T) {
    let r = (p.x * p.x + p.y * p.y).sqrt();
    let f = if r.val() > radius {
        T::lit(radius) / r
    } else {
        T::one()
    };
    let q = V3::new(p.x * f, p.y * f, p.z.clamp(lo, hi));
    (q, (p - q).length())
}

/// A warped distance `d` taken at the nearest point of the warp's region,
/// `e` away: at least `e` outside, so at least the distance to the region's box.
#[inline(always)]
pub fn beyond<T: Real>(e: T, d: T) -> T {
    if e.val() > 0.0 {
        e.max(d)
    } else {
        d
    }
}

/// The copies a repetition evaluates along one axis, as a closed range of
/// (centred) copy indices: those whose centre is less than `reach` cells from
/// `u = p/spacing`. Every copy further away has a nearer copy, shifted one
/// cell towards the point, with every one of its points nearer (this needs
/// `reach ≥ ½ + extent/spacing`, `extent` the child's reach from its
/// origin), so the minimum over the range is the union of all copies. `count`
/// copies (centred on the origin) or infinitely many.
#[inline(always)]
pub fn repeat_range(u: f64, reach: f64, count: Option<u32>) -> (f64, f64) {
    match count {
        None => ((u - reach).ceil(), (u + reach).floor()),
        Some(n) => {
            let mid = (n as f64 - 1.0) * 0.5;
            let v = u + mid;
            let lo = (v - reach).ceil().clamp(0.0, n as f64 - 1.0);
            let hi = (v + reach).floor().clamp(0.0, n as f64 - 1.0);
            (lo - mid, hi - mid)
        }
    }
}

/// A copy's term in a repetition whose child's value `f` is only a bound
/// on its distance. [`repeat_range`]'s window holds the nearest copy, but a
/// farther copy's bound may be lower and joins the window only past a cell
/// boundary, where a plain minimum would jump. So each copy gives
/// `max(b, min(f, w + ½·s_min))`: `b` the signed distance from `q` (the
/// point in the copy's frame) to the child's box `lo..hi` (at most `f`:
/// the child lies in its box), `w` how deep inside the
/// window the copy is (`½·s + extent − |q|` on the repeated axes, the least
/// of them, `extent` the box's reach from the origin: 0 where it enters),
/// `s_min` the least spacing. Never above the copy's signed distance (`f`
/// and `b` are both lower bounds of it; inside the copy, where the depth is
/// at least `½·s`, it is `f`); exactly `b` where the copy enters (its box
/// is at least `½·s` away along that axis), where [`repeat_beyond`] takes
/// over: the minimum of the terms and that is continuous, and Lipschitz
/// with the larger of 1 and the child's constant.
#[inline(always)]
pub fn repeat_bound_term<T: Real>(f: T, q: V3<T>, spacing: V3<T>, lo: V3<T>, hi: V3<T>) -> T {
    let zero = T::zero();
    let (q, s, lo, hi) = (
        q.to_array(),
        spacing.to_array(),
        lo.to_array(),
        hi.to_array(),
    );
    let (mut sq, mut deepest) = (zero, None::<T>);
    // (depth in the window, half the least spacing) over the repeated axes.
    let mut w: Option<(T, T)> = None;
    for i in 0..3 {
        let signed = (lo[i] - q[i]).max(q[i] - hi[i]);
        deepest = Some(deepest.map_or(signed, |d| d.max(signed)));
        let g = signed.max(zero);
        sq = sq + g * g;
        if s[i].val() > 0.0 {
            let half = s[i] * T::lit(0.5);
            let wi = half + lo[i].abs().max(hi[i].abs()) - q[i].abs();
            w = Some(w.map_or((wi, half), |(w, h)| (w.min(wi), h.min(half))));
        }
    }
    // The box's signed distance: negative inside, where the child is too.
    let deepest = deepest.expect("three axes");
    let b = if deepest.val() > 0.0 {
        sq.sqrt()
    } else {
        deepest
    };
    match w {
        Some((w, half)) => b.max(f.min(w + half)),
        None => f,
    }
}

/// How far `x` lies outside `lo..hi` (0 inside).
#[inline(always)]
fn box_gap<T: Real>(x: T, lo: T, hi: T) -> T {
    (lo - x).max(x - hi).max(T::zero())
}

/// The least distance from `p` to the boxes (`lo..hi` about each copy's
/// origin) of the copies a repetition leaves out of its `ranges` (see
/// [`repeat_range`]; copy indices centred on the origin): per repeated axis
/// with a copy beyond its range, the nearest such layer's gap along that
/// axis, with the nearest copy's gap along each other axis (a box's
/// distance is the root of the squared gaps, axis by axis). `None` when no
/// copy is left out.
pub fn repeat_beyond<T: Real>(
    p: V3<T>,
    spacing: V3<T>,
    (lo, hi): (V3<T>, V3<T>),
    count: [u32; 3],
    ranges: [(f64, f64); 3],
) -> Option<T> {
    let (p, s, lo, hi) = (
        p.to_array(),
        spacing.to_array(),
        lo.to_array(),
        hi.to_array(),
    );
    let gap = |i: usize, k: f64| {
        let off = s[i] * T::lit(k);
        box_gap(p[i], lo[i] + off, hi[i] + off)
    };
    // Whether copy k exists along axis i (counts are centred on the origin).
    let exists = |i: usize, k: f64| count[i] == 0 || k.abs() <= (count[i] as f64 - 1.0) * 0.5;
    // The nearest copy's gap along each axis (the single copy where
    // unrepeated): the gap is least at the copy whose box centre is nearest.
    let near: [T; 3] = std::array::from_fn(|i| {
        if s[i].val() <= 0.0 {
            return gap(i, 0.0);
        }
        let u = (p[i].val() - 0.5 * (lo[i].val() + hi[i].val())) / s[i].val();
        let k = if count[i] == 0 {
            u.round()
        } else {
            // Centred indices are whole for odd counts, halves for even.
            let mid = (count[i] as f64 - 1.0) * 0.5;
            ((u + mid).round() - mid).clamp(-mid, mid)
        };
        gap(i, k)
    });
    let mut best: Option<T> = None;
    for i in 0..3 {
        if s[i].val() <= 0.0 {
            continue;
        }
        let (first, last) = ranges[i];
        let outside = [first - 1.0, last + 1.0]
            .into_iter()
            .filter(|&k| exists(i, k))
            .map(|k| gap(i, k))
            .reduce(|a, b| a.min(b));
        let Some(a) = outside else { continue };
        let mut sq = a * a;
        for j in (0..3).filter(|&j| j != i) {
            sq = sq + near[j] * near[j];
        }
        let d = sq.sqrt();
        best = Some(best.map_or(d, |b| b.min(d)));
    }
    best
}

/// `p` rotated by `angle` around the unit `axis` (Rodrigues' formula).
#[inline(always)]
pub fn rotate<T: Real>(p: V3<T>, axis: V3<T>, angle: T) -> V3<T> {
    let (s, c) = (angle.sin(), angle.cos());
    let kdp = axis.dot(p);
    p * c + axis.cross(p) * s + axis * (kdp * (T::one() - c))
}
