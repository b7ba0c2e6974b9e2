//! `clipbench`: measured studies of the clipmap, run on demand (not part of the test suite).
//!
//! `clipbench accuracy` sweeps clip size, invalid border, disk speed (tiles a frame), flight speed and shape,
//! renders every frame from the full mipmap and from the clipmap, measures the vertical error of
//! height textures (two surfaces, the `mean` and `point` level rules) against disk speed, and
//! writes the tables, CSV, plots and `ACCURACY.md` where `--out` says (the repository's `docs/` only when asked for
//! with `--out docs`; by default a directory under the system's temporary directory).
//!
//! `clipbench engine` measures update throughput against memcpy, bytes per tick against the
//! strips a move uncovers, and resident memory against the clipmap formula.
//!
//! `clipbench perf` runs every performance comparison in one go (engine against memcpy, tile
//! ingest against plain reads, per-frame cost against GDAL and against full reloads, memory
//! against the formula, a 2^26 flight in real time, service latency) and prints ratios.
//!
//! `clipbench policies` flies the standard flights under every combination of prefetch policy
//! (ring, direction) and second-level pool eviction (none, LRU, shift) over a simulated disk
//! and a pool budget that forces eviction, and prints tiles read, hit rate, peak resident bytes,
//! ticks with a disabled level and mean min LOD for each.
//!
//! `clipbench views` flies several views of one clipmap (near each other, far apart, weighted
//! over a slow disk) against one view alone and against separate clipmaps, and prints tiles read,
//! peak resident bytes, settle ticks and min LOD with their ratios and the goals met.
//!
//! `clipbench growing` streams 4000 x 3000 patches into a growing texture and reports tile
//! rebuilds per second for 256² and 512² tiles beside the decode rate of the same patches.
//!
//! Exit status: 0 ok, 1 bad input, 2 the tool could not run.

#![forbid(unsafe_code)]

mod cog;
#[cfg(feature = "remote")]
mod cog_http;
mod cog_shared;
mod engine;
mod formats;
mod formats_flight;
mod growing;
mod perf;
mod policies;
#[cfg(feature = "remote")]
mod remote;
#[cfg(feature = "remote")]
mod serve;
#[cfg(feature = "remote")]
mod tiles;
/// Where a tile's CPU goes in `clipbench tiles`.
#[cfg(feature = "remote")]
mod tiles_cpu;
#[cfg(feature = "remote")]
mod tiles_flight;
#[cfg(feature = "remote")]
mod tiles_peers;
#[cfg(feature = "remote")]
mod tiles_planet;
mod views;

use clap::{Parser, Subcommand};
use clipmap::accuracy::sweep;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "clipbench",
    version,
    about = "Measured studies of the clipmap: accuracy against speed, performance",
    after_help = "\
Examples:
  clipbench perf --quick --json
  clipbench ingest --json
  clipbench policies --quick --json
  clipbench growing --quick --json
  clipbench views --quick --json
  clipbench remote --quick --json
  clipbench cog --quick --json
  clipbench formats --quick --json
  clipbench tiles --quick --json
  clipbench engine --quick
  clipbench accuracy --quick --out study

Reports go where --out says (or to standard output); nothing is written into the repository
unless asked for (`clipbench accuracy --out docs`).

Exit status: 0 ok, 1 the input is bad, 2 the tool could not run."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Update throughput against memcpy, bytes per tick against the strips, resident memory.
    #[command(after_help = "\
Examples:
  clipbench engine --quick
  clipbench engine --runs 7 --json
  clipbench engine --centre-alignment 8")]
    Engine {
        /// A small texture (2^20, clip 512) for a fast check.
        #[arg(long)]
        quick: bool,
        /// Runs per measurement (the median is reported).
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// A tiny texture (2^12, clip 128): checks that the benchmark runs (for tests).
        #[arg(long, hide = true, conflicts_with = "quick")]
        smoke: bool,
        /// Align each level's centre to multiples of this many level texels (1: texel-exact, the
        /// engine's default; Performer's InfiniteReality used 8).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=clipmap::clip::MAX_CENTRE_ALIGNMENT))]
        centre_alignment: u64,
        /// The texture's size, 2^N texels a side (clip, tiles and flights unchanged): `clipbench
        /// perf` flies the same flights at 2^30 beside its own size's.
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(12..=30))]
        size_log2: Option<u32>,
    },
    /// Every performance comparison in one run: engine against memcpy, tile ingest against plain
    /// reads, per-frame cost against GDAL and full reloads, memory against the formula, a 2^26
    /// flight in real time, service latency.
    #[command(after_help = "\
