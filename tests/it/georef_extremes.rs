//! Georeferencing at the extremes (docs/GEOREF.md): centres asked for in longitude / latitude and
//! map coordinates through the request mapping, read by `clipmapd` and shown by the Rust, C and
//! Python readers.

use crate::clipmapd::{c_reader, json_reply, python_reader, Service};
use clipmap::georef::Georef;
use clipmap::shm::{Client, RequestPosition};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

/// `clipmapd --source hash` of `size` texels a side georeferenced as the Web Mercator square.
fn mercator_service(d: &Path, name: &str, size: u64, extra: &[&str]) -> Service {
    let size = size.to_string();
    let source = ["--source", "hash", "--size", &size, "--clip", "256", "--tile", "64", "--georef", "web-mercator"];
    let s = Service::spawn_with(d, name, &source, extra);
    s.wait_ready();
    s
}

/// Waits until `STATS` satisfies `done`; returns it.
fn stats_until(svc: &Service, what: &str, done: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let stats = json_reply(&svc.ask("STATS"));
        if done(&stats) {
            return stats;
        }
        assert!(Instant::now() < deadline, "{what}: not within 20 s: {stats}\n{}", svc.dump());
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn centre_of(v: &serde_json::Value) -> [i64; 2] {
    [v[0].as_i64().unwrap_or(i64::MIN), v[1].as_i64().unwrap_or(i64::MIN)]
}

/// The texel `CENTRE LONLAT` would take: the one that holds the point.
fn floor_texel(g: &Georef, ll: [f64; 2]) -> [i64; 2] {
    let [s, t] = g.lonlat_to_texel(0, ll).unwrap();
    [s.floor() as i64, t.floor() as i64]
}

/// docs/SHM.md, "Positions in longitude / latitude or map coordinates": a renderer's request in
/// longitude / latitude or in map coordinates moves the centre to the texel that holds the point
/// (as `CENTRE LONLAT` does); one outside the domain or on a texture without georeferencing is
/// refused, counted and logged, and the centre stays; an older renderer's request (no position
/// record) still reads as texels. The C and Python readers show the request's kind and position.
#[test]
fn a_request_in_lonlat_or_map_coordinates_moves_the_centre_and_a_refused_one_is_counted() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let size = 1u64 << 16;
    let svc = mercator_service(d, "ll", size, &[]);
    let g = Georef::web_mercator_quad(16, 1);
    let client = Client::attach(d, "ll").unwrap();
    let seen = |n: u64| move |s: &serde_json::Value| s["requests_seen"].as_u64() == Some(n);

    let berlin = [13.4, 52.5];
    assert!(client.request_position(RequestPosition::LonLat(berlin), [0.0, 0.0]));
    let stats = stats_until(&svc, "lon/lat request", |s| centre_of(&s["centre"]) == floor_texel(&g, berlin));
    assert_eq!(stats["position_requests"], 1, "{stats}");
    let ll = stats["centre_lonlat"].as_array().unwrap();
    assert!((ll[0].as_f64().unwrap() - 13.4).abs() < 360.0 / size as f64, "{stats}");

    let (c, r) = (d.join("c-reader"), d.join("clipmap-ll.map"));
    let _ = c_reader(d);
    let show = |who: &str| {
        let out = match who {
            "c" => Command::new(&c).arg(&r).arg("--request").output().unwrap(),
            _ => python_reader().arg(&r).arg("--request").output().unwrap(),
        };
        assert!(out.status.success(), "{who}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).trim().to_string()
    };
    for who in ["c", "python"] {
        let line = show(who);
        assert!(line.starts_with("request count 1 centre 0 0 kind lonlat position 13.4"), "{who}: {line}");
        assert!(line.contains(" 52.5"), "{who}: {line}");
    }

    // Map coordinates: the texel whose south-west corner is the point.
    let xy = g.texel_to_map(0, [1000.0, 2000.0]).unwrap();
    assert!(client.request_position(RequestPosition::Map([xy[0] + 1.0, xy[1] + 1.0]), [0.0, 0.0]));
    let stats = stats_until(&svc, "map request", |s| centre_of(&s["centre"]) == [1000, 2000]);
    assert_eq!(stats["position_requests"], 2, "{stats}");
    for who in ["c", "python"] {
        assert!(show(who).contains("kind map position"), "{who}");
    }

    // Refused: beyond Web Mercator's latitudes. Taken (the count), counted, the centre stays.
    assert!(client.request_position(RequestPosition::LonLat([10.0, 86.0]), [0.0, 0.0]));
    let stats = stats_until(&svc, "refused request", seen(3));
    assert_eq!(stats["position_requests_refused"], 1, "{stats}");
    let why = stats["position_request_refused"].as_str().unwrap();
    assert!(why.contains("longitude / latitude (10, 86)") && why.contains("85.05"), "{why}");
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(centre_of(&json_reply(&svc.ask("STATS"))["centre"]), [1000, 2000]);
    assert!(std::fs::read_to_string(&svc.err).unwrap().contains("centre request refused"));

    // Texels again: the position record of an earlier request is not this one's.
    assert!(client.request_centre([300, 400], [0.0, 0.0]));
    stats_until(&svc, "texel request", |s| centre_of(&s["centre"]) == [300, 400]);
    for who in ["c", "python"] {
        assert!(show(who).starts_with("request count 4 centre 300 400 kind texels"), "{who}");
    }

    // A view's request record has its own position record.
    assert!(svc.ask("VIEW ADD left").starts_with("OK"));
    let left = Client::attach_view(d, "ll", "left").unwrap();
    let cape = [18.42, -33.92];
    assert!(left.request_position(RequestPosition::LonLat(cape), [0.0, 0.0]));
    stats_until(&svc, "view request", |s| {
        s["views"]
            .as_array()
            .unwrap()
            .iter()
            .any(|v| v["name"] == "left" && centre_of(&v["centre"]) == floor_texel(&g, cape))
    });
    assert_eq!(centre_of(&json_reply(&svc.ask("STATS"))["centre"]), [300, 400], "main stays");
}

/// A texture without georeferencing refuses a request in longitude / latitude with why.
#[test]
fn a_lonlat_request_on_a_texture_without_georeferencing_is_refused_with_why() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "plain", &[]);
    let client = Client::attach(d, "plain").unwrap();
    let before = centre_of(&json_reply(&svc.ask("STATS"))["centre"]);
    assert!(client.request_position(RequestPosition::LonLat([1.0, 2.0]), [0.0, 0.0]));
    let stats = stats_until(&svc, "refused", |s| s["position_requests_refused"] == 1);
    assert!(stats["position_request_refused"].as_str().unwrap().contains("no georeferencing"), "{stats}");
    assert_eq!(centre_of(&stats["centre"]), before);
}

