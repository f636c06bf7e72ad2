//! A NeRF as a model the trainer fits ([`NerfObjective`]) and as a field to
//! render ([`render_nerf_view`]): samples along rays → the network over the
//! whole batch → compositing per ray → MSE, and back.

use rayon::prelude::*;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::value::{LastInterval, Nerf};

use super::composite::{composite, composite_backward};
use super::nerf::{NerfNet, NerfWork};
use crate::train::fused::Batch;
use crate::train::{Objective, TensorSpec, TrainError};
use crate::volume::march::intervals_into;
use crate::volume::{camera_rays, ImageSize, Ray, Stratified, VolumeError};

/// Rays per block of the compositing pass (the unit of the ordered loss
/// reduction).
const RAY_BLOCK: usize = 64;
/// Samples per network pass when rendering (bounds the buffers).
const RENDER_ROWS: usize = 1 << 16;

/// A NeRF being trained.
pub struct NerfObjective {
    pub net: NerfNet,
    seed: u64,
    background: [f32; 3],
    work: NerfWork,
    points: Vec<f32>,
    dirs: Vec<f32>,
    d_sigma: Vec<f32>,
    d_rgb: Vec<f32>,
}

impl NerfObjective {
    pub fn new(spec: &Nerf) -> Self {
        NerfObjective {
            net: NerfNet::new(spec),
            seed: spec.seed,
            background: spec.background.map(|x| x as f32),
            work: NerfWork::default(),
            points: Vec::new(),
            dirs: Vec::new(),
            d_sigma: Vec::new(),
            d_rgb: Vec::new(),
        }
    }
}

/// Sample positions and directions of `rays`, `samples` per ray, with
/// depths `depth_of(ray)`.
fn sample_points<'d>(
    rays: &[Ray],
    samples: usize,
    depth_of: impl Fn(usize) -> &'d [f32] + Sync,
    points: &mut Vec<f32>,
    dirs: &mut Vec<f32>,
) {
    points.resize(rays.len() * samples * 3, 0.0);
    dirs.resize(rays.len() * samples * 3, 0.0);
    points
        .par_chunks_mut(samples * 3)
        .zip(dirs.par_chunks_mut(samples * 3))
        .enumerate()
        .for_each(|(r, (p, d))| {
            let ray = &rays[r];
            for (k, &t) in depth_of(r).iter().enumerate() {
                for i in 0..3 {
                    p[3 * k + i] = ray.origin[i] + t * ray.dir[i];
                    d[3 * k + i] = ray.dir[i];
                }
            }
        });
}

impl Objective for NerfObjective {
    fn tensors(&self) -> Vec<TensorSpec> {
        self.net
            .layers()
            .into_iter()
            .flat_map(|(name, d)| {
                let w = d.fan_in() * d.out;
                [
                    TensorSpec {
                        name: format!("{name}.weight"),
                        offset: d.offset,
                        len: w,
                    },
                    TensorSpec {
                        name: format!("{name}.bias"),
                        offset: d.offset + w,
                        len: d.out,
                    },
                ]
            })
            .collect()
    }

    fn initial(&self) -> Vec<f32> {
        self.net.init(self.seed)
    }

    fn loss_and_grad(
        &mut self,
        values: &[f32],
        batch: &Batch,
        weight: f64,
        grad: &mut [f32],
    ) -> Result<f64, TrainError> {
        let (rays, s) = (batch.rays.len(), batch.samples);
        sample_points(
            &batch.rays,
            s,
            |r| batch.depths_of(r),
            &mut self.points,
            &mut self.dirs,
        );
        self.net
            .forward(values, &self.points, &self.dirs, &mut self.work);
        self.d_sigma.resize(rays * s, 0.0);
        self.d_rgb.resize(rays * s * 3, 0.0);
        let scale = (weight / (3 * rays.max(1)) as f64) as f32;
        let (sigma, rgb, bg) = (&self.work.sigma, &self.work.rgb, self.background);
        let last = batch.last_interval;
        let block_losses: Vec<f64> = self
            .d_sigma
            .par_chunks_mut(RAY_BLOCK * s)
            .zip(self.d_rgb.par_chunks_mut(RAY_BLOCK * s * 3))
            .enumerate()
            .map(|(blk, (ds, dc))| {
                let (mut delta, mut trans) = (Vec::with_capacity(s), Vec::with_capacity(s + 1));
                let mut loss = 0f64;
                for (j, (ds, dc)) in ds.chunks_mut(s).zip(dc.chunks_mut(3 * s)).enumerate() {
                    let r = blk * RAY_BLOCK + j;
                    let t = batch.depths_of(r);
                    intervals_into(t, last, &mut delta);
                    let (sg, c) = (&sigma[r * s..(r + 1) * s], &rgb[3 * r * s..3 * (r + 1) * s]);
                    let out = composite(sg, c, t, &delta, bg);
                    let mut g = [0f32; 3];
                    for i in 0..3 {
                        let e = out.colour[i] - batch.targets[r][i];
                        loss += (e * e * scale) as f64;
                        g[i] = 2.0 * e * scale;
                    }
                    composite_backward(sg, c, &delta, bg, g, ds, dc, &mut trans);
                }
                loss
            })
            .collect();
        self.net.backward(
            values,
            &mut self.work,
            &mut self.d_sigma,
            &mut self.d_rgb,
            grad,
        );
        Ok(block_losses.iter().sum())
    }
}

