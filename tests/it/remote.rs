//! Tiles from HTTP servers and S3-compatible stores, end to end on loopback: Debian's nginx
//! serving a prepared hash pyramid (range requests), moto as the S3 store, and a fault proxy in
//! the test injecting 404, 500, 503 with Retry-After, slow answers, resets, truncated bodies,
//! wrong Content-Lengths, `200` error pages, answers for other ranges and answers that ignore
//! the range; a hostile S3 stand-in on a loopback socket; a disk cache whose files are replaced
//! by FIFOs, links and altered bytes. Every texel is checked against the hash texture, through
//! the library and through `clipmapd` with `clipmap-read`. nginx and moto are installed by
//! `.ci/run`; a test that cannot find one fails saying what to install.

use crate::common::remote::{point_config_at, Fault, FaultProxy, Moto, Nginx, Schedule};
use crate::common::{exec, exec_bounded, NO_IC_CT};
use clipmap::limits::Limits;
use clipmap::plan;
use clipmap::source::procedural::hash;
use clipmap::source::remote::{RemoteOptions, RemoteSource};
use clipmap::source::{SourceError, TileId, TileSource};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const CLIPPREP: &str = env!("CARGO_BIN_EXE_clipprep");
const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const CLIPMAPD: &str = env!("CARGO_BIN_EXE_clipmapd");
const READER: &str = env!("CARGO_BIN_EXE_clipmap-read");

/// Prepares a hash pyramid (RGBA8) in `dir` with extra clipprep options; returns `dir`.
pub(crate) fn prepare(dir: &Path, size: u64, tile: u64, clip: u64, extra: &[&str]) -> PathBuf {
    let (s, t, c) = (size.to_string(), tile.to_string(), clip.to_string());
    let mut args = vec!["--source", "hash", "--size", &s, "--tile", &t, "--clip", &c, "--format", "rgba8", "--quiet"];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", dir.to_str().unwrap()]);
    let (out, d) = exec(Path::new("."), CLIPPREP, &args);
    assert!(out.status.success(), "{d}");
    dir.to_path_buf()
}

pub(crate) fn load(ct: &Path) -> plan::ClipTexturePlan {
    let l = plan::load_clip_texture(ct, &plan::Options::default()).unwrap();
    let rendered = l.render();
    l.plan.unwrap_or_else(|| panic!("{} should load:\n{rendered}", ct.display()))
}

/// Short timeouts and backoffs, so that faults resolve quickly.
pub(crate) fn quick_opts() -> RemoteOptions {
    RemoteOptions {
        timeout: Duration::from_millis(1500),
        connect_timeout: Duration::from_millis(500),
        retries: 3,
        backoff: Duration::from_millis(2),
        backoff_max: Duration::from_millis(40),
        ..RemoteOptions::default()
    }
}

/// Every texel of `buf` (tile `id`, `w` x `h`, RGBA8) against the hash texture.
fn assert_hash_tile(id: TileId, w: u64, h: u64, buf: &[u8]) {
    let mut want = [0u8; 4];
    for y in 0..h {
        for x in 0..w {
            hash(id.level, id.s * w + x, id.t * h + y, &mut want);
            let at = ((y * w + x) * 4) as usize;
            assert_eq!(&buf[at..at + 4], &want, "{id}: texel ({x}, {y}) of the tile is wrong");
        }
    }
}

pub(crate) fn every_tile(src: &dyn TileSource) -> Vec<TileId> {
    let d = src.desc();
    (0..d.level_count() as u32)
        .flat_map(|k| {
            let t = d.level(k).tiles();
            (0..t[1]).flat_map(move |tt| (0..t[0]).map(move |s| TileId::new(k, s, tt)))
        })
        .collect()
}

pub(crate) fn read_checked(src: &dyn TileSource, id: TileId) -> Result<(), SourceError> {
    let d = src.desc().level(id.level);
    let mut buf = vec![0u8; src.desc().tile_bytes(id.level)];
    src.read_tile(id, &mut buf)?;
    assert_hash_tile(id, d.tile[0], d.tile[1], &buf);
    Ok(())
}

/// A running `clipmapd` over a configuration, killed on drop.
struct Service {
    child: Child,
    socket: PathBuf,
    err: PathBuf,
}

