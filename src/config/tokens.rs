//! The token table of both file kinds: names, aliases, argument shapes, where each is allowed,
//! and the order the `.ct` manual page documents.
//!
//! Tokens are matched as whole words (Performer 3.0 matched prefixes, which misread `remote.raw`
//! as a comment and `s_streams` as `s_stream` plus a stream named `s`; see docs/CONFIG.md).

/// The two kinds of configuration file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FileKind {
    /// A clip texture (`.ct`).
    ClipTexture,
    /// An image cache (`.ic`).
    ImageCache,
}

impl FileKind {
    /// Human name of the kind.
    pub(crate) fn noun(self) -> &'static str {
        match self {
            FileKind::ClipTexture => "clip texture (.ct)",
            FileKind::ImageCache => "image cache (.ic)",
        }
    }
}

/// Canonical identity of a token (aliases share one).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[allow(missing_docs)]
pub enum TokenId {
    CtVersion,
    IcVersion,
    ExtFormat,
    IntFormat,
    ImgFormat,
    /// `virt_size` in a `.ct`, `icache_size` in an `.ic` (each is the other's alias).
    Size,
    ClipSize,
    EffectiveLevels,
    AllocatedLevels,
    InvalidBorder,
    SmallestIcache,
    PhaseShift,
    PhaseMargin,
    IcacheBase,
    IcacheFormat,
    NumIcacheParams,
    IcacheParams,
    HeaderOffset,
    TileBase,
    TileFormat,
    NumTileParams,
    TileParams,
    IcacheFiles,
    TileFiles,
    TileSize,
    PageSize,
    ReadFunc,
    Lookahead,
    MemRegionSize,
    TexRegionSize,
    TexSize,
    TilesInFile,
    SStreams,
    TStreams,
    RStreams,
    NumStreams,
    DefaultTile,
}

/// The shape of a token's arguments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ArgShape {
    /// No argument (version tokens).
    None,
    /// One integer.
    Int,
    /// Up to three integers (S, T, R).
    Int3,
    /// A format name or number.
    Format,
    /// One word (a printf format, a file name).
    Word,
    /// One word, or nothing (the base tokens).
    Base,
    /// Words up to the next token.
    List,
    /// One or two words on the token's line (`read_func [dso] symbol`).
    ReadFunc,
    /// Obsolete: every following non-token word is skipped.
    SkipWords,
    /// Obsolete `num_streams`: up to three integers (S, T, R) on the same line, all ignored.
    NumStreams,
}

/// One row of the token table.
#[derive(Debug)]
pub struct TokenDef {
    /// Canonical identity.
    pub id: TokenId,
    /// Spelling this row matches.
    pub name: &'static str,
    /// Argument shape.
    pub args: ArgShape,
    /// Allowed in a `.ct`.
    pub in_ct: bool,
    /// Allowed in an `.ic`.
    pub in_ic: bool,
    /// Position in the `.ct` manual page's documented order (0: unordered / not in a `.ct`).
    pub ct_order: u8,
    /// The preferred spelling when this row is an alias.
    pub alias_of: Option<&'static str>,
    /// Obsolete: accepted and ignored.
    pub obsolete: bool,
}

const fn t(id: TokenId, name: &'static str, args: ArgShape, in_ct: bool, in_ic: bool, ct_order: u8) -> TokenDef {
    TokenDef { id, name, args, in_ct, in_ic, ct_order, alias_of: None, obsolete: false }
}

const fn alias(mut d: TokenDef, of: &'static str) -> TokenDef {
    d.alias_of = Some(of);
    d
}

const fn old(mut d: TokenDef) -> TokenDef {
    d.obsolete = true;
    d
}

use ArgShape as A;
use TokenId as I;

