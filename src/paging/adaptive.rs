//! Adaptive paging: each level's read-ahead sized from the viewer's measured motion and the
//! source's measured latency, within grids sized from a memory budget.
//!
//! The read-ahead a level needs along an axis is the number of tiles that enter its window while
//! a read issued now is still in flight: `speed x latency` in level texels, rounded up to whole
//! tiles ([`LevelPaging::lead_tiles`]). The speed is the centre's motion smoothed over a few ticks
//! ([`Motion`]: a reversal takes the new direction at once, a jump recentres), the latency the
//! ticks from asking for a tile to taking it, held at its recent peak and decaying slowly
//! ([`Latency`]), measured per stream server: each level plans with the slowest of the servers
//! that read its tiles ([`StreamMeasures`], which also measures each server's tile rate). The mem region ([`region`]) is then the ring of the default (lookahead-1) grid,
//! extended ahead of the motion until the lead lies beyond the window, as far as the grid allows:
//! at hover and on slow flights it is the ring itself (no more tiles read than the ring reads),
//! on a fast straight flight it is `ahead` with the needed distance, and after a jump it is
//! centred again.
//!
//! The grids themselves are sized once, at start, from a byte budget (`budget_grids`): every
//! level gets the default lookahead-1 grid plus `E >> k` spare tiles per axis (a level's texels
//! move half as fast as the next finer level's), with the largest `E` the budget allows. The
//! default budget is `DEFAULT_BUDGET_FACTOR` times the bytes of the lookahead-1 grids, capped
//! by the engine's `cache_bytes`. Grids a configuration fixes (`mem_region_size`, an explicit
//! lookahead) are kept as they are and reported as fixed.

use super::{needed, ring, Prefetch};
use crate::geom::{mem_grid, tiles_in_level, LevelShape, Rect};
use serde::Serialize;

/// The default grid budget, as a multiple of the bytes of the default (lookahead 1) grids.
pub(crate) const DEFAULT_BUDGET_FACTOR: u64 = 2;

/// Ticks of latency assumed before any read has been measured (a read asked for at the end of
/// one tick is taken at the start of the next at the earliest).
pub(crate) const INITIAL_LATENCY_TICKS: f64 = 1.0;

/// Adaptive placement as a pure policy: the lead of a one-tick latency (what the engine uses
/// before it has measured reads, and what `clipbench policies` compares with no measurements).
#[derive(Clone, Copy, Debug, Default)]
pub struct Adaptive;

impl Prefetch for Adaptive {
    fn mem_region(&self, shape: &LevelShape, tex: Rect, velocity: [i64; 2], _previous: Rect) -> Rect {
        let lead = velocity.map(|v| lead_texels(v.unsigned_abs() as f64, INITIAL_LATENCY_TICKS));
        region(shape, tex, velocity, lead)
    }
}

/// The level texels a window moving `speed` level texels a tick travels while a read that takes
/// `latency_ticks` ticks (from the tick that asks for it to the tick that takes it) is in flight,
/// rounded up: how far beyond the window's edge tiles must be asked for.
pub fn lead_texels(speed: f64, latency_ticks: f64) -> u64 {
    if !(speed.is_finite() && latency_ticks.is_finite()) || speed <= 0.0 || latency_ticks <= 0.0 {
        return 0;
    }
    // Bounded far beyond any level before the conversion, so no float reaches u64's edge.
    (speed * latency_ticks).ceil().min(1e15) as u64
}

