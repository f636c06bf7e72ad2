//! One test suite run against every evaluator (naive min-union, BVH-culled
//! with the candidate grid): each must match the f64 reference
//! `Shape::distance` on random scenes, and the two must agree exactly where
//! the reference is exact.

use std::sync::Arc;

use glam::{DVec3, Vec3A};
use sdfl_runtime::{LowerOptions, Lowered};
use sdfl_stdlib::shape::*;

struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
    fn v3(&mut self, r: f64) -> DVec3 {
        DVec3::new(self.range(-r, r), self.range(-r, r), self.range(-r, r))
    }
}

fn primitive(rng: &mut Lcg) -> Shape {
    let c = rng.v3(2.0);
    match (rng.next() * 7.0) as u32 {
        0 => Shape::from(Sphere {
            center: c.into(),
            radius: rng.range(0.05, 0.4).into(),
        }),
        1 => Shape::from(Cuboid {
            center: c.into(),
            size: DVec3::new(
                rng.range(0.1, 0.6),
                rng.range(0.1, 0.6),
                rng.range(0.1, 0.6),
            )
            .into(),
        }),
        2 => Shape::from(BoxFrame {
            center: c.into(),
            size: DVec3::splat(rng.range(0.4, 0.8)).into(),
            thickness: 0.05.into(),
        }),
        3 => Shape::from(Torus {
            center: c.into(),
            major: rng.range(0.2, 0.4).into(),
            minor: rng.range(0.03, 0.1).into(),
            axis: Axis::Z,
        }),
        4 => Shape::from(Capsule {
            a: c.into(),
            b: (c + rng.v3(0.3)).into(),
            radius: rng.range(0.03, 0.2).into(),
        }),
        5 => Shape::from(Cylinder {
            center: c.into(),
            radius: rng.range(0.05, 0.3).into(),
            height: rng.range(0.1, 0.6).into(),
            axis: Axis::Z,
        }),
        // Fields evaluate in the order written: the random draws keep their order.
        _ => Shape::Rotate {
            shape: Arc::new(Shape::from(Cuboid {
                center: DVec3::ZERO.into(),
                size: DVec3::splat(rng.range(0.1, 0.5)).into(),
            })),
            axis: rng.v3(1.0).normalize(),
            angle: rng.range(-3.0, 3.0).into(),
        },
    }
}

