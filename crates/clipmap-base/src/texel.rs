//! Texel formats: what a texel is on disk, how many bytes it takes, and how colours are encoded
//! into it and decoded from it.
//!
//! Owns the mapping from Performer's `img_format` (components) and `ext_format` (component type or
//! packed layout) to a [`TexelFormat`]. It knows nothing of files or levels.

use serde::Serialize;
use std::fmt;

/// Component layout as named by Performer's `img_format`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Components {
    /// One channel: luminance, or a single red/green/blue/alpha channel.
    One,
    /// Luminance and alpha.
    Two,
    /// Red, green, blue.
    Three,
    /// Red, green, blue, alpha (or ABGR).
    Four,
}

impl Components {
    /// Number of components.
    pub fn count(self) -> u32 {
        match self {
            Components::One => 1,
            Components::Two => 2,
            Components::Three => 3,
            Components::Four => 4,
        }
    }

    /// From a component count (1..=4).
    pub fn from_count(n: u32) -> Option<Self> {
        Some(match n {
            1 => Components::One,
            2 => Components::Two,
            3 => Components::Three,
            4 => Components::Four,
            _ => return None,
        })
    }
}

/// How one texel's components are stored, as named by Performer's `ext_format`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ComponentType {
    /// `GL_UNSIGNED_BYTE` and friends: one byte per component.
    U8,
    /// `GL_BYTE`.
    I8,
    /// `GL_UNSIGNED_SHORT`.
    U16,
    /// `GL_SHORT`.
    I16,
    /// `GL_UNSIGNED_INT`.
    U32,
    /// `GL_INT`.
    I32,
    /// `GL_FLOAT`.
    F32,
    /// A packed type: the whole texel takes this many bytes, whatever the component count.
    Packed(PackedType),
    /// `GL_BITMAP`: not meaningful for tiles.
    Bitmap,
    /// A block-compressed format: 4 x 4 texels in one block of [`Bc::block_bytes`] bytes
    /// ([`TexelFormat::block`]). Not one of Performer's; the mapping's and our `.ic` extension.
    Bc(Bc),
}

/// The block-compressed (BCn, DXT) formats a texture may be published in: every 4 x 4 texels
/// are one block, blocks in rows, each block's bytes as Direct3D and Vulkan define them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Bc {
    /// BC1 (DXT1): opaque RGB, 8 bytes a block (4 bits a texel).
    Bc1,
    /// BC4: one channel, 8 bytes a block.
    Bc4,
    /// BC5: two channels, 16 bytes a block.
    Bc5,
    /// BC7: RGBA, 16 bytes a block (8 bits a texel).
    Bc7,
}

impl Bc {
    /// Texels a side of one block.
    pub const EDGE: u64 = 4;

    /// Bytes of one 4 x 4 block.
    pub fn block_bytes(self) -> u32 {
        match self {
            Bc::Bc1 | Bc::Bc4 => 8,
            Bc::Bc5 | Bc::Bc7 => 16,
        }
    }

    /// The format's short name (`bc1`, `bc4`, `bc5`, `bc7`).
    pub fn name(self) -> &'static str {
        match self {
            Bc::Bc1 => "bc1",
            Bc::Bc4 => "bc4",
            Bc::Bc5 => "bc5",
            Bc::Bc7 => "bc7",
        }
    }

    /// The texel format of this block format.
    pub fn format(self) -> TexelFormat {
        match self {
            Bc::Bc1 => TexelFormat::BC1,
            Bc::Bc4 => TexelFormat::BC4,
            Bc::Bc5 => TexelFormat::BC5,
            Bc::Bc7 => TexelFormat::BC7,
        }
    }

    /// The block format named `name` (`bc1`, `bc4`, `bc5` or `bc7`, any case).
    pub fn parse(name: &str) -> Result<Bc, String> {
        match name.to_ascii_lowercase().as_str() {
            "bc1" => Ok(Bc::Bc1),
            "bc4" => Ok(Bc::Bc4),
            "bc5" => Ok(Bc::Bc5),
            "bc7" => Ok(Bc::Bc7),
            _ => Err(format!("`{name}` is not a block format: expected bc1, bc4, bc5 or bc7")),
        }
    }
}

