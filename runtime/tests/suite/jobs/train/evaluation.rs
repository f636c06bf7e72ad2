//! Held-out evaluation: PSNR inside a mask, large evaluations announced.

use sdfl_runtime::data::view_image::ViewImage;
use sdfl_runtime::data::TrainView;
use sdfl_runtime::jobs::train::evaluation::*;
use sdfl_runtime::metrics;
use sdfl_runtime::train::log::TrainEvent;
use sdfl_stdlib::camera::Camera;
use std::sync::Mutex;

fn views(n: usize, side: u32) -> Vec<TrainView> {
    let cam = Camera::look_at(
        glam::DVec3::new(0.0, 0.0, -3.0),
        glam::DVec3::ZERO,
        glam::DVec3::Y,
        1.0,
    );
    (0..n)
        .map(|_| TrainView {
            camera: cam,
            image: ViewImage::rgba8(side, side, vec![[0; 4]; (side * side) as usize], [0.0; 3]),
            mask: None,
            coverage: None,
        })
        .collect()
}

/// PSNR inside a mask counts only the pixels it covers at least
/// half, and a view whose mask covers none has no such PSNR (not
/// NaN, which a checkpoint would refuse on resuming).
#[test]
fn psnr_inside_a_mask_counts_its_pixels_only() {
    let target = [[0.5f32; 3]; 4];
    let colour = [[0.5, 0.5, 0.5], [0.6, 0.5, 0.5], [0.0; 3], [1.0; 3]];
    let cover = [255u8, 128, 127, 0];
    let want = metrics::psnr(&colour[..2], &target[..2]);
    assert_eq!(psnr_inside(&colour, &target, &cover, None), Some(want));
    let keep = [true, false, true, true];
    assert_eq!(
        psnr_inside(&colour, &target, &cover, Some(&keep)),
        Some(f64::INFINITY)
    );
    assert_eq!(psnr_inside(&colour, &target, &[0; 4], None), None);
}

/// Large held-out sets are announced with a line (shown piped), every
/// view on the status line; small ones only on the status line.
#[test]
fn a_large_evaluation_says_so_and_counts_its_views() {
    let seen = Mutex::new(Vec::new());
    let observer = |e: &TrainEvent| {
        let line = match e {
            TrainEvent::Note(t) => format!("note {t}"),
            TrainEvent::Status(t) => format!("status {t}"),
            _ => return,
        };
        seen.lock().unwrap().push(line);
    };
    let large = views(2, 800);
    let scored = announce("lego", 250, &large, &observer);
    scored(1);
    scored(2);
    assert_eq!(
        *seen.lock().unwrap(),
        [
            "note lego: scoring 2 held-out views of 800x800 at step 250",
            "status lego: scored held-out view 1 of 2 at step 250",
            "status lego: scored held-out view 2 of 2 at step 250",
        ]
    );
    seen.lock().unwrap().clear();
    let small = views(3, 100);
    announce("t", 10, &small, &observer)(1);
    assert_eq!(
        *seen.lock().unwrap(),
        ["status t: scored held-out view 1 of 3 at step 10"]
    );
}
