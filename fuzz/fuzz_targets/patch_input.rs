//! Fuzzes what a growing texture does with a patch before it keeps it: the sidecar parsed, the
//! payload decoded and checked as `PATCH DATA` takes it, and both read back from files as a
//! watched directory reads them. The logic is shared with the property tests
//! (`tests/it/common/patch_exercise.rs`), which run it where `cargo fuzz` cannot.
#![no_main]

#[path = "../../tests/it/common/patch_exercise.rs"]
mod patch_exercise;

use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

fn dir() -> &'static tempfile::TempDir {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| tempfile::tempdir().expect("temporary directory"))
}

fuzz_target!(|data: &[u8]| {
    patch_exercise::exercise_patch(data, dir().path());
});
