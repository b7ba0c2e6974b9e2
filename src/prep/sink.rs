//! Writes one level's rows into its tile files, a band of rows at a time.
//!
//! A band never spans two rows of tiles: image-cache levels are written one row of tiles at a
//! time (so a one-tile file is written whole, once); a pyramid level, a single tile, is written in
//! bands of at most [`Limits::pyramid_band_bytes`](super::Limits). Each band is cut into its
//! tiles, and each tile's part is written at its byte offset in its file (docs/PERFORMER-REFERENCE.md §1.12), with
//! the file's header in front when `header_offset` is set. Compressed image-cache tiles are
//! whole tiles, each compressed into its own file, the tiles of a band in parallel.

use super::error::PrepError;
use super::inset::TileRole;
use super::layout::{Compression, Layout, Level, LevelKind};
use rayon::prelude::*;
use std::fs::OpenOptions;
use std::io::{Seek, SeekFrom, Write};
use std::path::Path;

/// Buffers and writes the rows of one level.
pub(crate) struct LevelWriter<'a> {
    root: &'a Path,
    layout: &'a Layout,
    level: Level,
    row_bytes: usize,
    band_rows: usize,
    band: Vec<u8>,
    band_t0: u64,
    filled: usize,
    /// Total bytes of the prepared texture (for a full-disk message).
    total_bytes: u64,
}

impl<'a> LevelWriter<'a> {
    /// A writer for `level` of `layout`, writing under `root`.
    pub fn new(root: &'a Path, layout: &'a Layout, level: &Level, pyramid_band_bytes: u64) -> LevelWriter<'a> {
        let row_bytes = (level.width * layout.bpt()) as usize;
        let band_rows = match level.kind {
            LevelKind::ImageCache => level.tile_h as usize,
            // A block-compressed pyramid level is encoded whole (at most the clip size a side).
            LevelKind::Pyramid if layout.blocks.is_some() => level.height as usize,
            LevelKind::Pyramid => (pyramid_band_bytes as usize / row_bytes).clamp(1, level.height as usize),
        };
        LevelWriter {
            root,
            layout,
            level: level.clone(),
            row_bytes,
            band_rows,
            band: Vec::new(),
            band_t0: 0,
            filled: 0,
            total_bytes: layout.total_texels() * layout.bpt(),
        }
    }

    /// Rows per band.
    pub(crate) fn band_rows(&self) -> usize {
        self.band_rows
    }

    /// Bytes of one row.
    pub(crate) fn row_bytes(&self) -> usize {
        self.row_bytes
    }

    /// Appends rows (a whole number of them); writes each band as it fills. Returns the texels
    /// written to disk by this call.
    pub fn push(&mut self, rows: &[u8]) -> Result<u64, PrepError> {
        debug_assert_eq!(rows.len() % self.row_bytes, 0);
        let mut written = 0;
        if self.band.capacity() == 0 {
            // Allocated on first use, so writers of levels written otherwise hold nothing.
            self.band.reserve_exact(self.band_rows * self.row_bytes);
        }
        for row in rows.chunks_exact(self.row_bytes) {
            self.band.extend_from_slice(row);
            self.filled += 1;
            if self.filled == self.band_rows {
                written += self.flush()?;
            }
        }
        Ok(written)
    }

    /// Writes any rows still buffered. Returns the texels written.
    pub fn finish(&mut self) -> Result<u64, PrepError> {
        let written = self.flush()?;
        self.band = Vec::new();
        Ok(written)
    }

    fn flush(&mut self) -> Result<u64, PrepError> {
        let rows = self.filled;
        if rows == 0 {
            return Ok(0);
        }
        let bpt = self.layout.bpt() as usize;
        let level = &self.level;
        let tile_t = self.band_t0 / level.tile_h;
        let row_in_tile = self.band_t0 % level.tile_h;
        let tw = level.tile_w as usize;
        let tiles: Vec<u64> =
            (0..level.tiles_s()).filter(|&ts| self.layout.tile_role(level, ts, tile_t) == TileRole::Source).collect();
        let part_of = |tile_s: u64, part: &mut Vec<u8>| {
            part.clear();
            let x0 = tile_s as usize * tw * bpt;
            for r in 0..rows {
                let start = r * self.row_bytes + x0;
                part.extend_from_slice(&self.band[start..start + tw * bpt]);
            }
        };
        let offset = row_in_tile * tw as u64 * bpt as u64;
        if self.layout.compressed(level) {
            // Whole tiles (an image-cache band is one row of tiles), compressed in parallel.
            tiles.par_iter().try_for_each_init(Vec::new, |part, &tile_s| {
                part_of(tile_s, part);
                write_tile_part(self.root, self.layout, level, tile_s, tile_t, offset, part, self.total_bytes)
            })?;
        } else {
            let mut part = Vec::with_capacity(rows * tw * bpt);
            for tile_s in tiles {
                part_of(tile_s, &mut part);
                write_tile_part(self.root, self.layout, level, tile_s, tile_t, offset, &part, self.total_bytes)?;
            }
        }
        self.band_t0 += rows as u64;
        self.filled = 0;
        self.band.clear();
        Ok(rows as u64 * level.width)
    }
}

