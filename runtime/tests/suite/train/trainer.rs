//! The trainer: NaNs stop it, resumption, masked and covered pixels in
//! batches, warnings about the fit.

use sdfl_runtime::data::view_image::ViewImage;
use sdfl_runtime::train::checkpoint::Checkpoint;
use sdfl_runtime::train::export_names::{Layout, Piece};
use sdfl_runtime::train::fused::Batch;
use sdfl_runtime::train::objective::{Objective, TensorSpec};
use sdfl_runtime::train::trainer::*;
use sdfl_runtime::train::TrainError;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::param::Bound;
use sdfl_stdlib::value::{LastInterval, Optimizer, Sampler, Schedule};

/// One scalar `r` at least 0.5, pulled towards 2 by (r − 2)².
struct Pull;

impl Objective for Pull {
    fn tensors(&self) -> Vec<TensorSpec> {
        vec![TensorSpec {
            name: "sphere.radius".into(),
            offset: 0,
            len: 1,
        }]
    }
    fn initial(&self) -> Vec<f32> {
        vec![1.0]
    }
    fn loss_and_grad(
        &mut self,
        v: &[f32],
        _: &Batch,
        _: f64,
        g: &mut [f32],
    ) -> Result<f64, TrainError> {
        g[0] = 2.0 * (v[0] - 2.0);
        Ok(((v[0] - 2.0) as f64).powi(2))
    }
    fn project(&self, v: &mut [f32]) {
        v[0] = Bound::AtLeast(0.5).project(v[0] as f64) as f32;
    }
}

fn setup(points: &[[f32; 3]]) -> TrainSetup<'_> {
    TrainSetup {
        views: &[],
        points,
        sampler: Sampler {
            samples: 1,
            near: 0.0,
            far: 1.0,
            jitter: false,
            last_interval: LastInterval::Zero,
        },
        rays: 1,
        optimizer: Optimizer {
            lr: 0.1,
            schedule: Schedule::Constant,
            moments: Default::default(),
        },
        losses: &[],
        seed: 0,
    }
}

/// A NaN made by a step (here from a negative second moment, whose
/// square root is NaN) stops training with an error naming the
/// parameter; projection used to turn it into the lower bound, 0.5.
#[test]
fn a_nan_made_by_a_step_stops_training() {
    let points = [[0.0; 3]];
    let setup = setup(&points);
    let mut run = Run::of(Box::new(Pull), 0.1).unwrap();
    run.advance(&setup).unwrap();
    let mut ck = run.checkpoint(Default::default());
    ck.params[0].adam_v = vec![-1.0];
    run.resume(&ck).unwrap();
    let e = run.advance(&setup).unwrap_err().to_string();
    assert!(e.contains("`sphere.radius` became NaN at step 2"), "{e}");
}

