//! Static types and the signatures of built-ins. The built-ins themselves
//! live in the standard library, which hands the checker an [`Env`].

use std::fmt;

/// The static type of an expression.
#[derive(Debug, Clone, PartialEq)]
pub enum Type {
    /// Unknown (after an error) or deliberately open: accepts and is accepted
    /// by everything, so one mistake does not cascade.
    Any,
    /// A number (f64 in the language, f32 at run time).
    Number,
    /// `true` or `false`.
    Bool,
    /// A string.
    Str,
    /// Three numbers. A list of numbers is accepted where a vector is wanted;
    /// its length is checked when the value is known.
    Vec3,
    /// A list whose items are all of this type.
    List(Box<Type>),
    /// A domain type of the standard library: `shape`, `material`, `camera`…
    Named(&'static str),
    /// Any one of these.
    OneOf(Vec<Type>),
}

impl Type {
    /// A list of `of`.
    pub fn list(of: Type) -> Type {
        Type::List(Box::new(of))
    }

    /// Whether a value of type `actual` may be passed where `self` is wanted.
    pub fn accepts(&self, actual: &Type) -> bool {
        match (self, actual) {
            (Type::Any, _) | (_, Type::Any) => true,
            (Type::OneOf(options), a) => options.iter().any(|o| o.accepts(a)),
            (want, Type::OneOf(options)) => options.iter().all(|o| want.accepts(o)),
            (Type::Vec3, Type::List(e)) | (Type::List(e), Type::Vec3) => e.accepts(&Type::Number),
            (Type::List(a), Type::List(b)) => a.accepts(b),
            (a, b) => a == b,
        }
    }

    /// The type with an indefinite article, for messages: "a number", "an
    /// output", "any value".
    pub fn with_article(&self) -> String {
        let name = self.to_string();
        if matches!(self, Type::Any) {
            name
        } else if name.starts_with(['a', 'e', 'i', 'o', 'u']) {
            format!("an {name}")
        } else {
            format!("a {name}")
        }
    }

    /// Whether arithmetic applies: numbers, vectors, lists of them (or unknown).
    pub fn is_numeric(&self) -> bool {
        matches!(self, Type::Number | Type::Vec3 | Type::Any)
            || matches!(self, Type::List(e) if e.is_numeric())
    }
}

impl fmt::Display for Type {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Type::Any => write!(f, "any value"),
            Type::Number => write!(f, "number"),
            Type::Bool => write!(f, "bool"),
            Type::Str => write!(f, "string"),
            Type::Vec3 => write!(f, "vector [x, y, z]"),
            Type::List(e) => write!(f, "list of {e}"),
            Type::Named(n) => write!(f, "{n}"),
            Type::OneOf(options) => {
                for (i, o) in options.iter().enumerate() {
                    if i > 0 {
                        write!(f, " or ")?;
                    }
                    write!(f, "{o}")?;
                }
                Ok(())
            }
        }
    }
}

/// One parameter of a built-in function or one field of a block.
#[derive(Debug, Clone)]
pub struct Param {
    /// The name a caller writes (`radius:`).
    pub name: &'static str,
    /// The type accepted.
    pub ty: Type,
    /// The default as written in docs; `None` means the parameter is required.
    pub default: Option<&'static str>,
    /// One line for help texts and the reference.
    pub doc: &'static str,
}

impl Param {
    /// A parameter a caller must give.
    pub fn required(name: &'static str, ty: Type, doc: &'static str) -> Self {
        Param {
            name,
            ty,
            default: None,
            doc,
        }
    }
    /// A parameter with a default, shown as written in `default`.
    pub fn optional(
        name: &'static str,
        ty: Type,
        default: &'static str,
        doc: &'static str,
    ) -> Self {
        Param {
            name,
            ty,
            default: Some(default),
            doc,
        }
    }
}

/// The signature of a built-in function.
#[derive(Debug, Clone)]
pub struct Signature {
    /// The function's name.
    pub name: &'static str,
    /// Its parameters, in positional order.
    pub params: Vec<Param>,
    /// Extra positional arguments of this type (lists of it are flattened),
    /// as in `union(a, b, c)`.
    pub rest: Option<Param>,
    /// Extra named arguments of this type, passed on by the built-in
    /// (`sdf(f, major: 1)` passes `major` to the `fn` `f`).
    pub named_rest: Option<Param>,
    /// The type of its result.
    pub returns: Type,
    /// One line for help texts and the reference.
    pub doc: &'static str,
}

impl Signature {
    /// The parameter a positional argument at `index` binds to: none for a
    /// function with rest arguments, whose positional arguments are all
    /// rest and whose parameters are named only (`smooth_union(a, b, c, k: 0.2)`).
    pub fn positional(&self, index: usize) -> Option<&Param> {
        if self.rest.is_some() {
            None
        } else {
            self.params.get(index)
        }
    }

    /// `name(a: number, b: shape = ...)`, for help texts.
    pub fn synopsis(&self) -> String {
        let mut parts: Vec<String> = Vec::new();
        if let Some(r) = &self.rest {
            parts.push(format!("{}: {}...", r.name, r.ty));
        }
        let named_rest = self
            .named_rest
            .as_ref()
            .map(|r| format!("<{}>: {}...", r.name, r.ty));
        // Parameters of `fn`s are untyped (`Any`): shown by name only.
        parts.extend(self.params.iter().map(|p| match (p.default, &p.ty) {
            (Some(d), Type::Any) => format!("{}: {d}", p.name),
            (None, Type::Any) => p.name.to_string(),
            (Some(d), t) => format!("{}: {t} = {d}", p.name),
            (None, t) => format!("{}: {t}", p.name),
        }));
        parts.extend(named_rest);
        format!("{}({})", self.name, parts.join(", "))
    }
}

/// The signature of a block statement (`render`, …).
#[derive(Debug, Clone)]
pub struct BlockSig {
    /// The statement keyword.
    pub kind: &'static str,
    /// The fields it takes.
    pub fields: Vec<Param>,
    /// One line for help texts and the reference.
    pub doc: &'static str,
}

/// What the checker knows of the standard library.
pub trait Env {
    /// The built-in function of that name.
    fn function(&self, name: &str) -> Option<&Signature>;
    /// The statement of that keyword.
    fn block(&self, kind: &str) -> Option<&BlockSig>;
    /// The type of the built-in constant of that name (`pi`, colours…).
    fn constant(&self, name: &str) -> Option<Type>;
    /// Every built-in function's name, for suggestions.
    fn function_names(&self) -> Vec<&'static str>;
    /// Every statement keyword, for suggestions.
    fn block_names(&self) -> Vec<&'static str>;
    /// Every constant's name, for suggestions.
    fn constant_names(&self) -> Vec<&'static str>;
}
