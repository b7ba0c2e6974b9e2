//! The georef block of the mapping (docs/SHM.md, "Georef block"): where a texture lies on the
//! Earth, as raw numbers. The header's block carries the CRS (EPSG code, definition), the flags
//! and level 0's GDAL geotransform; each level's descriptor carries that level's affine terms.
//!
//! The mapping layer gives the numbers no meaning beyond their checks: the CRS is not parsed and
//! no projection is computed here. Every level is anchored at the texture's south-west corner
//! (t counts up from the south, and a level whose height was rounded down drops level 0's
//! northmost rows), so the corner shared by every level is the south-west one, `origin + H0 x
//! ([2], [5])` of level 0 ([`GeorefBlock::south_west`]); texel (s, t) of level k lies at
//! `SW + s ([1], [4]) - t ([2], [5])` of level k's terms ([`GeorefBlock::map_of_texel`]).

use crate::layout::{self, desc, georef as g, header};

/// The georef block's values: the writer's input and what a reader finds.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct GeorefBlock {
    /// The CRS's EPSG code, `None` when none is known.
    pub epsg: Option<u32>,
    /// The texture spans 360 degrees of longitude: s wraps modulo each level's width.
    pub wraps: bool,
    /// The CRS definition: a PROJ string or WKT, at most 1024 bytes of UTF-8 without NUL; may be
    /// empty (only the EPSG code, or a CRS nobody named).
    pub definition: String,
    /// Level 0's GDAL geotransform terms 0 and 3: the map coordinates of level 0's north-west
    /// corner. Only level 0's: a level whose height was rounded down has its north edge further
    /// south; the corner every level shares is the south-west one ([`Self::south_west`]).
    pub origin: [f64; 2],
    /// Each level's GDAL geotransform terms 1, 2, 4 and 5 (over that level's pixel / line), one
    /// entry per level, level 0 first.
    pub levels: Vec<[f64; 4]>,
}

/// Names a byte of the georef block (relative to the block) by its field, for the readers'
/// messages.
pub fn field_name(at: usize) -> &'static str {
    match at {
        0..4 => "present",
        4..8 => "EPSG code",
        8..12 => "flags",
        12..16 => "definition length",
        16..24 => "origin x",
        24..32 => "origin y",
        32..40 => "geotransform [1]",
        40..48 => "geotransform [2]",
        48..56 => "geotransform [4]",
        56..64 => "geotransform [5]",
        _ => "definition",
    }
}

/// The GDAL term number of the i-th of the four affine terms.
const TERM_NAMES: [&str; 4] = ["[1]", "[2]", "[4]", "[5]"];

impl GeorefBlock {
    /// The map coordinates of the texture's south-west corner, the corner every level shares:
    /// `origin + height0 x ([2], [5])` of level 0, `height0` the level-0 height in texels
    /// (header offset 48). `None` for a block without level 0.
    pub fn south_west(&self, height0: u64) -> Option<[f64; 2]> {
        let [_, b, _, e] = *self.levels.first()?;
        let h = height0 as f64;
        Some([self.origin[0] + h * b, self.origin[1] + h * e])
    }

    /// The GDAL geotransform of `level` (`[x0, a, b, y0, d, e]`: map x = x0 + a pixel + b line,
    /// map y = y0 + d pixel + e line, over the level's own pixel / line, line 0 its north edge):
    /// `[SWx - height b, a, b, SWy - height e, d, e]` with SW [`Self::south_west`], `height0` the
    /// level-0 height and `height` the level's (descriptor offset 8). `None` for a level the block
    /// has no entry for.
    pub fn geotransform(&self, level: usize, height0: u64, height: u64) -> Option<[f64; 6]> {
        let [a, b, d, e] = *self.levels.get(level)?;
        let [x, y] = self.south_west(height0)?;
        let h = height as f64;
        Some([x - h * b, a, b, y - h * e, d, e])
    }

