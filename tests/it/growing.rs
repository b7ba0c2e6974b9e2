//! `cliptex grow`, driven as a user drives it: patches (raw texels and PNGs) around and across
//! the origin, every level's picture against texels computed here from the patches alone (no
//! library code), kill -9 in the middle of a rebuild, and refused inputs that leave nothing
//! behind.

use crate::common::{exec, exec_bounded, Fixture};
use std::path::Path;
use std::time::Duration;

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");

/// One patch as the test writes it: box (world units), time, rating, size, grey texels.
#[derive(Clone)]
pub(crate) struct P {
    pub(crate) bbox: [f64; 4],
    pub(crate) time: u64,
    pub(crate) rating: f64,
    pub(crate) w: u32,
    pub(crate) h: u32,
    pub(crate) texels: Vec<u8>,
}

pub(crate) fn patch(bbox: [f64; 4], time: u64, rating: f64, w: u32, h: u32, seed: u32) -> P {
    let texels = (0..w * h).map(|n| ((n % w) * 3 + (n / w) * 7 + seed * 41) as u8).collect();
    P { bbox, time, rating, w, h, texels }
}

/// Writes `p` as `NAME.json` with raw texels, or with a grey PNG when `png`.
pub(crate) fn write(fx: &Fixture, name: &str, p: &P, png: bool) {
    let src = if png {
        let img = image::GrayImage::from_raw(p.w, p.h, p.texels.clone()).unwrap();
        // Image row 0 is the top of the box (its largest y), for PNGs and raw texels alike.
        img.save(fx.path(&format!("{name}.png"))).unwrap();
        format!("\"image\": \"{name}.png\"")
    } else {
        std::fs::write(fx.path(&format!("{name}.raw")), &p.texels).unwrap();
        format!("\"raw\": {{\"width\": {}, \"height\": {}}}", p.w, p.h)
    };
    let b = p.bbox;
    fx.write(
        &format!("{name}.json"),
        format!(
            "{{\"bbox\": [{}, {}, {}, {}], \"time\": {}, \"rating\": {}, {src}}}",
            b[0], b[1], b[2], b[3], p.time, p.rating
        ),
    );
}

/// Level-0 texels from the patches, by the rule the docs give: a texel takes the patch whose box
/// holds its centre with the highest (rating, time, order added), sampled at pixel
/// floor((centre - min) / (max - min) * size); `None` where no patch holds it. Over level-0
/// texels [i0, i0 + w) x [j0, j0 + h), grid origin `o`, `r` texels a unit.
pub(crate) fn oracle0(ps: &[P], o: [f64; 2], r: f64, i0: i64, j0: i64, w: usize, h: usize) -> Vec<Option<u8>> {
    let mut out = vec![None; w * h];
    for y in 0..h {
        for x in 0..w {
            let c = [o[0] + ((i0 + x as i64) as f64 + 0.5) / r, o[1] + ((j0 + y as i64) as f64 + 0.5) / r];
            let best = ps
                .iter()
                .enumerate()
                .filter(|(_, p)| p.bbox[0] <= c[0] && c[0] < p.bbox[2] && p.bbox[1] <= c[1] && c[1] < p.bbox[3])
                .max_by(|(ia, a), (ib, b)| (a.rating, a.time, ia).partial_cmp(&(b.rating, b.time, ib)).unwrap());
            if let Some((_, p)) = best {
                let px =
                    (((c[0] - p.bbox[0]) / (p.bbox[2] - p.bbox[0])) * p.w as f64).floor().clamp(0.0, p.w as f64 - 1.0);
                let py =
                    (((p.bbox[3] - c[1]) / (p.bbox[3] - p.bbox[1])) * p.h as f64).floor().clamp(0.0, p.h as f64 - 1.0);
                out[y * w + x] = Some(p.texels[py as usize * p.w as usize + px as usize]);
            }
        }
    }
    out
}

/// The next level up: each texel the rounded average of the texels under it that have data.
/// `lo` holds texels [i0, ..) x [j0, ..) (both even), `w` x `h`.
pub(crate) fn coarser(lo: &[Option<u8>], w: usize, h: usize) -> Vec<Option<u8>> {
    let (w2, h2) = (w / 2, h / 2);
    (0..w2 * h2)
        .map(|n| {
            let (x, y) = (n % w2, n / w2);
            let v: Vec<u32> = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .filter_map(|&(dx, dy)| lo[(2 * y + dy) * w + 2 * x + dx].map(u32::from))
                .collect();
            (!v.is_empty()).then(|| ((v.iter().sum::<u32>() + v.len() as u32 / 2) / v.len() as u32) as u8)
        })
        .collect()
}

