//! Tests of the shared-memory layer: every texel a client reads inside a published valid region
//! equals the `hash` texel, while the writer moves the centre in another thread; hostile
//! mappings are refused; names are exclusive and taken over after a crash.

use super::*;
use crate::clip::{Clipmap, CostTable, Settings};
use crate::source::procedural::hash;
use crate::source::{HashSource, TextureDesc};
use crate::texel::TexelFormat;
use std::os::unix::fs::PermissionsExt;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

fn engine(size: u64, clip: u64, tile: u64) -> Clipmap {
    let desc =
        TextureDesc::new([size, size], clip, TexelFormat::RGBA8, [tile, tile]).unwrap().with_invalid_border(4).unwrap();
    let settings = Settings {
        budget_ns: None,
        cost: Some(CostTable::fixed(100.0, 10.0, 1.0)),
        fade_ticks: 1,
        ..Settings::default()
    };
    Clipmap::new(Arc::new(HashSource::new(desc)), settings).unwrap()
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
    let dir = tempfile::tempdir().unwrap();
    let mut map = engine(1 << 14, 256, 64);
    let mut mirror = mirror::Mirror::create(dir.path(), "t1", &map, 0o600).unwrap();
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
    let dir = tempfile::tempdir().unwrap();
    let mut map = engine(1 << 16, 128, 32);
    let mut mirror = mirror::Mirror::create(dir.path(), "t2", &map, 0o600).unwrap();
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
