//! Culling per screen tile: before the rays of a tile are marched, the
//! members of the scene's top-level union whose boxes cannot come near any
//! of the tile's rays are dropped (a BVH walked against the tile's pyramid
//! of rays), and each ray starts where it enters the box around the rest.
//!
//! Conservative by construction: a member is dropped only when its box,
//! grown by a margin, lies wholly outside one plane of the pyramid. The
//! margin covers what the tracer compares with a distance (the hit
//! tolerance, the pixel footprint, twice over) and the reach of a normal's
//! samples, so wherever a ray or a normal sample is within the margin of a
//! surface, the tile's distance equals the whole scene's (every dropped
//! member is farther away than the margin); farther out it is larger, which
//! only lengthens steps that cannot reach a kept surface and can never reach
//! a dropped one. Rays that enter no kept box end as misses unmarched.

use super::*;
use crate::trace::{
    normal, sphere_trace, sphere_trace_packs, Distance, Hit, March, Step, TraceSettings,
};

/// Tile side in pixels.
pub const TILE: usize = 8;

/// Longest candidate list a tile marches over; a tile meeting more members
/// marches the whole scene (its grid and BVH are faster there) and keeps
/// only the entry point and the misses.
const MAX_TILE_MEMBERS: usize = 48;

/// How far beyond a surface a tile must keep it: `abs + per_distance·D`,
/// with `D` the farthest point of the member's box from the eye.
#[derive(Debug, Clone, Copy)]
pub struct Margin {
    /// The constant part, in world units.
    pub abs: f32,
    /// The part growing with the distance `D` from the eye (per unit of `D`).
    pub per_distance: f32,
}

impl Margin {
    /// The margin for tracing with `s` from `eye` and taking normals with
    /// steps of at most `normal_step` (what [`crate::trace::normal_step`]
    /// gives within `far` of the eye) in a scene with Lipschitz bound
    /// `lipschitz`: twice what a hit test accepts (`L·tolerance`, the
    /// tracer comparing `d / L`, and `L·2·footprint·t` for a ray decided at
    /// its footprint) plus the normal samples' reach (`√3·h`, over which a
    /// distance changes by up to `L·√3·h`), and a relative part for f32
    /// rounding of the box tests.
    pub fn for_trace(s: &TraceSettings, eye: Vec3A, normal_step: f32, lipschitz: f32) -> Margin {
        let l = lipschitz.max(1.0);
        let scale = eye.abs().max_element() + s.far;
        let tolerance = s.epsilon.max(scale * crate::trace::PRECISION_TOLERANCE);
        let reach = 3f32.sqrt() * normal_step * (l + 1.0);
        Margin {
            abs: 2.0 * (l * tolerance + reach),
            per_distance: 2.5 * l * s.footprint + 1e-5,
        }
    }

    #[inline]
    fn of_box(&self, q: Vec3A, h: Vec3A) -> f32 {
        self.abs + self.per_distance * (q.length() + h.length())
    }
}

/// The pyramid of rays `eye + t·(ax·x + ay·y + az)`, `t ≥ 0`, for `(x, y)`
/// in a rectangle of the image plane (NDC divided by the focal length).
#[derive(Debug, Clone, Copy)]
pub struct Frustum {
    eye: Vec3A,
    /// Inward unit normals of the four side planes (through the eye) and
    /// of the plane through the eye facing forward.
    planes: [Vec3A; 5],
}

impl Frustum {
    /// The rays from `eye` along `x·ax + y·ay + az` for `x` in `x0..x1` and
    /// `y` in `y0..y1` (either order): a screen tile's pyramid.
    pub fn new(
        eye: Vec3A,
        (ax, ay, az): (DVec3, DVec3, DVec3),
        (x0, x1): (f64, f64),
        (y0, y1): (f64, f64),
    ) -> Frustum {
        let (x0, x1) = (x0.min(x1), x0.max(x1));
        let (y0, y1) = (y0.min(y1), y0.max(y1));
        // A point q = u·ax + v·ay + w·az is inside when x0 ≤ u/w ≤ x1 and
        // y0 ≤ v/w ≤ y1: u - x0·w ≥ 0, x1·w - u ≥ 0, and so on.
        let planes = [ax - az * x0, az * x1 - ax, ay - az * y0, az * y1 - ay, az]
            .map(|n| Vec3A::from(n.normalize().as_vec3()));
        Frustum { eye, planes }
    }

    /// False only when the box (centre, half extents), grown by `margin`,
    /// lies wholly outside a plane of the pyramid.
    #[inline]
    pub fn may_meet(&self, c: Vec3A, h: Vec3A, margin: &Margin) -> bool {
        let q = c - self.eye;
        let m = margin.of_box(q, h);
        self.planes.iter().all(|n| n.dot(q) + n.abs().dot(h) >= -m)
    }
}

