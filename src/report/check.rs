//! `cliptex check`: can the data on disk serve every tile a clip texture names?
//!
//! Owns walking every tile of every level through the plan's file names and byte offsets and
//! sorting each into present, missing, short, unreadable or (compressed tiles that do not decode
//! to one tile) corrupt, and telling which missing or short tiles an image cache's default tile
//! covers (as [`crate::source::FileSource`] would serve them). It opens each file once, the way
//! the service does ([`crate::open::regular`]); it looks at the sizes of raw tile files without
//! reading their texels, and decodes every compressed tile as the service would. Printing is
//! the tool's business, apart from the text rendering here.

use crate::place::Place;
use crate::plan::{ClipTexturePlan, ImageCachePlan, LevelKind, TileLocation};
use serde::Serialize;
use std::collections::HashMap;
use std::fmt::Write;
use std::io;
use std::path::PathBuf;

pub use crate::limits::MAX_LISTED_PROBLEMS;

/// What is wrong with one tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Problem {
    /// Its file does not exist (or the level names no file).
    Missing,
    /// Its file ends before the tile does.
    Short,
    /// Its file exists but cannot be opened.
    Unreadable,
    /// Its file is a compressed tile (`.raw.zst`) that does not decode to exactly one tile.
    Corrupt,
}

/// One tile that cannot be read from its file.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct TileProblem {
    /// Level.
    pub level: u32,
    /// Tile column.
    pub s: u64,
    /// Tile row.
    pub t: u64,
    /// The file (absent when the level names none).
    pub path: Option<Place>,
    /// What is wrong.
    pub problem: Problem,
    /// Whether the level's default tile stands in for it.
    pub default_covered: bool,
    /// What the reader said, where it said more than the problem's name (a COG's damaged tile).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub detail: Option<String>,
}

/// An image cache's default tile, checked.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct DefaultTileCheck {
    /// The file.
    pub path: Place,
    /// Whether it can be served (readable, one tile long, or one tile after the header).
    pub usable: bool,
    /// Why not, when it cannot.
    pub error: Option<String>,
}

/// Tile counts of one level (or of all levels).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Counts {
    /// Tiles the level has.
    pub tiles: u64,
    /// Tiles whose file holds them whole.
    pub present: u64,
    /// Tiles whose file does not exist.
    pub missing: u64,
    /// Tiles whose file is too short.
    pub short: u64,
    /// Tiles whose file cannot be opened.
    pub unreadable: u64,
    /// Compressed tiles whose file is not a zstd frame of one tile.
    pub corrupt: u64,
    /// Missing or short tiles the default tile stands in for.
    pub default_covered: u64,
}

impl Counts {
    /// Tiles that can be served (present, or covered by the default tile).
    pub fn servable(&self) -> u64 {
        self.present + self.default_covered
    }

    fn add(&mut self, o: &Counts) {
        self.tiles += o.tiles;
        self.present += o.present;
        self.missing += o.missing;
        self.short += o.short;
        self.unreadable += o.unreadable;
        self.corrupt += o.corrupt;
        self.default_covered += o.default_covered;
    }
}

/// One level, checked.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct LevelCheck {
    /// Level number.
    pub level: u32,
    /// `image_cache` or `pyramid`.
    pub kind: &'static str,
    /// Level size in texels.
    pub size: [u64; 2],
    /// Tile counts.
    #[serde(flatten)]
    pub counts: Counts,
    /// The default tile, if the level's `.ic` names one.
    pub default_tile: Option<DefaultTileCheck>,
}

/// The whole check.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct CheckReport {
    /// The `.ct`.
    pub path: PathBuf,
    /// True when every tile can be served.
    pub servable: bool,
    /// Per level, finest first.
    pub levels: Vec<LevelCheck>,
    /// Sums over the levels.
    pub totals: Counts,
    /// The first [`MAX_LISTED_PROBLEMS`] problem tiles.
    pub problems: Vec<TileProblem>,
    /// Problem tiles not listed.
    pub problems_not_listed: u64,
}

/// What opening a file found: its length, or the problem every tile in it has and what the
/// reader said about it (a remote store's error, where it said more than the problem's name).
type FileState = Result<u64, (Problem, Option<String>)>;

fn probe(place: &Place) -> FileState {
    let path = match place {
        Place::Local(path) => path,
        Place::Remote(name) => return remote_probe::length(name),
    };
    match crate::open::regular(path) {
        Ok((_, m)) => Ok(m.len()),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Err((Problem::Missing, None)),
        Err(e) => Err((Problem::Unreadable, Some(e.to_string()))),
    }
}

