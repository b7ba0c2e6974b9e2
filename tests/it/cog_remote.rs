//! Remote COGs: the GDAL-written fixtures (tests/fixtures/cog) served by nginx and by moto's S3
//! server, read by `CogSource::open_remote`. Every texel equals the local source's and GDAL's
//! own decode; open costs one request of at most 64 KiB counted at a proxy in front of the
//! server, a first tile at most two more; adjacent tiles of a row are one request; an object
//! replaced after open is refused and faults on the wire end in a retry or an error, never in
//! a wrong texel.

use crate::cog::{fixture, gdal_level, level, Case, CASES};
use crate::common::exec;
use crate::common::remote::{Fault, FaultProxy, Moto, Nginx, Schedule};
use clipmap::place::RemoteName;
use clipmap::source::cog::LevelOrigin;
use clipmap::source::remote::http::Http;
use clipmap::source::remote::s3::S3;
use clipmap::source::remote::{Remote, RemoteOptions};
use clipmap::source::{CogSource, SourceError, TileId, TileSource};
use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, SystemTime};

/// Short timeouts and backoffs, so that faults resolve quickly.
fn quick_opts() -> RemoteOptions {
    RemoteOptions {
        timeout: Duration::from_millis(1500),
        connect_timeout: Duration::from_millis(500),
        retries: 3,
        backoff: Duration::from_millis(2),
        backoff_max: Duration::from_millis(40),
        ..RemoteOptions::default()
    }
}

/// A remote reader whose S3 backend is configured from `env` (a moto server's variables).
fn reader(env: &[(String, String)]) -> Arc<Remote> {
    let opts = quick_opts();
    let http = Arc::new(Http::new(&opts));
    let s3 = Arc::new(S3::with_vars(&opts, env.to_vec()));
    Arc::new(Remote::with_backends(opts, http, s3))
}

fn open(url: &str, remote: &Arc<Remote>, clip: u64) -> CogSource {
    CogSource::open_remote(&RemoteName::parse(url).unwrap(), Arc::clone(remote), clip)
        .unwrap_or_else(|e| panic!("{url}: {e}"))
}

/// Every level of `src` equals the local file's, and the levels that are images of the file
/// equal GDAL's decode of them.
fn assert_gdal_texels(src: &CogSource, case: &Case, clip: u64, ctx: &str) {
    let local = CogSource::open(&fixture(&format!("{}.tif", case.name)), clip).unwrap();
    assert_eq!(src.desc(), local.desc(), "{ctx}");
    for k in 0..src.desc().level_count() as u32 {
        let got = level(src, k).unwrap_or_else(|e| panic!("{ctx} level {k}: {e}"));
        if (k as usize) < case.ifd_levels {
            let (gdal, size) = gdal_level(case.name, k as usize, case.bpt);
            assert_eq!(size, src.desc().level(k).size, "{ctx} level {k}");
            assert!(gdal == got, "{ctx}: level {k} differs from GDAL's decode");
        }
        assert!(level(&local, k).unwrap() == got, "{ctx}: level {k} differs from the local file's");
    }
}

#[test]
fn gdal_cogs_over_nginx_and_s3_give_gdal_s_texels_as_the_local_files_do() {
    let nginx = Nginx::serve(&fixture(""));
    let moto = Moto::start();
    moto.create_bucket("cogs");
    let remote = reader(&moto.env());
    for case in &CASES {
        let bytes = std::fs::read(fixture(&format!("{}.tif", case.name))).unwrap();
        let s3 = format!("s3://cogs/{}.tif", case.name);
        remote.put(&s3, bytes.into()).unwrap();
        for url in [format!("{}/{}.tif", nginx.url(), case.name), s3] {
            // Stack levels in TIFF tiles, and whole levels assembled from rows of TIFF tiles.
            for clip in [64, 4096] {
                let src = open(&url, &remote, clip);
                assert_gdal_texels(&src, case, clip, &format!("{url} clip {clip}"));
            }
        }
    }
    assert_eq!(remote.stats().failures, 0);
}

/// A classic TIFF of `w x h` grey texels `(3x + 5y) & 255` in uncompressed `t x t` tiles, its
/// tile index after the tiles (far past the first 64 KiB), TileByteCounts right after
/// TileOffsets.
fn big_index_tiff(w: u32, h: u32, t: u32) -> Vec<u8> {
    tiled_tiff(w, h, t, false)
}

