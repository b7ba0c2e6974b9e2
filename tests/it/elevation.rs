//! Elevation textures (docs/ELEVATION.md): the `#clipmap height…` lines of a `.ct` (docs/CONFIG.md
//! §17) read into the plan, each refusal saying where and what was expected, `cliptex validate
//! --strict` flagging them as not Performer's, and `cliptex info` stating the level rule; the
//! height verification texture served by the real `clipmapd`, every texel read through the Rust
//! client equal to its definition.

use crate::common;

use clipmap::config::Severity;
use clipmap::height::{HeightStorage, LevelRule};
use common::*;
use serde_json::Value;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const CLIPMAPD: &str = env!("CARGO_BIN_EXE_clipmapd");
const CLIPPREP: &str = env!("CARGO_BIN_EXE_clipprep");
const ROOT: &str = env!("CLIPMAP_ROOT");

/// `NO_IC_CT` with heights of `ext` (a GL type name) as one luminance component.
fn height_ct(ext: &str, lines: &str) -> String {
    NO_IC_CT
        .replace("ext_format PFTEX_PACK_8", &format!("ext_format {ext}"))
        .replace("int_format PFTEX_RGB_8", "int_format PFTEX_I_16")
        .replace("img_format PFTEX_RGB", "img_format PFTEX_LUMINANCE")
        + lines
}

#[test]
fn height_lines_are_read_into_the_plan() {
    let (p, _) = ct_ok(&height_ct(
        "GL_UNSIGNED_SHORT",
        "#clipmap height l16\n#clipmap height_scale 0.01\n#clipmap height_offset -11000\n#clipmap height_nodata 0\n#clipmap height_levels point\n",
    ));
    let h = p.height.expect("a height texture");
    assert_eq!(h.format.storage(), HeightStorage::U16);
    assert_eq!((h.format.scale(), h.format.offset(), h.format.nodata()), (0.01, -11000.0, Some(0.0)));
    assert_eq!(h.levels, LevelRule::Point);
    assert_eq!(p.texel.short_name(), "l16");

    let (p, _) = ct_ok(&height_ct("GL_FLOAT", "#clipmap height l32f\n#clipmap height_nodata -32768\n"));
    let h = p.height.unwrap();
    assert_eq!(
        (h.format.storage(), h.format.nodata(), h.levels),
        (HeightStorage::F32, Some(-32768.0), LevelRule::Mean)
    );
    assert_eq!(p.texel.short_name(), "l32f");

    let (p, _) = ct_ok(&height_ct("GL_SHORT", "#clipmap height l16i\n#clipmap height_levels max\n"));
    assert_eq!(p.height.unwrap().format.storage(), HeightStorage::I16);
    assert_eq!(p.texel.short_name(), "l16i");
    // A colour texture has none.
    assert!(ct_ok(NO_IC_CT).0.height.is_none());
}

#[test]
fn height_lines_are_portability_findings() {
    let (_, d) = ct_ok(&height_ct("GL_FLOAT", "#clipmap height l32f\n"));
    let x = expect(&d, "height-extension", Severity::Warning, Some((10, 10)), &["Performer", "height"]);
    assert!(x.portability);
}

