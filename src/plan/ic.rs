//! Builds an [`ImageCachePlan`] from an `.ic` syntax tree (standalone, or as a level of a clip
//! texture with values inherited from the `.ct`), and synthesises one in no-`.ic` mode.

use super::fields::{Field, Reader};
use super::formats::{self, FormatRefusal, FormatValue, Which};
use super::naming::{self, anchor, Scope, TileNaming};
use super::values::{self, SizeRule};
use super::{check_version, portability, ImageCachePlan, Options, ReadFunc};
use crate::config::{Diagnostics, FileKind, Severity, Span, Spanned, SyntaxFile, TokenId, Value};
use crate::place::Place;
use crate::texel::{Bc, TexelFormat};
use std::path::{Path, PathBuf};

/// What a clip texture passes down to each of its image caches.
#[derive(Clone, Debug, Default)]
pub struct Context {
    /// The clip size (the tex region becomes min(clip, size)).
    pub clip_size: Option<u64>,
    /// `.ct` page size.
    pub page_size: Option<i64>,
    /// `.ct` lookahead.
    pub lookahead: Option<u64>,
    /// `.ct` read function.
    pub read_func: Option<ReadFunc>,
    /// The level this cache must describe, and its size.
    pub level: Option<(u32, [u64; 2])>,
    /// The clip texture's texel format.
    pub texel: Option<TexelFormat>,
    /// The COG the clip texture names (`#clipmap cog`).
    pub cog: Option<Place>,
}

impl Context {
    /// A standalone image cache.
    pub fn standalone() -> Self {
        Context::default()
    }
}

/// Resolves the three format tokens (shared with the `.ct` builder).
pub(crate) fn read_formats(
    r: &mut Reader<'_>,
    defaulted_ok: bool,
) -> Option<(FormatValue, FormatValue, FormatValue, TexelFormat)> {
    let mut vals = Vec::new();
    let mut spans: Vec<Option<Span>> = Vec::new();
    for (id, which, name) in [
        (TokenId::ExtFormat, Which::Ext, "ext_format"),
        (TokenId::IntFormat, Which::Int, "int_format"),
        (TokenId::ImgFormat, Which::Img, "img_format"),
    ] {
        let field = r.word(id, None);
        match field {
            Field::Given(w, span) => match formats::resolve(which, &w.value) {
                Ok(v) => {
                    if which == Which::Img && v.numeric {
                        let d = r
                            .diag(
                                Severity::Warning,
                                "numeric-img-format",
                                Some(w.span),
                                "Performer 3.0 refuses a number for `img_format` (its manual allows it)",
                            )
                            .found(w.value.clone())
                            .hint("write the name, e.g. PFTEX_RGB");
                        r.push(portability(d));
                    }
                    vals.push(Some(v));
                    spans.push(Some(span));
                }
                Err(refusal) => {
                    let mut d = r
                        .diag(
                            Severity::Error,
                            "unknown-format",
                            Some(w.span),
                            format!("`{}` is not a known `{name}` value", w.value),
                        )
                        .found(w.value.clone());
                    d = match refusal {
                        FormatRefusal::UnknownName(Some(s)) => d.hint(format!("did you mean `{s}`?")),
                        FormatRefusal::UnknownName(None) => d.expected(format!(
                            "a name such as {}",
                            match which {
                                Which::Ext => "PFTEX_UNSIGNED_BYTE",
                                Which::Int => "PFTEX_RGB_8",
                                Which::Img => "PFTEX_RGB",
                            }
                        )),
                        FormatRefusal::UnknownNumber => {
                            d.expected("a non-negative OpenGL enum value that names a known format")
                        }
                    };
                    r.push(d);
                    vals.push(None);
                    spans.push(None);
                }
            },
            Field::Absent => {
                if !defaulted_ok {
                    values::missing(
                        r,
                        format!("`{name}` is missing; it is mandatory"),
                        format!("add `{name} …` (see docs/CONFIG.md for the names)"),
                    );
                }
                vals.push(None);
                spans.push(None);
            }
            Field::Broken => {
                vals.push(None);
                spans.push(None);
            }
        }
    }
    let (ext, int, img) = (vals[0].clone()?, vals[1].clone()?, vals[2].clone()?);
    match formats::texel_format(ext.value, img.value) {
        Some(t) => {
            if let Some(bc) = t.block() {
                note_block_format(r, spans[0], &ext, bc);
            }
            Some((ext, int, img, t))
        }
        None => {
            let d = r
                .diag(
                    Severity::Error,
                    "unsupported-texel-format",
                    spans[0],
                    format!(
                        "`ext_format {}` with `img_format {}` does not describe a texel this reader can size",
                        ext.written, img.written
                    ),
                )
                .hint("GL_BITMAP has no meaning for tiles; use a component type such as PFTEX_UNSIGNED_BYTE");
            r.push(d);
            None
        }
    }
}

