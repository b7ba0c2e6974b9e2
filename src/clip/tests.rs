//! Tests of the update tick: published texels are never wrong, faults disable levels and heal,
//! load control follows the budget.

use super::*;
use crate::source::procedural::hash;
use crate::source::{Fault, FaultKind, FaultRule, FaultySource, HashSource, TileId};
use crate::texel::TexelFormat;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};

pub(crate) fn hash_source(size: [u64; 2], clip: u64, tile: u64, border: u64, format: TexelFormat) -> Arc<HashSource> {
    let desc = TextureDesc::new(size, clip, format, [tile, tile]).unwrap().with_invalid_border(border).unwrap();
    Arc::new(HashSource::new(desc))
}

pub(crate) fn settings(budget_ns: Option<u64>) -> Settings {
    Settings { budget_ns, fade_ticks: 2, retry_after_ticks: 2, ..Settings::default() }
}

/// Every texel of every published valid region against the hash texture; at most `stride`-th
/// texels of each row on very wide regions.
pub(crate) fn check_published(map: &Clipmap) -> Result<u64, String> {
    check_view(map, PRIMARY)
}

/// [`check_published`] of view `id`'s published regions.
pub(crate) fn check_view(map: &Clipmap, id: ViewId) -> Result<u64, String> {
    let bpt = map.desc().bytes_per_texel();
    let mut want = vec![0u8; bpt];
    let mut checked = 0;
    for k in 0..map.level_count() as u32 {
        let view = map.view_level(id, k).map_err(|e| e.to_string())?;
        let v = view.valid;
        let stride = (v.area() / 200_000).max(1) as i64;
        for t in v.t0..v.t1 {
            let mut s = v.s0 + (t % stride);
            while s < v.s1 {
                // A wrapping level's region may run past its width: texel s is texel s mod width.
                let real = if view.wrap { crate::geom::wrap(s, view.size[0]) } else { s as u64 };
                hash(k, real, t as u64, &mut want);
                let state = view.tile_state(s, t);
                if matches!(state, crate::cache::TileState::Failed { .. }) {
                    // A missing tile: published as such, served from a coarser level.
                    if view.texel(s, t).is_some() {
                        return Err(format!("view {id} level {k} texel ({s}, {t}): a missing tile's texel was served"));
                    }
                    s += stride;
                    continue;
                }
                let got = view.texel(s, t).ok_or_else(|| {
                    format!("view {id} level {k} texel ({s}, {t}): published but its tile is {state:?}")
                })?;
                if *got != *want.as_slice() {
                    return Err(format!("view {id} level {k} texel ({s}, {t}): got {got:?}, expected {want:?}"));
                }
                checked += 1;
                s += stride;
            }
        }
    }
    Ok(checked)
}

/// Ticks and checks the publication.
pub(crate) fn tick_and_check(map: &mut Clipmap, c: [i64; 2], errors: &mut Vec<String>) {
    map.tick(c, None);
    if let Err(e) = check_published(map) {
        errors.push(e);
    }
}

/// Ticks at `centre`, waiting for reads in between, until every level is published whole and
/// min LOD is 0; panics if that takes more than `max_ticks`.
pub(crate) fn settle(map: &mut Clipmap, centre: [i64; 2], max_ticks: usize) -> usize {
    for n in 0..max_ticks {
        let r = map.tick(centre, Some([0, 0]));
        if r.min_lod == 0.0
            && (0..map.level_count() as u32).all(|k| map.level(k).valid == map.levels[k as usize].frame.valid)
        {
            return n + 1;
        }
        map.wait_for_reads();
    }
    panic!("not settled after {max_ticks} ticks: min LOD {}", map.min_lod());
}

#[derive(Clone, Debug)]
enum Step {
    Move(i64, i64),
    Jump(i64, i64),
    Wait,
}

fn step() -> impl Strategy<Value = Step> {
    prop_oneof![
        4 => (-6i64..=6, -6i64..=6).prop_map(|(a, b)| Step::Move(a, b)),
        1 => (-(1i64 << 27)..(1i64 << 27), -(1i64 << 27)..(1i64 << 27)).prop_map(|(a, b)| Step::Jump(a, b)),
        1 => (-40i64..40, -40i64..40).prop_map(|(a, b)| Step::Jump(a, b)),
        3 => Just(Step::Wait),
    ]
}

fn edge() -> impl Strategy<Value = u64> {
    prop_oneof![1u64..=70, (0u32..=26).prop_map(|k| 1u64 << k), 1u64..=(1 << 26)]
}

/// Runs `steps` and checks every publication; then settles and checks again.
/// Level centres are aligned to multiples of `align` level texels.
fn walk(
    src: Arc<HashSource>,
    budget: Option<u64>,
    align: u64,
    start: [i64; 2],
    steps: &[Step],
) -> Result<(), TestCaseError> {
    let mut map = Clipmap::new(src, Settings { centre_alignment: align, ..settings(budget) }).unwrap();
    let mut errors = Vec::new();
    let mut c = start;
    for s in steps {
        match *s {
            Step::Move(a, b) => c = [c[0] + a, c[1] + b],
            Step::Jump(a, b) => c = [a, b],
            Step::Wait => map.wait_for_reads(),
        }
        tick_and_check(&mut map, c, &mut errors);
        prop_assert!(errors.is_empty(), "{:?}", errors);
        for k in 0..map.level_count() as u32 {
            prop_assert_eq!(map.level(k).centre, crate::geom::aligned_centre(c, k, align), "level {}", k);
        }
    }
    map.set_budget_ns(None);
    settle(&mut map, c, 60);
    prop_assert!(check_published(&map).map_err(TestCaseError::fail)? > 0);
    prop_assert_eq!(map.stats().tick_texel_bytes, 0);
    prop_assert_eq!(map.stats().slots_reassigned_under_published, 0);
    Ok(())
}