impl Service {
    fn start(dir: &Path, name: &str, ct: &Path, envs: &[(String, String)]) -> Service {
        let socket = dir.join(format!("{name}.sock"));
        let err = dir.join(format!("{name}.err"));
        let child = Command::new(CLIPMAPD)
            .arg(ct)
            .args(["--tick-hz", "60", "--name", name, "--shm-dir", dir.to_str().unwrap(), "--socket"])
            .arg(&socket)
            .envs(envs.iter().map(|(k, v)| (k.as_str(), v.as_str())))
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&err).unwrap())
            .spawn()
            .unwrap();
        let mut s = Service { child, socket, err };
        let t = Instant::now();
        loop {
            if let Ok(r) = s.try_ask("PING") {
                if r.starts_with("OK pong") {
                    return s;
                }
            }
            if let Ok(Some(st)) = s.child.try_wait() {
                panic!("clipmapd exited ({st}):\n{}", s.log());
            }
            assert!(t.elapsed() < Duration::from_secs(30), "the service did not come up:\n{}", s.log());
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.err).unwrap_or_default()
    }

    fn try_ask(&self, line: &str) -> std::io::Result<String> {
        let mut s = UnixStream::connect(&self.socket)?;
        s.set_read_timeout(Some(Duration::from_secs(10)))?;
        writeln!(s, "{line}")?;
        let mut reply = String::new();
        BufReader::new(s).read_line(&mut reply)?;
        Ok(reply.trim_end().to_string())
    }

    fn stats(&self) -> serde_json::Value {
        let r = self.try_ask("STATS").unwrap();
        serde_json::from_str(r.strip_prefix("OK ").unwrap_or_else(|| panic!("{r}"))).unwrap()
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Runs a driving reader for `seconds`; returns (passed, failed) texel counts.
fn read_service(dir: &Path, name: &str, seconds: u32) -> (u64, u64, Output) {
    let out = Command::new(READER)
        .args(["--name", name, "--shm-dir", dir.to_str().unwrap(), "--drive", "--seconds", &seconds.to_string()])
        .args(["--reads", "1000000000000"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let line = stdout
        .lines()
        .find(|l| l.contains(" passed, "))
        .unwrap_or_else(|| panic!("no counts from the reader:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr)));
    let mut w = line.split_whitespace();
    let passed = w.next().unwrap().parse().unwrap();
    let failed = w.nth(1).unwrap().parse().unwrap();
    (passed, failed, out)
}

#[test]
fn remote_names_are_kept_as_written_and_strict_validation_calls_them_an_extension() {
    let fx = crate::common::Fixture::new();
    let text = NO_IC_CT.replace("tile_format t.%d", "tile_format http://127.0.0.1:9/tiles/t.%d");
    let ct = fx.write("t.ct", &text);
    let l = plan::load_clip_texture(&ct, &crate::common::opts()).unwrap();
    let p = l.plan.as_ref().unwrap_or_else(|| panic!("{}", l.render()));
    let loc = p.locate(0, 3, 2).unwrap();
    assert_eq!(
        loc.path.remote().map(|r| r.as_str()),
        Some("http://127.0.0.1:9/tiles/t.4096.r2.c3.raw"),
        "not anchored to the .ct's directory"
    );
    let d = crate::common::expect(
        &l.diagnostics,
        "remote-location",
        clipmap::config::Severity::Note,
        Some((7, 13)),
        &["remote location", "extension", "Performer"],
    );
    assert!(d.portability);
    let (out, desc) = exec(fx.dir.path(), CLIPTEX, &["validate", "--strict", ct.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1), "--strict refuses the extension:\n{desc}");
    assert!(desc.contains("is a remote location, an extension") && desc.matches("7:13").count() == 1, "{desc}");
    let (out, desc) = exec(fx.dir.path(), CLIPTEX, &["validate", ct.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "without --strict it is a note:\n{desc}");

    // Stream servers and tile bases may be URLs too; an .ic file may not.
    let ic = "ic_version2.0\next_format PFTEX_PACK_8\nint_format PFTEX_RGB_8\nimg_format PFTEX_RGB\nicache_size 1024 1024 1\ntile_size 256 256 1\ntex_region_size 512 512 1\ntile_base s3://bucket/tiles/\ns_stream http://a:1/ http://b:2/\n";
    let (plan_ic, d) = crate::common::ic_ok(ic);
    assert_eq!(d.items.iter().filter(|x| x.code == "remote-location").count(), 3, "{}", crate::common::listing(&d));
    assert_eq!(
        plan_ic.locate(1, 0, 0).unwrap().path.to_string(),
        "http://b:2/s3://bucket/tiles/.1024.r000.c001.raw888"
    );
    assert!(plan_ic.locate(1, 0, 0).unwrap().path.remote().is_some() && plan_ic.names_remote());
    let ct = "ct_version2.0\next_format PFTEX_PACK_8\nint_format PFTEX_RGB_8\nimg_format PFTEX_RGB\nvirt_size 4096 4096 1\nclip_size 512\nicache_format http://h/l%d.ic\nicache_params PFCLIPTEX_FNAMEARG_LEVEL\n";
    let d = crate::common::ct_err(ct);
    crate::common::expect(&d, "remote-icache-file", clipmap::config::Severity::Error, Some((7, 15)), &["local"]);
}

#[test]
fn nginx_serves_a_prepared_pyramid_by_byte_ranges_and_adjacent_ranges_are_merged() {
    let dir = tempfile::tempdir().unwrap();
    // Four tiles to a file along S and T: tiles are byte ranges of shared files.
    let pyr = prepare(&dir.path().join("pyr"), 1024, 64, 128, &["--tiles-per-file", "4x4"]);
    let nginx = Nginx::serve(&pyr);
    let ct = point_config_at(&pyr, &dir.path().join("cfg"), &nginx.url(), &[]);
    let opts = RemoteOptions { in_flight: 1, ..quick_opts() };
    let src = RemoteSource::new(load(&ct), &Limits::default(), opts).unwrap();
    assert_eq!(src.endpoints(), [format!("http://127.0.0.1:{}", nginx.port)]);
    let tiles = every_tile(&src);
    // Eight readers taking neighbouring tiles in turn, and one request slot: ranges of one
    // file line up behind the slot and are merged.
    std::thread::scope(|s| {
        for j in 0..8 {
            let (src, tiles) = (&src, &tiles);
            s.spawn(move || {
                for &id in tiles.iter().skip(j).step_by(8) {
                    read_checked(src, id).unwrap_or_else(|e| panic!("{id}: {e}"));
                }
            });
        }
    });
    let st = src.stats();
    assert!(st.merged > 0, "adjacent ranges waiting together are merged: {st:?}");
    assert!(st.requests < tiles.len() as u64, "fewer requests than tiles: {st:?} for {} tiles", tiles.len());
    assert_eq!((st.failures, st.retries), (0, 0), "{st:?}");
    assert_eq!(st.peak_in_flight, 1, "the endpoint's bound holds: {st:?}");
}

#[test]
fn each_fault_ends_in_a_retry_a_missing_tile_or_an_error_never_in_wrong_texels() {
    let dir = tempfile::tempdir().unwrap();
    let pyr = prepare(&dir.path().join("pyr"), 256, 64, 64, &[]);
    let nginx = Nginx::serve(&pyr);
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let ct = point_config_at(&pyr, &dir.path().join("cfg"), &proxy.url(), &[]);
    let src = RemoteSource::new(
        load(&ct),
        &Limits::default(),
        RemoteOptions { timeout: Duration::from_millis(400), ..quick_opts() },
    )
    .unwrap();
    let id = TileId::new(0, 1, 2);
    let once = |f: Fault| Schedule { faults: vec![f], then: Vec::new(), every: 0 };
    for fault in [
        Fault::ServerError,
        Fault::Unavailable,
        Fault::Slow(1500),
        Fault::Reset,
        Fault::Truncate,
        Fault::LongLength,
        Fault::ShortLength,
    ] {
        let before = src.stats();
        proxy.set(once(fault));
        read_checked(&src, id).unwrap_or_else(|e| panic!("{fault:?} once, then healthy: {e}"));
        let after = src.stats();
        assert_eq!(after.retries - before.retries, 1, "{fault:?}: one retry: {after:?}");
    }
    // A 404 is final: the tile is missing (no default tile here), nothing is retried.
    let before = src.stats();
    proxy.set(once(Fault::NotFound));
    assert!(matches!(read_checked(&src, id), Err(SourceError::Missing { .. })));
    assert_eq!(src.stats().retries, before.retries);
    // A fault on every attempt: an error after the retries, never bytes.
    for fault in [Fault::Truncate, Fault::ShortLength, Fault::Unavailable, Fault::Slow(1000)] {
        let before = src.stats();
        proxy.set(Schedule { faults: Vec::new(), then: vec![fault], every: 1 });
        let e = read_checked(&src, id).expect_err("every attempt fails");
        assert!(matches!(e, SourceError::Io { .. }), "{fault:?}: {e}");
        assert_eq!(src.stats().retries - before.retries, 3, "{fault:?}: all retries used");
        if let Fault::Slow(_) = fault {
            assert!(e.to_string().contains("timed out"), "{e}");
        }
    }
    proxy.set(Schedule::pass());
    read_checked(&src, id).unwrap();
    let injected = proxy.injected.lock().unwrap().len();
    assert!(injected >= 8 + 4 * 4, "{injected} faults injected");
}

#[test]
fn a_service_behind_a_faulty_proxy_and_a_healthy_endpoint_serves_only_right_texels_and_keeps_ticking() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pyr = prepare(&d.join("pyr"), 4096, 64, 256, &["--streams", "2"]);
    let nginx = Nginx::serve(&pyr);
    // Stream server 0 through a proxy that breaks every third request (every kind of fault in
    // turn), stream server 1 straight to nginx: two endpoints, two read queues.
    let faults = vec![
        Fault::NotFound,
        Fault::ServerError,
        Fault::Unavailable,
        Fault::Slow(700),
        Fault::Reset,
        Fault::Truncate,
        Fault::LongLength,
        Fault::ShortLength,
    ];
    let proxy = FaultProxy::start(nginx.port, Schedule { faults: Vec::new(), then: faults, every: 3 }, 0);
    let ct = point_config_at(&pyr, &d.join("cfg"), &nginx.url(), &[proxy.url(), nginx.url()]);
    let envs: Vec<(String, String)> = [
        ("CLIPMAP_REMOTE_TIMEOUT_MS", "300"),
        ("CLIPMAP_REMOTE_RETRIES", "2"),
        ("CLIPMAP_REMOTE_BACKOFF_MS", "2"),
        ("CLIPMAP_REMOTE_BACKOFF_MAX_MS", "30"),
    ]
    .iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    let svc = Service::start(d, "faulty", &ct, &envs);
    let before = svc.stats();
    let (passed, failed, out) = read_service(d, "faulty", 3);
    assert_eq!(failed, 0, "{}\n{}", String::from_utf8_lossy(&out.stderr), svc.log());
    assert!(passed > 10_000, "{passed} texels checked");
    let after = svc.stats();
    let ticks = |v: &serde_json::Value| v["engine"]["ticks"].as_u64().unwrap();
    assert!(ticks(&after) > ticks(&before) + 60, "the tick goes on: {before}\n{after}");
    let streams = after["streams"].as_array().unwrap();
    assert_eq!(streams.len(), 2, "one read queue per endpoint: {after}");
    for q in streams {
        assert!(q["reads_done"].as_u64().unwrap() > 0, "both endpoints read: {after}");
    }
    assert!(proxy.injected.lock().unwrap().len() >= 8, "faults were injected: {:?}", proxy.injected.lock().unwrap());
}

#[test]
fn cliptex_check_over_http_gives_the_local_table() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pyr = prepare(&d.join("pyr"), 512, 64, 128, &[]);
    // Damage: one tile gone, one cut short.
    std::fs::remove_file(pyr.join("L00/r001.c002.raw")).unwrap();
    let f = pyr.join("L00/r003.c003.raw");
    let len = std::fs::metadata(&f).unwrap().len();
    std::fs::OpenOptions::new().write(true).open(&f).unwrap().set_len(len / 2).unwrap();
    let nginx = Nginx::serve(&pyr);
    let ct = point_config_at(&pyr, &d.join("cfg"), &nginx.url(), &[]);
    let local_ct = pyr.join("pyr.ct");
    let check = |ct: &Path| {
        let (out, desc) =
            exec_bounded(d, CLIPTEX, &["check", ct.to_str().unwrap(), "--json"], &[], Duration::from_secs(60));
        assert_eq!(out.status.code(), Some(1), "some tiles cannot be served:\n{desc}");
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        (v["totals"].clone(), v["levels"].as_array().unwrap().len())
    };
    let (remote, levels) = check(&ct);
    assert_eq!(check(&local_ct), (remote.clone(), levels), "the same table, local or remote");
    assert_eq!((remote["missing"].as_u64(), remote["short"].as_u64()), (Some(1), Some(1)), "{remote}");
    let (out, desc) = exec(d, CLIPTEX, &["check", ct.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(desc.contains("Missing: http://127.0.0.1:") && desc.contains("Short: http://"), "{desc}");
}

#[test]
fn a_pyramid_uploaded_to_s3_by_clipprep_is_checked_and_served_to_two_services_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let moto = Moto::start();
    moto.create_bucket("tiles");
    let env = moto.env();
    let envs: Vec<(&str, &str)> = env.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    let cfg = d.join("cfg");
    let args = [
        "--source",
        "hash",
        "--size",
        "2048",
        "--tile",
        "64",
        "--clip",
        "256",
        "--format",
        "rgba8",
        "--json",
        "--out",
        "s3://tiles/pyr",
        "--config-out",
        cfg.to_str().unwrap(),
    ];
    let (out, desc) = exec_bounded(d, CLIPPREP, &args, &envs, Duration::from_secs(120));
    assert!(out.status.success(), "{desc}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["uploaded_files"].as_u64().unwrap() > 1000, "{v}");
    assert_eq!(v["location"], "s3://tiles/pyr");
    assert!(!desc.contains("testing-secret-never-printed"), "the secret is never printed:\n{desc}");
    let ct = cfg.join("pyr.ct");
    let (out, desc) = exec(d, CLIPTEX, &["validate", ct.to_str().unwrap()]);
    assert!(out.status.success() && !desc.contains(": warning:"), "the written configuration is clean:\n{desc}");
    let (out, desc) =
        exec_bounded(d, CLIPTEX, &["check", ct.to_str().unwrap(), "--json"], &envs, Duration::from_secs(120));
    assert!(out.status.success(), "every uploaded tile is there:\n{desc}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["totals"]["present"], report["totals"]["tiles"], "{report}");

    let a = Service::start(d, "s3a", &ct, &env);
    let b = Service::start(d, "s3b", &ct, &env);
    let (ra, rb) = std::thread::scope(|s| {
        let ra = s.spawn(|| read_service(d, "s3a", 3));
        let rb = s.spawn(|| read_service(d, "s3b", 3));
        (ra.join().unwrap(), rb.join().unwrap())
    });
    for (name, (passed, failed, out), svc) in [("s3a", ra, &a), ("s3b", rb, &b)] {
        assert_eq!(failed, 0, "{name}: {}\n{}", String::from_utf8_lossy(&out.stderr), svc.log());
        assert!(passed > 10_000, "{name}: {passed}");
        assert!(svc.stats()["engine"]["tiles_read"].as_u64().unwrap() > 0);
        assert!(!svc.log().contains("testing-secret-never-printed"), "{name} never logs the secret");
    }
}

#[test]
fn the_disk_cache_serves_tiles_after_a_restart_without_the_server() {
    let dir = tempfile::tempdir().unwrap();
    let pyr = prepare(&dir.path().join("pyr"), 256, 64, 64, &[]);
    let cache = dir.path().join("cache");
    let nginx = Nginx::serve(&pyr);
    let ct = point_config_at(&pyr, &dir.path().join("cfg"), &nginx.url(), &[]);
    let opts = RemoteOptions { cache_dir: Some(cache.clone()), ..quick_opts() };
    let first = RemoteSource::new(load(&ct), &Limits::default(), opts.clone()).unwrap();
    let tiles: Vec<TileId> = every_tile(&first).into_iter().filter(|t| t.level == 0).collect();
    for &id in &tiles {
        read_checked(&first, id).unwrap();
    }
    assert_eq!(first.stats().cache_hits, 0);
    drop(first);
    drop(nginx);
    // The pyramid's small levels are read at start-up by nobody: only level 0 is asked for.
    let second = RemoteSource::new(load(&ct), &Limits::default(), RemoteOptions { retries: 0, ..opts }).unwrap();
    for &id in &tiles {
        read_checked(&second, id).unwrap_or_else(|e| panic!("{id} from the cache: {e}"));
    }
    let st = second.stats();
    assert_eq!((st.cache_hits, st.requests), (tiles.len() as u64, 0), "{st:?}");
    // A tile not in the cache needs the server, which is gone: an error, not a stall.
    assert!(read_checked(&second, TileId::new(1, 0, 0)).is_err());
}

#[test]
fn s3_reads_through_a_faulty_proxy_are_retried_and_serve_only_right_texels() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let moto = Moto::start();
    moto.create_bucket("faulty");
    let cfg = d.join("cfg");
    let env = moto.env();
    let envs: Vec<(&str, &str)> = env.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    let args = [
        "--source",
        "hash",
        "--size",
        "1024",
        "--tile",
        "64",
        "--clip",
        "256",
        "--format",
        "rgba8",
        "--quiet",
        "--out",
        "s3://faulty/pyr",
        "--config-out",
        cfg.to_str().unwrap(),
    ];
    let (out, desc) = exec_bounded(d, CLIPPREP, &args, &envs, Duration::from_secs(120));
    assert!(out.status.success(), "{desc}");
    // Every fourth request to the store fails, each kind of fault in turn.
    let faults = vec![Fault::Unavailable, Fault::Reset, Fault::Truncate, Fault::ServerError, Fault::Slow(700)];
    let proxy = FaultProxy::start(moto.port, Schedule { faults: Vec::new(), then: faults, every: 4 }, 0);
    let mut env: Vec<(String, String)> = env.into_iter().filter(|(k, _)| k != "AWS_ENDPOINT_URL").collect();
    env.push(("AWS_ENDPOINT_URL".into(), proxy.url()));
    for (k, v) in [
        ("CLIPMAP_REMOTE_TIMEOUT_MS", "400"),
        ("CLIPMAP_REMOTE_BACKOFF_MS", "2"),
        ("CLIPMAP_REMOTE_BACKOFF_MAX_MS", "30"),
    ] {
        env.push((k.into(), v.into()));
    }
    let svc = Service::start(d, "s3faulty", &cfg.join("pyr.ct"), &env);
    let (passed, failed, out) = read_service(d, "s3faulty", 3);
    assert_eq!(failed, 0, "{}\n{}", String::from_utf8_lossy(&out.stderr), svc.log());
    assert!(passed > 10_000, "{passed}");
    assert!(svc.stats()["engine"]["tiles_read"].as_u64().unwrap() > 0);
    assert!(proxy.injected.lock().unwrap().len() >= 5, "faults were injected: {:?}", proxy.injected.lock().unwrap());
}

#[test]
fn a_slow_endpoint_holds_back_only_its_own_read_queue() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pyr = prepare(&d.join("pyr"), 4096, 64, 256, &["--streams", "2"]);
    let nginx = Nginx::serve(&pyr);
    // Stream server 0 answers every request half a second late; stream server 1 at once.
    let slow = FaultProxy::start(nginx.port, Schedule::pass(), 500);
    let ct = point_config_at(&pyr, &d.join("cfg"), &nginx.url(), &[slow.url(), nginx.url()]);
    let svc = Service::start(d, "slowep", &ct, &[]);
    let (_, failed, out) = read_service(d, "slowep", 3);
    assert_eq!(failed, 0, "{}\n{}", String::from_utf8_lossy(&out.stderr), svc.log());
    let stats = svc.stats();
    let streams = stats["streams"].as_array().unwrap();
    assert_eq!(streams.len(), 2, "{stats}");
    let done = |i: usize| streams[i]["reads_done"].as_u64().unwrap();
    println!("reads done: slow endpoint {}, fast endpoint {}", done(0), done(1));
    // The slow queue keeps its reads in flight for 500 ms each; the other is not held: it reads
    // on at several times the slow one's pace (about 13 times here; 3 on a machine loaded far
    // beyond its cores; a queue held by the other would go at its pace, about 1).
    assert!(done(1) > 2 * done(0).max(1), "the fast endpoint's queue reads on: {stats}");
    assert!(done(0) > 0, "the slow endpoint is read too: {stats}");
}

#[test]
fn clipbench_remote_prints_its_contract_fields_and_reads_no_wrong_texel() {
    let dir = tempfile::tempdir().unwrap();
    // With a tail: a fifth of the delayed requests held 30 ms longer.
    let args = [
        "remote",
        "--smoke",
        "--json",
        "--tail-ms",
        "30",
        "--tail-percent",
        "20",
        "--dir",
        dir.path().to_str().unwrap(),
    ];
    let (out, desc) = exec_bounded(dir.path(), env!("CARGO_BIN_EXE_clipbench"), &args, &[], Duration::from_secs(300));
    assert_eq!(out.status.code(), Some(0), "{desc}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {desc}"));
    for key in ["tiles_per_s_local", "tiles_per_s_http", "tiles_per_s_s3", "in_flight", "wrong_texels"] {
        assert!(v.get(key).is_some_and(|x| x.is_number()), "`{key}` missing or not a number: {v}");
    }
    for key in ["tiles_per_s_local", "tiles_per_s_http", "tiles_per_s_s3"] {
        assert!(v[key].as_f64().unwrap() > 0.0, "{key}: {v}");
    }
    assert_eq!(v["wrong_texels"], 0, "{v}");
    assert_eq!(v["failed_reads"], 0, "{v}");
    assert!(v["in_flight"].as_u64().unwrap() >= 1, "{v}");
    // The real-time flight through the delaying proxy, every default.
    let f = &v["remote_flight"];
    assert_eq!(f["prefetch"], "adaptive", "{f}");
    let share = f["level0_shown_share"].as_f64().expect("remote_flight.level0_shown_share");
    assert!((0.0..=1.0).contains(&share), "{f}");
    assert!(f["texels_per_s"].as_f64().unwrap() > 0.0 && f["added_latency_ms"].as_u64().unwrap() > 0, "{f}");
    assert!(f["texels_checked"].as_u64().unwrap() > 0, "{f}");
    assert_eq!(f["wrong_texels"], 0, "{f}");
    // The time back to level 0 after a cold start and a jump, over HTTP, on local files and from
    // S3, and the requests in flight the source chose.
    for key in [
        "cold_start_to_level0_ms",
        "cold_start_to_level0_ms_local",
        "cold_start_to_level0_ms_s3",
        "jump_to_level0_ms",
        "jump_to_level0_ms_local",
        "jump_to_level0_ms_s3",
    ] {
        let ms = f[key].as_f64().unwrap_or_else(|| panic!("`{key}` missing: {f}"));
        assert!(ms > 0.0 && ms < 30_000.0, "{key}: level 0 is shown again: {f}");
    }
    assert!(f["in_flight_limit"].as_u64().unwrap() >= 16, "{f}");
    assert!(!f["in_flight_reason"].as_str().unwrap().is_empty(), "{f}");
    assert!((0.0..=0.05).contains(&f["hedged_share"].as_f64().unwrap()), "{f}");
    assert_eq!((f["tail_ms"].as_u64(), f["tail_share"].as_f64()), (Some(30), Some(0.2)), "{f}");
    assert!(f["tail_held_requests"].as_u64().unwrap() > 0, "the proxy held some requests longer: {f}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "the scratch directory is removed: {desc}");
}

#[test]
fn clipprep_uploads_with_http_put_and_the_tiles_are_read_back_by_ranged_gets() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let root = d.join("www");
    std::fs::create_dir_all(&root).unwrap();
    let nginx = Nginx::serve_writable(&root);
    let base = format!("{}/pyr", nginx.url());
    let cfg = d.join("cfg");
    let args = [
        "--source",
        "hash",
        "--size",
        "256",
        "--tile",
        "64",
        "--clip",
        "64",
        "--format",
        "rgba8",
        "--json",
        "--out",
        &base,
        "--config-out",
        cfg.to_str().unwrap(),
    ];
    let (out, desc) = exec_bounded(d, CLIPPREP, &args, &[], Duration::from_secs(120));
    assert!(out.status.success(), "{desc}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["location"], base.as_str(), "{v}");
    assert!(root.join("pyr/pyr.ct").is_file() && root.join("pyr/L00/r000.c000.raw").is_file(), "the files arrived");
    let src = RemoteSource::new(load(&cfg.join("pyr.ct")), &Limits::default(), quick_opts()).unwrap();
    for id in every_tile(&src) {
        read_checked(&src, id).unwrap_or_else(|e| panic!("{id}: {e}"));
    }
    assert_eq!(src.stats().failures, 0);
}

#[test]
fn a_remote_default_tile_stands_in_for_tiles_the_server_does_not_have() {
    let dir = tempfile::tempdir().unwrap();
    // A sparse pyramid: levels 0 and 1 exist only around the inset; each .ic names a default
    // tile, which the rewritten configuration reads from the server too.
    let pyr = prepare(&dir.path().join("pyr"), 2048, 64, 128, &["--inset", "1000,600,1200,700", "--inset-level", "2"]);
    let nginx = Nginx::serve(&pyr);
    let ct = point_config_at(&pyr, &dir.path().join("cfg"), &nginx.url(), &[]);
    let ic = std::fs::read_to_string(dir.path().join("cfg/L00.ic")).unwrap();
    assert!(ic.contains(&format!("default_tile {}/L00.default.raw", nginx.url())), "{ic}");
    let src = RemoteSource::new(load(&ct), &Limits::default(), quick_opts()).unwrap();
    assert!(src.files().has_default_tile(0), "read from the server at start-up");
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    // Far from the inset: absent on the server (404), served from the default tile.
    src.read_tile(TileId::new(0, 0, 0), &mut buf).unwrap();
    assert_eq!(buf, std::fs::read(pyr.join("L00.default.raw")).unwrap());
    assert_eq!(src.files().stats().default_tiles, 1);
    // Inside the inset: the tile itself.
    read_checked(&src, TileId::new(0, 1100 / 64, 650 / 64)).unwrap();
    assert_eq!(src.files().stats().default_tiles, 1);
}

#[test]
fn a_200_answer_with_an_html_error_page_to_a_ranged_get_is_refused_never_served_as_texels() {
    let dir = tempfile::tempdir().unwrap();
    // One tile to a file: a tile is the whole object, bytes 0 to 16383.
    let pyr = prepare(&dir.path().join("pyr"), 256, 64, 64, &[]);
    let nginx = Nginx::serve(&pyr);
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let ct = point_config_at(&pyr, &dir.path().join("cfg"), &proxy.url(), &[]);
    let src = RemoteSource::new(load(&ct), &Limits::default(), quick_opts()).unwrap();
    let id = TileId::new(0, 1, 2);
    let tile = src.desc().tile_bytes(0);
    let pages = [
        // Longer than the tile: its first bytes were served as texels.
        Fault::Page { len: tile + 3000, html: true },
        // The same, not called HTML: its length is not the object's (HEAD).
        Fault::Page { len: tile + 3000, html: false },
        // Exactly a tile long: its type gives it away.
        Fault::Page { len: tile, html: true },
        // Shorter than the tile: it was taken for a file cut short.
        Fault::Page { len: 300, html: false },
    ];
    for page in pages {
        let before = src.stats();
        proxy.set(Schedule { faults: vec![page], then: Vec::new(), every: 0 });
        read_checked(&src, id).unwrap_or_else(|e| panic!("{page:?} once, then a right answer: {e}"));
        assert_eq!(src.stats().retries - before.retries, 1, "{page:?}: refused and asked again");
    }
    for page in pages {
        let before = src.stats();
        proxy.set(Schedule { faults: Vec::new(), then: vec![page], every: 1 });
        let e = read_checked(&src, id).expect_err("every answer is a page");
        assert!(matches!(e, SourceError::Io { .. }), "{page:?}: a counted fault, not a short file: {e}");
        assert!(e.to_string().contains("HTTP 200"), "{page:?}: says what came: {e}");
        assert_eq!(src.stats().retries - before.retries, 3, "{page:?}: all retries used");
    }
    proxy.set(Schedule::pass());
    read_checked(&src, id).unwrap();
}

#[test]
fn a_206_answer_for_another_range_is_refused_and_a_whole_object_answer_is_cut_right() {
    let dir = tempfile::tempdir().unwrap();
    // Sixteen tiles to a file: tiles are byte ranges inside objects.
    let pyr = prepare(&dir.path().join("pyr"), 512, 64, 128, &["--tiles-per-file", "4x4"]);
    let nginx = Nginx::serve(&pyr);
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let ct = point_config_at(&pyr, &dir.path().join("cfg"), &proxy.url(), &[]);
    let src = RemoteSource::new(load(&ct), &Limits::default(), quick_opts()).unwrap();
    let id = TileId::new(0, 2, 3);
    let before = src.stats();
    proxy.set(Schedule { faults: vec![Fault::OtherRange], then: Vec::new(), every: 0 });
    read_checked(&src, id).unwrap_or_else(|e| panic!("another range once, then the right one: {e}"));
    assert_eq!(src.stats().retries - before.retries, 1);
    let before = src.stats();
    proxy.set(Schedule { faults: Vec::new(), then: vec![Fault::OtherRange], every: 1 });
    let e = read_checked(&src, id).expect_err("every answer is for another range");
    assert!(matches!(e, SourceError::Io { .. }) && e.to_string().contains("Content-Range"), "{e}");
    assert_eq!(src.stats().retries - before.retries, 3);
    // A server that ignores ranges: the whole object, checked against HEAD, then cut.
    let before = src.stats();
    proxy.set(Schedule { faults: Vec::new(), then: vec![Fault::IgnoreRange], every: 1 });
    for id in [TileId::new(0, 0, 0), TileId::new(0, 3, 1), TileId::new(0, 6, 7), TileId::new(1, 1, 2)] {
        read_checked(&src, id).unwrap_or_else(|e| panic!("{id} from a whole-object answer: {e}"));
    }
    assert_eq!(src.stats().retries, before.retries, "{:?}", src.stats());
}

/// A loopback server standing in for an S3 store: one object `s3://hostile/KIND` of 4096 bytes
/// (`i * 7 % 251`) for each kind of answer to a ranged GET: `right` (206, the range asked for),
/// `html` (200 and an error page), `other` (206 for the range one byte further on). Serves at
/// most `max` connections.
fn hostile_s3(max: usize) -> u16 {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    std::thread::spawn(move || {
        let object: Vec<u8> = (0..4096u32).map(|i| (i * 7 % 251) as u8).collect();
        for conn in listener.incoming().take(max) {
            let Ok(mut conn) = conn else { continue };
            conn.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            let head = request_head(&mut conn);
            let head = String::from_utf8_lossy(&head).to_ascii_lowercase();
            let path = head.split_whitespace().nth(1).unwrap_or("").to_string();
            let range = head.lines().find_map(|l| l.strip_prefix("range: bytes=")).and_then(|r| {
                let (a, b) = r.trim().split_once('-')?;
                Some((a.parse::<usize>().ok()?, b.parse::<usize>().ok()?))
            });
            let (a, b) = range.unwrap_or((0, object.len() - 1));
            let meta = "ETag: \"e1\"\r\nLast-Modified: Wed, 01 Jan 2025 00:00:00 GMT\r\nConnection: close\r\n";
            let answer = |status: &str, extra: String, body: &[u8]| {
                let mut v =
                    format!("HTTP/1.1 {status}\r\nContent-Length: {}\r\n{extra}{meta}\r\n", body.len()).into_bytes();
                v.extend_from_slice(body);
                v
            };
            let reply = if path.ends_with("/html") {
                let mut page = b"<html><body>503 Service Unavailable</body></html>".to_vec();
                page.resize(8192, b' ');
                answer("200 OK", "Content-Type: text/html\r\n".into(), &page)
            } else {
                let (a, b) = if path.ends_with("/other") { (a + 1, b + 1) } else { (a, b) };
                let b = b.min(object.len() - 1);
                answer(
                    "206 Partial Content",
                    format!("Content-Range: bytes {a}-{b}/{}\r\n", object.len()),
                    &object[a..=b],
                )
            };
            let _ = conn.write_all(&reply);
        }
    });
    port
}

#[test]
fn an_s3_answer_of_200_or_of_another_range_to_a_ranged_get_is_refused() {
    use clipmap::source::remote::{http::Http, s3::S3, Location, ReadError, Remote};
    use std::sync::Arc;
    let port = hostile_s3(64);
    let opts = RemoteOptions { retries: 1, ..quick_opts() };
    let vars = [
        ("AWS_ACCESS_KEY_ID", "testing-key-id"),
        ("AWS_SECRET_ACCESS_KEY", "testing-secret"),
        ("AWS_REGION", "us-east-1"),
        ("AWS_ENDPOINT_URL", &format!("http://127.0.0.1:{port}")),
    ]
    .iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    let remote = Remote::with_backends(opts.clone(), Arc::new(Http::new(&opts)), Arc::new(S3::with_vars(&opts, vars)));
    let read = |kind: &str| remote.fetcher().read(&Location::parse(&format!("s3://hostile/{kind}")).unwrap(), 100, 256);
    // The server is reached and a right answer is used: the refusals below are its answers'.
    let want: Vec<u8> = (100..356u32).map(|i| (i * 7 % 251) as u8).collect();
    assert_eq!(read("right").unwrap().to_bytes().as_ref(), want.as_slice());
    // object_store refuses a 200 to a ranged GET, and a Content-Range other than the one asked.
    match read("html") {
        Err(ReadError::Failed { why, .. }) => assert!(why.contains("non-partial response"), "{why}"),
        other => panic!("a 200 with a page is refused: {other:?}"),
    }
    match read("other") {
        Err(ReadError::Failed { why, .. }) => assert!(why.contains("Requested 100..356, got 101..357"), "{why}"),
        other => panic!("another range is refused: {other:?}"),
    }
}

/// The `.tile` files of a cache directory.
fn cache_files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "tile"))
        .collect();
    v.sort();
    v
}

/// Reads `ids` through a source with the disk cache `cache` (one at a time); returns each
/// tile's cache file, found as the file each read added.
fn cache_tiles(src: &RemoteSource, cache: &Path, ids: &[TileId]) -> Vec<PathBuf> {
    ids.iter()
        .map(|&id| {
            let before = cache_files(cache);
            read_checked(src, id).unwrap();
            let after = cache_files(cache);
            let new: Vec<PathBuf> = after.into_iter().filter(|p| !before.contains(p)).collect();
            assert_eq!(new.len(), 1, "{id}: one file cached");
            new[0].clone()
        })
        .collect()
}

/// Runs `f` on another thread and waits for it at most `limit`: a read that hangs fails the
/// test instead of hanging it.
fn bounded<T: Send + 'static>(limit: Duration, what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(limit).unwrap_or_else(|_| panic!("{what} did not end within {limit:?}"))
}

/// Replaces the cache files of tiles 0 to 2 with a FIFO, a link to `/dev/zero` and a link to
/// tile 3's file (a regular file and a valid entry, of another range).
fn plant_in_cache(files: &[PathBuf]) {
    std::fs::remove_file(&files[0]).unwrap();
    rustix::fs::mkfifoat(rustix::fs::CWD, &files[0], rustix::fs::Mode::from_raw_mode(0o600)).unwrap();
    std::fs::remove_file(&files[1]).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &files[1]).unwrap();
    std::fs::remove_file(&files[2]).unwrap();
    std::os::unix::fs::symlink(&files[3], &files[2]).unwrap();
}

