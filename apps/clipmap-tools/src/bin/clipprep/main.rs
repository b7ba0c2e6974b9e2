//! `clipprep`: prepares a clip texture (tiled pyramid plus `.ct`/`.ic`) from an image or a
//! procedural source. A thin shell over [`clipmap::prep`]: arguments, progress, signals, and
//! the summary; exit codes 0 (ok), 1 (bad input), 2 (could not run).

#![forbid(unsafe_code)]

mod config_only;

use anyhow::Context;
use clap::{Parser, ValueEnum};
use clipmap::height::{HeightFormat, HeightStorage, LevelRule, NonFinite};
use clipmap::prep::error::next_power_of_two;
use clipmap::prep::output::Staging;
use clipmap::prep::source::open_image;
use clipmap::prep::tiff_stream::HeightTiff;
use clipmap::prep::{Compression, Filter, Inset, Job, Layout, Limits, PrepError, Source, Spec};
use clipmap::prep::{HeightInput, HeightPrep};
use clipmap::texel::{Bc, TexelFormat};
use config_only::config_only;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum SourceKind {
    /// The verification texture: level k texel (s, t) = hash(k, s, t), every level generated.
    Hash,
    /// Fractal terrain at level 0, coarser levels filtered.
    Terrain,
    /// Heights: the height verification texture's level 0 (exactly computable texels, as
    /// `clipmapd --source heights` serves it), coarser levels by --height-levels.
    Heights,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Format {
    Rgb8,
    Rgba8,
    L8,
    Rgb565,
    Rgba5551,
    // 16-bit components, little-endian: luminance (heights), luminance and alpha, RGB, RGBA.
    L16,
    La16,
    Rgb16,
    Rgba16,
    // Heights (docs/ELEVATION.md): 32-bit float metres, signed 16-bit steps.
    L32f,
    L16i,
    // Block-compressed tiles (docs/CONFIG.md, "Block-compressed tiles"): encoded from RGB8 (bc1,
    // and bc5 from its first two channels), L8 (bc4) or RGBA8 (bc7) texels.
    Bc1,
    Bc4,
    Bc5,
    Bc7,
}

impl Format {
    fn texel(self) -> TexelFormat {
        match self {
            Format::Rgb8 => TexelFormat::RGB8,
            Format::Rgba8 => TexelFormat::RGBA8,
            Format::L8 => TexelFormat::L8,
            Format::Rgb565 => TexelFormat::RGB565,
            Format::Rgba5551 => TexelFormat::RGBA5551,
            Format::L16 => TexelFormat::L16,
            Format::La16 => TexelFormat::LA16,
            Format::Rgb16 => TexelFormat::RGB16,
            Format::Rgba16 => TexelFormat::RGBA16,
            Format::L32f => TexelFormat::L32F,
            Format::L16i => TexelFormat::L16I,
            Format::Bc1 | Format::Bc5 => TexelFormat::RGB8,
            Format::Bc4 => TexelFormat::L8,
            Format::Bc7 => TexelFormat::RGBA8,
        }
    }

    /// The block format tiles are stored in, for bc1, bc4, bc5 and bc7.
    fn blocks(self) -> Option<Bc> {
        match self {
            Format::Bc1 => Some(Bc::Bc1),
            Format::Bc4 => Some(Bc::Bc4),
            Format::Bc5 => Some(Bc::Bc5),
            Format::Bc7 => Some(Bc::Bc7),
            _ => None,
        }
    }

    /// The height storage of a format that can hold heights.
    fn height_storage(self) -> Option<HeightStorage> {
        match self {
            Format::L32f => Some(HeightStorage::F32),
            Format::L16 => Some(HeightStorage::U16),
            Format::L16i => Some(HeightStorage::I16),
            _ => None,
        }
    }
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum LevelsArg {
    Mean,
    Point,
    Min,
    Max,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum NanArg {
    Refuse,
    Nodata,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum FilterArg {
    Box,
    Lanczos3,
}

const AFTER_HELP: &str = "\
Level-0 texel (s, t) is image pixel (s, height-1-t): Performer's origin is the lower-left corner.

Examples:
  clipprep --input photo.png --tile 256 --clip 512 --format rgb8 --out pyr
  clipprep --input map.jpg --pad --tile 512 --clip 1024 --format rgb8 --filter lanczos3 --out map
  clipprep --source terrain --size 16384 --tile 256 --clip 1024 --format rgb8 --out terrain
  clipprep --source hash --size 65536x32768 --tile 512 --clip 2048 --format rgba8 --streams 4 --out verify
  clipprep --source terrain --size 8192 --tile 256 --clip 512 --format rgb8 --zstd 3 --out packed
  clipprep --input photo.png --tile 256 --clip 512 --format bc1 --zstd 3 --out blocks
  clipprep --input dem.tif --format l16 --height-scale 0.01 --height-offset -500 --height-nodata 0 \\
           --height-levels point --nan nodata --pad --tile 256 --clip 1024 --out dem
  clipprep --source heights --size 4096 --format l32f --height-nodata -32768 --tile 256 --clip 512 --out heights
  clipprep --source terrain --size 8192 --tile 256 --clip 512 --format rgb8 \\
           --inset 2048,2048,4096,4096 --inset-level 2 --out inset

Exit codes: 0 ok; 1 bad input (arguments and command-line syntax, image, existing output);
2 could not run (disk full, write error, interrupted).";

/// Prepares a clip texture: a tiled pyramid in Performer's raw tile layout plus its .ct and .ic
/// configuration files, with relative paths so the directory can be moved.
#[derive(Parser, Debug)]
#[command(
    name = "clipprep",
    version,
    after_help = AFTER_HELP
)]
struct Cli {
    /// Input image (PNG, JPEG, TIFF; TIFF is streamed, others are decoded into memory).
    #[arg(long, value_name = "IMAGE", required_unless_present = "source", conflicts_with = "source")]
    input: Option<PathBuf>,
    /// Procedural source instead of an image.
    #[arg(long, value_enum, requires = "size")]
    source: Option<SourceKind>,
    /// Size of a procedural texture: N (square) or WxH, powers of two.
    #[arg(long, value_name = "N|WxH")]
    size: Option<String>,
    /// Tile edge in texels (power of two). With --config-only: the COG's TIFF tiles (given, it
    /// must be their size).
    #[arg(long, value_name = "T", required_unless_present = "config_only")]
    tile: Option<u64>,
    /// Clip size in texels (power of two).
    #[arg(long, value_name = "C")]
    clip: u64,
    /// Texel format on disk (16-bit formats keep 16-bit samples exactly; 8-bit samples into them
    /// are scaled by 257). bc1, bc4, bc5, bc7: tiles stored as GPU blocks, encoded here (see
    /// --bc-quality) and served by clipmapd without encoding (docs/CONFIG.md, §20).
    /// With --config-only: the format the COG is served as (given, it must be that one).
    #[arg(long, value_enum, value_name = "FMT", required_unless_present = "config_only")]
    format: Option<Format>,
    /// Write only the configuration (.ct and .ic files) that serves --input, a tiled GeoTIFF or
    /// COG (a local file or an http(s):// or s3:// URL), as it is: each names it with a
    /// `#clipmap cog` line, and no tile is written (docs/COG.md). An --input naming a tile
    /// pyramid (`xyz:TEMPLATE`, a .pmtiles or .mbtiles) always writes only the configuration, its
    /// `.ct` naming it with a `#clipmap source` line (docs/TILES.md).
    #[arg(long, requires = "input")]
    config_only: bool,
    /// Round an input deeper than --format (16-bit samples for an 8-bit or packed format) to
    /// nearest instead of refusing it.
    #[arg(long)]
    reduce_depth: bool,
    /// Output directory (created; the .ct is at its top), or a remote location
    /// (s3://BUCKET/PREFIX, or an http(s):// URL that accepts PUT) to upload the pyramid to:
    /// it is prepared in a temporary directory, every file uploaded, and a configuration that
    /// reads the tiles from there written to --config-out.
    #[arg(long, value_name = "DIR|URL")]
    out: PathBuf,
    /// With a remote --out: the local directory for the .ct and .ic files that read the
    /// uploaded tiles (configuration files are read from local disk only).
    #[arg(long, value_name = "DIR")]
    config_out: Option<PathBuf>,
    /// Print a JSON summary on stdout: ct, levels, bytes, seconds, files, ...
    #[arg(long)]
    json: bool,
    /// No progress bar and no summary line.
    #[arg(long, short)]
    quiet: bool,
    /// Replace an output directory that already holds a clip texture.
    #[arg(long)]
    force: bool,
    /// Pad an image whose sides are not powers of two with black, transparent texels (at the
    /// right and the top) up to the next powers of two.
    #[arg(long)]
    pad: bool,
    /// Filter that builds each coarser level from the one below.
    #[arg(long, value_enum, default_value = "box")]
    filter: FilterArg,
    /// Average in linear light (decode sRGB, average, encode) instead of on stored values.
    #[arg(long)]
    linear_light: bool,
    /// Image-cache tiles per file: N (N along S) or NSxNT; written as tiles_in_file.
    #[arg(long, value_name = "N|NSxNT", default_value = "1")]
    tiles_per_file: String,
    /// Bytes of header at the start of each image-cache tile file (header_offset).
    #[arg(long, value_name = "H", default_value_t = 0)]
    header_bytes: u64,
    /// Spread image-cache tiles over N stream directories by tile column modulo N.
    #[arg(long, value_name = "N")]
    streams: Option<u32>,
    /// File stem of the .ct (default: the output directory's name).
    #[arg(long)]
    name: Option<String>,
    /// Seed of the terrain source (default: the built-in terrain's, as every tool serves it).
    #[arg(long, default_value_t = clipmap::source::TERRAIN_SEED)]
    seed: u64,
    /// Sparse inset: a level-0 region S0,T0,S1,T1 (texels, S1 and T1 exclusive) outside which
    /// the levels finer than --inset-level are absent (a default tile stands in), with a border
    /// of at least one clip size of texels magnified from the inset level around it.
    #[arg(long, value_name = "S0,T0,S1,T1", requires = "inset_level")]
    inset: Option<String>,
    /// The finest level that covers the whole texture when --inset is given (1 or more).
    #[arg(long, value_name = "K", requires = "inset")]
    inset_level: Option<u32>,
    /// Compress image-cache tiles with zstd at this level (1-22), one frame per tile file named
    /// `.raw.zst`: an extension only clipmap readers decode (Performer cannot); pyramid levels
    /// stay raw.
    #[arg(long, value_name = "LEVEL", value_parser = clap::value_parser!(i32).range(1..=22))]
    zstd: Option<i32>,
    /// Also write the prepared texture as one Cloud-Optimized GeoTIFF (level 0 and its
    /// overviews, laid out as GDAL's COG driver lays it out), which GDAL, QGIS and
    /// `clipmapd FILE.tif` read. 8-bit grey, RGB or RGBA; a local --out.
    #[arg(long, value_name = "FILE.tif")]
    cog: Option<PathBuf>,
    /// Compression of the --cog file's tiles.
    #[arg(long, value_enum, default_value = "deflate", requires = "cog")]
    cog_compression: CogCompressionArg,
    /// With --format bc1|bc4|bc5|bc7: how hard the encoder tries, fast, normal or slow (BC7's
    /// settings; BC1, BC4 and BC5 have one), as `clipmapd --bc-quality`.
    #[arg(long, value_name = "QUALITY", default_value = "normal", value_parser = clipmap::source::BcQuality::parse)]
    bc_quality: clipmap::source::BcQuality,
    /// Heights: the metres of one stored step of l16/l16i (stored x scale + offset = metres).
    /// Any height option (or --format l32f/l16i, or --source heights) makes the texture heights:
    /// --input is then a single-band elevation TIFF, the .ct carries `#clipmap height` lines.
    #[arg(long, value_name = "M")]
    height_scale: Option<f64>,
    /// Heights: the metres of a stored 0 of l16/l16i.
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    height_offset: Option<f64>,
    /// Heights: the stored value (not metres) that marks a texel without data (the input's
    /// GDAL_NODATA pixels and padding become it).
    #[arg(long, value_name = "V", allow_negative_numbers = true)]
    height_nodata: Option<f64>,
    /// Heights: how each coarser level is made: mean of the texels with data, point (the finer
    /// texel at the even position: point-registered), min or max.
    #[arg(long, value_enum, value_name = "RULE")]
    height_levels: Option<LevelsArg>,
    /// Heights: what a NaN or infinite input height becomes: refused (an error naming the pixel),
    /// or the nodata value (--height-nodata, or the input's GDAL_NODATA).
    #[arg(long, value_enum, value_name = "WHAT")]
    nan: Option<NanArg>,
    /// Memory limit in MiB for a decoded input image and the band cascade.
    #[arg(long, value_name = "MIB", default_value_t = 512, value_parser = clap::value_parser!(u64).range(1..=clipmap::prep::MAX_MEMORY_MIB))]
    max_memory: u64,
}

impl Cli {
    /// `--tile` (clap requires it without --config-only).
    fn tile(&self) -> u64 {
        self.tile.expect("clap requires --tile without --config-only")
    }

    /// `--format` (clap requires it without --config-only).
    fn format(&self) -> Format {
        self.format.expect("clap requires --format without --config-only")
    }
}

/// The options that ask for a conversion, which --config-only (no tile written) cannot honour:
/// the first one given, with why.
fn conversion_option(cli: &Cli) -> Option<(&'static str, &'static str)> {
    let heights = cli.height_scale.is_some()
        || cli.height_offset.is_some()
        || cli.height_nodata.is_some()
        || cli.height_levels.is_some()
        || cli.nan.is_some();
    [
        ("--pad", cli.pad, "the texture is served at the COG's size (the configuration's virt_size is rounded up to powers of two for Performer)"),
        ("--filter lanczos3", matches!(cli.filter, FilterArg::Lanczos3), "the coarser levels are the COG's overviews"),
        ("--linear-light", cli.linear_light, "the coarser levels are the COG's overviews"),
        ("--reduce-depth", cli.reduce_depth, "the texels are served as the COG stores them"),
        ("--tiles-per-file", cli.tiles_per_file != "1", "no tile file is written"),
        ("--header-bytes", cli.header_bytes != 0, "no tile file is written"),
        ("--streams", cli.streams.is_some(), "no tile file is written"),
        ("--inset", cli.inset.is_some(), "no level is written, sparse or not"),
        ("--zstd", cli.zstd.is_some(), "no tile file is written"),
        (
            "--format bc1|bc4|bc5|bc7",
            cli.format.is_some_and(|f| f.blocks().is_some()),
            "the COG's tiles are served as it stores them (clipmapd --format encodes them at run time)",
        ),
        ("--cog", cli.cog.is_some(), "the input is the COG already"),
        ("--config-out", cli.config_out.is_some(), "the configuration is written into --out, a local directory"),
        ("the height options", heights, "the heights are the COG's (its GDAL_NODATA is the nodata value)"),
    ]
    .into_iter()
    .find(|c| c.1)
    .map(|(flag, _, why)| (flag, why))
}

/// A name from the command line as it may be printed: a URL's password and signatures
/// replaced ([`clipmap::place::redacted`]).
fn shown(path: &Path) -> String {
    clipmap::place::redacted(&path.to_string_lossy()).into_owned()
}

/// `--cog-compression`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum CogCompressionArg {
    None,
    Deflate,
    Zstd,
}

/// Writes the prepared texture at `o.ct` as the COG `path`, stopping when `cancel` is set.
fn write_cog(
    o: &Outcome,
    path: &Path,
    c: CogCompressionArg,
    cancel: &AtomicBool,
) -> Result<clipmap::prep::cog::CogWritten, clipmap::prep::cog::CogWriteError> {
    use clipmap::prep::cog::{self, CogCompression, CogWriteError};
    let other = |why: String| CogWriteError::Unsupported(why);
    let loaded = clipmap::plan::load_clip_texture(&o.ct, &Default::default()).map_err(|e| other(e.to_string()))?;
    let Some(plan) = loaded.plan else {
        return Err(other(format!("{} does not load:\n{}", o.ct.display(), loaded.render())));
    };
    let src =
        clipmap::source::open_plan(plan, &clipmap::limits::Limits::default()).map_err(|e| other(e.to_string()))?;
    let compression = match c {
        CogCompressionArg::None => CogCompression::None,
        CogCompressionArg::Deflate => CogCompression::Deflate,
        CogCompressionArg::Zstd => CogCompression::Zstd,
    };
    cog::write(src.as_ref(), path, o.layout.spec.tile, compression, cancel)
}

fn parse_pair(text: &str, what: &str) -> Result<(u64, u64), PrepError> {
    let bad = || {
        PrepError::Geometry(format!("{what} '{text}' is not a number N or a pair NxM; expected e.g. 1024 or 2048x1024"))
    };
    let num = |s: &str| s.trim().parse::<u64>().map_err(|_| bad());
    match text.split_once(['x', 'X', ',']) {
        Some((a, b)) => Ok((num(a)?, num(b)?)),
        None => {
            let n = num(text)?;
            Ok((n, n))
        }
    }
}

fn parse_inset(text: &str, level: u32) -> Result<Inset, PrepError> {
    let v: Vec<u64> = text.split(',').filter_map(|x| x.trim().parse().ok()).collect();
    match v[..] {
        [s0, t0, s1, t1] if text.split(',').count() == 4 => Ok(Inset { s0, t0, s1, t1, level }),
        _ => Err(PrepError::Geometry(format!(
            "--inset '{text}' is not four numbers S0,T0,S1,T1; expected level-0 texels such as 1024,2048,3072,4096"
        ))),
    }
}

fn check_pow2(what: String, v: u64, hint: &'static str) -> Result<(), PrepError> {
    if v == 0 || !v.is_power_of_two() {
        return Err(PrepError::NotPowerOfTwo { what, found: v, next: next_power_of_two(v), hint });
    }
    Ok(())
}

fn default_name(out: &Path) -> String {
    let raw = out.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let clean: String =
        raw.chars().map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '_' }).collect();
    let clean = clean.trim_start_matches('.').to_string();
    if clean.is_empty() {
        "texture".into()
    } else {
        clean
    }
}

