//! The remote disk cache of fetched tiles and `cliptex seed`, driven through the real binaries
//! over tiles a peer wrote (`gdal2tiles.py --xyz`, served by nginx, requests counted by a proxy
//! in front of it): the cache's byte bound holds while two processes fill one directory; a
//! process killed (-9) while writing leaves no entry that is not the server's tile; a seeded
//! area is then read with no request at all; `--estimate` fetches its sample only; a seed
//! stopped and run again skips what it cached; bad areas and levels say what was expected.

use crate::common::remote::{FaultProxy, Nginx, Schedule};
use crate::tiles::{archives_of_the_tree, trees, MAX_ZOOM};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");

/// Bytes of the cache's entries and temporaries (every file but the 16-byte ledger).
fn cache_bytes(dir: &Path) -> u64 {
    let Ok(rd) = std::fs::read_dir(dir) else { return 0 };
    rd.flatten()
        .filter(|e| e.file_name() != "cache.ledger")
        .filter_map(|e| e.metadata().ok())
        .filter(|m| m.is_file())
        .map(|m| m.len())
        .sum()
}

/// Waits (up to 30 s) until the cache directory `dir` holds a whole entry (a `.tile` file): a
/// process killed after that has cached something, however slowly the machine started it.
fn wait_for_an_entry(dir: &Path, child: &mut std::process::Child) {
    let t = Instant::now();
    loop {
        let entries = std::fs::read_dir(dir)
            .map_or(0, |rd| rd.flatten().filter(|e| e.path().extension().is_some_and(|x| x == "tile")).count());
        if entries > 0 {
            return;
        }
        assert!(child.try_wait().unwrap().is_none(), "the process ended before caching a tile");
        assert!(t.elapsed() < Duration::from_secs(30), "no tile cached in 30 s");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// `cliptex ARGS` with `envs`, its output.
fn cliptex(cwd: &Path, args: &[&str], envs: &[(&str, &str)]) -> (Output, String) {
    let (o, d) = crate::common::exec_bounded(cwd, CLIPTEX, args, envs, Duration::from_secs(120));
    (o, d)
}

fn json(o: &Output, d: &str) -> serde_json::Value {
    serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("not JSON ({e}):\n{d}"))
}

/// The template of the XYZ tree behind `base`.
fn xyz(base: &str) -> String {
    format!("xyz:{base}/xyz/{{z}}/{{x}}/{{y}}.png")
}

/// Checks a `cliptex dump --level K` picture against GDAL's decode of every tile of zoom
/// `MAX_ZOOM - K`: the picture's top row is the north.
fn dump_is_gdals(png: &Path, k: u32, gdal: &HashMap<(u8, u32, u32), Vec<u8>>, what: &str) {
    let z = MAX_ZOOM - k as u8;
    let img = image::open(png).unwrap_or_else(|e| panic!("{what}: {e}")).into_rgba8();
    let side = 256u32 << z;
    assert_eq!(img.dimensions(), (side, side), "{what}");
    for r in 0..side {
        for c in 0..side {
            let tile = &gdal[&(z, c / 256, r / 256)];
            let i = (((r % 256) * 256 + c % 256) * 4) as usize;
            assert!(img.get_pixel(c, r).0[..] == tile[i..i + 4], "{what}: level {k} pixel ({c}, {r}) is not GDAL's");
        }
    }
}

/// Dumps every level of `template` with the cache `cache` and compares every texel with GDAL's.
fn every_level_is_gdals(d: &Path, template: &str, cache: &Path, gdal: &HashMap<(u8, u32, u32), Vec<u8>>, what: &str) {
    for k in 0..=u32::from(MAX_ZOOM) {
        let out = d.join(format!("check-{k}.png"));
        let zooms = format!("0..{MAX_ZOOM}");
        let (o, desc) = cliptex(
            d,
            &["dump", template, "--zooms", &zooms, "--level", &k.to_string(), "--out", out.to_str().unwrap()],
            &[("CLIPMAP_REMOTE_CACHE_DIR", cache.to_str().unwrap())],
        );
        assert!(o.status.success(), "{what}: {desc}");
        dump_is_gdals(&out, k, gdal, what);
    }
}

/// Each cached tile of the tree, read through the cache's own checks, is byte for byte the
/// server's file; returns how many the cache holds.
fn cached_tiles_are_the_servers(d: &Path, base: &str, cache: &Path) -> usize {
    use clipmap::source::remote::disk::{object_key, DiskCache};
    let c = DiskCache::open(cache, 1 << 40).unwrap();
    let mut held = 0;
    for z in 0..=MAX_ZOOM {
        for x in 0..1u32 << z {
            for y in 0..1u32 << z {
                let key = object_key(&format!("{base}/xyz/{z}/{x}/{y}.png"));
                if let Some(bytes) = c.get_object(&key, 32 << 20) {
                    let file = std::fs::read(d.join(format!("xyz/{z}/{x}/{y}.png"))).unwrap();
                    assert!(bytes == file, "the cached tile {z}/{x}/{y} is not the server's");
                    held += 1;
                }
            }
        }
    }
    held
}

#[test]
fn the_bound_holds_while_two_processes_fill_one_cache_directory() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = trees(d);
    let nginx = Nginx::serve_images(d);
    let template = xyz(&nginx.url());
    let cache = d.join("cache");
    // Room for about a third of zoom 2's tiles: both processes evict all along.
    let tiles: u64 = (0..4u32)
        .flat_map(|x| (0..4u32).map(move |y| (x, y)))
        .map(|(x, y)| std::fs::metadata(d.join(format!("xyz/2/{x}/{y}.png"))).unwrap().len())
        .sum();
    let bound = tiles / 3;
    let bound_text = bound.to_string();
    let envs = [("CLIPMAP_REMOTE_CACHE_DIR", cache.to_str().unwrap()), ("CLIPMAP_REMOTE_CACHE_BYTES", &bound_text)];
    let zooms = format!("0..{MAX_ZOOM}");
    // Two processes, each dumping every level three times over, one cache directory.
    let spawn = |n: usize| {
        let mut lines = Vec::new();
        for round in 0..3 {
            for k in 0..=MAX_ZOOM {
                lines.push(format!(
                    "'{CLIPTEX}' dump '{template}' --zooms {zooms} --level {k} --out p{n}-{round}-{k}.png || exit 1"
                ));
            }
        }
        let script = lines.join("\n");
        Command::new("sh")
            .arg("-c")
            .arg(script)
            .current_dir(d)
            .envs(envs.iter().copied())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let mut children = [spawn(0), spawn(1)];
    let (mut most, mut samples) = (0u64, 0u64);
    let t0 = Instant::now();
    while children.iter_mut().any(|c| c.try_wait().unwrap().is_none()) {
        most = most.max(cache_bytes(&cache));
        samples += 1;
        std::thread::sleep(Duration::from_millis(1));
        assert!(t0.elapsed() < Duration::from_secs(120), "the dumps did not end");
    }
    for c in children {
        let o = c.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    eprintln!("{samples} samples of the cache directory, at most {most} bytes, bound {bound}");
    assert!(samples > 10, "sampled while they ran");
    assert!(most <= bound, "{most} bytes in the cache directory, more than its bound of {bound}");
    assert!(most * 2 > bound, "the cache did fill: {most} bytes at most of {bound}");
    for n in 0..2 {
        for k in 0..=u32::from(MAX_ZOOM) {
            dump_is_gdals(&d.join(format!("p{n}-2-{k}.png")), k, &gdal, "a dump through a full, shared cache");
        }
    }
    assert!(cached_tiles_are_the_servers(d, &nginx.url(), &cache) > 0);
    assert!(cache_bytes(&cache) <= bound);
}

#[test]
fn a_kill_during_writes_leaves_no_corrupt_tile_served() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = trees(d);
    let nginx = Nginx::serve_images(d);
    // A little delay a request, so that kills land among the fetches and the writes.
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 3);
    let template = xyz(&proxy.url());
    let cache = d.join("cache");
    let zooms = format!("0..{MAX_ZOOM}");
    for (i, after_ms) in [40u64, 90, 150, 230, 320, 60, 120].into_iter().enumerate() {
        let mut child = Command::new(CLIPTEX)
            .args(["dump", &template, "--zooms", &zooms, "--level", &(i % 2).to_string(), "--out"])
            .arg(d.join("killed.png"))
            .current_dir(d)
            .env("CLIPMAP_REMOTE_CACHE_DIR", &cache)
            .env("CLIPMAP_REMOTE_IN_FLIGHT", "16")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        if i == 6 {
            // The last is killed only once some tile is cached (a slow machine may start every
            // process later than these times), then after its time.
            wait_for_an_entry(&cache, &mut child);
        }
        std::thread::sleep(Duration::from_millis(after_ms));
        let _ = child.kill(); // SIGKILL
        let _ = child.wait();
    }
    // A torn entry, as a writer without the temporary and the rename would leave: a cache file
    // cut short. It must be dropped, never served.
    let mut entries: Vec<PathBuf> = std::fs::read_dir(&cache)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "tile"))
        .collect();
    entries.sort();
    assert!(!entries.is_empty(), "the killed processes cached some tiles");
    let torn = &entries[0];
    let len = std::fs::metadata(torn).unwrap().len();
    std::fs::OpenOptions::new().write(true).open(torn).unwrap().set_len(len / 2).unwrap();
    // Every entry left that passes the cache's checks is the server's tile, byte for byte.
    let held = cached_tiles_are_the_servers(d, &proxy.url(), &cache);
    assert!(held < entries.len(), "the torn entry is not served");
    // Every texel read back through the cache (and the server for the rest) is GDAL's.
    every_level_is_gdals(d, &template, &cache, &gdal, "after kills");
    assert_eq!(cached_tiles_are_the_servers(d, &proxy.url(), &cache), 21, "every tile cached now");
    // No temporary is left once the cache is opened, and the ledger counts the files.
    let c = clipmap::source::remote::disk::DiskCache::open(&cache, 1 << 40).unwrap();
    assert_eq!(c.bytes(), cache_bytes(&cache));
    let temporaries =
        std::fs::read_dir(&cache).unwrap().flatten().filter(|e| e.file_name().to_string_lossy().contains(".tmp."));
    assert_eq!(temporaries.count(), 0);
}