#[test]
fn cached_tiles_replaced_by_a_fifo_or_links_to_dev_zero_are_dropped_and_read_again_without_hanging() {
    let dir = tempfile::tempdir().unwrap();
    let pyr = prepare(&dir.path().join("pyr"), 256, 64, 64, &[]);
    let cache = dir.path().join("cache");
    let nginx = Nginx::serve(&pyr);
    let ct = point_config_at(&pyr, &dir.path().join("cfg"), &nginx.url(), &[]);
    let opts = RemoteOptions { cache_dir: Some(cache.clone()), ..quick_opts() };
    let ids = [TileId::new(0, 0, 0), TileId::new(0, 1, 0), TileId::new(0, 2, 0), TileId::new(0, 3, 0)];
    let src = RemoteSource::new(load(&ct), &Limits::default(), opts.clone()).unwrap();
    let files = cache_tiles(&src, &cache, &ids);
    // Under a running source. The FIFO is read first: before the fix its read hung for good
    // (and the link to /dev/zero grew memory without bound).
    plant_in_cache(&files);
    let read_all = move |src: RemoteSource| {
        for id in ids {
            read_checked(&src, id).unwrap_or_else(|e| panic!("{id}: {e}"));
        }
        src
    };
    let src = bounded(Duration::from_secs(20), "reading the tiles over a hostile cache", move || read_all(src));
    let st = src.stats();
    assert_eq!((st.cache_dropped, st.cache_hits, st.requests), (3, 1, 7), "three dropped and read again: {st:?}");
    // Replaced by what was read again: a regular file each, served from now on.
    for f in &files[..3] {
        let m = std::fs::symlink_metadata(f).unwrap();
        assert!(m.file_type().is_file(), "{}: {m:?}", f.display());
    }
    let src = read_all(src);
    assert_eq!(src.stats().cache_hits, 5, "{:?}", src.stats());
    drop(src);
    // Planted while no source runs: dropped when the cache is opened.
    plant_in_cache(&files);
    let src = RemoteSource::new(load(&ct), &Limits::default(), opts).unwrap();
    assert_eq!(src.stats().cache_dropped, 3, "{:?}", src.stats());
    let src = bounded(Duration::from_secs(20), "reading the tiles after a reopen", move || read_all(src));
    let st = src.stats();
    assert_eq!((st.cache_dropped, st.cache_hits, st.requests), (3, 1, 3), "{st:?}");
    for f in &files[..3] {
        assert!(std::fs::symlink_metadata(f).unwrap().file_type().is_file(), "{}", f.display());
    }
}