// ---- Sizes up to 2^30: conversions against brute force, a flight through clipmapd ----

use proptest::prelude::*;

/// Web Mercator's half extent, metres (EPSG:3857).
const HALF: f64 = 20037508.342789244;
/// Web Mercator's latitude limit, degrees.
const MAX_LAT: f64 = 85.05112877980659;

/// WebMercatorQuad at `2^log2` texels a side (256-texel tiles, as a tile service serves it).
fn quad(log2: u32) -> Georef {
    Georef::web_mercator_quad(log2 - 8, 256)
}

/// Brute force in f64, by another formula than the engine's (`ln tan(pi/4 + lat/2)` for its
/// `asinh(tan(lat))`, degrees to texels without the map's metres): the continuous level-0 texel.
fn brute_texel(n: f64, [lon, lat]: [f64; 2]) -> [f64; 2] {
    let y = (std::f64::consts::FRAC_PI_4 + lat.to_radians() / 2.0).tan().ln();
    [(lon + 180.0) / 360.0 * n, (1.0 + y / std::f64::consts::PI) / 2.0 * n]
}

/// Longitudes and latitudes at the extremes: the antimeridian, the prime meridian, the equator and
/// Web Mercator's limits, and a little inside each.
fn extreme_lon() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(-180.0),
        Just(180.0),
        Just(0.0),
        (-1e-6f64..1e-6),
        (179.999f64..=180.0),
        (-180.0f64..=-179.999),
        (-180.0f64..=180.0),
    ]
}