/// A compressed tile file (docs/COMPRESSED-TILES.md): its length, when it decodes to exactly
/// one `tile`-byte tile. Decoded the very way the service reads it, through the same byte seam
/// ([`crate::source::file::read_stored`] over a local file or a remote object read by name), so
/// that `check` and the service agree on which frames are good; `buf` is reused between files.
fn probe_compressed(place: &Place, offset: u64, tile: u64, buf: &mut Vec<u8>) -> FileState {
    use crate::source::file::read_stored;
    use crate::source::range::LocalFile;
    use crate::source::{SourceError, TileId};
    buf.resize(tile as usize, 0);
    let id = TileId::new(0, 0, 0);
    let (decoded, len) = match place {
        Place::Local(path) => {
            let (file, meta) = match crate::open::regular(path) {
                Ok(f) => f,
                Err(e) if e.kind() == io::ErrorKind::NotFound => return Err((Problem::Missing, None)),
                Err(e) => return Err((Problem::Unreadable, Some(e.to_string()))),
            };
            (read_stored(&LocalFile(file), place, id, offset, buf), meta.len())
        }
        Place::Remote(name) => {
            let remote = match remote_probe::by_name() {
                Ok(r) => r,
                Err(why) => return Err((Problem::Unreadable, Some(why))),
            };
            (read_stored(&*remote.reader(name), place, id, offset, buf), offset + tile)
        }
    };
    match decoded {
        Ok(()) => Ok(len),
        Err(SourceError::Undecodable { .. }) => Err((Problem::Corrupt, None)),
        Err(SourceError::Missing { .. }) => Err((Problem::Missing, None)),
        Err(e) => Err((Problem::Unreadable, Some(e.to_string()))),
    }
}

fn check_default(ic: &ImageCachePlan, place: &Place) -> DefaultTileCheck {
    let tile = ic.tile_bytes();
    let len = match place {
        Place::Local(path) => crate::open::regular(path).map(|(_, m)| m.len()).map_err(|e| e.to_string()),
        Place::Remote(name) => remote_probe::length_or_error(name),
    };
    let error = match len {
        Err(e) => Some(e),
        Ok(n) if n == tile || (ic.header_offset > 0 && n == tile + ic.header_offset) => None,
        Ok(n) => Some(format!("{n} bytes: expected {tile} (one tile)")),
    };
    DefaultTileCheck { path: place.clone(), usable: error.is_none(), error }
}

/// Remote locations, checked the way [`crate::source::remote`] reads them: the length of an
/// object by HEAD, a compressed tile by reading it by name and decoding it; one reader (and its
/// connections) for the whole check, with the `CLIPMAP_REMOTE_*` options.
#[cfg(feature = "remote")]
mod remote_probe {
    use super::{FileState, Problem};
    use crate::place::RemoteName;
    use crate::source::range::ByName;
    use crate::source::remote::{ReadError, Remote, RemoteOptions};
    use std::sync::OnceLock;

    fn remote() -> Result<&'static Remote, String> {
        static R: OnceLock<Result<Remote, String>> = OnceLock::new();
        R.get_or_init(|| {
            let opts = RemoteOptions::from_env().map_err(|e| e.to_string())?;
            Remote::new(RemoteOptions { cache_dir: None, ..opts }).map_err(|e| e.to_string())
        })
        .as_ref()
        .map_err(|e| e.clone())
    }

    pub(crate) fn length_or_error(name: &RemoteName) -> Result<u64, String> {
        remote()?.length(name.as_str()).map_err(|e| e.to_string())
    }

    /// The object's length; a failure keeps the store's message (a refused credential, a bad
    /// endpoint, a TLS failure), not only the problem's name.
    pub fn length(name: &RemoteName) -> FileState {
        let r = remote().map_err(|why| (Problem::Unreadable, Some(why)))?;
        match r.length(name.as_str()) {
            Ok(n) => Ok(n),
            Err(ReadError::NotFound { .. }) => Err((Problem::Missing, None)),
            Err(e) => Err((Problem::Unreadable, Some(e.to_string()))),
        }
    }

    /// The reader of remote objects by name, or why the options allow none.
    pub(crate) fn by_name() -> Result<&'static dyn ByName, String> {
        remote().map(|r| r as &dyn ByName)
    }
}

/// Without the `remote` feature a remote location cannot be opened.
#[cfg(not(feature = "remote"))]
mod remote_probe {
    use super::{FileState, Problem};
    use crate::place::RemoteName;

    const WHY: &str = "a remote location, and this build cannot read them (the `remote` feature)";

    pub(crate) fn length_or_error(_: &RemoteName) -> Result<u64, String> {
        Err(WHY.to_string())
    }

