//! A growing texture on disk: its grid, every accepted patch, the rebuilt tiles, and how far the
//! rebuild is known to have gone, so that a restart keeps everything and a crash (kill -9 or a
//! power cut) in the middle of a rebuild loses nothing that was acknowledged.
//!
//! ```text
//! DIR/grid.json                  {"version": 1, "origin": [x, y], "texels_per_unit": r,
//!                                 "tile": 256, "format": "rgb8"}
//! DIR/patches/0000000007.texels  the patch's texels in the grid's format, row-major, or
//! DIR/patches/0000000007.image   the image file it came from (decoded again at open)
//! DIR/patches/0000000007.json    {"id": 7, "bbox": [...], "time": t, "rating": r,
//!                                 "width": w, "height": h}: the patch's commit record
//! DIR/tiles/K/T_S.tile           a rebuilt tile (header, texels, one bit a texel for data)
//! DIR/state.json                 {"applied": 7, "levels": 5}: every patch up to 7 is in the
//!                                 tiles on disk, and the texture had 5 levels then
//! ```
//!
//! **Writes.** Every file is written to a temporary name in its directory and renamed over the
//! target, so a reader (or a restart) sees the old file or the new one, never a part. A patch is
//! acknowledged ([`Growing::add`] returns) only when its texels and then its record are synced
//! and the directory entry is synced too; the record is written last, so a crash between the two
//! leaves a texels file without a record, which the next open deletes (the patch was never
//! acknowledged). Tiles are not synced one by one: `state.json` moves forward only when nothing
//! waits to be rebuilt or saved, and only after a sync of the whole file system (`syncfs`), so
//! every tile it vouches for is durable.
//!
//! **Restart.** [`Growing::open`] reads the grid, every patch (into the R*-tree), every tile, and
//! the state; then marks the whole footprint of every patch newer than `applied` at every level
//! (a tile rebuilt before the crash would otherwise look unchanged, and its parent never learn of
//! the patch). Tiles written after the last checkpoint are therefore rebuilt, and a tile file
//! that is damaged (a power cut before it reached the disk) is rebuilt too, whether or not a
//! replayed patch covers it.
//!
//! The working set is every tile, in memory (read back at open): a store of N tiles needs N tile
//! sizes of memory. Keeping only what rebuilds and readers need is the next step (see
//! docs/GROWING.md, "Limits").

use super::index::PatchIndex;
use super::rebuild::{Flags, Rebuilder, Tile, TileKey};
use super::{Grid, GrowError, NewPatch, Patch, PatchMeta, WorldBox};
use crate::texel::TexelFormat;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use thiserror::Error;

/// Magic bytes at the start of a tile file.
pub(crate) const TILE_MAGIC: [u8; 8] = *b"CLIPGT01";
/// Bytes of a tile file's header: magic, level (u32), S (i64), T (i64), tile (u32), bytes per
/// texel (u32), texels with data (u64); all little-endian.
pub(crate) const TILE_HEADER: usize = 8 + 4 + 8 + 8 + 4 + 4 + 8;

/// The texel formats a growing texture takes: 1 to 4 components of 8 or 16 bits.
pub const FORMATS: [(&str, TexelFormat); 7] = [
    ("l8", TexelFormat::L8),
    ("rgb8", TexelFormat::RGB8),
    ("rgba8", TexelFormat::RGBA8),
    ("l16", TexelFormat::L16),
    ("la16", TexelFormat::LA16),
    ("rgb16", TexelFormat::RGB16),
    ("rgba16", TexelFormat::RGBA16),
];

/// The format called `name`, with what a grid needs of it (bytes a texel, bytes a component).
pub(crate) fn format_named(name: &str) -> Option<(TexelFormat, usize, usize)> {
    FORMATS.iter().find(|(n, _)| *n == name).map(|&(_, f)| {
        let bpt = f.bytes_per_texel() as usize;
        (f, bpt, f.component_bits() as usize / 8)
    })
}

/// What can go wrong with a store.
#[derive(Debug, Error)]
pub enum StoreError {
    /// A file or directory could not be read or written.
    #[error("{path}: {what}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// What was being done to it.
        what: &'static str,
        /// The operating system's error.
        #[source]
        source: io::Error,
    },
    /// A file holds something else than the store wrote.
    #[error(
        "{path}: {problem}; the growing texture's directory is damaged (restore it from a copy, or start a new one)"
    )]
    Damaged {
        /// The file.
        path: PathBuf,
        /// What it holds instead.
        problem: String,
    },
    /// The directory is not a growing texture, or already is one.
    #[error("{path}: {problem}")]
    NotAStore {
        /// The directory.
        path: PathBuf,
        /// What it is.
        problem: String,
    },
    /// Another writer holds the directory.
    #[error("{path}: another process (pid {holder}) is adding to or rebuilding this growing texture; wait for it, or stop it (only one writer at a time; `cliptex grow status` and `dump` may look meanwhile)")]
    Busy {
        /// The directory.
        path: PathBuf,
        /// The other writer's process id.
        holder: String,
    },
    /// The grid is refused.
    #[error("{0}")]
    Grid(GrowError),
    /// The patch is refused (nothing was kept).
    #[error("{0}")]
    Patch(GrowError),
}

