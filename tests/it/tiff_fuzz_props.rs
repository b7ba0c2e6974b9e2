//! Property tests over hostile TIFFs: GDAL's fixtures and TIFFs written byte by byte (BigTIFF,
//! an index past the end, 2^26 texels a side), then cut, bit-flipped, with bytes inserted and
//! with offsets, counts and sizes overwritten by extreme values, and arbitrary bytes, through
//! the whole reader (`common/tiff_exercise.rs`): nothing may panic, an error names the file, and
//! an image's tile count is bounded by the file's size.
//!
//! The case count is fixed (fast in CI); `CLIPMAP_FUZZ_CASES=N` raises it for a longer run, which
//! is how this logic is fuzzed where `cargo fuzz` cannot run (see fuzz/README.md).

use crate::common::mutate::{cases, flip, insert, overwrite};
use crate::common::tiff_exercise::exercise_tiff;
use crate::tiff_hardening::{bigtiff, grey_ifd, DATA_AT};
use proptest::prelude::*;
use std::path::Path;

/// Valid and nearly valid TIFFs: the small fixtures GDAL wrote, and some written here.
pub fn seeds() -> Vec<Vec<u8>> {
    let dir = Path::new(env!("CLIPMAP_ROOT")).join("tests/fixtures/cog");
    let mut out: Vec<Vec<u8>> = ["grey_200x256", "u16_64x64", "bigtiff_200x256", "strips_64x64", "i32_64x64"]
        .iter()
        .map(|n| std::fs::read(dir.join(format!("{n}.tif"))).unwrap())
        .collect();
    // A 64 x 64 grey image in four tiles with sparse overviews; the same claiming 2^26 a side.
    let mut data = vec![0u8; 64];
    for i in 0..4 {
        data[i * 8..][..8].copy_from_slice(&(DATA_AT + 64).to_le_bytes());
        data[32 + i * 8..][..8].copy_from_slice(&1024u64.to_le_bytes());
    }
    data.resize(64 + 1024, 9);
    let mut ifds = vec![grey_ifd([64, 64], [32, 32], DATA_AT, 0)];
    ifds.extend((1..=6).map(|k| grey_ifd([64 >> k, 64 >> k], [32, 32], 0, 1)));
    out.push(bigtiff(&ifds, &data));
    let huge: Vec<_> = (0..=26u64).map(|k| grey_ifd([1 << (26 - k); 2], [256; 2], DATA_AT, (k > 0) as u64)).collect();
    out.push(bigtiff(&huge, &data));
    out
}

/// A seed mutated: cut, bytes flipped, bytes inserted, or a word overwritten by an extreme value.
fn mutated() -> impl Strategy<Value = Vec<u8>> {
    let seeds = seeds();
    let n = seeds.len();
    (0..n, 0usize..5, any::<u64>(), proptest::collection::vec(any::<u8>(), 1..8)).prop_map(move |(i, how, r, bytes)| {
        let mut v = seeds[i].clone();
        // Most structure lies in the first bytes: aim there half the time.
        let span = if r % 2 == 0 { v.len().min(512) } else { v.len() };
        let at = ((r >> 8) as usize) % span.max(1);
        match how {
            0 => v.truncate(at),
            1 => flip(&mut v, at, &bytes, 7),
            2 => insert(&mut v, at, &bytes),
            _ => {
                let extreme =
                    [0u64, 1, 0xFFFF, 0x7FFF_FFFF, 0xFFFF_FFFF, 1 << 26, 1 << 63, u64::MAX][(r >> 40) as usize % 8];
                let width = [2usize, 4, 8][(r >> 48) as usize % 3];
                overwrite(&mut v, at, extreme, width);
            }
        }
        v
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(64), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_as_a_tiff_never_panic(
        head in prop::sample::select(vec![b"II*\0".to_vec(), b"MM\0*".to_vec(), b"II+\0\x08\0\0\0".to_vec(), b"MM\0+\0\x08\0\0".to_vec()]),
        rest in proptest::collection::vec(any::<u8>(), 0..2048),
    ) {
        let mut data = head;
        data.extend_from_slice(&rest);
        exercise_tiff(&data);
    }

    #[test]
    fn mutated_tiffs_never_panic_and_keep_their_bounds(data in mutated()) {
        exercise_tiff(&data);
    }
}

#[test]
fn the_seeds_open_or_are_refused_as_expected() {
    let s = seeds();
    let name = Path::new("seed.tif");
    for (i, bytes) in s.iter().enumerate() {
        let r = clipmap::source::CogSource::from_bytes(name, std::sync::Arc::from(bytes.as_slice()), 64);
        // The strips fixture, the 32-bit integers and the index past the end are refused; the
        // others open.
        let refused = matches!(i, 3 | 4 | 6);
        assert_eq!(r.is_err(), refused, "seed {i}: {:?}", r.err().map(|e| e.to_string()));
        exercise_tiff(bytes);
    }
}
