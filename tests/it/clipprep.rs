//! `clipprep` end to end: the real binary writes a clip texture into a temporary directory, and
//! every check reads it back through the project's own resolution (`cliptex info`, `cliptex
//! tile`, `icache tile`) and `cliptex validate --strict`.

use clipmap::source::procedural::hash;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const CLIPPREP: &str = env!("CARGO_BIN_EXE_clipprep");
const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const ICACHE: &str = env!("CARGO_BIN_EXE_icache");

fn describe(cmd: &[&str], out: &Output) -> String {
    format!(
        "command: {}\nstatus: {:?}\nstdout:\n{}\nstderr:\n{}",
        cmd.join(" "),
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Runs a program; returns its output and a description for failure messages.
fn exec(prog: &str, args: &[&str]) -> (Output, String) {
    let out = Command::new(prog).args(args).output().expect("the binary runs");
    let mut cmd = vec![prog];
    cmd.extend_from_slice(args);
    let d = describe(&cmd, &out);
    (out, d)
}

/// Runs a program that must succeed; returns stdout.
fn ok(prog: &str, args: &[&str]) -> String {
    let (out, d) = exec(prog, args);
    assert!(out.status.success(), "expected success\n{d}");
    String::from_utf8(out.stdout).unwrap()
}

/// Runs clipprep with `args` plus `--out dir --json`; returns the JSON summary.
fn prep(dir: &Path, args: &[&str]) -> Value {
    let mut all: Vec<&str> = args.to_vec();
    let d = dir.to_str().unwrap();
    all.extend_from_slice(&["--out", d, "--json"]);
    serde_json::from_str(&ok(CLIPPREP, &all)).expect("--json prints JSON")
}

/// One level as the project's plan describes it.
struct LevelInfo {
    size: (u64, u64),
    tile: (u64, u64),
}

fn levels(ct: &str) -> Vec<LevelInfo> {
    let info: Value = serde_json::from_str(&ok(CLIPTEX, &["info", ct, "--json"])).unwrap();
    info["levels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| {
            let size = (l["size"][0].as_u64().unwrap(), l["size"][1].as_u64().unwrap());
            let tile = match l["tile_size"].as_array() {
                Some(t) => (t[0].as_u64().unwrap(), t[1].as_u64().unwrap()),
                None => size,
            };
            LevelInfo { size, tile }
        })
        .collect()
}

/// Reads tile (s, t) of `level` through `cliptex tile`.
fn read_tile(ct: &str, level: usize, s: u64, t: u64) -> Vec<u8> {
    let (l, s, t) = (level.to_string(), s.to_string(), t.to_string());
    let loc: Value = serde_json::from_str(&ok(CLIPTEX, &["tile", ct, "--level", &l, "--s", &s, "--t", &t, "--json"]))
        .expect("cliptex tile --json prints JSON");
    let bytes = std::fs::read(loc["path"].as_str().unwrap()).expect("the tile file exists");
    let (off, len) = (loc["offset"].as_u64().unwrap() as usize, loc["length"].as_u64().unwrap() as usize);
    assert!(bytes.len() >= off + len, "tile file too short: {loc}");
    bytes[off..off + len].to_vec()
}

/// A whole level, assembled from its tiles: rows in increasing t, s fastest.
fn read_level(ct: &str, level: usize, info: &LevelInfo, bpt: usize) -> Vec<u8> {
    let (w, h) = info.size;
    let (tw, th) = info.tile;
    let mut out = vec![0u8; (w * h) as usize * bpt];
    for tt in 0..h / th {
        for ts in 0..w / tw {
            let tile = read_tile(ct, level, ts, tt);
            assert_eq!(tile.len(), (tw * th) as usize * bpt);
            for r in 0..th {
                let src = &tile[(r * tw) as usize * bpt..][..tw as usize * bpt];
                let t = tt * th + r;
                let dst = ((t * w + ts * tw) as usize) * bpt;
                out[dst..dst + tw as usize * bpt].copy_from_slice(src);
            }
        }
    }
    out
}

fn validate_strict(ct: &str) {
    ok(CLIPTEX, &["validate", "--strict", ct]);
}

fn ct_path(summary: &Value) -> String {
    let ct = summary["ct"].as_str().expect("ct is a string").to_string();
    assert!(Path::new(&ct).is_file(), "{ct} exists");
    ct
}

#[test]
fn hash_texels_match_at_sampled_coordinates_of_every_level() {
    for (format, bpt) in [("rgb8", 3usize), ("rgba5551", 2), ("l8", 1)] {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("hash");
        let summary =
            prep(&dir, &["--source", "hash", "--size", "256", "--tile", "64", "--clip", "64", "--format", format]);
        let ct = ct_path(&summary);
        validate_strict(&ct);
        let lv = levels(&ct);
        assert_eq!(lv.len(), 9, "256 down to 1x1");
        assert_eq!(summary["levels"], 9);
        for (k, info) in lv.iter().enumerate() {
            let (w, h) = info.size;
            assert_eq!((w, h), (256 >> k, 256 >> k));
            for (s, t) in [(0, 0), (w - 1, h - 1), (w / 2, h / 3), ((w * 3) / 4, h - 1), (w - 1, 0)] {
                let tile = read_tile(&ct, k, s / info.tile.0, t / info.tile.1);
                let at = (((t % info.tile.1) * info.tile.0 + s % info.tile.0) as usize) * bpt;
                let mut expect = vec![0u8; bpt];
                hash(k as u32, s, t, &mut expect);
                assert_eq!(&tile[at..at + bpt], &expect[..], "{format} level {k} texel ({s}, {t})");
            }
        }
    }
}

/// floor((a + b + c + d + 2) / 4) per component, the rounding clipprep documents.
fn avg4(a: u32, b: u32, c: u32, d: u32) -> u32 {
    (a + b + c + d + 2) / 4
}

/// Checks that every level is the 2x2 rounded average of the one below, per byte component.
fn assert_box_pyramid(ct: &str, bpt: usize) {
    let lv = levels(ct);
    let mut below = read_level(ct, 0, &lv[0], bpt);
    for k in 1..lv.len() {
        let level = read_level(ct, k, &lv[k], bpt);
        let (w, h) = lv[k].size;
        let bw = lv[k - 1].size.0;
        for t in 0..h {
            for s in 0..w {
                for c in 0..bpt {
                    let px = |s: u64, t: u64| below[((t * bw + s) as usize) * bpt + c] as u32;
                    let want =
                        avg4(px(2 * s, 2 * t), px(2 * s + 1, 2 * t), px(2 * s, 2 * t + 1), px(2 * s + 1, 2 * t + 1));
                    let got = level[((t * w + s) as usize) * bpt + c] as u32;
                    assert_eq!(got, want, "level {k} texel ({s}, {t}) component {c}");
                }
            }
        }
        below = level;
    }
}

#[test]
fn box_filtered_terrain_levels_are_the_rounded_average_of_the_level_below() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("terrain");
    let summary =
        prep(&dir, &["--source", "terrain", "--size", "256", "--tile", "64", "--clip", "64", "--format", "rgb8"]);
    let ct = ct_path(&summary);
    validate_strict(&ct);
    assert_box_pyramid(&ct, 3);
}

#[test]
fn packed_5551_levels_average_each_packed_field() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("t5551");
    let summary =
        prep(&dir, &["--source", "terrain", "--size", "128", "--tile", "32", "--clip", "32", "--format", "rgba5551"]);
    let ct = ct_path(&summary);
    validate_strict(&ct);
    let lv = levels(&ct);
    let fields = |v: u16| [(v >> 11) as u32, ((v >> 6) & 31) as u32, ((v >> 1) & 31) as u32, (v & 1) as u32];
    let texel = |data: &[u8], w: u64, s: u64, t: u64| {
        let i = ((t * w + s) * 2) as usize;
        fields(u16::from_le_bytes([data[i], data[i + 1]]))
    };
    let l0 = read_level(&ct, 0, &lv[0], 2);
    let l1 = read_level(&ct, 1, &lv[1], 2);
    for t in 0..lv[1].size.1 {
        for s in 0..lv[1].size.0 {
            let q = [(2 * s, 2 * t), (2 * s + 1, 2 * t), (2 * s, 2 * t + 1), (2 * s + 1, 2 * t + 1)]
                .map(|(x, y)| texel(&l0, lv[0].size.0, x, y));
            let got = texel(&l1, lv[1].size.0, s, t);
            for c in 0..4 {
                assert_eq!(got[c], avg4(q[0][c], q[1][c], q[2][c], q[3][c]), "({s}, {t}) field {c}");
            }
        }
    }
}

