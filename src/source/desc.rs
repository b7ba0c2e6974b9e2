//! [`TextureDesc`]: what a clip texture is, independently of any configuration file.
//!
//! Owns the per-level sizes, tile sizes and the stack / pyramid split. It is built either directly
//! (procedural textures, tests) or from a parsed plan; it knows nothing of files, centres or
//! residency (see [`crate::geom`]).

use crate::texel::TexelFormat;
use serde::Serialize;
use thiserror::Error;

pub use crate::limits::MAX_TEXTURE_SIZE;
pub use crate::tile::{level_count, level_size};

/// One mipmap level: its size and the size of the tiles it is read in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct LevelDesc {
    /// Level size in texels, [s, t].
    pub size: [u64; 2],
    /// Tile size in texels, [s, t]. A pyramid level is one tile the size of the level.
    pub tile: [u64; 2],
}

impl LevelDesc {
    /// Tiles along each axis (the last row / column may be partial).
    pub fn tiles(&self) -> [u64; 2] {
        [self.size[0].div_ceil(self.tile[0]), self.size[1].div_ceil(self.tile[1])]
    }
}

/// Why a texture description was rejected.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum DescError {
    /// A level-0 edge outside 1..=2^30.
    #[error("texture size {size:?} is out of range: each edge must be in 1..={MAX_TEXTURE_SIZE}")]
    SizeOutOfRange {
        /// The level-0 size asked for, s and t.
        size: [u64; 2],
    },
    /// Clip size outside 1..=2^30.
    #[error("clip size {clip} is out of range: expected 1..={MAX_TEXTURE_SIZE}")]
    ClipOutOfRange {
        /// The clip size asked for.
        clip: u64,
    },
    /// A texel format without whole bytes (bitmap) or too wide.
    #[error("texel format {format} has {bytes} bytes per texel: expected 1..=16")]
    Format {
        /// The texel format.
        format: TexelFormat,
        /// Its bytes per texel.
        bytes: u32,
    },
    /// A level list whose length is not the mipmap depth of the level-0 size.
    #[error("{found} levels given for a {size:?} texture: expected {expected} (down to 1 x 1){}", if short != expected { format!(" or {short} (down to where the short side is 1, as Performer 3.0 ends non-square pyramids)") } else { String::new() })]
    LevelCount {
        /// The level-0 size, s and t.
        size: [u64; 2],
        /// The levels down to 1 x 1.
        expected: usize,
        /// The levels down to where the short side is 1.
        short: usize,
        /// The levels given.
        found: usize,
    },
    /// A level whose size is not level 0's shifted right by its index.
    #[error("level {level} is {found:?} texels: expected {expected:?}")]
    LevelSize {
        /// The level.
        level: u32,
        /// Level 0's size shifted right by the level.
        expected: [u64; 2],
        /// The size given.
        found: [u64; 2],
    },
    /// A zero tile edge.
    #[error("level {level} has tile size {tile:?}: each edge must be at least 1")]
    TileSize {
        /// The level.
        level: u32,
        /// Its tile size, s and t.
        tile: [u64; 2],
    },
    /// A stack level whose tiles are larger than one read may be.
    #[error("level {level} has {tile:?}-texel tiles of {bytes} bytes: expected at most {} bytes (MAX_TILE_BYTES) per tile; choose smaller tiles", crate::limits::MAX_TILE_BYTES)]
    TileTooLarge {
        /// The level.
        level: u32,
        /// Its tile size, s and t.
        tile: [u64; 2],
        /// One tile's bytes.
        bytes: u64,
    },
    /// A stack level whose clip window spans more tiles than a level's tile grid may hold.
    #[error("level {level}'s clip window of {clip} texels spans at least {tiles} tiles of {tile:?} texels: expected at most {} (MAX_GRID_TILES); choose larger tiles", crate::limits::MAX_GRID_TILES)]
    TooManyTiles {
        /// The level.
        level: u32,
        /// The clip size.
        clip: u64,
        /// Its tile size, s and t.
        tile: [u64; 2],
        /// The fewest tiles the clip window spans.
        tiles: u64,
    },
    /// An invalid border leaving nothing of the clip window to read.
    #[error("invalid border {border} leaves nothing of clip size {clip}: expected at most {max}")]
    Border {
        /// The invalid border asked for.
        border: u64,
        /// The clip size.
        clip: u64,
        /// The largest border that leaves texels to read.
        max: u64,
    },
}