/// Notes that the texels are a block-compressed format (`CLIPMAP_BC*`): this crate's extension,
/// which Performer 3.0 would not read, so a portability finding (an error under `--strict`), as
/// the other extensions are.
fn note_block_format(r: &mut Reader<'_>, span: Option<Span>, ext: &FormatValue, bc: Bc) {
    if r.reported("block-format-extension", span) {
        return;
    }
    let d = r
        .diag(
            Severity::Warning,
            "block-format-extension",
            span,
            format!(
                "`ext_format {}` names {} blocks, an extension of this reader; Performer 3.0 would not read it",
                ext.written,
                bc.name().to_uppercase()
            ),
        )
        .found(ext.written.clone())
        .hint("keep it for this engine (docs/CONFIG.md §20); for a texture Performer must read, prepare it with `clipprep --format rgb8` or `rgba8`");
    r.push(portability(d));
}

/// Builds the plan of one `.ic` file.
pub fn build(file: &SyntaxFile, ctx: &Context, opts: &Options, diags: &mut Diagnostics) -> Option<ImageCachePlan> {
    let mut r = Reader::new(file, diags);
    check_version(&mut r, FileKind::ImageCache);
    let mut defaulted = Vec::new();
    let formats = read_formats(&mut r, false);
    let limits = &opts.limits;

    let size_f = r.int3(TokenId::Size);
    let rule = SizeRule { pow2: true, max: limits.max_texture_size, allow_two: true, r_is_one: true };
    let size = values::mandatory_size3(
        &mut r,
        &size_f,
        "icache_size",
        "add `icache_size S T 1` (the size of this level in texels)",
        rule,
    );
    let tile_f = r.int3(TokenId::TileSize);
    let rule = SizeRule { pow2: false, max: limits.max_tile_size, allow_two: true, r_is_one: true };
    let tile = values::mandatory_size3(&mut r, &tile_f, "tile_size", "add `tile_size W H 1`; Performer 3.0 does not check this and fails later with \"memregion too small for texregion\"", rule);

    let tif_f = r.int3(TokenId::TilesInFile);
    let tiles_in_file = match &tif_f {
        Field::Absent => {
            defaulted.push("tiles_in_file");
            Some([1, 1, 1])
        }
        _ => values::size3(
            &mut r,
            &tif_f,
            "tiles_in_file",
            SizeRule { pow2: false, max: 1 << 20, allow_two: true, r_is_one: false },
        ),
    };
    let header_f = r.int(TokenId::HeaderOffset);
    let header_offset = values::non_negative(&mut r, &header_f, "header_offset", 0, &mut defaulted, "header_offset");
    let look_f = r.int(TokenId::Lookahead);
    let lookahead = match (&look_f, ctx.lookahead) {
        (Field::Absent, Some(l)) => Some(l),
        _ => values::non_negative(&mut r, &look_f, "lookahead", 1, &mut defaulted, "lookahead"),
    };
    let page_f = r.int(TokenId::PageSize);
    let page_size = page_size(&mut r, &page_f, ctx.page_size, &mut defaulted);
    let read_func = read_func(&mut r).or_else(|| ctx.read_func.clone());

    check_tiles_divide(&mut r, size, tile, &tile_f);
    check_against_clip_texture(&mut r, ctx, size, &size_f, &formats);

    let tex_region = tex_region(&mut r, ctx.clip_size, size, limits.max_texture_size);
    let tex_size = tex_size(&mut r, tex_region, limits.max_texture_size, &mut defaulted);

    let mem_f = r.int3(TokenId::MemRegionSize);
    let mem_region = match (size, tile, tex_region, lookahead) {
        (Some(sz), Some(tl), Some(tr), Some(la)) => {
            mem_region(&mut r, &mem_f, sz, tl, tr, la, limits.max_mem_region_tiles, &mut defaulted)
        }
        _ => None,
    };

    // Naming.
    let dir = file.path.parent().map(Path::to_path_buf).unwrap_or_default();
    let base_f = r.base(TokenId::TileBase);
    let cache_name = match &base_f {
        Field::Given(b, _) => naming::expand_field(&mut r, b, &opts.env),
        _ => String::new(),
    };
    let naming = tile_naming(&mut r, opts, &cache_name, &dir, &mut defaulted);

    let streams = stream_lists(&mut r, file);

    let default_tile = default_tile(&mut r, &cache_name, &dir);
    let _ = file.all(TokenId::NumStreams).count();

    // The COG line (docs/COG.md): under a `.ct`, the `.ct`'s COG; alone, opened and checked by
    // `crate::source::configured`.
    let cog = super::cog::read(&mut r, &dir, opts, "the image cache");
    if let Some((level, _)) = ctx.level {
        super::cog::check_level_line(&mut r, cog.as_ref(), ctx.cog.as_ref(), level);
    }

    let (ext, int, img, texel) = formats?;
    Some(ImageCachePlan {
        path: Some(file.path.clone()),
        bytes_per_texel: texel.bytes_per_texel(),
        ext_format: ext,
        int_format: int,
        img_format: img,
        texel,
        size: size?,
        tile_size: tile?,
        tiles_in_file: tiles_in_file?,
        header_offset: header_offset?,
        tex_region: tex_region?,
        tex_size: tex_size?,
        mem_region: mem_region?,
        lookahead: lookahead?,
        page_size: page_size?,
        read_func,
        naming: naming?,
        streams,
        default_tile,
        defaulted,
        cog,
    })
}

