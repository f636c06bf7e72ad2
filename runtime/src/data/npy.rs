//! Minimal NumPy `.npy`/`.npz` reader for float32 arrays (the assignment's
//! `box_*.npy` images and `bunny_pointcloud.npz`): format version 1.0,
//! little-endian `<f4`, C order. Anything else is rejected with an error.

use std::fmt;
use std::path::Path;

/// The first bytes of every `.npy` file.
pub const MAGIC: &[u8] = b"\x93NUMPY";

/// An RGB float image, row-major from the top-left pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Linear RGB of each pixel, `width × height` of them.
    pub pixels: Vec<[f32; 3]>,
}

/// Why a `.npy` file could not be read.
#[derive(Debug)]
pub enum NpyError {
    /// The file could not be opened or read.
    Io(std::io::Error),
    /// Not a `.npy` file, or a malformed header.
    Format(String),
    /// A valid `.npy` file this reader does not accept (dtype, order, shape, version).
    Unsupported(String),
    /// An `.npz` archive without the requested array.
    MissingKey(String),
}

impl fmt::Display for NpyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NpyError::Io(e) => write!(f, "cannot read .npy file: {e}"),
            NpyError::Format(m) => write!(f, "malformed .npy file: {m}"),
            NpyError::Unsupported(m) => write!(f, "unsupported .npy file: {m}"),
            NpyError::MissingKey(k) => write!(f, ".npz archive has no array '{k}'"),
        }
    }
}

impl std::error::Error for NpyError {}

impl From<std::io::Error> for NpyError {
    fn from(e: std::io::Error) -> Self {
        NpyError::Io(e)
    }
}

/// Reads an `(H, W, 3)` little-endian float32 C-order `.npy` v1 file.
pub fn read_rgb_f32(path: impl AsRef<Path>) -> Result<RgbImage, NpyError> {
    parse_rgb_f32(&read_limited(path.as_ref())?)
}

/// The bytes of a regular file no larger than an array may be.
fn read_limited(path: &Path) -> Result<Vec<u8>, NpyError> {
    read_at_most(path, MAX_ARRAY_BYTES + 10 + u16::MAX as u64)
}

/// The bytes of a regular file of at most `limit` bytes (a larger one is
/// refused, after reading no more than one byte past it).
fn read_at_most(path: &Path, limit: u64) -> Result<Vec<u8>, NpyError> {
    use std::io::Read;
    let file = sdfl_stdlib::files::open_regular(path)?;
    let mut buf = Vec::new();
    file.take(limit + 1).read_to_end(&mut buf)?;
    if buf.len() as u64 > limit {
        return Err(NpyError::Unsupported(format!(
            "file larger than {limit} bytes"
        )));
    }
    Ok(buf)
}

/// Largest array the readers accept, in data bytes: an `.npy` header or
/// an `.npz` entry may declare any size, so it is checked before reading.
pub const MAX_ARRAY_BYTES: u64 = 2_000_000_000;

/// A value of the header dict (a Python literal).
#[derive(Debug, Clone, PartialEq)]
enum HeaderValue {
    Str(String),
    Bool(bool),
    Tuple(Vec<usize>),
}

