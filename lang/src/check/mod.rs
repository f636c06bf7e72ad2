//! Name resolution and type checking of a parsed file against the built-ins
//! of an [`Env`] and the file's own `fn`s. Every problem found is reported;
//! an unknown name gets type [`Type::Any`] afterwards so one mistake does
//! not cascade into many.
//!
//! Items are checked in file order: a `let` or `fn` sees only the names
//! above it, so `fn`s cannot call each other in a cycle. A `fn`'s
//! parameters are untyped (`Any`): its body is checked once, where it is
//! defined, and values passed to it are checked when it is evaluated.
//! `import`s are expected to be resolved (spliced in) before checking.

use std::collections::{HashMap, HashSet};
use std::rc::Rc;
use std::sync::{Mutex, OnceLock};

use crate::ast::*;
use crate::diag::{codes, suggest, Diag, Diagnostics};
use crate::span::Span;
use crate::types::{Env, Param, Signature, Type};

/// Deepest nesting of lists (as `[[[1]]]`) a file may build. Brackets
/// alone cannot nest deeper than the parser's limit, but chains of `let`s
/// can (`let a1 = [a0]`, `let a2 = [a1]`, ...): 100k of them built a value
/// whose tree walkers and `Drop` overflowed the stack, and whose type took
/// quadratic time to check.
pub const MAX_LIST_NESTING: usize = 64;

/// Most parameters of one `fn`: checking and evaluating a call walks
/// them, so a call costs at most this much whatever the file.
pub const MAX_FN_PARAMS: usize = 256;

/// After this many diagnostics, unknown names get no "did you mean"
/// suggestion: each one compares the name against every visible name, which
/// is quadratic over a file of thousands of mistakes.
const MAX_SUGGESTIONS: usize = 100;

/// How many lists deep a type is (`list of list of number`: 2).
fn list_depth(t: &Type) -> usize {
    match t {
        Type::List(e) => 1 + list_depth(e),
        Type::OneOf(options) => options.iter().map(list_depth).max().unwrap_or(0),
        _ => 0,
    }
}

/// The type of a `fn` named as a value (`sdf(torus_d)`).
pub const FUNCTION: Type = Type::Named("function");

/// The components a member names (`.x` → `[0]`, `.xz` → `[0, 2]`): one to
/// four of `x`, `y`, `z`; `None` for any other name.
pub fn swizzle(name: &str) -> Option<Vec<usize>> {
    if name.is_empty() || name.len() > 4 {
        return None;
    }
    name.chars()
        .map(|c| match c {
            'x' => Some(0),
            'y' => Some(1),
            'z' => Some(2),
            _ => None,
        })
        .collect()
}

/// Check a file. Returns the diagnostics (empty when the file is fine).
pub fn check(file: &File, env: &dyn Env) -> Diagnostics {
    // Sized up front: a file of a million `let`s must not hold the table
    // twice while it grows.
    let lets = file
        .items
        .iter()
        .filter(|i| matches!(i, Item::Let(_)))
        .count();
    let mut c = Checker {
        env,
        globals: HashMap::with_capacity(lets),
        locals: Vec::new(),
        diags: Diagnostics::default(),
        deep_list_reported: false,
        fns: HashMap::new(),
        all_fns: HashMap::new(),
        current_fn: None,
    };
    for item in &file.items {
        // One named like a built-in is an error; calls mean the built-in.
        if let Item::Fn(f) = item {
            if env.function(&f.name.name).is_some() {
                continue;
            }
            c.all_fns.entry(f.name.name.clone()).or_insert(f.name.span);
        }
    }
    let mut blocks: HashMap<(String, String), Span> = HashMap::new();
    for item in &file.items {
        match item {
            // Resolved (spliced into the file) before checking; one left
            // here was reported by the resolver.
            Item::Import(_) => {}
            Item::Fn(f) => c.fn_def(f),
            Item::Let(l) => {
                let ty = c.expr(&l.value);
                if let Some((_, first)) = c.globals.get(l.name.name.as_str()) {
                    let first = *first;
                    c.diags.push(
                        Diag::new(
                            codes::DUPLICATE_NAME,
                            l.name.span,
                            format!("`{}` is defined twice", l.name.name),
                        )
                        .label("defined again here")
                        .note(first, "first defined here")
                        .help("a scene file states each name once; pick another name"),
                    );
                } else {
                    c.globals.insert(&l.name.name, (ty, l.name.span));
                }
            }
            Item::Block(b) => {
                c.block(b);
                if let Some(name) = &b.name {
                    let key = (b.kind.name.clone(), name.name.clone());
                    if let Some(first) = blocks.get(&key) {
                        c.diags.push(
                            Diag::new(
                                codes::DUPLICATE_NAME,
                                name.span,
                                format!("two `{}` blocks are named `{}`", b.kind.name, name.name),
                            )
                            .label("named again here")
                            .note(*first, "first named here")
                            .help("block names must be unique: they name the outputs"),
                        );
                    } else {
                        blocks.insert(key, name.span);
                    }
                }
            }
        }
    }
    c.diags.sorted()
}

