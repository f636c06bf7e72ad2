//! A shape the user wrote (`sdf(f, ...)`) as a leaf of the f32 evaluator.
//!
//! Its tape, with the arguments' values folded in (`Tape::bake`), is
//! compiled once into two forms, both computing each instruction with the
//! tape's own [`Func::apply`] (so every point and lane is bit for bit what
//! the tape's interpreter gives):
//!
//! - a [`Tree`] of closures for one point (the tracer's query): each
//!   value used once is a closure called by its user, its result passed
//!   in a register; values used more than once are computed first into
//!   slots. A point's evaluation is a chain of calls whose targets repeat
//!   from point to point, which the CPU predicts, rather than an
//!   interpreter's one dispatch jump per instruction, and no value goes
//!   through memory on the way (the tracer waits on each distance);
//! - a [`Program`] of register code for batches of packs, run column by
//!   column: each instruction over every pack before the next one, so one
//!   dispatch is paid per 256 points.
//!
//! The value is that of `sdfl_stdlib::shape::user::clipped` in f32,
//! `max(f(clamp(p, box)) / L, box(p))`, the same operations in the same
//! order.

use std::cell::Cell;
use std::mem::MaybeUninit;

use super::lanes::F16;
use super::*;
use sdfl_stdlib::shape::user::{Func, Op, Tape};
use sdfl_stdlib::shape::UserShape;

/// A closure computing one value of the tape at a point.
type Expr = Box<dyn Fn(&Env) -> f32 + Send + Sync>;

/// What a closure reads: the point's coordinates (values 0, 1, 2) and
/// then the shared values computed so far.
struct Env<'a> {
    vals: &'a [Cell<f32>],
}

impl Env<'_> {
    /// Value `i`.
    #[inline(always)]
    fn read(&self, i: u16) -> f32 {
        debug_assert!((i as usize) < self.vals.len());
        // SAFETY: a tree's operands index the point's coordinates or its
        // shared values, and `Tree::eval` gives that many (see `Tree::new`).
        unsafe { self.vals.get_unchecked(i as usize).get() }
    }
}

/// Where a value of the [`Tree`] comes from.
enum Operand {
    /// A coordinate of the point, or a value used more than once (computed
    /// first): its index in [`Env::vals`].
    Mem(u16),
    /// A constant.
    Lit(f32),
    /// A value used once: computed where it is read.
    Call(Expr),
}

/// An operand of a known kind, read without a branch on its kind.
trait Arg: Send + Sync + 'static {
    fn get(&self, e: &Env) -> f32;
}

struct Mem(u16);
impl Arg for Mem {
    #[inline(always)]
    fn get(&self, e: &Env) -> f32 {
        e.read(self.0)
    }
}

struct Lit(f32);
impl Arg for Lit {
    #[inline(always)]
    fn get(&self, _: &Env) -> f32 {
        self.0
    }
}

struct Call(Expr);
impl Arg for Call {
    #[inline(always)]
    fn get(&self, e: &Env) -> f32 {
        (self.0)(e)
    }
}

impl Arg for Operand {
    #[inline(always)]
    fn get(&self, e: &Env) -> f32 {
        match self {
            Operand::Mem(i) => e.read(*i),
            Operand::Lit(c) => *c,
            Operand::Call(x) => x(e),
        }
    }
}

/// An operation with a constant applied to a closure's result before it
/// returns (fused: one call fewer): `v + c`, `c - v`, `max(v, c)`...,
/// computed as the tape's instruction computes it ([`Func::apply`], the
/// operands in the tape's order).
#[derive(Debug, Clone, Copy)]
enum Post {
    None,
    /// `f(v, c)`: the value first.
    Then(Func, f32),
    /// `f(c, v)`: the constant first.
    After(Func, f32),
}

impl Post {
    #[inline(always)]
    fn apply(self, v: f32) -> f32 {
        match self {
            Post::None => v,
            Post::Then(f, c) => f.apply(|k| if k == 0 { v } else { c }),
            Post::After(f, c) => f.apply(|k| if k == 0 { c } else { v }),
        }
    }
}

