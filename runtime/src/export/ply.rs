//! PLY files with vertex colours (binary little-endian, as MeshLab, Open3D
//! and Blender read them): triangle meshes with normals, and point clouds.

use super::{Cloud, ColouredMesh};

/// A mesh: `x y z nx ny nz` as float, `red green blue` as uchar per vertex;
/// triangles as `uchar` counts and `int` indices.
pub fn mesh_bytes(m: &ColouredMesh) -> Vec<u8> {
    let mesh = &m.mesh;
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by sdfl\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices.len(),
        mesh.triangles.len()
    )
    .into_bytes();
    out.reserve(mesh.vertices.len() * 27 + mesh.triangles.len() * 13);
    let grey = [128u8; 3];
    for (i, v) in mesh.vertices.iter().enumerate() {
        let n = mesh.normals.get(i).copied().unwrap_or([0.0; 3]);
        for x in v.iter().chain(&n) {
            out.extend_from_slice(&x.to_le_bytes());
        }
        out.extend_from_slice(m.colours.get(i).unwrap_or(&grey));
    }
    for t in &mesh.triangles {
        out.push(3);
        for i in t {
            out.extend_from_slice(&(*i as i32).to_le_bytes());
        }
    }
    out
}

/// A point cloud: `x y z` as float and `red green blue` as uchar per point.
pub fn cloud_bytes(c: &Cloud) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by sdfl\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        c.points.len()
    )
    .into_bytes();
    out.reserve(c.points.len() * 27);
    for ((p, n), col) in c.points.iter().zip(&c.normals).zip(&c.colours) {
        for x in p.iter().chain(n) {
            out.extend_from_slice(&x.to_le_bytes());
        }
        out.extend_from_slice(col);
    }
    out
}
