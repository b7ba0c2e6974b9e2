//! `cliptex dump` and `icache dump` from disk: a region of one level read from its tile files
//! and written as a PNG: 8-bit RGB (RGBA for formats with alpha), or for the 16-bit formats a
//! 16-bit PNG of their components (grey, grey+alpha, RGB, RGBA) with the stored values exactly.
//!
//! Owns choosing and checking the region, gathering its tiles, converting texels and reporting
//! the tiles that could not be read (painted with `picture::missing_pattern`, never fatal).
//! Reading a tile is the caller's function: a [`crate::source::FileSource`] for a clip texture,
//! [`IcacheTiles`] for a standalone image cache. Pictures of a running service are
//! `clipmap_tools::inspect::live_dump`'s business.

use super::picture;
use crate::geom::{tile_texels, tiles_covering, Rect};
use crate::place::Place;
use crate::plan::ImageCachePlan;
use crate::source::{FaultKind, SourceError, TileId};
use crate::texel::{ComponentType, Components, TexelFormat};
use image::{DynamicImage, ImageBuffer, Luma, LumaA, Rgb, RgbImage, Rgba, RgbaImage};
use serde::Serialize;
use std::path::{Path, PathBuf};
use thiserror::Error;

pub use crate::limits::MAX_DUMP_TEXELS;

/// Why a dump could not be made.
#[derive(Debug, Error)]
pub enum DumpError {
    /// `--region` is not four numbers.
    #[error("--region `{text}`: expected S0,T0,S1,T1 (four whole numbers, the half-open texel rectangle [S0, S1) x [T0, T1))")]
    RegionSyntax {
        /// The text given.
        text: String,
    },
    /// The region is empty or leaves the level.
    #[error(
        "--region {s0},{t0},{s1},{t1} does not fit {what} ({w}x{h} texels): expected 0 <= S0 < S1 <= {w} and 0 <= T0 < T1 <= {h}"
    )]
    RegionOutside {
        /// The level (or picture) the region is of.
        what: String,
        /// First texel column of the region.
        s0: u64,
        /// First texel row of the region.
        t0: u64,
        /// One past its last column.
        s1: u64,
        /// One past its last row.
        t1: u64,
        /// Its width in texels.
        w: u64,
        /// Its height in texels.
        h: u64,
    },
    /// The region holds more texels than a dump writes.
    #[error(
        "{what} is {w}x{h} texels, more than one dump writes ({max} texels, as 4096x4096 does); choose a part with --region S0,T0,S1,T1, e.g. --region {s0},{t0},{s1},{t1}"
    )]
    TooLarge {
        /// The level (or region) asked for.
        what: String,
        /// Its width in texels.
        w: u64,
        /// Its height in texels.
        h: u64,
        /// The most texels one dump writes.
        max: u64,
        /// First texel column of a region that fits, suggested.
        s0: u64,
        /// Its first texel row.
        t0: u64,
        /// One past its last column.
        s1: u64,
        /// One past its last row.
        t1: u64,
    },
    /// The level does not exist.
    #[error("--level {level}: the texture has levels 0 to {last}")]
    NoLevel {
        /// The level asked for.
        level: u32,
        /// The texture's last level.
        last: u32,
    },
    /// The PNG could not be written.
    #[error("cannot write {}: {message}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why it could not be written.
        message: String,
    },
}

impl DumpError {
    /// The exit status: an unwritable output is 2 (the tool could not run); a region or level
    /// that does not fit is 1 (the input is bad).
    pub fn exit_code(&self) -> i32 {
        match self {
            DumpError::Write { .. } => super::exit::COULD_NOT_RUN,
            _ => super::exit::BAD_INPUT,
        }
    }
}

/// The error for an output file that could not be written, with the likely fix.
pub(crate) fn write_error(path: &Path, e: impl std::fmt::Display) -> DumpError {
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty());
    let message = match parent {
        Some(dir) if !dir.is_dir() => {
            format!("{e}: the directory {} does not exist; create it or write elsewhere", dir.display())
        }
        _ => format!("{e}; check the path and its permissions"),
    };
    DumpError::Write { path: path.to_path_buf(), message }
}

