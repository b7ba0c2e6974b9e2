//! Pictures of clip textures, shared by `cliptex dump` and `clipmapd --demo`: texels turned into
//! PNG-able colours, a level's window drawn with its valid region and invalid border outlined,
//! and the view coloured by the level each pixel would use (the concentric resolution rings).
//!
//! Owns drawing only. Where texels come from (a mapping, tile files) is the caller's business:
//! every function here takes the texels, or a function that reads them, as an argument.
//! Image rows run top-down while t runs up (Performer's origin is the lower-left corner), so
//! image row `y` of a picture of `[t0, t1)` shows `t = t1 - 1 - y`, as `clipprep` reads images.

use crate::geom::Rect;
use crate::shm::layout::format_from_code;
use crate::shm::{Client, Snapshot};
use crate::texel::{ComponentType, Components, TexelFormat};
use image::{Rgb, RgbImage};

/// One colour per level (repeating after 12), for pictures coloured by level.
pub const PALETTE: [[u8; 3]; 12] = [
    [230, 25, 75],
    [245, 130, 48],
    [255, 225, 25],
    [60, 180, 75],
    [70, 240, 240],
    [0, 130, 200],
    [145, 30, 180],
    [240, 50, 230],
    [170, 110, 40],
    [128, 128, 0],
    [0, 0, 128],
    [128, 128, 128],
];

/// Outline of a valid region.
pub const VALID_EDGE: [u8; 3] = [255, 0, 0];
/// Outline of a window (tex region).
pub const WINDOW_EDGE: [u8; 3] = [255, 255, 0];

/// Whether a format carries alpha (its pictures are RGBA, others RGB).
pub(crate) fn has_alpha(format: TexelFormat) -> bool {
    matches!(format.components, Components::Two | Components::Four)
}

/// One texel as 8-bit RGBA. 8-bit formats are copied exactly (luminance to grey); others are
/// decoded and rounded. `None` (an unknown format) shows the first three bytes as RGB.
pub fn texel_rgba(format: Option<TexelFormat>, texel: &[u8]) -> [u8; 4] {
    let Some(f) = format else {
        let b = |i: usize| texel.get(i).or(texel.last()).copied().unwrap_or(0);
        return [b(0), b(1), b(2), 255];
    };
    if f.ctype == ComponentType::U8 {
        return match f.components {
            Components::One => [texel[0], texel[0], texel[0], 255],
            Components::Two => [texel[0], texel[0], texel[0], texel[1]],
            Components::Three => [texel[0], texel[1], texel[2], 255],
            Components::Four => [texel[0], texel[1], texel[2], texel[3]],
        };
    }
    let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    let c = f.decode(texel);
    [q(c[0]), q(c[1]), q(c[2]), q(c[3])]
}

/// One texel as 16-bit RGBA, for the 16-bit pictures of 16-bit formats: 16-bit components are
/// copied exactly (luminance to grey, alpha 65535 where absent); other formats are
/// [`texel_rgba`] scaled by 257.
pub(crate) fn texel_rgba16(format: Option<TexelFormat>, texel: &[u8]) -> [u16; 4] {
    match format {
        Some(f) if f.ctype == ComponentType::U16 => {
            let w = |i: usize| u16::from_le_bytes([texel[2 * i], texel[2 * i + 1]]);
            match f.components {
                Components::One => [w(0), w(0), w(0), u16::MAX],
                Components::Two => [w(0), w(0), w(0), w(1)],
                Components::Three => [w(0), w(1), w(2), u16::MAX],
                Components::Four => [w(0), w(1), w(2), w(3)],
            }
        }
        _ => texel_rgba(format, texel).map(|v| v as u16 * 257),
    }
}

/// The stand-in painted where a texel could not be read (a missing tile): magenta and black
/// squares of 8 pixels, impossible to mistake for data.
pub(crate) fn missing_pattern(x: u32, y: u32) -> [u8; 4] {
    if (x / 8 + y / 8).is_multiple_of(2) {
        [255, 0, 255, 255]
    } else {
        [0, 0, 0, 255]
    }
}

/// What one picture of a level shows: the level-texel area drawn, one pixel per `scale` texels.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// First texel shown (lower-left corner).
    pub s0: i64,
    /// First texel shown.
    pub t0: i64,
    /// Pixels across and down.
    pub pixels: [u32; 2],
    /// Texels per pixel along each axis.
    pub scale: i64,
}

