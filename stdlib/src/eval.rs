//! Evaluation of a checked file into a [`Program`]: expressions are reduced
//! to values, loops unrolled, built-ins called and blocks turned into jobs.
//! Value errors (a negative radius, a loop too large) are diagnostics with
//! the span of the offending expression; evaluation carries on with
//! [`Value::Poison`] so every error of the file is reported.

use std::collections::HashMap;
use std::sync::Arc;

use sdfl_lang::ast::*;
use sdfl_lang::diag::{codes, Diag, Diagnostics};
use sdfl_lang::Span;

use crate::builtins::{Args, StdEnv};
use crate::value::{Program, Value};

/// Most iterations of one `for` binding.
pub const MAX_LOOP: u64 = 1_000_000;
/// Most loop iterations and calls in a whole file: a bound on evaluation
/// time and memory (a few hundred bytes per shape).
pub const MAX_WORK: u64 = 2_000_000;
/// Deepest nesting of shapes and lists (built through chains of `let`s,
/// which brackets do not limit): tree walkers recurse this deep.
pub const MAX_DEPTH: usize = 200;

/// Whether a value nests deeper than `limit` (visits at most `limit` levels).
fn deeper_than(v: &Value, limit: usize) -> bool {
    fn shape(s: &crate::shape::Shape, limit: usize) -> bool {
        limit == 0 || s.children().into_iter().any(|c| shape(c, limit - 1))
    }
    if limit == 0 {
        return true;
    }
    match v {
        Value::List(items) => items.iter().any(|i| deeper_than(i, limit - 1)),
        Value::Shape(s) => shape(s, limit),
        _ => false,
    }
}

pub struct Evaluator<'e> {
    env: &'e StdEnv,
    globals: HashMap<String, Value>,
    locals: Vec<HashMap<String, Value>>,
    pub(crate) diags: Diagnostics,
    work: u64,
    aborted: bool,
    defaults: HashMap<(&'static str, &'static str), Value>,
    /// Values replacing top-level `let`s (for sweeps).
    overrides: HashMap<String, Value>,
    /// `param(...)` calls evaluated so far (their ids).
    params: usize,
}

impl<'e> Evaluator<'e> {
    pub fn new(env: &'e StdEnv) -> Self {
        Evaluator {
            env,
            globals: HashMap::new(),
            locals: Vec::new(),
            diags: Diagnostics::default(),
            work: 0,
            aborted: false,
            defaults: HashMap::new(),
            overrides: HashMap::new(),
            params: 0,
        }
    }

    /// Replace the value of top-level `let NAME = ...` bindings.
    pub fn with_overrides(mut self, overrides: HashMap<String, Value>) -> Self {
        self.overrides = overrides;
        self
    }

    /// Evaluate a checked file.
    pub fn run(mut self, file: &File) -> Result<Program, Diagnostics> {
        let mut program = Program::default();
        for item in &file.items {
            if self.aborted {
                break;
            }
            match item {
                Item::Let(l) => {
                    let mut v = match self.overrides.get(&l.name.name) {
                        Some(v) => v.clone(),
                        None => self.expr(&l.value),
                    };
                    name_param(&mut v, &l.name.name);
                    self.globals.insert(l.name.name.clone(), v);
                }
                Item::Block(b) => {
                    let index =
                        program.renders.len() + program.volumes.len() + program.trains.len();
                    self.block(b, index, &mut program);
                }
            }
        }
        if self.diags.is_empty() {
            Ok(program)
        } else {
            Err(self.diags.sorted())
        }
    }

    fn error(&mut self, d: Diag) -> Value {
        self.diags.push(d);
        Value::Poison
    }

    fn spend(&mut self, span: Span) -> bool {
        self.work += 1;
        if self.work > MAX_WORK && !self.aborted {
            self.aborted = true;
            self.diags.push(
                Diag::new(
                    codes::TOO_LARGE,
                    span,
                    format!("the scene needs more than {MAX_WORK} loop iterations and calls"),
                )
                .label("evaluation stopped here")
                .help("reduce the loop counts; sdfl scenes are meant to stay below a million primitives"),
            );
        }
        !self.aborted
    }

