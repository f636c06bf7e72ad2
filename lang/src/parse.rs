//! Source text → owned AST. pest's `Pairs` are converted here and never
//! leave this module.
//!
//! Hostile input is handled before pest sees it: nesting deeper than
//! [`MAX_NESTING`] (which would overflow the recursive-descent parser's stack)
//! and overlong operator chains are rejected with diagnostics.

use std::f64::consts::PI;

use pest::error::{ErrorVariant, InputLocation};
use pest::iterators::Pair;
use pest::pratt_parser::{Assoc, Op, PrattParser};
use pest::Parser as _;
use std::sync::OnceLock;

use crate::ast::*;
use crate::diag::{codes, Diag, Diagnostics};
use crate::span::Span;

#[derive(pest_derive::Parser)]
#[grammar = "sdfl.pest"]
struct SdflParser;

/// Deepest bracket nesting accepted.
pub const MAX_NESTING: usize = 64;
/// Most binary operators in one expression (a left-deep tree this tall is
/// walked recursively later).
pub const MAX_OPERATORS: usize = 512;
/// Longest run of unary minus signs.
const MAX_PREFIX_RUN: usize = 16;
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
    let mut offset = 0;
    let mut file = None;
    while diags.len() < MAX_SYNTAX_ERRORS {
        match SdflParser::parse(Rule::file, &text[offset..]) {
            Ok(mut pairs) => {
                if offset == 0 {
                    let root = pairs.next().expect("file rule always yields one pair");
                    file = Some(build_file(root, &mut diags));
                }
                break;
            }
            Err(e) => {
                let pos = offset
                    + match e.location {
                        InputLocation::Pos(p) => p,
                        InputLocation::Span((s, _)) => s,
                    };
                diags.push(syntax_error(text, pos, &e.variant));
                match next_item_start(text, pos) {
                    Some(next) => offset = next,
                    None => break,
                }
            }
        }
    }
    match file {
        Some(f) if diags.is_empty() => Ok(f),
        _ => Err(diags),
    }
}

/// Start of the next line after `pos` that begins (in column 0) with a
/// letter: where a top-level `let` or block may start.
fn next_item_start(text: &str, pos: usize) -> Option<usize> {
    let mut i = pos;
    while let Some(nl) = text[i..].find('\n') {
        i += nl + 1;
        if text[i..].starts_with(|c: char| c.is_ascii_alphabetic() || c == '_') {
            return Some(i);
        }
    }
    None
}

/// Reject input that would make the recursive parser or tree walkers
/// overflow their stacks.
fn prescan(text: &str) -> Option<Diag> {
    let bytes = text.as_bytes();
    let mut depth = 0usize;
    let mut minus_run = 0usize;
    let mut i = 0;
    while i < bytes.len() {
        let c = bytes[i];
        match c {
            b'"' => {
                i += 1;
                while i < bytes.len() && bytes[i] != b'"' && bytes[i] != b'\n' {
                    i += if bytes[i] == b'\\' { 2 } else { 1 };
                }
            }
            b'/' if bytes.get(i + 1) == Some(&b'/') => {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
            }
            b'/' if bytes.get(i + 1) == Some(&b'*') => {
                i += 2;
                while i + 1 < bytes.len() && !(bytes[i] == b'*' && bytes[i + 1] == b'/') {
                    i += 1;
                }
                i += 1;
            }
            b'(' | b'[' | b'{' => {
                depth += 1;
                if depth > MAX_NESTING {
                    return Some(
                        Diag::new(
                            codes::NESTING,
                            Span::new(i, i + 1),
                            format!("brackets nested more than {MAX_NESTING} deep"),
                        )
                        .label("too deep")
                        .help("bind inner parts to names with `let` to flatten the expression"),
                    );
                }
            }
            b')' | b']' | b'}' => depth = depth.saturating_sub(1),
            _ => {}
        }
        if c == b'-' {
            minus_run += 1;
            if minus_run > MAX_PREFIX_RUN {
                return Some(
                    Diag::new(
                        codes::NESTING,
                        Span::new(i, i + 1),
                        format!("more than {MAX_PREFIX_RUN} minus signs in a row"),
                    )
                    .label("too many")
                    .help("an even number of minus signs cancels out: remove them"),
                );
            }
        } else if !c.is_ascii_whitespace() {
            minus_run = 0;
        }
        i += 1;
    }
    None
}

