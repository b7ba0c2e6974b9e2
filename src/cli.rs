//! The command line every binary shares (the `cli` feature, on by default): the `--env` /
//! `--unset` options and the loads they drive, the paging flags, `validate`'s arguments, and
//! the parse that exits by the tools' one rule ([`crate::report::exit`]: 0 ok, 1 bad input,
//! 2 could not run). The library builds without it (`default-features = false`): clap is only
//! here and in the binaries.

use crate::config::FileKind;
use crate::paging::{parse_bytes, EvictionKind, PagingOptions, PrefetchKind};
use crate::plan::{self, Options};
use crate::report::{exit, validate, EnvArgError};
use std::path::PathBuf;

/// The options every reading subcommand shares (`--env`, `--unset`).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct EnvArgs {
    /// Set an environment variable for `$VAR` expansion (repeatable): NAME=VALUE.
    #[arg(long = "env", value_name = "NAME=VALUE")]
    pub env: Vec<String>,
    /// Unset an environment variable for `$VAR` expansion (repeatable).
    #[arg(long = "unset", value_name = "NAME")]
    pub unset: Vec<String>,
}

impl EnvArgs {
    /// Reader options from these arguments.
    pub fn options(&self) -> Result<Options, EnvArgError> {
        crate::report::options(&self.env, &self.unset)
    }

    /// Loads a `.ct` the way every subcommand of `cliptex` does: warnings and errors rendered on
    /// standard error, `tool: FILE is not a valid ...` after errors. `ct_only` reads the `.ct`
    /// alone. `Err` is the exit status: 2 when the file cannot be read, 1 when it (or an
    /// `--env`) is invalid.
    pub fn load_clip_texture(
        &self,
        file: &std::path::Path,
        tool: &str,
        ct_only: bool,
    ) -> Result<(crate::plan::ClipTexturePlan, Vec<crate::config::Diagnostic>), i32> {
        let o = Options { ct_only, ..self.reader_options(tool)? };
        let loaded = crate::source::configured::load_clip_texture(file, &o).map_err(|e| {
            eprintln!("{tool}: {e}");
            exit::COULD_NOT_RUN
        })?;
        finish_load(loaded, file, tool, "clip texture")
    }

    /// Loads a standalone `.ic` the way every subcommand of `icache` does (see
    /// [`load_clip_texture`](Self::load_clip_texture)).
    pub fn load_image_cache(
        &self,
        file: &std::path::Path,
        tool: &str,
    ) -> Result<(crate::plan::ImageCachePlan, Vec<crate::config::Diagnostic>), i32> {
        let o = self.reader_options(tool)?;
        let loaded = crate::source::configured::load_image_cache(file, &o).map_err(|e| {
            eprintln!("{tool}: {e}");
            exit::COULD_NOT_RUN
        })?;
        finish_load(loaded, file, tool, "image cache")
    }

    /// Reader options, or exit status 1 (a bad `--env` value) with the reason on standard error.
    pub(crate) fn reader_options(&self, tool: &str) -> Result<Options, i32> {
        self.options().map_err(|e| {
            eprintln!("{tool}: {e}");
            exit::BAD_INPUT
        })
    }
}

/// Renders a load's warnings and errors on standard error and returns its plan, or exit status 1.
fn finish_load<T>(
    loaded: crate::plan::Loaded<T>,
    file: &std::path::Path,
    tool: &str,
    what: &str,
) -> Result<(T, Vec<crate::config::Diagnostic>), i32> {
    eprint!("{}", loaded.render_from(crate::config::Severity::Warning));
    match loaded.plan {
        Some(p) => Ok((p, crate::report::info::non_errors(&loaded.diagnostics.items))),
        None => {
            eprintln!("{tool}: {} is not a valid {what} configuration (see above)", file.display());
            Err(exit::BAD_INPUT)
        }
    }
}

