//! Point clouds: `.npz` (array `verts`, as the course assignment's bunny),
//! `.npy` (float32 N × 3), PLY (ASCII or binary little-endian, `x y z` the
//! first vertex properties) and plain text (`x y z` per line). Regular files
//! only, sizes capped, every coordinate finite; errors name the file.

use std::io::{self, Read};
use std::path::Path;

use super::image::open_regular;
use super::npy::{parse_f32, parse_npz_f32, F32Array};

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
    let mut bytes = Vec::new();
    open_regular(path)?
        .take(MAX_BYTES + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > MAX_BYTES {
        return Err(bad(path, format!("larger than {MAX_BYTES} bytes")));
    }
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let points = match ext.as_str() {
        "npz" => rows(parse_npz_f32(&bytes, "verts").map_err(|e| bad(path, e))?),
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

/// PLY with a `vertex` element whose first three properties are `x y z`
/// floats (ASCII, or binary little-endian with float/double properties).
fn parse_ply(bytes: &[u8]) -> Result<Vec<[f32; 3]>, String> {
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or("no `end_header` line: not a PLY file")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "the PLY header is not text")?;
    let body = &bytes[end + 11..];
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err("not a PLY file".into());
    }
    let (mut format, mut count, mut props) = (None, None, Vec::new());
    let mut in_vertex = false;
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, _] => format = Some(f.to_string()),
            ["element", "vertex", n] => {
                count = Some(n.parse::<usize>().map_err(|_| "bad vertex count")?);
                in_vertex = true;
            }
            ["element", ..] => in_vertex = false,
            ["property", ty, name] if in_vertex => props.push((ty.to_string(), name.to_string())),
            ["property", ..] if in_vertex => {
                return Err("list properties on vertices are not supported".into())
            }
            _ => {}
        }
    }
    let count = count.ok_or("no vertex element")?;
    if count > MAX_POINTS {
        return Err(format!("more than {MAX_POINTS} points"));
    }
    let names: Vec<&str> = props.iter().map(|p| p.1.as_str()).collect();
    if names.len() < 3 || names[..3] != ["x", "y", "z"] {
        return Err("the vertex properties must start with x y z".into());
    }
    match format.as_deref() {
        Some("ascii") => {
            let text = std::str::from_utf8(body).map_err(|_| "the PLY body is not text")?;
            let mut out = Vec::with_capacity(count);
            for line in text.lines().filter(|l| !l.trim().is_empty()).take(count) {
                let v: Vec<f32> = line
                    .split_whitespace()
                    .take(3)
                    .map(str::parse)
                    .collect::<Result<_, _>>()
                    .map_err(|_| "a vertex line is not numbers")?;
                if v.len() < 3 {
                    return Err("a vertex line has fewer than three numbers".into());
                }
                out.push([v[0], v[1], v[2]]);
            }
            if out.len() < count {
                return Err(format!("{count} vertices declared, {} found", out.len()));
            }
            Ok(out)
        }
        Some("binary_little_endian") => {
            let sizes: Vec<usize> = props
                .iter()
                .map(|(ty, _)| match ty.as_str() {
                    "float" | "float32" | "int" | "uint" | "int32" | "uint32" => Ok(4),
                    "double" | "float64" => Ok(8),
                    "char" | "uchar" | "int8" | "uint8" => Ok(1),
                    "short" | "ushort" | "int16" | "uint16" => Ok(2),
                    t => Err(format!("unknown property type `{t}`")),
                })
                .collect::<Result<_, _>>()?;
            let stride: usize = sizes.iter().sum();
            if body.len() < stride * count {
                return Err(format!("{count} vertices declared, the file is shorter"));
            }
            let read = |at: &[u8], ty: &str| -> Result<f32, String> {
                Ok(match ty {
                    "float" | "float32" => f32::from_le_bytes(at[..4].try_into().expect("4 bytes")),
                    "double" | "float64" => {
                        f64::from_le_bytes(at[..8].try_into().expect("8 bytes")) as f32
                    }
                    t => return Err(format!("x, y and z must be float or double, not `{t}`")),
                })
            };
            (0..count)
                .map(|i| {
                    let row = &body[i * stride..];
                    let mut at = 0;
                    let mut p = [0f32; 3];
                    for (k, slot) in p.iter_mut().enumerate() {
                        *slot = read(&row[at..], &props[k].0)?;
                        at += sizes[k];
                    }
                    Ok(p)
                })
                .collect()
        }
        Some(f) => Err(format!(
            "PLY format `{f}` is not supported (ascii or binary_little_endian)"
        )),
        None => Err("no format line".into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    #[test]
    fn reads_every_format_alike() {
        let dir = tempfile::tempdir().unwrap();
        let want = vec![[0.5f32, -1.0, 2.0], [3.25, 0.0, -0.125]];
        let ascii = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nend_header\n0.5 -1 2 7\n3.25 0 -0.125 9\n";
        let mut binary = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty double z\nproperty uchar red\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
        for p in &want {
            binary.extend(p[0].to_le_bytes());
            binary.extend(p[1].to_le_bytes());
            binary.extend((p[2] as f64).to_le_bytes());
            binary.push(1);
        }
        for (name, bytes) in [
            ("a.ply", ascii.as_bytes().to_vec()),
            ("b.ply", binary),
            ("c.xyz", b"# x y z\n0.5 -1 2\n3.25, 0, -0.125\n".to_vec()),
        ] {
            assert_eq!(
                read_points(&write(dir.path(), name, &bytes)).unwrap(),
                want,
                "{name}"
            );
        }
    }

    #[test]
    fn the_assignment_bunny_has_ten_thousand_points() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data/assignment3/bunny_pointcloud.npz");
        if !p.exists() {
            return; // the shared data is not part of every checkout
        }
        let pts = read_points(&p).unwrap();
        assert_eq!(pts.len(), 10_000);
    }

    #[test]
    fn hostile_files_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        for (name, bytes) in [
            ("t.ply", b"ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n".to_vec()),
            ("u.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec()),
            ("v.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float y\nproperty float x\nproperty float z\nend_header\n1 2 3\n".to_vec()),
            ("w.xyz", b"1 2 nan\n".to_vec()),
            ("x.xyz", b"1 2\n".to_vec()),
            ("y.xyz", b"".to_vec()),
            ("z.obj", b"v 1 2 3\n".to_vec()),
        ] {
            let e = read_points(&write(dir.path(), name, &bytes)).unwrap_err().to_string();
            assert!(e.contains(name), "{name}: {e}");
        }
    }
}
