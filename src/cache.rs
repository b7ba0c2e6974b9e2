//! Per-level tile caches: the mem regions of main memory.
//!
//! Owns, for every level, a toroidal grid of tile slots covering the level's mem region (tile
//! (S, T) lives in slot (S mod grid_w, T mod grid_h)), the state of each slot (absent, loading,
//! resident, failed) and the hard byte budget on resident tiles. It decides nothing about *which*
//! region to hold ([`crate::geom`]) nor how tiles are read ([`crate::queue`]).

use crate::geom::{wrap, Rect};
use crate::source::{FaultKind, TextureDesc, TileId};
use serde::Serialize;

/// The state of one tile of a mem region.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TileState {
    /// Not in memory and not requested (or outside the mem region).
    Absent,
    /// Requested from the read queue.
    Loading,
    /// In memory, texels valid.
    Resident,
    /// The last read failed; it is asked for again from tick `retry_at` on.
    Failed { kind: FaultKind, retry_at: u64 },
}

/// What happened to a tile offered to the cache.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Admit {
    /// Stored; its texels may be copied.
    Admitted,
    /// The tile left the mem region while it was read: discarded.
    Stale,
    /// Storing it would exceed the byte budget: discarded.
    OverBudget,
    /// The buffer is not one tile long: discarded.
    WrongSize,
}

#[derive(Clone, Debug)]
struct Slot {
    tile: Option<[i64; 2]>,
    state: TileState,
    data: Option<Vec<u8>>,
}

const EMPTY_SLOT: Slot = Slot { tile: None, state: TileState::Absent, data: None };

/// One level's grid of slots.
#[derive(Clone, Debug)]
struct LevelCache {
    grid: [u64; 2],
    tile_bytes: usize,
    mem: Rect,
    slots: Vec<Slot>,
}

impl LevelCache {
    fn slot_index(&self, st: [i64; 2]) -> usize {
        (wrap(st[1], self.grid[1]) * self.grid[0] + wrap(st[0], self.grid[0])) as usize
    }

    fn slot(&self, st: [i64; 2]) -> Option<&Slot> {
        let slot = &self.slots[self.slot_index(st)];
        (self.mem.contains(st[0], st[1]) && slot.tile == Some(st)).then_some(slot)
    }
}

/// The tile caches of every level, under one byte budget.
#[derive(Clone, Debug)]
pub struct TileCache {
    levels: Vec<LevelCache>,
    budget: usize,
    resident_bytes: usize,
    peak_bytes: usize,
}

impl TileCache {
    /// Empty caches for every level of `desc`, level `k` `grids[k]` tiles a side (the engine's
    /// [`crate::geom::level_grid`]), holding at most `budget` bytes of tiles in all.
    pub fn new(desc: &TextureDesc, grids: &[[u64; 2]], budget: usize) -> Self {
        let levels = desc
            .levels()
            .iter()
            .enumerate()
            .map(|(k, _)| {
                let grid = grids[k];
                let n = (grid[0] * grid[1]) as usize;
                LevelCache { grid, tile_bytes: desc.tile_bytes(k as u32), mem: Rect::EMPTY, slots: vec![EMPTY_SLOT; n] }
            })
            .collect();
        TileCache { levels, budget, resident_bytes: 0, peak_bytes: 0 }
    }

    /// Slots per axis of level `k`'s grid.
    pub fn grid(&self, k: u32) -> [u64; 2] {
        self.levels[k as usize].grid
    }

    /// Level `k`'s current mem region (tile indices).
    pub fn mem_region(&self, k: u32) -> Rect {
        self.levels[k as usize].mem
    }

    /// Moves level `k`'s mem region to `mem` (at most grid-sized): tiles that left are freed, new
    /// tiles start absent. Returns the number of resident tiles evicted.
    pub fn set_mem_region(&mut self, k: u32, mem: Rect) -> u64 {
        self.set_mem_region_recycling(k, mem, drop)
    }