/// Packed texel layouts (whole texel in one 8-, 16- or 32-bit word, little-endian on disk).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PackedType {
    /// 5-6-5 bits, red in the high bits.
    Rgb565,
    /// 4-4-4-4 bits, red in the high bits.
    Rgba4444,
    /// 5-5-5-1 bits, red in the high bits, alpha in bit 0.
    Rgba5551,
    /// 3-3-2 bits.
    Rgb332,
    /// 8-8-8-8 bits in a 32-bit word.
    Rgba8888,
    /// 10-10-10-2 bits in a 32-bit word.
    Rgb10A2,
}

impl PackedType {
    /// Bytes per texel.
    pub fn bytes(self) -> u32 {
        match self {
            PackedType::Rgb332 => 1,
            PackedType::Rgb565 | PackedType::Rgba4444 | PackedType::Rgba5551 => 2,
            PackedType::Rgba8888 | PackedType::Rgb10A2 => 4,
        }
    }
}

impl ComponentType {
    /// Bytes per component (for packed types: bytes per texel).
    pub fn bytes(self) -> u32 {
        match self {
            ComponentType::U8 | ComponentType::I8 => 1,
            ComponentType::U16 | ComponentType::I16 => 2,
            ComponentType::U32 | ComponentType::I32 | ComponentType::F32 => 4,
            ComponentType::Packed(p) => p.bytes(),
            ComponentType::Bitmap => 0,
            ComponentType::Bc(b) => b.block_bytes(),
        }
    }
}

/// A complete texel format: components plus their storage.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct TexelFormat {
    /// Component layout.
    pub components: Components,
    /// Storage of the components.
    pub ctype: ComponentType,
}

impl TexelFormat {
    /// 8-bit luminance.
    pub const L8: TexelFormat = TexelFormat { components: Components::One, ctype: ComponentType::U8 };
    /// 8-bit RGB.
    pub const RGB8: TexelFormat = TexelFormat { components: Components::Three, ctype: ComponentType::U8 };
    /// 8-bit RGBA.
    pub const RGBA8: TexelFormat = TexelFormat { components: Components::Four, ctype: ComponentType::U8 };
    /// 16-bit packed RGB 5-6-5.
    pub const RGB565: TexelFormat =
        TexelFormat { components: Components::Three, ctype: ComponentType::Packed(PackedType::Rgb565) };
    /// 16-bit packed RGBA 5-5-5-1.
    pub const RGBA5551: TexelFormat =
        TexelFormat { components: Components::Four, ctype: ComponentType::Packed(PackedType::Rgba5551) };
    /// 16-bit luminance (heights, for terrain).
    pub const L16: TexelFormat = TexelFormat { components: Components::One, ctype: ComponentType::U16 };
    /// Heights in 32-bit floats, metres (docs/ELEVATION.md).
    pub const L32F: TexelFormat = TexelFormat { components: Components::One, ctype: ComponentType::F32 };
    /// Heights in signed 16-bit steps (docs/ELEVATION.md; `L16` holds unsigned ones).
    pub const L16I: TexelFormat = TexelFormat { components: Components::One, ctype: ComponentType::I16 };
    /// 16-bit luminance and alpha.
    pub const LA16: TexelFormat = TexelFormat { components: Components::Two, ctype: ComponentType::U16 };
    /// 16-bit RGB.
    pub const RGB16: TexelFormat = TexelFormat { components: Components::Three, ctype: ComponentType::U16 };
    /// 16-bit RGBA.
    pub const RGBA16: TexelFormat = TexelFormat { components: Components::Four, ctype: ComponentType::U16 };

    /// BC1: opaque RGB in 8-byte 4 x 4 blocks.
    pub const BC1: TexelFormat = TexelFormat { components: Components::Three, ctype: ComponentType::Bc(Bc::Bc1) };
    /// BC4: one channel in 8-byte 4 x 4 blocks.
    pub const BC4: TexelFormat = TexelFormat { components: Components::One, ctype: ComponentType::Bc(Bc::Bc4) };
    /// BC5: two channels in 16-byte 4 x 4 blocks.
    pub const BC5: TexelFormat = TexelFormat { components: Components::Two, ctype: ComponentType::Bc(Bc::Bc5) };
    /// BC7: RGBA in 16-byte 4 x 4 blocks.
    pub const BC7: TexelFormat = TexelFormat { components: Components::Four, ctype: ComponentType::Bc(Bc::Bc7) };