/// Parses `S0,T0,S1,T1`.
pub fn parse_region(text: &str) -> Result<[u64; 4], DumpError> {
    let v: Vec<u64> = text
        .split(',')
        .map(|w| w.trim().parse::<u64>())
        .collect::<Result<_, _>>()
        .map_err(|_| DumpError::RegionSyntax { text: text.to_string() })?;
    <[u64; 4]>::try_from(v).map_err(|_| DumpError::RegionSyntax { text: text.to_string() })
}

/// Reads one tile into a buffer of one tile.
pub(crate) type ReadTile<'a> = dyn Fn(TileId, &mut [u8]) -> Result<(), SourceError> + 'a;

/// One level's geometry and its tile reader.
pub struct LevelTiles<'a> {
    /// Level number (for messages and tile ids); `None` for a standalone image cache.
    pub level: Option<u32>,
    /// Level size in texels.
    pub size: [u64; 2],
    /// Tile size in texels (the level size for a pyramid level).
    pub tile: [u64; 2],
    /// Texel format.
    pub format: TexelFormat,
    /// Reads tile (S, T) into a buffer of one tile.
    pub read: &'a ReadTile<'a>,
    /// The file a tile is read from, for messages (`None` where the configuration names none).
    pub file_of: &'a dyn Fn(TileId) -> Option<Place>,
}

/// A tile that could not be read.
#[derive(Clone, Debug, Serialize)]
pub struct MissingTile {
    /// Tile column.
    pub s: u64,
    /// Tile row.
    pub t: u64,
    /// What kind of failure.
    pub kind: FaultKind,
    /// The reader's message.
    pub problem: String,
    /// The file the tile should be read from.
    pub path: Option<String>,
}

/// What a dump wrote.
#[derive(Clone, Debug, Serialize)]
pub struct DumpReport {
    /// The configuration read.
    pub file: String,
    /// The level dumped (`null` for a standalone image cache).
    pub level: Option<u32>,
    /// Its size.
    pub level_size: [u64; 2],
    /// The region `[s0, t0, s1, t1)` in level texels.
    pub region: [u64; 4],
    /// Texel format on disk.
    pub format: String,
    /// The PNG written.
    pub png: String,
    /// The PNG's pixels: `rgb` or `rgba` (8 bits per sample), or for 16-bit formats `l16`,
    /// `la16`, `rgb16` or `rgba16` (16 bits per sample, grey, grey+alpha, RGB, RGBA).
    pub colour: &'static str,
    /// PNG width and height (the region's, one pixel per texel).
    pub pixels: [u64; 2],
    /// Tiles the region covers (each read once).
    pub tiles: u64,
    /// Tiles that could not be read (painted magenta and black).
    pub missing: Vec<MissingTile>,
    /// A height texture's picture: its legend (absent for colour textures).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heights: Option<HeightLegend>,
}

/// The legend of a height picture (docs/ELEVATION.md): the map is the picture's top-left
/// region-sized part, the legend the rows below it.
#[derive(Clone, Debug, Serialize)]
pub struct HeightLegend {
    /// The storage (`l32f`, `l16`, `l16i`).
    pub storage: String,
    /// The colour bar's lowest and highest metres: the region's least and greatest height with
    /// data, or `--range`; `null` when the region holds no data and no range was given.
    pub range: Option<[f64; 2]>,
    /// Whether the range came from `--range`.
    pub range_given: bool,
    /// The least and greatest height with data in the region, metres (`null`: none).
    pub region_range: Option<[f64; 2]>,
    /// Texels without data in the region.
    pub nodata_texels: u64,
    /// Whether the map is hillshaded.
    pub shaded: bool,
    /// The map's size in pixels (the region's; the picture is larger by the legend).
    pub map: [u64; 2],
    /// The legend's labels at the bar's ends.
    pub labels: [String; 2],
}

