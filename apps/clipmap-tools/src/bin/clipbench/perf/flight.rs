//! Per-frame cost of one continuous flight with the same per-level windows, three ways:
//! (a) the engine, incremental: one tick per frame plus waiting for the reads it started;
//! (b) GDAL: every level's window of every frame read from a tiled GeoTIFF with overviews, in
//!     one Python process that times itself (so process start is not counted);
//! (c) the engine without incremental updates: every frame a fresh clipmap over the same file
//!     source, ticked until every level is complete (tiles read and windows filled anew).
//!
//! All three start warm on the flight's first frame (untimed) and read the prepared files from
//! the page cache: each run reads its side's files once just before it ([`warm`]; the pyramid
//! for (a) and (c), the GeoTIFF for (b)), since a virtual machine may page out file pages left
//! untouched for a few seconds. The windows are the engine's tex regions ([`tex_region`] of each level's
//! centre, level 0's shifted right by the level).

use super::data::{warm, Gdal, Prepared};
use super::{quantile, Size, Stat};
use anyhow::Context;
use clipmap::clip::{Clipmap, Settings};
use clipmap::geom::{default_centre, tex_region};
use clipmap::limits::Limits;
use clipmap::plan;
use clipmap::source::{FileSource, TileSource};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

const SCRIPT: &str = include_str!("gdal_frames.py");

/// What the flight comparison measured.
#[derive(Clone, Debug, Serialize)]
pub struct Flight {
    pub texture: u64,
    pub clip: u64,
    pub levels: usize,
    /// Timed frames per run (after the untimed first frame).
    pub frames: usize,
    /// Level-0 texels per frame.
    pub velocity: [i64; 2],
    /// Bytes of all levels' windows (what GDAL and a full reload deliver every frame).
    pub window_bytes: u64,
    /// Mean per-frame seconds of each run.
    pub engine_frame_s: Stat,
    /// The update tick alone (without waiting for the reads it started), mean per run.
    pub engine_tick_s: Stat,
    pub engine_frame_p50_s: f64,
    pub engine_frame_p99_s: f64,
    /// Frames on which the engine could not show level 0 (min LOD above 0): should be 0.
    pub engine_degraded_frames: u64,
    /// Frames reloaded per run (every `reload_every`-th frame of the flight).
    pub reload_frames: usize,
    pub reload_every: usize,
    pub reload_frame_s: Stat,
    /// The part of a reload spent building the clipmap (its read-queue runtime, window buffers).
    pub reload_construct_s: Stat,
    pub speedup_vs_full_reload: Stat,
    pub gdal_frame_s: Option<Stat>,
    pub gdal_frame_p50_s: Option<f64>,
    pub gdal_frame_p99_s: Option<f64>,
    pub speedup_vs_gdal: Option<Stat>,
    pub gdal_version: Option<String>,
    pub gdal_cache_max_bytes: Option<u64>,
    /// Why GDAL was not measured, if it was not.
    pub gdal_note: String,
}

fn settings() -> Settings {
    let mut s = Settings { budget_ns: None, ..Settings::default() };
    s.limits.max_pending_reads = 4096;
    s.limits.max_ready_reads = 4096;
    s
}

