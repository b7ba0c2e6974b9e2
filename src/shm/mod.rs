//! The shared-memory access layer (docs/ARCHITECTURE.md §5, `docs/SHM.md`): the `clipmap-shm`
//! crate, re-exported whole (its layout, writer, client and the only `unsafe` code), and what
//! needs the engine besides: tiles a source takes from a mapping ([`shared_reads`]).

pub use clipmap_shm::*;

pub mod shared_reads;

#[cfg(test)]
mod tests;

pub use shared_reads::{Freshness, FromMapping};