/// The mem region of a level whose window is `tex`, moving with the sign of `velocity` on each
/// axis, with tiles wanted up to `lead` level texels beyond the window's edge along each moving
/// axis: the ring of the lookahead-1 grid (the tiles the window can touch and a margin around
/// them, centred on the window), extended ahead of the motion until it holds the tile `lead`
/// texels past the window's edge, at most the level's grid (what does not fit is cut behind). A
/// still axis, or a lead the ring's own margin already holds, is exactly the ring: slow and
/// swaying flights read what the ring reads. It always holds every tile `tex` touches and stays
/// inside the level.
pub fn region(shape: &LevelShape, tex: Rect, velocity: [i64; 2], lead: [u64; 2]) -> Rect {
    let (need, n) = needed(shape, tex);
    if need.is_empty() {
        return need;
    }
    let base = mem_grid(shape.size, shape.tile, shape.clip, 1);
    let mid = ring::middle(tex);
    let edges = [(tex.s0, tex.s1), (tex.t0, tex.t1)];
    let axis = |a: usize, lo: i64, hi: i64| -> (i64, i64) {
        let (g, e) = (shape.grid[a] as i64, shape.tile[a] as i64);
        let len = (base[a] as i64).min(g).max(hi - lo);
        let o = ring::centred(lo, hi, mid[a], shape.tile[a], len as u64, n[a]);
        let (mut r0, mut r1) = (o, o + len);
        // The lead, at most what the grid can hold beside the window's tiles.
        let most = (g - (hi - lo)).max(0).saturating_mul(e);
        let lead = (lead[a].min(i64::MAX as u64) as i64).min(most);
        // A lead of a tile or more that reaches the level's edge (not on a level that wraps
        // around there): a flight there can only turn back or stop, so the grid's tiles the edge
        // leaves unused keep the way it came, which a fast flight crosses again at once if it
        // turns. A slower flight keeps the ring (it reads no tile the ring does not).
        let edge = !(shape.wrap && a == 0) && lead >= e;
        match velocity[a].signum() {
            1 => {
                let front = (edges[a].1 + lead + e - 1).div_euclid(e);
                r1 = r1.max(front.min(hi + (g - (hi - lo)))).min(n[a] as i64);
                r0 = r0.max(r1 - g);
                if edge && front >= n[a] as i64 {
                    r0 = (r1 - g).max(0);
                }
            }
            -1 => {
                let front = (edges[a].0 - lead).div_euclid(e);
                r0 = r0.min(front.max(lo - (g - (hi - lo)))).max(0);
                r1 = r1.min(r0 + g);
                if edge && front <= 0 {
                    r1 = (r0 + g).min(n[a] as i64);
                }
            }
            _ => {}
        }
        (r0, r1)
    };
    let (s0, s1) = axis(0, need.s0, need.s1);
    let (t0, t1) = axis(1, need.t0, need.t1);
    Rect::new(s0, t0, s1, t1)
}

/// The grids of levels `(size, tile)` for clip size `clip` and `tile_bytes(k)` bytes a tile:
/// each the lookahead-1 grid plus `E >> k` tiles per axis (at most the level's tiles), with the
/// largest `E` whose grids fit in `budget` bytes. Returns the grids and `E`. A budget below the
/// lookahead-1 grids gives those grids (`E` = 0).
pub(crate) fn budget_grids(
    levels: &[([u64; 2], [u64; 2])],
    clip: u64,
    tile_bytes: impl Fn(usize) -> u64,
    budget: u64,
) -> (Vec<[u64; 2]>, u64) {
    let grids = |e: u64| -> Vec<[u64; 2]> {
        levels
            .iter()
            .enumerate()
            .map(|(k, &(size, tile))| {
                let base = mem_grid(size, tile, clip, 1);
                let n = tiles_in_level(size, tile);
                let extra = e.checked_shr(k as u32).unwrap_or(0);
                [0, 1].map(|a| base[a].saturating_add(extra).min(n[a]))
            })
            .collect()
    };
    let bytes = |g: &[[u64; 2]]| -> u64 {
        g.iter()
            .enumerate()
            .fold(0u64, |sum, (k, g)| sum.saturating_add(g[0].saturating_mul(g[1]).saturating_mul(tile_bytes(k))))
    };
    // Bytes grow with E: the largest E that fits, by doubling then bisection.
    let fits = |e: u64| bytes(&grids(e)) <= budget;
    if !fits(1) {
        return (grids(0), 0);
    }
    let mut hi = 2u64;
    let most = levels
        .iter()
        .map(|&(size, tile)| tiles_in_level(size, tile).iter().copied().max().unwrap_or(0))
        .max()
        .unwrap_or(0);
    while hi <= most && fits(hi) {
        hi *= 2;
    }
    let mut lo = hi / 2; // fits
    while hi - lo > 1 {
        let m = lo + (hi - lo) / 2;
        if fits(m) {
            lo = m;
        } else {
            hi = m;
        }
    }
    (grids(lo), lo)
}

/// Why a level reads ahead as far as it does, as `STATS`, `cliptex attach` and the tick log say.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Reason {
    /// A fixed policy, a grid a configuration fixes, or a grid that holds the whole level (a
    /// pyramid level): nothing is adapted.
    #[default]
    Fixed,
    /// Still: the ring of the default grid.
    Hover,
    /// Moving, with the whole lead the motion and the latency call for.
    KeepingUp,
    /// Moving, its window not whole while the lead is what it needs, or the lead needed more
    /// than the grid's spare tiles while the level's stream servers have reads waiting or
    /// deliver less than is asked of them ([`TileRate::short`]): the source does not deliver
    /// fast enough.
    SourceBound,
    /// The lead needed is more than the grid's spare tiles while the source keeps up: the memory
    /// budget limits it.
    BudgetBound,
    /// The window moves more than the grid's spare tiles in one tick: no read-ahead can keep it.
    BeyondGrid,
}