/// The tile size must divide the cache size on both axes.
fn check_tiles_divide(
    r: &mut Reader<'_>,
    size: Option<[u64; 3]>,
    tile: Option<[u64; 3]>,
    tile_f: &Field<Vec<Spanned<i64>>>,
) {
    if let (Some(sz), Some(tl)) = (size, tile) {
        for i in 0..2 {
            if tl[i] > sz[i] || sz[i] % tl[i] != 0 {
                let axis = ["S", "T"][i];
                let d = r
                    .diag(
                        Severity::Error,
                        "tile-does-not-divide",
                        values::span_of(tile_f),
                        format!("{axis} of `tile_size` ({}) does not divide the cache size ({})", tl[i], sz[i]),
                    )
                    .hint("the cache size must be a whole number of tiles; choose a tile size that divides it");
                r.push(d);
            }
        }
    }
}

/// Inside a clip texture, the image cache must describe its level: that level's size and the
/// clip texture's texel format.
fn check_against_clip_texture(
    r: &mut Reader<'_>,
    ctx: &Context,
    size: Option<[u64; 3]>,
    size_f: &Field<Vec<Spanned<i64>>>,
    formats: &Option<(FormatValue, FormatValue, FormatValue, TexelFormat)>,
) {
    if let (Some((level, lsize)), Some(sz)) = (ctx.level, size) {
        if [sz[0], sz[1]] != lsize {
            let d = r
                .diag(Severity::Error, "icache-size-mismatch", values::span_of(size_f), format!("this image cache is {}x{} but level {level} of the clip texture is {}x{}", sz[0], sz[1], lsize[0], lsize[1]))
                .hint("each level's .ic must describe that level: check the file list order (largest first) or the format's level parameter");
            r.push(d);
        }
    }
    if let (Some(want), Some((_, _, _, have))) = (ctx.texel, formats) {
        if want.bytes_per_texel() != have.bytes_per_texel() {
            let d = r
                .diag(Severity::Error, "format-mismatch", r.span_of(TokenId::ExtFormat), format!("this image cache stores {} ({} bytes per texel) but the clip texture is {} ({} bytes per texel)", have, have.bytes_per_texel(), want, want.bytes_per_texel()))
                .hint("every level must use the clip texture's texel format");
            r.push(d);
        } else if want != *have {
            let d = r.diag(
                Severity::Warning,
                "format-differs",
                r.span_of(TokenId::ExtFormat),
                format!("this image cache stores {have} but the clip texture is {want} (same size per texel)"),
            );
            r.push(d);
        }
    }
}

