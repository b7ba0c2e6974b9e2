//! The shared-memory layout, version 2: every offset and size, as pure arithmetic.
//!
//! The mapping publishes each level's image cache: a toroidal grid of slots, one slot one whole
//! tile in the tile files' texel order, each with a small seqlocked tag, plus one seqlocked
//! snapshot of every level's valid region and min LOD. Renderers' requests go through a separate
//! small request mapping, so the texel mapping can be mapped read-only.
//!
//! `docs/SHM.md` documents the same table for readers in other languages; `include/clipmap_shm.h`
//! and `clients/python/clipmap_shm.py` mirror it, and a test checks that they agree with this file.
//! All integers are little-endian. Every field the writer changes while readers run is 8 bytes,
//! naturally aligned, and accessed atomically.

use clipmap_base::geom::{tiles_in_level, Rect};

/// Magic bytes at offset 0 of the texel mapping.
pub const MAGIC: [u8; 8] = *b"CLIPMAP2";
/// Magic bytes at offset 0 of the request mapping.
pub const REQUEST_MAGIC: [u8; 8] = *b"CLIPREQ2";
/// Layout version.
pub const VERSION: u32 = 2;
/// Alignment of every level's tags and slots (a page).
pub const PAGE: u64 = 4096;
/// Most levels a mapping describes.
pub const MAX_LEVELS: usize = 32;
/// Bytes of the request mapping.
pub const REQUEST_BYTES: u64 = 4096;
/// Most attempts a reader makes at one seqlocked read (the snapshot, the growth block or a tag)
/// before it gives up for now: the writer holds a lock for microseconds, so more means the writer
/// is stuck or gone.
pub const MAX_RETRIES: usize = 64;

/// Header field offsets of the texel mapping.
pub mod header {
    /// `[u8; 8]` magic `CLIPMAP2`.
    pub const MAGIC: usize = 0;
    /// `u32` layout version (2).
    pub const VERSION: usize = 8;
    /// `u32` bytes before the first level's tags (a multiple of 4096).
    pub const HEADER_BYTES: usize = 12;
    /// `u64` size of the whole mapping.
    pub const TOTAL_BYTES: usize = 16;
    /// `u32` texel format code (see [`super::format_code`]).
    pub const TEXEL_FORMAT: usize = 24;
    /// `u32` bytes per texel; for a block-compressed format ([`super::is_block_code`]) the bytes
    /// of one 4 x 4 block (8 or 16).
    pub const BYTES_PER_TEXEL: usize = 28;
    /// `u32` clip size.
    pub const CLIP_SIZE: usize = 32;
    /// `u32` number of levels.
    pub const LEVEL_COUNT: usize = 36;
    /// `u64` level-0 width.
    pub const LEVEL0_S: usize = 40;
    /// `u64` level-0 height.
    pub const LEVEL0_T: usize = 48;
    /// `u32` process id of the writer.
    pub const WRITER_PID: usize = 56;
    /// `u64` (atomic) tick counter, incremented every update tick.
    pub const HEARTBEAT: usize = 64;
    /// `u64` (atomic) wall-clock time of the last tick, milliseconds since the Unix epoch.
    pub const HEARTBEAT_MS: usize = 72;
    /// `u64` a number unique to each start of the writer.
    pub const GENERATION: usize = 80;
    /// `u64` (atomic) flags: bit 0 set when the writer shut down cleanly.
    pub const FLAGS: usize = 88;
    /// `u64` the tick period in nanoseconds (the tick rate is 1e9 / this).
    pub const TICK_PERIOD_NS: usize = 96;
    /// `u64` byte offset of the views block ([`super::views`]; a multiple of 4096 after every
    /// level's slots), 0 when the mapping has none.
    pub const VIEWS_OFFSET: usize = 104;
    /// The snapshot: every level's state and min LOD under one seqlock.
    pub const SNAPSHOT: usize = 128;
    /// Level descriptors (static after creation), [`super::DESC_BYTES`] each.
    pub const LEVEL_DESCS: usize = SNAPSHOT + super::snapshot::LEVELS + super::MAX_LEVELS * super::STATE_BYTES;
    /// The growth block ([`super::growth`]): what a growing texture holds so far, under its own
    /// seqlock (all zero for a texture that does not grow).
    pub const GROWTH: usize = LEVEL_DESCS + super::MAX_LEVELS * super::DESC_BYTES;
    /// The heights block ([`super::heights`]): whether the texels are heights, and their scale,
    /// offset, nodata value and level rule (all zero for a texture that is not heights). Static.
    pub const HEIGHTS: usize = GROWTH + super::GROWTH_BYTES;
    /// The georef block ([`super::georef`]): where the texture lies on the Earth, its CRS and
    /// level 0's affine transform (all zero for a texture without georeferencing). Static.
    pub const GEOREF: usize = HEIGHTS + super::HEIGHTS_BYTES;
    /// End of the fixed header.
    pub const END: usize = GEOREF + super::GEOREF_BYTES;
}

