//! Data preparation: turns an image or a procedural source into a complete, valid clip texture
//! (tiled pyramid plus `.ct` and `.ic` files) that this crate, and Performer, can load.
//!
//! | module | owns |
//! |---|---|
//! | [`layout`] | level table (image cache vs pyramid), tile sizes, file names, offsets, streams |
//! | `configfile` | the `.ct` / `.ic` text of a layout |
//! | [`cog_config`] | the configuration alone of a COG served as it is (`clipprep --config-only`) |
//! | [`source`] | level texels: `hash` per level, `terrain` and images at level 0 |
//! | [`tiff_stream`] | streaming TIFF input, strip by strip or tile row by tile row |
//! | `inset` | sparse insets: which tiles of a finer level are inset, border or absent |
//! | `heights` | heights: level 0 in a height format, coarser levels by the level rule |
//! | `filter` | row-by-row 2:1 reduction (box, Lanczos-3, optional linear light) |
//! | `sink` | cutting bands of rows into tiles and writing them at their offsets |
//! | `border` | border tiles of sparse levels, magnified from the inset level |
//! | `pipeline` | one run: configuration, then the band cascade down the levels |
//! | [`output`] | the temporary sibling directory and the final rename |
//!
//! Memory is bounded by `pipeline::buffer_memory`, checked before anything is written: the hash
//! source writes image-cache levels tile by tile (one tile per worker thread, whatever the
//! texture's size); filtered sources (terrain, images) run a band cascade of a few bands of one
//! row of level-0 tiles (tile height x level-0 width), each coarser level fed row by row from the
//! one above, so their memory grows with the texture's width but never with its height.
//!
//! This module does not read configuration files; checking what it wrote is left to
//! [`crate::config`] and the plan.

pub(crate) mod band;
pub(crate) mod border;
pub mod cog;
pub mod cog_config;
pub(crate) mod configfile;
pub mod error;
pub(crate) mod filter;
pub(crate) mod heights;
pub(crate) mod inset;
pub mod jpeg_check;
pub mod layout;
pub mod output;
pub(crate) mod pipeline;
pub mod publish;
pub(crate) mod sink;
pub mod source;
pub mod tiff_stream;

pub use error::PrepError;
pub use filter::Filter;
pub use heights::{HeightInput, HeightPrep};
pub use inset::{Inset, SparseLevel, TileRect, TileRole};
pub use layout::{Compression, Layout, Level, LevelKind, Spec, TileLocation};
pub use pipeline::{run, Job, Source, Summary};

pub use crate::limits::MAX_MEMORY_MIB;

/// The preparation's bounds ([`crate::limits::PrepLimits`], with every other bound of the project).
pub use crate::limits::PrepLimits as Limits;
