//! Tests of tracing and compiling tapes. The kernel's agreement with the
//! f64 reference and the scalar kernel, for every primitive, operator,
//! density and colour, is in `runtime/tests/suite/gradients.rs`.

use sdfl_lang::SourceFile;
use sdfl_runtime::train::fused::{loss_and_grad_f32, Batch};
use sdfl_runtime::train::tape::*;
use sdfl_runtime::train::TrainModel;
use sdfl_runtime::volume::{camera_rays, ImageSize, Stratified};
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::num::{Dual, Real};
use sdfl_stdlib::value::LastInterval;

fn model(field: &str) -> TrainModel {
    let src = format!(
        "let cams = [look_at(eye: [0, 0, -3])]\n\
         train t {{ model: {field}, data: render_views(sdf_volume(sphere()), cameras: cams, size: [4, 4]) }}"
    );
    let program = sdfl_stdlib::load(&SourceFile::new("case.sdfl", src)).expect("loads");
    TrainModel::new(program.trains[0].model.as_sdf().expect("analytic"))
}

fn values(m: &TrainModel) -> Vec<f32> {
    m.initial_values().iter().map(|&x| x as f32).collect()
}

/// Every operation, on operands 0 to 3.
fn every_op() -> Vec<Op> {
    use Op::*;
    vec![
        Add(0, 1),
        Sub(0, 1),
        Mul(0, 1),
        Div(0, 1),
        Neg(0),
        Sqrt(0),
        Abs(0),
        Exp(0),
        Ln(0),
        Ln1p(0),
        ExpM1(0),
        Sin(0),
        Cos(0),
        Max(0, 1),
        Min(0, 1),
        IfGt(0, 1, 2, 3),
    ]
}

/// The pruning of values nothing reads rests on `rule_reads`: a rule given
/// NaN for everything it is said not to read must give the same shares.
#[test]
fn derivative_rules_read_only_what_they_declare() {
    for op in every_op() {
        let (_, arity) = op.operands();
        for x in [
            [0.7f32, 1.3, -0.4, 2.0],
            [1.9, 0.2, 0.5, -1.0],
            [0.0, 0.0, 1.0, 2.0],
        ] {
            let y = forward(op, x);
            let want = backward(op, x, y, 0.37);
            let (reads, result) = rule_reads(op);
            let mut hidden = x;
            for (j, h) in hidden.iter_mut().enumerate() {
                if reads & (1 << j) == 0 {
                    *h = f32::NAN;
                }
            }
            let y = if result { y } else { f32::NAN };
            let got = backward(op, hidden, y, 0.37);
            for j in 0..arity {
                assert_eq!(
                    got[j].to_bits(),
                    want[j].to_bits(),
                    "{op:?} at {x:?}, operand {j}"
                );
            }
        }
    }
}

/// Each operation's value is `Dual<f32, 0>`'s to the bit (the tape's
/// forward pass is the scalar kernel's), signed zeros and NaN included.
#[test]
fn values_are_dual_arithmetic() {
    type D = Dual<f32, 0>;
    let d = |x: f32| D::constant(x);
    let cases = [
        [0.7f32, 1.3, -0.4, 2.0],
        [-0.0, 0.0, 3.0, -3.0],
        [f32::NAN, 1.0, 2.0, 3.0],
        [2.5, f32::NAN, -1.0, 1.0],
    ];
    for x in cases {
        let [a, b, c, e] = x.map(d);
        for op in every_op() {
            use Op::*;
            let want = match op {
                Add(..) => a + b,
                Sub(..) => a - b,
                Mul(..) => a * b,
                Div(..) => a / b,
                Neg(_) => -a,
                Sqrt(_) => a.sqrt(),
                Abs(_) => a.abs(),
                Exp(_) => a.exp(),
                Ln(_) => a.ln(),
                Ln1p(_) => a.ln_1p(),
                ExpM1(_) => a.exp_m1(),
                Sin(_) => a.sin(),
                Cos(_) => a.cos(),
                Max(..) => a.max(b),
                Min(..) => a.min(b),
                IfGt(..) => D::if_gt(a, b, c, e),
                Input(_) | Const(_) | Param(_) => unreachable!(),
            }
            .v;
            let got = forward(op, x);
            assert!(
                got.to_bits() == want.to_bits() || got.is_nan() && want.is_nan(),
                "{op:?} at {x:?}: {got} vs {want}"
            );
        }
    }
}

