//! Source text → owned AST. pest's `Pairs` are converted here and never
//! leave this module.
//!
//! Hostile input is handled before pest sees it: nesting deeper than
//! [`MAX_NESTING`] (which would overflow the recursive-descent parser's stack)
//! is rejected with a diagnostic. While the AST is built, overlong operator
//! chains and expression trees taller than [`MAX_DEPTH`] (method chains,
//! operators inside brackets, many loop bindings) are rejected too, so the
//! recursive tree walkers after the parser (checker, evaluator, `Drop`)
//! cannot overflow their stacks either.

use std::f64::consts::PI;

use pest::error::{ErrorVariant, InputLocation};
use pest::iterators::Pair;
use pest::pratt_parser::{Assoc, Op, PrattParser};
use pest::Parser as _;
use std::sync::OnceLock;

use crate::ast::*;
use crate::diag::{codes, Diag, Diagnostics};
use crate::span::Span;

mod errors;
use errors::{next_item_start, prescan, syntax_error};

/// The parser pest derives from the grammar, and its `Rule`s.
mod grammar {
    #![allow(missing_docs, reason = "pest_derive generates the Rule enum")]
    #[derive(pest_derive::Parser)]
    #[grammar = "sdfl.pest"]
    pub(crate) struct SdflParser;
}
use grammar::{Rule, SdflParser};

/// Deepest bracket nesting accepted (a `for` whose body has not started
/// yet counts as one more level: `for a in for b in ...` nests too).
pub const MAX_NESTING: usize = 64;
/// Tallest expression tree accepted. Every operator, call, method, member
/// access and `for` binding adds a level; tree walkers recurse this deep.
pub const MAX_DEPTH: usize = 640;
/// Most binary operators in one expression (a left-deep tree this tall is
/// walked recursively later).
pub const MAX_OPERATORS: usize = 512;
/// Longest run of unary minus signs.
const MAX_PREFIX_RUN: usize = 16;
/// Most rule calls pest may make parsing one item (a `let`, `fn`, block
/// or `import`): one item's parse tree is held whole while it is built, so
/// this bounds the parser's memory (and time) whatever one statement holds.
/// A list of 400k numbers (3 MB) fits, parsed in about 200 MB; an 8 MB
/// list is refused at about the same (it took 1.3 GB).
pub const MAX_ITEM_CALLS: usize = 50_000_000;
/// Syntax errors reported before giving up on a file.
const MAX_SYNTAX_ERRORS: usize = 20;

/// Parse a whole file. Syntax errors are all collected (the parser resumes at
/// the next top-level item after each one); the AST is returned only when
/// there were none.
pub fn parse(text: &str) -> Result<File, Diagnostics> {
    let mut diags = Diagnostics::default();
    if let Some(d) = prescan(text) {
        diags.push(d);
        return Err(diags);
    }
    static LIMIT: OnceLock<()> = OnceLock::new();
    // Process-wide in pest, and only this parser uses pest.
    LIMIT.get_or_init(|| pest::set_call_limit(std::num::NonZeroUsize::new(MAX_ITEM_CALLS)));
    let mut items = Vec::new();
    // Where the next item's parse starts, and where the one before started
    // (an error is reported as a parse of the whole rest would report it:
    // the item before may also have wanted what comes next).
    let (mut offset, mut previous) = (0, 0);
    while diags.len() < MAX_SYNTAX_ERRORS {
        match SdflParser::parse(Rule::next_item, &text[offset..]) {
            Ok(mut pairs) => {
                let step = pairs.next().expect("next_item always yields one pair");
                let end = offset + step.as_span().end();
                let Some(item) = children(step).next() else {
                    break; // the end of the file
                };
                // Spans are built relative to `offset`, where pest began.
                let mut found = Diagnostics::default();
                let mut item = build_item(item, &mut found);
                item.shift(offset);
                for mut d in found.diags {
                    d.span.shift(offset);
                    d.notes.iter_mut().for_each(|(s, _)| s.shift(offset));
                    diags.push(d);
                }
                items.push(item);
                (previous, offset) = (offset, end);
            }
            Err(first) if over_limit(&first) => {
                let line = text[offset..].find('\n').map_or(text.len(), |n| offset + n);
                diags.push(
                    Diag::new(
                        codes::TOO_LARGE,
                        Span::new(offset, line.min(offset + 80)),
                        "statement too large to parse",
                    )
                    .label("this statement")
                    .help("split it into several `let`s, or build long lists with `for`; data sets belong in files (`.npy`, `.npz`, PNG)"),
                );
                match next_item_start(text, offset) {
                    Some(next) => (previous, offset) = (next, next),
                    None => break,
                }
                continue;
            }
            Err(first) => {
                // As a parse of the file from the item before reports it
                // (unless that parse, two items long, is over the limit).
                let (e, base) = match SdflParser::parse(Rule::file, &text[previous..]) {
                    Err(e) if !over_limit(&e) => (e, previous),
                    _ => (first, offset),
                };
                let pos = base
                    + match e.location {
                        InputLocation::Pos(p) => p,
                        InputLocation::Span((s, _)) => s,
                    };
                diags.push(syntax_error(text, pos, &e.variant));
                // An error at the start of a line that starts an item (the
                // line before was incomplete): parsing resumes right there.
                let item_here = pos > previous
                    && (pos == 0 || text[..pos].ends_with('\n'))
                    && text[pos..].starts_with(|c: char| c.is_ascii_alphabetic() || c == '_');
                let resume = if item_here {
                    Some(pos)
                } else {
                    next_item_start(text, pos)
                };
                match resume {
                    Some(next) => (previous, offset) = (next, next),
                    None => break,
                }
            }
        }
    }
    if diags.is_empty() {
        Ok(File { items })
    } else {
        Err(diags)
    }
}

