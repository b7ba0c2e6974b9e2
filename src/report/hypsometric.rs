//! Pictures of heights (docs/ELEVATION.md): metres in false colour (a hypsometric ramp from the
//! lowest to the highest height of a range), optionally hillshaded, nodata transparent, and a
//! legend below the map (the colour bar with its extremes in metres, drawn with a small bitmap
//! font, and the nodata swatch). Pure pixels: reading tiles is [`super::dump`]'s business.

use image::RgbaImage;

/// The colour of a texel without data: transparent (the missing-tile pattern is opaque magenta
/// and black, so the two never look alike).
pub const NODATA_RGBA: [u8; 4] = [0, 0, 0, 0];

/// The ramp's stops, from the lowest height (0) to the highest (1): deep blue, cyan, green,
/// yellow, brown, white.
const STOPS: [(f64, [u8; 3]); 6] = [
    (0.0, [20, 40, 140]),
    (0.2, [40, 170, 210]),
    (0.4, [50, 150, 60]),
    (0.6, [230, 210, 90]),
    (0.8, [140, 90, 50]),
    (1.0, [250, 250, 250]),
];

/// The ramp's colour at `f` (clamped to 0..=1).
pub fn ramp(f: f64) -> [u8; 3] {
    let f = if f.is_nan() { 0.0 } else { f.clamp(0.0, 1.0) };
    for w in STOPS.windows(2) {
        let ((a, ca), (b, cb)) = (w[0], w[1]);
        if f <= b {
            let u = (f - a) / (b - a);
            return [0, 1, 2].map(|i| (ca[i] as f64 + (cb[i] as f64 - ca[i] as f64) * u).round() as u8);
        }
    }
    STOPS[STOPS.len() - 1].1
}

/// Where `metres` lies in `[min, max]`, 0 to 1 (0 when the range is one height).
pub fn fraction(metres: f64, min: f64, max: f64) -> f64 {
    if max > min {
        (metres - min) / (max - min)
    } else {
        0.0
    }
}

/// One texel of a height picture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Texel {
    /// A height, metres.
    Height(f64),
    /// No data.
    Nodata,
    /// The tile could not be read (painted with the missing-tile pattern).
    Missing,
}

/// The lambert factor of a hillshade at texel (x, y) of `map` (`w` wide, rows top-down), light
/// from the north-west 45 degrees up; neighbours without a height take the texel's own.
/// `spacing` is the metres one texel spans horizontally.
fn shade(map: &[Texel], w: usize, h: usize, x: usize, y: usize, spacing: f64) -> f64 {
    let at = |xx: usize, yy: usize, own: f64| match map[yy * w + xx] {
        Texel::Height(m) if m.is_finite() => m,
        _ => own,
    };
    let Texel::Height(own) = map[y * w + x] else { return 1.0 };
    let (l, r) = (at(x.saturating_sub(1), y, own), at((x + 1).min(w - 1), y, own));
    let (u, d) = (at(x, y.saturating_sub(1), own), at(x, (y + 1).min(h - 1), own));
    // Slopes east and north (y runs down the picture), per metre.
    let dzdx = (r - l) / (2.0 * spacing);
    let dzdy = (u - d) / (2.0 * spacing);
    let n = [-dzdx, -dzdy, 1.0];
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let light = [-s * s, s * s, s];
    ((n[0] * light[0] + n[1] * light[1] + n[2] * light[2]) / len).clamp(0.0, 1.0)
}

/// Bitmap glyphs, 3 x 5, one row of 3 bits a line (top first).
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '-' => [0, 0, 7, 0, 0],
        '.' => [0, 0, 0, 0, 2],
        'm' => [0, 0, 7, 7, 5],
        'n' => [0, 0, 6, 5, 5],
        'o' => [0, 0, 7, 5, 7],
        'd' => [1, 1, 7, 5, 7],
        'a' => [0, 6, 1, 7, 7],
        't' => [2, 7, 2, 2, 3],
        _ => [0; 5],
    }
}

/// Pixels of one glyph cell (3 x 5 scaled by [`FONT_SCALE`], plus a column of space).
const FONT_SCALE: u32 = 2;
const ADVANCE: u32 = 4 * FONT_SCALE;

/// Draws `text` with its top-left corner at (x, y) in `colour`.
fn text(img: &mut RgbaImage, x: u32, y: u32, s: &str, colour: [u8; 4]) {
    for (i, c) in s.chars().enumerate() {
        let g = glyph(c);
        for (row, bits) in g.iter().enumerate() {
            for col in 0..3u32 {
                if bits >> (2 - col) & 1 == 1 {
                    for dy in 0..FONT_SCALE {
                        for dx in 0..FONT_SCALE {
                            let (px, py) =
                                (x + i as u32 * ADVANCE + col * FONT_SCALE + dx, y + row as u32 * FONT_SCALE + dy);
                            if px < img.width() && py < img.height() {
                                img.put_pixel(px, py, image::Rgba(colour));
                            }
                        }
                    }
                }
            }
        }
    }
}

/// The text width of `s` in pixels.
fn text_width(s: &str) -> u32 {
    s.chars().count() as u32 * ADVANCE
}

/// A legend label: metres with two decimals.
pub fn label(metres: f64) -> String {
    format!("{metres:.2} m")
}

