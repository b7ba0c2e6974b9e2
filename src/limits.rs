//! [`Limits`]: every bound the paging engine keeps, in one place; beside it the fixed bounds on
//! what a texture, a tile and a service may be (the constants below), each checked once where the
//! value enters ([`crate::source::TextureDesc`], [`crate::service::Options::check`], the tools'
//! options) and named in the error that refuses it.
//!
//! Owns the numbers only; [`crate::queue`], [`crate::cache`] and [`crate::clip`] enforce them.
//! Bounds of the configuration reader are [`crate::config::Limits`]; those of data preparation
//! are [`crate::prep::Limits`].

/// Largest tile of a stack level, in bytes: a tile is one read into one buffer, and a cache holds
/// a grid of them, so a tile larger than this is refused before anything is allocated.
pub const MAX_TILE_BYTES: u64 = 1 << 28;

/// Most tiles one stack level's clip window may span (its tile grid holds at least that many
/// slots, each with its own bookkeeping): refuses tiny tiles (`--tile 1`) before they multiply.
pub const MAX_GRID_TILES: u64 = 1 << 16;

/// Farthest a clip centre (and a velocity per tick) may be from the origin, level-0 texels, on
/// each axis: requests beyond are clamped to it. Far outside any texture (at most 2^26), yet far
/// from where differences and products of centres overflow 64 bits.
pub const MAX_CENTRE: i64 = 1 << 40;

/// Most control connections a service may be told to accept at once (`--max-connections`).
pub const MAX_CONNECTIONS: usize = 4096;

/// Smallest copy budget per tick, milliseconds: a smaller one would round to no work at all and
/// freeze every update.
pub const MIN_BUDGET_MS: f64 = 0.001;

/// Longest idle time of a control connection, milliseconds (`--idle-ms`): one day.
pub const MAX_IDLE_MS: u64 = 86_400_000;

/// Most frames one `cliptex roam` flies (a report line each).
pub const MAX_ROAM_FRAMES: u64 = 10_000_000;

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