/// What a height dump draws: the format, `--range` and `--shade`.
#[derive(Clone, Copy, Debug)]
pub struct HeightView {
    /// The texture's height format.
    pub format: crate::height::HeightFormat,
    /// The colour bar's metres (default: the region's range).
    pub range: Option<[f64; 2]>,
    /// Hillshade the map.
    pub shade: bool,
}

/// Parses `--range MIN,MAX` (metres, finite, MIN below MAX).
pub fn parse_range(text: &str) -> Result<[f64; 2], String> {
    let bad = || {
        format!("--range `{text}`: expected MIN,MAX in metres, two finite numbers with MIN below MAX, e.g. -100,2500")
    };
    let (a, b) = text.split_once(',').ok_or_else(bad)?;
    let num = |w: &str| w.trim().parse::<f64>().ok().filter(|v| v.is_finite());
    match (num(a), num(b)) {
        (Some(lo), Some(hi)) if lo < hi => Ok([lo, hi]),
        _ => Err(bad()),
    }
}

/// Dumps `region` of a level of heights to the PNG `out` in false colour with a legend
/// ([`super::hypsometric`]): RGBA, nodata transparent, tiles that could not be read painted
/// magenta and black.
pub fn dump_heights(
    file: &Path,
    src: &LevelTiles,
    view: &HeightView,
    region: Option<[u64; 4]>,
    out: &Path,
) -> Result<DumpReport, DumpError> {
    use super::hypsometric::Texel;
    let what = match src.level {
        Some(k) => format!("level {k}, the whole level,"),
        None => "the image cache, all of it,".to_string(),
    };
    let r = choose_region(src.level, src.size, region, &what)?;
    let f = view.format;
    let bpt = f.bytes_per_texel();
    let (w, h) = (r.width() as usize, r.height() as usize);
    let mut map = vec![Texel::Missing; w * h];
    let tiles = tiles_covering(r, src.tile);
    let mut buf = vec![0u8; (src.tile[0] * src.tile[1]) as usize * bpt];
    let (mut read, mut missing) = (0, Vec::new());
    for tt in tiles.t0..tiles.t1 {
        for ts in tiles.s0..tiles.s1 {
            let id = TileId::new(src.level.unwrap_or(0), ts as u64, tt as u64);
            read += 1;
            if let Err(e) = (src.read)(id, &mut buf) {
                let text = e.to_string();
                let problem = text.strip_prefix(&format!("{id}: ")).unwrap_or(&text).to_string();
                let path = (src.file_of)(id).map(|p| p.to_string());
                missing.push(MissingTile { s: id.s, t: id.t, kind: e.kind(), problem, path });
                continue;
            }
            let texels = tile_texels(src.size, src.tile, [id.s, id.t]).intersect(&r);
            for t in texels.t0..texels.t1 {
                let y = (r.t1 - 1 - t) as usize;
                for s in texels.s0..texels.s1 {
                    let j = (((t as u64 - id.t * src.tile[1]) * src.tile[0] + (s as u64 - id.s * src.tile[0]))
                        as usize)
                        * bpt;
                    map[y * w + (s - r.s0) as usize] = match f.decode(f.read(&buf[j..j + bpt])) {
                        Some(m) if m.is_finite() => Texel::Height(m),
                        _ => Texel::Nodata,
                    };
                }
            }
        }
    }
    let (img, legend) = height_picture(&map, w as u32, h as u32, view, picture::missing_pattern);
    let (pw, ph) = img.dimensions();
    crate::save::atomically(out, |wr| {
        DynamicImage::ImageRgba8(img).write_to(wr, image::ImageFormat::Png).map_err(crate::save::image_io)
    })
    .map_err(|e| write_error(out, e))?;
    Ok(DumpReport {
        file: file.display().to_string(),
        level: src.level,
        level_size: src.size,
        region: [r.s0 as u64, r.t0 as u64, r.s1 as u64, r.t1 as u64],
        format: src.format.short_name(),
        png: out.display().to_string(),
        colour: "rgba",
        pixels: [pw as u64, ph as u64],
        tiles: read,
        missing,
        heights: Some(legend),
    })
}

