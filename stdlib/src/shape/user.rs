//! Shapes users write themselves: `sdf(f, bound: ..)` turns a `fn` of the
//! point into a shape. The function is compiled once (in
//! `eval::user`) into a [`Tape`]: a flat SSA list of scalar operations
//! over the point's coordinates and the shape's arguments, vectors
//! scalarised. The tape is evaluated by one generic interpreter over
//! [`Real`], so the f64 reference, the f32 tracer, lanes, duals and the
//! training tape all run the same instructions; [`Tape::analyse`] bounds it
//! by interval arithmetic over the bound box (refusing results that can
//! be infinite) and estimates its Lipschitz constant.
//!
//! A user shape's value is `max(f(clamp(p, box)) / L, box(p))`: the
//! function is only ever evaluated inside its declared box (so huge
//! coordinates stay finite), divided by its Lipschitz bound `L` (so a
//! function that is not an exact distance still never overshoots), and
//! never below the box's distance (the bound invariant culling relies on).
//! The result is 1-Lipschitz: every evaluator and the tracer take it as is.

use std::collections::HashMap;
use std::mem::MaybeUninit;
use std::sync::Arc;

use glam::DVec3;
use sdfl_lang::Span;

use super::{Aabb, ArgSource};
use crate::num::{Real, V3};
use crate::param::{Arg, ParamUse};

/// The built-in that makes a user shape.
pub const BUILTIN: &str = "sdf";

/// Most instructions of one compiled function.
pub const MAX_OPS: usize = 4096;

/// Most numbers among a user shape's arguments (vectors count three).
pub const MAX_ARGS: usize = 256;

/// One instruction: its operands are earlier instructions' indices.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Op {
    /// A coordinate of the point: 0, 1, 2 for x, y, z.
    Input(u8),
    /// A constant.
    Const(f64),
    /// The shape's argument number `i` (vectors as three numbers).
    Arg(u32),
    /// `a + b`.
    Add(u32, u32),
    /// `a - b`.
    Sub(u32, u32),
    /// `a · b`.
    Mul(u32, u32),
    /// `a / b`.
    Div(u32, u32),
    /// The smaller (the first on ties).
    Min(u32, u32),
    /// The larger (the first on ties).
    Max(u32, u32),
    /// `-a`.
    Neg(u32),
    /// `|a|`.
    Abs(u32),
    /// `√max(a, 0)`.
    Sqrt(u32),
    /// `sin a`.
    Sin(u32),
    /// `cos a`.
    Cos(u32),
    /// `eᵃ`.
    Exp(u32),
    /// The largest whole number ≤ a.
    Floor(u32),
    /// `√(a² + b²)`: the length of a 2-vector (kept whole: its gradient's
    /// norm is that of its operands', which the Lipschitz estimate uses).
    Hypot2(u32, u32),
    /// `√(a² + b² + c²)`.
    Hypot3(u32, u32, u32),
    /// `then` where `a > b`, else `otherwise`: a select, both computed.
    IfGt(u32, u32, u32, u32),
}

impl Op {
    /// Its operands.
    pub fn operands(&self) -> Vec<u32> {
        match *self {
            Op::Input(_) | Op::Const(_) | Op::Arg(_) => vec![],
            Op::Neg(a)
            | Op::Abs(a)
            | Op::Sqrt(a)
            | Op::Sin(a)
            | Op::Cos(a)
            | Op::Exp(a)
            | Op::Floor(a) => vec![a],
            Op::Add(a, b)
            | Op::Sub(a, b)
            | Op::Mul(a, b)
            | Op::Div(a, b)
            | Op::Min(a, b)
            | Op::Max(a, b)
            | Op::Hypot2(a, b) => vec![a, b],
            Op::Hypot3(a, b, c) => vec![a, b, c],
            Op::IfGt(a, b, c, d) => vec![a, b, c, d],
        }
    }

