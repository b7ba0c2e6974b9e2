//! The second-level tile pool: an associative cache of whole tiles in process memory, beyond the
//! grids, under a hard byte budget, in front of a slower [`TileSource`].
//!
//! Owns the pooled tiles, their byte count and the eviction policy's state. A read that finds its
//! tile here is served by copying it into the slot (a tile read from a faster source: it still
//! happens inside the read, so the update tick writes no texel); any other read goes to the inner
//! source and its tile is kept, evicting by the [`Eviction`] policy until it fits. The clipmap
//! tells the pool where it is and where it goes each tick ([`PoolSource::hint`]). Which tiles are
//! read at all is the clipmap's and the prefetch policy's business.
//!
//! Bounds: the pool never holds more than its budget in tile bytes (a tile larger than the
//! budget is not kept); the bookkeeping is a few dozen bytes a tile beside it.

use super::{Delivered, SourceError, TextureDesc, TileSource};
use crate::geom::Rect;
use crate::paging::{Candidate, Eviction, EvictionKind, Motion};
use crate::tile::TileId;
use serde::Serialize;
use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};

/// What the pool did.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PoolStats {
    /// The hard budget, bytes of tiles (0: no pool).
    pub budget_bytes: u64,
    /// Reads served from the pool.
    pub hits: u64,
    /// Reads that went to the inner source and delivered a tile.
    pub misses: u64,
    /// Tiles given up to make room.
    pub evicted: u64,
    /// Tiles too large for the whole budget (not kept).
    pub too_large: u64,
    /// Tiles held now.
    pub tiles: u64,
    /// Bytes of the tiles held now.
    pub bytes: u64,
    /// Most bytes ever held.
    pub peak_bytes: u64,
}

impl PoolStats {
    /// Hits over reads that delivered a tile (0 when there were none).
    pub fn hit_rate(&self) -> f64 {
        let n = self.hits + self.misses;
        if n == 0 {
            0.0
        } else {
            self.hits as f64 / n as f64
        }
    }
}

struct Entry {
    data: Box<[u8]>,
    delivered: Delivered,
    last_used: u64,
}

struct State {
    entries: HashMap<TileId, Entry>,
    clock: u64,
    eviction: Box<dyn Eviction>,
    motion: Motion,
    stats: PoolStats,
    /// Evicted tiles in order, when recording (tests, reports).
    log: Option<Vec<TileId>>,
}

/// A [`TileSource`] that keeps the tiles it reads from `inner`, up to a byte budget.
pub struct PoolSource {
    inner: Arc<dyn TileSource>,
    policy: EvictionKind,
    state: Mutex<State>,
}

impl std::fmt::Debug for PoolSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PoolSource").field("policy", &self.policy).field("stats", &self.stats()).finish()
    }
}

impl PoolSource {
    /// A pool of at most `budget_bytes` of tiles over `inner`, evicting by `policy`.
    pub fn new(inner: Arc<dyn TileSource>, budget_bytes: u64, policy: EvictionKind) -> Self {
        let tile = inner.desc().levels().iter().map(|l| l.tile).collect();
        PoolSource {
            inner,
            policy,
            state: Mutex::new(State {
                entries: HashMap::new(),
                clock: 0,
                eviction: policy.policy(),
                motion: Motion { tile, ..Motion::default() },
                stats: PoolStats { budget_bytes, ..PoolStats::default() },
                log: None,
            }),
        }
    }