/// The false-colour picture of a map of heights (`w` x `h` texels, rows top-down) and its legend,
/// as `cliptex dump` draws a level of heights: the colour bar over `view`'s range (default the
/// map's least and greatest height with data), hillshaded when `view` says so, nodata
/// transparent, a texel of [`Texel::Missing`](super::hypsometric::Texel::Missing) painted by `missing` (the pixel's x and y). Also
/// `cliptex dump --attach`'s picture of each level of a height texture.
pub fn height_picture(
    map: &[super::hypsometric::Texel],
    w: u32,
    h: u32,
    view: &HeightView,
    missing: impl Fn(u32, u32) -> [u8; 4],
) -> (RgbaImage, HeightLegend) {
    use super::hypsometric::{self, Texel};
    let mut region_range: Option<[f64; 2]> = None;
    let mut nodata_texels = 0;
    for t in map {
        match *t {
            Texel::Height(m) => {
                region_range = Some(region_range.map_or([m, m], |[lo, hi]| [lo.min(m), hi.max(m)]));
            }
            Texel::Nodata => nodata_texels += 1,
            Texel::Missing => {}
        }
    }
    let range = view.range.or(region_range);
    let img = hypsometric::picture(map, w, h, range.map(|[a, b]| (a, b)), view.shade, missing);
    let labels = match range {
        Some([a, b]) => [hypsometric::label(a), hypsometric::label(b)],
        None => ["nodata".to_string(), "nodata".to_string()],
    };
    let legend = HeightLegend {
        storage: view.format.storage().short_name().to_string(),
        range,
        range_given: view.range.is_some(),
        region_range,
        nodata_texels,
        shaded: view.shade,
        map: [w as u64, h as u64],
        labels,
    };
    (img, legend)
}

/// Checks the region (the whole level when `None`) against the level and [`MAX_DUMP_TEXELS`].
pub(crate) fn choose_region(
    level: Option<u32>,
    size: [u64; 2],
    region: Option<[u64; 4]>,
    what: &str,
) -> Result<Rect, DumpError> {
    let [s0, t0, s1, t1] = region.unwrap_or([0, 0, size[0], size[1]]);
    if s0 >= s1 || t0 >= t1 || s1 > size[0] || t1 > size[1] {
        let what = level.map_or("the image cache".to_string(), |k| format!("level {k}"));
        return Err(DumpError::RegionOutside { what, s0, t0, s1, t1, w: size[0], h: size[1] });
    }
    let (w, h) = (s1 - s0, t1 - t0);
    if w.saturating_mul(h) > MAX_DUMP_TEXELS {
        // Suggest the largest square around the region's centre.
        let side = 4096u64;
        let (cs, ct) = (s0 + w / 2, t0 + h / 2);
        let a0 = cs.saturating_sub(side / 2).min(size[0].saturating_sub(side));
        let b0 = ct.saturating_sub(side / 2).min(size[1].saturating_sub(side));
        let what = if region.is_some() { "the region".to_string() } else { what.to_string() };
        return Err(DumpError::TooLarge {
            what,
            w,
            h,
            max: MAX_DUMP_TEXELS,
            s0: a0,
            t0: b0,
            s1: a0 + side.min(size[0]),
            t1: b0 + side.min(size[1]),
        });
    }
    Ok(Rect::new(s0 as i64, t0 as i64, s1 as i64, t1 as i64))
}