/// The tex region: inside a clip texture min(clip_size, icache_size) (a value in the file is
/// not used); standalone, `tex_region_size` from the file, within the cache.
fn tex_region(r: &mut Reader<'_>, clip_size: Option<u64>, size: Option<[u64; 3]>, max_size: u64) -> Option<[u64; 3]> {
    let tex_f = r.int3(TokenId::TexRegionSize);
    let tex_region = match (clip_size, size) {
        (Some(clip), Some(sz)) => {
            let want = [clip.min(sz[0]) as i64, clip.min(sz[1]) as i64];
            if let Field::Given(v, span) = &tex_f.clone() {
                let given: Vec<i64> = v.iter().map(|x| x.value).collect();
                if given.len() >= 2 && given[..2] == want {
                    // As the clip texture would set it: nothing to say.
                } else {
                    let d = r.diag(Severity::Note, "tex-region-replaced", Some(*span), format!("inside a clip texture the tex region is min(clip_size, icache_size) = {}x{}; the value here ({given:?}) is not used", clip.min(sz[0]), clip.min(sz[1])));
                    r.push(d);
                }
            }
            Some([clip.min(sz[0]), clip.min(sz[1]), 1])
        }
        (Some(_), None) => None,
        (None, _) => {
            if tex_f.is_absent() {
                values::missing(
                    r,
                    "`tex_region_size` is missing; a standalone image cache needs it",
                    "add `tex_region_size W H 1` (the part of the cache kept in texture memory)",
                );
            }
            let tr = values::size3(
                r,
                &tex_f,
                "tex_region_size",
                SizeRule { pow2: false, max: max_size, allow_two: true, r_is_one: true },
            );
            if let (Some(tr), Some(sz)) = (tr, size) {
                if tr[0] > sz[0] || tr[1] > sz[1] {
                    let d = r.diag(
                        Severity::Error,
                        "tex-region-too-large",
                        values::span_of(&tex_f),
                        format!("the tex region {}x{} is larger than the cache {}x{}", tr[0], tr[1], sz[0], sz[1]),
                    );
                    r.push(d);
                }
            }
            tr
        }
    };
    tex_region
}

/// The destination texture's size: `tex_size`, or the tex region when that is a power of two;
/// it must hold the whole tex region.
fn tex_size(
    r: &mut Reader<'_>,
    tex_region: Option<[u64; 3]>,
    max_size: u64,
    defaulted: &mut Vec<&'static str>,
) -> Option<[u64; 3]> {
    let texsize_f = r.int3(TokenId::TexSize);
    let tex_size = match (&texsize_f, tex_region) {
        (Field::Absent, Some(tr)) => {
            defaulted.push("tex_size");
            if !tr[0].is_power_of_two() || !tr[1].is_power_of_two() {
                let d = r
                    .diag(
                        Severity::Error,
                        "tex-size-not-power-of-two",
                        r.span_of(TokenId::TexRegionSize),
                        format!(
                            "the destination texture defaults to the tex region, {}x{}, which is not a power of two",
                            tr[0], tr[1]
                        ),
                    )
                    .hint(format!("add `tex_size {} {} 1`", values::next_pow2(tr[0]), values::next_pow2(tr[1])));
                r.push(d);
                None
            } else {
                Some(tr)
            }
        }
        (Field::Absent, None) => None,
        (f, tr) => {
            let ts = values::size3(
                r,
                f,
                "tex_size",
                SizeRule { pow2: true, max: max_size, allow_two: true, r_is_one: true },
            );
            if let (Some(ts), Some(tr)) = (ts, tr) {
                if ts[0] < tr[0] || ts[1] < tr[1] {
                    let d = r
                        .diag(
                            Severity::Error,
                            "tex-size-too-small",
                            values::span_of(f),
                            format!(
                                "`tex_size` {}x{} is smaller than the tex region {}x{}",
                                ts[0], ts[1], tr[0], tr[1]
                            ),
                        )
                        .hint("the destination texture must hold the whole tex region");
                    r.push(d);
                }
            }
            ts
        }
    };
    tex_size
}

