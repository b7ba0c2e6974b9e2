//! `clipbench views`: several views of one clipmap (src/clip/views.rs) against one view alone
//! and against separate clipmaps, one per view (docs/BENCHMARKS.md, ## Views).
//!
//! Three scenarios, each flown by every design the engine allows, and, in the same run, by each
//! of its views alone (`one_view`: view 0 alone, one clipmap with the default grids):
//! - `near`: 4 views within one clip size of each other (view 0 and three others offset by up to
//!   half a clip size along each axis) flying the same path together. Designs: one clipmap with
//!   the default grids (`views_spread_0`: views the grids cannot hold with the primary's window
//!   show coarser levels), one whose grids hold every view (`views_spread_clip`: `view_spread` =
//!   the clip size), and separate clipmaps over one source without and with a shared
//!   second-level pool (`separate_grids`, `separate_grids_shared_pool`); then the first two again
//!   under Performer's fixed ring of lookahead-1 grids (`prefetch` `ring`: `views_spread_0_ring`,
//!   `views_spread_clip_ring`, against `one_view_ring`), whose grids hold less beside the
//!   primary's window than the engine's default (adaptive) grids.
//! - `far`: 4 views far apart (a quarter of the texture and more) flying the same path shape.
//!   Designs: one clipmap with the default grids (`views_spread_0`; the spread that would hold
//!   them, and its mapping's bytes, are computed, not flown), and separate clipmaps without and
//!   with a shared pool.
//! - `weighted`: 2 views two clip sizes apart across the direction of flight (their finest two
//!   levels share no tile) in one clipmap whose grids hold both (`view_spread` = that distance),
//!   over a disk that serves one view's need but not both's; weights 3:1 (`weights_3_1`, view 0
//!   the heavy one) and 1:1 (`weights_1_1`), and view 0 alone with the same wide grids
//!   (`one_view_same_grids`). `weighted_tight` flies the same over a disk of one tile a tick
//!   less, about one view's need (a sensitivity run; the goal is checked on `weighted`).
//!
//! Every run has two phases. **Start**: every view placed at its start, standing still, ticking
//! until nothing more arrives (three ticks in a row without a read reaching the disk or the pool
//! and without a min LOD changing) or a cap. **Flight**: `flight_ticks` ticks along a straight
//! path at 30° from +s at an eighth of a tile a tick (`near` and `far`: every view jumps 24 tiles
//! along +s at a third and at two thirds of the flight; `weighted` has no jumps).
//!
//! **Settle ticks.** A start (the start phase's first tick) and each jump (the first flight tick
//! at the new place) are events. A view's settle time after an event is the number of ticks from
//! that event's tick, counted as 1, up to and including the first tick at whose end the view's
//! min LOD is 0 (it shows level 0 everywhere in its window); the view has not settled if that
//! does not happen before the next event (or the end of the run). `view_settle_ticks` is each
//! view's mean over the events, `settle_ticks` the mean over the events of the slowest view's
//! (ticks until *every* view shows level 0); both are null when a view did not settle after some
//! event (`views_never_settled` counts those views). `settle_vs_alone` is the largest, over the
//! views, of a view's `view_settle_ticks` over the same view's flown alone.
//!
//! Disks: simulated ([`ThrottledSource`]) and in lock step: each tick lets `disk_tiles_per_tick`
//! reads reach the texture, one read runs at a time, and every clipmap's tick is followed by
//! waiting for the reads it can start before the next clipmap ticks (separate clipmaps tick in
//! view order, view 0 first): the figures are the same on every machine and in every run.
//! `near`: 16 tiles a tick (4 a view), alone and together alike. `far`: a view alone gets its
//! share, 4 tiles a tick, and the four together a disk that serves all of them, 16 tiles a tick
//! (separate clipmaps share it, ticking in view order). `weighted`: view 0's mean reads per flight tick
//! (alone, default grids) and both views' (the 3:1 clipmap) are measured over an unthrottled
//! disk first; the disk then serves `ceil(1.25 x` one view's need`)` tiles a tick, for the views
//! together and alone alike (`weighted_disk` says whether that is below both views' need).
//!
//! Counted: `tiles_read`, reads that reached the texture (pool hits do not), over both phases;
//! `window_tiles`, the distinct tiles (every level) some view's window touched at some tick, the
//! least any design must read;
//! `peak_resident_bytes`, the largest sum over a tick of every clipmap's image-cache mapping plus
//! the pool's tiles; mean min LODs over the flight ticks. Ratios are against `one_view` of the
//! same scenario and run (`weighted`: view 0 alone over the same slow disk).
//!
//! Exit status: 0 ok (goals met or not: the figures are the output), 2 the benchmark could not
//! run.

mod report;

pub use report::*;

use anyhow::Context;
use clipmap::clip::{Clipmap, Settings, ViewId, PRIMARY};
use clipmap::geom::{aligned_centre, tex_region, tiles_covering};
use clipmap::paging::{EvictionKind, PrefetchKind};
use clipmap::shm::{Client, FromMapping, Writer, WriterOptions};
use clipmap::source::{HashSource, PoolSource, TextureDesc, ThrottledSource, TileSource};
use clipmap::texel::TexelFormat;
use clipmap::tile::TileId;
use serde::Serialize;
use std::collections::HashSet;
use std::sync::Arc;