pub use crate::limits::{MAX_GROWING_LEVELS as MAX_LEVELS, MAX_RECORD_BYTES};

/// Reads one of the store's small files with the one checked open (regular files only, never
/// blocking on a FIFO or a device, at most [`MAX_RECORD_BYTES`]).
fn read_record(path: &Path) -> Result<Vec<u8>, StoreError> {
    crate::open::read_capped(path, MAX_RECORD_BYTES).map_err(|e| sized_err(path, "could not read", MAX_RECORD_BYTES, e))
}

fn sized_err(path: &Path, what: &'static str, max: u64, e: crate::open::SizedError) -> StoreError {
    match e {
        crate::open::SizedError::Io(source) if source.kind() == io::ErrorKind::InvalidInput => StoreError::Damaged {
            path: path.to_path_buf(),
            problem: format!("{source} where the store keeps a regular file"),
        },
        crate::open::SizedError::Io(source) => StoreError::Io { path: path.to_path_buf(), what, source },
        crate::open::SizedError::Length(n) => StoreError::Damaged {
            path: path.to_path_buf(),
            problem: format!("{n} bytes where this file has at most {max}"),
        },
    }
}

fn io_err<'a>(path: &'a Path, what: &'static str) -> impl FnOnce(io::Error) -> StoreError + 'a {
    move |source| StoreError::Io { path: path.to_path_buf(), what, source }
}

/// `grid.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct GridFile {
    pub version: u32,
    pub origin: [f64; 2],
    pub texels_per_unit: f64,
    pub tile: u64,
    pub format: String,
    /// Level-0 texels over which patch edges are feathered (the optional blend; absent or 0: the
    /// best patch wins each texel outright).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub feather: f64,
    /// The EPSG code of the CRS whose map units the world coordinates are (the patches' boxes
    /// georeferenced in it; docs/GEOREF.md, "Growing textures"); absent: the world units are the
    /// user's own, and the texture has no georeferencing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub epsg: Option<u32>,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// The widest feather a growing texture takes, in level-0 texels.
pub(crate) const MAX_FEATHER: f64 = 4096.0;

/// A patch's commit record.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct PatchRecord {
    id: u64,
    bbox: [f64; 4],
    time: u64,
    rating: f64,
    width: u32,
    height: u32,
    /// Where it came from, when a watcher took it from a directory (`NAME#DIGEST`), so that a
    /// restart does not take the same file twice.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    source: Option<String>,
    /// Set when the patch is kept as its image file (`ID.image`): the digest of the texels it
    /// decoded to, checked when it is decoded again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    image_digest: Option<String>,
}

/// `state.json`.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
struct State {
    applied: u64,
    levels: u32,
}

/// A growing texture kept in a directory: the index, the rebuild and the files behind them.
pub struct Growing {
    dir: PathBuf,
    grid: Grid,
    format: TexelFormat,
    index: PatchIndex,
    rebuild: Rebuilder,
    /// The next patch's id (ids start at 1).
    next_id: u64,
    /// Every patch up to this id is in the tiles on disk.
    applied: u64,
    /// Patches replayed at open.
    replayed: usize,
    /// Tile files found damaged at open (and marked to be rebuilt), with what was wrong.
    damaged: Vec<(PathBuf, String)>,
    /// The writer's lock (`DIR/lock`, an exclusive `flock` held while this lives); `None` for a
    /// read-only handle.
    lock: Option<std::fs::File>,
    /// The `source` of every patch that has one.
    sources: std::collections::HashSet<String>,
    /// Tiles changed and saved since [`Growing::take_saved`] last took them.
    saved: Vec<TileKey>,
    /// The CRS of the world coordinates, an EPSG code ([`GridFile::epsg`]).
    epsg: Option<u32>,
}

impl Growing {
    /// A new growing texture in `dir` (created if needed; it must be empty, or not exist).
    pub fn create(
        dir: &Path,
        origin: [f64; 2],
        texels_per_unit: f64,
        tile: u64,
        format: &str,
    ) -> Result<Growing, StoreError> {
        Growing::create_feathered(dir, origin, texels_per_unit, tile, format, 0.0)
    }

    /// The EPSG code of the CRS the world coordinates are in, if the grid names one.
    pub fn epsg(&self) -> Option<u32> {
        self.epsg
    }

