//! The machinery behind one declaration per primitive: `primitives!`
//! turns each entry of `primitives.rs` (name, doc, arguments with their
//! checks, defaults and test ranges, the formula call, bounds, exactness)
//! into a struct generic over where its numbers come from ([`Family`]),
//! one variant of [`Primitive`], an implementation of [`Declared`] and a row
//! of the registry [`Primitive::SPECS`]. Everything else (sampling,
//! parameter visiting, names, the built-in rows, the runtime's f32 leaf,
//! the tests) walks those, so nothing can leave a primitive out.

use glam::DVec3;

use super::{Aabb, Exactness, Primitive};
use crate::num::{Real, V3};
use crate::param::Arg;
use sdfl_lang::diag::Diag;

/// Where a primitive's numbers come from: its arguments as written (with
/// their parameters: [`Ir`]), plain f64 values ([`Val`], for bounds and
/// checks), or numbers of any [`Real`] type ([`Num`], for evaluation).
pub trait Family: 'static {
    /// A scalar argument.
    type S: Clone + Send + Sync + 'static;
    /// A 3-vector argument.
    type V: Clone + Send + Sync + 'static;
}

/// The scene IR: arguments with their trainable parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ir;
impl Family for Ir {
    type S = Arg<f64>;
    type V = Arg<DVec3>;
}

/// Plain values, for bounds and argument checks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Val;
impl Family for Val {
    type S = f64;
    type V = DVec3;
}

/// Numbers of type `T`, for evaluating the formula.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num<T>(std::marker::PhantomData<T>);
impl<T: Real> Family for Num<T> {
    type S = T;
    type V = V3<T>;
}

/// What a primitive's argument is. The order of trainable arguments
/// (scalars, then points, then vectors, each in declaration order) is the
/// order [`super::Shape::visit_params`] reports them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArgKind {
    /// A number.
    Scalar,
    /// A position: moved with the primitive (`center`, a capsule's ends).
    Point,
    /// A 3-vector that is not a position (sizes, radii, a normal).
    Vector,
    /// The axis a shape is built along (`"x"`, `"y"` or `"z"`): fixed.
    Axis,
}

/// How the built-in reads and checks an argument.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Check {
    /// Any finite value (trainable).
    Free,
    /// A length `> 0` (trained values stay at least `MIN_LENGTH`).
    Length,
    /// A number `≥ 0`.
    NonNegative,
    /// A number within `lo..=hi`.
    Within(f64, f64),
    /// Side lengths or semi-axes: a number (all three) or a vector, each `> 0`.
    Size,
    /// A nonzero direction, normalised (fixed).
    Direction,
    /// The axis names.
    Axis,
}

/// One argument of a primitive, as its entry declares it.
#[derive(Debug, Clone, Copy)]
pub struct ArgSpec {
    /// The keyword the argument is passed by in sdfl.
    pub name: &'static str,
    /// Scalar, point, vector or axis: how it is read and trained.
    pub kind: ArgKind,
    /// The values the argument accepts (checked when the call is read).
    pub check: Check,
    /// sdfl source text; `None`: required.
    pub default: Option<&'static str>,
    /// One line for the built-in's reference (`sdfl help`).
    pub doc: &'static str,
    /// Values the tests draw from (each component of a vector).
    pub range: (f64, f64),
}

/// A primitive's declaration: what the registry lists.
#[derive(Debug, Clone, Copy)]
pub struct PrimSpec {
    /// The built-in's name (also the kind in reports).
    pub name: &'static str,
    /// What the primitive is, for the built-in's reference.
    pub doc: &'static str,
    /// Its arguments, in declaration order.
    pub args: &'static [ArgSpec],
    /// Whether its formula is an exact distance or only a bound.
    pub exactness: Exactness,
    /// A bound on the gradient's norm.
    pub lipschitz: f64,
    /// The formula never branches on the point (only on constants), so it
    /// runs on lanes of points at once; otherwise lane by lane.
    pub lanes: bool,
}

/// Arguments that no value of the ranges can make valid: why, on which
/// argument (its span is reported), and how to fix it.
#[derive(Debug, Clone)]
pub struct Invalid {
    /// The argument the diagnostic points at (`None`: the whole call).
    pub arg: Option<&'static str>,
    /// What is wrong, with the offending values.
    pub message: String,
    /// The label under the argument's span.
    pub label: &'static str,
    /// How to make the arguments valid.
    pub help: &'static str,
}

