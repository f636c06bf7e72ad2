//! Effects on demand: soft shadows, ambient occlusion, fog and
//! supersampling against references, each computed only when asked (the
//! render's counters prove it), and their hard cases (grazing light, rays
//! starting on the surface, huge coordinates).

use glam::{DVec3, Vec3A};
use sdfl_lang::SourceFile;
use sdfl_runtime::effects::{soft_shadow, Counters, EffectStats, SurfacePoint};
use sdfl_runtime::render::{render_view, Needs, Plan};
use sdfl_runtime::{LowerOptions, Lowered};
use sdfl_stdlib::effects::{AmbientOcclusion, SoftShadows, Surroundings};
use sdfl_stdlib::RenderJob;

fn load(src: &str) -> sdfl_stdlib::Program {
    let file = SourceFile::new("effects.sdfl", src.to_string());
    sdfl_stdlib::load(&file).unwrap_or_else(|d| panic!("{}", sdfl_lang::render(&file, &d, false)))
}

/// The first render of `src`, traced: its colour (0..1 per channel) and
/// what its effects cost.
fn render(src: &str) -> (RenderJob, Vec<f64>, EffectStats, u64) {
    let program = load(src);
    let job = program.renders[0].clone();
    let scene = Lowered::new(&job.scene, LowerOptions::default());
    let plan = Plan::of(&job);
    let view = render_view(
        &scene,
        &job,
        &job.cameras[0],
        (job.width, job.height),
        Needs::from(&plan),
        &|_| {},
    );
    let colour = view
        .color
        .unwrap()
        .iter()
        .map(|c| *c as f64 / 255.0)
        .collect();
    (job, colour, view.effects, view.rays)
}

fn pixel(colour: &[f64], width: u32, i: u32, j: u32) -> DVec3 {
    let k = 3 * (j * width + i) as usize;
    DVec3::new(colour[k], colour[k + 1], colour[k + 2])
}

/// A sphere of radius 0.5 centred 1 above a ground plane, seen from above
/// at an angle; the light straight overhead puts the origin in the shadow's
/// core (the sphere covers 30° around the light from there), and the
/// camera's centre ray ends at the origin, past the sphere.
fn sphere_over_plane(material_options: &str) -> String {
    format!(
        "render s {{
           scene: union(plane(), sphere(0.5, center: [0, 1, 0])),
           material: lambert(albedo: [0.8, 0.6, 0.4], light: [0, 1, 0], ambient: 0.25{material_options}),
           camera: look_at([0, 3, -3], at: [0, 0, 0], focal: 1.5),
           size: [33, 33], far: 20,
           outputs: [image(\"s.png\")],
         }}"
    )
}

#[test]
fn a_scene_without_shadows_never_marches_a_shadow_ray() {
    let (_, _, fx, _) = render(&sphere_over_plane(""));
    assert_eq!(
        fx,
        EffectStats::default(),
        "no effect asked for, none computed"
    );
    let (job, _, fx, _) = render(&sphere_over_plane(", shadows: soft(k: 8, steps: 24)"));
    assert!(
        fx.shadow_rays > 0 && fx.shadow_steps >= fx.shadow_rays,
        "{fx:?}"
    );
    assert!(
        fx.shadow_steps <= 24 * fx.shadow_rays,
        "the step budget holds: {fx:?}"
    );
    assert_eq!(fx.occlusion_samples, 0, "occlusion was not asked for");
    assert!(!Plan::of(&job).shadows.is_empty());
    let (_, _, fx, _) = render(&sphere_over_plane(", ao: ao(samples: 3)"));
    assert_eq!((fx.shadow_rays, fx.shadow_steps), (0, 0));
    assert!(
        fx.occlusion_samples > 0 && fx.occlusion_samples % 3 == 0,
        "{fx:?}"
    );
    // A material asks, but no output shows colour: nothing is shaded.
    let src = sphere_over_plane(", shadows: soft(), ao: ao()").replace("image(", "depth(");
    let program = load(&src);
    let job = &program.renders[0];
    let plan = Plan::of(job);
    assert!(plan.shadows.is_empty() && plan.occlusion.is_empty());
    let scene = Lowered::new(&job.scene, LowerOptions::default());
    let view = render_view(
        &scene,
        job,
        &job.cameras[0],
        (33, 33),
        Needs::from(&plan),
        &|_| {},
    );
    assert_eq!(view.effects, EffectStats::default());
}

