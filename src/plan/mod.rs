//! Stage two of reading a configuration: syntax tree → validated, immutable plan.
//!
//! [`load_clip_texture`] and [`load_image_cache`] read a file (and, for a `.ct`, every `.ic` it
//! names), check everything docs/PERFORMER-REFERENCE.md §1.15 checks and more, expand environment variables,
//! build and anchor every file name, and derive the per-level geometry. The result is a
//! [`ClipTexturePlan`] or [`ImageCachePlan`] that everything downstream borrows; nothing after this
//! module reads configuration text.

pub mod cog;
mod ct;
pub(crate) mod env;
mod fields;
pub(crate) mod formats;
pub mod georef;
mod height;
mod ic;
mod naming;
mod paging;
pub mod params;
pub mod printf;
pub mod source_line;
mod tile;
mod values;

pub use cog::CogPlan;
pub use env::Env;
pub use formats::FormatValue;
pub use height::{texel_of as height_texel, HeightPlan};
pub use naming::TileNaming;
pub use tile::{TileError, TileLocation};

use crate::config::{self, Diagnostic, Diagnostics, FileKind, Limits, Severity};
use crate::place::Place;
use crate::texel::TexelFormat;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// How to read: where variables come from, and the bounds.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// Environment for `$VAR` expansion.
    pub env: Env,
    /// Input bounds.
    pub limits: Limits,
    /// Check a `.ct` alone: the `.ic` files it names are resolved but not opened (their levels
    /// are [`LevelKind::IcacheNotOpened`]). For checking configurations where their data is not.
    pub ct_only: bool,
}

/// The result of loading: the plan when there was no error, all findings, and the text of every
/// file read (so findings can be shown with their source line).
#[derive(Debug)]
pub struct Loaded<T> {
    /// The plan, when no finding is an error.
    pub plan: Option<T>,
    /// Every finding, in every file read.
    pub diagnostics: Diagnostics,
    /// The bytes of every configuration file read, by path.
    pub sources: BTreeMap<PathBuf, Vec<u8>>,
}

impl<T> Loaded<T> {
    /// Renders every finding with its source line.
    pub fn render(&self) -> String {
        self.render_from(Severity::Note)
    }

    /// Renders the findings of at least `min` severity with their source lines.
    pub fn render_from(&self, min: Severity) -> String {
        self.diagnostics
            .items
            .iter()
            .filter(|d| d.severity >= min)
            .map(|d| d.render(self.sources.get(&d.path).map(|v| v.as_slice())))
            .collect()
    }
}

/// The top-level file could not be read at all (the tool could not run).
#[derive(Debug, thiserror::Error)]
#[error("cannot read {}: {source}", path.display())]
pub struct LoadError {
    /// The file.
    pub path: PathBuf,
    /// Why.
    #[source]
    pub source: std::io::Error,
}

/// A custom read function named in a configuration (not supported: the default reader is used).
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct ReadFunc {
    /// The library, for `read_func LIBRARY SYMBOL`.
    pub library: Option<String>,
    /// The symbol.
    pub symbol: String,
}

/// One image cache (one stack level, or a standalone `.ic`), fully resolved.
#[derive(Clone, Debug, Serialize)]
pub struct ImageCachePlan {
    /// The `.ic` file (absolute), or `None` when synthesised from the `.ct` (no-`.ic` mode).
    pub path: Option<PathBuf>,
    /// `ext_format`.
    pub ext_format: FormatValue,
    /// `int_format`.
    pub int_format: FormatValue,
    /// `img_format`.
    pub img_format: FormatValue,
    /// The texel format these give.
    pub texel: TexelFormat,
    /// Bytes per texel.
    pub bytes_per_texel: u32,
    /// Size of the cache (texels, S T R).
    pub size: [u64; 3],
    /// Size of one tile (texels).
    pub tile_size: [u64; 3],
    /// Tiles per file along S, T, R.
    pub tiles_in_file: [u64; 3],
    /// Bytes skipped at the start of each file.
    pub header_offset: u64,
    /// The part kept in texture memory (texels).
    pub tex_region: [u64; 3],
    /// The destination texture size (texels).
    pub tex_size: [u64; 3],
    /// The grid of tiles kept in main memory (tiles).
    pub mem_region: [u64; 3],
    /// Extra tile rows/columns in the mem region.
    pub lookahead: u64,
    /// Memory alignment for direct I/O (-1: default 4096; 0: no direct I/O).
    pub page_size: i64,
    /// Custom read function, if named.
    pub read_func: Option<ReadFunc>,
    /// How tile files are named.
    pub naming: TileNaming,
    /// Stream server path prefixes per axis (S, T, R).
    pub streams: [Vec<String>; 3],
    /// The default tile's file (absolute, or a remote location), if any.
    pub default_tile: Option<Place>,
    /// Fields that took their default value.
    pub defaulted: Vec<&'static str>,
    /// The COG its `#clipmap cog` line names (docs/COG.md), if any: its tiles are then read
    /// from the COG's level, not from the tile files named above.
    pub cog: Option<CogPlan>,
}

