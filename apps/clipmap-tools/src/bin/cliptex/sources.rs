//! The sources `cliptex` opens itself, beside configurations: tiled GeoTIFFs / COGs and tile
//! pyramids (templates, PMTiles, MBTiles): opening them, their `info`, `tile` and `check`.

use super::locate;
use clipmap::cli::TilesArgs;
use clipmap::place::Place;
use clipmap::report::{self, check, exit};
use clipmap::source::TileSource as _;
use std::path::{Path, PathBuf};

/// `clipmapd`'s and `cliptex info`'s clip size for a COG served as it is.
pub(crate) const COG_CLIP: u64 = 1024;

/// Whether `file` names a tiled GeoTIFF / COG: a local file that starts like a TIFF, or an
/// http(s):// or s3:// name ending in .tif / .tiff.
pub(crate) fn is_cog(file: &Path) -> bool {
    clipmap::source::cog::is_tiff_place(&Place::from_path(file.to_path_buf()))
}

/// Opens a tiled GeoTIFF / COG, local or remote, as `clipmapd` serves it; the error is printed
/// for `tool`.
pub(crate) fn open_cog(file: &Path, tool: &str) -> Result<clipmap::source::CogSource, i32> {
    clipmap::source::CogSource::open_place(&Place::from_path(file.to_path_buf()), COG_CLIP).map_err(|e| {
        eprintln!("{tool}: {e}");
        exit::BAD_INPUT
    })
}

/// The most texture tiles `cliptex check` walks in a tile pyramid.
pub(crate) const MAX_CHECKED_PYRAMID_TILES: u64 = 1 << 20;

/// Opens the tile service or tree `file` names (`xyz:TEMPLATE`), served as `clipmapd` serves it
/// (clip size 1024), or `None` when it names none; the error is printed for `tool`.
pub(crate) fn open_pyramid(
    file: &Path,
    tiles: &TilesArgs,
    tool: &str,
) -> Option<Result<clipmap::source::tiles::PyramidSource, i32>> {
    let text = file.to_string_lossy();
    if !clipmap::source::tiles::is_pyramid(&text) {
        return None;
    }
    let opts = match tiles.options(Some(COG_CLIP)) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("{tool}: {e}");
            return Some(Err(exit::BAD_INPUT));
        }
    };
    let opened = clipmap::source::tiles::open(&text, &opts)?;
    Some(opened.map_err(|e| {
        eprintln!("{tool}: {e}");
        exit::BAD_INPUT
    }))
}

/// `cliptex info xyz:...`: the pyramid and the texture it is served as.
pub(crate) fn pyramid_info(src: &clipmap::source::tiles::PyramidSource, json: bool) -> i32 {
    let d = src.desc();
    let georef = clipmap::source::TileSource::georef(src);
    let info = serde_json::json!({
        "place": src.archive().place(),
        "pyramid": src.info(),
        "size": d.size(),
        "clip_size": d.clip_size(),
        "format": d.format().to_string(),
        "georef": georef.as_ref().map(clipmap::georef::Georef::summary),
        "levels": d.levels().iter().enumerate().map(|(k, l)| serde_json::json!({
            "level": k,
            "zoom": i32::from(src.info().max_zoom) - k as i32,
            "size": l.size,
            "tile": l.tile,
            "built": (k as i32) > i32::from(src.info().max_zoom) - i32::from(src.info().min_zoom),
        })).collect::<Vec<_>>(),
    });
    report::emit(json, &info, |_| {
        let p = src.info();
        let mut out = format!(
            "{}\n  zooms {}..{}, {}-texel tiles, encoding {}, bounds {}\n  texture {}x{} texels, {}, clip size {}, {} levels (level 0 = zoom {})\n",
            src.archive().place(),
            p.min_zoom,
            p.max_zoom,
            p.tile_size,
            p.encoding.map_or("any (told by each tile)", |e| e.name()),
            p.bounds.map_or("the whole world".to_string(), |b| format!("{},{},{},{}", b[0], b[1], b[2], b[3])),
            d.size()[0],
            d.size()[1],
            d.format(),
            d.clip_size(),
            d.level_count(),
            p.max_zoom
        );
        if p.min_zoom > 0 || d.level_count() > usize::from(p.max_zoom) + 1 {
            out.push_str(&format!(
                "  levels coarser than zoom {} are built from it once, kept in memory\n",
                p.min_zoom
            ));
        }
        if let Some(g) = &georef {
            out += &locate::lines(g, d.level_count() as u32);
        }
        out
    });
    exit::OK
}

