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
//! policy) and the second-level tile pool [`crate::paging`]'s, slots are `crate::cache`'s and
//! [`crate::shm::memory`]'s, reads [`crate::queue`]'s.

mod frames;
pub(crate) mod load;
mod refresh;
pub(crate) mod stats;
pub(crate) mod views;

pub use crate::cache::TileState;
pub use load::{next_min_lod, target_min_lod};
pub use stats::{FaultCounts, Stats, TickReport};
pub use views::{demotion, offset_for_footprint, LodWindow, ViewError, ViewId, MAX_VIEWS, PRIMARY};

use crate::cache::{Admit, TileCache};
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
    /// (`views`): each level's grid gets `ceil((view_spread >> k) / tile)` more tiles per axis
    /// (0: grids for one view; the views share what it holds). `cliptex plan`'s memory formula
    /// counts them.
    pub view_spread: u64,
    /// The texture spans 360 degrees of longitude (its georeferencing says so,
    /// `Georef::is_global_in_longitude`): every level that [`crate::geom::level_wraps`] wraps
    /// along s, its windows crossing the antimeridian (tile S is tile S mod the tiles across, and
    /// its grid width divides the tiles across, [`crate::geom::wrap_grid`]). `false`: windows
    /// stop at the texture's edges.
    pub wrap_longitude: bool,
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
            wrap_longitude: false,
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
        block: desc.format().block_edge(),
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
    /// Bytes per texel; for a block-compressed format the bytes of one 4 x 4 block.
    pub bpt: usize,
    /// Published valid region: texels readers may read (where their tiles are readable).
    pub valid: Rect,
    /// The level's current centre.
    pub centre: [i64; 2],
    /// Whether the level wraps along s ([`crate::geom::level_wraps`]): its valid region's
    /// s-range may run past the width, and texel s is texel `s mod width`.
    pub wrap: bool,
    /// The block format of a block-compressed texture ([`LevelView::texel`] decodes).
    block: Option<crate::texel::Bc>,
    cache: &'a TileCache,
}

impl LevelView<'_> {
    /// The tile holding texel (s, t).
    pub fn tile_of(&self, s: i64, t: i64) -> TileId {
        let s = self.real_s(s);
        TileId::new(self.level, s.div_euclid(self.tile[0] as i64) as u64, t.div_euclid(self.tile[1] as i64) as u64)
    }

    /// Column s of the level itself: `s mod width` when the level wraps, else `s`.
    fn real_s(&self, s: i64) -> i64 {
        if self.wrap {
            crate::geom::wrap(s, self.size[0]) as i64
        } else {
            s
        }
    }

    /// The state of the tile holding texel (s, t).
    pub fn tile_state(&self, s: i64, t: i64) -> TileState {
        self.cache.state(self.tile_of(s, t))
    }

    /// The texel at (s, t) if it lies in the published valid region and its tile is readable (a
    /// missing tile's texels come from a coarser level). For a block-compressed texture, the
    /// texel decoded from its 4 x 4 block (RGBA8 for `bc1` and `bc7`, one byte for `bc4`, two
    /// for `bc5`; `crate::shm::blocks`).
    pub fn texel(&self, s: i64, t: i64) -> Option<Texel> {
        if !crate::geom::contains_wrapped(&self.valid, s, t, self.wrap.then_some(self.size[0])) {
            return None;
        }
        let s = self.real_s(s);
        let tile = self.tile_of(s, t);
        let (tw, th) = (self.tile[0] as i64, self.tile[1] as i64);
        if let Some(bc) = self.block {
            return self.block_texel(bc, tile, s - tile.s as i64 * tw, t - tile.t as i64 * th);
        }
        let i = ((t - tile.t as i64 * th) * tw + (s - tile.s as i64 * tw)) as usize * self.bpt;
        let mut texel = Texel { bytes: [0; 16], len: self.bpt.min(16) as u8 };
        self.cache.read(tile, i, &mut texel.bytes[..texel.len as usize]).then_some(texel)
    }
}

impl LevelView<'_> {
    /// Texel (x, y) of `tile` of a block-compressed level, decoded from the block holding it.
    fn block_texel(&self, bc: crate::texel::Bc, tile: TileId, x: i64, y: i64) -> Option<Texel> {
        let across = self.tile[0].div_ceil(4) as i64;
        let mut block = [0u8; 16];
        let block = &mut block[..self.bpt.min(16)];
        if !self.cache.read(tile, ((y / 4) * across + x / 4) as usize * self.bpt, block) {
            return None;
        }
        let texels = crate::shm::blocks::decode(bc, block, 4, 4).ok()?;
        let n = crate::shm::blocks::decoded_bytes(bc);
        let at = ((y % 4) * 4 + x % 4) as usize * n;
        let mut texel = Texel { bytes: [0; 16], len: n as u8 };
        texel.bytes[..n].copy_from_slice(&texels[at..at + n]);
        Some(texel)
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
            return Self::wrap_grids(desc, settings, views::spread_grids(desc, fixed, settings.view_spread));
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
        Self::wrap_grids(desc, settings, views::spread_grids(desc, out, settings.view_spread))
    }

    /// Whether level `k` of `desc` wraps along s under `settings` ([`crate::geom::level_wraps`]).
    pub fn level_wraps(desc: &TextureDesc, settings: &Settings, k: u32) -> bool {
        let l = desc.level(k);
        crate::geom::level_wraps(settings.wrap_longitude, l.size, l.tile, desc.clip_size())
    }

    /// `grids` with the width of every wrapping level's raised to a divisor of its tiles across.
    fn wrap_grids(desc: &TextureDesc, settings: &Settings, mut grids: Vec<[u64; 2]>) -> Vec<[u64; 2]> {
        for (k, g) in grids.iter_mut().enumerate() {
            if Self::level_wraps(desc, settings, k as u32) {
                let l = desc.level(k as u32);
                g[0] = crate::geom::wrap_grid(crate::geom::tiles_in_level(l.size, l.tile)[0], g[0]);
            }
        }
        grids
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
            .enumerate()
            .map(|(k, (l, &grid))| Level {
                shape: LevelShape {
                    size: l.size,
                    tile: l.tile,
                    clip,
                    grid,
                    wrap: Self::level_wraps(&desc, &settings, k as u32),
                },
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
        let mut cache = TileCache::new(&grids, Arc::clone(&memory), keeper);
        for (k, l) in levels.iter().enumerate() {
            cache.set_tile_period(k as u32, l.shape.tile_period());
        }
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
    pub fn stream_stats(&self) -> Vec<crate::queue::QueueStats> {
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
    pub fn set_invalid_border(&mut self, border: u64) {
        self.border = border.min((self.desc.clip_size() - 1) / 2);
    }

    /// Sets the bound on a tick's own work (ns; `None`: unbounded).
    pub fn set_budget_ns(&mut self, budget: Option<u64>) {
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
            wrap: l.shape.wrap,
            block: self.desc.format().block(),
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
}

#[cfg(test)]
pub(crate) mod tests;
