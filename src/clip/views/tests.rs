//! Tests of further views: every view's published texels are right after any walk of any views
//! (the layout-2 invariant per view), near views share reads and grids, weights order reads.

use super::*;
use crate::clip::tests::{check_view, disk_step, hash_source, over_disk, settings};
use crate::clip::Settings;
use crate::texel::TexelFormat;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};
use std::sync::Arc;

#[derive(Clone, Debug)]
enum Step {
    /// Moves the primary view.
    Primary(i64, i64),
    /// Moves further view `i` (of those live, modulo their count) by a step.
    Move(usize, i64, i64),
    /// Puts further view `i` near the primary (offset in level-0 texels).
    Near(usize, i64, i64),
    /// Jumps further view `i` anywhere.
    Jump(usize, i64, i64),
    Add(u8),
    Remove(usize),
    Weight(usize, u8),
    /// Sets view `i`'s LOD window (4: the primary's): offset, effective levels.
    Lod(usize, u32, u32),
    Wait,
}

fn step() -> impl Strategy<Value = Step> {
    prop_oneof![
        3 => (-6i64..=6, -6i64..=6).prop_map(|(a, b)| Step::Primary(a, b)),
        3 => (0usize..4, -9i64..=9, -9i64..=9).prop_map(|(i, a, b)| Step::Move(i, a, b)),
        2 => (0usize..4, -300i64..300, -300i64..300).prop_map(|(i, a, b)| Step::Near(i, a, b)),
        1 => (0usize..4, -(1i64 << 20)..(1i64 << 20), -(1i64 << 20)..(1i64 << 20)).prop_map(|(i, a, b)| Step::Jump(i, a, b)),
        1 => (1u8..=4).prop_map(Step::Add),
        1 => (0usize..4).prop_map(Step::Remove),
        1 => (0usize..5, 1u8..=4).prop_map(|(i, w)| Step::Weight(i, w)),
        1 => (0usize..5, 0u32..4, prop_oneof![Just(u32::MAX), 1u32..4]).prop_map(|(i, o, e)| Step::Lod(i, o, e)),
        3 => Just(Step::Wait),
    ]
}

