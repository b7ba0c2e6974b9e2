//! Read queues: one per stream server, reading tiles asynchronously in priority order.
//!
//! Owns getting tiles from a [`TileSource`] into their slots of the image caches
//! ([`ImageMemory`]) without ever blocking the update tick: the synchronous [`ReadQueues`] front
//! (used by [`crate::clip`]) sends each queue's runner the tiles wanted now with fresh
//! [priorities](fn@priority), and drains finished reads from a channel. A read writes its tile
//! straight into the slot (`pread` into the mapping, a decoder or generator writing there), under
//! the slot's claim (`ImageMemory::fill`); nothing is copied afterwards. Which slot a tile has
//! is `crate::cache`'s business; which tiles are wanted is decided by the caller from
//! [`crate::geom`]. A tile whose texels changed at the source (a growing texture's rebuilt tile,
//! [`crate::clip::Clipmap::refresh`]) is read again the same way: the engine reopens its settled
//! slot (`ImageMemory::replace`) and asks for it like any other tile; the queues do not tell
//! the two apart.
//!
//! Design: each queue is a cloneable handle (a bounded command sender) plus a private runner task
//! owning all of the queue's state, on the process's runtime ([`crate::runtime`]); blocking reads
//! run on `spawn_blocking`. Completions come back over a channel that the tick drains when it runs, so
//! the tick stays synchronous and deterministic: [`ReadQueues::flush`] waits until every read that
//! could start has finished, which lets tests step reads and ticks in lock step.
//!
//! Bounds ([`Limits`]): pending requests per queue, reads running or undrained per queue, command
//! channel capacity. A tile leaving every mem region is dropped from the queue at the next update
//! (counted as stale); a tile wanted while its read runs is coalesced with it.

pub mod priority;
mod runner;

pub use priority::{priority, soonest_first, Priority};

use crate::limits::Limits;
use crate::shm::ImageMemory;
use crate::source::{Delivered, SourceError, TileId, TileSource};
use runner::{Command, Event, Runner};
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc as std_mpsc;
use std::sync::Arc;
use thiserror::Error;
use tokio::sync::{mpsc, oneshot};

/// A tile wanted now, and how urgently.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadRequest {
    /// The tile.
    pub tile: TileId,
    /// Lower is more urgent.
    pub priority: Priority,
}

/// How a read ended.
#[derive(Debug)]
pub enum Outcome {
    /// The tile's slot holds what was read, filled in this generation of the slot's claim.
    Filled(u64, Delivered),
    /// The slot no longer belonged to the tile when the read started: nothing was read.
    NotWanted,
    /// The read failed (in this generation of the slot's claim, when it got that far); the slot
    /// holds no promise.
    Failed(Option<u64>, SourceError),
}

/// A finished read.
#[derive(Debug)]
pub struct Completion {
    /// The tile read.
    pub tile: TileId,
    /// How it ended.
    pub outcome: Outcome,
}

/// Counters of one queue (or the sum over queues).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(default)]
pub struct QueueStats {
    /// Distinct tiles newly queued.
    pub requested: u64,
    /// Requests for a tile whose read was already running (or finished, not yet taken).
    pub coalesced: u64,
    /// Queued requests dropped because their tile was no longer wanted.
    pub stale_dropped: u64,
    /// Requests dropped because the queue was full.
    pub overflow_dropped: u64,
    /// Updates skipped because a queue's command channel was full.
    pub updates_skipped: u64,
    /// Reads started.
    pub reads_started: u64,
    /// Reads that delivered a tile.
    pub reads_done: u64,
    /// Reads that failed.
    pub reads_failed: u64,
    /// Requests waiting now.
    pub pending: u64,
    /// Most requests ever waiting in one queue.
    pub peak_pending: u64,
    /// Reads running now.
    pub in_flight: u64,
    /// Bytes of the tiles delivered (reads done).
    pub bytes_read: u64,
}

impl QueueStats {
    fn add(&mut self, o: &QueueStats) {
        self.requested += o.requested;
        self.coalesced += o.coalesced;
        self.stale_dropped += o.stale_dropped;
        self.overflow_dropped += o.overflow_dropped;
        self.updates_skipped += o.updates_skipped;
        self.reads_started += o.reads_started;
        self.reads_done += o.reads_done;
        self.reads_failed += o.reads_failed;
        self.pending += o.pending;
        self.peak_pending = self.peak_pending.max(o.peak_pending);
        self.in_flight += o.in_flight;
        self.bytes_read += o.bytes_read;
    }
}