#[test]
fn height_errors_say_where_and_what_was_expected() {
    // Line 10 is the first line after NO_IC_CT.
    let d = ct_err(&height_ct("GL_UNSIGNED_SHORT", "#clipmap height l24\n"));
    expect(&d, "bad-extension-value", Severity::Error, Some((10, 17)), &["l24", "`l32f`", "`l16i`"]);
    let d = ct_err(&NO_IC_CT.replace("tile_size 256 256 1\n", "tile_size 256 256 1\n#clipmap height l16\n"));
    expect(
        &d,
        "height-format-mismatch",
        Severity::Error,
        Some((10, 10)),
        &["rgb8", "GL_UNSIGNED_SHORT", "PFTEX_LUMINANCE"],
    );
    let d = ct_err(&height_ct("GL_UNSIGNED_SHORT", "#clipmap height l32f\n"));
    expect(&d, "height-format-mismatch", Severity::Error, Some((10, 10)), &["l16 texels", "GL_FLOAT"]);
    let d = ct_err(&height_ct("GL_UNSIGNED_SHORT", "#clipmap height_scale 0.01\n"));
    expect(
        &d,
        "height-setting-without-height",
        Severity::Error,
        Some((10, 10)),
        &["height_scale", "#clipmap height l16"],
    );
    for bad in ["nan", "inf", "-infinity", "NaN", "1e999", "ten"] {
        let d = ct_err(&height_ct("GL_UNSIGNED_SHORT", &format!("#clipmap height l16\n#clipmap height_scale {bad}\n")));
        expect(&d, "bad-extension-value", Severity::Error, Some((11, 23)), &[bad, "finite decimal number above zero"]);
    }
    let d = ct_err(&height_ct("GL_UNSIGNED_SHORT", "#clipmap height l16\n#clipmap height_scale 0\n"));
    expect(&d, "bad-height-format", Severity::Error, Some((11, 10)), &["height scale 0", "above zero"]);
    let d = ct_err(&height_ct("GL_UNSIGNED_SHORT", "#clipmap height l16\n#clipmap height_scale -0.5\n"));
    expect(&d, "bad-height-format", Severity::Error, Some((11, 10)), &["-0.5", "above zero"]);
    let d = ct_err(&height_ct("GL_UNSIGNED_SHORT", "#clipmap height l16\n#clipmap height_scale 1000\n"));
    expect(&d, "bad-height-format", Severity::Error, Some((11, 10)), &["65535000 m", "past the"]);
    let d = ct_err(&height_ct("GL_UNSIGNED_SHORT", "#clipmap height l16\n#clipmap height_nodata 70000\n"));
    expect(&d, "bad-height-format", Severity::Error, Some((11, 10)), &["70000", "0..=65535", "stored value"]);
    let d = ct_err(&height_ct("GL_FLOAT", "#clipmap height l32f\n#clipmap height_scale 0.01\n"));
    expect(&d, "bad-height-format", Severity::Error, Some((11, 10)), &["l32f stores metres"]);
    let d = ct_err(&height_ct("GL_SHORT", "#clipmap height l16i\n#clipmap height_levels median\n"));
    expect(&d, "bad-extension-value", Severity::Error, Some((11, 24)), &["median", "`point`"]);
    let d = ct_err(&height_ct("GL_SHORT", "#clipmap height_levls point\n"));
    expect(&d, "unknown-extension", Severity::Error, Some((10, 10)), &["did you mean `height_levels`?"]);
}

#[test]
fn validate_strict_flags_height_lines_and_info_states_the_level_rule() {
    let fx = Fixture::new();
    let ct = fx.write(
        "h.ct",
        height_ct(
            "GL_UNSIGNED_SHORT",
            "#clipmap height l16\n#clipmap height_scale 0.01\n#clipmap height_offset -11000\n#clipmap height_nodata 0\n#clipmap height_levels point\n",
        ),
    );
    let ct = ct.to_str().unwrap();
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["validate", ct]);
    assert!(out.status.success(), "without --strict the lines are notes\n{d}");
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["validate", ct, "--strict"]);
    assert!(!out.status.success(), "--strict refuses what Performer does not know\n{d}");
    assert!(d.contains("declares heights, which Performer 3.0 does not know"), "{d}");
    assert!(d.contains("(1 error, 0 warnings)"), "one finding a file, at its first height line\n{d}");
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["info", ct]);
    assert!(out.status.success(), "{d}");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("levels point (point-registered"), "{text}");
    assert!(text.contains("nodata 0"), "{text}");
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["info", ct, "--json"]);
    assert!(out.status.success(), "{d}");
    let info: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(info["texel_format"], "l16");
    assert_eq!(info["height"]["levels"], "point", "{info}");
    assert_eq!(info["height"]["format"]["storage"], "u16", "{info}");
    assert_eq!(info["height"]["format"]["scale"], 0.01, "{info}");
    assert_eq!(info["height"]["format"]["offset"], -11000.0, "{info}");
    assert_eq!(info["height"]["format"]["nodata"], 0.0, "{info}");
}

/// A running `clipmapd`, killed on drop.
struct Service {
    child: Child,
    err: PathBuf,
}

