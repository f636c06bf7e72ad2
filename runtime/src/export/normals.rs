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

/// `a · b`.
#[doc(hidden)]
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
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
#[doc(hidden)]
pub fn smallest_eigenvalue(c: &[[f64; 3]; 3]) -> f64 {
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
