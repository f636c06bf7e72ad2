//! The neural surface's gradient against finite differences, β's schedule,
//! fine samples at the surface, finite colours.

use sdfl_runtime::neural::field::Samples;
use sdfl_runtime::neural::surface::skip::{Selection, SkipGrid};
use sdfl_runtime::neural::surface::*;
use sdfl_runtime::train::fused::Batch;
use sdfl_runtime::train::Objective;
use sdfl_runtime::volume::importance::Spacing;
use sdfl_runtime::volume::{ImageSize, Ray, SplitMix64, Stratified};
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::value::{
    DensityKind, Harmonic as HarmonicSpec, LastInterval, Loss, LossKind, NeuralSdf, NeuralSurface,
};

fn spec(density: DensityKind, view_dependent: bool) -> NeuralSurface {
    NeuralSurface {
        sdf: NeuralSdf {
            encoding: sdfl_stdlib::value::Encoding::Harmonic(HarmonicSpec {
                freqs: 2,
                include_input: true,
            }),
            layers: 2,
            width: 8,
            skips: vec![],
            beta: 20.0,
            radius: 0.5,
            seed: 3,
            level_every: 0,
            eikonal_step: None,
        },
        density,
        alpha: 10.0,
        beta: 0.1,
        train_beta: false,
        beta_end: None,
        color_layers: 2,
        color_width: 8,
        color_freqs: 2,
        view_dependent,
        background: [0.2, 0.3, 0.4],
        fine: 0,
    }
}

fn batch(rays: usize, samples: usize) -> Batch {
    let mut rng = SplitMix64::new(9);
    let rays: Vec<Ray> = (0..rays)
        .map(|_| {
            let o = [rng.next_f32() - 0.5, rng.next_f32() - 0.5, -2.0];
            let d = [
                0.2 * (rng.next_f32() - 0.5),
                0.2 * (rng.next_f32() - 0.5),
                1.0,
            ];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            Ray {
                origin: o,
                dir: d.map(|x| x / len),
                view: 0,
                pixel: 0,
            }
        })
        .collect();
    let targets = (0..rays.len())
        .map(|_| [rng.next_f32(), rng.next_f32(), rng.next_f32()])
        .collect();
    let depths = (0..samples)
        .map(|i| 1.0 + 2.0 * i as f32 / (samples - 1) as f32)
        .collect();
    Batch {
        rays,
        targets,
        coverage: Vec::new(),
        depths,
        samples,
        shared: true,
        last_interval: LastInterval::Zero,
        seed: 1,
        step: 0,
        points: Vec::new(),
    }
}

/// Every parameter's gradient (a sample of them) against central
/// differences of the loss, with and without view dependence, for both
/// densities, MSE and eikonal together.
#[test]
fn gradient_matches_finite_differences() {
    let losses = [
        Loss {
            kind: LossKind::Mse,
            weight: 1.0,
        },
        Loss {
            kind: LossKind::Eikonal,
            weight: 0.1,
        },
    ];
    // A scheduled β (the last two) is a value, not a weight: the
    // networks' gradient is checked mid-schedule, and β's is zero.
    for (density, view, train_beta, beta_end) in [
        (DensityKind::VolSdf, true, false, None),
        (DensityKind::Neus, false, false, None),
        (DensityKind::VolSdf, false, true, None),
        (DensityKind::Neus, true, true, None),
        (DensityKind::VolSdf, true, false, Some(0.02)),
        (DensityKind::Neus, false, false, Some(0.02)),
    ] {
        let s = NeuralSurface {
            train_beta,
            beta_end,
            ..spec(density, view)
        };
        let mut obj = SurfaceObjective::new(&s, &losses).unwrap().with_steps(10);
        let mut values = obj.initial();
        obj.at_step(5, &mut values);
        let b = batch(7, 24);
        let mut grad = vec![0.0; values.len()];
        obj.loss_and_grad(&values, &b, 1.0, &mut grad).unwrap();
        let weights = values.len() - usize::from(beta_end.is_some());
        if beta_end.is_some() {
            assert_eq!(grad[weights], 0.0, "a scheduled β is not trained");
        }
        let mut rng = SplitMix64::new(4);
        let mut checked = 0;
        for n in 0..60 {
            // A trained β is the last value: always checked.
            let i = if train_beta && n == 0 {
                values.len() - 1
            } else {
                rng.below(weights as u64) as usize
            };
            let h = 1e-3;
            let at = |x: f32, obj: &mut SurfaceObjective| {
                let mut v = values.clone();
                v[i] = x;
                let mut g = vec![0.0; v.len()];
                obj.loss_and_grad(&v, &b, 1.0, &mut g).unwrap()
            };
            let fd = (at(values[i] + h, &mut obj) - at(values[i] - h, &mut obj)) / (2.0 * h as f64);
            let got = grad[i] as f64;
            assert!(
                (got - fd).abs() <= 2e-3 * (1.0 + fd.abs()) + 1e-4,
                "{density:?} parameter {i}: {got} vs {fd}"
            );
            checked += (fd.abs() > 1e-5) as usize;
        }
        assert!(checked > 10, "most sampled gradients are not zero");
    }
}

/// A scheduled β falls geometrically from `beta` at step 0 to
/// `beta_end` at the last step and stays there; the objective keeps
/// it where a trained β is kept, so a render at the run's values sees
/// it; nothing but the schedule moves it.
#[test]
fn a_scheduled_beta_falls_geometrically() {
    let s = NeuralSurface {
        beta: 0.1,
        beta_end: Some(0.001),
        ..spec(DensityKind::VolSdf, false)
    };
    let obj = SurfaceObjective::new(&s, &[]).unwrap().with_steps(101);
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-5 * b;
    assert!(close(obj.scheduled_beta(0), 0.1));
    assert!(
        close(obj.scheduled_beta(50), 0.01),
        "the geometric mean halfway"
    );
    assert!(close(obj.scheduled_beta(100), 0.001));
    assert!(
        close(obj.scheduled_beta(500), 0.001),
        "beta_end after the last step"
    );
    let mut values = obj.initial();
    assert!(close(obj.beta(&values) as f64, 0.1));
    for step in [1, 37, 100] {
        obj.at_step(step, &mut values);
        let mut projected = values.clone();
        obj.project(&mut projected);
        assert_eq!(projected, values, "project leaves a scheduled β alone");
        assert!(close(obj.beta(&values) as f64, obj.scheduled_beta(step)));
    }
    // Without a schedule nothing moves, and a fixed β has no slot.
    let fixed = SurfaceObjective::new(&spec(DensityKind::VolSdf, false), &[])
        .unwrap()
        .with_steps(101);
    let mut v = fixed.initial();
    let before = v.clone();
    fixed.at_step(50, &mut v);
    assert_eq!(v, before);
    assert_eq!(v.len() + 1, values.len());
}

