//! Where everything goes: the level table of a prepared clip texture (which levels are image
//! caches, which are pyramid levels), tile sizes per level, and the relative path, byte offset and
//! stream of every tile.
//!
//! Pure geometry: no I/O. The names chosen here are the ones `super::configfile` writes into
//! the `.ct`/`.ic` files, so a reader that follows docs/PERFORMER-REFERENCE.md §1.9–§1.14 finds every tile.
//!
//! Layout of a prepared directory:
//!
//! ```text
//! NAME.ct                    the clip texture
//! L00.ic, L01.ic, ...        one image cache per image-cache level
//! [streamN/]L00/rRRR.cCCC.raw  image-cache tile files (R = file row, C = file column);
//!                            `.raw.zst` when compressed (one zstd frame per tile)
//! pyramid/L05.raw, ...       one file per pyramid level (a single tile the size of the level)
//! ```

use super::error::{next_power_of_two, PrepError};
use super::inset::{Inset, SparseLevel, TileRect, TileRole};
use crate::texel::TexelFormat;
use std::path::PathBuf;

/// Performer raises any smaller `invalid_border` to this (docs/PERFORMER-REFERENCE.md §1.4), so a clip window
/// must be larger than twice it.
pub(crate) const MIN_INVALID_BORDER: u64 = 8;

/// What the user asked for, before any derivation.
#[derive(Clone, Debug)]
pub struct Spec {
    /// Level-0 width (S) in texels.
    pub width: u64,
    /// Level-0 height (T) in texels.
    pub height: u64,
    /// Clip size (texels).
    pub clip: u64,
    /// Tile edge (texels) of image-cache tiles.
    pub tile: u64,
    /// Texel format on disk.
    pub format: TexelFormat,
    /// Tiles per file along S and T (`tiles_in_file`); (1, 1) is one tile per file.
    pub tiles_in_file: (u64, u64),
    /// Bytes of header at the start of every image-cache tile file (`header_offset`).
    pub header_bytes: u64,
    /// Number of stream servers (directories `stream0/` ...); `None` for none.
    pub streams: Option<u32>,
    /// A sparse inset: levels finer than its level exist only around it.
    pub inset: Option<Inset>,
    /// Compression of image-cache tiles (pyramid levels stay raw).
    pub compression: Option<Compression>,
}

impl Spec {
    /// A plain RGB8 texture of `width` x `height`: one tile per file, no header, streams, inset
    /// or compression (the tests' starting point).
    #[cfg(test)]
    pub(crate) fn plain(width: u64, height: u64, clip: u64, tile: u64) -> Spec {
        Spec {
            width,
            height,
            clip,
            tile,
            format: TexelFormat::RGB8,
            tiles_in_file: (1, 1),
            header_bytes: 0,
            streams: None,
            inset: None,
            compression: None,
        }
    }
}

/// How image-cache tiles are compressed: an extension of this crate, which Performer cannot read.
///
/// Each tile is one file holding one zstd frame of the raw tile (the bytes Performer's layout
/// would hold); the tile files end in `.raw.zst` instead of `.raw`, which is the only mark in the
/// configuration. Pyramid levels stay raw.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Compression {
    /// zstd at the given level (1 to 22; 3 is zstd's default).
    Zstd(i32),
}

/// Whether a level is paged through an image cache or held whole.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LevelKind {
    /// A level at least `smallest_icache` large: an `.ic` and tiles.
    ImageCache,
    /// A smaller level: one file holding the whole level as a single tile.
    Pyramid,
}

/// One level of the prepared texture.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Level {
    /// Level index, 0 the finest.
    pub index: u32,
    /// Width in texels.
    pub width: u64,
    /// Height in texels.
    pub height: u64,
    /// Image cache or pyramid.
    pub kind: LevelKind,
    /// Tile width in texels (the level width for a pyramid level).
    pub tile_w: u64,
    /// Tile height in texels (the level height for a pyramid level).
    pub tile_h: u64,
}

impl Level {
    /// Tiles along S.
    pub(crate) fn tiles_s(&self) -> u64 {
        self.width / self.tile_w
    }

    /// Tiles along T.
    pub(crate) fn tiles_t(&self) -> u64 {
        self.height / self.tile_h
    }

