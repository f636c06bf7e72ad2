//! Triangle meshes of a distance field's zero level set (surface nets), PLY
//! files, surface samples, and exact distances to a mesh for geometric
//! error ([`nearest`]).
//!
//! Surface nets: the field is sampled on a grid one plane at a time (memory
//! grows with the square of the resolution, not its cube); every cell whose
//! corners change sign gets one vertex per separate piece of surface in it
//! (its crossed edges joined across the cell's faces, ambiguous faces
//! decided by the asymptotic decider) at the mean of the piece's edge
//! crossings, and every grid edge that changes sign becomes a quad joining
//! the pieces of the four cells around it, oriented so that its normal
//! points to positive values (outside). Vertices are then projected onto
//! the surface along the gradient (one Newton step, never farther than a
//! cell), which removes most of the grid's bias at little cost: the surface
//! has far fewer vertices than the grid has points. A field without holes
//! in the region gives a closed, consistently oriented 2-manifold mesh:
//! every edge in exactly two triangles, one fan of triangles around every
//! vertex (tested on thin tubes, blobs and a gyroid, and through the Euler
//! characteristic).

use std::collections::HashMap;
use std::io::{self, Write};
use std::path::Path;

use rayon::prelude::*;

use sdfl_stdlib::value::{MeshRegion, Output, OutputKind};

use crate::output::Atomic;
pub use crate::output::MeshStats;
use crate::output::{Written, WrittenKind};
use crate::volume::SplitMix64;

pub mod nearest;
pub use nearest::MeshDistance;

/// Extracts and writes the `mesh` output `o` of `field`. `auto` is the
/// region `bounds: "auto"` stands for (none for unbounded shapes, which
/// evaluation refuses).
pub fn write_mesh(
    out_dir: &Path,
    o: &Output,
    field: &dyn DistanceField,
    auto: Option<([f64; 3], [f64; 3])>,
) -> io::Result<(Written, Mesh)> {
    write_mesh_to(out_dir, o, field, auto, &glam::DAffine3::IDENTITY)
}

/// [`write_mesh`] of a field trained in a capture's scene frame: the mesh
/// (written and returned) is moved by `to_data` into the data's own frame,
/// as the other exports are.
pub fn write_mesh_to(
    out_dir: &Path,
    o: &Output,
    field: &dyn DistanceField,
    auto: Option<([f64; 3], [f64; 3])>,
    to_data: &glam::DAffine3,
) -> io::Result<(Written, Mesh)> {
    let t = std::time::Instant::now();
    let OutputKind::Mesh { resolution, region } = o.kind else {
        return Err(io::Error::other("not a mesh output"));
    };
    let (min, max) = match region {
        MeshRegion::Box { min, max } => (min, max),
        MeshRegion::Auto => auto.ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "`{}`: the shape is unbounded; give the mesh `bounds`",
                    o.path.display()
                ),
            )
        })?,
    };
    let grid = MeshGrid::covering(min, max, resolution);
    // Grid points must stay apart in f32 (a small region far out).
    let far_out = (0..3)
        .map(|a| min[a].abs().max(max[a].abs()))
        .fold(0.0, f64::max);
    if grid.step < 8.0 * far_out * f32::EPSILON as f64 {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "`{}`: cells of {:.1e} this far from the origin ({:.1e}) are below f32 precision: lower `resolution` or move the region",
                o.path.display(),
                grid.step,
                far_out
            ),
        ));
    }
    let max = sdfl_stdlib::work::MAX_MESH_VERTICES;
    let mut mesh = match surface_nets(field, &grid, max, &|_| {}) {
        // A field steeper than its assumed bound (a network) is sampled
        // again at every grid point.
        Err(MeshError::BoundBroken) => surface_nets(&Dense(field), &grid, max, &|_| {}),
        r => r,
    }
    .map_err(|e| io::Error::other(format!("`{}`: {e}", o.path.display())))?;
    mesh.transform(to_data);
    mesh.write_ply(&out_dir.join(&o.path))?;
    let stats = MeshStats {
        vertices: mesh.vertices.len(),
        triangles: mesh.triangles.len(),
        resolution,
        // In the file's units, as the area.
        cell: grid.step * to_data.matrix3.determinant().abs().cbrt(),
        area: mesh.area(),
        seconds: t.elapsed().as_secs_f64(),
    };
    let written = Written {
        path: o.path.clone(),
        kind: WrittenKind::Mesh,
        width: 0,
        height: 0,
        frames: 0,
        mesh: Some(stats),
        warning: None,
    };
    Ok((written, mesh))
}