fn random_scene(seed: u64, n: usize, with_bounds_ops: bool) -> Shape {
    let mut rng = Lcg(seed);
    let mut members: Vec<Arc<Shape>> = (0..n).map(|_| Arc::new(primitive(&mut rng))).collect();
    if with_bounds_ops {
        // Mix in combinators and transforms that make members bounds.
        let a = Arc::new(primitive(&mut rng));
        let b = Arc::new(primitive(&mut rng));
        members.push(Arc::new(Shape::SmoothUnion(
            a.clone(),
            b.clone(),
            0.2.into(),
        )));
        members.push(Arc::new(Shape::Subtraction(a.clone(), b.clone())));
        members.push(Arc::new(Shape::Intersection(vec![a.clone(), b])));
        members.push(Arc::new(Shape::Displace {
            shape: a.clone(),
            amplitude: 0.03.into(),
            frequency: 8.0.into(),
        }));
        members.push(Arc::new(Shape::Scale(
            Arc::new(Shape::Translate(a, rng.v3(1.0).into())),
            1.7.into(),
        )));
        // A nested union under a transform gets flattened into the BVH.
        let inner: Vec<Arc<Shape>> = (0..20).map(|_| Arc::new(primitive(&mut rng))).collect();
        members.push(Arc::new(Shape::Translate(
            Arc::new(Shape::Union(inner)),
            DVec3::new(0.3, 0.0, -0.2).into(),
        )));
        // Offsets, shells, xor and an ellipsoid (drawn last, so the draws
        // above keep their order).
        let (c, d) = (Arc::new(primitive(&mut rng)), Arc::new(primitive(&mut rng)));
        members.push(Arc::new(Shape::Round(c.clone(), 0.07.into())));
        members.push(Arc::new(Shape::Onion(d.clone(), 0.03.into())));
        members.push(Arc::new(Shape::Xor(c, d)));
        members.push(Arc::new(Shape::from(Ellipsoid {
            center: rng.v3(2.0).into(),
            radii: DVec3::new(0.5, 0.1, 0.2).into(),
        })));
        members.push(Arc::new(Shape::from(Octahedron {
            center: rng.v3(2.0).into(),
            size: 0.3.into(),
        })));
        members.push(Arc::new(Shape::from(CappedCone {
            center: rng.v3(2.0).into(),
            height: 0.5.into(),
            bottom: 0.25.into(),
            top: 0.05.into(),
            axis: Axis::Y,
        })));
        // The newer primitives along every axis, and the domain operators
        // (each lowered as a warp node, some under transforms).
        members.push(Arc::new(Shape::from(RoundCone {
            center: rng.v3(2.0).into(),
            bottom: 0.2.into(),
            top: 0.08.into(),
            height: 0.4.into(),
            axis: Axis::X,
        })));
        members.push(Arc::new(Shape::from(HexPrism {
            center: rng.v3(2.0).into(),
            radius: 0.2.into(),
            height: 0.3.into(),
            axis: Axis::Y,
        })));
        members.push(Arc::new(Shape::from(TriPrism {
            center: rng.v3(2.0).into(),
            side: 0.4.into(),
            height: 0.2.into(),
            axis: Axis::Z,
        })));
        members.push(Arc::new(Shape::from(Link {
            center: rng.v3(2.0).into(),
            length: 0.3.into(),
            major: 0.15.into(),
            minor: 0.04.into(),
            axis: Axis::X,
        })));
        let (e, f) = (Arc::new(primitive(&mut rng)), Arc::new(primitive(&mut rng)));
        members.push(Arc::new(Shape::Elongate(
            e.clone(),
            DVec3::new(0.2, 0.0, 0.1).into(),
        )));
        members.push(Arc::new(Shape::Mirror(f.clone(), Axis::X)));
        members.push(Arc::new(Shape::Translate(
            Arc::new(Shape::Twist(e.clone(), 2.0.into())),
            rng.v3(1.0).into(),
        )));
        members.push(Arc::new(Shape::Scale(
            Arc::new(Shape::Bend(f.clone(), 1.5.into())),
            0.8.into(),
        )));
        members.push(Arc::new(Shape::ScaleXyz(
            e,
            DVec3::new(1.5, 0.6, 1.0).into(),
        )));
        let small: Vec<Arc<Shape>> = (0..3)
            .map(|_| {
                Arc::new(Shape::from(Sphere {
                    center: rng.v3(0.3).into(),
                    radius: 0.1.into(),
                }))
            })
            .collect();
        members.push(Arc::new(Shape::Repeat {
            shape: Arc::new(Shape::Union(small)),
            spacing: DVec3::new(0.7, 0.0, 0.5).into(),
            count: [5, 1, 3],
        }));
        // A child whose value is only a bound, its copies overlapping: the
        // repetition's continuous terms in both evaluators.
        let blend = Shape::SmoothUnion(
            Arc::new(primitive(&mut rng)),
            Arc::new(primitive(&mut rng)),
            0.3.into(),
        );
        members.push(Arc::new(Shape::Repeat {
            shape: Arc::new(blend),
            spacing: DVec3::new(0.4, 0.9, 0.0).into(),
            count: [4, 3, 1],
        }));
        // Unbounded: kept out of the BVH, never culled.
        members.push(Arc::new(Shape::Translate(
            Arc::new(Shape::Repeat {
                shape: f,
                spacing: DVec3::new(1.3, 0.0, 1.1).into(),
                count: [0, 1, 0],
            }),
            DVec3::new(0.0, -3.0, 0.0).into(),
        )));
    }
    Shape::Union(members)
}

fn evaluators(shape: &Shape) -> Vec<(&'static str, Lowered)> {
    vec![
        (
            "naive",
            Lowered::new(
                shape,
                LowerOptions {
                    cull: false,
                    ..Default::default()
                },
            ),
        ),
        ("culled", Lowered::new(shape, LowerOptions::default())),
        (
            "culled-bvh-everywhere",
            Lowered::new(
                shape,
                LowerOptions {
                    cull: true,
                    bvh_threshold: 2,
                    ..Default::default()
                },
            ),
        ),
        // Lowered relative to a point away from the world origin (as for a
        // camera there): the same function of the world point.
        (
            "relative",
            Lowered::relative_to(shape, LowerOptions::default(), DVec3::new(2.5, -1.25, 3.0)),
        ),
        // Every member its own node (no packed unions): the per-point
        // evaluator as it was before packing.
        (
            "culled-unpacked",
            Lowered::new(
                shape,
                LowerOptions {
                    pack: false,
                    ..Default::default()
                },
            ),
        ),
    ]
}

