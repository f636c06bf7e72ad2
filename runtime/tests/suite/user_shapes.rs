//! Shapes users write (`sdf(f, ...)`) in the runtime: the f32 leaf and its
//! lanes against the f64 reference, the tracer on a function that is not a
//! distance, a user-written torus rendered as the built-in one, and its
//! `param` arguments trained (gradients against finite differences, a
//! descent that converges).

use std::sync::Arc;

use glam::{DVec3, Vec3A};
use sdfl_lang::SourceFile;
use sdfl_runtime::lanes::{F8, P8};
use sdfl_runtime::render::{render_view, Needs, Plan};
use sdfl_runtime::sdf::Node;
use sdfl_runtime::trace::{sphere_trace, sphere_trace_packs, March, Step, TraceSettings};
use sdfl_runtime::train::fused::{loss_and_grad_f32, loss_and_grad_f64, traced, Batch};
use sdfl_runtime::train::TrainModel;
use sdfl_runtime::volume::{camera_rays, ImageSize, Stratified};
use sdfl_runtime::{LowerOptions, Lowered};
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::eval::globals_of;
use sdfl_stdlib::num::V3;
use sdfl_stdlib::shape::Shape;
use sdfl_stdlib::value::{LastInterval, Value};
use sdfl_stdlib::RenderJob;

const TORUS: &str =
    "fn torus_d(p, major: 1, minor: 0.25) { length([length(p.xy) - major, p.z]) - minor }";

/// Shapes written as IQ writes them (a torus, a rounded box, a twisted
/// prism, a gyroid shell), each as `let s = ...`.
const SHAPES: &[&str] = &[
    "let s = sdf(torus_d, major: 0.9, bound: [1.2, 1.2, 0.3])",
    "fn rbox(p, b: [0.5, 0.3, 0.4], r: 0.1) { let q = abs(p) - b; length(max(q, 0)) + min(max(q.x, max(q.y, q.z)), 0) - r }\nlet s = sdf(rbox, bound: [0.6, 0.4, 0.5])",
    "fn twisted(p, k: 1.5) { let c = cos(k * p.y); let s = sin(k * p.y); let q = [c * p.x - s * p.z, p.y, s * p.x + c * p.z]; let d = abs(q) - [0.4, 0.8, 0.2]; length(max(d, 0)) + min(max(d.x, max(d.y, d.z)), 0) }\nlet s = sdf(twisted, bound: [0.5, 0.8, 0.5])",
    "fn gyroid(p, scale: 6, t: 0.05) { let q = p * scale; abs(dot(sin(q), cos(q.yzx))) / scale - t }\nlet s = sdf(gyroid, bound: 1)",
];

fn shape(src: &str) -> Arc<Shape> {
    let src = format!("{TORUS}\n{src}");
    match globals_of(&src)
        .unwrap_or_else(|d| panic!("{src}: {d:?}"))
        .remove("s")
    {
        Some(Value::Shape(s)) => s,
        other => panic!("not a shape: {other:?}"),
    }
}

struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn v3(&mut self, r: f64) -> DVec3 {
        DVec3::new(self.next(), self.next(), self.next()) * (2.0 * r) - DVec3::splat(r)
    }
}

