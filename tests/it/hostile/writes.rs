//! Writes that fail: a full device, a preparation killed half way.

use super::service::{fails, run, CLIPPREP, CLIPTEX, ROOT};
use std::path::Path;

#[test]
fn dump_to_dev_full_exits_2() {
    if !Path::new("/dev/full").exists() {
        eprintln!("skipped: no /dev/full");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let ct = Path::new(ROOT).join("config_examples/prepared/hash256.ct");
    fails(d, CLIPTEX, &["dump", ct.to_str().unwrap(), "--level", "0", "--out", "/dev/full"], 2, &["/dev/full"]);
}

#[test]
fn a_dump_replaces_its_picture_whole_and_leaves_no_temporary() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let ct = Path::new(ROOT).join("config_examples/prepared/hash256.ct");
    let png = d.join("l0.png");
    std::fs::write(&png, "the previous picture").unwrap();
    let (o, desc) = run(d, CLIPTEX, &["dump", ct.to_str().unwrap(), "--level", "0", "--out", png.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{desc}");
    let bytes = std::fs::read(&png).unwrap();
    assert!(bytes.starts_with(b"\x89PNG"), "replaced whole by the new picture");
    let left: Vec<_> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 1, "no temporary left: {left:?}");
}

#[test]
fn a_killed_clipprep_leaves_nothing_that_validates_and_the_next_run_removes_it() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let out = d.join("pyr");
    let mut child = std::process::Command::new(CLIPPREP)
        .args(["--source", "terrain", "--size", "8192", "--tile", "64", "--clip", "256", "--format", "rgb8", "--out"])
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Kill it once its partial output exists (bounded wait).
    let t = std::time::Instant::now();
    let partial = loop {
        let found = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.file_name().unwrap().to_string_lossy().starts_with(".pyr.clipprep-partial-"));
        if let Some(p) = found {
            if std::fs::read_dir(&p).map(|r| r.count()).unwrap_or(0) > 0 {
                break Some(p);
            }
        }
        if t.elapsed() > super::service::LIMIT || child.try_wait().unwrap().is_some() {
            break None;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    };
    let _ = child.kill();
    let _ = child.wait();
    let Some(partial) = partial else {
        eprintln!("skipped: clipprep finished before it could be killed");
        return;
    };
    if out.exists() {
        eprintln!("skipped: clipprep finished before it was killed");
        return;
    }
    // Nothing there validates: no configuration file is written before every tile is.
    let configs: Vec<_> =
        walk(&partial).into_iter().filter(|p| p.extension().is_some_and(|e| e == "ct" || e == "ic")).collect();
    assert!(configs.is_empty(), "a killed run left configuration files: {configs:?}");
    // The next run removes the stale partial output and succeeds.
    let (o, desc) = run(
        d,
        CLIPPREP,
        &[
            "--source",
            "hash",
            "--size",
            "256",
            "--tile",
            "64",
            "--clip",
            "64",
            "--format",
            "rgb8",
            "--out",
            out.to_str().unwrap(),
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{desc}");
    assert!(!partial.exists(), "stale partial output removed");
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = e.path();
        if p.is_dir() {
            v.extend(walk(&p));
        } else {
            v.push(p);
        }
    }
    v
}

/// The arguments of a small prepared hash texture written as a COG at `cog` too.
fn cog_args<'a>(out: &'a str, cog: &'a str, size: &'a str) -> Vec<&'a str> {
    vec![
        "--source", "hash", "--size", size, "--tile", "256", "--clip", "512", "--format", "rgb8", "--out", out,
        "--cog", cog,
    ]
}

/// What of `.NAME...` temporaries is beside `name` in `dir`.
fn temporaries(dir: &Path, name: &str) -> Vec<String> {
    let prefix = format!(".{name}.");
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(&prefix))
        .collect()
}