    /// Texels in the level.
    pub fn texels(&self) -> u64 {
        self.width * self.height
    }
}

/// Where one tile lives, relative to the prepared directory.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct TileLocation {
    /// The file, relative to the directory of the `.ct`.
    pub path: PathBuf,
    /// Byte offset of the tile in the file.
    pub offset: u64,
    /// Bytes of the tile.
    pub length: u64,
    /// Stream server index, if streams are used.
    pub stream: Option<u32>,
}

/// The derived level table and naming scheme.
#[derive(Clone, Debug)]
pub struct Layout {
    /// What was asked for.
    pub spec: Spec,
    /// Every level, finest first.
    pub levels: Vec<Level>,
    /// Performer's `smallest_icache` (S, T) for this layout.
    pub smallest_icache: (u64, u64),
    /// True when `smallest_icache` equals Performer's default (so the `.ct` need not say it).
    pub smallest_icache_is_default: bool,
    /// Tiles stored block-compressed ([`Layout::with_blocks`]): the format and the encoder's
    /// quality; `None` for texels as they are.
    pub blocks: Option<(crate::texel::Bc, crate::source::BcQuality)>,
}

fn check_pow2(what: String, v: u64, hint: &'static str) -> Result<(), PrepError> {
    if v == 0 || !v.is_power_of_two() {
        return Err(PrepError::NotPowerOfTwo { what, found: v, next: next_power_of_two(v), hint });
    }
    Ok(())
}

impl Layout {
    /// Derives the level table, following docs/PERFORMER-REFERENCE.md §1.14.
    ///
    /// `smallest_icache` is Performer's default where that default is valid (square textures and
    /// aspect ratios up to 2); for more elongated textures the default would exceed twice the clip
    /// size (which 3.0 rejects), so the long side is set to 2 x clip and the short side follows the
    /// aspect ratio; the `.ct` then states it.
    pub fn new(spec: Spec) -> Result<Layout, PrepError> {
        check_pow2("the clip size".into(), spec.clip, "; pass --clip with a power of two")?;
        check_pow2("the tile size".into(), spec.tile, "; pass --tile with a power of two")?;
        if spec.clip <= 2 * MIN_INVALID_BORDER {
            return Err(PrepError::Geometry(format!(
                "the clip size {} leaves nothing of the clip window once Performer's minimum invalid border of {MIN_INVALID_BORDER} texels is taken from each side; expected a clip size of at least {}; pass a larger --clip",
                spec.clip,
                4 * MIN_INVALID_BORDER
            )));
        }
        if spec.format.bytes_per_texel() == 0 {
            return Err(PrepError::Geometry(format!("texel format {} has no byte size", spec.format)));
        }
        let (w, h) = (spec.width, spec.height);
        let max = crate::source::MAX_TEXTURE_SIZE;
        if w > max || h > max || spec.tile > max {
            return Err(PrepError::Geometry(format!(
                "the texture is {w}x{h} with {} texel tiles; expected each at most {max} (MAX_TEXTURE_SIZE, 2^30) texels; pass a smaller --size or --tile",
                spec.tile
            )));
        }
        let (long, short) = (w.max(h), w.min(h));
        if spec.clip > short {
            return Err(PrepError::Geometry(format!(
                "the clip size {} is larger than the texture's shorter side ({w}x{h}); expected a clip size of at most {short}; pass a smaller --clip",
                spec.clip
            )));
        }
        if spec.tiles_in_file.0 == 0 || spec.tiles_in_file.1 == 0 {
            return Err(PrepError::Geometry("--tiles-per-file must be at least 1 along each axis".into()));
        }
        if spec.compression.is_some() && (spec.tiles_in_file != (1, 1) || spec.header_bytes != 0) {
            return Err(PrepError::Geometry(
                "compressed tiles are one tile per file without a header (a compressed tile has no fixed offset); drop --tiles-per-file and --header-bytes, or --compress".into(),
            ));
        }
        if spec.streams == Some(0) {
            return Err(PrepError::Geometry("--streams must be at least 1".into()));
        }
        let ratio = long / short;
        let c2 = 2 * spec.clip;
        if c2 < ratio {
            return Err(PrepError::Geometry(format!(
                "the texture's aspect ratio {ratio}:1 ({w}x{h}) exceeds twice the clip size ({c2}); Performer's level layout cannot express it; pass --clip {} or more",
                ratio.div_ceil(2)
            )));
        }
        let mut smallest = if w >= h { (c2, c2 / ratio) } else { (c2 / ratio, c2) };
        if smallest.0 > w {
            // The whole texture fits the clip window (size == clip): level 0 becomes the one
            // image cache, rather than a smallest_icache larger than the texture.
            smallest = (w, h);
        }
        let default = if w == h {
            (c2, c2)
        } else if w > h {
            (spec.clip * ratio, spec.clip)
        } else {
            (spec.clip, spec.clip * ratio)
        };
        let mut levels = Vec::new();
        let mut k = 0u32;
        while (w >> k) >= smallest.0 && (h >> k) >= smallest.1 {
            let (lw, lh) = (w >> k, h >> k);
            levels.push(Level {
                index: k,
                width: lw,
                height: lh,
                kind: LevelKind::ImageCache,
                tile_w: spec.tile.min(lw),
                tile_h: spec.tile.min(lh),
            });
            k += 1;
        }
        while (w >> k) > 0 && (h >> k) > 0 {
            let (lw, lh) = (w >> k, h >> k);
            levels.push(Level { index: k, width: lw, height: lh, kind: LevelKind::Pyramid, tile_w: lw, tile_h: lh });
            k += 1;
        }
        let layout = Layout {
            spec,
            levels,
            smallest_icache: smallest,
            smallest_icache_is_default: smallest == default,
            blocks: None,
        };
        if let Some(inset) = &layout.spec.inset {
            layout.check_inset(inset)?;
        }
        Ok(layout)
    }

