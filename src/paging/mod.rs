//! Paging policies: which tiles each level's grid holds ahead of the motion (prefetch), and
//! which tiles a second, associative pool in process memory keeps beyond the grids (eviction).
//!
//! Owns the two policy traits and their implementations, one file each: [`Prefetch`]
//! ([`adaptive`]: read-ahead sized each tick from the measured motion and read latency, within
//! grids sized from a memory budget, the default; `ring`: spare tiles around the window, the
//! best fixed placement and the default before; `direction`: spare tiles put ahead when the
//! centre crosses a tile boundary, held otherwise; `ahead`: spare tiles ahead at every moving
//! tick, the engine's former placement), and [`Eviction`] (`lru`: least recently used first,
//! the default; `shift`: farthest behind the direction of motion first). The pool those rank is a
//! source in front of a source ([`crate::source::PoolSource`]), so it lives with the sources.
//! The comparison is `clipbench policies` (docs/BENCHMARKS.md, ## Policies).
//!
//! Everything here is pure: a prefetch policy is a function of the level's shape,
//! its tex region, its motion and last tick's mem region; an eviction policy ranks the pool's
//! tiles given the motion the clipmap last reported ([`Motion`]). Which slots change and when is
//! still `crate::cache`'s and [`crate::clip`]'s business (a slot is given to another tile only
//! after a snapshot that no longer covers its old one).

pub mod adaptive;
pub(crate) mod ahead;
pub(crate) mod direction;
pub(crate) mod lru;
pub(crate) mod ring;
pub(crate) mod shift;

use crate::geom::{tiles_covering, tiles_in_level, LevelShape, Rect};
use crate::tile::TileId;
use serde::Serialize;
use std::fmt;
use std::str::FromStr;

/// Decides a level's mem region: the tiles its grid holds.
pub trait Prefetch: Send + Sync + fmt::Debug {
    /// The mem region (tile indices, `shape.grid` tiles a side) for a level whose tex region is
    /// `tex`, moving at `velocity` level texels per tick, whose mem region was `previous` last
    /// tick ([`Rect::EMPTY`] at first). It must hold every tile `tex` touches and stay inside
    /// the level.
    fn mem_region(&self, shape: &LevelShape, tex: Rect, velocity: [i64; 2], previous: Rect) -> Rect;
}

/// One axis of a mem region: the tiles `[lo, hi)` the window needs, `grid` tiles kept, `tiles`
/// in the level. Returns the origins a region may take that hold `[lo, hi)` and stay inside the
/// level, as `(first, last)`.
pub(crate) fn origins(lo: i64, hi: i64, grid: u64, tiles: u64) -> (i64, i64) {
    let g = grid as i64;
    let first = (hi - g).max(0);
    let last = lo.min(tiles as i64 - g);
    (first, last.max(first))
}

/// The tiles a tex region needs, and the level's tiles per axis.
pub(crate) fn needed(shape: &LevelShape, tex: Rect) -> (Rect, [u64; 2]) {
    (tiles_covering(tex, shape.tile), tiles_in_level(shape.size, shape.tile))
}

/// The prefetch policies there are. The default, [`PrefetchKind::Adaptive`], reads what the
/// best fixed policy ([`PrefetchKind::Ring`]) reads on every flight of the comparison, with no
/// more ticks with a disabled level (docs/BENCHMARKS.md, ## Policies).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PrefetchKind {
    /// Spare tiles around the window on both axes, margins balanced (`ring::Ring`).
    Ring,
    /// Spare tiles put ahead of the motion when the centre crosses a tile boundary, held
    /// otherwise (Luo and Duan; `direction::Direction`).
    Direction,
    /// Spare tiles ahead of the motion at every moving tick (the former placement;
    /// `ahead::Ahead`).
    Ahead,
    /// Read-ahead sized each tick from the measured motion and read latency, within grids sized
    /// from a memory budget ([`adaptive`]).
    #[default]
    Adaptive,
}

/// The eviction policies of the second-level pool. The default, [`EvictionKind::Lru`], is the
/// comparison's winner (docs/BENCHMARKS.md, ## Policies).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EvictionKind {
    /// Least recently used first (`lru::Lru`).
    #[default]
    Lru,
    /// Farthest behind the direction of motion first (`shift::Shift`).
    Shift,
}

impl PrefetchKind {
    /// Every policy, in the order reports list them.
    pub const ALL: [PrefetchKind; 4] =
        [PrefetchKind::Ring, PrefetchKind::Direction, PrefetchKind::Ahead, PrefetchKind::Adaptive];

    /// The policy.
    pub fn policy(self) -> &'static dyn Prefetch {
        match self {
            PrefetchKind::Ring => &ring::Ring,
            PrefetchKind::Direction => &direction::Direction,
            PrefetchKind::Ahead => &ahead::Ahead,
            PrefetchKind::Adaptive => &adaptive::Adaptive,
        }
    }

    /// The name used on command lines, in configurations and in reports.
    pub fn name(self) -> &'static str {
        match self {
            PrefetchKind::Ring => "ring",
            PrefetchKind::Direction => "direction",
            PrefetchKind::Ahead => "ahead",
            PrefetchKind::Adaptive => "adaptive",
        }
    }
}

impl EvictionKind {
    /// Every policy, in the order reports list them.
    pub const ALL: [EvictionKind; 2] = [EvictionKind::Lru, EvictionKind::Shift];

