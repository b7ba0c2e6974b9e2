//! Builds a [`ClipTexturePlan`] from a `.ct` syntax tree: global values, the level layout
//! (docs/PERFORMER-REFERENCE.md §1.14), the naming groups (§1.6), each level's `.ic` (loaded and checked with
//! the values the `.ct` passes down) and each pyramid file name.

use super::fields::{Field, Reader};
use super::ic::{self, Context, Synth};
use super::naming::{self, anchor, Scope, TileNaming};
use super::params::{Param, ParamRef};
use super::printf::{Arg, Format};
use super::values::{self, SizeRule};
use super::{check_version, portability, ClipTexturePlan, GroupMode, Level, LevelKind, Options, PyramidTile};
use crate::config::{self, Diagnostic, Diagnostics, FileKind, Severity, Span, Spanned, SyntaxFile, TokenId};
use crate::place::Place;
use crate::texel::TexelFormat;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Builds the plan; `sources` receives the text of every `.ic` read.
pub fn build(
    file: &SyntaxFile,
    opts: &Options,
    diags: &mut Diagnostics,
    sources: &mut BTreeMap<PathBuf, Vec<u8>>,
) -> Option<ClipTexturePlan> {
    let mut r = Reader::new(file, diags);
    check_version(&mut r, FileKind::ClipTexture);
    check_order(&mut r);
    let mut defaulted = Vec::new();
    let limits = &opts.limits;
    let formats = ic::read_formats(&mut r, false);

    let virt_f = r.int3(TokenId::Size);
    let virt = virt_size(&mut r, &virt_f, limits.max_texture_size);

    let clip_f = r.int(TokenId::ClipSize);
    let clip = clip_size(&mut r, &clip_f, virt, limits.max_texture_size);

    let border_f = r.int(TokenId::InvalidBorder);
    let invalid_border = invalid_border(&mut r, &border_f, clip, &clip_f, &mut defaulted);

    let eff_f = r.int(TokenId::EffectiveLevels);
    let effective = positive_u32(&mut r, &eff_f, "effective_levels", 16, &mut defaulted);
    let alloc_f = r.int(TokenId::AllocatedLevels);
    let allocated = positive_u32(&mut r, &alloc_f, "allocated_levels", 1000, &mut defaulted);
    let header_f = r.int(TokenId::HeaderOffset);
    let header_offset = values::non_negative(&mut r, &header_f, "header_offset", 0, &mut defaulted, "header_offset");
    let page_f = r.int(TokenId::PageSize);
    let page_size = ic::page_size(&mut r, &page_f, None, &mut defaulted);
    let look_f = r.int(TokenId::Lookahead);
    let lookahead_given = matches!(look_f, Field::Given(..));
    let lookahead = values::non_negative(&mut r, &look_f, "lookahead", 1, &mut defaulted, "lookahead");
    let read_func = ic::read_func(&mut r);
    let paging = super::paging::read(&mut r);
    let height = super::height::read(&mut r, formats.as_ref().map(|f| f.3));
    let georef = super::georef::read(&mut r, virt);
    let tile_f = r.int3(TokenId::TileSize);
    let tile_size = match &tile_f {
        Field::Absent => None,
        f => values::size3(
            &mut r,
            f,
            "tile_size",
            SizeRule { pow2: false, max: limits.max_tile_size, allow_two: true, r_is_one: true },
        ),
    };

    let smallest = match (virt, clip) {
        (Some(v), Some(c)) => smallest_icache(&mut r, v, c, &mut defaulted),
        _ => None,
    };

    // Naming groups.
    let icache_mode = group_mode(&mut r, TokenId::IcacheFormat, TokenId::IcacheParams, TokenId::IcacheFiles, "icache");
    let tile_mode = group_mode(&mut r, TokenId::TileFormat, TokenId::TileParams, TokenId::TileFiles, "tile");
    check_base_after_files(&mut r, TokenId::IcacheBase, TokenId::IcacheFiles);
    check_base_after_files(&mut r, TokenId::TileBase, TokenId::TileFiles);
    let dir = file.path.parent().map(Path::to_path_buf).unwrap_or_default();
    let icache_base_f = r.base(TokenId::IcacheBase);
    let icache_base = expand_base(&mut r, &icache_base_f, opts);
    let tile_base_f = r.base(TokenId::TileBase);
    let tile_base = expand_base(&mut r, &tile_base_f, opts);

    // The COG the `#clipmap cog` line names (docs/COG.md; opened and checked against the
    // header by `crate::source::configured`).
    let cog = super::cog::read(&mut r, &dir, opts, "the clip texture");
    // The tile pyramid the `#clipmap source` line names (docs/TILES.md; opened by the source
    // floor with the clip size below).
    let source = super::source_line::read(&mut r, &dir, opts);
    if let (Some(c), Some(s)) = (&cog, &source) {
        let d = r
            .diag(
                Severity::Error,
                "duplicate-extension",
                Some(s.span),
                "`#clipmap source` and `#clipmap cog` both name the clip texture's texels",
            )
            .found(s.written.clone())
            .expected(format!("one of them (the COG `{}` is named at line {})", c.written, c.span.line))
            .hint("keep the line of the source to serve");
        r.push(d);
    }

    let (Some(virt), Some(clip), Some(smallest)) = (virt, clip, smallest) else {
        return None;
    };
    let (sizes, n_icache) = level_sizes(&mut r, virt, smallest, limits.max_levels, &virt_f)?;

    // Level .ic files.
    let icache_names = level_names(
        &mut r,
        Group::Icache,
        icache_mode,
        &sizes[..n_icache as usize],
        virt,
        &icache_base,
        &tile_base,
        &dir,
        opts,
    );
    let pyramid_sizes = &sizes[n_icache as usize..];
    let pyramid_names =
        level_names(&mut r, Group::Tile, tile_mode, pyramid_sizes, virt, &icache_base, &tile_base, &dir, opts);

    let no_ic_naming = if icache_mode == GroupMode::None {
        no_ic_naming(&mut r, &tile_base, &dir, opts, tile_size, &tile_f)
    } else {
        None
    };

    let (ext, int, img, texel) = formats?;
    let header_offset = header_offset?;
    let lookahead = lookahead?;
    let page_size = page_size?;
    let mut levels = Vec::new();
    for (l, &size) in sizes.iter().enumerate() {
        let level = l as u32;
        if l < n_icache as usize {
            let plan = if icache_mode == GroupMode::None {
                let (naming, span) = no_ic_naming.clone()?;
                Synth {
                    level: (level, size),
                    formats: (ext.clone(), int.clone(), img.clone(), texel),
                    tile_size: tile_size?,
                    naming,
                    header_offset,
                    clip_size: clip,
                    lookahead,
                    lookahead_given,
                    page_size,
                    read_func: read_func.clone(),
                    span,
                    ct_path: &file.path,
                }
                .build(diags, limits.max_mem_region_tiles)
            } else {
                let (path, span) = icache_names.as_ref()?.get(l)?.clone()?;
                if opts.ct_only {
                    levels.push(Level { level, size, kind: LevelKind::IcacheNotOpened { path: path.into_path_buf() } });
                    continue;
                }
                let ctx = Context {
                    clip_size: Some(clip),
                    page_size: Some(page_size),
                    // A lookahead the .ct does not give is each .ic's default (the same 1),
                    // marked defaulted there, so the engine may size that level's grid.
                    lookahead: lookahead_given.then_some(lookahead),
                    read_func: read_func.clone(),
                    level: Some((level, size)),
                    texel: Some(texel),
                    cog: cog.as_ref().map(|c| c.place.clone()),
                };
                load_level_ic(&path, span, &file.path, &ctx, opts, diags, sources)
            };
            if let Some(p) = plan {
                levels.push(Level { level, size, kind: LevelKind::Icache(Box::new(p)) });
            }
        } else {
            let idx = l - n_icache as usize;
            let path = pyramid_names.as_ref().and_then(|v| v.get(idx).cloned().flatten()).map(|(p, _)| p);
            levels.push(pyramid_level(file, diags, (level, size), path, header_offset, texel)?);
        }
    }
    if levels.len() != sizes.len() {
        return None;
    }
    let n_levels = levels.len() as u32;
    let effective = effective?;
    Some(ClipTexturePlan {
        path: file.path.clone(),
        version: file.first(TokenId::CtVersion).map(|e| e.def.name.to_string()),
        bytes_per_texel: texel.bytes_per_texel(),
        ext_format: ext,
        int_format: int,
        img_format: img,
        texel,
        virt_size: virt,
        clip_size: clip,
        invalid_border: invalid_border?,
        effective_levels: effective,
        allocated_levels: allocated?,
        smallest_icache: smallest,
        header_offset,
        page_size,
        lookahead,
        paging,
        height,
        read_func,
        tile_size,
        icache_mode,
        tile_mode,
        is_virtual: effective < n_levels,
        levels,
        defaulted,
        cog,
        source,
        georef,
    })
}