/// Like [`big_index_tiff`]; with `gdal`, laid out as GDAL writes a COG: a ghost area after the
/// header announcing block leaders and trailers, and each tile framed by them.
fn tiled_tiff(w: u32, h: u32, t: u32, gdal: bool) -> Vec<u8> {
    let (across, tiles) = (w.div_ceil(t), w.div_ceil(t) * h.div_ceil(t));
    let tile_len = t * t;
    let frame = if gdal { 8 } else { 0 };
    let ghost = if gdal {
        let body = "LAYOUT=IFDS_BEFORE_DATA\nBLOCK_ORDER=ROW_MAJOR\nBLOCK_LEADER=SIZE_AS_UINT4\nBLOCK_TRAILER=LAST_4_BYTES_REPEATED\nKNOWN_INCOMPATIBLE_EDITION=NO\n ";
        format!("GDAL_STRUCTURAL_METADATA_SIZE={:06} bytes\n{body}", body.len()).into_bytes()
    } else {
        Vec::new()
    };
    let ifd_at = 8 + ghost.len() as u32;
    let data_at = 4096u32;
    let arrays_at = data_at + tiles * (tile_len + frame);
    let entries: [(u16, u16, u32, u32); 9] = [
        (256, 4, 1, w),
        (257, 4, 1, h),
        (258, 3, 1, 8),
        (259, 3, 1, 1),
        (262, 3, 1, 1),
        (322, 4, 1, t),
        (323, 4, 1, t),
        (324, 4, tiles, arrays_at),
        (325, 4, tiles, arrays_at + 4 * tiles),
    ];
    let mut f = b"II*\0".to_vec();
    f.extend(ifd_at.to_le_bytes());
    f.extend(&ghost);
    f.extend((entries.len() as u16).to_le_bytes());
    for (tag, ty, count, value) in entries {
        f.extend(tag.to_le_bytes());
        f.extend(ty.to_le_bytes());
        f.extend(count.to_le_bytes());
        f.extend(value.to_le_bytes());
    }
    f.extend(0u32.to_le_bytes());
    f.resize(data_at as usize, 0);
    for i in 0..tiles {
        if gdal {
            f.extend(tile_len.to_le_bytes());
        }
        for r in 0..t {
            for c in 0..t {
                let (x, y) = ((i % across) * t + c, (i / across) * t + r);
                f.push(((3 * x + 5 * y) & 255) as u8);
            }
        }
        if gdal {
            let last = f[f.len() - 4..].to_vec();
            f.extend(last);
        }
    }
    f.extend((0..tiles).flat_map(|i| (data_at + i * (tile_len + frame) + frame / 2).to_le_bytes()));
    f.extend((0..tiles).flat_map(|_| tile_len.to_le_bytes()));
    f
}

/// Texture tile `(s, t)` of level 0 of a [`tiled_tiff`] image `h` texels high, checked.
fn assert_formula_tile(src: &CogSource, s: u64, t: u64, h: u64, buf: &[u8]) {
    let l = src.desc().level(0);
    for (j, &v) in buf.iter().enumerate() {
        let (x, tt) = (s * l.tile[0] + j as u64 % l.tile[0], t * l.tile[1] + j as u64 / l.tile[0]);
        let y = h - 1 - tt;
        assert_eq!(v, ((3 * x + 5 * y) & 255) as u8, "texel ({x}, {tt})");
    }
}

