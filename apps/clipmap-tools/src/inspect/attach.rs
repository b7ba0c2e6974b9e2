//! `cliptex attach`: a live view of a running service, read straight from its shared-memory
//! mapping (levels, centres, valid regions, min LOD, heartbeat, tick rate), plus each read
//! queue's length and throughput from the control socket's `STATS` reply (sampled at both ends
//! of the interval), and each level's paging as the service's last tick chose it (read-ahead,
//! grid and why, with the read latency planned with; from the later reply).

use clipmap::paging::adaptive::LevelPaging;
use clipmap::shm::{Client, ShmError};
use clipmap_service::ServiceStats;
use serde::Serialize;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::time::{Duration, Instant};

/// How long a `STATS` request may take before the view goes without stream figures.
const STATS_TIMEOUT: Duration = Duration::from_secs(2);

/// One stream server's read queue, from two `STATS` replies.
#[derive(Clone, Debug, Serialize)]
pub struct StreamRow {
    /// Stream server (read queue) index.
    pub stream: usize,
    /// Requests waiting now.
    pub pending: u64,
    /// Reads running now.
    pub in_flight: u64,
    /// Most requests ever waiting.
    pub peak_pending: u64,
    /// Reads that delivered a tile, so far.
    pub reads_done: u64,
    /// Reads that failed, so far.
    pub reads_failed: u64,
    /// Bytes delivered, so far.
    pub bytes_read: u64,
    /// Queued requests dropped (stale or overflow), so far.
    pub dropped: u64,
    /// Tiles delivered per second over the sampling interval.
    pub tiles_per_second: f64,
    /// Bytes delivered per second over the sampling interval.
    pub bytes_per_second: f64,
    /// The read latency the adaptive controller measured on this stream server, in ticks (from
    /// the later reply; 0 for a fixed policy, `null` when the reply has none: an older clipmapd).
    pub read_latency_ticks: Option<f64>,
}

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
    /// The level's paging as the service's last tick chose it (`lead_tiles`, `lead_texels`,
    /// `grid`, `reason`; from `STATS`, `null` when the socket did not answer: see
    /// `streams_error`).
    pub paging: Option<LevelPaging>,
    /// A height texture's published tile ranges: one per tile its slots hold ready or default
    /// (docs/SHM.md, "Tile ranges"); absent for a texture that is not heights.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_ranges: Option<Vec<TileRangeRow>>,
}

/// One tile's published range of heights.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TileRangeRow {
    /// Tile column S.
    pub s: i64,
    /// Tile row T.
    pub t: i64,
    /// Least height in metres, nodata excluded (`null`: every texel is nodata, or the tile holds
    /// a texel that is not a finite height).
    pub min: Option<f64>,
    /// Greatest height in metres (`null` as for `min`).
    pub max: Option<f64>,
}