/// `clip_size`: mandatory, a positive power of two within `max_size`; warns when it is larger
/// than the texture's smaller side.
fn clip_size(r: &mut Reader<'_>, clip_f: &Field<Spanned<i64>>, virt: Option<[u64; 3]>, max_size: u64) -> Option<u64> {
    let clip = match clip_f {
        Field::Absent => {
            values::missing(
                r,
                "`clip_size` is missing; it is mandatory",
                "add `clip_size N` (a power of two, usually the display width)",
            );
            None
        }
        Field::Broken => None,
        Field::Given(v, _) => {
            if v.value <= 0 {
                let d = r
                    .diag(Severity::Error, "clip-size-not-positive", Some(v.span), "`clip_size` must be positive")
                    .found(v.value.to_string())
                    .expected("a positive power of two");
                r.push(d);
                None
            } else if !(v.value as u64).is_power_of_two() {
                let u = v.value as u64;
                let d = r
                    .diag(
                        Severity::Error,
                        "clip-size-not-power-of-two",
                        Some(v.span),
                        "`clip_size` must be a power of two",
                    )
                    .found(v.value.to_string())
                    .hint(format!(
                        "the nearest powers of two are {} and {}",
                        values::next_pow2(u) / 2,
                        values::next_pow2(u)
                    ));
                r.push(d);
                None
            } else if v.value as u64 > max_size {
                let d = r
                    .diag(
                        Severity::Error,
                        "clip-size-too-large",
                        Some(v.span),
                        "`clip_size` is larger than this reader's limit",
                    )
                    .found(v.value.to_string());
                r.push(d);
                None
            } else {
                Some(v.value as u64)
            }
        }
    };
    if let (Some(v), Some(c)) = (virt, clip) {
        if v[0].min(v[1]) < c {
            let d = r
                .diag(
                    Severity::Warning,
                    "clip-larger-than-texture",
                    values::span_of(clip_f),
                    format!("`clip_size` {c} is larger than the texture's smaller side ({})", v[0].min(v[1])),
                )
                .hint(
                    "a clip size above the texture size keeps the whole texture resident; lower it to the texture size",
                );
            r.push(d);
        }
    }
    clip
}

