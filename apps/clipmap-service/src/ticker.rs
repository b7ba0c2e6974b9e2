//! The tick loop: a dedicated thread that owns the [`Clipmap`] (synchronous, with its own small
//! read runtime, its image caches in the mapping) and the mapping's [`Writer`], and runs one
//! update tick per period.
//!
//! Handle and runner: [`Ticker`] is the cloneable handle (a bounded command sender and a watch on
//! the latest [`TickStats`]); the runner owns every piece of mutable state, without locks. Each
//! tick takes the newest renderer request from the request mapping, then ticks the engine, which
//! publishes its snapshot into the mapping, and beats the heartbeat. Commands (budget, border, centre,
//! views, stop) are taken between ticks and answered through a one-shot reply: a typed
//! [`Reply`] or [`Refusal`], which [`super::protocol`] turns into the socket's text. What each view
//! is told, and its grids, are `super::views`'s.

use super::own_views::Setup;
use super::protocol::{Refusal, Reply, ViewCommand};
use super::stats::TickStats;
use super::views::Views;
use super::{Options, ServiceError};
use clipmap::clip::{Clipmap, Settings, PRIMARY};
use clipmap::paging::adaptive::{LevelPaging, Reason};
use clipmap::shm::{Writer, WriterOptions};
use clipmap::source::TileSource;
use std::sync::mpsc::{self, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tokio::sync::{oneshot, watch};

/// Commands waiting for the tick loop, at most (a full queue answers "busy", never blocks).
pub(crate) const COMMAND_QUEUE: usize = 64;

/// What the tick loop is asked to do between ticks; each carries the one-shot sender of its
/// answer.
#[derive(Debug)]
pub enum Command {
    /// Sets the copy budget per tick (ms; `None`: unlimited).
    Budget {
        /// Milliseconds a tick's own work may take.
        ms: Option<f64>,
        /// The budget set.
        reply: oneshot::Sender<Reply>,
    },
    /// Sets the invalid border (clamped by the engine).
    Border {
        /// Texels asked for.
        texels: u64,
        /// The border applied.
        reply: oneshot::Sender<Reply>,
    },
    /// Moves the clip centre (level-0 texels).
    Centre {
        /// The centre asked for.
        centre: [i64; 2],
        /// The centre the snapshot will publish (bounded).
        reply: oneshot::Sender<Reply>,
    },
    /// Moves the clip centre to a longitude / latitude (`CENTRE LONLAT`).
    CentreLonLat {
        /// WGS 84 longitude and latitude, degrees.
        lonlat: [f64; 2],
        /// The centre the snapshot will publish, or why not.
        reply: oneshot::Sender<Result<Reply, Refusal>>,
    },
    /// A command for one view (docs/VIEWS.md).
    View {
        /// What to do.
        view: ViewCommand,
        /// What was done, or why not.
        reply: oneshot::Sender<Result<Reply, Refusal>>,
    },
    /// Puts the mapping under its name, its views in it, and starts ticking
    /// ([`Ticker::prepare`], [`Ticker::publish`]).
    Publish {
        /// Whether the mapping is there.
        reply: oneshot::Sender<Result<(), clipmap::shm::ShmError>>,
    },
    /// Stops after closing the mapping.
    Stop,
}

/// What the texture and mapping look like, once the tick loop is running.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Started {
    /// The mapping file.
    pub mapping: std::path::PathBuf,
    /// Level-0 size.
    pub size: [u64; 2],
    /// Clip size.
    pub clip_size: u64,
    /// Number of levels.
    pub levels: usize,
    /// Texel format.
    pub format: String,
    /// Bytes of the mapping.
    pub mapping_bytes: u64,
}

/// The handle of the tick loop.
#[derive(Clone, Debug)]
pub struct Ticker {
    commands: SyncSender<Command>,
    stats: watch::Receiver<TickStats>,
}

