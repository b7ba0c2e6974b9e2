//! Tests of the shared-memory layer (layout 2): every texel a client reads inside a published
//! valid region equals the `hash` texel while the engine flies in another thread; after any walk
//! every tile under a published region is settled in its slot and no such slot is written while
//! the snapshot stands; a missing tile costs a coarser level for that tile only; hostile mappings
//! are refused; names are exclusive and taken over after a crash.

use super::*;
use crate::clip::{Clipmap, Settings};
use crate::geom::{tiles_covering, Rect};
use crate::source::procedural::{hash, splitmix64};
use crate::source::{Fault, FaultRule, FaultySource, HashSource, TextureDesc, TileId, TileSource};
use crate::texel::TexelFormat;
use std::os::unix::fs::PermissionsExt;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

fn desc(size: u64, clip: u64, tile: u64) -> TextureDesc {
    TextureDesc::new([size, size], clip, TexelFormat::RGBA8, [tile, tile]).unwrap().with_invalid_border(4).unwrap()
}

fn settings() -> Settings {
    Settings { budget_ns: None, fade_ticks: 1, ..Settings::default() }
}

/// A service's engine: its image caches in a mapping `name` in `dir`.
fn service(dir: &Path, name: &str, source: Arc<dyn TileSource>) -> (Clipmap, Writer) {
    let shape = Clipmap::shape_for(source.desc(), &settings());
    let w = Writer::create(WriterOptions::new(dir, name, shape, source.desc().format())).unwrap();
    let map = Clipmap::with_memory(source, settings(), w.memory()).unwrap();
    (map, w)
}

fn hash_service(dir: &Path, name: &str, size: u64, clip: u64, tile: u64) -> (Clipmap, Writer) {
    service(dir, name, Arc::new(HashSource::new(desc(size, clip, tile))))
}

/// Reads random blocks inside the published regions and checks them; returns (texels, wrong).
fn read_and_check(c: &Client, rng: &mut u64, reads: u64) -> (u64, u64) {
    let mut check = verify::HashCheck::default();
    let mut buf = Vec::new();
    for _ in 0..reads {
        check.step(c, rng, 5, &mut buf, &hash);
    }
    if let Some(f) = &check.first_failure {
        eprintln!("first failure: {f}");
    }
    (check.passed, check.failed)
}

/// The oracle of the writer's invariant, checked against the mapping as a reader sees it: every
/// tile under every published region is in its slot, settled; returns each such slot's tag
/// sequence, to compare later.
fn tiles_under_published(c: &Client) -> Vec<(usize, u64, u64)> {
    let snap = c.try_snapshot().unwrap();
    let mut out = Vec::new();
    for (k, st) in snap.levels.iter().enumerate() {
        if !st.enabled {
            continue;
        }
        let d = c.levels[k];
        let tiles = tiles_covering(st.rect(), d.tile);
        for t in tiles.t0..tiles.t1 {
            for s in tiles.s0..tiles.s1 {
                let slot = layout::slot_index(d.grid, [s, t]);
                let b = (d.tags + slot * layout::TAG_BYTES as u64) as usize;
                let seq = c.raw_region().load(b + layout::tag::SEQ, Ordering::Acquire);
                let tile = [
                    c.raw_region().load(b + layout::tag::TILE_S, Ordering::Relaxed) as i64,
                    c.raw_region().load(b + layout::tag::TILE_T, Ordering::Relaxed) as i64,
                ];
                let state =
                    layout::SlotState::from_code(c.raw_region().load(b + layout::tag::STATE, Ordering::Relaxed));
                assert_eq!(seq % 2, 0, "level {k} slot {slot}: tag being written under a published region");
                assert_eq!(tile, [s, t], "level {k}: the slot of tile ({s}, {t}) holds another tile");
                assert!(state.is_some_and(|x| x.settled()), "level {k} tile ({s}, {t}) is {state:?}");
                out.push((k, slot, seq));
            }
        }
    }
    out
}

#[test]
fn after_any_walk_every_tile_under_a_published_region_is_settled_and_untouched_until_the_next_snapshot() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, _w) = hash_service(dir.path(), "walk", 1 << 12, 128, 32);
    let c = Client::attach(dir.path(), "walk").unwrap();
    let mut rng = 11u64;
    let mut centre = [2000i64, 2000];
    let (mut checked, mut texels) = (0, 0);
    for tick in 0..120 {
        rng = splitmix64(rng);
        // Steps, reversals and jumps larger than the window.
        let step = match rng % 8 {
            0 => [(rng >> 8) as i64 % 3000 - 1500, (rng >> 20) as i64 % 3000 - 1500],
            1..=3 => [37, -21],
            4 | 5 => [-40, 13],
            _ => [0, 90],
        };
        centre = [(centre[0] + step[0]).clamp(0, 4095), (centre[1] + step[1]).clamp(0, 4095)];
        map.tick(centre, None);
        let before = tiles_under_published(&c);
        // Reads complete while this snapshot stands: none may touch a slot it covers.
        map.wait_for_reads();
        let after: Vec<u64> = before
            .iter()
            .map(|&(k, slot, _)| {
                let d = c.levels[k];
                c.raw_region().load((d.tags + slot * layout::TAG_BYTES as u64) as usize, Ordering::Acquire)
            })
            .collect();
        for (&(k, slot, seq), now) in before.iter().zip(after) {
            assert_eq!(seq, now, "tick {tick}: level {k} slot {slot} changed under the published snapshot");
        }
        checked += before.len();
        let (ok, bad) = read_and_check(&c, &mut rng, 20);
        assert_eq!(bad, 0, "tick {tick}");
        texels += ok;
    }
    assert!(checked > 1000 && texels > 1000, "{checked} tiles, {texels} texels checked");
    assert_eq!(map.stats().tick_texel_bytes, 0, "ticks write no texels");
    assert_eq!(map.stats().slots_reassigned_under_published, 0);
}

