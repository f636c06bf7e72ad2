//! `sdfl fmt`: a file in the canonical layout, comments kept.
//!
//! The layout: two spaces of indentation; one top-level item a line, with
//! at most one empty line kept where the source had some; block fields
//! one a line as `name: value,`; spaces around binary operators and after
//! commas and colons; calls, lists, parameters and bodies on one line when
//! they fit in [`WIDTH`] columns, else one item a line with a trailing
//! comma; `;` after `let` and `import` dropped. Literals are kept as
//! written (`45deg`, `1e-4`, escapes) and so are parentheses.
//!
//! The layout is computed from the AST (every node kind is matched
//! exhaustively, so a new syntax does not compile until it is formatted)
//! while a cursor walks the source alongside, to pick up what the AST does
//! not keep: comments, empty lines and parentheses. The result is checked
//! before it is returned: it must parse to the same AST (spans aside) and
//! hold the same comments, else the file is reported, not changed.

// Public for the tests in lang/tests/suite only.
#[doc(hidden)]
pub mod doc;
#[doc(hidden)]
pub mod source;

use std::collections::HashMap;

use crate::ast::*;
use crate::diag::Diagnostics;
use crate::span::Span;
use doc::Doc;
use source::{trivia, Comment};

/// The line width the layout aims for.
pub const WIDTH: usize = 100;

/// Why a file could not be formatted.
#[derive(Debug)]
pub enum FormatError {
    /// The file does not parse: its syntax errors.
    Syntax(Diagnostics),
    /// The formatter would have changed the file's meaning or lost a
    /// comment (a bug in the formatter): what differed.
    Unsafe(String),
}

/// `text` in the canonical layout.
pub fn format(text: &str) -> Result<String, FormatError> {
    let file = crate::parse::parse(text).map_err(FormatError::Syntax)?;
    let formatted = layout(text, &file)?;
    let reparsed = crate::parse::parse(&formatted).map_err(|d| {
        FormatError::Unsafe(format!(
            "the formatted text does not parse ({} errors)",
            d.len()
        ))
    })?;
    if spanless(file) != spanless(reparsed) {
        return Err(FormatError::Unsafe(
            "the formatted text means something else".into(),
        ));
    }
    let trimmed = |t: &str| -> Vec<String> {
        source::comments(t)
            .iter()
            .map(|c| c.lines().map(str::trim_end).collect::<Vec<_>>().join("\n"))
            .collect()
    };
    if trimmed(text) != trimmed(&formatted) {
        return Err(FormatError::Unsafe(
            "a comment would be lost or moved out of order".into(),
        ));
    }
    Ok(formatted)
}

/// Lays out a parsed file.
fn layout(text: &str, file: &File) -> Result<String, FormatError> {
    let mut f = Formatter {
        text,
        pos: 0,
        parens: source::parentheses(text),
        error: None,
    };
    let mut docs = Vec::new();
    for (i, item) in file.items.iter().enumerate() {
        if i > 0 {
            docs.push(Doc::HardLine);
        }
        docs.push(f.item(item));
    }
    docs.push(f.leading());
    if let Some(e) = f.error {
        return Err(FormatError::Unsafe(e));
    }
    let mut out = doc::print(Doc::Concat(docs), WIDTH);
    let kept = out.trim_end().len();
    out.truncate(kept);
    if !out.is_empty() {
        out.push('\n');
    }
    Ok(out)
}

/// Builds a file's document while walking its source.
struct Formatter<'a> {
    text: &'a str,
    /// How far the source has been consumed.
    pos: usize,
    /// Matching parentheses, `(` → `)`.
    parens: HashMap<usize, usize>,
    /// The first place where the source did not hold what the AST said.
    error: Option<String>,
}

/// A consumed token: its text, with the comments before and after it.
struct Token {
    lead: Doc,
    text: String,
    trail: Doc,
}

impl Token {
    fn doc(self) -> Doc {
        Doc::Concat(vec![self.lead, Doc::Text(self.text), self.trail])
    }
    /// The token printed as `text` instead (a comma only when broken).
    fn printed_as(self, doc: Doc) -> Doc {
        Doc::Concat(vec![self.lead, doc, self.trail])
    }
}

