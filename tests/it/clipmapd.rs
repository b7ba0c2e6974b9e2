//! The `clipmapd` service end to end: the real binary in a temporary directory, readers in Rust
//! (`clipmap-read`), C (`clients/c/reader.c`, built with `cc`) and Python
//! (`clients/python/clipmap_shm.py`) verifying every texel they read against the hash texture
//! while the centre moves fast, jumps and reverses; the service killed with SIGKILL and
//! restarted under the readers; hostile control-socket input; permissions; refused mappings.
//!
//! Every service is killed when its guard drops; failures print the command and its output.

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::fs::PermissionsExt;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

pub(crate) const CLIPMAPD: &str = env!("CARGO_BIN_EXE_clipmapd");
pub(crate) const READER: &str = env!("CARGO_BIN_EXE_clipmap-read");
pub(crate) const ROOT: &str = env!("CLIPMAP_ROOT");

/// A running `clipmapd`, killed on drop; its output goes to files in the temp dir.
pub(crate) struct Service {
    pub(crate) child: Child,
    args: Vec<String>,
    out: PathBuf,
    pub(crate) err: PathBuf,
    pub(crate) socket: PathBuf,
}

impl Service {
    /// Starts `clipmapd --source hash` named `name` in `dir` with `extra` options and waits until
    /// its socket answers.
    pub(crate) fn start(dir: &Path, name: &str, extra: &[&str]) -> Service {
        let s = Service::spawn(dir, name, extra);
        s.wait_ready();
        s
    }

    pub(crate) fn spawn(dir: &Path, name: &str, extra: &[&str]) -> Service {
        let source = ["--source", "hash", "--size", "65536", "--clip", "256", "--tile", "64"];
        Service::spawn_with(dir, name, &source, extra)
    }

    /// Starts `clipmapd SOURCE...` (a configuration file or procedural options).
    pub(crate) fn spawn_with(dir: &Path, name: &str, source: &[&str], extra: &[&str]) -> Service {
        let given = extra.iter().position(|a| *a == "--socket").map(|i| PathBuf::from(extra[i + 1]));
        let socket = given.clone().unwrap_or_else(|| dir.join(format!("{name}.sock")));
        let mut args: Vec<String> = source.iter().map(|s| s.to_string()).collect();
        args.extend(
            ["--tick-hz", "120", "--name", name, "--shm-dir", dir.to_str().unwrap()].iter().map(|s| s.to_string()),
        );
        if given.is_none() {
            args.extend(["--socket".to_string(), socket.to_str().unwrap().to_string()]);
        }
        args.extend(extra.iter().map(|s| s.to_string()));
        let n = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos();
        let (out, err) = (dir.join(format!("{name}-{n}.out")), dir.join(format!("{name}-{n}.err")));
        let child = Command::new(CLIPMAPD)
            .args(&args)
            .env("RUST_LOG", "info")
            .stdout(std::fs::File::create(&out).unwrap())
            .stderr(std::fs::File::create(&err).unwrap())
            .spawn()
            .unwrap();
        Service { child, args, out, err, socket }
    }