    /// [`Growing::create`], feathering patch edges over `feather` level-0 texels (0 to
    /// `MAX_FEATHER`; 0: off), see `super::rebuild::level0_tile_feathered`.
    pub fn create_feathered(
        dir: &Path,
        origin: [f64; 2],
        texels_per_unit: f64,
        tile: u64,
        format: &str,
        feather: f64,
    ) -> Result<Growing, StoreError> {
        Growing::create_georeferenced(dir, origin, texels_per_unit, tile, format, feather, None)
    }

    /// [`Growing::create_feathered`] with the world coordinates in the CRS `epsg` (an EPSG code
    /// this engine knows; `None`: the user's own units, no georeferencing): the patches' boxes are
    /// map coordinates of it, and the texture is georeferenced by its grid (docs/GEOREF.md).
    pub fn create_georeferenced(
        dir: &Path,
        origin: [f64; 2],
        texels_per_unit: f64,
        tile: u64,
        format: &str,
        feather: f64,
        epsg: Option<u32>,
    ) -> Result<Growing, StoreError> {
        if let Some(Err(e)) = epsg.map(crate::georef::Crs::epsg) {
            return Err(StoreError::NotAStore {
                path: dir.to_path_buf(),
                problem: format!(
                    "the CRS of the world coordinates: {e}; give an EPSG code such as 4326, 3857 or 32633"
                ),
            });
        }
        if !(feather.is_finite() && (0.0..=MAX_FEATHER).contains(&feather)) {
            return Err(StoreError::NotAStore {
                path: dir.to_path_buf(),
                problem: format!(
                    "the feather {feather} is not a width in level-0 texels from 0 (off) to {MAX_FEATHER}"
                ),
            });
        }
        let Some((texel, bpt, cb)) = format_named(format) else {
            let names: Vec<&str> = FORMATS.iter().map(|f| f.0).collect();
            return Err(StoreError::NotAStore {
                path: dir.to_path_buf(),
                problem: format!(
                    "the texel format {format:?} is not one a growing texture takes; expected one of {}",
                    names.join(", ")
                ),
            });
        };
        let grid = Grid::new(origin, texels_per_unit, tile, bpt, cb).map_err(StoreError::Grid)?;
        std::fs::create_dir_all(dir).map_err(io_err(dir, "could not create the directory"))?;
        let mut entries = std::fs::read_dir(dir).map_err(io_err(dir, "could not list the directory"))?;
        if entries.next().is_some() {
            return Err(StoreError::NotAStore {
                path: dir.to_path_buf(),
                problem: "the directory is not empty; a new growing texture needs an empty (or new) directory (to add to an existing one, open it instead)".into(),
            });
        }
        let lock = take_lock(dir)?;
        for sub in ["patches", "tiles"] {
            let p = dir.join(sub);
            std::fs::create_dir(&p).map_err(io_err(&p, "could not create the directory"))?;
        }
        let file = GridFile { version: 1, origin, texels_per_unit, tile, format: format.to_string(), feather, epsg };
        write_json(&dir.join("state.json"), &State::default())?;
        // grid.json last: a directory without it is not a store, and is refused by `open`.
        write_json(&dir.join("grid.json"), &file)?;
        sync_dir(dir)?;
        Ok(Growing {
            dir: dir.to_path_buf(),
            grid,
            format: texel,
            index: PatchIndex::new(),
            rebuild: {
                let mut r = Rebuilder::new(grid);
                r.set_feather(feather);
                r
            },
            next_id: 1,
            applied: 0,
            replayed: 0,
            damaged: Vec::new(),
            lock: Some(lock),
            sources: Default::default(),
            saved: Vec::new(),
            epsg,
        })
    }

    /// The growing texture in `dir`, as it was left (see the module documentation), to add to
    /// and rebuild: one writer at a time (an exclusive lock on `DIR/lock`; a second writer is
    /// refused with the first one's process id).
    pub fn open(dir: &Path) -> Result<Growing, StoreError> {
        Growing::open_as(dir, true)
    }

    /// The growing texture in `dir` to look at, while a writer may be at work: nothing is locked,
    /// deleted or written; [`Growing::add`] and [`Growing::step`] refuse. What it shows is what
    /// the files held when it read them (each file whole).
    pub fn open_read_only(dir: &Path) -> Result<Growing, StoreError> {
        Growing::open_as(dir, false)
    }