fn comment_docs(comments: &[Comment], first_at_line_start: bool, docs: &mut Vec<Doc>) {
    for (i, c) in comments.iter().enumerate() {
        let own_line = c.newlines_before > 0 || (i == 0 && first_at_line_start);
        // A comment followed on its line by another (`/* a */ // b`): the
        // line ends after the last.
        let next_on_line = comments.get(i + 1).is_some_and(|n| n.newlines_before == 0);
        if own_line {
            docs.push(Doc::LineStart);
            if c.newlines_before > 1 {
                docs.push(Doc::Blank);
            }
        }
        match (own_line, c.ends_line && !next_on_line) {
            (_, true) => {
                docs.push(Doc::text(c.text));
                docs.push(Doc::HardLine);
            }
            (true, false) => docs.push(Doc::text(format!("{} ", c.text))),
            (false, false) => docs.push(Doc::Inline(c.text.to_string())),
        }
    }
}

impl<'a> Formatter<'a> {
    // ------------------------------------------------------------ the cursor

    /// The comments before the next token, consumed, as a document: own-line
    /// comments on their own lines (an empty line kept before one), block
    /// comments between tokens inline. An empty line before the token itself
    /// is kept too.
    fn leading(&mut self) -> Doc {
        self.leading_comments(true)
    }

    /// The comments before a closing bracket (no empty line before it).
    fn before_close(&mut self) -> Doc {
        self.leading_comments(false)
    }

    fn leading_comments(&mut self, keep_blank: bool) -> Doc {
        let (comments, next, newlines) = trivia(self.text, self.pos);
        let mut docs = Vec::new();
        comment_docs(&comments, self.pos == 0, &mut docs);
        if newlines > 1 && keep_blank {
            docs.push(Doc::Blank);
        }
        self.pos = next;
        Doc::Concat(docs)
    }

    /// Comments on the rest of the line after a token: printed at the end
    /// of its line (after a comma the layout adds, if any), breaking the
    /// enclosing groups so that the line ends there.
    fn trailing(&mut self) -> Doc {
        let (comments, _, _) = trivia(self.text, self.pos);
        // The comments left on the token's line, taken only when they end
        // it (else they stay before the next token), and kept as one suffix
        // (`/* a */ // b`): as two, the second would start a line of its own.
        let same_line = comments.iter().take_while(|c| c.newlines_before == 0);
        let line: Vec<_> = same_line.collect();
        match line.last() {
            Some(last) if last.ends_line => {
                self.pos = last.end;
                let text: Vec<&str> = line.iter().map(|c| c.text).collect();
                Doc::Concat(vec![Doc::LineSuffix(text.join(" ")), Doc::BreakParent])
            }
            _ => Doc::Concat(Vec::new()),
        }
    }

    /// The next token, which must be `expected` (else the error is noted).
    fn token(&mut self, expected: &str) -> Token {
        let lead = self.leading();
        if self.text[self.pos..].starts_with(expected) {
            self.pos += expected.len();
        } else if self.error.is_none() {
            self.error = Some(format!(
                "expected `{expected}` at byte {}, found `{}`",
                self.pos,
                self.text[self.pos..].chars().take(20).collect::<String>()
            ));
        }
        let trail = self.trailing();
        Token {
            lead,
            text: expected.to_string(),
            trail,
        }
    }

    /// The token `expected` if it comes next (an optional `,` or `;`).
    fn optional(&mut self, expected: &str) -> Option<Token> {
        let (_, next, _) = trivia(self.text, self.pos);
        self.text[next..]
            .starts_with(expected)
            .then(|| self.token(expected))
    }

    /// Whether the next token is the word `word`.
    fn next_is_word(&self, word: &str) -> bool {
        let (_, next, _) = trivia(self.text, self.pos);
        let rest = &self.text[next..];
        rest.starts_with(word)
            && !rest[word.len()..].starts_with(|c: char| c.is_ascii_alphanumeric() || c == '_')
    }

    /// The token written at `span` (a name or a literal), as written.
    fn atom(&mut self, span: Span) -> Doc {
        let lead = self.leading();
        if self.pos != span.start && self.error.is_none() {
            self.error = Some(format!(
                "expected a token at byte {}, at {}",
                span.start, self.pos
            ));
        }
        let text = self
            .text
            .get(span.start..span.end)
            .unwrap_or_default()
            .to_string();
        self.pos = self.pos.max(span.end);
        let trail = self.trailing();
        Doc::Concat(vec![lead, Doc::Text(text), trail])
    }

    // ------------------------------------------------------------- items

