//! Tile sources: where texels come from (files described by a plan, or procedural textures).
//!
//! Owns texel *values* and the unit they are read in: the [`TileSource`] trait, its typed
//! [`SourceError`], the [`TextureDesc`] a source serves, the tile files a plan names
//! ([`FileSource`]), tiled GeoTIFFs and COGs served as they are ([`CogSource`]), the procedural sources ([`HashSource`], [`TerrainSource`]) and a
//! fault-injecting wrapper ([`FaultySource`]). Residency, queues and
//! windows belong to later modules ([`crate::cache`], [`crate::queue`], [`crate::clip`]).
//!
//! Tile layout (docs/ARCHITECTURE.md §11): a tile of level `k` is `tile[0] x tile[1]` texels, rows in
//! increasing t, s fastest. Texel (s, t) of tile (S, T) is at byte
//! `((t - T*tile[1]) * tile[0] + (s - S*tile[0])) * bytes_per_texel`. Texels of an edge tile that
//! lie outside the level are zero.

mod ahead;
pub mod bc;
pub mod cog;
pub mod configured;
mod configured_tiles;
pub mod desc;
pub mod faulty;
pub mod file;
pub mod global;
mod lzw;
pub mod merge;
pub mod pool;
pub mod procedural;
pub mod range;
#[cfg(feature = "remote")]
pub mod remote;
mod synthetic;
pub mod throttle;
pub mod tiles;

pub use crate::tile::TileId;
pub use bc::{BcQuality, BcSource};
pub use cog::{CogError, CogSource};
pub use configured::cog_of;
pub use desc::{level_count, level_size, DescError, LevelDesc, TextureDesc, MAX_TEXTURE_SIZE};
pub use faulty::{Fault, FaultRule, FaultySource};
pub use file::{FileSource, FileSourceError, FileStats};
pub use global::GlobalSource;
pub use pool::{PoolSource, PoolStats};
pub use synthetic::{HashSource, HeightLevels, HeightSource, Procedural, TerrainSource, TERRAIN_SEED};
pub use throttle::ThrottledSource;

use serde::Serialize;
use thiserror::Error;

/// What went wrong reading a tile, without its details: used for counting and fault injection.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// The tile (or its file) does not exist.
    Missing,
    /// Fewer bytes than a tile were available.
    Short,
    /// The data has the wrong size or layout.
    Corrupt,
    /// The tile exists but may not be read.
    PermissionDenied,
    /// Any other I/O failure.
    Io,
    /// A request for a tile that is not part of the texture, or into a wrong-sized buffer.
    BadRequest,
}

