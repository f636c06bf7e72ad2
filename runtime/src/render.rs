//! Running a `render` job: plan what the outputs need, lower the scene, trace
//! every view in parallel bands of rows, and write the outputs.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::{DVec3, Vec3A};
use rayon::prelude::*;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::effects::{subpixel_offsets, AmbientOcclusion, Fog, SoftShadows};
use sdfl_stdlib::material::Material;
use sdfl_stdlib::value::HitTolerance;
use sdfl_stdlib::{OutputKind, RenderJob};
use serde::Serialize;

use crate::data::export::DatasetWriter;
use crate::effects::{Counters, EffectStats, SurfacePoint};
use crate::output::{colormap, to_u8, write_png, GifWriter, Written, WrittenKind};
use crate::sdf::tiles::{Margin, TILE};
use crate::sdf::{LowerOptions, Lowered};
use crate::trace::{normal, normal_step, TraceSettings};
use crate::video::VideoWriter;

/// Rows per parallel work unit: one row of screen tiles.
const BAND_ROWS: usize = TILE;

/// Which per-pixel quantities a job computes, and which output asks for each.
/// Quantities no output needs are never computed.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Plan {
    /// The outputs (by path) that need shaded colour.
    pub color: Vec<String>,
    /// The outputs that need hit depth.
    pub depth: Vec<String>,
    /// The outputs that need surface normals.
    pub normals: Vec<String>,
    /// The outputs that need the hit mask.
    pub mask: Vec<String>,
    /// Surface meshes (the distance on a grid).
    pub meshes: Vec<String>,
    /// Shading needs normals at hit points (a material uses them); they are
    /// then computed per hit, not stored.
    pub shading_normals: bool,
    /// Shading needs the view (ray) direction (a specular material): the
    /// colour differs between views of one point.
    pub shading_view: bool,
    /// The soft shadows the materials ask for (each distinct setting with
    /// the most lights it is marched towards); empty: no shadow rays.
    pub shadows: Vec<ShadowPlan>,
    /// The ambient occlusion the materials ask for (each distinct setting).
    pub occlusion: Vec<AmbientOcclusion>,
    /// Fog over the colour.
    pub fog: Option<Fog>,
    /// Rays per pixel for the colour (1 without colour outputs).
    pub samples_per_pixel: u32,
}

/// Soft shadows of one setting, marched towards up to `lights` lights per
/// shaded sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ShadowPlan {
    /// The soft-shadow setting.
    pub shadows: SoftShadows,
    /// Lights a shaded sample marches towards.
    pub lights: usize,
}

impl Plan {
    /// What `job`'s outputs need.
    pub fn of(job: &RenderJob) -> Plan {
        let mut plan = Plan::default();
        for o in &job.outputs {
            let who = o.path.display().to_string();
            match o.kind {
                OutputKind::Image | OutputKind::Gif { .. } | OutputKind::Video { .. } => {
                    plan.color.push(who)
                }
                OutputKind::Depth | OutputKind::DepthGif { .. } => plan.depth.push(who),
                OutputKind::Normals => plan.normals.push(who),
                OutputKind::Mask => plan.mask.push(who),
                // RGBA: colour, with the hit mask as alpha.
                OutputKind::Dataset { .. } => {
                    plan.color.push(who.clone());
                    plan.mask.push(who);
                }
                // Camera visual checks need no tracing; sample points and
                // loss curves are refused for renders when evaluated.
                OutputKind::Grid
                | OutputKind::Rays
                | OutputKind::SamplePoints
                | OutputKind::LossCurve
                | OutputKind::PsnrCurve
                | OutputKind::Comparison => {}
                // Meshes sample the distance on a grid, not along rays.
                OutputKind::Mesh { .. } => plan.meshes.push(who),
                // Refused for renders when evaluated.
                OutputKind::GeometryGif { .. }
                | OutputKind::DensityMesh { .. }
                | OutputKind::PointCloud { .. }
                | OutputKind::RawDepth { .. }
                | OutputKind::DepthMap { .. } => {}
            }
        }
        let shaded = !plan.color.is_empty();
        plan.shading_normals =
            shaded && (job.material.needs_normal() || any_painted(job, Material::needs_normal));
        plan.shading_view =
            shaded && (job.material.needs_view() || any_painted(job, Material::needs_view));
        plan.samples_per_pixel = 1;
        if shaded {
            let mut materials = vec![&*job.material];
            painted(&job.scene, &mut materials);
            for m in materials {
                let lights = m.shadowed_lights();
                for e in m.effects() {
                    if let Some(s) = e.shadows {
                        match plan.shadows.iter_mut().find(|p| p.shadows == s) {
                            Some(p) => p.lights = p.lights.max(lights),
                            None => plan.shadows.push(ShadowPlan { shadows: s, lights }),
                        }
                    }
                    if let Some(o) = e.occlusion {
                        if !plan.occlusion.contains(&o) {
                            plan.occlusion.push(o);
                        }
                    }
                }
            }
            plan.fog = job.fog;
            plan.samples_per_pixel = job.samples_per_pixel;
        }
        plan
    }