/// The heights the options ask for (`None` for a colour texture): any height option, a height
/// format other than `l16` (which alone keeps its 16-bit luminance meaning) or `--source heights`.
fn height_prep(cli: &Cli) -> Result<Option<HeightPrep>, PrepError> {
    let options = cli.height_scale.is_some()
        || cli.height_offset.is_some()
        || cli.height_nodata.is_some()
        || cli.height_levels.is_some()
        || cli.nan.is_some();
    let asked = options
        || matches!(cli.format(), Format::L32f | Format::L16i)
        || matches!(cli.source, Some(SourceKind::Heights));
    if !asked {
        return Ok(None);
    }
    let fmt = cli.format().texel().short_name();
    let Some(storage) = cli.format().height_storage() else {
        return Err(PrepError::Geometry(format!(
            "height options (or --source heights) were given with --format {fmt}, which holds colours; expected --format l32f, l16 or l16i for heights; choose one, or drop the height options"
        )));
    };
    if let Some(kind @ (SourceKind::Hash | SourceKind::Terrain)) = cli.source {
        let name = if matches!(kind, SourceKind::Hash) { "hash" } else { "terrain" };
        return Err(PrepError::Geometry(format!(
            "--source {name} is a colour source, but height options or --format {fmt} ask for heights; expected --source heights or --input DEM.tif; choose one, or drop the height options"
        )));
    }
    let colour_only = [
        (
            "--filter lanczos3",
            matches!(cli.filter, FilterArg::Lanczos3),
            "coarser levels of heights are made by --height-levels",
        ),
        ("--linear-light", cli.linear_light, "heights are no sRGB colours"),
        (
            "--reduce-depth",
            cli.reduce_depth,
            "heights are converted by --height-scale and --height-offset, refused when out of range",
        ),
        ("--inset", cli.inset.is_some(), "sparse insets are not built for heights"),
    ];
    if let Some((flag, _, why)) = colour_only.iter().find(|c| c.1) {
        return Err(PrepError::Geometry(format!(
            "{flag} is for colour textures and this is a height texture (--format {fmt}): {why}; drop {flag}"
        )));
    }
    let format = HeightFormat::new(
        storage,
        cli.height_scale.unwrap_or(1.0),
        cli.height_offset.unwrap_or(0.0),
        cli.height_nodata,
    )
    .map_err(|e| PrepError::Geometry(format!("--format {fmt} with the --height-* options given: {e}")))?;
    let non_finite = match cli.nan {
        Some(NanArg::Nodata) => {
            // An input elevation model may carry its own nodata (GDAL_NODATA): checked in
            // `prepare`, once it is open.
            if format.nodata().is_none() && cli.input.is_none() {
                return Err(PrepError::Geometry(
                    "--nan nodata stores NaN and infinite heights as the nodata value, and none was given; expected --height-nodata V (a stored value outside the data, e.g. -32768); pass it, or --nan refuse".into(),
                ));
            }
            NonFinite::Nodata
        }
        Some(NanArg::Refuse) | None => NonFinite::Refuse,
    };
    let rule = match cli.height_levels {
        Some(LevelsArg::Mean) | None => LevelRule::Mean,
        Some(LevelsArg::Point) => LevelRule::Point,
        Some(LevelsArg::Min) => LevelRule::Min,
        Some(LevelsArg::Max) => LevelRule::Max,
    };
    Ok(Some(HeightPrep { format, rule, non_finite }))
}

