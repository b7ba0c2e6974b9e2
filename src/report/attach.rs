//! `cliptex attach`: a live view of a running service, read straight from its shared-memory
//! mapping (levels, centres, valid regions, min LOD, heartbeat, tick rate).

use crate::shm::{Client, ShmError};
use serde::Serialize;
use std::path::Path;
use std::time::{Duration, Instant};

/// One level as published.
#[derive(Clone, Debug, Serialize)]
pub struct LevelRow {
    /// Level number.
    pub level: usize,
    /// Level size.
    pub size: [u64; 2],
    /// Pyramid (resident whole) or stack level.
    pub pyramid: bool,
    /// Centre.
    pub centre: [i64; 2],
    /// Valid region `[s0, t0, s1, t1)`.
    pub valid: [i64; 4],
    /// Renderers may use it.
    pub enabled: bool,
    /// Invalid border.
    pub invalid_border: u64,
}

/// A status view.
#[derive(Clone, Debug, Serialize)]
pub struct Status {
    /// The mapping.
    pub mapping: String,
    /// Writer generation.
    pub generation: u64,
    /// Tick of the global state.
    pub tick: u64,
    /// Finest level renderers may use.
    pub min_lod: f64,
    /// Heartbeat ticks counted.
    pub heartbeat: u64,
    /// Milliseconds since the last heartbeat.
    pub heartbeat_age_ms: u64,
    /// Update ticks per second over the sampling interval.
    pub ticks_per_second: f64,
    /// The service shut down cleanly.
    pub closed: bool,
    /// Clip size.
    pub clip_size: u64,
    /// Bytes per texel.
    pub bytes_per_texel: usize,
    /// Per level.
    pub levels: Vec<LevelRow>,
}

/// Takes a status view, sampling the heartbeat over `interval` for the tick rate.
pub fn status(dir: &Path, name: &str, interval: Duration) -> Result<Status, ShmError> {
    let c = Client::attach(dir, name)?;
    let (h0, t0) = (c.heartbeat(), Instant::now());
    std::thread::sleep(interval);
    let (h1, dt) = (c.heartbeat(), t0.elapsed().as_secs_f64());
    let snap = c.snapshot();
    let levels = snap
        .levels
        .iter()
        .enumerate()
        .map(|(k, st)| LevelRow {
            level: k,
            size: c.levels[k].size,
            pyramid: c.levels[k].pyramid,
            centre: st.centre,
            valid: st.valid,
            enabled: st.enabled,
            invalid_border: st.invalid_border,
        })
        .collect();
    Ok(Status {
        mapping: c.path().display().to_string(),
        generation: c.generation,
        tick: snap.tick,
        min_lod: snap.min_lod,
        heartbeat: h1,
        heartbeat_age_ms: c.heartbeat_age().as_millis() as u64,
        ticks_per_second: if dt > 0.0 { h1.saturating_sub(h0) as f64 / dt } else { 0.0 },
        closed: c.closed(),
        clip_size: c.clip_size,
        bytes_per_texel: c.bytes_per_texel,
        levels,
    })
}

/// The human form.
pub fn human(s: &Status) -> String {
    let mut o = format!(
        "{}  generation {:016x}\ntick {}  min LOD {:.2}  {:.1} ticks/s  heartbeat {} ms ago{}\nclip {}  {} bytes per texel\n\n",
        s.mapping,
        s.generation,
        s.tick,
        s.min_lod,
        s.ticks_per_second,
        s.heartbeat_age_ms,
        if s.closed { "  (service stopped)" } else { "" },
        s.clip_size,
        s.bytes_per_texel
    );
    o.push_str(
        "level  size                kind     centre                  valid region                              use\n",
    );
    for l in &s.levels {
        o.push_str(&format!(
            "{:<6} {:<19} {:<8} {:<23} {:<41} {}\n",
            l.level,
            format!("{}x{}", l.size[0], l.size[1]),
            if l.pyramid { "pyramid" } else { "stack" },
            format!("({}, {})", l.centre[0], l.centre[1]),
            format!("[{}, {}) x [{}, {})", l.valid[0], l.valid[2], l.valid[1], l.valid[3]),
            if !l.enabled {
                "disabled"
            } else if (l.level as f64) < s.min_lod.floor() {
                "below min LOD"
            } else {
                "yes"
            }
        ));
    }
    o
}