/// Most bytes of the georef block's CRS definition.
pub const GEOREF_DEFINITION_MAX: usize = 1024;
/// Bytes of the georef block.
pub const GEOREF_BYTES: usize = georef::DEFINITION + GEOREF_DEFINITION_MAX;
/// Georef block fields, relative to [`header::GEOREF`]; static (written before the mapping
/// appears under its name). A mapping whose block is all zero has no georeferencing: a texture
/// that does not say where it lies, or a mapping of a writer from before the block
/// (docs/SHM.md, "Georef block"). Each level's own affine terms are in its descriptor
/// ([`desc::GEOREF`]).
pub mod georef {
    /// `u32` 1 when the texture is georeferenced (the fields below mean something), 0 otherwise.
    pub const PRESENT: usize = 0;
    /// `u32` the CRS's EPSG code, 0 when none is known.
    pub const EPSG: usize = 4;
    /// `u32` flags: bit 0 ([`WRAPS`]) the texture spans 360 degrees of longitude.
    pub const FLAGS: usize = 8;
    /// `u32` bytes of the CRS definition at [`DEFINITION`] (at most 1024).
    pub const DEFINITION_LEN: usize = 12;
    /// `f64` bits: level 0's GDAL geotransform term 0, the map x of level 0's north-west corner.
    pub const ORIGIN_X: usize = 16;
    /// `f64` bits: level 0's GDAL geotransform term 3, the map y of level 0's north-west corner
    /// (a level whose height was rounded down has its north edge further south; every level
    /// shares the south-west corner).
    pub const ORIGIN_Y: usize = 24;
    /// `f64` bits x 4: level 0's GDAL geotransform terms 1, 2, 4 and 5.
    pub const TERMS: usize = 32;
    /// The CRS definition: UTF-8 (a PROJ string or WKT), not NUL-terminated, zero after its
    /// length.
    pub const DEFINITION: usize = 64;
    /// Flag bit 0: the texture spans 360 degrees of longitude (s wraps modulo a level's width).
    pub const WRAPS: u32 = 1;
    /// Every flag bit a reader of this release knows.
    pub const KNOWN_FLAGS: u32 = WRAPS;
}

/// Bytes of the heights block.
pub const HEIGHTS_BYTES: usize = 64;

mod heights_block;
pub use heights_block::*;

/// Bytes of the growth block.
pub const GROWTH_BYTES: usize = 128;
/// Growth block fields, relative to [`header::GROWTH`]; every field 8 bytes, all atomic, all under
/// the sequence counter at offset 0. A growing texture (docs/GROWING.md) is served in a fixed
/// frame of level-0 texels whose centre is the grid's origin, so no address ever moves as it grows;
/// this block says which part of the frame has data and how far the texture has grown.
pub mod growth {
    /// `u64` sequence counter (odd while the writer changes the block).
    pub const SEQ: usize = 0;
    /// `u64` 1 when the texture grows (the fields below mean something), 0 otherwise.
    pub const GROWING: usize = 8;
    /// `i64` extent of the data in level-0 texels of the frame, half-open: s0 <= s < s1,
    /// t0 <= t < t1 (all 0 when there is no data yet; clipped to the frame).
    pub const EXTENT_S0: usize = 16;
    /// `i64`.
    pub const EXTENT_T0: usize = 24;
    /// `i64`.
    pub const EXTENT_S1: usize = 32;
    /// `i64`.
    pub const EXTENT_T1: usize = 40;
    /// `u64` levels the texture's data has grown (its own pyramid: level 0 up to the level whose
    /// 2 x 2 tiles around the origin hold every patch); the mapping's levels above are averages
    /// of these.
    pub const DATA_LEVELS: usize = 48;
    /// `u64` patches accepted so far (each durable on disk).
    pub const PATCHES: usize = 56;
    /// `u64` tiles rebuilt so far (every level).
    pub const TILES_REBUILT: usize = 64;
    /// `u64` tiles waiting to be rebuilt.
    pub const TILES_PENDING: usize = 72;
    /// `u64` tiles replaced in their slots so far (a rebuilt tile that was resident).
    pub const TILES_REPLACED: usize = 80;
    /// `f64` bits: world x of the frame's level-0 texel (0, 0) lower-left corner.
    pub const WORLD_S0: usize = 88;
    /// `f64` bits: world y of the same corner.
    pub const WORLD_T0: usize = 96;
    /// `f64` bits: level-0 texels per world unit.
    pub const TEXELS_PER_UNIT: usize = 104;
    /// `u64` patches lying (partly) outside the frame: their texels there are not served.
    pub const OUTSIDE_FRAME: usize = 112;
}

/// The growth block's values (see [`growth`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Growth {
    /// Extent of the data, level-0 texels of the frame `[s0, t0, s1, t1)` (all 0: no data).
    pub extent: [i64; 4],
    /// Levels the data has grown.
    pub data_levels: u64,
    /// Patches accepted.
    pub patches: u64,
    /// Tiles rebuilt.
    pub tiles_rebuilt: u64,
    /// Tiles waiting to be rebuilt.
    pub tiles_pending: u64,
    /// Tiles replaced in their slots.
    pub tiles_replaced: u64,
    /// World coordinates of the frame's level-0 texel (0, 0) lower-left corner.
    pub world_origin: [f64; 2],
    /// Level-0 texels per world unit.
    pub texels_per_unit: f64,
    /// Patches lying (partly) outside the frame.
    pub outside_frame: u64,
}

