//! # clipmap
//!
//! Clipmaps for textures far larger than memory: a faithful reader for OpenGL Performer's
//! clip-texture (`.ct`) and image-cache (`.ic`) configuration files, and the pieces that turn such
//! a configuration into per-level windows of texels.
//!
//! ## The crates
//!
//! This is the core crate of a workspace whose crates follow the floors (docs/ARCHITECTURE.md,
//! "Crates"; a crate depends only on the ones before it):
//!
//! | crate | holds |
//! |---|---|
//! | `clipmap-base` | the ground floor: tiles, texels, heights, geometry, georeferencing, bounds (re-exported here under their old paths) |
//! | `clipmap-shm` | the shared mapping: layout, writer, the reader a renderer links alone (re-exported here as [`shm`]) |
//! | `clipmap` (this crate) | configuration, plan, sources, the engine, sampling, the reports and the command line the tools share |
//! | `clipmap-service` | the `clipmapd` service: tick loop, control socket, statistics, views, patches |
//! | `clipmap-tools` | the tools' library above the service (`inspect`, `demo`) and the binaries |
//! | `clipgpu` | the GPU client |
//!
//! ## Map of this crate, in data-flow order
//!
//! (docs/ARCHITECTURE.md §12 gives each module's floor; a module imports only lower floors.)
//!
//! | module | owns |
//! |---|---|
//! | [`tile`] | the ground floor: tile ids, level sizes and counts, the 64-bit mixing of the verification texture |
//! | [`place`] | where a named file lives: a local path or a remote location, decided once where the name enters |
//! | [`open`] | the one way to open a file a configuration names: regular files only, never blocking |
//! | [`config`] | text → syntax tree with a span for every value; no arithmetic, no other files |
//! | [`plan`] | syntax tree → validated, immutable plan: levels, formats, file names, byte offsets |
//! | [`texel`] | texel formats, bytes per texel, colour encoding |
//! | [`height`] | elevation: height encodings (`l32f`, `l16`, `l16i` with scale, offset, nodata), level rules for heights, per-tile height ranges |
//! | [`source`] | texel values: tile files through the plan, tiled GeoTIFFs and COGs, remote tiles (`http(s)://`, `s3://`), procedural textures, the second-level tile pool, fault and throttle wrappers |
//! | [`geom`] | pure level geometry: centres, tex / valid / mem regions, toroidal addressing |
//! | [`limits`] | every bound the paging engine keeps (queue lengths, reads in flight, bytes) |
//! | [`runtime`] | the process's one tokio runtime (read queues, remote requests, the service, the tools) and its thread bounds |
//! | [`queue`] | per-stream-server async read queues: priorities, coalescing, stale drops |
//! | [`paging`] | paging policies: where each grid's spare tiles go (adaptive, the default; ring, direction, ahead), and how the second-level tile pool evicts (LRU, the default; shift) |
//! | `cache` | per-level toroidal grids of slots (mem regions): which tile each slot of the mapping holds (crate-private: the engine's own) |
//! | [`clip`] | the engine: per-level windows, the update tick, load control (min LOD), adaptive paging, views, statistics |
//! | [`shm`] | the shared-memory layout (layout 2: the image caches themselves), the slots' memory and claims, writer and client (the `clipmap-shm` crate, re-exported; the only `unsafe` code), and the engine's reads from a mapping |
//! | [`sample`] | reference point / bilinear / trilinear sampling of the full mipmap and the clipmap |
//! | [`roam`] | in-process flight simulation (`cliptex roam`): flight specs, per-frame report |
//! | [`accuracy`] | the reference renderer, per-frame accuracy metrics and the speed/accuracy sweep |
//! | [`sizing`] | memory and bandwidth arithmetic, clip-size and virtual-level recommendations |
//! | [`save`] | writing a result file completely or not at all (temporary, sync, rename) |
//! | [`report`] | what the tools print: validation reports, info, tile locations, dumps, pictures and their labels (below the service, which names its exit statuses) |
//! | `cli` | the command line the binaries share (`--env`, paging flags, `validate`'s arguments, the parse that exits 1 on usage errors); the `cli` feature, on by default |
//! | [`prep`] | data preparation: image or procedural source → tiled pyramid plus `.ct`/`.ic` |
//! | [`growing`] | growing textures: patches, the fixed tile grid anchored at a world origin, the R*-tree index, tile rebuilds |
//!
//! ## The public API
//!
//! What is public is what the crates above use (the service, the tools' library, the binaries,
//! the GPU client, the benchmarks and the integration tests) and what docs/ shows users; the rest
//! is `pub(crate)`. Every module of the map above is public but `cache`. Inside them, the types and
//! functions users name are re-exported where they look for them (`clip::Clipmap`,
//! `source::{FileSource, CogSource, TileSource}`, `config::Diagnostic`, `plan::Env`,
//! `prep::{Job, Spec}`, ...), and so is every type a public signature names (no public item
//! names a type users cannot name: `rustc -W unnameable_types` finds none). Only these
//! submodules are public:
//!
//! | module | public submodules, and what for |
//! |---|---|
//! | [`accuracy`] | `render` (the reference renderer and its camera), `study` (per-frame metrics, flights), `sweep` (the speed/accuracy sweep), `heights` (the height study), `formats` (the texel-format axis: PSNR, bytes and encoding of each format): `clipbench accuracy`, `clipbench formats` and the GPU client |
//! | [`config`] | `tokens` (the token table: `cliptex tokens`, the tests of every token) |
//! | [`growing`] | `index`, `input`, `rebuild`, `serve`, `store`, `watch`: a growing texture's stages, which the service's patch admission and `clipbench growing` drive one by one |
//! | [`paging`] | `adaptive` (the default policy's per-level paging and its reasons, in the service's statistics) |
//! | [`plan`] | `cog`, `georef`, `source_line` (the `#clipmap` extension lines the tools read and write); `printf`, `params` (Performer's tile-name formats and their parameters, the vocabulary of `TileNaming`) |
//! | [`prep`] | `cog`, `cog_config`, `error`, `jpeg_check`, `layout`, `output`, `publish`, `source`, `tiff_stream`: `clipprep`'s stages |
//! | [`queue`] | `priority` (read priorities, pure functions) |
//! | [`report`] | `check`, `dump`, `exit`, `hypsometric`, `info`, `label`, `picture`, `plan`, `validate`: each a report (or its pictures and exit statuses) the tools print |
//! | [`sample`] | `blocks` (block-compressed texels decoded for sampling) |
//! | [`shm`] | the `clipmap-shm` crate whole, and `shared_reads` (tiles a source takes from a mapping) |
//! | [`source`] | `cog`, `configured`, `procedural`, `remote` (with `disk`, `flight`, `http`, `object`, `options` and its `ENV_VARS`, `range`, `s3`, `seen`), `tiles` (with `mbtiles`, `pmtiles` and its `directory`, `pyramid`): the sources the tools open and measure directly; `range` with its `reader` (the byte seam: `RangeRead`, `RangeReader`, what a tile archive is opened from) and `merge` (the one merge of ranges and its figure, `Merged`, which the remote reader's statistics carry) |
//!
//! `clip`, `cli`, `place`, `roam` and `runtime` have no public submodule. `tests/it/api.rs` holds
//! this list and fails on a new public module or crate-root re-export.
//!
//! ## Invariants
//!
//! - Nothing after the plan reads configuration text.
//! - The plan, residency and priority logic are pure and synchronous.
//! - Texel addressing is done in 64-bit integers; world coordinates in f64.
//! - There is no `unsafe` code outside the shared-memory access layer.

#![deny(unsafe_code)]

// The ground floor, a crate of its own (`clipmap-base`), under its old paths.
pub use clipmap_base::{geom, georef, height, limits, open, save, sizing, texel, tile};

pub mod accuracy;
pub(crate) mod cache;
#[cfg(feature = "cli")]
pub mod cli;
pub mod clip;
pub mod config;
pub mod growing;
pub mod paging;
pub mod place;
pub mod plan;
pub mod prep;
pub mod queue;
pub mod report;
pub mod roam;
pub mod runtime;
pub mod sample;
pub mod shm;
pub mod source;
