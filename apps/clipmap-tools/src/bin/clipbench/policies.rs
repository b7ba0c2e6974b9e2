//! `clipbench policies`: the paging policies side by side (docs/ARCHITECTURE.md §9).
//!
//! Flies the standard flights (straight, turning, zig-zag, hover, fast straight, sudden jumps,
//! a turn-around) over the hash texture once for every combination of prefetch policy (ring,
//! direction, ahead, adaptive) and eviction policy of the second-level pool (LRU, shift; and no pool, for a
//! baseline), under a pool budget that forces eviction, and reports per run: tiles read from the
//! disk, the pool's hit rate, peak resident bytes (the grids' whole mapping plus the pool's
//! tiles), ticks with a disabled level and the mean min LOD.
//!
//! Deterministic: the disk is simulated ([`ThrottledSource`], N tiles a tick, the rest put off to
//! the next tick in priority order), one read runs at a time, and every tick waits for the
//! reads it can start (lock step), so late data shows as ticks with a disabled level and a
//! raised min LOD the same on every machine, and two runs print the same rows. Each run first
//! settles at its start (not counted), then flies.
//!
//! Exit status: 0 ok, 1 a bad option (an unknown flight or policy), 2 the benchmark could not
//! run.

use anyhow::Context;
use clipmap::clip::{Clipmap, Settings};
use clipmap::paging::{EvictionKind, PrefetchKind};
use clipmap::roam::Flight;
use clipmap::source::{HashSource, TextureDesc, ThrottledSource, TileSource};
use clipmap::texel::TexelFormat;
use serde::Serialize;
use std::sync::Arc;

/// Options of `clipbench policies`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A smaller texture and shorter flights (well under a minute in a release build).
    #[arg(long)]
    quick: bool,
    /// Tiny sizes: checks that every run works (for tests); the figures mean little.
    #[arg(long, hide = true, conflicts_with = "quick")]
    smoke: bool,
    /// Print one JSON object (`setup`, `rows`) instead of tables.
    #[arg(long)]
    json: bool,
    /// Clamp the centre's step per tick to this many level-0 texels along each axis (the
    /// offset clamp; counted in `centre_clamps`).
    #[arg(long)]
    max_centre_step: Option<u64>,
    /// Only these prefetch policies (default: all four).
    #[arg(long, value_delimiter = ',')]
    prefetch: Vec<PrefetchKind>,
    /// Only these eviction policies (`none`: no pool; default: none, lru, shift).
    #[arg(long, value_delimiter = ',')]
    eviction: Vec<String>,
    /// The pool's budget instead of 1.5 times the grids' bytes (k, m, g suffixes: KiB, MiB, GiB).
    #[arg(long, value_name = "BYTES", value_parser = clipmap::paging::parse_bytes)]
    pool_bytes: Option<u64>,
    /// Only these flights (straight, turning, zigzag, hover, fast_straight, jumps, turn_around).
    #[arg(long, value_delimiter = ',')]
    flight: Vec<String>,
}

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
    /// Ticks flown per run (after settling at the start).
    pub ticks: u64,
    /// Tiles the simulated disk reads a tick.
    pub disk_tiles_per_tick: u64,
    /// The pool's hard budget (bytes of tiles).
    pub pool_bytes: u64,
    /// Bytes of the image caches' mapping (every grid, the pyramid, the header) of the fixed
    /// policies (lookahead 1).
    pub grid_bytes: u64,
    /// The same for `adaptive`, whose grids take the default budget (twice the lookahead-1
    /// grids).
    pub adaptive_grid_bytes: u64,
    pub max_centre_step: Option<u64>,
}

/// One run: a flight under one combination of policies.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub prefetch: &'static str,
    /// `lru`, `shift`, or `none` (no pool).
    pub eviction: &'static str,
    pub flight: &'static str,
    /// Tiles read from the (simulated) disk while flying.
    pub tiles_read: u64,
    /// Pool hits over reads that delivered a tile (0 without a pool).
    pub hit_rate: f64,
    /// Most bytes held: the image caches' mapping plus the pool's tiles.
    pub peak_resident_bytes: u64,
    pub ticks_with_disabled_level: u64,
    pub mean_min_lod: f64,
    /// Reads served from the pool.
    pub pool_hits: u64,
    /// Tiles the pool gave up.
    pub pool_evicted: u64,
    /// Settled tiles whose grid slots went to other tiles.
    pub grid_evictions: u64,
    /// Reads the disk put off to a later tick (it had read its tiles for the tick).
    pub reads_put_off: u64,
    pub centre_clamps: u64,
    /// Most level-0 texels (along either axis) the applied centre lagged the flight's (the
    /// clamp's price: where the window is not, renderers use coarser levels).
    pub max_centre_lag: u64,
}

