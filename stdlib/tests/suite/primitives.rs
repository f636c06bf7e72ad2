//! Every exact primitive against brute force: the distance from a query point
//! to a dense sample of the surface (made independently of the SDF formula)
//! must match `|sdf|`, and the sign must match an independent inside test.

use std::f64::consts::TAU;
use std::sync::Arc;

use glam::{DQuat, DVec3};
use sdfl_stdlib::shape::*;

/// Deterministic uniform numbers in [0, 1).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn in_box(&mut self, lo: DVec3, hi: DVec3) -> DVec3 {
        lo + (hi - lo) * DVec3::new(self.next(), self.next(), self.next())
    }
}

/// Points on the faces of an axis-aligned box, spaced about `h`.
fn box_surface(c: DVec3, half: DVec3, h: f64) -> Vec<DVec3> {
    let mut out = Vec::new();
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let nu = (2.0 * half[u] / h).ceil() as usize + 1;
        let nv = (2.0 * half[v] / h).ceil() as usize + 1;
        for side in [-1.0, 1.0] {
            for i in 0..nu {
                for j in 0..nv {
                    let mut p = DVec3::ZERO;
                    p[axis] = side * half[axis];
                    p[u] = -half[u] + 2.0 * half[u] * i as f64 / (nu - 1) as f64;
                    p[v] = -half[v] + 2.0 * half[v] * j as f64 / (nv - 1) as f64;
                    out.push(c + p);
                }
            }
        }
    }
    out
}

fn check(shape: &Shape, surface: &[DVec3], inside: impl Fn(DVec3) -> bool, spacing: f64) {
    let b = shape.bounds().expect("bounded").expand(0.6);
    let mut rng = Lcg(42);
    for _ in 0..300 {
        let p = rng.in_box(b.min, b.max);
        let brute = surface
            .iter()
            .map(|s| (p - *s).length())
            .fold(f64::INFINITY, f64::min);
        let d = shape.distance(p);
        // Sampling can only overestimate the true distance, by at most about
        // the spacing; the SDF must never exceed the sampled distance.
        assert!(
            d.abs() <= brute + 1e-9,
            "{}: |sdf| {d} > brute {brute} at {p}",
            shape.name()
        );
        assert!(
            brute - d.abs() <= spacing,
            "{}: sdf {d} vs brute {brute} at {p}",
            shape.name()
        );
        if brute > spacing {
            assert_eq!(
                d < 0.0,
                inside(p),
                "{}: sign wrong at {p} (sdf {d})",
                shape.name()
            );
        }
    }
}

#[test]
fn sphere() {
    let (c, r) = (DVec3::new(0.3, -0.2, 0.1), 0.8);
    let n = 40_000;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let surface: Vec<DVec3> = (0..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let rad = (1.0 - y * y).sqrt();
            let t = golden * i as f64;
            c + r * DVec3::new(rad * t.cos(), y, rad * t.sin())
        })
        .collect();
    check(
        &Shape::from(Sphere {
            center: c.into(),
            radius: r.into(),
        }),
        &surface,
        |p| (p - c).length() < r,
        0.02,
    );
}

#[test]
fn box_() {
    let (c, size) = (DVec3::new(0.1, 0.2, -0.3), DVec3::new(1.0, 0.6, 0.8));
    let surface = box_surface(c, size / 2.0, 0.01);
    let inside = |p: DVec3| ((p - c).abs() - size / 2.0).max_element() < 0.0;
    check(
        &Shape::from(Cuboid {
            center: c.into(),
            size: size.into(),
        }),
        &surface,
        inside,
        0.01,
    );
}