    /// The same operation on operands renamed by `m` (a tape rewritten
    /// into another: baked, pruned).
    fn map_operands(self, m: impl Fn(u32) -> u32) -> Op {
        match self {
            Op::Input(_) | Op::Const(_) | Op::Arg(_) => self,
            Op::Add(a, c) => Op::Add(m(a), m(c)),
            Op::Sub(a, c) => Op::Sub(m(a), m(c)),
            Op::Mul(a, c) => Op::Mul(m(a), m(c)),
            Op::Div(a, c) => Op::Div(m(a), m(c)),
            Op::Min(a, c) => Op::Min(m(a), m(c)),
            Op::Max(a, c) => Op::Max(m(a), m(c)),
            Op::Neg(a) => Op::Neg(m(a)),
            Op::Abs(a) => Op::Abs(m(a)),
            Op::Sqrt(a) => Op::Sqrt(m(a)),
            Op::Sin(a) => Op::Sin(m(a)),
            Op::Cos(a) => Op::Cos(m(a)),
            Op::Exp(a) => Op::Exp(m(a)),
            Op::Floor(a) => Op::Floor(m(a)),
            Op::Hypot2(a, c) => Op::Hypot2(m(a), m(c)),
            Op::Hypot3(a, c, d) => Op::Hypot3(m(a), m(c), m(d)),
            Op::IfGt(a, c, d, e) => Op::IfGt(m(a), m(c), m(d), m(e)),
        }
    }

    /// The arithmetic it computes and its operands (unused ones 0);
    /// `None` for the point's coordinates, constants and arguments. What
    /// compilers of the tape into other forms read (the runtime's register
    /// code), so every form computes with [`Func::apply`].
    pub fn func(&self) -> Option<(Func, [u32; 4])> {
        Some(match *self {
            Op::Input(_) | Op::Const(_) | Op::Arg(_) => return None,
            Op::Add(a, b) => (Func::Add, [a, b, 0, 0]),
            Op::Sub(a, b) => (Func::Sub, [a, b, 0, 0]),
            Op::Mul(a, b) => (Func::Mul, [a, b, 0, 0]),
            Op::Div(a, b) => (Func::Div, [a, b, 0, 0]),
            Op::Min(a, b) => (Func::Min, [a, b, 0, 0]),
            Op::Max(a, b) => (Func::Max, [a, b, 0, 0]),
            Op::Neg(a) => (Func::Neg, [a, 0, 0, 0]),
            Op::Abs(a) => (Func::Abs, [a, 0, 0, 0]),
            Op::Sqrt(a) => (Func::Sqrt, [a, 0, 0, 0]),
            Op::Sin(a) => (Func::Sin, [a, 0, 0, 0]),
            Op::Cos(a) => (Func::Cos, [a, 0, 0, 0]),
            Op::Exp(a) => (Func::Exp, [a, 0, 0, 0]),
            Op::Floor(a) => (Func::Floor, [a, 0, 0, 0]),
            Op::Hypot2(a, b) => (Func::Hypot2, [a, b, 0, 0]),
            Op::Hypot3(a, b, c) => (Func::Hypot3, [a, b, c, 0]),
            Op::IfGt(a, b, c, d) => (Func::IfGt, [a, b, c, d]),
        })
    }

    /// The operation on values of any number type (`r` reads an operand).
    /// Each arm names its [`Func`], so the match on it folds away.
    #[inline(always)]
    fn apply<T: Real>(&self, p: &V3<T>, args: &[T], r: impl Fn(u32) -> T) -> T {
        match *self {
            Op::Input(0) => p.x,
            Op::Input(1) => p.y,
            Op::Input(_) => p.z,
            Op::Const(c) => T::lit(c),
            Op::Arg(i) => args[i as usize],
            Op::Add(a, b) => Func::Add.apply(|k| r([a, b][k])),
            Op::Sub(a, b) => Func::Sub.apply(|k| r([a, b][k])),
            Op::Mul(a, b) => Func::Mul.apply(|k| r([a, b][k])),
            Op::Div(a, b) => Func::Div.apply(|k| r([a, b][k])),
            Op::Min(a, b) => Func::Min.apply(|k| r([a, b][k])),
            Op::Max(a, b) => Func::Max.apply(|k| r([a, b][k])),
            Op::Neg(a) => Func::Neg.apply(|_| r(a)),
            Op::Abs(a) => Func::Abs.apply(|_| r(a)),
            Op::Sqrt(a) => Func::Sqrt.apply(|_| r(a)),
            Op::Sin(a) => Func::Sin.apply(|_| r(a)),
            Op::Cos(a) => Func::Cos.apply(|_| r(a)),
            Op::Exp(a) => Func::Exp.apply(|_| r(a)),
            Op::Floor(a) => Func::Floor.apply(|_| r(a)),
            Op::Hypot2(a, b) => Func::Hypot2.apply(|k| r([a, b][k])),
            Op::Hypot3(a, b, c) => Func::Hypot3.apply(|k| r([a, b, c][k])),
            Op::IfGt(a, b, t, e) => Func::IfGt.apply(|k| r([a, b, t, e][k])),
        }
    }
}