    /// Bytes one texel takes on disk and in memory (0 for `GL_BITMAP`); for a block format
    /// ([`block`](Self::block)) the bytes of one 4 x 4 block: use [`bytes_for`](Self::bytes_for)
    /// for the bytes of a rectangle of texels, which holds for both.
    pub fn bytes_per_texel(self) -> u32 {
        match self.ctype {
            ComponentType::Packed(p) => p.bytes(),
            ComponentType::Bc(b) => b.block_bytes(),
            other => other.bytes() * self.components.count(),
        }
    }

    /// The block format, `None` for a format of whole texels.
    pub fn block(self) -> Option<Bc> {
        match self.ctype {
            ComponentType::Bc(b) => Some(b),
            _ => None,
        }
    }

    /// Texels a side of the format's unit of storage: 4 for a block format, 1 otherwise.
    pub fn block_edge(self) -> u64 {
        if self.block().is_some() {
            Bc::EDGE
        } else {
            1
        }
    }

    /// Bytes of a `w` x `h` rectangle of texels stored whole (a tile): `w * h` texels, or for a
    /// block format `ceil(w / 4) * ceil(h / 4)` blocks (a partial block at an edge is a whole
    /// block). `None` on overflow.
    pub fn bytes_for(self, w: u64, h: u64) -> Option<u64> {
        let e = self.block_edge();
        w.div_ceil(e).checked_mul(h.div_ceil(e))?.checked_mul(u64::from(self.bytes_per_texel()))
    }

    /// Bits of the deepest component (8 for the 8-bit and packed formats of 8 bits or fewer per
    /// component, 16 for the 16-bit ones).
    pub fn component_bits(self) -> u32 {
        match self.ctype {
            ComponentType::Packed(PackedType::Rgb10A2) => 10,
            ComponentType::Packed(_) => 8,
            other => other.bytes() * 8,
        }
    }

    /// Short lower-case name used by the tools (`rgb8`, `rgba5551`, …).
    pub fn short_name(self) -> String {
        let comps = match self.components {
            Components::One => "l",
            Components::Two => "la",
            Components::Three => "rgb",
            Components::Four => "rgba",
        };
        match self.ctype {
            ComponentType::U8 => format!("{comps}8"),
            ComponentType::I8 => format!("{comps}8i"),
            ComponentType::U16 => format!("{comps}16"),
            ComponentType::I16 => format!("{comps}16i"),
            ComponentType::U32 => format!("{comps}32"),
            ComponentType::I32 => format!("{comps}32i"),
            ComponentType::F32 => format!("{comps}32f"),
            ComponentType::Packed(PackedType::Rgb565) => "rgb565".into(),
            ComponentType::Packed(PackedType::Rgba4444) => "rgba4444".into(),
            ComponentType::Packed(PackedType::Rgba5551) => "rgba5551".into(),
            ComponentType::Packed(PackedType::Rgb332) => "rgb332".into(),
            ComponentType::Packed(PackedType::Rgba8888) => "rgba8888".into(),
            ComponentType::Packed(PackedType::Rgb10A2) => "rgb10a2".into(),
            ComponentType::Bitmap => "bitmap".into(),
            ComponentType::Bc(b) => b.name().into(),
        }
    }