    pub(crate) fn wait_ready(&self) {
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(30) {
            if let Ok(mut s) = UnixStream::connect(&self.socket) {
                if writeln!(s, "PING").is_ok() {
                    let mut line = String::new();
                    let _ = BufReader::new(s).read_line(&mut line);
                    if line.starts_with("OK pong") {
                        return;
                    }
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("the service did not come up\n{}", self.dump());
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }

    pub(crate) fn dump(&self) -> String {
        format!(
            "command: {CLIPMAPD} {}\nstdout:\n{}\nstderr:\n{}",
            self.args.join(" "),
            std::fs::read_to_string(&self.out).unwrap_or_default(),
            std::fs::read_to_string(&self.err).unwrap_or_default()
        )
    }

    /// Sends one request and returns the first reply line.
    pub(crate) fn ask(&self, line: &str) -> String {
        ask(&self.socket, line)
    }

    fn wait_exit(&mut self, within: Duration) -> Option<std::process::ExitStatus> {
        let t = Instant::now();
        while t.elapsed() < within {
            if let Some(st) = self.child.try_wait().unwrap() {
                return Some(st);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub(crate) fn ask(socket: &Path, line: &str) -> String {
    let mut s = UnixStream::connect(socket).unwrap_or_else(|e| panic!("connect {}: {e}", socket.display()));
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    writeln!(s, "{line}").unwrap();
    let mut reply = String::new();
    BufReader::new(s).read_line(&mut reply).unwrap();
    reply.trim_end().to_string()
}

pub(crate) fn json_reply(reply: &str) -> serde_json::Value {
    let body = reply.strip_prefix("OK ").unwrap_or_else(|| panic!("not OK: {reply}"));
    serde_json::from_str(body).unwrap_or_else(|e| panic!("{e}: {reply}"))
}

/// Parses "N passed, M failed" from a reader's output.
pub(crate) fn counts(out: &Output, what: &str) -> (u64, u64) {
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout.lines().find(|l| l.contains(" passed, ")).unwrap_or_else(|| {
        panic!(
            "{what}: no counts\nstatus {:?}\nstdout:\n{stdout}\nstderr:\n{}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        )
    });
    let mut w = line.split_whitespace();
    let passed = w.next().unwrap().parse().unwrap();
    let failed = w.nth(1).unwrap().parse().unwrap();
    (passed, failed)
}

pub(crate) fn rust_reader(dir: &Path, name: &str, extra: &[&str]) -> Command {
    let mut c = Command::new(READER);
    c.args(["--name", name, "--shm-dir", dir.to_str().unwrap()]).args(extra);
    c.stdout(Stdio::piped()).stderr(Stdio::piped());
    c
}

/// Builds the C example reader with the system compiler.
pub(crate) fn c_reader(dir: &Path) -> PathBuf {
    let exe = dir.join("c-reader");
    let out = Command::new("cc")
        .args(["-O2", "-Wall", "-Werror", "-I"])
        .arg(Path::new(ROOT).join("include"))
        .arg(Path::new(ROOT).join("clients/c/reader.c"))
        .arg("-o")
        .arg(&exe)
        .output()
        .expect("a C compiler (`cc`) is needed: .ci/run installs gcc");
    assert!(out.status.success(), "cc failed:\n{}", String::from_utf8_lossy(&out.stderr));
    exe
}

pub(crate) fn python_reader() -> Command {
    let mut c = Command::new("python3");
    c.arg(Path::new(ROOT).join("clients/python/clipmap_shm.py"));
    c.stdout(Stdio::piped()).stderr(Stdio::piped());
    c
}

#[test]
fn readers_in_rust_c_and_python_verify_every_texel_while_the_centre_moves_fast() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "fly", &["--budget-ms", "2"]);
    let map = d.join("clipmap-fly.map");
    let creader = c_reader(d);
    let secs = "3";
    // Each reader reads until the time is up (the caps are far above what a reader reaches).
    // One Rust reader drives: fast steps, reversals and jumps larger than the window.
    let readers: Vec<(String, std::process::Child)> = vec![
        (
            "rust driver".into(),
            rust_reader(d, "fly", &["--drive", "--reads", "1000000000000", "--seconds", secs]).spawn().unwrap(),
        ),
        (
            "rust 1".into(),
            rust_reader(d, "fly", &["--reads", "1000000000000", "--seconds", secs, "--seed", "2"]).spawn().unwrap(),
        ),
        (
            "rust 2".into(),
            rust_reader(d, "fly", &["--reads", "1000000000000", "--seconds", secs, "--block", "3", "--seed", "3"])
                .spawn()
                .unwrap(),
        ),
        (
            "c".into(),
            Command::new(&creader)
                .arg(&map)
                .args(["1000000000000", "5", secs])
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap(),
        ),
        ("python".into(), python_reader().arg(&map).args(["1000000000000", "7", secs]).spawn().unwrap()),
    ];
    let mut total = 0;
    for (what, child) in readers {
        let out = child.wait_with_output().unwrap();
        let (passed, failed) = counts(&out, &what);
        assert_eq!(failed, 0, "{what}: {failed} mismatches\n{}\n{}", String::from_utf8_lossy(&out.stderr), svc.dump());
        assert!(out.status.success(), "{what}: {:?}\n{}", out.status, String::from_utf8_lossy(&out.stderr));
        assert!(passed > 10_000, "{what}: only {passed} texels checked");
        eprintln!("{what}: {passed} texels checked");
        total += passed;
    }
    eprintln!("all readers: {total} texels checked, none wrong");
    assert!(total >= 10_000_000, "only {total} texels checked");
    let stats = json_reply(&svc.ask("STATS"));
    assert!(stats["requests_seen"].as_u64().unwrap() > 100, "the driver's requests must arrive: {stats}");
    assert_eq!(stats["engine"]["tick_texel_bytes"], 0, "ticks write no texels: {stats}");
    assert_eq!(stats["engine"]["slots_reassigned_under_published"], 0, "{stats}");
    assert!(stats["engine"]["tiles_read"].as_u64().unwrap() > 100, "{stats}");
}

#[test]
fn with_aligned_level_centres_a_driving_reader_still_sees_only_right_texels() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "steps", &["--centre-alignment", "8", "--budget-ms", "2"]);
    let out = rust_reader(d, "steps", &["--drive", "--reads", "1000000000000", "--seconds", "1"]).output().unwrap();
    let (passed, failed) = counts(&out, "rust driver");
    assert_eq!(failed, 0, "{failed} mismatches\n{}\n{}", String::from_utf8_lossy(&out.stderr), svc.dump());
    assert!(out.status.success(), "{:?}\n{}", out.status, String::from_utf8_lossy(&out.stderr));
    assert!(passed > 10_000, "only {passed} texels checked");
    // Every snapshot it took was checked whole: each level from min LOD up published.
    let first = String::from_utf8_lossy(&out.stdout).lines().next().unwrap_or_default().to_string();
    let line: serde_json::Value = serde_json::from_str(&first).unwrap_or_else(|e| panic!("{e}: {first}"));
    let snapshots = line["snapshots"].as_u64().unwrap_or_else(|| panic!("no snapshot count: {first}"));
    assert!(snapshots > 1000, "only {snapshots} snapshots checked");
    let stats = json_reply(&svc.ask("STATS"));
    assert_eq!(stats["engine"]["tick_texel_bytes"], 0, "{stats}");
}

#[test]
fn kill_9_mid_update_readers_see_no_torn_state_notice_the_stale_heartbeat_and_reattach() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut svc = Service::start(d, "crash", &[]);
    let follow = ["--follow", "--stale-ms", "400", "--seconds", "9", "--reads", "1000000000000"];
    let driver = rust_reader(d, "crash", &[&follow[..], &["--drive"]].concat()).spawn().unwrap();
    let reader = rust_reader(d, "crash", &[&follow[..], &["--block", "5", "--seed", "9"]].concat()).spawn().unwrap();
    let kills = 3;
    for i in 0..kills {
        std::thread::sleep(Duration::from_millis(900));
        let st = json_reply(&svc.ask("STATS"));
        assert!(st["engine"]["ticks"].as_u64().unwrap() > 0, "{st}");
        svc.child.kill().unwrap(); // SIGKILL, in the middle of whatever it was doing
        svc.child.wait().unwrap();
        std::thread::sleep(Duration::from_millis(900));
        // A clean takeover: the dead service's lock died with it, its socket is stale.
        svc = Service::start(d, "crash", &[]);
        eprintln!("restart {} done", i + 1);
    }
    for (what, child) in [("driver", driver), ("reader", reader)] {
        let out = child.wait_with_output().unwrap();
        let (passed, failed) = counts(&out, what);
        let stdout = String::from_utf8_lossy(&out.stdout);
        let json: serde_json::Value = serde_json::from_str(stdout.lines().next().unwrap()).unwrap();
        eprintln!("{what}: {json}");
        assert_eq!(failed, 0, "{what}: {stdout}\n{}\n{}", String::from_utf8_lossy(&out.stderr), svc.dump());
        assert!(passed > 100_000, "{what}: {stdout}");
        assert!(json["stale_seen"].as_u64().unwrap() >= kills, "{what} must notice every stale heartbeat: {json}");
        assert!(json["reattached"].as_u64().unwrap() >= kills, "{what} must reattach after every restart: {json}");
    }
}

#[test]
fn killed_readers_go_unnoticed_but_in_the_statistics() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "rk", &[]);
    let mut seen = 0;
    for _ in 0..3 {
        let mut r = rust_reader(d, "rk", &["--drive", "--seconds", "30", "--reads", "1000000000000"]).spawn().unwrap();
        // Killed mid-flight, once the service has counted its requests in STATS (however slowly
        // a loaded machine starts it): the statistics see the readers, within 30 s each.
        let t = Instant::now();
        loop {
            let now = json_reply(&svc.ask("STATS"))["requests_seen"].as_u64().unwrap();
            if now > seen {
                seen = now;
                break;
            }
            assert!(t.elapsed() < Duration::from_secs(30), "the reader's requests never arrived\n{}", svc.dump());
            std::thread::sleep(Duration::from_millis(20));
        }
        r.kill().unwrap();
        r.wait().unwrap();
    }
    let before = json_reply(&svc.ask("STATS"));
    // Still ticking: a later tick is counted (bounded wait).
    let t = Instant::now();
    loop {
        let after = json_reply(&svc.ask("STATS"));
        if after["engine"]["ticks"].as_u64() > before["engine"]["ticks"].as_u64() {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(10), "not ticking any more: {after}\n{}", svc.dump());
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = rust_reader(d, "rk", &["--drive", "--reads", "200000"]).output().unwrap();
    let (passed, failed) = counts(&out, "reader after the kills");
    assert_eq!((failed, passed >= 200_000), (0, true), "{}", String::from_utf8_lossy(&out.stdout));
}

#[test]
fn hostile_control_input_gets_errors_bounded_memory_and_the_service_keeps_serving() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "hostile", &["--idle-ms", "700", "--max-connections", "8"]);
    let connect = || {
        let s = UnixStream::connect(&svc.socket).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        s
    };
    let read_all = |mut s: UnixStream| {
        let mut text = String::new();
        let _ = s.read_to_string(&mut text);
        text
    };
    // Garbage, bad arguments and binary on one connection: one ERR each, the connection stays.
    let mut s = connect();
    s.write_all(b"HELLO\n\xff\xfe\x00\n\nBUDGET -3\nBORDER many\nCENTRE 1\nPING\nQUIT\n").unwrap();
    let replies = read_all(s);
    let lines: Vec<&str> = replies.lines().collect();
    assert_eq!(lines.len(), 8, "{replies}");
    assert!(lines[..6].iter().all(|l| l.starts_with("ERR ")), "{replies}");
    assert!(lines[0].contains("unknown command") && lines[1].contains("UTF-8"), "{replies}");
    assert_eq!(lines[6..], ["OK pong", "OK bye"]);
    // A huge line: refused as soon as it passes the limit, not buffered.
    let mut s = connect();
    let huge = vec![b'A'; 4 << 20];
    let _ = s.write_all(&huge); // the service may close before all of it is sent
    let reply = read_all(s);
    assert!(reply.starts_with("ERR request longer than 4096 bytes"), "{reply}");
    // Half a line, then the writer goes away.
    let mut s = connect();
    s.write_all(b"STAT").unwrap();
    s.shutdown(std::net::Shutdown::Write).unwrap();
    assert!(read_all(s).starts_with("ERR incomplete request"));
    // Half a line and silence: closed after the idle time.
    let mut s = connect();
    s.write_all(b"STATU").unwrap();
    assert!(read_all(s).starts_with("ERR idle"));
    // Many connections at once: beyond the limit, refused with a reason.
    // Every connection is held until all are counted: one closed early would free a place for a
    // later one the service had not yet accepted.
    let held: Vec<UnixStream> = (0..40).map(|_| connect()).collect();
    std::thread::sleep(Duration::from_millis(100));
    let refused = held
        .iter()
        .map(|mut s| {
            let _ = writeln!(s, "PING");
            let mut line = String::new();
            let _ = BufReader::new(s).read_line(&mut line);
            line
        })
        .filter(|l| l.starts_with("ERR too many connections"))
        .count();
    drop(held);
    assert!(refused >= 30, "{refused} of 40 refused");
    // Still serving, and it counted everything: asked once the service has closed the held
    // connections (until then a new one may be refused too), within a bound.
    let t = Instant::now();
    let st = loop {
        let reply = svc.ask("STATS");
        if !(reply.starts_with("ERR too many connections") && t.elapsed() < Duration::from_secs(10)) {
            break json_reply(&reply);
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(st["control"]["errors"].as_u64().unwrap() >= 9, "{st}");
    assert!(st["control"]["refused"].as_u64().unwrap() >= 30, "{st}");
    assert_eq!(st["control"]["long_lines"], 1);
    assert_eq!(svc.ask("PING"), "OK pong");
    let status = std::fs::read_to_string(format!("/proc/{}/status", svc.pid())).unwrap_or_default();
    if let Some(kb) = status.lines().find(|l| l.starts_with("VmRSS:")) {
        let kb: u64 = kb.split_whitespace().nth(1).unwrap().parse().unwrap();
        assert!(kb < 256 * 1024, "resident memory {kb} kB after hostile input");
    }
}

#[test]
fn control_commands_change_the_service_and_shutdown_stops_it_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut svc = Service::start(d, "ctl", &[]);
    assert_eq!(svc.ask("BUDGET 2.5"), "OK budget 2.5 ms");
    assert_eq!(svc.ask("budget off"), "OK budget off");
    assert_eq!(svc.ask("BORDER 12"), "OK border 12");
    assert_eq!(svc.ask("BORDER 100000"), "OK border 127", "clamped to what the clip size allows");
    assert_eq!(svc.ask("CENTRE 1000 2000"), "OK centre 1000 2000");
    // Until a tick has taken the centre (bounded wait).
    let t = Instant::now();
    let status = loop {
        let status = json_reply(&svc.ask("STATUS"));
        if status["centre"] == serde_json::json!([1000, 2000]) || t.elapsed() > Duration::from_secs(10) {
            break status;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(status["centre"], serde_json::json!([1000, 2000]), "{status}");
    assert_eq!(status["invalid_border"], 127);
    assert_eq!(status["budget_ms"], serde_json::Value::Null);
    assert_eq!(status["levels"], 17);
    assert_eq!(status["pid"], svc.pid());
    // Prometheus text: a header line giving the count, then that many lines.
    let mut s = UnixStream::connect(&svc.socket).unwrap();
    writeln!(s, "STATS PROM").unwrap();
    let mut r = BufReader::new(s);
    let mut head = String::new();
    r.read_line(&mut head).unwrap();
    let n: usize = head.trim().strip_prefix("OK prometheus ").unwrap().parse().unwrap();
    let body: Vec<String> = (0..n)
        .map(|_| {
            let mut l = String::new();
            r.read_line(&mut l).unwrap();
            l
        })
        .collect();
    let ticks = body.iter().find(|l| l.starts_with("clipmapd_ticks_total{name=\"ctl\"} ")).expect("ticks sample");
    assert!(ticks.split_whitespace().nth(1).unwrap().parse::<f64>().unwrap() > 0.0);
    assert!(body.iter().any(|l| l.starts_with("clipmapd_budget_overruns_total")));
    assert!(body.iter().any(|l| l.starts_with("clipmapd_levels_disabled")));
    assert_eq!(svc.ask("SHUTDOWN"), "OK shutting down");
    let st = svc.wait_exit(Duration::from_secs(10)).unwrap_or_else(|| panic!("still running\n{}", svc.dump()));
    assert!(st.success(), "{st:?}\n{}", svc.dump());
    assert!(!d.join("clipmap-ctl.map").exists() && !svc.socket.exists(), "names removed on a clean stop");
    // Its log went to a file: plain text, no terminal colour codes.
    let log = std::fs::read_to_string(&svc.err).unwrap();
    assert!(log.contains("INFO"), "the log has lines\n{log}");
    assert!(!log.contains('\x1b'), "colour codes in a log file\n{log}");
}

#[test]
fn sigterm_stops_gracefully_and_a_second_service_on_the_same_name_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut first = Service::start(d, "one", &[]);
    let mut second = Service::spawn(d, "one", &["--socket", d.join("other.sock").to_str().unwrap()]);
    let st = second.wait_exit(Duration::from_secs(20)).expect("the second service must exit");
    assert_eq!(st.code(), Some(2), "{}", second.dump());
    assert!(second.dump().contains("already publishes `one`"), "{}", second.dump());
    assert_eq!(first.ask("PING"), "OK pong", "the first keeps serving");
    // A second service on another name but the same socket is refused too.
    let mut third = Service::spawn(d, "two", &["--socket", first.socket.to_str().unwrap()]);
    let st = third.wait_exit(Duration::from_secs(20)).expect("the third service must exit");
    assert_eq!(st.code(), Some(2), "{}", third.dump());
    assert!(third.dump().contains("another process accepts connections"), "{}", third.dump());
    assert!(!d.join("clipmap-two.map").exists(), "a refused service leaves no mapping behind");
    let kill = Command::new("kill").args(["-TERM", &first.pid().to_string()]).status().unwrap();
    assert!(kill.success());
    let st = first.wait_exit(Duration::from_secs(10)).unwrap_or_else(|| panic!("still running\n{}", first.dump()));
    assert!(st.success(), "{st:?}\n{}", first.dump());
    assert!(first.dump().contains("SIGTERM"), "{}", first.dump());
    assert!(!d.join("clipmap-one.map").exists() && !first.socket.exists());
}

#[test]
fn the_mapping_and_the_socket_are_owner_only_unless_widened() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    let a = Service::start(d, "priv", &[]);
    assert_eq!(mode(&d.join("clipmap-priv.map")), 0o600);
    assert_eq!(mode(&a.socket), 0o600);
    let b = Service::start(d, "shared", &["--shm-mode", "640"]);
    assert_eq!(mode(&d.join("clipmap-shared.map")), 0o640);
    assert_eq!(mode(&b.socket), 0o600, "the control socket stays owner-only");
    let mut c = Service::spawn(d, "bad", &["--shm-mode", "777"]);
    assert_eq!(c.wait_exit(Duration::from_secs(20)).unwrap().code(), Some(1), "{}", c.dump());
}

#[test]
fn every_client_refuses_a_mapping_with_a_wrong_magic_version_or_size() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let good = {
        let svc = Service::start(d, "src", &[]);
        let bytes = std::fs::read(d.join("clipmap-src.map")).unwrap();
        drop(svc);
        bytes
    };
    let creader = c_reader(d);
    let mut cases: Vec<(&str, Vec<u8>, &str)> = Vec::new();
    let mut b = good.clone();
    b[0..8].copy_from_slice(b"NOTACLIP");
    cases.push(("magic", b, "wrong magic"));
    let mut b = good.clone();
    b[8..12].copy_from_slice(&9u32.to_le_bytes());
    cases.push(("version", b, "layout version 9"));
    cases.push(("short", good[..good.len() - 4096].to_vec(), "the header says"));
    cases.push(("tiny", good[..512].to_vec(), "truncated"));
    for (name, bytes, want) in cases {
        let p = d.join(format!("{name}.map"));
        std::fs::write(&p, &bytes).unwrap();
        let runs: [(&str, Output); 3] = [
            ("rust", Command::new(READER).arg("--path").arg(&p).args(["--reads", "10"]).output().unwrap()),
            ("c", Command::new(&creader).arg(&p).arg("10").output().unwrap()),
            ("python", python_reader().arg(&p).arg("10").output().unwrap()),
        ];
        for (who, out) in runs {
            let err = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(2), "{who} on {name}: {:?}\n{err}", out.status);
            assert!(err.contains(want), "{who} on {name}: expected `{want}` in: {err}");
        }
    }
}