/// A signed distance field evaluated in batches.
pub trait DistanceField: Sync {
    /// Distances at `points` into `out` (same length).
    fn distances(&self, points: &[[f32; 3]], out: &mut [f32]);

    /// Distances and gradients at `points`. By default central differences
    /// with step `h`; fields with an exact gradient override it.
    fn gradients(&self, points: &[[f32; 3]], h: f32, f: &mut [f32], g: &mut [[f32; 3]]) {
        self.distances(points, f);
        let mut probe = Vec::with_capacity(points.len() * 6);
        for p in points {
            for axis in 0..3 {
                for s in [h, -h] {
                    let mut q = *p;
                    q[axis] += s;
                    probe.push(q);
                }
            }
        }
        let mut d = vec![0.0; probe.len()];
        self.distances(&probe, &mut d);
        for (gi, d) in g.iter_mut().zip(d.chunks(6)) {
            for axis in 0..3 {
                gi[axis] = (d[2 * axis] - d[2 * axis + 1]) / (2.0 * h);
            }
        }
    }

    /// A bound on `‖∇f‖`, if the field has one (see [`Lipschitz`]).
    fn lipschitz(&self) -> Option<f32> {
        None
    }
}

impl<F: Fn(&[[f32; 3]], &mut [f32]) + Sync> DistanceField for F {
    fn distances(&self, points: &[[f32; 3]], out: &mut [f32]) {
        self(points, out)
    }
}

/// A field with a bound on its gradient's norm: grid points far from the
/// surface are then not evaluated, their sign following from an earlier
/// value (a distance of `d` one plane back is at least `d − L·step` here).
pub struct Lipschitz<F>(pub F, pub f32);

impl<F: DistanceField> DistanceField for Lipschitz<F> {
    fn distances(&self, points: &[[f32; 3]], out: &mut [f32]) {
        self.0.distances(points, out)
    }
    fn gradients(&self, points: &[[f32; 3]], h: f32, f: &mut [f32], g: &mut [[f32; 3]]) {
        self.0.gradients(points, h, f, g)
    }
    fn lipschitz(&self) -> Option<f32> {
        Some(self.1)
    }
}

/// A triangle mesh with one normal per vertex.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub vertices: Vec<[f32; 3]>,
    /// Unit normal per vertex.
    pub normals: Vec<[f32; 3]>,
    /// Counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

/// The sampling grid: `points` grid points per axis from `min`, `step` apart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshGrid {
    /// The grid's low corner.
    pub min: [f64; 3],
    /// Distance between grid points.
    pub step: f64,
    /// Grid points along x, y and z.
    pub points: [usize; 3],
}

impl MeshGrid {
    /// A grid over `[min, max]` with `resolution` cells along its longest
    /// side, padded by two cells on every side so that a surface inside the
    /// box closes.
    pub fn covering(min: [f64; 3], max: [f64; 3], resolution: u32) -> MeshGrid {
        let extent = (0..3).map(|a| max[a] - min[a]).fold(0.0, f64::max);
        let step = (extent / resolution.max(1) as f64).max(f64::MIN_POSITIVE);
        let pad = 2.0 * step;
        let points =
            std::array::from_fn(|a| (((max[a] - min[a]) / step).ceil().max(0.0) as usize) + 1 + 4);
        MeshGrid {
            min: std::array::from_fn(|a| min[a] - pad),
            step,
            points,
        }
    }

    /// Field evaluations the grid needs.
    pub fn evaluations(&self) -> u64 {
        self.points.iter().map(|&n| n as u64).product()
    }

    fn point(&self, i: usize, j: usize, k: usize) -> [f32; 3] {
        [
            (self.min[0] + i as f64 * self.step) as f32,
            (self.min[1] + j as f64 * self.step) as f32,
            (self.min[2] + k as f64 * self.step) as f32,
        ]
    }
}

const NO_VERTEX: u32 = u32::MAX;

/// Most planes a grid point is skipped for on the strength of a Lipschitz
/// bound before it is evaluated again (and the bound checked).
const RECHECK_PLANES: usize = 8;

/// The 12 edges of a cell as pairs of corner numbers (corner `c` is at
/// offset `(c & 1, c >> 1 & 1, c >> 2 & 1)`).
const CELL_EDGES: [(usize, usize); 12] = [
    (0, 1),
    (2, 3),
    (4, 5),
    (6, 7),
    (0, 2),
    (1, 3),
    (4, 6),
    (5, 7),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
];