/// Options of `clipbench views`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A smaller texture and a shorter flight (a few seconds in a release build).
    #[arg(long)]
    quick: bool,
    /// Tiny sizes: checks that every run works (for tests); the figures mean little.
    #[arg(long, hide = true, conflicts_with = "quick")]
    smoke: bool,
    /// Print one JSON object (`setup`, `scenarios`, `goals`, `weighted_disk`) instead of tables.
    #[arg(long)]
    json: bool,
}

/// Tiles a tick the disk gives each view (`near`, `far`; a policies-benchmark disk).
const DISK_PER_VIEW: u64 = 4;
/// A disk that is never the limit (the `weighted` need is measured over it).
const UNTHROTTLED: u64 = 1 << 40;
/// Most ticks of a start phase.
const START_CAP: u64 = 5000;

/// What every run flies over.
#[derive(Clone, Debug, Serialize)]
pub struct Setup {
    /// `full`, `quick` or `smoke`.
    pub size_name: &'static str,
    /// Texels a side (RGBA8 hash texture).
    pub size: u64,
    pub clip: u64,
    pub tile: u64,
    pub levels: usize,
    /// Bytes of one tile.
    pub tile_bytes: u64,
    /// Ticks of each flight (after the start phase).
    pub flight_ticks: u64,
    /// Level-0 texels a tick, at `angle_deg` from +s.
    pub speed: f64,
    pub angle_deg: f64,
    /// Flight ticks at which `near` and `far` jump, and by how many level-0 texels along +s.
    pub jump_ticks: Vec<u64>,
    pub jump_texels: u64,
    /// Tiles a tick a view alone reads in `near` and `far` (several views: this many per view).
    pub disk_tiles_per_tick_per_view: u64,
    /// The engine's default prefetch policy, used by every run.
    pub prefetch: &'static str,
    /// Ticks over which min LOD fades down a level (the engine's default).
    pub fade_ticks: u32,
    /// The image caches' mapping of one clipmap with the default grids.
    pub one_view_mapping_bytes: u64,
    /// The shared pool's budget (1.5 times one view's mapping, whole tiles).
    pub pool_bytes: u64,
}

/// A straight flight at 30° with jumps along +s, shared by every view of a scenario.
#[derive(Clone, Debug)]
struct Flight {
    speed: f64,
    angle_deg: f64,
    ticks: u64,
    jump_at: Vec<u64>,
    jump: f64,
    size: u64,
}

impl Flight {
    /// Where a view starting at `start` is at flight tick `tick` (0: the start phase).
    fn at(&self, start: [f64; 2], tick: u64) -> [i64; 2] {
        let a = self.angle_deg.to_radians();
        let jumps = self.jump_at.iter().filter(|&&j| j <= tick).count() as f64;
        let x = tick as f64;
        let p = [start[0] + x * self.speed * a.cos() + jumps * self.jump, start[1] + x * self.speed * a.sin()];
        p.map(|c| (c.floor() as i64).clamp(0, self.size as i64 - 1))
    }
}

/// How the views are held.
#[derive(Clone, Copy, Debug)]
enum Design {
    /// One clipmap, the views sharing its grids, widened by `spread`, placed by `prefetch`.
    One { spread: u64, prefetch: PrefetchKind },
    /// One clipmap per view over one disk, optionally through one shared pool.
    Separate { pool: bool },
    /// The service's views with grids of their own (`--view NAME:W:own`, docs/VIEWS.md, "Views
    /// far apart"): one clipmap per view, each with its own read queues, so that the disk serves
    /// them side by side: each gets an equal share of the disk's reads a tick. View 0's clipmap
    /// is mapped as the service maps it, and the others take the tiles its slots hold from there
    /// (`FromMapping`) instead of reading them again.
    Own,
}

/// What one run measured.
struct Run {
    tiles_read: u64,
    window_tiles: u64,
    level0_grid: [u64; 2],
    flight_tiles_read: u64,
    peak_resident_bytes: u64,
    mapping_bytes: u64,
    view_mean_min_lod: Vec<f64>,
    settle: Vec<Vec<Option<u64>>>,
    start_ticks: u64,
    pool_hits: u64,
    reads_put_off: u64,
    under_views: u64,
    under_published: u64,
}

fn desc(size: u64, clip: u64, tile: u64) -> TextureDesc {
    TextureDesc::new([size, size], clip, TexelFormat::RGBA8, [tile, tile]).expect("a valid benchmark texture")
}

/// The engine's defaults, lock step: one read at a time, no tick budget.
fn settings(spread: u64, prefetch: PrefetchKind) -> Settings {
    let mut s = Settings { budget_ns: None, view_spread: spread, prefetch, ..Settings::default() };
    s.limits.max_in_flight_reads = 1;
    s.limits.max_ready_reads = 1 << 16;
    s.limits.max_pending_reads = 1 << 16;
    s
}

fn mapping_bytes(desc: &TextureDesc, spread: u64) -> u64 {
    clipmap::shm::layout::place(&Clipmap::shape_for(desc, &settings(spread, PrefetchKind::default())))
        .map_or(0, |p| p.total_bytes)
}

