//! The sdfl standard library: the built-ins' signatures, docs and meaning,
//! the values a scene file evaluates to, and the scene IR (shapes,
//! materials, cameras, render jobs) handed to the runtime.
//!
//! [`load`] runs the whole front half of the pipeline:
//! parse → resolve imports → check → evaluate, reporting every error of the
//! file together.
#![warn(missing_docs)]

pub mod builtins;
pub mod camera;
pub mod camera_path;
pub mod density;
pub mod effects;
pub mod eval;
pub mod files;
pub mod imports;
pub mod lens;
pub mod limits;
pub mod material;
pub mod model;
pub mod num;
pub mod outputs;
pub mod param;
pub mod precision;
pub mod sdf;
pub mod shape;
pub mod size;
pub mod value;
pub mod work;

pub use builtins::StdEnv;
pub use value::{Output, OutputKind, Program, RenderJob, Value};

use sdfl_lang::{Diagnostics, SourceFile};

/// Parse, check and evaluate a scene file.
pub fn load(source: &SourceFile) -> Result<Program, Diagnostics> {
    load_warned(source).map(|(p, _)| p)
}

/// [`load`], with the warnings of a file that has no errors (a file with
/// errors reports its warnings among them).
pub fn load_warned(source: &SourceFile) -> Result<(Program, Diagnostics), Diagnostics> {
    let (file, sources) = imports::resolve(source);
    let located = |d| sources.locate(d);
    let file = file.map_err(located)?;
    let env = StdEnv::get();
    let mut diags = sdfl_lang::check::check(&file, env);
    if !diags.is_empty() {
        // The statements the checker passed are evaluated too, so that
        // their value errors come in the same report.
        let spans = diags.diags.iter().map(|d| d.span).collect();
        if let Some(evaluator) = eval::Evaluator::new(env).without_failed(&file, spans) {
            diags.diags.extend(match evaluator.run_warned(&file) {
                Ok((_, warnings)) => warnings.diags,
                Err(found) => found.diags,
            });
        }
        return Err(located(diags.sorted()));
    }
    eval::Evaluator::new(env)
        .with_base(input_base(source))
        .run_warned(&file)
        .map(|(p, w)| (p, located(w)))
        .map_err(located)
}

/// The directory input files are relative to, the scene file's, when the
/// source is a file on disk; a program built in memory (or read from
/// standard input) has none, and its inputs are checked only when run.
fn input_base(source: &SourceFile) -> Option<std::sync::Arc<std::path::Path>> {
    let path = source.disk_path();
    if !path.is_file() {
        return None;
    }
    Some(match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.into(),
        _ => std::path::Path::new(".").into(),
    })
}

/// [`load`] with top-level `let` bindings replaced by the given numbers
/// (`sdfl sweep`). Names that no top-level `let` binds are reported.
pub fn load_with(source: &SourceFile, overrides: &[(String, f64)]) -> Result<Program, Diagnostics> {
    let (file, sources) = imports::resolve(source);
    let file = file.map_err(|d| sources.locate(d))?;
    let env = StdEnv::get();
    let diags = sdfl_lang::check::check(&file, env);
    if !diags.is_empty() {
        return Err(sources.locate(diags));
    }
    let mut map = std::collections::HashMap::new();
    let mut missing = Diagnostics::default();
    for (name, v) in overrides {
        let bound = file
            .items
            .iter()
            .any(|i| matches!(i, sdfl_lang::ast::Item::Let(l) if &l.name.name == name));
        if !bound {
            missing.push(
                sdfl_lang::Diag::new(sdfl_lang::codes::UNKNOWN_NAME, sdfl_lang::Span::new(0, 0), format!("no top-level `let {name}` to set"))
                    .label("the file starts here")
                    .help(format!("sweeps replace `let` bindings: add `let {name} = ...` and use `{name}` where it matters")),
            );
        }
        map.insert(name.clone(), Value::Number(*v));
    }
    if !missing.is_empty() {
        return Err(missing);
    }
    eval::Evaluator::new(env)
        .with_base(input_base(source))
        .with_overrides(map)
        .run(&file)
        .map_err(|d| sources.locate(d))
}

/// Parse and check only (no evaluation): what `sdfl check` needs for
/// syntax and names. Value errors are found by [`load`].
pub fn check(source: &SourceFile) -> Result<(), Diagnostics> {
    let (file, sources) = imports::resolve(source);
    let file = file.map_err(|d| sources.locate(d))?;
    let diags = sdfl_lang::check::check(&file, StdEnv::get());
    if diags.is_empty() {
        Ok(())
    } else {
        Err(sources.locate(diags))
    }
}