fn status(dir: &Path, tex: &str) -> serde_json::Value {
    let (out, d) = exec(dir, CLIPTEX, &["grow", "status", tex, "--json"]);
    assert!(out.status.success(), "{d}");
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}\n{d}"))
}

/// Dumps every level and compares each texel with the oracle (alpha 0 where no data).
fn check_every_level(fx: &Fixture, tex: &str, ps: &[P], o: [f64; 2], r: f64, tile: i64) {
    let st = status(fx.dir.path(), tex);
    let levels = st["levels"].as_u64().unwrap() as u32;
    let t = st["extent_tiles"].as_array().unwrap().iter().map(|v| v.as_i64().unwrap()).collect::<Vec<_>>();
    assert!(levels >= 2);
    // The oracle over level-0 texels of whole top-level tiles, so every level divides evenly.
    let span = tile << (levels - 1);
    let (s0, t0) = ((t[0] * tile).div_euclid(span) * span, (t[1] * tile).div_euclid(span) * span);
    let (s1, t1) =
        (((t[2] * tile) + span - 1).div_euclid(span) * span, ((t[3] * tile) + span - 1).div_euclid(span) * span);
    let (mut w, mut h) = ((s1 - s0) as usize, (t1 - t0) as usize);
    let mut want = oracle0(ps, o, r, s0, t0, w, h);
    let (mut base_s, mut base_t) = (s0, t0);
    for k in 0..levels {
        if k > 0 {
            want = coarser(&want, w, h);
            (w, h, base_s, base_t) = (w / 2, h / 2, base_s / 2, base_t / 2);
        }
        let png = fx.path(&format!("level{k}.png"));
        let (out, d) = exec(
            fx.dir.path(),
            CLIPTEX,
            &["grow", "dump", tex, "--level", &k.to_string(), "--out", png.to_str().unwrap()],
        );
        assert!(out.status.success(), "{d}");
        let img = image::open(&png).unwrap().to_rgba8();
        // The picture covers the level's tiles under the extent, from tile ts0, tt0; row 0 is the top.
        let (ps0, pt0) = ((t[0] * tile).div_euclid(tile << k) * tile, (t[1] * tile).div_euclid(tile << k) * tile);
        let (pw, ph) = (img.width() as i64, img.height() as i64);
        let mut checked = 0;
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let (i, j) = (base_s + x, base_t + y);
                let (px, py) = (i - ps0, j - pt0);
                let got = if (0..pw).contains(&px) && (0..ph).contains(&py) {
                    let p = img.get_pixel(px as u32, (ph - 1 - py) as u32).0;
                    (p[3] == 255).then_some(p[0])
                } else {
                    None
                };
                assert_eq!(got, want[y as usize * w + x as usize], "level {k} texel ({i}, {j})");
                checked += got.is_some() as usize;
            }
        }
        assert!(checked > 0, "level {k} has data");
    }
}

/// Patches around and across the origin, overlapping, so that growth goes left, right, down and
/// up and ratings and times both decide.
fn survey(big: bool) -> Vec<P> {
    let m = if big { 4.0 } else { 1.0 };
    let px = |v: u32| if big { v * 3 } else { v };
    vec![
        patch([-20.0 * m, -10.0 * m, 25.0 * m, 18.0 * m], 1, 1.0, px(30), px(20), 1),
        patch([10.0 * m, 5.0 * m, 70.0 * m, 30.0 * m], 2, 1.0, px(40), px(16), 2),
        patch([-90.0 * m, -5.0 * m, -15.0 * m, 12.0 * m], 3, 0.0, px(25), px(9), 3),
        patch([-30.0 * m, -60.0 * m, 0.0 * m, -2.0 * m], 4, 2.0, px(12), px(30), 4),
        patch([-5.0 * m, 20.0 * m, 15.0 * m, 75.0 * m], 5, 0.5, px(10), px(28), 5),
        patch([-8.0 * m, -8.0 * m, 8.0 * m, 8.0 * m], 0, 1.0, px(8), px(8), 6),
    ]
}