/// How a clip texture's level `.ic` files or pyramid files are named.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum GroupMode {
    /// Named by a printf format with parameters.
    Format,
    /// Named by an explicit list.
    FileList,
    /// Not named (image caches: no-`.ic` mode; pyramid: blank levels).
    None,
}

/// A pyramid level's single tile.
#[derive(Clone, Debug, Serialize)]
pub struct PyramidTile {
    /// The file (absolute, or a remote location), or `None` when the configuration names none.
    pub path: Option<Place>,
    /// Bytes skipped at the start of the file.
    pub header_offset: u64,
    /// Bytes of texels.
    pub length: u64,
}

/// What a level is made of.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum LevelKind {
    /// An image cache (a stack level in Performer's split).
    Icache(Box<ImageCachePlan>),
    /// A single tile holding the whole level.
    Pyramid(PyramidTile),
    /// An image cache whose `.ic` file was named but not opened ([`Options::ct_only`]): what only
    /// the `.ic` gives (tile size, regions, streams) is unknown. Never served.
    IcacheNotOpened {
        /// The `.ic` file the `.ct` names (absolute, variables expanded).
        path: PathBuf,
    },
}

/// One mipmap level of a clip texture.
#[derive(Clone, Debug, Serialize)]
pub struct Level {
    /// Level number, 0 the finest.
    pub level: u32,
    /// Size (texels, S T).
    pub size: [u64; 2],
    /// Its data.
    pub kind: LevelKind,
}

/// A clip texture, fully resolved.
#[derive(Clone, Debug, Serialize)]
pub struct ClipTexturePlan {
    /// The `.ct` file (absolute).
    pub path: PathBuf,
    /// The version token, if any.
    pub version: Option<String>,
    /// `ext_format`.
    pub ext_format: FormatValue,
    /// `int_format`.
    pub int_format: FormatValue,
    /// `img_format`.
    pub img_format: FormatValue,
    /// The texel format.
    pub texel: TexelFormat,
    /// Bytes per texel.
    pub bytes_per_texel: u32,
    /// Level-0 size (texels, S T R).
    pub virt_size: [u64; 3],
    /// Side of the window kept per clipped level.
    pub clip_size: u64,
    /// Invalid border (after Performer's raise to 8).
    pub invalid_border: u64,
    /// Levels the renderer addresses at once.
    pub effective_levels: u32,
    /// Levels given texture memory, as written (default 1000: all).
    pub allocated_levels: u32,
    /// Smallest image cache size (texels).
    pub smallest_icache: [u64; 3],
    /// Header bytes of pyramid files.
    pub header_offset: u64,
    /// Page size passed to the image caches.
    pub page_size: i64,
    /// Lookahead passed to the image caches.
    pub lookahead: u64,
    /// Paging policies, pool budget and centre clamp from the `#clipmap` extension lines
    /// (docs/CONFIG.md §16; the defaults without any).
    pub paging: crate::paging::PagingOptions,
    /// The heights the `#clipmap height…` lines declare (docs/CONFIG.md §17), `None` for a
    /// texture of colours.
    pub height: Option<HeightPlan>,
    /// Custom read function, if named.
    pub read_func: Option<ReadFunc>,
    /// `tile_size` of the `.ct` (used in no-`.ic` mode).
    pub tile_size: Option<[u64; 3]>,
    /// How the level `.ic` files are named.
    pub icache_mode: GroupMode,
    /// How the pyramid files are named.
    pub tile_mode: GroupMode,
    /// Every level, finest first.
    pub levels: Vec<Level>,
    /// True when `effective_levels` is less than the level count (a virtual clip texture).
    pub is_virtual: bool,
    /// Fields that took their default value.
    pub defaulted: Vec<&'static str>,
    /// The COG its `#clipmap cog` line names (docs/COG.md), if any: the texture is then the
    /// COG's, served as `clipmapd FILE.tif --clip CLIP_SIZE` serves it, and the levels above
    /// describe the configuration only (no tile file of theirs is read).
    pub cog: Option<CogPlan>,
    /// The tile pyramid its `#clipmap source` line names (docs/TILES.md), if any: the texture
    /// is then the pyramid's, served as `clipmapd NAME --clip CLIP_SIZE` serves it, and the
    /// levels above describe the configuration only (no tile file of theirs is read).
    pub source: Option<source_line::SourceLine>,
    /// Where the texture is on the Earth, as its `#clipmap georef_…` lines record it (a
    /// pyramid `clipprep` prepared from a georeferenced input; docs/GEOREF.md), if they do.
    #[serde(skip)]
    pub georef: Option<crate::georef::Georef>,
}

