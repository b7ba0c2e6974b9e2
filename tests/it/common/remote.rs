//! Servers on loopback for the remote-tile tests: Debian's `nginx` serving a directory (range
//! requests), an S3-compatible server (`moto[server]` from PyPI), and a fault-injecting HTTP
//! proxy put in front of either. `.ci/run` installs nginx and moto; a test that needs one that
//! is missing fails saying what to install.
#![allow(dead_code)]

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A free loopback port (bound, then released for the server to take).
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// Starts a server with `spawn(port)` on a free loopback port and waits (30 s at most) until it
/// listens: the port comes back once it listens and the server still runs. A port is free only
/// until the server binds it (another process may take it between), so a server that ends
/// before it listens is started again on another port, five times at most.
fn start_listening(what: &str, log: &Path, mut spawn: impl FnMut(u16) -> Child) -> (Child, u16) {
    for _ in 0..5 {
        let port = free_port();
        let mut child = spawn(port);
        let t = Instant::now();
        loop {
            if let Some(status) = child.try_wait().unwrap() {
                eprintln!("{what} ended ({status}) before it listened on port {port}; again on another port");
                break;
            }
            if TcpStream::connect(("127.0.0.1", port)).is_ok() && child.try_wait().unwrap().is_none() {
                return (child, port);
            }
            if t.elapsed() > Duration::from_secs(30) {
                let _ = child.kill();
                let _ = child.wait();
                panic!(
                    "{what} did not listen on port {port} within 30 s; its log:\n{}",
                    std::fs::read_to_string(log).unwrap_or_default()
                );
            }
            std::thread::sleep(Duration::from_millis(25));
        }
    }
    panic!(
        "{what} ended five times before it listened; its log:\n{}",
        std::fs::read_to_string(log).unwrap_or_default()
    );
}

fn find_program(names: &[&str], install: &str) -> PathBuf {
    for n in names {
        let p = Path::new(n);
        if p.is_absolute() && p.exists() {
            return p.to_path_buf();
        }
        if let Some(path) = std::env::var_os("PATH") {
            for d in std::env::split_paths(&path) {
                let c = d.join(n);
                if c.is_file() {
                    return c;
                }
            }
        }
    }
    panic!("{} is needed for this test and was not found: {install} (.ci/run does it)", names[0]);
}

/// `nginx` serving `root` on a loopback port; stopped on drop.
pub struct Nginx {
    child: Child,
    /// Its port.
    pub port: u16,
    dir: tempfile::TempDir,
}

impl Nginx {
    /// Starts nginx (one process, no daemon, everything under a temporary directory).
    pub fn serve(root: &Path) -> Nginx {
        Nginx::serve_with(root, "")
    }

    /// Like [`Nginx::serve`], answering images with their types (`image/png`, `image/jpeg`,
    /// `image/webp`) and `.html` as `text/html`, as a tile server does (the others: `text/plain`).
    pub fn serve_images(root: &Path) -> Nginx {
        Nginx::serve_with(root, "types { image/png png; image/jpeg jpg jpeg; image/webp webp; text/html html; }")
    }

    /// Like [`Nginx::serve`], and files may be written with HTTP PUT (the DAV module).
    pub fn serve_writable(root: &Path) -> Nginx {
        Nginx::serve_with(root, "dav_methods PUT; create_full_put_path on; client_max_body_size 0;")
    }

    /// Like [`Nginx::serve`], speaking HTTP/2 only: with prior knowledge (h2c) on plain HTTP,
    /// or offered by ALPN over TLS with `tls`'s certificate and key (PEM files). Every request
    /// is logged ([`Nginx::requests`]) with its connection and protocol.
    pub fn serve_h2(root: &Path, tls: Option<(&Path, &Path)>) -> Nginx {
        let (listen, server) = match tls {
            None => ("http2".to_string(), String::new()),
            Some((cert, key)) => (
                "ssl http2".to_string(),
                format!("ssl_certificate {};\n    ssl_certificate_key {};\n", cert.display(), key.display()),
            ),
        };
        Nginx::start(root, &listen, &server, "", true)
    }

    /// Like [`Nginx::serve`], and every request is logged ([`Nginx::requests`]).
    pub fn serve_logged(root: &Path) -> Nginx {
        Nginx::start(root, "", "", "", true)
    }