/// Why a command did not reach the tick loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SendError {
    /// Its command queue is full.
    #[error("the tick loop is busy; try again")]
    Busy,
    /// It has stopped.
    #[error("the tick loop has stopped")]
    Stopped,
}

impl Ticker {
    /// Starts the tick loop on its own thread; returns once the mapping is published under its
    /// name (or could not be made). Blocks: call it off async worker threads. The tests' way in
    /// ([`run`](crate::run) prepares the loop and publishes once the socket is bound).
    #[cfg(test)]
    pub fn start(
        source: Arc<dyn TileSource>,
        options: &Options,
    ) -> Result<(Ticker, Started, JoinHandle<()>), ServiceError> {
        let (ticker, started, join) = Ticker::prepare(source, options)?;
        let published = ticker.publish().map(|rx| rx.blocking_recv());
        match published {
            Ok(Ok(Ok(()))) => Ok((ticker, started, join)),
            failed => {
                let _ = ticker.send(Command::Stop);
                let _ = join.join();
                Err(match failed {
                    Ok(Ok(Err(e))) => e.into(),
                    _ => ServiceError::TickLoopDied,
                })
            }
        }
    }

    /// Asks the tick loop to put the mapping under its name and start ticking; the answer says
    /// whether it is there.
    pub fn publish(&self) -> Result<oneshot::Receiver<Result<(), clipmap::shm::ShmError>>, ServiceError> {
        let (tx, rx) = oneshot::channel();
        self.send(Command::Publish { reply: tx }).map_err(|_| ServiceError::TickLoopDied)?;
        Ok(rx)
    }

