//! The parser on small sources: values, precedence, spans, and hostile
//! input refused with diagnostics.

use sdfl_lang::codes;
use std::f64::consts::PI;

use sdfl_lang::ast::*;
use sdfl_lang::parse::*;

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