/// Every token of both file kinds.
pub static TOKENS: &[TokenDef] = &[
    t(I::CtVersion, "ct_version1.0", A::None, true, false, 1),
    t(I::CtVersion, "ct_version2.0", A::None, true, false, 1),
    t(I::IcVersion, "ic_version1.0", A::None, false, true, 0),
    t(I::IcVersion, "ic_version2.0", A::None, false, true, 0),
    t(I::ExtFormat, "ext_format", A::Format, true, true, 2),
    t(I::IntFormat, "int_format", A::Format, true, true, 3),
    t(I::ImgFormat, "img_format", A::Format, true, true, 4),
    t(I::Size, "virt_size", A::Int3, true, true, 5),
    t(I::Size, "icache_size", A::Int3, true, true, 5),
    t(I::ClipSize, "clip_size", A::Int, true, false, 6),
    t(I::EffectiveLevels, "effective_levels", A::Int, true, false, 7),
    t(I::AllocatedLevels, "allocated_levels", A::Int, true, false, 8),
    t(I::InvalidBorder, "invalid_border", A::Int, true, false, 9),
    t(I::SmallestIcache, "smallest_icache", A::Int3, true, false, 10),
    old(t(I::PhaseShift, "phase_shift", A::SkipWords, true, false, 0)),
    old(t(I::PhaseMargin, "phase_margin", A::SkipWords, true, false, 0)),
    t(I::IcacheBase, "icache_base", A::Base, true, false, 11),
    t(I::IcacheFormat, "icache_format", A::Word, true, false, 12),
    old(t(I::NumIcacheParams, "num_icache_params", A::Int, true, false, 13)),
    t(I::IcacheParams, "icache_params", A::List, true, false, 14),
    t(I::HeaderOffset, "header_offset", A::Int, true, true, 15),
    t(I::TileBase, "tile_base", A::Base, true, true, 16),
    t(I::TileFormat, "tile_format", A::Word, true, true, 17),
    old(t(I::NumTileParams, "num_tile_params", A::Int, true, true, 17)),
    t(I::TileParams, "tile_params", A::List, true, true, 18),
    t(I::IcacheFiles, "icache_files", A::List, true, false, 19),
    t(I::TileFiles, "tile_files", A::List, true, false, 20),
    t(I::TileSize, "tile_size", A::Int3, true, true, 21),
    t(I::PageSize, "page_size", A::Int, true, true, 21),
    t(I::ReadFunc, "read_func", A::ReadFunc, true, true, 22),
    t(I::Lookahead, "lookahead", A::Int, true, true, 23),
    t(I::MemRegionSize, "mem_region_size", A::Int3, false, true, 0),
    alias(t(I::MemRegionSize, "cache_size", A::Int3, false, true, 0), "mem_region_size"),
    t(I::TexRegionSize, "tex_region_size", A::Int3, false, true, 0),
    alias(t(I::TexRegionSize, "valid_region", A::Int3, false, true, 0), "tex_region_size"),
    t(I::TexSize, "tex_size", A::Int3, false, true, 0),
    alias(t(I::TexSize, "valid_region_dst", A::Int3, false, true, 0), "tex_size"),
    t(I::TilesInFile, "tiles_in_file", A::Int3, false, true, 0),
    t(I::SStreams, "s_streams", A::List, false, true, 0),
    alias(t(I::SStreams, "s_stream", A::List, false, true, 0), "s_streams"),
    t(I::TStreams, "t_streams", A::List, false, true, 0),
    alias(t(I::TStreams, "t_stream", A::List, false, true, 0), "t_streams"),
    t(I::RStreams, "r_streams", A::List, false, true, 0),
    alias(t(I::RStreams, "r_stream", A::List, false, true, 0), "r_streams"),
    old(t(I::NumStreams, "num_streams", A::NumStreams, false, true, 0)),
    t(I::DefaultTile, "default_tile", A::Word, false, true, 0),
];

/// Looks a whole word up in the token table.
pub fn lookup(word: &str) -> Option<&'static TokenDef> {
    TOKENS.iter().find(|d| d.name == word)
}

/// The preferred spelling of a token in a file kind (for messages).
pub fn preferred_name(id: TokenId, kind: FileKind) -> &'static str {
    match (id, kind) {
        (TokenId::Size, FileKind::ClipTexture) => "virt_size",
        (TokenId::Size, FileKind::ImageCache) => "icache_size",
        (TokenId::CtVersion, _) => "ct_version2.0",
        (TokenId::IcVersion, _) => "ic_version2.0",
        _ => TOKENS.iter().find(|d| d.id == id && d.alias_of.is_none()).map(|d| d.name).unwrap_or("?"),
    }
}

/// True when `word` starts a comment where a token is expected. The symbolic markers (`#`, `;`,
/// `//`) start a comment even when glued to the text (`#note`); the word markers (`comment`,
/// `rem`) only as whole words, so `remote.raw` is a file name, not a comment.
pub(crate) fn is_comment_start(word: &str) -> bool {
    word.starts_with('#') || word.starts_with(';') || word.starts_with("//") || word == "comment" || word == "rem"
}

/// True when `word` starts a comment inside a list or between numbers. Here a word starting with
/// `//` longer than the marker (`//server/share`) is a value, not a comment.
pub(crate) fn is_comment_in_value_position(word: &str) -> bool {
    word.starts_with('#') || word.starts_with(';') || word == "//" || word == "comment" || word == "rem"
}

/// Suggests the closest token name allowed in `kind` for a misspelled word.
pub(crate) fn suggest(word: &str, kind: FileKind) -> Option<&'static str> {
    let mut best: Option<(f64, &'static str)> = None;
    for d in TOKENS {
        let allowed = match kind {
            FileKind::ClipTexture => d.in_ct,
            FileKind::ImageCache => d.in_ic,
        };
        if !allowed {
            continue;
        }
        let score = strsim::jaro_winkler(word, d.name);
        if score > 0.85 && best.is_none_or(|(b, _)| score > b) {
            best = Some((score, d.name));
        }
    }
    best.map(|(_, n)| n)
}

/// If `word` is a token name glued to a value (`clip_size512`, Performer's prefix matching),
/// returns the token and the rest.
pub fn glued(word: &str) -> Option<(&'static TokenDef, &str)> {
    TOKENS
        .iter()
        .filter(|d| word.len() > d.name.len() && word.starts_with(d.name))
        .max_by_key(|d| d.name.len())
        .map(|d| (d, &word[d.name.len()..]))
}
