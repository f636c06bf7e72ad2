//! Evaluation of a checked file into a [`Program`]: expressions are reduced
//! to values, loops unrolled, built-ins called and blocks turned into jobs.
//! Value errors (a negative radius, a loop too large) are diagnostics with
//! the span of the offending expression; evaluation carries on with
//! [`Value::Poison`] so every error of the file is reported.

use std::collections::HashMap;
use std::sync::Arc;

use sdfl_lang::ast::*;
use sdfl_lang::diag::{codes, fmt_num, Diag, Diagnostics};
use sdfl_lang::Span;

use crate::builtins::{Args, StdEnv};
use crate::size::{
    fmt_bytes, fmt_count, size_error, Size, Sizes, BYTES_PER_PRIMITIVE, MAX_NODES, MAX_PRIMITIVES,
};
use crate::value::{describe, Program, StatementKind, Value};

mod blocks;
mod user;

/// Most iterations of one `for` binding.
pub const MAX_LOOP: u64 = 1_000_000;
/// Most loop iterations and calls in a whole file: a bound on evaluation
/// time.
pub const MAX_WORK: u64 = 2_000_000;
pub use crate::size::MAX_DEPTH;

/// Most call sites labelled on one error inside a `fn` (the others are
/// counted).
const MAX_CALL_LABELS: usize = 6;

/// Deepest nesting of expression evaluation, `fn` calls included: the
/// parser bounds one expression's height, and a call evaluates another
/// expression inside the caller's, so chains of calls are bounded here to
/// the same depth (the evaluator recurses once per level).
pub const MAX_EVAL_DEPTH: usize = sdfl_lang::parse::MAX_DEPTH;

/// Evaluates a checked file into a [`Program`]: unrolls loops, calls
/// built-ins and `fn`s, and gathers every diagnostic.
pub struct Evaluator<'e> {
    env: &'e StdEnv,
    /// The `fn`s defined so far.
    fns: HashMap<String, Arc<FnDef>>,
    /// Current nesting of [`Evaluator::expr`].
    depth: usize,
    globals: HashMap<String, Value>,
    locals: Vec<HashMap<String, Value>>,
    pub(crate) diags: Diagnostics,
    work: u64,
    aborted: bool,
    defaults: HashMap<(&'static str, &'static str), Value>,
    /// Where the items the checker found errors in start (sorted): they are
    /// not evaluated (a `let` binds poison, a `fn` is left undefined).
    failed: Vec<usize>,
    /// Values replacing top-level `let`s (for sweeps).
    overrides: HashMap<String, Value>,
    /// `param(...)` calls evaluated so far (their ids).
    params: usize,
    sizes: Sizes,
    /// The `fn` calls being evaluated (their names and call sites),
    /// outermost first.
    calls: Vec<(Arc<FnDef>, Span)>,
    /// Where each diagnostic reported so far is, by what it says: the same
    /// error met again (a `fn` called twice, a loop) is reported once.
    reported: HashMap<(&'static str, Span, String), usize>,
    /// Calls met by a diagnostic beyond those labelled, by its index.
    more_calls: HashMap<usize, usize>,
    /// Estimated evaluations and primitives of the statements so far.
    total_evaluations: f64,
    total_primitives: u64,
    total_refused: bool,
    /// Every file the program writes so far, for collisions.
    files: crate::outputs::Files,
    /// The scene file's directory, for input paths (see [`Args::base`]).
    base: Option<std::sync::Arc<std::path::Path>>,
}

impl<'e> Evaluator<'e> {
    /// An evaluator over the standard library `env`.
    pub fn new(env: &'e StdEnv) -> Self {
        Evaluator {
            env,
            fns: HashMap::new(),
            depth: 0,
            globals: HashMap::new(),
            locals: Vec::new(),
            diags: Diagnostics::default(),
            work: 0,
            aborted: false,
            defaults: HashMap::new(),
            overrides: HashMap::new(),
            failed: Vec::new(),
            params: 0,
            sizes: Sizes::default(),
            calls: Vec::new(),
            reported: HashMap::new(),
            more_calls: HashMap::new(),
            total_evaluations: 0.0,
            total_primitives: 0,
            total_refused: false,
            files: crate::outputs::Files::default(),
            base: None,
        }
    }