impl TileRangeRow {
    fn of(tile: [i64; 2], r: clipmap::height::TileRange) -> TileRangeRow {
        let (min, max) = match r {
            clipmap::height::TileRange::Heights { min, max } if min.is_finite() && max.is_finite() => {
                (Some(min), Some(max))
            }
            _ => (None, None),
        };
        TileRangeRow { s: tile[0], t: tile[1], min, max }
    }
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
    /// The control socket asked for statistics.
    pub socket: String,
    /// Per stream server (empty when the socket did not answer: see `streams_error`).
    pub streams: Vec<StreamRow>,
    /// Why there are no stream figures (`null` when there are).
    pub streams_error: Option<String>,
    /// The read latency the adaptive controller plans with, in ticks (0 for a fixed policy;
    /// `null` when the socket did not answer).
    pub read_latency_ticks: Option<f64>,
    /// A growing texture's growth block (`null` for a texture that does not grow).
    pub growth: Option<clipmap::shm::layout::Growth>,
    /// The heights block: storage, scale, offset, nodata (a stored value; `null`: none) and level
    /// rule of a height texture (`null` for a texture that is not heights).
    pub heights: Option<clipmap::shm::layout::Heights>,
    /// The georef block: EPSG code (`null`: none known), whether the texture wraps in longitude,
    /// the CRS definition, the origin (GDAL geotransform terms 0 and 3) and each level's terms 1,
    /// 2, 4 and 5 (docs/SHM.md, "Georef block"); `null` for a texture without georeferencing.
    pub georef: Option<clipmap::shm::GeorefBlock>,
    /// The shown view's level-0 centre, texels (level 0's state in its snapshot).
    pub centre: [i64; 2],
    /// That centre's WGS 84 `[longitude, latitude]`, of its texel's middle (s + 0.5, t + 0.5), as
    /// `STATS` `centre_lonlat` shows it (docs/GEOREF.md); `null` without georeferencing.
    pub centre_lonlat: Option<[f64; 2]>,
    /// The view shown (`main`: the primary; docs/VIEWS.md).
    pub view: String,
    /// Every view's figures from the socket's statistics, `main` first (empty when the socket
    /// did not answer).
    pub views: Vec<clipmap_service::stats::ViewStats>,
    /// The source's remote reads from the later `STATS` reply (requests, retries, merged,
    /// bytes, failures, cache hits and drops, peak in flight; `null` for a local source or
    /// without a `STATS` reply).
    #[cfg(feature = "remote")]
    pub remote: Option<clipmap::source::remote::RemoteStats>,
}