/// Snapshot fields, relative to [`header::SNAPSHOT`]; every field 8 bytes, all atomic, all
/// under the one sequence counter at offset 0.
pub mod snapshot {
    /// `u64` sequence counter (odd while the writer changes the snapshot).
    pub const SEQ: usize = 0;
    /// `f64` bits: the finest level renderers may use (fractional while fading).
    pub const MIN_LOD: usize = 8;
    /// `u64` the tick this snapshot belongs to (0 before the first).
    pub const TICK: usize = 16;
    /// `u64` invalid border in use (stack levels).
    pub const INVALID_BORDER: usize = 24;
    /// `i64` level-0 centre applied by that tick.
    pub const CENTRE_S: usize = 32;
    /// `i64`.
    pub const CENTRE_T: usize = 40;
    /// Level states, [`super::STATE_BYTES`] each.
    pub const LEVELS: usize = 64;
}

/// Bytes of one level state in the snapshot.
pub const STATE_BYTES: usize = 64;
/// Level state fields, relative to the state.
pub mod state {
    /// `i64` level centre, level texels.
    pub const CENTRE_S: usize = 0;
    /// `i64`.
    pub const CENTRE_T: usize = 8;
    /// `i64` valid region, half-open: s0 <= s < s1, t0 <= t < t1 (level texels).
    pub const VALID_S0: usize = 16;
    /// `i64`.
    pub const VALID_T0: usize = 24;
    /// `i64`.
    pub const VALID_S1: usize = 32;
    /// `i64`.
    pub const VALID_T1: usize = 40;
    /// `u64` 1 when renderers may use the level (then the region is not empty), else 0.
    pub const ENABLED: usize = 48;
    /// `u64` tick of the last change of this level's state.
    pub const UPDATED_TICK: usize = 56;
}

/// Bytes of one level descriptor.
pub const DESC_BYTES: usize = 128;
/// Level descriptor fields, relative to the descriptor; every field a static `u64`.
pub mod desc {
    /// Level width in texels.
    pub const SIZE_S: usize = 0;
    /// Level height.
    pub const SIZE_T: usize = 8;
    /// Tile width in texels.
    pub const TILE_S: usize = 16;
    /// Tile height.
    pub const TILE_T: usize = 24;
    /// Slots per row of the grid.
    pub const GRID_S: usize = 32;
    /// Slot rows of the grid.
    pub const GRID_T: usize = 40;
    /// Bytes of one slot (tile width x tile height x bytes per texel).
    pub const SLOT_BYTES: usize = 48;
    /// Byte offset of the level's tags (a multiple of 4096).
    pub const TAGS_OFFSET: usize = 56;
    /// Byte offset of the level's slots (a multiple of 4096).
    pub const SLOTS_OFFSET: usize = 64;
    /// 0: stack level (a toroidal grid around the centre), 1: pyramid level (no larger than the
    /// clip size; its grid holds every tile of the level).
    pub const KIND: usize = 72;
    /// Byte offset of the level's tile ranges ([`super::range`], a multiple of 4096, between the
    /// tags and the slots); 0 when the texels are not heights.
    pub const RANGES_OFFSET: usize = 80;
    /// `f64` bits x 4: the level's GDAL geotransform terms 1, 2, 4 and 5 (over the level's
    /// pixel / line; the origin is the georef block's), 0 when the texture has no georeferencing.
    pub const GEOREF: usize = 88;
}

/// Bytes of one tile range entry (one per slot, at the level's ranges offset + 16 x slot).
pub const RANGE_BYTES: usize = 16;
/// Tile range entry fields, relative to the entry; each an `f64`'s bits stored atomically, read
/// under the slot's tag like its texels (docs/SHM.md, "Tile ranges").
pub mod range {
    /// `f64` bits: the least height of the slot's tile in metres, nodata excluded (NaN when every
    /// texel is nodata; -inf when the tile holds a texel that is not a finite height).
    pub const MIN: usize = 0;
    /// `f64` bits: the greatest height in metres (NaN when every texel is nodata; +inf when the
    /// tile holds a texel that is not a finite height).
    pub const MAX: usize = 8;
}

/// Bytes of one slot tag.
pub const TAG_BYTES: usize = 32;
/// Slot tag fields, relative to the tag; every field 8 bytes, all atomic.
pub mod tag {
    /// `u64` sequence counter (odd while the writer changes the tag).
    pub const SEQ: usize = 0;
    /// `i64` tile column S the slot holds (or is being loaded with).
    pub const TILE_S: usize = 8;
    /// `i64` tile row T.
    pub const TILE_T: usize = 16;
    /// `u64` one of [`super::SlotState`].
    pub const STATE: usize = 24;
}

/// What a slot holds, as its tag says.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SlotState {
    /// Nothing yet.
    Empty = 0,
    /// Being loaded with the tile the tag names: its bytes may be changing.
    Loading = 1,
    /// Holds the tile's texels.
    Ready = 2,
    /// The tile could not be read: use a coarser level for its texels.
    Missing = 3,
    /// Holds the configuration's default tile in place of a tile that does not exist.
    Default = 4,
}

impl SlotState {
    /// The state of a tag's `STATE` value (`None` for a value no writer writes).
    pub fn from_code(code: u64) -> Option<SlotState> {
        [SlotState::Empty, SlotState::Loading, SlotState::Ready, SlotState::Missing, SlotState::Default]
            .into_iter()
            .find(|s| *s as u64 == code)
    }

