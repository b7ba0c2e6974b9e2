//! `cliptex roam` end to end: the real binary flies over the procedural hash texture and over the
//! checked-in prepared pyramid (run from an unrelated working directory), and the JSON report
//! keeps its contract: per-frame rows, totals, no texel copied by any tick, and exactly the tiles
//! a steady flight brings into the mem regions read, each once.

use crate::common;
use serde_json::Value;
use std::path::Path;
use std::process::Output;

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");

/// Runs `cliptex` in `cwd`; returns the output and a description for failure messages.
fn cliptex(cwd: &Path, args: &[&str]) -> (Output, String) {
    common::exec(cwd, CLIPTEX, args)
}

/// Runs a roam that must succeed with `--json`; returns the report.
fn roam_json(cwd: &Path, args: &[&str]) -> Value {
    let mut all = vec!["roam"];
    all.extend_from_slice(args);
    all.push("--json");
    let (out, d) = cliptex(cwd, &all);
    assert_eq!(out.status.code(), Some(0), "{d}");
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("not JSON: {e}\n{d}"))
}

fn u(v: &Value) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("not an unsigned integer: {v}"))
}

/// Checks the JSON contract and returns (clip, bytes per texel, level sizes, frame centres,
/// tiles read per frame). No frame copies a texel: tiles are read straight into their slots.
fn contract(r: &Value, frames: usize) -> (i64, u64, Vec<i64>, Vec<[i64; 2]>, Vec<u64>) {
    let clip = u(&r["clip_size"]) as i64;
    let bpt = u(&r["bytes_per_texel"]);
    for key in [
        "bytes_copied",
        "bytes_read",
        "tiles_read",
        "ticks_over_budget",
        "frames_with_disabled_level",
        "peak_resident_bytes",
    ] {
        u(&r["totals"][key]);
    }
    let rows = r["frames"].as_array().expect("frames is a list");
    assert_eq!(rows.len(), frames);
    let centres: Vec<[i64; 2]> =
        rows.iter().map(|f| [f["centre"][0].as_i64().unwrap(), f["centre"][1].as_i64().unwrap()]).collect();
    for (f, row) in rows.iter().enumerate() {
        assert_eq!(u(&row["bytes_copied"]), 0, "frame {f}: a tick copied texels");
    }
    assert_eq!(u(&r["totals"]["bytes_copied"]), 0);
    let read: u64 = rows.iter().map(|f| u(&f["bytes_read"])).sum();
    assert_eq!(read, u(&r["totals"]["bytes_read"]), "totals add up");
    let tiles: Vec<u64> = rows.iter().map(|f| u(&f["tiles_read"])).collect();
    assert_eq!(tiles.iter().sum::<u64>(), u(&r["totals"]["tiles_read"]));
    let size = u(&r["size"][0]) as i64;
    let levels: Vec<i64> = (0..u(&r["levels"])).map(|k| (size >> k).max(1)).collect();
    (clip, bpt, levels, centres, tiles)
}

/// Each stack level's mem region (tiles) for level-0 centre `c` moving by `v` texels a tick, as
/// the engine places it (lookahead 1, centres aligned to `align`, the default prefetch policy,
/// which also sees last frame's regions `previous`).
#[allow(clippy::too_many_arguments)]
fn mem_regions(
    levels: &[i64],
    clip: i64,
    tile: i64,
    border: u64,
    align: u64,
    c: [i64; 2],
    v: [i64; 2],
    previous: &[clipmap::geom::Rect],
) -> Vec<clipmap::geom::Rect> {
    let policy = clipmap::paging::PrefetchKind::default().policy();
    levels
        .iter()
        .enumerate()
        .filter(|&(_, &size)| size > clip)
        .map(|(k, &size)| {
            let k32 = k as u32;
            let t = tile.min(size) as u64;
            let shape = clipmap::geom::LevelShape::new([size as u64; 2], [t, t], clip as u64, 1);
            let lv = v.map(|x| if x != 0 && (x >> k32) == 0 { x.signum() } else { x >> k32 });
            let frame = shape.frame(clipmap::geom::aligned_centre(c, k32, align), border, lv);
            let before = previous.get(k).copied().unwrap_or(clipmap::geom::Rect::EMPTY);
            policy.mem_region(&shape, frame.tex, lv, before)
        })
        .collect()
}

