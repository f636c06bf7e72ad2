//! `video(...)` outputs: H.264 MP4 files that every player plays, encoded
//! by an `ffmpeg` found on the system (`SDFL_FFMPEG`, else the first
//! `ffmpeg` on `PATH`), frames piped to it as raw RGB24:
//!
//! ```text
//! ffmpeg -f rawvideo -pix_fmt rgb24 -s WxH -r FPS -i - \
//!        -c:v libx264 -pix_fmt yuv420p -crf 18 -f mp4 <temporary file>
//! ```
//!
//! The MP4 is written like every other output: to a temporary file beside
//! its destination, created by [`Atomic`] (mode 0666 less the umask,
//! removed on a signal or failure), renamed into place when ffmpeg has
//! finished. Before the first frame, the same command encodes one black
//! frame of the video's size to nothing (`-f null`), so that a missing
//! ffmpeg, one without libx264, or one refusing the size is found while
//! the frames can still go elsewhere: then they go to the animated GIF at
//! the output's fallback path, and the written file carries the reason
//! ([`Written::fallback`]), which the CLI prints as a warning. An ffmpeg
//! that passed that check and fails while encoding (a full disk, killed)
//! is an error naming it and its last message.

use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::output::{with_path, Atomic, GifWriter, Written, WrittenKind};

/// The environment variable naming the ffmpeg to use (a path, or a name
/// looked up on `PATH`); where unset or empty, `ffmpeg` on `PATH`.
pub const FFMPEG_ENV: &str = "SDFL_FFMPEG";

/// The code of the warning that a video was written as its GIF fallback.
pub const FALLBACK: &str = "sdfl::warn::video-fallback";

/// How long the one-frame check may take before ffmpeg is taken as
/// unusable (it encodes a single frame; a program that never reads its
/// input or never exits must not hang the run).
const PROBE_TIMEOUT: Duration = Duration::from_secs(60);

/// Bytes of ffmpeg's error output kept for messages.
const STDERR_KEPT: usize = 4096;

/// The ffmpeg to run: `SDFL_FFMPEG` where set (a path, or a name looked up
/// on `PATH`), else `ffmpeg` on `PATH`. The error says what was looked for.
pub fn find_ffmpeg() -> Result<PathBuf, String> {
    let path_var = std::env::var_os("PATH");
    match std::env::var_os(FFMPEG_ENV).filter(|v| !v.is_empty()) {
        Some(named) => {
            let named = PathBuf::from(named);
            let found = if named.components().count() > 1 || named.is_absolute() {
                is_executable(&named).then(|| named.clone())
            } else {
                search_path(named.as_os_str(), path_var.as_deref())
            };
            found.ok_or_else(|| {
                format!(
                    "{FFMPEG_ENV} names `{}`, which is no executable file",
                    named.display()
                )
            })
        }
        None => search_path("ffmpeg".as_ref(), path_var.as_deref()).ok_or_else(|| {
            format!("no `ffmpeg` was found on PATH (install it, or name one with {FFMPEG_ENV})")
        }),
    }
}

/// The first executable file `name` in the directories of `path_var`.
#[doc(hidden)]
pub fn search_path(name: &std::ffi::OsStr, path_var: Option<&std::ffi::OsStr>) -> Option<PathBuf> {
    std::env::split_paths(path_var?)
        .filter(|dir| !dir.as_os_str().is_empty())
        .map(|dir| dir.join(name))
        .find(|p| is_executable(p))
}

fn is_executable(p: &Path) -> bool {
    let Ok(meta) = std::fs::metadata(p) else {
        return false;
    };
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        meta.is_file() && meta.permissions().mode() & 0o111 != 0
    }
    #[cfg(not(unix))]
    {
        meta.is_file()
    }
}

/// The size of the video of `width × height` frames: H.264 in 4:2:0 needs
/// even sides, so an odd side grows by one pixel, a copy of the last row or
/// column (padding keeps every rendered pixel; cropping would drop one).
pub fn even_size(width: u32, height: u32) -> (u32, u32) {
    (width + (width & 1), height + (height & 1))
}