/// The corners `[c00, c10, c01, c11]` of each cell face (ordered by the two
/// axes in the face, so both cells sharing it see the same order) and its
/// edges `[c00–c10, c10–c11, c01–c11, c00–c01]` as [`CELL_EDGES`] numbers.
const CELL_FACES: [([usize; 4], [usize; 4]); 6] = {
    let mut faces = [([0; 4], [0; 4]); 6];
    let mut f = 0;
    while f < 6 {
        let (axis, side) = (f / 2, f % 2);
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let (u, v) = if u < v { (u, v) } else { (v, u) };
        let at = side << axis;
        let c = [at, at | 1 << u, at | 1 << v, at | 1 << u | 1 << v];
        let pairs = [(c[0], c[1]), (c[1], c[3]), (c[2], c[3]), (c[0], c[2])];
        let mut k = 0;
        while k < 4 {
            let mut e = 0;
            while CELL_EDGES[e].0 != pairs[k].0 || CELL_EDGES[e].1 != pairs[k].1 {
                e += 1;
            }
            faces[f].1[k] = e;
            k += 1;
        }
        faces[f].0 = c;
        f += 1;
    }
    faces
};

/// The separate pieces of surface in one cell: crossed edges joined where
/// the surface runs from one to the other across a cell face. A cell where
/// two pieces meet at a single vertex would make the mesh non-manifold
/// there (two surfaces touching at a point or along an edge); each piece
/// gets its own vertex instead, as in manifold dual contouring.
struct CellPieces {
    /// How many pieces (0 to 4).
    count: u8,
    /// Two bits per cell edge: the piece that crosses it.
    packed: u32,
    crossed: u16,
    /// Per face with all four edges crossed: whether the corners kept apart
    /// are inside, and whether one piece crosses the face twice.
    ambiguous: [Option<(bool, bool)>; 6],
}

impl CellPieces {
    /// The pieces of a cell with corner values `corner`.
    fn of(corner: &[f32; 8]) -> CellPieces {
        let inside = |v: f32| v < 0.0;
        let mut crossed = 0u16;
        for (e, &(a, b)) in CELL_EDGES.iter().enumerate() {
            if inside(corner[a]) != inside(corner[b]) {
                crossed |= 1 << e;
            }
        }
        if crossed == 0 {
            return CellPieces {
                count: 0,
                packed: 0,
                crossed,
                ambiguous: [None; 6],
            };
        }
        let mut parent: [u8; 12] = std::array::from_fn(|e| e as u8);
        fn root(parent: &mut [u8; 12], mut e: u8) -> u8 {
            while parent[e as usize] != e {
                e = parent[e as usize];
            }
            e
        }
        let mut join = |a: usize, b: usize| {
            let (ra, rb) = (root(&mut parent, a as u8), root(&mut parent, b as u8));
            parent[ra as usize] = rb;
        };
        let mut ambiguous = [None; 6];
        for (f, (c, e)) in CELL_FACES.into_iter().enumerate() {
            let on = e.map(|e| crossed >> e & 1 == 1);
            match on.iter().filter(|&&x| x).count() {
                2 => {
                    let mut it = (0..4).filter(|&k| on[k]);
                    let (a, b) = (it.next().unwrap(), it.next().unwrap());
                    join(e[a], e[b]);
                }
                4 => {
                    // Diagonal corners alike: the bilinear interpolant's
                    // saddle decides which pair the surface keeps apart
                    // (the asymptotic decider). It depends on the face
                    // alone, so both cells sharing it agree.
                    let v = c.map(|c| corner[c]);
                    let [a, b, cc, d] = v.map(|x| x as f64);
                    let saddle = (a * d - b * cc) / (a + d - b - cc);
                    let joins_00_11 = inside(saddle as f32) == inside(v[0]);
                    if joins_00_11 {
                        // The surface cuts off c10 and c01.
                        join(e[0], e[1]);
                        join(e[2], e[3]);
                    } else {
                        join(e[0], e[3]);
                        join(e[1], e[2]);
                    }
                    ambiguous[f] = Some(inside(v[if joins_00_11 { 1 } else { 0 }]));
                }
                _ => {}
            }
        }
        // Edges 0 and 2 of a face lie in its two different strips.
        let ambiguous = std::array::from_fn(|f| {
            let e = CELL_FACES[f].1;
            ambiguous[f].map(|cut_inside: bool| {
                let twice = root(&mut parent, e[0] as u8) == root(&mut parent, e[2] as u8);
                (cut_inside, twice)
            })
        });
        let (mut count, mut packed) = (0u8, 0u32);
        let mut label = [u8::MAX; 12];
        for e in 0..12 {
            if crossed >> e & 1 == 0 {
                continue;
            }
            let r = root(&mut parent, e as u8) as usize;
            if label[r] == u8::MAX {
                label[r] = count;
                count += 1;
            }
            packed |= (label[r] as u32) << (2 * e);
        }
        CellPieces {
            count,
            packed,
            crossed,
            ambiguous,
        }
    }