proptest::proptest! {
    #![proptest_config(proptest::test_runner::Config {
        cases: 24,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x5107),
        failure_persistence: None,
        ..proptest::test_runner::Config::default()
    })]

    /// The oracle, over random shapes and walks: after every tick every tile under a published
    /// region is settled in its own slot, and no such slot changes while the reads of that
    /// publication complete.
    #[test]
    fn no_slot_under_a_published_region_is_written_during_its_publication(
        size_log in 7u32..=12,
        clip_log in 4u32..=8,
        tile_log in 2u32..=6,
        steps in proptest::collection::vec((-300i64..300, -300i64..300, proptest::bool::ANY), 1..30),
    ) {
        let (size, clip, tile) = (1u64 << size_log, 1u64 << clip_log.min(size_log), 1u64 << tile_log.min(clip_log));
        let dir = tempfile::tempdir().unwrap();
        let (mut map, _w) = hash_service(dir.path(), "prop", size, clip, tile);
        let c = Client::attach(dir.path(), "prop").unwrap();
        let mut centre = [(size / 2) as i64; 2];
        for (ds, dt, wait) in steps {
            centre = [centre[0] + ds, centre[1] + dt];
            map.tick(centre, None);
            let before = tiles_under_published(&c);
            if wait {
                map.wait_for_reads();
            }
            for &(k, slot, seq) in &before {
                let d = c.levels[k];
                let now = c.raw_region().load((d.tags + slot * layout::TAG_BYTES as u64) as usize, Ordering::Acquire);
                proptest::prop_assert_eq!(seq, now, "level {} slot {} changed under its publication", k, slot);
            }
        }
        proptest::prop_assert_eq!(map.stats().tick_texel_bytes, 0);
        proptest::prop_assert_eq!(map.stats().slots_reassigned_under_published, 0);
    }
}

#[test]
fn concurrent_readers_never_see_a_wrong_texel() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, _w) = hash_service(dir.path(), "race", 1 << 13, 256, 64);
    let stop = Arc::new(AtomicBool::new(false));
    let total = Arc::new(AtomicU64::new(0));
    let readers: Vec<_> = (0..2)
        .map(|i| {
            let (stop, total) = (Arc::clone(&stop), Arc::clone(&total));
            let dir = dir.path().to_path_buf();
            std::thread::spawn(move || {
                let c = Client::attach(&dir, "race").unwrap();
                let mut rng = 100 + i;
                let mut bad = 0;
                while !stop.load(Ordering::Relaxed) {
                    let (ok, b) = read_and_check(&c, &mut rng, 50);
                    total.fetch_add(ok, Ordering::Relaxed);
                    bad += b;
                }
                bad
            })
        })
        .collect();
    let mut centre = [4000i64, 4000];
    let mut rng = 5u64;
    for tick in 0..400 {
        rng = splitmix64(rng);
        centre = if tick % 50 == 49 {
            [(rng % 8000) as i64, ((rng >> 20) % 8000) as i64]
        } else {
            [(centre[0] + 23).min(8000), (centre[1] - 17).max(0)]
        };
        map.tick(centre, None);
        if tick % 3 == 0 {
            map.wait_for_reads();
        }
    }
    stop.store(true, Ordering::Relaxed);
    let bad: u64 = readers.into_iter().map(|h| h.join().unwrap()).sum();
    assert_eq!(bad, 0);
    assert!(total.load(Ordering::Relaxed) > 1000, "readers checked {} texels", total.load(Ordering::Relaxed));
}

#[test]
fn a_missing_tile_costs_a_coarser_level_for_that_tile_only() {
    let dir = tempfile::tempdir().unwrap();
    let d = desc(1 << 12, 128, 32);
    let faulty = Arc::new(FaultySource::new(Arc::new(HashSource::new(d))));
    // Tile (63, 63) of level 0: under the window centred at (2040, 2040).
    faulty.add(FaultRule::tile(TileId::new(0, 63, 63), Fault::Missing));
    let (mut map, _w) = service(dir.path(), "hole", faulty);
    let c = Client::attach(dir.path(), "hole").unwrap();
    for _ in 0..10 {
        map.tick([2040, 2040], None);
        map.wait_for_reads();
    }
    let snap = c.try_snapshot().unwrap();
    assert_eq!(snap.min_lod, 0.0, "a missing tile does not disable its level");
    let valid = snap.levels[0].rect();
    assert!(valid.contains(63 * 32, 63 * 32) && valid.width() > 100, "{valid:?}");
    let mut texel = vec![0u8; 4];
    let hole = Rect::new(63 * 32 + 5, 63 * 32 + 5, 63 * 32 + 6, 63 * 32 + 6);
    assert_eq!(c.read_region_in(&snap, 0, hole, &mut texel), Err(ReadError::Missing { level: 0, s: 63, t: 63 }));
    // Every other tile of the level is served.
    let next = Rect::new(64 * 32 + 1, 63 * 32 + 1, 64 * 32 + 2, 63 * 32 + 2);
    c.read_region_in(&snap, 0, next, &mut texel).unwrap();
    let mut want = vec![0u8; 4];
    hash(0, next.s0 as u64, next.t0 as u64, &mut want);
    assert_eq!(texel, want);
    // Level 1 serves the hole (the sampler's fallback is tested in `crate::sample`).
    let above = Rect::new(hole.s0 / 2, hole.t0 / 2, hole.s0 / 2 + 1, hole.t0 / 2 + 1);
    c.read_region_in(&snap, 1, above, &mut texel).unwrap();
    hash(1, above.s0 as u64, above.t0 as u64, &mut want);
    assert_eq!(texel, want);
}

#[test]
fn a_region_across_tiles_and_the_toroidal_wrap_reads_equal_to_the_source() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, _w) = hash_service(dir.path(), "wrap", 1 << 12, 128, 32);
    let c = Client::attach(dir.path(), "wrap").unwrap();
    // Fly far enough that the grid has wrapped, then read the whole valid region of level 0.
    for i in 0..40 {
        map.tick([1000 + 37 * i, 1000 + 29 * i], None);
        map.wait_for_reads();
    }
    let snap = c.try_snapshot().unwrap();
    let r = snap.levels[0].rect();
    let tiles = tiles_covering(r, [32, 32]);
    assert!(tiles.s0 % 6 != 0 || tiles.t0 % 6 != 0, "the region starts off the grid's first slot: {tiles:?}");
    let mut out = vec![0u8; (r.area() * 4) as usize];
    c.read_region_in(&snap, 0, r, &mut out).unwrap();
    let mut want = vec![0u8; 4];
    for (i, got) in out.chunks_exact(4).enumerate() {
        let (s, t) = (r.s0 as u64 + i as u64 % r.width(), r.t0 as u64 + i as u64 / r.width());
        hash(0, s, t, &mut want);
        assert_eq!(got, want.as_slice(), "texel ({s}, {t})");
    }
}

#[test]
fn the_mapping_is_owner_only_read_only_for_readers_and_the_name_is_exclusive() {
    let dir = tempfile::tempdir().unwrap();
    let shape = Clipmap::shape_for(&desc(1024, 64, 32), &settings());
    let mk = || {
        Writer::create(
            WriterOptions::new(dir.path(), "excl", shape.clone(), TexelFormat::RGBA8)
                .mode(0o640)
                .tick_period_ns(1_000_000),
        )
    };
    let first = mk().unwrap();
    let mode = |p: std::path::PathBuf| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(map_path(dir.path(), "excl")), 0o640);
    assert_eq!(mode(request_path(dir.path(), "excl")), 0o600);
    match mk() {
        Err(ShmError::AlreadyRunning { pid, .. }) => assert_eq!(pid, std::process::id()),
        other => panic!("expected AlreadyRunning, got {other:?}"),
    }
    // A writer that goes away without closing (as in a crash) releases the name.
    let old = Client::attach(dir.path(), "excl").unwrap();
    assert!(old.can_request());
    drop(first);
    let _second = mk().unwrap();
    assert!(old.replaced(), "the old client must notice the new mapping");
    let new = Client::attach(dir.path(), "excl").unwrap();
    assert_ne!(new.generation, old.generation);
}