#[test]
fn a_seeded_area_is_read_with_no_request_and_a_stopped_seed_goes_on_where_it_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = trees(d);
    let nginx = Nginx::serve_images(d);
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let template = xyz(&proxy.url());
    let cache = d.join("cache");
    let c = cache.to_str().unwrap();
    let zooms = format!("0..{MAX_ZOOM}");
    let requests = || proxy.requests.load(Ordering::SeqCst);
    // The coarser levels first (zooms 0 and 1: 5 tiles) ...
    let world = "--bbox=-180,-85,180,85";
    let (o, desc) =
        cliptex(d, &["seed", &template, "--zooms", &zooms, world, "--levels", "1..2", "--cache-dir", c, "--json"], &[]);
    assert!(o.status.success(), "{desc}");
    let j = json(&o, &desc);
    assert_eq!(
        (j["tiles"].as_u64(), j["fetched"].as_u64(), j["skipped_cached"].as_u64()),
        (Some(5), Some(5), Some(0)),
        "{j}"
    );
    assert_eq!((j["requests"].as_u64(), j["missing"].as_u64()), (Some(5), Some(0)), "{j}");
    assert_eq!(requests(), 5);
    // ... then all of them, as a seed stopped after those would be run again: the 5 are skipped.
    let (o, desc) =
        cliptex(d, &["seed", &template, "--zooms", &zooms, world, "--levels", "0..2", "--cache-dir", c, "--json"], &[]);
    assert!(o.status.success(), "{desc}");
    let j = json(&o, &desc);
    assert_eq!(
        (j["tiles"].as_u64(), j["fetched"].as_u64(), j["skipped_cached"].as_u64()),
        (Some(21), Some(16), Some(5)),
        "{j}"
    );
    assert_eq!(j["requests"].as_u64(), Some(16), "{j}");
    let zoom2: u64 = (0..4u32)
        .flat_map(|x| (0..4u32).map(move |y| (x, y)))
        .map(|(x, y)| std::fs::metadata(d.join(format!("xyz/2/{x}/{y}.png"))).unwrap().len())
        .sum();
    assert_eq!(j["bytes"].as_u64(), Some(zoom2), "the bytes of zoom 2's tiles: {j}");
    assert!(j["seconds"].as_f64().is_some(), "{j}");
    assert_eq!(requests(), 21, "one request a tile, none for the cached ones");
    // The seeded area read back, every level, every texel GDAL's: not one request.
    every_level_is_gdals(d, &template, &cache, &gdal, "after the seed");
    assert_eq!(requests(), 21, "the seeded area was read with no request");
    // And with the server gone.
    drop(proxy);
    drop(nginx);
    every_level_is_gdals(d, &template, &cache, &gdal, "after the seed, without the server");
}

