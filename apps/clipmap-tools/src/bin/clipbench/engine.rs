//! `clipbench engine`: measures the paging engine against its goals in one run.
//!
//! `clipbench engine` flies a clipmap over the procedural hash texture (2^26 texels, clip size
//! 2048, RGBA8; `--quick`: 2^20, clip 512) along +s, +t and the diagonal and reports, with medians
//! over several runs:
//! - the median update tick of each steady flight (the tick alone, as the service runs it: the
//!   reads it asks for go on in the background, straight into their slots, and are waited for
//!   between ticks without being timed), and `direction_ratio`, the slowest flight's over the
//!   fastest's; beside it the tick together with its reads;
//! - tiles read per tick against the exact tiles that enter the mem regions (placed as the
//!   engine's prefetch policy places them), and the texel bytes the ticks themselves wrote
//!   (`tick_texel_bytes`, measured at the mapping's write primitive);
//! - peak resident memory (`VmHWM` growth) against the image caches' formula: every stack level's
//!   grid of tiles, every pyramid level whole, and the header;
//! - the same flights, after those figures, over two clipmaps side by side, one of `rgba8` colours
//!   (the hash texture) and one of `l32f` heights (the height verification texture, 4 bytes a
//!   texel too), their ticks taking turns: the update tick's time per tile read in each format
//!   and `l32f_vs_rgba8_tick_per_tile`, their ratio (goal: at most 1.1, heights cost no more per
//!   byte than colour).
//!
//! Exit status: 0 ok (goals met or not: the figures are the output), 2 the benchmark could not run.

use anyhow::Context;
use clipmap::clip::{Clipmap, Settings};
use clipmap::geom::{aligned_centre, LevelShape, Rect};
use clipmap::paging::Prefetch;
use clipmap::source::{HashSource, HeightSource, TextureDesc, TileSource};
use clipmap::texel::TexelFormat;
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

/// What one engine benchmark flies.
#[derive(Clone, Copy, Debug, Serialize)]
struct Setup {
    size: u64,
    clip: u64,
    tile: u64,
    border: u64,
    bytes_per_texel: usize,
    speed: i64,
    frames_per_run: usize,
    runs: usize,
    /// Level centres aligned to multiples of this many level texels (1: texel-exact).
    centre_alignment: u64,
}

/// One direction of steady flight.
#[derive(Clone, Debug, Serialize)]
struct Flight {
    direction: &'static str,
    /// Median update tick over every tick of every run: the tick alone, without its reads (s).
    median_tick_s: f64,
    /// Every run's median update tick (s).
    run_tick_s: Vec<f64>,
    /// Median over runs of the mean time of a tick together with the reads it asked for (s).
    median_tick_with_reads_s: f64,
    /// Tiles read per run.
    tiles_per_run: u64,
    /// Mean tiles read per tick, and the exact tiles entering the mem regions per tick.
    mean_tiles_per_tick: f64,
    mean_exact_tiles_per_tick: f64,
    /// |tiles read - tiles entering| over the flight, each tick's reads against the tiles that
    /// entered the mem regions (placed by the engine's prefetch policy) one tick before, when
    /// they were asked for: 0 when the engine reads exactly what enters; anything else is waste
    /// or a tile missed.
    tile_excess: u64,
    /// Texel bytes the ticks of this flight wrote other than by tile reads.
    tick_texel_bytes: u64,
}

#[derive(Clone, Debug, Serialize)]
pub struct Report {
    setup: Setup,
    flights: Vec<Flight>,
    /// Slowest flight's median update tick / fastest flight's (goal: at most 1.25).
    direction_ratio: f64,
    /// Texel bytes written by ticks other than by tile reads, all flights (goal: 0).
    tick_texel_bytes: u64,
    /// Every stack level's grid of tiles, every pyramid level whole, and the header.
    formula_bytes: u64,
    /// The image caches' memory as laid out (the mapping a service publishes).
    mapping_bytes: u64,
    engine_peak_resident_bytes: u64,
    /// `VmRSS` just before the clipmap was built (the program itself).
    vm_rss_before_bytes: u64,
    vm_hwm_bytes: u64,
    /// (VmHWM - VmRSS before) / formula (goal: at most 1.1).
    resident_ratio: f64,
    settle_ticks: usize,
    settle_s: f64,
    /// `rgba8` and `l32f` flown side by side (same flights, ticks taking turns).
    formats: Vec<FormatRow>,
    /// `l32f`'s update tick time per tile over `rgba8`'s (goal: at most 1.1).
    l32f_vs_rgba8_tick_per_tile: f64,
}

