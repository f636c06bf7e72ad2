//! The invariant BVH culling relies on: `distance(p) ≥ box.signed_distance(p)`
//! for every shape and point, on random shape trees.

use std::sync::Arc;

use glam::DVec3;
use proptest::prelude::*;
use sdfl_stdlib::shape::Shape;

fn v3(r: f64) -> impl Strategy<Value = DVec3> {
    (-r..r, -r..r, -r..r).prop_map(|(x, y, z)| DVec3::new(x, y, z))
}

fn leaf() -> impl Strategy<Value = Shape> {
    prop_oneof![
        (v3(1.0), 0.05f64..1.0).prop_map(|(c, r)| Shape::Sphere {
            center: c.into(),
            radius: r.into()
        }),
        (v3(1.0), v3(1.0)).prop_map(|(c, s)| Shape::Box {
            center: c.into(),
            size: (s.abs() + DVec3::splat(0.05)).into()
        }),
        (v3(1.0), v3(1.0)).prop_map(|(c, s)| Shape::BoxFrame {
            center: c.into(),
            size: (s.abs() + DVec3::splat(0.3)).into(),
            thickness: 0.05.into()
        }),
        (v3(1.0), 0.3f64..1.0, 0.05f64..0.25).prop_map(|(c, a, b)| Shape::Torus {
            center: c.into(),
            major: a.into(),
            minor: b.into()
        }),
        (v3(1.0), 0.05f64..1.0).prop_map(|(c, s)| Shape::Octahedron {
            center: c.into(),
            size: s.into()
        }),
        (v3(1.0), 0.05f64..1.0, 0.0f64..0.6, 0.0f64..0.6).prop_map(|(c, h, b, t)| {
            Shape::CappedCone {
                center: c.into(),
                height: h.into(),
                bottom: (b + 0.01).into(),
                top: t.into(),
            }
        }),
        (v3(1.0), v3(1.0)).prop_map(|(c, r)| Shape::Ellipsoid {
            center: c.into(),
            radii: (r.abs() + DVec3::splat(0.02)).into()
        }),
        (v3(1.0), v3(1.0), 0.05f64..0.5).prop_map(|(a, b, r)| Shape::Capsule {
            a: a.into(),
            b: b.into(),
            radius: r.into()
        }),
        (v3(1.0), 0.05f64..1.0, 0.05f64..1.0).prop_map(|(c, r, h)| Shape::Cylinder {
            center: c.into(),
            radius: r.into(),
            height: h.into()
        }),
    ]
}

fn tree() -> impl Strategy<Value = Shape> {
    leaf().prop_recursive(4, 24, 4, |inner| {
        let a = || inner.clone().prop_map(Arc::new);
        prop_oneof![
            prop::collection::vec(a(), 1..4).prop_map(Shape::Union),
            prop::collection::vec(a(), 1..3).prop_map(Shape::Intersection),
            (a(), a()).prop_map(|(x, y)| Shape::Subtraction(x, y)),
            (a(), a(), 0.01f64..0.5).prop_map(|(x, y, k)| Shape::SmoothUnion(x, y, k.into())),
            (a(), a(), 0.01f64..0.5).prop_map(|(x, y, k)| Shape::SmoothIntersection(
                x,
                y,
                k.into()
            )),
            (a(), a(), 0.01f64..0.5).prop_map(|(x, y, k)| Shape::SmoothSubtraction(x, y, k.into())),
            (a(), v3(2.0)).prop_map(|(x, t)| Shape::Translate(x, t.into())),
            (a(), v3(1.0), -3.0f64..3.0).prop_map(|(x, ax, ang)| {
                let axis = if ax.length() > 1e-3 {
                    ax.normalize()
                } else {
                    DVec3::Z
                };
                Shape::Rotate {
                    shape: x,
                    axis,
                    angle: ang.into(),
                }
            }),
            (a(), 0.2f64..3.0).prop_map(|(x, s)| Shape::Scale(x, s.into())),
            (a(), 0.01f64..0.5).prop_map(|(x, r)| Shape::Round(x, r.into())),
            (a(), 0.01f64..0.5).prop_map(|(x, t)| Shape::Onion(x, t.into())),
            (a(), a()).prop_map(|(x, y)| Shape::Xor(x, y)),
            (a(), 0.01f64..0.2, 1.0f64..20.0).prop_map(|(x, amp, f)| Shape::Displace {
                shape: x,
                amplitude: amp.into(),
                frequency: f.into()
            }),
        ]
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]
    #[test]
    fn distance_is_at_least_the_box_distance(shape in tree(), points in prop::collection::vec(v3(4.0), 32)) {
        let b = shape.bounds().expect("no planes in these trees");
        for p in points {
            let d = shape.distance(p);
            let lb = b.signed_distance(p);
            prop_assert!(d >= lb - 1e-9, "{} at {p}: distance {d} < box bound {lb}", shape.name());
        }
    }
}
