//! The owned, spanned syntax tree. Nothing here refers to pest: the parser
//! converts its parse tree into these types at once.

use crate::span::Span;

/// A parsed file: its items in source order.
#[derive(Debug, Clone, PartialEq)]
pub struct File {
    /// Top-level `let`s, blocks, `fn`s and `import`s.
    pub items: Vec<Item>,
}

/// A top-level item of a file.
#[derive(Debug, Clone, PartialEq)]
pub enum Item {
    /// `let name = value`
    Let(Let),
    /// A statement such as `render name { ... }`.
    Block(Block),
    /// `fn name(params) { body }`
    Fn(FnDef),
    /// `import "path.sdfl"`
    Import(Import),
}

/// `import "path.sdfl"`
#[derive(Debug, Clone, PartialEq)]
pub struct Import {
    /// The path as written (escapes resolved).
    pub path: String,
    /// The span of the string literal.
    pub path_span: Span,
    /// The whole item.
    pub span: Span,
}

/// `fn name(params) { body }`
#[derive(Debug, Clone, PartialEq)]
pub struct FnDef {
    /// The function's name.
    pub name: Ident,
    /// Its parameters in order; callers may name or place them.
    pub params: Vec<FnParam>,
    /// Its `let`s and result, evaluated per call.
    pub body: Body,
    /// The whole definition.
    pub span: Span,
}

/// A parameter of a `fn`, with its default (`None`: required).
#[derive(Debug, Clone, PartialEq)]
pub struct FnParam {
    /// The parameter's name, bound in the body.
    pub name: Ident,
    /// The value when a call leaves it out.
    pub default: Option<Expr>,
}

/// A name as written, with its span.
#[derive(Debug, Clone, PartialEq)]
pub struct Ident {
    /// The name's text.
    pub name: String,
    /// Where it is written.
    pub span: Span,
}

/// `let name = value`
#[derive(Debug, Clone, PartialEq)]
pub struct Let {
    /// The name bound.
    pub name: Ident,
    /// The expression it stands for.
    pub value: Expr,
    /// The whole binding.
    pub span: Span,
}

/// `kind name { field: value, ... }`
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    /// The statement keyword as written (`render`, `train`, `volume`…).
    pub kind: Ident,
    /// The statement's name, used in output paths and messages.
    pub name: Option<Ident>,
    /// Its `name: value` fields in source order.
    pub fields: Vec<Field>,
    /// The whole statement.
    pub span: Span,
}

/// `name: value` inside a block.
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    /// The field's name.
    pub name: Ident,
    /// Its value.
    pub value: Expr,
}

/// An expression with the span of its text.
#[derive(Debug, Clone, PartialEq)]
pub struct Expr {
    /// What kind of expression, with its parts.
    pub kind: ExprKind,
    /// The whole expression.
    pub span: Span,
}

/// A binary operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BinOp {
    /// `+`
    Add,
    /// `-`
    Sub,
    /// `*`
    Mul,
    /// `/`
    Div,
    /// `%`: the Euclidean remainder (not negative for a positive divisor).
    Rem,
    /// `^`: a power.
    Pow,
    /// `<`
    Lt,
    /// `<=`
    Le,
    /// `>`
    Gt,
    /// `>=`
    Ge,
    /// `==`
    Eq,
    /// `!=`
    Ne,
    /// `&&`, short-circuiting.
    And,
    /// `||`, short-circuiting.
    Or,
}

impl BinOp {
    /// The operator as written, for messages.
    pub fn symbol(self) -> &'static str {
        match self {
            BinOp::Add => "+",
            BinOp::Sub => "-",
            BinOp::Mul => "*",
            BinOp::Div => "/",
            BinOp::Rem => "%",
            BinOp::Pow => "^",
            BinOp::Lt => "<",
            BinOp::Le => "<=",
            BinOp::Gt => ">",
            BinOp::Ge => ">=",
            BinOp::Eq => "==",
            BinOp::Ne => "!=",
            BinOp::And => "&&",
            BinOp::Or => "||",
        }
    }
    /// `< <= > >=`: numbers in, a bool out.
    pub fn is_ordering(self) -> bool {
        matches!(self, BinOp::Lt | BinOp::Le | BinOp::Gt | BinOp::Ge)
    }
    /// `== !=`
    pub fn is_equality(self) -> bool {
        matches!(self, BinOp::Eq | BinOp::Ne)
    }
    /// `&& ||`: bools in, a bool out.
    pub fn is_logical(self) -> bool {
        matches!(self, BinOp::And | BinOp::Or)
    }
    /// `+ - * / % ^`
    pub fn is_arithmetic(self) -> bool {
        !(self.is_ordering() || self.is_equality() || self.is_logical())
    }
}

