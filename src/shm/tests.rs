//! Tests of the shared-memory layer: every texel a client reads inside a published valid region
//! equals the `hash` texel, while the writer moves the centre in another thread; hostile
//! mappings are refused; names are exclusive and taken over after a crash.

use super::*;
use crate::clip::{Clipmap, CostTable, Settings};
use crate::source::procedural::hash;
use crate::source::{HashSource, TextureDesc};
use crate::texel::TexelFormat;
use std::os::unix::fs::PermissionsExt;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

fn desc(size: u64, clip: u64, tile: u64) -> TextureDesc {
    TextureDesc::new([size, size], clip, TexelFormat::RGBA8, [tile, tile]).unwrap().with_invalid_border(4).unwrap()
}

fn settings() -> Settings {
    Settings { budget_ns: None, cost: Some(CostTable::fixed(100.0, 10.0, 1.0)), fade_ticks: 1, ..Settings::default() }
}

fn engine(size: u64, clip: u64, tile: u64) -> Clipmap {
    Clipmap::new(Arc::new(HashSource::new(desc(size, clip, tile))), settings()).unwrap()
}

/// An engine and its mirror in `dir`: copying from private windows, or (`direct`) with the
/// engine's windows in the mapping itself, as the service runs it.
fn engine_and_mirror(
    dir: &Path,
    name: &str,
    size: u64,
    clip: u64,
    tile: u64,
    direct: bool,
) -> (Clipmap, mirror::Mirror) {
    if direct {
        let d = desc(size, clip, tile);
        let writer = Writer::create(dir, name, mirror::shape_of_desc(&d), d.format(), 0o600).unwrap();
        let map = Clipmap::with_windows(Arc::new(HashSource::new(d)), settings(), writer.window_stores()).unwrap();
        let m = mirror::Mirror::direct(writer, &map).unwrap();
        (map, m)
    } else {
        let map = engine(size, clip, tile);
        let m = mirror::Mirror::create(dir, name, &map, 0o600).unwrap();
        (map, m)
    }
}

/// Reads random texels inside the published regions and checks them; returns (reads, mismatches).
fn read_and_check(c: &Client, rng: &mut u64, reads: u64) -> (u64, u64) {
    let bpt = c.bytes_per_texel;
    let (mut ok, mut bad) = (0, 0);
    let mut got = vec![0u8; bpt * 4];
    let mut want = vec![0u8; bpt];
    let mut next = || {
        *rng = crate::source::procedural::splitmix64(*rng);
        *rng
    };
    for _ in 0..reads {
        let level = (next() % c.levels.len() as u64) as usize;
        let Some(st) = c.level_state(level) else { continue };
        if !st.enabled || st.valid[2] - st.valid[0] < 2 || st.valid[3] - st.valid[1] < 2 {
            continue;
        }
        let s = st.valid[0] + (next() % (st.valid[2] - st.valid[0] - 1) as u64) as i64;
        let t = st.valid[1] + (next() % (st.valid[3] - st.valid[1] - 1) as u64) as i64;
        if c.read_region(level, s, t, 2, 2, &mut got).is_err() {
            continue;
        }
        for (i, (ds, dt)) in [(0, 0), (1, 0), (0, 1), (1, 1)].into_iter().enumerate() {
            hash(level as u32, (s + ds) as u64, (t + dt) as u64, &mut want);
            if got[i * bpt..(i + 1) * bpt] == want[..] {
                ok += 1;
            } else {
                bad += 1;
            }
        }
    }
    (ok, bad)
}

#[test]
fn a_client_reads_exactly_the_hash_texels_while_the_centre_moves() {
    client_reads_hash_texels(false);
}

#[test]
fn a_client_reads_exactly_the_hash_texels_when_the_engine_writes_into_the_mapping() {
    client_reads_hash_texels(true);
}