    fn serve_with(root: &Path, location: &str) -> Nginx {
        Nginx::start(root, "", "", location, false)
    }

    /// nginx with extra `listen` parameters, server directives and location directives; with
    /// an access log of each request's connection, protocol and status if `log`.
    fn start(root: &Path, listen: &str, server: &str, location: &str, log: bool) -> Nginx {
        let exe = find_program(&["nginx", "/usr/sbin/nginx"], "install Debian's nginx: apt-get install nginx");
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        for sub in ["body", "proxy", "fastcgi", "uwsgi", "scgi"] {
            std::fs::create_dir_all(d.join(sub)).unwrap();
        }
        let access = if log {
            format!("log_format conns '$connection $connection_requests $server_protocol $status';\n  access_log {}/access.log conns;", d.display())
        } else {
            "access_log off;".to_string()
        };
        let conf = |port: u16| {
            format!(
                "daemon off;\nmaster_process off;\nworker_processes 1;\npid {d}/nginx.pid;\nerror_log {d}/error.log warn;\n\
                 events {{ worker_connections 512; }}\n\
                 http {{\n  {access}\n  client_body_temp_path {d}/body;\n  proxy_temp_path {d}/proxy;\n  fastcgi_temp_path {d}/fastcgi;\n  uwsgi_temp_path {d}/uwsgi;\n  scgi_temp_path {d}/scgi;\n  keepalive_requests 100000;\n  sendfile on;\n  tcp_nodelay on;\n\
                   server {{\n    listen 127.0.0.1:{port} {listen};\n    {server}root {root};\n    location / {{ {location} }}\n  }}\n}}\n",
                d = d.display(),
                root = root.display()
            )
        };
        let log = d.join("stderr.log");
        let (child, port) = start_listening("nginx", &d.join("error.log"), |port| {
            std::fs::write(d.join("nginx.conf"), conf(port)).unwrap();
            Command::new(&exe)
                .args(["-p", d.to_str().unwrap(), "-e", d.join("error.log").to_str().unwrap(), "-c"])
                .arg(d.join("nginx.conf"))
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(&log).unwrap())
                .spawn()
                .expect("nginx starts")
        });
        Nginx { child, port, dir }
    }

    /// `http://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// The requests logged so far (a server started with a log): connection serial number,
    /// requests on it so far, protocol (`HTTP/1.1`, `HTTP/2.0`) and status.
    pub fn requests(&self) -> Vec<(u64, u64, String, u16)> {
        let log = std::fs::read_to_string(self.dir.path().join("access.log")).unwrap_or_default();
        log.lines()
            .map(|l| {
                let f: Vec<&str> = l.split(' ').collect();
                assert_eq!(f.len(), 4, "an access log line: {l}");
                (f[0].parse().unwrap(), f[1].parse().unwrap(), f[2].to_string(), f[3].parse().unwrap())
            })
            .collect()
    }
}

