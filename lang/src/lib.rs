//! The sdfl front end: source text → owned, spanned AST → checked program.
//!
//! This crate knows the syntax and the type system, never the built-ins'
//! meaning: the standard library supplies their signatures through
//! [`types::Env`]. It depends on neither the runtime nor dfdx.
#![warn(missing_docs)]

pub mod ast;
pub mod check;
pub mod diag;
pub mod fmt;
pub mod parse;
pub mod span;
pub mod types;

pub use diag::{codes, fmt_num, render, Diag, DiagData, Diagnostics, Severity, SourceFile};
pub use span::Span;