fn extreme_lat() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(0.0),
        Just(MAX_LAT),
        Just(-MAX_LAT),
        (-1e-6f64..1e-6),
        (85.05f64..=MAX_LAT),
        (-MAX_LAT..=-85.05f64),
        (-MAX_LAT..=MAX_LAT),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// docs/GEOREF.md, "Sizes up to 2^30": at 2^26, 2^28 and 2^30 texels a side, the texel of a
    /// longitude / latitude at the extremes equals the brute force's (f64, another formula) to
    /// 1e-6 texel along s and 1e-4 along t (the latitude's formula is ill-conditioned near the
    /// limits), and the round trip texel -> lon/lat -> texel drifts by at most 1e-3 texel
    /// (lon/lat -> texel -> lon/lat likewise, measured in texels).
    #[test]
    fn lonlat_to_texel_matches_brute_force_and_round_trips_within_a_thousandth_of_a_texel(
        log2 in prop_oneof![Just(26u32), Just(28), Just(30)],
        lon in extreme_lon(),
        lat in extreme_lat(),
    ) {
        let g = quad(log2);
        let n = (1u64 << log2) as f64;
        let st = g.lonlat_to_texel(0, [lon, lat]).unwrap();
        let want = brute_texel(n, [lon, lat]);
        prop_assert!((st[0] - want[0]).abs() <= 1e-6, "s {} against {}", st[0], want[0]);
        prop_assert!((st[1] - want[1]).abs() <= 1e-4, "t {} against {}", st[1], want[1]);
        let ll = g.texel_to_lonlat(0, st).unwrap();
        let back = g.lonlat_to_texel(0, ll).unwrap();
        prop_assert!((back[0] - st[0]).abs() <= 1e-3 && (back[1] - st[1]).abs() <= 1e-3, "{st:?} -> {ll:?} -> {back:?}");
        // The same round trip in longitude / latitude, its difference measured in texels.
        let dl = brute_texel(n, ll);
        prop_assert!((dl[0] - want[0]).abs() <= 1e-3 + 1e-6 && (dl[1] - want[1]).abs() <= 1e-3 + 1e-4, "{ll:?}");
    }

    /// Exact rational arithmetic where there is one: a longitude of whole nanodegrees L (lon =
    /// L / 10^9) lies in column floor((L + 180 x 10^9) x N / (360 x 10^9)), computed in integers;
    /// the engine's clip centre (`CENTRE LONLAT`'s floor) is that column, unless the exact position
    /// lies within 1e-6 texel of the column's edge (then either neighbour).
    #[test]
    fn the_column_of_a_longitude_is_the_exact_rational_ones(
        log2 in prop_oneof![Just(26u32), Just(28), Just(30)],
        nano in prop_oneof![
            Just(-180_000_000_000i64), Just(0), Just(179_999_999_999),
            (-180_000_000_000i64..=-179_999_000_000), (179_999_000_000i64..180_000_000_000),
            (-1_000i64..=1_000), (-180_000_000_000i64..180_000_000_000),
        ],
        lat in extreme_lat(),
    ) {
        let g = quad(log2);
        let n = 1i128 << log2;
        let num = (nano as i128 + 180_000_000_000) * n;
        let den = 360_000_000_000i128;
        let exact = num.div_euclid(den);
        let s = g.lonlat_to_texel(0, [nano as f64 / 1e9, lat]).unwrap()[0].floor() as i128;
        let rem = num.rem_euclid(den) as f64 / den as f64;
        let near_edge = !(1e-6..=1.0 - 1e-6).contains(&rem);
        prop_assert!(s == exact || (near_edge && (s - exact).abs() == 1), "column {s}, exact {exact} (fraction {rem})");
    }
}