/// One texel format of the side-by-side flights.
#[derive(Clone, Debug, Serialize)]
struct FormatRow {
    /// Texel format (`rgba8`, `l32f`).
    format: String,
    /// What the texels are.
    source: &'static str,
    /// Median over runs of the run's update tick time (the tick alone) over the tiles its ticks
    /// took (s a tile).
    tick_per_tile_s: f64,
    /// Each run's tick time per tile (s).
    run_tick_per_tile_s: Vec<f64>,
    /// Median update tick over every tick of every run (s).
    median_tick_s: f64,
    /// Tiles the ticks took, all runs.
    tiles: u64,
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return 0.0;
    }
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        (s[n / 2 - 1] + s[n / 2]) / 2.0
    }
}

/// `VmHWM` (peak resident set) of this process, in bytes.
fn vm_hwm() -> anyhow::Result<u64> {
    proc_status("VmHWM:")
}

/// A size field (`VmHWM:`, `VmRSS:`) of `/proc/self/status`, in bytes.
fn proc_status(field: &str) -> anyhow::Result<u64> {
    let status = std::fs::read_to_string("/proc/self/status").context("reading /proc/self/status")?;
    let line =
        status.lines().find(|l| l.starts_with(field)).with_context(|| format!("no {field} in /proc/self/status"))?;
    let kib: u64 = line.split_whitespace().nth(1).with_context(|| format!("{field} without a value"))?.parse()?;
    Ok(kib * 1024)
}

/// Each level's mem region (tiles) for level-0 centre `c` moving `v` texels a tick, placed as the
/// engine places it: its prefetch policy (`Settings::prefetch`, ring by default) over the level's
/// tex region and velocity, given the level's mem region of the tick before (`previous`).
fn mem_regions(
    desc: &TextureDesc,
    grids: &[[u64; 2]],
    policy: &dyn Prefetch,
    c: [i64; 2],
    v: [i64; 2],
    align: u64,
    previous: &[Rect],
) -> Vec<Rect> {
    (0..desc.level_count())
        .map(|k| {
            let l = desc.level(k as u32);
            let shape = LevelShape { size: l.size, tile: l.tile, clip: desc.clip_size(), grid: grids[k], wrap: false };
            let k32 = k as u32;
            let lv = v.map(|x| if x != 0 && (x >> k32) == 0 { x.signum() } else { x >> k32 });
            let tex = shape.frame(aligned_centre(c, k32, align), desc.invalid_border(), lv).tex;
            policy.mem_region(&shape, tex, lv, previous.get(k).copied().unwrap_or(Rect::EMPTY))
        })
        .collect()
}

/// Tiles in `now` and not in `before`, over all levels.
fn entering(now: &[Rect], before: &[Rect]) -> u64 {
    now.iter().zip(before).map(|(n, b)| n.area() - n.intersect(b).area().min(n.area())).sum()
}

/// The image caches' formula: every stack level's grid of tiles, every pyramid level's texels,
/// and the 8 KiB header.
pub fn formula_bytes(desc: &TextureDesc, grids: &[[u64; 2]]) -> u64 {
    let bpt = desc.bytes_per_texel() as u64;
    8192 + (0..desc.level_count() as u32)
        .map(|k| {
            let l = desc.level(k);
            if desc.is_stack(k) {
                grids[k as usize][0] * grids[k as usize][1] * desc.tile_bytes(k) as u64
            } else {
                l.size[0] * l.size[1] * bpt
            }
        })
        .sum::<u64>()
}

/// The sizes `clipbench engine` flies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Size {
    /// 2^26 texels, clip 2048 (the goal's case).
    Full,
    /// 2^20 texels, clip 512.
    Quick,
    /// 2^12 texels, clip 128: checks that the benchmark runs, measures nothing worth reading.
    Smoke,
}