#[test]
fn bad_options_exit_with_status_1_and_say_why() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let cases: &[(&[&str], &str)] = &[
        (&["--source", "hash", "--size", "1000", "--shm-dir", d], "size"),
        (&["--source", "hash", "--tick-hz", "0", "--shm-dir", d], "--tick-hz"),
        (&["--source", "hash", "--budget-ms", "soon", "--shm-dir", d], "--budget-ms"),
        (&["--source", "hash", "--centre-alignment", "0", "--shm-dir", d], "--centre-alignment"),
        (&["--source", "hash", "--name", "../x", "--shm-dir", d], "invalid name"),
        (&["--shm-dir", d], "--source"),
    ];
    for (args, want) in cases {
        let mut child =
            Command::new(CLIPMAPD).args(*args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
        let t = Instant::now();
        while child.try_wait().unwrap().is_none() && t.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = child.kill(); // never leave a service running if it wrongly started
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: expected `{want}` in: {err}");
    }
}

#[test]
fn the_demo_writes_its_pictures_and_a_summary_and_exits() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("pictures");
    let out = Command::new(CLIPMAPD)
        .args(["--demo", "--demo-frames", "60", "--out", out_dir.to_str().unwrap()])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains(&format!("pictures in {}", out_dir.display())), "{stdout}");
    let pngs: Vec<_> = std::fs::read_dir(&out_dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    assert_eq!(pngs.len(), 9, "{pngs:?}");
    for p in &pngs {
        assert!(stdout.contains(p.file_name().unwrap().to_str().unwrap()), "{stdout}");
        assert_eq!(&std::fs::read(p).unwrap()[..8], b"\x89PNG\r\n\x1a\n");
    }
    let stats: serde_json::Value = serde_json::from_slice(&std::fs::read(out_dir.join("stats.json")).unwrap()).unwrap();
    assert_eq!(stats["requests_seen"], 60);
    // Every picture is labelled: caption text across its top rows, and the level pictures carry
    // a legend below with the valid region's red and the window's yellow swatches.
    for p in &pngs {
        let img = image::open(p).unwrap().to_rgb8();
        let caption = (0..20).flat_map(|y| (0..img.width()).map(move |x| (x, y)));
        let text = caption.filter(|&(x, y)| img.get_pixel(x, y).0 == [235, 235, 235]).count();
        assert!(text > 100, "{}: no caption ({text} text pixels)", p.display());
        let name = p.file_name().unwrap().to_str().unwrap();
        if name.starts_with("levels-") || name.starts_with("lod-") {
            let rows = if name.starts_with("levels-") { 30 } else { 70 }; // the level legend wraps
            let bottom = (img.height() - rows..img.height()).flat_map(|y| (0..img.width()).map(move |x| (x, y)));
            let colours: std::collections::HashSet<[u8; 3]> = bottom.map(|(x, y)| img.get_pixel(x, y).0).collect();
            let want: &[[u8; 3]] =
                if name.starts_with("levels-") { &[[255, 0, 0], [255, 255, 0]] } else { &[[230, 25, 75]] };
            for c in want {
                assert!(colours.contains(c), "{name}: the legend lacks {c:?}");
            }
        }
    }
}

