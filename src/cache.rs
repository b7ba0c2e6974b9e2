//! Per-level image caches: the mem regions of main memory, as toroidal grids of whole tiles.
//!
//! Owns, for every level, which tile each slot of its grid should hold (tile (S, T) lives in slot
//! (S mod grid width, T mod grid height)) and what the engine knows of it (absent, loading,
//! resident, defaulted, failed, replacing). The slots' bytes and tags live in an [`ImageMemory`]
//! (the service's mapping, or anonymous memory): reads write there directly, and this module only
//! moves claims (`ImageMemory::assign`, `ImageMemory::replace`, `ImageMemory::settle`). It
//! decides nothing about *which* region to hold ([`crate::geom`]) nor how tiles are read
//! ([`crate::queue`]).

use crate::geom::{wrap, Rect};
use crate::shm::layout::SlotState;
use crate::shm::memory::Assign;
use crate::shm::{ImageMemory, SlotKeeper};
use crate::source::{Delivered, FaultKind, TileId};
use serde::Serialize;
use std::sync::Arc;

/// The state of one tile of a mem region.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TileState {
    /// Not in memory and not requested (or outside the mem region, or waiting for its slot).
    Absent,
    /// Requested from the read queue.
    Loading,
    /// In its slot, texels valid.
    Resident,
    /// The configuration's default tile is in its slot (the tile's file does not exist).
    Defaulted,
    /// The last read failed (readers use a coarser level for it); it is asked for again from
    /// tick `retry_at` on.
    Failed {
        /// What went wrong.
        kind: FaultKind,
        /// The tick from which it is asked for again.
        retry_at: u64,
    },
    /// Was resident (or defaulted) and is being read again into its slot, in place, because its
    /// texels changed at the source ([`crate::clip::Clipmap::refresh`]): asked of the read queues
    /// like any tile. Settled (its level stays published), not readable: the slot's tag says
    /// loading, so readers use a coarser level for this tile until the read settles it.
    Replacing,
}

impl TileState {
    /// True when nothing more is expected for the tile now (it can be published).
    pub fn settled(self) -> bool {
        matches!(self, TileState::Resident | TileState::Defaulted | TileState::Failed { .. } | TileState::Replacing)
    }

    /// True when its texels may be read.
    pub fn readable(self) -> bool {
        matches!(self, TileState::Resident | TileState::Defaulted)
    }
}

/// What happened to a finished read offered to the cache.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Admit {
    /// The slot holds the tile now.
    Admitted,
    /// The slot holds the tile's new texels now: a replacement in place
    /// ([`TileCache::replace`]) ended.
    Replaced,
    /// The tile left the mem region (or its slot was given to another) while it was read.
    Stale,
}

#[derive(Clone, Copy, Debug)]
struct Slot {
    /// The tile the engine wants in this slot.
    tile: Option<[i64; 2]>,
    state: TileState,
    /// True once the slot's claim and tag were moved to `tile` (`ImageMemory::assign`).
    assigned: bool,
}

const EMPTY_SLOT: Slot = Slot { tile: None, state: TileState::Absent, assigned: false };

/// One level's grid of slots.
#[derive(Clone, Debug)]
struct LevelCache {
    grid: [u64; 2],
    /// The mem region, in tile indices; on a wrapping level its columns may run past the
    /// level's tiles (tile U is tile U mod `period`).
    mem: Rect,
    slots: Vec<Slot>,
    /// The level's tiles across when it wraps along s (the grid width divides it, so tile U
    /// and tile U mod `period` take the same slot), `None` otherwise.
    period: Option<u64>,
}

impl LevelCache {
    fn slot_index(&self, st: [i64; 2]) -> usize {
        (wrap(st[1], self.grid[1]) * self.grid[0] + wrap(st[0], self.grid[0])) as usize
    }

    /// The level's own tile of tile index `st` of the mem region (column modulo the tiles
    /// across on a wrapping level).
    fn real(&self, st: [i64; 2]) -> [i64; 2] {
        match self.period {
            Some(n) => [wrap(st[0], n) as i64, st[1]],
            None => st,
        }
    }

    /// Whether tile `st` (the level's own index) is in the mem region.
    fn in_mem(&self, st: [i64; 2]) -> bool {
        crate::geom::contains_wrapped(&self.mem, st[0], st[1], self.period)
    }

    fn slot(&self, st: [i64; 2]) -> Option<&Slot> {
        let slot = &self.slots[self.slot_index(st)];
        (self.in_mem(st) && slot.tile == Some(st)).then_some(slot)
    }
}

