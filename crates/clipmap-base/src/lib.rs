//! # clipmap-base
//!
//! The ground floor of `clipmap` (docs/ARCHITECTURE.md §12, floor 1): the words every other part
//! speaks and that speak of nothing else. It depends on no other crate of the workspace, runs no
//! async runtime and reads no network.
//!
//! | module | owns |
//! |---|---|
//! | [`tile`] | a tile's name, the size of a mipmap level, the 64-bit mixing behind the verification texture |
//! | [`texel`] | texel formats, bytes per texel, colour encoding |
//! | [`height`] | elevation: height encodings, level rules for heights, per-tile height ranges |
//! | [`geom`] | pure level geometry: centres, tex / valid / mem regions, toroidal addressing |
//! | [`georef`] | where a texture is on the Earth: CRS, each level's transform, texel <-> map <-> longitude / latitude |
//! | [`limits`] | every bound the paging engine keeps (queue lengths, reads in flight, bytes) |
//! | [`open`] | the one way to open a file a configuration names: regular files only, never blocking |
//! | [`save`] | writing a result file completely or not at all (temporary, sync, rename) |
//! | [`sizing`] | memory and bandwidth arithmetic, clip-size and virtual-level recommendations |
//!
//! The `clipmap` crate re-exports every module under its old path (`clipmap::geom`, ...).

#![deny(unsafe_code)]

pub mod geom;
pub mod georef;
pub mod height;
pub mod limits;
pub mod open;
pub mod save;
pub mod sizing;
pub mod texel;
pub mod tile;
