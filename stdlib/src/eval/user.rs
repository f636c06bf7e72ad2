//! `sdf(f, <f's arguments>, bound:, lipschitz:)`: a `fn` of the point
//! compiled, once, into a [`Tape`] by evaluating its body symbolically:
//! the point is three inputs, each argument one (or three) argument
//! slots, every number an instruction; vectors are lists of instructions
//! (GLSL-style: swizzles, componentwise arithmetic and math), `if` on a
//! comparison of numbers computed from the point is a select, other `fn`s
//! are inlined. Whatever the tape cannot hold (loops, strings, shapes,
//! `random`) is an error pointing into the body.

use super::*;
use crate::builtins::Args;
use crate::param::{Arg as ArgOf, Bound};
use crate::shape::user::{Op, Tape, TapeBuilder, UserArg, UserShape, MAX_ARGS, MAX_OPS};
use crate::shape::{Aabb, Shape};
use glam::DVec3;
use sdfl_lang::check::swizzle;

/// A value while compiling: numbers are instructions.
#[derive(Debug, Clone)]
enum Sym {
    /// A number.
    Num(u32),
    /// A vector of 1 to 4 numbers.
    Vec(Vec<u32>),
    /// A bool known while compiling.
    Bool(bool),
    /// `a > b` (or its negation) of numbers that vary with the point.
    Cond { a: u32, b: u32, negated: bool },
}

impl Sym {
    fn kind(&self) -> &'static str {
        match self {
            Sym::Num(_) => "number",
            Sym::Vec(_) => "vector",
            Sym::Bool(_) | Sym::Cond { .. } => "bool",
        }
    }
}

type R<T = Sym> = Result<T, Diag>;

/// What a shape function may call, for help texts.
const SUPPORTED: &str = "arithmetic, `if` on comparisons, `let`, other `fn`s, swizzles (`p.xz`) and length, abs, min, max, dot, cross, clamp, mix, sin, cos, tan, sqrt, exp, floor, fract, mod, sign, normalize, radians";

fn unsupported(span: Span, message: impl Into<String>, label: impl Into<String>) -> Diag {
    Diag::new(codes::SHAPE_FN, span, message)
        .label(label)
        .help(format!("a shape's function may use {SUPPORTED}"))
}

struct Compiler<'a, 'e> {
    ev: &'a mut Evaluator<'e>,
    tape: TapeBuilder,
    scopes: Vec<HashMap<String, Sym>>,
    depth: usize,
}

impl<'e> Evaluator<'e> {
    /// `sdf(...)`: the bound arguments and the extra ones, named for `f`.
    pub(super) fn user_shape(
        &mut self,
        bound: &Args,
        extra: Vec<(Ident, Value, Span)>,
        site: Span,
    ) -> Value {
        match self.compile_user_shape(bound, extra, site) {
            Ok(s) => Value::Shape(Arc::new(Shape::User(Arc::new(s)))),
            // Stopped by the work limit, which reported it.
            Err(_) if self.aborted => Value::Poison,
            Err(Some(mut d)) => {
                // Inside the `fn`'s body: say which `sdf` compiled it.
                let within = |s: Span| site.start <= s.start && s.end <= site.end;
                if !within(d.span) && !d.notes.iter().any(|(s, _)| within(*s)) {
                    d = d.note(site, "compiled as a shape here");
                }
                self.error(d)
            }
            // An argument that was reported already.
            Err(None) => Value::Poison,
        }
    }

