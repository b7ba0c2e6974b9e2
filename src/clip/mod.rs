//! The clipmap: per-level image caches (toroidal grids of whole tiles) kept filled around a
//! moving centre, and what renderers may read of them.
//!
//! Owns the update tick. Each tick it takes finished reads (each already in its slot), moves
//! every level's regions to the new centre, publishes — once, as one snapshot — each level's
//! valid region as far as the tiles under it are settled, with min LOD moved past any level whose
//! region is not whole yet (load control, docs/ARCHITECTURE.md §6), and only then gives the slots
//! of tiles that left their mem region to the tiles that entered it and asks the read queues for
//! them. The tick itself writes no texel: reads write tiles straight into their slots, on the
//! read queues' threads, a growing texture's rebuilt tiles included ([`Clipmap::refresh`]: the
//! tick reopens a resident tile's slot and asks the queues for it).
//!
//! The invariant it keeps: **every texel inside a published valid region is in a settled slot**
//! (ready, the default tile, or missing, which readers see in the slot's tag and serve from a
//! coarser level), and a slot is given to another tile only after a snapshot that no longer
//! covers its old tile. Geometry is [`crate::geom`]'s, where each mem region lies (the prefetch
//! policy) and the second-level tile pool [`crate::paging`]'s, slots are [`crate::cache`]'s and
//! [`crate::shm::memory`]'s, reads [`crate::queue`]'s.

pub mod load;
pub mod stats;
pub mod views;

pub use load::{next_min_lod, target_min_lod};
pub use stats::{FaultCounts, Stats, TickReport};
pub use views::{demotion, offset_for_footprint, LodWindow, ViewError, ViewId, MAX_VIEWS, PRIMARY};

use crate::cache::{Admit, TileCache, TileState};
use crate::geom::{aligned_centre, level_grid, tile_texels, tiles_covering, LevelFrame, LevelShape, Rect};
use crate::limits::Limits;
use crate::paging::{adaptive, EvictionKind, PrefetchKind};
use crate::queue::{priority, soonest_first, Completion, Outcome, QueueError, ReadQueues, ReadRequest};
use crate::shm::layout::{self, Shape};
use crate::shm::{ImageMemory, Publication, PublishedLevel};
use crate::source::{PoolSource, SourceError, TextureDesc, TileSource};
use crate::tile::TileId;
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};
use thiserror::Error;

/// Run-time settings of a clipmap.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Extra tile rows and columns kept beyond those the window touches (Performer default 1).
    pub lookahead: u64,
    /// Number of stream servers (read queues); the source picks each tile's queue
    /// ([`TileSource::stream_of`], by default tile column S mod n). Use the source's
    /// [`TileSource::stream_servers`] to give each configured server its own queue.
    pub streams: usize,
    /// Bound on the time one tick spends on its own work (taking finished reads, in
    /// nanoseconds); reads left over are taken by the next tick. `None`: unbounded.
    pub budget_ns: Option<u64>,
    /// Ticks to fade one level back in after it is up to date again (0: at once).
    pub fade_ticks: u32,
    /// Most level-0 texels the centre may move per tick along each axis; `None`: unclamped.
    pub max_centre_step: Option<u64>,
    /// Each level's centre (level 0's shifted right by the level) is aligned down to a multiple
    /// of this many level texels, Performer's "shift and mask" (its InfiniteReality aligned to 8).
    /// 1 (or 0) keeps centres texel-exact. Larger values make a level's window move in steps, so
    /// column strips are copied wider and less often (faster), while the valid region lags the
    /// true centre by up to `alignment - 1` level texels on the side the view moves towards
    /// (less of the finest level there). Levels given their own centre are not aligned.
    pub centre_alignment: u64,
    /// Ticks to wait before reading a failed tile again.
    pub retry_after_ticks: u64,
    /// Where each level's grid puts its spare tiles ([`crate::paging`]).
    pub prefetch: PrefetchKind,
    /// Bytes of tiles a second-level pool keeps in process memory beyond the grids
    /// ([`PoolSource`]; 0: no pool). Counted with the image caches against
    /// `limits.cache_bytes`.
    pub pool_bytes: u64,
    /// Which pooled tile goes first when a new one does not fit.
    pub eviction: EvictionKind,
    /// Bounds on queues and memory.
    pub limits: Limits,
    /// Bytes the grids of levels without a configured mem region may take under the adaptive
    /// policy (`None`: `crate::paging::adaptive::DEFAULT_BUDGET_FACTOR` times the bytes of the
    /// lookahead-1 grids), capped by `limits.cache_bytes` less the pool. The fixed policies
    /// size grids from `lookahead` and ignore it.
    pub grid_budget: Option<u64>,
    /// Level-0 texels by which further views' windows may lie apart and still be held whole
    /// ([`views`]): each level's grid gets `ceil((view_spread >> k) / tile)` more tiles per axis
    /// (0: grids for one view; the views share what it holds). `cliptex plan`'s memory formula
    /// counts them.
    pub view_spread: u64,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            lookahead: 1,
            streams: 1,
            budget_ns: Some(6_000_000),
            fade_ticks: 5,
            max_centre_step: None,
            centre_alignment: 1,
            retry_after_ticks: 4,
            prefetch: PrefetchKind::default(),
            pool_bytes: 0,
            eviction: EvictionKind::default(),
            limits: Limits::default(),
            grid_budget: None,
            view_spread: 0,
        }
    }
}

