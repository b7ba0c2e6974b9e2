//! A shared directory without room for a mapping (docs/SHM.md, "Where"): any local user can fill
//! `/dev/shm`, and a shared mapping of a file whose pages the file system cannot supply faults
//! with SIGBUS at the first store. The service reserves a mapping's bytes before it touches a page
//! and refuses, with the bytes needed and how to make room, at start and on `VIEW ADD ... own`,
//! leaving nothing behind and (on the socket) running on.
//!
//! A full file system needs a small one: these tests mount a tmpfs of a few megabytes, which only
//! root may do (CI runs as root); as another user they say so and check nothing.

use crate::clipmapd::{ask, CLIPMAPD};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A tmpfs of `size` mounted on a fresh directory, unmounted (and the directory removed) on drop.
struct SmallTmpfs {
    dir: tempfile::TempDir,
}

impl SmallTmpfs {
    /// Mounts one, or says why it cannot (not root, or the mount was refused) and gives `None`.
    fn mount(size: &str) -> Option<SmallTmpfs> {
        if rustix::process::geteuid().as_raw() != 0 {
            eprintln!("skipped: mounting a small tmpfs needs root (CI runs as root)");
            return None;
        }
        let dir = tempfile::tempdir().unwrap();
        let out = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size},mode=1777"), "tmpfs"])
            .arg(dir.path())
            .output()
            .unwrap();
        if !out.status.success() {
            eprintln!("skipped: mount -t tmpfs was refused: {}", String::from_utf8_lossy(&out.stderr));
            return None;
        }
        Some(SmallTmpfs { dir })
    }

    fn path(&self) -> &Path {
        self.dir.path()
    }

    fn resize(&self, size: &str) {
        let out =
            Command::new("mount").args(["-o", &format!("remount,size={size}")]).arg(self.path()).output().unwrap();
        assert!(out.status.success(), "remount: {out:?}");
    }

    /// The names in it.
    fn names(&self) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(self.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }
}

impl Drop for SmallTmpfs {
    fn drop(&mut self) {
        // The services are gone before this runs (declared after it); a lazy unmount if not.
        let done = Command::new("umount").arg(self.dir.path()).status().is_ok_and(|s| s.success());
        if !done {
            let _ = Command::new("umount").arg("-l").arg(self.dir.path()).status();
        }
    }
}

/// `clipmapd --source hash` (a mapping of about 10 MB) publishing into `shm`, its socket and log
/// in `logs`; killed on drop.
struct Hash {
    child: Child,
    socket: PathBuf,
    err: PathBuf,
}

impl Hash {
    fn spawn(shm: &Path, logs: &Path) -> Hash {
        let socket = logs.join("room.sock");
        let err = logs.join("room.err");
        let child = Command::new(CLIPMAPD)
            .args(["--source", "hash", "--size", "65536", "--clip", "256", "--tile", "64", "--name", "room"])
            .arg("--shm-dir")
            .arg(shm)
            .arg("--socket")
            .arg(&socket)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&err).unwrap())
            .spawn()
            .unwrap();
        Hash { child, socket, err }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.err).unwrap_or_default()
    }

    fn wait_exit(&mut self) -> std::process::ExitStatus {
        let t = Instant::now();
        loop {
            if let Some(st) = self.child.try_wait().unwrap() {
                return st;
            }
            assert!(t.elapsed() < Duration::from_secs(30), "clipmapd did not stop\n{}", self.log());
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Hash {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn no_room_in_the_shm_file_system_at_start_is_an_error_that_leaves_nothing_not_a_sigbus() {
    let Some(fs) = SmallTmpfs::mount("1m") else { return };
    let logs = tempfile::tempdir().unwrap();
    let mut svc = Hash::spawn(fs.path(), logs.path());
    let st = svc.wait_exit();
    let log = svc.log();
    assert_eq!(st.code(), Some(2), "refused as a service that could not run, not killed by a signal: {st:?}\n{log}");
    let map = fs.path().join("clipmap-room.map");
    for words in [
        format!("{}: no room for a mapping of ", map.display()),
        format!("the file system of {} has ", fs.path().display()),
        "bytes free".to_string(),
        "--shm-dir".to_string(),
    ] {
        assert!(log.contains(&words), "`{words}` in:\n{log}");
    }
    let needed: u64 =
        log.split("no room for a mapping of ").nth(1).unwrap().split(' ').next().unwrap().parse().unwrap();
    assert!(needed > 1 << 20, "{log}");
    assert_eq!(fs.names(), Vec::<String>::new(), "no temporary, request mapping or lock file is left");
    // With room, the same start works.
    fs.resize("16m");
    let svc = Hash::spawn(fs.path(), logs.path());
    let t = Instant::now();
    // The service binds its socket before it puts the mapping under its name: wait for both.
    while std::os::unix::net::UnixStream::connect(&svc.socket).is_err() || !map.is_file() {
        assert!(t.elapsed() < Duration::from_secs(30), "{}", svc.log());
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(std::fs::metadata(&map).unwrap().len(), needed);
}

#[test]
fn no_room_in_the_shm_file_system_at_view_add_own_is_refused_on_the_socket_not_a_sigbus() {
    // Room for the service's mapping (about 10 MB), not for a second one.
    let Some(fs) = SmallTmpfs::mount("14m") else { return };
    let logs = tempfile::tempdir().unwrap();
    let mut svc = Hash::spawn(fs.path(), logs.path());
    let t = Instant::now();
    let pong = loop {
        match std::os::unix::net::UnixStream::connect(&svc.socket) {
            Ok(_) => break ask(&svc.socket, "PING"),
            Err(_) if t.elapsed() < Duration::from_secs(30) => std::thread::sleep(Duration::from_millis(20)),
            Err(e) => panic!("{e}\n{}", svc.log()),
        }
    };
    assert_eq!(pong, "OK pong");
    let before = fs.names();
    let reply = ask(&svc.socket, "VIEW ADD far 1 own");
    let own = fs.path().join("clipmap-room@far.map");
    assert!(reply.starts_with("ERR "), "{reply}\n{}", svc.log());
    for words in [format!("{}: no room for a mapping of ", own.display()), "bytes free".to_string()] {
        assert!(reply.contains(&words), "`{words}` in {reply}");
    }
    // Still running, with nothing of the view left.
    assert_eq!(svc.child.try_wait().unwrap(), None, "{}", svc.log());
    assert_eq!(ask(&svc.socket, "PING"), "OK pong");
    assert_eq!(fs.names(), before, "the view's temporary, request mapping and lock are gone");
    let views = ask(&svc.socket, "VIEWS");
    assert!(views.starts_with("OK ") && !views.contains("\"far\""), "{views}");
    // Room made, the same view is added.
    fs.resize("32m");
    let reply = ask(&svc.socket, "VIEW ADD far 1 own");
    assert!(reply.starts_with("OK view far added"), "{reply}\n{}", svc.log());
    assert!(own.is_file());
    assert_eq!(ask(&svc.socket, "SHUTDOWN"), "OK shutting down");
    assert_eq!(svc.wait_exit().code(), Some(0), "{}", svc.log());
}