/// How tiles are named: `tile_format` and `tile_params` (the default format without them).
fn tile_naming(
    r: &mut Reader<'_>,
    opts: &Options,
    cache_name: &str,
    dir: &Path,
    defaulted: &mut Vec<&'static str>,
) -> Option<TileNaming> {
    let fmt_f = r.word(TokenId::TileFormat, None);
    let params_f = r.list(TokenId::TileParams, None);
    let naming = match &fmt_f {
        Field::Given(f, _) => {
            let expanded = naming::expand_field(r, f, &opts.env);
            let params = params_f.value().cloned().unwrap_or_default();
            let pspan = values::span_of(&params_f);
            naming::check_format(r, f, &expanded, &params, pspan, Scope::Ic).map(|(fmt, refs)| {
                TileNaming::new(fmt, refs.iter().map(|p| p.param).collect(), cache_name.to_string(), dir.to_path_buf())
            })
        }
        Field::Absent => {
            if let Field::Given(p, span) = &params_f {
                if !p.is_empty() {
                    let d = r
                        .diag(
                            Severity::Warning,
                            "params-without-format",
                            Some(*span),
                            "`tile_params` without `tile_format` is ignored; the default name format is used",
                        )
                        .hint("add the `tile_format` these parameters belong to, or remove them");
                    r.push(d);
                }
            }
            defaulted.push("tile_format");
            Some(TileNaming::default_format(cache_name.to_string(), dir.to_path_buf()))
        }
        Field::Broken => None,
    };
    naming
}

/// The stream server lists of the three axes (`s_streams`, `t_streams`, `r_streams`).
fn stream_lists(r: &mut Reader<'_>, file: &SyntaxFile) -> [Vec<String>; 3] {
    let mut streams: [Vec<String>; 3] = Default::default();
    for (i, id) in [TokenId::SStreams, TokenId::TStreams, TokenId::RStreams].into_iter().enumerate() {
        if let Field::Given(items, span) = r.list(id, None) {
            if items.is_empty() {
                let d = r.diag(
                    Severity::Warning,
                    "empty-stream-list",
                    Some(span),
                    "the stream list is empty; it has no effect",
                );
                r.push(d);
            }
            for e in file.all(id) {
                if e.def.name.ends_with('s') {
                    let d = r
                        .diag(
                            Severity::Warning,
                            "plural-streams-token",
                            Some(e.span),
                            format!(
                                "Performer 3.0 reads `{}` as `{}` followed by a stream named `s`",
                                e.def.name,
                                &e.def.name[..e.def.name.len() - 1]
                            ),
                        )
                        .hint(format!(
                            "write `{}` (the singular alias) for files Performer must read",
                            &e.def.name[..e.def.name.len() - 1]
                        ));
                    r.push(portability(d));
                }
            }
            for item in &items {
                naming::note_remote(r, item.span, &item.value, "the stream server");
            }
            streams[i] = items.into_iter().map(|s| s.value).collect();
        }
    }
    streams
}

/// `default_tile`, after the cache name, anchored at the `.ic`'s directory.
fn default_tile(r: &mut Reader<'_>, cache_name: &str, dir: &Path) -> Option<Place> {
    match r.word(TokenId::DefaultTile, None) {
        Field::Given(w, _) => {
            if w.value.starts_with('$') {
                let d = r.diag(
                    Severity::Warning,
                    "default-tile-not-expanded",
                    Some(w.span),
                    "`default_tile` is not environment-expanded (as in Performer); the `$` is part of the name",
                );
                r.push(d);
            }
            let name = format!("{cache_name}{}", w.value);
            naming::note_remote(r, w.span, &name, "the default tile");
            Some(anchor(dir, &name))
        }
        _ => None,
    }
}