/// The names in a directory, sorted.
fn names_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

#[test]
fn a_start_that_fails_part_way_leaves_nothing_of_its_own_behind() {
    let dir = tempfile::tempdir().unwrap();
    let shape = Clipmap::shape_for(&desc(1024, 64, 32), &settings());
    let options = || WriterOptions::new(dir.path(), "part", shape.clone(), TexelFormat::RGBA8);
    // Every temporary name of the texel mapping is taken: the start fails after it took the lock
    // and put the request mapping in place.
    let pid = std::process::id();
    let taken: Vec<String> = (0..16).map(|n| format!(".clipmap-part.map.{pid}.{n}")).collect();
    for t in &taken {
        std::fs::write(dir.path().join(t), b"someone else's").unwrap();
    }
    let before = names_in(dir.path());
    match Writer::create(options()) {
        Err(ShmError::Io { path, .. }) => assert!(path.ends_with(&taken[15]), "{path:?}"),
        other => panic!("expected the temporary name's error, got {other:?}"),
    }
    assert_eq!(names_in(dir.path()), before, "no lock file, request mapping or temporary is left");
    for t in &taken {
        assert_eq!(std::fs::read(dir.path().join(t)).unwrap(), b"someone else's", "{t} is not ours: left alone");
    }
    for t in &taken {
        std::fs::remove_file(dir.path().join(t)).unwrap();
    }
    // The name is taken by something that is not a mapping of ours: publishing fails after the
    // texel mapping was made, and that is removed too, the directory kept.
    std::fs::create_dir(map_path(dir.path(), "part")).unwrap();
    let before = names_in(dir.path());
    match Writer::create(options()) {
        Err(ShmError::Foreign { path, .. }) => assert_eq!(path, map_path(dir.path(), "part")),
        other => panic!("expected the name's foreign file, got {other:?}"),
    }
    assert_eq!(names_in(dir.path()), before, "only the foreign directory is left");
    // With the name free, the same start succeeds and is exclusive.
    std::fs::remove_dir(map_path(dir.path(), "part")).unwrap();
    let w = Writer::create(options()).unwrap();
    assert_eq!(names_in(dir.path()), ["clipmap-part.lock", "clipmap-part.map", "clipmap-part.req"]);
    w.close();
    assert_eq!(names_in(dir.path()), Vec::<String>::new());
}

#[test]
fn hostile_mappings_are_refused_with_a_clear_error() {
    /// A damage done to a copy of a mapping's bytes.
    type Damage = Box<dyn Fn(&mut Vec<u8>)>;
    let dir = tempfile::tempdir().unwrap();
    let (mut map, w) = hash_service(dir.path(), "good", 1024, 64, 32);
    for _ in 0..10 {
        map.tick([500, 500], None);
        map.wait_for_reads();
    }
    assert_eq!(map.min_lod(), 0.0);
    let good = std::fs::read(w.path()).unwrap();
    let put = |b: &mut Vec<u8>, at: usize, v: u64| b[at..at + 8].copy_from_slice(&v.to_le_bytes());
    let snap_level0 = layout::header::SNAPSHOT + layout::snapshot::LEVELS;
    let d0 = layout::header::LEVEL_DESCS;
    let cases: Vec<(&str, Damage, &str)> = vec![
        ("magic", Box::new(|b| b[0] = b'X'), "wrong magic"),
        ("v1", Box::new(|b| b[..8].copy_from_slice(b"CLIPMAP1")), "layout version 1"),
        ("version", Box::new(|b| b[8] = 9), "layout version 9"),
        ("truncated", Box::new(|b| b.truncate(b.len() - 4096)), "the header says"),
        ("tiny", Box::new(|b| b.truncate(100)), "truncated"),
        ("levels", Box::new(|b| b[36] = 200), "implausible header"),
        ("grid0", Box::new(move |b| put(b, d0 + layout::desc::GRID_S, 0)), "inconsistent"),
        ("grid-huge", Box::new(move |b| put(b, d0 + layout::desc::GRID_S, 1 << 40)), "inconsistent"),
        ("slots-past-end", Box::new(move |b| put(b, d0 + layout::desc::SLOTS_OFFSET, 1 << 50)), "inconsistent"),
    ];
    for (name, corrupt, want) in cases {
        let mut bytes = good.clone();
        corrupt(&mut bytes);
        let p = dir.path().join(format!("clipmap-{name}.map"));
        std::fs::write(&p, &bytes).unwrap();
        let err = Client::attach(dir.path(), name).unwrap_err().to_string();
        assert!(err.contains(want), "{name}: {err}");
    }
    // Published state outside its bounds: attaching works, every read is refused as corrupt.
    let published: Vec<(&str, Damage)> = vec![
        ("outside", Box::new(move |b| put(b, snap_level0 + layout::state::VALID_S1, 5000))),
        ("far", Box::new(move |b| put(b, snap_level0 + layout::state::VALID_S0, (-(1i64 << 62)) as u64))),
        ("huge", Box::new(move |b| put(b, snap_level0 + layout::state::VALID_S1, 1 << 62))),
        ("nan", Box::new(move |b| put(b, layout::header::SNAPSHOT + layout::snapshot::MIN_LOD, f64::NAN.to_bits()))),
        ("enabled", Box::new(move |b| put(b, snap_level0 + layout::state::ENABLED, 7))),
    ];
    for (name, corrupt) in published {
        let mut bytes = good.clone();
        corrupt(&mut bytes);
        let p = dir.path().join(format!("clipmap-{name}.map"));
        std::fs::write(&p, &bytes).unwrap();
        let c = Client::attach(dir.path(), name).unwrap();
        assert!(matches!(c.try_snapshot(), Err(ReadError::Corrupt(_))), "{name}");
        assert!(c.texel(0, 500, 500).is_err(), "{name}");
    }
    // A growth block that is impossible: refused as corrupt by the growth reader, and nothing else
    // is affected. A texture that does not grow reads as `None`; a good block reads back whole.
    assert_eq!(Client::attach(dir.path(), "good").unwrap().growth().unwrap(), None);
    let g0 = layout::header::GROWTH;
    let good_growth = layout::Growth {
        extent: [10, 20, 30, 40],
        data_levels: 3,
        patches: 2,
        world_origin: [-512.0, 7.5],
        texels_per_unit: 2.0,
        ..Default::default()
    };
    w.memory().publish_growth(&good_growth);
    let grown = std::fs::read(w.path()).unwrap();
    std::fs::write(dir.path().join("clipmap-grown.map"), &grown).unwrap();
    assert_eq!(Client::attach(dir.path(), "grown").unwrap().growth().unwrap(), Some(good_growth));
    let growth: Vec<(&str, Damage, &str)> = vec![
        ("g-flag", Box::new(move |b| put(b, g0 + layout::growth::GROWING, 7)), "growing is 7"),
        ("g-out", Box::new(move |b| put(b, g0 + layout::growth::EXTENT_S1, 5000)), "not inside the 1024x1024 frame"),
        ("g-far", Box::new(move |b| put(b, g0 + layout::growth::EXTENT_S0, (-(1i64 << 62)) as u64)), "not inside"),
        ("g-nan", Box::new(move |b| put(b, g0 + layout::growth::TEXELS_PER_UNIT, f64::NAN.to_bits())), "not finite"),
        ("g-levels", Box::new(move |b| put(b, g0 + layout::growth::DATA_LEVELS, 1 << 40)), "data levels"),
    ];
    for (name, corrupt, want) in growth {
        let mut bytes = grown.clone();
        corrupt(&mut bytes);
        std::fs::write(dir.path().join(format!("clipmap-{name}.map")), &bytes).unwrap();
        let c = Client::attach(dir.path(), name).unwrap();
        match c.growth() {
            Err(ReadError::Corrupt(e)) => assert!(e.contains(want), "{name}: {e}"),
            other => panic!("{name}: {other:?}"),
        }
        assert!(c.try_snapshot().is_ok(), "{name}: the snapshot is unaffected");
    }
    assert!(matches!(Client::attach(dir.path(), "absent"), Err(ShmError::NotFound { .. })));
    assert!(matches!(Client::attach(dir.path(), "../x"), Err(ShmError::BadName(_))));
}