fn write_png(path: &Path, w: u32, h: u32) -> image::RgbaImage {
    let img = image::RgbaImage::from_fn(w, h, |x, y| {
        let v = (x * 7 + y * 13) as u8;
        image::Rgba([v, (x * 3) as u8, (y * 5) as u8, 255 - (x as u8)])
    });
    img.save(path).unwrap();
    img
}

#[test]
fn png_input_is_level_zero_with_a_lower_left_origin_and_filtered_below() {
    let tmp = tempfile::tempdir().unwrap();
    let png = tmp.path().join("in.png");
    let img = write_png(&png, 128, 64);
    let dir = tmp.path().join("png");
    let summary = prep(
        &dir,
        &[
            "--input",
            png.to_str().unwrap(),
            "--tile",
            "32",
            "--clip",
            "32",
            "--format",
            "rgba8",
            "--tiles-per-file",
            "2",
        ],
    );
    let ct = ct_path(&summary);
    validate_strict(&ct);
    let lv = levels(&ct);
    assert_eq!(lv[0].size, (128, 64));
    let l0 = read_level(&ct, 0, &lv[0], 4);
    for t in 0..64u32 {
        for s in 0..128u32 {
            let want = img.get_pixel(s, 63 - t).0;
            let i = ((t * 128 + s) * 4) as usize;
            assert_eq!(&l0[i..i + 4], &want, "texel ({s}, {t})");
        }
    }
    assert_box_pyramid(&ct, 4);
    // Performer's non-square pyramid ends when the short side reaches 1: 128x64 ... 2x1.
    assert_eq!(lv.last().unwrap().size, (2, 1));
}

#[test]
fn tiff_input_is_streamed_strip_by_strip() {
    use tiff::encoder::{colortype, TiffEncoder};
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("in.tif");
    let (w, h) = (64u32, 32u32);
    let data: Vec<u8> = (0..w * h * 3).map(|i| (i * 31 % 251) as u8).collect();
    {
        let file = std::fs::File::create(&path).unwrap();
        let mut enc = TiffEncoder::new(file).unwrap();
        let mut image = enc.new_image::<colortype::RGB8>(w, h).unwrap();
        image.rows_per_strip(3).unwrap();
        image.write_data(&data).unwrap();
    }
    let dir = tmp.path().join("tif");
    let summary = prep(&dir, &["--input", path.to_str().unwrap(), "--tile", "16", "--clip", "32", "--format", "rgb8"]);
    let ct = ct_path(&summary);
    let lv = levels(&ct);
    let l0 = read_level(&ct, 0, &lv[0], 3);
    for t in 0..h {
        for s in 0..w {
            let src = (((h - 1 - t) * w + s) * 3) as usize;
            let dst = ((t * w + s) * 3) as usize;
            assert_eq!(&l0[dst..dst + 3], &data[src..src + 3], "texel ({s}, {t})");
        }
    }
    assert_box_pyramid(&ct, 3);
}

#[test]
fn rgba_tiff_input_is_copied_row_by_row_and_padded_with_zeros() {
    use tiff::encoder::{colortype, TiffEncoder};
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("in.tif");
    let (w, h) = (48u32, 32u32);
    let data: Vec<u8> = (0..w * h * 4).map(|i| (i * 29 % 253) as u8).collect();
    {
        let file = std::fs::File::create(&path).unwrap();
        let mut enc = TiffEncoder::new(file).unwrap();
        let mut image = enc.new_image::<colortype::RGBA8>(w, h).unwrap();
        image.rows_per_strip(5).unwrap();
        image.write_data(&data).unwrap();
    }
    let dir = tmp.path().join("tif");
    let args = ["--input", path.to_str().unwrap(), "--tile", "16", "--clip", "32", "--format", "rgba8", "--pad"];
    let ct = ct_path(&prep(&dir, &args));
    let lv = levels(&ct);
    assert_eq!(lv[0].size, (64, 32));
    let l0 = read_level(&ct, 0, &lv[0], 4);
    for t in 0..h {
        for s in 0..64 {
            let dst = ((t * 64 + s) * 4) as usize;
            let want = if s < w { &data[(((h - 1 - t) * w + s) * 4) as usize..][..4] } else { &[0u8; 4][..] };
            assert_eq!(&l0[dst..dst + 4], want, "texel ({s}, {t})");
        }
    }
    assert_box_pyramid(&ct, 4);
}

#[test]
fn linear_light_averages_in_linear_space_and_lanczos_keeps_flat_areas_flat() {
    let tmp = tempfile::tempdir().unwrap();
    let png = tmp.path().join("checker.png");
    image::GrayImage::from_fn(64, 64, |x, y| image::Luma([if (x + y) % 2 == 0 { 0 } else { 255 }])).save(&png).unwrap();
    let args = |extra: &'static [&'static str]| {
        let mut a = vec!["--input", png.to_str().unwrap(), "--tile", "16", "--clip", "32", "--format", "l8"];
        a.extend_from_slice(extra);
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let level1 = |name: &str, extra: &'static [&'static str]| {
        let a = args(extra);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        let ct = ct_path(&prep(&tmp.path().join(name), &a));
        validate_strict(&ct);
        let lv = levels(&ct);
        read_level(&ct, 1, &lv[1], 1)
    };
    // Stored values: (0 + 255 + 0 + 255 + 2) / 4 = 128. Linear light: half of full intensity is
    // sRGB 0.7354, 187.5 of 255, rounded up to 188.
    assert!(level1("plain", &[]).iter().all(|&v| v == 128));
    assert!(level1("linear", &["--linear-light"]).iter().all(|&v| v == 188));
    // A flat image stays flat through Lanczos-3 (its weights sum to one).
    let flat = tmp.path().join("flat.png");
    image::GrayImage::from_pixel(64, 64, image::Luma([77])).save(&flat).unwrap();
    let ct = ct_path(&prep(
        &tmp.path().join("lanczos"),
        &["--input", flat.to_str().unwrap(), "--tile", "16", "--clip", "32", "--format", "l8", "--filter", "lanczos3"],
    ));
    let lv = levels(&ct);
    for (k, info) in lv.iter().enumerate() {
        assert!(read_level(&ct, k, info, 1).iter().all(|&v| v == 77), "level {k}");
    }
}

#[test]
fn multi_tile_files_hold_a_header_then_tiles_at_their_offsets() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("multi");
    let args = [
        "--source",
        "hash",
        "--size",
        "256",
        "--tile",
        "32",
        "--clip",
        "32",
        "--format",
        "rgb8",
        "--tiles-per-file",
        "2x2",
        "--header-bytes",
        "100",
    ];
    let ct = ct_path(&prep(&dir, &args));
    validate_strict(&ct);
    let ic = dir.join("L00.ic");
    let text = std::fs::read_to_string(&ic).unwrap();
    assert!(text.contains("tiles_in_file 2 2 1") && text.contains("header_offset 100"), "{text}");
    let tile_bytes = 32 * 32 * 3;
    for (s, t) in [(0u64, 0u64), (1, 0), (0, 1), (1, 1), (5, 6), (7, 7)] {
        let (ss, ts) = (s.to_string(), t.to_string());
        let loc: Value =
            serde_json::from_str(&ok(ICACHE, &["tile", ic.to_str().unwrap(), "--s", &ss, "--t", &ts, "--json"]))
                .unwrap();
        let expect_offset = ((s % 2) + 2 * (t % 2)) * tile_bytes + 100;
        assert_eq!(loc["offset"].as_u64(), Some(expect_offset), "tile ({s}, {t})");
        assert_eq!(loc["length"].as_u64(), Some(tile_bytes));
        let file = std::fs::read(loc["path"].as_str().unwrap()).unwrap();
        assert_eq!(file.len() as u64, 100 + 4 * tile_bytes, "four tiles after the header");
        assert!(file.starts_with(b"clipmap tiles: level 0"), "the header describes the file");
        let at = expect_offset as usize;
        let mut first = [0u8; 3];
        hash(0, s * 32, t * 32, &mut first);
        assert_eq!(&file[at..at + 3], &first, "first texel of tile ({s}, {t})");
        let mut last = [0u8; 3];
        hash(0, s * 32 + 31, t * 32 + 31, &mut last);
        let end = at + tile_bytes as usize;
        assert_eq!(&file[end - 3..end], &last, "last texel of tile ({s}, {t})");
    }
}