impl Settings {
    /// These settings with the user's paging choices (prefetch, pool, eviction, centre clamp).
    pub fn with_paging(self, p: &crate::paging::PagingOptions) -> Settings {
        Settings {
            prefetch: p.prefetch,
            eviction: p.eviction,
            pool_bytes: p.pool_bytes,
            max_centre_step: p.max_centre_step,
            grid_budget: p.grid_budget,
            ..self
        }
    }
}

pub use crate::limits::MAX_CENTRE_ALIGNMENT;

/// Most [`Clipmap::refresh`]ed tiles being replaced at once, per read slot of the queues
/// (`streams` times `Limits::max_in_flight_reads`): a run of reads each (a queue's thread reads
/// up to 16 tiles in a row), so that the replacements keep the queues busy while few tiles at a
/// time fall back to a coarser level.
const MAX_REPLACING_PER_READ_SLOT: usize = 16;

/// Why a clipmap could not be built.
#[derive(Debug, Error)]
pub enum ClipError {
    /// The read queues could not start.
    #[error(transparent)]
    Queue(#[from] QueueError),
    /// The image caches would take more memory than allowed.
    #[error("the image caches need {needed} bytes, any tile pool's budget included: the limit is {limit} bytes (Limits::cache_bytes); choose a smaller clip size, larger tiles, a smaller mem region or a smaller pool")]
    CacheBytes {
        /// The bytes the image caches need, any pool included.
        needed: u64,
        /// The most allowed (`Limits::cache_bytes`).
        limit: u64,
    },
    /// The image caches cannot be laid out or mapped.
    #[error("cannot make the image caches: {0}")]
    Memory(String),
    /// Caller-supplied memory is laid out for another texture or other grids.
    #[error("the image-cache memory supplied is laid out as {found:?}: this texture and its settings need {expected:?}; make it from Clipmap::memory_shape")]
    MemoryShape {
        /// How the memory supplied is laid out.
        found: Box<Shape>,
        /// How this texture and its settings need it.
        expected: Box<Shape>,
    },
}

/// The layout of the image caches of `desc` with mem grids `grids` (one per level).
pub fn memory_shape(desc: &TextureDesc, grids: &[[u64; 2]]) -> Shape {
    Shape {
        bytes_per_texel: desc.bytes_per_texel() as u64,
        clip_size: desc.clip_size(),
        levels: desc
            .levels()
            .iter()
            .zip(grids)
            .map(|(l, &grid)| layout::LevelShape { size: l.size, tile: l.tile, grid })
            .collect(),
    }
}

/// A read-only view of one level, as published.
#[derive(Clone, Copy, Debug)]
pub struct LevelView<'a> {
    /// Level index.
    pub level: u32,
    /// Level size in texels.
    pub size: [u64; 2],
    /// Clip size.
    pub clip: u64,
    /// Tile size in texels.
    pub tile: [u64; 2],
    /// Slots per axis of the level's grid.
    pub grid: [u64; 2],
    /// Bytes per texel.
    pub bpt: usize,
    /// Published valid region: texels readers may read (where their tiles are readable).
    pub valid: Rect,
    /// The level's current centre.
    pub centre: [i64; 2],
    cache: &'a TileCache,
}

impl LevelView<'_> {
    /// The tile holding texel (s, t).
    pub fn tile_of(&self, s: i64, t: i64) -> TileId {
        TileId::new(self.level, s.div_euclid(self.tile[0] as i64) as u64, t.div_euclid(self.tile[1] as i64) as u64)
    }

    /// The state of the tile holding texel (s, t).
    pub fn tile_state(&self, s: i64, t: i64) -> TileState {
        self.cache.state(self.tile_of(s, t))
    }

    /// The texel at (s, t) if it lies in the published valid region and its tile is readable (a
    /// missing tile's texels come from a coarser level).
    pub fn texel(&self, s: i64, t: i64) -> Option<Texel> {
        if !self.valid.contains(s, t) {
            return None;
        }
        let tile = self.tile_of(s, t);
        let (tw, th) = (self.tile[0] as i64, self.tile[1] as i64);
        let i = ((t - tile.t as i64 * th) * tw + (s - tile.s as i64 * tw)) as usize * self.bpt;
        let mut texel = Texel { bytes: [0; 16], len: self.bpt.min(16) as u8 };
        self.cache.read(tile, i, &mut texel.bytes[..texel.len as usize]).then_some(texel)
    }
}

/// One texel's bytes (at most 16: four 32-bit components), copied out of a window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Texel {
    bytes: [u8; 16],
    len: u8,
}

impl std::ops::Deref for Texel {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        &self.bytes[..self.len as usize]
    }
}

struct Level {
    shape: LevelShape,
    frame: LevelFrame,
    /// What the last snapshot published.
    published: Rect,
    updated_tick: u64,
}