#[test]
fn the_f32_leaf_and_its_lanes_match_the_f64_reference() {
    let mut rng = Lcg(7);
    for src in SHAPES {
        let s = shape(src);
        assert!(matches!(&*s, Shape::User(_)));
        // Alone, and translated inside a union (the leaf in a frame).
        let moved = Shape::Union(vec![
            Arc::new(Shape::Translate(
                s.clone(),
                DVec3::new(0.3, -0.2, 0.1).into(),
            )),
            Arc::new(Shape::from(sdfl_stdlib::shape::Sphere {
                radius: 0.2.into(),
                center: DVec3::new(3.0, 0.0, 0.0).into(),
            })),
        ]);
        for scene in [(*s).clone(), moved] {
            let l = Lowered::new(&scene, LowerOptions::default());
            let points: Vec<DVec3> = (0..256).map(|_| rng.v3(2.5)).collect();
            let pts: Vec<Vec3A> = points.iter().map(|p| p.as_vec3().into()).collect();
            let mut batch = vec![0.0f32; pts.len()];
            l.eval_batch(&pts, &mut batch);
            for ((p, q), b) in points.iter().zip(&pts).zip(&batch) {
                let want = scene.distance(*p);
                let got = l.dist(*q);
                let tol = 2e-5 * (1.0 + want.abs());
                assert!(
                    (got as f64 - want).abs() <= tol,
                    "{src} at {p}: f32 {got}, f64 {want}"
                );
                assert!(
                    (*b as f64 - want).abs() <= tol,
                    "{src} at {p}: lanes {b}, f64 {want}"
                );
            }
        }
    }
}

/// The f32 value the tape's own interpreter gives (`clipped` over the
/// baked tape): what the compiled register code must equal bit for bit.
fn interpreted(s: &Shape, p: Vec3A) -> f32 {
    let Shape::User(u) = s else {
        panic!("not a user shape")
    };
    let baked = u.tape.bake(&u.arg_values());
    let q = V3::new(p.x, p.y, p.z);
    sdfl_stdlib::shape::user::clipped(q, &u.bound, 1.0 / u.lipschitz, |q| baked.eval(q, &[]))
}

/// Points that test the box: random ones in and around it, on its faces,
/// edges and corners (and an ulp either side), far away and huge.
fn box_points(s: &Shape, rng: &mut Lcg) -> Vec<Vec3A> {
    let b = s.bounds().expect("a user shape is bounded");
    let (lo, hi) = (b.min.as_vec3(), b.max.as_vec3());
    let mut pts: Vec<Vec3A> = (0..300).map(|_| rng.v3(2.5).as_vec3().into()).collect();
    for i in 0..27 {
        let pick = |k: usize, l: f32, h: f32| match (i / 3usize.pow(k as u32)) % 3 {
            0 => l,
            1 => 0.5 * (l + h),
            _ => h,
        };
        let c = Vec3A::new(
            pick(0, lo.x, hi.x),
            pick(1, lo.y, hi.y),
            pick(2, lo.z, hi.z),
        );
        pts.push(c);
        pts.push(Vec3A::new(c.x.next_up(), c.y.next_down(), c.z.next_up()));
        pts.push(Vec3A::new(c.x.next_down(), c.y.next_up(), c.z.next_down()));
    }
    pts.extend([
        Vec3A::new(1e20, -3e19, 7.0),
        Vec3A::new(-1e30, 1e30, 1e30),
        Vec3A::new(1e-30, -1e-30, 0.0),
        Vec3A::new(-0.0, 0.0, -0.0),
    ]);
    pts
}

/// Operations with a constant on either side (fused after the closure
/// of the value they read), ties of `min`/`max` with the constant first.
const CONSTANT_FIRST: &str = "fn mixed(p) { min(0.3, max(0.2, 1.5 - length(p)) / 2) + 2 * abs(p.y) - 1 / (2 + p.x * p.x) + max(0, p.z) - min(p.x, 0) }\nlet s = sdf(mixed, bound: [1, 0.8, 0.6])";

#[test]
fn compiled_code_and_its_columns_equal_the_tape_interpreter_bit_for_bit() {
    let mut rng = Lcg(11);
    // The sheet: divided by its derived bound (the products by 1 the
    // others skip are taken).
    for src in SHAPES.iter().chain(&[CONSTANT_FIRST, SHEET]) {
        let s = shape(src);
        let l = Lowered::new(&s, LowerOptions::default());
        let pts = box_points(&s, &mut rng);
        let mut batch = vec![0.0f32; pts.len()];
        l.eval_batch(&pts, &mut batch);
        for (p, b) in pts.iter().zip(&batch) {
            let want = interpreted(&s, *p);
            let got = l.dist(*p);
            assert_eq!(
                got.to_bits(),
                want.to_bits(),
                "{src} at {p}: {got} vs {want}"
            );
            assert_eq!(
                b.to_bits(),
                want.to_bits(),
                "{src} at {p}: lanes {b} vs {want}"
            );
        }
    }
}