/// Fine samples gather where a ray crosses the surface (the network
/// starts as a sphere of radius 0.5), sorted along each ray, for both
/// densities; a ray that misses keeps them spread out.
#[test]
fn fine_samples_gather_at_the_surface() {
    for density in [DensityKind::VolSdf, DensityKind::Neus] {
        let s = NeuralSurface {
            fine: 16,
            ..spec(density, false)
        };
        let obj = SurfaceObjective::new(&s, &[]).unwrap();
        let values = obj.initial();
        let rays = [
            Ray {
                origin: [0.0, 0.0, -2.0],
                dir: [0.0, 0.0, 1.0],
                view: 0,
                pixel: 0,
            },
            Ray {
                origin: [2.0, 0.0, -2.0],
                dir: [0.0, 0.0, 1.0],
                view: 0,
                pixel: 1,
            },
        ];
        let n = 24;
        let t: Vec<f32> = (0..n)
            .map(|i| 0.5 + 3.0 * i as f32 / (n - 1) as f32)
            .collect();
        let mut coarse = Samples::default();
        coarse.fixed(2, n, |_| &t, LastInterval::Zero);
        let place = |rays: &[Ray], coarse: &Samples, work: &mut Placing| {
            let mut out = Samples::default();
            obj.upsample(
                &values,
                Levels::All,
                obj.beta(&values),
                rays,
                coarse,
                n,
                Spacing::Even,
                LastInterval::Zero,
                work,
                &mut out,
            )
            .unwrap();
            out
        };
        let mut work = Placing::default();
        let out = place(&rays, &coarse, &mut work);
        let m = n + 16;
        // The buffers kept from a larger call change nothing.
        let mut one = Samples::default();
        one.fixed(1, n, |_| &t, LastInterval::Zero);
        assert_eq!(place(&rays[1..], &one, &mut work).t, out.t[m..]);
        assert_eq!(place(&rays, &coarse, &mut work).t, out.t);
        assert_eq!(out.t.len(), 2 * m);
        let mut f = vec![0.0; 2 * m];
        let (mut points, mut dirs) = (Vec::new(), Vec::new());
        out.points(&rays, &mut points, &mut dirs);
        obj.sdf
            .distance(&values[..obj.sdf.len()], &points, Levels::All, &mut f);
        // The hit ray enters the sphere near t = 1.5: its samples crowd
        // within three coarse intervals of it, twice as many as a miss's.
        let hit = &out.t[..m];
        assert!(hit.windows(2).all(|p| p[0] <= p[1]), "{hit:?}");
        let gap = 3.0 / (n - 1) as f32;
        let near = |t: &[f32]| t.iter().filter(|&&t| (t - 1.5).abs() < 3.0 * gap).count();
        assert!(
            near(hit) >= 16,
            "{density:?}: {} near the surface: {hit:?}",
            near(hit)
        );
        let miss = &out.t[m..];
        assert!(miss.windows(2).all(|p| p[0] <= p[1]));
        assert!(
            2 * near(miss) <= near(hit),
            "{density:?}: the miss has {}",
            near(miss)
        );
    }
}

#[test]
fn renders_finite_colours_over_the_background() {
    let s = spec(DensityKind::VolSdf, true);
    let obj = SurfaceObjective::new(&s, &[]).unwrap();
    let values = obj.initial();
    let cam = Camera::look_at(
        glam::DVec3::new(0.0, 0.0, -3.0),
        glam::DVec3::ZERO,
        glam::DVec3::Y,
        1.0,
    );
    let sampler = Stratified::new(32, 0.5, 5.0).unwrap();
    let size = ImageSize {
        width: 9,
        height: 9,
    };
    let v = obj
        .render_view(&values, &sampler, LastInterval::Zero, &cam, size)
        .unwrap();
    assert!(v
        .colour
        .iter()
        .flatten()
        .all(|x| x.is_finite() && (0.0..=1.0).contains(x)));
    // A corner ray misses the starting sphere (radius 0.5): background.
    let corner = v.colour[0];
    for (c, bg) in corner.iter().zip(s.background) {
        assert!((c - bg as f32).abs() < 1e-3, "{corner:?}");
    }
    // The centre ray hits it: opaque, not the background.
    assert!((v.colour[40][2] - 0.4).abs() > 1e-3 || (v.colour[40][0] - 0.2).abs() > 1e-3);
}

// ---- The hash-grid SDF as the surface's geometry ----

use sdfl_stdlib::value::{Encoding, HashGridSpec};

/// A small hash surface: 4 levels of 4 to 16 cells over [-1, 1]³, one
/// softplus layer of 8; `eikonal_step` 0 for the exact form.
fn hash_spec(density: DensityKind, eikonal_step: f64, level_every: usize) -> NeuralSurface {
    let base = spec(density, true);
    NeuralSurface {
        sdf: NeuralSdf {
            encoding: Encoding::HashGrid(HashGridSpec {
                levels: 4,
                features: 2,
                log2_table: 8,
                min_res: 4,
                max_res: 16,
                min: [-1.0; 3],
                max: [1.0; 3],
            }),
            layers: 1,
            width: 8,
            skips: vec![],
            level_every,
            eikonal_step: (eikonal_step > 0.0).then_some(eikonal_step),
            ..base.sdf
        },
        ..base
    }
}

const MSE_AND_EIKONAL: [Loss; 2] = [
    Loss {
        kind: LossKind::Mse,
        weight: 1.0,
    },
    Loss {
        kind: LossKind::Eikonal,
        weight: 0.1,
    },
];

/// The terms above and the silhouette term, weighed up so that it
/// weighs in the gradients as much as the colour.
const WITH_SILHOUETTE: [Loss; 3] = [
    MSE_AND_EIKONAL[0],
    MSE_AND_EIKONAL[1],
    Loss {
        kind: LossKind::Silhouette,
        weight: 0.5,
    },
];

