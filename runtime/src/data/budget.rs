//! What a data set read from files costs its statement: the bytes its
//! views hold and their decoding's peak, counted once the views are read
//! and estimated by `sdfl plan` from image headers, with the same numbers.

use std::io;

use super::format::PlannedView;
use super::formats;
use super::image::{held_bytes_per_pixel, image_dimensions};
use super::view::{downscale_size_of, DataNeeds, TrainView};
use super::view_image;

/// Bytes a view of `pixels` holds once read: its colours (`colour`
/// bytes a pixel: 4 for 8-bit files, 12 for others, see
/// [`view_image`]) and a byte a pixel of coverage and of mask where it
/// keeps them. The one count of the budget checked once data are read and
/// of `sdfl plan`'s estimate from image headers.
pub fn view_bytes(pixels: f64, colour: f64, coverage: bool, mask: bool) -> f64 {
    pixels * (colour + f64::from(u8::from(coverage)) + f64::from(u8::from(mask)))
}

/// [`view_bytes`] of views read.
pub fn views_bytes<'a>(views: impl IntoIterator<Item = &'a TrainView>) -> f64 {
    views
        .into_iter()
        .map(|v| {
            let pixels = v.image.width as f64 * v.image.height as f64;
            view_bytes(
                pixels,
                v.image.bytes_per_pixel(),
                v.coverage.is_some(),
                v.mask.is_some(),
            )
        })
        .sum()
}

/// Bytes beyond the views already read while one image of `pixels` from a
/// file of `file_bytes` is decoded (images are read one at a time): the
/// file's bytes, the decoder's pixels (up to 8 a pixel, 16-bit RGBA), its
/// f32 RGBA copy and the list made of it (16 each), about 3× the f32 RGB
/// the view keeps.
pub fn decode_bytes(pixels: f64, file_bytes: f64) -> f64 {
    file_bytes + 40.0 * pixels
}

/// What a data set read from files adds to its statement's budget: the
/// held-out views' scoring and the views' bytes. Checked once the data are
/// read ([`view_bytes`] of what was read), estimated by `sdfl plan` (from
/// image headers), with the same numbers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OnceRead {
    /// The statement's expected evaluations (empty space skipped) with
    /// the held-out views' scoring.
    pub evaluations: f64,
    /// Of those, the held-out views' scoring.
    pub held_out_evaluations: f64,
    /// The statement's peak memory with the views held.
    pub memory: f64,
}

impl OnceRead {
    /// The budget of `job` (at `size` when `--size` overrides its
    /// images) with `test_views` held-out views, the largest of
    /// `largest_test` pixels, and views holding `held` bytes.
    pub fn of(
        job: &sdfl_stdlib::value::TrainJob,
        size: Option<(u32, u32)>,
        test_views: usize,
        largest_test: f64,
        held: f64,
    ) -> OnceRead {
        use sdfl_stdlib::work::{held_out_cost, train_work};
        let held_out = held_out_cost(job, test_views, largest_test);
        let work = train_work(job, size);
        OnceRead {
            evaluations: work.expected + held_out.expected,
            held_out_evaluations: held_out.expected,
            memory: work.memory + held + held_out.memory,
        }
    }
}

/// Most image headers `sdfl plan` reads of one data set: a sample spread
/// over a larger one, the rest taken as their mean, so that a set of
/// 10 000 images plans in milliseconds.
pub const MAX_HEADERS: usize = 64;

/// A data set read from files, estimated from its image headers before it
/// is read (`sdfl plan`).
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// Views read, held-out ones included.
    pub views: usize,
    /// Of those, held out.
    pub test_views: usize,
    /// The data set's held-out views, those `eval_views` leaves unread
    /// included.
    pub test_views_in_data: usize,
    /// Headers read (all views' up to [`MAX_HEADERS`]).
    pub headers: usize,
    /// The image size as held (box-filtered where the data set
    /// downscales), where every header read gives the same.
    pub size: Option<(u32, u32)>,
    /// Every view's pixels as held (a view not read as the mean of those
    /// read).
    pub pixels: f64,
    /// Bytes the views hold through training ([`view_bytes`]).
    pub held: f64,
    /// Most bytes while they are read: every view held, and a pool's width
    /// of the largest image being decoded ([`decode_bytes`]).
    pub reading: f64,
    /// The statement's budget with these views.
    pub budget: OnceRead,
}

