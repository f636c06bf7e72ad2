//! The owned, spanned syntax tree. Nothing here refers to pest: the parser
//! converts its parse tree into these types at once.

use crate::span::Span;

/// A parsed file: its items in source order.
#[derive(Debug, Clone, PartialEq)]
pub struct File {
    pub items: Vec<Item>,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Item {
    Let(Let),
    Block(Block),
    Fn(FnDef),
    Import(Import),
}

/// `import "path.sdfl"`
#[derive(Debug, Clone, PartialEq)]
pub struct Import {
    /// The path as written (escapes resolved).
    pub path: String,
    /// The span of the string literal.
    pub path_span: Span,
    pub span: Span,
}

/// `fn name(params) { body }`
#[derive(Debug, Clone, PartialEq)]
pub struct FnDef {
    pub name: Ident,
    pub params: Vec<FnParam>,
    pub body: Body,
    pub span: Span,
}

/// A parameter of a `fn`, with its default (`None`: required).
#[derive(Debug, Clone, PartialEq)]
pub struct FnParam {
    pub name: Ident,
    pub default: Option<Expr>,
}

/// A name as written, with its span.
#[derive(Debug, Clone, PartialEq)]
pub struct Ident {
    pub name: String,
    pub span: Span,
}

/// `let name = value`
#[derive(Debug, Clone, PartialEq)]
pub struct Let {
    pub name: Ident,
    pub value: Expr,
    pub span: Span,
}

/// `kind name { field: value, ... }`
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    pub kind: Ident,
    pub name: Option<Ident>,
    pub fields: Vec<Field>,
    pub span: Span,
}

/// `name: value` inside a block.
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    pub name: Ident,
    pub value: Expr,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Expr {
    pub kind: ExprKind,
    pub span: Span,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BinOp {
    Add,
    Sub,
    Mul,
    Div,
    Rem,
    Pow,
    Lt,
    Le,
    Gt,
    Ge,
    Eq,
    Ne,
    And,
    Or,
}

impl BinOp {
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

#[derive(Debug, Clone, PartialEq)]
pub enum ExprKind {
    /// A number literal; degrees are already converted to radians.
    Number(f64),
    Bool(bool),
    Str(String),
    Var(Ident),
    List(Vec<Expr>),
    /// `callee(args)`, or `receiver.callee(args)` with `method` set and the
    /// receiver as the first positional argument.
    Call {
        callee: Ident,
        args: Vec<Arg>,
        method: bool,
    },
    /// `value.name`: a vector component.
    Member(Box<Expr>, Ident),
    Neg(Box<Expr>),
    /// `!value`
    Not(Box<Expr>),
    /// `list[index]`
    Index(Box<Expr>, Box<Expr>),
    /// `if cond { then } else { otherwise }`; `else if` is an `otherwise`
    /// body holding only another `If`.
    If {
        cond: Box<Expr>,
        then: Body,
        otherwise: Body,
    },
    Binary(BinOp, Box<Expr>, Box<Expr>),
    For {
        bindings: Vec<Binding>,
        body: Body,
    },
}

/// A call argument, named (`radius: 1`) or positional.
#[derive(Debug, Clone, PartialEq)]
pub struct Arg {
    pub name: Option<Ident>,
    pub value: Expr,
}

/// `var in source` of a `for`.
#[derive(Debug, Clone, PartialEq)]
pub struct Binding {
    pub var: Ident,
    pub source: Source,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Source {
    Range {
        start: Expr,
        end: Expr,
        inclusive: bool,
    },
    List(Expr),
}

/// `{ let a = ...; value }`
#[derive(Debug, Clone, PartialEq)]
pub struct Body {
    pub lets: Vec<Let>,
    pub value: Box<Expr>,
}

// ------------------------------------------------------------ moving spans

/// Moving every span of a tree by a fixed offset: an imported file is
/// parsed on its own and its tree moved to a range of offsets no other file
/// uses, so one span still names one place in one file.
pub trait Shift {
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
