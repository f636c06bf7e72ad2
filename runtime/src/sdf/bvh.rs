use super::*;

// ----------------------------------------------------------------------- BVH

/// Signed distance to an axis-aligned box (centre offset `q`, half extents
/// `half`): the culling bound, in SIMD lanes.
#[inline(always)]
pub(super) fn box_sd(q: Vec3A, half: Vec3A) -> f32 {
    let q = q.abs() - half;
    q.max(Vec3A::ZERO).length() + q.max_element().min(0.0)
}

#[derive(Clone, Copy)]
pub(super) struct BvhNode {
    pub(super) center: Vec3A,
    pub(super) half: Vec3A,
    /// Leaf: `count > 0`, members `first..first + count`. Inner: children
    /// at `first` and `first + 1`.
    pub(super) first: u32,
    pub(super) count: u32,
}

/// A union culled with a bounding volume hierarchy, and a grid of cells
/// each listing the only members that can attain the minimum inside it.
#[doc(hidden)]
pub struct BvhUnion {
    pub(super) nodes: Vec<BvhNode>,
    /// The bounded members.
    pub members: Vec<Box<dyn Node>>,
    /// Each member's world box as (centre, half extents).
    pub boxes: Vec<(Vec3A, Vec3A)>,
    /// Members without bounds (planes): always evaluated.
    pub unbounded: Vec<Box<dyn Node>>,
    pub(super) grid: Option<CellGrid>,
    /// The members as one table when all are primitives of one packable
    /// kind: a cell's candidates are then evaluated eight at a time.
    pub(super) table: Option<Box<dyn MemberTable>>,
}

pub(super) const LEAF_SIZE: usize = 4;
/// Most members of a union with a [`MemberTable`] whose batches are
/// evaluated against every member, eight points at a time, instead of
/// culled point by point: below it the packed minimum is faster (measured
/// on spheres: at 100 members 4× the culled evaluator per point, at 1 000
/// half of it; see BENCHMARKS.md). The value is the same either way (the
/// culled minimum is the minimum).
pub(super) const PACKED_MEMBERS: usize = 256;
pub(super) const STACK: usize = 64;

/// Candidate lists per cell of a regular grid over the union's bounds.
///
/// For a cell with centre `c` and half-diagonal `r`, the minimum over the
/// members anywhere in the cell is at most `m + L·r`, where `m` is the
/// minimum at `c` and `L` the largest member Lipschitz bound. A member whose
/// box is farther than that from the cell is never below the minimum there
/// (its value is at least the distance to its box), so only the others are
/// listed, and the union evaluated over a point's list is exact.
pub(super) struct CellGrid {
    pub(super) min: Vec3A,
    pub(super) inv_size: Vec3A,
    pub(super) res: [usize; 3],
    /// (start, count) into `candidates`; `count == FALLBACK`: use the BVH.
    pub(super) cells: Vec<(u32, u32)>,
    pub(super) candidates: Vec<u32>,
}

pub(super) const FALLBACK: u32 = u32::MAX;
/// Longest candidate list kept; cells needing more fall back to the BVH.
pub(super) const MAX_CANDIDATES: usize = 32;
/// Most BVH nodes visited to list one cell's candidates.
pub(super) const MAX_CANDIDATE_VISITS: usize = 16 * MAX_CANDIDATES;
/// Most BVH nodes visited for a cell's upper bound.
pub(super) const UPPER_BOUND_VISITS: usize = 256;
/// How far the grid extends past the union's bounds, per side, as a
/// fraction of their size.
pub(super) const GRID_MARGIN: f32 = 0.5;
/// Most grid cells.
pub(super) const MAX_CELLS: usize = 262_144;

impl CellGrid {
    #[inline(always)]
    pub(super) fn lookup(&self, p: Vec3A) -> Option<&[u32]> {
        let q = (p - self.min) * self.inv_size;
        // NaN or outside: no cell.
        if !(q.cmpge(Vec3A::ZERO).all()) {
            return None;
        }
        let (i, j, k) = (q.x as usize, q.y as usize, q.z as usize);
        if i >= self.res[0] || j >= self.res[1] || k >= self.res[2] {
            return None;
        }
        let (start, count) = self.cells[(k * self.res[1] + j) * self.res[0] + i];
        (count != FALLBACK).then(|| &self.candidates[start as usize..(start + count) as usize])
    }
}