#[test]
fn the_c_header_and_the_python_reader_agree_with_the_layout() {
    use clipmap::shm::layout::{
        desc, header, heights, request, snapshot, state, tag, DESC_BYTES, HEIGHTS_BYTES, MAX_LEVELS, MAX_RETRIES, PAGE,
        REQUEST_BYTES, STATE_BYTES, TAG_BYTES, VERSION,
    };
    let h = std::fs::read_to_string(Path::new(ROOT).join("include/clipmap_shm.h")).unwrap();
    let define = |name: &str| -> usize {
        let line = h
            .lines()
            .find(|l| l.split_whitespace().nth(1) == Some(name) && l.starts_with("#define"))
            .unwrap_or_else(|| panic!("{name} is not defined in the header"));
        let value = line.split_whitespace().nth(2).unwrap().trim_end_matches('u');
        value.parse().unwrap_or_else(|_| panic!("{line}"))
    };
    let pairs: &[(&str, usize)] = &[
        ("CLIPMAP_VERSION", VERSION as usize),
        ("CLIPMAP_PAGE", PAGE as usize),
        ("CLIPMAP_MAX_LEVELS", MAX_LEVELS),
        ("CLIPMAP_MAX_RETRIES", MAX_RETRIES),
        ("CLIPMAP_REQUEST_BYTES", REQUEST_BYTES as usize),
        ("CLIPMAP_H_VERSION", header::VERSION),
        ("CLIPMAP_H_HEADER_BYTES", header::HEADER_BYTES),
        ("CLIPMAP_H_TOTAL_BYTES", header::TOTAL_BYTES),
        ("CLIPMAP_H_TEXEL_FORMAT", header::TEXEL_FORMAT),
        ("CLIPMAP_H_BYTES_PER_TEXEL", header::BYTES_PER_TEXEL),
        ("CLIPMAP_H_CLIP_SIZE", header::CLIP_SIZE),
        ("CLIPMAP_H_LEVEL_COUNT", header::LEVEL_COUNT),
        ("CLIPMAP_H_LEVEL0_S", header::LEVEL0_S),
        ("CLIPMAP_H_LEVEL0_T", header::LEVEL0_T),
        ("CLIPMAP_H_WRITER_PID", header::WRITER_PID),
        ("CLIPMAP_H_HEARTBEAT", header::HEARTBEAT),
        ("CLIPMAP_H_HEARTBEAT_MS", header::HEARTBEAT_MS),
        ("CLIPMAP_H_GENERATION", header::GENERATION),
        ("CLIPMAP_H_FLAGS", header::FLAGS),
        ("CLIPMAP_H_TICK_PERIOD_NS", header::TICK_PERIOD_NS),
        ("CLIPMAP_H_SNAPSHOT", header::SNAPSHOT),
        ("CLIPMAP_H_LEVEL_DESCS", header::LEVEL_DESCS),
        ("CLIPMAP_H_HEIGHTS", header::HEIGHTS),
        ("CLIPMAP_H_END", header::END),
        ("CLIPMAP_HEIGHTS_BYTES", HEIGHTS_BYTES),
        ("CLIPMAP_HT_IS_HEIGHTS", heights::IS_HEIGHTS),
        ("CLIPMAP_HT_RULE", heights::RULE),
        ("CLIPMAP_HT_SCALE", heights::SCALE),
        ("CLIPMAP_HT_OFFSET", heights::OFFSET),
        ("CLIPMAP_HT_NODATA", heights::NODATA),
        ("CLIPMAP_H_GEOREF", header::GEOREF),
        ("CLIPMAP_GEOREF_BYTES", clipmap::shm::layout::GEOREF_BYTES),
        ("CLIPMAP_GEOREF_DEFINITION_MAX", clipmap::shm::layout::GEOREF_DEFINITION_MAX),
        ("CLIPMAP_GR_PRESENT", clipmap::shm::layout::georef::PRESENT),
        ("CLIPMAP_GR_DEFINITION", clipmap::shm::layout::georef::DEFINITION),
        ("CLIPMAP_D_GEOREF", desc::GEOREF),
        ("CLIPMAP_SNAP_SEQ", snapshot::SEQ),
        ("CLIPMAP_SNAP_MIN_LOD", snapshot::MIN_LOD),
        ("CLIPMAP_SNAP_TICK", snapshot::TICK),
        ("CLIPMAP_SNAP_INVALID_BORDER", snapshot::INVALID_BORDER),
        ("CLIPMAP_SNAP_CENTRE_S", snapshot::CENTRE_S),
        ("CLIPMAP_SNAP_CENTRE_T", snapshot::CENTRE_T),
        ("CLIPMAP_SNAP_LEVELS", snapshot::LEVELS),
        ("CLIPMAP_STATE_BYTES", STATE_BYTES),
        ("CLIPMAP_S_CENTRE_S", state::CENTRE_S),
        ("CLIPMAP_S_CENTRE_T", state::CENTRE_T),
        ("CLIPMAP_S_VALID_S0", state::VALID_S0),
        ("CLIPMAP_S_VALID_T0", state::VALID_T0),
        ("CLIPMAP_S_VALID_S1", state::VALID_S1),
        ("CLIPMAP_S_VALID_T1", state::VALID_T1),
        ("CLIPMAP_S_ENABLED", state::ENABLED),
        ("CLIPMAP_S_UPDATED_TICK", state::UPDATED_TICK),
        ("CLIPMAP_DESC_BYTES", DESC_BYTES),
        ("CLIPMAP_D_SIZE_S", desc::SIZE_S),
        ("CLIPMAP_D_SIZE_T", desc::SIZE_T),
        ("CLIPMAP_D_TILE_S", desc::TILE_S),
        ("CLIPMAP_D_TILE_T", desc::TILE_T),
        ("CLIPMAP_D_GRID_S", desc::GRID_S),
        ("CLIPMAP_D_GRID_T", desc::GRID_T),
        ("CLIPMAP_D_SLOT_BYTES", desc::SLOT_BYTES),
        ("CLIPMAP_D_TAGS_OFFSET", desc::TAGS_OFFSET),
        ("CLIPMAP_D_SLOTS_OFFSET", desc::SLOTS_OFFSET),
        ("CLIPMAP_D_KIND", desc::KIND),
        ("CLIPMAP_D_RANGES_OFFSET", desc::RANGES_OFFSET),
        ("CLIPMAP_RANGE_BYTES", clipmap::shm::layout::RANGE_BYTES),
        ("CLIPMAP_R_MIN", clipmap::shm::layout::range::MIN),
        ("CLIPMAP_R_MAX", clipmap::shm::layout::range::MAX),
        ("CLIPMAP_TAG_BYTES", TAG_BYTES),
        ("CLIPMAP_T_SEQ", tag::SEQ),
        ("CLIPMAP_T_TILE_S", tag::TILE_S),
        ("CLIPMAP_T_TILE_T", tag::TILE_T),
        ("CLIPMAP_T_STATE", tag::STATE),
        ("CLIPMAP_R_VERSION", request::VERSION),
        ("CLIPMAP_R_GENERATION", request::GENERATION),
        ("CLIPMAP_R_SEQ", request::SEQ),
        ("CLIPMAP_R_CENTRE_S", request::CENTRE_S),
        ("CLIPMAP_R_CENTRE_T", request::CENTRE_T),
        ("CLIPMAP_R_VEL_S", request::VEL_S),
        ("CLIPMAP_R_VEL_T", request::VEL_T),
        ("CLIPMAP_R_CLIENT_PID", request::CLIENT_PID),
        ("CLIPMAP_R_COUNT", request::COUNT),
    ];
    for (name, want) in pairs {
        assert_eq!(define(name), *want, "{name}");
    }
    use clipmap::shm::layout::SlotState as S;
    for (name, st) in [
        ("CLIPMAP_SLOT_EMPTY", S::Empty),
        ("CLIPMAP_SLOT_LOADING", S::Loading),
        ("CLIPMAP_SLOT_READY", S::Ready),
        ("CLIPMAP_SLOT_MISSING", S::Missing),
        ("CLIPMAP_SLOT_DEFAULT", S::Default),
    ] {
        assert_eq!(define(name), st as usize, "{name}");
    }
    // Python's copy of them, computed by Python itself.
    let py = Command::new("python3")
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .arg("-c")
        .arg(
            "import sys; sys.path.insert(0, sys.argv[1]); import clipmap_shm as c; \
             print(c.H_SNAPSHOT, c.H_LEVEL_DESCS, c.H_END, c.H_TICK_PERIOD_NS, c.DESC_BYTES, c.STATE_BYTES, \
             c.TAG_BYTES, c.DESC_SLOTS_OFFSET, c.TAG_STATE, c.S_UPDATED_TICK, c.SNAP_CENTRE_T, c.MAX_RETRIES, \
             c.DESC_RANGES_OFFSET, c.RANGE_BYTES, c.RANGE_MIN, c.RANGE_MAX)",
        )
        .arg(Path::new(ROOT).join("clients/python"))
        .output()
        .unwrap();
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    let want = format!(
        "{} {} {} {} {} {} {} {} {} {} {} {} {} {} {} {}",
        header::SNAPSHOT,
        header::LEVEL_DESCS,
        header::END,
        header::TICK_PERIOD_NS,
        DESC_BYTES,
        STATE_BYTES,
        TAG_BYTES,
        desc::SLOTS_OFFSET,
        tag::STATE,
        state::UPDATED_TICK,
        snapshot::CENTRE_T,
        MAX_RETRIES,
        desc::RANGES_OFFSET,
        clipmap::shm::layout::RANGE_BYTES,
        clipmap::shm::layout::range::MIN,
        clipmap::shm::layout::range::MAX
    );
    assert_eq!(String::from_utf8_lossy(&py.stdout).trim(), want);
}

