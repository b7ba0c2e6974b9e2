//! Least-recently-used eviction: the pool gives up the tile read or served longest ago (the
//! common default). It ignores the motion, so it keeps the tiles the viewer has just left and
//! gives up those it saw long ago, wherever the viewer is heading.

use super::{Candidate, Eviction, Motion};

/// Least recently used first (ties: the smallest tile id, so runs are reproducible).
#[derive(Clone, Copy, Debug, Default)]
pub struct Lru;

impl Eviction for Lru {
    fn victim(&self, candidates: &[Candidate], _motion: &Motion) -> usize {
        (0..candidates.len()).min_by_key(|&i| (candidates[i].last_used, candidates[i].tile)).expect("candidates")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tile::TileId;

    #[test]
    fn the_least_recently_used_tile_goes_first_whatever_the_motion() {
        let c = |s, used| Candidate { tile: TileId::new(0, s, 0), last_used: used };
        let pool = [c(5, 3), c(1, 9), c(7, 2), c(2, 2)];
        let motion = Motion { direction: [-10, 0], ..Motion::default() };
        // Tiles 7 and 2 were used at 2: the smaller id first.
        assert_eq!(Lru.victim(&pool, &motion), 3);
        assert_eq!(Lru.victim(&pool[..3], &Motion::default()), 2);
    }
}
