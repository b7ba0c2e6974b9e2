//! PNG tiles decoded straight into their slot, and the check that a PNG is whole.
//!
//! The pyramid's texels of a PNG tile are RGBA8 in texture orientation (rows from the south).
//! A plain PNG (8 bits a sample, RGBA or RGB without a `tRNS` chunk, not interlaced: what
//! `gdal2tiles.py`, GDAL's MBTiles driver and most tile services write) is decoded by `zune-png`
//! into the slot the texels are published from, then its rows are turned over in place: no
//! buffer of its own, no copy of the whole tile. Any other PNG (palette, grey, 16 bits, `tRNS`,
//! interlaced) goes through the `image` crate's decoder, as before, which expands it to RGBA.
//!
//! Why `zune-png`: decoding the 256² RGBA tiles of `clipbench tiles` (gdal2tiles.py's, about
//! 55 to 65 KB each) costs a thread about 460 µs of CPU a tile with it (500 µs with its CRC
//! and Adler-32 checks on, as here), about 515 µs with the `png` crate decoding row by row into
//! the slot, and about 650 µs through `image::load_from_memory` plus the RGBA conversion (the
//! decoder used before); turning the rows over costs about 5 µs. docs/TILES.md gives the
//! measurement.
//!
//! Before a byte is inflated, [`png_chunks`] walks the PNG's chunks: each must lie within the
//! answer and the last must be `IEND`, so an answer cut short (a reset, a truncated file served
//! whole) is refused, never decoded with its missing part filled in; the decoder then checks every
//! chunk's CRC and the image data's Adler-32, so damaged bytes are refused too.

use zune_png::zune_core::bytestream::ZCursor;
use zune_png::zune_core::options::DecoderOptions;
use zune_png::PngDecoder;

/// What [`png_chunks`] read from a whole PNG's header chunk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct PngHeader {
    pub width: u32,
    pub height: u32,
    /// Whether `zune-png` decodes it straight into an RGBA8 slot: 8 bits a sample, RGBA or RGB
    /// (colour types 6 and 2), no `tRNS` chunk, not interlaced.
    pub plain: bool,
}

const SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A];

/// Walks the chunks of `bytes`: the signature, then `IHDR` first, every chunk within the bytes,
/// up to `IEND`. Says what is wrong (where, what was found, what was expected) otherwise.
pub(crate) fn png_chunks(bytes: &[u8]) -> Result<PngHeader, String> {
    if bytes.len() < 8 || bytes[..8] != SIGNATURE {
        return Err("the PNG signature is missing".into());
    }
    let mut at = 8usize;
    let mut header: Option<(u32, u32, u8, u8, u8)> = None;
    let mut trns = false;
    loop {
        let Some(head) = bytes.get(at..at + 8) else {
            return Err(format!(
                "the PNG of {} bytes ends at byte {at} without its IEND chunk: it was cut short",
                bytes.len()
            ));
        };
        let len = u32::from_be_bytes([head[0], head[1], head[2], head[3]]) as usize;
        let kind = [head[4], head[5], head[6], head[7]];
        let end = at.saturating_add(12).saturating_add(len);
        if end > bytes.len() {
            return Err(format!(
                "the PNG's {} chunk at byte {at} says {len} bytes, and the answer ends {} bytes later: it was cut short",
                String::from_utf8_lossy(&kind),
                bytes.len() - at
            ));
        }
        let data = &bytes[at + 8..at + 8 + len];
        match &kind {
            b"IHDR" if header.is_none() && len == 13 => {
                let w = u32::from_be_bytes([data[0], data[1], data[2], data[3]]);
                let h = u32::from_be_bytes([data[4], data[5], data[6], data[7]]);
                header = Some((w, h, data[8], data[9], data[12]));
            }
            _ if header.is_none() => {
                return Err(format!(
                    "the PNG's first chunk is {} of {len} bytes: expected IHDR of 13 bytes",
                    String::from_utf8_lossy(&kind)
                ))
            }
            b"tRNS" => trns = true,
            b"IEND" => break,
            _ => {}
        }
        at = end;
    }
    let (width, height, depth, colour, interlace) = header.expect("IHDR was read before IEND");
    Ok(PngHeader { width, height, plain: depth == 8 && (colour == 6 || colour == 2) && !trns && interlace == 0 })
}

/// Decodes a plain PNG (see [`PngHeader::plain`]) of `side`² texels into `out` (`side`² RGBA8
/// texels), rows from the south. `out` is left zero when it fails.
pub(crate) fn png_into_slot(bytes: &[u8], side: usize, out: &mut [u8]) -> Result<(), String> {
    let row = 4 * side;
    debug_assert_eq!(out.len(), row * side);
    let options = DecoderOptions::default()
        .png_set_confirm_crc(true)
        .inflate_set_confirm_adler(true)
        .png_set_add_alpha_channel(true)
        .set_max_width(side)
        .set_max_height(side);
    let mut decoder = PngDecoder::new_with_options(ZCursor::new(bytes), options);
    let decoded = decoder.decode_headers().map_err(|e| e.to_string()).and_then(|()| {
        match (decoder.dimensions(), decoder.output_buffer_size()) {
            (Some((w, h)), Some(n)) if w == side && h == side && n == out.len() => {
                decoder.decode_into(out).map_err(|e| e.to_string())
            }
            (dims, n) => {
                Err(format!("the decoder makes {n:?} bytes of {dims:?} texels: expected {} RGBA texels", side * side))
            }
        }
    });
    if let Err(e) = decoded {
        out.fill(0);
        return Err(e.trim_end().to_string());
    }
    flip_rows(out, row);
    Ok(())
}

