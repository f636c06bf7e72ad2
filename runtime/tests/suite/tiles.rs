//! The tiled tracer (culling per screen tile, rays starting where they
//! enter the kept members' box) against the plain per-pixel tracer it
//! replaced (`LowerOptions::tiles` off: every ray marches the whole scene
//! from `near`), on whole views: hit masks, depth, normals and colour, over
//! scenes that exercise each path of the culling and the tracer's hard
//! cases (grazing rays, large coordinates, bound SDFs, rays from inside).

use sdfl_runtime::render::{render_view, Needs, ViewBuffers, ViewScenes};
use sdfl_runtime::LowerOptions;

/// Renders the only view of `src` (a `render` statement) tiled and plain,
/// every quantity, as `sdfl run` lowers it.
fn both(src: &str) -> (ViewBuffers, ViewBuffers, sdfl_stdlib::RenderJob) {
    let program = sdfl_stdlib::load(&sdfl_lang::SourceFile::new("tiles.sdfl", src.to_string()))
        .unwrap_or_else(|e| panic!("{e:?}"));
    let job = &program.renders[0];
    let cam = &job.cameras[0];
    let needs = Needs {
        color: true,
        depth: true,
        normals: true,
        mask: true,
    };
    let view = |tiles: bool| {
        let options = LowerOptions {
            tiles,
            ..Default::default()
        };
        let mut scenes = ViewScenes::new(&job.scene, options, &job.cameras);
        let scene = scenes.for_view(cam);
        render_view(scene, job, cam, (job.width, job.height), needs, &|_| {})
    };
    (view(true), view(false), job.clone())
}

/// Pixels of a view whose hit point is farther from the surface than a
/// hit at the pixel footprint may be (`L·2·footprint·t`, with slack for
/// f32), by the f64 reference distance.
fn off_surface(view: &ViewBuffers, job: &sdfl_stdlib::RenderJob) -> usize {
    let cam = &job.cameras[0];
    let (w, h) = (job.width, job.height);
    let footprint = 1.0 / ((w.max(h) - 1) as f64 * cam.focal);
    let l = job.scene.lipschitz().max(1.0);
    let depth = view.depth.as_ref().unwrap();
    let mut off = 0;
    for j in 0..h {
        for i in 0..w {
            let t = depth[(j * w + i) as usize] as f64;
            if t > 0.0 {
                let (x, y) = cam.pixel_ndc(i, j, w, h);
                let p = cam.eye + cam.ray_direction(x, y) * t;
                let d = job.scene.distance(p).abs();
                off += (d > l * 2.0 * footprint * t + 1e-3 * (1.0 + t)) as usize;
            }
        }
    }
    off
}

/// What differs between the tiled and the plain view.
#[derive(Debug)]
struct Diff {
    pixels: usize,
    hits: u64,
    /// Pixels hit in one view and not the other.
    mask: usize,
    /// Over pixels both hit: the largest depth difference relative to the
    /// depth, and how many differ by more than 1e-3.
    depth: f32,
    depth_pixels: usize,
    /// Normal map and colour: the largest channel difference, the mean
    /// one, and pixels off by more than 24 in a channel (the golden test's
    /// measures).
    normal: (u8, f64, usize),
    colour: (u8, f64, usize),
    undecided: (u64, u64),
}

/// Channel differences, the largest over pixels both views hit or both
/// miss (`same`).
fn channels(a: &[u8], b: &[u8], same: &[bool]) -> (u8, f64, usize) {
    let (mut worst, mut sum, mut bad) = (0u8, 0u64, 0usize);
    for ((p, q), same) in a.chunks_exact(3).zip(b.chunks_exact(3)).zip(same) {
        let d = (0..3).map(|c| p[c].abs_diff(q[c])).max().unwrap();
        if *same {
            worst = worst.max(d);
        }
        sum += (0..3).map(|c| p[c].abs_diff(q[c]) as u64).sum::<u64>();
        bad += (d > 24) as usize;
    }
    (worst, sum as f64 / a.len() as f64, bad)
}