/// Reads `region` of a level tile by tile into an image (RGB, or RGBA for formats with alpha;
/// for 16-bit formats a 16-bit image of their components, values exact); row 0 of the image is
/// the region's last t row. Returns the image, tiles read and the tiles that could not be read.
pub fn read_region(src: &LevelTiles, region: Rect) -> (DynamicImage, u64, Vec<MissingTile>) {
    let bpt = src.format.bytes_per_texel() as usize;
    let (w, h) = (region.width() as u32, region.height() as u32);
    let deep = src.format.ctype == ComponentType::U16;
    let mut rgba = RgbaImage::new(if deep { 0 } else { w }, if deep { 0 } else { h });
    let mut rgba16: Vec<u16> = if deep { vec![0; w as usize * h as usize * 4] } else { Vec::new() };
    let tiles = tiles_covering(region, src.tile);
    let mut buf = vec![0u8; (src.tile[0] * src.tile[1]) as usize * bpt];
    let (mut read, mut missing) = (0, Vec::new());
    for tt in tiles.t0..tiles.t1 {
        for ts in tiles.s0..tiles.s1 {
            let id = TileId::new(src.level.unwrap_or(0), ts as u64, tt as u64);
            let result = (src.read)(id, &mut buf);
            read += 1;
            if let Err(e) = &result {
                let text = e.to_string();
                let problem = text.strip_prefix(&format!("{id}: ")).unwrap_or(&text).to_string();
                let path = (src.file_of)(id).map(|p| p.to_string());
                missing.push(MissingTile { s: id.s, t: id.t, kind: e.kind(), problem, path });
            }
            let texels = tile_texels(src.size, src.tile, [id.s, id.t]).intersect(&region);
            for t in texels.t0..texels.t1 {
                let y = (region.t1 - 1 - t) as u32;
                for s in texels.s0..texels.s1 {
                    let x = (s - region.s0) as u32;
                    let j = (((t as u64 - id.t * src.tile[1]) * src.tile[0] + (s as u64 - id.s * src.tile[0]))
                        as usize)
                        * bpt;
                    if deep {
                        let px = if result.is_ok() {
                            picture::texel_rgba16(Some(src.format), &buf[j..j + bpt])
                        } else {
                            picture::missing_pattern(x, y).map(|v| v as u16 * 257)
                        };
                        let o = (y as usize * w as usize + x as usize) * 4;
                        rgba16[o..o + 4].copy_from_slice(&px);
                        continue;
                    }
                    let px = if result.is_ok() {
                        picture::texel_rgba(Some(src.format), &buf[j..j + bpt])
                    } else {
                        picture::missing_pattern(x, y)
                    };
                    rgba.put_pixel(x, y, image::Rgba(px));
                }
            }
        }
    }
    if deep {
        return (sixteen_bit_image(src.format.components, w, h, &rgba16), read, missing);
    }
    let img = if picture::has_alpha(src.format) {
        DynamicImage::ImageRgba8(rgba)
    } else {
        DynamicImage::ImageRgb8(RgbImage::from_fn(w, h, |x, y| {
            let p = rgba.get_pixel(x, y).0;
            image::Rgb([p[0], p[1], p[2]])
        }))
    };
    (img, read, missing)
}

/// The 16-bit picture of `components` from RGBA16 pixels (`w * h * 4` samples, rows top-down).
fn sixteen_bit_image(components: Components, w: u32, h: u32, px: &[u16]) -> DynamicImage {
    let at = |x: u32, y: u32| {
        let o = (y as usize * w as usize + x as usize) * 4;
        [px[o], px[o + 1], px[o + 2], px[o + 3]]
    };
    match components {
        Components::One => DynamicImage::ImageLuma16(ImageBuffer::from_fn(w, h, |x, y| Luma([at(x, y)[0]]))),
        Components::Two => DynamicImage::ImageLumaA16(ImageBuffer::from_fn(w, h, |x, y| {
            let p = at(x, y);
            LumaA([p[0], p[3]])
        })),
        Components::Three => DynamicImage::ImageRgb16(ImageBuffer::from_fn(w, h, |x, y| {
            let p = at(x, y);
            Rgb([p[0], p[1], p[2]])
        })),
        Components::Four => DynamicImage::ImageRgba16(ImageBuffer::from_fn(w, h, |x, y| Rgba(at(x, y)))),
    }
}

