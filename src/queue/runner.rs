//! The read-queue runner: one tokio task per stream server owning that queue's whole state.
//!
//! Owns the pending requests (sorted by priority, bounded), the reads in flight, the completions
//! delivered but not yet taken, and the queue's counters. Nothing else touches them: the handle
//! only sends commands. Reads run on `spawn_blocking` threads, never on the async workers.
//!
//! Each blocking task reads a run of requests, the most urgent first, rather than one: a task per
//! read cost two thread wake-ups and switches per tile, about as much CPU as reading a 256 KiB
//! tile from the page cache (the engine's CPU per tile in the ingest benchmark fell from medians
//! of 100..125 to 75..90 µs). The pending requests are shared out among the free read slots
//! (`max_in_flight_reads`), at most [`MAX_BATCH`] a task. Each read is reported the moment it
//! ends (a channel to this runner), not at the end of its run, and its thread then yields the
//! core, so that the update tick, waiting for a core on a small machine, is not kept waiting for
//! a run of reads that decode or generate tiles and never block (without the yield the real-time
//! flight's tick p99 went from 0.9 to 5 ms on two cores). The price: a request that becomes more
//! urgent waits until a slot's run ends (at most `MAX_BATCH` reads, about a millisecond from the
//! page cache); a tile of a run that left its mem region meanwhile is not read, because its slot's
//! claim moved to another tile (`ImageMemory::fill` refuses it, counted stale).

use super::{Completion, Outcome, Priority, QueueStats, ReadRequest};
use crate::limits::Limits;
use crate::shm::ImageMemory;
use crate::source::{SourceError, TileId, TileSource};
use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::mpsc as std_mpsc;
use std::sync::Arc;
use tokio::sync::{mpsc, oneshot};
use tokio::task::JoinSet;

/// What the handle asks of the runner.
/// Most requests one blocking task reads in a row (see the module's documentation).
pub(super) const MAX_BATCH: usize = 16;

pub(super) enum Command {
    /// The tiles wanted now, with fresh priorities; `drained` completions were taken since the
    /// last update.
    Update { wanted: Vec<ReadRequest>, drained: usize },
    /// Answer once no read runs and none can start before the owner takes completions.
    Flush(oneshot::Sender<()>),
}

/// A message from a runner to the owner of the queues.
pub(super) enum Event {
    /// A read finished.
    Done(Completion),
    /// The runner's counters changed.
    Counters { stream: usize, stats: QueueStats },
}

pub(super) struct Runner {
    pub stream: usize,
    pub commands: mpsc::Receiver<Command>,
    pub events: std_mpsc::Sender<Event>,
    pub source: Arc<dyn TileSource>,
    pub memory: Arc<ImageMemory>,
    pub limits: Limits,
    pending: Vec<ReadRequest>,
    in_flight: HashSet<TileId>,
    /// Completions sent but not yet reported taken, oldest first.
    delivered: VecDeque<TileId>,
    /// One task per run of reads; each ends with the tiles it did not report (all of them when
    /// its thread panicked, none otherwise).
    reads: JoinSet<Vec<TileId>>,
    /// Each read's completion, sent by its thread the moment it ends.
    done_tx: mpsc::UnboundedSender<Completion>,
    done_rx: mpsc::UnboundedReceiver<Completion>,
    flushes: Vec<oneshot::Sender<()>>,
    stats: QueueStats,
}

impl Runner {
    pub fn new(
        stream: usize,
        commands: mpsc::Receiver<Command>,
        events: std_mpsc::Sender<Event>,
        source: Arc<dyn TileSource>,
        memory: Arc<ImageMemory>,
        limits: Limits,
    ) -> Self {
        let (done_tx, done_rx) = mpsc::unbounded_channel();
        Runner {
            stream,
            commands,
            events,
            source,
            memory,
            limits,
            pending: Vec::new(),
            in_flight: HashSet::new(),
            delivered: VecDeque::new(),
            reads: JoinSet::new(),
            done_tx,
            done_rx,
            flushes: Vec::new(),
            stats: QueueStats::default(),
        }
    }

    /// Serves commands and reads until the handle side is dropped.
    pub async fn run(mut self) {
        loop {
            self.start_reads();
            self.answer_flushes();
            tokio::select! {
                command = self.commands.recv() => match command {
                    None => break,
                    Some(Command::Update { wanted, drained }) => self.update(wanted, drained),
                    Some(Command::Flush(reply)) => self.flushes.push(reply),
                },
                Some(done) = self.done_rx.recv() => {
                    if !self.finished(done) {
                        break;
                    }
                    self.publish_counters();
                }
                Some(joined) = self.reads.join_next(), if !self.reads.is_empty() => {
                    // Its completions were sent before it ended: take them first.
                    let mut alive = true;
                    while let Ok(done) = self.done_rx.try_recv() {
                        alive &= self.finished(done);
                    }
                    let mut unreported = joined.unwrap_or_default();
                    unreported.retain(|t| self.in_flight.contains(t));
                    for tile in unreported {
                        let source = std::io::Error::other("the tile read's thread failed (panicked)");
                        let outcome = Outcome::Failed(None, SourceError::Io { tile, source });
                        alive &= self.finished(Completion { tile, outcome });
                    }
                    if !alive {
                        break;
                    }
                    self.publish_counters();
                }
            }
        }
    }

