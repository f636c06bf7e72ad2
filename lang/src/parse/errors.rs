//! Syntax errors: the pre-scan that refuses runaway nesting before pest
//! sees it, where parsing resumes after an error, and the messages for
//! what pest rejects (unterminated strings and brackets named as such).

use super::*;

/// Start of the next line after `pos` that begins (in column 0) with a
/// letter: where a top-level `let` or block may start.
pub(super) fn next_item_start(text: &str, pos: usize) -> Option<usize> {
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
pub(super) fn prescan(text: &str) -> Option<Diag> {
    let bytes = text.as_bytes();
    let mut depth = 0usize;
    // `for`s whose body `{` has not been seen: each is a level of nesting
    // that no bracket shows (`for a in for b in [1] { 1 } { 2 }`).
    let mut open_fors = 0usize;
    let mut minus_run = 0usize;
    let mut i = 0;
    let is_ident = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    while i < bytes.len() {
        if let Some(last) = literal_end(bytes, i) {
            i = last + 1;
            minus_run = 0;
            continue;
        }
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

pub(super) fn syntax_error(text: &str, pos: usize, variant: &ErrorVariant<Rule>) -> Diag {
    if let Some(d) = unterminated(text, pos) {
        return d;
    }
    if let Some(d) = unit_error(text, pos) {
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

/// What a unit word after a number means in sdfl: `deg` is the only unit
/// (radians are the default, lengths are plain numbers in scene units).
#[derive(Clone, Copy, PartialEq)]
enum UnitWord {
    Degrees,
    Radians,
    Length,
}

fn unit_word(word: &str) -> Option<UnitWord> {
    match word {
        "deg" | "degs" | "degree" | "degrees" | "°" => Some(UnitWord::Degrees),
        "rad" | "rads" | "radian" | "radians" => Some(UnitWord::Radians),
        "mm" | "cm" | "m" | "km" | "px" => Some(UnitWord::Length),
        _ => None,
    }
}

/// The number literal ending at `end` (its start), if one does: digits and
/// `.`, with an exponent, not the tail of a name (`x1`).
fn number_before(text: &str, end: usize) -> Option<usize> {
    let b = text.as_bytes();
    let back = |mut i: usize| {
        while i > 0 && (b[i - 1].is_ascii_digit() || b[i - 1] == b'.') {
            i -= 1;
        }
        i
    };
    let mut i = back(end);
    if i == end {
        return None;
    }
    // An exponent: `1e-3`, `2E5`.
    let mut j = i;
    if j > 0 && matches!(b[j - 1], b'+' | b'-') {
        j -= 1;
    }
    if j > 0 && matches!(b[j - 1], b'e' | b'E') && back(j - 1) < j - 1 {
        i = back(j - 1);
    }
    let in_name = i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_');
    (!in_name && text[i..end].parse::<f64>().is_ok()).then_some(i)
}

/// A unit word at `pos` right after a number (`50mm`, `30 deg`), or the
/// word just before `pos` that was one (`let a = 30 deg` then a new line,
/// where the parser took `deg` for the start of a block): what to write.
fn unit_error(text: &str, pos: usize) -> Option<Diag> {
    let word_at = |at: usize| -> &str {
        let rest = &text[at..];
        if rest.starts_with('°') {
            return &rest[..'°'.len_utf8()];
        }
        let n = rest
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(rest.len());
        &rest[..n]
    };
    // The word at `pos`, else the one before it (back over whitespace).
    let before = text[..pos].trim_end();
    let word_start_before = before
        .rfind(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .map_or(0, |i| {
            i + before[i..].chars().next().map_or(1, char::len_utf8)
        });
    let candidates = [pos, word_start_before];
    let (start, word, kind) = candidates.into_iter().find_map(|at| {
        let word = word_at(at);
        unit_word(word).map(|k| (at, word, k))
    })?;
    // The number before the word, apart by spaces or tabs only.
    let gap_start = text[..start].trim_end_matches([' ', '\t']).len();
    let num_start = number_before(text, gap_start)?;
    let number = &text[num_start..gap_start];
    let apart = gap_start < start;
    let value: f64 = number.parse().ok()?;
    let span = Span::new(start, start + word.len());
    let field = text[..num_start].trim_end();
    let (message, label, help) = match kind {
        UnitWord::Degrees if word == "deg" => (
            "a unit is written right after its number".to_string(),
            "apart from its number".to_string(),
            format!("write `{number}deg`"),
        ),
        UnitWord::Degrees => (
            format!("`{word}` is not a unit: sdfl writes degrees as `deg`"),
            "not a unit".to_string(),
            format!("write `{number}deg`"),
        ),
        UnitWord::Radians => (
            format!("`{word}` is not a unit: angles are in radians unless marked `deg`"),
            "not a unit".to_string(),
            format!("write `{number}` (or `{number}deg` for degrees)"),
        ),
        UnitWord::Length if field.ends_with("focal:") && word == "mm" => (
            format!("`{word}` is not a unit: `focal` is in NDC units, not millimetres"),
            "not a unit".to_string(),
            format!(
                "1 is a 90° field of view (`focal = 1/tan(fov/2)`); a {number} mm lens on a 36 mm-wide sensor is `focal: {:.2}` (f/18)",
                value / 18.0
            ),
        ),
        UnitWord::Length => (
            format!("`{word}` is not a unit: lengths are plain numbers in scene units"),
            "not a unit".to_string(),
            format!("write `{number}`"),
        ),
    };
    let label = if apart && kind != UnitWord::Degrees {
        "a unit sdfl does not have".to_string()
    } else {
        label
    };
    Some(
        Diag::new(codes::UNIT, span, message)
            .label(label)
            .help(help),
    )
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
        if let Some(last) = literal_end(bytes, i) {
            i = last + 1;
            continue;
        }
        match bytes[i] {
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

/// Where a string or comment starting at `i` ends (its last byte; the end
/// of the text or of the line when unterminated), or `None` when none
/// starts there: what bracket and keyword scans skip, as the parser does.
fn literal_end(bytes: &[u8], mut i: usize) -> Option<usize> {
    match (bytes[i], bytes.get(i + 1)) {
        (b'"', _) => {
            i += 1;
            while i < bytes.len() && bytes[i] != b'"' && bytes[i] != b'\n' {
                i += if bytes[i] == b'\\' { 2 } else { 1 };
            }
        }
        (b'/', Some(b'/')) => {
            while i < bytes.len() && bytes[i] != b'\n' {
                i += 1;
            }
        }
        (b'/', Some(b'*')) => {
            i += 2;
            while i + 1 < bytes.len() && !(bytes[i] == b'*' && bytes[i + 1] == b'/') {
                i += 1;
            }
            i += 1;
        }
        _ => return None,
    }
    Some(i)
}
