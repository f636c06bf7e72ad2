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
//!
//! Temporary files in flight are registered, so that a signal can remove
//! them before the process exits ([`abandon_in_flight`]); what `kill -9`
//! leaves, the next run in the same directory removes ([`OutDir::open`]).
//! Files are created with mode 0666 less the umask, like any other tool's.

use std::collections::BTreeSet;
use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::{Component, Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};

use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, ImageEncoder, RgbaImage};
use tempfile::TempPath;

/// Writes `text` to stderr, ignoring failure: a closed or full stderr
/// (`2>/dev/full`, `2>&1 | head -1`) must not turn a run into a panic, as
/// `eprint!` would; the exit status still tells the outcome. Every message
/// of the CLI goes through here.
pub fn stderr(text: &str) {
    let _ = io::stderr().lock().write_all(text.as_bytes());
}

/// An I/O error that names the path it concerns (once: an error that
/// already starts with the path is returned as it is).
pub fn with_path(path: &Path, e: io::Error) -> io::Error {
    let shown = path.display().to_string();
    if e.to_string().starts_with(&format!("{shown}: ")) {
        return e;
    }
    io::Error::new(e.kind(), format!("{shown}: {e}"))
}

/// Temporary files are `.sdfl-XXXXXX.tmp`, X alphanumeric (tempfile's
/// alphabet): [`is_temporary_name`] recognises exactly these.
const TMP_PREFIX: &str = ".sdfl-";
const TMP_SUFFIX: &str = ".tmp";
const TMP_RANDOM: usize = 6;

/// Whether `name` is one of this module's temporary file names.
pub fn is_temporary_name(name: &std::ffi::OsStr) -> bool {
    let Some(name) = name.to_str() else {
        return false;
    };
    name.strip_prefix(TMP_PREFIX)
        .and_then(|n| n.strip_suffix(TMP_SUFFIX))
        .is_some_and(|x| x.len() == TMP_RANDOM && x.bytes().all(|b| b.is_ascii_alphanumeric()))
}

/// A new empty temporary file in `dir`, mode 0666 less the umask
/// (tempfile's default, 0600, would ignore the umask). Its errors are the
/// system's, without the temporary name that `tempfile_in` would add (the
/// user asked for another file).
#[doc(hidden)]
pub fn temporary_in(dir: &Path) -> io::Result<tempfile::NamedTempFile> {
    tempfile::Builder::new()
        .prefix(TMP_PREFIX)
        .suffix(TMP_SUFFIX)
        .rand_bytes(TMP_RANDOM)
        .make_in(dir, |path| {
            let mut o = fs::OpenOptions::new();
            o.read(true).write(true).create_new(true);
            #[cfg(unix)]
            std::os::unix::fs::OpenOptionsExt::mode(&mut o, 0o666);
            o.open(path)
        })
}

/// The temporary files being written, and whether the process is exiting
/// (then no new one is made).
#[derive(Default)]
#[doc(hidden)]
pub struct InFlight {
    /// The temporary files.
    pub paths: BTreeSet<PathBuf>,
    /// Whether the process is exiting.
    pub closed: bool,
}

static IN_FLIGHT: Mutex<InFlight> = Mutex::new(InFlight {
    paths: BTreeSet::new(),
    closed: false,
});

/// The process-wide set of temporary files being written.
#[doc(hidden)]
pub fn in_flight() -> MutexGuard<'static, InFlight> {
    // A panic elsewhere while holding it leaves the set consistent.
    IN_FLIGHT.lock().unwrap_or_else(|e| e.into_inner())
}

/// Removes every temporary file being written and refuses new ones, for a
/// process about to exit on a signal; returns how many were removed. A
/// file being renamed into place meanwhile is complete (the rename holds
/// the registry).
pub fn abandon_in_flight() -> usize {
    in_flight().abandon()
}

