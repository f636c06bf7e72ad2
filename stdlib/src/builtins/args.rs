//! Arguments bound to a built-in's parameters, read and checked by name:
//! numbers and vectors in f32's range, trainable arguments with their
//! ranges, materials, shapes.

use super::*;

/// The arguments of one call of a built-in (or one statement's fields),
/// bound to parameter names, defaults filled in.
pub struct Args {
    /// By parameter name: the value and where it was written (the call, for a
    /// default).
    pub named: HashMap<&'static str, (Value, Span)>,
    /// Extra positional arguments, for built-ins with rest parameters.
    pub rest: Vec<(Value, Span)>,
    /// The whole call.
    pub span: Span,
    /// The built-in or block the arguments are for (names trainable
    /// arguments, `torus.major`).
    pub owner: &'static str,
    /// The parameters that took their default (not written in the call).
    pub defaulted: Vec<&'static str>,
    /// The directory that input paths are relative to (the scene file's),
    /// where the program has a file on disk: inputs are checked to exist.
    pub base: Option<std::sync::Arc<std::path::Path>>,
}

pub(crate) fn value_error(
    span: Span,
    message: impl Into<String>,
    label: impl Into<String>,
    help: impl Into<String>,
) -> Diag {
    Diag::new(codes::VALUE, span, message)
        .label(label)
        .help(help)
}

pub(crate) fn type_error(span: Span, want: &str, got: &Value) -> Diag {
    Diag::new(
        codes::TYPE,
        span,
        format!("expected a {want}, found a {}", describe(got)),
    )
    .label(format!("this is a {}", describe(got)))
    .help(format!("pass a {want} here"))
}

impl Args {
    /// No arguments yet, for the call at `span`.
    pub fn new(span: Span) -> Self {
        Args {
            named: HashMap::new(),
            rest: Vec::new(),
            span,
            owner: "",
            defaulted: Vec::new(),
            base: None,
        }
    }

    /// Whether the call wrote this parameter (it did not take its default).
    pub(crate) fn given(&self, name: &str) -> bool {
        self.named.contains_key(name) && !self.defaulted.contains(&name)
    }

    pub(crate) fn get(&self, name: &str) -> (&Value, Span) {
        let (v, s) = self.named.get(name).unwrap_or_else(|| {
            panic!("parameter `{name}` is neither given nor defaulted: the checker guarantees one")
        });
        (v, *s)
    }

    /// A number in f32's range (not a `param`).
    pub fn number(&self, name: &str) -> Result<f64, Diag> {
        match self.get(name) {
            (Value::Number(x), s) => f32_range(*x, s, name),
            (Value::Param(_), s) => Err(not_trainable(s, name)),
            (v, s) => Err(type_error(s, "number", v)),
        }
    }

    /// A number argument that may be trainable, checked against `bound`
    /// (its initial value when trainable).
    pub fn scalar_arg(&self, name: &str, bound: Bound) -> Result<Arg<f64>, Diag> {
        let (v, span) = self.get(name);
        let (value, param) = match v {
            Value::Number(x) => (f32_range(*x, span, name)?, None),
            Value::Param(d) => match d.init {
                ParamInit::Scalar(x) => (
                    f32_range(x, span, name)?,
                    Some(self.param_use(d, name, bound)),
                ),
                ParamInit::Vec3(_) => return Err(type_error(span, "number", v)),
            },
            _ => return Err(type_error(span, "number", v)),
        };
        check_bound(value, bound, name, span)?;
        if param.is_some() {
            check_floor(value, bound, name, span)?;
        }
        Ok(Arg { value, param })
    }

    /// A vector argument (a number means all three components) that may be
    /// trainable, each component checked against `bound`.
    pub fn vec3_arg(&self, name: &str, bound: Bound) -> Result<Arg<DVec3>, Diag> {
        let (v, span) = self.get(name);
        let (value, param) = match v {
            Value::Param(d) => {
                let value = match d.init {
                    ParamInit::Scalar(x) => DVec3::splat(x),
                    ParamInit::Vec3(v) => v,
                };
                for x in value.to_array() {
                    f32_range(x, span, name)?;
                }
                (value, Some(self.param_use(d, name, bound)))
            }
            _ => (self.vec3(name)?, None),
        };
        for x in value.to_array() {
            check_bound(x, bound, name, span)?;
            if param.is_some() {
                check_floor(x, bound, name, span)?;
            }
        }
        Ok(Arg { value, param })
    }

