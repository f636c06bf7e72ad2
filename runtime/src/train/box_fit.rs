//! The assignment's part 2 ("train_box"): fit a box volume's centre and side
//! lengths to posed RGB views with Adam on batches of random rays.

use std::ops::ControlFlow;

use sdfl_stdlib::camera::Camera;

use dfdx::prelude::*;

use super::box_graph::box_loss_graph;
use super::box_op::box_volume_colours;
use super::params::{Adam, ParamStore};
use super::TrainError;
use crate::data::npy::RgbImage;
use crate::volume::rays::{random_rays, ImageSize, SplitMix64, Stratified};
use crate::volume::{box_loss_and_grad, BoxVolume};

/// One training view: a camera and the image it saw.
#[derive(Debug, Clone)]
pub struct FitView {
    pub camera: Camera,
    pub image: RgbImage,
}

/// Which implementation computes loss and gradients.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FitBackend {
    /// Hand-written f32 forward/backward, parallel over rays (fast path).
    Fused,
    /// The dfdx autodiff graph of [`super::box_graph`].
    Dfdx,
    /// A dfdx graph whose colours come from the fused kernel as one op
    /// ([`super::box_op`]); the MSE and the backward run through dfdx.
    FusedOp,
}

/// Settings of a box fit.
#[derive(Debug, Clone)]
pub struct BoxFitConfig {
    /// Initial box; its α and β stay fixed.
    pub start: BoxVolume,
    pub sampler: Stratified,
    /// Rays per batch, drawn without replacement from all pixels of all views.
    pub batch_rays: usize,
    pub lr: f64,
    /// The learning rate is multiplied by this every `decay_every`
    /// iterations (`decay_every == 0`: constant).
    pub lr_decay: f64,
    pub decay_every: usize,
    pub iterations: usize,
    pub seed: u64,
    pub backend: FitBackend,
}

impl BoxFitConfig {
    /// The assignment's settings: start centre (0,0,0), sides (1.5,1.5,1.5),
    /// α = 1, β = 0.05, 64 samples on [0, 5], 4096 rays, Adam lr 5e-4, and
    /// [`Self::ASSIGNMENT_ITERATIONS`] iterations.
    pub fn assignment() -> Self {
        BoxFitConfig {
            start: BoxVolume {
                center: [0.0; 3],
                sides: [1.5; 3],
                alpha: 1.0,
                beta: 0.05,
            },
            sampler: Stratified {
                n: 64,
                near: 0.0,
                far: 5.0,
            },
            batch_rays: 4096,
            lr: 5e-4,
            lr_decay: 1.0,
            decay_every: 0,
            iterations: Self::ASSIGNMENT_ITERATIONS,
            seed: 0,
            backend: FitBackend::Fused,
        }
    }

    /// Iterations at lr 5e-4 after which the fit is within 0.01 of the
    /// target on the assignment's views (measured; see the tests).
    /// With 4096 rays on the 256×256 views: within 0.01 after ~1230
    /// iterations, ~0.005 after 1500 (1024 rays: ~1270).
    pub const ASSIGNMENT_ITERATIONS: usize = 2000;
}

/// Outcome of a fit.
#[derive(Debug, Clone)]
pub struct BoxFitResult {
    pub volume: BoxVolume,
    pub iterations: usize,
    /// Batch loss of every iteration (before its update).
    pub losses: Vec<f32>,
}

/// The four cameras of the assignment's `box_{0..3}.npy` views.
pub fn assignment_cameras() -> Vec<Camera> {
    use glam::DVec3;
    [
        (-2.5, 0.0, 0.0),
        (-1.0, 0.0, -2.2),
        (0.0, 0.0, -2.5),
        (1.0, 0.0, -2.2),
    ]
    .iter()
    .map(|&(x, y, z)| Camera::look_at(DVec3::new(x, y, z), DVec3::ZERO, DVec3::Y, 1.0))
    .collect()
}

/// Fits the box for `cfg.iterations` iterations.
pub fn fit_box(views: &[FitView], cfg: &BoxFitConfig) -> Result<BoxFitResult, TrainError> {
    fit_box_with(views, cfg, |_, _, _| ControlFlow::Continue(()))
}

