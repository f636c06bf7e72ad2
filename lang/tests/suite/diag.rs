use sdfl_lang::diag::*;
use sdfl_lang::{codes, Diag, Diagnostics, Span};

#[test]
fn a_diag_is_one_pointer() {
    // Results carrying it stay small (clippy's result_large_err).
    assert_eq!(std::mem::size_of::<Diag>(), std::mem::size_of::<usize>());
    assert_eq!(
        std::mem::size_of::<Result<(), Diag>>(),
        std::mem::size_of::<usize>()
    );
}

#[test]
fn numbers_print_short() {
    assert_eq!(fmt_num(1e308), "1e308");
    assert_eq!(fmt_num(-1e-46), "-1e-46");
    assert_eq!(fmt_num(0.25), "0.25");
    assert_eq!(fmt_num(1_000_000.0), "1000000");
    assert_eq!(fmt_num(2.5e9), "2.5e9");
    assert_eq!(fmt_num(0.0), "0");
    assert_eq!(fmt_num(f64::INFINITY), "inf");
}

#[test]
fn warnings_do_not_count_as_errors() {
    let mut d = Diagnostics::default();
    d.push(
        Diag::new(codes::MISSES_SCENE, Span::new(0, 1), "w")
            .label("l")
            .help("h"),
    );
    assert!(!d.has_errors());
    let src = SourceFile::new("f", "x");
    assert!(render(&src, &d, false).ends_with("1 warning in f\n"));
    d.push(
        Diag::new(codes::VALUE, Span::new(0, 1), "e")
            .label("l")
            .help("h"),
    );
    assert!(d.has_errors());
    assert!(render(&src, &d, false).ends_with("1 error in f\n"));
}

#[test]
fn diagnostics_in_imported_files_are_shown_there() {
    let main = SourceFile::new("main.sdfl", "import \"lib.sdfl\"\nlet a = 1\n");
    let lib = SourceFile::new("lib.sdfl", "let a = 2\n");
    let base = main.text.len() + 1;
    let mut d = Diagnostics::default();
    // In main, with a note in lib; and one in lib itself.
    d.push(
        Diag::new(codes::DUPLICATE_NAME, Span::new(22, 23), "twice")
            .label("again")
            .help("rename")
            .note(Span::new(base + 4, base + 5), "first"),
    );
    d.push(
        Diag::new(codes::TYPE, Span::new(base + 8, base + 9), "in lib")
            .label("here")
            .help("h"),
    );
    d.files.push((base, lib));
    assert_eq!(d.locate(Span::new(base + 8, base + 9)).1, Span::new(8, 9));
    assert!(d.locate(Span::new(3, 4)).0.is_none());
    let text = render(&main, &d, false);
    assert!(text.contains("[lib.sdfl:1:9]"), "{text}");
    assert!(text.contains("[main.sdfl:2:5]"), "{text}");
    assert!(text.contains("rename (first: lib.sdfl:1:5)"), "{text}");
}
