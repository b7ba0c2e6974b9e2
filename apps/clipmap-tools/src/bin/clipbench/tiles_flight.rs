//! The flight of `clipbench tiles` (`tiles.rs`): a clipmap with every default setting over the
//! XYZ service, served by nginx through a relay that holds every request (20 ms by default), flown
//! in real time at 60 ticks a second back and forth along s, as `clipbench remote`'s
//! `remote_flight` flies; first at the stated speed (32 level-0 texels a tick), then faster, for
//! the largest speed at which level 0 is still shown on at least 95 % of the ticks.

use super::serve::{Faults, Proxy};
use super::tiles_peers::Reference;
use clipmap::clip::{Clipmap, Settings};
use clipmap::source::remote::RemoteOptions;
use clipmap::source::tiles::{self, OpenOptions, PyramidOptions, TemplateOptions};
use clipmap::source::TileSource;
use serde::Serialize;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The share of ticks with level 0 shown that a speed must keep.
const SHOWN_GOAL: f64 = 0.95;

/// Ticks a second.
const HZ: f64 = 60.0;

/// One flight at one speed.
#[derive(Clone, Debug, Serialize)]
pub struct Leg {
    pub texels_per_tick: i64,
    /// Ticks after the first second with level 0 shown (min LOD < 1), over those ticks.
    pub level0_shown_share: f64,
    pub mean_min_lod: f64,
    pub ticks: u64,
    pub seconds: f64,
    pub ticks_with_disabled_levels: u64,
    /// Requests the flight made (tiles fetched).
    pub requests: u64,
}

/// What the flights measured.
#[derive(Debug, Serialize)]
pub struct Flight {
    /// The stated speed (`--flight-speed`), level-0 texels a tick.
    pub texels_per_tick: i64,
    /// Level 0 shown at the stated speed (goal >= 0.95).
    pub level0_shown_share: f64,
    /// The largest speed tried at which level 0 is shown on >= 95 % of the ticks (`null`: not
    /// even the stated one).
    pub max_texels_per_tick: Option<i64>,
    /// Whether a faster speed was tried and failed (else the largest is only a lower bound).
    pub max_bounded: bool,
    pub tick_hz: f64,
    pub added_latency_ms: u64,
    /// Texture size and clip size flown.
    pub texture: u64,
    pub clip: u64,
    /// Every speed flown, in order.
    pub legs: Vec<Leg>,
    /// Published level-0 texels checked against GDAL's decode (five a tick), and how many
    /// differed.
    pub texels_checked: u64,
    pub wrong_texels: u64,
}

/// What the flights need.
pub struct FlightRun<'a> {
    pub nginx_port: u16,
    pub max_zoom: u8,
    pub clip: u64,
    pub latency_ms: u64,
    pub speed: i64,
    pub quick: bool,
    pub reference: &'a Reference,
}

/// Flies at the stated speed, then doubles it while level 0 still holds, then tries the midpoint
/// between the last speed that held and the first that did not.
pub fn flights(run: &FlightRun) -> anyhow::Result<Flight> {
    let stop = Arc::new(AtomicBool::new(false));
    let proxy = Proxy::start(run.nginx_port, Duration::from_millis(run.latency_ms), Faults::default(), stop.clone())?;
    let template = format!("xyz:http://127.0.0.1:{}/xyz/{{z}}/{{x}}/{{y}}.png", proxy.port);
    let size = 256u64 << run.max_zoom;
    // The span flown back and forth is size - 2 clip; a speed is tried while a leg of it takes
    // at least 16 ticks.
    let span = size as i64 - 2 * run.clip as i64;
    let fastest = (span / 16).max(run.speed);
    let seconds = if run.quick { 2.0 } else { 10.0 };
    let tries = if run.quick { 2 } else { 6 };
    let (mut checked, mut wrong) = (0, 0);
    let mut legs = Vec::new();
    let mut fly_at = |speed: i64, legs: &mut Vec<Leg>| -> anyhow::Result<bool> {
        let (leg, c, w) = fly(&template, run, seconds, speed)?;
        checked += c;
        wrong += w;
        let ok = leg.level0_shown_share >= SHOWN_GOAL;
        legs.push(leg);
        Ok(ok)
    };
    let stated = fly_at(run.speed, &mut legs)?;
    let (mut best, mut failed) = (stated.then_some(run.speed), (!stated).then_some(run.speed));
    let mut speed = run.speed;
    for _ in 0..tries {
        if failed.is_some() {
            break;
        }
        speed *= 2;
        if speed > fastest {
            break;
        }
        if fly_at(speed, &mut legs)? {
            best = Some(speed);
        } else {
            failed = Some(speed);
        }
    }
    if let (Some(b), Some(f), false) = (best, failed, run.quick) {
        let mid = (b + f) / 2;
        if mid > b && fly_at(mid, &mut legs)? {
            best = Some(mid);
        }
    }
    stop.store(true, Ordering::Relaxed);
    Ok(Flight {
        texels_per_tick: run.speed,
        level0_shown_share: legs[0].level0_shown_share,
        max_texels_per_tick: best,
        max_bounded: failed.is_some_and(|f| best.is_some_and(|b| f > b)),
        tick_hz: HZ,
        added_latency_ms: run.latency_ms,
        texture: size,
        clip: run.clip,
        legs,
        texels_checked: checked,
        wrong_texels: wrong,
    })
}

