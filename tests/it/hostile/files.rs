//! Files a configuration names (the `.ct` and `.ic` themselves, tiles, default tiles) that are
//! not regular files or are far larger than their format allows: FIFOs, devices, directories.

use super::service::{fails, mkfifo, run, Service, CLIPMAPD, CLIPTEX, ICACHE, LIMIT, ROOT};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// A copy of `config_examples/prepared` (hash256.ct: 256 square, clip 64, two image-cache
/// levels of 64-texel RGB tiles, seven pyramid files) in `dir`.
fn prepared(dir: &Path) -> PathBuf {
    let src = Path::new(ROOT).join("config_examples/prepared");
    let dst = dir.join("prepared");
    copy_tree(&src, &dst);
    dst
}

fn copy_tree(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        let to = dst.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &to);
        } else {
            std::fs::copy(e.path(), &to).unwrap();
        }
    }
}

fn replace_with_link(path: &Path, target: &str) {
    std::fs::remove_file(path).unwrap();
    std::os::unix::fs::symlink(target, path).unwrap();
}

fn replace_with_fifo(path: &Path) {
    std::fs::remove_file(path).unwrap();
    mkfifo(path);
}

#[test]
fn tiles_that_are_fifos_or_links_to_devices_are_counted_faults_never_texels_nor_a_wedged_queue() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let p = prepared(d);
    let saved = std::fs::read(p.join("L01/r000.c000.raw")).unwrap();
    replace_with_fifo(&p.join("L01/r000.c000.raw"));
    replace_with_link(&p.join("L01/r000.c001.raw"), "/dev/zero");
    replace_with_link(&p.join("L01/r001.c000.raw"), "/dev/urandom");
    replace_with_fifo(&p.join("pyramid/L04.raw"));
    let ct = p.join("hash256.ct");
    // `cliptex check` calls each of them unreadable, and exits 1 without hanging.
    let out = fails(d, CLIPTEX, &["check", ct.to_str().unwrap()], 1, &[]);
    assert!(out.contains("unreadable"), "{out}");
    // The service counts them as failed reads and keeps serving.
    let s = Service::start(d, "bad", &[ct.to_str().unwrap()], &[]);
    let t = Instant::now();
    let failed = loop {
        let st = s.stats();
        let n = st["engine"]["queue"]["reads_failed"].as_u64().unwrap_or(0);
        if n >= 4 || t.elapsed() > LIMIT {
            break n;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(failed >= 4, "four bad tiles, each a counted fault: {}", s.stats());
    // No texel of theirs is ever published: a reader checking every texel it reads finds none wrong.
    let (out, desc) = run(
        d,
        env!("CARGO_BIN_EXE_clipmap-read"),
        &["--name", "bad", "--shm-dir", d.to_str().unwrap(), "--seconds", "1", "--reads", "1000000000"],
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains(" 0 failed"), "no wrong texel: {desc}");
    assert!(s.alive());
    // Repaired, the tile is read again: its queue was never wedged.
    std::fs::remove_file(p.join("L01/r000.c000.raw")).unwrap();
    std::fs::write(p.join("L01/r000.c000.raw"), &saved).unwrap();
    let done0 = s.stats()["engine"]["queue"]["reads_done"].as_u64().unwrap_or(0);
    let t = Instant::now();
    while s.stats()["engine"]["queue"]["reads_done"].as_u64().unwrap_or(0) <= done0 && t.elapsed() < LIMIT {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(s.stats()["engine"]["queue"]["reads_done"].as_u64().unwrap_or(0) > done0, "{}", s.stats());
}

#[test]
fn a_ct_or_ic_that_is_a_fifo_is_refused_by_every_tool_without_hanging() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let fifo = d.join("t.ct");
    mkfifo(&fifo);
    let f = fifo.to_str().unwrap();
    for (prog, args) in [
        (CLIPTEX, vec!["validate", f]),
        (CLIPTEX, vec!["info", f]),
        (CLIPTEX, vec!["check", f]),
        (CLIPTEX, vec!["dump", f, "--out", "x.png"]),
        (CLIPMAPD, vec![f, "--shm-dir", d.to_str().unwrap()]),
    ] {
        let (out, desc) = run(d, prog, &args);
        assert_ne!(out.status.code(), Some(0), "{desc}");
        assert!(desc.contains("a FIFO"), "{desc}");
    }
    let ic = d.join("t.ic");
    mkfifo(&ic);
    let (out, desc) = run(d, ICACHE, &["info", ic.to_str().unwrap()]);
    assert_ne!(out.status.code(), Some(0), "{desc}");
    assert!(desc.contains("a FIFO"), "{desc}");
    // A level .ic named by a .ct.
    let p = prepared(d);
    replace_with_fifo(&p.join("L00.ic"));
    let ct = p.join("hash256.ct");
    let (out, desc) = run(d, CLIPTEX, &["validate", ct.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1), "{desc}");
    assert!(desc.contains("a FIFO"), "{desc}");
}

/// hash256's level 0 `.ic` with a default tile line naming `target`.
fn with_default_tile(p: &Path, target: &str) -> PathBuf {
    let ic = p.join("L00.ic");
    let text = std::fs::read_to_string(&ic).unwrap();
    std::fs::write(&ic, format!("{text}default_tile {target}\n")).unwrap();
    p.join("hash256.ct")
}

#[test]
fn a_default_tile_naming_dev_zero_is_refused_not_read_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let p = prepared(d);
    let ct = with_default_tile(&p, "/dev/zero");
    let c = ct.to_str().unwrap();
    let err = fails(d, CLIPMAPD, &[c, "--shm-dir", d.to_str().unwrap(), "--name", "z"], 1, &["/dev/zero"]);
    assert!(err.contains("a character device, not a regular file"), "{err}");
    let out = fails(d, CLIPTEX, &["check", c], 1, &["/dev/zero"]);
    assert!(out.contains("a character device"), "{out}");
    // The dump reads the tiles and ignores the unusable default tile, bounded.
    let (o, desc) = run(d, CLIPTEX, &["dump", c, "--level", "0", "--out", d.join("l0.png").to_str().unwrap()]);
    assert!(matches!(o.status.code(), Some(0 | 1)), "{desc}");
}