#[test]
fn stream_servers_take_tiles_by_column_modulo_their_number() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("streams");
    let args =
        ["--source", "hash", "--size", "256", "--tile", "32", "--clip", "32", "--format", "l8", "--streams", "3"];
    let ct = ct_path(&prep(&dir, &args));
    validate_strict(&ct);
    let text = std::fs::read_to_string(dir.join("L00.ic")).unwrap();
    assert!(text.contains("s_stream stream0/ stream1/ stream2/"), "{text}");
    assert!(!text.contains("s_streams"), "the singular spelling avoids Performer 3.0's misparse");
    for s in 0..8u64 {
        for t in [0u64, 3] {
            let (ss, ts) = (s.to_string(), t.to_string());
            let ic = dir.join("L00.ic");
            let loc: Value =
                serde_json::from_str(&ok(ICACHE, &["tile", ic.to_str().unwrap(), "--s", &ss, "--t", &ts, "--json"]))
                    .unwrap();
            let stream = format!("stream{}/", s % 3);
            assert_eq!(loc["stream"].as_str(), Some(stream.as_str()));
            let path = PathBuf::from(loc["path"].as_str().unwrap());
            assert!(path.to_string_lossy().contains(&stream), "{}", path.display());
            let tile = std::fs::read(&path).unwrap();
            let mut texel = [0u8; 1];
            hash(0, s * 32 + 5, t * 32 + 2, &mut texel);
            assert_eq!(tile[2 * 32 + 5], texel[0]);
            for other in (0..3).filter(|&o| o != s % 3) {
                let elsewhere = dir.join(format!("stream{other}")).join(path.strip_prefix(dir.join(&stream)).unwrap());
                assert!(!elsewhere.exists(), "{} should not exist", elsewhere.display());
            }
        }
    }
}

#[test]
fn json_summary_reports_the_contract_fields() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("json");
    let v = prep(&dir, &["--source", "hash", "--size", "512", "--tile", "64", "--clip", "128", "--format", "rgba8"]);
    let ct = ct_path(&v);
    assert!(ct.ends_with("json.ct"), "{ct}");
    assert_eq!(v["levels"], 10);
    assert!(v["seconds"].as_f64().unwrap() >= 0.0);
    fn du(p: &Path) -> (u64, u64) {
        let mut t = (0, 0);
        for e in std::fs::read_dir(p).unwrap() {
            let e = e.unwrap();
            if e.file_type().unwrap().is_dir() {
                let (f, b) = du(&e.path());
                t = (t.0 + f, t.1 + b);
            } else {
                t = (t.0 + 1, t.1 + e.metadata().unwrap().len());
            }
        }
        t
    }
    let (files, bytes) = du(&dir);
    assert_eq!(v["bytes"].as_u64(), Some(bytes));
    assert_eq!(v["files"].as_u64(), Some(files));
    // Texels of all levels times 4 bytes, plus the configuration files.
    let texels: u64 = (0..10).map(|k| (512u64 >> k) * (512 >> k)).sum();
    assert!(bytes > texels * 4 && bytes < texels * 4 + 16 * 1024, "{bytes}");
}

fn fails(args: &[&str], code: i32) -> String {
    let (out, d) = exec(CLIPPREP, args);
    assert_eq!(out.status.code(), Some(code), "expected exit {code}\n{d}");
    String::from_utf8(out.stderr).unwrap()
}

#[test]
fn an_existing_pyramid_is_refused_without_force_and_replaced_with_it() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("again");
    let d = dir.to_str().unwrap();
    let base = ["--source", "hash", "--size", "128", "--tile", "32", "--clip", "32", "--out", d];
    ok(CLIPPREP, &[&base[..], &["--format", "rgb8", "-q"]].concat());
    let err = fails(&[&base[..], &["--format", "l8"]].concat(), 1);
    assert!(err.contains("already holds a clip texture") && err.contains("--force"), "{err}");
    assert!(std::fs::read_to_string(dir.join("again.ct")).unwrap().contains("PFTEX_RGB_8"), "left untouched");
    ok(CLIPPREP, &[&base[..], &["--format", "l8", "--force", "-q"]].concat());
    assert!(std::fs::read_to_string(dir.join("again.ct")).unwrap().contains("PFTEX_LUMINANCE"), "replaced");
    // A directory holding anything else is never replaced, even with --force.
    let other = tmp.path().join("other");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("notes.txt"), "mine").unwrap();
    let o = other.to_str().unwrap();
    let err = fails(
        &["--source", "hash", "--size", "64", "--tile", "32", "--clip", "32", "--format", "l8", "--out", o, "--force"],
        1,
    );
    assert!(err.contains("not an empty directory"), "{err}");
    assert_eq!(std::fs::read_to_string(other.join("notes.txt")).unwrap(), "mine");
}

#[test]
fn non_power_of_two_sizes_are_refused_naming_the_next_power_or_padded() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("npot");
    let o = out.to_str().unwrap();
    let err =
        fails(&["--source", "hash", "--size", "300", "--tile", "32", "--clip", "32", "--format", "l8", "--out", o], 1);
    assert!(err.contains("300") && err.contains("512"), "{err}");
    let err =
        fails(&["--source", "hash", "--size", "256", "--tile", "48", "--clip", "32", "--format", "l8", "--out", o], 1);
    assert!(err.contains("tile size is 48") && err.contains("64"), "{err}");
    let err =
        fails(&["--source", "hash", "--size", "256", "--tile", "16", "--clip", "16", "--format", "l8", "--out", o], 1);
    assert!(err.contains("clip size 16") && err.contains("at least 32"), "{err}");
    assert!(!out.exists());
    let png = tmp.path().join("odd.png");
    write_png(&png, 100, 60);
    let p = png.to_str().unwrap();
    let err = fails(&["--input", p, "--tile", "32", "--clip", "32", "--format", "rgb8", "--out", o], 1);
    assert!(err.contains("width of") && err.contains("100") && err.contains("128") && err.contains("--pad"), "{err}");
    let ct = ct_path(&prep(&out, &["--input", p, "--tile", "32", "--clip", "32", "--format", "rgb8", "--pad"]));
    validate_strict(&ct);
    let lv = levels(&ct);
    assert_eq!(lv[0].size, (128, 64));
    let l0 = read_level(&ct, 0, &lv[0], 3);
    // Padding is black, at the right (s >= 100) and the top (t >= 60).
    assert_eq!(&l0[((10 * 128 + 120) * 3)..][..3], &[0, 0, 0]);
    assert_eq!(&l0[((62 * 128 + 10) * 3)..][..3], &[0, 0, 0]);
}

#[test]
fn a_truncated_png_fails_with_exit_1_and_leaves_nothing_behind() {
    let tmp = tempfile::tempdir().unwrap();
    let png = tmp.path().join("cut.png");
    write_png(&png, 64, 64);
    let bytes = std::fs::read(&png).unwrap();
    std::fs::write(&png, &bytes[..bytes.len() / 2]).unwrap();
    let out = tmp.path().join("never");
    let err = fails(
        &[
            "--input",
            png.to_str().unwrap(),
            "--tile",
            "32",
            "--clip",
            "32",
            "--format",
            "rgb8",
            "--out",
            out.to_str().unwrap(),
        ],
        1,
    );
    assert!(err.contains("cannot decode") && err.contains("cut.png"), "{err}");
    assert!(!out.exists());
    let left: Vec<_> = std::fs::read_dir(tmp.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 1, "only the input remains: {left:?}");
}

