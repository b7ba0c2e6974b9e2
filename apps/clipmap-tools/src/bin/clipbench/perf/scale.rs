//! Scale: a 2^26 x 2^26 procedural texture flown at 1000 level-0 texels per tick along +s, 60
//! ticks a second in real time (each tick starts at its slot; reads run in the background as in
//! the service, straight into their slots), with the default tick budget and load control.
//! Counts the share of ticks after the first second on which level 0 is published
//! (`level0_shown_share`), ticks with disabled levels, late ticks (longer than the tick period)
//! and the throughput; then the
//! flight first with each stack level's mem region sized by hand for its motion (`scale`), then
//! with every default (`scale_default`: the adaptive policy, which sizes its grids from the
//! default budget and its read-ahead from the motion and the reads' latency it measures).

use super::{quantile, Size};
use clipmap::clip::{Clipmap, Settings};
use clipmap::paging::PrefetchKind;
use clipmap_service::{procedural_source, Procedural};
use serde::Serialize;
use std::time::{Duration, Instant};

/// What the real-time flight measured.
#[derive(Clone, Debug, Serialize)]
pub struct Scale {
    /// Extra tile columns read ahead along the motion at level 0 (1 across it; the default
    /// square lookahead when both are 1).
    pub lookahead: u64,
    /// Where the spare tiles go (`ahead` for the mem region sized for the flight).
    pub prefetch: PrefetchKind,
    pub texture: u64,
    pub clip: u64,
    pub tile: u64,
    pub texels_per_tick: i64,
    pub tick_hz: f64,
    pub seconds: f64,
    pub budget_ms: f64,
    pub ticks: u64,
    pub ticks_over_budget: u64,
    pub ticks_with_disabled_levels: u64,
    /// Share of the ticks after the first second on which level 0 is published (min LOD below 1).
    pub level0_shown_share: f64,
    /// Most levels disabled at once.
    pub max_disabled_levels: usize,
    /// Mean min LOD over the ticks (0: level 0 always shown).
    pub mean_min_lod: f64,
    /// Ticks that took longer than the tick period.
    pub late_ticks: u64,
    pub tick_p50_s: f64,
    pub tick_p99_s: f64,
    pub tick_max_s: f64,
    /// Texel bytes the ticks wrote other than by tile reads (0: tiles go straight into slots).
    pub tick_texel_bytes: u64,
    pub tiles_read_per_s: f64,
    /// Level-0 texels the centre moved per second of wall time.
    pub texels_flown_per_s: f64,
    /// CPU time of this process (update tick and tile reads) per second of the flight: 2.0 on two
    /// cores means the machine, not the engine's pacing, is the limit.
    pub cpu_cores_used: f64,
    /// Most bytes the image caches held (their whole mapping).
    pub peak_resident_bytes: u64,
    /// The adaptive policy's grid budget (null for the fixed policies): the default, twice the
    /// lookahead-1 grids, when no flag gives one.
    pub grid_budget_bytes: Option<u64>,
    /// Level 0's paging at the end of the flight (lead, grid, reason).
    pub level0_paging: Option<clipmap::paging::adaptive::LevelPaging>,
    /// The read latency the controller planned with at the end (ticks; 0 for fixed policies).
    pub read_latency_ticks: f64,
}

/// The flight with each stack level's mem region sized for its motion (what a configuration for
/// this flight gives with `mem_region_size`: two ticks of motion read ahead along +s, the default
/// one spare tile across it), and the same flight with every default (no tuning: the adaptive
/// policy).
pub fn measure(size: Size) -> anyhow::Result<(Scale, Scale)> {
    let (clip, tile, seconds, again) = match size {
        Size::Full => (2048, 256, 60.0, 20.0),
        Size::Quick => (2048, 256, 5.0, 3.0),
        Size::Smoke => (256, 64, 0.5, 0.5),
    };
    let ahead = fly(clip, tile, seconds, Some((2 * 1000u64).div_ceil(tile)))?;
    let plain = fly(clip, tile, again, None)?;
    Ok((ahead, plain))
}