fn diff(tiled: &ViewBuffers, plain: &ViewBuffers) -> Diff {
    let (mt, mp) = (tiled.mask.as_ref().unwrap(), plain.mask.as_ref().unwrap());
    let (dt, dp) = (tiled.depth.as_ref().unwrap(), plain.depth.as_ref().unwrap());
    let same: Vec<bool> = mt.iter().zip(mp).map(|(a, b)| a == b).collect();
    let mut d = Diff {
        pixels: mt.len(),
        hits: plain.hits,
        mask: mt.iter().zip(mp).filter(|(a, b)| a != b).count(),
        depth: 0.0,
        depth_pixels: 0,
        normal: channels(
            tiled.normals.as_ref().unwrap(),
            plain.normals.as_ref().unwrap(),
            &same,
        ),
        colour: channels(
            tiled.color.as_ref().unwrap(),
            plain.color.as_ref().unwrap(),
            &same,
        ),
        undecided: (tiled.undecided, plain.undecided),
    };
    for k in 0..mt.len() {
        if mt[k] > 0 && mp[k] > 0 {
            let rel = (dt[k] - dp[k]).abs() / dp[k].max(1.0);
            d.depth = d.depth.max(rel);
            d.depth_pixels += (rel > 1e-3) as usize;
        }
    }
    d
}

/// The tiled view is the plain one. With `exact` hits (the absolute ε)
/// a hit point moves by at most the tolerance: the same hit mask (but
/// for rays the plain tracer left undecided), depth
/// within 1e-3 relative, normals and colour within 3 levels. Hits decided
/// at the pixel footprint (`hit_tolerance: "pixel"`) may land anywhere
/// along the stretch where the ray is within the footprint (long at
/// grazing angles, and `L` times longer for bound SDFs), which depends on
/// where the steps fall (and tiny shapes within a footprint of a ray may be
/// hit or passed): there at most 0.2 % of the pixels change between hit
/// and miss, every hit lies within the footprint of the surface (by the
/// f64 reference), and the normal map and colour stay within the golden test's tolerance
/// (mean difference ≤ 1 level, under 1 % of pixels off by more than 24;
/// colour: ≤ 0.5 and 0.5 %).
fn assert_same(name: &str, src: &str, exact: bool) -> Diff {
    let (tiled, plain, job) = both(src);
    let d = diff(&tiled, &plain);
    assert!(d.hits > 0, "{name}: nothing hit: {d:?}");
    assert!(d.undecided.0 <= d.undecided.1, "{name}: undecided: {d:?}");
    // Fewer steps: culled tiles and rays starting at their box.
    assert!(tiled.steps <= plain.steps, "{name}: steps");
    if exact {
        // Only rays the plain tracer left undecided (out of steps) may
        // be decided now.
        assert!(
            d.mask as u64 <= d.undecided.1 - d.undecided.0,
            "{name}: hit masks differ: {d:?}"
        );
        assert!(d.depth <= 1e-3, "{name}: depth: {d:?}");
        assert!(d.normal.0 <= 3 && d.colour.0 <= 3, "{name}: {d:?}");
    } else {
        assert!(d.mask * 500 <= d.pixels, "{name}: hit masks: {d:?}");
        // Every hit is one the footprint allows, as in the plain view.
        assert_eq!(off_surface(&tiled, &job), 0, "{name}: off the surface");
        assert_eq!(
            off_surface(&plain, &job),
            0,
            "{name}: plain, off the surface"
        );
        let (normal, colour) = (d.normal, d.colour);
        assert!(
            normal.1 <= 1.0 && normal.2 * 100 < d.pixels,
            "{name}: normals: {d:?}"
        );
        assert!(
            colour.1 <= 0.5 && colour.2 * 200 < d.pixels,
            "{name}: colour: {d:?}"
        );
    }
    d
}

/// `n` spheres (every `kinds`-th another kind: rotated boxes, tori) spread
/// over [-1, 1]³, as sdfl source.
fn scattered(n: usize, kinds: usize) -> String {
    let mut seed = 99u64;
    let mut next = move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let r = 0.5 / (n as f64).cbrt();
    let shapes: Vec<String> = (0..n)
        .map(|k| {
            let c = [next(), next(), next()].map(|x| 2.0 * x - 1.0);
            let c = format!("[{:.4}, {:.4}, {:.4}]", c[0], c[1], c[2]);
            let s = r * (0.5 + 0.5 * next());
            match k % kinds {
                0 => format!("sphere({s:.4}, center: {c})"),
                1 => format!(
                    "rotate(box(center: {c}, size: [{:.4}, {:.4}, {:.4}]), {:.3}, axis: [1, 1, 0])",
                    2.0 * s,
                    1.5 * s,
                    s,
                    next() * 3.0
                ),
                _ => format!("torus(center: {c}, major: {s:.4}, minor: {:.4})", 0.3 * s),
            }
        })
        .collect();
    format!("union({})", shapes.join(", "))
}

