//! `cliptex dump`, `icache dump` and `cliptex attach` end to end, checked texel by texel against
//! the hash verification texture (docs/ARCHITECTURE.md §11): `clipprep --source hash` writes pyramids in a
//! temporary directory and every pixel of the dumped PNGs must be the hash texel it shows; a
//! running `clipmapd --source hash` is pictured level by level (valid texels, outlines) and as
//! rings (each pixel in the colour of the level it must use), and `cliptex attach --once --json`
//! must report its levels and read queues.
//!
//! Failures print the command, its exit status and its output.

use crate::common;
use clipmap::report::picture::{PALETTE, VALID_EDGE, WINDOW_EDGE};
use clipmap::source::procedural::hash;
use common::exec;
use serde_json::Value;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

const CLIPPREP: &str = env!("CARGO_BIN_EXE_clipprep");
const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const ICACHE: &str = env!("CARGO_BIN_EXE_icache");
const CLIPMAPD: &str = env!("CARGO_BIN_EXE_clipmapd");

/// A 256 x 256 hash pyramid in `format` with 32-texel tiles and clip 32 under `dir/NAME`;
/// returns the directory and the `.ct`.
fn prepare(dir: &Path, format: &str) -> (PathBuf, PathBuf) {
    let out = dir.join(format);
    let o = out.to_str().unwrap();
    let args = ["--source", "hash", "--size", "256", "--tile", "32", "--clip", "32", "--format", format, "--out", o];
    let (r, d) = exec(dir, CLIPPREP, &[&args[..], &["--json"]].concat());
    assert!(r.status.success(), "{d}");
    let summary: Value = serde_json::from_slice(&r.stdout).unwrap_or_else(|e| panic!("{e}\n{d}"));
    let ct = PathBuf::from(summary["ct"].as_str().expect("the summary names the .ct"));
    let ct = if ct.is_absolute() { ct } else { dir.join(ct) };
    (out, ct)
}

/// The PNG colour of hash texel (level, s, t) stored in `format`, computed from the format's
/// definition (not from the tool's converter).
fn expected(format: &str, level: u32, s: u64, t: u64) -> [u8; 4] {
    let mut b = [0u8; 4];
    hash(level, s, t, &mut b);
    let w = u16::from_le_bytes([b[0], b[1]]) as u32;
    let q = |v: u32, max: u32| ((v * 255 + max / 2) / max) as u8;
    match format {
        "rgb8" => [b[0], b[1], b[2], 255],
        "rgba8" => b,
        "l8" => [b[0], b[0], b[0], 255],
        "rgb565" => [q(w >> 11, 31), q((w >> 5) & 63, 63), q(w & 31, 31), 255],
        "rgba5551" => [q(w >> 11, 31), q((w >> 6) & 31, 31), q((w >> 1) & 31, 31), q(w & 1, 1)],
        _ => unreachable!("{format}"),
    }
}

/// Runs a dump with `--json`; returns its exit status, report and the PNG as RGBA (with whether
/// the file itself is RGBA).
fn dump(dir: &Path, prog: &str, args: &[&str]) -> (i32, Value, image::RgbaImage, bool, String) {
    let (o, d) = exec(dir, prog, &[args, &["--json"]].concat());
    let r: Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("not JSON: {e}\n{d}"));
    let img = image::open(r["png"].as_str().unwrap()).unwrap_or_else(|e| panic!("{e}\n{d}"));
    let rgba = matches!(img, image::DynamicImage::ImageRgba8(_));
    (o.status.code().unwrap(), r, img.to_rgba8(), rgba, d)
}