#[test]
fn placed_user_shapes_in_packs_equal_them_point_by_point() {
    // Moved, turned and scaled (the leaf's frame and its scale factor),
    // batches of every length up to three passes of 32 packs and a part.
    let mut rng = Lcg(13);
    for src in [
        "let s = scale(rotate(translate(sdf(torus_d, bound: [1.5, 1.5, 0.5]), [0.2, -0.1, 0.3]), 0.7, axis: [1, 1, 0]), 1.7)",
        "fn sheet(p) { abs(p.y - 0.15 * sin(12 * p.x) * sin(12 * p.z)) - 0.01 }\nlet s = scale(sdf(sheet, bound: [2, 0.2, 2]), 0.5)",
    ] {
        let s = shape(src);
        let l = Lowered::new(&s, LowerOptions::default());
        let pts: Vec<Vec3A> = (0..800).map(|_| rng.v3(3.0).as_vec3().into()).collect();
        for len in [1, 7, 8, 9, 16, 17, 255, 256, 257, 800] {
            let mut batch = vec![0.0f32; len];
            l.eval_batch(&pts[..len], &mut batch);
            for (p, b) in pts.iter().zip(&batch) {
                let want = l.dist(*p);
                assert_eq!(b.to_bits(), want.to_bits(), "{src} at {p}, {len}: {b} vs {want}");
            }
        }
    }
}

/// A function whose `n` terms are all live at once before they are summed:
/// `n` constants and `n` products in registers together.
fn wide(n: usize) -> Arc<Shape> {
    let mut body = String::new();
    for i in 0..n {
        body.push_str(&format!("let a{i} = p.x * {}; ", 1.0 + i as f64 / 1024.0));
    }
    // Summed in parts of 100 (an expression holds at most 512 operators).
    let names: Vec<String> = (0..n).map(|i| format!("a{i}")).collect();
    let mut parts = Vec::new();
    for (k, chunk) in names.chunks(100).enumerate() {
        body.push_str(&format!("let t{k} = {}; ", chunk.join(" + ")));
        parts.push(format!("t{k}"));
    }
    // Up to 300 terms also read a second time (kept as shared values).
    let again = match names.len() {
        0..=300 => format!(" + max({}) / 8", names.join(", ")),
        _ => String::new(),
    };
    let src = format!(
        "fn wide(p) {{ {body} ({}) / {n}{again} + length(p.yz) - 1 }}\nlet s = sdf(wide, bound: 1.5)",
        parts.join(" + ")
    );
    shape(&src)
}

#[test]
fn code_with_more_registers_than_the_stack_holds_equals_the_interpreter() {
    let mut rng = Lcg(12);
    // 40 terms: more shared values than the small per-point array holds,
    // fewer packs per pass; 300: past the larger array, on the heap; 1100:
    // past the column buffer, on the heap.
    for n in [40, 300, 1100] {
        let s = wide(n);
        let Shape::User(u) = &*s else {
            panic!("not a user shape")
        };
        assert!(u.tape.ops().len() > 2 * n, "{n} terms compiled");
        let l = Lowered::new(&s, LowerOptions::default());
        let pts: Vec<Vec3A> = (0..200).map(|_| rng.v3(2.0).as_vec3().into()).collect();
        let mut batch = vec![0.0f32; pts.len()];
        l.eval_batch(&pts, &mut batch);
        for (p, b) in pts.iter().zip(&batch) {
            let want = interpreted(&s, *p);
            assert_eq!(l.dist(*p).to_bits(), want.to_bits(), "{n} terms at {p}");
            assert_eq!(b.to_bits(), want.to_bits(), "{n} terms at {p}: lanes");
        }
    }
}