/// The `.ct` comment lines that describe heights.
fn height_description(h: &HeightPrep) -> Vec<String> {
    let f = &h.format;
    let nodata = f.nodata().map_or("none".to_string(), |v| v.to_string());
    let range = match f.storage() {
        HeightStorage::F32 => String::new(),
        _ => {
            let (lo, hi) = f.metre_bounds();
            format!(", {lo} m to {hi} m")
        }
    };
    let words = match h.rule {
        LevelRule::Mean => "the mean of the finer texels with data",
        LevelRule::Point => "point-registered, the finer texel at the even position",
        LevelRule::Min => "the least finer height with data",
        LevelRule::Max => "the greatest finer height with data",
    };
    let non_finite = match h.non_finite {
        NonFinite::Refuse => "refused",
        NonFinite::Nodata => "stored as nodata",
    };
    vec![
        format!(
            "Heights {}: scale {} m, offset {} m, nodata {nodata}{range}; non-finite input {non_finite}.",
            f.storage(),
            f.scale(),
            f.offset()
        ),
        format!("Coarser levels: height rule {} ({words}).", h.rule),
    ]
}

struct Outcome {
    ct: PathBuf,
    summary: clipmap::prep::Summary,
    seconds: f64,
    layout: Layout,
}

fn prepare(cli: &Cli, out: &Path, cancel: &AtomicBool) -> Result<Outcome, PrepError> {
    let started = Instant::now();
    let limits = Limits { max_memory_bytes: cli.max_memory << 20, ..Limits::default() };
    let format = cli.format().texel();
    let heights = height_prep(cli)?;
    let (source, (width, height), origin) = match (&cli.input, cli.source, heights) {
        (Some(path), _, Some(mut prep)) => {
            let tiff = HeightTiff::open(path, &limits)?;
            // The input's nodata carries over, as GDAL carries it, unless --height-nodata names
            // another (a NaN one names no stored value: --nan decides what NaN pixels become).
            if let (None, Some(nd)) = (cli.height_nodata, tiff.nodata().filter(|v| !v.is_nan())) {
                let f = prep.format;
                prep.format = HeightFormat::new(f.storage(), f.scale(), f.offset(), Some(nd)).map_err(|e| {
                    PrepError::Geometry(format!(
                        "{}: its GDAL_NODATA {nd}, which the texture would keep as its nodata value, is not a stored value of --format {}: {e}; pass --height-nodata V (a stored value outside the data)",
                        path.display(),
                        format.short_name()
                    ))
                })?;
            }
            if matches!(prep.non_finite, NonFinite::Nodata) && prep.format.nodata().is_none() {
                return Err(PrepError::Geometry(format!(
                    "--nan nodata stores NaN and infinite heights as the nodata value, and neither --height-nodata nor {} (no GDAL_NODATA, or a NaN one) gives one; expected --height-nodata V (a stored value outside the data, e.g. -32768); pass it, or --nan refuse",
                    path.display()
                )));
            }
            let (w, h) = tiff.dimensions();
            let size = if cli.pad {
                if (w, h) != (next_power_of_two(w), next_power_of_two(h)) && prep.format.nodata().is_none() {
                    return Err(PrepError::Geometry(format!(
                        "--pad fills a height texture with the nodata value, and none was given; expected --height-nodata V for {} ({w}x{h}); pass it, or crop the elevation model to powers of two",
                        path.display()
                    )));
                }
                (next_power_of_two(w), next_power_of_two(h))
            } else {
                let hint = "; pass --pad (with --height-nodata) to pad it with nodata, or crop the elevation model";
                check_pow2(format!("the width of {}", path.display()), w, hint)?;
                check_pow2(format!("the height of {}", path.display()), h, hint)?;
                (w, h)
            };
            let file = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let mut origin = format!("elevation model {file} ({w}x{h}, {} samples", tiff.sample());
            if let Some(nd) = tiff.nodata() {
                origin.push_str(&format!(", nodata {nd}"));
            }
            if size != (w, h) {
                origin.push_str(&format!(", padded with nodata to {}x{}", size.0, size.1));
            }
            origin.push(')');
            (Source::Heights { prep, input: HeightInput::Tiff(Box::new(tiff)) }, size, origin)
        }
        (Some(path), _, None) => {
            let mut img = open_image(path, &limits)?;
            img.reduce_depth = cli.reduce_depth;
            img.check_depth(format)?;
            let (w, h) = (img.width, img.height);
            let size = if cli.pad {
                (next_power_of_two(w), next_power_of_two(h))
            } else {
                let hint = "; pass --pad to pad it with black, transparent texels, or resize the image";
                check_pow2(format!("the width of {}", path.display()), w, hint)?;
                check_pow2(format!("the height of {}", path.display()), h, hint)?;
                (w, h)
            };
            let file = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let mut origin = format!("image {file} ({w}x{h}");
            if size != (w, h) {
                origin.push_str(&format!(", padded to {}x{}", size.0, size.1));
            }
            origin.push(')');
            (Source::Image(img), size, origin)
        }
        (None, Some(kind), heights) => {
            let text = cli.size.as_deref().unwrap_or_default();
            let (w, h) = parse_pair(text, "--size")?;
            let hint = "; pass --size with a power of two";
            check_pow2("the --size width".into(), w, hint)?;
            check_pow2("the --size height".into(), h, hint)?;
            match kind {
                SourceKind::Hash => (Source::Hash, (w, h), "the hash verification source (not filtered)".into()),
                SourceKind::Terrain => {
                    (Source::Terrain { seed: cli.seed }, (w, h), format!("the terrain source, seed {}", cli.seed))
                }
                SourceKind::Heights => {
                    let prep = heights.expect("--source heights asks for heights");
                    let origin = "the height verification source at level 0 (docs/ELEVATION.md)".to_string();
                    (Source::Heights { prep, input: HeightInput::Verification }, (w, h), origin)
                }
            }
        }
        (None, None, _) => unreachable!("clap requires --input or --source"),
    };
    let tiles_in_file = match cli.tiles_per_file.split_once(['x', 'X', ',']) {
        Some(_) => parse_pair(&cli.tiles_per_file, "--tiles-per-file")?,
        None => (parse_pair(&cli.tiles_per_file, "--tiles-per-file")?.0, 1),
    };
    let inset = match (&cli.inset, cli.inset_level) {
        (Some(text), Some(level)) => Some(parse_inset(text, level)?),
        _ => None,
    };
    let layout = Layout::new(Spec {
        width,
        height,
        clip: cli.clip,
        tile: cli.tile(),
        format,
        tiles_in_file,
        header_bytes: cli.header_bytes,
        streams: cli.streams,
        inset,
        compression: cli.zstd.map(Compression::Zstd),
    })?;
    let layout = match cli.format().blocks() {
        Some(bc) => layout.with_blocks(bc, cli.bc_quality)?,
        None => layout,
    };
    let filter = match cli.filter {
        FilterArg::Box => Filter::Box,
        FilterArg::Lanczos3 => Filter::Lanczos3,
    };
    let mut description = vec![format!("Prepared by clipprep {} from {origin}.", env!("CARGO_PKG_VERSION"))];
    if let Some(h) = &heights {
        description.extend(height_description(h));
    } else if !matches!(source, Source::Hash) {
        let f = match filter {
            Filter::Box => "2x2 box",
            Filter::Lanczos3 => "Lanczos-3",
        };
        let light = if cli.linear_light { "linear light" } else { "stored values" };
        description.push(format!("Coarser levels: {f} filter on {light}."));
    }
    description.push(match &source {
        Source::Image(image) => image.georef_note(),
        _ => "Georeferencing: none (the input is not a georeferenced image; docs/GEOREF.md).".into(),
    });
    let name = cli.name.clone().unwrap_or_else(|| default_name(&cli.out));
    let staging = Staging::begin(out, cli.force)?;
    let bar = if cli.quiet || !std::io::stderr().is_terminal() {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::with_draw_target(Some(layout.total_texels()), ProgressDrawTarget::stderr());
        b.set_style(
            ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {percent:>3}% {msg} (eta {eta})")
                .expect("a valid template")
                .progress_chars("=> "),
        );
        b.set_message(format!("{} levels", layout.levels.len()));
        b
    };
    let job = Job { layout: layout.clone(), source, filter, linear_light: cli.linear_light, name, description, limits };
    let summary = clipmap::prep::run(job, staging.path(), cancel, out, &|n| bar.inc(n))?;
    bar.finish_and_clear();
    if cancel.load(Ordering::Relaxed) {
        return Err(PrepError::Interrupted { dir: out.to_path_buf() });
    }
    staging.commit()?;
    Ok(Outcome { ct: out.join(&summary.ct), summary, seconds: started.elapsed().as_secs_f64(), layout })
}

