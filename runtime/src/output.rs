//! Writing images and GIFs atomically and confined: each file is written
//! to a temporary file beside its destination, created exclusively under an
//! unpredictable name (`tempfile`), and renamed into place once complete,
//! so a reader never sees a half-written file, a failed run leaves none, and
//! a link planted at a guessable name is never written through.
//!
//! Every directory on the way to a destination must be a real directory:
//! a symbolic link anywhere in the path is refused, and missing directories
//! are created one at a time (never through a link). The CLI canonicalises
//! `--out` first, so a link *inside* the output directory can never lead
//! outside it. (A local attacker racing the checks could still swap a
//! directory for a link between check and create; the threat handled here
//! is links left in an output directory, not a concurrent adversary.)

use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::{Component, Path, PathBuf};
use std::sync::{Arc, Mutex};

use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, ImageEncoder, RgbaImage};
use tempfile::NamedTempFile;

/// An I/O error that names the path it concerns.
pub fn with_path(path: &Path, e: io::Error) -> io::Error {
    io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}

/// Makes every directory of `dir` exist as a real directory, refusing
/// symbolic links and non-directories among its components.
pub fn ensure_dir(dir: &Path) -> io::Result<()> {
    let mut at = PathBuf::new();
    for c in dir.components() {
        at.push(c);
        if matches!(
            c,
            Component::Prefix(_) | Component::RootDir | Component::CurDir
        ) {
            continue;
        }
        if c == Component::ParentDir {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("{}: output paths cannot contain `..`", dir.display()),
            ));
        }
        match fs::symlink_metadata(&at) {
            Ok(m) if m.file_type().is_symlink() => {
                return Err(io::Error::new(
                    io::ErrorKind::PermissionDenied,
                    format!(
                        "{} is a symbolic link; outputs are only written into real directories",
                        at.display()
                    ),
                ))
            }
            Ok(m) if m.is_dir() => {}
            Ok(_) => {
                return Err(io::Error::new(
                    io::ErrorKind::AlreadyExists,
                    format!("{} exists and is not a directory", at.display()),
                ))
            }
            Err(e) if e.kind() == io::ErrorKind::NotFound => match fs::create_dir(&at) {
                Ok(()) => {}
                // Created meanwhile by someone else: check what it is.
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                    if !fs::symlink_metadata(&at)?.is_dir() {
                        return Err(with_path(&at, e));
                    }
                }
                Err(e) => return Err(with_path(&at, e)),
            },
            Err(e) => return Err(with_path(&at, e)),
        }
    }
    Ok(())
}

/// A file being written; becomes visible at `path` on [`Atomic::commit`].
pub struct Atomic {
    path: PathBuf,
    file: Option<BufWriter<NamedTempFile>>,
}

impl Atomic {
    pub fn create(path: &Path) -> io::Result<Atomic> {
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        if path.file_name().is_none() || path.as_os_str().to_string_lossy().ends_with('/') {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("{}: not a file name", path.display()),
            ));
        }
        ensure_dir(dir)?;
        match fs::symlink_metadata(path) {
            Ok(m) if m.is_dir() => {
                return Err(io::Error::new(
                    io::ErrorKind::AlreadyExists,
                    format!("{} is a directory", path.display()),
                ))
            }
            // A link or file there is replaced by the rename, not followed.
            _ => {}
        }
        let tmp = tempfile::Builder::new()
            .prefix(".sdfl-")
            .suffix(".tmp")
            .tempfile_in(dir)
            .map_err(|e| {
                io::Error::new(
                    e.kind(),
                    format!("cannot create a file in {}: {e}", dir.display()),
                )
            })?;
        Ok(Atomic {
            path: path.to_path_buf(),
            file: Some(BufWriter::new(tmp)),
        })
    }

    pub fn writer(&mut self) -> &mut BufWriter<NamedTempFile> {
        self.file.as_mut().expect("writer used after commit")
    }

    pub fn commit(mut self) -> io::Result<()> {
        let file = self.file.take().expect("committed once");
        let tmp = file
            .into_inner()
            .map_err(|e| with_path(&self.path, e.into_error()))?;
        tmp.as_file()
            .sync_all()
            .map_err(|e| with_path(&self.path, e))?;
        // On failure the temporary file is removed when dropped.
        tmp.persist(&self.path)
            .map_err(|e| with_path(&self.path, e.error))?;
        Ok(())
    }
}

/// Write an RGB8 PNG atomically.
pub fn write_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> io::Result<()> {
    let mut out = Atomic::create(path)?;
    image::codecs::png::PngEncoder::new(out.writer())
        .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|e| with_path(path, io::Error::other(e)))?;
    out.commit()
}

/// Write an RGBA8 PNG atomically.
pub fn write_png_rgba(path: &Path, width: u32, height: u32, rgba: &[u8]) -> io::Result<()> {
    let mut out = Atomic::create(path)?;
    image::codecs::png::PngEncoder::new(out.writer())
        .write_image(rgba, width, height, image::ExtendedColorType::Rgba8)
        .map_err(|e| with_path(path, io::Error::other(e)))?;
    out.commit()
}