fn render(scene: &str, eye: [f64; 3], at: [f64; 3], rest: &str) -> String {
    format!(
        "render r {{ scene: {scene}, material: lambert(albedo: [0.8, 0.7, 0.6], \
         light: [-0.6, 0.8, -0.5], ambient: 0.2), \
         camera: look_at(eye: {eye:?}, at: {at:?}), size: [96, 96], {rest} \
         outputs: [image(\"i.png\")] }}"
    )
}

#[test]
fn scattered_unions_of_every_size_render_as_untiled() {
    // 10 spheres: a packed union, its tile union built beside it; 40 and
    // 300: a culled union with a member table (300: lists past the tile
    // maximum in places); mixed kinds: no member table.
    for (n, kinds) in [(1, 1), (10, 1), (40, 1), (300, 1), (60, 3)] {
        for (eye, tolerance) in [([0.3, 0.4, -3.5], "absolute"), ([2.5, 1.5, 2.0], "pixel")] {
            let src = render(
                &scattered(n, kinds),
                eye,
                [0.0, 0.0, 0.0],
                &format!("far: 8, hit_tolerance: \"{tolerance}\","),
            );
            assert_same(
                &format!("{n} shapes from {eye:?}"),
                &src,
                tolerance == "absolute",
            );
        }
    }
}