/// The views block is checked as the C and Python readers check it: one placed outside the
/// mapping, or of a known version with a wrong record count or size, refuses the mapping; one of
/// a magic or version this reader does not know leaves `main` readable and refuses only a view.
#[test]
fn a_views_block_this_reader_does_not_know_refuses_views_not_main() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, w) = hash_service(dir.path(), "vgood", 1024, 64, 32);
    let left = map.add_named_view("left", 1.0).unwrap();
    map.move_view(left, [300, 300], None).unwrap();
    for _ in 0..10 {
        map.tick([500, 500], None);
        map.wait_for_reads();
    }
    let good = std::fs::read(w.path()).unwrap();
    let vb = u64::from_le_bytes(good[layout::header::VIEWS_OFFSET..][..8].try_into().unwrap()) as usize;
    assert!(vb > 0);
    let c = Client::attach_view(dir.path(), "vgood", "left").expect("a known block binds");
    assert_eq!(c.view_name(), "left");
    let put32 = |b: &mut Vec<u8>, at: usize, v: u32| b[at..at + 4].copy_from_slice(&v.to_le_bytes());
    let put64 = |b: &mut Vec<u8>, at: usize, v: u64| b[at..at + 8].copy_from_slice(&v.to_le_bytes());
    use layout::views as v;
    type Corrupt = Box<dyn Fn(&mut Vec<u8>)>;
    // Refused at attach, naming the field.
    let refused: Vec<(&str, Corrupt, &str)> = vec![
        ("vodd", Box::new(move |b| put64(b, layout::header::VIEWS_OFFSET, vb as u64 + 8)), "views block offset"),
        ("vpast", Box::new(move |b| put64(b, layout::header::VIEWS_OFFSET, 1 << 40)), "views block offset"),
        ("vrecords", Box::new(move |b| put32(b, vb + v::RECORDS, 0)), "view records"),
        ("vbytes", Box::new(move |b| put32(b, vb + v::RECORD_BYTES_AT, 64)), "record bytes"),
    ];
    for (name, corrupt, want) in refused {
        let mut bytes = good.clone();
        corrupt(&mut bytes);
        std::fs::write(dir.path().join(format!("clipmap-{name}.map")), &bytes).unwrap();
        let err = Client::attach(dir.path(), name).unwrap_err().to_string();
        assert!(err.contains(want), "{name}: {err}");
    }
    // Version 1 (the first release's) is read as version 2 is, but knows no state 2.
    let state = vb + v::FIRST + v::STATE;
    let mut v1 = good.clone();
    put32(&mut v1, vb + v::VERSION, 1);
    std::fs::write(dir.path().join("clipmap-v1.map"), &v1).unwrap();
    let c = Client::attach_view(dir.path(), "v1", "left").expect("a version-1 block binds");
    assert_eq!(c.view_name(), "left");
    put64(&mut v1, state, v::STATE_OWN);
    std::fs::write(dir.path().join("clipmap-v1own.map"), &v1).unwrap();
    let err = Client::attach_view(dir.path(), "v1own", "left").unwrap_err().to_string();
    assert!(err.contains("(state): found 2, expected 0 (free) or 1 (live) in a version-1 block"), "{err}");
    // State 2 in version 2: the view is in its own mapping, which must be there.
    let mut own = good.clone();
    put64(&mut own, state, v::STATE_OWN);
    std::fs::write(dir.path().join("clipmap-v2own.map"), &own).unwrap();
    let err = Client::attach_view(dir.path(), "v2own", "left").unwrap_err().to_string();
    assert!(
        err.contains("view `left` has grids of its own, but its mapping")
            && err.contains("clipmap-v2own@left.map is not there"),
        "{err}"
    );
    // There (a mapping of no live view): read as its `main`, answering to the view's name.
    let mut alone = good.clone();
    put64(&mut alone, state, v::STATE_FREE);
    std::fs::write(dir.path().join("clipmap-v2own@left.map"), &alone).unwrap();
    let c = Client::attach_view(dir.path(), "v2own", "left").expect("follows to the own mapping");
    assert!(c.reads_own_grids() && c.view_name() == "left");
    assert!(c.path().ends_with("clipmap-v2own@left.map"), "{:?}", c.path());
    let mut rng = 9;
    let (read, wrong) = read_and_check(&c, &mut rng, 200);
    assert!(read > 0 && wrong == 0, "own mapping: read {read}, wrong {wrong}");
    // An own mapping that itself publishes views is not a view's own.
    std::fs::write(dir.path().join("clipmap-v2bad.map"), &own).unwrap();
    std::fs::write(dir.path().join("clipmap-v2bad@left.map"), &good).unwrap();
    let err = Client::attach_view(dir.path(), "v2bad", "left").unwrap_err().to_string();
    assert!(err.contains("found 1 live view records, expected none"), "{err}");
    // Unknown: main reads, the view is refused with the field and the value found.
    let unknown: Vec<(&str, Corrupt, &str)> = vec![
        ("vmagic", Box::new(move |b| b[vb + v::MAGIC] = b'X'), "expected \"CLIPVIEW\""),
        ("vversion", Box::new(move |b| put32(b, vb + v::VERSION, 3)), "found 3, this reader knows versions 1 to 2"),
    ];
    for (name, corrupt, want) in unknown {
        let mut bytes = good.clone();
        corrupt(&mut bytes);
        std::fs::write(dir.path().join(format!("clipmap-{name}.map")), &bytes).unwrap();
        let c = Client::attach(dir.path(), name).unwrap_or_else(|e| panic!("{name}: main must stay readable: {e}"));
        let snap = c.snapshot();
        let mut rng = 7;
        let (read, wrong) = read_and_check(&c, &mut rng, 200);
        assert!(read > 0 && wrong == 0, "{name}: main reads {read}, wrong {wrong}, snapshot {snap:?}");
        let err = Client::attach_view(dir.path(), name, "left").unwrap_err().to_string();
        assert!(err.contains(want), "{name}: {err}");
        assert!(Client::attach_view(dir.path(), name, "main").is_ok(), "{name}: main by name");
    }
}