/// A clip texture: level-0 size, clip size, invalid border, texel format and per-level tiles.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct TextureDesc {
    size: [u64; 2],
    clip_size: u64,
    invalid_border: u64,
    format: TexelFormat,
    levels: Vec<LevelDesc>,
    /// Per level, the mem region (tiles per axis) its configuration asks for, if any.
    mem_grids: Vec<Option<[u64; 2]>>,
}

impl TextureDesc {
    /// A texture whose stack levels are all read in `tile`-sized tiles (clamped to the level) and
    /// whose pyramid levels are single tiles. The invalid border starts at 0.
    pub fn new(size: [u64; 2], clip_size: u64, format: TexelFormat, tile: [u64; 2]) -> Result<Self, DescError> {
        Self::check_size(size)?;
        let levels = (0..level_count(size) as u32)
            .map(|k| {
                let ls = level_size(size, k);
                let stack = ls[0] > clip_size || ls[1] > clip_size;
                let tile = if stack { [tile[0].min(ls[0]), tile[1].min(ls[1])] } else { ls };
                LevelDesc { size: ls, tile }
            })
            .collect();
        if tile[0] == 0 || tile[1] == 0 {
            return Err(DescError::TileSize { level: 0, tile });
        }
        Self::from_levels(size, clip_size, format, levels)
    }

    /// A texture with explicitly described levels (as read from a plan). Levels must be the full
    /// mipmap chain of `size` down to 1 x 1, or, for a non-square texture, the chain down to where
    /// the short side is 1 (as Performer 3.0 builds it).
    pub(crate) fn from_levels(
        size: [u64; 2],
        clip_size: u64,
        format: TexelFormat,
        levels: Vec<LevelDesc>,
    ) -> Result<Self, DescError> {
        Self::check_size(size)?;
        if clip_size == 0 || clip_size > MAX_TEXTURE_SIZE {
            return Err(DescError::ClipOutOfRange { clip: clip_size });
        }
        let bytes = format.bytes_per_texel();
        if !(1..=16).contains(&bytes) {
            return Err(DescError::Format { format, bytes });
        }
        let expected = level_count(size);
        // Performer 3.0 ends a non-square pyramid where its short side reaches 1 (8192 x 2048
        // ends at 4 x 1): such a chain is served as given, its last level the coarsest.
        let short = level_count([size[0].min(size[1]); 2]);
        if levels.len() != expected && levels.len() != short {
            return Err(DescError::LevelCount { size, expected, short, found: levels.len() });
        }
        for (k, l) in levels.iter().enumerate() {
            let want = level_size(size, k as u32);
            if l.size != want {
                return Err(DescError::LevelSize { level: k as u32, expected: want, found: l.size });
            }
            if l.tile[0] == 0 || l.tile[1] == 0 {
                return Err(DescError::TileSize { level: k as u32, tile: l.tile });
            }
            let stack = l.size[0] > clip_size || l.size[1] > clip_size;
            if stack {
                let bytes = format.bytes_for(l.tile[0], l.tile[1]).unwrap_or(u64::MAX);
                if bytes > crate::limits::MAX_TILE_BYTES {
                    return Err(DescError::TileTooLarge { level: k as u32, tile: l.tile, bytes });
                }
                // The fewest tiles a window of the clip size can touch at any alignment.
                let across =
                    |a: usize| (clip_size.min(l.size[a]).div_ceil(l.tile[a]) + 1).min(l.size[a].div_ceil(l.tile[a]));
                let tiles = across(0).saturating_mul(across(1));
                if tiles > crate::limits::MAX_GRID_TILES {
                    return Err(DescError::TooManyTiles { level: k as u32, clip: clip_size, tile: l.tile, tiles });
                }
            }
        }
        let mem_grids = vec![None; levels.len()];
        Ok(TextureDesc { size, clip_size, invalid_border: 0, format, levels, mem_grids })
    }