proptest! {
    #![proptest_config(Config { cases: 160, rng_seed: RngSeed::Fixed(0xC11F), failure_persistence: None, ..Config::default() })]

    #[test]
    fn published_texels_equal_the_source_after_any_walk(
        sw in edge(), sh in edge(), clip in 1u64..=16, tile in 1u64..=9, border in 0u64..4,
        budget in prop_oneof![Just(None), (200u64..20_000).prop_map(Some)],
        start in (-(1i64 << 27)..(1i64 << 27), -(1i64 << 27)..(1i64 << 27)),
        align in prop_oneof![2 => Just(1u64), 1 => 2u64..=9],
        steps in proptest::collection::vec(step(), 1..24),
    ) {
        let border = border.min((clip - 1) / 2);
        let src = hash_source([sw, sh], clip, tile, border, TexelFormat::RGB8);
        walk(src, budget, align, [start.0, start.1], &steps)?;
    }
}

proptest! {
    #![proptest_config(Config { cases: 8, rng_seed: RngSeed::Fixed(0xB16), failure_persistence: None, ..Config::default() })]

    /// Large clip sizes on long, thin textures keep the per-case work small.
    #[test]
    fn published_texels_equal_the_source_with_large_clip_sizes(
        clip in prop_oneof![Just(1024u64), Just(4096), Just(8192), 1000u64..8192],
        tall in 1u64..=12, tile in prop_oneof![Just(256u64), Just(1000)],
        steps in proptest::collection::vec(step(), 1..6),
    ) {
        let src = hash_source([1 << 26, tall], clip, tile, 16, TexelFormat::L8);
        walk(src, Some(2_000_000), 1, [(1 << 26) - 5, 0], &steps)?;
    }
}

#[test]
fn a_one_texel_texture_is_published_whole() {
    let mut map = Clipmap::new(hash_source([1, 1], 1, 1, 0, TexelFormat::RGBA8), settings(None)).unwrap();
    settle(&mut map, [-5, 7], 10);
    assert_eq!(map.level(0).valid, Rect::new(0, 0, 1, 1));
    assert_eq!(check_published(&map), Ok(1));
}

#[test]
fn aligned_centres_move_windows_in_whole_steps_and_lag_by_less_than_a_step() {
    // Clip 32, centres aligned to 8 level texels, a flight of one level-0 texel a tick along s.
    let (clip, align) = (32i64, 8i64);
    let src = hash_source([1024, 1024], clip as u64, 8, 0, TexelFormat::L8);
    let mut map = Clipmap::new(src, Settings { centre_alignment: align as u64, ..settings(None) }).unwrap();
    settle(&mut map, [96, 200], 20);
    for i in 1..=16 {
        let c = [96 + i, 200];
        settle(&mut map, c, 20);
        // Level 0's window stays put until the centre reaches the next multiple of 8, so the
        // valid region still holds every texel within clip/2 - (align - 1) of the true centre.
        let reach = clip / 2 - (align - 1);
        let near = Rect::new(c[0] - reach, c[1] - reach, c[0] + reach, c[1] + reach);
        assert!(map.level(0).valid.contains_rect(&near), "tick {i}: {:?} lacks {near:?}", map.level(0).valid);
        assert_eq!(map.level(0).centre, [c[0] / align * align, 200]);
    }
    assert_eq!(map.stats().tick_texel_bytes, 0);
    assert!(check_published(&map).unwrap() > 0);
}

#[test]
fn each_fault_kind_costs_its_tiles_a_coarser_level_never_a_wrong_texel_and_heals() {
    let faults = [
        (Fault::Missing, FaultKind::Missing),
        (Fault::Short, FaultKind::Short),
        (Fault::Corrupt, FaultKind::Corrupt),
        (Fault::PermissionDenied, FaultKind::PermissionDenied),
        (Fault::Io, FaultKind::Io),
    ];
    for (fault, kind) in faults {
        let inner = hash_source([4096, 4096], 32, 16, 4, TexelFormat::RGBA8);
        let src = Arc::new(FaultySource::new(inner));
        let mut map = Clipmap::new(src.clone(), settings(None)).unwrap();
        settle(&mut map, [1000, 1000], 30);
        src.add(FaultRule::level(0, fault));
        src.add(FaultRule::level(1, fault));
        let mut errors = Vec::new();
        // Jump to a place whose level-0 and level-1 tiles all fail: they are published missing
        // (per-tile availability), so every sample there comes from level 2 or coarser.
        for _ in 0..8 {
            map.tick([3000, 500], None);
            if let Err(e) = check_published(&map) {
                errors.push(e);
            }
            map.wait_for_reads();
        }
        for k in 0..2 {
            let v = map.level(k);
            assert!(!v.valid.is_empty(), "{fault:?}: level {k} is published, its tiles missing");
            for (s, t) in [(v.valid.s0, v.valid.t0), (v.valid.s1 - 1, v.valid.t1 - 1)] {
                assert!(matches!(v.tile_state(s, t), crate::cache::TileState::Failed { .. }), "{fault:?}");
                assert!(v.texel(s, t).is_none(), "{fault:?}: a missing tile's texel is never served");
            }
        }
        let sample = crate::sample::sample_clipmap(&map, crate::sample::Filter::Bilinear, 3000.5, 500.5, 0.0).unwrap();
        assert!(sample.lod >= 2.0, "{fault:?}: served from level {}", sample.lod);
        assert!(errors.is_empty(), "{fault:?}: {errors:?}");
        let faults_seen = map.stats().read_faults.clone();
        assert!(faults_seen.total() > 0 && faults_seen == count_of(kind, faults_seen.total()), "{faults_seen:?}");
        // The fault clears: bounded recovery (failed tiles are read again after the retry delay).
        src.set_enabled(false);
        let mut healed_after = None;
        for n in 1..=12 {
            let r = map.tick([3000, 500], None);
            if let Err(e) = check_published(&map) {
                errors.push(e);
            }
            map.wait_for_reads();
            let v = map.level(0);
            if r.min_lod == 0.0
                && v.texel(v.valid.s0, v.valid.t0).is_some()
                && v.texel(v.valid.s1 - 1, v.valid.t1 - 1).is_some()
            {
                healed_after = Some(n);
                break;
            }
        }
        assert!(healed_after.is_some(), "{fault:?}: not healed, min LOD {}", map.min_lod());
        assert!(errors.is_empty(), "{fault:?}: {errors:?}");
        assert_eq!(map.stats().tick_texel_bytes, 0);
    }
}

