//! Decoding of the block-compressed formats (`bc1`, `bc4`, `bc5`, `bc7`; docs/SHM.md,
//! "Block-compressed formats"), for checks and for renderers without the GPU formats.
//!
//! Decodes with `bcdec_rs`, a port of the public-domain `bcdec`: a decoder independent of the
//! encoder the service uses (ISPC's kernels through `intel_tex_2`), so a test that compares the
//! two checks one against the other rather than the encoder against itself.

use clipmap_base::texel::Bc;

/// Bytes a decoded texel of `bc` takes: 4 (RGBA8) for `bc1` and `bc7`, 1 for `bc4`, 2 for `bc5`.
pub fn decoded_bytes(bc: Bc) -> usize {
    match bc {
        Bc::Bc1 | Bc::Bc7 => 4,
        Bc::Bc4 => 1,
        Bc::Bc5 => 2,
    }
}

/// Decodes `blocks`, a `w` x `h`-texel tile stored as `ceil(w / 4)` x `ceil(h / 4)` blocks in
/// rows, into `w * h` texels of [`decoded_bytes`] each (rows in increasing t, s fastest); the
/// texels of a partial block beyond `w` or `h` are dropped. `Err` when `blocks` is not that many
/// blocks long.
pub fn decode(bc: Bc, blocks: &[u8], w: u64, h: u64) -> Result<Vec<u8>, String> {
    let (bw, bh) = (w.div_ceil(4) as usize, h.div_ceil(4) as usize);
    let bb = bc.block_bytes() as usize;
    if blocks.len() != bw * bh * bb {
        return Err(format!(
            "{} bytes of {} blocks for a {w}x{h} tile: expected {bw}x{bh} blocks of {bb} bytes ({})",
            blocks.len(),
            bc.name(),
            bw * bh * bb
        ));
    }
    let px = decoded_bytes(bc);
    // Decoded whole blocks first (a padded image), then cropped to w x h.
    let pitch = bw * 4 * px;
    let mut padded = vec![0u8; pitch * bh * 4];
    for (i, b) in blocks.chunks_exact(bb).enumerate() {
        let (x, y) = (i % bw, i / bw);
        let at = &mut padded[y * 4 * pitch + x * 4 * px..];
        match bc {
            Bc::Bc1 => bcdec_rs::bc1(b, at, pitch),
            Bc::Bc4 => bcdec_rs::bc4(b, at, pitch, false),
            Bc::Bc5 => bcdec_rs::bc5(b, at, pitch, false),
            Bc::Bc7 => bcdec_rs::bc7(b, at, pitch),
        }
    }
    let (w, h) = (w as usize, h as usize);
    let mut out = Vec::with_capacity(w * h * px);
    for row in padded.chunks_exact(pitch).take(h) {
        out.extend_from_slice(&row[..w * px]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bc4_block_decodes_by_its_palette_and_partial_blocks_are_cropped() {
        // Endpoints 200 and 100 (first > second: eight-value palette), every index 0 but texel
        // (1, 0) index 1: 200 everywhere and 100 at (1, 0).
        let mut block = [200u8, 100, 0, 0, 0, 0, 0, 0];
        block[2] = 1 << 3;
        let out = decode(Bc::Bc4, &block, 4, 4).unwrap();
        assert_eq!(out.len(), 16);
        assert_eq!((out[0], out[1], out[2], out[15]), (200, 100, 200, 200));
        // A 5 x 3 tile: 2 x 1 blocks, 15 texels back.
        let two = [block, [50, 50, 0, 0, 0, 0, 0, 0]].concat();
        let out = decode(Bc::Bc4, &two, 5, 3).unwrap();
        assert_eq!(out.len(), 15);
        assert_eq!((out[1], out[4], out[5 + 4]), (100, 50, 50));
        let e = decode(Bc::Bc4, &two, 9, 3).unwrap_err();
        assert!(e.contains("expected 3x1 blocks of 8 bytes"), "{e}");
    }

    #[test]
    fn a_bc1_block_of_one_colour_decodes_to_it_opaque() {
        // Both endpoints pure red in 5:6:5 (0xf800), indices 0: red, alpha 255.
        let block = [0x00, 0xf8, 0x00, 0xf8, 0, 0, 0, 0];
        let out = decode(Bc::Bc1, &block, 4, 4).unwrap();
        assert!(out.chunks_exact(4).all(|p| p == [255, 0, 0, 255]), "{out:?}");
    }
}