/// Whether pest stopped at [`MAX_ITEM_CALLS`] (not at a syntax error).
fn over_limit(e: &pest::error::Error<Rule>) -> bool {
    matches!(&e.variant, ErrorVariant::CustomError { message } if message.contains("limit reached"))
}

// ------------------------------------------------------------- AST building

fn span_of(pair: &Pair<Rule>) -> Span {
    let s = pair.as_span();
    Span::new(s.start(), s.end())
}

fn is_punctuation(rule: Rule) -> bool {
    matches!(
        rule,
        Rule::kw_let
            | Rule::kw_for
            | Rule::kw_in
            | Rule::kw_if
            | Rule::kw_else
            | Rule::kw_fn
            | Rule::kw_import
            | Rule::op_assign
            | Rule::dot
            | Rule::comma
            | Rule::colon
            | Rule::semicolon
            | Rule::paren_open
            | Rule::paren_close
            | Rule::bracket_open
            | Rule::bracket_close
            | Rule::brace_open
            | Rule::brace_close
            | Rule::EOI
    )
}

/// The meaningful children of a pair: punctuation is dropped.
fn children(pair: Pair<Rule>) -> impl Iterator<Item = Pair<Rule>> {
    pair.into_inner().filter(|p| !is_punctuation(p.as_rule()))
}

fn build_item(p: Pair<Rule>, diags: &mut Diagnostics) -> Item {
    match p.as_rule() {
        Rule::let_stmt => Item::Let(build_let(p, diags).0),
        Rule::block => Item::Block(build_block(p, diags)),
        Rule::fn_def => Item::Fn(build_fn(p, diags)),
        Rule::import_stmt => {
            let span = span_of(&p);
            let lit = children(p).next().expect("import has a path");
            let path_span = span_of(&lit);
            let path = match build_string(lit, diags) {
                ExprKind::Str(s) => s,
                _ => unreachable!("build_string makes strings"),
            };
            Item::Import(Import {
                path,
                path_span,
                span,
            })
        }
        r => unreachable!("grammar: item cannot be {r:?}"),
    }
}

fn build_ident(pair: Pair<Rule>) -> Ident {
    Ident {
        name: pair.as_str().to_string(),
        span: span_of(&pair),
    }
}

/// A built expression (or part of one) with the height of its tree.
type Built<T> = (T, usize);

/// Returns the `let` and the height of its value.
fn build_let(pair: Pair<Rule>, diags: &mut Diagnostics) -> Built<Let> {
    let span = span_of(&pair);
    let mut it = children(pair);
    let name = build_ident(it.next().expect("let has a name"));
    let (value, depth) = build_expr(it.next().expect("let has a value"), diags);
    (Let { name, value, span }, depth)
}