    fn compile_user_shape(
        &mut self,
        bound: &Args,
        extra: Vec<(Ident, Value, Span)>,
        site: Span,
    ) -> Result<UserShape, Option<Diag>> {
        let (fv, fspan) = bound.get("f");
        let Value::Function(f) = fv.clone() else {
            return Err(Some(crate::builtins::type_error(
                fspan,
                "`fn` of the point",
                fv,
            )));
        };
        let Some((point, params)) = f.params.split_first() else {
            return Err(Some(
                Diag::new(
                    codes::SHAPE_FN,
                    f.name.span,
                    format!("`{}` takes no point", f.name.name),
                )
                .label("no parameters")
                .note(fspan, "used as a shape here")
                .help("a shape's function takes the point first: `fn name(p, size: 1) { ... }`"),
            ));
        };
        let mut given: HashMap<String, (Value, Span)> = HashMap::new();
        for (name, v, span) in extra {
            if !params.iter().any(|p| p.name.name == name.name) {
                let names: Vec<&str> = params.iter().map(|p| p.name.name.as_str()).collect();
                return Err(Some(
                    Diag::new(
                        codes::UNKNOWN_ARG,
                        name.span,
                        format!("`{}` has no parameter `{}`", f.name.name, name.name),
                    )
                    .label("unknown parameter")
                    .note(f.name.span, "defined here")
                    .help(match names.is_empty() {
                        true => format!("`{}` takes only the point", f.name.name),
                        false => format!("its parameters after the point: {}", names.join(", ")),
                    }),
                ));
            }
            given.insert(name.name.clone(), (v, span));
        }
        // Arguments: given, or the `fn`'s defaults evaluated as at a call.
        let mut args: Vec<UserArg> = Vec::new();
        let mut scope: HashMap<String, Sym> = HashMap::new();
        let mut tape = TapeBuilder::new();
        let mut slots = 0u32;
        for p in params {
            let (v, span) = match given.remove(&p.name.name) {
                Some(x) => x,
                None => match &p.default {
                    Some(d) => {
                        let caller = std::mem::take(&mut self.locals);
                        let v = self.expr(d);
                        self.locals = caller;
                        (v, d.span)
                    }
                    None => {
                        return Err(Some(
                            Diag::new(
                                codes::MISSING_ARG,
                                site,
                                format!(
                                    "`sdf` needs `{}`'s argument `{}`",
                                    f.name.name, p.name.name
                                ),
                            )
                            .label(format!("`{}` is missing", p.name.name))
                            .note(p.name.span, "a parameter without default")
                            .help(format!(
                                "pass it by name: `sdf({}, {}: ...)`",
                                f.name.name, p.name.name
                            )),
                        ))
                    }
                },
            };
            if v.is_poison() {
                return Err(None);
            }
            let owner = intern(&f.name.name);
            let name = intern(&p.name.name);
            let mut one = Args::new(span);
            one.owner = owner;
            one.named.insert(name, (v.clone(), span));
            let mut slot = |tape: &mut TapeBuilder| {
                let i = tape.push(Op::Arg(slots), span);
                slots += 1;
                i
            };
            let scalar_param = matches!(&v, Value::Param(d) if matches!(d.init, crate::param::ParamInit::Scalar(_)));
            let sym = match &v {
                Value::Bool(b) => Sym::Bool(*b),
                Value::Number(_) => {
                    args.push(UserArg::Scalar(one.scalar_arg(name, Bound::Free)?));
                    Sym::Num(slot(&mut tape))
                }
                Value::Param(_) if scalar_param => {
                    args.push(UserArg::Scalar(one.scalar_arg(name, Bound::Free)?));
                    Sym::Num(slot(&mut tape))
                }
                Value::Param(_) => {
                    args.push(UserArg::Vector(one.vec3_arg(name, Bound::Free)?));
                    Sym::Vec((0..3).map(|_| slot(&mut tape)).collect())
                }
                Value::List(items) if items.len() == 3 => {
                    args.push(UserArg::Vector(one.vec3_arg(name, Bound::Free)?));
                    Sym::Vec((0..3).map(|_| slot(&mut tape)).collect())
                }
                Value::List(items) if (1..=4).contains(&items.len()) => {
                    let Some((xs, _)) = crate::builtins::numbers_of(&v) else {
                        return Err(Some(crate::builtins::type_error(
                            span,
                            "vector of numbers",
                            &v,
                        )));
                    };
                    let mut comps = Vec::new();
                    for x in xs {
                        args.push(UserArg::Scalar(ArgOf::fixed(crate::precision::f32_range(
                            x, span, name,
                        )?)));
                        comps.push(slot(&mut tape));
                    }
                    Sym::Vec(comps)
                }
                other => {
                    return Err(Some(Diag::new(
                        codes::SHAPE_FN,
                        span,
                        format!("a {} cannot be an argument of a shape's function", other.type_name()),
                    )
                    .label(format!("this is a {}", describe(other)))
                    .help("a shape's function takes numbers, vectors (of up to 4 numbers) and bools")));
                }
            };
            if slots as usize > MAX_ARGS {
                return Err(Some(
                    Diag::new(
                        codes::TOO_LARGE,
                        span,
                        format!("a shape's arguments hold more than {MAX_ARGS} numbers"),
                    )
                    .label("one too many")
                    .help("pass fewer or smaller vectors"),
                ));
            }
            scope.insert(p.name.name.clone(), sym);
        }
        let (half, bspan) = self.user_bound(bound)?;
        let declared = match bound.get("lipschitz") {
            (Value::Number(l), s) if l.is_finite() && *l >= 0.0 => (*l > 0.0).then_some((*l, s)),
            (v, s) => {
                return Err(Some(
                    Diag::new(codes::VALUE, s, "`lipschitz` must be a number ≥ 0")
                        .label(format!("this is {}", describe(v)))
                        .help("a bound on the function's gradient norm; 0 derives one"),
                ))
            }
        };
        let inputs: Vec<u32> = (0..3)
            .map(|i| tape.push(Op::Input(i), point.name.span))
            .collect();
        scope.insert(point.name.name.clone(), Sym::Vec(inputs));
        self.calls.push((f.clone(), site));
        let mut c = Compiler {
            ev: self,
            tape,
            scopes: vec![scope],
            depth: 0,
        };
        let result = c.body(&f.body);
        let tape = c.tape;
        self.calls.pop();
        let out = match result? {
            Sym::Num(i) => i,
            other => {
                return Err(Some(
                    Diag::new(
                        codes::SHAPE_FN,
                        f.body.value.span,
                        format!(
                            "a shape's function must give a number, not a {}",
                            other.kind()
                        ),
                    )
                    .label(format!("this is a {}", other.kind()))
                    .note(fspan, "used as a shape here")
                    .help("give the signed distance: `length(p) - 1`, not `p`"),
                ));
            }
        };
        let tape: Tape = tape.finish(out);
        let shape = UserShape {
            name: f.name.name.clone(),
            tape: Arc::new(tape),
            args,
            bound: Aabb::new(-half, half),
            lipschitz: 1.0,
        };
        let analysis = shape.tape.analyse(-half, half, &shape.arg_values());
        if let Some(i) = analysis.unbounded {
            let d = if analysis.past_f32 {
                Diag::new(
                    codes::SHAPE_UNBOUNDED,
                    shape.tape.span(i),
                    format!(
                        "`{}` can pass f32's range (±3.4e38) within its bound, and shapes are evaluated in f32",
                        f.name.name
                    ),
                )
                .label("past f32's range over the bound box")
                .help("scale the constants so that every step stays within ±1e38 (`x · 1e30 · 1e30 / 1e60` is `x`)")
            } else {
                Diag::new(
                    codes::SHAPE_UNBOUNDED,
                    shape.tape.span(i),
                    format!("`{}` can be infinite within its bound", f.name.name),
                )
                .label("unbounded over the bound box")
                .help("guard the division or root (`max(x, 1e-3)`, `abs`), or give a box that keeps away from the pole")
            };
            return Err(Some(d.note(bspan, "the box it is evaluated in")));
        }
        let lipschitz = match declared {
            Some((l, _)) => l,
            None if analysis.lipschitz.is_finite() && analysis.lipschitz > 0.0 => {
                analysis.lipschitz
            }
            // No bound derived (a step, a select that switches): a
            // distance is assumed, as SDF tools do; `lipschitz:` overrides.
            None => 1.0,
        };
        Ok(UserShape { lipschitz, ..shape })
    }

