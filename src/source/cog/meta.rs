//! What a COG's samples mean beyond their layout: GDAL's band metadata (scale, offset, unit),
//! heights and their nodata value ([`heights_of`]), and the alpha a colour image gets from its
//! mask or GDAL_NODATA ([`alpha_of`]).

use super::error::CogError;
use super::level::{AlphaRule, Level};
use crate::texel::TexelFormat;
use std::path::Path;

/// The nodata value of 16-bit signed heights with an internal mask and no GDAL_NODATA value:
/// the least value of the samples (GDAL's usual nodata for Int16).
pub const MASK_NODATA_I16: f64 = -32768.0;

/// The nodata value of 32-bit float heights with an internal mask and no GDAL_NODATA value (or
/// `nan`, which the heights block cannot name): the least finite 32-bit float,
/// -3.4028234663852886e38 (GDAL's usual nodata for Float32).
pub const MASK_NODATA_F32: f64 = f32::MIN as f64;

/// The nodata value of 16-bit unsigned heights (samples with a GDAL scale, offset or unit) with
/// an internal mask and no GDAL_NODATA value: the least value of the samples, 0.
pub const MASK_NODATA_U16: f64 = 0.0;

/// What GDAL's metadata (the GDAL_METADATA tag, 42112) says of the first band: its scale and
/// offset (`gdal_translate -a_scale -a_offset`, `gdal_edit.py -scale -offset`) and its unit
/// (`-a_unit`, `SetUnitType`).
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct BandMeta {
    pub(super) scale: Option<f64>,
    pub(super) offset: Option<f64>,
    pub(super) unit: Option<String>,
}

impl BandMeta {
    /// Reads the `<Item name=... sample="0" role="scale|offset|unittype">` items of GDAL's XML; a
    /// value that is no number is refused (the text, then what it is).
    pub(super) fn parse(xml: &str) -> Result<BandMeta, String> {
        let mut meta = BandMeta::default();
        for item in xml.split("<Item ").skip(1) {
            let Some((attrs, rest)) = item.split_once('>') else { continue };
            let Some((value, _)) = rest.split_once("</Item>") else { continue };
            let value = value.trim();
            let has = |a: &str| attrs.split_whitespace().any(|w| w.trim_end_matches('/') == a);
            if !has("sample=\"0\"") {
                continue;
            }
            let number = |what: &str| {
                value
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| format!("the first band's {what} is {value:?}, expected a finite number"))
            };
            if has("role=\"scale\"") {
                meta.scale = Some(number("scale")?);
            } else if has("role=\"offset\"") {
                meta.offset = Some(number("offset")?);
            } else if has("role=\"unittype\"") {
                meta.unit = Some(value.to_string());
            }
        }
        Ok(meta)
    }

    /// Whether GDAL's metadata makes 16-bit unsigned samples heights.
    pub(super) fn says_heights(&self) -> bool {
        self.scale.is_some() || self.offset.is_some() || self.unit.is_some()
    }
}

