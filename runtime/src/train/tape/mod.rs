//! A training model traced into a flat tape, once per step: the field
//! (shape and colour), the absorption and `ln(1 − opacity)` of one sample
//! as a list of f32 operations on four per-sample inputs (the point and
//! the interval), read from the same generic definitions every evaluator
//! uses (`Shape::sample`, `absorption`), through [`Traced`], a [`Real`] that
//! records instead of computing.
//!
//! What the tape buys over carrying forward-mode tangents through the
//! recursive evaluator: operations that depend on the parameters only
//! (`1/β`, a rotation's sine) are computed once at tracing; operations that
//! depend on the sample run on 16 samples at a time in one function that is
//! compiled for AVX-512 or AVX2 where the CPU has them; and the gradient
//! with respect to every parameter comes from one reverse sweep through the
//! tape instead of one tangent per parameter. Repeated subexpressions (the
//! absorption's `exp(−|sdf|/β)` is formed three times) are recorded once.
//!
//! Each operation's value is the one [`Dual`](sdfl_stdlib::num::Dual)`<f32,
//! 0>` gives (division as `a · (1/b)`, `abs`/`max`/`min` as selects), so a
//! tape's forward pass is the plain pass of the scalar kernel to the bit,
//! and its derivative rules are `Dual`'s (the subgradient 0 of `sqrt` at
//! 0, ties to the first operand).
//!
//! A formula that branches on a per-sample value (`Real::val` of a varying
//! node: unions choosing a colour, repeats choosing copies) cannot be
//! traced; tracing then fails and the trainer takes the scalar kernel.

mod kernel;

use std::cell::RefCell;
use std::collections::HashMap;
use std::ops::{Add, Div, Mul, Neg, Sub};

use glam::DVec3;
use sdfl_stdlib::num::{Real, V3};
use sdfl_stdlib::param::{Arg, ParamInit};
use sdfl_stdlib::shape::ArgSource;

use super::model::field_at;
use super::model::TrainModel;

pub use kernel::{lanes_per_register, loss_and_grad};

/// Most nodes a tape may have (beyond it the scalar kernel runs: a scene
/// that large is not a small-scene training step).
const MAX_NODES: usize = 1 << 14;

/// One operation; operands are node (or, in a compiled tape, register)
/// numbers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[doc(hidden)]
pub enum Op {
    /// A per-sample input: 0, 1, 2 the point, 3 the interval.
    Input(u8),
    /// A constant, by its bits.
    Const(u32),
    /// A scalar of the model's flat parameter vector.
    Param(u32),
    Add(u32, u32),
    Sub(u32, u32),
    Mul(u32, u32),
    Div(u32, u32),
    Neg(u32),
    Sqrt(u32),
    Abs(u32),
    Exp(u32),
    Ln(u32),
    Ln1p(u32),
    ExpM1(u32),
    Sin(u32),
    Cos(u32),
    Max(u32, u32),
    Min(u32, u32),
    /// `then` where `a > b`, else `otherwise`.
    IfGt(u32, u32, u32, u32),
}

impl Op {
    /// The operands and how many there are.
    pub fn operands(self) -> ([u32; 4], usize) {
        use Op::*;
        match self {
            Input(_) | Const(_) | Param(_) => ([0; 4], 0),
            Neg(a) | Sqrt(a) | Abs(a) | Exp(a) | Ln(a) | Ln1p(a) | ExpM1(a) | Sin(a) | Cos(a) => {
                ([a, 0, 0, 0], 1)
            }
            Add(a, b) | Sub(a, b) | Mul(a, b) | Div(a, b) | Max(a, b) | Min(a, b) => {
                ([a, b, 0, 0], 2)
            }
            IfGt(a, b, c, d) => ([a, b, c, d], 4),
        }
    }