    /// The piece crossing cell edge `e`, if it is crossed.
    fn piece(&self, e: usize) -> Option<usize> {
        (self.crossed >> e & 1 == 1).then_some((self.packed >> (2 * e) & 3) as usize)
    }
}

/// A cell's vertices: the first, and each crossed edge's piece.
#[derive(Clone, Copy)]
struct CellVertices {
    first: u32,
    pieces: u32,
}

impl CellVertices {
    const NONE: CellVertices = CellVertices {
        first: NO_VERTEX,
        pieces: 0,
    };

    /// The vertex of the piece crossing cell edge `e` (meaningless where
    /// the edge is not crossed: quads are only made of crossed edges).
    fn at(&self, e: usize) -> u32 {
        self.first.wrapping_add(self.pieces >> (2 * e) & 3)
    }
}

/// Why a mesh could not be made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshError {
    /// The surface crosses more cells than a mesh may have vertices.
    TooManyVertices(usize),
    /// A value changed faster than the field's Lipschitz bound allows, so
    /// points skipped on its strength may have the wrong sign.
    BoundBroken,
}

impl std::fmt::Display for MeshError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MeshError::TooManyVertices(n) => write!(
                f,
                "the surface crosses more than {n} grid cells (the most a mesh may have vertices): lower `resolution` or the region"
            ),
            MeshError::BoundBroken => write!(f, "the field is steeper than its Lipschitz bound"),
        }
    }
}

/// A field seen without its Lipschitz bound: every grid point evaluated.
#[doc(hidden)]
pub struct Dense<'a>(pub &'a dyn DistanceField);

impl DistanceField for Dense<'_> {
    fn distances(&self, points: &[[f32; 3]], out: &mut [f32]) {
        self.0.distances(points, out)
    }
    fn gradients(&self, points: &[[f32; 3]], h: f32, f: &mut [f32], g: &mut [[f32; 3]]) {
        self.0.gradients(points, h, f, g)
    }
}

