//! [`Stats`] and [`TickReport`]: every decision the update tick makes, counted.
//!
//! Owns the counters only; [`super`] increments them.

use crate::geom::Rect;
use crate::queue::QueueStats;
use crate::source::FaultKind;
use serde::Serialize;

/// Read failures by kind.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(default)]
pub struct FaultCounts {
    pub missing: u64,
    pub short: u64,
    pub corrupt: u64,
    pub permission_denied: u64,
    pub io: u64,
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
    /// Texel bytes copied from tiles into windows.
    pub bytes_copied: u64,
    /// Bands copied.
    pub bands_copied: u64,
    /// Tiles read and admitted to the cache.
    pub tiles_read: u64,
    /// Reads that failed, by kind.
    pub read_faults: FaultCounts,
    /// Tiles that arrived after leaving their mem region (discarded).
    pub late_tiles: u64,
    /// Tiles refused because the cache's byte budget was spent.
    pub tiles_over_cache_budget: u64,
    /// Resident tiles evicted because their mem region moved.
    pub tiles_evicted: u64,
    /// Ticks on which the copy budget ran out with work left.
    pub ticks_over_budget: u64,
    /// Level updates stopped by a tile that was not resident.
    pub levels_waiting_for_tiles: u64,
    /// Level updates stopped by the copy budget.
    pub levels_out_of_budget: u64,
    /// Ticks with at least one level disabled (below min LOD).
    pub ticks_with_disabled_level: u64,
    /// Times min LOD was raised.
    pub min_lod_raises: u64,
    /// Ticks on which min LOD faded down.
    pub min_lod_fades: u64,
    /// Ticks on which the centre's speed was clamped.
    pub centre_clamps: u64,
    /// Publications of the levels' state (two per tick).
    pub publications: u64,
    /// Texel writes that landed inside a published valid region. Always 0; counted so that
    /// tests can prove it.
    pub writes_into_published: u64,
    /// Estimated copy time spent, all ticks (ns).
    pub estimated_copy_ns: f64,
    /// Most bytes held in tiles and windows together.
    pub peak_resident_bytes: u64,
    /// The read queues' counters (summed over stream servers).
    pub queue: QueueStats,
}

/// What one tick did.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TickReport {
    /// Level-0 centre applied (after any speed clamp).
    pub centre: [i64; 2],
    /// Texel bytes copied this tick.
    pub bytes_copied: u64,
    /// Tiles admitted this tick.
    pub tiles_read: u64,
    /// Min LOD after the tick.
    pub min_lod: f64,
    /// Levels renderers may not use after the tick (finer than min LOD).
    pub disabled_levels: Vec<u32>,
    /// Whether the copy budget ran out with work left.
    pub over_budget: bool,
    /// Estimated copy time spent (ns).
    pub estimated_copy_ns: f64,
    /// Published valid region per level after the tick.
    pub valid: Vec<Rect>,
}
