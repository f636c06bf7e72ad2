//! Probe: how many iterations the assignment's box fit needs (self-rendered
//! targets or the real data when present).
use sdfl_runtime::data::npy::{read_rgb_f32, RgbImage};
use sdfl_runtime::train::*;
use sdfl_runtime::volume::*;
use std::ops::ControlFlow;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let real = args.get(1).map(|s| s == "real").unwrap_or(false);
    let rays: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(4096);
    let lr: f64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(5e-4);
    let res: u32 = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(256);
    let cams = assignment_cameras();
    let views: Vec<FitView> = if real {
        (0..4)
            .map(|k| FitView {
                camera: cams[k],
                image: read_rgb_f32(format!("../shared/data/assignment3/box_{k}.npy")).unwrap(),
            })
            .collect()
    } else {
        let target = BoxVolume::new([0.25, 0.25, 0.0], [2.0, 1.5, 1.5], 1.0, 0.05).unwrap();
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        let size = ImageSize {
            width: res,
            height: res,
        };
        cams.iter()
            .map(|c| {
                let img = render_box_image(&target, &s, c, size).unwrap();
                FitView {
                    camera: *c,
                    image: RgbImage {
                        width: res,
                        height: res,
                        pixels: img.colour,
                    },
                }
            })
            .collect()
    };
    let mut cfg = BoxFitConfig::assignment();
    cfg.batch_rays = rays;
    cfg.lr = lr;
    cfg.iterations = 20000;
    let t0 = std::time::Instant::now();
    let want = [0.25f32, 0.25, 0.0, 2.0, 1.5, 1.5];
    let mut first_ok = None;
    let r = fit_box_with(&views, &cfg, |it, v, loss| {
        let p = [
            v.center[0],
            v.center[1],
            v.center[2],
            v.sides[0],
            v.sides[1],
            v.sides[2],
        ];
        let err = p
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        if it % 250 == 0 {
            println!("{it} loss {loss:.6} err {err:.4} {p:?}");
        }
        if err < 0.01 && first_ok.is_none() {
            first_ok = Some(it);
            println!("within 0.01 at {it}");
        }
        if err >= 0.01 {
            first_ok = None;
        }
        if first_ok.map(|f| it >= f + 500).unwrap_or(false) {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    })
    .unwrap();
    println!(
        "{:?} after {} its, {:.2}s",
        r.volume,
        r.iterations,
        t0.elapsed().as_secs_f64()
    );
}
