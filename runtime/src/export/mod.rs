//! Exports from any radiance field (a NeRF, a hash grid, an analytic SDF
//! field): a mesh where the density reaches a level, a coloured point
//! cloud where the cameras' rays end, raw and colour-mapped depth, and the
//! camera paths a trained model is rendered along.
//!
//! Every export asks the field the same thing, density and colour at
//! points seen along directions ([`RadianceField`]), and marches its own
//! rays ([`march_rays`]): stratified samples, weights from densities (or an
//! opacity field's per-sample opacities), and per ray the composited
//! colour, the expected depth `Σ wᵢtᵢ` and the accumulated opacity `Σ wᵢ`.
//! Positions are mapped into the data's own frame by a `DAffine3` (the
//! identity where the data had no normalisation).

use glam::{DAffine3, DVec3};
use rayon::prelude::*;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::value::LastInterval;

use crate::mesh::{DistanceField, Mesh, MeshGrid};
use crate::volume::composite::{weights_from_density, weights_from_opacity};
use crate::volume::march::intervals_into;
use crate::volume::rays::pixel_ray;
use crate::volume::{DensityModel, ImageSize, Ray, SplitMix64, Stratified, VolumeError};

pub mod depth;
pub mod normals;
/// nerfstudio's `camera_path.json`, read when the file is evaluated.
pub use sdfl_stdlib::camera_path as paths;
pub mod ply;
pub mod write;

/// Samples a network pass evaluates at most (its buffers grow with it).
pub(crate) const NETWORK_ROWS: usize = 65_536;

/// A field that has density and colour everywhere.
pub trait RadianceField: Sync {
    /// Density (for [`Self::opacity_form`], a per-sample opacity) and colour
    /// at `points` seen along the unit directions `dirs`.
    fn query(
        &self,
        points: &[[f32; 3]],
        dirs: &[[f32; 3]],
        sigma: &mut [f32],
        rgb: &mut [[f32; 3]],
    );

    /// Whether `query` gives each sample's opacity (the assignment's opacity
    /// form) instead of a density per unit length.
    fn opacity_form(&self) -> bool {
        false
    }
}

/// An SDF with a colour seen as a volume under a density model.
pub struct Analytic<F> {
    /// Point → (signed distance, colour).
    pub field: F,
    /// How distance becomes density.
    pub model: DensityModel,
}

impl<F: Fn([f32; 3]) -> (f32, [f32; 3]) + Sync> RadianceField for Analytic<F> {
    fn query(&self, points: &[[f32; 3]], _: &[[f32; 3]], sigma: &mut [f32], rgb: &mut [[f32; 3]]) {
        let m = &self.model;
        let inv_beta = 1.0 / m.beta;
        points
            .par_iter()
            .zip(sigma.par_iter_mut().zip(rgb.par_iter_mut()))
            .with_min_len(256)
            .for_each(|(p, (s, c))| {
                let (d, col) = (self.field)(*p);
                *s = m.kind.sigma(d, m.alpha, inv_beta);
                *c = col;
            });
    }

    fn opacity_form(&self) -> bool {
        self.model.kind.per_sample_opacity()
    }
}

/// The end of one ray through a field.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RayEnd {
    /// `Σ wᵢcᵢ`, no background.
    pub colour: [f32; 3],
    /// `Σ wᵢtᵢ`: the expected depth, not yet divided by the opacity.
    pub depth: f32,
    /// `Σ wᵢ`, the accumulated opacity.
    pub opacity: f32,
}

impl RayEnd {
    /// The depth where the ray ends, `Σ wᵢtᵢ / Σ wᵢ`, where its opacity
    /// reaches `min_opacity` (and is not 0).
    pub fn surface_depth(&self, min_opacity: f32) -> Option<f32> {
        (self.opacity > 0.0 && self.opacity >= min_opacity)
            .then(|| self.depth / self.opacity)
            .filter(|d| d.is_finite())
    }

    /// The colour seen where it ends, `Σ wᵢcᵢ / Σ wᵢ`, in 0..1.
    pub fn surface_colour(&self) -> [f32; 3] {
        self.colour
            .map(|c| (c / self.opacity.max(1e-12)).clamp(0.0, 1.0))
    }
}

