//! `cliptex dump --attach` on a texture of heights: each level drawn as `cliptex dump` draws
//! heights from disk (false colour over the level's range, legend below), not as grey clamped to
//! 0..1 m; checked texel by texel against the heights a reader reads from the mapping.

use crate::clipmapd::Service;
use clipmap::report::hypsometric::{fraction, ramp, NODATA_RGBA};
use clipmap::shm::Client;
use serde_json::Value;
use std::time::{Duration, Instant};

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");

#[test]
fn dump_attach_drew_heights_as_grey_clamped_to_one_metre_instead_of_false_colour_with_a_legend() {
    let dir = tempfile::tempdir().unwrap();
    let source = ["--source", "heights", "--size", "65536", "--clip", "256", "--tile", "64"];
    check_heights_dump(dir.path(), &source, "l32f");
}

#[test]
fn dump_attach_drew_sixteen_bit_heights_black_instead_of_false_colour_with_a_legend() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("l16");
    let prep = std::process::Command::new(env!("CARGO_BIN_EXE_clipprep"))
        .args(["--source", "heights", "--size", "1024", "--format", "l16", "--height-scale", "0.5"])
        .args(["--height-offset", "-100", "--height-nodata", "0", "--tile", "64", "--clip", "256", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(prep.status.success(), "{prep:?}");
    let ct = out.join("l16.ct");
    check_heights_dump(d, &[ct.to_str().unwrap()], "l16");
}

/// Serves `source` as `hts` in `d`, waits until every level is usable, dumps it with `cliptex
/// dump --attach` and checks every texel of every level's valid region against the false colour
/// of the height a reader reads there.
fn check_heights_dump(d: &std::path::Path, source: &[&str], format: &str) {
    let svc = Service::spawn_with(d, "hts", source, &[]);
    svc.wait_ready();
    let client = Client::attach(d, "hts").unwrap();
    let t = Instant::now();
    while client.snapshot().min_lod != 0.0 {
        assert!(t.elapsed() < Duration::from_secs(60), "never settled\n{}", svc.dump());
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = d.join("pictures");
    let o = std::process::Command::new(CLIPTEX)
        .args([
            "dump",
            "--attach",
            "hts",
            "--shm-dir",
            d.to_str().unwrap(),
            "--out-dir",
            out.to_str().unwrap(),
            "--json",
        ])
        .output()
        .unwrap();
    let said = format!("{o:?}");
    assert_eq!(o.status.code(), Some(0), "{said}");
    let r: Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}\n{said}"));
    assert_eq!(r["format"], format, "{said}");
    let f = client.heights.as_ref().unwrap().format();
    let rect = |v: &Value| -> [i64; 4] { serde_json::from_value(v.clone()).unwrap() };
    let mut coloured = 0;
    for l in r["levels"].as_array().unwrap() {
        let k = l["level"].as_u64().unwrap() as usize;
        let legend = &l["heights"];
        assert_eq!(legend["storage"], format, "level {k}: {l}");
        // `null`: no texel of the level has data (the heights texture's 1 x 1 level).
        let range: Option<[f64; 2]> =
            serde_json::from_value(legend["range"].clone()).unwrap_or_else(|e| panic!("{e}: {l}"));
        let img = image::open(l["png"].as_str().unwrap()).unwrap().to_rgba8();
        let (w, v) = (rect(&l["window"]), rect(&l["valid"]));
        // The map: the window plus 2 pixels a side; the legend's 40 rows below it.
        let map_h = (w[3] - w[1] + 4) as u32;
        assert_eq!(img.height(), map_h + 40, "level {k}");
        assert!(img.width() >= (w[2] - w[0] + 4) as u32, "level {k}");
        let bpt = client.bytes_per_texel;
        let mut row = vec![0u8; (v[2] - v[0]) as usize * bpt];
        for t in v[1]..v[3] {
            client.read_region(k, v[0], t, (v[2] - v[0]) as u64, 1, &mut row).unwrap();
            for s in v[0]..v[2] {
                let j = (s - v[0]) as usize * bpt;
                let want = match (f.decode(f.read(&row[j..j + bpt])), range) {
                    (Some(m), Some([lo, hi])) if m.is_finite() => {
                        let c = ramp(fraction(m, lo, hi));
                        [c[0], c[1], c[2], 255]
                    }
                    _ => NODATA_RGBA,
                };
                let (x, y) = ((s - w[0] + 2) as u32, map_h - 1 - (t - w[1] + 2) as u32);
                let got = img.get_pixel(x, y).0;
                assert_eq!(got, want, "level {k} texel ({s}, {t}) in {}", l["png"]);
                coloured += u64::from(got[0] != got[1] || got[1] != got[2]);
            }
        }
    }
    assert!(coloured > 1000, "{format}: false colour, not grey: {coloured} coloured texels");
    let range: [f64; 2] = serde_json::from_value(r["view_range"].clone()).unwrap_or_else(|e| panic!("{e}\n{said}"));
    assert!(range[0] < range[1], "{range:?}");
}