/// The kinds of expression.
#[derive(Debug, Clone, PartialEq)]
pub enum ExprKind {
    /// A number literal; degrees are already converted to radians.
    Number(f64),
    /// `true` or `false`.
    Bool(bool),
    /// A string literal, escapes resolved.
    Str(String),
    /// A name: a `let`, a `fn` parameter, a `for` variable or a constant.
    Var(Ident),
    /// `[a, b, c]`
    List(Vec<Expr>),
    /// `callee(args)`, or `receiver.callee(args)` with `method` set and the
    /// receiver as the first positional argument.
    Call {
        /// The function called.
        callee: Ident,
        /// Its arguments as written (a method's receiver first).
        args: Vec<Arg>,
        /// Written as `receiver.callee(...)`.
        method: bool,
    },
    /// `value.name`: a vector component.
    Member(Box<Expr>, Ident),
    /// `-value`
    Neg(Box<Expr>),
    /// `!value`
    Not(Box<Expr>),
    /// `list[index]`
    Index(Box<Expr>, Box<Expr>),
    /// `if cond { then } else { otherwise }`; `else if` is an `otherwise`
    /// body holding only another `If`.
    If {
        /// The condition, a bool.
        cond: Box<Expr>,
        /// The value when it holds.
        then: Body,
        /// The value when it does not.
        otherwise: Body,
    },
    /// `left op right`
    Binary(BinOp, Box<Expr>, Box<Expr>),
    /// `for a in 0..n, b in list { body }`: a list of the body's values,
    /// one per combination of the bindings.
    For {
        /// The loop variables with what each runs over.
        bindings: Vec<Binding>,
        /// The value computed per iteration.
        body: Body,
    },
}

/// A call argument, named (`radius: 1`) or positional.
#[derive(Debug, Clone, PartialEq)]
pub struct Arg {
    /// The parameter named; `None` for a positional argument.
    pub name: Option<Ident>,
    /// The argument's value.
    pub value: Expr,
}

/// `var in source` of a `for`.
#[derive(Debug, Clone, PartialEq)]
pub struct Binding {
    /// The loop variable.
    pub var: Ident,
    /// What it runs over.
    pub source: Source,
}

/// What a `for` variable runs over.
#[derive(Debug, Clone, PartialEq)]
pub enum Source {
    /// `start..end` or `start..=end`, whole numbers.
    Range {
        /// The first value.
        start: Expr,
        /// The bound.
        end: Expr,
        /// `..=`: the bound is included.
        inclusive: bool,
    },
    /// The items of a list, in order.
    List(Expr),
}

/// `{ let a = ...; value }`
#[derive(Debug, Clone, PartialEq)]
pub struct Body {
    /// Local bindings, each seeing those before it.
    pub lets: Vec<Let>,
    /// The body's result.
    pub value: Box<Expr>,
}

// ------------------------------------------------------------ moving spans

/// Moving every span of a tree by a fixed offset: an imported file is
/// parsed on its own and its tree moved to a range of offsets no other file
/// uses, so one span still names one place in one file.
pub trait Shift {
    /// Moves every span by `by` bytes.
    fn shift(&mut self, by: usize);
}

impl Shift for Span {
    fn shift(&mut self, by: usize) {
        self.start += by;
        self.end += by;
    }
}

impl Shift for Ident {
    fn shift(&mut self, by: usize) {
        self.span.shift(by);
    }
}

impl Shift for Item {
    fn shift(&mut self, by: usize) {
        match self {
            Item::Let(l) => l.shift(by),
            Item::Block(b) => {
                b.kind.shift(by);
                if let Some(n) = &mut b.name {
                    n.shift(by);
                }
                for f in &mut b.fields {
                    f.name.shift(by);
                    f.value.shift(by);
                }
                b.span.shift(by);
            }
            Item::Fn(f) => {
                f.name.shift(by);
                for p in &mut f.params {
                    p.name.shift(by);
                    if let Some(d) = &mut p.default {
                        d.shift(by);
                    }
                }
                f.body.shift(by);
                f.span.shift(by);
            }
            Item::Import(i) => {
                i.path_span.shift(by);
                i.span.shift(by);
            }
        }
    }
}

impl Shift for Let {
    fn shift(&mut self, by: usize) {
        self.name.shift(by);
        self.value.shift(by);
        self.span.shift(by);
    }
}

impl Shift for Body {
    fn shift(&mut self, by: usize) {
        for l in &mut self.lets {
            l.shift(by);
        }
        self.value.shift(by);
    }
}

impl Shift for Expr {
    fn shift(&mut self, by: usize) {
        self.span.shift(by);
        match &mut self.kind {
            ExprKind::Number(_) | ExprKind::Bool(_) | ExprKind::Str(_) => {}
            ExprKind::Var(id) => id.shift(by),
            ExprKind::List(items) => items.iter_mut().for_each(|i| i.shift(by)),
            ExprKind::Call { callee, args, .. } => {
                callee.shift(by);
                for a in args {
                    if let Some(n) = &mut a.name {
                        n.shift(by);
                    }
                    a.value.shift(by);
                }
            }
            ExprKind::Member(e, id) => {
                e.shift(by);
                id.shift(by);
            }
            ExprKind::Neg(e) | ExprKind::Not(e) => e.shift(by),
            ExprKind::Index(a, b) | ExprKind::Binary(_, a, b) => {
                a.shift(by);
                b.shift(by);
            }
            ExprKind::If {
                cond,
                then,
                otherwise,
            } => {
                cond.shift(by);
                then.shift(by);
                otherwise.shift(by);
            }
            ExprKind::For { bindings, body } => {
                for b in bindings {
                    b.var.shift(by);
                    match &mut b.source {
                        Source::Range { start, end, .. } => {
                            start.shift(by);
                            end.shift(by);
                        }
                        Source::List(e) => e.shift(by),
                    }
                }
                body.shift(by);
            }
        }
    }
}