/// The closure of `f` over operands `x(k)`, then `post`, one closure type
/// per operation (the operation fixed in it).
macro_rules! closure_of {
    ($f:expr, $post:ident, $e:ident, $x:expr) => {
        match $f {
            Func::Add => Box::new(move |$e: &Env| $post.apply(Func::Add.apply($x))),
            Func::Sub => Box::new(move |$e: &Env| $post.apply(Func::Sub.apply($x))),
            Func::Mul => Box::new(move |$e: &Env| $post.apply(Func::Mul.apply($x))),
            Func::Div => Box::new(move |$e: &Env| $post.apply(Func::Div.apply($x))),
            Func::Min => Box::new(move |$e: &Env| $post.apply(Func::Min.apply($x))),
            Func::Max => Box::new(move |$e: &Env| $post.apply(Func::Max.apply($x))),
            Func::Neg => Box::new(move |$e: &Env| $post.apply(Func::Neg.apply($x))),
            Func::Abs => Box::new(move |$e: &Env| $post.apply(Func::Abs.apply($x))),
            Func::Sqrt => Box::new(move |$e: &Env| $post.apply(Func::Sqrt.apply($x))),
            Func::Sin => Box::new(move |$e: &Env| $post.apply(Func::Sin.apply($x))),
            Func::Cos => Box::new(move |$e: &Env| $post.apply(Func::Cos.apply($x))),
            Func::Exp => Box::new(move |$e: &Env| $post.apply(Func::Exp.apply($x))),
            Func::Floor => Box::new(move |$e: &Env| $post.apply(Func::Floor.apply($x))),
            Func::Hypot2 => Box::new(move |$e: &Env| $post.apply(Func::Hypot2.apply($x))),
            Func::Hypot3 => Box::new(move |$e: &Env| $post.apply(Func::Hypot3.apply($x))),
            Func::IfGt => Box::new(move |$e: &Env| $post.apply(Func::IfGt.apply($x))),
        }
    };
}

/// A one-operand operation's closure, its operand's kind known.
fn unary<A: Arg>(f: Func, post: Post, a: A) -> Expr {
    closure_of!(f, post, e, |_| a.get(e))
}

/// A two-operand operation's closure, both operands' kinds known.
fn binary<A: Arg, B: Arg>(f: Func, post: Post, a: A, b: B) -> Expr {
    closure_of!(f, post, e, |k| if k == 0 { a.get(e) } else { b.get(e) })
}

/// Any operation's closure, operands read by their kind.
fn general(f: Func, post: Post, o: [Operand; 4]) -> Expr {
    closure_of!(f, post, e, |k| o[k].get(e))
}

/// A tape as closures for one point (see the module): the shared values
/// in the tape's order, each into its slot, then the result.
pub(super) struct Tree {
    shared: Vec<(u16, Expr)>,
    root: Operand,
}

/// Closures nest at most this deep (a longer chain of values used once
/// is cut by a shared slot), so a point's evaluation stays shallow on the
/// stack whatever the tape.
const MAX_DEPTH: usize = 32;

/// Values (the point's and the shared ones) kept in a small array on the
/// stack, or else in a larger one (more take the heap, an allocation per
/// point: only tapes far larger than any of the examples).
const STACK_VALS: usize = 16;
const LARGE_STACK_VALS: usize = 256;

impl Tree {
    /// The closures of a tape without arguments (baked).
    pub(super) fn new(tape: &Tape) -> Tree {
        let ops = tape.ops();
        let out = tape.out() as usize;
        let mut uses = vec![0usize; ops.len()];
        uses[out] += 1;
        for op in ops {
            if let Some((f, src)) = op.func() {
                for &a in &src[..arity(f)] {
                    uses[a as usize] += 1;
                }
            }
        }
        // Shared: computed values read more than once, or ending a chain
        // of `MAX_DEPTH` values read once.
        let mut shared = vec![false; ops.len()];
        let mut depth = vec![0usize; ops.len()];
        for (i, op) in ops.iter().enumerate() {
            if let Some((f, src)) = op.func() {
                let below = src[..arity(f)]
                    .iter()
                    .map(|&a| {
                        if shared[a as usize] {
                            0
                        } else {
                            depth[a as usize]
                        }
                    })
                    .max()
                    .unwrap_or(0);
                depth[i] = below + 1;
                shared[i] = i != out && (uses[i] > 1 || depth[i] >= MAX_DEPTH);
            }
        }
        let mut slot = vec![u16::MAX; ops.len()];
        let mut next = INPUTS as u16;
        for i in 0..ops.len() {
            if shared[i] {
                slot[i] = next;
                next += 1;
            }
        }
        let b = TreeBuilder { ops, slot: &slot };
        let mut list = Vec::new();
        for i in 0..ops.len() {
            if shared[i] {
                list.push((slot[i], b.expr(i)));
            }
        }
        let root = b.operand(out as u32, true);
        Tree { shared: list, root }
    }