    fn item(&mut self, item: &Item) -> Doc {
        match item {
            Item::Let(l) => self.let_(l),
            Item::Block(b) => self.block(b),
            Item::Fn(f) => self.fn_def(f),
            Item::Import(i) => {
                let mut docs = vec![self.token("import").doc(), Doc::text(" ")];
                docs.push(self.atom(i.path_span));
                if let Some(semi) = self.optional(";") {
                    docs.push(semi.printed_as(Doc::Concat(Vec::new())));
                }
                Doc::Concat(docs)
            }
        }
    }

    fn let_(&mut self, l: &Let) -> Doc {
        let mut docs = vec![self.token("let").doc(), Doc::text(" ")];
        docs.push(self.atom(l.name.span));
        docs.push(Doc::text(" "));
        docs.push(self.token("=").doc());
        docs.push(Doc::text(" "));
        docs.push(self.expr(&l.value));
        if let Some(semi) = self.optional(";") {
            docs.push(semi.printed_as(Doc::Concat(Vec::new())));
        }
        Doc::Concat(docs)
    }

    fn block(&mut self, b: &Block) -> Doc {
        let mut docs = vec![self.atom(b.kind.span)];
        if let Some(name) = &b.name {
            docs.push(Doc::text(" "));
            docs.push(self.atom(name.span));
        }
        docs.push(Doc::text(" "));
        docs.push(self.token("{").doc());
        let mut fields = Vec::new();
        for field in &b.fields {
            fields.push(Doc::HardLine);
            fields.push(self.atom(field.name.span));
            fields.push(self.token(":").doc());
            fields.push(Doc::text(" "));
            fields.push(self.expr(&field.value));
            match self.optional(",") {
                Some(comma) => fields.push(comma.doc()),
                None => fields.push(Doc::text(",")),
            }
        }
        let closing = self.before_close();
        let empty = b.fields.is_empty() && matches!(&closing, Doc::Concat(d) if d.is_empty());
        if !empty {
            fields.push(closing);
            docs.push(Doc::indent(fields));
            docs.push(Doc::HardLine);
        }
        docs.push(self.token("}").doc());
        Doc::Concat(docs)
    }

    fn fn_def(&mut self, f: &FnDef) -> Doc {
        let mut docs = vec![self.token("fn").doc(), Doc::text(" ")];
        docs.push(self.atom(f.name.span));
        docs.push(self.delimited("(", f.params.len(), ")", |s, i| {
            let p = &f.params[i];
            let mut docs = vec![s.atom(p.name.span)];
            if let Some(default) = &p.default {
                docs.push(s.token(":").doc());
                docs.push(Doc::text(" "));
                docs.push(s.expr(default));
            }
            Doc::Concat(docs)
        }));
        docs.push(Doc::text(" "));
        docs.push(self.body(&f.body));
        Doc::Concat(docs)
    }

    /// `{ let ...; value }`: on one line if it has no `let`s and fits.
    /// Comments after the `}` are left out of the group.
    fn body(&mut self, body: &Body) -> Doc {
        let (parts, trail) = self.body_parts(body);
        Doc::Concat(vec![Doc::group(parts), trail])
    }

    /// A body's documents, and the comments after its `}`.
    fn body_parts(&mut self, body: &Body) -> (Vec<Doc>, Doc) {
        let open = self.token("{").doc();
        let mut inner = Vec::new();
        for l in &body.lets {
            inner.push(Doc::HardLine);
            inner.push(self.let_(l));
        }
        inner.push(Doc::Line);
        inner.push(self.expr(&body.value));
        inner.push(self.before_close());
        let close = self.token("}");
        let parts = vec![
            open,
            Doc::indent(inner),
            Doc::Line,
            close.lead,
            Doc::Text(close.text),
        ];
        (parts, close.trail)
    }

    /// `open item, item close`: on one line if it fits, else one item a
    /// line with a trailing comma.
    fn delimited(
        &mut self,
        open: &str,
        n: usize,
        close: &str,
        mut item: impl FnMut(&mut Self, usize) -> Doc,
    ) -> Doc {
        let open = self.token(open).doc();
        let mut inner = vec![Doc::SoftLine];
        for i in 0..n {
            inner.push(item(self, i));
            if i + 1 < n {
                inner.push(self.token(",").doc());
                inner.push(Doc::Line);
            } else {
                let comma = Doc::IfBreak(",");
                match self.optional(",") {
                    Some(t) => inner.push(t.printed_as(comma)),
                    None => inner.push(comma),
                }
            }
        }
        inner.push(self.before_close());
        let close = self.token(close);
        Doc::Concat(vec![
            Doc::group(vec![
                open,
                Doc::indent(inner),
                Doc::SoftLine,
                close.lead,
                Doc::Text(close.text),
            ]),
            close.trail,
        ])
    }