#[test]
fn a_remote_cog_opens_with_one_request_of_at_most_64_kib_and_a_first_tile_costs_at_most_two_more() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(fixture("rgb_512x384.tif"), dir.path().join("rgb.tif")).unwrap();
    // 2048 x 2048 in 16 x 16 tiles: 16384 tiles, two 64 KiB index arrays past the tiles.
    std::fs::write(dir.path().join("big_index.tif"), big_index_tiff(2048, 2048, 16)).unwrap();
    std::fs::write(dir.path().join("gdal_like.tif"), tiled_tiff(2048, 2048, 8, true)).unwrap();
    let nginx = Nginx::serve(dir.path());
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let seen = || proxy.requests.load(Ordering::SeqCst);

    // GDAL's COG (93 100 bytes): header, ghost area, IFDs and tile index in the first 64 KiB.
    let remote = reader(&[]);
    let src = open(&format!("{}/rgb.tif", proxy.url()), &remote, 64);
    assert_eq!(seen(), 1, "open is one request at the server");
    assert!(remote.stats().bytes <= 64 << 10, "{:?}", remote.stats());
    // Texture tile (0, 0) is the image's bottom-left TIFF tile, written last, past the first 64 KiB.
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    src.read_tile(TileId::new(0, 0, 0), &mut buf).unwrap();
    let first = seen() - 1;
    assert!((1..=2).contains(&first), "the first tile cost {first} requests");
    let want = CogSource::open(&fixture("rgb_512x384.tif"), 64).unwrap();
    let mut local = vec![0u8; buf.len()];
    want.read_tile(TileId::new(0, 0, 0), &mut local).unwrap();
    assert!(buf == local);

    // A whole level assembled from several TIFF tiles: one request a row of tiles, not a tile.
    let src = open(&format!("{}/rgb.tif", proxy.url()), &remote, 4096);
    let LevelOrigin::Ifd { tile, .. } = src.origins()[0] else { panic!("level 0 is IFD 0") };
    let (across, rows) = (512u64.div_ceil(tile[0]), 384u64.div_ceil(tile[1]));
    assert!(across > 1, "{tile:?}");
    let before = seen();
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    src.read_tile(TileId::new(0, 0, 0), &mut buf).unwrap();
    let cost = seen() - before;
    assert!(cost <= rows, "{cost} requests for {rows} rows of {across} tiles");
    let want = CogSource::open(&fixture("rgb_512x384.tif"), 4096).unwrap();
    let mut local = vec![0u8; buf.len()];
    want.read_tile(TileId::new(0, 0, 0), &mut local).unwrap();
    assert!(buf == local);

    // A tile index of 128 KiB past the first 64 KiB: open reads none of it.
    let before = seen();
    let src = open(&format!("{}/big_index.tif", proxy.url()), &remote, 64);
    assert_eq!(seen() - before, 1, "open is one request however large the index");
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    for (i, (s, t)) in [(77u64, 55u64), (78, 55), (3, 120)].into_iter().enumerate() {
        let before = seen();
        src.read_tile(TileId::new(0, s, t), &mut buf).unwrap();
        let cost = seen() - before;
        // The first tile reads both arrays (128 KiB together, at most MAX_INDEX_READ) in one
        // request and its bytes in another; later tiles only their bytes.
        assert_eq!(cost, if i == 0 { 2 } else { 1 }, "tile ({s}, {t}) cost {cost} requests");
        assert_formula_tile(&src, s, t, 2048, &buf);
    }

    // An index of 512 KiB (65536 tiles), framed as GDAL frames tiles: a first tile costs the
    // chunk of TileOffsets that names it and its bytes, whose leader confirms its byte count
    // (TileByteCounts is not read).
    let before = seen();
    let src = open(&format!("{}/gdal_like.tif", proxy.url()), &remote, 64);
    assert_eq!(seen() - before, 1, "open is one request however large the index");
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    for (i, (s, t)) in [(100u64, 200u64), (101, 200), (7, 9)].into_iter().enumerate() {
        let before = seen();
        src.read_tile(TileId::new(0, s, t), &mut buf).unwrap();
        let cost = seen() - before;
        assert_eq!(cost, if i == 1 { 1 } else { 2 }, "tile ({s}, {t}) cost {cost} requests");
        assert_formula_tile(&src, s, t, 2048, &buf);
    }
    // A leader that disagrees: TileByteCounts is read after all, and the tile refused.
    let mut bad = tiled_tiff(2048, 2048, 8, true);
    let index = (255 - 9) * 256 + 7;
    let leader = 4096 + index * (64 + 8);
    assert_eq!(bad[leader..leader + 4], 64u32.to_le_bytes());
    bad[leader] = 65;
    std::fs::write(dir.path().join("gdal_bad.tif"), &bad).unwrap();
    let src = open(&format!("{}/gdal_bad.tif", proxy.url()), &remote, 64);
    let e = src.read_tile(TileId::new(0, 7, 9), &mut buf).unwrap_err();
    assert!(matches!(e, SourceError::Chunk { .. }) && e.to_string().contains("BLOCK_LEADER) say 65 bytes"), "{e}");
    src.read_tile(TileId::new(0, 8, 9), &mut buf).unwrap();
    assert_formula_tile(&src, 8, 9, 2048, &buf);
}

/// Replaces `path` with `bytes`, its modification time moved on (so that nginx's ETag, made of
/// the time and the size, changes even when the size does not).
fn replace(path: &Path, bytes: &[u8]) {
    std::fs::write(path, bytes).unwrap();
    let f = std::fs::File::options().write(true).open(path).unwrap();
    f.set_modified(SystemTime::now() + Duration::from_secs(1000)).unwrap();
}

/// Reads every tile of every level of `src` once the object was replaced: each read is the
/// old object's texels (`want`) or an error saying it changed; returns how many said so.
fn reads_after_replacement(src: &CogSource, want: &CogSource, ctx: &str) -> usize {
    let mut refused = 0;
    let desc = src.desc().clone();
    for k in 0..desc.level_count() as u32 {
        let tiles = desc.level(k).tiles();
        let mut buf = vec![0u8; desc.tile_bytes(k)];
        let mut expect = vec![0u8; desc.tile_bytes(k)];
        for t in 0..tiles[1] {
            for s in 0..tiles[0] {
                let id = TileId::new(k, s, t);
                match src.read_tile(id, &mut buf) {
                    Ok(()) => {
                        want.read_tile(id, &mut expect).unwrap();
                        assert!(buf == expect, "{ctx}: {id} is not the opened object's");
                    }
                    Err(e) => {
                        assert!(matches!(e, SourceError::Chunk { .. }), "{ctx}: {id}: {e}");
                        let text = e.to_string();
                        assert!(text.contains("changed since it was opened") && text.contains("ETag"), "{ctx}: {text}");
                        refused += 1;
                    }
                }
            }
        }
    }
    refused
}