    /// The map coordinates of the continuous texel position (s, t) of `level` (t counts up from
    /// the south): `SW + s ([1], [4]) - t ([2], [5])` with the level's terms and SW
    /// [`Self::south_west`] of `height0`, the level-0 height in texels. `None` for a level the
    /// block has no entry for. ([`crate::Client::map_of_texel`] takes the height from the mapping.)
    pub fn map_of_texel(&self, level: usize, height0: u64, s: f64, t: f64) -> Option<[f64; 2]> {
        let [a, b, d, e] = *self.levels.get(level)?;
        let [x, y] = self.south_west(height0)?;
        Some([x + a * s - b * t, y + d * s - e * t])
    }

    /// Checks the block before a writer publishes it for a texture of `levels` levels: finite
    /// numbers, every level's transform invertible, a definition of at most 1024 bytes without
    /// NUL, an EPSG code other than 0, one entry per level. The error says what and how to fix.
    pub fn check(&self, levels: usize) -> Result<(), String> {
        if self.levels.len() != levels {
            return Err(format!(
                "{} levels of affine terms for a texture of {levels} levels: give one entry (GDAL geotransform terms 1, 2, 4, 5) per level",
                self.levels.len()
            ));
        }
        if self.epsg == Some(0) {
            return Err("EPSG code 0: give None when no EPSG code is known".into());
        }
        let n = self.definition.len();
        if n > layout::GEOREF_DEFINITION_MAX {
            return Err(format!(
                "a CRS definition of {n} bytes: at most {} fit; give a shorter one (a PROJ string, or WKT without its optional parts)",
                layout::GEOREF_DEFINITION_MAX
            ));
        }
        if let Some(i) = self.definition.bytes().position(|b| b == 0) {
            return Err(format!("the CRS definition has a NUL at byte {i}: remove it (readers in C end it there)"));
        }
        for (i, v) in self.origin.iter().enumerate() {
            if !v.is_finite() {
                return Err(format!("origin {}: found {v}, expected a finite number", ["x", "y"][i]));
            }
        }
        for (k, t) in self.levels.iter().enumerate() {
            if let Some(i) = t.iter().position(|v| !v.is_finite()) {
                return Err(format!("level {k}: geotransform {} is {}, expected a finite number", TERM_NAMES[i], t[i]));
            }
            if let Err(d) = determinant(t) {
                return Err(format!(
                    "level {k}: geotransform [1] x [5] - [2] x [4] = {d}, expected a finite number other than 0 (the level's texels must span an area)"
                ));
            }
        }
        Ok(())
    }

    /// The block's bytes (at [`header::GEOREF`]) and each level's four descriptor words (at
    /// [`desc::GEOREF`]), as a writer stores them. The block must have passed [`check`](Self::check).
    pub fn encode(&self) -> (Vec<u8>, Vec<[u64; 4]>) {
        let mut b = vec![0u8; layout::GEOREF_BYTES];
        let mut put = |at: usize, bytes: &[u8]| b[at..at + bytes.len()].copy_from_slice(bytes);
        put(g::PRESENT, &1u32.to_le_bytes());
        put(g::EPSG, &self.epsg.unwrap_or(0).to_le_bytes());
        put(g::FLAGS, &(if self.wraps { g::WRAPS } else { 0 }).to_le_bytes());
        put(g::DEFINITION_LEN, &(self.definition.len() as u32).to_le_bytes());
        put(g::ORIGIN_X, &self.origin[0].to_le_bytes());
        put(g::ORIGIN_Y, &self.origin[1].to_le_bytes());
        for (i, v) in self.levels[0].iter().enumerate() {
            put(g::TERMS + 8 * i, &v.to_le_bytes());
        }
        put(g::DEFINITION, self.definition.as_bytes());
        (b, self.levels.iter().map(|t| t.map(f64::to_bits)).collect())
    }