/// Why a tile could not be read.
#[derive(Debug, Error)]
pub enum SourceError {
    /// The tile (or the file holding it) does not exist.
    #[error("{tile}: missing")]
    Missing {
        /// The tile asked for.
        tile: TileId,
    },
    /// The read ended early.
    #[error("{tile}: short read: got {got} of {expected} bytes")]
    Short {
        /// The tile asked for.
        tile: TileId,
        /// The bytes a tile takes.
        expected: u64,
        /// The bytes there were.
        got: u64,
    },
    /// The stored tile has the wrong size.
    #[error("{tile}: corrupt: {found} bytes stored, expected {expected}")]
    Corrupt {
        /// The tile asked for.
        tile: TileId,
        /// The bytes a tile takes.
        expected: u64,
        /// The bytes stored.
        found: u64,
    },
    /// A compressed tile file (`.zst`, docs/COMPRESSED-TILES.md) that does not decode to exactly
    /// one tile.
    #[error("{tile}: compressed tile {path} cannot be used: {problem}; restore the file or prepare the pyramid again (clipprep --zstd)", path = path.display())]
    Undecodable {
        /// The tile asked for.
        tile: TileId,
        /// The compressed tile file.
        path: std::path::PathBuf,
        /// What the decoder found.
        problem: String,
    },
    /// A tile of a TIFF ([`CogSource`]) whose stored bytes cannot be used: its index entry or
    /// bytes out of place, or data that does not decode to one tile.
    #[error("{tile}: {path}: {problem}; the file is damaged or was changed while served: restore it", path = path.display())]
    Chunk {
        /// The tile asked for.
        tile: TileId,
        /// The TIFF file.
        path: std::path::PathBuf,
        /// What is wrong with the stored bytes.
        problem: String,
    },
    /// A tile of a tile pyramid ([`tiles::PyramidSource`]) that could not be read or used: the
    /// archive's or service's failure, or an answer that is not the tile (another image type, a
    /// wrong size, an HTML page, undecodable bytes).
    #[error("{tile}: {problem}")]
    Pyramid {
        /// The tile asked for.
        tile: TileId,
        /// The kind of failure.
        kind: FaultKind,
        /// The place, the pyramid tile, what was found and what was expected.
        problem: String,
    },
    /// The tile may not be read.
    #[error("{tile}: permission denied")]
    PermissionDenied {
        /// The tile asked for.
        tile: TileId,
    },
    /// Any other I/O failure.
    #[error("{tile}: I/O error: {source}")]
    Io {
        /// The tile asked for.
        tile: TileId,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// The tile is not part of the texture.
    #[error("{tile}: outside the texture: level has {tiles:?} tiles and {levels} levels exist")]
    OutOfRange {
        /// The tile asked for.
        tile: TileId,
        /// The level's tiles along s and t.
        tiles: [u64; 2],
        /// The levels the texture has.
        levels: usize,
    },
    /// The caller's buffer is not one tile long.
    #[error("{tile}: buffer holds {found} bytes, expected {expected}")]
    BufferSize {
        /// The tile asked for.
        tile: TileId,
        /// The bytes a tile takes.
        expected: usize,
        /// The bytes the caller's buffer holds.
        found: usize,
    },
    /// The source cannot read now (a simulated disk spent its reads for the tick,
    /// [`ThrottledSource`]): not a fault, the tile stays wanted and is asked for again.
    #[error("{tile}: put off: the source reads at most {per_tick} tiles a tick")]
    Busy {
        /// The tile asked for.
        tile: TileId,
        /// The most tiles the source reads a tick.
        per_tick: u64,
    },
}

impl SourceError {
    /// The kind of failure, for statistics.
    pub fn kind(&self) -> FaultKind {
        match self {
            SourceError::Missing { .. } => FaultKind::Missing,
            SourceError::Pyramid { kind, .. } => *kind,
            SourceError::Short { .. } => FaultKind::Short,
            SourceError::Corrupt { .. } | SourceError::Undecodable { .. } | SourceError::Chunk { .. } => {
                FaultKind::Corrupt
            }
            SourceError::PermissionDenied { .. } => FaultKind::PermissionDenied,
            SourceError::Io { .. } | SourceError::Busy { .. } => FaultKind::Io,
            SourceError::OutOfRange { .. } | SourceError::BufferSize { .. } => FaultKind::BadRequest,
        }
    }

    /// The tile the error is about.
    pub fn tile(&self) -> TileId {
        match self {
            SourceError::Missing { tile }
            | SourceError::Short { tile, .. }
            | SourceError::Corrupt { tile, .. }
            | SourceError::Undecodable { tile, .. }
            | SourceError::Chunk { tile, .. }
            | SourceError::Pyramid { tile, .. }
            | SourceError::PermissionDenied { tile }
            | SourceError::Io { tile, .. }
            | SourceError::OutOfRange { tile, .. }
            | SourceError::BufferSize { tile, .. }
            | SourceError::Busy { tile, .. } => *tile,
        }
    }
}

/// What a successful read put into the buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Delivered {
    /// The tile's own texels.
    Tile,
    /// The configuration's default tile, in place of a tile whose file is missing or short.
    Default,
}

/// Something tiles can be read from. Reads block (disk, network, computation): callers run them
/// off async worker threads (the read queue uses `spawn_blocking`).
pub trait TileSource: Send + Sync {
    /// The texture this source serves.
    fn desc(&self) -> &TextureDesc;

    /// Reads `tile` into `out`, which must be exactly [`TextureDesc::tile_bytes`] of its level
    /// long, laid out as described in the [module docs](self). On success every byte of `out` has
    /// been written (buffers are reused, so a byte left alone would be an old tile's); on error
    /// `out` holds no promise.
    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError>;

    /// [`read_tile`](Self::read_tile), saying what `out` got: the tile itself, or the
    /// configuration's default tile standing in for a tile that does not exist.
    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<Delivered, SourceError> {
        self.read_tile(tile, out).map(|()| Delivered::Tile)
    }

    /// The source this one wraps (a cache, a throttle, a fault injector in front of the real
    /// source), whose stream layout it keeps; `None` for a source of its own.
    fn wrapped(&self) -> Option<&dyn TileSource> {
        None
    }