#[test]
fn a_killed_seed_run_again_fetches_only_what_it_had_not_cached() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    trees(d);
    let nginx = Nginx::serve_images(d);
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 40);
    let template = xyz(&proxy.url());
    let cache = d.join("cache");
    let zooms = format!("0..{MAX_ZOOM}");
    let mut child = Command::new(CLIPTEX)
        .args(["seed", &template, "--zooms", &zooms, "--bbox=-180,-85,180,85", "--levels", "0..2", "--jobs", "1"])
        .arg("--cache-dir")
        .arg(&cache)
        .current_dir(d)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Killed once it has cached a tile (at 40 ms a request, one at a time, well before its 21st).
    wait_for_an_entry(&cache, &mut child);
    let _ = child.kill();
    let _ = child.wait();
    let before = proxy.requests.load(Ordering::SeqCst);
    assert!(before < 21, "killed before the end: {before} requests");
    let (o, desc) = cliptex(
        d,
        &["seed", &template, "--zooms", &zooms, "--bbox=-180,-85,180,85", "--levels", "0..2", "--json"],
        &[("CLIPMAP_REMOTE_CACHE_DIR", cache.to_str().unwrap())],
    );
    assert!(o.status.success(), "{desc}");
    let j = json(&o, &desc);
    let (fetched, skipped) = (j["fetched"].as_u64().unwrap(), j["skipped_cached"].as_u64().unwrap());
    assert_eq!(fetched + skipped, 21, "{j}");
    assert!(skipped > 0, "the tiles cached before the kill are skipped: {j}");
    // Every tile fetched by the first run was cached (a request whose answer the kill cut short
    // may be asked again).
    assert!(skipped + 1 >= before, "{before} fetched before the kill, {skipped} skipped now: {j}");
    assert_eq!(proxy.requests.load(Ordering::SeqCst) - before, fetched, "{j}");
}

