//! Tile pyramids written by a peer: an XYZ tree (`gdal2tiles.py --xyz`) and a TMS tree
//! (`gdal2tiles.py`'s default) of a small GDAL-made image, read from disk and over nginx. Every
//! texel served equals GDAL's own decode of the same tile at the same place (zoom as level, rows
//! flipped to texture orientation); a 404 storm gives missing tiles and an HTML page answered
//! for a tile gives errors, never texels.

use crate::common::gdal::python;
use crate::common::remote::{Fault, FaultProxy, Nginx, Schedule};
use clipmap::source::remote::RemoteOptions;
use clipmap::source::tiles::{self, OpenOptions, PyramidOptions, PyramidSource, TemplateOptions};
use clipmap::source::{SourceError, TileId, TileSource};
use std::collections::HashMap;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// The finest zoom of the trees.
pub(crate) const MAX_ZOOM: u8 = 2;

/// Makes `src.tif` (512² RGB in Web Mercator, the whole world), its XYZ and TMS trees
/// (`xyz/`, `tms/`, zooms 0..2) and GDAL's decode of every tile: `(z, x, y from the north)` ->
/// RGBA rows from the north.
pub(crate) fn trees(dir: &Path) -> HashMap<(u8, u32, u32), Vec<u8>> {
    let make = r#"
from osgeo import gdal, osr
import numpy as np
ds = gdal.GetDriverByName('GTiff').Create('src.tif', 512, 512, 3, gdal.GDT_Byte)
h = 20037508.342789244
ds.SetGeoTransform([-h, 2 * h / 512, 0, h, 0, -2 * h / 512])
s = osr.SpatialReference(); s.ImportFromEPSG(3857); ds.SetProjection(s.ExportToWkt())
y, x = np.mgrid[0:512, 0:512]
ds.GetRasterBand(1).WriteArray(((x * 7) % 251).astype(np.uint8))
ds.GetRasterBand(2).WriteArray(((y * 5) % 253).astype(np.uint8))
ds.GetRasterBand(3).WriteArray(((x // 32 + 3 * (y // 32)) * 17 % 256).astype(np.uint8))
ds = None
"#;
    run_python(make, dir, &[]);
    for (args, out) in [(vec!["--xyz"], "xyz"), (vec![], "tms")] {
        let mut c = Command::new("gdal2tiles.py");
        c.args(&args).args(["-z", &format!("0-{MAX_ZOOM}"), "-q", "src.tif", out]).current_dir(dir);
        let o = c.output().expect("gdal2tiles.py (gdal-bin)");
        assert!(o.status.success(), "gdal2tiles.py {args:?}: {}", String::from_utf8_lossy(&o.stderr));
    }
    // GDAL's decode of each XYZ tile, and a check that the TMS tree holds the same tiles with
    // rows from the south.
    let decode = r#"
import sys, os
from osgeo import gdal
import numpy as np
for z in range(int(sys.argv[1]) + 1):
    n = 2 ** z
    for x in range(n):
        for y in range(n):
            a = gdal.Open(f'xyz/{z}/{x}/{y}.png').ReadAsArray()
            b = gdal.Open(f'tms/{z}/{x}/{n - 1 - y}.png').ReadAsArray()
            assert (a == b).all(), (z, x, y)
            if a.shape[0] == 3:
                a = np.concatenate([a, np.full((1,) + a.shape[1:], 255, np.uint8)])
            open(f'decoded/{z}_{x}_{y}.raw', 'wb').write(a.transpose(1, 2, 0).astype(np.uint8).tobytes())
"#;
    std::fs::create_dir_all(dir.join("decoded")).unwrap();
    run_python(decode, dir, &[MAX_ZOOM.to_string()]);
    let mut out = HashMap::new();
    for z in 0..=MAX_ZOOM {
        for x in 0..1u32 << z {
            for y in 0..1u32 << z {
                let raw = std::fs::read(dir.join(format!("decoded/{z}_{x}_{y}.raw"))).unwrap();
                assert_eq!(raw.len(), 256 * 256 * 4);
                out.insert((z, x, y), raw);
            }
        }
    }
    out
}

pub(crate) fn run_python(script: &str, dir: &Path, args: &[String]) {
    let o = Command::new(python()).arg("-c").arg(script).args(args).current_dir(dir).output().expect("python3");
    assert!(o.status.success(), "GDAL failed: {}", String::from_utf8_lossy(&o.stderr));
}

pub(crate) fn quick() -> RemoteOptions {
    RemoteOptions {
        timeout: Duration::from_millis(3000),
        connect_timeout: Duration::from_millis(500),
        retries: 2,
        backoff: Duration::from_millis(2),
        backoff_max: Duration::from_millis(40),
        ..RemoteOptions::default()
    }
}

pub(crate) fn open(text: &str) -> PyramidSource {
    let opts = OpenOptions {
        template: TemplateOptions { remote: Some(quick()), zooms: Some([0, MAX_ZOOM]), ..Default::default() },
        // A clip size of one tile: every level but the coarsest zooms' is read tile by tile.
        pyramid: PyramidOptions { clip_size: Some(256), ..Default::default() },
    };
    tiles::open(text, &opts).expect("a template").unwrap_or_else(|e| panic!("{text}: {e}"))
}

/// Reads every texture tile of the zooms' levels and compares each texel with GDAL's decode of
/// the pyramid tile at the same place: texture tile (s, t) of level k is tile x = s,
/// y = 2^z - 1 - t of zoom z = MAX_ZOOM - k, its texture row r the tile's row 255 - r.
pub(crate) fn every_texel_is_gdals(src: &PyramidSource, gdal: &HashMap<(u8, u32, u32), Vec<u8>>, what: &str) {
    assert_eq!(src.desc().size(), [1024, 1024], "{what}");
    let mut compared = 0u64;
    for k in 0..=u32::from(MAX_ZOOM) {
        let z = MAX_ZOOM - k as u8;
        let level = src.desc().level(k);
        assert_eq!(level.tile, [256, 256], "{what}: level {k}");
        let n = 1u64 << z;
        let mut buf = vec![0u8; src.desc().tile_bytes(k)];
        for t in 0..n {
            for s in 0..n {
                src.read_tile(TileId { level: k, s, t }, &mut buf).unwrap_or_else(|e| panic!("{what}: {e}"));
                let expected = &gdal[&(z, s as u32, (n - 1 - t) as u32)];
                for r in 0..256usize {
                    let got = &buf[r * 1024..(r + 1) * 1024];
                    let want = &expected[(255 - r) * 1024..(256 - r) * 1024];
                    assert!(got == want, "{what}: level {k} tile ({s}, {t}) texture row {r} differs from GDAL's decode of tile {z}/{s}/{}", n - 1 - t);
                }
                compared += 256 * 256;
            }
        }
    }
    assert_eq!(compared, (1024 * 1024 + 512 * 512 + 256 * 256) as u64, "{what}");
}

#[test]
fn gdal2tiles_xyz_and_tms_trees_serve_gdals_own_texels_from_disk_and_over_nginx() {
    let dir = tempfile::tempdir().unwrap();
    let gdal = trees(dir.path());
    let d = dir.path().display();
    every_texel_is_gdals(&open(&format!("xyz:{d}/xyz/{{z}}/{{x}}/{{y}}.png")), &gdal, "local XYZ");
    every_texel_is_gdals(&open(&format!("xyz:{d}/tms/{{z}}/{{x}}/{{-y}}.png")), &gdal, "local TMS");
    let nginx = Nginx::serve_images(dir.path());
    let url = nginx.url();
    let xyz = open(&format!("xyz:{url}/xyz/{{z}}/{{x}}/{{y}}.png"));
    every_texel_is_gdals(&xyz, &gdal, "XYZ over nginx");
    let stats = xyz.remote_stats().unwrap();
    assert_eq!((stats.requests, stats.failures), (21, 0), "one request a tile: {stats:?}");
    every_texel_is_gdals(&open(&format!("xyz:{url}/tms/{{z}}/{{x}}/{{-y}}.png")), &gdal, "TMS over nginx");
    // The coarser levels are built from zoom 0: level 3 (128²) is its 2x2 means.
    let src = open(&format!("xyz:{d}/xyz/{{z}}/{{x}}/{{y}}.png"));
    let mut half = vec![0u8; src.desc().tile_bytes(3)];
    src.read_tile(TileId { level: 3, s: 0, t: 0 }, &mut half).unwrap();
    let z0 = &gdal[&(0, 0, 0)];
    for (t, s, c) in [(0usize, 0usize, 0usize), (17, 90, 1), (127, 127, 2), (64, 3, 3)] {
        // Texture row t from the south covers zoom-0 rows 255 - 2t and 254 - 2t from the north.
        let at = |row: usize, col: usize| u32::from(z0[(row * 256 + col) * 4 + c]);
        let (r0, r1) = (255 - 2 * t, 254 - 2 * t);
        let sum = at(r0, 2 * s) + at(r0, 2 * s + 1) + at(r1, 2 * s) + at(r1, 2 * s + 1);
        assert_eq!(u32::from(half[(t * 128 + s) * 4 + c]), (sum + 2) / 4, "level 3 texel ({s}, {t}) component {c}");
    }
}

#[test]
fn a_404_storm_is_missing_tiles_and_an_html_page_is_an_error_never_texels() {
    let dir = tempfile::tempdir().unwrap();
    let gdal = trees(dir.path());
    let nginx = Nginx::serve_images(dir.path());
    // Every request answered 404 by the proxy: every tile missing, no texel published.
    let storm = Schedule { faults: Vec::new(), then: vec![Fault::NotFound], every: 1 };
    let proxy = FaultProxy::start(nginx.port, storm, 0);
    let src = open(&format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", proxy.url()));
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    for s in 0..4 {
        for t in 0..4 {
            let r = src.read_tile(TileId { level: 0, s, t }, &mut buf);
            assert!(matches!(r, Err(SourceError::Missing { .. })), "tile ({s}, {t}): {r:?}");
        }
    }
    assert_eq!(src.remote_stats().unwrap().retries, 0, "404 is not retried");
    drop(proxy);
    // A 200 HTML page for every other tile: those are errors naming the tile and what came,
    // the others GDAL's texels.
    let pages =
        Schedule { faults: Vec::new(), then: vec![Fault::Page { len: 900, html: true }, Fault::Pass], every: 1 };
    let proxy = FaultProxy::start(nginx.port, pages, 0);
    let src = open(&format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", proxy.url()));
    let (mut errors, mut good) = (0, 0);
    for s in 0..4u64 {
        for t in 0..4u64 {
            match src.read_tile(TileId { level: 0, s, t }, &mut buf) {
                Ok(()) => {
                    let expected = &gdal[&(2, s as u32, (3 - t) as u32)];
                    for r in 0..256usize {
                        assert!(
                            buf[r * 1024..(r + 1) * 1024] == expected[(255 - r) * 1024..(256 - r) * 1024],
                            "tile ({s}, {t}) row {r}"
                        );
                    }
                    good += 1;
                }
                Err(e) => {
                    let text = e.to_string();
                    assert!(
                        text.contains("text/html") && text.contains("expected an image") && text.contains("tile 2/"),
                        "{text}"
                    );
                    errors += 1;
                }
            }
        }
    }
    assert_eq!((errors, good), (8, 8));
    // An HTML page stored as a tile (served as image/png) is told by its bytes.
    std::fs::write(dir.path().join("xyz/2/1/1.png"), b"<!DOCTYPE html><html><body>Over quota</body></html>").unwrap();
    let src = open(&format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", nginx.url()));
    let e = src.read_tile(TileId { level: 0, s: 1, t: 2 }, &mut buf).unwrap_err().to_string();
    assert!(e.contains("tile 2/1/1") && e.contains("not an image") && e.contains("expected a png tile"), "{e}");
}

#[test]
fn cliptex_dump_of_a_template_writes_gdals_texels_with_the_north_up() {
    let dir = tempfile::tempdir().unwrap();
    let gdal = trees(dir.path());
    let out = dir.path().join("l1.png");
    let template = format!("xyz:{}/tms/{{z}}/{{x}}/{{-y}}.png", dir.path().display());
    let (o, _) = crate::common::exec(
        dir.path(),
        env!("CARGO_BIN_EXE_cliptex"),
        &["dump", &template, "--level", "1", "--out", out.to_str().unwrap()],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&out).unwrap().into_rgba8();
    assert_eq!(img.dimensions(), (512, 512));
    // The picture's top row is the north: its pixel (c, r) is zoom 1's tile (c / 256, r / 256) at
    // (c % 256, r % 256), as GDAL decodes it.
    for (c, r) in [(0u32, 0u32), (300, 10), (511, 511), (255, 256), (100, 400)] {
        let tile = &gdal[&(1, c / 256, r / 256)];
        let i = (((r % 256) * 256 + c % 256) * 4) as usize;
        assert_eq!(img.get_pixel(c, r).0[..], tile[i..i + 4], "pixel ({c}, {r})");
    }
}

#[test]
fn clipmapd_publishes_gdals_texels_of_a_gdal2tiles_tree_at_their_places() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = trees(d);
    let template = std::path::PathBuf::from(format!("xyz:{}/tms/{{z}}/{{x}}/{{-y}}.png", d.display()));
    // Clip 1024, the texture's size: every level is resident whole, every texel compared.
    let served = crate::common::gdal::Served::start(&template, 1024, "xyz", d);
    assert_eq!(served.client.bytes_per_texel, 4, "RGBA8 for PNG tiles");
    for k in 0..=usize::from(MAX_ZOOM) {
        served_level_is_gdals(&served, k, &gdal);
    }
}

#[test]
fn a_503_with_retry_after_is_retried_and_then_served() {
    let dir = tempfile::tempdir().unwrap();
    let gdal = trees(dir.path());
    let nginx = Nginx::serve_images(dir.path());
    let first = Schedule { faults: vec![Fault::Unavailable, Fault::Unavailable], then: Vec::new(), every: 0 };
    let proxy = FaultProxy::start(nginx.port, first, 0);
    let src = open(&format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", proxy.url()));
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    src.read_tile(TileId { level: 0, s: 2, t: 1 }, &mut buf).unwrap();
    let expected = &gdal[&(2, 2, 2)];
    assert!(buf[..1024] == expected[255 * 1024..], "texture row 0 is the tile's southern row");
    let stats = src.remote_stats().unwrap();
    assert_eq!((stats.requests, stats.retries, stats.failures), (3, 2, 0), "{stats:?}");
}

#[test]
fn a_key_in_a_header_never_reaches_a_message() {
    let dir = tempfile::tempdir().unwrap();
    trees(dir.path());
    let nginx = Nginx::serve_images(dir.path());
    let pages = Schedule { faults: Vec::new(), then: vec![Fault::Page { len: 300, html: true }], every: 1 };
    let proxy = FaultProxy::start(nginx.port, pages, 0);
    let opts = OpenOptions {
        template: TemplateOptions {
            remote: Some(quick()),
            zooms: Some([0, MAX_ZOOM]),
            headers: vec![("X-Api-Key".into(), "s3cr3t-k3y".into())],
            user_agent: Some("clipmap-tests/1 (tests@example.org)".into()),
            ..Default::default()
        },
        pyramid: PyramidOptions { clip_size: Some(256), ..Default::default() },
    };
    let src = tiles::open(&format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", proxy.url()), &opts).unwrap().unwrap();
    let mut buf = vec![0u8; src.desc().tile_bytes(0)];
    let e = src.read_tile(TileId { level: 0, s: 0, t: 0 }, &mut buf).unwrap_err();
    let text = format!("{e} {e:?}");
    assert!(text.contains("text/html") && !text.contains("s3cr3t"), "{text}");
    // A header that would split the request is refused, without its value.
    let bad = OpenOptions {
        template: TemplateOptions {
            headers: vec![("X-Api-Key".into(), "s3cr3t\r\nHost: evil".into())],
            ..Default::default()
        },
        ..Default::default()
    };
    let e = tiles::open("xyz:https://tile.example.org/{z}/{x}/{y}.png", &bad).unwrap().unwrap_err().to_string();
    assert!(e.contains("header \"X-Api-Key\"") && !e.contains("s3cr3t"), "{e}");
}

/// Packs the XYZ tree's PNG tiles (gdal2tiles.py's, zooms 0..MAX_ZOOM) into `tree.pmtiles` with
/// the reference PMTiles writer and into `tree.mbtiles` (TMS rows, with its metadata) with
/// Python's sqlite3 module: the same encoded tiles in both archives.
pub(crate) fn archives_of_the_tree(dir: &Path) {
    let pack = r#"
import sqlite3, sys
from pmtiles.tile import Compression, TileType, zxy_to_tileid
from pmtiles.writer import Writer
top = int(sys.argv[1])
tiles = sorted((zxy_to_tileid(z, x, y), open(f'xyz/{z}/{x}/{y}.png', 'rb').read(), z, x, y)
               for z in range(top + 1) for x in range(2 ** z) for y in range(2 ** z))
with open('tree.pmtiles', 'wb') as f:
    w = Writer(f)
    for tid, data, *_ in tiles:
        w.write_tile(tid, data)
    w.finalize({'tile_type': TileType.PNG, 'tile_compression': Compression.NONE, 'min_zoom': 0, 'max_zoom': top,
                'min_lon_e7': int(-180e7), 'min_lat_e7': int(-85.0511287e7), 'max_lon_e7': int(180e7), 'max_lat_e7': int(85.0511287e7)},
               {'name': 'tree'})
db = sqlite3.connect('tree.mbtiles')
db.execute('CREATE TABLE metadata (name TEXT, value TEXT)')
db.execute('CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER, tile_data BLOB)')
db.executemany('INSERT INTO metadata VALUES (?, ?)', [('name', 'tree'), ('format', 'png'), ('minzoom', '0'), ('maxzoom', str(top)), ('bounds', '-180,-85.0511,180,85.0511')])
db.executemany('INSERT INTO tiles VALUES (?, ?, ?, ?)', [(z, x, 2 ** z - 1 - y, data) for _, data, z, x, y in tiles])
db.commit()
"#;
    run_python(pack, dir, &[MAX_ZOOM.to_string()]);
}

#[test]
fn pmtiles_and_mbtiles_of_gdal2tiles_png_serve_gdals_own_texels_locally_and_over_nginx() {
    let dir = tempfile::tempdir().unwrap();
    let gdal = trees(dir.path());
    archives_of_the_tree(dir.path());
    let d = dir.path().display();
    every_texel_is_gdals(&open(&format!("{d}/tree.pmtiles")), &gdal, "local PMTiles");
    every_texel_is_gdals(&open(&format!("{d}/tree.mbtiles")), &gdal, "local MBTiles");
    // A tile size given on the command line is the one served, and tiles of another size are
    // refused before a byte is decoded, never turned into texels.
    let given = |size| OpenOptions {
        template: TemplateOptions { tile_size: Some(size), ..Default::default() },
        pyramid: PyramidOptions { clip_size: Some(256), ..Default::default() },
    };
    let right = tiles::open(&format!("{d}/tree.pmtiles"), &given(256)).unwrap().unwrap();
    every_texel_is_gdals(&right, &gdal, "local PMTiles, --tile-size 256");
    let wrong = tiles::open(&format!("{d}/tree.pmtiles"), &given(512)).unwrap().unwrap();
    assert_eq!(wrong.desc().size(), [2048, 2048], "--tile-size 512 is served as given");
    let mut buf = vec![0u8; wrong.desc().tile_bytes(0)];
    let e = wrong.read_tile(TileId { level: 0, s: 0, t: 0 }, &mut buf).expect_err("a 256-texel tile served as 512");
    assert!(!matches!(e, SourceError::Missing { .. }), "{e}");
    let nginx = Nginx::serve_images(dir.path());
    let src = open(&format!("{}/tree.pmtiles", nginx.url()));
    every_texel_is_gdals(&src, &gdal, "PMTiles over nginx");
    let stats = src.remote_stats().expect("a remote archive counts its requests");
    // The open (header and root directory: one request of at most 16 KiB), at most one more for
    // the first tile's size, then at most one request for each of the 21 tiles.
    assert!(stats.requests <= 2 + 21, "{stats:?}");
    assert_eq!(stats.failures, 0, "{stats:?}");
}

#[test]
fn clipmapd_takes_centres_in_lonlat_on_a_gdal2tiles_tree_as_cliptex_locate_places_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    trees(d);
    let template = format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", d.display());
    let served = crate::common::gdal::Served::start(std::path::Path::new(&template), 256, "xyzll", d);
    // cliptex info: the WebMercatorQuad, as a COG's georef.
    let info =
        std::process::Command::new(env!("CARGO_BIN_EXE_cliptex")).args(["info", "--json", &template]).output().unwrap();
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    assert_eq!(info["georef"]["epsg"], 3857, "{info}");
    let h = 20037508.342789244;
    let side = 256.0 * f64::from(1u32 << MAX_ZOOM);
    assert_eq!(info["georef"]["geotransform"], serde_json::json!([-h, 2.0 * h / side, 0.0, h, 0.0, -2.0 * h / side]));
    let points = [[13.4, 52.5], [-122.42, 37.77], [0.0001, -0.0001], [-179.9, 80.0]];
    crate::georef::centre_lonlat_lands_on_locates_texel(&template, &d.join("xyzll.sock"), d, &points);
    drop(served);
}

/// Waits until level `k` of the served texture is valid whole and compares each of its texels
/// with GDAL's decode of the pyramid tile there (rows flipped to texture orientation).
fn served_level_is_gdals(served: &crate::common::gdal::Served, k: usize, gdal: &HashMap<(u8, u32, u32), Vec<u8>>) {
    let c = &served.client;
    let z = MAX_ZOOM - k as u8;
    let side = 1024u64 >> k;
    let n = 1u64 << z;
    let t0 = std::time::Instant::now();
    let texels = loop {
        if let Some(st) = c.level_state(k) {
            if st.enabled && st.valid == [0, 0, side as i64, side as i64] {
                let mut buf = vec![0u8; (side * side * 4) as usize];
                if c.read_region(k, 0, 0, side, side, &mut buf).is_ok() {
                    break buf;
                }
            }
        }
        assert!(t0.elapsed() < Duration::from_secs(30), "level {k} never became valid\n{}", served.log());
        std::thread::sleep(Duration::from_millis(5));
    };
    for t in 0..side {
        for s in 0..side {
            let tile = &gdal[&(z, (s / 256) as u32, (n - 1 - t / 256) as u32)];
            let i = (((255 - t % 256) * 256 + s % 256) * 4) as usize;
            let at = ((t * side + s) * 4) as usize;
            assert_eq!(texels[at..at + 4], tile[i..i + 4], "level {k} texel ({s}, {t})\n{}", served.log());
        }
    }
}

fn cliptex(dir: &Path, args: &[&str]) -> (std::process::ExitStatus, String) {
    let (o, _) = crate::common::exec(dir, env!("CARGO_BIN_EXE_cliptex"), args);
    (o.status, format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)))
}

#[test]
fn cliptex_check_of_a_tree_with_a_tile_removed_says_the_tile_source_has_none_there() {
    let dir = tempfile::tempdir().unwrap();
    trees(dir.path());
    // A tree one zoom deeper (2048², more than the check's clip of 1024, so level 0 is read in
    // tiles of 256): zoom 3's tile x 2, y 5 (from the north) is level 0's tile (2, 2).
    let o = Command::new("gdal2tiles.py")
        .args(["--xyz", "-z", "0-3", "-q", "src.tif", "xyz3"])
        .current_dir(dir.path())
        .output()
        .expect("gdal2tiles.py (gdal-bin)");
    assert!(o.status.success(), "gdal2tiles.py: {}", String::from_utf8_lossy(&o.stderr));
    std::fs::remove_file(dir.path().join("xyz3/3/2/5.png")).unwrap();
    let template = format!("xyz:{}/xyz3/{{z}}/{{x}}/{{y}}.png", dir.path().display());
    let (o, desc) = crate::common::exec(dir.path(), env!("CARGO_BIN_EXE_cliptex"), &["check", &template, "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}: {desc}"));
    let problems = v["problems"].as_array().unwrap();
    assert_eq!(problems.len(), 1, "{v}");
    let p = &problems[0];
    assert_eq!((p["level"].as_u64(), p["s"].as_u64(), p["t"].as_u64()), (Some(0), Some(2), Some(2)), "{p}");
    assert_eq!(p["problem"], "missing", "{p}");
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains("the tile source has no tile there"), "{detail}");
    assert!(!detail.contains("byte count"), "not a COG's wording: {detail}");
}

#[test]
fn clipprep_input_of_a_template_pmtiles_or_mbtiles_writes_a_ct_naming_it_that_clipmapd_serves_as_the_source() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = trees(d);
    archives_of_the_tree(d);
    let inputs = [
        ("tms", format!("xyz:{}/tms/{{z}}/{{x}}/{{-y}}.png", d.display())),
        ("pm", d.join("tree.pmtiles").display().to_string()),
        ("mb", d.join("tree.mbtiles").display().to_string()),
    ];
    for (name, input) in &inputs {
        let out = d.join(format!("cfg-{name}"));
        let (o, _) = crate::common::exec(
            d,
            env!("CARGO_BIN_EXE_clipprep"),
            &["--input", input, "--clip", "1024", "--json", "--out", out.to_str().unwrap()],
        );
        assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(
            (v["config_only"].as_bool(), v["size"].clone()),
            (Some(true), serde_json::json!([1024, 1024])),
            "{v}"
        );
        // Only the configuration: a .ct and its .ic files, no tile.
        let files: Vec<String> =
            std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        assert!(files.iter().all(|f| f.ends_with(".ct") || f.ends_with(".ic")), "{name}: {files:?}");
        let ct = out.join(format!("cfg-{name}.ct"));
        let text = std::fs::read_to_string(&ct).unwrap();
        assert!(text.contains(&format!("#clipmap source {input}")), "{name}: {text}");
        // Served by clipmapd: every texel of every zoom's level is GDAL's.
        let served = crate::common::gdal::Served::start(&ct, 1024, &format!("ct{name}"), d);
        assert_eq!(served.client.bytes_per_texel, 4);
        for k in 0..=usize::from(MAX_ZOOM) {
            served_level_is_gdals(&served, k, &gdal);
        }
    }
    // A pyramid's --input refuses conversions.
    let (o, _) = crate::common::exec(
        d,
        env!("CARGO_BIN_EXE_clipprep"),
        &["--input", &inputs[1].1, "--clip", "256", "--tile", "512", "--out", d.join("bad").to_str().unwrap()],
    );
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--tile 512") && !d.join("bad").exists());
}

#[test]
fn a_ct_naming_a_tile_source_by_a_relative_path_is_served_and_strict_validation_names_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = trees(d);
    let out = d.join("cfg");
    let (o, _) = crate::common::exec(
        d,
        env!("CARGO_BIN_EXE_clipprep"),
        &["--input", &format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", d.display()), "--clip", "1024", "--out", "cfg"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The line written by hand, relative to the .ct's directory.
    let ct = out.join("cfg.ct");
    let text = std::fs::read_to_string(&ct).unwrap();
    let line = text.lines().position(|l| l.starts_with("#clipmap source ")).unwrap() + 1;
    let text: String = text
        .lines()
        .map(|l| if l.starts_with("#clipmap source ") { "#clipmap source xyz:../xyz/{z}/{x}/{y}.png" } else { l })
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&ct, text).unwrap();
    let (status, text) = cliptex(d, &["validate", "cfg/cfg.ct"]);
    assert!(status.success(), "{text}");
    assert!(text.contains("note: `#clipmap source` serves the clip texture's texels from the tile source"), "{text}");
    let (status, text) = cliptex(d, &["validate", "--strict", "cfg/cfg.ct"]);
    assert_eq!(status.code(), Some(1), "{text}");
    assert!(text.contains(&format!("cfg.ct:{line}:10: error: `#clipmap source`")), "{text}");
    assert!(text.contains("which Performer 3.0 does not know"), "{text}");
    let (_, text) = cliptex(d, &["validate", "--strict", "--json", "cfg/cfg.ct"]);
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let codes: Vec<&str> =
        v["files"][0]["diagnostics"].as_array().unwrap().iter().filter_map(|d| d["code"].as_str()).collect();
    assert!(codes.contains(&"source-extension"), "{v}");
    let (status, text) = cliptex(d, &["info", "cfg/cfg.ct"]);
    assert!(status.success(), "{text}");
    assert!(
        text.contains(&format!("texels from the tile source xyz:{}", out.join("../xyz/{z}/{x}/{y}.png").display())),
        "{text}"
    );
    let served = crate::common::gdal::Served::start(&ct, 1024, "ctrel", d);
    for k in 0..=usize::from(MAX_ZOOM) {
        served_level_is_gdals(&served, k, &gdal);
    }
    drop(served);
    // A value that names no tile source, and a second source line, are errors at their lines.
    let bad = std::fs::read_to_string(&ct).unwrap().replace("xyz:../xyz/{z}/{x}/{y}.png", "../earth.tif");
    std::fs::write(out.join("bad.ct"), bad).unwrap();
    let (status, text) = cliptex(d, &["validate", "cfg/bad.ct"]);
    assert_eq!(status.code(), Some(1), "{text}");
    assert!(text.contains("`#clipmap source` names no tile source") && text.contains("#clipmap cog"), "{text}");
}

#[test]
fn a_pmtiles_of_brotli_tiles_packed_by_the_reference_writer_serves_gdals_texels() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = trees(d);
    // The reference writer stores tiles as given and says how they are compressed: the PNG tiles
    // compressed with brotli here (the `brotli` crate's encoder), the header saying BROTLI.
    std::fs::create_dir_all(d.join("br")).unwrap();
    let params = brotli::enc::BrotliEncoderParams { quality: 9, ..Default::default() };
    for z in 0..=MAX_ZOOM {
        for x in 0..1u32 << z {
            for y in 0..1u32 << z {
                let png = std::fs::read(d.join(format!("xyz/{z}/{x}/{y}.png"))).unwrap();
                let mut out = Vec::new();
                brotli::BrotliCompress(&mut &png[..], &mut out, &params).unwrap();
                assert_ne!(out, png);
                std::fs::write(d.join(format!("br/{z}_{x}_{y}.br")), out).unwrap();
            }
        }
    }
    let pack = r#"
import sys
from pmtiles.tile import Compression, TileType, zxy_to_tileid
from pmtiles.writer import Writer
top = int(sys.argv[1])
tiles = sorted((zxy_to_tileid(z, x, y), open(f'br/{z}_{x}_{y}.br', 'rb').read())
               for z in range(top + 1) for x in range(2 ** z) for y in range(2 ** z))
with open('br.pmtiles', 'wb') as f:
    w = Writer(f)
    for tid, data in tiles:
        w.write_tile(tid, data)
    w.finalize({'tile_type': TileType.PNG, 'tile_compression': Compression.BROTLI, 'min_zoom': 0, 'max_zoom': top,
                'min_lon_e7': int(-180e7), 'min_lat_e7': int(-85.0511287e7), 'max_lon_e7': int(180e7), 'max_lat_e7': int(85.0511287e7)},
               {'name': 'br'})
"#;
    run_python(pack, d, &[MAX_ZOOM.to_string()]);
    every_texel_is_gdals(&open(&format!("{}/br.pmtiles", d.display())), &gdal, "PMTiles of brotli tiles");
}

#[test]
fn a_ct_whose_header_does_not_describe_its_tile_source_is_a_source_mismatch_at_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    trees(d);
    let (o, _) = crate::common::exec(
        d,
        env!("CARGO_BIN_EXE_clipprep"),
        &["--input", &format!("xyz:{}/xyz/{{z}}/{{x}}/{{y}}.png", d.display()), "--clip", "1024", "--out", "cfg"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ct = d.join("cfg/cfg.ct");
    let text = std::fs::read_to_string(&ct).unwrap();
    // What clipprep wrote describes the pyramid: no mismatch.
    let (status, out) = cliptex(d, &["validate", "cfg/cfg.ct"]);
    assert!(status.success() && !out.contains("source-mismatch"), "{out}");
    // The PNG tiles are RGBA8; a .ct saying RGB8 is refused at its format lines. (A wrong
    // `virt_size` also changes how many image cache levels the file must list, an error that
    // `validate` reports first: the format is the header field that changes nothing else.)
    assert!(text.contains("int_format PFTEX_RGBA_8") && text.contains("img_format PFTEX_RGBA\n"), "{text}");
    let line = text.lines().position(|l| l.trim_start().starts_with("ext_format")).expect("an ext_format line") + 1;
    let bad = text
        .replace("int_format PFTEX_RGBA_8", "int_format PFTEX_RGB_8")
        .replace("img_format PFTEX_RGBA\n", "img_format PFTEX_RGB\n");
    std::fs::write(d.join("cfg/bad.ct"), bad).unwrap();
    // Its image cache says the same (a file whose levels disagree is another error).
    let ic = std::fs::read_to_string(d.join("cfg/L00.ic")).unwrap();
    let ic = ic
        .replace("int_format PFTEX_RGBA_8", "int_format PFTEX_RGB_8")
        .replace("img_format PFTEX_RGBA\n", "img_format PFTEX_RGB\n");
    std::fs::write(d.join("cfg/L00.ic"), ic).unwrap();
    let (status, out) = cliptex(d, &["validate", "cfg/bad.ct"]);
    assert_eq!(status.code(), Some(1), "{out}");
    assert!(out.contains(&format!("bad.ct:{line}:")), "at the format lines: {out}");
    assert!(
        out.contains("error: `ext_format / int_format / img_format` does not describe the tile source `xyz:"),
        "{out}"
    );
    assert!(out.to_lowercase().contains("rgba8 texels (rgb8 for jpeg tiles, rgba8 otherwise)"), "{out}");
    let (_, out) = cliptex(d, &["validate", "--json", "cfg/bad.ct"]);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let codes: Vec<&str> =
        v["files"][0]["diagnostics"].as_array().unwrap().iter().filter_map(|d| d["code"].as_str()).collect();
    assert!(codes.contains(&"source-mismatch"), "{v}");
    // Nor is it served: `cliptex info` says why.
    let (status, out) = cliptex(d, &["info", "cfg/bad.ct"]);
    assert!(!status.success() && out.contains("does not describe the tile source"), "{out}");
}
