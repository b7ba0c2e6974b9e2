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
//! ends, straight to the owner's channel (which the update tick drains without blocking), not at
//! the end of its run and not through this runner: waking the runner for every tile cost a
//! thread wake-up per tile again (an inter-processor interrupt on a virtual machine, and the
//! runner's own turn on a core). The runner books a run's reads when its task ends; the owner
//! tells it which tiles it took ([`Command::Update`]'s `drained`), so a tile taken before its
//! run ended is known as taken. A reading thread yields the core once it has read for
//! [`YIELD_AFTER`] since its last yield, so that the update tick, waiting for a core on a small
//! machine, is not kept waiting for a run of reads that decode or generate tiles and never block
//! (without any yield the real-time flight's tick p99 went from 0.9 to 5 ms on two cores; a yield
//! after every tile cost a context switch a tile when tiles come from the page cache). The price: a request that becomes more
//! urgent waits until a slot's run ends (at most `MAX_BATCH` reads, about a millisecond from the
//! page cache); a tile of a run that left its mem region meanwhile is not read, because its slot's
//! claim moved to another tile (`ImageMemory::fill` refuses it, counted stale).

use super::{Completion, Outcome, Priority, QueueStats, ReadRequest};
use crate::limits::Limits;
use crate::shm::ImageMemory;
use crate::source::{SourceError, TileId, TileSource};
use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc as std_mpsc;
use std::sync::Arc;
use tokio::sync::{mpsc, oneshot};
use tokio::task::JoinSet;

/// Most requests one blocking task reads in a row (see the module's documentation).
pub(super) const MAX_BATCH: usize = 16;

/// How long a reading thread reads before it yields the core (see the module's documentation):
/// about a tile generated or decoded, a few tiles from the page cache.
pub(super) const YIELD_AFTER: std::time::Duration = std::time::Duration::from_micros(250);

/// How a reported read ended, for the runner's counters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ended {
    Filled,
    Failed,
    NotWanted,
}

/// The reads of one run reported so far, in order (shared by the run's thread and its task, so
/// that a thread that panics still leaves a true record).
type Reported = Arc<std::sync::Mutex<Vec<(TileId, Ended)>>>;

/// What the handle asks of the runner.
pub(super) enum Command {
    /// The tiles wanted now, with fresh priorities; the owner took the completions of `drained`
    /// since the last update.
    Update { wanted: Vec<ReadRequest>, drained: Vec<TileId> },
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
    /// The queues in all (for [`TileSource::read_slots`]).
    pub streams: usize,
    pub commands: mpsc::Receiver<Command>,
    pub events: std_mpsc::Sender<Event>,
    pub source: Arc<dyn TileSource>,
    pub memory: Arc<ImageMemory>,
    pub limits: Limits,
    pending: Vec<ReadRequest>,
    /// For each tile, the reads of it started whose completions the owner has not yet said it
    /// took (running, or reported and waiting in the owner's channel). A count, not a flag: a
    /// tile taken before its run ended may be read again by a second run while the first still
    /// runs, and both completions may be taken before either run ends.
    owed: HashMap<TileId, u32>,
    /// The sum of `owed`: reads running or undrained, bounded by `max_ready_reads`.
    owed_total: usize,
    /// Reads in runs whose task has not been joined yet.
    running: usize,
    /// One task per run of reads; each ends with its batch and what its thread reported.
    reads: JoinSet<(Vec<TileId>, Reported)>,
    flushes: Vec<oneshot::Sender<()>>,
    stats: QueueStats,
    /// Updates taken so far.
    updates: u64,
    /// The number of updates taken when this runner last was idle (no read running, none that
    /// can start before the owner takes completions): the owner's flush needs no round trip
    /// while it equals the updates it sent (see [`answer_flushes`](Self::answer_flushes)).
    idle: Arc<AtomicU64>,
}

