//! The control socket: a Unix stream socket (owner-only) answering the line protocol of
//! [`super::protocol`] — status, statistics, budget, invalid border, centre and shutdown.
//!
//! One task accepts; one task per connection reads lines with a hard length limit and an idle
//! timeout, and holds one of [`ControlLimits::max_connections`] permits. Commands that change the
//! engine go to the tick loop through its bounded handle and wait (bounded) for its answer.
//! Nothing a client sends can make the service hold more than the limits say.

use super::protocol::{self, Request};
use super::stats::{ControlCounters, ServiceStats};
use super::ticker::{Command, Started, Ticker};
use super::{ControlLimits, ServiceError};
use crate::shm::names::{self, Identity};
use std::os::unix::fs::{DirBuilderExt, FileTypeExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::{oneshot, watch, OwnedSemaphorePermit, Semaphore};
use tokio::task::JoinSet;

/// What every connection shares.
#[derive(Debug)]
pub struct Context {
    /// Publication name.
    pub name: String,
    /// Socket path.
    pub socket: PathBuf,
    /// Texture and mapping.
    pub started: Started,
    /// The tick loop.
    pub ticker: Ticker,
    /// Bounds.
    pub limits: ControlLimits,
    /// Counters.
    pub counters: ControlCounters,
    /// Set to true to stop the service.
    pub stop: watch::Sender<bool>,
    /// A growing texture's grower (the `PATCH` commands), if the texture grows.
    pub grower: Option<crate::growing::serve::Grower>,
}

impl Context {
    /// Everything `STATS` reports.
    pub fn stats(&self) -> ServiceStats {
        ServiceStats { name: self.name.clone(), tick: self.ticker.stats(), control: self.counters.get() }
    }
}

/// Binds `path` as an owner-only socket: bound inside a fresh 0700 directory, made 0600, then
/// renamed into place (never over anything that is there), so it is never reachable with wider
/// permissions. A stale socket of this user left by a crash (connecting is refused) is replaced;
/// a live one, one of another user, or anything that is not a socket is refused and left alone.
/// Returns the listener and the socket's identity, for removing it (and only it) at the end.
pub fn bind(path: &Path) -> Result<(UnixListener, Identity), ServiceError> {
    let err = |source| ServiceError::Socket { path: path.to_path_buf(), source };
    let in_use = |why: String| ServiceError::SocketInUse { path: path.to_path_buf(), why };
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        let who = names::owner(meta.uid());
        if !meta.file_type().is_socket() {
            return Err(in_use(format!(
                "it exists and is {} owned by {who}, not a socket",
                crate::open::kind_of(&meta)
            )));
        }
        match std::os::unix::net::UnixStream::connect(path) {
            Ok(_) => {
                return Err(in_use(format!("another process accepts connections on it (the socket is owned by {who})")))
            }
            Err(_) if meta.uid() != names::euid() => {
                return Err(in_use(format!("it is a socket owned by {who}, not by this service's user")))
            }
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => std::fs::remove_file(path).map_err(err)?,
            Err(e) => return Err(in_use(format!("cannot tell whether a service listens on it ({e})"))),
        }
    }
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
    let tmp_dir = parent.join(format!(".clipmapd-{}-{nanos}", std::process::id()));
    std::fs::DirBuilder::new().mode(0o700).create(&tmp_dir).map_err(err)?;
    let tmp = tmp_dir.join("s");
    let bound = std::os::unix::net::UnixListener::bind(&tmp)
        .and_then(|l| std::fs::set_permissions(&tmp, std::fs::Permissions::from_mode(0o600)).map(|_| l))
        .and_then(|l| std::fs::symlink_metadata(&tmp).map(|m| (l, Identity::of(&m))))
        .and_then(|(l, id)| names::rename_no_replace(&tmp, path).map(|_| (l, id)))
        .and_then(|(l, id)| l.set_nonblocking(true).map(|_| (l, id)));
    let _ = std::fs::remove_file(&tmp);
    let _ = std::fs::remove_dir(&tmp_dir);
    let (listener, id) = bound.map_err(|e| match e.kind() {
        std::io::ErrorKind::AlreadyExists => in_use("another process created it while this one started".into()),
        _ => err(e),
    })?;
    Ok((UnixListener::from_std(listener).map_err(err)?, id))
}