fn client_reads_hash_texels(direct: bool) {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, mut mirror) = engine_and_mirror(dir.path(), "t1", 1 << 14, 256, 64, direct);
    let client = Client::attach(dir.path(), "t1").unwrap();
    let mut rng = 7u64;
    let mut centre = [100i64, 8000];
    let mut total = (0, 0);
    for tick in 0..200 {
        centre = match tick % 50 {
            0 => [(crate::source::procedural::splitmix64(tick) % (1 << 14)) as i64, centre[1]],
            _ => [centre[0] + 3, centre[1] - 2],
        };
        map.tick_with(centre, None, &mut mirror);
        map.wait_for_reads();
        let (ok, bad) = read_and_check(&client, &mut rng, 200);
        total = (total.0 + ok, total.1 + bad);
    }
    assert_eq!(total.1, 0, "mismatched texels");
    assert!(total.0 > 50_000, "too few texels were checked: {}", total.0);
}

#[test]
fn concurrent_readers_never_see_a_wrong_texel() {
    concurrent_readers(false);
}

#[test]
fn concurrent_readers_never_see_a_wrong_texel_when_the_engine_writes_into_the_mapping() {
    concurrent_readers(true);
}

fn concurrent_readers(direct: bool) {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, mut mirror) = engine_and_mirror(dir.path(), "t2", 1 << 16, 128, 32, direct);
    let stop = Arc::new(AtomicBool::new(false));
    let counts = Arc::new((AtomicU64::new(0), AtomicU64::new(0)));
    let readers: Vec<_> = (0..2)
        .map(|i| {
            let (stop, counts, path) = (stop.clone(), counts.clone(), dir.path().to_path_buf());
            std::thread::spawn(move || {
                let c = Client::attach(&path, "t2").unwrap();
                let mut rng = 99 + i;
                while !stop.load(Ordering::Relaxed) {
                    let (ok, bad) = read_and_check(&c, &mut rng, 100);
                    counts.0.fetch_add(ok, Ordering::Relaxed);
                    counts.1.fetch_add(bad, Ordering::Relaxed);
                }
            })
        })
        .collect();
    let mut centre = [30_000i64, 30_000];
    for tick in 0..600u64 {
        // Fast flight, reversals and jumps larger than the window.
        centre = match tick % 150 {
            0 => [centre[0] + 5000, centre[1] - 3000],
            75 => [centre[0] - 40, centre[1]],
            _ if tick % 150 > 75 => [centre[0] - 9, centre[1] + 7],
            _ => [centre[0] + 9, centre[1] + 7],
        };
        map.tick_with(centre, None, &mut mirror);
        if tick % 5 == 0 {
            map.wait_for_reads();
        }
    }
    stop.store(true, Ordering::Relaxed);
    for r in readers {
        r.join().unwrap();
    }
    let (ok, bad) = (counts.0.load(Ordering::Relaxed), counts.1.load(Ordering::Relaxed));
    assert_eq!(bad, 0, "{bad} mismatches out of {}", ok + bad);
    assert!(ok > 10_000, "too few reads: {ok}");
}

#[test]
fn the_mapping_is_owner_only_and_the_name_is_exclusive() {
    let dir = tempfile::tempdir().unwrap();
    let map = engine(1024, 64, 32);
    let first = mirror::Mirror::create(dir.path(), "excl", &map, 0o600).unwrap();
    let mode = std::fs::metadata(map_path(dir.path(), "excl")).unwrap().permissions().mode();
    assert_eq!(mode & 0o777, 0o600);
    match mirror::Mirror::create(dir.path(), "excl", &map, 0o600) {
        Err(ShmError::AlreadyRunning { pid, .. }) => assert_eq!(pid, std::process::id()),
        other => panic!("expected AlreadyRunning, got {other:?}"),
    }
    // A writer that goes away without closing (as in a crash) releases the name.
    let old = Client::attach(dir.path(), "excl").unwrap();
    drop(first);
    let _second = mirror::Mirror::create(dir.path(), "excl", &map, 0o600).unwrap();
    assert!(old.replaced(), "the old client must notice the new mapping");
    let new = Client::attach(dir.path(), "excl").unwrap();
    assert_ne!(new.generation, old.generation);
}