impl Drop for Nginx {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// An S3-compatible server (`moto[server]`) on a loopback port; stopped on drop.
pub struct Moto {
    child: Child,
    /// Its port.
    pub port: u16,
    log: PathBuf,
    _dir: tempfile::TempDir,
}

impl Moto {
    /// Starts `moto_server` (or `python3 -m moto.server`).
    pub fn start() -> Moto {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("moto.log");
        let python = find_program(&["python3"], "install python3");
        let ok = Command::new(&python)
            .args(["-c", "import moto.server"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "moto is needed for this test and was not found: pip install 'moto[server]' (.ci/run does it)");
        let err = dir.path().join("moto.err");
        let (child, port) = start_listening("moto", &err, |port| {
            Command::new(&python)
                .args(["-m", "moto.server", "-H", "127.0.0.1", "-p", &port.to_string()])
                .stdout(std::fs::File::create(&log).unwrap())
                .stderr(std::fs::File::create(&err).unwrap())
                .spawn()
                .expect("moto starts")
        });
        Moto { child, port, log: err, _dir: dir }
    }

    /// `http://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// The `AWS_*` variables that point a client at this server.
    pub fn env(&self) -> Vec<(String, String)> {
        vec![
            ("AWS_ACCESS_KEY_ID".into(), "testing-key-id".into()),
            ("AWS_SECRET_ACCESS_KEY".into(), "testing-secret-never-printed".into()),
            ("AWS_REGION".into(), "us-east-1".into()),
            ("AWS_ENDPOINT_URL".into(), self.url()),
        ]
    }

    /// Makes a bucket (S3 `CreateBucket`, which moto accepts unsigned).
    pub fn create_bucket(&self, bucket: &str) {
        let mut s = TcpStream::connect(("127.0.0.1", self.port)).unwrap();
        write!(
            s,
            "PUT /{bucket} HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n",
            self.port
        )
        .unwrap();
        let mut reply = String::new();
        s.read_to_string(&mut reply).unwrap();
        assert!(reply.starts_with("HTTP/1.1 200"), "CreateBucket {bucket}: {reply}");
    }
}

impl Drop for Moto {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// What the fault proxy does to one request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// Forwards it untouched.
    Pass,
    /// Answers 404 itself.
    NotFound,
    /// Answers 500 itself.
    ServerError,
    /// Answers 503 with `Retry-After: 1`.
    Unavailable,
    /// Forwards it after this many milliseconds.
    Slow(u64),
    /// Closes the connection without an answer (a reset).
    Reset,
    /// Forwards the head and half the body, then closes.
    Truncate,
    /// Forwards the answer with a `Content-Length` larger than its body, then closes.
    LongLength,
    /// Forwards the answer with a `Content-Length` smaller than its body.
    ShortLength,
    /// Answers a GET itself with `200 OK` and a page of `len` bytes, of type `text/html` when
    /// `html` (an error page of a proxy or a misconfigured server), else
    /// `application/octet-stream`; a HEAD is forwarded.
    Page {
        /// The page's length.
        len: usize,
        /// Sent as `text/html`.
        html: bool,
    },
    /// Forwards a GET without its `Range` header, so that the server answers `200 OK` with the
    /// whole object (a server that ignores ranges).
    IgnoreRange,
    /// Forwards a GET asking for the range one byte further on, so that the server answers
    /// `206` for a range that was not asked for.
    OtherRange,
    /// Answers `204 No Content` itself.
    NoContent,
    /// Answers `429 Too Many Requests` with `Retry-After: 1` itself.
    TooMany,
    /// Answers `200 OK` with an empty body of type `image/png` itself.
    EmptyOk,
    /// Forwards the answer with its body cut to half and a `Content-Length` that says so: a
    /// whole answer of a truncated file.
    HalfBody,
}

/// The proxy's schedule: request `i` (from 0) gets `faults[i]` while `i < faults.len()`, then
/// `then` (every `every`-th request, the others pass).
#[derive(Clone, Debug)]
pub struct Schedule {
    /// The first requests' faults, in order.
    pub faults: Vec<Fault>,
    /// Faults after those, in rotation, applied to every `every`-th request.
    pub then: Vec<Fault>,
    /// See `then` (0: pass everything after `faults`).
    pub every: u64,
}

impl Schedule {
    /// Every request passes.
    pub fn pass() -> Schedule {
        Schedule { faults: Vec::new(), then: Vec::new(), every: 0 }
    }

