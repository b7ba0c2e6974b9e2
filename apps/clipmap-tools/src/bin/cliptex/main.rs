//! `cliptex`: inspect, validate and locate data of Performer clip-texture (`.ct`) configurations.
//!
//! Exit status: 0 ok, 1 the input is bad, 2 the tool could not run.

#![forbid(unsafe_code)]

mod grow;
mod locate;
#[cfg(feature = "remote")]
mod seed;
mod sources;

use clap::{Parser, Subcommand};
use clipmap::cli::{self as cmdline, EnvArgs, TilesArgs};
use clipmap::config::FileKind;
use clipmap::place::Place;
use clipmap::plan;
use clipmap::report::{self, check, exit, info, validate};
use clipmap::roam;
use clipmap::source::TileSource as _;
use sources::*;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "cliptex",
    version,
    about = "Inspect, validate, size and fly clip textures (.ct configurations and their data)",
    after_help = "\
Examples:
  cliptex validate config_examples/*.ct
  cliptex validate --strict --json my.ct
  cliptex info config_examples/v2_format_params.ct
  cliptex tile my.ct --level 0 --s 3 --t 5 --json
  cliptex info my.ct --env DATA=/mnt/terrain
  cliptex roam --source hash --size 65536 --clip 1024 --flight straight:16:30 --frames 100
  cliptex roam my.ct --flight circle:2000:8 --frames 300 --budget-ms 4 --json
  cliptex check my.ct --json
  cliptex dump my.ct --level 2 --out level2.png
  cliptex dump --attach terrain --out-dir pictures
  cliptex grow add survey flight1/*.json
  cliptex seed 'xyz:https://tiles.example.org/{z}/{x}/{y}.png' --bbox 13.0,52.3,13.8,52.7 --levels 0..4 --estimate

Exit status: 0 ok, 1 the input is bad, 2 the tool could not run."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check .ct files (and every .ic they name); report every problem with file:line:col.
    #[command(after_help = "\
Examples:
  cliptex validate config_examples/*.ct
  cliptex validate --strict --json my.ct
  cliptex validate --ct-only --env DATA=/mnt/terrain configs/*.ct   # on a machine without the data
  cliptex validate --quiet --unset HOME configs/*.ct

Exit status: 0 every file valid, 1 some file invalid, 2 some file could not be read.")]
    Validate {
        #[command(flatten)]
        args: cmdline::ValidateArgs,
        /// Check each .ct alone: the .ic files it names are resolved and printed, not opened
        /// (for CI on a machine without the data volume).
        #[arg(long)]
        ct_only: bool,
    },
    /// A growing texture in a directory: create it, add georeferenced patches, rebuild, status,
    /// pictures (docs/GROWING.md).
    #[command(after_help = "\
Examples:
  cliptex grow create survey --origin 0,0 --texels-per-unit 1 --tile 256 --format rgb8
  cliptex grow add survey flight1/*.json
  cliptex grow status survey --json
  cliptex grow dump survey --level 0 --out level0.png")]
    Grow {
        #[command(subcommand)]
        cmd: grow::GrowCommand,
    },
    /// A live view of a running service (levels, centres, valid regions, min LOD, tick rate, read queues).
    #[command(after_help = "\
Examples:
  cliptex attach demo
  cliptex attach terrain --once --json
  cliptex attach terrain --shm-dir /tmp/maps --interval 0.5")]
    Attach {
        /// The service's --name.
        name: String,
        /// Where the service's mapping lives (the service's --shm-dir).
        #[arg(long)]
        shm_dir: Option<PathBuf>,
        /// The service's control socket, asked for queue figures (default: the service's
        /// default, clipmap-NAME.sock beside the mapping).
        #[arg(long)]
        socket: Option<PathBuf>,
        /// The view to show (docs/VIEWS.md): `main`, the primary, or a further view's name.
        #[arg(long, default_value = "main")]
        view: String,
        /// Print one view and exit.
        #[arg(long)]
        once: bool,
        /// Print JSON (implies --once).
        #[arg(long)]
        json: bool,
        /// Seconds between refreshes (and over which the tick rate is measured).
        #[arg(long, default_value_t = 1.0)]
        interval: f64,
    },
    /// Print every value (defaults marked) and the level table.
    #[command(after_help = "\
Examples:
  cliptex info config_examples/v2_format_params.ct
  cliptex info my.ct --json
  cliptex info my.ct --env DATA=/mnt/terrain
  cliptex info --ct-only my.ct     # the level table without opening the .ic files")]
    Info {
        /// The .ct file, or a tiled GeoTIFF / COG (the texture it is served as, clip size 1024),
        /// or a tile service or tree, `xyz:TEMPLATE` (docs/TILES.md).
        file: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        tiles: TilesArgs,
        /// Read the .ct alone: the .ic files it names are resolved and listed, not opened; what
        /// only they give (tile size, regions) is shown as unknown (`?`, null in JSON).
        #[arg(long)]
        ct_only: bool,
        #[command(flatten)]
        env: EnvArgs,
    },
    /// Where a longitude / latitude is in texels of a level of a COG or a tile pyramid, or the reverse (docs/GEOREF.md)
    #[command(after_help = "\
Texel (s, t) covers [s, s+1) x [t, t+1); t counts up from the south edge (t = height - line for
GDAL's continuous line). Longitude / latitude are WGS 84 degrees.

Examples:
  cliptex locate ortho.tif --lonlat 13.4,52.5
  cliptex locate ortho.tif --lonlat=-122.42,37.77 --level 3 --json
  cliptex locate ortho.tif --texel 1024.5,2048.5
  cliptex locate 'xyz:tiles/{z}/{x}/{y}.png' --lonlat 13.4,52.5   # WebMercatorQuad")]
    Locate {
        /// A georeferenced tiled GeoTIFF / COG, or a tile pyramid (`xyz:TEMPLATE`, `.pmtiles`,
        /// `.mbtiles`; EPSG:3857 WebMercatorQuad, level 0 = its maximum zoom).
        file: PathBuf,
        /// The point's longitude and latitude, degrees: prints its continuous texel (s, t).
        #[arg(long, value_name = "LON,LAT", allow_hyphen_values = true, conflicts_with = "texel")]
        lonlat: Option<String>,
        /// A continuous texel (s, t) of the level: prints its longitude / latitude and map x / y.
        #[arg(long, value_name = "S,T", allow_hyphen_values = true)]
        texel: Option<String>,
        /// The level the texel is of.
        #[arg(long, default_value_t = 0)]
        level: u32,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        tiles: TilesArgs,
    },
    /// Size a deployment: clipmap memory against the full mipmap, update bandwidth, clip size for a display.
    #[command(after_help = "\
Examples:
  cliptex plan --size 67108864 --clip 2048 --texel-bytes 4
  cliptex plan --size 65536 --clip 1024 --texel-bytes 3 --display 1920 --speed 2000 --json
  cliptex plan --size 67108864 --clip 2048 --texel-bytes 4 --display 1920 --eye-height 3000
  cliptex plan --size 8192x2048 --clip 512 --texel-bytes 3
  cliptex plan my.ct                       # sizes, clip and texel format from the .ct
  cliptex plan my.ct --clip 2048 --json    # the same texture with another clip size
  cliptex plan --size 65536 --clip 512 --tile 128 --view-spread 4096   # grids for views 4096 texels apart
  cliptex plan --size 65536 --clip 512 --tile 128 --own-views 3        # and three views with grids of their own
  cliptex plan --table --clip 2048 --texel-bytes 4")]
    Plan {
        /// A .ct to size: its virt_size, clip_size, texel format and invalid_border (its .ic
        /// files are not opened); or a GeoTIFF / COG: its size rounded up to powers of two and
        /// its texel format; --clip, --texel-bytes and --invalid-border override them.
        #[arg(conflicts_with_all = ["size", "table"])]
        file: Option<PathBuf>,
        /// Texture size in texels: N (square) or WxH, powers of two.
        #[arg(long, value_name = "N|WxH", required_unless_present_any = ["table", "file"], value_parser = parse_plan_size)]
        size: Option<[u64; 2]>,
        /// Clip size (a power of two) [default: 1024, or the .ct's].
        #[arg(long)]
        clip: Option<u64>,
        /// Bytes per texel (e.g. 3 for RGB8, 4 for RGBA8, 2 for RGB565) [default: 4, or the .ct's].
        #[arg(long)]
        texel_bytes: Option<u64>,
        /// The block format clipmapd publishes (`clipmapd --format bc1|bc4|bc5|bc7`): the image
        /// caches are sized in 4 x 4 blocks (the `slots` line states the formula).
        #[arg(long, value_name = "FORMAT", value_parser = clipmap::texel::Bc::parse)]
        format: Option<clipmap::texel::Bc>,
        /// Display width in pixels: recommends a clip size.
        #[arg(long)]
        display: Option<u64>,
        /// Horizontal field of view in degrees.
        #[arg(long, default_value_t = 60.0)]
        fov: f64,
        /// Centre speed in level-0 texels per second: update bandwidth.
        #[arg(long)]
        speed: Option<f64>,
        /// Eye height in metres: levels a virtual clip texture should address.
        #[arg(long)]
        eye_height: Option<f64>,
        /// Metres per level-0 texel (with --eye-height).
        #[arg(long, default_value_t = 1.0)]
        texel_metres: f64,
        /// With --eye-height: 0 keeps the finest levels (resolution), 1 keeps the coarsest (area), as Performer's rule.
        #[arg(long, default_value_t = 0.0)]
        tradeoff: f64,
        /// Invalid border (with --eye-height) [default: 8, or the .ct's].
        #[arg(long)]
        invalid_border: Option<u64>,
        /// Tile size of the stack levels (texels, square), for the image caches `clipmapd` maps
        /// (for a .ct, its .ic's tile_size).
        #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u64).range(1..=65536))]
        tile: u64,
        /// Spare tile rows and columns each stack level's grid keeps beyond its window: fixed
        /// grids (as `--prefetch ring|direction|ahead` keep). Without it, the grids the default
        /// adaptive policy sizes from its default budget (twice the lookahead-1 grids); an .ic's
        /// mem_region_size sets a grid of its own.
        #[arg(long, value_parser = clap::value_parser!(u64).range(0..=64))]
        lookahead: Option<u64>,
        /// The texels are heights (a .ct with `#clipmap height` lines says so itself): the image
        /// caches also hold each level's tile height ranges, 16 bytes a slot.
        #[arg(long)]
        heights: bool,
        /// Level-0 texels further views may lie apart and still be held whole, as `clipmapd
        /// --view-spread` (docs/VIEWS.md): the grids the engine widens for it, and their bytes.
        #[arg(long, value_name = "TEXELS", default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=clipmap::limits::MAX_TEXTURE_SIZE))]
        view_spread: u64,
        /// Views with grids of their own, as `clipmapd --view NAME:W:own` (docs/VIEWS.md, "Views
        /// far apart"): each one view's mapping more, and the bytes of every mapping together.
        #[arg(long, value_name = "N", default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=15))]
        own_views: u64,
        /// The texture spans 360 degrees of longitude, as `clipmapd --global` serves it (a global
        /// COG, or a .ct whose georeferencing spans 360 degrees, says so itself): its levels
        /// wider than the clip wrap, with the wider grids the engine gives them (docs/GEOREF.md).
        #[arg(long)]
        global: bool,
        /// Print memory for texture sizes 2^10 to 2^26 at once.
        #[arg(long)]
        table: bool,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        env: EnvArgs,
    },
    /// Print where a tile's texels are: file, byte offset, length, stream server.
    #[command(after_help = "\
Examples:
  cliptex tile config_examples/prepared/hash256.ct --level 0 --s 1 --t 2
  cliptex tile my.ct --level 3 --s 12 --t 40 --json
  cliptex tile my.ct --level 9 --s 0 --t 0 --env DATA=/mnt/terrain   # a pyramid level: one tile

Exit status: 0 found, 1 no such tile or an invalid configuration, 2 the tool could not run.")]
    Tile {
        /// The .ct file, or a tile service or tree, `xyz:TEMPLATE` (docs/TILES.md).
        file: PathBuf,
        #[command(flatten)]
        tiles: TilesArgs,
        /// Level (0 is the finest).
        #[arg(long)]
        level: u32,
        /// Tile column (0 for pyramid levels).
        #[arg(long)]
        s: u64,
        /// Tile row (0 for pyramid levels).
        #[arg(long)]
        t: u64,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        env: EnvArgs,
    },
    /// Fly the clip centre over a texture and report what every frame cost.
    #[command(after_help = "\
Flights (speeds and distances in level-0 texels per frame, angles in degrees from +s):
  straight:SPEED[:ANGLE]  circle:RADIUS:SPEED  zigzag:SPEED:PERIOD  hover  jump:EVERY:DIST

Frames run on a 60 frames/s clock by default, reads arriving in real time as in the service;
--fps sets the rate, --wait-for-reads makes every read finish between frames (deterministic).

Examples:
  cliptex roam --source hash --size 65536 --clip 1024 --flight straight:16 --frames 120
  cliptex roam --source hash --size 65536 --clip 1024 --flight straight:16 --frames 50 --wait-for-reads
  cliptex roam config_examples/prepared/hash256.ct --flight straight:4:45 --frames 20 --json
  cliptex roam --source terrain --size 1048576 --clip 2048 --flight zigzag:64:20 --frames 200 --budget-ms inf")]
    Roam(RoamArgs),
    /// Fill the remote disk cache with the tiles of an area at some levels of a tile service or
    /// remote archive, before a flight; --estimate says what it would take (docs/TILES.md).
    #[cfg(feature = "remote")]
    #[command(after_help = "\
The area is a box (--bbox W,S,E,N, degrees of longitude and latitude, WGS 84) or a corridor
--width-km wide along a route (--route FILE: one LON,LAT point a line, in flight order; blank
lines and lines starting with # are skipped). Levels are cliptex's: level 0 is the finest zoom.
Tiles the cache holds already are skipped: stop a seed at any time (Ctrl-C) and run it again to
go on. Missing tiles (404, 204) are counted, never cached.

Examples:
  cliptex seed 'xyz:https://tiles.example.org/{z}/{x}/{y}.png' --zooms 0..18 --bbox 13.0,52.3,13.8,52.7 --levels 0..4 --estimate
  cliptex seed 'xyz:https://tiles.example.org/{z}/{x}/{y}.png' --zooms 0..18 --route flight.txt --width-km 5 --levels 0..6 --cache-dir /var/cache/clipmap
  cliptex seed https://data.example.org/world.pmtiles --bbox=-10,35,30,60 --levels 2..8 --json

Exit status: 0 done (or estimated), 1 bad input (area, route, levels, source, no cache), 2 some
tiles could not be fetched (run it again to fetch them).")]
    Seed(seed::SeedArgs),
    /// Write a level region to PNG from the tile files, or every level of a running service.
    #[command(after_help = "\
From disk, one level (or a part of it) becomes one PNG, one pixel per texel, t upwards (the
last row of the region is the top of the picture). 16-bit formats give 16-bit PNGs of the stored
values (grey, grey and alpha, RGB, RGBA); others are converted to 8-bit RGB, or RGBA when they
carry alpha. A tile that cannot be read is painted as magenta and black squares, listed, and the
exit status is 1.

From a running service (--attach NAME --out-dir DIR): DIR/level-NN.png shows each level's window
(yellow outline), its valid region (red outline) and the invalid border (dark checkerboard);
DIR/view.png is the view around the centre as a renderer would texture it and DIR/rings.png the
same view coloured by the level each pixel uses. A texture of heights is drawn as from disk: each
level in false colour with its legend below (--range and --shade as there), the view over the
range of every level.

Examples:
  cliptex dump config_examples/prepared/hash256.ct --level 1 --out level1.png
  cliptex dump my.ct --level 0 --region 4096,4096,6144,6144 --out part.png --json
  cliptex dump --attach terrain --out-dir pictures
  cliptex dump --attach hash --shm-dir /tmp/maps --out-dir pictures --json

Exit status: 0 written, 1 some tiles could not be read (the picture is written) or bad options,
2 the tool could not run (unreadable configuration, no such service, unwritable output).")]
    Dump(DumpArgs),
    /// Walk every tile on disk: per level, tiles present, missing, short, unreadable, corrupt (compressed) and covered by the default tile.
    #[command(after_help = "\
Examples:
  cliptex check config_examples/prepared/hash256.ct
  cliptex check my.ct --json > check.json
  cliptex check my.ct --quiet --env DATA=/mnt/terrain     # in CI: problems and the verdict only

Exit status: 0 every tile can be served (present, or covered by a default tile), 1 some cannot
or the configuration is invalid, 2 the configuration cannot be read.")]
    Check {
        /// The .ct file, or a tiled GeoTIFF / COG (`.tif`, `.tiff`) served as it is, or a tile
        /// service or tree, `xyz:TEMPLATE` (docs/TILES.md).
        file: PathBuf,
        #[command(flatten)]
        tiles: TilesArgs,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// No progress bar and no table: only problems and a failing verdict are printed.
        #[arg(long, short)]
        quiet: bool,
        #[command(flatten)]
        env: EnvArgs,
    },
}

#[derive(clap::Args)]
struct DumpArgs {
    /// The .ct file whose tiles are read, or a tiled GeoTIFF / COG, or a tile service or tree
    /// `xyz:TEMPLATE` (docs/TILES.md) (or use --attach).
    #[arg(required_unless_present = "attach", conflicts_with = "attach", requires = "out")]
    config: Option<PathBuf>,
    /// Level to dump (0 is the finest).
    #[arg(long, default_value_t = 0)]
    level: u32,
    /// Part of the level: S0,T0,S1,T1 in level texels, half-open (default: the whole level, if
    /// it has at most 4096x4096 texels).
    #[arg(long, value_name = "S0,T0,S1,T1", value_parser = report::dump::parse_region)]
    region: Option<[u64; 4]>,
    /// The PNG to write (with a .ct file).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Heights: hillshade the false-colour map (light from the north-west).
    #[arg(long)]
    shade: bool,
    /// Heights: the metres the colour bar spans, MIN,MAX (default: the region's least and
    /// greatest height with data).
    #[arg(long, value_name = "MIN,MAX", value_parser = report::dump::parse_range, allow_hyphen_values = true)]
    range: Option<[f64; 2]>,
    /// Picture a running service instead: its --name.
    #[arg(long, value_name = "NAME", requires = "out_dir", conflicts_with_all = ["region", "out"])]
    attach: Option<String>,
    /// Where the service's mapping lives (the service's --shm-dir; with --attach).
    #[arg(long, requires = "attach")]
    shm_dir: Option<PathBuf>,
    /// Directory for the pictures (with --attach; created if needed).
    #[arg(long, requires = "attach")]
    out_dir: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Print nothing but problems.
    #[arg(long, short)]
    quiet: bool,
    #[command(flatten)]
    env: EnvArgs,
    #[command(flatten)]
    tiles: TilesArgs,
}

#[derive(clap::Args)]
struct RoamArgs {
    /// The .ct file whose tiles are read, or a GeoTIFF / COG (path or URL) flown as clipmapd
    /// serves it (clip size --clip, default 1024); or use --source.
    #[arg(required_unless_present = "source", conflicts_with = "source")]
    config: Option<PathBuf>,
    /// A procedural texture instead of a configuration (4-byte texels).
    #[arg(long, value_enum, requires_all = ["size", "clip"])]
    source: Option<ProceduralArg>,
    /// Procedural texture size in texels a side.
    #[arg(long)]
    size: Option<u64>,
    /// Clip size: of the procedural texture, or of a GeoTIFF / COG (default 1024).
    #[arg(long)]
    clip: Option<u64>,
    /// Procedural tile size in texels a side.
    #[arg(long, default_value_t = 256)]
    tile: u64,
    /// Invalid border in texels (default: the configuration's, 0 for a procedural texture).
    #[arg(long)]
    border: Option<u64>,
    /// The flight: straight:SPEED[:ANGLE], circle:RADIUS:SPEED, zigzag:SPEED:PERIOD, hover, jump:EVERY:DIST,
    /// or lonlat:LON,LAT:LON,LAT (from one WGS 84 place to another over the frames, through the
    /// texture's georeferencing; docs/GEOREF.md).
    // This comment is clap's help text, printed as written: `[:ANGLE]` marks an optional argument,
    // not a link, and escaping it would change the help.
    #[allow(rustdoc::broken_intra_doc_links)]
    #[arg(long, allow_hyphen_values = true)]
    flight: roam::Flight,
    /// Georeferences a procedural texture (--source) as the whole Web Mercator square (EPSG:3857,
    /// as `clipmapd --georef web-mercator`), so that a flight may be given in longitude / latitude.
    #[arg(long, value_name = "web-mercator", requires = "source", value_parser = ["web-mercator"])]
    georef: Option<String>,
    /// Frames to fly.
    #[arg(long)]
    frames: u64,
    /// Copy budget per frame in milliseconds (`inf` or `off`: no limit).
    #[arg(long, default_value = "6", value_parser = parse_budget_ms)]
    budget_ms: f64,
    /// Wait for every read between frames (an ideally fast disk): the report is deterministic.
    #[arg(long)]
    wait_for_reads: bool,
    /// Frames per second of the frame clock: frames are paced as a renderer's and reads arrive
    /// in real time between them, as in the service (0: frames back to back, no clock).
    #[arg(long, default_value_t = 60.0, conflicts_with = "wait_for_reads", value_parser = parse_fps)]
    fps: f64,
    /// Align each level's centre down to a multiple of this many level texels (1: texel-exact;
    /// Performer's InfiniteReality used 8). Copies column strips wider and less often, at the
    /// cost of up to ALIGNMENT - 1 texels of each level on the side the view moves towards.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=clipmap::clip::MAX_CENTRE_ALIGNMENT))]
    centre_alignment: u64,
    /// Print JSON instead of the per-frame table.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    paging: clipmap::cli::PagingArgs,
    #[command(flatten)]
    env: EnvArgs,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum ProceduralArg {
    Hash,
    Terrain,
}

fn main() -> ExitCode {
    let cli: Cli = cmdline::parse();
    clipmap::cli::init_tool_log();
    exit::status(run(cli))
}

/// `--budget-ms`: milliseconds of at least `MIN_BUDGET_MS` (less rounds to no work), or `inf` /
/// `off` for no limit.
fn parse_budget_ms(text: &str) -> Result<f64, String> {
    if text.trim().eq_ignore_ascii_case("off") {
        return Ok(f64::INFINITY);
    }
    let min = clipmap::limits::MIN_BUDGET_MS;
    match text.trim().parse::<f64>() {
        Ok(ms) if ms >= min => Ok(ms),
        _ => Err(format!(
            "`{text}` is not a budget: expected a number of milliseconds of at least {min} (MIN_BUDGET_MS; less rounds to no work), or inf (or off) for no limit"
        )),
    }
}

/// `--fps`: 0 (no clock) or a rate up to 10000 frames a second.
fn parse_fps(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(f) if f.is_finite() && (0.0..=10_000.0).contains(&f) => Ok(f),
        _ => Err(format!(
            "`{text}` is not a frame rate: expected 0 (no clock) or a number of frames per second up to 10000"
        )),
    }
}

/// `--size N` or `--size WxH`.
fn parse_plan_size(text: &str) -> Result<[u64; 2], String> {
    let num =
        |t: &str| t.trim().parse::<u64>().map_err(|_| format!("`{text}` is not N or WxH (e.g. 65536 or 8192x2048)"));
    match text.split_once(['x', 'X']) {
        Some((w, h)) => Ok([num(w)?, num(h)?]),
        None => num(text).map(|n| [n, n]),
    }
}

fn load(file: &Path, env: &EnvArgs) -> Result<(plan::ClipTexturePlan, Vec<clipmap::config::Diagnostic>), i32> {
    env.load_clip_texture(file, "cliptex", false)
}

fn roam(args: RoamArgs) -> i32 {
    let flight = args.flight;
    let mut paging_base = clipmap::paging::PagingOptions::default();
    let options = match (&args.config, args.source) {
        // A GeoTIFF or COG, local or remote, flown as `clipmapd FILE.tif --clip C` serves it.
        (Some(file), _) if is_cog(file) => {
            let place = Place::from_path(file.clone());
            match clipmap::source::CogSource::open_place(&place, args.clip.unwrap_or(COG_CLIP)) {
                Ok(src) => roam::RoamOptions::over(std::sync::Arc::new(src), flight, args.frames),
                Err(e) => {
                    eprintln!("cliptex roam: {e}");
                    return exit::BAD_INPUT;
                }
            }
        }
        (Some(file), _) => {
            let plan = match load(file, &args.env) {
                Ok((p, _)) => p,
                Err(c) => return c,
            };
            // The configuration's `#clipmap` lines, under the command line's flags.
            paging_base = plan.paging;
            match clipmap::source::open_plan(plan, &clipmap::limits::Limits::default()) {
                Ok(src) => roam::RoamOptions::over(src, flight, args.frames),
                Err(e) => {
                    eprintln!("cliptex roam: {e}");
                    return exit::BAD_INPUT;
                }
            }
        }
        (None, Some(kind)) => {
            let kind = match kind {
                ProceduralArg::Hash => roam::Procedural::Hash,
                ProceduralArg::Terrain => roam::Procedural::Terrain,
            };
            let (size, clip) = (args.size.unwrap_or(0), args.clip.unwrap_or(0));
            match roam::RoamOptions::procedural(kind, size, clip, args.tile, 0, flight, args.frames) {
                Ok(o) if args.georef.is_some() => {
                    roam::RoamOptions { source: clipmap_service::web_mercator_square(o.source.clone()), ..o }
                }
                Ok(o) => o,
                Err(e) => {
                    eprintln!("cliptex roam: {e}");
                    return exit::BAD_INPUT;
                }
            }
        }
        (None, None) => {
            eprintln!("cliptex roam: give a .ct file or --source hash|terrain with --size and --clip");
            return exit::BAD_INPUT;
        }
    };
    let mut settings = options.settings.with_paging(&args.paging.over(paging_base));
    settings.centre_alignment = args.centre_alignment;
    let options = roam::RoamOptions {
        settings,
        budget_ms: args.budget_ms.is_finite().then_some(args.budget_ms),
        wait_for_reads: args.wait_for_reads,
        fps: (args.fps > 0.0).then_some(args.fps),
        invalid_border: args.border,
        ..options
    };
    match roam::run(options) {
        Ok(report) => {
            report::emit(args.json, &report, roam::human);
            exit::OK
        }
        Err(e) => {
            eprintln!("cliptex roam: {e}");
            e.exit_code()
        }
    }
}

fn dump(args: DumpArgs) -> i32 {
    use clipmap_tools::inspect::live_dump;
    if let Some(name) = &args.attach {
        let dir = args.shm_dir.clone().unwrap_or_else(clipmap::shm::default_dir);
        let out = args.out_dir.clone().unwrap_or_default();
        let options = live_dump::Options { shade: args.shade, range: args.range };
        return match live_dump::dump(&dir, name, &out, &options) {
            Ok(d) => {
                if args.json {
                    println!("{}", serde_json::to_string_pretty(&d).expect("dump serialises"));
                } else if !args.quiet {
                    print!("{}", live_dump::human(&d));
                }
                exit::OK
            }
            Err(e) => {
                eprintln!("cliptex dump: {e}");
                exit::COULD_NOT_RUN
            }
        };
    }
    let (Some(file), Some(out)) = (&args.config, &args.out) else {
        eprintln!("cliptex dump: give a .ct file with --out FILE.png, or --attach NAME with --out-dir DIR");
        return exit::BAD_INPUT;
    };
    if let Some(src) = open_pyramid(file, &args.tiles, "cliptex dump") {
        let src = match src {
            Ok(s) => s,
            Err(c) => return c,
        };
        let shown = PathBuf::from(src.archive().place());
        let place = Place::from_path(shown.clone());
        return dump_level(&args, &shown, out, &src, &|_| Some(place.clone()));
    }
    if is_cog(file) {
        let src = match open_cog(file, "cliptex dump") {
            Ok(s) => s,
            Err(c) => return c,
        };
        // Reported under the name as it may be shown (a URL's password and signatures replaced).
        let shown = PathBuf::from(clipmap::place::redacted(&file.to_string_lossy()).as_ref());
        let place = Place::from_path(shown.clone());
        return dump_level(&args, &shown, out, &src, &|_| Some(place.clone()));
    }
    let plan = match load(file, &args.env) {
        Ok((p, _)) => p,
        Err(c) => return c,
    };
    let locator = plan.clone();
    let cog = plan.cog.as_ref().map(|c| c.place.clone());
    let src = match clipmap::source::open_plan(plan, &clipmap::limits::Limits::default()) {
        Ok(src) => src,
        Err(e) => {
            eprintln!("cliptex dump: {e}");
            return exit::BAD_INPUT;
        }
    };
    // A configuration naming a COG: every tile is the COG's.
    let file_of =
        |id: clipmap::source::TileId| cog.clone().or_else(|| locator.locate(id.level, id.s, id.t).ok().map(|l| l.path));
    dump_level(&args, file, out, src.as_ref(), &file_of)
}

/// Dumps `--level` (and `--region`) of `src` to `out`; `file_of` names the file of a tile.
fn dump_level(
    args: &DumpArgs,
    file: &Path,
    out: &Path,
    src: &dyn clipmap::source::TileSource,
    file_of: &dyn Fn(clipmap::source::TileId) -> Option<Place>,
) -> i32 {
    use report::dump;
    let count = src.desc().level_count() as u32;
    if args.level >= count {
        let e = dump::DumpError::NoLevel { level: args.level, last: count.saturating_sub(1) };
        return dump::finish(Err(e), args.json, args.quiet, "cliptex");
    }
    let d = src.desc().level(args.level);
    let read = |id, buf: &mut [u8]| src.read_tile(id, buf);
    let tiles = dump::LevelTiles {
        level: Some(args.level),
        size: d.size,
        tile: d.tile,
        format: src.desc().format(),
        read: &read,
        file_of,
    };
    match src.heights() {
        Some(h) => {
            let view = dump::HeightView { format: h.format, range: args.range, shade: args.shade };
            dump::finish(dump::dump_heights(file, &tiles, &view, args.region, out), args.json, args.quiet, "cliptex")
        }
        None if args.shade || args.range.is_some() => {
            let flag = if args.shade { "--shade" } else { "--range" };
            eprintln!(
                "cliptex dump: {flag} draws heights, and {} is a colour texture ({}, no `#clipmap height` lines); expected a height texture (docs/ELEVATION.md); drop {flag}",
                file.display(),
                src.desc().format()
            );
            exit::BAD_INPUT
        }
        None => dump::finish(dump::dump(file, &tiles, args.region, out), args.json, args.quiet, "cliptex"),
    }
}

/// What `cliptex plan` takes from a `.ct` or a COG it is given.
struct PlanFrom {
    path: PathBuf,
    size: [u64; 2],
    clip: u64,
    texel_bytes: u64,
    invalid_border: u64,
    heights: bool,
    /// Its georeferencing spans 360 degrees of longitude.
    global: bool,
}

fn check(file: &Path, json: bool, quiet: bool, env: &EnvArgs, tiles: &TilesArgs) -> i32 {
    if let Some(src) = open_pyramid(file, tiles, "cliptex check") {
        return match src {
            Ok(src) => check_pyramid(file, &src, json, quiet),
            Err(c) => c,
        };
    }
    if is_cog(file) {
        return check_cog(file, json, quiet);
    }
    let plan = match load(file, env) {
        Ok((p, _)) => p,
        Err(c) => return c,
    };
    // A configuration naming a COG (`#clipmap cog`): the COG's tiles, as the service reads them.
    if let Some(cog) = &plan.cog {
        if let Some(src) = clipmap::source::cog_of(cog) {
            return check_cog_source(file, &cog.place, &src, json, quiet);
        }
    }
    // A shape the service refuses to start on has no tile to serve: said before any walk (the
    // default tiles are reported in the walk's table).
    if let Some(why) = validate::unservable_shape(&plan) {
        eprintln!("cliptex check: {}: the service cannot serve it: {why}", file.display());
        return exit::BAD_INPUT;
    }
    let bar = tile_bar(check::tile_count(&plan), quiet);
    let report = check::run(&plan, &|n| bar.inc(n));
    bar.finish_and_clear();
    report::emit(json, &report, |r| check::human(r, quiet));
    if report.servable {
        exit::OK
    } else {
        exit::BAD_INPUT
    }
}

fn run(cli: Cli) -> i32 {
    match cli.command {
        Command::Check { file, json, quiet, env, tiles } => check(&file, json, quiet, &env, &tiles),
        Command::Roam(args) => roam(args),
        #[cfg(feature = "remote")]
        Command::Seed(args) => seed::run(args),
        Command::Grow { cmd } => grow::run(cmd),
        Command::Dump(args) => dump(args),
        Command::Attach { name, shm_dir, socket, once, json, interval, view } => {
            let dir = shm_dir.unwrap_or_else(clipmap::shm::default_dir);
            let socket = socket.unwrap_or_else(|| clipmap_service::default_socket(&dir, &name));
            let every = std::time::Duration::from_secs_f64(interval.clamp(0.05, 3600.0));
            let live = !once && !json && std::io::IsTerminal::is_terminal(&std::io::stdout());
            loop {
                match clipmap_tools::inspect::attach::status_of_view(
                    &dir,
                    &name,
                    &view,
                    every.min(std::time::Duration::from_millis(250)).max(if live {
                        every
                    } else {
                        std::time::Duration::ZERO
                    }),
                    &socket,
                ) {
                    Ok(s) => {
                        if json {
                            println!("{}", serde_json::to_string_pretty(&s).expect("status serialises"));
                        } else {
                            if live {
                                print!("\x1b[2J\x1b[H");
                            }
                            print!("{}", clipmap_tools::inspect::attach::human(&s));
                        }
                        if !live || s.closed {
                            return exit::OK;
                        }
                    }
                    Err(e) => {
                        eprintln!("cliptex attach: {e}");
                        return exit::COULD_NOT_RUN;
                    }
                }
            }
        }
        Command::Validate { args, ct_only } => cmdline::validate(&args, FileKind::ClipTexture, "cliptex", ct_only),
        // A tile pyramid (xyz:TEMPLATE, .pmtiles, .mbtiles): the texture it is served as.
        Command::Info { file, json, tiles, .. } if clipmap::source::tiles::is_pyramid(&file.to_string_lossy()) => {
            match open_pyramid(&file, &tiles, "cliptex") {
                Some(Ok(src)) => pyramid_info(&src, json),
                Some(Err(c)) => c,
                None => exit::BAD_INPUT,
            }
        }
        // A tiled GeoTIFF / COG: the texture it is served as (clipmapd's default clip size).
        // A local file that starts like a TIFF, or an http(s):// or s3:// name ending in .tif / .tiff.
        Command::Info { file, json, .. } if is_cog(&file) => match open_cog(&file, "cliptex") {
            Err(c) => c,
            Ok(src) => {
                let info = src.info();
                let levels = info.levels.len() as u32;
                report::emit(json, &locate::CogInfoJson::of(&info, &src), |_| {
                    info.human() + &locate::human(&src, levels)
                });
                exit::OK
            }
        },
        Command::Locate { file, lonlat, texel, level, json, tiles } => {
            if let Some(opened) = open_pyramid(&file, &tiles, "cliptex locate") {
                return match opened {
                    Err(c) => c,
                    Ok(src) => {
                        let g = clipmap::source::TileSource::georef(&src).expect("a pyramid is WebMercatorQuad");
                        locate::locate(&g, src.archive().place(), lonlat.as_deref(), texel.as_deref(), level, json)
                    }
                };
            }
            if !is_cog(&file) {
                eprintln!(
                    "cliptex locate: {}: neither a tiled GeoTIFF / COG nor a tile pyramid (xyz:TEMPLATE, .pmtiles, .mbtiles): only those carry georeferencing (docs/GEOREF.md)",
                    file.display()
                );
                return exit::BAD_INPUT;
            }
            match open_cog(&file, "cliptex locate") {
                Err(c) => c,
                Ok(src) => locate::run(&src, &file, lonlat.as_deref(), texel.as_deref(), level, json),
            }
        }
        Command::Info { file, json, env, ct_only, .. } => match env.load_clip_texture(&file, "cliptex", ct_only) {
            Err(c) => c,
            Ok((p, warnings)) => {
                report::emit(json, &info::clip_texture(&p, &warnings), |_| info::clip_texture_human(&p));
                exit::OK
            }
        },
        Command::Plan {
            file,
            size,
            clip,
            texel_bytes,
            format,
            display,
            fov,
            speed,
            eye_height,
            texel_metres,
            tradeoff,
            invalid_border,
            tile,
            lookahead,
            heights,
            view_spread,
            own_views,
            global,
            table,
            json,
            env,
        } => {
            // From a .ct (read alone: sizing needs no .ic), a GeoTIFF or COG (its size rounded
            // up to powers of two, as a `#clipmap cog` configuration's virt_size), or the options.
            let from_ct = match &file {
                None => None,
                Some(f) if is_cog(f) => match open_cog(f, "cliptex plan") {
                    Ok(src) => Some(PlanFrom {
                        path: f.clone(),
                        size: clipmap::plan::cog::rounded_size(src.desc().size()),
                        clip: COG_CLIP,
                        texel_bytes: src.desc().bytes_per_texel() as u64,
                        invalid_border: 8,
                        heights: src.heights().is_some(),
                        global: clipmap::source::TileSource::georef(&src).is_some_and(|g| g.is_global_in_longitude()),
                    }),
                    Err(code) => return code,
                },
                Some(f) => match env.load_clip_texture(f, "cliptex", true) {
                    Ok((p, _)) => Some(PlanFrom {
                        path: p.path.clone(),
                        size: [p.virt_size[0], p.virt_size[1]],
                        clip: p.clip_size,
                        texel_bytes: p.bytes_per_texel as u64,
                        invalid_border: p.invalid_border,
                        heights: p.height.is_some(),
                        global: p.georef.as_ref().is_some_and(|g| g.is_global_in_longitude()),
                    }),
                    Err(code) => return code,
                },
            };
            let clip = clip.or(from_ct.as_ref().map(|p| p.clip)).unwrap_or(1024);
            let texel_bytes = texel_bytes.or(from_ct.as_ref().map(|p| p.texel_bytes)).unwrap_or(4);
            let invalid_border = invalid_border.or(from_ct.as_ref().map(|p| p.invalid_border)).unwrap_or(8);
            let size = match &from_ct {
                Some(p) => p.size,
                None => size.unwrap_or([0, 0]),
            };
            if table {
                return match report::plan::table(clip, texel_bytes, 10, 26) {
                    Ok((text, rows)) => {
                        report::emit(json, &rows, |_| text);
                        exit::OK
                    }
                    Err(e) => {
                        eprintln!("cliptex plan: {e}");
                        exit::BAD_INPUT
                    }
                };
            }
            let req = report::plan::Request {
                from: from_ct.as_ref().map(|p| p.path.clone()),
                size,
                clip,
                texel_bytes,
                display,
                fov_deg: fov,
                speed,
                eye_height,
                texel_metres,
                tradeoff,
                invalid_border,
                tile,
                lookahead,
                heights: heights || from_ct.as_ref().is_some_and(|p| p.heights),
                view_spread,
                own_views,
                format,
                global: global || from_ct.as_ref().is_some_and(|p| p.global),
            };
            match report::plan::compute(&req) {
                Ok(p) => {
                    report::emit(json, &p, |p| report::plan::human(p, &req));
                    exit::OK
                }
                Err(e) => {
                    eprintln!("cliptex plan: {e}");
                    exit::BAD_INPUT
                }
            }
        }
        Command::Tile { file, level, s, t, json, tiles, .. }
            if clipmap::source::tiles::is_pyramid(&file.to_string_lossy()) =>
        {
            match open_pyramid(&file, &tiles, "cliptex tile") {
                Some(Ok(src)) => pyramid_tile(&src, level, s, t, json),
                Some(Err(c)) => c,
                None => exit::BAD_INPUT,
            }
        }
        Command::Tile { file, level, s, t, json, env, .. } => match load(&file, &env) {
            Err(c) => c,
            Ok((p, _)) => info::print_tile(p.locate(level, s, t), json, "cliptex", &file),
        },
    }
}