/// A rendered view: colour and (when asked) expected depth per pixel.
pub struct NerfView {
    pub colour: Vec<[f32; 3]>,
    pub depth: Vec<f32>,
}

/// Renders one view of a NeRF with stratified (unjittered) samples.
pub fn render_nerf_view(
    net: &NerfNet,
    params: &[f32],
    background: [f32; 3],
    sampler: &Stratified,
    last: LastInterval,
    cam: &Camera,
    size: ImageSize,
) -> Result<NerfView, VolumeError> {
    sampler.validate()?;
    let rays = camera_rays(cam, size)?;
    let t = sampler.depths();
    let s = t.len();
    let mut delta = Vec::new();
    intervals_into(&t, last, &mut delta);
    let mut view = NerfView {
        colour: vec![[0.0; 3]; rays.len()],
        depth: vec![0.0; rays.len()],
    };
    let (mut work, mut points, mut dirs) = (NerfWork::default(), Vec::new(), Vec::new());
    let per_pass = (RENDER_ROWS / s.max(1)).max(1);
    for (chunk, (colour, depth)) in rays.chunks(per_pass).zip(
        view.colour
            .chunks_mut(per_pass)
            .zip(view.depth.chunks_mut(per_pass)),
    ) {
        sample_points(chunk, s, |_| &t, &mut points, &mut dirs);
        net.forward(params, &points, &dirs, &mut work);
        colour
            .par_iter_mut()
            .zip(depth.par_iter_mut())
            .enumerate()
            .for_each(|(r, (c, d))| {
                let out = composite(
                    &work.sigma[r * s..(r + 1) * s],
                    &work.rgb[3 * r * s..3 * (r + 1) * s],
                    &t,
                    &delta,
                    background,
                );
                *c = out.colour;
                *d = out.depth;
            });
    }
    Ok(view)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::neural::mlp::Activation;
    use crate::volume::SplitMix64;
    use sdfl_stdlib::value::{Encoding, Harmonic};

    #[test]
    fn objective_gradient_matches_finite_differences() {
        let spec = Nerf {
            position: Encoding::Harmonic(Harmonic {
                freqs: 2,
                include_input: true,
            }),
            direction: Some(Encoding::Harmonic(Harmonic {
                freqs: 1,
                include_input: true,
            })),
            layers: 3,
            width: 12,
            skips: vec![1],
            color_width: 6,
            background: [0.3, 0.6, 0.9],
            seed: 4,
        };
        let mut obj = NerfObjective::new(&spec);
        // Smooth activations so differences see no kinks; same wiring.
        let smooth = Activation::Softplus { beta: 1.0 };
        let net = &mut obj.net;
        for d in net
            .trunk
            .iter_mut()
            .chain([&mut net.density, &mut net.color_hidden])
        {
            d.act = smooth;
        }
        let mut rng = SplitMix64::new(8);
        let rays: Vec<Ray> = (0..9)
            .map(|k| Ray {
                origin: [0.1 * k as f32, -0.2, -2.0],
                dir: [0.1, 0.05 * k as f32, 1.0],
                view: 0,
                pixel: k,
            })
            .collect();
        let samples = 7;
        let depths: Vec<f32> = (0..rays.len() * samples)
            .map(|i| 1.0 + 0.4 * (i % samples) as f32 + 0.1 * rng.next_f32())
            .collect();
        let batch = Batch {
            targets: rays
                .iter()
                .map(|_| [rng.next_f32(), rng.next_f32(), rng.next_f32()])
                .collect(),
            rays,
            depths,
            samples,
            shared: false,
            last_interval: LastInterval::Zero,
        };
        let values = obj.initial();
        let mut grad = vec![0.0; values.len()];
        obj.loss_and_grad(&values, &batch, 2.0, &mut grad).unwrap();
        let mut loss_at = |v: &[f32]| {
            let mut g = vec![0.0; v.len()];
            obj.loss_and_grad(v, &batch, 2.0, &mut g).unwrap()
        };
        let tensors = NerfObjective::new(&spec).tensors();
        for t in &tensors {
            for i in [t.offset, t.offset + t.len / 2, t.offset + t.len - 1] {
                let h = 1e-2;
                let mut v = values.clone();
                v[i] += h;
                let up = loss_at(&v);
                v[i] -= 2.0 * h;
                let down = loss_at(&v);
                let fd = (up - down) / (2.0 * h as f64);
                let got = grad[i] as f64;
                assert!(
                    (got - fd).abs() < 2e-2 * fd.abs().max(got.abs()) + 2e-5,
                    "{} [{i}]: {got} vs {fd}",
                    t.name
                );
            }
        }
    }
}