impl Reason {
    /// The name reports print.
    pub fn name(self) -> &'static str {
        match self {
            Reason::Fixed => "fixed",
            Reason::Hover => "hover",
            Reason::KeepingUp => "keeping_up",
            Reason::SourceBound => "source_bound",
            Reason::BudgetBound => "budget_bound",
            Reason::BeyondGrid => "beyond_grid",
        }
    }
}

/// One level's paging as the controller chose it this tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
#[serde(default)]
pub struct LevelPaging {
    /// Tiles the mem region holds beyond the window's along the motion, on s and t (0 on a
    /// still axis).
    pub lead_tiles: [u64; 2],
    /// The lead the controller asked for: level texels beyond the window's edge (speed x
    /// latency, held while it wavers).
    pub lead_texels: [u64; 2],
    /// The grid's tiles per axis.
    pub grid: [u64; 2],
    /// Why.
    pub reason: Reason,
    /// The read latency this level's lead plans with (ticks): the slowest of the stream servers
    /// that read its tiles ([`StreamMeasures::level`]; 0 for a fixed level).
    pub read_latency_ticks: f64,
}

/// The centre's motion, smoothed: level-0 texels a tick per axis.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Motion {
    /// The smoothed velocity.
    pub velocity: [f64; 2],
}

/// Weight of a new velocity sample in the smoothed one.
const MOTION_WEIGHT: f64 = 0.3;

impl Motion {
    /// Takes one tick's velocity `v`; `jump` is a move of more than `jump` level-0 texels on an
    /// axis, which recentres (the smoothed motion restarts at 0). A reversal on an axis takes the
    /// new velocity at once; a stop decays like any change.
    pub fn update(&mut self, v: [i64; 2], jump: u64) {
        for (vel, &va) in self.velocity.iter_mut().zip(&v) {
            let x = va as f64;
            let old = *vel;
            *vel = if va.unsigned_abs() > jump {
                0.0
            } else if x * old < 0.0 {
                x
            } else {
                old + MOTION_WEIGHT * (x - old)
            };
            if vel.abs() < 0.05 {
                *vel = 0.0;
            }
        }
    }

    /// The smoothed speed in level `k`'s texels a tick, per axis.
    pub(crate) fn speed_at_level(&self, k: u32) -> [f64; 2] {
        self.velocity.map(|x| x.abs() / (1u64 << k.min(62)) as f64)
    }

    /// The smoothed velocity in level `k`'s texels, rounded away from 0 to whole texels (a level
    /// whose texels move less than one a tick still moves).
    pub(crate) fn at_level(&self, k: u32) -> [i64; 2] {
        self.velocity.map(|x| {
            let y = x / (1u64 << k.min(62)) as f64;
            if y == 0.0 {
                0
            } else {
                (y.signum() * y.abs().ceil()).clamp(-1e15, 1e15) as i64
            }
        })
    }
}

/// The latency of reads in ticks, from asking for a tile to taking it: the largest recent
/// sample, decaying by a twentieth of the difference a sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Latency {
    /// The estimate (ticks).
    pub ticks: f64,
}

impl Default for Latency {
    fn default() -> Self {
        Latency { ticks: INITIAL_LATENCY_TICKS }
    }
}

/// The most ticks of latency the controller plans with (10 s at 60 ticks a second): a read that
/// took longer says the source is down, not how far to read ahead.
pub(crate) const MAX_LATENCY_TICKS: f64 = 600.0;

impl Latency {
    /// Takes one read's latency (ticks).
    pub fn sample(&mut self, ticks: u64) {
        let x = (ticks as f64).clamp(INITIAL_LATENCY_TICKS, MAX_LATENCY_TICKS);
        self.ticks = if x >= self.ticks { x } else { self.ticks + (x - self.ticks) / 20.0 };
    }

    /// A tick that measured no read: the estimate decays by a sixty-fourth of its distance from
    /// one tick, so that a peak measured while reads queued (a fill, a source that could not keep
    /// up) does not stay the plan for good.
    pub fn rest(&mut self) {
        self.ticks += (INITIAL_LATENCY_TICKS - self.ticks) / 64.0;
    }
}