/// `--prefetch`, `--eviction`, `--pool-bytes`, `--max-centre-step`.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct PagingArgs {
    /// Where each level's tile grid puts its spare tiles: `adaptive` (the default: read-ahead
    /// sized each tick from the measured motion and read latency, in grids sized from
    /// `--grid-budget`), `ring` (around the window), `direction` (ahead, moved when the centre
    /// crosses a tile boundary) or `ahead` (ahead at every moving tick, the former placement).
    #[arg(long, value_name = "adaptive|ring|direction|ahead")]
    pub prefetch: Option<PrefetchKind>,
    /// Which tile the second-level pool gives up first: `lru` (least recently used; the
    /// default) or `shift` (farthest behind the direction of motion).
    #[arg(long, value_name = "lru|shift")]
    pub eviction: Option<EvictionKind>,
    /// Hard budget of the second-level tile pool kept in process memory beyond the grids, bytes
    /// (k, m, g suffixes: KiB, MiB, GiB); 0: no pool.
    #[arg(long, value_name = "BYTES", value_parser = parse_bytes)]
    pub pool_bytes: Option<u64>,
    /// Most level-0 texels the centre may move per tick along each axis (the offset clamp;
    /// counted as centre clamps when it acts).
    #[arg(long, value_name = "TEXELS", value_parser = clap::value_parser!(u64).range(1..))]
    pub max_centre_step: Option<u64>,
    /// Bytes the adaptive policy's grids may take, all levels together (k, m, g suffixes);
    /// default twice the bytes of lookahead-1 grids. Levels whose `.ic` fixes a mem region keep
    /// it. Ignored by the fixed policies.
    #[arg(long, value_name = "BYTES", value_parser = parse_bytes)]
    pub grid_budget: Option<u64>,
}

impl PagingArgs {
    /// The options: each given flag over `base` (the configuration's, or the defaults).
    pub fn over(&self, base: PagingOptions) -> PagingOptions {
        PagingOptions {
            prefetch: self.prefetch.unwrap_or(base.prefetch),
            eviction: self.eviction.unwrap_or(base.eviction),
            pool_bytes: self.pool_bytes.unwrap_or(base.pool_bytes),
            max_centre_step: self.max_centre_step.or(base.max_centre_step),
            grid_budget: self.grid_budget.or(base.grid_budget),
        }
    }
}

/// The arguments of `cliptex validate` and `icache validate`.
#[derive(Clone, Debug, clap::Args)]
pub struct ValidateArgs {
    /// The configuration files.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Also fail on warnings and on anything Performer 3.0 would not read as intended.
    #[arg(long)]
    pub strict: bool,
    /// Print a JSON report instead of text.
    #[arg(long)]
    pub json: bool,
    /// Print only the invalid files.
    #[arg(long, short)]
    pub quiet: bool,
    /// `--env` and `--unset` (a flattened field: clap takes no help text from this comment).
    #[command(flatten)]
    pub env: EnvArgs,
}

/// Runs a `validate` subcommand: prints the report and returns the exit status. `ct_only`
/// (`cliptex validate --ct-only`) checks each `.ct` without opening the `.ic` files it names.
pub fn validate(args: &ValidateArgs, kind: FileKind, tool: &str, ct_only: bool) -> i32 {
    let opts = match args.env.reader_options(tool) {
        Ok(o) => plan::Options { ct_only, ..o },
        Err(code) => return code,
    };
    let r = validate::run(&args.files, kind, args.strict, &opts);
    crate::report::emit(args.json, &r, |r| r.human(args.quiet));
    r.exit_code()
}

/// The exit status of a command-line parse error: 0 for `--help` and `--version` (which
/// clap reports as errors), [`exit::BAD_INPUT`] for usage errors (clap's own default is 2).
pub(crate) fn of_clap(e: &clap::Error) -> i32 {
    use clap::error::ErrorKind;
    match e.kind() {
        ErrorKind::DisplayHelp | ErrorKind::DisplayVersion => exit::OK,
        _ => exit::BAD_INPUT,
    }
}

/// Parses the command line like [`clap::Parser::parse`], but exits by this module's rule:
/// a usage error prints clap's message and exits [`exit::BAD_INPUT`].
pub fn parse<C: clap::Parser>() -> C {
    match C::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            std::process::exit(of_clap(&e));
        }
    }
}

/// [`parse`] of `args` (the program's name first) in place of the process's arguments.
pub fn parse_from<C: clap::Parser>(args: Vec<std::ffi::OsString>) -> C {
    match C::try_parse_from(args) {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            std::process::exit(of_clap(&e));
        }
    }
}