    /// Starts the tick loop on its own thread with the mapping made, the command line's views in
    /// it, under its temporary name: it appears under its name, and the loop ticks, at
    /// [`publish`](Self::publish) (the service has its control socket bound by then).
    /// Returns once that far (or the mapping could not be made). Blocks: call it off async worker
    /// threads.
    pub fn prepare(
        source: Arc<dyn TileSource>,
        options: &Options,
    ) -> Result<(Ticker, Started, JoinHandle<()>), ServiceError> {
        let (ready_tx, ready_rx) = mpsc::sync_channel(1);
        let (cmd_tx, cmd_rx) = mpsc::sync_channel(COMMAND_QUEUE);
        let (stats_tx, stats_rx) = watch::channel(TickStats::default());
        let options = options.clone();
        let join = std::thread::Builder::new()
            .name("clipmapd-tick".into())
            .spawn(move || match Runner::new(source, &options, cmd_rx, stats_tx) {
                Ok((runner, started)) => {
                    let _ = ready_tx.send(Ok(started));
                    runner.run();
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            })
            .map_err(ServiceError::Thread)?;
        match ready_rx.recv() {
            Ok(Ok(started)) => Ok((Ticker { commands: cmd_tx, stats: stats_rx }, started, join)),
            Ok(Err(e)) => {
                let _ = join.join();
                Err(e)
            }
            Err(_) => Err(ServiceError::TickLoopDied),
        }
    }

    /// Sends a command without blocking; `Err` when the loop is busy or gone.
    pub fn send(&self, cmd: Command) -> Result<(), SendError> {
        self.commands.try_send(cmd).map_err(|e| match e {
            TrySendError::Full(_) => SendError::Busy,
            TrySendError::Disconnected(_) => SendError::Stopped,
        })
    }

    /// The latest statistics.
    pub fn stats(&self) -> TickStats {
        self.stats.borrow().clone()
    }

    /// A watch that changes after every tick (and closes when the loop stops).
    pub fn watch(&self) -> watch::Receiver<TickStats> {
        self.stats.clone()
    }
}

struct Runner {
    clipmap: Clipmap,
    writer: Writer,
    commands: mpsc::Receiver<Command>,
    stats_tx: watch::Sender<TickStats>,
    period: Duration,
    hz: f64,
    stats: TickStats,
    started: Instant,
    /// A growing texture's shared state, and the growth block's last published values.
    growing: Option<(Arc<clipmap::growing::serve::Served>, Option<clipmap::shm::layout::Growth>)>,
    /// Each level's paging reason as last logged (the log says when one changes).
    reasons: Vec<Reason>,
    /// Every view, the primary first ([`super::views`]).
    views: Views,
}

impl Runner {
    fn new(
        source: Arc<dyn TileSource>,
        o: &Options,
        commands: mpsc::Receiver<Command>,
        stats_tx: watch::Sender<TickStats>,
    ) -> Result<(Runner, Started), ServiceError> {
        let desc = source.desc().clone();
        let georef = source.georef();
        let settings = engine_settings(source.as_ref(), o);
        // Refused before anything is created in the shared directory.
        let shape = Clipmap::shape_for(&desc, &settings);
        let heights = source.heights().map(|h| clipmap::shm::layout::Heights::of(&h.format, h.levels));
        check_room(&shape, heights.is_some(), &settings)?;
        // The engine keeps its image caches in the mapping itself: each tile is read straight
        // into its slot, where renderers read it, and nothing is copied afterwards.
        let period_ns = (1e9 / o.tick_hz).round() as u64;
        let request_mode = o.request_mode.unwrap_or(o.shm_mode);
        let georef_block = georef_block(georef.as_ref(), desc.level_count());
        // Published once the views are in it (`Runner::publish`): a reader that finds the mapping
        // finds the command line's views.
        let writer = Writer::prepare(
            WriterOptions::new(&o.shm_dir, &o.name, shape, desc.format())
                .mode(o.shm_mode)
                .request_mode(request_mode)
                .tick_period_ns(period_ns)
                .heights(heights)
                .georef(georef_block.clone()),
        )?;
        let setup = Setup {
            source: Arc::clone(&source),
            // An own view's grids hold that view alone: never widened for others.
            settings: Settings { view_spread: 0, ..settings.clone() },
            dir: o.shm_dir.clone(),
            service: o.name.clone(),
            shm_mode: o.shm_mode,
            request_mode,
            period_ns,
            heights,
            georef: georef_block,
            effective_levels: o.effective_levels,
            main_mapping: writer.file_path().to_path_buf(),
            fresh: Default::default(),
            generation: writer.generation(),
        };
        let mut clipmap = match Clipmap::with_memory(source, settings, writer.memory()) {
            Ok(c) => c,
            Err(e) => {
                // Leave nothing behind that looks like a service.
                writer.close();
                return Err(e.into());
            }
        };
        if let Some(b) = o.invalid_border {
            clipmap.set_invalid_border(b);
        }
        let started = Started {
            mapping: writer.path().to_path_buf(),
            size: desc.size(),
            clip_size: desc.clip_size(),
            levels: desc.level_count(),
            format: desc.format().short_name(),
            mapping_bytes: writer.placement().total_bytes,
        };
        let mut runner = Runner::assemble(clipmap, writer, setup, o, commands, stats_tx);
        runner.views.set_georef(georef);
        Ok((runner.start_views(o)?, started))
    }

    /// The runner of a clipmap and its mapping, its primary centred on the texture.
    fn assemble(
        clipmap: Clipmap,
        writer: Writer,
        setup: Setup,
        o: &Options,
        commands: mpsc::Receiver<Command>,
        stats_tx: watch::Sender<TickStats>,
    ) -> Runner {
        let size = clipmap.desc().size();
        let stats = TickStats { tick_hz: o.tick_hz, budget_ms: o.budget_ms, ..TickStats::default() };
        Runner {
            clipmap,
            writer,
            commands,
            stats_tx,
            period: Duration::from_secs_f64(1.0 / o.tick_hz),
            hz: o.tick_hz,
            stats,
            started: Instant::now(),
            growing: o.growing.as_ref().map(|g| (g.served().clone(), None)),
            reasons: Vec::new(),
            views: Views::new(setup, [(size[0] / 2) as i64, (size[1] / 2) as i64]),
        }
    }

