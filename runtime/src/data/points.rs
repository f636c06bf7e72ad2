//! Point clouds: `.npz` (array `verts`, as the course assignment's bunny),
//! `.npy` (float32 N × 3), PLY (ASCII or binary little-endian, the vertex
//! element's `x y z`) and plain text (`x y z` per line). Regular files
//! only, sizes capped, every coordinate finite; errors name the file.

use std::io::{self, Read};
use std::path::Path;

use super::image::open_regular;
use super::npy::{parse_f32, parse_npz_f32_at_most, F32Array};

/// Most points a cloud may hold.
pub const MAX_POINTS: usize = 10_000_000;
/// Most bytes read from a point file.
const MAX_BYTES: u64 = 1 << 30;

fn bad(path: &Path, what: impl std::fmt::Display) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("{}: {what}", path.display()),
    )
}

/// The points of `path`, by its extension.
pub fn read_points(path: &Path) -> io::Result<Vec<[f32; 3]>> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    // An array's header says how many points it holds: too many are
    // refused before the file is read.
    let max_values = 3 * MAX_POINTS as u64;
    if ext == "npy" {
        let shape = super::npy::read_shape(path).map_err(|e| bad(path, e))?;
        super::npy::check_values(&shape, max_values).map_err(|e| bad(path, e))?;
    }
    let mut bytes = Vec::new();
    open_regular(path)?
        .take(MAX_BYTES + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > MAX_BYTES {
        return Err(bad(path, format!("larger than {MAX_BYTES} bytes")));
    }
    let points = match ext.as_str() {
        "npz" => {
            rows(parse_npz_f32_at_most(&bytes, "verts", max_values).map_err(|e| bad(path, e))?)
        }
        "npy" => rows(parse_f32(&bytes).map_err(|e| bad(path, e))?),
        "ply" => parse_ply(&bytes),
        "xyz" | "txt" => parse_text(&bytes),
        other => Err(format!(
            "unknown point file type `.{other}`: use .npz (verts), .npy, .ply or .xyz"
        )),
    }
    .map_err(|e| bad(path, e))?;
    if points.is_empty() {
        return Err(bad(path, "holds no points"));
    }
    if points.len() > MAX_POINTS {
        return Err(bad(path, format!("more than {MAX_POINTS} points")));
    }
    if let Some(i) = points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        return Err(bad(
            path,
            format!("point {i} is {:?}, not finite", points[i]),
        ));
    }
    Ok(points)
}

fn rows(a: F32Array) -> Result<Vec<[f32; 3]>, String> {
    match a.shape.as_slice() {
        [_, 3] => Ok(a.data.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect()),
        s => Err(format!("points must be an N × 3 array, not {s:?}")),
    }
}

fn parse_text(bytes: &[u8]) -> Result<Vec<[f32; 3]>, String> {
    let text = std::str::from_utf8(bytes).map_err(|_| "not UTF-8 text".to_string())?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f32> = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|s| !s.is_empty())
            .take(3)
            .map(|s| s.parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("line {}: not three numbers", n + 1))?;
        if v.len() < 3 {
            return Err(format!("line {}: not three numbers", n + 1));
        }
        out.push([v[0], v[1], v[2]]);
        if out.len() > MAX_POINTS {
            break;
        }
    }
    Ok(out)
}

/// A PLY property: a scalar, or a list (its count's type, its items').
#[derive(Debug)]
enum PlyProp {
    Scalar(Scalar, String),
    List(Scalar, Scalar),
}

/// A PLY scalar type.
#[derive(Debug, Clone, Copy)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(t: &str) -> Result<Scalar, String> {
        Ok(match t {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            t => return Err(format!("unknown property type `{t}`")),
        })
    }
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
    /// The little-endian value at the start of `b` (at least `size` bytes).
    fn read_le(self, b: &[u8]) -> f64 {
        match self {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(b[..8].try_into().expect("8 bytes")),
        }
    }
}

/// A PLY element: its name, count and properties, in header order.
#[derive(Debug)]
struct PlyElement {
    name: String,
    count: u64,
    props: Vec<PlyProp>,
}

/// Where a PLY header's `end_header` line starts, and where the body
/// starts: right after that line's newline, `\n` or `\r\n` (Windows tools
/// write CRLF headers). Whole lines from the top, so the search stops at
/// the header and never reads a binary body as text.
fn header_end(bytes: &[u8]) -> Option<(usize, usize)> {
    let mut start = 0;
    while start < bytes.len() {
        let nl = start + bytes[start..].iter().position(|&b| b == b'\n')?;
        let line = &bytes[start..nl];
        if line.trim_ascii_end() == b"end_header" {
            return Some((start, nl + 1));
        }
        start = nl + 1;
    }
    None
}

