//! Sparse insets: the levels finer than an inset level exist only inside a region of the texture
//! (the inset) and a border around it; elsewhere their tiles are absent.
//!
//! Geometry only; [`super::sink`] skips absent tiles and [`super::border`] fills the border.
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

use super::error::PrepError;
use super::layout::{Layout, Level, LevelKind};

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
    pub fn role(&self, s: u64, t: u64) -> TileRole {
        if self.inset.contains(s, t) {
            TileRole::Source
        } else if self.written.contains(s, t) {
            TileRole::Border
        } else {
            TileRole::Absent
        }
    }
}

impl Inset {
    /// Checks the inset against the level table: a non-empty region inside level 0, and an inset
    /// level K >= 1 such that every level finer than K is an image-cache level.
    pub fn check(&self, layout: &Layout) -> Result<(), PrepError> {
        let (w, h) = (layout.spec.width, layout.spec.height);
        if self.s0 >= self.s1 || self.t0 >= self.t1 || self.s1 > w || self.t1 > h {
            return Err(PrepError::Geometry(format!(
                "the inset {},{},{},{} is not a non-empty region of the {w}x{h} texture; expected S0,T0,S1,T1 with S0 < S1 <= {w} and T0 < T1 <= {h} (level-0 texels, S1 and T1 exclusive)",
                self.s0, self.t0, self.s1, self.t1
            )));
        }
        let ics = layout.image_cache_levels().count() as u32;
        if self.level == 0 || self.level > ics || (self.level as usize) >= layout.levels.len() {
            return Err(PrepError::Geometry(format!(
                "--inset-level {} leaves no sparse level or makes a pyramid level sparse; this texture has {ics} image-cache levels, so expected an inset level from 1 to {ics}",
                self.level
            )));
        }
        Ok(())
    }

    /// The tiles of `level` if it is sparse (finer than the inset level), `None` if complete.
    pub fn sparse(&self, layout: &Layout, level: &Level) -> Option<SparseLevel> {
        if level.index >= self.level || level.kind != LevelKind::ImageCache {
            return None;
        }
        let k = level.index;
        let (tw, th) = (level.tile_w, level.tile_h);
        let scale_out = |v: u64| v.div_ceil(1 << k);
        let inset = TileRect {
            s0: (self.s0 >> k) / tw,
            t0: (self.t0 >> k) / th,
            s1: scale_out(self.s1).div_ceil(tw),
            t1: scale_out(self.t1).div_ceil(th),
        };
        let clip = layout.spec.clip;
        let border_tiles = clip.div_ceil(tw).max(clip.div_ceil(th));
        let written = TileRect {
            s0: inset.s0.saturating_sub(border_tiles),
            t0: inset.t0.saturating_sub(border_tiles),
            s1: (inset.s1 + border_tiles).min(level.tiles_s()),
            t1: (inset.t1 + border_tiles).min(level.tiles_t()),
        };
        Some(SparseLevel { inset, written, border_tiles })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::prep::layout::Spec;
    use crate::texel::TexelFormat;

    fn layout(size: u64, clip: u64, tile: u64) -> Layout {
        Layout::new(Spec {
            width: size,
            height: size,
            clip,
            tile,
            format: TexelFormat::L8,
            tiles_in_file: (1, 1),
            header_bytes: 0,
            streams: None,
            inset: None,
            compression: None,
        })
        .unwrap()
    }

    #[test]
    fn inset_tiles_round_outwards_and_the_border_is_a_clip_size_wide() {
        let l = layout(4096, 256, 64);
        let inset = Inset { s0: 1000, t0: 2000, s1: 1100, t1: 2001, level: 2 };
        inset.check(&l).unwrap();
        let l0 = inset.sparse(&l, &l.levels[0]).unwrap();
        assert_eq!(l0.inset, TileRect { s0: 15, t0: 31, s1: 18, t1: 32 });
        assert_eq!(l0.border_tiles, 4);
        assert_eq!(l0.written, TileRect { s0: 11, t0: 27, s1: 22, t1: 36 });
        assert_eq!(l0.role(15, 31), TileRole::Source);
        assert_eq!(l0.role(11, 35), TileRole::Border);
        assert_eq!(l0.role(10, 31), TileRole::Absent);
        let l1 = inset.sparse(&l, &l.levels[1]).unwrap();
        // Level 1: columns 500 .. 550, rows 1000 .. 1001 (1001 rounded out).
        assert_eq!(l1.inset, TileRect { s0: 7, t0: 15, s1: 9, t1: 16 });
        assert!(inset.sparse(&l, &l.levels[2]).is_none());
    }

    #[test]
    fn the_border_is_clamped_to_the_level() {
        let l = layout(1024, 256, 128);
        let inset = Inset { s0: 0, t0: 0, s1: 1, t1: 1, level: 1 };
        let l0 = inset.sparse(&l, &l.levels[0]).unwrap();
        assert_eq!(l0.written, TileRect { s0: 0, t0: 0, s1: 3, t1: 3 });
    }

    #[test]
    fn an_empty_region_or_a_sparse_pyramid_level_is_refused() {
        let l = layout(1024, 256, 128);
        let empty = Inset { s0: 10, t0: 0, s1: 10, t1: 5, level: 1 };
        assert!(empty.check(&l).unwrap_err().to_string().contains("non-empty"));
        // 1024 with clip 256: image caches 1024 and 512 only.
        let deep = Inset { s0: 0, t0: 0, s1: 8, t1: 8, level: 3 };
        assert!(deep.check(&l).unwrap_err().to_string().contains("from 1 to 2"));
        let zero = Inset { level: 0, ..deep };
        assert!(zero.check(&l).is_err());
    }
}