/// First crossing of the f64 reference along a ray, by dense marching.
fn first_crossing(shape: &Shape, o: DVec3, d: DVec3, far: f64) -> Option<f64> {
    let mut t = 0.0;
    while t < far {
        if shape.distance(o + d * t) < 0.0 {
            return Some(t);
        }
        t += 1e-4;
    }
    None
}

#[test]
fn the_tracer_does_not_tunnel_through_a_function_that_is_no_distance() {
    // A thin wavy sheet, steep across: 0.15·12 = 1.8 times its waves.
    let sheet = shape(
        "fn sheet(p) { abs(p.y - 0.15 * sin(12 * p.x) * sin(12 * p.z)) - 0.01 }\nlet s = sdf(sheet, bound: [2, 0.2, 2])",
    );
    let Shape::User(u) = &*sheet else {
        unreachable!()
    };
    // Its gradient's norm reaches about 2 (the derived bound is above).
    assert!(u.lipschitz > 2.0, "derived {}", u.lipschitz);
    // The same function declared a distance: steps overshoot.
    let unscaled = shape(
        "fn sheet(p) { abs(p.y - 0.15 * sin(12 * p.x) * sin(12 * p.z)) - 0.01 }\nlet s = sdf(sheet, bound: [2, 0.2, 2], lipschitz: 1)",
    );
    let (l, lu) = (
        Lowered::new(&sheet, LowerOptions::default()),
        Lowered::new(&unscaled, LowerOptions::default()),
    );
    let settings = TraceSettings {
        near: 0.0,
        far: 20.0,
        max_steps: 4000,
        epsilon: 1e-5,
        footprint: 0.0,
        relax: false,
        lipschitz: l.lipschitz,
    };
    let mut tunnelled = 0;
    for k in 0..40 {
        let x = -1.2 + 2.4 * k as f64 / 39.0;
        let o = DVec3::new(x, 1.0, 0.37 * x);
        let d = DVec3::new(0.6, -1.0, 0.2).normalize();
        let expected = first_crossing(&sheet, o, d, 4.0).expect("the ray crosses the sheet");
        let (of, df): (Vec3A, Vec3A) = (o.as_vec3().into(), d.as_vec3().into());
        let h = sphere_trace(&*l.root, of, df, &settings);
        assert!(h.hit, "ray {k} missed");
        assert!(
            (h.t as f64 - expected).abs() < 2e-3,
            "ray {k}: hit at {} but the surface is first crossed at {expected}",
            h.t
        );
        let u = sphere_trace(&*lu.root, of, df, &settings);
        if !u.hit || (u.t as f64 - expected).abs() > 2e-3 {
            tunnelled += 1;
        }
    }
    // The division by the derived bound is what makes this work.
    assert!(tunnelled > 0);
}

fn render_job(scene: Arc<Shape>) -> RenderJob {
    let src = "render t { scene: sphere(), material: rainbow(), camera: look_at(eye: [1.5, -2.2, 1.8]), size: [96, 96], outputs: [image(\"t.png\"), mask(\"m.png\")] }";
    let mut job = sdfl_stdlib::load(&SourceFile::new("t.sdfl", src))
        .expect("loads")
        .renders
        .remove(0);
    job.scene = scene;
    job
}