impl ClipTexturePlan {
    /// The level, if it exists.
    pub fn level(&self, level: u32) -> Option<&Level> {
        self.levels.get(level as usize)
    }

    /// Number of image-cache levels (opened or not).
    pub fn icache_levels(&self) -> usize {
        self.levels
            .iter()
            .filter(|l| matches!(l.kind, LevelKind::Icache(_) | LevelKind::IcacheNotOpened { .. }))
            .count()
    }

    /// True when some level's `.ic` was not opened ([`Options::ct_only`]): such a plan describes
    /// the configuration but cannot be served or checked against data.
    pub(crate) fn is_ct_only(&self) -> bool {
        self.levels.iter().any(|l| matches!(l.kind, LevelKind::IcacheNotOpened { .. }))
    }
}

fn read_source(path: &Path, limits: &Limits) -> std::io::Result<Vec<u8>> {
    // Regular files only, never blocking; one byte more than the limit so the parser can say
    // the file is too large.
    crate::open::read_bounded(path, limits.max_file_bytes as u64)
}

/// The absolute form of a path (without resolving symbolic links in the file name itself).
pub fn absolute(path: &Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

/// Loads a clip texture and every image cache it names.
pub fn load_clip_texture(path: &Path, opts: &Options) -> Result<Loaded<ClipTexturePlan>, LoadError> {
    let src = read_source(path, &opts.limits).map_err(|e| LoadError { path: path.to_path_buf(), source: e })?;
    let abs = absolute(path);
    let (file, mut diags) = config::parse_bytes(&src, &abs, FileKind::ClipTexture, &opts.limits);
    let mut sources = BTreeMap::new();
    sources.insert(abs.clone(), src);
    let plan = if diags.has_errors() && file.entries.is_empty() {
        None
    } else {
        ct::build(&file, opts, &mut diags, &mut sources)
    };
    let plan = if diags.has_errors() { None } else { plan };
    Ok(Loaded { plan, diagnostics: diags, sources })
}

/// Loads a standalone image cache.
pub fn load_image_cache(path: &Path, opts: &Options) -> Result<Loaded<ImageCachePlan>, LoadError> {
    let src = read_source(path, &opts.limits).map_err(|e| LoadError { path: path.to_path_buf(), source: e })?;
    let abs = absolute(path);
    let (file, mut diags) = config::parse_bytes(&src, &abs, FileKind::ImageCache, &opts.limits);
    let mut sources = BTreeMap::new();
    sources.insert(abs.clone(), src);
    // A file of which nothing could be read (binary data) is not built: its findings say so.
    let plan = if diags.has_errors() && file.entries.is_empty() {
        None
    } else {
        ic::build(&file, &ic::Context::standalone(), opts, &mut diags)
    };
    let plan = if diags.has_errors() { None } else { plan };
    Ok(Loaded { plan, diagnostics: diags, sources })
}

/// Checks the version token of a file: it must come first (a warning otherwise, as in 3.0).
fn check_version(r: &mut fields::Reader<'_>, kind: FileKind) {
    let want = match kind {
        FileKind::ClipTexture => config::TokenId::CtVersion,
        FileKind::ImageCache => config::TokenId::IcVersion,
    };
    let name = config::tokens::preferred_name(want, kind);
    match r.file.position(want) {
        None => {
            let d = r
                .diag(
                    Severity::Warning,
                    "missing-version",
                    Some(config::Span::START),
                    format!("the file does not start with a version token (`{name}`)"),
                )
                .hint(format!("add `{name}` as the first line; tools use it to tell the file kinds apart"));
            r.push(d);
        }
        Some(0) => {}
        Some(_) => {
            let span = r.span_of(want);
            let d = r
                .diag(Severity::Warning, "version-not-first", span, format!("`{name}` must begin the file"))
                .hint("move the version token to the first line");
            r.push(d);
        }
    }
}

/// A finding that is only about portability to Performer 3.0.
fn portability(mut d: Diagnostic) -> Diagnostic {
    d.portability = true;
    d
}