    /// The half extents of `bound:` (a number: a cube).
    fn user_bound(&mut self, a: &Args) -> R<(DVec3, Span)> {
        let (v, s) = a.get("bound");
        let half = match v {
            Value::Number(r) => Some(DVec3::splat(*r)),
            v => v.as_vec3(),
        };
        match half {
            Some(h) if h.min_element() > 0.0 && h.max_element() <= 1e6 => Ok((h, s)),
            _ => Err(Diag::new(
                codes::VALUE,
                s,
                "`bound` must be a half-size from 0 (excluded) to 1e6 (a number or a vector)",
            )
            .label(format!("this is {}", describe(v)))
            .help("the shape lies in the box from -bound to +bound: `bound: 1.5` or `bound: [2, 1, 1]`")),
        }
    }
}

/// A name with a `'static` lifetime (argument names of `fn`s, as
/// trainable arguments' sites): each distinct name is leaked once.
fn intern(name: &str) -> &'static str {
    use std::collections::HashSet;
    use std::sync::{Mutex, OnceLock};
    static NAMES: OnceLock<Mutex<HashSet<&'static str>>> = OnceLock::new();
    let mut names = NAMES
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    if let Some(n) = names.get(name) {
        return n;
    }
    let n: &'static str = Box::leak(name.into());
    names.insert(n);
    n
}

impl Compiler<'_, '_> {
    fn push(&mut self, op: Op, span: Span) -> R<u32> {
        if self.tape.len() >= MAX_OPS {
            return Err(Diag::new(
                codes::TOO_LARGE,
                span,
                format!("a shape's function of more than {MAX_OPS} operations"),
            )
            .label("compiled this far")
            .help("simplify the function, or build the shape from several `sdf`s"));
        }
        if !self.ev.spend(span) {
            return Err(Diag::new(codes::TOO_LARGE, span, "stopped").label("stopped"));
        }
        Ok(self.tape.push(op, span))
    }

    fn constant(&mut self, c: f64, span: Span) -> R<u32> {
        self.push(Op::Const(c), span)
    }

    fn body(&mut self, b: &Body) -> R {
        self.scopes.push(HashMap::new());
        let r = (|| {
            for l in &b.lets {
                let v = self.expr(&l.value)?;
                self.scopes
                    .last_mut()
                    .expect("pushed")
                    .insert(l.name.name.clone(), v);
            }
            self.expr(&b.value)
        })();
        self.scopes.pop();
        r
    }