    /// What the effects cost, one line each (empty without effects), as
    /// `sdfl plan` prints them.
    pub fn effect_lines(&self) -> Vec<(&'static str, String)> {
        let mut lines = Vec::new();
        for s in &self.shadows {
            lines.push((
                "soft shadows",
                format!(
                    "k {}: up to {} SDF evaluations per shaded sample per light facing it ({} light{})",
                    s.shadows.k,
                    s.shadows.steps,
                    s.lights,
                    if s.lights == 1 { "" } else { "s" }
                ),
            ));
        }
        for o in &self.occlusion {
            lines.push((
                "occlusion",
                format!(
                    "{} SDF evaluations per shaded sample along the normal, within {}",
                    o.samples, o.distance
                ),
            ));
        }
        if let Some(f) = &self.fog {
            lines.push((
                "fog",
                format!(
                    "exponential, density {}, colour {:?}: per pixel, no SDF evaluations",
                    f.density,
                    f.color.to_array()
                ),
            ));
        }
        if self.samples_per_pixel > 1 {
            let m = (self.samples_per_pixel as f64).sqrt().round() as u32;
            lines.push((
                "supersampling",
                format!(
                    "{0} samples per pixel ({m}x{m} rotated grid): {0}x primary rays and shading for colour{1}",
                    self.samples_per_pixel,
                    if self.depth.is_empty() && self.normals.is_empty() && self.mask.is_empty() {
                        ""
                    } else {
                        ", plus the pixel centre's ray for depth, normals and mask"
                    }
                ),
            ));
        }
        lines
    }
}

/// The materials painted onto parts of `s`.
fn painted<'a>(s: &'a sdfl_stdlib::shape::Shape, out: &mut Vec<&'a Material>) {
    if let sdfl_stdlib::shape::Shape::Paint(_, m) = s {
        out.push(m);
    }
    for c in s.children() {
        painted(c, out);
    }
}

/// Whether any material painted onto a part of the scene has `property`.
fn any_painted(job: &RenderJob, property: fn(&Material) -> bool) -> bool {
    fn walk(s: &sdfl_stdlib::shape::Shape, property: fn(&Material) -> bool) -> bool {
        let painted = matches!(s, sdfl_stdlib::shape::Shape::Paint(_, m) if property(m));
        painted || s.children().into_iter().any(|c| walk(c, property))
    }
    walk(&job.scene, property)
}

/// How far from the origin of a scene's coordinates a camera may be before
/// the scene is lowered again relative to it. Nearer, f32 coordinates
/// resolve the image as well as at the world origin (a sphere seen from
/// 1e3 away from the world origin renders within 61 dB of the same view at
/// it; 34 dB at 1e4, 26 dB at 1e5), and scenes near the world origin keep
/// their world coordinates, so their images are bit-identical to those of
/// a tracer without relative coordinates.
pub const RELATIVE_BEYOND: f64 = 16.0;

/// The lowered scene of a job's views: in world coordinates while every
/// camera is within [`RELATIVE_BEYOND`] of the world origin; else relative
/// to the cameras' mean eye, and lowered again at a view's eye for a view
/// farther than that from the origin in use.
pub struct ViewScenes<'a> {
    shape: &'a sdfl_stdlib::shape::Shape,
    options: LowerOptions,
    scene: Lowered,
    /// Seconds spent lowering, and how many times the scene was lowered.
    pub lower_s: f64,
    /// Times the scene was lowered.
    pub lowerings: usize,
}

