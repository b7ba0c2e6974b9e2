//! `info` and `tile`: every value of a configuration with defaults marked, the level table, and
//! where a tile's texels are.

use super::human_bytes;
use crate::config::{Diagnostic, Severity};
use crate::place::Place;
use crate::plan::{ClipTexturePlan, ImageCachePlan, LevelKind, TileLocation};
use serde::Serialize;
use std::path::PathBuf;

/// One row of the level table.
#[derive(Debug, Serialize)]
pub struct LevelRow {
    /// Level number.
    pub level: u32,
    /// Size in texels.
    pub size: [u64; 2],
    /// `icache` or `pyramid`.
    pub kind: &'static str,
    /// The level's `.ic` file (absolute), or null (pyramid levels, no-`.ic` mode).
    pub icache_config: Option<PathBuf>,
    /// The pyramid file (absolute), or null (image cache levels, unnamed pyramid levels).
    pub tile_file: Option<Place>,
    /// Tile size in texels (a pyramid level is one tile). Null (unknown) when the level's `.ic`
    /// was not opened (`--ct-only`), as for the fields below but `tex_region`.
    pub tile_size: Option<[u64; 2]>,
    /// Tex region in texels. Inside a clip texture it is min(clip_size, level size) per side,
    /// which the `.ct` alone fixes: known under `--ct-only` too.
    pub tex_region: Option<[u64; 2]>,
    /// Mem region in tiles.
    pub mem_region: Option<[u64; 2]>,
    /// Header bytes of each file.
    pub header_offset: Option<u64>,
    /// Tiles along S and T.
    pub tiles: Option<[u64; 2]>,
    /// False when the level's `.ic` was named but not opened (`--ct-only`).
    pub icache_opened: bool,
}

/// `cliptex info --json`.
#[derive(Debug, Serialize)]
pub struct ClipTextureInfo<'a> {
    /// The `.ct` file.
    pub path: &'a std::path::Path,
    /// Level-0 size.
    pub virt_size: [u64; 3],
    /// Clip size.
    pub clip_size: u64,
    /// Invalid border in use.
    pub invalid_border: u64,
    /// Effective levels.
    pub effective_levels: u32,
    /// Allocated levels as written (1000: all).
    pub allocated_levels: u32,
    /// Smallest image cache.
    pub smallest_icache: [u64; 3],
    /// Bytes per texel.
    pub bytes_per_texel: u32,
    /// Texel format short name.
    pub texel_format: String,
    /// `ext_format`, `int_format`, `img_format` as written.
    pub formats: [&'a str; 3],
    /// Level count.
    pub level_count: usize,
    /// Virtual clip texture.
    pub is_virtual: bool,
    /// Header offset of pyramid files.
    pub header_offset: u64,
    /// Lookahead.
    pub lookahead: u64,
    /// The paging settings of the `#clipmap` lines (docs/CONFIG.md §16), when they differ from
    /// the defaults.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub paging: Option<crate::paging::PagingOptions>,
    /// The heights the `#clipmap height…` lines declare (storage, scale, offset, nodata, level
    /// rule; docs/ELEVATION.md), absent for a texture of colours.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub height: Option<crate::plan::HeightPlan>,
    /// Page size.
    pub page_size: i64,
    /// How the `.ic` files are named.
    pub icache_mode: crate::plan::GroupMode,
    /// How the pyramid files are named.
    pub tile_mode: crate::plan::GroupMode,
    /// Fields that took their default.
    pub defaulted: &'a [&'static str],
    /// Warnings and notes.
    pub warnings: &'a [Diagnostic],
    /// The level table.
    pub levels: Vec<LevelRow>,
    /// The COG the `#clipmap cog` line names, as it is served (its size, format and levels;
    /// docs/COG.md): the texture served is this one. `null` for a texture of tile files.
    pub cog: Option<crate::source::cog::CogInfo>,
    /// Where the texture is on the Earth, as its `#clipmap georef_…` lines record it
    /// (docs/GEOREF.md, "Prepared pyramids"): `{"epsg", "crs", "geotransform"}`, or null.
    pub georef: Option<crate::georef::GeorefSummary>,
}