/// The diagnostic for an expression taller than [`MAX_DEPTH`], and the
/// placeholder that replaces it (so enclosing expressions are not reported
/// again, and the tall tree is dropped while it is still shallow enough).
/// The diagnostic is left out when one was already given inside `whole`.
fn too_deep(at: Span, whole: Span, diags: &mut Diagnostics) -> Built<Expr> {
    let inner_reported = diags.diags.iter().any(|d| {
        d.code == codes::NESTING && whole.start <= d.span.start && d.span.end <= whole.end
    });
    if !inner_reported {
        diags.push(
            Diag::new(
                codes::NESTING,
                at,
                format!("expression nested more than {MAX_DEPTH} levels deep"),
            )
            .label("too deep")
            .help(
                "every operator, call, method, `.x` and loop binding adds a level: \
             split the expression into parts bound with `let`",
            ),
        );
    }
    let placeholder = Expr {
        kind: ExprKind::Number(0.0),
        span: at,
    };
    (placeholder, 1)
}

/// The span of the first line of a pair's text (a whole multi-line
/// expression would be quoted in full).
fn first_line_span(pair: &Pair<Rule>) -> Span {
    let span = span_of(pair);
    let len = pair.as_str().find('\n').unwrap_or(span.len());
    Span::new(span.start, span.start + len)
}

fn build_block(pair: Pair<Rule>, diags: &mut Diagnostics) -> Block {
    let span = span_of(&pair);
    let mut kind = None;
    let mut name = None;
    let mut fields = Vec::new();
    for p in children(pair) {
        match p.as_rule() {
            Rule::ident if kind.is_none() => kind = Some(build_ident(p)),
            Rule::ident => name = Some(build_ident(p)),
            Rule::field => {
                let mut it = children(p);
                let fname = build_ident(it.next().expect("field has a name"));
                let (value, _) = build_expr(it.next().expect("field has a value"), diags);
                fields.push(Field { name: fname, value });
            }
            r => unreachable!("grammar: block cannot contain {r:?}"),
        }
    }
    Block {
        kind: kind.expect("block has a kind"),
        name,
        fields,
        span,
    }
}

fn build_fn(pair: Pair<Rule>, diags: &mut Diagnostics) -> FnDef {
    let span = span_of(&pair);
    let mut it = children(pair);
    let name = build_ident(it.next().expect("fn has a name"));
    let mut params = Vec::new();
    let mut body = None;
    for p in it {
        match p.as_rule() {
            Rule::fn_param => {
                let mut parts = children(p);
                let pname = build_ident(parts.next().expect("parameter has a name"));
                let default = parts.next().map(|e| build_expr(e, diags).0);
                params.push(FnParam {
                    name: pname,
                    default,
                });
            }
            Rule::body => body = Some(build_body(p, diags).0),
            r => unreachable!("grammar: fn cannot contain {r:?}"),
        }
    }
    FnDef {
        name,
        params,
        body: body.expect("fn has a body"),
        span,
    }
}

fn is_infix(rule: Rule) -> bool {
    matches!(
        rule,
        Rule::op_add
            | Rule::op_sub
            | Rule::op_mul
            | Rule::op_div
            | Rule::op_rem
            | Rule::op_pow
            | Rule::op_lt
            | Rule::op_le
            | Rule::op_gt
            | Rule::op_ge
            | Rule::op_eq
            | Rule::op_ne
            | Rule::op_and
            | Rule::op_or
    )
}

fn pratt() -> &'static PrattParser<Rule> {
    static PRATT: OnceLock<PrattParser<Rule>> = OnceLock::new();
    PRATT.get_or_init(|| {
        PrattParser::new()
            .op(Op::infix(Rule::op_or, Assoc::Left))
            .op(Op::infix(Rule::op_and, Assoc::Left))
            .op(Op::infix(Rule::op_lt, Assoc::Left)
                | Op::infix(Rule::op_le, Assoc::Left)
                | Op::infix(Rule::op_gt, Assoc::Left)
                | Op::infix(Rule::op_ge, Assoc::Left)
                | Op::infix(Rule::op_eq, Assoc::Left)
                | Op::infix(Rule::op_ne, Assoc::Left))
            .op(Op::infix(Rule::op_add, Assoc::Left) | Op::infix(Rule::op_sub, Assoc::Left))
            .op(Op::infix(Rule::op_mul, Assoc::Left)
                | Op::infix(Rule::op_div, Assoc::Left)
                | Op::infix(Rule::op_rem, Assoc::Left))
            .op(Op::prefix(Rule::op_neg) | Op::prefix(Rule::op_not))
            .op(Op::infix(Rule::op_pow, Assoc::Right))
    })
}