/// Parses the header, a Python dict literal such as
/// `{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 3), }`,
/// with a small tokenizer: keys are found only as keys, never inside a
/// string value.
fn parse_header(h: &str) -> Result<std::collections::HashMap<String, HeaderValue>, NpyError> {
    #[derive(Debug, PartialEq)]
    enum Tok {
        Punct(char),
        Str(String),
        Word(String),
    }
    let bad = |m: &str| NpyError::Format(format!("bad header: {m}"));
    let mut toks = Vec::new();
    let mut chars = h.char_indices().peekable();
    while let Some((_, c)) = chars.next() {
        match c {
            c if c.is_whitespace() => {}
            '{' | '}' | '(' | ')' | ':' | ',' => toks.push(Tok::Punct(c)),
            '\'' | '"' => {
                let mut s = String::new();
                loop {
                    match chars.next() {
                        Some((_, ch)) if ch == c => break,
                        Some((_, '\\')) => match chars.next() {
                            Some((_, e)) => s.push(e),
                            None => return Err(bad("unterminated string")),
                        },
                        Some((_, ch)) => s.push(ch),
                        None => return Err(bad("unterminated string")),
                    }
                }
                toks.push(Tok::Str(s));
            }
            c if c.is_ascii_alphanumeric() || c == '_' => {
                let mut w = c.to_string();
                while let Some(&(_, n)) = chars.peek() {
                    if n.is_ascii_alphanumeric() || n == '_' {
                        w.push(n);
                        chars.next();
                    } else {
                        break;
                    }
                }
                toks.push(Tok::Word(w));
            }
            other => return Err(bad(&format!("unexpected `{other}`"))),
        }
    }
    let mut it = toks.into_iter().peekable();
    if it.next() != Some(Tok::Punct('{')) {
        return Err(bad("not a dict"));
    }
    let mut dict = std::collections::HashMap::new();
    loop {
        let key = match it.next() {
            Some(Tok::Punct('}')) => break,
            Some(Tok::Str(k)) => k,
            _ => return Err(bad("expected a quoted key")),
        };
        if it.next() != Some(Tok::Punct(':')) {
            return Err(bad("expected `:`"));
        }
        let value = match it.next() {
            Some(Tok::Str(s)) => HeaderValue::Str(s),
            Some(Tok::Word(w)) if w == "True" => HeaderValue::Bool(true),
            Some(Tok::Word(w)) if w == "False" => HeaderValue::Bool(false),
            Some(Tok::Punct('(')) => {
                let mut dims = Vec::new();
                loop {
                    match it.next() {
                        Some(Tok::Punct(')')) => break,
                        Some(Tok::Word(w)) => {
                            dims.push(w.parse::<usize>().map_err(|_| bad("bad shape"))?);
                            match it.next() {
                                Some(Tok::Punct(',')) => {}
                                Some(Tok::Punct(')')) => break,
                                _ => return Err(bad("bad shape")),
                            }
                        }
                        _ => return Err(bad("bad shape")),
                    }
                }
                HeaderValue::Tuple(dims)
            }
            _ => return Err(bad(&format!("bad value of '{key}'"))),
        };
        if dict.insert(key.clone(), value).is_some() {
            return Err(bad(&format!("'{key}' given twice")));
        }
        match it.next() {
            Some(Tok::Punct(',')) => {}
            Some(Tok::Punct('}')) => break,
            _ => return Err(bad("expected `,` or `}`")),
        }
    }
    if it.next().is_some() {
        return Err(bad("text after the dict"));
    }
    Ok(dict)
}

/// The checked header of a float32 C-order `.npy` v1 file: its shape, and
/// where the data starts.
fn header_shape(bytes: &[u8]) -> Result<(Vec<usize>, usize), NpyError> {
    header(bytes, false).map(|(s, start, _)| (s, start))
}