    fn fault(&self, i: u64) -> Fault {
        if let Some(f) = self.faults.get(i as usize) {
            return *f;
        }
        let j = i - self.faults.len() as u64;
        if self.every == 0 || self.then.is_empty() || !j.is_multiple_of(self.every) {
            return Fault::Pass;
        }
        self.then[((j / self.every) % self.then.len() as u64) as usize]
    }
}

/// A loopback HTTP proxy in front of `upstream` that injects faults (and an optional delay on
/// every request); one connection per request (`Connection: close`). Stops on drop.
pub struct FaultProxy {
    /// Its port.
    pub port: u16,
    /// Requests seen.
    pub requests: Arc<AtomicU64>,
    /// Faults injected, by kind.
    pub injected: Arc<Mutex<Vec<Fault>>>,
    /// Requests being answered now, and the most there were at once.
    pub in_flight: Arc<InFlight>,
    /// Each request's arrival, path and fault, in order of arrival.
    pub seen: Arc<Mutex<Vec<(Instant, String, Fault)>>>,
    schedule: Arc<Mutex<Schedule>>,
    stop: Arc<AtomicBool>,
}

impl FaultProxy {
    /// A proxy to `127.0.0.1:upstream` following `schedule`, delaying every request by
    /// `delay_ms`.
    pub fn start(upstream: u16, schedule: Schedule, delay_ms: u64) -> FaultProxy {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        let requests = Arc::new(AtomicU64::new(0));
        let injected = Arc::new(Mutex::new(Vec::new()));
        let schedule = Arc::new(Mutex::new(schedule));
        let stop = Arc::new(AtomicBool::new(false));
        let in_flight = Arc::new(InFlight::default());
        let seen = Arc::new(Mutex::new(Vec::new()));
        {
            let (requests, injected, schedule, stop, in_flight, seen) =
                (requests.clone(), injected.clone(), schedule.clone(), stop.clone(), in_flight.clone(), seen.clone());
            std::thread::spawn(move || {
                for conn in listener.incoming() {
                    if stop.load(Ordering::SeqCst) {
                        break;
                    }
                    let Ok(conn) = conn else { continue };
                    let (requests, injected, schedule, in_flight, seen) =
                        (requests.clone(), injected.clone(), schedule.clone(), in_flight.clone(), seen.clone());
                    std::thread::spawn(move || {
                        let tally = Tally { in_flight: &in_flight, seen: &seen };
                        let _ = serve(conn, upstream, delay_ms, &requests, &injected, &schedule, &tally);
                    });
                }
            });
        }
        FaultProxy { port, requests, injected, in_flight, seen, schedule, stop }
    }

    /// `http://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// Replaces the schedule (its request numbers count from the requests seen so far).
    pub fn set(&self, mut schedule: Schedule) {
        let seen = self.requests.load(Ordering::SeqCst) as usize;
        let mut faults = vec![Fault::Pass; seen];
        faults.append(&mut schedule.faults);
        schedule.faults = faults;
        *self.schedule.lock().unwrap() = schedule;
    }
}

impl Drop for FaultProxy {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        let _ = TcpStream::connect(("127.0.0.1", self.port));
    }
}

/// The requests a proxy is answering at once.
#[derive(Debug, Default)]
pub struct InFlight {
    /// Now.
    pub now: AtomicU64,
    /// The most at once so far.
    pub peak: AtomicU64,
}

/// Where one connection's request is counted.
struct Tally<'a> {
    in_flight: &'a InFlight,
    seen: &'a Mutex<Vec<(Instant, String, Fault)>>,
}

/// A request counted in flight until dropped.
struct Counted<'a>(&'a InFlight);

impl Drop for Counted<'_> {
    fn drop(&mut self) {
        self.0.now.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Reads one request head (and its body, by Content-Length) from `r`.
fn read_request(r: &mut BufReader<TcpStream>) -> std::io::Result<Option<Vec<u8>>> {
    let mut head = Vec::new();
    let mut len = 0usize;
    loop {
        let mut line = String::new();
        if r.read_line(&mut line)? == 0 {
            return Ok(None);
        }
        if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
            len = v.trim().parse().unwrap_or(0);
        }
        let lower = line.to_ascii_lowercase();
        if lower.starts_with("connection:") {
            continue;
        }
        if line == "\r\n" {
            head.extend_from_slice(b"Connection: close\r\n\r\n");
            break;
        }
        head.extend_from_slice(line.as_bytes());
    }
    let mut body = vec![0u8; len];
    r.read_exact(&mut body)?;
    head.extend_from_slice(&body);
    Ok(Some(head))
}

