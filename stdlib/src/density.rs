//! Every density, defined once: how a signed distance becomes absorption
//! along a ray. One [`Density`] impl per density holds its built-in's name,
//! doc and `alpha` range, whether it takes a neural SDF, and its formulas
//! over [`Real`], so the f32 renderer, the traced training tape, the dual
//! kernels, the neural surface and the f64 references all run the same
//! code; derivatives come from [`crate::num::Dual`], none is written by hand.
//!
//! The `densities!` macro lists the densities once: it makes [`DensityKind`] (one
//! variant each), the dispatch methods on it (exhaustive matches) and
//! [`visit_densities`], which the built-ins table and the tests iterate, so
//! a density left out of either cannot compile or fails a test.
//!
//! Every form evaluates one `exp(−|sdf|/β) ∈ [0, 1]`, and the two sides of
//! the surface are selected ([`Real::if_gt`]), not branched on, so no side
//! can overflow: tiny β and huge |sdf| give finite values and derivatives.

use crate::num::Real;

/// What one sample absorbs: its opacity `a` and the kept fraction `1 − a`,
/// each formed without cancellation.
#[derive(Debug, Clone, Copy)]
pub struct Absorption<T> {
    /// `a`: the share of light the sample stops.
    pub opacity: T,
    /// `1 − a`: the share it lets through.
    pub keep: T,
}

/// Whether, and how, a density sees a neural SDF trained from images.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NeuralUse {
    /// Shapes only.
    Refused,
    /// Each sample absorbs `σ(f)·Δ`; `alpha` scales σ.
    PerSample,
    /// Each interval between consecutive samples absorbs a depth of the
    /// two distances; no `alpha`.
    PerInterval,
}

impl NeuralUse {
    /// Whether `alpha` means anything for a neural SDF.
    pub fn takes_alpha(self) -> bool {
        self == NeuralUse::PerSample
    }
}

/// One density. `inv_beta` is `1/β`, computed once per ray so that hot
/// loops do not divide.
pub trait Density {
    /// Its variant of [`DensityKind`].
    const KIND: DensityKind;
    /// The built-in that makes a volume with it.
    const NAME: &'static str;
    /// Its name in messages ("NeuS").
    const TITLE: &'static str;
    /// The built-in's documentation.
    const DOC: &'static str;
    /// `alpha`'s default, as sdfl source.
    const ALPHA_DEFAULT: &'static str;
    /// The largest `alpha` (1 where it is an opacity); the smallest is
    /// [`ALPHA_MIN`] for all.
    const ALPHA_MAX: f64;
    /// Whether, and how, it takes a neural SDF.
    const NEURAL: NeuralUse;
    /// Whether a sample absorbs a fixed opacity whatever its interval
    /// ([`Density::sigma`] is then that opacity, composited as one).
    const PER_SAMPLE_OPACITY: bool = false;

    /// The density `σ` at signed distance `sdf` (for a per-sample opacity
    /// form, that opacity: what a density export writes).
    fn sigma<T: Real>(sdf: T, alpha: T, inv_beta: T) -> T;

    /// What a sample absorbs over an interval of length `delta`.
    #[inline(always)]
    fn absorption<T: Real>(sdf: T, alpha: T, inv_beta: T, delta: T) -> Absorption<T> {
        let tau = Self::sigma(sdf, alpha, inv_beta) * delta;
        Absorption {
            opacity: -(-tau).exp_m1(),
            keep: (-tau).exp(),
        }
    }

    /// `ln(1 − a)` of [`Density::absorption`], finite wherever the kept
    /// fraction underflows (the log-transmittance step).
    #[inline(always)]
    fn log_keep<T: Real>(sdf: T, alpha: T, inv_beta: T, delta: T) -> T {
        -(Self::sigma(sdf, alpha, inv_beta) * delta)
    }

    /// The optical depth sample `k` of a neural SDF's ray adds, `f` its
    /// distance, `next` the next sample's (`None` at the ray's last) and
    /// `delta` its interval. It may branch on values: scalar types only.
    #[inline(always)]
    fn neural_depth<T: Real>(f: T, next: Option<T>, alpha: T, inv_beta: T, delta: T) -> T {
        let _ = next;
        -Self::log_keep(f, alpha, inv_beta, delta)
    }
}

/// The smallest `alpha` of every density (trained values stay above it).
pub const ALPHA_MIN: f64 = 1e-6;

/// Something done for every density ([`visit_densities`]).
pub trait DensityVisitor {
    /// Called once for each density `D`.
    fn visit<D: Density>(&mut self);
}

