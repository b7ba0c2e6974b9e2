//! Reading a texture tile's TIFF tiles: several in one request where they lie back to back
//! (a row's span, the tiles announced to be read next), and a region of a level filled from
//! every TIFF tile it touches.

use super::decode::{keep, CHUNK};
use super::level::{Compression, IfdLevel, Level};
use super::structure::Span;
use super::{CogSource, AHEAD_WINDOW, MAX_SPAN_BYTES};
use crate::source::ahead::{Piece, Plan};
use crate::source::range::{RangeError, Shared};
use crate::source::{SourceError, TileId};
use std::sync::Arc;

impl CogSource {
    /// The most bytes a merged request reads ahead (the range reader's merge cap, at most
    /// [`MAX_SPAN_BYTES`]); 0 for a local file, which reads nothing ahead.
    pub(super) fn ahead_cap(&self) -> u64 {
        self.bytes.merge_cap().min(MAX_SPAN_BYTES)
    }

    /// The bytes a read of TIFF tile `index` of `lv` fetches (framing included), when they are
    /// to be fetched: `None` for a sparse tile, one in the first bytes, or one whose place cannot
    /// be had.
    pub(super) fn stored_range(&self, lv: &IfdLevel, index: u64, need: u64, tile: TileId) -> Option<(u64, u64)> {
        let (offset, count) = self.tile_place(lv, index, tile).ok()?;
        if offset == 0 || count == 0 {
            return None;
        }
        let (from, len) = match lv.compression {
            Compression::None if count < need => return None,
            Compression::None if count != need => (offset, need),
            _ => {
                let (lead, trail) = self.framing(offset, count);
                (offset - lead, lead.saturating_add(count).saturating_add(trail))
            }
        };
        // Wholly in the first bytes (read at open): nothing to fetch. One that starts there is
        // merged; its request fetches only the bytes past them ([`CogSource::read_ahead`]).
        if (Span { start: 0, bytes: &self.prefix }).get(from, len).is_some() {
            return None;
        }
        Some((from, len))
    }

    /// The bytes of a request that holds TIFF tile `index` of `lv` (texture tile `tile`) and the
    /// announced tiles stored next to it (docs/COG.md, "The request budget of a remote COG"),
    /// from the byte they start at; `None` when the tile is to be read on its own.
    pub(super) fn read_ahead(
        &self,
        lv: &IfdLevel,
        tile: TileId,
        index: u64,
        need: u64,
    ) -> Result<Option<(u64, Shared)>, SourceError> {
        let cap = self.ahead_cap();
        let (rows, across) = (lv.rows(), lv.across);
        let tiles = rows * across;
        if cap == 0 || index >= tiles {
            return Ok(None);
        }
        let id = |j: u64| TileId { level: tile.level, s: j % across, t: rows - 1 - j / across };
        let near: Vec<TileId> =
            (index.saturating_sub(AHEAD_WINDOW)..=(index + AHEAD_WINDOW).min(tiles - 1)).map(id).collect();
        let place = |k: &TileId| {
            let j = (rows - 1 - k.t) * across + k.s;
            self.stored_range(lv, j, need, *k).map(|(start, len)| Piece { key: *k, start, len })
        };
        match self.ahead.plan(tile, &near, place, cap) {
            Plan::Alone => Ok(None),
            Plan::Take { start, bytes } => Ok(bytes.map(|b| (start, b))),
            Plan::Send { start, end, merged, ticket } => {
                let ranges = merged.len() as u64 + 1;
                let mut started = Ok(());
                // This tile's own bytes, once whole (`None`: read it on its own).
                // The bytes the open read already are handed over first, not fetched again.
                let held = (self.prefix.len() as u64).saturating_sub(start).min(end - start);
                let own = ticket.detach(|feed| {
                    if held > 0 {
                        feed.push(&self.prefix[start as usize..(start + held) as usize]);
                    }
                    if held < end - start {
                        started = self.bytes.stream(start + held, end - start - held, ranges, Arc::new(feed));
                    }
                });
                match started {
                    // A tile whose place runs past the end: each tile then says what is wrong
                    // with it.
                    Err(RangeError::Eof { .. }) => Ok(None),
                    Err(e) => Err(e.for_tile(tile, &self.path, start, end - start)),
                    Ok(()) => Ok(own),
                }
            }
        }
    }

    /// Whether texture tiles of `level` are read one TIFF tile each (and so may be read ahead).
    pub(super) fn one_tiff_tile_each(&self, level: u32) -> Option<&IfdLevel> {
        let d = self.desc.level(level);
        match self.levels.get(level as usize)? {
            Level::Ifd(lv) if lv.tile == d.tile && lv.size[1] % lv.tile[1] == 0 => Some(lv),
            _ => None,
        }
    }