/// Everything derived from one entry, for generic code: implemented by
/// each primitive's struct in the IR family.
pub trait Declared: Clone + Into<Primitive> + 'static {
    /// The struct in any family (`Self` is `Of<Ir>`).
    type Of<F: Family>: Clone + Send + Sync + 'static;
    /// The entry's declaration (its row of [`Primitive::SPECS`]).
    const SPEC: &'static PrimSpec;
    /// The struct with each number mapped.
    fn map<F: Family, G: Family>(
        x: &Self::Of<F>,
        s: impl Fn(&F::S) -> G::S,
        v: impl Fn(&F::V) -> G::V,
    ) -> Self::Of<G>;
    /// Itself as the IR struct (identity; lets generic code name it).
    fn ir(&self) -> &Self::Of<Ir>;
    /// The signed distance (or bound) at `p`.
    fn distance<T: Real>(x: &Self::Of<Num<T>>, p: V3<T>) -> T;
    /// The centre the rainbow material colours around.
    fn center<T: Real>(x: &Self::Of<Num<T>>) -> V3<T>;
    /// A box `B` with `distance(p) ≥ B.signed_distance(p)`; `None`: unbounded.
    fn bounds(x: &Self::Of<Val>) -> Option<Aabb>;
    /// Constraints between arguments that their checks alone miss.
    fn check(x: &Self::Of<Val>) -> Result<(), Invalid>;
    /// Eight members' values as lanes (`s` and `v` build a lane type from
    /// eight values); the fixed arguments (axes) are the first member's.
    fn gather<F: Family, G: Family>(
        ms: [&Self::Of<F>; 8],
        s: impl Fn([&F::S; 8]) -> G::S,
        v: impl Fn([&F::V; 8]) -> G::V,
    ) -> Self::Of<G>;
    /// Whether two members share their fixed arguments (axes), so they can
    /// be evaluated together by [`Declared::gather`].
    fn same_fixed<F: Family>(a: &Self::Of<F>, b: &Self::Of<F>) -> bool;
    /// The primitive from a call's arguments, each read and checked as
    /// declared (not yet [`Declared::check`]ed).
    fn read(r: &mut dyn ArgReader) -> Result<Self, Diag>;
    /// Draw a valid primitive from the declared ranges (`rng` uniform in
    /// `0..1`), retrying those [`Declared::check`] refuses.
    fn random(rng: &mut dyn FnMut() -> f64) -> Self;
}