/// Accepts connections until `stop` turns true, then closes every connection.
pub async fn serve(listener: UnixListener, ctx: Arc<Context>) {
    let permits = Arc::new(Semaphore::new(ctx.limits.max_connections));
    let mut stop = ctx.stop.subscribe();
    let mut conns = JoinSet::new();
    loop {
        while conns.try_join_next().is_some() {}
        let stream = tokio::select! {
            r = listener.accept() => match r {
                Ok((s, _)) => s,
                Err(e) => {
                    tracing::warn!("control socket accept failed: {e}");
                    tokio::time::sleep(std::time::Duration::from_millis(10)).await;
                    continue;
                }
            },
            _ = async { let _ = stop.wait_for(|s| *s).await; } => break,
        };
        match permits.clone().try_acquire_owned() {
            Ok(permit) => {
                ControlCounters::bump(&ctx.counters.accepted);
                conns.spawn(connection(stream, ctx.clone(), permit));
            }
            Err(_) => {
                ControlCounters::bump(&ctx.counters.refused);
                let limit = ctx.limits.max_connections;
                // Best effort, never waiting: the refusal must not hold anything.
                let _ = stream.try_write(format!("ERR too many connections (limit {limit}); closing\n").as_bytes());
            }
        }
    }
    conns.shutdown().await;
}

enum Flow {
    Continue,
    Close,
}

async fn connection(stream: UnixStream, ctx: Arc<Context>, _permit: OwnedSemaphorePermit) {
    ControlCounters::bump(&ctx.counters.open);
    let (rd, mut wr) = stream.into_split();
    let mut rd = BufReader::with_capacity(4096, rd);
    let limits = ctx.limits;
    let mut line = Vec::with_capacity(256);
    loop {
        line.clear();
        let mut limited = (&mut rd).take(limits.max_line as u64 + 1);
        let read = limited.read_until(b'\n', &mut line);
        let (reply, flow) = match tokio::time::timeout(limits.idle, read).await {
            Err(_) => {
                ControlCounters::bump(&ctx.counters.idle_closed);
                (format!("ERR idle for {} ms; closing", limits.idle.as_millis()), Flow::Close)
            }
            Ok(Err(_)) | Ok(Ok(0)) => break,
            Ok(Ok(_)) if line.last() == Some(&b'\n') => {
                line.pop();
                answer(&ctx, &line, &mut rd).await
            }
            Ok(Ok(_)) if line.len() > limits.max_line => {
                ControlCounters::bump(&ctx.counters.long_lines);
                (format!("ERR request longer than {} bytes; closing", limits.max_line), Flow::Close)
            }
            Ok(Ok(_)) => ("ERR incomplete request (no newline before end of input)".to_string(), Flow::Close),
        };
        let counter = if reply.starts_with("OK") { &ctx.counters.ok } else { &ctx.counters.errors };
        ControlCounters::bump(counter);
        let mut out = reply.into_bytes();
        out.push(b'\n');
        let sent = tokio::time::timeout(limits.idle, wr.write_all(&out)).await;
        if !matches!(sent, Ok(Ok(()))) || matches!(flow, Flow::Close) {
            break;
        }
    }
    ctx.counters.open.fetch_sub(1, std::sync::atomic::Ordering::Relaxed);
}

