//! `-- user [reps]`: a torus written by the user (`sdf(torus_d, ...)`,
//! the compiled tape run by the f32 leaf) against the built-in `torus`,
//! and against fidget's JIT on the same expression
//! (`|(|p.xy| - 1, p.z)| - 0.25`), in one run:
//!
//! - evaluation: 200 000 points in [-1.5, 1.5]³, one thread, batched
//!   (`eval_batch`) and per point (`dist`, what the tracer calls), against
//!   fidget's bulk f32 JIT evaluator;
//! - frames: 512² colour frames (all threads) of each torus, and depth +
//!   normals of the user torus against fidget's voxel renderer.
//!
//! Best of `reps`, the contenders alternating so they see the same load.

use std::sync::Arc;

use glam::{DVec3, Vec3A};
use sdfl_runtime::render::Needs;
use sdfl_runtime::{LowerOptions, Lowered};
use sdfl_stdlib::shape::{Axis, Shape, Torus};
use sdfl_stdlib::value::Value;

use crate::{best_of, frame, peer, sample_points, FRAME};

/// The user's torus, as `examples/iq_torus.sdfl` writes it.
fn user_torus() -> Shape {
    let src =
        "fn torus_d(p, major: 1, minor: 0.25) { length([length(p.xy) - major, p.z]) - minor }\n\
               let s = sdf(torus_d, bound: [1.5, 1.5, 0.5])";
    match sdfl_stdlib::eval::globals_of(src)
        .expect("the user torus loads")
        .remove("s")
    {
        Some(Value::Shape(s)) => Arc::unwrap_or_clone(s),
        other => panic!("not a shape: {other:?}"),
    }
}

fn builtin_torus() -> Shape {
    Shape::from(Torus {
        major: 1.0.into(),
        minor: 0.25.into(),
        center: DVec3::ZERO.into(),
        axis: Axis::Z,
    })
}

/// Points per second of `f` over `points` (best of `reps`).
fn rate(reps: usize, points: &[Vec3A], mut f: impl FnMut()) -> f64 {
    points.len() as f64 / best_of(reps, &mut f)
}

/// Runs the comparison and prints two Markdown tables.
pub fn main(reps: usize) {
    let (user, builtin) = (user_torus(), builtin_torus());
    let (lu, lb) = (
        Lowered::new(&user, LowerOptions::default()),
        Lowered::new(&builtin, LowerOptions::default()),
    );
    let points = sample_points(200_000);
    // The three agree inside the box before anything is timed.
    for p in points.iter().take(2000) {
        let (a, b) = (lu.dist(*p), lb.dist(*p));
        let inside = p.x.abs() < 1.5 && p.y.abs() < 1.5 && p.z.abs() < 0.5;
        assert!(
            !inside || (a - b).abs() <= 1e-5,
            "user {a} != built-in {b} at {p}"
        );
    }
    let fidget = peer::FidgetScene::build(|ctx| peer::torus(ctx, 1.0, 0.25));
    fidget.check_against(&lb, &points[..2000]);

    let mut out = vec![0f32; points.len()];
    let (mut ub, mut bb, mut up, mut bp, mut fj) = (0f64, 0f64, 0f64, 0f64, 0f64);
    for _ in 0..reps {
        ub = ub.max(rate(1, &points, || lu.eval_batch(&points, &mut out)));
        bb = bb.max(rate(1, &points, || lb.eval_batch(&points, &mut out)));
        up = up.max(rate(1, &points, || {
            for (p, o) in points.iter().zip(out.iter_mut()) {
                *o = lu.dist(*p);
            }
        }));
        bp = bp.max(rate(1, &points, || {
            for (p, o) in points.iter().zip(out.iter_mut()) {
                *o = lb.dist(*p);
            }
        }));
        fj = fj.max(fidget.throughput(&points, 1).0);
        std::hint::black_box(&out);
    }
    println!("| torus evaluation, one thread | user Mpts/s | built-in Mpts/s | fidget JIT Mpts/s | **user / built-in** | **user / fidget** |");
    println!("|---|---:|---:|---:|---:|---:|");
    println!(
        "| batched (`eval_batch`) | {:.1} | {:.1} | {:.1} | **{:.2}** | **{:.2}** |",
        ub / 1e6,
        bb / 1e6,
        fj / 1e6,
        ub / bb,
        ub / fj
    );
    println!(
        "| per point (`dist`) | {:.1} | {:.1} | {:.1} | **{:.2}** | **{:.2}** |",
        up / 1e6,
        bp / 1e6,
        fj / 1e6,
        up / bp,
        up / fj
    );

    let colour = Needs {
        color: true,
        depth: false,
        normals: false,
        mask: false,
    };
    let geometry = Needs {
        color: false,
        depth: true,
        normals: true,
        mask: false,
    };
    let voxels = peer::FidgetFrame::build(|ctx| peer::torus(ctx, 1.0, 0.25), FRAME);
    let (mut uf, mut bf, mut ug, mut fv) =
        (f64::INFINITY, f64::INFINITY, f64::INFINITY, f64::INFINITY);
    let (mut hits_u, mut hits_b) = (0, 0);
    for _ in 0..reps {
        let (s, v) = frame(&lu, &user, colour, 1);
        uf = uf.min(s);
        hits_u = v.hits;
        let (s, v) = frame(&lb, &builtin, colour, 1);
        bf = bf.min(s);
        hits_b = v.hits;
        ug = ug.min(frame(&lu, &user, geometry, 1).0);
        fv = fv.min(voxels.render().0);
    }
    println!();
    println!("| torus frame {FRAME}², all threads | user ms | built-in ms | **user / built-in time** | user depth+normals ms | fidget voxel ms | **fidget / user time** | hits user / built-in |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    println!(
        "| colour; depth + normals | {:.2} | {:.2} | **{:.2}** | {:.2} | {:.2} | **{:.2}** | {hits_u} / {hits_b} |",
        uf * 1e3,
        bf * 1e3,
        uf / bf,
        ug * 1e3,
        fv * 1e3,
        fv / ug
    );
}