/// Euclidean gap between two boxes given as (centre, half extents); 0 when
/// they overlap.
#[inline(always)]
pub(super) fn box_gap(ca: Vec3A, ha: Vec3A, cb: Vec3A, hb: Vec3A) -> f32 {
    ((ca - cb).abs() - ha - hb).max(Vec3A::ZERO).length()
}

impl BvhUnion {
    pub(super) fn build(
        items: Vec<(Box<dyn Node>, Aabb, f32)>,
        unbounded: Vec<Box<dyn Node>>,
    ) -> Self {
        let lipschitz = items.iter().map(|i| i.2).fold(1.0f32, f32::max);
        let mut union = Self::tree(items, unbounded);
        union.grid = Some(union.build_grid(lipschitz));
        union
    }

    /// The BVH alone (no grid).
    pub(super) fn tree(
        items: Vec<(Box<dyn Node>, Aabb, f32)>,
        unbounded: Vec<Box<dyn Node>>,
    ) -> Self {
        let mut items: Vec<(Box<dyn Node>, Aabb, DVec3)> = items
            .into_iter()
            .map(|(n, b, _)| (n, b, b.center()))
            .collect();
        let mut nodes = vec![BvhNode {
            center: Vec3A::ZERO,
            half: Vec3A::ZERO,
            first: 0,
            count: 0,
        }];
        // Work list of (node index, range of items); items are reordered in
        // place so each leaf's members are contiguous.
        let mut work = vec![(0usize, 0usize, items.len())];
        while let Some((ni, lo, hi)) = work.pop() {
            let bounds = items[lo..hi]
                .iter()
                .map(|i| i.1)
                .reduce(Aabb::union)
                .expect("nonempty range");
            let (center, half) = padded(bounds);
            nodes[ni].center = center;
            nodes[ni].half = half;
            if hi - lo <= LEAF_SIZE {
                nodes[ni].first = lo as u32;
                nodes[ni].count = (hi - lo) as u32;
                continue;
            }
            // Median split along the widest axis of the member centres.
            let (cmin, cmax) = items[lo..hi]
                .iter()
                .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), i| {
                    (a.min(i.2), b.max(i.2))
                });
            let ext = cmax - cmin;
            let axis = if ext.x >= ext.y && ext.x >= ext.z {
                0
            } else if ext.y >= ext.z {
                1
            } else {
                2
            };
            let mid = (lo + hi) / 2;
            items[lo..hi].select_nth_unstable_by(mid - lo, |a, b| a.2[axis].total_cmp(&b.2[axis]));
            let left = nodes.len();
            nodes.push(BvhNode {
                center: Vec3A::ZERO,
                half: Vec3A::ZERO,
                first: 0,
                count: 0,
            });
            nodes.push(BvhNode {
                center: Vec3A::ZERO,
                half: Vec3A::ZERO,
                first: 0,
                count: 0,
            });
            nodes[ni].first = left as u32;
            work.push((left, lo, mid));
            work.push((left + 1, mid, hi));
        }
        let boxes = items.iter().map(|i| padded(i.1)).collect();
        BvhUnion {
            nodes,
            members: items.into_iter().map(|i| i.0).collect(),
            boxes,
            unbounded,
            grid: None,
            table: None,
        }
    }

    pub(super) fn build_grid(&self, lipschitz: f32) -> CellGrid {
        use rayon::prelude::*;
        // The grid reaches past the bounds by half their size on each side,
        // where rays approaching the scene spend most of their steps.
        let root = self.nodes[0];
        let half_ext = root.half.max(Vec3A::splat(1e-6)) * (1.0 + 2.0 * GRID_MARGIN);
        let (lo, ext) = (root.center - half_ext, half_ext * 2.0);
        let target = (self.members.len() * 32).clamp(4096, MAX_CELLS) as f32;
        let size = (ext.x * ext.y * ext.z / target).cbrt().max(1e-6);
        let res = [ext.x, ext.y, ext.z].map(|e| ((e / size).ceil() as usize).clamp(1, 128));
        let cell = ext / Vec3A::new(res[0] as f32, res[1] as f32, res[2] as f32);
        let half = cell * 0.5;
        let radius = half.length();
        let lists: Vec<Option<Vec<u32>>> = (0..res[0] * res[1] * res[2])
            .into_par_iter()
            .map(|idx| {
                let (i, j, k) = (
                    idx % res[0],
                    (idx / res[0]) % res[1],
                    idx / (res[0] * res[1]),
                );
                let c = lo + cell * Vec3A::new(i as f32 + 0.5, j as f32 + 0.5, k as f32 + 0.5);
                let m = self.upper_bound(c);
                // Slack for f32 rounding of the member values.
                let bound = m + lipschitz * radius + 1e-4 * (1.0 + m.abs());
                self.candidates(c, half, bound)
            })
            .collect();
        let mut cells = Vec::with_capacity(lists.len());
        let mut candidates = Vec::new();
        for list in lists {
            match list {
                Some(l) => {
                    cells.push((candidates.len() as u32, l.len() as u32));
                    candidates.extend(l);
                }
                None => cells.push((0, FALLBACK)),
            }
        }
        CellGrid {
            min: lo,
            inv_size: Vec3A::ONE / cell,
            res,
            cells,
            candidates,
        }
    }

    /// An upper bound on the union's minimum at `p`: a branch-and-bound
    /// search, nearer children first, that stops after
    /// [`UPPER_BOUND_VISITS`] nodes. In ordinary scenes it finishes and the
    /// bound is the exact minimum (the tightest candidate lists); where
    /// members overlap so that nothing prunes (coincident primitives) it
    /// stops early, so a cell costs O(log n) whatever the input. Any upper
    /// bound keeps the candidate lists exact: a looser one only lengthens
    /// them.
    pub(super) fn upper_bound(&self, p: Vec3A) -> f32 {
        self.search_within::<true>(p, f32::INFINITY, |m, best| {
            best.min(self.members[m].dist(p))
        })
    }

    /// Members that may be below `bound` somewhere in the cell: those whose
    /// box overlaps it or lies within `bound` of it. `None` past the limit,
    /// or when the search visits too many nodes (the BVH is then used for
    /// the cell, which is exact too): each cell costs O(log n) at most.
    pub(super) fn candidates(&self, c: Vec3A, h: Vec3A, bound: f32) -> Option<Vec<u32>> {
        let mut out = Vec::new();
        let mut stack = vec![0usize];
        let mut visited = 0;
        while let Some(n) = stack.pop() {
            visited += 1;
            if visited > MAX_CANDIDATE_VISITS {
                return None;
            }
            let node = self.nodes[n];
            let gap = box_gap(c, h, node.center, node.half);
            if gap > 0.0 && gap > bound {
                continue;
            }
            if node.count == 0 {
                stack.push(node.first as usize);
                stack.push(node.first as usize + 1);
                continue;
            }
            for m in node.first..node.first + node.count {
                let (bc, bh) = self.boxes[m as usize];
                let gap = box_gap(c, h, bc, bh);
                if gap == 0.0 || gap <= bound {
                    out.push(m);
                    if out.len() > MAX_CANDIDATES {
                        return None;
                    }
                }
            }
        }
        Some(out)
    }

    #[inline(always)]
    pub(super) fn lower_bound(&self, n: usize, p: Vec3A) -> f32 {
        box_sd(p - self.nodes[n].center, self.nodes[n].half)
    }

    /// Branch-and-bound minimum; `visit` evaluates a member, returning its
    /// distance, and may record more (the id).
    #[inline(always)]
    pub(super) fn search(&self, p: Vec3A, best: f32, visit: impl FnMut(usize, f32) -> f32) -> f32 {
        self.search_within::<false>(p, best, visit)
    }

    /// [`Self::search`], stopping after [`UPPER_BOUND_VISITS`] nodes when
    /// `CAPPED` (the result is then an upper bound on the minimum).
    #[inline(always)]
    fn search_within<const CAPPED: bool>(
        &self,
        p: Vec3A,
        mut best: f32,
        mut visit: impl FnMut(usize, f32) -> f32,
    ) -> f32 {
        let mut stack = [0u32; STACK];
        let mut top = 0;
        let mut visits = 0;
        if self.lower_bound(0, p) < best {
            stack[0] = 0;
            top = 1;
        }
        while top > 0 {
            if CAPPED {
                visits += 1;
                if visits > UPPER_BOUND_VISITS {
                    break;
                }
            }
            top -= 1;
            let node = self.nodes[stack[top] as usize];
            if node.count > 0 {
                for m in node.first..node.first + node.count {
                    let (bc, bh) = self.boxes[m as usize];
                    if box_sd(p - bc, bh) < best {
                        best = visit(m as usize, best);
                    }
                }
                continue;
            }
            let (l, r) = (node.first as usize, node.first as usize + 1);
            let (dl, dr) = (self.lower_bound(l, p), self.lower_bound(r, p));
            // Visit the nearer child first: push it last.
            let (near, dn, far, df) = if dl <= dr {
                (l, dl, r, dr)
            } else {
                (r, dr, l, dl)
            };
            if df < best && top < STACK {
                stack[top] = far as u32;
                top += 1;
            }
            if dn < best && top < STACK {
                stack[top] = near as u32;
                top += 1;
            }
        }
        best
    }
}

