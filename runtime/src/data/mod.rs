//! Readers for input data sets.

pub mod capture;
pub mod colmap;
pub mod export;
pub mod idr;
pub mod image;
pub mod llff;
pub mod nerf_synthetic;
pub mod nerfstudio;
pub mod normalize;
pub mod npy;
pub mod points;
pub mod view_image;

use std::io;

use sdfl_lang::Span;

/// An error reading an input that an argument of the program names (a
/// data set's path): the argument's span travels with it, so that the
/// diagnostic points at the argument rather than the statement.
#[derive(Debug)]
pub struct AtArgument {
    /// The argument that named the input.
    pub span: Span,
    /// What went wrong reading it.
    pub error: io::Error,
}

impl std::fmt::Display for AtArgument {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.error.fmt(f)
    }
}

impl std::error::Error for AtArgument {}

/// `e`, pointing at `span` unless it already points at an argument.
pub fn at_argument(span: Span, e: io::Error) -> io::Error {
    if e.get_ref().is_some_and(|r| r.is::<AtArgument>()) {
        return e;
    }
    io::Error::new(e.kind(), AtArgument { span, error: e })
}

/// The argument an error points at, if any.
pub fn argument_span(e: &io::Error) -> Option<Span> {
    e.get_ref()
        .and_then(|r| r.downcast_ref::<AtArgument>())
        .map(|a| a.span)
}

/// Farthest a data file may put a camera from its origin, on any axis and
/// in its own units: as far as a number a program may write, so that the
/// scene frame, and exports mapped back into the data's frame, stay finite.
pub const MAX_POSITION: f64 = sdfl_stdlib::precision::F32_SAFE.1;

/// Checks a position read from a data file (`what`: "camera position",
/// "translation") against [`MAX_POSITION`]: one check for every reader
/// (nerfstudio and NeRF-synthetic, COLMAP, LLFF).
pub fn check_position(what: &str, p: glam::DVec3) -> Result<(), String> {
    if p.is_finite() && p.abs().max_element() <= MAX_POSITION {
        return Ok(());
    }
    Err(format!(
        "the {what} [{}, {}, {}] is out of range (at most {} from the origin on each axis)",
        sdfl_lang::fmt_num(p.x),
        sdfl_lang::fmt_num(p.y),
        sdfl_lang::fmt_num(p.z),
        sdfl_lang::fmt_num(MAX_POSITION)
    ))
}

/// Checks that `r` is a rotation (orthonormal within 1e-3, not mirrored):
/// a scaled, sheared or mirrored pose is no camera, and a huge entry would
/// overflow once normalised.
pub fn check_rotation(r: glam::DMat3) -> Result<(), String> {
    let e = r.transpose() * r - glam::DMat3::IDENTITY;
    if e.to_cols_array().iter().all(|x| x.abs() <= 1e-3) && r.determinant() > 0.0 {
        return Ok(());
    }
    Err("the rotation is not orthonormal (a scaled, sheared or mirrored pose)".into())
}

/// Checks a rigid map given as rows (the first three rows of a 4 × 4 or a
/// 3 × 4 matrix): its rotation, and its translation (`what`) in range.
pub fn check_rigid(what: &str, rows: &[[f64; 4]; 3]) -> Result<(), String> {
    let col = |c: usize| glam::DVec3::new(rows[0][c], rows[1][c], rows[2][c]);
    check_rotation(glam::DMat3::from_cols(col(0), col(1), col(2)))?;
    check_position(what, col(3))
}

/// One training view: a camera and the image it sees.
#[derive(Debug, Clone)]
pub struct TrainView {
    /// The camera the image was taken with, in the scene frame.
    pub camera: sdfl_stdlib::camera::Camera,
    /// The image the camera sees: the training target.
    pub image: view_image::ViewImage,
    /// Pixels to train on and score (row-major, `false`: masked out, as a
    /// capture's `mask_path` says); `None`: every pixel.
    pub mask: Option<std::sync::Arc<[bool]>>,
    /// How much of each pixel the object covers, in 255ths (row-major; the
    /// target of [`sdfl_stdlib::value::LossKind::Silhouette`]); `None`:
    /// not known, or not asked for. A byte a pixel, as it comes (8-bit
    /// alpha, the tracer's hit or miss), beside the image's twelve: a
    /// batch converts only its rays' to f32.
    pub coverage: Option<std::sync::Arc<[u8]>>,
}