impl InFlight {
    /// Removes every file and refuses new ones; returns how many were removed.
    pub fn abandon(&mut self) -> usize {
        self.closed = true;
        std::mem::take(&mut self.paths)
            .iter()
            .filter(|p| fs::remove_file(p).is_ok())
            .count()
    }
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

/// Most directory entries looked at for stale temporary files (as many
/// as a run may write): `--out .` in a large tree costs no more.
const STALE_SCAN_ENTRIES: usize = 100_000;
/// Deepest directory looked into (paths are at most 1024 bytes anyway).
const STALE_SCAN_DEPTH: usize = 64;

/// An output directory in use by this run. A shared lock on it, held as
/// long as this lives, tells a run starting there meanwhile that the
/// temporary files it sees are in flight, not stale.
pub struct OutDir {
    _lock: fs::File,
}

impl OutDir {
    /// Opens the existing directory `dir` for a run: checks that a file
    /// can be created in it (before any work, rather than at the first
    /// write after a whole training run) and, unless another run holds it,
    /// removes the temporary files that killed runs left there (at any
    /// depth, not following links). Returns how many were removed.
    pub fn open(dir: &Path) -> io::Result<(OutDir, usize)> {
        let lock = fs::File::open(dir).map_err(|e| with_path(dir, e))?;
        drop(temporary_in(dir).map_err(|e| {
            io::Error::new(
                e.kind(),
                format!("cannot create files in {}: {}", dir.display(), e),
            )
        })?);
        let mut removed = 0;
        // Where locks are not supported, nothing is removed: it could be
        // another run's.
        if lock.try_lock().is_ok() {
            let mut budget = STALE_SCAN_ENTRIES;
            removed = remove_stale(dir, STALE_SCAN_DEPTH, &mut budget);
            let _ = lock.unlock();
        }
        let _ = lock.lock_shared();
        Ok((OutDir { _lock: lock }, removed))
    }
}

/// Checks, before any work, that every directory outputs go to (relative
/// to the output directory `out`) can be made and written: each existing
/// step on the way is a directory, not a link or a file, and the deepest
/// existing one takes a new file. (Otherwise a whole training run could
/// end on "exists and is not a directory".)
pub fn check_output_dirs(out: &Path, dirs: &[PathBuf]) -> io::Result<()> {
    let mut probed = std::collections::HashSet::new();
    // `out` itself was probed when it was opened (`OutDir::open`).
    for rel in dirs.iter().filter(|d| !d.as_os_str().is_empty()) {
        let mut at = out.to_path_buf();
        for c in rel.components() {
            let next = at.join(c);
            match fs::symlink_metadata(&next) {
                Ok(m) if m.file_type().is_symlink() => {
                    return Err(io::Error::new(
                        io::ErrorKind::PermissionDenied,
                        format!(
                            "{} is a symbolic link: outputs never follow links",
                            next.display()
                        ),
                    ))
                }
                Ok(m) if m.is_dir() => at = next,
                Ok(_) => {
                    return Err(io::Error::new(
                        io::ErrorKind::AlreadyExists,
                        format!(
                            "{} exists and is not a directory, but outputs go inside it",
                            next.display()
                        ),
                    ))
                }
                Err(e) if e.kind() == io::ErrorKind::NotFound => break,
                Err(e) => return Err(with_path(&next, e)),
            }
        }
        if probed.insert(at.clone()) {
            drop(temporary_in(&at).map_err(|e| {
                io::Error::new(
                    e.kind(),
                    format!("cannot create files in {}: {e}", at.display()),
                )
            })?);
        }
    }
    Ok(())
}

/// Removes this module's temporary files in `dir` and below: regular
/// files named exactly as [`temporary_in`] names them. Links are neither
/// followed nor removed.
fn remove_stale(dir: &Path, depth: usize, budget: &mut usize) -> usize {
    let Ok(entries) = fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.flatten() {
        if *budget == 0 {
            break;
        }
        *budget -= 1;
        // The entry's own type: a link is a link, not what it leads to.
        let Ok(t) = e.file_type() else { continue };
        if t.is_dir() && depth > 0 {
            removed += remove_stale(&e.path(), depth - 1, budget);
        } else if t.is_file()
            && is_temporary_name(&e.file_name())
            && fs::remove_file(e.path()).is_ok()
        {
            removed += 1;
        }
    }
    removed
}

/// A file being written; becomes visible at `path` on [`Atomic::commit`].
pub struct Atomic {
    path: PathBuf,
    file: Option<BufWriter<Named<fs::File>>>,
    /// Removes the temporary file when dropped uncommitted.
    tmp: Option<TempPath>,
}

impl Atomic {
    /// A temporary file beside `path` (its directory created), to become
    /// `path` on commit.
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
        // Created and registered together, so a signal never misses one.
        let mut set = in_flight();
        if set.closed {
            return Err(io::Error::new(
                io::ErrorKind::Interrupted,
                format!("{}: not written: sdfl is stopping", path.display()),
            ));
        }
        let (file, tmp) = temporary_in(dir)
            .map_err(|e| {
                io::Error::new(
                    e.kind(),
                    format!(
                        "{}: cannot create a file in {}: {}",
                        path.display(),
                        dir.display(),
                        e
                    ),
                )
            })?
            .into_parts();
        set.paths.insert(tmp.to_path_buf());
        drop(set);
        Ok(Atomic::of(path, file, tmp))
    }