#[test]
fn every_format_and_layout_option_passes_strict_validation() {
    let tmp = tempfile::tempdir().unwrap();
    for (i, (format, size, extra)) in [
        ("rgb565", "256", &["--streams", "2"][..]),
        ("rgba5551", "512x128", &["--tiles-per-file", "3x2", "--header-bytes", "64"][..]),
        ("rgba8", "128x512", &[][..]),
        ("l8", "1024x64", &["--streams", "4", "--tiles-per-file", "2"][..]),
        ("rgb8", "32", &[][..]),
    ]
    .into_iter()
    .enumerate()
    {
        let dir = tmp.path().join(format!("v{i}"));
        let mut args = vec!["--source", "terrain", "--size", size, "--tile", "32", "--clip", "32", "--format", format];
        args.extend_from_slice(extra);
        let ct = ct_path(&prep(&dir, &args));
        validate_strict(&ct);
        for e in std::fs::read_dir(&dir).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "ic") {
                ok(ICACHE, &["validate", "--strict", p.to_str().unwrap()]);
            }
        }
        let text = std::fs::read_to_string(&ct).unwrap();
        assert!(text.starts_with("ct_version2.0\n"), "{text}");
        for line in text.lines() {
            assert!(!line.contains('#') || line.starts_with('#'), "comments stand on their own lines: {line}");
            assert!(!line.contains('/') || !line.trim_start().starts_with('/'), "no absolute paths: {line}");
        }
    }
}

#[test]
fn the_prepared_example_is_what_clipprep_writes() {
    let example = Path::new(env!("CLIPMAP_ROOT")).join("config_examples/prepared");
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("prepared");
    let ct = ct_path(&prep(
        &dir,
        &["--source", "hash", "--size", "256", "--tile", "64", "--clip", "64", "--format", "rgb8", "--name", "hash256"],
    ));
    validate_strict(example.join("hash256.ct").to_str().unwrap());
    fn files(root: &Path, p: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(p).unwrap() {
            let e = e.unwrap().path();
            if e.is_dir() {
                files(root, &e, out);
            } else {
                out.push(e.strip_prefix(root).unwrap().to_path_buf());
            }
        }
    }
    let (mut a, mut b) = (Vec::new(), Vec::new());
    files(&dir, &dir, &mut a);
    files(&example, &example, &mut b);
    a.sort();
    b.sort();
    assert_eq!(a, b, "same files");
    for f in &a {
        assert_eq!(std::fs::read(dir.join(f)).unwrap(), std::fs::read(example.join(f)).unwrap(), "{}", f.display());
    }
    assert!(ct.ends_with("hash256.ct"));
}

#[cfg(unix)]
#[test]
fn an_interrupted_run_leaves_neither_output_nor_partial_directory() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cut");
    let args = ["--source", "terrain", "--size", "4096", "--tile", "256", "--clip", "256", "--format", "rgba8", "-q"];
    let child = Command::new(CLIPPREP)
        .args(args)
        .arg("--out")
        .arg(&out)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let partial =
        |p: &Path| std::fs::read_dir(p).unwrap().any(|e| e.unwrap().file_name().to_string_lossy().contains("partial"));
    let start = std::time::Instant::now();
    while !partial(tmp.path()) && start.elapsed() < std::time::Duration::from_secs(20) {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let status = Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
    assert!(status.success());
    let out_put = child.wait_with_output().unwrap();
    let d = describe(&["clipprep (interrupted)"], &out_put);
    assert_eq!(out_put.status.code(), Some(2), "{d}");
    assert!(String::from_utf8_lossy(&out_put.stderr).contains("interrupted"), "{d}");
    assert!(!out.exists(), "{d}");
    assert!(!partial(tmp.path()), "the partial directory was removed\n{d}");
}

#[test]
fn an_image_over_the_memory_limit_is_refused_naming_the_sizes_and_the_fix() {
    let tmp = tempfile::tempdir().unwrap();
    let png = tmp.path().join("wide.png");
    write_png(&png, 1024, 512);
    let out = tmp.path().join("never");
    let err = fails(
        &[
            "--input",
            png.to_str().unwrap(),
            "--tile",
            "64",
            "--clip",
            "64",
            "--format",
            "rgb8",
            "--max-memory",
            "1",
            "--out",
            out.to_str().unwrap(),
        ],
        1,
    );
    assert!(err.contains("1024x512") && err.contains("2 MiB") && err.contains("TIFF"), "{err}");
    assert!(!out.exists());
}

#[test]
fn jpeg_input_is_accepted() {
    let tmp = tempfile::tempdir().unwrap();
    let jpg = tmp.path().join("in.jpg");
    image::RgbImage::from_fn(64, 64, |x, y| image::Rgb([(x * 4) as u8, (y * 4) as u8, 128])).save(&jpg).unwrap();
    let ct = ct_path(&prep(
        &tmp.path().join("jpeg"),
        &["--input", jpg.to_str().unwrap(), "--tile", "32", "--clip", "32", "--format", "rgb565"],
    ));
    validate_strict(&ct);
    assert_eq!(levels(&ct).len(), 7);
}

/// Whether `cliptex tile` resolves tile (s, t) of `level` to a file that exists.
fn tile_exists(ct: &str, level: usize, s: u64, t: u64) -> bool {
    let (l, s, t) = (level.to_string(), s.to_string(), t.to_string());
    let loc: Value = serde_json::from_str(&ok(CLIPTEX, &["tile", ct, "--level", &l, "--s", &s, "--t", &t, "--json"]))
        .expect("cliptex tile --json prints JSON");
    Path::new(loc["path"].as_str().unwrap()).exists()
}

