//! Normals of a point cloud from the points themselves, as open3d's
//! `estimate_normals` gives them: the direction of least spread of each
//! point's nearest neighbours (their covariance's smallest eigenvector).
//! Which way each faces is decided by the caller ([`orient`]): by the
//! field's density falling outwards where it can tell, else towards where
//! the point was seen from (unreliable at silhouettes, where a grazing
//! ray's point lies just past the tangent).

use std::num::NonZero;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;

/// Neighbours a normal is fitted to (the point included).
pub const NEIGHBOURS: usize = sdfl_stdlib::work::CLOUD_NORMAL_NEIGHBOURS;

/// A point's fitted plane: its unit normal (either way round; `None`
/// where the neighbours do not span a plane: fewer than three points, all
/// on a line or all at one place) and the distance to its farthest
/// neighbour, the scale the fit saw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fitted {
    /// The plane's unit normal.
    pub normal: Option<[f64; 3]>,
    /// Distance to the farthest of the neighbours.
    pub spacing: f64,
}

/// The plane through each point's [`NEIGHBOURS`] nearest points.
pub fn fit_planes(points: &[[f32; 3]]) -> Vec<Fitted> {
    if points.is_empty() {
        return Vec::new();
    }
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(points);
    let k = NonZero::new(NEIGHBOURS.min(points.len())).unwrap_or(NonZero::<usize>::MIN);
    points
        .par_iter()
        .map(|p| {
            let near = tree.nearest_n::<SquaredEuclidean>(p, k);
            let spacing = near
                .iter()
                .map(|n| n.distance as f64)
                .fold(0.0, f64::max)
                .sqrt();
            let near: Vec<[f64; 3]> = near
                .iter()
                .map(|n| points[n.item as usize].map(f64::from))
                .collect();
            Fitted {
                normal: plane_normal(&near),
                spacing,
            }
        })
        .collect()
}

/// The unit normal of `fit` facing `outward` (a direction the surface
/// faces, e.g. down the density's gradient) where that is finite and not
/// along the plane, else facing `back` (towards where the point was seen
/// from); with no plane, `back` itself. Zero where nothing is finite.
pub fn orient(fit: &Fitted, outward: Option<[f64; 3]>, back: [f64; 3]) -> [f32; 3] {
    let unit = |v: [f64; 3]| {
        let len = dot(v, v).sqrt();
        (len > 0.0 && len.is_finite()).then(|| v.map(|x| x / len))
    };
    let n = match fit.normal {
        None => unit(back),
        Some(n) => {
            let by = outward
                .and_then(unit)
                .filter(|o| dot(*o, n).abs() > 0.1)
                .or_else(|| unit(back));
            match by {
                Some(o) if dot(o, n) < 0.0 => Some(n.map(|x| -x)),
                _ => Some(n),
            }
        }
    };
    n.map_or([0.0; 3], |n| n.map(|x| x as f32))
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The unit normal of the plane through `points` (least squares), or
/// `None` when they do not single one out.
pub fn plane_normal(points: &[[f64; 3]]) -> Option<[f64; 3]> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let mean = [0, 1, 2].map(|a| points.iter().map(|p| p[a]).sum::<f64>() / n);
    let mut c = [[0.0f64; 3]; 3];
    for p in points {
        let d = [0, 1, 2].map(|a| p[a] - mean[a]);
        for i in 0..3 {
            for j in 0..3 {
                c[i][j] += d[i] * d[j] / n;
            }
        }
    }
    let scale = c[0][0] + c[1][1] + c[2][2];
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    let lambda = smallest_eigenvalue(&c);
    // The eigenvector is orthogonal to every row of C − λI: the largest
    // cross product of two rows is the best-conditioned.
    let rows = [0, 1, 2].map(|i| {
        let mut r = c[i];
        r[i] -= lambda;
        r
    });
    let v = [
        cross(rows[0], rows[1]),
        cross(rows[0], rows[2]),
        cross(rows[1], rows[2]),
    ]
    .into_iter()
    .max_by(|a, b| dot(*a, *a).total_cmp(&dot(*b, *b)))?;
    let len2 = dot(v, v);
    // Rows of rank one (a line, or two equal small eigenvalues): no plane.
    if len2.is_nan() || len2 <= 1e-18 * scale.powi(4) {
        return None;
    }
    let len = len2.sqrt();
    Some(v.map(|x| x / len))
}

/// The smallest eigenvalue of the symmetric `c`, in closed form (the
/// roots of its characteristic cubic by the trigonometric method).
fn smallest_eigenvalue(c: &[[f64; 3]; 3]) -> f64 {
    let off = c[0][1] * c[0][1] + c[0][2] * c[0][2] + c[1][2] * c[1][2];
    if off == 0.0 {
        return c[0][0].min(c[1][1]).min(c[2][2]);
    }
    let q = (c[0][0] + c[1][1] + c[2][2]) / 3.0;
    let p2 = (c[0][0] - q).powi(2) + (c[1][1] - q).powi(2) + (c[2][2] - q).powi(2) + 2.0 * off;
    let p = (p2 / 6.0).sqrt();
    let b = |i: usize, j: usize| (c[i][j] - if i == j { q } else { 0.0 }) / p;
    let det = b(0, 0) * (b(1, 1) * b(2, 2) - b(1, 2) * b(2, 1))
        - b(0, 1) * (b(1, 0) * b(2, 2) - b(1, 2) * b(2, 0))
        + b(0, 2) * (b(1, 0) * b(2, 1) - b(1, 1) * b(2, 0));
    let phi = (det / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
    q + 2.0 * p * (phi + 2.0 * std::f64::consts::PI / 3.0).cos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::SplitMix64;

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
}
