//! The service's statistics: a snapshot the tick loop publishes after every tick, the control
//! server's own counters, and their Prometheus text form.
//!
//! Owns the numbers' names and units only; the tick loop (`super::ticker`) and the control
//! server (`super::control`) fill them in.

use clipmap::clip::Stats;
use clipmap::queue::QueueStats;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};

/// What the tick loop reports after each tick.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct TickStats {
    /// Seconds since the tick loop started.
    pub uptime_s: f64,
    /// Ticks per second asked for.
    pub tick_hz: f64,
    /// Ticks that took longer than the tick period (the loop then skips ahead, never bursts).
    pub tick_overruns: u64,
    /// Ticks started early because a renderer's request arrived (the tick loop polls the
    /// request block every millisecond while it waits, so a request is published in about the
    /// time of one tick's work instead of waiting for the next period).
    pub ticks_on_request: u64,
    /// Seconds spent inside update ticks (reads taken, strips copied, states published).
    pub tick_busy_s: f64,
    /// Level-0 centre of the last tick.
    pub centre: [i64; 2],
    /// That centre's WGS 84 `[longitude, latitude]` (its texel's middle; `null` when the texture
    /// has no georeferencing, docs/GEOREF.md).
    pub centre_lonlat: Option<[f64; 2]>,
    /// Renderer requests seen through the mapping (the request block's count).
    pub requests_seen: u64,
    /// LOD requests (docs/SHM.md, "Asking for a view's levels") applied, every view's.
    #[serde(default)]
    pub lod_requests: u64,
    /// LOD requests refused (a height or pixel angle that is not a positive finite number, an
    /// angle of pi or more); each is logged with the view and the field.
    #[serde(default)]
    pub lod_requests_refused: u64,
    /// Requests whose centre was given in longitude / latitude or map coordinates (docs/SHM.md,
    /// "Positions in longitude / latitude or map coordinates") and taken.
    #[serde(default)]
    pub position_requests: u64,
    /// Such requests refused (no georeferencing, a position outside the texture or the
    /// projection's domain, an unknown coordinate kind); each is logged with why, and its view
    /// stays where it was.
    #[serde(default)]
    pub position_requests_refused: u64,
    /// Why the latest one was refused (`null` when none was).
    #[serde(default)]
    pub position_request_refused: Option<String>,
    /// The latest request's velocity as the look-ahead takes it, in level-0 texels per tick
    /// (divided by the tick rate, rounded, clamped to 2^30, NaN and infinities 0); `null` when
    /// there is none, both are 0 or a `CENTRE` cleared it: the centre's change is used instead.
    pub request_velocity: Option<[i64; 2]>,
    /// Times the request mapping was found not whole (shorter than its 4096 bytes: truncated by a
    /// process that can write it); each is reported once in the log, and requests are ignored
    /// while it lasts.
    pub request_faults: u64,
    /// The first such report (`null` when there was none).
    pub request_fault: Option<String>,
    /// Centres set through the control socket.
    pub socket_centres: u64,
    /// Finest level renderers may use.
    pub min_lod: f64,
    /// Levels renderers may not use now (finer than min LOD).
    pub levels_disabled: u64,
    /// Copy budget per tick in milliseconds (`null`: unlimited).
    pub budget_ms: Option<f64>,
    /// Invalid border in use.
    pub invalid_border: u64,
    /// Texel bytes read into the mapping's slots (tile reads write there directly).
    pub bytes_published: u64,
    /// Snapshots published in the mapping (one per tick).
    pub publications: u64,
    /// Bytes of the image caches (the whole mapping).
    pub resident_bytes: u64,
    /// Per level: the published valid region `[s0, t0, s1, t1]`.
    pub valid: Vec<[i64; 4]>,
    /// The engine's counters.
    pub engine: Stats,
    /// Per stream server (read queue), in server order: queue lengths and reads, the same
    /// counters as `engine.queue` sums.
    pub streams: Vec<QueueStats>,
    /// A growing texture's growth block as last published (`null` for a texture that does not
    /// grow).
    pub growth: Option<clipmap::shm::layout::Growth>,
    /// The remote reads of a source that reads over the network (HTTP or S3 tiles, a remote
    /// COG): requests sent (retries included), retries, ranges read by a merged request, bytes
    /// received, ranges that failed after retries, disk-cache hits and dropped cache files, the
    /// most requests in flight to one endpoint; `null` for local files.
    #[cfg(feature = "remote")]
    pub remote: Option<clipmap::source::remote::RemoteStats>,
    /// Each view (docs/VIEWS.md), the primary (`main`) first: its name, weight, centre, min LOD
    /// and published regions.
    pub views: Vec<ViewStats>,
}

