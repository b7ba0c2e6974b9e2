//! The tile index: the TileOffsets and TileByteCounts arrays ([`Array`]), never read whole at
//! open. An entry in the first bytes is taken from there; a local file reads a tile's two entries
//! with positioned reads; a remote object reads both arrays at once when they fit in
//! [`MAX_INDEX_READ`], else chunks of [`INDEX_CHUNK_BYTES`], kept once read, and takes a tile's
//! byte count from the offsets where GDAL's block leader confirms it.

use super::level::{Array, Compression, IfdLevel};
use super::structure::Span;
use super::structure::{unsigned_size, Image, Layout};
use super::{CogSource, INDEX_CHUNK_BYTES, MAX_INDEX_READ};
use crate::source::range::{RangeError, Shared};
use crate::source::{SourceError, TileId};
use std::sync::Arc;

/// The tile index array of tag `tag`, without reading it.
pub(super) fn array(
    layout: Layout,
    image: &Image,
    tag: u16,
    name: &str,
    count: u64,
) -> Result<Array, (String, String)> {
    let at = format!("IFD {} tag {name}", image.ifd);
    let Some(e) = image.entries.iter().find(|e| e.tag == tag) else {
        return Err((at, "missing, required in a tiled image".into()));
    };
    let size = match e.ty {
        3 | 4 | 16 => unsigned_size(e.ty).unwrap_or(8),
        ty => return Err((at, format!("type {ty} found, expected SHORT (3), LONG (4) or LONG8 (16)"))),
    };
    if e.count != count {
        return Err((at, format!("{} values, expected {count} (one per tile)", e.count)));
    }
    let inline = (count * size <= layout.field() as u64).then_some(e.field);
    Ok(Array { ty: e.ty, size, count, inline, at: layout.offset(&e.field) })
}

impl CogSource {
    /// One value of a tile index.
    pub(super) fn index_value(&self, a: &Array, i: u64, tile: TileId) -> Result<u64, SourceError> {
        if i >= a.count {
            let problem = format!("the tile index has {} entries, tile {i} asked for", a.count);
            return Err(SourceError::Chunk { tile, path: self.path.clone(), problem });
        }
        if let Some(b) = a.inline {
            let at = (i * a.size) as usize;
            return Ok(self.layout.value(a.ty, &b[at..]));
        }
        let at = a.at.saturating_add(i * a.size);
        if let Some(b) = (Span { start: 0, bytes: &self.prefix }).get(at, a.size) {
            return Ok(self.layout.value(a.ty, b));
        }
        let past_end = |len: u64| SourceError::Chunk {
            tile,
            path: self.path.clone(),
            problem: format!("its tile index entry at byte {at} lies past the end of the file ({len} bytes)"),
        };
        if self.chunked {
            let (chunk, from) = self.index_chunk(a, i, tile)?;
            return Ok(self.layout.value(a.ty, &chunk[from..from + a.size as usize]));
        }
        let mut b = [0u8; 8];
        match self.bytes.read_at(at, &mut b[..a.size as usize]) {
            Ok(()) => Ok(self.layout.value(a.ty, &b)),
            Err(RangeError::Eof { size }) => Err(past_end(size)),
            Err(e) => Err(e.for_tile(tile, &self.path, at, a.size)),
        }
    }

