//! The clip-texture service behind `clipmapd`: keeps one clip texture's windows filled around
//! the centre renderers ask for and publishes them in shared memory, answering a control socket.
//!
//! ## The public API
//!
//! What `clipmapd`, the tools, the GPU client's demo and the tests use, all at the crate root but
//! the statistics:
//!
//! - [`run`] with its [`Options`] ([`ControlLimits`], [`ViewOption`], [`default_socket`]), the
//!   [`Summary`] it returns ([`Started`], [`ServiceStats`]) and its [`ServiceError`];
//! - [`stats`]: the statistics the control socket's `STATS` answers (JSON and Prometheus text),
//!   whose types the tools read back;
//! - the demo's sources: [`procedural_source`], [`web_mercator_square`], [`Procedural`] and
//!   [`TERRAIN_SEED`] (re-exported from `clipmap::source`).
//!
//! Everything else is crate-private: the socket speaks its line protocol to clients, not Rust
//! types, so its commands, replies, parsers and the tick loop's handle (`Ticker`) are not an
//! API. `tests/it/api.rs` holds this list.
//!
//! | file | owns |
//! |---|---|
//! | `options` | run-time options and the control socket's bounds, validated once (re-exported at the root) |
//! | `ticker` | the tick loop: a dedicated thread owning the engine and the mapping's writer |
//! | `views` | the views, the primary included: what each is told (commands, requests) and its grids, shared or own |
//! | `control` | the owner-only Unix control socket (tokio): one task per connection, bounded |
//! | `protocol` | the control socket's line protocol, as pure functions: requests parsed, answers rendered |
//! | `patches` | a growing texture's patches taken on the control socket (`PATCH FILE`, `PATCH DATA`) |
//! | [`stats`] | statistics: JSON and Prometheus text |
//!
//! The entry point [`run`] takes its shutdown signal as an argument (a future), so the binary
//! passes SIGINT/SIGTERM and tests pass whatever they like. Reading configuration files and
//! tiles is left to [`clipmap::source`]; the layout and its `unsafe` access to [`clipmap::shm`]. The
//! demo (`clipmapd --demo`, `clipmap_tools::demo`) is a client of this module like any other.

pub(crate) mod control;
pub(crate) mod options;
mod own_views;
pub(crate) mod patches;
pub(crate) mod protocol;
mod requests;
pub mod stats;
pub(crate) mod ticker;
mod views;

pub use options::{default_socket, ControlLimits, Options, ViewOption};
pub use stats::ServiceStats;
pub use ticker::Started;
use ticker::Ticker;

use clipmap::source::{TextureDesc, TileSource};
use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;

