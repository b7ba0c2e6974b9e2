//! A texture that spans 360 degrees of longitude wraps there (docs/SHM.md, "How a region
//! wraps"; docs/GEOREF.md, "The antimeridian"): `clipmapd --source hash --global` serves the
//! hash texture placed on the whole Earth; a flight across the antimeridian is read by the Rust,
//! C and Python readers, every texel the hash texture's at s mod width, and level 0 shows the
//! whole window there as often as away from the seam. A texture not marked global still stops
//! at its edge.

use crate::clipmapd::{c_reader, counts, python_reader, rust_reader, Service};
use clipmap::geom::{contains_wrapped, wrap, Rect};
use clipmap::shm::{Client, ReadError};
use std::path::Path;
use std::time::{Duration, Instant};

const SIZE: u64 = 4096;
const CLIP: u64 = 256;

fn serve(d: &Path, name: &str, global: bool) -> Service {
    let size = SIZE.to_string();
    let clip = CLIP.to_string();
    let mut source = vec!["--source", "hash", "--size", size.as_str(), "--clip", clip.as_str(), "--tile", "64"];
    if global {
        source.push("--global");
    }
    let s = Service::spawn_with(d, name, &source, &[]);
    s.wait_ready();
    s
}

/// The hash texture's texel (level, s, t), as many bytes as a texel has.
fn hash(level: u32, s: u64, t: u64, bpt: usize) -> Vec<u8> {
    let v = clipmap::source::procedural::hash_value(level, s, t).to_le_bytes();
    (0..bpt).map(|i| v[i % 8]).collect()
}