    /// The command line's views (`--effective-levels`, each `--view`), in the mapping before it
    /// is published. Refused: the mapping (and every own view's) is closed.
    fn start_views(mut self, o: &Options) -> Result<Runner, ServiceError> {
        // Holding the service's lock: what a dead predecessor left of its views' own mappings goes.
        for view in clipmap::shm::writer::remove_dead_own_mappings(&o.shm_dir, &o.name) {
            tracing::info!(view = %view, "removed the own mapping a stopped service left for view {view}");
        }
        if let Some(e) = o.effective_levels {
            let lod = clipmap::clip::LodWindow { offset: 0, effective: e };
            if let Err(why) = self.clipmap.set_view_lod(PRIMARY, lod) {
                self.writer.close();
                return Err(ServiceError::BadOption(format!("--effective-levels {e}: {why}")));
            }
        }
        for v in &o.views {
            if let Err(why) = self.views.add(&mut self.clipmap, &v.name, v.weight, v.own) {
                self.views.close_all();
                self.writer.close();
                return Err(ServiceError::BadOption(format!("--view {}: {why}", v.name)));
            }
        }
        self.publish_views();
        Ok(self)
    }

    /// Puts the mapping under its name: every view it was started with is in it by then, and
    /// the own views take their tiles from it under that name from now on.
    ///
    /// One tick first: the mapping appears with its first snapshot and (a growing texture) its
    /// growth block in it, as when it appeared after the loop had ticked.
    fn publish(&mut self) -> Result<(), clipmap::shm::ShmError> {
        self.tick();
        self.writer.publish()?;
        self.views.published(self.writer.path());
        Ok(())
    }

    fn run(mut self) {
        // Nothing ticks before the mapping is published (`Ticker::publish`).
        loop {
            match self.commands.recv() {
                Ok(Command::Publish { reply }) => {
                    let r = self.publish();
                    let ok = r.is_ok();
                    let _ = reply.send(r);
                    if ok {
                        break;
                    }
                }
                Ok(Command::Stop) | Err(_) => {
                    self.writer.close();
                    self.views.close_all();
                    return;
                }
                Ok(cmd) => self.apply(cmd),
            }
        }
        // While waiting for the next period, look at the request block this often; a new
        // request starts a tick at once, but never sooner than `min_gap` after the last one.
        let poll = Duration::from_millis(1);
        let min_gap = self.period / 4;
        let mut next = Instant::now();
        let mut last_start = next - self.period;
        'ticks: loop {
            loop {
                let now = Instant::now();
                if now >= next {
                    break;
                }
                if now >= last_start + min_gap && self.views.requests_changed(&self.writer) {
                    self.stats.ticks_on_request += 1;
                    break;
                }
                match self.commands.recv_timeout((next - now).min(poll)) {
                    Ok(Command::Stop) | Err(RecvTimeoutError::Disconnected) => break 'ticks,
                    Ok(cmd) => {
                        // A command may be long (a view with grids of its own makes a mapping).
                        self.apply(cmd);
                        self.writer.alive();
                        self.views.alive();
                    }
                    Err(RecvTimeoutError::Timeout) => {}
                }
            }
            let start = Instant::now();
            let early = start < next;
            last_start = start;
            self.tick();
            next = if early { start + self.period } else { next + self.period };
            let now = Instant::now();
            if now > next {
                self.stats.tick_overruns += 1;
                next = now;
            }
        }
        tracing::info!(ticks = self.stats.engine.ticks, "tick loop stopping; closing the mapping");
        // The service's mapping first: a reader that sees its view's own mapping closed then
        // finds the service closed (a stop), not the view's record live (docs/SHM.md).
        self.writer.close();
        self.views.close_all();
    }

