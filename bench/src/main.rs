//! Benchmarks of the SDF evaluator and sphere tracer: run by hand with
//! `cargo run --release -p sdfl-bench`, never as a timed test.
//!
//! For N = 1, 10, 100, 1 000, 10 000 primitives (spheres scattered in a
//! cube, scaled so the scene keeps its size) it measures evaluation
//! throughput (points/s, one thread) and 512×512 frame time (all threads),
//! naive min-union against BVH-culled (batched: `eval_batch`; and per point
//! without packed unions, the evaluator before issue 10), and the same expression evaluated by
//! the fidget crate's JIT in the same run; it prints a Markdown table.
//! `-- frames` times frames (depth + normals) against fidget's own voxel
//! renderer (see `peer.rs`), `-- showcase` the showcase's trace with and
//! without tiles.
//! `-- user` times a torus the user writes (`sdf(torus_d, ...)`) against
//! the built-in one and fidget's JIT on the same expression (see `user.rs`).
//! `cargo run --release -p sdfl-bench -- train` times training steps instead
//! (see `train.rs`; `-- train 20 fused` the fused kernel only); `-- nerf` times NeRF steps and `-- neural-sdf` neural SDF steps (see `nerf.rs`); `-- density` what each density runs through (see `density.rs`); `-- view` the frames per second of `sdfl view` (see `view.rs`); `-- surface` a neural surface step against PyTorch, `-- hash-sdf` the hash-grid SDF step and `-- hash-surface` a hash-grid NeuS step and its parts (see `surface.rs`, `hash_sdf.rs`, `hash_surface.rs`).
#![warn(missing_docs)]

use std::time::Instant;

use glam::{DVec3, Vec3A};
use sdfl_runtime::render::{render_view, Needs, ViewBuffers};
use sdfl_runtime::{LowerOptions, Lowered};
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::material::Material;
use sdfl_stdlib::shape::{Shape, Sphere};
use sdfl_stdlib::RenderJob;
use std::sync::Arc;

mod adam;
mod density;
mod hash_sdf;
mod hash_surface;
mod nerf;
mod peer;
mod stats;
mod surface;
mod train;
mod user;
mod view;

