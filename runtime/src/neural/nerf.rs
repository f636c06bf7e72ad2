//! The NeRF network: encoded position → trunk of ReLU layers (with the
//! encoding appended again at the skips) → density (ReLU) and, through a
//! narrower branch that sees the encoded view direction when the field is
//! view-dependent, colour (sigmoid). Built only as the spec asks: no
//! direction encoding, feature layer or direction inputs unless
//! view-dependent.
//!
//! Forward and backward run over a batch of samples with buffers kept in a
//! [`NerfWork`] that is reused from step to step (no allocation once it has
//! grown to the batch).

use sdfl_stdlib::value::{DensityActivation, Encoding, HashGridSpec, Nerf};

use super::encoding::Harmonic;
use super::hashgrid::{HashGrid, HashGridConfig, Touched};
use super::mlp::{Activation, Dense};
use super::warp::Warp;
use crate::volume::SplitMix64;

/// A harmonic 3-vector encoding as the runtime computes it.
fn harmonic(h: &sdfl_stdlib::value::Harmonic) -> Harmonic {
    Harmonic {
        dims: 3,
        freqs: h.freqs,
        include_input: h.include_input,
    }
}

/// How positions are encoded: fixed features, or a trainable hash grid
/// whose tables come first in the network's parameters.
#[derive(Debug, Clone)]
pub enum PositionEncoding {
    /// Sines and cosines of the position.
    Harmonic(Harmonic),
    /// A trainable hash grid.
    Grid {
        /// The grid's levels and tables.
        grid: HashGrid,
        /// Where its tables start in the flat parameters.
        offset: usize,
    },
}

impl PositionEncoding {
    /// Features per position.
    pub fn width(&self) -> usize {
        match self {
            PositionEncoding::Harmonic(h) => h.width(),
            PositionEncoding::Grid { grid, .. } => grid.output_dim(),
        }
    }

    /// Trainable scalars of the encoding.
    #[allow(
        clippy::len_without_is_empty,
        reason = "a count of parameters, not of the encoding's contents"
    )]
    pub fn len(&self) -> usize {
        match self {
            PositionEncoding::Harmonic(_) => 0,
            PositionEncoding::Grid { grid, .. } => grid.param_count(),
        }
    }

    /// Whether it has parameters of its own (a hash grid).
    pub fn is_trainable(&self) -> bool {
        self.len() > 0
    }
}

/// The runtime's hash grid for a spec (the language checked its ranges);
/// over an unbounded scene's box (`warp`'s cube) when it is one.
pub fn hash_grid(g: &HashGridSpec, warp: Option<&Warp>) -> Result<HashGrid, String> {
    let (min, max) = warp.map_or((g.min, g.max), Warp::cube);
    HashGrid::new(HashGridConfig {
        levels: g.levels,
        features: g.features,
        log2_table: g.log2_table,
        min_res: g.min_res,
        max_res: g.max_res,
        bbox_min: min.map(|x| x as f32),
        bbox_max: max.map(|x| x as f32),
    })
}

/// The density head's starting bias where [`NerfNet::transparent_start`]
/// (density about e^-5 a unit).
pub const UNBOUNDED_DENSITY_BIAS: f32 = -5.0;

/// Rows of 3 floats as points.
fn as_points(flat: &[f32]) -> &[[f32; 3]] {
    assert_eq!(flat.len() % 3, 0);
    // SAFETY: [f32; 3] has the layout and alignment of three f32s.
    unsafe { std::slice::from_raw_parts(flat.as_ptr().cast(), flat.len() / 3) }
}

/// The network's layers and where each lives in the flat parameters.
#[derive(Debug, Clone)]
pub struct NerfNet {
    /// How sample positions are encoded.
    pub position: PositionEncoding,
    /// How view directions are encoded (view-dependent colour only).
    pub direction: Option<Harmonic>,
    /// Hidden layers of the trunk.
    pub trunk: Vec<Dense>,
    /// The density head.
    pub density: Dense,
    /// The trunk's features before the direction joins (view-dependent only).
    pub feature: Option<Dense>,
    /// The colour branch's hidden layer.
    pub color_hidden: Dense,
    /// The colour head (sigmoid).
    pub color_out: Dense,
    /// Positions contracted, or moved into NDC, before they are encoded
    /// (unbounded scenes).
    pub warp: Option<Warp>,
    /// The density starts near zero (unbounded scenes, learned
    /// backgrounds): at the usual start (density about 1 a unit
    /// everywhere) rays of many units are opaque, the background behind
    /// gets no gradient, and the field fits each view with fog in front of
    /// its camera (held-out 11 dB where this start gives 30 on a toy).
    /// Not for ReLU, whose negative bias would be dead.
    pub transparent_start: bool,
    /// Where its parameters start in the flat vector, and how many.
    pub first: usize,
    /// How many parameters it has.
    pub len: usize,
}

