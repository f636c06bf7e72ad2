//! Writing images and GIFs atomically: each file is written to a temporary
//! name beside its destination and renamed into place once complete, so a
//! reader never sees a half-written file and a failed run leaves none.

use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, ImageEncoder, RgbaImage};

/// A file being written; becomes visible at `path` on [`Atomic::commit`].
pub struct Atomic {
    tmp: PathBuf,
    path: PathBuf,
    file: Option<BufWriter<File>>,
}

impl Atomic {
    pub fn create(path: &Path) -> io::Result<Atomic> {
        if let Some(dir) = path.parent() {
            fs::create_dir_all(dir)?;
        }
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("out");
        let tmp = path.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
        let file = BufWriter::new(File::create(&tmp)?);
        Ok(Atomic {
            tmp,
            path: path.to_path_buf(),
            file: Some(file),
        })
    }

    pub fn writer(&mut self) -> &mut BufWriter<File> {
        self.file.as_mut().expect("writer used after commit")
    }

    pub fn commit(mut self) -> io::Result<()> {
        let mut file = self.file.take().expect("committed once");
        file.flush()?;
        file.get_ref().sync_all()?;
        drop(file);
        fs::rename(&self.tmp, &self.path)
    }
}

impl Drop for Atomic {
    fn drop(&mut self) {
        if self.file.is_some() {
            let _ = fs::remove_file(&self.tmp);
        }
    }
}

/// Write an RGB8 PNG atomically.
pub fn write_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> io::Result<()> {
    let mut out = Atomic::create(path)?;
    image::codecs::png::PngEncoder::new(out.writer())
        .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(io::Error::other)?;
    out.commit()
}

/// An animated GIF, encoded frame by frame into memory (compressed; raw
/// frames are not kept) and written atomically by [`GifWriter::finish`].
pub struct GifWriter {
    encoder: GifEncoder<SharedBuf>,
    bytes: SharedBuf,
    path: PathBuf,
    delay: Delay,
    pub frames: usize,
}

impl GifWriter {
    pub fn create(path: &Path, fps: f64) -> io::Result<GifWriter> {
        let bytes = SharedBuf::default();
        let mut encoder = GifEncoder::new_with_speed(bytes.clone(), 10);
        encoder
            .set_repeat(Repeat::Infinite)
            .map_err(io::Error::other)?;
        let ms = (1000.0 / fps).round().clamp(10.0, 60_000.0) as u32;
        Ok(GifWriter {
            encoder,
            bytes,
            path: path.to_path_buf(),
            delay: Delay::from_numer_denom_ms(ms, 1),
            frames: 0,
        })
    }

    pub fn push(&mut self, width: u32, height: u32, rgb: &[u8]) -> io::Result<()> {
        let rgba: Vec<u8> = rgb
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect();
        let img = RgbaImage::from_raw(width, height, rgba).expect("buffer matches dimensions");
        self.encoder
            .encode_frame(Frame::from_parts(img, 0, 0, self.delay))
            .map_err(io::Error::other)?;
        self.frames += 1;
        Ok(())
    }

    pub fn finish(self) -> io::Result<()> {
        // Dropping the encoder writes the GIF trailer into the buffer.
        drop(self.encoder);
        let bytes = std::mem::take(&mut *self.bytes.0.lock().expect("not poisoned"));
        let mut out = Atomic::create(&self.path)?;
        out.writer().write_all(&bytes)?;
        out.commit()
    }
}

/// An in-memory writer the GIF encoder can own while we keep a handle.
#[derive(Clone, Default)]
struct SharedBuf(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

impl Write for SharedBuf {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.lock().expect("not poisoned").extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// A perceptual colour map (inferno-like, five stops) for `x` in 0..1.
pub fn colormap(x: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [0.0, 0.0, 4.0],
        [87.0, 16.0, 110.0],
        [188.0, 55.0, 84.0],
        [249.0, 142.0, 9.0],
        [252.0, 255.0, 164.0],
    ];
    let x = if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let f = x * 4.0;
    let i = (f.floor() as usize).min(3);
    let w = f - i as f32;
    let mut out = [0u8; 3];
    for c in 0..3 {
        out[c] = (STOPS[i][c] * (1.0 - w) + STOPS[i + 1][c] * w).round() as u8;
    }
    out
}

/// Linear 0..1 to 8 bits (no gamma: the assignment's images are linear).
#[inline]
pub fn to_u8(x: f64) -> u8 {
    if x.is_finite() {
        (x.clamp(0.0, 1.0) * 255.0).round() as u8
    } else {
        0
    }
}