#[test]
fn cameras_inside_the_scene_and_inside_a_shape() {
    let scene = scattered(120, 1);
    // Among the spheres, looking through them; then from inside a sphere.
    assert_same(
        "among",
        &render(&scene, [0.05, 0.02, 0.01], [1.0, 0.2, 0.5], "far: 8,"),
        false,
    );
    assert_same(
        "among, absolute",
        &render(
            &scene,
            [0.05, 0.02, 0.01],
            [1.0, 0.2, 0.5],
            "far: 8, hit_tolerance: \"absolute\",",
        ),
        true,
    );
    let inside = format!("union(sphere(0.5, center: [0.1, 0, 0]), {scene})");
    let (tiled, plain, _) = both(&render(
        &inside,
        [0.1, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        "far: 8,",
    ));
    let d = diff(&tiled, &plain);
    assert_eq!(d.mask, 0, "{d:?}");
    // Every ray starts inside: hit at once, in both.
    assert_eq!(plain.hits as usize, d.pixels);
    assert_eq!(d.depth, 0.0);
}

/// The grazing scene (an unbounded plane: every tile keeps it, and
/// no ray starts past `near`) and a union of a plane with spheres.
#[test]
fn grazing_rays_over_a_plane() {
    for tolerance in ["pixel", "absolute"] {
        let src = render(
            "union(plane(), sphere(0.5, center: [0, 0.5, 3]))",
            [0.0, 0.3, 0.0],
            [0.0, 0.3, 1.0],
            &format!("far: 100, iterations: 64, hit_tolerance: \"{tolerance}\","),
        );
        assert_same(
            &format!("plane, {tolerance}"),
            &src,
            tolerance == "absolute",
        );
    }
    let src = render(
        &format!(
            "union(plane(height: -1.1), {})",
            scattered(50, 1)
                .strip_prefix("union(")
                .and_then(|s| s.strip_suffix(')'))
                .unwrap()
        ),
        [0.0, -1.0, -4.0],
        [0.0, -0.5, 0.0],
        "far: 40, hit_tolerance: \"pixel\",",
    );
    assert_same("plane and spheres", &src, false);
}

/// A scene and its camera 1e5 from the origin (lowered relative to the
/// camera), and a large one seen from far away (wide margins).
#[test]
fn large_coordinates_and_far_scenes() {
    let scene = format!("translate({}, [1e5, -2e4, 3e4])", scattered(40, 2));
    let src = render(
        &scene,
        [1e5 + 0.5, -2e4 + 0.3, 3e4 - 3.5],
        [1e5, -2e4, 3e4],
        "far: 8, hit_tolerance: \"pixel\",",
    );
    assert_same("at 1e5", &src, false);
    let src = render(
        &scene,
        [1e5 + 0.5, -2e4 + 0.3, 3e4 - 3.5],
        [1e5, -2e4, 3e4],
        "far: 8, hit_tolerance: \"absolute\", epsilon: 1e-4,",
    );
    assert_same("at 1e5, absolute", &src, true);
    let src = render(
        &format!("scale({}, 12)", scattered(40, 1)),
        [0.0, 0.0, -60.0],
        [0.0, 0.0, 0.0],
        "far: 100, hit_tolerance: \"pixel\",",
    );
    assert_same("from 60 away", &src, false);
}

/// Bound SDFs with Lipschitz constants above 1 (a displaced sheet, twisted
/// and bent plates) in a union with spheres, and a scene that is no union
/// (a smooth union: culled as one box).
#[test]
fn bound_shapes_and_scenes_that_are_not_unions() {
    let src = render(
        "union(displace(box(size: [3, 0.05, 3]), amplitude: 0.1, frequency: 8), \
         twist(box(center: [0, 0.8, 0], size: [1.6, 0.04, 1.2]), 2), \
         bend(box(center: [0, -0.8, 0], size: [1.6, 0.04, 1.2]), 1), \
         sphere(0.3, center: [1, 1, 0]), sphere(0.2, center: [-1, 0.5, 0.5]))",
        [0.8, 2.0, -3.0],
        [0.0, 0.0, 0.0],
        "far: 10, iterations: 400,",
    );
    assert_same("bound shapes", &src, false);
    let src = render(
        "union(displace(box(size: [3, 0.05, 3]), amplitude: 0.1, frequency: 8), \
         sphere(0.3, center: [1, 1, 0]), sphere(0.2, center: [-1, 0.5, 0.5]))",
        [0.8, 2.0, -3.0],
        [0.0, 0.0, 0.0],
        "far: 10, iterations: 400, hit_tolerance: \"absolute\",",
    );
    assert_same("bound shapes, absolute", &src, true);
    let src = render(
        "smooth_union(sphere(0.6), box(center: [0.5, 0.3, 0], size: [0.6, 0.6, 0.6]), k: 0.2)",
        [0.0, 0.5, -3.0],
        [0.0, 0.0, 0.0],
        "far: 8,",
    );
    assert_same("smooth union", &src, false);
}

/// Supersampled colour: sub-pixel rays reach half a pixel past the centres,
/// and the tile covers them.
#[test]
fn supersampled_silhouettes() {
    let src = render(
        &scattered(80, 2),
        [0.4, 0.2, -3.2],
        [0.0, 0.0, 0.0],
        "far: 8, samples_per_pixel: 4, hit_tolerance: \"pixel\",",
    );
    assert_same("4 samples", &src, false);
}

/// A scene that is no union keeps the plain tracer's steps (its tiles only
/// skip rays that miss its box): the same images bit for bit, here the
/// low-resolution views a training test learns from, where hits decided at
/// a wide pixel footprint would move with any other start.
#[test]
fn scenes_that_are_no_union_render_bit_for_bit_as_untiled() {
    let src = "let cams = orbit(radius: 3, up: [0, 1, 0], focal: 1.5, views: 12)\n\
               render r { scene: sphere(0.7), material: lambert(albedo: [0.9, 0.5, 0.2]), \
               camera: cams, size: [16, 16], outputs: [image(\"i.png\")] }";
    let program = sdfl_stdlib::load(&sdfl_lang::SourceFile::new("tiles.sdfl", src.to_string()))
        .unwrap_or_else(|e| panic!("{e:?}"));
    let job = &program.renders[0];
    let needs = Needs {
        color: true,
        depth: true,
        normals: true,
        mask: true,
    };
    for cam in &job.cameras {
        let view = |tiles: bool| {
            let options = LowerOptions {
                tiles,
                ..Default::default()
            };
            let mut scenes = ViewScenes::new(&job.scene, options, &job.cameras);
            render_view(scenes.for_view(cam), job, cam, (16, 16), needs, &|_| {})
        };
        let (tiled, plain) = (view(true), view(false));
        assert!(plain.hits > 0);
        assert_eq!(tiled.color, plain.color);
        assert_eq!(tiled.depth, plain.depth);
        assert_eq!(tiled.normals, plain.normals);
        assert_eq!(tiled.mask, plain.mask);
    }
}
