//! The reader programs against a running `clipmapd` (docs/SHM.md, "Readers in this repository"):
//! the Rust reader refuses a view's own mapping that is a symbolic link or another user's file, as
//! the C and Python readers do; and all three dump a region of any texture, raw or as a PNG, with
//! exactly the engine's texels.

use crate::clipmapd::{c_reader, python_reader, rust_reader, Service};
use clipmap::source::{Procedural, TileId};
use std::path::Path;
use std::process::Output;

fn text(out: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Each reader reading `--view far` of the service `name` in `d` a moment.
fn read_far(d: &Path, name: &str) -> Vec<(&'static str, Output)> {
    let map = d.join(format!("clipmap-{name}.map"));
    let rust = rust_reader(d, name, &["--view", "far", "--reads", "100"]).output().unwrap();
    let mut c = std::process::Command::new(c_reader(d));
    let c = c.arg(&map).args(["100", "1", "5", "--view", "far"]).output().unwrap();
    let py = python_reader().arg(&map).args(["100", "1", "5", "--view", "far"]).output().unwrap();
    vec![("rust", rust), ("c", c), ("python", py)]
}

#[test]
fn the_rust_reader_refuses_a_symlinked_or_another_users_own_view_mapping_as_c_and_python_do() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let _svc = Service::start(d, "sym", &["--view", "far:own"]);
    let own = d.join("clipmap-sym@far.map");
    for (who, out) in read_far(d, "sym") {
        assert!(out.status.success(), "{who} reads the view as published\n{}", text(&out));
    }
    // A link planted at the name, to a mapping that is otherwise fine.
    let aside = d.join("aside.map");
    std::fs::rename(&own, &aside).unwrap();
    std::os::unix::fs::symlink(&aside, &own).unwrap();
    for (who, out) in read_far(d, "sym") {
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{who} refuses the link\n{}", text(&out));
        assert!(err.contains(own.to_str().unwrap()) && err.contains("a symbolic link"), "{who}: {err}");
    }
    std::fs::remove_file(&own).unwrap();
    std::fs::rename(&aside, &own).unwrap();
    // Another user's file at the name.
    if rustix::process::geteuid().as_raw() != 0 {
        eprintln!("skipped the owner check: giving a file to another user needs root (CI runs as root)");
        return;
    }
    std::os::unix::fs::chown(&own, Some(65534), None).unwrap();
    for (who, out) in read_far(d, "sym") {
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{who} refuses another user's file\n{}", text(&out));
        assert!(err.contains("owned by uid 65534") && err.contains("expected uid 0"), "{who}: {err}");
    }
}

/// The engine's texels of `rect` (`[s0, t0, s1, t1)`) of `level` of the terrain texture the
/// service below serves: its tiles read from the source itself, rows in increasing t.
fn terrain_texels(level: u32, rect: [u64; 4]) -> Vec<u8> {
    let src = clipmap_service::procedural_source(Procedural::Terrain, 65536, 256, 64).unwrap();
    let desc = src.desc();
    let d = *desc.level(level);
    let bpt = desc.bytes_per_texel();
    let mut tile = vec![0u8; desc.tile_bytes(level)];
    let (w, h) = ((rect[2] - rect[0]) as usize, (rect[3] - rect[1]) as usize);
    let mut out = vec![0u8; w * h * bpt];
    for ts in rect[0] / d.tile[0]..rect[2].div_ceil(d.tile[0]) {
        for tt in rect[1] / d.tile[1]..rect[3].div_ceil(d.tile[1]) {
            src.read_tile(TileId::new(level, ts, tt), &mut tile).unwrap();
            for t in (tt * d.tile[1]).max(rect[1])..((tt + 1) * d.tile[1]).min(rect[3]) {
                for s in (ts * d.tile[0]).max(rect[0])..((ts + 1) * d.tile[0]).min(rect[2]) {
                    let from = (((t - tt * d.tile[1]) * d.tile[0] + s - ts * d.tile[0]) as usize) * bpt;
                    let to = (((t - rect[1]) as usize) * w + (s - rect[0]) as usize) * bpt;
                    out[to..to + bpt].copy_from_slice(&tile[from..from + bpt]);
                }
            }
        }
    }
    out
}