/// Starting values with the tables drawn U(−0.05, 0.05), so that the
/// field is no longer the sphere and every term feels the tables.
fn rough_values(obj: &SurfaceObjective) -> Vec<f32> {
    let mut values = obj.initial();
    let SurfaceSdf::Hash(h) = &obj.sdf else {
        panic!("a hash surface")
    };
    let mut rng = SplitMix64::new(17);
    for v in &mut values[..h.net.table_params()] {
        *v = 0.1 * (rng.next_f32() - 0.5);
    }
    values
}

/// The whole loss (colour MSE through compositing, and the eikonal term)
/// against central differences of table entries, MLP weights and colour
/// weights, for both eikonal forms and both densities. (Without fine
/// samples: where they go is a constant to the gradient, but moves under
/// a finite difference.)
#[test]
fn hash_surface_gradient_matches_finite_differences() {
    for (density, step, losses) in [
        (DensityKind::VolSdf, 0.0, &MSE_AND_EIKONAL[..]),
        (DensityKind::Neus, 0.0, &MSE_AND_EIKONAL[..]),
        (DensityKind::VolSdf, 0.02, &MSE_AND_EIKONAL[..]),
        (DensityKind::Neus, 0.02, &MSE_AND_EIKONAL[..]),
        (DensityKind::VolSdf, 0.0, &WITH_SILHOUETTE[..]),
        (DensityKind::Neus, 0.0, &WITH_SILHOUETTE[..]),
    ] {
        let s = hash_spec(density, step, 0);
        let mut obj = SurfaceObjective::new(&s, losses).unwrap();
        let values = rough_values(&obj);
        let mut b = batch(9, 20);
        // Pixels alternately covered and not, so that the silhouette term
        // pulls both ways.
        b.coverage = (0..b.rays.len()).map(|r| (r % 2) as f32).collect();
        let mut grad = vec![0.0; values.len()];
        let loss = obj.loss_and_grad(&values, &b, 1.0, &mut grad).unwrap();
        assert!(loss.is_finite() && loss > 0.0);
        let SurfaceSdf::Hash(h) = &obj.sdf else {
            unreachable!()
        };
        let (tables, sdf_len) = (h.net.table_params(), h.net.param_count());
        // Table entries the batch reads (a non-zero gradient), then any
        // MLP and colour weights.
        let read: Vec<usize> = (0..tables).filter(|&i| grad[i] != 0.0).collect();
        assert!(read.len() > 20, "the batch reads the tables");
        let mut rng = SplitMix64::new(5);
        let mut picks: Vec<(usize, &str)> = Vec::new();
        for _ in 0..25 {
            picks.push((read[rng.below(read.len() as u64) as usize], "table"));
        }
        for _ in 0..20 {
            let i = tables + rng.below((sdf_len - tables) as u64) as usize;
            picks.push((i, "sdf mlp"));
        }
        for _ in 0..20 {
            let i = sdf_len + rng.below((values.len() - sdf_len) as u64) as usize;
            picks.push((i, "colour"));
        }
        // The loss is f32 per sample: central differences carry ~5e-6 of
        // rounding noise at h = 1e-3, ~1.5e-6 at 3e-3, ~5e-7 at 1e-2. The
        // distance network is smooth (softplus) but NeuS's opacity clamps
        // at 0 and the colour network's ReLUs have kinks, which a large
        // step may cross: a distance parameter passes when either of two
        // steps agrees (a wrong gradient agrees with neither); the colour
        // network takes 1e-3.
        let mut checked = 0;
        for (i, what) in picks {
            let steps: &[(f32, f64)] = if what == "colour" {
                &[(1e-3, 1e-5)]
            } else {
                &[(3e-3, 3e-6), (1e-2, 1e-6)]
            };
            let at = |x: f32, obj: &mut SurfaceObjective| {
                let mut v = values.clone();
                v[i] = x;
                let mut g = vec![0.0; v.len()];
                obj.loss_and_grad(&v, &b, 1.0, &mut g).unwrap()
            };
            let got = grad[i] as f64;
            let fds: Vec<(f64, f64)> = steps
                .iter()
                .map(|&(h, floor)| {
                    let fd = (at(values[i] + h, &mut obj) - at(values[i] - h, &mut obj))
                        / (2.0 * h as f64);
                    (fd, floor)
                })
                .collect();
            assert!(
                fds.iter()
                    .any(|&(fd, floor)| (got - fd).abs() <= 3e-2 * fd.abs() + floor),
                "{density:?} step {step} {losses:?}: {what} parameter {i}: {got:e} vs {fds:?}"
            );
            checked += (fds[0].0.abs() > 10.0 * fds[0].1) as usize;
        }
        assert!(
            checked >= 15,
            "sampled gradients well above the noise: {checked}"
        );
    }
}

/// Levels not yet on are read as zero and get no gradient; all of them
/// switch on by `level_every`.
#[test]
fn hash_surface_levels_not_yet_on_get_no_gradient() {
    let s = hash_spec(DensityKind::Neus, 0.0, 5);
    let mut obj = SurfaceObjective::new(&s, &MSE_AND_EIKONAL).unwrap();
    let values = obj.initial();
    let SurfaceSdf::Hash(h) = &obj.sdf else {
        unreachable!()
    };
    let offsets = h.net.grid().level_offsets();
    let tables = h.net.table_params();
    assert!(values[offsets[1]..tables].iter().all(|&v| v == 0.0));
    let mut b = batch(9, 20);
    for (step, on) in [(0, 1), (5, 2), (14, 3), (15, 4), (1000, 4)] {
        b.step = step;
        let mut grad = vec![0.0; values.len()];
        obj.loss_and_grad(&values, &b, 1.0, &mut grad).unwrap();
        for l in 0..4 {
            let end = offsets.get(l + 1).copied().unwrap_or(tables);
            let any = grad[offsets[l]..end].iter().any(|&g| g != 0.0);
            assert_eq!(any, l < on, "step {step}: level {l}");
        }
    }
}

