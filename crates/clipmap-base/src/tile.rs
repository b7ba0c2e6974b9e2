//! The ground floor: the words every other module speaks and that speak of nothing else.
//!
//! A tile's name ([`TileId`]), the size of a mipmap level ([`level_size`], [`level_count`]) and
//! the 64-bit mixing behind the verification texture and every deterministic choice
//! ([`mix64`], [`splitmix64`], [`hash_value`]). This module imports nothing of the crate, so
//! sources, paging policies, plans and growing textures can all use it without importing each
//! other (docs/ARCHITECTURE.md, "Floors").

use serde::Serialize;
use std::fmt;

/// A tile: level, tile column S and tile row T.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub struct TileId {
    /// Mipmap level (0 is the finest).
    pub level: u32,
    /// Tile column S (texels S*tile_width ..).
    pub s: u64,
    /// Tile row T (texels T*tile_height ..).
    pub t: u64,
}

impl TileId {
    /// Tile (s, t) of `level`.
    #[inline]
    pub fn new(level: u32, s: u64, t: u64) -> Self {
        TileId { level, s, t }
    }
}

impl fmt::Display for TileId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "level {} tile ({}, {})", self.level, self.s, self.t)
    }
}

/// Size of level `k` of a texture whose level 0 is `size`: each edge halved k times (rounding
/// down), at least 1.
#[inline]
pub fn level_size(size: [u64; 2], k: u32) -> [u64; 2] {
    [(size[0] >> k.min(63)).max(1), (size[1] >> k.min(63)).max(1)]
}

/// Number of levels of a full mipmap of `size`: down to 1 x 1.
#[inline]
pub fn level_count(size: [u64; 2]) -> usize {
    let edge = size[0].max(size[1]).max(1);
    (64 - edge.leading_zeros()) as usize
}

/// The SplitMix64 finaliser alone (all arithmetic wrapping on 64 bits): spreads every input bit
/// over the output.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// SplitMix64: the golden-ratio increment, then [`mix64`] (docs/ARCHITECTURE.md §11).
#[inline]
pub fn splitmix64(x: u64) -> u64 {
    mix64(x.wrapping_add(0x9E37_79B9_7F4A_7C15))
}

/// The 64-bit hash behind the verification texel at (level, s, t).
///
/// `s` and `t` must be below 2^29 and `level` below 64 for the key to be unique; textures up to
/// 2^29 texels a side satisfy this. Past it (up to 2^30, `MAX_TEXTURE_SIZE`) the key is kept
/// (every reader, Rust, C and Python, computes the same texture): level-0 texel (s, t) with
/// s >= 2^29 shares its key with (s - 2^29, t | 1) where t is odd, so a reader that misplaced a read
/// by exactly 2^29 texels along s on such rows would not notice; any other misplacement it does.
#[inline]
pub fn hash_value(level: u32, s: u64, t: u64) -> u64 {
    splitmix64(((level as u64) << 58) | (t << 29) | s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix64_matches_the_reference_sequence() {
        // The reference generator's first outputs from state 0 (state += gamma, then mix).
        let mut state = 0u64;
        let mut next = || {
            let out = splitmix64(state);
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            out
        };
        assert_eq!(next(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(next(), 0x6E78_9E6A_A1B9_65F4);
        assert_eq!(next(), 0x06C4_5D18_8009_454F);
    }

    #[test]
    fn level_sizes_halve_rounding_down_and_stop_at_one() {
        assert_eq!(level_size([1000, 333], 1), [500, 166]);
        assert_eq!(level_size([1000, 333], 9), [1, 1]);
        assert_eq!(level_size([1, 1], 70), [1, 1]);
        assert_eq!(level_count([1000, 333]), 10);
        assert_eq!(level_count([1, 1]), 1);
        assert_eq!(level_count([1 << 26, 1 << 26]), 27);
    }
}
