//! Reading a file a user named, or one found where sdfl writes, only if it
//! is a regular file: a FIFO blocks whoever opens it for reading until a
//! writer comes, and `/dev/zero` never ends. Every reader of such paths
//! (scene files, imports, data, logs, sweep rows, the watcher's stamps)
//! goes through here, so none of them can hang or read without limit.

use std::fs::File;
use std::io::{self, Read};
use std::path::Path;

use sdfl_lang::diag::{codes, Diag};
use sdfl_lang::Span;

/// An error that names `path`.
fn named(path: &Path, e: io::Error) -> io::Error {
    io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}

fn not_regular(path: &Path) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("{}: not a regular file", path.display()),
    )
}

/// Opens `path` without ever waiting on a FIFO; the caller checks what
/// was opened.
#[doc(hidden)]
pub fn open_nonblocking(path: &Path) -> io::Result<File> {
    let mut o = std::fs::OpenOptions::new();
    o.read(true);
    // Opening a FIFO with O_NONBLOCK returns at once (the handle's
    // metadata then refuses it) instead of waiting for a writer; it changes
    // nothing for reads of a regular file. Elsewhere the check before
    // opening still refuses anything that is no regular file then.
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.custom_flags(libc::O_NONBLOCK);
    }
    o.open(path).map_err(|e| named(path, e))
}

/// Opens `path` for reading if, after following links, it is a regular
/// file: checked before opening (a device is never opened) and again on
/// the handle (the path may have changed in between).
pub fn open_regular(path: &Path) -> io::Result<File> {
    if !std::fs::metadata(path)
        .map_err(|e| named(path, e))?
        .is_file()
    {
        return Err(not_regular(path));
    }
    let file = open_nonblocking(path)?;
    if !file.metadata().map_err(|e| named(path, e))?.is_file() {
        return Err(not_regular(path));
    }
    Ok(file)
}

/// Opens `path` for reading if it is itself a regular file, not a link to
/// one: for files sdfl wrote in its output directory, where a planted link
/// must not make it read (and copy into its logs) what lies elsewhere.
pub fn open_regular_unlinked(path: &Path) -> io::Result<File> {
    let meta = std::fs::symlink_metadata(path).map_err(|e| named(path, e))?;
    if !meta.is_file() {
        return Err(not_regular(path));
    }
    let file = open_nonblocking(path)?;
    let opened = file.metadata().map_err(|e| named(path, e))?;
    if !opened.is_file() || !same_file(&meta, &opened) {
        return Err(not_regular(path));
    }
    Ok(file)
}

#[cfg(unix)]
fn same_file(a: &std::fs::Metadata, b: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    (a.dev(), a.ino()) == (b.dev(), b.ino())
}

#[cfg(not(unix))]
fn same_file(_: &std::fs::Metadata, _: &std::fs::Metadata) -> bool {
    true
}

/// Reads `file` (named `path` in errors) to its end, refusing more than
/// `cap` bytes; never holds more than `cap + 1`.
pub fn read_to_cap(file: File, path: &Path, cap: u64) -> io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    file.take(cap.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|e| named(path, e))?;
    if bytes.len() as u64 > cap {
        return Err(io::Error::new(
            io::ErrorKind::FileTooLarge,
            format!("{}: larger than {cap} bytes", path.display()),
        ));
    }
    Ok(bytes)
}

/// The bytes of the regular file `path` (links followed), at most `cap`.
pub fn read_capped(path: &Path, cap: u64) -> io::Result<Vec<u8>> {
    read_to_cap(open_regular(path)?, path, cap)
}

/// Text that is not UTF-8: where its first bad byte is, and the text as
/// decoded with U+FFFD for each bad sequence (the same up to that byte, so
/// the offset places a label in it).
pub struct NotUtf8 {
    /// Offset of the first byte that is not UTF-8.
    pub at: usize,
    /// That byte.
    pub byte: u8,
    /// The text, decoded lossily, for showing where the error is.
    pub lossy: String,
}

/// `bytes` as UTF-8 text, or where they stop being it.
pub fn utf8(bytes: Vec<u8>) -> Result<String, NotUtf8> {
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let bytes = e.into_bytes();
        NotUtf8 {
            at,
            byte: bytes[at],
            lossy: String::from_utf8_lossy(&bytes).into_owned(),
        }
    })
}

impl NotUtf8 {
    /// 1-based line and column (in characters) of the bad byte.
    pub fn line_col(&self) -> (usize, usize) {
        let before = &self.lossy[..self.at];
        let line = before.matches('\n').count() + 1;
        let column = before.rsplit('\n').next().unwrap_or("").chars().count() + 1;
        (line, column)
    }

    /// Where the bad byte is, in words: `byte 25 (0xe9, line 2, column 9)`.
    pub fn place(&self) -> String {
        let (line, column) = self.line_col();
        format!(
            "byte {} ({:#04x}, line {line}, column {column})",
            self.at, self.byte
        )
    }

    /// The diagnostic of a scene file that is not UTF-8, placed in
    /// [`NotUtf8::lossy`] at the replacement character of the bad byte.
    pub fn diag(&self) -> Diag {
        let (line, column) = self.line_col();
        Diag::new(
            codes::SOURCE_ENCODING,
            Span::new(self.at, self.at + char::REPLACEMENT_CHARACTER.len_utf8()),
            format!(
                "the file is not UTF-8 text: byte {} ({:#04x}, line {line}, column {column}) is not UTF-8",
                self.at, self.byte
            ),
        )
        .label(format!("byte {:#04x}, not UTF-8", self.byte))
        .help("save the file as UTF-8: sdfl reads no other encoding")
    }
}