    /// The chunk of array `a` that holds entry `i`, read once ([`INDEX_CHUNK_BYTES`] of
    /// entries, the array's last chunk shorter), and where entry `i` starts in it.
    pub(super) fn index_chunk(&self, a: &Array, i: u64, tile: TileId) -> Result<(Shared, usize), SourceError> {
        let per = (INDEX_CHUNK_BYTES / a.size).max(1);
        let j = i / per;
        let from = ((i - j * per) * a.size) as usize;
        let key = (a.at, j);
        if let Some(c) = self.index.lock().unwrap_or_else(|e| e.into_inner()).get(&key) {
            return Ok((Arc::clone(c), from));
        }
        let start = a.at.saturating_add(j * per * a.size);
        let len = ((a.count - j * per).min(per)) * a.size;
        let chunk = match self.bytes.read_bytes(start, len) {
            Ok(c) => c,
            Err(RangeError::Eof { size }) => {
                return Err(SourceError::Chunk {
                    tile,
                    path: self.path.clone(),
                    problem: format!(
                        "its tile index entries at bytes {start}..{} lie past the end of the file ({size} bytes)",
                        start.saturating_add(len)
                    ),
                })
            }
            Err(e) => return Err(e.for_tile(tile, &self.path, start, len)),
        };
        self.index.lock().unwrap_or_else(|e| e.into_inner()).insert(key, Arc::clone(&chunk));
        Ok((chunk, from))
    }

    /// Reads the chunks of both index arrays that hold entry `i` with one read, when neither is
    /// read yet and both lie within [`MAX_INDEX_READ`] bytes (GDAL writes an image's
    /// TileByteCounts right after its TileOffsets): a tile's index then costs one request, and
    /// every chunk of either array inside that read is kept.
    pub(super) fn index_pair(&self, lv: &IfdLevel, i: u64, tile: TileId) -> Result<(), SourceError> {
        let (a, b) = (&lv.offsets, &lv.counts);
        if a.inline.is_some() || b.inline.is_some() || i >= a.count || i >= b.count {
            return Ok(());
        }
        let per = |x: &Array| (INDEX_CHUNK_BYTES / x.size).max(1);
        // Chunk j of array x: its key, first byte and length.
        let chunk = |x: &Array, j: u64| {
            let start = x.at.saturating_add(j * per(x) * x.size);
            ((x.at, j), start, ((x.count - j * per(x)).min(per(x))) * x.size)
        };
        let ((ka, sa, la), (kb, sb, lb)) = (chunk(a, i / per(a)), chunk(b, i / per(b)));
        let prefix = Span { start: 0, bytes: &self.prefix };
        if prefix.get(sa, la).is_some() || prefix.get(sb, lb).is_some() {
            return Ok(());
        }
        // Both arrays whole when they fit in one read, else the two chunks, else nothing here.
        let end = |x: &Array| x.at.saturating_add(x.count.saturating_mul(x.size));
        let whole = (a.at.min(b.at), end(a).max(end(b)));
        let pair = (sa.min(sb), sa.saturating_add(la).max(sb.saturating_add(lb)));
        let (lo, hi) = if whole.1 - whole.0 <= MAX_INDEX_READ { whole } else { pair };
        if hi - lo > MAX_INDEX_READ {
            return Ok(());
        }
        {
            let cache = self.index.lock().unwrap_or_else(|e| e.into_inner());
            if cache.contains_key(&ka) || cache.contains_key(&kb) {
                return Ok(());
            }
        }
        let both = match self.bytes.read_bytes(lo, hi - lo) {
            Ok(b) => b,
            // Each chunk on its own then says what is wrong with it.
            Err(RangeError::Eof { .. }) => return Ok(()),
            Err(e) => return Err(e.for_tile(tile, &self.path, lo, hi - lo)),
        };
        let mut cache = self.index.lock().unwrap_or_else(|e| e.into_inner());
        for x in [a, b] {
            for j in 0..x.count.div_ceil(per(x)) {
                let (key, start, len) = chunk(x, j);
                if start >= lo && start.saturating_add(len) <= hi {
                    let from = (start - lo) as usize;
                    cache.entry(key).or_insert_with(|| Arc::new(both[from..from + len as usize].to_vec()));
                }
            }
        }
        Ok(())
    }

    /// Where TIFF tile `index` of `lv` is stored: its offset and byte count.
    pub(super) fn tile_place(&self, lv: &IfdLevel, index: u64, tile: TileId) -> Result<(u64, u64), SourceError> {
        if self.chunked {
            self.index_pair(lv, index, tile)?;
        }
        Ok((self.index_value(&lv.offsets, index, tile)?, self.index_value(&lv.counts, index, tile)?))
    }

