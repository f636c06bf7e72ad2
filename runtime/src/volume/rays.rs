//! Rays for pixels of the conventions' cameras, seeded random ray batches,
//! stratified depth samples, and chunked iteration over an image's rays.

use rayon::prelude::*;
use sdfl_stdlib::camera::Camera;

use super::VolumeError;

/// One camera ray: origin, unit direction, and the view and pixel
/// (`row·width + column`) it came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Where the ray starts (a pinhole camera's eye).
    pub origin: [f32; 3],
    /// Unit direction of travel.
    pub dir: [f32; 3],
    /// Index of the view (camera) the ray belongs to.
    pub view: u32,
    /// The pixel, `row·width + column`.
    pub pixel: u32,
}

/// An image size; pixel `(i, j)` is column `i` from the left, row `j` from the top.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageSize {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

impl ImageSize {
    /// Number of pixels, `width × height`.
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// The ray through pixel `pixel = j·W + i` of `cam`, per CONVENTIONS.md.
pub fn pixel_ray(cam: &Camera, size: ImageSize, view: u32, pixel: u32) -> Ray {
    let i = pixel % size.width;
    let j = pixel / size.width;
    let d = cam.pixel_direction(i as f64, j as f64, size.width, size.height);
    Ray {
        origin: cam.eye.to_array().map(|v| v as f32),
        dir: d.to_array().map(|v| v as f32),
        view,
        pixel,
    }
}

/// All rays of a camera, row-major from the top-left pixel.
pub fn camera_rays(cam: &Camera, size: ImageSize) -> Result<Vec<Ray>, VolumeError> {
    check_camera(cam, size)?;
    Ok((0..size.pixels() as u32)
        .map(|p| pixel_ray(cam, size, 0, p))
        .collect())
}

fn check_camera(cam: &Camera, size: ImageSize) -> Result<(), VolumeError> {
    if !cam.is_valid() {
        return Err(VolumeError::InvalidCamera);
    }
    if size.width == 0 || size.height == 0 {
        return Err(VolumeError::Invalid("image size must be non-zero".into()));
    }
    Ok(())
}

/// Calls `f(rays, out_chunk)` for consecutive chunks of at most `chunk` pixels
/// of the image, in parallel, with `out` holding one element per pixel; stops
/// at an error `f` returns. Rays are generated per chunk, so memory beyond
/// `out` is O(chunk) per thread.
pub fn for_each_ray_chunk<T: Send>(
    cam: &Camera,
    size: ImageSize,
    chunk: usize,
    out: &mut [T],
    f: impl Fn(&[Ray], &mut [T]) -> Result<(), VolumeError> + Sync,
) -> Result<(), VolumeError> {
    check_camera(cam, size)?;
    if out.len() != size.pixels() {
        return Err(VolumeError::Invalid(format!(
            "output holds {} pixels, image has {}",
            out.len(),
            size.pixels()
        )));
    }
    let chunk = chunk.max(1);
    out.par_chunks_mut(chunk)
        .enumerate()
        .try_for_each(|(c, o)| {
            let start = (c * chunk) as u32;
            let rays: Vec<Ray> = (0..o.len() as u32)
                .map(|k| pixel_ray(cam, size, 0, start + k))
                .collect();
            f(&rays, o)
        })
}

/// A small, fast, seedable generator (SplitMix64). Deterministic across
/// platforms and versions, which is all the samplers need.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator whose stream is fixed by `seed`.
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `[0, 1)`.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
    /// Uniform in `[0, 1)` with 53 bits.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
    /// Uniform in `0..n` (n > 0), without modulo bias worth mentioning for n ≪ 2⁶⁴.
    pub fn below(&mut self, n: u64) -> u64 {
        ((self.next_u64() as u128 * n as u128) >> 64) as u64
    }
}

/// `count` distinct rays drawn uniformly from all pixels of all `cams`
/// (each of image size `size`), reproducibly from `rng`. Floyd's algorithm
/// draws the subset without materialising all pixel indices.
pub fn random_rays(
    cams: &[Camera],
    size: ImageSize,
    count: usize,
    rng: &mut SplitMix64,
) -> Result<Vec<Ray>, VolumeError> {
    if cams.is_empty() {
        return Err(VolumeError::Invalid("no views to sample rays from".into()));
    }
    for c in cams {
        check_camera(c, size)?;
    }
    let per_view = size.pixels() as u64;
    let total = per_view * cams.len() as u64;
    if count as u64 > total {
        return Err(VolumeError::Invalid(format!(
            "asked for {count} rays, the views have {total} pixels"
        )));
    }
    let mut chosen = std::collections::HashSet::with_capacity(count);
    let mut order = Vec::with_capacity(count);
    for j in (total - count as u64)..total {
        let t = rng.below(j + 1);
        let pick = if chosen.insert(t) { t } else { j };
        chosen.insert(pick);
        order.push(pick);
    }
    // The draw is sequential (one stream); the rays are not.
    Ok(order
        .into_par_iter()
        .map(|idx| {
            let view = (idx / per_view) as u32;
            pixel_ray(&cams[view as usize], size, view, (idx % per_view) as u32)
        })
        .collect())
}

/// Stratified depth sampler: `n` depths evenly spaced from `near` to `far`
/// inclusive (linspace).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stratified {
    /// Number of depths, at least 2.
    pub n: usize,
    /// The first depth, ≥ 0.
    pub near: f32,
    /// The last depth, beyond `near`.
    pub far: f32,
}

impl Stratified {
    /// The sampler, or an error unless `n ≥ 2` and `0 ≤ near < far`, both finite.
    pub fn new(n: usize, near: f32, far: f32) -> Result<Self, VolumeError> {
        let s = Stratified { n, near, far };
        s.validate()?;
        Ok(s)
    }

    /// Checks `n ≥ 2` and `0 ≤ near < far`, both finite (the fields are public,
    /// so every consumer re-checks).
    pub fn validate(&self) -> Result<(), VolumeError> {
        let (n, near, far) = (self.n, self.near, self.far);
        let ordered = near.is_finite() && far.is_finite() && near >= 0.0 && far > near;
        if n < 2 || !ordered {
            return Err(VolumeError::Invalid(format!(
                "sampler needs n ≥ 2 and 0 ≤ near < far (got n={n}, near={near}, far={far})"
            )));
        }
        Ok(())
    }

    /// The linspace depths, computed in f64 and rounded once.
    pub fn depths(&self) -> Vec<f32> {
        let (a, b) = (self.near as f64, self.far as f64);
        (0..self.n)
            .map(|k| (a + (b - a) * k as f64 / (self.n - 1) as f64) as f32)
            .collect()
    }

    /// Jittered depths for training: each depth is drawn uniformly in its
    /// stratum `[mid_{k−1}, mid_k]` (mid = midpoints of the linspace, the ends
    /// clamped to near/far), so they stay sorted within `[near, far]`.
    pub fn jittered_into(&self, rng: &mut SplitMix64, out: &mut [f32]) -> Result<(), VolumeError> {
        self.validate()?;
        if out.len() != self.n {
            return Err(VolumeError::Invalid(format!(
                "jittered_into: {} slots for {} depths",
                out.len(),
                self.n
            )));
        }
        let t = self.depths();
        for k in 0..self.n {
            let lo = if k == 0 {
                t[0]
            } else {
                0.5 * (t[k - 1] + t[k])
            };
            let hi = if k + 1 == self.n {
                t[k]
            } else {
                0.5 * (t[k] + t[k + 1])
            };
            out[k] = lo + (hi - lo) * rng.next_f32();
        }
        Ok(())
    }
}