    /// The same layout with its tiles stored block-compressed in `bc` (`clipprep --format
    /// bc1|bc4|bc5|bc7`; docs/CONFIG.md, "Block-compressed tiles"): the levels are made of
    /// `spec.format` texels as before (8-bit: the encoder's input), and each tile is encoded whole
    /// at `quality` as it is written, so a service serves the blocks without encoding. Refused
    /// for texels other than 8-bit grey, RGB or RGBA, and for tiles that do not start on a 4 x 4
    /// block (tiles of fewer than 4 texels that do not span their level).
    pub fn with_blocks(mut self, bc: crate::texel::Bc, quality: crate::source::BcQuality) -> Result<Layout, PrepError> {
        use crate::texel::ComponentType;
        if self.spec.format.ctype != ComponentType::U8 {
            return Err(PrepError::Geometry(format!(
                "--format {} encodes 8-bit texels, and the texels are {}; expected an 8-bit grey, RGB or RGBA source",
                bc.name(),
                self.spec.format
            )));
        }
        for l in &self.levels {
            let ok = |tile: u64, size: u64| tile.is_multiple_of(4) || tile >= size;
            if !ok(l.tile_w, l.width) || !ok(l.tile_h, l.height) {
                return Err(PrepError::Geometry(format!(
                    "--format {}: level {} ({}x{}) has {}x{} tiles, which do not start on 4 x 4 blocks; pass a --tile of at least 4",
                    bc.name(),
                    l.index,
                    l.width,
                    l.height,
                    l.tile_w,
                    l.tile_h
                )));
            }
        }
        self.blocks = Some((bc, quality));
        Ok(self)
    }

    /// The format of the tiles on disk: the block format when tiles are block-compressed, else
    /// `spec.format`.
    pub fn disk_format(&self) -> TexelFormat {
        self.blocks.map_or(self.spec.format, |(bc, _)| bc.format())
    }

    /// Bytes of one tile of `level` on disk (whole 4 x 4 blocks when block-compressed).
    pub fn tile_bytes(&self, level: &Level) -> u64 {
        self.disk_format().bytes_for(level.tile_w, level.tile_h).unwrap_or(u64::MAX)
    }

    /// The tiles of `level` if the layout has an inset and the level is finer than its level.
    pub fn sparse(&self, level: &Level) -> Option<SparseLevel> {
        self.spec.inset.as_ref().and_then(|i| self.sparse_of(i, level))
    }