Examples:
  clipbench perf --quick --json
  clipbench perf --runs 7 --dir /var/tmp")]
    Perf(perf::Args),
    /// Tile ingest alone: tiles per second through the engine's tile path against plain reads
    /// of the same files (the `ingest` part of `clipbench perf`, with the same sizes).
    #[command(after_help = "\
Examples:
  clipbench ingest --json
  clipbench ingest --quick --runs 9")]
    Ingest(perf::IngestArgs),
    /// Paging policies side by side: ring or direction-aware prefetch, LRU or shift eviction
    /// of a second-level tile pool, on the standard flights over a simulated disk.
    #[command(after_help = "\
Examples:
  clipbench policies --quick --json
  clipbench policies                     # the table in docs/BENCHMARKS.md
  clipbench policies --prefetch direction --eviction none,shift --max-centre-step 32

Deterministic: a simulated disk of a few tiles a tick, reads in lock step with the ticks.")]
    Policies(policies::Args),
    /// Growing textures: tile rebuilds per second while 4000x3000 patches stream in, for 256²
    /// and 512² tiles, beside the decode rate of the same patches.
    #[command(after_help = "\
Examples:
  clipbench growing --quick --json
  clipbench growing                      # the figures in docs/BENCHMARKS.md

Prints tiles_per_s_256, tiles_per_s_512 and ingest_mb_per_s (texel MB/s through decode and
rebuild), each run's tiles and seconds, and the flexible-clipmap paper's figures beside them.")]
    Growing(growing::Args),
    /// Several views of one clipmap: near each other, far apart, weighted over a slow disk,
    /// against one view alone and against separate clipmaps (one per view).
    #[command(after_help = "\
Examples:
  clipbench views --quick --json
  clipbench views                        # the figures in docs/BENCHMARKS.md

Deterministic: simulated disks, reads in lock step with the ticks. Prints, per scenario and
design, tiles read, peak resident bytes, settle ticks and mean min LOD per view, their ratios
against one view alone, and which goals are met.")]
    Views(views::Args),
    /// Tiles per second from local files, loopback HTTP (nginx) and loopback S3 (moto) in one
    /// run, and the requests in flight that hide an added latency per request.
    #[cfg(feature = "remote")]
    #[command(after_help = "\
Examples:
  clipbench remote --quick --json
  clipbench remote --depth 32 --latency-ms 50

Needs nginx (apt-get install nginx) and moto (pip install 'moto[server]'); starts both on
loopback ports and stops them at the end. Exit status: 0 ok, 1 a wrong texel was read, 2 the
benchmark could not run.")]
    Remote(remote::Args),
    /// A Cloud-Optimized GeoTIFF served as it is, against GDAL reading the same tiles.
    #[command(after_help = "\
Examples:
  clipbench cog --quick --json
  clipbench cog --install-peers --passes 9
  clipbench cog --quick --link-rate 100

Needs GDAL (gdal_translate and Python's osgeo.gdal; --install-peers runs apt-get). Writes a COG
with GDAL, reads every level-0 tile with both, and compares the texels. Exit status: 0 ok, 1 a
texel differs from GDAL's decode, 2 the benchmark could not run.")]
    Cog(cog::Args),
    /// Texel formats (rgba8, bc7, bc1, bc4, bc5) on a photograph: PSNR, bytes, encoding and ingest.
    #[command(after_help = "\
Examples:
  clipbench formats --quick --json
  clipbench formats --image photo.jpg

The photograph: --image, else matplotlib's grace_hopper.jpg (apt-get install
python-matplotlib-data, or pip install matplotlib); without it, the procedural terrain, said so.")]
    Formats(formats::Args),
    /// A tile service and tile archives served as they are (XYZ over HTTP, PMTiles over HTTP
    /// and from disk, MBTiles) against GDAL reading the same tiles and curl fetching them, and
    /// a real-time flight over the XYZ service with latency added to every request.
    #[cfg(feature = "remote")]
    #[command(after_help = "\