/// The arithmetic of an instruction, apart from where its operands are:
/// the one definition of what each operation computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Func {
    /// `a + b`.
    Add,
    /// `a - b`.
    Sub,
    /// `a · b`.
    Mul,
    /// `a / b`.
    Div,
    /// The smaller (the first on ties).
    Min,
    /// The larger (the first on ties).
    Max,
    /// `-a`.
    Neg,
    /// `|a|`.
    Abs,
    /// `√max(a, 0)`.
    Sqrt,
    /// `sin a`.
    Sin,
    /// `cos a`.
    Cos,
    /// `eᵃ`.
    Exp,
    /// The largest whole number ≤ a.
    Floor,
    /// `√(a² + b²)`.
    Hypot2,
    /// `√(a² + b² + c²)`.
    Hypot3,
    /// `c` where `a > b`, else `d`.
    IfGt,
}

impl Func {
    /// The operation on values of any number type; `x(k)` gives operand
    /// `k` (read only for the operands the operation has).
    #[inline(always)]
    pub fn apply<T: Real>(self, x: impl Fn(usize) -> T) -> T {
        match self {
            Func::Add => x(0) + x(1),
            Func::Sub => x(0) - x(1),
            Func::Mul => x(0) * x(1),
            Func::Div => x(0) / x(1),
            Func::Min => x(0).min(x(1)),
            Func::Max => x(0).max(x(1)),
            Func::Neg => -x(0),
            Func::Abs => x(0).abs(),
            Func::Sqrt => x(0).max(T::zero()).sqrt(),
            Func::Sin => x(0).sin(),
            Func::Cos => x(0).cos(),
            Func::Exp => x(0).exp(),
            Func::Floor => x(0).floor(),
            Func::Hypot2 => {
                let (a, b) = (x(0), x(1));
                (a * a + b * b).sqrt()
            }
            Func::Hypot3 => {
                let (a, b, c) = (x(0), x(1), x(2));
                (a * a + b * b + c * c).sqrt()
            }
            Func::IfGt => T::if_gt(x(0), x(1), x(2), x(3)),
        }
    }
}

/// A compiled function of the point: instructions, each with the span of
/// the expression it computes (for diagnostics), and the result's index.
#[derive(Debug, Clone, PartialEq)]
pub struct Tape {
    ops: Vec<Op>,
    spans: Vec<Span>,
    out: u32,
    args: usize,
}

/// Builds a [`Tape`]: folds constants and shares repeated instructions.
#[derive(Debug, Default)]
pub struct TapeBuilder {
    ops: Vec<Op>,
    spans: Vec<Span>,
    seen: HashMap<OpKey, u32>,
    args: usize,
}

/// An instruction as a hash key (constants by their bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct OpKey(u8, u64, [u32; 4]);

fn key(op: &Op) -> OpKey {
    let mut ops = [0u32; 4];
    for (i, a) in op.operands().into_iter().enumerate() {
        ops[i] = a;
    }
    let (tag, extra) = match *op {
        Op::Input(i) => (0, i as u64),
        Op::Const(c) => (1, c.to_bits()),
        Op::Arg(i) => (2, i as u64),
        Op::Add(..) => (3, 0),
        Op::Sub(..) => (4, 0),
        Op::Mul(..) => (5, 0),
        Op::Div(..) => (6, 0),
        Op::Min(..) => (7, 0),
        Op::Max(..) => (8, 0),
        Op::Neg(..) => (9, 0),
        Op::Abs(..) => (10, 0),
        Op::Sqrt(..) => (11, 0),
        Op::Sin(..) => (12, 0),
        Op::Cos(..) => (13, 0),
        Op::Exp(..) => (14, 0),
        Op::Floor(..) => (15, 0),
        Op::Hypot2(..) => (16, 0),
        Op::Hypot3(..) => (17, 0),
        Op::IfGt(..) => (18, 0),
    };
    OpKey(tag, extra, ops)
}

