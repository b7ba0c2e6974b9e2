//! The border tiles of sparse levels: texels of the inset level K, magnified to level k by
//! nearest neighbour (level-k texel (s, t) is level-K texel (s >> (K - k), t >> (K - k))).
//!
//! Runs after every level has been written, and reads level K back from the output, one
//! level-K row segment (or, compressed, one level-K tile) at a time, so it needs one tile of
//! memory whatever the texture size.
//! Which tiles are borders is [`super::inset`]'s business.

use super::error::PrepError;
use super::inset::TileRole;
use super::layout::{Layout, Level};
use super::sink::write_tile_part;
use std::collections::HashMap;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// Reads texel row segments of one level from the written output.
struct LevelReader<'a> {
    root: &'a Path,
    layout: &'a Layout,
    level: &'a Level,
    files: HashMap<PathBuf, File>,
    /// The last tile decoded, when the level is compressed: (tile s, tile t, texels).
    decoded: Option<(u64, u64, Vec<u8>)>,
}

impl LevelReader<'_> {
    /// Reads `n` texels of row `t` from column `s` on; they must lie in one tile.
    fn segment(&mut self, s: u64, t: u64, n: u64, out: &mut Vec<u8>) -> std::io::Result<()> {
        let l = self.level;
        let bpt = self.layout.bpt();
        let (ts, tt) = (s / l.tile_w, t / l.tile_h);
        let loc = self.layout.tile(l, ts, tt);
        let within = ((t % l.tile_h) * l.tile_w + s % l.tile_w) * bpt;
        let path = self.root.join(&loc.path);
        if self.layout.compressed(l) {
            if !matches!(&self.decoded, Some((a, b, _)) if (*a, *b) == (ts, tt)) {
                let packed = std::fs::read(&path)?;
                self.decoded = Some((ts, tt, zstd::bulk::decompress(&packed, loc.length as usize)?));
            }
            let tile = &self.decoded.as_ref().expect("decoded above").2;
            out.clear();
            out.extend_from_slice(&tile[within as usize..(within + n * bpt) as usize]);
            return Ok(());
        }
        let offset = loc.offset + within;
        let f = match self.files.entry(path) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => {
                let f = File::open(e.key())?;
                e.insert(f)
            }
        };
        f.seek(SeekFrom::Start(offset))?;
        out.resize((n * bpt) as usize, 0);
        f.read_exact(out)
    }
}

/// Writes every border tile of every sparse level under `root`; returns the number written.
pub(crate) fn write_borders(root: &Path, layout: &Layout, total_bytes: u64) -> Result<u64, PrepError> {
    let Some(inset) = layout.spec.inset else {
        return Ok(0);
    };
    let coarse = &layout.levels[inset.level as usize];
    let mut reader = LevelReader { root, layout, level: coarse, files: HashMap::new(), decoded: None };
    let bpt = layout.bpt() as usize;
    let mut written = 0;
    let mut tile = Vec::new();
    let mut segment = Vec::new();
    for level in &layout.levels {
        let Some(sparse) = layout.sparse(level) else {
            continue;
        };
        let shift = inset.level - level.index;
        let (tw, th) = (level.tile_w, level.tile_h);
        let span = (tw >> shift).max(1);
        for t in sparse.written.t0..sparse.written.t1 {
            for s in sparse.written.s0..sparse.written.s1 {
                if sparse.role(s, t) != TileRole::Border {
                    continue;
                }
                tile.clear();
                let mut last_row = None;
                for r in 0..th {
                    let ct = (t * th + r) >> shift;
                    if last_row != Some(ct) {
                        reader
                            .segment((s * tw) >> shift, ct, span, &mut segment)
                            .map_err(|e| PrepError::write(root.join(layout.tile(coarse, 0, 0).path), e, total_bytes))?;
                        last_row = Some(ct);
                    }
                    for x in 0..tw {
                        let cx = (((s * tw + x) >> shift) - ((s * tw) >> shift)) as usize;
                        tile.extend_from_slice(&segment[cx * bpt..(cx + 1) * bpt]);
                    }
                }
                write_tile_part(root, layout, level, s, t, 0, &tile, total_bytes)?;
                written += 1;
            }
        }
    }
    Ok(written)
}
