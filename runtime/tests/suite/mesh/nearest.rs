//! Distances to triangles and meshes against brute force, degenerate
//! triangles included.

use sdfl_runtime::mesh::nearest::*;
use sdfl_runtime::mesh::Mesh;
use sdfl_runtime::volume::SplitMix64;

/// The distance to a triangle by brute force: the minimum over a fine
/// barycentric grid and the exact edges (an upper bound within the
/// grid's spacing of the truth, and never below it).
fn brute_triangle(p: [f64; 3], t: &[[f32; 3]; 3]) -> f64 {
    let [a, b, c] = t.map(|v| v.map(f64::from));
    let mut best = segment_distance2(p, a, b)
        .min(segment_distance2(p, b, c))
        .min(segment_distance2(p, c, a));
    let n = 200;
    for i in 0..=n {
        for j in 0..=n - i {
            let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
            let q = [0, 1, 2].map(|k| a[k] + u * (b[k] - a[k]) + v * (c[k] - a[k]));
            best = best.min(distance2(p, q));
        }
    }
    best.sqrt()
}

fn random_triangle(rng: &mut SplitMix64) -> [[f32; 3]; 3] {
    std::array::from_fn(|_| std::array::from_fn(|_| rng.next_f32() * 2.0 - 1.0))
}

#[test]
fn triangle_distances_match_brute_force_in_every_region() {
    let mut rng = SplitMix64::new(7);
    for _ in 0..300 {
        let t = random_triangle(&mut rng);
        let p: [f64; 3] = std::array::from_fn(|_| rng.next_f64() * 4.0 - 2.0);
        let exact = triangle_distance2(p, &t).sqrt();
        let brute = brute_triangle(p, &t);
        // The grid's points lie on the triangle: never nearer than the
        // truth, and within its spacing of it (edges ≤ 2√3 long).
        assert!(exact <= brute + 1e-12, "{exact} > {brute}");
        assert!(brute - exact < 0.02, "{exact} against {brute}");
    }
}

#[test]
fn degenerate_triangles_are_measured_by_their_edges() {
    let p = [0.5, 1.0, 0.0];
    // Collinear corners: a segment from (0,0,0) to (2,0,0).
    let line = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
    assert!((triangle_distance2(p, &line).sqrt() - 1.0).abs() < 1e-12);
    // A single point, repeated.
    let point = [[1.0, 1.0, 1.0]; 3];
    let d = triangle_distance2(p, &point).sqrt();
    assert!((d - (0.25f64 + 1.0).sqrt()).abs() < 1e-12, "{d}");
    // Far away and huge coordinates stay finite.
    let far = [1e30, -1e30, 1e30];
    assert!(triangle_distance2(far, &line).is_finite());
}

/// A random triangle soup against the brute minimum over every
/// triangle, and the mean at two thread counts.
#[test]
fn mesh_distances_match_the_brute_minimum_over_triangles() {
    let mut rng = SplitMix64::new(3);
    let mut mesh = Mesh {
        vertices: Vec::new(),
        normals: Vec::new(),
        triangles: Vec::new(),
    };
    for k in 0..500u32 {
        let t = random_triangle(&mut rng);
        // Small triangles scattered over the box, some large.
        let scale = if k % 50 == 0 { 1.0 } else { 0.05 };
        let centre: [f32; 3] = std::array::from_fn(|_| rng.next_f32() * 2.0 - 1.0);
        for v in t {
            mesh.vertices
                .push(std::array::from_fn(|a| centre[a] + scale * v[a]));
            mesh.normals.push([0.0, 0.0, 1.0]);
        }
        mesh.triangles.push([3 * k, 3 * k + 1, 3 * k + 2]);
    }
    let index = MeshDistance::new(&mesh).unwrap();
    let points: Vec<[f32; 3]> = (0..400)
        .map(|_| std::array::from_fn(|_| rng.next_f32() * 6.0 - 3.0))
        .collect();
    let mut sum = 0.0;
    for p in &points {
        let brute = mesh
            .triangles
            .iter()
            .map(|t| triangle_distance2(p.map(f64::from), &t.map(|i| mesh.vertices[i as usize])))
            .fold(f64::INFINITY, f64::min)
            .sqrt();
        let d = index.distance(*p);
        assert_eq!(d, brute, "at {p:?}");
        sum += brute;
    }
    let mean = index.mean_distance(&points);
    assert!((mean - sum / points.len() as f64).abs() < 1e-12);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    assert_eq!(one.install(|| index.mean_distance(&points)), mean);
    let empty = Mesh {
        vertices: Vec::new(),
        normals: Vec::new(),
        triangles: Vec::new(),
    };
    assert!(MeshDistance::new(&empty).is_none());
}