#[test]
fn hostile_mappings_are_refused_with_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let map = engine(1024, 64, 32);
    let w = mirror::Mirror::create(dir.path(), "good", &map, 0o600).unwrap();
    let good = std::fs::read(w.writer().path()).unwrap();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "magic",
            {
                let mut b = good.clone();
                b[0] = b'X';
                b
            },
            "wrong magic",
        ),
        (
            "version",
            {
                let mut b = good.clone();
                b[8] = 9;
                b
            },
            "layout version 9",
        ),
        ("truncated", good[..good.len() - 4096].to_vec(), "the header says"),
        ("tiny", good[..100].to_vec(), "truncated"),
        (
            "levels",
            {
                let mut b = good.clone();
                b[36] = 200;
                b
            },
            "implausible header",
        ),
        (
            "window",
            {
                let mut b = good.clone();
                b[layout::header::LEVEL_DESCS + 16] ^= 0x10;
                b
            },
            "inconsistent",
        ),
    ];
    for (name, bytes, want) in cases {
        let p = dir.path().join(format!("clipmap-{name}.map"));
        std::fs::write(&p, &bytes).unwrap();
        let err = Client::attach(dir.path(), name).unwrap_err().to_string();
        assert!(err.contains(want), "{name}: {err}");
    }
    assert!(matches!(Client::attach(dir.path(), "absent"), Err(ShmError::NotFound { .. })));
    assert!(matches!(Client::attach(dir.path(), "../x"), Err(ShmError::BadName(_))));
}

#[test]
fn a_renderer_request_reaches_the_writer() {
    let dir = tempfile::tempdir().unwrap();
    let map = engine(1024, 64, 32);
    let m = mirror::Mirror::create(dir.path(), "req", &map, 0o600).unwrap();
    assert_eq!(m.writer().request(), None);
    let c = Client::attach(dir.path(), "req").unwrap();
    c.request_centre([123, -45], [1.5, 0.0]);
    c.request_centre([124, -46], [1.5, 0.0]);
    let r = m.writer().request().unwrap();
    assert_eq!((r.centre, r.velocity, r.count), ([124, -46], [1.5, 0.0], 2));
    m.into_writer().close();
    assert!(c.closed());
}

#[test]
fn a_renderer_that_died_holding_the_request_lock_does_not_silence_the_others() {
    use std::os::unix::fs::FileExt;
    let dir = tempfile::tempdir().unwrap();
    let map = engine(1024, 64, 32);
    let m = mirror::Mirror::create(dir.path(), "dead", &map, 0o600).unwrap();
    let c = Client::attach(dir.path(), "dead").unwrap();
    c.request_centre([1, 2], [0.0, 0.0]);
    // A renderer killed between taking the lock (odd) and releasing it.
    let f = std::fs::OpenOptions::new().write(true).open(m.writer().path()).unwrap();
    f.write_all_at(&3u64.to_le_bytes(), (layout::header::REQUEST + layout::request::SEQ) as u64).unwrap();
    assert_eq!(m.writer().request(), None, "a half-written request is never taken");
    c.request_centre([7, 8], [0.0, 0.0]);
    let r = m.writer().request().unwrap();
    assert_eq!(r.centre, [7, 8]);
}