fn check_scene(shape: &Shape, seed: u64) {
    let mut rng = Lcg(seed ^ 0x9e37);
    let evals = evaluators(shape);
    // Lowered relative to an origin, the culled scene reports the same
    // primitives at the same world centres.
    let (culled, relative) = (&evals[1].1, &evals[3].1);
    assert_eq!(culled.prims.len(), relative.prims.len());
    for (a, b) in culled.prims.iter().zip(&relative.prims) {
        assert!(
            (a.center - b.center).length() < 1e-9,
            "{} vs {}",
            a.center,
            b.center
        );
    }
    let points: Vec<DVec3> = (0..3000).map(|_| rng.v3(3.5)).collect();
    // The batched path (packs of 8 points) equals the per-point one.
    let pf: Vec<Vec3A> = points.iter().map(|p| p.as_vec3().into()).collect();
    for (name, e) in &evals {
        assert_batch_equals_points(name, e, &pf, false);
    }
    for &p in &points {
        let reference = shape.distance(p);
        let pf: Vec3A = p.as_vec3().into();
        for (name, e) in &evals {
            let d = e.dist(pf) as f64;
            let tol = 2e-5 * (1.0 + reference.abs() + p.length());
            assert!(
                (d - reference).abs() <= tol,
                "{name}: {d} vs reference {reference} at {p}"
            );
            let (did, id) = e.root.dist_id(e.from_world(pf));
            assert_eq!(did, e.dist(pf), "{name}: dist_id disagrees with dist");
            assert!(
                (id as usize) < e.prims.len(),
                "{name}: id {id} out of range"
            );
        }
    }
}

#[test]
fn large_unions_of_exact_primitives() {
    for (seed, n) in [(1, 5), (2, 40), (3, 300), (4, 2000)] {
        check_scene(&random_scene(seed, n, false), seed);
    }
}

#[test]
fn unions_with_bounds_transforms_and_nesting() {
    for (seed, n) in [(11, 10), (12, 100), (13, 600)] {
        check_scene(&random_scene(seed, n, true), seed);
    }
}

#[test]
fn planes_are_never_culled() {
    let mut rng = Lcg(5);
    let mut members: Vec<Arc<Shape>> = (0..100).map(|_| Arc::new(primitive(&mut rng))).collect();
    members.push(Arc::new(Shape::from(Plane {
        normal: DVec3::Y.into(),
        height: (-2.5).into(),
    })));
    check_scene(&Shape::Union(members), 5);
}

#[test]
fn ids_name_the_primitive_attaining_the_minimum() {
    let shape = random_scene(21, 200, false);
    let culled = Lowered::new(&shape, LowerOptions::default());
    let Shape::Union(members) = &shape else {
        unreachable!()
    };
    let mut rng = Lcg(77);
    for _ in 0..500 {
        let p = rng.v3(2.5);
        let (d, id) = culled.root.dist_id(p.as_vec3().into());
        let m = &members[0..];
        // The primitive with that id (lowering numbers leaves in order)
        // attains the minimum.
        let direct = m[id as usize].distance(p);
        assert!((direct - d as f64).abs() < 1e-4, "id {id}: {direct} vs {d}");
    }
}

#[test]
fn batch_matches_single_points() {
    let shape = random_scene(31, 500, true);
    let e = Lowered::new(&shape, LowerOptions::default());
    let mut rng = Lcg(8);
    let pts: Vec<Vec3A> = (0..1000).map(|_| rng.v3(3.0).as_vec3().into()).collect();
    let mut out = vec![0.0; pts.len()];
    e.eval_batch(&pts, &mut out);
    for (p, d) in pts.iter().zip(&out) {
        assert_eq!(*d, e.dist(*p));
    }
}

/// `eval_batch` equals `dist` point by point: bit for bit (up to the sign
/// of zero) when `exact`, else within 1e-6 relative (a culled union may
/// evaluate a batch against every member, whose minimum can differ from
/// the culled one by rounding far away), for a batch and for batches ending
/// inside a pack.
fn assert_batch_equals_points(name: &str, e: &Lowered, points: &[Vec3A], exact: bool) {
    let mut out = vec![f32::NAN; points.len()];
    e.eval_batch(points, &mut out);
    for (p, d) in points.iter().zip(&out) {
        let single = e.dist(*p);
        if exact {
            assert_eq!(*d, single, "{name}: batch vs single point at {p}");
        } else {
            assert!(
                (d - single).abs() <= 1e-6 * d.abs().max(single.abs()),
                "{name}: batch {d} vs single point {single} at {p}"
            );
        }
    }
    // Batches ending inside a pack (the remainder lanes repeat the last point).
    for len in [1, 3, 7, 9, 15, 17]
        .into_iter()
        .filter(|l| *l <= points.len())
    {
        let mut short = vec![f32::NAN; len];
        e.eval_batch(&points[..len], &mut short);
        assert_eq!(short, out[..len], "{name}: batch of {len}");
    }
}