/// Every pixel of `img`, a picture of `[s0, s1) x [t0, t1)` of `level`, is the hash texel.
fn assert_hash_picture(img: &image::RgbaImage, format: &str, level: u32, region: [u64; 4], d: &str) {
    let [s0, t0, s1, t1] = region;
    assert_eq!(img.dimensions(), ((s1 - s0) as u32, (t1 - t0) as u32), "{d}");
    for (x, y, px) in img.enumerate_pixels() {
        let (s, t) = (s0 + x as u64, t1 - 1 - y as u64);
        assert_eq!(
            px.0,
            expected(format, level, s, t),
            "{format} level {level} texel ({s}, {t}) at pixel ({x}, {y})\n{d}"
        );
    }
}

#[test]
fn dumps_from_disk_are_the_hash_texture_in_every_format() {
    let dir = tempfile::tempdir().unwrap();
    for format in ["rgb8", "rgba8", "l8", "rgb565", "rgba5551"] {
        let (_, ct) = prepare(dir.path(), format);
        let ct = ct.to_str().unwrap();
        let png = dir.path().join(format!("{format}.png"));
        let p = png.to_str().unwrap();
        // A region across tile edges of level 0, a whole image-cache level, a pyramid level.
        for (level, region) in [(0u32, Some([5u64, 7, 100, 90])), (1, None), (3, None)] {
            let lv = level.to_string();
            let text = region.map(|r| format!("{},{},{},{}", r[0], r[1], r[2], r[3]));
            let mut args = vec!["dump", ct, "--level", &lv, "--out", p];
            if let Some(t) = &text {
                args.extend(["--region", t]);
            }
            let (code, r, img, rgba, d) = dump(dir.path(), CLIPTEX, &args);
            assert_eq!(code, 0, "{d}");
            assert_eq!(rgba, format.starts_with("rgba"), "alpha formats give RGBA pictures, others RGB\n{d}");
            let size = 256 >> level;
            let want = region.unwrap_or([0, 0, size, size]);
            assert_eq!(r["region"], serde_json::json!(want), "{d}");
            assert!(r["missing"].as_array().unwrap().is_empty(), "{d}");
            assert_hash_picture(&img, format, level, want, &d);
        }
    }
}

#[test]
fn icache_dump_reads_the_same_texels_as_cliptex_dump() {
    let dir = tempfile::tempdir().unwrap();
    let (out, _) = prepare(dir.path(), "rgb8");
    let png = dir.path().join("ic.png");
    let ic = out.join("L01.ic");
    let args = ["dump", ic.to_str().unwrap(), "--region", "30,1,97,64", "--out", png.to_str().unwrap()];
    let (code, r, img, _, d) = dump(dir.path(), ICACHE, &args);
    assert_eq!(code, 0, "{d}");
    assert_eq!(r["level"], Value::Null, "a standalone image cache has no level\n{d}");
    assert_hash_picture(&img, "rgb8", 1, [30, 1, 97, 64], &d);
}