/// A clip texture being kept up to date around a centre.
pub struct Clipmap {
    desc: TextureDesc,
    settings: Settings,
    cache: TileCache,
    queues: ReadQueues,
    levels: Vec<Level>,
    /// Finished reads not yet taken (a tick's budget ran out).
    backlog: VecDeque<Completion>,
    /// The second-level tile pool the queues read through, if any.
    pool: Option<Arc<PoolSource>>,
    /// The source, as given (its counters: [`Clipmap::source`]).
    source: Arc<dyn TileSource>,
    centre: Option<[i64; 2]>,
    border: u64,
    min_lod: f64,
    tick: u64,
    stats: Stats,
    /// Tiles whose texels changed at the source, waiting to be replaced in their slots, in order.
    refresh: VecDeque<TileId>,
    /// The same tiles, to ask for each once.
    refreshing: std::collections::HashSet<TileId>,
    /// Tiles being replaced in their slots ([`TileState::Replacing`]): their reads asked of the
    /// queues, not yet taken.
    replacing: std::collections::HashSet<TileId>,
    /// The adaptive policy's measurements and choices (`None` for the fixed policies).
    controller: Option<Controller>,
    /// The source's heights (`None`: colours), for the height sampler.
    heights: Option<crate::plan::HeightPlan>,
    /// Further views sharing the grids ([`views`]), and the primary's weight.
    views: views::Views,
    /// The source's [`TileSource::version`] when every tile held was last read of it.
    source_version: u64,
}

/// What the adaptive policy measures and chose ([`crate::paging::adaptive`]).
#[derive(Debug, Default)]
struct Controller {
    motion: adaptive::Motion,
    /// Each stream server's read latency and tile rate, and which servers read each level's
    /// tiles.
    latency: adaptive::StreamMeasures,
    /// Tiles first asked of each stream server since its rate last took a tick's counts.
    asked_now: Vec<u64>,
    /// The tick each tile being read was first asked for, whether its level was whole then, and
    /// the stream server that reads it.
    asked: std::collections::HashMap<TileId, (u64, bool, usize)>,
    /// Each level's lead now and the lead its motion needed (level texels per axis).
    lead: Vec<[u64; 2]>,
    needed: Vec<[u64; 2]>,
}

impl Clipmap {
    /// A clipmap of `source`'s texture with nothing resident yet (min LOD above every level),
    /// its image caches in private memory.
    pub fn new(source: Arc<dyn TileSource>, settings: Settings) -> Result<Self, ClipError> {
        let shape = Self::shape_for(source.desc(), &settings);
        let memory = ImageMemory::anonymous(shape, source.desc().format()).map_err(ClipError::Memory)?;
        Self::with_memory(source, settings, Arc::new(memory))
    }

    /// The mem grid of each level of `desc` under `settings` (lookahead, or the configuration's
    /// mem regions).
    pub fn grids(desc: &TextureDesc, settings: &Settings) -> Vec<[u64; 2]> {
        let clip = desc.clip_size();
        let fixed: Vec<[u64; 2]> = desc
            .levels()
            .iter()
            .enumerate()
            .map(|(k, l)| level_grid(l.size, l.tile, clip, settings.lookahead, desc.mem_grid(k as u32)))
            .collect();
        if settings.prefetch != PrefetchKind::Adaptive {
            return views::spread_grids(desc, fixed, settings.view_spread);
        }
        // Levels whose configuration fixes a mem region keep it; the others share the budget.
        let free: Vec<usize> = (0..fixed.len()).filter(|&k| desc.mem_grid(k as u32).is_none()).collect();
        let bytes = |k: usize, g: [u64; 2]| g[0] * g[1] * desc.tile_bytes(k as u32) as u64;
        let (total, fixed_bytes) = Self::budget_parts(desc, settings);
        let budget = total.saturating_sub(fixed_bytes);
        let levels: Vec<_> = free.iter().map(|&k| (desc.level(k as u32).size, desc.level(k as u32).tile)).collect();
        let (grids, _) = crate::paging::adaptive::budget_grids(&levels, clip, |i| bytes(free[i], [1, 1]), budget);
        let mut out = fixed;
        for (i, &k) in free.iter().enumerate() {
            out[k] = grids[i];
        }
        views::spread_grids(desc, out, settings.view_spread)
    }

    /// The bytes the adaptive policy's grids may take, all levels together (`None` for the fixed
    /// policies): `settings.grid_budget`, or by default `adaptive::DEFAULT_BUDGET_FACTOR` times
    /// the bytes of the lookahead-1 grids of the levels no configuration fixes plus the bytes of
    /// those it fixes (which keep their grids), capped by `limits.cache_bytes` less the pool.
    pub fn grid_budget(desc: &TextureDesc, settings: &Settings) -> Option<u64> {
        if settings.prefetch != PrefetchKind::Adaptive {
            return None;
        }
        Some(Self::budget_parts(desc, settings).0)
    }

    /// (the adaptive grids' whole budget, the bytes of the levels whose grids a configuration
    /// fixes within it).
    fn budget_parts(desc: &TextureDesc, settings: &Settings) -> (u64, u64) {
        let clip = desc.clip_size();
        let bytes = |k: u32, g: [u64; 2]| g[0] * g[1] * desc.tile_bytes(k) as u64;
        let (mut base, mut fixed) = (0u64, 0u64);
        for (k, l) in desc.levels().iter().enumerate() {
            let k = k as u32;
            match desc.mem_grid(k) {
                None => base = base.saturating_add(bytes(k, crate::geom::mem_grid(l.size, l.tile, clip, 1))),
                Some(_) => {
                    let g = level_grid(l.size, l.tile, clip, settings.lookahead, desc.mem_grid(k));
                    fixed = fixed.saturating_add(bytes(k, g));
                }
            }
        }
        let cap = (settings.limits.cache_bytes as u64).saturating_sub(settings.pool_bytes);
        let default = base.saturating_mul(adaptive::DEFAULT_BUDGET_FACTOR).saturating_add(fixed);
        (settings.grid_budget.unwrap_or(default).min(cap), fixed)
    }

