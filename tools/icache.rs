//! `icache`: inspect, validate and locate tiles of Performer image-cache (`.ic`) configurations.
//!
//! Exit status: 0 ok, 1 the input is bad, 2 the tool could not run.

use clap::{Parser, Subcommand};
use clipmap::config::FileKind;
use clipmap::plan;
use clipmap::report::{exit, info, validate, EnvArgs};
use std::path::PathBuf;
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

Exit status: 0 ok, 1 the input is bad, 2 the tool could not run."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check standalone .ic files; report every problem with file:line:col.
    Validate(validate::ValidateArgs),
    /// Print every value (defaults marked).
    Info {
        /// The .ic file.
        file: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        env: EnvArgs,
    },
    /// Print where a tile's texels are: file, byte offset, length, stream server.
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
    ExitCode::from(run(Cli::parse()) as u8)
}

fn opts(env: &EnvArgs) -> Result<plan::Options, i32> {
    env.options().map_err(|e| {
        eprintln!("icache: {e}");
        exit::COULD_NOT_RUN
    })
}

fn load(file: &PathBuf, env: &EnvArgs) -> Result<(plan::ImageCachePlan, Vec<clipmap::config::Diagnostic>), i32> {
    let o = opts(env)?;
    let loaded = plan::load_image_cache(file, &o).map_err(|e| {
        eprintln!("icache: {e}");
        exit::COULD_NOT_RUN
    })?;
    eprint!("{}", loaded.render_from(clipmap::config::Severity::Warning));
    match loaded.plan {
        Some(p) => Ok((p, info::non_errors(&loaded.diagnostics.items))),
        None => {
            eprintln!("icache: {} is not a valid image cache configuration (see above)", file.display());
            Err(exit::BAD_INPUT)
        }
    }
}

fn run(cli: Cli) -> i32 {
    match cli.command {
        Command::Validate(args) => validate::cli(&args, FileKind::ImageCache, "icache"),
        Command::Info { file, json, env } => match load(&file, &env) {
            Err(c) => c,
            Ok((p, warnings)) => {
                if json {
                    println!(
                        "{}",
                        serde_json::to_string_pretty(&info::image_cache(&p, &warnings)).expect("info serialises")
                    );
                } else {
                    print!("{}", info::image_cache_human(&p));
                }
                exit::OK
            }
        },
        Command::Tile { file, s, t, r, json, env } => match load(&file, &env) {
            Err(c) => c,
            Ok((p, _)) => info::print_tile(p.locate(s, t, r), json, "icache", &file),
        },
    }
}