#[test]
fn direct_windows_must_match_the_texture_and_a_private_engine_is_not_direct() {
    let dir = tempfile::tempdir().unwrap();
    let d = desc(1024, 64, 32);
    let writer = Writer::create(dir.path(), "shape", mirror::shape_of_desc(&d), d.format(), 0o600).unwrap();
    // Stores of another texture (clip 32) do not fit this one (clip 64).
    let other = desc(1024, 32, 32);
    let w2 = Writer::create(dir.path(), "other", mirror::shape_of_desc(&other), other.format(), 0o600).unwrap();
    let Err(err) = Clipmap::with_windows(Arc::new(HashSource::new(d.clone())), settings(), w2.window_stores()) else {
        panic!("stores of another texture were accepted")
    };
    let msg = err.to_string();
    assert!(msg.contains("level 0") && msg.contains("found 4096 bytes, expected 16384"), "{msg}");
    let mut fewer = writer.window_stores();
    fewer.pop();
    let Err(err) = Clipmap::with_windows(Arc::new(HashSource::new(d.clone())), settings(), fewer) else {
        panic!("too few stores were accepted")
    };
    assert!(err.to_string().contains("supplied"), "{err}");
    // An engine with private windows cannot be published without copies.
    let private = engine(1024, 64, 32);
    let err = mirror::Mirror::direct(writer, &private).unwrap_err();
    assert!(err.to_string().contains("private memory"), "{err}");
}

#[test]
fn a_direct_engine_samples_what_a_private_one_samples() {
    let dir = tempfile::tempdir().unwrap();
    let (mut a, mut ma) = engine_and_mirror(dir.path(), "sa", 1 << 12, 128, 32, true);
    let mut b = engine(1 << 12, 128, 32);
    let mut c = [1000i64, 1500];
    for _ in 0..40 {
        c = [c[0] + 13, c[1] - 7];
        a.tick_with(c, None, &mut ma);
        b.tick(c, None);
        a.wait_for_reads();
        b.wait_for_reads();
    }
    for k in 0..a.level_count() as u32 {
        let (va, vb) = (a.level(k), b.level(k));
        assert_eq!(va.valid, vb.valid, "level {k}");
        assert!(va.texels.as_slice().is_none() && vb.texels.as_slice().is_some());
        for t in va.valid.t0..va.valid.t1 {
            for s in va.valid.s0..va.valid.s1 {
                assert_eq!(va.texel(s, t), vb.texel(s, t), "level {k} ({s}, {t})");
            }
        }
    }
    assert!(ma.bytes_copied > 0);
}

/// Checks, just before each after-writes publication (when the engine has written this tick's
/// texels but not yet published them), that every texel the mapping publishes still holds its
/// `hash` value: a write into a published slot is caught even when no reader happened to race
/// it.
struct CheckBeforePublishing<'a> {
    mirror: &'a mut mirror::Mirror,
    client: &'a Client,
    checked: u64,
    bad: u64,
}

impl crate::clip::Publisher for CheckBeforePublishing<'_> {
    fn publish(&mut self, phase: crate::clip::Phase, clipmap: &Clipmap) {
        if phase == crate::clip::Phase::AfterWrites {
            let bpt = self.client.bytes_per_texel;
            let mut want = vec![0u8; bpt];
            for k in 0..self.client.levels.len() {
                let Some(st) = self.client.level_state(k) else { continue };
                let [s0, t0, s1, t1] = st.valid;
                if !st.enabled || s1 <= s0 || t1 <= t0 {
                    continue;
                }
                let mut got = vec![0u8; ((s1 - s0) * (t1 - t0)) as usize * bpt];
                self.client.read_region(k, s0, t0, (s1 - s0) as u64, (t1 - t0) as u64, &mut got).unwrap();
                for (i, px) in got.chunks(bpt).enumerate() {
                    let (s, t) = (s0 + i as i64 % (s1 - s0), t0 + i as i64 / (s1 - s0));
                    hash(k as u32, s as u64, t as u64, &mut want);
                    self.checked += 1;
                    self.bad += u64::from(px != &want[..]);
                }
            }
        }
        self.mirror.publish(phase, clipmap);
    }
}