/// The shape, where the data start and the bytes of one value (`<f4`, or
/// `<f8` as well when `f64_too`).
fn header(bytes: &[u8], f64_too: bool) -> Result<(Vec<usize>, usize, u64), NpyError> {
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(NpyError::Format("missing \\x93NUMPY magic".into()));
    }
    if bytes[6] != 1 {
        return Err(NpyError::Unsupported(format!(
            "format version {}.{} (only 1.0)",
            bytes[6], bytes[7]
        )));
    }
    let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let data_start = 10 + hlen;
    if bytes.len() < data_start {
        return Err(NpyError::Format("truncated header".into()));
    }
    let header = std::str::from_utf8(&bytes[10..data_start])
        .map_err(|_| NpyError::Format("header is not ASCII".into()))?;
    let dict = parse_header(header)?;
    let width = match dict.get("descr") {
        Some(HeaderValue::Str(d)) if d == "<f4" => 4u64,
        Some(HeaderValue::Str(d)) if d == "<f8" && f64_too => 8,
        Some(HeaderValue::Str(d)) => {
            return Err(NpyError::Unsupported(format!(
                "dtype {d} (only little-endian float32 '<f4'{})",
                if f64_too { " or float64 '<f8'" } else { "" }
            )))
        }
        _ => return Err(NpyError::Format("header has no 'descr' string".into())),
    };
    match dict.get("fortran_order") {
        Some(HeaderValue::Bool(false)) => {}
        Some(HeaderValue::Bool(true)) => {
            return Err(NpyError::Unsupported("Fortran order (only C order)".into()))
        }
        _ => return Err(NpyError::Format("header has no 'fortran_order'".into())),
    }
    let Some(HeaderValue::Tuple(shape)) = dict.get("shape") else {
        return Err(NpyError::Format("header has no 'shape' tuple".into()));
    };
    // The declared shape is checked before anything is allocated for it.
    let fits = shape
        .iter()
        .try_fold(width, |a, &d| a.checked_mul(d as u64))
        .is_some_and(|b| b <= MAX_ARRAY_BYTES);
    if !fits {
        return Err(NpyError::Unsupported(format!(
            "shape {shape:?} holds more than {MAX_ARRAY_BYTES} bytes"
        )));
    }
    Ok((shape.clone(), data_start, width))
}

/// A float32 or float64 (`<f4`, `<f8`) `.npy` v1 file of any shape, as
/// f64 (LLFF's `poses_bounds.npy` is float64).
pub fn read_f64(path: impl AsRef<Path>) -> Result<(Vec<usize>, Vec<f64>), NpyError> {
    parse_f64(&read_limited(path.as_ref())?)
}

/// An array of `shape` holds at most `max_values` numbers.
pub fn check_values(shape: &[usize], max_values: u64) -> Result<(), NpyError> {
    let n = shape
        .iter()
        .try_fold(1u64, |a, &d| a.checked_mul(d as u64))
        .unwrap_or(u64::MAX);
    if n > max_values {
        return Err(NpyError::Unsupported(format!(
            "shape {shape:?} holds {n} numbers, more than {max_values}"
        )));
    }
    Ok(())
}

/// The shape declared by a `.npy` file's header, reading only the header.
pub fn read_shape(path: impl AsRef<Path>) -> Result<Vec<usize>, NpyError> {
    use std::io::Read;
    let file = sdfl_stdlib::files::open_regular(path.as_ref())?;
    let mut head = Vec::new();
    file.take(10 + u16::MAX as u64).read_to_end(&mut head)?;
    if head.len() >= 10 {
        let hlen = u16::from_le_bytes([head[8], head[9]]) as usize;
        head.truncate(10 + hlen);
    }
    header_shape(&head).map(|(s, _)| s)
}

/// A float32 array of any shape, C order.
#[derive(Debug, Clone, PartialEq)]
pub struct F32Array {
    /// The array's dimensions, outermost first.
    pub shape: Vec<usize>,
    /// The elements in C (row-major) order.
    pub data: Vec<f32>,
}

/// Parses the bytes of a float32 `.npy` v1 file of any shape.
pub fn parse_f32(bytes: &[u8]) -> Result<F32Array, NpyError> {
    let (shape, data_start) = header_shape(bytes)?;
    let shape_text = format!("{shape:?}");
    let n: usize = shape.iter().product();
    let data = &bytes[data_start..];
    if data.len() != n * 4 {
        return Err(NpyError::Format(format!(
            "expected {} data bytes for shape {shape_text}, found {}",
            n * 4,
            data.len()
        )));
    }
    Ok(F32Array {
        shape,
        data: data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
    })
}