#[test]
fn a_user_written_torus_renders_as_the_built_in_torus() {
    // A box with a margin: silhouettes lie inside it, where the value is
    // the torus's exactly (beyond it, only a bound: grazing rays there
    // come closer by its measure).
    let user = shape("let s = sdf(torus_d, bound: [1.5, 1.5, 0.5])");
    let builtin = sdfl_stdlib::shape::Torus {
        major: 1.0.into(),
        minor: 0.25.into(),
        center: DVec3::ZERO.into(),
        axis: sdfl_stdlib::shape::Axis::Z,
    };
    let images: Vec<_> = [user, Arc::new(Shape::from(builtin))]
        .into_iter()
        .map(|s| {
            let job = render_job(s);
            let l = Lowered::new(&job.scene, LowerOptions::default());
            let plan = Plan::of(&job);
            render_view(
                &l,
                &job,
                &job.cameras[0],
                (96, 96),
                Needs::from(&plan),
                &|_| {},
            )
        })
        .collect();
    let (a, b) = (&images[0], &images[1]);
    let (ma, mb) = (a.mask.as_ref().unwrap(), b.mask.as_ref().unwrap());
    let hits = mb.iter().filter(|&&m| m > 0).count();
    assert!(hits > 500, "the torus is in view");
    let mask_diff = ma.iter().zip(mb).filter(|(x, y)| x != y).count();
    assert!(
        mask_diff * 200 <= hits,
        "{mask_diff} of {hits} pixels hit one torus only"
    );
    let (ca, cb) = (a.color.as_ref().unwrap(), b.color.as_ref().unwrap());
    let off = ca
        .iter()
        .zip(cb)
        .filter(|(x, y)| x.abs_diff(**y) > 3)
        .count();
    assert!(
        off * 50 <= hits * 3,
        "{off} colour channels differ by more than 3/255 ({hits} hits)"
    );
    let mean = ca
        .iter()
        .zip(cb)
        .map(|(x, y)| x.abs_diff(*y) as f64)
        .sum::<f64>()
        / ca.len() as f64;
    assert!(mean < 1.0, "mean difference {mean}/255");
}

/// The wavy sheet (not a distance: its values are divided by the derived
/// bound, and the tracer's steps by the scene's).
const SHEET: &str = "fn sheet(p) { abs(p.y - 0.15 * sin(12 * p.x) * sin(12 * p.z)) - 0.01 }\nlet s = sdf(sheet, bound: [2, 0.2, 2])";

#[test]
fn rays_marched_in_packs_end_as_rays_marched_one_by_one() {
    let mut rng = Lcg(21);
    for src in SHAPES.iter().chain(&[CONSTANT_FIRST, SHEET]) {
        let s = shape(src);
        let l = Lowered::new(&s, LowerOptions::default());
        assert!(l.root.traces_in_packs(), "a user shape traces in packs");
        // Relaxed and plain steps, footprint hits and their refinement,
        // steps running out (none at all too), rays ending at `far`, from
        // inside the box and outside it; 37 rays (a partial pack).
        for (k, (relax, footprint, max_steps, far)) in [
            (false, 0.0, 200, 8.0),
            (true, 2e-3, 200, 8.0),
            (true, 2e-2, 12, 8.0),
            (false, 0.0, 3, 8.0),
            (true, 1e-3, 0, 8.0),
            (true, 1e-3, 200, 1.3),
        ]
        .into_iter()
        .enumerate()
        {
            let settings = TraceSettings {
                near: if k == 5 { 0.2 } else { 0.0 },
                far,
                max_steps,
                epsilon: 1e-5,
                footprint,
                relax,
                lipschitz: l.lipschitz,
            };
            let eye: Vec3A = rng.v3(if k % 2 == 0 { 3.0 } else { 0.5 }).as_vec3().into();
            let rays: Vec<(Vec3A, Step)> = (0..37)
                .map(|_| {
                    let aim: Vec3A = rng.v3(0.6).as_vec3().into();
                    let dir = (aim - eye).normalize();
                    (dir, Step::At(Vec3A::ZERO))
                })
                .collect();
            let marches = rays
                .iter()
                .map(|(dir, _)| March::start(eye, *dir, &settings))
                .collect();
            let packed = sphere_trace_packs(&*l.root, marches);
            let mut hits = 0;
            for ((dir, _), got) in rays.iter().zip(&packed) {
                let want = sphere_trace(&*l.root, eye, *dir, &settings);
                hits += want.hit as usize;
                assert_eq!(
                    (got.t.to_bits(), got.hit, got.steps, got.undecided),
                    (want.t.to_bits(), want.hit, want.steps, want.undecided),
                    "{src}, settings {k}, ray {dir}: {got:?} vs {want:?}"
                );
            }
            // Every other eye sits outside the box: some rays hit.
            assert!(max_steps < 20 || k % 2 == 1 || hits > 0, "{src}, {k}");
        }
    }
}

