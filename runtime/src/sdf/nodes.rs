use super::*;

// ---------------------------------------------------------------- primitives

pub(super) trait Prim: Send + Sync + 'static {
    fn local(&self, p: Vec3A) -> f32;
    /// [`Prim::local`] of a pack of points. Primitives whose formula has no
    /// branch on the point evaluate the same generic formula on the lanes;
    /// the others (the default) go lane by lane.
    #[inline(always)]
    fn local8(&self, p: P8) -> F8 {
        per_lane(&p, |q| self.local(q))
    }
}

/// A constant in every lane.
#[inline(always)]
fn s8(x: f32) -> F8 {
    F8::splat(x)
}

#[inline(always)]
fn v8(v: V3<f32>) -> P8 {
    V3::new(s8(v.x), s8(v.y), s8(v.z))
}

#[inline(always)]
pub(super) fn v3(p: Vec3A) -> V3<f32> {
    V3::new(p.x, p.y, p.z)
}

/// A vector of a leaf's arguments, 16-byte aligned: the formula reads it
/// with one aligned load (an unaligned one across a cache line costs the
/// per-point evaluator a quarter of its speed).
#[derive(Clone, Copy)]
#[repr(C, align(16))]
pub(super) struct A3(pub(super) V3<f32>);

/// A leaf's arguments as stored: f32, vectors aligned.
pub(super) struct Stored;
impl Family for Stored {
    type S = f32;
    type V = A3;
}

/// One primitive's values in f32, for any declared kind `K`: the one leaf
/// of every primitive. It evaluates the formula its declaration gives, in
/// f32, or on eight lanes at once where the declaration says the formula
/// never branches on the point (else lane by lane).
pub(super) struct PrimOf<K: Declared>(pub(super) K::Of<Stored>);

impl<K: Declared> Clone for PrimOf<K> {
    #[inline(always)]
    fn clone(&self) -> Self {
        PrimOf(self.0.clone())
    }
}

impl<K: Declared> PrimOf<K> {
    /// The primitive's arguments at their values, in f32.
    pub(super) fn new(x: &K) -> Self {
        PrimOf(K::map::<Ir, Stored>(
            x.ir(),
            |a| a.value as f32,
            |a| A3(V3::lit(a.value.to_array())),
        ))
    }
}