    /// Whether the texels are heights, and their scale, offset, nodata value and level rule (the
    /// mapping's heights block): the [`wrapped`](Self::wrapped) source's, or `None` (colours).
    fn heights(&self) -> Option<crate::plan::HeightPlan> {
        self.wrapped().and_then(|inner| inner.heights())
    }

    /// Where the texture is on the Earth (docs/GEOREF.md): its CRS and level 0's transform, level
    /// k's being [`Georef::level_transform`](crate::georef::Georef::level_transform) of it. The
    /// [`wrapped`](Self::wrapped) source's, or `None` (a texture without georeferencing: the
    /// procedural sources, a plan's tile files).
    fn georef(&self) -> Option<crate::georef::Georef> {
        self.wrapped().and_then(|inner| inner.georef())
    }

    /// The counters of the remote reads (requests, retries, merged ranges, bytes, cache hits)
    /// of a source that reads over the network: the [`wrapped`](Self::wrapped) source's, or
    /// `None` for one that reads local files only.
    #[cfg(feature = "remote")]
    fn remote_stats(&self) -> Option<remote::RemoteStats> {
        self.wrapped().and_then(|inner| inner.remote_stats())
    }

    /// How many reads of stream server `stream` (of `streams`) the source can serve at once,
    /// when it knows better than the engine's fixed bound
    /// ([`Limits::max_in_flight_reads`](crate::limits::Limits)): a remote source answers with
    /// the requests in flight its endpoints allow now (sized from their latency and the rate
    /// of reads), and a read queue runs that many reads. The [`wrapped`](Self::wrapped)
    /// source's answer, or `None`.
    fn read_slots(&self, stream: usize, streams: usize) -> Option<usize> {
        self.wrapped().and_then(|inner| inner.read_slots(stream, streams))
    }

    /// Number of stream servers (separate disks, one read queue each) the source is laid out
    /// for: the [`wrapped`](Self::wrapped) source's, or 1 when it has no notion of them.
    fn stream_servers(&self) -> usize {
        self.wrapped().map_or(1, |inner| inner.stream_servers())
    }

    /// Which of `streams` read queues should read `tile` (`streams` >= 1): the
    /// [`wrapped`](Self::wrapped) source's answer, or by default the tile column modulo the number
    /// of queues; [`FileSource`] answers with the stream server its configuration names for the
    /// tile.
    fn stream_of(&self, tile: TileId, streams: usize) -> usize {
        match self.wrapped() {
            Some(inner) => inner.stream_of(tile, streams),
            None => (tile.s % streams.max(1) as u64) as usize,
        }
    }

    /// Says that `tiles` are about to be read (a read queue's run, most urgent first), so that a
    /// source that reads byte ranges of one object may read several of them with one request
    /// (docs/COG.md, "The request budget of a remote COG"). A hint only: a tile announced may be
    /// read or [withdrawn](Self::withdraw), and one never announced is read as well. The
    /// [`wrapped`](Self::wrapped) source is told; by default nothing else happens.
    fn will_read(&self, tiles: &[TileId]) {
        if let Some(inner) = self.wrapped() {
            inner.will_read(tiles);
        }
    }

    /// Says that `tile`, [announced](Self::will_read), will not be read after all: nothing more is
    /// fetched for it, and bytes fetched ahead for it are dropped.
    fn withdraw(&self, tile: TileId) {
        if let Some(inner) = self.wrapped() {
            inner.withdraw(tile);
        }
    }

    /// A number that changes each time any tile's texels may have changed at once: a remote COG
    /// replaced in its store and opened again ([`cog::Reopening`]). A clipmap that sees it change
    /// reads every tile it holds again ([`crate::clip::Clipmap::refresh`]). The
    /// [`wrapped`](Self::wrapped) source's, or 0 for a source whose tiles never change so.
    fn version(&self) -> u64 {
        self.wrapped().map_or(0, |inner| inner.version())
    }
}

/// Checks that `tile` exists in `desc` and that `out` is one tile long: the common preamble of
/// every [`TileSource::read_tile`].
pub(crate) fn check_request(desc: &TextureDesc, tile: TileId, out: &[u8]) -> Result<(), SourceError> {
    if tile.level as usize >= desc.level_count() {
        return Err(SourceError::OutOfRange { tile, tiles: [0, 0], levels: desc.level_count() });
    }
    let tiles = desc.level(tile.level).tiles();
    if tile.s >= tiles[0] || tile.t >= tiles[1] {
        return Err(SourceError::OutOfRange { tile, tiles, levels: desc.level_count() });
    }
    let expected = desc.tile_bytes(tile.level);
    if out.len() != expected {
        return Err(SourceError::BufferSize { tile, expected, found: out.len() });
    }
    Ok(())
}