/// A scene's root marched ray by ray (its distances unchanged).
struct OneByOne(Box<dyn Node>);

impl Node for OneByOne {
    fn dist(&self, p: Vec3A) -> f32 {
        self.0.dist(p)
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        self.0.dist_id(p)
    }
    fn dist_packs(&self, p: &[P8], out: &mut [F8]) {
        self.0.dist_packs(p, out)
    }
}

#[test]
fn a_frame_traced_in_packs_equals_the_frame_traced_ray_by_ray() {
    let frames: Vec<_> = [true, false]
        .into_iter()
        .map(|packs| {
            let mut job = render_job(shape("let s = sdf(torus_d, bound: [1.5, 1.5, 0.5])"));
            // Two rays per pixel: colour from sub-pixel rays (their own
            // settings), depth and normals from the pixel centres.
            job.samples_per_pixel = 2;
            let mut l = Lowered::new(&job.scene, LowerOptions::default());
            if !packs {
                l.root = Box::new(OneByOne(l.root));
            }
            assert_eq!(l.root.traces_in_packs(), packs);
            let needs = Needs {
                color: true,
                depth: true,
                normals: true,
                mask: true,
            };
            render_view(&l, &job, &job.cameras[0], (64, 48), needs, &|_| {})
        })
        .collect();
    let (a, b) = (&frames[0], &frames[1]);
    assert!(a.hits > 100, "the torus is in view: {} hits", a.hits);
    assert_eq!(
        (a.hits, a.steps, a.rays, a.undecided),
        (b.hits, b.steps, b.rays, b.undecided)
    );
    assert_eq!(a.color, b.color);
    assert_eq!(a.mask, b.mask);
    assert_eq!(a.normals, b.normals);
    let bits = |d: &Option<Vec<f32>>| {
        d.as_ref()
            .map(|d| d.iter().map(|x| x.to_bits()).collect::<Vec<_>>())
    };
    assert_eq!(bits(&a.depth), bits(&b.depth));
}

fn model(field: &str) -> TrainModel {
    let src = format!(
        "{TORUS}\nlet cams = [look_at(eye: [0, 0, -3])]\n\
         train t {{ model: {field}, data: render_views(sdf_volume(sphere()), cameras: cams, size: [4, 4]) }}"
    );
    let program = sdfl_stdlib::load(&SourceFile::new("case.sdfl", src))
        .unwrap_or_else(|e| panic!("{field}: {e:?}"));
    TrainModel::new(program.trains[0].model.as_sdf().expect("analytic"))
}

fn batch(eye: DVec3, targets: Option<Vec<[f32; 3]>>) -> Batch {
    let cam = Camera::look_at(eye, DVec3::ZERO, DVec3::Y, 1.0);
    let rays = camera_rays(
        &cam,
        ImageSize {
            width: 8,
            height: 8,
        },
    )
    .unwrap();
    let n = rays.len();
    Batch {
        rays,
        targets: targets
            .unwrap_or_else(|| (0..n).map(|k| [0.5, 0.3 + 0.01 * k as f32, 0.2]).collect()),
        coverage: Vec::new(),
        depths: Stratified::new(48, 0.0, 6.0).unwrap().depths(),
        samples: 48,
        shared: true,
        last_interval: LastInterval::Zero,
        seed: 0,
        step: 0,
        points: Vec::new(),
    }
}

const TRAINED: &str = "sdf_volume(translate(sdf(torus_d, major: param(0.8), minor: param(0.3), bound: [1.3, 1.3, 0.4]), param([0.05, 0.1, 0])), color: [0.9, 0.5, 0.2])";

