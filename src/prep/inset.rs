//! Sparse insets: the levels finer than an inset level exist only inside a region of the texture
//! (the inset) and a border around it; elsewhere their tiles are absent.
//!
//! The inset's vocabulary only: which tiles of a sparse level hold what. [`super::layout`] works
//! out each level's [`SparseLevel`] from its level table, [`super::sink`] skips absent tiles and
//! [`super::border`] fills the border.
//! For each sparse level k (k < K, the inset level):
//!
//! - *inset tiles*: every tile that overlaps the inset, `[s0, s1) x [t0, t1)` in level-0
//!   texels, scaled to level k (rounded outwards). They hold the source's texels of level k.
//! - *border tiles*: the tiles within `ceil(clip / tile)` tiles of the inset tiles (so the border
//!   is at least one clip size wide in level-k texels, as the clipmap paper asks: a clip window
//!   centred anywhere in the inset reads no absent tile), clamped to the level. They hold the
//!   texels of level K magnified to level k by nearest neighbour: texel (s, t) of level k is
//!   texel (s >> (K - k), t >> (K - k)) of level K.
//! - *absent tiles*: all others. They are not written; the level's `.ic` names a default tile
//!   (all zeros: black, transparent) that readers use in their place.
//!
//! Level K and every coarser level are complete.

/// A region of level 0 with finer levels than the rest of the texture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Inset {
    /// First level-0 column of the region.
    pub s0: u64,
    /// First level-0 row of the region.
    pub t0: u64,
    /// One past the last level-0 column.
    pub s1: u64,
    /// One past the last level-0 row.
    pub t1: u64,
    /// The finest level that covers the whole texture (K); levels 0 .. K are sparse.
    pub level: u32,
}

/// A half-open rectangle of tiles: `[s0, s1) x [t0, t1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct TileRect {
    /// First tile column.
    pub s0: u64,
    /// First tile row.
    pub t0: u64,
    /// One past the last tile column.
    pub s1: u64,
    /// One past the last tile row.
    pub t1: u64,
}

impl TileRect {
    /// True when tile (s, t) lies in the rectangle.
    pub fn contains(&self, s: u64, t: u64) -> bool {
        s >= self.s0 && s < self.s1 && t >= self.t0 && t < self.t1
    }

    /// Tiles in the rectangle.
    pub fn count(&self) -> u64 {
        (self.s1 - self.s0) * (self.t1 - self.t0)
    }
}

/// What one tile of a level holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TileRole {
    /// The source's texels (every tile of a complete level, and inset tiles of a sparse one).
    Source,
    /// Texels of the inset level magnified (border tiles of a sparse level).
    Border,
    /// Not written; the default tile stands in.
    Absent,
}

/// The tiles of one sparse level.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct SparseLevel {
    /// The tiles overlapping the inset.
    pub inset: TileRect,
    /// The inset tiles plus the border: every tile written.
    pub written: TileRect,
    /// Width of the border in tiles on each side (before clamping to the level).
    pub border_tiles: u64,
}

impl SparseLevel {
    /// The role of tile (s, t).
    pub(crate) fn role(&self, s: u64, t: u64) -> TileRole {
        if self.inset.contains(s, t) {
            TileRole::Source
        } else if self.written.contains(s, t) {
            TileRole::Border
        } else {
            TileRole::Absent
        }
    }
}
