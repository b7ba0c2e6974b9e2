//! The height settings of the `#clipmap` extension (docs/CONFIG.md §17, docs/ELEVATION.md): a
//! `.ct` whose texels are heights says so, with the storage, scale, offset, nodata value and
//! level rule. Performer 3.0 reads the lines as comments and would serve the texels as a plain
//! luminance texture, so each is a portability finding (an error under `validate --strict`).

use super::fields::Reader;
use super::portability;
use crate::config::{Severity, Span};
use crate::height::{HeightFormat, HeightStorage, LevelRule};
use crate::texel::{ComponentType, Components, TexelFormat};

/// The settings a height line may give.
pub(crate) const SETTINGS: [&str; 5] = ["height", "height_scale", "height_offset", "height_nodata", "height_levels"];

/// What the `#clipmap height…` lines of a `.ct` declare.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct HeightPlan {
    /// Storage, scale, offset and nodata value.
    pub format: HeightFormat,
    /// How each coarser level is made from the finer one.
    pub levels: LevelRule,
}

/// The texel format a height storage is served as (`l32f`, `l16`, `l16i`).
pub fn texel_of(storage: HeightStorage) -> TexelFormat {
    let ctype = match storage {
        HeightStorage::F32 => ComponentType::F32,
        HeightStorage::U16 => ComponentType::U16,
        HeightStorage::I16 => ComponentType::I16,
    };
    TexelFormat { components: Components::One, ctype }
}

/// The `img_format` and `ext_format` a `.ct` gives for a height storage.
fn formats_of(storage: HeightStorage) -> &'static str {
    match storage {
        HeightStorage::F32 => "img_format PFTEX_LUMINANCE with ext_format GL_FLOAT",
        HeightStorage::U16 => "img_format PFTEX_LUMINANCE with ext_format GL_UNSIGNED_SHORT",
        HeightStorage::I16 => "img_format PFTEX_LUMINANCE with ext_format GL_SHORT",
    }
}

/// Reads the height lines. `texel` is the texel format the `.ct`'s formats give (`None` when
/// they were refused, reported already). Lines without a value were reported by the paging
/// reader, which reads every `#clipmap` line's shape; `None` when the texture is no height
/// texture or a height line was refused.
pub fn read(r: &mut Reader<'_>, texel: Option<TexelFormat>) -> Option<HeightPlan> {
    let settings = r.extension_settings(&SETTINGS);
    let mut storage: Option<(HeightStorage, Span)> = None;
    let (mut scale, mut offset, mut nodata, mut levels) = (None, None, None, LevelRule::default());
    let mut first_setting: Option<(String, Span)> = None;
    let mut failed = false;
    // Once a file, at its first height line.
    if let Some((key, _)) = settings.first() {
        let d = r
            .diag(
                Severity::Warning,
                "height-extension",
                Some(key.span),
                format!("`#clipmap {}` declares heights, which Performer 3.0 does not know", key.value),
            )
            .hint("Performer reads the `#clipmap` lines as comments and would serve the texels as plain luminance; keep them for this engine (docs/ELEVATION.md)");
        r.push(portability(d));
    }
    for (key, value) in &settings {
        let mut bad = |r: &mut Reader<'_>, expected: &str| {
            r.bad_extension_value(key, value, expected);
            failed = true;
        };
        // Only plain decimal numbers: Rust would read `nan` and `inf` as numbers too.
        let number = |s: &str| {
            let plain = !s.is_empty() && s.chars().all(|c| c.is_ascii_digit() || "+-.eE".contains(c));
            plain.then(|| s.parse::<f64>().ok()).flatten().filter(|v| v.is_finite())
        };
        match key.value.as_str() {
            "height" => match HeightStorage::from_short_name(&value.value) {
                Some(s) => storage = Some((s, key.span)),
                None => bad(
                    r,
                    "`l32f` (32-bit float metres), `l16` (unsigned 16-bit steps) or `l16i` (signed 16-bit steps)",
                ),
            },
            "height_scale" => match number(&value.value) {
                Some(v) => scale = Some((v, key.span)),
                None => bad(r, "the metres of one stored step, a finite decimal number above zero, e.g. 0.01"),
            },
            "height_offset" => match number(&value.value) {
                Some(v) => offset = Some((v, key.span)),
                None => bad(r, "the metres of a stored 0, a finite decimal number, e.g. -11000"),
            },
            "height_nodata" => match (value.value.as_str(), number(&value.value)) {
                ("none", _) => nodata = None,
                (_, Some(v)) => nodata = Some((v, key.span)),
                _ => {
                    bad(r, "the stored value (not metres) that marks a texel without data, e.g. 0 or -32768, or `none`")
                }
            },
            _ => match LevelRule::from_name(&value.value) {
                Some(rule) => levels = rule,
                None => bad(r, "`mean` (nodata left out), `point` (point-registered), `min` or `max`"),
            },
        }
        if key.value != "height" && first_setting.is_none() {
            first_setting = Some((key.value.clone(), key.span));
        }
    }
    let Some((storage, at)) = storage else {
        if let Some((name, span)) = first_setting {
            let d = r
                .diag(
                    Severity::Error,
                    "height-setting-without-height",
                    Some(span),
                    format!("`#clipmap {name}` without `#clipmap height`"),
                )
                .expected("a `#clipmap height l32f|l16|l16i` line declaring the texture's heights")
                .hint("add `#clipmap height l16` (or l32f, l16i), or remove the height settings");
            r.push(d);
        }
        return None;
    };
    if let Some(texel) = texel {
        let want = texel_of(storage);
        if texel != want {
            let d = r
                .diag(
                    Severity::Error,
                    "height-format-mismatch",
                    Some(at),
                    format!("`#clipmap height {storage}` on a texture of {texel} texels"),
                )
                .found(format!("{texel} texels from the `.ct`'s formats"))
                .expected(format!("{want} texels: {}", formats_of(storage)))
                .hint(format!("write {}, or declare the height storage the texels have", formats_of(storage)));
            r.push(d);
            failed = true;
        }
    }
    let (scale_v, scale_at) = scale.unwrap_or((1.0, at));
    let (offset_v, offset_at) = offset.unwrap_or((0.0, at));
    match HeightFormat::new(storage, scale_v, offset_v, nodata.map(|(v, _)| v)) {
        Ok(format) if !failed => Some(HeightPlan { format, levels }),
        Ok(_) => None,
        Err(e) => {
            use crate::height::HeightError as E;
            let span = match e {
                E::Scale { .. } | E::FloatScaled { .. } => scale_at,
                E::Offset { .. } => offset_at,
                E::Nodata { .. } => nodata.map_or(at, |(_, s)| s),
                _ => at,
            };
            let d = r.diag(Severity::Error, "bad-height-format", Some(span), e.to_string());
            r.push(d);
            None
        }
    }
}
