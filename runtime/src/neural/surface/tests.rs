//! The neural surface's gradient against finite differences, β's schedule,
//! fine samples at the surface, finite colours.

use super::*;
use sdfl_stdlib::value::{Harmonic as HarmonicSpec, NeuralSdf};

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
        let mut out = Samples::default();
        obj.upsample(
            &values,
            Levels::All,
            obj.beta(&values),
            &rays,
            &coarse,
            n,
            Spacing::Even,
            LastInterval::Zero,
            &mut out,
        )
        .unwrap();
        let m = n + 16;
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

/// The gradient is the same, bit for bit, at one and at two threads, over
/// more samples than one block of the backward holds.
#[test]
fn hash_surface_gradient_is_bit_identical_at_any_thread_count() {
    for step in [0.0, 0.02] {
        let s = NeuralSurface {
            fine: 8,
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
        const { assert!(300 * 32 > crate::neural::hash_sdf::volume::BLOCK) };
        assert_eq!(run(1), run(2), "eikonal step {step}");
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
