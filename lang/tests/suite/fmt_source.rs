use sdfl_lang::fmt::source::*;

#[test]
fn comments_are_found_outside_strings_only() {
    let text = "let a = \"// no /* no\" // yes\n/* and\n this */ let b = (1)";
    assert_eq!(comments(text), ["// yes", "/* and\n this */"]);
}

#[test]
fn parentheses_match_across_strings() {
    let pairs = parentheses("f((a), \")\")");
    assert_eq!(pairs[&1], 10);
    assert_eq!(pairs[&2], 4);
}

#[test]
fn trivia_counts_line_breaks_and_sees_line_ends() {
    let (c, next, newlines) = trivia("  /* a */ x\n\n// b\n\n  y", 0);
    assert_eq!(c[0].text, "/* a */");
    assert!(!c[0].ends_line);
    assert_eq!(next, 10);
    assert_eq!(newlines, 0);
    let (c, next, newlines) = trivia("  /* a */ x\n\n// b\n\n  y", 11);
    assert_eq!(
        (c[0].text, c[0].newlines_before, c[0].ends_line),
        ("// b", 2, true)
    );
    assert_eq!((next, newlines), (21, 2));
}
