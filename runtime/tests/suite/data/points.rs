//! Point clouds read from every format alike, hostile files refused, the
//! assignment's bunny.

use sdfl_runtime::data::points::*;
use std::path::Path;

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

/// Elements before `vertex` (faces here, with list properties) were
/// read as vertices: the face "3 0 1 2" became the point (3, 0, 1).
/// They are skipped, by their list counts, ASCII and binary.
#[test]
fn elements_are_read_in_header_order() {
    let dir = tempfile::tempdir().unwrap();
    let want = vec![[0.5f32, -1.0, 2.0], [3.25, 0.0, -0.125], [1.0, 1.0, 1.0]];
    let ascii = "ply\nformat ascii 1.0\ncomment faces first\nelement face 2\nproperty list uchar int vertex_indices\nproperty uchar flags\nelement vertex 3\nproperty uchar red\nproperty float z\nproperty float x\nproperty float y\nend_header\n3 0 1 2 7\n4 0 1 2 0\n9\n9 2 0.5 -1 5 -0.125 3.25 0 6 1 1 1\n";
    let mut binary = b"ply\nformat binary_little_endian 1.0\nelement edge 2\nproperty int a\nproperty int b\nelement face 2\nproperty list uchar int vertex_indices\nelement vertex 3\nproperty float x\nproperty double y\nproperty float z\nelement face2 1\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
    binary.extend([7u8; 16]); // two edges
    for n in [3u8, 4] {
        binary.push(n);
        binary.extend((0..n as i32).flat_map(|i| i.to_le_bytes()));
    }
    for p in &want {
        binary.extend(p[0].to_le_bytes());
        binary.extend((p[1] as f64).to_le_bytes());
        binary.extend(p[2].to_le_bytes());
    }
    binary.extend([3, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0]);
    for (name, bytes) in [("a.ply", ascii.as_bytes().to_vec()), ("b.ply", binary)] {
        assert_eq!(
            read_points(&write(dir.path(), name, &bytes)).unwrap(),
            want,
            "{name}"
        );
    }
    // A list whose count runs past the end, a negative count.
    for (name, bytes) in [
        ("c.ply", b"ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list uint int v\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n\xff\xff\xff\xff".to_vec()),
        ("d.ply", b"ply\nformat ascii 1.0\nelement face 1\nproperty list char int v\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n-1 1 2 3\n".to_vec()),
        ("e.ply", b"ply\nformat binary_little_endian 1.0\nelement face 4000000000\nproperty int v\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec()),
    ] {
        let e = read_points(&write(dir.path(), name, &bytes)).unwrap_err().to_string();
        assert!(e.contains(name) && e.contains("face"), "{name}: {e}");
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
        ("v.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float y\nproperty float x\nproperty float w\nend_header\n1 2 3\n".to_vec()),
        ("w.xyz", b"1 2 nan\n".to_vec()),
        ("x.xyz", b"1 2\n".to_vec()),
        ("y.xyz", b"".to_vec()),
        ("z.obj", b"v 1 2 3\n".to_vec()),
    ] {
        let e = read_points(&write(dir.path(), name, &bytes)).unwrap_err().to_string();
        assert!(e.contains(name), "{name}: {e}");
    }
}