#[test]
fn a_remote_cog_replaced_after_open_is_refused_never_mixed() {
    let original = std::fs::read(fixture("rgb_512x384.tif")).unwrap();
    // The same size, every byte past the first 64 KiB altered: tiles that would decode to other
    // texels, or fail to.
    let mut altered = original.clone();
    for b in &mut altered[64 << 10..] {
        *b ^= 0x5a;
    }
    let want = CogSource::open(&fixture("rgb_512x384.tif"), 64).unwrap();

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rgb.tif");
    std::fs::write(&path, &original).unwrap();
    let nginx = Nginx::serve(dir.path());
    let remote = reader(&[]);
    let src = open(&format!("{}/rgb.tif", nginx.url()), &remote, 64);
    replace(&path, &altered);
    let refused = reads_after_replacement(&src, &want, "nginx");
    assert!(refused > 0, "the tiles past the first 64 KiB are refused");

    let moto = Moto::start();
    moto.create_bucket("cogs");
    let remote = reader(&moto.env());
    remote.put("s3://cogs/rgb.tif", original.into()).unwrap();
    let src = open("s3://cogs/rgb.tif", &remote, 64);
    remote.put("s3://cogs/rgb.tif", altered.into()).unwrap();
    let refused = reads_after_replacement(&src, &want, "s3");
    assert!(refused > 0, "the tiles past the first 64 KiB are refused");
}

#[test]
fn faults_on_the_wire_end_in_a_retry_or_an_error_never_in_a_wrong_texel() {
    let nginx = Nginx::serve(&fixture(""));
    // Small COGs lie mostly in the first 64 KiB read at open: every request after it, in turn,
    // is cut, mis-sized, failed or passed.
    let faults = vec![
        Fault::Truncate,
        Fault::Pass,
        Fault::LongLength,
        Fault::ShortLength,
        Fault::Pass,
        Fault::ServerError,
        Fault::Reset,
        Fault::Pass,
    ];
    let proxy = FaultProxy::start(nginx.port, Schedule { faults: vec![Fault::Pass], then: faults, every: 1 }, 0);
    let remote = reader(&[]);
    let (mut good, mut failed) = (0, 0);
    for name in CASES.iter().map(|c| c.name) {
        let want = CogSource::open(&fixture(&format!("{name}.tif")), 64).unwrap();
        let src = match CogSource::open_remote(
            &RemoteName::parse(&format!("{}/{name}.tif", proxy.url())).unwrap(),
            Arc::clone(&remote),
            64,
        ) {
            Ok(s) => s,
            Err(e) => {
                failed += 1;
                assert!(e.to_string().contains(name), "{e}");
                continue;
            }
        };
        assert_eq!(src.desc(), want.desc());
        let desc = src.desc().clone();
        for k in 0..desc.level_count() as u32 {
            let tiles = desc.level(k).tiles();
            let (mut buf, mut expect) = (vec![0u8; desc.tile_bytes(k)], vec![0u8; desc.tile_bytes(k)]);
            for t in 0..tiles[1] {
                for s in 0..tiles[0] {
                    let id = TileId::new(k, s, t);
                    match src.read_tile(id, &mut buf) {
                        Ok(()) => {
                            want.read_tile(id, &mut expect).unwrap();
                            assert!(buf == expect, "{name} {id}");
                            good += 1;
                        }
                        Err(e) => {
                            assert!(!matches!(e, SourceError::Missing { .. }), "{name} {id}: {e}");
                            failed += 1;
                        }
                    }
                }
            }
        }
    }
    let injected = proxy.injected.lock().unwrap().iter().filter(|f| **f != Fault::Pass).count();
    assert!(injected > 10, "faults were injected: {injected}");
    assert!(remote.stats().retries > 0, "{:?}", remote.stats());
    assert!(good > 50, "{good} tiles read right, {failed} failed");
}

#[test]
fn cliptex_info_of_a_cog_url_shows_its_levels_read_with_one_request() {
    let nginx = Nginx::serve(&fixture(""));
    let dir = tempfile::tempdir().unwrap();
    let url = format!("{}/grey_1000x700.tif", nginx.url());
    let (out, desc) = exec(dir.path(), env!("CARGO_BIN_EXE_cliptex"), &["info", &url]);
    assert!(out.status.success(), "{desc}");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.starts_with(&format!("{url}: tiled TIFF served as it is: 1000 x 700 texels")), "{text}");
    assert!(text.contains("built when first read from level 2 (2 x 2 box)"), "{text}");
    let missing = format!("{}/nothing.tif", nginx.url());
    let (out, desc) = exec(dir.path(), env!("CARGO_BIN_EXE_cliptex"), &["info", &missing]);
    assert!(!out.status.success(), "{desc}");
    assert!(desc.contains(&format!("{missing}: not found")), "{desc}");
}