/// The heights a COG's samples are (docs/ELEVATION.md): 16-bit signed integers (`l16i`) and
/// 32-bit floats (`l32f`) always, and 16-bit unsigned integers (`l16`) when GDAL's metadata
/// gives their band a scale, an offset or a unit (else they are grey); the metres of a stored
/// value are `v x scale + offset` with GDAL's scale and offset (1 and 0 when it gives none;
/// floats take none other). The GDAL_NODATA tag's value is the nodata value (a NaN nodata means
/// none: the mapping's heights block cannot name NaN, and NaN texels stay NaN); other formats
/// are colours, whose GDAL_NODATA gives an alpha instead ([`alpha_of`]). A height image with an
/// internal mask (`masked`) and no nodata value gets [`MASK_NODATA_I16`], [`MASK_NODATA_U16`] or
/// [`MASK_NODATA_F32`], served where the mask is 0.
pub(super) fn heights_of(
    path: &Path,
    format: TexelFormat,
    nodata: Option<&str>,
    masked: bool,
    meta: &BandMeta,
) -> Result<Option<crate::plan::HeightPlan>, CogError> {
    use crate::height::{HeightError, HeightFormat, HeightStorage, LevelRule};
    let storage = match format {
        TexelFormat::L32F => HeightStorage::F32,
        TexelFormat::L16I => HeightStorage::I16,
        TexelFormat::L16 if meta.says_heights() => HeightStorage::U16,
        _ => return Ok(None),
    };
    let refuse = |found: String| {
        CogError::Unsupported {
        path: path.to_path_buf(),
        ifd: 0,
        tag: "GDAL_NODATA (42113)",
        found,
        supported: "a number that is a value of the samples (a whole number in -32768..32767 for 16-bit signed samples, 0..65535 for 16-bit unsigned ones, a finite 32-bit float or nan for floats)",
    }
    };
    let value = match nodata {
        None => None,
        Some(text) => match text.parse::<f64>() {
            Ok(v) if v.is_nan() => None,
            Ok(v) => Some(v),
            Err(_) => return Err(refuse(format!("{text:?}"))),
        },
    };
    let value = match (value, masked, storage) {
        (None, true, HeightStorage::I16) => Some(MASK_NODATA_I16),
        (None, true, HeightStorage::U16) => Some(MASK_NODATA_U16),
        (None, true, _) => Some(MASK_NODATA_F32),
        (v, _, _) => v,
    };
    let (scale, offset) = (meta.scale.unwrap_or(1.0), meta.offset.unwrap_or(0.0));
    let format = HeightFormat::new(storage, scale, offset, value).map_err(|e| match e {
        HeightError::Nodata { .. } => refuse(format!("{} ({e})", nodata.unwrap_or(""))),
        e => CogError::Unsupported {
            path: path.to_path_buf(),
            ifd: 0,
            tag: "GDAL_METADATA (42112)",
            found: format!("scale {scale}, offset {offset} for {storage} heights ({e})"),
            supported: "a scale above 0 and an offset for 16-bit integer heights within the metres heights may take; none (scale 1, offset 0) for 32-bit floats: write the metres themselves (gdal_translate -unscale -ot Float32)",
        },
    })?;
    Ok(Some(crate::plan::HeightPlan { format, levels: LevelRule::Mean }))
}

/// The RGBA variant of a colour format (grey and RGB gain an alpha; RGBA stays).
pub(super) fn rgba_of(format: TexelFormat) -> TexelFormat {
    if format.ctype == crate::texel::ComponentType::U16 {
        TexelFormat::RGBA16
    } else {
        TexelFormat::RGBA8
    }
}

/// Whether a colour image gets an alpha: when its full-resolution image has a mask, or it has a
/// GDAL_NODATA value (which must then be a value of its samples). Heights never do (their
/// nodata is the heights block's).
pub(super) fn alpha_of(
    path: &Path,
    format: TexelFormat,
    nodata: Option<&str>,
    levels: &[Level],
) -> Result<Option<AlphaRule>, CogError> {
    if matches!(format, TexelFormat::L16I | TexelFormat::L32F) {
        return Ok(None);
    }
    let max = if format.ctype == crate::texel::ComponentType::U16 { 65535.0 } else { 255.0 };
    let nodata = match nodata {
        None => None,
        Some(text) => {
            match text.parse::<f64>() {
                Ok(v) if v.fract() == 0.0 && (0.0..=max).contains(&v) => Some(v as u16),
                _ => return Err(CogError::Unsupported {
                    path: path.to_path_buf(),
                    ifd: 0,
                    tag: "GDAL_NODATA (42113)",
                    found: format!("{text:?} with {format} samples"),
                    supported:
                        "a value of the samples: a whole number in 0..=255 for 8-bit samples, 0..=65535 for 16-bit ones",
                }),
            }
        }
    };
    let masked = matches!(levels.first(), Some(Level::Ifd(l)) if l.mask.is_some());
    Ok((masked || nodata.is_some()).then_some(AlphaRule { nodata }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_masked_height_image_without_nodata_gets_the_least_value_of_its_samples() {
        let p = Path::new("dem.tif");
        let nodata = |format, tag, masked| {
            heights_of(p, format, tag, masked, &BandMeta::default())
                .unwrap()
                .and_then(|plan: crate::plan::HeightPlan| plan.format.nodata())
        };
        assert_eq!(nodata(TexelFormat::L16I, None, true), Some(-32768.0));
        assert_eq!(nodata(TexelFormat::L32F, None, true), Some(-3.4028234663852886e38));
        // nan names no value: a mask then takes the chosen one, without a mask there is none.
        assert_eq!(nodata(TexelFormat::L32F, Some("nan"), true), Some(MASK_NODATA_F32));
        assert_eq!(nodata(TexelFormat::L32F, Some("nan"), false), None);
        // GDAL_NODATA, masked or not, is the nodata value.
        assert_eq!(nodata(TexelFormat::L16I, Some("-9999"), true), Some(-9999.0));
        assert_eq!(nodata(TexelFormat::L16I, None, false), None);
        assert!(heights_of(p, TexelFormat::RGB8, None, true, &BandMeta::default()).unwrap().is_none());
    }
}
