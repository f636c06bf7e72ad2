//! Screen tiles: the union lowered once for points, no member dropped near
//! its rays, rays entering boxes.

use glam::{DVec3, Vec3A};
use sdfl_runtime::sdf::tiles::*;
use sdfl_runtime::sdf::*;
use sdfl_runtime::trace::{normal_step, Distance, TraceSettings};
use sdfl_stdlib::shape::{Cuboid, Plane, Shape, Sphere, Torus};
use std::sync::Arc;

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn v(&mut self, s: f64) -> DVec3 {
        DVec3::new(self.next(), self.next(), self.next()) * 2.0 * s - DVec3::splat(s)
    }
}

/// Spheres, rotated boxes and tori (so some unions have a member
/// table and some do not), optionally with a ground plane.
fn scene(n: usize, kinds: usize, plane: bool, rng: &mut Rng) -> Shape {
    let r = 0.6 / (n as f64).cbrt();
    let mut members: Vec<Arc<Shape>> = (0..n)
        .map(|k| {
            let c = rng.v(1.0);
            Arc::new(match k % kinds {
                0 => Sphere {
                    center: c.into(),
                    radius: (r * (0.3 + rng.next())).into(),
                }
                .into(),
                1 => Shape::Rotate {
                    shape: Arc::new(
                        Cuboid {
                            center: c.into(),
                            size: (DVec3::splat(r) + rng.v(r * 0.5).abs()).into(),
                        }
                        .into(),
                    ),
                    axis: rng.v(1.0).normalize(),
                    angle: (rng.next() * 3.0).into(),
                },
                _ => Torus {
                    center: c.into(),
                    major: r.into(),
                    minor: (r * 0.3).into(),
                    axis: sdfl_stdlib::sdf::Axis::Y,
                }
                .into(),
            })
        })
        .collect();
    if plane {
        members.push(Arc::new(
            Plane {
                normal: DVec3::Y.into(),
                height: (-1.2).into(),
            }
            .into(),
        ));
    }
    Shape::Union(members)
}

/// Only tracing culls per tile: a scene lowered for distance queries
/// holds no second lowering of its union, and answers the same.
#[test]
fn point_queries_lower_the_union_once() {
    let shape = scene(6, 3, false, &mut Rng(3));
    let traced = Lowered::new(&shape, LowerOptions::default());
    let queried = Lowered::new(&shape, LowerOptions::point_queries());
    assert!(
        traced.tile_union.is_some(),
        "a small plain union is lowered again for tiles"
    );
    assert!(queried.tile_union.is_none() && !queried.tiles);
    let mut rng = Rng(4);
    for _ in 0..200 {
        let p = Vec3A::from(rng.v(1.5).as_vec3());
        assert_eq!(traced.dist(p).to_bits(), queried.dist(p).to_bits());
    }
}

fn settings(footprint: f32) -> TraceSettings {
    TraceSettings {
        near: 0.0,
        far: 12.0,
        max_steps: 128,
        epsilon: 1e-4,
        footprint,
        relax: footprint > 0.0,
        lipschitz: 1.0,
    }
}

/// For random tiles of random views: the BVH walk keeps exactly the
/// members a flat test keeps; no dropped member comes within the
/// margin of any sampled point of any ray of the tile (brute force
/// along rays through the tile's corners, edges and inside); and where
/// the whole scene is within the margin of a surface, the tile's
/// distance equals it.
#[test]
fn tiles_never_drop_a_member_near_their_rays() {
    let mut rng = Rng(7);
    let mut dropped_checked = 0usize;
    for (n, kinds, plane) in [
        (10, 1, false),
        (40, 1, false),
        (300, 1, false),
        (60, 3, false),
        (30, 2, true),
    ] {
        let shape = scene(n, kinds, plane, &mut rng);
        let lowered = Lowered::new(&shape, LowerOptions::default());
        for view in 0..6 {
            let eye = rng.v(1.0).normalize() * (2.5 + 2.0 * rng.next());
            let eye = if view == 0 {
                DVec3::new(0.2, 0.1, 0.3)
            } else {
                eye
            };
            let cam = sdfl_stdlib::camera::Camera::look_at(eye, rng.v(0.3), DVec3::Y, 1.2);
            let axes = cam.axes();
            let footprint = if view % 2 == 0 { 0.0 } else { 2e-3 };
            let s = settings(footprint);
            let o: Vec3A = eye.as_vec3().into();
            let h = normal_step(Vec3A::splat(o.abs().max_element() + s.far));
            let margin = Margin::for_trace(&s, o, h, lowered.lipschitz);
            let tiles = lowered.tiles(o, margin);
            let u = tiles.union.expect("a union");
            for _ in 0..12 {
                let (x0, y0) = (rng.next() * 1.8 - 0.9, rng.next() * 1.8 - 0.9);
                let size = 0.01 + 0.1 * rng.next();
                let (x, y) = ((x0, x0 + size), (y0, y0 + size));
                let f = Frustum::new(o, axes, x, y);
                let tile = tiles.cull(&f);
                let flat: Vec<u32> = (0..u.boxes.len() as u32)
                    .filter(|m| {
                        let (c, h) = u.boxes[*m as usize];
                        f.may_meet(c, h, &margin)
                    })
                    .collect();
                let mut kept = tile.members().map(<[u32]>::to_vec);
                if let Some(k) = kept.as_mut() {
                    k.sort_unstable();
                    assert_eq!(*k, flat, "n {n}: the BVH walk and the flat test differ");
                }
                assert_eq!(tile.is_empty(), flat.is_empty() && u.unbounded.is_empty());
                for a in 0..5 {
                    for b in 0..5 {
                        let xs = x.0 + (x.1 - x.0) * a as f64 / 4.0;
                        let ys = y.0 + (y.1 - y.0) * b as f64 / 4.0;
                        let d: Vec3A = (axes.0 * xs + axes.1 * ys + axes.2)
                            .normalize()
                            .as_vec3()
                            .into();
                        for k in 0..600 {
                            let t = s.far * k as f32 / 599.0;
                            let p = o + d * t;
                            for m in (0..u.boxes.len() as u32).filter(|m| !flat.contains(m)) {
                                let dist = u.members[m as usize].dist(p);
                                assert!(
                                    dist > margin.abs + 2.0 * footprint * t,
                                    "n {n}: dropped member {m} is {dist} from a ray at t {t}"
                                );
                                dropped_checked += 1;
                            }
                            if kept.is_some() && lowered.root.dist(p) < margin.abs {
                                assert_eq!(tile.dist(p), lowered.root.dist(p), "n {n} at {p}");
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(dropped_checked > 100_000, "only {dropped_checked} checks");
}

/// A ray's entry into a box: through faces, along a face, from inside,
/// and past it.
#[test]
fn rays_enter_boxes_where_they_cross_them() {
    let (lo, hi) = (Vec3A::splat(-1.0), Vec3A::splat(1.0));
    let o = Vec3A::new(0.0, 0.0, -5.0);
    assert_eq!(enter(o, Vec3A::Z, lo, hi), Some((4.0, 6.0)));
    // Along the face x = 1: inside (a tiny component stands in for 0).
    let (t_in, _) = enter(Vec3A::new(1.0, 0.0, -5.0), Vec3A::Z, lo, hi).expect("on a face");
    assert_eq!(t_in, 4.0);
    let (t_in, t_out) = enter(Vec3A::ZERO, Vec3A::X, lo, hi).expect("inside");
    assert!(t_in < 0.0 && t_out == 1.0);
    assert_eq!(enter(Vec3A::new(2.0, 0.0, -5.0), Vec3A::Z, lo, hi), None);
}