/// Waits until level 0's published region holds the whole window around the snapshot's centre
/// `want` (less the border), s taken modulo the width where the texture wraps.
fn wait_whole(c: &Client, want: [i64; 2], what: &str, svc: &Service) -> clipmap::shm::Snapshot {
    let t0 = Instant::now();
    loop {
        let snap = c.snapshot();
        if snap.centre == want && shows_window(c, &snap) {
            return snap;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "{what}: level 0 never showed the window: {snap:?}\n{}",
            svc.dump()
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Whether level 0 is enabled and its region holds every texel of the window around the
/// snapshot's level-0 centre, less the border (modulo the width where the texture wraps).
fn shows_window(c: &Client, snap: &clipmap::shm::Snapshot) -> bool {
    let l = &snap.levels[0];
    if !l.enabled {
        return false;
    }
    let r = l.rect();
    let half = (CLIP / 2) as i64 - snap.invalid_border as i64;
    let period = c.texel_period(0);
    let [cs, ct] = snap.centre;
    [cs - half, cs + half - 1].iter().all(|&s| contains_wrapped(&r, s, ct, period))
}

#[test]
fn a_flight_across_the_antimeridian_is_read_right_by_every_reader_and_level_0_shows_there_as_elsewhere() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = serve(d, "globe", true);
    let c = Client::attach(d, "globe").unwrap();
    assert!(c.wraps(), "the georef block says it spans 360 degrees");
    assert_eq!(c.georef.as_ref().unwrap().epsg, Some(4326));
    let bpt = c.bytes_per_texel;

    // Every reader checks random blocks of the published regions while the centre flies.
    let map = d.join("clipmap-globe.map");
    let creader = c_reader(d);
    let secs = "6";
    let readers = vec![
        ("rust", rust_reader(d, "globe", &["--reads", "1000000000000", "--seconds", secs]).spawn().unwrap()),
        (
            "c",
            std::process::Command::new(&creader)
                .arg(&map)
                .args(["1000000000000", "7", secs])
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap(),
        ),
        ("python", python_reader().arg(&map).args(["1000000000000", "7", secs]).spawn().unwrap()),
    ];

    // Two flights at the same speed, in longitude as a renderer gives it: across the antimeridian
    // (170 east to 170 west) and across the prime meridian (10 west to 10 east). Each samples how
    // often level 0 shows the whole window around the published centre.
    let fly = |from: f64, what: &str| -> (u64, u64, u64) {
        let (mut shown, mut samples, mut crossing) = (0u64, 0u64, 0u64);
        for i in 0..=160 {
            let mut lon = from + 0.125 * i as f64;
            if lon >= 180.0 {
                lon -= 360.0;
            }
            let reply = svc.ask(&format!("CENTRE LONLAT {lon} 0"));
            assert!(reply.starts_with("OK centre "), "{what}: {reply}");
            let until = Instant::now() + Duration::from_millis(12);
            while Instant::now() < until {
                let snap = c.snapshot();
                if snap.tick > 0 {
                    samples += 1;
                    shown += u64::from(shows_window(&c, &snap));
                    crossing += u64::from(snap.levels[0].enabled && snap.levels[0].valid[2] > SIZE as i64);
                }
                std::thread::sleep(Duration::from_micros(500));
            }
        }
        (shown, samples, crossing)
    };
    let (seam_shown, seam_samples, seam_crossing) = fly(170.0, "across the antimeridian");
    let (away_shown, away_samples, _) = fly(-10.0, "across the prime meridian");
    let seam = seam_shown as f64 / seam_samples as f64;
    let away = away_shown as f64 / away_samples as f64;
    eprintln!("level 0 showed the whole window in {seam:.3} of the snapshots across the antimeridian ({seam_samples}), {away:.3} across the prime meridian ({away_samples}); {seam_crossing} regions ran past the width");
    assert!(seam_crossing > 0, "some regions run past the width at the seam");
    assert!(seam >= away - 0.05 && seam > 0.5, "level 0 shown {seam:.3} at the seam, {away:.3} away from it");

    for (who, child) in readers {
        let out = child.wait_with_output().unwrap();
        let (passed, failed) = counts(&out, who);
        assert!(
            out.status.success() && failed == 0 && passed > 0,
            "{who}: {passed} passed, {failed} failed\n{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }

    // At rest on the antimeridian: every texel of every level's region is the hash texture's at
    // s mod width, read across the seam in one rectangle.
    assert_eq!(svc.ask("CENTRE 0 2048"), "OK centre 0 2048");
    let snap = wait_whole(&c, [0, 2048], "at the antimeridian", &svc);
    let r = snap.levels[0].rect();
    assert!(r.s0 > SIZE as i64 / 2 && r.s1 > SIZE as i64, "level 0's region runs past the width: {r:?}");
    for (k, l) in snap.levels.iter().enumerate().filter(|(_, l)| l.enabled) {
        let r = l.rect();
        let mut buf = vec![0u8; (r.area() as usize) * bpt];
        match c.read_region_in(&snap, k, r, &mut buf) {
            Ok(()) => {}
            Err(ReadError::Stale(_)) => continue,
            Err(e) => panic!("level {k} {r:?}: {e}"),
        }
        let w = c.levels[k].size[0];
        for (i, got) in buf.chunks_exact(bpt).enumerate() {
            let (s, t) = (r.s0 + (i as u64 % r.width()) as i64, r.t0 + (i as u64 / r.width()) as i64);
            assert_eq!(got, hash(k as u32, wrap(s, w), t as u64, bpt).as_slice(), "level {k} texel ({s}, {t})");
        }
        // The same texels named on the other lap (s - width): read modulo the width.
        let west = Rect::new(r.s0 - w as i64, r.t0, r.s1 - w as i64, r.t0 + 1);
        let mut row = vec![0u8; r.width() as usize * bpt];
        if c.read_region_in(&snap, k, west, &mut row).is_ok() {
            assert_eq!(row, buf[..row.len()], "level {k}: a lap away is the same row");
        }
    }
}

#[test]
fn a_texture_not_marked_global_still_stops_at_its_edge() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = serve(d, "flat", false);
    let c = Client::attach(d, "flat").unwrap();
    assert!(!c.wraps() && c.georef.is_none() && c.texel_period(0).is_none());
    assert_eq!(svc.ask("CENTRE 4090 2048"), "OK centre 4090 2048");
    let t0 = Instant::now();
    let snap = loop {
        let snap = c.snapshot();
        if snap.centre == [4090, 2048] && snap.levels[0].enabled && snap.min_lod == 0.0 {
            break snap;
        }
        assert!(t0.elapsed() < Duration::from_secs(20), "never settled: {snap:?}\n{}", svc.dump());
        std::thread::sleep(Duration::from_millis(5));
    };
    let r = snap.levels[0].rect();
    assert_eq!(
        (r.s0, r.s1),
        (SIZE as i64 - CLIP as i64 + snap.invalid_border as i64, SIZE as i64),
        "the window lies against the east edge"
    );
    let mut texel = vec![0u8; c.bytes_per_texel];
    assert!(matches!(
        c.read_region_in(&snap, 0, Rect::new(SIZE as i64, 2048, SIZE as i64 + 1, 2049), &mut texel),
        Err(ReadError::NotValid(0))
    ));
    assert!(matches!(c.read_region_in(&snap, 0, Rect::new(0, 2048, 1, 2049), &mut texel), Err(ReadError::NotValid(0))));
    // The C and Python readers read it as before.
    let map = d.join("clipmap-flat.map");
    let creader = c_reader(d);
    let out = std::process::Command::new(&creader).arg(&map).args(["20000", "3", "2"]).output().unwrap();
    let (p, f) = counts(&out, "c");
    assert!(out.status.success() && f == 0 && p > 0, "{}", String::from_utf8_lossy(&out.stderr));
    let out = python_reader().arg(&map).args(["2000", "3", "2"]).output().unwrap();
    let (p, f) = counts(&out, "python");
    assert!(out.status.success() && f == 0 && p > 0, "{}", String::from_utf8_lossy(&out.stderr));
}

#[test]
fn a_gdal2tiles_pyramid_wraps_at_the_antimeridian_with_gdals_texels_on_both_sides() {
    // The peer's tree of the whole world (zooms 0 to 2, 1024 texels a side at zoom 2), served with
    // a clip size of 256: level 0 (zoom 2) and level 1 (zoom 1) are wider than the window.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gdal = crate::tiles::trees(d);
    let template = std::path::PathBuf::from(format!("xyz:{}/tms/{{z}}/{{x}}/{{-y}}.png", d.display()));
    let served = crate::common::gdal::Served::start(&template, 256, "wrapxyz", d);
    let c = &served.client;
    assert!(c.wraps(), "a WebMercatorQuad pyramid spans 360 degrees");
    let reply = crate::clipmapd::ask(&d.join("wrapxyz.sock"), "CENTRE LONLAT 180 10");
    assert!(reply.starts_with("OK centre "), "{reply}");
    for k in 0..2usize {
        let side = 1024u64 >> k;
        let n = 4u64 >> k;
        let z = 2 - k as u8;
        let t0 = Instant::now();
        let (snap, r) = loop {
            let snap = c.snapshot();
            let st = snap.levels[k];
            if st.enabled && st.valid[2] > side as i64 && snap.min_lod == 0.0 {
                break (snap.clone(), st.rect());
            }
            assert!(t0.elapsed() < Duration::from_secs(30), "level {k} never wrapped: {snap:?}\n{}", served.log());
            std::thread::sleep(Duration::from_millis(5));
        };
        let mut texels = vec![0u8; (r.area() * 4) as usize];
        c.read_region_in(&snap, k, r, &mut texels).unwrap_or_else(|e| panic!("level {k} {r:?}: {e}"));
        for t in r.t0 as u64..r.t1 as u64 {
            for s in r.s0..r.s1 {
                let real = wrap(s, side);
                let tile = &gdal[&(z, (real / 256) as u32, (n - 1 - t / 256) as u32)];
                let i = (((255 - t % 256) * 256 + real % 256) * 4) as usize;
                let at = (((t - r.t0 as u64) * r.width() + (s - r.s0) as u64) * 4) as usize;
                assert_eq!(texels[at..at + 4], tile[i..i + 4], "level {k} texel ({s}, {t}) = ({real}, {t})");
            }
        }
    }
}

/// `cliptex plan --global` counts the wider grids a texture that wraps in longitude takes (each
/// wrapping level's grid as wide as a divisor of its tiles across, so that tiles n - 1 and 0 take
/// distinct slots): its image caches are the bytes `clipmapd --global` maps, and more than the
/// same texture's without the wrap.
#[test]
fn cliptex_plan_global_sizes_the_wider_grids_of_a_wrapping_texture_as_the_service_maps_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // `Service::start`'s texture: hash (RGBA8), 65536, clip 256, tiles of 64; marked global.
    let _svc = crate::clipmapd::Service::start(d, "wrapplan", &["--global"]);
    let mapped = std::fs::metadata(d.join("clipmap-wrapplan.map")).unwrap().len();
    let plan = |global: bool| -> serde_json::Value {
        let mut args = vec!["plan", "--size", "65536", "--clip", "256", "--tile", "64", "--texel-bytes", "4", "--json"];
        if global {
            args.push("--global");
        }
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex")).args(&args).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_slice(&out.stdout).unwrap()
    };
    let (flat, global) = (plan(false), plan(true));
    assert_eq!(global["image_caches"]["bytes"].as_u64(), Some(mapped), "{global}");
    assert!(
        global["image_caches"]["bytes"].as_u64() > flat["image_caches"]["bytes"].as_u64(),
        "the wrap widens grids: {global} against {flat}"
    );
    // Levels 0 to 7 (65536 down to 512 texels, wider than the clip) wrap; level 0's grid is as
    // wide as a divisor of its 1024 tiles across.
    assert_eq!(global["image_caches"]["wrapping_levels"], serde_json::json!([0, 1, 2, 3, 4, 5, 6, 7]), "{global}");
    assert_eq!(flat["image_caches"]["wrapping_levels"], serde_json::json!([]), "{flat}");
    let g0 = global["image_caches"]["level0_grid"][0].as_u64().unwrap();
    assert!(1024 % g0 == 0 && g0 >= flat["image_caches"]["level0_grid"][0].as_u64().unwrap(), "{global}");
    let human = std::process::Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["plan", "--size", "65536", "--clip", "256", "--tile", "64", "--texel-bytes", "4", "--global"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&human.stdout);
    assert!(text.contains("levels 0 to 7 wrap in longitude"), "{text}");
}