    /// A number, or an error at `span` naming what it is instead.
    fn num(&self, s: &Sym, span: Span, what: &str) -> R<u32> {
        match s {
            Sym::Num(i) => Ok(*i),
            Sym::Vec(v) if v.len() == 1 => Ok(v[0]),
            other => Err(Diag::new(
                codes::TYPE,
                span,
                format!("{what} needs a number, not a {}", other.kind()),
            )
            .label(format!("this is a {}", other.kind()))
            .help("pick a component (`v.x`) or reduce the vector (`length(v)`)")),
        }
    }

    /// The numbers of a number or vector, and whether it is a vector.
    fn parts(&self, s: &Sym, span: Span) -> R<(Vec<u32>, bool)> {
        match s {
            Sym::Num(i) => Ok((vec![*i], false)),
            Sym::Vec(v) => Ok((v.clone(), true)),
            other => Err(Diag::new(
                codes::TYPE,
                span,
                format!("a {} where a number or vector is needed", other.kind()),
            )
            .label(format!("this is a {}", other.kind()))
            .help("a bool is only a condition of `if`")),
        }
    }

    fn vector(v: Vec<u32>, vector: bool) -> Sym {
        if vector {
            Sym::Vec(v)
        } else {
            Sym::Num(v[0])
        }
    }