    /// The layout of the image caches a clipmap of `desc` under `settings` keeps (what
    /// [`with_memory`](Self::with_memory) wants, e.g. for [`crate::shm::Writer::create`]).
    pub fn shape_for(desc: &TextureDesc, settings: &Settings) -> Shape {
        memory_shape(desc, &Self::grids(desc, settings))
    }

    /// [`new`](Self::new), keeping the image caches in `memory` (laid out by
    /// [`shape_for`](Self::shape_for)), such as the service's mapping: tiles are then read
    /// straight to where renderers read them.
    pub fn with_memory(
        source: Arc<dyn TileSource>,
        settings: Settings,
        memory: Arc<ImageMemory>,
    ) -> Result<Self, ClipError> {
        let desc = source.desc().clone();
        let grids = Self::grids(&desc, &settings);
        let expected = memory_shape(&desc, &grids);
        if *memory.shape() != expected {
            return Err(ClipError::MemoryShape {
                found: Box::new(memory.shape().clone()),
                expected: Box::new(expected),
            });
        }
        let needed = memory.total_bytes().saturating_add(settings.pool_bytes);
        let limit = settings.limits.cache_bytes as u64;
        if needed > limit {
            return Err(ClipError::CacheBytes { needed, limit });
        }
        let clip = desc.clip_size();
        let levels: Vec<Level> = desc
            .levels()
            .iter()
            .zip(&grids)
            .map(|(l, &grid)| Level {
                shape: LevelShape { size: l.size, tile: l.tile, clip, grid },
                frame: LevelFrame { centre: [0, 0], tex: Rect::EMPTY, valid: Rect::EMPTY, mem: Rect::EMPTY },
                published: Rect::EMPTY,
                updated_tick: 0,
            })
            .collect();
        let keeper = memory.take_keeper().ok_or_else(|| {
            ClipError::Memory(
                "another clipmap already keeps this memory's slots (one memory has one engine at a time): \
                 drop it first, or give this clipmap a memory of its own"
                    .to_string(),
            )
        })?;
        let cache = TileCache::new(&desc, &grids, Arc::clone(&memory), keeper);
        let pool = (settings.pool_bytes > 0)
            .then(|| Arc::new(PoolSource::new(source.clone(), settings.pool_bytes, settings.eviction)));
        let reader: Arc<dyn TileSource> = match &pool {
            Some(p) => p.clone(),
            None => source.clone(),
        };
        let queues = ReadQueues::new(reader, memory, settings.streams, settings.limits)?;
        let (settings_prefetch, level_count, streams) = (settings.prefetch, levels.len(), queues.streams());
        let heights = source.heights();
        Ok(Clipmap {
            heights,
            border: desc.invalid_border(),
            min_lod: desc.level_count() as f64,
            desc,
            settings,
            cache,
            queues,
            levels,
            backlog: VecDeque::new(),
            pool,
            source: source.clone(),
            centre: None,
            views: views::Views::default(),
            source_version: source.version(),
            tick: 0,
            stats: Stats::default(),
            refresh: VecDeque::new(),
            refreshing: Default::default(),
            replacing: Default::default(),
            controller: (settings_prefetch == PrefetchKind::Adaptive).then(|| Controller {
                lead: vec![[0, 0]; level_count],
                needed: vec![[0, 0]; level_count],
                latency: adaptive::StreamMeasures::new(streams, level_count),
                asked_now: vec![0; streams],
                ..Controller::default()
            }),
        })
    }

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
    fn follow_source_version(&mut self) {
        let now = self.source.version();
        if now == self.source_version {
            return;
        }
        self.source_version = now;
        let held: Vec<TileId> = (0..self.levels.len() as u32)
            .flat_map(|k| {
                let mem = self.cache.mem_region(k);
                (mem.t0.max(0)..mem.t1)
                    .flat_map(move |t| (mem.s0.max(0)..mem.s1).map(move |s| TileId::new(k, s as u64, t as u64)))
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
    fn replace_tiles(&mut self) {
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

    /// The texture.
    pub fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    /// The image caches' memory.
    pub fn memory(&self) -> &Arc<ImageMemory> {
        self.cache.memory()
    }

    /// The source the clipmap reads, as given to it (before any tile pool).
    pub fn source(&self) -> &Arc<dyn TileSource> {
        &self.source
    }

    /// Counters so far.
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// Each read queue's counters, in stream-server order (their sum is `stats().queue`).
    pub(crate) fn stream_stats(&self) -> Vec<crate::queue::QueueStats> {
        self.queues.stream_stats()
    }

    /// The finest level renderers may use (fractional while a level fades in; the level count
    /// when none may be used yet).
    pub fn min_lod(&self) -> f64 {
        self.min_lod
    }

    /// Whether the texels are heights, and their format and level rule (the source's,
    /// [`TileSource::heights`]); `None` for colours.
    pub fn heights(&self) -> Option<crate::plan::HeightPlan> {
        self.heights
    }

    /// The level-0 centre applied by the last tick.
    pub fn centre(&self) -> Option<[i64; 2]> {
        self.centre
    }

    /// The invalid border now.
    pub fn invalid_border(&self) -> u64 {
        self.border
    }

    /// Widens (or narrows) the invalid border from the next tick on, clamped so that at least one
    /// texel of each stack window stays readable.
    pub(crate) fn set_invalid_border(&mut self, border: u64) {
        self.border = border.min((self.desc.clip_size() - 1) / 2);
    }

    /// Sets the bound on a tick's own work (ns; `None`: unbounded).
    pub(crate) fn set_budget_ns(&mut self, budget: Option<u64>) {
        self.settings.budget_ns = budget;
    }

    /// Level `k` as published.
    pub fn level(&self, k: u32) -> LevelView<'_> {
        let l = &self.levels[k as usize];
        LevelView {
            level: k,
            size: l.shape.size,
            clip: l.shape.clip,
            tile: l.shape.tile,
            grid: l.shape.grid,
            bpt: self.desc.bytes_per_texel(),
            valid: l.published,
            centre: l.frame.centre,
            cache: &self.cache,
        }
    }

    /// Each level's mem region (tile indices) as the last tick placed it: the tiles its grid
    /// holds or is reading.
    pub fn mem_regions(&self) -> Vec<Rect> {
        (0..self.levels.len() as u32).map(|k| self.cache.mem_region(k)).collect()
    }

    /// Number of levels.
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// Bytes of the image caches (every slot of every level, the tags and the header), whatever
    /// is in them, plus the tiles the second-level pool holds now: what this clipmap holds.
    pub fn resident_bytes(&self) -> u64 {
        self.cache.memory().total_bytes() + self.pool.as_ref().map_or(0, |p| p.stats().bytes)
    }

    /// The second-level tile pool, if the settings ask for one.
    pub fn pool(&self) -> Option<&Arc<PoolSource>> {
        self.pool.as_ref()
    }

    /// Blocks until every read that can start has finished (tests and offline simulation; not
    /// from async code). The next tick takes the results.
    pub fn wait_for_reads(&mut self) {
        self.queues.flush();
    }

    /// One update tick towards `centre` (level-0 texels), moving at `velocity` level-0 texels per
    /// tick if given (else the change since the last tick).
    pub fn tick(&mut self, centre: [i64; 2], velocity: Option<[i64; 2]>) -> TickReport {
        let started = Instant::now();
        self.tick += 1;
        self.stats.ticks += 1;
        // Whatever a renderer asked for (any i64 through the mapping or the socket): bounded
        // before any arithmetic, so that no difference or product of them can overflow.
        let far = crate::limits::MAX_CENTRE;
        let clamps = self.stats.centre_clamps;
        let centre = self.clamp_centre(centre.map(|c| c.clamp(-far, far)));
        let velocity = velocity.map(|v| v.map(|x| x.clamp(-far, far)));
        let velocity = velocity.unwrap_or_else(|| self.centre.map_or([0, 0], |c| [centre[0] - c[0], centre[1] - c[1]]));
        self.centre = Some(centre);
        let mut report =
            TickReport { centre, clamped: self.stats.centre_clamps > clamps, velocity, ..TickReport::default() };

        let (taken, replaced, left) = self.take_reads(started);
        report.tiles_read = taken;
        report.tiles_replaced = replaced;
        report.over_budget = left > 0;
        if left > 0 {
            self.stats.ticks_over_budget += 1;
            self.stats.reads_deferred += left as u64;
        }
        self.follow_source_version();
        if !self.refresh.is_empty() || !self.replacing.is_empty() {
            self.replace_tiles();
        }
        self.move_view_frames();
        let velocities = self.move_frames(centre, velocity);
        if let Some(pool) = &self.pool {
            pool.hint(centre, velocity, self.levels.iter().map(|l| l.frame.mem).collect());
        }

        // Publish what is settled under each valid region, once, as one snapshot.
        let mut complete = Vec::with_capacity(self.levels.len());
        let lod = self.views.primary_lod;
        for k in 0..self.levels.len() {
            // A level finer than the primary's LOD offset is not published for it (nor held for it).
            let shown = lod.shows(k as u32);
            let region = if shown { self.settled_region(k) } else { Rect::EMPTY };
            let level = &mut self.levels[k];
            complete.push(if shown { region == level.frame.valid || level.frame.valid.is_empty() } else { false });
            if region != level.published {
                level.published = region;
                level.updated_tick = self.tick;
            }
            if shown && region != level.frame.valid && !level.frame.valid.is_empty() {
                self.stats.levels_waiting_for_tiles += 1;
            }
        }
        self.update_min_lod(&complete);
        self.publish_views();
        self.publish();
        self.stats.paging = self.paging_report(&complete);
        self.stats.read_latency_ticks = self.controller.as_ref().map_or(0.0, |c| c.latency.slowest());
        self.stats.stream_read_latency_ticks =
            self.controller.as_ref().map_or_else(|| vec![0.0; self.queues.streams()], |c| c.latency.per_stream());

        // Only now may slots of tiles that left their mem region go to the tiles that entered.
        self.request_tiles(&velocities);

        report.min_lod = self.min_lod;
        report.disabled_levels = (0..self.levels.len() as u32).filter(|&k| ((k + 1) as f64) <= self.min_lod).collect();
        if !report.disabled_levels.is_empty() {
            self.stats.ticks_with_disabled_level += 1;
        }
        report.valid = self.levels.iter().map(|l| l.published).collect();
        self.stats.queue = self.queues.stats();
        self.stats.slots_reassigned_under_published = self.cache.memory().invariant_violations();
        if let Some(pool) = &self.pool {
            self.stats.pool = pool.stats();
        }
        self.stats.peak_resident_bytes = self.stats.peak_resident_bytes.max(self.resident_bytes());
        report.tick_ns = started.elapsed().as_nanos() as u64;
        self.stats.tick_ns += report.tick_ns;
        report
    }

    fn publish(&mut self) {
        let p = Publication {
            min_lod: self.min_lod,
            tick: self.tick,
            invalid_border: self.border,
            centre: self.centre.unwrap_or([0, 0]),
            levels: self
                .levels
                .iter()
                .map(|l| PublishedLevel { centre: l.frame.centre, valid: l.published, updated_tick: l.updated_tick })
                .collect(),
        };
        self.cache.memory().publish(&p);
        self.store_view_publications();
        self.stats.publications += 1;
    }

    fn clamp_centre(&mut self, want: [i64; 2]) -> [i64; 2] {
        let (Some(step), Some(old)) = (self.settings.max_centre_step, self.centre) else { return want };
        let step = step.min(i64::MAX as u64) as i64;
        let clamp = |w: i64, o: i64| w.clamp(o.saturating_sub(step), o.saturating_add(step));
        let got = [clamp(want[0], old[0]), clamp(want[1], old[1])];
        if got != want {
            self.stats.centre_clamps += 1;
        }
        got
    }

    /// Takes finished reads (each already in its slot) until the tick's budget is spent; returns
    /// (tiles admitted, tiles replaced in their slots, left for the next tick).
    fn take_reads(&mut self, started: Instant) -> (u64, u64, usize) {
        self.backlog.extend(self.queues.drain());
        // The stream servers that measured a read this tick, and the tiles each delivered.
        let streams = self.controller.as_ref().map_or(0, |c| c.latency.stream_count());
        let mut sampled = vec![false; streams];
        let mut taken = vec![0u64; streams];
        let budget = self.settings.budget_ns.map(Duration::from_nanos);
        let mut admitted = 0;
        let mut replaced = 0;
        let mut n = 0u32;
        while let Some(done) = self.backlog.pop_front() {
            match done.outcome {
                Outcome::Filled(generation, delivered) => match self.cache.admit(done.tile, generation, delivered) {
                    Admit::Admitted => {
                        admitted += 1;
                        if let Some(c) = &mut self.controller {
                            if let Some((at, whole, stream)) = c.asked.remove(&done.tile) {
                                if whole {
                                    c.latency.sample(stream, self.tick.saturating_sub(at));
                                    sampled[stream] = true;
                                }
                                taken[stream] += 1;
                            }
                        }
                        if delivered == crate::source::Delivered::Default {
                            self.stats.default_tiles += 1;
                        }
                    }
                    // A refreshed tile's new texels (not a read the paging asked for).
                    Admit::Replaced => replaced += 1,
                    Admit::Stale => self.stats.late_tiles += 1,
                },
                // A simulated disk spent its reads for the tick: the tile stays wanted.
                Outcome::Failed(_, SourceError::Busy { .. }) => {
                    self.stats.reads_put_off += 1;
                    self.cache.mark_not_read(done.tile);
                }
                Outcome::NotWanted => {
                    self.stats.late_tiles += 1;
                    self.cache.mark_not_read(done.tile);
                }
                Outcome::Failed(generation, e) => {
                    tracing::debug!("tile read failed: {e}");
                    self.stats.read_faults.add(e.kind());
                    let retry_at = self.tick + self.settings.retry_after_ticks;
                    self.cache.mark_failed(done.tile, generation, e.kind(), retry_at);
                }
            }
            n += 1;
            if n.is_multiple_of(16) && budget.is_some_and(|b| started.elapsed() >= b) {
                break;
            }
        }
        self.stats.tiles_read += admitted;
        self.stats.tiles_replaced += replaced;
        if let Some(c) = &mut self.controller {
            for (stream, _) in sampled.iter().enumerate().filter(|(_, &measured)| !measured) {
                c.latency.rest(stream);
            }
            for (stream, &d) in taken.iter().enumerate() {
                let asked = std::mem::take(&mut c.asked_now[stream]);
                c.latency.count(stream, asked, d);
            }
        }
        (admitted, replaced, self.backlog.len())
    }

    /// Moves every level's frame to the new centre; returns each level's velocity in its texels.
    fn move_frames(&mut self, centre: [i64; 2], velocity: [i64; 2]) -> Vec<[i64; 2]> {
        let mut out = Vec::with_capacity(self.levels.len());
        let others = self.views_windows();
        if let Some(c) = &mut self.controller {
            // A move of more than a window is a jump: the read-ahead restarts centred.
            c.motion.update(velocity, self.desc.clip_size());
        }
        for (k, level) in self.levels.iter_mut().enumerate() {
            let k32 = k as u32;
            let c = aligned_centre(centre, k32, self.settings.centre_alignment);
            let v = velocity.map(|x| if x != 0 && (x >> k32.min(63)) == 0 { x.signum() } else { x >> k32.min(63) });
            let previous = level.frame.mem;
            level.frame = level.shape.frame(c, self.border, v);
            // With further views, the grid holds the union of their windows where it can; a level
            // no view shows (their LOD windows) holds nothing and reads nothing.
            let own = if self.views.primary_lod.shows(k32) { level.frame.tex } else { Rect::EMPTY };
            let tex = views::mem_window(&level.shape, own, &others[k]);
            if tex.is_empty() {
                level.frame.mem = Rect::EMPTY;
                out.push(v);
                continue;
            }
            level.frame.mem = match &mut self.controller {
                None => self.settings.prefetch.policy().mem_region(&level.shape, tex, v, previous),
                // A grid a configuration fixes (`mem_region_size`, or its lookahead) is held whole,
                // as the configuration says, its spare tiles around the window: reported fixed.
                Some(_) if self.desc.mem_grid(k32).is_some() => {
                    PrefetchKind::Ring.policy().mem_region(&level.shape, tex, v, previous)
                }
                Some(ctl) => {
                    let smooth = ctl.motion.at_level(k32);
                    let speed = ctl.motion.speed_at_level(k32);
                    let jump = velocity.map(|x| x.unsigned_abs() > self.desc.clip_size());
                    // The latency of the stream servers that read this level's tiles.
                    let latency = ctl.latency.level(k);
                    let mut lead = [0; 2];
                    for a in 0..2 {
                        // The smoothed speed, or this tick's when it is faster (a flight that
                        // speeds up is led at once) and no jump.
                        let now = if jump[a] { 0.0 } else { v[a].unsigned_abs() as f64 };
                        let need = adaptive::lead_texels(speed[a].max(now), latency);
                        ctl.needed[k][a] = need;
                        // A still axis (or one just recentred by a jump) holds no lead.
                        lead[a] = if smooth[a] == 0 { 0 } else { adaptive::held_lead(ctl.lead[k][a], need) };
                    }
                    ctl.lead[k] = lead;
                    adaptive::region(&level.shape, tex, smooth, lead)
                }
            };
            out.push(v);
        }
        out
    }

    /// The part of level `k`'s valid region whose tiles are all settled: the whole region when
    /// they are, else the largest rectangle of settled tiles grown from the centre's tile (empty
    /// when that tile is not settled).
    fn settled_region(&self, k: usize) -> Rect {
        self.settled_in(k, &self.levels[k].frame)
    }

    /// [`settled_region`](Self::settled_region) of any view's `frame` of level `k`: only tiles
    /// inside the level's new mem region count as settled (a tile about to leave it is not
    /// published, so no slot the tick reassigns lies under a published region).
    fn settled_in(&self, k: usize, frame: &LevelFrame) -> Rect {
        let level = &self.levels[k];
        let valid = frame.valid;
        if valid.is_empty() {
            return Rect::EMPTY;
        }
        let tile = level.shape.tile;
        let tiles = tiles_covering(valid, tile);
        let mem = level.frame.mem;
        let settled = |s: i64, t: i64| {
            mem.contains(s, t) && self.cache.state(TileId::new(k as u32, s as u64, t as u64)).settled()
        };
        let all = |r: Rect| (r.t0..r.t1).all(|t| (r.s0..r.s1).all(|s| settled(s, t)));
        if all(tiles) {
            return valid;
        }
        let c = frame.centre;
        let cs = c[0].clamp(valid.s0, valid.s1 - 1).div_euclid(tile[0] as i64);
        let ct = c[1].clamp(valid.t0, valid.t1 - 1).div_euclid(tile[1] as i64);
        if !settled(cs, ct) {
            return Rect::EMPTY;
        }
        let mut r = Rect::new(cs, ct, cs + 1, ct + 1);
        loop {
            let mut grew = false;
            if r.s0 > tiles.s0 && all(Rect::new(r.s0 - 1, r.t0, r.s0, r.t1)) {
                r.s0 -= 1;
                grew = true;
            }
            if r.s1 < tiles.s1 && all(Rect::new(r.s1, r.t0, r.s1 + 1, r.t1)) {
                r.s1 += 1;
                grew = true;
            }
            if r.t0 > tiles.t0 && all(Rect::new(r.s0, r.t0 - 1, r.s1, r.t0)) {
                r.t0 -= 1;
                grew = true;
            }
            if r.t1 < tiles.t1 && all(Rect::new(r.s0, r.t1, r.s1, r.t1 + 1)) {
                r.t1 += 1;
                grew = true;
            }
            if !grew {
                break;
            }
        }
        let (tw, th) = (tile[0] as i64, tile[1] as i64);
        valid.intersect(&Rect::new(r.s0 * tw, r.t0 * th, r.s1 * tw, r.t1 * th))
    }

    /// Gives the slots of tiles that left each mem region to the tiles that entered, and asks
    /// the read queues for every tile wanted now.
    fn request_tiles(&mut self, velocities: &[[i64; 2]]) {
        let count = self.levels.len();
        let mut wanted = Vec::new();
        // A tile whose finished read waits in the backlog (a spent budget) is in its slot already:
        // asking for it again would read it twice.
        let waiting: std::collections::HashSet<TileId> = self.backlog.iter().map(|c| c.tile).collect();
        let views = self.views.live().next().is_some();
        for (k, level) in self.levels.iter().enumerate() {
            let k32 = k as u32;
            if views {
                self.stats.slots_reassigned_under_views += self.under_views_leaving(k, level.frame.mem);
            }
            self.stats.tiles_evicted += self.cache.set_mem_region(k32, level.frame.mem);
            for tile in self.cache.wanted(k32, self.tick) {
                if waiting.contains(&tile) {
                    continue;
                }
                let texels = tile_texels(level.shape.size, level.shape.tile, [tile.s, tile.t]);
                let p = if self.controller.is_some() {
                    soonest_first(k32, count, texels, level.frame.valid, level.shape.clip, velocities[k])
                } else {
                    priority(k32, count, texels, level.frame.valid, level.shape.clip, velocities[k])
                };
                let p = if views { self.view_priority(k, texels, p, self.controller.is_some()) } else { p };
                wanted.push(ReadRequest { tile, priority: p });
                self.cache.mark_loading(tile);
                // A tile replaced in its slot is no paging read: the read-ahead's latency is not
                // measured on it.
                let replacing = self.replacing.contains(&tile);
                if let Some(c) = self.controller.as_mut().filter(|_| !replacing) {
                    // Asked again every tick while it loads: the latency counts from the first.
                    // Only reads asked for while the level was whole measure the latency the
                    // read-ahead plans with: while it fills (a start, a jump, a source that
                    // cannot keep up) reads wait behind each other, which a lead cannot cure.
                    let whole = level.published == level.frame.valid;
                    if let std::collections::hash_map::Entry::Vacant(e) = c.asked.entry(tile) {
                        let stream = self.queues.stream_of(tile);
                        c.latency.note(k, stream);
                        c.asked_now[stream] += 1;
                        e.insert((self.tick, whole, stream));
                    }
                }
            }
        }
        self.queues.update(&wanted);
        if let Some(c) = &mut self.controller {
            // Tiles that left their mem region (their requests dropped) never come back, and a
            // failed read is asked for afresh after its retry delay: forget both.
            let cache = &self.cache;
            c.asked.retain(|&t, _| cache.state(t) == TileState::Loading);
        }
    }

    /// Each level's paging this tick and why, from the controller's choices and whether each
    /// level's valid region is whole (`complete`).
    fn paging_report(&self, complete: &[bool]) -> Vec<adaptive::LevelPaging> {
        // Reads waiting in each stream server's queue.
        let pending: Vec<bool> = self.queues.stream_stats().iter().map(|q| q.pending > 0).collect();
        self.levels
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let Some(c) = self.controller.as_ref().filter(|_| self.desc.mem_grid(k as u32).is_none()) else {
                    return adaptive::LevelPaging { grid: l.shape.grid, ..Default::default() };
                };
                let speed = c.motion.speed_at_level(k as u32).map(|x| x.ceil() as u64);
                let speed = if c.motion.at_level(k as u32) == [0, 0] { [0, 0] } else { speed };
                let mut reason = adaptive::reason(&l.shape, speed, c.needed[k], complete[k]);
                // Reads of this level's tiles wait in their stream servers' queues (any server's
                // before the level has asked for a tile).
                let mut streams = c.latency.streams_of(k).peekable();
                let backlog = if streams.peek().is_some() {
                    streams.any(|s| pending.get(s).copied().unwrap_or(false))
                } else {
                    pending.iter().any(|&p| p)
                };
                // A lead the grid cannot hold is the budget's doing only while the source keeps
                // up: reads waiting in the level's queues, or a queue delivering less than is
                // asked of it (a rate a lead cannot raise), make it the source's.
                let source_short = backlog || c.latency.level_short(k);
                if reason == adaptive::Reason::BudgetBound && source_short && !complete[k] {
                    reason = adaptive::Reason::SourceBound;
                }
                let need = tiles_covering(l.frame.tex, l.shape.tile);
                let (m, dir) = (l.frame.mem, c.motion.at_level(k as u32));
                let beyond = |a: usize| match dir[a].signum() {
                    1 => (if a == 0 { m.s1 - need.s1 } else { m.t1 - need.t1 }).max(0) as u64,
                    -1 => (if a == 0 { need.s0 - m.s0 } else { need.t0 - m.t0 }).max(0) as u64,
                    _ => 0,
                };
                if reason == adaptive::Reason::Fixed {
                    return adaptive::LevelPaging { grid: l.shape.grid, ..Default::default() };
                }
                adaptive::LevelPaging {
                    lead_tiles: [beyond(0), beyond(1)],
                    lead_texels: c.lead[k],
                    grid: l.shape.grid,
                    reason,
                    read_latency_ticks: c.latency.level(k),
                }
            })
            .collect()
    }

    fn update_min_lod(&mut self, complete: &[bool]) {
        let target = target_min_lod(complete);
        // Until some level is shown there is nothing to fade from: the first picture comes at once.
        let fade = if self.min_lod >= self.levels.len() as f64 { 0 } else { self.settings.fade_ticks };
        let next = next_min_lod(self.min_lod, target, fade);
        if next > self.min_lod {
            self.stats.min_lod_raises += 1;
        } else if next < self.min_lod {
            self.stats.min_lod_fades += 1;
        }
        self.min_lod = next;
    }
}

#[cfg(test)]
pub(crate) mod tests;