    /// Encodes a linear-or-not (caller's choice) RGBA colour with components in 0..=1 into `out`,
    /// which must be exactly [`bytes_per_texel`](Self::bytes_per_texel) long. One-component
    /// formats take the luminance (Rec. 709 weights); two take luminance and alpha. A block
    /// format has no texel of its own: `out` is left alone (blocks are encoded whole, at ingest).
    pub fn encode(self, rgba: [f32; 4], out: &mut [u8]) {
        let c = |v: f32| v.clamp(0.0, 1.0);
        let lum = c(0.2126 * rgba[0] + 0.7152 * rgba[1] + 0.0722 * rgba[2]);
        let chans: [f32; 4] = match self.components {
            Components::One => [lum, 0.0, 0.0, 0.0],
            Components::Two => [lum, c(rgba[3]), 0.0, 0.0],
            Components::Three => [c(rgba[0]), c(rgba[1]), c(rgba[2]), 0.0],
            Components::Four => [c(rgba[0]), c(rgba[1]), c(rgba[2]), c(rgba[3])],
        };
        let n = self.components.count() as usize;
        let q = |v: f32, max: u32| (v * max as f32).round() as u32;
        match self.ctype {
            ComponentType::U8 | ComponentType::I8 => {
                for i in 0..n {
                    out[i] = q(chans[i], 255) as u8;
                }
            }
            ComponentType::U16 | ComponentType::I16 => {
                for i in 0..n {
                    out[2 * i..2 * i + 2].copy_from_slice(&(q(chans[i], 65535) as u16).to_le_bytes());
                }
            }
            ComponentType::U32 | ComponentType::I32 => {
                for i in 0..n {
                    let v = (chans[i] as f64 * u32::MAX as f64).round() as u32;
                    out[4 * i..4 * i + 4].copy_from_slice(&v.to_le_bytes());
                }
            }
            ComponentType::F32 => {
                for i in 0..n {
                    out[4 * i..4 * i + 4].copy_from_slice(&chans[i].to_le_bytes());
                }
            }
            ComponentType::Packed(p) => {
                let (r, g, b, a) = (rgba[0], rgba[1], rgba[2], rgba[3]);
                match p {
                    PackedType::Rgb565 => {
                        let v = (q(c(r), 31) << 11) | (q(c(g), 63) << 5) | q(c(b), 31);
                        out.copy_from_slice(&(v as u16).to_le_bytes());
                    }
                    PackedType::Rgba4444 => {
                        let v = (q(c(r), 15) << 12) | (q(c(g), 15) << 8) | (q(c(b), 15) << 4) | q(c(a), 15);
                        out.copy_from_slice(&(v as u16).to_le_bytes());
                    }
                    PackedType::Rgba5551 => {
                        let v = (q(c(r), 31) << 11) | (q(c(g), 31) << 6) | (q(c(b), 31) << 1) | q(c(a), 1);
                        out.copy_from_slice(&(v as u16).to_le_bytes());
                    }
                    PackedType::Rgb332 => {
                        out[0] = ((q(c(r), 7) << 5) | (q(c(g), 7) << 2) | q(c(b), 3)) as u8;
                    }
                    PackedType::Rgba8888 => {
                        let v = (q(c(r), 255) << 24) | (q(c(g), 255) << 16) | (q(c(b), 255) << 8) | q(c(a), 255);
                        out.copy_from_slice(&v.to_le_bytes());
                    }
                    PackedType::Rgb10A2 => {
                        let v = (q(c(r), 1023) << 22) | (q(c(g), 1023) << 12) | (q(c(b), 1023) << 2) | q(c(a), 3);
                        out.copy_from_slice(&v.to_le_bytes());
                    }
                }
            }
            ComponentType::Bitmap | ComponentType::Bc(_) => {}
        }
    }

