//! Texel format names and numbers: `ext_format`, `int_format` and `img_format` values
//! (docs/PERFORMER-REFERENCE.md §1.3), resolved to OpenGL enum values and to a [`TexelFormat`].

use crate::texel::{Bc, ComponentType, Components, PackedType, TexelFormat};

/// External (on-disk component type) format names with their GL value.
pub(crate) const EXT_FORMATS: &[(&str, u32)] = &[
    ("PFTEX_PACK_8", 5121),
    ("PFTEX_UNSIGNED_BYTE", 5121),
    ("GL_UNSIGNED_BYTE", 5121),
    ("PFTEX_BYTE", 5120),
    ("GL_BYTE", 5120),
    ("PFTEX_PACK_16", 5123),
    ("PFTEX_UNSIGNED_SHORT", 5123),
    ("GL_UNSIGNED_SHORT", 5123),
    ("PFTEX_SHORT", 5122),
    ("GL_SHORT", 5122),
    ("PFTEX_INT", 5124),
    ("GL_INT", 5124),
    ("PFTEX_UNSIGNED_INT", 5125),
    ("GL_UNSIGNED_INT", 5125),
    ("PFTEX_FLOAT", 5126),
    ("GL_FLOAT", 5126),
    ("PFTEX_PACK_USHORT_5_6_5", 34817),
    ("PFTEX_PACK_USHORT_4_4_4_4", 34818),
    ("PFTEX_UNSIGNED_SHORT_5_5_5_1", 32820),
    ("GL_UNSIGNED_SHORT_5_5_5_1_EXT", 32820),
    ("GL_UNSIGNED_SHORT_4_4_4_4_EXT", 32819),
    ("GL_UNSIGNED_BYTE_3_3_2_EXT", 32818),
    ("GL_UNSIGNED_INT_8_8_8_8_EXT", 32821),
    ("GL_UNSIGNED_INT_10_10_10_2_EXT", 32822),
    ("GL_BITMAP", 6656),
    // This crate's extension (docs/CONFIG.md, "Block-compressed tiles"): tiles stored as BCn
    // blocks, each name's value the OpenGL compressed format's.
    ("CLIPMAP_BC1", 33776),
    ("CLIPMAP_BC4", 36283),
    ("CLIPMAP_BC5", 36285),
    ("CLIPMAP_BC7", 36492),
];