/// The whole comparison.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub setup: Setup,
    pub rows: Vec<Row>,
}

/// A standard flight, in tiles so that every size flies the same shape.
#[derive(Clone, Copy, Debug)]
enum Path {
    Roam(Flight),
    /// Jitter around the start, `amp` texels along each axis (a hovering viewer's sway).
    Hover {
        amp: f64,
    },
    /// +s at `speed`, back along -s from tick `at` on.
    TurnAround {
        speed: f64,
        at: u64,
    },
}

impl Path {
    fn at(&self, start: [f64; 2], tick: u64) -> [f64; 2] {
        match *self {
            Path::Roam(f) => f.position(start, tick),
            Path::Hover { amp } => {
                let x = tick as f64;
                [start[0] + amp * (x / 9.0).sin(), start[1] + amp * (x / 13.0).sin()]
            }
            Path::TurnAround { speed, at } => {
                let x = if tick <= at { tick as f64 } else { 2.0 * at as f64 - tick as f64 };
                [start[0] + speed * x, start[1]]
            }
        }
    }
}

/// The flights, for tiles of `tile` texels over `ticks` ticks, with their starts (fractions of
/// the texture's size, chosen off every level's tile boundaries so that the levels do not all
/// cross one at the same tick).
fn flights(tile: f64, ticks: u64) -> Vec<(&'static str, Path, [f64; 2])> {
    let slow = tile / 8.0;
    vec![
        ("straight", Path::Roam(Flight::Straight { speed: slow, angle: 0.0 }), [0.2718, 0.5123]),
        // A circle of 12 tiles' radius: one turn every 600 ticks.
        ("turning", Path::Roam(Flight::Circle { radius: 12.0 * tile, speed: slow }), [0.5123, 0.4871]),
        ("zigzag", Path::Roam(Flight::Zigzag { speed: slow, period: (ticks / 12).max(4) }), [0.2718, 0.5123]),
        // Swaying about a point, 0.6 tiles each way.
        ("hover", Path::Hover { amp: 0.6 * tile }, [0.5123, 0.4871]),
        ("fast_straight", Path::Roam(Flight::Straight { speed: tile / 2.0, angle: 45.0 }), [0.1414, 0.1732]),
        ("jumps", Path::Roam(Flight::Jump { every: (ticks / 8).max(2), dist: 24.0 * tile }), [0.1414, 0.5123]),
        ("turn_around", Path::TurnAround { speed: slow, at: ticks / 2 }, [0.2718, 0.5123]),
    ]
}

fn setup(args: &Args) -> Setup {
    // (name, size, clip, tile, ticks, disk tiles a tick): quick and full have the same shape in
    // tiles (6 x 6 grids, 7 stack levels), full has tiles four times as large and flies twice as
    // long.
    let (size_name, size, clip, tile, ticks, disk) = if args.smoke {
        ("smoke", 1u64 << 12, 64, 16, 48, 6)
    } else if args.quick {
        ("quick", 1 << 15, 256, 64, 480, 4)
    } else {
        ("full", 1 << 16, 512, 128, 960, 4)
    };
    let desc = desc(size, clip, tile);
    let tile_bytes = desc.tile_bytes(0) as u64;
    let mapping = |prefetch| {
        let shape = Clipmap::shape_for(&desc, &Settings { prefetch, ..Settings::default() });
        clipmap::shm::layout::place(&shape).map_or(0, |p| p.total_bytes)
    };
    let grid_bytes = mapping(PrefetchKind::Ring);
    let adaptive_grid_bytes = mapping(PrefetchKind::Adaptive);
    // The pool is inclusive (it keeps copies of tiles the grids hold too): half as much again
    // as the grids leaves room for tiles beyond them, far less than a flight reads.
    let pool_tiles = (grid_bytes * 3 / 2).div_ceil(tile_bytes);
    let pool_bytes = args.pool_bytes.unwrap_or(pool_tiles * tile_bytes);
    Setup {
        size_name,
        size,
        clip,
        tile,
        levels: desc.level_count(),
        tile_bytes,
        ticks,
        disk_tiles_per_tick: disk,
        pool_bytes,
        grid_bytes,
        adaptive_grid_bytes,
        max_centre_step: args.max_centre_step,
    }
}

