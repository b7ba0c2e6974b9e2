//! The image caches' memory: one layout-2 mapping (a file the service publishes, or anonymous
//! memory for an engine without a service) holding every level's grid of tile slots, their tags
//! and the published snapshot.
//!
//! Owns the writer's side of the slot protocol (docs/SHM.md, "The writer's invariant"):
//! - each slot has a private **claim** (atomics in this process, not in the mapping): the tile the
//!   engine assigned to it, a generation counted up by every assignment (and reopening), and
//!   whether it is loading, being filled by one read, or settled. A read fills a slot only after
//!   taking the claim from loading to busy by compare-and-swap, so at most one read writes a slot
//!   at a time, and never a settled one; a finished read settles the slot only under the
//!   generation it filled it in, so a late completion of an earlier assignment of the same tile
//!   cannot mark another read's bytes ready;
//! - the engine reassigns a slot only when no read holds it, storing the tag (loading, new tile)
//!   before the claim, so a reader sees the tag change before any byte does; it reopens a settled
//!   slot for new texels of the same tile ([`ImageMemory::replace`], a growing texture) the same
//!   way, tag first, and a read then fills it like any other;
//! - taking a slot out of settled ([`ImageMemory::assign`], [`ImageMemory::replace`]) needs the
//!   memory's one [`SlotKeeper`] `&mut`, and copying a settled slot in process
//!   ([`ImageMemory::read_settled`]) needs it `&`: no such copy overlaps a change that lets the
//!   slot's bytes be rewritten, whoever calls these public methods, from whatever thread;
//! - the tick publishes the snapshot once, whole, under its seqlock.
//!
//! It decides nothing about which tiles to hold (`clipmap::cache`) nor when to publish
//! (`clipmap::clip`).

use super::layout::{self, growth, header, snapshot, state, tag, Placement, Shape, SlotState};
use super::raw::Region;
use clipmap_base::geom::Rect;
use clipmap_base::texel::TexelFormat;
use clipmap_base::tile::TileId;
use std::sync::atomic::{fence, AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

const LOADING: u64 = 0;
const BUSY: u64 = 1;
const SETTLED: u64 = 2;
const UNASSIGNED: u64 = 3;
const NO_TILE: u64 = u64::MAX;

/// The state bits of a claim word (the rest is the generation).
fn state_of(claim: u64) -> u64 {
    claim & 3
}

/// A claim word: generation and state.
fn word(generation: u64, state: u64) -> u64 {
    (generation << 2) | state
}

fn key(tile: [i64; 2]) -> u64 {
    // Tile indices are below 2^30 (levels are at most 2^30 texels a side, MAX_TEXTURE_SIZE, tiles
    // at least 1): 31 bits each, above the two low bits (always 0: never NO_TILE).
    ((tile[0] as u64 & 0x7FFF_FFFF) << 33) | ((tile[1] as u64 & 0x7FFF_FFFF) << 2)
}

fn tile_of_key(key: u64) -> [i64; 2] {
    [((key >> 33) & 0x7FFF_FFFF) as i64, ((key >> 2) & 0x7FFF_FFFF) as i64]
}

/// The one right to take slots of an [`ImageMemory`] out of settled ([`ImageMemory::assign`],
/// [`ImageMemory::replace`]) and to copy settled slots' bytes in process
/// ([`ImageMemory::read_settled`]): the engine's. At most one exists per memory at a time
/// ([`ImageMemory::take_keeper`]; dropping it gives it back); it is not `Clone` and cannot be made
/// outside this crate. The first two take it `&mut`, the copy `&`, so the borrow rules keep every
/// in-process copy of a settled slot apart from every change that lets its bytes be rewritten
/// (docs/ARCHITECTURE.md §12). A method given the keeper of another memory panics.
pub struct SlotKeeper {
    /// The [`ImageMemory::id`] of the memory it keeps.
    memory: u64,
    /// The memory's flag that a keeper is out, cleared when this one is dropped.
    out: Arc<AtomicBool>,
}

impl std::fmt::Debug for SlotKeeper {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SlotKeeper").field("memory", &self.memory).finish()
    }
}

impl Drop for SlotKeeper {
    fn drop(&mut self) {
        // Release: whatever this keeper did happens before anything the next one does (its
        // `take_keeper` acquires the flag).
        self.out.store(false, Ordering::Release);
    }
}

/// Ids of memories, for [`SlotKeeper`]s to name theirs (never reused).
static NEXT_ID: AtomicU64 = AtomicU64::new(0);

/// What [`ImageMemory::assign`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
pub enum Assign {
    /// The slot now belongs to the tile (loading).
    Assigned,
    /// A read is filling the slot with its previous tile right now: try again next tick.
    Busy,
}

/// One level's state as the tick publishes it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PublishedLevel {
    /// Level centre.
    pub centre: [i64; 2],
    /// Valid region, half-open `[s0, s1) x [t0, t1)`; empty when the level is disabled.
    pub valid: Rect,
    /// Tick of the level's last change.
    pub updated_tick: u64,
}