    /// Input paths are relative to `base`, and checked to exist there.
    pub fn with_base(mut self, base: Option<std::sync::Arc<std::path::Path>>) -> Self {
        self.base = base;
        self
    }

    /// Replace the value of top-level `let NAME = ...` bindings.
    pub fn with_overrides(mut self, overrides: HashMap<String, Value>) -> Self {
        self.overrides = overrides;
        self
    }

    /// An evaluator of the items of `file` that hold none of the checker's
    /// errors at `errors` (only those are checked: the others are skipped).
    /// `None` when an error lies outside every item.
    pub fn without_failed(mut self, file: &File, errors: Vec<Span>) -> Option<Self> {
        let mut items: Vec<Span> = file.items.iter().map(item_span).collect();
        items.sort_unstable_by_key(|s| s.start);
        let mut failed = Vec::new();
        for e in errors {
            // The last item starting at or before the error must hold it.
            let k = items.partition_point(|s| s.start <= e.start);
            let item = items.get(k.checked_sub(1)?)?;
            if e.start >= item.end {
                return None;
            }
            failed.push(item.start);
        }
        failed.sort_unstable();
        failed.dedup();
        self.failed = failed;
        Some(self)
    }

    fn item_failed(&self, item: &Item) -> bool {
        self.failed.binary_search(&item_span(item).start).is_ok()
    }

    /// Evaluate a checked file.
    pub fn run(self, file: &File) -> Result<Program, Diagnostics> {
        self.run_warned(file).map(|(p, _)| p)
    }

    /// Evaluate a checked file; with the warnings when it has no errors.
    /// (When it has, the warnings are reported with the errors.)
    pub fn run_warned(mut self, file: &File) -> Result<(Program, Diagnostics), Diagnostics> {
        let mut program = Program::default();
        // Sized up front: a table growing holds its old copy too.
        let lets = file
            .items
            .iter()
            .filter(|i| matches!(i, Item::Let(_)))
            .count();
        self.globals.reserve(lets);
        for item in &file.items {
            if self.aborted {
                break;
            }
            if self.item_failed(item) {
                if let Item::Let(l) = item {
                    self.globals.insert(l.name.name.clone(), Value::Poison);
                }
                continue;
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
                Item::Fn(f) => {
                    self.fns.insert(f.name.name.clone(), Arc::new(f.clone()));
                }
                // Spliced into the file by the resolver before evaluation.
                Item::Import(_) => {}
            }
        }
        for (&i, &n) in &self.more_calls {
            let d = &mut self.diags.diags[i];
            let more = format!("(and {n} more call{})", if n == 1 { "" } else { "s" });
            d.help = Some(match d.help.take() {
                Some(h) => format!("{h} {more}"),
                None => more,
            });
        }
        if self.diags.has_errors() {
            Err(self.diags.sorted())
        } else {
            Ok((program, self.diags.sorted()))
        }
    }

    fn error(&mut self, d: Diag) -> Value {
        self.report(d);
        Value::Poison
    }

    /// Reports `d` once: inside `fn` calls, with each call site as a label
    /// (the error is at the definition, which every call shares); the same
    /// error met again adds its call sites to the first report.
    pub(crate) fn report(&mut self, d: Diag) {
        let key = (d.code, d.span, d.message.clone());
        let i = match self.reported.get(&key) {
            Some(&i) => i,
            None => {
                self.reported.insert(key, self.diags.len());
                self.diags.push(d);
                self.diags.len() - 1
            }
        };
        for (f, site) in &self.calls {
            let d = &mut self.diags.diags[i];
            if d.notes.iter().any(|(s, _)| s == site) {
                continue;
            }
            if d.notes.len() >= MAX_CALL_LABELS {
                *self.more_calls.entry(i).or_insert(0) += 1;
                continue;
            }
            d.notes
                .push((*site, format!("`{}` called here", f.name.name)));
        }
    }