#[test]
fn box_frame() {
    let (c, size, e) = (DVec3::new(0.0, 0.1, 0.0), DVec3::new(1.2, 1.0, 0.8), 0.1);
    let half = size / 2.0;
    // The frame is the union of 12 edge boxes; its surface is the part of
    // their faces not strictly inside another edge box.
    let mut edges = Vec::new();
    for axis in 0..3 {
        for s1 in [-1.0, 1.0] {
            for s2 in [-1.0, 1.0] {
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let mut ec = DVec3::ZERO;
                ec[u] = s1 * (half[u] - e / 2.0);
                ec[v] = s2 * (half[v] - e / 2.0);
                let mut eh = DVec3::splat(e / 2.0);
                eh[axis] = half[axis];
                edges.push((c + ec, eh));
            }
        }
    }
    let inside_edge =
        |p: DVec3, (ec, eh): (DVec3, DVec3)| ((p - ec).abs() - eh).max_element() < -1e-9;
    let surface: Vec<DVec3> = edges
        .iter()
        .flat_map(|(ec, eh)| box_surface(*ec, *eh, 0.008))
        .filter(|p| !edges.iter().any(|e| inside_edge(*p, *e)))
        .collect();
    let inside = |p: DVec3| edges.iter().any(|e| inside_edge(p, *e));
    check(
        &Shape::from(BoxFrame {
            center: c.into(),
            size: size.into(),
            thickness: e.into(),
        }),
        &surface,
        inside,
        0.008,
    );
}

#[test]
fn torus() {
    let (c, big, small) = (DVec3::new(0.2, 0.0, -0.1), 1.0, 0.25);
    let (nu, nv) = (900, 220);
    let mut surface = Vec::new();
    for i in 0..nu {
        for j in 0..nv {
            let (u, v) = (TAU * i as f64 / nu as f64, TAU * j as f64 / nv as f64);
            let ring = big + small * v.cos();
            surface.push(c + DVec3::new(ring * u.cos(), ring * u.sin(), small * v.sin()));
        }
    }
    let inside = |p: DVec3| {
        let q = p - c;
        let a = (q.x * q.x + q.y * q.y).sqrt() - big;
        a * a + q.z * q.z < small * small
    };
    check(
        &Shape::from(Torus {
            center: c.into(),
            major: big.into(),
            minor: small.into(),
            axis: Axis::Z,
        }),
        &surface,
        inside,
        0.01,
    );
}

#[test]
fn capsule() {
    let (a, b, r) = (DVec3::new(-0.5, 0.0, 0.2), DVec3::new(0.4, 0.3, -0.2), 0.3);
    let axis = (b - a).normalize();
    let (u, v) = (axis.any_orthonormal_pair().0, axis.any_orthonormal_pair().1);
    let mut surface = Vec::new();
    let len = (b - a).length();
    for i in 0..=200 {
        for j in 0..300 {
            let t = len * i as f64 / 200.0;
            let ang = TAU * j as f64 / 300.0;
            surface.push(a + axis * t + r * (u * ang.cos() + v * ang.sin()));
        }
    }
    // Hemispherical caps: the full spheres' points that are beyond the ends.
    for (end, dir) in [(a, -axis), (b, axis)] {
        for i in 0..20_000 {
            let y = 1.0 - 2.0 * (i as f64 + 0.5) / 20_000.0;
            let rad = (1.0 - y * y).sqrt();
            let t = 2.399963229728653 * i as f64;
            let d = DVec3::new(rad * t.cos(), y, rad * t.sin());
            if d.dot(dir) >= 0.0 {
                surface.push(end + r * d);
            }
        }
    }
    let inside = |p: DVec3| {
        let h = ((p - a).dot(b - a) / (b - a).length_squared()).clamp(0.0, 1.0);
        (p - a - (b - a) * h).length() < r
    };
    check(
        &Shape::from(Capsule {
            a: a.into(),
            b: b.into(),
            radius: r.into(),
        }),
        &surface,
        inside,
        0.012,
    );
}

#[test]
fn cylinder() {
    let (c, r, h) = (DVec3::new(0.0, 0.2, 0.1), 0.5, 1.2);
    let mut surface = Vec::new();
    for i in 0..=240 {
        for j in 0..400 {
            let ang = TAU * j as f64 / 400.0;
            let z = -h / 2.0 + h * i as f64 / 240.0;
            surface.push(c + DVec3::new(r * ang.cos(), r * ang.sin(), z));
        }
    }
    for i in 0..=100 {
        for j in 0..400 {
            let rad = r * i as f64 / 100.0;
            let ang = TAU * j as f64 / 400.0;
            for z in [-h / 2.0, h / 2.0] {
                surface.push(c + DVec3::new(rad * ang.cos(), rad * ang.sin(), z));
            }
        }
    }
    let inside = |p: DVec3| {
        let q = p - c;
        (q.x * q.x + q.y * q.y).sqrt() < r && q.z.abs() < h / 2.0
    };
    check(
        &Shape::from(Cylinder {
            center: c.into(),
            radius: r.into(),
            height: h.into(),
            axis: Axis::Z,
        }),
        &surface,
        inside,
        0.01,
    );
}