#[test]
fn a_missing_tile_is_painted_and_reported_and_the_rest_is_dumped() {
    let dir = tempfile::tempdir().unwrap();
    let (out, ct) = prepare(dir.path(), "rgb8");
    let ic = out.join("L00.ic");
    let (o, d) = exec(dir.path(), ICACHE, &["tile", ic.to_str().unwrap(), "--s", "2", "--t", "1", "--json"]);
    assert!(o.status.success(), "{d}");
    let tile: Value = serde_json::from_slice(&o.stdout).unwrap();
    let gone = tile["path"].as_str().unwrap().to_string();
    std::fs::remove_file(&gone).unwrap();
    let png = dir.path().join("m.png");
    for prog in [CLIPTEX, ICACHE] {
        let target = if prog == CLIPTEX { ct.to_str().unwrap() } else { ic.to_str().unwrap() };
        let (code, r, img, _, d) =
            dump(dir.path(), prog, &["dump", target, "--region", "0,0,128,96", "--out", png.to_str().unwrap()]);
        assert_eq!(code, 1, "a missing tile is a data problem\n{d}");
        assert_eq!(img.dimensions(), (128, 96), "the picture is written all the same\n{d}");
        let missing = r["missing"].as_array().unwrap();
        assert_eq!(missing.len(), 1, "{d}");
        assert_eq!(
            (&missing[0]["s"], &missing[0]["t"], &missing[0]["kind"]),
            (&2.into(), &1.into(), &"missing".into())
        );
        assert_eq!(missing[0]["path"].as_str(), Some(gone.as_str()), "{d}");
        assert!(String::from_utf8_lossy(
            &exec(dir.path(), prog, &["dump", target, "--out", png.to_str().unwrap(), "-q"]).0.stderr
        )
        .contains("could not be read"));
        let img = image::open(&png).unwrap().to_rgba8();
        // The quiet run dumped the whole level: tile (2, 1) is texels [64, 96) x [32, 64).
        for (x, y, px) in img.enumerate_pixels() {
            let (s, t) = (x as u64, 255 - y as u64);
            if (64..96).contains(&s) && (32..64).contains(&t) {
                assert!(px.0 == [255, 0, 255, 255] || px.0 == [0, 0, 0, 255], "texel ({s}, {t}): {:?}", px.0);
            } else {
                assert_eq!(px.0, expected("rgb8", 0, s, t), "texel ({s}, {t})");
            }
        }
        let magenta = img.pixels().filter(|p| p.0 == [255, 0, 255, 255]).count();
        assert_eq!(magenta, 32 * 32 / 2, "half of the missing tile is magenta");
    }
}

/// A running `clipmapd`, killed on drop.
struct Service {
    child: Child,
    dir: PathBuf,
    name: &'static str,
    socket: PathBuf,
}

