//! Writing a statement's field exports: density meshes, point clouds and
//! per-view depth, atomically through `crate::output`.

use std::io;
use std::path::Path;
use std::time::Instant;

use glam::DAffine3;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::value::{CloudCrop, MeshRegion, Output, OutputKind, Sampler};

use super::{depth, ply, RadianceField};
use crate::mesh::{MeshGrid, MeshStats};
use crate::output::{write_bytes, write_png};
use crate::output::{Written, WrittenKind};
use crate::volume::{ImageSize, Stratified};

/// What the field exports of one statement need besides the field.
pub struct ExportContext<'a> {
    /// The output directory.
    pub out_dir: &'a Path,
    /// Where samples fall along each ray.
    pub sampler: &'a Sampler,
    /// The views per-view outputs (depth) are rendered from, at `size`.
    pub cameras: &'a [Camera],
    /// Image size of `cameras`' views.
    pub size: (u32, u32),
    /// The cameras a point cloud casts rays from (the training views, each
    /// with its own image size).
    pub ray_views: &'a [(Camera, ImageSize)],
    /// The region `bounds: "auto"` stands for.
    pub auto_region: Option<([f64; 3], [f64; 3])>,
    /// The object's region in the field's frame, where a point cloud with
    /// `crop: "auto"` keeps its points (none: everywhere).
    pub object_region: Option<([f64; 3], [f64; 3])>,
    /// Seed of the point cloud's rays.
    pub seed: u64,
    /// From the field's frame into the data's own: positions of meshes
    /// and point clouds are moved by it, depths (lengths along the ray)
    /// scaled by it.
    pub to_data: DAffine3,
    /// Told what is being written, for progress.
    pub status: &'a (dyn Fn(&str) + Sync),
    /// A view's ray ends as the field renders it, skipping empty space
    /// (a trained NeRF's); `None`: depth outputs march every sample.
    pub ray_ends: Option<&'a RayEnds<'a>>,
}

/// A view's ray ends from `camera` at a size, as a field renders it.
pub type RayEnds<'a> = dyn Fn(&Camera, ImageSize) -> Result<Vec<super::RayEnd>, String> + Sync + 'a;

fn invalid(e: impl std::fmt::Display) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, e.to_string())
}

