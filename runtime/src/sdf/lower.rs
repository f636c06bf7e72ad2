use super::*;

// ------------------------------------------------------------------ lowering

pub(super) struct Lowering {
    pub(super) options: LowerOptions,
    pub(super) prims: Vec<PrimInfo>,
    pub(super) bvh_nodes: usize,
    /// Inside a domain operator: its frame's local → world map, for the
    /// primitives' centres (the rainbow's `c`; the copy at the origin for
    /// a repetition).
    pub(super) warp_to_world: DAffine3,
    /// Lowering relative to an origin away from the world's: each
    /// primitive's own position is moved into its frame (see [`anchored`]).
    pub(super) relative: bool,
}

impl Lowering {
    pub(super) fn leaf<P: Prim>(&mut self, prim: P, shape: &Shape, frame: &Frame) -> Box<dyn Node> {
        let id = self.prim_id(shape, frame);
        Box::new(Leaf {
            prim,
            xform: frame.xform(),
            scale: frame.scale as f32,
            id,
        })
    }

    /// A new primitive id for `shape` in `frame`, with its shading data.
    fn prim_id(&mut self, shape: &Shape, frame: &Frame) -> u32 {
        let id = self.prims.len() as u32;
        self.prims.push(PrimInfo {
            center: self.world_center(shape, frame),
            material: frame.material.clone(),
            kind: shape.name(),
        });
        id
    }

    /// A primitive's centre in the world (the rainbow's `c`).
    fn world_center(&self, shape: &Shape, frame: &Frame) -> DVec3 {
        let local_center = shape.primitive_center().unwrap_or(DVec3::ZERO);
        (self.warp_to_world * frame.to_local.inverse()).transform_point3(local_center)
    }

