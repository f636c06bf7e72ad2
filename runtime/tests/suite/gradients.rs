//! Gradient conformance: for every primitive, operator, transform, density
//! model and colour, the fused kernel's gradient of a batch of rendered
//! pixels' loss with respect to each parameter agrees with central finite
//! differences of the same loss in f64. Every declared primitive is a
//! case by being declared (`primitive_cases`, from the registry); the
//! operators, densities and colours are in `CASES`. Hard cases (β = 1e-4, grazing rays, points on a box's edge)
//! must give finite values and gradients.

use glam::DVec3;
use sdfl_lang::SourceFile;
use sdfl_runtime::train::fused::{
    loss_and_grad_f32, loss_and_grad_f64, loss_and_grad_scalar_f32, traced, Batch,
};
use sdfl_runtime::train::TrainModel;
use sdfl_runtime::volume::{camera_rays, ImageSize, Stratified};
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::shape::{ArgValue, Check, Primitive};
use sdfl_stdlib::value::{DensityKind, LastInterval};

/// Models, each with every argument that can be trained marked `param`.
const CASES: &[(&str, &str)] = &[
    ("sphere with a colour", "sdf_volume(sphere(param(0.9), center: param([0.1, -0.1, 0.2])), color: param([0.3, 0.5, 0.7]))"),
    ("union", "sdf_volume(union(sphere(param(0.5), center: [-0.5, 0, 0]), sphere(param(0.55), center: [0.5, 0.1, 0])))"),
    ("subtraction", "sdf_volume(subtraction(box(size: param([1.4, 1.2, 1.2])), sphere(param(0.7), center: [0.2, 0.1, -0.5])))"),
    ("smooth_union", "sdf_volume(smooth_union(sphere(0.6, center: [-0.4, 0, 0]), sphere(0.6, center: [0.4, 0.1, 0]), k: param(0.3)))"),
    ("smooth_intersection", "sdf_volume(smooth_intersection(sphere(0.8, center: [-0.3, 0, 0]), sphere(0.8, center: [0.3, 0.1, 0]), k: param(0.3)))"),
    ("smooth_subtraction", "sdf_volume(smooth_subtraction(sphere(0.9), sphere(0.5, center: [0.2, 0.1, -0.6]), k: param(0.3)))"),
    ("translate", "sdf_volume(translate(box(size: [1, 0.9, 0.8]), param([0.1, 0.2, 0.05])))"),
    ("rotate", "sdf_volume(rotate(box(size: [1.2, 0.8, 0.6]), param(0.4), axis: [0.3, 1, 0.2]))"),
    ("scale", "sdf_volume(scale(torus(major: 0.8, minor: 0.3), param(1.1)))"),
    ("displace", "sdf_volume(displace(sphere(0.9), amplitude: param(0.05), frequency: param(6)))"),
    ("round", "sdf_volume(round(box(size: [1, 0.8, 0.7]), param(0.15)))"),
    ("onion", "sdf_volume(onion(sphere(0.8), param(0.1)))"),
    ("xor", "sdf_volume(xor(sphere(param(0.7), center: [-0.2, 0, 0]), sphere(param(0.6), center: [0.3, 0.1, 0])))"),
    ("cone", "sdf_volume(cone(radius: param(0.7), height: param(1.3), center: param([0.05, 0.1, 0]), axis: \"y\"))"),
    ("elongate", "sdf_volume(elongate(sphere(0.5), param([0.3, 0.1, 0.2])))"),
    ("repeat", "sdf_volume(repeat(sphere(0.25), spacing: param([0.7, 0.6, 0.8]), count: [3, 2, 1]))"),
    ("mirror", "sdf_volume(mirror(sphere(param(0.4), center: param([0.4, 0.1, 0]))))"),
    ("twist", "sdf_volume(twist(box(size: [1, 0.5, 1.2]), rate: param(0.8)))"),
    ("bend", "sdf_volume(bend(box(size: [1.4, 0.4, 0.6]), rate: param(0.5)))"),
    ("scale per axis", "sdf_volume(scale(sphere(0.6), param([1.3, 0.8, 1.1])))"),
    ("paint", "sdf_volume(union(paint(sphere(0.5, center: [-0.5, 0, 0]), param([0.9, 0.1, 0.1])), sphere(0.5, center: [0.5, 0, 0])))"),
    ("constant", "sdf_volume(sphere(0.9), color: constant(param([0.2, 0.3, 0.4])))"),
    ("opacity", "sdf_volume(sphere(0.9), alpha: param(0.9), beta: param(0.06))"),
    ("opacity at α = 1", "sdf_volume(sphere(0.9), alpha: param(1), beta: param(0.2))"),
    ("volsdf", "volsdf(sphere(0.9), alpha: param(8), beta: param(0.08), color: param([0.2, 0.4, 0.6]))"),
    ("neus", "neus(sphere(0.9), alpha: param(20), beta: param(0.07))"),
];