/// A primitive of every declared kind (`kind` < `Primitive::SPECS.len()`)
/// drawn from its ranges and moved to a random place, and after them a
/// transformed leaf (not packed).
fn primitive_of_kind(rng: &mut Lcg, kind: usize) -> Shape {
    let c = rng.v3(2.0);
    if kind < Primitive::SPECS.len() {
        let mut p = Primitive::random(kind, &mut || rng.next());
        for pt in p.points_mut() {
            *pt += c;
        }
        return Shape::Prim(p);
    }
    Shape::Translate(
        Arc::new(Shape::from(Sphere {
            center: DVec3::ZERO.into(),
            radius: rng.range(0.05, 0.4).into(),
        })),
        c.into(),
    )
}

/// Every declared primitive in the evaluator suite: unions of it (plain,
/// culled, packed, relative to an origin), and under transforms, against
/// the f64 reference.
#[test]
fn every_primitive_agrees_with_the_reference() {
    let mut rng = Lcg(23);
    for kind in 0..Primitive::SPECS.len() {
        let members: Vec<Arc<Shape>> = (0..24)
            .map(|i| {
                let s = Arc::new(primitive_of_kind(&mut rng, kind));
                match i % 3 {
                    0 => s,
                    1 => Arc::new(Shape::Rotate {
                        shape: s,
                        axis: rng.v3(1.0).normalize(),
                        angle: rng.range(-3.0, 3.0).into(),
                    }),
                    _ => Arc::new(Shape::Scale(s, rng.range(0.5, 1.5).into())),
                }
            })
            .collect();
        check_scene(&Shape::Union(members), 100 + kind as u64);
    }
}

/// The tracer on every declared primitive: every ray from outside towards
/// a point inside a random instance hits, where the f64 reference is within
/// the hit tolerance of the surface.
#[test]
fn every_primitive_traces_to_its_surface() {
    use sdfl_runtime::trace::{sphere_trace, TraceSettings};
    let mut rng = Lcg(31);
    for (kind, spec) in Primitive::SPECS.iter().enumerate() {
        let mut hits = 0;
        for _ in 0..40 {
            let s = primitive_of_kind(&mut rng, kind);
            let l = Lowered::new(&s, LowerOptions::default());
            let settings = TraceSettings {
                near: 0.0,
                far: 40.0,
                max_steps: 512,
                epsilon: 1e-5,
                footprint: 0.0,
                relax: false,
                lipschitz: l.lipschitz,
            };
            // A point inside: every ray from outside towards it hits.
            let (lo, hi) = match s.bounds() {
                Some(b) => (b.min, b.max),
                None => {
                    let c = s.primitive_center().expect("a primitive");
                    (c - DVec3::ONE, c + DVec3::ONE)
                }
            };
            let target = (0..10_000)
                .map(|_| lo + (hi - lo) * DVec3::new(rng.next(), rng.next(), rng.next()))
                .find(|p| s.distance(*p) < 0.0)
                .expect("a point inside");
            let origin = target + rng.v3(1.0).normalize_or(DVec3::X) * 6.0;
            // A ray starting inside hits where it starts.
            if s.distance(origin) <= 0.0 {
                continue;
            }
            let dir = (target - origin).normalize();
            let h = sphere_trace(
                &*l.root,
                origin.as_vec3().into(),
                dir.as_vec3().into(),
                &settings,
            );
            assert!(h.hit, "{}: a ray towards {target} misses", spec.name);
            {
                hits += 1;
                let at = origin + dir * h.t as f64;
                let d = s.distance(at);
                assert!(
                    d.abs() <= 1e-4,
                    "{}: the ray stops {d} from the surface at {at}",
                    spec.name
                );
            }
        }
        assert!(hits >= 10, "{}: only {hits} rays start outside", spec.name);
    }
}