impl TapeBuilder {
    /// An empty tape.
    pub fn new() -> Self {
        Self::default()
    }

    /// How many instructions so far.
    pub fn len(&self) -> usize {
        self.ops.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.ops.is_empty()
    }

    /// The constant an instruction computes, if it does.
    pub fn constant(&self, i: u32) -> Option<f64> {
        match self.ops[i as usize] {
            Op::Const(c) => Some(c),
            _ => None,
        }
    }

    /// Adds `op` (computed by the source at `span`) and returns its index:
    /// the constant when all its operands are constants, an earlier equal
    /// instruction when there is one. Operands must be earlier indices.
    pub fn push(&mut self, op: Op, span: Span) -> u32 {
        let operands = op.operands();
        let n = self.ops.len() as u32;
        assert!(operands.iter().all(|&a| a < n), "operands come first");
        if let Op::Arg(i) = op {
            self.args = self.args.max(i as usize + 1);
        }
        let folds = !operands.is_empty() && operands.iter().all(|&a| self.constant(a).is_some());
        let op = if folds {
            let ops = &self.ops;
            let c = op.apply::<f64>(&V3::splat(0.0), &[], |a| match ops[a as usize] {
                Op::Const(c) => c,
                _ => unreachable!("every operand is a constant"),
            });
            Op::Const(c)
        } else {
            op
        };
        let k = key(&op);
        if let Some(&i) = self.seen.get(&k) {
            return i;
        }
        self.ops.push(op);
        self.spans.push(span);
        self.seen.insert(k, n);
        n
    }

    /// The tape whose result is instruction `out`.
    pub fn finish(self, out: u32) -> Tape {
        assert!(
            (out as usize) < self.ops.len(),
            "the result is an instruction"
        );
        Tape {
            ops: self.ops,
            spans: self.spans,
            out,
            args: self.args,
        }
    }
}

/// Registers of the interpreter kept on the stack up to this many
/// instructions (longer tapes use the heap).
const INLINE: usize = 128;

impl Tape {
    /// The instructions.
    pub fn ops(&self) -> &[Op] {
        &self.ops
    }

    /// Where instruction `i` comes from in the source.
    pub fn span(&self, i: usize) -> Span {
        self.spans[i]
    }

    /// The instruction whose value is the result.
    pub fn out(&self) -> u32 {
        self.out
    }

    /// How many argument numbers it reads.
    pub fn arg_count(&self) -> usize {
        self.args
    }

    /// The function at `p` with arguments `args` (at least
    /// [`Tape::arg_count`] of them), in any number type.
    #[inline]
    pub fn eval<T: Real>(&self, p: V3<T>, args: &[T]) -> T {
        assert!(args.len() >= self.args, "every argument is given");
        if self.ops.len() <= INLINE {
            let mut regs = [MaybeUninit::<T>::uninit(); INLINE];
            self.run(p, args, &mut regs)
        } else {
            let mut regs = vec![MaybeUninit::<T>::uninit(); self.ops.len()];
            self.run(p, args, &mut regs)
        }
    }

    #[inline(always)]
    fn run<T: Real>(&self, p: V3<T>, args: &[T], regs: &mut [MaybeUninit<T>]) -> T {
        let regs = &mut regs[..self.ops.len()];
        for i in 0..self.ops.len() {
            let v = self.ops[i].apply(&p, args, |a| {
                // SAFETY: `TapeBuilder::push` asserts every operand is an
                // earlier instruction, written by an earlier iteration, and
                // `a < i < regs.len()`.
                unsafe { regs.get_unchecked(a as usize).assume_init() }
            });
            regs[i].write(v);
        }
        // SAFETY: `finish` asserts `out` is an instruction; all are written.
        unsafe { regs[self.out as usize].assume_init() }
    }

    /// The tape with its arguments replaced by these constants (folded):
    /// what an evaluator that never trains runs.
    pub fn bake(&self, args: &[f64]) -> Tape {
        let mut b = TapeBuilder::new();
        let mut map = Vec::with_capacity(self.ops.len());
        for (op, span) in self.ops.iter().zip(&self.spans) {
            let m = |a: u32| map[a as usize];
            let op = match *op {
                Op::Arg(i) => Op::Const(args[i as usize]),
                op => op.map_operands(m),
            };
            map.push(b.push(op, *span));
        }
        let out = map[self.out as usize];
        // Only what the result reads.
        b.finish(out).pruned()
    }