#[test]
fn parameter_gradients_match_finite_differences_on_every_kernel() {
    let m = model(TRAINED);
    assert_eq!(m.scalars, 5);
    let b = batch(DVec3::new(0.3, 0.4, -3.0), None);
    let v0 = m.initial_values();
    let g = loss_and_grad_f64(&m, &v0, &b, 1.0).grad;
    let loss = |v: &[f64]| loss_and_grad_f64(&m, v, &b, 1.0).loss;
    let h = 1e-6;
    for i in 0..m.scalars {
        let (mut up, mut down) = (v0.clone(), v0.clone());
        up[i] += h;
        down[i] -= h;
        let fd = (loss(&up) - loss(&down)) / (2.0 * h);
        assert!(
            (g[i] - fd).abs() <= 1e-7 + 1e-4 * fd.abs(),
            "scalar {i}: kernel {} vs finite differences {fd}",
            g[i]
        );
    }
    assert!(
        g.iter().all(|x| x.abs() > 1e-7),
        "every argument reaches the loss: {g:?}"
    );
    // The tape kernel (training's fast path) traces it and agrees.
    let v32: Vec<f32> = v0.iter().map(|&x| x as f32).collect();
    assert!(
        traced(&m, &v32, &b).is_some(),
        "a user torus is on the tape"
    );
    let a = loss_and_grad_f32(&m, &v32, &b, 1.0);
    let scale = g.iter().fold(1e-3f64, |m, x| m.max(x.abs()));
    for (x, y) in a.grad.iter().zip(&g) {
        assert!((x - y).abs() <= 2e-3 * scale, "tape {x} vs f64 {y}");
    }
}

#[test]
fn a_user_torus_fits_the_built_in_one() {
    // Targets: the built-in torus (major 1, minor 0.25) rendered by the
    // f64 reference from three views; the user torus starts at 0.8 / 0.3.
    // (A `train` needs a parameter: the colour, at the value both use.)
    let target = model("sdf_volume(torus(major: 1, minor: 0.25), color: param([0.9, 0.5, 0.2]))");
    let m = model(
        "sdf_volume(sdf(torus_d, major: param(0.8), minor: param(0.3), bound: [1.4, 1.4, 0.5]), color: [0.9, 0.5, 0.2])",
    );
    let eyes = [
        DVec3::new(0.3, 0.4, -3.0),
        DVec3::new(2.6, 0.5, -1.4),
        DVec3::new(-0.4, 2.7, 1.2),
    ];
    // Targets from the reference: its colours where the loss is 0.
    let batches: Vec<Batch> = eyes
        .iter()
        .map(|&e| {
            let probe = batch(e, None);
            let colours = sdfl_runtime::train::fused::render_rays(
                &target,
                &[0.9, 0.5, 0.2],
                &probe.rays,
                &probe.depths,
                probe.last_interval,
            )
            .iter()
            .map(|c| [c.colour.x, c.colour.y, c.colour.z])
            .collect();
            batch(e, Some(colours))
        })
        .collect();
    // Adam on the summed loss.
    let mut v = m.initial_values();
    let (mut mo, mut ve) = (vec![0.0; v.len()], vec![0.0; v.len()]);
    let lr = 0.01;
    for step in 1..=400 {
        let mut g = vec![0.0; v.len()];
        for b in &batches {
            for (gi, x) in g.iter_mut().zip(loss_and_grad_f64(&m, &v, b, 1.0).grad) {
                *gi += x;
            }
        }
        for i in 0..v.len() {
            mo[i] = 0.9 * mo[i] + 0.1 * g[i];
            ve[i] = 0.999 * ve[i] + 0.001 * g[i] * g[i];
            let (mh, vh) = (
                mo[i] / (1.0 - 0.9f64.powi(step)),
                ve[i] / (1.0 - 0.999f64.powi(step)),
            );
            v[i] -= lr * mh / (vh.sqrt() + 1e-8);
        }
    }
    assert!(
        (v[0] - 1.0).abs() < 0.02 && (v[1] - 0.25).abs() < 0.02,
        "fitted {v:?}"
    );
}