    /// What tile (s, t) of `level` holds.
    pub(crate) fn tile_role(&self, level: &Level, s: u64, t: u64) -> TileRole {
        self.sparse(level).map_or(TileRole::Source, |sp| sp.role(s, t))
    }

    /// The default tile of a sparse image-cache level, relative to the `.ct` (beside its `.ic`).
    pub(crate) fn default_tile_file(level: u32) -> String {
        format!("L{level:02}.default.raw")
    }

    /// Texels written over all levels (all of them, less the absent tiles of sparse levels).
    pub(crate) fn written_texels(&self) -> u64 {
        self.levels
            .iter()
            .map(|l| match self.sparse(l) {
                Some(sp) => sp.written.count() * l.tile_w * l.tile_h,
                None => l.texels(),
            })
            .sum()
    }

    /// Bytes per texel.
    pub fn bpt(&self) -> u64 {
        // The texels the levels are made of (the encoder's input when tiles are block-compressed).

        self.spec.format.bytes_per_texel() as u64
    }

    /// The image-cache levels, finest first.
    pub fn image_cache_levels(&self) -> impl Iterator<Item = &Level> {
        self.levels.iter().filter(|l| l.kind == LevelKind::ImageCache)
    }

    /// The pyramid levels, finest first.
    pub fn pyramid_levels(&self) -> impl Iterator<Item = &Level> {
        self.levels.iter().filter(|l| l.kind == LevelKind::Pyramid)
    }

    /// Total texels over all levels.
    pub fn total_texels(&self) -> u64 {
        self.levels.iter().map(Level::texels).sum()
    }

    /// The `.ic` file of an image-cache level, relative to the `.ct`.
    pub(crate) fn ic_file(level: u32) -> String {
        format!("L{level:02}.ic")
    }

    /// The directory of an image-cache level's tiles (inside each stream directory, if any).
    pub(crate) fn level_dir(level: u32) -> String {
        format!("L{level:02}")
    }

    /// The file of a pyramid level, relative to the `.ct`.
    pub(crate) fn pyramid_file(level: u32) -> String {
        format!("pyramid/L{level:02}.raw")
    }

    /// The name (path prefix, with its trailing `/`) of stream server `i`.
    pub(crate) fn stream_name(i: u32) -> String {
        format!("stream{i}/")
    }

    /// The printf format of an image-cache level's tile files, as written into its `.ic`; its
    /// parameters are [`Layout::tile_params`].
    pub fn tile_format(&self, level: u32) -> String {
        let stream = if self.spec.streams.is_some() { "%s" } else { "" };
        format!("{stream}{}/r%03d.c%03d{}", Self::level_dir(level), self.tile_extension())
    }

    /// The extension of image-cache tile files: `.raw`, or `.raw.zst` when compressed.
    pub(crate) fn tile_extension(&self) -> &'static str {
        match self.spec.compression {
            None => ".raw",
            Some(Compression::Zstd(_)) => ".raw.zst",
        }
    }

    /// True when tiles of `level` are written compressed (whole tiles, one per file).
    pub fn compressed(&self, level: &Level) -> bool {
        self.spec.compression.is_some() && level.kind == LevelKind::ImageCache
    }

    /// The `tile_params` of [`Layout::tile_format`].
    pub fn tile_params(&self) -> Vec<&'static str> {
        let mut p = Vec::new();
        if self.spec.streams.is_some() {
            p.push("PFIMAGECACHE_TILE_FILENAMEARG_STREAMSERVERNAME");
        }
        p.push("PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_T");
        p.push("PFIMAGECACHE_TILE_FILENAMEARG_FILENUM_S");
        p
    }

    /// Where tile (s, t) of `level` lives. For a pyramid level only (0, 0) exists.
    pub fn tile(&self, level: &Level, s: u64, t: u64) -> TileLocation {
        let length = self.tile_bytes(level);
        match level.kind {
            LevelKind::Pyramid => {
                TileLocation { path: PathBuf::from(Self::pyramid_file(level.index)), offset: 0, length, stream: None }
            }
            LevelKind::ImageCache => {
                let (ns, nt) = self.spec.tiles_in_file;
                let (fs, ft) = (s / ns, t / nt);
                let pos = (s % ns) + ns * (t % nt);
                let stream = self.spec.streams.map(|n| (s % n as u64) as u32);
                let mut path = String::new();
                if let Some(i) = stream {
                    path.push_str(&Self::stream_name(i));
                }
                path.push_str(&format!("{}/r{ft:03}.c{fs:03}{}", Self::level_dir(level.index), self.tile_extension()));
                TileLocation {
                    path: PathBuf::from(path),
                    offset: pos * length + self.spec.header_bytes,
                    length,
                    stream,
                }
            }
        }
    }

    /// Directories (relative) that tiles are written into.
    pub fn directories(&self) -> Vec<PathBuf> {
        let mut dirs = Vec::new();
        let prefixes: Vec<String> = match self.spec.streams {
            Some(n) => (0..n).map(Self::stream_name).collect(),
            None => vec![String::new()],
        };
        for level in self.image_cache_levels() {
            for p in &prefixes {
                dirs.push(PathBuf::from(format!("{p}{}", Self::level_dir(level.index))));
            }
        }
        if self.pyramid_levels().next().is_some() {
            dirs.push(PathBuf::from("pyramid"));
        }
        dirs
    }
}

