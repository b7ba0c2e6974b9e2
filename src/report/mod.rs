//! What the inspection tools print: validation reports, configuration summaries and tile
//! locations, each as a human text and as JSON. The binaries only parse arguments and call these.

pub mod check;
pub mod dump;
pub mod info;
pub mod label;
mod paging_args;
pub mod picture;
pub mod plan;
pub mod validate;

use crate::plan::{Env, Options};
pub use paging_args::PagingArgs;

/// An `--env` argument that is not `NAME=VALUE`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EnvArgError {
    /// No `=`.
    #[error("--env expects NAME=VALUE, found `{0}`")]
    NoEquals(String),
    /// `=VALUE`.
    #[error("--env expects NAME=VALUE with a non-empty NAME, found `{0}`")]
    EmptyName(String),
}

/// Builds reader options from `--env NAME=VALUE` and `--unset NAME` arguments.
pub fn options(env: &[String], unset: &[String]) -> Result<Options, EnvArgError> {
    let mut e = Env::process();
    for kv in env {
        let Some((k, v)) = kv.split_once('=') else {
            return Err(EnvArgError::NoEquals(kv.clone()));
        };
        if k.is_empty() {
            return Err(EnvArgError::EmptyName(kv.clone()));
        }
        e.set(k, v);
    }
    for k in unset {
        e.unset(k);
    }
    Ok(Options { env: e, ..Options::default() })
}

/// Prints a report on standard output: pretty JSON with `--json`, else its human text. The one
/// place every tool's `--json` goes, so the two forms cannot drift apart per tool.
pub fn emit<T: serde::Serialize + ?Sized>(json: bool, value: &T, human: impl FnOnce(&T) -> String) {
    if json {
        println!("{}", serde_json::to_string_pretty(value).expect("reports serialise"));
    } else {
        print!("{}", human(value));
    }
}

/// Formats a byte count the way a person reads it (KiB, MiB, GiB, TiB).
pub fn human_bytes(bytes: u128) -> String {
    const UNITS: [&str; 6] = ["B", "KiB", "MiB", "GiB", "TiB", "PiB"];
    let mut v = bytes as f64;
    let mut u = 0;
    while v >= 1024.0 && u < UNITS.len() - 1 {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{bytes} B")
    } else {
        format!("{v:.2} {}", UNITS[u])
    }
}

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
        options(&self.env, &self.unset)
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
        let loaded = crate::plan::load_clip_texture(file, &o).map_err(|e| {
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
        let loaded = crate::plan::load_image_cache(file, &o).map_err(|e| {
            eprintln!("{tool}: {e}");
            exit::COULD_NOT_RUN
        })?;
        finish_load(loaded, file, tool, "image cache")
    }

    /// Reader options, or exit status 1 (a bad `--env` value) with the reason on standard error.
    pub fn reader_options(&self, tool: &str) -> Result<Options, i32> {
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
        Some(p) => Ok((p, info::non_errors(&loaded.diagnostics.items))),
        None => {
            eprintln!("{tool}: {} is not a valid {what} configuration (see above)", file.display());
            Err(exit::BAD_INPUT)
        }
    }
}

/// Exit statuses shared by the tools: one rule for every tool, carried by the error types
/// (`exit_code()` on each) and pinned by the hostile-input suite.
pub mod exit {
    /// Everything is fine.
    pub const OK: i32 = 0;
    /// The input is bad: an invalid configuration or image, missing or unreadable tiles, an
    /// option value out of its bound, a command line that does not parse (usage errors).
    pub const BAD_INPUT: i32 = 1;
    /// The tool could not run: a file that cannot be opened or read, an output that cannot be
    /// written (a full disk), a name taken, no service to attach to, an interruption.
    pub const COULD_NOT_RUN: i32 = 2;

    /// The exit status of a command-line parse error: 0 for `--help` and `--version` (which
    /// clap reports as errors), [`BAD_INPUT`] for usage errors (clap's own default is 2).
    pub fn of_clap(e: &clap::Error) -> i32 {
        use clap::error::ErrorKind;
        match e.kind() {
            ErrorKind::DisplayHelp | ErrorKind::DisplayVersion => OK,
            _ => BAD_INPUT,
        }
    }

    /// Parses the command line like [`clap::Parser::parse`], but exits by this module's rule:
    /// a usage error prints clap's message and exits [`BAD_INPUT`].
    pub fn parse<C: clap::Parser>() -> C {
        match C::try_parse() {
            Ok(c) => c,
            Err(e) => {
                let _ = e.print();
                std::process::exit(of_clap(&e));
            }
        }
    }
}