    /// [`set_mem_region`](Self::set_mem_region), handing each evicted tile's buffer to `recycle`.
    pub fn set_mem_region_recycling(&mut self, k: u32, mem: Rect, mut recycle: impl FnMut(Vec<u8>)) -> u64 {
        let level = &mut self.levels[k as usize];
        debug_assert!(mem.width() <= level.grid[0] && mem.height() <= level.grid[1], "mem region larger than grid");
        level.mem = mem;
        let mut evicted = 0;
        let mut freed = 0;
        for t in mem.t0..mem.t1 {
            for s in mem.s0..mem.s1 {
                let i = level.slot_index([s, t]);
                let slot = &mut level.slots[i];
                if slot.tile != Some([s, t]) {
                    if let Some(buf) = slot.data.take() {
                        evicted += 1;
                        freed += level.tile_bytes;
                        recycle(buf);
                    }
                    *slot = Slot { tile: Some([s, t]), state: TileState::Absent, data: None };
                }
            }
        }
        // Slots outside a region smaller than the grid (edges of small levels) hold nothing.
        let (gw, gh) = (level.grid[0] as i64, level.grid[1] as i64);
        if mem.area() < (gw * gh) as u64 {
            for slot in level.slots.iter_mut() {
                if slot.tile.is_some_and(|[s, t]| !mem.contains(s, t)) {
                    if let Some(buf) = slot.data.take() {
                        evicted += 1;
                        freed += level.tile_bytes;
                        recycle(buf);
                    }
                    *slot = EMPTY_SLOT;
                }
            }
        }
        self.resident_bytes -= freed;
        evicted
    }

    /// The state of `tile` ([`TileState::Absent`] when outside its level's mem region).
    pub fn state(&self, tile: TileId) -> TileState {
        self.level_slot(tile).map_or(TileState::Absent, |s| s.state)
    }

    fn level_slot(&self, tile: TileId) -> Option<&Slot> {
        self.levels.get(tile.level as usize)?.slot([tile.s as i64, tile.t as i64])
    }

    fn level_slot_mut(&mut self, tile: TileId) -> Option<&mut Slot> {
        let level = self.levels.get_mut(tile.level as usize)?;
        let st = [tile.s as i64, tile.t as i64];
        if !level.mem.contains(st[0], st[1]) {
            return None;
        }
        let i = level.slot_index(st);
        let slot = &mut level.slots[i];
        (slot.tile == Some(st)).then_some(slot)
    }

    /// Notes that `tile` was requested (ignored unless it is absent or failed in its mem region).
    pub fn mark_loading(&mut self, tile: TileId) {
        if let Some(slot) = self.level_slot_mut(tile) {
            if matches!(slot.state, TileState::Absent | TileState::Failed { .. }) {
                slot.state = TileState::Loading;
            }
        }
    }

    /// Notes that reading `tile` failed; it will be wanted again from tick `retry_at`.
    pub fn mark_failed(&mut self, tile: TileId, kind: FaultKind, retry_at: u64) {
        if let Some(slot) = self.level_slot_mut(tile) {
            if slot.state != TileState::Resident {
                slot.state = TileState::Failed { kind, retry_at };
            }
        }
    }

    /// Offers the texels of `tile`.
    pub fn admit(&mut self, tile: TileId, data: Vec<u8>) -> Admit {
        let Some(level) = self.levels.get(tile.level as usize) else { return Admit::Stale };
        let tile_bytes = level.tile_bytes;
        if data.len() != tile_bytes {
            return Admit::WrongSize;
        }
        let (budget, used) = (self.budget, self.resident_bytes);
        let Some(slot) = self.level_slot_mut(tile) else { return Admit::Stale };
        if slot.data.is_none() {
            if used + tile_bytes > budget {
                return Admit::OverBudget;
            }
            slot.data = Some(data);
            self.resident_bytes += tile_bytes;
            self.peak_bytes = self.peak_bytes.max(self.resident_bytes);
        } else {
            slot.data = Some(data);
        }
        if let Some(slot) = self.level_slot_mut(tile) {
            slot.state = TileState::Resident;
        }
        Admit::Admitted
    }

    /// The texels of `tile` if it is resident.
    pub fn texels(&self, tile: TileId) -> Option<&[u8]> {
        let slot = self.level_slot(tile)?;
        (slot.state == TileState::Resident).then_some(slot.data.as_deref()?)
    }