/// The image caches of every level, over one [`ImageMemory`].
#[derive(Debug)]
pub struct TileCache {
    levels: Vec<LevelCache>,
    memory: Arc<ImageMemory>,
    /// The memory's one keeper: assigning and reopening slots take it `&mut`, copying settled
    /// ones `&` (`ImageMemory::read_settled`), so no copy overlaps a slot's rewrite.
    keeper: SlotKeeper,
}

impl TileCache {
    /// Empty caches for every level, level `k` `grids[k]` tiles a side (the engine's
    /// `crate::geom::level_grid`), their slots in `memory` (laid out for the same grids), which
    /// `keeper` (`ImageMemory::take_keeper`) is the keeper of.
    pub fn new(grids: &[[u64; 2]], memory: Arc<ImageMemory>, keeper: SlotKeeper) -> Self {
        let levels = grids
            .iter()
            .map(|&grid| LevelCache {
                grid,
                mem: Rect::EMPTY,
                slots: vec![EMPTY_SLOT; (grid[0] * grid[1]) as usize],
                period: None,
            })
            .collect();
        TileCache { levels, memory, keeper }
    }

    /// The memory the slots live in.
    pub fn memory(&self) -> &Arc<ImageMemory> {
        &self.memory
    }

    /// Level `k` wraps along s with `period` tiles across (`None`: it does not): its mem
    /// regions may run past its tiles, tile U being tile U mod `period`. The grid width must
    /// divide `period` ([`crate::geom::wrap_grid`]). Call before the first mem region.
    pub(crate) fn set_tile_period(&mut self, k: u32, period: Option<u64>) {
        let level = &mut self.levels[k as usize];
        debug_assert!(
            period.is_none_or(|n| n % level.grid[0] == 0),
            "a wrapping grid's width divides the tiles across"
        );
        level.period = period;
    }

    /// Slots per axis of level `k`'s grid (the engine keeps its own; the tests check this).
    #[cfg(test)]
    pub fn grid(&self, k: u32) -> [u64; 2] {
        self.levels[k as usize].grid
    }

    /// Level `k`'s current mem region (tile indices).
    pub fn mem_region(&self, k: u32) -> Rect {
        self.levels[k as usize].mem
    }

    /// Moves level `k`'s mem region to `mem` (at most grid-sized): each slot whose tile left is
    /// given to the tile that now maps to it (tag to loading, then claim). Call only after a
    /// publication that no longer covers the tiles that left. A slot a read is still filling
    /// keeps its old tile until a later call. Returns the number of settled tiles evicted.
    pub(crate) fn set_mem_region(&mut self, k: u32, mem: Rect) -> u64 {
        let memory = Arc::clone(&self.memory);
        let level = &mut self.levels[k as usize];
        debug_assert!(mem.width() <= level.grid[0] && mem.height() <= level.grid[1], "mem region larger than grid");
        level.mem = mem;
        let mut evicted = 0;
        for t in mem.t0..mem.t1 {
            for u in mem.s0..mem.s1 {
                let [s, t] = level.real([u, t]);
                let i = level.slot_index([s, t]);
                let slot = &mut level.slots[i];
                if slot.tile != Some([s, t]) {
                    if slot.state.settled() {
                        evicted += 1;
                    }
                    *slot = Slot { tile: Some([s, t]), state: TileState::Absent, assigned: false };
                }
                if !slot.assigned {
                    slot.assigned = memory.assign(&mut self.keeper, k, [s, t]) == Assign::Assigned;
                }
            }
        }
        // Slots outside a region smaller than the grid (edges of small levels) hold nothing the
        // engine uses; their memory keeps whatever tile it had, which no region covers.
        if mem.area() < level.grid[0] * level.grid[1] {
            let period = level.period;
            for slot in level.slots.iter_mut() {
                if slot.tile.is_some_and(|[s, t]| !crate::geom::contains_wrapped(&mem, s, t, period)) {
                    if slot.state.settled() {
                        evicted += 1;
                    }
                    *slot = EMPTY_SLOT;
                }
            }
        }
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
        if !level.in_mem(st) {
            return None;
        }
        let i = level.slot_index(st);
        let slot = &mut level.slots[i];
        (slot.tile == Some(st) && slot.assigned).then_some(slot)
    }

    /// Notes that `tile` was requested (ignored unless it is absent). A failed tile that is read
    /// again stays failed (published as missing, readers use a coarser level) until the retry
    /// settles it.
    pub(crate) fn mark_loading(&mut self, tile: TileId) {
        if let Some(slot) = self.level_slot_mut(tile) {
            if slot.state == TileState::Absent {
                slot.state = TileState::Loading;
            }
        }
    }