    fn block(&mut self, b: &Block, index: usize, program: &mut Program) {
        let Some(sig) = self.env.block_sig(&b.kind.name) else {
            return;
        };
        let mut args = Args::new(b.kind.span);
        args.owner = sig.kind;
        for f in &b.fields {
            let v = self.expr(&f.value);
            if let Some(p) = sig.fields.iter().find(|p| p.name == f.name.name) {
                args.named.insert(p.name, (v, f.value.span));
            }
        }
        for p in &sig.fields {
            if let (false, Some(src)) = (args.named.contains_key(p.name), p.default) {
                let v = self.default_value(sig.kind, p.name, src);
                args.named.insert(p.name, (v, b.kind.span));
            }
        }
        if args.named.values().any(|(v, _)| v.is_poison()) {
            return;
        }
        let name = b
            .name
            .as_ref()
            .map_or_else(|| format!("{}{index}", b.kind.name), |n| n.name.clone());
        let result = match (sig.kind, args.named.get("scene")) {
            ("train", _) => {
                crate::builtins::train_block(&name, &args).map(|j| program.trains.push(j))
            }
            (_, Some((Value::Field(f), _))) => {
                crate::builtins::volume_block(&name, &args, f.clone())
                    .map(|j| program.volumes.push(j))
            }
            _ => crate::builtins::render_block(&name, &args).map(|j| program.renders.push(j)),
        };
        if let Err(d) = result {
            self.diags.push(d);
        }
    }

    /// The value of a parameter's default, written as sdfl source in the
    /// signature (so docs and behaviour cannot disagree).
    fn default_value(
        &mut self,
        owner: &'static str,
        param: &'static str,
        src: &'static str,
    ) -> Value {
        if let Some(v) = self.defaults.get(&(owner, param)) {
            return v.clone();
        }
        let text = format!("let default = {src}");
        let v = match sdfl_lang::parse::parse(&text) {
            Ok(file) => match file.items.first() {
                Some(Item::Let(l)) => {
                    let mut sub = Evaluator::new(self.env);
                    let v = sub.expr(&l.value);
                    assert!(
                        sub.diags.is_empty(),
                        "default of {owner}.{param} is invalid: {src}"
                    );
                    v
                }
                _ => unreachable!("a let parses to a let"),
            },
            Err(_) => panic!("default of {owner}.{param} does not parse: {src}"),
        };
        self.defaults.insert((owner, param), v.clone());
        v
    }

    fn lookup(&self, name: &str) -> Option<Value> {
        for scope in self.locals.iter().rev() {
            if let Some(v) = scope.get(name) {
                return Some(v.clone());
            }
        }
        self.globals
            .get(name)
            .cloned()
            .or_else(|| self.env.constant_value(name))
    }

    pub(crate) fn expr(&mut self, e: &Expr) -> Value {
        if self.aborted {
            return Value::Poison;
        }
        match &e.kind {
            ExprKind::Number(x) => Value::Number(*x),
            ExprKind::Bool(b) => Value::Bool(*b),
            ExprKind::Str(s) => Value::Str(s.as_str().into()),
            // The checker has resolved every name; an unknown one here means
            // the file was not checked, which is poison rather than a panic.
            ExprKind::Var(id) => self.lookup(&id.name).unwrap_or(Value::Poison),
            ExprKind::List(items) => {
                let items: Vec<Value> = items.iter().map(|i| self.expr(i)).collect();
                // A list holding poison is poison: the depth of what was
                // already reported must not keep growing unchecked.
                if items.iter().any(|i| matches!(i, Value::Poison)) {
                    return Value::Poison;
                }
                self.depth_checked(Value::List(Arc::new(items)), e.span)
            }
            ExprKind::Call { callee, args, .. } => self.call(callee, args, e.span),
            ExprKind::Member(recv, name) => {
                let v = self.expr(recv);
                if v.is_poison() {
                    return Value::Poison;
                }
                let idx = match name.name.as_str() {
                    "x" => 0,
                    "y" => 1,
                    _ => 2,
                };
                match v.as_vec3() {
                    Some(p) => Value::Number(p[idx]),
                    None => self.error(
                        Diag::new(
                            codes::TYPE,
                            recv.span,
                            format!("`.{}` needs a vector of three numbers", name.name),
                        )
                        .label(format!("this is a {}", describe(&v)))
                        .help("components exist on vectors `[x, y, z]`"),
                    ),
                }
            }
            ExprKind::Neg(inner) => {
                let v = self.expr(inner);
                self.arith(BinOp::Sub, Value::Number(0.0), v, e.span, inner.span)
            }
            ExprKind::Binary(op, l, r) => {
                let (lv, rv) = (self.expr(l), self.expr(r));
                self.arith(*op, lv, rv, e.span, r.span)
            }
            ExprKind::For { bindings, body } => {
                let mut out = Vec::new();
                self.locals.push(HashMap::new());
                self.comprehension(bindings, body, e.span, &mut out);
                self.locals.pop();
                if out.iter().any(Value::is_poison) {
                    return Value::Poison;
                }
                Value::List(Arc::new(out))
            }
        }
    }