    fn open_as(dir: &Path, write: bool) -> Result<Growing, StoreError> {
        let (file, format, grid) = read_grid(dir)?;
        let lock = if write { Some(take_lock(dir)?) } else { None };
        let state = read_state(dir)?;

        // Patches, in id order; those past the last applied one (or decoding to other texels
        // than when added) are replayed.
        let pdir = dir.join("patches");
        let records = list_patches(&pdir, write)?;
        let mut index = PatchIndex::new();
        let mut replay = Vec::new();
        let mut sources = std::collections::HashSet::new();
        for (id, path) in &records {
            let (patch, source, redo) = load_patch(&grid, &pdir, *id, path)?;
            sources.extend(source);
            let patch = index.insert(patch);
            if *id > state.applied || redo {
                replay.push(patch);
            }
        }

        let tiles = load_tiles(&dir.join("tiles"), &grid, write)?;
        let mut rebuild = Rebuilder::restore(grid, tiles.good, state.levels);
        rebuild.set_feather(file.feather);
        for p in &replay {
            rebuild.mark_footprint(&index, p);
        }
        for (k, s, t) in tiles.damaged {
            rebuild.mark_tile(k, s, t);
        }
        let next_id = records.last().map_or(1, |r| r.0 + 1);
        Ok(Growing {
            dir: dir.to_path_buf(),
            grid,
            format,
            index,
            rebuild,
            next_id,
            applied: state.applied,
            replayed: replay.len(),
            damaged: tiles.damaged_files,
            lock,
            sources,
            saved: Vec::new(),
            epsg: file.epsg,
        })
    }

    /// Checks `p`, keeps it on disk, indexes it and marks what it changes; returns its id. When
    /// this returns, the patch survives any crash. A refused patch leaves nothing behind.
    pub fn add(&mut self, p: NewPatch) -> Result<u64, StoreError> {
        self.add_from(p, None)
    }

    /// [`Growing::add`], recording where the patch came from (see [`Growing::has_source`]).
    pub(crate) fn add_from(&mut self, p: NewPatch, source: Option<String>) -> Result<u64, StoreError> {
        self.writable()?;
        let id = self.next_id;
        let NewPatch { patch: given, encoded } = p;
        let meta = PatchMeta { id, bbox: given.bbox, time: given.time, rating: given.rating };
        let patch = Patch::new(&self.grid, meta, given.width, given.height, given.texels).map_err(StoreError::Patch)?;
        let pdir = self.dir.join("patches");
        let rpath = pdir.join(format!("{id:010}.json"));
        let (tpath, image_digest) = match &encoded {
            Some(bytes) => {
                let path = pdir.join(format!("{id:010}.image"));
                write_file(&path, bytes, true)?;
                (path, Some(format!("{:016x}", super::digest(&patch.texels))))
            }
            None => {
                let path = pdir.join(format!("{id:010}.texels"));
                write_file(&path, &patch.texels, true)?;
                (path, None)
            }
        };
        let rec = PatchRecord {
            id,
            bbox: [patch.bbox.min[0], patch.bbox.min[1], patch.bbox.max[0], patch.bbox.max[1]],
            time: patch.time,
            rating: patch.rating,
            width: patch.width,
            height: patch.height,
            source: source.clone(),
            image_digest,
        };
        if let Err(e) = write_json(&rpath, &rec).and_then(|_| sync_dir(&pdir)) {
            let _ = std::fs::remove_file(&rpath);
            let _ = std::fs::remove_file(&tpath);
            return Err(e);
        }
        self.next_id += 1;
        self.sources.extend(source);
        let patch = self.index.insert(patch);
        self.rebuild.patch_added(&self.index, &patch);
        Ok(id)
    }

    /// Rebuilds at most `max` waiting tiles and saves those that changed; when nothing waits any
    /// more, records (after a file-system sync) that every patch so far is in the tiles. Returns
    /// the tiles rebuilt. A tile that could not be saved stays waiting to be saved, and the
    /// error is returned.
    pub fn step(&mut self, max: usize) -> Result<Vec<TileKey>, StoreError> {
        self.writable()?;
        let done = self.rebuild.step(&self.index, max);
        self.save_changed()?;
        if self.rebuild.pending() == 0 && self.applied + 1 < self.next_id {
            self.checkpoint()?;
        }
        Ok(done)
    }

    /// Rebuilds until nothing waits (at most `per_step` tiles a step).
    pub fn finish(&mut self, per_step: usize) -> Result<usize, StoreError> {
        let mut n = 0;
        while self.rebuild.pending() > 0 || self.applied + 1 < self.next_id {
            n += self.step(per_step.max(1))?.len();
        }
        Ok(n)
    }

    fn writable(&self) -> Result<(), StoreError> {
        match self.lock {
            Some(_) => Ok(()),
            None => Err(StoreError::NotAStore {
                path: self.dir.clone(),
                problem: "opened to look at only: open it to write (no other writer at work) to add or rebuild".into(),
            }),
        }
    }

    fn save_changed(&mut self) -> Result<(), StoreError> {
        let keys = self.rebuild.take_changed();
        for (i, &(k, s, t)) in keys.iter().enumerate() {
            let path = self.tile_path(k, s, t);
            let saved = match self.rebuild.tile(k, s, t) {
                Some(tile) => {
                    let ldir = path.parent().expect("a tile path has a directory");
                    std::fs::create_dir_all(ldir)
                        .map_err(io_err(ldir, "could not create the directory"))
                        .and_then(|_| write_file(&path, &tile_bytes(&self.grid, (k, s, t), tile), false))
                }
                None => match std::fs::remove_file(&path) {
                    Ok(()) => Ok(()),
                    Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(()),
                    Err(e) => Err(io_err(&path, "could not remove")(e)),
                },
            };
            if let Err(e) = saved {
                self.rebuild.unsaved(keys[i..].iter().copied());
                self.saved.extend_from_slice(&keys[..i]);
                return Err(e);
            }
        }
        self.saved.extend(keys);
        Ok(())
    }

