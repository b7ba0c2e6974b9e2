//! Faults between a tile service or archive and the reader: a proxy in front of nginx answering
//! `204`, empty bodies, `429` with `Retry-After`, resets in the middle of a body, truncated and
//! foreign bodies; archives (PMTiles over HTTP and on disk, MBTiles) replaced while they are
//! read. In every case each texel served is the peer's own decode of the tile at its place
//! (GDAL's, or the tree's own read without faults), a tile that cannot be had is missing or an
//! error naming it, every read ends in bounded time, and the provider's limits hold (requests in
//! flight counted at the proxy, `Retry-After` waited for).

use crate::common::remote::{Fault, FaultProxy, Nginx, Schedule};
use crate::tiles::{open, quick, run_python, trees, MAX_ZOOM};
use clipmap::source::remote::RemoteOptions;
use clipmap::source::tiles::{self, OpenOptions, PyramidOptions, PyramidSource, TemplateOptions};
use clipmap::source::{SourceError, TileId, TileSource};
use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

type Decoded = HashMap<(u8, u32, u32), Vec<u8>>;

/// What reading one texture tile of level 0 (one pyramid tile of zoom `MAX_ZOOM`) gave.
#[derive(Debug, PartialEq)]
enum Read {
    /// Its texels, equal to the expected decode.
    Right,
    /// Missing.
    Missing,
    /// An error (its text).
    Error(String),
}

/// Reads texture tile `(s, t)` of level `k` and compares it, texel for texel, with `want`'s decode
/// of the pyramid tile there (`k` < 3: one pyramid tile a texture tile). Panics on a wrong
/// texel.
fn read(src: &PyramidSource, k: u32, s: u64, t: u64, want: &Decoded, what: &str) -> Read {
    let z = MAX_ZOOM - k as u8;
    let n = 1u64 << z;
    let mut buf = vec![0u8; src.desc().tile_bytes(k)];
    match src.read_tile(TileId { level: k, s, t }, &mut buf) {
        Ok(()) => {
            let expected = &want[&(z, s as u32, (n - 1 - t) as u32)];
            let row = buf.len() / 256;
            for r in 0..256usize {
                assert!(
                    buf[r * row..(r + 1) * row] == expected[(255 - r) * row..(256 - r) * row],
                    "{what}: a wrong texel in level {k} tile ({s}, {t}) texture row {r}"
                );
            }
            Read::Right
        }
        Err(SourceError::Missing { .. }) => Read::Missing,
        Err(e) => Read::Error(e.to_string()),
    }
}

/// Every texture tile of levels 0..=MAX_ZOOM, read by `threads` threads at once.
fn read_all(src: &PyramidSource, want: &Decoded, threads: usize, what: &str) -> Vec<Read> {
    let mut jobs = Vec::new();
    for k in 0..=u32::from(MAX_ZOOM) {
        let n = 1u64 << (MAX_ZOOM - k as u8);
        for t in 0..n {
            for s in 0..n {
                jobs.push((k, s, t));
            }
        }
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let out = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|sc| {
        for _ in 0..threads {
            sc.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::SeqCst);
                let Some(&(k, s, t)) = jobs.get(i) else { break };
                let r = read(src, k, s, t, want, what);
                out.lock().unwrap().push(r);
            });
        }
    });
    out.into_inner().unwrap()
}

fn opts(remote: RemoteOptions) -> OpenOptions {
    OpenOptions {
        template: TemplateOptions { remote: Some(remote), zooms: Some([0, MAX_ZOOM]), ..Default::default() },
        pyramid: PyramidOptions { clip_size: Some(256), ..Default::default() },
    }
}

