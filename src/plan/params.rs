//! File-name parameter tokens (`tile_params`, `icache_params`): names, types, and which file and
//! group each may appear in (docs/PERFORMER-REFERENCE.md §1.9).

use super::printf::ArgType;

/// A parameter token's meaning.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "SCREAMING_SNAKE_CASE")]
#[allow(missing_docs)]
pub enum Param {
    VsizeS,
    VsizeT,
    VsizeR,
    TilenumS,
    TilenumT,
    TilenumR,
    TileorgS,
    TileorgT,
    TileorgR,
    StreamServerName,
    CacheName,
    FilenumS,
    FilenumT,
    FilenumR,
    /// `PFCLIPTEX_FNAMEARG_LEVEL`.
    Level,
    /// `PFCLIPTEX_FNAMEARG_IMAGE_CACHE_BASE`.
    ImageCacheBase,
}

const IC: &str = "PFIMAGECACHE_TILE_FILENAMEARG_";

/// Every accepted spelling.
pub(crate) const NAMES: &[(&str, Param)] = &[
    ("PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S", Param::VsizeS),
    ("PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_T", Param::VsizeT),
    ("PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_R", Param::VsizeR),
    ("PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S", Param::TilenumS),
    ("PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T", Param::TilenumT),
    ("PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_R", Param::TilenumR),
    ("PFIMAGECACHE_TILE_FILENAMEARG_TILEORG_S", Param::TileorgS),
    ("PFIMAGECACHE_TILE_FILENAMEARG_TILEORG_T", Param::TileorgT),
    ("PFIMAGECACHE_TILE_FILENAMEARG_TILEORG_R", Param::TileorgR),
    ("PFIMAGECACHE_TILE_FILENAMEARG_STREAMSERVERNAME", Param::StreamServerName),
    ("PFIMAGECACHE_TILE_FILENAMEARG_CACHENAME", Param::CacheName),
    ("PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_S", Param::FilenumS),
    ("PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_T", Param::FilenumT),
    ("PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_R", Param::FilenumR),
    ("PFCLIPTEX_FNAMEARG_LEVEL", Param::Level),
    ("PFCLIPTEX_FNAMEARG_LEVEL_SIZE", Param::VsizeS),
    ("PFCLIPTEX_FNAMEARG_IMAGE_CACHE_BASE", Param::ImageCacheBase),
    ("PFCLIPTEX_FNAMEARG_TILE_BASE", Param::CacheName),
];

impl Param {
    /// Looks a spelling up.
    pub(crate) fn from_name(name: &str) -> Option<Param> {
        NAMES.iter().find(|(n, _)| *n == name).map(|&(_, p)| p)
    }

    /// True for the clip-texture-only spellings (`PFCLIPTEX_…`), which an `.ic` refuses.
    pub(crate) fn is_cliptex_spelling(name: &str) -> bool {
        name.starts_with("PFCLIPTEX_")
    }

    /// The closest known spelling, for "did you mean".
    pub(crate) fn suggest(name: &str) -> Option<&'static str> {
        // The clip texture manual's own examples misspell this one; string similarity alone
        // would point at the tile base instead.
        if name == "PFCLIPTEX_FNAMEARG_ICACHE_BASE" {
            return Some("PFCLIPTEX_FNAMEARG_IMAGE_CACHE_BASE");
        }
        NAMES
            .iter()
            .map(|&(n, _)| (strsim::jaro_winkler(name, n), n))
            .filter(|(s, _)| *s > 0.85)
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, n)| n)
    }

    /// The argument type the parameter provides.
    pub(crate) fn arg_type(self) -> ArgType {
        match self {
            Param::StreamServerName | Param::CacheName | Param::ImageCacheBase => ArgType::Str,
            _ => ArgType::Int,
        }
    }

    /// The canonical image-cache spelling (for messages).
    pub(crate) fn canonical(self) -> String {
        match self {
            Param::Level => "PFCLIPTEX_FNAMEARG_LEVEL".into(),
            Param::ImageCacheBase => "PFCLIPTEX_FNAMEARG_IMAGE_CACHE_BASE".into(),
            p => {
                let n = NAMES.iter().find(|&&(_, q)| q == p).map(|&(n, _)| n).unwrap_or("?");
                n.to_string()
            }
        }
    }

    /// Short name without the prefix.
    pub fn short(self) -> String {
        self.canonical().trim_start_matches(IC).trim_start_matches("PFCLIPTEX_FNAMEARG_").to_string()
    }
}

/// A parameter list entry with its spelling and place.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct ParamRef {
    /// The meaning.
    pub param: Param,
    /// As written.
    pub name: String,
    /// Where.
    pub span: crate::config::Span,
}