Examples:
  clipbench tiles --quick --json
  clipbench tiles --passes 9
  clipbench tiles --link-rate 100

Needs GDAL (gdal2tiles.py and Python's osgeo.gdal), Python's pmtiles package (the reference
PMTiles writer), nginx and curl; makes its own tiles with no network, starts nginx on a loopback
port and stops it at the end. Exit status: 0 ok, 1 a texel read differs from GDAL's decode of
its tile, 2 the benchmark could not run.")]
    Tiles(tiles::Args),
    /// Speed against accuracy: sweep the knobs, render each frame twice, measure the difference.
    #[command(after_help = "\
Examples:
  clipbench accuracy --quick                       # writes under $TMPDIR/clipbench-accuracy
  clipbench accuracy --quick --out study --json > rows.json
  clipbench accuracy --out docs                    # refreshes the repository's docs/ACCURACY.md")]
    Accuracy {
        /// A small sweep at 192x144 pixels that finishes in about a minute.
        #[arg(long)]
        quick: bool,
        /// Directory for ACCURACY.md and accuracy/ (CSV, SVG plots, sample frames), created if
        /// needed [default: clipbench-accuracy under the system's temporary directory]. The
        /// repository's committed report is refreshed only with an explicit `--out docs`.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print the rows as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// No progress on stderr.
        #[arg(long, short)]
        quiet: bool,
        /// Texel format of the studied texture; 16-bit formats are compared at 16 bits a channel
        /// (PSNR against 65535).
        #[arg(long, value_enum, default_value = "rgba8")]
        format: StudyFormat,
    },
}

fn main() -> ExitCode {
    let cli: Cli = clipmap::cli::parse();
    let code = match cli.command {
        Command::Accuracy { quick, out, json, quiet, format } => accuracy(
            quick,
            out.unwrap_or_else(|| std::env::temp_dir().join("clipbench-accuracy")),
            json,
            quiet,
            format.texel(),
        ),
        Command::Perf(args) => perf::main(args),
        Command::Ingest(args) => perf::ingest_main(args),
        Command::Policies(args) => policies::main(args),
        Command::Growing(args) => growing::main(args),
        Command::Views(args) => views::main(args),
        #[cfg(feature = "remote")]
        Command::Remote(args) => remote::main(args),
        Command::Cog(args) => cog::main(args),
        Command::Formats(args) => formats::main(args),
        #[cfg(feature = "remote")]
        Command::Tiles(args) => tiles::main(args),
        Command::Engine { quick, runs, json, smoke, centre_alignment, size_log2 } => {
            match engine::engine(engine_size(quick, smoke), runs, centre_alignment, size_log2) {
                Ok(r) => {
                    clipmap::report::emit(json, &r, engine::human);
                    0
                }
                Err(e) => {
                    eprintln!("clipbench engine: {e:#}");
                    2
                }
            }
        }
    };
    clipmap::report::exit::status(code as i32)
}

fn engine_size(quick: bool, smoke: bool) -> engine::Size {
    if smoke {
        engine::Size::Smoke
    } else if quick {
        engine::Size::Quick
    } else {
        engine::Size::Full
    }
}

/// The formats `clipbench accuracy --format` studies.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum StudyFormat {
    Rgba8,
    L16,
    Rgb16,
    Rgba16,
}

impl StudyFormat {
    fn texel(self) -> clipmap::texel::TexelFormat {
        use clipmap::texel::TexelFormat as F;
        match self {
            StudyFormat::Rgba8 => F::RGBA8,
            StudyFormat::L16 => F::L16,
            StudyFormat::Rgb16 => F::RGB16,
            StudyFormat::Rgba16 => F::RGBA16,
        }
    }
}

