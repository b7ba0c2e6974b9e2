//! Requests in flight sized by the remote source itself (docs/COG.md, "Requests in flight"):
//! reads paced at a fixed rate through the test's delaying proxy in front of nginx, at 5, 20
//! and 80 ms a request; the source's limit follows rate x latency (within its floor and cap),
//! the proxy sees about that many requests at once, and the limit drops when the proxy answers
//! `503`.

use crate::common::exec;
use crate::common::remote::{point_config_at, Fault, FaultProxy, Nginx, Schedule};
use clipmap::limits::Limits;
use clipmap::plan;
use clipmap::source::procedural::hash;
use clipmap::source::remote::{flight, RemoteOptions, RemoteSource};
use clipmap::source::{TileId, TileSource};
use std::path::Path;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Reads a second.
const RATE: f64 = 400.0;

/// A `size`² hash-texture pyramid of 64-texel tiles (clip 256) prepared by `clipprep` under
/// `d/pyr`, and nginx serving it.
fn served_hash_pyramid(d: &Path, size: u32) -> (std::path::PathBuf, Nginx) {
    let pyr = d.join("pyr");
    let size = size.to_string();
    let args = ["--source", "hash", "--size", &size, "--tile", "64", "--clip", "256", "--format", "rgba8", "--quiet"];
    let (out, desc) =
        exec(Path::new("."), env!("CARGO_BIN_EXE_clipprep"), &[&args[..], &["--out", pyr.to_str().unwrap()]].concat());
    assert!(out.status.success(), "{desc}");
    let nginx = Nginx::serve(&pyr);
    (pyr, nginx)
}

fn source(ct: &Path) -> RemoteSource {
    let l = plan::load_clip_texture(ct, &plan::Options::default()).unwrap();
    let rendered = l.render();
    let plan = l.plan.unwrap_or_else(|| panic!("{rendered}"));
    let opts = RemoteOptions {
        timeout: Duration::from_secs(5),
        retries: 3,
        backoff: Duration::from_millis(2),
        backoff_max: Duration::from_millis(40),
        ..RemoteOptions::default()
    };
    RemoteSource::new(plan, &Limits::default(), opts).unwrap()
}

/// Reads level-0 tiles (a different one each time, from `first` on) at `RATE` a second for
/// `secs`, from as many threads as it takes; checks each tile's corners against the hash
/// texture. Returns the reads that failed and the next tile.
fn paced(src: &RemoteSource, first: usize, secs: f64) -> (u64, usize) {
    let d = src.desc().level(0);
    let [tw, th] = d.tile;
    let per_row = d.tiles()[0] as usize;
    let count = (RATE * secs) as usize;
    let next = AtomicUsize::new(0);
    let failed = AtomicU64::new(0);
    let start = Instant::now();
    std::thread::scope(|s| {
        for _ in 0..128 {
            s.spawn(|| {
                let mut buf = vec![0u8; src.desc().tile_bytes(0)];
                let mut want = [0u8; 4];
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= count {
                        break;
                    }
                    let due = start + Duration::from_secs_f64(i as f64 / RATE);
                    std::thread::sleep(due.saturating_duration_since(Instant::now()));
                    let n = first + i;
                    let id = TileId::new(0, (n % per_row) as u64, (n / per_row) as u64);
                    if src.read_tile(id, &mut buf).is_err() {
                        failed.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    for (x, y) in [(0, 0), (tw - 1, th - 1)] {
                        hash(0, id.s * tw + x, id.t * th + y, &mut want);
                        let at = ((y * tw + x) * 4) as usize;
                        assert_eq!(buf[at..at + 4], want, "{id}: texel ({x}, {y})");
                    }
                }
            });
        }
    });
    (failed.into_inner(), first + count)
}

