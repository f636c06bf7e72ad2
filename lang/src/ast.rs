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
