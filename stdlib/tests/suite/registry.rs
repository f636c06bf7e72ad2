//! Every declared primitive, walked through the registry
//! (`Primitive::SPECS`): its bounds and Lipschitz constant hold, an exact
//! one is a distance, its built-in has the declared signature, and every
//! trainable argument is visited. A new primitive is tested by being
//! declared.

use glam::DVec3;
use sdfl_stdlib::shape::*;
use sdfl_stdlib::StdEnv;

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

fn point(rng: &mut dyn FnMut() -> f64, r: f64) -> DVec3 {
    DVec3::new(rng() * 2.0 - 1.0, rng() * 2.0 - 1.0, rng() * 2.0 - 1.0) * r
}

/// Random instances of every kind, with random points around them (near
/// the surface and far).
fn each_kind(mut f: impl FnMut(&PrimSpec, &Shape, &mut dyn FnMut() -> f64)) {
    for (k, spec) in Primitive::SPECS.iter().enumerate() {
        let mut rng = uniform(7 + k as u64);
        for _ in 0..30 {
            let s = Shape::Prim(Primitive::random(k, &mut rng));
            assert_eq!(s.name(), spec.name);
            f(spec, &s, &mut rng);
        }
    }
}

#[test]
fn every_primitive_keeps_its_bounds_and_lipschitz_constant() {
    each_kind(|spec, s, rng| {
        let b = s.bounds();
        for i in 0..300 {
            let p = point(rng, if i % 2 == 0 { 1.5 } else { 6.0 });
            let d = s.distance(p);
            assert!(d.is_finite(), "{}: {d} at {p}", spec.name);
            if let Some(b) = b {
                let bd = b.signed_distance(p);
                assert!(
                    d >= bd - 1e-9,
                    "{}: {d} below its box's {bd} at {p}",
                    spec.name
                );
            }
            let q = p + point(rng, if i % 3 == 0 { 1e-3 } else { 0.5 });
            let (dq, l) = (s.distance(q), spec.lipschitz);
            assert!(
                (d - dq).abs() <= l * (p - q).length() * (1.0 + 1e-9) + 1e-12,
                "{}: |{d} - {dq}| over {} times |p - q| ({p}, {q})",
                spec.name,
                l
            );
        }
    });
}

/// No primitive's value overstates the distance to its surface: the ball
/// of radius `|d(p)|` around `p` holds no point on the other side (an exact
/// value or a bound alike; what sphere tracing and culling rely on).
#[test]
fn no_primitive_overstates_its_distance() {
    each_kind(|spec, s, rng| {
        for _ in 0..40 {
            let p = point(rng, 1.5);
            let d = s.distance(p);
            for _ in 0..150 {
                let u = point(rng, 1.0).normalize_or(DVec3::X);
                let q = p + u * d.abs() * (0.9 + 0.0999 * rng());
                let e = s.distance(q);
                assert!(
                    e * d.signum() >= -1e-9,
                    "{}: {e} at {q}, within {d} of {p}",
                    spec.name
                );
            }
        }
    });
}

/// An exact primitive's value is a distance: its gradient has length 1
/// and the point it leads to, `p − d·∇d`, lies on the surface. Points on
/// the medial axis (where the gradient jumps) are skipped.
#[test]
fn exact_primitives_are_distances() {
    each_kind(|spec, s, rng| {
        if spec.exactness != Exactness::Exact {
            return;
        }
        let grad = |p: DVec3, h: f64| {
            let e = |v: DVec3| (s.distance(p + v * h) - s.distance(p - v * h)) / (2.0 * h);
            DVec3::new(e(DVec3::X), e(DVec3::Y), e(DVec3::Z))
        };
        let mut checked = 0;
        for _ in 0..200 {
            let p = point(rng, 1.5);
            let (g, g2) = (grad(p, 1e-6), grad(p, 4e-6));
            if (g - g2).length() > 1e-4 {
                continue;
            }
            checked += 1;
            let d = s.distance(p);
            assert!(
                (g.length() - 1.0).abs() < 1e-4,
                "{}: |∇d| = {} at {p}",
                spec.name,
                g.length()
            );
            let on = p - g * d;
            let e = s.distance(on);
            assert!(
                e.abs() <= 1e-5 * (1.0 + d.abs()),
                "{}: {e} at p − d·∇d = {on} (p = {p}, d = {d})",
                spec.name
            );
        }
        assert!(checked > 50, "{}: only {checked} smooth points", spec.name);
    });
}

/// Each primitive's built-in has its declared arguments, in order (a
/// built-in may take more, for another form of the same shape), with their
/// defaults and docs.
#[test]
fn every_primitive_is_a_builtin_with_its_declared_signature() {
    use sdfl_lang::types::Env;
    let env = StdEnv::get();
    for spec in Primitive::SPECS {
        let sig = env
            .function(spec.name)
            .unwrap_or_else(|| panic!("{}: no built-in", spec.name));
        assert!(sig.doc.starts_with(spec.doc), "{}", spec.name);
        let mut params = sig.params.iter();
        for a in spec.args {
            let p = params
                .find(|p| p.name == a.name)
                .unwrap_or_else(|| panic!("{}.{}: missing or out of order", spec.name, a.name));
            assert_eq!(p.default, a.default, "{}.{}", spec.name, a.name);
            assert_eq!(p.doc, a.doc, "{}.{}", spec.name, a.name);
        }
    }
}

/// Every number a primitive takes, except fixed directions, is visited as a
/// parameter when it is one: none can be left out of training.
#[test]
fn every_trainable_argument_is_visited() {
    for (k, spec) in Primitive::SPECS.iter().enumerate() {
        let trainable = spec
            .args
            .iter()
            .filter(|a| !matches!(a.kind, ArgKind::Axis) && !matches!(a.check, Check::Direction))
            .count();
        let src = primitive_call(spec, k);
        let program = sdfl_stdlib::load(&sdfl_lang::SourceFile::new(
            "case.sdfl",
            format!(
                "let s = {src}\nrender r {{ scene: s, camera: look_at([0, 0, -3]), outputs: [image(\"o.png\")] }}"
            ),
        ))
        .unwrap_or_else(|e| panic!("{}: {src}: {e:?}", spec.name));
        let mut seen = 0;
        program.renders[0].scene.visit_params(&mut |_| seen += 1);
        assert_eq!(seen, trainable, "{}: {src}", spec.name);
    }
}

/// A call of the primitive with every trainable argument as `param(...)`,
/// at values drawn from its declared ranges.
fn primitive_call(spec: &PrimSpec, k: usize) -> String {
    let p = Primitive::random(k, &mut uniform(3));
    let num = |x: f64| format!("{x}");
    let vec = |v: DVec3| format!("[{}, {}, {}]", v.x, v.y, v.z);
    let args: Vec<String> = spec
        .args
        .iter()
        .zip(p.args())
        .map(|(a, v)| {
            let text = match (v, a.check) {
                (ArgValue::Axis(axis), _) => format!("\"{}\"", ["x", "y", "z"][axis.index()]),
                (ArgValue::Vector(v), Check::Direction) => vec(v.value),
                (ArgValue::Vector(v), _) => format!("param({})", vec(v.value)),
                (ArgValue::Scalar(x), _) => format!("param({})", num(x.value)),
            };
            format!("{}: {text}", a.name)
        })
        .collect();
    format!("{}({})", spec.name, args.join(", "))
}