#[test]
fn a_cached_tile_with_altered_bytes_of_the_same_length_is_dropped_and_read_again() {
    let dir = tempfile::tempdir().unwrap();
    let pyr = prepare(&dir.path().join("pyr"), 256, 64, 64, &[]);
    let cache = dir.path().join("cache");
    let nginx = Nginx::serve(&pyr);
    let ct = point_config_at(&pyr, &dir.path().join("cfg"), &nginx.url(), &[]);
    let opts = RemoteOptions { cache_dir: Some(cache.clone()), ..quick_opts() };
    let id = TileId::new(0, 2, 1);
    let src = RemoteSource::new(load(&ct), &Limits::default(), opts).unwrap();
    let file = cache_tiles(&src, &cache, &[id]).remove(0);
    read_checked(&src, id).unwrap();
    assert_eq!(src.stats().cache_hits, 1);
    // One texel changed in place: same length, same key.
    let mut bytes = std::fs::read(&file).unwrap();
    let at = bytes.len() - 5;
    bytes[at] ^= 0x40;
    std::fs::write(&file, &bytes).unwrap();
    let before = src.stats();
    read_checked(&src, id).unwrap_or_else(|e| panic!("read again from the server: {e}"));
    let st = src.stats();
    assert_eq!((st.cache_dropped, st.cache_hits, st.requests - before.requests), (1, 1, 1), "{st:?}");
    // The entry read again is good.
    read_checked(&src, id).unwrap();
    assert_eq!(src.stats().cache_hits, 2);
}

