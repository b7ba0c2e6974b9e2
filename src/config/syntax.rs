//! The syntax tree: what the user wrote, entry by entry, with a span on every value.
//!
//! Nothing here is interpreted: numbers are kept as written (already range-checked as `i64`),
//! names are not resolved, paths are not expanded. The plan stage does all of that.

use super::diag::Span;
use super::tokens::{FileKind, TokenDef, TokenId};
use std::path::PathBuf;

/// A value with the place it was written.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Spanned<T> {
    /// The value.
    pub value: T,
    /// Where it was written.
    pub span: Span,
}

/// The arguments of one entry, shaped by the token's [`ArgShape`](super::tokens::ArgShape).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Value {
    /// No argument.
    None,
    /// One integer.
    Int(Spanned<i64>),
    /// Up to three integers (fewer when the file gave fewer).
    Int3(Vec<Spanned<i64>>),
    /// One word.
    Word(Spanned<String>),
    /// A base: one word, or absent (empty string).
    Base(Option<Spanned<String>>),
    /// A list of words.
    List(Vec<Spanned<String>>),
    /// Arguments of an obsolete token, ignored.
    Ignored,
    /// The arguments could not be read (an error was reported).
    Missing,
}

/// One token with its arguments.
#[derive(Clone, Debug)]
pub struct Entry {
    /// The token's row in the table (gives its id and spelling).
    pub def: &'static TokenDef,
    /// Where the token was written.
    pub span: Span,
    /// Its arguments.
    pub value: Value,
}

impl Entry {
    /// The canonical token id.
    pub fn id(&self) -> TokenId {
        self.def.id
    }
}

/// One line of this engine's extension (docs/CONFIG.md §16): a comment to Performer, whose
/// first word is `#clipmap`, then a setting and its value.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Extension {
    /// Where `#clipmap` was written.
    pub span: Span,
    /// The words after it on its line (the setting, then its value), as written.
    pub words: Vec<Spanned<String>>,
}

/// A parsed file.
#[derive(Clone, Debug)]
pub struct SyntaxFile {
    /// The path as given to the reader.
    pub path: PathBuf,
    /// The kind of file expected.
    pub kind: FileKind,
    /// Every entry, in file order.
    pub entries: Vec<Entry>,
    /// Every `#clipmap` extension line, in file order.
    pub extensions: Vec<Extension>,
}

impl SyntaxFile {
    /// All entries with a given id, in file order.
    pub fn all(&self, id: TokenId) -> impl Iterator<Item = &Entry> {
        self.entries.iter().filter(move |e| e.def.id == id)
    }

    /// The last entry with a given id (repeated scalars: the last one wins).
    pub fn last(&self, id: TokenId) -> Option<&Entry> {
        self.entries.iter().rev().find(|e| e.def.id == id)
    }

    /// The first entry with a given id.
    pub fn first(&self, id: TokenId) -> Option<&Entry> {
        self.entries.iter().find(|e| e.def.id == id)
    }

    /// Index of the first entry with a given id.
    pub fn position(&self, id: TokenId) -> Option<usize> {
        self.entries.iter().position(|e| e.def.id == id)
    }
}
