//! Loopback servers the remote benchmarks share (`clipbench remote`, `clipbench cog`): nginx
//! serving a directory (optionally logging every request), and an HTTP relay in front of it that
//! can add latency and inject faults.

use clipmap::source::procedural::splitmix64;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A child process killed (and waited for) on drop.
pub struct Killed(pub Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A loopback port free now.
pub fn free_port() -> anyhow::Result<u16> {
    Ok(TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// Waits up to 30 s for `what` to accept connections on `port`.
pub fn wait_port(port: u16, what: &str) -> anyhow::Result<()> {
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(30) {
        if TcpStream::connect(("127.0.0.1", port)).is_ok() {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(25));
    }
    anyhow::bail!("{what} did not listen on port {port} within 30 s")
}

/// The first of `names` found: an absolute path that is a file, or a name on `PATH`.
pub fn program(names: &[&str]) -> Option<PathBuf> {
    for n in names {
        let p = Path::new(n);
        if p.is_absolute() && p.is_file() {
            return Some(p.to_path_buf());
        }
        for d in std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default()) {
            if d.join(n).is_file() {
                return Some(d.join(n));
            }
        }
    }
    None
}

/// nginx's program, if installed.
pub fn nginx_program() -> Option<PathBuf> {
    program(&["nginx", "/usr/sbin/nginx"])
}

/// nginx serving `root` on a loopback port (one worker, keep-alive, `sendfile`; images with
/// their types, anything else `application/octet-stream`), its files
/// under `dir`; with `log`, every request is logged there as `STATUS BODY_BYTES METHOD
/// "RANGE"` ([`AccessLog`]). With `link_rate`, each connection sends at most that many bytes a
/// second (nginx's `limit_rate`): a network link, where one connection's throughput bounds a
/// transfer rather than the CPU. Stops on drop.
pub struct Nginx {
    _child: Killed,
    pub port: u16,
}

impl Nginx {
    /// The server's process id (one process: `master_process off`).
    pub fn pid(&self) -> u32 {
        self._child.0.id()
    }

    pub fn serve(root: &Path, dir: &Path, log: Option<&Path>, link_rate: Option<u64>) -> anyhow::Result<Nginx> {
        let exe = nginx_program()
            .ok_or_else(|| anyhow::anyhow!("nginx is needed and was not found: install it (apt-get install nginx)"))?;
        let port = free_port()?;
        for sub in ["body", "proxy", "fastcgi", "uwsgi", "scgi"] {
            std::fs::create_dir_all(dir.join(sub))?;
        }
        let d = dir.display();
        let access = match log {
            Some(p) => format!(
                " log_format clipbench '$status $body_bytes_sent $request_method \"$http_range\"';\n access_log {} clipbench;\n",
                p.display()
            ),
            None => " access_log off;\n".to_string(),
        };
        let limit = link_rate.map_or(String::new(), |b| format!(" limit_rate {b};\n"));
        let conf = format!(
            "daemon off;\nmaster_process off;\nworker_processes 1;\npid {d}/nginx.pid;\nerror_log {d}/error.log warn;\n\
             events {{ worker_connections 1024; }}\nhttp {{\n{access} client_body_temp_path {d}/body;\n proxy_temp_path {d}/proxy;\n fastcgi_temp_path {d}/fastcgi;\n uwsgi_temp_path {d}/uwsgi;\n scgi_temp_path {d}/scgi;\n keepalive_requests 1000000;\n types {{ image/png png; image/jpeg jpg jpeg; image/webp webp; }}\n default_type application/octet-stream;\n sendfile on;\n tcp_nodelay on;\n{limit} server {{ listen 127.0.0.1:{port}; root {}; location / {{ }} }}\n}}\n",
            root.display()
        );
        std::fs::write(dir.join("nginx.conf"), conf)?;
        let child = Command::new(exe)
            .args(["-p", &d.to_string(), "-e", &format!("{d}/error.log"), "-c", &format!("{d}/nginx.conf")])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()?;
        let k = Killed(child);
        wait_port(port, "nginx")?;
        Ok(Nginx { _child: k, port })
    }
}

/// One request in nginx's access log.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Hit {
    pub status: u16,
    /// Body bytes sent.
    pub bytes: u64,
    pub method: String,
    /// The `Range` asked for (`bytes=A-B`, both ends included), if one was.
    pub range: Option<(u64, u64)>,
}

/// nginx's access log as [`Nginx::serve`] writes it.
pub struct AccessLog(pub PathBuf);

impl AccessLog {
    /// Every request logged so far.
    pub fn hits(&self) -> anyhow::Result<Vec<Hit>> {
        let text = match std::fs::read_to_string(&self.0) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
            Err(e) => return Err(e.into()),
        };
        text.lines()
            .map(|line| {
                let bad = || anyhow::anyhow!("{}: cannot parse the line `{line}`", self.0.display());
                let mut it = line.splitn(4, ' ');
                let status = it.next().and_then(|s| s.parse().ok()).ok_or_else(bad)?;
                let bytes = it.next().and_then(|s| s.parse().ok()).ok_or_else(bad)?;
                let method = it.next().ok_or_else(bad)?.to_string();
                let range = it.next().unwrap_or("").trim_matches('"');
                let range = range.strip_prefix("bytes=").and_then(|r| {
                    let (a, b) = r.split_once('-')?;
                    Some((a.parse().ok()?, b.parse().ok()?))
                });
                Ok(Hit { status, bytes, method, range })
            })
            .collect()
    }

    /// Every request logged so far, once the log has stopped growing for 50 ms (nginx writes
    /// a request's line just after its last byte, so a reader may return before it is written).
    pub fn settled(&self) -> anyhow::Result<Vec<Hit>> {
        let len = || std::fs::metadata(&self.0).map_or(0, |m| m.len());
        let (mut last, mut since, t) = (len(), Instant::now(), Instant::now());
        while since.elapsed() < Duration::from_millis(50) && t.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(5));
            let now = len();
            if now != last {
                (last, since) = (now, Instant::now());
            }
        }
        self.hits()
    }
}