/// Rays that graze the starting sphere, run wholly outside the grid's box
/// or far away (samples at 1e6), and batches of empty space only: the
/// loss and every gradient stay finite, for both eikonal forms.
#[test]
fn hash_surface_hard_rays_give_finite_loss_and_gradient() {
    let ray = |o: [f32; 3], d: [f32; 3]| Ray {
        origin: o,
        dir: d,
        view: 0,
        pixel: 0,
    };
    let z = [0.0, 0.0, 1.0];
    let cases = [
        // Grazing the sphere of radius 0.5, and through its centre.
        vec![ray([0.5, 0.0, -2.0], z), ray([0.0, 0.0, -2.0], z)],
        // Outside the box [-1, 1]³: samples clamped onto it.
        vec![ray([3.0, 3.0, -2.0], z), ray([-1.5, 0.0, -2.0], z)],
        // Far away.
        vec![ray([1e6, -1e6, -2.0], z)],
    ];
    for step in [0.0, 0.02] {
        for fine in [0, 6] {
            for rays in &cases {
                let s = NeuralSurface {
                    fine,
                    ..hash_spec(DensityKind::Neus, step, 0)
                };
                let mut obj = SurfaceObjective::new(&s, &MSE_AND_EIKONAL).unwrap();
                let values = rough_values(&obj);
                let mut b = batch(rays.len(), 16);
                b.rays = rays.clone();
                let mut grad = vec![0.0; values.len()];
                let loss = obj.loss_and_grad(&values, &b, 1.0, &mut grad).unwrap();
                assert!(loss.is_finite(), "step {step}, {rays:?}");
                assert!(grad.iter().all(|g| g.is_finite()), "step {step}, {rays:?}");
            }
        }
    }
}

/// The gradient is the same, bit for bit, at one, two and three threads,
/// over more samples than one block of the backward holds, with β fixed
/// and trained (its gradient a sum over every sample).
#[test]
fn hash_surface_gradient_is_bit_identical_at_any_thread_count() {
    for (step, train_beta) in [(0.0, false), (0.02, false), (0.0, true)] {
        let s = NeuralSurface {
            fine: 8,
            train_beta,
            ..hash_spec(DensityKind::VolSdf, step, 0)
        };
        let run = |threads: usize| {
            let mut obj = SurfaceObjective::new(&s, &MSE_AND_EIKONAL).unwrap();
            let values = rough_values(&obj);
            let b = batch(300, 24);
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut grad = vec![0.0; values.len()];
                let loss = obj.loss_and_grad(&values, &b, 1.0, &mut grad).unwrap();
                (
                    loss.to_bits(),
                    grad.iter().map(|g| g.to_bits()).collect::<Vec<_>>(),
                )
            })
        };
        const { assert!(300 * 32 > sdfl_runtime::neural::hash_sdf::volume::BLOCK) };
        let one = run(1);
        assert_eq!(one, run(2), "eikonal step {step}, β trained {train_beta}");
        assert_eq!(one, run(3), "eikonal step {step}, β trained {train_beta}");
    }
}

/// The finite-difference form's normal is the central difference of the
/// exact field (so the colour network sees ∇f either way), and the exact
/// form's is the field's gradient.
#[test]
fn hash_surface_normals_are_the_fields_gradient() {
    let exact = SurfaceObjective::new(&hash_spec(DensityKind::VolSdf, 0.0, 0), &[]).unwrap();
    let fd = SurfaceObjective::new(&hash_spec(DensityKind::VolSdf, 1e-3, 0), &[]).unwrap();
    let values = rough_values(&exact);
    let points: Vec<f32> = vec![0.1, 0.2, 0.3, -0.4, 0.25, 0.05, 0.6, -0.1, -0.2];
    let (mut a, mut b) = (GeometryWork::default(), GeometryWork::default());
    let p = &values[..exact.sdf.len()];
    exact.sdf.forward(p, &points, Levels::All, &mut a);
    fd.sdf.forward(p, &points, Levels::All, &mut b);
    assert_eq!(exact.sdf.distances(&a), fd.sdf.distances(&b));
    for (x, y) in exact.sdf.gradients(&a).iter().zip(fd.sdf.gradients(&b)) {
        assert!((x - y).abs() < 2e-2 * (1.0 + x.abs()), "{x} vs {y}");
    }
    let mut f = vec![0.0; 3];
    exact.sdf.distance(p, &points, Levels::All, &mut f);
    assert_eq!(f, exact.sdf.distances(&a));
}

// ---- Empty space skipped ----

use sdfl_runtime::neural::surface::skip::{band, Span};

/// A field with thin features, steeper than a distance: a torus of tube
/// radius 0.012 and a plate 0.016 thick (both under a fifth of a cell of
/// a 32³ grid over [-1, 1]³), scaled by 1.3 and moved `shift` along x.
fn thin_field(p: [f64; 3], shift: f64) -> f64 {
    let [x, y, z] = [p[0] - shift, p[1], p[2]];
    let torus = (((x * x + z * z).sqrt() - 0.5).powi(2) + y * y).sqrt() - 0.012;
    let plate = (y - 0.3).abs() - 0.008;
    1.3 * torus.min(plate.max((x * x + z * z).sqrt() - 0.7))
}

/// Cells of `grid` that the zero set of `f` passes through, found by brute
/// force: a lattice six points a cell, a sign change between neighbours
/// bisected to its point.
fn crossed_cells(grid: &skip::SkipGrid, f: impl Fn([f64; 3]) -> f64) -> Vec<usize> {
    let m = 32 * 6 + 1;
    let at = |i: usize| -1.0 + 2.0 * i as f64 / (m - 1) as f64;
    let point = |i: usize, j: usize, k: usize| [at(i), at(j), at(k)];
    let mut cells = Vec::new();
    for i in 0..m {
        for j in 0..m {
            for k in 0..m {
                let p = point(i, j, k);
                let fp = f(p);
                for q in [
                    (i + 1 < m).then(|| point(i + 1, j, k)),
                    (j + 1 < m).then(|| point(i, j + 1, k)),
                    (k + 1 < m).then(|| point(i, j, k + 1)),
                ]
                .into_iter()
                .flatten()
                {
                    if (fp > 0.0) == (f(q) > 0.0) {
                        continue;
                    }
                    let (mut a, mut b) = (p, q);
                    for _ in 0..30 {
                        let mid = std::array::from_fn(|d| 0.5 * (a[d] + b[d]));
                        if (f(mid) > 0.0) == (fp > 0.0) {
                            a = mid;
                        } else {
                            b = mid;
                        }
                    }
                    let x = a.map(|v| v as f32);
                    if let Some(c) = grid.cell_of(x) {
                        cells.push(c);
                    }
                }
            }
        }
    }
    cells.sort_unstable();
    cells.dedup();
    cells
}