    /// The value at `q`.
    #[inline(always)]
    fn eval(&self, q: V3<f32>) -> f32 {
        let n = INPUTS + self.shared.len();
        if n <= STACK_VALS {
            let vals = [const { Cell::new(0.0f32) }; STACK_VALS];
            self.run(q, &vals)
        } else if n <= LARGE_STACK_VALS {
            let vals = [const { Cell::new(0.0f32) }; LARGE_STACK_VALS];
            self.run(q, &vals)
        } else {
            let vals = vec![Cell::new(0.0f32); n];
            self.run(q, &vals)
        }
    }

    #[inline(always)]
    fn run(&self, q: V3<f32>, vals: &[Cell<f32>]) -> f32 {
        vals[0].set(q.x);
        vals[1].set(q.y);
        vals[2].set(q.z);
        let e = Env { vals };
        for (s, x) in &self.shared {
            vals[*s as usize].set(x(&e));
        }
        self.root.get(&e)
    }
}

/// Builds a [`Tree`]'s closures, each value read once moved into its reader.
struct TreeBuilder<'a> {
    ops: &'a [Op],
    slot: &'a [u16],
}

impl TreeBuilder<'_> {
    /// Value `i` as an operand: a coordinate, a constant, a shared value,
    /// or its closure (`whole`: the value itself is wanted, not a read of
    /// its slot).
    fn operand(&self, i: u32, whole: bool) -> Operand {
        let i = i as usize;
        match self.ops[i] {
            Op::Input(k) => Operand::Mem(k.min(2) as u16),
            Op::Const(c) => Operand::Lit(c as f32),
            Op::Arg(_) => panic!("a baked tape reads no arguments"),
            _ if !whole && self.slot[i] != u16::MAX => Operand::Mem(self.slot[i]),
            _ => Operand::Call(self.expr(i)),
        }
    }

    /// The closure computing value `i` from its operands.
    fn expr(&self, i: usize) -> Expr {
        self.expr_then(i, Post::None)
    }

    /// For a two-operand instruction of operands `a` and `b`: the one that
    /// is a value read only here, whether it comes first, and the other,
    /// a constant.
    fn fusable(&self, a: u32, b: u32) -> Option<(usize, bool, f32)> {
        let single = |i: u32| {
            let i = i as usize;
            (self.ops[i].func().is_some() && self.slot[i] == u16::MAX).then_some(i)
        };
        let lit = |i: u32| match self.ops[i as usize] {
            Op::Const(c) => Some(c as f32),
            _ => None,
        };
        match (single(a), lit(b), single(b), lit(a)) {
            (Some(v), Some(c), ..) => Some((v, true, c)),
            (_, _, Some(v), Some(c)) => Some((v, false, c)),
            _ => None,
        }
    }

    /// The closure computing value `i`, then `post`.
    fn expr_then(&self, i: usize, post: Post) -> Expr {
        let (f, src) = self.ops[i].func().expect("a computed value");
        // `v op c` (or `c op v`) of a value read only here: that value's
        // closure with this operation fused after it.
        let fuses = matches!(
            f,
            Func::Add | Func::Sub | Func::Mul | Func::Div | Func::Min | Func::Max
        );
        if let (Post::None, true) = (post, fuses) {
            if let Some((v, first, c)) = self.fusable(src[0], src[1]) {
                let post = if first {
                    Post::Then(f, c)
                } else {
                    Post::After(f, c)
                };
                return self.expr_then(v, post);
            }
        }
        let mut o: [Operand; 4] = std::array::from_fn(|_| Operand::Lit(0.0));
        for (k, &a) in src[..arity(f)].iter().enumerate() {
            o[k] = self.operand(a, false);
        }
        let arity = arity(f);
        let [a, b, c, d] = o;
        match arity {
            1 => match a {
                Operand::Mem(x) => unary(f, post, Mem(x)),
                Operand::Lit(x) => unary(f, post, Lit(x)),
                Operand::Call(x) => unary(f, post, Call(x)),
            },
            2 => match (a, b) {
                (Operand::Mem(x), Operand::Mem(y)) => binary(f, post, Mem(x), Mem(y)),
                (Operand::Mem(x), Operand::Lit(y)) => binary(f, post, Mem(x), Lit(y)),
                (Operand::Mem(x), Operand::Call(y)) => binary(f, post, Mem(x), Call(y)),
                (Operand::Lit(x), Operand::Mem(y)) => binary(f, post, Lit(x), Mem(y)),
                (Operand::Lit(x), Operand::Lit(y)) => binary(f, post, Lit(x), Lit(y)),
                (Operand::Lit(x), Operand::Call(y)) => binary(f, post, Lit(x), Call(y)),
                (Operand::Call(x), Operand::Mem(y)) => binary(f, post, Call(x), Mem(y)),
                (Operand::Call(x), Operand::Lit(y)) => binary(f, post, Call(x), Lit(y)),
                (Operand::Call(x), Operand::Call(y)) => binary(f, post, Call(x), Call(y)),
            },
            _ => general(f, post, [a, b, c, d]),
        }
    }
}