/// A neural SDF's checkpoint written before its tensors were named
/// (each stored flat under its trainer name, no frame in the
/// metadata) still resumes, to the same values; a piece stored under
/// another shape is still refused.
#[test]
fn a_flat_neural_sdf_checkpoint_still_resumes() {
    use sdfl_runtime::neural::distance::NeuralSdfObjective;
    use sdfl_stdlib::value::{Encoding, Field, Harmonic, NeuralSdf};
    let spec = NeuralSdf {
        encoding: Encoding::Harmonic(Harmonic {
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
    };
    let run_of = || {
        let obj = NeuralSdfObjective::new(&spec, &[], 1.0);
        let mut run = Run::of(Box::new(obj), 0.1).unwrap();
        let tensors = run.objective.tensors();
        run.describe(Layout::of(&Field::NeuralSdf(spec.clone()), &tensors));
        run
    };
    let run = run_of();
    assert!(run.layout.params[0][0].transposed, "named and shaped");
    let mut ck = run.checkpoint(Default::default());
    // As such a file was: flat pieces, no model, no frame.
    ck.pieces = run
        .tensors
        .iter()
        .map(|t| vec![Piece::flat(&t.name, t.len)])
        .collect();
    ck.model = serde_json::Value::Null;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("old.ckpt");
    ck.write(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let mut meta = header.metadata().clone().unwrap();
    for key in ["data_to_model", "warp", "background"] {
        assert!(meta.remove(key).is_some(), "{key}");
    }
    let t = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    std::fs::write(
        &path,
        safetensors::serialize(t.tensors(), &Some(meta)).unwrap(),
    )
    .unwrap();
    let old = Checkpoint::read(&path).unwrap();
    assert_eq!(old.frame, sdfl_runtime::train::frame::ModelFrame::default());
    let mut resumed = run_of();
    resumed.resume(&old).unwrap();
    assert_eq!(resumed.values(), run.values());
    // A shape that is neither the model's nor the flat one is refused.
    let mut odd = old.clone();
    odd.pieces[0][0].shape = vec![2, odd.pieces[0][0].shape[0] / 2];
    let e = run_of().resume(&odd).unwrap_err().to_string();
    assert!(e.contains("the checkpoint stores `hidden.0.weight`"), "{e}");
}

/// Values outside their parameter's range are refused on resuming.
#[test]
fn resumed_values_must_be_in_range() {
    let mut run = Run::of(Box::new(Pull), 0.1).unwrap();
    let mut ck = run.checkpoint(Default::default());
    for bad in [-5.0, f32::NAN, f32::INFINITY] {
        ck.params[0].values = vec![bad];
        let e = run.resume(&ck).unwrap_err().to_string();
        assert!(
            e.contains("`sphere.radius`") && e.contains("outside its range"),
            "{e}"
        );
    }
    ck.params[0].values = vec![0.75];
    run.resume(&ck).unwrap();
}

/// Rays never fall on masked pixels; views without a mask keep all.
#[test]
fn batches_leave_out_masked_pixels() {
    use glam::DVec3;
    let cam = Camera::look_at(DVec3::new(0.0, 0.0, -3.0), DVec3::ZERO, DVec3::Y, 1.0);
    let image = ViewImage::rgb32(4, 4, vec![[0.5; 3]; 16]);
    // View 0: only the left column kept.
    let mask: std::sync::Arc<[bool]> = (0..16).map(|i| i % 4 == 0).collect();
    let views = [
        TrainView {
            camera: cam,
            image: image.clone(),
            mask: Some(mask.clone()),
            coverage: None,
        },
        TrainView {
            camera: cam,
            image,
            mask: None,
            coverage: None,
        },
    ];
    let mut s = setup(&[]);
    s.sampler.samples = 4;
    s.views = &views;
    s.rays = 24;
    let (mut seen0, mut seen1) = (0, 0);
    for step in 0..20 {
        let b = s.batch(step).unwrap();
        assert_eq!(b.rays.len(), b.targets.len());
        for r in &b.rays {
            if r.view == 0 {
                assert!(mask[r.pixel as usize], "step {step}: pixel {}", r.pixel);
                seen0 += 1;
            } else {
                seen1 += 1;
            }
        }
    }
    // Both views are trained on; the unmasked one about four times as often.
    assert!(seen0 > 0 && seen1 > 2 * seen0, "{seen0} {seen1}");
    // Every pixel masked: an error, not an empty batch.
    let none: std::sync::Arc<[bool]> = vec![false; 16].into();
    let all_masked = [TrainView {
        mask: Some(none),
        ..views[0].clone()
    }];
    s.views = &all_masked;
    assert!(s.batch(0).is_err());
}

/// Each ray's coverage is its own pixel's, where every view knows it;
/// none where a view does not.
#[test]
fn batch_coverage_follows_the_rays() {
    use glam::DVec3;
    let cam = Camera::look_at(DVec3::new(0.0, 0.0, -3.0), DVec3::ZERO, DVec3::Y, 1.0);
    let image = ViewImage::rgb32(4, 4, vec![[0.5; 3]; 16]);
    let cover =
        |k: usize| -> std::sync::Arc<[u8]> { (0..16).map(|i| (i * 16 + k) as u8).collect() };
    let views: Vec<TrainView> = (0..2)
        .map(|k| TrainView {
            camera: cam,
            image: image.clone(),
            mask: None,
            coverage: Some(cover(k)),
        })
        .collect();
    let mut s = setup(&[]);
    s.sampler.samples = 4;
    s.views = &views;
    s.rays = 24;
    let b = s.batch(3).unwrap();
    assert_eq!(b.coverage.len(), b.rays.len());
    for (r, c) in b.rays.iter().zip(&b.coverage) {
        assert_eq!(*c, cover(r.view as usize)[r.pixel as usize] as f32 / 255.0);
    }
    let mut partly = views.clone();
    partly[1].coverage = None;
    s.views = &partly;
    assert!(s.batch(3).unwrap().coverage.is_empty());
}

#[test]
fn a_converging_fit_gives_no_warning() {
    let losses: Vec<f32> = (0..500).map(|i| 1.0 / (1.0 + i as f32)).collect();
    assert!(fit_warnings(&losses, &[]).is_empty());
    // Noise around a floor is not a divergence.
    let noisy: Vec<f32> = (0..500)
        .map(|i| 0.01 + 1.0 / (1.0 + i as f32) + 0.005 * ((i * 7919) % 13) as f32 / 13.0)
        .collect();
    assert!(fit_warnings(&noisy, &[]).is_empty());
    // Too short to judge.
    assert!(fit_warnings(&[1.0, 5.0, 100.0], &[]).is_empty());
    // Already at the optimum: nothing to fall.
    assert!(fit_warnings(&[1e-9; 100], &[]).is_empty());
}

#[test]
fn a_diverging_fit_and_parameters_at_bounds_warn() {
    let losses: Vec<f32> = (0..400)
        .map(|i| {
            if i < 100 {
                0.05 / (1.0 + i as f32)
            } else {
                0.31
            }
        })
        .collect();
    let w = fit_warnings(&losses, &[]);
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(
        w[0].contains("diverged") && w[0].contains("learning rate"),
        "{w:?}"
    );
    // A loss that jumps at the first step and stays there.
    let w = fit_warnings(&[0.04; 40], &["radius".to_string()]);
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(w[0].contains("did not fall"), "{w:?}");
    assert!(w[1].contains("radius"), "{w:?}");
}

/// Held-out PSNR that falls by a decibel or more from its best while the
/// training loss falls is said; a smaller wander, a single evaluation, a
/// loss that rose too (the divergence warning's case) and a NaN score are
/// not.
#[test]
fn held_out_psnr_falling_while_the_loss_falls_warns() {
    let falling: Vec<f32> = (0..2000).map(|i| 0.1 / (1.0 + i as f32 / 50.0)).collect();
    let w = held_out_warning(&falling, &[(500, 25.0), (1000, 26.0), (2000, 24.5)]);
    let w = w.expect("a warning");
    assert!(
        w.contains("26.00 dB (step 1000)") && w.contains("24.50 dB (step 2000)"),
        "{w}"
    );
    assert!(held_out_warning(&falling, &[(1000, 26.0), (2000, 25.5)]).is_none());
    assert!(held_out_warning(&falling, &[(2000, 20.0)]).is_none());
    assert!(held_out_warning(&falling, &[]).is_none());
    assert!(held_out_warning(&falling, &[(1000, 26.0), (2000, f64::NAN)]).is_none());
    let rising: Vec<f32> = (0..2000).map(|i| 0.01 + i as f32 * 1e-4).collect();
    assert!(held_out_warning(&rising, &[(1000, 26.0), (2000, 20.0)]).is_none());
    // Rising held-out PSNR: nothing to say.
    assert!(held_out_warning(&falling, &[(1000, 20.0), (2000, 26.0)]).is_none());
}
