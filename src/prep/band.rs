//! Bands of rows: what a level's producer hands the pipeline, and the pixel encodings every
//! producer shares (8- and 16-bit RGBA into a texel format).
//!
//! The floor under [`super::source`] (procedural sources and decoded images) and
//! [`super::tiff_stream`] (GeoTIFFs read strip by strip), so that neither imports the other's
//! helpers.

use super::error::PrepError;
use crate::texel::{ComponentType, Components, TexelFormat};

/// Produces the rows of one level, band by band, in increasing t.
pub(crate) trait BandSource: Send {
    /// Fills rows `t0 .. t0 + rows` (each `width * bpt` bytes, s fastest) into `out`.
    fn fill(&mut self, t0: u64, rows: usize, out: &mut [u8]) -> Result<(), PrepError>;
}

/// An 8-bit pixel on the 16-bit scale (times 257, exact).
pub fn widen(p: [u8; 4]) -> [u16; 4] {
    p.map(|v| v as u16 * 257)
}

/// Encodes an 8-bit RGBA pixel into `format`.
pub(crate) fn encode_rgba8(format: TexelFormat, p: [u8; 4], out: &mut [u8]) {
    if format == TexelFormat::RGBA8 {
        out.copy_from_slice(&p);
    } else if format == TexelFormat::RGB8 {
        out.copy_from_slice(&p[..3]);
    } else {
        let f = |v: u8| v as f32 / 255.0;
        format.encode([f(p[0]), f(p[1]), f(p[2]), f(p[3])], out);
    }
}

/// One row of pixels into texels of `format` (`row`, one texel a pixel, the rest of `row`
/// left alone): each pixel as RGBA, its samples 16-bit when `deep`, else 8-bit values held in
/// `u16`s; 16-bit ones encoded by [`encode_rgba16`], 8-bit ones by [`encode_rgba8`] (widened
/// for a 16-bit format). The one pixels-to-texels path of the producers that decode rows.
pub(crate) fn encode_row(format: TexelFormat, deep: bool, pixels: impl Iterator<Item = [u16; 4]>, row: &mut [u8]) {
    let bpt = format.bytes_per_texel() as usize;
    for (texel, p) in row.chunks_exact_mut(bpt).zip(pixels) {
        if deep {
            encode_rgba16(format, p, texel);
            continue;
        }
        let p8 = p.map(|v| v as u8);
        if format.ctype == ComponentType::U16 {
            encode_rgba16(format, widen(p8), texel);
        } else {
            encode_rgba8(format, p8, texel);
        }
    }
}

/// Encodes a 16-bit RGBA pixel into `format`: 16-bit formats take the samples as they are,
/// 8-bit formats the samples rounded to nearest (v / 257), packed formats their encoding.
/// One-component formats take the luminance (Rec. 709 weights; a grey pixel's value exactly).
pub(crate) fn encode_rgba16(format: TexelFormat, p: [u16; 4], out: &mut [u8]) {
    let lum = || -> f64 {
        if p[0] == p[1] && p[1] == p[2] {
            p[0] as f64
        } else {
            0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64
        }
    };
    let chans: [f64; 4] = match format.components {
        Components::One => [lum(), 0.0, 0.0, 0.0],
        Components::Two => [lum(), p[3] as f64, 0.0, 0.0],
        Components::Three => [p[0] as f64, p[1] as f64, p[2] as f64, 0.0],
        Components::Four => p.map(|v| v as f64),
    };
    let n = format.components.count() as usize;
    match format.ctype {
        ComponentType::U16 => {
            for (o, c) in out.chunks_exact_mut(2).zip(&chans[..n]) {
                o.copy_from_slice(&(c.round().clamp(0.0, 65535.0) as u16).to_le_bytes());
            }
        }
        ComponentType::U8 => {
            for (o, c) in out.iter_mut().zip(&chans[..n]) {
                *o = (c / 257.0).round().clamp(0.0, 255.0) as u8;
            }
        }
        _ => format.encode(p.map(|v| v as f32 / 65535.0), out),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_row_of_pixels_becomes_texels_by_its_depth_and_the_format() {
        let grey = [[10u16, 10, 10, 255], [200, 200, 200, 255]];
        // 8-bit samples into an 8-bit format: as encode_rgba8 does; the rest of the row untouched.
        let mut row = [9u8; 3];
        encode_row(TexelFormat::L8, false, grey.into_iter(), &mut row);
        assert_eq!(row, [10, 200, 9]);
        // 8-bit samples into a 16-bit format: widened (times 257).
        let mut row = [0u8; 4];
        encode_row(TexelFormat::L16, false, grey.into_iter(), &mut row);
        assert_eq!(row, [(10u16 * 257).to_le_bytes(), (200u16 * 257).to_le_bytes()].concat()[..]);
        // 16-bit samples into an 8-bit format: rounded to nearest (v / 257).
        let mut row = [0u8; 8];
        encode_row(TexelFormat::RGBA8, true, [[257u16, 514, 65535, 0], [128, 129, 0, 65535]].into_iter(), &mut row);
        assert_eq!(row, [1, 2, 255, 0, 0, 1, 0, 255]);
    }
}