    /// Reads and checks a georef block as a reader finds it: `block` the block's bytes, `descs`
    /// each level's four descriptor words (level 0 first, one per level of the mapping).
    /// `Ok(None)` when the block is all zero (no georeferencing, or a writer from before the
    /// block); `Err` naming the byte offset and field, what was found and what was expected.
    pub fn read(block: &[u8], descs: &[[u64; 4]]) -> Result<Option<GeorefBlock>, String> {
        assert_eq!(block.len(), layout::GEOREF_BYTES, "the whole block");
        let at = |field: usize| format!("georef block, byte {} ({})", header::GEOREF + field, field_name(field));
        let desc_at = |k: usize, i: usize| {
            format!(
                "level {k} descriptor, byte {} (georef {})",
                header::LEVEL_DESCS + k * layout::DESC_BYTES + desc::GEOREF + 8 * i,
                TERM_NAMES[i]
            )
        };
        let u32_at = |o: usize| u32::from_le_bytes(block[o..o + 4].try_into().expect("4 bytes"));
        let f64_at = |o: usize| f64::from_le_bytes(block[o..o + 8].try_into().expect("8 bytes"));
        match u32_at(g::PRESENT) {
            0 => {
                if let Some(i) = block.iter().position(|&b| b != 0) {
                    return Err(format!(
                        "{}: found byte {:#04x}, expected 0: the block says the texture has no georeferencing (present 0), so it must be all zero",
                        at(i),
                        block[i]
                    ));
                }
                for (k, d) in descs.iter().enumerate() {
                    if let Some(i) = d.iter().position(|&w| w != 0) {
                        return Err(format!(
                            "{}: found {}, expected 0: the texture has no georeferencing (georef block all zero)",
                            desc_at(k, i),
                            f64::from_bits(d[i])
                        ));
                    }
                }
                return Ok(None);
            }
            1 => {}
            other => {
                return Err(format!(
                    "{}: found {other}, expected 0 (no georeferencing) or 1 (georeferenced)",
                    at(g::PRESENT)
                ))
            }
        }
        let flags = u32_at(g::FLAGS);
        if flags & !g::KNOWN_FLAGS != 0 {
            return Err(format!(
                "{}: found {flags:#x}, expected only bit 0 (wraps in longitude): a bit this reader does not know",
                at(g::FLAGS)
            ));
        }
        let len = u32_at(g::DEFINITION_LEN) as usize;
        if len > layout::GEOREF_DEFINITION_MAX {
            return Err(format!(
                "{}: found {len}, expected at most {}",
                at(g::DEFINITION_LEN),
                layout::GEOREF_DEFINITION_MAX
            ));
        }
        let mut values = [0.0; 6];
        for (i, o) in
            [g::ORIGIN_X, g::ORIGIN_Y, g::TERMS, g::TERMS + 8, g::TERMS + 16, g::TERMS + 24].into_iter().enumerate()
        {
            values[i] = f64_at(o);
            if !values[i].is_finite() {
                return Err(format!("{}: found {}, expected a finite number", at(o), values[i]));
            }
        }
        let level0 = [values[2], values[3], values[4], values[5]];
        if let Err(d) = determinant(&level0) {
            return Err(format!(
                "{}: [1] x [5] - [2] x [4] = {d}, expected a finite number other than 0 (texels must span an area)",
                at(g::TERMS)
            ));
        }
        let text = &block[g::DEFINITION..g::DEFINITION + len];
        let definition = match std::str::from_utf8(text) {
            Ok(s) => s,
            Err(e) => {
                let i = e.valid_up_to();
                return Err(format!(
                    "{}: byte {i} of the definition ({:#04x}) is not UTF-8, expected UTF-8 text (a PROJ string or WKT)",
                    at(g::DEFINITION + i),
                    text[i]
                ));
            }
        };
        if let Some(i) = text.iter().position(|&b| b == 0) {
            return Err(format!(
                "{}: a NUL at byte {i} of the {len}-byte definition, expected text without NUL",
                at(g::DEFINITION + i)
            ));
        }
        if let Some(i) = block[g::DEFINITION + len..].iter().position(|&b| b != 0) {
            let o = g::DEFINITION + len + i;
            return Err(format!(
                "{}: found byte {:#04x} after the definition's {len} bytes, expected 0",
                at(o),
                block[o]
            ));
        }
        let mut levels = Vec::with_capacity(descs.len());
        for (k, d) in descs.iter().enumerate() {
            let t = d.map(f64::from_bits);
            if let Some(i) = t.iter().position(|v| !v.is_finite()) {
                return Err(format!("{}: found {}, expected a finite number", desc_at(k, i), t[i]));
            }
            if let Err(det) = determinant(&t) {
                return Err(format!(
                    "{}: [1] x [5] - [2] x [4] = {det}, expected a finite number other than 0 (the level's texels must span an area)",
                    desc_at(k, 0)
                ));
            }
            if k == 0 {
                if let Some(i) = (0..4).find(|&i| d[i] != level0[i].to_bits()) {
                    return Err(format!(
                        "{}: found {}, expected {}, the georef block's level-0 term (byte {})",
                        desc_at(0, i),
                        t[i],
                        level0[i],
                        header::GEOREF + g::TERMS + 8 * i
                    ));
                }
            }
            levels.push(t);
        }
        let epsg = u32_at(g::EPSG);
        Ok(Some(GeorefBlock {
            epsg: (epsg != 0).then_some(epsg),
            wraps: flags & g::WRAPS != 0,
            definition: definition.to_string(),
            origin: [values[0], values[1]],
            levels,
        }))
    }
}

