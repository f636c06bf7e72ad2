//! Quality against ground truth: PSNR and SSIM of images (colours in
//! 0..1), and how well a distance field fits its points.

/// Peak signal-to-noise ratio in dB for a peak of 1: `−10·log10(MSE)`
/// over every channel of every pixel (∞ for identical images).
pub fn psnr(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    assert_eq!(a.len(), b.len());
    let n = (3 * a.len()).max(1) as f64;
    let mse: f64 = a
        .iter()
        .zip(b)
        .flat_map(|(x, y)| (0..3).map(move |i| (x[i] as f64 - y[i] as f64).powi(2)))
        .sum::<f64>()
        / n;
    -10.0 * mse.log10()
}

/// Side of the Gaussian window and its standard deviation (Wang et al. 2004).
const WINDOW: usize = 11;
const SIGMA: f64 = 1.5;
const C1: f64 = 0.01 * 0.01;
const C2: f64 = 0.03 * 0.03;

/// Structural similarity (Wang et al. 2004): an 11×11 Gaussian window
/// (σ = 1.5) over every position where it fits, per channel, averaged.
/// Images smaller than the window are compared as one window.
pub fn ssim(a: &[[f32; 3]], b: &[[f32; 3]], width: usize, height: usize) -> f64 {
    assert_eq!(a.len(), width * height);
    assert_eq!(b.len(), width * height);
    let win = WINDOW.min(width).min(height).max(1);
    let g: Vec<f64> = (0..win)
        .map(|i| {
            let x = i as f64 - (win - 1) as f64 / 2.0;
            (-x * x / (2.0 * SIGMA * SIGMA)).exp()
        })
        .collect();
    let gsum: f64 = g.iter().sum();
    let g: Vec<f64> = g.iter().map(|v| v / gsum).collect();
    let (mut total, mut count) = (0.0, 0usize);
    for c in 0..3 {
        // Separable blur of x, y, x², y², xy: rows first, then columns.
        let ch = |img: &[[f32; 3]], f: &dyn Fn(f64, f64) -> f64, other: &[[f32; 3]]| -> Vec<f64> {
            let (ow, oh) = (width - win + 1, height - win + 1);
            let mut rows = vec![0.0; ow * height];
            for y in 0..height {
                for x in 0..ow {
                    rows[y * ow + x] = (0..win)
                        .map(|k| {
                            let p = y * width + x + k;
                            g[k] * f(img[p][c] as f64, other[p][c] as f64)
                        })
                        .sum();
                }
            }
            let mut out = vec![0.0; ow * oh];
            for y in 0..oh {
                for x in 0..ow {
                    out[y * ow + x] = (0..win).map(|k| g[k] * rows[(y + k) * ow + x]).sum();
                }
            }
            out
        };
        let mx = ch(a, &|x, _| x, b);
        let my = ch(b, &|y, _| y, a);
        let xx = ch(a, &|x, _| x * x, b);
        let yy = ch(b, &|y, _| y * y, a);
        let xy = ch(a, &|x, y| x * y, b);
        for i in 0..mx.len() {
            let (vx, vy, cxy) = (
                xx[i] - mx[i] * mx[i],
                yy[i] - my[i] * my[i],
                xy[i] - mx[i] * my[i],
            );
            total += ((2.0 * mx[i] * my[i] + C1) * (2.0 * cxy + C2))
                / ((mx[i] * mx[i] + my[i] * my[i] + C1) * (vx + vy + C2));
            count += 1;
        }
    }
    total / count.max(1) as f64
}

/// How well a trained distance field fits its points.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SdfFit {
    /// Mean |f| at the data points.
    pub surface_mean_abs: f64,
    /// Mean (‖∇f‖ − 1)² at the data points and as many random points.
    pub eikonal: f64,
    /// Symmetric Chamfer distance (mean of both directions' mean nearest
    /// distance) between surface samples of the field and the data points.
    pub chamfer: f64,
    /// Surface samples found (random points projected onto f = 0).
    pub surface_samples: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
