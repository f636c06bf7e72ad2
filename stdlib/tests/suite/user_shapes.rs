//! User shapes (`sdf(f, ...)`): the compiled tape against the language's
//! own evaluation, interval bounds, derivatives, hard points.

use glam::DVec3;
use proptest::prelude::*;
use sdfl_stdlib::eval::globals_of;
use sdfl_stdlib::num::{Dual, V3};
use sdfl_stdlib::param::Fixed;
use sdfl_stdlib::shape::user::UserShape;
use sdfl_stdlib::shape::Shape;
use sdfl_stdlib::value::Value;

/// Functions written as users write them, with the arguments `sdf` and a
/// direct call pass: every construct the compiler knows.
const FNS: &[(&str, &str)] = &[
    (
        "fn f(p, major: 1, minor: 0.25) { length([length(p.xz) - major, p.y]) - minor }",
        "major: 0.8",
    ),
    (
        "fn f(p, b: [0.6, 0.4, 0.5], r: 0.1) { let q = abs(p) - b; length([max(q.x, 0), max(q.y, 0), max(q.z, 0)]) + min(max(q.x, max(q.y, q.z)), 0) - r }",
        "r: 0.05",
    ),
    (
        "fn f(p, h: [0.5, 0.7]) { let d = abs([length(p.xz), p.y]) - h; min(max(d.x, d.y), 0) + length([max(d.x, 0), max(d.y, 0)]) }",
        "",
    ),
    (
        "fn f(p, k: 2) { let c = cos(k * p.y); let s = sin(k * p.y); let q = [c * p.x - s * p.z, s * p.x + c * p.z, p.y]; length(q.xz) - 0.5 + 0.1 * q.y }",
        "k: 1.5",
    ),
    (
        "fn f(p, t: 0.1) { abs(sin(p.x * 4) * cos(p.y * 4) + sin(p.y * 4) * cos(p.z * 4) + sin(p.z * 4) * cos(p.x * 4)) / 4 - t }",
        "",
    ),
    (
        "fn g(v, s) { dot(v, v) * s } fn f(p, a: [1, 2, 3]) { let q = mix(p, a, 0.25); let side = if q.x > 0.2 { q.y } else { -q.z }; clamp(g(q.zy, 0.5), 0.1, 2) + side + mod(p.x, 0.7) + sign(p.z) * fract(p.y) - floor(p.x * 2) / 8 }",
        "",
    ),
    (
        "fn f(p) { let n = normalize(p); dot(n, [0, 1, 0]) * 0.2 + length(p) - 1 + (p.x ^ 2) * 0.1 + cross(p, [1, 0, 0]).y + tan(p.x * 0.3) + exp(p.y * 0.2) + sqrt(abs(p.z)) + radians(p.x) + (p.y % 0.5) }",
        "",
    ),
];

/// The user shape of `fn` source `f` with `args`, in a box of half-size 1.5.
fn shape_of(f: &str, args: &str) -> UserShape {
    let src = format!("{f}\nlet s = sdf(f, bound: 1.5, {args})");
    let globals = globals_of(&src).unwrap_or_else(|d| panic!("{src}: {d:?}"));
    match &globals["s"] {
        Value::Shape(s) => match &**s {
            Shape::User(u) => (**u).clone(),
            other => panic!("not a user shape: {other:?}"),
        },
        other => panic!("not a shape: {other:?}"),
    }
}

/// `f(p, args)` evaluated by the language at each point.
fn direct(f: &str, args: &str, points: &[DVec3]) -> Vec<f64> {
    let sep = if args.is_empty() { "" } else { ", " };
    let mut src = f.to_string();
    for (i, p) in points.iter().enumerate() {
        src += &format!(
            "\nlet v{i} = f([{:?}, {:?}, {:?}]{sep}{args})",
            p.x, p.y, p.z
        );
    }
    let globals = globals_of(&src).unwrap_or_else(|d| panic!("{src}: {d:?}"));
    (0..points.len())
        .map(|i| match &globals[&format!("v{i}")] {
            Value::Number(x) => *x,
            other => panic!("not a number: {other:?}"),
        })
        .collect()
}

fn tape_at(u: &UserShape, p: DVec3) -> f64 {
    u.tape.eval(V3::new(p.x, p.y, p.z), &u.arg_values())
}