#[test]
fn patches_grow_a_texture_in_every_direction_and_every_level_matches_them() {
    let fx = Fixture::new();
    let (o, r, tile) = ([0.5, -1.25], 1.5, 8);
    let (out, d) = exec(
        fx.dir.path(),
        CLIPTEX,
        &[
            "grow",
            "create",
            "tex",
            "--origin",
            "0.5,-1.25",
            "--texels-per-unit",
            "1.5",
            "--tile",
            "8",
            "--format",
            "l8",
        ],
    );
    assert!(out.status.success(), "{d}");
    let ps = survey(false);
    let mut levels = Vec::new();
    for (n, p) in ps.iter().enumerate() {
        write(&fx, &format!("p{n}"), p, n % 2 == 1);
        let (out, d) =
            exec(fx.dir.path(), CLIPTEX, &["grow", "add", "tex", &format!("p{n}.json"), "--json", "--per-step", "5"]);
        assert!(out.status.success(), "{d}");
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["added"][0]["id"], n as u64 + 1, "{d}");
        assert_eq!(v["status"]["pending"], 0);
        assert_eq!(v["status"]["applied"], n as u64 + 1);
        levels.push(v["status"]["levels"].as_u64().unwrap());
        // After each patch the texture is what the patches so far imply, at every level.
        check_every_level(&fx, "tex", &ps[..=n], o, r, tile);
    }
    assert!(levels.windows(2).all(|w| w[0] <= w[1]) && levels[0] < *levels.last().unwrap(), "levels grow: {levels:?}");
    let st = status(fx.dir.path(), "tex");
    let e = st["extent"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect::<Vec<_>>();
    assert_eq!(e, vec![-90.0, -60.0, 70.0, 75.0]);
    for field in [
        "format",
        "tile",
        "origin",
        "texels_per_unit",
        "patches",
        "tiles",
        "tiles_per_level",
        "pending",
        "applied",
        "replayed",
    ] {
        assert!(!st[field].is_null(), "status has {field}: {st}");
    }
}

#[test]
fn kill_9_in_the_middle_of_a_rebuild_loses_no_acknowledged_patch() {
    let (o, r, tile) = ([0.0, 0.0], 1.0, 8);
    let ps = survey(true);
    let mut interrupted = 0;
    for (round, delay_ms) in [0u64, 50, 200].into_iter().enumerate() {
        let fx = Fixture::new();
        let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "create", "tex", "--tile", "8", "--format", "l8"]);
        assert!(out.status.success(), "{d}");
        let mut args = vec!["grow".to_string(), "add".into(), "tex".into(), "--per-step".into(), "16".into()];
        for (n, p) in ps.iter().enumerate() {
            write(&fx, &format!("p{n}"), p, false);
            args.push(format!("p{n}.json"));
        }
        let mut child = std::process::Command::new(CLIPTEX)
            .current_dir(fx.dir.path())
            .args(&args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        // Read the acknowledgements as they come; kill -9 a moment after the last one, while
        // the tiles are being rebuilt.
        let mut acked = Vec::new();
        let mut lines = std::io::BufRead::lines(std::io::BufReader::new(child.stdout.take().unwrap()));
        for line in lines.by_ref() {
            let line = line.unwrap();
            if let Some(id) = line.split("added as patch ").nth(1) {
                acked.push(id.trim().parse::<u64>().unwrap());
                if acked.len() == ps.len() {
                    break;
                }
            }
        }
        std::thread::sleep(Duration::from_millis(delay_ms));
        // Child::kill sends SIGKILL on Unix: no handler runs, nothing is flushed or cleaned up.
        child.kill().ok();
        child.wait().unwrap();
        assert_eq!(acked, (1..=ps.len() as u64).collect::<Vec<_>>(), "round {round}");
        let st = status(fx.dir.path(), "tex");
        assert_eq!(st["patches"], ps.len(), "round {round}: every acknowledged patch is kept: {st}");
        if st["applied"].as_u64().unwrap() < ps.len() as u64 {
            interrupted += 1;
            assert!(st["replayed"].as_u64().unwrap() > 0, "{st}");
        }
        let (out, d) =
            exec_bounded(fx.dir.path(), CLIPTEX, &["grow", "rebuild", "tex", "--json"], &[], Duration::from_secs(120));
        assert!(out.status.success(), "{d}");
        let st = status(fx.dir.path(), "tex");
        assert_eq!(
            (st["pending"].as_u64(), st["applied"].as_u64(), st["replayed"].as_u64()),
            (Some(0), Some(ps.len() as u64), Some(0))
        );
        check_every_level(&fx, "tex", &ps, o, r, tile);
    }
    assert!(interrupted > 0, "at least one kill landed in the middle of a rebuild");
}

