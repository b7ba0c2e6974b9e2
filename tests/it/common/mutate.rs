//! What the fuzz property tests share: the case count (`tiff_fuzz_props.rs`,
//! `patch_fuzz_props.rs`, `config_fuzz_props.rs`) and the byte mutations of a seed (the TIFF and
//! patch tests). Each mutation takes the seed and where to act, so a test's strategy only picks
//! the seed, the mutation and its place, and adds the mutations of its own format.

/// The proptest cases of a fuzz property: `default` (fast in CI), or `CLIPMAP_FUZZ_CASES` for a
/// longer run (how this logic is fuzzed where `cargo fuzz` cannot run, fuzz/README.md).
pub fn cases(default: u32) -> u32 {
    std::env::var("CLIPMAP_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Flips bits in `bytes.len()` bytes of a non-empty `v`, the k-th at `at + k * stride` (wrapping
/// round the end), each by its byte of `bytes` with the lowest bit set, so every byte touched
/// changes.
pub fn flip(v: &mut [u8], at: usize, bytes: &[u8], stride: usize) {
    for (k, b) in bytes.iter().enumerate() {
        let j = (at + k * stride) % v.len();
        v[j] ^= b | 1;
    }
}

/// Inserts `bytes` into `v` before byte `at`.
pub fn insert(v: &mut Vec<u8>, at: usize, bytes: &[u8]) {
    let tail = v.split_off(at);
    v.extend_from_slice(bytes);
    v.extend_from_slice(&tail);
}

/// Overwrites the `width` bytes of `v` from `at` (those inside it) with `word`'s first bytes in
/// little-endian order: an offset, count or size replaced by another value.
pub fn overwrite(v: &mut [u8], at: usize, word: u64, width: usize) {
    for (k, w) in word.to_le_bytes().iter().enumerate().take(width) {
        if let Some(b) = v.get_mut(at + k) {
            *b = *w;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flip_changes_every_byte_it_touches_and_wraps_round_the_end() {
        let mut v = vec![0u8; 10];
        flip(&mut v, 8, &[0, 0xF0, 2], 1);
        assert_eq!(v, [3, 0, 0, 0, 0, 0, 0, 0, 1, 0xF1]);
    }

    #[test]
    fn insert_keeps_both_sides() {
        let mut v = vec![1, 2, 3];
        insert(&mut v, 1, &[9, 9]);
        assert_eq!(v, [1, 9, 9, 2, 3]);
        insert(&mut v, 5, &[7]);
        assert_eq!(v, [1, 9, 9, 2, 3, 7]);
    }

    #[test]
    fn overwrite_writes_little_endian_and_stops_at_the_end() {
        let mut v = vec![0u8; 6];
        overwrite(&mut v, 1, 0x0102_0304, 4);
        assert_eq!(v, [0, 4, 3, 2, 1, 0]);
        overwrite(&mut v, 4, u64::MAX, 8);
        assert_eq!(v, [0, 4, 3, 2, 0xFF, 0xFF]);
    }
}