/// The whole published state of one tick.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Publication {
    /// Min LOD.
    pub min_lod: f64,
    /// The tick.
    pub tick: u64,
    /// Invalid border in use.
    pub invalid_border: u64,
    /// Level-0 centre.
    pub centre: [i64; 2],
    /// Per level.
    pub levels: Vec<PublishedLevel>,
}

/// A layout-2 mapping as the engine's image caches.
pub struct ImageMemory {
    region: Region,
    placement: Placement,
    shape: Shape,
    /// Per level and slot: generation << 2 | state.
    claims: Vec<Vec<AtomicU64>>,
    /// Per level and slot: the key of the tile assigned.
    keys: Vec<Vec<AtomicU64>>,
    /// Per view (0 the primary, v the further view v) and level, the tiles under the region of
    /// the snapshot published last (the writer's own record, to check its invariant, for every
    /// view at once, at every assignment).
    published_tiles: std::sync::Mutex<Vec<Vec<Rect>>>,
    /// Assignments of a slot whose settled tile the current snapshot still covers (the writer's
    /// invariant says: never).
    violations: AtomicU64,
    /// The height format of a height texture whose levels have tile ranges (`None`: no ranges).
    heights: Option<clipmap_base::height::HeightFormat>,
    /// This memory's id, unique in the process (what its [`SlotKeeper`] records).
    id: u64,
    /// Whether its [`SlotKeeper`] is out.
    keeper_out: Arc<AtomicBool>,
}

impl std::fmt::Debug for ImageMemory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ImageMemory").field("bytes", &self.placement.total_bytes).field("shape", &self.shape).finish()
    }
}

/// Why a shape cannot be laid out.
pub fn shape_error(shape: &Shape) -> String {
    for (k, l) in shape.levels.iter().enumerate() {
        if let Err(e) = layout::check_level(l, shape.clip_size, shape.bytes_per_texel) {
            return format!("level {k}: {e}");
        }
    }
    format!(
        "{} levels, clip {}, {} bytes per texel: too many levels or too many bytes",
        shape.levels.len(),
        shape.clip_size,
        shape.bytes_per_texel
    )
}

/// The raw mapping, for the tests of the `clipmap` crate (the `test-hooks` feature).
#[cfg(feature = "test-hooks")]
#[doc(hidden)]
impl ImageMemory {
    /// The mapping.
    pub fn raw_region(&self) -> &Region {
        &self.region
    }
}

impl ImageMemory {
    /// Image caches in private anonymous memory (an engine without a service).
    pub fn anonymous(shape: Shape, format: TexelFormat) -> Result<ImageMemory, String> {
        let placement = layout::place(&shape).ok_or_else(|| shape_error(&shape))?;
        let len =
            usize::try_from(placement.total_bytes).map_err(|_| "the mapping does not fit in memory".to_string())?;
        let region = Region::anonymous(len).map_err(|e| format!("cannot map {len} bytes: {e}"))?;
        let memory = Self::over(region, placement, shape, None);
        memory.init(format, 0, 0, None, None);
        Ok(memory)
    }

    /// Image caches over a mapping already sized to `placement` (the service's file); `heights`
    /// when the placement has tile ranges ([`layout::place_with`]), which every settled tile's
    /// range is then published in.
    pub(super) fn over(
        region: Region,
        placement: Placement,
        shape: Shape,
        heights: Option<clipmap_base::height::HeightFormat>,
    ) -> ImageMemory {
        debug_assert!(placement.levels.iter().all(|l| (l.ranges != 0) == heights.is_some()));
        let per_slot = |v: u64| -> Vec<Vec<AtomicU64>> {
            placement.levels.iter().map(|l| (0..l.slot_count).map(|_| AtomicU64::new(v)).collect()).collect()
        };
        let (claims, keys) = (per_slot(UNASSIGNED), per_slot(NO_TILE));
        let published_tiles = std::sync::Mutex::new(vec![vec![Rect::EMPTY; shape.levels.len()]]);
        ImageMemory {
            region,
            placement,
            shape,
            claims,
            keys,
            published_tiles,
            violations: AtomicU64::new(0),
            heights,
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            keeper_out: Arc::new(AtomicBool::new(false)),
        }
    }

