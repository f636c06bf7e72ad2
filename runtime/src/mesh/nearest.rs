//! Exact distances from points to a triangle mesh, through a bounding
//! volume hierarchy over its triangles. A Chamfer distance's mesh side is
//! measured to the triangles themselves: standing the surface in by
//! samples would add their mean gap to every distance, and a query far
//! from a densely sampled surface visits thousands of samples where the
//! hierarchy visits a few boxes.

use rayon::prelude::*;

use super::Mesh;

/// Most triangles in a leaf.
const LEAF: usize = 4;

/// A box of the hierarchy: a leaf holds `count` triangles from `first`;
/// an inner node (`count` 0) has its children at `first` and `first + 1`.
#[derive(Debug, Clone, Copy)]
struct Node {
    lo: [f32; 3],
    hi: [f32; 3],
    first: u32,
    count: u32,
}

/// A mesh's triangles, ready for nearest-point queries.
#[derive(Debug, Clone)]
pub struct MeshDistance {
    nodes: Vec<Node>,
    /// The triangles' corners, in the hierarchy's order.
    triangles: Vec<[[f32; 3]; 3]>,
}

impl MeshDistance {
    /// The hierarchy of `mesh`'s triangles; `None` for a mesh without any.
    pub fn new(mesh: &Mesh) -> Option<MeshDistance> {
        let mut triangles: Vec<[[f32; 3]; 3]> = mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| mesh.vertices[i as usize]))
            .collect();
        if triangles.is_empty() {
            return None;
        }
        let mut nodes = Vec::with_capacity(2 * triangles.len().div_ceil(LEAF));
        nodes.push(Node {
            lo: [0.0; 3],
            hi: [0.0; 3],
            first: 0,
            count: 0,
        });
        build(&mut nodes, 0, &mut triangles, 0);
        Some(MeshDistance { nodes, triangles })
    }

    /// The distance from `p` to the nearest point of the mesh.
    pub fn distance(&self, p: [f32; 3]) -> f64 {
        self.distance_with(p, &mut Vec::with_capacity(64), &mut 0)
    }

    /// [`MeshDistance::distance`] with a reused stack, starting from the
    /// distance to triangle `nearest` (a guess: a query close by had it as
    /// its nearest), which prunes the search from the first box; `nearest`
    /// is then set to this query's nearest triangle.
    fn distance_with(&self, p: [f32; 3], stack: &mut Vec<u32>, nearest: &mut usize) -> f64 {
        let p = p.map(f64::from);
        let mut best = triangle_distance2(p, &self.triangles[*nearest]);
        stack.clear();
        stack.push(0);
        while let Some(k) = stack.pop() {
            let node = &self.nodes[k as usize];
            if box_distance2(node, p) >= best {
                continue;
            }
            let first = node.first as usize;
            if node.count > 0 {
                for (i, t) in self.triangles[first..first + node.count as usize]
                    .iter()
                    .enumerate()
                {
                    let d = triangle_distance2(p, t);
                    if d < best {
                        best = d;
                        *nearest = first + i;
                    }
                }
                continue;
            }
            // The nearer child is searched first, so the farther one is
            // usually pruned by then.
            let (a, b) = (first as u32, first as u32 + 1);
            let da = box_distance2(&self.nodes[a as usize], p);
            let db = box_distance2(&self.nodes[b as usize], p);
            let (near, far, dn, df) = if da <= db {
                (a, b, da, db)
            } else {
                (b, a, db, da)
            };
            if df < best {
                stack.push(far);
            }
            if dn < best {
                stack.push(near);
            }
        }
        best.sqrt()
    }

    /// The mean distance from `points` to the mesh (0 for no points).
    /// Queries run in Morton order, so each starts from its neighbour's
    /// nearest triangle; sums of fixed chunks of that order are added in
    /// order, the same at any thread count.
    pub fn mean_distance(&self, points: &[[f32; 3]]) -> f64 {
        let sorted = morton_order(points);
        let sums: Vec<f64> = sorted
            .par_chunks(4096)
            .map(|c| {
                let (mut stack, mut nearest) = (Vec::with_capacity(64), 0);
                c.iter()
                    .map(|p| self.distance_with(*p, &mut stack, &mut nearest))
                    .sum()
            })
            .collect();
        sums.iter().sum::<f64>() / points.len().max(1) as f64
    }
}

