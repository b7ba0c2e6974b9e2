//! The clipmap: per-level toroidal windows kept filled around a moving centre.
//!
//! Owns the update tick. Each tick it takes finished reads into the tile cache, moves every
//! level's mem region and asks the read queues for the tiles now wanted, then brings windows up to
//! date coarse levels first within a copy budget (estimated from a [`CostTable`]), and finally
//! moves min LOD past any level it could not bring up to date (load control, docs/ARCHITECTURE.md §6).
//!
//! The invariant it keeps: **every texel inside a published valid region equals the source
//! texel**. Each tick first shrinks every published region to texels that stay correct and will
//! not be overwritten, publishes, writes new texels only outside the published regions (into the
//! invalid border or the part of a level not yet published), and only then publishes the grown
//! regions. The [`Publisher`] hook sees both publications; the shared-memory layer plugs in
//! there. Geometry is [`crate::geom`]'s, tiles are [`crate::cache`]'s and reads
//! [`crate::queue`]'s.

pub mod load;
pub mod stats;
mod window;

pub use load::{next_min_lod, target_min_lod, CostTable};
pub use stats::{FaultCounts, Stats, TickReport};

use crate::cache::{Admit, TileCache};
use crate::geom::{aligned_centre, level_grid, tile_texels, LevelFrame, LevelShape, Rect};
use crate::limits::Limits;
use crate::queue::{priority, QueueError, ReadQueues, ReadRequest};
use crate::source::{TextureDesc, TileSource};
use std::sync::Arc;
use thiserror::Error;
use window::Window;
pub use window::{Store, WindowStore};

/// Run-time settings of a clipmap.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Extra tile rows and columns kept beyond those the window touches (Performer default 1).
    pub lookahead: u64,
    /// Number of stream servers (read queues); the source picks each tile's queue
    /// ([`TileSource::stream_of`], by default tile column S mod n). Use the source's
    /// [`TileSource::stream_servers`] to give each configured server its own queue.
    pub streams: usize,
    /// Copy budget per tick in nanoseconds of estimated cost; `None` copies everything.
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
    /// Copy costs; `None` measures this machine at start-up.
    pub cost: Option<CostTable>,
    /// Bounds on queues and memory.
    pub limits: Limits,
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
            cost: None,
            limits: Limits::default(),
        }
    }
}

pub use crate::limits::MAX_CENTRE_ALIGNMENT;

/// Why a clipmap could not be built.
#[derive(Debug, Error)]
pub enum ClipError {
    /// The read queues could not start.
    #[error(transparent)]
    Queue(#[from] QueueError),
    /// The windows would take more memory than allowed.
    #[error("clip windows need {needed} bytes: the limit is {limit} bytes (Limits::window_bytes); choose a smaller clip size")]
    WindowBytes { needed: usize, limit: usize },
    /// Caller-supplied window memory does not match the texture.
    #[error("window memory for level {level}: found {found} bytes, expected {expected} (the window of a {dims:?}-texel buffer); supply one store per level, sized by Clipmap::window_bytes")]
    WindowStore { level: usize, found: usize, expected: usize, dims: [u64; 2] },
    /// Caller-supplied window memory has the wrong number of levels.
    #[error("window memory for {found} levels supplied: the texture has {expected} levels")]
    WindowStores { found: usize, expected: usize },
}

/// When the [`Publisher`] is called within a tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Valid regions shrunk to what stays correct; no texel written yet this tick.
    BeforeWrites,
    /// Texels written; valid regions grown to what is now correct.
    AfterWrites,
}

/// Receives each publication of the levels' state (for the shared-memory layer, or tests).
pub trait Publisher {
    /// Called twice per tick; read the state through `clipmap`'s accessors.
    fn publish(&mut self, phase: Phase, clipmap: &Clipmap);
}

impl<F: FnMut(Phase, &Clipmap)> Publisher for F {
    fn publish(&mut self, phase: Phase, clipmap: &Clipmap) {
        self(phase, clipmap)
    }
}

/// A read-only view of one level, as published.
#[derive(Clone, Copy, Debug)]
pub struct LevelView<'a> {
    /// Level index.
    pub level: u32,
    /// Level size in texels.
    pub size: [u64; 2],
    /// Clip size (the toroidal period).
    pub clip: u64,
    /// Buffer size in texels per axis.
    pub dims: [u64; 2],
    /// Bytes per texel.
    pub bpt: usize,
    /// Published valid region: texels readers may read.
    pub valid: Rect,
    /// The toroidal buffer: texel (s, t) at byte `((t mod clip) * dims[0] + s mod clip) * bpt`.
    pub texels: &'a Store,
    /// The level's current centre.
    pub centre: [i64; 2],
}