#[test]
fn the_reader_programs_dump_a_region_of_any_texture_raw_or_png_with_the_engines_texels() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let source = ["--source", "terrain", "--size", "65536", "--clip", "256", "--tile", "64"];
    let svc = Service::spawn_with(d, "land", &source, &[]);
    svc.wait_ready();
    let map = d.join("clipmap-land.map");
    let c = c_reader(d);
    // Level 0 around the centre (32768, 32768) across a tile corner, and a part of level 3.
    for (level, rect) in [(0u32, [32690u64, 32700, 32770, 32790]), (3, [4000, 4010, 4100, 4090])] {
        let want = terrain_texels(level, rect);
        let region = rect.map(|v| v.to_string()).join(",");
        let (w, h) = ((rect[2] - rect[0]) as u32, (rect[3] - rect[1]) as u32);
        let out = |who: &str, ext: &str| d.join(format!("{who}-{level}.{ext}"));
        let lvl = level.to_string();
        let rust = |file: &Path| {
            let args = ["--dump-level", &lvl, "--region", &region, "--out", file.to_str().unwrap(), "--seconds", "20"];
            rust_reader(d, "land", &args).output().unwrap()
        };
        let runs = [
            ("rust", rust(&out("rust", "raw"))),
            ("rust png", rust(&out("rust", "png"))),
            (
                "c",
                std::process::Command::new(&c)
                    .arg(&map)
                    .args(["--dump", &lvl, &region])
                    .arg(out("c", "raw"))
                    .arg("20")
                    .output()
                    .unwrap(),
            ),
            (
                "python",
                python_reader()
                    .arg(&map)
                    .args(["--dump", &lvl, &region])
                    .arg(out("python", "raw"))
                    .arg("20")
                    .output()
                    .unwrap(),
            ),
            (
                "python png",
                python_reader()
                    .arg(&map)
                    .args(["--dump", &lvl, &region])
                    .arg(out("python", "png"))
                    .arg("20")
                    .output()
                    .unwrap(),
            ),
        ];
        for (who, o) in &runs {
            assert!(o.status.success(), "{who}, level {level}\n{}\n{}", text(o), svc.dump());
        }
        for who in ["rust", "c", "python"] {
            let got = std::fs::read(out(who, "raw")).unwrap();
            assert!(got == want, "{who}: level {level} {region}: the raw dump is not the engine's texels");
        }
        // A PNG runs t upwards: its top row is the region's last t row.
        for who in ["rust", "python"] {
            let img = image::open(out(who, "png")).unwrap().to_rgba8();
            assert_eq!(img.dimensions(), (w, h), "{who}");
            for y in 0..h {
                for x in 0..w {
                    let i = (((h - 1 - y) * w + x) * 4) as usize;
                    assert_eq!(img.get_pixel(x, y).0, want[i..i + 4], "{who} png pixel ({x}, {y}), level {level}");
                }
            }
        }
    }
    // A region the level does not publish: refused, naming what it publishes.
    let far = rust_reader(d, "land", &["--dump-level", "0", "--region", "0,0,10,10", "--out"])
        .arg(d.join("far.raw"))
        .args(["--seconds", "1"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&far.stderr);
    assert_eq!(far.status.code(), Some(2), "{}", text(&far));
    assert!(err.contains("the level publishes [32648, 32888) x [32648, 32888)"), "{err}");
    assert!(!d.join("far.raw").exists());
}