    pub(super) fn lower(&mut self, shape: &Shape, frame: &Frame) -> Box<dyn Node> {
        if self.relative {
            if let Some((moved, by)) = anchored(shape, frame) {
                // A primitive: lowered at its anchor (once, not again), with
                // the centre of the shape as written.
                self.relative = false;
                let node = self.lower(&moved, &frame.then(DAffine3::from_translation(-by), 1.0));
                self.relative = true;
                let center = self.world_center(shape, frame);
                self.prims
                    .last_mut()
                    .expect("a primitive was lowered")
                    .center = center;
                return node;
            }
        }
        let f = |a: &Arg<f64>| a.value as f32;
        let c = |a: &Arg<DVec3>| V3::lit(a.value.to_array());
        match shape {
            Shape::Prim(x) => x.with(LowerLeaf {
                lowering: self,
                shape,
                frame,
            }),
            Shape::User(u) => {
                let id = self.prim_id(shape, frame);
                Box::new(UserLeaf::new(u, frame.xform(), frame.scale as f32, id))
            }
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
                xform: self.noise_frame(frame, frequency.value).xform(),
                amplitude: (amplitude.value * frame.scale) as f32,
                frequency: frequency.value as f32,
            }),
            Shape::Paint(s, m) => {
                let mut painted = frame.clone();
                painted.material = Some(m.clone());
                self.lower(s, &painted)
            }
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
            Shape::Elongate(s, h) => self.warp(s, WarpOp::Elongate(c(h)), frame),
            Shape::Mirror(s, axis) => self.warp(s, WarpOp::Mirror(axis.index()), frame),
            Shape::Repeat {
                shape: s,
                spacing,
                count,
            } => self.warp(
                s,
                WarpOp::Repeat {
                    spacing: c(spacing),
                    extent: s.extent(),
                    count: *count,
                    bound: s.repeated_as_bound().map(box_outwards),
                },
                frame,
            ),
            Shape::Twist(s, rate) | Shape::Bend(s, rate) => {
                let (radius, lo, hi) = s.turn_region();
                let op = WarpOp::Turn {
                    rate: f(rate),
                    bend: matches!(shape, Shape::Bend(..)),
                    radius,
                    lo,
                    hi,
                };
                self.warp(s, op, frame)
            }
            Shape::ScaleXyz(s, by) => {
                let boxed = s.bounds().map(|b| {
                    let (ctr, size) = (b.center() * by.value, (b.max - b.min) * by.value);
                    (V3::lit(ctr.to_array()), V3::lit(size.to_array()))
                });
                self.warp(s, WarpOp::Scale { by: c(by), boxed }, frame)
            }
        }
    }

    /// The frame a displacement's `sin(f·x)·sin(f·y)·sin(f·z)` is evaluated
    /// in. Lowered relative to an origin, its translation (which holds the
    /// origin) is reduced modulo the period `2π/f` on each axis, in f64:
    /// the same function, evaluated in f32 on coordinates near the camera
    /// instead of near the origin's size.
    fn noise_frame(&self, frame: &Frame, frequency: f64) -> Frame {
        let mut noise = frame.clone();
        if self.relative && frequency != 0.0 {
            let period = std::f64::consts::TAU / frequency.abs();
            let t = noise.to_local.translation;
            noise.to_local.translation = t - (t / period).round() * period;
        }
        noise
    }

    /// A domain operator: its child is lowered in the operator's own frame
    /// (keeping the material), the warp applied between the two.
    fn warp(&mut self, child: &Shape, op: WarpOp, frame: &Frame) -> Box<dyn Node> {
        let mut inner_frame = Frame::identity();
        inner_frame.material = frame.material.clone();
        let outer = self.warp_to_world;
        self.warp_to_world = outer * frame.to_local.inverse();
        let inner = self.lower(child, &inner_frame);
        self.warp_to_world = outer;
        Box::new(Warp {
            inner,
            xform: frame.xform(),
            scale: frame.scale as f32,
            op,
        })
    }

    pub(super) fn binary(
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
    pub(super) fn union_members<'s>(
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

    /// The members of `shape`'s top-level union (through transforms and
    /// paint) as a BVH without a grid, for culling per screen tile: `None`
    /// unless at least two are bounded.
    pub(super) fn tile_union(&mut self, shape: &Shape, frame: &Frame) -> Option<BvhUnion> {
        let mut members = Vec::new();
        self.union_members(shape, frame, &mut members);
        let members = dedup_primitives(members);
        if members.iter().filter(|(s, _)| s.bounds().is_some()).count() < 2 {
            return None;
        }
        let (items, unbounded) = self.lower_members(&members);
        let mut bvh = BvhUnion::tree(items, unbounded);
        if self.options.pack {
            bvh.table = member_table(&bvh.members);
        }
        Some(bvh)
    }

    /// Members lowered, the bounded ones with their world boxes and
    /// Lipschitz bounds.
    #[allow(clippy::type_complexity)]
    fn lower_members(
        &mut self,
        members: &[(&Shape, Frame)],
    ) -> (Vec<(Box<dyn Node>, Aabb, f32)>, Vec<Box<dyn Node>>) {
        let mut items = Vec::with_capacity(members.len());
        let mut unbounded = Vec::new();
        for (s, f) in members {
            let node = self.lower(s, f);
            match s.bounds() {
                Some(b) => items.push((node, f.world_box(b), s.lipschitz() as f32)),
                None => unbounded.push(node),
            }
        }
        (items, unbounded)
    }

    pub(super) fn union(&mut self, members: Vec<(&Shape, Frame)>) -> Box<dyn Node> {
        let members = if self.options.cull {
            dedup_primitives(members)
        } else {
            members
        };
        let bounded = members.iter().filter(|(s, _)| s.bounds().is_some()).count();
        if !self.options.cull || bounded < self.options.bvh_threshold {
            let mut nodes: Vec<_> = members.iter().map(|(s, f)| self.lower(s, f)).collect();
            if self.options.pack {
                nodes = pack_union(nodes);
            }
            if nodes.len() == 1 {
                return nodes.pop().expect("one node");
            }
            return Box::new(Union(nodes));
        }
        let (items, unbounded) = self.lower_members(&members);
        let mut bvh = BvhUnion::build(items, unbounded);
        if self.options.pack {
            bvh.table = member_table(&bvh.members);
        }
        self.bvh_nodes += bvh.nodes.len();
        Box::new(bvh)
    }
}

/// A primitive moved to its own anchor, and the anchor (in the primitive's
/// frame): its centre (a capsule's midpoint), or for a plane the point of
/// it nearest the evaluator's origin. Lowered at the anchor with the
/// anchor's translation in its frame, composed with the rest in f64, the
/// f32 formula sees coordinates relative to the primitive, as small as the
/// distances it returns near the camera however far both are from the world
/// origin. The value is the same function of the point; only the rounding
/// differs. `None` for anything but a primitive.
pub(super) fn anchored(shape: &Shape, frame: &Frame) -> Option<(Shape, DVec3)> {
    let mut moved = shape.clone();
    let Shape::Prim(p) = &mut moved else {
        return None;
    };
    let by = match p {
        // A plane has no centre: its point nearest the origin of the frame.
        Primitive::Plane(Plane { normal, height }) => {
            let n = normal.value;
            let e = frame.to_local.translation;
            let by = e - (e.dot(n) - height.value) * n;
            height.value -= n.dot(by);
            by
        }
        // Every other primitive at its centre, its points moved with it.
        other => {
            let by = other.center();
            for pt in other.points_mut() {
                *pt -= by;
            }
            by
        }
    };
    Some((moved, by))
}

