//! The COG line of the `#clipmap` extension (docs/CONFIG.md §18, docs/COG.md): a `.ct` or `.ic`
//! whose texels come from a tiled GeoTIFF or Cloud-Optimized GeoTIFF served as it is, named by
//! `#clipmap cog PATH_OR_URL`. Performer 3.0 reads the line as a comment and would read the
//! tile files the rest of the configuration names (none exist for a COG), so the line is a
//! portability note (an error under `validate --strict`).
//!
//! The rest of the file stays a Performer configuration, and its header must describe the
//! texture the COG is served as: `virt_size` is the COG's size rounded up to powers of two (what
//! Performer needs; the texture is served at the COG's own size), the formats give the COG's
//! texel format, every `tile_size` is the COG's TIFF tile (cut to the level), and the `#clipmap
//! height` lines declare the COG's heights. Each disagreement is an error at the field, naming
//! the value written and the COG's.

use super::fields::Reader;
use super::naming::{anchor, expand_field};
use super::{portability, HeightPlan, Options};
use crate::config::{Diagnostic, Severity, Span, Spanned, TokenId};
use crate::place::Place;
use crate::source::cog::LevelOrigin;
use crate::source::{CogSource, TileSource};
use crate::texel::TexelFormat;
use serde::Serialize;
use std::path::Path;
use std::sync::Arc;

/// The settings a COG line may give.
pub(crate) const SETTINGS: [&str; 1] = ["cog"];

/// The COG a configuration names, and (once opened) the source it is served from.
#[derive(Clone, Debug, Serialize)]
pub struct CogPlan {
    /// The name as written on the `#clipmap cog` line.
    pub written: String,
    /// Where it is: a local path (a relative one anchored to the configuration file's
    /// directory, `$VAR` expanded) or a remote location (http://, https://, s3://).
    pub place: Place,
    /// The COG's level-0 size in texels, once opened.
    pub size: Option<[u64; 2]>,
    /// The texel format it is served as, once opened.
    pub format: Option<TexelFormat>,
    /// For a standalone `.ic`: the COG level it describes (the level whose size, rounded up to
    /// powers of two, is the `icache_size`). `None` for a `.ct` (every level) and an `.ic` read
    /// as a level of a `.ct` (that level).
    pub level: Option<u32>,
    /// Where the line is.
    #[serde(skip)]
    pub span: Span,
    /// The opened source (`None` when not opened: `--ct-only`, or an `.ic` of a `.ct`).
    #[serde(skip)]
    pub source: Option<Arc<CogSource>>,
}

/// What a `.ct` naming a COG passes down to each of its `.ic` files: the COG, and the tile
/// size that level is served in.
#[derive(Clone, Debug)]
pub struct LevelCheck {
    /// The COG the `.ct` names.
    pub place: Place,
    /// The `.ic`'s expected `tile_size` (S, T), `None` when the COG was not opened.
    pub tile: Option<[u64; 2]>,
}

/// Reads the file's `#clipmap cog` line (lines without a value were reported by the paging
/// reader, which reads every `#clipmap` line's shape). `None` when there is none.
pub(crate) fn read(r: &mut Reader<'_>, dir: &Path, opts: &Options, what: &str) -> Option<CogPlan> {
    let lines = r.file.extensions.clone();
    let mut found: Option<(Spanned<String>, Span)> = None;
    for line in &lines {
        let (Some(key), Some(value)) = (line.words.first(), line.words.get(1)) else { continue };
        if key.value != "cog" {
            continue;
        }
        if let Some((_, first)) = &found {
            let d = r
                .diag(Severity::Error, "duplicate-extension", Some(key.span), "`#clipmap cog` is given twice")
                .found(value.value.clone())
                .expected(format!("one COG for {what}"))
                .hint(format!("keep one `#clipmap cog` line; the first one is at line {}", first.line));
            r.push(d);
            continue;
        }
        found = Some((value.clone(), key.span));
    }
    let (value, span) = found?;
    let d = r
        .diag(
            Severity::Note,
            "cog-extension",
            Some(span),
            format!("`#clipmap cog` serves {what}'s texels from the COG `{}`, which Performer 3.0 does not know", value.value),
        )
        .hint("Performer reads `#clipmap` lines as comments and would read the tile files this configuration names instead (none are written for a COG); keep the line for this engine (docs/COG.md)");
    r.push(portability(d));
    let expanded = expand_field(r, &value, &opts.env);
    Some(CogPlan {
        written: value.value,
        place: anchor(dir, &expanded),
        size: None,
        format: None,
        level: None,
        span: value.span,
        source: None,
    })
}

/// Opens the COG `cog` names with clip size `clip`, reporting at its line why it cannot be.
pub(crate) fn open(r: &mut Reader<'_>, cog: &mut CogPlan, clip: u64) -> bool {
    match CogSource::open_place(&cog.place, clip) {
        Ok(src) => {
            cog.size = Some(src.desc().size());
            cog.format = Some(src.desc().format());
            cog.source = Some(Arc::new(src));
            true
        }
        Err(e) => {
            let anchored = match &cog.place {
                Place::Local(_) if !Path::new(&cog.written).is_absolute() => format!(
                    " (a relative path is taken from the directory of {}, here {})",
                    r.file.path.display(),
                    cog.place
                ),
                _ => String::new(),
            };
            let d = r
                .diag(
                    Severity::Error,
                    "cog-unreadable",
                    Some(cog.span),
                    format!("the COG `{}` cannot be served: {e}", cog.written),
                )
                .found(format!("{}{anchored}", cog.written))
                .expected("a tiled GeoTIFF or COG this engine serves (docs/COG.md), as `clipmapd FILE.tif` would")
                .hint("fix the path or URL on the `#clipmap cog` line, or write the file (gdal_translate -of COG)");
            r.push(d);
            false
        }
    }
}