/// The mem region (docs/PERFORMER-REFERENCE.md §1.10): computed per axis when absent, checked when given.
#[allow(clippy::too_many_arguments)]
fn mem_region(
    r: &mut Reader<'_>,
    field: &Field<Vec<crate::config::Spanned<i64>>>,
    size: [u64; 3],
    tile: [u64; 3],
    tex: [u64; 3],
    lookahead: u64,
    max_tiles: u64,
    defaulted: &mut Vec<&'static str>,
) -> Option<[u64; 3]> {
    let tiles_in_cache = |i: usize| size[i].div_ceil(tile[i]);
    let mem = match field {
        Field::Absent => {
            defaulted.push("mem_region");
            let mut m = [1u64; 3];
            for i in 0..2 {
                m[i] = if tile[i] == size[i] {
                    1
                } else {
                    (tex[i].div_ceil(tile[i]) + 1 + lookahead).min(tiles_in_cache(i))
                };
            }
            m
        }
        Field::Broken => return None,
        Field::Given(v, span) => {
            if v.iter().any(|x| x.value == 0) {
                let d = r
                    .diag(Severity::Error, "mem-region-zero", Some(*span), "`mem_region_size` cannot be 0 in any axis")
                    .hint("remove it to let it be computed from the tex region and lookahead");
                r.push(d);
                return None;
            }
            let m = values::size3(
                r,
                field,
                "mem_region_size",
                SizeRule { pow2: false, max: u64::MAX, allow_two: true, r_is_one: false },
            )?;
            let mut ok = true;
            for i in 0..2 {
                let axis = ["S", "T"][i];
                if tex[i] > m[i].saturating_mul(tile[i]) {
                    let d = r
                        .diag(
                            Severity::Error,
                            "mem-region-too-small",
                            Some(*span),
                            format!(
                                "{axis}: the mem region ({} tiles of {}) is smaller than the tex region ({})",
                                m[i], tile[i], tex[i]
                            ),
                        )
                        .hint(format!(
                            "use at least {} tiles (remove the token to have it computed)",
                            tex[i].div_ceil(tile[i]) + 1
                        ));
                    r.push(d);
                    ok = false;
                } else if m[i] < 2 && m[i] * tile[i] < size[i] {
                    let d = r.diag(Severity::Error, "mem-region-one-tile", Some(*span), format!("{axis}: a mem region of one tile must cover the whole cache ({} texels), but the tile is {}", size[i], tile[i])).hint("use at least 2 tiles");
                    r.push(d);
                    ok = false;
                } else if m[i].saturating_mul(tile[i]) < size[i] && tex[i].div_ceil(tile[i]) + 2 > m[i] {
                    let d = r.diag(
                        Severity::Warning,
                        "mem-region-tight",
                        Some(*span),
                        format!(
                            "{axis}: {} tiles leave too few to move freely (Performer suggests at least {})",
                            m[i],
                            tex[i].div_ceil(tile[i]) + 2
                        ),
                    );
                    r.push(d);
                }
                if m[i] > tiles_in_cache(i) {
                    let d = r.diag(
                        Severity::Warning,
                        "mem-region-larger-than-cache",
                        Some(*span),
                        format!(
                            "{axis}: the mem region ({} tiles) is larger than the cache ({} tiles)",
                            m[i],
                            tiles_in_cache(i)
                        ),
                    );
                    r.push(d);
                }
            }
            if !ok {
                return None;
            }
            m
        }
    };
    // R counts too: a given R is otherwise unchecked, and the tile count multiplies it.
    if mem.iter().any(|&m| m > max_tiles) {
        let d = r
            .diag(
                Severity::Error,
                "mem-region-too-many-tiles",
                values::span_of(field).or(r.span_of(TokenId::TileSize)),
                format!(
                    "the mem region is {}x{}x{} tiles; Performer allows at most {max_tiles} along each axis",
                    mem[0], mem[1], mem[2]
                ),
            )
            .hint("use larger tiles");
        r.push(d);
        return None;
    }
    Some(mem)
}

/// `page_size`: -1 keeps the default (4096), 0 disables direct I/O, else a power of two.
pub fn page_size(
    r: &mut Reader<'_>,
    field: &Field<crate::config::Spanned<i64>>,
    inherited: Option<i64>,
    defaulted: &mut Vec<&'static str>,
) -> Option<i64> {
    match field {
        Field::Absent => {
            if inherited.is_none() {
                defaulted.push("page_size");
            }
            Some(inherited.unwrap_or(-1))
        }
        Field::Broken => None,
        Field::Given(v, _) => {
            if v.value < -1 {
                let d = r
                    .diag(
                        Severity::Error,
                        "bad-page-size",
                        Some(v.span),
                        "`page_size` must be -1 (default), 0 (no direct I/O) or a positive power of two",
                    )
                    .found(v.value.to_string());
                r.push(d);
                None
            } else {
                if v.value > 0 && !(v.value as u64).is_power_of_two() {
                    let d = r
                        .diag(
                            Severity::Warning,
                            "page-size-not-power-of-two",
                            Some(v.span),
                            "`page_size` is not a power of two; direct I/O needs a power-of-two alignment",
                        )
                        .found(v.value.to_string());
                    r.push(d);
                }
                Some(v.value)
            }
        }
    }
}