impl Frame {
    /// A frame showing `area` at one pixel per texel, or fewer pixels so that neither side
    /// exceeds `max_pixels`.
    pub fn fit(area: Rect, max_pixels: u32) -> Frame {
        let longest = area.width().max(area.height()).max(1);
        let scale = longest.div_ceil(max_pixels.max(1) as u64).max(1) as i64;
        let px = |n: u64| n.div_ceil(scale as u64).max(1) as u32;
        Frame { s0: area.s0, t0: area.t0, pixels: [px(area.width()), px(area.height())], scale }
    }

    /// Like [`fit`](Self::fit), with a margin of `margin` pixels on every side (room for the
    /// outlines, which are drawn just outside the rectangles they mark).
    pub fn around(area: Rect, max_pixels: u32, margin: u32) -> Frame {
        let mut f = Frame::fit(area, max_pixels);
        f.s0 -= margin as i64 * f.scale;
        f.t0 -= margin as i64 * f.scale;
        f.pixels = [f.pixels[0] + 2 * margin, f.pixels[1] + 2 * margin];
        f
    }

    /// The texel pixel (x, y) shows.
    pub fn texel(&self, x: u32, y: u32) -> (i64, i64) {
        (self.s0 + x as i64 * self.scale, self.t0 + (self.pixels[1] - 1 - y) as i64 * self.scale)
    }
}

/// Draws one level into `img` at (x0, y0): texels of the valid region from `row` (which fills a
/// row of the valid region, `valid.width()` texels, and returns false when it could not), the
/// rest of the window as a dark checkerboard (the invalid border, or not yet loaded), black
/// outside the level; the window outlined in yellow and the valid region in red, each outline
/// one pixel outside its rectangle.
#[allow(clippy::too_many_arguments)]
pub fn draw_level(
    img: &mut RgbImage,
    x0: u32,
    y0: u32,
    frame: Frame,
    size: [u64; 2],
    window: Rect,
    valid: Option<Rect>,
    format: Option<TexelFormat>,
    bytes_per_texel: usize,
    row: &mut dyn FnMut(i64, &mut [u8]) -> bool,
) {
    let valid = valid.filter(|v| !v.is_empty());
    let width = valid.map_or(0, |v| v.width() as usize);
    let mut line = vec![0u8; width * bytes_per_texel];
    for y in 0..frame.pixels[1] {
        let (_, t) = frame.texel(0, y);
        let have = match valid {
            Some(v) if t >= v.t0 && t < v.t1 => row(t, &mut line),
            _ => false,
        };
        for x in 0..frame.pixels[0] {
            let (s, t) = frame.texel(x, y);
            let px = match valid.filter(|v| have && v.contains(s, t)) {
                Some(v) => {
                    let j = (s - v.s0) as usize * bytes_per_texel;
                    let c = texel_rgba(format, &line[j..j + bytes_per_texel]);
                    [c[0], c[1], c[2]]
                }
                None => backdrop(&frame, size, window, valid, s, t),
            };
            img.put_pixel(x0 + x, y0 + y, Rgb(px));
        }
    }
}

/// What a level picture shows at texel (s, t) where it shows no texel of the level's valid
/// region: the window's outline (yellow) or the valid region's (red), each the ring of pixels just
/// outside its rectangle (so it never hides a texel of it); else the rest of the window as a dark
/// checkerboard (the invalid border, or not yet loaded), black outside the level and dark grey
/// elsewhere ([`draw_level`], and the height pictures of `clipmap_tools::inspect::live_dump`).
pub fn backdrop(frame: &Frame, size: [u64; 2], window: Rect, valid: Option<Rect>, s: i64, t: i64) -> [u8; 3] {
    let sc = frame.scale;
    let on_edge = |r: &Rect| {
        let near = s >= r.s0 - sc && s < r.s1 + sc && t >= r.t0 - sc && t < r.t1 + sc;
        near && !r.contains(s, t) && !r.is_empty()
    };
    if valid.is_some_and(|v| on_edge(&v)) {
        return VALID_EDGE;
    }
    if on_edge(&window) {
        return WINDOW_EDGE;
    }
    let inside_level = s >= 0 && t >= 0 && (s as u64) < size[0] && (t as u64) < size[1];
    if !inside_level {
        [0, 0, 0]
    } else if window.contains(s, t) {
        if (s / 16 + t / 16) % 2 == 0 {
            [60, 60, 60]
        } else {
            [80, 80, 80]
        }
    } else {
        [24, 24, 24]
    }
}