    fn comprehension(
        &mut self,
        bindings: &[Binding],
        body: &Body,
        span: Span,
        out: &mut Vec<Value>,
    ) {
        let Some((first, rest)) = bindings.split_first() else {
            self.locals.push(HashMap::new());
            for l in &body.lets {
                let v = self.expr(&l.value);
                self.locals
                    .last_mut()
                    .expect("pushed")
                    .insert(l.name.name.clone(), v);
            }
            out.push(self.expr(&body.value));
            self.locals.pop();
            return;
        };
        let items: Vec<Value> = match &first.source {
            Source::Range {
                start,
                end,
                inclusive,
            } => {
                let (s, t) = (self.expr(start), self.expr(end));
                let (Value::Number(s), Value::Number(t)) = (s, t) else {
                    out.push(Value::Poison);
                    return;
                };
                let count = if *inclusive {
                    (t - s).floor() + 1.0
                } else {
                    (t - s).ceil()
                };
                let count = count.max(0.0);
                if count > MAX_LOOP as f64 {
                    let span = start.span.to(end.span);
                    self.error(
                        Diag::new(
                            codes::TOO_LARGE,
                            span,
                            format!("range has {count:.0} values (at most {MAX_LOOP})"),
                        )
                        .label("too many iterations")
                        .help("sdfl scenes are meant to stay below a million primitives"),
                    );
                    out.push(Value::Poison);
                    return;
                }
                (0..count as u64)
                    .map(|k| Value::Number(s + k as f64))
                    .collect()
            }
            Source::List(list) => match self.expr(list) {
                Value::List(items) => items.as_ref().clone(),
                Value::Poison => {
                    out.push(Value::Poison);
                    return;
                }
                other => {
                    let d = Diag::new(
                        codes::TYPE,
                        list.span,
                        format!("cannot loop over a {}", other.type_name()),
                    )
                    .label("not a list")
                    .help("loop over a range `0..n` or a list `[...]`");
                    out.push(self.error(d));
                    return;
                }
            },
        };
        for item in items {
            if !self.spend(span) {
                return;
            }
            self.locals
                .last_mut()
                .expect("pushed by caller")
                .insert(first.var.name.clone(), item);
            self.comprehension(rest, body, span, out);
        }
    }