/// The report's name of a picture's pixels.
fn colour_of(img: &DynamicImage) -> &'static str {
    match img {
        DynamicImage::ImageRgba8(_) => "rgba",
        DynamicImage::ImageLuma16(_) => "l16",
        DynamicImage::ImageLumaA16(_) => "la16",
        DynamicImage::ImageRgb16(_) => "rgb16",
        DynamicImage::ImageRgba16(_) => "rgba16",
        _ => "rgb",
    }
}

/// Dumps `region` of a level to the PNG `out`.
pub fn dump(file: &Path, src: &LevelTiles, region: Option<[u64; 4]>, out: &Path) -> Result<DumpReport, DumpError> {
    let what = match src.level {
        Some(k) => format!("level {k}, the whole level,"),
        None => "the image cache, all of it,".to_string(),
    };
    let r = choose_region(src.level, src.size, region, &what)?;
    let (img, tiles, missing) = read_region(src, r);
    let colour = colour_of(&img);
    crate::save::atomically(out, |w| img.write_to(w, image::ImageFormat::Png).map_err(crate::save::image_io))
        .map_err(|e| write_error(out, e))?;
    Ok(DumpReport {
        file: file.display().to_string(),
        level: src.level,
        level_size: src.size,
        region: [r.s0 as u64, r.t0 as u64, r.s1 as u64, r.t1 as u64],
        format: src.format.short_name(),
        png: out.display().to_string(),
        colour,
        pixels: [r.width(), r.height()],
        tiles,
        missing,
        heights: None,
    })
}

/// The human form.
pub fn human(r: &DumpReport) -> String {
    let [s0, t0, s1, t1] = r.region;
    let mut o = format!(
        "{} ({}x{}, {}): [{s0}, {s1}) x [{t0}, {t1}) -> {} ({}x{} {})\ntiles {}: {} read, {} could not be read\n",
        r.level.map_or("image cache".to_string(), |k| format!("level {k}")),
        r.level_size[0],
        r.level_size[1],
        r.format,
        r.png,
        r.pixels[0],
        r.pixels[1],
        r.colour.to_uppercase(),
        r.tiles,
        r.tiles - r.missing.len() as u64,
        r.missing.len()
    );
    for m in r.missing.iter().take(20) {
        let at = m.path.as_deref().map(|p| format!(" ({p})")).unwrap_or_default();
        o.push_str(&format!("  tile ({}, {}): {}{at}\n", m.s, m.t, m.problem));
    }
    if let Some(hl) = &r.heights {
        let range = match (hl.range, hl.range_given) {
            (Some([a, b]), true) => format!("{a} m to {b} m (--range)"),
            (Some([a, b]), false) => format!("{a} m to {b} m (the region's)"),
            (None, _) => "none (no texel with data)".to_string(),
        };
        o.push_str(&format!(
            "heights {}: colours {range}, {} nodata texels (transparent){}; legend below the {}x{} map\n",
            hl.storage,
            hl.nodata_texels,
            if hl.shaded { ", hillshaded" } else { "" },
            hl.map[0],
            hl.map[1]
        ));
    }
    if r.missing.len() > 20 {
        o.push_str(&format!("  ... and {} more (--json lists every one)\n", r.missing.len() - 20));
    }
    if !r.missing.is_empty() {
        o.push_str("tiles that could not be read are painted as magenta and black squares\n");
    }
    o
}

/// Prints a dump's outcome the way both tools do and returns the exit status: 0, or 1 when some
/// tile could not be read (the picture is written all the same). `--quiet` prints only problems.
pub fn finish(result: Result<DumpReport, DumpError>, json: bool, quiet: bool, tool: &str) -> i32 {
    match result {
        Err(e) => {
            eprintln!("{tool} dump: {e}");
            e.exit_code()
        }
        Ok(r) => {
            if json {
                println!("{}", serde_json::to_string_pretty(&r).expect("report serialises"));
            } else if !quiet {
                print!("{}", human(&r));
            }
            if r.missing.is_empty() {
                super::exit::OK
            } else {
                if quiet || json {
                    eprintln!(
                        "{tool} dump: {} of {} tiles could not be read (first: tile ({}, {}): {}{}); they are painted as magenta and black squares in {}",
                        r.missing.len(),
                        r.tiles,
                        r.missing[0].s,
                        r.missing[0].t,
                        r.missing[0].problem,
                        r.missing[0].path.as_deref().map(|p| format!(", {p}")).unwrap_or_default(),
                        r.png
                    );
                }
                super::exit::BAD_INPUT
            }
        }
    }
}