/// Draws level `k` of a mapping as published in `snap` over `frame` (see [`draw_level`]).
pub fn draw_published_level(
    img: &mut RgbImage,
    x0: u32,
    y0: u32,
    frame: Frame,
    client: &Client,
    snap: &Snapshot,
    k: usize,
) {
    let st = snap.levels[k];
    let size = client.levels[k].size;
    let window = crate::geom::tex_region(size, client.clip_size, st.centre);
    let v = Rect::new(st.valid[0], st.valid[1], st.valid[2], st.valid[3]);
    let valid = st.enabled.then_some(v);
    let Some(decoded) = client.decoded_format() else {
        let format = format_from_code(client.format_code);
        let mut row = |t: i64, out: &mut [u8]| client.read_region(k, v.s0, t, v.width(), 1, out).is_ok();
        draw_level(img, x0, y0, frame, size, window, valid, format, client.bytes_per_texel, &mut row);
        return;
    };
    // A block format: the valid region decoded once, tile by tile (nothing of it when a tile
    // under it cannot be read), its rows given from there.
    let bpt = decoded.bytes_per_texel() as usize;
    let texels = decoded_region(client, snap, k);
    let pitch = v.width() as usize * bpt;
    let mut row = |t: i64, out: &mut [u8]| match &texels {
        Some(b) => {
            out.copy_from_slice(&b[(t - v.t0) as usize * pitch..][..pitch]);
            true
        }
        None => false,
    };
    draw_level(img, x0, y0, frame, size, window, valid, Some(decoded), bpt, &mut row);
}

/// The texels of level `k`'s valid region in `snap` of a block-compressed mapping, decoded
/// ([`Client::decode_region_in`]); `None` for a level disabled, empty, or with a tile under it
/// that cannot be read.
fn decoded_region(client: &Client, snap: &Snapshot, k: usize) -> Option<Vec<u8>> {
    let st = snap.levels[k];
    let v = st.rect();
    let n = client.decoded_format()?.bytes_per_texel() as usize;
    if !st.enabled || v.is_empty() {
        return None;
    }
    let mut out = vec![0u8; (v.width() * v.height()) as usize * n];
    client.decode_region_in(snap, k, v, &mut out).ok().map(|()| out)
}

