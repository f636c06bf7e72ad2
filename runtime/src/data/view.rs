//! Training views as every data set gives them (a camera, its image, mask
//! and coverage), what a job reads of them, and the checks and warnings
//! about views once read, whatever made them.

use std::io;
use std::sync::Arc;

use super::view_image::ViewImage;

/// One training view: a camera and the image it sees.
#[derive(Debug, Clone)]
pub struct TrainView {
    /// The camera the image was taken with, in the scene frame.
    pub camera: sdfl_stdlib::camera::Camera,
    /// The image the camera sees: the training target.
    pub image: ViewImage,
    /// Pixels to train on and score (row-major, `false`: masked out, as a
    /// capture's `mask_path` says); `None`: every pixel.
    pub mask: Option<Arc<[bool]>>,
    /// How much of each pixel the object covers, in 255ths (row-major; the
    /// target of [`sdfl_stdlib::value::LossKind::Silhouette`]); `None`:
    /// not known, or not asked for. A byte a pixel, as it comes (8-bit
    /// alpha, the tracer's hit or miss), beside the image's twelve: a
    /// batch converts only its rays' to f32.
    pub coverage: Option<Arc<[u8]>>,
}

/// Each pixel's coverage from its alpha (clamped to 0..1), in 255ths: 8-bit
/// alpha exactly, 16-bit to the nearest 255th.
pub fn coverage_from_alpha(rgba: &[[f32; 4]]) -> Arc<[u8]> {
    rgba.iter()
        .map(|p| (p[3].clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect()
}

/// The size of a `w × h` image box-filtered to 1/`n` a side (1: as it
/// is), or why `n` cannot: it must divide both sides (the message names
/// the factors up to 16 that do).
pub fn downscaled_size(w: u32, h: u32, n: u32) -> Result<(u32, u32), String> {
    if n <= 1 {
        return Ok((w, h));
    }
    if !w.is_multiple_of(n) || !h.is_multiple_of(n) {
        let divisors: Vec<String> = (2..=16)
            .filter(|&d| w.is_multiple_of(d) && h.is_multiple_of(d))
            .map(|d| d.to_string())
            .collect();
        return Err(format!(
            "{n} does not divide its {w}x{h} images{}",
            if divisors.is_empty() {
                " (no factor up to 16 does)".to_string()
            } else {
                format!(" (factors that do: {})", divisors.join(", "))
            }
        ));
    }
    Ok((w / n, h / n))
}

/// The size of `path`'s `w × h` images read at 1/`downscale` a side, or
/// the coded error (`sdfl::data::downscale`) of a factor that does not
/// divide it, naming the factors that do ([`downscaled_size`]).
pub fn downscale_size_of(
    path: &std::path::Path,
    (w, h): (u32, u32),
    downscale: u32,
) -> io::Result<(u32, u32)> {
    downscaled_size(w, h, downscale).map_err(|why| {
        super::error::Coded {
            code: super::error::DOWNSCALE,
            message: format!("{}: `downscale`: {why}", path.display()),
            help:
                "give a factor that divides the images' width and height, or leave `downscale` out",
        }
        .into_io()
    })
}

impl TrainView {
    /// The view at 1/`n` of its size a side (`n` dividing both,
    /// [`downscaled_size`]): each block of `n`×`n` pixels becomes its
    /// mean over the block's unmasked pixels (masked out only where all of
    /// them are), its coverage the block's mean. Colours are averaged as
    /// the view holds them, composited over the background: the mean of
    /// `rgb·a + bg·(1 − a)` is the block's premultiplied mean over the
    /// same background, so averaging RGBA with premultiplied alpha and
    /// compositing after gives the same colour. The camera is the same:
    /// its rays are functions of the fractional pixel position over the
    /// image size, so a pixel of the small image sees the ray through its
    /// block's centre (half-pixel centres and pixel intrinsics; the
    /// conventions' corner centres do not, but no data set has them).
    pub fn downscaled(&self, n: u32) -> Result<TrainView, String> {
        let (w, h) = (self.image.width, self.image.height);
        if n <= 1 {
            return Ok(self.clone());
        }
        let (sw, sh) = downscaled_size(w, h, n)?;
        let (sw, sh, n) = (sw as usize, sh as usize, n as usize);
        let (w, nn) = (w as usize, (n * n) as f32);
        let kept = |i: usize| self.mask.as_ref().is_none_or(|m| m[i]);
        let mut colour = Vec::with_capacity(sw * sh);
        let mut mask = Vec::with_capacity(sw * sh);
        let mut coverage = Vec::with_capacity(sw * sh);
        for by in 0..sh {
            for bx in 0..sw {
                let (mut sum, mut count, mut covered) = ([0f32; 3], 0u32, 0u32);
                for y in by * n..(by + 1) * n {
                    for x in bx * n..(bx + 1) * n {
                        let i = y * w + x;
                        if let Some(c) = &self.coverage {
                            covered += c[i] as u32;
                        }
                        if kept(i) {
                            let p = self.image.pixel(i);
                            (0..3).for_each(|k| sum[k] += p[k]);
                            count += 1;
                        }
                    }
                }
                let mean = sum.map(|v| if count > 0 { v / count as f32 } else { 0.0 });
                colour.push(mean);
                mask.push(count > 0);
                coverage.push((covered as f32 / nn).round() as u8);
            }
        }
        Ok(TrainView {
            camera: self.camera,
            image: ViewImage::rgb32(sw as u32, sh as u32, colour),
            mask: self.mask.as_ref().map(|_| mask.into()),
            coverage: self.coverage.as_ref().map(|_| coverage.into()),
        })
    }
}

/// What a job reads of its data beyond each view's camera and colours.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DataNeeds {
    /// Each training view's coverage by the object (`silhouette()`), from
    /// its object mask (IDR's `mask/`) or else its image's alpha, which the
    /// images must then have. Read only when asked: a 100-view 800² set
    /// holds 64 MB more with it. (A shape's
    /// traced views always carry theirs: the hit mask comes with the
    /// trace.)
    pub coverage: bool,
    /// Held-out views to read (`eval_views`), evenly spaced over the data
    /// set's ([`DataNeeds::keeps_held_out`]); `None`: all of them. The
    /// others are never decoded: 200 test views of 800² are 512 MB.
    pub held_out: Option<usize>,
}

impl DataNeeds {
    /// What `job`'s loss terms and evaluations read of its data.
    pub fn of(job: &sdfl_stdlib::value::TrainJob) -> Self {
        DataNeeds {
            coverage: job
                .losses
                .iter()
                .any(|l| l.kind == sdfl_stdlib::value::LossKind::Silhouette),
            held_out: job.eval_views,
        }
    }

    /// Which of `held_out` held-out views are read: for each, whether it
    /// is (by position among the held-out views).
    pub fn keeps_held_out(&self, held_out: usize) -> Vec<bool> {
        let n = self.held_out.map_or(held_out, |n| n.min(held_out));
        let mut keep = vec![false; held_out];
        for i in 0..n {
            keep[i * held_out / n] = true;
        }
        keep
    }
}

/// Checks that every pixel of `views` (each with where it came from, for
/// the message) is a finite colour; the first that is not is named.
pub fn check_finite<'a>(
    views: impl IntoIterator<Item = (&'a TrainView, &'a str)>,
) -> io::Result<()> {
    for (v, origin) in views {
        if let Some(i) = v
            .image
            .colours()
            .position(|p| !p.iter().all(|x| x.is_finite()))
        {
            let w = v.image.width.max(1) as usize;
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "{origin}: pixel (column {}, row {}) is {:?}, not a finite colour",
                    i % w,
                    i / w,
                    v.image.pixel(i)
                ),
            ));
        }
    }
    Ok(())
}

/// A warning when the views' coverage, read from alpha, is everywhere
/// whole: such alpha says nothing of the object's outline, and
/// `silhouette()` then pulls every ray opaque, the background too.
pub fn opaque_alpha_warning(views: &[TrainView]) -> Option<String> {
    let read: Vec<&[u8]> = views.iter().filter_map(|v| v.coverage.as_deref()).collect();
    (!read.is_empty() && read.iter().all(|c| c.iter().all(|&a| a == 255))).then(|| {
        "warning: every pixel of the training images is opaque (alpha 1): `silhouette()` then takes the object to cover every pixel and makes every ray opaque; give images whose alpha is the object's coverage, or leave `silhouette()` out".to_string()
    })
}