/// What depends on parameters only is computed once at tracing, and what
/// nothing reads is not computed: the rotation's sine and cosine are not on
/// the tape, nor, at α = 1 (a constant), `ln(1 − o)`'s value or the term
/// that α = 1 multiplies by 0.
#[test]
fn tapes_hold_only_per_sample_work_that_is_read() {
    let m = model("sdf_volume(rotate(torus(major: param(0.8), minor: param(0.35)), param(0.4), axis: [0.3, 1, 0.2]))");
    let tape = Tape::trace(&m, &values(&m)).expect("traces");
    let ops: Vec<Op> = tape.forward.iter().map(|&(op, _)| op).collect();
    assert!(
        !ops.iter().any(|op| matches!(op, Op::Sin(_) | Op::Cos(_))),
        "{ops:?}"
    );
    assert!(
        !ops.iter().any(|op| matches!(op, Op::Ln1p(_) | Op::Div(..))),
        "{ops:?}"
    );
    // The angle still gets its gradient, through the uniform nodes.
    assert!(tape.uniforms.iter().any(|u| u.grad));
    // Every adjoint is written before it is read: nothing to zero.
    assert!(tape.adjoint_registers.is_empty());
    // Trainable α keeps ln(1 − o)'s dependence on it.
    let m = model("sdf_volume(torus(major: param(0.8), minor: 0.3), alpha: param(0.9))");
    let tape = Tape::trace(&m, &values(&m)).expect("traces");
    assert!(tape
        .reverse
        .iter()
        .any(|&(op, _, _, _)| matches!(op, Op::Ln1p(_))));
}

#[test]
fn a_branch_on_the_sample_or_a_huge_scene_is_not_traced() {
    let m = model("sdf_volume(union(paint(sphere(0.5, center: [-0.5, 0, 0]), [1, 0, 0]), sphere(param(0.5))))");
    assert_eq!(
        Tape::trace(&m, &values(&m)).err(),
        Some("a branch on a per-sample value")
    );
    let spheres: Vec<String> = (0..4000)
        .map(|k| format!("sphere(0.01, center: [{}, 0, 0])", k as f64 * 0.001))
        .collect();
    let src = format!(
        "let cams = [look_at(eye: [0, 0, -3])]\n\
         train t {{ model: sdf_volume(union({}, sphere(param(0.5)))), iterations: 1, rays: 16, \
         data: render_views(sdf_volume(sphere()), cameras: cams, size: [4, 4]) }}",
        spheres.join(", ")
    );
    let program = sdfl_stdlib::load(&SourceFile::new("many.sdfl", src)).expect("loads");
    let m = TrainModel::new(program.trains[0].model.as_sdf().expect("analytic"));
    assert_eq!(
        Tape::trace(&m, &values(&m)).err(),
        Some("too many operations")
    );
    // The trace left nothing behind: the next one starts afresh.
    let m = model("sdf_volume(sphere(param(0.9)))");
    assert!(Tape::trace(&m, &values(&m)).is_ok());
}

/// The blocks' sums are added in order: the same bits at any thread count.
#[test]
fn the_tape_kernel_gives_the_same_bits_at_any_thread_count() {
    let m = model("sdf_volume(smooth_union(torus(major: param(0.8), minor: param(0.3)), sphere(param(0.4), center: param([0.5, 0.1, 0])), k: param(0.2)))");
    let cam = Camera::look_at(
        glam::DVec3::new(0.3, 0.4, -3.0),
        glam::DVec3::ZERO,
        glam::DVec3::Y,
        1.0,
    );
    let rays = camera_rays(
        &cam,
        ImageSize {
            width: 24,
            height: 24,
        },
    )
    .unwrap();
    let n = rays.len();
    let batch = Batch {
        rays,
        targets: (0..n).map(|k| [0.5, 0.3 + 0.001 * k as f32, 0.2]).collect(),
        coverage: Vec::new(),
        depths: Stratified::new(40, 0.0, 6.0).unwrap().depths(),
        samples: 40,
        shared: true,
        last_interval: LastInterval::Zero,
        seed: 0,
        step: 0,
        points: Vec::new(),
    };
    let v = values(&m);
    assert!(Tape::trace(&m, &v).is_ok());
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| loss_and_grad_f32(&m, &v, &batch, 1.0))
    };
    let (one, two) = (run(1), run(2));
    assert_eq!(one.loss.to_bits(), two.loss.to_bits());
    assert!(one.grad.iter().any(|g| *g != 0.0));
    for (a, b) in one.grad.iter().zip(&two.grad) {
        assert_eq!(a.to_bits(), b.to_bits());
    }
}