    /// True when the slot's texels may be read (ready or the default tile).
    pub fn readable(self) -> bool {
        matches!(self, SlotState::Ready | SlotState::Default)
    }

    /// True when nothing more is coming for the tile (readable, or missing for good).
    pub fn settled(self) -> bool {
        self != SlotState::Loading && self != SlotState::Empty
    }
}

/// The views block (docs/SHM.md, "Views"): further views' names, weights and snapshots, at the
/// header's [`header::VIEWS_OFFSET`]. Added to layout 2 without changing its version (a reader
/// that ignores it reads the primary view, `main`, at [`header::SNAPSHOT`]); it has its own.
pub mod views {
    /// `[u8; 8]` magic.
    pub const MAGIC: usize = 0;
    /// `u32` views block version.
    pub const VERSION: usize = 8;
    /// `u32` view records in the block.
    pub const RECORDS: usize = 12;
    /// `u32` bytes of one record.
    pub const RECORD_BYTES_AT: usize = 16;
    /// Where record 0 starts.
    pub const FIRST: usize = 64;
    /// The magic bytes.
    pub const MAGIC_BYTES: [u8; 8] = *b"CLIPVIEW";
    /// This block's version: 2 adds record state [`STATE_OWN`] to version 1 (docs/SHM.md,
    /// "Views"). Readers read both.
    pub const BLOCK_VERSION: u32 = 2;
    /// Bytes of one record: its fields, then its snapshot.
    pub const RECORD_BYTES: usize = SNAPSHOT + super::header::LEVEL_DESCS - super::header::SNAPSHOT;
    /// Most records a block may have.
    pub const MAX_RECORDS: usize = 64;
    /// Records the service's mappings have: one per further view the engine keeps.
    pub const SERVICE_RECORDS: usize = 15;
    const _: () = assert!(SERVICE_RECORDS == clipmap_base::limits::MAX_VIEWS - 1);
    /// Most bytes of a view's name (NUL-padded to [`NAME_BYTES`]).
    pub const MAX_NAME: usize = 31;
    /// The name of the primary view.
    pub const PRIMARY_NAME: &str = "main";

    /// Record fields, relative to the record.
    /// `u64` the record's sequence counter (odd while the writer changes fields 0..128).
    pub const SEQ: usize = 0;
    /// `u64` [`STATE_FREE`], [`STATE_LIVE`] or [`STATE_OWN`].
    pub const STATE: usize = 8;
    /// State of a free record.
    pub const STATE_FREE: u64 = 0;
    /// State of a live view's record.
    pub const STATE_LIVE: u64 = 1;
    /// State of a live view with grids of its own (version 2): its texels, snapshot and requests
    /// are those of `main` of the mapping named [`own_mapping_name`] in the same directory.
    pub const STATE_OWN: u64 = 2;
    /// `u64` incremented each time the record is given to a view.
    pub const INCARNATION: usize = 16;
    /// `f64` bits: the view's weight.
    pub const WEIGHT: usize = 24;
    /// `[u8; 32]` the name, NUL-padded, as four `u64` words.
    pub const NAME: usize = 64;
    /// Bytes of the name field.
    pub const NAME_BYTES: usize = 32;
    /// The view's snapshot, laid out as the one at [`super::header::SNAPSHOT`].
    pub const SNAPSHOT: usize = 128;

    /// The name of the mapping of view `view`'s own grids (record state [`STATE_OWN`]) for the
    /// service named `service`: `DIR/clipmap-{service}@{view}.map` and `.req`.
    pub fn own_mapping_name(service: &str, view: &str) -> String {
        format!("{service}@{view}")
    }

    /// Bytes of a block of `records` records, page-rounded.
    pub fn block_bytes(records: usize) -> u64 {
        ((FIRST + records * RECORD_BYTES) as u64).div_ceil(super::PAGE) * super::PAGE
    }

    /// Offset of record `r` from the block.
    pub fn record(r: usize) -> usize {
        FIRST + r * RECORD_BYTES
    }

    /// Request records in the request mapping: one per view record, at
    /// [`REQUEST_BASE`] + [`REQUEST_RECORD_BYTES`] x r.
    pub const REQUEST_BASE: usize = 512;
    /// Bytes of one request record.
    pub const REQUEST_RECORD_BYTES: usize = 64;
    /// Most request records the request mapping holds (they end where the LOD requests begin).
    pub const MAX_REQUEST_RECORDS: usize = (LOD_BASE - REQUEST_BASE) / REQUEST_RECORD_BYTES;

    /// LOD requests in the request mapping (docs/SHM.md, "Asking for a view's levels"): one
    /// record of [`LOD_RECORD_BYTES`] per view, the primary's first, at [`LOD_BASE`] +
    /// [`LOD_RECORD_BYTES`] x i (i = 0: `main`, under the main request's lock word; i = 1 + r:
    /// view record r's, under its request record's lock word).
    pub const LOD_BASE: usize = 2048;
    /// Bytes of one LOD request record.
    pub const LOD_RECORD_BYTES: usize = 32;
    /// LOD request fields, relative to the record: `f64` height of the view above the texture,
    /// in level-0 texels (0: no LOD request).
    pub const LOD_HEIGHT: usize = 0;
    /// `f64` the angle one screen pixel spans, radians.
    pub const LOD_PIXEL_ANGLE: usize = 8;
    /// `u32` (in a `u64`) levels the renderer addresses at once (0: all).
    pub const LOD_EFFECTIVE: usize = 16;
    /// `u64` LOD requests made (the service acts when it changes).
    pub const LOD_COUNT: usize = 24;