    /// The same operation on other operand numbers.
    fn renumber(self, f: impl Fn(u32) -> u32) -> Op {
        use Op::*;
        match self {
            Input(_) | Const(_) | Param(_) => self,
            Add(a, b) => Add(f(a), f(b)),
            Sub(a, b) => Sub(f(a), f(b)),
            Mul(a, b) => Mul(f(a), f(b)),
            Div(a, b) => Div(f(a), f(b)),
            Max(a, b) => Max(f(a), f(b)),
            Min(a, b) => Min(f(a), f(b)),
            Neg(a) => Neg(f(a)),
            Sqrt(a) => Sqrt(f(a)),
            Abs(a) => Abs(f(a)),
            Exp(a) => Exp(f(a)),
            Ln(a) => Ln(f(a)),
            Ln1p(a) => Ln1p(f(a)),
            ExpM1(a) => ExpM1(f(a)),
            Sin(a) => Sin(f(a)),
            Cos(a) => Cos(f(a)),
            IfGt(a, b, c, d) => IfGt(f(a), f(b), f(c), f(d)),
        }
    }
}

/// The value of an operation on operand values `x` (the leaves are not
/// operations). `Dual<F, 0>`'s arithmetic, so that the tape's values are
/// the scalar kernel's.
#[inline(always)]
#[doc(hidden)]
pub fn forward<F: Real>(op: Op, x: [F; 4]) -> F {
    use Op::*;
    match op {
        Input(_) | Const(_) | Param(_) => x[0],
        Add(..) => x[0] + x[1],
        Sub(..) => x[0] - x[1],
        Mul(..) => x[0] * x[1],
        Div(..) => x[0] * (F::one() / x[1]),
        Neg(_) => -x[0],
        Sqrt(_) => x[0].sqrt(),
        Abs(_) => F::if_gt(F::zero(), x[0], -x[0], x[0]),
        Exp(_) => x[0].exp(),
        Ln(_) => x[0].ln(),
        Ln1p(_) => x[0].ln_1p(),
        ExpM1(_) => x[0].exp_m1(),
        Sin(_) => x[0].sin(),
        Cos(_) => x[0].cos(),
        Max(..) => F::if_gt(x[1], x[0], x[1], x[0]),
        Min(..) => F::if_gt(x[0], x[1], x[1], x[0]),
        IfGt(..) => F::if_gt(x[0], x[1], x[2], x[3]),
    }
}

/// What an operation of value `y` on operands `x` passes back to each
/// operand from the adjoint `g` of its value: `Dual`'s derivative rules.
#[inline(always)]
#[doc(hidden)]
pub fn backward<F: Real>(op: Op, x: [F; 4], y: F, g: F) -> [F; 4] {
    use Op::*;
    let z = F::zero();
    match op {
        Input(_) | Const(_) | Param(_) => [z; 4],
        Add(..) => [g, g, z, z],
        Sub(..) => [g, -g, z, z],
        Mul(..) => [g * x[1], g * x[0], z, z],
        Div(..) => {
            let inv = F::one() / x[1];
            let ga = g * inv;
            [ga, -(ga * y), z, z]
        }
        Neg(_) => [-g, z, z, z],
        Sqrt(_) => [F::if_gt(y, z, g * (F::lit(0.5) / y), z), z, z, z],
        Abs(_) => [F::if_gt(z, x[0], -g, g), z, z, z],
        Exp(_) => [g * y, z, z, z],
        Ln(_) => [g * (F::one() / x[0]), z, z, z],
        Ln1p(_) => [g * (F::one() / (F::one() + x[0])), z, z, z],
        ExpM1(_) => [g * x[0].exp(), z, z, z],
        Sin(_) => [g * x[0].cos(), z, z, z],
        Cos(_) => [g * -x[0].sin(), z, z, z],
        Max(..) => [F::if_gt(x[1], x[0], z, g), F::if_gt(x[1], x[0], g, z), z, z],
        Min(..) => [F::if_gt(x[0], x[1], z, g), F::if_gt(x[0], x[1], g, z), z, z],
        IfGt(..) => [z, z, F::if_gt(x[0], x[1], g, z), F::if_gt(x[0], x[1], z, g)],
    }
}