/// Faults a [`Proxy`] injects, as shares of the requests it relays (each request's fate is
/// drawn from its number: the same requests fail in every run).
#[derive(Clone, Copy, Debug, Default)]
pub struct Faults {
    /// Answered `503 Service Unavailable` by the proxy itself (no `Retry-After`).
    pub unavailable: f64,
    /// Forwarded, then the connection is closed after half the answer's body.
    pub cut: f64,
}

/// A tail a [`Proxy`] adds: a share of the requests (drawn from their numbers, after the
/// faults' shares) held `hold` longer than the others, as a store's slowest requests are.
#[derive(Clone, Copy, Debug, Default)]
pub struct Tail {
    pub share: f64,
    pub hold: Duration,
}

/// What a [`Proxy`] did.
#[derive(Debug, Default)]
pub struct ProxyCounters {
    pub requests: AtomicU64,
    pub unavailable: AtomicU64,
    pub cut: AtomicU64,
    /// Requests held longer ([`Tail`]).
    pub held: AtomicU64,
}

/// A keep-alive HTTP relay to a loopback `upstream` that holds every request `delay` before
/// forwarding it and injects `faults`; stops accepting when `stop` is set.
pub struct Proxy {
    pub port: u16,
    pub counters: Arc<ProxyCounters>,
}

impl Proxy {
    pub fn start(upstream: u16, delay: Duration, faults: Faults, stop: Arc<AtomicBool>) -> anyhow::Result<Proxy> {
        Proxy::start_with_tail(upstream, delay, faults, Tail::default(), stop)
    }

    /// [`Proxy::start`], and `tail`'s share of the requests held `tail.hold` longer.
    pub fn start_with_tail(
        upstream: u16,
        delay: Duration,
        faults: Faults,
        tail: Tail,
        stop: Arc<AtomicBool>,
    ) -> anyhow::Result<Proxy> {
        let listener = TcpListener::bind("127.0.0.1:0")?;
        let port = listener.local_addr()?.port();
        let counters = Arc::new(ProxyCounters::default());
        let c = counters.clone();
        std::thread::spawn(move || {
            for conn in listener.incoming() {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                let Ok(conn) = conn else { continue };
                let c = c.clone();
                std::thread::spawn(move || {
                    let _ = relay(conn, upstream, delay, (faults, tail), &c);
                });
            }
        });
        Ok(Proxy { port, counters })
    }
}

fn read_head(r: &mut BufReader<TcpStream>) -> std::io::Result<Option<(Vec<u8>, usize)>> {
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
        head.extend_from_slice(line.as_bytes());
        if line == "\r\n" {
            return Ok(Some((head, len)));
        }
    }
}

fn relay(
    client: TcpStream,
    upstream: u16,
    delay: Duration,
    (faults, tail): (Faults, Tail),
    c: &ProxyCounters,
) -> std::io::Result<()> {
    client.set_nodelay(true)?;
    let mut from_client = BufReader::new(client.try_clone()?);
    let mut to_client = client;
    let up = TcpStream::connect(("127.0.0.1", upstream))?;
    up.set_nodelay(true)?;
    let mut from_up = BufReader::new(up.try_clone()?);
    let mut to_up = up;
    let mut body = Vec::new();
    while let Some((head, len)) = read_head(&mut from_client)? {
        body.resize(len, 0);
        from_client.read_exact(&mut body)?;
        let i = c.requests.fetch_add(1, Ordering::Relaxed);
        // A uniform draw in [0, 1) from the request's number.
        let x = (splitmix64(i ^ 0x5eed) >> 11) as f64 / (1u64 << 53) as f64;
        if x < faults.unavailable {
            c.unavailable.fetch_add(1, Ordering::Relaxed);
            to_client.write_all(b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\n\r\n")?;
            continue;
        }
        let faulty = faults.unavailable + faults.cut;
        if (faulty..faulty + tail.share).contains(&x) {
            c.held.fetch_add(1, Ordering::Relaxed);
            std::thread::sleep(delay + tail.hold);
        } else {
            std::thread::sleep(delay);
        }
        to_up.write_all(&head)?;
        to_up.write_all(&body)?;
        let Some((rhead, rlen)) = read_head(&mut from_up)? else { return Ok(()) };
        let head_only = head.starts_with(b"HEAD ");
        body.resize(if head_only { 0 } else { rlen }, 0);
        from_up.read_exact(&mut body)?;
        to_client.write_all(&rhead)?;
        if x < faults.unavailable + faults.cut && !body.is_empty() {
            c.cut.fetch_add(1, Ordering::Relaxed);
            to_client.write_all(&body[..body.len() / 2])?;
            let _ = to_client.shutdown(Shutdown::Both);
            return Ok(());
        }
        to_client.write_all(&body)?;
    }
    Ok(())
}