/// Write bytes (a JSON file) atomically.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut out = Atomic::create(path)?;
    out.writer()
        .write_all(bytes)
        .map_err(|e| with_path(path, e))?;
    out.commit()
}

/// An animated GIF, encoded frame by frame straight into its temporary
/// file (no frame is kept in memory) and renamed into place by
/// [`GifWriter::finish`].
pub struct GifWriter {
    encoder: GifEncoder<SharedFile>,
    file: SharedFile,
    delay: Delay,
    pub frames: usize,
}

impl GifWriter {
    pub fn create(path: &Path, fps: f64) -> io::Result<GifWriter> {
        let file = SharedFile(Arc::new(Mutex::new(Some(Atomic::create(path)?))));
        let mut encoder = GifEncoder::new_with_speed(file.clone(), 10);
        encoder
            .set_repeat(Repeat::Infinite)
            .map_err(io::Error::other)?;
        let ms = (1000.0 / fps).round().clamp(10.0, 60_000.0) as u32;
        Ok(GifWriter {
            encoder,
            file,
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
        // Dropping the encoder writes the GIF trailer into the file.
        drop(self.encoder);
        let atomic = self
            .file
            .0
            .lock()
            .map_err(|_| io::Error::other("GIF writer poisoned"))?
            .take()
            .expect("finished once");
        atomic.commit()
    }
}

/// The temporary file the GIF encoder owns while we keep a handle.
#[derive(Clone)]
struct SharedFile(Arc<Mutex<Option<Atomic>>>);

impl Write for SharedFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match self.0.lock() {
            Ok(mut g) => match g.as_mut() {
                Some(a) => a.writer().write(buf),
                None => Err(io::Error::other("GIF already finished")),
            },
            Err(_) => Err(io::Error::other("GIF writer poisoned")),
        }
    }
    fn flush(&mut self) -> io::Result<()> {
        match self.0.lock() {
            Ok(mut g) => g.as_mut().map_or(Ok(()), |a| a.writer().flush()),
            Err(_) => Err(io::Error::other("GIF writer poisoned")),
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("sdfl-output-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn temporary_names_are_unpredictable_and_cleaned_up() {
        let d = dir("tmp");
        let a = Atomic::create(&d.join("x.png")).unwrap();
        let b = Atomic::create(&d.join("x.png")).unwrap();
        let names = |d: &Path| -> Vec<String> {
            fs::read_dir(d)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect()
        };
        let tmp = names(&d);
        assert_eq!(tmp.len(), 2, "{tmp:?}");
        assert!(tmp
            .iter()
            .all(|n| !n.contains(&std::process::id().to_string())));
        drop((a, b));
        assert!(names(&d).is_empty());
    }

    #[cfg(unix)]
    #[test]
    fn links_and_non_directories_on_the_way_are_refused() {
        let d = dir("links");
        let elsewhere = d.join("elsewhere");
        fs::create_dir_all(&elsewhere).unwrap();
        std::os::unix::fs::symlink(&elsewhere, d.join("sub")).unwrap();
        let e = write_png(&d.join("sub/deeper/x.png"), 1, 1, &[0, 0, 0]).unwrap_err();
        assert!(e.to_string().contains("symbolic link"), "{e}");
        assert!(!elsewhere.join("deeper").exists());
        fs::write(d.join("file"), "x").unwrap();
        let e = write_png(&d.join("file/x.png"), 1, 1, &[0, 0, 0]).unwrap_err();
        assert!(e.to_string().contains("not a directory"), "{e}");
        // A link at the destination is replaced, not written through.
        fs::write(d.join("victim"), "keep").unwrap();
        std::os::unix::fs::symlink(d.join("victim"), d.join("y.png")).unwrap();
        write_png(&d.join("y.png"), 1, 1, &[0, 0, 0]).unwrap();
        assert_eq!(fs::read_to_string(d.join("victim")).unwrap(), "keep");
        // A directory at the destination, or a name ending in `/`, is an
        // error naming the path, and leaves no temporary file.
        fs::create_dir_all(d.join("z.png")).unwrap();
        let e = write_png(&d.join("z.png"), 1, 1, &[0, 0, 0]).unwrap_err();
        assert!(e.to_string().contains("z.png"), "{e}");
        assert!(Atomic::create(Path::new(&format!("{}/w.png/", d.display()))).is_err());
        assert!(fs::read_dir(&d).unwrap().all(|e| !e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .ends_with(".tmp")));
    }

    #[test]
    fn gifs_stream_to_their_file() {
        let d = dir("gif");
        let mut g = GifWriter::create(&d.join("a.gif"), 10.0).unwrap();
        // Noise, so the frames compress to more than the write buffer.
        let mut seed = 1u32;
        for _ in 0..3 {
            let rgb: Vec<u8> = (0..128 * 128 * 3)
                .map(|_| {
                    seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    (seed >> 24) as u8
                })
                .collect();
            g.push(128, 128, &rgb).unwrap();
        }
        // Frames are in the temporary file already, not in memory.
        let tmp_len: u64 = fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().metadata().unwrap().len())
            .sum();
        assert!(tmp_len > 0);
        g.finish().unwrap();
        let img = image::open(d.join("a.gif")).unwrap();
        assert_eq!((img.width(), img.height()), (128, 128));
    }
}
