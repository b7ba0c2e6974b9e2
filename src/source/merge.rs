//! Range merging, in one place: which ranges of one object are read with one request. Two
//! policies share it:
//! - [`coalesce`]: the tiles a read queue announced, read with the tile asked for when their
//!   stored bytes lie within a gap of each other and the request stays within a byte cap (the
//!   bytes of the gaps are read and dropped): `ahead::ReadAhead`, for a remote COG;
//! - [`adjacent`]: ranges waiting together for the same endpoint, merged when they touch exactly
//!   and the request stays within the remote options' `merge_bytes`: the remote fetcher
//!   (`remote::fetch`).
//!
//! The figures of merged reads are counted by whoever sends the request (the remote reader's
//! counters, `remote::fetch::Counters`), told how many ranges a request holds
//! (`range::RangeReader::stream`).

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

/// The pieces to read with one request together with `pieces[head]`: the index range `lo..=hi`
/// (containing `head`) of `pieces`, sorted by start, grown from the head forward while the next
/// piece starts at most `gap` bytes after the run ends, then backward the same way, as long as
/// the run's bytes (gaps included) stay within `cap`; the head alone may be larger than `cap`.
pub fn coalesce<K>(pieces: &[Piece<K>], head: usize, gap: u64, cap: u64) -> (usize, usize) {
    let (mut lo, mut hi) = (head, head);
    let (mut start, mut end) = (pieces[head].start, pieces[head].end());
    while hi + 1 < pieces.len() {
        let next = &pieces[hi + 1];
        let new_end = end.max(next.end());
        if next.start < start || next.start.saturating_sub(end) > gap || new_end - start > cap {
            break;
        }
        hi += 1;
        end = new_end;
    }
    while lo > 0 {
        let prev = &pieces[lo - 1];
        let new_start = start.min(prev.start);
        if prev.end() > end || start.saturating_sub(prev.end()) > gap || end - new_start > cap {
            break;
        }
        lo -= 1;
        start = new_start;
    }
    (lo, hi)
}

/// The ranges read with one request together with `ranges[at]` (`(start, len)` each, sorted by
/// start) when they must touch exactly: the index range `lo..=hi` (containing `at`), grown one
/// range forward then one backward in turn while the next range starts where the run ends (the
/// previous one ends where it starts) and the ranges' bytes stay within `cap`; `at` alone may
/// be larger than `cap`.
pub fn adjacent(ranges: &[(u64, u64)], at: usize, cap: u64) -> (usize, usize) {
    let (mut lo, mut hi) = (at, at);
    let mut bytes = ranges[at].1;
    loop {
        let mut grew = false;
        if hi + 1 < ranges.len() {
            let (a, b) = (ranges[hi], ranges[hi + 1]);
            if b.0 == a.0 + a.1 && bytes + b.1 <= cap {
                hi += 1;
                bytes += b.1;
                grew = true;
            }
        }
        if lo > 0 {
            let (a, b) = (ranges[lo - 1], ranges[lo]);
            if a.0 + a.1 == b.0 && bytes + a.1 <= cap {
                lo -= 1;
                bytes += a.1;
                grew = true;
            }
        }
        if !grew {
            break;
        }
    }
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adjacent_ranges_merge_both_ways_within_the_cap_and_a_gap_or_overlap_stops_them() {
        // 0..10, 10..20, 20..30, a gap, 31..41, 41..51.
        let r = [(0, 10), (10, 10), (20, 10), (31, 10), (41, 10)];
        assert_eq!(adjacent(&r, 1, 100), (0, 2), "the gap before 31 stops the run");
        assert_eq!(adjacent(&r, 4, 100), (3, 4));
        // Grown forward then backward in turn: 10..20 takes 20..30, then 0..10 would pass 25.
        assert_eq!(adjacent(&r, 1, 25), (1, 2));
        assert_eq!(adjacent(&r, 1, 5), (1, 1), "a range larger than the cap is read alone");
        // Overlapping ranges are not adjacent.
        assert_eq!(adjacent(&[(0, 10), (5, 10)], 0, 100), (0, 0));
    }

    #[test]
    fn coalescing_reads_gaps_up_to_the_gap_and_stops_at_the_cap() {
        let p = |key, start, len| Piece { key, start, len };
        let ps = [p(0, 0, 10), p(1, 15, 10), p(2, 40, 10), p(3, 51, 10)];
        assert_eq!(coalesce(&ps, 1, 5, 1000), (0, 1), "the 15-byte gap before 40 is too wide");
        assert_eq!(coalesce(&ps, 2, 5, 1000), (2, 3));
        assert_eq!(coalesce(&ps, 2, 20, 40), (2, 3), "15..61 would pass the cap");
        assert_eq!(coalesce(&ps, 2, 20, 50), (1, 3), "forward first, then back while the run fits");
        assert_eq!(coalesce(&ps, 0, 20, 5), (0, 0));
    }
}