#[test]
fn requests_in_flight_follow_rate_times_latency_and_drop_when_the_store_says_slow_down() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (pyr, nginx) = served_hash_pyramid(d, 4096);
    let mut last = None;
    for delay in [5u64, 20, 80] {
        let proxy = FaultProxy::start(nginx.port, Schedule::pass(), delay);
        let ct = point_config_at(&pyr, &d.join(format!("cfg{delay}")), &proxy.url(), &[]);
        let src = source(&ct);
        let t = Instant::now();
        let (failed, next) = paced(&src, 0, 2.5);
        // The rate the reads came at: `RATE`, or less on a machine too loaded to keep the pace.
        let rate = (RATE * 2.5).floor() / t.elapsed().as_secs_f64();
        assert_eq!(failed, 0, "{delay} ms");
        let st = src.stats();
        let peak = proxy.in_flight.peak.load(Ordering::SeqCst);
        let latency = st.latency_us as f64 / 1e6;
        println!(
            "+{delay} ms: limit {} ({}), latency {:.1} ms, {} reads/s, peak {} in flight at the proxy, {} at the source",
            st.in_flight_limit,
            st.in_flight_reason,
            latency * 1e3,
            st.reads_per_s,
            peak,
            st.peak_in_flight
        );
        // What the source measured: the rate it was read at, and the proxy's delay plus a little
        // (the local server's answer and the machine's scheduling).
        assert!((0.8 * rate..=1.2 * rate).contains(&(st.reads_per_s as f64)), "read at {rate:.0} a second: {st:?}");
        let added = delay as f64 / 1e3;
        assert!(latency >= added && latency < added + 0.15, "{delay} ms: {st:?}");
        // Its limit: rate x latency with the headroom, within the floor and the cap.
        let want = (st.reads_per_s as f64 * latency * flight::HEADROOM).ceil() as u64;
        let floor = flight::FLOOR as u64;
        let near = |limit: u64| limit.abs_diff(want.clamp(floor, 256)) <= want / 4 + 2;
        assert!(near(st.in_flight_limit), "{delay} ms: the limit {} is not near {want}: {st:?}", st.in_flight_limit);
        assert!((floor..=256).contains(&st.in_flight_limit), "{st:?}");
        // The requests at once: about rate x latency.
        let needed = rate * added;
        assert!(peak as f64 >= 0.6 * needed, "{delay} ms: {peak} at once at the proxy, rate x latency is {needed}");
        if delay == 80 {
            assert_eq!(st.in_flight_reason, "rate x latency", "{st:?}");
            assert!(st.in_flight_limit > floor && peak > floor, "more than the floor of 16 when needed: {st:?}");
            last = Some((proxy, src, next, st));
        } else if delay == 5 && want <= floor {
            // (Where a loaded machine made even these answers slow, the limit is rate x latency,
            // checked above.)
            assert_eq!((st.in_flight_limit, st.in_flight_reason.as_str()), (floor, "floor"), "{st:?}");
        }
    }
    // The store says slow down: the limit halves (once a latency), and says why.
    let (proxy, src, next, before) = last.unwrap();
    proxy.set(Schedule { faults: vec![Fault::Unavailable; 60], then: Vec::new(), every: 0 });
    let _ = paced(&src, next, 0.4);
    let st = src.stats();
    println!("after 503s: limit {} ({}), {} throttled", st.in_flight_limit, st.in_flight_reason, st.throttled);
    assert!(st.throttled > 0, "{st:?}");
    assert!(
        st.in_flight_limit * 4 < before.in_flight_limit * 3,
        "the limit drops: {} then {st:?}",
        before.in_flight_limit
    );
    assert_eq!(st.in_flight_reason, "throttled (429/503/SlowDown)", "{st:?}");
}

/// Reads every tile of `src` with `threads` threads, each tile checked whole against the hash
/// texture; returns the reads that failed.
fn read_all(src: &RemoteSource, threads: usize) -> u64 {
    let d = src.desc();
    let tiles: Vec<TileId> = (0..d.level_count() as u32)
        .flat_map(|k| {
            let t = d.level(k).tiles();
            (0..t[1]).flat_map(move |tt| (0..t[0]).map(move |s| TileId::new(k, s, tt)))
        })
        .collect();
    let next = AtomicUsize::new(0);
    let failed = AtomicU64::new(0);
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| {
                let mut want = [0u8; 4];
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(&id) = tiles.get(i) else { break };
                    let l = src.desc().level(id.level);
                    let mut buf = vec![0u8; src.desc().tile_bytes(id.level)];
                    if src.read_tile(id, &mut buf).is_err() {
                        failed.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    let [w, h] = l.tile;
                    for y in 0..h {
                        for x in 0..w {
                            hash(id.level, id.s * w + x, id.t * h + y, &mut want);
                            let at = ((y * w + x) * 4) as usize;
                            assert_eq!(buf[at..at + 4], want, "{id}: texel ({x}, {y})");
                        }
                    }
                }
            });
        }
    });
    failed.into_inner()
}

#[test]
fn reads_held_twenty_times_longer_than_their_peers_are_hedged_within_their_share_and_every_texel_is_right() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (pyr, nginx) = served_hash_pyramid(d, 1024);
    // 20 ms a request; one request in a hundred held 400 ms more.
    let tail = Schedule { faults: Vec::new(), then: vec![Fault::Slow(400)], every: 100 };
    let proxy = FaultProxy::start(nginx.port, tail, 20);
    let ct = point_config_at(&pyr, &d.join("cfg"), &proxy.url(), &[]);
    let src = source(&ct);
    assert_eq!(read_all(&src, 16), 0);
    let st = src.stats();
    let held = proxy.injected.lock().unwrap().iter().filter(|f| matches!(f, Fault::Slow(_))).count();
    println!("{} requests, {} held, {} hedged", st.requests, held, st.hedged);
    assert!(st.hedged >= 1 && held >= 2, "the held reads are hedged: {st:?}");
    assert!(st.hedged as f64 <= flight::HEDGE_SHARE * st.requests as f64, "within the share: {st:?}");
    assert_eq!((st.failures, st.duplicate_reads), (0, 0), "{st:?}");
}