    /// The stored bytes of TIFF tiles `cx0..=cx1` of tile row `cy` in one read, when they lie
    /// back to back (GDAL writes a row's tiles so) and are not all in the first bytes: a remote
    /// object's one ranged GET instead of one a tile. `None` when they do not, or locally.
    pub(super) fn row_span(
        &self,
        lv: &IfdLevel,
        cy: u64,
        [cx0, cx1]: [u64; 2],
        tile: TileId,
    ) -> Result<Option<(u64, Shared)>, SourceError> {
        if !self.bytes.is_remote() || cx1 <= cx0 {
            return Ok(None);
        }
        let mut start = None;
        let mut end = 0u64;
        for cx in cx0..=cx1 {
            let (offset, count) = self.tile_place(lv, cy * lv.across + cx, tile)?;
            if offset == 0 || count == 0 {
                return Ok(None);
            }
            let (lead, trail) = self.framing(offset, count);
            let from = offset - lead;
            match start {
                None => start = Some(from),
                Some(_) if from != end => return Ok(None),
                Some(_) => {}
            }
            end = offset.saturating_add(count).saturating_add(trail);
        }
        let Some(start) = start else { return Ok(None) };
        if end - start > MAX_SPAN_BYTES || (Span { start: 0, bytes: &self.prefix }).get(start, end - start).is_some() {
            return Ok(None);
        }
        // A span that starts in the first bytes (read at open) fetches only the rest.
        let held = (self.prefix.len() as u64).saturating_sub(start);
        if held > 0 {
            let mut b = self.prefix[start as usize..(start + held) as usize].to_vec();
            let rest = self.bytes.read_bytes(start + held, end - start - held);
            let rest = rest.map_err(|e| e.for_tile(tile, &self.path, start + held, end - start - held))?;
            b.extend_from_slice(&rest);
            return Ok(Some((start, Arc::new(b))));
        }
        match self.bytes.read_bytes(start, end - start) {
            Ok(b) => Ok(Some((start, b))),
            Err(e) => Err(e.for_tile(tile, &self.path, start, end - start)),
        }
    }

    /// Fills the `w x h` texels from `(s0, t0)` of level `lv` into `out` (rows in increasing t,
    /// `stride` texels apart), from every TIFF tile they touch; texels of `out` outside the region
    /// are left alone. A sparse TIFF tile is [`SourceError::Missing`], or zeros with
    /// `sparse_zero`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn fill_region(
        &self,
        lv: &IfdLevel,
        tile: TileId,
        [s0, t0]: [u64; 2],
        [w, h]: [u64; 2],
        out: &mut [u8],
        stride: usize,
        sparse_zero: bool,
    ) -> Result<(), SourceError> {
        let bpt = self.desc.bytes_per_texel();
        let [tw, th] = lv.tile;
        let height = lv.size[1];
        // Image rows y_lo..=y_hi (top-down) hold texture rows t0 + h - 1 down to t0.
        let (y_lo, y_hi) = (height - (t0 + h), height - 1 - t0);
        let chunk_bytes = (tw * th) as usize * bpt;
        let mut chunk = CHUNK.with(|cell| std::mem::take(&mut *cell.borrow_mut()));
        chunk.resize(chunk_bytes, 0);
        let result = (|| {
            for cy in y_lo / th..=y_hi / th {
                let (cx0, cx1) = (s0 / tw, (s0 + w - 1) / tw);
                let row = self.row_span(lv, cy, [cx0, cx1], tile)?;
                let span = row.as_ref().map(|(start, b)| Span { start: *start, bytes: b });
                for cx in cx0..=cx1 {
                    match self.decode_texels(lv, cy * lv.across + cx, tile, &mut chunk, span.as_ref()) {
                        Ok(()) => {}
                        Err(SourceError::Missing { .. }) if sparse_zero => self.blank(&mut chunk),
                        Err(e) => return Err(e),
                    }
                    let (xa, xb) = (s0.max(cx * tw), (s0 + w).min((cx + 1) * tw));
                    let len = (xb - xa) as usize * bpt;
                    for y in y_lo.max(cy * th)..=y_hi.min((cy + 1) * th - 1) {
                        let r = (height - 1 - y - t0) as usize;
                        let from = (((y - cy * th) * tw + xa - cx * tw) as usize) * bpt;
                        let to = (r * stride + (xa - s0) as usize) * bpt;
                        out[to..to + len].copy_from_slice(&chunk[from..from + len]);
                    }
                }
            }
            Ok(())
        })();
        keep(&CHUNK, chunk);
        result
    }
}
