//! `cliptex`: inspect, validate and locate data of Performer clip-texture (`.ct`) configurations.
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
    name = "cliptex",
    version,
    about = "Inspect and validate clip-texture (.ct) configurations",
    after_help = "\
Examples:
  cliptex validate config_examples/*.ct
  cliptex validate --strict --json my.ct
  cliptex info config_examples/v2_format_params.ct
  cliptex tile my.ct --level 0 --s 3 --t 5 --json
  cliptex info my.ct --env DATA=/mnt/terrain

Exit status: 0 ok, 1 the input is bad, 2 the tool could not run."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check .ct files (and every .ic they name); report every problem with file:line:col.
    Validate {
        /// The .ct files.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Also fail on warnings and on anything Performer 3.0 would not read as intended.
        #[arg(long)]
        strict: bool,
        /// Print a JSON report instead of text.
        #[arg(long)]
        json: bool,
        /// Print only the invalid files.
        #[arg(long, short)]
        quiet: bool,
        #[command(flatten)]
        env: EnvArgs,
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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    ExitCode::from(run(cli) as u8)
}

fn opts(env: &EnvArgs) -> Result<plan::Options, i32> {
    env.options().map_err(|e| {
        eprintln!("cliptex: {e}");
        exit::COULD_NOT_RUN
    })
}

fn load(
    file: &PathBuf,
    env: &EnvArgs,
) -> Result<(plan::ClipTexturePlan, Vec<clipmap::config::Diagnostic>), i32> {
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
            eprintln!(
                "cliptex: {} is not a valid clip texture configuration (see above)",
                file.display()
            );
            Err(exit::BAD_INPUT)
        }
    }
}

fn run(cli: Cli) -> i32 {
    match cli.command {
        Command::Validate {
            files,
            strict,
            json,
            quiet,
            env,
        } => {
            let o = match opts(&env) {
                Ok(o) => o,
                Err(c) => return c,
            };
            let r = validate::run(&files, FileKind::ClipTexture, strict, &o);
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&r).expect("report serialises")
                );
            } else {
                print!("{}", r.human(quiet));
            }
            r.exit_code()
        }
        Command::Info { file, json, env } => match load(&file, &env) {
            Err(c) => c,
            Ok((p, warnings)) => {
                if json {
                    println!(
                        "{}",
                        serde_json::to_string_pretty(&info::clip_texture(&p, &warnings))
                            .expect("info serialises")
                    );
                } else {
                    print!("{}", info::clip_texture_human(&p));
                }
                exit::OK
            }
        },
        Command::Tile {
            file,
            level,
            s,
            t,
            json,
            env,
        } => match load(&file, &env) {
            Err(c) => c,
            Ok((p, _)) => match p.locate(level, s, t) {
                Ok(loc) => {
                    if json {
                        println!(
                            "{}",
                            serde_json::to_string_pretty(&loc).expect("location serialises")
                        );
                    } else {
                        print!("{}", info::tile_human(&loc));
                    }
                    exit::OK
                }
                Err(e) => {
                    eprintln!("cliptex: {}: {e}", file.display());
                    exit::BAD_INPUT
                }
            },
        },
    }
}