fn two(a: [u64; 3]) -> [u64; 2] {
    [a[0], a[1]]
}

/// The level table of a clip texture.
pub(crate) fn level_rows(plan: &ClipTexturePlan) -> Vec<LevelRow> {
    plan.levels
        .iter()
        .map(|l| match &l.kind {
            LevelKind::Icache(ic) => LevelRow {
                level: l.level,
                size: l.size,
                kind: "icache",
                icache_config: ic.path.clone(),
                tile_file: None,
                tile_size: Some(two(ic.tile_size)),
                tex_region: Some(two(ic.tex_region)),
                mem_region: Some(two(ic.mem_region)),
                header_offset: Some(ic.header_offset),
                tiles: Some(two(ic.tile_count())),
                icache_opened: true,
            },
            LevelKind::IcacheNotOpened { path } => LevelRow {
                level: l.level,
                size: l.size,
                kind: "icache",
                icache_config: Some(path.clone()),
                tile_file: None,
                tile_size: None,
                // As the .ic's plan sets it (a differing `tex_region_size` there is not used).
                tex_region: Some([l.size[0].min(plan.clip_size), l.size[1].min(plan.clip_size)]),
                mem_region: None,
                header_offset: None,
                tiles: None,
                icache_opened: false,
            },
            LevelKind::Pyramid(p) => LevelRow {
                level: l.level,
                size: l.size,
                kind: "pyramid",
                icache_config: None,
                tile_file: p.path.clone(),
                tile_size: Some(l.size),
                tex_region: Some(l.size),
                mem_region: Some([1, 1]),
                header_offset: Some(p.header_offset),
                tiles: Some([1, 1]),
                icache_opened: true,
            },
        })
        .collect()
}

/// Builds the JSON form of `cliptex info`.
pub fn clip_texture<'a>(plan: &'a ClipTexturePlan, warnings: &'a [Diagnostic]) -> ClipTextureInfo<'a> {
    ClipTextureInfo {
        path: &plan.path,
        virt_size: plan.virt_size,
        clip_size: plan.clip_size,
        invalid_border: plan.invalid_border,
        effective_levels: plan.effective_levels,
        allocated_levels: plan.allocated_levels,
        smallest_icache: plan.smallest_icache,
        bytes_per_texel: plan.bytes_per_texel,
        texel_format: plan.texel.short_name(),
        formats: [&plan.ext_format.written, &plan.int_format.written, &plan.img_format.written],
        level_count: plan.levels.len(),
        is_virtual: plan.is_virtual,
        header_offset: plan.header_offset,
        lookahead: plan.lookahead,
        paging: (plan.paging != crate::paging::PagingOptions::default()).then_some(plan.paging),
        height: plan.height,
        page_size: plan.page_size,
        icache_mode: plan.icache_mode,
        tile_mode: plan.tile_mode,
        defaulted: &plan.defaulted,
        warnings,
        levels: level_rows(plan),
        cog: cog_info(plan),
        georef: plan.georef.as_ref().map(crate::georef::Georef::summary),
    }
}

/// The served texture of the COG a plan names, when it was opened.
fn cog_info(plan: &ClipTexturePlan) -> Option<crate::source::cog::CogInfo> {
    plan.cog.as_ref().and_then(crate::source::cog_of).map(|src| src.info())
}

fn mark(defaulted: &[&str], key: &str) -> &'static str {
    if defaulted.contains(&key) {
        "  (default)"
    } else {
        ""
    }
}

fn rel(p: Option<&std::path::Path>, base: &std::path::Path) -> String {
    match p {
        None => "-".into(),
        Some(p) => p.strip_prefix(base).unwrap_or(p).display().to_string(),
    }
}

/// A tile file as [`rel`] writes a path; a remote location as written.
fn rel_place(p: &Option<Place>, base: &std::path::Path) -> String {
    match p {
        Some(Place::Remote(name)) => name.to_string(),
        p => rel(p.as_ref().and_then(Place::as_local), base),
    }
}