#[test]
fn packed_unions_of_one_kind_equal_the_per_point_path() {
    let mut rng = Lcg(41);
    for kind in 0..=Primitive::SPECS.len() {
        for n in [1, 2, 7, 8, 9, 15, 16, 17, 100, 200] {
            let members: Vec<Shape> = (0..n).map(|_| primitive_of_kind(&mut rng, kind)).collect();
            let shape = Shape::Union(members.iter().cloned().map(Arc::new).collect());
            // Hard cases: the centres themselves (zero vectors inside the
            // formulas), far and huge coordinates; then random points, a
            // count that leaves a partial pack.
            let mut points: Vec<Vec3A> = members
                .iter()
                .filter_map(|m| m.primitive_center())
                .map(|c| c.as_vec3().into())
                .collect();
            points.extend([
                Vec3A::ZERO,
                Vec3A::splat(1e6),
                Vec3A::new(-3e7, 2e7, 1e-30),
                Vec3A::new(1e-38, -1e-38, 0.0),
            ]);
            points.extend((0..1003).map(|_| Vec3A::from(rng.v3(4.0).as_vec3())));
            let packed = Lowered::new(&shape, LowerOptions::default());
            let unpacked = Lowered::new(
                &shape,
                LowerOptions {
                    pack: false,
                    ..Default::default()
                },
            );
            let name = format!("kind {kind}, {n} members");
            // Plain unions (below the BVH threshold) are exact.
            assert_batch_equals_points(&name, &packed, &points, n < 16);
            assert_batch_equals_points(&name, &unpacked, &points, n < 16);
            for p in &points {
                let (a, b) = (packed.dist(*p), unpacked.dist(*p));
                assert!(a.is_finite(), "{name}: {a} at {p}");
                assert!(
                    (a - b).abs() <= 1e-6 * a.abs().max(b.abs()),
                    "{name}: packed {a} vs unpacked {b} at {p}"
                );
                let (d, id) = packed.root.dist_id(*p);
                assert_eq!(d, a, "{name}: dist_id");
                let direct = members[id as usize].distance(p.as_dvec3());
                assert!(
                    (direct - d as f64).abs() <= 1e-4 * (1.0 + direct.abs()),
                    "{name}: id {id} gives {direct}, not {d}"
                );
            }
        }
    }
}

#[test]
fn degenerate_unions_stay_exact() {
    // Coincident copies (dropped when lowering), copies a hair apart (kept:
    // no bound separates them), and copies under different transforms or
    // materials, mixed with distinct members: culled equals naive.
    let mut rng = Lcg(41);
    let sphere = Arc::new(Shape::from(Sphere {
        center: DVec3::new(0.3, -0.2, 0.1).into(),
        radius: 0.6.into(),
    }));
    let mut members: Vec<Arc<Shape>> = vec![sphere.clone(); 300];
    members.extend((0..300).map(|i| {
        Arc::new(Shape::from(Cuboid {
            center: DVec3::new(i as f64 * 1e-9, 0.0, 0.0).into(),
            size: DVec3::splat(0.8).into(),
        }))
    }));
    members.extend((0..50).map(|_| Arc::new(Shape::Translate(sphere.clone(), DVec3::X.into()))));
    members.extend((0..50).map(|_| Arc::new(Shape::Scale(sphere.clone(), 0.5.into()))));
    members.extend((0..100).map(|_| Arc::new(primitive(&mut rng))));
    let shape = Shape::Union(members);
    check_scene(&shape, 41);
    // The repeats are lowered once each: 1 sphere, 300 boxes, the two
    // transformed spheres, 100 random primitives.
    let culled = Lowered::new(&shape, LowerOptions::default());
    assert_eq!(culled.prims.len(), 1 + 300 + 2 + 100);
    let naive = Lowered::new(
        &shape,
        LowerOptions {
            cull: false,
            ..Default::default()
        },
    );
    assert_eq!(naive.prims.len(), 800);
}

/// Primitives under a domain operator are lowered in the operator's frame;
/// their centres (the rainbow's `c`) are still reported in world space,
/// as the reference's for points near the original (copy at the origin).
#[test]
fn warped_primitives_keep_world_centres() {
    let ball = Arc::new(Shape::from(Sphere {
        center: DVec3::new(0.2, 0.1, 0.0).into(),
        radius: 0.3.into(),
    }));
    let shape = Shape::Translate(
        Arc::new(Shape::Scale(
            Arc::new(Shape::Twist(
                Arc::new(Shape::Translate(ball, DVec3::new(0.0, 0.0, 0.5).into())),
                0.7.into(),
            )),
            2.0.into(),
        )),
        DVec3::new(1.0, -1.0, 0.5).into(),
    );
    let l = Lowered::new(&shape, LowerOptions::default());
    assert_eq!(l.prims.len(), 1);
    let expected = DVec3::new(0.2, 0.1, 0.5) * 2.0 + DVec3::new(1.0, -1.0, 0.5);
    assert!(
        (l.prims[0].center - expected).length() < 1e-12,
        "{}",
        l.prims[0].center
    );
}
