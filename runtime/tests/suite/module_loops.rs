//! Modules import each other without loops: a module that needs
//! another's items sits below it. Among `data/`'s modules none is allowed
//! (issue 38 found capture ↔ colmap / llff / nerfstudio through
//! `inside()`, and image ↔ npy), nor among the runtime's top-level
//! modules. As `stdlib/tests/suite/module_loops.rs`
//! does for the standard library, from the source text: a module uses
//! another where its code (comments and `#[cfg(test)]` modules left out:
//! tests may reach anywhere) writes a path into it.

use std::path::Path;

#[path = "../../../tests/support/module_graph.rs"]
mod module_graph;
use module_graph::{crate_graph, folder_graph, loops_found};

#[test]
fn data_modules_have_no_loops() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/data");
    let graph = folder_graph(&data, &["data"]);
    // The graph sees the formats and what they share.
    assert!(graph["formats::llff"].contains("frames"));
    assert!(graph["formats"].contains("formats::llff"));
    let found = loops_found(&graph);
    assert!(
        found.is_empty(),
        "data/'s modules import each other in a loop: {found:?}"
    );
}

#[test]
fn no_data_format_imports_another() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/data");
    let graph = folder_graph(&data, &["data"]);
    let is_format = |m: &str| m.starts_with("formats::");
    assert!(graph.keys().filter(|m| is_format(m)).count() >= 5);
    for (m, uses) in graph.iter().filter(|(m, _)| is_format(m)) {
        let formats: Vec<&String> = uses.iter().filter(|u| is_format(u)).collect();
        assert!(formats.is_empty(), "{m} imports {formats:?}");
        // Nor the registry: what formats share lives beside it.
        assert!(!uses.contains("formats"), "{m} imports the registry");
    }
}

/// None either among the runtime's top-level modules (issue 38 found
/// nine in one loop; the last, `neural` ↔ `train`, went when each model
/// kind's checkpoint layout moved to `neural::layout` and the NDC frame's
/// check to the frame itself).
#[test]
fn runtime_modules_have_no_loops() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let graph = crate_graph(&src);
    assert!(graph["jobs"].contains("data") && graph["neural"].contains("train"));
    let found = loops_found(&graph);
    assert!(
        found.is_empty(),
        "the runtime's modules import each other in a loop: {found:?}"
    );
}