#[test]
fn rotated_scaled_translated_box_stays_exact() {
    let size = DVec3::new(1.0, 0.5, 0.7);
    let (axis, angle) = (DVec3::new(1.0, 2.0, 0.5).normalize(), 0.7);
    let q = DQuat::from_axis_angle(axis, angle);
    let (s, t) = (1.3, DVec3::new(0.2, -0.1, 0.4));
    let shape = Shape::Translate(
        Arc::new(Shape::Scale(
            Arc::new(Shape::Rotate {
                shape: Arc::new(Shape::from(Cuboid {
                    center: DVec3::ZERO.into(),
                    size: size.into(),
                })),
                axis,
                angle: angle.into(),
            }),
            s.into(),
        )),
        t.into(),
    );
    let surface: Vec<DVec3> = box_surface(DVec3::ZERO, size / 2.0, 0.006)
        .into_iter()
        .map(|p| q * p * s + t)
        .collect();
    let inside = |p: DVec3| {
        let local = q.inverse() * ((p - t) / s);
        (local.abs() - size / 2.0).max_element() < 0.0
    };
    check(&shape, &surface, inside, 0.01);
}

#[test]
fn plane_is_signed_distance_to_the_plane() {
    let n = DVec3::new(1.0, 2.0, 2.0) / 3.0;
    let plane = Shape::from(Plane {
        normal: n.into(),
        height: 0.5.into(),
    });
    let mut rng = Lcg(7);
    for _ in 0..100 {
        let p = rng.in_box(DVec3::splat(-3.0), DVec3::splat(3.0));
        // Foot of the perpendicular, found independently by projection.
        let foot = p - n * (p.dot(n) - 0.5);
        assert!((foot.dot(n) - 0.5).abs() < 1e-12);
        let d = plane.distance(p);
        assert!((d.abs() - (p - foot).length()).abs() < 1e-12);
    }
}

/// The ellipsoid is a bound: it never exceeds the distance to a dense
/// sample of its surface, has the right sign, and is within a factor of the
/// axes' ratio of the truth.
#[test]
fn ellipsoid_bound_never_overestimates() {
    let (c, r) = (DVec3::new(0.2, -0.1, 0.3), DVec3::new(1.0, 0.3, 0.6));
    let shape = Shape::from(Ellipsoid {
        center: c.into(),
        radii: r.into(),
    });
    let mut surface = Vec::new();
    let n = 240;
    for i in 0..n {
        for j in 0..=n / 2 {
            let (u, v) = (
                TAU * i as f64 / n as f64,
                std::f64::consts::PI * j as f64 / (n / 2) as f64,
            );
            surface.push(
                c + DVec3::new(
                    r.x * u.cos() * v.sin(),
                    r.y * u.sin() * v.sin(),
                    r.z * v.cos(),
                ),
            );
        }
    }
    let mut rng = Lcg(7);
    let b = shape.bounds().unwrap().expand(1.0);
    for _ in 0..400 {
        let p = rng.in_box(b.min, b.max);
        let brute = surface
            .iter()
            .map(|s| (p - *s).length())
            .fold(f64::INFINITY, f64::min);
        let d = shape.distance(p);
        assert!(d.abs() <= brute + 1e-9, "|f| {d} > {brute} at {p}");
        let q = (p - c) / r;
        if brute > 0.02 {
            assert_eq!(d < 0.0, q.length() < 1.0, "sign at {p}");
            assert!(
                d.abs() >= brute * 0.3 / 1.0 - 0.02,
                "too loose: {d} vs {brute}"
            );
        }
    }
}