enum Publish {
    #[cfg_attr(not(feature = "remote"), allow(dead_code))]
    Prep(PrepError),
    Other(i32, String),
}

/// A remote `--out`: prepares into a temporary directory, uploads every file to `url`, writes
/// the configuration that reads them from there into `--config-out`, removes the temporary
/// directory. Returns the outcome (its `.ct` the one in `--config-out`) and the files and bytes
/// uploaded.
fn publish(cli: &Cli, url: &str, cancel: &AtomicBool) -> Result<(Outcome, (u64, u64)), Publish> {
    let Some(config_out) = &cli.config_out else {
        return Err(Publish::Other(
            1,
            format!("--out {url} is a remote location: give --config-out DIR, the local directory for the .ct and .ic files that read the uploaded tiles"),
        ));
    };
    remote_upload(cli, url, config_out, cancel)
}

#[cfg(feature = "remote")]
fn remote_upload(
    cli: &Cli,
    url: &str,
    config_out: &Path,
    cancel: &AtomicBool,
) -> Result<(Outcome, (u64, u64)), Publish> {
    use clipmap::source::remote::{Location, Remote, RemoteOptions};
    let url = url.trim_end_matches('/');
    if let Err(e) = Location::parse(&format!("{url}/x")) {
        return Err(Publish::Other(1, format!("--out: {e}")));
    }
    let opts = RemoteOptions::from_env().map_err(|e| Publish::Other(1, e.to_string()))?;
    let remote =
        Remote::new(RemoteOptions { cache_dir: None, ..opts }).map_err(|e| Publish::Other(2, e.to_string()))?;
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    let stage = std::env::temp_dir().join(format!("clipprep-upload-{}-{nanos}", std::process::id()));
    let outcome = prepare(cli, &stage, cancel).map_err(Publish::Prep);
    let result = outcome.and_then(|o| {
        let up = clipmap::prep::publish::upload(&stage, url, &remote, &|_| {})
            .map_err(|e| Publish::Other(2, format!("{e}; the pyramid was not fully uploaded")))?;
        let ct = clipmap::prep::publish::write_pointed_config(&stage, config_out, url, &[])
            .map_err(|e| Publish::Other(2, format!("writing the configuration into {}: {e}", config_out.display())))?;
        Ok((Outcome { ct, ..o }, up))
    });
    let _ = std::fs::remove_dir_all(&stage);
    result
}