pub fn engine(size: Size, runs: usize, centre_alignment: u64, size_log2: Option<u32>) -> anyhow::Result<Report> {
    let mut setup = if size == Size::Smoke {
        Setup {
            size: 1 << 12,
            clip: 128,
            tile: 32,
            border: 8,
            bytes_per_texel: 4,
            speed: 8,
            frames_per_run: 4,
            runs,
            centre_alignment,
        }
    } else if size == Size::Quick {
        Setup {
            size: 1 << 20,
            clip: 512,
            tile: 128,
            border: 8,
            bytes_per_texel: 4,
            speed: 32,
            frames_per_run: 8,
            runs,
            centre_alignment,
        }
    } else {
        Setup {
            size: 1 << 26,
            clip: 2048,
            tile: 256,
            border: 8,
            bytes_per_texel: 4,
            speed: 64,
            frames_per_run: 32,
            runs,
            centre_alignment,
        }
    };
    if let Some(n) = size_log2 {
        setup.size = 1 << n;
    }
    let runs = runs.max(1);
    let desc = TextureDesc::new([setup.size; 2], setup.clip, TexelFormat::RGBA8, [setup.tile; 2])?
        .with_invalid_border(setup.border)?;
    let mut settings = Settings { budget_ns: None, centre_alignment: setup.centre_alignment, ..Settings::default() };
    settings.limits.max_pending_reads = 4096;
    settings.limits.max_ready_reads = 4096;
    let grids = Clipmap::grids(&desc, &settings);
    let policy = settings.prefetch.policy();
    // The adaptive policy's regions depend on the latency it measures: the engine's own regions
    // are the model then (the count still shows any tile read twice or read without entering).
    let adaptive = settings.prefetch == clipmap::paging::PrefetchKind::Adaptive;
    let formula = formula_bytes(&desc, &grids);
    let source: Arc<dyn TileSource> = Arc::new(HashSource::new(desc.clone()));
    let rss_before = proc_status("VmRSS:")?;
    let mut map = Clipmap::new(source, settings.clone())?;
    let mapping_bytes = map.resident_bytes();

    let mut c = [(setup.size / 2) as i64; 2];
    let started = Instant::now();
    let mut settle_ticks = 0;
    loop {
        let r = map.tick(c, Some([0, 0]));
        settle_ticks += 1;
        if r.min_lod == 0.0 && settle_ticks > 1 {
            break;
        }
        anyhow::ensure!(settle_ticks < 100, "the clipmap did not fill in 100 ticks (min LOD {})", r.min_lod);
        map.wait_for_reads();
    }
    let settle_s = started.elapsed().as_secs_f64();
    // The engine's mem regions as of its last tick (the settled, still centre).
    let mut last = if adaptive {
        map.mem_regions()
    } else {
        mem_regions(&desc, &grids, policy, c, [0, 0], setup.centre_alignment, &[])
    };

    let d = setup.speed;
    let align = setup.centre_alignment;
    // The three directions take turns within every run (in a rotating order), so that whatever
    // the machine does meanwhile falls on all three alike.
    let dirs: [(&'static str, [i64; 2]); 3] = [("+s", [d, 0]), ("+t", [0, d]), ("diagonal", [d, d])];
    #[derive(Default)]
    struct Acc {
        run_tick: Vec<f64>,
        run_with_reads: Vec<f64>,
        all_ticks: Vec<f64>,
        tiles: u64,
        exact: u64,
        n: u64,
        tiles_per_run: u64,
        copied: u64,
    }
    let mut acc: Vec<Acc> = (0..3).map(|_| Acc::default()).collect();
    for run in 0..runs {
        for i in 0..3 {
            let which = (i + run) % 3;
            let v = dirs[which].1;
            // One untimed tick to turn the mem regions towards the motion and fetch ahead.
            map.tick([c[0] + v[0], c[1] + v[1]], Some(v));
            map.wait_for_reads();
            c = [c[0] + v[0], c[1] + v[1]];
            // A tick asks for the tiles that entered its mem regions; the next tick takes them.
            let now = if adaptive { map.mem_regions() } else { mem_regions(&desc, &grids, policy, c, v, align, &last) };
            let mut asked = entering(&now, &last);
            last = now;
            let copied0 = map.stats().tick_texel_bytes;
            let a = &mut acc[which];
            let (mut secs, mut ticks, mut run_tiles) = (0f64, Vec::new(), 0u64);
            for _ in 0..setup.frames_per_run {
                let next = [c[0] + v[0], c[1] + v[1]];
                let t = Instant::now();
                let r = map.tick(next, Some(v));
                let dt_tick = t.elapsed().as_secs_f64();
                map.wait_for_reads();
                secs += t.elapsed().as_secs_f64();
                ticks.push(dt_tick);
                anyhow::ensure!(r.min_lod == 0.0, "a level fell behind during the steady flight: {r:?}");
                // The tiles taken now are those that entered the mem regions one tick ago.
                a.exact += asked;
                a.tiles += r.tiles_read;
                run_tiles += r.tiles_read;
                a.n += 1;
                let now = if adaptive {
                    map.mem_regions()
                } else {
                    mem_regions(&desc, &grids, policy, next, v, align, &last)
                };
                asked = entering(&now, &last);
                last = now;
                c = next;
            }
            a.tiles_per_run = run_tiles;
            a.run_tick.push(median(&ticks));
            a.all_ticks.extend(ticks);
            a.run_with_reads.push(secs / setup.frames_per_run as f64);
            a.copied += map.stats().tick_texel_bytes - copied0;
        }
    }
    let flights: Vec<Flight> = dirs
        .iter()
        .zip(acc)
        .map(|(&(direction, _), a)| Flight {
            direction,
            median_tick_s: median(&a.all_ticks),
            run_tick_s: a.run_tick,
            median_tick_with_reads_s: median(&a.run_with_reads),
            tiles_per_run: a.tiles_per_run,
            mean_tiles_per_tick: a.tiles as f64 / a.n.max(1) as f64,
            mean_exact_tiles_per_tick: a.exact as f64 / a.n.max(1) as f64,
            tile_excess: a.tiles.abs_diff(a.exact),
            tick_texel_bytes: a.copied,
        })
        .collect();
    let engine_peak = map.stats().peak_resident_bytes;
    let hwm = vm_hwm()?;
    let tick_texel_bytes = map.stats().tick_texel_bytes;
    drop(map);
    let formats = side_by_side(&setup, &desc, settings, runs)?;
    let tpt = |f: &str| formats.iter().find(|r| r.format == f).map_or(0.0, |r| r.tick_per_tile_s);
    let slowest = flights.iter().map(|f| f.median_tick_s).fold(0.0, f64::max);
    let fastest = flights.iter().map(|f| f.median_tick_s).fold(f64::INFINITY, f64::min);
    Ok(Report {
        setup,
        flights,
        direction_ratio: if fastest > 0.0 { slowest / fastest } else { 0.0 },
        tick_texel_bytes,
        formula_bytes: formula,
        mapping_bytes,
        engine_peak_resident_bytes: engine_peak,
        vm_rss_before_bytes: rss_before,
        vm_hwm_bytes: hwm,
        resident_ratio: hwm.saturating_sub(rss_before) as f64 / formula as f64,
        settle_ticks,
        settle_s,
        l32f_vs_rgba8_tick_per_tile: if tpt("rgba8") > 0.0 { tpt("l32f") / tpt("rgba8") } else { 0.0 },
        formats,
    })
}

/// Flies `rgba8` colours (the hash texture) and `l32f` heights (the height verification texture)
/// of the shape of `desc` side by side: both clipmaps settle at the centre, then every run flies
/// the three directions, each tick of one format followed by the same tick of the other (the
/// order swapping each run), so that whatever the machine does meanwhile falls on both alike.
fn side_by_side(setup: &Setup, desc: &TextureDesc, settings: Settings, runs: usize) -> anyhow::Result<Vec<FormatRow>> {
    let colour: Arc<dyn TileSource> = Arc::new(HashSource::new(desc.clone()));
    let heights: Arc<dyn TileSource> =
        Arc::new(HeightSource::new(desc.clone(), clipmap::height::HeightFormat::VERIFICATION));
    anyhow::ensure!(
        heights.desc().bytes_per_texel() == desc.bytes_per_texel(),
        "l32f and rgba8 texels differ in size ({} and {} bytes): the comparison is per byte",
        heights.desc().bytes_per_texel(),
        desc.bytes_per_texel()
    );
    let sources = [("rgba8", "hash texture", colour), ("l32f", "height verification texture", heights)];
    let mut maps = Vec::new();
    for (_, _, src) in &sources {
        maps.push(Clipmap::new(src.clone(), settings.clone())?);
    }
    let mut c = [(setup.size / 2) as i64; 2];
    for map in &mut maps {
        for tick in 0.. {
            let r = map.tick(c, Some([0, 0]));
            if r.min_lod == 0.0 && tick > 0 {
                break;
            }
            anyhow::ensure!(tick < 100, "the clipmap did not fill in 100 ticks (min LOD {})", r.min_lod);
            map.wait_for_reads();
        }
    }
    let d = setup.speed;
    let dirs = [[d, 0], [0, d], [d, d]];
    let mut run_secs = vec![Vec::new(); maps.len()];
    let mut run_tiles = vec![Vec::new(); maps.len()];
    let mut ticks = vec![Vec::new(); maps.len()];
    for run in 0..runs {
        let (mut secs, mut tiles) = (vec![0f64; maps.len()], vec![0u64; maps.len()]);
        for i in 0..3 {
            let v = dirs[(i + run) % 3];
            for step in 0..=setup.frames_per_run {
                let next = [c[0] + v[0], c[1] + v[1]];
                for j in 0..maps.len() {
                    let m = if run % 2 == 0 { j } else { maps.len() - 1 - j };
                    let map = &mut maps[m];
                    let t = Instant::now();
                    let r = map.tick(next, Some(v));
                    let dt = t.elapsed().as_secs_f64();
                    map.wait_for_reads();
                    // The first tick of a direction turns the mem regions: not timed.
                    if step > 0 {
                        anyhow::ensure!(r.min_lod == 0.0, "{}: a level fell behind: {r:?}", sources[m].0);
                        secs[m] += dt;
                        tiles[m] += r.tiles_read;
                        ticks[m].push(dt);
                    }
                }
                c = next;
            }
        }
        for m in 0..maps.len() {
            run_secs[m].push(secs[m]);
            run_tiles[m].push(tiles[m]);
        }
    }
    Ok(sources
        .iter()
        .enumerate()
        .map(|(m, (format, source, _))| {
            let per_tile: Vec<f64> =
                run_secs[m].iter().zip(&run_tiles[m]).map(|(&s, &n)| s / n.max(1) as f64).collect();
            FormatRow {
                format: format.to_string(),
                source,
                tick_per_tile_s: median(&per_tile),
                run_tick_per_tile_s: per_tile,
                median_tick_s: median(&ticks[m]),
                tiles: run_tiles[m].iter().sum(),
            }
        })
        .collect())
}

fn mib(b: f64) -> String {
    format!("{:.1} MiB", b / (1u64 << 20) as f64)
}

pub fn human(r: &Report) -> String {
    use std::fmt::Write;
    let s = &r.setup;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "texture 2^{} texels a side, clip {}, tile {}, {} bytes per texel, border {}; steady flight {} texels per tick, {} ticks x {} runs",
        s.size.trailing_zeros(),
        s.clip,
        s.tile,
        s.bytes_per_texel,
        s.border,
        s.speed,
        s.frames_per_run,
        s.runs
    );
    if s.centre_alignment > 1 {
        let _ = writeln!(o, "level centres aligned to multiples of {} level texels", s.centre_alignment);
    }
    let _ = writeln!(o, "first fill: {} ticks, {:.2} s (reads included)", r.settle_ticks, r.settle_s);
    let _ = writeln!(
        o,
        "{:<9} {:>12} {:>14} {:>12} {:>14} {:>12}",
        "flight", "tick", "tick+reads", "tiles/tick", "entering/tick", "tick bytes"
    );
    for f in &r.flights {
        let _ = writeln!(
            o,
            "{:<9} {:>10.3}ms {:>12.3}ms {:>12.2} {:>14.2} {:>12}",
            f.direction,
            f.median_tick_s * 1e3,
            f.median_tick_with_reads_s * 1e3,
            f.mean_tiles_per_tick,
            f.mean_exact_tiles_per_tick,
            f.tick_texel_bytes
        );
    }
    let _ =
        writeln!(o, "direction ratio (slowest / fastest median update tick): {:.3}  (goal <= 1.25)", r.direction_ratio);
    let _ = writeln!(o, "texel bytes written by ticks: {}  (goal 0)", r.tick_texel_bytes);
    let _ = writeln!(
        o,
        "resident: VmHWM growth {} against the formula {} (mapping as laid out {}): ratio {:.3}  (goal <= 1.1)",
        mib(r.vm_hwm_bytes.saturating_sub(r.vm_rss_before_bytes) as f64),
        mib(r.formula_bytes as f64),
        mib(r.mapping_bytes as f64),
        r.resident_ratio,
    );
    let _ = writeln!(o, "side by side (same flights, ticks taking turns):");
    for f in &r.formats {
        let _ = writeln!(
            o,
            "  {:<6} {:<28} tick {:>8.3}ms, {:>8.3}µs a tile ({} tiles)",
            f.format,
            f.source,
            f.median_tick_s * 1e3,
            f.tick_per_tile_s * 1e6,
            f.tiles
        );
    }
    let _ = writeln!(o, "l32f / rgba8 update tick time per tile: {:.3}  (goal <= 1.1)", r.l32f_vs_rgba8_tick_per_tile);
    o
}
