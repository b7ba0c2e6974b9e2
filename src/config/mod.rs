//! Stage one of reading a configuration: text → syntax tree.
//!
//! Owns the lexical rules (words, comments, whole-word tokens), the token table, and the
//! diagnostics type shared by both stages. It does no arithmetic, expands no variables and reads
//! no other file: that is [`crate::plan`]'s job.

pub(crate) mod diag;
pub(crate) mod lexer;
pub(crate) mod parse;
pub(crate) mod syntax;
pub mod tokens;

pub use diag::{Diagnostic, Diagnostics, Severity, Span};
pub use syntax::{Entry, Extension, Spanned, SyntaxFile, Value};
pub use tokens::{FileKind, TokenId};

use std::path::Path;

/// The reader's bounds ([`crate::limits::ConfigLimits`], with every other bound of the project).
pub use crate::limits::ConfigLimits as Limits;

/// Parses configuration text of a known kind.
pub fn parse_bytes(src: &[u8], path: &Path, kind: FileKind, limits: &Limits) -> (SyntaxFile, Diagnostics) {
    parse::parse(src, path, kind, limits)
}