    /// Takes a finished read, which filled the slot in `generation`: its slot is settled as
    /// ready (or the default tile).
    pub(crate) fn admit(&mut self, tile: TileId, generation: u64, delivered: Delivered) -> Admit {
        let memory = Arc::clone(&self.memory);
        let Some(slot) = self.level_slot_mut(tile) else { return Admit::Stale };
        let (state, tag) = match delivered {
            Delivered::Tile => (TileState::Resident, SlotState::Ready),
            Delivered::Default => (TileState::Defaulted, SlotState::Default),
        };
        if !memory.settle(tile, generation, tag) {
            return Admit::Stale;
        }
        let replaced = slot.state == TileState::Replacing;
        slot.state = state;
        if replaced {
            Admit::Replaced
        } else {
            Admit::Admitted
        }
    }

    /// Notes that reading `tile` failed: its tag says missing (readers use a coarser level for
    /// it) and it will be wanted again from tick `retry_at`.
    pub(crate) fn mark_failed(&mut self, tile: TileId, generation: Option<u64>, kind: FaultKind, retry_at: u64) {
        let memory = Arc::clone(&self.memory);
        let Some(slot) = self.level_slot_mut(tile) else { return };
        if slot.state.readable() {
            return;
        }
        let generation = generation.or_else(|| memory.loading_generation(tile));
        if generation.is_some_and(|g| memory.settle(tile, g, SlotState::Missing)) {
            slot.state = TileState::Failed { kind, retry_at };
        } else if slot.state == TileState::Loading {
            slot.state = TileState::Absent;
        }
    }

    /// Opens resident (or defaulted) `tile`'s slot to be read again in place
    /// (`ImageMemory::replace`: tag loading, claim loading under a new generation): the tile
    /// is [`TileState::Replacing`], wanted from the read queues like any tile, and its read's
    /// completion settles it again ([`admit`](Self::admit), or [`mark_failed`](Self::mark_failed):
    /// missing, read again from its retry tick). `false` (nothing changed) unless the tile is
    /// resident or defaulted in its slot. Call only from the tick, after no in-process reader
    /// can hold the slot.
    pub(crate) fn replace(&mut self, tile: TileId) -> bool {
        let memory = Arc::clone(&self.memory);
        if !self.level_slot_mut(tile).is_some_and(|slot| slot.state.readable())
            || memory.replace(&mut self.keeper, tile).is_none()
        {
            return false;
        }
        if let Some(slot) = self.level_slot_mut(tile) {
            slot.state = TileState::Replacing;
        }
        true
    }

    /// A failed tile is wanted again from tick `now` on (its source has new data for it).
    pub(crate) fn retry_now(&mut self, tile: TileId, now: u64) {
        if let Some(slot) = self.level_slot_mut(tile) {
            if let TileState::Failed { kind, .. } = slot.state {
                slot.state = TileState::Failed { kind, retry_at: now };
            }
        }
    }

    /// A read of `tile` started too late (its slot had moved on) or found the slot busy: it is
    /// wanted again if its slot still expects it.
    pub(crate) fn mark_not_read(&mut self, tile: TileId) {
        if let Some(slot) = self.level_slot_mut(tile) {
            if slot.state == TileState::Loading {
                slot.state = TileState::Absent;
            }
        }
    }

    /// Copies bytes of `tile`'s slot, starting `offset` bytes into the tile, if it is readable.
    pub fn read(&self, tile: TileId, offset: usize, out: &mut [u8]) -> bool {
        self.state(tile).readable() && self.memory.read_settled(&self.keeper, tile, offset, out)
    }

    /// Tiles of level `k`'s mem region that should be read at tick `now`: absent, loading or
    /// replacing (still wanted, so their priority is refreshed) or failed with their retry time
    /// reached, in slots already given to them.
    pub fn wanted(&self, k: u32, now: u64) -> Vec<TileId> {
        let level = &self.levels[k as usize];
        let mut out = Vec::new();
        for t in level.mem.t0..level.mem.t1 {
            for u in level.mem.s0..level.mem.s1 {
                let [s, t] = level.real([u, t]);
                let slot = &level.slots[level.slot_index([s, t])];
                let want = slot.assigned
                    && match slot.state {
                        TileState::Absent | TileState::Loading | TileState::Replacing => true,
                        TileState::Failed { retry_at, .. } => retry_at <= now,
                        TileState::Resident | TileState::Defaulted => false,
                    };
                if want {
                    out.push(TileId::new(k, s as u64, t as u64));
                }
            }
        }
        out
    }