/// `[1] x [5] - [2] x [4]` of a level's terms: `Ok` when finite and not 0, else `Err` with it.
fn determinant(t: &[f64; 4]) -> Result<f64, f64> {
    let d = t[0] * t[3] - t[1] * t[2];
    if d.is_finite() && d != 0.0 {
        Ok(d)
    } else {
        Err(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A global EPSG:4326 texture of 3 levels, 4096 x 2048 at level 0.
    fn global() -> GeorefBlock {
        let l0 = 360.0 / 4096.0;
        GeorefBlock {
            epsg: Some(4326),
            wraps: true,
            definition: "+proj=longlat +datum=WGS84 +no_defs".into(),
            origin: [-180.0, 90.0],
            levels: (0..3).map(|k| [l0 * f64::from(1 << k), 0.0, 0.0, -l0 * f64::from(1 << k)]).collect(),
        }
    }

    fn split(b: &GeorefBlock) -> (Vec<u8>, Vec<[u64; 4]>) {
        b.encode()
    }

    #[test]
    fn the_block_fits_below_the_header_bytes_and_after_the_heights_block() {
        const { assert!(header::GEOREF == 6528 && layout::GEOREF_BYTES == 1088) };
        const { assert!(header::END == 7616 && header::END <= 8192) };
        assert_eq!(desc::GEOREF + 32, 120, "the descriptor's terms leave 8 reserved bytes");
    }

    #[test]
    fn a_block_round_trips_through_its_bytes() {
        for b in [
            global(),
            GeorefBlock { epsg: None, wraps: false, definition: String::new(), ..global() },
            GeorefBlock { definition: "é".repeat(512), ..global() },
            // A rotated UTM grid.
            GeorefBlock {
                epsg: Some(32633),
                wraps: false,
                definition: "+proj=utm +zone=33 +datum=WGS84".into(),
                origin: [500000.0, 5_000_000.0],
                levels: vec![[0.5, 0.1, 0.1, -0.5]],
            },
        ] {
            b.check(b.levels.len()).unwrap();
            let (block, descs) = split(&b);
            assert_eq!(GeorefBlock::read(&block, &descs), Ok(Some(b.clone())));
        }
    }

    #[test]
    fn an_all_zero_block_reads_as_none() {
        let zero = vec![0u8; layout::GEOREF_BYTES];
        assert_eq!(GeorefBlock::read(&zero, &[[0; 4]; 3]), Ok(None));
        let e = GeorefBlock::read(&zero, &[[0; 4], [0, 0, 1.0f64.to_bits(), 0]]).unwrap_err();
        assert!(e.contains("level 1 descriptor, byte 2472 (georef [4])") && e.contains("expected 0"), "{e}");
        let mut b = zero.clone();
        b[700] = 7;
        let e = GeorefBlock::read(&b, &[[0; 4]]).unwrap_err();
        assert!(e.contains("byte 7228 (definition)") && e.contains("found byte 0x07"), "{e}");
    }

    #[test]
    fn a_texel_lies_at_pixel_s_and_line_height_minus_t() {
        let b = global();
        // Level 0 is 4096 x 2048: texel (0, 0) is the south-west corner's texel, its lower-left
        // corner at (-180, -90); texel (2048, 1024)'s lower-left corner is (0, 0).
        assert_eq!(b.south_west(2048), Some([-180.0, -90.0]));
        assert_eq!(b.map_of_texel(0, 2048, 0.0, 0.0), Some([-180.0, -90.0]));
        assert_eq!(b.map_of_texel(0, 2048, 2048.0, 1024.0), Some([0.0, 0.0]));
        assert_eq!(b.map_of_texel(1, 2048, 2048.0, 1024.0), Some([180.0, 90.0]), "level 1 is 2048 x 1024");
        assert_eq!(b.map_of_texel(3, 2048, 0.0, 0.0), None, "no level 3");
        assert_eq!(b.geotransform(0, 2048, 2048), Some([-180.0, 360.0 / 4096.0, 0.0, 90.0, 0.0, -360.0 / 4096.0]));
        assert_eq!(b.geotransform(1, 2048, 1024), Some([-180.0, 360.0 / 2048.0, 0.0, 90.0, 0.0, -360.0 / 2048.0]));
        assert_eq!(b.geotransform(3, 2048, 256), None, "no level 3");
    }

    /// Levels are anchored at the south-west corner: with a level-0 height of 1001, level 1 is
    /// 500 texels high and covers level 0's 1000 southmost rows, so its north edge lies one
    /// level-0 row south of level 0's, while every level shares the south-west corner.
    #[test]
    fn a_level_whose_height_was_rounded_down_drops_level_0s_northmost_rows() {
        // A rotated grid (exact binary fractions, so the sums are exact): level k's terms are
        // level 0's times 2^k.
        let l0 = [2.0, 0.5, 0.25, -2.0];
        let b = GeorefBlock {
            epsg: None,
            wraps: false,
            definition: String::new(),
            origin: [1000.0, 2000.0],
            levels: (0..3).map(|k| l0.map(|v| v * f64::from(1 << k))).collect(),
        };
        let (h0, heights) = (1001, [1001u64, 500, 250]);
        // The south-west corner: origin + 1001 x ([2], [5]) of level 0.
        let sw = [1000.0 + 1001.0 * 0.5, 2000.0 - 1001.0 * 2.0];
        assert_eq!(b.south_west(h0), Some(sw));
        for k in 0..3 {
            assert_eq!(b.map_of_texel(k, h0, 0.0, 0.0), Some(sw), "level {k} shares the south-west corner");
        }
        // Level 0's north-west corner is the origin; level 1's lies one level-0 row south of it.
        assert_eq!(b.map_of_texel(0, h0, 0.0, 1001.0), Some([1000.0, 2000.0]));
        let one_row_south = [1000.0 + 0.5, 2000.0 - 2.0];
        assert_eq!(b.map_of_texel(1, h0, 0.0, 500.0), Some(one_row_south));
        assert_eq!(b.geotransform(1, h0, 500), Some([one_row_south[0], 4.0, 1.0, one_row_south[1], 0.5, -4.0]));
        assert_eq!(b.geotransform(0, h0, 1001), Some([1000.0, 2.0, 0.5, 2000.0, 0.25, -2.0]), "level 0's own");
        // Level 2 (250 high) covers the 1000 southmost rows too.
        assert_eq!(b.map_of_texel(2, h0, 0.0, 250.0), Some(one_row_south));
        // A level's own geotransform at pixel s, line height - t is map_of_texel at (s, t); a
        // texel of level 1 is two of level 0's along each axis from the shared corner.
        for (k, &h) in heights.iter().enumerate() {
            let [x0, a, bb, y0, d, e] = b.geotransform(k, h0, h).unwrap();
            for (s, t) in [(0.0, 0.0), (3.5, 7.25), (100.0, h as f64)] {
                let line = h as f64 - t;
                assert_eq!(
                    b.map_of_texel(k, h0, s, t),
                    Some([x0 + a * s + bb * line, y0 + d * s + e * line]),
                    "level {k} ({s}, {t})"
                );
            }
        }
        assert_eq!(b.map_of_texel(1, h0, 3.0, 5.0), b.map_of_texel(0, h0, 6.0, 10.0));
    }

    #[test]
    fn the_writer_refuses_what_no_reader_would_take_saying_what_to_fix() {
        let refused = |b: GeorefBlock, levels: usize, words: &[&str]| {
            let e = b.check(levels).expect_err("refused");
            for w in words {
                assert!(e.contains(w), "{e:?} lacks {w:?}");
            }
        };
        refused(global(), 4, &["3 levels", "4 levels", "one entry"]);
        refused(GeorefBlock { epsg: Some(0), ..global() }, 3, &["EPSG code 0", "None"]);
        refused(GeorefBlock { definition: "x".repeat(1025), ..global() }, 3, &["1025 bytes", "at most 1024"]);
        refused(GeorefBlock { definition: "a\0b".into(), ..global() }, 3, &["NUL at byte 1"]);
        refused(GeorefBlock { origin: [f64::NAN, 0.0], ..global() }, 3, &["origin x", "NaN", "finite"]);
        let mut b = global();
        b.levels[2][3] = f64::INFINITY;
        refused(b, 3, &["level 2", "[5]", "inf"]);
        let mut b = global();
        b.levels[1] = [1.0, 2.0, 2.0, 4.0];
        refused(b, 3, &["level 1", "= 0", "span an area"]);
        let mut b = global();
        b.levels[0] = [1e200, 0.0, 0.0, -1e200];
        refused(b, 3, &["level 0", "-inf"]);
        assert_eq!(GeorefBlock { definition: "x".repeat(1024), ..global() }.check(3), Ok(()));
    }

    #[test]
    fn a_reader_refuses_each_bad_field_by_its_byte_and_name() {
        let (good, descs) = split(&global());
        let refused = |block: &[u8], descs: &[[u64; 4]], words: &[&str]| {
            let e = GeorefBlock::read(block, descs).expect_err("refused");
            for w in words {
                assert!(e.contains(w), "{e:?} lacks {w:?}");
            }
        };
        let with = |o: usize, bytes: &[u8]| {
            let mut b = good.clone();
            b[o..o + bytes.len()].copy_from_slice(bytes);
            b
        };
        refused(
            &with(0, &2u32.to_le_bytes()),
            &descs,
            &["byte 6528 (present)", "found 2", "0 (no georeferencing) or 1"],
        );
        refused(&with(8, &2u32.to_le_bytes()), &descs, &["byte 6536 (flags)", "found 0x2", "only bit 0"]);
        refused(
            &with(12, &1025u32.to_le_bytes()),
            &descs,
            &["byte 6540 (definition length)", "found 1025", "at most 1024"],
        );
        refused(&with(16, &f64::NAN.to_le_bytes()), &descs, &["byte 6544 (origin x)", "NaN", "finite"]);
        refused(&with(24, &f64::INFINITY.to_le_bytes()), &descs, &["byte 6552 (origin y)", "inf"]);
        refused(&with(40, &f64::NAN.to_le_bytes()), &descs, &["byte 6568 (geotransform [2])", "NaN"]);
        refused(&with(56, &0f64.to_le_bytes()), &descs, &["byte 6560 (geotransform [1])", "= 0", "other than 0"]);
        refused(&with(64 + 3, &[0xff]), &descs, &["byte 6595 (definition)", "byte 3", "0xff", "UTF-8"]);
        refused(&with(64 + 3, &[0]), &descs, &["byte 6595 (definition)", "NUL at byte 3"]);
        let len = global().definition.len();
        refused(
            &with(64 + len + 5, b"x"),
            &descs,
            &[&format!("byte {} (definition)", 6592 + len + 5), "0x78", "expected 0"],
        );
        let mut d = descs.clone();
        d[1][3] = f64::NAN.to_bits();
        refused(&good, &d, &["level 1 descriptor, byte 2480 (georef [5])", "NaN"]);
        let mut d = descs.clone();
        d[2] = [0; 4];
        refused(&good, &d, &["level 2 descriptor, byte 2584 (georef [1])", "= 0"]);
        let mut d = descs.clone();
        d[0][0] = 1.0f64.to_bits();
        refused(&good, &d, &["level 0 descriptor, byte 2328 (georef [1])", "found 1", "byte 6560"]);
    }
}
