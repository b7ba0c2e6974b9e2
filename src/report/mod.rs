//! What the inspection tools print: validation reports, configuration summaries and tile
//! locations, each as a human text and as JSON. The binaries only parse arguments and call these.

pub mod check;
pub mod dump;
pub mod info;
pub mod label;
pub mod picture;
pub mod plan;
pub mod validate;

use crate::plan::{Env, Options};

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
}

/// Exit statuses shared by the tools.
pub mod exit {
    /// Everything is fine.
    pub const OK: i32 = 0;
    /// The input is bad (invalid configuration, missing data).
    pub const BAD_INPUT: i32 = 1;
    /// The tool could not run (unreadable file, bad arguments, I/O failure).
    pub const COULD_NOT_RUN: i32 = 2;
}