/// The human form of `cliptex info`.
pub fn clip_texture_human(plan: &ClipTexturePlan) -> String {
    let d = &plan.defaulted;
    let dir = plan.path.parent().unwrap_or(std::path::Path::new(""));
    let mut o = String::new();
    let n = plan.levels.len();
    o.push_str(&format!("clip texture   {}\n", plan.path.display()));
    o.push_str(&format!("version        {}\n", plan.version.as_deref().unwrap_or("(none)")));
    o.push_str(&format!(
        "texel          {} ({} bytes{}; ext_format {}, int_format {}, img_format {})\n",
        plan.texel,
        plan.bytes_per_texel,
        if plan.texel.block().is_some() { " a 4 x 4 block" } else { "" },
        plan.ext_format.written,
        plan.int_format.written,
        plan.img_format.written
    ));
    o.push_str(&format!("virt_size      {} x {} x {}\n", plan.virt_size[0], plan.virt_size[1], plan.virt_size[2]));
    o.push_str(&format!("clip_size      {}\n", plan.clip_size));
    o.push_str(&format!(
        "invalid_border {}{}  (effective size {})\n",
        plan.invalid_border,
        mark(d, "invalid_border"),
        plan.clip_size.saturating_sub(2 * plan.invalid_border)
    ));
    o.push_str(&format!(
        "levels         {n} ({} image cache, {} pyramid)\n",
        plan.icache_levels(),
        n - plan.icache_levels()
    ));
    o.push_str(&format!(
        "effective      {}{}{}\n",
        plan.effective_levels,
        mark(d, "effective_levels"),
        if plan.is_virtual { "  (virtual clip texture)" } else { "" }
    ));
    o.push_str(&format!("allocated      {}{}\n", plan.allocated_levels, mark(d, "allocated_levels")));
    o.push_str(&format!(
        "smallest_icache {} x {} x {}{}\n",
        plan.smallest_icache[0],
        plan.smallest_icache[1],
        plan.smallest_icache[2],
        mark(d, "smallest_icache")
    ));
    o.push_str(&format!("header_offset  {}{}\n", plan.header_offset, mark(d, "header_offset")));
    o.push_str(&format!("lookahead      {}{}\n", plan.lookahead, mark(d, "lookahead")));
    let p = &plan.paging;
    if *p != crate::paging::PagingOptions::default() {
        let clamp = p.max_centre_step.map_or("off".to_string(), |c| format!("{c} texels a tick"));
        o.push_str(&format!(
            "paging         prefetch {}, pool {} bytes ({} eviction), centre step {clamp}  (#clipmap)\n",
            p.prefetch, p.pool_bytes, p.eviction
        ));
    }
    if let Some(h) = &plan.height {
        let f = &h.format;
        let nodata = f.nodata().map_or("none".to_string(), |v| v.to_string());
        let (lo, hi) = f.metre_bounds();
        o.push_str(&format!(
            "heights        {}: metres = stored x {} + {}, nodata {nodata}, {lo} m to {hi} m; levels {} ({})  (#clipmap)\n",
            f.storage(),
            f.scale(),
            f.offset(),
            h.levels,
            match h.levels {
                crate::height::LevelRule::Mean => "mean of the finer texels with data",
                crate::height::LevelRule::Point => "point-registered: the finer texel at the even position",
                crate::height::LevelRule::Min => "least of the finer texels with data",
                crate::height::LevelRule::Max => "greatest of the finer texels with data",
            }
        ));
    }
    match &plan.georef {
        Some(g) => o.push_str(&format!(
            "georef         {}, level 0's geotransform (GDAL's order) {:?}  (#clipmap)\n",
            g.crs().name(),
            g.geotransform().0
        )),
        None if plan.cog.is_none() && plan.source.is_none() => {
            o.push_str("georef         none (no `#clipmap georef_` lines; docs/GEOREF.md)\n")
        }
        None => {}
    }
    o.push_str(&format!("page_size      {}{}\n", plan.page_size, mark(d, "page_size")));
    o.push_str(&format!("naming         .ic files: {:?}, pyramid files: {:?}\n", plan.icache_mode, plan.tile_mode));
    // Bytes a texel, in sixteenths: a block format's block bytes cover 16 texels.
    let bpt = plan.bytes_per_texel as u128 * if plan.texel.block().is_some() { 1 } else { 16 };
    let resident: u128 = plan
        .levels
        .iter()
        .map(|l| (l.size[0].min(plan.clip_size) as u128) * (l.size[1].min(plan.clip_size) as u128))
        .sum();
    let full: u128 = plan.levels.iter().map(|l| l.size[0] as u128 * l.size[1] as u128).sum();
    o.push_str(&format!(
        "resident       {} texels ({}) against {} ({}) for the full mipmap\n",
        resident,
        human_bytes(resident * bpt / 16),
        full,
        human_bytes(full * bpt / 16)
    ));
    o.push_str("\nlevel  size              kind     tile          tex region   mem region  file\n");
    let pair = |v: Option<[u64; 2]>| v.map(|[a, b]| format!("{a}x{b}")).unwrap_or_else(|| "?".into());
    for r in level_rows(plan) {
        let file = if r.kind == "icache" { rel(r.icache_config.as_deref(), dir) } else { rel_place(&r.tile_file, dir) };
        let file = if r.kind == "icache" && r.icache_config.is_none() {
            "(no .ic: synthesised)".to_string()
        } else if !r.icache_opened {
            format!("{file}  (not opened)")
        } else {
            file
        };
        o.push_str(&format!(
            "{:<6} {:<17} {:<8} {:<13} {:<12} {:<11} {}\n",
            r.level,
            format!("{}x{}", r.size[0], r.size[1]),
            r.kind,
            pair(r.tile_size),
            pair(r.tex_region),
            pair(r.mem_region),
            file
        ));
    }
    if plan.is_ct_only() {
        o.push_str("\n.ct only: the .ic files were not opened; `?` marks what only they give.\n");
    }
    if let Some(c) = &plan.cog {
        o.push_str(&format!(
            "\ntexels from the COG {} (`#clipmap cog`): the texture is served as the COG is, not from the tile files above",
            c.place
        ));
        match cog_info(plan) {
            Some(info) => {
                o.push_str(":\n");
                o.push_str(&info.human());
            }
            None => o.push_str(" (not opened)\n"),
        }
    }
    if let Some(line) = &plan.source {
        o.push_str(&format!(
            "\ntexels from the tile source {} (`#clipmap source`): the texture is served as the pyramid is (docs/TILES.md), with the clip size above, not from the tile files above\n",
            crate::place::redacted(&line.name)
        ));
    }
    o
}