/// Texel corners at 2^30: the corners of the whole texture and the texels at the prime meridian and
/// the equator are where the WebMercatorQuad definition puts them, exactly in metres as integers
/// of the texel size allow (to 1e-6 m), and their longitudes / latitudes are the exact ones.
#[test]
fn at_2_30_the_texels_at_the_extremes_are_where_web_mercator_quad_puts_them() {
    let n = 1u64 << 30;
    let g = quad(30);
    let px = 2.0 * HALF / n as f64;
    for (st, xy) in [
        ([0.0, 0.0], [-HALF, -HALF]),
        ([n as f64, n as f64], [HALF, HALF]),
        ([(n / 2) as f64, (n / 2) as f64], [0.0, 0.0]),
        ([(n - 1) as f64, 1.0], [HALF - px, -HALF + px]),
    ] {
        let m = g.texel_to_map(0, st).unwrap();
        assert!((m[0] - xy[0]).abs() <= 1e-6 && (m[1] - xy[1]).abs() <= 1e-6, "{st:?}: {m:?} against {xy:?}");
    }
    let ll = |st| g.texel_to_lonlat(0, st).unwrap();
    assert!((ll([0.0, 0.0])[0] + 180.0).abs() < 1e-12 && (ll([0.0, 0.0])[1] + MAX_LAT).abs() < 1e-9);
    assert!(
        (ll([n as f64, n as f64])[0] - 180.0).abs() < 1e-12 && (ll([n as f64, n as f64])[1] - MAX_LAT).abs() < 1e-9
    );
    assert_eq!(ll([(n / 2) as f64, (n / 2) as f64]), [0.0, 0.0]);
    // Beyond the domain: refused, naming it.
    let e = g.lonlat_to_texel(0, [0.0, 85.06]).unwrap_err().to_string();
    assert!(e.contains("85.05"), "{e}");
}

/// Every reader's texels of a running 2^30 service: Rust (`clipmap-read`), C and Python, each
/// checking every texel it reads against the hash texture; returns the texels checked.
fn read_with_every_reader(d: &Path, name: &str, creader: &Path, seconds: &str) -> u64 {
    let map = d.join(format!("clipmap-{name}.map"));
    let children = vec![
        (
            "rust",
            crate::clipmapd::rust_reader(d, name, &["--reads", "1000000000000", "--seconds", seconds]).spawn().unwrap(),
        ),
        (
            "c",
            Command::new(creader)
                .arg(&map)
                .args(["1000000000000", "5", seconds])
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap(),
        ),
        ("python", python_reader().arg(&map).args(["1000000000000", "7", seconds]).spawn().unwrap()),
    ];
    let mut total = 0;
    for (who, child) in children {
        let out = child.wait_with_output().unwrap();
        let (passed, failed) = crate::clipmapd::counts(&out, who);
        assert_eq!(failed, 0, "{who}: {failed} wrong texels\n{}", String::from_utf8_lossy(&out.stderr));
        assert!(out.status.success(), "{who}: {:?}\n{}", out.status, String::from_utf8_lossy(&out.stderr));
        assert!(passed > 1000, "{who}: only {passed} texels checked");
        total += passed;
    }
    total
}