    fn apply(&mut self, cmd: Command) {
        match cmd {
            Command::Budget { ms, reply } => {
                let _ = reply.send(self.set_budget(ms));
            }
            Command::Border { texels, reply } => {
                let _ = reply.send(self.set_border(texels));
            }
            Command::Centre { centre, reply } => {
                let _ = reply.send(Reply::Centre(self.views.centre_primary(centre, &mut self.stats)));
            }
            Command::CentreLonLat { lonlat, reply } => {
                let _ = reply.send(self.views.centre_primary_lonlat(lonlat, &mut self.stats).map(Reply::Centre));
            }
            Command::View { view, reply } => {
                let _ = reply.send(self.view_command(view));
            }
            Command::Stop | Command::Publish { .. } => {}
        }
    }

    fn set_budget(&mut self, ms: Option<f64>) -> Reply {
        self.clipmap.set_budget_ns(ms.map(|ms| (ms * 1e6) as u64));
        self.stats.budget_ms = ms;
        tracing::info!(budget_ms = ?ms, "copy budget changed");
        Reply::Budget(ms)
    }

    fn set_border(&mut self, texels: u64) -> Reply {
        self.clipmap.set_invalid_border(texels);
        let applied = self.clipmap.invalid_border();
        tracing::info!(asked = texels, applied, "invalid border changed");
        Reply::Border(applied)
    }

    /// Carries out a `VIEW` command ([`Views::command`]). One that changes the views (all but a
    /// centre) publishes their figures at once.
    fn view_command(&mut self, cmd: ViewCommand) -> Result<Reply, Refusal> {
        let changes_views = !matches!(cmd, ViewCommand::Centre { .. } | ViewCommand::CentreLonLat { .. });
        let r = self.views.command(&mut self.clipmap, &mut self.stats, cmd);
        if r.is_ok() && changes_views {
            self.publish_views();
        }
        r
    }

    /// Publishes the views' figures now, not at the next tick: `VIEWS` and `STATS` asked after a
    /// `VIEW ADD`, `REMOVE` or `WEIGHT` was answered show it (as the mapping already does).
    fn publish_views(&mut self) {
        self.stats.views = self.views.stats(&self.clipmap);
        self.stats_tx.send_replace(self.stats.clone());
    }

    fn tick(&mut self) {
        self.views.take_primary_request(&mut self.clipmap, &self.writer, self.hz, &mut self.stats);
        (self.stats.request_faults, self.stats.request_fault) = self.writer.request_faults();
        if let Some((served, _)) = &self.growing {
            let changed = served.take_changed(self.clipmap.desc());
            // Every clipmap reads the changed tiles again: the primary's and each own view's.
            self.views.refresh(&changed);
            self.clipmap.refresh(changed);
            if self.stats.engine.ticks.is_multiple_of(256) {
                let (c, views) = (&self.clipmap, &self.views);
                served.retain_partial(|t| c.holds(t) || views.own_holds(t));
            }
        }
        self.views.take_further_requests(&mut self.clipmap, &self.writer, self.hz, &mut self.stats);
        let t0 = Instant::now();
        let (centre, velocity) = self.views.primary_motion();
        let report = self.clipmap.tick(centre, velocity);
        // Alive after each clipmap's tick, not only after the whole tick (see `Views::tick_own`).
        self.writer.alive();
        self.views.tick_own(&self.clipmap, &self.writer, self.hz, &mut self.stats);
        self.stats.views = self.views.stats(&self.clipmap);
        if let Some((served, last)) = &mut self.growing {
            let (_, mut g) = served.growth();
            g.tiles_replaced = self.clipmap.stats().tiles_replaced;
            if *last != Some(g) {
                self.writer.memory().publish_growth(&g);
                *last = Some(g);
                self.stats.growth = Some(g);
            }
        }
        self.writer.heartbeat();
        let s = &mut self.stats;
        s.tick_busy_s += t0.elapsed().as_secs_f64();
        s.uptime_s = self.started.elapsed().as_secs_f64();
        s.centre = report.centre;
        s.centre_lonlat = super::views::centre_lonlat(self.views.georef(), report.centre);
        s.min_lod = report.min_lod;
        s.levels_disabled = report.disabled_levels.len() as u64;
        s.invalid_border = self.clipmap.invalid_border();
        s.bytes_published = self.clipmap.stats().queue.bytes_read;
        s.publications = self.clipmap.stats().publications;
        s.resident_bytes = self.clipmap.resident_bytes() + self.views.own_resident_bytes();
        s.valid = report.valid.iter().map(|r| [r.s0, r.t0, r.s1, r.t1]).collect();
        s.engine = self.clipmap.stats().clone();
        s.streams = self.clipmap.stream_stats();
        #[cfg(feature = "remote")]
        {
            s.remote = self.clipmap.source().remote_stats();
        }
        log_reason_changes(&mut self.reasons, &s.engine.paging, s.engine.read_latency_ticks, s.engine.ticks);
        self.stats_tx.send_replace(s.clone());
    }
}