/// The log of a tool that is not the service (`cliptex`, `clipprep`): standard error, without
/// colour codes off a terminal, and by default only the remote stack's warnings (a server that
/// ignores range requests, said once an endpoint: docs/RELIABILITY.md §6), so that the tools'
/// reports stay as they are; `RUST_LOG` chooses otherwise.
pub fn init_tool_log() {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("clipmap::source::remote=warn"));
    let ansi = std::io::stderr().is_terminal();
    let _ = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_ansi(ansi).try_init();
}

/// The options of a tile pyramid named as `xyz:TEMPLATE` (docs/TILES.md): zooms, bounds,
/// subdomains, User-Agent, headers, tile size and default tile.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct TilesArgs {
    /// The zooms the service has, `MIN..MAX` (default: a local tree's zoom directories, else 0..18).
    #[arg(long, value_name = "MIN..MAX", value_parser = parse_zooms)]
    pub zooms: Option<[u8; 2]>,
    /// The area the tiles cover, `W,S,E,N` in degrees: tiles outside it are not asked for.
    #[arg(long, value_name = "W,S,E,N", value_parser = parse_bounds, allow_hyphen_values = true)]
    pub bounds: Option<[f64; 4]>,
    /// What the template's `{s}` takes, comma-separated (default: a,b,c).
    #[arg(long, value_name = "A,B,..", value_delimiter = ',')]
    pub subdomains: Vec<String>,
    /// A header sent with every tile request, `Name: value` (repeatable; never logged).
    #[arg(long = "header", value_name = "NAME: VALUE")]
    pub headers: Vec<String>,
    /// The User-Agent sent (default: clipmap/VERSION).
    #[arg(long)]
    pub user_agent: Option<String>,
    /// Tile width and height in texels (default 256).
    #[arg(long = "tile-size", value_name = "N")]
    pub tile_size: Option<u32>,
    /// A PNG, JPEG or WebP tile served in place of a missing one.
    #[arg(long, value_name = "FILE")]
    pub default_tile: Option<std::path::PathBuf>,
}

fn parse_zooms(text: &str) -> Result<[u8; 2], String> {
    let bad = || format!("`{text}` is not a zoom range: expected MIN..MAX, e.g. 0..18");
    let (a, b) = text.split_once("..").ok_or_else(bad)?;
    Ok([a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?])
}

fn parse_bounds(text: &str) -> Result<[f64; 4], String> {
    let v: Vec<f64> = text.split(',').filter_map(|p| p.trim().parse().ok()).collect();
    match v.as_slice() {
        &[w, s, e, n] if w < e && s < n => Ok([w, s, e, n]),
        _ => Err(format!("`{text}` is not bounds: expected W,S,E,N in degrees with W < E and S < N")),
    }
}

impl TilesArgs {
    /// The options to open a pyramid with, served at `clip`.
    pub fn options(&self, clip: Option<u64>) -> Result<crate::source::tiles::OpenOptions, String> {
        let mut headers = Vec::new();
        for h in &self.headers {
            let (name, value) = h.split_once(':').ok_or_else(|| {
                format!("--header {:?}: expected `Name: value`", h.split(':').next().unwrap_or_default())
            })?;
            headers.push((name.trim().to_string(), value.trim().to_string()));
        }
        let default_tile = match &self.default_tile {
            Some(p) => Some(std::fs::read(p).map_err(|e| format!("--default-tile {}: {e}", p.display()))?),
            None => None,
        };
        // The rest is `remote`, a field only a build with the `remote` feature has (without it
        // the update fills nothing, which clippy would otherwise refuse).
        #[allow(clippy::needless_update)]
        let template = crate::source::tiles::TemplateOptions {
            zooms: self.zooms,
            bounds: self.bounds,
            tile_size: self.tile_size,
            subdomains: self.subdomains.clone(),
            user_agent: self.user_agent.clone(),
            headers,
            ..Default::default()
        };
        Ok(crate::source::tiles::OpenOptions {
            template,
            pyramid: crate::source::tiles::PyramidOptions { clip_size: clip, default_tile },
        })
    }
}
