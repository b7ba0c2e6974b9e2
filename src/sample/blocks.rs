//! Texels of a block-compressed mapping (`bc1`, `bc4`, `bc5`, `bc7`; docs/SHM.md) for the
//! mapping sampler: each texel is read from its tile's blocks under the slot's tag and decoded
//! with the independent decoder (`crate::shm::blocks`, `bcdec_rs`), never with the encoder the
//! service used. The decoded texels are read as [`decoded_format`].

use crate::geom::Rect;
use crate::shm::{Client, Snapshot};
use crate::texel::{Bc, ComponentType, Components, TexelFormat};

/// The format a decoded texel of `bc` is read as: RGBA8 for `bc1` and `bc7`, grey (L8) for `bc4`,
/// grey and alpha (LA8: the two channels) for `bc5`, as `crate::shm::blocks::decode` lays them out.
pub fn decoded_format(bc: Bc) -> TexelFormat {
    match bc {
        Bc::Bc1 | Bc::Bc7 => TexelFormat::RGBA8,
        Bc::Bc4 => TexelFormat::L8,
        Bc::Bc5 => TexelFormat { components: Components::Two, ctype: ComponentType::U8 },
    }
}

/// The last tile read (one sample touches one or two tiles a level), and its blocks.
pub(super) struct BlockTexels {
    bc: Bc,
    key: Option<(u32, [i64; 2])>,
    blocks: Vec<u8>,
    ok: bool,
}

impl BlockTexels {
    pub(super) fn new(bc: Bc) -> BlockTexels {
        BlockTexels { bc, key: None, blocks: Vec::new(), ok: false }
    }

    /// Texel (s, t) of `level`, decoded, into `out` ([`decoded_format`]'s bytes); `false` when it
    /// is outside the level's published valid region in `snap` or its tile cannot be read.
    pub(super) fn texel(
        &mut self,
        client: &Client,
        snap: &Snapshot,
        level: u32,
        s: i64,
        t: i64,
        out: &mut [u8],
    ) -> bool {
        let (Some(d), Some(st)) = (client.levels.get(level as usize), snap.levels.get(level as usize)) else {
            return false;
        };
        let region = st.rect();
        let s = match client.texel_period(level as usize) {
            Some(p) => {
                let at = region.s0 + crate::geom::wrap(s - region.s0, p) as i64;
                if region.is_empty() || at >= region.s1 || t < region.t0 || t >= region.t1 {
                    return false;
                }
                s.rem_euclid(p as i64)
            }
            None if region.contains_rect(&Rect::new(s, t, s + 1, t + 1)) => s,
            None => return false,
        };
        let (tw, th) = (d.tile[0] as i64, d.tile[1] as i64);
        let tile = [s.div_euclid(tw), t.div_euclid(th)];
        if self.key != Some((level, tile)) {
            self.blocks.resize(d.slot_bytes as usize, 0);
            self.ok = client.read_tile(level as usize, tile, &mut self.blocks).is_ok();
            self.key = Some((level, tile));
        }
        if !self.ok {
            return false;
        }
        let (x, y) = ((s - tile[0] * tw) as usize, (t - tile[1] * th) as usize);
        let bb = self.bc.block_bytes() as usize;
        let at = ((y / 4) * (tw as usize).div_ceil(4) + x / 4) * bb;
        let Ok(texels) = crate::shm::blocks::decode(self.bc, &self.blocks[at..at + bb], 4, 4) else {
            return false;
        };
        let px = crate::shm::blocks::decoded_bytes(self.bc);
        let i = ((y % 4) * 4 + x % 4) * px;
        out.copy_from_slice(&texels[i..i + px]);
        true
    }
}
