//! The levels a file lacks: built from the last usable image by halving, once (at open for a
//! local file, when first read for a remote object).

use super::level::Level;
use super::CogSource;
use crate::source::{SourceError, TileId};
use std::sync::Arc;

/// Most bytes of texels of the image the built levels are made from that are kept after
/// building, to serve that image's own tiles without reading them again.
const KEPT_BASE_BYTES: usize = 16 << 20;

/// Most TIFF tiles of that image for a read of one of them to build the levels first (and so
/// read each of its tiles once); a larger image is read whole only when a built level is asked
/// for.
const KEPT_BASE_TILES: u64 = 4;

/// The levels built past the last usable image, and that image's texels when kept.
pub(super) struct Built {
    /// Each built level's texels (rows in increasing t), finest first.
    pub(super) levels: Vec<Vec<u8>>,
    /// The texels of the image they were built from (level `levels.len()` levels finer than the
    /// coarsest), when it has no sparse tile and at most [`KEPT_BASE_BYTES`]: its tiles are then
    /// served from here, each of its TIFF tiles read once.
    pub(super) base: Option<Vec<u8>>,
}

impl CogSource {
    /// The levels past the last usable image, built from it the first time they are asked for
    /// (by `tile`, or at open when `None`); a failure is not kept, the next read tries again.
    pub(super) fn built_levels(&self, tile: Option<TileId>) -> Result<Arc<Built>, SourceError> {
        let mut slot = self.built.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(b) = &*slot {
            return Ok(Arc::clone(b));
        }
        let n = self.desc.level_count();
        let used = self.levels.iter().filter(|l| matches!(l, Level::Ifd(_))).count();
        let mut out = Built { levels: Vec::new(), base: None };
        if used < n {
            let base = used as u32 - 1;
            let bpt = self.desc.bytes_per_texel();
            let Some(Level::Ifd(lv)) = self.levels.get(used - 1) else { return Ok(Arc::new(out)) };
            let mut size = lv.size;
            let mut texels = vec![0u8; (size[0] * size[1]) as usize * bpt];
            let whole = tile.unwrap_or(TileId::new(base, 0, 0));
            self.fill_region(lv, whole, [0, 0], size, &mut texels, size[0] as usize, true)?;
            for _ in used..n {
                let (next, next_size) = self.halve(out.levels.last().unwrap_or(&texels), size);
                out.levels.push(next);
                size = next_size;
            }
            // Kept only when every TIFF tile is there: a sparse one was read as zeros above, but
            // is Missing when its own tile is read.
            let whole_tiles = (0..lv.rows() * lv.across)
                .all(|i| self.tile_place(lv, i, whole).is_ok_and(|(offset, count)| offset != 0 && count != 0));
            if texels.len() <= KEPT_BASE_BYTES && whole_tiles {
                out.base = Some(texels);
            }
        }
        let b = Arc::new(out);
        *slot = Some(Arc::clone(&b));
        Ok(b)
    }

    /// The texels of level `level` when it is the image the built levels are made from and they
    /// were kept ([`Built::base`]), building them now if they were not yet.
    pub(super) fn kept_base(&self, level: u32, tile: TileId) -> Result<Option<Arc<Built>>, SourceError> {
        let used = self.levels.iter().filter(|l| matches!(l, Level::Ifd(_))).count();
        if used == 0 || used >= self.desc.level_count() || level as usize != used - 1 {
            return Ok(None);
        }
        // Built now only when that image is a few tiles (they are read for the built levels
        // anyway); a larger one is not read whole for one of its tiles.
        let built = match &self.levels[used - 1] {
            Level::Ifd(lv) if lv.rows() * lv.across <= KEPT_BASE_TILES => self.built_levels(Some(tile))?,
            _ => match self.built.lock().unwrap_or_else(|e| e.into_inner()).as_ref() {
                Some(b) => Arc::clone(b),
                None => return Ok(None),
            },
        };
        Ok(built.base.is_some().then_some(built))
    }