/// A flight at 2^30 texels a side (WebMercatorQuad zoom 22 at 256-texel tiles) through
/// `clipmapd`: at the origin, at the far corner (asked for in longitude / latitude with
/// `clipmap-read --lonlat`), and flown fast with jumps by a driving reader: the Rust, C and Python
/// readers find every texel right. `cliptex attach` shows the centre in texels and longitude /
/// latitude, equal to `STATS`.
#[test]
fn a_flight_at_2_30_through_clipmapd_reads_every_texel_right_at_the_origin_and_the_far_corner() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let n = 1u64 << 30;
    let svc = mercator_service(d, "big", n, &["--budget-ms", "4"]);
    let g = Georef::web_mercator_quad(30, 1);
    let creader = c_reader(d);
    let stats = json_reply(&svc.ask("STATS"));
    assert_eq!(stats["engine"]["slots_reassigned_under_published"], 0, "{stats}");

    // The origin.
    assert!(svc.ask("CENTRE 100 100").starts_with("OK centre 100 100"));
    stats_until(&svc, "origin", |s| centre_of(&s["centre"]) == [100, 100]);
    let mut total = read_with_every_reader(d, "big", &creader, "2");

    // The far corner, asked for in longitude / latitude.
    let far = [179.9999999, 85.0511];
    let out = crate::clipmapd::rust_reader(
        d,
        "big",
        &["--lonlat", &format!("{},{}", far[0], far[1]), "--reads", "100000", "--seconds", "20"],
    )
    .output()
    .unwrap();
    let (passed, failed) = crate::clipmapd::counts(&out, "clipmap-read --lonlat");
    assert!(out.status.success() && failed == 0 && passed > 0, "{}", String::from_utf8_lossy(&out.stderr));
    let first: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&out.stdout).lines().next().unwrap()).unwrap();
    let want = floor_texel(&g, far);
    assert!(want[0] > (n - 2) as i64 && want[1] > (n - 2000) as i64, "the far corner: {want:?}");
    assert_eq!(first["lonlat_centre"], serde_json::json!(want), "{first}");
    let stats = stats_until(&svc, "far corner", |s| centre_of(&s["centre"]) == want);
    total += read_with_every_reader(d, "big", &creader, "2");

    // `cliptex attach` shows the centre in texels and in longitude / latitude, as STATS does.
    let attach = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["attach", "big", "--once", "--json", "--shm-dir", d.to_str().unwrap(), "--socket"])
        .arg(d.join("big.sock"))
        .output()
        .unwrap();
    assert!(attach.status.success(), "{}", String::from_utf8_lossy(&attach.stderr));
    let a: serde_json::Value = serde_json::from_slice(&attach.stdout).unwrap();
    assert_eq!(a["centre"], serde_json::json!(want), "{a}");
    for i in 0..2 {
        let (x, y) = (a["centre_lonlat"][i].as_f64().unwrap(), stats["centre_lonlat"][i].as_f64().unwrap());
        assert!((x - y).abs() < 1e-9, "attach {x} against STATS {y}");
    }
    let human = Command::new(env!("CARGO_BIN_EXE_cliptex"))
        .args(["attach", "big", "--once", "--shm-dir", d.to_str().unwrap(), "--socket"])
        .arg(d.join("big.sock"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&human.stdout);
    assert!(text.contains(&format!("centre: {} {} (level-0 texels)  longitude 179.99", want[0], want[1])), "{text}");

    // Flown fast with jumps and reversals around the middle while every reader reads.
    let driver = crate::clipmapd::rust_reader(d, "big", &["--drive", "--reads", "1000000000000", "--seconds", "2"])
        .spawn()
        .unwrap();
    total += read_with_every_reader(d, "big", &creader, "2");
    let out = driver.wait_with_output().unwrap();
    let (_, failed) = crate::clipmapd::counts(&out, "driver");
    assert_eq!(failed, 0, "{}", String::from_utf8_lossy(&out.stderr));
    eprintln!("2^30: {total} texels checked by Rust, C and Python, none wrong");
    let stats = json_reply(&svc.ask("STATS"));
    assert_eq!(stats["engine"]["slots_reassigned_under_published"], 0, "{stats}");
}

/// `cliptex roam --flight lonlat:FROM:TO` flies from one place to another through the texture's
/// georeferencing, at 2^30 texels a side: its first and last frames are centred on the texels
/// that hold the two places. A texture without georeferencing refuses the flight with why.
#[test]
fn roam_flies_a_lonlat_flight_at_2_30_and_refuses_it_without_georeferencing() {
    let dir = tempfile::tempdir().unwrap();
    let (from, to) = ([-179.99, -85.0], [179.99, 85.0]);
    let spec = format!("lonlat:{},{}:{},{}", from[0], from[1], to[0], to[1]);
    let args = |georef: bool| {
        let mut a = vec!["roam", "--source", "hash", "--size", "1073741824", "--clip", "256", "--tile", "64"];
        a.extend(["--flight", spec.as_str(), "--frames", "5", "--wait-for-reads", "--json"]);
        if georef {
            a.extend(["--georef", "web-mercator"]);
        }
        a.iter().map(|s| s.to_string()).collect::<Vec<_>>()
    };
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex")).args(args(true)).current_dir(dir.path()).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let g = Georef::web_mercator_quad(30, 1);
    let frames = r["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 5);
    assert_eq!(centre_of(&frames[0]["centre"]), floor_texel(&g, from), "{}", frames[0]);
    assert_eq!(centre_of(&frames[4]["centre"]), floor_texel(&g, to), "{}", frames[4]);
    assert_eq!(centre_of(&frames[2]["centre"]), floor_texel(&g, [0.0, 0.0]), "half way: {}", frames[2]);
    let out = Command::new(env!("CARGO_BIN_EXE_cliptex")).args(args(false)).current_dir(dir.path()).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--flight lonlat") && err.contains("no georeferencing"), "{err}");
}