fn count_of(kind: FaultKind, n: u64) -> FaultCounts {
    let mut c = FaultCounts::default();
    for _ in 0..n {
        c.add(kind);
    }
    c
}

#[test]
fn a_slow_source_raises_min_lod_while_coarse_levels_stay_complete() {
    let inner = hash_source([1 << 14, 1 << 14], 64, 32, 4, TexelFormat::L8);
    let src = Arc::new(FaultySource::new(inner));
    let mut map = Clipmap::new(src.clone(), settings(None)).unwrap();
    settle(&mut map, [8000, 8000], 30);
    let coarse_from = map.desc().stack_levels() as u32;
    // Level-0 tiles now take long; the tick never waits for them.
    src.add(FaultRule::level(0, Fault::Slow(std::time::Duration::from_millis(300))));
    let r = map.tick([8600, 8000], None);
    assert!(r.min_lod >= 1.0 && r.disabled_levels.contains(&0), "{r:?}");
    for k in coarse_from..map.level_count() as u32 {
        assert_eq!(map.level(k).valid, map.levels[k as usize].frame.valid, "pyramid level {k} complete");
    }
    // Once the reads land, every level is up to date and min LOD fades down (fade_ticks 2).
    map.wait_for_reads();
    let mut expected = r.min_lod;
    for _ in 0..12 {
        expected = next_min_lod(expected, 0, 2);
        assert_eq!(map.tick([8600, 8000], None).min_lod, expected);
    }
    assert_eq!(expected, 0.0, "faded in within 12 ticks");
    assert_eq!(check_published(&map).map(|n| n > 0), Ok(true));
}

#[test]
fn widening_the_invalid_border_shrinks_the_valid_region() {
    let mut map = Clipmap::new(hash_source([1 << 12, 1 << 12], 64, 16, 4, TexelFormat::L8), settings(None)).unwrap();
    settle(&mut map, [2000, 2000], 30);
    assert_eq!(map.level(0).valid.width(), 56);
    map.set_invalid_border(12);
    map.tick([2000, 2000], None);
    assert_eq!(map.level(0).valid.width(), crate::geom::effective_size(64, 12));
    map.set_invalid_border(1000);
    assert_eq!(map.invalid_border(), 31);
}

#[test]
fn centre_speed_is_clamped_and_counted() {
    let mut s = settings(None);
    s.max_centre_step = Some(10);
    let mut map = Clipmap::new(hash_source([1 << 12, 1 << 12], 32, 16, 0, TexelFormat::L8), s).unwrap();
    map.tick([100, 100], None);
    let r = map.tick([500, 95], None);
    assert_eq!(r.centre, [110, 95]);
    assert_eq!(map.stats().centre_clamps, 1);
}

#[test]
fn the_clamp_is_reported_on_the_tick_it_acts() {
    let mut s = settings(None);
    s.max_centre_step = Some(10);
    let mut map = Clipmap::new(hash_source([1 << 12, 1 << 12], 32, 16, 0, TexelFormat::L8), s).unwrap();
    assert!(!map.tick([100, 100], None).clamped, "the first centre is taken as given");
    assert!(!map.tick([108, 92], None).clamped);
    assert!(map.tick([130, 92], None).clamped);
    assert_eq!(map.stats().centre_clamps, 1);
}

/// docs/SHM.md, "What the service does with a request": a tick given no velocity (the service
/// passes none when a request's both components are 0 per tick) looks ahead along the centre's
/// change since the last tick; a velocity given is used as given.
#[test]
fn without_a_velocity_the_look_ahead_follows_the_centres_change_since_the_last_tick() {
    let mut map = Clipmap::new(hash_source([1 << 12, 1 << 12], 32, 16, 0, TexelFormat::L8), settings(None)).unwrap();
    assert_eq!(map.tick([1000, 1000], None).velocity, [0, 0], "the first tick has no last centre");
    assert_eq!(map.tick([1030, 990], None).velocity, [30, -10]);
    assert_eq!(map.tick([1030, 990], Some([7, -3])).velocity, [7, -3], "a velocity given is used as given");
    assert_eq!(map.tick([1030, 990], None).velocity, [0, 0], "standing still");
    assert_eq!(map.tick([1020, 995], None).velocity, [-10, 5]);
}

/// A clipmap over the hash texture read through a disk of `per_tick` tiles a tick, in lock step.
pub(crate) fn over_disk(per_tick: u64, s: Settings) -> (Arc<crate::source::ThrottledSource>, Clipmap) {
    let inner = hash_source([1 << 12, 1 << 12], 64, 16, 0, TexelFormat::L8);
    let disk = Arc::new(crate::source::ThrottledSource::new(inner, per_tick));
    let mut s = s;
    s.limits.max_in_flight_reads = 1;
    s.limits.max_ready_reads = 4096;
    let map = Clipmap::new(disk.clone(), s).unwrap();
    (disk, map)
}

pub(crate) fn disk_step(disk: &crate::source::ThrottledSource, map: &mut Clipmap, c: [i64; 2]) -> TickReport {
    disk.next_tick();
    let r = map.tick(c, None);
    map.wait_for_reads();
    r
}

#[test]
fn a_slow_disk_puts_reads_off_and_the_levels_come_in_as_they_arrive() {
    let (disk, mut map) = over_disk(5, settings(None));
    let mut ticks = 0;
    let mut errors = Vec::new();
    while map.min_lod() > 0.0 && ticks < 500 {
        let r = disk_step(&disk, &mut map, [2000, 2000]);
        assert!(r.tiles_read <= 5, "at most 5 tiles a tick: {}", r.tiles_read);
        if let Err(e) = check_published(&map) {
            errors.push(e);
        }
        ticks += 1;
    }
    assert!(errors.is_empty(), "{errors:?}");
    assert_eq!(map.min_lod(), 0.0);
    // The spare tiles too, then one more tick to take the last reads.
    while disk_step(&disk, &mut map, [2000, 2000]).tiles_read > 0 {}
    map.tick([2000, 2000], None);
    let st = map.stats();
    assert!(st.reads_put_off > 0 && ticks > 10, "{ticks} ticks, {} put off", st.reads_put_off);
    assert_eq!(st.read_faults.total(), 0, "a busy disk is no fault");
    assert_eq!(disk.reads(), st.tiles_read, "each tile read once");
}