    /// Copies texture tile `tile` (`w x h` texels from `(s0, t0)` of a level `lw` texels wide,
    /// `tw x th` a tile) out of a level's whole `texels` into `out`, zeros past the level's edge.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn copy_tile(
        texels: &[u8],
        lw: usize,
        bpt: usize,
        [s0, t0]: [u64; 2],
        [w, h]: [u64; 2],
        [tw, th]: [u64; 2],
        out: &mut [u8],
    ) {
        if w < tw || h < th {
            out.fill(0);
        }
        let len = w as usize * bpt;
        for r in 0..h as usize {
            let from = ((t0 as usize + r) * lw + s0 as usize) * bpt;
            out[r * tw as usize * bpt..][..len].copy_from_slice(&texels[from..from + len]);
        }
    }

    /// The next coarser level of `src` (`size` texels, rows in increasing t): heights by the
    /// `mean` rule with nodata left out (docs/ELEVATION.md), colours by `clipprep`'s 2 x 2 box
    /// filter on each sample.
    pub(super) fn halve(&self, src: &[u8], size: [u64; 2]) -> (Vec<u8>, [u64; 2]) {
        let Some(plan) = &self.heights else {
            let sample = if self.desc.format().ctype == crate::texel::ComponentType::U16 { 2 } else { 1 };
            return halve(src, size, self.desc.bytes_per_texel(), sample);
        };
        let f = plan.format;
        let n = f.bytes_per_texel();
        let stored: Vec<f64> = src.chunks_exact(n).map(|b| f.read(b)).collect();
        let [w, h] = [size[0] as usize, size[1] as usize];
        let next = f.reduce_level(plan.levels, &stored, w, h).unwrap_or_default();
        let mut out = vec![0u8; next.len() * n];
        for (v, o) in next.iter().zip(out.chunks_exact_mut(n)) {
            f.write(*v, o);
        }
        (out, [(w / 2).max(1) as u64, (h / 2).max(1) as u64])
    }

    /// Fills `texels` as GDAL reads a sparse tile: nodata heights, or zeros.
    pub(super) fn blank(&self, texels: &mut [u8]) {
        match self.heights.and_then(|p| p.format.nodata().map(|v| (p.format, v))) {
            Some((f, v)) => {
                for t in texels.chunks_exact_mut(f.bytes_per_texel()) {
                    f.write(v, t);
                }
            }
            None => texels.fill(0),
        }
    }
}

/// The next coarser level of `src` (`size` texels, `bpt` bytes each, rows in increasing t) by
/// `clipprep`'s 2 x 2 box filter: `floor((a + b + c + d + 2) / 4)` per sample of `sample`
/// bytes (1, or 2: little-endian 16-bit), edges clamped.
pub(super) fn halve(src: &[u8], size: [u64; 2], bpt: usize, sample: usize) -> (Vec<u8>, [u64; 2]) {
    let [w, h] = [size[0] as usize, size[1] as usize];
    let (w2, h2) = ((w / 2).max(1), (h / 2).max(1));
    let mut out = vec![0u8; w2 * h2 * bpt];
    for j in 0..h2 {
        let (r0, r1) = (2 * j, (2 * j + 1).min(h - 1));
        for i in 0..w2 {
            let (c0, c1) = (2 * i, (2 * i + 1).min(w - 1));
            for b in (0..bpt).step_by(sample) {
                let at = |r: usize, c: usize| {
                    let p = (r * w + c) * bpt + b;
                    if sample == 2 {
                        u16::from_le_bytes([src[p], src[p + 1]]) as u32
                    } else {
                        src[p] as u32
                    }
                };
                let v = (at(r0, c0) + at(r0, c1) + at(r1, c0) + at(r1, c1) + 2) / 4;
                out[(j * w2 + i) * bpt + b..][..sample].copy_from_slice(&v.to_le_bytes()[..sample]);
            }
        }
    }
    (out, [w2 as u64, h2 as u64])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn halving_is_clipprep_box_filter_with_clamped_edges() {
        // 3 x 2 grey: the odd column is dropped, as level_size floors.
        let src = [0u8, 10, 200, 1, 3, 255];
        let (out, size) = halve(&src, [3, 2], 1, 1);
        assert_eq!(size, [1, 1]);
        assert_eq!(out, [(14 + 2) / 4]);
        // 1 x 3: the single column is its own neighbour.
        let (out, size) = halve(&[4, 8, 100], [1, 3], 1, 1);
        assert_eq!((out, size), (vec![(4 + 4 + 8 + 8 + 2) / 4], [1, 1]));
    }
}