/// Internal (hardware) format names with their GL value.
pub(crate) const INT_FORMATS: &[(&str, u32)] = &[
    ("PFTEX_I_8", 32832),
    // The OpenGL compressed formats of this crate's block-compressed tiles.
    ("GL_COMPRESSED_RGB_S3TC_DXT1_EXT", 33776),
    ("GL_COMPRESSED_RED_RGTC1", 36283),
    ("GL_COMPRESSED_RG_RGTC2", 36285),
    ("GL_COMPRESSED_RGBA_BPTC_UNORM", 36492),
    ("PFTEX_I_16", 32845),
    ("PFTEX_IA_8", 32837),
    ("PFTEX_I_12A_4", 32838),
    ("PFTEX_IA_12", 32839),
    ("PFTEX_RGB_4", 32847),
    ("PFTEX_RGB_5", 32848),
    ("PFTEX_RGB_8", 32849),
    ("PFTEX_RGB_12", 32851),
    ("PFTEX_RGBA_8", 32856),
    ("PFTEX_RGBA_12", 32858),
    ("PFTEX_RGB5_A1", 32855),
    ("PFTEX_RGBA_4", 32854),
    ("PFTEX_DEFAULT", 32767),
    ("GL_ALPHA", 6406),
    ("GL_ALPHA4_EXT", 32827),
    ("GL_ALPHA8_EXT", 32828),
    ("GL_ALPHA12_EXT", 32829),
    ("GL_ALPHA16_EXT", 32830),
    ("GL_LUMINANCE", 6409),
    ("GL_LUMINANCE4_EXT", 32831),
    ("GL_LUMINANCE8_EXT", 32832),
    ("GL_LUMINANCE12_EXT", 32833),
    ("GL_LUMINANCE16_EXT", 32834),
    ("GL_LUMINANCE_ALPHA", 6410),
    ("GL_LUMINANCE4_ALPHA4_EXT", 32835),
    ("GL_LUMINANCE6_ALPHA2_EXT", 32836),
    ("GL_LUMINANCE8_ALPHA8_EXT", 32837),
    ("GL_LUMINANCE12_ALPHA4_EXT", 32838),
    ("GL_LUMINANCE12_ALPHA12_EXT", 32839),
    ("GL_LUMINANCE16_ALPHA16_EXT", 32840),
    ("GL_INTENSITY_EXT", 32841),
    ("GL_INTENSITY4_EXT", 32842),
    ("GL_INTENSITY8_EXT", 32843),
    ("GL_INTENSITY12_EXT", 32844),
    ("GL_INTENSITY16_EXT", 32845),
    ("GL_RGB", 6407),
    ("GL_RGB2_EXT", 32846),
    ("GL_RGB4_EXT", 32847),
    ("GL_RGB5_EXT", 32848),
    ("GL_RGB8_EXT", 32849),
    ("GL_RGB10_EXT", 32850),
    ("GL_RGB12_EXT", 32851),
    ("GL_RGB16_EXT", 32852),
    ("GL_RGBA2_EXT", 32853),
    ("GL_RGBA4_EXT", 32854),
    ("GL_RGB5_A1_EXT", 32855),
    ("GL_RGBA", 6408),
    ("GL_RGBA8_EXT", 32856),
    ("GL_RGB10_A2_EXT", 32857),
    ("GL_RGBA12_EXT", 32858),
    ("GL_RGBA16_EXT", 32859),
];

/// Image (component layout) format names with their GL value and component count.
pub(crate) const IMG_FORMATS: &[(&str, u32, u32)] = &[
    ("PFTEX_RGB", 6407, 3),
    ("GL_RGB", 6407, 3),
    ("PFTEX_RGBA", 6408, 4),
    ("GL_RGBA", 6408, 4),
    ("PFTEX_LUMINANCE", 6409, 1),
    ("GL_LUMINANCE", 6409, 1),
    ("PFTEX_LUMINANCE_ALPHA", 6410, 2),
    ("GL_LUMINANCE_ALPHA", 6410, 2),
    ("GL_RED", 6403, 1),
    ("GL_GREEN", 6404, 1),
    ("GL_BLUE", 6405, 1),
    ("GL_ALPHA", 6406, 1),
    ("GL_ABGR_EXT", 32768, 4),
];

/// Which of the three format tokens.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Which {
    /// `ext_format`.
    Ext,
    /// `int_format`.
    Int,
    /// `img_format`.
    Img,
}

/// A format value as resolved.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct FormatValue {
    /// As written.
    pub written: String,
    /// The OpenGL enum value.
    pub value: u32,
    /// True when written as a number.
    pub numeric: bool,
}

/// Why a format value was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FormatRefusal {
    /// A name not in the table; carries the closest known name.
    UnknownName(Option<&'static str>),
    /// A number that is negative or names no known format.
    UnknownNumber,
}

fn table(which: Which) -> Vec<(&'static str, u32)> {
    match which {
        Which::Ext => EXT_FORMATS.to_vec(),
        Which::Int => INT_FORMATS.to_vec(),
        Which::Img => IMG_FORMATS.iter().map(|&(n, v, _)| (n, v)).collect(),
    }
}