    /// A fresh policy.
    pub fn policy(self) -> Box<dyn Eviction> {
        match self {
            EvictionKind::Lru => Box::new(lru::Lru),
            EvictionKind::Shift => Box::new(shift::Shift),
        }
    }

    /// The name used on command lines, in configurations and in reports.
    pub fn name(self) -> &'static str {
        match self {
            EvictionKind::Lru => "lru",
            EvictionKind::Shift => "shift",
        }
    }
}

impl fmt::Display for PrefetchKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl fmt::Display for EvictionKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A policy name that is none of the policies.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unknown {what} policy `{found}`: expected {expected}")]
pub struct PolicyError {
    /// `prefetch` or `eviction`.
    pub what: &'static str,
    /// What was written.
    pub found: String,
    /// The names there are.
    pub expected: &'static str,
}

impl FromStr for PrefetchKind {
    type Err = PolicyError;
    fn from_str(s: &str) -> Result<Self, PolicyError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "ring" => Ok(PrefetchKind::Ring),
            "direction" => Ok(PrefetchKind::Direction),
            "ahead" => Ok(PrefetchKind::Ahead),
            "adaptive" => Ok(PrefetchKind::Adaptive),
            _ => Err(PolicyError {
                what: "prefetch",
                found: s.into(),
                expected: "`ring`, `direction`, `ahead` or `adaptive`",
            }),
        }
    }
}

impl FromStr for EvictionKind {
    type Err = PolicyError;
    fn from_str(s: &str) -> Result<Self, PolicyError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "lru" => Ok(EvictionKind::Lru),
            "shift" => Ok(EvictionKind::Shift),
            _ => Err(PolicyError { what: "eviction", found: s.into(), expected: "`lru` or `shift`" }),
        }
    }
}

/// What the clipmap tells the pool each tick: where it is, where it goes, what the grids hold.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Motion {
    /// The level-0 centre.
    pub centre: [i64; 2],
    /// The direction of motion in level-0 texels per tick: the last non-zero velocity (zero
    /// until the centre first moves).
    pub direction: [i64; 2],
    /// Each level's mem region (tile indices): the expanded regions the grids hold.
    pub mem: Vec<Rect>,
    /// Each level's tile size in texels.
    pub tile: Vec<[u64; 2]>,
}

/// A tile in the pool, as an eviction policy sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Candidate {
    /// The tile.
    pub tile: TileId,
    /// When it was last read or served (a counter: larger is more recent).
    pub last_used: u64,
}

/// Decides which tile the pool gives up first when a new one does not fit.
pub trait Eviction: Send + fmt::Debug {
    /// The index in `candidates` (never empty) of the tile to evict, given the last motion.
    fn victim(&self, candidates: &[Candidate], motion: &Motion) -> usize;
}

/// The paging choices a user makes (a command line, a configuration's extension), resolved:
/// what [`crate::clip::Settings::with_paging`] applies.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct PagingOptions {
    /// Where each grid's spare tiles go.
    pub prefetch: PrefetchKind,
    /// Which pooled tile goes first.
    pub eviction: EvictionKind,
    /// The second-level pool's hard budget in bytes of tiles (0: no pool).
    pub pool_bytes: u64,
    /// Most level-0 texels the centre moves per tick along each axis (`None`: unclamped).
    pub max_centre_step: Option<u64>,
    /// Bytes the adaptive policy's grids may take (`None`: the default budget,
    /// `adaptive::DEFAULT_BUDGET_FACTOR` times the lookahead-1 grids).
    pub grid_budget: Option<u64>,
}

/// A byte count as written on a command line or in a configuration: digits with an optional
/// binary suffix `k`, `m` or `g` (KiB, MiB, GiB; case-insensitive, an optional `iB`/`B`).
pub fn parse_bytes(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let lower = t.to_ascii_lowercase();
    let body = lower.trim_end_matches("ib").trim_end_matches('b');
    let (digits, shift) = match body.chars().last() {
        Some('k') => (&body[..body.len() - 1], 10),
        Some('m') => (&body[..body.len() - 1], 20),
        Some('g') => (&body[..body.len() - 1], 30),
        _ => (body, 0),
    };
    digits
        .trim()
        .parse::<u64>()
        .ok()
        .and_then(|n| n.checked_mul(1u64 << shift))
        .ok_or_else(|| format!("`{text}` is not a byte count: expected a whole number of bytes, optionally with k, m or g (KiB, MiB, GiB), e.g. 268435456 or 256m"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_byte_counts_read_back() {
        for p in PrefetchKind::ALL {
            assert_eq!(p.name().parse::<PrefetchKind>(), Ok(p));
        }
        for e in EvictionKind::ALL {
            assert_eq!(e.name().to_uppercase().parse::<EvictionKind>(), Ok(e));
        }
        let e = "fifo".parse::<EvictionKind>().unwrap_err();
        assert_eq!(e.to_string(), "unknown eviction policy `fifo`: expected `lru` or `shift`");
        assert_eq!(parse_bytes("256m"), Ok(256 << 20));
        assert_eq!(parse_bytes("64KiB"), Ok(64 << 10));
        assert_eq!(parse_bytes("1G"), Ok(1 << 30));
        assert_eq!(parse_bytes("4096"), Ok(4096));
        assert!(parse_bytes("lots").is_err());
        assert!(parse_bytes("99999999999g").is_err());
    }
}