#[test]
fn capped_cone_is_exact() {
    let c = DVec3::new(0.1, 0.2, -0.1);
    let (h, r1, r2) = (1.2, 0.6, 0.25);
    for (bottom, top) in [(r1, r2), (r2, r1), (r1, 0.0)] {
        let shape = Shape::from(CappedCone {
            center: c.into(),
            height: h.into(),
            bottom: bottom.into(),
            top: top.into(),
            axis: Axis::Z,
        });
        let spacing = 0.01;
        let radius_at = |z: f64| bottom + (top - bottom) * (z / h + 0.5);
        let mut surface = Vec::new();
        // Caps as filled disks, the side as a ruled surface.
        for (z, r) in [(-h / 2.0, bottom), (h / 2.0, top)] {
            let rings = (r / spacing).ceil() as usize;
            for i in 0..=rings {
                let rho = r * i as f64 / rings.max(1) as f64;
                let n = ((TAU * rho / spacing).ceil() as usize).max(1);
                for k in 0..n {
                    let a = TAU * k as f64 / n as f64;
                    surface.push(c + DVec3::new(rho * a.cos(), rho * a.sin(), z));
                }
            }
        }
        let rows = (h / spacing).ceil() as usize;
        for i in 0..=rows {
            let z = -h / 2.0 + h * i as f64 / rows as f64;
            let r = radius_at(z);
            let n = ((TAU * r / spacing).ceil() as usize).max(1);
            for k in 0..n {
                let a = TAU * k as f64 / n as f64;
                surface.push(c + DVec3::new(r * a.cos(), r * a.sin(), z));
            }
        }
        let inside = |p: DVec3| {
            let q = p - c;
            q.z.abs() <= h / 2.0 && q.truncate().length() <= radius_at(q.z)
        };
        check(&shape, &surface, inside, 2.0 * spacing);
    }
}

/// Points on the boundary of the solid `inside` (within `lo..hi`): wherever
/// the inside test changes between neighbouring nodes of a grid of spacing
/// `h`, the crossing found by bisection. Independent of any SDF formula.
fn surface_of(inside: &dyn Fn(DVec3) -> bool, lo: DVec3, hi: DVec3, h: f64) -> Vec<DVec3> {
    let n = ((hi - lo) / h).ceil().as_uvec3() + glam::UVec3::ONE;
    let (nx, ny, nz) = (n.x as usize, n.y as usize, n.z as usize);
    let at = |i: usize, j: usize, k: usize| lo + DVec3::new(i as f64, j as f64, k as f64) * h;
    let grid: Vec<bool> = (0..nx * ny * nz)
        .map(|m| inside(at(m % nx, (m / nx) % ny, m / (nx * ny))))
        .collect();
    let idx = |i: usize, j: usize, k: usize| i + nx * (j + ny * k);
    let mut out = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let a = grid[idx(i, j, k)];
                for (di, dj, dk) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                    let (i2, j2, k2) = (i + di, j + dj, k + dk);
                    if i2 >= nx || j2 >= ny || k2 >= nz || grid[idx(i2, j2, k2)] == a {
                        continue;
                    }
                    let (mut p, mut q) = (at(i, j, k), at(i2, j2, k2));
                    for _ in 0..40 {
                        let m = (p + q) * 0.5;
                        if inside(m) == a {
                            p = m;
                        } else {
                            q = m;
                        }
                    }
                    out.push((p + q) * 0.5);
                }
            }
        }
    }
    out
}

/// A shape built along Z checked against its inside test (in its own
/// frame, Z up), laid along each axis: the brute-force surface comes from
/// the inside test, the axis mapping is written here independently.
fn check_along_axes(make: impl Fn(Axis) -> Shape, local_inside: impl Fn(DVec3) -> bool, c: DVec3) {
    let h = 0.012;
    for axis in [Axis::Z, Axis::X, Axis::Y] {
        let shape = make(axis);
        assert_eq!(shape.exactness(), Exactness::Exact, "{}", shape.name());
        let to_local = |p: DVec3| {
            let q = p - c;
            match axis {
                Axis::Z => q,
                Axis::X => DVec3::new(q.y, q.z, q.x),
                Axis::Y => DVec3::new(q.z, q.x, q.y),
            }
        };
        let inside = |p: DVec3| local_inside(to_local(p));
        let b = shape.bounds().unwrap().expand(2.0 * h);
        let surface = surface_of(&inside, b.min, b.max, h);
        assert!(
            surface.len() > 1000,
            "{}: {} surface points",
            shape.name(),
            surface.len()
        );
        check(&shape, &surface, inside, 1.5 * h);
    }
}