/// Weight of a new tick's count in a smoothed [`TileRate`] (about the last eight ticks).
const RATE_WEIGHT: f64 = 0.125;

/// The share of the tiles asked of a stream server it must deliver to count as keeping up.
pub const KEEPING_UP_SHARE: f64 = 0.75;

/// A stream server's measured tile rate: the tiles first asked of it and the tiles it delivered,
/// a tick each, smoothed over about eight ticks.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TileRate {
    /// Tiles asked for a tick (each tile once, however often it is asked again while it loads).
    pub asked: f64,
    /// Tiles delivered (read and taken) a tick.
    pub delivered: f64,
}

impl TileRate {
    /// Takes one tick's counts.
    pub fn update(&mut self, asked: u64, delivered: u64) {
        self.asked += RATE_WEIGHT * (asked as f64 - self.asked);
        self.delivered += RATE_WEIGHT * (delivered as f64 - self.delivered);
    }

    /// Whether the server delivers less than [`KEEPING_UP_SHARE`] of the tiles asked of it, at
    /// least one tile a tick being asked: it cannot keep up at any lead (the tiles it does not
    /// deliver leave their mem regions unread, or wait).
    pub fn short(&self) -> bool {
        self.asked >= 1.0 && self.delivered < KEEPING_UP_SHARE * self.asked
    }
}

/// Each stream server's read latency and tile rate, and which stream servers read each level's
/// tiles: a level plans its lead with the slowest of its own streams, so a slow stream lengthens
/// the leads of the levels it serves and no other's. With one stream every level plans with its
/// latency.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StreamMeasures {
    /// Per stream server, in server order.
    streams: Vec<Latency>,
    /// Per stream server, in server order.
    rates: Vec<TileRate>,
    /// Per level, per stream server: whether the server reads some tile of the level asked for
    /// so far.
    levels: Vec<Vec<bool>>,
}

impl StreamMeasures {
    /// `streams` stream servers (at least one) serving `levels` levels, nothing measured yet.
    pub fn new(streams: usize, levels: usize) -> Self {
        let streams = streams.max(1);
        StreamMeasures {
            streams: vec![Latency::default(); streams],
            rates: vec![TileRate::default(); streams],
            levels: vec![vec![false; streams]; levels],
        }
    }

    /// Takes one tick's tile counts of stream server `stream` (ignored out of range).
    pub fn count(&mut self, stream: usize, asked: u64, delivered: u64) {
        if let Some(r) = self.rates.get_mut(stream) {
            r.update(asked, delivered);
        }
    }

    /// Each stream server's tile rate, in server order.
    pub fn rates(&self) -> &[TileRate] {
        &self.rates
    }

    /// Whether a stream server that reads level `level`'s tiles (any server, before it has asked
    /// for a tile) delivers less than is asked of it ([`TileRate::short`]).
    pub(crate) fn level_short(&self, level: usize) -> bool {
        let mut own = self.streams_of(level).peekable();
        if own.peek().is_some() {
            own.any(|s| self.rates[s].short())
        } else {
            self.rates.iter().any(|r| r.short())
        }
    }

    /// Notes that stream server `stream` reads a tile of level `level` (ignored out of range).
    pub fn note(&mut self, level: usize, stream: usize) {
        if let Some(on) = self.levels.get_mut(level).and_then(|l| l.get_mut(stream)) {
            *on = true;
        }
    }

    /// Takes one read's latency (ticks) on stream server `stream` (ignored out of range).
    pub fn sample(&mut self, stream: usize, ticks: u64) {
        if let Some(l) = self.streams.get_mut(stream) {
            l.sample(ticks);
        }
    }

    /// A tick on which stream server `stream` measured no read ([`Latency::rest`]).
    pub fn rest(&mut self, stream: usize) {
        if let Some(l) = self.streams.get_mut(stream) {
            l.rest();
        }
    }

    /// Number of stream servers.
    pub(crate) fn stream_count(&self) -> usize {
        self.streams.len()
    }

    /// Each stream server's latency (ticks), in server order.
    pub fn per_stream(&self) -> Vec<f64> {
        self.streams.iter().map(|l| l.ticks).collect()
    }