/// One instruction of register code: `regs[dst] = func(regs[src[k]]…)`.
#[derive(Debug, Clone, Copy)]
struct Ins {
    func: Func,
    dst: u16,
    /// Operands; those `func` does not read are 0.
    src: [u16; 4],
}

/// Register code of a tape (see the module). Every register index is below
/// `regs` (checked when compiled), and every register is written before it
/// is read: the point's and the constants' first, each temporary by the
/// instruction computing it, which comes before its readers.
#[derive(Debug, Clone)]
pub(super) struct Program {
    /// Registers `3..3 + consts.len()`.
    consts: Vec<f32>,
    code: Vec<Ins>,
    regs: usize,
    out: u16,
}

/// Registers that hold the point.
const INPUTS: usize = 3;

/// Most registers a tape compiles to (a tape has at most
/// `MAX_OPS` = 4096 instructions: every one of them fits).
const MAX_REGS: usize = u16::MAX as usize;

impl Program {
    /// The register code of a tape without arguments (baked).
    pub(super) fn new(tape: &Tape) -> Program {
        let ops = tape.ops();
        let out = tape.out() as usize;
        // Where each value is last read (the result: past the end).
        let mut last = vec![0usize; ops.len()];
        for (i, op) in ops.iter().enumerate() {
            if let Some((f, src)) = op.func() {
                for &a in &src[..arity(f)] {
                    last[a as usize] = i;
                }
            }
        }
        last[out] = usize::MAX;
        let mut reg = vec![u16::MAX; ops.len()];
        let mut consts = Vec::new();
        for (i, op) in ops.iter().enumerate() {
            match *op {
                Op::Input(k) => reg[i] = k.min(2) as u16,
                Op::Const(c) => {
                    reg[i] = (INPUTS + consts.len()) as u16;
                    consts.push(c as f32);
                }
                Op::Arg(_) => panic!("a baked tape reads no arguments"),
                _ => {}
            }
        }
        let first_temp = INPUTS + consts.len();
        let (mut free, mut regs) = (Vec::<u16>::new(), first_temp);
        let mut code = Vec::new();
        for (i, op) in ops.iter().enumerate() {
            let Some((func, src)) = op.func() else {
                continue;
            };
            let dst = match free.pop() {
                Some(r) => r,
                None => {
                    regs += 1;
                    (regs - 1) as u16
                }
            };
            reg[i] = dst;
            let mut s = [0u16; 4];
            for (k, &a) in src[..arity(func)].iter().enumerate() {
                s[k] = reg[a as usize];
            }
            // Operands read for the last time free their temporaries (after
            // the result's register is taken: it never aliases them).
            for (k, &a) in src[..arity(func)].iter().enumerate() {
                let r = s[k];
                let again = src[..k].contains(&a);
                if last[a as usize] == i && r as usize >= first_temp && !again {
                    free.push(r);
                }
            }
            code.push(Ins { func, dst, src: s });
        }
        assert!(regs <= MAX_REGS, "a tape's registers fit u16");
        Program {
            consts,
            code,
            regs,
            out: reg[out],
        }
    }