struct Checker<'e, 'f> {
    env: &'e dyn Env,
    /// Keyed by the names in the file's tree: no copy of each.
    globals: HashMap<&'f str, (Type, Span)>,
    locals: Vec<HashMap<String, Type>>,
    diags: Diagnostics,
    /// Whether lists nested too deep were reported (once is enough: the
    /// file is not evaluated after a check error).
    deep_list_reported: bool,
    /// The `fn`s defined so far, as signatures (untyped parameters) with
    /// the type of their body, and where they are named.
    fns: HashMap<String, (Rc<Signature>, Span)>,
    /// Every `fn` of the file, to tell a call of a later one from an
    /// unknown name.
    all_fns: HashMap<String, Span>,
    /// The `fn` whose body is being checked.
    current_fn: Option<String>,
}

/// A name with a `'static` lifetime, as [`Signature`]s hold: each distinct
/// name is leaked once (a few bytes per name a file defines).
fn intern(name: &str) -> &'static str {
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

impl<'f> Checker<'_, 'f> {
    /// The type of an item of `t` (a list, or a vector of numbers); for
    /// anything else a type error at `span`: "{what} a number", with `help`.
    fn item_type(&mut self, t: Type, span: Span, what: &str, help: &str) -> Type {
        match t {
            Type::List(e) => *e,
            Type::Vec3 => Type::Number,
            Type::Any => Type::Any,
            t => {
                self.diags.push(
                    Diag::new(codes::TYPE, span, format!("{what} {}", t.with_article()))
                        .label(format!("this is {}", t.with_article()))
                        .help(help),
                );
                Type::Any
            }
        }
    }

    /// A `fn` definition: its name, parameters and body, checked where it
    /// stands (it sees the `let`s and `fn`s above it, not itself).
    fn fn_def(&mut self, f: &FnDef) {
        let name = &f.name;
        if self.env.function(&name.name).is_some() {
            self.diags.push(
                Diag::new(
                    codes::SHADOWS_BUILTIN,
                    name.span,
                    format!("`{}` is a built-in function", name.name),
                )
                .label("already a built-in")
                .help("a `fn` may not replace a built-in: give it another name"),
            );
        }
        let shadows = self.env.function(&name.name).is_some();
        if let Some(p) = f.params.get(MAX_FN_PARAMS) {
            self.diags.push(
                Diag::new(
                    codes::TOO_LARGE,
                    p.name.span,
                    format!("`{}` has more than {MAX_FN_PARAMS} parameters", name.name),
                )
                .label("one too many")
                .help("pass related values together as a list or vector"),
            );
        }
        let mut seen: HashMap<&str, Span> = HashMap::new();
        let mut scope = HashMap::new();
        let mut params = Vec::new();
        for p in &f.params {
            if let Some(first) = seen.insert(&p.name.name, p.name.span) {
                self.diags.push(
                    Diag::new(
                        codes::DUPLICATE_NAME,
                        p.name.span,
                        format!("parameter `{}` is named twice", p.name.name),
                    )
                    .label("named again here")
                    .note(first, "first named here")
                    .help("each parameter of a `fn` needs its own name"),
                );
                continue;
            }
            // Defaults are evaluated at the call, seeing only top-level names.
            if let Some(d) = &p.default {
                let saved = std::mem::take(&mut self.locals);
                self.expr(d);
                self.locals = saved;
            }
            // Untyped: a call may pass anything, checked when evaluated.
            scope.insert(p.name.name.clone(), Type::Any);
            params.push(Param {
                name: intern(&p.name.name),
                ty: Type::Any,
                default: p.default.as_ref().map(|_| "…"),
                doc: "a parameter of this `fn`",
            });
        }
        let saved = std::mem::replace(&mut self.locals, vec![scope]);
        let outer = self.current_fn.replace(name.name.clone());
        for l in &f.body.lets {
            let t = self.expr(&l.value);
            self.locals
                .last_mut()
                .expect("scope pushed above")
                .insert(l.name.name.clone(), t);
        }
        let returns = self.expr(&f.body.value);
        self.current_fn = outer;
        self.locals = saved;
        if shadows {
            return;
        }
        if let Some((_, first)) = self.fns.get(&name.name) {
            let first = *first;
            self.diags.push(
                Diag::new(
                    codes::DUPLICATE_NAME,
                    name.span,
                    format!("`fn {}` is defined twice", name.name),
                )
                .label("defined again here")
                .note(first, "first defined here")
                .help("a scene file defines each function once; pick another name"),
            );
            return;
        }
        let sig = Signature {
            name: intern(&name.name),
            params,
            rest: None,
            named_rest: None,
            returns,
            doc: "",
        };
        self.fns
            .insert(name.name.clone(), (Rc::new(sig), name.span));
    }

    fn lookup(&self, name: &str) -> Option<Type> {
        for scope in self.locals.iter().rev() {
            if let Some(t) = scope.get(name) {
                return Some(t.clone());
            }
        }
        if let Some((t, _)) = self.globals.get(name) {
            return Some(t.clone());
        }
        self.env.constant(name)
    }

    fn visible_names(&self) -> Vec<&str> {
        let mut names: Vec<&str> = self
            .locals
            .iter()
            .flat_map(|s| s.keys().map(String::as_str))
            .collect();
        names.extend(self.globals.keys().copied());
        names.extend(self.env.constant_names());
        names
    }

    fn block(&mut self, b: &Block) {
        let Some(sig) = self.env.block(&b.kind.name) else {
            let mut d = Diag::new(
                codes::UNKNOWN_BLOCK,
                b.kind.span,
                format!("unknown statement `{}`", b.kind.name),
            )
            .label("not a statement");
            let names = self.env.block_names();
            d = match suggest(&b.kind.name, names.iter().copied()) {
                Some(s) => d.help(format!("did you mean `{s}`?")),
                None => d.help(format!("statements are: {}", names.join(", "))),
            };
            self.diags.push(d);
            for f in &b.fields {
                self.expr(&f.value);
            }
            return;
        };
        let mut seen: HashMap<&str, Span> = HashMap::new();
        for f in &b.fields {
            let ty = self.expr(&f.value);
            let Some(param) = sig.fields.iter().find(|p| p.name == f.name.name) else {
                let names: Vec<&str> = sig.fields.iter().map(|p| p.name).collect();
                let help = match suggest(&f.name.name, names.iter().copied()) {
                    Some(s) => format!("did you mean `{s}`?"),
                    None => format!("`{}` has the fields: {}", sig.kind, names.join(", ")),
                };
                self.diags.push(
                    Diag::new(
                        codes::UNKNOWN_FIELD,
                        f.name.span,
                        format!("`{}` has no field `{}`", sig.kind, f.name.name),
                    )
                    .label("unknown field")
                    .help(help),
                );
                continue;
            };
            if let Some(first) = seen.insert(param.name, f.name.span) {
                self.diags.push(
                    Diag::new(
                        codes::DUPLICATE_FIELD,
                        f.name.span,
                        format!("field `{}` is given twice", f.name.name),
                    )
                    .label("given again here")
                    .note(first, "first given here")
                    .help("remove one of them"),
                );
            }
            self.expect_type(param, &ty, f.value.span);
        }
        for p in &sig.fields {
            if p.default.is_none() && !seen.contains_key(p.name) {
                self.diags.push(
                    Diag::new(
                        codes::MISSING_FIELD,
                        b.kind.span,
                        format!("`{}` needs the field `{}`", sig.kind, p.name),
                    )
                    .label(format!("`{}` is missing", p.name))
                    .help(format!(
                        "add `{}: ...` to `{}`: {}",
                        p.name, sig.kind, p.doc
                    )),
                );
            }
        }
    }

    fn expect_type(&mut self, param: &Param, actual: &Type, span: Span) {
        if !param.ty.accepts(actual) {
            // A single item where a list of such items is wanted.
            let options = match &param.ty {
                Type::OneOf(options) => options.as_slice(),
                t => std::slice::from_ref(t),
            };
            let wants_list_of_it = options
                .iter()
                .any(|o| matches!(o, Type::List(e) if e.accepts(actual)));
            let help = if wants_list_of_it {
                format!(
                    "put it in a list: `[...]` (`{}`: {})",
                    param.name, param.doc
                )
            } else {
                format!("`{}`: {}", param.name, param.doc)
            };
            self.diags.push(
                Diag::new(
                    codes::TYPE,
                    span,
                    format!(
                        "`{}` must be {}, not {}",
                        param.name,
                        param.ty.with_article(),
                        actual.with_article()
                    ),
                )
                .label(format!("this is {}", actual.with_article()))
                .help(help),
            );
        }
    }

    /// `t`, or [`Type::Any`] (after a diagnostic) when it is a list nested
    /// deeper than [`MAX_LIST_NESTING`].
    fn nesting_checked(&mut self, t: Type, span: Span) -> Type {
        if list_depth(&t) <= MAX_LIST_NESTING {
            return t;
        }
        if !self.deep_list_reported {
            self.deep_list_reported = true;
            self.diags.push(
                Diag::new(
                    codes::TOO_LARGE,
                    span,
                    format!("lists nested more than {MAX_LIST_NESTING} deep"),
                )
                .label("too deep")
                .help("a list of a list of ... this deep comes from a chain of `let`s; build flat lists with `for`"),
            );
        }
        Type::Any
    }

    fn expr(&mut self, e: &Expr) -> Type {
        match &e.kind {
            ExprKind::Number(_) => Type::Number,
            ExprKind::Bool(_) => Type::Bool,
            ExprKind::Str(_) => Type::Str,
            ExprKind::Var(id) => self.var(id),
            ExprKind::List(items) => {
                let types: Vec<Type> = items.iter().map(|i| self.expr(i)).collect();
                if types.len() == 3 && types.iter().all(|t| matches!(t, Type::Number)) {
                    return Type::Vec3;
                }
                let first = types.iter().find(|t| !matches!(t, Type::Any)).cloned();
                let t = match first {
                    None => Type::list(Type::Any),
                    Some(t) if types.iter().all(|u| t.accepts(u) && u.accepts(&t)) => Type::list(t),
                    // Mixed items: typed `list of any value`, so nesting
                    // through them is not counted here.
                    Some(_) => Type::list(Type::Any),
                };
                self.nesting_checked(t, e.span)
            }
            ExprKind::Call { callee, args, .. } => self.call(callee, args, e.span),
            ExprKind::Member(recv, name) => {
                let t = self.expr(recv);
                let Some(picked) = swizzle(&name.name) else {
                    self.diags.push(
                        Diag::new(
                            codes::UNKNOWN_FIELD,
                            name.span,
                            format!("no member `{}`", name.name),
                        )
                        .label("unknown member")
                        .help("vectors have the members `.x`, `.y` and `.z`, and swizzles of them such as `.xz` or `.zyx`"),
                    );
                    return Type::Any;
                };
                if !Type::Vec3.accepts(&t) {
                    self.diags.push(
                        Diag::new(
                            codes::TYPE,
                            recv.span,
                            format!("`.{}` needs a vector, not {}", name.name, t.with_article()),
                        )
                        .label(format!("this is {}", t.with_article()))
                        .help("only vectors `[x, y, z]` have components"),
                    );
                    return Type::Any;
                }
                match picked.len() {
                    1 => Type::Number,
                    3 => Type::Vec3,
                    _ => Type::list(Type::Number),
                }
            }
            ExprKind::Neg(inner) => {
                let t = self.expr(inner);
                if !t.is_numeric() {
                    self.diags.push(
                        Diag::new(
                            codes::TYPE,
                            inner.span,
                            format!("cannot negate {}", t.with_article()),
                        )
                        .label(format!("this is {}", t.with_article()))
                        .help("`-` applies to numbers and vectors"),
                    );
                    return Type::Any;
                }
                t
            }
            ExprKind::Not(inner) => {
                let t = self.expr(inner);
                self.expect_bool(&t, inner.span, "`!`");
                Type::Bool
            }
            ExprKind::Index(list, index) => {
                let (lt, it) = (self.expr(list), self.expr(index));
                if !Type::Number.accepts(&it) {
                    self.diags.push(
                        Diag::new(
                            codes::TYPE,
                            index.span,
                            format!("an index must be a number, not {}", it.with_article()),
                        )
                        .label(format!("this is {}", it.with_article()))
                        .help("index lists with whole numbers from 0: `xs[0]`"),
                    );
                }
                self.item_type(
                    lt,
                    list.span,
                    "cannot index",
                    "only lists and vectors have items `[i]`",
                )
            }
            ExprKind::If {
                cond,
                then,
                otherwise,
            } => {
                let t = self.expr(cond);
                self.expect_bool(&t, cond.span, "a condition");
                let a = self.body(then);
                let b = self.body(otherwise);
                // Branches of different types are checked when evaluated:
                // a `OneOf` of both would double in size at every `fn`
                // returning one of its argument's types or a list of it.
                match (a, b) {
                    (Type::Any, _) | (_, Type::Any) => Type::Any,
                    (a, b) if a.accepts(&b) && b.accepts(&a) => a,
                    _ => Type::Any,
                }
            }
            ExprKind::Binary(op, l, r) if op.is_logical() => {
                let (lt, rt) = (self.expr(l), self.expr(r));
                let what = format!("`{}`", op.symbol());
                self.expect_bool(&lt, l.span, &what);
                self.expect_bool(&rt, r.span, &what);
                Type::Bool
            }
            ExprKind::Binary(op, l, r) if !op.is_arithmetic() => {
                let (lt, rt) = (self.expr(l), self.expr(r));
                let comparable = |t: &Type| {
                    if op.is_ordering() {
                        Type::Number.accepts(t)
                    } else {
                        t.is_numeric() || Type::Bool.accepts(t) || Type::Str.accepts(t)
                    }
                };
                for (t, side) in [(&lt, l), (&rt, r)] {
                    if !comparable(t) {
                        let help = if op.is_ordering() {
                            "`<`, `<=`, `>` and `>=` compare numbers"
                        } else {
                            "`==` and `!=` compare numbers, vectors, bools and strings"
                        };
                        self.diags.push(
                            Diag::new(
                                codes::TYPE,
                                side.span,
                                format!("`{}` cannot compare {}", op.symbol(), t.with_article()),
                            )
                            .label(format!("this is {}", t.with_article()))
                            .help(help),
                        );
                        return Type::Bool;
                    }
                }
                Type::Bool
            }
            ExprKind::Binary(op, l, r) => {
                let (lt, rt) = (self.expr(l), self.expr(r));
                for (t, side) in [(&lt, l), (&rt, r)] {
                    if !t.is_numeric() {
                        self.diags.push(
                            Diag::new(
                                codes::TYPE,
                                side.span,
                                format!(
                                    "`{}` needs numbers or vectors, not {}",
                                    op.symbol(),
                                    t.with_article()
                                ),
                            )
                            .label(format!("this is {}", t.with_article()))
                            .help("arithmetic applies to numbers and vectors; shapes are combined with `union`, `intersection`, `subtraction`"),
                        );
                        return Type::Any;
                    }
                }
                match (lt, rt) {
                    (Type::Number, Type::Number) => Type::Number,
                    (Type::Any, _) | (_, Type::Any) => Type::Any,
                    _ => Type::Vec3,
                }
            }
            ExprKind::For { bindings, body } => {
                self.locals.push(HashMap::new());
                for b in bindings {
                    let elem = match &b.source {
                        Source::Range { start, end, .. } => {
                            for bound in [start, end] {
                                let t = self.expr(bound);
                                if !Type::Number.accepts(&t) {
                                    self.diags.push(
                                        Diag::new(
                                            codes::TYPE,
                                            bound.span,
                                            format!(
                                                "range bounds must be numbers, not {}",
                                                t.with_article()
                                            ),
                                        )
                                        .label(format!("this is {}", t.with_article()))
                                        .help("write ranges as `0..n` with whole numbers"),
                                    );
                                }
                            }
                            Type::Number
                        }
                        Source::List(list) => {
                            let t = self.expr(list);
                            self.item_type(
                                t,
                                list.span,
                                "cannot loop over",
                                "loop over a range `0..n` or a list `[...]`",
                            )
                        }
                    };
                    self.locals
                        .last_mut()
                        .expect("scope pushed above")
                        .insert(b.var.name.clone(), elem);
                }
                for l in &body.lets {
                    let t = self.expr(&l.value);
                    self.locals
                        .last_mut()
                        .expect("scope pushed above")
                        .insert(l.name.name.clone(), t);
                }
                let t = self.expr(&body.value);
                self.locals.pop();
                self.nesting_checked(Type::list(t), e.span)
            }
        }
    }

    /// A `{ let ...; value }` body's type, its lets in a scope of their own.
    fn body(&mut self, body: &Body) -> Type {
        self.locals.push(HashMap::new());
        for l in &body.lets {
            let t = self.expr(&l.value);
            self.locals
                .last_mut()
                .expect("scope pushed above")
                .insert(l.name.name.clone(), t);
        }
        let t = self.expr(&body.value);
        self.locals.pop();
        t
    }

    fn expect_bool(&mut self, t: &Type, span: Span, what: &str) {
        if !Type::Bool.accepts(t) {
            self.diags.push(
                Diag::new(
                    codes::TYPE,
                    span,
                    format!("{what} needs a bool, not {}", t.with_article()),
                )
                .label(format!("this is {}", t.with_article()))
                .help("compare values to get a bool: `x < 1`, `n == 0`, `a && b`"),
            );
        }
    }

    fn var(&mut self, id: &Ident) -> Type {
        if let Some(t) = self.lookup(&id.name) {
            return t;
        }
        // A `fn` defined above, as a value (`sdf(torus_d)`).
        if self.fns.contains_key(&id.name) && self.env.function(&id.name).is_none() {
            return FUNCTION;
        }
        let mut d = Diag::new(
            codes::UNKNOWN_NAME,
            id.span,
            format!("unknown name `{}`", id.name),
        )
        .label("not defined");
        if self.env.function(&id.name).is_some() {
            d = d.help(format!(
                "`{0}` is a built-in function: call it as `{0}(...)`",
                id.name
            ));
        } else if self.fns.contains_key(&id.name) {
            d = d.help(format!("`{0}` is a `fn`: call it as `{0}(...)`", id.name));
        } else if self.diags.len() >= MAX_SUGGESTIONS {
            d = d.help("define it first with `let name = ...`");
        } else {
            let names = self.visible_names();
            d = match suggest(&id.name, names.iter().copied()) {
                Some(s) => d.help(format!("did you mean `{s}`?")),
                None => d.help("define it first with `let name = ...`"),
            };
        }
        self.diags.push(d);
        Type::Any
    }

    fn call(&mut self, callee: &Ident, args: &[Arg], span: Span) -> Type {
        let arg_types: Vec<Type> = args.iter().map(|a| self.expr(&a.value)).collect();
        let user = self.fns.get(&callee.name).map(|(sig, _)| sig.clone());
        if user.is_none() {
            if let Some(at) = self.all_fns.get(&callee.name).copied() {
                let own = self.current_fn.as_deref() == Some(callee.name.as_str());
                let d = if own {
                    Diag::new(
                        codes::FN_ORDER,
                        callee.span,
                        format!("`{}` calls itself", callee.name),
                    )
                    .label("a recursive call")
                    .help("sdfl functions cannot recurse: build repetition with `for`")
                } else {
                    Diag::new(
                        codes::FN_ORDER,
                        callee.span,
                        format!("`{}` is defined below this call", callee.name),
                    )
                    .label("not defined yet")
                    .note(at, "defined here")
                    .help("define a `fn` above its first use (so functions cannot call each other in a cycle)")
                };
                self.diags.push(d);
                return Type::Any;
            }
        }
        let Some(sig) = user.or_else(|| self.env.function(&callee.name).cloned().map(Rc::new))
        else {
            let mut d = Diag::new(
                codes::UNKNOWN_FUNCTION,
                callee.span,
                format!("unknown function `{}`", callee.name),
            )
            .label("no such built-in");
            if self.lookup(&callee.name).is_some() {
                d = Diag::new(
                    codes::NOT_CALLABLE,
                    callee.span,
                    format!("`{}` is a value, not a function", callee.name),
                )
                .label("cannot be called")
                .help("only built-ins and `fn`s can be called; use the name without `(...)`");
            } else {
                let mut names = self.env.function_names();
                // A file's own `fn`s too, while suggestions stay cheap.
                if self.diags.len() < MAX_SUGGESTIONS {
                    names.extend(self.fns.values().map(|(sig, _)| sig.name));
                }
                d = match suggest(&callee.name, names.iter().copied()) {
                    Some(s) => d.help(format!("did you mean `{s}`?")),
                    None => d.help("`sdfl docs` lists the built-in functions"),
                };
            }
            self.diags.push(d);
            return Type::Any;
        };
        let mut given: HashMap<&str, Span> = HashMap::new();
        let mut seen_named = false;
        for (i, (arg, ty)) in args.iter().zip(&arg_types).enumerate() {
            let param = match &arg.name {
                None => {
                    if seen_named {
                        self.diags.push(
                            Diag::new(
                                codes::POSITIONAL_AFTER_NAMED,
                                arg.value.span,
                                "positional argument after a named one",
                            )
                            .label("positional")
                            .help("put positional arguments first, or name this one"),
                        );
                        continue;
                    }
                    match sig.positional(i) {
                        Some(p) => p,
                        None => match &sig.rest {
                            Some(rest) => {
                                let elem_ok =
                                    rest.ty.accepts(ty) || Type::list(rest.ty.clone()).accepts(ty);
                                if !elem_ok {
                                    self.expect_type(rest, ty, arg.value.span);
                                }
                                continue;
                            }
                            None => {
                                let n = sig.params.len();
                                self.diags.push(
                                    Diag::new(
                                        codes::TOO_MANY_ARGS,
                                        arg.value.span,
                                        format!(
                                            "`{}` takes {n} argument{}",
                                            sig.name,
                                            if n == 1 { "" } else { "s" }
                                        ),
                                    )
                                    .label("one too many")
                                    .help(format!("signature: {}", sig.synopsis())),
                                );
                                continue;
                            }
                        },
                    }
                }
                Some(name) => {
                    seen_named = true;
                    match sig.params.iter().find(|p| p.name == name.name) {
                        Some(p) => p,
                        // Passed on by the built-in under its own name.
                        None if sig.named_rest.is_some() => {
                            let rest = sig.named_rest.clone().expect("checked above");
                            let at = name.span;
                            if let Some(first) = given.insert(intern(&name.name), at) {
                                self.diags.push(
                                    Diag::new(
                                        codes::DUPLICATE_ARG,
                                        at,
                                        format!("`{}` is given twice", name.name),
                                    )
                                    .label("given again here")
                                    .note(first, "first given here")
                                    .help(format!("signature: {}", sig.synopsis())),
                                );
                            }
                            self.expect_type(&rest, ty, arg.value.span);
                            continue;
                        }
                        None => {
                            let names: Vec<&str> = sig.params.iter().map(|p| p.name).collect();
                            let help = match suggest(&name.name, names.iter().copied()) {
                                Some(s) => {
                                    format!("did you mean `{s}`? signature: {}", sig.synopsis())
                                }
                                None => format!("signature: {}", sig.synopsis()),
                            };
                            self.diags.push(
                                Diag::new(
                                    codes::UNKNOWN_ARG,
                                    name.span,
                                    format!("`{}` has no parameter `{}`", sig.name, name.name),
                                )
                                .label("unknown parameter")
                                .help(help),
                            );
                            continue;
                        }
                    }
                }
            };
            let at = arg.name.as_ref().map_or(arg.value.span, |n| n.span);
            if let Some(first) = given.insert(param.name, at) {
                self.diags.push(
                    Diag::new(
                        codes::DUPLICATE_ARG,
                        at,
                        format!("`{}` is given twice", param.name),
                    )
                    .label("given again here")
                    .note(first, "first given here")
                    .help(format!("signature: {}", sig.synopsis())),
                );
                continue;
            }
            let param = param.clone();
            self.expect_type(&param, ty, arg.value.span);
        }
        for p in &sig.params {
            if p.default.is_none() && !given.contains_key(p.name) {
                self.diags.push(
                    Diag::new(
                        codes::MISSING_ARG,
                        span,
                        format!("`{}` needs the argument `{}`", sig.name, p.name),
                    )
                    .label(format!("`{}` is missing", p.name))
                    .help(format!("signature: {}", sig.synopsis())),
                );
            }
        }
        sig.returns.clone()
    }
}
