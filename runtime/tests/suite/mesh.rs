//! Meshes from distance fields: Lipschitz culling, closed two-manifold
//! surfaces on the level set, genus, vertex limits, hostile fields, PLY.

mod nearest;

use sdfl_runtime::mesh::*;
use sdfl_runtime::volume::SplitMix64;

fn sphere(r: f32, c: [f32; 3]) -> impl Fn(&[[f32; 3]], &mut [f32]) + Sync {
    move |p: &[[f32; 3]], out: &mut [f32]| {
        for (p, o) in p.iter().zip(out) {
            let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
            *o = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - r;
        }
    }
}

fn torus(major: f32, minor: f32) -> impl Fn(&[[f32; 3]], &mut [f32]) + Sync {
    move |p: &[[f32; 3]], out: &mut [f32]| {
        for (p, o) in p.iter().zip(out) {
            let q = (p[0] * p[0] + p[1] * p[1]).sqrt() - major;
            *o = (q * q + p[2] * p[2]).sqrt() - minor;
        }
    }
}

fn mesh_of(f: &dyn DistanceField, min: f64, max: f64, res: u32) -> Mesh {
    surface_nets(
        f,
        &MeshGrid::covering([min; 3], [max; 3], res),
        usize::MAX,
        &|_| {},
    )
    .unwrap()
}

/// With a Lipschitz bound, points far from the surface are skipped and
/// the mesh is the same, bit for bit.
#[test]
fn a_lipschitz_bound_skips_far_points_and_changes_nothing() {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let count = AtomicUsize::new(0);
    let f = torus(0.7, 0.25);
    let counted = |p: &[[f32; 3]], o: &mut [f32]| {
        count.fetch_add(p.len(), Ordering::Relaxed);
        f(p, o)
    };
    let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], 64);
    let dense = surface_nets(&counted, &grid, usize::MAX, &|_| {}).unwrap();
    let all = count.swap(0, Ordering::Relaxed);
    let sparse = surface_nets(&Lipschitz(&counted, 1.0), &grid, usize::MAX, &|_| {}).unwrap();
    let some = count.load(Ordering::Relaxed);
    assert_eq!(dense, sparse);
    assert!(some * 2 < all, "{some} of {all} evaluations");
}

/// A field steeper than its claimed bound is caught where a skipped
/// point is seen again, and meshing it densely gives the right mesh.
#[test]
fn a_broken_bound_is_caught() {
    let f = sphere(0.5, [0.0; 3]);
    // Distances times 4, claimed 1-Lipschitz.
    let steep = |p: &[[f32; 3]], o: &mut [f32]| {
        f(p, o);
        o.iter_mut().for_each(|v| *v *= 4.0);
    };
    let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], 32);
    let r = surface_nets(&Lipschitz(&steep, 1.0), &grid, usize::MAX, &|_| {});
    assert_eq!(r, Err(MeshError::BoundBroken));
    let dense = surface_nets(&Dense(&Lipschitz(&steep, 1.0)), &grid, usize::MAX, &|_| {}).unwrap();
    assert_eq!(dense.euler_characteristic(), 2);
}

#[test]
fn too_many_vertices_is_an_error() {
    let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], 16);
    let r = surface_nets(&sphere(0.5, [0.0; 3]), &grid, 100, &|_| {});
    assert_eq!(r, Err(MeshError::TooManyVertices(100)));
}

#[test]
fn a_sphere_is_closed_outward_and_on_its_surface() {
    let (r, c) = (0.8f32, [0.1f32, -0.2, 0.3]);
    let f = sphere(r, c);
    let m = mesh_of(&f, -1.0, 1.2, 32);
    assert!(m.triangles.len() > 1000);
    assert_eq!(m.euler_characteristic(), 2, "closed, genus 0");
    // Every edge is shared by exactly two triangles, in opposite
    // directions (consistent orientation).
    let mut directed: Vec<(u32, u32)> = m
        .triangles
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .collect();
    directed.sort_unstable();
    let n = directed.len();
    directed.dedup();
    assert_eq!(directed.len(), n, "no directed edge twice");
    for &(a, b) in &directed {
        assert!(
            directed.binary_search(&(b, a)).is_ok(),
            "edge {a}-{b} unmatched"
        );
    }
    for (v, nrm) in m.vertices.iter().zip(&m.normals) {
        let d = [v[0] - c[0], v[1] - c[1], v[2] - c[2]];
        let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        assert!((dist - r).abs() < 1e-4, "vertex {dist} off the sphere");
        let along = (0..3).map(|k| nrm[k] * d[k] / dist).sum::<f32>();
        assert!(along > 0.999, "normal not radial: {along}");
    }
    // Triangles face outwards.
    for t in &m.triangles {
        let [a, b, cc] = t.map(|i| m.vertices[i as usize].map(|x| x as f64));
        let n = cross(sub(b, a), sub(cc, a));
        let mid: [f64; 3] = std::array::from_fn(|k| (a[k] + b[k] + cc[k]) / 3.0 - c[k] as f64);
        assert!((0..3).map(|k| n[k] * mid[k]).sum::<f64>() > 0.0);
    }
    let area = m.area();
    let exact = 4.0 * std::f64::consts::PI * (r as f64).powi(2);
    assert!((area / exact - 1.0).abs() < 0.02, "area {area} vs {exact}");
}

