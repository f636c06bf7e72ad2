//! The checker's typing of branches, conditions and operands, without
//! built-ins.

use sdfl_lang::check::*;
use sdfl_lang::types::*;
use sdfl_lang::types::{BlockSig, Signature};
use sdfl_lang::{codes, Diagnostics};

/// No built-ins: enough for the language's own constructs.
struct Empty;
impl Env for Empty {
    fn function(&self, _: &str) -> Option<&Signature> {
        None
    }
    fn block(&self, _: &str) -> Option<&BlockSig> {
        None
    }
    fn constant(&self, _: &str) -> Option<Type> {
        None
    }
    fn function_names(&self) -> Vec<&'static str> {
        Vec::new()
    }
    fn block_names(&self) -> Vec<&'static str> {
        Vec::new()
    }
    fn constant_names(&self) -> Vec<&'static str> {
        Vec::new()
    }
}

fn check_src(src: &str) -> Diagnostics {
    check(&sdfl_lang::parse::parse(src).expect("parses"), &Empty)
}

#[test]
fn branch_types_do_not_grow_with_functions() {
    // Each `fn` returns its argument's type or a list of it: a union
    // type of both would double at every level.
    let mut src = String::from("fn g0(c) { 1 }\n");
    for i in 1..200 {
        src.push_str(&format!(
            "fn g{i}(c) {{ if c {{ g{0}(c) }} else {{ [g{0}(c)] }} }}\n",
            i - 1
        ));
    }
    let t = std::time::Instant::now();
    assert!(check_src(&src).is_empty());
    assert!(t.elapsed().as_secs() < 5);
}

#[test]
fn conditions_and_operands_are_typed() {
    let d =
        check_src("let a = if 1 { 1 } else { 2 }\nlet b = !1\nlet c = true < 1\nlet d = [1][true]");
    assert_eq!(d.len(), 4, "{d:?}");
    assert!(d.diags.iter().all(|d| d.code == codes::TYPE));
    assert!(
        check_src("let a = if 1 < 2 && !(2 == 3) || false { [1, 2][0] } else { 3 }").is_empty()
    );
}