    /// Writes into `file`, to become `path`; `tmp` is `file`'s name.
    pub fn of(path: &Path, file: fs::File, tmp: TempPath) -> Atomic {
        Atomic {
            path: path.to_path_buf(),
            file: Some(BufWriter::new(Named {
                inner: file,
                dest: path.to_path_buf(),
            })),
            tmp: Some(tmp),
        }
    }

    /// The temporary file's path, for a program that writes it itself
    /// (ffmpeg); it becomes the destination on [`Atomic::commit`].
    pub fn temporary_path(&self) -> &Path {
        self.tmp
            .as_deref()
            .expect("temporary path used after commit")
    }

    /// The destination.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The file's writer: its errors name the destination (never the
    /// temporary file, which the user did not ask for).
    pub fn writer(&mut self) -> &mut BufWriter<Named<fs::File>> {
        self.file.as_mut().expect("writer used after commit")
    }

    /// Gives the file `permissions` before it is renamed into place (a
    /// file rewritten in place keeps its mode).
    pub fn set_permissions(&mut self, permissions: fs::Permissions) -> io::Result<()> {
        let file = &self.writer().get_ref().inner;
        file.set_permissions(permissions)
            .map_err(|e| with_path(&self.path, e))
    }

    /// Flushes, syncs and renames the file into place.
    pub fn commit(mut self) -> io::Result<()> {
        let file = self.file.take().expect("committed once");
        let file = file
            .into_inner()
            .map_err(|e| with_path(&self.path, e.into_error()))?
            .inner;
        file.sync_all().map_err(|e| with_path(&self.path, e))?;
        drop(file);
        let tmp = self.tmp.take().expect("committed once");
        let mut set = in_flight();
        if !set.paths.remove(&*tmp) {
            // Removed by a signal meanwhile: the process is exiting.
            return Err(io::Error::new(
                io::ErrorKind::Interrupted,
                format!("{}: not written: sdfl is stopping", self.path.display()),
            ));
        }
        // On failure the temporary file is removed when dropped.
        tmp.persist(&self.path)
            .map_err(|e| with_path(&self.path, e.error))?;
        Ok(())
    }
}

impl Drop for Atomic {
    fn drop(&mut self) {
        // Uncommitted: close, remove the temporary file, forget it.
        self.file.take();
        if let Some(tmp) = self.tmp.take() {
            // Removed under the registry, so a signal meanwhile sees it.
            let mut set = in_flight();
            set.paths.remove(&*tmp);
            drop(tmp);
            drop(set);
        }
    }
}

/// A writer whose errors name `dest`.
pub struct Named<W> {
    inner: W,
    dest: PathBuf,
}

impl<W: Write> Write for Named<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.inner.write(buf).map_err(|e| with_path(&self.dest, e))
    }
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush().map_err(|e| with_path(&self.dest, e))
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
    path: PathBuf,
    delay: Delay,
    /// Frames written so far.
    pub frames: usize,
}

impl GifWriter {
    /// An animated GIF at `path`, looping, at `fps` frames per second.
    pub fn create(path: &Path, fps: f64) -> io::Result<GifWriter> {
        let file = SharedFile(Arc::new(Mutex::new(Some(Atomic::create(path)?))));
        let mut encoder = GifEncoder::new_with_speed(file.clone(), 10);
        encoder
            .set_repeat(Repeat::Infinite)
            .map_err(|e| with_path(path, io::Error::other(e)))?;
        let ms = (1000.0 / fps).round().clamp(10.0, 60_000.0) as u32;
        Ok(GifWriter {
            encoder,
            file,
            path: path.to_path_buf(),
            delay: Delay::from_numer_denom_ms(ms, 1),
            frames: 0,
        })
    }

