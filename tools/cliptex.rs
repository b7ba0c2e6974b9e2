//! `cliptex`: inspect, validate and locate data of Performer clip-texture (`.ct`) configurations.
//!
//! Exit status: 0 ok, 1 the input is bad, 2 the tool could not run.

use clap::{Parser, Subcommand};
use clipmap::config::FileKind;
use clipmap::plan;
use clipmap::report::{self, check, exit, info, validate, EnvArgs};
use clipmap::roam;
use clipmap::source::FileSource;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

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

Exit status: 0 ok, 1 the input is bad, 2 the tool could not run."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check .ct files (and every .ic they name); report every problem with file:line:col.
    Validate(validate::ValidateArgs),
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
    Info {
        /// The .ct file.
        file: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        env: EnvArgs,
    },
    /// Size a deployment: clipmap memory against the full mipmap, update bandwidth, clip size for a display.
    #[command(after_help = "\
Examples:
  cliptex plan --size 67108864 --clip 2048 --texel-bytes 4
  cliptex plan --size 65536 --clip 1024 --texel-bytes 3 --display 1920 --speed 2000 --json
  cliptex plan --size 67108864 --clip 2048 --texel-bytes 4 --display 1920 --eye-height 3000
  cliptex plan --table --clip 2048 --texel-bytes 4")]
    Plan {
        /// Texture size in texels a side (a power of two).
        #[arg(long, required_unless_present = "table")]
        size: Option<u64>,
        /// Clip size (a power of two).
        #[arg(long, default_value_t = 1024)]
        clip: u64,
        /// Bytes per texel (e.g. 3 for RGB8, 4 for RGBA8, 2 for RGB565).
        #[arg(long, default_value_t = 4)]
        texel_bytes: u64,
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
        /// Invalid border (with --eye-height).
        #[arg(long, default_value_t = 8)]
        invalid_border: u64,
        /// Print memory for texture sizes 2^10 to 2^26 at once.
        #[arg(long)]
        table: bool,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Print where a tile's texels are: file, byte offset, length, stream server.
    Tile {
        /// The .ct file.
        file: PathBuf,
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

Examples:
  cliptex roam --source hash --size 65536 --clip 1024 --flight straight:16 --frames 50 --wait-for-reads
  cliptex roam config_examples/prepared/hash256.ct --flight straight:4:45 --frames 20 --json
  cliptex roam --source terrain --size 1048576 --clip 2048 --flight zigzag:64:20 --frames 200 --budget-ms inf")]
    Roam(RoamArgs),
    /// Write a level region to PNG from the tile files, or every level of a running service.
    #[command(after_help = "\
From disk, one level (or a part of it) becomes one PNG, one pixel per texel, t upwards (the
last row of the region is the top of the picture). Formats are converted to 8-bit RGB, or RGBA
when they carry alpha. A tile that cannot be read is painted as magenta and black squares,
listed, and the exit status is 1.

From a running service (--attach NAME --out-dir DIR): DIR/level-NN.png shows each level's window
(yellow outline), its valid region (red outline) and the invalid border (dark checkerboard);
DIR/view.png is the view around the centre as a renderer would texture it and DIR/rings.png the
same view coloured by the level each pixel uses.

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
Exit status: 0 every tile can be served (present, or covered by a default tile), 1 some cannot
or the configuration is invalid, 2 the configuration cannot be read.")]
    Check {
        /// The .ct file.
        file: PathBuf,
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
    /// The .ct file whose tiles are read (or use --attach).
    #[arg(required_unless_present = "attach", conflicts_with = "attach", requires = "out")]
    config: Option<PathBuf>,
    /// Level to dump (0 is the finest).
    #[arg(long, default_value_t = 0)]
    level: u32,
    /// Part of the level: S0,T0,S1,T1 in level texels, half-open (default: the whole level, if
    /// it has at most 4096x4096 texels).
    #[arg(long, value_name = "S0,T0,S1,T1")]
    region: Option<String>,
    /// The PNG to write (with a .ct file).
    #[arg(long)]
    out: Option<PathBuf>,
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
}

#[derive(clap::Args)]
struct RoamArgs {
    /// The .ct file whose tiles are read (or use --source).
    #[arg(required_unless_present = "source", conflicts_with = "source")]
    config: Option<PathBuf>,
    /// A procedural texture instead of a configuration (4-byte texels).
    #[arg(long, value_enum, requires_all = ["size", "clip"])]
    source: Option<ProceduralArg>,
    /// Procedural texture size in texels a side.
    #[arg(long)]
    size: Option<u64>,
    /// Procedural clip size.
    #[arg(long)]
    clip: Option<u64>,
    /// Procedural tile size in texels a side.
    #[arg(long, default_value_t = 256)]
    tile: u64,
    /// Invalid border in texels (default: the configuration's, 0 for a procedural texture).
    #[arg(long)]
    border: Option<u64>,
    /// The flight: straight:SPEED[:ANGLE], circle:RADIUS:SPEED, zigzag:SPEED:PERIOD, hover, jump:EVERY:DIST.
    #[arg(long)]
    flight: String,
    /// Frames to fly.
    #[arg(long)]
    frames: u64,
    /// Copy budget per frame in milliseconds (`inf`: no limit).
    #[arg(long, default_value_t = 6.0)]
    budget_ms: f64,
    /// Wait for every read between frames (an ideally fast disk): the report is deterministic.
    #[arg(long)]
    wait_for_reads: bool,
    /// Align each level's centre down to a multiple of this many level texels (1: texel-exact;
    /// Performer's InfiniteReality used 8). Copies column strips wider and less often, at the
    /// cost of up to ALIGNMENT - 1 texels of each level on the side the view moves towards.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=clipmap::clip::MAX_CENTRE_ALIGNMENT))]
    centre_alignment: u64,
    /// Print JSON instead of the per-frame table.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    env: EnvArgs,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum ProceduralArg {
    Hash,
    Terrain,
}

fn main() -> ExitCode {
    let cli: Cli = exit::parse();
    ExitCode::from(run(cli) as u8)
}

fn opts(env: &EnvArgs) -> Result<plan::Options, i32> {
    env.options().map_err(|e| {
        eprintln!("cliptex: {e}");
        exit::BAD_INPUT
    })
}

fn load(file: &Path, env: &EnvArgs) -> Result<(plan::ClipTexturePlan, Vec<clipmap::config::Diagnostic>), i32> {
    let o = opts(env)?;
    let loaded = plan::load_clip_texture(file, &o).map_err(|e| {
        eprintln!("cliptex: {e}");
        exit::COULD_NOT_RUN
    })?;
    let rendered = loaded.render_from(clipmap::config::Severity::Warning);
    match loaded.plan {
        Some(p) => {
            eprint!("{rendered}");
            Ok((p, info::non_errors(&loaded.diagnostics.items)))
        }
        None => {
            eprint!("{rendered}");
            eprintln!("cliptex: {} is not a valid clip texture configuration (see above)", file.display());
            Err(exit::BAD_INPUT)
        }
    }
}

fn roam(args: RoamArgs) -> i32 {
    let flight: roam::Flight = match args.flight.parse() {
        Ok(f) => f,
        Err(e) => {
            eprintln!("cliptex roam: --flight {e}");
            return exit::BAD_INPUT;
        }
    };
    if !(clipmap::limits::MIN_BUDGET_MS..).contains(&args.budget_ms) {
        eprintln!(
            "cliptex roam: --budget-ms {}: expected a number of milliseconds of at least {} (MIN_BUDGET_MS; less rounds to no work), or inf",
            args.budget_ms,
            clipmap::limits::MIN_BUDGET_MS
        );
        return exit::BAD_INPUT;
    }
    let options = match (&args.config, args.source) {
        (Some(file), _) => {
            let plan = match load(file, &args.env) {
                Ok((p, _)) => p,
                Err(c) => return c,
            };
            match FileSource::new(plan, &clipmap::limits::Limits::default()) {
                Ok(src) => roam::RoamOptions::over(Arc::new(src), flight, args.frames),
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
    let mut settings = options.settings;
    settings.centre_alignment = args.centre_alignment;
    let options = roam::RoamOptions {
        settings,
        budget_ms: args.budget_ms.is_finite().then_some(args.budget_ms),
        wait_for_reads: args.wait_for_reads,
        invalid_border: args.border,
        ..options
    };
    match roam::run(options) {
        Ok(report) => {
            if args.json {
                println!("{}", serde_json::to_string_pretty(&report).expect("report serialises"));
            } else {
                print!("{}", roam::human(&report));
            }
            exit::OK
        }
        Err(e) => {
            eprintln!("cliptex roam: {e}");
            e.exit_code()
        }
    }
}

fn dump(args: DumpArgs) -> i32 {
    use report::{dump, live_dump};
    if let Some(name) = &args.attach {
        let dir = args.shm_dir.clone().unwrap_or_else(clipmap::shm::default_dir);
        let out = args.out_dir.clone().unwrap_or_default();
        return match live_dump::dump(&dir, name, &out) {
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
    let region = match args.region.as_deref().map(dump::parse_region).transpose() {
        Ok(r) => r,
        Err(e) => return dump::finish(Err(e), args.json, args.quiet, "cliptex"),
    };
    let plan = match load(file, &args.env) {
        Ok((p, _)) => p,
        Err(c) => return c,
    };
    let count = plan.levels.len() as u32;
    if args.level >= count {
        let e = dump::DumpError::NoLevel { level: args.level, last: count.saturating_sub(1) };
        return dump::finish(Err(e), args.json, args.quiet, "cliptex");
    }
    let src = match FileSource::new(plan, &clipmap::limits::Limits::default()) {
        Ok(src) => src,
        Err(e) => {
            eprintln!("cliptex dump: {e}");
            return exit::BAD_INPUT;
        }
    };
    use clipmap::source::TileSource;
    let d = src.desc().level(args.level);
    let read = |id, buf: &mut [u8]| src.read_tile(id, buf);
    let file_of = |id: clipmap::source::TileId| src.plan().locate(id.level, id.s, id.t).ok().map(|l| l.path);
    let tiles = dump::LevelTiles {
        level: Some(args.level),
        size: d.size,
        tile: d.tile,
        format: src.desc().format(),
        read: &read,
        file_of: &file_of,
    };
    dump::finish(dump::dump(file, &tiles, region, out), args.json, args.quiet, "cliptex")
}

fn check(file: &Path, json: bool, quiet: bool, env: &EnvArgs) -> i32 {
    use std::io::IsTerminal;
    let plan = match load(file, env) {
        Ok((p, _)) => p,
        Err(c) => return c,
    };
    // A shape the service refuses to start on has no tile to serve: said before any walk (the
    // default tiles are reported in the walk's table).
    if let Some(why) = validate::unservable_shape(&plan) {
        eprintln!("cliptex check: {}: the service cannot serve it: {why}", file.display());
        return exit::BAD_INPUT;
    }
    let bar = if !quiet && std::io::stderr().is_terminal() {
        let bar = indicatif::ProgressBar::new(check::tile_count(&plan));
        if let Ok(style) = indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} tiles {eta}") {
            bar.set_style(style);
        }
        bar
    } else {
        indicatif::ProgressBar::hidden()
    };
    let report = check::run(&plan, &|n| bar.inc(n));
    bar.finish_and_clear();
    if json {
        println!("{}", serde_json::to_string_pretty(&report).expect("report serialises"));
    } else {
        print!("{}", check::human(&report, quiet));
    }
    if report.servable {
        exit::OK
    } else {
        exit::BAD_INPUT
    }
}

fn run(cli: Cli) -> i32 {
    match cli.command {
        Command::Check { file, json, quiet, env } => check(&file, json, quiet, &env),
        Command::Roam(args) => roam(args),
        Command::Dump(args) => dump(args),
        Command::Attach { name, shm_dir, socket, once, json, interval } => {
            let dir = shm_dir.unwrap_or_else(clipmap::shm::default_dir);
            let socket = socket.unwrap_or_else(|| clipmap::service::default_socket(&dir, &name));
            let every = std::time::Duration::from_secs_f64(interval.clamp(0.05, 3600.0));
            let live = !once && !json && std::io::IsTerminal::is_terminal(&std::io::stdout());
            loop {
                match report::attach::status(
                    &dir,
                    &name,
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
                            print!("{}", report::attach::human(&s));
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
        Command::Validate(args) => validate::cli(&args, FileKind::ClipTexture, "cliptex"),
        Command::Info { file, json, env } => match load(&file, &env) {
            Err(c) => c,
            Ok((p, warnings)) => {
                if json {
                    println!(
                        "{}",
                        serde_json::to_string_pretty(&info::clip_texture(&p, &warnings)).expect("info serialises")
                    );
                } else {
                    print!("{}", info::clip_texture_human(&p));
                }
                exit::OK
            }
        },
        Command::Plan {
            size,
            clip,
            texel_bytes,
            display,
            fov,
            speed,
            eye_height,
            texel_metres,
            tradeoff,
            invalid_border,
            table,
            json,
        } => {
            if table {
                return match report::plan::table(clip, texel_bytes, 10, 26) {
                    Ok((text, rows)) => {
                        if json {
                            println!("{}", serde_json::to_string_pretty(&rows).expect("rows serialise"));
                        } else {
                            print!("{text}");
                        }
                        exit::OK
                    }
                    Err(e) => {
                        eprintln!("cliptex plan: {e}");
                        exit::BAD_INPUT
                    }
                };
            }
            let req = report::plan::Request {
                size: size.unwrap_or(0),
                clip,
                texel_bytes,
                display,
                fov_deg: fov,
                speed,
                eye_height,
                texel_metres,
                tradeoff,
                invalid_border,
            };
            match report::plan::compute(&req) {
                Ok(p) => {
                    if json {
                        println!("{}", serde_json::to_string_pretty(&p).expect("plan serialises"));
                    } else {
                        print!("{}", report::plan::human(&p, &req));
                    }
                    exit::OK
                }
                Err(e) => {
                    eprintln!("cliptex plan: {e}");
                    exit::BAD_INPUT
                }
            }
        }
        Command::Tile { file, level, s, t, json, env } => match load(&file, &env) {
            Err(c) => c,
            Ok((p, _)) => info::print_tile(p.locate(level, s, t), json, "cliptex", &file),
        },
    }
}
