//! `cliptex attach` against a mapping published by this test process (the service's writer and
//! engine, without the service around them).

use clipmap::clip::{Clipmap, Settings};
use clipmap::shm::{Writer, WriterOptions};
use clipmap::source::{HashSource, TextureDesc};
use clipmap::texel::TexelFormat;
use std::process::Command;
use std::sync::Arc;

fn run(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex")).args(args).output().expect("cliptex runs");
    let (o, e) = (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned());
    (out.status.code().unwrap_or(-1), o, e)
}

#[test]
fn attach_once_json_reports_every_level_as_published() {
    let dir = tempfile::tempdir().unwrap();
    let desc =
        TextureDesc::new([4096, 4096], 256, TexelFormat::RGBA8, [64, 64]).unwrap().with_invalid_border(8).unwrap();
    let settings = Settings { budget_ns: None, ..Settings::default() };
    let shape = Clipmap::shape_for(&desc, &settings);
    let writer = Writer::create(WriterOptions::new(dir.path(), "att", shape, desc.format())).unwrap();
    let mut map = Clipmap::with_memory(Arc::new(HashSource::new(desc)), settings, writer.memory()).unwrap();
    for _ in 0..6 {
        map.tick([1000, 3000], None);
        map.wait_for_reads();
    }
    let d = dir.path().to_str().unwrap();
    let (code, out, err) = run(&["attach", "att", "--shm-dir", d, "--once", "--json", "--interval", "0.05"]);
    assert_eq!(code, 0, "stdout: {out}\nstderr: {err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let levels = v["levels"].as_array().unwrap();
    assert_eq!(levels.len(), map.level_count());
    for (k, l) in levels.iter().enumerate() {
        let want = map.level(k as u32).valid;
        let got: Vec<i64> = l["valid"].as_array().unwrap().iter().map(|x| x.as_i64().unwrap()).collect();
        assert_eq!(got, vec![want.s0, want.t0, want.s1, want.t1], "level {k}");
    }
    assert_eq!(v["clip_size"], 256);
    assert_eq!(v["min_lod"].as_f64(), Some(map.min_lod()));
    // No service around the mapping: no control socket, so no queue figures, and the reason.
    assert_eq!(v["streams"], serde_json::json!([]));
    let why = v["streams_error"].as_str().unwrap();
    assert!(why.contains("clipmap-att.sock"), "{why}");
    // Nor paging figures: those come from STATS too.
    assert_eq!(v["read_latency_ticks"], serde_json::Value::Null);
    assert!(levels.iter().all(|l| l["paging"].is_null()), "{v}");

    let (code, out, _) = run(&["attach", "att", "--shm-dir", d, "--once", "--interval", "0.05"]);
    assert_eq!(code, 0);
    assert!(out.contains("level  size") && out.contains("4096x4096") && out.contains("["), "{out}");
    assert!(out.contains("read queues: no figures (control socket"), "{out}");
    assert!(out.contains("paging: no figures (control socket"), "{out}");

    let (code, _, err) = run(&["attach", "absent", "--shm-dir", d, "--once"]);
    assert_eq!(code, 2);
    assert!(err.contains("no clip texture `absent`"), "{err}");
}

/// Runs `prog args`, bounded: a tool that blocks fails the test instead of hanging it.
fn run_bounded(prog: &str, args: &[&str]) -> (i32, String) {
    let dir = std::env::temp_dir();
    let (out, d) = crate::common::exec_bounded(&dir, prog, args, &[], std::time::Duration::from_secs(20));
    (out.status.code().unwrap_or(-1), d)
}

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");
const READ: &str = env!("CARGO_BIN_EXE_clipmap-read");

/// Every Rust reader of a mapping: `clipmap-read`, `cliptex attach`, `cliptex dump --attach`.
fn every_rust_reader(dir: &str, name: &str, out: &str) -> Vec<(&'static str, i32, String)> {
    let read = ["--name", name, "--shm-dir", dir, "--reads", "100", "--seconds", "5"];
    let attach = ["attach", name, "--shm-dir", dir, "--once", "--json", "--interval", "0.05"];
    let dump = ["dump", "--attach", name, "--shm-dir", dir, "--out-dir", out];
    vec![
        ("clipmap-read", run_bounded(READ, &read)),
        ("cliptex attach", run_bounded(CLIPTEX, &attach)),
        ("cliptex dump --attach", run_bounded(CLIPTEX, &dump)),
    ]
    .into_iter()
    .map(|(n, (c, d))| (n, c, d))
    .collect()
}

/// A published mapping (ticked until settled) in `dir` under `name`, and its bytes.
fn published(dir: &std::path::Path, name: &str) -> (Writer, Vec<u8>) {
    let desc =
        TextureDesc::new([1024, 1024], 128, TexelFormat::RGBA8, [64, 64]).unwrap().with_invalid_border(4).unwrap();
    let settings = Settings { budget_ns: None, ..Settings::default() };
    let shape = Clipmap::shape_for(&desc, &settings);
    let writer = Writer::create(WriterOptions::new(dir, name, shape, desc.format())).unwrap();
    let mut map = Clipmap::with_memory(Arc::new(HashSource::new(desc)), settings, writer.memory()).unwrap();
    for _ in 0..10 {
        map.tick([500, 500], None);
        map.wait_for_reads();
    }
    let bytes = std::fs::read(writer.path()).unwrap();
    (writer, bytes)
}

#[test]
fn a_fifo_planted_at_a_mapping_name_is_refused_at_once_by_every_rust_reader() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().to_str().unwrap();
    let fifo = tmp.path().join("clipmap-f.map");
    rustix::fs::mkfifoat(rustix::fs::CWD, &fifo, rustix::fs::Mode::from_raw_mode(0o600)).unwrap();
    let out = tmp.path().join("pics");
    for (tool, code, d) in every_rust_reader(d, "f", out.to_str().unwrap()) {
        assert_eq!(code, 2, "{tool}:\n{d}");
        assert!(
            d.contains("clipmap-f.map") && d.contains("a FIFO") && d.contains("not a regular file"),
            "{tool}:\n{d}"
        );
    }
    let reader = run_bounded(READ, &["--path", fifo.to_str().unwrap(), "--reads", "1"]);
    assert_eq!(reader.0, 2, "{}", reader.1);
}