impl<'a> ViewScenes<'a> {
    /// The scene of `cameras` lowered once (relative to their mean eye when
    /// they are far from the origin).
    pub fn new(
        shape: &'a sdfl_stdlib::shape::Shape,
        options: LowerOptions,
        cameras: &[Camera],
    ) -> Self {
        let near = cameras.iter().all(|c| c.eye.length() <= RELATIVE_BEYOND);
        let origin = if near || cameras.is_empty() {
            DVec3::ZERO
        } else {
            cameras.iter().map(|c| c.eye).sum::<DVec3>() / cameras.len() as f64
        };
        let t = Instant::now();
        let scene = Lowered::relative_to(shape, options, origin);
        ViewScenes {
            shape,
            options,
            scene,
            lower_s: t.elapsed().as_secs_f64(),
            lowerings: 1,
        }
    }

    /// The scene for a view of `cam`.
    pub fn for_view(&mut self, cam: &Camera) -> &Lowered {
        if (cam.eye - self.scene.origin).length() > RELATIVE_BEYOND {
            let t = Instant::now();
            self.scene = Lowered::relative_to(self.shape, self.options, cam.eye);
            self.lower_s += t.elapsed().as_secs_f64();
            self.lowerings += 1;
        }
        &self.scene
    }

    /// The scene as last lowered.
    pub fn current(&self) -> &Lowered {
        &self.scene
    }
}

/// Per-view buffers; `None` for quantities the plan does not need.
pub struct ViewBuffers {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Shaded colour, RGB8 row by row.
    pub color: Option<Vec<u8>>,
    /// Hit depth `t`, 0 for misses.
    pub depth: Option<Vec<f32>>,
    /// Normals as RGB8 colours, `(n + 1) / 2`.
    pub normals: Option<Vec<u8>>,
    /// 255 where the ray hit, 0 where it missed.
    pub mask: Option<Vec<u8>>,
    /// Primary rays that hit.
    pub hits: u64,
    /// Sphere-tracing steps of all primary rays.
    pub steps: u64,
    /// Rays whose steps ran out before they hit or passed `far`.
    pub undecided: u64,
    /// Primary rays traced (pixels × samples, and pixel centres).
    pub rays: u64,
    /// Shadow rays and occlusion samples.
    pub effects: EffectStats,
}

/// Which quantities to compute for each pixel.
#[derive(Debug, Clone, Copy)]
pub struct Needs {
    /// Shaded colour.
    pub color: bool,
    /// Hit depth.
    pub depth: bool,
    /// Surface normals.
    pub normals: bool,
    /// The hit mask.
    pub mask: bool,
}

impl From<&Plan> for Needs {
    fn from(p: &Plan) -> Self {
        Needs {
            color: !p.color.is_empty(),
            depth: !p.depth.is_empty(),
            normals: !p.normals.is_empty(),
            mask: !p.mask.is_empty(),
        }
    }
}

