//! Names in shared directories: the mapping, lock file and control socket of a service, planted,
//! squatted or taken by someone else before it starts.

use super::service::{fails, is_root, mkfifo, place, Service, CLIPMAPD, HASH};
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::Path;

fn victim(dir: &Path) -> std::path::PathBuf {
    let v = dir.join("victim");
    std::fs::write(&v, "precious contents\n").unwrap();
    std::fs::set_permissions(&v, std::fs::Permissions::from_mode(0o600)).unwrap();
    v
}

fn args(place: &[String]) -> Vec<&str> {
    HASH.iter().copied().chain(place.iter().map(String::as_str)).collect()
}

fn untouched(v: &Path) {
    assert_eq!(std::fs::read_to_string(v).unwrap(), "precious contents\n", "the victim file changed");
    assert_eq!(std::fs::metadata(v).unwrap().permissions().mode() & 0o777, 0o600);
}

#[test]
fn a_symlink_planted_at_the_lock_name_is_refused_and_its_target_untouched() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let v = victim(d);
    std::os::unix::fs::symlink(&v, d.join("clipmap-n.lock")).unwrap();
    let p = place(d, "n");
    fails(d, CLIPMAPD, &args(&p), 2, &["clipmap-n.lock", "a symbolic link owned by uid"]);
    untouched(&v);
    assert!(d.join("clipmap-n.lock").symlink_metadata().unwrap().file_type().is_symlink(), "the link is left alone");
    assert!(!d.join("clipmap-n.map").exists());
}

#[test]
fn a_symlink_planted_at_the_mapping_name_is_neither_followed_nor_replaced() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let v = victim(d);
    std::os::unix::fs::symlink(&v, d.join("clipmap-n.map")).unwrap();
    let p = place(d, "n");
    fails(d, CLIPMAPD, &args(&p), 2, &["clipmap-n.map", "a symbolic link owned by uid"]);
    untouched(&v);
    assert!(d.join("clipmap-n.map").symlink_metadata().unwrap().file_type().is_symlink());
    let left: Vec<_> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    assert!(!left.iter().any(|n| n.starts_with(".clipmap-")), "no temporary mapping left: {left:?}");
}

#[test]
fn a_fifo_planted_at_the_lock_name_is_refused_without_hanging() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    mkfifo(&d.join("clipmap-n.lock"));
    let p = place(d, "n");
    fails(d, CLIPMAPD, &args(&p), 2, &["clipmap-n.lock", "a FIFO"]);
}

#[test]
fn a_lock_file_of_another_user_is_refused_naming_its_owner() {
    if !is_root() {
        eprintln!("skipped: making a file of another user needs root");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let lock = d.join("clipmap-n.lock");
    std::fs::write(&lock, "").unwrap();
    std::os::unix::fs::chown(&lock, Some(65534), Some(65534)).unwrap();
    let p = place(d, "n");
    fails(d, CLIPMAPD, &args(&p), 2, &["clipmap-n.lock", "owned by uid 65534", "not by this service's user"]);
    assert_eq!(std::fs::metadata(&lock).unwrap().uid(), 65534);
}

#[test]
fn a_squatter_holding_the_lock_is_named_as_such_not_given_an_invented_pid() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let lock = d.join("clipmap-n.lock");
    std::fs::write(&lock, "squat").unwrap();
    let f = std::fs::OpenOptions::new().read(true).write(true).open(&lock).unwrap();
    f.lock().unwrap();
    let p = place(d, "n");
    let err = fails(d, CLIPMAPD, &args(&p), 2, &["clipmap-n.lock", "not a running service", "`squat`"]);
    assert!(!err.contains("process 0"), "{err}");
    assert_eq!(std::fs::read_to_string(&lock).unwrap(), "squat", "the squatter's file is not rewritten");
}

#[test]
fn a_squatter_listening_on_the_socket_name_is_named_and_left_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let sock = d.join("clipmap-n.sock");
    let _squatter = std::os::unix::net::UnixListener::bind(&sock).unwrap();
    let p = place(d, "n");
    fails(d, CLIPMAPD, &args(&p), 2, &["clipmap-n.sock", "another process accepts connections"]);
    assert!(sock.exists(), "the squatter's socket is left in place");
    assert!(!d.join("clipmap-n.map").exists(), "the failed start unpublished its own mapping");
}

