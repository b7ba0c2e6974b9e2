//! Ahead prefetch: the engine's placement before the policies were measured
//! ([`crate::geom::mem_region`]): on each axis that moves, every spare tile lies ahead of the
//! motion, at every tick (a reverse moves them to the new front at once, crossing or not); an
//! axis that does not move keeps its region while it holds the window.
//!
//! Kept beside [`super::ring`] and [`super::direction`] so that the comparison shows what the
//! change of default cost or bought.

use super::{needed, origins, ring, Prefetch};
use crate::geom::{LevelShape, Rect};

/// Spare tiles ahead of the motion on every tick that moves.
#[derive(Clone, Copy, Debug, Default)]
pub struct Ahead;

impl Prefetch for Ahead {
    fn mem_region(&self, shape: &LevelShape, tex: Rect, velocity: [i64; 2], previous: Rect) -> Rect {
        let (need, n) = needed(shape, tex);
        let g = shape.grid;
        let mid = ring::middle(tex);
        let axis = |a: usize, lo: i64, hi: i64, prev: Option<i64>| {
            let (first, last) = origins(lo, hi, g[a], n[a]);
            match (velocity[a].signum(), prev) {
                (1, _) => last,
                (-1, _) => first,
                (_, Some(o)) => o.clamp(first, last),
                (_, None) => ring::centred(lo, hi, mid[a], shape.tile[a], g[a], n[a]),
            }
        };
        let prev_s = (!previous.is_empty() && previous.width() == g[0]).then_some(previous.s0);
        let prev_t = (!previous.is_empty() && previous.height() == g[1]).then_some(previous.t0);
        let s = axis(0, need.s0, need.s1, prev_s);
        let t = axis(1, need.t0, need.t1, prev_t);
        Rect::new(s, t, s + g[0] as i64, t + g[1] as i64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spare_tiles_go_ahead_at_every_moving_tick_and_a_still_axis_holds() {
        let sh = LevelShape::new([4096, 4096], [256, 256], 1024, 1);
        let tex = Rect::new(1024, 1024, 2048, 2048); // tiles 4..8, two spare per axis
        let ring = Rect::new(3, 3, 9, 9);
        assert_eq!(Ahead.mem_region(&sh, tex, [5, 0], ring), Rect::new(4, 3, 10, 9));
        assert_eq!(Ahead.mem_region(&sh, tex, [5, -5], ring), Rect::new(4, 2, 10, 8));
        // A reverse within a tile flips the spare tiles (direction would hold them).
        assert_eq!(Ahead.mem_region(&sh, tex, [-1, 0], Rect::new(4, 3, 10, 9)), Rect::new(2, 3, 8, 9));
        assert_eq!(Ahead.mem_region(&sh, tex, [0, 0], Rect::new(4, 4, 10, 10)), Rect::new(4, 4, 10, 10));
        assert_eq!(Ahead.mem_region(&sh, tex, [0, 0], Rect::EMPTY), ring);
    }

    #[test]
    fn it_places_tiles_as_the_engine_did_before_policies_on_moving_axes() {
        // geom::mem_region is the former placement; on moving axes they agree.
        let sh = LevelShape::new([1 << 14, 1 << 14], [128, 128], 512, 1);
        for (c, v) in [([3000, 5000], [7, -3]), ([8000, 100], [-1, 1]), ([16000, 16000], [2, 2])] {
            let tex = crate::geom::tex_region(sh.size, sh.clip, c);
            let old = crate::geom::mem_region(sh.size, sh.tile, sh.grid, tex, v);
            assert_eq!(Ahead.mem_region(&sh, tex, v, Rect::EMPTY), old, "centre {c:?} velocity {v:?}");
        }
    }
}