/// `invalid_border`: 8 by default, raised to 8 as Performer does, and narrower than half the
/// clip window.
fn invalid_border(
    r: &mut Reader<'_>,
    border_f: &Field<Spanned<i64>>,
    clip: Option<u64>,
    clip_f: &Field<Spanned<i64>>,
    defaulted: &mut Vec<&'static str>,
) -> Option<u64> {
    let invalid_border = match border_f {
        Field::Absent => {
            defaulted.push("invalid_border");
            Some(8)
        }
        Field::Broken => None,
        Field::Given(v, _) if v.value < 0 => {
            let d = r
                .diag(Severity::Error, "negative-value", Some(v.span), "`invalid_border` cannot be negative")
                .found(v.value.to_string())
                .expected("8 or more");
            r.push(d);
            None
        }
        Field::Given(v, _) if v.value < 8 => {
            let d = r
                .diag(
                    Severity::Warning,
                    "border-raised",
                    Some(v.span),
                    format!(
                        "`invalid_border` {} is below the minimum of 8; it is raised to 8, as Performer does",
                        v.value
                    ),
                )
                .hint("write `invalid_border 8` (or more) to say what is used");
            r.push(d);
            Some(8)
        }
        Field::Given(v, _) => Some(v.value as u64),
    };
    if let (Some(b), Some(c)) = (invalid_border, clip) {
        if 2 * b >= c && c > 0 {
            let d = r
                .diag(
                    Severity::Error,
                    "border-too-wide",
                    values::span_of(border_f).or(values::span_of(clip_f)),
                    format!("an invalid border of {b} on each side leaves nothing of a {c}-texel clip window"),
                )
                .expected(format!("an invalid border below {}", c / 2))
                .hint("raise clip_size or lower invalid_border");
            r.push(d);
        }
    }
    invalid_border
}