impl Layout {
    /// Checks an inset against the level table: a non-empty region inside level 0, and an inset
    /// level K >= 1 such that every level finer than K is an image-cache level.
    fn check_inset(&self, region: &Inset) -> Result<(), PrepError> {
        let (w, h) = (self.spec.width, self.spec.height);
        let Inset { s0, t0, s1, t1, level } = *region;
        if s0 >= s1 || t0 >= t1 || s1 > w || t1 > h {
            return Err(PrepError::Geometry(format!(
                "the inset {s0},{t0},{s1},{t1} is not a non-empty region of the {w}x{h} texture; expected S0,T0,S1,T1 with S0 < S1 <= {w} and T0 < T1 <= {h} (level-0 texels, S1 and T1 exclusive)"
            )));
        }
        let ics = self.image_cache_levels().count() as u32;
        if level == 0 || level > ics || (level as usize) >= self.levels.len() {
            return Err(PrepError::Geometry(format!(
                "--inset-level {level} leaves no sparse level or makes a pyramid level sparse; this texture has {ics} image-cache levels, so expected an inset level from 1 to {ics}"
            )));
        }
        Ok(())
    }

    /// The tiles of `level` under the inset `region` if the level is sparse (finer than the inset
    /// level), `None` if it is complete.
    fn sparse_of(&self, region: &Inset, level: &Level) -> Option<SparseLevel> {
        if level.index >= region.level || level.kind != LevelKind::ImageCache {
            return None;
        }
        let k = level.index;
        let (tw, th) = (level.tile_w, level.tile_h);
        let scale_out = |v: u64| v.div_ceil(1 << k);
        let inset = TileRect {
            s0: (region.s0 >> k) / tw,
            t0: (region.t0 >> k) / th,
            s1: scale_out(region.s1).div_ceil(tw),
            t1: scale_out(region.t1).div_ceil(th),
        };
        let clip = self.spec.clip;
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

    fn spec(w: u64, h: u64, clip: u64, tile: u64) -> Spec {
        Spec::plain(w, h, clip, tile)
    }

    #[test]
    fn square_layout_matches_the_manual_example() {
        // virt 4096, clip 512: 3 image caches (4096, 2048, 1024) + 10 pyramid levels (512 .. 1).
        let l = Layout::new(spec(4096, 4096, 512, 256)).unwrap();
        assert_eq!(l.image_cache_levels().count(), 3);
        assert_eq!(l.pyramid_levels().count(), 10);
        assert_eq!(l.levels.last().unwrap().width, 1);
        assert!(l.smallest_icache_is_default);
    }

    #[test]
    fn non_square_pyramid_stops_when_the_short_side_would_vanish() {
        // 8192x2048 ends at 4x1 (docs/PERFORMER-REFERENCE.md §1.14).
        let l = Layout::new(spec(8192, 2048, 1024, 256)).unwrap();
        let last = l.levels.last().unwrap();
        assert_eq!((last.width, last.height), (4, 1));
        assert_eq!(l.smallest_icache, (2048, 512));
    }

    #[test]
    fn multi_tile_files_follow_the_offset_formula() {
        // docs/PERFORMER-REFERENCE.md §1.12: 256x256 RGB tiles, 4x4 per file, header 1024, tile (6, 9).
        let mut sp = spec(4096, 4096, 512, 256);
        sp.tiles_in_file = (4, 4);
        sp.header_bytes = 1024;
        let l = Layout::new(sp).unwrap();
        let loc = l.tile(&l.levels[0], 6, 9);
        assert_eq!(loc.offset, 1_180_672);
        assert_eq!(loc.path, PathBuf::from("L00/r002.c001.raw"));
    }

    #[test]
    fn a_texture_the_size_of_the_clip_window_is_one_image_cache_and_its_pyramid() {
        let l = Layout::new(spec(64, 64, 64, 32)).unwrap();
        assert_eq!(l.smallest_icache, (64, 64));
        assert!(!l.smallest_icache_is_default);
        assert_eq!(l.image_cache_levels().count(), 1);
        assert_eq!(l.levels.len(), 7);
    }

    #[test]
    fn compressed_tiles_are_named_raw_zst_one_per_file() {
        let mut sp = spec(1024, 1024, 256, 128);
        sp.compression = Some(Compression::Zstd(3));
        let l = Layout::new(sp.clone()).unwrap();
        assert_eq!(l.tile_format(0), "L00/r%03d.c%03d.raw.zst");
        assert_eq!(l.tile(&l.levels[1], 2, 3).path, PathBuf::from("L01/r003.c002.raw.zst"));
        assert!(l.compressed(&l.levels[1]) && !l.compressed(&l.levels[2]));
        sp.header_bytes = 16;
        assert!(Layout::new(sp).unwrap_err().to_string().contains("one tile per file"));
    }

    #[test]
    fn non_powers_of_two_are_refused_with_the_next_power() {
        let e = Layout::new(spec(256, 256, 100, 64)).unwrap_err();
        assert!(e.to_string().contains("128"), "{e}");
    }

    fn inset_layout(size: u64, clip: u64, tile: u64) -> Layout {
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
        let l = inset_layout(4096, 256, 64);
        let inset = Inset { s0: 1000, t0: 2000, s1: 1100, t1: 2001, level: 2 };
        l.check_inset(&inset).unwrap();
        let l0 = l.sparse_of(&inset, &l.levels[0]).unwrap();
        assert_eq!(l0.inset, TileRect { s0: 15, t0: 31, s1: 18, t1: 32 });
        assert_eq!(l0.border_tiles, 4);
        assert_eq!(l0.written, TileRect { s0: 11, t0: 27, s1: 22, t1: 36 });
        assert_eq!(l0.role(15, 31), TileRole::Source);
        assert_eq!(l0.role(11, 35), TileRole::Border);
        assert_eq!(l0.role(10, 31), TileRole::Absent);
        let l1 = l.sparse_of(&inset, &l.levels[1]).unwrap();
        // Level 1: columns 500 .. 550, rows 1000 .. 1001 (1001 rounded out).
        assert_eq!(l1.inset, TileRect { s0: 7, t0: 15, s1: 9, t1: 16 });
        assert!(l.sparse_of(&inset, &l.levels[2]).is_none());
    }

    #[test]
    fn the_border_is_clamped_to_the_level() {
        let l = inset_layout(1024, 256, 128);
        let inset = Inset { s0: 0, t0: 0, s1: 1, t1: 1, level: 1 };
        let l0 = l.sparse_of(&inset, &l.levels[0]).unwrap();
        assert_eq!(l0.written, TileRect { s0: 0, t0: 0, s1: 3, t1: 3 });
    }

    #[test]
    fn an_empty_region_or_a_sparse_pyramid_level_is_refused() {
        let l = inset_layout(1024, 256, 128);
        let empty = Inset { s0: 10, t0: 0, s1: 10, t1: 5, level: 1 };
        assert!(l.check_inset(&empty).unwrap_err().to_string().contains("non-empty"));
        // 1024 with clip 256: image caches 1024 and 512 only.
        let deep = Inset { s0: 0, t0: 0, s1: 8, t1: 8, level: 3 };
        assert!(l.check_inset(&deep).unwrap_err().to_string().contains("from 1 to 2"));
        let zero = Inset { level: 0, ..deep };
        assert!(l.check_inset(&zero).is_err());
    }
}
