//! Block compression at ingest: a source that serves another source's tiles encoded into a
//! block-compressed format (`bc1`, `bc4`, `bc5`, `bc7`; docs/SHM.md, "Block-compressed formats").
//!
//! Owns the encoder and the choice of it. [`BcSource`] wraps any source (prepared pyramids, COGs,
//! tile services and archives, growing textures, the procedural ones): each read decodes the
//! inner tile into a per-thread buffer (the encoder's input: RGBA8 for `bc1` and `bc7`, one
//! channel for `bc4`, two for `bc5`) and encodes it straight into the caller's buffer, which is
//! the tile's slot in the mapping. Reads run on the read queues' worker threads, never on the
//! tick thread.
//!
//! # The encoder, chosen by measurement
//!
//! ISPC's texture compressor (Intel's `ispc_texcomp` kernels, shipped prebuilt in the
//! `intel_tex_2` crate). Measured on one thread, release build, on a 512 x 600 photograph no one
//! here made (`grace_hopper.jpg` of matplotlib's sample data, a PyPI package), in one run on a
//! loaded two-core machine, PSNR of the RGB channels against the source, decoded with `bcdec_rs`:
//!
//! | encoder | Mpx/s | PSNR dB |
//! | --- | --- | --- |
//! | `intel_tex_2` BC1 | 687 | 34.72 |
//! | `texpresso` BC1, range fit | 13.0 | 32.63 |
//! | `texpresso` BC1, cluster fit | 0.3 | 35.26 |
//! | `intel_tex_2` BC7 ultra fast (`fast` here) | 60.7 | 40.98 |
//! | `intel_tex_2` BC7 very fast (`normal`) | 4.28 | 44.10 |
//! | `intel_tex_2` BC7 basic (`slow`) | 1.00 | 44.83 |
//! | `intel_tex_2` BC7 slow | 0.25 | 45.03 |
//!
//! So BC1 is 50 times `texpresso`'s speed at 2 dB more, and BC7 has quality steps no pure-Rust
//! crate offers at these speeds; `image_dds` encodes with the same `intel_tex_2`, and
//! `block_compression` encodes on a GPU (wgpu compute), which the service does not need.
//! `intel_tex_2`'s kernels name C++'s exception personality, so the library's build script
//! links the C++ runtime. BC1, BC4 and BC5 have one setting; [`BcQuality`] picks BC7's.

use super::{Delivered, SourceError, TextureDesc, TileId, TileSource};
use crate::texel::{Bc, ComponentType, Components, TexelFormat};
use serde::Serialize;
use std::cell::RefCell;
use std::sync::Arc;

/// How hard the encoder tries (BC7's settings; BC1, BC4 and BC5 have one).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BcQuality {
    /// BC7 "ultra fast": about 15 times `normal`'s speed, 3 dB less.
    Fast,
    /// BC7 "very fast".
    #[default]
    Normal,
    /// BC7 "basic": about a quarter of `normal`'s speed, 0.7 dB more.
    Slow,
}

impl BcQuality {
    /// The quality named `fast`, `normal` or `slow`.
    pub fn parse(name: &str) -> Result<BcQuality, String> {
        match name {
            "fast" => Ok(BcQuality::Fast),
            "normal" => Ok(BcQuality::Normal),
            "slow" => Ok(BcQuality::Slow),
            _ => Err(format!("`{name}` is not an encoding quality: expected fast, normal or slow")),
        }
    }
}

/// Why a source cannot be served block-compressed.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum BcError {
    /// The inner texels are not 8-bit grey, grey and alpha, RGB or RGBA.
    #[error("texel format {found} cannot be encoded to {bc}: expected 8-bit l8, la8, rgb8 or rgba8 texels")]
    Format {
        /// The inner source's format.
        found: String,
        /// The block format asked for.
        bc: &'static str,
    },
    /// The texels are heights: a block format would lose their precision.
    #[error("the texels are heights ({found}): block formats are for colours and grey images only")]
    Heights {
        /// The inner source's format.
        found: String,
    },
    /// A tile size that does not start every tile on a block: tiles must be multiples of 4
    /// texels, or span their level's whole side.
    #[error("level {level}: tile {tile:?} of a {size:?} level does not start every tile on a 4 x 4 block: give a tile size that is a multiple of 4 (such as 128 or 256)")]
    TileSize {
        /// The level.
        level: u32,
        /// Its tile size.
        tile: [u64; 2],
        /// Its size.
        size: [u64; 2],
    },
    /// The texture description refused the format.
    #[error("{0}")]
    Desc(String),
}

