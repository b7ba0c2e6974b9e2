//! A simulated disk: a wrapper that lets at most `per_tick` reads a tick reach the source it
//! wraps, and puts the others off ([`SourceError::Busy`]: the tile stays wanted and is asked
//! for again at the next tick, in priority order, as a disk with a queue would serve it).
//!
//! Owns the count of reads this tick and in all; the caller says when a tick starts
//! ([`ThrottledSource::next_tick`]). Benchmarks and tests use it in lock step with the clipmap
//! (a tick, then every read that can start), so that late data shows the same on every machine.

use super::{Delivered, SourceError, TextureDesc, TileId, TileSource};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// At most `per_tick` reads of `inner` a tick.
pub struct ThrottledSource {
    inner: Arc<dyn TileSource>,
    per_tick: u64,
    used: AtomicU64,
    reads: AtomicU64,
    busy: AtomicU64,
}

impl ThrottledSource {
    /// A disk of `per_tick` tiles a tick (at least 1) in front of `inner`.
    pub fn new(inner: Arc<dyn TileSource>, per_tick: u64) -> Self {
        ThrottledSource {
            inner,
            per_tick: per_tick.max(1),
            used: AtomicU64::new(0),
            reads: AtomicU64::new(0),
            busy: AtomicU64::new(0),
        }
    }

    /// A new tick: `per_tick` reads may start again.
    pub fn next_tick(&self) {
        self.used.store(0, Ordering::SeqCst);
    }

    /// Reads that reached the inner source (and delivered or failed there).
    pub fn reads(&self) -> u64 {
        self.reads.load(Ordering::SeqCst)
    }

    /// Reads put off because the tick's reads were spent.
    pub fn put_off(&self) -> u64 {
        self.busy.load(Ordering::SeqCst)
    }
}

impl TileSource for ThrottledSource {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.read_into(tile, out).map(|_| ())
    }

    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<Delivered, SourceError> {
        let per_tick = self.per_tick;
        if self.used.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |u| (u < per_tick).then_some(u + 1)).is_err() {
            self.busy.fetch_add(1, Ordering::SeqCst);
            return Err(SourceError::Busy { tile, per_tick });
        }
        self.reads.fetch_add(1, Ordering::SeqCst);
        self.inner.read_into(tile, out)
    }

    fn wrapped(&self) -> Option<&dyn TileSource> {
        Some(&*self.inner)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::HashSource;
    use crate::texel::TexelFormat;

    #[test]
    fn at_most_per_tick_reads_a_tick_reach_the_disk() {
        let desc = TextureDesc::new([64, 64], 32, TexelFormat::L8, [16, 16]).unwrap();
        let disk = ThrottledSource::new(Arc::new(HashSource::new(desc)), 2);
        let mut out = vec![0u8; 256];
        let mut read = |s| disk.read_into(TileId::new(0, s, 0), &mut out).is_ok();
        assert_eq!([read(0), read(1), read(2)], [true, true, false]);
        disk.next_tick();
        assert!(read(2));
        assert_eq!((disk.reads(), disk.put_off()), (3, 1));
    }
}