/// Why the queues could not start.
#[derive(Debug, Error)]
pub enum QueueError {
    /// The process's async runtime could not be built.
    #[error("cannot start the read-queue runtime: {0}")]
    Runtime(#[source] std::io::Error),
    /// A stream count of 0 or above the limit.
    #[error("{streams} stream servers requested: expected 1..={max}")]
    Streams {
        /// The stream servers requested.
        streams: usize,
        /// The most there may be.
        max: usize,
    },
}

/// One queue's runner as its owner holds it: the command channel and what the owner knows of
/// the runner's state.
#[derive(Debug)]
pub(crate) struct QueueHandle {
    commands: mpsc::Sender<Command>,
    /// Updates sent (taken by the channel).
    sent: u64,
    /// Whether the last update sent asked for nothing (it left nothing pending): another that asks
    /// for nothing and gives back nothing would change nothing, and is not sent.
    sent_nothing: bool,
    /// The updates the runner had taken when it was last idle (its [`Runner`] stores it).
    idle: Arc<AtomicU64>,
}

/// The read queues of one texture, one per stream server. The source chooses each tile's queue
/// ([`TileSource::stream_of`]: by default tile column S mod n; a [`crate::source::FileSource`]
/// follows its configuration's stream servers), so a tile always goes to the same queue.
pub struct ReadQueues {
    source: Arc<dyn TileSource>,
    /// The runners' tasks on the shared runtime, stopped when the queues are dropped.
    runners: Vec<tokio::task::JoinHandle<()>>,
    /// Disconnected once every runner's task has ended (each holds a sender until it is dropped).
    runners_gone: std_mpsc::Receiver<()>,
    handles: Vec<QueueHandle>,
    events: std_mpsc::Receiver<Event>,
    /// Tiles whose completions were taken, per stream, since the last update sent to it.
    drained: Vec<Vec<TileId>>,
    counters: Vec<QueueStats>,
    skipped: u64,
}

impl ReadQueues {
    /// Starts `streams` queues reading from `source` into `memory`, on the process's runtime.
    pub fn new(
        source: Arc<dyn TileSource>,
        memory: Arc<ImageMemory>,
        streams: usize,
        limits: Limits,
    ) -> Result<Self, QueueError> {
        if streams == 0 || streams > limits.max_streams {
            return Err(QueueError::Streams { streams, max: limits.max_streams });
        }
        // Reads in flight are bounded by each runner (`max_in_flight_reads`), threads by the
        // shared runtime (`runtime::MAX_BLOCKING_THREADS`).
        let runtime = crate::runtime::shared().map_err(QueueError::Runtime)?;
        let (tx, events) = std_mpsc::channel();
        let (alive, runners_gone) = std_mpsc::channel::<()>();
        let mut runners = Vec::with_capacity(streams);
        let handles = (0..streams)
            .map(|stream| {
                let (commands, rx) = mpsc::channel(limits.queue_commands.max(1));
                let idle = Arc::new(AtomicU64::new(0));
                let mut runner = Runner::new(
                    stream,
                    rx,
                    tx.clone(),
                    Arc::clone(&source),
                    Arc::clone(&memory),
                    limits,
                    Arc::clone(&idle),
                );
                runner.streams = streams;
                let alive = alive.clone();
                runners.push(runtime.spawn(async move {
                    let _alive = alive;
                    runner.run().await
                }));
                QueueHandle { commands, sent: 0, sent_nothing: false, idle }
            })
            .collect();
        Ok(ReadQueues {
            source,
            runners,
            runners_gone,
            handles,
            events,
            drained: vec![Vec::new(); streams],
            counters: vec![QueueStats::default(); streams],
            skipped: 0,
        })
    }

    /// Number of stream servers.
    pub fn streams(&self) -> usize {
        self.handles.len()
    }

    /// The stream server that reads `tile` (always below [`streams`](Self::streams)).
    pub fn stream_of(&self, tile: TileId) -> usize {
        let n = self.handles.len();
        self.source.stream_of(tile, n) % n
    }

