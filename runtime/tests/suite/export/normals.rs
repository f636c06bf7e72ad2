//! Point normals: the smallest eigenvalue, planes, degenerate clouds, the
//! way round chosen by the density.

use sdfl_runtime::export::normals::*;
use sdfl_runtime::volume::SplitMix64;

/// A unit normal per point of `points`, facing `seen_from` (each point's
/// ray origin): [`fit_planes`] and [`orient`] without the field.
fn estimate_normals(points: &[[f32; 3]], seen_from: &[[f32; 3]]) -> Vec<[f32; 3]> {
    assert_eq!(points.len(), seen_from.len());
    fit_planes(points)
        .iter()
        .zip(points.iter().zip(seen_from))
        .map(|(f, (p, o))| orient(f, None, [0, 1, 2].map(|a| o[a] as f64 - p[a] as f64)))
        .collect()
}

/// The smallest eigenvalue against the minimum of the Rayleigh
/// quotient over many directions (brute force).
#[test]
fn the_smallest_eigenvalue_matches_brute_force() {
    let mut rng = SplitMix64::new(11);
    for _ in 0..50 {
        let m: [[f64; 3]; 3] =
            std::array::from_fn(|_| std::array::from_fn(|_| rng.next_f64() - 0.5));
        // C = MᵀM: symmetric, positive semi-definite.
        let c: [[f64; 3]; 3] = std::array::from_fn(|i| {
            std::array::from_fn(|j| (0..3).map(|k| m[k][i] * m[k][j]).sum())
        });
        let mut brute = f64::INFINITY;
        let n = 400;
        for a in 0..n {
            let theta = std::f64::consts::PI * (a as f64 + 0.5) / n as f64;
            for b in 0..2 * n {
                let phi = std::f64::consts::PI * b as f64 / n as f64;
                let v = [
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                ];
                let cv: [f64; 3] = std::array::from_fn(|i| dot(c[i], v));
                brute = brute.min(dot(v, cv));
            }
        }
        let lambda = smallest_eigenvalue(&c);
        assert!(lambda <= brute + 1e-12, "{lambda} above {brute}");
        assert!(brute - lambda < 1e-4, "{lambda} against {brute}");
    }
}

#[test]
fn points_on_a_tilted_plane_give_its_normal_facing_the_viewer() {
    let want = {
        let n = [1.0f64, 2.0, 2.0];
        n.map(|x| x / 3.0)
    };
    // Two directions in the plane.
    let u = [2.0f64, -1.0, 0.0].map(|x| x / 5f64.sqrt());
    let v = cross(want, u);
    let mut rng = SplitMix64::new(5);
    let points: Vec<[f32; 3]> = (0..400)
        .map(|_| {
            let (s, t) = (rng.next_f64() * 2.0 - 1.0, rng.next_f64() * 2.0 - 1.0);
            [0, 1, 2].map(|a| (0.3 + s * u[a] + t * v[a]) as f32)
        })
        .collect();
    // Seen from the side the normal points to, then from the other.
    for (side, sign) in [(5.0f32, 1.0f64), (-5.0, -1.0)] {
        let eye = want.map(|x| x as f32 * side);
        let normals = estimate_normals(&points, &vec![eye; points.len()]);
        for n in normals {
            let d = [0, 1, 2].map(|a| n[a] as f64 - sign * want[a]);
            assert!(dot(d, d).sqrt() < 1e-4, "{n:?}");
        }
    }
}

#[test]
fn lines_single_points_and_tiny_clouds_point_back_along_the_ray() {
    let origin = [0.0f32, 0.0, 10.0];
    // Collinear points: no plane.
    let line: Vec<[f32; 3]> = (0..20).map(|k| [k as f32 * 0.1, 0.0, 0.0]).collect();
    for (p, n) in line
        .iter()
        .zip(estimate_normals(&line, &vec![origin; line.len()]))
    {
        let back = [0, 1, 2].map(|a| origin[a] - p[a]);
        let len = back.iter().map(|x| x * x).sum::<f32>().sqrt();
        for a in 0..3 {
            assert!((n[a] - back[a] / len).abs() < 1e-5, "{n:?}");
        }
    }
    // One point, the same point twice, and far-away coordinates.
    assert_eq!(
        estimate_normals(&[[0.0; 3]], &[origin]),
        vec![[0.0, 0.0, 1.0]]
    );
    let twice = estimate_normals(&[[1.0, 0.0, 0.0]; 2], &[origin; 2]);
    assert!(twice.iter().flatten().all(|x| x.is_finite()));
    let far = estimate_normals(&[[1e30, 0.0, 0.0]; 3], &[[-1e30, 0.0, 0.0]; 3]);
    assert!(far.iter().flatten().all(|x| x.is_finite()));
    assert!(estimate_normals(&[], &[]).is_empty());
}

/// At a silhouette the ray grazes the surface and its point lies just
/// past the tangent: the density's fall decides, where it has one.
#[test]
fn the_density_decides_the_way_round_over_the_view() {
    let fit = Fitted {
        normal: Some([0.0, 0.0, -1.0]),
        spacing: 0.1,
    };
    let grazing = [1.0, 0.0, -0.05];
    assert_eq!(
        orient(&fit, Some([0.0, 0.2, 3.0]), grazing),
        [0.0, 0.0, 1.0]
    );
    assert_eq!(orient(&fit, None, grazing), [0.0, 0.0, -1.0]);
    // A gradient along the plane, or not finite, says nothing.
    assert_eq!(
        orient(&fit, Some([1.0, 0.0, 0.0]), grazing),
        [0.0, 0.0, -1.0]
    );
    assert_eq!(
        orient(&fit, Some([f64::NAN, 0.0, 1.0]), grazing),
        [0.0, 0.0, -1.0]
    );
    // No plane: back along the ray; nothing finite: zero.
    let none = Fitted {
        normal: None,
        spacing: 0.0,
    };
    assert_eq!(
        orient(&none, Some([0.0, 0.0, 1.0]), [0.0, 2.0, 0.0]),
        [0.0, 1.0, 0.0]
    );
    assert_eq!(orient(&none, None, [f64::INFINITY, 0.0, 0.0]), [0.0; 3]);
}