fn describe_rule(rule: Rule) -> &'static str {
    match rule {
        Rule::EOI => "end of file",
        Rule::item | Rule::let_stmt | Rule::block => "`let` or a block like `render name { ... }`",
        Rule::field => "a field (`name: value`)",
        Rule::expr | Rule::postfixed => "an expression",
        Rule::call => "a call",
        Rule::arg => "an argument",
        Rule::list => "a list",
        Rule::for_expr => "`for`",
        Rule::binding => "a loop binding (`i in 0..n`)",
        Rule::range => "a range (`0..n`)",
        Rule::body => "`{`",
        Rule::number | Rule::number_value => "a number",
        Rule::unit => "a unit (`deg`)",
        Rule::string | Rule::string_inner => "a string",
        Rule::boolean => "`true` or `false`",
        Rule::ident | Rule::keyword => "a name",
        Rule::method => "a method call (`.name(...)`)",
        Rule::member => "a member (`.x`)",
        Rule::kw_let => "`let`",
        Rule::kw_for => "`for`",
        Rule::kw_in => "`in`",
        Rule::op_assign => "`=`",
        Rule::op_add | Rule::op_sub | Rule::op_mul | Rule::op_div | Rule::op_rem | Rule::op_pow => {
            "an operator"
        }
        Rule::op_neg => "`-`",
        Rule::range_inclusive => "`..=`",
        Rule::range_exclusive => "`..`",
        Rule::dot => "`.`",
        Rule::comma => "`,`",
        Rule::colon => "`:`",
        Rule::semicolon => "`;`",
        Rule::paren_open => "`(`",
        Rule::paren_close => "`)`",
        Rule::bracket_open => "`[`",
        Rule::bracket_close => "`]`",
        Rule::brace_open => "`{`",
        Rule::brace_close => "`}`",
        _ => "input",
    }
}

