//! Held-out evaluation: the trained field renders the views held out of
//! training, scored by PSNR and SSIM (masked pixels left out), during
//! training and at its end.

use super::super::*;
use crate::train::TrainedField;

pub use crate::train::log::HeldOut;

/// Each held-out view as a row: truth | render | |error|×4.
pub(super) fn comparison_image(
    views: &[TrainView],
    renders: &[Vec<[f32; 3]>],
) -> (u32, u32, Vec<u8>) {
    let w = views.iter().map(|v| v.image.width).max().unwrap_or(1);
    let h: u32 = views.iter().map(|v| v.image.height).sum::<u32>().max(1);
    let mut out = vec![0u8; (3 * w * h * 3) as usize];
    let mut y0 = 0;
    for (v, r) in views.iter().zip(renders) {
        let (vw, vh) = (v.image.width, v.image.height);
        for y in 0..vh {
            for x in 0..vw {
                let i = (y * vw + x) as usize;
                let (t, c) = (v.image.pixel(i), r[i]);
                let err = [0, 1, 2].map(|k| (4.0 * (t[k] - c[k]).abs()).min(1.0));
                for (panel, px) in [t, c, err].iter().enumerate() {
                    let o = 3 * (((y0 + y) * 3 * w) + panel as u32 * w + x) as usize;
                    for k in 0..3 {
                        out[o + k] = to_u8(px[k] as f64);
                    }
                }
            }
        }
        y0 += vh;
    }
    (3 * w, h, out)
}

/// The held-out views' mean PSNR and SSIM at some values, with each
/// view's render.
pub(super) struct Evaluation {
    /// Mean over the views of each view's PSNR (dB).
    pub psnr: f64,
    /// Mean over the views of each view's SSIM.
    pub ssim: f64,
    /// Each view's colours, row by row.
    pub renders: Vec<Vec<[f32; 3]>>,
}

/// Whether a held-out evaluation is due after step `step`: every
/// `eval_every` steps, where there are views to score.
pub(super) fn due(job: &TrainJob, step: usize, views: &[TrainView]) -> bool {
    step > 0 && job.eval_every > 0 && !views.is_empty() && step.is_multiple_of(job.eval_every)
}

/// Scores the held-out `views` at step `step` into `log`.
pub(super) fn evaluate_into(
    log: &mut crate::train::log::TrainLog,
    step: usize,
    field: &dyn TrainedField,
    values: &[f32],
    views: &[TrainView],
) -> io::Result<()> {
    let t = std::time::Instant::now();
    let e = evaluate(field, values, views)?;
    let took = t.elapsed().as_secs_f64();
    let first = crate::train::log::first_view(views, &e.renders);
    log.evaluated(step, e.psnr, e.ssim, took, first);
    Ok(())
}

/// The held-out `views` rendered by `field` at `values` and scored.
pub(super) fn evaluate(
    field: &dyn TrainedField,
    values: &[f32],
    views: &[TrainView],
) -> io::Result<Evaluation> {
    let (mut psnr, mut ssim, mut renders) = (0.0, 0.0, Vec::new());
    for v in views {
        let (w, h) = (v.image.width, v.image.height);
        let size = ImageSize {
            width: w,
            height: h,
        };
        let colour = field
            .render_view(values, &v.camera, size, false)
            .map_err(invalid)?
            .colour;
        // Masked pixels are not scored: left out of PSNR, and the
        // render's own colour in the target for SSIM's windows.
        let target: std::borrow::Cow<[[f32; 3]]> = match &v.mask {
            None => v.image.to_rgb().into(),
            Some(m) => v
                .image
                .colours()
                .zip(&colour)
                .zip(m.iter())
                .map(|((t, c), keep)| if *keep { t } else { *c })
                .collect::<Vec<_>>()
                .into(),
        };
        psnr += match &v.mask {
            None => metrics::psnr(&colour, &target),
            Some(m) => {
                let kept = |img: &[[f32; 3]]| -> Vec<[f32; 3]> {
                    img.iter()
                        .zip(m.iter())
                        .filter(|(_, k)| **k)
                        .map(|(p, _)| *p)
                        .collect()
                };
                metrics::psnr(&kept(&colour), &kept(&target))
            }
        };
        ssim += metrics::ssim(&colour, &target, w as usize, h as usize);
        renders.push(colour);
    }
    let n = views.len().max(1) as f64;
    Ok(Evaluation {
        psnr: psnr / n,
        ssim: ssim / n,
        renders,
    })
}
