//! The language's tests against its public API, one module per module of
//! `lang/src`: one test binary that links the release library `cargo run
//! --release` built, instead of compiling the crate again in test mode.

mod check;
mod diag;
mod fmt;
mod fmt_doc;
mod fmt_source;
mod module_loops;
mod parse;
mod types;