    fn checkpoint(&mut self) -> Result<(), StoreError> {
        let d = std::fs::File::open(&self.dir).map_err(io_err(&self.dir, "could not open"))?;
        rustix::fs::syncfs(&d).map_err(|e| io_err(&self.dir, "could not sync the file system")(e.into()))?;
        let state = State { applied: self.next_id - 1, levels: self.rebuild.levels() };
        write_json(&self.dir.join("state.json"), &state)?;
        self.applied = state.applied;
        Ok(())
    }

    fn tile_path(&self, k: u32, s: i64, t: i64) -> PathBuf {
        self.dir.join("tiles").join(k.to_string()).join(format!("{t}_{s}.tile"))
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The tiles whose texels changed (rebuilt differently, or gone) and were saved since the
    /// last call: what a service serving the texture must replace.
    pub(crate) fn take_saved(&mut self) -> Vec<TileKey> {
        std::mem::take(&mut self.saved)
    }

    /// Patches added so far (the last id given).
    pub fn patches(&self) -> u64 {
        self.next_id - 1
    }

    /// Whether a patch was added from `source` (what [`Growing::add_from`] recorded).
    pub(crate) fn has_source(&self, source: &str) -> bool {
        self.sources.contains(source)
    }

    /// Level-0 texels over which patch edges are feathered (0: off).
    pub fn feather(&self) -> f64 {
        self.rebuild.feather()
    }

    /// The texel format.
    pub fn format(&self) -> TexelFormat {
        self.format
    }

    /// The patches and their R*-tree.
    pub fn index(&self) -> &PatchIndex {
        &self.index
    }

    /// The tiles and the rebuild.
    pub fn rebuild(&self) -> &Rebuilder {
        &self.rebuild
    }

    /// Tile (s, t) of level k as built (`None`: no data there, or not built yet).
    pub fn tile(&self, k: u32, s: i64, t: i64) -> Option<&Arc<Tile>> {
        self.rebuild.tile(k, s, t)
    }

    /// Levels the texture has now.
    pub fn levels(&self) -> u32 {
        self.rebuild.levels()
    }

    /// Tiles waiting to be rebuilt.
    pub fn pending(&self) -> usize {
        self.rebuild.pending()
    }

    /// The last patch known to be in the tiles on disk (0: none).
    pub fn applied(&self) -> u64 {
        self.applied
    }

    /// Tile files `open` found damaged (a wrong length, not a regular file, ...) and marked to be
    /// rebuilt, with what was wrong with each.
    pub fn damaged(&self) -> &[(PathBuf, String)] {
        &self.damaged
    }

    /// Patches whose rebuild `open` had to redo.
    pub fn replayed(&self) -> usize {
        self.replayed
    }

    /// The directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

/// `grid.json`: the grid description, its texel format and the grid it makes, every value checked.
fn read_grid(dir: &Path) -> Result<(GridFile, TexelFormat, Grid), StoreError> {
    let grid_path = dir.join("grid.json");
    let text = match crate::open::read_capped(&grid_path, MAX_RECORD_BYTES) {
        Ok(t) => t,
        Err(crate::open::SizedError::Io(e)) if e.kind() == io::ErrorKind::NotFound => {
            return Err(StoreError::NotAStore {
                path: dir.to_path_buf(),
                problem:
                    "no grid.json here: this is not a growing texture (create one with `cliptex grow create DIR ...`)"
                        .into(),
            })
        }
        Err(e) => return Err(sized_err(&grid_path, "could not read", MAX_RECORD_BYTES, e)),
    };
    let file: GridFile = serde_json::from_slice(&text).map_err(|e| StoreError::Damaged {
        path: grid_path.clone(),
        problem: format!("not a grid description ({e})"),
    })?;
    if file.version != 1 {
        return Err(StoreError::Damaged {
            path: grid_path,
            problem: format!("version {} where this build reads version 1", file.version),
        });
    }
    let Some((format, bpt, cb)) = format_named(&file.format) else {
        return Err(StoreError::Damaged {
            path: grid_path,
            problem: format!("unknown texel format {:?}", file.format),
        });
    };
    if !(file.feather.is_finite() && (0.0..=MAX_FEATHER).contains(&file.feather)) {
        return Err(StoreError::Damaged {
            path: grid_path,
            problem: format!("feather {}: expected 0 (off) to {MAX_FEATHER} level-0 texels", file.feather),
        });
    }
    if let Some(Err(e)) = file.epsg.map(crate::georef::Crs::epsg) {
        return Err(StoreError::Damaged { path: grid_path, problem: format!("epsg: {e}") });
    }
    let grid = Grid::new(file.origin, file.texels_per_unit, file.tile, bpt, cb).map_err(StoreError::Grid)?;
    Ok((file, format, grid))
}

/// `state.json`: how far the rebuild got.
fn read_state(dir: &Path) -> Result<State, StoreError> {
    let state_path = dir.join("state.json");
    let state: State = serde_json::from_slice(&read_record(&state_path)?)
        .map_err(|e| StoreError::Damaged { path: state_path.clone(), problem: format!("not a rebuild state ({e})") })?;
    if state.levels > MAX_LEVELS {
        return Err(StoreError::Damaged {
            path: state_path,
            problem: format!("it says {} levels; a growing texture has at most {MAX_LEVELS}", state.levels),
        });
    }
    Ok(state)
}

/// The patch records in `pdir`, in id order. A texels or image file without its record was never
/// acknowledged: a writer removes it, as it removes half-written temporary files.
fn list_patches(pdir: &Path, write: bool) -> Result<Vec<(u64, PathBuf)>, StoreError> {
    let mut records = Vec::new();
    let mut texels_only = Vec::new();
    for entry in std::fs::read_dir(pdir).map_err(io_err(pdir, "could not list"))? {
        let path = entry.map_err(io_err(pdir, "could not list"))?.path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if let Some(id) = name.strip_suffix(".json").and_then(|n| n.parse::<u64>().ok()) {
            records.push((id, path));
        } else if let Some(id) =
            name.strip_suffix(".texels").or_else(|| name.strip_suffix(".image")).and_then(|n| n.parse::<u64>().ok())
        {
            texels_only.push((id, path));
        } else if name.contains(".tmp") && write {
            let _ = std::fs::remove_file(&path);
        }
    }
    records.sort();
    let known: std::collections::HashSet<u64> = records.iter().map(|r| r.0).collect();
    for (id, path) in texels_only {
        if !known.contains(&id) && write {
            tracing::warn!(path = %path.display(), "removing the texels of a patch that was never acknowledged");
            std::fs::remove_file(&path).map_err(io_err(&path, "could not remove"))?;
        }
    }
    Ok(records)
}

/// Patch `id` from its record at `path` and its texels (or image) beside it: the patch, the
/// source it names, and whether its tiles must be rebuilt because its image now decodes to other
/// texels.
fn load_patch(grid: &Grid, pdir: &Path, id: u64, path: &Path) -> Result<(Patch, Option<String>, bool), StoreError> {
    let rec: PatchRecord = serde_json::from_slice(&read_record(path)?)
        .map_err(|e| StoreError::Damaged { path: path.to_path_buf(), problem: format!("not a patch record ({e})") })?;
    if rec.id != id {
        return Err(StoreError::Damaged {
            path: path.to_path_buf(),
            problem: format!("it says id {} in a file named for {id}", rec.id),
        });
    }
    // What the record says the texels are, bounded before anything is read: a file of another
    // length (a sparse giant, a link to a device) is damaged, never read whole.
    let texel_bytes = rec.width as u64 * rec.height as u64 * grid.bytes_per_texel as u64;
    if rec.width > super::MAX_PATCH_PIXELS
        || rec.height > super::MAX_PATCH_PIXELS
        || texel_bytes > crate::limits::MAX_PATCH_BYTES
    {
        return Err(StoreError::Damaged {
            path: path.to_path_buf(),
            problem: format!(
                "a {}x{} patch; the most is {} a side and {} bytes of texels",
                rec.width,
                rec.height,
                super::MAX_PATCH_PIXELS,
                crate::limits::MAX_PATCH_BYTES
            ),
        });
    }
    let (texels, redo) = match &rec.image_digest {
        None => (read_patch_texels(&pdir.join(format!("{id:010}.texels")), texel_bytes)?, false),
        Some(want) => read_patch_image(grid, &pdir.join(format!("{id:010}.image")), &rec, texel_bytes, want)?,
    };
    let [x0, y0, x1, y1] = rec.bbox;
    let meta = PatchMeta { id, bbox: WorldBox { min: [x0, y0], max: [x1, y1] }, time: rec.time, rating: rec.rating };
    let patch = Patch::new(grid, meta, rec.width, rec.height, texels).map_err(|e| StoreError::Damaged {
        path: path.to_path_buf(),
        problem: format!("the patch is refused now: {e}"),
    })?;
    Ok((patch, rec.source, redo))
}

/// A patch's raw texels: exactly `texel_bytes` of them.
fn read_patch_texels(tpath: &Path, texel_bytes: u64) -> Result<Vec<u8>, StoreError> {
    crate::open::read_sized(tpath, &[texel_bytes]).map_err(|e| match e {
        crate::open::SizedError::Length(n) => StoreError::Damaged {
            path: tpath.to_path_buf(),
            problem: format!("{n} bytes where the record says {texel_bytes}"),
        },
        e => sized_err(tpath, "could not read the patch's texels", texel_bytes, e),
    })
}

/// A patch kept as its image: decoded and checked against the record's size. `true` beside the
/// texels when they differ from the digest taken when it was added.
fn read_patch_image(
    grid: &Grid,
    ipath: &Path,
    rec: &PatchRecord,
    texel_bytes: u64,
    want: &str,
) -> Result<(Vec<u8>, bool), StoreError> {
    let max = super::input::max_image_file_bytes(texel_bytes);
    let bytes = crate::open::read_capped(ipath, max)
        .map_err(|e| sized_err(ipath, "could not read the patch's image", max, e))?;
    let (w, h, texels) = super::input::decode_image(grid, &bytes, texel_bytes.max(1), &ipath.display().to_string())
        .map_err(|e| StoreError::Damaged { path: ipath.to_path_buf(), problem: e.to_string() })?;
    if (w, h) != (rec.width, rec.height) {
        return Err(StoreError::Damaged {
            path: ipath.to_path_buf(),
            problem: format!("a {w}x{h} image where the record says {}x{}", rec.width, rec.height),
        });
    }
    // Another decoder version may round differently: then the patch's tiles are rebuilt from
    // what it decodes to now, so tiles and patches agree again.
    let redo = want != format!("{:016x}", super::digest(&texels));
    if redo {
        tracing::warn!(path = %ipath.display(), "the image decodes to other texels than when it was added: rebuilding its tiles");
    }
    Ok((texels, redo))
}

/// The built tiles found under `tiles/`: the readable ones, and the damaged ones to rebuild.
struct LoadedTiles {
    good: HashMap<TileKey, Arc<Tile>>,
    damaged: Vec<TileKey>,
    /// Each damaged file and what is wrong with it, for the report.
    damaged_files: Vec<(PathBuf, String)>,
}

/// Reads every tile file under `tdir` (`LEVEL/T_S.tile`); a damaged one is dropped and rebuilt,
/// other names are passed over, and a writer removes half-written temporary files.
fn load_tiles(tdir: &Path, grid: &Grid, write: bool) -> Result<LoadedTiles, StoreError> {
    let mut out = LoadedTiles { good: HashMap::new(), damaged: Vec::new(), damaged_files: Vec::new() };
    for level in std::fs::read_dir(tdir).map_err(io_err(tdir, "could not list"))? {
        let ldir = level.map_err(io_err(tdir, "could not list"))?.path();
        let Some(k) = ldir.file_name().and_then(|n| n.to_str()).and_then(|n| n.parse::<u32>().ok()) else {
            continue;
        };
        for entry in std::fs::read_dir(&ldir).map_err(io_err(&ldir, "could not list"))? {
            let path = entry.map_err(io_err(&ldir, "could not list"))?.path();
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("").to_string();
            if name.contains(".tmp") {
                if write {
                    let _ = std::fs::remove_file(&path);
                }
                continue;
            }
            let Some((t, s)) = name.strip_suffix(".tile").and_then(|n| n.split_once('_')) else { continue };
            let (Ok(t), Ok(s)) = (t.parse::<i64>(), s.parse::<i64>()) else { continue };
            match read_tile(&path, grid, (k, s, t)) {
                Ok(tile) => {
                    out.good.insert((k, s, t), Arc::new(tile));
                }
                Err(problem) => {
                    tracing::warn!(path = %path.display(), %problem, "a damaged tile file: rebuilding it");
                    out.damaged.push((k, s, t));
                    out.damaged_files.push((path.clone(), problem));
                }
            }
        }
    }
    Ok(out)
}

/// Takes `DIR/lock` (created if needed) exclusively, without waiting, and writes this process's
/// id into it; refused, naming the holder, while another writer holds it.
fn take_lock(dir: &Path) -> Result<std::fs::File, StoreError> {
    use rustix::fs::{flock, FlockOperation};
    use std::io::Read;
    use std::os::unix::fs::OpenOptionsExt;
    let path = dir.join("lock");
    // Never through a link, never blocking on a FIFO: a lock planted as a link would have the
    // pid written into its target.
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .custom_flags((rustix::fs::OFlags::NOFOLLOW | rustix::fs::OFlags::NONBLOCK).bits() as i32)
        .open(&path)
        .map_err(|e| match e.raw_os_error() {
            Some(code) if code == rustix::io::Errno::LOOP.raw_os_error() => StoreError::Io {
                path: path.clone(),
                what: "it is a symbolic link where the store keeps its lock file (never followed); remove it",
                source: e,
            },
            _ => io_err(&path, "could not open the lock file")(e),
        })?;
    let meta = f.metadata().map_err(io_err(&path, "could not look at the lock file"))?;
    if !meta.is_file() {
        return Err(StoreError::Io {
            path,
            what: "it is not the store's lock file (a regular file); remove it",
            source: crate::open::not_regular(&meta),
        });
    }
    if let Err(e) = flock(&f, FlockOperation::NonBlockingLockExclusive) {
        if e == rustix::io::Errno::WOULDBLOCK {
            let mut holder = String::new();
            let _ = (&f).take(64).read_to_string(&mut holder);
            return Err(StoreError::Busy { path: dir.to_path_buf(), holder: holder.trim().to_string() });
        }
        return Err(io_err(&path, "could not lock")(e.into()));
    }
    use std::io::{Seek, SeekFrom};
    f.set_len(0)
        .and_then(|_| f.seek(SeekFrom::Start(0)).map(|_| ()))
        .and_then(|_| f.write_all(std::process::id().to_string().as_bytes()))
        .map_err(io_err(&path, "could not write"))?;
    Ok(f)
}

/// A tile file's bytes.
fn tile_bytes(grid: &Grid, (k, s, t): TileKey, tile: &Tile) -> Vec<u8> {
    let n = (grid.tile * grid.tile) as usize;
    let mut out = Vec::with_capacity(TILE_HEADER + tile.texels.len() + n.div_ceil(8));
    out.extend_from_slice(&TILE_MAGIC);
    out.extend_from_slice(&k.to_le_bytes());
    out.extend_from_slice(&s.to_le_bytes());
    out.extend_from_slice(&t.to_le_bytes());
    out.extend_from_slice(&(grid.tile as u32).to_le_bytes());
    out.extend_from_slice(&(grid.bytes_per_texel as u32).to_le_bytes());
    out.extend_from_slice(&(tile.has_data.count() as u64).to_le_bytes());
    out.extend_from_slice(&tile.texels);
    let bits = tile.has_data.to_bytes();
    debug_assert_eq!(bits.len(), n.div_ceil(8));
    out.extend_from_slice(&bits);
    out
}

/// A tile file, checked against the grid and the key its name gives.
fn read_tile(path: &Path, grid: &Grid, key: TileKey) -> Result<Tile, String> {
    let n = (grid.tile * grid.tile) as usize;
    let texel_bytes = n * grid.bytes_per_texel;
    let want = TILE_HEADER + texel_bytes + n.div_ceil(8);
    // Its length is checked before it is read (a sparse giant or a link to a device is damaged,
    // never read), and a FIFO is refused without blocking.
    let bytes = crate::open::read_sized(path, &[want as u64]).map_err(|e| match e {
        crate::open::SizedError::Io(e) => format!("could not read: {e}"),
        crate::open::SizedError::Length(n) => format!("{n} bytes where a tile of this grid has {want}"),
    })?;
    if bytes[..8] != TILE_MAGIC {
        return Err("it does not start with CLIPGT01".into());
    }
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let i64_at = |o: usize| i64::from_le_bytes(bytes[o..o + 8].try_into().expect("8 bytes"));
    let found = (u32_at(8), i64_at(12), i64_at(20));
    if found != key {
        return Err(format!("it holds tile {found:?} (level, S, T) where its name says {key:?}"));
    }
    if (u32_at(28) as u64, u32_at(32) as usize) != (grid.tile, grid.bytes_per_texel) {
        return Err(format!(
            "a tile of {} texels and {} bytes a texel where the grid has {} and {}",
            u32_at(28),
            u32_at(32),
            grid.tile,
            grid.bytes_per_texel
        ));
    }
    let filled = u64::from_le_bytes(bytes[36..44].try_into().expect("8 bytes")) as usize;
    let texels = bytes[TILE_HEADER..TILE_HEADER + texel_bytes].to_vec();
    let bits = &bytes[TILE_HEADER + texel_bytes..];
    let tile = Tile::new(texels, Flags::from_bytes(bits, n));
    if !tile.any_data() || tile.has_data.count() != filled {
        return Err(format!("its header says {filled} texels with data, its flags say otherwise"));
    }
    Ok(tile)
}

/// Writes `path` whole or not at all: a temporary file beside it, renamed over it (synced first
/// when `sync`).
fn write_file(path: &Path, bytes: &[u8], sync: bool) -> Result<(), StoreError> {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("file");
    let tmp = path.with_file_name(format!(".{name}.tmp{}", std::process::id()));
    let written = (|| {
        // A fresh file, never through a link or over something planted at the name.
        let _ = std::fs::remove_file(&tmp);
        let mut f = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        f.write_all(bytes)?;
        if sync {
            f.sync_all()?;
        }
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(io_err(path, "could not write")(e));
    }
    Ok(())
}

fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), StoreError> {
    let mut text = serde_json::to_vec_pretty(value).expect("store records serialise");
    text.push(b'\n');
    write_file(path, &text, true)
}

fn sync_dir(dir: &Path) -> Result<(), StoreError> {
    std::fs::File::open(dir).and_then(|d| d.sync_all()).map_err(io_err(dir, "could not sync the directory"))
}