/// The control server's counters (plain atomics: connections update them concurrently).
#[derive(Debug, Default)]
pub struct ControlCounters {
    /// Connections accepted.
    pub accepted: AtomicU64,
    /// Connections refused because the limit was reached.
    pub refused: AtomicU64,
    /// Connections open now.
    pub open: AtomicU64,
    /// Requests answered `OK`.
    pub ok: AtomicU64,
    /// Requests answered `ERR`.
    pub errors: AtomicU64,
    /// Connections closed for a line longer than the limit.
    pub long_lines: AtomicU64,
    /// Connections closed for idling.
    pub idle_closed: AtomicU64,
}

/// A copy of [`ControlCounters`].
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct ControlStats {
    /// Connections accepted.
    pub accepted: u64,
    /// Connections refused because the limit was reached.
    pub refused: u64,
    /// Connections open now.
    pub open: u64,
    /// Requests answered `OK`.
    pub ok: u64,
    /// Requests answered `ERR`.
    pub errors: u64,
    /// Connections closed for a line longer than the limit.
    pub long_lines: u64,
    /// Connections closed for idling.
    pub idle_closed: u64,
}

impl ControlCounters {
    /// Adds one to a counter.
    pub(crate) fn bump(c: &AtomicU64) {
        c.fetch_add(1, Ordering::Relaxed);
    }

    /// A copy.
    pub fn get(&self) -> ControlStats {
        let g = |c: &AtomicU64| c.load(Ordering::Relaxed);
        ControlStats {
            accepted: g(&self.accepted),
            refused: g(&self.refused),
            open: g(&self.open),
            ok: g(&self.ok),
            errors: g(&self.errors),
            long_lines: g(&self.long_lines),
            idle_closed: g(&self.idle_closed),
        }
    }
}

/// Everything `STATS` answers: the service serialises it and `cliptex attach` reads it back
/// into the same struct (missing fields, from an older service, take their defaults).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct ServiceStats {
    /// The publication name.
    pub name: String,
    /// The tick loop's figures.
    #[serde(flatten)]
    pub tick: TickStats,
    /// The control socket's figures.
    pub control: ControlStats,
}

/// Everything `STATUS` answers: the texture, the mapping and where the tick loop is
/// (docs/SHM.md, "Control socket"). Its JSON gives the fields in name order
/// (`super::protocol::render`).
#[derive(Clone, Debug, Serialize)]
pub struct Status {
    /// The publication name.
    pub name: String,
    /// The service's process id.
    pub pid: u32,
    /// The mapping file.
    pub mapping: std::path::PathBuf,
    /// The control socket.
    pub socket: std::path::PathBuf,
    /// Level-0 size.
    pub size: [u64; 2],
    /// Clip size.
    pub clip_size: u64,
    /// Number of levels.
    pub levels: usize,
    /// Texel format.
    pub format: String,
    /// Bytes of the mapping.
    pub mapping_bytes: u64,
    /// Seconds since the tick loop started.
    pub uptime_s: f64,
    /// Ticks so far.
    pub ticks: u64,
    /// Ticks per second asked for.
    pub tick_hz: f64,
    /// Level-0 centre of the last tick.
    pub centre: [i64; 2],
    /// The finest level renderers may use.
    pub min_lod: f64,
    /// Levels disabled.
    pub levels_disabled: u64,
    /// The copy budget per tick (`None`: off).
    pub budget_ms: Option<f64>,
    /// The invalid border in use.
    pub invalid_border: u64,
    /// Each level's valid region, `[s0, t0, s1, t1]`.
    pub valid: Vec<[i64; 4]>,
    /// The growth block's values (`None`: the texture does not grow).
    pub growth: Option<clipmap::shm::layout::Growth>,
}

