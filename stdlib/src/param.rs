//! Trainable parameters: `param(...)` declarations and the arguments that
//! read them.
//!
//! A parameter has an identity: `let c = param([0, 0, 0])` used in two
//! places is one parameter (the evaluator numbers each `param(...)` call
//! once, and every use shares its [`ParamDecl`]: identity is the `Arc`). Where an argument must stay
//! in a range (a radius above 0, a colour in 0..1) the use records the
//! [`Bound`], and training projects the parameter back into it after every
//! step, so a trained value never leaves the range a user could have typed.

use std::sync::Arc;

use glam::DVec3;

use crate::num::{Real, V3};
use sdfl_lang::Span;

/// The initial value of a parameter: a number or a vector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ParamInit {
    /// `param(0.5)`: one number.
    Scalar(f64),
    /// `param([0, 1, 0])`: three numbers trained together.
    Vec3(DVec3),
}

impl ParamInit {
    /// Number of scalars.
    pub fn len(&self) -> usize {
        match self {
            ParamInit::Scalar(_) => 1,
            ParamInit::Vec3(_) => 3,
        }
    }
    /// Never: a parameter holds one or three numbers.
    pub fn is_empty(&self) -> bool {
        false
    }
    /// The starting numbers, in order.
    pub fn values(&self) -> Vec<f64> {
        match self {
            ParamInit::Scalar(x) => vec![*x],
            ParamInit::Vec3(v) => v.to_array().to_vec(),
        }
    }
}

/// One `param(...)` call.
#[derive(Clone, PartialEq)]
pub struct ParamDecl {
    /// Dense number within the file, in evaluation order (indexes tables).
    pub id: usize,
    /// The starting value.
    pub init: ParamInit,
    /// The `param(...)` call.
    pub span: Span,
    /// The `let` it was bound to, if any: its name in reports.
    pub binding: Option<String>,
}

/// What the parameter is, not where it was written: its `Debug` form (which
/// run fingerprints hash) leaves out the span and the evaluation number, so
/// a comment or an unrelated line above it changes nothing.
impl std::fmt::Debug for ParamDecl {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ParamDecl")
            .field("init", &self.init)
            .field("binding", &self.binding)
            .finish()
    }
}

/// The range an argument must stay in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Bound {
    /// Any finite value.
    Free,
    /// At least this (a positive floor for radii, sizes, β, k).
    AtLeast(f64),
    /// Within `lo..=hi` (colours, opacities).
    Within(f64, f64),
}

impl Bound {
    /// Both ranges at once (a parameter used in two places).
    pub fn and(self, o: Bound) -> Bound {
        let (lo, hi) = self.limits();
        let (lo2, hi2) = o.limits();
        let (lo, hi) = (lo.max(lo2), hi.min(hi2));
        match (lo.is_finite(), hi.is_finite()) {
            (false, false) => Bound::Free,
            (true, false) => Bound::AtLeast(lo),
            _ => Bound::Within(lo, hi),
        }
    }
    /// The lowest and highest values allowed (infinite where open).
    pub fn limits(self) -> (f64, f64) {
        match self {
            Bound::Free => (f64::NEG_INFINITY, f64::INFINITY),
            Bound::AtLeast(lo) => (lo, f64::INFINITY),
            Bound::Within(lo, hi) => (lo, hi),
        }
    }
    /// `x` moved into the range. NaN stays NaN (`max`/`min` would turn it
    /// into a bound), so that training still reports it as an error.
    pub fn project(self, x: f64) -> f64 {
        let (lo, hi) = self.limits();
        if x.is_nan() {
            x
        } else {
            x.max(lo).min(hi)
        }
    }
}

/// Smallest trained value of a length that must be positive (a radius, a
/// side, a blend radius): far below anything visible, far above 0.
pub const MIN_LENGTH: f64 = 1e-4;
/// Smallest trained β: below it densities are steps that f32 cannot
/// differentiate usefully.
pub const MIN_BETA: f64 = 1e-4;

/// An argument read from a parameter.
#[derive(Debug, Clone)]
pub struct ParamUse {
    /// The parameter read.
    pub decl: Arc<ParamDecl>,
    /// The range this use needs; a parameter used twice keeps both.
    pub bound: Bound,
    /// Where it is used, `torus.major`: its name in reports unless a `let`
    /// names it.
    pub site: String,
}

impl PartialEq for ParamUse {
    fn eq(&self, o: &Self) -> bool {
        Arc::ptr_eq(&self.decl, &o.decl) && self.bound == o.bound && self.site == o.site
    }
}

/// A numeric argument of a shape, material or field: its value, and the
/// parameter it reads when trainable.
#[derive(Debug, Clone, PartialEq)]
pub struct Arg<T> {
    /// The value (the parameter's starting value when trainable).
    pub value: T,
    /// The parameter it reads, if trainable.
    pub param: Option<ParamUse>,
}

impl<T> Arg<T> {
    /// A value that never trains.
    pub fn fixed(value: T) -> Self {
        Arg { value, param: None }
    }
    /// Whether it reads a `param(...)`.
    pub fn is_param(&self) -> bool {
        self.param.is_some()
    }
}

impl From<f64> for Arg<f64> {
    fn from(v: f64) -> Self {
        Arg::fixed(v)
    }
}
impl From<DVec3> for Arg<DVec3> {
    fn from(v: DVec3) -> Self {
        Arg::fixed(v)
    }
}

/// Where the numeric arguments of a shape come from when it is evaluated:
/// their fixed values ([`Fixed`]), or trainable values with tangents.
pub trait ArgSource<T: Real> {
    /// The value (and tangent, when trained) of a scalar argument.
    fn scalar(&self, a: &Arg<f64>) -> T;
    /// The value (and tangents, when trained) of a vector argument.
    fn vector(&self, a: &Arg<DVec3>) -> V3<T>;
}

/// Every argument at its value (no parameters): the reference evaluator.
pub struct Fixed;

impl<T: Real> ArgSource<T> for Fixed {
    #[inline(always)]
    fn scalar(&self, a: &Arg<f64>) -> T {
        T::lit(a.value)
    }
    #[inline(always)]
    fn vector(&self, a: &Arg<DVec3>) -> V3<T> {
        V3::lit(a.value.to_array())
    }
}