#[test]
fn sparse_inset_levels_hold_the_inset_a_magnified_border_and_absent_tiles_elsewhere() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("inset");
    let (clip, tile, big_k) = (128u64, 64u64, 2usize);
    let (s0, t0, s1, t1) = (1000u64, 600u64, 1200u64, 700u64);
    let summary = prep(
        &dir,
        &[
            "--source",
            "hash",
            "--size",
            "2048",
            "--tile",
            "64",
            "--clip",
            "128",
            "--format",
            "rgba8",
            "--inset",
            "1000,600,1200,700",
            "--inset-level",
            "2",
        ],
    );
    let ct = ct_path(&summary);
    validate_strict(&ct);
    let lv = levels(&ct);
    let coarse = read_level(&ct, big_k, &lv[big_k], 4);
    let coarse_w = lv[big_k].size.0;
    let (mut inset_tiles, mut border_tiles, mut absent_tiles) = (0, 0, 0);
    for (k, info) in lv.iter().enumerate().take(big_k) {
        let (w, h) = info.size;
        assert_eq!(info.tile, (tile, tile));
        // The inset in level-k texels, rounded outwards.
        let (is0, it0) = (s0 >> k, t0 >> k);
        let (is1, it1) = (s1.div_ceil(1 << k), t1.div_ceil(1 << k));
        let inset = |s: u64, t: u64| (s + 1) * tile > is0 && s * tile < is1 && (t + 1) * tile > it0 && t * tile < it1;
        // The tiles that exist, and their bounding box.
        let (mut bs0, mut bt0, mut bs1, mut bt1) = (u64::MAX, u64::MAX, 0, 0);
        for t in 0..h / tile {
            for s in 0..w / tile {
                // Far-away tiles are checked on a coarse grid; everything near the inset exactly.
                let near = s * tile + 3 * clip >= is0
                    && s * tile <= is1 + 3 * clip
                    && t * tile + 3 * clip >= it0
                    && t * tile <= it1 + 3 * clip;
                if !near && (s % 5 != 0 || t % 5 != 0) {
                    continue;
                }
                if !tile_exists(&ct, k, s, t) {
                    assert!(!inset(s, t), "level {k} inset tile ({s}, {t}) exists");
                    absent_tiles += 1;
                    continue;
                }
                (bs0, bt0, bs1, bt1) = (bs0.min(s), bt0.min(t), bs1.max(s + 1), bt1.max(t + 1));
                let data = read_tile(&ct, k, s, t);
                let shift = big_k - k;
                for r in 0..tile {
                    for x in 0..tile {
                        let (ls, lt) = (s * tile + x, t * tile + r);
                        let got = &data[((r * tile + x) * 4) as usize..][..4];
                        if inset(s, t) {
                            let mut expect = [0u8; 4];
                            hash(k as u32, ls, lt, &mut expect);
                            assert_eq!(got, expect, "level {k} inset texel ({ls}, {lt})");
                        } else {
                            let at = (((lt >> shift) * coarse_w + (ls >> shift)) * 4) as usize;
                            assert_eq!(got, &coarse[at..at + 4], "level {k} border texel ({ls}, {lt})");
                        }
                    }
                }
                if inset(s, t) {
                    inset_tiles += 1;
                } else {
                    border_tiles += 1;
                }
            }
        }
        // The border is at least one clip size wide on every side, unless the level ends first.
        assert!(bs0 == 0 || bs0 * tile + clip <= is0, "level {k}: border left {bs0}");
        assert!(bt0 == 0 || bt0 * tile + clip <= it0, "level {k}: border below {bt0}");
        assert!(bs1 * tile == w || bs1 * tile >= is1 + clip, "level {k}: border right {bs1}");
        assert!(bt1 * tile == h || bt1 * tile >= it1 + clip, "level {k}: border above {bt1}");
        // Absent tiles are covered by the level's default tile: zeros, one tile long.
        let ic = dir.join(format!("L{k:02}.ic"));
        let info: Value =
            serde_json::from_str(&ok(ICACHE, &["info", ic.to_str().unwrap(), "--json"])).expect("icache info --json");
        let default = info["default_tile"].as_str().expect("the .ic names a default tile");
        let bytes = std::fs::read(default).expect("the default tile exists");
        assert_eq!(bytes.len() as u64, tile * tile * 4);
        assert!(bytes.iter().all(|&b| b == 0));
        ok(ICACHE, &["validate", "--strict", ic.to_str().unwrap()]);
    }
    assert!(!tile_exists(&ct, 0, 0, 0) && !tile_exists(&ct, 0, 31, 31), "far corners are absent");
    assert_eq!(summary["inset_tiles"], inset_tiles);
    assert_eq!(summary["border_tiles"], border_tiles);
    assert!(absent_tiles > 0);
    // Level K and coarser are complete: every texel is the source's.
    for (k, info) in lv.iter().enumerate().skip(big_k) {
        let level = read_level(&ct, k, info, 4);
        let (w, h) = info.size;
        for (s, t) in [(0, 0), (w - 1, h - 1), (w / 3, h / 2)] {
            let mut expect = [0u8; 4];
            hash(k as u32, s, t, &mut expect);
            assert_eq!(&level[((t * w + s) * 4) as usize..][..4], expect, "level {k} ({s}, {t})");
        }
    }
    assert!(std::fs::read_to_string(&ct).unwrap().contains("\n# Sparse: levels 0 to 1 exist only inside"));
}

#[test]
fn filtered_insets_keep_the_texels_of_a_complete_run() {
    let tmp = tempfile::tempdir().unwrap();
    let base = ["--source", "terrain", "--size", "512", "--tile", "32", "--clip", "64", "--format", "rgb8"];
    let full = ct_path(&prep(&tmp.path().join("full"), &base));
    let mut args = base.to_vec();
    args.extend_from_slice(&["--inset", "0,448,40,512", "--inset-level", "1"]);
    let sparse = ct_path(&prep(&tmp.path().join("sparse"), &args));
    validate_strict(&sparse);
    // Level 0 inset tiles (columns 0-1, rows 14-15) are the complete run's; coarser levels are equal.
    for (s, t) in [(0, 14), (1, 15), (0, 15)] {
        assert_eq!(read_tile(&sparse, 0, s, t), read_tile(&full, 0, s, t), "tile ({s}, {t})");
    }
    let lv = levels(&full);
    for (k, info) in lv.iter().enumerate().skip(1) {
        assert_eq!(read_level(&sparse, k, info, 3), read_level(&full, k, info, 3), "level {k}");
    }
    assert!(!tile_exists(&sparse, 0, 15, 0), "a tile far from the inset is absent");
}

#[test]
fn an_inset_outside_the_texture_or_at_a_pyramid_level_is_refused() {
    let e = fails(
        &[
            "--source",
            "hash",
            "--size",
            "256",
            "--tile",
            "32",
            "--clip",
            "64",
            "--format",
            "l8",
            "--inset",
            "0,0,300,10",
            "--inset-level",
            "1",
            "--out",
            "unused-inset-out",
        ],
        1,
    );
    assert!(e.contains("S1 <= 256"), "{e}");
    let e = fails(
        &[
            "--source",
            "hash",
            "--size",
            "256",
            "--tile",
            "32",
            "--clip",
            "64",
            "--format",
            "l8",
            "--inset",
            "0,0,8,8",
            "--inset-level",
            "5",
            "--out",
            "unused-inset-out",
        ],
        1,
    );
    assert!(e.contains("expected an inset level from 1 to 2"), "{e}");
    assert!(!Path::new("unused-inset-out").exists());
}

#[test]
fn zstd_tiles_decode_to_the_raw_tiles_and_keep_pyramid_levels_raw() {
    let tmp = tempfile::tempdir().unwrap();
    let base = ["--source", "terrain", "--size", "256", "--tile", "32", "--clip", "64", "--format", "rgb8"];
    let raw = ct_path(&prep(&tmp.path().join("raw"), &base));
    let mut args = base.to_vec();
    args.extend_from_slice(&["--zstd", "3", "--inset", "0,0,64,64", "--inset-level", "1", "--streams", "2"]);
    let dir = tmp.path().join("zst");
    let zst = ct_path(&prep(&dir, &args));
    validate_strict(&zst);
    let ic = std::fs::read_to_string(dir.join("L00.ic")).unwrap();
    assert!(ic.contains("tile_format %sL00/r%03d.c%03d.raw.zst\n"), "{ic}");
    let lv = levels(&raw);
    let written = |k: usize, s: u64, t: u64| {
        let (l, s, t) = (k.to_string(), s.to_string(), t.to_string());
        let loc: Value =
            serde_json::from_str(&ok(CLIPTEX, &["tile", &zst, "--level", &l, "--s", &s, "--t", &t, "--json"])).unwrap();
        std::fs::read(loc["path"].as_str().unwrap()).ok()
    };
    let level1 = read_level(&raw, 1, &lv[1], 3);
    let mut compressed = 0;
    for (k, info) in lv.iter().enumerate() {
        for t in 0..info.size.1 / info.tile.1 {
            for s in 0..info.size.0 / info.tile.0 {
                let Some(bytes) = written(k, s, t) else {
                    assert_eq!(k, 0, "only level 0 is sparse");
                    continue;
                };
                let plain = read_tile(&raw, k, s, t);
                if k < 2 {
                    // Image-cache levels: one zstd frame per tile file.
                    let decoded = zstd::bulk::decompress(&bytes, plain.len()).expect("a zstd frame");
                    if k == 1 || (s < 2 && t < 2) {
                        assert_eq!(decoded, plain, "level {k} tile ({s}, {t})");
                    } else {
                        // A border tile: level 1 (itself compressed) magnified.
                        for i in 0..32 * 32 {
                            let (x, y) = (s * 32 + i % 32, t * 32 + i / 32);
                            let at = (((y / 2) * 128 + x / 2) * 3) as usize;
                            assert_eq!(&decoded[i as usize * 3..][..3], &level1[at..at + 3], "border ({x}, {y})");
                        }
                    }
                    compressed += 1;
                } else {
                    assert_eq!(bytes, plain, "pyramid level {k} stays raw");
                }
            }
        }
    }
    assert!(compressed > 16);
    let e = fails(&[&base[..], &["--zstd", "3", "--tiles-per-file", "2", "--out", "unused-zstd-out"]].concat(), 1);
    assert!(e.contains("one tile per file"), "{e}");
}

