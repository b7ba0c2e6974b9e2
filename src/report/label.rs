//! Text on pictures: labels, captions and legends, so that a picture says what it shows (which
//! level, what the outlines mean, which moment) without anyone explaining it.
//!
//! Drawn with the public-domain 8x8 bitmap font of the `font8x8` crate, scaled by whole pixels;
//! characters the font lacks are drawn as `?`. Owns nothing but putting text and swatches on an
//! [`RgbImage`].

use font8x8::UnicodeFonts;
use image::{Rgb, RgbImage};

/// Height of one line of text at `scale`, with a pixel of spacing per scale step above and below.
pub fn line_height(scale: u32) -> u32 {
    10 * scale
}

/// Width `text` takes at `scale`.
pub(crate) fn text_width(text: &str, scale: u32) -> u32 {
    text.chars().count() as u32 * 8 * scale
}

/// Draws `text` with its top-left corner at (x, y); pixels outside the image are skipped.
/// Returns the x just after the text.
pub fn text(img: &mut RgbImage, x: u32, y: u32, text: &str, colour: [u8; 3], scale: u32) -> u32 {
    let scale = scale.max(1);
    let mut cx = x;
    for ch in text.chars() {
        let glyph = font8x8::BASIC_FONTS.get(ch).or_else(|| font8x8::BASIC_FONTS.get('?')).unwrap_or([0; 8]);
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8u32 {
                if bits >> col & 1 == 1 {
                    fill(img, cx + col * scale, y + row as u32 * scale, scale, scale, colour);
                }
            }
        }
        cx += 8 * scale;
    }
    cx
}

/// Fills a rectangle, clipped to the image.
pub fn fill(img: &mut RgbImage, x: u32, y: u32, w: u32, h: u32, colour: [u8; 3]) {
    for py in y..(y + h).min(img.height()) {
        for px in x..(x + w).min(img.width()) {
            img.put_pixel(px, py, Rgb(colour));
        }
    }
}

/// A copy of `img` with `lines` of caption above it (white on the picture's dark background),
/// at least `min_width` pixels wide; lines longer than the width are wrapped at spaces.
pub fn captioned(img: &RgbImage, lines: &[String], min_width: u32) -> RgbImage {
    let scale = 1;
    let pad = 6;
    let width = img.width().max(min_width).max(160);
    let lines = wrap(lines, ((width - 2 * pad) / (8 * scale)) as usize);
    let top = lines.len() as u32 * line_height(scale) + pad;
    let mut out = RgbImage::from_pixel(width, img.height() + top, Rgb(BACKGROUND));
    for (i, l) in lines.iter().enumerate() {
        text(&mut out, pad, pad / 2 + i as u32 * line_height(scale) + scale, l, [235, 235, 235], scale);
    }
    image::imageops::replace(&mut out, img, 0, top as i64);
    out
}

/// `lines` broken at spaces so that none is longer than `columns` characters (a word longer than
/// that stands on its own line).
fn wrap(lines: &[String], columns: usize) -> Vec<String> {
    let mut out = Vec::new();
    for line in lines {
        let mut cur = String::new();
        for word in line.split(' ') {
            if !cur.is_empty() && cur.chars().count() + 1 + word.chars().count() > columns {
                out.push(std::mem::take(&mut cur));
            }
            if !cur.is_empty() {
                cur.push(' ');
            }
            cur.push_str(word);
        }
        out.push(cur);
    }
    out
}

/// A legend row under `img`: one swatch and its meaning per entry, wrapped onto as many rows as
/// the width needs.
pub fn with_legend(img: &RgbImage, entries: &[(Swatch, String)]) -> RgbImage {
    let scale = 1;
    let pad = 6;
    let lh = line_height(scale) + 4;
    // Lay the entries out left to right, wrapping at the picture's width.
    let width = img.width().max(240);
    let mut places = Vec::with_capacity(entries.len());
    let (mut x, mut row) = (pad, 0u32);
    for (_, label) in entries {
        let w = 12 + 4 + text_width(label, scale) + 14;
        if x + w > width && x > pad {
            x = pad;
            row += 1;
        }
        places.push((x, row));
        x += w;
    }
    let rows = if entries.is_empty() { 0 } else { row + 1 };
    let mut out = RgbImage::from_pixel(width, img.height() + rows * lh + pad, Rgb(BACKGROUND));
    image::imageops::replace(&mut out, img, 0, 0);
    for ((swatch, label), (x, row)) in entries.iter().zip(places) {
        let y = img.height() + pad / 2 + row * lh;
        swatch.draw(&mut out, x, y + 1, 12);
        text(&mut out, x + 16, y + 3, label, [220, 220, 220], scale);
    }
    out
}