/// Why the service could not start or stopped early.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// An option is out of range.
    #[error("{0}")]
    BadOption(String),
    /// The shared-memory layer refused (name taken, directory not writable, ...).
    #[error(transparent)]
    Shm(#[from] clipmap::shm::ShmError),
    /// The engine could not be built.
    #[error(transparent)]
    Engine(#[from] clipmap::clip::ClipError),
    /// The texture description is not usable.
    #[error("texture: {0}")]
    Texture(#[from] clipmap::source::DescError),
    /// The control socket could not be bound.
    #[error("control socket {}: {source}", path.display())]
    Socket {
        /// The socket path.
        path: PathBuf,
        /// The error.
        #[source]
        source: std::io::Error,
    },
    /// The control socket path is taken.
    #[error("control socket {}: {why}; choose another --socket", path.display())]
    SocketInUse {
        /// The socket path.
        path: PathBuf,
        /// Why it cannot be used.
        why: String,
    },
    /// A thread could not be started.
    #[error("could not start the tick loop thread: {0}")]
    Thread(std::io::Error),
    /// The tick loop stopped unexpectedly.
    #[error("the tick loop stopped unexpectedly")]
    TickLoopDied,
    /// Writing the demo's pictures failed.
    #[error("{}: {message}", path.display())]
    Output {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

impl ServiceError {
    /// The documented exit status: 1 when the input (options, texture) is bad, 2 when the service
    /// could not run.
    pub fn exit_code(&self) -> i32 {
        match self {
            ServiceError::BadOption(_)
            | ServiceError::Texture(_)
            | ServiceError::Engine(
                clipmap::clip::ClipError::CacheBytes { .. } | clipmap::clip::ClipError::MemoryShape { .. },
            ) => clipmap::report::exit::BAD_INPUT,
            _ => clipmap::report::exit::COULD_NOT_RUN,
        }
    }
}

pub use clipmap::source::{Procedural, TERRAIN_SEED};

/// A procedural RGBA8 texture `size` texels a side with clip size `clip` and `tile`-texel tiles.
pub fn procedural_source(
    kind: Procedural,
    size: u64,
    clip: u64,
    tile: u64,
) -> Result<Arc<dyn TileSource>, ServiceError> {
    for (what, v) in [("--size", size), ("--clip", clip), ("--tile", tile)] {
        if !v.is_power_of_two() {
            return Err(ServiceError::BadOption(format!("{what} {v}: expected a power of two")));
        }
    }
    let desc = TextureDesc::new([size, size], clip, kind.texel_format(), [tile, tile])?;
    let border = (clip / 32).clamp(1, 16);
    let desc = desc.with_invalid_border(border.min((clip.saturating_sub(1)) / 2))?;
    Ok(kind.source(desc))
}

/// `source` (a square of a power of two texels a side, as [`procedural_source`] makes) georeferenced
/// as the whole Web Mercator square: WebMercatorQuad at zoom log2(size) with 1-texel tiles
/// (`clipmapd --georef web-mercator`; docs/GEOREF.md). Its texels are the source's.
pub fn web_mercator_square(source: Arc<dyn TileSource>) -> Arc<dyn TileSource> {
    let size = source.desc().size()[0];
    let georef = clipmap::georef::Georef::web_mercator_quad(size.trailing_zeros(), size >> size.trailing_zeros());
    Arc::new(Georeferenced { inner: source, georef })
}

/// A source with a georeferencing given to it ([`web_mercator_square`]).
struct Georeferenced {
    inner: Arc<dyn TileSource>,
    georef: clipmap::georef::Georef,
}

impl TileSource for Georeferenced {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }
    fn read_tile(&self, tile: clipmap::source::TileId, out: &mut [u8]) -> Result<(), clipmap::source::SourceError> {
        self.inner.read_tile(tile, out)
    }
    fn read_into(
        &self,
        tile: clipmap::source::TileId,
        out: &mut [u8],
    ) -> Result<clipmap::source::Delivered, clipmap::source::SourceError> {
        self.inner.read_into(tile, out)
    }
    fn wrapped(&self) -> Option<&dyn TileSource> {
        Some(self.inner.as_ref())
    }
    fn georef(&self) -> Option<clipmap::georef::Georef> {
        Some(self.georef.clone())
    }
}

/// What a service did, returned when it stops.
#[derive(Clone, Debug)]
pub struct Summary {
    /// The texture and mapping.
    pub started: Started,
    /// The final statistics.
    pub stats: ServiceStats,
}

/// Runs the service for `source` until `shutdown` resolves, `SHUTDOWN` arrives on the control
/// socket, or the tick loop fails. Creates the mapping (refusing a name a live service holds,
/// taking over from a dead one) with the command line's views in it, binds the control socket,
/// and only then puts the mapping under its name, serves the socket and ticks: a reader that finds
/// the mapping finds its views and the socket answering, and a reply means the mapping is there.
/// On the way out it marks the mapping closed and removes the mapping's and socket's names
/// (readers keep their mapping).
///
/// `ready` is called once the mapping is published and the socket answers (the binary logs
/// there; the demo starts its client there).
pub async fn run(
    source: Arc<dyn TileSource>,
    options: Options,
    shutdown: impl Future<Output = ()>,
    ready: impl FnOnce(&Started),
) -> Result<Summary, ServiceError> {
    options.check()?;
    let opts = options.clone();
    let (ticker, started, join) = tokio::task::spawn_blocking(move || Ticker::prepare(source, &opts))
        .await
        .map_err(|_| ServiceError::TickLoopDied)??;
    let stop_ticker = |ticker: Ticker, join: std::thread::JoinHandle<()>| async move {
        let _ = ticker.send(ticker::Command::Stop);
        drop(ticker);
        let _ = tokio::task::spawn_blocking(move || join.join()).await;
    };
    let (listener, socket_id) = match control::bind(&options.socket) {
        Ok(l) => l,
        Err(e) => {
            stop_ticker(ticker, join).await;
            return Err(e);
        }
    };
    // Bound (connections are accepted from here on, and wait) before the mapping appears under
    // its name, answered from right after: a reader that finds the mapping finds the socket
    // answering, and a reply means that the mapping is in place.
    let published = match ticker.publish() {
        Ok(rx) => rx.await.map_err(|_| ServiceError::TickLoopDied).and_then(|r| r.map_err(ServiceError::from)),
        Err(e) => Err(e),
    };
    if let Err(e) = published {
        drop(listener);
        stop_ticker(ticker, join).await;
        clipmap::shm::names::remove_if_same(&options.socket, socket_id);
        return Err(e);
    }
    let (stop_tx, mut stop_rx) = tokio::sync::watch::channel(false);
    let ctx = Arc::new(control::Context {
        name: options.name.clone(),
        socket: options.socket.clone(),
        started: started.clone(),
        ticker: ticker.clone(),
        limits: options.control,
        counters: Default::default(),
        stop: stop_tx,
        grower: options.growing.clone(),
    });
    let server = tokio::spawn(control::serve(listener, ctx.clone()));
    tracing::info!(
        name = %options.name,
        mapping = %started.mapping.display(),
        socket = %options.socket.display(),
        size = started.size[0],
        clip = started.clip_size,
        levels = started.levels,
        tick_hz = options.tick_hz,
        "serving"
    );
    ready(&started);
    let mut ticks = ticker.watch();
    let died = tokio::select! {
        _ = shutdown => { tracing::info!("shutdown signal received"); false }
        _ = async { let _ = stop_rx.wait_for(|s| *s).await; } => false,
        _ = async { while ticks.changed().await.is_ok() {} } => true,
    };
    ctx.stop.send_replace(true);
    let _ = server.await;
    let stats = ctx.stats();
    drop(ctx);
    stop_ticker(ticker, join).await;
    clipmap::shm::names::remove_if_same(&options.socket, socket_id);
    tracing::info!(ticks = stats.tick.engine.ticks, "stopped");
    if died {
        return Err(ServiceError::TickLoopDied);
    }
    Ok(Summary { started, stats })
}

#[cfg(test)]
mod tests;