#[test]
fn a_default_tile_that_is_a_fifo_or_far_too_large_is_refused_without_hanging() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let p = prepared(d);
    let fifo = d.join("default.fifo");
    mkfifo(&fifo);
    let ct = with_default_tile(&p, fifo.to_str().unwrap());
    let c = ct.to_str().unwrap();
    fails(d, CLIPMAPD, &[c, "--shm-dir", d.to_str().unwrap(), "--name", "f"], 1, &["a FIFO"]);
    fails(d, CLIPTEX, &["check", c], 1, &["a FIFO"]);
    // A sparse file of 1 GiB: its length is refused before anything is read.
    let big = d.join("big.raw");
    std::fs::File::create(&big).unwrap().set_len(1 << 30).unwrap();
    let p2 = d.join("p2");
    copy_tree(&p, &p2);
    let ic = p2.join("L00.ic");
    let text = std::fs::read_to_string(&ic).unwrap().replace(fifo.to_str().unwrap(), big.to_str().unwrap());
    std::fs::write(&ic, text).unwrap();
    let c2 = p2.join("hash256.ct");
    fails(
        d,
        CLIPMAPD,
        &[c2.to_str().unwrap(), "--shm-dir", d.to_str().unwrap(), "--name", "b"],
        1,
        &["1073741824 bytes"],
    );
}