fn desc(size: u64, clip: u64, tile: u64) -> TextureDesc {
    TextureDesc::new([size, size], clip, TexelFormat::RGBA8, [tile, tile]).expect("a valid benchmark texture")
}

/// Flies one path under one combination.
fn run(
    s: &Setup,
    prefetch: PrefetchKind,
    eviction: Option<EvictionKind>,
    name: &'static str,
    path: Path,
    start: [f64; 2],
) -> anyhow::Result<Row> {
    let disk =
        Arc::new(ThrottledSource::new(Arc::new(HashSource::new(desc(s.size, s.clip, s.tile))), s.disk_tiles_per_tick));
    let mut settings = Settings {
        budget_ns: None,
        prefetch,
        pool_bytes: eviction.map_or(0, |_| s.pool_bytes),
        eviction: eviction.unwrap_or_default(),
        max_centre_step: s.max_centre_step,
        ..Settings::default()
    };
    // One read at a time in priority order; the disk, not the queue, bounds a tick's reads.
    settings.limits.max_in_flight_reads = 1;
    settings.limits.max_ready_reads = 1 << 16;
    settings.limits.max_pending_reads = 1 << 16;
    let source: Arc<dyn TileSource> = disk.clone();
    let mut map = Clipmap::new(source, settings).context("the clipmap")?;
    let start = [start[0] * s.size as f64, start[1] * s.size as f64];
    let at = |tick: u64| {
        let p = path.at(start, tick);
        let clamp = |x: f64| (x.floor() as i64).clamp(0, s.size as i64 - 1);
        [clamp(p[0]), clamp(p[1])]
    };
    let step = |map: &mut Clipmap, centre: [i64; 2]| {
        // Before the tick: its requests may start reading as soon as it sends them.
        disk.next_tick();
        let r = map.tick(centre, None);
        map.wait_for_reads();
        r
    };
    // Settle at the start: until every level is shown and nothing more arrives.
    let mut settled = false;
    for _ in 0..100_000 {
        let r = step(&mut map, at(0));
        if r.min_lod == 0.0 && r.tiles_read == 0 {
            settled = true;
            break;
        }
    }
    anyhow::ensure!(settled, "{name}: the clipmap never settled at its start");
    // The pool's own counters, between reads (the copy in the clipmap's statistics is taken
    // during a tick, while that tick's first reads may already run).
    let pool = |map: &Clipmap| map.pool().map(|p| p.stats()).unwrap_or_default();
    let reads0 = disk.reads();
    let stats0 = map.stats().clone();
    let pool0 = pool(&map);
    let (mut disabled, mut lod_sum, mut peak, mut lag) = (0u64, 0.0f64, map.resident_bytes(), 0u64);
    for tick in 1..=s.ticks {
        let want = at(tick);
        let r = step(&mut map, want);
        lag = lag.max(want[0].abs_diff(r.centre[0]).max(want[1].abs_diff(r.centre[1])));
        disabled += !r.disabled_levels.is_empty() as u64;
        lod_sum += r.min_lod;
        peak = peak.max(map.resident_bytes());
    }
    let st = map.stats();
    let pool1 = pool(&map);
    let planned = if prefetch == PrefetchKind::Adaptive { s.adaptive_grid_bytes } else { s.grid_bytes };
    anyhow::ensure!(map.memory().total_bytes() == planned, "the grids' mapping is not the size planned");
    let (hits, misses) = (pool1.hits - pool0.hits, pool1.misses - pool0.misses);
    Ok(Row {
        prefetch: prefetch.name(),
        eviction: eviction.map_or("none", |e| e.name()),
        flight: name,
        tiles_read: disk.reads() - reads0,
        hit_rate: if hits + misses == 0 { 0.0 } else { hits as f64 / (hits + misses) as f64 },
        peak_resident_bytes: peak,
        ticks_with_disabled_level: disabled,
        mean_min_lod: lod_sum / s.ticks as f64,
        pool_hits: hits,
        pool_evicted: pool1.evicted - pool0.evicted,
        grid_evictions: st.tiles_evicted - stats0.tiles_evicted,
        reads_put_off: st.reads_put_off - stats0.reads_put_off,
        centre_clamps: st.centre_clamps - stats0.centre_clamps,
        max_centre_lag: lag,
    })
}

