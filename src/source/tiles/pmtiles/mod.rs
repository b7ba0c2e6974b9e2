//! PMTiles v3 archives of raster tiles, local, over HTTP and on S3, read through the byte seam
//! ([`crate::source::range`]) so that every read is one counted, retried request of the version
//! opened: `header` (the 127 bytes that say where everything lies), [`directory`] (Hilbert tile
//! ids and the varint-encoded directories), `archive` (open, leaf cache, tiles).
//!
//! Why not the `pmtiles` crate: its reader (`AsyncPmTilesReader`) is async only (synchronous
//! backends are on its to-do list), and its backends bring their own clients (reqwest, rust-s3,
//! object_store, mmap), which would bypass this crate's remote reader: its request counters,
//! retries with backoff, the pinning of the object's version seen at open and the remote
//! options. Driving it through a custom async backend over our blocking reader would need an
//! async runtime on every tile fetch, and its directory caches are an unbounded hash map or a
//! moka cache, not bounded in bytes. The format itself (a header, varints, a Hilbert curve) is
//! a few hundred lines, checked here against the reference Python writer's archives.

pub(crate) mod archive;
pub mod directory;
pub(crate) mod header;

pub use archive::{PmtilesArchive, DEFAULT_TILE_SIZE, LEAF_CACHE_BYTES, OPEN_BYTES};
pub use header::{Compression, Header};