#[test]
fn the_shadow_core_is_darker_by_the_diffuse_term() {
    let (_, lit, _, _) = render(&sphere_over_plane(""));
    let (_, shadowed, _, _) = render(&sphere_over_plane(", shadows: soft(k: 8, steps: 64)"));
    // The centre pixel sees the origin: lit, albedo·(0.25 + 0.75·1); in the
    // core, albedo·0.25: darker by albedo·0.75·(n·l = 1).
    let albedo = DVec3::new(0.8, 0.6, 0.4);
    let (a, b) = (pixel(&lit, 33, 16, 16), pixel(&shadowed, 33, 16, 16));
    assert!((a - albedo).abs().max_element() < 1.5 / 255.0, "{a}");
    assert!((b - albedo * 0.25).abs().max_element() < 1.5 / 255.0, "{b}");
    // A corner of the image sees open ground, away from the shadow: the
    // same with and without shadows.
    for (i, j) in [(0, 0), (32, 0)] {
        let (a, b) = (pixel(&lit, 33, i, j), pixel(&shadowed, 33, i, j));
        assert!(
            (a - b).abs().max_element() < 1.5 / 255.0,
            "({i}, {j}): {a} vs {b}"
        );
    }
    // Everywhere: shadows only darken, and never below the ambient term.
    for (x, y) in lit.iter().zip(&shadowed) {
        assert!(*y <= *x + 1.0 / 255.0 && y.is_finite());
    }
}

/// A surface point of `src`'s scene with its counters.
fn at<'a>(scene: &'a Lowered, counters: &'a Counters, p: Vec3A, n: Vec3A) -> SurfacePoint<'a> {
    SurfacePoint {
        sdf: &*scene.root,
        inv_lipschitz: 1.0 / scene.lipschitz,
        p,
        n,
        far: 1e6,
        epsilon: 1e-5,
        pixel: 0.0,
        counters,
    }
}

fn lowered(scene: &str) -> Lowered {
    let program = load(&format!(
        "render s {{ scene: {scene}, camera: look_at([0, 3, -3]), outputs: [image(\"s.png\")] }}"
    ));
    Lowered::new(&program.renders[0].scene, LowerOptions::default())
}

#[test]
fn occlusion_is_one_far_from_occluders_and_less_in_a_corner() {
    let scene = lowered("union(plane(), box(size: [1, 1, 1], center: [0, 0.5, 0]))");
    let counters = Counters::default();
    let ao = AmbientOcclusion {
        samples: 8,
        distance: 0.5,
    };
    // The top of the box and open ground: nothing nearer than the surface.
    for (p, n) in [
        (Vec3A::new(0.0, 1.0, 0.0), Vec3A::Y),
        (Vec3A::new(5.0, 0.0, 5.0), Vec3A::Y),
        (Vec3A::new(0.5, 0.5, 0.0), Vec3A::X),
    ] {
        assert_eq!(at(&scene, &counters, p, n).ambient_visibility(&ao), 1.0);
    }
    // At the foot of a wall: the samples above 0.1 are closer to the wall
    // than their height: h_i - d_i = h_i - 0.1.
    let got = at(&scene, &counters, Vec3A::new(0.6, 0.0, 0.0), Vec3A::Y).ambient_visibility(&ao);
    let want = sdfl_stdlib::effects::occlusion(&ao, |h| h.min(0.1));
    assert!((got - want).abs() < 1e-5 && got < 0.7, "{got} vs {want}");
    assert_eq!(counters.stats().occlusion_samples, 4 * 8);
}

#[test]
fn shadow_rays_starting_on_the_surface_see_no_acne() {
    // An open plane lit from any angle above it: nothing blocks the light.
    // From a point exactly on the plane (and one a hair inside, as a hit
    // refined to epsilon may be), with k = 8 the visible fraction is 1 for
    // light 8° above the plane or higher, and never NaN down to grazing.
    let scene = lowered("plane()");
    let counters = Counters::default();
    let shadows = SoftShadows { k: 8.0, steps: 64 };
    for y in [0.0f32, -1e-6, 1e-6] {
        for deg in [90.0f32, 45.0, 20.0, 8.0, 1.0, 0.1, 1e-3] {
            let l = DVec3::new(
                0.0,
                (deg as f64).to_radians().sin(),
                (deg as f64).to_radians().cos(),
            );
            let v = at(&scene, &counters, Vec3A::new(0.3, y, 0.2), Vec3A::Y)
                .light_visibility(l, &shadows);
            assert!((0.0..=1.0).contains(&v), "{deg}°: {v}");
            if deg >= 8.0 {
                assert!(v > 0.999, "{deg}° at y {y}: self-shadowed ({v})");
            }
        }
    }
    // A sphere lit from +x: every point of its lit half facing the light by
    // 10° or more is fully visible, on the far half not asked (n·l ≤ 0).
    let scene = lowered("sphere(1)");
    for k in 0..200 {
        let a = k as f64 * 0.1;
        let n = DVec3::new(a.cos(), (a * 0.7).sin() * 0.9, a.sin()).normalize();
        if n.x < 0.2 {
            continue;
        }
        let nv: Vec3A = n.as_vec3().into();
        let v = at(&scene, &counters, nv, nv).light_visibility(DVec3::X, &shadows);
        assert!(v > 0.999, "n {n}: {v}");
    }
}

