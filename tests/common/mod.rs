//! Helpers shared by the integration tests that drive the real binaries.

use std::path::Path;
use std::process::{Command, Output};

/// Runs `prog args` in `cwd`; returns the output and a description (command, status, stdout,
/// stderr) for failure messages.
pub fn exec(cwd: &Path, prog: &str, args: &[&str]) -> (Output, String) {
    let out = Command::new(prog).current_dir(cwd).args(args).output().expect("the binary runs");
    let d = format!(
        "command: {prog} {}\nstatus: {:?}\nstdout:\n{}\nstderr:\n{}",
        args.join(" "),
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out, d)
}
