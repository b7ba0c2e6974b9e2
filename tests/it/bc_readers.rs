//! The C and Python readers' block decoders on blocks made to exercise them (docs/SHM.md,
//! "Block-compressed formats"): Python's BC7 decoder on blocks of every one of BC7's eight modes
//! (and the reserved one), random past the mode bits, equals `bcdec_rs`'s (the Rust client's
//! decoder) bit for bit, as BC7 decoding is exact; the C reader's BC1, BC4 and BC5 decoders equal
//! it on random blocks of both palettes, and its BC7 decoder on blocks of every mode, partial
//! blocks cropped.

use crate::bc_formats::{hex, python, unhex};
use clipmap::shm::blocks;
use clipmap::texel::Bc;

/// `n` bytes of splitmix64 noise from `seed`.
fn noise(seed: u64, n: usize) -> Vec<u8> {
    let mut x = seed;
    (0..n.div_ceil(8))
        .flat_map(|_| {
            x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = x;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            (z ^ (z >> 31)).to_le_bytes()
        })
        .take(n)
        .collect()
}

#[test]
fn python_decodes_bc7_blocks_of_all_eight_modes_as_bcdec_does_bit_for_bit() {
    // 48 blocks a mode: random bits with the mode's unary prefix (mode m: m zero bits, then a
    // one), and one reserved block (no mode bit: transparent black), as one 4 x 4-block tile a mode.
    let tiles: Vec<Vec<u8>> = (0..=8u32).map(|mode| bc7_blocks_of_mode(mode, u64::from(mode) + 1, 48)).collect();
    // Each mode's 48 blocks as a tile of 8 x 6 blocks (32 x 24 texels), and as one of 30 x 21
    // texels (a partial last column and row of blocks).
    let script: String = tiles
        .iter()
        .flat_map(|b| {
            [
                format!("print(c.decode_blocks(23, bytes.fromhex('{}'), 32, 24).hex())\n", hex(b)),
                format!("print(c.decode_blocks(23, bytes.fromhex('{}'), 30, 21).hex())\n", hex(b)),
            ]
        })
        .collect();
    let text = python(&script);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2 * tiles.len());
    for (mode, b) in tiles.iter().enumerate() {
        for (i, [w, h]) in [[32, 24], [30, 21]].into_iter().enumerate() {
            let want = blocks::decode(Bc::Bc7, b, w, h).unwrap();
            let got = unhex(lines[2 * mode + i]);
            let first = got.iter().zip(&want).position(|(a, b)| a != b);
            assert!(got == want, "mode {mode}, {w}x{h}: Python differs from bcdec at byte {first:?}");
            if mode == 8 {
                assert!(got.iter().all(|&v| v == 0), "the reserved mode decodes to transparent black");
            }
        }
    }
    // A check that can fail: the modes give different texels from the same random bits.
    assert_ne!(lines[0], lines[2 * 6]);
}

/// `blocks` BC7 blocks of `mode` (0 to 7; 8: the reserved mode, no mode bit) from `seed`: random
/// bits behind the mode's unary prefix (mode m: m zero bits, then a one).
fn bc7_blocks_of_mode(mode: u32, seed: u64, blocks: usize) -> Vec<u8> {
    let mut b = noise(seed, blocks * 16);
    for block in b.chunks_exact_mut(16) {
        let low = u16::from_le_bytes([block[0], block[1]]);
        let prefix = if mode == 8 { 0 } else { 1u16 << mode };
        let v = (low & !((1u16 << (mode + 1)) - 1)) | prefix;
        block[..2].copy_from_slice(&v.to_le_bytes());
    }
    b
}

/// Compiles, in `dir`, a small program over the C header's decoder: it reads lines of FORMAT W H
/// and the hex blocks on stdin, and writes each tile's texels as hex, a line each (exit 4: the
/// decoder refused the blocks; 5: it took a wrong length; 6: it did not refuse a texel format).
fn c_decoder(dir: &std::path::Path) -> std::path::PathBuf {
    let src = dir.join("decode.c");
    std::fs::write(
        &src,
        r#"#include "clipmap_shm.h"
#include <stdlib.h>
int main(void) {
    unsigned code, w, h;
    while (scanf("%u %u %u", &code, &w, &h) == 3) {
        size_t len = (size_t)((w + 3) / 4) * ((h + 3) / 4) * clipmap_format_bytes(code);
        unsigned char *b = malloc(len), *out = malloc((size_t)w * h * 4 + 1);
        for (size_t i = 0; i < len; i++) if (scanf("%2hhx", &b[i]) != 1) return 3;
        if (clipmap_decode_blocks(code, b, len, w, h, out) != CLIPMAP_OK) return 4;
        for (size_t i = 0; i < (size_t)w * h * clipmap_decoded_bytes(code); i++) printf("%02x", out[i]);
        printf("\n");
        if (clipmap_decode_blocks(code, b, len + 1, w, h, out) != CLIPMAP_NOT_VALID) return 5;
        free(b);
        free(out);
    }
    unsigned char texel[4] = {0, 0, 0, 0}, out[4];
    return clipmap_decoded_bytes(CLIPMAP_FORMAT_RGBA8) == 0 &&
                   clipmap_decode_blocks(CLIPMAP_FORMAT_RGBA8, texel, 4, 1, 1, out) == CLIPMAP_NOT_VALID
               ? 0
               : 6;
}
"#,
    )
    .unwrap();
    let exe = dir.join("decode");
    let cc = std::process::Command::new("cc")
        .args(["-O2", "-Wall", "-Werror", "-std=c99", "-I"])
        .arg(std::path::Path::new(crate::clipmapd::ROOT).join("include"))
        .arg(&src)
        .arg("-o")
        .arg(&exe)
        .output()
        .expect("a C compiler (`cc`) is needed");
    assert!(cc.status.success(), "cc: {}", String::from_utf8_lossy(&cc.stderr));
    exe
}

