//! Held-out evaluation: the trained field renders the views held out of
//! training, scored by PSNR and SSIM (masked pixels left out), during
//! training and at its end.

use super::super::*;
use crate::train::log::{Observer, TrainEvent};
use crate::train::TrainedField;

pub use crate::train::log::HeldOut;

/// Each held-out view that has a render as a row: truth | render |
/// |error|×4.
pub(super) fn comparison_image(
    views: &[TrainView],
    renders: &[Vec<[f32; 3]>],
) -> (u32, u32, Vec<u8>) {
    let views = &views[..renders.len().min(views.len())];
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

/// The held-out views' mean PSNR and SSIM at some values, with the
/// renders of the first views.
pub(super) struct Evaluation {
    /// Mean over the views of each view's PSNR (dB).
    pub psnr: f64,
    /// Mean over the views of each view's SSIM.
    pub ssim: f64,
    /// Mean over the views of each view's PSNR inside its object mask
    /// (pixels covered at least half), where every view has one.
    pub psnr_in_mask: Option<f64>,
    /// The first views' colours, row by row (as many as asked to keep).
    pub renders: Vec<Vec<[f32; 3]>>,
}

impl Evaluation {
    /// Its scores of `views` views, as the log keeps them.
    pub fn scores(&self, views: usize) -> crate::train::log::Scores {
        crate::train::log::Scores {
            psnr: self.psnr,
            ssim: self.ssim,
            psnr_in_mask: self.psnr_in_mask,
            views,
        }
    }
}

/// Whether a held-out evaluation is due after step `step`: every
/// `eval_every` steps, where there are views to score.
pub(super) fn due(job: &TrainJob, step: usize, views: &[TrainView]) -> bool {
    step > 0 && job.eval_every > 0 && !views.is_empty() && step.is_multiple_of(job.eval_every)
}

/// Scores the held-out `views` at step `step` into `log`, telling
/// `observer` (see [`announce`]).
pub(super) fn evaluate_into(
    log: &mut crate::train::log::TrainLog,
    step: usize,
    field: &dyn TrainedField,
    values: &[f32],
    views: &[TrainView],
    (name, observer): (&str, &Observer),
) -> io::Result<()> {
    let t = std::time::Instant::now();
    // The first view's render is logged.
    let e = evaluate(
        field,
        values,
        views,
        1,
        &announce(name, step, views, observer),
    )?;
    let took = t.elapsed().as_secs_f64();
    let first = crate::train::log::first_view(views, &e.renders);
    log.evaluated(step, e.scores(views.len()), took, first);
    Ok(())
}

/// Held-out pixels from which an evaluation is announced with a line of
/// its own: scoring a megapixel takes seconds, 200 views of 800² minutes;
/// smaller ones would only add lines.
pub const ANNOUNCED_PIXELS: usize = 1 << 20;

/// What a held-out evaluation tells whoever watches the run (`observer`):
/// a line when it starts, for views of [`ANNOUNCED_PIXELS`] or more (shown
/// piped too), then each view done on the status line. Returns the
/// per-view callback for [`evaluate`].
pub fn announce<'a>(
    name: &'a str,
    step: usize,
    views: &[TrainView],
    observer: &'a Observer,
) -> impl Fn(usize) + 'a {
    let n = views.len();
    let pixels: usize = views.iter().map(|v| v.image.len()).sum();
    if let Some(v) = views.first().filter(|_| pixels >= ANNOUNCED_PIXELS) {
        observer(&TrainEvent::Note(&format!(
            "{name}: scoring {n} held-out view{} of {}x{} at step {step}",
            if n == 1 { "" } else { "s" },
            v.image.width,
            v.image.height
        )));
    }
    move |done| {
        observer(&TrainEvent::Status(&format!(
            "{name}: scored held-out view {done} of {n} at step {step}"
        )))
    }
}

/// The held-out `views` rendered by `field` at `values` and scored, the
/// renders of the first `keep` kept; `scored(k)` after the `k`-th view.
pub(super) fn evaluate(
    field: &dyn TrainedField,
    values: &[f32],
    views: &[TrainView],
    keep: usize,
    scored: &dyn Fn(usize),
) -> io::Result<Evaluation> {
    let (mut psnr, mut ssim, mut renders) = (0.0, 0.0, Vec::new());
    // PSNR inside the object masks: its sum and the views with pixels
    // inside (a view whose mask is empty has no such PSNR).
    let mut in_mask = Some((0.0, 0usize));
    for (k, v) in views.iter().enumerate() {
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
        in_mask = match (in_mask, &v.coverage) {
            (Some(acc), Some(c)) => {
                Some(match psnr_inside(&colour, &target, c, v.mask.as_deref()) {
                    Some(p) => (acc.0 + p, acc.1 + 1),
                    None => acc,
                })
            }
            _ => None,
        };
        if k < keep {
            renders.push(colour);
        }
        scored(k + 1);
    }
    let n = views.len().max(1) as f64;
    Ok(Evaluation {
        psnr: psnr / n,
        ssim: ssim / n,
        psnr_in_mask: in_mask
            .filter(|&(_, counted)| counted > 0)
            .map(|(sum, counted)| sum / counted as f64),
        renders,
    })
}

/// PSNR over the pixels a view's object mask covers at least half
/// (`coverage` in 255ths) and its `mask` keeps; `None` where none are.
pub fn psnr_inside(
    colour: &[[f32; 3]],
    target: &[[f32; 3]],
    coverage: &[u8],
    mask: Option<&[bool]>,
) -> Option<f64> {
    let inside = |img: &[[f32; 3]]| -> Vec<[f32; 3]> {
        img.iter()
            .zip(coverage)
            .enumerate()
            .filter(|(i, (_, &c))| c >= 128 && mask.is_none_or(|m| m[*i]))
            .map(|(_, (p, _))| *p)
            .collect()
    };
    let (ours, truth) = (inside(colour), inside(target));
    (!ours.is_empty()).then(|| metrics::psnr(&ours, &truth))
}