/// The legend's geometry below a map `h` rows tall: the colour bar's rows and columns.
pub struct Legend {
    /// First row of the colour bar.
    pub bar_y0: u32,
    /// Rows past the bar's last.
    pub bar_y1: u32,
    /// First column of the bar (the ramp's 0).
    pub bar_x0: u32,
    /// Columns past the bar's last (its last column is the ramp's 1).
    pub bar_x1: u32,
    /// The row of the labels' tops.
    pub label_y: u32,
}

/// The least width of a picture with a legend.
pub(crate) const LEGEND_WIDTH: u32 = 256;
/// Rows the legend adds below the map.
pub(crate) const LEGEND_ROWS: u32 = 40;

impl Legend {
    /// Where the legend of a picture `width` wide below a map `map_h` rows tall goes.
    pub fn at(width: u32, map_h: u32) -> Legend {
        Legend { bar_y0: map_h + 6, bar_y1: map_h + 18, bar_x0: 4, bar_x1: width - 4, label_y: map_h + 22 }
    }
}

/// The picture: the map (`w` x `h` texels, rows top-down) in false colour over `[min, max]`
/// metres, hillshaded when `shaded`, at the top left; the legend below. `missing` paints a
/// texel of a tile that could not be read.
pub fn picture(
    map: &[Texel],
    w: u32,
    h: u32,
    range: Option<(f64, f64)>,
    shaded: bool,
    missing: impl Fn(u32, u32) -> [u8; 4],
) -> RgbaImage {
    let width = w.max(LEGEND_WIDTH);
    let mut img = RgbaImage::from_pixel(width, h + LEGEND_ROWS, image::Rgba([255, 255, 255, 255]));
    let (min, max) = range.unwrap_or((0.0, 0.0));
    // The relief is drawn as if the range spanned an eighth of the map's wider side.
    let spacing = ((max - min) * 8.0 / w.max(h) as f64).max(f64::MIN_POSITIVE);
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let px = match map[i] {
                Texel::Nodata => NODATA_RGBA,
                Texel::Height(m) if !m.is_finite() => NODATA_RGBA,
                Texel::Missing => missing(x, y),
                Texel::Height(m) => {
                    let c = ramp(fraction(m, min, max));
                    if shaded {
                        let k = 0.35 + 0.65 * shade(map, w as usize, h as usize, x as usize, y as usize, spacing);
                        let c = c.map(|v| (v as f64 * k).round() as u8);
                        [c[0], c[1], c[2], 255]
                    } else {
                        [c[0], c[1], c[2], 255]
                    }
                }
            };
            img.put_pixel(x, y, image::Rgba(px));
        }
    }
    let lg = Legend::at(width, h);
    let black = [0, 0, 0, 255];
    let span = (lg.bar_x1 - lg.bar_x0 - 1).max(1) as f64;
    for x in lg.bar_x0..lg.bar_x1 {
        let c = ramp((x - lg.bar_x0) as f64 / span);
        for y in lg.bar_y0..lg.bar_y1 {
            img.put_pixel(x, y, image::Rgba([c[0], c[1], c[2], 255]));
        }
    }
    match range {
        Some((min, max)) => {
            text(&mut img, lg.bar_x0, lg.label_y, &label(min), black);
            let hi = label(max);
            text(&mut img, lg.bar_x1 - text_width(&hi), lg.label_y, &hi, black);
        }
        None => text(&mut img, lg.bar_x0, lg.label_y, "nodata", black),
    }
    // The nodata swatch: a transparent square outlined in black, then the word.
    let sx = width / 2 - 30;
    for y in lg.label_y..lg.label_y + 10 {
        for x in sx..sx + 10 {
            let edge = y == lg.label_y || y == lg.label_y + 9 || x == sx || x == sx + 9;
            img.put_pixel(x, y, image::Rgba(if edge { black } else { NODATA_RGBA }));
        }
    }
    text(&mut img, sx + 14, lg.label_y, "nodata", black);
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ramp_runs_through_its_stops_and_never_gives_the_nodata_colour() {
        assert_eq!(ramp(0.0), STOPS[0].1);
        assert_eq!(ramp(1.0), STOPS[5].1);
        assert_eq!(ramp(0.4), STOPS[2].1);
        assert_eq!(ramp(-3.0), ramp(0.0));
        let distinct: std::collections::BTreeSet<[u8; 3]> = (0..=100).map(|i| ramp(i as f64 / 100.0)).collect();
        assert!(distinct.len() > 50, "{}", distinct.len());
    }

    #[test]
    fn a_flat_map_is_lit_evenly_and_a_slope_facing_the_light_is_brighter() {
        let flat = vec![Texel::Height(5.0); 9];
        let k = shade(&flat, 3, 3, 1, 1, 1.0);
        assert!((k - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12, "{k}");
        // Rising to the east, the slope faces the north-western light: brighter than flat.
        let east: Vec<Texel> = (0..9).map(|i| Texel::Height((i % 3) as f64)).collect();
        assert!(shade(&east, 3, 3, 1, 1, 1.0) > k);
        let west: Vec<Texel> = (0..9).map(|i| Texel::Height(-((i % 3) as f64))).collect();
        assert!(shade(&west, 3, 3, 1, 1, 1.0) < k);
    }

    #[test]
    fn labels_are_drawn_with_every_glyph_they_need() {
        for c in "-0123456789. mnodata".chars().filter(|&c| c != ' ') {
            assert!(glyph(c).iter().any(|&r| r != 0), "{c}");
        }
        assert_eq!(label(-10999.5), "-10999.50 m");
    }
}