#[test]
fn a_ct_naming_a_cog_url_serves_the_local_files_texels() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let served = d.join("served");
    std::fs::create_dir(&served).unwrap();
    std::fs::copy(fixture("rgb_512x384.tif"), served.join("rgb_512x384.tif")).unwrap();
    let nginx = Nginx::serve(&served);
    let url = format!("{}/rgb_512x384.tif", nginx.url());
    // clipprep --config-only takes the URL and writes it on the `#clipmap cog` lines.
    let (out, desc) =
        exec(d, env!("CARGO_BIN_EXE_clipprep"), &["--input", &url, "--config-only", "--clip", "128", "--out", "g"]);
    assert!(out.status.success(), "{desc}");
    let ct = d.join("g/g.ct");
    let text = std::fs::read_to_string(&ct).unwrap();
    assert!(text.contains(&format!("\n#clipmap cog {url}\n")), "{text}");
    let (out, desc) = exec(d, env!("CARGO_BIN_EXE_cliptex"), &["validate", "g/g.ct"]);
    assert!(out.status.success(), "{desc}");
    // The plan's source is the remote COG: every level equals the local file's.
    let loaded = clipmap::source::configured::load_clip_texture(&ct, &clipmap::plan::Options::default()).unwrap();
    let rendered = loaded.render();
    let plan = loaded.plan.unwrap_or_else(|| panic!("{rendered}"));
    let src = clipmap::source::open_plan(plan, &clipmap::limits::Limits::default()).unwrap();
    let local = CogSource::open(&fixture("rgb_512x384.tif"), 128).unwrap();
    assert_eq!(src.desc(), local.desc());
    assert!(src.remote_stats().is_some(), "read over the network");
    for k in 0..local.desc().level_count() as u32 {
        assert!(level(src.as_ref(), k).unwrap() == level(&local, k).unwrap(), "level {k}");
    }
    // Replaced in its store (another ETag), it is opened again at the next read past the first
    // 64 KiB kept from the open, as `clipmapd URL` does (docs/COG.md, "One version of the object").
    assert_eq!(src.version(), 0);
    replace(&served.join("rgb_512x384.tif"), &std::fs::read(fixture("rgb_512x384.tif")).unwrap());
    std::thread::sleep(clipmap::source::cog::REOPEN_GAP);
    assert!(level(src.as_ref(), 0).unwrap() == level(&local, 0).unwrap(), "level 0, the new version");
    assert_eq!(src.version(), 1, "opened again");
    // An object that is not there: refused at the line, naming it.
    std::fs::write(&ct, text.replace(&url, &format!("{}/nothing.tif", nginx.url()))).unwrap();
    let (out, desc) = exec(d, env!("CARGO_BIN_EXE_cliptex"), &["validate", "g/g.ct"]);
    assert_eq!(out.status.code(), Some(1), "{desc}");
    assert!(desc.contains(&format!("{}/nothing.tif: not found", nginx.url())), "{desc}");
}

/// One control-socket exchange with a `clipmapd` (None until it answers).
fn ask(socket: &Path, line: &str) -> Option<String> {
    use std::io::{BufRead, BufReader, Write};
    let mut s = std::os::unix::net::UnixStream::connect(socket).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
    writeln!(s, "{line}").ok()?;
    let mut reply = String::new();
    BufReader::new(s).read_line(&mut reply).ok()?;
    Some(reply.trim_end().to_string())
}

#[test]
fn clipmapd_serves_a_cog_url_as_it_serves_the_file() {
    let nginx = Nginx::serve(&fixture(""));
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let socket = d.join("cogurl.sock");
    let err = d.join("cogurl.err");
    let url = format!("{}/rgb_512x384.tif", nginx.url());
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_clipmapd"))
        .args([url.as_str(), "--clip", "128", "--tick-hz", "60", "--name", "cogurl", "--shm-dir"])
        .arg(d)
        .arg("--socket")
        .arg(&socket)
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(&err).unwrap())
        .spawn()
        .unwrap();
    let log = || std::fs::read_to_string(&err).unwrap_or_default();
    let json = |line: &str| -> serde_json::Value {
        let r = ask(&socket, line).unwrap_or_default();
        serde_json::from_str(r.strip_prefix("OK ").unwrap_or_else(|| panic!("{line}: {r}\n{}", log()))).unwrap()
    };
    let t = std::time::Instant::now();
    while !ask(&socket, "PING").is_some_and(|r| r.starts_with("OK pong")) {
        if let Ok(Some(st)) = child.try_wait() {
            panic!("clipmapd exited ({st}):\n{}", log());
        }
        assert!(t.elapsed() < Duration::from_secs(30), "the service did not come up:\n{}", log());
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(json("STATUS")["levels"], 10, "the file's ten levels");
    // The first tiles can come from the bytes the open read (a request of their own is then
    // still to be sent, or under way): wait for a tile and a second request.
    while {
        let s = json("STATS");
        s["engine"]["tiles_read"].as_u64().unwrap() == 0 || s["remote"]["requests"].as_u64().unwrap() < 2
    } {
        assert!(t.elapsed() < Duration::from_secs(30), "no tile read, or no request after the open's\n{}", log());
        std::thread::sleep(Duration::from_millis(20));
    }
    // STATS counts the remote reads: the open's request and the tiles' ranges, and the bytes
    // they brought (at least the open's first bytes of the 93 100-byte file).
    let stats = json("STATS");
    let remote = &stats["remote"];
    let (requests, bytes) = (remote["requests"].as_u64().unwrap(), remote["bytes"].as_u64().unwrap());
    assert!(requests >= 2 && bytes > 0 && bytes <= 93_100 * requests, "{remote}");
    for field in ["retries", "merged", "failures", "cache_hits", "cache_dropped", "peak_in_flight"] {
        assert!(remote[field].is_u64(), "{field}: {remote}");
    }
    assert_eq!(remote["failures"], 0, "{remote}");
    // `cliptex attach` shows them: one line of text, and `remote` in its JSON.
    let attach = |json: bool| {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex"));
        c.args(["attach", "cogurl", "--once", "--interval", "0.05", "--shm-dir"]).arg(d).arg("--socket").arg(&socket);
        if json {
            c.arg("--json");
        }
        let out = c.output().unwrap();
        assert!(out.status.success(), "{out:?}\n{}", log());
        String::from_utf8(out.stdout).unwrap()
    };
    let v: serde_json::Value = serde_json::from_str(&attach(true)).unwrap();
    let shown = &v["remote"];
    assert!(shown["requests"].as_u64().unwrap() >= requests, "{shown}");
    assert!(shown["bytes"].as_u64().unwrap() >= bytes, "{shown}");
    for field in ["retries", "merged", "failures", "cache_hits", "cache_dropped", "peak_in_flight"] {
        assert!(shown[field].is_u64(), "{field}: {shown}");
    }
    let text = attach(false);
    let line = text.lines().find(|l| l.starts_with("remote: ")).unwrap_or_else(|| panic!("no remote line\n{text}"));
    for word in ["requests", "retries", "merged", "MiB", "failures", "cache", "hits", "dropped", "peak", "in flight"] {
        assert!(line.contains(word), "{word}: {line}");
    }
    let _ = child.kill();
    let _ = child.wait();
    // An object that is not there is refused before anything is created, naming it.
    let missing = format!("{}/nothing.tif", nginx.url());
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_clipmapd"))
        .arg(&missing)
        .args(["--shm-dir"])
        .arg(d)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stderr).contains(&format!("{missing}: not found")), "{out:?}");
}