/// Marches `rays` through `field` at the stratified depths of `sampler`
/// (intervals closed by `last`), `chunk` rays at a time.
pub fn march_rays(
    field: &dyn RadianceField,
    rays: &[Ray],
    sampler: &Stratified,
    last: LastInterval,
) -> Result<Vec<RayEnd>, VolumeError> {
    sampler.validate()?;
    let t = sampler.depths();
    let mut delta = Vec::new();
    intervals_into(&t, last, &mut delta);
    let n = t.len();
    let per_chunk = (NETWORK_ROWS / n.max(1)).max(1);
    let mut ends = vec![RayEnd::default(); rays.len()];
    let (mut points, mut dirs) = (Vec::new(), Vec::new());
    let (mut sigma, mut rgb) = (Vec::new(), Vec::new());
    for (chunk, out) in rays.chunks(per_chunk).zip(ends.chunks_mut(per_chunk)) {
        points.clear();
        dirs.clear();
        for r in chunk {
            for &ti in &t {
                points.push(std::array::from_fn(|a| r.origin[a] + ti * r.dir[a]));
                dirs.push(r.dir);
            }
        }
        sigma.resize(points.len(), 0.0);
        rgb.resize(points.len(), [0.0; 3]);
        field.query(&points, &dirs, &mut sigma, &mut rgb);
        let opacity_form = field.opacity_form();
        out.par_iter_mut().enumerate().for_each(|(i, end)| {
            let (s, c) = (&sigma[i * n..(i + 1) * n], &rgb[i * n..(i + 1) * n]);
            let mut w = vec![0.0f32; n];
            // Non-finite densities (a diverged network) count as empty.
            let s: Vec<f32> = s
                .iter()
                .map(|x| if x.is_finite() { x.max(0.0) } else { 0.0 })
                .collect();
            let ok = if opacity_form {
                weights_from_opacity(&s, &mut w)
            } else {
                weights_from_density(&s, &delta, &mut w)
            };
            if ok.is_err() {
                return;
            }
            let mut e = RayEnd::default();
            for k in 0..n {
                for (colour, c) in e.colour.iter_mut().zip(c[k]) {
                    *colour += w[k] * c;
                }
                e.depth += w[k] * t[k];
                e.opacity += w[k];
            }
            *end = e;
        });
    }
    Ok(ends)
}

/// Every pixel's ray end of one view, row-major from the top-left pixel.
pub fn render_ends(
    field: &dyn RadianceField,
    cam: &Camera,
    size: ImageSize,
    sampler: &Stratified,
    last: LastInterval,
) -> Result<Vec<RayEnd>, VolumeError> {
    let rays = crate::volume::camera_rays(cam, size)?;
    march_rays(field, &rays, sampler, last)
}

/// A coloured point cloud with normals.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Cloud {
    /// Point positions.
    pub points: Vec<[f32; 3]>,
    /// Unit normal per point: fitted to its neighbours
    /// ([`normals::fit_planes`]), facing where the density falls, else the
    /// camera that saw it ([`normals::orient`]).
    pub normals: Vec<[f32; 3]>,
    /// Colour per point.
    pub colours: Vec<[u8; 3]>,
    /// Rays it took.
    pub rays: usize,
}

/// Which of a cloud's points are kept by where they are.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Crop {
    /// Every point.
    None,
    /// Points inside a box of the field's frame.
    Field {
        /// Its low corner.
        min: [f64; 3],
        /// Its high corner.
        max: [f64; 3],
    },
    /// Points inside a box of the data's frame.
    Data {
        /// Its low corner.
        min: [f64; 3],
        /// Its high corner.
        max: [f64; 3],
    },
}

impl Crop {
    /// Whether the point at `field` (the field's frame), `data` (the
    /// data's) is kept.
    fn keeps(&self, field: DVec3, data: DVec3) -> bool {
        let inside = |p: DVec3, min: &[f64; 3], max: &[f64; 3]| {
            (0..3).all(|a| p[a] >= min[a] && p[a] <= max[a])
        };
        match self {
            Crop::None => true,
            Crop::Field { min, max } => inside(field, min, max),
            Crop::Data { min, max } => inside(data, min, max),
        }
    }
}