#[test]
fn view_records_no_view_publishes_in_hold_a_snapshot_of_nothing_published() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "unused", &["--view", "far:own"]);
    // A view that published and was removed: its record is free again.
    assert!(svc.ask("VIEW ADD gone 1").starts_with("OK view gone added"));
    assert!(svc.ask("VIEW CENTRE gone 1000 1000").starts_with("OK"));
    let t = std::time::Instant::now();
    while !crate::clipmapd::json_reply(&svc.ask("VIEWS")).to_string().contains("\"centre\":[1000,1000]") {
        assert!(t.elapsed() < std::time::Duration::from_secs(20), "{}", svc.dump());
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(svc.ask("VIEW REMOVE gone").starts_with("OK view gone removed"));
    let m = std::fs::read(d.join("clipmap-unused.map")).unwrap();
    let u64_at = |o: usize| u64::from_le_bytes(m[o..o + 8].try_into().unwrap());
    let u32_at = |o: usize| u32::from_le_bytes(m[o..o + 4].try_into().unwrap());
    let levels = u32_at(36) as f64;
    let block = u64_at(104) as usize;
    let records = u32_at(block + 12) as usize;
    let mut states = Vec::new();
    for r in 0..records {
        let rec = block + 64 + 2240 * r;
        let state = u64_at(rec + 8);
        states.push(state);
        if state == 1 {
            continue;
        }
        // State 0 (free: never used, or given back) or 2 (grids of its own, published elsewhere).
        let snap = rec + 128;
        assert_eq!(u64_at(snap) % 2, 0, "record {r} (state {state}): its snapshot's counter is even");
        assert_eq!(f64::from_bits(u64_at(snap + 8)), levels, "record {r} (state {state}): min LOD the level count");
        let rest: Vec<(usize, u64)> =
            (16..2112).step_by(8).map(|o| (o, u64_at(snap + o))).filter(|&(_, v)| v != 0).collect();
        assert!(rest.is_empty(), "record {r} (state {state}): every other snapshot field is 0: {rest:?}");
    }
    assert_eq!(&states[..2], [2, 0], "far's own grids, then gone's record given back: {states:?}");
}

/// The fault: nothing tied a view's own mapping `NAME@VIEW.map` to a start of the service, so a
/// reader holding a killed start's mapping bound the view to the next start's own mapping of that
/// name. The Rust reader checks the generation the own mapping carries; the C and Python readers
/// did not. Here a killed start's mapping sits beside the next start's own mapping of its view.
#[test]
fn the_c_and_python_readers_took_another_starts_own_mapping_for_this_ones() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut svc = Service::start(d, "gen", &["--view", "far:own"]);
    for (who, out) in read_far(d, "gen") {
        assert!(out.status.success(), "{who} reads the view as published\n{}", text(&out));
    }
    svc.child.kill().unwrap();
    svc.child.wait().unwrap();
    let old = tempfile::tempdir().unwrap();
    std::fs::copy(d.join("clipmap-gen.map"), old.path().join("clipmap-gen.map")).unwrap();
    let _next = Service::start(d, "gen", &["--view", "far:own"]);
    std::fs::copy(d.join("clipmap-gen@far.map"), old.path().join("clipmap-gen@far.map")).unwrap();
    for (who, out) in read_far(old.path(), "gen") {
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{who} refuses the next start's own mapping\n{}", text(&out));
        assert!(err.contains("belongs to another start of the service"), "{who}: {err}");
    }
}