/// Runs `steps` over a hash texture, checking every view's publication after every tick.
fn walk(
    size: u64,
    clip: u64,
    tile: u64,
    spread: u64,
    budget: Option<u64>,
    steps: &[Step],
) -> Result<(), TestCaseError> {
    let src = hash_source([size, size], clip, tile, 1.min(clip / 4), TexelFormat::RGBA8);
    let s = Settings { view_spread: spread, ..settings(budget) };
    let mut map = Clipmap::new(src, s).unwrap();
    let mut c = [size as i64 / 2, size as i64 / 3];
    let mut positions: std::collections::HashMap<ViewId, [i64; 2]> = Default::default();
    let first = map.add_view(1.0).unwrap();
    positions.insert(first, [c[0] + 40, c[1] - 25]);
    for st in steps {
        let live: Vec<ViewId> = map.view_ids().into_iter().filter(|&v| v != PRIMARY).collect();
        let pick = |i: usize| (!live.is_empty()).then(|| live[i % live.len()]);
        match *st {
            Step::Primary(a, b) => c = [c[0] + a, c[1] + b],
            Step::Move(i, a, b) => {
                if let Some(v) = pick(i) {
                    let p = positions.entry(v).or_insert(c);
                    *p = [p[0] + a, p[1] + b];
                }
            }
            Step::Near(i, a, b) => {
                if let Some(v) = pick(i) {
                    positions.insert(v, [c[0] + a, c[1] + b]);
                }
            }
            Step::Jump(i, a, b) => {
                if let Some(v) = pick(i) {
                    positions.insert(v, [a, b]);
                }
            }
            Step::Add(w) => {
                if let Ok(v) = map.add_view(w as f64) {
                    positions.insert(v, c);
                }
            }
            Step::Remove(i) => {
                if let Some(v) = pick(i) {
                    map.remove_view(v).unwrap();
                    positions.remove(&v);
                    prop_assert!(map.view_level(v, 0).is_err());
                }
            }
            Step::Weight(i, w) => {
                let v = if i == 4 { Some(PRIMARY) } else { pick(i) };
                if let Some(v) = v {
                    map.set_view_weight(v, w as f64).unwrap();
                }
            }
            Step::Lod(i, offset, effective) => {
                let v = if i == 4 { Some(PRIMARY) } else { pick(i) };
                if let Some(v) = v {
                    map.set_view_lod(v, LodWindow { offset, effective }).unwrap();
                }
            }
            Step::Wait => map.wait_for_reads(),
        }
        for (&v, &p) in &positions {
            map.move_view(v, p, None).unwrap();
        }
        map.tick(c, None);
        for v in map.view_ids() {
            check_view(&map, v).map_err(TestCaseError::fail)?;
        }
        prop_assert_eq!(map.stats().slots_reassigned_under_views, 0);
        prop_assert_eq!(map.stats().slots_reassigned_under_published, 0);
        // No view publishes a level finer than its LOD offset, nor uses one.
        for v in map.view_ids() {
            let lod = map.view_lod(v).unwrap();
            for k in 0..map.level_count() as u32 {
                if !lod.shows(k) {
                    prop_assert!(
                        map.view_level(v, k).unwrap().valid.is_empty(),
                        "view {} level {} outside {:?}",
                        v,
                        k,
                        lod
                    );
                }
            }
            prop_assert!(map.view_min_lod(v).unwrap() >= lod.offset as f64);
        }
    }
    // Settled: every view whose windows the grids hold whole (with the primary's) shows level 0.
    for v in map.view_ids() {
        map.set_view_lod(v, LodWindow::ALL).unwrap();
    }
    for _ in 0..80 {
        for (&v, &p) in &positions {
            map.move_view(v, p, Some([0, 0])).unwrap();
        }
        map.tick(c, Some([0, 0]));
        map.wait_for_reads();
    }
    for (&v, &p) in &positions {
        map.move_view(v, p, Some([0, 0])).unwrap();
    }
    map.tick(c, Some([0, 0]));
    for v in map.view_ids() {
        check_view(&map, v).map_err(TestCaseError::fail)?;
    }
    prop_assert_eq!(map.min_lod(), 0.0, "the primary's windows are always held");
    // When every view lies close enough to the primary that the grids hold all their windows,
    // every view shows level 0.
    let grid = map.level(0).grid;
    let close = |p: &[i64; 2]| {
        let d = (p[0] - c[0]).unsigned_abs().max((p[1] - c[1]).unsigned_abs());
        d + clip + 2 * tile <= (grid[0] - 1) * tile
    };
    if positions.values().all(close) {
        for &v in positions.keys() {
            prop_assert_eq!(map.view_min_lod(v).unwrap(), 0.0, "view {} of {:?}, primary at {:?}", v, positions, c);
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(Config { cases: 64, rng_seed: RngSeed::Fixed(0x7153), failure_persistence: None, ..Config::default() })]

    /// The oracle property of layout 2, per view: after every tick of any walk of any views
    /// (added, removed, reweighted, moved near and far), every texel each view publishes is the
    /// hash texture's, and no slot under any view's published region went to another tile.
    #[test]
    fn every_views_published_texels_equal_the_source_after_any_walk(
        spread in prop_oneof![Just(0u64), Just(64), Just(256)],
        budget in prop_oneof![Just(None), Just(Some(1u64))],
        steps in proptest::collection::vec(step(), 1..28),
    ) {
        walk(1 << 11, 128, 32, spread, budget, &steps)?;
    }
}

/// Four views within one clip size of each other, over a disk that counts reads.
fn near_flight(spread: u64) -> (Arc<crate::source::ThrottledSource>, Clipmap, Vec<ViewId>) {
    let (disk, mut map) = over_disk(1 << 20, Settings { view_spread: spread, ..settings(None) });
    let ids = (0..3).map(|_| map.add_view(1.0).unwrap()).collect();
    (disk, map, ids)
}

fn fly(disk: &crate::source::ThrottledSource, map: &mut Clipmap, ids: &[ViewId], c: [i64; 2], offsets: &[[i64; 2]]) {
    for (&v, o) in ids.iter().zip(offsets) {
        map.move_view(v, [c[0] + o[0], c[1] + o[1]], None).unwrap();
    }
    disk_step(disk, map, c);
}

#[test]
fn near_views_read_each_tile_once_and_all_show_level_0_when_the_grids_hold_them() {
    // Clip 64, tiles 16: the three further views within 64 texels of the primary.
    let offsets = [[64, 0], [0, -64], [-40, 40]];
    let (disk, mut map, ids) = near_flight(128);
    let mut c = [2000, 2000];
    for i in 0..120 {
        c[0] += 3;
        fly(&disk, &mut map, &ids, c, &offsets);
        for v in map.view_ids() {
            check_view(&map, v).unwrap_or_else(|e| panic!("tick {i}: {e}"));
        }
    }
    for _ in 0..3 {
        fly(&disk, &mut map, &ids, c, &offsets);
    }
    for v in map.view_ids() {
        assert_eq!(map.view_min_lod(v).unwrap(), 0.0, "view {v}");
        assert!(check_view(&map, v).unwrap() > 0);
    }
    let st = map.stats();
    assert_eq!(disk.reads(), st.tiles_read, "each tile read once for all four views");
    assert_eq!(st.slots_reassigned_under_views, 0);
    assert_eq!(st.slots_reassigned_under_published, 0);

    // The same flight with one view: the four read more tiles (their union), but far fewer than
    // four flights would.
    let (disk1, mut one, _) = near_flight(0);
    let mut c = [2000, 2000];
    for _ in 0..123 {
        c[0] += 3;
        disk_step(&disk1, &mut one, c);
    }
    let (four, alone) = (disk.reads() as f64, disk1.reads() as f64);
    assert!(four < 2.0 * alone, "four views read {four} tiles, one alone {alone}");
}

#[test]
fn a_view_the_grids_cannot_hold_shows_coarser_levels_never_a_wrong_texel() {
    let (disk, mut map, ids) = near_flight(0);
    let c = [2000, 2000];
    let offsets = [[1500, 0], [0, 0], [0, 0]];
    for _ in 0..60 {
        fly(&disk, &mut map, &ids, c, &offsets);
        for v in map.view_ids() {
            check_view(&map, v).unwrap();
        }
    }
    // The grid holds the primary's window: the far view is not held whole at level 0 but shows
    // the coarse levels, and the view sharing the primary's centre shows what the primary shows.
    let far = map.view_min_lod(ids[0]).unwrap();
    assert!(far >= 1.0, "the far view cannot show level 0: min LOD {far}");
    assert!(far < map.level_count() as f64, "coarse levels are shown");
    assert_eq!(map.view_min_lod(ids[1]).unwrap(), map.min_lod(), "a view on the primary's centre is the primary");
    for k in 0..map.level_count() as u32 {
        assert_eq!(map.view_level(ids[1], k).unwrap().valid, map.level(k).valid, "level {k}");
    }
    assert_eq!(map.stats().slots_reassigned_under_views, 0);
}

/// Mean min LOD of two views (weights `w0`, `w1`) 192 texels apart flying over a disk of 3 tiles a
/// tick, too slow for both.
fn weighted(w0: f64, w1: f64) -> (f64, f64) {
    let (disk, mut map) = over_disk(3, Settings { view_spread: 256, ..settings(None) });
    map.set_view_weight(PRIMARY, w0).unwrap();
    let other = map.add_view(w1).unwrap();
    let mut c = [1500, 1500];
    let (mut sum0, mut sum1) = (0.0, 0.0);
    let n = 300;
    for i in 0..n {
        c[0] += 4;
        c[1] += 1;
        map.move_view(other, [c[0] + 192, c[1] - 100], None).unwrap();
        disk_step(&disk, &mut map, c);
        if i >= 50 {
            sum0 += map.min_lod();
            sum1 += map.view_min_lod(other).unwrap();
        }
        check_view(&map, PRIMARY).unwrap();
        check_view(&map, other).unwrap();
    }
    ((sum0 / (n - 50) as f64), (sum1 / (n - 50) as f64))
}

#[test]
fn under_a_slow_disk_the_lighter_view_degrades_first() {
    let (heavy, light) = weighted(3.0, 1.0);
    assert!(light > heavy + 0.5, "3:1: heavy {heavy}, light {light}");
    // Swapped weights swap who degrades.
    let (light2, heavy2) = weighted(1.0, 3.0);
    assert!(light2 > heavy2 + 0.5, "1:3: light {light2}, heavy {heavy2}");
}

#[test]
fn demotion_is_log2_of_the_weight_ratio_rounded() {
    assert_eq!(demotion(1.0, 1.0), 0);
    assert_eq!(demotion(3.0, 1.0), 0, "the heavier is never demoted");
    assert_eq!(demotion(1.0, 2.0), 1);
    assert_eq!(demotion(1.0, 3.0), 2);
    assert_eq!(demotion(1.0, 4.0), 2);
    assert_eq!(demotion(1.0, 1e300), 64);
    assert_eq!(demotion(f64::NAN, 1.0), 0);
}

#[test]
fn bad_view_calls_say_what_was_expected() {
    let src = hash_source([1 << 10, 1 << 10], 64, 16, 0, TexelFormat::L8);
    let mut map = Clipmap::new(src, settings(None)).unwrap();
    for w in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let e = map.add_view(w).unwrap_err();
        assert!(matches!(e, ViewError::Weight(_)), "{e}");
        assert!(e.to_string().contains("positive finite"), "{e}");
    }
    assert_eq!(map.remove_view(PRIMARY), Err(ViewError::Primary));
    assert_eq!(map.remove_view(7), Err(ViewError::Unknown(7)));
    assert_eq!(map.move_view(3, [0, 0], None), Err(ViewError::Unknown(3)));
    let a = map.add_view(1.0).unwrap();
    let b = map.add_view(2.0).unwrap();
    assert_eq!((a, b), (1, 2));
    map.remove_view(a).unwrap();
    assert_eq!(map.view_ids(), vec![PRIMARY, b]);
    assert_eq!(map.add_view(1.0).unwrap(), a, "a removed view's number is reused");
    while map.add_view(1.0).is_ok() {}
    assert_eq!(map.view_ids().len(), MAX_VIEWS);
    assert_eq!(map.add_view(1.0), Err(ViewError::Full));
    // A view with no centre yet publishes nothing.
    map.tick([500, 500], None);
    assert_eq!(map.view_level(b, 0).unwrap().valid, crate::geom::Rect::EMPTY);
    assert_eq!(map.view_min_lod(b).unwrap(), map.level_count() as f64);
}