impl Service {
    fn start(dir: &Path, name: &'static str) -> Service {
        let socket = dir.join(format!("{name}.sock"));
        let args =
            ["--source", "hash", "--size", "65536", "--clip", "256", "--tile", "64", "--tick-hz", "60", "--name", name];
        let child = Command::new(CLIPMAPD)
            .args(args)
            .args(["--shm-dir", dir.to_str().unwrap(), "--socket", socket.to_str().unwrap()])
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(dir.join("clipmapd.err")).unwrap())
            .spawn()
            .unwrap();
        let s = Service { child, dir: dir.to_path_buf(), name, socket };
        s.wait_until("the socket answers PING", |s| s.ask("PING").starts_with("OK pong"));
        s
    }

    fn ask(&self, line: &str) -> String {
        let Ok(mut s) = UnixStream::connect(&self.socket) else { return String::new() };
        if writeln!(s, "{line}").is_err() {
            return String::new();
        }
        let mut reply = String::new();
        let _ = BufReader::new(s).read_line(&mut reply);
        reply
    }

    /// Waits (at most a minute: a liveness bound, not a timing assertion) until `ready`.
    fn wait_until(&self, what: &str, ready: impl Fn(&Service) -> bool) {
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(60) {
            if ready(self) {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        panic!("{what}: not reached\n{}", std::fs::read_to_string(self.dir.join("clipmapd.err")).unwrap_or_default());
    }

    fn attach(&self) -> (Value, String) {
        let d = self.dir.to_str().unwrap();
        let (o, dump) = exec(
            &self.dir,
            CLIPTEX,
            &[
                "attach",
                self.name,
                "--shm-dir",
                d,
                "--socket",
                self.socket.to_str().unwrap(),
                "--once",
                "--json",
                "--interval",
                "0.3",
            ],
        );
        assert_eq!(o.status.code(), Some(0), "{dump}");
        (serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}\n{dump}")), dump)
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Whether every level is published, enabled and min LOD is 0.
fn settled(v: &Value) -> bool {
    v["min_lod"].as_f64() == Some(0.0) && v["levels"].as_array().unwrap().iter().all(|l| l["enabled"] == true)
}

#[test]
fn attach_once_json_reports_levels_and_read_queues_of_a_running_service() {
    let dir = tempfile::tempdir().unwrap();
    let svc = Service::start(dir.path(), "att");
    svc.wait_until("every level usable", |s| settled(&s.attach().0));
    let (v, d) = svc.attach();
    assert_eq!(v["clip_size"], 256, "{d}");
    assert_eq!(v["bytes_per_texel"], 4, "{d}");
    assert_eq!(v["levels"].as_array().unwrap().len(), 17, "{d}");
    assert_eq!(v["closed"], false, "{d}");
    assert!(v["ticks_per_second"].as_f64().unwrap() > 0.0, "the service ticks while attached\n{d}");
    assert_eq!(v["socket"].as_str(), svc.socket.to_str(), "{d}");
    assert_eq!(v["streams_error"], Value::Null, "{d}");
    let streams = v["streams"].as_array().unwrap();
    assert_eq!(streams.len(), 1, "a procedural source has one stream server\n{d}");
    // The engine's summed counters (STATS) agree with the one stream's.
    let stats: Value = serde_json::from_str(svc.ask("STATS").trim_end().strip_prefix("OK ").unwrap()).unwrap();
    let q = &streams[0];
    assert!(q["reads_done"].as_u64().unwrap() > 0, "the windows were filled by reads\n{d}");
    assert!(q["reads_done"].as_u64() <= stats["engine"]["queue"]["reads_done"].as_u64(), "{d}");
    assert_eq!(stats["streams"].as_array().unwrap().len(), 1);
    let (bytes, reads) = (q["bytes_read"].as_u64().unwrap(), q["reads_done"].as_u64().unwrap());
    // Stack tiles are 64x64, pyramid levels one tile of at most the clip size (256x256).
    assert!(bytes >= reads * 4 && bytes <= reads * 256 * 256 * 4, "tile bytes per read\n{d}");
    for k in ["pending", "in_flight", "peak_pending", "reads_failed", "dropped", "tiles_per_second", "bytes_per_second"]
    {
        assert!(q[k].is_number(), "stream field {k}\n{d}");
    }
    assert_eq!(q["reads_failed"], 0, "{d}");

    // A socket that does not answer leaves the stream figures out and says why.
    let (o, d) = exec(
        dir.path(),
        CLIPTEX,
        &[
            "attach",
            "att",
            "--shm-dir",
            dir.path().to_str().unwrap(),
            "--socket",
            "/nonexistent.sock",
            "--once",
            "--json",
            "--interval",
            "0.05",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{d}");
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["streams"], serde_json::json!([]), "{d}");
    assert!(v["streams_error"].as_str().unwrap().contains("/nonexistent.sock"), "{d}");
}

fn pixel(img: &image::RgbImage, x: i64, y: i64) -> [u8; 3] {
    img.get_pixel(x as u32, y as u32).0
}

#[test]
fn dump_attach_pictures_every_level_and_the_rings_of_a_running_service() {
    let dir = tempfile::tempdir().unwrap();
    let svc = Service::start(dir.path(), "pic");
    // Off-centre, so the rings are not symmetric about the texture's middle.
    assert!(svc.ask("CENTRE 20000 41000").starts_with("OK"));
    svc.wait_until("centred and settled", |s| {
        let v = s.attach().0;
        settled(&v) && v["levels"][0]["centre"] == serde_json::json!([20000, 41000])
    });
    let out = dir.path().join("pictures");
    let (o, d) = exec(
        dir.path(),
        CLIPTEX,
        &[
            "dump",
            "--attach",
            "pic",
            "--shm-dir",
            dir.path().to_str().unwrap(),
            "--out-dir",
            out.to_str().unwrap(),
            "--json",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{d}");
    let r: Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}\n{d}"));
    assert_eq!(r["format"], "rgba8", "{d}");
    assert_eq!(r["closed"], false, "{d}");
    let levels = r["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 17, "{d}");
    let rect = |v: &Value| -> [i64; 4] { serde_json::from_value(v.clone()).unwrap() };
    for l in levels {
        let k = l["level"].as_u64().unwrap() as u32;
        let img = image::open(l["png"].as_str().unwrap()).unwrap().to_rgb8();
        let (w, v) = (rect(&l["window"]), rect(&l["valid"]));
        assert_eq!(l["texels_per_pixel"], 1, "clip 256 is drawn one pixel per texel\n{d}");
        assert_eq!(
            img.dimensions(),
            ((w[2] - w[0] + 4) as u32, (w[3] - w[1] + 4) as u32),
            "level {k}: window plus 2 pixels a side"
        );
        // Texel (s, t) is pixel (s - w.s0 + 2, h - 1 - (t - w.t0 + 2)).
        let h = img.height() as i64;
        let at = |s: i64, t: i64| pixel(&img, s - w[0] + 2, h - 1 - (t - w[1] + 2));
        for t in v[1]..v[3] {
            for s in v[0]..v[2] {
                let want = expected("rgba8", k, s as u64, t as u64);
                assert_eq!(at(s, t), [want[0], want[1], want[2]], "level {k} texel ({s}, {t}) in {}", l["png"]);
            }
        }
        let mid_t = (v[1] + v[3]) / 2;
        assert_eq!(at(v[0] - 1, mid_t), VALID_EDGE, "level {k}: red just left of the valid region");
        if k < 8 {
            assert_eq!(at(w[0] - 1, mid_t), WINDOW_EDGE, "level {k}: yellow just left of the window");
            // Stack levels: the invalid border (8 texels) between the two outlines is neither.
            // (On pyramid levels the valid region is the window: red covers yellow.)
            assert_eq!(v[0] - w[0], 8, "{d}");
            let b = at(w[0] + 3, mid_t);
            assert!(b == [60, 60, 60] || b == [80, 80, 80], "level {k} border {b:?}");
        }
    }

    // rings.png: each pixel has the colour of the finest level whose valid region holds it,
    // mixed with the texel's brightness from view.png, which must be that level's hash texel.
    let view = image::open(r["view"].as_str().unwrap()).unwrap().to_rgb8();
    let rings = image::open(r["rings"].as_str().unwrap()).unwrap().to_rgb8();
    let n = view.width() as i64;
    let step = r["view_extent"].as_i64().unwrap() / n;
    let c: [i64; 2] = serde_json::from_value(r["centre"].clone()).unwrap();
    let valid: Vec<[i64; 4]> = levels.iter().map(|l| rect(&l["valid"])).collect();
    let mut used = std::collections::BTreeSet::new();
    for y in 0..n {
        for x in 0..n {
            let s = c[0] + (x - n / 2) * step;
            let t = c[1] + ((n - 1 - y) - n / 2) * step;
            let k = (0..valid.len())
                .find(|&k| {
                    let (sk, tk, v) = (s >> k, t >> k, valid[k]);
                    sk >= v[0] && sk < v[2] && tk >= v[1] && tk < v[3]
                })
                .expect("the coarsest level covers the texture");
            used.insert(k);
            let want = expected("rgba8", k as u32, (s >> k) as u64, (t >> k) as u64);
            let got = pixel(&view, x, y);
            assert_eq!(got, [want[0], want[1], want[2]], "view pixel ({x}, {y}) = level {k} texel");
            let lum = (got[0] as u32 + got[1] as u32 + got[2] as u32) / 3;
            let mix = |a: u8| ((a as u32 * 3 + lum * 2) / 5) as u8;
            let p = PALETTE[k % PALETTE.len()];
            assert_eq!(pixel(&rings, x, y), [mix(p[0]), mix(p[1]), mix(p[2])], "rings pixel ({x}, {y}) is level {k}");
        }
    }
    assert!(used.len() >= 4 && used.contains(&0), "concentric rings of several levels: {used:?}");
}