    /// The code over `n` packs held column by column in `cols` (register
    /// `i`'s packs at `cols[i·n..(i + 1)·n]`), the inputs' columns written;
    /// the result's column is returned.
    #[inline(always)]
    fn run_columns<'a, L: Wide>(&self, cols: &'a mut [MaybeUninit<L>], n: usize) -> &'a [L] {
        let cols = &mut cols[..self.regs * n];
        for (i, c) in self.consts.iter().enumerate() {
            for slot in &mut cols[(INPUTS + i) * n..(INPUTS + i + 1) * n] {
                slot.write(L::splat(*c));
            }
        }
        let base = cols.as_mut_ptr();
        for ins in &self.code {
            // SAFETY: as in `run`, column by column: each column lies
            // within `cols`, and the result's never overlaps an operand's.
            unsafe {
                let col = |r: u16| base.add(r as usize * n) as *const L;
                let (a, b, c, d) = (
                    col(ins.src[0]),
                    col(ins.src[1]),
                    col(ins.src[2]),
                    col(ins.src[3]),
                );
                let dst = base.add(ins.dst as usize * n) as *mut L;
                // One loop per operation, the operation fixed in it.
                macro_rules! over {
                    ($f:expr) => {
                        for j in 0..n {
                            let x = [*a.add(j), *b.add(j), *c.add(j), *d.add(j)];
                            *dst.add(j) = $f.apply(|k| x[k]);
                        }
                    };
                }
                match ins.func {
                    Func::Add => over!(Func::Add),
                    Func::Sub => over!(Func::Sub),
                    Func::Mul => over!(Func::Mul),
                    Func::Div => over!(Func::Div),
                    Func::Min => over!(Func::Min),
                    Func::Max => over!(Func::Max),
                    Func::Neg => over!(Func::Neg),
                    Func::Abs => over!(Func::Abs),
                    Func::Sqrt => over!(Func::Sqrt),
                    Func::Sin => over!(Func::Sin),
                    Func::Cos => over!(Func::Cos),
                    Func::Exp => over!(Func::Exp),
                    Func::Floor => over!(Func::Floor),
                    Func::Hypot2 => over!(Func::Hypot2),
                    Func::Hypot3 => over!(Func::Hypot3),
                    Func::IfGt => over!(Func::IfGt),
                }
            }
        }
        let out = self.out as usize * n;
        // SAFETY: every register's column is written (see `Program`).
        unsafe { std::slice::from_raw_parts(cols[out..out + n].as_ptr() as *const L, n) }
    }
}

/// How many operands `f` reads.
fn arity(f: Func) -> usize {
    match f {
        Func::Neg | Func::Abs | Func::Sqrt | Func::Sin | Func::Cos | Func::Exp | Func::Floor => 1,
        Func::Add | Func::Sub | Func::Mul | Func::Div | Func::Min | Func::Max | Func::Hypot2 => 2,
        Func::Hypot3 => 3,
        Func::IfGt => 4,
    }
}

/// The box a user shape is evaluated in, in f32 as `clipped` rounds it.
#[derive(Debug, Clone, Copy)]
struct Clip {
    lo: V3<f32>,
    hi: V3<f32>,
    center: V3<f32>,
    half: V3<f32>,
    inv_l: f32,
}

/// The box's offsets are capped here (as in `clipped`).
const FAR: f64 = 1e15;

impl Clip {
    fn new(b: &Aabb, inv_l: f64) -> Clip {
        let lit = |v: DVec3| V3::lit(v.to_array());
        Clip {
            lo: lit(b.min),
            hi: lit(b.max),
            center: lit(b.center()),
            half: lit((b.max - b.min) * 0.5),
            inv_l: inv_l as f32,
        }
    }