impl NerfNet {
    /// Panics on a hash grid the language would have refused; see
    /// [`Self::try_new_at`].
    pub fn new(spec: &Nerf) -> Self {
        Self::try_new_at(spec, 0).expect("a valid hash grid")
    }

    /// The network with its parameters from `first` on in a flat vector
    /// holding others too (the coarse and fine networks of one model).
    pub fn try_new_at(spec: &Nerf, first: usize) -> Result<Self, String> {
        let warp = spec.unbounded.as_ref().map(Warp::new).transpose()?;
        let position = match &spec.position {
            Encoding::Harmonic(h) => PositionEncoding::Harmonic(harmonic(h)),
            Encoding::HashGrid(g) => PositionEncoding::Grid {
                grid: hash_grid(g, warp.as_ref())?,
                offset: first,
            },
        };
        let direction = match &spec.direction {
            Some(Encoding::Harmonic(h)) => Some(harmonic(h)),
            Some(Encoding::HashGrid(_)) => {
                return Err("a hash grid cannot encode directions".into())
            }
            None => None,
        };
        let (enc, w) = (position.width(), spec.width);
        let mut offset = first + position.len();
        let mut layer = |parts: &[usize], out: usize, act: Activation| {
            let d = Dense::new(parts, out, act, offset).with_precision(spec.precision);
            offset = d.end();
            d
        };
        let trunk: Vec<Dense> = (0..spec.layers)
            .map(|i| {
                if i == 0 {
                    layer(&[enc], w, Activation::Relu)
                } else if spec.skips.contains(&i) {
                    layer(&[w, enc], w, Activation::Relu)
                } else {
                    layer(&[w], w, Activation::Relu)
                }
            })
            .collect();
        let density = layer(
            &[w],
            1,
            match spec.density {
                DensityActivation::Relu => Activation::Relu,
                DensityActivation::Exp => Activation::Exp,
                DensityActivation::Softplus => Activation::Softplus { beta: 1.0 },
            },
        );
        let (feature, color_hidden) = match direction {
            Some(d) => {
                let feature = layer(&[w], w, Activation::Identity);
                let hidden = layer(&[w, d.width()], spec.color_width, Activation::Relu);
                (Some(feature), hidden)
            }
            None => (None, layer(&[w], spec.color_width, Activation::Relu)),
        };
        let color_out = layer(&[spec.color_width], 3, Activation::Sigmoid);
        Ok(NerfNet {
            position,
            direction,
            trunk,
            density,
            feature,
            color_hidden,
            color_out,
            warp,
            transparent_start: spec.unbounded.is_some()
                || matches!(spec.background, sdfl_stdlib::value::Background::Learned(_)),
            first,
            len: offset - first,
        })
    }

    /// Every layer with a stable name (checkpoints name tensors by it).
    pub fn layers(&self) -> Vec<(String, &Dense)> {
        let mut v: Vec<(String, &Dense)> = self
            .trunk
            .iter()
            .enumerate()
            .map(|(i, d)| (format!("trunk.{i}"), d))
            .collect();
        v.push(("density".into(), &self.density));
        if let Some(f) = &self.feature {
            v.push(("feature".into(), f));
        }
        v.push(("color_hidden".into(), &self.color_hidden));
        v.push(("color_out".into(), &self.color_out));
        v
    }

    /// PyTorch's default initialisation, layer by layer from one seed.
    pub fn init(&self, seed: u64) -> Vec<f32> {
        let mut params = vec![0.0; self.first + self.len];
        self.init_into(seed, &mut params);
        params
    }

