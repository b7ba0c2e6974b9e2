//! PMTiles archives of the reference Python writer (`write_pmtiles.py`).

use crate::common::remote::{FaultProxy, Moto, Nginx, Schedule};
use clipmap::place::{Place, RemoteName};
use clipmap::source::remote::http::Http;
use clipmap::source::remote::s3::S3;
use clipmap::source::remote::{Remote, RemoteOptions};
use clipmap::source::tiles::pmtiles::{PmtilesArchive, OPEN_BYTES};
use clipmap::source::tiles::{Fetched, TileAddr, TileArchive};
use std::collections::HashMap;
use std::path::Path;
use std::process::Command;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A tile the writer wrote, and its bytes.
type Tiles = Vec<(TileAddr, Vec<u8>)>;

/// A run of equal tiles: first tile id, how many, their bytes.
type Run = (u64, u64, Vec<u8>);

/// Writes the archives into `dir` with the reference writer.
fn write_archives(dir: &Path) {
    let script = Path::new(env!("CLIPMAP_ROOT")).join("tests/it/tiles_archives/write_pmtiles.py");
    let python = ["python3", "/usr/bin/python3"]
        .into_iter()
        .find(|p| Command::new(p).args(["-c", "import pmtiles"]).output().is_ok_and(|o| o.status.success()))
        .expect("the reference PMTiles writer is needed for this test: pip install pmtiles (.ci/run does it)");
    let out = Command::new(python).arg(&script).arg(dir).output().unwrap();
    assert!(out.status.success(), "write_pmtiles.py failed: {}", String::from_utf8_lossy(&out.stderr));
}

fn le32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

/// The tiles `NAME.manifest` lists, in the order written (increasing tile id).
fn manifest(dir: &Path, name: &str) -> Tiles {
    let b = std::fs::read(dir.join(format!("{name}.manifest"))).unwrap();
    let (mut at, mut out) = (0, Vec::new());
    while at < b.len() {
        let a = TileAddr { z: b[at], x: le32(&b, at + 1), y: le32(&b, at + 5) };
        let len = le32(&b, at + 9) as usize;
        out.push((a, b[at + 13..at + 13 + len].to_vec()));
        at += 13 + len;
    }
    out
}

/// The runs `NAME.runs` lists.
fn runs(dir: &Path, name: &str) -> Vec<Run> {
    let b = std::fs::read(dir.join(format!("{name}.runs"))).unwrap();
    let (mut at, mut out) = (0, Vec::new());
    while at < b.len() {
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap());
        let (first, n, len) = (u64_at(at), u64_at(at + 8), le32(&b, at + 16) as usize);
        out.push((first, n, b[at + 20..at + 20 + len].to_vec()));
        at += 20 + len;
    }
    out
}

/// The address of PMTiles tile id `id` (the archive's own conversion is tested against the
/// Hilbert curve in its unit tests; here the writer's ids meet ours).
fn addr(id: u64) -> TileAddr {
    clipmap::source::tiles::pmtiles::directory::tile_addr(id).unwrap()
}

/// Every `step`-th written tile reads back as written; the first, middle and last tile of each
/// run too; the tile after each checked one is missing unless written.
fn assert_tiles(a: &dyn TileArchive, tiles: &Tiles, runs: &[Run], step: usize, ctx: &str) {
    let written: HashMap<TileAddr, &[u8]> = tiles.iter().map(|(a, b)| (*a, b.as_slice())).collect();
    let in_run = |id: u64| runs.iter().any(|(f, n, _)| (*f..f + n).contains(&id));
    let id = clipmap::source::tiles::pmtiles::directory::tile_id;
    let mut missing = 0;
    for (at, bytes) in tiles.iter().step_by(step) {
        assert_eq!(a.fetch(*at).unwrap(), Fetched::Tile(bytes.clone()), "{ctx}: tile {at}");
        let next = id(*at) + 1;
        let next_at = addr(next);
        if !written.contains_key(&next_at) && !in_run(next) && next_at.z <= a.info().max_zoom {
            assert_eq!(a.fetch(next_at).unwrap(), Fetched::Missing, "{ctx}: tile {next_at}");
            missing += 1;
        }
    }
    for (first, n, bytes) in runs {
        for k in [0, n / 2, n - 1] {
            assert_eq!(a.fetch(addr(first + k)).unwrap(), Fetched::Tile(bytes.clone()), "{ctx}: run at {first} + {k}");
        }
        let after = first + n;
        if !written.contains_key(&addr(after)) && !in_run(after) {
            assert_eq!(a.fetch(addr(after)).unwrap(), Fetched::Missing, "{ctx}: after the run at {first}");
        }
    }
    assert!(missing > 0 || step > tiles.len(), "{ctx}: no absent tile was asked for");
}