    /// The stream servers known to read level `level`'s tiles (none before it asked for one).
    pub(crate) fn streams_of(&self, level: usize) -> impl Iterator<Item = usize> + '_ {
        self.levels.get(level).into_iter().flat_map(|l| l.iter().enumerate().filter(|(_, &on)| on).map(|(s, _)| s))
    }

    /// The latency level `level` plans with (ticks): the slowest of the stream servers that read
    /// its tiles, or of all of them before it has asked for a tile.
    pub fn level(&self, level: usize) -> f64 {
        self.streams_of(level).map(|s| self.streams[s].ticks).reduce(f64::max).unwrap_or_else(|| self.slowest())
    }

    /// The slowest stream server's latency (ticks).
    pub fn slowest(&self) -> f64 {
        self.streams.iter().map(|l| l.ticks).fold(INITIAL_LATENCY_TICKS, f64::max)
    }
}

/// The lead (texels) a level keeps: it grows at once and shrinks by at most a sixteenth a tick,
/// so that a speed that wavers does not read and evict the same tiles over and over.
pub(crate) fn held_lead(previous: u64, needed: u64) -> u64 {
    if needed >= previous {
        needed
    } else {
        needed.max(previous - (previous / 16).max(1))
    }
}

/// The reason for one level's paging: `speed` level texels a tick on an axis, `needed` the lead
/// in texels the motion calls for, `whole` whether the level's valid region is whole. The grid
/// holds a lead of at most its spare tiles beyond the window's. The clipmap turns a
/// [`Reason::BudgetBound`] of a level that is not whole into [`Reason::SourceBound`] when the
/// level's stream servers do not keep up (this function does not see them).
pub fn reason(shape: &LevelShape, speed: [u64; 2], needed: [u64; 2], whole: bool) -> Reason {
    let n = tiles_in_level(shape.size, shape.tile);
    if shape.grid[0] >= n[0] && shape.grid[1] >= n[1] {
        // The grid holds the whole level (a pyramid level, or a small one): nothing to page.
        return Reason::Fixed;
    }
    if speed == [0, 0] {
        return Reason::Hover;
    }
    let touch = mem_grid(shape.size, shape.tile, shape.clip, 0);
    for a in 0..2 {
        // A window at the level's edge on an axis (the grid holds the whole axis) never needs more.
        if shape.grid[a] >= n[a] {
            continue;
        }
        let spare_texels = shape.grid[a].saturating_sub(touch[a]).saturating_mul(shape.tile[a]);
        if speed[a] > spare_texels {
            return Reason::BeyondGrid;
        }
        if needed[a] > spare_texels {
            return Reason::BudgetBound;
        }
    }
    if whole {
        Reason::KeepingUp
    } else {
        Reason::SourceBound
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use proptest::test_runner::{Config, RngSeed};

    fn shape(grid: u64) -> LevelShape {
        LevelShape { size: [1 << 16, 1 << 16], tile: [256, 256], clip: 2048, grid: [grid, grid], wrap: false }
    }

    #[test]
    fn lead_is_speed_times_latency() {
        assert_eq!(lead_texels(0.0, 5.0), 0);
        assert_eq!(lead_texels(1000.0, 1.0), 1000);
        assert_eq!(lead_texels(1000.0, 2.5), 2500);
        assert_eq!(lead_texels(256.0, 0.0), 0);
        assert_eq!(lead_texels(f64::NAN, 1.0), 0);
        assert_eq!(lead_texels(1.0, f64::INFINITY), 0);
        assert_eq!(lead_texels(1e300, 1e300), 1_000_000_000_000_000);
        assert_eq!(lead_texels(0.1, 1.0), 1);
    }

    #[test]
    fn at_hover_the_region_is_the_default_rings() {
        let sh = shape(30);
        let tex = crate::geom::tex_region(sh.size, sh.clip, [20_000, 20_000]);
        let ring_shape = LevelShape { grid: mem_grid(sh.size, sh.tile, sh.clip, 1), ..sh };
        assert_eq!(region(&sh, tex, [0, 0], [0, 0]), ring::Ring.mem_region(&ring_shape, tex, [0, 0], Rect::EMPTY));
    }

    #[test]
    fn a_straight_flight_extends_the_ring_ahead_by_the_lead() {
        let sh = shape(30);
        let tex = crate::geom::tex_region(sh.size, sh.clip, [20_000, 20_000]);
        let need = crate::geom::tiles_covering(tex, sh.tile);
        let ring_shape = LevelShape { grid: mem_grid(sh.size, sh.tile, sh.clip, 1), ..sh };
        let ring = ring::Ring.mem_region(&ring_shape, tex, [0, 0], Rect::EMPTY);
        let r = region(&sh, tex, [1000, 0], [12 * 256, 0]);
        assert_eq!(r.s1 - need.s1, 12, "{r:?} {need:?}");
        assert_eq!(r.s0, ring.s0, "behind, the ring's margin");
        assert_eq!((r.t0, r.t1), (ring.t0, ring.t1), "across the motion, the ring");
        let back = region(&sh, tex, [-1000, 0], [12 * 256, 0]);
        assert_eq!(need.s0 - back.s0, 12);
        assert_eq!(back.s1, ring.s1);
        // A lead the ring's margin holds already: the ring itself.
        assert_eq!(region(&sh, tex, [5, 0], [0, 0]), ring);
        assert_eq!(region(&sh, tex, [5, 0], [10, 0]), ring);
        assert_eq!(region(&sh, tex, [-5, 3], [10, 10]), ring);
    }

    #[test]
    fn at_the_levels_edge_the_grid_keeps_the_way_back() {
        let sh = shape(14);
        let n = 256;
        // The window's last tile is the level's: the lead runs past the edge.
        let tex = crate::geom::tex_region(sh.size, sh.clip, [(1 << 16) - 1024, 20_000]);
        let need = crate::geom::tiles_covering(tex, sh.tile);
        assert_eq!(need.s1, n);
        let r = region(&sh, tex, [1000, 0], [4 * 256, 0]);
        assert_eq!((r.s0, r.s1), (n - 14, n), "the whole grid, behind the window");
        let back = region(&sh, crate::geom::tex_region(sh.size, sh.clip, [1024, 20_000]), [-1000, 0], [4 * 256, 0]);
        assert_eq!((back.s0, back.s1), (0, 14));
        // Away from the edge, behind the window only the ring's margin.
        let mid = crate::geom::tex_region(sh.size, sh.clip, [20_000, 20_000]);
        let ring_shape = LevelShape { grid: mem_grid(sh.size, sh.tile, sh.clip, 1), ..sh };
        let mid_ring = ring::Ring.mem_region(&ring_shape, mid, [0, 0], Rect::EMPTY);
        assert_eq!(region(&sh, mid, [1000, 0], [4 * 256, 0]).s0, mid_ring.s0);
        // A flight slower than a tile a latency keeps the ring there too.
        let ring = ring::Ring.mem_region(&ring_shape, tex, [0, 0], Rect::EMPTY);
        assert_eq!(region(&sh, tex, [10, 0], [10, 0]), ring);
        // A level that wraps along s has no edge there.
        let wraps = LevelShape { wrap: true, ..sh };
        assert!(region(&wraps, tex, [1000, 0], [4 * 256, 0]).s0 > n - 14);
    }

    #[test]
    fn a_lead_beyond_the_grid_is_capped_by_it() {
        let sh = shape(14);
        let tex = crate::geom::tex_region(sh.size, sh.clip, [20_000, 20_000]);
        let r = region(&sh, tex, [1000, 0], [40 * 256, 0]);
        assert_eq!(r.width(), 14);
        let need = crate::geom::tiles_covering(tex, sh.tile);
        assert_eq!(r.s0, need.s0, "every spare tile ahead");
    }

    #[test]
    fn budget_grids_fit_the_budget_and_spread_by_level() {
        let levels: Vec<_> = (0..8).map(|k| ([1u64 << (16 - k), 1u64 << (16 - k)], [256, 256])).collect();
        let tb = |_| 256 * 256 * 4;
        let base: u64 = levels.iter().map(|&(s, t)| mem_grid(s, t, 2048, 1)).map(|g| g[0] * g[1] * 256 * 256 * 4).sum();
        let (g, e) = budget_grids(&levels, 2048, tb, 2 * base);
        let used: u64 = g.iter().map(|g| g[0] * g[1] * 256 * 256 * 4).sum();
        assert!(used <= 2 * base && e > 0, "{used} {e}");
        let (g1, _) = budget_grids(&levels, 2048, tb, used + 10 * 256 * 256 * 4);
        assert!(g1[0][0] >= g[0][0]);
        assert!(g[0][0] >= g[1][0] && g[1][0] >= g[2][0], "{g:?}");
        // One more spare tile at level 0 would not fit.
        let more: u64 = levels
            .iter()
            .enumerate()
            .map(|(k, &(s, t))| {
                let b = mem_grid(s, t, 2048, 1);
                let n = tiles_in_level(s, t);
                let x = (e + 1) >> k;
                (b[0] + x).min(n[0]) * (b[1] + x).min(n[1]) * 256 * 256 * 4
            })
            .sum();
        assert!(more > 2 * base || g[0][0] == tiles_in_level(levels[0].0, levels[0].1)[0]);
        // Too small a budget: the default grids.
        let (g0, e0) = budget_grids(&levels, 2048, tb, 1);
        assert_eq!(e0, 0);
        assert_eq!(g0[0], mem_grid(levels[0].0, levels[0].1, 2048, 1));
    }

    #[test]
    fn motion_smooths_takes_reversals_at_once_and_recentres_after_a_jump() {
        let mut m = Motion::default();
        for _ in 0..30 {
            m.update([1000, 0], 2048);
        }
        assert!((m.velocity[0] - 1000.0).abs() < 1.0);
        m.update([-1000, 0], 2048);
        assert_eq!(m.velocity[0], -1000.0);
        m.update([100_000, 0], 2048);
        assert_eq!(m.velocity, [0.0, 0.0]);
        assert_eq!(Motion { velocity: [0.4, -3.0] }.at_level(2), [1, -1]);
    }

    #[test]
    fn latency_holds_its_peak_and_decays() {
        let mut l = Latency::default();
        l.sample(5);
        assert_eq!(l.ticks, 5.0);
        l.sample(1);
        assert!(l.ticks < 5.0 && l.ticks > 4.5);
        for _ in 0..400 {
            l.sample(1);
        }
        assert!((l.ticks - 1.0).abs() < 0.01);
        l.sample(1_000_000);
        assert_eq!(l.ticks, MAX_LATENCY_TICKS, "bounded");
        for _ in 0..600 {
            l.rest();
        }
        assert!(l.ticks < 2.0, "a peak decays at rest: {}", l.ticks);
    }

    #[test]
    fn each_level_plans_with_the_slowest_of_its_own_streams() {
        // Levels 0 and 2 read from stream 0, level 1 from stream 1, level 3 from both; level 4
        // has asked for nothing yet.
        let mut l = StreamMeasures::new(2, 5);
        for (level, stream) in [(0, 0), (2, 0), (1, 1), (3, 0), (3, 1)] {
            l.note(level, stream);
        }
        l.note(9, 0);
        l.note(0, 7);
        // Stream 0 slow (6 ticks a read), stream 1 fast (1 tick).
        for _ in 0..10 {
            l.sample(0, 6);
            l.sample(1, 1);
        }
        assert_eq!(l.per_stream(), vec![6.0, 1.0]);
        assert_eq!([0, 1, 2, 3, 4].map(|k| l.level(k)), [6.0, 1.0, 6.0, 6.0, 6.0]);
        assert_eq!(l.streams_of(3).collect::<Vec<_>>(), vec![0, 1]);
        // The slow stream's levels get the longer lead; the fast stream's are not inflated.
        let speed = 200.0;
        assert_eq!(lead_texels(speed, l.level(0)), 1200);
        assert_eq!(lead_texels(speed, l.level(1)), lead_texels(speed, INITIAL_LATENCY_TICKS));
        // Swapped: the other levels are the slow ones.
        let mut swapped = StreamMeasures::new(2, 2);
        swapped.note(0, 0);
        swapped.note(1, 1);
        swapped.sample(1, 6);
        assert_eq!([swapped.level(0), swapped.level(1)], [1.0, 6.0]);
        // Resting one stream leaves the other's estimate alone.
        l.rest(0);
        assert!(l.level(0) < 6.0);
        assert_eq!(l.level(1), 1.0);
        assert_eq!(l.slowest(), l.level(0));
    }

    #[test]
    fn a_stream_is_short_when_it_delivers_less_than_is_asked_of_it() {
        let mut m = StreamMeasures::new(2, 3);
        m.note(0, 0);
        m.note(1, 1);
        for _ in 0..40 {
            // Stream 0 asked 20 tiles a tick, delivers 2; stream 1 delivers what it is asked.
            m.count(0, 20, 2);
            m.count(1, 20, 20);
        }
        assert!(m.rates()[0].short() && !m.rates()[1].short(), "{:?}", m.rates());
        assert_eq!([m.level_short(0), m.level_short(1), m.level_short(2)], [true, false, true]);
        // A burst asked at one tick and delivered at the next is not short once it has passed.
        let mut burst = TileRate::default();
        burst.update(500, 0);
        burst.update(0, 500);
        for _ in 0..8 {
            burst.update(10, 10);
        }
        assert!(!burst.short(), "{burst:?}");
        // Nothing asked: never short.
        assert!(!TileRate::default().short());
    }

    #[test]
    fn one_stream_plans_every_level_with_its_latency() {
        let mut l = StreamMeasures::new(1, 3);
        let mut one = Latency::default();
        l.note(1, 0);
        for x in [3, 1, 7, 2] {
            l.sample(0, x);
            one.sample(x);
            assert_eq!([l.level(0), l.level(1), l.level(2), l.slowest()], [one.ticks; 4]);
        }
        l.rest(0);
        one.rest();
        assert_eq!([l.level(0), l.level(1), l.slowest()], [one.ticks; 3]);
        assert_eq!(StreamMeasures::new(0, 1).stream_count(), 1);
    }

    #[test]
    fn the_lead_grows_at_once_and_shrinks_slowly() {
        assert_eq!(held_lead(400, 800), 800);
        assert_eq!(held_lead(800, 0), 750);
        assert_eq!(held_lead(800, 790), 790);
        assert_eq!(held_lead(10, 0), 9);
        assert_eq!(held_lead(1, 0), 0);
        assert_eq!(held_lead(0, 0), 0);
    }

    /// A brute-force model of one axis: the window moves `speed` texels a tick along s; a tile
    /// asked for at tick `T` (when it first enters the region) is ready from tick `T + latency`
    /// on (reads are asked for at the end of a tick and taken at the start of a later one); it is
    /// needed when the window touches it. Returns whether every tile was ready when needed, after
    /// a start that fills the first region at once.
    fn keeps_up(speed: u64, latency: u64, tile: u64, lead: u64) -> bool {
        let touch = 2048 / tile + 1;
        let spare = lead.div_ceil(tile) + 2;
        let sh = LevelShape {
            size: [1 << 24, 1 << 24],
            tile: [tile, tile],
            clip: 2048,
            grid: [touch + spare, touch + 2],
            wrap: false,
        };
        let mut asked = std::collections::HashMap::<i64, u64>::new();
        let mut c = (1i64 << 22) + 77;
        for tick in 0..120u64 {
            let tex = crate::geom::tex_region(sh.size, sh.clip, [c, 1 << 22]);
            let need = crate::geom::tiles_covering(tex, sh.tile);
            for s in need.s0..need.s1 {
                match asked.get(&s) {
                    Some(&at) if at == 0 || at + latency <= tick => {}
                    None if tick == 0 => {}
                    _ => return false,
                }
            }
            let r = region(&sh, tex, [speed as i64, 0], [lead, 0]);
            for s in r.s0..r.s1 {
                asked.entry(s).or_insert(tick);
            }
            c += speed as i64;
        }
        true
    }

    proptest! {
        #![proptest_config(Config { cases: 300, rng_seed: RngSeed::Fixed(0xADA), failure_persistence: None, ..Config::default() })]

        /// The lead the controller computes keeps the brute-force model's window whole at every
        /// speed and latency, and is not more than a tile above the least lead that does.
        #[test]
        fn the_computed_lead_keeps_up_and_is_not_wasteful(speed in 1u64..3000, latency in 1u64..6, tile_k in 6u32..10) {
            let tile = 1u64 << tile_k;
            let lead = lead_texels(speed as f64, latency as f64);
            prop_assert!(keeps_up(speed, latency, tile, lead), "lead {lead} does not keep up");
            // Keeping up is monotone in the lead: bisect for the least lead that does.
            let (mut lo, mut hi) = (0u64, lead);
            if keeps_up(speed, latency, tile, 0) {
                hi = 0;
            }
            while hi - lo > 1 {
                let m = lo + (hi - lo) / 2;
                if keeps_up(speed, latency, tile, m) { hi = m } else { lo = m }
            }
            prop_assert!(lead <= hi + tile, "lead {lead}, least that keeps up {hi}");
        }

        /// Every region holds the window's tiles, stays inside the level and within the grid.
        #[test]
        fn regions_hold_the_window_and_fit(c in (-5000i64..70_000, -5000i64..70_000), v in (-3000i64..3000, -3000i64..3000), lead in (0u64..40, 0u64..40), grid in 10u64..40) {
            let sh = shape(grid);
            let tex = crate::geom::tex_region(sh.size, sh.clip, [c.0, c.1]);
            let need = crate::geom::tiles_covering(tex, sh.tile);
            let r = region(&sh, tex, [v.0, v.1], [lead.0, lead.1]);
            prop_assert!(r.contains_rect(&need), "{r:?} {need:?}");
            prop_assert!(r.width() <= grid && r.height() <= grid);
            prop_assert!(r.s0 >= 0 && r.t0 >= 0 && r.s1 <= 256 && r.t1 <= 256);
        }
    }
}