/// `points` sorted along a Morton (Z-order) curve over their box, so that
/// neighbours in the list are neighbours in space.
fn morton_order(points: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in points.iter().filter(|p| p.iter().all(|v| v.is_finite())) {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    // 21 bits an axis; a non-finite coordinate goes to cell 0.
    let cell = |v: f32, a: usize| -> u64 {
        let t = ((v - lo[a]) / (hi[a] - lo[a]).max(f32::MIN_POSITIVE)).clamp(0.0, 1.0);
        let t = if t.is_finite() { t } else { 0.0 };
        (t as f64 * ((1u64 << 21) - 1) as f64) as u64
    };
    let spread = |mut x: u64| {
        // Three zero bits between consecutive bits of a 21-bit number.
        x &= 0x1f_ffff;
        x = (x | x << 32) & 0x1f_0000_0000_ffff;
        x = (x | x << 16) & 0x1f_0000_ff00_00ff;
        x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
        x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
        x = (x | x << 2) & 0x1249_2492_4924_9249;
        x
    };
    let mut keyed: Vec<(u64, [f32; 3])> = points
        .iter()
        .map(|p| {
            let k = spread(cell(p[0], 0)) | spread(cell(p[1], 1)) << 1 | spread(cell(p[2], 2)) << 2;
            (k, *p)
        })
        .collect();
    keyed.sort_by_key(|(k, _)| *k);
    keyed.into_iter().map(|(_, p)| p).collect()
}

/// Fills node `k` with `triangles` (which start at index `offset` of the
/// whole list), splitting at the median centroid along the longest axis
/// of the centroids' box until at most [`LEAF`] remain. Depth is about
/// log2 of the triangle count, so recursion is shallow.
fn build(nodes: &mut Vec<Node>, k: usize, triangles: &mut [[[f32; 3]; 3]], offset: usize) {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    let (mut clo, mut chi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for t in triangles.iter() {
        for a in 0..3 {
            for v in t {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
            let c = centroid(t, a);
            clo[a] = clo[a].min(c);
            chi[a] = chi[a].max(c);
        }
    }
    nodes[k].lo = lo;
    nodes[k].hi = hi;
    if triangles.len() <= LEAF {
        nodes[k].first = offset as u32;
        nodes[k].count = triangles.len() as u32;
        return;
    }
    let axis = (0..3)
        .max_by(|&a, &b| (chi[a] - clo[a]).total_cmp(&(chi[b] - clo[b])))
        .unwrap_or(0);
    let mid = triangles.len() / 2;
    triangles.select_nth_unstable_by(mid, |s, t| centroid(s, axis).total_cmp(&centroid(t, axis)));
    let children = nodes.len();
    let empty = Node {
        lo: [0.0; 3],
        hi: [0.0; 3],
        first: 0,
        count: 0,
    };
    nodes.extend([empty, empty]);
    nodes[k].first = children as u32;
    nodes[k].count = 0;
    let (left, right) = triangles.split_at_mut(mid);
    build(nodes, children, left, offset);
    build(nodes, children + 1, right, offset + mid);
}

fn centroid(t: &[[f32; 3]; 3], axis: usize) -> f32 {
    (t[0][axis] + t[1][axis] + t[2][axis]) / 3.0
}

/// The squared distance from `p` to the box of `node` (0 inside).
fn box_distance2(node: &Node, p: [f64; 3]) -> f64 {
    (0..3)
        .map(|a| {
            let d = (node.lo[a] as f64 - p[a])
                .max(p[a] - node.hi[a] as f64)
                .max(0.0);
            d * d
        })
        .sum()
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `‖a − b‖²`.
#[doc(hidden)]
pub fn distance2(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = sub(a, b);
    dot(d, d)
}

/// The squared distance from `p` to the segment `ab`.
#[doc(hidden)]
pub fn segment_distance2(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> f64 {
    let ab = sub(b, a);
    let len2 = dot(ab, ab);
    let t = if len2 > 0.0 {
        (dot(sub(p, a), ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    distance2(p, [a[0] + t * ab[0], a[1] + t * ab[1], a[2] + t * ab[2]])
}

/// The squared distance from `p` to the triangle `t`: the nearest point
/// found by which of the triangle's Voronoi regions (corner, edge or face)
/// holds `p`, in f64. A degenerate triangle (a segment or a point) is
/// measured by its edges.
#[doc(hidden)]
pub fn triangle_distance2(p: [f64; 3], t: &[[f32; 3]; 3]) -> f64 {
    let [a, b, c] = t.map(|v| v.map(f64::from));
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return distance2(p, a);
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return distance2(p, b);
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return distance2(p, c);
    }
    let vc = d1 * d4 - d3 * d2;
    let vb = d5 * d2 - d1 * d6;
    let va = d3 * d6 - d5 * d4;
    let sum = va + vb + vc;
    // A degenerate triangle has no face region: its edges are all of it.
    if sum <= 0.0 || !sum.is_finite() {
        return segment_distance2(p, a, b)
            .min(segment_distance2(p, b, c))
            .min(segment_distance2(p, c, a));
    }
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return segment_distance2(p, a, b);
    }
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return segment_distance2(p, a, c);
    }
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return segment_distance2(p, b, c);
    }
    let (v, w) = (vb / sum, vc / sum);
    let q = [0, 1, 2].map(|i| a[i] + ab[i] * v + ac[i] * w);
    distance2(p, q)
}