/// The level layout (docs/PERFORMER-REFERENCE.md §1.14): the sizes of every level, finest
/// first, and how many of them are image-cache levels (down to `smallest`); the rest are
/// pyramid levels, halving to the end.
fn level_sizes(
    r: &mut Reader<'_>,
    virt: [u64; 3],
    smallest: [u64; 3],
    max_levels: u32,
    virt_f: &Field<Vec<Spanned<i64>>>,
) -> Option<(Vec<[u64; 2]>, u32)> {
    let n_icache = (virt[0] / smallest[0]).trailing_zeros() + 1;
    let mut sizes: Vec<[u64; 2]> = (0..n_icache).map(|l| [virt[0] >> l, virt[1] >> l]).collect();
    let mut p = [smallest[0] / 2, smallest[1] / 2];
    while p[0] > 0 && p[1] > 0 {
        sizes.push(p);
        p = [p[0] / 2, p[1] / 2];
    }
    if sizes.len() as u32 > max_levels {
        let d = r.diag(
            Severity::Error,
            "too-many-levels",
            values::span_of(virt_f),
            format!("the texture has {} levels; at most {} are supported", sizes.len(), max_levels),
        );
        r.push(d);
        return None;
    }
    if virt[0] != virt[1] && (virt[0].max(virt[1]) / virt[0].min(virt[1])) > 1 {
        let last = sizes[sizes.len() - 1];
        if last != [1, 1] {
            let d = r.diag(
                Severity::Note,
                "non-square-pyramid-end",
                values::span_of(virt_f),
                format!(
                    "as in Performer, the pyramid of a non-square texture ends at {}x{}, not 1x1",
                    last[0], last[1]
                ),
            );
            r.push(d);
        }
    }
    Some((sizes, n_icache))
}

/// `virt_size`: mandatory, powers of two within `max_size`.
fn virt_size(r: &mut Reader<'_>, virt_f: &Field<Vec<Spanned<i64>>>, max_size: u64) -> Option<[u64; 3]> {
    let rule = SizeRule { pow2: true, max: max_size, allow_two: true, r_is_one: true };
    values::mandatory_size3(r, virt_f, "virt_size", "add `virt_size S T 1` (the level-0 size in texels)", rule)
}

/// Pyramid level `level` of `size`, read whole from `path` after `header_offset` bytes; refused
/// when its byte count does not fit in 64 bits.
fn pyramid_level(
    file: &SyntaxFile,
    diags: &mut Diagnostics,
    (level, size): (u32, [u64; 2]),
    path: Option<Place>,
    header_offset: u64,
    texel: TexelFormat,
) -> Option<Level> {
    // Whole 4 x 4 blocks for a block-compressed format, texels for the others.
    let Some(length) = texel.bytes_for(size[0], size[1]) else {
        diags.push(
            Diagnostic::new(
                Severity::Error,
                "level-too-large",
                &file.path,
                file.first(TokenId::Size).map(|e| e.span),
                format!("pyramid level {level} ({}x{}) does not fit in a 64-bit byte count", size[0], size[1]),
            )
            .hint("a pyramid level is read whole: lower smallest_icache or clip_size"),
        );
        return None;
    };
    Some(Level { level, size, kind: LevelKind::Pyramid(PyramidTile { path, header_offset, length }) })
}

