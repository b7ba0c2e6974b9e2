//! `cliptex check` end to end: `clipprep` writes a hash pyramid into a temporary directory, tiles
//! are deleted, truncated and locked, and the real `cliptex check` must count each per level, use
//! a default tile where one is named, and exit 0 / 1 / 2 as documented.

use crate::common;
use common::exec;
use serde_json::Value;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

const CLIPPREP: &str = env!("CARGO_BIN_EXE_clipprep");
const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");

/// A 256 x 256 RGB8 hash pyramid with 32-texel tiles and clip 32 under `dir/tex`; returns the `.ct`.
fn prepare(dir: &Path) -> PathBuf {
    let out = dir.join("tex");
    let args = ["--source", "hash", "--size", "256", "--tile", "32", "--clip", "32", "--format", "rgb8", "--json"];
    let mut all = args.to_vec();
    all.extend_from_slice(&["--out", out.to_str().unwrap()]);
    let (o, d) = exec(dir, CLIPPREP, &all);
    assert!(o.status.success(), "{d}");
    let summary: Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}\n{d}"));
    let ct = PathBuf::from(summary["ct"].as_str().expect("the summary names the .ct"));
    if ct.is_absolute() {
        ct
    } else {
        out.join(ct)
    }
}

/// Runs `cliptex check CT --json`; returns the exit code and the report.
fn check(dir: &Path, ct: &Path) -> (i32, Value, String) {
    let (o, d) = exec(dir, CLIPTEX, &["check", ct.to_str().unwrap(), "--json"]);
    let v = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("not JSON: {e}\n{d}"));
    (o.status.code().unwrap(), v, d)
}

fn counts(level: &Value) -> [u64; 6] {
    ["tiles", "present", "missing", "short", "unreadable", "default_covered"].map(|k| level[k].as_u64().unwrap())
}

/// Whether this process reads files whatever their mode (root): a real probe, not a user id.
fn permissions_ignored(dir: &Path) -> bool {
    let probe = dir.join("probe");
    std::fs::write(&probe, b"x").unwrap();
    std::fs::set_permissions(&probe, std::fs::Permissions::from_mode(0o000)).unwrap();
    let ignored = std::fs::File::open(&probe).is_ok();
    std::fs::remove_file(&probe).unwrap();
    ignored
}

#[test]
fn an_intact_pyramid_is_servable_and_printed_as_a_table() {
    let dir = tempfile::tempdir().unwrap();
    let ct = prepare(dir.path());
    let (code, r, d) = check(dir.path(), &ct);
    assert_eq!(code, 0, "{d}");
    assert_eq!(r["servable"], true);
    // Levels 256, 128, 64 are image caches of 8x8, 4x4 and 2x2 tiles; 6 pyramid levels follow.
    let levels = r["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 9);
    assert_eq!(counts(&levels[0]), [64, 64, 0, 0, 0, 0]);
    assert_eq!(counts(&levels[2]), [4, 4, 0, 0, 0, 0]);
    assert_eq!((levels[3]["kind"].as_str(), counts(&levels[3])), (Some("pyramid"), [1, 1, 0, 0, 0, 0]));
    assert_eq!(r["totals"]["present"], 64 + 16 + 4 + 6);
    let (o, d) = exec(dir.path(), CLIPTEX, &["check", ct.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{d}");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("90 of 90 tiles servable") && text.contains("every tile can be served"), "{d}");
    let (o, d) = exec(dir.path(), CLIPTEX, &["check", ct.to_str().unwrap(), "--quiet"]);
    assert_eq!((o.status.code(), o.stdout.len(), o.stderr.len()), (Some(0), 0, 0), "quiet and fine: silent\n{d}");
}

#[test]
fn missing_short_and_unreadable_tiles_are_counted_per_level_and_fail_the_check() {
    let dir = tempfile::tempdir().unwrap();
    let ct = prepare(dir.path());
    let root = ct.parent().unwrap();
    std::fs::remove_file(root.join("L00/r000.c001.raw")).unwrap();
    std::fs::remove_file(root.join("L00/r000.c002.raw")).unwrap();
    std::fs::write(root.join("L01/r001.c001.raw"), [0u8; 100]).unwrap();
    std::fs::write(root.join("pyramid/L04.raw"), [0u8; 3]).unwrap();
    let locked = root.join("L02/r000.c000.raw");
    std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o000)).unwrap();
    let root_reads_all = permissions_ignored(dir.path());

    let (code, r, d) = check(dir.path(), &ct);
    assert_eq!(code, 1, "{d}");
    assert_eq!(r["servable"], false);
    let levels = r["levels"].as_array().unwrap();
    assert_eq!(counts(&levels[0]), [64, 62, 2, 0, 0, 0], "{d}");
    assert_eq!(counts(&levels[1]), [16, 15, 0, 1, 0, 0], "{d}");
    assert_eq!(counts(&levels[4]), [1, 0, 0, 1, 0, 0], "a pyramid file of the wrong size\n{d}");
    if root_reads_all {
        eprintln!("skipping the unreadable-tile count: this process reads files whatever their mode (root)");
        assert_eq!(counts(&levels[2]), [4, 4, 0, 0, 0, 0]);
    } else {
        assert_eq!(counts(&levels[2]), [4, 3, 0, 0, 1, 0], "{d}");
    }
    let problems = r["problems"].as_array().unwrap();
    assert!(problems.iter().any(|p| p["level"] == 0 && p["s"] == 1 && p["t"] == 0 && p["problem"] == "missing"), "{d}");
    let (o, d) = exec(dir.path(), CLIPTEX, &["check", ct.to_str().unwrap(), "-q"]);
    assert_eq!(o.status.code(), Some(1), "{d}");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("level 0 tile (2, 0): Missing") && text.contains("some tiles cannot be served"), "{d}");
}

