//! Replays every input kept in `tests/fuzz_regressions/` through the whole reader
//! (`common/exercise.rs`): each once crashed or hung it.

use crate::common;
use crate::common::exercise;

use common::Fixture;
use std::path::Path;

#[test]
fn every_kept_crash_input_is_handled() {
    let dir = Path::new(env!("CLIPMAP_ROOT")).join("tests/fuzz_regressions");
    let mut inputs: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().is_some_and(|n| n != "README.md"))
        .collect();
    inputs.sort();
    assert!(inputs.len() >= 4, "regression inputs: {inputs:?}");
    for input in inputs {
        let bytes = std::fs::read(&input).unwrap();
        let fx = Fixture::new();
        fx.write_level_ics("l", 2048, 1024, 256);
        let r = std::panic::catch_unwind(|| exercise::exercise(&bytes, fx.dir.path()));
        assert!(r.is_ok(), "{} crashes the reader", input.display());
    }
}