/// The view around `centre` (level-0 texels), `n` pixels a side over `extent` level-0 texels:
/// the texture as a renderer would sample it (the finest level available at each pixel, no
/// coarser than min LOD; each texel coloured by `colour`) and the same view coloured by that level
/// (texture luminance mixed in). Pixels outside the texture, or that no level covers, stay black:
/// where a side is not a power of two, the coarsest levels (at least one texel a side) reach past
/// level 0's edge, and a texel there is no texel of the texture.
pub fn view_and_rings(
    client: &Client,
    snap: &Snapshot,
    centre: [i64; 2],
    n: u32,
    extent: i64,
    colour: &dyn Fn(&[u8]) -> [u8; 3],
) -> (RgbImage, RgbImage) {
    let bpt = client.decoded_format().map_or(client.bytes_per_texel, |f| f.bytes_per_texel() as usize);
    // A block format: each level's valid region decoded once, when first needed.
    let mut decoded: Vec<Option<Option<Vec<u8>>>> = vec![None; client.levels.len()];
    let size0 = client.levels.first().map_or([0, 0], |l| l.size);
    let step = (extent / n as i64).max(1);
    let first = (snap.min_lod.max(0.0).ceil() as usize).min(client.levels.len());
    let mut view = RgbImage::new(n, n);
    let mut lod = RgbImage::new(n, n);
    let mut px = vec![0u8; bpt];
    for y in 0..n {
        for x in 0..n {
            let s = centre[0] + (x as i64 - n as i64 / 2) * step;
            let t = centre[1] + ((n - 1 - y) as i64 - n as i64 / 2) * step;
            if s < 0 || t < 0 || s as u64 >= size0[0] || t as u64 >= size0[1] {
                continue;
            }
            let found = (first..client.levels.len()).find(|&k| {
                let (sk, tk) = (s >> k, t >> k);
                if !snap.levels[k].contains(sk, tk) {
                    return false;
                }
                if client.block == 1 {
                    return client.read_region(k, sk, tk, 1, 1, &mut px).is_ok();
                }
                let v = snap.levels[k].rect();
                let Some(texels) = decoded[k].get_or_insert_with(|| decoded_region(client, snap, k)) else {
                    return false;
                };
                let i = ((tk - v.t0) as usize * v.width() as usize + (sk - v.s0) as usize) * bpt;
                px.copy_from_slice(&texels[i..i + bpt]);
                true
            });
            if let Some(k) = found {
                let c = colour(&px);
                view.put_pixel(x, y, Rgb(c));
                let p = PALETTE[k % PALETTE.len()];
                let lum = (c[0] as u32 + c[1] as u32 + c[2] as u32) / 3;
                let mix = |a: u8| ((a as u32 * 3 + lum * 2) / 5) as u8;
                lod.put_pixel(x, y, Rgb([mix(p[0]), mix(p[1]), mix(p[2])]));
            }
        }
    }
    (view, lod)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eight_bit_texels_are_copied_exactly_and_packed_ones_decoded() {
        assert_eq!(texel_rgba(Some(TexelFormat::L8), &[7]), [7, 7, 7, 255]);
        assert_eq!(texel_rgba(Some(TexelFormat::RGB8), &[1, 2, 3]), [1, 2, 3, 255]);
        assert_eq!(texel_rgba(Some(TexelFormat::RGBA8), &[1, 2, 3, 4]), [1, 2, 3, 4]);
        // 5-6-5: full red, no green, full blue.
        let v: u16 = (31 << 11) | 31;
        assert_eq!(texel_rgba(Some(TexelFormat::RGB565), &v.to_le_bytes()), [255, 0, 255, 255]);
        // 5-5-5-1: half-ish green, alpha bit clear.
        let v: u16 = 16 << 6;
        assert_eq!(texel_rgba(Some(TexelFormat::RGBA5551), &v.to_le_bytes()), [0, 132, 0, 0]);
        assert_eq!(texel_rgba(Some(TexelFormat::L16), &[0xff, 0xff]), [255, 255, 255, 255]);
        assert_eq!(texel_rgba(None, &[9, 8]), [9, 8, 8, 255]);
    }

    #[test]
    fn sixteen_bit_texels_are_copied_exactly_into_sixteen_bit_pixels() {
        let le = |v: &[u16]| v.iter().flat_map(|c| c.to_le_bytes()).collect::<Vec<u8>>();
        assert_eq!(texel_rgba16(Some(TexelFormat::L16), &le(&[1234])), [1234, 1234, 1234, 65535]);
        assert_eq!(texel_rgba16(Some(TexelFormat::LA16), &le(&[1, 2])), [1, 1, 1, 2]);
        assert_eq!(texel_rgba16(Some(TexelFormat::RGB16), &le(&[1, 2, 3])), [1, 2, 3, 65535]);
        assert_eq!(texel_rgba16(Some(TexelFormat::RGBA16), &le(&[1, 2, 3, 4])), [1, 2, 3, 4]);
        assert_eq!(texel_rgba16(Some(TexelFormat::RGB8), &[0, 1, 255]), [0, 257, 65535, 65535]);
        // 16-bit texels in 8-bit pictures are rounded: 0x1234 / 257 = 18.13.
        assert_eq!(texel_rgba(Some(TexelFormat::L16), &le(&[0x1234])), [18, 18, 18, 255]);
    }

    #[test]
    fn a_frame_fits_its_area_and_runs_t_upwards() {
        let f = Frame::fit(Rect::new(100, 200, 4196, 2248), 1024);
        assert_eq!((f.scale, f.pixels), (4, [1024, 512]));
        assert_eq!(f.texel(0, 511), (100, 200));
        assert_eq!(f.texel(1, 0), (104, 200 + 511 * 4));
        let g = Frame::fit(Rect::new(0, 0, 10, 3), 1024);
        assert_eq!((g.scale, g.pixels), (1, [10, 3]));
    }

    #[test]
    fn the_view_drew_the_coarse_levels_past_the_edge_of_a_texture_whose_sides_are_not_powers_of_two() {
        use crate::clip::{Clipmap, Settings};
        use crate::source::{HashSource, TextureDesc, TileSource};
        let dir = tempfile::tempdir().unwrap();
        let desc = TextureDesc::new([600, 200], 32, TexelFormat::RGBA8, [16, 16]).unwrap();
        let source: std::sync::Arc<dyn TileSource> = std::sync::Arc::new(HashSource::new(desc));
        let settings = Settings { budget_ns: None, fade_ticks: 1, ..Settings::default() };
        let shape = Clipmap::shape_for(source.desc(), &settings);
        let w = crate::shm::Writer::create(
            crate::shm::WriterOptions::new(dir.path(), "npot", shape, TexelFormat::RGBA8).tick_period_ns(1_000_000),
        )
        .unwrap();
        let mut map = Clipmap::with_memory(source, settings, w.memory()).unwrap();
        for _ in 0..10 {
            map.tick([300, 100], None);
            map.wait_for_reads();
        }
        let client = Client::attach(dir.path(), "npot").unwrap();
        let snap = client.try_snapshot().unwrap();
        assert_eq!(snap.min_lod, 0.0);
        // The last levels are 2 x 1 and 1 x 1 (at least one texel a side): t 200 to 255 lies in
        // their texel row 0, and s 512 to 599 in the 1 x 1 level's texel, but only t < 200 and
        // s < 600 are texels of the texture.
        let (n, extent, centre) = (128u32, 1024i64, [300i64, 100]);
        let white = |_: &[u8]| [255u8; 3];
        let (view, rings) = view_and_rings(&client, &snap, centre, n, extent, &white);
        let step = extent / n as i64;
        let (mut inside, mut outside) = (0, 0);
        for y in 0..n {
            for x in 0..n {
                let s = centre[0] + (x as i64 - n as i64 / 2) * step;
                let t = centre[1] + ((n - 1 - y) as i64 - n as i64 / 2) * step;
                let texel = (0..600).contains(&s) && (0..200).contains(&t);
                let (v, r) = (view.get_pixel(x, y).0, rings.get_pixel(x, y).0);
                if texel {
                    // (Not every one: a level halved rounding down drops its last odd texel, so
                    // some of the texture's last texels lie in no coarse level.)
                    inside += u32::from(v == [255; 3]);
                } else {
                    outside += 1;
                    assert_eq!((v, r), ([0; 3], [0; 3]), "pixel ({x}, {y}) shows ({s}, {t}), outside the texture");
                }
            }
        }
        assert!(inside > 1000 && outside > 1000, "{inside} drawn, {outside} outside");
    }

    #[test]
    fn a_drawn_level_outlines_its_valid_region_and_shows_texels_inside() {
        let window = Rect::new(0, 0, 32, 32);
        let valid = Rect::new(8, 8, 24, 24);
        let frame = Frame::around(window, 64, 2);
        assert_eq!((frame.s0, frame.t0, frame.pixels), (-2, -2, [36, 36]));
        let mut img = RgbImage::new(36, 36);
        let mut rows = Vec::new();
        let mut row = |t: i64, out: &mut [u8]| {
            rows.push(t);
            for (i, b) in out.chunks_mut(3).enumerate() {
                b.copy_from_slice(&[i as u8, t as u8, 7]);
            }
            true
        };
        draw_level(&mut img, 0, 0, frame, [64, 64], window, Some(valid), Some(TexelFormat::RGB8), 3, &mut row);
        assert_eq!(rows.len(), 16, "only rows of the valid region are read");
        // Texel (s, t) is pixel (s + 2, 33 - t).
        assert_eq!(img.get_pixel(14, 23).0, [4, 10, 7]);
        assert_eq!(img.get_pixel(10, 23).0, [0, 10, 7], "the valid region's edge texel is shown");
        assert_eq!(img.get_pixel(9, 23).0, VALID_EDGE, "texel (7, 10) is just outside");
        assert_eq!(img.get_pixel(1, 23).0, WINDOW_EDGE, "texel (-1, 10) is just outside the window");
        assert_eq!(img.get_pixel(0, 23).0, [0, 0, 0], "outside the level");
        let border = img.get_pixel(6, 18).0;
        assert!(border == [60, 60, 60] || border == [80, 80, 80], "{border:?}");
    }
}