#[test]
fn memory_of_another_shape_is_refused() {
    let d = desc(1024, 64, 32);
    let other = Clipmap::shape_for(&desc(1024, 32, 32), &settings());
    let memory = Arc::new(ImageMemory::anonymous(other, d.format()).unwrap());
    let Err(err) = Clipmap::with_memory(Arc::new(HashSource::new(d)), settings(), memory) else {
        panic!("memory of another texture was accepted")
    };
    assert!(err.to_string().contains("laid out as"), "{err}");
}

#[test]
fn texel_format_codes_round_trip() {
    use crate::texel::TexelFormat as F;
    let all =
        [F::L8, F::RGB8, F::RGBA8, F::RGB565, F::RGBA5551, F::L16, F::LA16, F::RGB16, F::RGBA16, F::L32F, F::L16I];
    for f in all {
        assert_eq!(layout::format_from_code(layout::format_code(f)), Some(f));
    }
    // The codes are part of the mapping's format (include/clipmap_shm.h, docs/SHM.md).
    assert_eq!(all.map(layout::format_code), [1, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]);
    assert_eq!(layout::format_from_code(0), None);
    assert_eq!(layout::format_from_code(99), None);
}

#[test]
fn a_whole_tile_reads_under_its_tag_inside_or_outside_the_published_region() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, _w) = hash_service(dir.path(), "tile", 1 << 12, 128, 32);
    let c = Client::attach(dir.path(), "tile").unwrap();
    for _ in 0..10 {
        map.tick([2040, 2040], None);
        map.wait_for_reads();
    }
    let snap = c.try_snapshot().unwrap();
    let valid = snap.levels[0].rect();
    let tiles = tiles_covering(valid, [32, 32]);
    // An edge tile of the region: part of it lies outside the valid region, all of it is read.
    let edge = [tiles.s0, tiles.t0];
    assert!(valid.s0 > edge[0] * 32, "the region starts inside its first tile: {valid:?}");
    let mut out = vec![0u8; 32 * 32 * 4];
    c.read_tile(0, edge, &mut out).unwrap();
    let mut want = vec![0u8; 4];
    for (i, got) in out.chunks_exact(4).enumerate() {
        let (s, t) = (edge[0] as u64 * 32 + i as u64 % 32, edge[1] as u64 * 32 + i as u64 / 32);
        hash(0, s, t, &mut want);
        assert_eq!(got, want.as_slice(), "texel ({s}, {t})");
    }
    // A tile the grid does not hold, one outside the level, a wrong buffer.
    assert_eq!(c.read_tile(0, [edge[0] + 20, edge[1]], &mut out), Err(ReadError::Stale(0)));
    assert_eq!(c.read_tile(0, [-1, 0], &mut out), Err(ReadError::NotValid(0)));
    assert_eq!(c.read_tile(0, [128, 0], &mut out), Err(ReadError::NotValid(0)));
    assert!(matches!(c.read_tile(0, edge, &mut out[..10]), Err(ReadError::Corrupt(_))));
}

/// docs/SHM.md lists every byte range of the header, the snapshot, the descriptors, the growth
/// block and the request mapping; the ranges it calls reserved are zero, in a mapping that has
/// been published and requested through.
#[test]
fn every_byte_the_contract_calls_reserved_is_zero() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, w) = hash_service(dir.path(), "zero", 1000, 64, 32);
    let c = Client::attach(dir.path(), "zero").unwrap();
    for i in 0..8 {
        assert!(c.request_centre([400 + i, 300], [1.0, -1.0]));
        map.tick([400 + i, 300], None);
        map.wait_for_reads();
    }
    let m = std::fs::read(w.path()).unwrap();
    let zero = |what: &str, r: std::ops::Range<usize>| {
        assert!(m[r.clone()].iter().all(|&b| b == 0), "{what} {r:?} is not zero");
    };
    use layout::{header as h, snapshot as s};
    zero("header: the u32 pid's upper half", h::WRITER_PID + 4..h::HEARTBEAT);
    zero("header", h::VIEWS_OFFSET + 8..h::SNAPSHOT);
    // The views block: its header's reserved bytes, and every free record whole.
    let vb = u64::from_le_bytes(m[h::VIEWS_OFFSET..h::VIEWS_OFFSET + 8].try_into().unwrap()) as usize;
    assert!(vb > 0 && vb.is_multiple_of(4096), "the service's mappings have a views block: {vb}");
    zero("views block", vb + 20..vb + layout::views::FIRST);
    let rec = vb + layout::views::record(0);
    zero("free view record", rec..rec + layout::views::SNAPSHOT);
    zero("snapshot", h::SNAPSHOT + s::CENTRE_T + 8..h::SNAPSHOT + s::LEVELS);
    let n = c.levels.len();
    let states = h::SNAPSHOT + s::LEVELS;
    zero("level states past the level count", states + n * layout::STATE_BYTES..h::LEVEL_DESCS);
    for k in 0..n {
        let d = h::LEVEL_DESCS + k * layout::DESC_BYTES;
        zero("descriptor", d + layout::desc::KIND + 8..d + layout::DESC_BYTES);
    }
    zero("descriptors past the level count", h::LEVEL_DESCS + n * layout::DESC_BYTES..h::GROWTH);
    zero("growth block (a texture that does not grow)", h::GROWTH..h::HEIGHTS);
    zero("heights block (a texture that is not heights)", h::HEIGHTS..h::END);
    let header_bytes = u32::from_le_bytes(m[h::HEADER_BYTES..h::HEADER_BYTES + 4].try_into().unwrap()) as usize;
    assert_eq!(header_bytes, 8192);
    zero("after the heights block", h::END..header_bytes);
    let mut end = header_bytes;
    for d in &c.levels {
        zero("before a level's tags", end..d.tags as usize);
        let tags_end = (d.tags + d.grid[0] * d.grid[1] * layout::TAG_BYTES as u64) as usize;
        zero("between a level's tags and its slots", tags_end..d.slots as usize);
        end = (d.slots + d.grid[0] * d.grid[1] * d.slot_bytes) as usize;
    }
    zero("after the last level", end..vb);
    let records = layout::views::SERVICE_RECORDS;
    for r in 0..records {
        let rec = vb + layout::views::record(r);
        zero("a view record's reserved bytes", rec + 32..rec + 64);
        zero("a free view record's name", rec + 64..rec + 128);
    }
    zero("after the views block", vb + layout::views::record(records)..m.len());
    let r = std::fs::read(w.request_path()).unwrap();
    assert_eq!(r.len(), 4096);
    let rzero = |what: &str, x: std::ops::Range<usize>| assert!(r[x.clone()].iter().all(|&b| b == 0), "{what} {x:?}");
    use layout::request as q;
    rzero("request: after the version", q::VERSION + 4..q::GENERATION);
    rzero("request: before the lock word", q::GENERATION + 8..q::SEQ);
    // A request in texels writes its position record too (kind 0, for its own count): the
    // rest stays zero.
    let pos = layout::views::position(0);
    rzero("request: after the count", q::COUNT + 8..pos);
    let word = |o: usize| u64::from_le_bytes(r[o..o + 8].try_into().unwrap());
    assert_eq!(word(pos + layout::views::POS_KIND), layout::views::KIND_TEXELS);
    assert_eq!(word(pos + layout::views::POS_FOR_COUNT), word(q::COUNT), "the position record is this request's");
    rzero("request: after the main position record", layout::views::position(1)..4096);
    assert_eq!(u64::from_le_bytes(r[q::CLIENT_PID..q::CLIENT_PID + 8].try_into().unwrap()), std::process::id() as u64);
}