    fn arith(&mut self, op: BinOp, l: Value, r: Value, span: Span, rhs_span: Span) -> Value {
        let apply = |a: f64, b: f64| match op {
            BinOp::Add => a + b,
            BinOp::Sub => a - b,
            BinOp::Mul => a * b,
            BinOp::Div => a / b,
            BinOp::Rem => a.rem_euclid(b),
            BinOp::Pow => a.powf(b),
        };
        let nums = |v: &Value| -> Option<Vec<f64>> {
            match v {
                Value::Number(x) => Some(vec![*x]),
                Value::List(items) => items
                    .iter()
                    .map(|i| {
                        if let Value::Number(x) = i {
                            Some(*x)
                        } else {
                            None
                        }
                    })
                    .collect(),
                _ => None,
            }
        };
        if l.is_poison() || r.is_poison() {
            return Value::Poison;
        }
        let (Some(a), Some(b)) = (nums(&l), nums(&r)) else {
            let d = Diag::new(
                codes::TYPE,
                span,
                format!("`{}` needs numbers or lists of numbers", op.symbol()),
            )
            .label(format!("{} {} {}", describe(&l), op.symbol(), describe(&r)))
            .help("arithmetic applies to numbers and vectors");
            return self.error(d);
        };
        let scalar = matches!((&l, &r), (Value::Number(_), Value::Number(_)));
        let result: Vec<f64> = match (a.len(), b.len()) {
            _ if scalar => vec![apply(a[0], b[0])],
            (n, m) if n == m => a.iter().zip(&b).map(|(x, y)| apply(*x, *y)).collect(),
            (_, 1) if !matches!(r, Value::List(_)) => a.iter().map(|x| apply(*x, b[0])).collect(),
            (1, _) if !matches!(l, Value::List(_)) => b.iter().map(|y| apply(a[0], *y)).collect(),
            (n, m) => {
                let d = Diag::new(
                    codes::TYPE,
                    span,
                    format!("cannot combine lists of {n} and {m} numbers"),
                )
                .label("lengths differ")
                .help(
                    "elementwise arithmetic needs lists of the same length, or a number and a list",
                );
                return self.error(d);
            }
        };
        if let Some(bad) = result.iter().find(|x| !x.is_finite()) {
            let zero_div = matches!(op, BinOp::Div | BinOp::Rem) && b.contains(&0.0);
            let d = if zero_div {
                Diag::new(codes::ARITHMETIC, rhs_span, "division by zero")
                    .label("this is zero")
                    .help("guard the divisor, e.g. `max(x, 1e-6)`")
            } else {
                Diag::new(codes::ARITHMETIC, span, format!("arithmetic gives {bad}"))
                    .label("not a finite number")
                    .help("check the operands: results must be finite numbers")
            };
            return self.error(d);
        }
        if scalar {
            Value::Number(result[0])
        } else {
            Value::List(Arc::new(result.into_iter().map(Value::Number).collect()))
        }
    }

    fn call(&mut self, callee: &Ident, args: &[Arg], span: Span) -> Value {
        if !self.spend(span) {
            return Value::Poison;
        }
        let Some(builtin) = self.env.builtin(&callee.name) else {
            return Value::Poison;
        };
        let sig = &builtin.sig;
        let mut bound = Args::new(span);
        bound.owner = sig.name;
        let mut poisoned = false;
        for (i, a) in args.iter().enumerate() {
            let v = self.expr(&a.value);
            poisoned |= v.is_poison();
            let slot = match &a.name {
                Some(n) => sig.params.iter().find(|p| p.name == n.name).map(|p| p.name),
                None => sig.params.get(i).map(|p| p.name),
            };
            match slot {
                Some(name) => {
                    bound.named.insert(name, (v, a.value.span));
                }
                None => bound.rest.push((v, a.value.span)),
            }
        }
        if poisoned {
            return Value::Poison;
        }
        for p in &sig.params {
            if let (false, Some(src)) = (bound.named.contains_key(p.name), p.default) {
                let v = self.default_value(sig.name, p.name, src);
                bound.named.insert(p.name, (v, span));
            }
        }
        match (builtin.eval)(&bound) {
            Ok(Value::Param(mut decl)) => {
                Arc::make_mut(&mut decl).id = self.params;
                self.params += 1;
                Value::Param(decl)
            }
            Ok(v) => self.depth_checked(v, span),
            Err(d) => self.error(d),
        }
    }

    fn depth_checked(&mut self, v: Value, span: Span) -> Value {
        if !deeper_than(&v, MAX_DEPTH) {
            return v;
        }
        self.error(
            Diag::new(
                codes::TOO_LARGE,
                span,
                format!("value nested more than {MAX_DEPTH} levels deep"),
            )
            .label("too deep")
            .help("build long sequences with `for` and `union` instead of chaining `let`s"),
        )
    }
}

/// A `param(...)` bound directly to a `let` takes the binding's name.
fn name_param(v: &mut Value, name: &str) {
    if let Value::Param(decl) = v {
        if decl.binding.is_none() {
            Arc::make_mut(decl).binding = Some(name.to_string());
        }
    }
}

/// A short description of a value for messages.
pub(crate) fn describe(v: &Value) -> String {
    match v {
        Value::Number(x) => format!("number {x}"),
        Value::List(items) => format!("list of {} items", items.len()),
        other => other.type_name().to_string(),
    }
}