#[test]
fn a_regular_file_at_the_socket_name_is_refused_and_untouched() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let sock = d.join("clipmap-n.sock");
    std::fs::write(&sock, "precious contents\n").unwrap();
    std::fs::set_permissions(&sock, std::fs::Permissions::from_mode(0o600)).unwrap();
    let p = place(d, "n");
    fails(d, CLIPMAPD, &args(&p), 2, &["clipmap-n.sock", "a regular file owned by uid", "not a socket"]);
    untouched(&sock);
}

#[test]
fn second_starts_on_the_same_name_or_socket_never_unpublish_the_running_service() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let first = Service::start(d, "one", &HASH, &[]);
    let map = d.join("clipmap-one.map");
    let ino = std::fs::metadata(&map).unwrap().ino();
    // The same name: refused, naming the live service.
    let p = place(d, "one");
    let mut same_name = args(&p);
    let other_sock = d.join("other.sock");
    let i = same_name.iter().position(|a| *a == "--socket").unwrap();
    same_name[i + 1] = other_sock.to_str().unwrap();
    let pid = first.child.id().to_string();
    fails(d, CLIPMAPD, &same_name, 2, &["already publishes `one`", &format!("process {pid}")]);
    // Another name on the same socket: refused.
    let mut same_socket: Vec<String> = place(d, "two");
    let j = same_socket.iter().position(|a| a == "--socket").unwrap();
    same_socket[j + 1] = first.socket.to_str().unwrap().to_string();
    let a2 = args(&same_socket);
    fails(d, CLIPMAPD, &a2, 2, &["another process accepts connections"]);
    assert!(first.alive(), "the first service still answers");
    assert_eq!(std::fs::metadata(&map).unwrap().ino(), ino, "its mapping is still the one published");
    assert!(d.join("clipmap-one.lock").exists());
    assert!(!d.join("clipmap-two.map").exists() && !other_sock.exists());
}

#[test]
fn shm_mode_gives_exactly_the_permissions_asked_whatever_the_umask() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    // The request mapping follows --shm-mode unless --request-mode says otherwise: 640 with
    // request mode 660 lets the group request centres without being able to write texels.
    for (mode, req, want, want_req) in [
        ("640", None, 0o640, 0o640),
        ("660", None, 0o660, 0o660),
        ("600", None, 0o600, 0o600),
        ("640", Some("660"), 0o640, 0o660),
    ] {
        let name = format!("m{mode}{}", req.unwrap_or(""));
        let mut args = vec!["--shm-mode", mode];
        args.extend(req.map(|r| ["--request-mode", r]).iter().flatten());
        let s = Service::spawn(d, &name, &HASH, &args, "umask 077;");
        s.wait_ready();
        for (f, want) in [
            (format!("clipmap-{name}.map"), want),
            (format!("clipmap-{name}.lock"), want),
            (format!("clipmap-{name}.req"), want_req),
        ] {
            let m = std::fs::metadata(d.join(&f)).unwrap().permissions().mode() & 0o777;
            assert_eq!(m, want, "{f} with --shm-mode {mode} --request-mode {req:?} under umask 077: {m:o}");
        }
        let sock = std::fs::metadata(&s.socket).unwrap().permissions().mode() & 0o777;
        assert_eq!(sock, 0o600, "the control socket stays owner-only");
    }
}

#[test]
fn a_group_member_writing_extreme_requests_cannot_crash_the_service() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let s = Service::start(d, "g", &HASH, &["--shm-mode", "660"]);
    let client = clipmap::shm::Client::attach(d, "g").expect("attach");
    let t0 = s.stats()["engine"]["ticks"].as_u64().unwrap_or(0);
    for (centre, velocity) in [
        ([i64::MIN, i64::MAX], [f64::MAX, -f64::MAX]),
        ([i64::MAX, i64::MIN], [f64::NAN, f64::INFINITY]),
        ([-1, 1 << 40], [1e300, -1e300]),
        ([0, 0], [0.0, 0.0]),
    ] {
        client.request_centre(centre, velocity);
        s.wait_ticks(2); // a whole tick with that request
        assert!(
            s.alive(),
            "the service died on a request of centre {centre:?}, velocity {velocity:?}:\n{}",
            std::fs::read_to_string(&s.err).unwrap_or_default()
        );
    }
    let t1 = s.stats()["engine"]["ticks"].as_u64().unwrap_or(0);
    assert!(t1 > t0, "the service keeps ticking ({t0} -> {t1})");
}

