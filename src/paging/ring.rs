//! Ring prefetch: the grid's spare tiles around the window on both axes, whatever the motion
//! (the common default the paging literature compares against): the region is the one whose
//! margins beyond the window are most nearly equal on each side, so it is symmetric about the
//! window's centre to within half a tile, and moves by one tile whenever the centre passes the
//! middle of a tile.

use super::{needed, origins, Prefetch};
use crate::geom::{LevelShape, Rect};

/// Spare tiles around the window, margins balanced.
#[derive(Clone, Copy, Debug, Default)]
pub struct Ring;

/// One axis: among the origins that hold the tiles `[lo, hi)`, the one whose region of `grid`
/// tiles of `edge` texels is centred nearest on the window's centre `mid` (ties: the later).
pub(super) fn centred(lo: i64, hi: i64, mid: i64, edge: u64, grid: u64, tiles: u64) -> i64 {
    let (first, last) = origins(lo, hi, grid, tiles);
    let (e, g) = (edge as i64, grid as i64);
    // Nearest whole o to (mid - g e / 2) / e, halves rounded up.
    let o = (2 * mid - g * e + e).div_euclid(2 * e);
    o.clamp(first, last)
}

/// The window's centre on each axis (level texels).
pub(super) fn middle(tex: Rect) -> [i64; 2] {
    [(tex.s0 + tex.s1).div_euclid(2), (tex.t0 + tex.t1).div_euclid(2)]
}

impl Prefetch for Ring {
    fn mem_region(&self, shape: &LevelShape, tex: Rect, _velocity: [i64; 2], _previous: Rect) -> Rect {
        let (need, n) = needed(shape, tex);
        let mid = middle(tex);
        let s = centred(need.s0, need.s1, mid[0], shape.tile[0], shape.grid[0], n[0]);
        let t = centred(need.t0, need.t1, mid[1], shape.tile[1], shape.grid[1], n[1]);
        Rect::new(s, t, s + shape.grid[0] as i64, t + shape.grid[1] as i64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4096-texel level of 256-texel tiles, clip 1024: the window touches 4 or 5 tiles, the
    /// grid holds 6.
    fn shape() -> LevelShape {
        LevelShape::new([4096, 4096], [256, 256], 1024, 1)
    }

    #[test]
    fn spare_tiles_go_on_both_sides_whatever_the_motion() {
        let sh = shape();
        assert_eq!(sh.grid, [6, 6]);
        // Window [1024, 2048): tiles 4..8, two spare: one before, one after.
        let tex = Rect::new(1024, 1024, 2048, 2048);
        for v in [[0, 0], [5, 0], [-5, 7]] {
            assert_eq!(Ring.mem_region(&sh, tex, v, Rect::EMPTY), Rect::new(3, 3, 9, 9), "velocity {v:?}");
        }
        // Window [1100, 2124): tiles 4..9, one spare: before it (margins 332 and 180 texels)
        // rather than after (76 and 436).
        let tex = Rect::new(1100, 1024, 2124, 2048);
        assert_eq!(Ring.mem_region(&sh, tex, [5, 0], Rect::EMPTY), Rect::new(3, 3, 9, 9));
        // Window [1200, 2224): one spare, after (margins 176 and 336, against 432 and 80).
        let tex = Rect::new(1200, 1024, 2224, 2048);
        assert_eq!(Ring.mem_region(&sh, tex, [-5, 0], Rect::EMPTY), Rect::new(4, 3, 10, 9));
    }

    #[test]
    fn a_flight_along_s_reads_one_column_per_tile_boundary_crossed() {
        // Hand-checked: the window moves 64 texels a tick from s0 = 1024 (centre 1536); the
        // region 3..9 is centred on 1536, 4..10 on 1792: it moves when the centre passes 1664
        // (tick 2), and again at 1920 (tick 6).
        let sh = shape();
        let mut prev = Rect::EMPTY;
        let mut firsts = Vec::new();
        for i in 0..9 {
            let s0 = 1024 + 64 * i;
            prev = Ring.mem_region(&sh, Rect::new(s0, 1024, s0 + 1024, 2048), [64, 0], prev);
            firsts.push(prev.s0);
        }
        assert_eq!(firsts, [3, 3, 4, 4, 4, 4, 5, 5, 5]);
    }

    #[test]
    fn the_ring_stays_inside_the_level_at_its_edges() {
        let sh = shape();
        assert_eq!(Ring.mem_region(&sh, Rect::new(0, 3072, 1024, 4096), [0, 0], Rect::EMPTY), Rect::new(0, 10, 6, 16));
    }
}
