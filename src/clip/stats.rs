//! [`Stats`] and [`TickReport`]: every decision the update tick makes, counted.
//!
//! Owns the counters only; [`super`] increments them.

use crate::geom::Rect;
use crate::paging::adaptive::LevelPaging;
use crate::queue::QueueStats;
use crate::source::FaultKind;
use crate::source::PoolStats;
use serde::Serialize;

/// Read failures by kind.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(default)]
pub struct FaultCounts {
    /// The tile (or its file) did not exist ([`FaultKind::Missing`]).
    pub missing: u64,
    /// Fewer bytes than a tile were there ([`FaultKind::Short`]).
    pub short: u64,
    /// The data had the wrong size or layout ([`FaultKind::Corrupt`]).
    pub corrupt: u64,
    /// The tile could not be read for its permissions ([`FaultKind::PermissionDenied`]).
    pub permission_denied: u64,
    /// Any other I/O failure ([`FaultKind::Io`]).
    pub io: u64,
    /// A request outside the texture or into a wrong-sized buffer ([`FaultKind::BadRequest`]).
    pub bad_request: u64,
}

impl FaultCounts {
    /// Counts one failure.
    pub fn add(&mut self, kind: FaultKind) {
        match kind {
            FaultKind::Missing => self.missing += 1,
            FaultKind::Short => self.short += 1,
            FaultKind::Corrupt => self.corrupt += 1,
            FaultKind::PermissionDenied => self.permission_denied += 1,
            FaultKind::Io => self.io += 1,
            FaultKind::BadRequest => self.bad_request += 1,
        }
    }

    /// All failures.
    pub fn total(&self) -> u64 {
        self.missing + self.short + self.corrupt + self.permission_denied + self.io + self.bad_request
    }
}

/// Counters since the clipmap started.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
#[serde(default)]
pub struct Stats {
    /// Update ticks run.
    pub ticks: u64,
    /// Texel bytes the update tick wrote into slots itself: always 0. The mapping has no copy
    /// path, and slot bytes are written only by tile reads on the read queues' threads, a growing
    /// texture's rebuilt tiles included ([`super::Clipmap::refresh`]); kept as the figure that
    /// shows it.
    pub tick_texel_bytes: u64,
    /// Tiles read into their slots and settled.
    pub tiles_read: u64,
    /// Of those, slots given the configuration's default tile.
    pub default_tiles: u64,
    /// Reads that failed, by kind.
    pub read_faults: FaultCounts,
    /// Tiles that arrived after leaving their mem region (discarded).
    pub late_tiles: u64,
    /// Settled tiles whose slots went to other tiles because their mem region moved.
    pub tiles_evicted: u64,
    /// Settled tiles read again into their slots in place because the source's texels changed
    /// (a growing texture, [`super::Clipmap::refresh`]): replacement reads taken, ready or
    /// default (a failed one is counted in `read_faults`).
    pub tiles_replaced: u64,
    /// Times the source said that every tile may have changed ([`crate::source::TileSource::version`]:
    /// a remote COG replaced in its store and opened again), each followed by reading every tile
    /// held again (counted in `tiles_replaced` as they land).
    pub source_versions: u64,
    /// Ticks whose budget ran out with finished reads left for the next tick.
    pub ticks_over_budget: u64,
    /// Finished reads left for a later tick by a spent budget.
    pub reads_deferred: u64,
    /// Level publications short of the whole valid region because tiles were still loading.
    pub levels_waiting_for_tiles: u64,
    /// Ticks with at least one level disabled (below min LOD).
    pub ticks_with_disabled_level: u64,
    /// Times min LOD was raised.
    pub min_lod_raises: u64,
    /// Ticks on which min LOD faded down.
    pub min_lod_fades: u64,
    /// Ticks on which the centre's speed was clamped.
    pub centre_clamps: u64,
    /// Snapshots published (one per tick).
    pub publications: u64,
    /// Slots given to another tile while the current snapshot still covered their settled tile:
    /// the writer's invariant, checked at every assignment (always 0; counted so that tests and
    /// `STATS` can prove it).
    pub slots_reassigned_under_published: u64,
    /// Settled slots given to another tile while a further view's published region covered them
    /// (`super::views`): the same invariant for every view, always 0.
    pub slots_reassigned_under_views: u64,
    /// Time the ticks themselves took, all ticks (ns).
    pub tick_ns: u64,
    /// Most bytes the image caches held (their whole memory).
    pub peak_resident_bytes: u64,
    /// The read queues' counters (summed over stream servers).
    pub queue: QueueStats,
    /// Reads the source put off (a simulated disk had spent its reads for the tick); their
    /// tiles stayed wanted.
    pub reads_put_off: u64,
    /// The second-level tile pool's counters (all 0 without a pool), as of the end of the last
    /// tick: the reads it asked for run on meanwhile ([`super::Clipmap::pool`] has the live ones).
    pub pool: PoolStats,
    /// Each level's paging as the last tick chose it: read-ahead in tiles, grid, and why
    /// ([`crate::paging::adaptive`]; reason `fixed` for the fixed policies).
    pub paging: Vec<LevelPaging>,
    /// The read latency the adaptive controller plans with (ticks from asking for a tile to
    /// taking it, held at its recent peak; 0 for the fixed policies): the slowest stream
    /// server's, [`stream_read_latency_ticks`](Self::stream_read_latency_ticks) has each one's.
    pub read_latency_ticks: f64,
    /// Each stream server's read latency, in server order (ticks, as `read_latency_ticks`; 0
    /// for the fixed policies). A level plans with the slowest of the servers that read its
    /// tiles (`paging[].read_latency_ticks`).
    pub stream_read_latency_ticks: Vec<f64>,
}

/// What one tick did.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TickReport {
    /// Level-0 centre applied (after any speed clamp).
    pub centre: [i64; 2],
    /// Whether the speed clamp (`Settings::max_centre_step`) moved the centre this tick.
    pub clamped: bool,
    /// Level-0 texels per tick the look-ahead used: the velocity given, or else the centre's
    /// change since the last tick (0 on the first).
    pub velocity: [i64; 2],
    /// Tiles settled this tick.
    pub tiles_read: u64,
    /// Tiles replaced in their slots this tick: replacement reads taken ([`super::Clipmap::refresh`]).
    pub tiles_replaced: u64,
    /// Min LOD after the tick.
    pub min_lod: f64,
    /// Levels renderers may not use after the tick (finer than min LOD).
    pub disabled_levels: Vec<u32>,
    /// Whether the tick's budget ran out with finished reads left for the next tick.
    pub over_budget: bool,
    /// Time the tick took (ns).
    pub tick_ns: u64,
    /// Published valid region per level after the tick.
    pub valid: Vec<Rect>,
}