/// Resolves a format word. Numbers are accepted for all three tokens (3.0 refuses numbers for
/// `img_format` although its manual allows them; the plan notes that as a portability issue).
/// Numeric `int_format` values are taken as they are (any hardware enum); numeric `ext_format`
/// and `img_format` values must name a known format, because the texel size depends on them.
pub fn resolve(which: Which, word: &str) -> Result<FormatValue, FormatRefusal> {
    let t = table(which);
    if let Some(&(_, v)) = t.iter().find(|(n, _)| *n == word) {
        return Ok(FormatValue { written: word.to_string(), value: v, numeric: false });
    }
    if word.starts_with(|c: char| c.is_ascii_digit() || c == '-' || c == '+') {
        return match word.parse::<i64>() {
            Ok(v) if v >= 0 && v <= u32::MAX as i64 => {
                let v = v as u32;
                if which == Which::Int || t.iter().any(|&(_, tv)| tv == v) {
                    Ok(FormatValue { written: word.to_string(), value: v, numeric: true })
                } else {
                    Err(FormatRefusal::UnknownNumber)
                }
            }
            _ => Err(FormatRefusal::UnknownNumber),
        };
    }
    let best = t
        .iter()
        .map(|&(n, _)| (strsim::jaro_winkler(&word.to_ascii_uppercase(), n), n))
        .filter(|(s, _)| *s > 0.8)
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, n)| n);
    Err(FormatRefusal::UnknownName(best))
}

/// Component count of an image format value.
pub(crate) fn components_of(img_value: u32) -> Option<u32> {
    IMG_FORMATS.iter().find(|&&(_, v, _)| v == img_value).map(|&(_, _, c)| c)
}

/// The `ext_format`, `int_format` and `img_format` names of a texel format, as `clipprep` writes
/// them and a COG's configuration must give them, or `None` for a format without names here.
pub fn names_of(f: TexelFormat) -> Option<(&'static str, &'static str, &'static str)> {
    Some(match (f.components, f.ctype) {
        (Components::One, ComponentType::U8) => ("PFTEX_UNSIGNED_BYTE", "GL_LUMINANCE8_EXT", "PFTEX_LUMINANCE"),
        (Components::Three, ComponentType::U8) => ("PFTEX_UNSIGNED_BYTE", "PFTEX_RGB_8", "PFTEX_RGB"),
        // Block-compressed tiles (this crate's extension, docs/CONFIG.md).
        (Components::Three, ComponentType::Bc(Bc::Bc1)) => {
            ("CLIPMAP_BC1", "GL_COMPRESSED_RGB_S3TC_DXT1_EXT", "PFTEX_RGB")
        }
        (Components::One, ComponentType::Bc(Bc::Bc4)) => ("CLIPMAP_BC4", "GL_COMPRESSED_RED_RGTC1", "PFTEX_LUMINANCE"),
        (Components::Two, ComponentType::Bc(Bc::Bc5)) => {
            ("CLIPMAP_BC5", "GL_COMPRESSED_RG_RGTC2", "PFTEX_LUMINANCE_ALPHA")
        }
        (Components::Four, ComponentType::Bc(Bc::Bc7)) => {
            ("CLIPMAP_BC7", "GL_COMPRESSED_RGBA_BPTC_UNORM", "PFTEX_RGBA")
        }
        (Components::Four, ComponentType::U8) => ("PFTEX_UNSIGNED_BYTE", "PFTEX_RGBA_8", "PFTEX_RGBA"),
        (Components::Three, ComponentType::Packed(PackedType::Rgb565)) => {
            ("PFTEX_PACK_USHORT_5_6_5", "PFTEX_RGB_5", "PFTEX_RGB")
        }
        (Components::Four, ComponentType::Packed(PackedType::Rgba5551)) => {
            ("PFTEX_UNSIGNED_SHORT_5_5_5_1", "PFTEX_RGB5_A1", "PFTEX_RGBA")
        }
        (Components::One, ComponentType::U16) => ("PFTEX_UNSIGNED_SHORT", "GL_LUMINANCE16_EXT", "PFTEX_LUMINANCE"),
        // Heights (docs/ELEVATION.md): 32-bit float metres, signed 16-bit steps.
        (Components::One, ComponentType::F32) => ("GL_FLOAT", "GL_LUMINANCE", "PFTEX_LUMINANCE"),
        (Components::One, ComponentType::I16) => ("GL_SHORT", "GL_LUMINANCE16_EXT", "PFTEX_LUMINANCE"),
        (Components::Two, ComponentType::U16) => {
            ("PFTEX_UNSIGNED_SHORT", "GL_LUMINANCE16_ALPHA16_EXT", "PFTEX_LUMINANCE_ALPHA")
        }
        (Components::Three, ComponentType::U16) => ("PFTEX_UNSIGNED_SHORT", "GL_RGB16_EXT", "PFTEX_RGB"),
        (Components::Four, ComponentType::U16) => ("PFTEX_UNSIGNED_SHORT", "GL_RGBA16_EXT", "PFTEX_RGBA"),
        _ => return None,
    })
}