/// No zero crossing is lost: every cell the surface passes is occupied,
/// for a field with features thinner than a cell, steeper than a
/// distance, that moves between refreshes (the grid of the refresh at
/// step 8 against the field anywhere up to the next refresh at 16). The
/// grid skips most cells all the same.
#[test]
fn skip_grid_keeps_every_cell_the_surface_crosses() {
    let mut grid = skip::SkipGrid::new([-1.0; 3], [1.0; 3], 32).unwrap();
    let speed = 0.002; // along x, a step
    let refresh = |grid: &mut skip::SkipGrid, step: usize| {
        let shift = speed * step as f64;
        grid.refresh(step, 0.0, |points, out| {
            for (o, p) in out.iter_mut().zip(points) {
                *o = thin_field(p.map(f64::from), shift) as f32;
            }
        })
    };
    refresh(&mut grid, 0);
    assert!(grid.is_whole(), "the first refresh has no drift to go by");
    refresh(&mut grid, 8);
    assert!(!grid.is_whole());
    assert!(
        grid.occupied_count() < grid.cells() / 4,
        "{} of {} occupied",
        grid.occupied_count(),
        grid.cells()
    );
    for step in [8, 12, 16] {
        let shift = speed * step as f64;
        let crossed = crossed_cells(&grid, |p| thin_field(p, shift));
        assert!(crossed.len() > 300, "the surface crosses cells");
        let lost: Vec<usize> = crossed
            .iter()
            .copied()
            .filter(|&c| !grid.is_occupied(c))
            .collect();
        assert!(lost.is_empty(), "step {step}: cells {lost:?} lost");
    }
    // A field that leaves the box leaks: nothing is skipped.
    let mut wide = skip::SkipGrid::new([-1.0; 3], [1.0; 3], 32).unwrap();
    for step in [0, 8] {
        wide.refresh(step, 0.0, |points, out| {
            for (o, p) in out.iter_mut().zip(points) {
                *o = (p[0] * p[0] + p[1] * p[1]).sqrt() - 0.3;
            }
        });
    }
    assert!(wide.is_whole());
}

/// A ray's span holds every depth whose point lies in an occupied cell
/// (brute force along the ray), and rays that cross none are empty.
#[test]
fn skip_span_holds_every_occupied_cell_a_ray_crosses() {
    let mut grid = skip::SkipGrid::new([-1.0; 3], [1.0; 3], 32).unwrap();
    for step in [0, 8] {
        grid.refresh(step, 0.0, |points, out| {
            for (o, p) in out.iter_mut().zip(points) {
                *o = thin_field(p.map(f64::from), 0.0) as f32;
            }
        });
    }
    let mut rng = SplitMix64::new(3);
    let (mut parts, mut empties) = (0, 0);
    for k in 0..440 {
        let (o, d) = if k < 400 {
            let o = [0.0f32; 3].map(|_| 4.0 * (rng.next_f32() - 0.5));
            let o = [o[0], o[1], -2.5 + 0.5 * o[2]];
            let target = [0.0f32; 3].map(|_| 1.6 * (rng.next_f32() - 0.5));
            let d: [f32; 3] = std::array::from_fn(|a| target[a] - o[a]);
            let len = d.iter().map(|x| x * x).sum::<f32>().sqrt();
            (o, d.map(|x| x / len))
        } else {
            // Along z through the box's corners, far from the field's
            // features: nothing occupied.
            let sx = if k % 2 == 0 { 1.0 } else { -1.0 };
            let sy = if k % 4 < 2 { 1.0 } else { -1.0 };
            let off = 0.01 * (k % 7) as f32;
            ([sx * (0.88 + off), sy * (0.9 - off), -2.5], [0.0, 0.0, 1.0])
        };
        let (lo, hi) = (0.5, 5.0);
        let span = grid.span(o, d, lo, hi);
        let (a, b) = match span {
            Span::Whole => (lo, hi),
            Span::Part(a, b) => {
                parts += 1;
                (a, b)
            }
            Span::Empty => {
                empties += 1;
                (f32::INFINITY, f32::NEG_INFINITY)
            }
        };
        for k in 0..=20_000 {
            let t = lo + (hi - lo) * k as f32 / 20_000.0;
            let p = std::array::from_fn(|i| o[i] + t * d[i]);
            if let Some(c) = grid.cell_of(p) {
                if grid.is_occupied(c) {
                    assert!(
                        a <= t && t <= b,
                        "{o:?} {d:?}: occupied at {t}, span {span:?}"
                    );
                }
            }
        }
    }
    assert!(
        parts > 50 && empties >= 40,
        "{parts} parts, {empties} empty"
    );
}

/// NeuS's tail is `e^(−b/β)`; VolSDF's, over a length, `α·ℓ/2·e^(−b/β)`.
#[test]
fn the_band_bounds_what_the_skipped_tail_absorbs() {
    let b = band(DensityKind::Neus, 10.0, 0.02, 3.0);
    assert!(((-b / 0.02).exp() - skip::OPACITY_LOST).abs() < 1e-6);
    let b = band(DensityKind::VolSdf, 50.0, 0.02, 3.0);
    let tail = 0.5 * 50.0 * 3.0 * (-b / 0.02).exp();
    assert!((tail - skip::OPACITY_LOST).abs() < 1e-6, "{tail}");
}

/// A hash surface (NeuS, β small enough that the grid skips) refreshed at
/// steps 0 and 8 at the same values: nothing moved, so the grid is in use
/// from step 8.
fn skipping_surface(beta: f64) -> (SurfaceObjective, Vec<f32>, Batch) {
    let s = NeuralSurface {
        beta,
        ..hash_spec(DensityKind::Neus, 0.0, 0)
    };
    let mut obj = SurfaceObjective::new(&s, &WITH_SILHOUETTE).unwrap();
    let values = rough_values(&obj);
    let mut b = batch(40, 20);
    // Spread over [-1, 1]² so that some rays miss the sphere's band.
    for r in &mut b.rays {
        r.origin = [2.0 * r.origin[0], 2.0 * r.origin[1], r.origin[2]];
    }
    b.coverage = (0..b.rays.len()).map(|r| (r % 2) as f32).collect();
    for step in [0, 8] {
        b.step = step;
        let mut g = vec![0.0; values.len()];
        obj.loss_and_grad(&values, &b, 1.0, &mut g).unwrap();
    }
    assert!(!obj.skip_grid().unwrap().is_whole());
    (obj, values, b)
}