/// The engine's settings for the service's options.
fn engine_settings(source: &dyn TileSource, o: &Options) -> Settings {
    let mut settings = Settings {
        budget_ns: o.budget_ms.map(|ms| (ms * 1e6) as u64),
        // One read queue per stream server the configuration names.
        streams: source.stream_servers(),
        centre_alignment: o.centre_alignment,
        ..Settings::default().with_paging(&o.paging)
    };
    settings.view_spread = o.view_spread;
    // A texture that spans 360 degrees of longitude wraps there (docs/SHM.md, "How a region
    // wraps"): its georeferencing says so, as the mapping's georef block's flag does.
    settings.wrap_longitude = source.georef().is_some_and(|g| g.is_global_in_longitude());
    if o.growing.is_some() {
        // A growing texture's tile without data is read again when data arrives for it
        // (`Clipmap::refresh`), not on a timer.
        settings.retry_after_ticks = u64::MAX / 4;
    }
    settings
}

/// The mapping's georef block (docs/SHM.md, "Georef block") of a texture of `levels` levels
/// georeferenced by `georef`: level 0's origin, each level's terms, the CRS's EPSG code and
/// definition, whether it spans 360 degrees of longitude. A definition the block cannot hold
/// (over 1024 bytes, or with a NUL) is left out, the EPSG code kept; a georeferencing the block
/// refuses (a level without an invertible transform) is not published, and the log says why.
fn georef_block(georef: Option<&clipmap::georef::Georef>, levels: usize) -> Option<clipmap::shm::GeorefBlock> {
    let g = georef?;
    let gt = g.geotransform().0;
    let mut definition = g.crs().definition().to_string();
    if definition.len() > 1024 || definition.contains('\0') {
        tracing::warn!(len = definition.len(), "the CRS definition does not fit the mapping's georef block (1024 bytes without NUL): only its EPSG code is published");
        definition.clear();
    }
    let block = clipmap::shm::GeorefBlock {
        epsg: g.crs().epsg_code().filter(|&c| c != 0),
        wraps: g.is_global_in_longitude(),
        definition,
        origin: [gt[0], gt[3]],
        levels: (0..levels as u32)
            .map(|k| {
                let t = g.level_transform(k).0;
                [t[1], t[2], t[4], t[5]]
            })
            .collect(),
    };
    match block.check(levels) {
        Ok(()) => Some(block),
        Err(e) => {
            tracing::warn!("the texture's georeferencing is not published in the mapping: {e}");
            None
        }
    }
}