/// From frame `steady` on, the tiles read each frame are exactly those that entered a mem region
/// the frame before (reads are asked for after the tick publishes, and taken by the next tick):
/// no tile is read twice, nothing is reloaded whole.
fn assert_steady_tiles(r: &Value, frames: usize, steady: usize, tile: i64, border: u64, align: u64) -> u64 {
    let (clip, _, levels, centres, tiles) = contract(r, frames);
    let mut regions: Vec<Vec<clipmap::geom::Rect>> = Vec::with_capacity(frames);
    for f in 0..frames {
        let v = if f == 0 { [0, 0] } else { [centres[f][0] - centres[f - 1][0], centres[f][1] - centres[f - 1][1]] };
        let previous = if f == 0 { Vec::new() } else { regions[f - 1].clone() };
        regions.push(mem_regions(&levels, clip, tile, border, align, centres[f], v, &previous));
    }
    let mut moved = 0;
    for f in steady..frames {
        let entered: u64 = regions[f - 1]
            .iter()
            .zip(&regions[f - 2])
            .map(|(now, before)| now.area() - now.intersect(before).area().min(now.area()))
            .sum();
        assert_eq!(tiles[f], entered, "frame {f}: {:?} -> {:?}", centres[f - 1], centres[f]);
        moved += entered;
    }
    let last = &r["frames"][frames - 1];
    assert_eq!(last["min_lod"].as_f64(), Some(0.0), "every level in use at the end");
    assert_eq!(u(&r["totals"]["ticks_over_budget"]), 0);
    moved
}

#[test]
fn a_straight_flight_over_the_hash_source_reads_exactly_the_tiles_entering_the_mem_regions() {
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "--source",
        "hash",
        "--size",
        "65536",
        "--clip",
        "256",
        "--tile",
        "64",
        "--flight",
        "straight:16",
        "--frames",
        "14",
        "--budget-ms",
        "inf",
        "--wait-for-reads",
    ];
    let r = roam_json(dir.path(), &args);
    assert_eq!((u(&r["clip_size"]), u(&r["bytes_per_texel"])), (256, 4));
    assert_eq!(r["flight"]["kind"], "straight");
    assert!(assert_steady_tiles(&r, 14, 4, 64, 0, 1) > 0, "the flight brought new tiles");
    let (_, _, _, centres, _) = contract(&r, 14);
    assert_eq!(centres[5], [32768 + 5 * 16, 32768]);
    assert!(u(&r["totals"]["frames_with_disabled_level"]) > 0, "nothing is resident before the first reads");
    assert!(u(&r["totals"]["peak_resident_bytes"]) > 0);
}

#[test]
fn a_diagonal_flight_reads_the_l_shaped_tile_bands() {
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "--source",
        "terrain",
        "--size",
        "16384",
        "--clip",
        "128",
        "--tile",
        "32",
        "--border",
        "8",
        "--flight",
        "straight:12:30",
        "--frames",
        "12",
        "--budget-ms",
        "inf",
        "--wait-for-reads",
    ];
    let r = roam_json(dir.path(), &args);
    assert!(assert_steady_tiles(&r, 12, 4, 32, 8, 1) > 0, "the flight brought new tiles");
}