/// Writes the field exports among `outputs`; the others are left to the
/// caller.
pub fn write_field_exports(
    field: &dyn RadianceField,
    outputs: &[Output],
    cx: &ExportContext,
) -> io::Result<Vec<Written>> {
    let mut written = Vec::new();
    if !outputs.iter().any(|o| o.kind.field_export()) {
        return Ok(written);
    }
    let strat = Stratified::new(
        cx.sampler.samples,
        cx.sampler.near as f32,
        cx.sampler.far as f32,
    )
    .map_err(invalid)?;
    let last = cx.sampler.last_interval;
    for o in outputs {
        let t = Instant::now();
        if matches!(
            o.kind,
            OutputKind::DensityMesh { .. } | OutputKind::PointCloud { .. }
        ) {
            (cx.status)(&format!("writing {}", o.path.display()));
        }
        let path = cx.out_dir.join(&o.path);
        let named = |e: &dyn std::fmt::Display| invalid(format!("`{}`: {e}", o.path.display()));
        match o.kind {
            OutputKind::DensityMesh {
                level,
                resolution,
                region,
            } => {
                let (min, max) = match region {
                    MeshRegion::Box { min, max } => (min, max),
                    MeshRegion::Auto => cx
                        .auto_region
                        .ok_or_else(|| named(&"the field has no bounds: give the mesh `bounds`"))?,
                };
                let grid = MeshGrid::covering(min, max, resolution);
                let m = super::density_mesh(
                    field,
                    level as f32,
                    &grid,
                    sdfl_stdlib::work::MAX_MESH_VERTICES,
                    &cx.to_data,
                )
                .map_err(|e| named(&e))?;
                write_bytes(&path, &ply::mesh_bytes(&m))?;
                written.push(Written {
                    path: o.path.clone(),
                    kind: WrittenKind::DensityMesh,
                    width: 0,
                    height: 0,
                    frames: 0,
                    mesh: Some(MeshStats {
                        vertices: m.mesh.vertices.len(),
                        triangles: m.mesh.triangles.len(),
                        resolution,
                        cell: grid.step,
                        area: m.mesh.area(),
                        seconds: t.elapsed().as_secs_f64(),
                    }),
                    warning: None,
                });
            }
            OutputKind::PointCloud {
                points,
                min_opacity,
                crop,
            } => {
                let crop = match crop {
                    CloudCrop::None => super::Crop::None,
                    CloudCrop::Auto => cx.object_region.map_or(super::Crop::None, |(min, max)| {
                        super::Crop::Field { min, max }
                    }),
                    CloudCrop::Box { min, max } => super::Crop::Data { min, max },
                };
                let cloud = super::point_cloud(
                    field,
                    cx.ray_views,
                    super::CloudSettings {
                        count: points as usize,
                        min_opacity: min_opacity as f32,
                        rays_per_point: sdfl_stdlib::work::CLOUD_RAYS_PER_POINT as usize,
                        crop,
                        seed: cx.seed,
                    },
                    &strat,
                    last,
                    &cx.to_data,
                )
                .map_err(|e| named(&e))?;
                write_bytes(&path, &ply::cloud_bytes(&cloud))?;
                // A cloud has vertices and no triangles.
                written.push(Written {
                    path: o.path.clone(),
                    kind: WrittenKind::PointCloud,
                    width: 0,
                    height: 0,
                    frames: 0,
                    mesh: Some(MeshStats {
                        vertices: cloud.points.len(),
                        triangles: 0,
                        resolution: 0,
                        cell: 0.0,
                        area: 0.0,
                        seconds: t.elapsed().as_secs_f64(),
                    }),
                    warning: None,
                });
            }
            _ => {}
        }
    }
    // Depth: one march per view serves every depth output.
    let depths: Vec<&Output> = outputs.iter().filter(|o| o.kind.depth_export()).collect();
    if depths.is_empty() {
        return Ok(written);
    }
    let (w, h) = cx.size;
    let size = ImageSize {
        width: w,
        height: h,
    };
    let n = cx.cameras.len();
    // The field's lengths in the data's units: `to_data` is a similarity,
    // so any axis's stretch (exactly 1 without a normalisation, which
    // leaves depths' bits alone).
    let unit = cx.to_data.matrix3.x_axis.length() as f32;
    let depth_values = |ends: &[super::RayEnd], min_opacity: f64| {
        let mut d = depth::depth_values(ends, min_opacity as f32);
        if unit != 1.0 {
            d.iter_mut().for_each(|v| *v *= unit);
        }
        d
    };
    let names: Vec<String> = depths
        .iter()
        .map(|o| o.path.display().to_string())
        .collect();
    for (k, cam) in cx.cameras.iter().enumerate() {
        (cx.status)(&format!(
            "depth of view {} of {n} for {}",
            k + 1,
            names.join(", ")
        ));
        let ends = match cx.ray_ends {
            Some(rendered) => rendered(cam, size).map_err(invalid)?,
            None => super::render_ends(field, cam, size, &strat, last).map_err(invalid)?,
        };
        for o in &depths {
            let rel = sdfl_stdlib::outputs::view_path(&o.path, k, n);
            let path = cx.out_dir.join(&rel);
            let (kind, pw, ph) = match o.kind {
                OutputKind::RawDepth { min_opacity } => {
                    let d = depth_values(&ends, min_opacity);
                    write_bytes(&path, &depth::npy_bytes(&d, h as usize, w as usize))?;
                    (WrittenKind::RawDepth, w, h)
                }
                OutputKind::DepthMap {
                    colormap,
                    range,
                    min_opacity,
                } => {
                    let d = depth_values(&ends, min_opacity);
                    let r = depth::depth_range(&d, range);
                    let (pw, ph, rgb) =
                        depth::depth_map(&d, (w, h), colormap, r).map_err(invalid)?;
                    write_png(&path, pw, ph, &rgb)?;
                    (WrittenKind::DepthMap, pw, ph)
                }
                _ => continue,
            };
            written.push(Written {
                path: rel,
                kind,
                width: pw,
                height: ph,
                frames: 1,
                mesh: None,
                warning: None,
            });
        }
    }
    Ok(written)
}
