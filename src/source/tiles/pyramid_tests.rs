use super::*;
use std::collections::HashMap;
use std::sync::Mutex;

/// An archive in memory: tiles by address, and the addresses asked for.
struct Mem {
    info: PyramidInfo,
    tiles: HashMap<TileAddr, Vec<u8>>,
    asked: Mutex<Vec<TileAddr>>,
}

impl TileArchive for Mem {
    fn place(&self) -> &str {
        "mem:test"
    }
    fn info(&self) -> &PyramidInfo {
        &self.info
    }
    fn fetch(&self, at: TileAddr) -> Result<Fetched, ArchiveError> {
        self.asked.lock().unwrap().push(at);
        Ok(self.tiles.get(&at).cloned().map_or(Fetched::Missing, Fetched::Tile))
    }
}

fn info(min_zoom: u8, max_zoom: u8, tile_size: u32, encoding: Option<TileEncoding>) -> PyramidInfo {
    PyramidInfo { min_zoom, max_zoom, tile_size, bounds: None, encoding }
}

/// The texel an image tile has at column `c`, row `r` from the north.
fn texel(at: TileAddr, c: u32, r: u32) -> [u8; 4] {
    [at.z.wrapping_mul(40).wrapping_add(at.x as u8 * 7), at.y as u8 * 50 + r as u8, c as u8 * 3, 200 + at.x as u8]
}