impl LevelView<'_> {
    /// The texel at (s, t) if it lies in the published valid region.
    pub fn texel(&self, s: i64, t: i64) -> Option<Texel> {
        if !self.valid.contains(s, t) {
            return None;
        }
        let i = crate::geom::window_index(s, t, self.clip, self.dims) * self.bpt;
        let mut texel = Texel { bytes: [0; 16], len: self.bpt.min(16) as u8 };
        self.texels.read(i, &mut texel.bytes[..texel.len as usize]);
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
    window: Window,
    centre_override: Option<[i64; 2]>,
    frame: LevelFrame,
}

/// A clip texture being kept up to date around a centre.
pub struct Clipmap {
    desc: TextureDesc,
    settings: Settings,
    cost: CostTable,
    cache: TileCache,
    queues: ReadQueues,
    levels: Vec<Level>,
    centre: Option<[i64; 2]>,
    border: u64,
    min_lod: f64,
    tick: u64,
    stats: Stats,
}

impl Clipmap {
    /// A clipmap of `source`'s texture with nothing resident yet (min LOD above every level).
    pub fn new(source: Arc<dyn TileSource>, settings: Settings) -> Result<Self, ClipError> {
        Self::build(source, settings, None)
    }

    /// Bytes of each level's window for `desc` (what [`with_windows`](Self::with_windows) wants).
    pub fn window_bytes(desc: &TextureDesc) -> Vec<usize> {
        let clip = desc.clip_size();
        desc.levels()
            .iter()
            .map(|l| {
                let d = Window::dims(l.size, clip);
                (d[0] * d[1]) as usize * desc.bytes_per_texel()
            })
            .collect()
    }

    /// [`new`](Self::new), keeping each level's window in caller-supplied memory (one store per
    /// level, of [`window_bytes`](Self::window_bytes) bytes), such as a shared mapping: texels
    /// are then written once, where readers read them.
    pub fn with_windows(
        source: Arc<dyn TileSource>,
        settings: Settings,
        stores: Vec<Box<dyn WindowStore>>,
    ) -> Result<Self, ClipError> {
        Self::build(source, settings, Some(stores))
    }