#[test]
fn a_pool_serves_a_return_flight_from_memory_and_the_tick_writes_no_texel() {
    let pooled = Settings { pool_bytes: 600 * 256, ..settings(None) };
    let mut reads = Vec::new();
    for s in [settings(None), pooled] {
        let (disk, mut map) = over_disk(64, s);
        let mut errors = Vec::new();
        // Out along +s for 40 tiles and back.
        for i in (0..80).chain((0..80).rev()) {
            disk_step(&disk, &mut map, [1000 + 8 * i, 2000]);
            if let Err(e) = check_published(&map) {
                errors.push(e);
            }
        }
        assert!(errors.is_empty(), "{errors:?}");
        let st = map.stats();
        assert_eq!(st.tick_texel_bytes, 0);
        assert_eq!(st.slots_reassigned_under_published, 0);
        assert!(st.pool.bytes <= st.pool.budget_bytes);
        reads.push((disk.reads(), st.pool.hits));
    }
    let ((bare, no_hits), (pooled, hits)) = (reads[0], reads[1]);
    assert_eq!(no_hits, 0);
    assert!(hits > 0 && pooled < bare, "disk reads {bare} without a pool, {pooled} with ({hits} hits)");
}

#[test]
fn every_prefetch_policy_keeps_the_published_texels_right_on_a_zigzag() {
    for prefetch in crate::paging::PrefetchKind::ALL {
        let (disk, mut map) = over_disk(6, Settings { prefetch, ..settings(None) });
        let mut errors = Vec::new();
        for i in 0..120i64 {
            let t = if (i / 15) % 2 == 0 { i % 15 } else { 15 - i % 15 };
            disk_step(&disk, &mut map, [1000 + 9 * i, 2000 + 11 * t]);
            if let Err(e) = check_published(&map) {
                errors.push(format!("{prefetch}: {e}"));
            }
        }
        assert!(errors.is_empty(), "{errors:?}");
        assert_eq!(map.stats().slots_reassigned_under_published, 0, "{prefetch}");
        for k in 0..map.level_count() as u32 {
            let mem = map.cache.mem_region(k);
            let need = crate::geom::tiles_covering(map.levels[k as usize].frame.tex, map.level(k).tile);
            assert!(mem.contains_rect(&need), "{prefetch}: level {k}: {mem:?} does not hold {need:?}");
        }
    }
}

#[test]
fn queue_length_stays_bounded_and_stale_requests_are_dropped_under_jumps() {
    let mut s = settings(None);
    s.limits.max_pending_reads = 8;
    s.limits.max_in_flight_reads = 1;
    s.streams = 2;
    let inner = hash_source([1 << 20, 1 << 20], 64, 8, 0, TexelFormat::L8);
    let src = Arc::new(FaultySource::new(inner));
    src.add(FaultRule::everywhere(Fault::Slow(std::time::Duration::from_millis(2))));
    let mut map = Clipmap::new(src, s).unwrap();
    for i in 0..30i64 {
        map.tick([(i * 7919 * 97) % (1 << 20), (i * 104_729) % (1 << 20)], None);
    }
    map.wait_for_reads();
    map.tick([0, 0], None);
    let q = &map.stats().queue;
    assert!(q.peak_pending <= 8, "{q:?}");
    assert!(q.stale_dropped > 0 && q.overflow_dropped > 0, "{q:?}");
    assert!(map.stats().late_tiles + q.stale_dropped > 0);
    let _ = TileId::new(0, 0, 0);
}

#[test]
fn a_spent_budget_defers_finished_reads_without_reading_their_tiles_again() {
    // A budget of zero takes 16 finished reads a tick; the rest wait in the backlog, already in
    // their slots. They must not be asked for again meanwhile.
    let inner = hash_source([4096, 4096], 256, 16, 0, TexelFormat::L8);
    let src = Arc::new(FaultySource::new(inner));
    let mut map = Clipmap::new(src.clone(), settings(Some(0))).unwrap();
    let mut over = 0;
    for _ in 0..200 {
        let r = map.tick([2000, 2000], Some([0, 0]));
        over += u64::from(r.over_budget);
        if r.min_lod == 0.0 && !r.over_budget {
            break;
        }
        map.wait_for_reads();
    }
    assert!(over > 0, "the budget deferred some reads");
    assert_eq!(map.min_lod(), 0.0, "every level complete in the end");
    let distinct = map.stats().tiles_read;
    assert_eq!(src.reads(), distinct, "every tile read once: {} reads for {distinct} tiles", src.reads());
    assert!(check_published(&map).unwrap() > 0);
}

/// A hash texture whose texels of level 0 are offset by a version that the test bumps (a texture
/// whose tiles change at the source, as a growing one's do).
struct Versioned {
    inner: HashSource,
    version: std::sync::atomic::AtomicU8,
}

impl TileSource for Versioned {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.inner.read_tile(tile, out)?;
        let v = self.version.load(std::sync::atomic::Ordering::Relaxed);
        if tile.level == 0 {
            out.iter_mut().for_each(|b| *b = b.wrapping_add(v));
        }
        Ok(())
    }
}

