use super::*;

// ---------------------------------------------------------------- primitives

pub(super) trait Prim: Send + Sync + 'static {
    fn local(&self, p: Vec3A) -> f32;
}

#[inline(always)]
pub(super) fn v3(p: Vec3A) -> V3<f32> {
    V3::new(p.x, p.y, p.z)
}

// Each primitive evaluates the one formula in `sdfl_stdlib::sdf`, in f32.

pub(super) struct Sphere {
    pub(super) c: V3<f32>,
    pub(super) r: f32,
}
impl Prim for Sphere {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::sphere(v3(p), self.c, self.r)
    }
}

pub(super) struct BoxPrim {
    pub(super) c: V3<f32>,
    pub(super) size: V3<f32>,
}
impl Prim for BoxPrim {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::cuboid(v3(p), self.c, self.size)
    }
}

pub(super) struct BoxFrame {
    pub(super) c: V3<f32>,
    pub(super) size: V3<f32>,
    pub(super) thickness: f32,
}
impl Prim for BoxFrame {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::box_frame(v3(p), self.c, self.size, self.thickness)
    }
}

pub(super) struct Octahedron {
    pub(super) c: V3<f32>,
    pub(super) size: f32,
}
impl Prim for Octahedron {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::octahedron(v3(p), self.c, self.size)
    }
}

pub(super) struct CappedCone {
    pub(super) c: V3<f32>,
    pub(super) height: f32,
    pub(super) bottom: f32,
    pub(super) top: f32,
}
impl Prim for CappedCone {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::capped_cone(v3(p), self.c, self.height, self.bottom, self.top)
    }
}

pub(super) struct Ellipsoid {
    pub(super) c: V3<f32>,
    pub(super) radii: V3<f32>,
}
impl Prim for Ellipsoid {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::ellipsoid(v3(p), self.c, self.radii)
    }
}

pub(super) struct Torus {
    pub(super) c: V3<f32>,
    pub(super) major: f32,
    pub(super) minor: f32,
}
impl Prim for Torus {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::torus(v3(p), self.c, self.major, self.minor)
    }
}

pub(super) struct Capsule {
    pub(super) a: V3<f32>,
    pub(super) b: V3<f32>,
    pub(super) r: f32,
}
impl Prim for Capsule {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::capsule(v3(p), self.a, self.b, self.r)
    }
}

pub(super) struct Cylinder {
    pub(super) c: V3<f32>,
    pub(super) r: f32,
    pub(super) height: f32,
}
impl Prim for Cylinder {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::cylinder(v3(p), self.c, self.r, self.height)
    }
}

pub(super) struct Plane {
    pub(super) n: V3<f32>,
    pub(super) h: f32,
}
impl Prim for Plane {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        sdf::plane(v3(p), self.n, self.h)
    }
}

/// A primitive placed in the world.
pub(super) struct Leaf<P> {
    pub(super) prim: P,
    pub(super) xform: Xform,
    pub(super) scale: f32,
    pub(super) id: u32,
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

pub(super) struct Union(pub(super) Vec<Box<dyn Node>>);
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

pub(super) struct Intersection(pub(super) Vec<Box<dyn Node>>);
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
pub(super) enum SmoothOp {
    Union,
    Intersection,
    Subtraction,
}

/// `Subtraction` with `k = 0` is the sharp `max(a, -b)`.
pub(super) struct Binary {
    pub(super) a: Box<dyn Node>,
    pub(super) b: Box<dyn Node>,
    pub(super) op: SmoothOp,
    pub(super) k: f32,
}

impl Binary {
    #[inline(always)]
    pub(super) fn combine(&self, a: f32, b: f32) -> f32 {
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
pub(super) struct Offset {
    pub(super) inner: Box<dyn Node>,
    pub(super) by: f32,
    pub(super) shell: bool,
}
impl Offset {
    #[inline(always)]
    pub(super) fn apply(&self, d: f32) -> f32 {
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
pub(super) struct Xor(pub(super) Box<dyn Node>, pub(super) Box<dyn Node>);
impl Node for Xor {
    fn dist(&self, p: Vec3A) -> f32 {
        sdf::xor(self.0.dist(p), self.1.dist(p))
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        let ((a, ia), (b, ib)) = (self.0.dist_id(p), self.1.dist_id(p));
        (sdf::xor(a, b), if a.abs() <= b.abs() { ia } else { ib })
    }
}

pub(super) struct Displace {
    pub(super) inner: Box<dyn Node>,
    pub(super) xform: Xform,
    pub(super) amplitude: f32,
    pub(super) frequency: f32,
}
impl Displace {
    #[inline(always)]
    pub(super) fn offset(&self, p: Vec3A) -> f32 {
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