/// Parses the bytes of an `(H, W, 3)` float32 `.npy` v1 file.
pub fn parse_rgb_f32(bytes: &[u8]) -> Result<RgbImage, NpyError> {
    let a = parse_f32(bytes)?;
    let (h, w) = match a.shape[..] {
        [h, w, 3] if h > 0 && w > 0 && h <= u32::MAX as usize && w <= u32::MAX as usize => (h, w),
        _ => {
            return Err(NpyError::Unsupported(format!(
                "shape {:?} (only (H, W, 3))",
                a.shape
            )))
        }
    };
    Ok(RgbImage {
        width: w as u32,
        height: h as u32,
        pixels: a.data.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect(),
    })
}

/// Reads array `key` (without `.npy`) from an `.npz` archive (stored or
/// deflated, as `np.savez`/`np.savez_compressed` write them).
pub fn read_npz_f32(path: impl AsRef<Path>, key: &str) -> Result<F32Array, NpyError> {
    parse_npz_f32(&read_limited(path.as_ref())?, key)
}

/// [`read_npz_f32`] on the archive's bytes.
pub fn parse_npz_f32(bytes: &[u8], key: &str) -> Result<F32Array, NpyError> {
    parse_npz_f32_at_most(bytes, key, u64::MAX)
}

/// [`parse_npz_f32`] refusing an array of more than `max_values` numbers
/// from its header, before the rest of the entry is inflated.
pub fn parse_npz_f32_at_most(
    bytes: &[u8],
    key: &str,
    max_values: u64,
) -> Result<F32Array, NpyError> {
    let mut zip = open_zip(std::io::Cursor::new(bytes))?;
    parse_f32(&entry_bytes(&mut zip, key, max_values, false)?)
}

fn open_zip<R: std::io::Read + std::io::Seek>(r: R) -> Result<zip::ZipArchive<R>, NpyError> {
    zip::ZipArchive::new(r).map_err(|e| NpyError::Format(format!("not a zip archive: {e}")))
}

/// The inflated bytes of the `.npy` entry `key` of an archive: refused
/// from the size the archive declares, and from the shape its header
/// declares (more than `max_values` numbers, of `<f4`, or `<f8` as well
/// when `f64_too`), before the rest is inflated.
fn entry_bytes<R: std::io::Read + std::io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    key: &str,
    max_values: u64,
    f64_too: bool,
) -> Result<Vec<u8>, NpyError> {
    use std::io::Read;
    let name = format!("{key}.npy");
    let mut entry = match zip.by_name(&name) {
        Ok(e) => e,
        Err(zip::result::ZipError::FileNotFound) => return Err(NpyError::MissingKey(key.into())),
        Err(e) => return Err(NpyError::Format(format!("bad archive entry {name}: {e}"))),
    };
    // A zip bomb is refused from the size the archive declares, before
    // anything is inflated; and the declared size may lie, so no more than
    // it is ever inflated.
    let limit = MAX_ARRAY_BYTES + 10 + u16::MAX as u64;
    let declared = entry.size();
    if declared > limit {
        return Err(NpyError::Unsupported(format!(
            "{name} declares {declared} bytes uncompressed (at most {limit})"
        )));
    }
    let mut buf = Vec::with_capacity(declared.min(1 << 24) as usize);
    let inflate_err = |e: std::io::Error| NpyError::Format(format!("cannot inflate {name}: {e}"));
    // The header first: an honestly declared but too large array is
    // refused before it is inflated.
    let head = declared.min(10 + u16::MAX as u64);
    (&mut entry)
        .take(head)
        .read_to_end(&mut buf)
        .map_err(inflate_err)?;
    if buf.len() >= 10 {
        let hlen = u16::from_le_bytes([buf[8], buf[9]]) as usize;
        // A header that does not parse is reported after the whole entry
        // is read, with the entry's other faults.
        if let Some(Ok((shape, _, _))) = buf.get(..10 + hlen).map(|h| header(h, f64_too)) {
            check_values(&shape, max_values)?;
        }
    }
    (&mut entry)
        .take(declared + 1 - buf.len() as u64)
        .read_to_end(&mut buf)
        .map_err(inflate_err)?;
    if buf.len() as u64 != declared {
        return Err(NpyError::Format(format!(
            "{name} inflates to {}{} bytes, but declares {declared}",
            if buf.len() as u64 > declared {
                "more than "
            } else {
                ""
            },
            buf.len().min(declared as usize)
        )));
    }
    Ok(buf)
}