    /// Decodes one texel into RGBA components in 0..=1 (the inverse of [`encode`](Self::encode)
    /// up to quantisation; one-component formats give grey, alpha 1 where absent). A block
    /// format has no texel of its own: decode its blocks whole (the mapping's client does).
    pub fn decode(self, texel: &[u8]) -> [f32; 4] {
        let n = self.components.count() as usize;
        let mut ch = [0f32; 4];
        match self.ctype {
            ComponentType::U8 | ComponentType::I8 => {
                for i in 0..n {
                    ch[i] = texel[i] as f32 / 255.0;
                }
            }
            ComponentType::U16 | ComponentType::I16 => {
                for i in 0..n {
                    ch[i] = u16::from_le_bytes([texel[2 * i], texel[2 * i + 1]]) as f32 / 65535.0;
                }
            }
            ComponentType::U32 | ComponentType::I32 => {
                for i in 0..n {
                    let b = [texel[4 * i], texel[4 * i + 1], texel[4 * i + 2], texel[4 * i + 3]];
                    ch[i] = (u32::from_le_bytes(b) as f64 / u32::MAX as f64) as f32;
                }
            }
            ComponentType::F32 => {
                for i in 0..n {
                    let b = [texel[4 * i], texel[4 * i + 1], texel[4 * i + 2], texel[4 * i + 3]];
                    ch[i] = f32::from_le_bytes(b);
                }
            }
            ComponentType::Packed(p) => {
                let w16 = || u16::from_le_bytes([texel[0], texel[1]]) as u32;
                let w32 = || u32::from_le_bytes([texel[0], texel[1], texel[2], texel[3]]);
                let f = |v: u32, bits: u32| v as f32 / ((1u32 << bits) - 1) as f32;
                return match p {
                    PackedType::Rgb565 => {
                        let v = w16();
                        [f(v >> 11, 5), f((v >> 5) & 63, 6), f(v & 31, 5), 1.0]
                    }
                    PackedType::Rgba4444 => {
                        let v = w16();
                        [f(v >> 12, 4), f((v >> 8) & 15, 4), f((v >> 4) & 15, 4), f(v & 15, 4)]
                    }
                    PackedType::Rgba5551 => {
                        let v = w16();
                        [f(v >> 11, 5), f((v >> 6) & 31, 5), f((v >> 1) & 31, 5), f(v & 1, 1)]
                    }
                    PackedType::Rgb332 => {
                        let v = texel[0] as u32;
                        [f(v >> 5, 3), f((v >> 2) & 7, 3), f(v & 3, 2), 1.0]
                    }
                    PackedType::Rgba8888 => {
                        let v = w32();
                        [f(v >> 24, 8), f((v >> 16) & 255, 8), f((v >> 8) & 255, 8), f(v & 255, 8)]
                    }
                    PackedType::Rgb10A2 => {
                        let v = w32();
                        [f(v >> 22, 10), f((v >> 12) & 1023, 10), f((v >> 2) & 1023, 10), f(v & 3, 2)]
                    }
                };
            }
            ComponentType::Bitmap | ComponentType::Bc(_) => {}
        }
        match self.components {
            Components::One => [ch[0], ch[0], ch[0], 1.0],
            Components::Two => [ch[0], ch[0], ch[0], ch[1]],
            Components::Three => [ch[0], ch[1], ch[2], 1.0],
            Components::Four => ch,
        }
    }
}

