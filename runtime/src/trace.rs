//! Sphere tracing and surface normals.

use glam::Vec3A;

use crate::sdf::Node;

/// Settings of one trace.
#[derive(Debug, Clone, Copy)]
pub struct TraceSettings {
    pub near: f32,
    pub far: f32,
    pub max_steps: u32,
    pub epsilon: f32,
    /// Lipschitz bound of the SDF: steps are `d / lipschitz`, so bound SDFs
    /// with a steeper gradient never step through thin parts.
    pub lipschitz: f32,
}

/// Where a ray ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter at the end (finite).
    pub t: f32,
    pub hit: bool,
    pub steps: u32,
}

/// March from `near` until the distance is below epsilon (a hit, also when
/// the ray starts inside a shape), `t` passes `far`, or the steps run out
/// (a miss). Always returns finite values within `max_steps` steps.
#[inline]
pub fn sphere_trace(sdf: &dyn Node, origin: Vec3A, dir: Vec3A, s: &TraceSettings) -> Hit {
    let inv_l = 1.0 / s.lipschitz;
    let mut t = s.near;
    for step in 0..s.max_steps {
        let d = sdf.dist(origin + dir * t);
        if d < s.epsilon {
            return Hit {
                t,
                hit: true,
                steps: step + 1,
            };
        }
        // A NaN distance (which valid scenes never produce) ends as a miss
        // rather than poisoning t.
        if !d.is_finite() {
            break;
        }
        t += d * inv_l;
        if t > s.far {
            return Hit {
                t: s.far,
                hit: false,
                steps: step + 1,
            };
        }
    }
    Hit {
        t: t.min(s.far),
        hit: false,
        steps: s.max_steps,
    }
}

/// Unit surface normal at `p` by tetrahedral central differences. Where the
/// gradient vanishes or is undefined (a sphere's centre, symmetric points
/// inside a box) it returns `fallback`, so it is never NaN.
pub fn normal(sdf: &dyn Node, p: Vec3A, h: f32, fallback: Vec3A) -> Vec3A {
    const K: [Vec3A; 4] = [
        Vec3A::new(1.0, -1.0, -1.0),
        Vec3A::new(-1.0, -1.0, 1.0),
        Vec3A::new(-1.0, 1.0, -1.0),
        Vec3A::new(1.0, 1.0, 1.0),
    ];
    let g = K
        .iter()
        .fold(Vec3A::ZERO, |acc, k| acc + *k * sdf.dist(p + *k * h));
    let len = g.length();
    if len.is_finite() && len > 1e-12 {
        g / len
    } else {
        fallback
    }
}