/// Where a ray's span is whole its samples are the same, and so is
/// everything: skipping with a grid that keeps the whole of every ray
/// gives the loss and gradient of no grid, bit for bit.
#[test]
fn skipping_leaves_a_whole_span_unchanged() {
    // β 0.2: the band covers the whole box, and the depths lie inside it:
    // every span is whole.
    let (mut skipping, values, mut b) = skipping_surface(0.2);
    // Rays within the box over those depths.
    b.rays = batch(40, 20).rays;
    b.depths = (0..20).map(|i| 1.3 + 1.4 * i as f32 / 19.0).collect();
    let grid = skipping.skip_grid().unwrap();
    for r in &b.rays {
        assert_eq!(grid.span(r.origin, r.dir, 1.3, 2.7), Span::Whole);
    }
    let s = NeuralSurface {
        beta: 0.2,
        ..hash_spec(DensityKind::Neus, 0.0, 0)
    };
    let mut plain = SurfaceObjective::new(&s, &WITH_SILHOUETTE).unwrap();
    plain.skip = None;
    let run = |obj: &mut SurfaceObjective| {
        let mut g = vec![0.0; values.len()];
        let loss = obj.loss_and_grad(&values, &b, 1.0, &mut g).unwrap();
        (
            loss.to_bits(),
            g.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
        )
    };
    assert_eq!(run(&mut skipping), run(&mut plain));
}

/// Skipping in use (some rays cut to their span, some missing): the
/// gradient against finite differences, and the same bits at one and two
/// threads.
#[test]
fn skipping_gradient_matches_finite_differences() {
    let (mut obj, values, b) = skipping_surface(0.03);
    let grid = obj.skip_grid().unwrap();
    let spans: Vec<Span> = b
        .rays
        .iter()
        .map(|r| grid.span(r.origin, r.dir, 1.0, 3.0))
        .collect();
    assert!(spans.iter().any(|s| matches!(s, Span::Part(..))));
    assert!(spans.contains(&Span::Empty));
    let mut grad = vec![0.0; values.len()];
    let loss = obj.loss_and_grad(&values, &b, 1.0, &mut grad).unwrap();
    assert!(loss.is_finite() && loss > 0.0);
    let sdf_len = obj.sdf.len();
    let mut rng = SplitMix64::new(8);
    let read: Vec<usize> = (0..values.len()).filter(|&i| grad[i] != 0.0).collect();
    assert!(read.len() > 40);
    let mut checked = 0;
    for _ in 0..60 {
        let i = read[rng.below(read.len() as u64) as usize];
        let steps: &[(f32, f64)] = if i >= sdf_len {
            &[(1e-3, 1e-5)]
        } else {
            &[(1e-3, 1e-5), (3e-3, 3e-6)]
        };
        let got = grad[i] as f64;
        let fds: Vec<(f64, f64)> = steps
            .iter()
            .map(|&(h, floor)| {
                let mut at = |x: f32| {
                    let mut v = values.clone();
                    v[i] = x;
                    let mut g = vec![0.0; v.len()];
                    obj.loss_and_grad(&v, &b, 1.0, &mut g).unwrap()
                };
                (
                    (at(values[i] + h) - at(values[i] - h)) / (2.0 * h as f64),
                    floor,
                )
            })
            .collect();
        assert!(
            fds.iter()
                .any(|&(fd, floor)| (got - fd).abs() <= 3e-2 * fd.abs() + floor),
            "parameter {i}: {got:e} vs {fds:?}"
        );
        checked += (fds[0].0.abs() > 10.0 * fds[0].1) as usize;
    }
    assert!(checked >= 10, "{checked} well above the noise");
    let threads = |n: usize| {
        let (mut obj, values, b) = skipping_surface(0.03);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap();
        pool.install(|| {
            let mut g = vec![0.0; values.len()];
            let loss = obj.loss_and_grad(&values, &b, 1.0, &mut g).unwrap();
            (
                loss.to_bits(),
                g.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            )
        })
    };
    assert_eq!(threads(1), threads(2));
}

/// A scene with nothing in it (the distance ≥ 0.5 everywhere): every cell
/// empty, every ray missed. The loss is finite (the background against
/// the targets, opacity 0 against the coverage), nothing reaches the
/// parameters, and a rendered view is the background at no network cost.
#[test]
fn skipping_an_empty_scene_gives_the_background() {
    let s = NeuralSurface {
        beta: 0.01,
        ..hash_spec(DensityKind::VolSdf, 0.0, 0)
    };
    let mut obj = SurfaceObjective::new(&s, &WITH_SILHOUETTE).unwrap();
    let mut values = obj.initial();
    let bias = obj.sdf.len() - 1;
    values[bias] += 1.0;
    let mut b = batch(20, 16);
    b.coverage = vec![0.0; b.rays.len()];
    let mut grad = vec![0.0; values.len()];
    for step in [0, 8] {
        b.step = step;
        grad.fill(0.0);
        let loss = obj.loss_and_grad(&values, &b, 1.0, &mut grad).unwrap();
        assert!(loss.is_finite() && loss > 0.0, "step {step}: {loss}");
    }
    assert_eq!(obj.skip_grid().unwrap().occupied_count(), 0);
    assert!(grad.iter().all(|&g| g == 0.0));
    // Pixels that show the object keep their rays (whole): the silhouette
    // term's pull grows a surface there, finite.
    b.coverage = vec![1.0; b.rays.len()];
    let loss = obj.loss_and_grad(&values, &b, 1.0, &mut grad).unwrap();
    assert!(loss.is_finite());
    assert!(grad.iter().all(|g| g.is_finite()) && grad.iter().any(|&g| g != 0.0));
    let cam = Camera::look_at(
        glam::DVec3::new(0.0, 0.0, -3.0),
        glam::DVec3::ZERO,
        glam::DVec3::Y,
        1.0,
    );
    let size = ImageSize {
        width: 6,
        height: 5,
    };
    let strat = Stratified::new(16, 1.0, 5.0).unwrap();
    let v = obj
        .render_view(&values, &strat, LastInterval::Zero, &cam, size)
        .unwrap();
    assert_eq!(v.evaluated, 0);
    assert!(v.colour.iter().all(|&c| c == [0.2, 0.3, 0.4]));
    assert!(v.depth.iter().all(|&d| d == 0.0));
}