#[cfg(not(feature = "remote"))]
fn remote_upload(_: &Cli, url: &str, _: &Path, _: &AtomicBool) -> Result<(Outcome, (u64, u64)), Publish> {
    Err(Publish::Other(
        2,
        format!("--out {url}: this build cannot write remote locations (build with the `remote` feature, the default)"),
    ))
}

/// Sets `flag` on Ctrl-C or SIGTERM, so the run stops between bands and removes its partial
/// output instead of dying mid-write. The handlers are registered before this returns.
fn watch_signals(flag: Arc<AtomicBool>) -> anyhow::Result<()> {
    // A task on the process's one runtime (which remote uploads use too).
    let rt = clipmap::runtime::shared().context("starting the signal watcher")?;
    #[cfg(unix)]
    let (mut int, mut term) = {
        use tokio::signal::unix::{signal, SignalKind};
        let _guard = rt.enter();
        (
            signal(SignalKind::interrupt()).context("watching SIGINT")?,
            signal(SignalKind::terminate()).context("watching SIGTERM")?,
        )
    };
    rt.spawn(async move {
        #[cfg(unix)]
        tokio::select! {
            _ = int.recv() => {}
            _ = term.recv() => {}
        }
        #[cfg(not(unix))]
        let _ = tokio::signal::ctrl_c().await;
        flag.store(true, Ordering::Relaxed);
    });
    Ok(())
}