    fn spend(&mut self, span: Span) -> bool {
        self.spend_n(1, span)
    }

    /// Spends `n` units of work: a loop iteration or call is one, and the
    /// items of lists passed to calls or combined by arithmetic one each
    /// (builtins and arithmetic walk them; a loop over `union(big)` costs
    /// the size of `big` every time).
    fn spend_n(&mut self, n: u64, span: Span) -> bool {
        self.work = self.work.saturating_add(n);
        if self.work > MAX_WORK && !self.aborted {
            self.aborted = true;
            self.diags.push(
                Diag::new(
                    codes::TOO_LARGE,
                    span,
                    format!("the scene needs more than {MAX_WORK} loop iterations and calls"),
                )
                .label("evaluation stopped here")
                .help("reduce the loop counts (lists passed to calls count one per item); sdfl scenes are meant to stay below a million primitives"),
            );
        }
        !self.aborted
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
        if self.depth >= MAX_EVAL_DEPTH {
            self.aborted = true;
            return self.error(
                Diag::new(
                    codes::TOO_LARGE,
                    e.span,
                    format!("expressions and `fn` calls nested more than {MAX_EVAL_DEPTH} levels deep"),
                )
                .label("evaluation stopped here")
                .help("each call evaluates the function's expression inside the caller's: bind parts to names with `let` instead of nesting calls"),
            );
        }
        self.depth += 1;
        let v = self.eval_expr(e);
        self.depth -= 1;
        v
    }

    /// `{ let ...; value }` in a scope of its own.
    fn body(&mut self, body: &Body) -> Value {
        self.locals.push(HashMap::new());
        for l in &body.lets {
            let v = self.expr(&l.value);
            self.locals
                .last_mut()
                .expect("pushed")
                .insert(l.name.name.clone(), v);
        }
        let v = self.expr(&body.value);
        self.locals.pop();
        v
    }

