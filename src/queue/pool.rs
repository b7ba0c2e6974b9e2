//! Tile buffers handed back for reuse.
//!
//! Every read needs a tile-sized buffer, and a fresh `vec![0; n]` costs a page-zeroing pass over
//! it before the read overwrites every byte (`memset`: 9% of all samples in the ingest profile
//! of docs/BENCHMARKS.md). The tile cache hands the buffers of evicted tiles back here and the
//! runners take them for their next reads. Reuse is safe because a [`TileSource`] that answers
//! `Ok` has written every byte of its buffer (its contract); a buffer whose read failed is never
//! handed back, so a torn read cannot leak into a later tile.
//!
//! [`TileSource`]: crate::source::TileSource

use std::sync::{Arc, Mutex};

/// A bounded stack of spare tile buffers, shared by the read runners and the tile cache's owner.
#[derive(Clone, Debug)]
pub struct BufferPool {
    inner: Arc<Mutex<Inner>>,
}

#[derive(Debug)]
struct Inner {
    free: Vec<Vec<u8>>,
    cap: usize,
    reused: u64,
    allocated: u64,
}

/// How the pool served the reads so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PoolCounts {
    /// Reads that got a handed-back buffer.
    pub reused: u64,
    /// Reads that got a freshly allocated, zeroed buffer.
    pub allocated: u64,
    /// Buffers waiting in the pool now.
    pub spare: usize,
}

impl BufferPool {
    /// A pool keeping at most `cap` spare buffers (more are freed).
    pub fn new(cap: usize) -> Self {
        BufferPool { inner: Arc::new(Mutex::new(Inner { free: Vec::new(), cap, reused: 0, allocated: 0 })) }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        // A panic while holding the lock leaves only a Vec of spare buffers behind: still valid.
        self.inner.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// A buffer of exactly `len` bytes. Its contents are unspecified (old texels or zeros): the
    /// caller must overwrite all of it before using it.
    pub fn take(&self, len: usize) -> Vec<u8> {
        let mut inner = self.lock();
        if let Some(i) = inner.free.iter().rposition(|b| b.len() == len) {
            inner.reused += 1;
            return inner.free.swap_remove(i);
        }
        inner.allocated += 1;
        drop(inner);
        vec![0; len]
    }

    /// Hands `buf` back for a later [`take`](Self::take); freed instead when the pool is full.
    pub fn give(&self, buf: Vec<u8>) {
        let mut inner = self.lock();
        if inner.free.len() < inner.cap && !buf.is_empty() {
            inner.free.push(buf);
        }
    }

    /// Counters so far.
    pub fn counts(&self) -> PoolCounts {
        let inner = self.lock();
        PoolCounts { reused: inner.reused, allocated: inner.allocated, spare: inner.free.len() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_come_back_by_length_and_the_pool_stays_bounded() {
        let pool = BufferPool::new(2);
        let a = pool.take(16);
        assert_eq!(a, vec![0; 16], "a fresh buffer is zeroed");
        pool.give(vec![7; 16]);
        pool.give(vec![8; 32]);
        pool.give(vec![9; 16]); // over the cap: freed
        assert_eq!(pool.counts(), PoolCounts { reused: 0, allocated: 1, spare: 2 });
        assert_eq!(pool.take(32), vec![8; 32], "the buffer of the asked length");
        assert_eq!(pool.take(16), vec![7; 16]);
        assert_eq!(pool.take(16), vec![0; 16], "none left of that length: a fresh one");
        assert_eq!(pool.counts(), PoolCounts { reused: 2, allocated: 2, spare: 0 });
    }
}
