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

use super::layout::SlotState;
use super::Client;
use crate::source::{Delivered, SourceError, TextureDesc, TileId, TileSource};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// A source that takes each tile from a mapping's slots when they hold it (module docs).
pub struct FromMapping {
    inner: Arc<dyn TileSource>,
    mapping: Client,
    hits: AtomicU64,
}

impl std::fmt::Debug for FromMapping {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FromMapping").field("mapping", &self.mapping.path()).field("hits", &self.hits()).finish()
    }
}

impl FromMapping {
    /// Reads through `inner`, taking tiles from `mapping` (a mapping of the same texture) when
    /// its slots hold them.
    pub fn new(inner: Arc<dyn TileSource>, mapping: Client) -> FromMapping {
        FromMapping { inner, mapping, hits: AtomicU64::new(0) }
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
        if let Ok(state) = self.mapping.read_tile_state(tile.level as usize, at, out) {
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
            .filter(|t| !self.mapping.holds_tile(t.level as usize, [t.s as i64, t.t as i64]))
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
