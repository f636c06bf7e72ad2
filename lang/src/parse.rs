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

#[derive(pest_derive::Parser)]
#[grammar = "sdfl.pest"]
struct SdflParser;

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
                // An error at the start of a line that starts an item (the
                // line before was incomplete): parsing resumes right there.
                let item_here = pos > offset
                    && (pos == 0 || text[..pos].ends_with('\n'))
                    && text[pos..].starts_with(|c: char| c.is_ascii_alphabetic() || c == '_');
                if item_here {
                    offset = pos;
                    continue;
                }
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
    // `for`s whose body `{` has not been seen: each is a level of nesting
    // that no bracket shows (`for a in for b in [1] { 1 } { 2 }`).
    let mut open_fors = 0usize;
    let mut minus_run = 0usize;
    let mut i = 0;
    let is_ident = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    while i < bytes.len() {
        let c = bytes[i];
        match c {
            // `for` and `if` open a level that lasts until their `{`.
            b'f' | b'i'
                if (i == 0 || !is_ident(bytes[i - 1]))
                    && [&b"for"[..], b"if"].iter().any(|kw| {
                        bytes[i..].starts_with(kw)
                            && !bytes.get(i + kw.len()).is_some_and(|b| is_ident(*b))
                    }) =>
            {
                let len = if c == b'f' { 3 } else { 2 };
                let kw = if c == b'f' { "for" } else { "if" };
                open_fors += 1;
                if depth + open_fors > MAX_NESTING {
                    return Some(
                        Diag::new(
                            codes::NESTING,
                            Span::new(i, i + len),
                            format!("`{kw}`s and brackets nested more than {MAX_NESTING} deep"),
                        )
                        .label("too deep")
                        .help("bind inner parts to names with `let` to flatten the expression"),
                    );
                }
                i += len - 1;
            }
            b'a'..=b'z' | b'A'..=b'Z' | b'_' | b'0'..=b'9' => {
                // Skip the rest of a name, so `xfor` or `for_x` is no `for`.
                while bytes.get(i + 1).is_some_and(|b| is_ident(*b)) {
                    i += 1;
                }
            }
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
                if c == b'{' {
                    open_fors = open_fors.saturating_sub(1);
                }
                depth += 1;
                if depth + open_fors > MAX_NESTING {
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
        // A run of prefix operators (`!` not starting `!=`).
        if c == b'-' || c == b'!' && bytes.get(i + 1) != Some(&b'=') {
            minus_run += 1;
            if minus_run > MAX_PREFIX_RUN {
                return Some(
                    Diag::new(
                        codes::NESTING,
                        Span::new(i, i + 1),
                        format!("more than {MAX_PREFIX_RUN} `-` or `!` signs in a row"),
                    )
                    .label("too many")
                    .help("an even number of `-` or `!` signs cancels out: remove them"),
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
        Rule::import_stmt => "`import`",
        Rule::fn_def => "`fn`",
        Rule::fn_param => "a parameter",
        Rule::if_expr => "`if`",
        Rule::index => "an index (`[i]`)",
        Rule::kw_if => "`if`",
        Rule::kw_else => "`else`",
        Rule::kw_fn => "`fn`",
        Rule::kw_import => "`import`",
        Rule::op_not => "`!`",
        Rule::field => "a field (`name: value`)",
        Rule::expr | Rule::postfixed => "an expression",
        Rule::call => "a call",
        Rule::arg => "an argument",
        Rule::list => "a list",
        Rule::for_expr => "`for`",
        Rule::binding => "a loop binding (`i in 0..n`)",
        Rule::range_end => "a range (`0..n`)",
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
        r if is_infix(r) => "an operator",
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
    if let Some(d) = unterminated(text, pos) {
        return d;
    }
    let mut expected: Vec<&str> = match variant {
        ErrorVariant::ParsingError { positives, .. } => {
            positives.iter().map(|r| describe_rule(*r)).collect()
        }
        ErrorVariant::CustomError { .. } => Vec::new(),
    };
    expected.sort_unstable();
    expected.dedup();
    // An operator, a method (`.`), an index (`[`) or a unit is always
    // possible after an operand and rarely the point; a minus sign is one
    // way to start an expression.
    for noise in ["an operator", "`.`", "`[`", "a unit (`deg`)"] {
        if expected.len() > 1 {
            expected.retain(|e| *e != noise);
        }
    }
    if expected.contains(&"an expression") {
        expected.retain(|e| *e != "`-`" && *e != "`!`");
    }
    let found = text[pos..].chars().next();
    let token: String = text[pos..]
        .chars()
        .take_while(|c| c.is_alphanumeric() || *c == '_')
        .take(24)
        .collect();
    let (found_desc, end) = match found {
        None => ("end of file".to_string(), pos),
        Some(c) if c.is_control() || !c.is_ascii() && !c.is_alphanumeric() => {
            (format!("character U+{:04X}", c as u32), pos + c.len_utf8())
        }
        Some(c) if token.is_empty() => (format!("`{c}`"), pos + c.len_utf8()),
        Some(_) => (format!("`{token}`"), pos + token.len()),
    };
    let expected_desc = match expected.len() {
        0 => "something else".to_string(),
        1 => expected[0].to_string(),
        n => format!("{} or {}", expected[..n - 1].join(", "), expected[n - 1]),
    };
    let line_of = |at: usize| text[..at].matches('\n').count() + 1;
    let at_line_start = text[..pos]
        .rsplit('\n')
        .next()
        .is_some_and(|before| before.trim().is_empty());
    // The innermost bracket still open, if the parser wanted it closed and
    // it was opened on an earlier line: the usual cause of an error at the
    // start of the next statement.
    let unclosed = innermost_unclosed(text, pos).filter(|(at, open)| {
        let close = match open {
            '(' => "`)`",
            '[' => "`]`",
            _ => "`}`",
        };
        expected.contains(&close) && (found.is_none() || line_of(*at) < line_of(pos))
    });
    let closer_of = |open: char| match open {
        '(' => ')',
        '[' => ']',
        _ => '}',
    };
    // A closing bracket the parser did not want: one too many, or the
    // wrong kind for the bracket that is open.
    let stray_closer = found
        .filter(|c| matches!(c, ')' | ']' | '}'))
        .filter(|c| !expected.contains(&format!("`{c}`").as_str()));
    let mut note = None;
    let help = match found {
        Some(c) if stray_closer.is_some() => match innermost_unclosed(text, pos) {
            Some((at, open)) if closer_of(open) != c => {
                note = Some((Span::new(at, at + 1), format!("this `{open}` is open")));
                format!(
                    "the `{open}` on line {} is closed with `{}`, not `{c}`",
                    line_of(at),
                    closer_of(open)
                )
            }
            _ => format!("this `{c}` closes no bracket: remove it, or open one before it"),
        },
        _ if unclosed.is_some() => {
            let (at, open) = unclosed.expect("checked");
            let close = closer_of(open);
            note = Some((
                Span::new(at, at + 1),
                format!("this `{open}` is not closed"),
            ));
            format!(
                "the `{open}` on line {} is never closed: add `{close}` where it ends",
                line_of(at)
            )
        }
        Some('=') if expected.contains(&"`:`") => {
            "fields and named arguments are written `name: value`".to_string()
        }
        Some(_) if at_line_start && expected.contains(&"an expression") => {
            "the line before ends in the middle of an expression: is something missing there?"
                .to_string()
        }
        Some(c) if c.is_ascii_alphanumeric() && expected.contains(&"`,`") => {
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
    let (message, label) = if let Some(c) = stray_closer {
        (
            format!("unexpected `{c}`"),
            format!("expected {expected_desc}"),
        )
    } else if expected.is_empty() {
        (
            format!("unexpected {found_desc}"),
            "unexpected here".to_string(),
        )
    } else {
        (
            format!("expected {expected_desc}, found {found_desc}"),
            format!("expected {expected_desc}"),
        )
    };
    let d = Diag::new(codes::SYNTAX, Span::new(pos, end), message)
        .label(label)
        .help(help);
    match note {
        Some((span, text)) => d.note(span, text),
        None => d,
    }
}

/// A string or block comment left open at `pos`, where the parser stopped:
/// pest reports only the `"` or the `*` it could not use.
fn unterminated(text: &str, pos: usize) -> Option<Diag> {
    let rest = &text[pos..];
    if rest.starts_with('"') {
        let line_end = rest.find('\n').unwrap_or(rest.len());
        let line = &rest[1..line_end];
        let mut escaped = false;
        let closed = line.chars().any(|c| {
            let quote = c == '"' && !escaped;
            escaped = c == '\\' && !escaped;
            quote
        });
        if !closed {
            return Some(
                Diag::new(
                    codes::SYNTAX,
                    Span::new(pos, pos + 1),
                    "string is not closed",
                )
                .label("this string has no closing `\"`")
                .help("end the string with `\"` on the same line: strings cannot span lines"),
            );
        }
    }
    let comment_at = if rest.starts_with("/*") {
        Some(pos)
    } else if rest.starts_with('*') && text[..pos].ends_with('/') {
        Some(pos - 1)
    } else {
        None
    };
    if let Some(at) = comment_at {
        if !text[at + 2..].contains("*/") {
            return Some(
                Diag::new(
                    codes::SYNTAX,
                    Span::new(at, at + 2),
                    "block comment is not closed",
                )
                .label("this comment has no closing `*/`")
                .help("end the comment with `*/` (block comments do not nest)"),
            );
        }
    }
    None
}

/// The innermost bracket opened before `pos` and not closed there, with its
/// offset (strings and comments skipped, as the parser does).
fn innermost_unclosed(text: &str, pos: usize) -> Option<(usize, char)> {
    let bytes = &text.as_bytes()[..pos];
    let mut stack = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
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
            c @ (b'(' | b'[' | b'{') => stack.push((i, c as char)),
            b')' | b']' | b'}' => {
                stack.pop();
            }
            _ => {}
        }
        i += 1;
    }
    stack.pop()
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

fn build_file(pair: Pair<Rule>, diags: &mut Diagnostics) -> File {
    let items = children(pair)
        .map(|p| match p.as_rule() {
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
    fn tall_expressions_are_one_diagnostic() {
        let bindings: Vec<String> = (0..5000).map(|i| format!("i{i} in [1]")).collect();
        for src in [
            format!("let a = sphere(){}", ".scale(1)".repeat(100_000)),
            format!("let a = v{}", ".x".repeat(100_000)),
            format!("let a = for {} {{ 1 }}", bindings.join(", ")),
            format!(
                "let a = {}1{}",
                "(1^".repeat(60).replace('^', &"1^".repeat(500)),
                ")".repeat(60)
            ),
            format!(
                "let a = {}[1]{}",
                "for x in ".repeat(100),
                " {1}".repeat(100)
            ),
        ] {
            let d = parse(&src).unwrap_err();
            assert_eq!(d.len(), 1, "{d:?}");
            assert_eq!(d.diags[0].code, codes::NESTING);
        }
        // As deep as allowed is fine.
        let src = format!("let a = sphere(){}", ".scale(1)".repeat(MAX_DEPTH - 2));
        assert!(parse(&src).is_ok());
    }

    #[test]
    fn nested_loop_sources_parse_in_linear_time() {
        // Trying `start..end` before a list parsed each source twice: 2^30.
        let mut e = String::from("[1]");
        for i in 0..30 {
            e = format!("[for i{i} in {e} {{ 1 }}]");
        }
        assert!(parse(&format!("let a = {e}")).is_ok());
        let f = parse("let a = for i in 1..=3, j in [1, 2] { i }").unwrap();
        let Item::Let(l) = &f.items[0] else { panic!() };
        let ExprKind::For { bindings, .. } = &l.value.kind else {
            panic!()
        };
        assert!(matches!(
            bindings[0].source,
            Source::Range {
                inclusive: true,
                ..
            }
        ));
        assert!(matches!(bindings[1].source, Source::List(_)));
    }

    #[test]
    fn an_error_at_the_start_of_an_item_resumes_there() {
        // The second `let` starts where the first one's error is found.
        let d = parse("let a = 1 +\nlet b = [1 2]\n").unwrap_err();
        assert_eq!(d.len(), 2, "{d:?}");
    }

    #[test]
    fn long_operator_chains_are_a_diagnostic() {
        let src = format!("let a = 1{}", "+1".repeat(100_000));
        let d = parse(&src).unwrap_err();
        assert_eq!(d.diags[0].code, codes::NESTING);
    }

    #[test]
    fn comparisons_sit_below_arithmetic_and_logic_lowest() {
        // a + 1 < b || c && !d == e  =  ((a + 1) < b) || (c && ((!d) == e))
        let ExprKind::Binary(BinOp::Or, l, r) = expr("a + 1 < b || c && !d == e").kind else {
            panic!()
        };
        let ExprKind::Binary(BinOp::Lt, ll, _) = &l.kind else {
            panic!("{l:?}")
        };
        assert!(matches!(ll.kind, ExprKind::Binary(BinOp::Add, _, _)));
        let ExprKind::Binary(BinOp::And, _, rr) = &r.kind else {
            panic!("{r:?}")
        };
        let ExprKind::Binary(BinOp::Eq, not, _) = &rr.kind else {
            panic!("{rr:?}")
        };
        assert!(matches!(not.kind, ExprKind::Not(_)));
        for (src, op) in [
            ("a <= b", BinOp::Le),
            ("a >= b", BinOp::Ge),
            ("a != b", BinOp::Ne),
            ("a > b", BinOp::Gt),
        ] {
            assert!(
                matches!(expr(src).kind, ExprKind::Binary(o, _, _) if o == op),
                "{src}"
            );
        }
    }

    #[test]
    fn if_with_parentheses_parses() {
        // This reported "`{` is never closed" before `if` existed.
        let e = expr("if (x > 1) { 1 } else { 2 }");
        assert!(matches!(e.kind, ExprKind::If { .. }));
        // `else if` nests in the `else` branch.
        let ExprKind::If { otherwise, .. } =
            expr("if a { 1 } else if b { 2 } else { let c = 3; c }").kind
        else {
            panic!()
        };
        let ExprKind::If { otherwise, .. } = &otherwise.value.kind else {
            panic!()
        };
        assert_eq!(otherwise.lets.len(), 1);
        // `else` is required: an `if` is an expression.
        let d = parse("let x = if a { 1 }").unwrap_err();
        assert!(d.diags[0].message.contains("`else`"), "{d:?}");
    }

    #[test]
    fn long_else_if_chains_are_a_diagnostic_not_an_overflow() {
        let src = format!(
            "let a = if x {{ 1 }}{} else {{ 2 }}",
            " else if x { 1 }".repeat(100_000)
        );
        let d = parse(&src).unwrap_err();
        assert_eq!(d.diags[0].code, codes::NESTING);
        assert!(parse(&format!("let a = {}1", "!".repeat(100_000))).is_err());
        let src = format!(
            "let a = {}1{}",
            "if x { 1 } else { ".repeat(10_000),
            " }".repeat(10_000)
        );
        assert_eq!(parse(&src).unwrap_err().diags[0].code, codes::NESTING);
        let src = format!(
            "let a = {}x{}",
            "if ".repeat(10_000),
            " { 1 } else { 2 }".repeat(10_000)
        );
        assert_eq!(parse(&src).unwrap_err().diags[0].code, codes::NESTING);
    }

    #[test]
    fn functions_imports_and_indexing() {
        let f = parse(
            "import \"lib/a.sdfl\"\nfn blob(r, k: 2,) { let x = r * k; x }\nlet y = xs[1][i + 1]",
        )
        .unwrap();
        let Item::Import(i) = &f.items[0] else {
            panic!()
        };
        assert_eq!(i.path, "lib/a.sdfl");
        let Item::Fn(func) = &f.items[1] else {
            panic!()
        };
        assert_eq!(func.name.name, "blob");
        assert_eq!(func.params.len(), 2);
        assert!(func.params[0].default.is_none() && func.params[1].default.is_some());
        assert_eq!(func.body.lets.len(), 1);
        let Item::Let(l) = &f.items[2] else { panic!() };
        let ExprKind::Index(inner, _) = &l.value.kind else {
            panic!()
        };
        assert!(matches!(inner.kind, ExprKind::Index(_, _)));
        // Keywords are not names.
        assert!(parse("let fn = 1").is_err());
        assert!(parse("let iffy = 1\nlet importance = 2").is_ok());
    }
}
