//! Reading training images (PNG and other formats `image` decodes, or
//! `.npy`) with their sizes checked before anything is decoded: a small
//! compressed file may declare an enormous image. Only regular files are
//! read (a FIFO would block forever, `/dev/zero` never ends), whatever
//! links lead to them.

use std::fs::File;
use std::io::{self, BufReader};
use std::path::Path;

use super::npy::{read_rgb_f32, read_shape, RgbImage};

/// Largest image side accepted for data, as for rendered images.
pub const MAX_SIDE: u32 = sdfl_stdlib::builtins::MAX_IMAGE_SIDE;
/// Most decoded bytes of one data set as training holds it (8-bit files 4
/// bytes a pixel, others 12): 500 views of 1000×1000 8-bit PNGs, or
/// about 40 views of 2048×2048 f32.
pub const MAX_DATASET_BYTES: u64 = 2_000_000_000;

fn invalid(path: &Path, m: impl std::fmt::Display) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("{}: {m}", path.display()),
    )
}

/// Opens `path` for reading if, after following links, it is a regular
/// file (never blocking on a FIFO): [`sdfl_stdlib::files::open_regular`],
/// kept here for the readers that call it.
pub fn open_regular(path: &Path) -> io::Result<File> {
    sdfl_stdlib::files::open_regular(path)
}

fn is_npy(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("npy"))
}

/// Most bytes of metadata (ICC profile, text chunks) one image may inflate
/// to: real profiles are a few kilobytes to a megabyte.
pub const MAX_METADATA_BYTES: u64 = 16 << 20;

/// Limits for reading an image: every allocation of the decoder counts
/// (the 8- or 16-bit pixels of the declared `w`×`h` when decoding, and each
/// compressed ancillary chunk it inflates, which the header read also
/// parses), so a tiny file cannot inflate gigabytes of colour profile. The
/// f32 copy is counted by the caller. For the header alone (`None`) the
/// sizes are checked by the caller, with a message naming them.
fn limits(decode: Option<(u32, u32)>) -> image::Limits {
    let mut l = image::Limits::no_limits();
    let pixels = decode.map_or(0, |(w, h)| {
        l.max_image_width = Some(MAX_SIDE);
        l.max_image_height = Some(MAX_SIDE);
        w as u64 * h as u64 * 8
    });
    l.max_alloc = Some(pixels + MAX_METADATA_BYTES);
    l
}

/// A reader of `path` within [`limits`].
fn reader(
    path: &Path,
    decode: Option<(u32, u32)>,
) -> io::Result<image::ImageReader<BufReader<File>>> {
    let mut r = image::ImageReader::new(BufReader::new(open_regular(path)?))
        .with_guessed_format()
        .map_err(|e| invalid(path, e))?;
    r.limits(limits(decode));
    Ok(r)
}

/// The declared width and height of an image file, read from its header.
pub fn image_dimensions(path: &Path) -> io::Result<(u32, u32)> {
    let (w, h) = if is_npy(path) {
        match read_shape(path).map_err(|e| invalid(path, e))?[..] {
            [h, w, 3] if h > 0 && w > 0 => (
                u32::try_from(w).unwrap_or(u32::MAX),
                u32::try_from(h).unwrap_or(u32::MAX),
            ),
            ref s => return Err(invalid(path, format!("shape {s:?} (only (H, W, 3))"))),
        }
    } else {
        reader(path, None)?
            .into_dimensions()
            .map_err(|e| invalid(path, e))?
    };
    if w > MAX_SIDE || h > MAX_SIDE {
        return Err(invalid(
            path,
            format!("declares {w}x{h} pixels (at most {MAX_SIDE} a side)"),
        ));
    }
    Ok((w, h))
}

/// Checks a data set's declared sizes before any image is decoded: each
/// within the side limit, all together within [`MAX_DATASET_BYTES`].
pub fn check_dataset<P: AsRef<Path>>(paths: impl IntoIterator<Item = P>) -> io::Result<()> {
    check_dataset_downscaled(paths.into_iter().map(|p| (p, 1)))
}

/// [`check_dataset`] of images each held at 1/`downscale` of its size a
/// side (box-filtered once decoded: [`held_bytes_per_pixel`]); every
/// image is still decoded whole, so each side stays within the limit.
pub fn check_dataset_downscaled<P: AsRef<Path>>(
    images: impl IntoIterator<Item = (P, u32)>,
) -> io::Result<()> {
    let mut total = 0u64;
    for (p, downscale) in images {
        let (w, h) = image_dimensions(p.as_ref())?;
        let colour = held_bytes_per_pixel(p.as_ref(), downscale)? as u64;
        let d = downscale.max(1) as u64;
        let pixels = (w as u64 / d) * (h as u64 / d);
        total = total.saturating_add(pixels.saturating_mul(colour));
        if total > MAX_DATASET_BYTES {
            return Err(invalid(
                p.as_ref(),
                format!(
                    "the data set up to this image decodes to {total} bytes (at most {MAX_DATASET_BYTES}); use fewer or smaller images"
                ),
            ));
        }
    }
    Ok(())
}

