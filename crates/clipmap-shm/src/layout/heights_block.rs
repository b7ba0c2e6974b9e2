//! The heights block (offset 6464): whether the texels are heights, with their scale, offset,
//! nodata value and level rule, and the checks every reader makes of it (docs/SHM.md, "Heights
//! block"). Its names are [`super`]'s: `layout::Heights`, `layout::check_heights`, ...

use super::header;

/// Heights block fields, relative to [`header::HEIGHTS`]; static (written before the mapping
/// appears under its name). A mapping whose block is all zero says its texels are not heights:
/// a colour texture, or a mapping of a writer from before the block (docs/SHM.md).
pub mod heights {
    /// `u32` 1 when the texels are heights (the fields below mean something), 0 otherwise.
    pub const IS_HEIGHTS: usize = 0;
    /// `u32` the level rule: 0 mean, 1 point, 2 min, 3 max ([`super::rule_code`]).
    pub const RULE: usize = 4;
    /// `f64` bits: metres of one stored step (1 for `l32f`).
    pub const SCALE: usize = 8;
    /// `f64` bits: metres of a stored 0 (0 for `l32f`).
    pub const OFFSET: usize = 16;
    /// `f64` bits: the stored value (not metres) that marks a texel without data; NaN: none.
    pub const NODATA: usize = 24;
}

/// What the heights block says of a height texture (see [`heights`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Heights {
    /// How the heights are stored (from the texel format code: 11 `l32f`, 7 `l16`, 12 `l16i`).
    pub storage: clipmap_base::height::HeightStorage,
    /// Metres of one stored step.
    pub scale: f64,
    /// Metres of a stored 0.
    pub offset: f64,
    /// The stored value that marks a texel without data (`None`: every texel has data).
    pub nodata: Option<f64>,
    /// How each coarser level is made from the finer one.
    pub levels: clipmap_base::height::LevelRule,
}

impl Heights {
    /// The block's values of a height format and level rule.
    pub fn of(format: &clipmap_base::height::HeightFormat, levels: clipmap_base::height::LevelRule) -> Heights {
        Heights {
            storage: format.storage(),
            scale: format.scale(),
            offset: format.offset(),
            nodata: format.nodata(),
            levels,
        }
    }

    /// The height format the block describes.
    pub fn format(&self) -> clipmap_base::height::HeightFormat {
        clipmap_base::height::HeightFormat::new(self.storage, self.scale, self.offset, self.nodata)
            .expect("checked by check_heights or made from a HeightFormat")
    }
}

/// The heights block's raw values, as a reader finds them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HeightsBlock {
    /// `IS_HEIGHTS`.
    pub is_heights: u32,
    /// `RULE`.
    pub rule: u32,
    /// `SCALE` bits.
    pub scale: u64,
    /// `OFFSET` bits.
    pub offset: u64,
    /// `NODATA` bits.
    pub nodata: u64,
}

/// Checks a heights block against the texel format code: `Ok(None)` for a block all zero (not
/// heights), `Ok(Some)` for a height texture whose values a writer of this layout writes, and
/// `Err` saying where (the byte offset and field), what was found and what was expected.
pub fn check_heights(format_code: u32, b: &HeightsBlock) -> Result<Option<Heights>, String> {
    use clipmap_base::height::{HeightError, HeightFormat, HeightStorage};
    let at = |field: usize, name: &str| format!("heights block, byte {} ({name})", header::HEIGHTS + field);
    match b.is_heights {
        0 => {
            if *b != HeightsBlock::default() {
                return Err(format!(
                    "{}: the texels are not heights but the block is not all zero (rule {}, scale bits {:#x}, offset bits {:#x}, nodata bits {:#x}); expected all zero",
                    at(heights::IS_HEIGHTS, "heights flag"),
                    b.rule,
                    b.scale,
                    b.offset,
                    b.nodata
                ));
            }
            return Ok(None);
        }
        1 => {}
        other => {
            return Err(format!(
                "{}: found {other}, expected 0 (not heights) or 1 (heights)",
                at(heights::IS_HEIGHTS, "heights flag")
            ))
        }
    }
    let storage = match format_code {
        11 => HeightStorage::F32,
        7 => HeightStorage::U16,
        12 => HeightStorage::I16,
        other => {
            return Err(format!(
                "{}: heights on texel format code {other}, expected a height format: 11 (l32f), 7 (l16) or 12 (l16i)",
                at(heights::IS_HEIGHTS, "heights flag")
            ))
        }
    };
    let levels = rule_from_code(b.rule).ok_or_else(|| {
        format!(
            "{}: found {}, expected 0 (mean), 1 (point), 2 (min) or 3 (max)",
            at(heights::RULE, "level rule"),
            b.rule
        )
    })?;
    let (scale, offset, nodata) = (f64::from_bits(b.scale), f64::from_bits(b.offset), f64::from_bits(b.nodata));
    if !scale.is_finite() || scale <= 0.0 {
        return Err(format!("{}: found {scale}, expected a finite number above zero", at(heights::SCALE, "scale")));
    }
    if !offset.is_finite() {
        return Err(format!("{}: found {offset}, expected a finite number", at(heights::OFFSET, "offset")));
    }
    let nodata = (!nodata.is_nan()).then_some(nodata);
    match HeightFormat::new(storage, scale, offset, nodata) {
        Ok(f) => Ok(Some(Heights::of(&f, levels))),
        Err(e) => {
            let (field, name) = match e {
                HeightError::Offset { .. } => (heights::OFFSET, "offset"),
                HeightError::Nodata { .. } => (heights::NODATA, "nodata"),
                _ => (heights::SCALE, "scale"),
            };
            Err(format!("{}: {e}", at(field, name)))
        }
    }
}

/// The heights block's code of a level rule (its place in [`clipmap_base::height::LevelRule::ALL`]).
pub fn rule_code(rule: clipmap_base::height::LevelRule) -> u32 {
    clipmap_base::height::LevelRule::ALL.iter().position(|r| *r == rule).unwrap_or(0) as u32
}

/// The level rule of a heights block code; `None` for a code no writer writes.
pub fn rule_from_code(code: u32) -> Option<clipmap_base::height::LevelRule> {
    clipmap_base::height::LevelRule::ALL.get(code as usize).copied()
}
