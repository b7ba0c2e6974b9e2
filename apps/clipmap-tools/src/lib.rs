//! # clipmap-tools
//!
//! The library of the clipmap tools above the service, and their binaries (`cliptex`, `icache`,
//! `clipbench`, `clipprep`, `clipmapd`, `clipmap-read`, each an ordinary bin target of this
//! package under `src/bin/`). The command line the binaries share and the reports they print live
//! below, in the `clipmap` crate (`clipmap::cli`, `clipmap::report`), so that the engine's own
//! tools and the GPU client share them; the service is `clipmap-service`.
//!
//! | module | owns |
//! |---|---|
//! | [`inspect`] | a running service seen from outside: `cliptex attach` and `dump --attach` |
//! | [`demo`] | `clipmapd --demo`: the service, a small flying client and pictures of what it saw (a client of the rest, the top floor) |
//!
//! Both are public, for the binaries: `inspect` with its `attach` (`cliptex attach`) and
//! `live_dump` (`dump --attach`), and `demo`; `tests/it/api.rs` holds this list.

#![deny(unsafe_code)]

pub mod demo;
pub mod inspect;