/// Reads an RGB image as f32 (`.npy`: `(H, W, 3)` float32; otherwise any
/// format `image` decodes, scaled to 0..1), its size checked first.
pub fn read_rgb_image(path: &Path) -> io::Result<RgbImage> {
    let size = image_dimensions(path)?;
    if is_npy(path) {
        return read_rgb_f32(path).map_err(|e| invalid(path, e));
    }
    let img = reader(path, Some(size))?
        .decode()
        .map_err(|e| invalid(path, e))?
        .to_rgb32f();
    Ok(RgbImage {
        width: img.width(),
        height: img.height(),
        pixels: img.pixels().map(|p| p.0).collect(),
    })
}

/// An image read as f32 RGBA.
#[derive(Debug, Clone)]
pub struct RgbaImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major RGBA in 0..1 (alpha 1 where the file has none).
    pub pixels: Vec<[f32; 4]>,
    /// Whether the file has an alpha channel: without one, alpha says
    /// nothing of what covers a pixel.
    pub has_alpha: bool,
}

/// Decodes an image file that may have alpha (not `.npy`), its size
/// checked first.
fn decode_with_alpha(path: &Path) -> io::Result<image::DynamicImage> {
    let size = image_dimensions(path)?;
    if is_npy(path) {
        return Err(invalid(
            path,
            "expected an image with alpha (PNG), not .npy",
        ));
    }
    reader(path, Some(size))?
        .decode()
        .map_err(|e| invalid(path, e))
}

/// Reads an image with its alpha channel as f32 RGBA in 0..1 (opaque where
/// the file has no alpha), its size checked first. Not `.npy`.
pub fn read_rgba_image(path: &Path) -> io::Result<RgbaImage> {
    let img = decode_with_alpha(path)?;
    let has_alpha = img.color().has_alpha();
    let img = img.to_rgba32f();
    Ok(RgbaImage {
        width: img.width(),
        height: img.height(),
        pixels: img.pixels().map(|p| p.0).collect(),
        has_alpha,
    })
}

/// An image decoded for training: 8-bit RGBA as the file has it, or f32
/// RGBA where it has more bits.
#[derive(Debug, Clone)]
pub struct DecodedView {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Whether the file has an alpha channel.
    pub has_alpha: bool,
    pixels: Decoded,
}

#[derive(Debug, Clone)]
enum Decoded {
    Rgba8(Vec<[u8; 4]>),
    Rgba32(Vec<[f32; 4]>),
}

impl DecodedView {
    /// Each pixel's coverage from its alpha, in 255ths (see
    /// [`super::view::coverage_from_alpha`]).
    pub fn coverage(&self) -> std::sync::Arc<[u8]> {
        match &self.pixels {
            Decoded::Rgba8(p) => p.iter().map(|p| p[3]).collect(),
            Decoded::Rgba32(p) => super::view::coverage_from_alpha(p),
        }
    }

    /// The view with `coverage` (255ths, a pixel each) as its alpha in
    /// place of its own: an object mask to composite it by.
    pub fn with_alpha(mut self, coverage: &[u8]) -> Self {
        match &mut self.pixels {
            Decoded::Rgba8(p) => p.iter_mut().zip(coverage).for_each(|(p, &c)| p[3] = c),
            Decoded::Rgba32(p) => p
                .iter_mut()
                .zip(coverage)
                .for_each(|(p, &c)| p[3] = c as f32 / 255.0),
        }
        self.has_alpha = true;
        self
    }

    /// The view's colours over `background`: kept 8-bit where they were.
    pub fn over(self, background: [f32; 3]) -> super::view_image::ViewImage {
        use super::view_image::ViewImage;
        match self.pixels {
            Decoded::Rgba8(p) => ViewImage::rgba8(self.width, self.height, p, background),
            Decoded::Rgba32(p) => {
                ViewImage::rgb32(self.width, self.height, composite_over(&p, background))
            }
        }
    }
}

/// Reads a training image (not `.npy`), its size checked first: 8-bit
/// files stay 8-bit, others become f32; opaque where it has no alpha.
pub fn read_view_image(path: &Path) -> io::Result<DecodedView> {
    let img = decode_with_alpha(path)?;
    let has_alpha = img.color().has_alpha();
    let eight = img.color().bytes_per_pixel() == img.color().channel_count();
    let (width, height) = (img.width(), img.height());
    let pixels = if eight {
        Decoded::Rgba8(img.to_rgba8().pixels().map(|p| p.0).collect())
    } else {
        Decoded::Rgba32(img.to_rgba32f().pixels().map(|p| p.0).collect())
    };
    Ok(DecodedView {
        width,
        height,
        has_alpha,
        pixels,
    })
}

