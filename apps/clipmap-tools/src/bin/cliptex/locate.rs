//! `cliptex locate` and the georeferencing `cliptex info` prints for a COG or a tile pyramid
//! (docs/GEOREF.md): where a longitude / latitude is in texels of a level, and the reverse.

use clipmap::georef::{Georef, GeorefSummary};
use clipmap::report::exit;
use clipmap::source::cog::CogInfo;
use clipmap::source::CogSource;
use serde::Serialize;
use std::fmt::Write;
use std::path::Path;

/// `cliptex info --json` of a COG: its info, and `georef` (null when the file has none).
#[derive(Serialize)]
pub struct CogInfoJson<'a> {
    #[serde(flatten)]
    pub info: &'a CogInfo,
    /// The CRS's EPSG code and definition, level 0's geotransform (GDAL's order).
    pub georef: Option<GeorefSummary>,
    /// Why the file's georeferencing tags cannot be read (absent when they can, or are absent).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub georef_problem: Option<String>,
}

impl<'a> CogInfoJson<'a> {
    pub fn of(info: &'a CogInfo, src: &CogSource) -> CogInfoJson<'a> {
        let (georef, georef_problem) = match src.georef() {
            Ok(g) => (g.map(Georef::summary), None),
            Err(e) => (None, Some(e.to_string())),
        };
        CogInfoJson { info, georef, georef_problem }
    }
}

/// The lines `cliptex info` adds for a COG: its CRS, bounds (map and longitude / latitude) and
/// each level's texel size.
pub fn human(src: &CogSource, levels: u32) -> String {
    match src.georef() {
        Ok(Some(g)) => lines(g, levels),
        Ok(None) => {
            "georeferencing: none (no ModelTransformationTag, nor ModelTiepointTag with ModelPixelScaleTag)\n".into()
        }
        Err(e) => format!("georeferencing: unreadable: {e}\n"),
    }
}

/// The lines `cliptex info` prints of a georeferencing (a COG's, a tile pyramid's): its CRS,
/// bounds and each of the `levels` levels' texel size.
pub fn lines(g: &Georef, levels: u32) -> String {
    let crs = g.crs();
    let mut out = match crs.epsg_code() {
        Some(c) => format!("CRS: EPSG:{c} ({})\n", crs.definition()),
        None => format!("CRS: {}\n", crs.definition()),
    };
    let t = g.geotransform().0;
    let _ = writeln!(out, "geotransform (GDAL's order): {t:?}");
    let b = g.bounds();
    let _ = writeln!(out, "bounds (map): x {} to {}, y {} to {}", b[0], b[2], b[1], b[3]);
    match g.lonlat_bounds() {
        Ok(b) => {
            let _ = writeln!(out, "bounds (WGS 84): longitude {} to {}, latitude {} to {}", b[0], b[2], b[1], b[3]);
        }
        Err(e) => {
            let _ = writeln!(out, "bounds (WGS 84): unknown: {e}");
        }
    }
    if g.is_global_in_longitude() {
        out.push_str("spans 360 degrees of longitude\n");
    }
    let unit = if crs.is_geographic() { "degrees" } else { "map units" };
    let _ = writeln!(out, "texel size ({unit}, east x north):");
    for k in 0..levels {
        let [e, n] = g.texel_size(k);
        let _ = writeln!(out, "{k:<6} {e} x {n}");
    }
    out
}

/// What `cliptex locate` prints.
#[derive(Serialize)]
struct Located {
    level: u32,
    s: f64,
    t: f64,
    x: f64,
    y: f64,
    lon: Option<f64>,
    lat: Option<f64>,
}

/// Two comma-separated numbers (`LON,LAT`, `S,T`).
fn pair(text: &str, what: &str) -> Result<[f64; 2], String> {
    let parsed = text.split_once(',').and_then(|(a, b)| Some([a.trim().parse().ok()?, b.trim().parse().ok()?]));
    match parsed {
        Some(p @ [a, b]) if f64::is_finite(a) && f64::is_finite(b) => Ok(p),
        _ => Err(format!("--{what} {text:?}: expected two finite numbers separated by a comma")),
    }
}

/// `cliptex locate FILE (--lonlat LON,LAT | --texel S,T) [--level L] [--json]` of a COG.
pub fn run(src: &CogSource, file: &Path, lonlat: Option<&str>, texel: Option<&str>, level: u32, json: bool) -> i32 {
    let g = match src.georef() {
        Ok(Some(g)) => g,
        Ok(None) => {
            return fail(format!(
                "{}: has no georeferencing (no ModelTransformationTag, nor ModelTiepointTag with ModelPixelScaleTag): \
                 give it one (gdal_translate -a_srs EPSG:... -a_ullr ...)",
                file.display()
            ))
        }
        Err(e) => return fail(e.to_string()),
    };
    locate(g, &file.display().to_string(), lonlat, texel, level, json)
}

fn fail(m: String) -> i32 {
    eprintln!("cliptex locate: {m}");
    exit::BAD_INPUT
}

/// `cliptex locate` of any georeferenced texture (a COG, a tile pyramid) named `place`.
pub fn locate(g: &Georef, place: &str, lonlat: Option<&str>, texel: Option<&str>, level: u32, json: bool) -> i32 {
    let levels = clipmap::tile::level_count(g.size()) as u32;
    if level >= levels {
        return fail(format!("--level {level}: {place} has levels 0 to {}", levels - 1));
    }
    let located = match (lonlat, texel) {
        (Some(text), None) => pair(text, "lonlat").and_then(|[lon, lat]| {
            let [s, t] = g.lonlat_to_texel(level, [lon, lat]).map_err(|e| e.to_string())?;
            let [x, y] = g.texel_to_map_unchecked(level, [s, t]);
            Ok(Located { level, s, t, x, y, lon: Some(lon), lat: Some(lat) })
        }),
        (None, Some(text)) => pair(text, "texel").and_then(|[s, t]| {
            let [x, y] = g.texel_to_map(level, [s, t]).map_err(|e| e.to_string())?;
            let ll = g.crs().to_lonlat([x, y]).ok();
            Ok(Located { level, s, t, x, y, lon: ll.map(|p| p[0]), lat: ll.map(|p| p[1]) })
        }),
        _ => Err("give one of --lonlat LON,LAT and --texel S,T".into()),
    };
    let l = match located {
        Ok(l) => l,
        Err(m) => return fail(format!("{place}: {m}")),
    };
    clipmap::report::emit(json, &l, |l| {
        let lonlat = match (l.lon, l.lat) {
            (Some(lon), Some(lat)) => format!("longitude {lon}, latitude {lat}"),
            _ => format!("longitude / latitude unknown ({} has no known definition)", g.crs().name()),
        };
        format!(
            "level {}: texel s {}, t {} (t from the south edge); map x {}, y {} ({}); {lonlat}\n",
            l.level,
            l.s,
            l.t,
            l.x,
            l.y,
            g.crs().name()
        )
    });
    exit::OK
}