    fn check_size(size: [u64; 2]) -> Result<(), DescError> {
        if size.iter().any(|&e| e == 0 || e > MAX_TEXTURE_SIZE) {
            return Err(DescError::SizeOutOfRange { size });
        }
        Ok(())
    }

    /// The same texture with another invalid border (texels on each side of a stack window).
    pub fn with_invalid_border(mut self, border: u64) -> Result<Self, DescError> {
        let max = (self.clip_size - 1) / 2;
        if border > max {
            return Err(DescError::Border { border, clip: self.clip_size, max });
        }
        self.invalid_border = border;
        Ok(self)
    }

    /// The same texture in another texel format (tile sizes in texels unchanged).
    /// Checked as `TextureDesc::from_levels` checks a new one: wider texels make every tile
    /// larger, and a tile too large for the new format is refused.
    pub fn with_format(mut self, format: TexelFormat) -> Result<Self, DescError> {
        Self::from_levels(self.size, self.clip_size, format, self.levels.clone())?;
        self.format = format;
        Ok(self)
    }

    /// The same texture with the mem regions (tiles per axis, one entry per level, `None`: the
    /// engine's lookahead decides) its configuration gives: an `.ic`'s `mem_region_size`, or the
    /// region computed from its `lookahead`. The engine raises a grid too small to cover the
    /// window at any alignment to that minimum.
    pub fn with_mem_grids(mut self, grids: Vec<Option<[u64; 2]>>) -> Self {
        assert_eq!(grids.len(), self.levels.len(), "one mem grid entry per level");
        self.mem_grids = grids;
        self
    }

    /// The mem region level `k`'s configuration asks for, if any.
    pub(crate) fn mem_grid(&self, k: u32) -> Option<[u64; 2]> {
        self.mem_grids.get(k as usize).copied().flatten()
    }

    /// Level-0 size [s, t].
    pub fn size(&self) -> [u64; 2] {
        self.size
    }

    /// Clip size (edge of every stack window).
    pub fn clip_size(&self) -> u64 {
        self.clip_size
    }

    /// Invalid border at start-up.
    pub fn invalid_border(&self) -> u64 {
        self.invalid_border
    }

    /// Texel format.
    pub fn format(&self) -> TexelFormat {
        self.format
    }

    /// Bytes per texel (1..=16).
    pub fn bytes_per_texel(&self) -> usize {
        self.format.bytes_per_texel() as usize
    }

    /// Number of levels (level 0 down to 1 x 1).
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// Level `k`. Panics if `k` is not below [`level_count`](Self::level_count).
    pub fn level(&self, k: u32) -> &LevelDesc {
        &self.levels[k as usize]
    }

    /// All levels, finest first.
    pub fn levels(&self) -> &[LevelDesc] {
        &self.levels
    }

    /// Whether level `k` is a stack level (larger than the clip size on some axis).
    pub fn is_stack(&self, k: u32) -> bool {
        let s = self.level(k).size;
        s[0] > self.clip_size || s[1] > self.clip_size
    }

    /// Number of stack levels (they are the finest ones).
    pub fn stack_levels(&self) -> usize {
        (0..self.levels.len() as u32).filter(|&k| self.is_stack(k)).count()
    }