    /// Also records every eviction, in order ([`evictions`](Self::evictions)).
    pub fn recording(self) -> Self {
        self.lock().log = Some(Vec::new());
        self
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic elsewhere while holding the lock leaves counters at worst one read behind.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The eviction policy.
    pub fn policy(&self) -> EvictionKind {
        self.policy
    }

    /// Where the viewer is (`centre`, level-0 texels), how it moves (`velocity`, level-0 texels
    /// per tick; a zero velocity keeps the last direction) and what each level's grid holds
    /// (`mem`, tile indices).
    pub fn hint(&self, centre: [i64; 2], velocity: [i64; 2], mem: Vec<Rect>) {
        let mut st = self.lock();
        st.motion.centre = centre;
        if velocity != [0, 0] {
            st.motion.direction = velocity;
        }
        st.motion.mem = mem;
    }

    /// The counters so far.
    pub fn stats(&self) -> PoolStats {
        self.lock().stats.clone()
    }

    /// Whether `tile` is held now.
    pub fn contains(&self, tile: TileId) -> bool {
        self.lock().entries.contains_key(&tile)
    }

    /// Drops `tile` if it is held (its texels changed at the inner source): the next read of it
    /// reads the inner source again. Not counted as an eviction.
    pub(crate) fn forget(&self, tile: TileId) {
        let mut st = self.lock();
        if let Some(old) = st.entries.remove(&tile) {
            st.stats.bytes -= old.data.len() as u64;
            st.stats.tiles = st.entries.len() as u64;
        }
    }

    /// Tiles evicted so far, in order (empty unless [`recording`](Self::recording)).
    pub fn evictions(&self) -> Vec<TileId> {
        self.lock().log.clone().unwrap_or_default()
    }

    fn keep(st: &mut State, tile: TileId, bytes: &[u8], delivered: Delivered) {
        let size = bytes.len() as u64;
        if size > st.stats.budget_bytes {
            st.stats.too_large += 1;
            return;
        }
        if let Some(old) = st.entries.remove(&tile) {
            st.stats.bytes -= old.data.len() as u64;
        }
        while st.stats.bytes + size > st.stats.budget_bytes && !st.entries.is_empty() {
            let candidates: Vec<Candidate> =
                st.entries.iter().map(|(&tile, e)| Candidate { tile, last_used: e.last_used }).collect();
            let victim = candidates[st.eviction.victim(&candidates, &st.motion)].tile;
            let gone = st.entries.remove(&victim).expect("a candidate is held");
            st.stats.bytes -= gone.data.len() as u64;
            st.stats.evicted += 1;
            if let Some(log) = st.log.as_mut() {
                log.push(victim);
            }
        }
        let last_used = st.clock;
        st.entries.insert(tile, Entry { data: bytes.into(), delivered, last_used });
        st.stats.bytes += size;
        st.stats.peak_bytes = st.stats.peak_bytes.max(st.stats.bytes);
        st.stats.tiles = st.entries.len() as u64;
    }
}

impl TileSource for PoolSource {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.read_into(tile, out).map(|_| ())
    }

    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<Delivered, SourceError> {
        {
            let mut st = self.lock();
            st.clock += 1;
            let now = st.clock;
            if let Some(e) = st.entries.get_mut(&tile).filter(|e| e.data.len() == out.len()) {
                out.copy_from_slice(&e.data);
                e.last_used = now;
                let delivered = e.delivered;
                st.stats.hits += 1;
                return Ok(delivered);
            }
        }
        // Not under the lock: the inner source may be a disk.
        let delivered = self.inner.read_into(tile, out)?;
        let mut st = self.lock();
        st.stats.misses += 1;
        st.clock += 1;
        Self::keep(&mut st, tile, out, delivered);
        Ok(delivered)
    }

    fn wrapped(&self) -> Option<&dyn TileSource> {
        Some(&*self.inner)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::HashSource;
    use crate::texel::TexelFormat;

    /// A hash texture of 64 x 64 texels in 16-texel tiles (256 bytes each, L8), counting reads.
    struct Counting {
        inner: HashSource,
        reads: Mutex<Vec<TileId>>,
    }

    impl TileSource for Counting {
        fn desc(&self) -> &TextureDesc {
            self.inner.desc()
        }
        fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
            self.reads.lock().unwrap().push(tile);
            self.inner.read_tile(tile, out)
        }
    }

