//! Views with grids of their own (docs/VIEWS.md, "Views far apart"; docs/SHM.md, "A view with
//! grids of its own"): a view that flies far from `main` gets a clipmap and a mapping of its own
//! (`--view NAME:WEIGHT:own`, `VIEW ADD NAME [WEIGHT] own`), readers find it by name in the
//! service's mapping and follow it there, it shows its finest level where a view sharing the
//! primary's grids cannot, and its mapping goes when it is removed.

use crate::clipmapd::{c_reader, counts, json_reply, python_reader, rust_reader, Service};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn view<'a>(stats: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    stats["views"].as_array().unwrap().iter().find(|v| v["name"] == name).unwrap_or_else(|| panic!("{name}: {stats}"))
}

#[test]
fn a_view_with_grids_of_its_own_shows_level_0_far_from_main_is_read_by_name_and_its_mapping_goes_with_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "vo", &["--view", "far:2:own", "--view", "shared"]);
    // Both far from main (the texture's centre), at the same place.
    for v in ["far", "shared"] {
        let r = svc.ask(&format!("VIEW CENTRE {v} 3000 60000"));
        assert!(r.starts_with(&format!("OK view {v} centre 3000 60000")), "{r}");
    }
    assert!(d.join("clipmap-vo@far.map").is_file() && d.join("clipmap-vo@far.req").is_file());
    let t = Instant::now();
    let stats = loop {
        let stats = json_reply(&svc.ask("STATS"));
        if view(&stats, "far")["min_lod"] == 0.0 && view(&stats, "far")["centre"] == serde_json::json!([3000, 60000]) {
            break stats;
        }
        assert!(t.elapsed() < Duration::from_secs(20), "far never showed level 0: {stats}\n{}", svc.dump());
        std::thread::sleep(Duration::from_millis(50));
    };
    let (far, shared) = (view(&stats, "far"), view(&stats, "shared"));
    assert_eq!((far["grids"].as_str(), shared["grids"].as_str()), (Some("own"), Some("shared")), "{stats}");
    assert_eq!(far["weight"], 2.0);
    assert_eq!(shared["shared_reads"], 0, "{shared}");
    // The shared grids hold main's window: a view that far away shows coarse levels only.
    assert!(shared["min_lod"].as_f64().unwrap() >= 3.0, "{stats}");
    assert!(far["resident_levels"].as_array().unwrap().contains(&0.into()), "{far}");
    // A reader finds it by name and reads it, every texel checked.
    let out = rust_reader(d, "vo", &["--view", "far", "--reads", "3000", "--block", "5"]).output().unwrap();
    let (passed, failed) = counts(&out, "far");
    assert!(out.status.success() && failed == 0 && passed > 1000, "{passed} {failed}\n{out:?}");
    let line: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&out.stdout).lines().next().unwrap()).unwrap();
    assert_eq!(line["view"], "far", "{line}");
    // The C and Python readers find it in the service's mapping and follow it to its own.
    let map = d.join("clipmap-vo.map");
    let mut c = Command::new(c_reader(d));
    c.stdout(Stdio::piped()).stderr(Stdio::piped());
    for (what, mut cmd) in [("c", c), ("python", python_reader())] {
        let out = cmd.arg(&map).args(["1000000000000", "5", "1", "--view", "far"]).output().unwrap();
        let (passed, failed) = counts(&out, what);
        assert!(out.status.success() && failed == 0 && passed > 1000, "{what}: {passed} {failed}\n{out:?}");
    }
    // Driven by its reader, it moves (its own mapping's request, not main's).
    let before = json_reply(&svc.ask("STATS"))["centre"].clone();
    let out =
        rust_reader(d, "vo", &["--view", "far", "--reads", "1000000000", "--seconds", "1", "--drive", "--seed", "3"])
            .output()
            .unwrap();
    let (_, failed) = counts(&out, "far, driven");
    assert!(out.status.success() && failed == 0, "{out:?}");
    let stats = json_reply(&svc.ask("STATS"));
    assert_ne!(view(&stats, "far")["centre"], serde_json::json!([3000, 60000]), "{stats}");
    assert_eq!(stats["centre"], before, "main did not move: {stats}");
    // On the socket: added with grids of its own, listed, removed with its mapping.
    let r = svc.ask("VIEW ADD sensor 1 own");
    assert!(r.starts_with("OK view sensor added, weight 1, grids of its own"), "{r}");
    assert!(d.join("clipmap-vo@sensor.map").is_file());
    // Added where main is, long after main settled: the tiles main's grids hold (its pyramid's
    // 27 at least) are taken from them, not read from the source again.
    let t = Instant::now();
    loop {
        let stats = json_reply(&svc.ask("STATS"));
        let sensor = view(&stats, "sensor");
        if sensor["min_lod"] == 0.0 {
            assert!(sensor["shared_reads"].as_u64().unwrap() >= 27, "{sensor}");
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(20), "sensor never showed level 0: {stats}");
        std::thread::sleep(Duration::from_millis(20));
    }
    let views = json_reply(&svc.ask("VIEWS"));
    let names: Vec<&str> = views.as_array().unwrap().iter().map(|v| v["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["main", "far", "shared", "sensor"], "{views}");
    assert!(svc.ask("VIEW REMOVE sensor").starts_with("OK view sensor removed"));
    assert!(!d.join("clipmap-vo@sensor.map").exists() && !d.join("clipmap-vo@sensor.req").exists());
    let gone = rust_reader(d, "vo", &["--view", "sensor", "--reads", "10"]).output().unwrap();
    assert_eq!(gone.status.code(), Some(2), "{gone:?}");
    assert!(String::from_utf8_lossy(&gone.stderr).contains("no view `sensor`"), "{gone:?}");
    // Names: `main` and taken names are refused with grids of their own as without.
    assert!(svc.ask("VIEW ADD main own").contains("the primary view's own"));
    assert!(svc.ask("VIEW ADD far own").contains("exists already"));
}

#[test]
fn a_service_name_with_an_at_sign_is_refused_it_is_kept_for_views_own_mappings() {
    let dir = tempfile::tempdir().unwrap();
    let out = std::process::Command::new(crate::clipmapd::CLIPMAPD)
        .args(["--source", "hash", "--size", "4096", "--clip", "256", "--tile", "64", "--name", "a@b", "--shm-dir"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(!out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("`@` is kept for the mappings of views"), "{out:?}");
}

#[test]
fn the_own_mappings_a_killed_service_left_go_at_the_next_start_and_command_line_ones_come_back() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut svc = Service::start(d, "vk2", &["--view", "tower:own"]);
    let r = svc.ask("VIEW ADD sensor 1 own");
    assert!(r.starts_with("OK view sensor added"), "{r}");
    let files = |view: &str| ["map", "req", "lock"].map(|e| d.join(format!("clipmap-vk2@{view}.{e}")));
    assert!(files("sensor").iter().chain(&files("tower")).all(|f| f.is_file()));
    // Something that only looks like one is not ours to remove.
    std::fs::create_dir(d.join("clipmap-vk2@dir.lock")).unwrap();
    svc.child.kill().unwrap();
    svc.child.wait().unwrap();
    assert!(files("sensor").iter().all(|f| f.is_file()), "SIGKILL leaves them");
    let svc = Service::start(d, "vk2", &["--view", "tower:own"]);
    assert!(files("sensor").iter().all(|f| !f.exists()), "the socket's view's files are gone\n{}", svc.dump());
    assert!(files("tower").iter().all(|f| f.is_file()), "the command line's view is back");
    assert!(d.join("clipmap-vk2@dir.lock").is_dir());
    assert!(svc.dump().contains("removed the own mapping a stopped service left for view sensor"), "{}", svc.dump());
    let out = rust_reader(d, "vk2", &["--view", "tower", "--reads", "2000"]).output().unwrap();
    let (passed, failed) = counts(&out, "tower");
    assert!(out.status.success() && failed == 0 && passed > 500, "{passed} {failed}\n{out:?}");
}

/// The fault: `CENTRE` and `VIEW CENTRE` echoed the centre as asked while every snapshot
/// published it bounded to -2^40..=2^40 (docs/SHM.md, "Centres"). The reply must say the centre
/// that will be published, for `main`, a view in the shared grids and one with grids of its own.
#[test]
fn centre_replies_echo_an_unclamped_centre() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "vc", &["--view", "left", "--view", "far:own"]);
    let far = 1i64 << 40;
    assert_eq!(svc.ask("CENTRE 5000000000000 -5000000000000"), format!("OK centre {far} -{far}"));
    for v in ["left", "far"] {
        assert_eq!(svc.ask(&format!("VIEW CENTRE {v} -5000000000000 7")), format!("OK view {v} centre -{far} 7"),);
    }
    assert_eq!(svc.ask("VIEW CENTRE main 3 9223372036854775807"), format!("OK view main centre 3 {far}"));
    // What each snapshot publishes.
    for (v, want) in [("main", [3, far]), ("left", [-far, 7]), ("far", [-far, 7])] {
        let c = clipmap::shm::Client::attach_view(d, "vc", v).unwrap();
        let t = Instant::now();
        while c.try_snapshot().map(|s| s.centre).ok() != Some(want) {
            assert!(t.elapsed() < Duration::from_secs(20), "{v}: {:?}, expected {want:?}", c.try_snapshot());
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

/// The fault: at a stop the service marked its views' own mappings closed before its own, so a
/// reader that saw its view's mapping closed and then read the service's mapping (as the
/// contract says) found it open and the view's record live, and reported the stop as a removal.
/// The rule (docs/SHM.md, "A view with grids of its own"): when an own mapping says closed, the
/// service's mapping already says closed (a stop), or the view's record is already free (`VIEW
/// REMOVE`).
#[test]
fn own_view_closed_before_the_service_reads_a_stop_as_a_removal() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svc = Service::start(d, "vs", &["--view", "a:own", "--view", "b:own", "--view", "c:own"]);
    let service = clipmap::shm::Client::attach(d, "vs").unwrap();
    // Waits in this thread, spinning, for `own` to say closed while `line` is sent on the socket
    // from another; returns what the service's mapping says right then.
    let closing = |own: &clipmap::shm::Client, line: &'static str| {
        let socket = svc.socket.clone();
        let asked = std::thread::spawn(move || crate::clipmapd::ask(&socket, line));
        let t = Instant::now();
        while !own.closed() {
            assert!(t.elapsed() < Duration::from_secs(20), "{line}: the own mapping never said closed");
            std::hint::spin_loop();
        }
        let seen = (service.closed(), service.view_names().unwrap());
        let _ = asked.join();
        seen
    };
    let c = clipmap::shm::Client::attach_view(d, "vs", "c").unwrap();
    let (closed, views) = closing(&c, "VIEW REMOVE c");
    assert!(!closed && !views.contains(&"c".to_string()), "VIEW REMOVE: the record is free first: {views:?}");
    let a = clipmap::shm::Client::attach_view(d, "vs", "a").unwrap();
    let (closed, views) = closing(&a, "SHUTDOWN");
    assert!(closed, "a stop: the service's mapping says closed first ({views:?})");
}

/// The fault: nothing tied a view's own mapping `NAME@VIEW.map` to a start of the service, so a
/// reader of a killed service's mapping, looking up a view, bound to the next start's own mapping
/// of that name. It carries its service's generation now, and a reader checks it.
#[test]
fn own_mapping_of_another_start_is_taken_for_this_ones() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut svc = Service::start(d, "vg", &["--view", "tower:own"]);
    let old = clipmap::shm::Client::attach(d, "vg").unwrap();
    let own = clipmap::shm::Client::attach_view(d, "vg", "tower").unwrap();
    assert_eq!(own.generation, old.generation, "the own mapping carries the service's generation");
    svc.child.kill().unwrap();
    svc.child.wait().unwrap();
    let _svc = Service::start(d, "vg", &["--view", "tower:own"]);
    let new = clipmap::shm::Client::attach(d, "vg").unwrap();
    assert_ne!(new.generation, old.generation);
    let mut stale = old;
    let err = stale.bind_view("tower").expect_err("the killed start's mapping must not bind to the new own mapping");
    assert!(err.to_string().contains("belongs to another start of the service"), "{err}");
    let mut fresh = new;
    fresh.bind_view("tower").unwrap();
    assert_eq!(fresh.generation, clipmap::shm::Client::attach(d, "vg").unwrap().generation);
}