fn point() -> impl Strategy<Value = DVec3> {
    (-1.5f64..1.5, -1.5f64..1.5, -1.5f64..1.5).prop_map(|(x, y, z)| DVec3::new(x, y, z))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8))]

    #[test]
    fn the_tape_equals_the_languages_evaluation(points in prop::collection::vec(point(), 16)) {
        for (f, args) in FNS {
            let u = shape_of(f, args);
            let want = direct(f, args, &points);
            for (p, w) in points.iter().zip(want) {
                let got = tape_at(&u, *p);
                prop_assert!((got - w).abs() <= 1e-12 * (1.0 + w.abs()), "{f} at {p}: tape {got}, direct {w}");
            }
        }
    }

    #[test]
    fn interval_bounds_hold_every_sample_and_the_lipschitz_bound_every_pair(
        a in point(), b in point(), lo in point(), hi in point()
    ) {
        for (f, args) in FNS {
            let u = shape_of(f, args);
            // A sub-box of the bound, and the whole bound.
            for (l, h) in [(lo.min(hi), lo.max(hi)), (u.bound.min, u.bound.max)] {
                let an = u.tape.analyse(l, h, &u.arg_values());
                prop_assert!(an.unbounded.is_none(), "{f}");
                let (a, b) = (a.clamp(l, h), b.clamp(l, h));
                for p in [a, b, (a + b) * 0.5] {
                    let v = tape_at(&u, p);
                    prop_assert!(an.range.0 - 1e-9 <= v && v <= an.range.1 + 1e-9, "{f}: {v} outside {:?} at {p}", an.range);
                }
                if an.lipschitz.is_finite() {
                    let d = (tape_at(&u, a) - tape_at(&u, b)).abs();
                    prop_assert!(d <= an.lipschitz * a.distance(b) * (1.0 + 1e-9) + 1e-12, "{f}: L {} broken", an.lipschitz);
                }
            }
            // The shape as every evaluator sees it: never below its box's
            // distance, and 1-Lipschitz where a bound was derived (where
            // none was, a distance is assumed, as SDF tools do: the
            // `sqrt(abs(p.z))` function is steeper than 1 near z = 0).
            let far = a * 7.0;
            let d = u.sample(far.into(), &Fixed);
            prop_assert!(d >= u.bound.signed_distance(far) - 1e-12, "{f}: {d} inside its box's distance at {far}");
            let whole = u.tape.analyse(u.bound.min, u.bound.max, &u.arg_values());
            if whole.lipschitz.is_finite() {
                let (da, db) = (u.sample(a.into(), &Fixed), u.sample(far.into(), &Fixed));
                prop_assert!((da - db).abs() <= a.distance(far) * (1.0 + 1e-9) + 1e-12, "{f}: {da} at {a}, {db} at {far}");
            }
        }
    }

    #[test]
    fn derivatives_match_finite_differences(p in point()) {
        for (f, args) in FNS {
            let u = shape_of(f, args);
            let vals = u.arg_values();
            // Point and arguments as one dual vector: 3 + up to 4 tangents.
            type D = Dual<f64, 8>;
            let n = vals.len().min(5);
            let q = V3::new(D::seed(p.x, 0), D::seed(p.y, 1), D::seed(p.z, 2));
            let args: Vec<D> = vals
                .iter()
                .enumerate()
                .map(|(i, &x)| if i < n { D::seed(x, 3 + i) } else { D::constant(x) })
                .collect();
            let g = u.tape.eval(q, &args);
            let h = 1e-6;
            let at = |p: DVec3, vals: &[f64]| u.tape.eval(V3::new(p.x, p.y, p.z), vals);
            for k in 0..3 + n {
                let (mut pp, mut pm, mut vp, mut vm) = (p, p, vals.clone(), vals.clone());
                if k < 3 {
                    pp[k] += h;
                    pm[k] -= h;
                } else {
                    vp[k - 3] += h;
                    vm[k - 3] -= h;
                }
                let (fp, fm) = (at(pp, &vp), at(pm, &vm));
                // Across a kink or a step the difference quotient is no
                // derivative: compared only where the function is smooth
                // (both one-sided quotients agree).
                let f0 = at(p, &vals);
                let (right, left) = ((fp - f0) / h, (f0 - fm) / h);
                if (right - left).abs() > 1e-3 * (1.0 + right.abs()) {
                    continue;
                }
                let fd = (fp - fm) / (2.0 * h);
                prop_assert!((g.d[k] - fd).abs() <= 1e-5 * (1.0 + fd.abs()), "{f}: d/d{k} {} vs {fd} at {p}", g.d[k]);
            }
        }
    }
}