    /// Appends one RGB8 frame.
    pub fn push(&mut self, width: u32, height: u32, rgb: &[u8]) -> io::Result<()> {
        let rgba: Vec<u8> = rgb
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect();
        let img = RgbaImage::from_raw(width, height, rgba).expect("buffer matches dimensions");
        self.encoder
            .encode_frame(Frame::from_parts(img, 0, 0, self.delay))
            .map_err(|e| with_path(&self.path, io::Error::other(e)))?;
        self.frames += 1;
        Ok(())
    }

    /// Writes the trailer and renames the file into place.
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

/// The inferno colour map (perceptually uniform, dark to light) for `x`
/// in 0..1 (clamped; non-finite is the dark end): depth images and GIFs,
/// the same map as `depth_map(colormap: "inferno")`.
pub fn colormap(x: f32) -> [u8; 3] {
    colour(sdfl_stdlib::value::Colormap::Inferno, x as f64)
}

/// `map` at `x` in 0..1 (clamped; non-finite gives the low end).
pub fn colour(map: sdfl_stdlib::value::Colormap, x: f64) -> [u8; 3] {
    use sdfl_stdlib::value::Colormap;
    let g = match map {
        Colormap::Turbo => colorous::TURBO,
        Colormap::Viridis => colorous::VIRIDIS,
        Colormap::Inferno => colorous::INFERNO,
        Colormap::Magma => colorous::MAGMA,
        Colormap::Plasma => colorous::PLASMA,
        Colormap::Cividis => colorous::CIVIDIS,
    };
    let x = if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let c = g.eval_continuous(x);
    [c.r, c.g, c.b]
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

/// A file that was written, as reports list it.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Written {
    /// The file, relative to the output directory.
    pub path: PathBuf,
    /// What it holds.
    pub kind: WrittenKind,
    /// Width in pixels (0 for files that are not images).
    pub width: u32,
    /// Height in pixels (0 for files that are not images).
    pub height: u32,
    /// Frames of an animation; 1 for a still image, 0 for other files.
    pub frames: usize,
    /// What a mesh holds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh: Option<MeshStats>,
    /// What the run warns of about this file: why it is a `video`'s GIF
    /// fallback instead of its MP4, why a data set's transforms files
    /// leave out the Blender form.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warning: Option<WrittenWarning>,
}

/// A warning about a written file, printed by the run and kept in its
/// report.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct WrittenWarning {
    /// The stable code (`sdfl::warn::...`).
    pub code: String,
    /// What happened and why.
    pub message: String,
}

/// What a written file holds; reports spell it in snake case (`image`,
/// `grid_image`, `rays_image`, …).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WrittenKind {
    /// A colour image of a view.
    Image,
    /// An animation, colour or colour-mapped depth, one frame per view.
    Gif,
    /// An H.264 MP4 video of the views' colour, one frame per view.
    Video,
    /// Colour-mapped depth of a view.
    Depth,
    /// Normals as colours.
    NormalMap,
    /// Which pixels hit the surface.
    Mask,
    /// The camera's grid of pixel positions.
    GridImage,
    /// The camera's rays.
    RaysImage,
    /// Stratified sample points along rays.
    SamplePoints,
    /// Training loss over the steps.
    LossCurve,
    /// Held-out PSNR over training time.
    PsnrCurve,
    /// Held-out views: truth, render and error.
    Comparison,
    /// A data set of views (images and poses).
    Dataset,
    /// A surface mesh of a distance field.
    Mesh,
    /// A neural SDF's surface traced from every view.
    GeometryGif,
    /// A mesh of a density's level set.
    DensityMesh,
    /// Points where rays' opacity gathers.
    PointCloud,
    /// Depths as an array.
    RawDepth,
    /// Depths as a colour-mapped image.
    DepthMap,
}

/// What a written mesh holds.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MeshStats {
    /// Vertices written.
    pub vertices: usize,
    /// Triangles written.
    pub triangles: usize,
    /// Grid cells along the region's longest side, and their size.
    pub resolution: u32,
    /// The cells' side.
    pub cell: f64,
    /// Total surface area.
    pub area: f64,
    /// Seconds the extraction took.
    pub seconds: f64,
}