/// Reads a call's arguments by name and declared check (the built-ins'
/// argument list implements it).
pub trait ArgReader {
    /// The number argument `name` (or a `param`), refused unless `check` holds.
    fn scalar(&mut self, name: &'static str, check: Check) -> Result<Arg<f64>, Diag>;
    /// The vector argument `name` (or a `param`), refused unless `check`
    /// holds; a direction is normalised and fixed.
    fn vector(&mut self, name: &'static str, check: Check) -> Result<Arg<DVec3>, Diag>;
    /// The axis name argument `name` (`x`, `y` or `z`).
    fn axis(&mut self, name: &'static str) -> Result<super::Axis, Diag>;
}

/// Code generic over the primitive kinds, called once per kind by
/// [`Primitive::for_each_kind`] (the runtime's packing, the tests).
pub trait KindVisitor {
    /// Called with each primitive kind `K` in turn.
    fn visit<K: Declared>(&mut self);
}

/// The f64 values of an IR struct.
pub fn values<K: Declared>(k: &K) -> K::Of<Val> {
    K::map::<Ir, Val>(k.ir(), |a| a.value, |a| a.value)
}

#[doc(hidden)]
pub fn draw_scalar(rng: &mut dyn FnMut() -> f64, (lo, hi): (f64, f64)) -> f64 {
    lo + (hi - lo) * rng()
}

#[doc(hidden)]
pub fn draw_vector(rng: &mut dyn FnMut() -> f64, r: (f64, f64), check: Check) -> DVec3 {
    let x = draw_scalar(rng, r);
    let y = draw_scalar(rng, r);
    let v = DVec3::new(x, y, draw_scalar(rng, r));
    // Directions are unit, as the built-in makes them.
    match check {
        Check::Direction => v.try_normalize().unwrap_or(DVec3::Y),
        _ => v,
    }
}

#[doc(hidden)]
pub fn draw_axis(rng: &mut dyn FnMut() -> f64) -> super::Axis {
    [super::Axis::X, super::Axis::Y, super::Axis::Z][((rng() * 3.0) as usize).min(2)]
}

/// The type of a field of kind `$kind` in family `$F`.
macro_rules! field_ty {
    (scalar, $F:ident) => {
        $F::S
    };
    (point, $F:ident) => {
        $F::V
    };
    (vector, $F:ident) => {
        $F::V
    };
    (axis, $F:ident) => {
        $crate::sdf::Axis
    };
}

macro_rules! arg_kind {
    (scalar) => {
        $crate::shape::declare::ArgKind::Scalar
    };
    (point) => {
        $crate::shape::declare::ArgKind::Point
    };
    (vector) => {
        $crate::shape::declare::ArgKind::Vector
    };
    (axis) => {
        $crate::shape::declare::ArgKind::Axis
    };
}

/// A field mapped by `s` (scalars) or `v` (vectors); axes copied.
macro_rules! map_field {
    (scalar, $x:expr, $s:ident, $v:ident) => {
        $s($x)
    };
    (point, $x:expr, $s:ident, $v:ident) => {
        $v($x)
    };
    (vector, $x:expr, $s:ident, $v:ident) => {
        $v($x)
    };
    (axis, $x:expr, $s:ident, $v:ident) => {
        *$x
    };
}

/// A field of eight members gathered into lanes.
macro_rules! gather_field {
    (axis, $ms:ident, $f:ident, $s:ident, $v:ident) => {
        $ms[0].$f
    };
    (scalar, $ms:ident, $f:ident, $s:ident, $v:ident) => {
        $s(std::array::from_fn(|i| &$ms[i].$f))
    };
    ($other:ident, $ms:ident, $f:ident, $s:ident, $v:ident) => {
        $v(std::array::from_fn(|i| &$ms[i].$f))
    };
}

/// Fixed fields compared (`true` for numbers).
macro_rules! same_fixed_field {
    (axis, $a:expr, $b:expr) => {
        $a == $b
    };
    ($other:ident, $a:expr, $b:expr) => {
        true
    };
}

/// A field drawn from its range.
macro_rules! draw_field {
    (scalar, $rng:ident, $r:expr, $c:expr) => {
        $crate::shape::declare::draw_scalar($rng, $r).into()
    };
    (point, $rng:ident, $r:expr, $c:expr) => {
        $crate::shape::declare::draw_vector($rng, $r, $c).into()
    };
    (vector, $rng:ident, $r:expr, $c:expr) => {
        $crate::shape::declare::draw_vector($rng, $r, $c).into()
    };
    (axis, $rng:ident, $r:expr, $c:expr) => {
        $crate::shape::declare::draw_axis($rng)
    };
}

/// A field read from a call.
macro_rules! read_field {
    (scalar, $r:ident, $name:expr, $c:expr) => {
        $r.scalar($name, $c)?
    };
    (point, $r:ident, $name:expr, $c:expr) => {
        $r.vector($name, $c)?
    };
    (vector, $r:ident, $name:expr, $c:expr) => {
        $r.vector($name, $c)?
    };
    (axis, $r:ident, $name:expr, $c:expr) => {
        $r.axis($name)?
    };
}

/// A field as an [`ArgValue`].
macro_rules! arg_value {
    (scalar, $x:expr) => {
        ArgValue::Scalar($x)
    };
    (point, $x:expr) => {
        ArgValue::Vector($x)
    };
    (vector, $x:expr) => {
        ArgValue::Vector($x)
    };
    (axis, $x:expr) => {
        ArgValue::Axis(*$x)
    };
}

/// `f(field)` when the field is of kind `$want`.
macro_rules! visit_field {
    (scalar, scalar, $x:expr, $f:ident) => {
        if let Some(u) = &$x.param {
            $f(u)
        }
    };
    (point, point, $x:expr, $f:ident) => {
        if let Some(u) = &$x.param {
            $f(u)
        }
    };
    (vector, vector, $x:expr, $f:ident) => {
        if let Some(u) = &$x.param {
            $f(u)
        }
    };
    ($want:ident, $kind:ident, $x:expr, $f:ident) => {};
}

/// `Some(&mut field)` for points, moved with the primitive.
macro_rules! point_field {
    (point, $x:expr, $out:ident) => {
        $out.push(&mut $x.value)
    };
    ($kind:ident, $x:expr, $out:ident) => {};
}

macro_rules! default_text {
    (req) => {
        None
    };
    ($d:literal) => {
        Some($d)
    };
}

/// Declares every primitive (see `primitives.rs` for the entries and
/// [`Declared`] for what each part means).
macro_rules! primitives {
    ($(
        $Name:ident $name:literal $doc:literal {
            $( $field:ident : $kind:ident ( $check:expr, $default:tt, $lo:literal .. $hi:literal, $adoc:expr ) ),+ $(,)?
        }
        distance($ds:ident, $dp:ident) = $dist:expr;
        center($cs:ident) = $center:expr;
        bounds($bs:ident) = $bounds:expr;
        exactness = $exact:ident;
        lipschitz = $lip:expr;
        lanes = $lanes:literal;
        check($ks:ident) = $checks:expr;
    )+) => {
        /// The primitives' structs, generic over where their numbers come
        /// from; `shape::Torus` and the like name them in the IR family.
        pub mod generic {
            #[allow(unused_imports)]
            use super::*;
            $(
                #[doc = $doc]
                pub struct $Name<F: Family> {
                    $( #[doc = $adoc] pub $field: field_ty!($kind, F), )+
                }

                impl<F: Family> Clone for $Name<F> {
                    #[inline(always)]
                    fn clone(&self) -> Self {
                        $Name { $( $field: self.$field.clone(), )+ }
                    }
                }
            )+
        }

        $(
            #[doc = $doc]
            pub type $Name = generic::$Name<Ir>;

            impl std::fmt::Debug for generic::$Name<Ir> {
                fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                    f.debug_struct(stringify!($Name))
                        $( .field(stringify!($field), &self.$field) )+
                        .finish()
                }
            }

            impl PartialEq for generic::$Name<Ir> {
                fn eq(&self, o: &Self) -> bool {
                    true $( && self.$field == o.$field )+
                }
            }

            impl From<generic::$Name<Ir>> for Primitive {
                fn from(p: generic::$Name<Ir>) -> Primitive {
                    Primitive::$Name(p)
                }
            }

            impl From<generic::$Name<Ir>> for Shape {
                fn from(p: generic::$Name<Ir>) -> Shape {
                    Shape::Prim(Primitive::$Name(p))
                }
            }

            impl Declared for generic::$Name<Ir> {
                type Of<F: Family> = generic::$Name<F>;
                const SPEC: &'static PrimSpec = &PrimSpec {
                    name: $name,
                    doc: $doc,
                    args: &[$(ArgSpec {
                        name: stringify!($field),
                        kind: arg_kind!($kind),
                        check: $check,
                        default: default_text!($default),
                        doc: $adoc,
                        range: ($lo, $hi),
                    }),+],
                    exactness: Exactness::$exact,
                    lipschitz: $lip,
                    lanes: $lanes,
                };
                #[inline(always)]
                fn map<F: Family, G: Family>(
                    x: &generic::$Name<F>,
                    s: impl Fn(&F::S) -> G::S,
                    v: impl Fn(&F::V) -> G::V,
                ) -> generic::$Name<G> {
                    let _ = (&s, &v);
                    generic::$Name { $( $field: map_field!($kind, &x.$field, s, v), )+ }
                }
                fn ir(&self) -> &Self {
                    self
                }
                #[inline(always)]
                fn distance<T: Real>($ds: &generic::$Name<Num<T>>, $dp: V3<T>) -> T {
                    $dist
                }
                #[inline(always)]
                fn center<T: Real>($cs: &generic::$Name<Num<T>>) -> V3<T> {
                    $center
                }
                fn bounds($bs: &generic::$Name<Val>) -> Option<Aabb> {
                    $bounds
                }
                fn check($ks: &generic::$Name<Val>) -> Result<(), Invalid> {
                    $checks
                }
                #[inline(always)]
                fn gather<F: Family, G: Family>(
                    ms: [&generic::$Name<F>; 8],
                    s: impl Fn([&F::S; 8]) -> G::S,
                    v: impl Fn([&F::V; 8]) -> G::V,
                ) -> generic::$Name<G> {
                    let _ = (&s, &v);
                    generic::$Name { $( $field: gather_field!($kind, ms, $field, s, v), )+ }
                }
                fn same_fixed<F: Family>(a: &generic::$Name<F>, b: &generic::$Name<F>) -> bool {
                    let _ = (a, b);
                    true $( && same_fixed_field!($kind, a.$field, b.$field) )+
                }
                fn read(r: &mut dyn ArgReader) -> Result<Self, Diag> {
                    Ok(generic::$Name { $( $field: read_field!($kind, r, stringify!($field), $check), )+ })
                }
                fn random(rng: &mut dyn FnMut() -> f64) -> Self {
                    for _ in 0..10_000 {
                        let x: Self = generic::$Name { $( $field: draw_field!($kind, rng, ($lo, $hi), $check), )+ };
                        if Self::check(&values(&x)).is_ok() {
                            return x;
                        }
                    }
                    panic!("{}: its ranges never pass its check", $name)
                }
            }
        )+

        /// One analytic primitive of the scene IR: one variant per entry.
        #[derive(Debug, Clone, PartialEq)]
        pub enum Primitive {
            $( #[doc = $doc] $Name($Name), )+
        }

        impl Primitive {
            /// The registry: every primitive's declaration, in entry order.
            pub const SPECS: &'static [&'static PrimSpec] = &[$( <$Name as Declared>::SPEC, )+];

            /// This primitive's declaration.
            pub fn spec(&self) -> &'static PrimSpec {
                match self {
                    $( Primitive::$Name(_) => <$Name as Declared>::SPEC, )+
                }
            }

            /// A valid primitive of kind `kind` (an index into
            /// [`Self::SPECS`]) drawn from its declared ranges, `rng`
            /// uniform in `0..1`: what the tests iterate.
            pub fn random(kind: usize, rng: &mut dyn FnMut() -> f64) -> Primitive {
                const DRAW: &[fn(&mut dyn FnMut() -> f64) -> Primitive] =
                    &[$( |r| Primitive::$Name(<$Name as Declared>::random(r)), )+];
                DRAW[kind](rng)
            }

            /// Calls `v.visit::<K>()` for every primitive kind `K`, in entry order.
            pub fn for_each_kind(v: &mut impl KindVisitor) {
                $( v.visit::<$Name>(); )+
            }

            /// The primitive at `p` in any number type, its arguments read
            /// through `args`: the distance and the rainbow's centre.
            #[inline(always)]
            pub fn sample<T: Real, A: ArgSource<T>>(&self, p: V3<T>, args: &A) -> (T, V3<T>) {
                match self {
                    $( Primitive::$Name(x) => {
                        let at = <$Name as Declared>::map::<Ir, Num<T>>(x, |a| args.scalar(a), |a| args.vector(a));
                        (<$Name as Declared>::distance(&at, p), <$Name as Declared>::center(&at))
                    } )+
                }
            }

            /// Its trainable arguments: scalars, then points, then vectors,
            /// each in declaration order.
            pub fn visit_params<'s>(&'s self, f: &mut dyn FnMut(&'s ParamUse)) {
                match self {
                    $( Primitive::$Name(x) => {
                        $( visit_field!(scalar, $kind, x.$field, f); )+
                        $( visit_field!(point, $kind, x.$field, f); )+
                        $( visit_field!(vector, $kind, x.$field, f); )+
                    } )+
                }
            }

            /// Its bounds (see [`Declared::bounds`]).
            pub fn bounds(&self) -> Option<Aabb> {
                match self {
                    $( Primitive::$Name(x) => <$Name as Declared>::bounds(&values(x)), )+
                }
            }

            /// The rainbow's centre in f64.
            pub fn center(&self) -> DVec3 {
                match self {
                    $( Primitive::$Name(x) => {
                        let at = <$Name as Declared>::map::<Ir, Num<f64>>(x, |a| a.value, |a| V3::lit(a.value.to_array()));
                        let c = <$Name as Declared>::center(&at);
                        DVec3::new(c.x, c.y, c.z)
                    } )+
                }
            }

            /// The values of its points (moved with it), to move it.
            pub fn points_mut(&mut self) -> Vec<&mut DVec3> {
                let mut out: Vec<&mut DVec3> = Vec::new();
                match self {
                    $( Primitive::$Name(x) => {
                        let _ = &x;
                        $( point_field!($kind, x.$field, out); )+
                    } )+
                }
                out
            }

            /// Its arguments in declaration order (the built-in's).
            pub fn args(&self) -> Vec<ArgValue<'_>> {
                match self {
                    $( Primitive::$Name(x) => vec![$( arg_value!($kind, &x.$field) ),+], )+
                }
            }

            /// Calls `w.with(x)` with the primitive as its own type.
            pub fn with<W: WithDeclared>(&self, w: W) -> W::Out {
                match self {
                    $( Primitive::$Name(x) => w.with(x), )+
                }
            }
        }
    };
}

pub(crate) use {
    arg_kind, arg_value, default_text, draw_field, field_ty, gather_field, map_field, point_field,
    primitives, read_field, same_fixed_field, visit_field,
};

/// One argument of a primitive ([`Primitive::args`]).
#[derive(Debug, Clone, Copy)]
pub enum ArgValue<'a> {
    /// A number, with its parameter if trainable.
    Scalar(&'a Arg<f64>),
    /// A point or vector, with its parameter if trainable.
    Vector(&'a Arg<DVec3>),
    /// An axis (fixed, never trained).
    Axis(super::Axis),
}

/// Code generic over one primitive, given as its own type
/// ([`Primitive::with`]): the runtime's lowering to its f32 leaf.
pub trait WithDeclared {
    /// What the code returns.
    type Out;
    /// Called once with the primitive as its declared type `K`.
    fn with<K: Declared>(self, x: &K) -> Self::Out;
}