/// docs/SHM.md: a level is level 0 halved k times rounding down (at least 1); level k's centre is
/// level 0's shifted right by k (floor, for negative centres too); a window starts `clip / 2`
/// texels before its centre and is translated to stay inside the level; published centres are
/// not clamped to the texture.
#[test]
fn level_sizes_round_down_centres_shift_by_floor_and_are_published_unclamped() {
    let dir = tempfile::tempdir().unwrap();
    let d = TextureDesc::new([1000, 333], 64, TexelFormat::RGBA8, [32, 32]).unwrap().with_invalid_border(4).unwrap();
    let (mut map, _w) = service(dir.path(), "odd", Arc::new(HashSource::new(d)));
    let c = Client::attach(dir.path(), "odd").unwrap();
    let sizes: Vec<[u64; 2]> = c.levels.iter().map(|l| l.size).collect();
    assert_eq!(&sizes[..4], &[[1000, 333], [500, 166], [250, 83], [125, 41]]);
    assert_eq!(sizes.last(), Some(&[1, 1]));
    assert_eq!(sizes.len(), 10, "down to 1 x 1: as many levels as the longer edge has bits");
    let settle = |map: &mut Clipmap, centre: [i64; 2]| {
        for _ in 0..12 {
            map.tick(centre, None);
            map.wait_for_reads();
        }
    };
    // An even clip size: the window of a centre c is [c - 32, c + 32).
    settle(&mut map, [500, 200]);
    let snap = c.try_snapshot().unwrap();
    assert_eq!(snap.levels[0].valid, [468 + 4, 168 + 4, 532 - 4, 232 - 4], "the window less the border");
    assert_eq!(snap.levels[1].centre, [250, 100]);
    // A centre outside the texture: published as given (floor-shifted per level), the windows
    // clamped to the edge (no border against it).
    settle(&mut map, [-3, 5000]);
    let snap = c.try_snapshot().unwrap();
    assert_eq!(snap.centre, [-3, 5000], "the level-0 centre is not clamped");
    assert_eq!(snap.levels[0].centre, [-3, 5000]);
    assert_eq!(snap.levels[1].centre, [-2, 2500], "-3 >> 1 = -2: floor");
    assert_eq!(snap.levels[2].centre, [-1, 1250]);
    assert_eq!(snap.levels[0].valid, [0, 333 - 64 + 4, 64 - 4, 333]);
}

/// docs/SHM.md: min LOD rises at once and falls by a fifth of the distance to its target each
/// tick (x0.8 of the distance) while that is at least a level, then by 0.2 a tick.
#[test]
fn min_lod_falls_by_the_documented_steps() {
    assert_eq!(Settings::default().fade_ticks, 5, "the service's fade");
    let mut lod = 3.0;
    let mut seen = vec![lod];
    while lod > 0.0 {
        lod = crate::clip::next_min_lod(lod, 0, 5);
        seen.push(lod);
    }
    for w in seen.windows(2) {
        let (a, b) = (w[0], w[1]);
        let want = if a >= 1.0 { a * 0.8 } else { (a - 0.2).max(0.0) };
        assert!((b - want).abs() < 1e-12, "{a} -> {b}, documented {want}: {seen:?}");
    }
    assert_eq!(crate::clip::next_min_lod(0.5, 4, 5), 4.0, "a rise is at once");
}

/// Counts this thread's seqlocked reads from zero while `f` runs (`client::Tally`).
fn tallied<R>(f: impl FnOnce() -> R) -> (R, client::Tally) {
    client::TALLY.with(|t| t.set(client::Tally::default()));
    let r = f();
    (r, client::TALLY.with(|t| t.get()))
}