/// Runs the program `c_decoder` built on `input`; its lines.
fn c_decode(exe: &std::path::Path, input: &str) -> Vec<String> {
    let mut child = std::process::Command::new(exe)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::Write;
    child.stdin.take().unwrap().write_all(input.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "the C decoder exited {:?}", out.status);
    String::from_utf8(out.stdout).unwrap().lines().map(str::to_owned).collect()
}

#[test]
fn the_c_reader_decodes_bc1_bc4_and_bc5_as_bcdec_does_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let exe = c_decoder(dir.path());
    // Random blocks: half of them with endpoint 0 above endpoint 1 (BC1's four colours, BC4's
    // eight values), half below (BC1's three and transparent black, BC4's six and 0, 255).
    let mut input = String::new();
    let mut cases = Vec::new();
    for (i, (bc, code)) in [(Bc::Bc1, 20), (Bc::Bc4, 21), (Bc::Bc5, 22)].into_iter().enumerate() {
        for [w, h] in [[16u64, 16u64], [7, 5], [1, 1]] {
            let n = (w.div_ceil(4) * h.div_ceil(4)) as usize * bc.block_bytes() as usize;
            let mut b = noise(100 + i as u64 * 10 + w, n);
            for (j, block) in b.chunks_exact_mut(8).enumerate() {
                if bc == Bc::Bc1 {
                    let c = [u16::from_le_bytes([block[0], block[1]]), u16::from_le_bytes([block[2], block[3]])];
                    let (lo, hi) = (c[0].min(c[1]), c[0].max(c[1]));
                    let (c0, c1) = if j % 2 == 0 { (hi, lo) } else { (lo, hi) };
                    block[..2].copy_from_slice(&c0.to_le_bytes());
                    block[2..4].copy_from_slice(&c1.to_le_bytes());
                } else {
                    let (lo, hi) = (block[0].min(block[1]), block[0].max(block[1]));
                    block[..2].copy_from_slice(&if j % 2 == 0 { [hi, lo] } else { [lo, hi] });
                }
            }
            input += &format!("{code} {w} {h} {}\n", hex(&b));
            cases.push((bc, w, h, b));
        }
    }
    let lines = c_decode(&exe, &input);
    assert_eq!(lines.len(), cases.len());
    for ((bc, w, h, b), line) in cases.iter().zip(lines) {
        let want = blocks::decode(*bc, b, *w, *h).unwrap();
        assert!(unhex(&line) == want, "{bc:?} {w}x{h}: the C decoder differs from bcdec");
    }
}

#[test]
fn the_c_reader_decodes_bc7_blocks_of_all_eight_modes_as_bcdec_does_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let exe = c_decoder(dir.path());
    // 96 blocks a mode and 96 of the reserved mode (transparent black), each set as a tile of 8 x
    // 12 blocks (32 x 48 texels) and as one of 30 x 45 texels (a partial last column and row of
    // blocks); one block alone as a 1 x 1 tile.
    let tiles: Vec<Vec<u8>> = (0..=8u32).map(|mode| bc7_blocks_of_mode(mode, 200 + u64::from(mode), 96)).collect();
    let sizes = [[32u64, 48u64], [30, 45]];
    let mut input = String::new();
    for b in &tiles {
        for [w, h] in sizes {
            input += &format!("23 {w} {h} {}\n", hex(b));
        }
        input += &format!("23 1 1 {}\n", hex(&b[..16]));
    }
    let lines = c_decode(&exe, &input);
    assert_eq!(lines.len(), 3 * tiles.len());
    for (mode, b) in tiles.iter().enumerate() {
        for (i, (w, h, b)) in [(32, 48, &b[..]), (30, 45, &b[..]), (1, 1, &b[..16])].into_iter().enumerate() {
            let want = blocks::decode(Bc::Bc7, b, w, h).unwrap();
            let got = unhex(&lines[3 * mode + i]);
            let first = got.iter().zip(&want).position(|(a, b)| a != b);
            assert!(got == want, "mode {mode}, {w}x{h}: the C decoder differs from bcdec at byte {first:?}");
            if mode == 8 {
                assert!(got.iter().all(|&v| v == 0), "the reserved mode decodes to transparent black");
            }
        }
    }
    // A check that can fail: every mode but the reserved one gives texels other than transparent
    // black.
    for (mode, line) in lines.iter().step_by(3).take(8).enumerate() {
        assert!(unhex(line).iter().any(|&v| v != 0), "mode {mode} decoded to transparent black");
    }
}