/// The block format's encoder input: bytes a texel.
fn input_bytes(bc: Bc) -> usize {
    match bc {
        Bc::Bc1 | Bc::Bc7 => 4,
        Bc::Bc4 => 1,
        Bc::Bc5 => 2,
    }
}

/// Encodes one tile: `input` is `ceil(w / 4) * 4` x `ceil(h / 4) * 4` texels of the encoder's
/// input (RGBA8 for `bc1` and `bc7`, one byte for `bc4`, two for `bc5`), rows tight; `out` is
/// `ceil(w / 4) * ceil(h / 4)` blocks. Public so that tests and benchmarks encode exactly as the
/// service does.
pub fn encode_padded(bc: Bc, quality: BcQuality, alpha: bool, input: &[u8], w: u64, h: u64, out: &mut [u8]) {
    let (pw, ph) = (w.div_ceil(4) as u32 * 4, h.div_ceil(4) as u32 * 4);
    let px = input_bytes(bc) as u32;
    assert_eq!(input.len(), (pw * ph * px) as usize, "encoder input of a {w}x{h} tile");
    let rgba = || intel_tex_2::RgbaSurface { data: input, width: pw, height: ph, stride: pw * 4 };
    match bc {
        Bc::Bc1 => intel_tex_2::bc1::compress_blocks_into(&rgba(), out),
        Bc::Bc4 => intel_tex_2::bc4::compress_blocks_into(
            &intel_tex_2::RSurface { data: input, width: pw, height: ph, stride: pw },
            out,
        ),
        Bc::Bc5 => intel_tex_2::bc5::compress_blocks_into(
            &intel_tex_2::RgSurface { data: input, width: pw, height: ph, stride: pw * 2 },
            out,
        ),
        Bc::Bc7 => {
            use intel_tex_2::bc7;
            let s = match (quality, alpha) {
                (BcQuality::Fast, false) => bc7::opaque_ultra_fast_settings(),
                (BcQuality::Normal, false) => bc7::opaque_very_fast_settings(),
                (BcQuality::Slow, false) => bc7::opaque_basic_settings(),
                (BcQuality::Fast, true) => bc7::alpha_ultra_fast_settings(),
                (BcQuality::Normal, true) => bc7::alpha_very_fast_settings(),
                (BcQuality::Slow, true) => bc7::alpha_basic_settings(),
            };
            bc7::compress_blocks_into(&s, &rgba(), out)
        }
    }
}

/// Converts a `w` x `h` tile of `from` texels (8-bit l, la, rgb or rgba) into the encoder's input
/// for `bc`, padded to whole blocks by repeating the last column and row (texels no renderer
/// samples; repeated, they cost the edge blocks no accuracy). `None` for another format.
pub fn encoder_input(bc: Bc, from: TexelFormat, tile: &[u8], w: u64, h: u64, input: &mut Vec<u8>) -> Option<()> {
    if from.ctype != ComponentType::U8 {
        return None;
    }
    let n = from.components.count() as usize;
    let (w, h) = (w as usize, h as usize);
    let (pw, ph) = (w.div_ceil(4) * 4, h.div_ceil(4) * 4);
    let px = input_bytes(bc);
    input.clear();
    input.resize(pw * ph * px, 0);
    // Rec. 709 luminance in integers (weights out of 65536), as `TexelFormat::encode` takes it.
    let lum = |p: &[u8]| ((13933 * p[0] as u32 + 46871 * p[1] as u32 + 4732 * p[2] as u32 + 32768) >> 16) as u8;
    for y in 0..ph {
        let sy = y.min(h - 1);
        for x in 0..pw {
            let sx = x.min(w - 1);
            let p = &tile[(sy * w + sx) * n..(sy * w + sx) * n + n];
            let o = &mut input[(y * pw + x) * px..(y * pw + x) * px + px];
            match (bc, from.components) {
                (Bc::Bc1 | Bc::Bc7, Components::One) => o.copy_from_slice(&[p[0], p[0], p[0], 255]),
                (Bc::Bc1 | Bc::Bc7, Components::Two) => o.copy_from_slice(&[p[0], p[0], p[0], p[1]]),
                (Bc::Bc1 | Bc::Bc7, Components::Three) => o.copy_from_slice(&[p[0], p[1], p[2], 255]),
                (Bc::Bc1 | Bc::Bc7, Components::Four) => o.copy_from_slice(p),
                (Bc::Bc4, Components::One | Components::Two) => o[0] = p[0],
                (Bc::Bc4, _) => o[0] = lum(p),
                (Bc::Bc5, Components::One) => o.copy_from_slice(&[p[0], p[0]]),
                (Bc::Bc5, _) => o.copy_from_slice(&p[..2]),
            }
        }
    }
    Some(())
}