/// What the derivative rule of an operation ([`backward`]) reads: a bit
/// per operand, and whether it reads the operation's own value. Values
/// nothing reads are not computed.
#[doc(hidden)]
pub fn rule_reads(op: Op) -> (u8, bool) {
    use Op::*;
    match op {
        Input(_) | Const(_) | Param(_) | Add(..) | Sub(..) | Neg(_) => (0, false),
        Mul(..) | Max(..) | Min(..) | IfGt(..) => (0b11, false),
        Div(..) => (0b10, true),
        Sqrt(_) | Exp(_) => (0, true),
        Abs(_) | Ln(_) | Ln1p(_) | ExpM1(_) | Sin(_) | Cos(_) => (0b1, false),
    }
}

/// A node while tracing: its operation, whether it depends on the sample,
/// and, when it does not, its value.
#[derive(Clone, Copy, Debug)]
struct Node {
    op: Op,
    varying: bool,
    value: f32,
}

/// The tape being recorded on this thread.
#[derive(Default)]
struct Recorder {
    nodes: Vec<Node>,
    index: HashMap<Op, u32>,
    /// Why the trace cannot be used, if it cannot.
    failed: Option<&'static str>,
}

thread_local! {
    static RECORDER: RefCell<Recorder> = RefCell::new(Recorder::default());
}

impl Recorder {
    /// Records `op` (a leaf with `leaf` as its value), or finds it.
    fn push(&mut self, op: Op, leaf: f32) -> u32 {
        if self.failed.is_some() {
            return 0;
        }
        if let Some(&i) = self.index.get(&op) {
            return i;
        }
        if self.nodes.len() >= MAX_NODES {
            self.failed = Some("too many operations");
            return 0;
        }
        let (args, n) = op.operands();
        let varying =
            matches!(op, Op::Input(_)) || args[..n].iter().any(|&a| self.nodes[a as usize].varying);
        let value = match op {
            Op::Const(_) | Op::Param(_) => leaf,
            _ if varying => 0.0,
            _ => forward(op, args.map(|a| self.nodes[a as usize].value)),
        };
        let i = self.nodes.len() as u32;
        self.nodes.push(Node { op, varying, value });
        self.index.insert(op, i);
        i
    }
}

/// A value being traced: a node of this thread's recording.
#[derive(Clone, Copy, Debug)]
pub struct Traced(u32);

fn record(op: Op) -> Traced {
    Traced(RECORDER.with(|r| r.borrow_mut().push(op, 0.0)))
}

macro_rules! traced_op {
    ($tr:ident, $f:ident, $op:ident) => {
        impl $tr for Traced {
            type Output = Traced;
            fn $f(self, o: Traced) -> Traced {
                record(Op::$op(self.0, o.0))
            }
        }
    };
}
traced_op!(Add, add, Add);
traced_op!(Sub, sub, Sub);
traced_op!(Mul, mul, Mul);
traced_op!(Div, div, Div);

impl Neg for Traced {
    type Output = Traced;
    fn neg(self) -> Traced {
        record(Op::Neg(self.0))
    }
}

impl Real for Traced {
    fn lit(x: f64) -> Self {
        let x = x as f32;
        Traced(RECORDER.with(|r| r.borrow_mut().push(Op::Const(x.to_bits()), x)))
    }
    /// The value of a node that does not depend on the sample (a branch on
    /// a parameter, such as `α = 1`, is taken at tracing, each step anew);
    /// a branch on the sample fails the trace.
    fn val(self) -> f64 {
        RECORDER.with(|r| {
            let mut r = r.borrow_mut();
            match r.nodes.get(self.0 as usize) {
                Some(n) if !n.varying => n.value as f64,
                _ => {
                    r.failed.get_or_insert("a branch on a per-sample value");
                    0.0
                }
            }
        })
    }
    fn sqrt(self) -> Self {
        record(Op::Sqrt(self.0))
    }
    fn abs(self) -> Self {
        record(Op::Abs(self.0))
    }
    fn exp(self) -> Self {
        record(Op::Exp(self.0))
    }
    fn ln(self) -> Self {
        record(Op::Ln(self.0))
    }
    fn ln_1p(self) -> Self {
        record(Op::Ln1p(self.0))
    }
    fn exp_m1(self) -> Self {
        record(Op::ExpM1(self.0))
    }
    fn sin(self) -> Self {
        record(Op::Sin(self.0))
    }
    fn cos(self) -> Self {
        record(Op::Cos(self.0))
    }
    fn max(self, o: Self) -> Self {
        record(Op::Max(self.0, o.0))
    }
    fn min(self, o: Self) -> Self {
        record(Op::Min(self.0, o.0))
    }
    fn if_gt(a: Self, b: Self, then: Self, otherwise: Self) -> Self {
        record(Op::IfGt(a.0, b.0, then.0, otherwise.0))
    }
}