fn fly(clip: u64, tile: u64, seconds: f64, ahead: Option<u64>) -> anyhow::Result<Scale> {
    let texture = 1u64 << 26;
    let plain = procedural_source(Procedural::Hash, texture, clip, tile)?;
    // A mem region sized for this flight puts its spare tiles ahead of the motion (the `ahead`
    // prefetch policy, `--prefetch ahead`): the default ring would split them around the window
    // and read only half as far ahead. The default flight keeps every default.
    let prefetch = if ahead.is_some() { PrefetchKind::Ahead } else { PrefetchKind::default() };
    let settings = Settings { prefetch, ..Settings::default() };
    let source: std::sync::Arc<dyn clipmap::source::TileSource> = match ahead {
        None => plain,
        Some(extra) => {
            // Per stack level: the window's tiles plus one, plus `extra` tiles of two ticks of
            // motion at level 0, halving per level (at least the default one) along s.
            let desc = plain.desc().clone();
            let grids = (0..desc.level_count() as u32)
                .map(|k| {
                    let l = desc.level(k);
                    let across = |a: usize| clip.min(l.size[a]).div_ceil(l.tile[a]) + 1;
                    desc.is_stack(k).then(|| [across(0) + (extra >> k).max(1), across(1) + 1])
                })
                .collect();
            std::sync::Arc::new(clipmap::source::HashSource::new(desc.with_mem_grids(grids)))
        }
    };
    let lookahead = ahead.unwrap_or(settings.lookahead);
    fly_over(source, settings, lookahead, seconds)
}

/// The flight itself over `source` (a 2^26 texture) with `settings`: 1000 level-0 texels a tick
/// along +s at 60 ticks a second for `seconds`, from where the whole flight stays inside the
/// texture, filled first (untimed). `lookahead` is reported as given. `clipbench formats` flies
/// it over pre-encoded block textures.
pub(crate) fn fly_over(
    source: std::sync::Arc<dyn clipmap::source::TileSource>,
    settings: Settings,
    lookahead: u64,
    seconds: f64,
) -> anyhow::Result<Scale> {
    let (texture, clip, tile) = (source.desc().size()[0], source.desc().clip_size(), source.desc().level(0).tile[0]);
    let (speed, hz) = (1000i64, 60.0);
    let prefetch = settings.prefetch;
    let budget_ms = settings.budget_ns.unwrap_or(0) as f64 / 1e6;
    let grid_budget_bytes = Clipmap::grid_budget(source.desc(), &settings);
    let mut map = Clipmap::new(source, settings)?;
    // Start where the whole flight stays inside the texture, filled (untimed).
    let mut c = [(texture / 4) as i64, (texture / 2) as i64];
    for _ in 0..100 {
        if map.tick(c, Some([0, 0])).min_lod == 0.0 {
            break;
        }
        map.wait_for_reads();
    }
    let before = map.stats().clone();
    let period = Duration::from_secs_f64(1.0 / hz);
    let ticks = (seconds * hz) as u64;
    let (mut times, mut over, mut disabled, mut max_disabled, mut lod_sum, mut late) =
        (Vec::new(), 0u64, 0u64, 0usize, 0.0, 0u64);
    let (mut shown, mut after_first_second) = (0u64, 0u64);
    let cpu_before = super::proc_self().cpu_s;
    let start = Instant::now();
    for i in 0..ticks {
        std::thread::sleep((start + period * i as u32).saturating_duration_since(Instant::now()));
        c[0] += speed;
        let t = Instant::now();
        let r = map.tick(c, Some([speed, 0]));
        let dt = t.elapsed();
        times.push(dt.as_secs_f64());
        late += (dt > period) as u64;
        over += r.over_budget as u64;
        disabled += !r.disabled_levels.is_empty() as u64;
        max_disabled = max_disabled.max(r.disabled_levels.len());
        lod_sum += r.min_lod;
        if i >= hz as u64 {
            after_first_second += 1;
            shown += u64::from(r.min_lod < 1.0);
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let cpu = super::proc_self().cpu_s - cpu_before;
    let after = map.stats();
    Ok(Scale {
        lookahead,
        prefetch,
        texture,
        clip,
        tile,
        texels_per_tick: speed,
        tick_hz: hz,
        seconds: wall,
        budget_ms,
        ticks,
        ticks_over_budget: over,
        ticks_with_disabled_levels: disabled,
        level0_shown_share: if after_first_second == 0 { 0.0 } else { shown as f64 / after_first_second as f64 },
        max_disabled_levels: max_disabled,
        mean_min_lod: lod_sum / ticks.max(1) as f64,
        late_ticks: late,
        tick_p50_s: quantile(&times, 0.5),
        tick_p99_s: quantile(&times, 0.99),
        tick_max_s: quantile(&times, 1.0),
        tick_texel_bytes: after.tick_texel_bytes - before.tick_texel_bytes,
        tiles_read_per_s: (after.tiles_read - before.tiles_read) as f64 / wall,
        texels_flown_per_s: (speed as u64 * ticks) as f64 / wall,
        cpu_cores_used: cpu / wall,
        peak_resident_bytes: after.peak_resident_bytes,
        grid_budget_bytes,
        level0_paging: after.paging.first().copied(),
        read_latency_ticks: after.read_latency_ticks,
    })
}
