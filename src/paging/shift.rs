//! Shift-based eviction (Luo and Duan): the pool gives up first the tiles farthest behind the
//! direction of motion. Each tile outside its level's expanded (mem) region is projected, by its
//! centre in level-0 texels, on the motion vector from the viewer's centre; the most negative
//! projection goes first. When none is behind, the tile farthest ahead goes first (the one
//! needed last, were the viewer to go on). Tiles inside a mem region (their grid holds them now)
//! go only when no other is left. Without any motion yet, the tile farthest from the centre goes
//! first.
//!
//! It forgets recency: a tile just left behind is kept over one left long ago only while it is
//! nearer along the motion, which is the policy's claim (the viewer rarely turns back) and its
//! risk (a turn-around or a circle needs the tiles behind again).

use super::{Candidate, Eviction, Motion};

/// Farthest behind the motion first (ties: least recently used, then the smallest tile id).
#[derive(Clone, Copy, Debug, Default)]
pub struct Shift;

/// How much `c` is worth keeping: (inside a mem region, ahead of the viewer, then the
/// projection on the motion for a tile behind, minus it for a tile ahead, minus the distance to
/// the centre when there is no motion). Smaller is evicted first.
fn standing(c: &Candidate, motion: &Motion) -> (bool, bool, f64) {
    let k = c.tile.level as usize;
    let inside = motion.mem.get(k).is_some_and(|m| m.contains(c.tile.s as i64, c.tile.t as i64));
    let tile = motion.tile.get(k).copied().unwrap_or([1, 1]);
    let scale = (1u64 << k.min(62)) as f64;
    let at = |i: u64, edge: u64, c0: i64| (i as f64 + 0.5) * edge as f64 * scale - c0 as f64;
    let rel = [at(c.tile.s, tile[0], motion.centre[0]), at(c.tile.t, tile[1], motion.centre[1])];
    let d = motion.direction;
    if d == [0, 0] {
        return (inside, false, -(rel[0] * rel[0] + rel[1] * rel[1]).sqrt());
    }
    let p = rel[0] * d[0] as f64 + rel[1] * d[1] as f64;
    if p < 0.0 {
        (inside, false, p)
    } else {
        (inside, true, -p)
    }
}

impl Eviction for Shift {
    fn victim(&self, candidates: &[Candidate], motion: &Motion) -> usize {
        let key: Vec<(bool, bool, f64)> = candidates.iter().map(|c| standing(c, motion)).collect();
        (0..candidates.len())
            .min_by(|&a, &b| {
                let ((ia, aa, pa), (ib, ab, pb)) = (key[a], key[b]);
                ia.cmp(&ib)
                    .then(aa.cmp(&ab))
                    .then(pa.total_cmp(&pb))
                    .then(candidates[a].last_used.cmp(&candidates[b].last_used))
                    .then(candidates[a].tile.cmp(&candidates[b].tile))
            })
            .expect("candidates")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Rect;
    use crate::paging::lru::Lru;
    use crate::tile::TileId;

    /// Evicts every candidate in turn; returns the tiles in the order they went.
    fn order(policy: &dyn Eviction, mut pool: Vec<Candidate>, motion: &Motion) -> Vec<(u32, u64)> {
        let mut out = Vec::new();
        while !pool.is_empty() {
            let c = pool.remove(policy.victim(&pool, motion));
            out.push((c.tile.level, c.tile.s));
        }
        out
    }

    /// Flying +s at x = 1000 over 100-texel tiles: level 0's grid holds columns 8..14, level 1's
    /// columns 3..7.
    fn flying_east() -> Motion {
        Motion {
            centre: [1000, 50],
            direction: [10, 0],
            mem: vec![Rect::new(8, 0, 14, 6), Rect::new(3, 0, 7, 4)],
            tile: vec![[100, 100], [100, 100]],
        }
    }

    #[test]
    fn tiles_farthest_behind_the_motion_go_first_and_the_grids_tiles_last() {
        let c = |level, s, used| Candidate { tile: TileId::new(level, s, 0), last_used: used };
        // Hand-checked projections on +s from x = 1000 (level-0 texels of tile centres):
        // (0, 2): 250 - 1000 = -750; (1, 1): 300 - 1000 = -700; (0, 5): 550 - 1000 = -450;
        // (0, 20): 2050 - 1000 = +1050 (left earlier, now ahead); (0, 9) and (1, 4) are inside
        // their grids.
        let pool = vec![c(0, 9, 8), c(0, 5, 5), c(0, 20, 1), c(1, 1, 7), c(0, 2, 6), c(1, 4, 2)];
        let m = flying_east();
        assert_eq!(order(&Shift, pool.clone(), &m), [(0, 2), (1, 1), (0, 5), (0, 20), (1, 4), (0, 9)]);
        // LRU goes by use alone: the tile ahead (used at 1) goes first.
        assert_eq!(order(&Lru, pool, &m), [(0, 20), (1, 4), (0, 5), (0, 2), (1, 1), (0, 9)]);
    }

    #[test]
    fn a_turn_around_gives_up_what_is_now_behind_then_the_farthest_ahead() {
        let c = |s, used| Candidate { tile: TileId::new(0, s, 0), last_used: used };
        let pool = vec![c(2, 1), c(5, 2), c(20, 3), c(11, 4)];
        // Flying west from x = 1000: column 20 (centre 2050) is behind; 2 (250) lies 750 texels
        // ahead, 5 (550) 450; column 11 is inside the grid.
        let west = Motion { direction: [-10, 0], ..flying_east() };
        assert_eq!(order(&Shift, pool, &west), [(0, 20), (0, 2), (0, 5), (0, 11)]);
    }

    #[test]
    fn without_motion_the_farthest_tile_goes_first_then_the_least_recently_used() {
        let c = |s, t, used| Candidate { tile: TileId::new(0, s, t), last_used: used };
        let m = Motion { direction: [0, 0], mem: vec![Rect::EMPTY], ..flying_east() };
        // Distances from (1000, 50): (0, 0) 950; (19, 0) 950; (10, 3) ~316; (12, 0) 250.
        let pool = vec![c(12, 0, 1), c(19, 0, 5), c(10, 3, 0), c(0, 0, 9)];
        let got: Vec<_> = {
            let mut p = pool;
            let mut out = Vec::new();
            while !p.is_empty() {
                let v = p.remove(Shift.victim(&p, &m));
                out.push((v.tile.s, v.tile.t));
            }
            out
        };
        assert_eq!(got, [(19, 0), (0, 0), (10, 3), (12, 0)]);
    }
}