    /// A tile's place without its TileByteCounts entry, when reading that entry would cost a
    /// request of its own (a remote index too large to read whole, the entry's chunk not read
    /// yet) and GDAL's block leader will confirm it: an uncompressed tile holds one tile's
    /// bytes, a compressed one those up to the next tile's leader (GDAL writes a level's tiles
    /// back to back, each with its leader and trailer). [`CogSource::decode`] reads the entry
    /// after all when the leader disagrees.
    pub(super) fn guessed_place(&self, lv: &IfdLevel, index: u64, need: u64, tile: TileId) -> Option<(u64, u64)> {
        let (a, c) = (&lv.offsets, &lv.counts);
        if !self.chunked || !self.ghost.leader || c.inline.is_some() || a.inline.is_some() {
            return None;
        }
        if (Span { start: 0, bytes: &self.prefix }).get(c.at.saturating_add(index * c.size), c.size).is_some() {
            return None;
        }
        self.index_pair(lv, index, tile).ok()?;
        let per = |x: &Array| (INDEX_CHUNK_BYTES / x.size).max(1);
        if self.index.lock().unwrap_or_else(|e| e.into_inner()).contains_key(&(c.at, index / per(c))) {
            return None;
        }
        let offset = self.index_value(a, index, tile).ok()?;
        if offset < 4 {
            return None;
        }
        if lv.compression == Compression::None {
            return Some((offset, need));
        }
        // The next entry, when it is in the same chunk of TileOffsets (no other request).
        if index + 1 >= a.count || (index + 1) / per(a) != index / per(a) {
            return None;
        }
        let next = self.index_value(a, index + 1, tile).ok()?;
        let trail = if self.ghost.trailer { 4 } else { 0 };
        let count = next.checked_sub(offset)?.checked_sub(4 + trail)?;
        (count >= 4).then_some((offset, count))
    }
}

#[cfg(test)]
mod tests {
    use super::super::level::Level;
    use super::super::PREFIX_BYTES;
    use super::*;
    use crate::source::TileSource;
    use std::path::Path;

    /// A classic little-endian TIFF of `w x h` grey texels `(3x + 5y) & 255` in uncompressed
    /// `t x t` tiles, its tile index (LONG arrays) placed after the tiles, past the first
    /// [`PREFIX_BYTES`].
    fn synthetic_tiff(w: u32, h: u32, t: u32) -> Vec<u8> {
        let (across, down) = (w.div_ceil(t), h.div_ceil(t));
        let tiles = across * down;
        let mut f = b"II*\0".to_vec();
        f.extend(8u32.to_le_bytes());
        let entries: [(u16, u16, u32, u32); 9] = [
            (256, 4, 1, w),
            (257, 4, 1, h),
            (258, 3, 1, 8),
            (259, 3, 1, 1),
            (262, 3, 1, 1),
            (322, 4, 1, t),
            (323, 4, 1, t),
            (324, 4, tiles, 0),
            (325, 4, tiles, 0),
        ];
        let data_at = 4096u32;
        let tile_len = t * t;
        let arrays_at = data_at + tiles * tile_len;
        assert!(arrays_at as u64 > PREFIX_BYTES);
        f.extend((entries.len() as u16).to_le_bytes());
        for (tag, ty, count, value) in entries {
            let value = match tag {
                324 => arrays_at,
                325 => arrays_at + 4 * tiles,
                _ => value,
            };
            f.extend(tag.to_le_bytes());
            f.extend(ty.to_le_bytes());
            f.extend(count.to_le_bytes());
            f.extend(value.to_le_bytes());
        }
        f.extend(0u32.to_le_bytes());
        f.resize(data_at as usize, 0);
        for i in 0..tiles {
            let (cx, cy) = (i % across, i / across);
            for r in 0..t {
                for c in 0..t {
                    let (x, y) = (cx * t + c, cy * t + r);
                    f.push(if x < w && y < h { ((3 * x + 5 * y) & 255) as u8 } else { 0 });
                }
            }
        }
        for i in 0..tiles {
            f.extend((data_at + i * tile_len).to_le_bytes());
        }
        for _ in 0..tiles {
            f.extend(tile_len.to_le_bytes());
        }
        f
    }