#[test]
fn aligned_centres_read_tiles_only_when_a_level_steps() {
    let dir = tempfile::tempdir().unwrap();
    let mut args = vec!["--source", "hash", "--size", "65536", "--clip", "256", "--tile", "64"];
    args.extend(["--flight", "straight:3", "--frames", "24", "--budget-ms", "inf", "--wait-for-reads"]);
    args.extend(["--centre-alignment", "8"]);
    let r = roam_json(dir.path(), &args);
    assert_eq!(u(&r["centre_alignment"]), 8);
    assert!(assert_steady_tiles(&r, 24, 4, 64, 0, 8) > 0, "the flight brought new tiles");
    let (out, d) = cliptex(
        dir.path(),
        &["roam", "--source", "hash", "--size", "4096", "--clip", "128"]
            .into_iter()
            .chain(["--flight", "hover", "--frames", "2", "--centre-alignment", "0"])
            .collect::<Vec<_>>(),
    );
    assert_eq!(out.status.code(), Some(1), "{d}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("--centre-alignment"), "{d}");
}

#[test]
fn a_flight_over_the_prepared_example_reads_its_files_from_any_working_directory() {
    let ct = Path::new(env!("CLIPMAP_ROOT")).join("config_examples/prepared/hash256.ct");
    let dir = tempfile::tempdir().unwrap();
    let args =
        [ct.to_str().unwrap(), "--flight", "straight:4", "--frames", "10", "--budget-ms", "inf", "--wait-for-reads"];
    let r = roam_json(dir.path(), &args);
    assert_eq!((u(&r["clip_size"]), u(&r["bytes_per_texel"]), u(&r["levels"])), (64, 3, 9));
    assert_eq!(u(&r["stats"]["read_faults"]["missing"]), 0, "every tile file found");
    // Level 0 pages a 3 x 3 mem region of its 4 x 4 tiles; level 1 (2 x 2) and the 7 pyramid
    // levels are held whole. Each tile is read once.
    assert_eq!(u(&r["totals"]["tiles_read"]), 9 + 4 + 7);
    assert_eq!(assert_steady_tiles(&r, 10, 3, 64, 0, 1), 0, "the short flight stays inside the 3 x 3 grid");
}

#[test]
fn the_default_output_is_a_table_with_totals() {
    let dir = tempfile::tempdir().unwrap();
    let args = ["roam", "--source", "hash", "--size", "4096", "--clip", "128", "--flight", "hover", "--frames", "3"];
    let (out, d) = cliptex(dir.path(), &args);
    assert_eq!(out.status.code(), Some(0), "{d}");
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("clip size 128, 4 bytes per texel"), "{d}");
    assert!(text.lines().any(|l| l.trim_start().starts_with("frame")), "{d}");
    for key in [
        "bytes read",
        "texel bytes copied by ticks",
        "tiles read",
        "ticks over budget",
        "frames with disabled level",
        "image caches (peak)",
    ] {
        assert!(text.contains(key), "missing {key}\n{d}");
    }
    let rows = text.lines().filter(|l| l.split_whitespace().next().is_some_and(|w| w.parse::<u64>().is_ok()));
    assert_eq!(rows.count(), 3, "one row per frame\n{d}");
}

#[test]
fn bad_arguments_and_bad_configurations_exit_with_their_codes() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path();
    let base = ["roam", "--source", "hash", "--size", "4096", "--clip", "128", "--frames", "2"];
    let with = |extra: &[&str]| {
        let mut a = base.to_vec();
        a.extend_from_slice(extra);
        cliptex(p, &a)
    };
    let (out, d) = with(&["--flight", "sideways:3"]);
    assert_eq!(out.status.code(), Some(1), "{d}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown flight `sideways`"), "{d}");
    let (out, d) = with(&["--flight", "straight:1", "--budget-ms", "-3"]);
    assert_eq!(out.status.code(), Some(1), "{d}");
    let (out, d) = cliptex(p, &["roam", "--source", "hash", "--size", "4096", "--flight", "hover", "--frames", "2"]);
    assert_eq!(out.status.code(), Some(1), "--source needs --clip\n{d}");
    let (out, d) = cliptex(p, &["roam", "missing.ct", "--flight", "hover", "--frames", "2"]);
    assert_eq!(out.status.code(), Some(2), "an unreadable file\n{d}");
    std::fs::write(p.join("bad.ct"), "ct_version2.0\nclip_size 64\n").unwrap();
    let (out, d) = cliptex(p, &["roam", "bad.ct", "--flight", "hover", "--frames", "2"]);
    assert_eq!(out.status.code(), Some(1), "an invalid configuration\n{d}");
}

