//! `icache`: inspect, validate and locate tiles of Performer image-cache (`.ic`) configurations.
//!
//! Exit status: 0 ok, 1 the input is bad, 2 the tool could not run.

#![forbid(unsafe_code)]

use clap::{Parser, Subcommand};
use clipmap::cli::{self as cmdline, EnvArgs};
use clipmap::config::FileKind;
use clipmap::plan;
use clipmap::report::{self, dump, exit, info};
use clipmap::source::TileId;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "icache",
    version,
    about = "Inspect and validate image-cache (.ic) configurations",
    after_help = "\
Examples:
  icache validate config_examples/ic/*.ic
  icache info level0.ic --json
  icache tile level0.ic --s 3 --t 5 --json
  icache dump level0.ic --region 0,0,1024,1024 --out corner.png

Exit status: 0 ok, 1 the input is bad, 2 the tool could not run."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check standalone .ic files; report every problem with file:line:col.
    #[command(after_help = "\
Examples:
  icache validate config_examples/*.ic
  icache validate --strict --json level0.ic
  icache validate --quiet --env DATA=/mnt/terrain ic/*.ic

Exit status: 0 every file valid, 1 some file invalid, 2 some file could not be read.")]
    Validate(cmdline::ValidateArgs),
    /// Print every value (defaults marked).
    #[command(after_help = "\
Examples:
  icache info config_examples/standalone.ic
  icache info level0.ic --json
  icache info level0.ic --env DATA=/mnt/terrain")]
    Info {
        /// The .ic file.
        file: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        env: EnvArgs,
    },
    /// Write a region of the image cache to PNG, read from its tile files.
    #[command(after_help = "\
One pixel per texel, t upwards (the last row of the region is the top of the picture). 16-bit
formats give 16-bit PNGs of the stored values; others are converted to 8-bit RGB, or RGBA when
they carry alpha. A tile that cannot be read (and is not covered by the default tile) is
painted as magenta and black squares, listed, and the exit status is 1.

Examples:
  icache dump level0.ic --out level0.png
  icache dump level0.ic --region 2048,2048,4096,4096 --out part.png --json

Exit status: 0 written, 1 some tiles could not be read, the .ic is invalid or an option is bad (the
picture is written when the .ic is valid), 2 the tool could not run (unreadable .ic, unwritable output).")]
    Dump {
        /// The .ic file.
        file: PathBuf,
        /// Part of the image: S0,T0,S1,T1 in texels, half-open (default: all of it, if it has at
        /// most 4096x4096 texels).
        #[arg(long, value_name = "S0,T0,S1,T1", value_parser = dump::parse_region)]
        region: Option<[u64; 4]>,
        /// The PNG to write.
        #[arg(long)]
        out: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Print nothing but problems.
        #[arg(long, short)]
        quiet: bool,
        #[command(flatten)]
        env: EnvArgs,
    },
    /// Print where a tile's texels are: file, byte offset, length, stream server.
    #[command(after_help = "\
Examples:
  icache tile config_examples/standalone.ic --s 3 --t 5
  icache tile level0.ic --s 3 --t 5 --json

Exit status: 0 found, 1 no such tile or an invalid .ic, 2 the tool could not run.")]
    Tile {
        /// The .ic file.
        file: PathBuf,
        /// Tile column.
        #[arg(long)]
        s: u64,
        /// Tile row.
        #[arg(long)]
        t: u64,
        /// Tile layer (R), for completeness.
        #[arg(long, default_value_t = 0)]
        r: u64,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        env: EnvArgs,
    },
}

fn main() -> ExitCode {
    exit::status(run(cmdline::parse()))
}

fn load(file: &Path, env: &EnvArgs) -> Result<(plan::ImageCachePlan, Vec<clipmap::config::Diagnostic>), i32> {
    env.load_image_cache(file, "icache")
}

fn dump(file: &Path, region: Option<[u64; 4]>, out: &Path, json: bool, quiet: bool, env: &EnvArgs) -> i32 {
    let plan = match load(file, env) {
        Ok((p, _)) => p,
        Err(c) => return c,
    };
    if plan.size[2] > 1 {
        eprintln!(
            "icache dump: {}: the image cache is {} layers deep (size R); dump reads 2D image caches only (R = 1)",
            file.display(),
            plan.size[2]
        );
        return exit::BAD_INPUT;
    }
    // An image cache naming a COG (`#clipmap cog`): the COG's level, as the service reads it.
    if let Some((src, k)) = plan.cog.as_ref().and_then(|c| Some((clipmap::source::cog_of(c)?, c.level?))) {
        use clipmap::source::TileSource;
        let place = plan.cog.as_ref().map(|c| c.place.clone());
        let d = *src.desc().level(k);
        let read = |id: TileId, buf: &mut [u8]| src.read_tile(TileId::new(k, id.s, id.t), buf);
        let file_of = |_: TileId| place.clone();
        let level = dump::LevelTiles {
            level: None,
            size: d.size,
            tile: d.tile,
            format: src.desc().format(),
            read: &read,
            file_of: &file_of,
        };
        return dump::finish(dump::dump(file, &level, region, out), json, quiet, "icache");
    }
    let (tiles, note) = dump::IcacheTiles::new(&plan);
    if let Some(note) = note {
        eprintln!("icache dump: {note}");
    }
    let read = |id, buf: &mut [u8]| tiles.read(id, buf);
    let file_of = |id: TileId| plan.locate(id.s, id.t, 0).ok().map(|l| l.path);
    let level = dump::LevelTiles {
        level: None,
        size: [plan.size[0], plan.size[1]],
        tile: [plan.tile_size[0], plan.tile_size[1]],
        format: plan.texel,
        read: &read,
        file_of: &file_of,
    };
    dump::finish(dump::dump(file, &level, region, out), json, quiet, "icache")
}

fn run(cli: Cli) -> i32 {
    match cli.command {
        Command::Validate(args) => cmdline::validate(&args, FileKind::ImageCache, "icache", false),
        Command::Dump { file, region, out, json, quiet, env } => dump(&file, region, &out, json, quiet, &env),
        Command::Info { file, json, env } => match load(&file, &env) {
            Err(c) => c,
            Ok((p, warnings)) => {
                report::emit(json, &info::image_cache(&p, &warnings), |_| info::image_cache_human(&p));
                exit::OK
            }
        },
        Command::Tile { file, s, t, r, json, env } => match load(&file, &env) {
            Err(c) => c,
            Ok((p, _)) => info::print_tile(p.locate(s, t, r), json, "icache", &file),
        },
    }
}