#[test]
fn a_compressed_tile_cut_after_its_frame_header_is_corrupt_for_check_and_the_service_alike() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let pyr = d.join("z");
    let (o, desc) = run(
        d,
        super::service::CLIPPREP,
        &["--source", "hash", "--size", "256", "--tile", "64", "--clip", "64", "--format", "rgb8", "--zstd", "3"]
            .into_iter()
            .chain(["--out", pyr.to_str().unwrap()])
            .collect::<Vec<_>>(),
    );
    assert_eq!(o.status.code(), Some(0), "{desc}");
    // Every level-1 tile cut to half: the frame header (which announces one tile) survives.
    let l1: Vec<PathBuf> = std::fs::read_dir(pyr.join("L01")).unwrap().map(|e| e.unwrap().path()).collect();
    assert!(!l1.is_empty());
    for f in &l1 {
        let bytes = std::fs::read(f).unwrap();
        std::fs::write(f, &bytes[..bytes.len() / 2]).unwrap();
    }
    let ct = std::fs::read_dir(&pyr)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "ct"))
        .unwrap();
    let c = ct.to_str().unwrap();
    let (o, desc) = run(d, CLIPTEX, &["check", c, "--json"]);
    assert_eq!(o.status.code(), Some(1), "{desc}");
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(r["levels"][1]["corrupt"].as_u64(), Some(l1.len() as u64), "{desc}");
    let s = Service::start(d, "zc", &[c], &[]);
    let t = Instant::now();
    while s.stats()["engine"]["read_faults"]["corrupt"].as_u64().unwrap_or(0) == 0 && t.elapsed() < LIMIT {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(s.stats()["engine"]["read_faults"]["corrupt"].as_u64().unwrap_or(0) > 0, "{}", s.stats());
}

/// A `/proc` file for the cases below: `/proc/kmsg` (a "regular" file of length 0 whose reads
/// block until the kernel logs something) when it exists and this user may open it; otherwise
/// `/proc/version`, which reads at once and is refused all the same. Says which it chose.
fn proc_file() -> &'static str {
    // Opening /proc/kmsg does not block and reads nothing; only a read would.
    let kmsg = "/proc/kmsg";
    let chosen = if std::fs::File::open(kmsg).is_ok() { kmsg } else { "/proc/version" };
    eprintln!("the /proc file of this test: {chosen}");
    chosen
}

#[test]
fn a_configuration_naming_proc_kmsg_is_refused_by_every_tool_at_once() {
    let proc = proc_file();
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let said = "a file of the kernel's proc (/proc) filesystem, not a regular file of data";
    // Named on the command line as the .ct, and through a link.
    let link = d.join("t.ct");
    std::os::unix::fs::symlink(proc, &link).unwrap();
    for ct in [proc, link.to_str().unwrap()] {
        for (prog, args) in [
            (CLIPTEX, vec!["validate", ct]),
            (CLIPTEX, vec!["info", ct]),
            (CLIPTEX, vec!["check", ct]),
            (CLIPMAPD, vec![ct, "--shm-dir", d.to_str().unwrap(), "--name", "kmsg"]),
        ] {
            let t = Instant::now();
            let (out, desc) = run(d, prog, &args);
            assert!(t.elapsed() < Duration::from_secs(10), "{proc}: not at once:\n{desc}");
            assert_eq!(out.status.code(), Some(2), "{proc}: cannot be read:\n{desc}");
            assert!(desc.contains(said) && desc.contains(ct), "{proc}: says what and where:\n{desc}");
        }
    }
    // A level .ic named by a .ct.
    let p = prepared(d);
    replace_with_link(&p.join("L00.ic"), proc);
    let (out, desc) = run(d, CLIPTEX, &["validate", p.join("hash256.ct").to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1), "{proc}:\n{desc}");
    assert!(desc.contains(said), "{proc}:\n{desc}");
    // A default tile.
    let p2 = d.join("p2");
    copy_tree(&Path::new(ROOT).join("config_examples/prepared"), &p2);
    let ct = with_default_tile(&p2, proc);
    let c = ct.to_str().unwrap();
    let err = fails(d, CLIPMAPD, &[c, "--shm-dir", d.to_str().unwrap(), "--name", "kd"], 1, &[proc]);
    assert!(err.contains(said), "{proc}: {err}");
    let out = fails(d, CLIPTEX, &["check", c], 1, &[proc]);
    assert!(out.contains("proc (/proc) filesystem"), "{proc}: {out}");
}