/// Why a `STATS` request got no statistics.
#[derive(Debug, thiserror::Error)]
pub(crate) enum StatsError {
    /// Connecting, writing or reading failed (or timed out).
    #[error("control socket {}: {source}", socket.display())]
    Io {
        /// The socket.
        socket: std::path::PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The reply was not `OK {json}`.
    #[error("control socket {}: expected `OK {{json}}` to STATS, found `{found}`", socket.display())]
    Reply {
        /// The socket.
        socket: std::path::PathBuf,
        /// The reply line.
        found: String,
    },
    /// The JSON is not the service's statistics.
    #[error("control socket {}: the STATS reply is not the service's statistics: {source}", socket.display())]
    Json {
        /// The socket.
        socket: std::path::PathBuf,
        /// Why.
        #[source]
        source: serde_json::Error,
    },
}

/// Sends `STATS` to the control socket and reads the reply into the service's own statistics
/// type (the struct the service serialised).
pub(crate) fn ask_stats(socket: &Path) -> Result<ServiceStats, StatsError> {
    let fail = |source: std::io::Error| StatsError::Io { socket: socket.to_path_buf(), source };
    let mut s = UnixStream::connect(socket).map_err(fail)?;
    s.set_read_timeout(Some(STATS_TIMEOUT)).map_err(fail)?;
    s.set_write_timeout(Some(STATS_TIMEOUT)).map_err(fail)?;
    s.write_all(b"STATS\n").map_err(fail)?;
    let mut line = String::new();
    BufReader::new(&s).read_line(&mut line).map_err(fail)?;
    let _ = s.write_all(b"QUIT\n");
    let body = line.trim_end().strip_prefix("OK ").ok_or_else(|| StatsError::Reply {
        socket: socket.to_path_buf(),
        found: line.trim_end().chars().take(200).collect(),
    })?;
    serde_json::from_str(body).map_err(|source| StatsError::Json { socket: socket.to_path_buf(), source })
}

/// Stream rows from a `STATS` reply taken `dt` seconds after `before`.
fn stream_rows(before: &ServiceStats, after: &ServiceStats, dt: f64) -> Result<Vec<StreamRow>, String> {
    let (b, a) = (&before.tick.streams, &after.tick.streams);
    if a.is_empty() {
        return Err("the service's STATS reply has no `streams` (an older clipmapd)".into());
    }
    let rate = |a: u64, b: u64| if dt > 0.0 { a.saturating_sub(b) as f64 / dt } else { 0.0 };
    let latency = &after.tick.engine.stream_read_latency_ticks;
    Ok(a.iter()
        .enumerate()
        .map(|(i, q)| {
            let p = b.get(i).unwrap_or(q);
            StreamRow {
                stream: i,
                pending: q.pending,
                in_flight: q.in_flight,
                peak_pending: q.peak_pending,
                reads_done: q.reads_done,
                reads_failed: q.reads_failed,
                bytes_read: q.bytes_read,
                dropped: q.stale_dropped + q.overflow_dropped,
                tiles_per_second: rate(q.reads_done, p.reads_done),
                bytes_per_second: rate(q.bytes_read, p.bytes_read),
                read_latency_ticks: latency.get(i).copied(),
            }
        })
        .collect())
}

/// Takes a status view, sampling the heartbeat (for the tick rate) and the control socket's
/// `STATS` (for queue throughput) over `interval`. A socket that does not answer leaves the
/// stream figures out, with the reason, rather than failing the view.
pub fn status(dir: &Path, name: &str, interval: Duration, socket: &Path) -> Result<Status, ShmError> {
    status_of_view(dir, name, clipmap::shm::layout::views::PRIMARY_NAME, interval, socket)
}

/// [`status`] of the view `view` (docs/VIEWS.md; `main`: the primary): its snapshot's levels and
/// min LOD, and every view's figures from the socket.
pub fn status_of_view(
    dir: &Path,
    name: &str,
    view: &str,
    interval: Duration,
    socket: &Path,
) -> Result<Status, ShmError> {
    let c = Client::attach_view(dir, name, view)?;
    let before = ask_stats(socket);
    let (h0, t0) = (c.heartbeat(), Instant::now());
    std::thread::sleep(interval);
    let after = ask_stats(socket);
    let (h1, dt) = (c.heartbeat(), t0.elapsed().as_secs_f64());
    let (streams, streams_error) = match (&before, &after) {
        (Ok(b), Ok(a)) => match stream_rows(b, a, dt) {
            Ok(rows) => (rows, None),
            Err(e) => (Vec::new(), Some(e)),
        },
        (Err(e), _) | (_, Err(e)) => (Vec::new(), Some(e.to_string())),
    };
    let engine = after.as_ref().ok().map(|a| &a.tick.engine);
    let snap = c.checked_snapshot()?;
    let growth = c.growth().unwrap_or_else(|e| {
        tracing::warn!("{}: growth block: {e}", c.path().display());
        None
    });
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
            invalid_border: snap.invalid_border,
            paging: engine.and_then(|e| e.paging.get(k).copied()),
            tile_ranges: c
                .heights
                .map(|_| c.tile_ranges(k).into_iter().map(|(tile, r)| TileRangeRow::of(tile, r)).collect()),
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
        socket: socket.display().to_string(),
        streams,
        streams_error,
        read_latency_ticks: engine.map(|e| e.read_latency_ticks),
        growth,
        heights: c.heights,
        georef: c.georef.clone(),
        centre: snap.levels.first().map_or([0, 0], |l| l.centre),
        centre_lonlat: snap
            .levels
            .first()
            .zip(c.levels.first())
            .and_then(|(l, d)| clipmap::shm::centre_lonlat(c.georef.as_ref(), d.size, l.centre)),
        view: c.view_name().to_string(),
        views: after.as_ref().map(|a| a.tick.views.clone()).unwrap_or_default(),
        #[cfg(feature = "remote")]
        remote: after.as_ref().ok().and_then(|a| a.tick.remote.clone()),
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
    let virtual_views = s.views.iter().any(|v| v.lod_offset > 0 || v.effective_levels < s.levels.len() as u32);
    if s.views.len() > 1 || s.view != clipmap::shm::layout::views::PRIMARY_NAME || virtual_views {
        o.push_str("view        weight  min LOD  LOD window    resident  grids   centre\n");
        for v in &s.views {
            let centre = v.centre.map_or("-".to_string(), |c| format!("{} {}", c[0], c[1]));
            let shown = if v.name == s.view { "  (shown below)" } else { "" };
            let window = format!("{}..{}", v.lod_offset, (v.lod_offset + v.effective_levels).saturating_sub(1));
            let grids = if v.grids.is_empty() { "shared" } else { v.grids.as_str() };
            o.push_str(&format!(
                "{:<11} {:>6.2}  {:>7.2}  {window:<12}  {:<8}  {grids:<6}  {centre}{shown}\n",
                v.name,
                v.weight,
                v.min_lod,
                level_list(&v.resident_levels)
            ));
        }
        o.push('\n');
    }
    if let Some(h) = &s.heights {
        o.push_str(&format!(
            "heights: {}  metres = stored x {} + {}  nodata {}  levels {}\n\n",
            h.storage,
            h.scale,
            h.offset,
            h.nodata.map_or_else(|| "none".to_string(), |v| v.to_string()),
            h.levels
        ));
    }
    if let Some(g) = &s.georef {
        let epsg = g.epsg.map_or_else(|| "no EPSG code".to_string(), |c| format!("EPSG:{c}"));
        let [a, b, d, e] = g.levels[0];
        o.push_str(&format!(
            "georef: {epsg}  origin {} {}  level 0 terms {a} {b} {d} {e}{}\n\n",
            g.origin[0],
            g.origin[1],
            if g.wraps { "  wraps in longitude" } else { "" }
        ));
    }
    match s.centre_lonlat {
        Some([lon, lat]) => o.push_str(&format!(
            "centre: {} {} (level-0 texels)  longitude {lon:.9} latitude {lat:.9} (WGS 84)\n\n",
            s.centre[0], s.centre[1]
        )),
        None => o.push_str(&format!("centre: {} {} (level-0 texels)\n\n", s.centre[0], s.centre[1])),
    }
    if let Some(g) = &s.growth {
        let e = g.extent;
        let extent = if e == [0; 4] {
            "no data yet".to_string()
        } else {
            format!("data over [{}, {}) x [{}, {})", e[0], e[2], e[1], e[3])
        };
        o.push_str(&format!(
            "growing: {extent}  {} data levels  {} patches  tiles rebuilt {}, waiting {}, replaced in their slots {}{}\n\n",
            g.data_levels,
            g.patches,
            g.tiles_rebuilt,
            g.tiles_pending,
            g.tiles_replaced,
            if g.outside_frame > 0 { format!("  ({} patches reach outside the frame)", g.outside_frame) } else { String::new() }
        ));
    }
    #[cfg(feature = "remote")]
    if let Some(r) = &s.remote {
        o.push_str(&remote_line(r));
    }
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
    o.push('\n');
    o.push_str(&paging_table(s));
    o.push('\n');
    match &s.streams_error {
        Some(e) => o.push_str(&format!("read queues: no figures ({e})\n")),
        None => {
            o.push_str(
                "stream  pending  in flight  peak  reads done  failed  dropped   tiles/s     MiB/s  latency (ticks)\n",
            );
            for q in &s.streams {
                let latency = q.read_latency_ticks.map_or_else(|| "-".to_string(), |l| format!("{l:.1}"));
                o.push_str(&format!(
                    "{:<7} {:>7}  {:>9}  {:>4}  {:>10}  {:>6}  {:>7}  {:>8.1}  {:>8.2}  {:>15}\n",
                    q.stream,
                    q.pending,
                    q.in_flight,
                    q.peak_pending,
                    q.reads_done,
                    q.reads_failed,
                    q.dropped,
                    q.tiles_per_second,
                    q.bytes_per_second / (1024.0 * 1024.0),
                    latency
                ));
            }
        }
    }
    o
}

/// The remote reads' line of the human form (and a blank line after it).
#[cfg(feature = "remote")]
fn remote_line(r: &clipmap::source::remote::RemoteStats) -> String {
    // A server that ignores ranges is said on the line (it makes every read fetch whole objects).
    let ignored = if r.ranges_ignored > 0 {
        format!("  ranges ignored {} (the server sends whole objects)", r.ranges_ignored)
    } else {
        String::new()
    };
    // Bytes fetched twice are said too: every tile is meant to be read once.
    let twice = if r.duplicate_reads > 0 {
        format!("  {} reads fetched {} bytes again", r.duplicate_reads, r.duplicate_bytes)
    } else {
        String::new()
    };
    // The requests in flight the source sized for its busiest endpoint, and why.
    let sized = if r.in_flight_limit > 0 {
        format!(
            "  sized {} in flight ({}; {:.1} ms, {} reads/s)",
            r.in_flight_limit,
            r.in_flight_reason,
            r.latency_us as f64 / 1e3,
            r.reads_per_s
        )
    } else {
        String::new()
    };
    // The HTTP versions the endpoints answered in (none before an answer, or for S3 alone).
    let version = if r.http_version.is_empty() { String::new() } else { format!("  over {}", r.http_version) };
    format!(
        "remote: {} requests  {} retries  {} merged  {:.2} MiB  {} failures  cache {} hits {} dropped  peak {} in flight{ignored}{twice}{sized}{version}\n\n",
        r.requests,
        r.retries,
        r.merged,
        r.bytes as f64 / (1024.0 * 1024.0),
        r.failures,
        r.cache_hits,
        r.cache_dropped,
        r.peak_in_flight
    )
}

/// The paging part of the human form: per level the reason, the read-ahead (tiles the mem region
/// holds beyond the window, and the level texels asked for) and the grid, on s x t.
fn paging_table(s: &Status) -> String {
    let Some(latency) = s.read_latency_ticks else {
        return format!("paging: no figures ({})\n", s.streams_error.as_deref().unwrap_or("no STATS reply"));
    };
    let mut o = format!("paging  read latency {latency:.1} ticks\n");
    o.push_str("level  reason         lead tiles  lead texels    grid\n");
    for l in &s.levels {
        let Some(p) = &l.paging else { continue };
        let x = |v: [u64; 2]| format!("{}x{}", v[0], v[1]);
        o.push_str(&format!(
            "{:<6} {:<14} {:<11} {:<14} {}\n",
            l.level,
            p.reason.name(),
            x(p.lead_tiles),
            x(p.lead_texels),
            x(p.grid)
        ));
    }
    o
}

/// Levels as runs: `3..9`, `0..2,5`, `-` for none.
fn level_list(levels: &[u32]) -> String {
    let mut runs: Vec<(u32, u32)> = Vec::new();
    for &k in levels {
        match runs.last_mut() {
            Some((_, end)) if *end + 1 == k => *end = k,
            _ => runs.push((k, k)),
        }
    }
    if runs.is_empty() {
        return "-".into();
    }
    runs.iter().map(|&(a, b)| if a == b { a.to_string() } else { format!("{a}..{b}") }).collect::<Vec<_>>().join(",")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stream_rows_take_lengths_from_the_later_reply_and_rates_from_both() {
        // The wire form the service writes (`streams` at the top level: the tick figures are
        // flattened), read back into the typed statistics.
        let typed = |v: serde_json::Value| serde_json::from_value::<ServiceStats>(v).unwrap();
        let b = typed(
            serde_json::json!({"name": "x", "streams": [{"reads_done": 10, "bytes_read": 1000}, {"reads_done": 0}]}),
        );
        let a = typed(serde_json::json!({"name": "x", "engine": {"stream_read_latency_ticks": [3.5]}, "streams": [
            {"reads_done": 30, "bytes_read": 5000, "pending": 7, "in_flight": 2, "peak_pending": 9,
             "stale_dropped": 1, "overflow_dropped": 2, "reads_failed": 1},
            {"reads_done": 4}
        ]}));
        let rows = stream_rows(&b, &a, 2.0).unwrap();
        assert_eq!(rows.len(), 2);
        let r = &rows[0];
        assert_eq!((r.pending, r.in_flight, r.peak_pending, r.dropped, r.reads_failed), (7, 2, 9, 3, 1));
        assert_eq!((r.tiles_per_second, r.bytes_per_second), (10.0, 2000.0));
        assert_eq!(rows[1].tiles_per_second, 2.0);
        // Each stream's latency from the later reply; none where it has none (an older clipmapd).
        assert_eq!((rows[0].read_latency_ticks, rows[1].read_latency_ticks), (Some(3.5), None));
        let e = stream_rows(&a, &typed(serde_json::json!({})), 1.0).unwrap_err();
        assert!(e.contains("no `streams`"), "{e}");
        // What the service serialises reads back to the same figures.
        let back = typed(serde_json::to_value(&a).unwrap());
        assert_eq!(back.tick.streams, a.tick.streams);
        assert_eq!(back.name, "x");
    }

    #[test]
    fn each_levels_reason_lead_and_grid_are_shown_with_the_read_latency() {
        use clipmap::paging::adaptive::Reason;
        let row = |level, paging| LevelRow {
            level,
            size: [1024, 1024],
            pyramid: false,
            centre: [512, 512],
            valid: [0, 0, 256, 256],
            enabled: true,
            invalid_border: 8,
            paging,
            tile_ranges: None,
        };
        let bound = LevelPaging {
            lead_tiles: [2, 0],
            lead_texels: [320, 0],
            grid: [8, 8],
            reason: Reason::SourceBound,
            read_latency_ticks: 4.25,
        };
        let mut s = Status {
            mapping: "m".into(),
            generation: 1,
            tick: 9,
            min_lod: 1.0,
            heartbeat: 9,
            heartbeat_age_ms: 1,
            ticks_per_second: 60.0,
            closed: false,
            clip_size: 256,
            bytes_per_texel: 4,
            levels: vec![
                row(0, Some(bound)),
                row(1, Some(LevelPaging { grid: [7, 7], reason: Reason::Hover, ..bound })),
            ],
            socket: "s".into(),
            streams: vec![StreamRow {
                stream: 0,
                pending: 1,
                in_flight: 2,
                peak_pending: 3,
                reads_done: 4,
                reads_failed: 0,
                bytes_read: 5,
                dropped: 0,
                tiles_per_second: 6.0,
                bytes_per_second: 0.0,
                read_latency_ticks: Some(4.25),
            }],
            streams_error: None,
            read_latency_ticks: Some(4.25),
            growth: None,
            heights: None,
            georef: None,
            centre: [512, 512],
            centre_lonlat: None,
            view: "main".into(),
            views: Vec::new(),
            #[cfg(feature = "remote")]
            remote: None,
        };
        let text = human(&s);
        assert!(text.contains("paging  read latency 4.2 ticks\n"), "{text}");
        assert!(text.contains("level  reason         lead tiles  lead texels    grid\n"), "{text}");
        assert!(text.contains("0      source_bound   2x0         320x0          8x8\n"), "{text}");
        assert!(text.contains("1      hover          2x0         320x0          7x7\n"), "{text}");
        assert!(text.contains("latency (ticks)\n0             1          2     3           4       0        0       6.0      0.00              4.2\n"), "{text}");
        let v = serde_json::to_value(&s).unwrap();
        assert_eq!(v["read_latency_ticks"], 4.25);
        assert_eq!(v["streams"][0]["read_latency_ticks"], 4.25);
        assert_eq!(
            v["levels"][0]["paging"],
            serde_json::json!({"lead_tiles": [2, 0], "lead_texels": [320, 0], "grid": [8, 8], "reason": "source_bound", "read_latency_ticks": 4.25})
        );
        // Without a STATS reply: no paging figures, and why.
        s.read_latency_ticks = None;
        s.streams_error = Some("control socket s: refused".into());
        s.levels.iter_mut().for_each(|l| l.paging = None);
        let text = human(&s);
        assert!(text.contains("paging: no figures (control socket s: refused)"), "{text}");
        assert!(!text.contains("heights:"), "a colour texture shows no heights line\n{text}");
        // A height texture: its heights block, one line, and in the JSON.
        let f = clipmap::height::HeightFormat::new(clipmap::height::HeightStorage::U16, 0.25, -500.0, Some(65535.0))
            .unwrap();
        s.heights = Some(clipmap::shm::layout::Heights::of(&f, clipmap::height::LevelRule::Max));
        let text = human(&s);
        assert!(text.contains("heights: l16  metres = stored x 0.25 + -500  nodata 65535  levels max\n"), "{text}");
        let v = serde_json::to_value(&s).unwrap();
        assert_eq!(
            v["heights"],
            serde_json::json!({"storage": "u16", "scale": 0.25, "offset": -500.0, "nodata": 65535.0, "levels": "max"})
        );
        // Without georeferencing: no georef line, `georef` null; with it: one line and the block.
        assert!(!text.contains("georef:"), "{text}");
        assert!(v["georef"].is_null(), "{v}");
        s.georef = Some(clipmap::shm::GeorefBlock {
            epsg: Some(3857),
            wraps: true,
            definition: "+proj=merc".into(),
            origin: [-20037508.0, 20037508.0],
            levels: vec![[0.5, 0.0, 0.0, -0.5], [1.0, 0.0, 0.0, -1.0]],
        });
        let text = human(&s);
        assert!(
            text.contains(
                "georef: EPSG:3857  origin -20037508 20037508  level 0 terms 0.5 0 0 -0.5  wraps in longitude\n"
            ),
            "{text}"
        );
        let v = serde_json::to_value(&s).unwrap();
        assert_eq!(
            v["georef"],
            serde_json::json!({"epsg": 3857, "wraps": true, "definition": "+proj=merc", "origin": [-20037508.0, 20037508.0], "levels": [[0.5, 0.0, 0.0, -0.5], [1.0, 0.0, 0.0, -1.0]]})
        );
        #[cfg(feature = "remote")]
        {
            // A local source: no remote line, `remote` null; a remote one: one line, every figure.
            assert!(!text.contains("remote:"), "{text}");
            assert_eq!(serde_json::to_value(&s).unwrap()["remote"], serde_json::Value::Null);
            s.remote = Some(clipmap::source::remote::RemoteStats {
                requests: 17,
                retries: 2,
                merged: 40,
                bytes: 3 << 20,
                failures: 1,
                cache_hits: 5,
                cache_dropped: 6,
                peak_in_flight: 8,
                ranges_ignored: 0,
                ..Default::default()
            });
            let text = human(&s);
            assert!(
                text.contains("remote: 17 requests  2 retries  40 merged  3.00 MiB  1 failures  cache 5 hits 6 dropped  peak 8 in flight\n"),
                "{text}"
            );
            // Bytes fetched twice are said on the line.
            s.remote.as_mut().unwrap().duplicate_reads = 3;
            s.remote.as_mut().unwrap().duplicate_bytes = 4096;
            assert!(human(&s).contains("in flight  3 reads fetched 4096 bytes again\n"), "{}", human(&s));
            s.remote.as_mut().unwrap().duplicate_reads = 0;
            // The requests in flight the source chose, and why.
            let r = s.remote.as_mut().unwrap();
            (r.in_flight_limit, r.in_flight_reason, r.latency_us, r.reads_per_s) =
                (96, "rate x latency".into(), 21_400, 2200);
            assert!(
                human(&s).contains("peak 8 in flight  sized 96 in flight (rate x latency; 21.4 ms, 2200 reads/s)\n"),
                "{}",
                human(&s)
            );
            // The HTTP version the answers came in, once there were answers.
            s.remote.as_mut().unwrap().http_version = "HTTP/2".into();
            assert!(human(&s).contains("2200 reads/s)  over HTTP/2\n"), "{}", human(&s));
            let v = serde_json::to_value(&s).unwrap();
            assert_eq!(v["remote"]["in_flight_limit"], 96);
            assert_eq!(v["remote"]["in_flight_reason"], "rate x latency");
            assert_eq!(v["remote"]["requests"], 17);
            assert_eq!(v["remote"]["peak_in_flight"], 8);
        }
        let v = serde_json::to_value(&s).unwrap();
        assert_eq!(
            (v["read_latency_ticks"].clone(), v["levels"][1]["paging"].clone()),
            (serde_json::Value::Null, serde_json::Value::Null)
        );
    }
}