/// The georef block (docs/SHM.md, "Georef block") written by the independent writer
/// (tests/fixtures/make_mapping.py --georef): the Rust client, the C reader and the Python reader
/// read the same values; a mapping without the block reads as none in all three; and each
/// hostile variant (`--corrupt georef-*`) is refused by all three naming the same byte and field.
#[test]
fn the_georef_block_reads_the_same_in_rust_c_and_python_and_each_bad_field_is_refused_by_all_three() {
    use clipmap::shm::{Client, GeorefBlock};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let creader = c_reader(d);
    let make = |out: &Path, extra: &[&str]| {
        let o = std::process::Command::new("python3")
            .arg(Path::new(crate::clipmapd::ROOT).join("tests/fixtures/make_mapping.py"))
            .arg(out)
            .args(["--size", "1000x600", "--clip", "128", "--tile", "32"])
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "make_mapping: {}", text(&o));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let c_and_python = |map: &Path| {
        let c = std::process::Command::new(&creader).arg(map).arg("--georef").output().unwrap();
        let py = python_reader().arg(map).arg("--georef").output().unwrap();
        [("C", c), ("Python", py)]
    };
    // A rotated UTM grid with a definition beyond ASCII; level k's terms are level 0's times 2^k
    // (1000 x 600 halved: 500 x 300, 250 x 150, 125 x 75, then 62 x 37: rounded down).
    let def = "+proj=utm +zone=33 +datum=WGS84 +units=m +no_defs +title=Zürich";
    let map = d.join("clipmap-geo.map");
    make(&map, &["--georef", "32633", "0", "500000", "5000000", "0.5", "0.01", "0.02", "-0.5", def]);
    let c = Client::attach_path(&map).unwrap();
    let g = c.georef.clone().expect("the block is read");
    let sizes: Vec<[u64; 2]> = c.levels.iter().map(|l| l.size).collect();
    let want = GeorefBlock {
        epsg: Some(32633),
        wraps: false,
        definition: def.into(),
        origin: [500000.0, 5000000.0],
        levels: (0..sizes.len()).map(|k| [0.5, 0.01, 0.02, -0.5].map(|v| v * (k as f64).exp2())).collect(),
    };
    assert_eq!(g, want);
    assert_eq!(sizes[4], [62, 37], "level 4's height was rounded down: 37 x 16 = 592 of level 0's 600 rows");
    // Texel (0, 600) of level 0 is pixel 0, line 0: the origin; texel (1000, 0) the far corner.
    assert_eq!(g.map_of_texel(0, 600, 0.0, 600.0), Some([500000.0, 5000000.0]));
    assert_eq!(c.map_of_texel(0, 0.0, 600.0), Some([500000.0, 5000000.0]));
    let far = g.map_of_texel(0, 600, 1000.0, 0.0).unwrap();
    assert!((far[0] - 500506.0).abs() < 1e-6 && (far[1] - 4999720.0).abs() < 1e-6, "{far:?}");
    // Every level shares the south-west corner, origin + 600 x (0.01, -0.5) = (500006, 4999700);
    // level 4 covers level 0's 592 southmost rows, so its north-west corner (0, 37) lies 8 level-0
    // rows south of level 0's: origin + 8 x (0.01, -0.5) = (500000.08, 4999996).
    let close = |got: [f64; 2], want: [f64; 2]| (got[0] - want[0]).abs() < 1e-6 && (got[1] - want[1]).abs() < 1e-6;
    let expected: [((usize, f64, f64), [f64; 2]); 5] = [
        ((4, 0.0, 0.0), [500006.0, 4999700.0]),
        ((4, 0.0, 37.0), [500000.08, 4999996.0]),
        ((4, 62.5, 0.0), [500506.0, 4999720.0]),
        ((4, 10.25, 20.5), [500006.0 + 82.0 - 3.28, 4999700.0 + 3.28 + 164.0]),
        ((3, 0.0, 75.0), [500000.0, 5000000.0]),
    ];
    for ((k, s, t), xy) in expected {
        let rust = c.map_of_texel(k, s, t).unwrap();
        assert!(close(rust, xy), "Rust: level {k} ({s}, {t}) at {rust:?}, expected {xy:?}");
        assert_eq!(
            g.geotransform(k, 600, sizes[k][1]).map(|gt| {
                let line = sizes[k][1] as f64 - t;
                close([gt[0] + gt[1] * s + gt[2] * line, gt[3] + gt[4] * s + gt[5] * line], xy)
            }),
            Some(true),
            "level {k}'s own geotransform at pixel {s}, line height - {t}"
        );
        let args = ["--map-of-texel".to_string(), k.to_string(), s.to_string(), t.to_string()];
        let c_out = std::process::Command::new(&creader).arg(&map).args(&args).output().unwrap();
        let py_out = python_reader().arg(&map).args(&args).output().unwrap();
        for (who, o) in [("C", c_out), ("Python", py_out)] {
            assert!(o.status.success(), "{who}: {}", text(&o));
            let got: Vec<f64> =
                String::from_utf8_lossy(&o.stdout).split_whitespace().map(|w| w.parse().unwrap()).collect();
            assert!(
                got.len() == 2 && close([got[0], got[1]], rust),
                "{who}: level {k} ({s}, {t}) at {got:?}, Rust at {rust:?}"
            );
        }
    }
    // The C and Python readers print the same numbers (as %.17g, which Rust's shortest form
    // round-trips through).
    let mut line = format!("georef epsg 32633 wraps 0 origin {} {}\n", 500000, 5000000);
    for (k, t) in g.levels.iter().enumerate() {
        line += &format!("level {k} {}\n", t.map(|v| format!("{}", v)).join(" "));
    }
    line += &format!("definition {def}\n");
    for (who, o) in c_and_python(&map) {
        assert!(o.status.success(), "{who}: {}", text(&o));
        let got = String::from_utf8(o.stdout).unwrap();
        let words: Vec<&str> = got.split([' ', '\n']).collect();
        let want_words: Vec<&str> = line.split([' ', '\n']).collect();
        assert_eq!(words.len(), want_words.len(), "{who}: {got}");
        for (a, b) in words.iter().zip(&want_words) {
            match (a.parse::<f64>(), b.parse::<f64>()) {
                (Ok(x), Ok(y)) => assert_eq!(x, y, "{who}: {got}"),
                _ => assert_eq!(a, b, "{who}: {got}"),
            }
        }
    }
    // `cliptex attach --json` shows the block as `georef` (no service answers on the socket: the
    // mapping alone is shown).
    let attach = |name: &str| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex"))
            .args(["attach", name, "--shm-dir", d.to_str().unwrap(), "--once", "--json", "--interval", "0.05"])
            .output()
            .unwrap();
        assert!(o.status.success(), "cliptex attach: {}", text(&o));
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()["georef"].clone()
    };
    // (Both through serde_json's parser, which may round the last digit of a number.)
    let json: serde_json::Value = serde_json::from_str(&serde_json::to_string(&want).unwrap()).unwrap();
    assert_eq!(attach("geo"), json);
    // Without the block: none, in all three.
    let plain = d.join("clipmap-plain.map");
    make(&plain, &[]);
    assert_eq!(Client::attach_path(&plain).unwrap().georef, None);
    assert!(attach("plain").is_null());
    for (who, o) in c_and_python(&plain) {
        assert!(o.status.success(), "{who}: {}", text(&o));
        assert_eq!(String::from_utf8_lossy(&o.stdout), "not georeferenced\n", "{who}");
    }
    // Every hostile block: refused by all three, each naming the byte and the field.
    let kinds = std::process::Command::new("python3")
        .arg(Path::new(crate::clipmapd::ROOT).join("tests/fixtures/make_mapping.py"))
        .args(["--list-kinds", "x"])
        .output()
        .unwrap();
    let kinds = String::from_utf8(kinds.stdout).unwrap();
    let kinds: Vec<(&str, String)> = kinds
        .lines()
        .filter(|l| l.starts_with("georef-"))
        .map(|l| {
            let (k, w) = l.split_once(' ').unwrap();
            (k, w.replace('_', " "))
        })
        .collect();
    assert!(kinds.len() >= 14, "{kinds:?}");
    for (kind, word) in kinds {
        let bad = d.join(format!("{kind}.map"));
        make(&bad, &["--corrupt", kind]);
        let e = Client::attach_path(&bad).expect_err(kind).to_string();
        assert!(e.contains(&word), "Rust, {kind}: {e:?} lacks {word:?}");
        // The word names the byte, and the field unless it ends in `(FIELD`: the message has the rest.
        let full = if word.ends_with(')') {
            word.clone()
        } else {
            let rest = e.split_once(&word).map(|(_, rest)| rest.split(')').next().unwrap_or("")).unwrap_or("");
            format!("{word}{rest})")
        };
        for (who, o) in c_and_python(&bad) {
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{who}, {kind}: {}", text(&o));
            // The same place and field as the Rust client's: `byte N (FIELD)`.
            assert!(err.contains(&full), "{who}, {kind}: {err} lacks {full:?} (Rust: {e})");
        }
    }
}