#[test]
fn round_cone_is_exact() {
    let c = DVec3::new(0.1, -0.2, 0.05);
    let (r1, r2, h) = (0.45, 0.15, 0.8);
    // The union of spheres along the axis, radius varying linearly: the
    // distance to it is convex in the parameter, so a golden-section search
    // finds its minimum (to 1e-9 of the axis, far below the grid step).
    let inside = |q: DVec3| {
        let f =
            |t: f64| (q - DVec3::new(0.0, 0.0, -h / 2.0 + h * t)).length() - (r1 + (r2 - r1) * t);
        let g = (5f64.sqrt() - 1.0) / 2.0;
        let (mut a, mut b) = (0.0, 1.0);
        let (mut m1, mut m2) = (b - g * (b - a), a + g * (b - a));
        let (mut f1, mut f2) = (f(m1), f(m2));
        for _ in 0..45 {
            if f1 < f2 {
                (b, m2, f2) = (m2, m1, f1);
                m1 = b - g * (b - a);
                f1 = f(m1);
            } else {
                (a, m1, f1) = (m1, m2, f2);
                m2 = a + g * (b - a);
                f2 = f(m2);
            }
        }
        f1.min(f2) < 0.0
    };
    check_along_axes(
        |axis| {
            Shape::from(RoundCone {
                center: c.into(),
                bottom: r1.into(),
                top: r2.into(),
                height: h.into(),
                axis,
            })
        },
        inside,
        c,
    );
}

#[test]
fn hex_prism_is_exact() {
    let c = DVec3::new(-0.1, 0.05, 0.2);
    let (r, h) = (0.4, 0.7);
    let inside = |q: DVec3| {
        q.y.abs() <= r
            && 3f64.sqrt() / 2.0 * q.x.abs() + q.y.abs() / 2.0 <= r
            && q.z.abs() <= h / 2.0
    };
    check_along_axes(
        |axis| {
            Shape::from(HexPrism {
                center: c.into(),
                radius: r.into(),
                height: h.into(),
                axis,
            })
        },
        inside,
        c,
    );
}

#[test]
fn tri_prism_is_exact() {
    let c = DVec3::new(0.2, 0.0, -0.1);
    let (side, h) = (0.9, 0.5);
    let k = 3f64.sqrt();
    // Base at −inradius, apex at +2·inradius, sides through the apex.
    let inside = |q: DVec3| {
        q.y >= -side / (2.0 * k) && k * q.x.abs() + q.y <= side / k && q.z.abs() <= h / 2.0
    };
    check_along_axes(
        |axis| {
            Shape::from(TriPrism {
                center: c.into(),
                side: side.into(),
                height: h.into(),
                axis,
            })
        },
        inside,
        c,
    );
}

#[test]
fn link_is_exact() {
    let c = DVec3::new(0.0, 0.1, 0.1);
    let (len, big, small) = (0.6, 0.35, 0.1);
    // Two straight tubes at x = ±major and two half tori at y = ±length/2.
    let inside = |q: DVec3| {
        let y = q.y.abs() - len / 2.0;
        if y <= 0.0 {
            (q.x.abs() - big).powi(2) + q.z * q.z < small * small
        } else {
            ((q.x * q.x + y * y).sqrt() - big).powi(2) + q.z * q.z < small * small
        }
    };
    check_along_axes(
        |axis| {
            Shape::from(Link {
                center: c.into(),
                length: len.into(),
                major: big.into(),
                minor: small.into(),
                axis,
            })
        },
        inside,
        c,
    );
}

#[test]
fn torus_cylinder_and_cone_along_each_axis() {
    let c = DVec3::new(0.1, 0.2, -0.1);
    let (big, small) = (0.5, 0.15);
    check_along_axes(
        |axis| {
            Shape::from(Torus {
                center: c.into(),
                major: big.into(),
                minor: small.into(),
                axis,
            })
        },
        |q| ((q.x * q.x + q.y * q.y).sqrt() - big).powi(2) + q.z * q.z < small * small,
        c,
    );
    let (r, h) = (0.35, 0.8);
    check_along_axes(
        |axis| {
            Shape::from(Cylinder {
                center: c.into(),
                radius: r.into(),
                height: h.into(),
                axis,
            })
        },
        |q| (q.x * q.x + q.y * q.y).sqrt() < r && q.z.abs() < h / 2.0,
        c,
    );
    // A pointed cone (`top: 0`).
    check_along_axes(
        |axis| {
            Shape::from(CappedCone {
                center: c.into(),
                height: h.into(),
                bottom: r.into(),
                top: 0.0.into(),
                axis,
            })
        },
        |q| q.z.abs() < h / 2.0 && (q.x * q.x + q.y * q.y).sqrt() < r * (0.5 - q.z / h),
        c,
    );
}