/// Fits the box, calling `on_step(iteration, box after the update, batch
/// loss)` after every iteration; `Break` stops early.
pub fn fit_box_with(
    views: &[FitView],
    cfg: &BoxFitConfig,
    mut on_step: impl FnMut(usize, &BoxVolume, f32) -> ControlFlow<()>,
) -> Result<BoxFitResult, TrainError> {
    cfg.start.validate()?;
    let sampler = Stratified::new(cfg.sampler.n, cfg.sampler.near, cfg.sampler.far)?;
    let first = views
        .first()
        .ok_or_else(|| TrainError::Invalid("no training views".into()))?;
    let size = ImageSize {
        width: first.image.width,
        height: first.image.height,
    };
    for v in views {
        if v.image.width != size.width
            || v.image.height != size.height
            || v.image.pixels.len() != size.pixels()
        {
            return Err(TrainError::Invalid(
                "all views must have the same image size".into(),
            ));
        }
    }
    if cfg.batch_rays == 0 {
        return Err(TrainError::Invalid("batch_rays must be positive".into()));
    }
    let cams: Vec<Camera> = views.iter().map(|v| v.camera).collect();
    let t = sampler.depths();

    let mut store = ParamStore::new();
    let center = store.add("center", &cfg.start.center, true)?;
    let sides = store.add("sides", &cfg.start.sides, true)?;
    let mut opt = Adam::new(cfg.lr)?;
    let mut rng = SplitMix64::new(cfg.seed);
    let mut losses = Vec::with_capacity(cfg.iterations);
    let current = |store: &ParamStore| -> BoxVolume {
        let c = store.values(center);
        let s = store.values(sides);
        BoxVolume {
            center: [c[0], c[1], c[2]],
            sides: [s[0], s[1], s[2]],
            ..cfg.start
        }
    };
    for it in 0..cfg.iterations {
        if cfg.decay_every > 0 {
            opt.cfg.lr = cfg.lr * cfg.lr_decay.powi((it / cfg.decay_every) as i32);
        }
        let rays = random_rays(&cams, size, cfg.batch_rays, &mut rng)?;
        let targets: Vec<[f32; 3]> = rays
            .iter()
            .map(|r| views[r.view as usize].image.pixels[r.pixel as usize])
            .collect();
        let loss = match cfg.backend {
            FitBackend::Fused => {
                let (loss, g) = box_loss_and_grad(&current(&store), &sampler, &rays, &targets)?;
                opt.update_from_slices(&mut store, &[(center, &g.center), (sides, &g.sides)])?;
                loss
            }
            FitBackend::Dfdx => {
                let a = cfg.start;
                let (loss, mut grads) =
                    box_loss_graph(&store, center, sides, a.alpha, a.beta, &t, &rays, &targets)?;
                opt.update(&mut store, &mut grads)?;
                loss
            }
            FitBackend::FusedOp => {
                let a = cfg.start;
                let rgb = box_volume_colours(
                    store.tensor(center).leaky_trace(),
                    store.tensor(sides).leaky_trace(),
                    a.alpha,
                    a.beta,
                    &sampler,
                    &rays,
                )?;
                let flat: Vec<f32> = targets.iter().flatten().copied().collect();
                let tgt = store.device().tensor_from_vec(flat, (rays.len(), 3usize));
                let loss = (rgb - tgt).square().mean();
                let value = loss.array();
                opt.update(&mut store, &mut loss.backward())?;
                value
            }
        };
        losses.push(loss);
        let vol = current(&store);
        vol.validate()?;
        if on_step(it + 1, &vol, loss).is_break() {
            break;
        }
    }
    Ok(BoxFitResult {
        volume: current(&store),
        iterations: losses.len(),
        losses,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::npy::read_rgb_f32;
    use crate::volume::{render_box_image, Ray};

    const WANT: [f32; 6] = [0.25, 0.25, 0.0, 2.0, 1.5, 1.5];

    fn max_err(v: &BoxVolume) -> f32 {
        let p = [
            v.center[0],
            v.center[1],
            v.center[2],
            v.sides[0],
            v.sides[1],
            v.sides[2],
        ];
        p.iter()
            .zip(&WANT)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max)
    }

    /// The four target views rendered by our own f32 volume renderer.
    fn synthetic_views(res: u32) -> Vec<FitView> {
        let target = BoxVolume::new([0.25, 0.25, 0.0], [2.0, 1.5, 1.5], 1.0, 0.05).unwrap();
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        let size = ImageSize {
            width: res,
            height: res,
        };
        assignment_cameras()
            .into_iter()
            .map(|camera| FitView {
                camera,
                image: RgbImage {
                    width: res,
                    height: res,
                    pixels: render_box_image(&target, &s, &camera, size).unwrap().colour,
                },
            })
            .collect()
    }

    /// The assignment's settings except 1024 rays a batch (4096 behaves the
    /// same per iteration, see `ASSIGNMENT_ITERATIONS`), to keep CI fast.
    fn test_config() -> BoxFitConfig {
        BoxFitConfig {
            batch_rays: 1024,
            iterations: 1600,
            ..BoxFitConfig::assignment()
        }
    }

    #[test]
    fn recovers_self_rendered_box_at_lr_5e4() {
        let views = synthetic_views(64);
        let r = fit_box(&views, &test_config()).unwrap();
        assert!(max_err(&r.volume) < 0.01, "{:?}", r.volume);
        assert!(r.losses[r.iterations - 1] < 1e-3 * r.losses[0]);
    }

    #[test]
    fn recovers_assignment_box_from_npy_views() {
        // Reads the assignment's data at ../shared/data/assignment3 (relative
        // to the repository root) only where that folder exists.
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/assignment3");
        if !dir.is_dir() {
            eprintln!(
                "note: {} not found; skipping the real-data box fit",
                dir.display()
            );
            return;
        }
        let views: Vec<FitView> = assignment_cameras()
            .into_iter()
            .enumerate()
            .map(|(k, camera)| FitView {
                camera,
                image: read_rgb_f32(dir.join(format!("box_{k}.npy"))).unwrap(),
            })
            .collect();
        assert_eq!((views[0].image.width, views[0].image.height), (256, 256));
        let r = fit_box(&views, &test_config()).unwrap();
        assert!(max_err(&r.volume) < 0.01, "{:?}", r.volume);
    }

    /// A finding about the assignment's data, kept as a test so it stays
    /// visible: `box_{k}.npy` were rendered with pixel centres at
    /// `1 − (2i+1)/W` (PyTorch3D's NDC pixel centres), not at
    /// `1 − 2i/(W−1)` as CONVENTIONS.md says. With the former our renderer
    /// reproduces the data to MSE ~1e-13; with the conventions' grid the MSE
    /// is ~1e-5 and the fit's x side settles at ≈ 2.005 instead of 2.000.
    #[test]
    fn assignment_data_has_half_pixel_centres() {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/assignment3");
        if !dir.is_dir() {
            eprintln!("note: {} not found; skipping", dir.display());
            return;
        }
        let target = BoxVolume::new([0.25, 0.25, 0.0], [2.0, 1.5, 1.5], 1.0, 0.05).unwrap();
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        let cam = assignment_cameras()[1];
        let img = read_rgb_f32(dir.join("box_1.npy")).unwrap();
        let (w, h) = (img.width, img.height);
        let mse = |ndc: &dyn Fn(u32, u32) -> f64| {
            let rays: Vec<Ray> = (0..w * h)
                .map(|p| {
                    let d = cam.ray_direction(ndc(p % w, w), ndc(p / w, h));
                    Ray {
                        origin: cam.eye.to_array().map(|v| v as f32),
                        dir: d.to_array().map(|v| v as f32),
                        view: 0,
                        pixel: p,
                    }
                })
                .collect();
            let r = crate::volume::render_box_rays(&target, &s, &rays).unwrap();
            let se: f64 = img
                .pixels
                .iter()
                .zip(&r)
                .map(|(a, b)| {
                    (0..3)
                        .map(|c| ((a[c] - b.colour[c]) as f64).powi(2))
                        .sum::<f64>()
                })
                .sum();
            se / (3 * rays.len()) as f64
        };
        let conventions = mse(&|i, n| 1.0 - 2.0 * i as f64 / (n - 1) as f64);
        let half_pixel = mse(&|i, n| 1.0 - (2.0 * i as f64 + 1.0) / n as f64);
        assert!(half_pixel < 1e-10, "{half_pixel}");
        assert!(conventions > 1e-6, "{conventions}");
    }

    #[test]
    fn dfdx_backend_follows_the_fused_one() {
        let views = synthetic_views(32);
        let cfg = BoxFitConfig {
            batch_rays: 256,
            iterations: 40,
            ..BoxFitConfig::assignment()
        };
        let a = fit_box(&views, &cfg).unwrap();
        let b = fit_box(
            &views,
            &BoxFitConfig {
                backend: FitBackend::Dfdx,
                ..cfg.clone()
            },
        )
        .unwrap();
        let op = fit_box(
            &views,
            &BoxFitConfig {
                backend: FitBackend::FusedOp,
                ..cfg.clone()
            },
        )
        .unwrap();
        // The op computes the same f32 numbers as the fused path up to the
        // summation order of the MSE.
        for i in 0..3 {
            assert!((a.volume.center[i] - op.volume.center[i]).abs() < 1e-4);
            assert!((a.volume.sides[i] - op.volume.sides[i]).abs() < 1e-4);
        }
        // Same batches and gradients equal to ~1e-4 relative, but Adam
        // normalises near-zero gradient components (centre z here), so the
        // trajectories agree to a fraction of the distance travelled (≤ 0.02).
        for i in 0..3 {
            assert!((a.volume.center[i] - b.volume.center[i]).abs() < 2e-3);
            assert!((a.volume.sides[i] - b.volume.sides[i]).abs() < 2e-3);
        }
        for (la, lb) in a.losses.iter().zip(&b.losses) {
            assert!((la - lb).abs() < 1e-3 * la);
        }
        assert_eq!(a.losses.len(), 40);
        // It moved towards the target (each step moves a parameter ≤ ~lr).
        assert!(max_err(&b.volume) < max_err(&cfg.start) - 0.015);
    }

    #[test]
    fn bad_inputs_are_errors() {
        let cfg = test_config();
        assert!(fit_box(&[], &cfg).is_err());
        let mut views = synthetic_views(8);
        views[1].image.width = 4;
        assert!(fit_box(&views, &cfg).is_err());
        let views = synthetic_views(8);
        let big = BoxFitConfig {
            batch_rays: 10_000,
            ..cfg.clone()
        };
        assert!(fit_box(&views, &big).is_err());
        let mut bad = cfg;
        bad.start.alpha = 2.0;
        assert!(fit_box(&views, &bad).is_err());
    }
}