#[test]
fn every_density_has_a_row() {
    for k in DensityKind::ALL {
        let call = format!("{}(", k.name());
        assert!(
            CASES.iter().any(|(_, src)| src.starts_with(&call)),
            "{k:?} has no row in CASES"
        );
    }
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

/// Every declared primitive as a case: a call with each trainable argument
/// `param(...)` at values drawn from its declared ranges (an unbounded one
/// cut by a sphere).
fn primitive_cases() -> Vec<(String, String)> {
    Primitive::SPECS
        .iter()
        .enumerate()
        .map(|(k, spec)| {
            let p = Primitive::random(k, &mut uniform(11 + k as u64));
            let vec = |v: DVec3| format!("[{}, {}, {}]", v.x, v.y, v.z);
            let args: Vec<String> = spec
                .args
                .iter()
                .zip(p.args())
                .map(|(a, v)| {
                    let text = match (v, a.check) {
                        (ArgValue::Axis(axis), _) => {
                            format!("\"{}\"", ["x", "y", "z"][axis.index()])
                        }
                        (ArgValue::Vector(v), Check::Direction) => vec(v.value),
                        (ArgValue::Vector(v), _) => format!("param({})", vec(v.value)),
                        (ArgValue::Scalar(x), _) => format!("param({})", x.value),
                    };
                    format!("{}: {text}", a.name)
                })
                .collect();
            let call = format!("{}({})", spec.name, args.join(", "));
            let field = match p.bounds() {
                Some(_) => format!("sdf_volume({call})"),
                None => format!("sdf_volume(intersection({call}, sphere(1.2)))"),
            };
            (spec.name.to_string(), field)
        })
        .collect()
}

/// The primitives' cases and `CASES`.
fn cases() -> Vec<(String, String)> {
    let mut all = primitive_cases();
    all.extend(CASES.iter().map(|(n, s)| (n.to_string(), s.to_string())));
    all
}

fn model(field: &str) -> TrainModel {
    let src = format!(
        "let cams = [look_at(eye: [0, 0, -3])]\n\
         train t {{ model: {field}, data: render_views(sdf_volume(sphere()), cameras: cams, size: [4, 4]) }}"
    );
    let program = sdfl_stdlib::load(&SourceFile::new("case.sdfl", src))
        .unwrap_or_else(|e| panic!("{field}: {e:?}"));
    TrainModel::new(program.trains[0].model.as_sdf().expect("analytic"))
}

/// A 6×6 view from (0.3, 0.4, −3) with 48 samples from 0 to 6, grey targets.
fn batch(eye: [f64; 3], last: LastInterval) -> Batch {
    let cam = Camera::look_at(eye.into(), glam::DVec3::ZERO, glam::DVec3::Y, 1.0);
    let rays = camera_rays(
        &cam,
        ImageSize {
            width: 6,
            height: 6,
        },
    )
    .unwrap();
    let n = rays.len();
    Batch {
        rays,
        targets: (0..n).map(|k| [0.5, 0.3 + 0.01 * k as f32, 0.2]).collect(),
        coverage: Vec::new(),
        depths: Stratified::new(48, 0.0, 6.0).unwrap().depths(),
        samples: 48,
        shared: true,
        last_interval: last,
        seed: 0,
        step: 0,
        points: Vec::new(),
    }
}

#[test]
fn every_parameter_gradient_matches_finite_differences() {
    let b = batch([0.3, 0.4, -3.0], LastInterval::Zero);
    let h = 1e-6;
    for (name, src) in &cases() {
        let m = model(src);
        assert!(m.scalars > 0, "{name}: no parameters");
        let v0 = m.initial_values();
        let g = loss_and_grad_f64(&m, &v0, &b, 1.0).grad;
        let loss = |v: &[f64]| loss_and_grad_f64(&m, v, &b, 1.0).loss;
        for i in 0..m.scalars {
            let (mut up, mut down) = (v0.clone(), v0.clone());
            up[i] += h;
            down[i] -= h;
            let fd = (loss(&up) - loss(&down)) / (2.0 * h);
            assert!(
                (g[i] - fd).abs() <= 1e-7 + 1e-4 * fd.abs(),
                "{name}, scalar {i}: kernel {} vs finite differences {fd}",
                g[i]
            );
        }
        // Every parameter matters to these pixels (a test that can fail).
        assert!(
            g.iter().any(|x| x.abs() > 1e-6),
            "{name}: all gradients are 0"
        );
    }
}

/// The tape kernel (the training path of fields it can trace): the scalar
/// kernel's loss to the bit, and the f64 reference's gradient within f32's
/// rounding, for every case it traces, on straight-on and grazing views.
#[test]
fn tape_kernel_matches_f64() {
    let mut on_tape = 0;
    for (eye, last) in [
        ([0.3, 0.4, -3.0], LastInterval::Zero),
        ([2.9, 0.05, -0.4], LastInterval::Infinite),
    ] {
        let b = batch(eye, last);
        for (name, src) in &cases() {
            let m = model(src);
            let v64 = m.initial_values();
            let v32: Vec<f32> = v64.iter().map(|&x| x as f32).collect();
            if traced(&m, &v32, &b).is_none() {
                continue;
            }
            on_tape += 1;
            let (a, s, r) = (
                loss_and_grad_f32(&m, &v32, &b, 1.0),
                loss_and_grad_scalar_f32(&m, &v32, &b, 1.0),
                loss_and_grad_f64(&m, &v64, &b, 1.0),
            );
            assert_eq!(a.loss.to_bits(), s.loss.to_bits(), "{name}");
            let scale = r.grad.iter().fold(1e-3f64, |m, x| m.max(x.abs()));
            for (i, (x, y)) in a.grad.iter().zip(&r.grad).enumerate() {
                assert!(
                    (x - y).abs() <= 2e-3 * scale,
                    "{name}, scalar {i}: tape {x} vs f64 {y}"
                );
            }
        }
    }
    // Most primitives, transforms, densities and colours trace.
    assert!(on_tape >= 2 * 28, "{on_tape} cases on the tape");
}

#[test]
fn f32_kernel_matches_f64() {
    let b = batch([0.3, 0.4, -3.0], LastInterval::Zero);
    for (name, src) in &cases() {
        let m = model(src);
        let v64 = m.initial_values();
        let v32: Vec<f32> = v64.iter().map(|&x| x as f32).collect();
        let (a, r) = (
            loss_and_grad_scalar_f32(&m, &v32, &b, 1.0),
            loss_and_grad_f64(&m, &v64, &b, 1.0),
        );
        assert!(
            (a.loss - r.loss).abs() <= 1e-5 * (1.0 + r.loss.abs()),
            "{name}"
        );
        let scale = r.grad.iter().fold(1e-3f64, |m, x| m.max(x.abs()));
        for (x, y) in a.grad.iter().zip(&r.grad) {
            assert!((x - y).abs() <= 2e-3 * scale, "{name}: {x} vs {y}");
        }
    }
}

#[test]
fn hard_cases_have_finite_values_and_gradients() {
    // Every density with tiny β, its largest α up to 1e4 and the
    // assignment's infinite last interval.
    let tiny: Vec<String> = DensityKind::ALL
        .iter()
        .map(|k| {
            format!(
                "{}(sphere(param(0.9)), alpha: param({}), beta: param(1e-4))",
                k.name(),
                k.alpha_max().min(1e4)
            )
        })
        .collect();
    // A ray grazing the unit sphere: the eye 3 away, looking along a tangent.
    let grazing = batch([1.0, 0.0, -3.0], LastInterval::Infinite);
    for src in tiny
        .iter()
        .map(String::as_str)
        .chain(cases().iter().map(|c| c.1.as_str()))
    {
        let m = model(src);
        let v = m.initial_values();
        for b in [
            batch([0.3, 0.4, -3.0], LastInterval::Infinite),
            grazing.clone(),
        ] {
            let v32: Vec<f32> = v.iter().map(|&x| x as f32).collect();
            for lg in [
                loss_and_grad_scalar_f32(&m, &v32, &b, 1.0),
                loss_and_grad_f32(&m, &v32, &b, 1.0),
            ] {
                assert!(
                    lg.loss.is_finite() && lg.grad.iter().all(|g| g.is_finite()),
                    "{src}: {lg:?}"
                );
            }
        }
    }
    // Samples exactly on a box's edge and corner, and at its centre: a ray
    // from each point, its first sample at the point itself.
    let m = model("sdf_volume(box(size: param([1, 1, 1]), center: param([0, 0, 0])))");
    let v: Vec<f64> = m.initial_values();
    for p in [
        [0.5, 0.5, 0.0],
        [0.5, 0.5, 0.5],
        [0.0, 0.0, 0.0],
        [0.5, 0.0, 0.0],
    ] {
        let mut b = batch([0.3, 0.4, -3.0], LastInterval::Zero);
        b.rays.truncate(1);
        b.targets.truncate(1);
        b.rays[0].origin = p;
        b.rays[0].dir = [0.0, 0.0, 1.0];
        let lg = loss_and_grad_f64(&m, &v, &b, 1.0);
        assert!(
            lg.loss.is_finite() && lg.grad.iter().all(|g| g.is_finite()),
            "{p:?}: {lg:?}"
        );
        assert!(lg.grad.iter().any(|g| *g != 0.0), "{p:?}: {lg:?}");
    }
}

#[test]
fn a_parameter_used_twice_is_one_parameter_named_by_its_let() {
    let src = "let cams = [look_at(eye: [0, 0, -3])]\n\
               let c = param([0.1, 0, 0])\n\
               train t { model: sdf_volume(union(sphere(0.3, center: c), box(center: c, size: param(0.4)), sphere(param(0.2)))), \
               data: render_views(sdf_volume(sphere()), cameras: cams, size: [4, 4]) }";
    let program = sdfl_stdlib::load(&SourceFile::new("shared.sdfl", src)).unwrap();
    let m = TrainModel::new(program.trains[0].model.as_sdf().expect("analytic"));
    let names: Vec<&str> = m.params.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["c", "box.size", "sphere.radius"]);
    assert_eq!(m.scalars, 5);
    // Its gradient is the sum over both uses: equal to finite differences.
    let b = batch([0.3, 0.4, -3.0], LastInterval::Zero);
    let v0 = m.initial_values();
    let g = loss_and_grad_f64(&m, &v0, &b, 1.0).grad;
    let h = 1e-6;
    let (mut up, mut down) = (v0.clone(), v0.clone());
    up[0] += h;
    down[0] -= h;
    let fd = (loss_and_grad_f64(&m, &up, &b, 1.0).loss
        - loss_and_grad_f64(&m, &down, &b, 1.0).loss)
        / (2.0 * h);
    assert!(
        (g[0] - fd).abs() <= 1e-7 + 1e-4 * fd.abs(),
        "{} vs {fd}",
        g[0]
    );
}