    /// Books a finished read and hands it to the owner; false when the owner is gone.
    fn finished(&mut self, done: Completion) -> bool {
        self.in_flight.remove(&done.tile);
        self.delivered.push_back(done.tile);
        match &done.outcome {
            Outcome::Filled(..) => {
                self.stats.reads_done += 1;
                self.stats.bytes_read += self.source.desc().tile_bytes(done.tile.level) as u64;
            }
            Outcome::Failed(..) => self.stats.reads_failed += 1,
            Outcome::NotWanted => self.stats.stale_dropped += 1,
        }
        self.events.send(Event::Done(done)).is_ok()
    }

    fn can_start(&self) -> bool {
        !self.pending.is_empty()
            && self.reads.len() < self.limits.max_in_flight_reads.max(1)
            && self.in_flight.len() + self.delivered.len() < self.limits.max_ready_reads.max(1)
    }

    fn start_reads(&mut self) {
        while self.can_start() {
            // One blocking task reads a run of the most urgent requests, one after the other, so
            // that a read costs no thread hand-off (about as much CPU as the read itself when
            // tiles come from the page cache): the pending requests are shared among the free
            // read slots, at most `MAX_BATCH` each.
            let slots = self.limits.max_in_flight_reads.max(1).saturating_sub(self.reads.len()).max(1);
            let room = self.limits.max_ready_reads.max(1) - self.in_flight.len() - self.delivered.len();
            let n = self.pending.len().div_ceil(slots).clamp(1, MAX_BATCH).min(room);
            let batch: Vec<TileId> = self.pending.drain(..n).map(|r| r.tile).collect();
            for &tile in &batch {
                self.in_flight.insert(tile);
            }
            self.stats.reads_started += batch.len() as u64;
            let source = Arc::clone(&self.source);
            let memory = Arc::clone(&self.memory);
            let done = self.done_tx.clone();
            self.reads.spawn(async move {
                let tiles = batch.clone();
                let read = tokio::task::spawn_blocking(move || {
                    for tile in batch {
                        // Straight into the tile's slot, under its claim: nothing is copied later.
                        let outcome = match memory.fill(tile, |slot| source.read_into(tile, slot)) {
                            None => Outcome::NotWanted,
                            Some((generation, Ok(delivered))) => Outcome::Filled(generation, delivered),
                            Some((generation, Err(e))) => Outcome::Failed(Some(generation), e),
                        };
                        // Reported at once, not at the end of the run: the tick takes it next.
                        if done.send(Completion { tile, outcome }).is_err() {
                            return;
                        }
                        // Lets a waiting thread (the update tick) have the core now rather than at
                        // the end of this thread's time slice: a run of reads that decode or
                        // generate tiles never blocks, and would otherwise delay the tick by
                        // milliseconds on a machine with few cores.
                        std::thread::yield_now();
                    }
                });
                // A panicked thread reported some of its tiles: the runner fails the others.
                match read.await {
                    Ok(()) => Vec::new(),
                    Err(_) => tiles,
                }
            });
        }
    }

    fn answer_flushes(&mut self) {
        // Every run's task joined, not only every read reported: a task that has reported all
        // its reads still holds its read slot until it is joined, and the requests waiting for
        // that slot could start.
        if self.in_flight.is_empty() && self.reads.is_empty() && !self.can_start() {
            for reply in self.flushes.drain(..) {
                let _ = reply.send(());
            }
        }
    }

    /// Replaces the pending set by `wanted`: stale requests are dropped, tiles already being read
    /// are coalesced, priorities refreshed, and the queue cut to its bound.
    fn update(&mut self, wanted: Vec<ReadRequest>, drained: usize) {
        for _ in 0..drained.min(self.delivered.len()) {
            self.delivered.pop_front();
        }
        let busy: HashSet<TileId> = self.in_flight.iter().chain(self.delivered.iter()).copied().collect();
        let mut fresh: HashMap<TileId, Priority> = HashMap::with_capacity(wanted.len());
        for r in wanted {
            if busy.contains(&r.tile) {
                self.stats.coalesced += 1;
                continue;
            }
            fresh.entry(r.tile).and_modify(|p| *p = (*p).min(r.priority)).or_insert(r.priority);
        }
        let was_pending: HashSet<TileId> = self.pending.iter().map(|r| r.tile).collect();
        self.stats.stale_dropped += was_pending.iter().filter(|t| !fresh.contains_key(t)).count() as u64;
        self.stats.requested += fresh.keys().filter(|t| !was_pending.contains(t)).count() as u64;
        let mut pending: Vec<ReadRequest> =
            fresh.into_iter().map(|(tile, priority)| ReadRequest { tile, priority }).collect();
        pending.sort_unstable_by_key(|r| (r.priority, r.tile));
        if pending.len() > self.limits.max_pending_reads {
            self.stats.overflow_dropped += (pending.len() - self.limits.max_pending_reads) as u64;
            pending.truncate(self.limits.max_pending_reads);
        }
        self.stats.pending = pending.len() as u64;
        self.stats.peak_pending = self.stats.peak_pending.max(self.stats.pending);
        self.pending = pending;
        self.publish_counters();
    }

    fn publish_counters(&mut self) {
        self.stats.pending = self.pending.len() as u64;
        self.stats.in_flight = self.in_flight.len() as u64;
        let _ = self.events.send(Event::Counters { stream: self.stream, stats: self.stats.clone() });
    }
}