#[test]
fn a_cold_starts_first_request_held_is_hedged_once_the_others_answers_time_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (pyr, nginx) = served_hash_pyramid(d, 1024);
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 20);
    let ct = point_config_at(&pyr, &d.join("cfg"), &proxy.url(), &[]);
    let src = source(&ct);
    // The first tile request after the open is held 10 s: sent before any answer was measured,
    // it can be timed for a hedge only by the answers that come after it.
    proxy.set(Schedule { faults: vec![Fault::Slow(10_000)], then: Vec::new(), every: 0 });
    let t = Instant::now();
    assert_eq!(read_all(&src, 16), 0);
    let st = src.stats();
    let held = proxy.injected.lock().unwrap().iter().filter(|f| matches!(f, Fault::Slow(_))).count();
    println!("{} requests, {} held, {} hedged, {:?}", st.requests, held, st.hedged, t.elapsed());
    assert_eq!(held, 1, "{st:?}");
    assert!(st.hedged >= 1, "the held request is hedged: {st:?}");
    // Its own answer cannot come before 10 s: every tile read sooner (and checked) came from
    // the hedge. (Without a hedge for requests sent before the first answers, it waited.) About
    // 0.5 s here; the hold leaves a slow machine room.
    assert!(t.elapsed() < Duration::from_secs(10), "{:?}: {st:?}", t.elapsed());
}

#[test]
fn an_object_replaced_between_a_request_and_its_hedge_is_refused_as_changed() {
    use clipmap::place::RemoteName;
    use clipmap::source::remote::object::{Object, ObjectError};
    use clipmap::source::remote::Remote;
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("www");
    std::fs::create_dir(&root).unwrap();
    let v1: Vec<u8> = (0..1u32 << 20).map(|i| (i * 7 % 251) as u8).collect();
    std::fs::write(root.join("obj.bin"), &v1).unwrap();
    let nginx = Nginx::serve(&root);
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 40);
    let remote =
        Arc::new(Remote::new(RemoteOptions { timeout: Duration::from_secs(10), ..RemoteOptions::default() }).unwrap());
    let name = RemoteName::parse(&format!("{}/obj.bin", proxy.url())).unwrap();
    let (obj, _) = Object::open(Arc::clone(&remote), &name, 1024).unwrap();
    // Enough answers for the endpoint's latency quantiles (and requests for the hedges' share).
    for i in 0..60u64 {
        let got = obj.read(10_000 * (i + 1), 1000).unwrap().to_bytes();
        assert_eq!(got.as_ref(), &v1[(10_000 * (i + 1)) as usize..][..1000]);
    }
    let hedged = remote.stats().hedged;
    // The next request is held 5 s; the object is replaced while it waits, before its hedge
    // (sent three times the 40 ms median later, then held 1 s at the proxy, so that a slow
    // machine still replaces the object before the hedge reaches the server) is answered.
    proxy.set(Schedule { faults: vec![Fault::Slow(5000), Fault::Slow(1000)], then: Vec::new(), every: 0 });
    let before = proxy.requests.load(Ordering::SeqCst);
    let reader = {
        let obj = obj.clone();
        std::thread::spawn(move || obj.read(500_000, 1000))
    };
    let deadline = Instant::now() + Duration::from_secs(5);
    while proxy.requests.load(Ordering::SeqCst) == before {
        assert!(Instant::now() < deadline, "the read never reached the proxy");
        std::thread::sleep(Duration::from_millis(1));
    }
    let v2: Vec<u8> = (0..(1u32 << 20) + 7).map(|i| (i * 11 % 253) as u8).collect();
    std::fs::write(root.join("obj.new"), &v2).unwrap();
    std::fs::rename(root.join("obj.new"), root.join("obj.bin")).unwrap();
    let t = Instant::now();
    let r = reader.join().unwrap();
    assert!(t.elapsed() < Duration::from_secs(4), "the hedge answered, not the held request: {:?}", t.elapsed());
    match r {
        Err(e @ ObjectError::Changed { .. }) => {
            assert!(e.to_string().contains("changed since it was opened"), "{e}")
        }
        other => panic!("expected the object's change refused, got {other:?}"),
    }
    assert_eq!(remote.stats().hedged, hedged + 1, "{:?}", remote.stats());
}
