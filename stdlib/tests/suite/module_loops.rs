//! The standard library's top-level modules import each other without
//! loops: a module that needs another's items sits below it. (Issue 23
//! found `builtins` ↔ `eval` ↔ `size`, `builtins` ↔ `camera_path` and
//! `material` ↔ `shape`.)

use std::path::Path;

#[path = "../../../tests/support/module_graph.rs"]
mod module_graph;
use module_graph::{arrows, crate_graph, loops};

/// Loops still open, each as its modules in order (none: `material` ↔
/// `shape` went when `ArgSource` moved to `param`, beside `Arg`).
const KNOWN: &[&[&str]] = &[];

#[test]
fn stdlib_modules_have_no_new_loops() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let graph = crate_graph(&src);
    assert!(graph.contains_key("builtins") && graph["eval"].contains("builtins"));
    for group in loops(&graph) {
        assert!(
            KNOWN.iter().any(|k| k.iter().eq(group.iter())),
            "modules import each other in a loop: {}",
            arrows(&graph, &group).join(", ")
        );
    }
}
