//! The command line's modules (`src/`) and the peer benchmarks' (`bench/`)
//! import each other without loops, as the library crates' do (their
//! suites' `module_loops.rs`): a module that needs another's items sits
//! below it.

use std::path::Path;

#[path = "../support/module_graph.rs"]
mod module_graph;
use module_graph::{crate_graph, loops_found};

#[test]
fn cli_and_bench_modules_have_no_loops() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // Each crate, and one import the graph must see in it.
    for (krate, from, to) in [
        ("src", "sweep", "progress"),
        ("bench/src", "surface", "stats"),
    ] {
        let graph = crate_graph(&root.join(krate));
        assert!(
            graph.get(from).is_some_and(|uses| uses.contains(to)),
            "{krate}: {graph:?}"
        );
        let found = loops_found(&graph);
        assert!(
            found.is_empty(),
            "{krate}'s modules import each other in a loop: {found:?}"
        );
    }
}
