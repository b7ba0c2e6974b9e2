//! Read priorities: which tile is read first. Pure functions, refreshed every tick.
//!
//! Coarser levels come first (a coarse level stands in for every finer one), then the estimated
//! number of ticks until the tile is needed: its distance from the level's valid region, divided
//! by the speed of the centre if the tile lies ahead of the motion, and lengthened by a clip size
//! if it lies behind. Lower is more urgent, as in Performer.

use crate::geom::Rect;
use serde::Serialize;

/// How urgent a read is; lower sorts first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub struct Priority {
    /// 0 for the coarsest level, growing towards level 0.
    pub rank: u32,
    /// Estimated ticks (or texels when the centre is still) until the tile is needed.
    pub eta: u64,
}

/// Gap between intervals `[a0, a1)` and `[b0, b1)` (0 when they overlap).
fn gap(a0: i64, a1: i64, b0: i64, b1: i64) -> u64 {
    if a1 <= b0 {
        (b0 - a1 + 1) as u64
    } else if b1 <= a0 {
        (a0 - b1 + 1) as u64
    } else {
        0
    }
}

/// Priority of reading a tile covering `texels` of level `level` (of `levels`), for a level whose
/// valid region is `valid`, whose clip size is `clip` and whose centre moves by `velocity` level
/// texels per tick.
pub fn priority(level: u32, levels: usize, texels: Rect, valid: Rect, clip: u64, velocity: [i64; 2]) -> Priority {
    let rank = (levels as u32).saturating_sub(1).saturating_sub(level);
    let d = gap(texels.s0, texels.s1, valid.s0, valid.s1).max(gap(texels.t0, texels.t1, valid.t0, valid.t1));
    let speed = velocity[0].unsigned_abs().max(velocity[1].unsigned_abs());
    if speed == 0 || d == 0 {
        return Priority { rank, eta: d };
    }
    // Twice the offsets from the valid region's centre, so odd extents stay exact.
    let ds = (texels.s0 + texels.s1) - (valid.s0 + valid.s1);
    let dt = (texels.t0 + texels.t1) - (valid.t0 + valid.t1);
    let ahead = (ds as i128) * velocity[0] as i128 + (dt as i128) * velocity[1] as i128 >= 0;
    let distance = if ahead { d } else { d.saturating_add(clip) };
    Priority { rank, eta: distance.div_ceil(speed) }
}

/// The adaptive policy's order: a tile the level's valid region touches keeps [`priority`]
/// (coarser levels first, so that a coarse level stands in for the finer ones), and every other
/// tile — read-ahead — comes after all of those, soonest needed first across levels (ties:
/// coarser first), so that read-ahead fills the capacity the window leaves and never delays it.
pub fn soonest_first(level: u32, levels: usize, texels: Rect, valid: Rect, clip: u64, velocity: [i64; 2]) -> Priority {
    let p = priority(level, levels, texels, valid, clip, velocity);
    let inside = gap(texels.s0, texels.s1, valid.s0, valid.s1).max(gap(texels.t0, texels.t1, valid.t0, valid.t1)) == 0;
    if inside {
        return p;
    }
    let above = (levels as u64).min(u32::MAX as u64);
    let rank = above.saturating_add(p.eta).min(u32::MAX as u64) as u32;
    Priority { rank, eta: p.rank as u64 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn soonest_first_reads_every_needed_tile_before_any_read_ahead() {
        let needed_fine = soonest_first(0, 8, Rect::new(120, 120, 136, 136), VALID, 64, [4, 0]);
        let ahead_coarse = soonest_first(5, 8, Rect::new(216, 150, 232, 166), VALID, 64, [4, 0]);
        let ahead_fine_near = soonest_first(0, 8, Rect::new(200, 150, 216, 166), VALID, 64, [4, 0]);
        let ahead_fine_far = soonest_first(0, 8, Rect::new(260, 150, 276, 166), VALID, 64, [4, 0]);
        assert!(needed_fine < ahead_coarse && needed_fine < ahead_fine_near);
        assert!(ahead_fine_near < ahead_coarse, "sooner first, whatever the level");
        assert!(ahead_coarse < ahead_fine_far);
        // Inside the valid region: the plain order.
        assert_eq!(needed_fine, priority(0, 8, Rect::new(120, 120, 136, 136), VALID, 64, [4, 0]));
        // Extremes do not overflow.
        let far = soonest_first(0, usize::MAX, Rect::new(68, 150, 84, 166), VALID, u64::MAX, [1, 0]);
        assert_eq!(far.rank, u32::MAX);
    }

    const VALID: Rect = Rect::new(100, 100, 200, 200);

    #[test]
    fn coarser_levels_always_come_first() {
        let far_coarse = priority(5, 8, Rect::new(10_000, 0, 10_016, 16), VALID, 64, [0, 0]);
        let near_fine = priority(0, 8, Rect::new(120, 120, 136, 136), VALID, 64, [0, 0]);
        assert!(far_coarse < near_fine);
        assert_eq!(far_coarse.rank, 2);
    }

    #[test]
    fn inside_before_near_before_far_and_ahead_before_behind() {
        let inside = priority(0, 4, Rect::new(150, 150, 166, 166), VALID, 64, [4, 0]);
        let ahead = priority(0, 4, Rect::new(216, 150, 232, 166), VALID, 64, [4, 0]);
        let farther_ahead = priority(0, 4, Rect::new(248, 150, 264, 166), VALID, 64, [4, 0]);
        let behind = priority(0, 4, Rect::new(68, 150, 84, 166), VALID, 64, [4, 0]);
        assert_eq!(inside.eta, 0);
        assert_eq!(ahead.eta, 17u64.div_ceil(4));
        assert!(inside < ahead && ahead < farther_ahead && farther_ahead < behind, "{ahead:?} {behind:?}");
        // Standing still, only distance counts: the same tile behind and ahead tie.
        let l = priority(0, 4, Rect::new(68, 150, 84, 166), VALID, 64, [0, 0]);
        let r = priority(0, 4, Rect::new(216, 150, 232, 166), VALID, 64, [0, 0]);
        assert_eq!(l, r);
    }
}