fn positive_u32(
    r: &mut Reader<'_>,
    f: &Field<Spanned<i64>>,
    name: &str,
    default: u32,
    defaulted: &mut Vec<&'static str>,
) -> Option<u32> {
    match f {
        Field::Absent => {
            defaulted.push(match name {
                "effective_levels" => "effective_levels",
                _ => "allocated_levels",
            });
            Some(default)
        }
        Field::Broken => None,
        Field::Given(v, _) if v.value < 1 || v.value > u32::MAX as i64 => {
            let d = r
                .diag(Severity::Error, "level-count-not-positive", Some(v.span), format!("`{name}` must be at least 1"))
                .found(v.value.to_string())
                .expected("a positive number of levels");
            r.push(d);
            None
        }
        Field::Given(v, _) => Some(v.value as u32),
    }
}

/// `smallest_icache`: the default rule and the checks of docs/PERFORMER-REFERENCE.md §1.14.
fn smallest_icache(
    r: &mut Reader<'_>,
    virt: [u64; 3],
    clip: u64,
    defaulted: &mut Vec<&'static str>,
) -> Option<[u64; 3]> {
    let f = r.int3(TokenId::SmallestIcache);
    let default = if virt[0] == virt[1] {
        [2 * clip, 2 * clip, 1]
    } else if virt[0] > virt[1] {
        [clip * (virt[0] / virt[1]), clip, 1]
    } else {
        [clip, clip * (virt[1] / virt[0]), 1]
    };
    let (s, span) = match &f {
        Field::Absent => {
            defaulted.push("smallest_icache");
            (default, None)
        }
        Field::Broken => return None,
        Field::Given(v, span) => {
            let mut out = [default[0], default[1], 1];
            for (i, x) in v.iter().enumerate().take(3) {
                if x.value == 0 {
                    let d = r
                        .diag(Severity::Error, "smallest-icache-zero", Some(x.span), "`smallest_icache` cannot be 0")
                        .expected("a positive size");
                    r.push(d);
                    return None;
                }
                if x.value > 0 {
                    out[i] = x.value as u64;
                }
            }
            // One of S/T given and the other negative: copy it.
            if v.len() >= 2 && v[0].value > 0 && v[1].value < 0 {
                out[1] = out[0];
            } else if v.len() >= 2 && v[1].value > 0 && v[0].value < 0 {
                out[0] = out[1];
            }
            (out, Some(*span))
        }
    };
    for (i, axis) in ["S", "T"].iter().enumerate() {
        // Only a value from the file is checked: Performer checks before computing the default,
        // whose S (or T) is clip x ratio for a non-square texture and may exceed 2 x clip.
        if span.is_some() && s[i] > 2 * clip {
            let d = r
                .diag(
                    Severity::Error,
                    "smallest-icache-too-large",
                    span.or(Some(Span::START)),
                    format!("{axis} of `smallest_icache` ({}) is more than twice `clip_size` ({clip})", s[i]),
                )
                .hint("every level larger than the clip size must be an image cache; lower smallest_icache");
            r.push(d);
            return None;
        }
        if s[i] > virt[i] {
            let d = r
                .diag(
                    Severity::Error,
                    "smallest-icache-larger-than-texture",
                    span.or(r.span_of(TokenId::ClipSize)),
                    format!("{axis} of `smallest_icache` ({}) is larger than the texture ({})", s[i], virt[i]),
                )
                .hint(if span.is_none() {
                    "the default is 2 x clip_size; lower clip_size or give smallest_icache"
                } else {
                    "lower smallest_icache"
                });
            r.push(d);
            return None;
        }
    }
    let (rs, rt) = (virt[0] / s[0], virt[1] / s[1]);
    if rs != rt || !rs.is_power_of_two() || !virt[0].is_multiple_of(s[0]) || !virt[1].is_multiple_of(s[1]) {
        let d = r
            .diag(
                Severity::Error,
                "smallest-icache-not-proportional",
                span.or(Some(Span::START)),
                format!(
                    "`smallest_icache` {}x{} is not the texture {}x{} divided by a power of two",
                    s[0], s[1], virt[0], virt[1]
                ),
            )
            .hint("smallest_icache must be virt_size / 2^k on both axes");
        r.push(d);
        return None;
    }
    Some(s)
}