    #[test]
    fn the_tile_index_read_in_chunks_gives_every_entry_the_eager_reader_gives() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big_index.tif");
        // 80 x 70 tiles of 8 x 8: 5600 entries a array, 22 KiB of LONGs, past the first 64 KiB.
        std::fs::write(&path, synthetic_tiff(640, 560, 8)).unwrap();
        let eager = CogSource::open(&path, 64).unwrap();
        let lazy = open_chunked(&path, 64);
        let Level::Ifd(lv) = &eager.levels[0] else { panic!("level 0 is an image") };
        for i in (0..lv.offsets.count).rev() {
            let id = TileId::new(0, 0, 0);
            assert_eq!(lazy.tile_place(lv, i, id).unwrap(), eager.tile_place(lv, i, id).unwrap(), "entry {i}");
        }
        let per = INDEX_CHUNK_BYTES / 4;
        let chunks = lv.offsets.count.div_ceil(per) as usize;
        assert_eq!(lazy.index.lock().unwrap().len(), 2 * chunks, "each chunk of both arrays read once");
        // The two arrays lie back to back (22400 bytes each, less than MAX_INDEX_READ together):
        // the first entry asked for reads them whole, every chunk kept.
        let lazy = open_chunked(&path, 64);
        lazy.tile_place(lv, 4000, TileId::new(0, 0, 0)).unwrap();
        let cache = lazy.index.lock().unwrap();
        assert_eq!(cache.len(), 2 * chunks);
        assert_eq!(cache[&(lv.counts.at, 5)].len(), (5600 - 5 * 1024) * 4, "the last chunk is short");
        drop(cache);
        // Every texel through the chunked index is the image's, bottom-up.
        let desc = lazy.desc().clone();
        let l0 = *desc.level(0);
        let mut buf = vec![0u8; desc.tile_bytes(0)];
        for tt in 0..l0.tiles()[1] {
            for ts in 0..l0.tiles()[0] {
                lazy.read_tile(TileId::new(0, ts, tt), &mut buf).unwrap();
                for (j, &v) in buf.iter().enumerate() {
                    let (s, t) = (ts * l0.tile[0] + j as u64 % l0.tile[0], tt * l0.tile[1] + j as u64 / l0.tile[0]);
                    let y = 559 - t;
                    assert_eq!(v, ((3 * s + 5 * y) & 255) as u8, "texel ({s}, {t})");
                }
            }
        }
        // An index that runs past the end of the file is refused at open, naming where (not
        // a texel, and not an error a tile, each read in vain).
        let mut cut = std::fs::read(&path).unwrap();
        cut.truncate(cut.len() - 100);
        std::fs::write(&path, &cut).unwrap();
        let e = CogSource::open(&path, 4096).unwrap_err().to_string();
        assert!(e.contains("IFD 0 tag TileByteCounts (325): its 5600 values (22400 bytes"), "{e}");
        assert!(e.contains("run past the end of the file"), "{e}");
    }

    /// `path` opened as a remote object is (structure from the first bytes, the index read in
    /// chunks, nothing built at open), over the local file.
    fn open_chunked(path: &Path, clip: u64) -> CogSource {
        let (bytes, prefix) = crate::source::range::open_local(path, PREFIX_BYTES).unwrap();
        let mut src = CogSource::from_range(path.to_path_buf(), bytes, prefix, clip, true).unwrap();
        src.chunked = true;
        src
    }
}
