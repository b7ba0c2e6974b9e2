//! Hostile and broken input: truncated files, non-UTF-8 bytes, overflowing and absurd numbers,
//! huge lines and words, many tokens, and special files named as configuration.

mod common;

use clipmap::config::{FileKind, Limits, Severity};
use clipmap::plan::{self, Options};
use common::*;
use std::time::{Duration, Instant};

#[test]
#[cfg(unix)]
fn level_ic_named_dev_zero_was_read_without_a_size_limit() {
    // A level .ic was read whole, with no bound: naming /dev/zero (or any huge file) made the
    // reader loop until memory ran out. It is now read up to the file-size limit, like the .ct.
    if !std::path::Path::new("/dev/zero").exists() {
        return;
    }
    let fx = Fixture::new();
    fx.write(
        "z.ct",
        format!(
            "ct_version2.0\n{RGB8}virt_size 1024 1024 1\nclip_size 512\nicache_files /dev/zero\n"
        ),
    );
    let o = Options {
        limits: Limits {
            max_file_bytes: 1 << 16,
            ..Limits::default()
        },
        ..opts()
    };
    let t = Instant::now();
    let l = plan::load_clip_texture(&fx.path("z.ct"), &o).unwrap();
    assert!(t.elapsed() < Duration::from_secs(10));
    let x = find(&l.diagnostics, "file-too-large");
    assert_eq!(x.severity, Severity::Error);
    assert!(x.path.ends_with("zero"));
    assert!(x.message.contains("65537 bytes"), "{}", x.message);
}