fn syntax_error(text: &str, pos: usize, variant: &ErrorVariant<Rule>) -> Diag {
    let mut expected: Vec<&str> = match variant {
        ErrorVariant::ParsingError { positives, .. } => {
            positives.iter().map(|r| describe_rule(*r)).collect()
        }
        ErrorVariant::CustomError { .. } => Vec::new(),
    };
    expected.sort_unstable();
    expected.dedup();
    // "an operator" is always possible after an operand and rarely the point.
    if expected.len() > 1 {
        expected.retain(|e| *e != "an operator");
    }
    let found = text[pos..].chars().next();
    let found_desc = match found {
        None => "end of file".to_string(),
        Some(c) if c.is_control() || !c.is_ascii() && !c.is_alphanumeric() => {
            format!("character U+{:04X}", c as u32)
        }
        Some(_) => {
            let token: String = text[pos..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .take(24)
                .collect();
            if token.is_empty() {
                format!("`{}`", found.unwrap())
            } else {
                format!("`{token}`")
            }
        }
    };
    let expected_desc = match expected.len() {
        0 => "something else".to_string(),
        1 => expected[0].to_string(),
        n => format!("{} or {}", expected[..n - 1].join(", "), expected[n - 1]),
    };
    let end = pos + found.map_or(0, char::len_utf8);
    let help = match found {
        Some('=') if expected.contains(&"`:`") => {
            "fields and named arguments are written `name: value`".to_string()
        }
        Some(c) if c.is_ascii_alphabetic() && expected.contains(&"`,`") => {
            "separate arguments and list elements with `,`".to_string()
        }
        None => "the file ended early: is a bracket or brace left open?".to_string(),
        _ if expected.contains(&"`)`")
            || expected.contains(&"`]`")
            || expected.contains(&"`}`") =>
        {
            "check that every bracket is closed and elements are separated by `,`".to_string()
        }
        _ => "see the language tour in README.md for the syntax".to_string(),
    };
    Diag::new(
        codes::SYNTAX,
        Span::new(pos, end),
        format!("expected {expected_desc}, found {found_desc}"),
    )
    .label(format!("expected {expected_desc}"))
    .help(help)
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

fn build_file(pair: Pair<Rule>, diags: &mut Diagnostics) -> File {
    let items = children(pair)
        .map(|p| match p.as_rule() {
            Rule::let_stmt => Item::Let(build_let(p, diags)),
            Rule::block => Item::Block(build_block(p, diags)),
            r => unreachable!("grammar: item cannot be {r:?}"),
        })
        .collect();
    File { items }
}

fn build_ident(pair: Pair<Rule>) -> Ident {
    Ident {
        name: pair.as_str().to_string(),
        span: span_of(&pair),
    }
}

fn build_let(pair: Pair<Rule>, diags: &mut Diagnostics) -> Let {
    let span = span_of(&pair);
    let mut it = children(pair);
    let name = build_ident(it.next().expect("let has a name"));
    let value = build_expr(it.next().expect("let has a value"), diags);
    Let { name, value, span }
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
                let value = build_expr(it.next().expect("field has a value"), diags);
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

fn pratt() -> &'static PrattParser<Rule> {
    static PRATT: OnceLock<PrattParser<Rule>> = OnceLock::new();
    PRATT.get_or_init(|| {
        PrattParser::new()
            .op(Op::infix(Rule::op_add, Assoc::Left) | Op::infix(Rule::op_sub, Assoc::Left))
            .op(Op::infix(Rule::op_mul, Assoc::Left)
                | Op::infix(Rule::op_div, Assoc::Left)
                | Op::infix(Rule::op_rem, Assoc::Left))
            .op(Op::prefix(Rule::op_neg))
            .op(Op::infix(Rule::op_pow, Assoc::Right))
    })
}

fn build_expr(pair: Pair<Rule>, diags: &mut Diagnostics) -> Expr {
    debug_assert_eq!(pair.as_rule(), Rule::expr);
    let span = span_of(&pair);
    let operators = pair
        .clone()
        .into_inner()
        .filter(|p| {
            matches!(
                p.as_rule(),
                Rule::op_add
                    | Rule::op_sub
                    | Rule::op_mul
                    | Rule::op_div
                    | Rule::op_rem
                    | Rule::op_pow
            )
        })
        .count();
    if operators > MAX_OPERATORS {
        diags.push(
            Diag::new(
                codes::NESTING,
                span,
                format!("expression has {operators} operators (at most {MAX_OPERATORS})"),
            )
            .label("too long")
            .help("split it into parts bound with `let`, or build the values with a `for`"),
        );
        return Expr {
            kind: ExprKind::Number(0.0),
            span,
        };
    }
    // The Pratt callbacks cannot borrow `diags` mutably together, so
    // conversion errors are gathered in a RefCell.
    let sink = std::cell::RefCell::new(std::mem::take(diags));
    let expr = pratt()
        .map_primary(|p| build_postfixed(p, &mut sink.borrow_mut()))
        .map_prefix(|op, rhs| Expr {
            span: span_of(&op).to(rhs.span),
            kind: ExprKind::Neg(Box::new(rhs)),
        })
        .map_infix(|lhs, op, rhs| {
            let bin = match op.as_rule() {
                Rule::op_add => BinOp::Add,
                Rule::op_sub => BinOp::Sub,
                Rule::op_mul => BinOp::Mul,
                Rule::op_div => BinOp::Div,
                Rule::op_rem => BinOp::Rem,
                Rule::op_pow => BinOp::Pow,
                r => unreachable!("grammar: {r:?} is not an infix operator"),
            };
            Expr {
                span: lhs.span.to(rhs.span),
                kind: ExprKind::Binary(bin, Box::new(lhs), Box::new(rhs)),
            }
        })
        .parse(pair.into_inner());
    *diags = sink.into_inner();
    expr
}

fn build_postfixed(pair: Pair<Rule>, diags: &mut Diagnostics) -> Expr {
    let mut it = children(pair);
    let mut expr = build_primary(it.next().expect("postfixed has an operand"), diags);
    for suffix in it {
        let span = expr.span.to(span_of(&suffix));
        match suffix.as_rule() {
            Rule::method => {
                let mut parts = children(suffix);
                let callee = build_ident(parts.next().expect("method has a name"));
                let mut args = vec![Arg {
                    name: None,
                    value: expr,
                }];
                args.extend(parts.map(|a| build_arg(a, diags)));
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
            r => unreachable!("grammar: {r:?} is not a postfix"),
        }
    }
    expr
}

fn build_arg(pair: Pair<Rule>, diags: &mut Diagnostics) -> Arg {
    let mut name = None;
    let mut value = None;
    for p in children(pair) {
        match p.as_rule() {
            Rule::ident => name = Some(build_ident(p)),
            Rule::expr => value = Some(build_expr(p, diags)),
            r => unreachable!("grammar: arg cannot contain {r:?}"),
        }
    }
    Arg {
        name,
        value: value.expect("arg has a value"),
    }
}

fn build_primary(pair: Pair<Rule>, diags: &mut Diagnostics) -> Expr {
    let span = span_of(&pair);
    let kind = match pair.as_rule() {
        Rule::number => build_number(pair, diags),
        Rule::string => build_string(pair, diags),
        Rule::boolean => ExprKind::Bool(pair.as_str() == "true"),
        Rule::ident => ExprKind::Var(build_ident(pair)),
        Rule::expr => return build_expr(pair, diags),
        Rule::list => ExprKind::List(children(pair).map(|p| build_expr(p, diags)).collect()),
        Rule::call => {
            let mut it = children(pair);
            let callee = build_ident(it.next().expect("call has a callee"));
            ExprKind::Call {
                callee,
                args: it.map(|a| build_arg(a, diags)).collect(),
                method: false,
            }
        }
        Rule::for_expr => build_for(pair, diags),
        r => unreachable!("grammar: {r:?} is not a primary"),
    };
    Expr { kind, span }
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

fn build_for(pair: Pair<Rule>, diags: &mut Diagnostics) -> ExprKind {
    let mut bindings = Vec::new();
    let mut body = None;
    for p in children(pair) {
        match p.as_rule() {
            Rule::binding => {
                let mut it = children(p);
                let var = build_ident(it.next().expect("binding has a variable"));
                let src = it.next().expect("binding has a source");
                let source = match src.as_rule() {
                    Rule::range => {
                        let mut r = children(src);
                        let start = build_expr(r.next().expect("range start"), diags);
                        let op = r.next().expect("range operator");
                        let end = build_expr(r.next().expect("range end"), diags);
                        Source::Range {
                            start,
                            end,
                            inclusive: op.as_rule() == Rule::range_inclusive,
                        }
                    }
                    Rule::expr => Source::List(build_expr(src, diags)),
                    r => unreachable!("grammar: binding source cannot be {r:?}"),
                };
                bindings.push(Binding { var, source });
            }
            Rule::body => {
                let mut lets = Vec::new();
                let mut value = None;
                for b in children(p) {
                    match b.as_rule() {
                        Rule::let_stmt => lets.push(build_let(b, diags)),
                        Rule::expr => value = Some(build_expr(b, diags)),
                        r => unreachable!("grammar: body cannot contain {r:?}"),
                    }
                }
                body = Some(Body {
                    lets,
                    value: Box::new(value.expect("body has a value")),
                });
            }
            r => unreachable!("grammar: for cannot contain {r:?}"),
        }
    }
    ExprKind::For {
        bindings,
        body: body.expect("for has a body"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn expr(src: &str) -> Expr {
        let f = parse(&format!("let x = {src}")).unwrap_or_else(|d| panic!("{d:?}"));
        match f.items.into_iter().next() {
            Some(Item::Let(l)) => l.value,
            _ => panic!("no let"),
        }
    }

    fn num(e: &Expr) -> f64 {
        match e.kind {
            ExprKind::Number(v) => v,
            _ => panic!("not a number: {e:?}"),
        }
    }

    #[test]
    fn numbers_with_exponents_and_degrees() {
        assert_eq!(num(&expr("1e-4")), 1e-4);
        assert_eq!(num(&expr(".5")), 0.5);
        assert_eq!(num(&expr("2.")), 2.0);
        assert!((num(&expr("180deg")) - PI).abs() < 1e-15);
    }

    #[test]
    fn precedence_and_associativity() {
        // -2^2 = -(2^2); 2^3^2 = 2^(3^2); 1-2-3 = (1-2)-3
        match expr("-2^2").kind {
            ExprKind::Neg(inner) => {
                assert!(matches!(inner.kind, ExprKind::Binary(BinOp::Pow, _, _)))
            }
            k => panic!("{k:?}"),
        }
        match expr("2^3^2").kind {
            ExprKind::Binary(BinOp::Pow, l, r) => {
                assert_eq!(num(&l), 2.0);
                assert!(matches!(r.kind, ExprKind::Binary(BinOp::Pow, _, _)));
            }
            k => panic!("{k:?}"),
        }
        match expr("1-2-3").kind {
            ExprKind::Binary(BinOp::Sub, l, r) => {
                assert!(matches!(l.kind, ExprKind::Binary(BinOp::Sub, _, _)));
                assert_eq!(num(&r), 3.0);
            }
            k => panic!("{k:?}"),
        }
    }

    #[test]
    fn ranges_are_not_numbers() {
        match expr("for i in 0..10 { i }").kind {
            ExprKind::For { bindings, .. } => match &bindings[0].source {
                Source::Range {
                    start,
                    end,
                    inclusive,
                } => {
                    assert_eq!((num(start), num(end), *inclusive), (0.0, 10.0, false));
                }
                s => panic!("{s:?}"),
            },
            k => panic!("{k:?}"),
        }
    }

    #[test]
    fn methods_desugar_to_calls() {
        match expr("sphere(1).translate([1, 0, 0])").kind {
            ExprKind::Call {
                callee,
                args,
                method,
            } => {
                assert_eq!(callee.name, "translate");
                assert!(method);
                assert_eq!(args.len(), 2);
                assert!(matches!(args[0].value.kind, ExprKind::Call { .. }));
            }
            k => panic!("{k:?}"),
        }
    }

    #[test]
    fn syntax_errors_are_all_reported() {
        let src = "let a = (1 +\nlet b = 2\nlet c = [1, 2\nlet d = 3\n";
        let d = parse(src).unwrap_err();
        assert_eq!(d.len(), 2, "{d:?}");
        assert!(d.diags.iter().all(|d| d.code == codes::SYNTAX));
    }

    #[test]
    fn deep_nesting_is_a_diagnostic() {
        let src = format!("let a = {}1{}", "(".repeat(100_000), ")".repeat(100_000));
        let d = parse(&src).unwrap_err();
        assert_eq!(d.diags[0].code, codes::NESTING);
    }

    #[test]
    fn long_operator_chains_are_a_diagnostic() {
        let src = format!("let a = 1{}", "+1".repeat(100_000));
        let d = parse(&src).unwrap_err();
        assert_eq!(d.diags[0].code, codes::NESTING);
    }
}
