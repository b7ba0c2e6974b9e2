//! The byte ranges of each object already fetched from its store, so that a read of bytes that
//! were fetched before is counted as a duplicate ([`Seen::fetched`]): every tile is meant to be
//! read once (the read-ahead keeps the bytes of the tiles a merged request passes over, the
//! built levels keep the level they are built from), and `STATS` shows `duplicate_reads` and
//! `duplicate_bytes` so that a regression shows.
//!
//! Ranges are kept per object as disjoint intervals, joined when they touch, at most
//! [`MAX_INTERVALS`] over all objects: past it the oldest object's ranges are forgotten (its
//! later duplicates go uncounted; the count is a floor, never an overcount).

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

/// Most intervals remembered over all objects.
pub const MAX_INTERVALS: usize = 1 << 16;

#[derive(Default)]
struct Ranges {
    /// Object name to its fetched intervals (start to end, disjoint, never touching).
    by_object: HashMap<String, BTreeMap<u64, u64>>,
    /// Objects in the order first seen (the oldest forgotten first).
    order: VecDeque<String>,
    intervals: usize,
}

/// Fetched ranges and the duplicates among them.
#[derive(Default)]
pub struct Seen {
    ranges: Mutex<Ranges>,
    reads: AtomicU64,
    bytes: AtomicU64,
}

impl Seen {
    /// Bytes `[start, start + len)` of `object` arrived from the store: counted as a duplicate
    /// read when any of them had arrived before. Returns the bytes fetched before.
    pub fn fetched(&self, object: &str, start: u64, len: u64) -> u64 {
        if len == 0 {
            return 0;
        }
        let end = start.saturating_add(len);
        let mut r = self.ranges.lock().unwrap_or_else(|e| e.into_inner());
        let r = &mut *r;
        if !r.by_object.contains_key(object) {
            r.order.push_back(object.to_string());
        }
        let map = r.by_object.entry(object.to_string()).or_default();
        // The intervals that overlap or touch [start, end): from the last one starting at or
        // before `start` on.
        let first = map.range(..=start).next_back().map(|(s, _)| *s);
        let keys: Vec<u64> =
            first.into_iter().chain(map.range(start.saturating_add(1)..=end).map(|(s, _)| *s)).collect();
        let (mut lo, mut hi, mut overlap) = (start, end, 0u64);
        let mut removed = 0usize;
        for k in keys {
            let e = map[&k];
            if e < start || k > end {
                continue;
            }
            overlap += e.min(end).saturating_sub(k.max(start));
            lo = lo.min(k);
            hi = hi.max(e);
            map.remove(&k);
            removed += 1;
        }
        map.insert(lo, hi);
        r.intervals = r.intervals + 1 - removed;
        while r.intervals > MAX_INTERVALS && r.order.len() > 1 {
            let Some(old) = r.order.pop_front() else { break };
            if let Some(m) = r.by_object.remove(&old) {
                r.intervals -= m.len();
            }
        }
        if overlap > 0 {
            self.reads.fetch_add(1, Ordering::Relaxed);
            self.bytes.fetch_add(overlap, Ordering::Relaxed);
        }
        overlap
    }

    /// Reads that fetched bytes fetched before.
    pub fn duplicate_reads(&self) -> u64 {
        self.reads.load(Ordering::Relaxed)
    }

    /// Bytes fetched more than once (each time after the first).
    pub fn duplicate_bytes(&self) -> u64 {
        self.bytes.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The overlap counted equals a brute-force count over a byte map.
        #[test]
        fn overlaps_are_the_bytes_seen_before(reads in proptest::collection::vec((0u64..200, 0u64..40), 1..60)) {
            let seen = Seen::default();
            let mut bytes = [false; 260];
            let (mut dup_reads, mut dup_bytes) = (0, 0);
            for (start, len) in reads {
                let before = (start..start + len).filter(|&b| bytes[b as usize]).count() as u64;
                prop_assert_eq!(seen.fetched("o", start, len), before);
                if before > 0 {
                    dup_reads += 1;
                    dup_bytes += before;
                }
                for b in start..start + len {
                    bytes[b as usize] = true;
                }
            }
            prop_assert_eq!(seen.duplicate_reads(), dup_reads);
            prop_assert_eq!(seen.duplicate_bytes(), dup_bytes);
        }
    }

    #[test]
    fn objects_are_apart_and_touching_ranges_are_not_duplicates() {
        let seen = Seen::default();
        assert_eq!(seen.fetched("a", 0, 10), 0);
        assert_eq!(seen.fetched("a", 10, 10), 0);
        assert_eq!(seen.fetched("b", 5, 10), 0);
        assert_eq!(seen.fetched("a", 5, 10), 10);
        assert_eq!((seen.duplicate_reads(), seen.duplicate_bytes()), (1, 10));
    }

    #[test]
    fn the_oldest_object_is_forgotten_past_the_bound() {
        let seen = Seen::default();
        for i in 0..MAX_INTERVALS as u64 {
            seen.fetched("old", i * 10, 1);
        }
        seen.fetched("new", 0, 1);
        // "old" was forgotten: its bytes read again are not counted.
        assert_eq!(seen.fetched("old", 0, 1), 0);
        assert_eq!(seen.fetched("new", 0, 1), 1);
    }
}
