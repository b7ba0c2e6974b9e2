//! Tiles read once for several grid sets (docs/VIEWS.md, "Views far apart"): a view with grids
//! of its own is held by a clipmap of its own, whose coarse levels cover the same tiles as the
//! primary's. [`FromMapping`] stands in front of such a clipmap's source and takes a tile from
//! the primary's mapping when one of its slots holds it ready, reading the source only for the
//! others: the pyramid levels and every other tile both grid sets hold are read from the source
//! once.
//!
//! It reads the mapping as any reader does ([`Client::read_tile`]: the whole slot under its
//! tag, taken only when the tag says the slot holds that tile, ready, before and after the
//! copy), so a slot the primary's engine reassigns meanwhile gives a fall-back to the source,
//! never a wrong tile.
//!
//! Of the tiles a read queue announces ([`TileSource::will_read`]), only those the mapping does
//! not hold are announced to the source, and a tile taken from the mapping is withdrawn from the
//! source ([`TileSource::withdraw`]): a remote COG then never fetches bytes ahead for a tile the
//! mapping gives.
//!
//! A tile is taken only when the mapping's copy is of the texels the source serves now
//! ([`Freshness`]): the mapping's clipmap says which version of the source it last followed
//! ([`TileSource::version`]: a remote COG replaced and opened again) and which tiles it is still
//! replacing (a growing texture's patch, a new version); a tile of another version, or one whose
//! slot still holds its texels from before the change, is read from the source. Without that, a
//! clipmap that follows a change sooner than the mapping's would copy the old texels back and
//! keep them.

use super::layout::SlotState;
use super::Client;
use crate::source::{Delivered, SourceError, TextureDesc, TileId, TileSource};
use std::collections::HashSet;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

/// Which of a mapping's tiles are of the texels its source serves now, as the mapping's writer
/// (its clipmap's tick) last said: the source version it followed and the tiles it is replacing.
/// Shared between that writer and every [`FromMapping`] over the mapping, in one process.
#[derive(Debug, Default)]
pub struct Freshness {
    state: Mutex<Fresh>,
}

#[derive(Debug, Default)]
struct Fresh {
    version: u64,
    stale: HashSet<TileId>,
}

impl Freshness {
    /// Says that every tile the mapping holds is of source version `version` (or later), except
    /// `stale`, whose slots may hold the texels from before a change
    /// ([`crate::clip::Clipmap::followed_version`], [`crate::clip::Clipmap::tiles_being_replaced`]).
    pub fn set(&self, version: u64, stale: impl IntoIterator<Item = TileId>) {
        let mut f = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        f.version = version;
        f.stale.clear();
        f.stale.extend(stale);
    }

    /// Whether the mapping's copy of `tile` may be taken by a reader of source version `version`.
    pub fn allows(&self, tile: TileId, version: u64) -> bool {
        let f = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        f.version == version && !f.stale.contains(&tile)
    }
}

/// A source that takes each tile from a mapping's slots when they hold it (module docs).
pub struct FromMapping {
    inner: Arc<dyn TileSource>,
    mapping: Client,
    fresh: Arc<Freshness>,
    hits: AtomicU64,
}

impl std::fmt::Debug for FromMapping {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FromMapping").field("mapping", &self.mapping.path()).field("hits", &self.hits()).finish()
    }
}

impl FromMapping {
    /// Reads through `inner`, taking tiles from `mapping` (a mapping of the same texture) when
    /// its slots hold them. Nobody says what of the mapping is fresh: while `inner`'s version is
    /// 0 every tile held is taken, after a change of version none (use
    /// [`following`](Self::following) for a source whose texels change).
    pub fn new(inner: Arc<dyn TileSource>, mapping: Client) -> FromMapping {
        FromMapping::following(inner, mapping, Arc::default())
    }

    /// As [`new`](Self::new), taking a tile only while `fresh` (kept by the mapping's writer)
    /// says that the mapping's copy is of the version `inner` serves and not being replaced.
    pub fn following(inner: Arc<dyn TileSource>, mapping: Client, fresh: Arc<Freshness>) -> FromMapping {
        FromMapping { inner, mapping, fresh, hits: AtomicU64::new(0) }
    }

    /// Whether the mapping's copy of `tile` is of the texels `inner` serves now.
    fn fresh(&self, tile: TileId) -> bool {
        // The version first: a change after this is followed by the reader's clipmap, which
        // reads again every tile it was reading meanwhile.
        self.fresh.allows(tile, self.inner.version())
    }

    /// Tiles taken from the mapping rather than read from the source.
    pub fn hits(&self) -> u64 {
        self.hits.load(Ordering::Relaxed)
    }
}

impl TileSource for FromMapping {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.read_into(tile, out).map(|_| ())
    }

    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<Delivered, SourceError> {
        let at = [tile.s as i64, tile.t as i64];
        let taken =
            if self.fresh(tile) { self.mapping.read_tile_state(tile.level as usize, at, out).ok() } else { None };
        if let Some(state) = taken {
            self.hits.fetch_add(1, Ordering::Relaxed);
            // Announced while the mapping did not hold it, perhaps: nothing is to be fetched.
            self.inner.withdraw(tile);
            // The configuration's default tile stands in for a missing one here as there.
            return Ok(if state == SlotState::Default { Delivered::Default } else { Delivered::Tile });
        }
        self.inner.read_into(tile, out)
    }

    fn will_read(&self, tiles: &[TileId]) {
        let from_source: Vec<TileId> = tiles
            .iter()
            .copied()
            .filter(|&t| !(self.fresh(t) && self.mapping.holds_tile(t.level as usize, [t.s as i64, t.t as i64])))
            .collect();
        if !from_source.is_empty() {
            self.inner.will_read(&from_source);
        }
    }

    fn withdraw(&self, tile: TileId) {
        self.inner.withdraw(tile);
    }

    fn wrapped(&self) -> Option<&dyn TileSource> {
        Some(&*self.inner)
    }
}