/// `cliptex tile xyz:...`: the pyramid tiles a texture tile is read from, and where they are.
pub(crate) fn pyramid_tile(src: &clipmap::source::tiles::PyramidSource, level: u32, s: u64, t: u64, json: bool) -> i32 {
    use clipmap::source::tiles::TileAddr;
    let d = src.desc();
    let p = src.info();
    if level as usize >= d.level_count() || s >= d.level(level).tiles()[0] || t >= d.level(level).tiles()[1] {
        eprintln!(
            "cliptex tile: {}: no tile ({s}, {t}) at level {level}: the texture has {} levels{}",
            src.archive().place(),
            d.level_count(),
            if (level as usize) < d.level_count() {
                format!(", level {level} has {:?} tiles", d.level(level).tiles())
            } else {
                String::new()
            }
        );
        return exit::BAD_INPUT;
    }
    let zoom = i64::from(p.max_zoom) - i64::from(level);
    let l = d.level(level);
    let mut tiles = Vec::new();
    if zoom >= i64::from(p.min_zoom) {
        let z = zoom as u8;
        let ts = u64::from(p.tile_size);
        let n = TileAddr::tiles_at(z);
        let (x0, x1) = (s * l.tile[0] / ts, ((s + 1) * l.tile[0]).min(l.size[0]).div_ceil(ts));
        let rows_from_south = (t * l.tile[1] / ts, ((t + 1) * l.tile[1]).min(l.size[1]).div_ceil(ts));
        for ty in rows_from_south.0..rows_from_south.1 {
            for x in x0..x1 {
                let at = TileAddr { z, x: x as u32, y: (n - 1 - ty) as u32 };
                tiles.push(serde_json::json!({"z": z, "x": at.x, "y": at.y, "location": src.archive().locate(at)}));
            }
        }
    }
    let out =
        serde_json::json!({"level": level, "s": s, "t": t, "zoom": zoom, "built": tiles.is_empty(), "tiles": tiles});
    report::emit(json, &out, |_| {
        if tiles.is_empty() {
            return format!(
                "level {level} (zoom {zoom}) tile ({s}, {t}): built from zoom {} (coarser than the service's)\n",
                p.min_zoom
            );
        }
        let mut text = format!("level {level} (zoom {zoom}) tile ({s}, {t}):\n");
        for t in &tiles {
            text.push_str(&format!("  {}/{}/{}  {}\n", t["z"], t["x"], t["y"], t["location"].as_str().unwrap_or("-")));
        }
        text
    });
    exit::OK
}

/// `cliptex check xyz:...`: every texture tile read and decoded as the service would.
pub(crate) fn check_pyramid(file: &Path, src: &clipmap::source::tiles::PyramidSource, json: bool, quiet: bool) -> i32 {
    let tiles: u64 = src.desc().levels().iter().map(|l| l.tiles().iter().product::<u64>()).sum();
    if tiles > MAX_CHECKED_PYRAMID_TILES {
        eprintln!(
            "cliptex check: {}: the texture has {tiles} tiles, more than the {MAX_CHECKED_PYRAMID_TILES} checked: give a lower maximum zoom (--zooms)",
            src.archive().place()
        );
        return exit::BAD_INPUT;
    }
    let max = i64::from(src.info().max_zoom);
    let min = i64::from(src.info().min_zoom);
    let kind_of = move |k: u32| if max - i64::from(k) >= min { "zoom" } else { "built" };
    let bar = tile_bar(tiles, quiet);
    let shown = PathBuf::from(src.archive().place());
    let missing = "sparse: the tile source has no tile there (no file, no archive entry, or a 404)";
    let report =
        check::run_source(&shown, &Place::from_path(file.to_path_buf()), src, &kind_of, missing, &|n| bar.inc(n));
    bar.finish_and_clear();
    report::emit(json, &report, |r| check::human(r, quiet));
    if report.servable {
        exit::OK
    } else {
        exit::BAD_INPUT
    }
}

/// A progress bar over `len` tiles on a terminal, hidden otherwise.
pub(crate) fn tile_bar(len: u64, quiet: bool) -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    if !quiet && std::io::stderr().is_terminal() {
        let bar = indicatif::ProgressBar::new(len);
        if let Ok(style) = indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} tiles {eta}") {
            bar.set_style(style);
        }
        bar
    } else {
        indicatif::ProgressBar::hidden()
    }
}

/// `cliptex check FILE.tif`: every tile of every level read and decoded as the service would.
pub(crate) fn check_cog(file: &Path, json: bool, quiet: bool) -> i32 {
    let src = match open_cog(file, "cliptex check") {
        Ok(s) => s,
        Err(c) => return c,
    };
    // Reported under the name as it may be shown (a URL's password and signatures replaced).
    let shown = PathBuf::from(clipmap::place::redacted(&file.to_string_lossy()).as_ref());
    check_cog_source(&shown, &Place::from_path(shown.clone()), &src, json, quiet)
}

/// Checks every tile of the COG `src` (at `place`), reported under the name `file` (the COG,
/// or the configuration naming it).
pub(crate) fn check_cog_source(
    file: &Path,
    place: &Place,
    src: &clipmap::source::CogSource,
    json: bool,
    quiet: bool,
) -> i32 {
    let origins = src.origins().to_vec();
    let kind_of = |k: u32| match origins.get(k as usize) {
        Some(clipmap::source::cog::LevelOrigin::Built { .. }) => "built",
        _ => "ifd",
    };
    let tiles: u64 = src.desc().levels().iter().map(|l| l.tiles().iter().product::<u64>()).sum();
    let bar = tile_bar(tiles, quiet);
    let missing = "sparse: the file holds no bytes for it (offset or byte count 0)";
    let report = check::run_source(file, place, src, &kind_of, missing, &|n| bar.inc(n));
    bar.finish_and_clear();
    report::emit(json, &report, |r| check::human(r, quiet));
    if report.servable {
        exit::OK
    } else {
        exit::BAD_INPUT
    }
}
