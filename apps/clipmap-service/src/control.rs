//! The control socket: a Unix stream socket (owner-only) answering the line protocol of
//! [`super::protocol`] — status, statistics, budget, invalid border, centre and shutdown.
//!
//! One task accepts; one task per connection reads lines with a hard length limit and an idle
//! timeout, and holds one of [`ControlLimits::max_connections`] permits. Commands that change the
//! engine go to the tick loop through its bounded handle and wait (bounded) for its answer.
//! Nothing a client sends can make the service hold more than the limits say.

use super::patches::{self, PatchRefusal};
use super::protocol::{self, Answer, Flow, Refusal, Refused, Reply, Request, Unanswered};
use super::stats::{ControlCounters, ServiceStats, Status};
use super::ticker::{Command, Started, Ticker};
use super::{ControlLimits, ServiceError};
use clipmap::shm::names::{self, Identity};
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
    pub grower: Option<clipmap::growing::serve::Grower>,
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
                clipmap::open::kind_of(&meta)
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
                let mut out = protocol::render(&Refused::TooMany { limit }.into());
                out.push('\n');
                let _ = stream.try_write(out.as_bytes());
            }
        }
    }
    conns.shutdown().await;
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
        let (answer, flow) = match tokio::time::timeout(limits.idle, read).await {
            Err(_) => {
                ControlCounters::bump(&ctx.counters.idle_closed);
                (Refused::Idle { ms: limits.idle.as_millis() }.into(), Flow::Close)
            }
            Ok(Err(_)) | Ok(Ok(0)) => break,
            Ok(Ok(_)) if line.last() == Some(&b'\n') => {
                line.pop();
                answer(&ctx, &line, &mut rd).await
            }
            Ok(Ok(_)) if line.len() > limits.max_line => {
                ControlCounters::bump(&ctx.counters.long_lines);
                (Refused::TooLong { max: limits.max_line }.into(), Flow::Close)
            }
            Ok(Ok(_)) => (Refused::Incomplete.into(), Flow::Close),
        };
        let counter = if answer.is_ok() { &ctx.counters.ok } else { &ctx.counters.errors };
        ControlCounters::bump(counter);
        let mut out = protocol::render(&answer).into_bytes();
        out.push(b'\n');
        let sent = tokio::time::timeout(limits.idle, wr.write_all(&out)).await;
        if !matches!(sent, Ok(Ok(()))) || matches!(flow, Flow::Close) {
            break;
        }
    }
    ctx.counters.open.fetch_sub(1, std::sync::atomic::Ordering::Relaxed);
}

async fn answer(ctx: &Context, line: &[u8], rd: &mut BufReader<tokio::net::unix::OwnedReadHalf>) -> (Answer, Flow) {
    let req = match protocol::parse(line) {
        Ok(r) => r,
        // The bytes that follow a PATCH DATA line are never read as requests: a line that cannot
        // say how many there are ends the connection.
        Err(e) if protocol::announces_data(line) => return (Refused::BadDataLine(e).into(), Flow::Close),
        Err(e) => return (e.into(), Flow::Continue),
    };
    let answer = match req {
        Request::Ping => Answer::Pong,
        Request::Status => {
            Answer::Status(Box::new(Status::of(&ctx.name, &ctx.socket, &ctx.started, &ctx.ticker.stats())))
        }
        Request::Stats => Answer::Stats(Box::new(ctx.stats())),
        Request::StatsProm => Answer::StatsProm(ctx.stats().prometheus()),
        Request::Views => Answer::Views(ctx.stats().tick.views),
        Request::Budget(ms) => done(ask(ctx, |reply| Command::Budget { ms, reply }).await.map(Ok)),
        Request::Border(texels) => done(ask(ctx, |reply| Command::Border { texels, reply }).await.map(Ok)),
        Request::Centre(centre) => done(ask(ctx, |reply| Command::Centre { centre, reply }).await.map(Ok)),
        Request::CentreLonLat(lonlat) => done(ask(ctx, |reply| Command::CentreLonLat { lonlat, reply }).await),
        Request::View(view) => done(ask(ctx, |reply| Command::View { view, reply }).await),
        Request::PatchFile(path) => patched(patches::file(ctx.grower.as_ref(), &ctx.limits, path.into()).await),
        Request::PatchData { bytes, json } => {
            let (taken, flow) = patches::data(ctx.grower.as_ref(), &ctx.limits, rd, bytes, json).await;
            return (patched(taken), flow);
        }
        Request::Quit => return (Answer::Bye, Flow::Close),
        Request::Shutdown => {
            tracing::info!("shutdown requested on the control socket");
            ctx.stop.send_replace(true);
            return (Answer::ShuttingDown, Flow::Close);
        }
    };
    (answer, Flow::Continue)
}

/// A tick loop command's answer.
fn done(r: Result<Result<Reply, Refusal>, Unanswered>) -> Answer {
    match r {
        Ok(Ok(reply)) => Answer::Done(reply),
        Ok(Err(why)) => why.into(),
        Err(e) => e.into(),
    }
}

/// A patch's answer.
fn patched(r: Result<u64, PatchRefusal>) -> Answer {
    r.map_or_else(Answer::from, Answer::Patched)
}

/// Sends the tick loop a command and waits (at most the reply timeout) for its answer.
async fn ask<T>(ctx: &Context, make: impl FnOnce(oneshot::Sender<T>) -> Command) -> Result<T, Unanswered> {
    let (tx, rx) = oneshot::channel();
    ctx.ticker.send(make(tx))?;
    match tokio::time::timeout(ctx.limits.reply_timeout, rx).await {
        Ok(Ok(answer)) => Ok(answer),
        Ok(Err(_)) => Err(Unanswered::Stopped),
        Err(_) => Err(Unanswered::Late),
    }
}