    /// Writes the initial weights into `params[first..first + len]`.
    pub fn init_into(&self, seed: u64, params: &mut [f32]) {
        let mut rng = SplitMix64::new(seed ^ 0x6E65_7266);
        if let PositionEncoding::Grid { grid, offset } = &self.position {
            let n = grid.param_count();
            params[*offset..*offset + n].copy_from_slice(&grid.init(rng.next_u64()));
        }
        for (_, d) in self.layers() {
            d.init(params, &mut rng);
        }
        if self.transparent_start && self.density.act != Activation::Relu {
            let bias = self.density.offset + self.density.fan_in();
            params[bias] = UNBOUNDED_DENSITY_BIAS;
        }
    }

    /// Multiply-adds of one sample's forward pass.
    pub fn multiply_adds(&self) -> usize {
        self.layers().iter().map(|(_, d)| d.fan_in() * d.out).sum()
    }

    /// Density and colour at `rows` samples: `points` and `dirs` are rows of
    /// 3 (`dirs` ignored unless view-dependent). Results in `work.sigma`
    /// and `work.rgb`; the intermediates stay in `work` for
    /// [`Self::backward`].
    pub fn forward(&self, params: &[f32], points: &[f32], dirs: &[f32], work: &mut NerfWork) {
        match &self.warp {
            Some(c) => {
                let mut contracted = std::mem::take(&mut work.contracted);
                c.apply_all(points, &mut contracted);
                self.forward_encoded(params, &contracted, dirs, work);
                work.contracted = contracted;
            }
            None => self.forward_encoded(params, points, dirs, work),
        }
    }

    /// The density alone at `points` (rows of 3, in the scene; warped as
    /// [`Self::forward`] warps them), into `work.sigma`.
    pub fn density(&self, params: &[f32], points: &[f32], work: &mut NerfWork) {
        match &self.warp {
            Some(c) => {
                let mut contracted = std::mem::take(&mut work.contracted);
                c.apply_all(points, &mut contracted);
                self.density_encoded(params, &contracted, work);
                work.contracted = contracted;
            }
            None => self.density_encoded(params, points, work),
        }
    }

    /// [`Self::forward`] at points already in the encoding's space (the
    /// contracted cube of an unbounded scene; the world otherwise): an
    /// occupancy grid's cells.
    pub fn forward_encoded(
        &self,
        params: &[f32],
        points: &[f32],
        dirs: &[f32],
        work: &mut NerfWork,
    ) {
        self.density_encoded(params, points, work);
        self.colour(params, dirs, work);
    }

    /// The colour of the rows [`Self::density_encoded`] (or
    /// [`Self::density`]) left in `work`, into `work.rgb`; `dirs` as
    /// [`Self::forward`]'s. Rows may have been dropped between the two
    /// ([`NerfWork::keep_rows`]): only the kept ones are coloured.
    pub fn colour(&self, params: &[f32], dirs: &[f32], work: &mut NerfWork) {
        let NerfWork {
            dir_enc,
            hidden,
            feature,
            color_hidden,
            rgb,
            ..
        } = work;
        let h = hidden.last().expect("at least one layer");
        match (&self.feature, self.direction) {
            (Some(f), Some(de)) => {
                de.encode(dirs, dir_enc);
                f.forward(params, &[h], feature);
                self.color_hidden
                    .forward(params, &[feature, dir_enc], color_hidden);
            }
            _ => self.color_hidden.forward(params, &[h], color_hidden),
        }
        self.color_out.forward(params, &[color_hidden], rgb);
    }

    /// The density alone at points already in the encoding's space (into
    /// `work.sigma`; the trunk's activations are kept for the colour): an
    /// occupancy grid's refresh reads no colour.
    pub fn density_encoded(&self, params: &[f32], points: &[f32], work: &mut NerfWork) {
        let rows = points.len() / 3;
        work.resize(self, rows);
        let NerfWork {
            enc, hidden, sigma, ..
        } = work;
        match &self.position {
            PositionEncoding::Harmonic(h) => h.encode(points, enc),
            PositionEncoding::Grid { grid, offset } => grid.encode(
                &params[*offset..*offset + grid.param_count()],
                as_points(points),
                enc,
            ),
        }
        for (i, d) in self.trunk.iter().enumerate() {
            let (before, rest) = hidden.split_at_mut(i);
            let out = &mut rest[0];
            let prev: &[f32] = if i == 0 { enc } else { &before[i - 1] };
            if d.parts.len() == 2 {
                d.forward(params, &[prev, enc], out);
            } else {
                d.forward(params, &[prev], out);
            }
        }
        let h = hidden.last().expect("at least one layer");
        self.density.forward(params, &[h], sigma);
    }