    /// Offset of LOD request record `i` (0: `main`; 1 + r: view record r) in the request mapping.
    pub fn lod(i: usize) -> usize {
        LOD_BASE + i * LOD_RECORD_BYTES
    }

    const _: () = assert!(LOD_BASE + (MAX_REQUEST_RECORDS + 1) * LOD_RECORD_BYTES <= super::REQUEST_BYTES as usize);

    /// Position records in the request mapping (docs/SHM.md, "Positions in longitude / latitude
    /// or map coordinates"): one of [`POSITION_RECORD_BYTES`] per view, the primary's first, at
    /// [`POSITION_BASE`] + [`POSITION_RECORD_BYTES`] x i (i = 0: `main`, under the main request's
    /// lock word; i = 1 + r: view record r's, under its request record's lock word). A request's
    /// centre is the record's position when the record's [`POS_FOR_COUNT`] equals the request's
    /// count and its kind is not [`KIND_TEXELS`]; else the request's texel centre. A renderer that
    /// knows nothing of these records (older) never writes the count, so its requests read as
    /// texels.
    pub const POSITION_BASE: usize = 3072;
    /// Bytes of one position record.
    pub const POSITION_RECORD_BYTES: usize = 32;
    /// Position record fields, relative to the record: `u64` the coordinate kind
    /// ([`KIND_TEXELS`], [`KIND_LONLAT`], [`KIND_MAP`]).
    pub const POS_KIND: usize = 0;
    /// `f64` bits: the position's first coordinate (longitude in degrees, or map x).
    pub const POS_X: usize = 8;
    /// `f64` bits: the second (latitude in degrees, or map y).
    pub const POS_Y: usize = 16;
    /// `u64` the request count (the request record's, after this request) the position belongs to.
    pub const POS_FOR_COUNT: usize = 24;
    /// Coordinate kind 0: the request's centre in level-0 texels (its `CENTRE_S` / `CENTRE_T`).
    pub const KIND_TEXELS: u64 = 0;
    /// Coordinate kind 1: WGS 84 longitude / latitude, degrees.
    pub const KIND_LONLAT: u64 = 1;
    /// Coordinate kind 2: map coordinates of the texture's CRS (the georef block's).
    pub const KIND_MAP: u64 = 2;

    /// Offset of position record `i` (0: `main`; 1 + r: view record r) in the request mapping.
    pub fn position(i: usize) -> usize {
        POSITION_BASE + i * POSITION_RECORD_BYTES
    }

    const _: () = assert!(LOD_BASE + (MAX_REQUEST_RECORDS + 1) * LOD_RECORD_BYTES <= POSITION_BASE);
    const _: () =
        assert!(POSITION_BASE + (MAX_REQUEST_RECORDS + 1) * POSITION_RECORD_BYTES <= super::REQUEST_BYTES as usize);
    const _: () = assert!(SERVICE_RECORDS <= MAX_REQUEST_RECORDS);
    /// Request record fields, relative to the record: the lock word (as
    /// [`super::request::SEQ`]).
    pub const REQ_SEQ: usize = 0;
    /// `i64` requested centre s.
    pub const REQ_CENTRE_S: usize = 8;
    /// `i64` requested centre t.
    pub const REQ_CENTRE_T: usize = 16;
    /// `f64` bits: velocity s (level-0 texels per second).
    pub const REQ_VEL_S: usize = 24;
    /// `f64` bits: velocity t.
    pub const REQ_VEL_T: usize = 32;
    /// `u64` requester's process id.
    pub const REQ_CLIENT_PID: usize = 40;
    /// `u64` requests made.
    pub const REQ_COUNT: usize = 48;
    /// `u64` the incarnation of the view the request is for.
    pub const REQ_INCARNATION: usize = 56;

    // The main request's fields lie at the same offsets from its lock word.
    const _: () = assert!(
        super::request::CENTRE_S - super::request::SEQ == REQ_CENTRE_S
            && super::request::CENTRE_T - super::request::SEQ == REQ_CENTRE_T
            && super::request::VEL_S - super::request::SEQ == REQ_VEL_S
            && super::request::VEL_T - super::request::SEQ == REQ_VEL_T
            && super::request::CLIENT_PID - super::request::SEQ == REQ_CLIENT_PID
            && super::request::COUNT - super::request::SEQ == REQ_COUNT
    );

    /// Offset of request record `r` in the request mapping.
    pub fn request(r: usize) -> usize {
        REQUEST_BASE + r * REQUEST_RECORD_BYTES
    }

    /// Whether `name` is one a view may have: 1 to [`MAX_NAME`] of `A-Z a-z 0-9 - _ .`, and not
    /// [`PRIMARY_NAME`] (the primary view's). `Err` says what is wrong and what is expected.
    pub fn check_name(name: &str) -> Result<(), String> {
        if name == PRIMARY_NAME {
            return Err(format!("view name `{name}` is the primary view's own; choose another for a further view"));
        }
        let ok = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.');
        if name.is_empty() || name.len() > MAX_NAME || !name.chars().all(ok) {
            let shown: String = name.chars().take(40).collect();
            return Err(format!(
                "view name `{shown}`: expected 1 to {MAX_NAME} of A-Z a-z 0-9 - _ . (such as left, right or sensor.1)"
            ));
        }
        Ok(())
    }
}