/// What a point cloud keeps, and how hard it looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CloudSettings {
    /// Points to keep.
    pub count: usize,
    /// Opacity a ray needs for its point.
    pub min_opacity: f32,
    /// At most this many rays a point are cast.
    pub rays_per_point: usize,
    /// Where points are kept.
    pub crop: Crop,
    /// Seed of the rays' pixels.
    pub seed: u64,
}

/// Up to `count` points where rays through seeded random pixels of `views`
/// (each camera with its image size) end, where their opacity reaches
/// `min_opacity` inside `crop`; at most `rays_per_point · count` rays are
/// cast. Positions and normals are in the data's frame (`to_data`).
pub fn point_cloud(
    field: &dyn RadianceField,
    views: &[(Camera, ImageSize)],
    settings: CloudSettings,
    sampler: &Stratified,
    last: LastInterval,
    to_data: &DAffine3,
) -> Result<Cloud, VolumeError> {
    let CloudSettings {
        count,
        min_opacity,
        rays_per_point,
        crop,
        seed,
    } = settings;
    let mut cloud = Cloud::default();
    let views: Vec<&(Camera, ImageSize)> = views.iter().filter(|(_, s)| s.pixels() > 0).collect();
    if views.is_empty() {
        return Err(VolumeError::Invalid("no views to cast rays from".into()));
    }
    if views.iter().any(|(c, _)| !c.is_valid()) {
        return Err(VolumeError::InvalidCamera);
    }
    let budget = count.saturating_mul(rays_per_point.max(1));
    let batch = 16_384usize;
    let mut rng = SplitMix64::new(seed ^ 0x0c10_0d00);
    // Where each kept point was seen from, and the point, in the field's
    // frame (its normal's way round is found there).
    let (mut seen_from, mut at) = (Vec::new(), Vec::new());
    while cloud.points.len() < count && cloud.rays < budget {
        let n = batch.min(budget - cloud.rays);
        let rays: Vec<Ray> = (0..n)
            .map(|_| {
                let v = rng.below(views.len() as u64) as usize;
                let (cam, size) = views[v];
                let p = rng.below(size.pixels() as u64) as u32;
                pixel_ray(cam, *size, v as u32, p)
            })
            .collect();
        cloud.rays += n;
        let ends = march_rays(field, &rays, sampler, last)?;
        for (r, e) in rays.iter().zip(&ends) {
            if cloud.points.len() >= count {
                break;
            }
            let Some(d) = e.surface_depth(min_opacity) else {
                continue;
            };
            let origin = DVec3::from(r.origin.map(f64::from));
            let p = origin + DVec3::from(r.dir.map(f64::from)) * d as f64;
            let q = to_data.transform_point3(p);
            if !q.is_finite() || !crop.keeps(p, q) {
                continue;
            }
            cloud.points.push(q.as_vec3().to_array());
            seen_from.push(origin);
            at.push(p);
            cloud
                .colours
                .push(e.surface_colour().map(|c| (c * 255.0).round() as u8));
        }
    }
    let fits = normals::fit_planes(&cloud.points);
    let outward = density_descent(field, &at, &fits, to_data);
    let linear = to_data.matrix3;
    cloud.normals = fits
        .iter()
        .zip(&outward)
        .zip(at.iter().zip(&seen_from))
        .map(|((f, o), (p, s))| {
            let back = linear * (*s - *p);
            normals::orient(f, o.map(|o| o.to_array()), back.to_array())
        })
        .collect();
    Ok(cloud)
}