/// A view flying high (its LOD offset 3) holds and reads nothing of levels 0 to 2: alone, those
/// grids stay empty; beside a low view far away, they hold the low view's windows only.
#[test]
fn a_view_with_a_lod_offset_holds_and_reads_no_grid_finer_than_it_shows() {
    let c = [2000, 2000];
    // The primary alone at offset 3, then at offset 0: reads of the fine levels only in the second.
    let (disk, mut high) = over_disk(1 << 20, settings(None));
    high.set_view_lod(PRIMARY, LodWindow { offset: 3, effective: u32::MAX }).unwrap();
    for _ in 0..40 {
        disk_step(&disk, &mut high, c);
        check_view(&high, PRIMARY).unwrap();
    }
    assert_eq!(high.min_lod(), 3.0, "it shows level 3 and coarser, whole");
    for k in 0..3 {
        assert!(high.mem_regions()[k].is_empty(), "level {k} holds nothing: {:?}", high.mem_regions()[k]);
        assert!(high.level(k as u32).valid.is_empty());
    }
    assert_eq!(high.view_resident_levels(PRIMARY).unwrap(), (3..high.level_count() as u32).collect::<Vec<_>>());
    let (disk_low, mut low) = over_disk(1 << 20, settings(None));
    for _ in 0..40 {
        disk_step(&disk_low, &mut low, c);
    }
    assert_eq!(low.min_lod(), 0.0);
    let fine: u64 = (0..3).map(|k| low.mem_regions()[k].area()).sum();
    assert!(fine > 0);
    assert_eq!(
        disk_low.reads() - disk.reads(),
        fine,
        "the high view reads exactly the fine levels' tiles fewer ({} vs {})",
        disk.reads(),
        disk_low.reads()
    );

    // Coming down: offset 0 again, the fine levels are read and shown.
    high.set_view_lod(PRIMARY, LodWindow::ALL).unwrap();
    for _ in 0..20 {
        disk_step(&disk, &mut high, c);
        check_view(&high, PRIMARY).unwrap();
    }
    assert_eq!(high.min_lod(), 0.0);

    // A high further view far from a low primary: the fine grids hold the primary's windows
    // only, exactly as with no further view.
    let (disk2, mut two) = over_disk(1 << 20, Settings { view_spread: 4096, ..settings(None) });
    let v = two.add_view(1.0).unwrap();
    two.set_view_lod(v, LodWindow { offset: 3, effective: u32::MAX }).unwrap();
    for _ in 0..40 {
        two.move_view(v, [c[0] + 1200, c[1] - 900], None).unwrap();
        disk_step(&disk2, &mut two, c);
        check_view(&two, PRIMARY).unwrap();
        check_view(&two, v).unwrap();
    }
    assert_eq!(two.view_min_lod(v).unwrap(), 3.0);
    for k in 0..3u32 {
        assert!(two.view_level(v, k).unwrap().valid.is_empty(), "level {k}");
        let window = tiles_covering(two.level(k).valid, two.level(k).tile);
        let mem = two.mem_regions()[k as usize];
        // With the spread the grid could hold both; it holds a primary-sized region.
        assert_eq!(mem.intersect(&window), window, "level {k}: the primary's window is held");
        assert!(
            mem.width() <= window.width() + 2 && mem.height() <= window.height() + 2,
            "level {k}: {mem:?} for {window:?}"
        );
    }
    // Level 3 holds both windows (the spread allows it).
    assert_eq!(two.view_min_lod(v).unwrap(), 3.0);
    assert!(two.view_resident_levels(v).unwrap().contains(&3));
    assert_eq!(two.stats().slots_reassigned_under_views, 0);
}