#[test]
fn bad_patches_are_refused_with_their_file_and_leave_nothing_behind() {
    let fx = Fixture::new();
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "create", "tex", "--tile", "8", "--format", "l8"]);
    assert!(out.status.success(), "{d}");
    let good = patch([0.0, 0.0, 10.0, 10.0], 0, 0.0, 4, 4, 1);
    write(&fx, "good", &good, false);
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "add", "tex", "good.json"]);
    assert!(out.status.success(), "{d}");
    let files_before = std::fs::read_dir(fx.path("tex/patches")).unwrap().count();
    let cases: Vec<(&str, String, &[u8], &str)> = vec![
        ("short", r#"{"bbox": [0, 0, 4, 4], "raw": {"width": 4, "height": 4}}"#.into(), &[1u8; 15][..], "expected 16"),
        (
            "empty",
            r#"{"bbox": [3, 0, 3, 4], "raw": {"width": 1, "height": 1}}"#.into(),
            &[1u8][..],
            "empty or inverted along x",
        ),
        (
            "inverted",
            r#"{"bbox": [0, 9, 4, 2], "raw": {"width": 1, "height": 1}}"#.into(),
            &[1u8][..],
            "empty or inverted along y",
        ),
        ("absurd", r#"{"bbox": [0, 0, 1e12, 4], "raw": {"width": 1, "height": 1}}"#.into(), &[1u8][..], "spans"),
        ("infinite", r#"{"bbox": [0, 0, 1e400, 4], "raw": {"width": 1, "height": 1}}"#.into(), &[1u8][..], "not valid"),
        (
            "garbage",
            r#"{"bbox": [0, 0, 4, 4], "image": "garbage.png"}"#.into(),
            &b"not an image at all"[..],
            "not in a format this build reads",
        ),
        (
            "typo",
            r#"{"bbox": [0, 0, 4, 4], "ratng": 2, "raw": {"width": 1, "height": 1}}"#.into(),
            &[1u8][..],
            "unknown field `ratng`",
        ),
        (
            "both",
            r#"{"bbox": [0, 0, 4, 4], "image": "x.png", "raw": {"width": 1, "height": 1}}"#.into(),
            &[1u8][..],
            "exactly one of",
        ),
    ];
    for (name, json, data, words) in &cases {
        fx.write(&format!("{name}.json"), json);
        let data_name = if *name == "garbage" { "garbage.png".to_string() } else { format!("{name}.raw") };
        std::fs::write(fx.path(&data_name), data).unwrap();
        let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "add", "tex", &format!("{name}.json")]);
        assert_eq!(out.status.code(), Some(1), "{d}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(&format!("{name}.json")) && err.contains(words), "{name}: {err}");
        assert!(!err.contains("patch 0"), "a patch being read has no id to name: {err}");
    }
    // A 16-bit PNG into an 8-bit texture: refused, not scaled.
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(2, 2, vec![1u16, 2, 3, 4])
        .unwrap()
        .save(fx.path("deep.png"))
        .unwrap();
    fx.write("deep.json", r#"{"bbox": [0, 0, 4, 4], "image": "deep.png"}"#);
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "add", "tex", "deep.json"]);
    assert_eq!(out.status.code(), Some(1), "{d}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("8 bits a component"), "{d}");
    assert_eq!(std::fs::read_dir(fx.path("tex/patches")).unwrap().count(), files_before, "nothing half-applied");
    let st = status(fx.dir.path(), "tex");
    assert_eq!((st["patches"].as_u64(), st["applied"].as_u64()), (Some(1), Some(1)));
    // Not a growing texture; an unknown format; a non-empty directory.
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "status", "."]);
    assert_eq!(out.status.code(), Some(1), "{d}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("cliptex grow create"), "{d}");
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "create", "t2", "--format", "rgb5"]);
    assert_eq!(out.status.code(), Some(1), "{d}");
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "create", "tex"]);
    assert_eq!(out.status.code(), Some(1), "{d}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("not empty"), "{d}");
}