#[test]
fn grazing_light_and_huge_distances_stay_in_range() {
    // A ground plane 1e5 from the origin, with a sphere on it: shadows and
    // occlusion there are finite and in 0..1, and the core is still dark.
    let far = 1e5f32;
    let scene = lowered("union(plane(), sphere(0.5, center: [100000, 1, 0]))");
    let counters = Counters::default();
    let shadows = SoftShadows { k: 8.0, steps: 64 };
    let ao = AmbientOcclusion {
        samples: 5,
        distance: 0.25,
    };
    let under = at(&scene, &counters, Vec3A::new(far, 0.0, 0.0), Vec3A::Y);
    assert!(under.light_visibility(DVec3::Y, &shadows) < 1e-3);
    assert!(under.ambient_visibility(&ao) > 0.99, "open within 0.25");
    let open = at(&scene, &counters, Vec3A::new(far + 3.0, 0.0, 0.0), Vec3A::Y);
    assert!(open.light_visibility(DVec3::Y, &shadows) > 0.999);
    for deg in [1e-4f64, 0.01, 0.5, 3.0] {
        let l = DVec3::new(-(deg.to_radians().cos()), deg.to_radians().sin(), 0.0);
        let v = open.light_visibility(l, &shadows);
        assert!((0.0..=1.0).contains(&v), "{deg}°: {v}");
    }
    // The march itself: zero-length budgets are refused by the language, a
    // light straight into the surface is dark, a NaN scene is not NaN.
    let (v, steps) = soft_shadow(
        &*scene.root,
        1.0,
        Vec3A::new(far, 1e-3, 0.0),
        -Vec3A::Y,
        1e-3,
        1e6,
        &shadows,
    );
    assert_eq!((v, steps), (0.0, 1));
    // Every pixel of a render at 1e5 is finite.
    let (_, colour, fx, _) = render(
        "render s {
           scene: union(plane(), sphere(0.5, center: [100000, 1, 0])),
           material: phong(albedo: [0.8, 0.6, 0.4], lights: [light(direction: [0.3, 1, 0.2]), light(direction: [-1, 0.001, 0])],
                           shadows: soft(k: 16, steps: 48), ao: ao()),
           camera: look_at([100000, 3, -3], at: [100000, 0, 0]),
           size: [24, 24], far: 50, fog: fog(density: 1e-3),
           outputs: [image(\"s.png\")],
         }",
    );
    assert!(fx.shadow_rays > 0 && colour.iter().all(|c| c.is_finite()));
}

#[test]
fn fog_at_distance_d_follows_the_formula() {
    // A wall facing the camera 4 away, a constant colour: the centre pixel
    // is fog + (c - fog)·exp(-density·4); a miss is fogged as at `far`.
    let src = |density: &str| {
        format!(
            "render s {{
               scene: box(size: [4, 4, 0.1], center: [0, 0, 4.05]),
               material: [0.9, 0.2, 0.1], background: [0, 0, 1],
               camera: look_at([0, 0, 0], at: [0, 0, 1], focal: 1),
               size: [33, 33], far: 12, fog: {density},
               outputs: [image(\"s.png\")],
             }}"
        )
    };
    let fog = DVec3::new(0.5, 0.6, 0.7);
    for density in [0.05, 0.3, 2.0] {
        let (_, c, fx, _) = render(&src(&format!(
            "fog(color: [0.5, 0.6, 0.7], density: {density})"
        )));
        let keep = (-density * 4.0f64).exp();
        let want = fog + (DVec3::new(0.9, 0.2, 0.1) - fog) * keep;
        let got = pixel(&c, 33, 16, 16);
        assert!(
            (got - want).abs().max_element() <= 1.0 / 255.0,
            "{density}: {got} vs {want}"
        );
        // The corner pixels miss (the wall spans ±0.5 in NDC).
        let sky = fog + (DVec3::Z - fog) * (-density * 12.0f64).exp();
        let got = pixel(&c, 33, 0, 0);
        assert!(
            (got - sky).abs().max_element() <= 1.0 / 255.0,
            "{got} vs {sky}"
        );
        assert_eq!(fx, EffectStats::default(), "fog marches nothing");
    }
    // Without fog, the colour itself.
    let (_, c, _, _) = render(&src("false"));
    assert!(
        (pixel(&c, 33, 16, 16) - DVec3::new(0.9, 0.2, 0.1))
            .abs()
            .max_element()
            <= 1.0 / 255.0
    );
}

#[test]
fn supersampled_edges_give_the_analytic_coverage() {
    // A white half-plane (a thin box, rotated 30° about the view axis) on
    // black at z = 2, seen straight on: each pixel's value is the fraction
    // of its square that the half-plane covers, found here by integrating
    // over the pixel in NDC (400 × 400 points) with the camera's own rays.
    let src = |spp: u32, tolerance: &str| {
        format!(
            "render s {{
               scene: box(size: [8, 8, 0.002], center: [4.1, 0, 2.001]).rotate(30deg, axis: [0, 0, 1]),
               material: [1, 1, 1],
               camera: look_at([0, 0, 0], at: [0, 0, 1], focal: 1),
               size: [16, 16], far: 6, iterations: 200,
               samples_per_pixel: {spp}, hit_tolerance: \"{tolerance}\",
               outputs: [image(\"s.png\")],
             }}"
        )
    };
    let (job, _, _, _) = render(&src(1, "absolute"));
    let cam = &job.cameras[0];
    // The half-plane: points of z = 2 whose coordinate along the box's
    // rotated x axis exceeds 0.1.
    let axis = DVec3::new(30f64.to_radians().cos(), 30f64.to_radians().sin(), 0.0);
    let inside = |x: f64, y: f64| {
        let d = cam.ray_direction(x, y);
        let p = cam.eye + d * (2.0 / d.z);
        p.dot(axis) > 0.1
    };
    let coverage = |i: u32, j: u32| {
        let n = 400;
        let mut c = 0;
        for a in 0..n {
            for b in 0..n {
                let (x, y) = cam.pixel_ndc_at(
                    i as f64 - 0.5 + (a as f64 + 0.5) / n as f64,
                    j as f64 - 0.5 + (b as f64 + 0.5) / n as f64,
                    16,
                    16,
                );
                c += inside(x, y) as u32;
            }
        }
        c as f64 / (n * n) as f64
    };
    let edge: Vec<(u32, u32, f64)> = (0..16)
        .flat_map(|j| (0..16).map(move |i| (i, j)))
        .map(|(i, j)| (i, j, coverage(i, j)))
        .filter(|p| p.2 > 0.0 && p.2 < 1.0)
        .collect();
    assert!(edge.len() >= 10, "the edge crosses the image");
    // (mean |error|, mean signed error, worst |error|) over the edge pixels.
    let errors = |spp: u32, tolerance: &str| {
        let (_, c, _, rays) = render(&src(spp, tolerance));
        assert_eq!(rays, 16 * 16 * spp as u64);
        let e: Vec<f64> = edge
            .iter()
            .map(|(i, j, want)| pixel(&c, 16, *i, *j).x - want)
            .collect();
        let n = e.len() as f64;
        (
            e.iter().map(|x| x.abs()).sum::<f64>() / n,
            e.iter().sum::<f64>() / n,
            e.iter().fold(0.0f64, |m, x| m.max(x.abs())),
        )
    };
    // Hits within epsilon: the samples alone. One ray a pixel is 0 or 1;
    // the n-rooks grids resolve 1/n steps, so the error shrinks with n and
    // has no bias.
    let one = errors(1, "absolute");
    let (e16, e64) = (errors(16, "absolute"), errors(64, "absolute"));
    assert!(
        e16.0 < one.0 / 3.0 && e64.0 < e16.0,
        "{one:?} {e16:?} {e64:?}"
    );
    assert!(
        e16.2 < 0.1 && e64.2 < 0.05 && e64.0 < 0.025,
        "{e16:?} {e64:?}"
    );
    assert!(
        e16.1.abs() < 0.01 && e64.1.abs() < 0.01,
        "unbiased: {e16:?} {e64:?}"
    );
    // Hits at the pixel's resolution (the default): sub-pixel rays decide
    // within half of 1/n of a pixel, so silhouettes widen by less than
    // the 1/n coverage steps.
    for spp in [16, 64] {
        let (mean, bias, worst) = errors(spp, "pixel");
        let step = 1.0 / spp as f64;
        assert!(bias > -0.01 && bias < step, "{spp}: bias {bias}");
        assert!(
            mean < 2.5 * step + 0.01 && worst < 0.12,
            "{spp}: {mean}, {worst}"
        );
    }
}

#[test]
fn plan_lists_each_effect_with_its_cost() {
    let program = load(
        "render s {
           scene: union(plane(), sphere(0.5, center: [0, 1, 0])),
           material: phong(lights: [light(), light(direction: [-1, 1, 0])], shadows: soft(k: 4, steps: 20), ao: ao(samples: 6, distance: 0.3)),
           camera: look_at([0, 3, -3]), size: [10, 10], samples_per_pixel: 9, fog: fog(density: 0.1),
           outputs: [image(\"s.png\"), depth(\"d.png\")],
         }
         render plain { scene: sphere(), camera: look_at([0, 0, -3]), outputs: [image(\"p.png\")] }",
    );
    let plan = Plan::of(&program.renders[0]);
    let lines: Vec<String> = plan
        .effect_lines()
        .iter()
        .map(|(w, c)| format!("{w}: {c}"))
        .collect();
    let text = lines.join("\n");
    assert!(text.contains("soft shadows: k 4: up to 20 SDF evaluations per shaded sample per light facing it (2 lights)"), "{text}");
    assert!(
        text.contains("occlusion: 6 SDF evaluations per shaded sample"),
        "{text}"
    );
    assert!(text.contains("fog: exponential, density 0.1"), "{text}");
    assert!(
        text.contains("supersampling: 9 samples per pixel (3x3 rotated grid): 9x primary rays"),
        "{text}"
    );
    assert!(text.contains("plus the pixel centre's ray"), "{text}");
    assert!(Plan::of(&program.renders[1]).effect_lines().is_empty());
    // The work estimate counts them: 9 + 1 rays of 64 steps, and 9 shaded
    // samples of 2 × 20 + 6 evaluations, per pixel.
    let work = sdfl_stdlib::work::render_work(&program.renders[0], None);
    assert_eq!(work.evaluations, 100.0 * (64.0 * 10.0 + 9.0 * 46.0));
}

#[test]
fn supersampling_leaves_depth_and_the_mask_at_the_pixel_centre() {
    let src = |spp: u32| {
        format!(
            "render s {{
               scene: union(plane(), sphere(0.5, center: [0, 1, 0])),
               material: lambert(albedo: [0.8, 0.6, 0.4], light: [0, 1, 0]),
               camera: look_at([0, 3, -3], at: [0, 0, 0], focal: 1.5),
               size: [20, 20], far: 20, samples_per_pixel: {spp},
               outputs: [image(\"s.png\"), depth(\"d.png\"), mask(\"m.png\")],
             }}"
        )
    };
    let trace = |spp: u32| {
        let program = load(&src(spp));
        let job = &program.renders[0];
        let scene = Lowered::new(&job.scene, LowerOptions::default());
        let plan = Plan::of(job);
        render_view(
            &scene,
            job,
            &job.cameras[0],
            (20, 20),
            Needs::from(&plan),
            &|_| {},
        )
    };
    let (one, four) = (trace(1), trace(4));
    // Four rays a pixel for the colour, and the centre's for the rest.
    assert_eq!((one.rays, four.rays), (400, 400 * 5));
    assert_eq!(one.depth, four.depth);
    assert_eq!(one.mask, four.mask);
    assert_ne!(one.color, four.color, "edges are averaged");
    // Without a colour output, one ray a pixel whatever the setting.
    let program = load(&src(16).replace("image(\"s.png\"), ", ""));
    let job = &program.renders[0];
    let plan = Plan::of(job);
    assert_eq!(plan.samples_per_pixel, 1);
    let scene = Lowered::new(&job.scene, LowerOptions::default());
    let v = render_view(
        &scene,
        job,
        &job.cameras[0],
        (20, 20),
        Needs::from(&plan),
        &|_| {},
    );
    assert_eq!(v.rays, 400);
}