thread_local! {
    /// Each read thread's buffers: the inner tile, and the encoder's input when it is not the
    /// inner tile itself.
    static SCRATCH: RefCell<(Vec<u8>, Vec<u8>)> = const { RefCell::new((Vec::new(), Vec::new())) };
}

/// Another source's tiles, block-compressed at each read.
pub struct BcSource {
    inner: Arc<dyn TileSource>,
    desc: TextureDesc,
    bc: Bc,
    quality: BcQuality,
}

impl BcSource {
    /// `inner`'s texture served in `bc` at `quality`. Refused: texels other than 8-bit l, la,
    /// rgb or rgba, heights, and tile sizes that are not multiples of 4 (unless a tile spans its
    /// level's whole side: a pyramid level's single tile, padded to whole blocks).
    pub fn new(inner: Arc<dyn TileSource>, bc: Bc, quality: BcQuality) -> Result<BcSource, BcError> {
        let d = inner.desc();
        if inner.heights().is_some() {
            return Err(BcError::Heights { found: d.format().short_name() });
        }
        if d.format().ctype != ComponentType::U8 {
            return Err(BcError::Format { found: d.format().short_name(), bc: bc.name() });
        }
        for (k, l) in d.levels().iter().enumerate() {
            let ok = |a: usize| l.tile[a].is_multiple_of(4) || l.tile[a] >= l.size[a];
            if !ok(0) || !ok(1) {
                return Err(BcError::TileSize { level: k as u32, tile: l.tile, size: l.size });
            }
        }
        let desc = d.clone().with_format(bc.format()).map_err(|e| BcError::Desc(e.to_string()))?;
        Ok(BcSource { inner, desc, bc, quality })
    }

    /// The block format.
    pub fn bc(&self) -> Bc {
        self.bc
    }
}