#[test]
fn an_estimate_fetches_only_its_sample_and_bad_areas_and_levels_say_what_was_expected() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    trees(d);
    let nginx = Nginx::serve_images(d);
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let template = xyz(&proxy.url());
    let zooms = format!("0..{MAX_ZOOM}");
    let seed = |extra: &[&str]| {
        let mut args = vec!["seed", &template, "--zooms", &zooms];
        args.extend_from_slice(extra);
        cliptex(d, &args, &[])
    };
    let (o, desc) = seed(&["--bbox=-180,-85,180,85", "--levels", "0..2", "--estimate", "--sample", "3", "--json"]);
    assert!(o.status.success(), "{desc}");
    let j = json(&o, &desc);
    assert_eq!((j["tiles"].as_u64(), j["sample"]["tiles"].as_u64()), (Some(21), Some(3)), "{j}");
    assert_eq!(j["sample"]["requests"].as_u64(), Some(3), "{j}");
    assert_eq!(proxy.requests.load(Ordering::SeqCst), 3, "nothing fetched beyond the sample");
    let per_tile = j["sample"]["bytes"].as_u64().unwrap() / 3;
    assert!(j["bytes"].as_u64().unwrap() >= per_tile * 15, "{j}");
    assert_eq!(j["requests"].as_u64(), Some(21), "{j}");
    assert_eq!(j["estimate_method"].as_str(), Some("sample"), "a tile service has no directories: {j}");
    assert!(j["seconds"].as_f64().unwrap() >= 0.0, "{j}");
    // In text, saying it measured on a sample.
    let (o, desc) = seed(&["--bbox", "0,0,90,60", "--levels", "0", "--estimate", "--sample", "1"]);
    assert!(o.status.success(), "{desc}");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("sample of 1 tiles") && text.contains("nothing else was fetched"), "{desc}");
    assert_eq!(proxy.requests.load(Ordering::SeqCst), 4);
    // A route: a corridor of 100 km along the equator at zoom 2 touches the tiles beside it.
    std::fs::write(d.join("route.txt"), "# lon,lat\n-100,0.5\n\n100,0.5\n").unwrap();
    let (o, desc) =
        seed(&["--route", "route.txt", "--width-km", "100", "--levels", "0", "--estimate", "--sample", "0", "--json"]);
    assert!(o.status.success(), "{desc}");
    assert_eq!(json(&o, &desc)["tiles"].as_u64(), Some(4), "columns 0..3 of the row above the equator: {desc}");
    // Bad input: exit 1, what was found, what was expected.
    std::fs::write(d.join("bad-route.txt"), "10,50\n50;10\n").unwrap();
    let cases: [(&[&str], &[&str]); 7] = [
        (
            &["--bbox", "20,60,10,50", "--levels", "0", "--estimate"],
            &["--bbox `20,60,10,50`", "west 20, east 10", "expected W,S,E,N"],
        ),
        (&["--bbox", "10,95,20,96", "--levels", "0", "--estimate"], &["latitudes 95 and 96", "longitude first"]),
        (&["--bbox", "1,2,3", "--levels", "0", "--estimate"], &["found 3 numbers"]),
        (
            &["--bbox", "0,0,10,10", "--levels", "1..5", "--estimate"],
            &["--levels 1..5", "has levels 0..2", "zooms 2..0"],
        ),
        (&["--bbox", "0,0,10,10", "--levels", "2..1", "--estimate"], &["--levels `2..1`", "expected A..B"]),
        (
            &["--route", "bad-route.txt", "--levels", "0", "--estimate"],
            &["bad-route.txt:2: `50;10` is not a point", "expected LON,LAT"],
        ),
        (&["--bbox", "0,0,10,10", "--levels", "0"], &["no cache to fill", "--cache-dir"]),
    ];
    for (args, says) in cases {
        let (o, desc) = seed(args);
        assert_eq!(o.status.code(), Some(1), "{desc}");
        let err = String::from_utf8_lossy(&o.stderr);
        for s in says {
            assert!(err.contains(s), "`{s}` not said:\n{desc}");
        }
    }
    let local = format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", d.display());
    let (o, desc) = cliptex(d, &["seed", &local, "--bbox", "0,0,10,10", "--levels", "0", "--cache-dir", "c"], &[]);
    assert_eq!(o.status.code(), Some(1), "{desc}");
    assert!(String::from_utf8_lossy(&o.stderr).contains("nothing to cache"), "{desc}");
    assert_eq!(
        proxy.requests.load(Ordering::SeqCst),
        4,
        "the route counted its tiles only, and no bad input fetched anything"
    );
}

