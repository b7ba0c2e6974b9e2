//! Configurations naming a COG (`#clipmap cog`, docs/CONFIG.md §18, docs/COG.md), loaded and
//! checked against it: the loaders every tool uses ([`load_clip_texture`], [`load_image_cache`]),
//! which are [`crate::plan`]'s with the COG opened and the header compared with it.
//!
//! A `.ct`: the COG is opened with the `.ct`'s `clip_size`, as `clipmapd FILE.tif --clip C`
//! opens it, and `virt_size` must be its size rounded up to powers of two, the formats its texel
//! format, `tile_size` (the `.ct`'s, and each `.ic`'s) its TIFF tiles cut to the level, and the
//! `#clipmap height` lines its heights. A standalone `.ic`: the COG is opened with the `.ic`'s
//! tex region as clip size, and the `.ic` describes the level whose size, rounded up to powers of
//! two, is its `icache_size`. Every disagreement is an error at the field (the file's text is
//! read again for the place), naming the value written and the COG's; a COG that cannot be
//! opened is an error at the line. The source opened is kept in the plan ([`cog_of`]) for
//! [`super::open_plan`].

use super::cog::LevelOrigin;
use super::{CogSource, TileSource};
use crate::config::{self, Diagnostic, FileKind, Severity, Span, SyntaxFile, TokenId, Value};
use crate::place::Place;
use crate::plan::cog::rounded_size;
use crate::plan::formats::{self, Which};
use crate::plan::{ClipTexturePlan, CogPlan, HeightPlan, ImageCachePlan, LevelKind, LoadError, Loaded, Options};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The COG a plan's `#clipmap cog` line names, when it was opened by this module's loaders.
pub fn cog_of(cog: &CogPlan) -> Option<Arc<CogSource>> {
    cog.opened.clone()?.downcast::<CogSource>().ok()
}

/// [`crate::plan::load_clip_texture`], with the COG a `#clipmap cog` line names opened and the
/// header checked against it (not with [`Options::ct_only`]). The COG is opened and the
/// `.ct`'s own fields checked whether or not the rest of the file gave a plan (a `virt_size`
/// that is not the COG's also makes the level lists wrong: both are said); each `.ic`'s
/// `tile_size` and the heights are checked when it did.
pub fn load_clip_texture(path: &Path, opts: &Options) -> Result<Loaded<ClipTexturePlan>, LoadError> {
    let mut loaded = crate::plan::load_clip_texture(path, opts)?;
    if opts.ct_only {
        return Ok(loaded);
    }
    let abs = crate::plan::absolute(path);
    let mut check = Check { sources: &loaded.sources, opts, found: Vec::new() };
    let Some(tree) = check.tree(&abs, FileKind::ClipTexture) else { return Ok(loaded) };
    // A `.ct` naming a tile pyramid: its header against the pyramid (`configured_tiles.rs`).
    let found = match loaded.plan.as_mut() {
        Some(plan) => match plan.source.as_ref().map(|line| super::configured_tiles::check(&abs, &tree, plan, line)) {
            Some((found, opened)) => {
                if let Some(line) = plan.source.as_mut() {
                    line.opened = opened.map(|src| src as Arc<dyn std::any::Any + Send + Sync>);
                }
                Some(found)
            }
            None => None,
        },
        None => None,
    };
    if let Some(found) = found {
        if found.iter().any(|d| d.severity == Severity::Error) {
            loaded.plan = None;
        }
        loaded.diagnostics.items.extend(found);
        return Ok(loaded);
    }
    let Some(mut cog) = crate::plan::cog::named(&tree, opts) else { return Ok(loaded) };
    let int = |id| match tree.last(id).map(|e| &e.value) {
        Some(Value::Int(v)) => u64::try_from(v.value).ok(),
        _ => None,
    };
    let clip = loaded.plan.as_ref().map(|p| p.clip_size).or(int(TokenId::ClipSize).filter(|c| c.is_power_of_two()));
    let Some(clip) = clip else { return Ok(loaded) };
    let src = check.open(&abs, &cog, clip);
    if let Some(src) = &src {
        check.header(&abs, &tree, &cog, src);
        if let Some(plan) = &loaded.plan {
            check.heights(&abs, Some(&tree), &cog, plan.height.as_ref(), src);
            check.levels(plan, &cog, src);
        }
    }
    let found = std::mem::take(&mut check.found);
    let failed = found.iter().any(|d| d.severity == Severity::Error);
    loaded.diagnostics.items.extend(found);
    match (loaded.plan.as_mut(), src) {
        (Some(plan), Some(src)) if !failed => {
            cog.size = Some(src.desc().size());
            cog.format = Some(src.desc().format());
            cog.opened = Some(src);
            plan.cog = Some(cog);
        }
        _ if failed => loaded.plan = None,
        _ => {}
    }
    Ok(loaded)
}