#[test]
fn many_parameters_take_several_tangent_passes() {
    // 20 spheres × 4 scalars: more than one chunk of tangents.
    let spheres: Vec<String> = (0..20)
        .map(|k| {
            let x = -1.0 + 0.1 * k as f64;
            format!(
                "sphere(param(0.12), center: param([{x}, {}, 0]))",
                0.05 * (k % 3) as f64
            )
        })
        .collect();
    let m = model(&format!("sdf_volume(union({}))", spheres.join(", ")));
    assert_eq!(m.scalars, 80);
    let b = batch([0.3, 0.4, -3.0], LastInterval::Zero);
    let v0 = m.initial_values();
    let g = loss_and_grad_f64(&m, &v0, &b, 1.0).grad;
    let h = 1e-6;
    for i in [0, 17, 40, 79] {
        let (mut up, mut down) = (v0.clone(), v0.clone());
        up[i] += h;
        down[i] -= h;
        let fd = (loss_and_grad_f64(&m, &up, &b, 1.0).loss
            - loss_and_grad_f64(&m, &down, &b, 1.0).loss)
            / (2.0 * h);
        assert!(
            (g[i] - fd).abs() <= 1e-7 + 1e-4 * fd.abs(),
            "scalar {i}: {} vs {fd}",
            g[i]
        );
    }
}