/// The dark grey behind captions and legends.
pub const BACKGROUND: [u8; 3] = [24, 24, 24];

/// How a legend entry's sample looks.
#[derive(Clone, Copy, Debug)]
pub enum Swatch {
    /// A filled square.
    Solid([u8; 3]),
    /// A square outlined in this colour (an outline in the picture).
    Outline([u8; 3]),
    /// The two-grey checkerboard of the invalid border and of texels not yet loaded.
    Checker,
}

impl Swatch {
    fn draw(self, img: &mut RgbImage, x: u32, y: u32, size: u32) {
        match self {
            Swatch::Solid(c) => fill(img, x, y, size, size, c),
            Swatch::Outline(c) => {
                fill(img, x, y, size, size, [40, 40, 40]);
                fill(img, x, y, size, 2, c);
                fill(img, x, y + size - 2, size, 2, c);
                fill(img, x, y, 2, size, c);
                fill(img, x + size - 2, y, 2, size, c);
            }
            Swatch::Checker => {
                for j in 0..size {
                    for i in 0..size {
                        let c = if (i / 4 + j / 4) % 2 == 0 { [60, 60, 60] } else { [80, 80, 80] };
                        fill(img, x + i, y + j, 1, 1, c);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_sets_the_glyph_pixels_and_nothing_beyond_its_box() {
        let mut img = RgbImage::new(40, 12);
        let end = text(&mut img, 2, 1, "L1", [255, 0, 0], 1);
        assert_eq!(end, 18);
        let lit: Vec<(u32, u32)> =
            img.enumerate_pixels().filter(|(_, _, p)| p.0 == [255, 0, 0]).map(|(x, y, _)| (x, y)).collect();
        assert!(lit.len() > 10, "both glyphs drawn: {lit:?}");
        assert!(lit.iter().all(|&(x, y)| (2..18).contains(&x) && (1..9).contains(&y)), "{lit:?}");
        // 'L' is a vertical stroke with a foot: its first column has more lit pixels than its last.
        let col = |c: u32| lit.iter().filter(|&&(x, _)| x == c).count();
        assert!((2..5).map(col).max() > (7..10).map(col).max());
    }

    #[test]
    fn a_caption_and_a_legend_grow_the_picture_and_keep_it_intact() {
        let mut img = RgbImage::new(50, 20);
        img.put_pixel(3, 4, Rgb([1, 2, 3]));
        let c = captioned(&img, &["level 0".into(), "min LOD 0.00".into()], 0);
        let top = c.height() - 20;
        assert!(top >= 2 * line_height(1));
        assert!(c.width() >= text_width("min LOD 0.00", 1));
        // A long line wraps at spaces to the picture's width instead of widening it.
        let long = "word ".repeat(60);
        let w = captioned(&RgbImage::new(200, 10), &[long], 0);
        assert_eq!(w.width(), 200);
        assert!(w.height() >= 10 + 5 * line_height(1), "wrapped onto several lines");
        assert_eq!(wrap(&["aa bb cc".into()], 5), ["aa bb", "cc"]);
        assert_eq!(c.get_pixel(3, top + 4).0, [1, 2, 3], "the picture sits under the caption");
        let l =
            with_legend(&c, &[(Swatch::Outline([255, 0, 0]), "valid region".into()), (Swatch::Checker, "x".into())]);
        assert!(l.height() > c.height());
        assert_eq!(l.get_pixel(3, top + 4).0, [1, 2, 3]);
        assert!(l.enumerate_pixels().any(|(_, y, p)| y >= c.height() && p.0 == [255, 0, 0]), "the red swatch");
    }
}