/// The zero level set of `field` on `grid`, with at most `max_vertices`
/// vertices. `progress` is called with the number of grid planes done.
pub fn surface_nets(
    field: &dyn DistanceField,
    grid: &MeshGrid,
    max_vertices: usize,
    progress: &dyn Fn(u64),
) -> Result<Mesh, MeshError> {
    let [nx, ny, nz] = grid.points;
    let mut mesh = Mesh::default();
    if nx < 2 || ny < 2 || nz < 2 {
        return Ok(mesh);
    }
    let (cx, cy) = (nx - 1, ny - 1);
    // With a Lipschitz bound L, a point whose last value `v` (from plane
    // k0) still bounds |f| above 2·L·step here cannot be a corner of a
    // crossed edge: it keeps v's sign and the bound as its value, and is
    // evaluated again only once the bound runs out.
    let reach = field.lipschitz().map(|l| l * grid.step as f32);
    let mut known: Vec<(f32, usize)> = vec![(f32::NAN, 0); nx * ny];
    let mut broken = false;
    let mut plane = |k: usize| -> Vec<f32> {
        let mut out = vec![0.0; nx * ny];
        let mut todo = Vec::with_capacity(nx * ny);
        for (idx, o) in out.iter_mut().enumerate() {
            if let Some(reach) = reach {
                let (v, k0) = known[idx];
                let bound = v.abs() - (k - k0) as f32 * reach;
                // Seen again every few planes, so that a field steeper
                // than its bound is caught (and meshed densely instead).
                if v.is_finite() && bound > 2.0 * reach && k - k0 < RECHECK_PLANES {
                    *o = bound.copysign(v);
                    continue;
                }
            }
            todo.push(idx);
        }
        let pts: Vec<[f32; 3]> = todo
            .iter()
            .map(|&idx| grid.point(idx % nx, idx / nx, k))
            .collect();
        let mut values = vec![0.0; pts.len()];
        const CHUNK: usize = 4096;
        pts.par_chunks(CHUNK)
            .zip(values.par_chunks_mut(CHUNK))
            .for_each(|(p, o)| field.distances(p, o));
        for (&idx, &v) in todo.iter().zip(&values) {
            // Values seen again must keep to the bound that let them be
            // skipped in between (a little slack for rounding).
            if let Some(reach) = reach {
                let (old, k0) = known[idx];
                let allowed = (k - k0) as f32 * reach * 1.001 + 1e-6 * (1.0 + old.abs());
                if old.is_finite() && v.is_finite() && (v - old).abs() > allowed {
                    broken = true;
                }
            }
            out[idx] = v;
            known[idx] = (v, k);
        }
        out
    };
    let inside = |v: f32| v < 0.0;
    let mut below = plane(0);
    let mut prev = vec![CellVertices::NONE; cx * cy];
    let mut quads: Vec<[u32; 4]> = Vec::new();
    // Ambiguous faces crossed twice by one piece of a cell, by (lowest
    // corner, normal axis): which corners the face keeps apart, and how
    // many of its two cells do so. Where both do, the pieces meet along two
    // strips and `strips` holds the quads to separate.
    let mut twice: HashMap<(usize, u8), (bool, u8)> = HashMap::new();
    let mut strips: Vec<Strip> = Vec::new();
    let point = |p: [usize; 3]| p[0] + nx * (p[1] + ny * p[2]);
    for k in 0..nz - 1 {
        let above = plane(k + 1);
        let mut cur = vec![CellVertices::NONE; cx * cy];
        for j in 0..cy {
            for i in 0..cx {
                let at = |c: usize| {
                    let (di, dj) = (c & 1, (c >> 1) & 1);
                    let layer = if c >> 2 & 1 == 0 { &below } else { &above };
                    layer[(j + dj) * nx + i + di]
                };
                let corner: [f32; 8] = std::array::from_fn(at);
                let pieces = CellPieces::of(&corner);
                if pieces.count == 0 {
                    continue;
                }
                for (f, a) in pieces.ambiguous.iter().enumerate() {
                    if let Some((cut_inside, true)) = *a {
                        let (axis, side) = (f / 2, f % 2);
                        let mut o = [i, j, k];
                        o[axis] += side;
                        let key = (o[0] + nx * (o[1] + ny * o[2]), axis as u8);
                        twice.entry(key).or_insert((cut_inside, 0)).1 += 1;
                    }
                }
                let first = mesh.vertices.len();
                if first + pieces.count as usize > max_vertices.min(NO_VERTEX as usize) {
                    return Err(MeshError::TooManyVertices(max_vertices));
                }
                // One vertex per piece, at the mean of its edges' crossings.
                let mut sum = [[0.0f64; 3]; 4];
                let mut n = [0.0f64; 4];
                for (e, &(a, b)) in CELL_EDGES.iter().enumerate() {
                    let Some(piece) = pieces.piece(e) else {
                        continue;
                    };
                    let (fa, fb) = (corner[a], corner[b]);
                    let t = fa as f64 / (fa as f64 - fb as f64);
                    let t = if t.is_finite() {
                        t.clamp(0.0, 1.0)
                    } else {
                        0.5
                    };
                    for (axis, s) in sum[piece].iter_mut().enumerate() {
                        let (oa, ob) = ((a >> axis) & 1, (b >> axis) & 1);
                        *s += oa as f64 + (ob as f64 - oa as f64) * t;
                    }
                    n[piece] += 1.0;
                }
                let base = [i, j, k];
                for p in 0..pieces.count as usize {
                    mesh.vertices.push(std::array::from_fn(|a| {
                        (grid.min[a] + (base[a] as f64 + sum[p][a] / n[p]) * grid.step) as f32
                    }));
                }
                cur[j * cx + i] = CellVertices {
                    first: first as u32,
                    pieces: pieces.packed,
                };
            }
        }
        let below_at = |i: usize, j: usize| below[j * nx + i];
        // A quad `[v00, v10, v11, v01]` in the plane of the two other axes
        // (cyclic after the edge's axis) faces +axis; flip it when the
        // field grows towards -axis.
        // The quad of the grid edge from `at` one step along `axis`.
        let mut quad = |from: f32, to: f32, at: [usize; 3], axis: usize, q: [u32; 4]| {
            if inside(from) == inside(to) {
                return;
            }
            if !twice.is_empty() {
                let mut end = at;
                end[axis] += 1;
                let (i_end, o_end) = if inside(from) { (at, end) } else { (end, at) };
                // The four faces around the edge.
                for b in (0..3).filter(|&b| b != axis) {
                    for back in 0..=at[b].min(1) {
                        let mut corner = at;
                        corner[b] -= back;
                        let key = (point(corner), (3 - axis - b) as u8);
                        if twice.get(&key).is_some_and(|t| t.1 == 2) {
                            strips.push((quads.len(), key, point(i_end), point(o_end)));
                        }
                    }
                }
            }
            quads.push(if inside(from) {
                q
            } else {
                [q[3], q[2], q[1], q[0]]
            });
        };
        // Edges along z between planes k and k+1: the cells around them
        // are all in this layer. Each cell gives the vertex of its piece
        // of surface that crosses the edge (named by its cell-edge number).
        for j in 1..cy {
            for i in 1..cx {
                let c = |i: usize, j: usize, e: usize| cur[j * cx + i].at(e);
                quad(
                    below_at(i, j),
                    above[j * nx + i],
                    [i, j, k],
                    2,
                    [
                        c(i - 1, j - 1, 11),
                        c(i, j - 1, 10),
                        c(i, j, 8),
                        c(i - 1, j, 9),
                    ],
                );
            }
        }
        // Edges along x and y in plane k: the cells around them are in
        // this layer and the one before.
        if k > 0 {
            let (p, c) = (
                |i: usize, j: usize, e: usize| prev[j * cx + i].at(e),
                |i: usize, j: usize, e: usize| cur[j * cx + i].at(e),
            );
            for j in 1..cy {
                for i in 0..cx {
                    quad(
                        below_at(i, j),
                        below_at(i + 1, j),
                        [i, j, k],
                        0,
                        [p(i, j - 1, 3), p(i, j, 2), c(i, j, 0), c(i, j - 1, 1)],
                    );
                }
            }
            for j in 0..cy {
                for i in 1..cx {
                    quad(
                        below_at(i, j),
                        below_at(i, j + 1),
                        [i, j, k],
                        1,
                        [p(i - 1, j, 7), c(i - 1, j, 5), c(i, j, 4), p(i, j, 6)],
                    );
                }
            }
        }
        below = above;
        prev = cur;
        progress(k as u64 + 1);
    }
    if broken {
        return Err(MeshError::BoundBroken);
    }
    let polygons = separate_strips(&mut mesh, &quads, &strips, &twice, grid, max_vertices)?;
    refine(field, grid.step as f32, &mut mesh);
    let v = &mesh.vertices;
    let len2 = |a: u32, b: u32| {
        let (a, b) = (v[a as usize], v[b as usize]);
        (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f32>()
    };
    for (n, q) in quads.into_iter().enumerate() {
        if let Some((p, from)) = polygons.get(&n) {
            // A fan from the inserted vertex: its diagonals reach vertices
            // of this quad alone, so no edge is made twice.
            let at = p.iter().position(|x| x == from).expect("inserted vertex");
            for k in 1..p.len() - 1 {
                let (a, b) = ((at + k) % p.len(), (at + k + 1) % p.len());
                mesh.triangles.push([p[at], p[a], p[b]]);
            }
            continue;
        }
        // Split along the shorter diagonal: better-shaped triangles.
        if len2(q[0], q[2]) <= len2(q[1], q[3]) {
            mesh.triangles.push([q[0], q[1], q[2]]);
            mesh.triangles.push([q[0], q[2], q[3]]);
        } else {
            mesh.triangles.push([q[0], q[1], q[3]]);
            mesh.triangles.push([q[1], q[2], q[3]]);
        }
    }
    Ok(mesh)
}

/// A quad on a face crossed twice on both sides: (quad, face as (lowest
/// corner, normal axis), its grid edge's inside end, outside end).
type Strip = (usize, (usize, u8), usize, usize);

/// Where a face is crossed twice by one piece of each of its cells, the
/// two pieces' vertices X and Y would share an edge with four quads (the
/// surface meets itself along two strips across the face). Each strip gets
/// a vertex of its own between X and Y, in its two quads, which become
/// polygons. Returns them by quad, with the first inserted vertex. Beside
/// the grid's boundary a face may have only two or three of its quads
/// (the others' grid edges lie on the boundary, where no quad is made): a
/// strip with both its quads is separated the same way, and the lone quad
/// keeps the edge X–Y to itself, an open edge of the cut surface.
fn separate_strips(
    mesh: &mut Mesh,
    quads: &[[u32; 4]],
    strips: &[Strip],
    twice: &HashMap<(usize, u8), (bool, u8)>,
    grid: &MeshGrid,
    max_vertices: usize,
) -> Result<HashMap<usize, (Vec<u32>, u32)>, MeshError> {
    let [nx, ny, _] = grid.points;
    let mut polygons: HashMap<usize, (Vec<u32>, u32)> = HashMap::new();
    // A face's quads: (quad, inside end, outside end).
    type Ends = Vec<(usize, usize, usize)>;
    let mut by_face: HashMap<(usize, u8), Ends> = HashMap::new();
    for &(q, face, i_end, o_end) in strips {
        by_face.entry(face).or_default().push((q, i_end, o_end));
    }
    let mut faces: Vec<_> = by_face.into_iter().collect();
    // Deterministic vertex numbering.
    faces.sort_unstable_by_key(|f| f.0);
    for (face, four) in faces {
        let cut_inside = twice[&face].0;
        // X and Y: the vertices all of the face's quads share.
        let shared: Vec<u32> = quads[four[0].0]
            .iter()
            .copied()
            .filter(|v| four.iter().all(|&(q, ..)| quads[q].contains(v)))
            .collect();
        if !(2..=4).contains(&four.len()) || shared.len() != 2 {
            debug_assert!(
                four.len() < 2,
                "a face crossed twice on both sides has at most four quads, all through X and Y"
            );
            continue;
        }
        let (x, y) = (shared[0], shared[1]);
        // A strip cuts off one corner of the face: its two edges share
        // that corner, the end of the class kept apart.
        let corner =
            |&(_, i_end, o_end): &(usize, usize, usize)| if cut_inside { i_end } else { o_end };
        for a in 0..four.len() {
            for b in a + 1..four.len() {
                if corner(&four[a]) != corner(&four[b]) {
                    continue;
                }
                if mesh.vertices.len() >= max_vertices.min(NO_VERTEX as usize) {
                    return Err(MeshError::TooManyVertices(max_vertices));
                }
                let m = mesh.vertices.len() as u32;
                let (px, py) = (mesh.vertices[x as usize], mesh.vertices[y as usize]);
                // Between X and Y, a quarter of the way towards the corner
                // this strip cuts off: the face's two strips start apart.
                // At the same midpoint, refinement moved both to one point,
                // and a mesh welded by position had edges in four triangles.
                let c = corner(&four[a]);
                let ijk = [c % nx, c / nx % ny, c / (nx * ny)];
                mesh.vertices.push(std::array::from_fn(|k| {
                    let mid = 0.5 * (px[k] as f64 + py[k] as f64);
                    let at = grid.min[k] + ijk[k] as f64 * grid.step;
                    (mid + 0.25 * (at - mid)) as f32
                }));
                for q in [four[a].0, four[b].0] {
                    let entry = polygons.entry(q).or_insert_with(|| (quads[q].to_vec(), m));
                    let p = &mut entry.0;
                    let n = p.len();
                    if let Some(k) = (0..n).find(|&k| {
                        let (u, w) = (p[k], p[(k + 1) % n]);
                        (u == x && w == y) || (u == y && w == x)
                    }) {
                        p.insert(k + 1, m);
                    }
                }
            }
        }
    }
    Ok(polygons)
}

/// Moves each vertex onto the surface by one Newton step along the
/// gradient (at most one cell) and gives it the normalised gradient there.
fn refine(field: &dyn DistanceField, step: f32, mesh: &mut Mesh) {
    let n = mesh.vertices.len();
    let h = step * 0.05;
    let (mut f, mut g) = (vec![0.0; n], vec![[0.0; 3]; n]);
    let eval = |pts: &[[f32; 3]], f: &mut [f32], g: &mut [[f32; 3]]| {
        const CHUNK: usize = 2048;
        pts.par_chunks(CHUNK)
            .zip(f.par_chunks_mut(CHUNK).zip(g.par_chunks_mut(CHUNK)))
            .for_each(|(p, (f, g))| field.gradients(p, h, f, g));
    };
    eval(&mesh.vertices, &mut f, &mut g);
    for ((v, f), g) in mesh.vertices.iter_mut().zip(&f).zip(&g) {
        let len2 = g.iter().map(|x| x * x).sum::<f32>();
        if !(len2 > 1e-12 && f.is_finite()) {
            continue;
        }
        let moved: [f32; 3] = std::array::from_fn(|a| -f * g[a] / len2);
        let dist = moved.iter().map(|x| x * x).sum::<f32>().sqrt();
        if dist <= step && dist.is_finite() {
            for a in 0..3 {
                v[a] += moved[a];
            }
        }
    }
    eval(&mesh.vertices, &mut f, &mut g);
    mesh.normals = g
        .iter()
        .map(|g| {
            let len = g.iter().map(|x| x * x).sum::<f32>().sqrt();
            if len > 1e-12 && len.is_finite() {
                g.map(|x| x / len)
            } else {
                [0.0, 0.0, 0.0]
            }
        })
        .collect();
}

impl Mesh {
    /// Moves the vertices by `m` and the normals by the inverse transpose
    /// of `m`'s linear part (renormalised).
    pub fn transform(&mut self, m: &glam::DAffine3) {
        use glam::{DAffine3, DVec3};
        if *m == DAffine3::IDENTITY {
            return;
        }
        let normal_m = m.matrix3.inverse().transpose();
        for v in &mut self.vertices {
            *v = m
                .transform_point3(DVec3::from(v.map(f64::from)))
                .as_vec3()
                .to_array();
        }
        for n in &mut self.normals {
            let q = (normal_m * DVec3::from(n.map(f64::from))).normalize_or_zero();
            *n = q.as_vec3().to_array();
        }
    }

    /// Total surface area.
    pub fn area(&self) -> f64 {
        self.triangles.iter().map(|t| self.triangle_area(t)).sum()
    }

    fn triangle_area(&self, t: &[u32; 3]) -> f64 {
        let [a, b, c] = t.map(|i| self.vertices[i as usize].map(|x| x as f64));
        let (u, v) = (sub(b, a), sub(c, a));
        0.5 * len(cross(u, v))
    }

    /// V − E + F: 2 for a closed surface of genus 0, 0 for a torus.
    pub fn euler_characteristic(&self) -> i64 {
        let mut edges: Vec<(u32, u32)> = self
            .triangles
            .iter()
            .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
            .map(|(a, b)| (a.min(b), a.max(b)))
            .collect();
        edges.sort_unstable();
        edges.dedup();
        self.vertices.len() as i64 - edges.len() as i64 + self.triangles.len() as i64
    }

    /// `n` points uniformly distributed over the surface (by area),
    /// reproducibly from `seed`.
    pub fn sample_surface(&self, n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut cumulative = Vec::with_capacity(self.triangles.len());
        let mut total = 0.0;
        for t in &self.triangles {
            total += self.triangle_area(t);
            cumulative.push(total);
        }
        if self.triangles.is_empty() || total <= 0.0 {
            return Vec::new();
        }
        let mut rng = SplitMix64::new(seed ^ 0x6d65_7368);
        (0..n)
            .map(|_| {
                let target = rng.next_f64() * total;
                let k = cumulative
                    .partition_point(|&c| c < target)
                    .min(self.triangles.len() - 1);
                let [a, b, c] = self.triangles[k].map(|i| self.vertices[i as usize]);
                // Uniform barycentric coordinates by folding the unit square.
                let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                std::array::from_fn(|i| a[i] + u * (b[i] - a[i]) + v * (c[i] - a[i]))
            })
            .collect()
    }

    /// The PLY file: binary little-endian, positions, normals, triangles.
    pub fn ply_bytes(&self) -> Vec<u8> {
        assert_eq!(
            self.normals.len(),
            self.vertices.len(),
            "a normal per vertex"
        );
        let mut out = format!(
            "ply\nformat binary_little_endian 1.0\ncomment written by sdfl\n\
             element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
             property float nx\nproperty float ny\nproperty float nz\n\
             element face {}\nproperty list uchar int vertex_indices\nend_header\n",
            self.vertices.len(),
            self.triangles.len()
        )
        .into_bytes();
        out.reserve(self.vertices.len() * 24 + self.triangles.len() * 13);
        for (v, n) in self.vertices.iter().zip(&self.normals) {
            for x in v.iter().chain(n) {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        for t in &self.triangles {
            out.push(3);
            for i in t {
                out.extend_from_slice(&(*i as i32).to_le_bytes());
            }
        }
        out
    }

    /// Writes the PLY file atomically.
    pub fn write_ply(&self, path: &Path) -> io::Result<()> {
        let mut file = Atomic::create(path)?;
        file.writer()
            .write_all(&self.ply_bytes())
            .map_err(|e| crate::output::with_path(path, e))?;
        file.commit()
    }
}

/// `a − b`.
#[doc(hidden)]
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| a[i] - b[i])
}
/// `a × b`.
#[doc(hidden)]
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn len(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}