/// PLY (ASCII or binary little-endian): the `x y z` properties of the
/// `vertex` element. Every element is read in the header's order and those
/// other than `vertex` (faces, edges, anything) are skipped, list
/// properties by their counts, so nothing else is ever read as a vertex.
fn parse_ply(bytes: &[u8]) -> Result<Vec<[f32; 3]>, String> {
    let (end, body_at) = header_end(bytes).ok_or("no `end_header` line: not a PLY file")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "the PLY header is not text")?;
    let body = &bytes[body_at..];
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err("not a PLY file".into());
    }
    let mut format = None;
    let mut elements: Vec<PlyElement> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, _] => format = Some(f.to_string()),
            ["element", name, n] => elements.push(PlyElement {
                name: name.to_string(),
                count: n
                    .parse()
                    .map_err(|_| format!("bad count of element `{name}`"))?,
                props: Vec::new(),
            }),
            ["property", rest @ ..] => {
                let e = elements.last_mut().ok_or("a property before any element")?;
                e.props.push(match rest {
                    ["list", count, item, _] => {
                        PlyProp::List(Scalar::parse(count)?, Scalar::parse(item)?)
                    }
                    [ty, name] => PlyProp::Scalar(Scalar::parse(ty)?, name.to_string()),
                    _ => return Err(format!("bad property line `{line}`")),
                });
            }
            ["element", ..] => return Err(format!("bad element line `{line}`")),
            _ => {}
        }
    }
    let Some(v) = elements.iter().position(|e| e.name == "vertex") else {
        return Err("no vertex element".into());
    };
    if elements[v].count > MAX_POINTS as u64 {
        return Err(format!("more than {MAX_POINTS} points"));
    }
    // Where x, y and z are among the vertex's properties.
    let mut xyz = [usize::MAX; 3];
    for (k, p) in elements[v].props.iter().enumerate() {
        match p {
            PlyProp::Scalar(_, n) => {
                if let Some(i) = ["x", "y", "z"].iter().position(|a| a == n) {
                    xyz[i] = k;
                }
            }
            PlyProp::List(..) => return Err("list properties on vertices are not supported".into()),
        }
    }
    if xyz.contains(&usize::MAX) {
        return Err("the vertex element has no x, y and z properties".into());
    }
    let mut out = Vec::with_capacity(elements[v].count as usize);
    match format.as_deref() {
        Some("ascii") => {
            let text = std::str::from_utf8(body).map_err(|_| "the PLY body is not text")?;
            let mut words = text.split_ascii_whitespace();
            let mut number = |what: &str| -> Result<f64, String> {
                let w = words
                    .next()
                    .ok_or_else(|| format!("the file ends inside the {what} element"))?;
                w.parse()
                    .map_err(|_| format!("`{w}` in the {what} element is not a number"))
            };
            let mut row = Vec::new();
            for (i, e) in elements.iter().enumerate() {
                if e.props.is_empty() {
                    continue;
                }
                for _ in 0..e.count {
                    row.clear();
                    for p in &e.props {
                        match p {
                            PlyProp::Scalar(..) => row.push(number(&e.name)?),
                            PlyProp::List(..) => {
                                let n = number(&e.name)?;
                                if !(n >= 0.0 && n.fract() == 0.0) {
                                    return Err(format!(
                                        "a list count of the {} element is {n}",
                                        e.name
                                    ));
                                }
                                for _ in 0..n as u64 {
                                    number(&e.name)?;
                                }
                            }
                        }
                    }
                    if i == v {
                        out.push(xyz.map(|k| row[k] as f32));
                    }
                }
                if i == v {
                    break;
                }
            }
            Ok(out)
        }
        Some("binary_little_endian") => {
            let short = |e: &PlyElement| format!("the file ends inside the {} element", e.name);
            let mut at = 0usize;
            for (i, e) in elements.iter().enumerate() {
                let fixed = e.props.iter().all(|p| matches!(p, PlyProp::Scalar(..)));
                if fixed && i != v {
                    // Skipped at once: no loop over a huge count.
                    let stride: u64 = e
                        .props
                        .iter()
                        .map(|p| match p {
                            PlyProp::Scalar(t, _) => t.size() as u64,
                            PlyProp::List(..) => 0,
                        })
                        .sum();
                    let len = stride
                        .checked_mul(e.count)
                        .filter(|&l| l <= (body.len() - at) as u64)
                        .ok_or_else(|| short(e))?;
                    at += len as usize;
                    continue;
                }
                let mut row = Vec::new();
                for _ in 0..e.count {
                    row.clear();
                    for p in &e.props {
                        let (t, n) = match p {
                            PlyProp::Scalar(t, _) => (*t, None),
                            PlyProp::List(c, t) => {
                                let b = body.get(at..at + c.size()).ok_or_else(|| short(e))?;
                                at += c.size();
                                let n = c.read_le(b);
                                if n < 0.0 {
                                    return Err(format!(
                                        "a list count of the {} element is {n}",
                                        e.name
                                    ));
                                }
                                (*t, Some(n as u64))
                            }
                        };
                        match n {
                            None => {
                                let b = body.get(at..at + t.size()).ok_or_else(|| short(e))?;
                                row.push(t.read_le(b));
                                at += t.size();
                            }
                            Some(n) => {
                                let len = (t.size() as u64)
                                    .checked_mul(n)
                                    .filter(|&l| l <= (body.len() - at) as u64)
                                    .ok_or_else(|| short(e))?;
                                at += len as usize;
                            }
                        }
                    }
                    if i == v {
                        out.push(xyz.map(|k| row[k] as f32));
                    }
                }
                if i == v {
                    break;
                }
            }
            Ok(out)
        }
        Some(f) => Err(format!(
            "PLY format `{f}` is not supported (ascii or binary_little_endian)"
        )),
        None => Err("no format line".into()),
    }
}