#[test]
fn clipprep_cog_naming_a_fifo_is_refused_at_once_and_never_opened() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let fifo = d.join("out.tif");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    let out = d.join("pyr");
    let args = cog_args(out.to_str().unwrap(), fifo.to_str().unwrap(), "512");
    // Before: blocked for ever opening the FIFO for writing (and deaf to SIGTERM meanwhile).
    let err = fails(d, CLIPPREP, &args, 2, &["out.tif", "a FIFO (named pipe), not a regular file"]);
    assert!(err.contains("a COG is written as a regular file"), "{err}");
    assert!(!out.exists(), "refused before any work: no pyramid written");
    let meta = std::fs::symlink_metadata(&fifo).unwrap();
    assert!(std::os::unix::fs::FileTypeExt::is_fifo(&meta.file_type()), "the FIFO is left as it was");
    // A character device likewise.
    if Path::new("/dev/null").exists() {
        let args = cog_args(out.to_str().unwrap(), "/dev/null", "512");
        fails(d, CLIPPREP, &args, 2, &["/dev/null", "a character device, not a regular file"]);
    }
}

#[test]
fn sigterm_while_a_cog_is_written_stops_it_removes_its_temporaries_and_exits_2() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let out = d.join("pyr");
    let cog = d.join("out.tif");
    let args = cog_args(out.to_str().unwrap(), cog.to_str().unwrap(), "4096");
    let mut child = std::process::Command::new(CLIPPREP)
        .current_dir(d)
        .args(&args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Signal it once the COG's scratch file of tiles has bytes (bounded wait).
    let t = std::time::Instant::now();
    let scratch = format!(".out.tif.{}.tiles.tmp", child.id());
    let seen = loop {
        if std::fs::metadata(d.join(&scratch)).is_ok_and(|m| m.len() > 0) {
            break true;
        }
        if t.elapsed() > super::service::LIMIT || child.try_wait().unwrap().is_some() {
            break false;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    };
    assert!(seen, "the COG's scratch file never appeared: the write finished too fast to test");
    let kill = std::process::Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    assert!(kill.success());
    let t = std::time::Instant::now();
    let status = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        if t.elapsed() > std::time::Duration::from_secs(10) {
            let _ = child.kill();
            panic!("clipprep went on writing the COG for 10 s after SIGTERM");
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
    // Before: the signal was ignored, the COG finished and the exit status was 0.
    assert_eq!(status.code(), Some(2), "exit status after SIGTERM: {status:?}\n{err}");
    assert!(err.contains("interrupted") && err.contains("out.tif"), "{err}");
    assert!(!cog.exists(), "no COG left at the target");
    assert_eq!(temporaries(d, "out.tif"), Vec::<String>::new(), "no temporary left");
}

#[test]
fn a_killed_clipprep_cogs_tiles_temporary_is_removed_by_the_next_run() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    // A pid that is surely gone: a process that ran and was waited for.
    let mut gone = std::process::Command::new("true").spawn().unwrap();
    gone.wait().unwrap();
    let dead = gone.id();
    let live = std::process::id(); // this test's own process: alive, and not clipprep's
    let stale = [format!(".out.tif.{dead}.tiles.tmp"), format!(".out.tif.tmp.{dead}.0")];
    let kept = format!(".out.tif.{live}.tiles.tmp");
    for n in stale.iter().chain([&kept]) {
        std::fs::write(d.join(n), vec![7u8; 4096]).unwrap();
    }
    let out = d.join("pyr");
    let cog = d.join("out.tif");
    let (o, desc) = run(d, CLIPPREP, &cog_args(out.to_str().unwrap(), cog.to_str().unwrap(), "512"));
    assert_eq!(o.status.code(), Some(0), "{desc}");
    assert!(cog.is_file());
    // Before: every killed run's scratch file stayed for good (46 to 114 MB each).
    assert_eq!(temporaries(d, "out.tif"), vec![kept], "a dead run's temporaries removed, a live run's kept");
}