/// The texel format for an external type and image layout. `None` for `GL_BITMAP`, which has no
/// meaning for tiles.
pub fn texel_format(ext_value: u32, img_value: u32) -> Option<TexelFormat> {
    let components = Components::from_count(components_of(img_value)?)?;
    // A block format: its components are the format's own (an image format of another count
    // names no format).
    let bc = match ext_value {
        33776 => Some(Bc::Bc1),
        36283 => Some(Bc::Bc4),
        36285 => Some(Bc::Bc5),
        36492 => Some(Bc::Bc7),
        _ => None,
    };
    if let Some(bc) = bc {
        return (bc.format().components == components).then(|| bc.format());
    }
    let ctype = match ext_value {
        5121 => ComponentType::U8,
        5120 => ComponentType::I8,
        5123 => ComponentType::U16,
        5122 => ComponentType::I16,
        5124 => ComponentType::I32,
        5125 => ComponentType::U32,
        5126 => ComponentType::F32,
        34817 => ComponentType::Packed(PackedType::Rgb565),
        34818 | 32819 => ComponentType::Packed(PackedType::Rgba4444),
        32820 => ComponentType::Packed(PackedType::Rgba5551),
        32818 => ComponentType::Packed(PackedType::Rgb332),
        32821 => ComponentType::Packed(PackedType::Rgba8888),
        32822 => ComponentType::Packed(PackedType::Rgb10A2),
        _ => return None,
    };
    Some(TexelFormat { components, ctype })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_numbers_resolve() {
        assert_eq!(resolve(Which::Ext, "PFTEX_PACK_8").unwrap().value, 5121);
        assert_eq!(resolve(Which::Ext, "5121").unwrap().value, 5121);
        assert_eq!(resolve(Which::Int, "PFTEX_RGB_8").unwrap().value, 32849);
        assert_eq!(resolve(Which::Int, "12345").unwrap().value, 12345);
        assert_eq!(resolve(Which::Img, "PFTEX_RGB").unwrap().value, 6407);
        assert_eq!(resolve(Which::Ext, "-5"), Err(FormatRefusal::UnknownNumber));
        assert_eq!(resolve(Which::Ext, "99"), Err(FormatRefusal::UnknownNumber));
        assert_eq!(resolve(Which::Img, "PFTEX_RBG"), Err(FormatRefusal::UnknownName(Some("PFTEX_RGB"))));
    }

    #[test]
    fn texel_sizes_follow_performer() {
        assert_eq!(texel_format(5121, 6407).unwrap().bytes_per_texel(), 3);
        assert_eq!(texel_format(32820, 6408).unwrap().bytes_per_texel(), 2);
        assert_eq!(texel_format(5123, 6408).unwrap().bytes_per_texel(), 8);
        assert_eq!(texel_format(6656, 6408), None);
        // Block formats: the bytes of one 4 x 4 block; an image format of another component
        // count names none.
        assert_eq!(texel_format(33776, 6407), Some(TexelFormat::BC1));
        assert_eq!(texel_format(36492, 6408).unwrap().bytes_per_texel(), 16);
        assert_eq!(texel_format(33776, 6408), None);
    }
}