/// A float32 or float64 `.npy` file's bytes as f64, with its shape.
fn parse_f64(bytes: &[u8]) -> Result<(Vec<usize>, Vec<f64>), NpyError> {
    let (shape, start, width) = header(bytes, true)?;
    let n: usize = shape.iter().product();
    let data = &bytes[start..];
    if data.len() as u64 != n as u64 * width {
        return Err(NpyError::Format(format!(
            "expected {} data bytes for shape {shape:?}, found {}",
            n as u64 * width,
            data.len()
        )));
    }
    let values = if width == 8 {
        data.chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
            .collect()
    } else {
        data.chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64)
            .collect()
    };
    Ok((shape, values))
}

/// An `.npz` archive (as `np.savez` writes it) whose float32 or float64
/// arrays are read by name, one at a time, as f64: for archives of many
/// small named arrays (IDR's `cameras_sphere.npz`), of which a reader
/// wants some.
pub struct Npz {
    zip: zip::ZipArchive<std::io::Cursor<Vec<u8>>>,
}

impl Npz {
    /// Reads the archive at `path`, refusing a file over `max_bytes`
    /// before reading it.
    pub fn read(path: impl AsRef<Path>, max_bytes: u64) -> Result<Npz, NpyError> {
        Npz::parse(read_at_most(path.as_ref(), max_bytes)?)
    }

    /// The archive of `bytes`.
    pub fn parse(bytes: Vec<u8>) -> Result<Npz, NpyError> {
        Ok(Npz {
            zip: open_zip(std::io::Cursor::new(bytes))?,
        })
    }

    /// The names of the arrays the archive holds (its `.npy` entries,
    /// without the extension), in the archive's order.
    pub fn keys(&self) -> Vec<&str> {
        self.zip
            .file_names()
            .filter_map(|n| n.strip_suffix(".npy"))
            .collect()
    }

    /// Array `key` as f64 with its shape; an array of more than
    /// `max_values` numbers is refused from its header, before it is
    /// inflated.
    pub fn read_f64(
        &mut self,
        key: &str,
        max_values: u64,
    ) -> Result<(Vec<usize>, Vec<f64>), NpyError> {
        parse_f64(&entry_bytes(&mut self.zip, key, max_values, true)?)
    }
}

/// A `.npy` v1 header for a little-endian, C-order array of `descr`
/// (`<f4`, `<f8`) and `shape`, padded so the data starts at a multiple of
/// 64 bytes.
pub fn encode_header(descr: &str, shape: &[usize]) -> Vec<u8> {
    let dims: String = match shape {
        [n] => format!("{n},"),
        _ => shape
            .iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", "),
    };
    let mut dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': ({dims}), }}");
    while (10 + dict.len() + 1) % 64 != 0 {
        dict.push(' ');
    }
    dict.push('\n');
    let mut out = Vec::with_capacity(10 + dict.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
}

/// Serialises an image as an `(H, W, 3)` `<f4` `.npy` v1 file.
pub fn encode_rgb_f32(img: &RgbImage) -> Vec<u8> {
    let mut out = encode_header("<f4", &[img.height as usize, img.width as usize, 3]);
    for p in &img.pixels {
        for v in p {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// Serialises `values` as a `<f8` `.npy` v1 file of `shape`.
pub fn encode_f64(shape: &[usize], values: &[f64]) -> Vec<u8> {
    debug_assert_eq!(values.len(), shape.iter().product::<usize>());
    let mut out = encode_header("<f8", shape);
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}