/// A box as (centre, half extents) in f32, padded by a relative epsilon so
/// rounding never makes the box distance exceed a member's distance.
pub(super) fn padded(b: Aabb) -> (Vec3A, Vec3A) {
    let pad = 1e-5
        * (b.max - b.min)
            .max_element()
            .max(b.center().abs().max_element())
            .max(1.0);
    let b = b.expand(pad);
    (
        b.center().as_vec3().into(),
        ((b.max - b.min) * 0.5).as_vec3().into(),
    )
}

impl Node for BvhUnion {
    fn dist(&self, p: Vec3A) -> f32 {
        let best = self
            .unbounded
            .iter()
            .fold(f32::INFINITY, |m, c| m.min(c.dist(p)));
        if let Some(list) = self.grid.as_ref().and_then(|g| g.lookup(p)) {
            if let Some(table) = &self.table {
                return table.min_over(p, list, best);
            }
            return list
                .iter()
                .fold(best, |m, i| m.min(self.members[*i as usize].dist(p)));
        }
        self.search(p, best, |m, best| best.min(self.members[m].dist(p)))
    }
    fn dist_packs(&self, p: &[P8], out: &mut [F8]) {
        match &self.table {
            Some(table) if self.members.len() <= PACKED_MEMBERS => {
                table.min_packs(p, out);
                for u in &self.unbounded {
                    combine_packs(u.as_ref(), p, out, |m, d| m.min(d));
                }
            }
            _ => {
                for (q, o) in p.iter().zip(out.iter_mut()) {
                    *o = per_lane(q, |x| self.dist(x));
                }
            }
        }
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        let mut best = (f32::INFINITY, u32::MAX);
        for c in &self.unbounded {
            let d = c.dist_id(p);
            if d.0 < best.0 {
                best = d;
            }
        }
        if let Some(list) = self.grid.as_ref().and_then(|g| g.lookup(p)) {
            for i in list {
                let d = self.members[*i as usize].dist_id(p);
                if d.0 < best.0 {
                    best = d;
                }
            }
            return best;
        }
        let mut id = best.1;
        let d = self.search(p, best.0, |m, cur| {
            let (d, i) = self.members[m].dist_id(p);
            if d < cur {
                id = i;
                d
            } else {
                cur
            }
        });
        (d, id)
    }
}