    /// Without the instructions the result does not read.
    fn pruned(&self) -> Tape {
        let mut live = vec![false; self.ops.len()];
        live[self.out as usize] = true;
        for i in (0..self.ops.len()).rev() {
            if live[i] {
                for a in self.ops[i].operands() {
                    live[a as usize] = true;
                }
            }
        }
        let mut b = TapeBuilder::new();
        let mut map = vec![0u32; self.ops.len()];
        for i in 0..self.ops.len() {
            if !live[i] {
                continue;
            }
            let m = |a: u32| map[a as usize];
            let op = self.ops[i].map_operands(m);
            map[i] = b.push(op, self.spans[i]);
        }
        let out = map[self.out as usize];
        b.finish(out)
    }

    /// Interval arithmetic over the box `lo..hi` with the arguments at
    /// `args`: each instruction's range, the first instruction whose range
    /// is not finite in f32, the precision shapes run in (from finite
    /// operands: `1e30 · 1e30` is finite in f64 and infinite on the lanes),
    /// and a bound on the gradient's
    /// norm over the box (infinite where none is derived: a division by
    /// a range holding 0, `floor`, a select whose condition changes).
    pub fn analyse(&self, lo: DVec3, hi: DVec3, args: &[f64]) -> Analysis {
        let mut at: Vec<Bounds> = Vec::with_capacity(self.ops.len());
        let mut unbounded = None;
        let mut past_f32 = false;
        const F32_MAX: f64 = f32::MAX as f64;
        for (i, op) in self.ops.iter().enumerate() {
            let b = bounds_of(op, &at, lo, hi, args);
            let finite = b.lo >= -F32_MAX && b.hi <= F32_MAX;
            if !finite && unbounded.is_none() {
                unbounded = Some(i);
                past_f32 = b.lo.is_finite() && b.hi.is_finite();
            }
            at.push(b);
        }
        let out = at[self.out as usize];
        Analysis {
            range: (out.lo, out.hi),
            unbounded,
            past_f32,
            lipschitz: if unbounded.is_some() {
                f64::INFINITY
            } else {
                out.lip
            },
        }
    }
}

/// What [`Tape::analyse`] finds over a box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Analysis {
    /// The result's range.
    pub range: (f64, f64),
    /// The first instruction whose range is not finite in f32.
    pub unbounded: Option<usize>,
    /// Whether that range is finite in f64, only past f32's (±3.4e38).
    pub past_f32: bool,
    /// A bound on the result's gradient norm (infinite: none derived).
    pub lipschitz: f64,
}

/// An instruction's range, a bound on its gradient's norm and which
/// coordinates its gradient may have (bits 0, 1, 2 for x, y, z).
#[derive(Debug, Clone, Copy)]
struct Bounds {
    lo: f64,
    hi: f64,
    lip: f64,
    support: u8,
}

impl Bounds {
    fn constant(lo: f64, hi: f64) -> Bounds {
        Bounds {
            lo,
            hi,
            lip: 0.0,
            support: 0,
        }
    }
    /// The largest magnitude.
    fn mag(&self) -> f64 {
        self.lo.abs().max(self.hi.abs())
    }
    /// The smallest magnitude (0 when the range holds 0).
    fn mig(&self) -> f64 {
        if self.lo <= 0.0 && self.hi >= 0.0 {
            0.0
        } else {
            self.lo.abs().min(self.hi.abs())
        }
    }
}

/// A bound on `|Σ ∇fᵢ·wᵢ|` for terms `(|wᵢ|·Lᵢ, supportᵢ)`: gradients of
/// terms on disjoint coordinates are orthogonal (their norms add in
/// quadrature), overlapping ones add.
fn sum_norm(terms: &[(f64, u8)]) -> (f64, u8) {
    let support = terms.iter().fold(0, |s, t| s | t.1);
    let disjoint = terms
        .iter()
        .enumerate()
        .all(|(i, a)| terms[i + 1..].iter().all(|b| a.1 & b.1 == 0));
    let lip = if disjoint {
        terms.iter().map(|t| t.0 * t.0).sum::<f64>().sqrt()
    } else {
        terms.iter().map(|t| t.0).sum()
    };
    (lip, support)
}

