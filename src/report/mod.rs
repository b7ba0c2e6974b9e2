//! What the inspection tools print: validation reports, configuration summaries and tile
//! locations, each as a human text and as JSON. The binaries only parse arguments and call these.

pub mod attach;
pub mod check;
pub mod dump;
pub mod info;
pub mod live_dump;
pub mod picture;
pub mod plan;
pub mod validate;

use crate::plan::{Env, Options};

/// Builds reader options from `--env NAME=VALUE` and `--unset NAME` arguments.
pub fn options(env: &[String], unset: &[String]) -> Result<Options, String> {
    let mut e = Env::process();
    for kv in env {
        let Some((k, v)) = kv.split_once('=') else {
            return Err(format!("--env expects NAME=VALUE, found `{kv}`"));
        };
        if k.is_empty() {
            return Err(format!("--env expects NAME=VALUE with a non-empty NAME, found `{kv}`"));
        }
        e.set(k, v);
    }
    for k in unset {
        e.unset(k);
    }
    Ok(Options { env: e, ..Options::default() })
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
    pub fn options(&self) -> Result<Options, String> {
        options(&self.env, &self.unset)
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
