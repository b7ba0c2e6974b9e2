//! [`Limits`]: every bound the paging engine keeps, in one place.
//!
//! Owns the numbers only; [`crate::queue`], [`crate::cache`] and [`crate::clip`] enforce them.

use serde::Serialize;

/// Bounds on the engine's queues, reads and memory. Each is a hard limit, not a hint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Limits {
    /// Most requests waiting (not yet started) in one stream server's read queue. Requests beyond
    /// it are dropped, most urgent kept, and asked for again at the next tick if still wanted.
    pub max_pending_reads: usize,
    /// Most reads of one queue running at once (each holds a blocking thread and a tile buffer).
    pub max_in_flight_reads: usize,
    /// Most reads of one queue running or finished but not yet taken by the update tick; no read
    /// starts while this many are outstanding.
    pub max_ready_reads: usize,
    /// Capacity of each queue's command channel; an update that does not fit is skipped (and
    /// counted) rather than blocking the tick.
    pub queue_commands: usize,
    /// Most bytes of tiles held in main memory, all levels together.
    pub cache_bytes: usize,
    /// Most bytes of clip windows (all levels together) a clipmap may allocate.
    pub window_bytes: usize,
    /// Most stream servers (read queues).
    pub max_streams: usize,
    /// Most tile files a file source keeps open at once (least recently used closed first; 0
    /// opens every file for each read).
    pub max_open_files: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_pending_reads: 256,
            max_in_flight_reads: 4,
            max_ready_reads: 256,
            queue_commands: 8,
            cache_bytes: 1 << 30,
            window_bytes: 2 << 30,
            max_streams: 64,
            max_open_files: 64,
        }
    }
}
