//! Fuzzes the configuration reader end to end: both parsers, both plan builders (through a
//! file, as the tools read it, next to two level `.ic` files a `.ct` may name), the tools'
//! reports and tile location. The logic is shared with the property tests
//! (`tests/it/common/exercise.rs`), which run it where `cargo fuzz` cannot.
#![no_main]

#[path = "../../tests/it/common/exercise.rs"]
mod exercise;

use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

fn dir() -> &'static tempfile::TempDir {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = tempfile::tempdir().expect("temporary directory");
        for s in [2048u32, 1024] {
            let text = format!(
                "ic_version2.0\next_format PFTEX_PACK_8\nint_format PFTEX_RGB_8\n\
                 img_format PFTEX_RGB\nicache_size {s} {s} 1\ntile_size 256 256 1\n"
            );
            std::fs::write(d.path().join(format!("l.{s}.ic")), text).expect("write");
        }
        d
    })
}

fuzz_target!(|data: &[u8]| {
    exercise::exercise(data, dir().path());
});