impl Service {
    fn start(dir: &Path, name: &str, args: &[&str]) -> Service {
        let socket = dir.join(format!("{name}.sock"));
        let err = dir.join(format!("{name}.err"));
        let child = Command::new(CLIPMAPD)
            .args(args)
            .args(["--tick-hz", "120", "--name", name, "--shm-dir", dir.to_str().unwrap(), "--socket"])
            .arg(&socket)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&err).unwrap())
            .spawn()
            .unwrap();
        let s = Service { child, err };
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(30) {
            if let Ok(mut c) = UnixStream::connect(&socket) {
                let mut line = String::new();
                if writeln!(c, "PING").is_ok()
                    && BufReader::new(c).read_line(&mut line).is_ok()
                    && line.starts_with("OK")
                {
                    return s;
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("the service did not come up: {}", s.log());
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.err).unwrap_or_default()
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn every_height_served_by_clipmapd_equals_the_verification_texture() {
    use clipmap::height::{HeightFormat, TileRange};
    use clipmap::source::procedural::height_stored;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "heights", &["--source", "heights", "--size", "1024", "--clip", "128", "--tile", "64"]);
    let c = clipmap::shm::Client::attach(d, "heights").expect("the mapping is there");
    assert_eq!((c.format_code, c.bytes_per_texel), (11, 4), "L32F in the mapping's header");
    let f = HeightFormat::VERIFICATION;
    // The header's heights block says what the source has: l32f metres, nodata -32768, and the
    // default level rule.
    let h = c.heights.expect("the header says the texels are heights");
    assert_eq!(h, clipmap::shm::layout::Heights::of(&f, LevelRule::Mean));
    assert_eq!((h.storage, h.scale, h.offset, h.nodata), (HeightStorage::F32, 1.0, 0.0, Some(-32768.0)));
    assert_eq!(h.format(), f);
    heights_seen_by_every_reader(d, "heights", "heights l32f scale 1 offset 0 nodata -32768 levels mean");
    let (mut checked, mut nodata) = (0usize, 0usize);
    for k in 0..c.levels.len() {
        // Wait for the level's valid region, then read it whole.
        let t = Instant::now();
        let v = loop {
            if let Some(st) = c.level_state(k) {
                let [s0, t0, s1, t1] = st.valid;
                if st.enabled && s1 > s0 && t1 > t0 {
                    break st.valid;
                }
            }
            assert!(t.elapsed() < Duration::from_secs(30), "level {k} never became valid\n{}", svc.log());
            std::thread::sleep(Duration::from_millis(5));
        };
        let [s0, t0, s1, t1] = v;
        let (w, h) = ((s1 - s0) as u64, (t1 - t0) as u64);
        let mut buf = vec![0u8; (w * h * 4) as usize];
        c.read_region(k, s0, t0, w, h, &mut buf).expect("the valid region reads");
        for (i, texel) in buf.chunks_exact(4).enumerate() {
            let (s, t) = (s0 as u64 + i as u64 % w, t0 as u64 + i as u64 / w);
            let want = height_stored(&f, k as u32, s, t) as f32;
            let got = f32::from_le_bytes([texel[0], texel[1], texel[2], texel[3]]);
            assert_eq!(got.to_bits(), want.to_bits(), "level {k} texel ({s}, {t}): {got} served, {want} defined");
            nodata += f.is_nodata(got as f64) as usize;
        }
        checked += buf.len() / 4;
        // The region's range as the height module reads it equals brute force over the definition.
        let metres: Vec<f64> = (0..w * h)
            .filter_map(|i| f.decode(height_stored(&f, k as u32, s0 as u64 + i % w, t0 as u64 + i / w)))
            .collect();
        let want = if metres.is_empty() {
            TileRange::Empty
        } else {
            TileRange::Heights {
                min: metres.iter().copied().fold(f64::INFINITY, f64::min),
                max: metres.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            }
        };
        assert_eq!(f.tile_range(&buf).unwrap(), want, "level {k}");
    }
    assert!(checked > 128 * 128 * 3, "every level read: {checked} texels");
    // One texel in sixteen is nodata.
    assert!(nodata * 32 > checked && nodata * 8 < checked, "{nodata} of {checked}");
}

/// The heights block of the mapping `name` in `dir`, as `cliptex attach --json`, the C reader and
/// the Python reader show it: each must say `line` (the readers' `--heights` line).
fn heights_seen_by_every_reader(dir: &Path, name: &str, line: &str) {
    let map = dir.join(format!("clipmap-{name}.map"));
    let (out, d) = exec(
        dir,
        CLIPTEX,
        &["attach", name, "--shm-dir", dir.to_str().unwrap(), "--once", "--json", "--interval", "0.05"],
    );
    assert!(out.status.success(), "{d}");
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let h = &v["heights"];
    if line == "not heights" {
        assert!(h.is_null(), "{v}");
    } else {
        let words: Vec<&str> = line.split(' ').collect();
        let storage = match words[1] {
            "l32f" => "f32",
            "l16" => "u16",
            _ => "i16",
        };
        assert_eq!(h["storage"], storage, "{h}");
        assert_eq!(h["scale"].as_f64(), words[3].parse::<f64>().ok(), "{h}");
        assert_eq!(h["offset"].as_f64(), words[5].parse::<f64>().ok(), "{h}");
        assert_eq!(h["nodata"].as_f64(), words[7].parse::<f64>().ok(), "{h}");
        assert_eq!(h["levels"], words[9], "{h}");
    }
    let reader = dir.join("reader");
    if !reader.exists() {
        let cc = Command::new(std::env::var("CC").unwrap_or_else(|_| "cc".into()))
            .args(["-O1", "-Wall", "-Wextra", "-Werror", "-I"])
            .arg(Path::new(ROOT).join("include"))
            .arg(Path::new(ROOT).join("clients/c/reader.c"))
            .arg("-o")
            .arg(&reader)
            .output()
            .unwrap();
        assert!(cc.status.success(), "{}", String::from_utf8_lossy(&cc.stderr));
    }
    let c = Command::new(&reader).arg(&map).arg("--heights").output().unwrap();
    assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
    assert_eq!(String::from_utf8_lossy(&c.stdout).trim(), line, "the C reader");
    let py = Command::new("python3")
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .arg(Path::new(ROOT).join("clients/python/clipmap_shm.py"))
        .arg(&map)
        .arg("--heights")
        .output()
        .unwrap();
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    assert_eq!(String::from_utf8_lossy(&py.stdout).trim(), line, "the Python reader");
}

/// A `.ct` of 16-bit luminance is not heights until its `#clipmap height` lines say so; with them
/// the mapping's heights block carries the `.ct`'s scale, offset, nodata value and level rule, and
/// every reader reads them. A damaged block is refused, saying where and what.
#[test]
fn a_ct_with_height_lines_publishes_its_heights_in_the_mapping_header() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("t");
    let args = ["--source", "terrain", "--size", "256", "--tile", "32", "--clip", "64", "--format", "l16", "--json"];
    let (o, log) = exec(d, CLIPPREP, &[&args[..], &["--out", out.to_str().unwrap()]].concat());
    assert!(o.status.success(), "{log}");
    let summary: Value = serde_json::from_slice(&o.stdout).unwrap();
    let ct = d.join(summary["ct"].as_str().unwrap());
    {
        let _svc = Service::start(d, "lum", &[ct.to_str().unwrap()]);
        let c = clipmap::shm::Client::attach(d, "lum").unwrap();
        assert_eq!((c.format_code, c.heights), (7, None), "16-bit luminance is not heights");
        heights_seen_by_every_reader(d, "lum", "not heights");
        // No tile ranges: every level descriptor's offset 80 is 0, and `cliptex attach --json`
        // shows no `tile_ranges`.
        use clipmap::shm::layout::{desc, header, DESC_BYTES};
        let b = std::fs::read(d.join("clipmap-lum.map")).unwrap();
        for k in 0..c.levels.len() {
            let o = header::LEVEL_DESCS + k * DESC_BYTES + desc::RANGES_OFFSET;
            assert_eq!(b[o..o + 8], [0; 8], "level {k}");
            assert_eq!(c.tile_ranges(k), vec![]);
        }
        let (o, log) = exec(
            d,
            CLIPTEX,
            &["attach", "lum", "--shm-dir", d.to_str().unwrap(), "--once", "--json", "--interval", "0.05"],
        );
        assert!(o.status.success(), "{log}");
        let v: Value = serde_json::from_slice(&o.stdout).unwrap();
        assert!(v["levels"].as_array().unwrap().iter().all(|l| l.get("tile_ranges").is_none()), "{v}");
        // A colour mapping whose descriptor claims ranges is refused by every reader.
        let mut bad = b.clone();
        let o = header::LEVEL_DESCS + desc::RANGES_OFFSET;
        bad[o..o + 8].copy_from_slice(&c.levels[0].slots.to_le_bytes());
        refused_by_every_reader(d, &bad, &["byte 2320 (tile ranges offset)", "expected 0", "not heights"]);
    }
    let text = std::fs::read_to_string(&ct).unwrap()
        + "#clipmap height l16\n#clipmap height_scale 0.25\n#clipmap height_offset -500\n#clipmap height_nodata 65535\n#clipmap height_levels max\n";
    let hct = d.join("t/heights.ct");
    std::fs::write(&hct, text).unwrap();
    let svc = Service::start(d, "dem", &[hct.to_str().unwrap()]);
    let c = clipmap::shm::Client::attach(d, "dem").unwrap();
    let h = c.heights.unwrap_or_else(|| panic!("the header says heights\n{}", svc.log()));
    assert_eq!(
        (c.format_code, h.storage, h.scale, h.offset, h.nodata, h.levels),
        (7, HeightStorage::U16, 0.25, -500.0, Some(65535.0), LevelRule::Max)
    );
    heights_seen_by_every_reader(d, "dem", "heights l16 scale 0.25 offset -500 nodata 65535 levels max");

    // A copy of the mapping with one value damaged is refused by every reader, saying where and what.
    use clipmap::shm::layout::{desc, header, heights, DESC_BYTES};
    let bytes = std::fs::read(d.join("clipmap-dem.map")).unwrap();
    // The tile ranges: level 1's off its page, or reaching into its slots.
    let r = c.levels[1].ranges;
    assert!(r != 0 && r < c.levels[1].slots, "an l16 height texture has ranges: {:?}", c.levels[1]);
    let at = header::LEVEL_DESCS + DESC_BYTES + desc::RANGES_OFFSET;
    for bad_offset in [r + 8, c.levels[1].slots] {
        let mut b = bytes.clone();
        b[at..at + 8].copy_from_slice(&bad_offset.to_le_bytes());
        refused_by_every_reader(d, &b, &["byte 2448 (tile ranges offset)", "multiple of 4096", "before the slots"]);
    }
    drop(c);
    let reserved = &bytes[header::HEIGHTS + heights::NODATA + 8..header::END];
    assert!(reserved.iter().all(|&b| b == 0), "the block's reserved bytes are zero");
    for (at, value, words) in [
        (heights::SCALE, f64::NAN.to_bits(), ["byte 6472 (scale)", "found NaN", "above zero"]),
        (heights::OFFSET, f64::INFINITY.to_bits(), ["byte 6480 (offset)", "found inf", "a finite number"]),
        (heights::RULE, 9, ["byte 6468 (level rule)", "found 9", "3 (max)"]),
        // What `HeightFormat::new` refuses: heights past 10,000 km from zero (blamed on the
        // offset when it alone is that far), and steps too fine for the offset.
        (heights::OFFSET, 2.0e7f64.to_bits(), ["byte 6480 (offset)", "20000000", "10000000 m"]),
        (heights::SCALE, 200.0f64.to_bits(), ["byte 6472 (scale)", "200", "10000000 m"]),
        (heights::SCALE, 1.0e-14f64.to_bits(), ["byte 6472 (scale)", "64-bit", "told apart"]),
    ] {
        let mut b = bytes.clone();
        let o = header::HEIGHTS + at;
        if at == heights::RULE {
            b[o..o + 4].copy_from_slice(&(value as u32).to_le_bytes());
        } else {
            b[o..o + 8].copy_from_slice(&value.to_le_bytes());
        }
        let bad = d.join("bad.map");
        std::fs::write(&bad, &b).unwrap();
        let e = clipmap::shm::Client::attach_path(&bad).expect_err("a damaged heights block is refused").to_string();
        for w in words {
            assert!(e.contains(w), "{e:?} lacks {w:?}");
        }
        let c = Command::new(d.join("reader")).arg(&bad).arg("--heights").output().unwrap();
        let py = Command::new("python3")
            .env("PYTHONDONTWRITEBYTECODE", "1")
            .arg(Path::new(ROOT).join("clients/python/clipmap_shm.py"))
            .arg(&bad)
            .arg("--heights")
            .output()
            .unwrap();
        for (who, o) in [("C", c), ("Python", py)] {
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{who}: {err}");
            let lower = err.to_lowercase();
            assert!(words.iter().all(|w| lower.contains(&w.to_lowercase())), "{who}: {err}");
        }
    }
}