/// The part of a lowered scene that tiles cull: its top-level union's
/// members with their boxes, or the whole scene as one member.
pub struct TileScene<'a> {
    root: &'a dyn Node,
    /// The top-level union's members with their boxes, when culled by them.
    #[doc(hidden)]
    pub union: Option<&'a BvhUnion>,
    /// The scene's box when it is not a union (or culling is off: `None`).
    whole: Option<(Vec3A, Vec3A)>,
    eye: Vec3A,
    margin: Margin,
}

/// One tile's view of the scene: what its rays march, and where they can
/// start.
pub struct Tile<'a> {
    scene: &'a TileScene<'a>,
    /// No surface near any of the tile's rays: every ray misses.
    empty: bool,
    /// Candidate members (into the union), when the tile marches them
    /// instead of the whole scene.
    members: Option<Vec<u32>>,
    /// A box (min, max) holding every kept member's grown box; `None`
    /// where a member is unbounded.
    bounds: Option<(Vec3A, Vec3A)>,
    /// Rays start where they enter `bounds` (else at `near`: a scene that
    /// is no union, or a tile that keeps every member, keeps the plain
    /// tracer's steps, so its pixels are the same bit for bit; rays
    /// missing `bounds` still end unmarched).
    enter: bool,
}

impl Lowered {
    /// The scene as tiles see it, for rays from `eye` (in the evaluator's
    /// coordinates); without culling (`LowerOptions::cull` or `tiles` off) every tile
    /// marches the whole scene from `near`.
    pub fn tiles(&self, eye: Vec3A, margin: Margin) -> TileScene<'_> {
        let root = &*self.root;
        let union = (root as &dyn std::any::Any)
            .downcast_ref::<BvhUnion>()
            .or(self.tile_union.as_deref());
        TileScene {
            root,
            union: union.filter(|_| self.tiles),
            whole: self.bounds.filter(|_| self.tiles),
            eye,
            margin,
        }
    }
}