    /// Bytes of one tile of level `k`.
    pub fn tile_bytes(&self, k: u32) -> usize {
        let t = self.level(k).tile;
        // Checked against `limits::MAX_TILE_BYTES` when the texture was described.
        self.format.bytes_for(t[0], t[1]).unwrap_or(u64::MAX) as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_halve_down_to_one_texel_and_split_at_the_clip_size() {
        let d = TextureDesc::new([1 << 12, 1 << 10], 256, TexelFormat::RGBA8, [64, 64]).unwrap();
        assert_eq!(d.level_count(), 13);
        assert_eq!(d.level(0).size, [4096, 1024]);
        assert_eq!(d.level(11).size, [2, 1]);
        assert_eq!(d.level(12).size, [1, 1]);
        // Level 4 is 256 x 64: no larger than the clip size, so a pyramid level held whole.
        assert!(d.is_stack(3) && !d.is_stack(4));
        assert_eq!(d.stack_levels(), 4);
        assert_eq!(d.level(3).tile, [64, 64]);
        assert_eq!(d.level(4).tile, [256, 64]);
        assert_eq!(d.level(0).tiles(), [64, 16]);
        assert_eq!(d.tile_bytes(0), 64 * 64 * 4);
    }

    #[test]
    fn a_one_texel_texture_has_one_pyramid_level() {
        let d = TextureDesc::new([1, 1], 1, TexelFormat::L8, [8, 8]).unwrap();
        assert_eq!(d.level_count(), 1);
        assert!(!d.is_stack(0));
        assert_eq!(d.level(0).tile, [1, 1]);
    }

    #[test]
    fn bad_descriptions_say_what_was_expected() {
        let e = TextureDesc::new([(1 << 30) + 1, 4], 4, TexelFormat::L8, [4, 4]).unwrap_err();
        assert_eq!(e, DescError::SizeOutOfRange { size: [(1 << 30) + 1, 4] });
        let e = TextureDesc::new([64, 64], 0, TexelFormat::L8, [4, 4]).unwrap_err();
        assert!(e.to_string().contains("expected 1..="), "{e}");
        let e = TextureDesc::new([64, 64], 16, TexelFormat::L8, [0, 4]).unwrap_err();
        assert!(matches!(e, DescError::TileSize { .. }));
        let d = TextureDesc::new([64, 64], 16, TexelFormat::L8, [4, 4]).unwrap();
        assert_eq!(d.clone().with_invalid_border(7).unwrap().invalid_border(), 7);
        assert!(matches!(d.with_invalid_border(8), Err(DescError::Border { max: 7, .. })));
        let levels = vec![LevelDesc { size: [4, 4], tile: [4, 4] }, LevelDesc { size: [3, 2], tile: [2, 2] }];
        let e = TextureDesc::from_levels([4, 4], 4, TexelFormat::L8, levels.clone()).unwrap_err();
        assert!(matches!(e, DescError::LevelCount { expected: 3, found: 2, .. }), "{e}");
        let mut three = levels;
        three.push(LevelDesc { size: [1, 1], tile: [1, 1] });
        let e = TextureDesc::from_levels([4, 4], 4, TexelFormat::L8, three).unwrap_err();
        assert_eq!(e.to_string(), "level 1 is [3, 2] texels: expected [2, 2]");
    }

    #[test]
    fn a_non_square_chain_may_end_where_its_short_side_is_one() {
        let chain = |n: u32| -> Vec<LevelDesc> {
            (0..n).map(|k| LevelDesc { size: level_size([16, 4], k), tile: level_size([16, 4], k) }).collect()
        };
        // 16x4 .. 1x1 is 5 levels; Performer 3.0 stops at 4x1: 3 levels.
        assert_eq!(TextureDesc::from_levels([16, 4], 4, TexelFormat::L8, chain(5)).unwrap().level_count(), 5);
        assert_eq!(TextureDesc::from_levels([16, 4], 4, TexelFormat::L8, chain(3)).unwrap().level_count(), 3);
        let e = TextureDesc::from_levels([16, 4], 4, TexelFormat::L8, chain(4)).unwrap_err();
        assert_eq!(
            e.to_string(),
            "4 levels given for a [16, 4] texture: expected 5 (down to 1 x 1) or 3 (down to where the short side is 1, as Performer 3.0 ends non-square pyramids)"
        );
    }
}
