//! Growing textures attacked where patches come in and where the store lives: images cut short,
//! links and FIFOs planted in the watched directory and in the store, sidecars naming files
//! elsewhere, devices and sparse giants, byte counts that would allocate everything, option
//! values without a bound, and a malformed `PATCH DATA` line followed by commands. Every run is
//! bounded; the tools and services that could run away are started under a 4 GiB (or 2 GiB)
//! address-space limit, so a regression fails instead of exhausting the machine.

use super::service::{ask, mkfifo, Service, CLIPMAPD, CLIPTEX, LIMIT};
use crate::common;
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::{Duration, Instant};

/// Runs `prog args` in `dir` under an address-space limit of `gib` GiB, bounded by [`LIMIT`];
/// returns the output, its description, and stdout + stderr.
fn limited(dir: &Path, gib: u64, prog: &str, args: &[&str]) -> (Output, String, String) {
    let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
    let script = format!("ulimit -v {}; exec '{prog}' {}", gib << 20, quoted.join(" "));
    let (out, desc) = common::exec_bounded(dir, "sh", &["-c", &script], &[("RUST_LOG", "warn")], LIMIT);
    let text = String::from_utf8_lossy(&out.stderr).into_owned() + &String::from_utf8_lossy(&out.stdout);
    (out, desc, text)
}

/// Asserts a limited run exits `code` and says every one of `words`; returns what it said.
fn fails_limited(dir: &Path, gib: u64, prog: &str, args: &[&str], code: i32, words: &[&str]) -> String {
    let (out, desc, text) = limited(dir, gib, prog, args);
    assert_eq!(out.status.code(), Some(code), "exit code:\n{desc}");
    for w in words {
        assert!(text.contains(w), "should say `{w}`:\n{desc}");
    }
    text
}

fn encoded(format: image::ImageFormat, w: u32, h: u32) -> Vec<u8> {
    let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 9) as u8, (y * 17) as u8, 200]));
    let mut out = std::io::Cursor::new(Vec::new());
    image::DynamicImage::from(img).write_to(&mut out, format).unwrap();
    out.into_inner()
}

fn png(w: u32, h: u32) -> Vec<u8> {
    encoded(image::ImageFormat::Png, w, h)
}

/// A JPEG without its end marker (EOI): the decoder takes it without a word, filling whatever a
/// cut leaves out with grey.
fn cut_jpeg() -> Vec<u8> {
    let mut j = encoded(image::ImageFormat::Jpeg, 32, 24);
    j.truncate(j.len() - 2);
    j
}