/// A transform's child, its world → local step and its distance scale.
pub(super) fn transform(shape: &Shape) -> Option<(&Shape, DAffine3, f64)> {
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
pub(super) fn dedup_primitives(members: Vec<(&Shape, Frame)>) -> Vec<(&Shape, Frame)> {
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

/// A plain union's members with the primitives of each kind that sit in
/// world coordinates (identity transform, scale 1: the leaf's value is the
/// formula's) gathered into one [`Packed`] node per kind, when there are at
/// least two; the rest unchanged. The minimum is the same; only which of
/// two members at exactly equal distance names the point may change.
pub(super) fn pack_union(nodes: Vec<Box<dyn Node>>) -> Vec<Box<dyn Node>> {
    struct Packer {
        rest: Vec<Box<dyn Node>>,
        out: Vec<Box<dyn Node>>,
    }
    impl KindVisitor for Packer {
        fn visit<K: Declared>(&mut self) {
            // Only formulas that run on lanes gain from packing.
            if K::SPEC.lanes {
                let rest = std::mem::take(&mut self.rest);
                self.rest = pack_kind::<PrimOf<K>>(rest, &mut self.out);
            }
        }
    }
    let mut p = Packer {
        rest: nodes,
        out: Vec::new(),
    };
    Primitive::for_each_kind(&mut p);
    p.out.extend(p.rest);
    p.out
}

/// Lowers a primitive to its leaf ([`Primitive::with`]).
struct LowerLeaf<'a> {
    lowering: &'a mut Lowering,
    shape: &'a Shape,
    frame: &'a Frame,
}

impl WithDeclared for LowerLeaf<'_> {
    type Out = Box<dyn Node>;
    fn with<K: Declared>(self, x: &K) -> Box<dyn Node> {
        self.lowering
            .leaf(PrimOf::<K>::new(x), self.shape, self.frame)
    }
}

/// A leaf of kind `P` in world coordinates (its value is the formula's):
/// its primitive and id.
fn packable<P: Prim + Clone>(n: &dyn Node) -> Option<(P, u32)> {
    (n as &dyn std::any::Any)
        .downcast_ref::<Leaf<P>>()
        .filter(|l| matches!(l.xform, Xform::Identity) && l.scale == 1.0)
        .map(|l| (l.prim.clone(), l.id))
}

/// A culled union's members as one [`MemberTable`] when all are packable
/// primitives of one [`Lanewise`] kind.
pub(super) fn member_table(members: &[Box<dyn Node>]) -> Option<Box<dyn MemberTable>> {
    struct Table<'a> {
        members: &'a [Box<dyn Node>],
        found: Option<Box<dyn MemberTable>>,
    }
    impl KindVisitor for Table<'_> {
        fn visit<K: Declared>(&mut self) {
            if self.found.is_some() || !K::SPEC.lanes {
                return;
            }
            let Some((prims, ids)) = self
                .members
                .iter()
                .map(|m| packable::<PrimOf<K>>(m.as_ref()))
                .collect::<Option<(Vec<_>, Vec<u32>)>>()
            else {
                return;
            };
            // Eight members evaluated together share their axes.
            if prims.iter().all(|p| K::same_fixed(&p.0, &prims[0].0)) {
                self.found = Some(Box::new(Packed { prims, ids }));
            }
        }
    }
    let mut t = Table {
        members,
        found: None,
    };
    Primitive::for_each_kind(&mut t);
    t.found
}

fn pack_kind<P: Prim + Clone>(
    nodes: Vec<Box<dyn Node>>,
    out: &mut Vec<Box<dyn Node>>,
) -> Vec<Box<dyn Node>> {
    let packable = packable::<P>;
    if nodes
        .iter()
        .filter(|n| packable(n.as_ref()).is_some())
        .count()
        < 2
    {
        return nodes;
    }
    let (mut prims, mut ids, mut rest) = (Vec::new(), Vec::new(), Vec::new());
    for n in nodes {
        match packable(n.as_ref()) {
            Some((p, id)) => {
                prims.push(p);
                ids.push(id);
            }
            None => rest.push(n),
        }
    }
    out.push(Box::new(Packed { prims, ids }));
    rest
}

/// A box in f32, rounded outwards: it still holds the shape, so distances
/// to it stay at most the shape's.
fn box_outwards(b: Aabb) -> (V3<f32>, V3<f32>) {
    let down = |x: f64| {
        let y = x as f32;
        if y as f64 > x {
            y.next_down()
        } else {
            y
        }
    };
    let up = |x: f64| {
        let y = x as f32;
        if (y as f64) < x {
            y.next_up()
        } else {
            y
        }
    };
    (
        V3::from_array(b.min.to_array().map(down)),
        V3::from_array(b.max.to_array().map(up)),
    )
}