impl TileSource for BcSource {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.read_into(tile, out).map(|_| ())
    }

    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<Delivered, SourceError> {
        let expected = self.desc.tile_bytes(tile.level);
        if out.len() != expected {
            return Err(SourceError::BufferSize { tile, expected, found: out.len() });
        }
        let from = self.inner.desc().format();
        let [w, h] = self.inner.desc().level(tile.level).tile;
        SCRATCH.with(|s| {
            let (texels, input) = &mut *s.borrow_mut();
            texels.resize(self.inner.desc().tile_bytes(tile.level), 0);
            let delivered = self.inner.read_into(tile, texels)?;
            let alpha = matches!(from.components, Components::Two | Components::Four);
            // The inner tile is the encoder's input as it is when it is whole blocks of it.
            let direct = w.is_multiple_of(4)
                && h.is_multiple_of(4)
                && from.components.count() as usize == input_bytes(self.bc)
                && !(self.bc == Bc::Bc5 && from.components != Components::Two);
            if direct {
                encode_padded(self.bc, self.quality, alpha, texels, w, h, out);
            } else {
                encoder_input(self.bc, from, texels, w, h, input).expect("formats checked at construction");
                encode_padded(self.bc, self.quality, alpha, input, w, h, out);
            }
            Ok(delivered)
        })
    }

    fn wrapped(&self) -> Option<&dyn TileSource> {
        Some(&*self.inner)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::HashSource;

    fn hash(format: TexelFormat, tile: u64) -> Arc<dyn TileSource> {
        let desc = TextureDesc::new([256, 256], 64, format, [tile, tile]).unwrap();
        Arc::new(HashSource::new(desc))
    }

    #[test]
    fn every_format_encodes_a_hash_tile_closer_to_its_texels_than_to_another_tiles() {
        // Hash texels are noise, the worst case for any encoder: the blocks must decode (with
        // bcdec_rs, not the encoder) much closer to the tile they came from than to its neighbour.
        let inner = hash(TexelFormat::RGBA8, 32);
        let texels = |s: u64| {
            let mut t = vec![0u8; inner.desc().tile_bytes(0)];
            inner.read_tile(TileId { level: 0, s, t: 2 }, &mut t).unwrap();
            t
        };
        let (own, other) = (texels(1), texels(2));
        let mean = |a: &[u8], b: &[u8], n: usize, m: usize| {
            let e: f64 = a.chunks_exact(n).zip(b.chunks_exact(m)).map(|(a, b)| (a[0] as f64 - b[0] as f64).abs()).sum();
            e / (32.0 * 32.0)
        };
        for bc in [Bc::Bc1, Bc::Bc4, Bc::Bc5, Bc::Bc7] {
            let src = BcSource::new(inner.clone(), bc, BcQuality::Fast).unwrap();
            let mut blocks = vec![0u8; src.desc().tile_bytes(0)];
            assert_eq!(blocks.len(), 8 * 8 * bc.block_bytes() as usize);
            src.read_tile(TileId { level: 0, s: 1, t: 2 }, &mut blocks).unwrap();
            let back = crate::shm::blocks::decode(bc, &blocks, 32, 32).unwrap();
            let n = crate::shm::blocks::decoded_bytes(bc);
            // Channel 0: red, or the luminance BC4 holds (compared with red: the hash is grey-free
            // noise, so only the bound against the other tile matters for it).
            let (near, far) = (mean(&own, &back, 4, n), mean(&other, &back, 4, n));
            if bc != Bc::Bc4 {
                assert!(near < 0.6 * far, "{bc:?}: mean error {near} against its tile, {far} against another");
            }
        }
    }

    #[test]
    fn grey_tiles_encode_to_bc4_exactly_where_a_block_is_flat_and_pyramid_tiles_pad() {
        // A 3 x 3 pyramid level's single tile pads to one block; a flat tile decodes exactly.
        struct Flat(TextureDesc);
        impl TileSource for Flat {
            fn desc(&self) -> &TextureDesc {
                &self.0
            }
            fn read_tile(&self, _: TileId, out: &mut [u8]) -> Result<(), SourceError> {
                out.fill(77);
                Ok(())
            }
        }
        let desc = TextureDesc::new([256, 256], 64, TexelFormat::L8, [32, 32]).unwrap();
        let src = BcSource::new(Arc::new(Flat(desc)), Bc::Bc4, BcQuality::Normal).unwrap();
        let top = src.desc().level_count() as u32 - 3; // 4 x 4
        for k in [0, top, top + 1, top + 2] {
            let [w, h] = src.desc().level(k).tile;
            let mut blocks = vec![0u8; src.desc().tile_bytes(k)];
            src.read_tile(TileId { level: k, s: 0, t: 0 }, &mut blocks).unwrap();
            let back = crate::shm::blocks::decode(Bc::Bc4, &blocks, w, h).unwrap();
            assert!(back.iter().all(|&v| v == 77), "level {k}");
        }
    }

    #[test]
    fn heights_other_formats_and_tiles_off_the_block_grid_are_refused() {
        let e = BcSource::new(hash(TexelFormat::RGB16, 32), Bc::Bc1, BcQuality::Fast).err().unwrap();
        assert!(e.to_string().contains("expected 8-bit l8, la8, rgb8 or rgba8"), "{e}");
        let e = BcSource::new(hash(TexelFormat::RGB8, 30), Bc::Bc7, BcQuality::Fast).err().unwrap();
        assert!(e.to_string().contains("level 0: tile [30, 30]") && e.to_string().contains("multiple of 4"), "{e}");
        assert!(BcQuality::parse("best").unwrap_err().contains("fast, normal or slow"));
    }
}