    /// Adds `∂L/∂params` to `grad` given `∂L/∂σ` and `∂L/∂rgb` per sample
    /// (consumed: they are overwritten) after [`Self::forward`] of
    /// `points` on `work`.
    pub fn backward(
        &self,
        params: &[f32],
        points: &[f32],
        work: &mut NerfWork,
        d_sigma: &mut [f32],
        d_rgb: &mut [f32],
        grad: &mut [f32],
    ) {
        let NerfWork {
            enc,
            dir_enc,
            hidden,
            sigma,
            feature,
            color_hidden,
            rgb,
            d_a,
            d_b,
            d_color_hidden,
            d_feature,
            d_enc,
            touched,
            contracted,
        } = work;
        let grid = match &self.position {
            PositionEncoding::Grid { grid, offset } => Some((grid, *offset)),
            PositionEncoding::Harmonic(_) => None,
        };
        // A trainable encoding collects its adjoint from layer 0 and every skip.
        let mut enc_written = false;
        let h = hidden.last().expect("at least one layer");
        self.color_out.backward(
            params,
            &[color_hidden],
            rgb,
            d_rgb,
            &mut [Some(d_color_hidden)],
            false,
            grad,
        );
        // ∂L/∂h of the last trunk layer collects into d_a.
        match &self.feature {
            Some(f) => {
                self.color_hidden.backward(
                    params,
                    &[feature, dir_enc],
                    color_hidden,
                    d_color_hidden,
                    &mut [Some(d_feature), None],
                    false,
                    grad,
                );
                f.backward(
                    params,
                    &[h],
                    feature,
                    d_feature,
                    &mut [Some(d_a)],
                    false,
                    grad,
                );
            }
            None => self.color_hidden.backward(
                params,
                &[h],
                color_hidden,
                d_color_hidden,
                &mut [Some(d_a)],
                false,
                grad,
            ),
        }
        self.density
            .backward(params, &[h], sigma, d_sigma, &mut [Some(d_a)], true, grad);
        // Down the trunk, ping-ponging the adjoint between d_a and d_b.
        for i in (0..self.trunk.len()).rev() {
            let d = &self.trunk[i];
            let input: &[f32] = if i == 0 { enc } else { &hidden[i - 1] };
            let (d_out, d_in) = (&mut *d_a, &mut *d_b);
            let wants_enc = grid.is_some() && (i == 0 || d.parts.len() == 2);
            let accumulate_enc = enc_written;
            enc_written |= wants_enc;
            if i == 0 {
                let mut d_inputs = [wants_enc.then_some(d_enc.as_mut_slice())];
                d.backward(
                    params,
                    &[input],
                    &hidden[i],
                    d_out,
                    &mut d_inputs,
                    accumulate_enc,
                    grad,
                );
            } else if d.parts.len() == 2 {
                // One accumulate flag for both parts: the hidden adjoint is
                // zeroed first when the encoding's accumulates.
                if accumulate_enc {
                    d_in.iter_mut().for_each(|x| *x = 0.0);
                }
                let mut d_inputs = [
                    Some(d_in.as_mut_slice()),
                    wants_enc.then_some(d_enc.as_mut_slice()),
                ];
                d.backward(
                    params,
                    &[input, enc],
                    &hidden[i],
                    d_out,
                    &mut d_inputs,
                    accumulate_enc,
                    grad,
                );
            } else {
                let mut d_inputs = [Some(d_in.as_mut_slice())];
                d.backward(
                    params,
                    &[input],
                    &hidden[i],
                    d_out,
                    &mut d_inputs,
                    false,
                    grad,
                );
            }
            std::mem::swap(d_a, d_b);
        }
        if let Some((grid, offset)) = grid {
            touched.get_or_insert_with(|| grid.touched_set()).clear();
            // The grid saw the contracted points (kept by the forward pass).
            let seen = if self.warp.is_some() {
                &contracted[..]
            } else {
                points
            };
            grid.backward(
                as_points(seen),
                d_enc,
                &mut grad[offset..offset + grid.param_count()],
                touched.as_mut().expect("just made"),
            );
        }
    }
}