/// The views `job`'s data set reads from files (paths relative to
/// `base`), without reading an image; `None` where its data are not
/// images read from files.
fn planned(
    job: &sdfl_stdlib::value::TrainJob,
    base: &std::path::Path,
) -> io::Result<Option<Vec<PlannedView>>> {
    if let sdfl_stdlib::value::Dataset::Files { images, .. } = &*job.data {
        return Ok(Some(
            images
                .iter()
                .map(|p| PlannedView {
                    image: base.join(p),
                    mask: false,
                    held_out: false,
                    downscale: 1,
                })
                .collect(),
        ));
    }
    formats::plan(&job.data, base)
}

/// Estimates `job`'s data set read from files (paths relative to `base`)
/// from the headers of its images, at most [`MAX_HEADERS`] of them spread
/// over the set; `None` where its data are not images read from files.
/// Views box-filtered once decoded (`nerf_synthetic(downscale:)`) count
/// their small size, held as f32 RGB, and decode at their whole size.
/// Errors are those reading its files (a missing image, a bad header, a
/// `downscale` that does not divide the images).
pub fn estimate(
    job: &sdfl_stdlib::value::TrainJob,
    base: &std::path::Path,
) -> io::Result<Option<Estimate>> {
    let Some(mut views) = planned(job, base)? else {
        return Ok(None);
    };
    // Held-out views no evaluation scores are never read.
    let test_views_in_data = views.iter().filter(|v| v.held_out).count();
    let keep = DataNeeds::of(job).keeps_held_out(test_views_in_data);
    let mut k = 0;
    views.retain(|v| {
        !v.held_out || {
            k += 1;
            keep[k - 1]
        }
    });
    let n = views.len();
    let sample: Vec<usize> = if n <= MAX_HEADERS {
        (0..n).collect()
    } else {
        (0..MAX_HEADERS).map(|i| i * n / MAX_HEADERS).collect()
    };
    let mut pixels: Vec<Option<f64>> = vec![None; n];
    let (mut size, mut same) = (None, true);
    let mut largest = (0.0, 0.0);
    // The widest colour of the sample stands for every view's.
    let mut colour = view_image::RGBA8_BYTES;
    for &k in &sample {
        let (image, downscale) = (&views[k].image, views[k].downscale);
        let (w, h) = image_dimensions(image)?;
        colour = colour.max(held_bytes_per_pixel(image, downscale)?);
        // Decoded whole, held box-filtered.
        let decoded = w as f64 * h as f64;
        let file = std::fs::metadata(image).map_or(0.0, |m| m.len() as f64);
        if decode_bytes(decoded, file) > decode_bytes(largest.0, largest.1) {
            largest = (decoded, file);
        }
        let (w, h) = downscale_size_of(image, (w, h), downscale)?;
        same &= size.is_none_or(|s| s == (w, h));
        size = Some((w, h));
        pixels[k] = Some(w as f64 * h as f64);
    }
    let mean = sample.iter().filter_map(|&k| pixels[k]).sum::<f64>() / sample.len().max(1) as f64;
    let coverage = DataNeeds::of(job).coverage;
    let (mut all, mut held, mut test, mut largest_test) = (0.0, 0.0, 0, 0.0f64);
    for (v, px) in views.iter().zip(&pixels) {
        let px = px.unwrap_or(mean);
        all += px;
        // Held-out views are only scored: no coverage is kept for them.
        held += view_bytes(px, colour, coverage && !v.held_out, v.mask);
        if v.held_out {
            test += 1;
            largest_test = largest_test.max(px);
        }
    }
    Ok(Some(Estimate {
        views: n,
        test_views: test,
        test_views_in_data,
        headers: sample.len(),
        size: size.filter(|_| same),
        pixels: all,
        held,
        // Images decode a pool's width at a time.
        reading: held + rayon::current_num_threads() as f64 * decode_bytes(largest.0, largest.1),
        budget: OnceRead::of(job, None, test, largest_test, held),
    }))
}