fn accuracy(quick: bool, out: PathBuf, json: bool, quiet: bool, format: clipmap::texel::TexelFormat) -> u8 {
    let started = std::time::Instant::now();
    let show = !quiet && (std::io::stderr().is_terminal() || !json);
    let rows = match sweep::run(quick, format, |i, n, r| {
        if show {
            eprintln!(
                "[{i}/{n}] clip {} border {} disk {} speed {} {}: PSNR min {}, {:.2}% coarser",
                r.clip_size,
                r.invalid_border,
                r.disk_tiles.map(|b| format!("{b} tiles/frame")).unwrap_or_else(|| "ideal".into()),
                r.speed,
                r.flight,
                r.summary.psnr_min.map(|p| format!("{p:.1} dB")).unwrap_or_else(|| "inf".into()),
                r.summary.coarser_pixel_share * 100.0
            );
        }
    }) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("clipbench accuracy: {e}");
            return 1;
        }
    };
    let heights = match clipmap::accuracy::heights::sweep(quick, |i, n, r| {
        if show {
            eprintln!(
                "[heights {i}/{n}] {} {} disk {} speed {}: mean {:.4} m, p99 {:.4} m, max {:.4} m, {:.2}% coarser",
                r.surface,
                r.rule,
                r.disk_tiles.map(|b| format!("{b} tiles/frame")).unwrap_or_else(|| "ideal".into()),
                r.speed,
                r.mean_m,
                r.p99_m,
                r.max_m,
                r.coarser_pixel_share * 100.0
            );
        }
    }) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("clipbench accuracy: heights: {e}");
            return 2;
        }
    };
    let fmt = if format == clipmap::texel::TexelFormat::RGBA8 {
        String::new()
    } else {
        format!(" --format {}", format.short_name())
    };
    let command = format!("clipbench accuracy{}{fmt} --out {}", if quick { " --quick" } else { "" }, out.display());
    let dir = out.join("accuracy");
    if let Err(e) = std::fs::create_dir_all(&dir)
        .map_err(|e| e.to_string())
        .and_then(|_| sweep::write_samples(&dir, quick).map_err(|e| e.to_string()))
    {
        eprintln!("clipbench accuracy: sample frames: {e}");
        return 2;
    }
    match sweep::write_outputs(&rows, &dir, quick, &command)
        .and_then(|report| clipmap::accuracy::heights::write_outputs(&heights, &dir).map(|()| report))
    {
        Ok(report) => {
            let path = out.join("ACCURACY.md");
            let mut text = format!(
                "{report}\n{}\n{}\n{}",
                sweep::CONCLUSIONS,
                clipmap::accuracy::heights::report(&heights, quick, &command),
                clipmap::accuracy::heights::CONCLUSIONS
            );
            // The texel format axis' section holds `clipbench formats`' figures: kept as it is.
            let old = std::fs::read_to_string(&path).unwrap_or_default();
            if let Some(kept) = clipmap::accuracy::formats::kept_section(&old) {
                text = format!("{}\n{kept}", text.trim_end());
            }
            if let Err(e) = sweep::write_whole(&path, text) {
                eprintln!("clipbench accuracy: cannot write {}: {e}", path.display());
                return 2;
            }
            if !quiet {
                eprintln!("wrote {} and {} ({:.1} s)", path.display(), dir.display(), started.elapsed().as_secs_f64());
            }
        }
        Err(e) => {
            eprintln!("clipbench accuracy: cannot write {}: {e}", dir.display());
            return 2;
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows).expect("rows serialise"));
    }
    0
}

/// Runs a benchmark that checks texels in a fresh scratch directory under `base` (the system's
/// temporary directory by default), removed at the end, and prints its report (JSON or text).
/// The exit status: 0 ok, 1 `wrong` says a texel read was wrong, 2 it could not run.
pub(crate) fn run_in_scratch<R: serde::Serialize>(
    tool: &str,
    base: Option<&std::path::Path>,
    json: bool,
    measure: impl FnOnce(&std::path::Path) -> anyhow::Result<R>,
    human: impl FnOnce(&R) -> String,
    wrong: impl FnOnce(&R) -> bool,
) -> u8 {
    let base = base.map_or_else(std::env::temp_dir, |b| b.to_path_buf());
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    let dir = base.join(format!("clipbench-{tool}-{}-{nanos}", std::process::id()));
    if let Err(e) = std::fs::create_dir_all(&dir) {
        eprintln!("clipbench {tool}: cannot make {}: {e}", dir.display());
        return 2;
    }
    let result = measure(&dir);
    let _ = std::fs::remove_dir_all(&dir);
    match result {
        Ok(r) => {
            let bad = wrong(&r);
            clipmap::report::emit(json, &r, human);
            u8::from(bad)
        }
        Err(e) => {
            eprintln!("clipbench {tool}: {e:#}");
            2
        }
    }
}
