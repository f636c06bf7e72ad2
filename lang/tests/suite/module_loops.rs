//! The language crate's top-level modules import each other without
//! loops, as the standard library's and the runtime's do (their
//! `module_loops.rs`): a module that needs another's items sits below it.

use std::path::Path;

#[path = "../../../tests/support/module_graph.rs"]
mod module_graph;
use module_graph::{crate_graph, loops_found};

#[test]
fn lang_modules_have_no_loops() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let graph = crate_graph(&src);
    // The graph sees the parser's use of the syntax tree.
    assert!(graph["parse"].contains("ast"), "{graph:?}");
    let found = loops_found(&graph);
    assert!(
        found.is_empty(),
        "lang's modules import each other in a loop: {found:?}"
    );
}