/// View 0's clipmap's mapping in a directory of its own (`own_grids`), removed when dropped.
struct Mapped {
    dir: std::path::PathBuf,
    writer: Option<Writer>,
}

impl Mapped {
    fn new(d: &TextureDesc, s: &Settings) -> anyhow::Result<Mapped> {
        use std::sync::atomic::{AtomicU64, Ordering};
        static RUN: AtomicU64 = AtomicU64::new(0);
        let n = RUN.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("clipbench-views-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&dir).with_context(|| format!("{}", dir.display()))?;
        let shape = Clipmap::shape_for(d, s);
        let writer = Writer::create(WriterOptions::new(&dir, "view0", shape, d.format()).tick_period_ns(1_000_000))
            .with_context(|| format!("view 0's mapping in {}", dir.display()));
        match writer {
            Ok(w) => Ok(Mapped { dir, writer: Some(w) }),
            Err(e) => {
                let _ = std::fs::remove_dir_all(&dir);
                Err(e)
            }
        }
    }
}

impl std::ops::Deref for Mapped {
    type Target = Writer;
    fn deref(&self) -> &Writer {
        self.writer.as_ref().expect("closed only when dropped")
    }
}

impl Drop for Mapped {
    fn drop(&mut self) {
        if let Some(w) = self.writer.take() {
            w.close();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// The clipmaps of one run and where each view lives in them.
struct Sim {
    disk: Arc<ThrottledSource>,
    /// [`Design::Own`]: each clipmap's share of the disk (the disk itself then serves none),
    /// view 0's mapping and the sources that read from it.
    lanes: Vec<Arc<ThrottledSource>>,
    _mapped: Option<Mapped>,
    shared: Vec<Arc<FromMapping>>,
    pool: Option<Arc<PoolSource>>,
    maps: Vec<Clipmap>,
    /// (clipmap, view id) of each view.
    ids: Vec<(usize, ViewId)>,
}

impl Sim {
    fn new(d: &TextureDesc, design: Design, weights: &[f64], rate: u64, pool_bytes: u64) -> anyhow::Result<Sim> {
        let disk = Arc::new(ThrottledSource::new(Arc::new(HashSource::new(d.clone())), rate));
        let mut maps = Vec::new();
        let mut ids = Vec::new();
        let mut pool = None;
        let mut lanes = Vec::new();
        let (mut mapped, mut shared) = (None, Vec::new());
        match design {
            Design::One { spread, prefetch } => {
                let mut map = Clipmap::new(disk.clone(), settings(spread, prefetch)).context("the clipmap")?;
                map.set_view_weight(PRIMARY, weights[0])?;
                ids.push((0, PRIMARY));
                for &w in &weights[1..] {
                    ids.push((0, map.add_view(w)?));
                }
                maps.push(map);
            }
            Design::Separate { pool: with_pool } => {
                let source: Arc<dyn TileSource> = if with_pool {
                    let p = Arc::new(PoolSource::new(disk.clone(), pool_bytes, EvictionKind::Lru));
                    pool = Some(p.clone());
                    p
                } else {
                    disk.clone()
                };
                for i in 0..weights.len() {
                    maps.push(Clipmap::new(source.clone(), settings(0, PrefetchKind::default())).context("a clipmap")?);
                    ids.push((i, PRIMARY));
                }
            }
            Design::Own => {
                let share = (rate / weights.len() as u64).max(1);
                let s = settings(0, PrefetchKind::default());
                let m = Mapped::new(d, &s)?;
                for i in 0..weights.len() {
                    let lane = Arc::new(ThrottledSource::new(Arc::new(HashSource::new(d.clone())), share));
                    let map = if i == 0 {
                        Clipmap::with_memory(lane.clone(), s.clone(), m.memory())
                    } else {
                        let main = Client::attach_path(m.path()).context("view 0's mapping")?;
                        let from = Arc::new(FromMapping::new(lane.clone(), main));
                        shared.push(from.clone());
                        Clipmap::new(from, s.clone())
                    };
                    maps.push(map.context("a clipmap")?);
                    ids.push((i, PRIMARY));
                    lanes.push(lane);
                }
                mapped = Some(m);
            }
        }
        Ok(Sim { disk, lanes, _mapped: mapped, shared, pool, maps, ids })
    }

    /// One tick of every clipmap, in order, each followed by the reads it can start.
    fn step(&mut self, at: &[[i64; 2]]) {
        self.disk.next_tick();
        for lane in &self.lanes {
            lane.next_tick();
        }
        for (m, map) in self.maps.iter_mut().enumerate() {
            let mut primary = None;
            for (v, &(mm, id)) in self.ids.iter().enumerate() {
                if mm != m {
                    continue;
                }
                if id == PRIMARY {
                    primary = Some(at[v]);
                } else {
                    map.move_view(id, at[v], None).expect("a live view");
                }
            }
            map.tick(primary.expect("every clipmap has its primary view"), None);
            map.wait_for_reads();
        }
    }

    fn min_lod(&self, v: usize) -> f64 {
        let (m, id) = self.ids[v];
        self.maps[m].view_min_lod(id).expect("a live view")
    }

    /// Reads served without the disk: the shared pool's hits, or (`own_grids`) the tiles taken
    /// from view 0's mapping.
    fn pool_hits(&self) -> u64 {
        self.pool.as_ref().map_or(0, |p| p.stats().hits) + self.shared.iter().map(|f| f.hits()).sum::<u64>()
    }

    /// Reads delivered so far (the disk's and the pool's).
    fn deliveries(&self) -> u64 {
        self.disk_reads() + self.pool_hits()
    }

    /// Reads that reached the disk (its lanes' included).
    fn disk_reads(&self) -> u64 {
        self.disk.reads() + self.lanes.iter().map(|l| l.reads()).sum::<u64>()
    }

    fn resident(&self) -> u64 {
        self.maps.iter().map(|m| m.resident_bytes()).sum::<u64>() + self.pool.as_ref().map_or(0, |p| p.stats().bytes)
    }
}

/// Flies `starts` (one per view) along `flight` under `design`.
fn run(
    d: &TextureDesc,
    design: Design,
    starts: &[[f64; 2]],
    weights: &[f64],
    flight: &Flight,
    rate: u64,
    pool_bytes: u64,
) -> anyhow::Result<Run> {
    let n = starts.len();
    let mut sim = Sim::new(d, design, weights, rate, pool_bytes)?;
    let events = 1 + flight.jump_at.len();
    let mut settle = vec![vec![None; events]; n];
    let mut peak = 0u64;
    // Start: standing still until nothing more arrives.
    let at0: Vec<[i64; 2]> = starts.iter().map(|&s| flight.at(s, 0)).collect();
    let mut windows = HashSet::new();
    add_windows(d, &at0, &mut windows);
    let (mut quiet, mut start_ticks) = (0, 0u64);
    let mut lods: Vec<f64> = (0..n).map(|_| f64::INFINITY).collect();
    while quiet < 3 && start_ticks < START_CAP {
        start_ticks += 1;
        let before = sim.deliveries();
        sim.step(&at0);
        peak = peak.max(sim.resident());
        let now: Vec<f64> = (0..n).map(|v| sim.min_lod(v)).collect();
        for v in 0..n {
            if settle[v][0].is_none() && now[v] == 0.0 {
                settle[v][0] = Some(start_ticks);
            }
        }
        quiet = if sim.deliveries() == before && now == lods { quiet + 1 } else { 0 };
        lods = now;
    }
    // Flight.
    let reads0 = sim.disk_reads();
    let mut lod_sum = vec![0.0; n];
    let (mut event, mut event_tick) = (0usize, 1u64);
    for t in 1..=flight.ticks {
        if flight.jump_at.contains(&t) {
            event += 1;
            event_tick = t;
        }
        let at: Vec<[i64; 2]> = starts.iter().map(|&s| flight.at(s, t)).collect();
        add_windows(d, &at, &mut windows);
        sim.step(&at);
        peak = peak.max(sim.resident());
        for v in 0..n {
            let lod = sim.min_lod(v);
            lod_sum[v] += lod;
            if event > 0 && settle[v][event].is_none() && lod == 0.0 {
                settle[v][event] = Some(t - event_tick + 1);
            }
        }
    }
    let stats = sim.maps.iter().map(|m| m.stats());
    let (mut put_off, mut under_views, mut under_published) = (0, 0, 0);
    for st in stats {
        put_off += st.reads_put_off;
        under_views += st.slots_reassigned_under_views;
        under_published += st.slots_reassigned_under_published;
    }
    Ok(Run {
        tiles_read: sim.disk_reads(),
        window_tiles: windows.len() as u64,
        level0_grid: sim.maps[0].level(0).grid,
        flight_tiles_read: sim.disk_reads() - reads0,
        peak_resident_bytes: peak,
        mapping_bytes: sim.maps.iter().map(|m| m.memory().total_bytes()).sum(),
        view_mean_min_lod: lod_sum.iter().map(|s| s / flight.ticks.max(1) as f64).collect(),
        settle,
        start_ticks,
        pool_hits: sim.pool_hits(),
        reads_put_off: put_off,
        under_views,
        under_published,
    })
}

/// Adds the tiles under each view's window at `at`, every level, to `set`.
fn add_windows(d: &TextureDesc, at: &[[i64; 2]], set: &mut HashSet<TileId>) {
    for k in 0..d.level_count() as u32 {
        let l = d.level(k);
        for &p in at {
            let r = tiles_covering(tex_region(l.size, d.clip_size(), aligned_centre(p, k, 1)), l.tile);
            for t in r.t0..r.t1 {
                for s in r.s0..r.s1 {
                    set.insert(TileId::new(k, s as u64, t as u64));
                }
            }
        }
    }
}

/// Mean of the events' settle ticks (None if any is None).
fn mean_settle(events: &[Option<u64>]) -> Option<f64> {
    let all: Option<Vec<u64>> = events.iter().copied().collect();
    all.map(|v| v.iter().sum::<u64>() as f64 / v.len().max(1) as f64)
}

/// Mean over the events of the slowest view's settle ticks.
fn every_view_settle(settle: &[Vec<Option<u64>>]) -> Option<f64> {
    let events = settle.first().map_or(0, |s| s.len());
    let mut sum = 0u64;
    for e in 0..events {
        let mut worst = 0;
        for view in settle {
            worst = worst.max(view[e]?);
        }
        sum += worst;
    }
    Some(sum as f64 / events.max(1) as f64)
}

/// A scenario: its views' starts and weights, its flight and disks.
struct Scenario {
    name: &'static str,
    starts: Vec<[f64; 2]>,
    flight: Flight,
    /// The disk of a view alone, and of the views together.
    alone_rate: u64,
    together_rate: u64,
}

/// One design of a scenario, as flown.
struct Spec {
    design: String,
    how: Design,
    weights: Vec<f64>,
    /// The design its ratios are against, flown alone (`one_view`, `one_view_ring`).
    baseline: &'static str,
}

/// The runs of one view alone on each view's path (one clipmap, default grids under `prefetch`,
/// the alone disk): view 0's, and each view's mean settle ticks.
fn alone(d: &TextureDesc, sc: &Scenario, prefetch: PrefetchKind) -> anyhow::Result<(Run, Vec<Option<f64>>)> {
    let mut first = None;
    let mut settles = Vec::new();
    for (v, &start) in sc.starts.iter().enumerate() {
        let r = run(d, Design::One { spread: 0, prefetch }, &[start], &[1.0], &sc.flight, sc.alone_rate, 0)
            .with_context(|| format!("{} view {v} alone", sc.name))?;
        settles.push(mean_settle(&r.settle[0]));
        if v == 0 {
            first = Some(r);
        }
    }
    Ok((first.expect("a scenario has a view"), settles))
}

/// Flies `spec` (the first as many of the scenario's views as it has weights) and makes its row.
fn fly(
    d: &TextureDesc,
    sc: &Scenario,
    spec: &Spec,
    pool_bytes: u64,
    one: &Run,
    alone: &[Option<f64>],
) -> anyhow::Result<Row> {
    let n = spec.weights.len();
    let rate = if n == 1 { sc.alone_rate } else { sc.together_rate };
    let pool = if matches!(spec.how, Design::Separate { pool: true }) { pool_bytes } else { 0 };
    let r = run(d, spec.how, &sc.starts[..n], &spec.weights, &sc.flight, rate, pool)
        .with_context(|| format!("{} {}", sc.name, spec.design))?;
    Ok(make_row(sc, spec, pool, &r, one, alone))
}

/// The row of `spec`'s run `r`, its ratios against `one` (the baseline's run) and `alone` (each
/// view's settle ticks alone).
fn make_row(sc: &Scenario, spec: &Spec, pool: u64, r: &Run, one: &Run, alone: &[Option<f64>]) -> Row {
    let n = spec.weights.len();
    let rate = if n == 1 { sc.alone_rate } else { sc.together_rate };
    let (spread, prefetch, clipmaps) = match spec.how {
        Design::One { spread, prefetch } => (spread, prefetch, 1),
        Design::Separate { .. } | Design::Own => (0, PrefetchKind::default(), n),
    };
    let alone = &alone[..n];
    let view_settle: Vec<Option<f64>> = r.settle.iter().map(|e| mean_settle(e)).collect();
    let settle_vs_alone = view_settle
        .iter()
        .zip(alone)
        .map(|(s, a)| match (s, a) {
            (Some(s), Some(a)) if *a > 0.0 => Some(s / a),
            _ => None,
        })
        .collect::<Option<Vec<f64>>>()
        .map(|v| v.into_iter().fold(0.0, f64::max));
    Row {
        name: sc.name,
        design: spec.design.clone(),
        baseline: spec.baseline,
        prefetch: prefetch.name(),
        views: n,
        weights: spec.weights.clone(),
        clipmaps,
        view_spread: spread,
        level0_grid: r.level0_grid,
        disk_tiles_per_tick: rate,
        pool_bytes: pool,
        tiles_read: r.tiles_read,
        flight_tiles_read: r.flight_tiles_read,
        window_tiles: r.window_tiles,
        peak_resident_bytes: r.peak_resident_bytes,
        mapping_bytes: r.mapping_bytes,
        settle_ticks: every_view_settle(&r.settle),
        views_never_settled: view_settle.iter().filter(|s| s.is_none()).count(),
        mean_min_lod: r.view_mean_min_lod.iter().sum::<f64>() / n.max(1) as f64,
        view_mean_min_lod: r.view_mean_min_lod.clone(),
        view_settle_ticks: view_settle,
        view_settle_events: r.settle.clone(),
        view_settle_alone_ticks: alone.to_vec(),
        start_ticks: r.start_ticks,
        tiles_read_vs_one: r.tiles_read as f64 / one.tiles_read.max(1) as f64,
        window_tiles_vs_one: r.window_tiles as f64 / one.window_tiles.max(1) as f64,
        resident_vs_one: r.peak_resident_bytes as f64 / one.peak_resident_bytes.max(1) as f64,
        settle_vs_alone,
        heavy_min_lod_delta: sc.name.starts_with("weighted").then(|| r.view_mean_min_lod[0] - one.view_mean_min_lod[0]),
        pool_hits: r.pool_hits,
        reads_put_off: r.reads_put_off,
        slots_reassigned_under_views: r.under_views,
        slots_reassigned_under_published: r.under_published,
    }
}

/// The sizes.
struct Size {
    name: &'static str,
    size: u64,
    clip: u64,
    tile: u64,
    ticks: u64,
}

fn size(args: &Args) -> Size {
    // quick and full have the same shape in tiles (clip 4 tiles); full has tiles four times as
    // large and flies longer.
    if args.smoke {
        Size { name: "smoke", size: 1 << 12, clip: 64, tile: 16, ticks: 96 }
    } else if args.quick {
        Size { name: "quick", size: 1 << 15, clip: 256, tile: 64, ticks: 360 }
    } else {
        Size { name: "full", size: 1 << 16, clip: 512, tile: 128, ticks: 960 }
    }
}

/// Runs every scenario and design.
pub fn report(args: &Args, mut progress: impl FnMut(&Row)) -> anyhow::Result<Report> {
    let z = size(args);
    let d = desc(z.size, z.clip, z.tile);
    let tile_bytes = d.tile_bytes(0) as u64;
    let one_mapping = mapping_bytes(&d, 0);
    let pool_bytes = (one_mapping * 3 / 2) / tile_bytes * tile_bytes;
    let (s, c) = (z.size as f64, z.clip as f64);
    let flight = Flight {
        speed: z.tile as f64 / 8.0,
        angle_deg: 30.0,
        ticks: z.ticks,
        jump_at: vec![z.ticks / 3, 2 * z.ticks / 3],
        jump: 24.0 * z.tile as f64,
        size: z.size,
    };
    let setup = Setup {
        size_name: z.name,
        size: z.size,
        clip: z.clip,
        tile: z.tile,
        levels: d.level_count(),
        tile_bytes,
        flight_ticks: z.ticks,
        speed: flight.speed,
        angle_deg: flight.angle_deg,
        jump_ticks: flight.jump_at.clone(),
        jump_texels: flight.jump as u64,
        disk_tiles_per_tick_per_view: DISK_PER_VIEW,
        prefetch: PrefetchKind::default().name(),
        fade_ticks: Settings::default().fade_ticks,
        one_view_mapping_bytes: one_mapping,
        pool_bytes,
    };
    let mut rows = Vec::new();
    let mut emit = |r: Row| {
        progress(&r);
        rows.push(r);
    };
    let adaptive = PrefetchKind::default();
    let spec = |design: &str, how: Design, weights: Vec<f64>, baseline: &'static str| Spec {
        design: design.to_string(),
        how,
        weights,
        baseline,
    };

    // near: view 0 and three views up to half a clip size off it along each axis.
    let p = [0.2718 * s, 0.3123 * s];
    let near = Scenario {
        name: "near",
        starts: vec![p, [p[0] + c / 2.0, p[1]], [p[0], p[1] - c / 2.0], [p[0] - c / 2.0, p[1] + c / 2.0]],
        flight: flight.clone(),
        alone_rate: 4 * DISK_PER_VIEW,
        together_rate: 4 * DISK_PER_VIEW,
    };
    // far: four views a quarter of the texture and more apart.
    let far = Scenario {
        name: "far",
        starts: vec![
            [0.1414 * s, 0.1732 * s],
            [0.6180 * s, 0.1732 * s],
            [0.1414 * s, 0.5772 * s],
            [0.6180 * s, 0.5772 * s],
        ],
        flight: flight.clone(),
        alone_rate: DISK_PER_VIEW,
        together_rate: 4 * DISK_PER_VIEW,
    };
    for sc in [&near, &far] {
        let four = vec![1.0; 4];
        // The engine's default grids (adaptive prefetch), then (near) Performer's fixed ring of
        // lookahead-1 grids, whose grids hold less beside the primary's window.
        let mut groups = vec![(adaptive, "one_view", "")];
        if sc.name == "near" {
            groups.push((PrefetchKind::Ring, "one_view_ring", "_ring"));
        }
        for (prefetch, baseline, suffix) in groups {
            let (one, settles) = alone(&d, sc, prefetch)?;
            let base = spec(baseline, Design::One { spread: 0, prefetch }, vec![1.0], baseline);
            emit(make_row(sc, &base, 0, &one, &one, &settles));
            let mut designs = vec![spec(
                &format!("views_spread_0{suffix}"),
                Design::One { spread: 0, prefetch },
                four.clone(),
                baseline,
            )];
            if sc.name == "near" {
                designs.push(spec(
                    &format!("views_spread_clip{suffix}"),
                    Design::One { spread: z.clip, prefetch },
                    four.clone(),
                    baseline,
                ));
            }
            if prefetch == adaptive {
                designs.push(spec("separate_grids", Design::Separate { pool: false }, four.clone(), baseline));
                designs.push(spec(
                    "separate_grids_shared_pool",
                    Design::Separate { pool: true },
                    four.clone(),
                    baseline,
                ));
                designs.push(spec("own_grids", Design::Own, four.clone(), baseline));
            }
            for sp in &designs {
                emit(fly(&d, sc, sp, pool_bytes, &one, &settles)?);
            }
        }
    }
    // far: the spread that would hold every far view in one clipmap's grids (not flown).
    let extent = |a: usize| {
        let (lo, hi) = far.starts.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| (lo.min(p[a]), hi.max(p[a])));
        hi - lo
    };
    let spread_needed = extent(0).max(extent(1)).ceil() as u64;
    let held = mapping_bytes(&d, spread_needed);
    let far_spread = FarSpread { spread_needed, mapping_bytes: held, vs_one: held as f64 / one_mapping as f64 };

    // weighted: two views two clip sizes apart across the flight, one clipmap holding both.
    let dist = 2.0 * c;
    let a = flight.angle_deg.to_radians();
    let h = [0.3123 * s, 0.2718 * s];
    let starts = vec![h, [h[0] - dist * a.sin(), h[1] + dist * a.cos()]];
    let spread = dist as u64;
    let wflight = Flight { jump_at: Vec::new(), ..flight.clone() };
    // The need, over an unthrottled disk.
    let need_one =
        run(&d, Design::One { spread: 0, prefetch: adaptive }, &starts[..1], &[1.0], &wflight, UNTHROTTLED, 0)?;
    let need_both =
        run(&d, Design::One { spread, prefetch: adaptive }, &starts, &[3.0, 1.0], &wflight, UNTHROTTLED, 0)?;
    let per_tick = |r: &Run| r.flight_tiles_read as f64 / wflight.ticks.max(1) as f64;
    let (one_need, both_need) = (per_tick(&need_one), per_tick(&need_both));
    let rate = ((1.25 * one_need).ceil() as u64).max(1);
    let tight = rate.saturating_sub(1).max(1);
    let weighted_disk = WeightedDisk {
        one_view_need_per_tick: one_need,
        both_views_need_per_tick: both_need,
        disk_tiles_per_tick: rate,
        too_slow_for_both: (rate as f64) < both_need,
        tight_disk_tiles_per_tick: tight,
    };
    for (name, rate) in [("weighted", rate), ("weighted_tight", tight)] {
        let sc =
            Scenario { name, starts: starts.clone(), flight: wflight.clone(), alone_rate: rate, together_rate: rate };
        let (one, settles) = alone(&d, &sc, adaptive)?;
        let base = spec("one_view", Design::One { spread: 0, prefetch: adaptive }, vec![1.0], "one_view");
        emit(make_row(&sc, &base, 0, &one, &one, &settles));
        let mut designs = Vec::new();
        if name == "weighted" {
            designs.push(spec(
                "one_view_same_grids",
                Design::One { spread, prefetch: adaptive },
                vec![1.0],
                "one_view",
            ));
        }
        designs.push(spec("weights_3_1", Design::One { spread, prefetch: adaptive }, vec![3.0, 1.0], "one_view"));
        designs.push(spec("weights_1_1", Design::One { spread, prefetch: adaptive }, vec![1.0, 1.0], "one_view"));
        for sp in &designs {
            emit(fly(&d, &sc, sp, pool_bytes, &one, &settles)?);
        }
    }

    let goals = goals(&rows);
    Ok(Report { setup, scenarios: rows, weighted_disk, far_spread, goals })
}

fn is_views_design(design: &str) -> bool {
    design.starts_with("views_") || design.starts_with("weights_") || design == "own_grids"
}

/// Checks every design against its scenario's goal.
fn goals(rows: &[Row]) -> Goals {
    let fmt = |x: Option<f64>| x.map_or("never (a view did not settle)".to_string(), |x| format!("{x:.3}"));
    let check = |name: &str, goal: &'static str, designs: &[&str], test: &dyn Fn(&Row) -> Vec<String>| {
        let mut checks = Vec::new();
        for r in rows.iter().filter(|r| {
            r.name == name
                && designs
                    .iter()
                    .any(|d| r.design == *d || (d.ends_with('*') && r.design.starts_with(&d[..d.len() - 1])))
        }) {
            let missed = test(r);
            checks.push(GoalCheck {
                design: r.design.clone(),
                met: missed.is_empty(),
                all_views_at_level_0: r.views_never_settled == 0,
                why: missed.join("; "),
            });
        }
        Goal {
            goal,
            met: checks.iter().any(|c| c.met && c.all_views_at_level_0 && is_views_design(&c.design)),
            met_by: checks.iter().filter(|c| c.met).map(|c| c.design.clone()).collect(),
            designs: checks,
        }
    };
    let near = check(
        "near",
        "4 views within one clip size of each other flying together: tiles read <= 1.1x one view's, resident bytes <= 1.25x one view's",
        &["views_*", "separate_grids*", "own_grids"],
        &|r| {
            let mut m = Vec::new();
            if r.tiles_read_vs_one > 1.1 {
                m.push(format!("tiles read {:.3}x one view's (goal 1.1x)", r.tiles_read_vs_one));
            }
            if r.resident_vs_one > 1.25 {
                m.push(format!("resident {:.3}x one view's (goal 1.25x)", r.resident_vs_one));
            }
            m
        },
    );
    let far = check(
        "far",
        "4 views far apart over a source that can serve all of them: each settles within 1.25x of its time alone, resident bytes <= 4.1x one view's",
        &["views_*", "separate_grids*", "own_grids"],
        &|r| {
            let mut m = Vec::new();
            if !r.settle_vs_alone.is_some_and(|x| x <= 1.25) {
                m.push(format!("settles at {} its time alone (goal 1.25x)", fmt(r.settle_vs_alone)));
            }
            if r.resident_vs_one > 4.1 {
                m.push(format!("resident {:.3}x one view's (goal 4.1x)", r.resident_vs_one));
            }
            m
        },
    );
    let weighted = check(
        "weighted",
        "2 views with weights 3:1 over a source too slow for both: the heavy view's mean min LOD within 0.25 of what it has alone",
        &["weights_3_1"],
        &|r| match r.heavy_min_lod_delta {
            Some(x) if x.abs() <= 0.25 => Vec::new(),
            x => vec![format!("heavy view's mean min LOD {} above alone (goal 0.25)", fmt(x))],
        },
    );
    Goals { near, far, weighted }
}

/// The report as a person reads it.
pub fn human(r: &Report) -> String {
    use std::fmt::Write;
    let s = &r.setup;
    let mib = |b: u64| b as f64 / (1u64 << 20) as f64;
    let opt = |x: Option<f64>| x.map_or("never".to_string(), |x| format!("{x:.1}"));
    let optr = |x: Option<f64>| x.map_or("-".to_string(), |x| format!("{x:.2}"));
    let mut o = String::new();
    let _ = writeln!(
        o,
        "hash texture {0}x{0} RGBA8, clip {1}, {2}-texel tiles ({3} KiB), {4} levels, prefetch {5}; flight {6} ticks at {7} texels a tick, {8}° from +s, jumps of {9} texels at ticks {10:?} (near, far); disk {11} tiles a tick a view; one view's mapping {12:.1} MiB; shared pool {13:.1} MiB",
        s.size,
        s.clip,
        s.tile,
        s.tile_bytes / 1024,
        s.levels,
        s.prefetch,
        s.flight_ticks,
        s.speed,
        s.angle_deg,
        s.jump_texels,
        s.jump_ticks,
        s.disk_tiles_per_tick_per_view,
        mib(s.one_view_mapping_bytes),
        mib(s.pool_bytes)
    );
    let w = &r.weighted_disk;
    let _ = writeln!(
        o,
        "weighted disk: {} tiles a tick (one view needs {:.2}, both {:.2}: {}); far views held in one clipmap would need view_spread {} ({:.1} MiB of mapping, {:.1}x one view's)",
        w.disk_tiles_per_tick,
        w.one_view_need_per_tick,
        w.both_views_need_per_tick,
        if w.too_slow_for_both { "too slow for both" } else { "NOT too slow for both" },
        r.far_spread.spread_needed,
        mib(r.far_spread.mapping_bytes),
        r.far_spread.vs_one
    );
    let _ = writeln!(o);
    let _ = writeln!(
        o,
        "| scenario | design | views | grid | disk | tiles read | x one | window tiles x one | peak resident MiB | x one | settle ticks | x alone | mean min LOD per view | heavy delta | pool hits |"
    );
    let _ = writeln!(o, "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|");
    for row in &r.scenarios {
        let _ = writeln!(
            o,
            "| {} | {} | {} | {} | {} | {} | {:.2} | {:.2} | {:.1} | {:.2} | {} | {} | {} | {} | {} |",
            row.name,
            row.design,
            row.views,
            row.level0_grid[0],
            row.disk_tiles_per_tick,
            row.tiles_read,
            row.tiles_read_vs_one,
            row.window_tiles_vs_one,
            mib(row.peak_resident_bytes),
            row.resident_vs_one,
            opt(row.settle_ticks),
            optr(row.settle_vs_alone),
            row.view_mean_min_lod.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(" "),
            optr(row.heavy_min_lod_delta),
            row.pool_hits
        );
    }
    let _ = writeln!(o);
    for (name, g) in [("near", &r.goals.near), ("far", &r.goals.far), ("weighted", &r.goals.weighted)] {
        let _ = writeln!(o, "goal {name}: {} — {}", if g.met { "met" } else { "NOT met" }, g.goal);
        for c in &g.designs {
            let _ = writeln!(
                o,
                "  {}: {}{}{}",
                c.design,
                if c.met { "bounds met" } else { "bounds missed" },
                if c.all_views_at_level_0 { "" } else { ", a view never shows level 0" },
                if c.why.is_empty() { String::new() } else { format!(" ({})", c.why) }
            );
        }
    }
    o
}

/// `clipbench views`.
pub fn main(args: Args) -> u8 {
    let started = std::time::Instant::now();
    let quiet = args.json;
    match report(&args, |row| {
        if !quiet {
            eprintln!(
                "{} {}: {} tiles read, peak {} bytes, settle {:?}",
                row.name, row.design, row.tiles_read, row.peak_resident_bytes, row.settle_ticks
            );
        }
    }) {
        Ok(r) => {
            clipmap::report::emit(args.json, &r, human);
            if !quiet {
                eprintln!("{} runs in {:.1} s", r.scenarios.len(), started.elapsed().as_secs_f64());
            }
            0
        }
        Err(e) => {
            eprintln!("clipbench views: {e:#}");
            2
        }
    }
}
