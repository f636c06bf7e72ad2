//! What a NeRF's rays see behind the field: a fixed colour, or a colour
//! learned from the ray's direction (for photographs without alpha, whose
//! background is the world). The learned one is a tiny network over the
//! rays of a batch: the unit direction harmonically encoded → one ReLU
//! layer → sigmoid RGB. It is composited with each ray's remaining
//! transmittance `T_n`, so `∂L/∂bg = T_n·∂L/∂C`, and trained with the field.

use sdfl_stdlib::value::{Background, LearnedBackground};

use super::encoding::Harmonic;
use super::mlp::{Activation, Dense};
use crate::volume::{Ray, SplitMix64};

/// A learned background's layers and where they live in the flat
/// parameters (after the field's networks).
#[derive(Debug, Clone)]
pub struct LearnedNet {
    /// The encoding of the ray's direction.
    pub encoding: Harmonic,
    /// The hidden ReLU layer.
    pub hidden: Dense,
    /// The sigmoid colour layer.
    pub out: Dense,
    /// Where its parameters start in the flat vector.
    pub first: usize,
    /// How many parameters it has.
    pub len: usize,
}

/// Buffers of one batch of rays.
#[derive(Debug, Default)]
pub struct BackdropWork {
    dirs: Vec<f32>,
    enc: Vec<f32>,
    hidden: Vec<f32>,
    rgb: Vec<f32>,
    d_hidden: Vec<f32>,
}

/// The background of a NeRF as the runtime computes it.
#[derive(Debug, Clone)]
pub enum Backdrop {
    /// A fixed colour.
    Color([f32; 3]),
    /// A colour learned from the ray's direction.
    Learned(LearnedNet),
}

impl Backdrop {
    /// The backdrop of `spec` with any parameters from `first` on
    /// (`Background::Data` unresolved is black, as outside a `train`).
    pub fn new(spec: &Background, first: usize) -> Self {
        match spec {
            Background::Data | Background::Color(_) => {
                Backdrop::Color(spec.color().unwrap_or([0.0; 3]).map(|x| x as f32))
            }
            Background::Learned(l) => Backdrop::Learned(LearnedNet::new(l, first)),
        }
    }

    /// Trainable scalars.
    pub fn len(&self) -> usize {
        match self {
            Backdrop::Color(_) => 0,
            Backdrop::Learned(n) => n.len,
        }
    }

    /// Whether it has no parameters (a fixed colour).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The learned layers with their names (none for a colour).
    pub fn layers(&self) -> Vec<(String, &Dense)> {
        match self {
            Backdrop::Color(_) => Vec::new(),
            Backdrop::Learned(n) => vec![
                ("background.hidden".into(), &n.hidden),
                ("background.out".into(), &n.out),
            ],
        }
    }

    /// PyTorch's default initialisation of the learned layers.
    pub fn init_into(&self, seed: u64, params: &mut [f32]) {
        let mut rng = SplitMix64::new(seed ^ 0x6267_6e64);
        for (_, d) in self.layers() {
            d.init(params, &mut rng);
        }
    }

    /// One colour per ray into `out` (resized).
    pub fn colours(
        &self,
        params: &[f32],
        rays: &[Ray],
        work: &mut BackdropWork,
        out: &mut Vec<[f32; 3]>,
    ) {
        out.clear();
        match self {
            Backdrop::Color(c) => out.resize(rays.len(), *c),
            Backdrop::Learned(n) => {
                n.forward(params, rays, work);
                out.extend(work.rgb.chunks(3).map(|c| [c[0], c[1], c[2]]));
            }
        }
    }

    /// Adds `∂L/∂params` given `∂L/∂colour` per ray, after
    /// [`Self::colours`] of the same rays on `work` (nothing for a colour).
    pub fn backward(
        &self,
        params: &[f32],
        work: &mut BackdropWork,
        d_colour: &[[f32; 3]],
        grad: &mut [f32],
    ) {
        if let Backdrop::Learned(n) = self {
            n.backward(params, work, d_colour, grad);
        }
    }
}

impl LearnedNet {
    /// The network `spec` describes, its parameters from `first` on.
    pub fn new(spec: &LearnedBackground, first: usize) -> Self {
        let encoding = Harmonic {
            dims: 3,
            freqs: spec.freqs,
            include_input: true,
        };
        let hidden = Dense::new(&[encoding.width()], spec.width, Activation::Relu, first);
        let out = Dense::new(&[spec.width], 3, Activation::Sigmoid, hidden.end());
        LearnedNet {
            encoding,
            len: out.end() - first,
            hidden,
            out,
            first,
        }
    }

    fn forward(&self, params: &[f32], rays: &[Ray], w: &mut BackdropWork) {
        let n = rays.len();
        w.dirs.clear();
        // The unit direction: the colour of a direction, whatever the
        // length of the ray's vector.
        for r in rays {
            let d = r.dir;
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
                .sqrt()
                .max(f32::MIN_POSITIVE);
            w.dirs.extend(d.map(|x| x / len));
        }
        w.enc.resize(n * self.encoding.width(), 0.0);
        self.encoding.encode(&w.dirs, &mut w.enc);
        w.hidden.resize(n * self.hidden.out, 0.0);
        self.hidden.forward(params, &[&w.enc], &mut w.hidden);
        w.rgb.resize(n * 3, 0.0);
        self.out.forward(params, &[&w.hidden], &mut w.rgb);
    }

    fn backward(
        &self,
        params: &[f32],
        w: &mut BackdropWork,
        d_colour: &[[f32; 3]],
        grad: &mut [f32],
    ) {
        let mut d_rgb: Vec<f32> = d_colour.iter().flatten().copied().collect();
        w.d_hidden.resize(w.hidden.len(), 0.0);
        self.out.backward(
            params,
            &[&w.hidden],
            &w.rgb,
            &mut d_rgb,
            &mut [Some(&mut w.d_hidden)],
            false,
            grad,
        );
        self.hidden.backward(
            params,
            &[&w.enc],
            &w.hidden,
            &mut w.d_hidden,
            &mut [None],
            false,
            grad,
        );
    }
}