    /// Tells every queue which tiles are wanted now (all of them: a tile not listed is dropped
    /// from its queue). Never blocks: a queue whose command channel is full skips this update.
    /// A queue told last time that nothing is wanted is not told so again while no completion
    /// was taken since (it would change nothing), so a clipmap at rest wakes no queue.
    pub fn update(&mut self, wanted: &[ReadRequest]) {
        let mut per_stream: Vec<Vec<ReadRequest>> = vec![Vec::new(); self.handles.len()];
        for r in wanted {
            per_stream[self.stream_of(r.tile)].push(*r);
        }
        for (stream, wanted) in per_stream.into_iter().enumerate() {
            let nothing = wanted.is_empty();
            let handle = &mut self.handles[stream];
            if nothing && handle.sent_nothing && self.drained[stream].is_empty() {
                continue;
            }
            let drained = std::mem::take(&mut self.drained[stream]);
            match handle.commands.try_send(Command::Update { wanted, drained }) {
                Ok(()) => {
                    handle.sent += 1;
                    handle.sent_nothing = nothing;
                }
                Err(e) => {
                    // Kept for the next update that fits.
                    if let mpsc::error::TrySendError::Full(Command::Update { drained, .. })
                    | mpsc::error::TrySendError::Closed(Command::Update { drained, .. }) = e
                    {
                        self.drained[stream] = drained;
                    }
                    self.skipped += 1;
                }
            }
        }
    }

    /// Takes every finished read, oldest first. Never blocks.
    pub fn drain(&mut self) -> Vec<Completion> {
        let mut done = Vec::new();
        while let Ok(event) = self.events.try_recv() {
            match event {
                Event::Done(c) => {
                    let stream = self.stream_of(c.tile);
                    self.drained[stream].push(c.tile);
                    done.push(c);
                }
                Event::Counters { stream, stats } => self.counters[stream] = stats,
            }
        }
        done
    }

    /// Blocks until, in every queue, no read is running and none can start before the finished
    /// ones are drained. For tests and offline simulation; must not be called from async code.
    pub fn flush(&mut self) {
        let mut replies = Vec::new();
        for h in &self.handles {
            // Idle since it took the last update sent: nothing runs or can start there, and what
            // it read is in the event channel already (the runner stores this last, releasing).
            if h.idle.load(Ordering::Acquire) == h.sent {
                continue;
            }
            let (tx, rx) = oneshot::channel();
            if h.commands.blocking_send(Command::Flush(tx)).is_ok() {
                replies.push(rx);
            }
        }
        for rx in replies {
            let _ = rx.blocking_recv();
        }
    }

    /// Each queue's counters, in stream-server order, as of the last [`drain`](Self::drain)
    /// (`updates_skipped` is counted only in the sum of [`stats`](Self::stats)).
    pub(crate) fn stream_stats(&self) -> Vec<QueueStats> {
        self.counters.clone()
    }

    /// Counters summed over the queues, as of the last [`drain`](Self::drain).
    pub fn stats(&self) -> QueueStats {
        let mut sum = QueueStats { updates_skipped: self.skipped, ..QueueStats::default() };
        for c in &self.counters {
            sum.add(c);
        }
        sum
    }
}

/// How long dropping the queues waits for their runners' tasks to end (they end within a poll;
/// this only bounds a runtime with no free worker).
const STOP_WAIT: std::time::Duration = std::time::Duration::from_secs(5);

impl Drop for ReadQueues {
    fn drop(&mut self) {
        // The runners stop, and their state (the source, the memory, the reads' tasks) is dropped
        // before this returns. Reads already running finish on their own threads (a read cannot
        // be stopped midway), and each stops at the end of its current tile: the completion
        // channel's receiver, dropped with these queues, refuses its report. Nothing waits for them.
        for runner in &self.runners {
            runner.abort();
        }
        let gone = crate::runtime::wait(|| self.runners_gone.recv_timeout(STOP_WAIT));
        if let Err(std_mpsc::RecvTimeoutError::Timeout) = gone {
            tracing::warn!("read queues dropped: a runner did not stop within {STOP_WAIT:?}");
        }
    }
}

#[cfg(test)]
mod tests;