    /// The memory's [`SlotKeeper`], for the engine that fills it; `None` while another one is out
    /// (another engine keeps this memory: one memory has one engine at a time).
    pub fn take_keeper(&self) -> Option<SlotKeeper> {
        // Acquire: everything the previous keeper did happens before what this one does.
        self.keeper_out.compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed).ok()?;
        Some(SlotKeeper { memory: self.id, out: Arc::clone(&self.keeper_out) })
    }

    /// Panics unless `keeper` is this memory's.
    fn check_keeper(&self, keeper: &SlotKeeper) {
        assert!(
            keeper.memory == self.id,
            "the slot keeper of image memory {} was given to image memory {}: pass the keeper that \
             `take_keeper` returned for this memory",
            keeper.memory,
            self.id
        );
    }

    /// Writes the static header (everything but the magic, which [`finish`](Self::finish)
    /// writes last).
    pub(super) fn init(
        &self,
        format: TexelFormat,
        tick_period_ns: u64,
        generation: u64,
        heights: Option<&layout::Heights>,
        georef: Option<&crate::GeorefBlock>,
    ) {
        let r = &self.region;
        let put32 = |off: usize, v: u32| r.write_u32(off, v);
        let put64 = |off: usize, v: u64| r.store(off, v, Ordering::Relaxed);
        put32(header::VERSION, layout::VERSION);
        put32(header::HEADER_BYTES, self.placement.header_bytes as u32);
        put64(header::TOTAL_BYTES, self.placement.total_bytes);
        put32(header::TEXEL_FORMAT, layout::format_code(format));
        put32(header::BYTES_PER_TEXEL, self.shape.bytes_per_texel as u32);
        put32(header::CLIP_SIZE, self.shape.clip_size as u32);
        put32(header::LEVEL_COUNT, self.shape.levels.len() as u32);
        put64(header::LEVEL0_S, self.shape.levels[0].size[0]);
        put64(header::LEVEL0_T, self.shape.levels[0].size[1]);
        put32(header::WRITER_PID, std::process::id());
        put64(header::GENERATION, generation);
        put64(header::TICK_PERIOD_NS, tick_period_ns);
        for (i, (l, p)) in self.shape.levels.iter().zip(&self.placement.levels).enumerate() {
            let b = header::LEVEL_DESCS + i * layout::DESC_BYTES;
            use layout::desc as d;
            for (off, v) in [
                (d::SIZE_S, l.size[0]),
                (d::SIZE_T, l.size[1]),
                (d::TILE_S, l.tile[0]),
                (d::TILE_T, l.tile[1]),
                (d::GRID_S, l.grid[0]),
                (d::GRID_T, l.grid[1]),
                (d::SLOT_BYTES, p.slot_bytes),
                (d::TAGS_OFFSET, p.tags),
                (d::SLOTS_OFFSET, p.slots),
                (d::KIND, p.kind),
                (d::RANGES_OFFSET, p.ranges),
            ] {
                put64(b + off, v);
            }
        }
        // The heights block: all zero for a texture that is not heights.
        if let Some(h) = heights {
            use layout::heights as ht;
            let b = header::HEIGHTS;
            put32(b + ht::IS_HEIGHTS, 1);
            put32(b + ht::RULE, layout::rule_code(h.levels));
            put64(b + ht::SCALE, h.scale.to_bits());
            put64(b + ht::OFFSET, h.offset.to_bits());
            put64(b + ht::NODATA, h.nodata.unwrap_or(f64::NAN).to_bits());
        }
        // The georef block and each level's affine terms: all zero without georeferencing.
        if let Some(g) = georef {
            let (block, levels) = g.encode();
            for (i, word) in block.chunks_exact(4).enumerate() {
                put32(header::GEOREF + 4 * i, u32::from_le_bytes(word.try_into().expect("4 bytes")));
            }
            for (k, terms) in levels.iter().enumerate() {
                for (i, v) in terms.iter().enumerate() {
                    put64(header::LEVEL_DESCS + k * layout::DESC_BYTES + layout::desc::GEOREF + 8 * i, *v);
                }
            }
        }
        // Before the first tick nothing may be used: min LOD is the level count.
        let s = header::SNAPSHOT;
        let none = (self.shape.levels.len() as f64).to_bits();
        r.store(s + snapshot::MIN_LOD, none, Ordering::Relaxed);
        // The views block: every record free, its snapshot showing nothing.
        if self.placement.views != 0 {
            use layout::views as v;
            let b = self.placement.views as usize;
            put64(header::VIEWS_OFFSET, self.placement.views);
            put64(b + v::MAGIC, u64::from_le_bytes(v::MAGIC_BYTES));
            put32(b + v::VERSION, v::BLOCK_VERSION);
            put32(b + v::RECORDS, self.placement.view_records as u32);
            put32(b + v::RECORD_BYTES_AT, v::RECORD_BYTES as u32);
            for rec in 0..self.placement.view_records as usize {
                r.store(b + v::record(rec) + v::SNAPSHOT + snapshot::MIN_LOD, none, Ordering::Relaxed);
            }
        }
        // The magic last, with a release store: a reader that loads it (acquire) sees every
        // field above.
        r.store(header::MAGIC, u64::from_le_bytes(layout::MAGIC), Ordering::Release);
    }

    /// The static shape.
    pub fn shape(&self) -> &Shape {
        &self.shape
    }

    /// Where everything lies.
    pub fn placement(&self) -> &Placement {
        &self.placement
    }

    pub(super) fn region(&self) -> &Region {
        &self.region
    }

    fn slot_of(&self, level: u32, tile: [i64; 2]) -> (usize, u64) {
        let grid = self.shape.levels[level as usize].grid;
        (level as usize, layout::slot_index(grid, tile))
    }

    fn store_tag(&self, level: usize, slot: u64, tile: [i64; 2], st: SlotState) {
        let b = self.placement.levels[level].tag_offset(slot) as usize;
        let r = &self.region;
        let seq = r.load(b + tag::SEQ, Ordering::Relaxed);
        r.store(b + tag::SEQ, seq.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        r.store(b + tag::TILE_S, tile[0] as u64, Ordering::Relaxed);
        r.store(b + tag::TILE_T, tile[1] as u64, Ordering::Relaxed);
        r.store(b + tag::STATE, st as u64, Ordering::Relaxed);
        r.store(b + tag::SEQ, seq.wrapping_add(2), Ordering::Release);
    }

    /// Gives `tile`'s slot to `tile` (loading): its tag first, then its claim (tile, then a new
    /// generation). Refused while a read fills the slot. Only the engine calls this (it holds the
    /// memory's `keeper`), and only for a slot whose old tile no published region covers.
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn assign(&self, keeper: &mut SlotKeeper, level: u32, tile: [i64; 2]) -> Assign {
        self.check_keeper(keeper);
        let (k, slot) = self.slot_of(level, tile);
        let claim = &self.claims[k][slot as usize];
        let now = claim.load(Ordering::Acquire);
        if state_of(now) == BUSY {
            return Assign::Busy;
        }
        let old = self.keys[k][slot as usize].load(Ordering::Acquire);
        if state_of(now) == SETTLED && old != NO_TILE {
            let [s, t] = tile_of_key(old);
            // A wrapping level's region may run past its tiles (column s + n is column s again,
            // docs/SHM.md "How a region wraps"); no other level's region reaches past its edge.
            let n = clipmap_base::geom::tiles_in_level(self.shape.levels[k].size, self.shape.levels[k].tile)[0] as i64;
            let covered = self
                .published_tiles
                .lock()
                .map(|p| p.iter().any(|v| v[k].contains(s, t) || v[k].contains(s + n, t)))
                .unwrap_or(false);
            if covered {
                self.violations.fetch_add(1, Ordering::Relaxed);
            }
        }
        self.store_tag(k, slot, tile, SlotState::Loading);
        self.keys[k][slot as usize].store(key(tile), Ordering::Release);
        match claim.compare_exchange(now, word((now >> 2) + 1, LOADING), Ordering::AcqRel, Ordering::Acquire) {
            Ok(_) => Assign::Assigned,
            // A read took the old tile's claim in between: the tag already says loading (nothing
            // readable), the read's completion no longer matches the key, and the engine assigns
            // again next tick.
            Err(_) => Assign::Busy,
        }
    }

    /// Lets a read fill `tile`'s slot: `fill` gets the slot's bytes (one whole tile) if the slot
    /// is assigned to `tile` and loading; `None` (nothing called) when it is not (the tile left
    /// its mem region, or it is settled, or another read fills it). Returns the generation the
    /// slot was filled in, for [`settle`](Self::settle), with what `fill` returned.
    #[allow(unsafe_code)] // the one call that lends a slot's bytes to a read (SAFETY below)
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn fill<R>(&self, tile: TileId, fill: impl FnOnce(&mut [u8]) -> R) -> Option<(u64, R)> {
        let st = [tile.s as i64, tile.t as i64];
        let level = tile.level;
        if level as usize >= self.claims.len() {
            return None;
        }
        let (k, slot) = self.slot_of(level, st);
        let claim = &self.claims[k][slot as usize];
        let now = claim.load(Ordering::Acquire);
        if state_of(now) != LOADING || self.keys[k][slot as usize].load(Ordering::Acquire) != key(st) {
            return None;
        }
        // From the generation read above: an assignment since then changed it, and this fails.
        claim.compare_exchange(now, word(now >> 2, BUSY), Ordering::AcqRel, Ordering::Relaxed).ok()?;
        let p = &self.placement.levels[k];
        let offset = p.slot_offset(slot) as usize;
        // Gives the claim back however `fill` ends: a source that panics leaves the slot loading
        // (its bytes no promise), for another read to fill, instead of busy for ever.
        struct GiveBack<'a>(&'a AtomicU64, u64);
        impl Drop for GiveBack<'_> {
            fn drop(&mut self) {
                self.0.store(self.1, Ordering::Release);
            }
        }
        let give_back = GiveBack(claim, now);
        // SAFETY: the claim is now `BUSY` for this slot, which only this call could set (the
        // compare-and-swap above succeeded from `LOADING`), and until `give_back` stores it back
        // (after `fill` returns, or while it unwinds):
        // no other read can take it (they compare from `LOADING`), no caller reassigns, reopens
        // or settles a busy slot (`assign` and `replace` compare from the state they loaded, which
        // was not `BUSY`, `settle` from `LOADING`), and in-process copies of a slot's bytes
        // (`read_settled`) run only while its claim is `SETTLED` and hold the memory's keeper `&`,
        // so every one of them ended before the `assign` or `replace` (keeper `&mut`) that took
        // this claim out of settled. So nothing else in this process touches these bytes while
        // `fill` runs, whoever calls it. Other processes map the file read-only and, by the tag
        // protocol, discard what they read from a slot whose tag says loading (the tag was set to
        // loading in `assign` or `replace`, before the claim).
        let out = unsafe { self.region.fill(offset, p.slot_bytes as usize, fill) };
        drop(give_back);
        Some((now >> 2, out))
    }

    /// Marks `tile` settled after a read filled its slot in `generation`: ready (or the default
    /// tile), or missing. `false` when the slot no longer belongs to that assignment of the tile
    /// (a late read: nothing changed).
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn settle(&self, tile: TileId, generation: u64, st: SlotState) -> bool {
        let t = [tile.s as i64, tile.t as i64];
        if tile.level as usize >= self.claims.len() {
            return false;
        }
        let (k, slot) = self.slot_of(tile.level, t);
        let claim = &self.claims[k][slot as usize];
        if self.keys[k][slot as usize].load(Ordering::Acquire) != key(t) {
            return false;
        }
        let loading = word(generation, LOADING);
        if st == SlotState::Missing {
            // The claim stays loading, so that a later retry may fill the slot; readers skip it.
            if claim.load(Ordering::Acquire) != loading {
                return false;
            }
            self.store_tag(k, slot, t, st);
            return true;
        }
        // Busy while the tile's range is computed from its bytes: no read fills the slot then
        // (a read takes only a loading claim) and the engine neither reassigns nor reopens it.
        if claim.compare_exchange(loading, word(generation, BUSY), Ordering::AcqRel, Ordering::Relaxed).is_err() {
            return false;
        }
        self.publish_range(k, slot, tile);
        claim.store(word(generation, SETTLED), Ordering::Release);
        // Ready (or default) only after the range entry: a reader that sees the tag's new counter
        // sees the entry too (the tag's counter is stored with release).
        self.store_tag(k, slot, t, st);
        true
    }

    /// Computes the range of heights of the tile in slot `slot` of level `k` from the slot's bytes
    /// (the texels inside the level only; nodata excluded) and stores it in the slot's range
    /// entry: NaN and NaN when every texel is nodata, -inf and +inf when a texel is not a finite
    /// height (a corrupt tile: nothing can be culled by it). Nothing for a level without ranges.
    /// Called by [`settle`](Self::settle) only, with the slot's claim busy and its tag loading.
    #[allow(unsafe_code)] // the copy of a busy slot's bytes (SAFETY below)
    fn publish_range(&self, k: usize, slot: u64, tile: TileId) {
        let (Some(format), Some(at)) = (self.heights, self.placement.levels[k].range_offset(slot)) else {
            return;
        };
        let p = &self.placement.levels[k];
        let l = &self.shape.levels[k];
        let bpt = self.shape.bytes_per_texel as usize;
        let [tw, th] = [l.tile[0] as usize, l.tile[1] as usize];
        // An edge tile's texels beyond the level's edge are no heights of the texture.
        let w = (l.size[0] - (tile.s * l.tile[0]).min(l.size[0])).min(l.tile[0]) as usize;
        let h = (l.size[1] - (tile.t * l.tile[1]).min(l.size[1])).min(l.tile[1]) as usize;
        let mut bytes = vec![0u8; tw * th * bpt];
        // SAFETY: the caller holds the slot's claim busy, which only `settle`'s compare-and-swap
        // from this generation's loading set, and only `settle` stores it back: no read fills the
        // slot (`fill` takes only a loading claim) and no caller reassigns or reopens it
        // (`assign` and `replace` compare from a state that was not busy), whatever thread any of
        // them runs on; `read_settled` only reads. So the bytes do not change while they are
        // copied into `bytes`, a private buffer.
        unsafe { self.region.read(p.slot_offset(slot) as usize, &mut bytes) };
        let range = (0..h).try_fold(clipmap_base::height::TileRange::Empty, |acc, row| {
            format.tile_range(&bytes[row * tw * bpt..(row * tw + w) * bpt]).map(|r| acc.union(r))
        });
        let (min, max) = match range {
            Ok(clipmap_base::height::TileRange::Heights { min, max }) => (min, max),
            Ok(clipmap_base::height::TileRange::Empty) => (f64::NAN, f64::NAN),
            Err(e) => {
                tracing::warn!("level {k} tile ({}, {}): {e}; its published range is -inf..inf", tile.s, tile.t);
                (f64::NEG_INFINITY, f64::INFINITY)
            }
        };
        self.region.store(at as usize + layout::range::MIN, min.to_bits(), Ordering::Relaxed);
        self.region.store(at as usize + layout::range::MAX, max.to_bits(), Ordering::Relaxed);
    }

    /// The generation of `tile`'s slot if it is assigned to the tile and loading (a read that
    /// failed before filling it settles it missing under this).
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn loading_generation(&self, tile: TileId) -> Option<u64> {
        let t = [tile.s as i64, tile.t as i64];
        if tile.level as usize >= self.claims.len() {
            return None;
        }
        let (k, slot) = self.slot_of(tile.level, t);
        let now = self.claims[k][slot as usize].load(Ordering::Acquire);
        (state_of(now) == LOADING && self.keys[k][slot as usize].load(Ordering::Acquire) == key(t)).then_some(now >> 2)
    }

    /// Copies bytes of a settled slot (in-process readers: the sampler over the engine, dumps).
    /// `false` when the slot does not hold `tile` settled.
    #[allow(unsafe_code)] // the one copy out of a settled slot in process (SAFETY below)
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn read_settled(&self, keeper: &SlotKeeper, tile: TileId, offset: usize, out: &mut [u8]) -> bool {
        self.check_keeper(keeper);
        let t = [tile.s as i64, tile.t as i64];
        if tile.level as usize >= self.claims.len() {
            return false;
        }
        let (k, slot) = self.slot_of(tile.level, t);
        let claim = &self.claims[k][slot as usize];
        if state_of(claim.load(Ordering::Acquire)) != SETTLED
            || self.keys[k][slot as usize].load(Ordering::Acquire) != key(t)
        {
            return false;
        }
        let p = &self.placement.levels[k];
        if offset + out.len() > p.slot_bytes as usize {
            return false;
        }
        // SAFETY: the claim was settled above (acquire: it was stored with release after the
        // bytes were written, so they are visible). A settled claim leaves settled only by
        // `assign` or `replace` (every other transition compares from loading or is made by the
        // one holding it busy), and only after that can a read's `fill` take it to busy and write
        // the bytes. Both need this memory's keeper `&mut`, checked above to be the keeper
        // borrowed here `&`; there is one keeper per memory (`take_keeper`), so while this copy
        // runs neither can run in any thread: nothing writes these bytes. Other processes map the
        // file read-only. The copy goes into `out`, a private buffer.
        unsafe { self.region.read(p.slot_offset(slot) as usize + offset, out) };
        true
    }

    /// Assignments so far of a slot whose settled tile the current snapshot still covered: the
    /// writer's invariant, checked where it could break (0 unless the engine is wrong).
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn invariant_violations(&self) -> u64 {
        self.violations.load(Ordering::Relaxed)
    }

    /// Publishes the whole state of a tick under the snapshot's seqlock.
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn publish(&self, p: &Publication) {
        self.publish_view(0, p);
    }

    /// Byte offset of view `view`'s record (`None`: the primary, 0, has none; or the mapping
    /// has no record for it).
    fn view_record(&self, view: usize) -> Option<usize> {
        let r = view.checked_sub(1)?;
        (self.placement.views != 0 && (r as u64) < self.placement.view_records)
            .then(|| self.placement.views as usize + layout::views::record(r))
    }

    /// Publishes view `view`'s state of a tick under its snapshot's seqlock: the primary's (0) at
    /// the header's snapshot, a further view's in its record (kept only in the writer's own
    /// record of published tiles when the mapping has no record for it).
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn publish_view(&self, view: usize, p: &Publication) {
        if let Ok(mut tiles) = self.published_tiles.lock() {
            if tiles.len() <= view {
                tiles.resize(view + 1, vec![Rect::EMPTY; self.shape.levels.len()]);
            }
            for (k, l) in p.levels.iter().enumerate() {
                tiles[view][k] = clipmap_base::geom::tiles_covering(l.valid, self.shape.levels[k].tile);
            }
        }
        let b = match view {
            0 => header::SNAPSHOT,
            v => match self.view_record(v) {
                Some(rec) => rec + layout::views::SNAPSHOT,
                None => return,
            },
        };
        self.store_snapshot(b, p);
    }

    /// A further view's regions stop counting for the invariant (the view was removed), and its
    /// record, if any, is freed: its snapshot shows nothing, its state says free.
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn close_view(&self, view: usize) {
        if let Ok(mut tiles) = self.published_tiles.lock() {
            if let Some(t) = tiles.get_mut(view) {
                t.iter_mut().for_each(|r| *r = Rect::EMPTY);
            }
        }
        let Some(rec) = self.view_record(view) else { return };
        use layout::views as v;
        let r = &self.region;
        self.record_locked(rec, || r.store(rec + v::STATE, 0, Ordering::Relaxed));
        let levels = self.shape.levels.len();
        let empty = Publication {
            min_lod: levels as f64,
            levels: vec![PublishedLevel::default(); levels],
            ..Publication::default()
        };
        self.store_snapshot(rec + v::SNAPSHOT, &empty);
    }

    /// Gives view `view`'s record to a view named `name` (checked by the caller) of weight
    /// `weight`, live in this mapping's grids or (`own`) with grids of its own in another
    /// mapping (docs/SHM.md, "A view with grids of its own"): returns its new incarnation, or
    /// `None` when the mapping has no record for it.
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn open_view(&self, view: usize, name: &str, weight: f64, own: bool) -> Option<u64> {
        let rec = self.view_record(view)?;
        use layout::views as v;
        let r = &self.region;
        let mut bytes = [0u8; v::NAME_BYTES];
        let n = name.len().min(v::MAX_NAME);
        bytes[..n].copy_from_slice(&name.as_bytes()[..n]);
        let incarnation = r.load(rec + v::INCARNATION, Ordering::Relaxed).wrapping_add(1);
        self.record_locked(rec, || {
            r.store(rec + v::STATE, if own { v::STATE_OWN } else { v::STATE_LIVE }, Ordering::Relaxed);
            r.store(rec + v::INCARNATION, incarnation, Ordering::Relaxed);
            r.store(rec + v::WEIGHT, weight.to_bits(), Ordering::Relaxed);
            for (i, w) in bytes.chunks_exact(8).enumerate() {
                r.store(rec + v::NAME + 8 * i, u64::from_le_bytes(w.try_into().expect("8 bytes")), Ordering::Relaxed);
            }
        });
        Some(incarnation)
    }

    /// A further view's record's incarnation, when its record is live (`None`: no record, or free).
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn view_incarnation(&self, view: usize) -> Option<u64> {
        let rec = self.view_record(view)?;
        let r = &self.region;
        (r.load(rec + layout::views::STATE, Ordering::Acquire) == 1)
            .then(|| r.load(rec + layout::views::INCARNATION, Ordering::Relaxed))
    }

    /// Sets a further view's weight in its record.
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn set_view_weight(&self, view: usize, weight: f64) {
        let Some(rec) = self.view_record(view) else { return };
        let r = &self.region;
        self.record_locked(rec, || r.store(rec + layout::views::WEIGHT, weight.to_bits(), Ordering::Relaxed));
    }

    /// Runs `write` with the record's sequence counter odd.
    fn record_locked(&self, rec: usize, write: impl FnOnce()) {
        let r = &self.region;
        let at = rec + layout::views::SEQ;
        let seq = r.load(at, Ordering::Relaxed);
        r.store(at, seq.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        write();
        r.store(at, seq.wrapping_add(2), Ordering::Release);
    }

    /// Stores a snapshot at `b` under its seqlock.
    fn store_snapshot(&self, b: usize, p: &Publication) {
        let r = &self.region;
        let seq = r.load(b + snapshot::SEQ, Ordering::Relaxed);
        r.store(b + snapshot::SEQ, seq.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        r.store(b + snapshot::MIN_LOD, p.min_lod.to_bits(), Ordering::Relaxed);
        r.store(b + snapshot::TICK, p.tick, Ordering::Relaxed);
        r.store(b + snapshot::INVALID_BORDER, p.invalid_border, Ordering::Relaxed);
        r.store(b + snapshot::CENTRE_S, p.centre[0] as u64, Ordering::Relaxed);
        r.store(b + snapshot::CENTRE_T, p.centre[1] as u64, Ordering::Relaxed);
        for (k, l) in p.levels.iter().enumerate() {
            let o = b + snapshot::LEVELS + k * layout::STATE_BYTES;
            let v = if l.valid.is_empty() { Rect::EMPTY } else { l.valid };
            let enabled = !v.is_empty();
            let coords = if enabled { [v.s0, v.t0, v.s1, v.t1] } else { [0; 4] };
            r.store(o + state::CENTRE_S, l.centre[0] as u64, Ordering::Relaxed);
            r.store(o + state::CENTRE_T, l.centre[1] as u64, Ordering::Relaxed);
            for (i, c) in coords.iter().enumerate() {
                r.store(o + state::VALID_S0 + 8 * i, *c as u64, Ordering::Relaxed);
            }
            r.store(o + state::ENABLED, u64::from(enabled), Ordering::Relaxed);
            r.store(o + state::UPDATED_TICK, l.updated_tick, Ordering::Relaxed);
        }
        r.store(b + snapshot::SEQ, seq.wrapping_add(2), Ordering::Release);
    }

    /// Publishes a growing texture's growth block under its seqlock.
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn publish_growth(&self, g: &layout::Growth) {
        let r = &self.region;
        let b = header::GROWTH;
        let seq = r.load(b + growth::SEQ, Ordering::Relaxed);
        r.store(b + growth::SEQ, seq.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        let put = |o: usize, v: u64| r.store(b + o, v, Ordering::Relaxed);
        put(growth::GROWING, 1);
        for (i, v) in g.extent.iter().enumerate() {
            put(growth::EXTENT_S0 + 8 * i, *v as u64);
        }
        put(growth::DATA_LEVELS, g.data_levels);
        put(growth::PATCHES, g.patches);
        put(growth::TILES_REBUILT, g.tiles_rebuilt);
        put(growth::TILES_PENDING, g.tiles_pending);
        put(growth::TILES_REPLACED, g.tiles_replaced);
        put(growth::WORLD_S0, g.world_origin[0].to_bits());
        put(growth::WORLD_T0, g.world_origin[1].to_bits());
        put(growth::TEXELS_PER_UNIT, g.texels_per_unit.to_bits());
        put(growth::OUTSIDE_FRAME, g.outside_frame);
        r.store(b + growth::SEQ, seq.wrapping_add(2), Ordering::Release);
    }

    /// Opens `tile`'s settled slot to be read again in place (a growing texture's rebuilt tile,
    /// `clipmap::clip::Clipmap::refresh`): its tag goes to loading (readers of this tile fall back
    /// to a coarser level, or discard what they copied, until it settles again) and then its claim
    /// to loading under a new generation, the tile and the slot unchanged. The new bytes then come
    /// as any tile's do: a read queue's thread fills the slot ([`fill`](Self::fill)) and the
    /// engine settles it ([`settle`](Self::settle)) under the generation returned here. `None`
    /// (nothing changed) unless the slot holds `tile` settled. Only the engine calls this, with
    /// the memory's `keeper` as for [`assign`](Self::assign): never while an in-process reader
    /// copies a slot ([`read_settled`](Self::read_settled) borrows the keeper), and a settled
    /// claim is never held by a read, so no byte is written here.
    #[doc(hidden)] // the writer's side of the slot protocol: for the engine (docs/ARCHITECTURE.md §12)
    pub fn replace(&self, keeper: &mut SlotKeeper, tile: TileId) -> Option<u64> {
        self.check_keeper(keeper);
        let t = [tile.s as i64, tile.t as i64];
        if tile.level as usize >= self.claims.len() {
            return None;
        }
        let (k, slot) = self.slot_of(tile.level, t);
        let claim = &self.claims[k][slot as usize];
        let now = claim.load(Ordering::Acquire);
        if state_of(now) != SETTLED || self.keys[k][slot as usize].load(Ordering::Acquire) != key(t) {
            return None;
        }
        // The tag first: no reader trusts the slot's bytes from here on.
        self.store_tag(k, slot, t, SlotState::Loading);
        let generation = (now >> 2) + 1;
        claim.compare_exchange(now, word(generation, LOADING), Ordering::AcqRel, Ordering::Acquire).ok()?;
        Some(generation)
    }

    /// Bytes of the whole mapping.
    pub fn total_bytes(&self) -> u64 {
        self.placement.total_bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use layout::LevelShape;

    /// One level of 64 x 64 one-byte texels in 16 x 16 tiles, a 4 x 4 grid of slots.
    fn memory() -> ImageMemory {
        let levels = vec![LevelShape { size: [64, 64], tile: [16, 16], grid: [4, 4] }];
        ImageMemory::anonymous(Shape { bytes_per_texel: 1, block: 1, clip_size: 64, levels }, TexelFormat::L8).unwrap()
    }

    fn panic_text(f: impl FnOnce()) -> String {
        let err = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).expect_err("it panics");
        err.downcast_ref::<String>().cloned().unwrap_or_default()
    }

    #[test]
    fn a_memory_has_one_keeper_at_a_time_given_back_when_dropped() {
        let m = memory();
        let keeper = m.take_keeper().expect("a new memory's keeper is free");
        assert!(m.take_keeper().is_none(), "a second keeper while the first is out");
        assert!(m.take_keeper().is_none(), "nor a third");
        drop(keeper);
        let again = m.take_keeper().expect("the dropped keeper was given back");
        assert!(m.take_keeper().is_none());
        // Another memory's keeper is its own.
        let other = memory();
        assert!(other.take_keeper().is_some());
        drop(again);
    }

    #[test]
    fn a_keeper_of_another_memory_is_refused_by_every_method_that_takes_one() {
        let (m, other) = (memory(), memory());
        let mut keeper = m.take_keeper().unwrap();
        let mut foreign = other.take_keeper().unwrap();
        let tile = TileId::new(0, 1, 2);
        let mut out = [0u8; 4];
        for text in [
            panic_text(|| {
                m.assign(&mut foreign, 0, [1, 2]);
            }),
            panic_text(|| {
                m.replace(&mut foreign, tile);
            }),
            panic_text(|| {
                m.read_settled(&foreign, tile, 0, &mut out);
            }),
        ] {
            assert!(
                text.contains(&format!(
                    "the slot keeper of image memory {} was given to image memory {}",
                    other.id, m.id
                )),
                "{text}"
            );
        }
        // Nothing changed: the slot was never assigned, and its own keeper still works.
        assert_eq!(m.loading_generation(tile), None);
        assert_eq!(m.assign(&mut keeper, 0, [1, 2]), Assign::Assigned);
        assert!(m.loading_generation(tile).is_some());
    }

    #[test]
    fn with_its_keeper_a_slot_is_assigned_filled_settled_read_and_reopened() {
        let m = memory();
        let mut keeper = m.take_keeper().unwrap();
        let tile = TileId::new(0, 1, 2);
        let mut out = [0u8; 4];
        assert_eq!(m.assign(&mut keeper, 0, [1, 2]), Assign::Assigned);
        assert!(!m.read_settled(&keeper, tile, 0, &mut out), "loading: nothing to copy");
        let (g, ()) = m.fill(tile, |b| b.iter_mut().enumerate().for_each(|(i, x)| *x = i as u8)).unwrap();
        assert!(m.settle(tile, g, SlotState::Ready));
        assert!(m.read_settled(&keeper, tile, 16, &mut out));
        assert_eq!(out, [16, 17, 18, 19]);
        assert!(!m.read_settled(&keeper, tile, 254, &mut out), "past the slot's end");
        let reopened = m.replace(&mut keeper, tile).expect("settled");
        assert_eq!(reopened, g + 1);
        assert!(!m.read_settled(&keeper, tile, 0, &mut out), "reopened: loading again");
    }
}