    fn eval_expr(&mut self, e: &Expr) -> Value {
        match &e.kind {
            ExprKind::Number(x) => Value::Number(*x),
            ExprKind::Bool(b) => Value::Bool(*b),
            ExprKind::Str(s) => Value::Str(s.as_str().into()),
            // The checker has resolved every name; an unknown one here means
            // the file was not checked, which is poison rather than a panic.
            ExprKind::Var(id) => self
                .lookup(&id.name)
                .or_else(|| self.fns.get(&id.name).cloned().map(Value::Function))
                .unwrap_or(Value::Poison),
            ExprKind::List(items) => {
                let items: Vec<Value> = items.iter().map(|i| self.expr(i)).collect();
                // A list holding poison is poison: the depth of what was
                // already reported must not keep growing unchecked, and
                // poison is then found without walking into lists.
                if items.iter().any(|i| matches!(i, Value::Poison)) {
                    return Value::Poison;
                }
                self.size_checked(Value::List(Arc::new(items)), e.span)
            }
            ExprKind::Call { callee, args, .. } => self.call(callee, args, e.span),
            ExprKind::Member(recv, name) => {
                let v = self.expr(recv);
                if matches!(v, Value::Poison) {
                    return Value::Poison;
                }
                let picks = sdfl_lang::check::swizzle(&name.name).unwrap_or_default();
                let comps = match crate::builtins::numbers_of(&v) {
                    Some((xs, true)) if picks.iter().all(|&k| k < xs.len()) => Some(xs),
                    _ => None,
                };
                match comps {
                    Some(xs) if picks.len() == 1 => Value::Number(xs[picks[0]]),
                    Some(xs) => Value::List(Arc::new(
                        picks.iter().map(|&k| Value::Number(xs[k])).collect(),
                    )),
                    None => self.error(
                        Diag::new(
                            codes::TYPE,
                            recv.span,
                            format!("`.{}` needs a vector with those components", name.name),
                        )
                        .label(format!("this is a {}", describe(&v)))
                        .help("components exist on vectors `[x, y, z]` (`.x` the first, `.z` the third)"),
                    ),
                }
            }
            ExprKind::Neg(inner) => {
                let v = self.expr(inner);
                self.arith(BinOp::Sub, Value::Number(0.0), v, e.span, inner.span)
            }
            ExprKind::Not(inner) => match self.expr(inner) {
                Value::Bool(b) => Value::Bool(!b),
                v => self.not_bool(v, inner.span, "`!`"),
            },
            ExprKind::If {
                cond,
                then,
                otherwise,
            } => match self.expr(cond) {
                // Only the branch taken is evaluated.
                Value::Bool(true) => self.body(then),
                Value::Bool(false) => self.body(otherwise),
                v => self.not_bool(v, cond.span, "a condition"),
            },
            ExprKind::Index(list, index) => {
                let (lv, iv) = (self.expr(list), self.expr(index));
                self.index(lv, iv, list.span, index.span)
            }
            ExprKind::Binary(op, l, r) if op.is_logical() => {
                let what = format!("`{}`", op.symbol());
                let lv = match self.expr(l) {
                    Value::Bool(b) => b,
                    v => return self.not_bool(v, l.span, &what),
                };
                // `false && x` and `true || x` do not evaluate `x`.
                if lv == (*op == BinOp::Or) {
                    return Value::Bool(lv);
                }
                match self.expr(r) {
                    Value::Bool(b) => Value::Bool(b),
                    v => self.not_bool(v, r.span, &what),
                }
            }
            ExprKind::Binary(op, l, r) if !op.is_arithmetic() => {
                let (lv, rv) = (self.expr(l), self.expr(r));
                self.compare(*op, lv, rv, e.span)
            }
            ExprKind::Binary(op, l, r) => {
                let (lv, rv) = (self.expr(l), self.expr(r));
                self.arith(*op, lv, rv, e.span, r.span)
            }
            ExprKind::For { bindings, body } => {
                let mut out = Vec::new();
                self.locals.push(HashMap::new());
                let mut acc = Size::node([], false);
                self.comprehension(bindings, body, e.span, &mut out, &mut acc);
                self.locals.pop();
                if out.iter().any(|i| matches!(i, Value::Poison)) {
                    return Value::Poison;
                }
                self.size_checked(Value::List(Arc::new(out)), e.span)
            }
        }
    }