impl<'a> TileScene<'a> {
    /// The tile of rays through the rectangle `x`, `y` of the image plane
    /// (NDC / focal) for a camera with axes `axes`.
    pub fn tile(&'a self, axes: (DVec3, DVec3, DVec3), x: (f64, f64), y: (f64, f64)) -> Tile<'a> {
        let f = Frustum::new(self.eye, axes, x, y);
        self.cull(&f)
    }

    /// The tile of the rays inside `f`.
    pub fn cull(&'a self, f: &Frustum) -> Tile<'a> {
        let mut tile = Tile {
            scene: self,
            empty: false,
            members: None,
            bounds: None,
            enter: true,
        };
        let grow = |c: Vec3A, h: Vec3A| {
            let m = self.margin.of_box(c - self.eye, h);
            (c - h - Vec3A::splat(m), c + h + Vec3A::splat(m))
        };
        let join = |a: Option<(Vec3A, Vec3A)>, b: (Vec3A, Vec3A)| match a {
            Some(a) => (a.0.min(b.0), a.1.max(b.1)),
            None => b,
        };
        if let Some(u) = self.union {
            let mut list = Vec::new();
            let mut bounds = None;
            let mut stack = vec![0usize];
            while let Some(n) = stack.pop() {
                let node = u.nodes[n];
                if !f.may_meet(node.center, node.half, &self.margin) {
                    continue;
                }
                if node.count == 0 {
                    stack.push(node.first as usize);
                    stack.push(node.first as usize + 1);
                    continue;
                }
                for m in node.first..node.first + node.count {
                    let (c, h) = u.boxes[m as usize];
                    if f.may_meet(c, h, &self.margin) {
                        list.push(m);
                        bounds = Some(join(bounds, grow(c, h)));
                    }
                }
            }
            if !u.unbounded.is_empty() {
                bounds = None;
            } else if list.is_empty() {
                tile.empty = true;
                return tile;
            }
            tile.bounds = bounds;
            if list.len() == u.members.len() {
                // Nothing to cull: the whole scene from `near`, the plain
                // tracer's steps (rays missing `bounds` still end at once).
                tile.enter = false;
            } else if list.len() <= MAX_TILE_MEMBERS {
                tile.members = Some(list);
            }
        } else if let Some((c, h)) = self.whole {
            if !f.may_meet(c, h, &self.margin) {
                tile.empty = true;
                return tile;
            }
            tile.bounds = Some(grow(c, h));
            tile.enter = false;
        }
        tile
    }
}

impl Tile<'_> {
    /// Whether every ray of the tile misses.
    pub fn is_empty(&self) -> bool {
        self.empty
    }

    /// The members the tile marches (`None`: the whole scene).
    pub fn members(&self) -> Option<&[u32]> {
        self.members.as_deref()
    }

    /// [`normal`] at `p` over the tile's candidates (equal to the whole
    /// scene's within the margin of a surface), or the whole scene's.
    pub fn normal(&self, p: Vec3A, h: f32, fallback: Vec3A) -> Vec3A {
        match self.members {
            Some(_) => normal(self, p, h, fallback),
            None => normal(self.scene.root, p, h, fallback),
        }
    }

    /// [`sphere_trace`] of a ray of the tile from the eye, over the tile's
    /// candidates, from where it enters their box (a miss, unmarched, when
    /// it enters none before `far`); a scene that is no union is marched
    /// whole from `near`.
    pub fn trace(&self, dir: Vec3A, s: &TraceSettings) -> Hit {
        let s = match self.settings(dir, s) {
            Ok(s) => s,
            Err(miss) => return miss,
        };
        match self.members {
            Some(_) => sphere_trace(self, self.scene.eye, dir, &s),
            None => sphere_trace(self.scene.root, self.scene.eye, dir, &s),
        }
    }

    /// Whether the tile's rays are best marched together
    /// ([`Tile::trace_packs`]): it marches the whole scene, and the scene
    /// evaluates packs of points much faster than points one by one
    /// ([`Node::traces_in_packs`]).
    pub fn traces_in_packs(&self) -> bool {
        !self.empty && self.members.is_none() && self.scene.root.traces_in_packs()
    }

    /// [`Tile::trace`] of each ray (direction, settings), the rays marched
    /// together ([`sphere_trace_packs`]) where the tile marches the whole
    /// scene; each ends as [`Tile::trace`] ends it.
    pub fn trace_packs(&self, rays: &[(Vec3A, TraceSettings)]) -> Vec<Hit> {
        if self.members.is_some() {
            return rays.iter().map(|(d, s)| self.trace(*d, s)).collect();
        }
        let marches = rays
            .iter()
            .map(|(dir, s)| match self.settings(*dir, s) {
                Ok(s) => March::start(self.scene.eye, *dir, &s),
                // An ended march (its settings unused).
                Err(miss) => (March::start(self.scene.eye, *dir, s).0, Step::End(miss)),
            })
            .collect();
        sphere_trace_packs(self.scene.root, marches)
    }

    /// The settings a ray of the tile marches with (from where it enters
    /// the candidates' box), or its miss when it cannot meet them.
    #[inline]
    fn settings(&self, dir: Vec3A, s: &TraceSettings) -> Result<TraceSettings, Hit> {
        let miss = Hit {
            t: s.far,
            hit: false,
            steps: 0,
            undecided: false,
        };
        if self.empty {
            return Err(miss);
        }
        let mut near = s.near;
        if let Some((lo, hi)) = self.bounds {
            match enter(self.scene.eye, dir, lo, hi) {
                Some((t_in, t_out)) if t_out >= s.near && t_in <= s.far => {
                    if self.enter {
                        near = near.max(t_in);
                    }
                }
                _ => return Err(miss),
            }
        }
        Ok(TraceSettings { near, ..*s })
    }
}

/// Where the ray `o + t·d` enters and leaves the box `lo..hi` (`None`:
/// never). A component of `d` too small to divide by keeps the ray within
/// that slab (faces included) or out of it for every `t`.
#[inline]
#[doc(hidden)]
pub fn enter(o: Vec3A, d: Vec3A, lo: Vec3A, hi: Vec3A) -> Option<(f32, f32)> {
    let (mut t_in, mut t_out) = (f32::NEG_INFINITY, f32::INFINITY);
    for k in 0..3 {
        if d[k].abs() < 1e-30 {
            if !(lo[k] <= o[k] && o[k] <= hi[k]) {
                return None;
            }
            continue;
        }
        let (a, b) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
        t_in = t_in.max(a.min(b));
        t_out = t_out.min(a.max(b));
    }
    (t_in <= t_out).then_some((t_in, t_out))
}

impl Distance for Tile<'_> {
    #[inline]
    fn dist(&self, p: Vec3A) -> f32 {
        let u = self.scene.union.expect("member tiles come from a union");
        let list = self.members.as_deref().unwrap_or(&[]);
        let best = u
            .unbounded
            .iter()
            .fold(f32::INFINITY, |m, c| m.min(c.dist(p)));
        match &u.table {
            Some(table) => table.min_over(p, list, best),
            None => list
                .iter()
                .fold(best, |m, i| m.min(u.members[*i as usize].dist(p))),
        }
    }
}