/// Request mapping fields (its own small file, written by renderers).
pub mod request {
    /// `[u8; 8]` magic `CLIPREQ2`.
    pub const MAGIC: usize = 0;
    /// `u32` layout version (2).
    pub const VERSION: usize = 8;
    /// `u64` the generation of the texel mapping this request file belongs to.
    pub const GENERATION: usize = 16;
    /// `u64` (atomic) sequence counter and lock word (even: stable; odd: a renderer holds it
    /// and its process id is in bits 1..=31; see [`super::request_lock`]).
    pub const SEQ: usize = 64;
    /// `i64` requested centre, level-0 texels.
    pub const CENTRE_S: usize = 72;
    /// `i64`.
    pub const CENTRE_T: usize = 80;
    /// `f64` bits: velocity, level-0 texels per second (0 when unknown).
    pub const VEL_S: usize = 88;
    /// `f64` bits.
    pub const VEL_T: usize = 96;
    /// `u64` process id of the requester.
    pub const CLIENT_PID: usize = 104;
    /// `u64` number of requests made (monotonic).
    pub const COUNT: usize = 112;
}

/// The request mapping's lock word (`request::SEQ`), as pure arithmetic.
///
/// Even: nobody writes the request (any even value). Odd: a renderer holds it, and bits 1..=31
/// are its process id, bits 32..=63 the epoch of the word it took. A renderer takes the word with
/// a compare-and-swap from an even `w` to [`locked(w, pid)`](request_lock::locked), writes the fields, and
/// releases it with a compare-and-swap from its locked word to [`released`](request_lock::released) of it (the next
/// epoch, low half zero): the word never returns to a value the service saw before, and never
/// moves backwards. A word left odd for more than [`TAKEOVER_MS`](request_lock::TAKEOVER_MS) whose owner is not a live
/// process (a renderer that died mid-write) may be advanced by anyone with the same
/// compare-and-swap from it to `released` of it. An owner that is alive is never overruled,
/// however long it stalls: overruling it would let its late stores mix with the next request.
pub mod request_lock {
    /// How long a word must stay odd, unchanged, before its owner is looked at.
    pub const TAKEOVER_MS: u64 = 100;
    /// How long a renderer waits for a word held by a live owner before giving up for now.
    pub const WAIT_MS: u64 = 1000;

    /// The word a renderer of process `pid` stores to take the even word `free`.
    pub fn locked(free: u64, pid: u32) -> u64 {
        (free & !0xFFFF_FFFF) | ((u64::from(pid) & 0x7FFF_FFFF) << 1) | 1
    }

    /// The word that releases (or takes over) the odd word `held`: the next epoch.
    pub fn released(held: u64) -> u64 {
        (held >> 32).wrapping_add(1) << 32
    }

    /// The process id an odd word records (0: none, as an older renderer's counter may give).
    pub fn owner(held: u64) -> u32 {
        ((held >> 1) & 0x7FFF_FFFF) as u32
    }
}

/// Texel format codes in the header.
pub fn format_code(f: clipmap_base::texel::TexelFormat) -> u32 {
    use clipmap_base::texel::TexelFormat as F;
    match f {
        x if x == F::L8 => 1,
        x if x == F::RGB8 => 3,
        x if x == F::RGBA8 => 4,
        x if x == F::RGB565 => 5,
        x if x == F::RGBA5551 => 6,
        x if x == F::L16 => 7,
        x if x == F::LA16 => 8,
        x if x == F::RGB16 => 9,
        x if x == F::RGBA16 => 10,
        x if x == F::L32F => 11,
        x if x == F::L16I => 12,
        x if x == F::BC1 => 20,
        x if x == F::BC4 => 21,
        x if x == F::BC5 => 22,
        x if x == F::BC7 => 23,
        _ => 0,
    }
}

/// The texel format of a `TEXEL_FORMAT` code; `None` for 0 (other) or an unknown code.
pub fn format_from_code(code: u32) -> Option<clipmap_base::texel::TexelFormat> {
    use clipmap_base::texel::TexelFormat as F;
    [
        F::L8,
        F::RGB8,
        F::RGBA8,
        F::RGB565,
        F::RGBA5551,
        F::L16,
        F::LA16,
        F::RGB16,
        F::RGBA16,
        F::L32F,
        F::L16I,
        F::BC1,
        F::BC4,
        F::BC5,
        F::BC7,
    ]
    .into_iter()
    .find(|&f| format_code(f) == code)
}

/// Whether a `TEXEL_FORMAT` code is a block-compressed format (20 `bc1`, 21 `bc4`, 22 `bc5`,
/// 23 `bc7`): its slots hold 4 x 4 blocks, `ceil(tile width / 4)` blocks a row, and the
/// header's bytes per texel are the bytes of one block (docs/SHM.md, "Block-compressed formats").
pub fn is_block_code(code: u32) -> bool {
    (20..=23).contains(&code)
}