/// Short timeouts and backoffs, so that faults resolve quickly.
fn remote(env: &[(String, String)]) -> Arc<Remote> {
    let opts = RemoteOptions {
        timeout: Duration::from_millis(3000),
        connect_timeout: Duration::from_millis(500),
        retries: 3,
        backoff: Duration::from_millis(2),
        backoff_max: Duration::from_millis(40),
        ..RemoteOptions::default()
    };
    let http = Arc::new(Http::new(&opts));
    let s3 = Arc::new(S3::with_vars(&opts, env.to_vec()));
    Arc::new(Remote::with_backends(opts, http, s3))
}

fn open_remote(url: &str, remote: &Arc<Remote>) -> PmtilesArchive {
    let (bytes, first) =
        clipmap::source::remote::range::open_with(&RemoteName::parse(url).unwrap(), Arc::clone(remote), OPEN_BYTES)
            .unwrap_or_else(|e| panic!("{url}: {e}"));
    PmtilesArchive::from_reader(url.to_string(), bytes, &first).unwrap_or_else(|e| panic!("{e}"))
}

const NAMES: [&str; 4] = ["small.pmtiles", "gzip.pmtiles", "leaves.pmtiles", "planet.pmtiles"];

#[test]
fn pmtiles_of_the_reference_writer_read_back_as_written_locally_over_nginx_and_from_s3() {
    let dir = tempfile::tempdir().unwrap();
    write_archives(dir.path());
    let nginx = Nginx::serve(dir.path());
    let moto = Moto::start();
    moto.create_bucket("tiles");
    let remote = remote(&moto.env());
    for name in NAMES {
        let (tiles, runs) = (manifest(dir.path(), name), runs(dir.path(), name));
        let local = PmtilesArchive::open(&Place::Local(dir.path().join(name))).unwrap();
        let zooms = tiles.iter().map(|t| t.0.z).chain(runs.iter().map(|r| addr(r.0).z));
        let (lo, hi) = (zooms.clone().min().unwrap(), zooms.max().unwrap());
        assert_eq!((local.info().min_zoom, local.info().max_zoom, local.info().bounds), (lo, hi, None), "{name}");
        assert_tiles(&local, &tiles, &runs, 1, &format!("{name} (local)"));
        if name != "small.pmtiles" {
            let leaves = local.header().leaves.1;
            assert_eq!(leaves > 0, name != "gzip.pmtiles", "{name}: leaf directories of {leaves} bytes");
        }
        let s3 = format!("s3://tiles/{name}");
        remote.put(&s3, std::fs::read(dir.path().join(name)).unwrap().into()).unwrap();
        // Remote: every tile of the small archives, a sample of the large ones.
        let step = if tiles.len() > 1000 { 97 } else { 1 };
        for url in [format!("{}/{name}", nginx.url()), s3] {
            let a = open_remote(&url, &remote);
            assert_tiles(&a, &tiles, &runs, step, &url);
        }
    }
    // `open` itself, over HTTP with the environment's remote options.
    let url = format!("{}/small.pmtiles", nginx.url());
    let a = PmtilesArchive::open(&Place::parse(&url)).unwrap();
    assert_tiles(&a, &manifest(dir.path(), "small.pmtiles"), &runs(dir.path(), "small.pmtiles"), 1, &url);
    assert!(a.remote_stats().is_some_and(|s| s.requests > 1));
    assert_eq!(remote.stats().failures, 0);
}