#[test]
fn a_204_storm_and_empty_bodies_are_missing_tiles_never_texels_nor_retries() {
    let dir = tempfile::tempdir().unwrap();
    let gdal = trees(dir.path());
    let nginx = Nginx::serve_images(dir.path());
    let storm = Schedule { faults: Vec::new(), then: vec![Fault::NoContent], every: 1 };
    let proxy = FaultProxy::start(nginx.port, storm, 0);
    let src = open(&format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", proxy.url()));
    let t0 = Instant::now();
    let reads = read_all(&src, &gdal, 4, "204 storm");
    assert!(reads.iter().all(|r| *r == Read::Missing), "{reads:?}");
    assert_eq!(reads.len(), 21);
    let stats = src.remote_stats().unwrap();
    assert_eq!((stats.requests, stats.retries, stats.failures), (21, 0, 0), "one request a tile: {stats:?}");
    drop(proxy);
    // 204s, empty 200s and right answers in turn: missing or GDAL's texels, nothing else.
    let mixed = Schedule { faults: Vec::new(), then: vec![Fault::NoContent, Fault::Pass, Fault::EmptyOk], every: 1 };
    let proxy = FaultProxy::start(nginx.port, mixed, 0);
    let src = open(&format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", proxy.url()));
    let reads = read_all(&src, &gdal, 4, "204 and empty bodies");
    let missing = reads.iter().filter(|r| **r == Read::Missing).count();
    let right = reads.iter().filter(|r| **r == Read::Right).count();
    assert_eq!((missing, right), (14, 7), "{reads:?}");
    assert_eq!(src.remote_stats().unwrap().retries, 0);
    assert!(t0.elapsed() < Duration::from_secs(30), "{:?}", t0.elapsed());
}

#[test]
fn a_429_storm_is_waited_out_as_retry_after_says_and_the_cap_on_requests_in_flight_holds() {
    let dir = tempfile::tempdir().unwrap();
    let gdal = trees(dir.path());
    let nginx = Nginx::serve_images(dir.path());
    // Every other request answered 429 with Retry-After: 1.
    let storm = Schedule { faults: Vec::new(), then: vec![Fault::TooMany], every: 2 };
    let proxy = FaultProxy::start(nginx.port, storm, 20);
    let remote = RemoteOptions { in_flight: 3, retries: 6, backoff_max: Duration::from_millis(1500), ..quick() };
    let src =
        tiles::open(&format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", proxy.url()), &opts(remote.clone())).unwrap().unwrap();
    let t0 = Instant::now();
    let reads = read_all(&src, &gdal, 8, "429 storm");
    let took = t0.elapsed();
    let right = reads.iter().filter(|r| **r == Read::Right).count();
    for r in &reads {
        if let Read::Error(e) = r {
            assert!(e.contains("429") && e.contains("tile "), "{e}");
        }
    }
    assert!(right >= 18, "most tiles are had after waiting: {reads:?}");
    // The provider's limits: never more than 3 requests at once, and no tile asked again
    // sooner than its Retry-After (1 s) after a 429.
    let peak = proxy.in_flight.peak.load(Ordering::SeqCst);
    assert!((1..=3).contains(&peak), "{peak} requests in flight at once at the proxy, 3 allowed");
    let seen = proxy.seen.lock().unwrap().clone();
    let mut last: HashMap<String, (Instant, Fault)> = HashMap::new();
    let mut waited = 0;
    for (at, path, fault) in &seen {
        if let Some((before, Fault::TooMany)) = last.get(path) {
            let gap = at.duration_since(*before);
            assert!(gap >= Duration::from_millis(990), "{path} asked again {gap:?} after a 429 with Retry-After: 1");
            waited += 1;
        }
        last.insert(path.clone(), (*at, *fault));
    }
    let stats = src.remote_stats().unwrap();
    assert!(waited >= 5 && stats.retries >= 5, "{waited} waits, {stats:?}");
    assert!(stats.peak_in_flight <= 3, "{stats:?}");
    // Bounded: 21 tiles, 3 at once, each waiting a second at most a few times.
    assert!(took < Duration::from_secs(40), "{took:?}");
    drop(proxy);
    // The rate limit is the host's: once a 429 was answered for one tile, a read of another
    // tile begun then waits out the same second before its request reaches the host.
    let first = Schedule { faults: vec![Fault::TooMany], then: Vec::new(), every: 0 };
    let proxy = FaultProxy::start(nginx.port, first, 0);
    let src = tiles::open(&format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", proxy.url()), &opts(remote)).unwrap().unwrap();
    std::thread::scope(|sc| {
        let first = sc.spawn(|| read(&src, 0, 0, 0, &gdal, "the tile answered 429"));
        // The retry is counted once the pause is set.
        while src.remote_stats().unwrap().retries == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(read(&src, 0, 1, 1, &gdal, "another tile"), Read::Right);
        assert_eq!(first.join().unwrap(), Read::Right);
    });
    let seen = proxy.seen.lock().unwrap().clone();
    assert_eq!(seen.len(), 3, "{seen:?}");
    assert_eq!(seen[0].2, Fault::TooMany);
    let other = seen.iter().find(|(_, path, _)| *path != seen[0].1).unwrap();
    let gap = other.0.duration_since(seen[0].0);
    assert!(
        gap >= Duration::from_millis(1000),
        "another tile's request reached the host {gap:?} after a 429 with Retry-After: 1"
    );
}

/// Makes a JPEG tree `jpg/{z}/{x}/{y}.jpg` of the XYZ tree's tiles (GDAL's JPEG driver).
fn jpeg_tree(dir: &Path) {
    let make = r#"
import os, sys
from osgeo import gdal
for z in range(int(sys.argv[1]) + 1):
    for x in range(2 ** z):
        os.makedirs(f'jpg/{z}/{x}', exist_ok=True)
        for y in range(2 ** z):
            gdal.Translate(f'jpg/{z}/{x}/{y}.jpg', f'xyz/{z}/{x}/{y}.png', format='JPEG', bandList=[1, 2, 3], creationOptions=['QUALITY=90'])
"#;
    run_python(make, dir, &[MAX_ZOOM.to_string()]);
    for f in walk(&dir.join("jpg")) {
        if f.extension().is_some_and(|e| e == "xml") {
            std::fs::remove_file(f).unwrap();
        }
    }
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// The tree's own decode of every tile, read from disk without faults (rows from the north,
/// as GDAL's decode is kept).
fn own_decode(src: &PyramidSource) -> Decoded {
    let mut out = HashMap::new();
    for k in 0..=u32::from(MAX_ZOOM) {
        let z = MAX_ZOOM - k as u8;
        let n = 1u64 << z;
        let mut buf = vec![0u8; src.desc().tile_bytes(k)];
        for t in 0..n {
            for s in 0..n {
                src.read_tile(TileId { level: k, s, t }, &mut buf).unwrap();
                let row = buf.len() / 256;
                let north: Vec<u8> = (0..256).rev().flat_map(|r| buf[r * row..(r + 1) * row].to_vec()).collect();
                out.insert((z, s as u32, (n - 1 - t) as u32), north);
            }
        }
    }
    out
}

#[test]
fn resets_mid_body_truncated_and_foreign_bodies_are_retried_or_errors_never_texels() {
    let dir = tempfile::tempdir().unwrap();
    let gdal = trees(dir.path());
    jpeg_tree(dir.path());
    let nginx = Nginx::serve_images(dir.path());
    let local_jpeg = open(&format!("xyz:{}/jpg/{{z}}/{{x}}/{{y}}.jpg", dir.path().display()));
    let jpeg = own_decode(&local_jpeg);
    let faults = vec![Fault::Truncate, Fault::Reset, Fault::HalfBody, Fault::Page { len: 700, html: false }];
    for (kind, ext, want) in [("xyz", "png", &gdal), ("jpg", "jpg", &jpeg)] {
        let schedule = Schedule { faults: Vec::new(), then: faults.clone(), every: 2 };
        let proxy = FaultProxy::start(nginx.port, schedule, 0);
        let remote = RemoteOptions { retries: 6, ..quick() };
        let src = tiles::open(&format!("xyz:{}/{kind}/{{z}}/{{x}}/{{y}}.{ext}", proxy.url()), &opts(remote))
            .unwrap()
            .unwrap();
        let t0 = Instant::now();
        let reads = read_all(&src, want, 4, kind);
        assert!(t0.elapsed() < Duration::from_secs(30), "{kind}: {:?}", t0.elapsed());
        let mut errors = 0;
        for r in &reads {
            match r {
                Read::Right => {}
                Read::Missing => panic!("{kind}: no tile is missing: {reads:?}"),
                Read::Error(e) => {
                    assert!(e.contains("tile "), "{kind}: {e}");
                    errors += 1;
                }
            }
        }
        let injected = proxy.injected.lock().unwrap().clone();
        let cut = injected.iter().filter(|f| **f == Fault::HalfBody).count();
        let pages = injected.iter().filter(|f| matches!(f, Fault::Page { .. })).count();
        // A truncated image and a page of bytes come whole (200, their length right): they are
        // not retried, and each is an error, never texels; resets mid-body are retried.
        assert!(cut >= 1 && pages >= 1, "{kind}: {injected:?}");
        assert_eq!(errors, cut + pages, "{kind}: {reads:?} {injected:?}");
        assert!(src.remote_stats().unwrap().retries >= 2, "{kind}");
    }
}

/// Writes `NAME.pmtiles` and `NAME.mbtiles` of the tree `tree/` (PNG tiles by `{z}/{x}/{y}`)
/// with the reference PMTiles writer and Python's sqlite3 module.
fn pack(dir: &Path, tree: &str, name: &str) {
    let script = r#"
import sqlite3, sys, os
from pmtiles.tile import Compression, TileType, zxy_to_tileid
from pmtiles.writer import Writer
top, tree, name = int(sys.argv[1]), sys.argv[2], sys.argv[3]
tiles = sorted((zxy_to_tileid(z, x, y), open(f'{tree}/{z}/{x}/{y}.png', 'rb').read(), z, x, y)
               for z in range(top + 1) for x in range(2 ** z) for y in range(2 ** z))
with open(f'{name}.pmtiles', 'wb') as f:
    w = Writer(f)
    for tid, data, *_ in tiles:
        w.write_tile(tid, data)
    w.finalize({'tile_type': TileType.PNG, 'tile_compression': Compression.NONE, 'min_zoom': 0, 'max_zoom': top,
                'min_lon_e7': int(-180e7), 'min_lat_e7': int(-85.0511287e7), 'max_lon_e7': int(180e7), 'max_lat_e7': int(85.0511287e7)},
               {'name': name})
if os.path.exists(f'{name}.mbtiles'):
    os.remove(f'{name}.mbtiles')
db = sqlite3.connect(f'{name}.mbtiles')
db.execute('CREATE TABLE metadata (name TEXT, value TEXT)')
db.execute('CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER, tile_data BLOB)')
db.executemany('INSERT INTO metadata VALUES (?, ?)', [('name', name), ('format', 'png'), ('minzoom', '0'), ('maxzoom', str(top))])
db.executemany('INSERT INTO tiles VALUES (?, ?, ?, ?)', [(z, x, 2 ** z - 1 - y, data) for _, data, z, x, y in tiles])
db.commit()
"#;
    run_python(script, dir, &[MAX_ZOOM.to_string(), tree.into(), name.into()]);
}

/// A second version of the XYZ tree, `neg/`, its colours inverted (alpha kept), and its decode.
fn negative_tree(dir: &Path, gdal: &Decoded) -> Decoded {
    let make = r#"
import os, sys
from osgeo import gdal
for z in range(int(sys.argv[1]) + 1):
    for x in range(2 ** z):
        os.makedirs(f'neg/{z}/{x}', exist_ok=True)
        for y in range(2 ** z):
            src = gdal.Open(f'xyz/{z}/{x}/{y}.png')
            mem = gdal.GetDriverByName('MEM').CreateCopy('', src)
            for b in (1, 2, 3):
                band = mem.GetRasterBand(b)
                band.WriteArray(255 - band.ReadAsArray())
            gdal.GetDriverByName('PNG').CreateCopy(f'neg/{z}/{x}/{y}.png', mem)
"#;
    run_python(make, dir, &[MAX_ZOOM.to_string()]);
    for f in walk(&dir.join("neg")) {
        if f.extension().is_some_and(|e| e == "xml") {
            std::fs::remove_file(f).unwrap();
        }
    }
    gdal.iter()
        .map(|(k, v)| {
            let mut v = v.clone();
            for (i, b) in v.iter_mut().enumerate() {
                if i % 4 != 3 {
                    *b = 255 - *b;
                }
            }
            (*k, v)
        })
        .collect()
}

/// Puts `from` at `to` by a rename (the way a new version is published), its modification time
/// `secs` seconds from now (an HTTP server's ETag tells versions apart by it and the size).
fn publish(from: &Path, to: &Path, secs: u64) {
    let tmp = to.with_extension("part");
    std::fs::copy(from, &tmp).unwrap();
    let f = std::fs::File::options().write(true).open(&tmp).unwrap();
    f.set_modified(std::time::SystemTime::now() + Duration::from_secs(secs)).unwrap();
    drop(f);
    std::fs::rename(&tmp, to).unwrap();
}

/// Which of the two versions' decodes a tile read equals, if all its texels equal one.
fn version_of(src: &PyramidSource, k: u32, s: u64, t: u64, v: [&Decoded; 2]) -> Result<usize, String> {
    let z = MAX_ZOOM - k as u8;
    let n = 1u64 << z;
    let mut buf = vec![0u8; src.desc().tile_bytes(k)];
    src.read_tile(TileId { level: k, s, t }, &mut buf).map_err(|e| e.to_string())?;
    let row = buf.len() / 256;
    let north: Vec<u8> = (0..256).rev().flat_map(|r| buf[r * row..(r + 1) * row].to_vec()).collect();
    let at = (z, s as u32, (n - 1 - t) as u32);
    (0..2)
        .find(|&i| v[i][&at] == north)
        .ok_or_else(|| panic!("level {k} tile ({s}, {t}) is of neither version: wrong texels"))
}

/// Serves `text` while its archive is replaced by the other version over and over: each tile
/// read is one version's whole, or an error; once the replacing stops, every tile is the last
/// version's and the source's version moved on.
fn replaced_while_read(text: &str, file: &Path, versions: [&Path; 2], decoded: [&Decoded; 2]) {
    publish(versions[0], file, 0);
    let src = open(text);
    for s in 0..4 {
        for t in 0..4 {
            assert_eq!(version_of(&src, 0, s, t, decoded), Ok(0), "{text}");
        }
    }
    assert_eq!(src.version(), 0);
    // Replaced once: read again, every tile is the new version's.
    publish(versions[1], file, 10);
    for k in 0..=u32::from(MAX_ZOOM) {
        let n = 1u64 << (MAX_ZOOM - k as u8);
        for s in 0..n {
            for t in 0..n {
                assert_eq!(version_of(&src, k, s, t, decoded), Ok(1), "{text}: level {k} tile ({s}, {t})");
            }
        }
    }
    assert!(src.version() >= 1, "{text}: the version moves on");
    // Replaced again and again while four threads read: never a mixed tile, no stall.
    let stop = std::sync::atomic::AtomicBool::new(false);
    let (mut good, mut errors) = (0, 0);
    std::thread::scope(|sc| {
        let readers: Vec<_> = (0..4u64)
            .map(|i| {
                let (src, stop) = (&src, &stop);
                sc.spawn(move || {
                    let (mut good, mut errors) = (0, 0);
                    let mut j = i;
                    while !stop.load(Ordering::SeqCst) {
                        match version_of(src, 0, j % 4, (j / 4) % 4, decoded) {
                            Ok(_) => good += 1,
                            Err(_) => errors += 1,
                        }
                        j += 1;
                    }
                    (good, errors)
                })
            })
            .collect();
        for round in 0..8u64 {
            std::thread::sleep(Duration::from_millis(60));
            publish(versions[(round % 2) as usize], file, 20 + round);
        }
        std::thread::sleep(Duration::from_millis(300));
        stop.store(true, Ordering::SeqCst);
        for r in readers {
            let (g, e) = r.join().unwrap();
            good += g;
            errors += e;
        }
    });
    assert!(good > 0, "{text}: {good} tiles read, {errors} errors");
    // The last version published was versions[1] (round 7): after the replacing, all of it.
    std::thread::sleep(Duration::from_millis(250));
    for s in 0..4 {
        for t in 0..4 {
            assert_eq!(version_of(&src, 0, s, t, decoded), Ok(1), "{text}: after the replacing");
        }
    }
}

#[test]
fn a_pmtiles_replaced_over_http_is_opened_again_and_its_tiles_never_mix_two_versions() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = trees(d);
    let neg = negative_tree(d, &gdal);
    pack(d, "xyz", "a");
    pack(d, "neg", "b");
    std::fs::create_dir_all(d.join("www")).unwrap();
    let nginx = Nginx::serve_images(&d.join("www"));
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let text = format!("{}/world.pmtiles", proxy.url());
    let before = Instant::now();
    replaced_while_read(
        &text,
        &d.join("www/world.pmtiles"),
        [&d.join("a.pmtiles"), &d.join("b.pmtiles")],
        [&gdal, &neg],
    );
    assert!(before.elapsed() < Duration::from_secs(60));
}

#[test]
fn a_local_pmtiles_or_mbtiles_replaced_or_rewritten_on_disk_is_opened_again_never_mixed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = trees(d);
    let neg = negative_tree(d, &gdal);
    pack(d, "xyz", "a");
    pack(d, "neg", "b");
    for ext in ["pmtiles", "mbtiles"] {
        let file = d.join(format!("world.{ext}"));
        let versions = [d.join(format!("a.{ext}")), d.join(format!("b.{ext}"))];
        replaced_while_read(file.to_str().unwrap(), &file, [&versions[0], &versions[1]], [&gdal, &neg]);
        // Rewritten in place (the same file, its bytes overwritten): opened again too.
        let src = open(file.to_str().unwrap());
        assert_eq!(version_of(&src, 0, 1, 2, [&gdal, &neg]), Ok(1), "{ext}");
        std::fs::write(&file, std::fs::read(&versions[0]).unwrap()).unwrap();
        for s in 0..4 {
            for t in 0..4 {
                assert_eq!(version_of(&src, 0, s, t, [&gdal, &neg]), Ok(0), "{ext}: rewritten in place");
            }
        }
        assert_eq!(src.version(), 1, "{ext}");
        // The coarser levels are built again from the new version.
        let mut buf = vec![0u8; src.desc().tile_bytes(3)];
        src.read_tile(TileId { level: 3, s: 0, t: 0 }, &mut buf).unwrap();
        std::thread::sleep(Duration::from_millis(250));
        std::fs::write(&file, std::fs::read(&versions[1]).unwrap()).unwrap();
        let mut again = vec![0u8; src.desc().tile_bytes(3)];
        src.read_tile(TileId { level: 3, s: 0, t: 0 }, &mut again).unwrap();
        assert_eq!(src.version(), 2, "{ext}");
        for (a, b) in buf.iter().zip(&again).take(4 * 128 * 128).step_by(97) {
            // Inverted colours (alpha 255 kept): their means are 255 minus the old ones, within
            // the rounding of the 2x2 means.
            assert!(a.abs_diff(255 - b) <= 1 || (*a == 255 && *b == 255), "{ext}: level 3 was not built again");
        }
    }
}
