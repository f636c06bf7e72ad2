//! A small Wadler-style pretty printer: a document of text, breakable
//! lines and groups, laid out so that a group is printed on one line when
//! it fits the width and with each of its lines broken otherwise.
//!
//! Both the printer and its look-ahead (`fits`) walk the document with an
//! explicit stack, so a deeply nested file cannot overflow the call stack.

/// Spaces per indentation level.
pub const INDENT: usize = 2;

/// A document to lay out.
#[derive(Debug)]
pub enum Doc {
    /// Text without line breaks (a block comment may hold some).
    Text(String),
    /// A space when its group is flat, a line break when it is broken.
    Line,
    /// Nothing when its group is flat, a line break when it is broken.
    SoftLine,
    /// Always a line break; its groups are broken.
    HardLine,
    /// An empty line, when printed at the start of a line that does not
    /// follow an opening bracket or another empty line (else nothing).
    Blank,
    /// A line break unless the line printed so far is empty; its groups
    /// are broken (an own-line comment).
    LineStart,
    /// A block comment between tokens on one line: spaced from the text
    /// before it unless that ends in a space or an opening bracket.
    Inline(String),
    /// Text printed at the end of the current line (a trailing comment).
    LineSuffix(String),
    /// Breaks every enclosing group.
    BreakParent,
    /// Text printed only when its group is broken (a trailing comma).
    IfBreak(&'static str),
    /// Its contents indented one level further after each line break.
    Indent(Box<Doc>),
    /// Contents laid out flat if they fit, broken otherwise; `true` once
    /// they are known to contain a forced break.
    Group(Box<Doc>, bool),
    /// Documents one after another.
    Concat(Vec<Doc>),
}

impl Doc {
    /// `text` as a document.
    pub fn text(text: impl Into<String>) -> Doc {
        Doc::Text(text.into())
    }
    /// A group of `docs`.
    pub fn group(docs: Vec<Doc>) -> Doc {
        Doc::Group(Box::new(Doc::Concat(docs)), false)
    }
    /// `docs` indented.
    pub fn indent(docs: Vec<Doc>) -> Doc {
        Doc::Indent(Box::new(Doc::Concat(docs)))
    }
}

/// Marks every group holding a forced break as broken; returns whether
/// `doc` holds one. Recursive, but only as deep as the document (bounded by
/// the parser's nesting limits).
fn propagate_breaks(doc: &mut Doc) -> bool {
    match doc {
        Doc::HardLine | Doc::LineStart | Doc::BreakParent => true,
        Doc::Text(t) | Doc::Inline(t) => t.contains('\n'),
        Doc::Line | Doc::SoftLine | Doc::Blank | Doc::LineSuffix(_) | Doc::IfBreak(_) => false,
        Doc::Indent(d) => propagate_breaks(d),
        Doc::Group(d, broken) => {
            let inner = propagate_breaks(d);
            *broken |= inner;
            inner
        }
        Doc::Concat(ds) => ds
            .iter_mut()
            .fold(false, |any, d| propagate_breaks(d) | any),
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Mode {
    Flat,
    Break,
}

/// Characters of `text` up to its first line break, and whether it has one.
fn first_line_width(text: &str) -> (usize, bool) {
    match text.find('\n') {
        Some(n) => (text[..n].chars().count(), true),
        None => (text.chars().count(), false),
    }
}

fn is_opener(c: char) -> bool {
    matches!(c, '(' | '[' | '{')
}

/// Lays `doc` out within `width` columns.
pub fn print(mut doc: Doc, width: usize) -> String {
    propagate_breaks(&mut doc);
    let mut p = Printer {
        out: String::new(),
        suffixes: Vec::new(),
        space_before_token: false,
    };
    let mut stack: Vec<(usize, Mode, &Doc)> = vec![(0, Mode::Break, &doc)];
    while let Some((indent, mode, d)) = stack.pop() {
        match d {
            Doc::Text(t) => p.text(t, indent),
            Doc::Inline(t) => {
                // One space between two inline comments, not the first's
                // space and this one's.
                p.space_before_token = false;
                if !p
                    .out
                    .ends_with(|c: char| c == ' ' || c == '\n' || is_opener(c))
                    && !p.out.is_empty()
                {
                    p.out.push(' ');
                }
                p.text(t, indent);
                p.space_before_token = true;
            }
            Doc::Line => match mode {
                Mode::Flat => p.out.push(' '),
                Mode::Break => p.newline(indent),
            },
            Doc::SoftLine => {
                if mode == Mode::Break {
                    p.newline(indent);
                }
            }
            Doc::HardLine => p.newline(indent),
            Doc::LineStart => {
                if !p.at_line_start() {
                    p.newline(indent);
                }
            }
            Doc::Blank => p.blank(indent),
            Doc::LineSuffix(t) => {
                // Two trailing comments with only a separator between them:
                // the second starts a line of its own.
                if !p.suffixes.is_empty() {
                    p.newline(indent);
                }
                p.suffixes.push(t.clone());
            }
            Doc::BreakParent => {}
            Doc::IfBreak(t) => {
                if mode == Mode::Break {
                    p.text(t, indent);
                }
            }
            Doc::Indent(inner) => stack.push((indent + INDENT, mode, inner)),
            Doc::Group(inner, broken) => {
                let flat = !*broken
                    && (mode == Mode::Flat
                        || fits(inner, &stack, width.saturating_sub(p.column())));
                let mode = if flat { Mode::Flat } else { Mode::Break };
                stack.push((indent, mode, inner));
            }
            Doc::Concat(ds) => stack.extend(ds.iter().rev().map(|d| (indent, mode, d))),
        }
    }
    p.flush_suffixes();
    p.out
}

/// Whether `next`, laid out flat, and what follows it up to the next
/// possible line break fit in `room` columns.
fn fits(next: &Doc, rest: &[(usize, Mode, &Doc)], room: usize) -> bool {
    let mut room = room as isize;
    let mut stack: Vec<(Mode, &Doc)> = vec![(Mode::Flat, next)];
    let mut rest = rest.iter().rev();
    loop {
        let Some((mode, d)) = stack.pop().or_else(|| rest.next().map(|&(_, m, d)| (m, d))) else {
            return true;
        };
        match d {
            Doc::Text(t) => {
                let (w, newline) = first_line_width(t);
                room -= w as isize;
                if newline {
                    return room >= 0;
                }
            }
            Doc::Inline(t) => room -= first_line_width(t).0 as isize + 2,
            Doc::Line => match mode {
                Mode::Flat => room -= 1,
                Mode::Break => return true,
            },
            Doc::SoftLine => {
                if mode == Mode::Break {
                    return true;
                }
            }
            Doc::HardLine | Doc::LineStart => return true,
            // A trailing comment is printed on this line: it counts, or a
            // line that fits only without it would, formatted again from
            // its own output, be laid out otherwise.
            Doc::LineSuffix(t) => room -= first_line_width(t).0 as isize + 1,
            Doc::Blank | Doc::BreakParent => {}
            Doc::IfBreak(t) => {
                if mode == Mode::Break {
                    room -= t.len() as isize;
                }
            }
            Doc::Indent(inner) => stack.push((mode, inner)),
            Doc::Group(inner, broken) => {
                let mode = if *broken { Mode::Break } else { mode };
                stack.push((mode, inner));
            }
            Doc::Concat(ds) => stack.extend(ds.iter().rev().map(|d| (mode, d))),
        }
        if room < 0 {
            return false;
        }
    }
}

struct Printer {
    out: String,
    /// Trailing comments waiting for the end of the line.
    suffixes: Vec<String>,
    /// After an inline comment: a space before the next token, unless it
    /// is a separator or a closing bracket.
    space_before_token: bool,
}

/// Tokens that may follow a trailing comment's token on its line (the
/// comment moves after them) and that an inline comment is not spaced from.
fn is_separator(text: &str) -> bool {
    text.starts_with([',', ';', ')', ']', '}'])
}

impl Printer {
    /// Prints a token or spacing. A trailing comment waiting for the end of
    /// the line lets only a separator join its line: anything else starts
    /// a new line (the comment ends its line in the source too).
    fn text(&mut self, t: &str, indent: usize) {
        let blank = t.trim().is_empty();
        if !self.suffixes.is_empty() && !t.starts_with([',', ';']) {
            if blank {
                return;
            }
            self.newline(indent);
        }
        if std::mem::take(&mut self.space_before_token) && !blank && !is_separator(t) {
            self.out.push(' ');
        }
        self.out.push_str(t);
    }

    fn column(&self) -> usize {
        let line = self.out.rfind('\n').map_or(0, |n| n + 1);
        self.out[line..].chars().count()
    }
    fn current_line(&self) -> &str {
        let line = self.out.rfind('\n').map_or(0, |n| n + 1);
        &self.out[line..]
    }
    fn at_line_start(&self) -> bool {
        self.current_line().trim().is_empty() && self.suffixes.is_empty()
    }
    fn trim_end(&mut self) {
        let kept = self.out.trim_end_matches([' ', '\t']).len();
        self.out.truncate(kept);
    }
    fn flush_suffixes(&mut self) {
        if self.suffixes.is_empty() {
            return;
        }
        // At the start of a line the comment keeps the line's indentation.
        if !self.current_line().trim().is_empty() {
            self.trim_end();
            self.out.push(' ');
        }
        let suffixes = std::mem::take(&mut self.suffixes);
        self.out.push_str(&suffixes.join(" "));
    }
    /// A line break (only one: empty lines come from [`Doc::Blank`]).
    fn newline(&mut self, indent: usize) {
        self.space_before_token = false;
        self.flush_suffixes();
        self.trim_end();
        if self.out.is_empty() {
            return;
        }
        if !self.out.ends_with('\n') {
            self.out.push('\n');
        }
        self.out.extend(std::iter::repeat_n(' ', indent));
    }
    /// An empty line here, if this is the start of a line that does not
    /// follow an opening bracket, the file's start or an empty line.
    fn blank(&mut self, indent: usize) {
        if !self.at_line_start() {
            return;
        }
        self.trim_end();
        let before = self.out.trim_end_matches('\n');
        let after_blank = self.out.len() - before.len() >= 2;
        if before.is_empty() || after_blank || before.ends_with(is_opener) {
            self.out.extend(std::iter::repeat_n(' ', indent));
            return;
        }
        self.out.push('\n');
        self.out.extend(std::iter::repeat_n(' ', indent));
    }
}