    /// Slots of every level that hold a readable tile now (the tests' count; the engine counts
    /// resident bytes itself, `Clipmap::resident_bytes`).
    #[cfg(test)]
    pub fn resident_tiles(&self) -> usize {
        self.levels.iter().map(|l| l.slots.iter().filter(|s| s.state.readable()).count()).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::mem_grid;
    use crate::source::TextureDesc;
    use crate::texel::TexelFormat;

    fn cache() -> TileCache {
        let desc = TextureDesc::new([256, 256], 32, TexelFormat::L8, [16, 16]).unwrap();
        let grids: Vec<[u64; 2]> =
            desc.levels().iter().map(|l| mem_grid(l.size, l.tile, desc.clip_size(), 1)).collect();
        let memory = Arc::new(ImageMemory::anonymous(crate::clip::memory_shape(&desc, &grids), desc.format()).unwrap());
        let keeper = memory.take_keeper().expect("a new memory's keeper is free");
        TileCache::new(&grids, memory, keeper)
    }

    fn fill(c: &TileCache, tile: TileId, byte: u8) -> u64 {
        c.memory().fill(tile, |b| b.fill(byte)).expect("the slot is the tile's").0
    }

    #[test]
    fn tiles_move_through_loading_resident_and_leave_with_the_mem_region() {
        let mut c = cache();
        assert_eq!(c.grid(0), [4, 4]);
        c.set_mem_region(0, Rect::new(2, 2, 6, 6));
        assert_eq!(c.wanted(0, 0).len(), 16);
        let tile = TileId::new(0, 3, 4);
        c.mark_loading(tile);
        assert_eq!(c.state(tile), TileState::Loading);
        let g = fill(&c, tile, 7);
        assert_eq!(c.admit(tile, g, Delivered::Tile), Admit::Admitted);
        let mut b = [0u8; 4];
        assert!(c.read(tile, 0, &mut b));
        assert_eq!(b, [7; 4]);
        assert_eq!(c.wanted(0, 0).len(), 15);
        assert_eq!(c.resident_tiles(), 1);
        // Moving by one tile keeps (3, 4) (same slot) and evicts nothing else resident.
        assert_eq!(c.set_mem_region(0, Rect::new(3, 2, 7, 6)), 0);
        assert_eq!(c.state(tile), TileState::Resident);
        // Moving away evicts it; a late read of it finds its slot given away and changes nothing.
        assert_eq!(c.set_mem_region(0, Rect::new(8, 8, 12, 12)), 1);
        assert_eq!(c.resident_tiles(), 0);
        assert_eq!(c.state(tile), TileState::Absent);
        assert!(c.memory().fill(tile, |b| b.fill(9)).is_none(), "the slot belongs to another tile now");
        assert_eq!(c.admit(tile, g, Delivered::Tile), Admit::Stale);
        // Back in the same slot, a late completion of the first read does not settle it.
        c.set_mem_region(0, Rect::new(2, 2, 6, 6));
        assert_eq!(c.admit(tile, g, Delivered::Tile), Admit::Stale, "an earlier generation's read");
        let g2 = fill(&c, tile, 8);
        assert!(g2 > g);
        assert_eq!(c.admit(tile, g2, Delivered::Tile), Admit::Admitted);
    }

    #[test]
    fn a_settled_slot_is_never_handed_to_a_read() {
        let mut c = cache();
        c.set_mem_region(0, Rect::new(0, 0, 4, 4));
        let tile = TileId::new(0, 1, 1);
        let g = fill(&c, tile, 1);
        assert_eq!(c.admit(tile, g, Delivered::Default), Admit::Admitted);
        assert_eq!(c.state(tile), TileState::Defaulted);
        assert!(c.memory().fill(tile, |b| b.fill(2)).is_none());
        let mut b = [0u8; 1];
        assert!(c.read(tile, 255, &mut b));
        assert_eq!(b, [1]);
    }

    #[test]
    fn failed_tiles_are_wanted_again_at_their_retry_tick() {
        let mut c = cache();
        c.set_mem_region(0, Rect::new(0, 0, 1, 1));
        let tile = TileId::new(0, 0, 0);
        c.mark_failed(tile, None, FaultKind::Missing, 5);
        assert!(c.wanted(0, 4).is_empty());
        assert_eq!(c.wanted(0, 5), vec![tile]);
        assert!(!c.read(tile, 0, &mut [0u8; 1]));
        // A retry may fill the slot (its claim stayed loading) and settle it.
        let g = fill(&c, tile, 3);
        assert_eq!(c.admit(tile, g, Delivered::Tile), Admit::Admitted);
        assert!(c.read(tile, 0, &mut [0u8; 1]));
    }
}