#[test]
fn hard_points_give_finite_values_and_derivatives() {
    let u = shape_of(
        "fn f(p) { let n = normalize(p); length(p) - 1 + 0.1 * n.y + length(p.xz) * 0 }",
        "",
    );
    type D = Dual<f64, 3>;
    for p in [
        DVec3::ZERO,
        DVec3::new(0.0, 1.0, 0.0),
        DVec3::splat(1e30),
        DVec3::splat(-1e300),
    ] {
        let d = u.sample(p.into(), &Fixed);
        assert!(d.is_finite(), "{d} at {p}");
        let q = V3::new(D::seed(p.x, 0), D::seed(p.y, 1), D::seed(p.z, 2));
        let g = u.sample(q, &Fixed);
        assert!(
            g.v.is_finite() && g.d.iter().all(|x| x.is_finite()),
            "{g:?} at {p}"
        );
        let f = u.sample(V3::new(p.x as f32, p.y as f32, p.z as f32), &Fixed);
        assert!(f.is_finite(), "f32 {f} at {p}");
    }
}

#[test]
fn the_users_torus_equals_the_built_in_torus_inside_its_box() {
    let u = shape_of(
        "fn f(p, major: 1, minor: 0.25) { length([length(p.xy) - major, p.z]) - minor }",
        "",
    );
    let torus = sdfl_stdlib::shape::Torus {
        major: 1.0.into(),
        minor: 0.25.into(),
        center: DVec3::ZERO.into(),
        axis: sdfl_stdlib::shape::Axis::Z,
    };
    let t: Shape = torus.into();
    // Derived: exactly 1 (the lengths' Jacobians have disjoint coordinates).
    assert_eq!(u.lipschitz, 1.0);
    for p in [
        DVec3::new(1.0, 0.0, 0.3),
        DVec3::new(0.2, -0.4, 0.1),
        DVec3::new(-1.2, 0.3, -0.2),
    ] {
        let a = u.sample(p.into(), &Fixed);
        assert!(
            (a - t.distance(p)).abs() < 1e-12,
            "{a} vs {} at {p}",
            t.distance(p)
        );
    }
}

#[test]
fn a_declared_lipschitz_constant_divides_the_value() {
    let src = "fn f(p) { 3 * (length(p) - 1) }\nlet a = sdf(f, bound: 1.5)\nlet b = sdf(f, bound: 1.5, lipschitz: 6)";
    let g = globals_of(src).expect("loads");
    let user = |k: &str| match &g[k] {
        Value::Shape(s) => match &**s {
            Shape::User(u) => (**u).clone(),
            _ => unreachable!(),
        },
        _ => unreachable!(),
    };
    let (a, b) = (user("a"), user("b"));
    assert!((a.lipschitz - 3.0).abs() < 1e-12, "derived {}", a.lipschitz);
    assert_eq!(b.lipschitz, 6.0);
    let p = DVec3::new(0.5, 0.0, 0.0);
    assert!((a.sample(p.into(), &Fixed) + 0.5).abs() < 1e-12);
    assert!((b.sample(p.into(), &Fixed) + 0.25).abs() < 1e-12);
}

#[test]
fn baking_the_arguments_keeps_the_values() {
    for (f, args) in FNS {
        let u = shape_of(f, args);
        let baked = u.tape.bake(&u.arg_values());
        assert_eq!(baked.arg_count(), 0);
        assert!(baked.ops().len() <= u.tape.ops().len());
        for p in [DVec3::new(0.3, -0.2, 0.9), DVec3::new(-1.0, 0.5, 0.1)] {
            let a = tape_at(&u, p);
            let b = baked.eval(V3::new(p.x, p.y, p.z), &[]);
            assert!((a - b).abs() <= 1e-12 * (1.0 + a.abs()), "{f}: {a} vs {b}");
        }
    }
}