/// [`crate::plan::load_image_cache`], with the COG a `#clipmap cog` line names opened, the
/// level the `.ic` describes found, and its formats and `tile_size` checked against it.
pub fn load_image_cache(path: &Path, opts: &Options) -> Result<Loaded<ImageCachePlan>, LoadError> {
    let mut loaded = crate::plan::load_image_cache(path, opts)?;
    let Some(mut plan) = loaded.plan.take() else { return Ok(loaded) };
    let Some(mut cog) = plan.cog.take() else {
        loaded.plan = Some(plan);
        return Ok(loaded);
    };
    let file = plan.path.clone().unwrap_or_else(|| path.to_path_buf());
    let mut check = Check { sources: &loaded.sources, opts, found: Vec::new() };
    // The tex region as the clip size: the level is read in its TIFF tiles.
    let clip = plan.tex_region[0].max(plan.tex_region[1]).max(1);
    let level = check.open(&file, &cog, clip).and_then(|src| {
        let k = check.image_cache(&file, &plan, &cog, &src)?;
        Some((src, k))
    });
    loaded.diagnostics.items.extend(check.found);
    if let Some((src, k)) = level {
        cog.level = Some(k);
        cog.size = Some(src.desc().size());
        cog.format = Some(src.desc().format());
        cog.opened = Some(src);
        plan.cog = Some(cog);
        loaded.plan = Some(plan);
    }
    Ok(loaded)
}

/// The TIFF tile level `k` of the COG is read in (a level built past the overviews: the last
/// overview's), cut to `within` (the level's size in the configuration).
pub fn level_tile(src: &CogSource, k: u32, within: [u64; 2]) -> Option<[u64; 2]> {
    let tile = src.origins().iter().take(k as usize + 1).rev().find_map(|o| match o {
        LevelOrigin::Ifd { tile, .. } => Some(*tile),
        LevelOrigin::Built { .. } => None,
    })?;
    Some([tile[0].min(within[0]), tile[1].min(within[1])])
}

/// The checks of one load: the text of every file read, and the findings.
struct Check<'a> {
    sources: &'a BTreeMap<PathBuf, Vec<u8>>,
    opts: &'a Options,
    found: Vec<Diagnostic>,
}