impl Status {
    /// The status of service `name` answering on `socket`, started as `started`, at its tick
    /// loop's latest figures `t`.
    pub fn of(name: &str, socket: &std::path::Path, started: &super::Started, t: &TickStats) -> Status {
        Status {
            name: name.to_string(),
            pid: std::process::id(),
            mapping: started.mapping.clone(),
            socket: socket.to_path_buf(),
            size: started.size,
            clip_size: started.clip_size,
            levels: started.levels,
            format: started.format.clone(),
            mapping_bytes: started.mapping_bytes,
            uptime_s: t.uptime_s,
            ticks: t.engine.ticks,
            tick_hz: t.tick_hz,
            centre: t.centre,
            min_lod: t.min_lod,
            levels_disabled: t.levels_disabled,
            budget_ms: t.budget_ms,
            invalid_border: t.invalid_border,
            valid: t.valid.clone(),
            growth: t.growth,
        }
    }
}

impl ServiceStats {
    /// The Prometheus text exposition form (`clipmapd_` prefix, label `name`).
    pub fn prometheus(&self) -> String {
        let mut out = String::new();
        for (name, kind, help, v) in self.sample_rows() {
            out.push_str(&self.sample(name, kind, help, v));
        }
        out.push_str(&self.stream_latency_prometheus());
        out.push_str(&self.paging_prometheus());
        #[cfg(feature = "remote")]
        out.push_str(&self.remote_prometheus());
        out
    }

    /// One metric of the service: its help, its type and its one sample, labelled `name`.
    fn sample(&self, name: &str, kind: &str, help: &str, v: impl std::fmt::Display) -> String {
        format!(
            "# HELP clipmapd_{name} {help}\n# TYPE clipmapd_{name} {kind}\nclipmapd_{name}{{name=\"{}\"}} {v}\n",
            self.name
        )
    }