    pub(crate) fn param_use(&self, decl: &Arc<ParamDecl>, name: &str, bound: Bound) -> ParamUse {
        ParamUse {
            decl: decl.clone(),
            bound,
            site: format!("{}.{name}", self.owner),
        }
    }

    /// A positive number argument that may be trainable (trained values
    /// stay at least [`MIN_LENGTH`]).
    pub fn length_arg(&self, name: &str) -> Result<Arg<f64>, Diag> {
        self.scalar_arg(name, Bound::AtLeast(MIN_LENGTH))
    }

    /// A finite number `> 0`.
    pub fn positive(&self, name: &str) -> Result<f64, Diag> {
        let x = self.number(name)?;
        if x > 0.0 {
            Ok(x)
        } else {
            Err(value_error(
                self.get(name).1,
                format!("`{name}` must be positive, got {}", sdfl_lang::fmt_num(x)),
                "not > 0",
                format!("give `{name}` a value greater than zero"),
            ))
        }
    }

    /// A whole number in `lo..=hi`.
    pub fn count(&self, name: &str, lo: u64, hi: u64) -> Result<u64, Diag> {
        let x = self.number(name)?;
        if x.fract() != 0.0 || x < lo as f64 || x > hi as f64 {
            return Err(value_error(
                self.get(name).1,
                format!(
                    "`{name}` must be a whole number from {lo} to {hi}, got {}",
                    sdfl_lang::fmt_num(x)
                ),
                "out of range",
                format!("use a whole number between {lo} and {hi}"),
            ));
        }
        Ok(x as u64)
    }

    /// A vector in f32's range (a number `x` is `[x, x, x]`; not a `param`).
    pub fn vec3(&self, name: &str) -> Result<DVec3, Diag> {
        let (v, s) = self.get(name);
        match v {
            Value::Number(x) => Ok(DVec3::splat(f32_range(*x, s, name)?)),
            Value::Param(_) => Err(not_trainable(s, name)),
            Value::List(items) if items.iter().any(|i| matches!(i, Value::Param(_))) => {
                Err(Diag::new(
                    codes::TYPE,
                    s,
                    format!("a `param` cannot be one component of `{name}`"),
                )
                .label("a list holding a `param`")
                .help("make the whole vector trainable instead: `param([x, y, z])`"))
            }
            _ => {
                let p = v
                    .as_vec3()
                    .ok_or_else(|| type_error(s, "vector [x, y, z]", v))?;
                p.to_array()
                    .iter()
                    .try_for_each(|x| f32_range(*x, s, name).map(drop))?;
                Ok(p)
            }
        }
    }

    /// A nonzero vector, normalised.
    pub fn direction(&self, name: &str) -> Result<DVec3, Diag> {
        let v = self.vec3(name)?;
        let len = v.length();
        if len > 1e-12 {
            Ok(v / len)
        } else {
            Err(value_error(
                self.get(name).1,
                format!("`{name}` must be a nonzero direction"),
                "zero vector",
                "give a direction such as [0, 0, 1]",
            ))
        }
    }

    /// A string, with where it was written.
    pub fn string(&self, name: &str) -> Result<(Arc<str>, Span), Diag> {
        match self.get(name) {
            (Value::Str(s), span) => Ok((s.clone(), span)),
            (v, s) => Err(type_error(s, "string", v)),
        }
    }

    /// A shape.
    pub fn shape(&self, name: &str) -> Result<Arc<Shape>, Diag> {
        match self.get(name) {
            (Value::Shape(s), _) => Ok(s.clone()),
            (v, s) => Err(type_error(s, "shape", v)),
        }
    }

    /// A material, or a colour `[r, g, b]` (possibly `param(...)`) meaning
    /// a constant material.
    pub fn material(&self, name: &str) -> Result<Arc<Material>, Diag> {
        match self.get(name) {
            (Value::Material(m), _) => Ok(m.clone()),
            (v, _) if matches!(v, Value::Param(_)) || v.as_vec3().is_some() => {
                Ok(Arc::new(Material::Constant(self.color_arg(name)?)))
            }
            (v, s) => Err(type_error(s, "material", v)),
        }
    }

    /// A colour `[r, g, b]` in 0..1, possibly trainable (kept in 0..1).
    pub fn color_arg(&self, name: &str) -> Result<Arg<DVec3>, Diag> {
        let c = self.vec3_arg(name, Bound::Free)?;
        colour(c.value, self.get(name).1)?;
        let param = c.param.map(|u| ParamUse {
            bound: Bound::Within(0.0, 1.0),
            ..u
        });
        Ok(Arg { param, ..c })
    }

