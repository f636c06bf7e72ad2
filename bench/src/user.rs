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
//! `-- user [rounds]` (default 5): each round times every contender in
//! turn (best of a few passes); figures are medians over the rounds and
//! ratios the median of the rounds' ratios (their range in brackets), so
//! both contenders of a ratio saw the same load.

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

/// Points per second of `f` over `points` (best of `passes`).
fn rate(passes: usize, points: &[Vec3A], mut f: impl FnMut()) -> f64 {
    points.len() as f64 / best_of(passes, &mut f)
}

/// Passes per contender in a round (its best is the round's figure).
const PASSES: usize = 3;

/// The median of `xs` and their range, as `median (lo–hi)`.
fn spread(xs: &mut [f64]) -> (f64, f64, f64) {
    xs.sort_by(f64::total_cmp);
    let n = xs.len();
    let median = if n % 2 == 1 {
        xs[n / 2]
    } else {
        0.5 * (xs[n / 2 - 1] + xs[n / 2])
    };
    (median, xs[0], xs[n - 1])
}

/// A ratio's median over the rounds, with its range.
fn ratio_cell(xs: &mut [f64]) -> String {
    let (m, lo, hi) = spread(xs);
    format!("**{m:.2}** ({lo:.2}–{hi:.2})")
}

/// Runs the comparison and prints two Markdown tables: each figure the
/// median over `rounds` rounds, each round timing every contender in turn
/// (best of a few passes), so the ratios pair contenders that saw the same
/// load; ratios are the median of the rounds' ratios, with their range.
pub fn main(rounds: usize) {
    let rounds = rounds.max(1);
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
    // Per round: user batched, built-in batched, user per point, built-in
    // per point, fidget JIT (points/s).
    let mut r: [Vec<f64>; 5] = Default::default();
    for _ in 0..rounds {
        r[0].push(rate(PASSES, &points, || lu.eval_batch(&points, &mut out)));
        r[1].push(rate(PASSES, &points, || lb.eval_batch(&points, &mut out)));
        r[2].push(rate(PASSES, &points, || {
            for (p, o) in points.iter().zip(out.iter_mut()) {
                *o = lu.dist(*p);
            }
        }));
        r[3].push(rate(PASSES, &points, || {
            for (p, o) in points.iter().zip(out.iter_mut()) {
                *o = lb.dist(*p);
            }
        }));
        r[4].push(fidget.throughput(&points, 1).0);
        std::hint::black_box(&out);
    }
    let per_round =
        |a: usize, b: usize| -> Vec<f64> { (0..rounds).map(|k| r[a][k] / r[b][k]).collect() };
    let (mut ub_bb, mut ub_fj, mut up_bp, mut up_fj) = (
        per_round(0, 1),
        per_round(0, 4),
        per_round(2, 3),
        per_round(2, 4),
    );
    let med = |k: usize| spread(&mut r[k].clone()).0 / 1e6;
    println!(
        "Medians over {rounds} rounds (ratios: median of the rounds' ratios, range in brackets).\n"
    );
    println!("| torus evaluation, one thread | user Mpts/s | built-in Mpts/s | fidget JIT Mpts/s | **user / built-in** | **user / fidget** |");
    println!("|---|---:|---:|---:|---:|---:|");
    println!(
        "| batched (`eval_batch`) | {:.1} | {:.1} | {:.1} | {} | {} |",
        med(0),
        med(1),
        med(4),
        ratio_cell(&mut ub_bb),
        ratio_cell(&mut ub_fj)
    );
    println!(
        "| per point (`dist`) | {:.1} | {:.1} | {:.1} | {} | {} |",
        med(2),
        med(3),
        med(4),
        ratio_cell(&mut up_bp),
        ratio_cell(&mut up_fj)
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
    // Per round: user colour, built-in colour, user geometry, fidget voxels (s).
    let mut f: [Vec<f64>; 4] = Default::default();
    let (mut hits_u, mut hits_b) = (0, 0);
    for _ in 0..rounds {
        let (s, v) = frame(&lu, &user, colour, PASSES);
        f[0].push(s);
        hits_u = v.hits;
        let (s, v) = frame(&lb, &builtin, colour, PASSES);
        f[1].push(s);
        hits_b = v.hits;
        f[2].push(frame(&lu, &user, geometry, PASSES).0);
        f[3].push(
            (0..PASSES)
                .map(|_| voxels.render().0)
                .fold(f64::INFINITY, f64::min),
        );
    }
    let ratios =
        |a: usize, b: usize| -> Vec<f64> { (0..rounds).map(|k| f[a][k] / f[b][k]).collect() };
    let (mut ub, mut fu) = (ratios(0, 1), ratios(3, 2));
    let ms = |k: usize| spread(&mut f[k].clone()).0 * 1e3;
    println!();
    println!("| torus frame {FRAME}², all threads | user ms | built-in ms | **user / built-in time** | user depth+normals ms | fidget voxel ms | **fidget / user time** | hits user / built-in |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    println!(
        "| colour; depth + normals | {:.2} | {:.2} | {} | {:.2} | {:.2} | {} | {hits_u} / {hits_b} |",
        ms(0),
        ms(1),
        ratio_cell(&mut ub),
        ms(2),
        ms(3),
        ratio_cell(&mut fu)
    );
}