    // ------------------------------------------------------- expressions

    /// An expression with the parentheses written around it.
    fn expr(&mut self, e: &Expr) -> Doc {
        let mut docs = Vec::new();
        let mut parens = 0;
        loop {
            let (_, next, _) = trivia(self.text, self.pos);
            let wraps = self.text[next..].starts_with('(')
                && self
                    .parens
                    .get(&next)
                    .is_some_and(|&close| close >= e.span.end);
            if !wraps {
                break;
            }
            docs.push(self.token("(").doc());
            parens += 1;
        }
        docs.push(self.expr_inner(e));
        for _ in 0..parens {
            docs.push(self.token(")").doc());
        }
        Doc::Concat(docs)
    }

    /// A `.` after `receiver`: spaced from a bare whole number, which would
    /// otherwise take the dot as its decimal point.
    fn dot_after(&mut self, receiver: &Expr) -> Doc {
        let bare_integer = matches!(receiver.kind, ExprKind::Number(_))
            && self.text[receiver.span.start..receiver.span.end]
                .bytes()
                .all(|b| b.is_ascii_digit())
            && !self.text[trivia(self.text, receiver.span.end).1..].starts_with(')');
        let dot = self.token(".").doc();
        if bare_integer {
            Doc::Concat(vec![Doc::text(" "), dot])
        } else {
            dot
        }
    }

    fn args(&mut self, args: &[Arg]) -> Doc {
        self.delimited("(", args.len(), ")", |s, i| {
            let a = &args[i];
            let mut docs = Vec::new();
            if let Some(name) = &a.name {
                docs.push(s.atom(name.span));
                docs.push(s.token(":").doc());
                docs.push(Doc::text(" "));
            }
            docs.push(s.expr(&a.value));
            Doc::Concat(docs)
        })
    }

    fn expr_inner(&mut self, e: &Expr) -> Doc {
        match &e.kind {
            ExprKind::Number(_) | ExprKind::Bool(_) | ExprKind::Str(_) => self.atom(e.span),
            ExprKind::Var(name) => self.atom(name.span),
            ExprKind::List(items) => {
                self.delimited("[", items.len(), "]", |s, i| s.expr(&items[i]))
            }
            ExprKind::Call {
                callee,
                args,
                method,
            } => match (method, args.split_first()) {
                (true, Some((receiver, rest))) => {
                    let mut docs = vec![self.expr(&receiver.value)];
                    docs.push(self.dot_after(&receiver.value));
                    docs.push(self.atom(callee.span));
                    docs.push(self.args(rest));
                    Doc::Concat(docs)
                }
                (true, None) | (false, _) => {
                    let name = self.atom(callee.span);
                    Doc::Concat(vec![name, self.args(args)])
                }
            },
            ExprKind::Member(value, name) => {
                let mut docs = vec![self.expr(value)];
                docs.push(self.dot_after(value));
                docs.push(self.atom(name.span));
                Doc::Concat(docs)
            }
            ExprKind::Neg(value) => Doc::Concat(vec![self.token("-").doc(), self.expr(value)]),
            ExprKind::Not(value) => Doc::Concat(vec![self.token("!").doc(), self.expr(value)]),
            ExprKind::Index(list, index) => Doc::Concat(vec![
                self.expr(list),
                self.token("[").doc(),
                self.expr(index),
                self.token("]").doc(),
            ]),
            ExprKind::If { .. } => self.if_chain(e),
            ExprKind::Binary(op, left, right) => Doc::Concat(vec![
                self.expr(left),
                Doc::text(" "),
                self.token(op.symbol()).doc(),
                Doc::text(" "),
                self.expr(right),
            ]),
            ExprKind::For { bindings, body } => {
                let mut docs = vec![self.token("for").doc()];
                for (i, b) in bindings.iter().enumerate() {
                    if i > 0 {
                        docs.push(self.token(",").doc());
                    }
                    docs.push(Doc::text(" "));
                    docs.push(self.atom(b.var.span));
                    docs.push(Doc::text(" "));
                    docs.push(self.token("in").doc());
                    docs.push(Doc::text(" "));
                    match &b.source {
                        Source::Range {
                            start,
                            end,
                            inclusive,
                        } => {
                            docs.push(self.expr(start));
                            docs.push(self.token(if *inclusive { "..=" } else { ".." }).doc());
                            docs.push(self.expr(end));
                        }
                        Source::List(list) => docs.push(self.expr(list)),
                    }
                }
                docs.push(Doc::text(" "));
                docs.push(self.body(body));
                Doc::Concat(docs)
            }
        }
    }