/// Turns the rows of `img` (rows of `row` bytes) over in place.
pub(crate) fn flip_rows(img: &mut [u8], row: usize) {
    let rows = img.len() / row;
    for r in 0..rows / 2 {
        let (top, bottom) = img.split_at_mut((rows - 1 - r) * row);
        top[r * row..(r + 1) * row].swap_with_slice(&mut bottom[..row]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{ImageEncoder, ImageFormat};

    fn encode(w: u32, h: u32, colour: image::ExtendedColorType, raw: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        image::codecs::png::PngEncoder::new(&mut out).write_image(raw, w, h, colour).expect("encodes");
        out
    }

    /// The `image` crate's RGBA decode, rows from the south: what the slow path publishes.
    fn by_image(bytes: &[u8]) -> Vec<u8> {
        let img = image::load_from_memory_with_format(bytes, ImageFormat::Png).expect("decodes").into_rgba8();
        let row = 4 * img.width() as usize;
        let mut raw = img.into_raw();
        flip_rows(&mut raw, row);
        raw
    }

    fn texels(n: usize, bpt: usize) -> Vec<u8> {
        (0..n * n * bpt).map(|i| ((i * 7919) ^ (i >> 5)) as u8).collect()
    }

    #[test]
    fn rgba_and_rgb_pngs_decode_into_the_slot_as_the_image_crate_decodes_them() {
        for (colour, bpt) in [(image::ExtendedColorType::Rgba8, 4), (image::ExtendedColorType::Rgb8, 3)] {
            let png = encode(64, 64, colour, &texels(64, bpt));
            let head = png_chunks(&png).expect("whole");
            assert_eq!(head, PngHeader { width: 64, height: 64, plain: true });
            let mut out = vec![7u8; 64 * 64 * 4];
            png_into_slot(&png, 64, &mut out).expect("decodes");
            assert_eq!(out, by_image(&png), "{colour:?}");
        }
    }

    #[test]
    fn grey_palette_and_sixteen_bit_pngs_are_not_plain() {
        for (colour, bpt) in [
            (image::ExtendedColorType::L8, 1),
            (image::ExtendedColorType::La8, 2),
            (image::ExtendedColorType::Rgba16, 8),
        ] {
            let png = encode(16, 16, colour, &texels(16, bpt));
            assert!(!png_chunks(&png).expect("whole").plain, "{colour:?}");
        }
        // An RGB PNG with a tRNS chunk (one colour transparent) is left to the image crate.
        let mut png = encode(4, 4, image::ExtendedColorType::Rgb8, &texels(4, 3));
        let iend = png.len() - 12;
        let trns = [0u8, 0, 0, 6, b't', b'R', b'N', b'S', 0, 1, 0, 2, 0, 3, 0, 0, 0, 0];
        png.splice(iend..iend, trns);
        assert!(!png_chunks(&png).expect("whole").plain);
    }

    #[test]
    fn a_png_cut_anywhere_is_refused_before_it_is_decoded() {
        let png = encode(32, 32, image::ExtendedColorType::Rgba8, &texels(32, 4));
        for cut in [0, 7, 8, 20, 33, png.len() / 2, png.len() - 12, png.len() - 1] {
            let e = png_chunks(&png[..cut]).expect_err("cut");
            assert!(e.contains("cut short") || e.contains("signature"), "cut at {cut}: {e}");
        }
        // Trailing bytes after IEND are no harm.
        let mut more = png.clone();
        more.extend_from_slice(&[0, 0, 0]);
        assert!(png_chunks(&more).is_ok());
    }

    #[test]
    fn a_damaged_png_is_an_error_and_leaves_the_slot_zero() {
        let png = encode(32, 32, image::ExtendedColorType::Rgba8, &texels(32, 4));
        // A byte of the image data changed: the IDAT chunk's CRC no longer matches.
        let idat = png.windows(4).position(|w| w == b"IDAT").expect("an IDAT chunk") + 10;
        let mut bad = png.clone();
        bad[idat] ^= 0x55;
        assert!(png_chunks(&bad).is_ok(), "the chunks are whole");
        let mut out = vec![9u8; 32 * 32 * 4];
        assert!(png_into_slot(&bad, 32, &mut out).is_err());
        assert!(out.iter().all(|&b| b == 0));
        // Another size than the slot's.
        assert!(png_into_slot(&png, 16, &mut vec![0u8; 16 * 16 * 4]).is_err());
    }

    #[test]
    fn flip_rows_turns_odd_and_even_row_counts_over() {
        let mut a = vec![1, 1, 2, 2, 3, 3];
        flip_rows(&mut a, 2);
        assert_eq!(a, [3, 3, 2, 2, 1, 1]);
        let mut b = vec![1, 2, 3, 4];
        flip_rows(&mut b, 1);
        assert_eq!(b, [4, 3, 2, 1]);
    }
}