/// Ticks at `c` until every level is complete; returns the ticks taken.
fn fill(map: &mut Clipmap, c: [i64; 2]) -> anyhow::Result<usize> {
    for ticks in 1..=100 {
        if map.tick(c, Some([0, 0])).min_lod == 0.0 {
            return Ok(ticks);
        }
        map.wait_for_reads();
    }
    anyhow::bail!("the clipmap did not fill in 100 ticks")
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

pub fn measure(prepared: &Prepared, size: Size, runs: usize, gdal: Result<&Gdal, &str>) -> anyhow::Result<Flight> {
    let (frames, velocity, reload_max) = match size {
        Size::Full => (240usize, [16i64, 8], 40usize),
        Size::Quick => (60, [8, 4], 15),
        Size::Smoke => (8, [4, 2], 8),
    };
    let n = prepared.size;
    let loaded = plan::load_clip_texture(&prepared.ct, &plan::Options::default())?;
    let rendered = loaded.render();
    let plan = loaded.plan.with_context(|| format!("{}: {rendered}", prepared.ct.display()))?;
    let source: Arc<dyn TileSource> = Arc::new(FileSource::new(plan, &Limits::default())?);
    let desc = source.desc().clone();
    let clip = desc.clip_size();
    let c0 = [0, 1].map(|a| n as i64 / 2 - frames as i64 * velocity[a] / 2);
    let centre = |i: usize| [c0[0] + i as i64 * velocity[0], c0[1] + i as i64 * velocity[1]];

    // (a) incremental.
    let (mut eng_runs, mut eng_all, mut degraded, mut tick_runs) = (Vec::new(), Vec::new(), 0u64, Vec::new());
    for _ in 0..runs {
        warm(&prepared.root)?;
        let mut map = Clipmap::new(Arc::clone(&source), settings())?;
        fill(&mut map, centre(0))?;
        let (mut times, mut ticks) = (Vec::with_capacity(frames), Vec::with_capacity(frames));
        for i in 1..=frames {
            let t = Instant::now();
            let r = map.tick(centre(i), Some(velocity));
            ticks.push(t.elapsed().as_secs_f64());
            map.wait_for_reads();
            times.push(t.elapsed().as_secs_f64());
            if r.min_lod > 0.0 {
                degraded += 1;
            }
        }
        eng_runs.push(mean(&times));
        tick_runs.push(mean(&ticks));
        eng_all.extend(times);
    }

    // (c) full reload every frame.
    let every = frames.div_ceil(reload_max).max(1);
    let reload_at: Vec<usize> = (1..=frames).filter(|i| i % every == 0).collect();
    let (mut reload_runs, mut construct_runs) = (Vec::new(), Vec::new());
    for _ in 0..runs {
        warm(&prepared.root)?;
        let (mut total, mut construct) = (Vec::new(), Vec::new());
        for &i in &reload_at {
            let t = Instant::now();
            let mut map = Clipmap::new(Arc::clone(&source), settings())?;
            construct.push(t.elapsed().as_secs_f64());
            fill(&mut map, centre(i))?;
            total.push(t.elapsed().as_secs_f64());
            drop(map);
        }
        reload_runs.push(mean(&total));
        construct_runs.push(mean(&construct));
    }
    let speedup_vs_full_reload = Stat::of(reload_runs.iter().zip(&eng_runs).map(|(r, e)| r / e).collect());

    // (b) GDAL.
    let sizes: Vec<u64> = desc.levels().iter().map(|l| l.size[0]).collect();
    let windows: Vec<Vec<[i64; 4]>> = (0..=frames)
        .map(|i| {
            (0..sizes.len() as u32)
                .map(|k| {
                    let l = desc.level(k);
                    let r = tex_region(l.size, clip, default_centre(centre(i), k));
                    [r.s0, r.t0, r.width() as i64, r.height() as i64]
                })
                .collect()
        })
        .collect();
    let window_bytes = windows[0].iter().map(|w| (w[2] * w[3]) as u64 * desc.bytes_per_texel() as u64).sum();
    let mut gdal_note = String::new();
    let gdal_out = match (gdal, &prepared.tif) {
        (Ok(g), Some(tif)) => Some(run_gdal(g, tif, &sizes, &windows, runs)?),
        (Err(why), _) => {
            gdal_note = why.to_string();
            None
        }
        (Ok(_), None) => {
            gdal_note = "no GeoTIFF prepared".into();
            None
        }
    };
    let (gdal_frame_s, gdal_p50, gdal_p99, speedup_vs_gdal, gdal_version, gdal_cache) = match gdal_out {
        Some(g) => {
            let per_run: Vec<f64> = g.runs.iter().map(|r| mean(r)).collect();
            let all: Vec<f64> = g.runs.iter().flatten().copied().collect();
            let speedup = Stat::of(per_run.iter().zip(&eng_runs).map(|(g, e)| g / e).collect());
            (
                Some(Stat::of(per_run)),
                Some(quantile(&all, 0.5)),
                Some(quantile(&all, 0.99)),
                Some(speedup),
                Some(g.version),
                Some(g.cache_max_bytes),
            )
        }
        None => (None, None, None, None, None, None),
    };
    Ok(Flight {
        texture: n,
        clip,
        levels: sizes.len(),
        frames,
        velocity,
        window_bytes,
        engine_frame_p50_s: quantile(&eng_all, 0.5),
        engine_frame_p99_s: quantile(&eng_all, 0.99),
        engine_frame_s: Stat::of(eng_runs),
        engine_tick_s: Stat::of(tick_runs),
        engine_degraded_frames: degraded,
        reload_frames: reload_at.len(),
        reload_every: every,
        reload_frame_s: Stat::of(reload_runs),
        reload_construct_s: Stat::of(construct_runs),
        speedup_vs_full_reload,
        gdal_frame_s,
        gdal_frame_p50_s: gdal_p50,
        gdal_frame_p99_s: gdal_p99,
        speedup_vs_gdal,
        gdal_version,
        gdal_cache_max_bytes: gdal_cache,
        gdal_note,
    })
}

#[derive(serde::Deserialize)]
struct GdalOut {
    version: String,
    cache_max_bytes: u64,
    runs: Vec<Vec<f64>>,
}

fn run_gdal(
    g: &Gdal,
    tif: &std::path::Path,
    sizes: &[u64],
    windows: &[Vec<[i64; 4]>],
    runs: usize,
) -> anyhow::Result<GdalOut> {
    let dir = tif.parent().context("the GeoTIFF has no directory")?;
    let script = dir.join("gdal_frames.py");
    std::fs::write(&script, SCRIPT)?;
    let spec = dir.join("frames.json");
    let body = serde_json::json!({ "tif": tif, "sizes": sizes, "runs": runs, "frames": windows });
    std::fs::write(&spec, serde_json::to_vec(&body)?)?;
    let what = format!("the GDAL reader ({} {})", g.python.display(), script.display());
    warm(tif)?;
    super::child_json(std::process::Command::new(&g.python).arg(&script).arg(&spec), &what)
}