fn png(at: TileAddr, size: u32) -> Vec<u8> {
    let img = image::RgbaImage::from_fn(size, size, |c, r| image::Rgba(texel(at, c, r)));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

fn mem(info: PyramidInfo, tiles: impl IntoIterator<Item = (TileAddr, Vec<u8>)>) -> Arc<Mem> {
    Arc::new(Mem { info, tiles: tiles.into_iter().collect(), asked: Mutex::new(Vec::new()) })
}

fn all_png(min: u8, max: u8, size: u32) -> Vec<(TileAddr, Vec<u8>)> {
    let mut v = Vec::new();
    for z in min..=max {
        for y in 0..1u32 << z {
            for x in 0..1u32 << z {
                let at = TileAddr { z, x, y };
                v.push((at, png(at, size)));
            }
        }
    }
    v
}

fn read(src: &PyramidSource, level: u32, s: u64, t: u64) -> Result<(Delivered, Vec<u8>), SourceError> {
    let tile = TileId { level, s, t };
    let mut out = vec![0u8; src.desc().tile_bytes(level)];
    src.read_into(tile, &mut out).map(|d| (d, out))
}

#[test]
fn texture_tiles_are_pyramid_tiles_with_rows_from_the_south() {
    let a = mem(info(0, 2, 4, Some(TileEncoding::Png)), all_png(0, 2, 4));
    let src = PyramidSource::new(a, &PyramidOptions { clip_size: Some(4), ..Default::default() }).unwrap();
    assert_eq!(src.desc().size(), [16, 16]);
    assert_eq!(src.desc().format(), TexelFormat::RGBA8);
    // Level 0 is zoom 2: texture tile (1, 0) is the southern row of tiles, x = 1, y = 3.
    let (d, out) = read(&src, 0, 1, 0).unwrap();
    assert_eq!(d, Delivered::Tile);
    let at = TileAddr { z: 2, x: 1, y: 3 };
    for t in 0..4u32 {
        for s in 0..4u32 {
            let i = ((t * 4 + s) * 4) as usize;
            // Texture row t from the south is image row 3 - t from the north.
            assert_eq!(out[i..i + 4], texel(at, s, 3 - t), "texel ({s}, {t})");
        }
    }
    // Level 1 is zoom 1: tile (0, 1) is the north-west tile.
    let (_, out) = read(&src, 1, 0, 1).unwrap();
    assert_eq!(out[0..4], texel(TileAddr { z: 1, x: 0, y: 0 }, 0, 3));
}

#[test]
fn a_level_of_one_texture_tile_is_put_together_from_its_pyramid_tiles() {
    let a = mem(info(0, 2, 4, Some(TileEncoding::Png)), all_png(0, 2, 4));
    // A clip size of 8: level 1 (zoom 1, 8 texels) is one texture tile of 2x2 pyramid tiles.
    let src = PyramidSource::new(a, &PyramidOptions { clip_size: Some(8), ..Default::default() }).unwrap();
    assert_eq!(src.desc().level(1).tile, [8, 8]);
    let (_, out) = read(&src, 1, 0, 0).unwrap();
    let at = |s: u32, t: u32| ((t * 8 + s) * 4) as usize;
    // South-west texel: tile x 0, y 1 (south), its bottom row (row 3 from the north).
    assert_eq!(out[at(0, 0)..at(0, 0) + 4], texel(TileAddr { z: 1, x: 0, y: 1 }, 0, 3));
    // North-east texel: tile x 1, y 0, its top row.
    assert_eq!(out[at(7, 7)..at(7, 7) + 4], texel(TileAddr { z: 1, x: 1, y: 0 }, 3, 0));
}

#[test]
fn missing_tiles_are_missing_or_the_default_tile() {
    let a = mem(info(0, 1, 4, Some(TileEncoding::Png)), vec![]);
    let src = PyramidSource::new(a.clone(), &PyramidOptions { clip_size: Some(4), ..Default::default() }).unwrap();
    assert!(matches!(read(&src, 0, 0, 0), Err(SourceError::Missing { .. })));
    let default = png(TileAddr { z: 9, x: 1, y: 1 }, 4);
    let src = PyramidSource::new(a, &PyramidOptions { clip_size: Some(4), default_tile: Some(default) }).unwrap();
    let (d, out) = read(&src, 0, 1, 1).unwrap();
    assert_eq!(d, Delivered::Default);
    assert_eq!(out[0..4], texel(TileAddr { z: 9, x: 1, y: 1 }, 0, 3));
    assert_eq!(src.default_tiles(), 1);
}

#[test]
fn answers_that_are_not_the_tile_are_errors_naming_the_place_the_tile_and_what_was_found() {
    let html = b"<!DOCTYPE html><html>quota exceeded</html>".to_vec();
    let small = png(TileAddr { z: 1, x: 1, y: 0 }, 2);
    let jpeg = {
        let img = image::RgbImage::from_pixel(4, 4, image::Rgb([1, 2, 3]));
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
        out.into_inner()
    };
    let tiles = vec![
        (TileAddr { z: 1, x: 0, y: 0 }, html),
        (TileAddr { z: 1, x: 1, y: 0 }, small),
        (TileAddr { z: 1, x: 0, y: 1 }, jpeg),
    ];
    let a = mem(info(0, 1, 4, Some(TileEncoding::Png)), tiles);
    let src = PyramidSource::new(a, &PyramidOptions { clip_size: Some(4), ..Default::default() }).unwrap();
    let e = read(&src, 0, 0, 1).unwrap_err().to_string();
    assert!(
        e.contains("mem:test") && e.contains("tile 1/0/0") && e.contains("not an image") && e.contains("<!DOCTYPE"),
        "{e}"
    );
    let e = read(&src, 0, 1, 1).unwrap_err().to_string();
    assert!(e.contains("tile 1/1/0 is 2x2 texels: expected 4x4"), "{e}");
    let e = read(&src, 0, 0, 0).unwrap_err().to_string();
    assert!(e.contains("tile 1/0/1 is jpeg, but the pyramid's tiles are png"), "{e}");
    assert_eq!(read(&src, 0, 0, 0).unwrap_err().kind(), FaultKind::Corrupt);
}

#[test]
fn tiles_outside_the_bounds_are_not_fetched() {
    let mut i = info(0, 2, 4, Some(TileEncoding::Png));
    // The north-east quarter of the world, roughly: zoom 2 columns 2..3, rows 0..1.
    i.bounds = Some([10.0, 10.0, 170.0, 80.0]);
    let a = mem(i, all_png(0, 2, 4));
    let src = PyramidSource::new(a.clone(), &PyramidOptions { clip_size: Some(4), ..Default::default() }).unwrap();
    assert!(matches!(read(&src, 0, 0, 0), Err(SourceError::Missing { .. })));
    assert!(read(&src, 0, 3, 3).is_ok());
    assert_eq!(*a.asked.lock().unwrap(), vec![TileAddr { z: 2, x: 3, y: 0 }]);
    assert_eq!(tile_range(&[10.0, 10.0, 170.0, 80.0], 2), [2, 0, 3, 1]);
    assert_eq!(tile_range(&[-180.0, -85.06, 180.0, 85.06], 3), [0, 0, 7, 7]);
}

#[test]
fn levels_coarser_than_the_minimum_zoom_are_box_filtered_from_it_once() {
    let a = mem(info(1, 1, 2, Some(TileEncoding::Png)), all_png(1, 1, 2));
    let src = PyramidSource::new(a.clone(), &PyramidOptions { clip_size: Some(2), ..Default::default() }).unwrap();
    assert_eq!(src.desc().level_count(), 3);
    // Level 1 (zoom 0, 2x2): each texel the mean of one zoom-1 tile's 4 texels.
    let (_, out) = read(&src, 1, 0, 0).unwrap();
    let mean = |at: TileAddr, c: usize| {
        let sum: u32 = [(0, 0), (1, 0), (0, 1), (1, 1)].iter().map(|&(s, r)| u32::from(texel(at, s, r)[c])).sum();
        ((sum + 2) / 4) as u8
    };
    // Texel (0, 0) (south-west) comes from tile x 0, y 1.
    for c in 0..4 {
        assert_eq!(out[c], mean(TileAddr { z: 1, x: 0, y: 1 }, c));
        assert_eq!(out[12 + c], mean(TileAddr { z: 1, x: 1, y: 0 }, c));
    }
    let fetched = a.asked.lock().unwrap().len();
    assert_eq!(fetched, 4);
    let (_, one) = read(&src, 2, 0, 0).unwrap();
    assert_eq!(one.len(), 4);
    assert_eq!(a.asked.lock().unwrap().len(), 4, "built once");
}

#[test]
fn jpeg_pyramids_are_rgb8_and_zoom_18_at_256_is_served() {
    let a = mem(info(0, 18, 256, Some(TileEncoding::Jpeg)), vec![]);
    let src = PyramidSource::new(a, &PyramidOptions::default()).unwrap();
    assert_eq!(src.desc().size(), [1 << 26, 1 << 26]);
    assert_eq!(src.desc().format(), TexelFormat::RGB8);
    assert!(matches!(read(&src, 0, 12345, 67890), Err(SourceError::Missing { .. })));
    // Zoom 22 at 256-texel tiles is 2^30 texels a side, the largest texture; zoom 23 is refused.
    let a = mem(info(0, 22, 256, None), vec![]);
    let src = PyramidSource::new(a, &PyramidOptions::default()).unwrap();
    assert_eq!(src.desc().size(), [1 << 30, 1 << 30]);
    let a = mem(info(0, 23, 256, None), vec![]);
    let e = PyramidSource::new(a, &PyramidOptions::default()).unwrap_err().to_string();
    assert!(e.contains("zoom 23 at 256-texel tiles is 2147483648 texels a side"), "{e}");
}

#[test]
fn the_georef_is_web_mercator_quad_and_a_tiles_corners_are_its_definition() {
    let a = mem(info(0, 2, 4, Some(TileEncoding::Png)), all_png(0, 2, 4));
    let src = PyramidSource::new(a, &PyramidOptions { clip_size: Some(4), ..Default::default() }).unwrap();
    let g = TileSource::georef(&src).expect("a pyramid is georeferenced");
    assert_eq!(g.crs().epsg_code(), Some(3857));
    assert_eq!(g.size(), src.desc().size());
    let close = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol * b.abs().max(1.0);
    for k in 0..3u32 {
        let z = 2 - k;
        // Level k's transform is zoom max_zoom - k's own WebMercatorQuad.
        let own = crate::georef::Georef::web_mercator_quad(z, 4).geotransform().0;
        let level = g.level_transform(k).0;
        for i in 0..6 {
            assert!(close(level[i], own[i], 1e-12), "level {k} term {i}: {} against zoom {z}'s {}", level[i], own[i]);
        }
        assert_eq!(g.level_size(k), src.desc().level(k).size);
        let n = 1u32 << z;
        let tile = src.desc().level(k).tile;
        for y in 0..n {
            for x in 0..n {
                // The texture tile that holds pyramid tile (z, x, y), read through the source.
                let (s, t) = (u64::from(x), u64::from(n - 1 - y));
                let (_, out) = read(&src, k, s, t).unwrap();
                let at = TileAddr { z: z as u8, x, y };
                // Its first texel (south-west) is the image's bottom-left one.
                assert_eq!(out[0..4], texel(at, 0, 3), "{at:?}");
                let [s0, t0] = [(s * tile[0]) as f64, (t * tile[1]) as f64];
                let nw = g.texel_to_lonlat(k, [s0, t0 + tile[1] as f64]).unwrap();
                let se = g.texel_to_lonlat(k, [s0 + tile[0] as f64, t0]).unwrap();
                // WebMercatorQuad: lon = x / 2^z * 360 - 180, lat = atan(sinh(pi (1 - 2 y / 2^z))).
                let lon = |x: u32| f64::from(x) / f64::from(n) * 360.0 - 180.0;
                let lat = |y: u32| {
                    (std::f64::consts::PI * (1.0 - 2.0 * f64::from(y) / f64::from(n))).sinh().atan().to_degrees()
                };
                for (got, want) in [(nw, [lon(x), lat(y)]), (se, [lon(x + 1), lat(y + 1)])] {
                    assert!(
                        close(got[0], want[0], 1e-12) && close(got[1], want[1], 1e-12),
                        "{at:?}: {got:?} against {want:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn cut_jpeg_and_webp_tiles_are_errors_never_grey_texels() {
    let at = TileAddr { z: 0, x: 0, y: 0 };
    let img = image::RgbImage::from_fn(16, 16, |c, r| {
        let t = texel(at, c, r);
        image::Rgb([t[0], t[1], t[2]])
    });
    let mut jpeg = std::io::Cursor::new(Vec::new());
    img.write_to(&mut jpeg, image::ImageFormat::Jpeg).unwrap();
    let jpeg = jpeg.into_inner();
    let whole = mem(info(0, 0, 16, Some(TileEncoding::Jpeg)), vec![(at, jpeg.clone())]);
    let src = PyramidSource::new(whole, &PyramidOptions::default()).unwrap();
    assert!(read(&src, 0, 0, 0).is_ok());
    // Half a JPEG: its decoder would fill the rest; refused, naming why.
    let cut = mem(info(0, 0, 16, Some(TileEncoding::Jpeg)), vec![(at, jpeg[..jpeg.len() / 2].to_vec())]);
    let src = PyramidSource::new(cut, &PyramidOptions::default()).unwrap();
    let e = read(&src, 0, 0, 0).unwrap_err().to_string();
    assert!(e.contains("end-of-image marker") && e.contains("cut short") && e.contains("tile 0/0/0"), "{e}");
    // A WebP shorter than its RIFF header says.
    let mut webp = b"RIFF\x40\0\0\0WEBPVP8L".to_vec();
    webp.resize(30, 0);
    let src = PyramidSource::new(mem(info(0, 0, 16, None), vec![(at, webp)]), &PyramidOptions::default()).unwrap();
    let e = read(&src, 0, 0, 0).unwrap_err().to_string();
    assert!(e.contains("RIFF header says 72 bytes") && e.contains("has 30"), "{e}");
}