    /// `p` clamped to the box, as `Real::clamp` does it.
    #[inline(always)]
    fn clamp<T: Real>(&self, p: V3<T>) -> V3<T> {
        let c = |x: T, lo: f32, hi: f32| x.max(T::lit(lo as f64)).min(T::lit(hi as f64));
        V3::new(
            c(p.x, self.lo.x, self.hi.x),
            c(p.y, self.lo.y, self.hi.y),
            c(p.z, self.lo.z, self.hi.z),
        )
    }

    /// The offsets of `p` from the box (≤ 0 inside), capped at `FAR`.
    #[inline(always)]
    fn offsets<T: Real>(&self, p: V3<T>) -> V3<T> {
        let off =
            |x: T, c: f32, h: f32| (x - T::lit(c as f64)).abs().min(T::lit(FAR)) - T::lit(h as f64);
        V3::new(
            off(p.x, self.center.x, self.half.x),
            off(p.y, self.center.y, self.half.y),
            off(p.z, self.center.z, self.half.z),
        )
    }

    /// The box's signed distance from its offsets.
    #[inline(always)]
    fn boxed<T: Real>(o: V3<T>) -> T {
        o.max_s(T::zero()).length() + o.max_element().min(T::zero())
    }
}

/// A user shape placed in the world: its code, its box, its frame.
#[doc(hidden)]
pub struct UserLeaf {
    tree: Tree,
    program: Program,
    clip: Clip,
    xform: Xform,
    scale: f32,
    id: u32,
}

impl UserLeaf {
    /// The shape `u` placed by `xform` and `scale`, its primitive id `id`.
    pub fn new(u: &UserShape, xform: Xform, scale: f32, id: u32) -> Self {
        let baked = u.tape.bake(&u.arg_values());
        UserLeaf {
            tree: Tree::new(&baked),
            program: Program::new(&baked),
            clip: Clip::new(&u.bound, 1.0 / u.lipschitz),
            xform,
            scale,
            id,
        }
    }

    /// The shape's value at `p` in its own frame.
    #[inline(always)]
    fn local(&self, p: V3<f32>) -> f32 {
        let c = &self.clip;
        let inside = self.tree.eval(c.clamp(p)) * c.inv_l;
        Real::max(inside, Clip::boxed(c.offsets(p)))
    }
}

impl Node for UserLeaf {
    #[inline(always)]
    fn dist(&self, p: Vec3A) -> f32 {
        self.local(v3(self.xform.apply(p))) * self.scale
    }
    fn dist_id(&self, p: Vec3A) -> (f32, u32) {
        (self.dist(p), self.id)
    }
    fn dist_packs(&self, p: &[P8], out: &mut [F8]) {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx512f")]
            unsafe fn avx512(leaf: &UserLeaf, p: &[P8], out: &mut [F8]) {
                let mut cols = [MaybeUninit::<F16>::uninit(); COLUMN_BUFFER / 2];
                user_packs(leaf, p, out, &mut cols)
            }
            if crate::cpu::kernels().avx512f {
                // SAFETY: the CPU supports AVX-512 F (checked just above).
                return unsafe { avx512(self, p, out) };
            }
        }
        #[cfg(any(target_arch = "x86_64", target_arch = "x86"))]
        {
            #[target_feature(enable = "avx2")]
            unsafe fn avx2(leaf: &UserLeaf, p: &[P8], out: &mut [F8]) {
                let mut cols = [MaybeUninit::<F8>::uninit(); COLUMN_BUFFER];
                user_packs(leaf, p, out, &mut cols)
            }
            if lanes::has_avx2() {
                // SAFETY: the CPU supports AVX2 (checked just above).
                return unsafe { avx2(self, p, out) };
            }
        }
        let mut cols = [MaybeUninit::<F8>::uninit(); COLUMN_BUFFER];
        user_packs(self, p, out, &mut cols)
    }
    fn traces_in_packs(&self) -> bool {
        true
    }
}

/// Packs per pass through the code (the columns of 64 registers fit the
/// stack buffer; more registers take fewer packs per pass).
const COLUMN_PACKS: usize = BATCH_PACKS;

/// F8 values in the stack buffer of the columns (64 KiB).
#[doc(hidden)]
pub const COLUMN_BUFFER: usize = 2048;

