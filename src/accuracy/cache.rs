//! A bounded tile cache in front of a [`TileSource`], so the reference renderer does not rebuild
//! procedural tiles for every frame and thread.

use crate::source::{SourceError, TextureDesc, TileId, TileSource};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// Caches up to `capacity` tiles of `inner` (cleared whole when full: the study's access pattern
/// moves slowly, so a simple policy suffices).
pub(crate) struct CachedSource {
    inner: Arc<dyn TileSource>,
    tiles: Mutex<HashMap<TileId, Arc<Vec<u8>>>>,
    capacity: usize,
}

impl CachedSource {
    /// A cache of `capacity` tiles over `inner`.
    pub fn new(inner: Arc<dyn TileSource>, capacity: usize) -> Self {
        CachedSource { inner, tiles: Mutex::new(HashMap::new()), capacity: capacity.max(1) }
    }
}

impl TileSource for CachedSource {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        let hit = self.tiles.lock().expect("tile cache lock").get(&tile).cloned();
        if let Some(t) = hit {
            out.copy_from_slice(&t);
            return Ok(());
        }
        self.inner.read_tile(tile, out)?;
        let mut tiles = self.tiles.lock().expect("tile cache lock");
        if tiles.len() >= self.capacity {
            tiles.clear();
        }
        tiles.insert(tile, Arc::new(out.to_vec()));
        Ok(())
    }
}