/// Deterministic uniform numbers in [0, 1).
pub struct Lcg(pub u64);
impl Lcg {
    /// The next number: 53 high bits of the state, as a fraction.
    pub fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `n` spheres in [-1, 1]^3 with radii shrinking as n grows (so they stay
/// mostly separate), as (centre, radius).
pub fn scattered_spheres(n: usize) -> Vec<(DVec3, f64)> {
    let mut rng = Lcg(1234);
    let r = 0.5 / (n as f64).cbrt();
    (0..n)
        .map(|_| {
            let c = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 2.0 - DVec3::ONE;
            (c, r * (0.5 + 0.5 * rng.uniform()))
        })
        .collect()
}

fn scene(spheres: &[(DVec3, f64)]) -> Shape {
    Shape::Union(
        spheres
            .iter()
            .map(|(c, r)| {
                Arc::new(Shape::from(Sphere {
                    center: (*c).into(),
                    radius: (*r).into(),
                }))
            })
            .collect(),
    )
}

fn sample_points(count: usize) -> Vec<Vec3A> {
    let mut rng = Lcg(99);
    (0..count)
        .map(|_| {
            Vec3A::new(
                rng.uniform() as f32,
                rng.uniform() as f32,
                rng.uniform() as f32,
            ) * 3.0
                - Vec3A::splat(1.5)
        })
        .collect()
}

/// Best of `reps` runs of `f`, in seconds.
fn best_of(reps: usize, mut f: impl FnMut()) -> f64 {
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The bench's render job: 512² of `shape` from z = -3.5 towards the
/// origin (focal 1), 128 steps, ε = 1e-4.
fn frame_job(shape: &Shape) -> RenderJob {
    RenderJob {
        name: "bench".into(),
        scene: Arc::new(shape.clone()),
        material: Arc::new(Material::Rainbow),
        cameras: vec![Camera::look_at(
            DVec3::new(0.0, 0.0, -3.5),
            DVec3::ZERO,
            DVec3::Y,
            1.0,
        )],
        width: FRAME,
        height: FRAME,
        near: 0.0,
        far: 8.0,
        iterations: 128,
        epsilon: 1e-4,
        hit_tolerance: sdfl_stdlib::value::HitTolerance::Absolute,
        background: DVec3::ZERO,
        fog: None,
        samples_per_pixel: 1,
        outputs: vec![],
    }
}

/// Frame size in pixels (and fidget's depth in voxels).
const FRAME: u32 = 512;

/// Best of `reps` frames of the quantities in `needs`, in seconds, and the
/// last frame's buffers.
fn frame(lowered: &Lowered, shape: &Shape, needs: Needs, reps: usize) -> (f64, ViewBuffers) {
    let job = frame_job(shape);
    let mut last = None;
    let secs = best_of(reps, || {
        last = Some(render_view(
            lowered,
            &job,
            &job.cameras[0],
            (FRAME, FRAME),
            needs,
            &|_| {},
        ));
    });
    (secs, last.expect("at least one frame"))
}

fn frame_time(lowered: &Lowered, shape: &Shape, reps: usize) -> f64 {
    let needs = Needs {
        color: true,
        depth: false,
        normals: false,
        mask: false,
    };
    frame(lowered, shape, needs, reps).0
}

/// `-- frames [N,N,…]`: sdfl's traced depth + normals against fidget's
/// voxel renderer (depth + normals, 512² × 512), same scene and frustum,
/// all threads, best of 3 each, alternating so both see the same load;
/// and sdfl's tracer before tiles (`LowerOptions::tiles` off). The hit
/// masks are compared as a check that both render the same scene (they
/// differ at silhouettes: fidget's voxels against sdfl's ε).
fn frames_main(sizes: &[usize]) {
    println!("| N | sdfl depth+normals ms | fidget voxel ms | **sdfl / fidget speed** | hit masks agree | steps per ray | sdfl untiled ms | untiled / fidget |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|");
    let needs = Needs {
        color: false,
        depth: true,
        normals: true,
        mask: false,
    };
    for &n in sizes {
        let spheres = scattered_spheres(n);
        let shape = scene(&spheres);
        let lowered = Lowered::new(&shape, LowerOptions::default());
        // The tracer before tiles, in the same run.
        let untiled = Lowered::new(
            &shape,
            LowerOptions {
                tiles: false,
                ..Default::default()
            },
        );
        let fidget = peer::FidgetFrame::new(&spheres, FRAME);
        let (mut sdfl_s, mut fidget_s, mut untiled_s) =
            (f64::INFINITY, f64::INFINITY, f64::INFINITY);
        let (mut view, mut peer_hits) = (None, Vec::new());
        for _ in 0..3 {
            let (s, v) = frame(&lowered, &shape, needs, 1);
            sdfl_s = sdfl_s.min(s);
            view = Some(v);
            let (s, h) = fidget.render();
            fidget_s = fidget_s.min(s);
            peer_hits = h;
            untiled_s = untiled_s.min(frame(&untiled, &shape, needs, 1).0);
        }
        let view = view.expect("rendered");
        let depth = view.depth.as_ref().expect("depth planned");
        let agree = depth
            .iter()
            .zip(&peer_hits)
            .filter(|(d, h)| (**d > 0.0) == h.is_some())
            .count();
        println!(
            "| {n} | {:.1} | {:.1} | **{:.2}** | {:.2} % | {:.1} | {:.1} | {:.2} |",
            sdfl_s * 1e3,
            fidget_s * 1e3,
            fidget_s / sdfl_s,
            100.0 * agree as f64 / depth.len() as f64,
            view.steps as f64 / view.rays as f64,
            untiled_s * 1e3,
            fidget_s / untiled_s,
        );
    }
}

/// `-- showcase [reps]`: the trace stage of `sdfl run` on the built-in
/// showcase (`examples/large_scene.sdfl`: every view, the quantities its
/// outputs need, all threads), tiled against untiled
/// (`LowerOptions::tiles` off: the tracer before tiles), alternating; best
/// of `reps` each.
fn showcase_main(reps: usize) {
    let src = sdfl_lang::SourceFile::new(
        "large_scene.sdfl",
        include_str!("../../examples/large_scene.sdfl"),
    );
    let program = sdfl_stdlib::load(&src).unwrap_or_else(|e| panic!("{e:?}"));
    let job = &program.renders[0];
    let needs = Needs::from(&sdfl_runtime::Plan::of(job));
    let trace = |tiles: bool| {
        let options = LowerOptions {
            tiles,
            ..Default::default()
        };
        let mut scenes = sdfl_runtime::render::ViewScenes::new(&job.scene, options, &job.cameras);
        let mut secs = 0.0;
        for cam in &job.cameras {
            let scene = scenes.for_view(cam);
            let t = Instant::now();
            render_view(scene, job, cam, (job.width, job.height), needs, &|_| {});
            secs += t.elapsed().as_secs_f64();
        }
        secs
    };
    let (mut tiled, mut plain) = (f64::INFINITY, f64::INFINITY);
    for _ in 0..reps {
        tiled = tiled.min(trace(true));
        plain = plain.min(trace(false));
    }
    println!("| showcase trace | tiled s | untiled s | untiled / tiled |");
    println!("|---|---:|---:|---:|");
    println!(
        "| {} views of {}² | {tiled:.3} | {plain:.3} | {:.2} |",
        job.cameras.len(),
        job.width,
        plain / tiled
    );
}

fn main() {
    if std::env::args().nth(1).as_deref() == Some("view") {
        let file = std::env::args().nth(2);
        let frames = std::env::args().nth(3).and_then(|r| r.parse().ok());
        return view::main(
            file.as_deref().unwrap_or("examples/large_scene.sdfl"),
            frames.unwrap_or(60),
        );
    }
    if std::env::args().nth(1).as_deref() == Some("showcase") {
        let reps = std::env::args()
            .nth(2)
            .and_then(|r| r.parse().ok())
            .unwrap_or(5);
        return showcase_main(reps);
    }
    if std::env::args().nth(1).as_deref() == Some("user") {
        let reps = std::env::args()
            .nth(2)
            .and_then(|r| r.parse().ok())
            .unwrap_or(5);
        return user::main(reps);
    }
    if std::env::args().nth(1).as_deref() == Some("train") {
        let reps = std::env::args()
            .nth(2)
            .and_then(|r| r.parse().ok())
            .unwrap_or(20);
        let only_fused = std::env::args().nth(3).as_deref() == Some("fused");
        return train::main(reps, only_fused);
    }
    if std::env::args().nth(1).as_deref() == Some("density") {
        let reps = std::env::args()
            .nth(2)
            .and_then(|r| r.parse().ok())
            .unwrap_or(10);
        return density::main(reps);
    }
    if std::env::args().nth(1).as_deref() == Some("nerf") {
        let reps = std::env::args()
            .nth(2)
            .and_then(|r| r.parse().ok())
            .unwrap_or(10);
        return nerf::main(reps);
    }
    if std::env::args().nth(1).as_deref() == Some("neural-sdf") {
        let reps = std::env::args()
            .nth(2)
            .and_then(|r| r.parse().ok())
            .unwrap_or(10);
        return nerf::neural_sdf_main(reps);
    }
    if std::env::args().nth(1).as_deref() == Some("surface") {
        if std::env::args().nth(2).as_deref() == Some("check") {
            let dir = std::env::args()
                .nth(3)
                .unwrap_or_else(|| "surface_check".into());
            return surface::check(std::path::Path::new(&dir));
        }
        let reps = std::env::args()
            .nth(2)
            .and_then(|r| r.parse().ok())
            .unwrap_or(10);
        let threads: Vec<usize> = std::env::args()
            .nth(3)
            .map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect())
            .unwrap_or_else(|| vec![1, 2]);
        return surface::main(reps, &threads);
    }
    if std::env::args().nth(1).as_deref() == Some("hash-sdf") {
        let reps = std::env::args()
            .nth(2)
            .and_then(|r| r.parse().ok())
            .unwrap_or(20);
        return hash_sdf::main(reps);
    }
    if std::env::args().nth(1).as_deref() == Some("adam") {
        let reps = std::env::args()
            .nth(2)
            .and_then(|r| r.parse().ok())
            .unwrap_or(10);
        return adam::main(reps);
    }
    if std::env::args().nth(1).as_deref() == Some("hash-surface") {
        let reps = std::env::args()
            .nth(2)
            .and_then(|r| r.parse().ok())
            .unwrap_or(10);
        return hash_surface::main(reps);
    }
    if std::env::args().nth(1).as_deref() == Some("frames") {
        let sizes: Vec<usize> = std::env::args()
            .nth(2)
            .map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect())
            .unwrap_or_else(|| vec![1, 10, 100, 1000, 10_000]);
        return frames_main(&sizes);
    }
    let sizes: Vec<usize> = std::env::args()
        .nth(1)
        .map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect())
        .unwrap_or_else(|| vec![1, 10, 100, 1000, 10_000]);
    let points = sample_points(200_000);
    // `-- 1,10 no-frames`: evaluation throughput only.
    let frames = std::env::args().nth(2).as_deref() != Some("no-frames");
    println!("| N | naive Mpts/s | per-point Mpts/s | culled Mpts/s | fidget JIT Mpts/s | per-point / fidget | culled / fidget | naive frame ms | per-point frame ms | culled frame ms | BVH nodes | lowering ms |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for &n in &sizes {
        let spheres = scattered_spheres(n);
        let shape = scene(&spheres);
        let naive = Lowered::new(
            &shape,
            LowerOptions {
                cull: false,
                ..Default::default()
            },
        );
        let t_lower = Instant::now();
        let culled = Lowered::new(&shape, LowerOptions::default());
        let lower_ms = t_lower.elapsed().as_secs_f64() * 1e3;
        // Check the evaluators agree before timing them.
        for p in points.iter().take(2000) {
            let (a, b) = (naive.dist(*p), culled.dist(*p));
            assert!(
                (a - b).abs() <= 1e-5 * a.abs().max(1.0),
                "naive {a} != culled {b} at {p}"
            );
        }
        let mut out = vec![0f32; points.len()];
        // Fewer points for the O(N) evaluators at large N keep runs short.
        let naive_pts = if n >= 1000 {
            &points[..20_000]
        } else {
            &points[..]
        };
        let t_naive = best_of(3, || {
            naive.eval_batch(naive_pts, &mut out[..naive_pts.len()])
        });
        let t_culled = best_of(3, || culled.eval_batch(&points, &mut out));
        // The evaluator before packed unions and batches (one point at a
        // time through a node per member), in the same run.
        let unpacked = Lowered::new(
            &shape,
            LowerOptions {
                pack: false,
                ..Default::default()
            },
        );
        let batch = out.clone();
        let t_point = best_of(3, || {
            for (p, o) in points.iter().zip(out.iter_mut()) {
                *o = unpacked.dist(*p);
            }
        });
        for (a, b) in batch.iter().zip(&out) {
            assert!(
                (a - b).abs() <= 1e-6 * a.abs().max(b.abs()),
                "batch {a} != per-point {b}"
            );
        }
        let fidget = peer::FidgetScene::new(&spheres);
        fidget.check_against(&culled, &points[..2000]);
        let (fidget_rate, _) = fidget.throughput(&points, n);
        let rate = |count: usize, t: f64| count as f64 / t / 1e6;
        let culled_rate = rate(points.len(), t_culled);
        println!(
            "| {n} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.1} | {:.1} | {:.1} | {} | {:.1} |",
            rate(naive_pts.len(), t_naive),
            rate(points.len(), t_point),
            culled_rate,
            fidget_rate / 1e6,
            rate(points.len(), t_point) * 1e6 / fidget_rate,
            culled_rate * 1e6 / fidget_rate,
            // One naive frame at large N already takes many seconds.
            if frames {
                frame_time(&naive, &shape, if n >= 1000 { 1 } else { 3 }) * 1e3
            } else {
                f64::NAN
            },
            if frames {
                frame_time(&unpacked, &shape, 3) * 1e3
            } else {
                f64::NAN
            },
            if frames {
                frame_time(&culled, &shape, 3) * 1e3
            } else {
                f64::NAN
            },
            culled.bvh_nodes,
            lower_ms,
        );
    }
}