fn main() -> ExitCode {
    // An --input naming a tile pyramid is served as it is: --config-only goes without saying.
    let cli: Cli = clipmap::cli::parse_from(config_only::pyramid_means_config_only(std::env::args_os().collect()));
    clipmap::cli::init_tool_log();
    let cancel = Arc::new(AtomicBool::new(false));
    if let Err(e) = watch_signals(cancel.clone()) {
        eprintln!("clipprep: warning: {e:#}; Ctrl-C will stop the run without cleaning up");
    }
    if cli.config_only {
        return match config_only(&cli) {
            Ok(()) => clipmap::report::exit::status(clipmap::report::exit::OK),
            Err(e) => {
                eprintln!("clipprep: error: {e}");
                clipmap::report::exit::status(e.exit_code())
            }
        };
    }
    // A remote --input is served as it is (--config-only); a pyramid is made from a local file.
    if let Some(input) =
        cli.input.as_ref().filter(|p| clipmap::place::Place::from_path(p.to_path_buf()).remote().is_some())
    {
        eprintln!(
            "clipprep: error: --input {} is a remote location, and a pyramid is prepared from a local image; add --config-only to serve a GeoTIFF or COG there as it is (docs/COG.md), or download the file and prepare it from disk",
            shown(input)
        );
        return clipmap::report::exit::status(clipmap::report::exit::BAD_INPUT);
    }
    let url = clipmap::place::Place::from_path(cli.out.clone()).remote().map(|u| u.to_string());
    if let Some(cog) = &cli.cog {
        // Refused before any work: what --cog could not write, or where.
        let refused = if url.is_some() {
            Some("it is written from a local --out; prepare locally, then upload the file".to_string())
        } else if let Some(bc) = cli.format().blocks() {
            Some(format!("a COG holds texels, and --format {} stores blocks; drop one of them", bc.name()))
        } else {
            clipmap::prep::cog::check(cli.format().texel(), cli.tile()).err().map(|e| e.to_string())
        };
        if let Some(why) = refused {
            eprintln!("clipprep: error: --cog {}: {why}", cog.display());
            return clipmap::report::exit::status(clipmap::report::exit::BAD_INPUT);
        }
        // A FIFO or a device there would block the write or swallow the file: never opened.
        if let Err(e) = clipmap::prep::cog::check_target(cog) {
            eprintln!("clipprep: error: --cog {e}");
            return clipmap::report::exit::status(clipmap::report::exit::COULD_NOT_RUN);
        }
    }
    let mut uploaded = None;
    let result = match &url {
        None => prepare(&cli, &cli.out, &cancel),
        Some(url) => match publish(&cli, url, &cancel) {
            Ok((o, u)) => {
                uploaded = Some(u);
                Ok(o)
            }
            Err(Publish::Prep(e)) => Err(e),
            Err(Publish::Other(code, why)) => {
                eprintln!("clipprep: error: {why}");
                return clipmap::report::exit::status(code);
            }
        },
    };
    let result = result.map(|o| {
        let cog = cli.cog.as_ref().map(|p| (p, write_cog(&o, p, cli.cog_compression, &cancel)));
        (o, cog)
    });
    match result {
        Ok((_, Some((path, Err(why))))) => {
            eprintln!("clipprep: error: --cog {}: {why} (the pyramid itself was written)", path.display());
            // Exit 2 for an interruption too, as for an interrupted pyramid.
            clipmap::report::exit::status(clipmap::report::exit::COULD_NOT_RUN)
        }
        Ok((o, cog)) => {
            let cog = cog.map(|(p, r)| (p, r.expect("an error returned above")));
            let s = &o.summary;
            let mib = s.bytes as f64 / (1u64 << 20) as f64;
            if cli.json {
                let spec = &o.layout.spec;
                let v = serde_json::json!({
                    "ct": o.ct,
                    "levels": s.levels,
                    "bytes": s.bytes,
                    "seconds": o.seconds,
                    "files": s.files,
                    "texels": s.texels,
                    "image_cache_levels": s.image_cache_levels,
                    "pyramid_levels": s.pyramid_levels,
                    "size": [spec.width, spec.height],
                    "clip": spec.clip,
                    "tile": spec.tile,
                    "format": o.layout.disk_format().short_name(),
                    "inset_tiles": s.inset_tiles,
                    "border_tiles": s.border_tiles,
                    "absent_tiles": s.absent_tiles,
                    "buffer_bytes": s.buffer_bytes,
                });
                let mut v = v;
                if let Some((path, w)) = &cog {
                    v["cog"] = serde_json::json!({ "path": path, "images": w.images, "tiles": w.tiles, "bytes": w.bytes, "bigtiff": w.bigtiff });
                }
                if let (Some(url), Some((files, bytes))) = (&url, uploaded) {
                    v["location"] = serde_json::json!(url);
                    v["uploaded_files"] = serde_json::json!(files);
                    v["uploaded_bytes"] = serde_json::json!(bytes);
                }
                println!("{v}");
            } else if !cli.quiet {
                println!(
                    "wrote {}: {} levels ({} image cache, {} pyramid), {} files, {:.1} MiB in {:.2} s ({:.1} MiB/s)",
                    o.ct.display(),
                    s.levels,
                    s.image_cache_levels,
                    s.pyramid_levels,
                    s.files,
                    mib,
                    o.seconds,
                    mib / o.seconds.max(1e-9)
                );
            }
            if let (Some((path, w)), false) = (&cog, cli.json || cli.quiet) {
                println!(
                    "wrote {}: a COG of {} images ({} tiles, {} bytes{})",
                    path.display(),
                    w.images,
                    w.tiles,
                    w.bytes,
                    if w.bigtiff { ", BigTIFF" } else { "" }
                );
            }
            if let (Some(url), Some((files, bytes)), false) = (&url, uploaded, cli.json || cli.quiet) {
                println!("uploaded {files} files ({bytes} bytes) to {url}; {} reads them from there", o.ct.display());
            }
            clipmap::report::exit::status(clipmap::report::exit::OK)
        }
        Err(e) => {
            eprintln!("clipprep: error: {e}");
            clipmap::report::exit::status(e.exit_code())
        }
    }
}
