//! Fuzzes the TIFF / COG reader: arbitrary bytes opened as a TIFF (header, IFD chain, every
//! image's tags, the levels past the overviews built), described, and every tile of every level
//! read, a bounded number of them. The logic is shared with the property tests
//! (`tests/it/common/tiff_exercise.rs`), which run it where `cargo fuzz` cannot.
#![no_main]

#[path = "../../tests/it/common/tiff_exercise.rs"]
mod tiff_exercise;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    tiff_exercise::exercise_tiff(data);
});
