//! Reading the source between the tokens the AST records: comments,
//! whitespace, punctuation and the parentheses the AST drops.

use std::collections::HashMap;

/// A comment as written.
#[derive(Debug, Clone, PartialEq)]
pub struct Comment<'a> {
    /// Its text, `//` or `/* */` included, trailing spaces dropped.
    pub text: &'a str,
    /// Line breaks between the text before it and it.
    pub newlines_before: usize,
    /// Whether a line break (or the end of the file, or a `//` comment)
    /// follows it on its line: always for `//` comments.
    pub ends_line: bool,
    /// Where it ends.
    pub end: usize,
}

/// Whitespace and comments from `pos`: the comments, then where the next
/// token starts and the line breaks right before it.
pub fn trivia(text: &str, mut pos: usize) -> (Vec<Comment<'_>>, usize, usize) {
    let mut comments = Vec::new();
    loop {
        let mut newlines = 0;
        while let Some(c) = text[pos..].chars().next() {
            match c {
                '\n' => newlines += 1,
                ' ' | '\t' | '\r' => {}
                _ => break,
            }
            pos += 1;
        }
        let rest = &text[pos..];
        let len = if rest.starts_with("//") {
            rest.find('\n').unwrap_or(rest.len())
        } else if let Some(body) = rest.strip_prefix("/*") {
            // Parsed files close every block comment.
            body.find("*/").map_or(rest.len(), |n| n + 4)
        } else {
            return (comments, pos, newlines);
        };
        let end = pos + len;
        let after = text[end..].trim_start_matches([' ', '\t', '\r']);
        comments.push(Comment {
            text: rest[..len].trim_end(),
            newlines_before: newlines,
            ends_line: rest.starts_with("//")
                || after.is_empty()
                || after.starts_with('\n')
                || after.starts_with("//"),
            end,
        });
        pos = end;
    }
}

/// Every comment of a parsed file, in order.
pub fn comments(text: &str) -> Vec<&str> {
    let mut all = Vec::new();
    let mut pos = 0;
    loop {
        let (found, next, _) = trivia(text, pos);
        all.extend(found.iter().map(|c| c.text));
        pos = next;
        match token_len(&text[pos..]) {
            0 => return all,
            n => pos += n,
        }
    }
}

/// The length of the token at the start of `rest` (0 at the end), enough to
/// skip strings (which may hold `//`, `(` or `"`) whole.
fn token_len(rest: &str) -> usize {
    let mut chars = rest.char_indices();
    match chars.next() {
        None => 0,
        Some((_, '"')) => {
            let mut escaped = false;
            for (i, c) in chars {
                match c {
                    '\\' if !escaped => escaped = true,
                    '"' if !escaped => return i + 1,
                    _ => escaped = false,
                }
            }
            rest.len()
        }
        Some((_, c)) => c.len_utf8(),
    }
}

/// The offsets of matching parentheses: `(` → `)`.
pub fn parentheses(text: &str) -> HashMap<usize, usize> {
    let mut pairs = HashMap::new();
    let mut open = Vec::new();
    let mut pos = 0;
    loop {
        pos = trivia(text, pos).1;
        match text[pos..].chars().next() {
            None => return pairs,
            Some('(') => open.push(pos),
            Some(')') => {
                if let Some(o) = open.pop() {
                    pairs.insert(o, pos);
                }
            }
            Some(_) => {}
        }
        pos += token_len(&text[pos..]);
    }
}