fn ball(c: DVec3, r: f64) -> Arc<Shape> {
    Arc::new(Shape::from(Sphere {
        center: c.into(),
        radius: r.into(),
    }))
}

/// The union of the copies, written out.
fn copies(
    shape: &Arc<Shape>,
    spacing: DVec3,
    range: [std::ops::RangeInclusive<i32>; 3],
    centre: DVec3,
) -> Shape {
    let mut out = Vec::new();
    for i in range[0].clone() {
        for j in range[1].clone() {
            for k in range[2].clone() {
                let off = DVec3::new(i as f64, j as f64, k as f64) * spacing - centre;
                out.push(Arc::new(Shape::Translate(shape.clone(), off.into())));
            }
        }
    }
    Shape::Union(out)
}

/// Repetitions equal the union of their copies, written out, everywhere
/// (across cell borders too), for copies apart, touching and overlapping,
/// and for children off-centre in their cell.
#[test]
fn repeat_is_the_union_of_its_copies() {
    let child = |c: DVec3, r: f64| {
        Arc::new(Shape::Union(vec![
            ball(c, r),
            Arc::new(Shape::from(Cuboid {
                center: (c + DVec3::new(0.2, -0.1, 0.0)).into(),
                size: DVec3::new(0.3, 0.5, r).into(),
            })),
        ]))
    };
    let spacing = DVec3::new(1.0, 0.8, 0.0);
    let mut rng = Lcg(3);
    for (c, r) in [
        (DVec3::ZERO, 0.25),
        (DVec3::new(0.3, 0.1, 0.0), 0.3),
        (DVec3::ZERO, 0.9),
        (DVec3::new(-0.6, 0.2, 0.1), 0.7),
    ] {
        let shape = child(c, r);
        // Limited: 4 × 3 copies, centred.
        let limited = Shape::Repeat {
            shape: shape.clone(),
            spacing: spacing.into(),
            count: [4, 3, 1],
        };
        let brute = copies(
            &shape,
            spacing,
            [0..=3, 0..=2, 0..=0],
            DVec3::new(1.5, 0.8, 0.0),
        );
        // Infinite, against enough copies to cover the points tested.
        let infinite = Shape::Repeat {
            shape: shape.clone(),
            spacing: spacing.into(),
            count: [0, 0, 1],
        };
        let many = copies(&shape, spacing, [-12..=12, -12..=12, 0..=0], DVec3::ZERO);
        for _ in 0..2000 {
            let p = rng.in_box(DVec3::splat(-4.0), DVec3::splat(4.0));
            let (a, b) = (limited.distance(p), brute.distance(p));
            assert!(
                (a - b).abs() < 1e-12,
                "limited {a} vs copies {b} at {p} ({c}, {r})"
            );
            let (a, b) = (infinite.distance(p), many.distance(p));
            assert!(
                (a - b).abs() < 1e-12,
                "infinite {a} vs copies {b} at {p} ({c}, {r})"
            );
        }
    }
}

/// Elongating a sphere gives a capsule; mirroring a shape on the positive
/// side gives the union with its reflection (both exact).
#[test]
fn elongate_and_mirror_match_their_constructions() {
    // Cut at the plane x = 0 through the sphere's centre.
    let s = ball(DVec3::new(0.0, 0.2, -0.1), 0.3);
    let long = Shape::Elongate(s.clone(), DVec3::new(0.5, 0.0, 0.0).into());
    let capsule = Shape::from(Capsule {
        a: DVec3::new(-0.5, 0.2, -0.1).into(),
        b: DVec3::new(0.5, 0.2, -0.1).into(),
        radius: 0.3.into(),
    });
    let right = Arc::new(Shape::from(Cuboid {
        center: DVec3::new(0.6, 0.1, 0.0).into(),
        size: DVec3::new(0.4, 0.3, 0.5).into(),
    }));
    let mirrored = Shape::Mirror(right.clone(), Axis::X);
    assert_eq!(mirrored.exactness(), Exactness::Exact);
    let both = Shape::Union(vec![
        right,
        Arc::new(Shape::from(Cuboid {
            center: DVec3::new(-0.6, 0.1, 0.0).into(),
            size: DVec3::new(0.4, 0.3, 0.5).into(),
        })),
    ]);
    let mut rng = Lcg(9);
    for _ in 0..2000 {
        let p = rng.in_box(DVec3::splat(-2.0), DVec3::splat(2.0));
        assert!(
            (long.distance(p) - capsule.distance(p)).abs() < 1e-12,
            "elongate at {p}"
        );
        assert!(
            (mirrored.distance(p) - both.distance(p)).abs() < 1e-12,
            "mirror at {p}"
        );
    }
}