    fn build(
        source: Arc<dyn TileSource>,
        settings: Settings,
        stores: Option<Vec<Box<dyn WindowStore>>>,
    ) -> Result<Self, ClipError> {
        let desc = source.desc().clone();
        let mut stores: Vec<Option<Box<dyn WindowStore>>> = match stores {
            None => desc.levels().iter().map(|_| None).collect(),
            Some(v) => {
                if v.len() != desc.level_count() {
                    return Err(ClipError::WindowStores { found: v.len(), expected: desc.level_count() });
                }
                let want = Self::window_bytes(&desc);
                for (k, (st, &expected)) in v.iter().zip(&want).enumerate() {
                    if st.len() != expected {
                        let dims = Window::dims(desc.levels()[k].size, desc.clip_size());
                        return Err(ClipError::WindowStore { level: k, found: st.len(), expected, dims });
                    }
                }
                v.into_iter().map(Some).collect()
            }
        };
        let bpt = desc.bytes_per_texel();
        let clip = desc.clip_size();
        let needed: usize =
            desc.levels().iter().map(|l| (clip.min(l.size[0]) * clip.min(l.size[1])) as usize * bpt).sum();
        if needed > settings.limits.window_bytes {
            return Err(ClipError::WindowBytes { needed, limit: settings.limits.window_bytes });
        }
        let levels: Vec<Level> = desc
            .levels()
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let grid = level_grid(l.size, l.tile, clip, settings.lookahead, desc.mem_grid(k as u32));
                let shape = LevelShape { size: l.size, tile: l.tile, clip, grid };
                Level {
                    shape,
                    window: Window::new(k as u32, l.size, clip, l.tile, bpt, stores[k].take()),
                    centre_override: None,
                    frame: LevelFrame { centre: [0, 0], tex: Rect::EMPTY, valid: Rect::EMPTY, mem: Rect::EMPTY },
                }
            })
            .collect();
        let grids: Vec<[u64; 2]> = levels.iter().map(|l| l.shape.grid).collect();
        let cache = TileCache::new(&desc, &grids, settings.limits.cache_bytes);
        let queues = ReadQueues::new(source, settings.streams, settings.limits)?;
        let cost = settings.cost.unwrap_or_else(|| CostTable::measure(bpt));
        Ok(Clipmap {
            border: desc.invalid_border(),
            min_lod: desc.level_count() as f64,
            desc,
            settings,
            cost,
            cache,
            queues,
            levels,
            centre: None,
            tick: 0,
            stats: Stats::default(),
        })
    }

    /// The texture.
    pub fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    /// The copy-cost table in use.
    pub fn cost(&self) -> &CostTable {
        &self.cost
    }

    /// Counters so far.
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// How the reads' tile buffers were served: handed back by evictions, or freshly allocated.
    pub fn read_buffers(&self) -> crate::queue::PoolCounts {
        self.queues.buffer_counts()
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

    /// Sets the copy budget per tick (estimated ns; `None`: unlimited).
    pub fn set_budget_ns(&mut self, budget: Option<u64>) {
        self.settings.budget_ns = budget;
    }

    /// Gives level `k` its own centre (level texels), or `None` to follow level 0's.
    pub fn set_level_centre(&mut self, k: u32, centre: Option<[i64; 2]>) {
        self.levels[k as usize].centre_override = centre;
    }

    /// Level `k` as published.
    pub fn level(&self, k: u32) -> LevelView<'_> {
        let l = &self.levels[k as usize];
        LevelView {
            level: k,
            size: l.shape.size,
            clip: l.shape.clip,
            dims: l.window.dims,
            bpt: l.window.bpt,
            valid: l.window.published,
            texels: &l.window.buf,
            centre: l.frame.centre,
        }
    }

    /// Number of levels.
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// Bytes held in tiles and windows now.
    pub fn resident_bytes(&self) -> u64 {
        (self.cache.resident_bytes() + self.levels.iter().map(|l| l.window.bytes()).sum::<usize>()) as u64
    }

    /// Blocks until every read that can start has finished (tests and offline simulation; not
    /// from async code). The next tick takes the results.
    pub fn wait_for_reads(&mut self) {
        self.queues.flush();
    }

    /// One update tick towards `centre` (level-0 texels), moving at `velocity` level-0 texels per
    /// tick if given (else the change since the last tick).
    pub fn tick(&mut self, centre: [i64; 2], velocity: Option<[i64; 2]>) -> TickReport {
        self.tick_with(centre, velocity, &mut |_: Phase, _: &Clipmap| {})
    }

    /// [`tick`](Self::tick), calling `publisher` at both publications.
    pub fn tick_with(
        &mut self,
        centre: [i64; 2],
        velocity: Option<[i64; 2]>,
        publisher: &mut dyn Publisher,
    ) -> TickReport {
        self.tick += 1;
        self.stats.ticks += 1;
        // Whatever a renderer asked for (any i64 through the mapping or the socket): bounded
        // before any arithmetic, so that no difference or product of them can overflow.
        let far = crate::limits::MAX_CENTRE;
        let centre = self.clamp_centre(centre.map(|c| c.clamp(-far, far)));
        let velocity = velocity.map(|v| v.map(|x| x.clamp(-far, far)));
        let velocity = velocity.unwrap_or_else(|| self.centre.map_or([0, 0], |c| [centre[0] - c[0], centre[1] - c[1]]));
        self.centre = Some(centre);
        let mut report = TickReport { centre, ..TickReport::default() };

        report.tiles_read = self.take_reads();
        self.move_regions(centre, velocity);

        for level in &mut self.levels {
            let w = &mut level.window;
            w.content = w.content.intersect(&level.frame.tex);
            w.published = w.published.intersect(&w.content).intersect(&level.frame.valid);
        }
        self.stats.publications += 1;
        publisher.publish(Phase::BeforeWrites, self);

        let (spent, over) = self.copy_within_budget(&mut report);
        report.over_budget = over;
        report.estimated_copy_ns = spent;
        self.stats.estimated_copy_ns += spent;
        if over {
            self.stats.ticks_over_budget += 1;
        }

        let complete: Vec<bool> = self.levels.iter().map(|l| l.window.content.contains_rect(&l.frame.valid)).collect();
        for level in &mut self.levels {
            level.window.published = level.frame.valid.intersect(&level.window.content);
        }
        self.update_min_lod(&complete);
        self.stats.publications += 1;
        publisher.publish(Phase::AfterWrites, self);

        report.min_lod = self.min_lod;
        report.disabled_levels = (0..self.levels.len() as u32).filter(|&k| ((k + 1) as f64) <= self.min_lod).collect();
        if !report.disabled_levels.is_empty() {
            self.stats.ticks_with_disabled_level += 1;
        }
        report.valid = self.levels.iter().map(|l| l.window.published).collect();
        self.stats.queue = self.queues.stats();
        self.stats.peak_resident_bytes = self.stats.peak_resident_bytes.max(self.resident_bytes());
        report
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

    /// Takes finished reads into the cache; returns the number admitted.
    fn take_reads(&mut self) -> u64 {
        let mut admitted = 0;
        for done in self.queues.drain() {
            match done.result {
                Ok(texels) => match self.cache.admit(done.tile, texels) {
                    Admit::Admitted => admitted += 1,
                    Admit::Stale => self.stats.late_tiles += 1,
                    Admit::OverBudget => self.stats.tiles_over_cache_budget += 1,
                    Admit::WrongSize => self.stats.read_faults.add(crate::source::FaultKind::Corrupt),
                },
                Err(e) => {
                    tracing::debug!("tile read failed: {e}");
                    self.stats.read_faults.add(e.kind());
                    self.cache.mark_failed(done.tile, e.kind(), self.tick + self.settings.retry_after_ticks);
                }
            }
        }
        self.stats.tiles_read += admitted;
        admitted
    }

    /// Moves every level's regions to the new centre and asks for the tiles now wanted.
    fn move_regions(&mut self, centre: [i64; 2], velocity: [i64; 2]) {
        let count = self.levels.len();
        let mut wanted = Vec::new();
        for (k, level) in self.levels.iter_mut().enumerate() {
            let k32 = k as u32;
            let c =
                level.centre_override.unwrap_or_else(|| aligned_centre(centre, k32, self.settings.centre_alignment));
            let v = velocity.map(|x| if x != 0 && (x >> k32.min(63)) == 0 { x.signum() } else { x >> k32.min(63) });
            level.frame = level.shape.frame(c, self.border, v);
            let queues = &self.queues;
            self.stats.tiles_evicted +=
                self.cache.set_mem_region_recycling(k32, level.frame.mem, |buf| queues.recycle(buf));
            for tile in self.cache.wanted(k32, self.tick) {
                let texels = tile_texels(level.shape.size, level.shape.tile, [tile.s, tile.t]);
                let p = priority(k32, count, texels, level.frame.valid, level.shape.clip, v);
                wanted.push(ReadRequest { tile, priority: p });
                self.cache.mark_loading(tile);
            }
        }
        self.queues.update(&wanted);
    }

    /// Copies bands coarse levels first: first what makes each valid region complete, then the
    /// invalid borders, until the budget is spent. Returns (estimated ns, budget ran out).
    fn copy_within_budget(&mut self, report: &mut TickReport) -> (f64, bool) {
        let budget = self.settings.budget_ns.map_or(f64::INFINITY, |b| b as f64);
        let mut spent = 0.0;
        let mut over = false;
        for pass in 0..2 {
            for level in self.levels.iter_mut().rev() {
                let goal = if pass == 0 { level.frame.valid } else { level.frame.tex };
                let w = &mut level.window;
                while let Some(band) = w.next_band(&goal) {
                    let line_bytes = band.line_texels() * w.bpt as u64;
                    let affordable = self.cost.lines_within(budget - spent, line_bytes);
                    let ready = w.resident_depth(&band, band.depth.min(affordable), &self.cache);
                    if ready == 0 {
                        if affordable == 0 {
                            over = true;
                            self.stats.levels_out_of_budget += 1;
                        } else {
                            self.stats.levels_waiting_for_tiles += 1;
                        }
                        break;
                    }
                    let rect = band.rect(ready);
                    if !rect.intersect(&w.published).is_empty() {
                        self.stats.writes_into_published += 1;
                    }
                    let Some(bytes) = w.copy_rect(rect, &self.cache) else { break };
                    w.grow(&band, ready);
                    spent += self.cost.band_ns(ready, line_bytes);
                    report.bytes_copied += bytes;
                    self.stats.bytes_copied += bytes;
                    self.stats.bands_copied += 1;
                }
                if over {
                    break;
                }
            }
            if over {
                break;
            }
        }
        (spent, over)
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