impl<K: Declared> Prim for PrimOf<K> {
    #[inline(always)]
    fn local(&self, p: Vec3A) -> f32 {
        K::distance(&K::map::<Stored, Num<f32>>(&self.0, |x| *x, |v| v.0), v3(p))
    }
    #[inline(always)]
    fn local8(&self, p: P8) -> F8 {
        if K::SPEC.lanes {
            K::distance(
                &K::map::<Stored, Num<F8>>(&self.0, |x| s8(*x), |v| v8(v.0)),
                p,
            )
        } else {
            per_lane(&p, |q| self.local(q))
        }
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
    fn dist_packs(&self, p: &[P8], out: &mut [F8]) {
        leaf_packs(self, p, out)
    }
}

#[inline(always)]
fn leaf_kernel<P: Prim>(leaf: &Leaf<P>, p: &[P8], out: &mut [F8]) {
    for (q, o) in p.iter().zip(out.iter_mut()) {
        *o = leaf.prim.local8(leaf.xform.apply8(*q)) * s8(leaf.scale);
    }
}
lanes::avx2_kernel!(leaf_packs, leaf_kernel, Leaf);

/// A union of primitives of one kind, each in world coordinates (identity
/// transform, scale 1): their parameters in one array, evaluated without a
/// call per member, and for packs of points member by member over the
/// packs (the same formula per lane as [`Prim::local`]).
pub(super) struct Packed<P> {
    pub(super) prims: Vec<P>,
    pub(super) ids: Vec<u32>,
}

impl<P: Prim> Node for Packed<P> {
    fn dist(&self, p: Vec3A) -> f32 {
        self.prims
            .iter()
            .fold(f32::INFINITY, |m, c| m.min(c.local(p)))
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        let mut best = (f32::INFINITY, u32::MAX);
        for (c, id) in self.prims.iter().zip(&self.ids) {
            let d = c.local(p);
            if d < best.0 {
                best = (d, *id);
            }
        }
        best
    }
    fn dist_packs(&self, p: &[P8], out: &mut [F8]) {
        packed_packs(self, p, out)
    }
}

#[inline(always)]
fn packed_kernel<P: Prim>(union: &Packed<P>, p: &[P8], out: &mut [F8]) {
    for (q, o) in p.iter().zip(out.iter_mut()) {
        let mut m = s8(f32::INFINITY);
        for c in &union.prims {
            m = m.min(c.local8(*q));
        }
        *o = m;
    }
}
lanes::avx2_kernel!(packed_packs, packed_kernel, Packed);

/// Primitives whose distances at one point are taken for eight members at
/// once (member `i` in lane `i`): the same formula, the members' parameters
/// in the lanes instead of the points.
pub(super) trait Lanewise: Prim + Clone {
    fn members8(ms: [&Self; LANES], p: Vec3A) -> F8;
}

impl<K: Declared> Lanewise for PrimOf<K> {
    #[inline(always)]
    fn members8(ms: [&Self; LANES], p: Vec3A) -> F8 {
        let at = K::gather::<Stored, Num<F8>>(
            ms.map(|m| &m.0),
            |x| F8(x.map(|x| *x)),
            |v| {
                V3::new(
                    F8(std::array::from_fn(|i| v[i].0.x)),
                    F8(std::array::from_fn(|i| v[i].0.y)),
                    F8(std::array::from_fn(|i| v[i].0.z)),
                )
            },
        );
        K::distance(&at, v8(v3(p)))
    }
}

/// A culled union's members as one table (all primitives of one
/// [`Lanewise`] kind in world coordinates): the minimum over a cell's
/// candidate list, eight members at a time.
pub(super) trait MemberTable: Send + Sync {
    /// `min(best, member distances of list)` at `p`.
    fn min_over(&self, p: Vec3A, list: &[u32], best: f32) -> f32;
    /// The minimum over all members, for packs of points.
    fn min_packs(&self, p: &[P8], out: &mut [F8]);
}

#[inline(always)]
fn table_kernel<P: Lanewise>(t: &Packed<P>, p: Vec3A, list: &[u32], best: f32) -> f32 {
    // A short list costs less one member at a time (still without a call).
    if list.len() < LANES / 2 {
        return list
            .iter()
            .fold(best, |m, i| m.min(t.prims[*i as usize].local(p)));
    }
    let mut m = s8(best);
    for chunk in list.chunks(LANES) {
        // A partial chunk repeats its last member.
        let last = chunk.len() - 1;
        let ms: [&P; LANES] = std::array::from_fn(|i| &t.prims[chunk[i.min(last)] as usize]);
        m = m.min(P::members8(ms, p));
    }
    m.0.iter().fold(best, |a, b| a.min(*b))
}

impl<P: Lanewise> MemberTable for Packed<P> {
    fn min_over(&self, p: Vec3A, list: &[u32], best: f32) -> f32 {
        #[cfg(any(target_arch = "x86_64", target_arch = "x86"))]
        {
            #[target_feature(enable = "avx2")]
            unsafe fn avx2<P: Lanewise>(t: &Packed<P>, p: Vec3A, list: &[u32], best: f32) -> f32 {
                table_kernel(t, p, list, best)
            }
            if lanes::has_avx2() {
                // SAFETY: the CPU supports AVX2 (checked just above).
                return unsafe { avx2(self, p, list, best) };
            }
        }
        table_kernel(self, p, list, best)
    }
    fn min_packs(&self, p: &[P8], out: &mut [F8]) {
        packed_packs(self, p, out)
    }
}

/// The elementwise `f(out, other)` of a node's packs and another's.
#[inline(always)]
pub(super) fn combine_packs(child: &dyn Node, p: &[P8], out: &mut [F8], f: impl Fn(F8, F8) -> F8) {
    let mut tmp = [s8(0.0); BATCH_PACKS];
    for (p, out) in p.chunks(BATCH_PACKS).zip(out.chunks_mut(BATCH_PACKS)) {
        let tmp = &mut tmp[..p.len()];
        child.dist_packs(p, tmp);
        for (o, t) in out.iter_mut().zip(tmp.iter()) {
            *o = f(*o, *t);
        }
    }
}

// ---------------------------------------------------------------- combinators

pub(super) struct Union(pub(super) Vec<Box<dyn Node>>);
impl Node for Union {
    fn dist(&self, p: Vec3A) -> f32 {
        self.0.iter().fold(f32::INFINITY, |m, c| m.min(c.dist(p)))
    }
    fn dist_packs(&self, p: &[P8], out: &mut [F8]) {
        for o in out.iter_mut() {
            *o = s8(f32::INFINITY);
        }
        for c in &self.0 {
            combine_packs(c.as_ref(), p, out, |m, d| m.min(d));
        }
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
    fn dist_packs(&self, p: &[P8], out: &mut [F8]) {
        for o in out.iter_mut() {
            *o = s8(f32::NEG_INFINITY);
        }
        for c in &self.0 {
            combine_packs(c.as_ref(), p, out, |m, d| m.max(d));
        }
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
    fn dist_packs(&self, p: &[P8], out: &mut [F8]) {
        self.inner.dist_packs(p, out);
        for o in out.iter_mut() {
            *o = if self.shell {
                o.abs() - s8(self.by)
            } else {
                *o - s8(self.by)
            };
        }
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

// ---------------------------------------------------------------- domain warps

/// A domain operator: the point is moved into the child's frame (`xform`,
/// then `op`), the child (lowered in that frame) is evaluated, and the
/// result scaled back to world units. Each op follows `Shape::sample`.
pub(super) struct Warp {
    pub(super) inner: Box<dyn Node>,
    pub(super) xform: Xform,
    pub(super) scale: f32,
    pub(super) op: WarpOp,
}

pub(super) enum WarpOp {
    Elongate(V3<f32>),
    Mirror(usize),
    Repeat {
        spacing: V3<f32>,
        extent: DVec3,
        count: [u32; 3],
        /// A bounded child whose value is only a bound: its box
        /// (continuous terms, `sdf::repeat_bound_term`).
        bound: Option<(V3<f32>, V3<f32>)>,
    },
    /// Twist (`bend: false`) or bend at `rate` in the cylinder `radius`, `lo..hi`.
    Turn {
        rate: f32,
        bend: bool,
        radius: f64,
        lo: f64,
        hi: f64,
    },
    /// Non-uniform scale, with the scaled child's box when it has one.
    Scale {
        by: V3<f32>,
        boxed: Option<(V3<f32>, V3<f32>)>,
    },
}

#[inline(always)]
fn a3(p: V3<f32>) -> Vec3A {
    Vec3A::new(p.x, p.y, p.z)
}

impl Warp {
    fn eval(&self, p: Vec3A, id: bool) -> (f32, u32) {
        let q = v3(self.xform.apply(p));
        let inner = |q: V3<f32>| {
            if id {
                self.inner.dist_id(a3(q))
            } else {
                (self.inner.dist(a3(q)), 0)
            }
        };
        let (d, i) = match &self.op {
            WarpOp::Elongate(h) => inner(sdf::elongate(q, *h)),
            WarpOp::Mirror(axis) => {
                let mut a = q.to_array();
                a[*axis] = a[*axis].abs();
                inner(V3::from_array(a))
            }
            WarpOp::Repeat {
                spacing: s,
                extent,
                count,
                bound,
            } => {
                let r = repeat_ranges(q, *s, *extent, *count);
                let mut best = (f32::INFINITY, u32::MAX);
                for kx in cells(r[0]) {
                    for ky in cells(r[1]) {
                        for kz in cells(r[2]) {
                            let off = V3::new(s.x * kx as f32, s.y * ky as f32, s.z * kz as f32);
                            let mut c = inner(q - off);
                            if let Some((lo, hi)) = bound {
                                c.0 = sdf::repeat_bound_term(c.0, q - off, *s, *lo, *hi);
                            }
                            if c.0 < best.0 {
                                best = c;
                            }
                        }
                    }
                }
                if let Some(b) = bound {
                    if let Some(d) = sdf::repeat_beyond(q, *s, *b, *count, r) {
                        best.0 = best.0.min(d);
                    }
                }
                best
            }
            WarpOp::Turn {
                rate,
                bend,
                radius,
                lo,
                hi,
            } => {
                let (c, e) = sdf::into_cylinder(q, *radius, *lo, *hi);
                let w = if *bend {
                    sdf::bend(c, *rate)
                } else {
                    sdf::twist(c, *rate)
                };
                let (d, i) = inner(w);
                (sdf::beyond(e, d), i)
            }
            WarpOp::Scale { by, boxed } => {
                let (d, i) = inner(q.zip(*by, |x, y| x / y));
                let d = d * by.min_element();
                match boxed {
                    Some((c, size)) => (d.max(sdf::cuboid(q, *c, *size)), i),
                    None => (d, i),
                }
            }
        };
        (d * self.scale, i)
    }
}

impl Node for Warp {
    fn dist(&self, p: Vec3A) -> f32 {
        self.eval(p, false).0
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        self.eval(p, true)
    }
}
