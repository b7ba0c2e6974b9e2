//! What `clipbench views` reports: a row per scenario and design, the goals and their checks.

use super::*;

/// One run: a scenario flown by one design.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// The scenario: `near`, `far` or `weighted`.
    pub name: &'static str,
    /// `one_view` (view 0 alone), `views_spread_N` (one clipmap, `view_spread` N),
    /// `separate_grids[_shared_pool]`, `weights_3_1`, `weights_1_1`, `one_view_same_grids`.
    pub design: String,
    /// The design the ratios are against: view 0 alone (`one_view`; `one_view_ring` for the
    /// `_ring` designs), over the alone disk.
    pub baseline: &'static str,
    /// Where each grid puts its spare tiles (`adaptive`: the engine's default).
    pub prefetch: &'static str,
    pub views: usize,
    pub weights: Vec<f64>,
    pub clipmaps: usize,
    pub view_spread: u64,
    /// Level 0's grid, tiles per axis (each clipmap's).
    pub level0_grid: [u64; 2],
    pub disk_tiles_per_tick: u64,
    /// The shared pool's budget (0: none).
    pub pool_bytes: u64,
    /// Reads that reached the texture, start and flight.
    pub tiles_read: u64,
    /// The same, flight ticks only.
    pub flight_tiles_read: u64,
    /// Distinct tiles, all levels, that some view's window touched at some tick: what any design
    /// must read at least once.
    pub window_tiles: u64,
    /// Most bytes held at the end of a tick: every clipmap's mapping plus the pool's tiles.
    pub peak_resident_bytes: u64,
    /// Every clipmap's mapping.
    pub mapping_bytes: u64,
    /// Mean over the events of the slowest view's settle ticks (null: a view did not settle).
    pub settle_ticks: Option<f64>,
    pub views_never_settled: usize,
    /// Mean over the views of each view's mean min LOD over the flight.
    pub mean_min_lod: f64,
    pub view_mean_min_lod: Vec<f64>,
    /// Each view's mean settle ticks over the events (null: not settled after some event).
    pub view_settle_ticks: Vec<Option<f64>>,
    /// Each view's settle ticks after each event (the start, then each jump).
    pub view_settle_events: Vec<Vec<Option<u64>>>,
    /// The same view flown alone (one clipmap, default grids, the alone disk).
    pub view_settle_alone_ticks: Vec<Option<f64>>,
    /// Ticks of the start phase.
    pub start_ticks: u64,
    /// `tiles_read` over the baseline's.
    pub tiles_read_vs_one: f64,
    /// `window_tiles` over the baseline's: the least `tiles_read_vs_one` any design could reach
    /// (if every tile were read once).
    pub window_tiles_vs_one: f64,
    /// `peak_resident_bytes` over the baseline's.
    pub resident_vs_one: f64,
    /// Largest over the views of `view_settle_ticks` over `view_settle_alone_ticks`.
    pub settle_vs_alone: Option<f64>,
    /// `weighted`: view 0's mean min LOD here less its mean min LOD alone (`one_view`).
    pub heavy_min_lod_delta: Option<f64>,
    /// Reads the shared pool served.
    pub pool_hits: u64,
    /// Reads the disk put off to a later tick.
    pub reads_put_off: u64,
    /// Always 0: slots under a further view's published region given to another tile.
    pub slots_reassigned_under_views: u64,
    /// Always 0: the same for the primary's.
    pub slots_reassigned_under_published: u64,
}

/// How `weighted`'s disk was chosen.
#[derive(Clone, Debug, Serialize)]
pub struct WeightedDisk {
    /// View 0's reads per flight tick alone, default grids, unthrottled.
    pub one_view_need_per_tick: f64,
    /// Both views' reads per flight tick in the 3:1 clipmap, unthrottled.
    pub both_views_need_per_tick: f64,
    /// `ceil(1.25 x one_view_need_per_tick)`.
    pub disk_tiles_per_tick: u64,
    /// Whether the disk is below both views' need (the scenario's premise).
    pub too_slow_for_both: bool,
    /// `weighted_tight`'s disk: one tile a tick less than `disk_tiles_per_tick` (at least 1), about
    /// one view's need.
    pub tight_disk_tiles_per_tick: u64,
}

/// `far`: what holding every far view in one clipmap's grids would take.
#[derive(Clone, Debug, Serialize)]
pub struct FarSpread {
    /// Level-0 texels between the farthest views along an axis (the `view_spread` needed).
    pub spread_needed: u64,
    /// The mapping of one clipmap with that spread (computed, not flown).
    pub mapping_bytes: u64,
    /// That over one view's mapping.
    pub vs_one: f64,
}

/// One design's check against its scenario's goal.
#[derive(Clone, Debug, Serialize)]
pub struct GoalCheck {
    pub design: String,
    /// The goal's bounds as stated.
    pub met: bool,
    /// Every view settled at level 0 after every event.
    pub all_views_at_level_0: bool,
    /// The bounds missed, with the figures.
    pub why: String,
}

/// One goal of the issue.
#[derive(Clone, Debug, Serialize)]
pub struct Goal {
    pub goal: &'static str,
    /// Met by a design of the engine's views (one clipmap), its views all at level 0.
    pub met: bool,
    /// Every design meeting the bounds as stated (separate clipmaps included).
    pub met_by: Vec<String>,
    pub designs: Vec<GoalCheck>,
}

/// The goals.
#[derive(Clone, Debug, Serialize)]
pub struct Goals {
    pub near: Goal,
    pub far: Goal,
    pub weighted: Goal,
}

/// The whole benchmark.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub setup: Setup,
    pub scenarios: Vec<Row>,
    pub weighted_disk: WeightedDisk,
    pub far_spread: FarSpread,
    pub goals: Goals,
}