macro_rules! densities {
    ($($(#[doc = $doc:literal])* $name:ident),* $(,)?) => {
        /// How an SDF becomes absorption in a volume: one variant per
        /// [`Density`].
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
        #[serde(rename_all = "snake_case")]
        pub enum DensityKind {
            $($(#[doc = $doc])* $name,)*
        }

        $(
            $(#[doc = $doc])*
            #[derive(Debug, Clone, Copy)]
            pub struct $name;
        )*

        /// Calls `v.visit::<D>()` for every density, in the order listed.
        pub fn visit_densities(v: &mut impl DensityVisitor) {
            $(v.visit::<$name>();)*
        }

        impl DensityKind {
            /// Every density, in the order listed.
            pub const ALL: &'static [DensityKind] = &[$(DensityKind::$name),*];

            /// [`Density::NAME`].
            pub fn name(self) -> &'static str {
                match self { $(DensityKind::$name => $name::NAME,)* }
            }
            /// [`Density::TITLE`].
            pub fn title(self) -> &'static str {
                match self { $(DensityKind::$name => $name::TITLE,)* }
            }
            /// [`Density::ALPHA_MAX`].
            pub fn alpha_max(self) -> f64 {
                match self { $(DensityKind::$name => $name::ALPHA_MAX,)* }
            }
            /// [`Density::NEURAL`].
            pub fn neural(self) -> NeuralUse {
                match self { $(DensityKind::$name => $name::NEURAL,)* }
            }
            /// [`Density::PER_SAMPLE_OPACITY`].
            pub fn per_sample_opacity(self) -> bool {
                match self { $(DensityKind::$name => $name::PER_SAMPLE_OPACITY,)* }
            }
            /// [`Density::sigma`].
            #[inline(always)]
            pub fn sigma<T: Real>(self, sdf: T, alpha: T, inv_beta: T) -> T {
                match self { $(DensityKind::$name => $name::sigma(sdf, alpha, inv_beta),)* }
            }
            /// [`Density::absorption`].
            #[inline(always)]
            pub fn absorption<T: Real>(self, sdf: T, alpha: T, inv_beta: T, delta: T) -> Absorption<T> {
                match self { $(DensityKind::$name => $name::absorption(sdf, alpha, inv_beta, delta),)* }
            }
            /// [`Density::log_keep`].
            #[inline(always)]
            pub fn log_keep<T: Real>(self, sdf: T, alpha: T, inv_beta: T, delta: T) -> T {
                match self { $(DensityKind::$name => $name::log_keep(sdf, alpha, inv_beta, delta),)* }
            }
            /// [`Density::neural_depth`].
            #[inline(always)]
            pub fn neural_depth<T: Real>(self, f: T, next: Option<T>, alpha: T, inv_beta: T, delta: T) -> T {
                match self { $(DensityKind::$name => $name::neural_depth(f, next, alpha, inv_beta, delta),)* }
            }
        }
    };
}

densities! {
    /// The assignment's opacity form `α·Ψ_β(−sdf)` per sample (parts 1–2).
    Opacity,
    /// VolSDF: density `σ = α·Ψ_β(−sdf)` (part 7).
    VolSdf,
    /// NeuS: the logistic density for shapes (part 8.3), the unbiased
    /// interval opacity for neural SDFs.
    Neus,
}

/// `α·Ψ_β(−sdf)` (Ψ_β the Laplace CDF) from one `e = exp(−|sdf|/β)`:
/// `α·e/2` outside, `α − α·e/2` inside.
#[inline(always)]
fn laplace<T: Real>(sdf: T, alpha: T, inv_beta: T) -> T {
    let e = (-sdf.abs() * inv_beta).exp();
    let out = alpha * e * T::lit(0.5);
    T::if_gt(T::zero(), sdf, alpha - out, out)
}

/// `softplus(x) = ln(1 + eˣ)` without overflow.
#[inline(always)]
fn softplus<T: Real>(x: T) -> T {
    x.max(T::zero()) + (-x.abs()).exp().ln_1p()
}

impl Density for Opacity {
    const KIND: DensityKind = DensityKind::Opacity;
    const NAME: &'static str = "sdf_volume";
    const TITLE: &'static str = "opacity";
    const DOC: &'static str = "An SDF as a volume, the assignment's form: per-sample opacity `alpha·Ψ_β(-sdf)` (Laplace CDF), 0 < alpha ≤ 1.";
    const ALPHA_DEFAULT: &'static str = "1";
    const ALPHA_MAX: f64 = 1.0;
    const NEURAL: NeuralUse = NeuralUse::Refused;
    const PER_SAMPLE_OPACITY: bool = true;

    #[inline(always)]
    fn sigma<T: Real>(sdf: T, alpha: T, inv_beta: T) -> T {
        laplace(sdf, alpha, inv_beta)
    }

    /// `o = α·Ψ_β(−sdf)` per sample (`delta` unused); `1 − o` formed so
    /// that it is exact at α = 1 (inside: `e/2`, never `1 − (1 − e/2)`).
    /// Both sides are formed and one selected (lanes of samples may lie
    /// on both).
    #[inline(always)]
    fn absorption<T: Real>(sdf: T, alpha: T, inv_beta: T, _delta: T) -> Absorption<T> {
        let e = (-sdf.abs() * inv_beta).exp();
        let out = alpha * e * T::lit(0.5);
        let inside = T::zero();
        Absorption {
            opacity: T::if_gt(inside, sdf, alpha - out, out),
            keep: T::if_gt(inside, sdf, (T::one() - alpha) + out, T::one() - out),
        }
    }

    /// Inside a shape with α = 1 the kept fraction is `e/2`, whose
    /// logarithm is `ln ½ − |sdf|/β` exactly (no underflow).
    #[inline(always)]
    fn log_keep<T: Real>(sdf: T, alpha: T, inv_beta: T, _delta: T) -> T {
        let half = T::lit(0.5);
        let x = -sdf.abs() * inv_beta;
        let e = x.exp();
        let outside = (-(alpha * e * half)).ln_1p();
        let inside = if alpha.val() == 1.0 {
            // ln(e/2) without forming e/2, which may underflow; the second
            // term is 0 at α = 1 but carries ∂/∂α = 1 − 2/e (e floored so
            // that the tangent stays finite in f32).
            let e = e.max(T::lit(1e-20));
            T::lit(0.5f64.ln()) + x + (alpha - T::one()) * (T::one() - T::lit(2.0) / e)
        } else {
            ((T::one() - alpha) + alpha * e * half).ln()
        };
        T::if_gt(T::zero(), sdf, inside, outside)
    }
}

impl Density for VolSdf {
    const KIND: DensityKind = DensityKind::VolSdf;
    const NAME: &'static str = "volsdf";
    const TITLE: &'static str = "VolSDF";
    const DOC: &'static str = "An SDF as a VolSDF volume: density `σ = alpha·Ψ_β(-sdf)`.";
    const ALPHA_DEFAULT: &'static str = "10";
    const ALPHA_MAX: f64 = f64::INFINITY;
    const NEURAL: NeuralUse = NeuralUse::PerSample;

    #[inline(always)]
    fn sigma<T: Real>(sdf: T, alpha: T, inv_beta: T) -> T {
        laplace(sdf, alpha, inv_beta)
    }
}

impl Density for Neus {
    const KIND: DensityKind = DensityKind::Neus;
    const NAME: &'static str = "neus";
    const TITLE: &'static str = "NeuS";
    const DOC: &'static str = "An SDF as a NeuS volume. A shape: logistic density `alpha·(1/β)·s(1-s)`, `s = sigmoid(-sdf/β)` (the course assignment's form). A `neural_sdf(...)`: NeuS's unbiased opacity between consecutive samples, `max(0, (Φ(f_k) − Φ(f_k+1))/Φ(f_k))` with `Φ = sigmoid(f/β)`, no `alpha`; nothing lies beyond the last sample, whatever the sampler's `last_interval`.";
    const ALPHA_DEFAULT: &'static str = "1";
    const ALPHA_MAX: f64 = f64::INFINITY;
    const NEURAL: NeuralUse = NeuralUse::PerInterval;

    /// `(α/β)·s(1 − s)`, `s = sigmoid(−sdf/β)`, as `e/(1 + e)²` with
    /// `e = exp(−|sdf|/β)` (even in sdf, bounded).
    #[inline(always)]
    fn sigma<T: Real>(sdf: T, alpha: T, inv_beta: T) -> T {
        let e = (-sdf.abs() * inv_beta).exp();
        let one_e = T::one() + e;
        alpha * inv_beta * e / (one_e * one_e)
    }

    /// NeuS's opacity of the interval from `f` to `next` (Wang et al.,
    /// 2021): with `Φ(f) = sigmoid(f/β)` it is `max(0, (Φ(f) − Φ(next))/Φ(f))`,
    /// so the depth is `max(0, ln Φ(f) − ln Φ(next))`. Weights built from
    /// it peak where the ray enters the zero level set, without the
    /// logistic density's bias, and a ray leaving a surface (`f` rising)
    /// absorbs nothing; the last sample absorbs nothing.
    #[inline(always)]
    fn neural_depth<T: Real>(f: T, next: Option<T>, _alpha: T, inv_beta: T, _delta: T) -> T {
        let Some(f_b) = next else {
            return T::zero();
        };
        let (x_a, x_b) = (f * inv_beta, f_b * inv_beta);
        // ln Φ(x) = −softplus(−x). Both inside: ln Φ(x) = x − ln(1 + eˣ),
        // and x_a − x_b is taken from the distances so that deep inside
        // (|x| huge) nothing cancels.
        let tau = if x_a.val() <= 0.0 && x_b.val() <= 0.0 {
            (f - f_b) * inv_beta - (x_a.exp().ln_1p() - x_b.exp().ln_1p())
        } else {
            softplus(-x_b) - softplus(-x_a)
        };
        if tau.val() > 0.0 {
            tau
        } else {
            T::zero()
        }
    }
}