#[test]
fn an_estimate_of_a_remote_pmtiles_takes_its_bytes_from_the_directories_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    trees(d);
    archives_of_the_tree(d);
    let nginx = Nginx::serve_images(d);
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let url = format!("{}/tree.pmtiles", proxy.url());
    let (o, desc) = cliptex(
        d,
        &["seed", &url, "--bbox=-180,-85,180,85", "--levels", "0..2", "--estimate", "--sample", "2", "--json"],
        &[],
    );
    assert!(o.status.success(), "{desc}");
    let j = json(&o, &desc);
    // The archive stores the tree's PNG files as they are: its entries' lengths are theirs.
    let files: u64 = (0..=MAX_ZOOM)
        .flat_map(|z| (0..1u32 << z).flat_map(move |x| (0..1u32 << z).map(move |y| (z, x, y))))
        .map(|(z, x, y)| std::fs::metadata(d.join(format!("xyz/{z}/{x}/{y}.png"))).unwrap().len())
        .sum();
    assert_eq!(j["estimate_method"].as_str(), Some("directories"), "{j}");
    assert_eq!((j["tiles"].as_u64(), j["missing"].as_u64()), (Some(21), Some(0)), "{j}");
    assert_eq!(j["bytes"].as_u64(), Some(files), "every tile's bytes, exactly: {j}");
    // One request a tile (its root directory holds every entry: no leaf to read).
    assert_eq!(j["requests"].as_u64(), Some(21), "{j}");
    assert_eq!(j["sample"]["tiles"].as_u64(), Some(2), "{j}");
    // In text, it says so.
    let (o, desc) =
        cliptex(d, &["seed", &url, "--bbox=-180,-85,180,85", "--levels", "0", "--estimate", "--sample", "1"], &[]);
    assert!(o.status.success(), "{desc}");
    assert!(String::from_utf8_lossy(&o.stdout).contains("from the archive's directories, exactly"), "{desc}");
}