/// The offset follows a view's height: finer at once a quarter level early, coarser half a level
/// late, never outside the levels, the same answer when asked again.
#[test]
fn the_lod_offset_follows_the_footprint_with_hysteresis() {
    let f = |current, lod: f64| offset_for_footprint(current, lod.exp2(), 12);
    assert_eq!(f(0, 3.3), 2, "from finer it moves coarser to floor(3.3 - 0.5) only");
    assert_eq!(f(3, 3.3), 3);
    assert_eq!(f(3, 3.2), 2, "a quarter level early, finer");
    assert_eq!(f(3, 4.4), 3, "coarser only half a level late");
    assert_eq!(f(3, 4.5), 4);
    assert_eq!(f(5, -2.0), 0, "a view below one texel a pixel shows level 0");
    assert_eq!(f(0, 40.0), 11, "never past the coarsest level");
    assert_eq!(offset_for_footprint(4, f64::NAN, 12), 4);
    assert_eq!(offset_for_footprint(4, 0.0, 12), 4);
    for current in 0..12 {
        for tenth in -20..130 {
            let lod = tenth as f64 / 10.0;
            let o = f(current, lod);
            let (lo, hi) = ((lod - 0.5).floor().clamp(0.0, 11.0) as u32, (lod - 0.25).floor().clamp(0.0, 11.0) as u32);
            assert_eq!(o, current.clamp(lo, hi), "{current} at {lod}");
            assert_eq!(f(o, lod), o, "stable: {current} at {lod}");
        }
    }
}

#[test]
fn bad_lod_windows_say_what_was_expected() {
    let src = hash_source([1 << 10, 1 << 10], 64, 16, 0, TexelFormat::L8);
    let mut map = Clipmap::new(src, settings(None)).unwrap();
    let levels = map.level_count() as u32;
    let e = map.set_view_lod(PRIMARY, LodWindow { offset: levels, effective: 1 }).unwrap_err();
    assert!(e.to_string().contains(&format!("expected 0 to {}", levels - 1)), "{e}");
    let e = map.set_view_lod(PRIMARY, LodWindow { offset: 0, effective: 0 }).unwrap_err();
    assert!(e.to_string().contains("at least 1"), "{e}");
    assert_eq!(map.set_view_lod(9, LodWindow::ALL), Err(ViewError::Unknown(9)));
    let e = map.set_view_footprint(PRIMARY, f64::NAN).unwrap_err();
    assert!(e.to_string().contains("positive finite"), "{e}");
    assert_eq!(map.set_view_footprint(PRIMARY, 8.0 * 1.5).unwrap(), 3);
    assert_eq!(map.view_lod(PRIMARY).unwrap(), LodWindow { offset: 3, effective: u32::MAX });
}