fn build_expr(pair: Pair<Rule>, diags: &mut Diagnostics) -> Built<Expr> {
    debug_assert_eq!(pair.as_rule(), Rule::expr);
    let span = span_of(&pair);
    let first_line = first_line_span(&pair);
    let operators = pair
        .clone()
        .into_inner()
        .filter(|p| is_infix(p.as_rule()))
        .count();
    if operators > MAX_OPERATORS {
        diags.push(
            Diag::new(
                codes::NESTING,
                first_line,
                format!("expression has {operators} operators (at most {MAX_OPERATORS})"),
            )
            .label("too long")
            .help("split it into parts bound with `let`, or build the values with a `for`"),
        );
        let placeholder = Expr {
            kind: ExprKind::Number(0.0),
            span,
        };
        return (placeholder, 1);
    }
    // The operands are built first, each checked for height on its own;
    // the Pratt parser then only combines them. (Building them from inside
    // the Pratt callbacks nested the parser's recursion for `^` chains
    // inside that of every enclosing bracket: 60 brackets of 500 `^` each
    // overflowed the stack before any height was known.)
    let mut operands = Vec::new();
    for p in pair.clone().into_inner() {
        if p.as_rule() == Rule::postfixed {
            operands.push(build_postfixed(p, diags));
        }
    }
    let mut operands = operands.into_iter();
    let (expr, depth) = pratt()
        .map_primary(|_| operands.next().expect("one operand per primary"))
        .map_prefix(|op, (rhs, depth): Built<Expr>| {
            let span = span_of(&op).to(rhs.span);
            let kind = match op.as_rule() {
                Rule::op_not => ExprKind::Not(Box::new(rhs)),
                _ => ExprKind::Neg(Box::new(rhs)),
            };
            let expr = Expr { span, kind };
            (expr, depth + 1)
        })
        .map_infix(|(lhs, l), op, (rhs, r)| {
            let bin = match op.as_rule() {
                Rule::op_add => BinOp::Add,
                Rule::op_sub => BinOp::Sub,
                Rule::op_mul => BinOp::Mul,
                Rule::op_div => BinOp::Div,
                Rule::op_rem => BinOp::Rem,
                Rule::op_pow => BinOp::Pow,
                Rule::op_lt => BinOp::Lt,
                Rule::op_le => BinOp::Le,
                Rule::op_gt => BinOp::Gt,
                Rule::op_ge => BinOp::Ge,
                Rule::op_eq => BinOp::Eq,
                Rule::op_ne => BinOp::Ne,
                Rule::op_and => BinOp::And,
                Rule::op_or => BinOp::Or,
                r => unreachable!("grammar: {r:?} is not an infix operator"),
            };
            let expr = Expr {
                span: lhs.span.to(rhs.span),
                kind: ExprKind::Binary(bin, Box::new(lhs), Box::new(rhs)),
            };
            (expr, l.max(r) + 1)
        })
        .parse(pair.into_inner());
    if depth > MAX_DEPTH {
        return too_deep(first_line, span, diags);
    }
    (expr, depth)
}