async fn answer(ctx: &Context, line: &[u8], rd: &mut BufReader<tokio::net::unix::OwnedReadHalf>) -> (String, Flow) {
    let req = match protocol::parse(line) {
        Ok(r) => r,
        // The bytes that follow a PATCH DATA line are never read as requests: a line that cannot
        // say how many there are ends the connection.
        Err(e) if protocol::announces_data(line) => {
            return (format!("ERR {e}; closing (nothing was taken)"), Flow::Close)
        }
        Err(e) => return (format!("ERR {e}"), Flow::Continue),
    };
    match req {
        Request::Ping => ("OK pong".into(), Flow::Continue),
        Request::Status => (format!("OK {}", status(ctx)), Flow::Continue),
        Request::Stats => (format!("OK {}", serde_json::to_string(&ctx.stats()).unwrap_or_default()), Flow::Continue),
        Request::StatsProm => {
            let text = ctx.stats().prometheus();
            let text = text.trim_end();
            (format!("OK prometheus {}\n{text}", text.lines().count()), Flow::Continue)
        }
        Request::Budget(ms) => (command(ctx, |tx| Command::Budget(ms, tx)).await, Flow::Continue),
        Request::Border(b) => (command(ctx, |tx| Command::Border(b, tx)).await, Flow::Continue),
        Request::Centre(c) => (command(ctx, |tx| Command::Centre(c, tx)).await, Flow::Continue),
        Request::ViewAdd(name, w, own) => {
            (fallible(ctx, |tx| Command::ViewAdd(name, w, own, tx)).await, Flow::Continue)
        }
        Request::ViewRemove(name) => (fallible(ctx, |tx| Command::ViewRemove(name, tx)).await, Flow::Continue),
        Request::ViewCentre(name, c) => (fallible(ctx, |tx| Command::ViewCentre(name, c, tx)).await, Flow::Continue),
        Request::ViewWeight(name, w) => (fallible(ctx, |tx| Command::ViewWeight(name, w, tx)).await, Flow::Continue),
        Request::ViewLod(name, o, e) => (fallible(ctx, |tx| Command::ViewLod(name, o, e, tx)).await, Flow::Continue),
        Request::ViewHeight(name, h, a, e) => {
            (fallible(ctx, |tx| Command::ViewHeight(name, h, a, e, tx)).await, Flow::Continue)
        }
        Request::Views => {
            (format!("OK {}", serde_json::to_string(&ctx.stats().tick.views).unwrap_or_default()), Flow::Continue)
        }
        Request::PatchFile(path) => (patch(ctx, Patch::File(path.into())).await, Flow::Continue),
        Request::PatchData { bytes, json } => {
            let Some(g) = &ctx.grower else {
                return (
                    "ERR PATCH: this service's texture does not grow (start clipmapd --growing DIR)".into(),
                    Flow::Close,
                );
            };
            if bytes > g.max_patch_bytes {
                return (
                    format!(
                        "ERR PATCH DATA: {bytes} bytes announced; the most is {} (--max-patch-bytes); closing",
                        g.max_patch_bytes
                    ),
                    Flow::Close,
                );
            }
            // Every PATCH DATA in flight, all connections together, holds its share of the
            // grower's bound until its patch is decoded and handed over; one that cannot have it
            // within the idle time is refused. The buffer grows as bytes arrive, so an announced
            // size that never comes costs nothing.
            let share = bytes.div_ceil(crate::growing::serve::IN_FLIGHT_UNIT) as u32;
            let permit = match tokio::time::timeout(ctx.limits.idle, g.in_flight.clone().acquire_many_owned(share)).await {
                Ok(Ok(p)) => p,
                _ => {
                    return (
                        format!(
                            "ERR PATCH DATA: {bytes} bytes announced while the {} bytes of patches the service holds in flight at once (twice --max-patch-bytes) stayed taken for {} ms; nothing was taken; try again later; closing",
                            g.max_in_flight_bytes,
                            ctx.limits.idle.as_millis()
                        ),
                        Flow::Close,
                    )
                }
            };
            let mut data = Vec::with_capacity(bytes.min(64 << 10) as usize);
            let mut limited = (&mut *rd).take(bytes);
            let read = limited.read_to_end(&mut data);
            match tokio::time::timeout(ctx.limits.idle, read).await {
                Ok(Ok(n)) if n as u64 == bytes => {
                    let reply = patch(ctx, Patch::Data(json, data)).await;
                    drop(permit);
                    (reply, Flow::Continue)
                }
                Ok(Ok(n)) => (
                    format!("ERR PATCH DATA: {n} of {bytes} bytes arrived before the end of input; nothing was taken"),
                    Flow::Close,
                ),
                Ok(Err(e)) => (format!("ERR PATCH DATA: reading the bytes: {e}; nothing was taken"), Flow::Close),
                Err(_) => (
                    format!(
                        "ERR PATCH DATA: the bytes did not arrive within {} ms; nothing was taken; closing",
                        ctx.limits.idle.as_millis()
                    ),
                    Flow::Close,
                ),
            }
        }
        Request::Quit => ("OK bye".into(), Flow::Close),
        Request::Shutdown => {
            tracing::info!("shutdown requested on the control socket");
            ctx.stop.send_replace(true);
            ("OK shutting down".into(), Flow::Close)
        }
    }
}