/// The norm of a Jacobian whose rows have norms `Lᵢ` on coordinates
/// `supportᵢ` (the gradient of a vector's length is its unit direction
/// times this Jacobian): rows on disjoint coordinates form separate
/// blocks, the norm is the largest block's (each block at most its
/// Frobenius norm).
fn rows_norm(rows: &[(f64, u8)]) -> (f64, u8) {
    let support = rows.iter().fold(0, |s, t| s | t.1);
    // Blocks: rows sharing coordinates merged until none do (constant
    // rows, with no coordinates, add nothing).
    let mut blocks: Vec<(f64, u8)> = rows.iter().map(|&(l, s)| (l * l, s)).collect();
    let mut merged = true;
    while merged {
        merged = false;
        'find: for i in 0..blocks.len() {
            for j in i + 1..blocks.len() {
                if blocks[i].1 & blocks[j].1 != 0 {
                    let b = blocks.swap_remove(j);
                    blocks[i] = (blocks[i].0 + b.0, blocks[i].1 | b.1);
                    merged = true;
                    break 'find;
                }
            }
        }
    }
    let lip = blocks.iter().map(|b| b.0.sqrt()).fold(0.0, f64::max);
    (lip, support)
}

fn mul_range(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    let c = [a.0 * b.0, a.0 * b.1, a.1 * b.0, a.1 * b.1];
    if c.iter().any(|x| x.is_nan()) {
        return (f64::NEG_INFINITY, f64::INFINITY);
    }
    (
        c.iter().copied().fold(f64::INFINITY, f64::min),
        c.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    )
}

/// The range of `sin` over `lo..=hi`: the ends, and ±1 where a peak
/// (`π/2 + 2kπ`) or trough (`-π/2 + 2kπ`) lies between them.
fn sin_range(lo: f64, hi: f64) -> (f64, f64) {
    use std::f64::consts::{FRAC_PI_2, TAU};
    // NaN widths too.
    if (hi - lo).partial_cmp(&TAU) != Some(std::cmp::Ordering::Less) {
        return (-1.0, 1.0);
    }
    // Whether `c + 2kπ` lies in the range for some whole k.
    let holds = |c: f64| ((lo - c) / TAU).ceil() * TAU + c <= hi;
    let (a, b) = (lo.sin(), hi.sin());
    let low = if holds(-FRAC_PI_2) { -1.0 } else { a.min(b) };
    let high = if holds(FRAC_PI_2) { 1.0 } else { a.max(b) };
    // Rounding of the ends' sines: widened by an ulp's worth.
    (low - 1e-15, high + 1e-15)
}