#[test]
fn a_pmtiles_opens_with_one_request_of_16_kib_and_a_tile_in_a_leaf_costs_two_cold_then_one() {
    let dir = tempfile::tempdir().unwrap();
    write_archives(dir.path());
    let nginx = Nginx::serve(dir.path());
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let seen = || proxy.requests.load(Ordering::SeqCst);
    let mut opened = Vec::new();
    for name in NAMES {
        // Each archive through a reader of its own, so that its bytes are counted alone.
        let remote = remote(&[]);
        let before = seen();
        let start = Instant::now();
        let a = open_remote(&format!("{}/{name}", proxy.url()), &remote);
        let took = start.elapsed();
        assert_eq!(seen() - before, 1, "{name}: opening is one request at the server");
        let bytes = remote.stats().bytes;
        assert!(bytes <= 16384, "{name}: opening read {bytes} bytes");
        opened.push((name, a, remote, took, bytes));
    }
    for (name, a, _, took, bytes) in &opened {
        eprintln!(
            "{name}: opened in {:.2} ms, 1 request of {bytes} bytes; {} tiles addressed, {} entries",
            took.as_secs_f64() * 1e3,
            a.header().addressed_tiles,
            a.header().tile_entries
        );
    }
    // The sparse planet addresses millions of tiles in leaf directories, yet opens as the small one.
    let planet = &opened[3].1;
    assert!(planet.header().addressed_tiles >= 3_000_000 && planet.header().leaves.1 > 0);
    assert_eq!((planet.info().min_zoom, planet.info().max_zoom), (0, 18));

    for (name, i) in [("leaves.pmtiles", 2), ("planet.pmtiles", 3)] {
        let a = &opened[i].1;
        let tiles = manifest(dir.path(), name);
        // Entries 100 and 101 of the writer's first leaf (4096 entries a leaf at least).
        let (first, second) = (&tiles[100], &tiles[101]);
        let before = seen();
        assert_eq!(a.fetch(first.0).unwrap(), Fetched::Tile(first.1.clone()));
        let cold = seen() - before;
        assert!((1..=2).contains(&cold), "{name}: a tile in a leaf cost {cold} requests cold");
        assert_eq!(cold, 2, "{name}: the leaf and the tile");
        let before = seen();
        assert_eq!(a.fetch(second.0).unwrap(), Fetched::Tile(second.1.clone()));
        assert_eq!(seen() - before, 1, "{name}: a tile of a cached leaf is one request");
        let before = seen();
        let gap = clipmap::source::tiles::pmtiles::directory::tile_id(first.0) + 1;
        if addr(gap) != second.0 {
            assert_eq!(a.fetch(addr(gap)).unwrap(), Fetched::Missing);
            assert_eq!(seen() - before, 0, "{name}: an absent tile of a cached leaf costs no request");
        }
        assert!(a.leaf_cache_bytes() > 0);
    }
    // A tile of a run of a million equal tiles, in the planet's deepest zoom.
    let run = runs(dir.path(), "planet.pmtiles")[1].clone();
    let before = seen();
    assert_eq!(planet.fetch(addr(run.0 + run.1 / 3)).unwrap(), Fetched::Tile(run.2));
    assert!(seen() - before <= 2);
}

#[test]
fn a_ct_naming_a_remote_pmtiles_opens_it_once_to_check_its_header_and_to_serve_it() {
    let dir = tempfile::tempdir().unwrap();
    write_archives(dir.path());
    let nginx = Nginx::serve(dir.path());
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let seen = || proxy.requests.load(Ordering::SeqCst);
    let url = format!("{}/small.pmtiles", proxy.url());
    let out = dir.path().join("cfg");
    let (o, _) = crate::common::exec(
        dir.path(),
        env!("CARGO_BIN_EXE_clipprep"),
        &["--input", &url, "--clip", "256", "--out", out.to_str().unwrap()],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ct = out.join("cfg.ct");
    assert!(std::fs::read_to_string(&ct).unwrap().contains(&format!("#clipmap source {url}")));

    // What opening the archive costs: its header and directory, and its first tile (PMTiles
    // does not record the tile size).
    let before = seen();
    let opts = clipmap::source::tiles::OpenOptions::default();
    drop(clipmap::source::tiles::open(&url, &opts).unwrap().unwrap());
    let open = seen() - before;
    assert_eq!(open, 2, "an open is the header's request and the first tile's");

    let before = seen();
    let loaded = clipmap::source::configured::load_clip_texture(&ct, &clipmap::plan::Options::default()).unwrap();
    assert!(!loaded.diagnostics.has_errors(), "{:?}", loaded.diagnostics);
    let plan = loaded.plan.expect("a plan");
    assert_eq!(seen() - before, open, "checking the .ct against the archive opens it once");
    let src = clipmap::source::open_plan(plan, &clipmap::limits::Limits::default()).unwrap();
    assert_eq!(seen() - before, open, "serving the archive the check opened costs no second open");
    assert_eq!(src.desc().size()[0], 256 * 8, "zooms 0..3 of 256-texel tiles");
}
