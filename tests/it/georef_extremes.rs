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
