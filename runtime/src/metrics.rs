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

/// Side of the Gaussian window (Wang et al. 2004).
pub const WINDOW: usize = 11;
/// The window's standard deviation.
pub const SIGMA: f64 = 1.5;
/// SSIM's constant `(K₁L)²` for values in [0, 1].
pub const C1: f64 = 0.01 * 0.01;
/// SSIM's constant `(K₂L)²` for values in [0, 1].
pub const C2: f64 = 0.03 * 0.03;

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
