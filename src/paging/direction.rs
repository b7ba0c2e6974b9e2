//! Direction-aware prefetch (Luo and Duan, "Clipmap based Loading and Rendering of Large Terrain
//! Texture"): on each axis, when the centre crosses a tile boundary in the direction of motion,
//! the grid's spare tiles are put ahead of it, so the next row (or column) is read then; at any
//! other tick the region stays where it is as long as it holds the window (a hovering or
//! swaying viewer, or one that turns back within a tile, reads nothing on that axis).
//!
//! A reverse that crosses a boundary moves the spare tiles to the new front at once: the rows
//! that were ahead are given up and the rows behind read (the price the comparison measures on
//! zig-zag and turn-around flights).

use super::{needed, origins, ring, Prefetch};
use crate::geom::{LevelShape, Rect};

/// Spare tiles put ahead of the motion when the centre crosses a tile boundary; held otherwise.
#[derive(Clone, Copy, Debug, Default)]
pub struct Direction;

/// Whether the centre `mid` (level texels), having moved `v` since the last tick, is in another
/// tile than before (tiles of `edge` texels).
pub(crate) fn crossed(mid: i64, v: i64, edge: u64) -> bool {
    let e = edge as i64;
    v != 0 && mid.div_euclid(e) != mid.saturating_sub(v).div_euclid(e)
}

/// One axis: the tiles `[lo, hi)` needed, the centre `mid` and its velocity, last tick's origin.
fn axis((lo, hi): (i64, i64), mid: i64, v: i64, edge: u64, grid: u64, tiles: u64, previous: Option<i64>) -> i64 {
    let (first, last) = origins(lo, hi, grid, tiles);
    match previous {
        None => ring::centred(lo, hi, mid, edge, grid, tiles),
        Some(_) if crossed(mid, v, edge) && v > 0 => last,
        Some(_) if crossed(mid, v, edge) => first,
        Some(o) => o.clamp(first, last),
    }
}

