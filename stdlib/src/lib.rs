//! The sdfl standard library: the built-ins' signatures, docs and meaning,
//! the values a scene file evaluates to, and the scene IR (shapes,
//! materials, cameras, render jobs) handed to the runtime.
//!
//! [`load`] runs the whole front half of the pipeline:
//! parse → check → evaluate, reporting every error of the file together.

pub mod builtins;
pub mod camera;
pub mod eval;
pub mod material;
pub mod shape;
pub mod value;

pub use builtins::StdEnv;
pub use value::{Output, OutputKind, Program, RenderJob, Value};

use sdfl_lang::{Diagnostics, SourceFile};

/// Parse, check and evaluate a scene file.
pub fn load(source: &SourceFile) -> Result<Program, Diagnostics> {
    let file = sdfl_lang::parse::parse(&source.text)?;
    let env = StdEnv::get();
    let diags = sdfl_lang::check::check(&file, env);
    if !diags.is_empty() {
        return Err(diags);
    }
    eval::Evaluator::new(env).run(&file)
}

/// Parse and check only (no evaluation): what `sdfl check` needs for
/// syntax and names. Value errors are found by [`load`].
pub fn check(source: &SourceFile) -> Result<(), Diagnostics> {
    let file = sdfl_lang::parse::parse(&source.text)?;
    let diags = sdfl_lang::check::check(&file, StdEnv::get());
    if diags.is_empty() {
        Ok(())
    } else {
        Err(diags)
    }
}