fn bounds_of(op: &Op, at: &[Bounds], lo: DVec3, hi: DVec3, args: &[f64]) -> Bounds {
    let g = |a: u32| at[a as usize];
    match *op {
        Op::Input(i) => Bounds {
            lo: lo[i as usize],
            hi: hi[i as usize],
            lip: 1.0,
            support: 1 << i,
        },
        Op::Const(c) => Bounds::constant(c, c),
        Op::Arg(i) => Bounds::constant(args[i as usize], args[i as usize]),
        Op::Add(a, b) | Op::Sub(a, b) => {
            let (a, b) = (g(a), g(b));
            let (l, h) = if matches!(op, Op::Add(..)) {
                (a.lo + b.lo, a.hi + b.hi)
            } else {
                (a.lo - b.hi, a.hi - b.lo)
            };
            let (lip, support) = sum_norm(&[(a.lip, a.support), (b.lip, b.support)]);
            Bounds {
                lo: l,
                hi: h,
                lip,
                support,
            }
        }
        Op::Mul(ia, ib) => {
            let (a, b) = (g(ia), g(ib));
            let (l, h) = if ia == ib {
                // A square is never below 0.
                (a.mig() * a.mig(), a.mag() * a.mag())
            } else {
                mul_range((a.lo, a.hi), (b.lo, b.hi))
            };
            let (lip, support) =
                sum_norm(&[(b.mag() * a.lip, a.support), (a.mag() * b.lip, b.support)]);
            Bounds {
                lo: l,
                hi: h,
                lip,
                support,
            }
        }
        Op::Div(a, b) => {
            let (a, b) = (g(a), g(b));
            let (l, h) = if b.mig() > 0.0 {
                mul_range((a.lo, a.hi), (1.0 / b.hi, 1.0 / b.lo))
            } else {
                (f64::NEG_INFINITY, f64::INFINITY)
            };
            let m = b.mig();
            let (lip, support) = sum_norm(&[
                (a.lip / m, a.support),
                (a.mag() * b.lip / (m * m), b.support),
            ]);
            Bounds {
                lo: l,
                hi: h,
                lip: if lip.is_nan() { f64::INFINITY } else { lip },
                support,
            }
        }
        Op::Min(a, b) | Op::Max(a, b) => {
            let (a, b) = (g(a), g(b));
            let (l, h) = if matches!(op, Op::Min(..)) {
                (a.lo.min(b.lo), a.hi.min(b.hi))
            } else {
                (a.lo.max(b.lo), a.hi.max(b.hi))
            };
            Bounds {
                lo: l,
                hi: h,
                lip: a.lip.max(b.lip),
                support: a.support | b.support,
            }
        }
        Op::Neg(a) => {
            let a = g(a);
            Bounds {
                lo: -a.hi,
                hi: -a.lo,
                ..a
            }
        }
        Op::Abs(a) => {
            let a = g(a);
            Bounds {
                lo: a.mig(),
                hi: a.mag(),
                ..a
            }
        }
        Op::Sqrt(a) => {
            let a = g(a);
            let (l, h) = (a.lo.max(0.0).sqrt(), a.hi.max(0.0).sqrt());
            let lip = if a.lip == 0.0 {
                0.0
            } else if a.lo > 0.0 {
                a.lip / (2.0 * l)
            } else {
                f64::INFINITY
            };
            Bounds {
                lo: l,
                hi: h,
                lip,
                support: a.support,
            }
        }
        Op::Sin(a) | Op::Cos(a) => {
            let a = g(a);
            // cos x = sin(x + π/2).
            let shift = if matches!(op, Op::Cos(_)) {
                std::f64::consts::FRAC_PI_2
            } else {
                0.0
            };
            let (l, h) = sin_range(a.lo + shift, a.hi + shift);
            Bounds { lo: l, hi: h, ..a }
        }
        Op::Exp(a) => {
            let a = g(a);
            let (l, h) = (a.lo.exp(), a.hi.exp());
            Bounds {
                lo: l,
                hi: h,
                lip: a.lip * h,
                support: a.support,
            }
        }
        Op::Floor(a) => {
            let a = g(a);
            Bounds {
                lo: a.lo.floor(),
                hi: a.hi.floor(),
                // A step function: no Lipschitz bound unless constant.
                lip: if a.lip == 0.0 || a.lo.floor() == a.hi.floor() {
                    0.0
                } else {
                    f64::INFINITY
                },
                support: a.support,
            }
        }
        Op::Hypot2(..) | Op::Hypot3(..) => {
            let parts: Vec<Bounds> = op.operands().into_iter().map(g).collect();
            let lo2: f64 = parts.iter().map(|b| b.mig() * b.mig()).sum();
            let hi2: f64 = parts.iter().map(|b| b.mag() * b.mag()).sum();
            let rows: Vec<(f64, u8)> = parts.iter().map(|b| (b.lip, b.support)).collect();
            let (lip, support) = rows_norm(&rows);
            Bounds {
                lo: lo2.sqrt(),
                hi: hi2.sqrt(),
                lip,
                support,
            }
        }
        Op::IfGt(a, b, t, e) => {
            let (a, b, t, e) = (g(a), g(b), g(t), g(e));
            if a.lo > b.hi {
                t
            } else if a.hi <= b.lo {
                e
            } else {
                // The condition changes within the box: a jump, unless the
                // branches meet there (not known here).
                Bounds {
                    lo: t.lo.min(e.lo),
                    hi: t.hi.max(e.hi),
                    lip: f64::INFINITY,
                    support: t.support | e.support | a.support | b.support,
                }
            }
        }
    }
}

/// An argument of a user shape, as its `fn` receives it.
#[derive(Debug, Clone, PartialEq)]
pub enum UserArg {
    /// A number (trainable with `param`).
    Scalar(Arg<f64>),
    /// A 3-vector (trainable with `param`).
    Vector(Arg<DVec3>),
}