fn serve(
    conn: TcpStream,
    upstream: u16,
    delay_ms: u64,
    requests: &AtomicU64,
    injected: &Mutex<Vec<Fault>>,
    schedule: &Mutex<Schedule>,
    tally: &Tally,
) -> std::io::Result<()> {
    let mut r = BufReader::new(conn.try_clone()?);
    let mut out = conn;
    let Some(req) = read_request(&mut r)? else { return Ok(()) };
    let now = tally.in_flight.now.fetch_add(1, Ordering::SeqCst) + 1;
    tally.in_flight.peak.fetch_max(now, Ordering::SeqCst);
    // Released just before the answer is written: the client frees its slot once the answer
    // has come, which may be before this thread has returned, so a later count could otherwise
    // see one request too many at once.
    let mut counted = Some(Counted(tally.in_flight));
    let i = requests.fetch_add(1, Ordering::SeqCst);
    let fault = schedule.lock().unwrap().fault(i);
    if fault != Fault::Pass {
        injected.lock().unwrap().push(fault);
    }
    let path = String::from_utf8_lossy(&req).split_whitespace().nth(1).unwrap_or_default().to_string();
    tally.seen.lock().unwrap().push((Instant::now(), path, fault));
    if delay_ms > 0 {
        std::thread::sleep(Duration::from_millis(delay_ms));
    }
    let canned = |status: &str, extra: &str| {
        format!("HTTP/1.1 {status}\r\nContent-Length: 0\r\n{extra}Connection: close\r\n\r\n").into_bytes()
    };
    if matches!(
        fault,
        Fault::NotFound
            | Fault::ServerError
            | Fault::Unavailable
            | Fault::NoContent
            | Fault::TooMany
            | Fault::EmptyOk
            | Fault::Reset
            | Fault::Page { .. }
    ) {
        counted.take();
    }
    match fault {
        Fault::NotFound => return out.write_all(&canned("404 Not Found", "")),
        Fault::ServerError => return out.write_all(&canned("500 Internal Server Error", "")),
        Fault::Unavailable => return out.write_all(&canned("503 Service Unavailable", "Retry-After: 1\r\n")),
        Fault::NoContent => return out.write_all(&canned("204 No Content", "")),
        Fault::TooMany => return out.write_all(&canned("429 Too Many Requests", "Retry-After: 1\r\n")),
        Fault::EmptyOk => return out.write_all(&canned("200 OK", "Content-Type: image/png\r\n")),
        Fault::Reset => {
            // Closed with the request unread past its head: no answer at all.
            return out.shutdown(Shutdown::Both);
        }
        Fault::Slow(ms) => std::thread::sleep(Duration::from_millis(ms)),
        Fault::Page { len, html } if req.starts_with(b"GET ") => {
            let kind = if html { "text/html" } else { "application/octet-stream" };
            let mut page = b"<html><head><title>502 Bad Gateway</title></head><body>".to_vec();
            page.resize(len, b' ');
            out.write_all(
                format!(
                    "HTTP/1.1 200 OK\r\nContent-Type: {kind}\r\nContent-Length: {len}\r\nConnection: close\r\n\r\n"
                )
                .as_bytes(),
            )?;
            out.write_all(&page)?;
            out.flush()?;
            return out.shutdown(Shutdown::Write);
        }
        _ => {}
    }
    let req = match fault {
        Fault::IgnoreRange | Fault::OtherRange if req.starts_with(b"GET ") => rewrite_range(&req, fault),
        _ => req,
    };
    let mut up = TcpStream::connect(("127.0.0.1", upstream))?;
    up.write_all(&req)?;
    let mut resp = Vec::new();
    up.read_to_end(&mut resp)?;
    let split = resp.windows(4).position(|w| w == b"\r\n\r\n").map_or(resp.len(), |p| p + 4);
    let (head, body) = resp.split_at(split);
    let head = String::from_utf8_lossy(head).into_owned();
    let rewrite_length = |n: usize| -> String {
        head.lines()
            .map(|l| {
                if l.to_ascii_lowercase().starts_with("content-length:") {
                    format!("Content-Length: {n}")
                } else {
                    l.to_string()
                }
            })
            .collect::<Vec<_>>()
            .join("\r\n")
    };
    counted.take();
    match fault {
        Fault::Truncate => {
            out.write_all(head.as_bytes())?;
            out.write_all(&body[..body.len() / 2])?;
        }
        Fault::LongLength => {
            out.write_all(rewrite_length(body.len() + 100).as_bytes())?;
            out.write_all(body)?;
        }
        Fault::ShortLength => {
            out.write_all(rewrite_length(body.len().saturating_sub(10)).as_bytes())?;
            out.write_all(body)?;
        }
        Fault::HalfBody => {
            // `rewrite_length` leaves out the blank line that ends the head.
            out.write_all(format!("{}\r\n", rewrite_length(body.len() / 2)).as_bytes())?;
            out.write_all(&body[..body.len() / 2])?;
        }
        _ => {
            out.write_all(head.as_bytes())?;
            out.write_all(body)?;
        }
    }
    out.flush()?;
    out.shutdown(Shutdown::Write)
}