#[test]
fn a_hard_link_planted_at_the_lock_name_is_refused_and_the_linked_file_untouched() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let v = victim(d);
    std::fs::hard_link(&v, d.join("clipmap-n.lock")).unwrap();
    let p = place(d, "n");
    fails(d, CLIPMAPD, &args(&p), 2, &["clipmap-n.lock", "2 hard links", "remove it or choose another --name"]);
    untouched(&v);
    assert_eq!(std::fs::metadata(&v).unwrap().nlink(), 2, "the link is left alone");
    assert!(!d.join("clipmap-n.map").exists() && !d.join("clipmap-n.req").exists());
}

#[test]
fn a_second_start_after_the_lock_file_was_deleted_leaves_the_running_service_published() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let first = Service::start(d, "one", &HASH, &[]);
    let (map, req, lock) = (d.join("clipmap-one.map"), d.join("clipmap-one.req"), d.join("clipmap-one.lock"));
    let ino = |p: &Path| std::fs::metadata(p).unwrap().ino();
    let (map_ino, req_ino) = (ino(&map), ino(&req));
    let generation = clipmap::shm::Client::attach(d, "one").unwrap().generation;
    std::fs::remove_file(&lock).unwrap();
    // The same name and the same socket: the new lock file proves nothing (the running service
    // holds its lock on the removed file), its mapping does.
    let p = place(d, "one");
    let pid = first.child.id().to_string();
    fails(d, CLIPMAPD, &args(&p), 2, &["already publishes `one`", &format!("process {pid}")]);
    assert!(first.alive(), "the first service still answers");
    assert_eq!((ino(&map), ino(&req)), (map_ino, req_ino), "its mapping and request mapping are the ones published");
    assert!(!lock.exists(), "the failed start removed the lock file it made, and only that");
    let c = clipmap::shm::Client::attach(d, "one").expect("readers still find the running service");
    assert_eq!(c.generation, generation);
    assert!(c.can_request());
    let left: Vec<_> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    assert!(!left.iter().any(|n| n.starts_with(".clipmap")), "no temporary left: {left:?}");
}

#[test]
fn a_request_mapping_truncated_by_a_group_member_does_not_kill_the_service() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let s = Service::start(d, "t", &HASH, &["--shm-mode", "640", "--request-mode", "660"]);
    let req = d.join("clipmap-t.req");
    let f = std::fs::OpenOptions::new().write(true).open(&req).unwrap();
    f.set_len(0).unwrap();
    // Reported (once) within a few ticks; the service keeps ticking.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    let mut stats = s.stats();
    while stats["request_faults"].as_u64() != Some(1) && std::time::Instant::now() < deadline {
        assert!(s.alive(), "the service died: {}", std::fs::read_to_string(&s.err).unwrap_or_default());
        std::thread::yield_now();
        stats = s.stats();
    }
    assert_eq!(stats["request_faults"], 1, "{stats}");
    let why = stats["request_fault"].as_str().unwrap_or_default().to_string();
    assert!(why.contains("clipmap-t.req") && why.contains("0 bytes, expected 4096"), "{why}");
    let t0 = stats["engine"]["ticks"].as_u64().unwrap();
    while s.stats()["engine"]["ticks"].as_u64().unwrap_or(0) < t0 + 10 && std::time::Instant::now() < deadline {
        std::thread::yield_now();
    }
    let after = s.stats();
    assert!(after["engine"]["ticks"].as_u64().unwrap() >= t0 + 10, "the service keeps ticking: {after}");
    assert_eq!(after["request_faults"], 1, "reported once, not every tick");
    assert!(s.alive());
    let log = std::fs::read_to_string(&s.err).unwrap_or_default();
    assert_eq!(log.matches("clipmap-t.req: 0 bytes").count(), 1, "one warning in the log:\n{log}");
}