#[test]
fn a_wide_hash_texture_is_written_tile_by_tile_within_a_small_memory_limit() {
    // 32768x128: a level-0 band of the filter cascade would be 3 x 128 rows x 32768 texels = 12 MiB;
    // the hash source needs a tile per worker thread and the pyramid bands, under 1 MiB here.
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("wide");
    let args = ["--source", "hash", "--size", "32768x128", "--tile", "64", "--clip", "128", "--format", "l8"];
    let summary = prep(&dir, &[&args[..], &["--max-memory", "1"]].concat());
    let buffers = summary["buffer_bytes"].as_u64().unwrap();
    assert!(buffers <= 1 << 20, "{summary}");
    assert!(buffers * 8 < 3 * 128 * 32768, "buffers do not grow with the width: {summary}");
    let ct = ct_path(&summary);
    validate_strict(&ct);
    let lv = levels(&ct);
    for (k, info) in lv.iter().enumerate().take(4) {
        let (w, h) = info.size;
        for (s, t) in [(0, 0), (w - 1, h - 1), (w / 2 + 3, h / 3)] {
            let tile = read_tile(&ct, k, s / info.tile.0, t / info.tile.1);
            let mut expect = [0u8; 1];
            hash(k as u32, s, t, &mut expect);
            assert_eq!(tile[((t % info.tile.1) * info.tile.0 + s % info.tile.0) as usize], expect[0], "{k} ({s}, {t})");
        }
    }
    // The filtered sources still run the band cascade, whose memory grows with the width.
    let e = fails(
        &[&["--source", "terrain"][..], &args[2..], &["--max-memory", "1", "--out", "unused-wide-out"]].concat(),
        1,
    );
    assert!(e.contains("one row of level-0 tiles"), "{e}");
}

// ---- Heights (docs/ELEVATION.md): `clipprep` writing l32f, l16 and l16i with the level rules.

mod heights {
    use super::*;
    use clipmap::height::{HeightFormat, LevelRule};
    use clipmap::source::procedural::height_stored;
    use clipmap::source::TileId;

    /// One level of stored heights: width, height, values (rows in increasing t, s fastest).
    type Level = (usize, usize, Vec<f64>);

    /// Every level of a prepared height texture, read through the plan and the file source
    /// (each tile in turn), with the height format and rule its `.ct` declares.
    fn read_heights(ct: &Path) -> (HeightFormat, LevelRule, Vec<Level>) {
        let loaded = clipmap::plan::load_clip_texture(ct, &Default::default()).unwrap();
        let rendered = loaded.render();
        let plan = loaded.plan.unwrap_or_else(|| panic!("{} does not load:\n{rendered}", ct.display()));
        let h = plan.height.expect("the .ct declares heights");
        let src = clipmap::source::open_plan(plan, &Default::default()).unwrap();
        let desc = src.desc().clone();
        let b = h.format.bytes_per_texel();
        let mut levels = Vec::new();
        for (k, l) in desc.levels().iter().enumerate() {
            let ([w, hh], [tw, th]) = (l.size, l.tile);
            let mut v = vec![0f64; (w * hh) as usize];
            let mut tile = vec![0u8; (tw * th) as usize * b];
            for tt in 0..hh.div_ceil(th) {
                for ts in 0..w.div_ceil(tw) {
                    src.read_tile(TileId { level: k as u32, s: ts, t: tt }, &mut tile).unwrap();
                    for r in 0..th.min(hh) {
                        for c in 0..tw.min(w) {
                            let (s, t) = (ts * tw + c, tt * th + r);
                            v[(t * w + s) as usize] = h.format.read(&tile[((r * tw + c) as usize) * b..]);
                        }
                    }
                }
            }
            levels.push((w as usize, hh as usize, v));
        }
        (h.format, h.levels, levels)
    }

    /// Asserts every level after the first is `rule` applied, by brute force with `height.rs`, to
    /// the level above, the chain started from level 0 as written; compares stored values bit
    /// for bit (an f64 holding an f32 or an integer).
    fn assert_rule_chain(what: &str, format: &HeightFormat, rule: LevelRule, levels: &[Level]) {
        let mut want = levels[0].2.clone();
        let (mut w, mut h) = (levels[0].0, levels[0].1);
        for (k, (lw, lh, got)) in levels.iter().enumerate().skip(1) {
            want = format.reduce_level(rule, &want, w, h).unwrap();
            (w, h) = ((w / 2).max(1), (h / 2).max(1));
            assert_eq!((*lw, *lh), (w, h), "{what}: level {k} size");
            for (i, (g, e)) in got.iter().zip(&want).enumerate() {
                assert!(
                    g.to_bits() == e.to_bits(),
                    "{what}, rule {rule}: level {k} texel ({}, {}) is {g}, the rule gives {e}",
                    i % w,
                    i / w
                );
            }
        }
    }

    fn prep_fails(args: &[&str]) -> String {
        let (out, d) = exec(CLIPPREP, args);
        assert_eq!(out.status.code(), Some(1), "expected a refusal (exit 1)\n{d}");
        String::from_utf8_lossy(&out.stderr).into_owned()
    }

    #[test]
    fn the_procedural_heights_obey_every_rule_at_every_level_in_every_storage() {
        let dir = tempfile::tempdir().unwrap();
        let cases: [(&str, &[&str]); 6] = [
            ("l32f", &["--height-nodata", "-32768", "--height-levels", "mean"]),
            ("l32f", &["--height-nodata", "-32768", "--height-levels", "point"]),
            ("l32f", &["--height-nodata", "-32768", "--height-levels", "min"]),
            ("l32f", &["--height-nodata", "-32768", "--height-levels", "max"]),
            ("l16", &["--height-scale", "0.01", "--height-offset", "-300", "--height-nodata", "0"]),
            ("l16i", &["--height-scale", "0.5", "--height-nodata", "-32768", "--height-levels", "min"]),
        ];
        for (i, (format, extra)) in cases.iter().enumerate() {
            let out = dir.path().join(format!("h{i}"));
            let mut args =
                vec!["--source", "heights", "--size", "128x64", "--tile", "32", "--clip", "32", "--format", format];
            args.extend_from_slice(extra);
            let json = prep(&out, &args);
            let ct = out.join(json["ct"].as_str().unwrap().rsplit('/').next().unwrap());
            let (f, rule, levels) = read_heights(&ct);
            let what = format!("--format {format} {}", extra.join(" "));
            assert_eq!(f.storage().short_name(), *format, "{what}");
            // Level 0 is the height verification texture's, texel by texel.
            let (w, _, l0) = &levels[0];
            for (i, v) in l0.iter().enumerate() {
                let want = height_stored(&f, 0, (i % w) as u64, (i / w) as u64);
                assert_eq!(v.to_bits(), want.to_bits(), "{what}: level 0 texel {i}");
            }
            assert!(l0.iter().any(|&v| f.is_nodata(v)), "{what}: the source has nodata texels");
            assert_rule_chain(&what, &f, rule, &levels);
            assert_eq!(levels.len(), 7, "{what}: 128x64 down to 2x1");
            // `cliptex info` states the rule.
            let info = ok(CLIPTEX, &["info", ct.to_str().unwrap()]);
            assert!(info.contains(&format!("levels {rule}")), "{what}:\n{info}");
        }
        // The l32f verification heights with nodata -32768 are clipmapd's own at level 0.
        let (f, _, levels) = read_heights(&dir.path().join("h0/h0.ct"));
        assert_eq!(f, HeightFormat::VERIFICATION);
        assert_eq!(levels[0].2[5 * 128 + 17], height_stored(&HeightFormat::VERIFICATION, 0, 17, 5));
    }

