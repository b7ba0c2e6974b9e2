//! What the inspection tools print: validation reports, configuration summaries and tile
//! locations, each as a human text and as JSON. The binaries only parse arguments and call these.

pub mod check;
pub mod dump;
pub mod hypsometric;
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
pub(crate) fn human_bytes(bytes: u128) -> String {
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

    /// The process exit status of one of the codes above (every binary ends through this): a
    /// code outside them is a defect of the tool, reported as [`COULD_NOT_RUN`].
    pub fn status(code: i32) -> std::process::ExitCode {
        match code {
            OK | BAD_INPUT | COULD_NOT_RUN => std::process::ExitCode::from(code as u8),
            _ => std::process::ExitCode::from(COULD_NOT_RUN as u8),
        }
    }
}