/// `icache info --json`.
#[derive(Debug, Serialize)]
pub struct ImageCacheInfo<'a> {
    /// The plan (every value).
    #[serde(flatten)]
    pub plan: &'a ImageCachePlan,
    /// Tiles along S, T, R.
    pub tiles: [u64; 3],
    /// Bytes of one tile.
    pub tile_bytes: u64,
    /// Where tile (0, 0) is.
    pub first_tile: Option<TileLocation>,
    /// Warnings and notes.
    pub warnings: &'a [Diagnostic],
}

/// The JSON form of `icache info`.
pub fn image_cache<'a>(plan: &'a ImageCachePlan, warnings: &'a [Diagnostic]) -> ImageCacheInfo<'a> {
    ImageCacheInfo {
        plan,
        tiles: plan.tile_count(),
        tile_bytes: plan.tile_bytes(),
        first_tile: plan.locate(0, 0, 0).ok(),
        warnings,
    }
}

/// The human form of `icache info`.
pub fn image_cache_human(plan: &ImageCachePlan) -> String {
    let d = &plan.defaulted;
    let t = plan.tile_count();
    let mut o = String::new();
    let f3 = |a: [u64; 3]| format!("{} x {} x {}", a[0], a[1], a[2]);
    o.push_str(&format!(
        "image cache    {}\n",
        plan.path.as_ref().map(|p| p.display().to_string()).unwrap_or_else(|| "(synthesised)".into())
    ));
    o.push_str(&format!(
        "texel          {} ({} bytes; ext_format {}, int_format {}, img_format {})\n",
        plan.texel, plan.bytes_per_texel, plan.ext_format.written, plan.int_format.written, plan.img_format.written
    ));
    o.push_str(&format!("icache_size    {}\n", f3(plan.size)));
    o.push_str(&format!(
        "tile_size      {}  ({} x {} tiles, {} each)\n",
        f3(plan.tile_size),
        t[0],
        t[1],
        human_bytes(plan.tile_bytes() as u128)
    ));
    o.push_str(&format!("tiles_in_file  {}{}\n", f3(plan.tiles_in_file), mark(d, "tiles_in_file")));
    o.push_str(&format!("header_offset  {}{}\n", plan.header_offset, mark(d, "header_offset")));
    o.push_str(&format!("tex_region     {}\n", f3(plan.tex_region)));
    o.push_str(&format!("tex_size       {}{}\n", f3(plan.tex_size), mark(d, "tex_size")));
    o.push_str(&format!(
        "mem_region     {} tiles{}  ({} in memory)\n",
        f3(plan.mem_region),
        mark(d, "mem_region"),
        human_bytes(plan.mem_region.iter().product::<u64>() as u128 * plan.tile_bytes() as u128)
    ));
    o.push_str(&format!("lookahead      {}{}\n", plan.lookahead, mark(d, "lookahead")));
    o.push_str(&format!("page_size      {}{}\n", plan.page_size, mark(d, "page_size")));
    o.push_str(&format!("tile_format    {}{}\n", plan.naming.format, mark(d, "tile_format")));
    o.push_str(&format!(
        "tile_params    {}\n",
        plan.naming.params.iter().map(|p| p.short()).collect::<Vec<_>>().join(" ")
    ));
    o.push_str(&format!("cache name     {:?}\n", plan.naming.cache_name));
    for (axis, list) in ["s", "t", "r"].iter().zip(&plan.streams) {
        if !list.is_empty() {
            o.push_str(&format!("{axis}_streams      {}\n", list.join(" ")));
        }
    }
    if let Some(dt) = &plan.default_tile {
        o.push_str(&format!("default_tile   {dt}\n"));
    }
    if let Ok(loc) = plan.locate(0, 0, 0) {
        o.push_str(&format!("tile (0, 0)    {} @ {} (+{} bytes)\n", loc.path, loc.offset, loc.length));
    }
    if let Some(c) = &plan.cog {
        let level = c.level.map_or(String::new(), |k| format!(", its level {k}"));
        let size = c.size.map_or(String::new(), |s| format!(" ({} x {} texels at level 0)", s[0], s[1]));
        o.push_str(&format!("cog            {}{size}{level}: tiles are read from it (#clipmap cog)\n", c.place));
    }
    o
}

/// The human form of a tile location.
pub(crate) fn tile_human(loc: &TileLocation) -> String {
    let mut o = format!("path    {}\noffset  {}\nlength  {}\n", loc.path, loc.offset, loc.length);
    if !loc.stream.is_empty() {
        o.push_str(&format!("stream  {}\n", loc.stream));
    }
    o
}

/// Warnings and notes of a loaded plan (errors make no plan).
pub fn non_errors(diags: &[Diagnostic]) -> Vec<Diagnostic> {
    diags.iter().filter(|d| d.severity != Severity::Error).cloned().collect()
}

/// Prints a tile location (or why there is none) for `cliptex tile` / `icache tile`; returns the
/// exit status.
pub fn print_tile(
    found: Result<TileLocation, crate::plan::TileError>,
    json: bool,
    tool: &str,
    file: &std::path::Path,
) -> i32 {
    match found {
        Ok(loc) => {
            super::emit(json, &loc, tile_human);
            super::exit::OK
        }
        Err(e) => {
            eprintln!("{tool}: {}: {e}", file.display());
            super::exit::BAD_INPUT
        }
    }
}