    fn pool(tiles: u64, policy: EvictionKind) -> (Arc<Counting>, PoolSource) {
        let desc = TextureDesc::new([64, 64], 32, TexelFormat::L8, [16, 16]).unwrap();
        let inner = Arc::new(Counting { inner: HashSource::new(desc), reads: Mutex::new(Vec::new()) });
        let p = PoolSource::new(inner.clone(), tiles * 256, policy).recording();
        (inner, p)
    }

    fn read(p: &PoolSource, s: u64) -> Vec<u8> {
        let mut out = vec![0u8; 256];
        p.read_into(TileId::new(0, s, 0), &mut out).unwrap();
        out
    }

    fn ids(v: &[TileId]) -> Vec<u64> {
        v.iter().map(|t| t.s).collect()
    }

    #[test]
    fn hits_are_copies_of_what_the_inner_source_gave_and_never_reach_it() {
        let (inner, p) = pool(3, EvictionKind::Lru);
        let first = read(&p, 1);
        assert_eq!(read(&p, 1), first);
        let mut direct = vec![0u8; 256];
        inner.inner.read_tile(TileId::new(0, 1, 0), &mut direct).unwrap();
        assert_eq!(first, direct);
        assert_eq!(ids(&inner.reads.lock().unwrap()), [1]);
        let s = p.stats();
        assert_eq!((s.hits, s.misses, s.tiles, s.bytes), (1, 1, 1, 256));
        assert_eq!(s.hit_rate(), 0.5);
    }

    #[test]
    fn lru_evicts_the_least_recently_used_within_the_byte_budget() {
        // Hand-checked, three tiles of room: read 0 1 2, touch 0, read 3 (evicts 1), read 1
        // (a miss, evicts 2), read 0 (a hit).
        let (inner, p) = pool(3, EvictionKind::Lru);
        for s in [0, 1, 2, 0, 3, 1, 0] {
            read(&p, s);
        }
        assert_eq!(ids(&inner.reads.lock().unwrap()), [0, 1, 2, 3, 1]);
        assert_eq!(ids(&p.evictions()), [1, 2]);
        let s = p.stats();
        assert_eq!((s.hits, s.misses, s.evicted, s.peak_bytes), (2, 5, 2, 3 * 256));
        assert!(s.bytes <= s.budget_bytes);
    }

    #[test]
    fn shift_evicts_the_tiles_farthest_behind_the_motion() {
        // The same reads as the LRU case, the viewer at x = 40 flying -s (projections of the
        // centres of columns 0 to 3 on -s: 128, 64, 0, -64): column 3 is behind, the others
        // ahead, 0 the farthest. Read 0 1 2, touch 0, read 3 (evicts 0: nothing of 0 1 2 is
        // behind), read 1 (a hit), read 0 (evicts 3, behind), read 2 (a hit).
        let (inner, p) = pool(3, EvictionKind::Shift);
        p.hint([40, 8], [-4, 0], vec![Rect::EMPTY; 3]);
        for s in [0, 1, 2, 0, 3, 1, 0, 2] {
            read(&p, s);
        }
        assert_eq!(ids(&inner.reads.lock().unwrap()), [0, 1, 2, 3, 0]);
        assert_eq!(ids(&p.evictions()), [0, 3]);
        // A stop keeps the last direction: 0 is again the farthest ahead.
        p.hint([40, 8], [0, 0], vec![Rect::EMPTY; 3]);
        read(&p, 3);
        assert_eq!(ids(&p.evictions()), [0, 3, 0]);
    }

    #[test]
    fn a_zero_budget_keeps_nothing() {
        let (inner, p) = pool(0, EvictionKind::Shift);
        read(&p, 1);
        read(&p, 1);
        assert_eq!(inner.reads.lock().unwrap().len(), 2);
        assert_eq!(p.stats().too_large, 2);
        assert_eq!(p.stats().peak_bytes, 0);
    }
}