/// One level of a shape: its size, tile size and grid of slots.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelShape {
    /// Level size in texels.
    pub size: [u64; 2],
    /// Tile size in texels.
    pub tile: [u64; 2],
    /// Slots per axis.
    pub grid: [u64; 2],
}

/// The static shape of a mapping.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Shape {
    /// Bytes per texel; for a block format the bytes of one block.
    pub bytes_per_texel: u64,
    /// Texels a side of the unit of storage: 1 (texels), or 4 for a block-compressed format,
    /// whose slots hold `ceil(tile width / 4) x ceil(tile height / 4)` blocks of
    /// `bytes_per_texel` bytes each.
    pub block: u64,
    /// Clip size.
    pub clip_size: u64,
    /// Levels, finest first.
    pub levels: Vec<LevelShape>,
}

/// Where one level's tags and slots lie.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelPlace {
    /// Byte offset of the tags.
    pub tags: u64,
    /// Byte offset of the slots.
    pub slots: u64,
    /// Bytes of one slot.
    pub slot_bytes: u64,
    /// Number of slots (grid width x height).
    pub slot_count: u64,
    /// 0 stack, 1 pyramid.
    pub kind: u64,
    /// Byte offset of the tile ranges (0: none, the texels are not heights).
    pub ranges: u64,
}

impl LevelPlace {
    /// Byte offset of slot `index`.
    pub fn slot_offset(&self, index: u64) -> u64 {
        self.slots + index * self.slot_bytes
    }

    /// Byte offset of slot `index`'s tag.
    pub fn tag_offset(&self, index: u64) -> u64 {
        self.tags + index * TAG_BYTES as u64
    }

    /// Byte offset of slot `index`'s tile range entry (`None`: the level has no ranges).
    pub fn range_offset(&self, index: u64) -> Option<u64> {
        (self.ranges != 0).then(|| self.ranges + index * RANGE_BYTES as u64)
    }
}

/// Where every level lies, and the whole size.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Placement {
    /// Bytes before the first level.
    pub header_bytes: u64,
    /// Per level.
    pub levels: Vec<LevelPlace>,
    /// Byte offset of the views block ([`views`]; 0: none).
    pub views: u64,
    /// View records in the views block (0: none).
    pub view_records: u64,
    /// Whole mapping.
    pub total_bytes: u64,
}

impl Placement {
    /// Bytes of the slots of every level (the texels).
    pub fn slot_bytes(&self) -> u64 {
        self.levels.iter().map(|l| l.slot_bytes * l.slot_count).sum()
    }
}

/// The slot index of tile (S, T) in a grid: (S mod grid width, T mod grid height), Euclidean.
pub fn slot_index(grid: [u64; 2], tile: [i64; 2]) -> u64 {
    tile[1].rem_euclid(grid[1] as i64) as u64 * grid[0] + tile[0].rem_euclid(grid[0] as i64) as u64
}

/// Whether a level's static description is one a writer of this layout makes: non-zero tiles, a grid no larger than the level's tiles and large enough for a window
/// of the clip size at any alignment, and a pyramid level (no larger than the clip size) whole. `Err` says what is wrong.
pub fn check_level(l: &LevelShape, clip: u64, bpt: u64) -> Result<(), String> {
    let [w, h] = l.size;
    if w == 0 || h == 0 || l.tile[0] == 0 || l.tile[1] == 0 || l.grid[0] == 0 || l.grid[1] == 0 {
        return Err(format!("a zero size: level {w}x{h}, tile {:?}, grid {:?}", l.tile, l.grid));
    }
    let n = tiles_in_level(l.size, l.tile);
    if l.grid[0] > n[0] || l.grid[1] > n[1] {
        return Err(format!("grid {:?} larger than the level's {n:?} tiles", l.grid));
    }
    // One axis at a time over four arrays (size, tile, tiles, grid), the axis named in the error.
    #[allow(clippy::needless_range_loop)]
    for a in 0..2 {
        let least = (clip.min(l.size[a]).div_ceil(l.tile[a]) + 1).min(n[a]);
        if l.grid[a] < least {
            return Err(format!("grid {:?} cannot hold a {clip}-texel window (needs {least} along axis {a})", l.grid));
        }
    }
    let pyramid = w <= clip && h <= clip;
    if pyramid && l.grid != n {
        return Err(format!(
            "a pyramid level ({w}x{h}, clip {clip}) must hold all its {n:?} tiles, not a {:?} grid",
            l.grid
        ));
    }
    l.tile[0]
        .checked_mul(l.tile[1])
        .and_then(|x| x.checked_mul(bpt))
        .and_then(|x| x.checked_mul(l.grid[0] * l.grid[1]))
        .ok_or_else(|| format!("tile {:?} x grid {:?} x {bpt} bytes overflows", l.tile, l.grid))?;
    Ok(())
}

/// Bytes of one slot of a `tile`-sized tile: `tile[0] * tile[1]` texels of `bytes` bytes for
/// `block` 1, or `ceil(tile[0] / 4) * ceil(tile[1] / 4)` blocks of `bytes` bytes for `block` 4
/// (a partial block at a tile's edge is a whole block). `None` on overflow.
pub fn slot_bytes(tile: [u64; 2], block: u64, bytes: u64) -> Option<u64> {
    let block = block.max(1);
    tile[0].div_ceil(block).checked_mul(tile[1].div_ceil(block))?.checked_mul(bytes)
}