#[test]
fn a_torus_has_genus_one_and_samples_lie_on_it() {
    let f = torus(0.7, 0.25);
    let m = mesh_of(&f, -1.0, 1.0, 40);
    assert_eq!(m.euler_characteristic(), 0);
    let pts = m.sample_surface(2000, 7);
    assert_eq!(pts.len(), 2000);
    let mut d = vec![0.0; pts.len()];
    f(&pts, &mut d);
    // Samples lie on flat triangles between vertices on the surface:
    // off by at most the sagitta of a cell-sized chord.
    let worst = d.iter().fold(0.0f32, |m, x| m.max(x.abs()));
    assert!(worst < 0.01, "sample {worst} off the torus");
    assert_eq!(pts, m.sample_surface(2000, 7), "reproducible");
}

#[test]
fn empty_full_and_hostile_fields_give_finite_meshes() {
    let empty = |_: &[[f32; 3]], o: &mut [f32]| o.fill(1.0);
    assert!(mesh_of(&empty, -1.0, 1.0, 8).triangles.is_empty());
    let full = |_: &[[f32; 3]], o: &mut [f32]| o.fill(-1.0);
    assert!(mesh_of(&full, -1.0, 1.0, 8).triangles.is_empty());
    // NaN and infinite values count as outside and never make NaN
    // vertices.
    let wild = |p: &[[f32; 3]], o: &mut [f32]| {
        for (p, o) in p.iter().zip(o) {
            *o = if p[0] > 0.3 {
                f32::NAN
            } else if p[1] > 0.3 {
                f32::INFINITY
            } else {
                p[2] * 1e30
            };
        }
    };
    let m = mesh_of(&wild, -1.0, 1.0, 8);
    assert!(!m.triangles.is_empty());
    assert!(m.vertices.iter().flatten().all(|x| x.is_finite()));
    assert!(m.normals.iter().flatten().all(|x| x.is_finite()));
    // A plane exactly through grid points.
    let plane = |p: &[[f32; 3]], o: &mut [f32]| {
        for (p, o) in p.iter().zip(o) {
            *o = p[2];
        }
    };
    let m = mesh_of(&plane, -1.0, 1.0, 8);
    assert!(m.vertices.iter().all(|v| v[2].abs() < 1e-6));
}

/// Every edge of `m` borders exactly two triangles, once in each
/// direction (closed and consistently oriented), and the triangles
/// around each vertex form one fan (no two surfaces meeting at a point).
fn assert_two_manifold(m: &Mesh, what: &str) {
    use std::collections::HashMap;
    let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
    for t in &m.triangles {
        for k in 0..3 {
            *edges.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
        }
    }
    let bad = edges
        .iter()
        .filter(|(&(a, b), &n)| n != 1 || edges.get(&(b, a)) != Some(&1))
        .count();
    assert_eq!(
        bad, 0,
        "{what}: {bad} directed edges not shared by exactly two triangles"
    );
    // Around each vertex, "next" maps the far corner of one triangle to
    // that of the next: a 2-manifold vertex has a single cycle.
    let mut next: HashMap<u32, Vec<(u32, u32)>> = HashMap::new();
    for t in &m.triangles {
        for k in 0..3 {
            next.entry(t[k])
                .or_default()
                .push((t[(k + 1) % 3], t[(k + 2) % 3]));
        }
    }
    for (v, fan) in &next {
        let step: HashMap<u32, u32> = fan.iter().copied().collect();
        let (start, mut at, mut n) = (fan[0].0, fan[0].1, 1);
        while at != start && n <= fan.len() {
            at = step[&at];
            n += 1;
        }
        assert_eq!(
            n,
            fan.len(),
            "{what}: vertex {v} has {} triangles in more than one fan",
            fan.len()
        );
    }
    assert!(
        m.vertices
            .iter()
            .enumerate()
            .all(|(i, _)| next.contains_key(&(i as u32))),
        "{what}: a vertex without triangles"
    );
}