/// The size Performer needs for a COG of `size` texels: each side rounded up to a power of two.
pub fn rounded_size(size: [u64; 2]) -> [u64; 2] {
    [size[0].next_power_of_two(), size[1].next_power_of_two()]
}

/// The TIFF tile level `k` of the COG is read in (a level built past the overviews: the last
/// overview's), cut to `within` (the level's size in the configuration).
pub fn level_tile(src: &CogSource, k: u32, within: [u64; 2]) -> Option<[u64; 2]> {
    let origins = src.origins();
    let tile = origins.iter().take(k as usize + 1).rev().find_map(|o| match o {
        LevelOrigin::Ifd { tile, .. } => Some(*tile),
        LevelOrigin::Built { .. } => None,
    })?;
    Some([tile[0].min(within[0]), tile[1].min(within[1])])
}

/// A mismatch between a header field and the COG, reported at the field.
pub(crate) fn mismatch(
    r: &Reader<'_>,
    cog: &CogPlan,
    span: Option<Span>,
    field: &str,
    written: String,
    has: String,
    fix: String,
) -> Diagnostic {
    r.diag(
        Severity::Error,
        "cog-mismatch",
        span.or(Some(cog.span)),
        format!("`{field}` does not describe the COG `{}` this file serves (line {})", cog.written, cog.span.line),
    )
    .found(written)
    .expected(has)
    .hint(fix)
}

/// Checks the `.ct`'s header against the opened COG: `virt_size`, the formats, `tile_size`
/// and the heights.
pub(crate) fn check_ct(
    r: &mut Reader<'_>,
    cog: &CogPlan,
    virt: Option<[u64; 3]>,
    texel: Option<TexelFormat>,
    tile_size: Option<[u64; 3]>,
    height: Option<&HeightPlan>,
) {
    let Some(src) = &cog.source else { return };
    let desc = src.desc();
    let size = desc.size();
    let want = rounded_size(size);
    if let Some(v) = virt {
        if [v[0], v[1]] != want {
            let note = if want != size {
                format!(
                    " (its {} x {} texels rounded up to powers of two, as Performer needs; the texture is served at the COG's own size)",
                    size[0], size[1]
                )
            } else {
                String::new()
            };
            let d = mismatch(
                r,
                cog,
                r.span_of(TokenId::Size),
                "virt_size",
                format!("virt_size {} {} {}", v[0], v[1], v[2]),
                format!("virt_size {} {} 1{note}", want[0], want[1]),
                format!("write `virt_size {} {} 1`", want[0], want[1]),
            );
            r.push(d);
        }
    }
    check_format(r, cog, texel);
    if let Some(t) = tile_size {
        if let Some(want) = level_tile(src, 0, [u64::MAX, u64::MAX]) {
            if [t[0], t[1]] != want {
                let d = mismatch(
                    r,
                    cog,
                    r.span_of(TokenId::TileSize),
                    "tile_size",
                    format!("tile_size {} {} {}", t[0], t[1], t[2]),
                    format!("tile_size {} {} 1 (the COG's TIFF tiles of level 0)", want[0], want[1]),
                    format!("write `tile_size {} {} 1`", want[0], want[1]),
                );
                r.push(d);
            }
        }
    }
    let has = src.heights();
    if height != has.as_ref() {
        let words = |h: Option<&HeightPlan>| match h {
            None => "no heights (a colour texture: no `#clipmap height` lines)".to_string(),
            Some(h) => format!(
                "heights {}, scale {}, offset {}, nodata {}, levels {}",
                h.format.storage(),
                h.format.scale(),
                h.format.offset(),
                h.format.nodata().map_or("none".to_string(), |v| v.to_string()),
                h.levels
            ),
        };
        let span = r.file.extensions.iter().find(|l| l.words.first().is_some_and(|w| w.value.starts_with("height")));
        let fix = match &has {
            None => "remove the `#clipmap height` lines".to_string(),
            Some(h) => format!(
                "write `#clipmap height {}` and `#clipmap height_nodata {}` (the COG's GDAL_NODATA; scale 1, offset 0, levels mean)",
                h.format.storage(),
                h.format.nodata().map_or("none".to_string(), |v| v.to_string())
            ),
        };
        let d = mismatch(r, cog, span.map(|l| l.span), "#clipmap height", words(height), words(has.as_ref()), fix);
        r.push(d);
    }
}

/// Checks the formats of a `.ct` or `.ic` against the opened COG's texel format.
pub(crate) fn check_format(r: &mut Reader<'_>, cog: &CogPlan, texel: Option<TexelFormat>) {
    let (Some(texel), Some(has)) = (texel, cog.format) else { return };
    if texel == has {
        return;
    }
    let names = crate::prep::configfile::format_names(has)
        .map(|(e, i, m)| format!("ext_format {e}, int_format {i}, img_format {m}"))
        .unwrap_or_default();
    let d = mismatch(
        r,
        cog,
        r.span_of(TokenId::ExtFormat).or(r.span_of(TokenId::ImgFormat)),
        "ext_format / int_format / img_format",
        format!("{texel} texels"),
        format!("{has} texels: {names}"),
        format!("write {names}"),
    );
    r.push(d);
}