    /// The metrics of one sample each: name, type, help, value.
    fn sample_rows(&self) -> [(&'static str, &'static str, &'static str, f64); 34] {
        let t = &self.tick;
        let e = &t.engine;
        let c = &self.control;
        let q = &e.queue;
        [
            ("ticks_total", "counter", "Update ticks run", e.ticks as f64),
            ("tick_overruns_total", "counter", "Ticks longer than the tick period", t.tick_overruns as f64),
            (
                "ticks_on_request_total",
                "counter",
                "Ticks started early by a renderer's request",
                t.ticks_on_request as f64,
            ),
            ("tick_busy_seconds_total", "counter", "Seconds spent inside update ticks", t.tick_busy_s),
            ("uptime_seconds", "gauge", "Seconds since start", t.uptime_s),
            (
                "tick_texel_bytes_total",
                "counter",
                "Texel bytes written into the mapping other than by tile reads",
                e.tick_texel_bytes as f64,
            ),
            ("bytes_published_total", "counter", "Texel bytes read into the mapping's slots", t.bytes_published as f64),
            ("publications_total", "counter", "Snapshots published", t.publications as f64),
            ("tiles_read_total", "counter", "Tiles read and admitted", e.tiles_read as f64),
            ("read_faults_total", "counter", "Tile reads that failed", e.read_faults.total() as f64),
            ("late_tiles_total", "counter", "Tiles that arrived after leaving their region", e.late_tiles as f64),
            ("tiles_evicted_total", "counter", "Tiles evicted", e.tiles_evicted as f64),
            ("queue_pending", "gauge", "Read requests waiting", q.pending as f64),
            ("queue_in_flight", "gauge", "Reads running", q.in_flight as f64),
            ("queue_peak_pending", "gauge", "Most read requests ever waiting in one queue", q.peak_pending as f64),
            (
                "queue_dropped_total",
                "counter",
                "Queued reads dropped (stale or overflow)",
                (q.stale_dropped + q.overflow_dropped) as f64,
            ),
            ("levels_disabled", "gauge", "Levels renderers may not use now", t.levels_disabled as f64),
            (
                "ticks_with_disabled_level_total",
                "counter",
                "Ticks with a level disabled",
                e.ticks_with_disabled_level as f64,
            ),
            (
                "budget_overruns_total",
                "counter",
                "Ticks whose copy budget ran out with work left",
                e.ticks_over_budget as f64,
            ),
            ("min_lod", "gauge", "Finest level renderers may use", t.min_lod),
            ("min_lod_raises_total", "counter", "Times min LOD was raised", e.min_lod_raises as f64),
            (
                "read_latency_ticks",
                "gauge",
                "Read latency the adaptive paging plans with, ticks from asking for a tile to taking it",
                e.read_latency_ticks,
            ),
            ("invalid_border_texels", "gauge", "Invalid border in use", t.invalid_border as f64),
            ("resident_bytes", "gauge", "Bytes in tiles and windows", t.resident_bytes as f64),
            ("requests_seen_total", "counter", "Centre requests made through the mapping", t.requests_seen as f64),
            ("lod_requests_total", "counter", "LOD requests applied, every view's", t.lod_requests as f64),
            (
                "lod_requests_refused_total",
                "counter",
                "LOD requests refused (bad numbers)",
                t.lod_requests_refused as f64,
            ),
            (
                "position_requests_total",
                "counter",
                "Centre requests in longitude / latitude or map coordinates taken",
                t.position_requests as f64,
            ),
            (
                "position_requests_refused_total",
                "counter",
                "Centre requests in longitude / latitude or map coordinates refused",
                t.position_requests_refused as f64,
            ),
            ("control_connections_total", "counter", "Control connections accepted", c.accepted as f64),
            ("control_connections_refused_total", "counter", "Control connections refused (limit)", c.refused as f64),
            ("control_connections_open", "gauge", "Control connections open", c.open as f64),
            ("control_requests_ok_total", "counter", "Control requests answered OK", c.ok as f64),
            ("control_requests_err_total", "counter", "Control requests answered ERR", c.errors as f64),
        ]
    }

    /// A remote source's counters (nothing for local files).
    #[cfg(feature = "remote")]
    fn remote_prometheus(&self) -> String {
        let mut out = String::new();
        if let Some(r) = &self.tick.remote {
            let remote = [
                ("remote_requests_total", "counter", "Remote requests sent, retries included", r.requests),
                ("remote_retries_total", "counter", "Remote requests retried", r.retries),
                ("remote_merged_total", "counter", "Ranges read by a merged remote request", r.merged),
                ("remote_bytes_total", "counter", "Bytes received from remote stores", r.bytes),
                ("remote_failures_total", "counter", "Remote ranges that failed after retries", r.failures),
                ("remote_cache_hits_total", "counter", "Ranges served from the disk cache", r.cache_hits),
                ("remote_peak_in_flight", "gauge", "Most remote requests in flight to one endpoint", r.peak_in_flight),
                ("remote_duplicate_reads_total", "counter", "Remote reads of bytes fetched before", r.duplicate_reads),
                (
                    "remote_duplicate_bytes_total",
                    "counter",
                    "Bytes fetched from remote stores more than once",
                    r.duplicate_bytes,
                ),
            ];
            for (name, kind, help, v) in remote {
                out.push_str(&self.sample(name, kind, help, v));
            }
        }
        out
    }

    /// Each stream server's read latency the adaptive paging measured (ticks), label `stream`
    /// (nothing before the first tick).
    fn stream_latency_prometheus(&self) -> String {
        let latency = &self.tick.engine.stream_read_latency_ticks;
        if latency.is_empty() {
            return String::new();
        }
        let mut out = String::from(
            "# HELP clipmapd_stream_read_latency_ticks Read latency the adaptive paging measured on the stream server, ticks from asking for a tile to taking it\n# TYPE clipmapd_stream_read_latency_ticks gauge\n",
        );
        for (i, l) in latency.iter().enumerate() {
            out.push_str(&format!("clipmapd_stream_read_latency_ticks{{name=\"{}\",stream=\"{i}\"}} {l}\n", self.name));
        }
        out
    }

    /// The per-level paging families (nothing before the first tick): the read-ahead on each
    /// axis in tiles and in level texels, the grid, and the reason as one 0/1 sample per reason
    /// (the current one 1), labels `name`, `level` (and `axis` s or t, or `reason`).
    fn paging_prometheus(&self) -> String {
        use clipmap::paging::adaptive::Reason;
        let paging = &self.tick.engine.paging;
        if paging.is_empty() {
            return String::new();
        }
        let name = &self.name;
        let mut out = String::new();
        type PerAxis = fn(&clipmap::paging::adaptive::LevelPaging) -> [u64; 2];
        let axes: [(&str, &str, PerAxis); 3] = [
            ("paging_lead_tiles", "Tiles the mem region holds beyond the window along the motion", |p| p.lead_tiles),
            ("paging_lead_texels", "Read-ahead the adaptive paging asked for beyond the window, level texels", |p| {
                p.lead_texels
            }),
            ("paging_grid_tiles", "Tiles of the level's grid", |p| p.grid),
        ];
        for (metric, help, get) in axes {
            out.push_str(&format!("# HELP clipmapd_{metric} {help}\n# TYPE clipmapd_{metric} gauge\n"));
            for (k, p) in paging.iter().enumerate() {
                for (a, axis) in ["s", "t"].iter().enumerate() {
                    out.push_str(&format!(
                        "clipmapd_{metric}{{name=\"{name}\",level=\"{k}\",axis=\"{axis}\"}} {}\n",
                        get(p)[a]
                    ));
                }
            }
        }
        let reasons = [
            Reason::Fixed,
            Reason::Hover,
            Reason::KeepingUp,
            Reason::SourceBound,
            Reason::BudgetBound,
            Reason::BeyondGrid,
        ];
        out.push_str(
            "# HELP clipmapd_paging_reason Why the level reads ahead as far as it does (1: the current reason)\n# TYPE clipmapd_paging_reason gauge\n",
        );
        for (k, p) in paging.iter().enumerate() {
            for r in reasons {
                out.push_str(&format!(
                    "clipmapd_paging_reason{{name=\"{name}\",level=\"{k}\",reason=\"{}\"}} {}\n",
                    r.name(),
                    u8::from(p.reason == r)
                ));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prometheus_text_has_one_sample_per_metric() {
        let s = ServiceStats { name: "x".into(), tick: TickStats::default(), control: ControlStats::default() };
        let text = s.prometheus();
        let samples: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
        assert_eq!(samples.len(), 34);
        assert!(samples.iter().all(|l| l.starts_with("clipmapd_") && l.contains("{name=\"x\"} ")));
        assert_eq!(text.lines().filter(|l| l.starts_with("# TYPE")).count(), 34);
    }

    #[cfg(feature = "remote")]
    #[test]
    fn prometheus_text_has_the_remote_counters_of_a_remote_source_only() {
        let mut s = ServiceStats { name: "x".into(), ..ServiceStats::default() };
        assert!(!s.prometheus().contains("remote"), "a local source has no remote counters");
        s.tick.remote =
            Some(clipmap::source::remote::RemoteStats { requests: 7, bytes: 4096, merged: 3, ..Default::default() });
        let text = s.prometheus();
        for want in [
            "clipmapd_remote_requests_total{name=\"x\"} 7",
            "clipmapd_remote_bytes_total{name=\"x\"} 4096",
            "clipmapd_remote_merged_total{name=\"x\"} 3",
            "clipmapd_remote_retries_total{name=\"x\"} 0",
        ] {
            assert!(text.contains(want), "{want} in\n{text}");
        }
    }

    #[test]
    fn prometheus_text_has_each_levels_lead_grid_and_reason_and_the_latency() {
        use clipmap::paging::adaptive::{LevelPaging, Reason};
        let mut s = ServiceStats { name: "x".into(), ..ServiceStats::default() };
        s.tick.engine.read_latency_ticks = 4.5;
        s.tick.engine.stream_read_latency_ticks = vec![4.5, 1.25];
        s.tick.engine.paging = vec![
            LevelPaging {
                lead_tiles: [2, 0],
                lead_texels: [320, 0],
                grid: [8, 8],
                reason: Reason::SourceBound,
                read_latency_ticks: 4.5,
            },
            LevelPaging { grid: [7, 7], reason: Reason::Hover, ..LevelPaging::default() },
        ];
        let text = s.prometheus();
        for want in [
            "clipmapd_read_latency_ticks{name=\"x\"} 4.5",
            "clipmapd_stream_read_latency_ticks{name=\"x\",stream=\"0\"} 4.5",
            "clipmapd_stream_read_latency_ticks{name=\"x\",stream=\"1\"} 1.25",
            "clipmapd_paging_lead_tiles{name=\"x\",level=\"0\",axis=\"s\"} 2",
            "clipmapd_paging_lead_texels{name=\"x\",level=\"0\",axis=\"s\"} 320",
            "clipmapd_paging_lead_texels{name=\"x\",level=\"0\",axis=\"t\"} 0",
            "clipmapd_paging_grid_tiles{name=\"x\",level=\"1\",axis=\"t\"} 7",
            "clipmapd_paging_reason{name=\"x\",level=\"0\",reason=\"source_bound\"} 1",
            "clipmapd_paging_reason{name=\"x\",level=\"0\",reason=\"hover\"} 0",
            "clipmapd_paging_reason{name=\"x\",level=\"1\",reason=\"hover\"} 1",
        ] {
            assert!(text.lines().any(|l| l == want), "{want} missing:\n{text}");
        }
        // Per family one HELP and one TYPE; 34 plain metrics, 2 streams' latencies, 3 x 2 levels
        // x 2 axes, 2 x 6 reasons.
        let samples = text.lines().filter(|l| !l.starts_with('#')).count();
        assert_eq!(samples, 34 + 2 + 12 + 12);
        assert_eq!(text.lines().filter(|l| l.starts_with("# TYPE")).count(), 39);
        let ones = text.lines().filter(|l| l.starts_with("clipmapd_paging_reason") && l.ends_with(" 1")).count();
        assert_eq!(ones, 2, "one current reason a level");
    }
}

/// One view's figures in `STATS` and `VIEWS`.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ViewStats {
    /// Its name (`main`: the primary).
    pub name: String,
    /// `shared`: it shares the primary's grids; `own`: it has grids of its own, in the mapping
    /// `NAME@VIEW` (docs/VIEWS.md, "Views far apart").
    #[serde(default)]
    pub grids: String,
    /// A view with grids of its own: tiles its grids took from the primary's rather than read
    /// from the source again (0 for a view sharing the primary's grids).
    #[serde(default)]
    pub shared_reads: u64,
    /// Its weight.
    pub weight: f64,
    /// Its level-0 centre as the last tick applied it (`null` before its first).
    pub centre: Option<[i64; 2]>,
    /// That centre's WGS 84 `[longitude, latitude]` (its texel's middle; `null` before its
    /// first tick or when the texture has no georeferencing).
    #[serde(default)]
    pub centre_lonlat: Option<[f64; 2]>,
    /// Its min LOD.
    pub min_lod: f64,
    /// Its levels renderers may not use now.
    pub levels_disabled: u64,
    /// Its published valid region per level, `[s0, t0, s1, t1]`.
    pub valid: Vec<[i64; 4]>,
    /// The finest level it shows (its LOD offset; docs/VIEWS.md, "Virtual views").
    #[serde(default)]
    pub lod_offset: u32,
    /// How many levels from the offset it shows (the texture's level count at most).
    #[serde(default)]
    pub effective_levels: u32,
    /// The levels it shows whose grids hold part of its windows now.
    #[serde(default)]
    pub resident_levels: Vec<u32>,
}