fn build_postfixed(pair: Pair<Rule>, diags: &mut Diagnostics) -> Built<Expr> {
    let mut it = children(pair);
    let (mut expr, mut depth) = build_primary(it.next().expect("postfixed has an operand"), diags);
    for suffix in it {
        let suffix_span = span_of(&suffix);
        let span = expr.span.to(suffix_span);
        match suffix.as_rule() {
            Rule::method => {
                let mut parts = children(suffix);
                let callee = build_ident(parts.next().expect("method has a name"));
                let mut args = vec![Arg {
                    name: None,
                    value: expr,
                }];
                for a in parts {
                    let (arg, d) = build_arg(a, diags);
                    depth = depth.max(d);
                    args.push(arg);
                }
                expr = Expr {
                    kind: ExprKind::Call {
                        callee,
                        args,
                        method: true,
                    },
                    span,
                };
            }
            Rule::member => {
                let name = build_ident(children(suffix).next().expect("member has a name"));
                expr = Expr {
                    kind: ExprKind::Member(Box::new(expr), name),
                    span,
                };
            }
            Rule::index => {
                let (index, d) =
                    build_expr(children(suffix).next().expect("index has a value"), diags);
                depth = depth.max(d);
                expr = Expr {
                    kind: ExprKind::Index(Box::new(expr), Box::new(index)),
                    span,
                };
            }
            r => unreachable!("grammar: {r:?} is not a postfix"),
        }
        depth += 1;
        // Checked per suffix: a chain of 100k methods must not be built
        // whole (dropping it would recurse 100k deep).
        if depth > MAX_DEPTH {
            return too_deep(suffix_span, span, diags);
        }
    }
    (expr, depth)
}

fn build_arg(pair: Pair<Rule>, diags: &mut Diagnostics) -> Built<Arg> {
    let mut name = None;
    let mut value = None;
    for p in children(pair) {
        match p.as_rule() {
            Rule::ident => name = Some(build_ident(p)),
            Rule::expr => value = Some(build_expr(p, diags)),
            r => unreachable!("grammar: arg cannot contain {r:?}"),
        }
    }
    let (value, depth) = value.expect("arg has a value");
    (Arg { name, value }, depth)
}

fn build_primary(pair: Pair<Rule>, diags: &mut Diagnostics) -> Built<Expr> {
    let span = span_of(&pair);
    let mut depth = 0;
    let kind = match pair.as_rule() {
        Rule::number => build_number(pair, diags),
        Rule::string => build_string(pair, diags),
        Rule::boolean => ExprKind::Bool(pair.as_str() == "true"),
        Rule::ident => ExprKind::Var(build_ident(pair)),
        Rule::expr => return build_expr(pair, diags),
        Rule::list => {
            let mut items = Vec::new();
            for p in children(pair) {
                let (item, d) = build_expr(p, diags);
                depth = depth.max(d);
                items.push(item);
            }
            ExprKind::List(items)
        }
        Rule::call => {
            let mut it = children(pair);
            let callee = build_ident(it.next().expect("call has a callee"));
            let mut args = Vec::new();
            for a in it {
                let (arg, d) = build_arg(a, diags);
                depth = depth.max(d);
                args.push(arg);
            }
            ExprKind::Call {
                callee,
                args,
                method: false,
            }
        }
        Rule::for_expr => {
            let (kind, d) = build_for(pair, diags);
            depth = d;
            kind
        }
        Rule::if_expr => return build_if(pair, diags),
        r => unreachable!("grammar: {r:?} is not a primary"),
    };
    (Expr { kind, span }, depth + 1)
}

fn build_number(pair: Pair<Rule>, diags: &mut Diagnostics) -> ExprKind {
    let span = span_of(&pair);
    let mut value = 0.0;
    let mut degrees = false;
    for p in pair.into_inner() {
        match p.as_rule() {
            Rule::number_value => {
                // The grammar only admits valid float syntax.
                value = p.as_str().parse::<f64>().unwrap_or(f64::INFINITY);
            }
            Rule::unit => degrees = true,
            r => unreachable!("grammar: number cannot contain {r:?}"),
        }
    }
    if !value.is_finite() {
        diags.push(
            Diag::new(codes::NUMBER, span, "number is too large")
                .label("larger than 1.8e308")
                .help("numbers are 64-bit floats; use a smaller exponent"),
        );
        value = 0.0;
    }
    ExprKind::Number(if degrees { value * PI / 180.0 } else { value })
}

fn build_string(pair: Pair<Rule>, diags: &mut Diagnostics) -> ExprKind {
    let inner = pair.into_inner().next().expect("string has contents");
    let start = inner.as_span().start();
    let raw = inner.as_str();
    let mut out = String::with_capacity(raw.len());
    let mut chars = raw.char_indices();
    while let Some((_, c)) = chars.next() {
        if c != '\\' {
            out.push(c);
            continue;
        }
        match chars.next() {
            Some((_, '"')) => out.push('"'),
            Some((_, '\\')) => out.push('\\'),
            Some((_, 'n')) => out.push('\n'),
            Some((_, 't')) => out.push('\t'),
            Some((i, other)) => diags.push(
                Diag::new(
                    codes::ESCAPE,
                    Span::new(start + i - 1, start + i + other.len_utf8()),
                    format!("unknown escape `\\{other}`"),
                )
                .label("not an escape")
                .help("strings understand `\\\"`, `\\\\`, `\\n` and `\\t`"),
            ),
            None => {}
        }
    }
    ExprKind::Str(out)
}