impl Runner {
    pub fn new(
        stream: usize,
        commands: mpsc::Receiver<Command>,
        events: std_mpsc::Sender<Event>,
        source: Arc<dyn TileSource>,
        memory: Arc<ImageMemory>,
        limits: Limits,
        idle: Arc<AtomicU64>,
    ) -> Self {
        Runner {
            stream,
            streams: 1,
            commands,
            events,
            source,
            memory,
            limits,
            pending: Vec::new(),
            owed: HashMap::new(),
            owed_total: 0,
            running: 0,
            reads: JoinSet::new(),
            flushes: Vec::new(),
            stats: QueueStats::default(),
            updates: 0,
            idle,
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
                    Some(Command::Update { wanted, drained }) => {
                        self.updates += 1;
                        self.update(wanted, drained);
                    }
                    Some(Command::Flush(reply)) => self.flushes.push(reply),
                },
                Some(joined) = self.reads.join_next(), if !self.reads.is_empty() => {
                    // The task returns its batch whether its thread ended or panicked.
                    let Ok((batch, reported)) = joined else { continue };
                    self.running -= batch.len();
                    let reported = std::mem::take(&mut *reported.lock().unwrap_or_else(|e| e.into_inner()));
                    for &(tile, ended) in &reported {
                        self.booked(tile, ended);
                    }
                    // A thread that panicked reported some of its tiles: the runner fails the others
                    // (a batch names a tile once), which the owner takes like any completion.
                    let unreported: Vec<TileId> = if reported.len() == batch.len() {
                        Vec::new()
                    } else {
                        let done: HashSet<TileId> = reported.iter().map(|&(t, _)| t).collect();
                        batch.into_iter().filter(|t| !done.contains(t)).collect()
                    };
                    for tile in unreported {
                        let source = std::io::Error::other("the tile read's thread failed (panicked)");
                        let outcome = Outcome::Failed(None, SourceError::Io { tile, source });
                        if self.events.send(Event::Done(Completion { tile, outcome })).is_err() {
                            return;
                        }
                        self.booked(tile, Ended::Failed);
                    }
                    self.publish_counters();
                }
            }
        }
    }

    /// Counts a read its run reported to the owner (whose completion stays owed until the owner
    /// says it took it, which it may have done already).
    fn booked(&mut self, tile: TileId, ended: Ended) {
        match ended {
            Ended::Filled => {
                self.stats.reads_done += 1;
                self.stats.bytes_read += self.source.desc().tile_bytes(tile.level) as u64;
            }
            Ended::Failed => self.stats.reads_failed += 1,
            Ended::NotWanted => self.stats.stale_dropped += 1,
        }
    }

    /// Reads the queue runs at once: the engine's bound, or more where the source can serve
    /// more at once ([`TileSource::read_slots`]: a remote source's requests in flight, each
    /// read holding its thread for a round trip), never more than `max_ready_reads`.
    /// A source's own number makes each read a task of its own: its reads wait for round trips,
    /// and a run of them in one task would wait for each in turn. Returns the slots and whether
    /// they are the source's.
    fn slots(&self) -> (usize, bool) {
        let own = self.limits.max_in_flight_reads.max(1);
        match self.source.read_slots(self.stream, self.streams) {
            Some(n) if n > own => (n.min(self.limits.max_ready_reads.max(1)).max(own), true),
            _ => (own, false),
        }
    }

    fn can_start(&self) -> bool {
        self.can_start_with(self.slots().0)
    }

    fn can_start_with(&self, slots: usize) -> bool {
        !self.pending.is_empty() && self.reads.len() < slots && self.owed_total < self.limits.max_ready_reads.max(1)
    }

    fn start_reads(&mut self) {
        let (all, one_each) = self.slots();
        while self.can_start_with(all) {
            // One blocking task reads a run of the most urgent requests, one after the other, so
            // that a read costs no thread hand-off (about as much CPU as the read itself when
            // tiles come from the page cache): the pending requests are shared among the free
            // read slots, at most `MAX_BATCH` each.
            let slots = all.saturating_sub(self.reads.len()).max(1);
            let room = self.limits.max_ready_reads.max(1) - self.owed_total;
            let n = if one_each { 1 } else { self.pending.len().div_ceil(slots).clamp(1, MAX_BATCH).min(room) };
            let batch: Vec<TileId> = self.pending.drain(..n).map(|r| r.tile).collect();
            for &tile in &batch {
                *self.owed.entry(tile).or_default() += 1;
            }
            self.owed_total += batch.len();
            self.running += batch.len();
            self.stats.reads_started += batch.len() as u64;
            let source = Arc::clone(&self.source);
            let memory = Arc::clone(&self.memory);
            let events = self.events.clone();
            let reported: Reported = Arc::default();
            let record = Arc::clone(&reported);
            self.reads.spawn(async move {
                let tiles = batch.clone();
                // Whether the thread ends or panics, what it reported is in `reported`.
                let _ = tokio::task::spawn_blocking(move || {
                    let mut since_yield = std::time::Instant::now();
                    // The run's tiles, announced: a source reading byte ranges of one object
                    // fetches those lying side by side with one request.
                    source.will_read(&batch);
                    for tile in batch {
                        // Straight into the tile's slot, under its claim: nothing is copied later.
                        let (outcome, ended) = match memory.fill(tile, |slot| source.read_into(tile, slot)) {
                            None => {
                                source.withdraw(tile);
                                (Outcome::NotWanted, Ended::NotWanted)
                            }
                            Some((generation, Ok(delivered))) => {
                                (Outcome::Filled(generation, delivered), Ended::Filled)
                            }
                            Some((generation, Err(e))) => (Outcome::Failed(Some(generation), e), Ended::Failed),
                        };
                        // Reported at once and straight to the owner: the tick takes it next.
                        if events.send(Event::Done(Completion { tile, outcome })).is_err() {
                            return;
                        }
                        record.lock().unwrap_or_else(|e| e.into_inner()).push((tile, ended));
                        // Lets a waiting thread (the update tick) have the core now rather than at
                        // the end of this thread's time slice: a run of reads that decode or
                        // generate tiles never blocks, and would otherwise delay the tick by
                        // milliseconds on a machine with few cores.
                        if since_yield.elapsed() >= YIELD_AFTER {
                            std::thread::yield_now();
                            since_yield = std::time::Instant::now();
                        }
                    }
                })
                .await;
                (tiles, reported)
            });
        }
    }

    fn answer_flushes(&mut self) {
        // Every run's task joined, not only every read reported: a task that has reported all
        // its reads still holds its read slot until it is joined, and the requests waiting for
        // that slot could start.
        if self.reads.is_empty() && !self.can_start() {
            // Idle until the next update: reads start only from pending requests, which only an
            // update adds, and the owed completions (which can hold the reads back) only an
            // update pays off.
            // Stored after every completion of this state was sent and every counter published
            // (release), so an owner that sees it (acquire) finds them in its channel; and before
            // the flushes are answered, so an owner woken by an answer sees it too.
            self.idle.store(self.updates, Ordering::Release);
            for reply in self.flushes.drain(..) {
                let _ = reply.send(());
            }
        }
    }

    /// Replaces the pending set by `wanted`: stale requests are dropped, tiles already being read
    /// are coalesced, priorities refreshed, and the queue cut to its bound.
    fn update(&mut self, wanted: Vec<ReadRequest>, drained: Vec<TileId>) {
        for tile in drained {
            // Taken, whether or not its run has ended: the tile may be asked for (and read) again
            // at once unless another read of it is still owed.
            if let std::collections::hash_map::Entry::Occupied(mut owed) = self.owed.entry(tile) {
                *owed.get_mut() -= 1;
                self.owed_total -= 1;
                if *owed.get() == 0 {
                    owed.remove();
                }
            }
        }
        let mut fresh: HashMap<TileId, Priority> = HashMap::with_capacity(wanted.len());
        for r in wanted {
            if self.owed.contains_key(&r.tile) {
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
        self.stats.in_flight = self.running as u64;
        let _ = self.events.send(Event::Counters { stream: self.stream, stats: self.stats.clone() });
    }
}