    pub fn length(_: &RemoteName) -> FileState {
        Err((Problem::Unreadable, Some(WHY.to_string())))
    }

    /// None: this build reads no remote objects.
    pub(crate) fn by_name() -> Result<&'static dyn crate::source::range::ByName, String> {
        Err(WHY.to_string())
    }
}

/// Number of tiles of every level (for a progress bar's length).
pub fn tile_count(plan: &ClipTexturePlan) -> u64 {
    plan.levels
        .iter()
        .map(|l| match &l.kind {
            LevelKind::Icache(ic) => ic.tile_count().iter().product(),
            LevelKind::Pyramid(_) => 1,
            LevelKind::IcacheNotOpened { .. } => 0,
        })
        .sum()
}

/// Checks every tile of `plan`; `progress` is told the number of tiles checked since its last
/// call.
pub fn run(plan: &ClipTexturePlan, progress: &dyn Fn(u64)) -> CheckReport {
    let mut files: HashMap<Place, FileState> = HashMap::new();
    let mut problems = Vec::new();
    let mut not_listed = 0u64;
    let mut levels = Vec::with_capacity(plan.levels.len());
    let mut totals = Counts::default();
    let mut scratch = Vec::new();
    for l in &plan.levels {
        let mut counts = Counts::default();
        let (kind, default_tile, tiles) = match &l.kind {
            LevelKind::Icache(ic) => {
                let d = ic.default_tile.as_ref().map(|p| check_default(ic, p));
                let n = ic.tile_count();
                ("image_cache", d, [n[0], n[1]])
            }
            LevelKind::Pyramid(_) => ("pyramid", None, [1, 1]),
            // Only a `.ct`-only plan has these, and `check` loads every `.ic`.
            LevelKind::IcacheNotOpened { .. } => ("image_cache_not_opened", None, [0, 0]),
        };
        let covers = default_tile.as_ref().is_some_and(|d| d.usable);
        for t in 0..tiles[1] {
            for s in 0..tiles[0] {
                counts.tiles += 1;
                let loc: Option<TileLocation> = plan.locate(l.level, s, t).ok();
                let state = match &loc {
                    None => Err((Problem::Missing, None)),
                    Some(loc) if crate::source::file::compressed_extension(loc.path.extension()) => files
                        .entry(loc.path.clone())
                        .or_insert_with(|| probe_compressed(&loc.path, loc.offset, loc.length, &mut scratch))
                        .clone(),
                    Some(loc) => {
                        let len = files.entry(loc.path.clone()).or_insert_with(|| probe(&loc.path)).clone();
                        len.and_then(|len| {
                            if len >= loc.offset.saturating_add(loc.length) {
                                Ok(len)
                            } else {
                                Err((Problem::Short, None))
                            }
                        })
                    }
                };
                let Err((problem, detail)) = state else {
                    counts.present += 1;
                    continue;
                };
                match problem {
                    Problem::Missing => counts.missing += 1,
                    Problem::Short => counts.short += 1,
                    Problem::Unreadable => counts.unreadable += 1,
                    Problem::Corrupt => counts.corrupt += 1,
                }
                // As the file source serves them: the default tile stands in for missing and
                // short tiles only.
                let covered = covers && matches!(problem, Problem::Missing | Problem::Short);
                counts.default_covered += covered as u64;
                if problems.len() < MAX_LISTED_PROBLEMS {
                    let path = loc.map(|l| l.path);
                    problems.push(TileProblem {
                        level: l.level,
                        s,
                        t,
                        path,
                        problem,
                        default_covered: covered,
                        detail,
                    });
                } else {
                    not_listed += 1;
                }
            }
            progress(tiles[0]);
        }
        totals.add(&counts);
        levels.push(LevelCheck { level: l.level, kind, size: l.size, counts, default_tile });
    }
    // A named default tile that cannot be used stops the service from starting (as
    // `FileSource::new` refuses it), so no tile of the texture can be served then.
    let defaults_usable = levels.iter().all(|l| l.default_tile.as_ref().is_none_or(|d| d.usable));
    CheckReport {
        path: plan.path.clone(),
        servable: defaults_usable && totals.servable() == totals.tiles,
        levels,
        totals,
        problems,
        problems_not_listed: not_listed,
    }
}

