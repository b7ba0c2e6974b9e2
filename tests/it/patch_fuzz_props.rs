//! Property tests over hostile patches: a sidecar and a payload (valid PNG, JPEG, TIFF and raw
//! patches, then cut, bit-flipped, with their sidecar's numbers and names mangled, and arbitrary
//! bytes) through everything the service does with a patch before it keeps it
//! (`common/patch_exercise.rs`): nothing may panic, and a cut JPEG or an image outside the
//! sidecar's directory is never taken.
//!
//! The case count is fixed (fast in CI); `CLIPMAP_FUZZ_CASES=N` raises it for a longer run, which
//! is how this logic is fuzzed where `cargo fuzz` cannot run (see fuzz/README.md).

use crate::common::mutate::{cases, flip, insert};
use crate::common::patch_exercise::exercise_patch;
use proptest::prelude::*;
use std::io::Cursor;

fn encoded(format: image::ImageFormat, w: u32, h: u32) -> Vec<u8> {
    let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 7) as u8, (y * 13) as u8, (x ^ y) as u8]));
    let mut out = Cursor::new(Vec::new());
    image::DynamicImage::from(img).write_to(&mut out, format).expect("encode");
    out.into_inner()
}

/// Valid inputs: the format byte (1 = rgb8), a sidecar, a payload.
pub fn seeds() -> Vec<Vec<u8>> {
    let with = |json: &str, payload: &[u8]| {
        let mut v = vec![1u8];
        v.extend_from_slice(json.as_bytes());
        v.push(b'\n');
        v.extend_from_slice(payload);
        v
    };
    let mut out = Vec::new();
    for (f, name) in
        [(image::ImageFormat::Png, "a.png"), (image::ImageFormat::Jpeg, "a.jpg"), (image::ImageFormat::Tiff, "a.tif")]
    {
        let json = format!(r#"{{"bbox": [-4, -3, 12, 9], "time": 3, "rating": 1.5, "image": "{name}"}}"#);
        out.push(with(&json, &encoded(f, 16, 12)));
    }
    let raw: Vec<u8> = (0..4 * 3 * 3).map(|i| i as u8).collect();
    out.push(with(r#"{"bbox": [0, 0, 4, 3], "raw": {"width": 4, "height": 3}}"#, &raw));
    out
}

/// A seed mutated: cut, bytes flipped, a slice repeated, or a sidecar field replaced.
fn mutated() -> impl Strategy<Value = Vec<u8>> {
    let seeds = seeds();
    let n = seeds.len();
    (0..n, 0usize..8, any::<u64>(), proptest::collection::vec(any::<u8>(), 0..8)).prop_map(move |(i, how, r, bytes)| {
        let mut v = seeds[i].clone();
        let at = (r as usize) % v.len().max(1);
        match how {
            0 => v.truncate(at),
            1 => flip(&mut v, at, &bytes, 31),
            2 => insert(&mut v, at, &bytes),
            3 => {
                let s = String::from_utf8_lossy(&v).into_owned();
                let bad = ["\"../a.png\"", "\"/etc/hostname\"", "\"\"", "\".\"", "\"a/../../b\""][(r % 5) as usize];
                let s = s.replacen("\"a.png\"", bad, 1).replacen("\"a.jpg\"", bad, 1);
                v = s.into_bytes();
            }
            4 => {
                let s = String::from_utf8_lossy(&v).into_owned();
                let big = ["4294967295", "1e308", "-1e308", "0", "65537", "18446744073709551615"][(r % 6) as usize];
                v = s.replacen("16", big, 1).replacen("\"width\": 4", &format!("\"width\": {big}"), 1).into_bytes();
            }
            5 => v[0] = r as u8,
            6 => {
                // A JPEG's last bytes (its EOI marker) dropped.
                let cut = (r % 4) as usize + 1;
                v.truncate(v.len().saturating_sub(cut));
            }
            _ => v.extend_from_slice(&bytes),
        }
        v
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(300), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_patches_never_panic(data in proptest::collection::vec(any::<u8>(), 0..2048)) {
        let dir = tempfile::tempdir().unwrap();
        exercise_patch(&data, dir.path());
    }

    #[test]
    fn mutated_patches_never_panic_and_cut_jpegs_are_never_taken(data in mutated()) {
        let dir = tempfile::tempdir().unwrap();
        exercise_patch(&data, dir.path());
    }
}

#[test]
fn the_seeds_are_taken_whole() {
    let grid = clipmap::growing::Grid::new([0.0, 0.0], 1.0, 16, 3, 1).unwrap();
    for s in seeds() {
        let rest = &s[1..];
        let cut = rest.iter().position(|&b| b == b'\n').unwrap();
        let d = clipmap::growing::input::sidecar(&rest[..cut], "seed").unwrap();
        clipmap::growing::input::new_patch(&grid, &d, rest[cut + 1..].to_vec(), 1 << 20, "seed").unwrap();
    }
}