impl UserArg {
    /// How many of the tape's argument numbers it fills.
    pub fn width(&self) -> usize {
        match self {
            UserArg::Scalar(_) => 1,
            UserArg::Vector(_) => 3,
        }
    }
}

/// A shape written by the user: `sdf(f, ...)`.
#[derive(Debug, Clone, PartialEq)]
pub struct UserShape {
    /// The `fn`'s name (for reports).
    pub name: String,
    /// The compiled function of the point and the arguments.
    pub tape: Arc<Tape>,
    /// The arguments, in the tape's order.
    pub args: Vec<UserArg>,
    /// The box the shape lies in (`bound:`): the function is evaluated
    /// only inside it.
    pub bound: Aabb,
    /// The function's Lipschitz bound over the box (declared, derived, or
    /// 1): its value is divided by it.
    pub lipschitz: f64,
}

impl UserShape {
    /// Instructions a built-in primitive's distance is worth: one
    /// evaluation in the estimates (a rounded box takes about a dozen).
    pub const OPS_PER_EVALUATION: usize = 12;

    /// What one evaluation of this shape counts in the estimates: its
    /// instructions in primitive distances, at least one.
    pub fn evaluation_cost(&self) -> f64 {
        (self.tape.ops().len() as f64 / Self::OPS_PER_EVALUATION as f64).max(1.0)
    }

    /// The arguments' values as the tape reads them.
    pub fn arg_values(&self) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.tape.arg_count());
        for a in &self.args {
            match a {
                UserArg::Scalar(s) => out.push(s.value),
                UserArg::Vector(v) => out.extend(v.value.to_array()),
            }
        }
        out
    }

    /// The shape at `p`, its arguments read from `source`.
    pub fn sample<T: Real, A: ArgSource<T>>(&self, p: V3<T>, source: &A) -> T {
        let mut args: Vec<T> = Vec::with_capacity(self.tape.arg_count());
        for a in &self.args {
            match a {
                UserArg::Scalar(s) => args.push(source.scalar(s)),
                UserArg::Vector(v) => args.extend(source.vector(v).to_array()),
            }
        }
        self.distance_with(p, |q| self.tape.eval(q, &args))
    }

    /// `max(f(clamp(p)) / L, box(p))` for the function `f` (see the module).
    #[inline(always)]
    pub fn distance_with<T: Real>(&self, p: V3<T>, f: impl FnOnce(V3<T>) -> T) -> T {
        clipped(p, &self.bound, 1.0 / self.lipschitz, f)
    }

    /// Its trainable arguments in order.
    pub fn visit_params<'s>(&'s self, f: &mut dyn FnMut(&'s ParamUse)) {
        for a in &self.args {
            let p = match a {
                UserArg::Scalar(s) => &s.param,
                UserArg::Vector(v) => &v.param,
            };
            if let Some(u) = p {
                f(u)
            }
        }
    }
}

/// `max(f(clamp(p, box)) · inv_l, box(p))`: a function known inside a box,
/// scaled to be 1-Lipschitz there, continued outside as a bound.
#[inline(always)]
pub fn clipped<T: Real>(p: V3<T>, b: &Aabb, inv_l: f64, f: impl FnOnce(V3<T>) -> T) -> T {
    let q = V3::new(
        p.x.clamp(b.min.x, b.max.x),
        p.y.clamp(b.min.y, b.max.y),
        p.z.clamp(b.min.z, b.max.z),
    );
    let inside = f(q) * T::lit(inv_l);
    // The box's distance, its offsets capped at `FAR` (so squares stay
    // finite in f32 at any coordinate; a capped offset only lowers the
    // bound, which stays 1-Lipschitz).
    const FAR: f64 = 1e15;
    let c = b.center();
    let h = (b.max - b.min) * 0.5;
    let off = |x: T, c: f64, h: f64| (x - T::lit(c)).abs().min(T::lit(FAR)) - T::lit(h);
    let o = V3::new(off(p.x, c.x, h.x), off(p.y, c.y, h.y), off(p.z, c.z, h.z));
    let boxed = o.max_s(T::zero()).length() + o.max_element().min(T::zero());
    inside.max(boxed)
}