/// An RGB8 frame of `width × height` padded to [`even_size`] by repeating
/// its last column and row.
#[doc(hidden)]
pub fn padded(rgb: &[u8], width: u32, height: u32) -> std::borrow::Cow<'_, [u8]> {
    let (w, h) = (width as usize, height as usize);
    let (ew, eh) = even_size(width, height);
    if (ew, eh) == (width, height) {
        return rgb.into();
    }
    let mut out = Vec::with_capacity(ew as usize * eh as usize * 3);
    for row in rgb.chunks_exact(3 * w).take(h) {
        out.extend_from_slice(row);
        if ew as usize > w {
            out.extend_from_slice(&row[3 * (w - 1)..]);
        }
    }
    if eh as usize > h {
        let last = out[out.len() - 3 * ew as usize..].to_vec();
        out.extend_from_slice(&last);
    }
    out.into()
}

/// ffmpeg's arguments for `fps` frames of `width × height` (even) RGB24 on
/// its standard input, encoded to `output` as `format`.
#[doc(hidden)]
pub fn ffmpeg_args(
    width: u32,
    height: u32,
    fps: f64,
    format: &str,
    output: &Path,
) -> Vec<std::ffi::OsString> {
    let mut args: Vec<std::ffi::OsString> = [
        "-hide_banner",
        "-loglevel",
        "error",
        "-y",
        "-f",
        "rawvideo",
        "-pix_fmt",
        "rgb24",
        "-s",
        &format!("{width}x{height}"),
        "-r",
        &format!("{fps}"),
        "-i",
        "-",
        "-c:v",
        "libx264",
        "-pix_fmt",
        "yuv420p",
        "-crf",
        "18",
        "-f",
        format,
    ]
    .iter()
    .map(Into::into)
    .collect();
    if format == "mp4" {
        // The index first, so a browser starts playing before the end.
        args.extend(["-movflags".into(), "+faststart".into()]);
    }
    args.push(output.as_os_str().to_owned());
    args
}

/// A running ffmpeg: its input, and a thread keeping the end of its errors.
struct Running {
    child: Child,
    stdin: Option<ChildStdin>,
    stderr: Option<JoinHandle<Vec<u8>>>,
}

impl Running {
    fn spawn(ffmpeg: &Path, args: &[std::ffi::OsString]) -> io::Result<Running> {
        let mut child = Command::new(ffmpeg)
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()?;
        let stdin = child.stdin.take();
        let stderr = child.stderr.take().map(|mut e| {
            std::thread::spawn(move || {
                let mut kept = Vec::new();
                let mut buf = [0u8; 4096];
                while let Ok(n) = e.read(&mut buf) {
                    if n == 0 {
                        break;
                    }
                    kept.extend_from_slice(&buf[..n]);
                    if kept.len() > 2 * STDERR_KEPT {
                        kept.drain(..kept.len() - STDERR_KEPT);
                    }
                }
                kept
            })
        });
        Ok(Running {
            child,
            stdin,
            stderr,
        })
    }

    /// Closes ffmpeg's input and waits for it (at most `timeout`, then it
    /// is killed); `Err` holds what went wrong, ffmpeg's last words too.
    fn finish(mut self, timeout: Option<Duration>) -> Result<(), String> {
        drop(self.stdin.take());
        let status = match timeout {
            None => self.child.wait().map_err(|e| e.to_string())?,
            Some(limit) => {
                let start = Instant::now();
                loop {
                    match self.child.try_wait().map_err(|e| e.to_string())? {
                        Some(s) => break s,
                        None if start.elapsed() > limit => {
                            let _ = self.child.kill();
                            let _ = self.child.wait();
                            return Err(format!(
                                "it did not finish one frame in {} s",
                                limit.as_secs()
                            ));
                        }
                        None => std::thread::sleep(Duration::from_millis(5)),
                    }
                }
            }
        };
        let said = self.said();
        if status.success() {
            return Ok(());
        }
        let how = match status.code() {
            Some(code) => format!("it exited with status {code}"),
            None => "it was stopped by a signal".to_string(),
        };
        Err(match said {
            Some(said) => format!("{how}: {said}"),
            None => how,
        })
    }