impl Prefetch for Direction {
    fn mem_region(&self, shape: &LevelShape, tex: Rect, velocity: [i64; 2], previous: Rect) -> Rect {
        let (need, n) = needed(shape, tex);
        let g = shape.grid;
        let prev_s = (!previous.is_empty() && previous.width() == g[0]).then_some(previous.s0);
        let prev_t = (!previous.is_empty() && previous.height() == g[1]).then_some(previous.t0);
        let mid = ring::middle(tex);
        let s = axis((need.s0, need.s1), mid[0], velocity[0], shape.tile[0], g[0], n[0], prev_s);
        let t = axis((need.t0, need.t1), mid[1], velocity[1], shape.tile[1], g[1], n[1], prev_t);
        Rect::new(s, t, s + g[0] as i64, t + g[1] as i64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::paging::ring::Ring;
    use proptest::prelude::*;
    use proptest::test_runner::{Config, RngSeed};

    /// A 4096-texel level of 256-texel tiles, clip 1024: the window touches 4 or 5 tiles, the
    /// grid holds 6.
    fn shape() -> LevelShape {
        LevelShape::new([4096, 4096], [256, 256], 1024, 1)
    }

    const TEX: Rect = Rect::new(1024, 1024, 2048, 2048); // tiles 4..8, centre (1536, 1536)
    const RING: Rect = Rect::new(3, 3, 9, 9);

    #[test]
    fn spare_tiles_go_ahead_when_the_centre_crosses_a_tile_boundary() {
        let sh = shape();
        // Nothing before: split like the ring, whatever the motion.
        assert_eq!(Direction.mem_region(&sh, TEX, [5, 0], Rect::EMPTY), RING);
        // +5 on s: the centre came from 1531 (tile 5) to 1536 (tile 6): spares ahead on s; t is
        // still and keeps its rows.
        assert_eq!(Direction.mem_region(&sh, TEX, [5, 0], RING), Rect::new(4, 3, 10, 9));
        // -1 on s stays in tile 6 (held); +1 on t came from 1535 (tile 5): spares ahead on t.
        assert_eq!(Direction.mem_region(&sh, TEX, [-1, 1], RING), Rect::new(3, 4, 9, 10));
        // -5 on t came from 1541, the same tile: held.
        assert_eq!(Direction.mem_region(&sh, TEX, [5, -5], RING), Rect::new(4, 3, 10, 9));
    }

    #[test]
    fn between_crossings_the_region_holds_while_it_covers_the_window() {
        let sh = shape();
        let ahead = Rect::new(4, 4, 10, 10);
        assert_eq!(Direction.mem_region(&sh, TEX, [0, 0], ahead), ahead, "a stop keeps the tiles read ahead");
        // The window moves within its centre's tile, either way: nothing moves.
        let tex = Rect::new(1100, 1024, 2124, 2048);
        assert_eq!(Direction.mem_region(&sh, tex, [8, 0], ahead), ahead);
        assert_eq!(Direction.mem_region(&sh, tex, [-8, 0], ahead), ahead);
        // Still, the window reaches tile 3: the region shifts by one only.
        let tex = Rect::new(800, 1024, 1824, 2048);
        assert_eq!(Direction.mem_region(&sh, tex, [0, 0], ahead), Rect::new(3, 4, 9, 10));
        // The ring recentres instead (and reads a column and a row behind).
        assert_eq!(Ring.mem_region(&sh, TEX, [0, 0], ahead), RING);
    }

    #[test]
    fn a_flight_along_s_reads_the_next_columns_at_the_crossing() {
        // Hand-checked: the window moves 64 texels a tick from s0 = 1024 (centre 1536, the start
        // of tile 6). The first region is the ring's (3..9); the centre enters tile 7 at tick 4,
        // when the region jumps ahead to 5..11 (columns 9 and 10 read), then holds until tick 8,
        // when it moves to 6..12 (column 11).
        let sh = shape();
        let mut prev = Rect::EMPTY;
        let mut read = Vec::new();
        for i in 0..9 {
            let s0 = 1024 + 64 * i;
            let next = Direction.mem_region(&sh, Rect::new(s0, 1024, s0 + 1024, 2048), [64, 0], prev);
            for col in next.s0..next.s1 {
                if !prev.is_empty() && !(prev.s0..prev.s1).contains(&col) {
                    read.push((i, col));
                }
            }
            prev = next;
        }
        assert_eq!(read, [(4, 9), (4, 10), (8, 11)]);
    }

    #[test]
    fn a_reverse_moves_the_spare_tiles_only_when_it_crosses_back() {
        let sh = shape();
        let forward = Rect::new(4, 3, 10, 9);
        assert_eq!(Direction.mem_region(&sh, TEX, [-8, 0], forward), forward, "still in tile 6");
        // Centre 1528 (tile 5), from 1536: spares to the -s side.
        let tex = Rect::new(1016, 1024, 2040, 2048);
        assert_eq!(Direction.mem_region(&sh, tex, [-8, 0], forward), Rect::new(2, 3, 8, 9));
    }

    fn config(cases: u32) -> Config {
        Config { cases, rng_seed: RngSeed::Fixed(0xD1), failure_persistence: None, ..Config::default() }
    }

    proptest! {
        #![proptest_config(config(3000))]

        /// Against a brute-force oracle: enumerate every origin a grid-sized region may take
        /// inside the level and keep those that hold every tile of the window. With nothing
        /// before, both policies take the one whose margins beyond the window are most nearly
        /// equal (the ring always does); when
        /// the window's centre (found in its tile by search) changed tile since the last tick,
        /// direction takes the last of them moving forward (spare tiles ahead), the first moving
        /// backward; otherwise the one nearest last tick's.
        #[test]
        fn regions_match_a_brute_force_oracle(
            size in 1u64..=300, clip in 1u64..=64, tile in 1u64..=40, look in 0u64..3,
            c in -50i64..350, v in -3i64..=3, prev in proptest::option::of(-5i64..20),
        ) {
            let sh = LevelShape::new([size, size], [tile, tile], clip, look);
            let tex = crate::geom::tex_region(sh.size, clip, [c, c]);
            let g = sh.grid[0] as i64;
            let n = size.div_ceil(tile) as i64;
            let need = crate::geom::tiles_covering(tex, sh.tile);
            let ok: Vec<i64> = (0..=n - g).filter(|&o| o <= need.s0 && o + g >= need.s1).collect();
            prop_assert!(!ok.is_empty());
            let nearest = |x: i64| *ok.iter().min_by_key(|&&o| ((o - x).abs(), o)).unwrap();
            let previous = prev.map_or(Rect::EMPTY, |o| Rect::new(o, o, o + g, o + g));
            let tw = tile as i64;
            let mid = (tex.s0 + tex.s1).div_euclid(2);
            // The ring's: margins before and after the window most nearly equal (ties: later).
            let ringed = *ok.iter().min_by_key(|&&o| ((2 * mid - (2 * o + g) * tw).abs(), std::cmp::Reverse(o))).unwrap();
            let tile_of = |x: i64| (-1000i64..1000).find(|k| k * tw <= x && x < (k + 1) * tw).unwrap();
            let crossed = tile_of(mid) != tile_of(mid - v);
            let want = match (prev, crossed, v.signum()) {
                (None, _, _) => ringed,
                (Some(_), true, 1) => *ok.last().unwrap(),
                (Some(_), true, -1) => ok[0],
                (Some(o), _, _) => nearest(o),
            };
            let got = Direction.mem_region(&sh, tex, [v, v], previous);
            prop_assert_eq!((got.s0, got.s1), (want, want + g));
            prop_assert_eq!((got.t0, got.t1), (want, want + g));
            let ring = Ring.mem_region(&sh, tex, [v, v], previous);
            prop_assert_eq!(ring.s0, ringed);
            // Both hold every tile the window touches and stay inside the level.
            for r in [got, ring] {
                prop_assert!(r.contains_rect(&need));
                prop_assert!(r.s0 >= 0 && r.s1 <= n);
            }
        }
    }
}