#[test]
fn capped_torus_is_exact() {
    let c = DVec3::new(0.1, -0.2, 0.05);
    let (a, r, m) = (2.0, 0.6, 0.15);
    // The arc's nearest point by its angle from +Y, clamped to the arc.
    let inside = |q: DVec3| {
        let phi = q.x.atan2(q.y).clamp(-a, a);
        let on = DVec3::new(r * phi.sin(), r * phi.cos(), 0.0);
        (q - on).length() < m
    };
    check_along_axes(
        |axis| {
            Shape::from(CappedTorus {
                center: c.into(),
                angle: a.into(),
                major: r.into(),
                minor: m.into(),
                axis,
            })
        },
        inside,
        c,
    );
}

/// Hard cases: a capped torus open by 180° is the torus, and one closed to
/// 0° the ball at its arc's one point; on its axis every arc point is as near.
#[test]
fn capped_torus_at_its_limits() {
    let mut rng = Lcg(5);
    let whole = Shape::from(CappedTorus {
        center: DVec3::ZERO.into(),
        angle: std::f64::consts::PI.into(),
        major: 0.7.into(),
        minor: 0.2.into(),
        axis: Axis::Y,
    });
    let torus = Shape::from(Torus {
        center: DVec3::ZERO.into(),
        major: 0.7.into(),
        minor: 0.2.into(),
        axis: Axis::Y,
    });
    let closed = Shape::from(CappedTorus {
        center: DVec3::ZERO.into(),
        angle: 0.0.into(),
        major: 0.7.into(),
        minor: 0.2.into(),
        axis: Axis::Z,
    });
    for _ in 0..500 {
        let p = rng.in_box(DVec3::splat(-2.0), DVec3::splat(2.0));
        assert!((whole.distance(p) - torus.distance(p)).abs() < 1e-9, "{p}");
        let ball = (p - DVec3::new(0.0, 0.7, 0.0)).length() - 0.2;
        assert!((closed.distance(p) - ball).abs() < 1e-9, "{p}");
    }
    let z = 0.3;
    let on_axis = closed.distance(DVec3::new(0.0, 0.0, z));
    assert!((on_axis - ((0.7f64 * 0.7 + z * z).sqrt() - 0.2)).abs() < 1e-12);
}

#[test]
fn cone_by_angle_is_exact() {
    let c = DVec3::new(-0.1, 0.2, 0.05);
    let (a, h) = (0.5f64, 0.9);
    let inside = |q: DVec3| {
        let r = (q.x * q.x + q.y * q.y).sqrt();
        q.z.abs() < h / 2.0 && r < (h / 2.0 - q.z) * a.tan()
    };
    check_along_axes(
        |axis| {
            Shape::from(Cone {
                center: c.into(),
                angle: a.into(),
                height: h.into(),
                axis,
            })
        },
        inside,
        c,
    );
}

/// The two forms of `cone` are one solid: by the side's angle, and by the
/// base's radius (a capped cone with no top), both exact, agree.
#[test]
fn cone_forms_agree() {
    let mut rng = Lcg(9);
    for (radius, height) in [(0.5, 1.0), (1e-3, 1.0), (3.0, 0.2)] {
        let by_angle = Shape::from(Cone {
            center: DVec3::ZERO.into(),
            angle: f64::atan2(radius, height).into(),
            height: height.into(),
            axis: Axis::X,
        });
        let by_radius = Shape::from(CappedCone {
            center: DVec3::ZERO.into(),
            height: height.into(),
            bottom: radius.into(),
            top: 0.0.into(),
            axis: Axis::X,
        });
        for _ in 0..500 {
            let p = rng.in_box(DVec3::splat(-2.0), DVec3::splat(2.0));
            let (a, b) = (by_angle.distance(p), by_radius.distance(p));
            assert!(
                (a - b).abs() < 1e-9,
                "{radius}, {height}: {a} vs {b} at {p}"
            );
        }
    }
}