/// Runs every combination on every flight.
pub fn report(args: &Args, mut progress: impl FnMut(&Row)) -> anyhow::Result<Report> {
    let s = setup(args);
    let prefetches = if args.prefetch.is_empty() { PrefetchKind::ALL.to_vec() } else { args.prefetch.clone() };
    let mut evictions: Vec<Option<EvictionKind>> = Vec::new();
    for e in &args.eviction {
        if e.trim().eq_ignore_ascii_case("none") {
            evictions.push(None);
        } else {
            evictions.push(Some(e.parse().map_err(|e| anyhow::anyhow!("--eviction: {e} (or `none`: no pool)"))?));
        }
    }
    if evictions.is_empty() {
        evictions = vec![None, Some(EvictionKind::Lru), Some(EvictionKind::Shift)];
    }
    let all = flights(s.tile as f64, s.ticks);
    for f in &args.flight {
        anyhow::ensure!(
            all.iter().any(|(name, ..)| name == f),
            "--flight {f}: expected one of {}",
            all.iter().map(|(n, ..)| *n).collect::<Vec<_>>().join(", ")
        );
    }
    let mut rows = Vec::new();
    for (name, path, start) in all {
        if !args.flight.is_empty() && !args.flight.iter().any(|f| f == name) {
            continue;
        }
        for &p in &prefetches {
            for &e in &evictions {
                let row = run(&s, p, e, name, path, start)?;
                progress(&row);
                rows.push(row);
            }
        }
    }
    Ok(Report { setup: s, rows })
}

/// The report as a person reads it: the setup, then one Markdown table row per run.
pub fn human(r: &Report) -> String {
    use std::fmt::Write;
    let s = &r.setup;
    let mut o = String::new();
    let mib = |b: u64| b as f64 / (1u64 << 20) as f64;
    let _ = writeln!(
        o,
        "hash texture {0}x{0} RGBA8, clip {1}, {2}-texel tiles ({3} KiB), {4} levels; {5} ticks a flight; disk {6} tiles a tick; pool {7:.1} MiB ({8} tiles); grids {9:.1} MiB{10}",
        s.size,
        s.clip,
        s.tile,
        s.tile_bytes / 1024,
        s.levels,
        s.ticks,
        s.disk_tiles_per_tick,
        mib(s.pool_bytes),
        s.pool_bytes / s.tile_bytes.max(1),
        mib(s.grid_bytes),
        s.max_centre_step.map(|c| format!("; centre step clamped to {c} texels")).unwrap_or_default()
    );
    let _ = writeln!(o);
    let _ = writeln!(
        o,
        "| flight | prefetch | eviction | tiles read | hit rate | peak resident MiB | ticks with a disabled level | mean min LOD | pool evictions | clamps | max lag |"
    );
    let _ = writeln!(o, "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for row in &r.rows {
        let _ = writeln!(
            o,
            "| {} | {} | {} | {} | {:.3} | {:.1} | {} | {:.3} | {} | {} | {} |",
            row.flight,
            row.prefetch,
            row.eviction,
            row.tiles_read,
            row.hit_rate,
            mib(row.peak_resident_bytes),
            row.ticks_with_disabled_level,
            row.mean_min_lod,
            row.pool_evicted,
            row.centre_clamps,
            row.max_centre_lag
        );
    }
    o
}

/// The options' names checked before anything runs.
fn check(args: &Args) -> Result<(), String> {
    let names: Vec<&str> = flights(1.0, 16).iter().map(|(n, ..)| *n).collect();
    if let Some(f) = args.flight.iter().find(|f| !names.contains(&f.as_str())) {
        return Err(format!("--flight {f}: expected one of {}", names.join(", ")));
    }
    for e in &args.eviction {
        if !e.trim().eq_ignore_ascii_case("none") {
            e.parse::<EvictionKind>().map_err(|err| format!("--eviction: {err} (or `none`: no pool)"))?;
        }
    }
    Ok(())
}

/// `clipbench policies`.
pub fn main(args: Args) -> u8 {
    let started = std::time::Instant::now();
    if let Err(e) = check(&args) {
        eprintln!("clipbench policies: {e}");
        return 1;
    }
    let quiet = args.json;
    match report(&args, |row| {
        if !quiet {
            eprintln!(
                "{} {}/{}: {} tiles read, hit rate {:.3}",
                row.flight, row.prefetch, row.eviction, row.tiles_read, row.hit_rate
            );
        }
    }) {
        Ok(r) => {
            clipmap::report::emit(args.json, &r, human);
            if !quiet {
                eprintln!("{} runs in {:.1} s", r.rows.len(), started.elapsed().as_secs_f64());
            }
            0
        }
        Err(e) => {
            eprintln!("clipbench policies: {e:#}");
            2
        }
    }
}
