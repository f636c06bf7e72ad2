//! A training view's colours as a run holds them. Most data sets are 8-bit
//! images: they stay 8-bit RGBA (4 bytes a pixel, not 12 as f32 RGB) and
//! are composited over the background when a pixel is read, giving the
//! same f32 bits as compositing them all up front. Sources with more than
//! 8 bits (16-bit PNGs, `.npy`, views sdfl rendered) are held as f32 RGB.
//! A 100-view 800² set takes 256 MB this way, a DTU scan (49 views of
//! 1600 × 1200) 376 MB.

use super::npy::RgbImage;

/// A view's colours, row-major from the top-left pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewImage {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    pixels: Pixels,
}

#[derive(Debug, Clone, PartialEq)]
enum Pixels {
    /// 8-bit RGBA as decoded, shown over `background`.
    Rgba8 {
        rgba: Vec<[u8; 4]>,
        background: [f32; 3],
    },
    /// Linear f32 RGB.
    Rgb32(Vec<[f32; 3]>),
}

/// Bytes a pixel of an 8-bit view holds.
pub const RGBA8_BYTES: f64 = 4.0;
/// Bytes a pixel of an f32 view holds.
pub const RGB32_BYTES: f64 = 12.0;

/// One 8-bit RGBA pixel over `background`, as `composite_over` does it to
/// the pixel's f32 RGBA (the same operations, so the same bits).
#[inline]
fn over(p: [u8; 4], background: [f32; 3]) -> [f32; 3] {
    let a = (p[3] as f32 / 255.0).clamp(0.0, 1.0);
    [0, 1, 2].map(|c| (p[c] as f32 / 255.0) * a + background[c] * (1.0 - a))
}

impl ViewImage {
    /// 8-bit RGBA pixels (`width × height`) shown over `background`.
    pub fn rgba8(width: u32, height: u32, rgba: Vec<[u8; 4]>, background: [f32; 3]) -> Self {
        debug_assert_eq!(rgba.len(), width as usize * height as usize);
        ViewImage {
            width,
            height,
            pixels: Pixels::Rgba8 { rgba, background },
        }
    }

    /// An f32 RGB image's pixels (`width × height`).
    pub fn rgb32(width: u32, height: u32, pixels: Vec<[f32; 3]>) -> Self {
        debug_assert_eq!(pixels.len(), width as usize * height as usize);
        ViewImage {
            width,
            height,
            pixels: Pixels::Rgb32(pixels),
        }
    }

    /// Pixel `i`'s colour (row-major).
    #[inline]
    pub fn pixel(&self, i: usize) -> [f32; 3] {
        match &self.pixels {
            Pixels::Rgba8 { rgba, background } => over(rgba[i], *background),
            Pixels::Rgb32(p) => p[i],
        }
    }

    /// Pixels in all.
    pub fn len(&self) -> usize {
        match &self.pixels {
            Pixels::Rgba8 { rgba, .. } => rgba.len(),
            Pixels::Rgb32(p) => p.len(),
        }
    }

    /// Whether the image has no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Every pixel's colour in order.
    pub fn colours(&self) -> impl Iterator<Item = [f32; 3]> + '_ {
        (0..self.len()).map(|i| self.pixel(i))
    }

    /// Every pixel's colour as f32 RGB: one view at a time, for scoring.
    pub fn to_rgb(&self) -> Vec<[f32; 3]> {
        match &self.pixels {
            Pixels::Rgb32(p) => p.clone(),
            Pixels::Rgba8 { .. } => self.colours().collect(),
        }
    }

    /// Bytes a pixel holds.
    pub fn bytes_per_pixel(&self) -> f64 {
        match &self.pixels {
            Pixels::Rgba8 { .. } => RGBA8_BYTES,
            Pixels::Rgb32(_) => RGB32_BYTES,
        }
    }
}

impl From<RgbImage> for ViewImage {
    fn from(img: RgbImage) -> Self {
        ViewImage::rgb32(img.width, img.height, img.pixels)
    }
}
