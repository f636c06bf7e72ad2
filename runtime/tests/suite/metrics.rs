//! Image metrics: PSNR and SSIM against their definitions, tiny and flat
//! images.

use sdfl_runtime::metrics::*;

fn image(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> Vec<[f32; 3]> {
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| f(x, y))
        .collect()
}

#[test]
fn psnr_of_a_known_error() {
    let a = image(8, 8, |_, _| [0.5; 3]);
    let b = image(8, 8, |_, _| [0.6; 3]);
    // MSE 0.01 → 20 dB.
    assert!((psnr(&a, &b) - 20.0).abs() < 1e-5);
    assert_eq!(psnr(&a, &a), f64::INFINITY);
}

/// SSIM by its definition, one window at a time in f64.
fn ssim_reference(a: &[[f32; 3]], b: &[[f32; 3]], w: usize, h: usize) -> f64 {
    let win = WINDOW;
    let wts: Vec<f64> = (0..win)
        .map(|i| {
            let x = i as f64 - 5.0;
            (-x * x / (2.0 * SIGMA * SIGMA)).exp()
        })
        .collect();
    let s: f64 = wts.iter().sum::<f64>().powi(2);
    let (mut total, mut n) = (0.0, 0);
    for c in 0..3 {
        for y0 in 0..=h - win {
            for x0 in 0..=w - win {
                let (mut mx, mut my, mut xx, mut yy, mut xy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for j in 0..win {
                    for i in 0..win {
                        let wt = wts[i] * wts[j] / s;
                        let p = (y0 + j) * w + x0 + i;
                        let (x, y) = (a[p][c] as f64, b[p][c] as f64);
                        mx += wt * x;
                        my += wt * y;
                        xx += wt * x * x;
                        yy += wt * y * y;
                        xy += wt * x * y;
                    }
                }
                let (vx, vy, cxy) = (xx - mx * mx, yy - my * my, xy - mx * my);
                total += ((2.0 * mx * my + C1) * (2.0 * cxy + C2))
                    / ((mx * mx + my * my + C1) * (vx + vy + C2));
                n += 1;
            }
        }
    }
    total / n as f64
}

#[test]
fn ssim_matches_its_definition() {
    let (w, h) = (23, 17);
    let a = image(w, h, |x, y| {
        [
            ((x * 7 + y * 3) % 11) as f32 / 10.0,
            (x as f32 / w as f32),
            0.3,
        ]
    });
    let b = image(w, h, |x, y| {
        [
            ((x * 5 + y * 3) % 11) as f32 / 10.0,
            (y as f32 / h as f32),
            0.35,
        ]
    });
    assert!((ssim(&a, &a, w, h) - 1.0).abs() < 1e-9);
    let got = ssim(&a, &b, w, h);
    let want = ssim_reference(&a, &b, w, h);
    assert!((got - want).abs() < 1e-9, "{got} vs {want}");
    assert!(got < 0.9);
}

#[test]
fn tiny_and_flat_images_are_finite() {
    let a = image(3, 2, |_, _| [0.0; 3]);
    let b = image(3, 2, |_, _| [1.0; 3]);
    assert!(ssim(&a, &b, 3, 2).is_finite());
    assert!(ssim(&a, &a, 3, 2) > 0.999);
    assert!(psnr(&a, &b).is_finite());
}
