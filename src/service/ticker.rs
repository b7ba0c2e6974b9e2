//! The tick loop: a dedicated thread that owns the [`Clipmap`] (synchronous, with its own small
//! read runtime, its image caches in the mapping) and the mapping's [`Writer`], and runs one
//! update tick per period.
//!
//! Handle and runner: [`Ticker`] is the cloneable handle (a bounded command sender and a watch on
//! the latest [`TickStats`]); the runner owns every piece of mutable state, without locks. Each
//! tick takes the newest renderer request from the request mapping, then ticks the engine, which
//! publishes its snapshot into the mapping, and beats the heartbeat. Commands (budget, border, centre, stop)
//! are taken between ticks and answered through a one-shot reply.

use super::own_views::{OwnViews, Setup};
use super::requests::{apply_lod, bounded_centre, velocity_per_tick};
use super::stats::TickStats;
use super::{Options, ServiceError};
use crate::clip::{Clipmap, Settings, ViewId, PRIMARY};
use crate::paging::adaptive::{LevelPaging, Reason};
use crate::shm::{Writer, WriterOptions};
use crate::source::TileSource;
use std::sync::mpsc::{self, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tokio::sync::{oneshot, watch};

/// Commands waiting for the tick loop, at most (a full queue answers "busy", never blocks).
pub(crate) const COMMAND_QUEUE: usize = 64;

/// What the tick loop is asked to do between ticks.
#[derive(Debug)]
pub enum Command {
    /// Sets the copy budget per tick (ms; `None`: unlimited).
    Budget(Option<f64>, oneshot::Sender<String>),
    /// Sets the invalid border (clamped by the engine); replies with the border applied.
    Border(u64, oneshot::Sender<String>),
    /// Moves the clip centre (level-0 texels).
    Centre([i64; 2], oneshot::Sender<String>),
    /// Adds a named view of a weight (docs/VIEWS.md), with grids of its own when asked;
    /// replies `Err` with why not.
    ViewAdd(String, f64, bool, oneshot::Sender<Result<String, String>>),
    /// Removes a view.
    ViewRemove(String, oneshot::Sender<Result<String, String>>),
    /// Moves a view's centre (`main`: the primary's, as `Centre`).
    ViewCentre(String, [i64; 2], oneshot::Sender<Result<String, String>>),
    /// Sets a view's weight.
    ViewWeight(String, f64, oneshot::Sender<Result<String, String>>),
    /// Sets a view's LOD window: offset, effective levels (`None`: all).
    ViewLod(String, u32, Option<u32>, oneshot::Sender<Result<String, String>>),
    /// A LOD request from the socket: height, pixel angle, effective levels (0: all).
    ViewHeight(String, f64, f64, u32, oneshot::Sender<Result<String, String>>),
    /// Puts the mapping under its name, its views in it, and starts ticking
    /// ([`Ticker::prepare`], [`Ticker::publish`]).
    Publish(oneshot::Sender<Result<(), crate::shm::ShmError>>),
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
    /// name (or could not be made). Blocks: call it off async worker threads.
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
    pub fn publish(&self) -> Result<oneshot::Receiver<Result<(), crate::shm::ShmError>>, ServiceError> {
        let (tx, rx) = oneshot::channel();
        self.send(Command::Publish(tx)).map_err(|_| ServiceError::TickLoopDied)?;
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
    centre: [i64; 2],
    velocity: Option<[i64; 2]>,
    last_request: u64,
    /// The primary's last LOD request's count.
    last_lod: u64,
    /// Levels every view addresses at once unless told otherwise (`None`: all).
    effective_levels: Option<u32>,
    stats: TickStats,
    started: Instant,
    /// A growing texture's shared state, and the growth block's last published values.
    growing: Option<(Arc<crate::growing::serve::Served>, Option<crate::shm::layout::Growth>)>,
    /// Each level's paging reason as last logged (the log says when one changes).
    reasons: Vec<Reason>,
    /// Each further view's centre and velocity as asked for, and its last request's count.
    view_state: std::collections::BTreeMap<ViewId, ViewState>,
    /// The views with grids of their own ([`super::own_views`]).
    own: OwnViews,
}

/// A further view's centre as asked for (socket or request record).
#[derive(Clone, Debug, Default)]
struct ViewState {
    centre: Option<[i64; 2]>,
    velocity: Option<[i64; 2]>,
    last_request: u64,
    last_lod: u64,
}

impl Runner {
    fn new(
        source: Arc<dyn TileSource>,
        o: &Options,
        commands: mpsc::Receiver<Command>,
        stats_tx: watch::Sender<TickStats>,
    ) -> Result<(Runner, Started), ServiceError> {
        let desc = source.desc().clone();
        let mut settings = Settings {
            budget_ns: o.budget_ms.map(|ms| (ms * 1e6) as u64),
            // One read queue per stream server the configuration names.
            streams: source.stream_servers(),
            centre_alignment: o.centre_alignment,
            ..Settings::default().with_paging(&o.paging)
        };
        settings.view_spread = o.view_spread;
        if o.growing.is_some() {
            // A growing texture's tile without data is read again when data arrives for it
            // (`Clipmap::refresh`), not on a timer.
            settings.retry_after_ticks = u64::MAX / 4;
        }
        // Refused before anything is created in the shared directory.
        let shape = Clipmap::shape_for(&desc, &settings);
        let heights = source.heights().map(|h| crate::shm::layout::Heights::of(&h.format, h.levels));
        let placement = crate::shm::layout::place_with(&shape, heights.is_some())
            .and_then(|p| crate::shm::layout::with_views(p, crate::shm::layout::views::SERVICE_RECORDS))
            .ok_or_else(|| crate::clip::ClipError::Memory(crate::shm::memory::shape_error(&shape)))?;
        let limit = settings.limits.cache_bytes as u64;
        let needed = placement.total_bytes.saturating_add(settings.pool_bytes);
        if needed > limit {
            return Err(crate::clip::ClipError::CacheBytes { needed, limit }.into());
        }
        // The engine keeps its image caches in the mapping itself: each tile is read straight
        // into its slot, where renderers read it, and nothing is copied afterwards.
        let period_ns = (1e9 / o.tick_hz).round() as u64;
        let request_mode = o.request_mode.unwrap_or(o.shm_mode);
        // Published once the views are in it (`Runner::publish`): a reader that finds the mapping
        // finds the command line's views.
        let writer = Writer::prepare(
            WriterOptions::new(&o.shm_dir, &o.name, shape, desc.format())
                .mode(o.shm_mode)
                .request_mode(request_mode)
                .tick_period_ns(period_ns)
                .heights(heights),
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
        let size = desc.size();
        let stats = TickStats { tick_hz: o.tick_hz, budget_ms: o.budget_ms, ..TickStats::default() };
        let runner = Runner {
            clipmap,
            writer,
            commands,
            stats_tx,
            period: Duration::from_secs_f64(1.0 / o.tick_hz),
            hz: o.tick_hz,
            centre: [(size[0] / 2) as i64, (size[1] / 2) as i64],
            velocity: None,
            last_request: 0,
            last_lod: 0,
            effective_levels: o.effective_levels,
            stats,
            started: Instant::now(),
            growing: o.growing.as_ref().map(|g| (g.served().clone(), None)),
            reasons: Vec::new(),
            view_state: Default::default(),
            own: OwnViews::new(setup),
        };
        let mut runner = runner;
        // Holding the service's lock: what a dead predecessor left of its views' own mappings goes.
        for view in crate::shm::writer::remove_dead_own_mappings(&o.shm_dir, &o.name) {
            tracing::info!(view = %view, "removed the own mapping a stopped service left for view {view}");
        }
        if let Some(e) = o.effective_levels {
            let lod = crate::clip::LodWindow { offset: 0, effective: e };
            if let Err(why) = runner.clipmap.set_view_lod(PRIMARY, lod) {
                runner.writer.close();
                return Err(ServiceError::BadOption(format!("--effective-levels {e}: {why}")));
            }
        }
        for v in &o.views {
            if let Err(why) = runner.add_view(&v.name, v.weight, v.own) {
                runner.own.close_all();
                runner.writer.close();
                return Err(ServiceError::BadOption(format!("--view {}: {why}", v.name)));
            }
        }
        runner.publish_views();
        Ok((runner, started))
    }

    /// Puts the mapping under its name: every view it was started with is in it by then, and
    /// the own views take their tiles from it under that name from now on.
    ///
    /// One tick first: the mapping appears with its first snapshot and (a growing texture) its
    /// growth block in it, as when it appeared after the loop had ticked.
    fn publish(&mut self) -> Result<(), crate::shm::ShmError> {
        self.tick();
        self.writer.publish()?;
        self.own.published(self.writer.path());
        Ok(())
    }

    fn run(mut self) {
        // Nothing ticks before the mapping is published (`Ticker::publish`).
        loop {
            match self.commands.recv() {
                Ok(Command::Publish(reply)) => {
                    let r = self.publish();
                    let ok = r.is_ok();
                    let _ = reply.send(r);
                    if ok {
                        break;
                    }
                }
                Ok(Command::Stop) | Err(_) => {
                    self.writer.close();
                    self.own.close_all();
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
                if now >= last_start + min_gap
                    && (self.writer.request_count() != self.last_request || self.own.requests_changed())
                {
                    self.stats.ticks_on_request += 1;
                    break;
                }
                match self.commands.recv_timeout((next - now).min(poll)) {
                    Ok(Command::Stop) | Err(RecvTimeoutError::Disconnected) => break 'ticks,
                    Ok(cmd) => {
                        // A command may be long (a view with grids of its own makes a mapping).
                        self.apply(cmd);
                        self.writer.alive();
                        self.own.alive();
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
        self.own.close_all();
    }

    fn apply(&mut self, cmd: Command) {
        match cmd {
            Command::Budget(ms, reply) => {
                self.clipmap.set_budget_ns(ms.map(|ms| (ms * 1e6) as u64));
                self.stats.budget_ms = ms;
                tracing::info!(budget_ms = ?ms, "copy budget changed");
                let _ = reply.send(match ms {
                    Some(ms) => format!("budget {ms} ms"),
                    None => "budget off".to_string(),
                });
            }
            Command::Border(b, reply) => {
                self.clipmap.set_invalid_border(b);
                let applied = self.clipmap.invalid_border();
                tracing::info!(asked = b, applied, "invalid border changed");
                let _ = reply.send(format!("border {applied}"));
            }
            Command::Centre(c, reply) => {
                let c = bounded_centre(c);
                self.centre = c;
                self.velocity = None;
                self.stats.request_velocity = None;
                self.stats.socket_centres += 1;
                let _ = reply.send(format!("centre {} {}", c[0], c[1]));
            }
            Command::ViewAdd(name, weight, own, reply) => {
                let r = self.add_view(&name, weight, own);
                if r.is_ok() {
                    self.publish_views();
                }
                let _ = reply.send(r);
            }
            Command::ViewRemove(name, reply) => {
                let r = match self.clipmap.view_named(&name).filter(|&id| id != PRIMARY) {
                    None => Err(self.no_view(&name)),
                    Some(id) => {
                        self.view_state.remove(&id);
                        // The record first (readers see the view removed), then its own mapping.
                        let r = self.clipmap.remove_view(id);
                        self.own.remove(&name);
                        r.map(|()| format!("view {name} removed")).map_err(|e| e.to_string())
                    }
                };
                if r.is_ok() {
                    tracing::info!(view = %name, "view removed");
                    self.publish_views();
                }
                let _ = reply.send(r);
            }
            Command::ViewCentre(name, c, reply) => {
                let c = bounded_centre(c);
                let r = match self.clipmap.view_named(&name) {
                    None => Err(self.no_view(&name)),
                    Some(PRIMARY) => {
                        self.centre = c;
                        self.velocity = None;
                        self.stats.request_velocity = None;
                        self.stats.socket_centres += 1;
                        Ok(format!("view main centre {} {}", c[0], c[1]))
                    }
                    Some(_) if self.own.get(&name).is_some() => {
                        let v = self.own.get_mut(&name).expect("looked up above");
                        v.centre = c;
                        v.velocity = None;
                        self.stats.socket_centres += 1;
                        Ok(format!("view {name} centre {} {}", c[0], c[1]))
                    }
                    Some(id) => {
                        let st = self.view_state.entry(id).or_default();
                        st.centre = Some(c);
                        st.velocity = None;
                        self.stats.socket_centres += 1;
                        Ok(format!("view {name} centre {} {}", c[0], c[1]))
                    }
                };
                let _ = reply.send(r);
            }
            Command::ViewWeight(name, w, reply) => {
                let r = match self.clipmap.view_named(&name) {
                    None => Err(self.no_view(&name)),
                    Some(id) => self
                        .clipmap
                        .set_view_weight(id, w)
                        .map(|()| format!("view {name} weight {w}"))
                        .map_err(|e| e.to_string()),
                };
                if r.is_ok() {
                    self.publish_views();
                }
                let _ = reply.send(r);
            }
            Command::ViewLod(name, offset, effective, reply) => {
                let r = match self.clipmap.view_named(&name) {
                    None => Err(self.no_view(&name)),
                    Some(id) => {
                        let lod = crate::clip::LodWindow { offset, effective: effective.unwrap_or(u32::MAX) };
                        let (map, id) = match self.own.get_mut(&name) {
                            Some(v) => (&mut v.clipmap, PRIMARY),
                            None => (&mut self.clipmap, id),
                        };
                        map.set_view_lod(id, lod).map(|()| describe_lod(&name, lod)).map_err(|e| e.to_string())
                    }
                };
                if r.is_ok() {
                    self.publish_views();
                }
                let _ = reply.send(r);
            }
            Command::ViewHeight(name, height, pixel_angle, effective, reply) => {
                let r = match self.clipmap.view_named(&name) {
                    None => Err(self.no_view(&name)),
                    Some(id) => {
                        let req = crate::shm::writer::LodRequest {
                            height,
                            pixel_angle,
                            effective: u64::from(effective),
                            count: 0,
                        };
                        let (map, id) = match self.own.get_mut(&name) {
                            Some(v) => (&mut v.clipmap, PRIMARY),
                            None => (&mut self.clipmap, id),
                        };
                        apply_lod(map, id, &name, &req, &mut self.stats).map(|lod| describe_lod(&name, lod))
                    }
                };
                if r.is_ok() {
                    self.publish_views();
                }
                let _ = reply.send(r);
            }
            Command::Stop | Command::Publish(_) => {}
        }
    }

    /// Publishes the views' figures now, not at the next tick: `VIEWS` and `STATS` asked after a
    /// `VIEW ADD`, `REMOVE` or `WEIGHT` was answered show it (as the mapping already does).
    fn publish_views(&mut self) {
        self.stats.views = self.view_stats();
        self.stats_tx.send_replace(self.stats.clone());
    }

    /// Adds a named view, centred where the primary is until it is told otherwise, in the shared
    /// grids or (`own`) with grids of its own ([`super::own_views`]).
    fn add_view(&mut self, name: &str, weight: f64, own: bool) -> Result<String, String> {
        if own {
            // Its own mapping first, then the record that sends readers there: a reader never
            // finds the record without the mapping.
            self.clipmap.check_new_name(name).map_err(|e| e.to_string())?;
            self.own.add(name, self.centre)?;
            if let Err(e) = self.clipmap.add_view_elsewhere(name, weight) {
                self.own.remove(name);
                return Err(e.to_string());
            }
            return Ok(format!("view {name} added, weight {weight}, grids of its own"));
        }
        let id = self.clipmap.add_named_view(name, weight).map_err(|e| e.to_string())?;
        if let Some(e) = self.effective_levels {
            let _ = self.clipmap.set_view_lod(id, crate::clip::LodWindow { offset: 0, effective: e });
        }
        self.view_state.insert(id, ViewState { centre: Some(self.centre), ..ViewState::default() });
        tracing::info!(view = %name, weight, "view added");
        Ok(format!("view {name} added, weight {weight}"))
    }

    /// The error for a view name no view has, naming those that exist.
    fn no_view(&self, name: &str) -> String {
        let names: Vec<&str> =
            self.clipmap.view_ids().into_iter().filter_map(|id| self.clipmap.view_name(id)).collect();
        format!("no view `{name}`: the views are {}", names.join(", "))
    }

    /// Takes each further view's request record (docs/SHM.md, "Asking for a view's centre"):
    /// a new request for the view's current incarnation moves it.
    fn take_view_requests(&mut self) {
        let reqs = self.writer.view_requests();
        let mut lods = Vec::new();
        for (id, st) in self.view_state.iter_mut() {
            let Some(req) = reqs.get(*id as usize - 1).copied().flatten() else { continue };
            let incarnation = self.writer.memory().view_incarnation(*id as usize);
            if Some(req.incarnation) != incarnation {
                continue;
            }
            if req.count != st.last_request {
                st.last_request = req.count;
                st.centre = Some(req.centre);
                st.velocity = velocity_per_tick(req.velocity, self.hz);
            }
            if let Some(lod) = req.lod.filter(|l| l.count != st.last_lod) {
                st.last_lod = lod.count;
                lods.push((*id, lod));
            }
        }
        for (id, lod) in lods {
            let name = self.clipmap.view_name(id).unwrap_or("?").to_string();
            let _ = apply_lod(&mut self.clipmap, id, &name, &lod, &mut self.stats);
        }
    }

    fn tick(&mut self) {
        if let Some(req) = self.writer.request() {
            if req.count != self.last_request {
                self.last_request = req.count;
                self.centre = req.centre;
                self.velocity = velocity_per_tick(req.velocity, self.hz);
                self.stats.request_velocity = self.velocity;
                self.stats.requests_seen = req.count;
            }
            if let Some(lod) = req.lod.filter(|l| l.count != self.last_lod) {
                self.last_lod = lod.count;
                let _ = apply_lod(&mut self.clipmap, PRIMARY, "main", &lod, &mut self.stats);
            }
        }
        (self.stats.request_faults, self.stats.request_fault) = self.writer.request_faults();
        if let Some((served, _)) = &self.growing {
            let changed = served.take_changed(self.clipmap.desc());
            // Every clipmap reads the changed tiles again: the primary's and each own view's.
            self.own.refresh(&changed);
            self.clipmap.refresh(changed);
            if self.stats.engine.ticks.is_multiple_of(256) {
                let (c, own) = (&self.clipmap, &self.own);
                served.retain_partial(|t| c.holds(t) || own.holds(t));
            }
        }
        self.take_view_requests();
        for (&id, st) in &self.view_state {
            if let Some(c) = st.centre {
                let _ = self.clipmap.move_view(id, c, st.velocity);
            }
        }
        let t0 = Instant::now();
        let report = self.clipmap.tick(self.centre, self.velocity);
        // Alive after each clipmap's tick, not only after the whole tick (see `OwnViews::tick`).
        self.writer.alive();
        self.own.tick(&self.clipmap, &self.writer, self.hz, &mut self.stats);
        self.stats.views = self.view_stats();
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
        s.min_lod = report.min_lod;
        s.levels_disabled = report.disabled_levels.len() as u64;
        s.invalid_border = self.clipmap.invalid_border();
        s.bytes_published = self.clipmap.stats().queue.bytes_read;
        s.publications = self.clipmap.stats().publications;
        s.resident_bytes = self.clipmap.resident_bytes() + self.own.resident_bytes();
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

impl Runner {
    /// Each view's figures, the primary first.
    fn view_stats(&self) -> Vec<super::stats::ViewStats> {
        let main = &self.clipmap;
        main.view_ids()
            .into_iter()
            .map(|vid| {
                let name = main.view_name(vid).unwrap_or("").to_string();
                // A view with grids of its own: its figures are its own clipmap's primary's.
                let own = self.own.get(&name).filter(|_| main.view_elsewhere(vid));
                let (m, id) = match own {
                    Some(v) => (&v.clipmap, PRIMARY),
                    None => (main, vid),
                };
                let levels = m.level_count();
                let min_lod = m.view_min_lod(id).unwrap_or(levels as f64);
                super::stats::ViewStats {
                    name,
                    grids: if own.is_some() { "own" } else { "shared" }.to_string(),
                    shared_reads: own.map_or(0, |v| v.shared_reads()),
                    weight: main.view_weight(vid).unwrap_or(1.0),
                    centre: m.view_centre(id).ok().flatten(),
                    min_lod,
                    levels_disabled: (0..levels as u32).filter(|&k| ((k + 1) as f64) <= min_lod).count() as u64,
                    lod_offset: m.view_lod(id).map_or(0, |l| l.offset),
                    effective_levels: m
                        .view_lod(id)
                        .map_or(levels as u32, |l| l.effective.min(levels as u32 - l.offset.min(levels as u32))),
                    resident_levels: m.view_resident_levels(id).unwrap_or_default(),
                    valid: (0..levels as u32)
                        .map(|k| m.view_level(id, k).map(|l| l.valid).unwrap_or(crate::geom::Rect::EMPTY))
                        .map(|r| [r.s0, r.t0, r.s1, r.t1])
                        .collect(),
                }
            })
            .collect()
    }
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

/// The reply to `VIEW LOD`: the levels the view shows from the next tick.
fn describe_lod(name: &str, lod: crate::clip::LodWindow) -> String {
    if lod.effective == u32::MAX {
        format!("view {name} lod offset {} effective all", lod.offset)
    } else {
        format!("view {name} lod offset {} effective {}", lod.offset, lod.effective)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// docs/SHM.md, "What the service does with a request": the velocity (level-0 texels per
    /// second) is divided by the tick rate and rounded to texels per tick (halves away from zero),
    /// clamped to 2^26 a tick, NaN and infinities read as 0; both 0 is no velocity at all (the
    /// engine then follows the centre's change).
    #[test]
    fn a_requests_velocity_is_divided_by_the_tick_rate_rounded_clamped_and_nan_or_infinite_reads_zero() {
        let max = 1i64 << 26;
        assert_eq!(crate::source::MAX_TEXTURE_SIZE as i64, max);
        assert_eq!(velocity_per_tick([600.0, -120.0], 60.0), Some([10, -2]));
        assert_eq!(velocity_per_tick([100.0, 0.0], 4.0), Some([25, 0]), "one component may be 0");
        assert_eq!(velocity_per_tick([10.0, -6.0], 4.0), Some([3, -2]), "2.5 and -1.5: halves away from zero");
        assert_eq!(velocity_per_tick([10.0, -9.9], 4.0), Some([3, -2]), "-2.475: to the nearest");
        assert_eq!(velocity_per_tick([1.0, -1.9], 4.0), None, "0.25 and -0.475 round to 0: no velocity");
        assert_eq!(velocity_per_tick([0.0, -0.0], 60.0), None, "0: unknown");
        assert_eq!(velocity_per_tick([1e300, -1e300], 60.0), Some([max, -max]), "clamped to 2^26 a tick");
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
        use crate::source::{HashSource, TextureDesc};
        let dir = tempfile::tempdir().unwrap();
        let desc = TextureDesc::new([4096, 4096], 128, crate::texel::TexelFormat::RGBA8, [32, 32]).unwrap();
        let options = Options { shm_dir: dir.path().to_path_buf(), tick_hz: 4.0, ..Options::new("vel") };
        let (ticker, _, join) = Ticker::start(Arc::new(HashSource::new(desc)), &options).unwrap();
        let client = crate::shm::Client::attach(dir.path(), "vel").unwrap();
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
        assert_eq!(request([100.0, -1e300]), Some([25, -(1 << 26)]), "at 4 ticks a second");
        assert_eq!(request([f64::NAN, f64::INFINITY]), None);
        assert_eq!(request([-10.0, 1.0]), Some([-3, 0]));
        assert_eq!(request([0.0, 0.0]), None);
        assert_eq!(request([40.0, 8.0]), Some([10, 2]));
        let (tx, rx) = oneshot::channel();
        ticker.send(Command::Centre([100, 100], tx)).unwrap();
        assert_eq!(rx.blocking_recv().unwrap(), "centre 100 100");
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