/// Reports the portability problem of tokens out of the documented order.
fn check_order(r: &mut Reader<'_>) {
    let mut max: Option<(u8, &'static str)> = None;
    let mut found = Vec::new();
    for e in &r.file.entries {
        let o = e.def.ct_order;
        if o == 0 {
            continue;
        }
        match max {
            Some((m, name)) if o < m => found.push((e.span, e.def.name, name)),
            _ => max = Some((o, e.def.name)),
        }
    }
    for (span, name, after) in found {
        let d = r
            .diag(Severity::Warning, "out-of-order", Some(span), format!("`{name}` comes after `{after}`; Performer's manual says the tokens must follow its documented order"))
            .hint("reorder the tokens as in docs/CONFIG.md (Performer 3.0 does not check, but other readers may)");
        r.push(portability(d));
    }
}

fn group_mode(r: &mut Reader<'_>, fmt: TokenId, params: TokenId, files: TokenId, group: &str) -> GroupMode {
    let has_fmt = r.file.first(fmt).is_some();
    let has_params = r.file.first(params).is_some();
    let has_files = r.file.first(files).is_some();
    if has_params && !has_fmt {
        let d = r
            .diag(
                Severity::Error,
                "params-without-format",
                r.span_of(params),
                format!("`{group}_params` without `{group}_format`"),
            )
            .hint(format!("add `{group}_format` (Performer 3.0 crashes here), or remove the parameters"));
        r.push(d);
    }
    if (has_fmt || has_params) && has_files {
        let second = [r.span_of(files), r.span_of(fmt)].into_iter().flatten().max_by_key(|s| s.offset);
        let d = r
            .diag(
                Severity::Error,
                "format-and-file-list",
                second,
                format!("both `{group}_format` and `{group}_files` are given; use one method"),
            )
            .hint(format!("keep either the format (with `{group}_params`) or the explicit list"));
        r.push(d);
    }
    if has_fmt || has_params {
        GroupMode::Format
    } else if has_files {
        GroupMode::FileList
    } else {
        GroupMode::None
    }
}

fn check_base_after_files(r: &mut Reader<'_>, base: TokenId, files: TokenId) {
    if let (Some(b), Some(f)) = (r.file.position(base), r.file.position(files)) {
        if b > f {
            let span = r.span_of(base);
            let d = r
                .diag(
                    Severity::Warning,
                    "base-after-files",
                    span,
                    format!(
                        "`{}` comes after `{}`: Performer 3.0 applies a base only to lists read after it",
                        r.file.entries[b].def.name, r.file.entries[f].def.name
                    ),
                )
                .hint("move the base before the list; this reader applies it to every entry either way");
            r.push(portability(d));
        }
    }
}

fn expand_base(r: &mut Reader<'_>, f: &Field<Spanned<String>>, opts: &Options) -> String {
    match f {
        Field::Given(b, _) => naming::expand_field(r, b, &opts.env),
        _ => String::new(),
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Group {
    Icache,
    Tile,
}

/// Each level's file name with the span that named it; `None` for a level without a name.
type LevelNames = Vec<Option<(Place, Option<Span>)>>;

/// The file name of every level of a group, with the span that named it. `None` for the whole
/// group when its naming is broken (already reported); a `None` entry for a level without a name.
#[allow(clippy::too_many_arguments)]
fn level_names(
    r: &mut Reader<'_>,
    group: Group,
    mode: GroupMode,
    sizes: &[[u64; 2]],
    virt: [u64; 3],
    icache_base: &str,
    tile_base: &str,
    dir: &Path,
    opts: &Options,
) -> Option<LevelNames> {
    let (fmt_id, params_id, files_id, base, gname) = match group {
        Group::Icache => (TokenId::IcacheFormat, TokenId::IcacheParams, TokenId::IcacheFiles, icache_base, "icache"),
        Group::Tile => (TokenId::TileFormat, TokenId::TileParams, TokenId::TileFiles, tile_base, "tile"),
    };
    match mode {
        GroupMode::None => {
            if group == Group::Tile && !sizes.is_empty() {
                let d = r
                    .diag(
                        Severity::Warning,
                        "pyramid-unnamed",
                        Some(Span::START),
                        format!(
                            "no `tile_files` or `tile_format`: the {} pyramid levels have no files and will be blank",
                            sizes.len()
                        ),
                    )
                    .hint("name the pyramid files with `tile_files` (one per level, largest first) or `tile_format`");
                r.push(d);
            }
            Some(sizes.iter().map(|_| None).collect())
        }
        GroupMode::FileList => {
            let Field::Given(items, span) = r.list(files_id, Some("a file list")) else {
                return None;
            };
            if items.len() < sizes.len() {
                let what = if group == Group::Icache { "image cache level" } else { "pyramid level" };
                let d = r
                    .diag(
                        Severity::Error,
                        "file-list-too-short",
                        Some(span),
                        format!(
                            "`{gname}_files` has {} entr{} but there {} {} {what}{}",
                            items.len(),
                            if items.len() == 1 { "y" } else { "ies" },
                            if sizes.len() == 1 { "is" } else { "are" },
                            sizes.len(),
                            if sizes.len() == 1 { "" } else { "s" }
                        ),
                    )
                    .hint(format!(
                        "list one file per {what}, largest first: sizes {}",
                        sizes.iter().map(|s| format!("{}x{}", s[0], s[1])).collect::<Vec<_>>().join(", ")
                    ));
                r.push(d);
                return None;
            }
            if items.len() > sizes.len() {
                let extra = &items[sizes.len()];
                let d = r
                    .diag(
                        Severity::Warning,
                        "file-list-too-long",
                        Some(extra.span),
                        format!(
                            "`{gname}_files` has {} entries but only {} are used; the rest are ignored",
                            items.len(),
                            sizes.len()
                        ),
                    )
                    .found(extra.value.clone());
                r.push(d);
            }
            let mut out = Vec::new();
            for item in items.iter().take(sizes.len()) {
                let name = naming::expand_field(r, item, &opts.env);
                out.push(Some((anchor(dir, &format!("{base}{name}")), Some(item.span))));
            }
            Some(out)
        }
        GroupMode::Format => {
            let fmt_f = r.word(fmt_id, Some("a format"));
            let Field::Given(fmt, _) = fmt_f else {
                return None;
            };
            let expanded = naming::expand_field(r, &fmt, &opts.env);
            let params_f = r.list(params_id, None);
            let params = params_f.value().cloned().unwrap_or_default();
            let scope = match group {
                Group::Icache => Scope::CtIcache,
                Group::Tile => Scope::CtTile {
                    no_ic: r.file.first(TokenId::IcacheFormat).is_none()
                        && r.file.first(TokenId::IcacheFiles).is_none()
                        && r.file.first(TokenId::IcacheParams).is_none(),
                },
            };
            let (parsed, refs) = naming::check_format(r, &fmt, &expanded, &params, values::span_of(&params_f), scope)?;
            let mut out = Vec::new();
            for (i, size) in sizes.iter().enumerate() {
                let level = match group {
                    Group::Icache => i as u64,
                    Group::Tile => virt_level(virt, *size),
                };
                let name = render_level(&parsed, &refs, level, *size, icache_base, tile_base);
                out.push(Some((anchor(dir, &name), Some(fmt.span))));
            }
            Some(out)
        }
    }
}

/// The level number of a level size (for pyramid files, whose index is not the position).
fn virt_level(virt: [u64; 3], size: [u64; 2]) -> u64 {
    (virt[0] / size[0]).trailing_zeros() as u64
}

fn render_level(
    fmt: &Format,
    refs: &[ParamRef],
    level: u64,
    size: [u64; 2],
    icache_base: &str,
    tile_base: &str,
) -> String {
    let args: Vec<Arg> = refs
        .iter()
        .map(|p| match p.param {
            Param::Level => Arg::Int(level as i64),
            Param::VsizeS => Arg::Int(size[0] as i64),
            Param::VsizeT => Arg::Int(size[1] as i64),
            Param::VsizeR => Arg::Int(1),
            Param::ImageCacheBase => Arg::Str(icache_base.to_string()),
            Param::CacheName => Arg::Str(tile_base.to_string()),
            Param::StreamServerName => Arg::Str(String::new()),
            _ => Arg::Int(0),
        })
        .collect();
    fmt.render(&args)
}

/// In no-`.ic` mode, the naming handed to every synthesised image cache.
fn no_ic_naming(
    r: &mut Reader<'_>,
    tile_base: &str,
    dir: &Path,
    opts: &Options,
    tile_size: Option<[u64; 3]>,
    tile_f: &Field<Vec<Spanned<i64>>>,
) -> Option<(TileNaming, Option<Span>)> {
    if tile_size.is_none() && tile_f.is_absent() {
        let d = r
            .diag(
                Severity::Error,
                "no-ic-needs-tile-size",
                Some(Span::START),
                "without `.ic` files (no `icache_files` or `icache_format`), `tile_size` is required",
            )
            .hint("add `tile_size W H 1`, or name one .ic file per image cache level");
        r.push(d);
    }
    let cache_name = if tile_base.is_empty() { "./".to_string() } else { tile_base.to_string() };
    let fmt_f = r.word(TokenId::TileFormat, Some("a format"));
    match fmt_f {
        Field::Given(fmt, span) => {
            let expanded = naming::expand_field(r, &fmt, &opts.env);
            let params_f = r.list(TokenId::TileParams, None);
            let params = params_f.value().cloned().unwrap_or_default();
            let (parsed, refs) = naming::check_format(
                r,
                &fmt,
                &expanded,
                &params,
                values::span_of(&params_f),
                Scope::CtTile { no_ic: true },
            )?;
            Some((
                TileNaming::new(parsed, refs.iter().map(|p| p.param).collect(), cache_name, dir.to_path_buf()),
                Some(span),
            ))
        }
        Field::Absent => {
            let d = r
                .diag(Severity::Warning, "no-ic-default-format", Some(Span::START), "without `.ic` files and without `tile_format`, image cache tiles use the default name format `%s%s.%d.r%03d.c%03d.raw888`")
                .hint("give `tile_format` and `tile_params` to name the tiles");
            r.push(d);
            Some((TileNaming::default_format(cache_name, dir.to_path_buf()), None))
        }
        Field::Broken => None,
    }
}

/// Reads, parses and builds the `.ic` of one level.
fn load_level_ic(
    path: &Place,
    span: Option<Span>,
    ct_path: &Path,
    ctx: &Context,
    opts: &Options,
    diags: &mut Diagnostics,
    sources: &mut BTreeMap<PathBuf, Vec<u8>>,
) -> Option<super::ImageCachePlan> {
    let level = ctx.level.map(|l| l.0).unwrap_or(0);
    let Place::Local(path) = path else {
        diags.push(
            Diagnostic::new(
                Severity::Error,
                "remote-icache-file",
                ct_path,
                span,
                format!("the image cache file of level {level} is a remote location; configuration files are read from local disk only"),
            )
            .found(path.to_string())
            .expected("a local .ic file name")
            .hint("keep the .ct and its .ic files local, and name the tiles remotely: a URL as the .ic's tile_base, stream servers or tile_format (docs/CONFIG.md §15)"),
        );
        return None;
    };
    let src = match super::read_source(path, &opts.limits) {
        Ok(s) => s,
        Err(e) => {
            let what = if e.kind() == std::io::ErrorKind::NotFound { "not found".to_string() } else { e.to_string() };
            diags.push(
                Diagnostic::new(
                    Severity::Error,
                    "icache-file-unreadable",
                    ct_path,
                    span,
                    format!("the image cache file of level {level} cannot be read: {what}"),
                )
                .found(path.display().to_string())
                .hint(
                    "check the name (relative names are taken from the .ct file's directory) and that the file exists; to check the .ct where its data is not, use `cliptex validate --ct-only`",
                ),
            );
            return None;
        }
    };
    let (file, d) = config::parse_bytes(&src, path, FileKind::ImageCache, &opts.limits);
    sources.insert(path.to_path_buf(), src);
    diags.extend(d);
    ic::build(&file, ctx, opts, diags)
}