#[test]
fn cache_temporaries_are_created_exclusively_and_a_link_planted_at_their_name_is_never_written_through() {
    use clipmap::source::remote::disk::{key, DiskCache};
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let victim = dir.path().join("victim");
    std::fs::write(&victim, b"the victim's own bytes").unwrap();
    let c = DiskCache::open(&cache, 1 << 20).unwrap();
    let k = key("http://127.0.0.1:9/t.raw", 0, 100);
    c.put(&k, &[1u8; 100]);
    let entry = cache_files(&cache).remove(0);
    // The next temporary names this process would use, each a link to the victim.
    let pid = std::process::id();
    for n in 1..5 {
        let name = format!("{}.tmp.{pid}.{n}", entry.file_name().unwrap().to_str().unwrap());
        std::os::unix::fs::symlink(&victim, cache.join(name)).unwrap();
    }
    c.put(&k, &[2u8; 100]);
    assert_eq!(std::fs::read(&victim).unwrap(), b"the victim's own bytes", "never written through a link");
    let m = std::fs::symlink_metadata(&entry).unwrap();
    assert!(m.file_type().is_file(), "the entry is a file of its own, not a link: {m:?}");
    let mut out = [0u8; 100];
    assert!(c.get(&k, &mut out) && out == [2u8; 100], "stored under a name no one had");
    assert_eq!(c.dropped(), 0);
}

