//! Tiles read again in place: a growing texture's rebuilt tiles and a replaced source's (the clipmap's refresh queue).

use super::*;

impl Clipmap {
    /// Says that the source's texels of `tiles` changed (a growing texture rebuilt them): each
    /// one the clipmap holds resident (or defaulted) is read again into its slot, in place, through
    /// the read queues like any tile (same priorities, same queues and bounds, counted in the
    /// queues' counters), while its level stays published: a coming tick opens the slot (its tag
    /// says loading while its bytes change, so readers fall back to a coarser level for that tile
    /// only, or discard what they copied) and asks for the tile, a queue's thread reads it into the
    /// slot, and the tick that takes the read settles it, ready (or the default tile), or missing
    /// if the read failed (read again after the retry delay). At most 16 tiles per read slot of the
    /// queues (a run of reads each) are replaced at once. A tile
    /// whose read is under way (a first read or a replacement) is replaced once it has settled
    /// (its read may have started before the change); one whose read failed (a tile with no data
    /// yet) is read again at once; one the clipmap does not hold needs nothing (its read, when it
    /// enters a mem region, sees the change). A tile that leaves its mem region while it is
    /// replaced is dropped like any read. A second-level pool's copy of each tile is dropped.
    pub fn refresh(&mut self, tiles: impl IntoIterator<Item = TileId>) {
        for t in tiles {
            if (t.level as usize) < self.levels.len() && self.refreshing.insert(t) {
                if let Some(pool) = &self.pool {
                    pool.forget(t);
                }
                self.refresh.push_back(t);
            }
        }
    }

    /// When the source says that any tile may have changed ([`TileSource::version`]: a remote
    /// COG replaced in its store and opened again), reads every tile held again, as
    /// [`refresh`](Self::refresh) does.
    pub(super) fn follow_source_version(&mut self) {
        let now = self.source.version();
        if now == self.source_version {
            return;
        }
        self.source_version = now;
        let held: Vec<TileId> = (0..self.levels.len() as u32)
            .flat_map(|k| {
                let mem = self.cache.mem_region(k);
                // A wrapping level's columns may run past its tiles: tile U is tile U mod n.
                let period = self.levels[k as usize].shape.tile_period();
                let real = move |s: i64| period.map_or(s, |n| crate::geom::wrap(s, n) as i64);
                let lo = if period.is_some() { mem.s0 } else { mem.s0.max(0) };
                (mem.t0.max(0)..mem.t1)
                    .flat_map(move |t| (lo..mem.s1).map(move |s| TileId::new(k, real(s) as u64, t as u64)))
            })
            .filter(|&t| self.holds(t))
            .collect();
        self.stats.source_versions += 1;
        self.refresh(held);
    }

    /// Whether the clipmap holds `tile` in a slot (loading, settled or failed).
    pub fn holds(&self, tile: TileId) -> bool {
        (tile.level as usize) < self.levels.len() && self.cache.state(tile) != TileState::Absent
    }

    /// Tiles waiting to be replaced in their slots, or being replaced (their reads not yet taken).
    pub fn refresh_pending(&self) -> usize {
        self.refresh.len() + self.replacing.len()
    }

    /// The tiles [`refresh_pending`](Self::refresh_pending) counts: until a tile leaves them, its
    /// slot may still hold the texels it had before the change (a slot waiting for its
    /// replacement is still published ready).
    pub fn tiles_being_replaced(&self) -> impl Iterator<Item = TileId> + '_ {
        self.refreshing.iter().chain(self.replacing.iter()).copied()
    }

    /// The source's [`TileSource::version`] this clipmap last followed: every tile it holds is of
    /// that version or a later one, except [`tiles_being_replaced`](Self::tiles_being_replaced).
    pub fn followed_version(&self) -> u64 {
        self.source_version
    }

    /// Opens the slots of waiting [`refresh`](Self::refresh)ed tiles for their new texels (the
    /// read queues are asked for them with the tick's other reads), up to the bound on
    /// replacements under way. The tick reads nothing itself.
    pub(super) fn replace_tiles(&mut self) {
        // Replacements that ended, or left with their mem region (their requests dropped).
        let cache = &self.cache;
        self.replacing.retain(|&t| cache.state(t) == TileState::Replacing);
        let slots = self.queues.streams() * self.settings.limits.max_in_flight_reads.max(1);
        let bound = slots.saturating_mul(MAX_REPLACING_PER_READ_SLOT);
        for _ in 0..self.refresh.len() {
            if self.replacing.len() >= bound {
                break;
            }
            let Some(tile) = self.refresh.pop_front() else { break };
            match self.cache.state(tile) {
                TileState::Loading | TileState::Replacing => {
                    // Its read may predate the change: replace it after it settles.
                    self.refresh.push_back(tile);
                    continue;
                }
                TileState::Resident | TileState::Defaulted => {}
                TileState::Failed { .. } => {
                    // Read again at once (not after the retry delay): the source has its data now.
                    self.refreshing.remove(&tile);
                    self.cache.retry_now(tile, self.tick);
                    continue;
                }
                TileState::Absent => {
                    self.refreshing.remove(&tile);
                    continue;
                }
            }
            self.refreshing.remove(&tile);
            // No read of it is under way (it is settled): a pooled copy dropped now cannot come
            // back with the old texels.
            if let Some(pool) = &self.pool {
                pool.forget(tile);
            }
            if self.cache.replace(tile) {
                self.replacing.insert(tile);
            }
        }
    }
}