/// Decoded pixels that [`read_view_images`] decodes in parallel at most:
/// beyond it images are decoded one at a time, so that two very large
/// images do not double the peak (a decoder holds its output twice while
/// converting).
pub const PARALLEL_DECODE_BYTES: u64 = 256 << 20;

/// Training images decoded a pool's width at a time, in parallel: most of
/// a large set's load is decoding. A batch holds at most
/// [`PARALLEL_DECODE_BYTES`] of decoded pixels (by the headers), or one
/// image. Returns each path's image, in order; `each` sees every decoded
/// one in order before the next batch is decoded (so that no more than a
/// batch is held beside what `each` keeps), and stops the read with its
/// error.
pub fn read_view_images<'a, P: AsRef<Path> + Sync + 'a>(
    paths: &'a [P],
    mut each: impl FnMut(usize, DecodedView) -> io::Result<()>,
) -> io::Result<()> {
    use rayon::prelude::*;
    let width = rayon::current_num_threads().max(1);
    let mut start = 0;
    while start < paths.len() {
        let ahead = &paths[start..paths.len().min(start + width)];
        let sizes = ahead
            .iter()
            .map(|p| image_dimensions(p.as_ref()))
            .collect::<io::Result<Vec<_>>>()?;
        let end = start + batch_len(&sizes);
        let decoded: Vec<io::Result<DecodedView>> = paths[start..end]
            .par_iter()
            .map(|p| read_view_image(p.as_ref()))
            .collect();
        for (i, d) in decoded.into_iter().enumerate() {
            each(start + i, d?)?;
        }
        start = end;
    }
    Ok(())
}

/// How many of the next images (their sizes) one parallel batch decodes:
/// as many as fit [`PARALLEL_DECODE_BYTES`] at 4 bytes a pixel (8-bit
/// RGBA, the least a decoder holds), and at least one.
#[doc(hidden)]
pub fn batch_len(sizes: &[(u32, u32)]) -> usize {
    let mut bytes = 0u64;
    let fitting = sizes
        .iter()
        .take_while(|&&(w, h)| {
            bytes = bytes.saturating_add(w as u64 * h as u64 * 4);
            bytes <= PARALLEL_DECODE_BYTES
        })
        .count();
    fitting.max(1).min(sizes.len())
}

/// Bytes a pixel of the image at `path` takes once read for training
/// (4: 8-bit files, kept as RGBA; 12: others, as f32 RGB), from its header.
pub fn view_bytes_per_pixel(path: &Path) -> io::Result<f64> {
    use image::ImageDecoder;
    if is_npy(path) {
        return Ok(super::view_image::RGB32_BYTES);
    }
    let decoder = reader(path, None)?
        .into_decoder()
        .map_err(|e| invalid(path, e))?;
    let c = decoder.color_type();
    Ok(if c.bytes_per_pixel() == c.channel_count() {
        super::view_image::RGBA8_BYTES
    } else {
        super::view_image::RGB32_BYTES
    })
}

/// Bytes a pixel of the image at `path` takes once read for training at
/// 1/`downscale` of its size a side: [`view_bytes_per_pixel`] as decoded;
/// 12 (f32 RGB, the blocks' means) when box-filtered.
pub fn held_bytes_per_pixel(path: &Path, downscale: u32) -> io::Result<f64> {
    if downscale > 1 {
        Ok(super::view_image::RGB32_BYTES)
    } else {
        view_bytes_per_pixel(path)
    }
}

/// RGBA pixels composited over `background` (alpha clamped to [0, 1]).
pub fn composite_over(rgba: &[[f32; 4]], background: [f32; 3]) -> Vec<[f32; 3]> {
    rgba.iter()
        .map(|p| {
            let a = p[3].clamp(0.0, 1.0);
            [0, 1, 2].map(|c| p[c] * a + background[c] * (1.0 - a))
        })
        .collect()
}

/// Reads a checkpoint file whole, refusing symbolic links on its path and files over 1 GiB.
pub fn read_checkpoint_bytes(path: &Path) -> io::Result<Vec<u8>> {
    use std::io::Read;
    const MAX: u64 = 1 << 30;
    let mut bytes = Vec::new();
    open_checkpoint(path)?
        .take(MAX + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| invalid(path, e))?;
    if bytes.len() as u64 > MAX {
        return Err(invalid(path, "checkpoint larger than 1 GiB"));
    }
    Ok(bytes)
}

/// Opens a checkpoint file to read, refusing symbolic links on its path.
pub fn open_checkpoint(path: &Path) -> io::Result<File> {
    // Checkpoints live in the output directory, which is never read or
    // written through a link (see `output`).
    let mut at = std::path::PathBuf::new();
    for c in path.components() {
        at.push(c);
        if std::fs::symlink_metadata(&at).is_ok_and(|m| m.file_type().is_symlink()) {
            return Err(invalid(
                path,
                format!("{} is a symbolic link", at.display()),
            ));
        }
    }
    open_regular(path)
}
