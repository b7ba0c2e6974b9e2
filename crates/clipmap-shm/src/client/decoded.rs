//! Texels of a block-compressed mapping, decoded (docs/SHM.md, "Block-compressed formats"): a
//! region read tile by tile under each slot's tag, each tile decoded once with the independent
//! decoder of [`crate::blocks`], for pictures and checks that want texels rather than blocks.
//! Renderers upload the blocks themselves ([`Client::read_tile`]).

use super::{Client, ReadError, Snapshot};
use clipmap_base::geom::Rect;
use clipmap_base::texel::{Bc, ComponentType, Components, TexelFormat};

impl Client {
    /// The block format of a block-compressed mapping; `None` for a mapping of texels.
    pub fn block_format(&self) -> Option<Bc> {
        crate::layout::format_from_code(self.format_code).and_then(|f| f.block())
    }

    /// The format of the texels [`decode_region_in`](Self::decode_region_in) gives: RGBA8 for
    /// `bc1` and `bc7`, one byte for `bc4`, two for `bc5` (its two channels); `None` for a
    /// mapping of texels.
    pub fn decoded_format(&self) -> Option<TexelFormat> {
        let components = match self.block_format()? {
            Bc::Bc1 | Bc::Bc7 => Components::Four,
            Bc::Bc4 => Components::One,
            Bc::Bc5 => Components::Two,
        };
        Some(TexelFormat { components, ctype: ComponentType::U8 })
    }

    /// Decodes the texels of `rect` of `level` of a block-compressed mapping into `out` (rows in
    /// increasing t, s fastest, [`decoded_format`](Self::decoded_format) texels), each tile
    /// under it read whole under its slot's tag and decoded once. The region must lie inside the
    /// level's valid region in `snap` (`NotValid`); on a texture that wraps in longitude, tile
    /// columns past the width are those of the level itself. Errors as
    /// [`read_region_in`](Self::read_region_in); `Corrupt` for a mapping of texels.
    pub fn decode_region_in(&self, snap: &Snapshot, level: usize, rect: Rect, out: &mut [u8]) -> Result<(), ReadError> {
        let format = self.decoded_format().ok_or_else(|| {
            ReadError::Corrupt(format!("texel format code {} is not block-compressed: read_region", self.format_code))
        })?;
        let d = *self.levels.get(level).ok_or(ReadError::NoLevel(level))?;
        let st = snap.levels.get(level).ok_or(ReadError::NoLevel(level))?;
        let n = format.bytes_per_texel() as usize;
        let (w, h) = (rect.width() as usize, rect.height() as usize);
        if out.len() != w * h * n {
            return Err(ReadError::Corrupt(format!("buffer of {} bytes for a {w}x{h} region", out.len())));
        }
        if w == 0 || h == 0 {
            return Ok(());
        }
        if !st.rect().contains_rect(&rect) {
            return Err(ReadError::NotValid(level));
        }
        let across = d.size[0].div_ceil(d.tile[0]) as i64;
        let (tw, th) = (d.tile[0] as i64, d.tile[1] as i64);
        let tiles = clipmap_base::geom::tiles_covering(rect, d.tile);
        for ts in tiles.s0..tiles.s1 {
            let real = if self.texel_period(level).is_some() { ts.rem_euclid(across) } else { ts };
            for tt in tiles.t0..tiles.t1 {
                let texels = self.decode_tile(level, [real, tt])?;
                let part = rect.intersect(&Rect::new(ts * tw, tt * th, (ts + 1) * tw, (tt + 1) * th));
                let run = part.width() as usize * n;
                for t in part.t0..part.t1 {
                    let src = (((t - tt * th) * tw + (part.s0 - ts * tw)) as usize) * n;
                    let dst = ((t - rect.t0) as usize * w + (part.s0 - rect.s0) as usize) * n;
                    out[dst..dst + run].copy_from_slice(&texels[src..src + run]);
                }
            }
        }
        Ok(())
    }
}