#[test]
fn an_ifd_past_the_first_64_kib_is_read_where_it_lies_and_a_failed_read_of_it_is_said_so() {
    // The IFD moved to the end of the file, past the first 64 KiB.
    let mut tiff = big_index_tiff(512, 512, 16);
    let ifd = tiff[8..8 + 2 + 9 * 12 + 4].to_vec();
    let at = tiff.len() as u32;
    tiff.extend(ifd);
    tiff[4..8].copy_from_slice(&at.to_le_bytes());
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("late.tif"), &tiff).unwrap();
    let nginx = Nginx::serve(dir.path());
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let url = format!("{}/late.tif", proxy.url());
    let remote = reader(&[]);
    let src = open(&url, &remote, 64);
    assert_eq!(proxy.requests.load(Ordering::SeqCst), 2, "the first 64 KiB, then the IFD where it lies");
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    src.read_tile(TileId::new(0, 5, 6), &mut buf).unwrap();
    let y = 511 - 6 * 16;
    assert_eq!(buf[0], ((3 * 5 * 16 + 5 * y) & 255) as u8);
    // Every request after the first fails: open says the object could not be read, not that
    // the file is damaged.
    proxy.set(Schedule { faults: vec![Fault::Pass], then: vec![Fault::ServerError], every: 1 });
    let e = CogSource::open_remote(&RemoteName::parse(&url).unwrap(), remote, 64).unwrap_err();
    let text = e.to_string();
    assert!(text.contains("reading its structure") && text.contains("HTTP 500") && text.contains(&url), "{text}");
    assert!(!text.contains("damaged"), "{text}");
}

#[test]
fn a_masked_cog_over_nginx_gives_the_local_files_rgba_texels() {
    // GDAL's masked COG with overviews (its masks 1-bit, after every overview), read remote with
    // and without the tiles announced (the mask tiles are read beside each image tile).
    let dir = tempfile::tempdir().unwrap();
    let case = &crate::cog_masks::CASES[3];
    crate::cog_masks::write(case, dir.path());
    let nginx = Nginx::serve(dir.path());
    let url = format!("{}/{}.tif", nginx.url(), case.name);
    let remote = reader(&[]);
    for (clip, announce) in [(64, false), (64, true), (512, false)] {
        let src = open(&url, &remote, clip);
        let local = CogSource::open(&dir.path().join(format!("{}.tif", case.name)), clip).unwrap();
        assert_eq!(src.desc(), local.desc(), "clip {clip}");
        assert_eq!(src.desc().format(), clipmap::texel::TexelFormat::RGBA8);
        for k in 0..src.desc().level_count() as u32 {
            if announce {
                let l = *src.desc().level(k);
                let t = l.tiles();
                let all: Vec<TileId> =
                    (0..t[1]).flat_map(|tt| (0..t[0]).map(move |ts| TileId::new(k, ts, tt))).collect();
                src.will_read(&all);
            }
            let got = level(&src, k).unwrap_or_else(|e| panic!("clip {clip} level {k}: {e}"));
            assert!(got == level(&local, k).unwrap(), "clip {clip} level {k}: the remote texels differ");
        }
    }
}