#[test]
fn compressed_tiles_are_checked_by_their_frame_header_not_their_length() {
    // Terrain compresses well: every tile file is far shorter than a raw tile, and must not be
    // counted as short. A file that is not a zstd frame of one tile is corrupt.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("z");
    let args = ["--source", "terrain", "--size", "256", "--tile", "32", "--clip", "32", "--format", "rgb8"];
    let (o, d) = exec(dir.path(), CLIPPREP, &[&args[..], &["--zstd", "3", "--out", out.to_str().unwrap()]].concat());
    assert!(o.status.success(), "{d}");
    let ct = out.join("z.ct");
    let l0 = out.join("L00");
    assert!(std::fs::metadata(l0.join("r000.c000.raw.zst")).unwrap().len() < 32 * 32 * 3, "terrain compresses");
    let (code, r, d) = check(dir.path(), &ct);
    assert_eq!((code, &r["servable"]), (0, &Value::Bool(true)), "{d}");
    assert_eq!(r["totals"]["corrupt"], 0, "{d}");
    std::fs::write(l0.join("r000.c001.raw.zst"), b"not a frame").unwrap();
    std::fs::write(l0.join("r000.c002.raw.zst"), zstd_frame_of(100)).unwrap();
    let (code, r, d) = check(dir.path(), &ct);
    assert_eq!(code, 1, "{d}");
    assert_eq!(r["levels"][0]["corrupt"], 2, "{d}");
    assert_eq!(counts(&r["levels"][0]), [64, 62, 0, 0, 0, 0], "{d}");
    let problems = r["problems"].as_array().unwrap();
    assert!(problems.iter().all(|p| p["problem"] == "corrupt" && p["level"] == 0), "{d}");
}

/// A well-formed zstd frame of `n` bytes (not one tile).
fn zstd_frame_of(n: usize) -> Vec<u8> {
    zstd::bulk::compress(&vec![9u8; n], 3).unwrap()
}

#[test]
fn a_default_tile_covers_missing_and_short_tiles() {
    let dir = tempfile::tempdir().unwrap();
    let ct = prepare(dir.path());
    let root = ct.parent().unwrap();
    std::fs::remove_file(root.join("L00/r003.c004.raw")).unwrap();
    std::fs::write(root.join("L00/r005.c005.raw"), [0u8; 10]).unwrap();
    let ic = root.join("L00.ic");
    let text = std::fs::read_to_string(&ic).unwrap() + "default_tile sea.raw\n";
    std::fs::write(&ic, text).unwrap();
    // No default tile file yet: it cannot cover anything.
    let (code, r, d) = check(dir.path(), &ct);
    assert_eq!(code, 1, "{d}");
    assert_eq!(r["levels"][0]["default_tile"]["usable"], false, "{d}");
    assert_eq!(counts(&r["levels"][0]), [64, 62, 1, 1, 0, 0]);
    std::fs::write(root.join("sea.raw"), vec![7u8; 32 * 32 * 3]).unwrap();
    let (code, r, d) = check(dir.path(), &ct);
    assert_eq!(code, 0, "{d}");
    assert_eq!(counts(&r["levels"][0]), [64, 62, 1, 1, 0, 2]);
    assert_eq!(r["totals"]["default_covered"], 2);
    let problems = r["problems"].as_array().unwrap();
    assert!(problems.iter().all(|p| p["default_covered"] == true), "{d}");
}

#[test]
fn a_configuration_that_cannot_be_read_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let (o, d) = exec(dir.path(), CLIPTEX, &["check", "nothing-here.ct"]);
    assert_eq!(o.status.code(), Some(2), "{d}");
    std::fs::write(dir.path().join("bad.ct"), "ct_version2.0\nvirt_size 64 64 1\n").unwrap();
    let (o, d) = exec(dir.path(), CLIPTEX, &["check", "bad.ct", "--json"]);
    assert_eq!(o.status.code(), Some(1), "an invalid configuration is bad input, as for `info`\n{d}");
}