/// The model's arguments as traced parameters at `values`.
struct TracedArgs<'a> {
    model: &'a TrainModel,
    values: &'a [f32],
}

impl TracedArgs<'_> {
    fn param(&self, i: usize) -> Traced {
        let op = Op::Param(i as u32);
        Traced(RECORDER.with(|r| r.borrow_mut().push(op, self.values[i])))
    }
}

impl ArgSource<Traced> for TracedArgs<'_> {
    fn scalar(&self, a: &Arg<f64>) -> Traced {
        match self.model.scalar_index(a) {
            Some(i) => self.param(i),
            None => Traced::lit(a.value),
        }
    }
    fn vector(&self, a: &Arg<DVec3>) -> V3<Traced> {
        match self.model.vector_index(a) {
            Some((i, ParamInit::Scalar(_))) => V3::splat(self.param(i)),
            Some((i, ParamInit::Vec3(_))) => {
                V3::new(self.param(i), self.param(i + 1), self.param(i + 2))
            }
            None => V3::lit(a.value.to_array()),
        }
    }
}

/// The tape's outputs, in order.
const OPACITY: usize = 0;
const KEEP: usize = 1;
const LOG_KEEP: usize = 2;
const COLOUR: usize = 3;
const OUTPUTS: usize = 6;

/// A value that does not depend on the sample, held in every lane of a
/// register.
#[derive(Debug, Clone, Copy)]
#[doc(hidden)]
pub struct Uniform {
    register: u32,
    value: f32,
    node: u32,
    /// Whether it depends on a parameter (its adjoint is summed).
    pub grad: bool,
}

/// A traced model compiled for evaluation on lanes of samples. Every node
/// the outputs need has a register: a varying node is computed in it by an
/// instruction, a uniform one (depending on parameters and constants only)
/// holds its value in every lane.
#[derive(Debug, Clone)]
pub struct Tape {
    /// Operations of the varying nodes in order, operands and result as
    /// registers: (operation, result register).
    #[doc(hidden)]
    pub forward: Vec<(Op, u32)>,
    /// The instructions whose result carries a gradient, last first, with a
    /// bit per operand that wants its adjoint and a bit per operand whose
    /// adjoint it writes first (stores rather than adds: no register is
    /// zeroed that something writes before reading).
    #[doc(hidden)]
    pub reverse: Vec<(Op, u32, u8, u8)>,
    registers: usize,
    /// Registers of the inputs (point x, y, z, interval), if used.
    inputs: [Option<u32>; 4],
    /// Registers of the outputs (opacity, keep, ln keep, colour r, g, b).
    outputs: [u32; OUTPUTS],
    /// Whether each output carries a gradient.
    output_grads: [bool; OUTPUTS],
    /// Whether each output's seed is the first write to its register's
    /// adjoint (outputs may share a register).
    seed_first: [bool; OUTPUTS],
    /// Registers whose adjoints are read before anything writes them
    /// (zeroed first; none in the tapes the compiler makes).
    #[doc(hidden)]
    pub adjoint_registers: Vec<u32>,
    /// Uniform values held in registers.
    #[doc(hidden)]
    pub uniforms: Vec<Uniform>,
    /// The uniform nodes, for the gradient through what depends on the
    /// parameters only: (operation on nodes, value).
    nodes: Vec<(Op, f32)>,
}