/// Why [`open_plan`] cannot serve a plan.
#[derive(Debug, Error)]
pub enum OpenPlanError {
    /// The plan cannot be served (its levels, a default tile).
    #[error(transparent)]
    Files(#[from] FileSourceError),
    /// A remote source could not be set up (its options, its disk cache).
    #[error("{0}")]
    Remote(String),
    /// The COG a configuration names (`#clipmap cog`) cannot be served.
    #[error("{path}: the COG of its `#clipmap cog` line cannot be served: {source}", path = path.display())]
    Cog {
        /// The `.ct`.
        path: std::path::PathBuf,
        /// Why.
        #[source]
        source: Box<CogError>,
    },
    /// The tile pyramid the plan's `#clipmap source` line names cannot be served.
    #[error("{path}: the tile source of its `#clipmap source` line cannot be served: {problem}", path = path.display())]
    Pyramid {
        /// The `.ct`.
        path: std::path::PathBuf,
        /// Why, naming the source.
        problem: String,
    },
    /// The plan names remote locations, and this build cannot read them.
    #[error("{path} names remote locations (http://, https://, s3://), and this build cannot read them: build with the `remote` feature (on by default)", path = path.display())]
    NoRemote {
        /// The `.ct`.
        path: std::path::PathBuf,
    },
}

/// The source a plan is served from: the [`CogSource`] of the COG its `#clipmap cog` line
/// names (the one opened when the plan was loaded, else opened now), a [`FileSource`] when it
/// names local files only, a [`remote::RemoteSource`] (remote options from the
/// `CLIPMAP_REMOTE_*` variables) when it names a remote location.
pub fn open_plan(
    plan: crate::plan::ClipTexturePlan,
    limits: &crate::limits::Limits,
) -> Result<std::sync::Arc<dyn TileSource>, OpenPlanError> {
    // A configuration naming a tile pyramid (`#clipmap source`, docs/TILES.md): the pyramid,
    // served as `clipmapd NAME --clip CLIP_SIZE` serves it.
    if let Some(line) = &plan.source {
        // Opened once: the loader that checked the `.ct` against it kept it.
        if let Some(src) = configured_tiles::pyramid_of(line) {
            return Ok(src);
        }
        let src = tiles::open(&line.name, &configured_tiles::options(&plan))
            .unwrap_or_else(|| {
                Err(tiles::PyramidError::Info { place: line.name.clone(), problem: "names no tile source".into() })
            })
            .map_err(|e| OpenPlanError::Pyramid { path: plan.path.clone(), problem: e.to_string() })?;
        return Ok(std::sync::Arc::new(src));
    }
    // A configuration naming a COG (`#clipmap cog`, docs/COG.md): the COG, served as
    // `clipmapd FILE.tif --clip CLIP_SIZE` serves it.
    if let Some(cog) = &plan.cog {
        let src = match cog_of(cog) {
            Some(src) => src,
            None => std::sync::Arc::new(
                CogSource::open_place(&cog.place, plan.clip_size)
                    .map_err(|e| OpenPlanError::Cog { path: plan.path.clone(), source: Box::new(e) })?,
            ),
        };
        // A remote object replaced in its store is opened again, as `clipmapd URL` does.
        #[cfg(feature = "remote")]
        if let crate::place::Place::Remote(name) = &cog.place {
            if let Some(r) = cog::Reopening::serving(name, std::sync::Arc::clone(&src), plan.clip_size) {
                return Ok(std::sync::Arc::new(r));
            }
        }
        return Ok(src);
    }
    #[cfg(feature = "remote")]
    {
        if plan.names_remote() {
            let opts = remote::RemoteOptions::from_env().map_err(|e| OpenPlanError::Remote(e.to_string()))?;
            let src = remote::RemoteSource::new(plan, limits, opts).map_err(|e| match e {
                remote::RemoteSourceError::Plan(p) => OpenPlanError::Files(p),
                other => OpenPlanError::Remote(other.to_string()),
            })?;
            return Ok(std::sync::Arc::new(src));
        }
    }
    #[cfg(not(feature = "remote"))]
    {
        if plan.names_remote() {
            return Err(OpenPlanError::NoRemote { path: plan.path.clone() });
        }
    }
    Ok(std::sync::Arc::new(FileSource::new(plan, limits)?))
}
