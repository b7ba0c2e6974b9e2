//! Every bound of the project, in one place: [`Limits`] (the paging engine's queues, reads and
//! memory), [`ConfigLimits`] (the configuration reader's, against hostile or broken files),
//! [`PrepLimits`] (data preparation's memory), and the fixed bounds on what a texture, a tile, a
//! service, a picture or a flight may be (the constants). Each is checked once, where the value
//! enters (`clipmap::config`, `clipmap::source::TextureDesc`, `clipmap_service::Options::check`,
//! the tools' value parsers), and named in the error that refuses it. `docs/RELIABILITY.md`
//! lists them with what each protects against.
//!
//! Owns the numbers only; the modules that take the values in enforce them. The old paths
//! (`config::Limits`, `prep::Limits`, `report::dump::MAX_DUMP_TEXELS`, ...) re-export these.

/// Largest level-0 edge a texture may have (texels): 2^30, WebMercatorQuad zoom 22 at 256-texel
/// tiles (the whole earth at about 4 cm). Level indices of tiles stay below 2^31 and every
/// position, product and difference of positions the engine and the mapping form stays far inside
/// 64 bits; texel positions of this size need f64 (30 bits of integer part), never f32
/// (docs/GEOREF.md, "Sizes up to 2^30").
pub const MAX_TEXTURE_SIZE: u64 = 1 << 30;

/// Most texels one dump reads (a 4096 x 4096 region): 64 MiB of RGBA in memory at most (128 MiB
/// for the 16-bit formats).
pub const MAX_DUMP_TEXELS: u64 = 4096 * 4096;

/// Most problem tiles listed one by one; the rest are only counted.
pub const MAX_LISTED_PROBLEMS: usize = 50;

/// Largest centre alignment the tools accept (level texels): a level's window would jump by
/// more than most clip sizes beyond it.
pub const MAX_CENTRE_ALIGNMENT: u64 = 4096;

/// Largest copy budget accepted, in milliseconds.
pub const MAX_BUDGET_MS: f64 = 10_000.0;

/// Longest side of a level picture in pixels (larger windows are shown one pixel per several texels).
pub const MAX_LEVEL_PIXELS: u32 = 1024;

/// Largest `--max-memory`, MiB (16 TiB): a larger value would overflow when turned into bytes.
pub const MAX_MEMORY_MIB: u64 = 1 << 24;

/// Largest tile of a stack level, in bytes: a tile is one read into one buffer, and a cache holds
/// a grid of them, so a tile larger than this is refused before anything is allocated.
pub const MAX_TILE_BYTES: u64 = 1 << 28;

/// Most tiles one stack level's clip window may span (its tile grid holds at least that many
/// slots, each with its own bookkeeping): refuses tiny tiles (`--tile 1`) before they multiply.
pub const MAX_GRID_TILES: u64 = 1 << 16;

/// Farthest a clip centre (and a velocity per tick) may be from the origin, level-0 texels, on
/// each axis: requests beyond are clamped to it. Far outside any texture (at most 2^30), yet far
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

/// Largest `--max-patch-bytes` (`clipmapd --growing`, `cliptex grow add` and `watch`): 4 GiB of
/// texels in one patch. A patch is held in memory whole (its bytes as they arrive, then its
/// texels), and the decoder's own bound is a few times this, so a larger value would only let one
/// request take the machine's memory.
pub const MAX_PATCH_BYTES: u64 = 4 << 30;

/// Most bytes of a patch's sidecar (its JSON description): a few lines; a longer one is refused
/// from its length before it is read.
pub const MAX_SIDECAR_BYTES: u64 = 64 << 10;

/// Most bytes of a growing texture's own small files (`grid.json`, `state.json`, a patch's
/// record): a longer one is damaged, refused from its length before it is read.
pub const MAX_RECORD_BYTES: u64 = 64 << 10;

/// Most levels a growing texture's `state.json` may say it has: far more than a grid of 2^40
/// texels (the farthest a patch may be from the origin) in tiles of one texel needs.
pub const MAX_GROWING_LEVELS: u32 = 64;

use serde::Serialize;

/// Bounds on the engine's queues, reads and memory. Each is a hard limit, not a hint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Limits {
    /// Most requests waiting (not yet started) in one stream server's read queue. Requests beyond
    /// it are dropped, most urgent kept, and asked for again at the next tick if still wanted.
    pub max_pending_reads: usize,
    /// Most reads of one queue running at once (each holds a blocking thread and a tile buffer);
    /// a source that serves more at once (a remote one: its requests in flight) raises it, up to
    /// `max_ready_reads`.
    pub max_in_flight_reads: usize,
    /// Most reads of one queue running or finished but not yet taken by the update tick; no read
    /// starts while this many are outstanding.
    pub max_ready_reads: usize,
    /// Capacity of each queue's command channel; an update that does not fit is skipped (and
    /// counted) rather than blocking the tick.
    pub queue_commands: usize,
    /// Most bytes of the image caches, all levels together: the whole mapping (every level's grid
    /// of tiles, their tags and the header). Layout 1 bounded tiles (1 GiB) and texel windows
    /// (2 GiB) apart; layout 2 holds the tiles only, under this one bound.
    pub cache_bytes: usize,
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
            cache_bytes: 3 << 30,
            max_streams: 64,
            max_open_files: 64,
        }
    }
}

/// Every bound the reader enforces against hostile or broken input.
#[derive(Clone, Debug)]
pub struct ConfigLimits {
    /// Largest configuration file read (bytes). Real files are a few kilobytes.
    pub max_file_bytes: usize,
    /// Longest word (bytes). Performer's buffers held 255 (tokens) and 2047 (values).
    pub max_word_bytes: usize,
    /// Most entries (tokens) in one file.
    pub max_entries: usize,
    /// Most items in one list.
    pub max_list_items: usize,
    /// Most findings reported for one file before giving up.
    pub max_diagnostics: usize,
    /// Largest texture edge accepted (texels): 2^32.
    pub max_texture_size: u64,
    /// Largest tile edge accepted (texels).
    pub max_tile_size: u64,
    /// Most levels in a clip texture (Performer's `PFCLIPTEXTURE_MAX_LEVELS`).
    pub max_levels: u32,
    /// Largest mem region edge in tiles (Performer clamps to 128).
    pub max_mem_region_tiles: u64,
}

impl Default for ConfigLimits {
    fn default() -> Self {
        ConfigLimits {
            max_file_bytes: 4 << 20,
            max_word_bytes: 4096,
            max_entries: 10_000,
            max_list_items: 1024,
            max_diagnostics: 200,
            max_texture_size: 1 << 32,
            max_tile_size: 1 << 16,
            max_levels: 33,
            max_mem_region_tiles: 128,
        }
    }
}

/// Every memory bound of a preparation run.
#[derive(Clone, Debug)]
pub struct PrepLimits {
    /// Most memory a run may plan to use: the decoded size of an in-memory input image, and the
    /// buffers of `clipmap::prep::pipeline::buffer_memory` (for filtered sources about three bands of one row
    /// of level-0 tiles).
    pub max_memory_bytes: u64,
    /// Most bytes of one band of a pyramid level (pyramid levels are one tile each, written in
    /// bands of rows).
    pub pyramid_band_bytes: u64,
}

impl Default for PrepLimits {
    fn default() -> Self {
        PrepLimits { max_memory_bytes: 512 << 20, pyramid_band_bytes: 16 << 20 }
    }
}

/// Most views one clip texture keeps, the primary included (docs/VIEWS.md): the engine's bound,
/// and one view record in the mapping for each further view.
pub const MAX_VIEWS: usize = 16;
