//! Minimal NumPy `.npy` reader/writer for RGB float32 images (the
//! assignment's `box_*.npy`): format version 1.0, little-endian `<f4`,
//! C order, shape `(H, W, 3)`. Anything else is rejected with an error.

use std::fmt;
use std::path::Path;

const MAGIC: &[u8] = b"\x93NUMPY";

/// An RGB float image, row-major from the top-left pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
}

/// Why a `.npy` file could not be read.
#[derive(Debug)]
pub enum NpyError {
    Io(std::io::Error),
    /// Not a `.npy` file, or a malformed header.
    Format(String),
    /// A valid `.npy` file this reader does not accept (dtype, order, shape, version).
    Unsupported(String),
}

impl fmt::Display for NpyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NpyError::Io(e) => write!(f, "cannot read .npy file: {e}"),
            NpyError::Format(m) => write!(f, "malformed .npy file: {m}"),
            NpyError::Unsupported(m) => write!(f, "unsupported .npy file: {m}"),
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
    parse_rgb_f32(&std::fs::read(path)?)
}

/// Value of `key` in the header dict: the text after `'key':` up to the
/// next top-level `,` or `}` (parentheses are kept together).
fn dict_value<'a>(header: &'a str, key: &str) -> Result<&'a str, NpyError> {
    let pat = format!("'{key}':");
    let start = header
        .find(&pat)
        .ok_or_else(|| NpyError::Format(format!("header has no '{key}'")))?
        + pat.len();
    let rest = &header[start..];
    let mut depth = 0i32;
    for (i, ch) in rest.char_indices() {
        match ch {
            '(' => depth += 1,
            ')' => depth -= 1,
            ',' | '}' if depth == 0 => return Ok(rest[..i].trim()),
            _ => {}
        }
        if depth < 0 {
            break;
        }
    }
    Err(NpyError::Format(format!("unterminated value of '{key}'")))
}

/// Parses the bytes of an `(H, W, 3)` float32 `.npy` v1 file.
pub fn parse_rgb_f32(bytes: &[u8]) -> Result<RgbImage, NpyError> {
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
    let descr = dict_value(header, "descr")?.trim_matches(|c| c == '\'' || c == '"');
    if descr != "<f4" {
        return Err(NpyError::Unsupported(format!(
            "dtype {descr} (only little-endian float32 '<f4')"
        )));
    }
    if dict_value(header, "fortran_order")? != "False" {
        return Err(NpyError::Unsupported("Fortran order (only C order)".into()));
    }
    let shape = dict_value(header, "shape")?;
    let dims: Vec<usize> = shape
        .trim_start_matches('(')
        .trim_end_matches(')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| NpyError::Format(format!("bad shape {shape}")))
        })
        .collect::<Result<_, _>>()?;
    let (h, w) = match dims[..] {
        [h, w, 3] if h > 0 && w > 0 && h <= u32::MAX as usize && w <= u32::MAX as usize => (h, w),
        _ => {
            return Err(NpyError::Unsupported(format!(
                "shape {shape} (only (H, W, 3))"
            )))
        }
    };
    let n = h
        .checked_mul(w)
        .and_then(|v| v.checked_mul(3))
        .ok_or_else(|| NpyError::Format("shape overflows".into()))?;
    let data = &bytes[data_start..];
    if data.len() != n * 4 {
        return Err(NpyError::Format(format!(
            "expected {} data bytes for shape {shape}, found {}",
            n * 4,
            data.len()
        )));
    }
    let pixels = data
        .chunks_exact(12)
        .map(|px| {
            let f = |k: usize| f32::from_le_bytes([px[k], px[k + 1], px[k + 2], px[k + 3]]);
            [f(0), f(4), f(8)]
        })
        .collect();
    Ok(RgbImage {
        width: w as u32,
        height: h as u32,
        pixels,
    })
}

/// Serialises an image as an `(H, W, 3)` `<f4` `.npy` v1 file.
pub fn encode_rgb_f32(img: &RgbImage) -> Vec<u8> {
    let mut header = format!(
        "{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}, 3), }}",
        img.height, img.width
    );
    // Pad with spaces so that the data starts at a multiple of 64, ending in '\n'.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + img.pixels.len() * 12);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for p in &img.pixels {
        for v in p {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> RgbImage {
        RgbImage {
            width: 3,
            height: 2,
            pixels: (0..6).map(|k| [k as f32, 0.5, -1.25 * k as f32]).collect(),
        }
    }

    #[test]
    fn round_trip() {
        let img = sample();
        let bytes = encode_rgb_f32(&img);
        assert_eq!(bytes.len() % 4, 0);
        assert_eq!(parse_rgb_f32(&bytes).unwrap(), img);
    }

    fn with_header(h: &str, data_len: usize) -> Vec<u8> {
        let mut b = MAGIC.to_vec();
        b.extend_from_slice(&[1, 0]);
        b.extend_from_slice(&(h.len() as u16).to_le_bytes());
        b.extend_from_slice(h.as_bytes());
        b.extend(std::iter::repeat_n(0u8, data_len));
        b
    }

    #[test]
    fn rejects_everything_else() {
        let bad = [
            with_header("{'descr': '>f4', 'fortran_order': False, 'shape': (2, 3, 3), }", 72),
            with_header("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3, 3), }", 144),
            with_header("{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3, 3), }", 72),
            with_header("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }", 24),
            with_header("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 4), }", 96),
            with_header("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 3), }", 71),
            with_header("{'descr': '<f4', 'fortran_order': False, 'shape': (2, x, 3), }", 72),
            with_header("{'descr': '<f4', 'fortran_order': False, 'shape': (0, 3, 3), }", 0),
            with_header("{'descr': '<f4', 'shape': (2, 3, 3), }", 72),
            with_header("{'descr': '<f4', 'fortran_order': False, 'shape': (99999999999, 99999999999, 3), }", 0),
            b"NUMPY".to_vec(),
            Vec::new(),
        ];
        for b in &bad {
            assert!(parse_rgb_f32(b).is_err());
        }
        let mut v2 = encode_rgb_f32(&sample());
        v2[6] = 2;
        assert!(matches!(parse_rgb_f32(&v2), Err(NpyError::Unsupported(_))));
        let mut trunc = encode_rgb_f32(&sample());
        trunc.truncate(20);
        assert!(parse_rgb_f32(&trunc).is_err());
        assert!(matches!(
            read_rgb_f32("/nonexistent/x.npy"),
            Err(NpyError::Io(_))
        ));
    }
}