/// Trace one view. `progress` is called with the number of pixels finished.
pub fn render_view(
    scene: &Lowered,
    job: &RenderJob,
    cam: &Camera,
    (width, height): (u32, u32),
    needs: Needs,
    progress: &(dyn Fn(u64) + Sync),
) -> ViewBuffers {
    let (w, h) = (width as usize, height as usize);
    // Half a pixel's width per unit of distance, in the image's NDC.
    let footprint = match job.hit_tolerance {
        HitTolerance::Pixel => cam.half_pixel_tangent(width, height) as f32,
        HitTolerance::Absolute => 0.0,
    };
    let settings = TraceSettings {
        near: job.near as f32,
        far: job.far as f32,
        max_steps: job.iterations,
        epsilon: job.epsilon as f32,
        footprint,
        relax: job.hit_tolerance == HitTolerance::Pixel,
        lipschitz: scene.lipschitz,
    };
    let (ax, ay, az) = cam.axes();
    // Rays start at the eye in the scene's coordinates (relative to its
    // origin: near 0 when it was lowered at this camera).
    let origin: Vec3A = (cam.eye - scene.origin).as_vec3().into();
    let alloc = |on: bool, n: usize| on.then(|| vec![0u8; n]);
    let mut color = alloc(needs.color, w * h * 3);
    let mut depth = needs.depth.then(|| vec![0f32; w * h]);
    let mut normals = alloc(needs.normals, w * h * 3);
    let mut mask = alloc(needs.mask, w * h);

    // Split every buffer into bands of rows; each band is traced by one task.
    let bands = h.div_ceil(BAND_ROWS);
    let mut color_b = split(color.as_deref_mut(), w * 3 * BAND_ROWS, bands);
    let mut depth_b = split(depth.as_deref_mut(), w * BAND_ROWS, bands);
    let mut normal_b = split(normals.as_deref_mut(), w * 3 * BAND_ROWS, bands);
    let mut mask_b = split(mask.as_deref_mut(), w * BAND_ROWS, bands);
    let work: Vec<_> = (0..bands)
        .map(|b| {
            (
                b,
                color_b[b].take(),
                depth_b[b].take(),
                normal_b[b].take(),
                mask_b[b].take(),
            )
        })
        .collect();
    // Colour averages the rays of `samples_per_pixel` sub-pixel points; the
    // geometric buffers are the pixel centre's, traced separately only
    // when the colour's rays miss it.
    let offsets = subpixel_offsets(if needs.color {
        job.samples_per_pixel
    } else {
        1
    });
    // Sub-pixel rays decide hits within half of 1/n of a pixel for n
    // samples: a pixel's footprint would widen every silhouette by half a
    // pixel, and 1/n keeps the widening below the coverage levels the n
    // samples resolve (each row and column of the n × n grid holds one).
    let sub_settings = TraceSettings {
        footprint: settings.footprint / offsets.len() as f32,
        ..settings
    };
    // Each tile of TILE × TILE pixels marches only the members that can
    // come near its rays (see `sdf::tiles`).
    let reach = origin.abs().max_element() + settings.far;
    let margin = Margin::for_trace(
        &settings,
        origin,
        normal_step(Vec3A::splat(reach)),
        scene.lipschitz,
    );
    let tiles = scene.tiles(origin, margin);
    let geometry = needs.depth || needs.normals || needs.mask;
    let centre_separate = offsets.len() > 1 && geometry;
    let inv_l = 1.0 / scene.lipschitz;
    let fog_far = job.far;
    let background64 = job.background;
    let fogged_background = job
        .fog
        .map_or(background64, |f| f.apply(background64, fog_far));
    let background = fogged_background.to_array().map(to_u8);
    // The ray through fractional pixel (x, y).
    let direction = |x: f64, y: f64| -> (DVec3, Vec3A) {
        let d64 = cam.pixel_direction(x, y, width, height);
        (d64, d64.as_vec3().into())
    };
    // The shaded, fogged colour of a hit, and its normal if shading used it.
    let shade = |hit: &crate::trace::Hit, d64: DVec3, dir: Vec3A, counters: &Counters| {
        let p = origin + dir * hit.t;
        let (_, id) = scene.root.dist_id(p);
        let info = scene.prims.get(id as usize);
        let material = info
            .and_then(|i| i.material.as_deref())
            .unwrap_or(&job.material);
        let center = info.map_or(DVec3::ZERO, |i| i.center);
        let shading_normal = material
            .needs_normal()
            .then(|| normal(&*scene.root, p, normal_step(p), -dir));
        let n = shading_normal.unwrap_or(Vec3A::Z);
        let p64 = scene.to_world(p);
        let n64 = DVec3::from(n.to_array().map(f64::from));
        let env = SurfacePoint {
            sdf: &*scene.root,
            inv_lipschitz: inv_l,
            p,
            n,
            far: settings.far,
            epsilon: settings.epsilon,
            pixel: settings.footprint * hit.t,
            counters,
        };
        let rgb = material.shade_in(p64, center, n64, d64, &env);
        let rgb = match &job.fog {
            Some(f) => f.apply(rgb, hit.t as f64),
            None => rgb,
        };
        (rgb, shading_normal)
    };
    let (hits, steps, undecided, rays, effects) = work
        .into_par_iter()
        .map(|(band, mut col, mut dep, mut nor, mut msk)| {
            let (mut hits, mut steps, mut undecided, mut rays) = (0u64, 0u64, 0u64, 0u64);
            let counters = Counters::default();
            let rows = (band * BAND_ROWS)..((band + 1) * BAND_ROWS).min(h);
            let nrows = rows.len();
            for i0 in (0..w).step_by(TILE) {
                let i1 = (i0 + TILE).min(w);
                // The tile's rectangle on the image plane, half a pixel
                // past its outer pixel centres (sub-pixel rays stay inside).
                let (tx, ty) = cam.tangent_bounds(
                    (i0 as f64 - 0.5, rows.start as f64 - 0.5),
                    (i1 as f64 - 0.5, rows.end as f64 - 0.5),
                    width,
                    height,
                );
                let tile = tiles.tile((ax, ay, az), tx, ty);
                if tile.is_empty() && offsets.len() == 1 {
                    // Every ray misses: only the background to write.
                    rays += (nrows * (i1 - i0)) as u64;
                    if let Some(c) = col.as_deref_mut() {
                        for r in 0..nrows {
                            for k in r * w + i0..r * w + i1 {
                                c[k * 3..k * 3 + 3].copy_from_slice(&background);
                            }
                        }
                    }
                    continue;
                }
                // Where the tile's rays are marched together, all of them
                // first, in the order the loop below asks for them.
                let mut traced = tile.traces_in_packs().then(|| {
                    let mut rays = Vec::new();
                    for j in rows.clone() {
                        for i in i0..i1 {
                            if centre_separate || offsets.len() == 1 {
                                rays.push((direction(i as f64, j as f64), settings));
                            }
                            if offsets.len() > 1 && col.is_some() {
                                for (dx, dy) in &offsets {
                                    let d = direction(i as f64 + dx, j as f64 + dy);
                                    rays.push((d, sub_settings));
                                }
                            }
                        }
                    }
                    let dirs: Vec<_> = rays.iter().map(|((_, d), s)| (*d, *s)).collect();
                    let hits = tile.trace_packs(&dirs);
                    rays.into_iter().map(|(d, _)| d).zip(hits)
                });
                // The ray through fractional pixel (x, y) and where it ends.
                let mut trace = |x: f64, y: f64, s: &TraceSettings| {
                    let ((d64, dir), hit) = match traced.as_mut() {
                        Some(t) => t.next().expect("every ray is traced"),
                        None => {
                            let (d64, dir) = direction(x, y);
                            ((d64, dir), tile.trace(dir, s))
                        }
                    };
                    steps += hit.steps as u64;
                    undecided += hit.undecided as u64;
                    rays += 1;
                    (d64, dir, hit)
                };
                for (r, j) in rows.clone().enumerate() {
                    for i in i0..i1 {
                        let k = r * w + i;
                        if centre_separate || offsets.len() == 1 {
                            // The pixel centre: every quantity when it is the
                            // only ray, else depth, normals and the mask.
                            let (d64, dir, hit) = trace(i as f64, j as f64, &settings);
                            if !hit.hit {
                                if let (Some(c), false) = (col.as_deref_mut(), centre_separate) {
                                    c[k * 3..k * 3 + 3].copy_from_slice(&background);
                                }
                            } else {
                                hits += 1;
                                let p = origin + dir * hit.t;
                                let mut shading_normal = None;
                                if let (Some(c), false) = (col.as_deref_mut(), centre_separate) {
                                    let (rgb, n) = shade(&hit, d64, dir, &counters);
                                    shading_normal = n;
                                    c[k * 3..k * 3 + 3].copy_from_slice(&rgb.to_array().map(to_u8));
                                }
                                if let Some(d) = dep.as_deref_mut() {
                                    d[k] = hit.t;
                                }
                                if let Some(nb) = nor.as_deref_mut() {
                                    let n = shading_normal
                                        .unwrap_or_else(|| tile.normal(p, normal_step(p), -dir));
                                    let rgb =
                                        [n.x, n.y, n.z].map(|x| to_u8(((x + 1.0) * 0.5) as f64));
                                    nb[k * 3..k * 3 + 3].copy_from_slice(&rgb);
                                }
                                if let Some(m) = msk.as_deref_mut() {
                                    m[k] = 255;
                                }
                            }
                        }
                        if offsets.len() > 1 {
                            let Some(c) = col.as_deref_mut() else {
                                continue;
                            };
                            let mut sum = DVec3::ZERO;
                            for (dx, dy) in &offsets {
                                let (d64, dir, hit) =
                                    trace(i as f64 + dx, j as f64 + dy, &sub_settings);
                                sum += if hit.hit {
                                    hits += 1;
                                    shade(&hit, d64, dir, &counters).0
                                } else {
                                    fogged_background
                                };
                            }
                            let rgb = sum / offsets.len() as f64;
                            c[k * 3..k * 3 + 3].copy_from_slice(&rgb.to_array().map(to_u8));
                        }
                    }
                }
            }
            progress((nrows * w) as u64);
            (hits, steps, undecided, rays, counters.stats())
        })
        .reduce(
            || (0, 0, 0, 0, EffectStats::default()),
            |mut a, b| {
                a.4 += b.4;
                (a.0 + b.0, a.1 + b.1, a.2 + b.2, a.3 + b.3, a.4)
            },
        );
    ViewBuffers {
        width,
        height,
        color,
        depth,
        normals,
        mask,
        hits,
        steps,
        undecided,
        rays,
        effects,
    }
}