async fn command(ctx: &Context, make: impl FnOnce(oneshot::Sender<String>) -> Command) -> String {
    let (tx, rx) = oneshot::channel();
    if let Err(e) = ctx.ticker.send(make(tx)) {
        return format!("ERR {e}");
    }
    match tokio::time::timeout(ctx.limits.reply_timeout, rx).await {
        Ok(Ok(text)) => format!("OK {text}"),
        Ok(Err(_)) => "ERR the tick loop has stopped".into(),
        Err(_) => "ERR the tick loop did not answer in time".into(),
    }
}

/// [`command`] for a command that may be refused: `OK text` or `ERR why`.
async fn fallible(ctx: &Context, make: impl FnOnce(oneshot::Sender<Result<String, String>>) -> Command) -> String {
    let (tx, rx) = oneshot::channel();
    if let Err(e) = ctx.ticker.send(make(tx)) {
        return format!("ERR {e}");
    }
    match tokio::time::timeout(ctx.limits.reply_timeout, rx).await {
        Ok(Ok(Ok(text))) => format!("OK {text}"),
        Ok(Ok(Err(why))) => format!("ERR {why}"),
        Ok(Err(_)) => "ERR the tick loop has stopped".into(),
        Err(_) => "ERR the tick loop did not answer in time".into(),
    }
}

enum Patch {
    File(PathBuf),
    Data(String, Vec<u8>),
}

/// Reads and checks a patch (off the async workers: decoding is work), hands it to the grower and
/// waits for its answer: `OK patch <id>` once it is durable.
async fn patch(ctx: &Context, p: Patch) -> String {
    let Some(g) = ctx.grower.clone() else {
        return "ERR PATCH: this service's texture does not grow (start clipmapd --growing DIR)".into();
    };
    let grid = g.grid();
    let max = g.max_patch_bytes;
    let read = tokio::task::spawn_blocking(move || match p {
        // The owner's own request: the sidecar's image may be anywhere it can read.
        Patch::File(path) => {
            crate::growing::input::read_sidecar(&grid, &path, max, crate::growing::input::Paths::Anywhere)
        }
        Patch::Data(json, bytes) => crate::growing::input::sidecar(json.as_bytes(), "the request")
            .and_then(|d| crate::growing::input::new_patch(&grid, &d, bytes, max, "the request")),
    })
    .await;
    let new = match read {
        Ok(Ok(n)) => n,
        Ok(Err(e)) => return format!("ERR PATCH: {e}; nothing was taken"),
        Err(_) => return "ERR PATCH: reading the patch failed unexpectedly; nothing was taken".into(),
    };
    let (tx, rx) = oneshot::channel();
    if !g.send(crate::growing::serve::GrowCommand::Add { patch: new, source: None, reply: tx }) {
        return "ERR PATCH: the grower is busy or has stopped; try again".into();
    }
    // Keeping a patch syncs it to disk: allow longer than a tick command.
    match tokio::time::timeout(ctx.limits.reply_timeout * 6, rx).await {
        Ok(Ok(Ok(id))) => format!("OK patch {id}"),
        Ok(Ok(Err(e))) => format!("ERR PATCH: {e}; nothing was taken"),
        Ok(Err(_)) => "ERR PATCH: the grower has stopped".into(),
        Err(_) => "ERR PATCH: the grower did not answer in time (the patch may still be taken)".into(),
    }
}

fn status(ctx: &Context) -> String {
    let t = ctx.ticker.stats();
    let s = &ctx.started;
    serde_json::json!({
        "name": ctx.name,
        "pid": std::process::id(),
        "mapping": s.mapping,
        "socket": ctx.socket,
        "size": s.size,
        "clip_size": s.clip_size,
        "levels": s.levels,
        "format": s.format,
        "mapping_bytes": s.mapping_bytes,
        "uptime_s": t.uptime_s,
        "ticks": t.engine.ticks,
        "tick_hz": t.tick_hz,
        "centre": t.centre,
        "min_lod": t.min_lod,
        "levels_disabled": t.levels_disabled,
        "budget_ms": t.budget_ms,
        "invalid_border": t.invalid_border,
        "valid": t.valid,
        "growth": t.growth,
    })
    .to_string()
}
