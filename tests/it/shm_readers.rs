//! The reader programs against a running `clipmapd` (docs/SHM.md, "Readers in this repository"):
//! the Rust reader refuses a view's own mapping that is a symbolic link or another user's file, as
//! the C and Python readers do.

use crate::clipmapd::{c_reader, python_reader, rust_reader, Service};
use std::path::Path;
use std::process::Output;

fn text(out: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Each reader reading `--view far` of the service `name` in `d` a moment.
fn read_far(d: &Path, name: &str) -> Vec<(&'static str, Output)> {
    let map = d.join(format!("clipmap-{name}.map"));
    let rust = rust_reader(d, name, &["--view", "far", "--reads", "100"]).output().unwrap();
    let mut c = std::process::Command::new(c_reader(d));
    let c = c.arg(&map).args(["100", "1", "5", "--view", "far"]).output().unwrap();
    let py = python_reader().arg(&map).args(["100", "1", "5", "--view", "far"]).output().unwrap();
    vec![("rust", rust), ("c", c), ("python", py)]
}

#[test]
fn the_rust_reader_refuses_a_symlinked_or_another_users_own_view_mapping_as_c_and_python_do() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let _svc = Service::start(d, "sym", &["--view", "far:own"]);
    let own = d.join("clipmap-sym@far.map");
    for (who, out) in read_far(d, "sym") {
        assert!(out.status.success(), "{who} reads the view as published\n{}", text(&out));
    }
    // A link planted at the name, to a mapping that is otherwise fine.
    let aside = d.join("aside.map");
    std::fs::rename(&own, &aside).unwrap();
    std::os::unix::fs::symlink(&aside, &own).unwrap();
    for (who, out) in read_far(d, "sym") {
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{who} refuses the link\n{}", text(&out));
        assert!(err.contains(own.to_str().unwrap()) && err.contains("a symbolic link"), "{who}: {err}");
    }
    std::fs::remove_file(&own).unwrap();
    std::fs::rename(&aside, &own).unwrap();
    // Another user's file at the name.
    if rustix::process::geteuid().as_raw() != 0 {
        eprintln!("skipped the owner check: giving a file to another user needs root (CI runs as root)");
        return;
    }
    std::os::unix::fs::chown(&own, Some(65534), None).unwrap();
    for (who, out) in read_far(d, "sym") {
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{who} refuses another user's file\n{}", text(&out));
        assert!(err.contains("owned by uid 65534") && err.contains("expected uid 0"), "{who}: {err}");
    }
}