#[test]
fn refreshed_tiles_are_replaced_in_their_slots_while_their_level_stays_published() {
    let desc = TextureDesc::new([1024, 1024], 64, TexelFormat::RGBA8, [16, 16]).unwrap();
    let src = Arc::new(Versioned { inner: HashSource::new(desc), version: Default::default() });
    let mut map = Clipmap::new(src.clone(), settings(None)).unwrap();
    for _ in 0..4 {
        map.tick([500, 500], None);
        map.wait_for_reads();
    }
    map.tick([500, 500], None);
    let valid = map.level(0).valid;
    assert!(!valid.is_empty() && map.min_lod() == 0.0);
    let at = |map: &Clipmap| map.level(0).texel(valid.s0, valid.t0).map(|t| t.to_vec());
    let before = at(&map).unwrap();
    src.version.store(7, std::sync::atomic::Ordering::Relaxed);
    let tile = map.level(0).tile_of(valid.s0, valid.t0);
    // An absent tile asks for nothing; a held one is opened by the next tick (readers fall back
    // for it) and asked of the read queues, and replaced by the tick that takes its read, the
    // level staying published throughout.
    map.refresh([tile, TileId::new(0, 60, 60)]);
    assert_eq!(map.refresh_pending(), 2);
    let report = map.tick([500, 500], None);
    assert_eq!((report.tiles_replaced, map.refresh_pending()), (0, 1));
    assert_eq!(report.valid[0], valid, "level 0 stayed published");
    assert_eq!(map.level(0).tile_state(valid.s0, valid.t0), crate::cache::TileState::Replacing);
    assert_eq!(at(&map), None, "the tile being replaced is not read");
    map.wait_for_reads();
    let report = map.tick([500, 500], None);
    assert_eq!((report.tiles_replaced, map.refresh_pending()), (1, 0));
    assert_eq!(report.valid[0], valid, "level 0 stayed published");
    let after = at(&map).unwrap();
    assert_eq!(after, before.iter().map(|b| b.wrapping_add(7)).collect::<Vec<_>>());
    // Its neighbour was not asked for, and keeps the old texels.
    let other = map.level(0).tile_of(valid.s0 + 16, valid.t0);
    assert_ne!(other, tile);
    let mut want = [0u8; 4];
    hash(0, (valid.s0 + 16) as u64, valid.t0 as u64, &mut want);
    assert_eq!(map.level(0).texel(valid.s0 + 16, valid.t0).unwrap().to_vec(), want.to_vec());
    assert_eq!(map.stats().tiles_replaced, 1);
    assert_eq!(map.stats().slots_reassigned_under_published, 0);
}

/// With a second-level tile pool in front of the source, a refreshed tile's replacement read
/// reaches the source (the pool's copy is dropped), so the slot gets the new texels.
#[test]
fn a_refreshed_tile_is_read_from_the_source_not_from_the_pool() {
    let desc = TextureDesc::new([1024, 1024], 64, TexelFormat::RGBA8, [16, 16]).unwrap();
    let src = Arc::new(Versioned { inner: HashSource::new(desc), version: Default::default() });
    let mut map = Clipmap::new(src.clone(), Settings { pool_bytes: 4 << 20, ..settings(None) }).unwrap();
    settle(&mut map, [500, 500], 50);
    let valid = map.level(0).valid;
    let tile = map.level(0).tile_of(valid.s0, valid.t0);
    assert!(map.pool().unwrap().contains(tile), "the pool holds the tile's first read");
    let before = map.level(0).texel(valid.s0, valid.t0).unwrap().to_vec();
    src.version.store(3, std::sync::atomic::Ordering::Relaxed);
    map.refresh([tile]);
    map.tick([500, 500], None);
    map.wait_for_reads();
    assert_eq!(map.tick([500, 500], None).tiles_replaced, 1);
    let after = map.level(0).texel(valid.s0, valid.t0).unwrap().to_vec();
    assert_eq!(after, before.iter().map(|b| b.wrapping_add(3)).collect::<Vec<_>>());
}

/// A [`Versioned`] texture whose reads record the thread they run on and, while the gate is
/// closed, wait for it to open, except on the thread that ticks (so that a read there, which the
/// tick must never do, is recorded rather than hung).
struct Gated {
    inner: Versioned,
    tick_thread: std::thread::ThreadId,
    /// Whether reads may proceed, and its condition.
    open: std::sync::Mutex<bool>,
    opened: std::sync::Condvar,
    /// Each read's tile and thread, in order.
    reads: std::sync::Mutex<Vec<(TileId, std::thread::ThreadId)>>,
}

impl Gated {
    fn new(desc: TextureDesc) -> Self {
        Gated {
            inner: Versioned { inner: HashSource::new(desc), version: Default::default() },
            tick_thread: std::thread::current().id(),
            open: std::sync::Mutex::new(true),
            opened: std::sync::Condvar::new(),
            reads: Default::default(),
        }
    }

    fn set_open(&self, open: bool) {
        *self.open.lock().unwrap() = open;
        self.opened.notify_all();
    }

    /// The tiles read on the thread that ticks.
    fn read_on_tick_thread(&self) -> Vec<TileId> {
        self.reads.lock().unwrap().iter().filter(|(_, th)| *th == self.tick_thread).map(|(t, _)| *t).collect()
    }

    fn reads_of(&self, tile: TileId) -> usize {
        self.reads.lock().unwrap().iter().filter(|(t, _)| *t == tile).count()
    }
}

impl TileSource for Gated {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        let me = std::thread::current().id();
        self.reads.lock().unwrap().push((tile, me));
        if me != self.tick_thread {
            let mut open = self.open.lock().unwrap();
            while !*open {
                open = self.opened.wait(open).unwrap();
            }
        }
        self.inner.read_tile(tile, out)
    }
}

/// Every texel of level-0 `tile` as the map serves it, `None` where it serves none.
fn tile_texels_served(map: &Clipmap, tile: TileId) -> Vec<Option<Vec<u8>>> {
    let v = map.level(0);
    let (tw, th) = (v.tile[0] as i64, v.tile[1] as i64);
    let (s0, t0) = (tile.s as i64 * tw, tile.t as i64 * th);
    (t0..t0 + th)
        .flat_map(|t| (s0..s0 + tw).map(move |s| (s, t)))
        .map(|(s, t)| v.texel(s, t).map(|x| x.to_vec()))
        .collect()
}