    /// Writes `values` (rows top-down, x fastest) as a single-band GeoTIFF of GDAL data type
    /// `ty` (Float32 or Int16) through `gdal_translate`, from a raw file described by a VRT,
    /// tiled 16 x 16 or in strips, with `nodata` as its GDAL_NODATA.
    fn gdal_dem(
        dir: &Path,
        name: &str,
        w: usize,
        ty: &str,
        values: &[f64],
        nodata: Option<f64>,
        tiled: bool,
    ) -> PathBuf {
        let h = values.len() / w;
        let (raw, size): (Vec<u8>, usize) = match ty {
            "Float32" => (values.iter().flat_map(|&v| (v as f32).to_le_bytes()).collect(), 4),
            "Int16" => (values.iter().flat_map(|&v| (v as i16).to_le_bytes()).collect(), 2),
            _ => panic!("{ty}"),
        };
        std::fs::write(dir.join(format!("{name}.raw")), raw).unwrap();
        let vrt = format!(
            r#"<VRTDataset rasterXSize="{w}" rasterYSize="{h}">
  <VRTRasterBand dataType="{ty}" band="1" subClass="VRTRawRasterBand">
    <SourceFilename relativetoVRT="1">{name}.raw</SourceFilename>
    <ImageOffset>0</ImageOffset><PixelOffset>{size}</PixelOffset><LineOffset>{}</LineOffset><ByteOrder>LSB</ByteOrder>
  </VRTRasterBand>
</VRTDataset>"#,
            w * size
        );
        std::fs::write(dir.join(format!("{name}.vrt")), vrt).unwrap();
        let tif = dir.join(format!("{name}.tif"));
        let mut args: Vec<String> = vec!["-q".into(), "-of".into(), "GTiff".into()];
        if tiled {
            args.extend(["-co", "TILED=YES", "-co", "BLOCKXSIZE=16", "-co", "BLOCKYSIZE=16"].map(String::from));
        } else {
            args.extend(["-co", "BLOCKYSIZE=5"].map(String::from));
        }
        if let Some(nd) = nodata {
            args.extend(["-a_nodata".to_string(), nd.to_string()]);
        }
        args.extend([format!("{name}.vrt"), tif.to_str().unwrap().to_string()]);
        let out = Command::new("gdal_translate").args(&args).current_dir(dir).output().expect("gdal_translate runs");
        assert!(out.status.success(), "gdal_translate {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        tif
    }

    /// No `clipprep` staging directory or output left beside `out`.
    fn assert_nothing_written(out: &Path) {
        assert!(!out.exists(), "{} was written", out.display());
        let name = out.file_name().unwrap().to_string_lossy().into_owned();
        for e in std::fs::read_dir(out.parent().unwrap()).unwrap().flatten() {
            let n = e.file_name().to_string_lossy().into_owned();
            assert!(!(n.contains(&name) && e.path().is_dir()), "left behind: {n}");
        }
    }

    #[test]
    fn a_float_dem_from_gdal_with_nodata_and_a_nan_obeys_every_rule() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // 40 x 36 pixels (padded to 64 x 64), quarter-metre heights, GDAL nodata -9999 on a
        // diagonal band, one NaN at (5, 7).
        let (w, h) = (40usize, 36usize);
        let metres = |x: usize, y: usize| ((x * 37 + y * 101) % 2000) as f64 * 0.25 - 100.0;
        let is_nd = |x: usize, y: usize| (x + y).is_multiple_of(11);
        let values: Vec<f64> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if (x, y) == (5, 7) {
                    f64::NAN
                } else if is_nd(x, y) {
                    -9999.0
                } else {
                    metres(x, y)
                }
            })
            .collect();
        for tiled in [true, false] {
            let name = if tiled { "tiled" } else { "strips" };
            let tif = gdal_dem(d, name, w, "Float32", &values, Some(-9999.0), tiled);
            let tif = tif.to_str().unwrap();
            let base = ["--input", tif, "--pad", "--tile", "16", "--clip", "32", "--format", "l32f"];
            // Refused by default, naming the pixel, the value and the fix; nothing written.
            let out = d.join(format!("refused_{name}"));
            let mut args = base.to_vec();
            args.extend(["--height-nodata", "-32768", "--out", out.to_str().unwrap()]);
            let e = prep_fails(&args);
            assert!(e.contains("pixel (5, 7)") && e.contains("NaN") && e.contains("--nan nodata"), "{e}");
            assert_nothing_written(&out);
            // --nan nodata without --height-nodata takes the input's GDAL_NODATA as the value.
            let carried = d.join(format!("carried_{name}"));
            let mut args = base.to_vec();
            args.extend(["--nan", "nodata"]);
            prep(&carried, &args);
            let (f, _, _) = read_heights(&carried.join(format!("carried_{name}.ct")));
            assert_eq!(f.nodata(), Some(-9999.0), "the input's GDAL_NODATA");
            for rule in ["mean", "point", "min", "max"] {
                let out = d.join(format!("{name}_{rule}"));
                let mut args = base.to_vec();
                args.extend(["--height-nodata", "-32768", "--nan", "nodata", "--height-levels", rule]);
                prep(&out, &args);
                let (f, r, levels) = read_heights(&out.join(format!("{name}_{rule}.ct")));
                assert_eq!(r.name(), rule);
                let (lw, lh, l0) = &levels[0];
                assert_eq!((*lw, *lh), (64, 64));
                // Texel (s, t) is pixel (s, h - 1 - t); NaN, GDAL's nodata and the padding are nodata.
                for (i, v) in l0.iter().enumerate() {
                    let (s, t) = (i % lw, i / lw);
                    let want = if s >= w || t >= h {
                        -32768.0
                    } else {
                        let y = h - 1 - t;
                        if (s, y) == (5, 7) || is_nd(s, y) {
                            -32768.0
                        } else {
                            metres(s, y) as f32 as f64
                        }
                    };
                    assert_eq!(v.to_bits(), want.to_bits(), "{name} {rule}: level 0 texel ({s}, {t})");
                }
                assert_rule_chain(&format!("{name} DEM"), &f, r, &levels);
            }
        }
        // A 16-bit signed DEM in strips into l16i at half-metre steps, nodata kept.
        let ints: Vec<f64> =
            (0..32 * 32).map(|i| if i % 13 == 0 { -32768.0 } else { (i * 997 % 60_001) as f64 - 30_000.0 }).collect();
        let tif = gdal_dem(d, "int16", 32, "Int16", &ints, Some(-32768.0), false);
        let out = d.join("int16_out");
        let args = ["--input", tif.to_str().unwrap(), "--tile", "16", "--clip", "32", "--format", "l16i"];
        let mut a = args.to_vec();
        a.extend(["--height-scale", "2", "--height-nodata", "-32768", "--height-levels", "max"]);
        prep(&out, &a);
        let (f, r, levels) = read_heights(&out.join("int16_out.ct"));
        for (i, v) in levels[0].2.iter().enumerate() {
            let (s, t) = (i % 32, i / 32);
            let m = ints[(31 - t) * 32 + s];
            let want = if m == -32768.0 { -32768.0 } else { (m / 2.0).round() };
            assert_eq!(*v, want, "int16 texel ({s}, {t})");
        }
        assert_rule_chain("int16 DEM", &f, r, &levels);
    }

    #[test]
    fn centimetre_l16_round_trips_at_both_ends_and_refuses_what_it_cannot_hold() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // Every pixel at one end of l16's range with 0.01 m steps from -11000 m, or beside it.
        let (lo, hi) = (-11000.0, -11000.0 + 65535.0 * 0.01);
        let ends = [lo, lo + 0.01, lo + 0.02, hi - 0.02, hi - 0.01, hi];
        let values: Vec<f64> = (0..32 * 32).map(|i| ends[i % ends.len()]).collect();
        let tif = gdal_dem(d, "ends", 32, "Float32", &values, None, true);
        let out = d.join("ends_out");
        let base =
            ["--tile", "16", "--clip", "32", "--format", "l16", "--height-scale", "0.01", "--height-offset", "-11000"];
        let mut args = vec!["--input", tif.to_str().unwrap()];
        args.extend_from_slice(&base);
        prep(&out, &args);
        let (f, _, levels) = read_heights(&out.join("ends_out.ct"));
        let stored: Vec<f64> = [0.0, 1.0, 2.0, 65533.0, 65534.0, 65535.0].to_vec();
        for (i, v) in levels[0].2.iter().enumerate() {
            let (s, t) = (i % 32, i / 32);
            let k = ((31 - t) * 32 + s) % ends.len();
            assert_eq!(*v, stored[k], "texel ({s}, {t})");
            // Decoded, each is within half a step of the metres asked for (the f32 input), and
            // encodes back to itself.
            let m = f.decode(*v).unwrap();
            assert!((m - ends[k] as f32 as f64).abs() <= 0.005 + 1e-9, "texel ({s}, {t}): {m}");
            assert_eq!(f.encode(m).unwrap(), *v);
        }
        // One step past the top is refused, naming the pixel, the value, the range and the fix.
        let mut past = values.clone();
        past[3 * 32 + 9] = hi + 0.01;
        let tif = gdal_dem(d, "past", 32, "Float32", &past, None, true);
        let out = d.join("past_out");
        let mut args = vec!["--input", tif.to_str().unwrap(), "--out", out.to_str().unwrap()];
        args.extend_from_slice(&base);
        let e = prep_fails(&args);
        for want in ["pixel (9, 3)", "-10344.63", "-11000 m to -10344.65", "l16 with scale 0.01", "--format l32f"] {
            assert!(e.contains(want), "missing {want:?}: {e}");
        }
        assert_nothing_written(&out);
        // Height options on a colour format, and colour options on heights, are refused.
        let e = prep_fails(&[
            "--source", "heights", "--size", "64", "--tile", "16", "--clip", "32", "--format", "rgb8", "--out", "x",
        ]);
        assert!(e.contains("--format rgb8") && e.contains("l32f, l16 or l16i"), "{e}");
        let e = prep_fails(&[
            "--source", "heights", "--size", "64", "--tile", "16", "--clip", "32", "--format", "l32f", "--filter",
            "lanczos3", "--out", "x",
        ]);
        assert!(e.contains("--filter lanczos3") && e.contains("--height-levels"), "{e}");
        let e = prep_fails(&[
            "--source",
            "heights",
            "--size",
            "64",
            "--tile",
            "16",
            "--clip",
            "32",
            "--format",
            "l32f",
            "--height-scale",
            "2",
            "--out",
            "x",
        ]);
        assert!(e.contains("l32f stores metres"), "{e}");
    }

    #[test]
    fn cliptex_dump_draws_heights_in_false_colour_with_a_legend_of_the_regions_range() {
        use clipmap::report::hypsometric::{fraction, ramp, Legend};
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("hd");
        prep(
            &out,
            &[
                "--source",
                "heights",
                "--size",
                "128",
                "--tile",
                "32",
                "--clip",
                "32",
                "--format",
                "l32f",
                "--height-nodata",
                "-32768",
            ],
        );
        let ct = out.join("hd.ct");
        let ct = ct.to_str().unwrap();
        let f = HeightFormat::VERIFICATION;
        let (s0, t0, s1, t1) = (16u64, 8u64, 80u64, 56u64);
        let metres = |s: u64, t: u64| f.decode(height_stored(&f, 0, s, t));
        // The region's range, by brute force over the definition.
        let all: Vec<f64> = (t0..t1).flat_map(|t| (s0..s1).filter_map(move |s| metres(s, t))).collect();
        let (lo, hi) = all.iter().fold((f64::MAX, f64::MIN), |(a, b), &m| (a.min(m), b.max(m)));
        let nodata = (t1 - t0) * (s1 - s0) - all.len() as u64;
        assert!(nodata > 0, "the region has nodata texels");
        for (extra, range) in
            [(vec![], (lo, hi)), (vec!["--shade"], (lo, hi)), (vec!["--range", "-5000,5000"], (-5000.0, 5000.0))]
        {
            let png = dir.path().join("h.png");
            let region = format!("{s0},{t0},{s1},{t1}");
            let mut args =
                vec!["dump", ct, "--level", "0", "--region", &region, "--out", png.to_str().unwrap(), "--json"];
            args.extend(extra.iter().copied());
            let json: Value = serde_json::from_str(&ok(CLIPTEX, &args)).unwrap();
            let what = format!("cliptex dump {extra:?}");
            let hl = &json["heights"];
            assert_eq!(hl["range"][0].as_f64().unwrap(), range.0, "{what}: {json}");
            assert_eq!(hl["range"][1].as_f64().unwrap(), range.1, "{what}: {json}");
            assert_eq!(
                (hl["region_range"][0].as_f64(), hl["region_range"][1].as_f64()),
                (Some(lo), Some(hi)),
                "{what}"
            );
            assert_eq!(hl["nodata_texels"].as_u64(), Some(nodata), "{what}");
            assert_eq!(hl["labels"][0].as_str().unwrap(), format!("{:.2} m", range.0), "{what}");
            let img = image::open(&png).unwrap().to_rgba8();
            let h = (t1 - t0) as u32;
            assert_eq!(json["pixels"], serde_json::json!([img.width(), img.height()]), "{what}");
            let mut colours = std::collections::BTreeSet::new();
            for t in t0..t1 {
                for s in s0..s1 {
                    let (x, y) = ((s - s0) as u32, (t1 - 1 - t) as u32);
                    let p = img.get_pixel(x, y).0;
                    colours.insert(p);
                    match metres(s, t) {
                        None => assert_eq!(p, [0, 0, 0, 0], "{what}: nodata texel ({s}, {t}) is transparent"),
                        Some(m) if extra.is_empty() || extra[0] == "--range" => {
                            let c = ramp(fraction(m, range.0, range.1));
                            assert_eq!(p, [c[0], c[1], c[2], 255], "{what}: texel ({s}, {t}) at {m} m");
                        }
                        Some(_) => assert_eq!(p[3], 255, "{what}: texel ({s}, {t}) is opaque"),
                    }
                }
            }
            assert!(colours.len() > 100, "{what}: {} distinct colours", colours.len());
            // The legend's bar runs from the colour of the range's lowest metres to its highest.
            let lg = Legend::at(img.width(), h);
            let c0 = ramp(0.0);
            let c1 = ramp(1.0);
            assert_eq!(img.get_pixel(lg.bar_x0, lg.bar_y0).0, [c0[0], c0[1], c0[2], 255], "{what}");
            assert_eq!(img.get_pixel(lg.bar_x1 - 1, lg.bar_y1 - 1).0, [c1[0], c1[1], c1[2], 255], "{what}");
            // The region's extremes take the bar's end colours (without --range or --shade).
            if extra.is_empty() {
                let at = |want: f64| {
                    let (s, t) = (t0..t1)
                        .flat_map(|t| (s0..s1).map(move |s| (s, t)))
                        .find(|&(s, t)| metres(s, t) == Some(want))
                        .unwrap();
                    img.get_pixel((s - s0) as u32, (t1 - 1 - t) as u32).0
                };
                assert_eq!(at(lo), [c0[0], c0[1], c0[2], 255]);
                assert_eq!(at(hi), [c1[0], c1[1], c1[2], 255]);
            }
            // The labels are drawn: black pixels under the bar.
            let black = (lg.label_y..img.height())
                .flat_map(|y| (0..img.width()).map(move |x| (x, y)))
                .filter(|&(x, y)| img.get_pixel(x, y).0 == [0, 0, 0, 255])
                .count();
            assert!(black > 50, "{what}: {black} label pixels");
        }
        // --shade and --range are refused on a colour texture.
        let colour = dir.path().join("c");
        prep(&colour, &["--source", "hash", "--size", "64", "--tile", "32", "--clip", "32", "--format", "rgb8"]);
        let cct = colour.join("c.ct");
        let (o, d) = exec(
            CLIPTEX,
            &["dump", cct.to_str().unwrap(), "--shade", "--out", dir.path().join("x.png").to_str().unwrap()],
        );
        assert_eq!(o.status.code(), Some(1), "{d}");
        assert!(String::from_utf8_lossy(&o.stderr).contains("--shade draws heights"), "{d}");
    }
}