/// `read_func [LIBRARY] SYMBOL`: recorded; custom read functions are not loaded.
pub fn read_func(r: &mut Reader<'_>) -> Option<ReadFunc> {
    let e = r.file.last(TokenId::ReadFunc)?;
    let Value::List(items) = &e.value else {
        return None;
    };
    let rf = match items.as_slice() {
        [sym] => ReadFunc { library: None, symbol: sym.value.clone() },
        [lib, sym] => ReadFunc { library: Some(lib.value.clone()), symbol: sym.value.clone() },
        _ => return None,
    };
    let d = r
        .diag(Severity::Warning, "read-func-unsupported", Some(e.span), format!("custom read function `{}` is not loaded; the default reader is used (as Performer does when it cannot find one)", rf.symbol))
        .hint("remove `read_func`, or convert the data to raw tiles (clipprep)");
    r.push(d);
    Some(rf)
}

/// Synthesises the image cache of a level in no-`.ic` mode (docs/PERFORMER-REFERENCE.md §1.6).
pub(crate) struct Synth<'a> {
    /// Level and its size.
    pub level: (u32, [u64; 2]),
    /// Texel format (ext, int, img, texel).
    pub formats: (FormatValue, FormatValue, FormatValue, TexelFormat),
    /// The `.ct` `tile_size`.
    pub tile_size: [u64; 3],
    /// The naming (from `tile_base`/`tile_format`/`tile_params`, image-cache meanings).
    pub naming: TileNaming,
    /// The `.ct` header offset.
    pub header_offset: u64,
    /// Clip size, lookahead, page size, read function.
    pub clip_size: u64,
    /// Lookahead.
    pub lookahead: u64,
    /// Whether the `.ct` gave the lookahead (else it is the default, and the level's grid is
    /// the engine's to size).
    pub lookahead_given: bool,
    /// Page size.
    pub page_size: i64,
    /// Read function.
    pub read_func: Option<ReadFunc>,
    /// Where to report problems.
    pub span: Option<Span>,
    /// The `.ct` path.
    pub ct_path: &'a PathBuf,
}

impl Synth<'_> {
    /// Builds the synthesised cache, reporting problems against the `.ct`.
    pub fn build(self, diags: &mut Diagnostics, max_tiles: u64) -> Option<ImageCachePlan> {
        let (level, lsize) = self.level;
        let size = [lsize[0], lsize[1], 1];
        let tile = [self.tile_size[0].min(size[0]), self.tile_size[1].min(size[1]), 1];
        if size[0] % tile[0] != 0 || size[1] % tile[1] != 0 {
            diags.push(
                crate::config::Diagnostic::new(
                    Severity::Error,
                    "tile-does-not-divide",
                    self.ct_path,
                    self.span,
                    format!(
                        "`tile_size` {}x{} does not divide level {level} ({}x{})",
                        tile[0], tile[1], size[0], size[1]
                    ),
                )
                .hint("choose a tile size that divides every image cache level"),
            );
            return None;
        }
        let tex = [self.clip_size.min(size[0]), self.clip_size.min(size[1]), 1];
        let mut mem = [1u64; 3];
        for i in 0..2 {
            mem[i] = if tile[i] == size[i] {
                1
            } else {
                (tex[i].div_ceil(tile[i]) + 1 + self.lookahead).min(size[i].div_ceil(tile[i]))
            };
        }
        if mem[0] > max_tiles || mem[1] > max_tiles {
            diags.push(crate::config::Diagnostic::new(Severity::Error, "mem-region-too-many-tiles", self.ct_path, self.span, format!("level {level}: the mem region is {}x{} tiles; Performer allows at most {max_tiles}x{max_tiles}", mem[0], mem[1])).hint("use larger tiles"));
            return None;
        }
        let (ext, int, img, texel) = self.formats;
        Some(ImageCachePlan {
            path: None,
            bytes_per_texel: texel.bytes_per_texel(),
            ext_format: ext,
            int_format: int,
            img_format: img,
            texel,
            size,
            tile_size: tile,
            tiles_in_file: [1, 1, 1],
            header_offset: self.header_offset,
            tex_region: tex,
            tex_size: tex,
            mem_region: mem,
            lookahead: self.lookahead,
            page_size: self.page_size,
            read_func: self.read_func,
            naming: self.naming,
            streams: Default::default(),
            default_tile: None,
            defaulted: if self.lookahead_given {
                vec!["tiles_in_file", "tex_size", "mem_region"]
            } else {
                vec!["tiles_in_file", "tex_size", "mem_region", "lookahead"]
            },
            cog: None,
        })
    }
}
