//! The invariant BVH culling relies on: `distance(p) ≥ box.signed_distance(p)`
//! for every shape and point, on random shape trees.

use std::sync::Arc;

use glam::DVec3;
use proptest::prelude::*;
use sdfl_stdlib::shape::*;

fn axis() -> impl Strategy<Value = Axis> {
    prop_oneof![Just(Axis::X), Just(Axis::Y), Just(Axis::Z)]
}

fn v3(r: f64) -> impl Strategy<Value = DVec3> {
    (-r..r, -r..r, -r..r).prop_map(|(x, y, z)| DVec3::new(x, y, z))
}

/// A uniform `0..1` generator from a seed.
fn uniform(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Every registered primitive with bounds (not planes), drawn from its
/// declared ranges: a new primitive joins these tests by being declared.
fn leaf() -> impl Strategy<Value = Shape> {
    let bounded: Vec<usize> = (0..Primitive::SPECS.len())
        .filter(|&k| Primitive::random(k, &mut uniform(1)).bounds().is_some())
        .collect();
    (prop::sample::select(bounded), any::<u64>())
        .prop_map(|(k, seed)| Shape::Prim(Primitive::random(k, &mut uniform(seed))))
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
            (a(), v3(0.5)).prop_map(|(x, h)| Shape::Elongate(x, h.abs().into())),
            // Limited only: an infinite repetition has no bounds.
            (a(), v3(2.0), (0u32..4, 0u32..4, 0u32..4)).prop_map(|(x, s, (i, j, k))| {
                Shape::Repeat {
                    shape: x,
                    spacing: (s.abs() + DVec3::splat(0.3)).into(),
                    count: [i + 1, j + 1, k + 1],
                }
            }),
            (a(), axis()).prop_map(|(x, ax)| Shape::Mirror(x, ax)),
            (a(), -3.0f64..3.0).prop_map(|(x, k)| Shape::Twist(x, k.into())),
            (a(), -2.0f64..2.0).prop_map(|(x, k)| Shape::Bend(x, k.into())),
            (a(), v3(1.0))
                .prop_map(|(x, s)| Shape::ScaleXyz(x, (s.abs() + DVec3::splat(0.2)).into())),
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

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    /// Sphere tracing steps `d / L`: no two points may differ in value by
    /// more than `L` times their distance (a sampled Lipschitz check, which
    /// also covers the region borders of twists and bends).
    #[test]
    fn values_change_at_most_by_the_lipschitz_constant(
        shape in tree(),
        pairs in prop::collection::vec((v3(3.0), v3(0.3)), 32),
    ) {
        let l = shape.lipschitz();
        for (p, dp) in pairs {
            let (a, b) = (shape.distance(p), shape.distance(p + dp));
            prop_assert!(
                (a - b).abs() <= l * dp.length() * (1.0 + 1e-9) + 1e-9,
                "{}: |{a} - {b}| > {l}·{} at {p}", shape.name(), dp.length()
            );
        }
    }

    /// An exact shape's value is the distance: `|f(p) − f(q)| ≤ |p − q|`,
    /// so the same check with `L = 1` holds for everything marked exact.
    #[test]
    fn exact_shapes_are_1_lipschitz(shape in tree(), pairs in prop::collection::vec((v3(3.0), v3(0.3)), 16)) {
        if shape.exactness() == Exactness::Exact {
            for (p, dp) in pairs {
                let (a, b) = (shape.distance(p), shape.distance(p + dp));
                prop_assert!((a - b).abs() <= dp.length() + 1e-9, "{} at {p}", shape.name());
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]
    /// A repetition of a shape whose value is only a bound stays below the
    /// distance: below the least, over every copy (brute force), of the
    /// larger of the copy's own bound and its box's signed distance (both
    /// at most that copy's signed distance), so negative inside any copy.
    #[test]
    fn repeated_bounds_stay_below_every_copy(
        child in tree(),
        spacing in v3(1.5),
        count in (1u32..5, 1u32..4, 1u32..5),
        points in prop::collection::vec(v3(4.0), 16),
        near in prop::collection::vec(v3(0.3), 8),
    ) {
        let Some(b) = child.repeated_as_bound() else { return Ok(()) };
        let spacing = spacing.abs() + DVec3::splat(0.2);
        let count = [count.0, count.1, count.2];
        let child = Arc::new(child);
        let shape = Shape::Repeat { shape: child.clone(), spacing: spacing.into(), count };
        let copies = |i: usize| (0..count[i]).map(move |k| k as f64 - (count[i] as f64 - 1.0) * 0.5);
        // Points near the copies' centres too, where the value is negative.
        let centre = b.center();
        let near = near.into_iter().map(|d| centre + d + DVec3::new(1.0, 0.0, 0.0) * spacing.x * 0.5 * ((count[0] + 1) % 2) as f64);
        for p in points.into_iter().chain(near) {
            let mut brute = f64::INFINITY;
            for kx in copies(0) {
                for ky in copies(1) {
                    for kz in copies(2) {
                        let q = p - DVec3::new(kx, ky, kz) * spacing;
                        let gap = (b.min - q).max(q - b.max);
                        let boxed = if gap.max_element() > 0.0 {
                            gap.max(DVec3::ZERO).length()
                        } else {
                            gap.max_element()
                        };
                        brute = brute.min(child.distance(q).max(boxed));
                    }
                }
            }
            let d = shape.distance(p);
            prop_assert!(d <= brute + 1e-9, "at {p}: {d} above {brute}");
        }
    }
}

/// An infinite repetition has no bounds (unions keep it out of their BVH
/// and never cull it); a limited one is bounded by its end copies.
#[test]
fn infinite_repeat_is_unbounded() {
    let child = Arc::new(Shape::from(Sphere {
        center: DVec3::new(0.1, 0.0, 0.0).into(),
        radius: 0.3.into(),
    }));
    let r = |count| Shape::Repeat {
        shape: child.clone(),
        spacing: DVec3::new(1.0, 0.0, 1.5).into(),
        count,
    };
    assert_eq!(r([0, 1, 0]).bounds(), None);
    assert_eq!(r([3, 1, 0]).bounds(), None);
    let b = r([3, 1, 2]).bounds().unwrap();
    assert!(
        (b.min - DVec3::new(-1.2, -0.3, -1.05)).length() < 1e-12,
        "{b:?}"
    );
    assert!(
        (b.max - DVec3::new(1.4, 0.3, 1.05)).length() < 1e-12,
        "{b:?}"
    );
}
