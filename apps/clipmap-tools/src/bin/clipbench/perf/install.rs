//! Installing what `clipbench perf` compares against (`--install-peers`). An installer's own
//! output goes to our standard error: with `--json`, standard output carries the JSON alone.
//! (Self-contained: the integration tests include this file to run it.)

use std::ffi::OsStr;
use std::process::{Command, Stdio};

/// Runs `program args` and waits for it, its standard output sent to our standard error (its
/// standard error is ours already); `Err` says what failed: not started, or its exit status.
pub fn run(program: &OsStr, args: &[&str]) -> Result<(), String> {
    let shown = format!("{} {}", program.to_string_lossy(), args.join(" "));
    let status = Command::new(program)
        .args(args)
        .stdout(Stdio::from(std::io::stderr()))
        .status()
        .map_err(|e| format!("{shown}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{shown} failed ({status})"))
    }
}