/// Every texel a clipmap publishes, level by level, against two versions of a texture: how many
/// equal `new`'s, how many equal only `old`'s, and how many equal neither.
fn tally(map: &clipmap::clip::Clipmap, old: &CogSource, new: &CogSource) -> [u64; 3] {
    let mut n = [0u64; 3];
    let desc = map.desc().clone();
    let bpt = desc.format().bytes_per_texel() as usize;
    for k in 0..desc.level_count() as u32 {
        let view = map.level(k);
        let v = view.valid;
        let (mut a, mut b) = (vec![0u8; desc.tile_bytes(k)], vec![0u8; desc.tile_bytes(k)]);
        let mut last = None;
        for t in v.t0..v.t1 {
            for s in v.s0..v.s1 {
                let Some(texel) = view.texel(s, t) else { continue };
                let tile = view.tile_of(s, t);
                if last != Some(tile) {
                    old.read_tile(tile, &mut a).unwrap();
                    new.read_tile(tile, &mut b).unwrap();
                    last = Some(tile);
                }
                let i = ((t - tile.t as i64 * view.tile[1] as i64) * view.tile[0] as i64
                    + (s - tile.s as i64 * view.tile[0] as i64)) as usize
                    * bpt;
                let got: &[u8] = &texel;
                if got == &b[i..i + bpt] {
                    n[0] += 1;
                } else if got == &a[i..i + bpt] {
                    n[1] += 1;
                } else {
                    n[2] += 1;
                }
            }
        }
    }
    n
}

#[test]
fn a_served_remote_cog_replaced_in_its_store_is_opened_again_and_every_tile_read_anew() {
    use clipmap::clip::{Clipmap, Settings};
    use clipmap::source::cog::Reopening;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Two versions of one texture (the same size, tiles and levels), the second's colours
    // inverted, and a third of another size.
    let script = "from osgeo import gdal\nimport sys\nsrc = sys.argv[1]\nco = ['COMPRESS=LZW', 'BLOCKSIZE=64']\n\
                  gdal.Translate('a.tif', src, format='COG', creationOptions=co)\n\
                  gdal.Translate('b.tif', src, format='COG', creationOptions=co, scaleParams=[[0, 255, 255, 0]])\n\
                  gdal.Translate('c.tif', src, format='COG', creationOptions=co, width=256, height=192)\n";
    let src = fixture("rgb_512x384.tif").to_string_lossy().into_owned();
    crate::common::gdal::write_with(script, &["-".into(), src], d, "two versions of a COG");
    let (old, new) = (CogSource::open(&d.join("a.tif"), 64).unwrap(), CogSource::open(&d.join("b.tif"), 64).unwrap());
    assert_eq!(old.desc(), new.desc());

    let served = d.join("served");
    std::fs::create_dir(&served).unwrap();
    let path = served.join("obj.tif");
    std::fs::copy(d.join("a.tif"), &path).unwrap();
    let nginx = Nginx::serve(&served);
    let name = RemoteName::parse(&format!("{}/obj.tif", nginx.url())).unwrap();
    let source = Arc::new(Reopening::open(&name, reader(&[]), 64).unwrap());
    let mut map = Clipmap::new(source.clone(), Settings::default()).unwrap();
    let size = old.desc().size().map(|x| x as i64);
    let (here, there) = ([size[0] / 4, size[1] / 4], [size[0] * 3 / 4, size[1] * 3 / 4]);
    let settle = |map: &mut Clipmap, at: [i64; 2], until: &dyn Fn(&Clipmap) -> bool, what: &str| {
        let t = std::time::Instant::now();
        loop {
            map.tick(at, None);
            map.wait_for_reads();
            let n = tally(map, &old, &new);
            assert_eq!(n[2], 0, "{what}: texels of neither version: {n:?}");
            if until(map) {
                return n;
            }
            assert!(t.elapsed() < Duration::from_secs(30), "{what}: {n:?}, {:?}", map.stats());
        }
    };
    let n = settle(&mut map, here, &|m| m.min_lod() == 0.0, "the first version");
    assert_eq!(n[0], 0, "the first version's texels only: {n:?}");
    assert!(n[1] > 0, "{n:?}");

    // Replaced: the next tile read sees another ETag, the object is opened again, and every
    // tile held is read anew; no texel is ever of neither version.
    replace(&path, &std::fs::read(d.join("b.tif")).unwrap());
    let n = settle(
        &mut map,
        there,
        &|m| m.min_lod() == 0.0 && m.refresh_pending() == 0 && tally(m, &old, &new)[1] == 0,
        "the second version",
    );
    assert!(n[0] > 0 && n[1] == 0, "every texel the new version's: {n:?}");
    assert_eq!(source.reopened(), 1);
    assert_eq!(map.stats().source_versions, 1);
    assert!(map.stats().tiles_replaced > 0, "{:?}", map.stats());
    assert_eq!(source.refused(), None);

    // Replaced by another texture: not served; the reads are refused, the texels stay the
    // second version's.
    replace(&path, &std::fs::read(d.join("c.tif")).unwrap());
    std::thread::sleep(clipmap::source::cog::REOPEN_GAP);
    let n = settle(&mut map, here, &|_| source.refused().is_some(), "another texture");
    assert_eq!(n[1], 0, "{n:?}");
    let why = source.refused().unwrap();
    assert!(why.contains("another texture") && why.contains("[256, 192]") && why.contains("restart"), "{why}");
    assert_eq!(source.reopened(), 1);
}