fn sidecar(image: &str) -> String {
    format!(r#"{{"bbox": [0, 0, 32, 24], "time": 1, "rating": 1, "image": "{image}"}}"#)
}

/// A growing texture `tex` in `d` (RGB, 16-texel tiles), and `inc/` beside it.
fn store(d: &Path) -> PathBuf {
    let (o, desc) = super::service::run(
        d,
        CLIPTEX,
        &["grow", "create", "tex", "--origin", "0,0", "--texels-per-unit", "1", "--tile", "16", "--format", "rgb8"],
    );
    assert_eq!(o.status.code(), Some(0), "{desc}");
    std::fs::create_dir(d.join("inc")).unwrap();
    d.join("tex")
}

/// A store with one PNG patch added and rebuilt.
fn store_with_patch(d: &Path) -> PathBuf {
    let tex = store(d);
    std::fs::create_dir(d.join("src")).unwrap();
    std::fs::write(d.join("src/a.png"), png(32, 24)).unwrap();
    std::fs::write(d.join("src/a.json"), sidecar("a.png")).unwrap();
    let (o, desc) = super::service::run(d, CLIPTEX, &["grow", "add", "tex", "src/a.json"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    tex
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A growing service on `tex` watching `inc`, in `d`, under a 4 GiB address-space limit.
fn service(d: &Path, name: &str, extra: &[&str]) -> Service {
    let (tex, inc) = (d.join("tex"), d.join("inc"));
    let mut args = vec!["--incoming", s(&inc)];
    args.extend_from_slice(extra);
    let svc =
        Service::spawn(d, name, &["--growing", s(&tex), "--size", "512", "--clip", "64"], &args, "ulimit -v 4194304;");
    svc.wait_ready();
    svc
}

/// Sends `line` and `bytes` on a fresh connection; the first line of the answer ("" if none
/// within 20 s).
fn send(socket: &Path, line: &str, bytes: &[u8]) -> String {
    let Ok(mut c) = UnixStream::connect(socket) else { return String::new() };
    c.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    let _ = c.write_all(format!("{line}\n").as_bytes());
    let _ = c.write_all(bytes);
    let mut reply = String::new();
    let _ = BufReader::new(c).read_line(&mut reply);
    reply.trim_end().to_string()
}

/// Waits (bounded) until `cond` holds.
fn wait_for(what: &str, mut cond: impl FnMut() -> bool) {
    let t = Instant::now();
    while t.elapsed() < LIMIT {
        if cond() {
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    panic!("{what} did not happen within {LIMIT:?}");
}

fn patches_in(d: &Path) -> u64 {
    let (o, desc) = super::service::run(d, CLIPTEX, &["grow", "status", "tex", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    v["patches"].as_u64().unwrap()
}

// Wrong data --------------------------------------------------------------------------------

#[test]
fn a_jpeg_cut_short_is_refused_on_the_socket_in_the_watched_directory_and_by_grow_add() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store(d);
    // cliptex grow add
    std::fs::write(d.join("cut.jpg"), cut_jpeg()).unwrap();
    std::fs::write(d.join("cut.json"), sidecar("cut.jpg")).unwrap();
    fails_limited(d, 4, CLIPTEX, &["grow", "add", "tex", "cut.json"], 1, &["cut.json", "ends early", "no EOI marker"]);
    // cliptex grow watch
    std::fs::write(d.join("inc/cut.jpg"), cut_jpeg()).unwrap();
    std::fs::write(d.join("inc/cut.json"), sidecar("cut.jpg")).unwrap();
    let (o, desc, _) = limited(d, 4, CLIPTEX, &["grow", "watch", "tex", "inc", "--once"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    let why = std::fs::read_to_string(d.join("inc/rejected/cut.error.txt")).unwrap();
    assert!(why.contains("ends early"), "{why}");
    assert_eq!(patches_in(d), 0, "nothing was taken");
    // PATCH DATA on the socket
    let svc = service(d, "cutjpeg", &[]);
    let j = cut_jpeg();
    let reply = send(&svc.socket, &format!("PATCH DATA {} {}", j.len(), sidecar("x.jpg")), &j);
    assert!(reply.starts_with("ERR PATCH") && reply.contains("ends early"), "{reply}");
    let whole = encoded(image::ImageFormat::Jpeg, 32, 24);
    let reply = send(&svc.socket, &format!("PATCH DATA {} {}", whole.len(), sidecar("x.jpg")), &whole);
    assert!(reply.starts_with("OK patch 1"), "a whole JPEG is still taken: {reply}");
}

// Files outside where they belong -------------------------------------------------------------

#[test]
fn an_error_file_planted_as_a_symlink_is_replaced_never_written_through() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store(d);
    let victim = d.join("victim.txt");
    std::fs::write(&victim, "precious\n").unwrap();
    std::fs::create_dir(d.join("inc/rejected")).unwrap();
    std::os::unix::fs::symlink(&victim, d.join("inc/rejected/bad.error.txt")).unwrap();
    std::fs::write(d.join("inc/bad.json"), "{ not a sidecar").unwrap();
    let (o, desc, _) = limited(d, 4, CLIPTEX, &["grow", "watch", "tex", "inc", "--once"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious\n", "the link's target is untouched");
    let err = d.join("inc/rejected/bad.error.txt");
    assert!(std::fs::symlink_metadata(&err).unwrap().is_file(), "the link was replaced by the error file");
    assert!(std::fs::read_to_string(&err).unwrap().contains("not valid"));
    assert!(d.join("inc/rejected/bad.json").exists());
}

#[test]
fn a_done_directory_planted_as_a_symlink_is_refused_and_nothing_moves_through_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store(d);
    let elsewhere = d.join("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    std::os::unix::fs::symlink(&elsewhere, d.join("inc/done")).unwrap();
    std::fs::write(d.join("inc/a.png"), png(32, 24)).unwrap();
    std::fs::write(d.join("inc/a.json"), sidecar("a.png")).unwrap();
    fails_limited(d, 4, CLIPTEX, &["grow", "watch", "tex", "inc", "--once"], 2, &["inc/done", "symbolic link"]);
    assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0, "nothing was moved through the link");
    assert!(d.join("inc/a.json").exists() && d.join("inc/a.png").exists(), "the patch stays where it was");
    // Once the link is gone, the same sidecar is only moved (it was kept before the move failed).
    std::fs::remove_file(d.join("inc/done")).unwrap();
    let (o, desc, _) = limited(d, 4, CLIPTEX, &["grow", "watch", "tex", "inc", "--once"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    assert!(d.join("inc/done/a.json").exists() && d.join("inc/done/a.png").exists(), "{desc}");
    assert_eq!(patches_in(d), 1, "taken once");
}

#[test]
fn a_sidecar_image_with_dotdot_or_an_absolute_path_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store(d);
    let secret = d.join("secret.png");
    std::fs::write(&secret, png(32, 24)).unwrap();
    std::fs::write(d.join("inc/up.json"), sidecar("../secret.png")).unwrap();
    std::fs::write(d.join("inc/abs.json"), sidecar(s(&secret))).unwrap();
    std::os::unix::fs::symlink(&secret, d.join("inc/link.png")).unwrap();
    std::fs::write(d.join("inc/link.json"), sidecar("link.png")).unwrap();
    let (o, desc, _) = limited(d, 4, CLIPTEX, &["grow", "watch", "tex", "inc", "--once"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    for (name, says) in [("up", "not a path inside"), ("abs", "not a path inside"), ("link", "symbolic link")] {
        let why = std::fs::read_to_string(d.join(format!("inc/rejected/{name}.error.txt")))
            .unwrap_or_else(|e| panic!("{name} was not refused ({e}):\n{desc}"));
        assert!(why.contains(says), "{name}: {why}");
    }
    assert!(secret.exists(), "a file outside is neither read nor moved");
    std::fs::write(d.join("up.json"), sidecar("../secret.png")).unwrap();
    fails_limited(d, 4, CLIPTEX, &["grow", "add", "tex", "up.json"], 1, &["up.json", "not a path inside"]);
    assert_eq!(patches_in(d), 0);
    // The owner's own request on the control socket may name an image anywhere.
    std::fs::write(d.join("own.json"), sidecar(s(&secret))).unwrap();
    let svc = service(d, "dotdot", &[]);
    let reply = send(&svc.socket, &format!("PATCH FILE {}", s(&d.join("own.json"))), &[]);
    assert!(reply.starts_with("OK patch 1"), "{reply}");
}

// Crash, hang, unbounded memory --------------------------------------------------------------

#[test]
fn patch_file_naming_a_fifo_answers_at_once_and_sigterm_still_stops_the_service() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store(d);
    mkfifo(&d.join("fifo.json"));
    mkfifo(&d.join("fifo.png"));
    std::fs::write(d.join("img.json"), sidecar("fifo.png")).unwrap();
    let mut svc = service(d, "fifo", &[]);
    for (side, says) in [("fifo.json", "a FIFO"), ("img.json", "a FIFO")] {
        let t = Instant::now();
        let reply = send(&svc.socket, &format!("PATCH FILE {}", s(&d.join(side))), &[]);
        assert!(reply.starts_with("ERR PATCH") && reply.contains(says), "{side}: {reply}");
        assert!(t.elapsed() < Duration::from_secs(5), "{side}: answered in {:?}", t.elapsed());
    }
    rustix::process::kill_process(
        rustix::process::Pid::from_raw(svc.child.id() as i32).unwrap(),
        rustix::process::Signal::TERM,
    )
    .unwrap();
    let t = Instant::now();
    let status = loop {
        if let Some(st) = svc.child.try_wait().unwrap() {
            break st;
        }
        assert!(t.elapsed() < LIMIT, "SIGTERM did not stop the service");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(status.success(), "{status:?}");
}

#[test]
fn a_fifo_image_in_the_watched_directory_does_not_hold_up_later_patches() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store(d);
    let svc = service(d, "fifoinc", &[]);
    mkfifo(&d.join("inc/f.png"));
    std::fs::write(d.join("inc/f.json"), sidecar("f.png")).unwrap();
    wait_for("the FIFO's sidecar refused", || d.join("inc/rejected/f.error.txt").exists());
    let why = std::fs::read_to_string(d.join("inc/rejected/f.error.txt")).unwrap();
    assert!(why.contains("a FIFO"), "{why}");
    let p = png(32, 24);
    let reply = send(&svc.socket, &format!("PATCH DATA {} {}", p.len(), sidecar("p.png")), &p);
    assert!(reply.starts_with("OK patch 1"), "{reply}");
}

#[test]
fn devices_and_sparse_giants_as_sidecar_or_image_are_refused_from_their_length() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store(d);
    std::os::unix::fs::symlink("/dev/zero", d.join("zero.json")).unwrap();
    std::os::unix::fs::symlink("/dev/urandom", d.join("random.png")).unwrap();
    std::fs::write(d.join("random.json"), sidecar("random.png")).unwrap();
    std::fs::File::create(d.join("sparse.png")).unwrap().set_len(2 << 30).unwrap();
    std::fs::write(d.join("sparse.json"), sidecar("sparse.png")).unwrap();
    std::fs::File::create(d.join("sparse-side.json")).unwrap().set_len(2 << 30).unwrap();
    let svc = service(d, "devices", &[]);
    for (side, says) in [
        ("zero.json", "a character device"),
        ("random.json", "a character device"),
        ("sparse.json", "2147483648 bytes"),
        ("sparse-side.json", "2147483648 bytes"),
    ] {
        let t = Instant::now();
        let reply = send(&svc.socket, &format!("PATCH FILE {}", s(&d.join(side))), &[]);
        assert!(reply.starts_with("ERR PATCH") && reply.contains(says), "{side}: {reply}");
        assert!(t.elapsed() < Duration::from_secs(5), "{side}: answered in {:?}", t.elapsed());
    }
    assert!(svc.alive());
    // The same in the watched directory, where links are not followed at all.
    std::fs::copy(d.join("sparse.json"), d.join("inc/sparse.json")).unwrap();
    std::fs::File::create(d.join("inc/sparse.png")).unwrap().set_len(2 << 30).unwrap();
    wait_for("the sparse image refused", || d.join("inc/rejected/sparse.error.txt").exists());
    assert!(std::fs::read_to_string(d.join("inc/rejected/sparse.error.txt")).unwrap().contains("2147483648 bytes"));
    assert!(svc.alive());
}

#[test]
fn patch_data_announcing_huge_sizes_on_many_connections_allocates_nothing_up_front() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store(d);
    let svc = service(d, "announce", &[]);
    let json = r#"{"bbox": [0, 0, 8192, 8192], "raw": {"width": 8192, "height": 8192}}"#;
    // 40 connections announcing 256 MiB each (10 GiB in all under a 4 GiB limit), sending none.
    let mut conns: Vec<UnixStream> = (0..40)
        .map(|_| {
            let mut c = UnixStream::connect(&svc.socket).unwrap();
            c.write_all(format!("PATCH DATA 268435456 {json}\n").as_bytes()).unwrap();
            c
        })
        .collect();
    assert_eq!(ask(&svc.socket, "PING"), "OK pong", "the service lives");
    let st = ask(&svc.socket, "STATUS");
    assert!(st.starts_with("OK {"), "{st}");
    // A small patch still goes through once the announced ones give up theirs.
    drop(conns.drain(..));
    let p = png(32, 24);
    let reply = send(&svc.socket, &format!("PATCH DATA {} {}", p.len(), sidecar("p.png")), &p);
    assert!(reply.starts_with("OK patch 1"), "{reply}");
}

#[test]
fn max_patch_bytes_beyond_its_bound_is_refused_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store(d);
    let sock = d.join("s.sock");
    for v in ["18446744073709551615", "0", "5g"] {
        fails_limited(
            d,
            4,
            CLIPMAPD,
            &["--growing", "tex", "--max-patch-bytes", v, "--socket", s(&sock), "--shm-dir", s(d), "--name", "mpb"],
            1,
            &["--max-patch-bytes", "MAX_PATCH_BYTES"],
        );
    }
    fails_limited(
        d,
        4,
        CLIPTEX,
        &["grow", "add", "tex", "x.json", "--max-patch-bytes", "1099511627776"],
        1,
        &["MAX_PATCH_BYTES"],
    );
}

#[test]
fn a_state_json_of_four_billion_levels_is_refused_as_damaged() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store_with_patch(d);
    std::fs::write(d.join("tex/state.json"), r#"{"applied": 0, "levels": 4294967295}"#).unwrap();
    for sub in ["status", "rebuild"] {
        fails_limited(d, 2, CLIPTEX, &["grow", sub, "tex"], 1, &["state.json", "4294967295 levels", "at most 64"]);
    }
}

#[test]
fn store_files_that_are_fifos_do_not_block_the_tools_or_the_service() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let tex = store_with_patch(d);
    // A tile that is a FIFO is damaged: rebuilt, and a regular file again.
    let tile = first_tile(&tex);
    std::fs::remove_file(&tile).unwrap();
    mkfifo(&tile);
    let (o, desc, _) = limited(d, 4, CLIPTEX, &["grow", "rebuild", "tex"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    assert!(std::fs::symlink_metadata(&tile).unwrap().is_file(), "the tile was rebuilt: {desc}");
    // A state.json that is a FIFO: refused at once by the tools and the service.
    std::fs::remove_file(tex.join("state.json")).unwrap();
    mkfifo(&tex.join("state.json"));
    fails_limited(d, 4, CLIPTEX, &["grow", "status", "tex"], 1, &["state.json", "a FIFO"]);
    fails_limited(d, 4, CLIPTEX, &["grow", "rebuild", "tex"], 1, &["state.json", "a FIFO"]);
    let sock = d.join("s.sock");
    fails_limited(
        d,
        4,
        CLIPMAPD,
        &["--growing", "tex", "--socket", s(&sock), "--shm-dir", s(d), "--name", "fifostore", "--size", "512"],
        1,
        &["state.json", "a FIFO"],
    );
}

fn first_tile(tex: &Path) -> PathBuf {
    let l0 = tex.join("tiles/0");
    let mut tiles: Vec<PathBuf> = std::fs::read_dir(&l0).unwrap().map(|e| e.unwrap().path()).collect();
    tiles.sort();
    tiles.into_iter().find(|p| p.extension().is_some_and(|x| x == "tile")).expect("a level-0 tile")
}

#[test]
fn store_files_linked_to_dev_zero_or_sparse_are_not_read_whole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let tex = store_with_patch(d);
    let mut tiles: Vec<PathBuf> = std::fs::read_dir(tex.join("tiles/0")).unwrap().map(|e| e.unwrap().path()).collect();
    tiles.sort();
    let (a, b) = (&tiles[0], &tiles[1]);
    let len = std::fs::metadata(a).unwrap().len();
    std::fs::remove_file(a).unwrap();
    std::os::unix::fs::symlink("/dev/zero", a).unwrap();
    std::fs::OpenOptions::new().write(true).open(b).unwrap().set_len(3 << 30).unwrap();
    // Under a 2 GiB limit, so that reading either whole fails instead of taking 3 GB; both are
    // refused for what they are before a byte is read, and rebuilt.
    let (o, desc, said) = limited(d, 2, CLIPTEX, &["grow", "rebuild", "tex"]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    assert!(said.contains("a character device"), "{desc}");
    assert!(said.contains(&format!("3221225472 bytes where a tile of this grid has {len}")), "{desc}");
    for t in [a, b] {
        let m = std::fs::symlink_metadata(t).unwrap();
        assert!(m.is_file() && m.len() == len, "{} rebuilt: {m:?}", t.display());
    }
    // A patch's record or its image linked to a device: the store is damaged, nothing is read.
    let rec = tex.join("patches/0000000001.json");
    let kept = std::fs::read(&rec).unwrap();
    std::fs::remove_file(&rec).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &rec).unwrap();
    fails_limited(d, 2, CLIPTEX, &["grow", "status", "tex"], 1, &["0000000001.json", "a character device"]);
    std::fs::remove_file(&rec).unwrap();
    std::fs::write(&rec, kept).unwrap();
    let img = tex.join("patches/0000000001.image");
    std::fs::OpenOptions::new().write(true).open(&img).unwrap().set_len(3 << 30).unwrap();
    fails_limited(d, 2, CLIPTEX, &["grow", "status", "tex"], 1, &["0000000001.image", "3221225472 bytes"]);
}

#[test]
fn a_lock_planted_as_a_symlink_is_refused_and_its_target_untouched() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let tex = store_with_patch(d);
    let victim = d.join("victim.txt");
    std::fs::write(&victim, "precious\n").unwrap();
    std::fs::remove_file(tex.join("lock")).unwrap();
    std::os::unix::fs::symlink(&victim, tex.join("lock")).unwrap();
    fails_limited(d, 4, CLIPTEX, &["grow", "rebuild", "tex"], 2, &["lock", "symbolic link"]);
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious\n");
    std::fs::remove_file(tex.join("lock")).unwrap();
    mkfifo(&tex.join("lock"));
    fails_limited(d, 4, CLIPTEX, &["grow", "rebuild", "tex"], 2, &["lock", "a FIFO"]);
}

#[test]
fn an_incoming_directory_that_is_or_holds_or_lies_in_the_store_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let tex = store_with_patch(d);
    std::os::unix::fs::symlink(&tex, d.join("alias")).unwrap();
    let sock = d.join("s.sock");
    for inc in ["tex", "tex/patches", ".", "alias"] {
        fails_limited(
            d,
            4,
            CLIPMAPD,
            &[
                "--growing",
                "tex",
                "--incoming",
                inc,
                "--socket",
                s(&sock),
                "--shm-dir",
                s(d),
                "--name",
                "inc",
                "--size",
                "512",
            ],
            1,
            &["--incoming", "the growing texture"],
        );
        fails_limited(d, 4, CLIPTEX, &["grow", "watch", "tex", inc, "--once"], 1, &["the growing texture"]);
    }
    assert!(tex.join("grid.json").exists() && tex.join("state.json").exists(), "the store is whole");
    assert_eq!(patches_in(d), 1);
}

#[test]
fn a_malformed_patch_data_line_never_has_its_payload_read_as_commands() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    store(d);
    let svc = service(d, "malformed", &[]);
    for line in ["PATCH DATA 9 nojson", "PATCH DATA x {}", "patch data 9", "PATCH DATA"] {
        let mut c = UnixStream::connect(&svc.socket).unwrap();
        c.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        c.write_all(format!("{line}\nSHUTDOWN\n").as_bytes()).unwrap();
        let mut all = String::new();
        let _ = c.read_to_string(&mut all);
        assert!(all.starts_with("ERR") && all.contains("closing"), "{line}: {all}");
        assert!(!all.contains("shutting down"), "{line}: the payload was read as a command: {all}");
        assert_eq!(ask(&svc.socket, "PING"), "OK pong", "{line}: the service still runs");
    }
}