    /// `f` of each component pair, numbers broadcast over vectors.
    fn zip(
        &mut self,
        (a, sa): (&Sym, Span),
        (b, sb): (&Sym, Span),
        span: Span,
        mut f: impl FnMut(&mut Self, u32, u32) -> R<u32>,
    ) -> R {
        let (x, vx) = self.parts(a, sa)?;
        let (y, vy) = self.parts(b, sb)?;
        if vx && vy && x.len() != y.len() {
            return Err(Diag::new(
                codes::TYPE,
                span,
                format!(
                    "cannot combine vectors of {} and {} numbers",
                    x.len(),
                    y.len()
                ),
            )
            .label("lengths differ")
            .help("swizzle one to the other's length (`p.xz`)"));
        }
        let n = x.len().max(y.len());
        let pick = |v: &[u32], i: usize| if v.len() == 1 { v[0] } else { v[i] };
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            out.push(f(self, pick(&x, i), pick(&y, i))?);
        }
        Ok(Self::vector(out, vx || vy))
    }

    /// `f` of each component.
    fn map(&mut self, a: &Sym, span: Span, mut f: impl FnMut(&mut Self, u32) -> R<u32>) -> R {
        let (x, vx) = self.parts(a, span)?;
        let mut out = Vec::with_capacity(x.len());
        for c in x {
            out.push(f(self, c)?);
        }
        Ok(Self::vector(out, vx))
    }

    fn expr(&mut self, e: &Expr) -> R {
        if self.depth >= MAX_EVAL_DEPTH {
            return Err(Diag::new(
                codes::TOO_LARGE,
                e.span,
                format!("a shape's function nested more than {MAX_EVAL_DEPTH} levels deep"),
            )
            .label("compiled this far")
            .help("bind parts to names with `let` instead of nesting calls"));
        }
        self.depth += 1;
        let r = self.expr_inner(e);
        self.depth -= 1;
        r
    }

    fn expr_inner(&mut self, e: &Expr) -> R {
        let span = e.span;
        match &e.kind {
            ExprKind::Number(x) => Ok(Sym::Num(self.constant(*x, span)?)),
            ExprKind::Bool(b) => Ok(Sym::Bool(*b)),
            ExprKind::Str(_) => Err(unsupported(
                span,
                "a string in a shape's function",
                "not a number",
            )),
            ExprKind::Var(id) => self.var(id),
            ExprKind::List(items) => {
                if !(1..=4).contains(&items.len()) {
                    return Err(unsupported(
                        span,
                        format!("a vector of {} numbers in a shape's function", items.len()),
                        "vectors have 1 to 4 numbers",
                    ));
                }
                let mut comps = Vec::new();
                for i in items {
                    let s = self.expr(i)?;
                    comps.push(self.num(&s, i.span, "a vector's item")?);
                }
                Ok(Sym::Vec(comps))
            }
            ExprKind::Member(recv, name) => {
                let v = self.expr(recv)?;
                let (comps, _) = self.parts(&v, recv.span)?;
                let picks = swizzle(&name.name).unwrap_or_default();
                let mut out = Vec::new();
                for k in picks {
                    match comps.get(k) {
                        Some(&c) => out.push(c),
                        None => {
                            return Err(Diag::new(
                                codes::INDEX,
                                name.span,
                                format!("`.{}` of a vector of {} numbers", name.name, comps.len()),
                            )
                            .label("no such component")
                            .help("`.x`, `.y`, `.z` are the first, second and third numbers"))
                        }
                    }
                }
                Ok(if out.len() == 1 {
                    Sym::Num(out[0])
                } else {
                    Sym::Vec(out)
                })
            }
            ExprKind::Neg(inner) => {
                let v = self.expr(inner)?;
                self.map(&v, inner.span, |c, x| c.push(Op::Neg(x), span))
            }
            ExprKind::Not(inner) => match self.expr(inner)? {
                Sym::Bool(b) => Ok(Sym::Bool(!b)),
                Sym::Cond { a, b, negated } => Ok(Sym::Cond {
                    a,
                    b,
                    negated: !negated,
                }),
                other => Err(Diag::new(
                    codes::TYPE,
                    inner.span,
                    format!("`!` needs a bool, not a {}", other.kind()),
                )
                .label(format!("this is a {}", other.kind()))
                .help("compare values to get a bool: `p.y < 0`")),
            },
            ExprKind::Index(list, index) => {
                let v = self.expr(list)?;
                let (comps, _) = self.parts(&v, list.span)?;
                let i = self.expr(index)?;
                let k = self.num(&i, index.span, "an index")?;
                match self.tape.constant(k) {
                    Some(x) if x.fract() == 0.0 && x >= 0.0 && (x as usize) < comps.len() => {
                        Ok(Sym::Num(comps[x as usize]))
                    }
                    Some(_) => Err(
                        Diag::new(codes::INDEX, index.span, "index out of the vector")
                            .label(format!("the vector has {} numbers", comps.len()))
                            .help("index vectors with whole numbers from 0"),
                    ),
                    None => Err(unsupported(
                        index.span,
                        "an index that varies with the point",
                        "not a constant",
                    )),
                }
            }
            ExprKind::If {
                cond,
                then,
                otherwise,
            } => match self.expr(cond)? {
                // Known while compiling: only the branch taken.
                Sym::Bool(true) => self.body(then),
                Sym::Bool(false) => self.body(otherwise),
                Sym::Cond { a, b, negated } => {
                    let t = self.body(then)?;
                    let o = self.body(otherwise)?;
                    let (tv, tvec) = self.parts(&t, then.value.span)?;
                    let (ov, ovec) = self.parts(&o, otherwise.value.span)?;
                    if tv.len() != ov.len() || tvec != ovec {
                        return Err(Diag::new(
                            codes::TYPE,
                            span,
                            format!("the branches give a {} and a {}", t.kind(), o.kind()),
                        )
                        .label("branches differ")
                        .help("both branches of a shape's `if` give the same kind of value"));
                    }
                    let mut out = Vec::new();
                    for (x, y) in tv.into_iter().zip(ov) {
                        let (x, y) = if negated { (y, x) } else { (x, y) };
                        out.push(self.push(Op::IfGt(a, b, x, y), span)?);
                    }
                    Ok(Self::vector(out, tvec))
                }
                other => Err(Diag::new(
                    codes::TYPE,
                    cond.span,
                    format!("a condition needs a bool, not a {}", other.kind()),
                )
                .label(format!("this is a {}", other.kind()))
                .help("compare values to get a bool: `p.y < 0`")),
            },
            ExprKind::Binary(op, l, r) if op.is_logical() => {
                let (a, b) = (self.expr(l)?, self.expr(r)?);
                match (a, b) {
                    (Sym::Bool(a), Sym::Bool(b)) => {
                        Ok(Sym::Bool(if *op == BinOp::And { a && b } else { a || b }))
                    }
                    _ => Err(unsupported(
                        span,
                        format!("`{}` of conditions on the point", op.symbol()),
                        "not one comparison",
                    )),
                }
            }
            ExprKind::Binary(op, l, r) if !op.is_arithmetic() => {
                let (a, b) = (self.expr(l)?, self.expr(r)?);
                let a = self.num(&a, l.span, &format!("`{}`", op.symbol()))?;
                let b = self.num(&b, r.span, &format!("`{}`", op.symbol()))?;
                if let (Some(x), Some(y)) = (self.tape.constant(a), self.tape.constant(b)) {
                    return Ok(Sym::Bool(match op {
                        BinOp::Lt => x < y,
                        BinOp::Le => x <= y,
                        BinOp::Gt => x > y,
                        BinOp::Ge => x >= y,
                        BinOp::Eq => x == y,
                        _ => x != y,
                    }));
                }
                Ok(match op {
                    BinOp::Gt => Sym::Cond {
                        a,
                        b,
                        negated: false,
                    },
                    BinOp::Lt => Sym::Cond {
                        a: b,
                        b: a,
                        negated: false,
                    },
                    BinOp::Le => Sym::Cond {
                        a,
                        b,
                        negated: true,
                    },
                    BinOp::Ge => Sym::Cond {
                        a: b,
                        b: a,
                        negated: true,
                    },
                    _ => {
                        return Err(unsupported(
                            span,
                            format!("`{}` of numbers that vary with the point", op.symbol()),
                            "equality is no condition for a shape",
                        ))
                    }
                })
            }
            ExprKind::Binary(op, l, r) => {
                let (a, b) = (self.expr(l)?, self.expr(r)?);
                let op = *op;
                self.zip((&a, l.span), (&b, r.span), span, |c, x, y| {
                    c.binop(op, x, y, span, r.span)
                })
            }
            ExprKind::For { .. } => Err(unsupported(
                span,
                "a loop in a shape's function",
                "not an operation on numbers",
            )),
            ExprKind::Call { callee, args, .. } => self.call(callee, args, span),
        }
    }

    fn binop(&mut self, op: BinOp, x: u32, y: u32, span: Span, rspan: Span) -> R<u32> {
        match op {
            BinOp::Add => self.push(Op::Add(x, y), span),
            BinOp::Sub => self.push(Op::Sub(x, y), span),
            BinOp::Mul => self.push(Op::Mul(x, y), span),
            BinOp::Div => self.push(Op::Div(x, y), span),
            // As the evaluator's `%`: the Euclidean remainder, `x - |y|·floor(x/|y|)`.
            BinOp::Rem => {
                let m = self.push(Op::Abs(y), span)?;
                let q = self.push(Op::Div(x, m), span)?;
                let f = self.push(Op::Floor(q), span)?;
                let t = self.push(Op::Mul(m, f), span)?;
                self.push(Op::Sub(x, t), span)
            }
            BinOp::Pow => {
                let Some(k) = self.tape.constant(y) else {
                    return Err(unsupported(
                        rspan,
                        "`^` with an exponent that varies with the point",
                        "not a constant",
                    ));
                };
                if k == 0.5 {
                    return self.push(Op::Sqrt(x), span);
                }
                if k.fract() != 0.0 || k.abs() > 64.0 {
                    return Err(unsupported(
                        rspan,
                        format!("`^ {}` in a shape's function", fmt_num(k)),
                        "whole exponents up to 64, or 0.5",
                    ));
                }
                // Square and multiply.
                let mut n = k.abs() as u32;
                let mut base = x;
                let mut acc = self.constant(1.0, span)?;
                while n > 0 {
                    if n & 1 == 1 {
                        acc = self.push(Op::Mul(acc, base), span)?;
                    }
                    n >>= 1;
                    if n > 0 {
                        base = self.push(Op::Mul(base, base), span)?;
                    }
                }
                if k < 0.0 {
                    let one = self.constant(1.0, span)?;
                    acc = self.push(Op::Div(one, acc), span)?;
                }
                Ok(acc)
            }
            _ => unreachable!("comparisons and logic are compiled before arithmetic"),
        }
    }

    fn var(&mut self, id: &Ident) -> R {
        for s in self.scopes.iter().rev() {
            if let Some(v) = s.get(&id.name) {
                return Ok(v.clone());
            }
        }
        let Some(v) = self.ev.lookup(&id.name) else {
            return Err(unsupported(
                id.span,
                format!("`{}` in a shape's function", id.name),
                "not a number",
            ));
        };
        let (xs, list) = match &v {
            Value::Bool(b) => return Ok(Sym::Bool(*b)),
            Value::Param(_) => return Err(Diag::new(
                codes::SHAPE_FN,
                id.span,
                format!(
                    "`{}` is a `param` read from outside the shape's arguments",
                    id.name
                ),
            )
            .label("not an argument")
            .help(
                "make it a parameter of the `fn` and pass it to `sdf`: `sdf(f, size: param(1))`",
            )),
            v => {
                match crate::builtins::numbers_of(v) {
                    Some(x) if (1..=4).contains(&x.0.len()) => x,
                    _ => return Err(Diag::new(
                        codes::SHAPE_FN,
                        id.span,
                        format!("a {} in a shape's function", v.type_name()),
                    )
                    .label(format!("this is a {}", describe(v)))
                    .help(
                        "a shape's function computes with numbers and vectors of up to 4 numbers",
                    )),
                }
            }
        };
        let mut comps = Vec::new();
        for x in xs {
            comps.push(self.constant(x, id.span)?);
        }
        Ok(Self::vector(comps, list))
    }

    fn call(&mut self, callee: &Ident, args: &[Arg], span: Span) -> R {
        if let Some(f) = self.ev.fns.get(&callee.name).cloned() {
            return self.inline(&f, args, span);
        }
        let Some(sig) = self.ev.env.builtin(&callee.name).map(|b| &b.sig) else {
            return Err(unsupported(
                callee.span,
                format!("`{}`", callee.name),
                "unknown",
            ));
        };
        let name = sig.name;
        // Arguments in the signature's order (positional, then named; the
        // checker bound them), rest arguments in order.
        let mut vals: Vec<Option<(Sym, Span)>> = vec![None; sig.params.len()];
        let mut rest = Vec::new();
        let supported = matches!(
            name,
            "length"
                | "abs"
                | "sqrt"
                | "sin"
                | "cos"
                | "tan"
                | "exp"
                | "floor"
                | "fract"
                | "sign"
                | "radians"
                | "min"
                | "max"
                | "dot"
                | "cross"
                | "clamp"
                | "mix"
                | "mod"
                | "normalize"
        );
        if !supported {
            return Err(Diag::new(
                codes::SHAPE_FN,
                callee.span,
                format!("`{}` cannot be used in a shape's function", callee.name),
            )
            .label("not an operation on numbers")
            .help(format!("a shape's function may use {SUPPORTED}")));
        }
        for (i, a) in args.iter().enumerate() {
            let v = self.expr(&a.value)?;
            let slot = match &a.name {
                Some(n) => sig.params.iter().position(|p| p.name == n.name),
                None => sig.positional(i).map(|_| i),
            };
            match slot {
                Some(k) => vals[k] = Some((v, a.value.span)),
                None => rest.push((v, a.value.span)),
            }
        }
        let mut arg = |k: usize| -> R<(Sym, Span)> {
            vals.get_mut(k).and_then(Option::take).ok_or_else(|| {
                Diag::new(
                    codes::MISSING_ARG,
                    span,
                    format!("`{name}` needs more arguments"),
                )
                .label("missing")
                .help("the checker binds them: this is a bug")
            })
        };
        let unary = |c: &mut Self, s: &(Sym, Span), op: fn(u32) -> Op| {
            c.map(&s.0, s.1, |c, x| c.push(op(x), span))
        };
        match name {
            "abs" => unary(self, &arg(0)?, Op::Abs),
            "sqrt" => unary(self, &arg(0)?, Op::Sqrt),
            "sin" => unary(self, &arg(0)?, Op::Sin),
            "cos" => unary(self, &arg(0)?, Op::Cos),
            "exp" => unary(self, &arg(0)?, Op::Exp),
            "floor" => unary(self, &arg(0)?, Op::Floor),
            "tan" => {
                let a = arg(0)?;
                self.map(&a.0, a.1, |c, x| {
                    let (s, k) = (c.push(Op::Sin(x), span)?, c.push(Op::Cos(x), span)?);
                    c.push(Op::Div(s, k), span)
                })
            }
            "fract" => {
                let a = arg(0)?;
                self.map(&a.0, a.1, |c, x| {
                    let f = c.push(Op::Floor(x), span)?;
                    c.push(Op::Sub(x, f), span)
                })
            }
            "sign" => {
                let a = arg(0)?;
                self.map(&a.0, a.1, |c, x| {
                    let (zero, one, minus) = (
                        c.constant(0.0, span)?,
                        c.constant(1.0, span)?,
                        c.constant(-1.0, span)?,
                    );
                    let below = c.push(Op::IfGt(zero, x, minus, zero), span)?;
                    c.push(Op::IfGt(x, zero, one, below), span)
                })
            }
            "radians" => {
                let a = arg(0)?;
                self.map(&a.0, a.1, |c, x| {
                    let k = c.constant(std::f64::consts::PI / 180.0, span)?;
                    c.push(Op::Mul(x, k), span)
                })
            }
            "length" => {
                let a = arg(0)?;
                let (v, _) = self.parts(&a.0, a.1)?;
                Ok(Sym::Num(self.length(&v, span)?))
            }
            "normalize" => {
                let a = arg(0)?;
                let (v, vec) = self.parts(&a.0, a.1)?;
                let len = self.length(&v, span)?;
                // Finite at the origin (the zero vector stays zero).
                let tiny = self.constant(1e-30, span)?;
                let len = self.push(Op::Max(len, tiny), span)?;
                let mut out = Vec::new();
                for c in v {
                    out.push(self.push(Op::Div(c, len), span)?);
                }
                Ok(Self::vector(out, vec))
            }
            "dot" => {
                let (a, b) = (arg(0)?, arg(1)?);
                let prod = self.zip((&a.0, a.1), (&b.0, b.1), span, |c, x, y| {
                    c.push(Op::Mul(x, y), span)
                })?;
                let (terms, _) = self.parts(&prod, span)?;
                let mut acc = terms[0];
                for &t in &terms[1..] {
                    acc = self.push(Op::Add(acc, t), span)?;
                }
                Ok(Sym::Num(acc))
            }
            "cross" => {
                let (a, b) = (arg(0)?, arg(1)?);
                let (x, _) = self.parts(&a.0, a.1)?;
                let (y, _) = self.parts(&b.0, b.1)?;
                if x.len() != 3 || y.len() != 3 {
                    return Err(Diag::new(
                        codes::TYPE,
                        span,
                        "`cross` of vectors that are not 3 numbers",
                    )
                    .label("needs two 3-vectors")
                    .help("`cross` is defined for 3-vectors"));
                }
                let mut out = Vec::new();
                for (i, j) in [(1, 2), (2, 0), (0, 1)] {
                    let l = self.push(Op::Mul(x[i], y[j]), span)?;
                    let r = self.push(Op::Mul(x[j], y[i]), span)?;
                    out.push(self.push(Op::Sub(l, r), span)?);
                }
                Ok(Sym::Vec(out))
            }
            "clamp" => {
                let (x, lo, hi) = (arg(0)?, arg(1)?, arg(2)?);
                let m = self.zip((&x.0, x.1), (&lo.0, lo.1), span, |c, a, b| {
                    c.push(Op::Max(a, b), span)
                })?;
                self.zip((&m, x.1), (&hi.0, hi.1), span, |c, a, b| {
                    c.push(Op::Min(a, b), span)
                })
            }
            "mix" => {
                let (a, b, t) = (arg(0)?, arg(1)?, arg(2)?);
                let d = self.zip((&b.0, b.1), (&a.0, a.1), span, |c, x, y| {
                    c.push(Op::Sub(x, y), span)
                })?;
                let s = self.zip((&d, span), (&t.0, t.1), span, |c, x, y| {
                    c.push(Op::Mul(x, y), span)
                })?;
                self.zip((&a.0, a.1), (&s, span), span, |c, x, y| {
                    c.push(Op::Add(x, y), span)
                })
            }
            "mod" => {
                let (x, y) = (arg(0)?, arg(1)?);
                self.zip((&x.0, x.1), (&y.0, y.1), span, |c, a, b| {
                    let q = c.push(Op::Div(a, b), span)?;
                    let f = c.push(Op::Floor(q), span)?;
                    let t = c.push(Op::Mul(b, f), span)?;
                    c.push(Op::Sub(a, t), span)
                })
            }
            // `min`/`max`: two values with a vector componentwise, else
            // the extreme of every number given.
            _ => {
                let pick = if name == "min" { Op::Min } else { Op::Max };
                if let [a, b] = rest.as_slice() {
                    if matches!(a.0, Sym::Vec(_)) || matches!(b.0, Sym::Vec(_)) {
                        let (xa, _) = self.parts(&a.0, a.1)?;
                        let (xb, _) = self.parts(&b.0, b.1)?;
                        if xa.len() == xb.len() || xa.len() == 1 || xb.len() == 1 {
                            return self.zip((&a.0, a.1), (&b.0, b.1), span, |c, x, y| {
                                c.push(pick(x, y), span)
                            });
                        }
                    }
                }
                let mut all = Vec::new();
                for (s, sp) in &rest {
                    all.extend(self.parts(s, *sp)?.0);
                }
                let Some((&first, others)) = all.split_first() else {
                    return Err(
                        Diag::new(codes::VALUE, span, format!("`{name}` of no numbers"))
                            .label("empty")
                            .help("give at least one number"),
                    );
                };
                let mut acc = first;
                for &x in others {
                    acc = self.push(pick(acc, x), span)?;
                }
                Ok(Sym::Num(acc))
            }
        }
    }

    /// The length of a vector: kept whole for 2 and 3 numbers.
    fn length(&mut self, v: &[u32], span: Span) -> R<u32> {
        match *v {
            [a] => self.push(Op::Abs(a), span),
            [a, b] => self.push(Op::Hypot2(a, b), span),
            [a, b, c] => self.push(Op::Hypot3(a, b, c), span),
            [a, b, c, d] => {
                let (x, y) = (
                    self.push(Op::Hypot2(a, b), span)?,
                    self.push(Op::Hypot2(c, d), span)?,
                );
                self.push(Op::Hypot2(x, y), span)
            }
            _ => Err(unsupported(span, "the length of an empty vector", "empty")),
        }
    }

    /// Another `fn` called from a shape's function: its body compiled in
    /// place, its parameters bound as at a call.
    fn inline(&mut self, f: &Arc<FnDef>, args: &[Arg], span: Span) -> R {
        if !self.ev.spend_n(f.params.len() as u64 + 1, span) {
            return Err(Diag::new(codes::TOO_LARGE, span, "stopped").label("stopped"));
        }
        let mut scope: HashMap<String, Sym> = HashMap::new();
        for (i, a) in args.iter().enumerate() {
            let v = self.expr(&a.value)?;
            let slot = match &a.name {
                Some(n) => f.params.iter().find(|p| p.name.name == n.name),
                None => f.params.get(i),
            };
            if let Some(p) = slot {
                scope.insert(p.name.name.clone(), v);
            }
        }
        // Defaults see only top-level names, as at a call.
        let caller = std::mem::take(&mut self.scopes);
        let mut r = Ok(());
        for p in &f.params {
            if let (false, Some(d)) = (scope.contains_key(&p.name.name), &p.default) {
                match self.expr(d) {
                    Ok(v) => {
                        scope.insert(p.name.name.clone(), v);
                    }
                    Err(e) => {
                        r = Err(e);
                        break;
                    }
                }
            }
        }
        self.scopes = vec![scope];
        let v = r.and_then(|_| self.body(&f.body));
        self.scopes = caller;
        v
    }
}
