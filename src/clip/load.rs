//! Load control (docs/ARCHITECTURE.md §6, docs/PERFORMER-REFERENCE.md §2.5): how min LOD moves.
//!
//! Owns the pure rules that turn "which levels are whole" into min LOD: raise it at once past any
//! level that is not, lower it by one level per `fade_ticks` ticks once they are. Deciding which
//! levels are whole (their tiles settled) is [`super`]'s business.

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
}