/// Reads every level-0 tile of `src` a row at a time, each row announced first (as the engine's
/// read queues announce a run: one merged, streamed request a row), checking each against the
/// formula of [`tiled_tiff`]; returns the errors.
fn read_rows_announced(src: &CogSource, h: u64) -> Vec<String> {
    let [across, rows] = src.desc().level(0).tiles();
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    let mut errors = Vec::new();
    for t in 0..rows {
        let row: Vec<TileId> = (0..across).map(|s| TileId::new(0, s, t)).collect();
        src.will_read(&row);
        for id in row {
            match src.read_tile(id, &mut buf) {
                Ok(()) => assert_formula_tile(src, id.s, id.t, h, &buf),
                // The error names the tile.
                Err(e) => errors.push(e.to_string()),
            }
        }
    }
    errors
}

#[test]
fn a_merged_request_cut_or_reset_mid_body_resumes_and_every_tile_is_right_over_http_and_s3() {
    let dir = tempfile::tempdir().unwrap();
    // 1792 x 2048 in 256 x 256 tiles, framed as GDAL frames them: 8 rows of 7 tiles of 64 KiB,
    // past the first 64 KiB. A body cut half way is cut inside a tile.
    std::fs::write(dir.path().join("rows.tif"), tiled_tiff(1792, 2048, 256, true)).unwrap();
    let nginx = Nginx::serve(dir.path());
    let url = |port: u16| format!("http://127.0.0.1:{port}/rows.tif");

    // Without faults: one request a row (the open, the tile index, a request for each row not
    // in the first bytes).
    let proxy = FaultProxy::start(nginx.port, Schedule::pass(), 0);
    let remote = reader(&[]);
    let src = open(&url(proxy.port), &remote, 1024);
    assert!(read_rows_announced(&src, 2048).is_empty());
    let clean = proxy.requests.load(Ordering::SeqCst);
    assert!(clean <= 2 + 8, "{clean} requests for 8 rows");
    assert!(remote.stats().merged >= 7 * 7, "{:?}", remote.stats());

    // Every other request after the open cut half way through its body or reset: each merged
    // request resumes where its body was cut, and no tile is wrong.
    let faults = vec![Fault::Truncate, Fault::Pass, Fault::Reset, Fault::Pass, Fault::LongLength, Fault::Pass];
    let proxy = FaultProxy::start(nginx.port, Schedule { faults: vec![Fault::Pass], then: faults, every: 1 }, 0);
    let remote = reader(&[]);
    let src = open(&url(proxy.port), &remote, 1024);
    let errors = read_rows_announced(&src, 2048);
    assert!(errors.is_empty(), "{errors:?}");
    let injected = proxy.injected.lock().unwrap().iter().filter(|f| **f != Fault::Pass).count();
    assert!(injected >= 4, "faults were injected: {injected}");
    assert!(remote.stats().retries >= injected as u64, "{:?}", remote.stats());

    // The object replaced after open: a merged request's answer is refused before any of its
    // bytes reach a tile, and each tile then says the object changed.
    let remote = reader(&[]);
    let src = open(&url(nginx.port), &remote, 1024);
    let mut altered = tiled_tiff(1792, 2048, 256, true);
    for b in &mut altered[8192..] {
        *b = !*b;
    }
    replace(&dir.path().join("rows.tif"), &altered);
    let errors = read_rows_announced(&src, 2048);
    assert!(errors.len() == 56, "{} tiles refused", errors.len());
    assert!(errors.iter().all(|e| e.contains("changed since it was opened")), "{errors:?}");

    // The same over S3 (object_store's streamed answers): every tile right, one request a row
    // (the put, the open and the tile index besides); then the object replaced, every tile
    // refused.
    let moto = Moto::start();
    moto.create_bucket("rows");
    let remote = reader(&moto.env());
    remote.put("s3://rows/rows.tif", tiled_tiff(1792, 2048, 256, true).into()).unwrap();
    let src = open("s3://rows/rows.tif", &remote, 1024);
    assert!(read_rows_announced(&src, 2048).is_empty());
    assert!(remote.stats().merged >= 7 * 7 && remote.stats().requests <= 3 + 8, "{:?}", remote.stats());
    remote.put("s3://rows/rows.tif", altered.into()).unwrap();
    let errors = read_rows_announced(&src, 2048);
    assert!(errors.len() == 56 && errors.iter().all(|e| e.contains("changed since it was opened")), "{errors:?}");
}