/// Writes `data` at byte `offset` of tile (s, t) of `level` (offset 0 is the tile's first texel),
/// with the file's header in front when the layout has one. `total_bytes` is the size of the
/// whole output, for a full-disk message.
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_tile_part(
    root: &Path,
    layout: &Layout,
    level: &Level,
    s: u64,
    t: u64,
    offset: u64,
    data: &[u8],
    total_bytes: u64,
) -> Result<(), PrepError> {
    let loc = layout.tile(level, s, t);
    let path = root.join(&loc.path);
    let encoded;
    let data = match layout.blocks {
        Some(_) => {
            assert_eq!(offset, 0, "block-compressed tiles are written whole");
            encoded = on_disk(layout, level, data);
            &encoded[..]
        }
        None => data,
    };
    if let (true, Some(Compression::Zstd(z))) = (layout.compressed(level), layout.spec.compression) {
        assert!(offset == 0 && data.len() as u64 == loc.length, "compressed tiles are written whole");
        let packed = zstd::bulk::compress(data, z).map_err(|e| PrepError::write(&path, e, total_bytes))?;
        return std::fs::write(&path, packed).map_err(|e| PrepError::write(&path, e, total_bytes));
    }
    write_at(&path, &header(layout, level, s, t), loc.offset + offset, data)
        .map_err(|e| PrepError::write(&path, e, total_bytes))
}

/// A whole tile of `level` as it is stored: `texels` (tile width x height texels of the layout's
/// format) as they are, or encoded into blocks when the layout's tiles are block-compressed.
pub(crate) fn on_disk(layout: &Layout, level: &Level, texels: &[u8]) -> Vec<u8> {
    let Some((bc, quality)) = layout.blocks else {
        return texels.to_vec();
    };
    let (w, h) = (level.tile_w, level.tile_h);
    assert_eq!(texels.len() as u64, w * h * layout.bpt(), "a whole tile of level {}", level.index);
    let from = layout.spec.format;
    let mut input = Vec::new();
    crate::source::bc::encoder_input(bc, from, texels, w, h, &mut input).expect("8-bit texels, checked by with_blocks");
    let alpha = from.components.count().is_multiple_of(2);
    let mut out = vec![0u8; layout.tile_bytes(level) as usize];
    crate::source::bc::encode_padded(bc, quality, alpha, &input, w, h, &mut out);
    out
}

/// The header of the file holding tile (s, t): a line of text describing the file, padded
/// with zeros (or cut) to `header_offset` bytes. Empty without a header.
fn header(layout: &Layout, level: &Level, s: u64, t: u64) -> Vec<u8> {
    let h = layout.spec.header_bytes as usize;
    if h == 0 || level.kind == LevelKind::Pyramid {
        return Vec::new();
    }
    let (ns, nt) = layout.spec.tiles_in_file;
    let text = format!(
        "clipmap tiles: level {} file {} {} holds {}x{} tiles of {}x{} {} texels, s fastest, after {} header bytes\n",
        level.index,
        s / ns,
        t / nt,
        ns,
        nt,
        level.tile_w,
        level.tile_h,
        layout.spec.format,
        h
    );
    let mut out = text.into_bytes();
    out.resize(h, 0);
    out
}

fn write_at(path: &Path, header: &[u8], offset: u64, data: &[u8]) -> std::io::Result<()> {
    let mut f = OpenOptions::new().write(true).create(true).truncate(false).open(path)?;
    if !header.is_empty() {
        f.write_all(header)?;
    }
    f.seek(SeekFrom::Start(offset))?;
    f.write_all(data)?;
    Ok(())
}