/// docs/SHM.md, "Reading consistently" step 2: a tag that names its tile and says loading under a
/// published region (a growing texture's tile being rebuilt in place, `ImageMemory::replace`) is
/// neither waited nor retried for: one look at the tag and the level is stale for that tile,
/// `read_region` gives up after its 4 snapshots, and the sampler takes that tile's texels from
/// the next level while the tile beside it is still read from level 0. Once the tile is settled
/// again it is read as before.
#[test]
fn a_tile_loading_under_a_published_region_falls_back_to_a_coarser_level_without_waiting_or_retrying() {
    use crate::sample::{sample_mapping_in, Filter};
    let dir = tempfile::tempdir().unwrap();
    let (mut map, w) = hash_service(dir.path(), "rebuild", 1 << 12, 128, 32);
    let c = Client::attach(dir.path(), "rebuild").unwrap();
    for _ in 0..10 {
        map.tick([2040, 2040], None);
        map.wait_for_reads();
    }
    let snap = c.try_snapshot().unwrap();
    assert_eq!(snap.min_lod, 0.0);
    let tile = TileId::new(0, 63, 63);
    let inside = Rect::new(63 * 32 + 5, 63 * 32 + 5, 63 * 32 + 6, 63 * 32 + 6);
    let beside = Rect::new(64 * 32 + 1, 63 * 32 + 1, 64 * 32 + 2, 63 * 32 + 2);
    assert!(snap.levels[0].rect().contains_rect(&inside) && snap.levels[0].rect().contains_rect(&beside));
    let (mut texel, mut want) = (vec![0u8; 4], vec![0u8; 4]);
    let point =
        |r: Rect, lod: f64| sample_mapping_in(&c, &snap, Filter::Point, r.s0 as f64 + 0.5, r.t0 as f64 + 0.5, lod);
    // The test acts as the engine's tick from here on: it takes the memory's keeper, which the
    // clipmap gives back when dropped.
    drop(map);
    let memory = w.memory();
    let mut keeper = memory.take_keeper().expect("the dropped clipmap gave the keeper back");
    // The tick opens the slot (tag loading), then a read fills it as any read does.
    let generation =
        memory.replace(&mut keeper, tile).expect("tile (63, 63) is settled in its slot under the published region");
    let (filled, ()) = memory
        .fill(tile, |_| {
            // The tag now says (63, 63) loading, under level 0's published region.
            let (got, n) = tallied(|| c.read_region_in(&snap, 0, inside, &mut texel));
            assert_eq!(got, Err(ReadError::Stale(0)), "a loading tile is not read");
            assert_eq!((n.tag_attempts, n.spins), (1, 0), "one look at the tag, no pause, no retry: {n:?}");
            let (got, n) = tallied(|| c.read_region(0, inside.s0, inside.t0, 1, 1, &mut texel));
            assert_eq!(got.map(|_| ()), Err(ReadError::Stale(0)), "read_region: stale after its snapshots");
            assert_eq!(n, client::Tally { locked_attempts: 4, yields: 0, tag_attempts: 4, spins: 0 }, "4 snapshots");
            c.read_region_in(&snap, 0, beside, &mut texel).unwrap();
            hash(0, beside.s0 as u64, beside.t0 as u64, &mut want);
            assert_eq!(texel, want, "the tile beside it is served");
            let fell_back = point(inside, 0.0).expect("level 1 holds the footprint");
            assert_eq!(fell_back.lod, 1.0, "the loading tile's texels come from the next level");
            assert_eq!(Some(fell_back), point(inside, 1.0));
            assert_eq!(point(beside, 0.0).map(|x| x.lod), Some(0.0), "only that tile falls back");
        })
        .expect("the opened slot is lent to one read");
    assert_eq!(filled, generation);
    assert!(memory.settle(tile, generation, layout::SlotState::Ready));
    c.read_region_in(&snap, 0, inside, &mut texel).unwrap();
    hash(0, inside.s0 as u64, inside.t0 as u64, &mut want);
    assert_eq!(texel, want, "ready again: read from its slot");
    assert_eq!(point(inside, 0.0).map(|x| x.lod), Some(0.0));
}

/// docs/SHM.md, "Retries are bounded": facing a sequence counter the writer holds odd, a reader
/// makes 64 attempts (`MAX_RETRIES`) and gives up for now with `Busy`, yielding the processor
/// between attempts at the snapshot and at the growth block and issuing only the pause hint
/// between attempts at a tag; a snapshot it already holds still reads. `checked_snapshot` tries
/// again for a second before it reports the service busy. Once the counter is even again every
/// read succeeds.
#[test]
fn a_counter_held_odd_costs_64_paused_attempts_and_then_busy_never_an_endless_spin() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, w) = hash_service(dir.path(), "held", 1 << 12, 128, 32);
    let c = Client::attach(dir.path(), "held").unwrap();
    for _ in 0..10 {
        map.tick([2040, 2040], None);
        map.wait_for_reads();
    }
    let memory = w.memory();
    let r = memory.raw_region();
    let hold = |at: usize| {
        let seq = r.load(at, Ordering::Relaxed);
        assert_eq!(seq % 2, 0);
        r.store(at, seq + 1, Ordering::Release);
        move || r.store(at, seq + 2, Ordering::Release)
    };
    let n_tries = layout::MAX_RETRIES as u64;
    assert_eq!(n_tries, 64);
    let snap = c.try_snapshot().unwrap();
    let inside = Rect::new(63 * 32 + 5, 63 * 32 + 5, 63 * 32 + 6, 63 * 32 + 6);
    let mut texel = vec![0u8; 4];

    // The snapshot.
    let release = hold(layout::header::SNAPSHOT + layout::snapshot::SEQ);
    let (got, n) = tallied(|| c.try_snapshot());
    assert_eq!(got.map(|_| ()), Err(ReadError::Busy(0)));
    assert_eq!(n, client::Tally { locked_attempts: n_tries, yields: n_tries, ..Default::default() }, "a yield each");
    assert_eq!(c.read_region(2, 500, 500, 1, 1, &mut texel).map(|_| ()), Err(ReadError::Busy(2)), "the level is busy");
    c.read_region_in(&snap, 0, inside, &mut texel).expect("the snapshot it had still reads");
    let started = std::time::Instant::now();
    let (got, n) = tallied(|| c.checked_snapshot());
    let waited = started.elapsed();
    match got {
        Err(e @ ShmError::Busy { ms, .. }) => {
            assert!(ms >= 1000 && waited >= std::time::Duration::from_secs(1), "gave up after {ms} ms ({waited:?})");
            assert!(e.to_string().contains("kept its published state locked"), "{e}");
        }
        other => panic!("a snapshot held odd for ever: {other:?}"),
    }
    assert!(n.locked_attempts >= 2 * n_tries && n.locked_attempts % n_tries == 0, "whole rounds of 64: {n:?}");
    assert_eq!(n.yields, n.locked_attempts);
    release();
    assert!(c.try_snapshot().is_ok() && c.checked_snapshot().is_ok());

    // The growth block (all zero: a texture that does not grow).
    let release = hold(layout::header::GROWTH + layout::growth::SEQ);
    let (got, n) = tallied(|| c.growth());
    assert_eq!(got, Err(ReadError::Busy(0)));
    assert_eq!(n, client::Tally { locked_attempts: n_tries, yields: n_tries, ..Default::default() }, "a yield each");
    release();
    assert_eq!(c.growth(), Ok(None));

    // A tag under the published region.
    let d = c.levels[0];
    let slot = layout::slot_index(d.grid, [63, 63]);
    let release = hold((d.tags + slot * layout::TAG_BYTES as u64) as usize + layout::tag::SEQ);
    let (got, n) = tallied(|| c.read_region_in(&snap, 0, inside, &mut texel));
    assert_eq!(got, Err(ReadError::Busy(0)));
    assert_eq!(n, client::Tally { tag_attempts: n_tries, spins: n_tries, ..Default::default() }, "a pause hint each");
    release();
    c.read_region_in(&snap, 0, inside, &mut texel).unwrap();
    let mut want = vec![0u8; 4];
    hash(0, inside.s0 as u64, inside.t0 as u64, &mut want);
    assert_eq!(texel, want);
}