/// The brute-force range of tile (S, T) of `level` of the height verification texture: the
/// metres of its texels inside the level, nodata excluded (`None`: all nodata).
fn defined_range(level: u32, size: [u64; 2], tile: [u64; 2], st: [i64; 2]) -> Option<(f64, f64)> {
    use clipmap::height::HeightFormat;
    use clipmap::source::procedural::height_stored;
    let f = HeightFormat::VERIFICATION;
    let (s0, t0) = (st[0] as u64 * tile[0], st[1] as u64 * tile[1]);
    let mut r: Option<(f64, f64)> = None;
    for t in t0..(t0 + tile[1]).min(size[1]) {
        for s in s0..(s0 + tile[0]).min(size[0]) {
            if let Some(m) = f.decode(height_stored(&f, level, s, t)) {
                r = Some(r.map_or((m, m), |(lo, hi)| (lo.min(m), hi.max(m))));
            }
        }
    }
    r
}

/// Runs a reader program, which must succeed; its standard output.
fn reader_output(cmd: &mut Command, who: &str) -> String {
    let o = cmd.env("PYTHONDONTWRITEBYTECODE", "1").output().unwrap();
    assert!(o.status.success(), "{who}: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

/// Issue #33's proof for tile ranges: through the real `clipmapd --source heights`, the published
/// range of every ready tile of every level, as the Rust client, the C reader, the Python reader
/// and `cliptex attach --json` read it, equals the brute-force range of the tile's texels as the
/// height source defines them; every texel of every level's published region the C and Python
/// readers read equals the definition; and `cliptex plan --heights` sizes the mapping, tile ranges
/// included, to the byte.
#[test]
fn every_published_tile_range_equals_brute_force_through_every_reader() {
    use clipmap::height::{HeightFormat, TileRange};
    use clipmap::source::procedural::height_stored;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "ranges", &["--source", "heights", "--size", "1024", "--clip", "128", "--tile", "32"]);
    let c = clipmap::shm::Client::attach(d, "ranges").expect("the mapping is there");
    let t = Instant::now();
    while c.try_snapshot().map_or(true, |s| s.min_lod != 0.0) {
        assert!(t.elapsed() < Duration::from_secs(30), "the levels never became whole\n{}", svc.log());
        std::thread::sleep(Duration::from_millis(10));
    }
    let snap = c.try_snapshot().unwrap();
    let map = d.join("clipmap-ranges.map");
    let bytes = std::fs::read(&map).unwrap();
    let u64_at = |o: usize| u64::from_le_bytes(bytes[o..o + 8].try_into().unwrap());
    let want = |k: usize, st: [i64; 2]| defined_range(k as u32, c.levels[k].size, c.levels[k].tile, st);
    let as_pair = |r: TileRange| match r {
        TileRange::Empty => None,
        TileRange::Heights { min, max } => Some((min, max)),
    };

    // The descriptors: each level's ranges between its tags and its slots, on a page.
    let mut range_bytes = 0;
    for (k, l) in c.levels.iter().enumerate() {
        use clipmap::shm::layout::{desc, header, DESC_BYTES, PAGE, RANGE_BYTES, TAG_BYTES};
        let r = u64_at(header::LEVEL_DESCS + k * DESC_BYTES + desc::RANGES_OFFSET);
        let slots = l.grid[0] * l.grid[1];
        assert_eq!(r, l.ranges);
        assert!(r % PAGE == 0 && r >= l.tags + slots * TAG_BYTES as u64, "level {k}: {l:?}");
        assert!(r + slots * RANGE_BYTES as u64 <= l.slots, "level {k}: {l:?}");
        range_bytes += l.slots - r;
    }

    // The Rust client: every tile under every published region is ready with its range, and
    // every range published equals brute force.
    let mut rust = std::collections::BTreeMap::new();
    let mut under = 0;
    for (k, st) in snap.levels.iter().enumerate() {
        assert!(st.enabled, "level {k}");
        for (tile, r) in c.tile_ranges(k) {
            assert_eq!(as_pair(r), want(k, tile), "level {k} tile {tile:?}: published against defined");
            assert_eq!(c.tile_range(k, tile), Ok(Some(r)));
            rust.insert((k, tile), as_pair(r));
        }
        let [s0, t0, s1, t1] = st.valid;
        let [tw, th] = [c.levels[k].tile[0] as i64, c.levels[k].tile[1] as i64];
        for ts in s0 / tw..=(s1 - 1) / tw {
            for tt in t0 / th..=(t1 - 1) / th {
                assert!(rust.contains_key(&(k, [ts, tt])), "level {k} tile ({ts}, {tt}) under the region has a range");
                under += 1;
            }
        }
    }
    // Regions of some size were checked (4 x 4 tiles or more at each of the three finest levels;
    // 56 tiles here), besides the spare tiles read ahead by now (how many depends on the pace).
    assert!(under >= 48, "{under} tiles under the regions");

    // The C and Python readers: `--ranges` lines "LEVEL S T MIN MAX", each equal to brute force,
    // covering every tile the Rust client found (the service stands still: nothing moves).
    heights_seen_by_every_reader(d, "ranges", "heights l32f scale 1 offset 0 nodata -32768 levels mean");
    let py_reader = Path::new(ROOT).join("clients/python/clipmap_shm.py");
    for (who, out) in [
        ("C", reader_output(Command::new(d.join("reader")).arg(&map).arg("--ranges"), "C")),
        ("Python", reader_output(Command::new("python3").arg(&py_reader).arg(&map).arg("--ranges"), "Python")),
    ] {
        let mut n = 0;
        for line in out.lines() {
            let w: Vec<&str> = line.split(' ').collect();
            assert_eq!(w.len(), 5, "{who}: {line:?}");
            let (k, s, t) =
                (w[0].parse::<usize>().unwrap(), w[1].parse::<i64>().unwrap(), w[2].parse::<i64>().unwrap());
            let (lo, hi) = (w[3].parse::<f64>().unwrap(), w[4].parse::<f64>().unwrap());
            let got = if lo.is_nan() && hi.is_nan() { None } else { Some((lo, hi)) };
            assert_eq!(got, want(k, [s, t]), "{who}: level {k} tile ({s}, {t})");
            n += rust.contains_key(&(k, [s, t])) as usize;
        }
        assert_eq!(n, rust.len(), "{who} read the range of every tile the Rust client read");
    }

    // Every texel of every level's published region, in metres, as the C and Python readers read it.
    let f = HeightFormat::VERIFICATION;
    for (who, out) in [
        ("C", reader_output(Command::new(d.join("reader")).arg(&map).arg("--heights-region"), "C")),
        ("Python", reader_output(Command::new("python3").arg(&py_reader).arg(&map).arg("--heights-region"), "Python")),
    ] {
        let mut lines = out.lines();
        let (mut levels, mut texels, mut nodata) = (0, 0u64, 0u64);
        while let Some(head) = lines.next() {
            let w: Vec<i64> = head.split(' ').filter_map(|x| x.parse().ok()).collect();
            assert!(head.starts_with("level ") && w.len() == 5, "{who}: {head:?}");
            let (k, [s0, t0, s1, t1]) = (w[0] as usize, [w[1], w[2], w[3], w[4]]);
            assert_eq!([s0, t0, s1, t1], snap.levels[k].valid, "{who}: level {k}'s region");
            for t in t0..t1 {
                let row: Vec<&str> = lines.next().expect("a row").split(' ').collect();
                assert_eq!(row.len() as i64, s1 - s0, "{who}: level {k} row {t}");
                for (i, v) in row.iter().enumerate() {
                    let s = s0 + i as i64;
                    let defined = f.decode(height_stored(&f, k as u32, s as u64, t as u64));
                    let got = if *v == "nodata" { None } else { Some(v.parse::<f64>().unwrap()) };
                    assert_eq!(got, defined, "{who}: level {k} texel ({s}, {t})");
                    nodata += got.is_none() as u64;
                    texels += 1;
                }
            }
            levels += 1;
        }
        assert_eq!(levels, c.levels.len(), "{who}: every level");
        assert!(texels > 128 * 128 * 3 && nodata * 32 > texels, "{who}: {texels} texels, {nodata} nodata");
    }

    // `cliptex attach --json`: each level's `tile_ranges`, null for an all-nodata tile.
    let (out, log) = exec(
        d,
        CLIPTEX,
        &["attach", "ranges", "--shm-dir", d.to_str().unwrap(), "--once", "--json", "--interval", "0.05"],
    );
    assert!(out.status.success(), "{log}");
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let mut shown = 0;
    for (k, level) in v["levels"].as_array().unwrap().iter().enumerate() {
        for e in level["tile_ranges"].as_array().unwrap_or_else(|| panic!("level {k}: {level}")) {
            let st = [e["s"].as_i64().unwrap(), e["t"].as_i64().unwrap()];
            let got = e["min"].as_f64().map(|lo| (lo, e["max"].as_f64().unwrap()));
            assert_eq!(got, want(k, st), "attach: level {k} tile {st:?}");
            assert_eq!(e["min"].is_null(), e["max"].is_null(), "{e}");
            shown += 1;
        }
    }
    assert!(shown >= rust.len(), "attach shows every ready tile: {shown} of {}", rust.len());

    // `cliptex plan --heights` sizes the mapping as served, 16 bytes a slot of it tile ranges.
    let plan = |extra: &[&str]| {
        let args =
            [&["plan", "--size", "1024", "--clip", "128", "--tile", "32", "--texel-bytes", "4", "--json"], extra]
                .concat();
        let (out, log) = exec(d, CLIPTEX, &args);
        assert!(out.status.success(), "{log}");
        serde_json::from_slice::<Value>(&out.stdout).unwrap()["image_caches"].clone()
    };
    let (with, without) = (plan(&["--heights"]), plan(&[]));
    assert_eq!(with["bytes"].as_u64(), Some(bytes.len() as u64), "{with}");
    assert_eq!(with["tile_range_bytes"].as_u64(), Some(range_bytes), "{with}");
    assert_eq!(without["bytes"].as_u64(), Some(bytes.len() as u64 - range_bytes), "{without}");
    assert_eq!(without["tile_range_bytes"].as_u64(), Some(0), "{without}");
}

/// `bytes`, written as a mapping, is refused by the Rust client, the C reader and the Python
/// reader (exit 2), each message holding every one of `words` (case aside).
fn refused_by_every_reader(d: &Path, bytes: &[u8], words: &[&str]) {
    let bad = d.join("refused.map");
    std::fs::write(&bad, bytes).unwrap();
    let e = clipmap::shm::Client::attach_path(&bad).expect_err("refused").to_string();
    let c = Command::new(d.join("reader")).arg(&bad).arg("--heights").output().unwrap();
    let py = Command::new("python3")
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .arg(Path::new(ROOT).join("clients/python/clipmap_shm.py"))
        .arg(&bad)
        .arg("--heights")
        .output()
        .unwrap();
    assert_eq!((c.status.code(), py.status.code()), (Some(2), Some(2)), "{c:?} {py:?}");
    for (who, msg) in [
        ("Rust", e),
        ("C", String::from_utf8_lossy(&c.stderr).into_owned()),
        ("Python", String::from_utf8_lossy(&py.stderr).into_owned()),
    ] {
        let lower = msg.to_lowercase();
        assert!(words.iter().all(|w| lower.contains(&w.to_lowercase())), "{who}: {msg}");
    }
}