/// A GET's head without its `Range` line ([`Fault::IgnoreRange`]) or with the range moved one
/// byte on ([`Fault::OtherRange`]).
fn rewrite_range(req: &[u8], fault: Fault) -> Vec<u8> {
    let text = String::from_utf8_lossy(req);
    let mut out = String::new();
    for line in text.split_inclusive("\r\n") {
        let lower = line.to_ascii_lowercase();
        let Some(spec) = lower.strip_prefix("range: bytes=") else {
            out.push_str(line);
            continue;
        };
        if fault == Fault::OtherRange {
            let (a, b) = spec.trim().split_once('-').unwrap();
            let (a, b): (u64, u64) = (a.parse().unwrap(), b.parse().unwrap());
            out.push_str(&format!("Range: bytes={}-{}\r\n", a + 1, b + 1));
        }
    }
    out.into_bytes()
}

/// Writes the configuration of the pyramid prepared in `src` into `dst`, every tile read from
/// `base` (and stream server i from `stream_bases[i % len]`); returns the `.ct`.
pub fn point_config_at(src: &Path, dst: &Path, base: &str, stream_bases: &[String]) -> PathBuf {
    clipmap::prep::publish::write_pointed_config(src, dst, base, stream_bases).expect("the configuration is rewritten")
}

/// A static-file HTTP server in Python (`http.server`) on a loopback port that logs every
/// request (`METHOD PATH-WITH-QUERY RANGE`) to a file and answers `Range` only when asked to:
/// without ranges it answers every GET `200` with the whole file, as some servers do. An `ETag`
/// names the file's version. Stopped on drop.
pub struct PyServer {
    child: Child,
    /// Its port.
    pub port: u16,
    dir: tempfile::TempDir,
}

const PY_SERVER: &str = r#"
import http.server, os, sys, urllib.parse
root, port, log, ranges = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4] == "ranges"
class H(http.server.BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    def log_message(self, *a):
        pass
    def answer(self, body):
        with open(log, "a") as f:
            f.write("%s %s %s\n" % (self.command, self.path, self.headers.get("Range", "-")))
        path = os.path.join(root, urllib.parse.unquote(urllib.parse.urlsplit(self.path).path).lstrip("/"))
        if not os.path.isfile(path):
            self.send_response(404); self.send_header("Content-Length", "0"); self.end_headers(); return
        data = open(path, "rb").read()
        st = os.stat(path)
        status, start, end = 200, 0, len(data)
        r = self.headers.get("Range")
        if ranges and r and r.startswith("bytes="):
            a, b = r[6:].split("-")
            start, end = int(a), min(int(b) + 1, len(data))
            status = 206
        self.send_response(status)
        self.send_header("Content-Type", "image/tiff")
        self.send_header("ETag", '"%x-%x"' % (st.st_mtime_ns, st.st_size))
        self.send_header("Content-Length", str(end - start))
        if status == 206:
            self.send_header("Content-Range", "bytes %d-%d/%d" % (start, end - 1, len(data)))
        self.end_headers()
        if body:
            self.wfile.write(data[start:end])
    def do_GET(self):
        self.answer(True)
    def do_HEAD(self):
        self.answer(False)
http.server.ThreadingHTTPServer(("127.0.0.1", port), H).serve_forever()
"#;

impl PyServer {
    /// Serves `root`; `ranges` says whether `Range` is answered (`206`) or ignored (`200`).
    pub fn serve(root: &Path, ranges: bool) -> PyServer {
        let dir = tempfile::tempdir().unwrap();
        let err = dir.path().join("stderr.log");
        let (child, port) = start_listening("python3 http.server", &err, |port| {
            Command::new("python3")
                .args(["-c", PY_SERVER])
                .arg(root)
                .arg(port.to_string())
                .arg(dir.path().join("requests.log"))
                .arg(if ranges { "ranges" } else { "whole" })
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(&err).unwrap())
                .spawn()
                .expect("python3 runs")
        });
        PyServer { child, port, dir }
    }

    /// `http://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// The requests so far, one `METHOD PATH RANGE` line each.
    pub fn requests(&self) -> Vec<String> {
        std::fs::read_to_string(self.dir.path().join("requests.log"))
            .unwrap_or_default()
            .lines()
            .map(str::to_string)
            .collect()
    }
}

impl Drop for PyServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