    /// Unrolls a loop into `out`; false once it must stop. `acc` is the
    /// expanded size of `out` so far: a loop is stopped as soon as its
    /// list grows past the limits, before it holds terabytes.
    fn comprehension(
        &mut self,
        bindings: &[Binding],
        body: &Body,
        span: Span,
        out: &mut Vec<Value>,
        acc: &mut Size,
    ) -> bool {
        let Some((first, rest)) = bindings.split_first() else {
            self.locals.push(HashMap::new());
            for l in &body.lets {
                let v = self.expr(&l.value);
                self.locals
                    .last_mut()
                    .expect("pushed")
                    .insert(l.name.name.clone(), v);
            }
            let v = self.expr(&body.value);
            self.locals.pop();
            let size = self.sizes.of(&v);
            *acc = Size::node([*acc, size], false);
            if let Some(mut d) = size_error(*acc, span) {
                // Stopped early: the whole loop would be larger still.
                let what = if acc.primitives > MAX_PRIMITIVES {
                    format!("{} primitives", fmt_count(MAX_PRIMITIVES))
                } else {
                    format!("{} items", fmt_count(MAX_NODES))
                };
                d.message = format!("this loop would make more than {what} once expanded");
                d.label = format!(
                    "{} primitives and {} items after {} iterations, about {} of memory",
                    fmt_count(acc.primitives),
                    fmt_count(acc.nodes),
                    out.len() + 1,
                    fmt_bytes(
                        acc.primitives as f64 * BYTES_PER_PRIMITIVE as f64
                            + acc.nodes as f64 * 32.0
                    )
                );
                out.push(self.error(d));
                return false;
            }
            out.push(v);
            return true;
        };
        let items: Vec<Value> = match &first.source {
            Source::Range {
                start,
                end,
                inclusive,
            } => {
                let (s, t) = (self.expr(start), self.expr(end));
                let (s, t) = match (s, t) {
                    (Value::Number(s), Value::Number(t)) => (s, t),
                    (s, t) => {
                        // A value the checker let through (a `param`, typed
                        // "any") is an error here; poison was reported already.
                        for (v, e) in [(&s, start), (&t, end)] {
                            if !v.is_poison() && !matches!(v, Value::Number(_)) {
                                let d = Diag::new(
                                    codes::TYPE,
                                    e.span,
                                    format!("a range bound must be a number, not a {}", v.type_name()),
                                )
                                .label("not a number")
                                .help("ranges count with plain numbers; a `param` is trained, not looped over");
                                self.error(d);
                            }
                        }
                        out.push(Value::Poison);
                        return false;
                    }
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
                            format!(
                                "range has {} values (at most {MAX_LOOP})",
                                fmt_count(count.min(u64::MAX as f64) as u64)
                            ),
                        )
                        .label("too many iterations")
                        .help("sdfl scenes are meant to stay below a million primitives"),
                    );
                    out.push(Value::Poison);
                    return false;
                }
                (0..count as u64)
                    .map(|k| Value::Number(s + k as f64))
                    .collect()
            }
            Source::List(list) => match self.expr(list) {
                Value::List(items) => items.as_ref().clone(),
                Value::Poison => {
                    out.push(Value::Poison);
                    return false;
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
                    return false;
                }
            },
        };
        for item in items {
            if !self.spend(span) {
                return false;
            }
            self.locals
                .last_mut()
                .expect("pushed by caller")
                .insert(first.var.name.clone(), item);
            if !self.comprehension(rest, body, span, out, acc) {
                return false;
            }
        }
        true
    }

    /// Poison for a value that should have been a bool (with a diagnostic
    /// unless it is poison already).
    fn not_bool(&mut self, v: Value, span: Span, what: &str) -> Value {
        // Shallow, like every poison test here: a list holding poison is
        // poison itself, and walking lists would cost their length.
        if matches!(v, Value::Poison) {
            return Value::Poison;
        }
        self.error(
            Diag::new(
                codes::TYPE,
                span,
                format!("{what} needs a bool, not a {}", v.type_name()),
            )
            .label(format!("this is a {}", describe(&v)))
            .help("compare values to get a bool: `x < 1`, `n == 0`, `a && b`"),
        )
    }

    fn index(&mut self, list: Value, index: Value, list_span: Span, span: Span) -> Value {
        if matches!(list, Value::Poison) || matches!(index, Value::Poison) {
            return Value::Poison;
        }
        let Value::List(items) = &list else {
            let d = Diag::new(
                codes::TYPE,
                list_span,
                format!("cannot index a {}", list.type_name()),
            )
            .label(format!("this is a {}", describe(&list)))
            .help("only lists and vectors have items `[i]`");
            return self.error(d);
        };
        let Value::Number(i) = index else {
            let d = Diag::new(
                codes::TYPE,
                span,
                format!("an index must be a number, not a {}", index.type_name()),
            )
            .label(format!("this is a {}", describe(&index)))
            .help("index lists with whole numbers from 0: `xs[0]`");
            return self.error(d);
        };
        let n = items.len();
        let last = match n {
            0 => "the list is empty".to_string(),
            n => format!("indices of this list are 0 to {}", n - 1),
        };
        let problem = if i.fract() != 0.0 {
            Some(("not a whole number", "round it: `floor(x)`".to_string()))
        } else if i < 0.0 {
            Some((
                "negative",
                format!("{last}; indices count from 0 at the start"),
            ))
        } else if i >= n as f64 {
            Some((
                "past the end",
                format!("{last}; `len(xs)` is the item count"),
            ))
        } else {
            None
        };
        match problem {
            Some((what, help)) => self.error(
                Diag::new(
                    codes::INDEX,
                    span,
                    format!("index {} is {what}", fmt_num(i)),
                )
                .label(match n {
                    1 => "the list has 1 item".to_string(),
                    n => format!("the list has {n} items"),
                })
                .help(help),
            ),
            None => items[i as usize].clone(),
        }
    }

    /// `< <= > >=` on numbers, `== !=` on numbers, bools, strings and lists
    /// of numbers.
    fn compare(&mut self, op: BinOp, l: Value, r: Value, span: Span) -> Value {
        use std::cmp::Ordering;
        if matches!(l, Value::Poison) || matches!(r, Value::Poison) {
            return Value::Poison;
        }
        // Comparing lists walks them, as arithmetic does: one unit per item.
        let walked = [&l, &r]
            .iter()
            .map(|v| match v {
                Value::List(items) => items.len() as u64,
                _ => 0,
            })
            .max()
            .unwrap_or(0);
        if !self.spend_n(walked, span) {
            return Value::Poison;
        }
        let nums = |v: &Value| -> Option<Vec<f64>> {
            match v {
                Value::List(_) => crate::builtins::one_or_list(v, |v| match v {
                    Value::Number(x) => Some(*x),
                    _ => None,
                }),
                _ => None,
            }
        };
        let result = match (&l, &r) {
            (Value::Number(a), Value::Number(b)) => a.partial_cmp(b),
            _ if op.is_ordering() => None,
            (Value::Bool(a), Value::Bool(b)) => Some(a.cmp(b)),
            (Value::Str(a), Value::Str(b)) => Some(a.cmp(b)),
            _ => match (nums(&l), nums(&r)) {
                (Some(a), Some(b)) => Some(if a == b {
                    Ordering::Equal
                } else {
                    Ordering::Less
                }),
                _ => None,
            },
        };
        let Some(ord) = result else {
            let help = if op.is_ordering() {
                "`<`, `<=`, `>` and `>=` compare numbers"
            } else {
                "`==` and `!=` compare numbers, vectors, bools and strings of the same kind"
            };
            return self.error(
                Diag::new(
                    codes::TYPE,
                    span,
                    format!(
                        "`{}` cannot compare a {} with a {}",
                        op.symbol(),
                        l.type_name(),
                        r.type_name()
                    ),
                )
                .label(format!("{} {} {}", describe(&l), op.symbol(), describe(&r)))
                .help(help),
            );
        };
        Value::Bool(match op {
            BinOp::Lt => ord == Ordering::Less,
            BinOp::Le => ord != Ordering::Greater,
            BinOp::Gt => ord == Ordering::Greater,
            BinOp::Ge => ord != Ordering::Less,
            BinOp::Eq => ord == Ordering::Equal,
            _ => ord != Ordering::Equal,
        })
    }

    /// A call of a `fn`: arguments bound as the checker bound them,
    /// defaults evaluated at the call, and the body evaluated with only its
    /// parameters and the top-level names in scope.
    fn call_fn(&mut self, f: Arc<FnDef>, args: &[Arg], site: Span) -> Value {
        let mut scope: HashMap<String, Value> = HashMap::new();
        let mut poisoned = false;
        for (i, a) in args.iter().enumerate() {
            let v = self.expr(&a.value);
            poisoned |= matches!(v, Value::Poison);
            let slot = match &a.name {
                Some(n) => f.params.iter().find(|p| p.name.name == n.name),
                None => f.params.get(i),
            };
            if let Some(p) = slot {
                scope.insert(p.name.name.clone(), v);
            }
        }
        // With poison passed in, the body is not evaluated: its errors
        // would repeat what was reported, and a chain of calls stops here.
        if poisoned {
            return Value::Poison;
        }
        // Binding walks the parameters: their count is work, like the items
        // of a list passed to a built-in.
        if !self.spend_n(f.params.len() as u64, f.name.span) {
            return Value::Poison;
        }
        let caller = std::mem::take(&mut self.locals);
        self.calls.push((f.clone(), site));
        for p in &f.params {
            if let (false, Some(d)) = (scope.contains_key(&p.name.name), &p.default) {
                let v = self.expr(d);
                scope.insert(p.name.name.clone(), v);
            }
        }
        self.locals.push(scope);
        let v = self.body(&f.body);
        self.calls.pop();
        self.locals = caller;
        v
    }

    fn arith(&mut self, op: BinOp, l: Value, r: Value, span: Span, rhs_span: Span) -> Value {
        let apply = |a: f64, b: f64| match op {
            BinOp::Add => a + b,
            BinOp::Sub => a - b,
            BinOp::Mul => a * b,
            BinOp::Div => a / b,
            BinOp::Rem => a.rem_euclid(b),
            BinOp::Pow => a.powf(b),
            // Comparisons and logic are evaluated before arithmetic.
            _ => f64::NAN,
        };
        let nums = |v: &Value| -> Option<Vec<f64>> {
            crate::builtins::one_or_list(v, |v| match v {
                Value::Number(x) => Some(*x),
                _ => None,
            })
        };
        if matches!(l, Value::Poison) || matches!(r, Value::Poison) {
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
        if !self.spend_n(a.len().max(b.len()) as u64 - 1, span) {
            return Value::Poison;
        }
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
                Diag::new(
                    codes::ARITHMETIC,
                    span,
                    format!("arithmetic gives {}", fmt_num(*bad)),
                )
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
        if let Some(f) = self.fns.get(&callee.name) {
            return self.call_fn(f.clone(), args, span);
        }
        let Some(builtin) = self.env.builtin(&callee.name) else {
            return Value::Poison;
        };
        let sig = &builtin.sig;
        let mut bound = Args::new(span);
        bound.owner = sig.name;
        bound.base = self.base.clone();
        let mut poisoned = false;
        // Named arguments the built-in passes on (`sdf(f, major: 1)`).
        let mut extra = Vec::new();
        for (i, a) in args.iter().enumerate() {
            let v = self.expr(&a.value);
            poisoned |= matches!(v, Value::Poison);
            let slot = match &a.name {
                Some(n) => sig.params.iter().find(|p| p.name == n.name).map(|p| p.name),
                None => sig.positional(i).map(|p| p.name),
            };
            match (slot, &a.name) {
                (Some(name), _) => {
                    bound.named.insert(name, (v, a.value.span));
                }
                (None, Some(n)) if sig.named_rest.is_some() => {
                    extra.push((n.clone(), v, a.value.span));
                }
                (None, _) => bound.rest.push((v, a.value.span)),
            }
        }
        if poisoned {
            return Value::Poison;
        }
        let walked: u64 = bound
            .named
            .values()
            .chain(&bound.rest)
            .map(|(v, _)| self.sizes.of(v).items)
            .fold(0, u64::saturating_add);
        if !self.spend_n(walked, span) {
            return Value::Poison;
        }
        for p in &sig.params {
            if let (false, Some(src)) = (bound.named.contains_key(p.name), p.default) {
                let v = self.default_value(sig.name, p.name, src);
                bound.named.insert(p.name, (v, span));
                bound.defaulted.push(p.name);
            }
        }
        for w in crate::builtins::unit_warnings(sig.name, &bound) {
            self.report(w);
        }
        if sig.name == crate::shape::user::BUILTIN {
            return self.user_shape(&bound, extra, span);
        }
        match (builtin.eval)(&bound) {
            Ok(Value::Param(mut decl)) => {
                Arc::make_mut(&mut decl).id = self.params;
                self.params += 1;
                Value::Param(decl)
            }
            Ok(v) => self.size_checked(v, span),
            Err(d) => self.every_error(builtin, bound, d, span),
        }
    }

    /// A built-in's errors all together, not only its first: the argument
    /// an error points into, where it was written and has a default, is
    /// set to its default and the call evaluated again, until an error
    /// points elsewhere or none is left (at most once an argument).
    fn every_error(
        &mut self,
        builtin: &crate::builtins::Builtin,
        mut bound: Args,
        first: Diag,
        span: Span,
    ) -> Value {
        let sig = &builtin.sig;
        let mut replaced: Vec<&'static str> = Vec::new();
        let mut next = Some(first);
        while let Some(d) = next.take() {
            let within = |s: &Span| s.start <= d.span.start && d.span.end <= s.end;
            let written = |p: &&sdfl_lang::types::Param| {
                !bound.defaulted.contains(&p.name)
                    && bound.named.get(p.name).is_some_and(|(_, s)| within(s))
            };
            // A later error stands only where it points into an argument
            // as written and names no argument set to its default here:
            // else it may be the default's own conflict with the rest
            // (`hashgrid(min_res: 0, max_res: 8)` is not "max below min").
            let genuine = replaced.is_empty()
                || (sig.params.iter().any(|p| written(&p))
                    && !replaced
                        .iter()
                        .any(|r| d.message.contains(&format!("`{r}`"))));
            if !genuine {
                break;
            }
            let culprit = sig
                .params
                .iter()
                .find(|p| p.default.is_some() && written(p));
            self.report(d);
            let Some(p) = culprit else { break };
            let default = p.default.unwrap_or_default();
            let v = self.default_value(sig.name, p.name, default);
            bound.named.insert(p.name, (v, span));
            bound.defaulted.push(p.name);
            replaced.push(p.name);
            next = (builtin.eval)(&bound).err();
        }
        Value::Poison
    }

    /// The value, or poison with a diagnostic when it nests too deep or
    /// expands to more than the scene limits (measured as a DAG).
    fn size_checked(&mut self, v: Value, span: Span) -> Value {
        let size = self.sizes.of(&v);
        if size.depth > MAX_DEPTH {
            return self.error(
                Diag::new(
                    codes::TOO_LARGE,
                    span,
                    format!("value nested more than {MAX_DEPTH} levels deep"),
                )
                .label("too deep")
                .help("build long sequences with `for` and `union` instead of chaining `let`s"),
            );
        }
        match size_error(size, span) {
            Some(d) => self.error(d),
            None => v,
        }
    }
}

/// The top-level `let`s of a file (parsed, checked and evaluated; its
/// statements are not run), for tests that read values.
#[doc(hidden)]
pub fn globals_of(src: &str) -> Result<HashMap<String, Value>, Diagnostics> {
    let file = sdfl_lang::parse::parse(src)?;
    let env = StdEnv::get();
    let checked = sdfl_lang::check::check(&file, env);
    if checked.has_errors() {
        return Err(checked);
    }
    let mut ev = Evaluator::new(env);
    for item in &file.items {
        match item {
            Item::Let(l) => {
                let v = ev.expr(&l.value);
                ev.globals.insert(l.name.name.clone(), v);
            }
            Item::Fn(f) => {
                ev.fns.insert(f.name.name.clone(), Arc::new(f.clone()));
            }
            Item::Block(_) | Item::Import(_) => {}
        }
    }
    if ev.diags.has_errors() {
        Err(ev.diags.sorted())
    } else {
        Ok(ev.globals)
    }
}

fn item_span(item: &Item) -> Span {
    match item {
        Item::Let(l) => l.span,
        Item::Block(b) => b.span,
        Item::Fn(f) => f.span,
        Item::Import(i) => i.span,
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