/// The tiles of a standalone image cache, read as its `.ic` file describes (default tile where
/// a tile is missing or short).
pub struct IcacheTiles<'a> {
    plan: &'a ImageCachePlan,
    default: Option<Vec<u8>>,
}

impl<'a> IcacheTiles<'a> {
    /// Reads the default tile now, if one is named; a default tile of the wrong size is ignored
    /// and reported in the returned message.
    pub fn new(plan: &'a ImageCachePlan) -> (Self, Option<String>) {
        let expected = plan.tile_bytes();
        let (default, note) = match &plan.default_tile {
            None => (None, None),
            // This reader reads local files only (the service reads remote ones).
            Some(p @ Place::Remote(_)) => {
                (None, Some(format!("default tile {p}: a remote location, not read here; not used")))
            }
            Some(Place::Local(p)) => {
                let allowed = [expected, expected.saturating_add(plan.header_offset)];
                match crate::open::read_sized(p, &allowed) {
                    Ok(b) if b.len() as u64 == expected => (Some(b), None),
                    Ok(b) => (Some(b[plan.header_offset as usize..].to_vec()), None),
                    Err(crate::open::SizedError::Length(n)) => (
                        None,
                        Some(format!(
                            "default tile {}: {n} bytes, expected {expected} (one tile); not used",
                            p.display()
                        )),
                    ),
                    Err(crate::open::SizedError::Io(e)) => {
                        (None, Some(format!("default tile {}: {e}; not used", p.display())))
                    }
                }
            }
        };
        (IcacheTiles { plan, default }, note)
    }

    /// Reads tile `id` (its level is ignored).
    pub fn read(&self, id: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        let r = self.read_file(id, out);
        match (r, &self.default) {
            (Err(SourceError::Missing { .. } | SourceError::Short { .. }), Some(d)) if d.len() == out.len() => {
                out.copy_from_slice(d);
                Ok(())
            }
            (r, _) => r,
        }
    }