/// Checks every tile of a texture served as it is from one file or tile source (a COG, a tile
/// archive, a template): each tile is read and decoded as the service would read it
/// (`TileSource::read_tile`), and sorted by what the read says. `kind_of` names each level's
/// origin (`ifd`, `zoom`, `built`); `missing` says what a missing tile means for this kind of
/// source (its problem's detail); `progress` is told the tiles checked since its last call.
pub fn run_source(
    path: &std::path::Path,
    place: &Place,
    src: &dyn crate::source::TileSource,
    kind_of: &dyn Fn(u32) -> &'static str,
    missing: &str,
    progress: &dyn Fn(u64),
) -> CheckReport {
    use crate::source::{SourceError, TileId};
    let (mut problems, mut not_listed) = (Vec::new(), 0u64);
    let (mut levels, mut totals) = (Vec::new(), Counts::default());
    for (k, d) in src.desc().levels().iter().enumerate() {
        let level = k as u32;
        let mut counts = Counts::default();
        let [ts, tt] = d.tiles();
        let mut buf = vec![0u8; src.desc().tile_bytes(level)];
        for t in 0..tt {
            for s in 0..ts {
                counts.tiles += 1;
                let (problem, detail) = match src.read_tile(TileId { level, s, t }, &mut buf) {
                    Ok(()) => {
                        counts.present += 1;
                        continue;
                    }
                    Err(SourceError::Missing { .. }) => (Problem::Missing, Some(missing.to_string())),
                    Err(e @ SourceError::Short { .. }) => (Problem::Short, Some(e.to_string())),
                    Err(e @ (SourceError::PermissionDenied { .. } | SourceError::Io { .. })) => {
                        (Problem::Unreadable, Some(e.to_string()))
                    }
                    Err(e) => (Problem::Corrupt, Some(e.to_string())),
                };
                match problem {
                    Problem::Missing => counts.missing += 1,
                    Problem::Short => counts.short += 1,
                    Problem::Unreadable => counts.unreadable += 1,
                    Problem::Corrupt => counts.corrupt += 1,
                }
                if problems.len() < MAX_LISTED_PROBLEMS {
                    let path = Some(place.clone());
                    problems.push(TileProblem { level, s, t, path, problem, default_covered: false, detail });
                } else {
                    not_listed += 1;
                }
            }
            progress(ts);
        }
        totals.add(&counts);
        levels.push(LevelCheck { level, kind: kind_of(level), size: d.size, counts, default_tile: None });
    }
    CheckReport {
        path: path.to_path_buf(),
        servable: totals.servable() == totals.tiles,
        levels,
        totals,
        problems,
        problems_not_listed: not_listed,
    }
}

/// The report as a person reads it: a table per level, the problem tiles, the verdict.
pub fn human(r: &CheckReport, quiet: bool) -> String {
    let mut o = String::new();
    if !quiet {
        let _ = writeln!(
            o,
            "{:>5} {:<11} {:>17} {:>9} {:>9} {:>8} {:>6} {:>10} {:>7} {:>8}",
            "level", "kind", "size", "tiles", "present", "missing", "short", "unreadable", "corrupt", "default"
        );
        for l in &r.levels {
            let c = &l.counts;
            let _ = writeln!(
                o,
                "{:>5} {:<11} {:>17} {:>9} {:>9} {:>8} {:>6} {:>10} {:>7} {:>8}",
                l.level,
                l.kind,
                format!("{}x{}", l.size[0], l.size[1]),
                c.tiles,
                c.present,
                c.missing,
                c.short,
                c.unreadable,
                c.corrupt,
                c.default_covered
            );
            if let Some(d) = l.default_tile.as_ref().filter(|d| !d.usable) {
                let why = d.error.as_deref().unwrap_or("unusable");
                let _ = writeln!(o, "      default tile {} cannot be used: {why}", d.path);
            }
        }
    }
    for p in r.problems.iter().filter(|p| !p.default_covered || !quiet) {
        let path = p.path.as_ref().map_or("(no file named)".into(), |p| p.to_string());
        let covered = if p.default_covered { " (default tile used)" } else { "" };
        let detail = p.detail.as_deref().map(|d| format!(" ({d})")).unwrap_or_default();
        let _ = writeln!(o, "level {} tile ({}, {}): {:?}: {path}{covered}{detail}", p.level, p.s, p.t, p.problem);
    }
    if r.problems_not_listed > 0 {
        let _ = writeln!(o, "... and {} more problem tiles", r.problems_not_listed);
    }
    let t = &r.totals;
    if !quiet || !r.servable {
        let bad_default = r.levels.iter().any(|l| l.default_tile.as_ref().is_some_and(|d| !d.usable));
        let verdict = if r.servable {
            "every tile can be served"
        } else if bad_default {
            "a default tile cannot be used, so the texture cannot be served"
        } else {
            "some tiles cannot be served"
        };
        let _ = writeln!(
            o,
            "{}: {} of {} tiles servable ({} present, {} covered by a default tile): {verdict}",
            r.path.display(),
            t.servable(),
            t.tiles,
            t.present,
            t.default_covered
        );
    }
    o
}