#[test]
fn a_remote_pmtiles_seeded_reads_its_tiles_from_the_cache_with_only_its_open_asked() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = trees(d);
    archives_of_the_tree(d);
    let nginx = Nginx::serve_images(d);
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let url = format!("{}/tree.pmtiles", proxy.url());
    let cache = d.join("cache");
    let c = cache.to_str().unwrap();
    let (o, desc) =
        cliptex(d, &["seed", &url, "--bbox=-180,-85,180,85", "--levels", "0..2", "--cache-dir", c, "--json"], &[]);
    assert!(o.status.success(), "{desc}");
    let j = json(&o, &desc);
    // The open read the first tile for its size (kept in the cache): it is skipped.
    let (fetched, skipped) = (j["fetched"].as_u64().unwrap(), j["skipped_cached"].as_u64().unwrap());
    assert_eq!((j["tiles"].as_u64(), fetched + skipped, j["missing"].as_u64()), (Some(21), 21, Some(0)), "{j}");
    assert!(skipped <= 1, "{j}");
    let seeded = proxy.requests.load(Ordering::SeqCst);
    // Again: every tile skipped; the open is the only request (it names the archive's version).
    let (o, desc) =
        cliptex(d, &["seed", &url, "--bbox=-180,-85,180,85", "--levels", "0..2", "--cache-dir", c, "--json"], &[]);
    assert!(o.status.success(), "{desc}");
    let j = json(&o, &desc);
    assert_eq!(j["skipped_cached"].as_u64(), Some(21), "{j}");
    let again = proxy.requests.load(Ordering::SeqCst) - seeded;
    assert!(again <= 1, "{again} requests for a seeded archive: {j}");
    // Read back: every texel GDAL's, one request a run (the open), the tile-size probe included.
    let before = proxy.requests.load(Ordering::SeqCst);
    every_level_is_gdals(d, &url, &cache, &gdal, "a seeded PMTiles");
    let runs = u64::from(MAX_ZOOM) + 1;
    assert_eq!(proxy.requests.load(Ordering::SeqCst) - before, runs, "one request a run: the open");
}

#[test]
fn missing_tiles_errors_and_pages_answered_for_tiles_are_never_cached() {
    use crate::common::remote::Fault;
    use clipmap::source::remote::RemoteOptions;
    use clipmap::source::tiles::{self, OpenOptions, PyramidOptions, TemplateOptions};
    use clipmap::source::{SourceError, TileId, TileSource};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    trees(d);
    let nginx = Nginx::serve_images(d);
    let cache = d.join("cache");
    let open = |base: &str| {
        let remote = RemoteOptions { cache_dir: Some(cache.clone()), retries: 0, ..RemoteOptions::default() };
        let opts = OpenOptions {
            template: TemplateOptions { remote: Some(remote), zooms: Some([0, MAX_ZOOM]), ..Default::default() },
            pyramid: PyramidOptions { clip_size: Some(256), ..Default::default() },
        };
        tiles::open(&xyz(base), &opts).unwrap().unwrap()
    };
    let entries = || cache_bytes(&cache);
    let mut buf = vec![0u8; 256 * 256 * 4];
    let level0 = |s, t| TileId { level: 0, s, t };
    // 404 for every tile: missing, nothing cached.
    let storm =
        FaultProxy::start(nginx.port, Schedule { faults: Vec::new(), then: vec![Fault::NotFound], every: 1 }, 0);
    let src = open(&storm.url());
    for s in 0..4 {
        let r = src.read_tile(level0(s, 0), &mut buf);
        assert!(matches!(r, Err(SourceError::Missing { .. })), "{r:?}");
    }
    assert_eq!(entries(), 0, "a missing tile is never cached");
    drop(storm);
    // A page answered for every tile, as HTML and as `application/octet-stream`: errors, nothing
    // cached.
    for html in [true, false] {
        let pages = Schedule { faults: Vec::new(), then: vec![Fault::Page { len: 700, html }], every: 1 };
        let proxy = FaultProxy::start(nginx.port, pages, 0);
        let src = open(&proxy.url());
        for s in 0..4 {
            assert!(src.read_tile(level0(s, 1), &mut buf).is_err(), "a page is not a tile (html {html})");
        }
        assert_eq!(entries(), 0, "a page answered for a tile is never cached (html {html})");
    }
    // The tiles themselves: cached, then read with no request.
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let src = open(&proxy.url());
    for s in 0..4 {
        src.read_tile(level0(s, 1), &mut buf).unwrap();
    }
    assert_eq!(proxy.requests.load(Ordering::SeqCst), 4);
    assert!(entries() > 0);
    let again = open(&proxy.url());
    for s in 0..4 {
        again.read_tile(level0(s, 1), &mut buf).unwrap();
    }
    assert_eq!(proxy.requests.load(Ordering::SeqCst), 4, "read from the cache");
    assert_eq!(again.remote_stats().unwrap().cache_hits, 4);
}