impl Check<'_> {
    /// The syntax tree of `path` (read by the load), for the places of its fields.
    fn tree(&self, path: &Path, kind: FileKind) -> Option<SyntaxFile> {
        let src = self.sources.get(path)?;
        Some(config::parse_bytes(src, path, kind, &self.opts.limits).0)
    }

    /// Opens the COG `cog` (named in `file`) with clip size `clip`, reporting at its line why it
    /// cannot be.
    fn open(&mut self, file: &Path, cog: &CogPlan, clip: u64) -> Option<Arc<CogSource>> {
        match CogSource::open_place(&cog.place, clip) {
            Ok(src) => Some(Arc::new(src)),
            Err(e) => {
                let anchored = match &cog.place {
                    Place::Local(_) if !Path::new(&cog.written).is_absolute() => format!(
                        " (a relative path is taken from the directory of {}, here {})",
                        file.display(),
                        cog.place
                    ),
                    _ => String::new(),
                };
                self.found.push(
                    Diagnostic::new(
                        Severity::Error,
                        "cog-unreadable",
                        file,
                        Some(cog.span),
                        format!("the COG `{}` cannot be served: {e}", cog.written),
                    )
                    .found(format!("{}{anchored}", cog.written))
                    .expected("a tiled GeoTIFF or COG this engine serves (docs/COG.md), as `clipmapd FILE.tif` would")
                    .hint("fix the path or URL on the `#clipmap cog` line, or write the file (gdal_translate -of COG)"),
                );
                None
            }
        }
    }

    /// A field of `file` that disagrees with the COG: at `span`, `written` against the COG's
    /// `has`, with the line to write. `line` is the file's own `#clipmap cog` line, `None` for
    /// an `.ic` without one (the COG is its `.ct`'s).
    #[allow(clippy::too_many_arguments)]
    fn mismatch(
        &mut self,
        file: &Path,
        cog: &CogPlan,
        line: Option<Span>,
        span: Option<Span>,
        field: &str,
        written: String,
        has: String,
        fix: String,
    ) {
        let whose = match line {
            Some(l) => format!("this file serves (line {})", l.line),
            None => "its clip texture serves".to_string(),
        };
        self.found.push(
            Diagnostic::new(
                Severity::Error,
                "cog-mismatch",
                file,
                span.or(line),
                format!("`{field}` does not describe the COG `{}` {whose}", cog.written),
            )
            .found(written)
            .expected(has)
            .hint(fix),
        );
    }

    /// The formats of `file` (`texel`) against the COG's texel format.
    fn format(
        &mut self,
        file: &Path,
        tree: Option<&SyntaxFile>,
        cog: &CogPlan,
        line: Option<Span>,
        texel: crate::texel::TexelFormat,
        src: &CogSource,
    ) {
        let has = src.desc().format();
        if texel == has {
            return;
        }
        let names = crate::plan::formats::names_of(has)
            .map(|(e, i, m)| format!("ext_format {e}, int_format {i}, img_format {m}"))
            .unwrap_or_default();
        let span = tree.and_then(|t| t.first(TokenId::ExtFormat).or(t.first(TokenId::ImgFormat)).map(|e| e.span));
        self.mismatch(
            file,
            cog,
            line,
            span,
            "ext_format / int_format / img_format",
            format!("{texel} texels"),
            format!("{has} texels: {names}"),
            format!("write {names}"),
        );
    }

    /// `tile_size` of `file` (`tile`) against the COG's TIFF tiles of level `k`, cut to `within`.
    #[allow(clippy::too_many_arguments)]
    fn tile(
        &mut self,
        file: &Path,
        tree: Option<&SyntaxFile>,
        cog: &CogPlan,
        line: Option<Span>,
        tile: [u64; 3],
        k: u32,
        within: [u64; 2],
        src: &CogSource,
    ) {
        let Some(want) = level_tile(src, k, within) else { return };
        if [tile[0], tile[1]] == want {
            return;
        }
        let cut = if within[0] < u64::MAX { ", cut to the level" } else { "" };
        let span = tree.and_then(|t| t.first(TokenId::TileSize)).map(|e| e.span);
        self.mismatch(
            file,
            cog,
            line,
            span,
            "tile_size",
            format!("tile_size {} {} {}", tile[0], tile[1], tile[2]),
            format!("tile_size {} {} 1 (the COG's TIFF tiles of level {k}{cut})", want[0], want[1]),
            format!("write `tile_size {} {} 1`", want[0], want[1]),
        );
    }

    /// A `.ct`'s own fields against the COG, from its syntax tree: `virt_size`, the formats,
    /// `tile_size` (the last of each, as the plan takes them).
    fn header(&mut self, file: &Path, tree: &SyntaxFile, cog: &CogPlan, src: &CogSource) {
        let line = Some(cog.span);
        let int3 = |id| match tree.last(id) {
            Some(e) => match &e.value {
                Value::Int3(v) if v.len() >= 2 => Some((v.iter().map(|x| x.value).collect::<Vec<i64>>(), e.span)),
                _ => None,
            },
            None => None,
        };
        let shown = |v: &[i64]| v.iter().map(i64::to_string).collect::<Vec<_>>().join(" ");
        let size = src.desc().size();
        let want = rounded_size(size);
        if let Some((v, span)) = int3(TokenId::Size) {
            if [v[0], v[1]] != [want[0] as i64, want[1] as i64] {
                let note = if want != size {
                    format!(
                        " (its {} x {} texels rounded up to powers of two, as Performer needs; the texture is served at the COG's own size)",
                        size[0], size[1]
                    )
                } else {
                    String::new()
                };
                self.mismatch(
                    file,
                    cog,
                    line,
                    Some(span),
                    "virt_size",
                    format!("virt_size {}", shown(&v)),
                    format!("virt_size {} {} 1{note}", want[0], want[1]),
                    format!("write `virt_size {} {} 1`", want[0], want[1]),
                );
            }
        }
        let word = |id| match tree.last(id).map(|e| &e.value) {
            Some(Value::Word(w)) => Some(w.value.clone()),
            _ => None,
        };
        let ext = word(TokenId::ExtFormat).and_then(|w| formats::resolve(Which::Ext, &w).ok());
        let img = word(TokenId::ImgFormat).and_then(|w| formats::resolve(Which::Img, &w).ok());
        if let Some(texel) = ext.zip(img).and_then(|(e, i)| formats::texel_format(e.value, i.value)) {
            self.format(file, Some(tree), cog, line, texel, src);
        }
        if let Some((t, _)) = int3(TokenId::TileSize) {
            let t = [t[0].max(0) as u64, t[1].max(0) as u64, t.get(2).map_or(1, |r| r.max(&0).unsigned_abs())];
            self.tile(file, Some(tree), cog, line, t, 0, [u64::MAX, u64::MAX], src);
        }
    }

    /// The `tile_size` of each `.ic` of a `.ct` against the COG level it describes.
    fn levels(&mut self, plan: &ClipTexturePlan, cog: &CogPlan, src: &CogSource) {
        for l in &plan.levels {
            let LevelKind::Icache(ic) = &l.kind else { continue };
            let Some(ic_file) = &ic.path else { continue };
            let ic_tree = self.tree(ic_file, FileKind::ImageCache);
            let ic_line = ic.cog.as_ref().map(|c| c.span);
            self.tile(ic_file, ic_tree.as_ref(), cog, ic_line, ic.tile_size, l.level, l.size, src);
        }
    }

    /// The `#clipmap height` lines of a `.ct` against the COG's heights.
    fn heights(
        &mut self,
        file: &Path,
        tree: Option<&SyntaxFile>,
        cog: &CogPlan,
        height: Option<&HeightPlan>,
        src: &CogSource,
    ) {
        let has = src.heights();
        if height == has.as_ref() {
            return;
        }
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
        let span = tree.and_then(|t| {
            t.extensions.iter().find(|l| l.words.first().is_some_and(|w| w.value.starts_with("height"))).map(|l| l.span)
        });
        let fix = match &has {
            None => "remove the `#clipmap height` lines".to_string(),
            Some(h) => format!(
                "write `#clipmap height {}`, `#clipmap height_scale {}`, `#clipmap height_offset {}` and \
                 `#clipmap height_nodata {}` (the COG's GDAL scale, offset and GDAL_NODATA; levels mean), \
                 or let `clipprep --input COG --config-only` write them",
                h.format.storage(),
                h.format.scale(),
                h.format.offset(),
                h.format.nodata().map_or("none".to_string(), |v| v.to_string())
            ),
        };
        self.mismatch(file, cog, Some(cog.span), span, "#clipmap height", words(height), words(has.as_ref()), fix);
    }

    /// A standalone `.ic` against the COG: the level it describes, its formats and `tile_size`.
    fn image_cache(&mut self, file: &Path, plan: &ImageCachePlan, cog: &CogPlan, src: &CogSource) -> Option<u32> {
        let tree = self.tree(file, FileKind::ImageCache);
        let tree = tree.as_ref();
        let line = Some(cog.span);
        let desc = src.desc();
        let size = plan.size;
        let n = desc.level_count() as u32;
        let Some(k) = (0..n).find(|&k| rounded_size(desc.level(k).size) == [size[0], size[1]]) else {
            let sizes: Vec<String> = (0..n)
                .take(6)
                .map(|k| {
                    let s = desc.level(k).size;
                    let p = rounded_size(s);
                    format!("level {k}: {} x {} ({} x {} rounded up)", p[0], p[1], s[0], s[1])
                })
                .collect();
            let span = tree.and_then(|t| t.first(TokenId::Size)).map(|e| e.span);
            self.mismatch(
                file,
                cog,
                line,
                span,
                "icache_size",
                format!("icache_size {} {} {}", size[0], size[1], size[2]),
                format!("the size of a level of the COG, rounded up to powers of two: {}", sizes.join(", ")),
                "write the `icache_size` of the level this image cache describes".into(),
            );
            return None;
        };
        let before = self.found.len();
        self.format(file, tree, cog, line, plan.texel, src);
        self.tile(file, tree, cog, line, plan.tile_size, k, [size[0], size[1]], src);
        (self.found.len() == before).then_some(k)
    }
}