/// A height texture's engine: the verification heights (`l32f`, nodata -32768) in a mapping
/// `name` in `dir`, with tile ranges.
fn height_service(dir: &Path, name: &str, size: u64, clip: u64, tile: u64) -> (Clipmap, Writer) {
    use crate::height::{HeightFormat, LevelRule};
    let d = TextureDesc::new([size, size], clip, TexelFormat::L32F, [tile, tile]).unwrap();
    let source: Arc<dyn TileSource> = Arc::new(crate::source::HeightSource::new(d, HeightFormat::VERIFICATION));
    let shape = Clipmap::shape_for(source.desc(), &settings());
    let heights = Some(layout::Heights::of(&HeightFormat::VERIFICATION, LevelRule::Mean));
    let w = Writer::create(WriterOptions::new(dir, name, shape, TexelFormat::L32F).heights(heights)).unwrap();
    let map = Clipmap::with_memory(source, settings(), w.memory()).unwrap();
    (map, w)
}

/// docs/SHM.md, "Tile ranges": every ready tile's published range equals the range of its texels
/// (read through the same client, nodata excluded), a colour texture's levels have none, and a
/// tile replaced in its slot never shows another fill's range: while its tag says loading the
/// client gives no range, and a reader racing a writer that refills the slot with one height
/// after another only ever sees a range whose minimum and maximum are the same fill's, never
/// going back.
#[test]
fn a_tile_range_is_never_seen_for_another_fill_of_its_slot() {
    use crate::height::{HeightFormat, TileRange};
    let dir = tempfile::tempdir().unwrap();
    let (mut map, w) = height_service(dir.path(), "ranges", 1 << 10, 128, 32);
    let c = Client::attach(dir.path(), "ranges").unwrap();
    for _ in 0..10 {
        map.tick([512, 512], None);
        map.wait_for_reads();
    }
    assert_eq!(c.try_snapshot().unwrap().min_lod, 0.0);
    let f = HeightFormat::VERIFICATION;
    let mut seen = 0;
    for k in 0..c.levels.len() {
        let d = c.levels[k];
        assert!(d.ranges != 0 && d.ranges.is_multiple_of(layout::PAGE) && d.ranges < d.slots, "{d:?}");
        for (tile, r) in c.tile_ranges(k) {
            let mut bytes = vec![0u8; d.slot_bytes as usize];
            c.read_tile(k, tile, &mut bytes).unwrap();
            // Only the texels inside the level count (all of them here: 2^n sizes).
            assert_eq!(r, f.tile_range(&bytes).unwrap(), "level {k} tile {tile:?}");
            seen += 1;
        }
    }
    assert!(seen >= 2 * 25, "ranges of every level's resident tiles: {seen}");
    // A colour texture: no ranges anywhere.
    let (mut hmap, _hw) = hash_service(dir.path(), "colour", 1 << 10, 128, 32);
    hmap.tick([512, 512], None);
    hmap.wait_for_reads();
    let hc = Client::attach(dir.path(), "colour").unwrap();
    assert!(hc.levels.iter().all(|d| d.ranges == 0));
    assert_eq!(hc.tile_range(0, [16, 16]), Ok(None));

    // The test acts as the engine's tick from here on (see above).
    drop(map);
    let memory = w.memory();
    let mut keeper = memory.take_keeper().expect("the dropped clipmap gave the keeper back");
    let tile = TileId::new(0, 16, 16);
    let before = c.tile_range(0, [16, 16]).unwrap().expect("tile (16, 16) is ready");
    let generation = memory.replace(&mut keeper, tile).expect("settled in its slot");
    assert_eq!(c.tile_range(0, [16, 16]), Ok(None), "no range while the tag says loading");
    memory.fill(tile, |b| b.chunks_exact_mut(4).for_each(|x| x.copy_from_slice(&(-32768f32).to_le_bytes())));
    assert_eq!(c.tile_range(0, [16, 16]), Ok(None), "nor while the bytes change");
    assert!(memory.settle(tile, generation, layout::SlotState::Ready));
    assert_eq!(c.tile_range(0, [16, 16]), Ok(Some(TileRange::Empty)), "all nodata now");
    assert_ne!(before, TileRange::Empty);

    // A reader racing the writer's refills of the slot: fill i holds the height i everywhere.
    let stop = Arc::new(AtomicBool::new(false));
    let reader = {
        let (stop, path) = (Arc::clone(&stop), c.path().to_path_buf());
        std::thread::spawn(move || {
            let c = Client::attach_path(&path).unwrap();
            let (mut last, mut ranges, mut none) = (f64::NEG_INFINITY, 0u64, 0u64);
            while !stop.load(Ordering::Relaxed) {
                match c.tile_range(0, [16, 16]) {
                    Ok(Some(TileRange::Heights { min, max })) => {
                        assert_eq!(min, max, "minimum and maximum of two fills");
                        assert!(min >= last, "a range older than one seen before: {min} after {last}");
                        last = min;
                        ranges += 1;
                    }
                    Ok(Some(TileRange::Empty)) => assert_eq!(last, f64::NEG_INFINITY, "the nodata fill came first"),
                    Ok(None) | Err(ReadError::Busy(_)) => none += 1,
                    Err(e) => panic!("{e}"),
                }
            }
            (ranges, none, last)
        })
    };
    let fills = 2000;
    for i in 1..=fills {
        let g = memory.replace(&mut keeper, tile).expect("settled");
        memory.fill(tile, |b| b.chunks_exact_mut(4).for_each(|x| x.copy_from_slice(&(i as f32).to_le_bytes())));
        assert!(memory.settle(tile, g, layout::SlotState::Ready));
        if i % 50 == 0 {
            // A settled moment the reader can see on any scheduler (two cores, under load).
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
    }
    stop.store(true, Ordering::Relaxed);
    let (ranges, none, last) = reader.join().unwrap();
    assert!(ranges > 0, "the reader saw ranges ({none} times none)");
    assert_eq!(c.tile_range(0, [16, 16]), Ok(Some(TileRange::Heights { min: fills as f64, max: fills as f64 })));
    assert!(last <= fills as f64);
}

mod requests;
mod shared_reads;