fn split<T>(buf: Option<&mut [T]>, chunk: usize, bands: usize) -> Vec<Option<&mut [T]>> {
    match buf {
        Some(b) => b.chunks_mut(chunk).map(Some).collect(),
        None => (0..bands).map(|_| None).collect(),
    }
}

/// An animated output of a job: a GIF (colour or depth) or a video.
enum Animation {
    Gif(GifWriter, PathBuf),
    Video(VideoWriter),
}

/// The GIF and video outputs of a job, open for one frame per view; each
/// shows colour or (colour-mapped) depth.
pub(crate) struct Gifs(Vec<(Animation, bool)>);

impl Gifs {
    pub(crate) fn open(outputs: &[sdfl_stdlib::Output], out_dir: &Path) -> std::io::Result<Gifs> {
        let mut gifs = Vec::new();
        for o in outputs {
            let (animation, depth) = match o.kind {
                OutputKind::Gif { fps } | OutputKind::DepthGif { fps } => (
                    Animation::Gif(
                        GifWriter::create(&out_dir.join(&o.path), fps)?,
                        o.path.clone(),
                    ),
                    matches!(o.kind, OutputKind::DepthGif { .. }),
                ),
                OutputKind::Video { fps } => {
                    let fallback = o.fallback().expect("a video has a fallback");
                    (
                        Animation::Video(VideoWriter::new(out_dir, &o.path, &fallback, fps)),
                        false,
                    )
                }
                _ => continue,
            };
            gifs.push((animation, depth));
        }
        Ok(Gifs(gifs))
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Whether a GIF shows depth (so the caller colour-maps it).
    pub(crate) fn wants_depth(&self) -> bool {
        self.0.iter().any(|g| g.1)
    }

    /// One frame: the colour, and the colour-mapped depth when
    /// [`Self::wants_depth`].
    pub(crate) fn push(
        &mut self,
        width: u32,
        height: u32,
        colour: Option<&[u8]>,
        depth: Option<&[u8]>,
    ) -> std::io::Result<()> {
        self.0.iter_mut().try_for_each(|(g, is_depth)| {
            let frame = if *is_depth { depth } else { colour };
            let frame = frame.expect("the plan computes what every GIF shows");
            match g {
                Animation::Gif(g, _) => g.push(width, height, frame),
                Animation::Video(v) => v.push(width, height, frame),
            }
        })
    }

    /// Write every GIF and video (atomically) and report it.
    pub(crate) fn finish(self, width: u32, height: u32) -> std::io::Result<Vec<Written>> {
        self.0
            .into_iter()
            .map(|(g, _)| match g {
                Animation::Gif(g, path) => {
                    let frames = g.frames;
                    g.finish()?;
                    Ok(Written {
                        path,
                        kind: WrittenKind::Gif,
                        width,
                        height,
                        frames,
                        mesh: None,
                        warning: None,
                    })
                }
                Animation::Video(v) => v.finish(),
            })
            .collect()
    }
}

/// What a job did and how long each stage took.
#[derive(Debug, Clone, Serialize)]
pub struct JobReport {
    /// The statement's name.
    pub name: String,
    /// Primitives of the lowered scene.
    pub primitives: usize,
    /// Nodes of its bounding volume hierarchy.
    pub bvh_nodes: usize,
    /// Its Lipschitz bound (steps are divided by it).
    pub lipschitz: f32,
    /// Views rendered.
    pub views: usize,
    /// Primary rays traced: pixels × views × samples per pixel (and the
    /// pixel centres where supersampled colour and depth, normals or a
    /// mask are both asked for); `hits` of them hit.
    pub rays: u64,
    /// Primary rays that hit.
    pub hits: u64,
    /// Sphere-tracing steps of all primary rays.
    pub steps: u64,
    /// Rays whose steps ran out before they hit or passed `far` (shown as
    /// misses: more `iterations` or `hit_tolerance: "pixel"` decide them).
    pub undecided: u64,
    /// Shadow rays and occlusion samples (all 0 unless a material asks).
    pub effects: EffectStats,
    /// What was computed, for which output.
    pub plan: Plan,
    /// The files written.
    pub written: Vec<Written>,
    /// (stage, seconds)
    pub stages: Vec<(String, f64)>,
}

/// Options a caller can set on top of the scene file.
#[derive(Debug, Clone, Copy, Default)]
pub struct RunOptions {
    /// Overrides every render's `size`.
    pub size: Option<(u32, u32)>,
    /// Evaluate unions without BVH culling (for comparisons).
    pub no_cull: bool,
    /// Training starts over instead of resuming its checkpoint.
    pub restart: bool,
}

/// The file name for view `k` of `n` (shared with the evaluator, which
/// checks every name for collisions before anything runs).
pub use sdfl_stdlib::outputs::view_path;

/// Run one render job, writing its outputs under `out_dir`.
pub fn run_job(
    job: &RenderJob,
    out_dir: &Path,
    options: RunOptions,
    progress: &(dyn Fn(u64) + Sync),
) -> std::io::Result<JobReport> {
    let mut scenes = ViewScenes::new(
        &job.scene,
        LowerOptions {
            cull: !options.no_cull,
            ..Default::default()
        },
        &job.cameras,
    );
    let plan = Plan::of(job);
    let needs = Needs::from(&plan);
    let (width, height) = options.size.unwrap_or((job.width, job.height));
    let views = job.cameras.len();
    let mut gifs = Gifs::open(&job.outputs, out_dir)?;
    let mut datasets: Vec<DatasetWriter> = job
        .outputs
        .iter()
        .filter_map(|o| DatasetWriter::for_output(out_dir, o, (width, height), views))
        .collect();
    let mut written = Vec::new();
    let (mut trace_s, mut encode_s) = (0.0, 0.0);
    let (mut hits, mut steps, mut undecided, mut rays) = (0, 0, 0, 0);
    let mut effects = EffectStats::default();
    for (k, cam) in job.cameras.iter().enumerate() {
        let scene = scenes.for_view(cam);
        let t = Instant::now();
        let view = render_view(scene, job, cam, (width, height), needs, progress);
        trace_s += t.elapsed().as_secs_f64();
        hits += view.hits;
        steps += view.steps;
        undecided += view.undecided;
        rays += view.rays;
        effects += view.effects;
        let t = Instant::now();
        for o in &job.outputs {
            let rel = view_path(&o.path, k, views);
            let (kind, rgb): (WrittenKind, Option<Vec<u8>>) = match o.kind {
                OutputKind::Gif { .. }
                | OutputKind::Video { .. }
                | OutputKind::DepthGif { .. }
                | OutputKind::Dataset { .. } => continue,
                OutputKind::Image => (WrittenKind::Image, view.color.clone()),
                OutputKind::Normals => (WrittenKind::NormalMap, view.normals.clone()),
                OutputKind::Mask => (
                    WrittenKind::Mask,
                    view.mask
                        .as_ref()
                        .map(|m| m.iter().flat_map(|v| [*v; 3]).collect()),
                ),
                OutputKind::Depth => (
                    WrittenKind::Depth,
                    view.depth.as_ref().map(|d| depth_image(d)),
                ),
                OutputKind::Rays if k == 0 => (
                    WrittenKind::RaysImage,
                    Some(crate::volume::figures::rays_image(cam, width, height)),
                ),
                OutputKind::Grid if k == 0 => (
                    WrittenKind::GridImage,
                    Some(crate::volume::figures::xy_grid_image(width, height)),
                ),
                OutputKind::Grid
                | OutputKind::Rays
                | OutputKind::SamplePoints
                | OutputKind::LossCurve
                | OutputKind::PsnrCurve
                | OutputKind::Comparison
                | OutputKind::Mesh { .. }
                | OutputKind::GeometryGif { .. }
                | OutputKind::DensityMesh { .. }
                | OutputKind::PointCloud { .. }
                | OutputKind::RawDepth { .. }
                | OutputKind::DepthMap { .. } => continue,
            };
            // The camera checks are written once, for the first view.
            let rel = if matches!(o.kind, OutputKind::Grid | OutputKind::Rays) {
                o.path.clone()
            } else {
                rel
            };
            let path = out_dir.join(&rel);
            let rgb = rgb.expect("the plan computes what every output needs");
            write_png(&path, width, height, &rgb)?;
            written.push(Written {
                path: rel,
                kind,
                width,
                height,
                frames: 1,
                mesh: None,
                warning: None,
            });
        }
        if !gifs.is_empty() {
            let depth = gifs
                .wants_depth()
                .then(|| view.depth.as_ref().map(|d| depth_image(d)))
                .flatten();
            gifs.push(width, height, view.color.as_deref(), depth.as_deref())?;
        }
        for d in &mut datasets {
            let rgb = view.color.as_deref().expect("datasets plan colour");
            written.push(d.push(k, cam, rgb, view.mask.as_deref())?);
        }
        encode_s += t.elapsed().as_secs_f64();
    }
    let t = Instant::now();
    written.extend(gifs.finish(width, height)?);
    for d in datasets {
        written.push(d.finish()?);
    }
    encode_s += t.elapsed().as_secs_f64();
    let t = Instant::now();
    let scene = scenes.current();
    let bounds = job
        .scene
        .bounds()
        .map(|b| (b.min.to_array(), b.max.to_array()));
    let distance = |p: &[[f32; 3]], out: &mut [f32]| {
        for (p, o) in p.iter().zip(out) {
            *o = scene.dist(Vec3A::from(*p));
        }
    };
    for o in job
        .outputs
        .iter()
        .filter(|o| matches!(o.kind, OutputKind::Mesh { .. }))
    {
        let field = crate::mesh::Lipschitz(&distance, scene.lipschitz);
        written.push(crate::mesh::write_mesh(out_dir, o, &field, bounds)?.0);
    }
    let mesh_s = t.elapsed().as_secs_f64();
    let mut stages = vec![
        ("lower".into(), scenes.lower_s),
        ("trace".into(), trace_s),
        ("encode".into(), encode_s),
    ];
    if !plan.meshes.is_empty() {
        stages.push(("mesh".into(), mesh_s));
    }
    Ok(JobReport {
        name: job.name.clone(),
        primitives: job.scene.primitive_count(),
        bvh_nodes: scene.bvh_nodes,
        lipschitz: scene.lipschitz,
        views,
        rays,
        hits,
        steps,
        undecided,
        effects,
        plan,
        written,
        stages,
    })
}

/// Depth normalised by its maximum over hits and colour-mapped; misses black.
pub fn depth_image(depth: &[f32]) -> Vec<u8> {
    let max = depth
        .iter()
        .copied()
        .filter(|d| *d > 0.0 && d.is_finite())
        .fold(0.0f32, f32::max);
    depth
        .iter()
        .flat_map(|d| {
            if *d > 0.0 && max > 0.0 {
                colormap(d / max)
            } else {
                [0, 0, 0]
            }
        })
        .collect()
}