/// Per point (`at`, in the field's frame), the direction the density
/// falls fastest in the data's frame, by central differences over the
/// point's neighbour spacing; `None` where it is not finite.
fn density_descent(
    field: &dyn RadianceField,
    at: &[DVec3],
    fits: &[normals::Fitted],
    to_data: &DAffine3,
) -> Vec<Option<DVec3>> {
    let to_field = to_data.matrix3.inverse();
    // Normals move with the inverse transpose (a similarity: its rotation).
    let normal_to_data = to_field.transpose();
    let mut probes = Vec::with_capacity(6 * at.len());
    let mut steps = Vec::with_capacity(at.len());
    for (p, f) in at.iter().zip(fits) {
        // The data-frame spacing as a field-frame length (half of it: the
        // fit's scale, not beyond).
        let h = 0.5 * (to_field * DVec3::new(f.spacing, 0.0, 0.0)).length();
        let h = if h > 0.0 && h.is_finite() { h } else { 1e-3 };
        steps.push(h);
        for a in 0..3 {
            for sign in [1.0, -1.0] {
                let mut q = *p;
                q[a] += sign * h;
                probes.push(q.as_vec3().to_array());
            }
        }
    }
    let dirs = vec![[0.0, 0.0, 1.0]; probes.len()];
    let mut sigma = vec![0.0f32; probes.len()];
    let mut rgb = vec![[0.0f32; 3]; probes.len()];
    for ((p, d), (s, c)) in probes
        .chunks(NETWORK_ROWS)
        .zip(dirs.chunks(NETWORK_ROWS))
        .zip(
            sigma
                .chunks_mut(NETWORK_ROWS)
                .zip(rgb.chunks_mut(NETWORK_ROWS)),
        )
    {
        field.query(p, d, s, c);
    }
    sigma
        .chunks(6)
        .zip(&steps)
        .map(|(s, h)| {
            let gradient = DVec3::new(
                s[0] as f64 - s[1] as f64,
                s[2] as f64 - s[3] as f64,
                s[4] as f64 - s[5] as f64,
            ) / (2.0 * h);
            let out = normal_to_data * -gradient;
            (out.is_finite() && out.length_squared() > 0.0).then_some(out)
        })
        .collect()
}

/// A triangle mesh with a colour per vertex.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ColouredMesh {
    /// Positions, normals and triangles.
    pub mesh: Mesh,
    /// Colour per vertex.
    pub colours: Vec<[u8; 3]>,
}

/// The field seen as `level − density`: positive (outside) where the
/// density is below `level`, so surface nets orient normals outwards.
struct LevelSet<'a> {
    field: &'a dyn RadianceField,
    level: f32,
}

impl DistanceField for LevelSet<'_> {
    fn distances(&self, points: &[[f32; 3]], out: &mut [f32]) {
        // Density does not depend on the direction (a NeRF's density head
        // sees the position only).
        let dirs = vec![[0.0, 0.0, 1.0]; points.len()];
        let mut rgb = vec![[0.0; 3]; points.len()];
        self.field.query(points, &dirs, out, &mut rgb);
        for o in out.iter_mut() {
            // A non-finite density counts as empty space.
            *o = if o.is_finite() {
                self.level - *o
            } else {
                self.level
            };
        }
    }
}

/// The surface where `field`'s density reaches `level` on `grid`, its
/// vertices coloured by the field seen along the reversed normal (from
/// outside) and moved with their normals into the data's frame by `to_data`.
pub fn density_mesh(
    field: &dyn RadianceField,
    level: f32,
    grid: &MeshGrid,
    max_vertices: usize,
    to_data: &DAffine3,
) -> Result<ColouredMesh, crate::mesh::MeshError> {
    let mut mesh =
        crate::mesh::surface_nets(&LevelSet { field, level }, grid, max_vertices, &|_| {})?;
    let dirs: Vec<[f32; 3]> = mesh
        .normals
        .iter()
        .map(|n| {
            let d = [-n[0], -n[1], -n[2]];
            if d.iter().all(|x| *x == 0.0) {
                [0.0, 0.0, 1.0]
            } else {
                d
            }
        })
        .collect();
    let mut sigma = vec![0.0; mesh.vertices.len()];
    let mut rgb = vec![[0.0; 3]; mesh.vertices.len()];
    field.query(&mesh.vertices, &dirs, &mut sigma, &mut rgb);
    let colours = rgb
        .iter()
        .map(|c| {
            c.map(|x| {
                (if x.is_finite() {
                    x.clamp(0.0, 1.0)
                } else {
                    0.0
                } * 255.0)
                    .round() as u8
            })
        })
        .collect();
    mesh.transform(to_data);
    Ok(ColouredMesh { mesh, colours })
}