/// A run resumed from its state at step 21 (the grid last refreshed at
/// 16, then widened for a grown β) continues as the uninterrupted one,
/// bit for bit, across the refresh at 24.
#[test]
fn skipping_resumes_the_same_run() {
    // A trained β, grown threefold at step 18 so that the grid is widened
    // between the refreshes at 16 and 24, before the break at 21.
    let s = NeuralSurface {
        beta: 0.01,
        train_beta: true,
        ..hash_spec(DensityKind::Neus, 0.0, 0)
    };
    let mut b = batch(40, 20);
    b.coverage = (0..b.rays.len()).map(|r| (r % 2) as f32).collect();
    let beta = SurfaceObjective::new(&s, &WITH_SILHOUETTE)
        .unwrap()
        .beta_at()
        .unwrap();
    // Plain gradient descent stands in for the optimiser (β moved only
    // by hand: a step of 0.5 would fling it out of range).
    let step = |obj: &mut SurfaceObjective, values: &mut Vec<f32>, b: &mut Batch, s: usize| {
        b.step = s;
        let mut g = vec![0.0; values.len()];
        let loss = obj.loss_and_grad(values, b, 1.0, &mut g).unwrap();
        g[beta] = 0.0;
        for (v, g) in values.iter_mut().zip(&g) {
            *v -= 0.5 * g;
        }
        loss.to_bits()
    };
    let mut whole = SurfaceObjective::new(&s, &WITH_SILHOUETTE).unwrap();
    let mut values = rough_values(&whole);
    let (mut losses, mut at_break, mut threshold) = (Vec::new(), None, Vec::new());
    for s in 0..30 {
        if s == 18 {
            values[beta] += 3f32.ln() / BETA_RATE;
        }
        losses.push(step(&mut whole, &mut values, &mut b, s));
        threshold.push(whole.state()[1].1[1]);
        if s == 21 {
            at_break = Some((values.clone(), whole.state()));
        }
    }
    assert!(
        threshold[18] > threshold[17],
        "widened at step 18: {threshold:?}"
    );
    let (mut resumed_values, state) = at_break.unwrap();
    assert_eq!(state[1].1[0], 17.0, "last refreshed at step 16");
    let mut resumed = SurfaceObjective::new(&s, &WITH_SILHOUETTE).unwrap();
    resumed.restore_state(&state).unwrap();
    assert!(!resumed.skip_grid().unwrap().is_whole());
    for (s, &loss) in losses.iter().enumerate().skip(22) {
        assert_eq!(
            step(&mut resumed, &mut resumed_values, &mut b, s),
            loss,
            "step {s}"
        );
    }
    assert_eq!(resumed_values, values);
    assert!(!resumed.skip_grid().unwrap().is_whole());
    // State of another shape is refused.
    let mut other = SurfaceObjective::new(&s, &WITH_SILHOUETTE).unwrap();
    let mut bad = state.clone();
    bad[0].1.pop();
    assert!(other.restore_state(&bad).is_err());
    bad = state.clone();
    bad[1].1[1] = -1.0;
    assert!(other.restore_state(&bad).is_err());
}

/// A covered pixel's ray that crosses no occupied cell is kept, sampled
/// whole, where the silhouette term needs its pull; an uncovered one is
/// dropped. With an infinite last interval nothing is skipped.
#[test]
fn covered_rays_far_from_the_surface_are_kept_whole() {
    let mut g = SkipGrid::new([-1.0; 3], [1.0; 3], 8).unwrap();
    let sphere = |c: &[[f32; 3]], o: &mut [f32]| {
        for (p, o) in c.iter().zip(o) {
            *o = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 0.2;
        }
    };
    g.refresh(0, 0.01, sphere);
    g.refresh(8, 0.01, sphere);
    let ray = |x: f32, pixel| Ray {
        origin: [x, 0.9, -3.0],
        dir: [0.0, 0.0, 1.0],
        view: 0,
        pixel,
    };
    // Both pass far from the small sphere, in the box's corner rows.
    let rays = [ray(0.9, 0), ray(-0.9, 1)];
    let t: Vec<f32> = (0..8).map(|k| 1.0 + k as f32 * 0.5).collect();
    assert_eq!(g.span(rays[0].origin, rays[0].dir, t[0], t[7]), Span::Empty);
    let mut sel = Selection::default();
    sel.select(Some(&g), &rays, 8, |_| &t, |r| r == 0);
    assert_eq!(
        (sel.hits.as_slice(), sel.misses.as_slice()),
        (&[0][..], &[1][..])
    );
    assert_eq!(sel.depths, t, "kept whole");
    let grid = skipping(Some(&g), LastInterval::Infinite);
    sel.select(grid, &rays, 8, |_| &t, |_| false);
    assert_eq!(sel.hits, [0, 1]);
}

/// A grid whose threshold overflowed (a diverging field) saves a state
/// that restores: the checkpoint stays resumable.
#[test]
fn an_overflowed_skip_threshold_still_restores() {
    let mut g = SkipGrid::new([-1.0; 3], [1.0; 3], 4).unwrap();
    g.refresh(0, 0.01, |_, o| o.fill(0.0));
    g.refresh(8, 0.01, |_, o| {
        o.fill(0.0);
        o[5] = 3e38;
    });
    let s = g.state();
    let mut h = SkipGrid::new([-1.0; 3], [1.0; 3], 4).unwrap();
    h.restore(&s[0].1, &s[1].1).unwrap();
    assert_eq!(h.occupied_count(), g.occupied_count());
}

/// A trained β that grows between refreshes widens the grid's band at
/// once: no cell left empty lies within the band of the β a step uses
/// (plus half a cell's diagonal), so the skipped space still absorbs less
/// than `OPACITY_LOST`. Adam can grow β about 2.2-fold in one refresh
/// interval at lr 5e-3.
#[test]
fn a_growing_trained_beta_widens_the_band_before_the_next_refresh() {
    let s = NeuralSurface {
        beta: 0.02,
        train_beta: true,
        ..hash_spec(DensityKind::Neus, 0.0, 0)
    };
    let mut obj = SurfaceObjective::new(&s, &MSE_AND_EIKONAL).unwrap();
    let mut values = obj.initial();
    obj.refresh_skip(&values, 0);
    obj.refresh_skip(&values, NeuralSurface::SKIP_EVERY);
    let (res, cell) = (NeuralSurface::SKIP_CELLS as usize, 2.0 / 32.0);
    let centres: Vec<f32> = (0..res * res * res)
        .flat_map(|i| [i % res, i / res % res, i / (res * res)])
        .map(|c| -1.0 + (c as f32 + 0.5) * cell)
        .collect();
    let mut f = vec![0.0; res * res * res];
    let half_diagonal = 0.5 * 3f32.sqrt() * cell;
    // Cells left empty that lie within the band of β at `values`.
    let within_band = |obj: &SurfaceObjective, values: &[f32], f: &mut Vec<f32>| {
        obj.sdf
            .distance(&values[..obj.sdf.len()], &centres, Levels::All, f);
        let grid = obj.skip_grid().unwrap();
        let b = band(DensityKind::Neus, 10.0, obj.beta(values), grid.diagonal());
        assert!(!grid.is_whole());
        (0..f.len())
            .filter(|&i| !grid.is_occupied(i) && f[i].abs() <= b + half_diagonal)
            .count()
    };
    assert_eq!(within_band(&obj, &values, &mut f), 0);
    let before = obj.skip_grid().unwrap().occupied_count();
    // β four times larger, before the next refresh.
    let i = obj.beta_at().unwrap();
    values[i] += 4f32.ln() / BETA_RATE;
    obj.refresh_skip(&values, NeuralSurface::SKIP_EVERY + 1);
    assert_eq!(within_band(&obj, &values, &mut f), 0);
    let widened = obj.skip_grid().unwrap().occupied_count();
    assert!(
        widened > before,
        "{widened} cells occupied, {before} before"
    );
    // A smaller β narrows nothing before the next refresh.
    values[i] -= 4f32.ln() / BETA_RATE;
    obj.refresh_skip(&values, NeuralSurface::SKIP_EVERY + 2);
    assert_eq!(obj.skip_grid().unwrap().occupied_count(), widened);
    // The widened grid is what a resumed run sees.
    let mut resumed = SurfaceObjective::new(&s, &MSE_AND_EIKONAL).unwrap();
    resumed.restore_state(&obj.state()).unwrap();
    assert_eq!(resumed.skip_grid().unwrap().occupied_count(), widened);
}