impl Tape {
    /// Traces `model` at `values`, or says why it cannot be.
    pub fn trace(model: &TrainModel, values: &[f32]) -> Result<Tape, &'static str> {
        RECORDER.with(|r| *r.borrow_mut() = Recorder::default());
        // Node 0 is the constant 0 (what a failed recording returns).
        let zero = Traced::lit(0.0);
        debug_assert_eq!(zero.0, 0);
        let args = TracedArgs { model, values };
        let [x, y, z, dk] = [0u8, 1, 2, 3].map(|i| record(Op::Input(i)));
        let f = &model.field;
        let (sdf, c) = field_at(model, &args, V3::new(x, y, z));
        let alpha = args.scalar(&f.alpha);
        let inv_beta = Traced::one() / args.scalar(&f.beta);
        let a = f.density.absorption(sdf, alpha, inv_beta, dk);
        let lk = f.density.log_keep(sdf, alpha, inv_beta, dk);
        let outputs = [a.opacity, a.keep, lk, c.x, c.y, c.z].map(|t| t.0);
        let recorder = RECORDER.with(|r| std::mem::take(&mut *r.borrow_mut()));
        if let Some(why) = recorder.failed {
            return Err(why);
        }
        Ok(Tape::compile(&recorder.nodes, outputs))
    }

    fn compile(nodes: &[Node], outputs: [u32; OUTPUTS]) -> Tape {
        let n = nodes.len();
        let operands = |i: usize| {
            let (args, k) = nodes[i].op.operands();
            args.into_iter().take(k).map(|a| a as usize)
        };
        // What depends on a parameter (carries a gradient).
        let mut grad = vec![false; n];
        for i in 0..n {
            grad[i] = matches!(nodes[i].op, Op::Param(_)) || operands(i).any(|a| grad[a]);
        }
        // Which operands of each node its adjoint reaches: those with a
        // gradient, except the other factor of a product with a uniform 0
        // (the `(α − 1)·…` term of the opacity form at α = 1: its adjoint
        // is 0, so what feeds it needs no reverse pass).
        let zero = |a: usize| !nodes[a].varying && !grad[a] && nodes[a].value == 0.0;
        let wants = |i: usize| -> u8 {
            let (args, k) = nodes[i].op.operands();
            let mut mask = 0u8;
            for (j, &a) in args[..k].iter().enumerate() {
                let killed = match nodes[i].op {
                    Op::Mul(..) => zero(args[1 - j] as usize),
                    // A select's comparison gets no adjoint.
                    Op::IfGt(..) => j < 2,
                    _ => false,
                };
                mask |= ((grad[a as usize] && !killed) as u8) << j;
            }
            mask
        };
        // Adjoints flow from the seeded outputs (opacity, ln keep, colour).
        let mut live = vec![false; n];
        for o in [OPACITY, LOG_KEEP, COLOUR, COLOUR + 1, COLOUR + 2] {
            live[outputs[o] as usize] = grad[outputs[o] as usize];
        }
        for i in (0..n).rev() {
            if live[i] && nodes[i].varying {
                let (args, k) = nodes[i].op.operands();
                let m = wants(i);
                for (j, &a) in args[..k].iter().enumerate() {
                    if m & (1 << j) != 0 {
                        live[a as usize] = true;
                    }
                }
            }
        }
        let reversed = |i: usize| live[i] && nodes[i].varying && grad[i] && wants(i) != 0;
        // Values computed: what the compositing reads (opacity, keep,
        // colour), what the derivative rules of the reverse pass read, and
        // what those need (`ln(1 − o)` itself is never read: only its
        // adjoint is wanted).
        let mut needed = vec![false; n];
        for o in [OPACITY, KEEP, COLOUR, COLOUR + 1, COLOUR + 2] {
            needed[outputs[o] as usize] = true;
        }
        for i in 0..n {
            if reversed(i) {
                let (reads, result) = rule_reads(nodes[i].op);
                needed[i] |= result;
                for (j, a) in operands(i).enumerate() {
                    needed[a] |= reads & (1 << j) != 0;
                }
            }
        }
        for i in (0..n).rev() {
            if needed[i] {
                for a in operands(i) {
                    needed[a] = true;
                }
            }
        }
        // Registers: the varying nodes computed or reversed, the uniform
        // ones they read, and the outputs.
        let mut in_register = vec![false; n];
        for i in 0..n {
            if (needed[i] || reversed(i)) && nodes[i].varying {
                in_register[i] = true;
                for a in operands(i) {
                    in_register[a] = true;
                }
            }
        }
        for &o in &outputs {
            in_register[o as usize] = true;
        }
        let mut register = vec![u32::MAX; n];
        let mut registers = 0u32;
        for i in 0..n {
            if in_register[i] {
                register[i] = registers;
                registers += 1;
            }
        }
        let reg = |a: u32| register[a as usize];
        let mut tape = Tape {
            forward: Vec::new(),
            reverse: Vec::new(),
            registers: registers as usize,
            inputs: [None; 4],
            outputs: outputs.map(reg),
            output_grads: outputs.map(|o| live[o as usize]),
            seed_first: [false; OUTPUTS],
            adjoint_registers: Vec::new(),
            uniforms: Vec::new(),
            nodes: nodes.iter().map(|n| (n.op, n.value)).collect(),
        };
        for (i, node) in nodes.iter().enumerate() {
            if !in_register[i] {
                continue;
            }
            match node.op {
                Op::Input(k) => tape.inputs[k as usize] = Some(reg(i as u32)),
                _ if !node.varying => tape.uniforms.push(Uniform {
                    register: reg(i as u32),
                    value: node.value,
                    node: i as u32,
                    grad: live[i] && grad[i],
                }),
                op => {
                    if needed[i] {
                        tape.forward.push((op.renumber(reg), reg(i as u32)));
                    }
                    if reversed(i) {
                        tape.reverse
                            .push((op.renumber(reg), reg(i as u32), wants(i), 0));
                    }
                }
            }
        }
        tape.reverse.reverse();
        // Which write to each adjoint comes first, in the order the kernel
        // runs: the seeds, then the reverse instructions.
        let mut written = vec![false; tape.registers];
        let read = |r: u32, written: &[bool], zeroed: &mut Vec<u32>| {
            if !written[r as usize] && !zeroed.contains(&r) {
                zeroed.push(r);
            }
        };
        for o in [OPACITY, LOG_KEEP, COLOUR, COLOUR + 1, COLOUR + 2] {
            if tape.output_grads[o] {
                let r = tape.outputs[o] as usize;
                tape.seed_first[o] = !written[r];
                written[r] = true;
            }
        }
        let mut zeroed = Vec::new();
        for (op, dst, wants, first) in &mut tape.reverse {
            read(*dst, &written, &mut zeroed);
            let (args, k) = op.operands();
            for (j, &a) in args[..k].iter().enumerate() {
                if *wants & (1 << j) != 0 {
                    *first |= (!written[a as usize] as u8) << j;
                    written[a as usize] = true;
                }
            }
        }
        for u in &tape.uniforms {
            if u.grad {
                read(u.register, &written, &mut zeroed);
            }
        }
        tape.adjoint_registers = zeroed;
        tape
    }

    /// Instructions run per sample (forward).
    pub fn len(&self) -> usize {
        self.forward.len()
    }

    /// Whether the tape has no instructions.
    pub fn is_empty(&self) -> bool {
        self.forward.is_empty()
    }

    /// Instructions run per sample in reverse.
    pub fn reverse_len(&self) -> usize {
        self.reverse.len()
    }

    /// Registers per chunk of 16 samples.
    pub fn registers(&self) -> usize {
        self.registers
    }

    /// The gradient of the parameters from the adjoints of the uniform
    /// nodes in registers (`adjoints[k]` for `uniforms[k]`), through the
    /// operations on parameters alone, in f64.
    fn parameter_gradient(&self, adjoints: &[f64], scalars: usize) -> Vec<f64> {
        let mut adj = vec![0.0f64; self.nodes.len()];
        for (u, &a) in self.uniforms.iter().zip(adjoints) {
            adj[u.node as usize] += a;
        }
        let mut grad = vec![0.0; scalars];
        for i in (0..self.nodes.len()).rev() {
            let a = adj[i];
            if a == 0.0 {
                continue;
            }
            let (op, value) = self.nodes[i];
            if let Op::Param(s) = op {
                grad[s as usize] += a;
                continue;
            }
            let (args, k) = op.operands();
            let x = args.map(|j| self.nodes[j as usize].1 as f64);
            let d = backward(op, x, value as f64, a);
            for (j, &arg) in args[..k].iter().enumerate() {
                adj[arg as usize] += d[j];
            }
        }
        grad
    }
}