#[test]
fn by_default_a_straight_flight_runs_on_a_frame_clock_and_its_levels_come_in_as_reads_arrive() {
    // Before the frame clock, frames ran back to back (240 frames in 0.13 s): no read had time to
    // arrive, every level was disabled on every frame. On the default 60 frames/s clock the
    // reads land between frames and the fine levels are enabled once they have.
    let dir = tempfile::tempdir().unwrap();
    let args = ["--source", "hash", "--size", "65536", "--clip", "256", "--tile", "64", "--flight", "straight:4"];
    let started = std::time::Instant::now();
    let r = roam_json(dir.path(), &[&args[..], &["--frames", "60"]].concat());
    let took = started.elapsed().as_secs_f64();
    assert_eq!(r["pacing"], "frame_clock", "{r}");
    assert_eq!(r["fps"].as_f64(), Some(60.0));
    assert!(took >= 59.0 / 60.0, "60 frames at 60 frames/s take about a second, took {took:.2} s");
    let rows = r["frames"].as_array().unwrap();
    assert!(!rows[0]["disabled_levels"].as_array().unwrap().is_empty(), "nothing is read before frame 0");
    let tail = &rows[30..];
    let enabled = tail.iter().filter(|f| f["disabled_levels"].as_array().unwrap().is_empty()).count();
    assert!(enabled * 2 > tail.len(), "most of the last 30 frames have every level: {enabled} of 30\n{r}");
    assert!(tail.iter().any(|f| f["min_lod"].as_f64() == Some(0.0)), "level 0 is shown");
    // --fps 0 is the old back-to-back run, reported as such; --fps with --wait-for-reads is a
    // usage error (exit 1, bad input), as is a rate that is no rate.
    let r = roam_json(dir.path(), &[&args[..], &["--frames", "3", "--fps", "0"]].concat());
    assert_eq!((r["pacing"].as_str(), r["fps"].is_null()), (Some("back_to_back"), true), "{r}");
    let r = roam_json(dir.path(), &[&args[..], &["--frames", "3", "--wait-for-reads"]].concat());
    assert_eq!(r["pacing"], "wait_for_reads");
    for bad in [&["--fps", "30", "--wait-for-reads"][..], &["--fps", "-1"], &["--fps", "inf"]] {
        let all = [&["roam"][..], &args[..], &["--frames", "2"], bad].concat();
        let (out, d) = cliptex(dir.path(), &all);
        assert_eq!(out.status.code(), Some(1), "{d}");
    }
}

#[test]
fn a_configured_lookahead_or_mem_region_changes_what_the_engine_reads_and_holds() {
    // Before, the engine derived every mem region from its own lookahead of 1: a configured
    // `lookahead 0` or `3` changed what `cliptex info` printed but not what the engine held.
    // The prepared example: level 0 is 4 x 4 tiles of 64 x 64 RGB texels, clip 64; level 1 is
    // 2 x 2 tiles; seven pyramid levels of 5461 texels in all.
    let src = Path::new(env!("CLIPMAP_ROOT")).join("config_examples/prepared");
    let tile = 64 * 64 * 3u64;
    let roam = |extra_ct: &str, extra_ic: &str| {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("p");
        copy_dir(&src, &d);
        let append = |name: &str, text: &str| {
            let mut s = std::fs::read_to_string(d.join(name)).unwrap();
            s.push_str(text);
            std::fs::write(d.join(name), s).unwrap();
        };
        append("hash256.ct", extra_ct);
        append("L00.ic", extra_ic);
        let ct = d.join("hash256.ct");
        let args = [
            ct.to_str().unwrap(),
            "--flight",
            "straight:4",
            "--frames",
            "10",
            "--budget-ms",
            "inf",
            "--wait-for-reads",
        ];
        let r = roam_json(dir.path(), &args);
        (u(&r["totals"]["tiles_read"]), u(&r["totals"]["peak_resident_bytes"]))
    };
    // The image caches are the mapping: a slot per grid tile (a tile of 12288 bytes is three
    // pages, so a grid's slots differ by whole tiles), tags and header alike in every case.
    // lookahead 1, given: a 3 x 3 grid at level 0, never crossed by the short flight.
    let (tiles, held) = roam("lookahead 1\n", "");
    assert_eq!(tiles, 9 + 4 + 7);
    // No lookahead given: the adaptive policy sizes level 0's grid from its budget (here the whole
    // 4 x 4 level), and reads, on this slow flight, what the lookahead-1 ring reads.
    let (tiles, budgeted) = roam("", "");
    assert_eq!(tiles, 9 + 4 + 7);
    assert_eq!(budgeted, held + 7 * tile, "a 4 x 4 grid at level 0");
    // lookahead 0: a 2 x 2 grid; the 40-texel flight crosses one tile column, read as it comes.
    assert_eq!(roam("lookahead 0\n", ""), (4 + 2 + 4 + 7, held - 5 * tile));
    // lookahead 3: the grid grows to the whole 4 x 4 level.
    assert_eq!(roam("lookahead 3\n", ""), (16 + 4 + 7, held + 7 * tile));
    // An .ic's own mem_region_size wins over the .ct's lookahead.
    assert_eq!(roam("lookahead 0\n", "mem_region_size 4 4 1\n"), (16 + 4 + 7, held + 7 * tile));
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), &target).unwrap();
        }
    }
}