#[test]
fn the_engine_never_writes_a_slot_the_mapping_publishes() {
    let dir = tempfile::tempdir().unwrap();
    let (mut map, mut mirror) = engine_and_mirror(dir.path(), "inv", 1 << 12, 64, 16, true);
    let client = Client::attach(dir.path(), "inv").unwrap();
    let mut check = CheckBeforePublishing { mirror: &mut mirror, client: &client, checked: 0, bad: 0 };
    let mut c = [2000i64, 2000];
    for tick in 0..120u64 {
        // Steady moves, reversals, and a jump larger than the window every 40 ticks.
        c = match tick % 40 {
            0 => [c[0] + 300, c[1] - 200],
            20..=29 => [c[0] - 5, c[1] + 3],
            _ => [c[0] + 6, c[1] + 2],
        };
        map.tick_with(c, None, &mut check);
        map.wait_for_reads();
    }
    assert_eq!(check.bad, 0, "{} published texels were overwritten before publication", check.bad);
    assert!(check.checked > 100_000, "too few texels checked: {}", check.checked);
}

#[test]
fn a_client_samples_the_mapping_exactly_as_the_engine_is_sampled() {
    use crate::sample::{sample_clipmap, Filter, MipmapSampler};
    let dir = tempfile::tempdir().unwrap();
    let (mut map, mut mirror) = engine_and_mirror(dir.path(), "smp", 1 << 12, 128, 32, true);
    let client = Client::attach(dir.path(), "smp").unwrap();
    let full_source = HashSource::new(desc(1 << 12, 128, 32));
    let mut full = MipmapSampler::new(&full_source);
    let mut c = [1500i64, 2500];
    let mut rng = 3u64;
    let mut next = || {
        rng = crate::source::procedural::splitmix64(rng);
        rng
    };
    let (mut compared, mut coarser) = (0, 0);
    for tick in 0..30 {
        c = [c[0] + 11, c[1] - 9];
        map.tick_with(c, None, &mut mirror);
        map.wait_for_reads();
        if tick < 5 {
            continue;
        }
        for _ in 0..100 {
            // Around the centre, out to a few windows away, at LODs from 0 to 6.
            let u = c[0] as f64 + (next() % 1200) as f64 - 600.0 + (next() % 1000) as f64 / 1000.0;
            let v = c[1] as f64 + (next() % 1200) as f64 - 600.0 + (next() % 1000) as f64 / 1000.0;
            let lod = (next() % 600) as f64 / 100.0;
            let filter = [Filter::Point, Filter::Bilinear, Filter::Trilinear][(next() % 3) as usize];
            let from_engine = sample_clipmap(&map, filter, u, v, lod).expect("the engine holds every footprint");
            let from_mapping = client.sample(filter, u, v, lod).expect("the mapping holds every footprint");
            assert_eq!(from_mapping, from_engine, "{filter:?} at ({u}, {v}) lod {lod}");
            let reference = full.sample(filter, u, v, from_mapping.lod).unwrap();
            assert_eq!(from_mapping.rgba, reference, "{filter:?} at ({u}, {v}) lod {}", from_mapping.lod);
            compared += 1;
            coarser += usize::from(from_mapping.lod > lod);
        }
    }
    assert_eq!(compared, 2500);
    assert!(coarser > 0, "some samples fall outside the finer windows and use a coarser level");
}

#[test]
fn texel_format_codes_round_trip() {
    use crate::texel::TexelFormat as F;
    let all = [F::L8, F::RGB8, F::RGBA8, F::RGB565, F::RGBA5551, F::L16, F::LA16, F::RGB16, F::RGBA16];
    for f in all {
        assert_eq!(layout::format_from_code(layout::format_code(f)), Some(f));
    }
    // The codes are part of the mapping's format (include/clipmap_shm.h, docs/SHM.md).
    assert_eq!(all.map(layout::format_code), [1, 3, 4, 5, 6, 7, 8, 9, 10]);
    assert_eq!(layout::format_from_code(0), None);
    assert_eq!(layout::format_from_code(99), None);
}