    /// Tiles of level `k`'s mem region that should be read at tick `now`: absent, loading (still
    /// wanted, so their priority is refreshed) or failed with their retry time reached.
    pub fn wanted(&self, k: u32, now: u64) -> Vec<TileId> {
        let level = &self.levels[k as usize];
        let mut out = Vec::new();
        for t in level.mem.t0..level.mem.t1 {
            for s in level.mem.s0..level.mem.s1 {
                let want = match level.slots[level.slot_index([s, t])].state {
                    TileState::Absent | TileState::Loading => true,
                    TileState::Failed { retry_at, .. } => retry_at <= now,
                    TileState::Resident => false,
                };
                if want {
                    out.push(TileId::new(k, s as u64, t as u64));
                }
            }
        }
        out
    }

    /// Bytes of resident tiles now.
    pub fn resident_bytes(&self) -> usize {
        self.resident_bytes
    }

    /// Most bytes of resident tiles ever held.
    pub fn peak_bytes(&self) -> usize {
        self.peak_bytes
    }

    /// The byte budget.
    pub fn budget(&self) -> usize {
        self.budget
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::mem_grid;
    use crate::texel::TexelFormat;

    fn cache(budget: usize) -> (TextureDesc, TileCache) {
        let desc = TextureDesc::new([256, 256], 32, TexelFormat::L8, [16, 16]).unwrap();
        let grids: Vec<[u64; 2]> =
            desc.levels().iter().map(|l| mem_grid(l.size, l.tile, desc.clip_size(), 1)).collect();
        let cache = TileCache::new(&desc, &grids, budget);
        (desc, cache)
    }

    #[test]
    fn tiles_move_through_loading_resident_and_leave_with_the_mem_region() {
        let (_, mut c) = cache(1 << 20);
        assert_eq!(c.grid(0), [4, 4]);
        c.set_mem_region(0, Rect::new(2, 2, 6, 6));
        assert_eq!(c.wanted(0, 0).len(), 16);
        let tile = TileId::new(0, 3, 4);
        c.mark_loading(tile);
        assert_eq!(c.state(tile), TileState::Loading);
        assert_eq!(c.admit(tile, vec![7; 256]), Admit::Admitted);
        assert_eq!(c.texels(tile).unwrap()[0], 7);
        assert_eq!(c.wanted(0, 0).len(), 15);
        assert_eq!(c.resident_bytes(), 256);
        // Moving by one tile keeps (3, 4) (same slot) and evicts nothing else resident.
        assert_eq!(c.set_mem_region(0, Rect::new(3, 2, 7, 6)), 0);
        assert_eq!(c.state(tile), TileState::Resident);
        // Moving away evicts it; a late copy of it is stale.
        assert_eq!(c.set_mem_region(0, Rect::new(8, 8, 12, 12)), 1);
        assert_eq!(c.resident_bytes(), 0);
        assert_eq!(c.state(tile), TileState::Absent);
        assert_eq!(c.admit(tile, vec![7; 256]), Admit::Stale);
        assert_eq!(c.peak_bytes(), 256);
    }

    #[test]
    fn the_byte_budget_is_never_exceeded() {
        let (_, mut c) = cache(3 * 256);
        c.set_mem_region(0, Rect::new(0, 0, 4, 4));
        let results: Vec<Admit> = (0..4).map(|s| c.admit(TileId::new(0, s, 0), vec![0; 256])).collect();
        assert_eq!(results[..3], [Admit::Admitted; 3]);
        assert_eq!(results[3], Admit::OverBudget);
        assert_eq!(c.resident_bytes(), 768);
        assert_eq!(c.admit(TileId::new(0, 0, 1), vec![0; 255]), Admit::WrongSize);
        // Replacing a resident tile costs nothing extra.
        assert_eq!(c.admit(TileId::new(0, 0, 0), vec![1; 256]), Admit::Admitted);
        assert_eq!(c.resident_bytes(), 768);
    }

    #[test]
    fn failed_tiles_are_wanted_again_at_their_retry_tick() {
        let (_, mut c) = cache(1 << 20);
        c.set_mem_region(0, Rect::new(0, 0, 1, 1));
        let tile = TileId::new(0, 0, 0);
        c.mark_failed(tile, FaultKind::Missing, 5);
        assert!(c.wanted(0, 4).is_empty());
        assert_eq!(c.wanted(0, 5), vec![tile]);
        assert!(c.texels(tile).is_none());
    }
}
