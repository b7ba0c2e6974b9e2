//! `cliptex attach` against a mapping published by this test process (the service's writer and
//! engine, without the service around them).

use clipmap::clip::{Clipmap, Settings};
use clipmap::shm::Writer;
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
    let writer = Writer::create(dir.path(), "att", shape, desc.format(), 0o600, 0o600, 16_666_667).unwrap();
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

    let (code, out, _) = run(&["attach", "att", "--shm-dir", d, "--once", "--interval", "0.05"]);
    assert_eq!(code, 0);
    assert!(out.contains("level  size") && out.contains("4096x4096") && out.contains("["), "{out}");
    assert!(out.contains("read queues: no figures (control socket"), "{out}");

    let (code, _, err) = run(&["attach", "absent", "--shm-dir", d, "--once"]);
    assert_eq!(code, 2);
    assert!(err.contains("no clip texture `absent`"), "{err}");
}
