//! A `clipmapd` run for the hostile cases: started in a temporary directory with its mapping,
//! lock and socket there, killed when dropped; and bounded runs of the tools.

#![allow(dead_code)]

use crate::common;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

pub const CLIPMAPD: &str = env!("CARGO_BIN_EXE_clipmapd");
pub const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
pub const ICACHE: &str = env!("CARGO_BIN_EXE_icache");
pub const CLIPPREP: &str = env!("CARGO_BIN_EXE_clipprep");
pub const CLIPBENCH: &str = env!("CARGO_BIN_EXE_clipbench");
pub const ROOT: &str = env!("CLIPMAP_ROOT");

/// The longest any single tool run may take in this suite.
pub const LIMIT: Duration = Duration::from_secs(20);

/// Runs `prog args` in `dir`, bounded by [`LIMIT`].
pub fn run(dir: &Path, prog: &str, args: &[&str]) -> (Output, String) {
    common::exec_bounded(dir, prog, args, &[("RUST_LOG", "warn")], LIMIT)
}

/// Runs `prog args` and asserts its exit code and that its standard error holds every one of
/// `words`; returns the standard error.
pub fn fails(dir: &Path, prog: &str, args: &[&str], code: i32, words: &[&str]) -> String {
    let (out, d) = run(dir, prog, args);
    assert_eq!(out.status.code(), Some(code), "exit code:\n{d}");
    let err = String::from_utf8_lossy(&out.stderr).into_owned() + &String::from_utf8_lossy(&out.stdout);
    for w in words {
        assert!(err.contains(w), "should say `{w}`:\n{d}");
    }
    err
}

/// The procedural-source arguments of a small hash texture.
pub const HASH: [&str; 8] = ["--source", "hash", "--size", "4096", "--clip", "256", "--tile", "64"];

/// The common arguments that put a service's names in `dir`.
pub fn place(dir: &Path, name: &str) -> Vec<String> {
    let d = dir.to_str().unwrap().to_string();
    let sock = dir.join(format!("clipmap-{name}.sock")).to_str().unwrap().to_string();
    ["--name", name, "--shm-dir", &d, "--socket", &sock, "--tick-hz", "60"].iter().map(|s| s.to_string()).collect()
}

/// A running `clipmapd`, killed on drop.
pub struct Service {
    pub child: Child,
    pub socket: PathBuf,
    pub err: PathBuf,
}

impl Service {
    /// Starts `clipmapd SOURCE... --name NAME` with everything in `dir` and waits (bounded) until
    /// its socket answers.
    pub fn start(dir: &Path, name: &str, source: &[&str], extra: &[&str]) -> Service {
        let s = Service::spawn(dir, name, source, extra, "");
        s.wait_ready();
        s
    }

    /// Spawns it under `sh -c` with `prefix` before the command (e.g. `umask 077;`).
    pub fn spawn(dir: &Path, name: &str, source: &[&str], extra: &[&str], prefix: &str) -> Service {
        let mut args: Vec<String> = source.iter().map(|s| s.to_string()).collect();
        args.extend(place(dir, name));
        args.extend(extra.iter().map(|s| s.to_string()));
        let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
        let err = dir.join(format!("{name}.{}.err", std::process::id()));
        let child = Command::new("sh")
            .arg("-c")
            .arg(format!("{prefix} exec '{CLIPMAPD}' {}", quoted.join(" ")))
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&err).unwrap())
            .spawn()
            .unwrap();
        Service { child, socket: dir.join(format!("clipmap-{name}.sock")), err }
    }

    pub fn wait_ready(&self) {
        let t = Instant::now();
        while t.elapsed() < LIMIT {
            if ask(&self.socket, "PING").starts_with("OK pong") {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("clipmapd did not answer in {LIMIT:?}: {}", std::fs::read_to_string(&self.err).unwrap_or_default());
    }

    /// Whether it still answers on its socket.
    pub fn alive(&self) -> bool {
        ask(&self.socket, "PING").starts_with("OK pong")
    }

    /// The `STATS` reply as JSON.
    pub fn stats(&self) -> serde_json::Value {
        let r = ask(&self.socket, "STATS");
        serde_json::from_str(r.strip_prefix("OK ").unwrap_or("null")).unwrap_or(serde_json::Value::Null)
    }

    /// Waits (bounded by [`LIMIT`]) until `n` more ticks are counted, so that what was asked
    /// before has been taken by a tick; returns at once when the service stops answering.
    pub fn wait_ticks(&self, n: u64) {
        let ticks = || self.stats()["engine"]["ticks"].as_u64();
        let Some(t0) = ticks() else { return };
        let t = Instant::now();
        while ticks().is_some_and(|now| now < t0 + n) {
            assert!(t.elapsed() < LIMIT, "fewer than {n} ticks in {LIMIT:?}");
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Sends one line to a control socket and reads one line back (bounded); "" when nothing.
pub fn ask(socket: &Path, line: &str) -> String {
    let Ok(mut s) = UnixStream::connect(socket) else { return String::new() };
    let _ = s.set_read_timeout(Some(Duration::from_secs(5)));
    if writeln!(s, "{line}").is_err() {
        return String::new();
    }
    let mut reply = String::new();
    let _ = BufReader::new(s).read_line(&mut reply);
    reply.trim_end().to_string()
}

/// Makes a FIFO at `path`.
pub fn mkfifo(path: &Path) {
    rustix::fs::mkfifoat(rustix::fs::CWD, path, rustix::fs::Mode::from_raw_mode(0o600)).expect("mkfifo");
}

/// True when the suite runs as root (so it can make files owned by another user).
pub fn is_root() -> bool {
    rustix::process::geteuid().is_root()
}
