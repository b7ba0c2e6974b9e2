//! Load control (docs/ARCHITECTURE.md §6, docs/PERFORMER-REFERENCE.md §2.5): what a copy costs and how min LOD moves.
//!
//! Owns the copy-cost table (measured at start-up, or given by tests so that decisions are
//! deterministic) and the pure rules that turn "which levels are up to date" into min LOD: raise
//! it at once past any level that is not, lower it by one level per `fade_ticks` ticks once they
//! are. Applying these decisions to windows is [`super`]'s business.

use serde::Serialize;
use std::time::Instant;

/// Estimated cost of copying a band of texels: a fixed cost per band, per line and per byte.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CostTable {
    /// Nanoseconds per band (bookkeeping, tile look-ups).
    pub per_band_ns: f64,
    /// Nanoseconds per line of a band.
    pub per_line_ns: f64,
    /// Nanoseconds per byte copied.
    pub per_byte_ns: f64,
}

impl CostTable {
    /// A table with the given costs (deterministic; for tests and simulations).
    pub fn fixed(per_band_ns: f64, per_line_ns: f64, per_byte_ns: f64) -> Self {
        CostTable { per_band_ns, per_line_ns, per_byte_ns }
    }

    /// Measures this machine: copies rows of `bpt`-byte texels and keeps the fastest of a few
    /// runs, so a busy moment does not inflate the estimate.
    pub fn measure(bpt: usize) -> Self {
        // Larger than the caches, as window copies are.
        let row = 256 * bpt.max(1);
        let rows = (8 << 20) / row;
        let src = vec![0x5Au8; row * rows];
        let mut dst = vec![0u8; row * rows];
        let mut best_short = f64::MAX;
        let mut best_long = f64::MAX;
        for _ in 0..3 {
            let t = Instant::now();
            for (d, s) in dst.chunks_exact_mut(8).zip(src.chunks_exact(8)) {
                d.copy_from_slice(s);
            }
            best_short = best_short.min(t.elapsed().as_nanos() as f64 / (src.len() / 8) as f64);
            let t = Instant::now();
            for (d, s) in dst.chunks_exact_mut(row).zip(src.chunks_exact(row)) {
                d.copy_from_slice(s);
            }
            best_long = best_long.min(t.elapsed().as_nanos() as f64);
            std::hint::black_box(&dst);
        }
        let per_byte_ns = (best_long / src.len() as f64).max(0.01);
        let per_line_ns = (best_short * 8.0 - 8.0 * per_byte_ns).max(1.0);
        CostTable { per_band_ns: 200.0, per_line_ns, per_byte_ns }
    }

    /// Estimated nanoseconds to copy `lines` lines of `line_bytes` bytes as one band.
    pub fn band_ns(&self, lines: u64, line_bytes: u64) -> f64 {
        self.per_band_ns + lines as f64 * (self.per_line_ns + line_bytes as f64 * self.per_byte_ns)
    }

    /// Most lines of `line_bytes` bytes one band may have within `budget_ns` (0 if none fit).
    pub fn lines_within(&self, budget_ns: f64, line_bytes: u64) -> u64 {
        let per_line = self.per_line_ns + line_bytes as f64 * self.per_byte_ns;
        let left = budget_ns - self.per_band_ns;
        if left < per_line {
            0
        } else if per_line <= 0.0 {
            u64::MAX
        } else {
            (left / per_line).floor().min(u64::MAX as f64) as u64
        }
    }
}

/// The finest level renderers may use given which levels are up to date: the smallest `m` such
/// that every level from `m` to the coarsest is complete (`complete.len()` if the coarsest is not).
pub fn target_min_lod(complete: &[bool]) -> usize {
    complete.iter().rposition(|&c| !c).map_or(0, |k| k + 1)
}

/// The next min LOD: at once up to `target` if it lies above (a level not up to date must never
/// be shown), else down towards it by `(current - target) / fade_ticks` per tick as Performer
/// does, but by at least `1 / fade_ticks`, so that the last level fades in over exactly
/// `fade_ticks` ticks and the approach ends (at once when `fade_ticks` is 0).
pub fn next_min_lod(current: f64, target: usize, fade_ticks: u32) -> f64 {
    let target = target as f64;
    if current <= target || fade_ticks == 0 {
        return target;
    }
    let n = fade_ticks as f64;
    let step = ((current - target) / n).max(1.0 / n);
    (current - step).max(target)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn min_lod_target_is_the_finest_level_above_which_all_are_complete() {
        let cases: [(&[bool], usize); 5] = [
            (&[true, true, true], 0),
            (&[false, true, true], 1),
            (&[true, false, true], 2),
            (&[true, true, false], 3),
            (&[], 0),
        ];
        for (complete, want) in cases {
            assert_eq!(target_min_lod(complete), want, "{complete:?}");
        }
    }

    #[test]
    fn min_lod_rises_at_once_and_fades_down_in_bounded_ticks() {
        assert_eq!(next_min_lod(0.0, 3, 4), 3.0);
        // The last level fades in over exactly `fade_ticks` ticks.
        let lods: Vec<f64> = (1..=4)
            .scan(2.0, |lod, _| {
                Some({
                    *lod = next_min_lod(*lod, 1, 4);
                    *lod
                })
            })
            .collect();
        assert_eq!(lods, vec![1.75, 1.5, 1.25, 1.0]);
        // Several levels: a quarter of the gap per tick, then a quarter level per tick.
        assert_eq!(next_min_lod(9.0, 1, 4), 7.0);
        let mut lod = 9.0;
        let mut steps = 0;
        while lod > 1.0 {
            let next = next_min_lod(lod, 1, 4);
            assert!(next < lod && (lod - next >= 0.25 || next == 1.0));
            lod = next;
            steps += 1;
        }
        assert_eq!(lod, 1.0);
        assert!(steps <= 4 * 4, "bounded: {steps} ticks");
        assert_eq!(next_min_lod(3.0, 1, 0), 1.0);
        assert_eq!(next_min_lod(1.25, 1, 2), 1.0, "never below the target");
    }

    #[test]
    fn cost_table_sizes_bands_to_the_budget() {
        let c = CostTable::fixed(100.0, 10.0, 1.0);
        assert_eq!(c.band_ns(4, 90), 100.0 + 4.0 * 100.0);
        assert_eq!(c.lines_within(500.0, 90), 4);
        assert_eq!(c.lines_within(199.0, 90), 0);
        let m = CostTable::measure(4);
        assert!(m.per_byte_ns > 0.0 && m.per_line_ns > 0.0 && m.band_ns(10, 1024).is_finite());
    }
}