/// A refreshed tile is read again by a read queue's thread, never by the thread that ticks: while
/// that read is held up, ticks go on, the level stays published and only that tile falls back;
/// once it is taken, every texel of the tile is the source's new one, and the read is counted
/// in the queues' counters like any other.
#[test]
fn a_refreshed_tile_is_read_on_a_queue_thread_not_the_tick_and_gets_the_new_texels() {
    let desc = TextureDesc::new([1024, 1024], 64, TexelFormat::RGBA8, [16, 16]).unwrap();
    let src = Arc::new(Gated::new(desc));
    let mut map = Clipmap::new(src.clone(), settings(None)).unwrap();
    settle(&mut map, [500, 500], 50);
    let valid = map.level(0).valid;
    let tile = map.level(0).tile_of(valid.s0 + 20, valid.t0 + 20);
    let neighbour = map.level(0).tile_of(valid.s0 + 36, valid.t0 + 20);
    assert_ne!(tile, neighbour);
    let old = tile_texels_served(&map, neighbour);
    assert!(old.iter().all(Option::is_some));
    assert!(src.read_on_tick_thread().is_empty());
    let (reads_before, bytes_before) = (map.stats().queue.reads_done, map.stats().queue.bytes_read);

    let read_before = src.reads_of(tile);
    src.inner.version.store(9, std::sync::atomic::Ordering::Relaxed);
    src.set_open(false);
    map.refresh([tile]);
    for _ in 0..5 {
        let r = map.tick([500, 500], None);
        assert_eq!(r.tiles_replaced, 0);
        assert_eq!(r.valid[0], valid, "level 0 stays published while its tile is replaced");
        assert!(src.read_on_tick_thread().is_empty(), "the tick read {:?} itself", src.read_on_tick_thread());
        assert_eq!(map.refresh_pending(), 1);
        assert!(tile_texels_served(&map, tile).iter().all(Option::is_none), "the tile falls back meanwhile");
        assert_eq!(tile_texels_served(&map, neighbour), old, "its neighbour is served as before");
        std::thread::sleep(Duration::from_millis(2));
    }
    let waited = std::time::Instant::now();
    while src.reads_of(tile) == read_before && waited.elapsed() < Duration::from_secs(20) {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(src.reads_of(tile) - read_before, 1, "one read of it, under way on a queue's thread");

    src.set_open(true);
    map.wait_for_reads();
    let r = map.tick([500, 500], None);
    assert_eq!((r.tiles_replaced, map.refresh_pending()), (1, 0));
    assert_eq!(r.valid[0], valid);
    let mut want = [0u8; 4];
    let (tw, th) = (16, 16);
    let got = tile_texels_served(&map, tile);
    for (i, texel) in got.iter().enumerate() {
        let (s, t) = (tile.s * tw + i as u64 % tw, tile.t * th + i as u64 / tw);
        hash(0, s, t, &mut want);
        let new: Vec<u8> = want.iter().map(|b| b.wrapping_add(9)).collect();
        assert_eq!(texel.as_deref(), Some(new.as_slice()), "texel ({s}, {t})");
    }
    assert_eq!(tile_texels_served(&map, neighbour), old, "a tile not refreshed keeps its texels");
    assert!(src.read_on_tick_thread().is_empty());
    let st = map.stats();
    assert_eq!(st.tiles_replaced, 1);
    assert_eq!(st.tick_texel_bytes, 0, "the tick wrote no texel");
    assert_eq!(st.queue.reads_done - reads_before, 1, "the replacement is a queue read");
    assert_eq!(st.queue.bytes_read - bytes_before, 16 * 16 * 4);
    assert_eq!(st.slots_reassigned_under_published, 0);
}

/// A replacement whose read fails leaves the tile missing (published, served from a coarser
/// level) and reads it again after the retry delay; one whose tile leaves its mem region while it
/// is read is dropped, and its late read changes nothing.
#[test]
fn a_failed_replacement_is_retried_and_one_that_leaves_its_mem_region_is_dropped() {
    let desc = TextureDesc::new([1024, 1024], 64, TexelFormat::RGBA8, [16, 16]).unwrap();
    let faulty = Arc::new(FaultySource::new(Arc::new(HashSource::new(desc))));
    let mut map = Clipmap::new(faulty.clone(), settings(None)).unwrap();
    settle(&mut map, [500, 500], 50);
    let valid = map.level(0).valid;
    let tile = map.level(0).tile_of(valid.s0 + 20, valid.t0 + 20);
    faulty.add(FaultRule::tile(tile, Fault::Missing));
    map.refresh([tile]);
    map.tick([500, 500], None);
    map.wait_for_reads();
    let r = map.tick([500, 500], None);
    assert_eq!((r.tiles_replaced, map.refresh_pending()), (0, 0));
    assert_eq!(r.valid[0], valid, "a failed tile is settled: the level stays published");
    assert!(matches!(map.level(0).tile_state(valid.s0 + 20, valid.t0 + 20), crate::cache::TileState::Failed { .. }));
    assert_eq!(map.stats().read_faults.missing, 1);
    check_published(&map).unwrap();
    // Read again after the retry delay (2 ticks), and settled ready.
    faulty.clear();
    for _ in 0..4 {
        map.tick([500, 500], None);
        map.wait_for_reads();
    }
    map.tick([500, 500], None);
    assert_eq!(map.level(0).tile_state(valid.s0 + 20, valid.t0 + 20), crate::cache::TileState::Resident);
    assert_eq!(check_published(&map).map(|n| n > 0), Ok(true));

    // Held up at the source, then the view jumps away: the replacement is dropped.
    let gated = Arc::new(Gated::new(map.desc().clone()));
    let mut map = Clipmap::new(gated.clone(), settings(None)).unwrap();
    settle(&mut map, [500, 500], 50);
    let tile = map.level(0).tile_of(500, 500);
    gated.set_open(false);
    map.refresh([tile]);
    map.tick([500, 500], None);
    assert_eq!(map.refresh_pending(), 1);
    map.tick([900, 900], None);
    assert!(!map.holds(tile));
    map.tick([900, 900], None);
    assert_eq!(map.refresh_pending(), 0, "a replacement that left its mem region is no longer pending");
    gated.set_open(true);
    settle(&mut map, [900, 900], 50);
    assert_eq!(map.stats().tiles_replaced, 0);
    assert_eq!(map.stats().slots_reassigned_under_published, 0);
    check_published(&map).unwrap();
}

/// Flies the adaptive policy along +s at `speed` level-0 texels a tick over a disk reading
/// `per_tick` tiles a tick, from a settled start; returns the clipmap and the level-0 paging of
/// the last tick.
fn adaptive_flight(per_tick: u64, speed: i64, ticks: i64) -> (Clipmap, crate::paging::adaptive::LevelPaging) {
    let s = Settings { prefetch: PrefetchKind::Adaptive, ..settings(None) };
    let (disk, mut map) = over_disk(per_tick, s);
    for _ in 0..400 {
        if disk_step(&disk, &mut map, [1000, 2000]).min_lod == 0.0 {
            break;
        }
    }
    let mut errors = Vec::new();
    for i in 1..=ticks {
        disk_step(&disk, &mut map, [1000 + speed * i, 2000]);
        if let Err(e) = check_published(&map) {
            errors.push(e);
        }
    }
    assert!(errors.is_empty(), "{errors:?}");
    assert_eq!(map.stats().slots_reassigned_under_published, 0);
    let p = map.stats().paging[0];
    (map, p)
}

#[test]
fn adaptive_paging_hovers_as_the_ring_and_reads_ahead_when_moving() {
    use crate::paging::adaptive::Reason;
    let (map, hover) = adaptive_flight(1000, 0, 10);
    assert_eq!(hover.reason, Reason::Hover);
    assert_eq!(hover.lead_tiles, [0, 0]);
    // At hover the mem region is the lookahead-1 ring, whatever the larger grid.
    let ring = Settings { prefetch: PrefetchKind::Ring, ..settings(None) };
    let fixed = Clipmap::grids(map.desc(), &ring);
    assert_eq!(map.cache.mem_region(0).width(), fixed[0][0]);
    assert!(map.level(0).grid[0] > fixed[0][0], "the budget gives level 0 a larger grid");
    let (map, moving) = adaptive_flight(1000, 24, 40);
    assert_eq!(moving.reason, Reason::KeepingUp, "{moving:?}");
    assert!(moving.lead_texels[0] >= 24 && moving.lead_tiles[0] >= 1, "{moving:?}");
    assert_eq!((moving.lead_texels[1], moving.lead_tiles[1]), (0, 0), "{moving:?}");
    assert_eq!(map.min_lod(), 0.0);
}

#[test]
fn adaptive_paging_says_source_bound_when_the_disk_cannot_keep_up() {
    use crate::paging::adaptive::Reason;
    let (map, p) = adaptive_flight(2, 40, 60);
    assert!(map.min_lod() > 0.0, "two tiles a tick cannot keep level 0 at 40 texels a tick");
    // The disk delivers two of the many tiles a tick the flight asks for: whatever the lead and
    // the grid, the rate is short.
    assert_eq!(p.reason, Reason::SourceBound, "{p:?}");
    assert!(map.stats().read_latency_ticks > 1.0, "put-off reads are late: {}", map.stats().read_latency_ticks);
}

#[test]
fn adaptive_lead_grows_with_latency() {
    // The same flight over a slower disk: reads wait longer, so the lead is longer.
    let (fast, a) = adaptive_flight(1000, 16, 40);
    let (slow, b) = adaptive_flight(12, 16, 40);
    assert!(slow.stats().read_latency_ticks > fast.stats().read_latency_ticks);
    assert!(b.lead_texels[0] > a.lead_texels[0], "{a:?} {b:?}");
}

#[test]
fn adaptive_paging_recentres_after_a_jump() {
    use crate::paging::adaptive::Reason;
    let s = Settings { prefetch: PrefetchKind::Adaptive, ..settings(None) };
    let (disk, mut map) = over_disk(1000, s);
    for i in 0..30 {
        disk_step(&disk, &mut map, [1000 + 20 * i, 2000]);
    }
    assert!(map.stats().paging[0].lead_texels[0] > 0);
    disk_step(&disk, &mut map, [3000, 1000]);
    assert_eq!(map.stats().paging[0].lead_texels, [0, 0]);
    assert_eq!(map.stats().paging[0].lead_tiles, [0, 0]);
    assert_eq!(map.stats().paging[0].reason, Reason::Hover);
    check_published(&map).unwrap();
}

/// The hash texture behind two simulated disks, one per stream server: level `k`'s tiles are read
/// by stream `k mod 2`, through disk `k mod 2` (`per_tick[k mod 2]` tiles a tick).
struct TwoDisks {
    disks: [crate::source::ThrottledSource; 2],
}

impl TwoDisks {
    fn new(per_tick: [u64; 2]) -> Self {
        let inner: Arc<dyn TileSource> = hash_source([1 << 12, 1 << 12], 64, 16, 0, TexelFormat::L8);
        TwoDisks { disks: per_tick.map(|n| crate::source::ThrottledSource::new(inner.clone(), n)) }
    }

    fn next_tick(&self) {
        self.disks.iter().for_each(|d| d.next_tick());
    }
}

impl TileSource for TwoDisks {
    fn desc(&self) -> &TextureDesc {
        self.disks[0].desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.read_into(tile, out).map(|_| ())
    }

    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<crate::source::Delivered, SourceError> {
        self.disks[tile.level as usize % 2].read_into(tile, out)
    }

    fn stream_servers(&self) -> usize {
        2
    }

    fn stream_of(&self, tile: TileId, streams: usize) -> usize {
        tile.level as usize % 2 % streams.max(1)
    }
}

/// Flies the adaptive policy along +s at 16 level-0 texels a tick over [`TwoDisks`] of
/// `per_tick` tiles a tick, from a settled start; returns the clipmap.
fn two_stream_flight(per_tick: [u64; 2]) -> Clipmap {
    let src = Arc::new(TwoDisks::new(per_tick));
    let mut s = Settings { prefetch: PrefetchKind::Adaptive, streams: 2, ..settings(None) };
    s.limits.max_in_flight_reads = 1;
    s.limits.max_ready_reads = 4096;
    let mut map = Clipmap::new(src.clone(), s).unwrap();
    let step = |map: &mut Clipmap, c: [i64; 2]| {
        src.next_tick();
        let r = map.tick(c, None);
        map.wait_for_reads();
        r
    };
    for _ in 0..400 {
        if step(&mut map, [1000, 2000]).min_lod == 0.0 {
            break;
        }
    }
    let mut errors = Vec::new();
    for i in 1..=40 {
        step(&mut map, [1000 + 16 * i, 2000]);
        if let Err(e) = check_published(&map) {
            errors.push(e);
        }
    }
    assert!(errors.is_empty(), "{errors:?}");
    assert_eq!(map.stats().slots_reassigned_under_published, 0);
    map
}

#[test]
fn each_level_leads_by_its_own_streams_latency() {
    let both_fast = two_stream_flight([1000, 1000]);
    let p = |map: &Clipmap, k: usize| map.stats().paging[k];
    let (fast0, fast1) = (p(&both_fast, 0), p(&both_fast, 1));
    assert_eq!(both_fast.stats().stream_read_latency_ticks.len(), 2);
    // Stream 0 (levels 0, 2, ...) slow: level 0 leads further, level 1 as with two fast disks.
    let slow0 = two_stream_flight([6, 1000]);
    let lat = &slow0.stats().stream_read_latency_ticks;
    assert!(lat[0] > lat[1], "{lat:?}");
    assert_eq!(slow0.stats().read_latency_ticks, lat[0], "the slowest stream's");
    assert_eq!((p(&slow0, 0).read_latency_ticks, p(&slow0, 1).read_latency_ticks), (lat[0], lat[1]));
    assert!(p(&slow0, 0).lead_texels[0] > fast0.lead_texels[0], "{:?} {fast0:?}", p(&slow0, 0));
    assert_eq!(p(&slow0, 1).lead_texels, fast1.lead_texels, "level 1 not inflated");
    // Stream 1 (levels 1, 3, ...) slow: the other way round.
    let slow1 = two_stream_flight([1000, 6]);
    let lat = &slow1.stats().stream_read_latency_ticks;
    assert!(lat[1] > lat[0], "{lat:?}");
    assert!(p(&slow1, 1).lead_texels[0] > fast1.lead_texels[0], "{:?} {fast1:?}", p(&slow1, 1));
    assert_eq!(p(&slow1, 0).lead_texels, fast0.lead_texels, "level 0 not inflated");
}

/// The hash texture whose every tile is ready only `delay` ticks after it was first asked for:
/// a source of unbounded rate and a fixed latency (the reads before are put off, as a busy disk's).
struct Latent {
    inner: HashSource,
    delay: u64,
    tick: std::sync::atomic::AtomicU64,
    first: std::sync::Mutex<std::collections::HashMap<TileId, u64>>,
}

impl TileSource for Latent {
    fn desc(&self) -> &TextureDesc {
        self.inner.desc()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        let now = self.tick.load(std::sync::atomic::Ordering::SeqCst);
        let first = *self.first.lock().unwrap().entry(tile).or_insert(now);
        if now < first + self.delay {
            return Err(SourceError::Busy { tile, per_tick: 0 });
        }
        self.inner.read_tile(tile, out)
    }
}

/// Flies the adaptive policy along +s at `speed` level-0 texels a tick over a [`Latent`] source
/// of `delay` ticks, with grids of `grid_budget` bytes; returns the level-0 paging of the last
/// tick.
fn latent_flight(delay: u64, speed: i64, grid_budget: Option<u64>) -> crate::paging::adaptive::LevelPaging {
    let desc = TextureDesc::new([1 << 12, 1 << 12], 64, TexelFormat::L8, [16, 16]).unwrap();
    let src =
        Arc::new(Latent { inner: HashSource::new(desc), delay, tick: Default::default(), first: Default::default() });
    let s = Settings { prefetch: PrefetchKind::Adaptive, grid_budget, ..settings(None) };
    let mut map = Clipmap::new(src.clone(), s).unwrap();
    let step = |map: &mut Clipmap, c: [i64; 2]| {
        src.tick.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let r = map.tick(c, None);
        map.wait_for_reads();
        r
    };
    for _ in 0..100 {
        if step(&mut map, [1000, 2000]).min_lod == 0.0 {
            break;
        }
    }
    let mut errors = Vec::new();
    for i in 1..=40 {
        step(&mut map, [1000 + speed * i, 2000]);
        if let Err(e) = check_published(&map) {
            errors.push(e);
        }
    }
    assert!(errors.is_empty(), "{errors:?}");
    assert_eq!(map.stats().slots_reassigned_under_published, 0);
    map.stats().paging[0]
}

#[test]
fn adaptive_paging_says_budget_bound_when_the_grid_cannot_hold_the_lead() {
    use crate::paging::adaptive::Reason;
    // Reads take three ticks, at any rate; 12 texels a tick need a lead of 36 texels (3 tiles of
    // 16), but a grid budget below the lookahead-1 grids leaves level 0 one spare tile.
    let tiny = latent_flight(2, 12, Some(1));
    assert_eq!(tiny.reason, Reason::BudgetBound, "{tiny:?}");
    assert_eq!(tiny.grid, [6, 6], "{tiny:?}");
    assert!(tiny.lead_texels[0] > 16, "{tiny:?}");
    // The same flight with the default budget keeps up.
    let roomy = latent_flight(2, 12, None);
    assert_eq!(roomy.reason, Reason::KeepingUp, "{roomy:?}");
    assert_eq!(roomy.lead_texels, tiny.lead_texels, "the same lead asked for: {roomy:?} {tiny:?}");
}

mod wrap;