#[test]
fn dfdx_graph_backend_matches_the_fused_kernel() {
    let dev = dfdx::prelude::Cpu::default();
    for last in [LastInterval::Zero, LastInterval::Infinite] {
        let b = batch([0.3, 0.4, -3.0], last);
        for (name, src) in &cases() {
            let m = model(src);
            let v64 = m.initial_values();
            let v32: Vec<f32> = v64.iter().map(|&x| x as f32).collect();
            let g = sdfl_runtime::train::graph::loss_and_grad(&dev, &m, &v32, &b, 1.0).unwrap();
            let r = loss_and_grad_f64(&m, &v64, &b, 1.0);
            assert!(
                (g.loss - r.loss).abs() <= 1e-5 * (1.0 + r.loss.abs()),
                "{name}: {} vs {}",
                g.loss,
                r.loss
            );
            let scale = r.grad.iter().fold(1e-3f64, |m, x| m.max(x.abs()));
            for (x, y) in g.grad.iter().zip(&r.grad) {
                assert!(
                    (x - y).abs() <= 2e-3 * scale,
                    "{name}: graph {x} vs fused {y}"
                );
            }
        }
    }
}

/// The tape kernel on batches whose samples do not fill its 16 lanes and
/// whose rays do not fill its groups (2, 5, 17, 40 samples; 3 to 37 rays),
/// with colours that are one parameter for all three channels.
#[test]
fn tape_kernel_matches_f64_on_ragged_batches() {
    let fields = [
        "sdf_volume(sphere(param(0.9), center: param([0.1, -0.1, 0.2])), color: constant(param(0.4)))",
        "sdf_volume(union(sphere(param(0.5), center: [-0.5, 0, 0]), box(size: param([0.6, 0.5, 0.7]), center: [0.5, 0.1, 0])))",
        "volsdf(torus(major: param(0.8), minor: param(0.3)), alpha: param(8), beta: param(0.08), color: param([0.2, 0.4, 0.6]))",
    ];
    for (samples, rays) in [(2, 3), (5, 7), (17, 5), (40, 37)] {
        let mut b = batch([0.3, 0.4, -3.0], LastInterval::Infinite);
        b.rays.truncate(rays);
        b.targets.truncate(rays);
        b.depths = Stratified::new(samples, 0.5, 5.5).unwrap().depths();
        b.samples = samples;
        for src in fields {
            let m = model(src);
            let v64 = m.initial_values();
            let v32: Vec<f32> = v64.iter().map(|&x| x as f32).collect();
            assert!(traced(&m, &v32, &b).is_some(), "{src}");
            let (a, s, r) = (
                loss_and_grad_f32(&m, &v32, &b, 1.0),
                loss_and_grad_scalar_f32(&m, &v32, &b, 1.0),
                loss_and_grad_f64(&m, &v64, &b, 1.0),
            );
            assert_eq!(
                a.loss.to_bits(),
                s.loss.to_bits(),
                "{src}, {samples} samples"
            );
            let scale = r.grad.iter().fold(1e-3f64, |m, x| m.max(x.abs()));
            for (i, (x, y)) in a.grad.iter().zip(&r.grad).enumerate() {
                assert!(
                    (x - y).abs() <= 2e-3 * scale,
                    "{src}, {samples} samples, scalar {i}: tape {x} vs f64 {y}"
                );
            }
        }
    }
}
