//! A JPEG checked whole before it is decoded: the decoder fills what a truncated file lacks with
//! grey and reports success, so a truncated or cut-short JPEG would become a pyramid that is
//! mostly flat. [`check`] walks the marker segments from SOI to EOI (entropy-coded scans
//! included, as many as a progressive file has) and says where the file ends early.
//!
//! Owns the structure walk only; decoding is the `image` crate's.

/// What is wrong with a JPEG's structure.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum JpegDefect {
    /// The first two bytes are not FF D8.
    #[error("it does not start with a JPEG SOI marker")]
    NoStart,
    /// The file stops inside something.
    #[error("the file ends early ({what} at byte {at} of {len}); no EOI marker")]
    EndsEarly {
        /// Where it stops.
        what: String,
        /// The offset.
        at: usize,
        /// The file's length.
        len: usize,
    },
    /// A byte that should begin a marker does not.
    #[error("byte {at} is 0x{byte:02X} where a marker was expected")]
    NotAMarker {
        /// The offset.
        at: usize,
        /// The byte found.
        byte: u8,
    },
}

/// Checks that `bytes` (a whole file starting with the JPEG SOI marker) runs from SOI through
/// complete segments and scans to an EOI marker. The error says what was cut short.
pub fn check(bytes: &[u8]) -> Result<(), JpegDefect> {
    let n = bytes.len();
    if n < 4 || bytes[0] != 0xFF || bytes[1] != 0xD8 {
        return Err(JpegDefect::NoStart);
    }
    let cut = |what: &str, at: usize| Err(JpegDefect::EndsEarly { what: what.to_string(), at, len: n });
    let mut pos = 2;
    loop {
        // Markers may be preceded by fill bytes 0xFF.
        if pos >= n {
            return cut("before a marker", pos);
        }
        if bytes[pos] != 0xFF {
            return Err(JpegDefect::NotAMarker { at: pos, byte: bytes[pos] });
        }
        while pos < n && bytes[pos] == 0xFF {
            pos += 1;
        }
        if pos >= n {
            return cut("in a marker", pos);
        }
        let marker = bytes[pos];
        pos += 1;
        match marker {
            0xD9 => return Ok(()),
            0x01 | 0xD0..=0xD7 => continue,
            _ => {}
        }
        if pos + 2 > n {
            return cut("in a segment length", pos);
        }
        let len = u16::from_be_bytes([bytes[pos], bytes[pos + 1]]) as usize;
        if len < 2 || pos + len > n {
            return cut(&format!("in a segment of {len} bytes (marker 0x{marker:02X})"), pos);
        }
        pos += len;
        if marker == 0xDA {
            // Entropy-coded data: runs until a marker other than a stuffed 0xFF00 or a restart.
            loop {
                if pos + 1 >= n {
                    return cut("in the entropy-coded data of a scan", pos);
                }
                if bytes[pos] == 0xFF && !matches!(bytes[pos + 1], 0x00 | 0xD0..=0xD7 | 0xFF) {
                    break;
                }
                pos += 1;
            }
        }
    }
}

/// Whether `head` (the first bytes of a file) is a JPEG's.
pub fn is_jpeg(head: &[u8]) -> bool {
    head.starts_with(&[0xFF, 0xD8, 0xFF])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn jpeg() -> Vec<u8> {
        let img = image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([x as u8 * 3, y as u8 * 5, (x ^ y) as u8]));
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
        out.into_inner()
    }

    #[test]
    fn a_whole_jpeg_passes_and_every_cut_is_refused() {
        let j = jpeg();
        check(&j).unwrap();
        let mut tail = j.clone();
        tail.extend_from_slice(b"trailing bytes after EOI are ignored");
        check(&tail).unwrap();
        for cut in [4, 20, j.len() / 2, j.len() - 2, j.len() - 1] {
            let e = check(&j[..cut]).unwrap_err();
            assert!(matches!(e, JpegDefect::EndsEarly { len, .. } if len == cut), "cut at {cut}: {e}");
            assert!(e.to_string().contains("ends early"), "cut at {cut}: {e}");
        }
    }
}
