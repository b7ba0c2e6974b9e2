//! Every byte of a remote COG is fetched once by a process: the tools and the service read each
//! TIFF tile's range once (the first bytes read at open are not fetched again, the bytes a
//! merged request passes over are kept for the tiles lying there, the image the coarse levels
//! are built from serves its own tiles), counted at the server, and `STATS` counts any byte
//! fetched twice (`duplicate_reads`, `duplicate_bytes`) so that a regression shows.

use crate::common::gdal::{python, Served};
use crate::common::remote::PyServer;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

/// A 2048 x 2048 RGB COG written by GDAL (deflate, 256-texel tiles, its own overviews).
fn gdal_cog(dir: &Path) {
    let script = r#"
from osgeo import gdal
import numpy as np
n = 2048
d = gdal.GetDriverByName('MEM').Create('', n, n, 3, gdal.GDT_Byte)
y, x = np.mgrid[0:n, 0:n].astype(np.uint32)
for b in range(3):
    d.GetRasterBand(b + 1).WriteArray(((x * (7 + 13 * b) + y * (3 + 5 * b)) // 5 % 251).astype(np.uint8))
gdal.Translate('a.tif', d, format='COG', creationOptions=['BLOCKSIZE=256', 'COMPRESS=DEFLATE'])
"#;
    let out = Command::new(python()).args(["-c", script]).current_dir(dir).output().unwrap();
    assert!(out.status.success(), "GDAL failed: {}", String::from_utf8_lossy(&out.stderr));
}

/// The byte ranges the server was asked for (`GET` lines with a `bytes=A-B` range), in order.
fn ranges(server: &PyServer) -> Vec<(u64, u64)> {
    server
        .requests()
        .iter()
        .filter_map(|l| {
            let r = l.split(' ').nth(2)?.strip_prefix("bytes=")?;
            let (a, b) = r.split_once('-')?;
            Some((a.parse().ok()?, b.parse::<u64>().ok()? + 1))
        })
        .collect()
}

/// The bytes asked for more than once among `ranges` (brute force over a byte map).
fn twice(ranges: &[(u64, u64)]) -> u64 {
    let end = ranges.iter().map(|r| r.1).max().unwrap_or(0) as usize;
    let mut seen = vec![0u8; end];
    let mut dup = 0;
    for &(a, b) in ranges {
        for s in &mut seen[a as usize..b as usize] {
            dup += u64::from(*s > 0);
            *s = 1;
        }
    }
    dup
}

/// Hedging off: a hedge asks the server for a range once more on purpose (counted as `hedged`,
/// not as a duplicate), and on a loaded machine a loopback request can wait long enough to be
/// hedged; this test counts the ranges the server sees.
const NO_HEDGES: [(&str, &str); 1] = [("CLIPMAP_REMOTE_HEDGE_PERCENT", "0")];

fn cliptex(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex")).envs(NO_HEDGES).args(args).output().unwrap();
    assert!(out.status.success(), "cliptex {args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

fn ask(socket: &Path, line: &str) -> String {
    use std::io::{BufRead, BufReader, Write};
    let mut s = std::os::unix::net::UnixStream::connect(socket).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    writeln!(s, "{line}").unwrap();
    let mut r = String::new();
    BufReader::new(s).read_line(&mut r).unwrap();
    r.trim_end().to_string()
}

#[test]
fn a_gdal_cog_over_http_has_each_byte_fetched_once_by_the_tools_and_the_service() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    gdal_cog(d);
    let size = std::fs::metadata(d.join("a.tif")).unwrap().len();
    let server = PyServer::serve(d, true);
    let url = format!("{}/a.tif", server.url());

    // `cliptex dump` of level 0 and `cliptex check`, each a process of its own: every range
    // once within each.
    let png = d.join("l0.png");
    cliptex(&["dump", &url, "--level", "0", "--out", png.to_str().unwrap(), "-q"]);
    let dump = ranges(&server);
    assert!(dump.len() >= 64, "64 tiles of level 0 and the open: {dump:?}");
    assert_eq!(twice(&dump), 0, "cliptex dump fetched bytes twice: {dump:?}");
    cliptex(&["check", &url, "-q"]);
    let check = ranges(&server)[dump.len()..].to_vec();
    assert_eq!(twice(&check), 0, "cliptex check fetched bytes twice: {check:?}");
    let bytes: u64 = check.iter().map(|r| r.1 - r.0).sum();
    assert!(bytes <= size, "cliptex check read {bytes} bytes of a {size}-byte file: {check:?}");

    // The service at its open (the first window at the texture's middle and the coarse
    // levels): no byte fetched twice, at the server and in STATS.
    let before = ranges(&server).len();
    let requests_before = server.requests().len();
    let at_server = || server.requests().len() - requests_before;
    let served = Served::start_with(Path::new(&url), 512, "once", d, &NO_HEDGES);
    let socket = d.join("once.sock");
    let stats = settled(&socket, at_server);
    let remote = &stats["remote"];
    assert!(remote["requests"].as_u64().unwrap() > 2, "{remote}");
    let open = ranges(&server)[before..].to_vec();
    let log = server.requests()[before..].join("\n");
    assert_eq!(twice(&open), 0, "the service's open fetched bytes twice: {remote}\n{log}");
    assert_eq!(remote["duplicate_reads"], 0, "{remote}\n{}", served.log());
    assert_eq!(remote["duplicate_bytes"], 0, "{remote}");

    // Flown towards a corner: STATS counts exactly the bytes the server was asked for twice
    // (a tile whose slot the cache gave to another, read again when the window needs it again,
    // is fetched again: the disk cache is what keeps such tiles).
    for step in 1..12u64 {
        let s = 1024 + step * 72;
        let r = ask(&socket, &format!("CENTRE {s} {s}"));
        assert!(r.starts_with("OK"), "{r}\n{}", served.log());
        std::thread::sleep(Duration::from_millis(150));
    }
    let stats = settled(&socket, at_server);
    let service = ranges(&server)[before..].to_vec();
    assert_eq!(stats["remote"]["duplicate_bytes"].as_u64(), Some(twice(&service)), "{}", stats["remote"]);
}

/// STATS once the reads have settled (two replies a quarter of a second apart count the same
/// requests, and the server has logged as many as the service sent: a loaded machine can pause
/// the service for a quarter of a second mid-flight), within 30 s.
fn settled(socket: &Path, at_server: impl Fn() -> usize) -> serde_json::Value {
    let t = Instant::now();
    let v = |r: &str| -> serde_json::Value { serde_json::from_str(r.strip_prefix("OK ").unwrap()).unwrap() };
    loop {
        let a = v(&ask(socket, "STATS"));
        std::thread::sleep(Duration::from_millis(250));
        let b = v(&ask(socket, "STATS"));
        let sent = b["remote"]["requests"].as_u64().unwrap();
        if (a["remote"]["requests"] == b["remote"]["requests"]
            && a["engine"]["tiles_read"] == b["engine"]["tiles_read"]
            && sent == at_server() as u64)
            || t.elapsed() > Duration::from_secs(30)
        {
            return b;
        }
    }
}