impl fmt::Display for TexelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.short_name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_per_texel_follows_performer_rules() {
        assert_eq!(TexelFormat::RGB8.bytes_per_texel(), 3);
        assert_eq!(TexelFormat::RGBA8.bytes_per_texel(), 4);
        assert_eq!(TexelFormat::L8.bytes_per_texel(), 1);
        assert_eq!(TexelFormat::RGBA5551.bytes_per_texel(), 2);
        assert_eq!(TexelFormat::RGB565.bytes_per_texel(), 2);
        let rgb16 = TexelFormat { components: Components::Three, ctype: ComponentType::U16 };
        assert_eq!(rgb16, TexelFormat::RGB16);
        assert_eq!(rgb16.bytes_per_texel(), 6);
        assert_eq!(TexelFormat::L16.bytes_per_texel(), 2);
        assert_eq!(TexelFormat::LA16.bytes_per_texel(), 4);
        assert_eq!(TexelFormat::RGBA16.bytes_per_texel(), 8);
    }

    #[test]
    fn sixteen_bit_formats_are_named_and_sized() {
        let names: Vec<String> = [TexelFormat::L16, TexelFormat::LA16, TexelFormat::RGB16, TexelFormat::RGBA16]
            .iter()
            .map(|f| f.short_name())
            .collect();
        assert_eq!(names, ["l16", "la16", "rgb16", "rgba16"]);
        assert_eq!((TexelFormat::L32F.short_name(), TexelFormat::L32F.bytes_per_texel()), ("l32f".to_string(), 4));
        assert_eq!((TexelFormat::L16I.short_name(), TexelFormat::L16I.bytes_per_texel()), ("l16i".to_string(), 2));
        assert_eq!(TexelFormat::RGBA16.component_bits(), 16);
        assert_eq!(TexelFormat::L8.component_bits(), 8);
        assert_eq!(TexelFormat::RGB565.component_bits(), 8);
    }

    #[test]
    fn sixteen_bit_components_encode_and_decode_exactly_little_endian() {
        // Every 16-bit value survives encode(decode(v)), in every component position.
        for fmt in [TexelFormat::L16, TexelFormat::LA16, TexelFormat::RGB16, TexelFormat::RGBA16] {
            let n = fmt.components.count() as usize;
            let mut buf = vec![0u8; fmt.bytes_per_texel() as usize];
            for v in (0..=65535u32).step_by(7).chain([1, 256, 257, 32767, 32768, 65534, 65535]) {
                let v = v as u16;
                // A different value per component: v, 65535 - v, v / 2, v ^ 0x5a5a.
                let comps = [v, 65535 - v, v / 2, v ^ 0x5a5a];
                let mut texel = Vec::new();
                for c in comps.iter().take(n) {
                    texel.extend_from_slice(&c.to_le_bytes());
                }
                let rgba = fmt.decode(&texel);
                let colour = match n {
                    1 => [rgba[0]; 4],
                    2 => [rgba[0], rgba[0], rgba[0], rgba[3]],
                    _ => rgba,
                };
                fmt.encode(colour, &mut buf);
                assert_eq!(buf, texel, "{fmt} {comps:?}");
            }
        }
        // Little-endian on disk: 0x1234 is stored as 34 12.
        let mut b = [0u8; 2];
        TexelFormat::L16.encode([0x1234 as f32 / 65535.0; 4], &mut b);
        assert_eq!(b, [0x34, 0x12]);
    }

    #[test]
    fn block_formats_are_named_and_sized_in_whole_blocks() {
        let all = [TexelFormat::BC1, TexelFormat::BC4, TexelFormat::BC5, TexelFormat::BC7];
        let names: Vec<String> = all.iter().map(|f| f.short_name()).collect();
        assert_eq!(names, ["bc1", "bc4", "bc5", "bc7"]);
        assert_eq!(all.map(|f| f.bytes_per_texel()), [8, 8, 16, 16]);
        assert_eq!(all.map(|f| f.components.count()), [3, 1, 2, 4]);
        for f in all {
            let b = f.block().unwrap();
            assert_eq!((b.format(), Bc::parse(b.name()), f.block_edge()), (f, Ok(b), 4));
        }
        // A 256 x 256 tile: 64 x 64 blocks; BC1 is an eighth of RGBA8, BC7 a quarter.
        assert_eq!(TexelFormat::BC1.bytes_for(256, 256), Some(64 * 64 * 8));
        assert_eq!(TexelFormat::RGBA8.bytes_for(256, 256), Some(256 * 256 * 4));
        assert_eq!(TexelFormat::BC7.bytes_for(256, 256), Some(256 * 256));
        // A partial block at an edge is a whole block: 5 x 3 texels are 2 x 1 blocks.
        assert_eq!(TexelFormat::BC4.bytes_for(5, 3), Some(16));
        assert_eq!(TexelFormat::BC5.bytes_for(1, 1), Some(16));
        assert_eq!(TexelFormat::RGB8.bytes_for(5, 3), Some(45));
        assert_eq!(TexelFormat::RGB8.block(), None);
        assert_eq!(TexelFormat::BC7.bytes_for(u64::MAX, u64::MAX), None);
        assert!(Bc::parse("dxt1").unwrap_err().contains("bc1, bc4, bc5 or bc7"));
    }

    #[test]
    fn encode_then_decode_round_trips_within_quantisation() {
        for fmt in [TexelFormat::RGB8, TexelFormat::RGBA8, TexelFormat::RGB565, TexelFormat::RGBA5551] {
            let mut buf = vec![0u8; fmt.bytes_per_texel() as usize];
            let colour = [0.25, 0.5, 0.75, 1.0];
            fmt.encode(colour, &mut buf);
            let back = fmt.decode(&buf);
            for i in 0..3 {
                assert!((back[i] - colour[i]).abs() < 1.0 / 30.0, "{fmt}: {back:?}");
            }
        }
    }
}