    /// The rest arguments, with lists flattened, as numbers.
    pub fn rest_numbers(&self) -> Result<Vec<f64>, Diag> {
        fn walk(v: &Value, span: Span, out: &mut Vec<f64>) -> Result<(), Diag> {
            match v {
                Value::Number(x) => {
                    out.push(f32_range(*x, span, "x")?);
                    Ok(())
                }
                Value::List(items) => items.iter().try_for_each(|i| walk(i, span, out)),
                other => Err(type_error(span, "number", other)),
            }
        }
        let mut out = Vec::new();
        for (v, s) in &self.rest {
            walk(v, *s, &mut out)?;
        }
        Ok(out)
    }

    /// The rest arguments, with lists flattened, as shapes.
    pub fn rest_shapes(&self) -> Result<Vec<Arc<Shape>>, Diag> {
        fn walk(v: &Value, span: Span, out: &mut Vec<Arc<Shape>>) -> Result<(), Diag> {
            match v {
                Value::Shape(s) => {
                    out.push(s.clone());
                    Ok(())
                }
                Value::List(items) => items.iter().try_for_each(|i| walk(i, span, out)),
                other => Err(type_error(span, "shape", other)),
            }
        }
        let mut out = Vec::new();
        for (v, s) in &self.rest {
            walk(v, *s, &mut out)?;
        }
        Ok(out)
    }
}

pub(crate) fn not_trainable(span: Span, name: &str) -> Diag {
    Diag::new(codes::VALUE, span, format!("`{name}` cannot be trained"))
        .label("marked with `param`")
        .help("`param(...)` marks numeric arguments of shapes, transforms, blends, colours and fields; cameras, samplers and settings are fixed: drop `param(...)` here")
}

/// A trainable value starts where training keeps it: at least the floor of
/// its range (which is above 0 for lengths and β).
pub(crate) fn check_floor(x: f64, bound: Bound, name: &str, span: Span) -> Result<(), Diag> {
    match bound {
        Bound::AtLeast(lo) if x < lo => Err(value_error(
            span,
            format!(
                "a trained `{name}` starts at {}, below {}, the smallest value training keeps",
                sdfl_lang::diag::fmt_num(x),
                sdfl_lang::diag::fmt_num(lo)
            ),
            "too small to train",
            format!("start `{name}` at {} or more", sdfl_lang::diag::fmt_num(lo)),
        )),
        _ => Ok(()),
    }
}

/// `x` within `bound`, or a diagnostic naming the argument.
pub(crate) fn check_bound(x: f64, bound: Bound, name: &str, span: Span) -> Result<(), Diag> {
    match bound {
        Bound::Free => Ok(()),
        Bound::AtLeast(_) if x > 0.0 => Ok(()),
        Bound::AtLeast(_) => Err(value_error(
            span,
            format!("`{name}` must be positive, got {x}"),
            "not > 0",
            format!("give `{name}` a value greater than zero"),
        )),
        Bound::Within(lo, hi) if (lo..=hi).contains(&x) => Ok(()),
        Bound::Within(lo, hi) => Err(value_error(
            span,
            format!("`{name}` must be in {lo}..{hi}, got {x}"),
            format!("out of {lo}..{hi}"),
            format!("give `{name}` a value from {lo} to {hi}"),
        )),
    }
}

pub(crate) fn colour(c: DVec3, span: Span) -> Result<DVec3, Diag> {
    if c.min_element() >= 0.0 && c.max_element() <= 1.0 {
        Ok(c)
    } else {
        Err(value_error(
            span,
            format!(
                "colour components must be in 0..1, got [{}, {}, {}]",
                c.x, c.y, c.z
            ),
            "out of 0..1",
            "colours are linear RGB with components from 0 to 1",
        ))
    }
}

/// The errors of a statement's fields, collected: every field is read and
/// checked whatever the others hold, so one `check` reports them all. An
/// error about a field that is poison (its own error was reported where it
/// was made) is left out.
pub(crate) struct Errors<'a> {
    args: &'a Args,
    pub diags: Vec<Diag>,
}

impl<'a> Errors<'a> {
    pub fn new(args: &'a Args) -> Self {
        Errors {
            args,
            diags: Vec::new(),
        }
    }

    /// The value, or `None` with its error kept.
    pub fn ok<T>(&mut self, r: Result<T, Diag>) -> Option<T> {
        match r {
            Ok(v) => Some(v),
            Err(d) => {
                let poisoned = self
                    .args
                    .named
                    .values()
                    .any(|(v, s)| v.is_poison() && *s == d.span);
                if !poisoned {
                    self.diags.push(d);
                }
                None
            }
        }
    }
}