/// Each pixel's coverage from its alpha (clamped to 0..1), in 255ths: 8-bit
/// alpha exactly, 16-bit to the nearest 255th.
pub fn coverage_from_alpha(rgba: &[[f32; 4]]) -> std::sync::Arc<[u8]> {
    rgba.iter()
        .map(|p| (p[3].clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect()
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

/// The stable code of images that cannot give `silhouette()` each pixel's
/// coverage: they have no alpha channel.
pub const NO_COVERAGE: &str = "sdfl::data::no-coverage";

/// A data error with its own stable code and help, carried in an
/// `io::Error` so that the CLI reports it under that code rather than as
/// an unreadable file.
#[derive(Debug)]
pub struct Coded {
    /// The diagnostic code.
    pub code: &'static str,
    /// What is wrong, naming the file.
    pub message: String,
    /// What to do about it.
    pub help: &'static str,
}

impl std::fmt::Display for Coded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Coded {}

impl Coded {
    /// `self` as an `io::Error` (invalid data).
    pub fn into_io(self) -> io::Error {
        io::Error::new(io::ErrorKind::InvalidData, self)
    }
}

/// The coded data error `e` carries, if any (also under the argument that
/// named the data).
pub fn coded(e: &io::Error) -> Option<&Coded> {
    let inner = e.get_ref()?;
    match inner.downcast_ref::<AtArgument>() {
        Some(a) => coded(&a.error),
        None => inner.downcast_ref::<Coded>(),
    }
}

/// The error of an image without alpha read for `silhouette()`.
pub fn no_coverage(path: &std::path::Path) -> io::Error {
    Coded {
        code: NO_COVERAGE,
        message: format!(
            "{}: the image has no alpha channel, and `silhouette()` takes each pixel's coverage by the object from it",
            path.display()
        ),
        help: "give RGBA PNGs whose alpha is the object's coverage (as Blender's NeRF-synthetic sets and sdfl's `dataset(...)` are), or leave `silhouette()` out",
    }
    .into_io()
}

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
    /// The image size, where every header read gives the same.
    pub size: Option<(u32, u32)>,
    /// Every view's pixels (a view not read as the mean of those read).
    pub pixels: f64,
    /// Bytes the views hold through training ([`view_bytes`]).
    pub held: f64,
    /// Most bytes while they are read: every view held, and a pool's width
    /// of the largest image being decoded ([`decode_bytes`]).
    pub reading: f64,
    /// The statement's budget with these views.
    pub budget: OnceRead,
}

/// One view a data set will read: its image, mask, and whether it is held
/// out.
struct Planned {
    image: std::path::PathBuf,
    mask: bool,
    held_out: bool,
}

/// The views `job`'s data set reads from files (paths relative to
/// `base`), without reading an image; `None` where its data are not
/// images read from files.
fn planned(
    job: &sdfl_stdlib::value::TrainJob,
    base: &std::path::Path,
) -> io::Result<Option<Vec<Planned>>> {
    use sdfl_stdlib::value::{CaptureFormat, Dataset};
    let view = |image: std::path::PathBuf, held_out: bool| Planned {
        image,
        mask: false,
        held_out,
    };
    Ok(Some(match &*job.data {
        Dataset::Rendered { .. } | Dataset::Traced { .. } | Dataset::Points { .. } => {
            return Ok(None)
        }
        Dataset::Files { images, .. } => images.iter().map(|p| view(base.join(p), false)).collect(),
        Dataset::NerfSynthetic {
            path,
            split,
            test_split,
            ..
        } => {
            use nerf_synthetic::{read_transforms, transforms_path};
            let dir = base.join(path);
            let train = transforms_path(&dir, split);
            let mut files = vec![(train.clone(), false)];
            if let Some(t) = test_split.as_deref() {
                let test = transforms_path(&dir, t);
                if test != train {
                    files.push((test, true));
                }
            }
            let mut views = Vec::new();
            for (file, held_out) in files {
                let t = read_transforms(&file)?;
                views.extend(t.frames.into_iter().map(|f| view(f.image, held_out)));
            }
            views
        }
        Dataset::Capture(spec) => {
            let path = base.join(&spec.path);
            let folder = match spec.downscale {
                0 | 1 => "images".to_string(),
                d => format!("images_{d}"),
            };
            let (images, test): (Vec<std::path::PathBuf>, Vec<usize>) =
                match capture::format_of(spec, &path)? {
                    CaptureFormat::Nerfstudio | CaptureFormat::Auto => {
                        let t = nerfstudio::read_transforms_scaled(
                            &capture::nerfstudio_file(&path),
                            spec.downscale,
                        )?;
                        return Ok(Some(
                            t.selection(spec.test_every)?
                                .into_iter()
                                .map(|(k, held_out)| Planned {
                                    image: t.frames[k].image.clone(),
                                    mask: t.frames[k].mask.is_some(),
                                    held_out,
                                })
                                .collect(),
                        ));
                    }
                    CaptureFormat::Colmap => {
                        let model = colmap::model_dir(&path).ok_or_else(|| {
                            capture::invalid(
                                &path,
                                "holds no COLMAP text model (sparse/0/cameras.txt and images.txt)",
                            )
                        })?;
                        let mut names: Vec<String> =
                            colmap::read_images(&model.join("images.txt"))?
                                .into_iter()
                                .map(|i| i.name)
                                .collect();
                        names.sort();
                        let dir = std::path::Path::new(&folder);
                        let images = names
                            .iter()
                            .map(|n| {
                                nerfstudio::inside(&path, &dir.join(n), n)
                                    .map_err(|e| capture::invalid(&path, e))
                            })
                            .collect::<io::Result<Vec<_>>>()?;
                        let test = capture::every_nth(images.len(), spec.test_every);
                        (images, test)
                    }
                    CaptureFormat::Llff => {
                        let images = image_files(&path.join(&folder))?;
                        let test = capture::every_nth(images.len(), spec.test_every);
                        (images, test)
                    }
                    // Object masks are read only as coverage, which
                    // `view_bytes` counts by itself.
                    CaptureFormat::Idr => {
                        let images = idr::images(&path, spec.downscale)?;
                        let test = capture::every_nth(images.len(), spec.test_every);
                        (images, test)
                    }
                };
            images
                .into_iter()
                .enumerate()
                .map(|(k, image)| view(image, test.binary_search(&k).is_ok()))
                .collect()
        }
    }))
}

/// The PNG and JPEG files of `folder`, sorted by name, as LLFF's reader
/// takes them; at most `MAX_VIEWS`.
fn image_files(folder: &std::path::Path) -> io::Result<Vec<std::path::PathBuf>> {
    let mut files = Vec::new();
    for e in std::fs::read_dir(folder).map_err(|e| capture::invalid(folder, e))? {
        let p = e.map_err(|e| capture::invalid(folder, e))?.path();
        let ext = p
            .extension()
            .and_then(|x| x.to_str())
            .map(str::to_ascii_lowercase);
        if matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg")) {
            files.push(p);
        }
        if files.len() > sdfl_stdlib::builtins::MAX_VIEWS {
            return Err(capture::invalid(
                folder,
                format!("more than {} images", sdfl_stdlib::builtins::MAX_VIEWS),
            ));
        }
    }
    files.sort();
    Ok(files)
}

/// Estimates `job`'s data set read from files (paths relative to `base`)
/// from the headers of its images, at most [`MAX_HEADERS`] of them spread
/// over the set; `None` where its data are not images read from files.
/// Errors are those reading its files (a missing image, a bad header).
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
        let image = &views[k].image;
        let (w, h) = image::image_dimensions(image)?;
        colour = colour.max(image::view_bytes_per_pixel(image)?);
        let px = w as f64 * h as f64;
        let file = std::fs::metadata(image).map_or(0.0, |m| m.len() as f64);
        if decode_bytes(px, file) > decode_bytes(largest.0, largest.1) {
            largest = (px, file);
        }
        same &= size.is_none_or(|s| s == (w, h));
        size = Some((w, h));
        pixels[k] = Some(px);
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
