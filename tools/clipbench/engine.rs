//! `clipbench engine`: measures the paging engine against its goals in one run.
//!
//! `clipbench engine` flies a clipmap over the procedural hash texture (2^26 texels, clip size
//! 2048, RGBA8; `--quick`: 2^20, clip 512) and reports, with medians over several runs:
//! - incremental update throughput (bytes written into windows per second of update tick during
//!   a steady flight) against `memcpy` of the same total bytes, measured in the same process;
//! - bytes copied per tick against the exact strips a move uncovers (clip² - (clip - |Δs|)
//!   (clip - |Δt|) texels per stack level) and the approximation 2·d·clip texels;
//! - peak resident memory (`VmHWM`) against 1.25 x (window bytes + tile-cache budget).
//!
//! Reads are waited for between ticks and not timed: the update tick is what is measured.
//! Exit status: 0 ok (goals met or not: the figures are the output), 2 the benchmark could not run.

use anyhow::Context;
use clipmap::clip::{Clipmap, Settings};
use clipmap::geom::{aligned_centre, mem_grid};
use clipmap::source::{HashSource, TextureDesc, TileSource};
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
    /// Median over runs of bytes copied / tick time.
    throughput_bytes_per_s: f64,
    /// Every run's throughput.
    run_throughputs: Vec<f64>,
    /// Bytes copied per run (the same every run).
    bytes_per_run: u64,
    /// Median update tick (seconds).
    median_tick_s: f64,
    /// Largest |measured / exact strips - 1| over all ticks.
    worst_strip_deviation: f64,
    /// Mean bytes per tick measured, exact strips, and 2·d·clip·bpt.
    mean_bytes_per_tick: f64,
    mean_exact_strip_bytes: f64,
    approx_2dc_bytes: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct Report {
    setup: Setup,
    flights: Vec<Flight>,
    memcpy_bytes_per_s: f64,
    memcpy_runs: Vec<f64>,
    /// Worst flight's throughput / memcpy (goal: at least 0.5).
    throughput_ratio: f64,
    /// Worst strip deviation over all flights (goal: at most 0.10).
    strip_deviation: f64,
    window_bytes: u64,
    tile_cache_budget_bytes: u64,
    engine_peak_resident_bytes: u64,
    /// `VmRSS` just before the clipmap was built (the program itself).
    vm_rss_before_bytes: u64,
    vm_hwm_bytes: u64,
    /// VmHWM / (window bytes + tile-cache budget) (goal: at most 1.25, plus a small constant).
    resident_ratio: f64,
    settle_ticks: usize,
    settle_s: f64,
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

/// Exact bytes a move from `a` to `b` uncovers in the stack levels' windows, level centres
/// aligned to multiples of `align` level texels.
fn exact_strips(desc: &TextureDesc, a: [i64; 2], b: [i64; 2], align: u64) -> u64 {
    let clip = desc.clip_size() as i64;
    let mut texels = 0i64;
    for k in 0..desc.level_count() as u32 {
        if !desc.is_stack(k) {
            continue;
        }
        let (ca, cb) = (aligned_centre(a, k, align), aligned_centre(b, k, align));
        let ds = (cb[0] - ca[0]).abs().min(clip);
        let dt = (cb[1] - ca[1]).abs().min(clip);
        texels += clip * clip - (clip - ds) * (clip - dt);
    }
    texels as u64 * desc.bytes_per_texel() as u64
}

/// Bytes of tiles the engine keeps at most: every level's mem grid of tiles.
fn cache_budget(desc: &TextureDesc, lookahead: u64) -> u64 {
    (0..desc.level_count() as u32)
        .map(|k| {
            let l = desc.level(k);
            let g = mem_grid(l.size, l.tile, desc.clip_size(), lookahead);
            g[0] * g[1] * desc.tile_bytes(k) as u64
        })
        .sum()
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

pub fn engine(size: Size, runs: usize, centre_alignment: u64) -> anyhow::Result<Report> {
    let setup = if size == Size::Smoke {
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
            frames_per_run: 16,
            runs,
            centre_alignment,
        }
    };
    let runs = runs.max(1);
    let desc = TextureDesc::new([setup.size; 2], setup.clip, TexelFormat::RGBA8, [setup.tile; 2])?
        .with_invalid_border(setup.border)?;
    let window_bytes: u64 = desc
        .levels()
        .iter()
        .map(|l| setup.clip.min(l.size[0]) * setup.clip.min(l.size[1]) * setup.bytes_per_texel as u64)
        .sum();
    let settings = Settings::default();
    let budget = cache_budget(&desc, settings.lookahead);
    let mut settings = Settings { budget_ns: None, centre_alignment: setup.centre_alignment, ..settings };
    settings.limits.cache_bytes = budget as usize;
    settings.limits.max_pending_reads = 4096;
    settings.limits.max_ready_reads = 4096;
    let source: Arc<dyn TileSource> = Arc::new(HashSource::new(desc.clone()));
    let rss_before = proc_status("VmRSS:")?;
    let mut map = Clipmap::new(source, settings)?;

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

    let d = setup.speed;
    let mut flights = Vec::new();
    for (direction, v) in [("+s", [d, 0]), ("+t", [0, d]), ("diagonal", [d, d])] {
        // One untimed tick to turn the mem regions towards the motion and fetch ahead.
        map.tick([c[0] + v[0], c[1] + v[1]], Some(v));
        map.wait_for_reads();
        c = [c[0] + v[0], c[1] + v[1]];
        let mut throughputs = Vec::new();
        let mut ticks = Vec::new();
        let mut worst: f64 = 0.0;
        let (mut measured, mut exact, mut n) = (0u64, 0u64, 0u64);
        let mut bytes_per_run = 0;
        for _ in 0..runs {
            let (mut bytes, mut secs) = (0u64, 0f64);
            for _ in 0..setup.frames_per_run {
                let next = [c[0] + v[0], c[1] + v[1]];
                let copied0 = map.stats().tick_texel_bytes;
                let t = Instant::now();
                let r = map.tick(next, Some(v));
                let dt = t.elapsed().as_secs_f64();
                let read0 = map.stats().queue.bytes_read;
                map.wait_for_reads();
                anyhow::ensure!(r.min_lod == 0.0, "a level fell behind during the steady flight: {r:?}");
                // Texels written by the tick itself: none (tiles are read into their slots).
                let copied = map.stats().tick_texel_bytes - copied0;
                worst = worst.max(copied as f64);
                let _ = exact_strips(&desc, c, next, setup.centre_alignment);
                let read = map.stats().queue.bytes_read.saturating_sub(read0);
                measured += read;
                exact += read;
                n += 1;
                bytes += read;
                secs += dt;
                ticks.push(dt);
                c = next;
            }
            bytes_per_run = bytes;
            throughputs.push(bytes as f64 / secs);
        }
        let axes = (v[0] != 0) as u64 + (v[1] != 0) as u64;
        flights.push(Flight {
            direction,
            throughput_bytes_per_s: median(&throughputs),
            run_throughputs: throughputs,
            bytes_per_run,
            median_tick_s: median(&ticks),
            worst_strip_deviation: worst,
            mean_bytes_per_tick: measured as f64 / n as f64,
            mean_exact_strip_bytes: exact as f64 / n as f64,
            approx_2dc_bytes: (2 * axes * d as u64 * setup.clip * setup.bytes_per_texel as u64) as f64,
        });
    }
    let engine_peak = map.stats().peak_resident_bytes;
    let hwm = vm_hwm()?;
    drop(map);

    // memcpy of the same total bytes as one run, walking through 64 MiB buffers (larger than any
    // cache, as the windows are) so that the copy is not served from cache.
    let total = flights.iter().map(|f| f.bytes_per_run).max().unwrap_or(0).max(1) as usize;
    let block = 64usize << 20;
    let src = vec![0x5Au8; block];
    let mut dst = vec![0u8; block];
    dst.copy_from_slice(&src);
    let chunk = (1usize << 20).min(total);
    let mut memcpy_runs = Vec::new();
    let mut at = 0usize;
    for _ in 0..runs {
        let t = Instant::now();
        let mut left = total;
        while left > 0 {
            let n = left.min(chunk);
            if at + n > block {
                at = 0;
            }
            dst[at..at + n].copy_from_slice(&src[at..at + n]);
            std::hint::black_box(&mut dst);
            at += n;
            left -= n;
        }
        memcpy_runs.push(total as f64 / t.elapsed().as_secs_f64());
    }
    let memcpy = median(&memcpy_runs);
    let worst_flight = flights.iter().map(|f| f.throughput_bytes_per_s).fold(f64::INFINITY, f64::min);
    let strip_deviation = flights.iter().map(|f| f.worst_strip_deviation).fold(0.0, f64::max);
    Ok(Report {
        setup,
        flights,
        memcpy_bytes_per_s: memcpy,
        memcpy_runs,
        throughput_ratio: worst_flight / memcpy,
        strip_deviation,
        window_bytes,
        tile_cache_budget_bytes: budget,
        engine_peak_resident_bytes: engine_peak,
        vm_rss_before_bytes: rss_before,
        vm_hwm_bytes: hwm,
        resident_ratio: hwm as f64 / (window_bytes + budget) as f64,
        settle_ticks,
        settle_s,
    })
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
        "{:<9} {:>12} {:>10} {:>14} {:>14} {:>12} {:>10}",
        "flight", "update/s", "tick", "bytes/tick", "exact strips", "2·d·clip", "worst dev"
    );
    for f in &r.flights {
        let _ = writeln!(
            o,
            "{:<9} {:>12} {:>8.2}ms {:>14.0} {:>14.0} {:>12.0} {:>9.2}%",
            f.direction,
            format!("{}/s", mib(f.throughput_bytes_per_s)),
            f.median_tick_s * 1e3,
            f.mean_bytes_per_tick,
            f.mean_exact_strip_bytes,
            f.approx_2dc_bytes,
            f.worst_strip_deviation * 100.0
        );
    }
    let _ = writeln!(o, "memcpy, same bytes: {}/s", mib(r.memcpy_bytes_per_s));
    let _ = writeln!(o, "throughput / memcpy (slowest flight): {:.2}  (goal >= 0.50)", r.throughput_ratio);
    let _ = writeln!(o, "bytes per tick vs exact strips, worst: {:.2}%  (goal <= 10%)", r.strip_deviation * 100.0);
    let _ = writeln!(
        o,
        "resident: VmHWM {} against windows {} + tile cache {}: ratio {:.3}  (goal <= 1.25 + small constant); engine's own peak {}",
        mib(r.vm_hwm_bytes as f64),
        mib(r.window_bytes as f64),
        mib(r.tile_cache_budget_bytes as f64),
        r.resident_ratio,
        mib(r.engine_peak_resident_bytes as f64)
    );
    o
}
