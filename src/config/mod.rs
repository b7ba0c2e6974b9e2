//! Stage one of reading a configuration: text → syntax tree.
//!
//! Owns the lexical rules (words, comments, whole-word tokens), the token table, and the
//! diagnostics type shared by both stages. It does no arithmetic, expands no variables and reads
//! no other file: that is [`crate::plan`]'s job.

pub mod diag;
pub mod lexer;
pub mod parse;
pub mod syntax;
pub mod tokens;

pub use diag::{Diagnostic, Diagnostics, Severity, Span};
pub use syntax::{Entry, Spanned, SyntaxFile, Value};
pub use tokens::{FileKind, TokenId};

use std::path::Path;

/// Every bound the reader enforces against hostile or broken input.
#[derive(Clone, Debug)]
pub struct Limits {
    /// Largest configuration file read (bytes). Real files are a few kilobytes.
    pub max_file_bytes: usize,
    /// Longest word (bytes). Performer's buffers held 255 (tokens) and 2047 (values).
    pub max_word_bytes: usize,
    /// Most entries (tokens) in one file.
    pub max_entries: usize,
    /// Most items in one list.
    pub max_list_items: usize,
    /// Most findings reported for one file before giving up.
    pub max_diagnostics: usize,
    /// Largest texture edge accepted (texels): 2^32.
    pub max_texture_size: u64,
    /// Largest tile edge accepted (texels).
    pub max_tile_size: u64,
    /// Most levels in a clip texture (Performer's `PFCLIPTEXTURE_MAX_LEVELS`).
    pub max_levels: u32,
    /// Largest mem region edge in tiles (Performer clamps to 128).
    pub max_mem_region_tiles: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_file_bytes: 4 << 20,
            max_word_bytes: 4096,
            max_entries: 10_000,
            max_list_items: 1024,
            max_diagnostics: 200,
            max_texture_size: 1 << 32,
            max_tile_size: 1 << 16,
            max_levels: 33,
            max_mem_region_tiles: 128,
        }
    }
}

/// Parses configuration text of a known kind.
pub fn parse_bytes(src: &[u8], path: &Path, kind: FileKind, limits: &Limits) -> (SyntaxFile, Diagnostics) {
    parse::parse(src, path, kind, limits)
}
