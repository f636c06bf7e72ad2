use sdfl_lang::fmt::doc::*;

fn call(name: &str, args: &[&str]) -> Doc {
    let mut inner = vec![Doc::SoftLine];
    for (i, a) in args.iter().enumerate() {
        inner.push(Doc::text(*a));
        if i + 1 < args.len() {
            inner.push(Doc::text(","));
            inner.push(Doc::Line);
        } else {
            inner.push(Doc::IfBreak(","));
        }
    }
    Doc::group(vec![
        Doc::text(format!("{name}(")),
        Doc::indent(inner),
        Doc::SoftLine,
        Doc::text(")"),
    ])
}

#[test]
fn a_group_that_fits_stays_on_one_line() {
    assert_eq!(print(call("f", &["a", "b"]), 10), "f(a, b)");
}

#[test]
fn a_group_too_wide_puts_one_item_a_line_with_a_trailing_comma() {
    assert_eq!(
        print(call("f", &["aaaa", "bbbb"]), 10),
        "f(\n  aaaa,\n  bbbb,\n)"
    );
}

#[test]
fn text_after_a_group_counts_towards_its_width() {
    let doc = Doc::Concat(vec![call("f", &["a"]), Doc::text(".long_method_name()")]);
    assert_eq!(print(doc, 12), "f(\n  a,\n).long_method_name()");
}

#[test]
fn a_trailing_comment_lets_only_a_separator_join_its_line() {
    let doc = Doc::Concat(vec![
        Doc::text("a"),
        Doc::LineSuffix("// c".into()),
        Doc::text(","),
        Doc::text(" "),
        Doc::text("b"),
        Doc::HardLine,
        Doc::group(vec![
            Doc::text("x"),
            Doc::Line,
            Doc::text("y"),
            Doc::HardLine,
        ]),
    ]);
    assert_eq!(print(doc, 80), "a, // c\nb\nx\ny\n");
}

#[test]
fn blank_lines_are_kept_once_and_never_after_an_opener() {
    let doc = Doc::Concat(vec![
        Doc::text("{"),
        Doc::HardLine,
        Doc::Blank,
        Doc::text("a"),
        Doc::HardLine,
        Doc::Blank,
        Doc::Blank,
        Doc::text("b"),
    ]);
    assert_eq!(print(doc, 80), "{\na\n\nb");
}