/// The lanes the column code runs on: one pack of points ([`F8`]), or two
/// side by side ([`F16`], one AVX-512 register, where the CPU has it);
/// each lane's operations are the same f32 operations either way.
#[doc(hidden)]
pub trait Wide: Real {
    /// Packs of points side by side.
    const PACKS: usize;
    /// Every lane `x`.
    fn splat(x: f32) -> Self;
    /// The lanes of `PACKS` packs.
    fn join(p: &[F8]) -> Self;
    /// Its lanes as packs (the first `out.len()` of them).
    fn split(self, out: &mut [F8]);
}

impl Wide for F8 {
    const PACKS: usize = 1;
    #[inline(always)]
    fn splat(x: f32) -> Self {
        F8::splat(x)
    }
    #[inline(always)]
    fn join(p: &[F8]) -> Self {
        p[0]
    }
    #[inline(always)]
    fn split(self, out: &mut [F8]) {
        out[0] = self;
    }
}

impl Wide for F16 {
    const PACKS: usize = 2;
    #[inline(always)]
    fn splat(x: f32) -> Self {
        F16::splat(x)
    }
    #[inline(always)]
    fn join(p: &[F8]) -> Self {
        let mut r = [0.0; 16];
        r[..LANES].copy_from_slice(&p[0].0);
        r[LANES..].copy_from_slice(&p[1].0);
        F16(r)
    }
    #[inline(always)]
    fn split(self, out: &mut [F8]) {
        for (k, o) in out.iter_mut().enumerate().take(2) {
            o.0.copy_from_slice(&self.0[k * LANES..(k + 1) * LANES]);
        }
    }
}

/// [`UserLeaf::dist`] of every pack: the box's clamp and distance pack by
/// pack, the code column by column (in `stack`'s columns when they fit),
/// `L::PACKS` packs side by side.
#[inline(always)]
#[doc(hidden)]
pub fn user_packs<L: Wide>(
    leaf: &UserLeaf,
    p: &[P8],
    out: &mut [F8],
    stack: &mut [MaybeUninit<L>],
) {
    let regs = leaf.program.regs;
    let mut heap = Vec::new();
    let per_pass = (stack.len() / regs).clamp(1, COLUMN_PACKS / L::PACKS);
    let cols: &mut [MaybeUninit<L>] = if regs * per_pass <= stack.len() {
        stack
    } else {
        heap.resize(regs * per_pass, MaybeUninit::uninit());
        &mut heap
    };
    let c = &leaf.clip;
    let mut boxed = [MaybeUninit::<L>::uninit(); COLUMN_PACKS];
    let (inv_l, scale) = (L::splat(c.inv_l), L::splat(leaf.scale));
    // Products by 1 change no value (the tape's inputs are NaN-free, and
    // a NaN times 1 is that NaN): skipped.
    let unscaled = c.inv_l == 1.0 && leaf.scale == 1.0;
    let step = per_pass * L::PACKS;
    for (p, out) in p.chunks(step).zip(out.chunks_mut(step)) {
        let n = p.len().div_ceil(L::PACKS);
        for j in 0..n {
            // The packs side by side (past the end: the last again).
            let mut side = [[F8::splat(0.0); 2]; 3];
            for k in 0..L::PACKS {
                let q = leaf.xform.apply8(p[(j * L::PACKS + k).min(p.len() - 1)]);
                (side[0][k], side[1][k], side[2][k]) = (q.x, q.y, q.z);
            }
            let [x, y, z] = side.map(|s| L::join(&s[..L::PACKS]));
            let w = V3::new(x, y, z);
            let q = c.clamp(w);
            cols[j].write(q.x);
            cols[n + j].write(q.y);
            cols[2 * n + j].write(q.z);
            boxed[j].write(Clip::boxed(c.offsets(w)));
        }
        let f = leaf.program.run_columns(cols, n);
        for (j, (f, b)) in f.iter().zip(&boxed[..n]).enumerate() {
            // SAFETY: the first `n` were written just above.
            let b = unsafe { b.assume_init() };
            let v = if unscaled {
                Real::max(*f, b)
            } else {
                Real::max(*f * inv_l, b) * scale
            };
            let end = ((j + 1) * L::PACKS).min(out.len());
            let o = &mut out[j * L::PACKS..end];
            v.split(o);
        }
    }
}