/// Lays a shape out without tile ranges (a texture whose texels are not heights). `None` when it
/// has too many levels, a level fails [`check_level`] or the sizes overflow.
pub fn place(shape: &Shape) -> Option<Placement> {
    place_with(shape, false)
}

/// Lays a shape out, with each level's tile ranges between its tags and its slots when `ranges`
/// (a height texture: [`RANGE_BYTES`] a slot, page-rounded). `None` as for [`place`].
pub fn place_with(shape: &Shape, ranges: bool) -> Option<Placement> {
    if shape.levels.is_empty()
        || shape.levels.len() > MAX_LEVELS
        || shape.bytes_per_texel == 0
        || !(shape.block == 1 || shape.block == 4)
        || shape.clip_size == 0
        || shape.levels.iter().any(|l| check_level(l, shape.clip_size, shape.bytes_per_texel).is_err())
    {
        return None;
    }
    let round = |v: u64| v.checked_add(PAGE - 1).map(|x| x / PAGE * PAGE);
    let header_bytes = round(header::END as u64)?;
    let mut at = header_bytes;
    let mut levels = Vec::new();
    for l in &shape.levels {
        let slot_count = l.grid[0].checked_mul(l.grid[1])?;
        let slot_bytes = slot_bytes(l.tile, shape.block, shape.bytes_per_texel)?;
        let tags = at;
        let tags_end = round(tags.checked_add(slot_count.checked_mul(TAG_BYTES as u64)?)?)?;
        let (ranges_at, slots) = if ranges {
            (tags_end, round(tags_end.checked_add(slot_count.checked_mul(RANGE_BYTES as u64)?)?)?)
        } else {
            (0, tags_end)
        };
        let kind = u64::from(l.size[0] <= shape.clip_size && l.size[1] <= shape.clip_size);
        levels.push(LevelPlace { tags, slots, slot_bytes, slot_count, kind, ranges: ranges_at });
        at = round(slots.checked_add(slot_count.checked_mul(slot_bytes)?)?)?;
    }
    Some(Placement { header_bytes, levels, views: 0, view_records: 0, total_bytes: at })
}

/// `p` with a views block of `records` records (1..=[`views::MAX_RECORDS`]) after its last
/// level: the service's mappings ([`views::SERVICE_RECORDS`]). `None` when `records` is out of
/// range or the size overflows.
pub fn with_views(mut p: Placement, records: usize) -> Option<Placement> {
    if records == 0 || records > views::MAX_RECORDS {
        return None;
    }
    p.views = p.total_bytes;
    p.view_records = records as u64;
    p.total_bytes = p.total_bytes.checked_add(views::block_bytes(records))?;
    Some(p)
}

/// Whether a published valid region is one a writer of this layout publishes for a level of
/// `l`'s shape: inside the level, and spanning no more tiles than the grid has slots per axis (so
/// the tiles under it have distinct slots). `Err` says what is wrong.
#[cfg(test)]
pub(crate) fn check_region(l: &LevelShape, r: [i64; 4]) -> Result<Rect, String> {
    check_region_wrapping(l, r, false)
}

/// Whether level `l`'s region may run past its width: the texture wraps in longitude (the
/// georef block's flag bit 0) and the level's width is a whole number of tiles (docs/SHM.md,
/// "How a region wraps").
pub fn region_may_wrap(l: &LevelShape, texture_wraps: bool) -> bool {
    texture_wraps && l.tile[0] > 0 && l.size[0].is_multiple_of(l.tile[0])
}

/// [`check_region`] of a level of a texture that may wrap (`texture_wraps`, the georef block's
/// flag): where [`region_may_wrap`], the region's s-range is `0 <= s0 < width` and
/// `s0 < s1 <= s0 + width` (texel s of it is texel `s mod width`); otherwise inside the level.
pub(crate) fn check_region_wrapping(l: &LevelShape, r: [i64; 4], texture_wraps: bool) -> Result<Rect, String> {
    let [s0, t0, s1, t1] = r;
    let inside = |lo: i64, hi: i64, size: u64| 0 <= lo && lo < hi && hi as u64 <= size;
    let wraps = region_may_wrap(l, texture_wraps);
    let s_ok = if wraps {
        0 <= s0 && (s0 as u64) < l.size[0] && s0 < s1 && (s1 as u64).saturating_sub(s0 as u64) <= l.size[0]
    } else {
        inside(s0, s1, l.size[0])
    };
    if !s_ok || !inside(t0, t1, l.size[1]) {
        let how = if wraps { " (it wraps: s0 inside the level, s1 - s0 at most its width)" } else { "" };
        return Err(format!(
            "valid region {r:?} is not a non-empty rectangle inside the {}x{} level{how}",
            l.size[0], l.size[1]
        ));
    }
    let rect = Rect::new(s0, t0, s1, t1);
    let tiles = clipmap_base::geom::tiles_covering(rect, l.tile);
    if tiles.width() > l.grid[0] || tiles.height() > l.grid[1] {
        return Err(format!(
            "valid region {r:?} spans {}x{} tiles, more than the {:?} grid holds",
            tiles.width(),
            tiles.height(),
            l.grid
        ));
    }
    Ok(rect)
}

#[cfg(test)]
mod tests;