#[test]
fn a_service_behind_a_delaying_proxy_shows_coarser_levels_only_right_texels_and_says_source_bound() {
    use crate::common::flight::{all_at_rest, fly, reason, wait_stats, Control};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pyr = prepare(&d.join("pyr"), 4096, 64, 256, &[]);
    let nginx = Nginx::serve(&pyr);
    // Every tile request waits 60 ms in the proxy, and at most 4 are in flight (a store that
    // allows no more, as the cap says): about 66 tiles a second, a link far slower than the
    // flight below asks for. (Without the cap the source sizes its requests in flight to the
    // rate and keeps level 0 whole on most of this flight.)
    let slow = FaultProxy::start(nginx.port, Schedule::pass(), 60);
    let ct = point_config_at(&pyr, &d.join("cfg"), &slow.url(), &[]);
    let svc = Service::start(d, "link", &ct, &[("CLIPMAP_REMOTE_IN_FLIGHT".into(), "4".into())]);
    let mut c = Control::open(&svc.socket);
    let (st, ok) =
        wait_stats(&mut c, Duration::from_secs(30), |st| st["min_lod"].as_f64() == Some(0.0) && all_at_rest(st));
    assert!(ok, "at rest, before the flight: every level hovers, level 0 shown\n{st}\n{}", svc.log());
    let reader = Command::new(READER)
        .args(["--name", "link", "--shm-dir", d.to_str().unwrap(), "--seconds", "4", "--reads", "1000000000000"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (mut bound, mut coarse, mut samples) = (0u32, 0u32, 0u32);
    let mut seen = std::collections::BTreeMap::<String, u32>::new();
    // 3000 texels a second (50 level-0 texels a tick at 60 ticks a second), back and forth.
    fly(&mut c, 2048, (512, 3584), 3000.0, 3.0, 8, |st, flown| {
        if flown < 0.3 {
            return;
        }
        samples += 1;
        let r = reason(st, 0);
        *seen.entry(r.clone()).or_default() += 1;
        bound += u32::from(r == "source_bound");
        coarse += u32::from(st["min_lod"].as_f64().unwrap() > 0.0);
    });
    eprintln!("level 0 reasons over {samples} samples: {seen:?}; min LOD above 0 in {coarse}");
    assert!(bound * 2 > samples, "level 0 is source-bound on most of the flight: {seen:?}");
    assert!(coarse * 2 > samples, "coarser levels are shown on most of the flight: {coarse} of {samples}");
    let (st, ok) =
        wait_stats(&mut c, Duration::from_secs(30), |st| st["min_lod"].as_f64() == Some(0.0) && all_at_rest(st));
    assert!(ok, "at rest again: every level hovers and level 0 is shown again\n{st}");
    let out = reader.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout.lines().find(|l| l.contains(" passed, ")).unwrap_or_else(|| panic!("no counts: {stdout}"));
    let mut w = line.split_whitespace();
    let (passed, failed): (u64, u64) = (w.next().unwrap().parse().unwrap(), w.nth(1).unwrap().parse().unwrap());
    assert_eq!(failed, 0, "{}\n{}", String::from_utf8_lossy(&out.stderr), svc.log());
    assert!(passed > 10_000, "only {passed} texels checked");
    assert!(slow.requests.load(std::sync::atomic::Ordering::SeqCst) > 0, "the tiles came through the proxy");
}

/// The head of one request on `conn`, read byte by byte up to its blank line (at most 64 KiB; less
/// when the client stops).
fn request_head(conn: &mut std::net::TcpStream) -> Vec<u8> {
    use std::io::Read;
    let mut head = Vec::new();
    let mut byte = [0u8; 1];
    while !head.ends_with(b"\r\n\r\n") && head.len() < 65536 {
        match conn.read(&mut byte) {
            Ok(1) => head.push(byte[0]),
            _ => break,
        }
    }
    head
}

/// A server that answers every request `403 Forbidden` with a short reason; returns its port.
fn forbidding_server() -> u16 {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            let Ok(mut conn) = conn else { continue };
            conn.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            request_head(&mut conn);
            let body = "AccessDenied";
            let reply =
                format!("HTTP/1.1 403 Forbidden\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}", body.len());
            let _ = conn.write_all(reply.as_bytes());
        }
    });
    port
}

#[test]
fn cliptex_check_keeps_the_remote_error_of_an_unreadable_tile() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pyr = prepare(&d.join("pyr"), 512, 64, 128, &[]);
    let port = forbidding_server();
    let ct = point_config_at(&pyr, &d.join("cfg"), &format!("http://127.0.0.1:{port}"), &[]);
    let (out, desc) =
        exec_bounded(d, CLIPTEX, &["check", ct.to_str().unwrap(), "--json"], &[], Duration::from_secs(120));
    assert_eq!(out.status.code(), Some(1), "no tile can be served:\n{desc}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["totals"]["unreadable"].as_u64().unwrap() > 0, "{}", v["totals"]);
    let first = &v["problems"][0];
    assert_eq!(first["problem"], "unreadable", "{first}");
    let detail = first["detail"].as_str().unwrap_or_default();
    assert!(detail.contains("403"), "the store's answer is kept, not only 'unreadable': {first}");
    let (out, desc) = exec_bounded(d, CLIPTEX, &["check", ct.to_str().unwrap()], &[], Duration::from_secs(120));
    assert_eq!(out.status.code(), Some(1));
    assert!(desc.contains("403"), "the table's problem list says why too:\n{desc}");
}