/// Buffers of a forward and backward pass, grown to the largest batch seen.
#[derive(Debug, Default)]
pub struct NerfWork {
    /// Encoded positions, one row per sample.
    pub enc: Vec<f32>,
    /// Encoded directions, one row per sample.
    pub dir_enc: Vec<f32>,
    /// Each trunk layer's activations.
    pub hidden: Vec<Vec<f32>>,
    /// Densities, one per sample.
    pub sigma: Vec<f32>,
    /// The trunk's features where the direction joins.
    pub feature: Vec<f32>,
    /// The colour branch's hidden activations.
    pub color_hidden: Vec<f32>,
    /// Colours, three per sample.
    pub rgb: Vec<f32>,
    d_a: Vec<f32>,
    d_b: Vec<f32>,
    d_color_hidden: Vec<f32>,
    d_feature: Vec<f32>,
    d_enc: Vec<f32>,
    touched: Option<Touched>,
    /// The contracted sample points (unbounded scenes).
    contracted: Vec<f32>,
}

impl NerfWork {
    /// Keeps only rows `keep` (ascending) of a density pass (the encoding,
    /// the trunk's activations, the density and the contracted points),
    /// moved to the front in order; the buffers shrink to them, so a
    /// [`NerfNet::colour`] and [`NerfNet::backward`] see those rows alone.
    pub fn keep_rows(&mut self, net: &NerfNet, keep: &[usize]) {
        fn compact(v: &mut [f32], width: usize, keep: &[usize]) {
            for (to, &from) in keep.iter().enumerate() {
                if to != from {
                    v.copy_within(from * width..(from + 1) * width, to * width);
                }
            }
        }
        let e = net.position.width();
        compact(&mut self.enc, e, keep);
        let w = net.trunk[0].out;
        for h in &mut self.hidden {
            compact(h, w, keep);
        }
        compact(&mut self.sigma, 1, keep);
        if net.warp.is_some() {
            compact(&mut self.contracted, 3, keep);
            self.contracted.truncate(3 * keep.len());
        }
        self.resize(net, keep.len());
    }

    fn resize(&mut self, net: &NerfNet, rows: usize) {
        let w = net.trunk[0].out;
        let set = |v: &mut Vec<f32>, n: usize| v.resize(n, 0.0);
        set(&mut self.enc, rows * net.position.width());
        self.hidden.resize_with(net.trunk.len(), Vec::new);
        for h in &mut self.hidden {
            set(h, rows * w);
        }
        set(&mut self.sigma, rows);
        set(&mut self.rgb, rows * 3);
        set(&mut self.color_hidden, rows * net.color_hidden.out);
        set(&mut self.d_color_hidden, rows * net.color_hidden.out);
        if let Some(d) = net.direction {
            set(&mut self.dir_enc, rows * d.width());
            set(&mut self.feature, rows * w);
            set(&mut self.d_feature, rows * w);
        }
        set(&mut self.d_a, rows * w);
        set(&mut self.d_b, rows * w);
        if net.position.is_trainable() {
            set(&mut self.d_enc, rows * net.position.width());
        }
    }
}

/// A NeRF network at its parameters (the fine network where there is one:
/// the one that renders).
pub struct NerfField<'a> {
    /// The network.
    pub net: &'a NerfNet,
    /// Its parameters.
    pub params: &'a [f32],
}

impl crate::export::RadianceField for NerfField<'_> {
    fn query(
        &self,
        points: &[[f32; 3]],
        dirs: &[[f32; 3]],
        sigma: &mut [f32],
        rgb: &mut [[f32; 3]],
    ) {
        let mut work = NerfWork::default();
        let rows = crate::export::NETWORK_ROWS;
        for (start, p) in (0..points.len()).step_by(rows).zip(points.chunks(rows)) {
            let end = start + p.len();
            let flat = p.as_flattened();
            let d = dirs[start..end].as_flattened();
            self.net.forward(self.params, flat, d, &mut work);
            sigma[start..end].copy_from_slice(&work.sigma[..p.len()]);
            for (c, w) in rgb[start..end].iter_mut().zip(work.rgb.chunks_exact(3)) {
                *c = [w[0], w[1], w[2]];
            }
        }
    }
}
