//! Range merging, in one place: which ranges of one object are read with one request, by one
//! rule ([`run`]) with a parameter ([`Rule`]), and the figure of the ranges read that way
//! ([`Merged`]). Two readers use it:
//! - the tiles a read queue announced, read with the tile asked for when their stored bytes lie
//!   within a gap of each other and the request stays within a byte cap (the bytes of the gaps
//!   are read and dropped): [`Rule::within`], for `ahead::ReadAhead` (a remote COG);
//! - ranges waiting together for the same endpoint, merged when they touch exactly and the
//!   request stays within the remote options' `merge_bytes`: [`Rule::touching`], for the remote
//!   fetcher (`remote::fetch`).
//!
//! Whoever sends a merged request counts it in the [`Merged`] of its remote reader (the fetcher
//! for the waiting ranges it merges itself; `range::RangeReader::stream` told how many ranges a
//! read-ahead request holds).

use std::sync::atomic::{AtomicU64, Ordering};

/// A tile's stored bytes in the object: `[start, start + len)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Piece<K> {
    /// The tile.
    pub key: K,
    /// First byte.
    pub start: u64,
    /// Bytes.
    pub len: u64,
}

impl<K> Piece<K> {
    /// One past its last byte.
    pub fn end(&self) -> u64 {
        self.start.saturating_add(self.len)
    }
}

/// How far apart the ranges of one request may lie, and how many bytes it may read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rule {
    /// The most bytes between the run and a range that joins it, read and dropped; `None`: the
    /// range must start exactly where the run ends (no gap, no overlap).
    pub gap: Option<u64>,
    /// The most bytes the request reads (its gaps included); the range asked for alone may be
    /// larger.
    pub cap: u64,
}

impl Rule {
    /// Ranges within `gap` bytes of the run (or overlapping it), at most `cap` bytes in all.
    pub fn within(gap: u64, cap: u64) -> Rule {
        Rule { gap: Some(gap), cap }
    }

    /// Ranges that touch exactly, at most `cap` bytes in all.
    pub fn touching(cap: u64) -> Rule {
        Rule { gap: None, cap }
    }

    /// Whether a range starting at `start` may follow a run that ends at `end` (and starts at
    /// `first`).
    fn follows(&self, first: u64, end: u64, start: u64) -> bool {
        match self.gap {
            None => start == end,
            Some(gap) => start >= first && start.saturating_sub(end) <= gap,
        }
    }
}

/// The pieces to read with one request together with `pieces[head]`: the index range `lo..=hi`
/// (containing `head`) of `pieces`, sorted by start, grown from the head forward while the next
/// piece may follow the run ([`Rule::gap`]), then backward the same way (the run may follow the
/// previous piece), as long as the run's bytes (gaps included) stay within [`Rule::cap`]; the
/// head alone may be larger than the cap.
pub fn run<K>(pieces: &[Piece<K>], head: usize, rule: Rule) -> (usize, usize) {
    let (mut lo, mut hi) = (head, head);
    let (mut start, mut end) = (pieces[head].start, pieces[head].end());
    while hi + 1 < pieces.len() {
        let next = &pieces[hi + 1];
        let new_end = end.max(next.end());
        if !rule.follows(start, end, next.start) || new_end - start > rule.cap {
            break;
        }
        hi += 1;
        end = new_end;
    }
    while lo > 0 {
        let prev = &pieces[lo - 1];
        let new_start = start.min(prev.start);
        if prev.end() > end || !rule.follows(prev.start, prev.end(), start) || end - new_start > rule.cap {
            break;
        }
        lo -= 1;
        start = new_start;
    }
    (lo, hi)
}

/// Ranges read by a request that merged several (a request of one range is not counted): the
/// `merged` figure of a remote reader's statistics.
#[derive(Debug, Default)]
pub struct Merged(AtomicU64);

impl Merged {
    /// Counts a request that read `ranges` ranges.
    pub fn count(&self, ranges: u64) {
        if ranges > 1 {
            self.0.fetch_add(ranges, Ordering::Relaxed);
        }
    }

    /// Ranges counted so far.
    pub fn get(&self) -> u64 {
        self.0.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pieces(ranges: &[(u64, u64)]) -> Vec<Piece<usize>> {
        ranges.iter().enumerate().map(|(key, &(start, len))| Piece { key, start, len }).collect()
    }

    #[test]
    fn adjacent_ranges_merge_both_ways_within_the_cap_and_a_gap_or_overlap_stops_them() {
        // 0..10, 10..20, 20..30, a gap, 31..41, 41..51.
        let r = pieces(&[(0, 10), (10, 10), (20, 10), (31, 10), (41, 10)]);
        let touching = |at, cap| run(&r, at, Rule::touching(cap));
        assert_eq!(touching(1, 100), (0, 2), "the gap before 31 stops the run");
        assert_eq!(touching(4, 100), (3, 4));
        // Grown forward first: 10..20 takes 20..30, then 0..10 would pass 25.
        assert_eq!(touching(1, 25), (1, 2));
        assert_eq!(touching(1, 5), (1, 1), "a range larger than the cap is read alone");
        // Overlapping ranges are not adjacent.
        assert_eq!(run(&pieces(&[(0, 10), (5, 10)]), 0, Rule::touching(100)), (0, 0));
        assert_eq!(run(&pieces(&[(0, 10), (5, 10)]), 1, Rule::touching(100)), (1, 1));
    }

    #[test]
    fn coalescing_reads_gaps_up_to_the_gap_and_stops_at_the_cap() {
        let ps = pieces(&[(0, 10), (15, 10), (40, 10), (51, 10)]);
        let within = |head, gap, cap| run(&ps, head, Rule::within(gap, cap));
        assert_eq!(within(1, 5, 1000), (0, 1), "the 15-byte gap before 40 is too wide");
        assert_eq!(within(2, 5, 1000), (2, 3));
        assert_eq!(within(2, 20, 40), (2, 3), "15..61 would pass the cap");
        assert_eq!(within(2, 20, 50), (1, 3), "forward first, then back while the run fits");
        assert_eq!(within(0, 20, 5), (0, 0));
        // Within a gap, a piece overlapping the run joins it (its bytes are cut from the run's).
        assert_eq!(run(&pieces(&[(0, 10), (5, 10)]), 0, Rule::within(0, 100)), (0, 1));
    }

    #[test]
    fn one_rule_grows_forward_first_whatever_the_gap() {
        // Four touching ranges of 10 bytes, the second asked for, 30 bytes at most: forward as far
        // as the cap allows, then back; the same run with or without gaps allowed.
        let ps = pieces(&[(0, 10), (10, 10), (20, 10), (30, 10)]);
        assert_eq!(run(&ps, 1, Rule::touching(30)), (1, 3));
        assert_eq!(run(&ps, 1, Rule::within(4, 30)), (1, 3));
        assert_eq!(run(&ps, 3, Rule::touching(30)), (1, 3), "nothing ahead: back as far as the cap allows");
    }

    #[test]
    fn only_requests_of_several_ranges_are_counted_as_merged() {
        let m = Merged::default();
        m.count(1);
        m.count(0);
        assert_eq!(m.get(), 0, "a request of one range is not merged");
        m.count(3);
        m.count(2);
        assert_eq!(m.get(), 5);
    }
}