#[test]
fn a_watched_directory_takes_patches_as_they_appear_and_one_writer_at_a_time() {
    let fx = Fixture::new();
    let (o, r, tile) = ([0.0, 0.0], 1.0, 8);
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "create", "tex", "--tile", "8", "--format", "l8"]);
    assert!(out.status.success(), "{d}");
    let log = std::fs::File::create(fx.path("watch.log")).unwrap();
    let mut child = std::process::Command::new(CLIPTEX)
        .current_dir(fx.dir.path())
        .args(["grow", "watch", "tex", "incoming", "--interval", "0.02", "--per-step", "7"])
        .stdout(log.try_clone().unwrap())
        .stderr(log)
        .spawn()
        .unwrap();
    let ps = survey(false);
    let wait_for = |applied: u64| {
        let start = std::time::Instant::now();
        loop {
            let st = status(fx.dir.path(), "tex");
            if st["applied"].as_u64() == Some(applied) && st["pending"].as_u64() == Some(0) {
                return st;
            }
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "the watcher took {st}\n{}",
                std::fs::read_to_string(fx.path("watch.log")).unwrap()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    // Until the watcher has made the drop directory: bounded, and not after it has exited.
    let start = std::time::Instant::now();
    while !fx.path("incoming").exists() {
        let exited = child.try_wait().unwrap();
        assert!(
            exited.is_none() && start.elapsed() < Duration::from_secs(60),
            "the watcher made no incoming/ (exited: {exited:?})\n{}",
            std::fs::read_to_string(fx.path("watch.log")).unwrap()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    // As a writer should: the data first, the sidecar renamed into place last.
    for (n, p) in ps.iter().enumerate() {
        write(&fx, &format!("p{n}"), p, n % 2 == 0);
        let data = if n % 2 == 0 { format!("p{n}.png") } else { format!("p{n}.raw") };
        std::fs::rename(fx.path(&data), fx.path(&format!("incoming/{data}"))).unwrap();
        std::fs::rename(fx.path(&format!("p{n}.json")), fx.path(&format!("incoming/p{n}.json"))).unwrap();
        if n == 2 {
            std::fs::write(fx.path("incoming/bad.raw"), [0u8]).unwrap();
            // Renamed into place like the others (written in place, the watcher could see it
            // still empty, which is a different refusal).
            fx.write("bad.json", r#"{"bbox": [0, 0, 0, 4], "raw": {"width": 1, "height": 1}}"#);
            std::fs::rename(fx.path("bad.json"), fx.path("incoming/bad.json")).unwrap();
        }
    }
    wait_for(ps.len() as u64);
    // While it runs, another writer is refused, and lookers are not.
    write(&fx, "extra", &ps[0], false);
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "add", "tex", "extra.json"]);
    assert_eq!(out.status.code(), Some(1), "{d}");
    assert!(String::from_utf8_lossy(&out.stderr).contains(&format!("another process (pid {})", child.id())), "{d}");
    check_every_level(&fx, "tex", &ps, o, r, tile);
    let err = std::fs::read_to_string(fx.path("incoming/rejected/bad.error.txt")).unwrap();
    assert!(err.contains("bad.json") && err.contains("empty or inverted along x"), "{err}");
    assert!(fx.path("incoming/rejected/bad.raw").exists());
    for n in 0..ps.len() {
        assert!(fx.path(&format!("incoming/done/p{n}.json")).exists(), "p{n} moved to done/");
    }
    assert!(fx.path("incoming/done/p1.raw").exists() && fx.path("incoming/done/p0.png").exists());
    // The same sidecar again, byte for byte (a crash after the patch was kept): taken once.
    std::fs::copy(fx.path("incoming/done/p1.json"), fx.path("incoming/p1.json")).unwrap();
    std::fs::copy(fx.path("incoming/done/p1.raw"), fx.path("incoming/p1.raw")).unwrap();
    let start = std::time::Instant::now();
    while fx.path("incoming/p1.json").exists() {
        assert!(start.elapsed() < Duration::from_secs(30), "the watcher moves it");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(status(fx.dir.path(), "tex")["patches"], ps.len());
    let kill = std::process::Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    assert!(kill.success());
    let st = child.wait().unwrap();
    let log = std::fs::read_to_string(fx.path("watch.log")).unwrap();
    assert!(st.success(), "{log}");
    assert!(log.contains("p1.json: already added"), "{log}");
    // Its lock is gone with it.
    let (out, d) = exec(fx.dir.path(), CLIPTEX, &["grow", "add", "tex", "extra.json"]);
    assert!(out.status.success(), "{d}");
}