/// Returns the loop and its height: the evaluator recurses once per
/// binding, so each binding counts as a level.
fn build_for(pair: Pair<Rule>, diags: &mut Diagnostics) -> Built<ExprKind> {
    let mut bindings = Vec::new();
    let mut body = None;
    let mut depth = 0;
    for p in children(pair) {
        match p.as_rule() {
            Rule::binding => {
                let mut it = children(p);
                let var = build_ident(it.next().expect("binding has a variable"));
                let (first, d) = build_expr(it.next().expect("binding has a source"), diags);
                depth = depth.max(d);
                let source = match it.next() {
                    Some(range_end) => {
                        let mut r = children(range_end);
                        let op = r.next().expect("range operator");
                        let (end, d) = build_expr(r.next().expect("range end"), diags);
                        depth = depth.max(d);
                        Source::Range {
                            start: first,
                            end,
                            inclusive: op.as_rule() == Rule::range_inclusive,
                        }
                    }
                    None => Source::List(first),
                };
                bindings.push(Binding { var, source });
            }
            Rule::body => {
                let (b, d) = build_body(p, diags);
                depth = depth.max(d);
                body = Some(b);
            }
            r => unreachable!("grammar: for cannot contain {r:?}"),
        }
    }
    let depth = depth + bindings.len();
    let kind = ExprKind::For {
        bindings,
        body: body.expect("for has a body"),
    };
    (kind, depth)
}

/// `{ let ...; value }` and its height.
fn build_body(pair: Pair<Rule>, diags: &mut Diagnostics) -> Built<Body> {
    let mut lets = Vec::new();
    let mut value = None;
    let mut depth = 0;
    for b in children(pair) {
        match b.as_rule() {
            Rule::let_stmt => {
                let (l, d) = build_let(b, diags);
                depth = depth.max(d);
                lets.push(l);
            }
            Rule::expr => {
                let (v, d) = build_expr(b, diags);
                depth = depth.max(d);
                value = Some(v);
            }
            r => unreachable!("grammar: body cannot contain {r:?}"),
        }
    }
    let body = Body {
        lets,
        value: Box::new(value.expect("body has a value")),
    };
    (body, depth)
}

/// `if a { x } else if b { y } else { z }`: the conditions and bodies come
/// as a flat list, nested here from the last `else` back (iteratively: a
/// chain of thousands must not recurse). Each `else if` adds a level.
fn build_if(pair: Pair<Rule>, diags: &mut Diagnostics) -> Built<Expr> {
    let span = span_of(&pair);
    let first_line = first_line_span(&pair);
    let mut conds = Vec::new();
    let mut bodies = Vec::new();
    let mut depth = 0;
    for p in children(pair) {
        match p.as_rule() {
            Rule::expr => {
                let (c, d) = build_expr(p.clone(), diags);
                depth = depth.max(d);
                conds.push((c, span_of(&p).start));
            }
            Rule::body => {
                let (b, d) = build_body(p, diags);
                depth = depth.max(d);
                bodies.push(b);
            }
            r => unreachable!("grammar: if cannot contain {r:?}"),
        }
    }
    let height = depth + conds.len();
    if height > MAX_DEPTH {
        return too_deep(first_line, span, diags);
    }
    let mut otherwise = bodies.pop().expect("if has an else");
    loop {
        let (cond, start) = conds.pop().expect("one condition per `if`");
        let then = bodies.pop().expect("one body per condition");
        // An `else if` spans from its condition; the first, the whole.
        let at = if conds.is_empty() { span.start } else { start };
        let expr = Expr {
            span: Span::new(at, span.end),
            kind: ExprKind::If {
                cond: Box::new(cond),
                then,
                otherwise,
            },
        };
        if conds.is_empty() {
            return (expr, height);
        }
        otherwise = Body {
            lets: Vec::new(),
            value: Box::new(expr),
        };
    }
}