    /// The last line ffmpeg wrote on its error output, if any.
    fn said(&mut self) -> Option<String> {
        let bytes = self.stderr.take()?.join().ok()?;
        let text = String::from_utf8_lossy(&bytes);
        text.lines()
            .map(str::trim)
            .rfind(|l| !l.is_empty())
            .map(|l| l.chars().take(300).collect())
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        // Not finished (an error elsewhere): stop it, reap it.
        drop(self.stdin.take());
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

/// Whether `ffmpeg` encodes `width × height` (even) RGB24 frames at `fps`
/// with libx264: one black frame, encoded to nothing.
pub fn probe(ffmpeg: &Path, width: u32, height: u32, fps: f64) -> Result<(), String> {
    let args = ffmpeg_args(width, height, fps, "null", Path::new("-"));
    let mut run = Running::spawn(ffmpeg, &args).map_err(|e| e.to_string())?;
    let frame = vec![0u8; width as usize * height as usize * 3];
    let mut stdin = run.stdin.take().expect("piped");
    // Written from a thread, so that one that never reads times out.
    let writer = std::thread::spawn(move || stdin.write_all(&frame));
    let result = run.finish(Some(PROBE_TIMEOUT));
    // A write refused because it exited says nothing more than its status.
    let _ = writer.join();
    result
}

/// An MP4 being encoded by ffmpeg into its temporary file.
pub struct Mp4Writer {
    /// ffmpeg, until it is waited for.
    run: Option<Running>,
    file: Atomic,
    ffmpeg: PathBuf,
    width: u32,
    height: u32,
    /// Frames written so far.
    pub frames: usize,
}

impl Mp4Writer {
    /// Starts `ffmpeg` encoding `width × height` frames (any size: padded
    /// to even) at `fps` into a temporary file that becomes `path`.
    pub fn start(
        ffmpeg: &Path,
        path: &Path,
        width: u32,
        height: u32,
        fps: f64,
    ) -> io::Result<Mp4Writer> {
        let file = Atomic::create(path)?;
        let (w, h) = even_size(width, height);
        let args = ffmpeg_args(w, h, fps, "mp4", file.temporary_path());
        let run = Running::spawn(ffmpeg, &args).map_err(|e| {
            with_path(
                path,
                io::Error::new(e.kind(), format!("cannot run {}: {e}", ffmpeg.display())),
            )
        })?;
        Ok(Mp4Writer {
            run: Some(run),
            file,
            ffmpeg: ffmpeg.to_path_buf(),
            width,
            height,
            frames: 0,
        })
    }

    fn failed(&mut self, why: &str) -> io::Error {
        // Stopped first: its error output ends when it exits.
        let said = self.run.take().and_then(|mut run| {
            drop(run.stdin.take());
            if let Ok(None) = run.child.try_wait() {
                let _ = run.child.kill();
            }
            let _ = run.child.wait();
            run.said()
        });
        let said = said.map(|s| format!(": {s}")).unwrap_or_default();
        with_path(
            self.file.path(),
            io::Error::other(format!(
                "{} failed while encoding ({why}){said}",
                self.ffmpeg.display()
            )),
        )
    }

    /// Appends one RGB8 frame of the size the video was started with.
    pub fn push(&mut self, rgb: &[u8]) -> io::Result<()> {
        let frame = padded(rgb, self.width, self.height);
        let Some(stdin) = self.run.as_mut().and_then(|r| r.stdin.as_mut()) else {
            return Err(self.failed("it had stopped"));
        };
        if let Err(e) = stdin.write_all(&frame) {
            return Err(self.failed(&e.to_string()));
        }
        self.frames += 1;
        Ok(())
    }

    /// Waits for ffmpeg to finish the file and renames it into place.
    pub fn finish(mut self) -> io::Result<()> {
        let Some(run) = self.run.take() else {
            return Err(self.failed("it had stopped"));
        };
        run.finish(None).map_err(|e| {
            with_path(
                self.file.path(),
                io::Error::other(format!(
                    "{} failed while encoding: {e}",
                    self.ffmpeg.display()
                )),
            )
        })?;
        self.file.commit()
    }
}

/// What a `video` output writes: nothing yet (ffmpeg is checked at the
/// first frame, when the size is known), the MP4, or the GIF fallback and
/// why.
enum Encoder {
    Waiting,
    Mp4(Mp4Writer),
    Gif(GifWriter, String),
}

/// A `video(...)` output: the MP4 where ffmpeg encodes it, else its GIF.
pub struct VideoWriter {
    out_dir: PathBuf,
    path: PathBuf,
    fallback: PathBuf,
    fps: f64,
    size: (u32, u32),
    encoder: Encoder,
}

impl VideoWriter {
    /// The video `path` (relative to `out_dir`) at `fps`, falling back to
    /// the GIF `fallback`.
    pub fn new(out_dir: &Path, path: &Path, fallback: &Path, fps: f64) -> VideoWriter {
        VideoWriter {
            out_dir: out_dir.to_path_buf(),
            path: path.to_path_buf(),
            fallback: fallback.to_path_buf(),
            fps,
            size: (0, 0),
            encoder: Encoder::Waiting,
        }
    }

    /// Starts the MP4, or the GIF where ffmpeg is missing or cannot.
    fn open(&mut self, width: u32, height: u32) -> io::Result<()> {
        self.size = (width, height);
        let (w, h) = even_size(width, height);
        let fps = self.fps;
        let checked = find_ffmpeg().and_then(|ffmpeg| {
            probe(&ffmpeg, w, h, fps)
                .map(|()| ffmpeg.clone())
                .map_err(|e| format!("`{}` cannot encode H.264 at {w}x{h}: {e}", ffmpeg.display()))
        });
        self.encoder = match checked {
            Ok(ffmpeg) => Encoder::Mp4(Mp4Writer::start(
                &ffmpeg,
                &self.out_dir.join(&self.path),
                width,
                height,
                fps,
            )?),
            Err(why) => {
                let gif = GifWriter::create(&self.out_dir.join(&self.fallback), fps)?;
                let reason = format!(
                    "`{}` is not written: {why}; its frames are in the GIF `{}` instead",
                    self.path.display(),
                    self.fallback.display()
                );
                Encoder::Gif(gif, reason)
            }
        };
        Ok(())
    }

    /// Appends one RGB8 frame; every frame has the first one's size.
    pub fn push(&mut self, width: u32, height: u32, rgb: &[u8]) -> io::Result<()> {
        if matches!(self.encoder, Encoder::Waiting) {
            self.open(width, height)?;
        }
        debug_assert_eq!(self.size, (width, height), "frames of one size");
        match &mut self.encoder {
            Encoder::Mp4(m) => m.push(rgb),
            Encoder::Gif(g, _) => g.push(width, height, rgb),
            Encoder::Waiting => unreachable!("opened above"),
        }
    }

    /// Finishes the file and says what was written.
    pub fn finish(mut self) -> io::Result<Written> {
        if matches!(self.encoder, Encoder::Waiting) {
            // No frame at all: an empty GIF says so more plainly than no file.
            let gif = GifWriter::create(&self.out_dir.join(&self.fallback), self.fps)?;
            let reason = format!("`{}` has no frames to encode", self.path.display());
            self.encoder = Encoder::Gif(gif, reason);
        }
        let (width, height) = self.size;
        match self.encoder {
            Encoder::Mp4(m) => {
                let frames = m.frames;
                m.finish()?;
                let (width, height) = even_size(width, height);
                Ok(Written {
                    path: self.path,
                    kind: WrittenKind::Video,
                    width,
                    height,
                    frames,
                    mesh: None,
                    warning: None,
                })
            }
            Encoder::Gif(g, reason) => {
                let frames = g.frames;
                g.finish()?;
                Ok(Written {
                    path: self.fallback,
                    kind: WrittenKind::Gif,
                    width,
                    height,
                    frames,
                    mesh: None,
                    warning: Some(crate::output::WrittenWarning {
                        code: FALLBACK.to_string(),
                        message: reason,
                    }),
                })
            }
            Encoder::Waiting => unreachable!("a GIF when no frame came"),
        }
    }
}