    fn read_file(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        let loc = self
            .plan
            .locate(tile.s, tile.t, 0)
            .map_err(|e| SourceError::Io { tile, source: std::io::Error::other(e) })?;
        if loc.length != out.len() as u64 {
            return Err(SourceError::Corrupt { tile, expected: out.len() as u64, found: loc.length });
        }
        // A remote tile is not read here: missing, as a file that is not there.
        let Place::Local(path) = &loc.path else { return Err(SourceError::Missing { tile }) };
        let (f, _) = crate::open::regular(path).map_err(|e| crate::source::file::io_error(tile, e))?;
        crate::source::file::read_stored(&crate::source::range::LocalFile(f), &loc.path, tile, loc.offset, out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_parse_and_are_checked_against_the_level() {
        assert_eq!(parse_region("1, 2,3,4").unwrap(), [1, 2, 3, 4]);
        for bad in ["1,2,3", "1,2,3,4,5", "a,b,c,d", "-1,0,2,2", ""] {
            assert!(matches!(parse_region(bad), Err(DumpError::RegionSyntax { .. })), "{bad}");
        }
        assert_eq!(choose_region(Some(0), [64, 32], None, "x").unwrap(), Rect::new(0, 0, 64, 32));
        let e = choose_region(Some(2), [64, 32], Some([0, 0, 65, 8]), "x").unwrap_err().to_string();
        assert!(e.contains("does not fit level 2 (64x32 texels)") && e.contains("S1 <= 64"), "{e}");
        assert!(choose_region(None, [64, 32], Some([5, 5, 5, 8]), "x").is_err(), "empty");
        let e = choose_region(Some(0), [65536, 65536], None, "level 0, the whole level,").unwrap_err().to_string();
        assert!(e.contains("level 0, the whole level, is 65536x65536 texels"), "{e}");
        assert!(e.contains("--region 30720,30720,34816,34816"), "{e}");
    }

    #[test]
    fn a_region_is_read_across_tiles_with_missing_ones_painted() {
        let read = |id: TileId, out: &mut [u8]| {
            if (id.s, id.t) == (1, 1) {
                return Err(SourceError::Missing { tile: id });
            }
            for (i, px) in out.chunks_mut(3).enumerate() {
                let (s, t) = (id.s * 4 + i as u64 % 4, id.t * 4 + i as u64 / 4);
                px.copy_from_slice(&[s as u8, t as u8, 9]);
            }
            Ok(())
        };
        let file_of = |id: TileId| Some(Place::parse(&format!("t{}{}", id.s, id.t)));
        let src = LevelTiles {
            level: Some(0),
            size: [8, 8],
            tile: [4, 4],
            format: TexelFormat::RGB8,
            read: &read,
            file_of: &file_of,
        };
        let (img, n, missing) = read_region(&src, Rect::new(2, 1, 7, 6));
        assert_eq!((n, missing.len(), missing[0].s, missing[0].t), (4, 1, 1, 1));
        assert_eq!((missing[0].problem.as_str(), missing[0].path.as_deref()), ("missing", Some("t11")));
        let img = img.as_rgb8().expect("rgb8 gives an RGB picture");
        assert_eq!(img.dimensions(), (5, 5));
        // Texel (2, 1) is the bottom-left pixel; (3, 5) is in the top row.
        assert_eq!(img.get_pixel(0, 4).0, [2, 1, 9]);
        assert_eq!(img.get_pixel(1, 0).0, [3, 5, 9]);
        // Texel (6, 5) lies in missing tile (1, 1).
        let p = img.get_pixel(4, 0).0;
        assert!(p == [255, 0, 255] || p == [0, 0, 0], "{p:?}");
    }

    #[test]
    fn a_sixteen_bit_level_gives_a_sixteen_bit_picture_of_its_exact_values() {
        let value = |s: u64, t: u64| (s * 7919 + t * 104 + 301) as u16;
        let read = |id: TileId, out: &mut [u8]| {
            if (id.s, id.t) == (1, 0) {
                return Err(SourceError::Missing { tile: id });
            }
            for (i, px) in out.chunks_mut(4).enumerate() {
                let (s, t) = (id.s * 4 + i as u64 % 4, id.t * 4 + i as u64 / 4);
                px[..2].copy_from_slice(&value(s, t).to_le_bytes());
                px[2..].copy_from_slice(&(65535 - value(s, t)).to_le_bytes());
            }
            Ok(())
        };
        let file_of = |_: TileId| None;
        let src = LevelTiles {
            level: Some(0),
            size: [8, 8],
            tile: [4, 4],
            format: TexelFormat::LA16,
            read: &read,
            file_of: &file_of,
        };
        let (img, n, missing) = read_region(&src, Rect::new(0, 0, 8, 8));
        assert_eq!((n, missing.len()), (4, 1));
        assert_eq!(colour_of(&img), "la16");
        let img = img.as_luma_alpha16().expect("la16 gives a 16-bit grey+alpha picture");
        for t in 0..8u32 {
            for s in 0..8u32 {
                let p = img.get_pixel(s, 7 - t).0;
                if s >= 4 && t < 4 {
                    // Missing tile (1, 0): the pattern, in 16 bits.
                    assert!(p == [65535, 65535] || p == [0, 65535], "{p:?}");
                } else {
                    let v = value(s as u64, t as u64);
                    assert_eq!(p, [v, 65535 - v], "texel ({s}, {t})");
                }
            }
        }
    }
}