/// The objective of `s` at its starting values with its grid refreshed
/// twice (so that it skips), and its twin without a grid.
fn skipping_and_not(s: &NeuralSurface) -> (SurfaceObjective, SurfaceObjective, Vec<f32>) {
    let mut obj = SurfaceObjective::new(s, &MSE_AND_EIKONAL).unwrap();
    let values = obj.initial();
    obj.refresh_skip(&values, 0);
    obj.refresh_skip(&values, NeuralSurface::SKIP_EVERY);
    assert!(!obj.skip_grid().unwrap().is_whole());
    let mut unskipped = SurfaceObjective::new(s, &MSE_AND_EIKONAL).unwrap();
    unskipped.skip = None;
    (obj, unskipped, values)
}

/// A render after β grew past the grid's band skips by a copy widened to
/// it: the same frame as after a step had widened the grid itself, and
/// not the frame without skipping.
#[test]
fn a_render_past_the_grids_band_widens_a_copy() {
    let s = NeuralSurface {
        beta: 0.02,
        train_beta: true,
        ..hash_spec(DensityKind::Neus, 0.0, 0)
    };
    let (mut obj, unskipped, mut values) = skipping_and_not(&s);
    let cam = Camera::look_at(
        glam::DVec3::new(0.0, 0.3, -2.5),
        glam::DVec3::ZERO,
        glam::DVec3::Y,
        1.2,
    );
    let sampler = Stratified::new(24, 1.0, 4.0).unwrap();
    let render = |obj: &SurfaceObjective, values: &[f32]| {
        let size = ImageSize {
            width: 12,
            height: 12,
        };
        obj.render_view(values, &sampler, LastInterval::Zero, &cam, size)
            .unwrap()
            .colour
    };
    let i = obj.beta_at().unwrap();
    values[i] += 4f32.ln() / BETA_RATE;
    let before = obj.skip_grid().unwrap().occupied_count();
    let frame = render(&obj, &values);
    assert_eq!(
        obj.skip_grid().unwrap().occupied_count(),
        before,
        "the grid is left as it was"
    );
    obj.refresh_skip(&values, NeuralSurface::SKIP_EVERY + 1);
    assert!(obj.skip_grid().unwrap().occupied_count() > before);
    assert_eq!(frame, render(&obj, &values));
    assert_ne!(frame, render(&unskipped, &values));
}

/// Inside the object both densities are opaque (VolSDF's is about α,
/// NeuS's opacity grows as `f` falls): a ray whose near plane lies inside
/// sees the interior with skipping as without (the same depth and colour
/// to within what sampling a shorter span changes).
#[test]
fn rays_starting_inside_the_object_keep_its_interior() {
    for density in [DensityKind::VolSdf, DensityKind::Neus] {
        // A β small enough that the centre of the sphere is beyond the band.
        let s = NeuralSurface {
            beta: 0.01,
            ..hash_spec(density, 0.0, 0)
        };
        let (obj, unskipped, values) = skipping_and_not(&s);
        // The sphere of radius 0.5 spans t ∈ [1.5, 2.5] on the axis; the
        // near plane at 1.8 is inside it for every ray of this narrow view.
        let cam = Camera::look_at(
            glam::DVec3::new(0.0, 0.0, -2.0),
            glam::DVec3::ZERO,
            glam::DVec3::Y,
            4.0,
        );
        let size = ImageSize {
            width: 6,
            height: 6,
        };
        let sampler = Stratified::new(48, 1.8, 4.0).unwrap();
        let render = |obj: &SurfaceObjective| {
            obj.render_view(&values, &sampler, LastInterval::Zero, &cam, size)
                .unwrap()
        };
        let (skipped, whole) = (render(&obj), render(&unskipped));
        for (p, (d, e)) in skipped.depth.iter().zip(&whole.depth).enumerate() {
            assert!(
                *e < 2.1,
                "{density:?} pixel {p}: the interior starts at 1.8, depth {e}"
            );
            assert!(
                (d - e).abs() < 0.05,
                "{density:?} pixel {p}: depth {d}, {e} unskipped"
            );
            for c in 0..3 {
                let (a, b) = (skipped.colour[p][c], whole.colour[p][c]);
                assert!(
                    (a - b).abs() < 0.02,
                    "{density:?} pixel {p}: colour {a}, {b} unskipped"
                );
            }
        }
    }
}

/// What `sdfl plan` counts as the model's trained numbers is what the
/// objective trains: the hash tables, both networks and a trained β.
#[test]
fn the_plans_weight_count_is_the_objectives() {
    for density in [DensityKind::VolSdf, DensityKind::Neus] {
        for s in [
            spec(density, true),
            spec(density, false),
            hash_spec(density, 0.0, 0),
            NeuralSurface {
                train_beta: true,
                ..hash_spec(density, 0.0, 0)
            },
        ] {
            let obj = SurfaceObjective::new(&s, &[]).unwrap();
            assert_eq!(obj.initial().len() as u64, s.weights(), "{s:?}");
        }
    }
}