#[test]
fn the_c_and_python_readers_pass_the_independent_fixture_mappings() {
    // An independent layout-2 writer (tests/fixtures/make_mapping.py) makes valid, missing-tile
    // and hostile mappings; both readers must read the first all right, skip missing tiles and
    // refuse each hostile one (exit 2, never a crash or a hang).
    let out = Command::new("bash")
        .arg(Path::new(ROOT).join("tests/fixtures/check_readers.sh"))
        .args(["--quick", "--no-asan"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "stdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_ct_configuration_is_served_from_its_tile_files_one_read_queue_per_stream_server() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pyr = d.join("pyr");
    let prep = Command::new(env!("CARGO_BIN_EXE_clipprep"))
        .args(["--source", "hash", "--size", "4096", "--tile", "64", "--clip", "256", "--format", "rgba8"])
        .args(["--streams", "2", "--out"])
        .arg(&pyr)
        .output()
        .unwrap();
    assert!(prep.status.success(), "clipprep: {}", String::from_utf8_lossy(&prep.stderr));
    let ct = pyr.join("pyr.ct");
    let svc = Service::spawn_with(d, "pyr", &[ct.to_str().unwrap()], &[]);
    svc.wait_ready();
    let out = rust_reader(d, "pyr", &["--drive", "--seconds", "2", "--reads", "1000000000000"]).output().unwrap();
    let (passed, failed) = counts(&out, "reader of the file-backed texture");
    assert_eq!(failed, 0, "{}\n{}", String::from_utf8_lossy(&out.stderr), svc.dump());
    assert!(passed > 100_000, "{passed}");
    let stats = json_reply(&svc.ask("STATS"));
    assert!(stats["engine"]["tiles_read"].as_u64().unwrap() > 0, "{stats}");
    // Tiles are spread over two stream directories: each has its own queue, and both read.
    let streams = stats["streams"].as_array().expect("STATS lists the read queues");
    assert_eq!(streams.len(), 2, "{stats}");
    for q in streams {
        assert!(q["reads_done"].as_u64().unwrap() > 0, "every stream server's queue reads: {stats}");
    }
    assert_eq!(json_reply(&svc.ask("STATUS"))["levels"], 13);
}

#[test]
fn a_cog_is_served_as_it_is() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let tif = Path::new(ROOT).join("tests/fixtures/cog/rgb_512x384.tif");
    let svc = Service::spawn_with(d, "cog", &[tif.to_str().unwrap(), "--clip", "128"], &[]);
    svc.wait_ready();
    assert_eq!(json_reply(&svc.ask("STATUS"))["levels"], 10, "{}", svc.dump());
    let t = Instant::now();
    while json_reply(&svc.ask("STATS"))["engine"]["tiles_read"].as_u64().unwrap() == 0 {
        assert!(t.elapsed() < Duration::from_secs(20), "no tile read\n{}", svc.dump());
        std::thread::sleep(Duration::from_millis(20));
    }
    // A local file reads nothing over the network.
    assert!(json_reply(&svc.ask("STATS"))["remote"].is_null(), "{}", svc.dump());
    // And `cliptex attach` says so: `remote` null, no remote line.
    let v: serde_json::Value = serde_json::from_str(&attach_output(attach(d, "cog", &svc.socket, true))).unwrap();
    assert!(v["remote"].is_null() && v.get("remote").is_some() == cfg!(feature = "remote"), "{v}");
    let text = attach_output(attach(d, "cog", &svc.socket, false));
    assert!(text.contains("level  size") && !text.contains("remote:"), "{text}");
    // A layout it does not serve is refused before anything is created, naming the tag.
    let i32 = Path::new(ROOT).join("tests/fixtures/cog/i32_64x64.tif");
    let out = Command::new(CLIPMAPD).arg(&i32).args(["--shm-dir", d.to_str().unwrap()]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("BitsPerSample (258) / SampleFormat (339) is [32] bits"),
        "{out:?}"
    );
}

#[test]
fn a_renderer_request_is_published_without_waiting_for_the_next_period() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Two ticks a second: a request that waited for the period would wait up to half a second.
    let svc = Service::start(d, "early", &["--tick-hz", "2"]);
    let c = clipmap::shm::Client::attach(d, "early").unwrap();
    let before = json_reply(&svc.ask("STATS"));
    for i in 1..=5i64 {
        let want = [30_000 + 100 * i, 20_000 - 50 * i];
        c.request_centre(want, [0.0, 0.0]);
        let t = Instant::now();
        while c.level_state(0).is_none_or(|s| s.centre != want) {
            assert!(t.elapsed() < Duration::from_secs(10), "request {i} was never published\n{}", svc.dump());
            std::thread::sleep(Duration::from_millis(1));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let after = json_reply(&svc.ask("STATS"));
    let early = after["ticks_on_request"].as_u64().unwrap() - before["ticks_on_request"].as_u64().unwrap();
    assert!(early >= 4, "at most one of 5 requests may coincide with a periodic tick: {after}");
    assert!(after["tick_busy_s"].as_f64().unwrap() > 0.0, "{after}");
    assert!(svc.ask("STATS PROM").starts_with("OK prometheus"));
}

#[test]
fn cliptex_plan_sizes_the_image_caches_as_the_service_maps_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The same texture as `Service::spawn`'s: hash (RGBA8), 65536, clip 256, tiles of 64.
    let _svc = Service::start(d, "planned", &[]);
    let mapped = std::fs::metadata(d.join("clipmap-planned.map")).unwrap().len();
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["plan", "--size", "65536", "--clip", "256", "--tile", "64", "--texel-bytes", "4", "--json"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["image_caches"]["bytes"].as_u64(), Some(mapped), "{j}");
    // Brute force. With `--lookahead 1` (fixed grids): 8 stack levels (65536 down to 512) each a
    // grid of (256/64 + 1 + 1)^2 = 36 tiles of 64^2 texels; 9 pyramid levels (256 down to 1)
    // whole; 4 bytes a texel.
    let tile = 64 * 64 * 4u64;
    let stack = 8 * 36 * tile;
    let pyramid: u64 = (0..9).map(|k| (256u64 >> k) * (256 >> k) * 4).sum();
    let fixed = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args([
            "plan",
            "--size",
            "65536",
            "--clip",
            "256",
            "--tile",
            "64",
            "--texel-bytes",
            "4",
            "--lookahead",
            "1",
            "--json",
        ])
        .output()
        .unwrap();
    let f: serde_json::Value = serde_json::from_slice(&fixed.stdout).unwrap();
    assert_eq!(f["image_caches"]["slot_bytes"].as_u64(), Some(stack + pyramid), "{f}");
    assert_eq!(f["image_caches"]["level0_grid"], serde_json::json!([6, 6]));
    assert_eq!(f["image_caches"]["grids"], "fixed");
    // The service's default (adaptive): level k's grid is 6 + (E >> k) tiles a side (at most its
    // 1024 >> k tiles), with the largest E whose slots fit in twice the fixed grids' bytes.
    let budget = 2 * (stack + pyramid);
    let bytes = |e: u64| (0..8).map(|k| (6 + (e >> k)).min(1024 >> k).pow(2) * tile).sum::<u64>() + pyramid;
    let e = (0..1024u64).take_while(|&e| bytes(e) <= budget).last().unwrap();
    assert!(e > 0);
    assert_eq!(j["image_caches"]["grids"], "adaptive");
    assert_eq!(j["image_caches"]["grid_budget_bytes"].as_u64(), Some(budget), "{j}");
    assert_eq!(j["image_caches"]["slot_bytes"].as_u64(), Some(bytes(e)), "{j}");
    assert_eq!(j["image_caches"]["level0_grid"], serde_json::json!([6 + e, 6 + e]));
    assert_eq!(j["image_caches"]["view_spread"], 0, "{j}");
    // `--view-spread 1024` (docs/VIEWS.md): a service started with it maps exactly what the plan
    // with it says, every stack level's grid ceil((1024 >> k) / 64) tiles wider than one view's
    // (at most its tiles), the pyramid levels whole as before.
    let spread_svc = Service::start(d, "spread", &["--view-spread", "1024"]);
    let spread_mapped = std::fs::metadata(d.join("clipmap-spread.map")).unwrap().len();
    let plan_args = ["plan", "--size", "65536", "--clip", "256", "--tile", "64", "--texel-bytes", "4"];
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(plan_args)
        .args(["--view-spread", "1024", "--json"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s["image_caches"]["bytes"].as_u64(), Some(spread_mapped), "{s}\n{}", spread_svc.dump());
    assert_eq!(s["image_caches"]["view_spread"], 1024, "{s}");
    let widened = |k: u64| ((6 + (e >> k)).min(1024 >> k) + (1024u64 >> k).div_ceil(64)).min(1024 >> k);
    let spread_bytes = (0..8).map(|k| widened(k).pow(2) * tile).sum::<u64>() + pyramid;
    assert_eq!(s["image_caches"]["slot_bytes"].as_u64(), Some(spread_bytes), "{s}");
    assert_eq!(s["image_caches"]["level0_grid"], serde_json::json!([6 + e + 16, 6 + e + 16]), "{s}");
    assert_eq!(s["image_caches"]["views_block_bytes"], j["image_caches"]["views_block_bytes"], "{s}");
    let text =
        Command::new(env!("CARGO_BIN_EXE_cliptex")).args(plan_args).args(["--view-spread", "1024"]).output().unwrap();
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(text.contains("widened for views up to 1024 level-0 texels apart"), "{text}");
    // Views with grids of their own (docs/VIEWS.md, "Views far apart"): each a mapping of one
    // view's grids (never widened) beside the service's, every byte of them as the plan says.
    let own_svc = Service::start(d, "owned", &["--view-spread", "1024", "--view", "a:1:own", "--view", "b:2:own"]);
    let size = |n: &str| std::fs::metadata(d.join(format!("clipmap-{n}.map"))).unwrap().len();
    let all = size("owned") + size("owned@a") + size("owned@b");
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(plan_args)
        .args(["--view-spread", "1024", "--own-views", "2", "--json"])
        .output()
        .unwrap();
    let o: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ic = &o["image_caches"];
    assert_eq!(ic["all_bytes"].as_u64(), Some(all), "{o}\n{}", own_svc.dump());
    assert_eq!((ic["own_views"].as_u64(), ic["own_view_bytes"].as_u64()), (Some(2), Some(mapped)), "{o}");
    assert_eq!((size("owned@a"), ic["bytes"].as_u64()), (mapped, Some(spread_mapped)), "{o}");
    let text = Command::new(env!("CARGO_BIN_EXE_cliptex")).args(plan_args).args(["--own-views", "2"]).output().unwrap();
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(text.contains("2 views with grids of their own: a mapping of"), "{text}");
    // A spread no service takes is refused naming the option and the range.
    let bad = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(plan_args)
        .args(["--view-spread", "1073741825"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(bad.status.code(), Some(1), "{err}");
    assert!(err.contains("--view-spread") && err.contains("1073741825") && err.contains("0..=1073741824"), "{err}");
}

#[test]
fn paging_flags_reach_the_engine_and_the_clamp_and_pool_are_counted_in_stats() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "paging", &["--pool-bytes", "4m", "--eviction", "shift", "--max-centre-step", "16"]);
    assert!(svc.ask("CENTRE 40000 40000").starts_with("OK"));
    // The centre moves at most 16 texels a tick towards the request: clamped on many ticks.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    let stats = loop {
        let stats = json_reply(&svc.ask("STATS"));
        if stats["engine"]["centre_clamps"].as_u64().unwrap_or(0) >= 3 || std::time::Instant::now() > deadline {
            break stats;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let e = &stats["engine"];
    assert!(e["centre_clamps"].as_u64().unwrap() >= 3, "the clamp acts and is counted: {stats}");
    assert_eq!(e["pool"]["budget_bytes"], 4 << 20, "{stats}");
    assert!(e["pool"]["misses"].as_u64().unwrap() > 0, "reads go through the pool: {stats}");
    assert!(e["pool"]["bytes"].as_u64().unwrap() <= 4 << 20, "{stats}");
    assert_eq!(e["tick_texel_bytes"], 0, "{stats}");
}

#[test]
fn a_pool_past_the_memory_limit_is_refused_before_anything_is_created() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let shm = d.join("shm");
    std::fs::create_dir(&shm).unwrap();
    let out = Command::new(CLIPMAPD)
        .args(["--source", "hash", "--size", "65536", "--clip", "256", "--tile", "64", "--name", "big"])
        .args(["--shm-dir", shm.to_str().unwrap(), "--pool-bytes", "4g"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("tile pool's budget included") && err.contains("smaller pool"), "{err}");
    assert_eq!(std::fs::read_dir(&shm).unwrap().count(), 0, "nothing created");
}

/// `cliptex attach NAME --once` against a service in `dir` (its socket given), bounded.
fn attach(dir: &Path, name: &str, socket: &Path, json: bool) -> std::process::Child {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cliptex"));
    c.args(["attach", name, "--shm-dir", dir.to_str().unwrap(), "--once", "--interval", "0.05", "--socket"]);
    c.arg(socket);
    if json {
        c.arg("--json");
    }
    c.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap()
}

fn attach_output(child: std::process::Child) -> String {
    let out = child.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "cliptex attach: {:?}\n{text}\n{}", out.status, String::from_utf8_lossy(&out.stderr));
    text
}

#[test]
fn a_source_that_cannot_keep_up_shows_coarser_levels_only_right_texels_and_says_source_bound() {
    use crate::common::flight::{all_at_rest, fly, reason, wait_stats, Control};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Every tile read takes 40 ms: four reads in flight deliver about 100 tiles a second, where a
    // flight of 6000 texels a second over 64-texel tiles asks for several hundred.
    let svc = Service::start(d, "slow", &["--source-delay-ms", "40"]);
    let reader = rust_reader(d, "slow", &["--reads", "1000000000000", "--seconds", "5"]).spawn().unwrap();
    let mut c = Control::open(&svc.socket);
    let before = c.stats();
    let (mut bound, mut coarse, mut samples) = (0u32, 0u32, 0u32);
    let mut seen = std::collections::BTreeMap::<String, u32>::new();
    let mut during = None;
    fly(&mut c, 32768, (8192, 57344), 6000.0, 3.0, 8, |st, flown| {
        samples += 1;
        let r = reason(st, 0);
        *seen.entry(r.clone()).or_default() += 1;
        bound += u32::from(r == "source_bound");
        coarse += u32::from(st["min_lod"].as_f64().unwrap() > 0.0);
        if during.is_none() && flown > 1.5 {
            during = Some(attach(d, "slow", &svc.socket, true));
        }
    });
    let after = c.stats();
    eprintln!("level 0 reasons over {samples} samples: {seen:?}; min LOD above 0 in {coarse}");
    let ticks = |v: &serde_json::Value| v["engine"]["ticks"].as_u64().unwrap();
    assert!(ticks(&after) > ticks(&before) + 120, "no stall: the tick goes on\n{before}\n{after}");
    assert!(bound * 2 > samples, "level 0 is source-bound on most of the flight: {seen:?}\n{after}");
    assert!(coarse * 2 > samples, "coarser levels are shown on most of the flight: {coarse} of {samples}\n{after}");
    // The latency planned with is measured only from reads asked for while their level was whole
    // (queueing behind a backlog is not a latency a lead cures): here at least the initial tick.
    assert!(after["engine"]["read_latency_ticks"].as_f64().unwrap() >= 1.0, "{after}");
    // One stream server: its latency is the one every level plans with.
    let per_stream = after["engine"]["stream_read_latency_ticks"].as_array().expect("per-stream latency");
    assert_eq!(per_stream.len(), 1, "{after}");
    assert_eq!(per_stream[0], after["engine"]["read_latency_ticks"], "{after}");
    assert_eq!(after["engine"]["paging"][0]["read_latency_ticks"], per_stream[0], "{after}");
    // `cliptex attach` said so too, mid-flight.
    let v: serde_json::Value = serde_json::from_str(&attach_output(during.expect("attached mid-flight"))).unwrap();
    assert!(v["read_latency_ticks"].as_f64().unwrap() >= 1.0, "{v}");
    assert_eq!(v["streams"][0]["read_latency_ticks"], v["read_latency_ticks"], "{v}");
    assert!(v["min_lod"].as_f64().unwrap() > 0.0, "coarser levels shown: {v}");
    let level0 = &v["levels"][0]["paging"];
    assert_eq!(level0["reason"], "source_bound", "{v}");
    assert!(level0["lead_texels"][0].as_u64().unwrap() > 0 && level0["grid"][0].as_u64().unwrap() > 0, "{v}");
    // At rest again: every level hovers, and the finest level comes back.
    let (st, ok) =
        wait_stats(&mut c, Duration::from_secs(20), |st| all_at_rest(st) && st["min_lod"].as_f64() == Some(0.0));
    assert!(ok, "at rest every level hovers and level 0 is shown again: {st}");
    let text = attach_output(attach(d, "slow", &svc.socket, false));
    assert!(text.contains("paging  read latency ") && text.contains("\n0      hover  "), "{text}");
    let out = reader.wait_with_output().unwrap();
    let (passed, failed) = counts(&out, "rust reader");
    assert_eq!(failed, 0, "{failed} wrong texels\n{}\n{}", String::from_utf8_lossy(&out.stderr), svc.dump());
    assert!(passed > 10_000, "only {passed} texels checked");
    // The tick log says when a level's reason changes, not every tick.
    let log = std::fs::read_to_string(&svc.err).unwrap();
    let changes: Vec<&str> = log.lines().filter(|l| l.contains("paging reason changed")).collect();
    assert!(changes.iter().any(|l| l.contains("level=0") && l.contains("reason=\"source_bound\"")), "{log}");
    assert!(changes.iter().any(|l| l.contains("level=0") && l.contains("reason=\"hover\"")), "{log}");
    let ticked = ticks(&c.stats()) as usize;
    // (A line a level a tick would be 17 times the ticks.)
    assert!(changes.len() < ticked, "{} change lines in {ticked} ticks:\n{log}", changes.len());
    eprintln!("{} reason changes logged in {ticked} ticks", changes.len());
}

#[test]
fn a_fast_source_at_a_moderate_speed_keeps_up_with_a_lead_and_hovers_at_rest() {
    use crate::common::flight::{all_at_rest, fly, reason, wait_stats, Control};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "brisk", &[]);
    let reader = rust_reader(d, "brisk", &["--reads", "1000000000000", "--seconds", "3"]).spawn().unwrap();
    let mut c = Control::open(&svc.socket);
    let (st, ok) = wait_stats(&mut c, Duration::from_secs(20), all_at_rest);
    assert!(ok, "at rest every level hovers: {st}");
    let (mut ahead, mut samples) = (0u32, 0u32);
    let mut seen = std::collections::BTreeMap::<String, u32>::new();
    // 1200 texels a second: 10 level-0 texels a tick at 120 ticks a second.
    fly(&mut c, 32768, (8192, 57344), 1200.0, 2.0, 8, |st, flown| {
        if flown < 0.3 {
            return;
        }
        samples += 1;
        let r = reason(st, 0);
        *seen.entry(r.clone()).or_default() += 1;
        ahead += u32::from(r == "keeping_up" && st["engine"]["paging"][0]["lead_texels"][0].as_u64().unwrap() > 0);
    });
    eprintln!("level 0 reasons over {samples} samples: {seen:?}");
    assert!(ahead * 2 > samples, "level 0 keeps up with a lead on most of the flight: {seen:?}");
    let out = reader.wait_with_output().unwrap();
    let (passed, failed) = counts(&out, "rust reader");
    assert_eq!(failed, 0, "{failed} wrong texels\n{}\n{}", String::from_utf8_lossy(&out.stderr), svc.dump());
    assert!(passed > 10_000, "only {passed} texels checked");
}

#[test]
fn a_source_delay_beyond_its_bound_is_refused_with_status_1() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(CLIPMAPD)
        .args(["--source", "hash", "--shm-dir", dir.path().to_str().unwrap(), "--source-delay-ms", "10001"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("--source-delay-ms") && err.contains("10001"), "{err}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "nothing created");
}

#[test]
fn a_window_that_moves_past_the_grids_spare_tiles_in_a_tick_says_beyond_grid_and_shows_only_right_texels() {
    use crate::common::flight::{fly, reason, Control};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The smallest grids (a budget below the lookahead-1 grids gives those): level 0 holds 6
    // tiles an axis, one spare beyond the 5 its window can touch, 64 texels.
    let svc = Service::start(d, "past", &["--grid-budget", "1"]);
    let reader = rust_reader(d, "past", &["--reads", "1000000000000", "--seconds", "3"]).spawn().unwrap();
    let mut c = Control::open(&svc.socket);
    let (mut beyond, mut samples) = (0u32, 0u32);
    let mut seen = std::collections::BTreeMap::<String, u32>::new();
    // 12000 texels a second: 100 level-0 texels a tick at 120 ticks a second, past the spare 64.
    fly(&mut c, 32768, (8192, 57344), 12000.0, 2.0, 8, |st, flown| {
        if flown < 0.3 {
            return;
        }
        samples += 1;
        let r = reason(st, 0);
        *seen.entry(r.clone()).or_default() += 1;
        beyond += u32::from(r == "beyond_grid");
        assert_eq!(st["engine"]["paging"][0]["grid"], serde_json::json!([6, 6]), "{st}");
    });
    eprintln!("level 0 reasons over {samples} samples: {seen:?}");
    assert!(beyond * 2 > samples, "level 0 moves beyond its grid on most of the flight: {seen:?}");
    let out = reader.wait_with_output().unwrap();
    let (passed, failed) = counts(&out, "rust reader");
    assert_eq!(failed, 0, "{failed} wrong texels\n{}\n{}", String::from_utf8_lossy(&out.stderr), svc.dump());
    assert!(passed > 10_000, "only {passed} texels checked");
}

#[test]
fn four_views_fly_at_once_read_by_readers_in_rust_c_and_python_every_texel_right() {
    // Four views of one service (docs/VIEWS.md): `main`; `near`, added on the command line and
    // driven through its own request record by a Rust reader; `far`, added on the socket and
    // moved far away (the shared grids cannot hold it whole: it shows coarser levels, never a
    // wrong texel); `stereo`, on main's centre. A Rust, a C and a Python reader each read one view
    // while the views move; a fifth view is added mid-flight, read and removed.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "views", &["--budget-ms", "2", "--view", "near:3", "--view-spread", "256"]);
    let map = d.join("clipmap-views.map");
    let creader = c_reader(d);
    assert!(svc.ask("VIEW ADD far 1").starts_with("OK view far added"));
    assert!(svc.ask("VIEW ADD stereo").starts_with("OK"));
    assert!(svc.ask("VIEW CENTRE far 60000 3000").starts_with("OK view far centre 60000 3000"));
    assert!(svc.ask("VIEW ADD near").contains("exists already"), "names are unique");
    assert!(svc.ask("VIEW REMOVE nobody").contains("no view `nobody`: the views are main, near, far, stereo"));
    assert!(svc.ask("VIEW ADD main").starts_with("ERR"), "main is the primary's name");
    let secs = "3";
    let readers: Vec<(String, Child)> = vec![
        (
            "rust main (driving)".into(),
            rust_reader(d, "views", &["--drive", "--reads", "1000000000000", "--seconds", secs]).spawn().unwrap(),
        ),
        (
            "rust near (driving near)".into(),
            rust_reader(d, "views", &["--view", "near", "--drive", "--reads", "1000000000000", "--seconds", secs])
                .spawn()
                .unwrap(),
        ),
        (
            "c far".into(),
            Command::new(&creader)
                .arg(&map)
                .args(["1000000000000", "5", secs, "--view", "far"])
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap(),
        ),
        (
            "python stereo".into(),
            python_reader().arg(&map).args(["1000000000000", "7", secs, "--view", "stereo"]).spawn().unwrap(),
        ),
    ];
    // Mid-flight: a fifth view comes, is read, and goes.
    std::thread::sleep(Duration::from_millis(700));
    assert!(svc.ask("VIEW ADD late 2").starts_with("OK"));
    assert!(svc.ask("VIEW CENTRE late 20000 20000").starts_with("OK"));
    let late =
        rust_reader(d, "views", &["--view", "late", "--reads", "1000000000000", "--seconds", "1"]).output().unwrap();
    let (late_passed, late_failed) = counts(&late, "rust late");
    assert_eq!(late_failed, 0, "late: {}", String::from_utf8_lossy(&late.stderr));
    assert!(svc.ask("VIEW REMOVE late").starts_with("OK view late removed"));
    let gone = rust_reader(d, "views", &["--view", "late", "--seconds", "1"]).output().unwrap();
    assert!(!gone.status.success() && String::from_utf8_lossy(&gone.stderr).contains("no view `late`"));
    let mut total = late_passed;
    for (what, child) in readers {
        let out = child.wait_with_output().unwrap();
        let (passed, failed) = counts(&out, &what);
        assert_eq!(failed, 0, "{what}: {failed} mismatches\n{}\n{}", String::from_utf8_lossy(&out.stderr), svc.dump());
        assert!(out.status.success(), "{what}: {:?}\n{}", out.status, String::from_utf8_lossy(&out.stderr));
        assert!(passed > 1_000, "{what}: only {passed} texels checked");
        total += passed;
    }
    eprintln!("five views: {total} texels checked, none wrong");
    let stats = json_reply(&svc.ask("STATS"));
    assert_eq!(stats["engine"]["slots_reassigned_under_published"], 0, "{stats}");
    assert_eq!(stats["engine"]["slots_reassigned_under_views"], 0, "{stats}");
    let views: Vec<&str> = stats["views"].as_array().unwrap().iter().map(|v| v["name"].as_str().unwrap()).collect();
    assert_eq!(views, ["main", "near", "far", "stereo"], "{stats}");
    let list = json_reply(&svc.ask("VIEWS"));
    let near = &list[1];
    assert_eq!(near["weight"], 3.0);
    assert_ne!(near["centre"], list[0]["centre"], "near follows its own requests, not main's: {list}");
    let far = &list[2];
    assert!(far["min_lod"].as_f64().unwrap() >= 1.0, "far is not held whole at level 0: {list}");
    // `cliptex attach --view` shows one view's levels and every view's figures.
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["attach", "views", "--view", "near", "--json", "--shm-dir", d.to_str().unwrap(), "--socket"])
        .arg(d.join("views.sock"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let st: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(st["view"], "near");
    let names: Vec<&str> = st["views"].as_array().unwrap().iter().map(|v| v["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["main", "near", "far", "stereo"], "{st}");
    let bad = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["attach", "views", "--view", "nobody", "--json", "--shm-dir", d.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("no view `nobody`"));
}

#[test]
fn the_c_and_python_readers_read_views_of_the_independent_fixture_mappings() {
    // The views block written by an independent writer (tests/fixtures/make_mapping.py --view):
    // each view's snapshot and texels read exactly, every corrupt variant refused naming its
    // field, unknown and removed views reported, view requests landing in their records.
    let out = tempfile::tempdir().unwrap();
    let run = Command::new("bash")
        .arg(Path::new(ROOT).join("tests/fixtures/check_views.sh"))
        .arg(out.path())
        .arg("--no-asan")
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "stdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    );
}

#[test]
fn a_virtual_view_follows_its_height_reads_no_finer_level_and_every_texel_is_right() {
    // docs/VIEWS.md, "Virtual views": `high` asks through its request record for the levels it
    // can use 12000 texels above the texture with a pixel of 1 mrad (12 texels a pixel: LOD 3.58,
    // offset 3); `main` is bounded on the socket. Every texel read is right, and neither view
    // publishes a level outside its window.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "virt", &["--budget-ms", "2", "--view", "high"]);
    let out = rust_reader(
        d,
        "virt",
        &["--view", "high", "--lod", "12000,0.001", "--reads", "1000000000000", "--seconds", "2"],
    )
    .output()
    .unwrap();
    let (passed, failed) = counts(&out, "rust high");
    assert_eq!(failed, 0, "{}\n{}", String::from_utf8_lossy(&out.stderr), svc.dump());
    assert!(passed > 1000, "only {passed} texels checked");
    let stats = json_reply(&svc.ask("STATS"));
    let high = &stats["views"][1];
    assert_eq!(high["name"], "high");
    assert_eq!(high["lod_offset"], 3, "{high}");
    assert!(high["min_lod"].as_f64().unwrap() >= 3.0, "{high}");
    for k in 0..3 {
        assert_eq!(high["valid"][k], serde_json::json!([0, 0, 0, 0]), "level {k} is finer than high shows: {high}");
    }
    let resident: Vec<u64> = high["resident_levels"].as_array().unwrap().iter().map(|x| x.as_u64().unwrap()).collect();
    assert!(!resident.is_empty() && resident.iter().all(|&k| k >= 3), "{high}");
    assert!(stats["lod_requests"].as_u64().unwrap() >= 1, "{stats}");
    assert_eq!(stats["lod_requests_refused"], 0);

    // The C reader asks through its request record (100 texels up, 0.1 texel a pixel: offset 0),
    // then Python through the socket (40000 up: 40 texels a pixel, LOD 5.3: offset 4).
    let creader = c_reader(d);
    let map = d.join("clipmap-virt.map");
    let out = Command::new(&creader)
        .arg(&map)
        .args(["1000000000000", "5", "1", "--view", "high", "--lod", "100,0.001"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stats = json_reply(&svc.ask("STATS"));
    assert_eq!(stats["views"][1]["lod_offset"], 0, "C's LOD request: {}", stats["views"][1]);
    let py = Command::new("python3")
        .arg("-c")
        .arg(format!(
            "import sys; sys.path.insert(0, {:?}); import clipmap_shm as c; print(c.request_lod({:?}, 40000, 0.001, view='high'))",
            Path::new(ROOT).join("clients/python").to_str().unwrap(),
            d.join("virt.sock").to_str().unwrap()
        ))
        .output()
        .unwrap();
    let reply = String::from_utf8_lossy(&py.stdout);
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    assert_eq!(reply.trim(), "OK view high lod offset 4 effective all");
    let bad = svc.ask("VIEW HEIGHT high 100 7");
    assert!(bad.contains("pixel angle `7`: expected a finite number above 0 and below pi"), "{bad}");

    // The socket: main shows levels 2 and coarser (addressing 4 at once: the coarser ones stay
    // published, each a clip-size square at most, for the readers' fallback); a bad offset is
    // refused naming the range.
    let levels = stats["views"][0]["valid"].as_array().unwrap().len();
    assert_eq!(svc.ask("VIEW LOD main 2 4"), "OK view main lod offset 2 effective 4");
    assert!(
        svc.ask(&format!("VIEW LOD high {levels}")).contains(&format!("expected 0 to {}", levels - 1)),
        "offsets past the coarsest level are refused"
    );
    assert!(svc.ask("VIEW LOD nobody 1").contains("no view `nobody`"));
    let out = rust_reader(d, "virt", &["--reads", "1000000000000", "--seconds", "1"]).output().unwrap();
    let (passed, failed) = counts(&out, "rust main");
    assert!(failed == 0 && passed > 1000, "{passed} passed, {failed} failed");
    let stats = json_reply(&svc.ask("STATS"));
    let main = &stats["views"][0];
    assert_eq!((main["lod_offset"].as_u64(), main["effective_levels"].as_u64()), (Some(2), Some(4)), "{main}");
    for k in 0..2 {
        assert_eq!(main["valid"][k], serde_json::json!([0, 0, 0, 0]), "level {k} is finer than main shows: {main}");
    }
    assert!((2..levels).all(|k| main["valid"][k] != serde_json::json!([0, 0, 0, 0])), "{main}");
    assert_eq!(stats["engine"]["slots_reassigned_under_published"], 0, "{stats}");
    assert_eq!(stats["engine"]["slots_reassigned_under_views"], 0, "{stats}");
    // `cliptex attach` shows each view's levels and those resident.
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["attach", "virt", "--shm-dir", d.to_str().unwrap(), "--socket"])
        .arg(d.join("virt.sock"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("LOD window    resident"), "{text}");
    assert!(text.lines().any(|l| l.starts_with("main") && l.contains("2..5")), "{text}");
    assert!(text.lines().any(|l| l.starts_with("high") && l.contains(&format!("4..{}", levels - 1))), "{text}");
}