#[test]
fn a_mapping_whose_format_disagrees_with_its_bytes_per_texel_is_refused_by_every_rust_reader() {
    let tmp = tempfile::tempdir().unwrap();
    let (_w, mut bytes) = published(tmp.path(), "good");
    // RGBA8 texels (4 bytes) under the code of RGBA16 (8 bytes): decoding one would read past it.
    let at = clipmap::shm::layout::header::TEXEL_FORMAT;
    bytes[at..at + 4].copy_from_slice(&10u32.to_le_bytes());
    std::fs::write(tmp.path().join("clipmap-fmt.map"), &bytes).unwrap();
    let out = tmp.path().join("pics");
    let d = tmp.path().to_str().unwrap();
    for (tool, code, d) in every_rust_reader(d, "fmt", out.to_str().unwrap()) {
        assert_eq!(code, 2, "{tool}:\n{d}");
        assert!(d.contains("texel format 10 (rgba16) has 8 bytes per texel, the header says 4"), "{tool}:\n{d}");
        assert!(!d.contains("panicked"), "{tool}:\n{d}");
    }
}

#[test]
fn corrupt_published_state_is_refused_by_cliptex_attach_and_dump_not_shown_as_disabled_levels() {
    let tmp = tempfile::tempdir().unwrap();
    let (_w, good) = published(tmp.path(), "good");
    let d = tmp.path().to_str().unwrap();
    use clipmap::shm::layout::{header, snapshot, state};
    let level0 = header::SNAPSHOT + snapshot::LEVELS;
    for (name, at, value, says) in [
        ("nan", header::SNAPSHOT + snapshot::MIN_LOD, f64::NAN.to_bits(), "min LOD NaN outside"),
        ("outside", level0 + state::VALID_S1, 5000, "not a non-empty rectangle inside the 1024x1024 level"),
    ] {
        let mut bytes = good.clone();
        bytes[at..at + 8].copy_from_slice(&value.to_le_bytes());
        std::fs::write(tmp.path().join(format!("clipmap-{name}.map")), &bytes).unwrap();
        let out = tmp.path().join(format!("pics-{name}"));
        for (tool, code, d) in every_rust_reader(d, name, out.to_str().unwrap()).into_iter().skip(1) {
            assert_eq!(code, 2, "{name}: {tool}:\n{d}");
            assert!(d.contains("published state outside its bounds") && d.contains(says), "{name}: {tool}:\n{d}");
        }
    }
    // The good mapping is shown as before.
    let (code, d) = run_bounded(CLIPTEX, &["attach", "good", "--shm-dir", d, "--once", "--json", "--interval", "0.05"]);
    assert_eq!(code, 0, "{d}");
}