/// Refuses a clipmap whose mapping (of `shape`, with heights or not) could not be laid out, or
/// would not fit the cache bound with the read pool.
fn check_room(shape: &clipmap::shm::layout::Shape, heights: bool, settings: &Settings) -> Result<(), ServiceError> {
    let placement = clipmap::shm::layout::place_with(shape, heights)
        .and_then(|p| clipmap::shm::layout::with_views(p, clipmap::shm::layout::views::SERVICE_RECORDS))
        .ok_or_else(|| clipmap::clip::ClipError::Memory(clipmap::shm::memory::shape_error(shape)))?;
    let limit = settings.limits.cache_bytes as u64;
    let needed = placement.total_bytes.saturating_add(settings.pool_bytes);
    if needed > limit {
        return Err(clipmap::clip::ClipError::CacheBytes { needed, limit }.into());
    }
    Ok(())
}

/// Logs each level whose paging reason differs from the one in `last` (one line a change, never
/// one a tick), and remembers the new reasons. The first tick only sets where they start (every
/// level `hover`, or `fixed`: nothing to say). Returns the levels logged.
fn log_reason_changes(last: &mut Vec<Reason>, paging: &[LevelPaging], latency: f64, tick: u64) -> Vec<usize> {
    let mut changed = Vec::new();
    for (k, p) in paging.iter().enumerate() {
        let Some(was) = last.get(k).copied() else { continue };
        if was == p.reason {
            continue;
        }
        changed.push(k);
        tracing::info!(
            tick,
            level = k,
            reason = p.reason.name(),
            was = was.name(),
            lead_tiles = ?p.lead_tiles,
            lead_texels = ?p.lead_texels,
            grid = ?p.grid,
            read_latency_ticks = latency,
            level_read_latency_ticks = p.read_latency_ticks,
            "paging reason changed"
        );
    }
    *last = paging.iter().map(|p| p.reason).collect();
    changed
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::requests::velocity_per_tick;

    /// docs/SHM.md, "What the service does with a request": the velocity (level-0 texels per
    /// second) is divided by the tick rate and rounded to texels per tick (halves away from zero),
    /// clamped to 2^30 a tick, NaN and infinities read as 0; both 0 is no velocity at all (the
    /// engine then follows the centre's change).
    #[test]
    fn a_requests_velocity_is_divided_by_the_tick_rate_rounded_clamped_and_nan_or_infinite_reads_zero() {
        let max = 1i64 << 30;
        assert_eq!(clipmap::source::MAX_TEXTURE_SIZE as i64, max);
        assert_eq!(velocity_per_tick([600.0, -120.0], 60.0), Some([10, -2]));
        assert_eq!(velocity_per_tick([100.0, 0.0], 4.0), Some([25, 0]), "one component may be 0");
        assert_eq!(velocity_per_tick([10.0, -6.0], 4.0), Some([3, -2]), "2.5 and -1.5: halves away from zero");
        assert_eq!(velocity_per_tick([10.0, -9.9], 4.0), Some([3, -2]), "-2.475: to the nearest");
        assert_eq!(velocity_per_tick([1.0, -1.9], 4.0), None, "0.25 and -0.475 round to 0: no velocity");
        assert_eq!(velocity_per_tick([0.0, -0.0], 60.0), None, "0: unknown");
        assert_eq!(velocity_per_tick([1e300, -1e300], 60.0), Some([max, -max]), "clamped to 2^30 a tick");
        assert_eq!(velocity_per_tick([f64::MAX, -f64::MAX], 1.0), Some([max, -max]));
        assert_eq!(
            velocity_per_tick([(max as f64 + 2.0) * 2.0, 0.0], 2.0),
            Some([max, 0]),
            "clamped after the division"
        );
        assert_eq!(velocity_per_tick([(max as f64 - 1.0) * 2.0, 0.0], 2.0), Some([max - 1, 0]));
        assert_eq!(velocity_per_tick([f64::NAN, 120.0], 60.0), Some([0, 2]), "NaN reads as 0");
        assert_eq!(velocity_per_tick([f64::INFINITY, f64::NEG_INFINITY], 60.0), None, "infinities read as 0");
        assert_eq!(velocity_per_tick([f64::NEG_INFINITY, 60.0], 60.0), Some([0, 1]));
        assert_eq!(velocity_per_tick([f64::NAN, f64::NAN], 60.0), None);
    }

    /// The tick loop takes each new request's velocity through [`velocity_per_tick`] at its own
    /// tick rate (`request_velocity` in `STATS`), keeps it until the next request, and a `CENTRE`
    /// clears it.
    #[test]
    fn the_tick_loop_takes_a_requests_velocity_per_tick_and_a_centre_command_clears_it() {
        use clipmap::source::{HashSource, TextureDesc};
        let dir = tempfile::tempdir().unwrap();
        let desc = TextureDesc::new([4096, 4096], 128, clipmap::texel::TexelFormat::RGBA8, [32, 32]).unwrap();
        let options = Options { shm_dir: dir.path().to_path_buf(), tick_hz: 4.0, ..Options::new("vel") };
        let (ticker, _, join) = Ticker::start(Arc::new(HashSource::new(desc)), &options).unwrap();
        let client = clipmap::shm::Client::attach(dir.path(), "vel").unwrap();
        let mut asked = 0;
        let mut request = |velocity: [f64; 2]| {
            assert!(client.request_centre([2000, 2000], velocity), "the request lock is free");
            asked += 1;
            let deadline = Instant::now() + Duration::from_secs(20);
            loop {
                let stats = ticker.stats();
                if stats.requests_seen == asked {
                    return stats.request_velocity;
                }
                assert!(Instant::now() < deadline, "request {asked} not taken in 20 s: {}", stats.requests_seen);
                std::thread::sleep(Duration::from_millis(5));
            }
        };
        assert_eq!(request([100.0, -1e300]), Some([25, -(1 << 30)]), "at 4 ticks a second");
        assert_eq!(request([f64::NAN, f64::INFINITY]), None);
        assert_eq!(request([-10.0, 1.0]), Some([-3, 0]));
        assert_eq!(request([0.0, 0.0]), None);
        assert_eq!(request([40.0, 8.0]), Some([10, 2]));
        let (reply, rx) = oneshot::channel();
        ticker.send(Command::Centre { centre: [100, 100], reply }).unwrap();
        let reply = rx.blocking_recv().unwrap();
        assert_eq!(reply, Reply::Centre([100, 100]));
        assert_eq!(super::super::protocol::render(&super::super::protocol::Answer::Done(reply)), "OK centre 100 100");
        let deadline = Instant::now() + Duration::from_secs(20);
        while ticker.stats().socket_centres == 0 {
            assert!(Instant::now() < deadline, "no tick published the CENTRE in 20 s");
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(ticker.stats().request_velocity, None, "a CENTRE clears the request's velocity");
        ticker.send(Command::Stop).unwrap();
        join.join().unwrap();
    }

    #[test]
    fn a_paging_reason_is_logged_when_it_changes_not_every_tick() {
        let p = |reason| LevelPaging { reason, grid: [8, 8], ..LevelPaging::default() };
        let mut last = Vec::new();
        let hover = [p(Reason::Hover), p(Reason::Hover)];
        assert_eq!(
            log_reason_changes(&mut last, &hover, 1.0, 1),
            Vec::<usize>::new(),
            "the first tick: where it starts"
        );
        assert_eq!(log_reason_changes(&mut last, &hover, 1.0, 2), Vec::<usize>::new());
        let bound = [p(Reason::SourceBound), p(Reason::Hover)];
        assert_eq!(log_reason_changes(&mut last, &bound, 4.0, 3), vec![0]);
        assert_eq!(log_reason_changes(&mut last, &bound, 4.0, 4), Vec::<usize>::new());
        assert_eq!(last, vec![Reason::SourceBound, Reason::Hover]);
    }
}
