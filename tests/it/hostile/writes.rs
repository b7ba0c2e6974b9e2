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