/// One flight of `seconds` at `speed`, on a fresh source and clipmap (settled at the start,
/// untimed); (the leg, texels checked, texels wrong).
fn fly(template: &str, run: &FlightRun, seconds: f64, speed: i64) -> anyhow::Result<(Leg, u64, u64)> {
    let opts = OpenOptions {
        template: TemplateOptions {
            zooms: Some([0, run.max_zoom]),
            remote: Some(RemoteOptions { cache_dir: None, ..RemoteOptions::default() }),
            ..Default::default()
        },
        pyramid: PyramidOptions { clip_size: Some(run.clip), ..Default::default() },
    };
    let src = tiles::open(template, &opts)
        .ok_or_else(|| anyhow::anyhow!("{template}: not a template"))?
        .map_err(|e| anyhow::anyhow!("opening {template}: {e}"))?;
    let src: Arc<dyn TileSource> = Arc::new(src);
    let desc = src.desc().clone();
    let mut map = Clipmap::new(src.clone(), Settings::default())?;
    let (size, clip) = (desc.size()[0] as i64, desc.clip_size() as i64);
    let (lo, hi) = (clip, (size - clip).max(clip + 1));
    let at = |i: i64| {
        let span = hi - lo;
        let x = (i * speed).rem_euclid(2 * span);
        [lo + if x <= span { x } else { 2 * span - x }, size / 2]
    };
    for _ in 0..3000 {
        if map.tick(at(0), Some([0, 0])).min_lod == 0.0 {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let before = src.remote_stats().map_or(0, |s| s.requests);
    let period = Duration::from_secs_f64(1.0 / HZ);
    let ticks = (seconds * HZ) as u64;
    let (mut shown, mut after, mut lod_sum, mut disabled, mut checked, mut wrong) = (0u64, 0u64, 0.0, 0u64, 0u64, 0u64);
    let start = Instant::now();
    for i in 0..ticks {
        std::thread::sleep((start + period * i as u32).saturating_duration_since(Instant::now()));
        let r = map.tick(at(i as i64 + 1), None);
        lod_sum += r.min_lod;
        disabled += u64::from(!r.disabled_levels.is_empty());
        if i >= HZ as u64 {
            after += 1;
            shown += u64::from(r.min_lod < 1.0);
        }
        let v = map.level(0);
        let g = v.valid;
        if !g.is_empty() {
            let mid = [(g.s0 + g.s1) / 2, (g.t0 + g.t1) / 2];
            for [s, t] in [[g.s0, g.t0], [g.s1 - 1, g.t0], [g.s0, g.t1 - 1], [g.s1 - 1, g.t1 - 1], mid] {
                if let Some(texel) = v.texel(s, t) {
                    checked += 1;
                    wrong += u64::from(texel[..] != *run.reference.texel(s as u64, t as u64));
                }
            }
        }
    }
    let leg = Leg {
        texels_per_tick: speed,
        level0_shown_share: if after == 0 { 0.0 } else { shown as f64 / after as f64 },
        mean_min_lod: lod_sum / ticks.max(1) as f64,
        ticks,
        seconds: start.elapsed().as_secs_f64(),
        ticks_with_disabled_levels: disabled,
        requests: src.remote_stats().map_or(0, |s| s.requests) - before,
    };
    Ok((leg, checked, wrong))
}

pub fn human(f: &Flight) -> String {
    let mut o = format!(
        "real-time flight over the XYZ service through +{} ms a request, {}² texture, clip {}, {} ticks/s: level 0 shown on {:.1}% of the ticks at {} texels a tick (goal >= 95%); the largest speed holding 95%: {}\n",
        f.added_latency_ms,
        f.texture,
        f.clip,
        f.tick_hz,
        f.level0_shown_share * 100.0,
        f.texels_per_tick,
        match f.max_texels_per_tick {
            Some(s) => format!("{s} texels a tick{}", if f.max_bounded { "" } else { " (the fastest tried)" }),
            None => "none".into(),
        }
    );
    for l in &f.legs {
        o.push_str(&format!(
            "  {:>5} texels a tick: {:.1}% shown, mean min LOD {:.2}, {} requests\n",
            l.texels_per_tick,
            l.level0_shown_share * 100.0,
            l.mean_min_lod,
            l.requests
        ));
    }
    o.push_str(&format!("  {} of {} published texels wrong\n", f.wrong_texels, f.texels_checked));
    o
}