/// Fields whose grids have cells with two or more pieces of surface
/// (diagonal corners on a face or through a cell, thin walls, many small
/// blobs) still give closed 2-manifold meshes, as a `trimesh`
/// watertightness check would ask.
#[test]
fn closed_surfaces_give_two_manifold_meshes() {
    let gyroid = |p: &[[f32; 3]], o: &mut [f32]| {
        for (p, o) in p.iter().zip(o) {
            let [x, y, z] = p.map(|c| c * 9.0);
            let g = x.sin() * y.cos() + y.sin() * z.cos() + z.sin() * x.cos();
            // Closed inside a sphere: the gyroid shell cut by it.
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 0.9;
            *o = (g.abs() - 0.2).max(r);
        }
    };
    assert_two_manifold(&mesh_of(&gyroid, -1.0, 1.0, 24), "gyroid shell");
    assert_two_manifold(
        &mesh_of(&sphere(0.8, [0.01, 0.02, 0.03]), -1.0, 1.0, 16),
        "sphere",
    );
    for res in [12, 17, 20, 23, 31] {
        assert_two_manifold(&mesh_of(&torus(0.6, 0.06), -1.0, 1.0, res), "thin torus");
    }
    // Thin tubes in every direction, about a cell across.
    let mut rng = SplitMix64::new(5);
    for trial in 0..40 {
        let tubes: Vec<([f32; 3], [f32; 3], f32)> = (0..8)
            .map(|_| {
                let a = [0; 3].map(|_| rng.next_f32() * 1.4 - 0.7);
                let b = [0; 3].map(|_| rng.next_f32() * 1.4 - 0.7);
                (a, b, 0.03 + 0.05 * rng.next_f32())
            })
            .collect();
        let f = |p: &[[f32; 3]], o: &mut [f32]| {
            for (p, o) in p.iter().zip(o) {
                *o = tubes
                    .iter()
                    .map(|(a, b, r)| {
                        let pa: [f32; 3] = std::array::from_fn(|k| p[k] - a[k]);
                        let ba: [f32; 3] = std::array::from_fn(|k| b[k] - a[k]);
                        let dot =
                            |x: [f32; 3], y: [f32; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
                        let h = (dot(pa, ba) / dot(ba, ba)).clamp(0.0, 1.0);
                        let d: [f32; 3] = std::array::from_fn(|k| pa[k] - ba[k] * h);
                        dot(d, d).sqrt() - r
                    })
                    .fold(f32::INFINITY, f32::min);
            }
        };
        assert_two_manifold(
            &mesh_of(&f, -1.0, 1.0, 16 + trial % 9),
            &format!("tubes {trial}"),
        );
    }
    // Blobs of random size and place, many of them near cell size, so
    // that cells see every marching-cubes case including ambiguous ones.
    let mut rng = SplitMix64::new(11);
    for trial in 0..80 {
        let balls: Vec<([f32; 3], f32)> = (0..30)
            .map(|_| {
                let c = [0; 3].map(|_| rng.next_f32() * 1.6 - 0.8);
                (c, 0.02 + 0.12 * rng.next_f32())
            })
            .collect();
        let f = |p: &[[f32; 3]], o: &mut [f32]| {
            for (p, o) in p.iter().zip(o) {
                *o = balls
                    .iter()
                    .map(|(c, r)| {
                        let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
                        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - r
                    })
                    .fold(f32::INFINITY, f32::min);
            }
        };
        assert_two_manifold(
            &mesh_of(&f, -1.0, 1.0, 14 + trial % 7),
            &format!("blobs {trial}"),
        );
    }
}

#[test]
fn ply_header_and_sizes() {
    let m = mesh_of(&sphere(0.5, [0.0; 3]), -1.0, 1.0, 8);
    let bytes = m.ply_bytes();
    let end = b"end_header\n";
    let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
    let header = std::str::from_utf8(&bytes[..at]).unwrap();
    assert!(header.contains(&format!("element vertex {}", m.vertices.len())));
    assert!(header.contains(&format!("element face {}", m.triangles.len())));
    assert_eq!(
        bytes.len() - at,
        m.vertices.len() * 24 + m.triangles.len() * 13
    );
    let first = f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    assert_eq!(first, m.vertices[0][0]);
}