    /// `if c { a } else if d { b } else { c }`: one group, so every body is
    /// on one line or every body broken. Walked as a loop: a long `else if`
    /// chain must not recurse.
    fn if_chain(&mut self, e: &Expr) -> Doc {
        let mut docs = Vec::new();
        let mut current = e;
        loop {
            let ExprKind::If {
                cond,
                then,
                otherwise,
            } = &current.kind
            else {
                self.error
                    .get_or_insert_with(|| "an `else if` holds no `if`".into());
                break;
            };
            docs.push(self.token("if").doc());
            docs.push(Doc::text(" "));
            docs.push(self.expr(cond));
            docs.push(Doc::text(" "));
            let (parts, trail) = self.body_parts(then);
            docs.extend(parts);
            docs.push(trail);
            docs.push(Doc::text(" "));
            docs.push(self.token("else").doc());
            docs.push(Doc::text(" "));
            if self.next_is_word("if") && otherwise.lets.is_empty() {
                current = &otherwise.value;
                continue;
            }
            let (parts, trail) = self.body_parts(otherwise);
            docs.extend(parts);
            return Doc::Concat(vec![Doc::group(docs), trail]);
        }
        Doc::group(docs)
    }
}

// ------------------------------------------------------- comparing trees

/// The tree with every span zeroed, to compare two parses of different text.
#[doc(hidden)]
pub fn spanless(mut file: File) -> File {
    for item in &mut file.items {
        erase_item(item);
    }
    file
}

fn erase_item(item: &mut Item) {
    match item {
        Item::Let(l) => erase_let(l),
        Item::Block(b) => {
            b.kind.span = Span::default();
            if let Some(n) = &mut b.name {
                n.span = Span::default();
            }
            for f in &mut b.fields {
                f.name.span = Span::default();
                erase_expr(&mut f.value);
            }
            b.span = Span::default();
        }
        Item::Fn(f) => {
            f.name.span = Span::default();
            for p in &mut f.params {
                p.name.span = Span::default();
                if let Some(d) = &mut p.default {
                    erase_expr(d);
                }
            }
            erase_body(&mut f.body);
            f.span = Span::default();
        }
        Item::Import(i) => {
            i.path_span = Span::default();
            i.span = Span::default();
        }
    }
}

fn erase_let(l: &mut Let) {
    l.name.span = Span::default();
    l.span = Span::default();
    erase_expr(&mut l.value);
}

fn erase_body(b: &mut Body) {
    b.lets.iter_mut().for_each(erase_let);
    erase_expr(&mut b.value);
}

fn erase_expr(e: &mut Expr) {
    e.span = Span::default();
    match &mut e.kind {
        ExprKind::Number(_) | ExprKind::Bool(_) | ExprKind::Str(_) => {}
        ExprKind::Var(id) => id.span = Span::default(),
        ExprKind::List(items) => items.iter_mut().for_each(erase_expr),
        ExprKind::Call { callee, args, .. } => {
            callee.span = Span::default();
            for a in args {
                if let Some(n) = &mut a.name {
                    n.span = Span::default();
                }
                erase_expr(&mut a.value);
            }
        }
        ExprKind::Member(value, name) => {
            erase_expr(value);
            name.span = Span::default();
        }
        ExprKind::Neg(value) | ExprKind::Not(value) => erase_expr(value),
        ExprKind::Index(a, b) | ExprKind::Binary(_, a, b) => {
            erase_expr(a);
            erase_expr(b);
        }
        ExprKind::If {
            cond,
            then,
            otherwise,
        } => {
            erase_expr(cond);
            erase_body(then);
            erase_body(otherwise);
        }
        ExprKind::For { bindings, body } => {
            for b in bindings {
                b.var.span = Span::default();
                match &mut b.source {
                    Source::Range { start, end, .. } => {
                        erase_expr(start);
                        erase_expr(end);
                    }
                    Source::List(list) => erase_expr(list),
                }
            }
            erase_body(body);
        }
    }
}
