//! Where level texels come from: the procedural sources (per level for `hash`, level 0 for
//! `terrain`) and decoded images, delivered in bands of whole rows.
//!
//! Image convention: Performer's texture origin is the lower-left corner, so level-0 texel
//! (s, t) is image pixel (column s, row H - 1 - t) (image rows run top-down). With padding, the
//! texels beyond the image (s >= width or t >= height) are zero (black, transparent).
//!
//! Depth: 16-bit samples reach 16-bit formats unchanged (never through 8 bits); 8-bit samples
//! into a 16-bit format are scaled by 257 (exact: 255 becomes 65535). An input deeper than the
//! chosen format (16-bit samples, a format of 8 bits or fewer per component) is refused unless
//! the reduction is asked for ([`OpenedImage::reduce_depth`]); it then rounds to nearest.

use super::band::{encode_rgba16, encode_rgba8, encode_row, widen, BandSource};
use super::error::PrepError;
use super::tiff_stream::TiffStream;
use super::Limits;
use crate::source::procedural::{hash_region, Terrain};
use crate::texel::{ComponentType, Components, TexelFormat};
use image::{DynamicImage, GenericImageView, ImageDecoder, ImageReader};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// The verification texture of one level (docs/ARCHITECTURE.md §11).
pub(crate) struct HashLevel {
    /// Level index.
    pub level: u32,
    /// Level width.
    pub width: u64,
    /// Bytes per texel.
    pub bpt: usize,
}

impl BandSource for HashLevel {
    fn fill(&mut self, t0: u64, _rows: usize, out: &mut [u8]) -> Result<(), PrepError> {
        let row_bytes = self.width as usize * self.bpt;
        out.par_chunks_mut(row_bytes).enumerate().for_each(|(i, row)| {
            hash_region(self.level, 0, t0 + i as u64, self.width as usize, 1, self.bpt, row);
        });
        Ok(())
    }
}

/// Level 0 of the terrain texture: its colours, or for the 16-bit luminance formats (`l16`,
/// `la16`) its heights (0..=1 as 0..=65535, alpha opaque): a height map.
pub(crate) struct TerrainLevel0 {
    /// The terrain.
    pub terrain: Terrain,
    /// Level-0 width.
    pub width: u64,
    /// Texel format.
    pub format: TexelFormat,
}

impl BandSource for TerrainLevel0 {
    fn fill(&mut self, t0: u64, _rows: usize, out: &mut [u8]) -> Result<(), PrepError> {
        let bpt = self.format.bytes_per_texel() as usize;
        let row_bytes = self.width as usize * bpt;
        let heights = self.format.ctype == ComponentType::U16
            && matches!(self.format.components, Components::One | Components::Two);
        out.par_chunks_mut(row_bytes).enumerate().for_each(|(i, row)| {
            for (s, texel) in row.chunks_exact_mut(bpt).enumerate() {
                if heights {
                    let h = self.terrain.height(0, s as u64, t0 + i as u64).clamp(0.0, 1.0);
                    let v = (h * 65535.0).round() as u16;
                    encode_rgba16(self.format, [v, v, v, u16::MAX], texel);
                } else {
                    self.terrain.texel(0, s as u64, t0 + i as u64, self.format, texel);
                }
            }
        });
        Ok(())
    }
}

/// An image decoded into memory (any format the `image` crate reads).
pub(crate) struct MemoryImage {
    image: DynamicImage,
    format: TexelFormat,
    /// Level-0 width (image width, or padded).
    width: u64,
    /// The image has 16-bit samples, or the format 16-bit components: pixels go through
    /// [`encode_rgba16`].
    deep: bool,
}

/// Pixel (x, y) of a decoded image as 16-bit RGBA (8-bit samples scaled by 257; grey repeated).
fn pixel16(image: &DynamicImage, x: u32, y: u32) -> [u16; 4] {
    match image {
        DynamicImage::ImageLuma16(i) => {
            let v = i.get_pixel(x, y).0[0];
            [v, v, v, u16::MAX]
        }
        DynamicImage::ImageLumaA16(i) => {
            let [v, a] = i.get_pixel(x, y).0;
            [v, v, v, a]
        }
        DynamicImage::ImageRgb16(i) => {
            let [r, g, b] = i.get_pixel(x, y).0;
            [r, g, b, u16::MAX]
        }
        DynamicImage::ImageRgba16(i) => i.get_pixel(x, y).0,
        other => widen(other.get_pixel(x, y).0),
    }
}

impl BandSource for MemoryImage {
    fn fill(&mut self, t0: u64, _rows: usize, out: &mut [u8]) -> Result<(), PrepError> {
        let bpt = self.format.bytes_per_texel() as usize;
        let row_bytes = self.width as usize * bpt;
        let (iw, ih) = self.image.dimensions();
        let image = &self.image;
        let format = self.format;
        let deep = self.deep;
        out.par_chunks_mut(row_bytes).enumerate().for_each(|(i, row)| {
            let t = t0 + i as u64;
            row.fill(0);
            if t >= ih as u64 {
                return;
            }
            let y = ih - 1 - t as u32;
            for (x, texel) in row.chunks_exact_mut(bpt).take(iw as usize).enumerate() {
                if deep {
                    encode_rgba16(format, pixel16(image, x as u32, y), texel);
                } else {
                    encode_rgba8(format, image.get_pixel(x as u32, y).0, texel);
                }
            }
        });
        Ok(())
    }
}

/// An opened input image: its size and a band source for level 0.
pub struct OpenedImage {
    /// Image width in pixels.
    pub width: u64,
    /// Image height in pixels.
    pub height: u64,
    /// True when the image is streamed rather than held in memory.
    pub streamed: bool,
    /// Bits per sample: 8 or 16.
    pub bits: u32,
    /// Samples per pixel: 1 grey, 2 grey and alpha, 3 RGB, 4 RGBA.
    pub samples: u32,
    /// Round samples deeper than the texel format to it instead of refusing the image.
    pub reduce_depth: bool,
    /// Where the image is on the Earth: a TIFF's GeoTIFF tags read as a COG's are
    /// (`crate::source::cog::tiff_georef`; docs/GEOREF.md). `Ok(None)`: none (not a TIFF, or no
    /// transform tag); `Err`: the tags could not be read, and why.
    pub georef: Result<Option<crate::georef::Georef>, String>,
    path: PathBuf,
    opener: Opener,
}

enum Opener {
    Memory(DynamicImage),
    Tiff(PathBuf),
    /// A tiled TIFF the `tiff` crate does not decode (GDAL's YCbCr JPEG), read by the COG
    /// reader.
    Cog(Box<crate::source::CogSource>),
}

impl OpenedImage {
    /// Refuses an image deeper than `format` (16-bit samples for a format of 8 bits or fewer per
    /// component) unless [`reduce_depth`](Self::reduce_depth) asks for the reduction.
    pub fn check_depth(&self, format: TexelFormat) -> Result<(), PrepError> {
        let allowed = if format.component_bits() >= 16 { 16 } else { 8 };
        if self.bits <= allowed || self.reduce_depth {
            return Ok(());
        }
        let wider = TexelFormat { components: format.components, ctype: ComponentType::U16 };
        Err(PrepError::DeeperThanFormat {
            path: self.path.clone(),
            bits: self.bits,
            layout: match self.samples {
                1 => "grey",
                2 => "grey+alpha",
                3 => "RGB",
                _ => "RGBA",
            },
            format: format.short_name(),
            allowed,
            wider: wider.short_name(),
        })
    }

    /// A band source producing level 0 of `padded_width` in `format` (refused by
    /// [`check_depth`](Self::check_depth) when the image is deeper than the format).
    pub(crate) fn into_source(self, format: TexelFormat, padded_width: u64) -> Result<Box<dyn BandSource>, PrepError> {
        self.check_depth(format)?;
        let deep = self.bits == 16 || format.ctype == ComponentType::U16;
        Ok(match self.opener {
            Opener::Memory(image) => Box::new(MemoryImage { image, format, width: padded_width, deep }),
            Opener::Tiff(path) => Box::new(TiffStream::open(&path)?.into_source(format, padded_width)),
            Opener::Cog(src) => {
                Box::new(CogBand { src: *src, format, width: padded_width, cache: Vec::new(), rows: None })
            }
        })
    }
}

fn decode_error(path: &Path, e: impl std::fmt::Display) -> PrepError {
    PrepError::ImageDecode { path: path.to_path_buf(), message: e.to_string() }
}

/// Refuses an image whose decoder would accept it cut short: a JPEG is walked from its SOI to
/// its EOI marker ([`super::jpeg_check`]); PNG and TIFF decoders find truncation themselves.
fn check_whole(path: &Path, limits: &Limits) -> Result<(), PrepError> {
    let open_err = |source| PrepError::ImageOpen { path: path.into(), source };
    let bytes = crate::open::read_bounded(path, limits.max_memory_bytes).map_err(open_err)?;
    if super::jpeg_check::is_jpeg(&bytes) && bytes.len() as u64 <= limits.max_memory_bytes {
        super::jpeg_check::check(&bytes).map_err(|m| decode_error(path, m))?;
    }
    Ok(())
}

/// Level 0 of a TIFF read by the COG reader ([`crate::source::CogSource::read_full_resolution`]),
/// one row of TIFF tiles at a time, its texels (grey, RGB or RGBA of 8 or 16 bits, an alpha
/// added for a mask or GDAL_NODATA as `clipmapd` serves it) encoded into `format`.
struct CogBand {
    src: crate::source::CogSource,
    format: TexelFormat,
    width: u64,
    /// Texture rows `rows.0 .. rows.1` of level 0, as the source serves them.
    cache: Vec<u8>,
    rows: Option<(u64, u64)>,
}

impl CogBand {
    /// Reads the texture rows of the TIFF tile row holding texture row `t` into the cache.
    fn load(&mut self, t: u64) -> Result<(), PrepError> {
        use crate::source::TileSource;
        let [iw, ih] = self.src.desc().size();
        let th = self.src.desc().level(0).tile[1].max(1);
        let th = self.src.origins().first().map_or(th, |o| match o {
            crate::source::cog::LevelOrigin::Ifd { tile, .. } => tile[1],
            _ => th,
        });
        // Image rows cy * th .. (cy + 1) * th, top-down, are texture rows counted from the bottom.
        let cy = (ih - 1 - t) / th;
        let (y0, y1) = (cy * th, ((cy + 1) * th).min(ih));
        let (t0, t1) = (ih - y1, ih - y0);
        let bpt = self.src.desc().bytes_per_texel();
        self.cache.resize((iw * (t1 - t0)) as usize * bpt, 0);
        self.src
            .read_full_resolution([0, t0], [iw, t1 - t0], &mut self.cache)
            .map_err(|e| PrepError::ImageDecode { path: self.src.path().to_path_buf(), message: e.to_string() })?;
        self.rows = Some((t0, t1));
        Ok(())
    }
}

impl BandSource for CogBand {
    fn fill(&mut self, t0: u64, rows: usize, out: &mut [u8]) -> Result<(), PrepError> {
        use crate::source::TileSource;
        let bpt = self.format.bytes_per_texel() as usize;
        let row_bytes = self.width as usize * bpt;
        let [iw, ih] = self.src.desc().size();
        let served = self.src.desc().format();
        let (n, sb) = (served.components.count() as usize, if served.ctype == ComponentType::U16 { 2 } else { 1 });
        let deep_in = sb == 2;
        for i in 0..rows {
            let row = &mut out[i * row_bytes..(i + 1) * row_bytes];
            row.fill(0);
            let t = t0 + i as u64;
            if t >= ih {
                continue;
            }
            if !self.rows.is_some_and(|(a, b)| (a..b).contains(&t)) {
                self.load(t)?;
            }
            let (a, _) = self.rows.unwrap_or((t, t));
            let line = &self.cache[((t - a) * iw) as usize * n * sb..][..iw as usize * n * sb];
            let pixels = line.chunks_exact(n * sb).map(|px| {
                let get =
                    |k: usize| if deep_in { u16::from_le_bytes([px[2 * k], px[2 * k + 1]]) } else { px[k] as u16 };
                let max = if deep_in { u16::MAX } else { 255 };
                match n {
                    1 => [get(0), get(0), get(0), max],
                    2 => [get(0), get(0), get(0), get(1)],
                    3 => [get(0), get(1), get(2), max],
                    _ => [get(0), get(1), get(2), get(3)],
                }
            });
            encode_row(self.format, deep_in, pixels, row);
        }
        Ok(())
    }
}

/// A TIFF the image decoders refused, opened by the COG reader when it serves it as colour
/// (`None` when it does not: the decoder's refusal stands).
fn open_by_cog_reader(path: &Path, limits: &Limits) -> Option<Result<OpenedImage, PrepError>> {
    use crate::source::TileSource;
    let src = crate::source::CogSource::open_full_resolution(path).ok()?;
    let f = src.desc().format();
    if src.heights().is_some() || !matches!(f.ctype, ComponentType::U8 | ComponentType::U16) {
        return None;
    }
    let [width, height] = src.desc().size();
    // One row of TIFF tiles is held, as the served texels: at most a quarter of the limit.
    let th = src.origins().first().map_or(1, |o| match o {
        crate::source::cog::LevelOrigin::Ifd { tile, .. } => tile[1],
        _ => 1,
    });
    let band = width * th.min(height) * src.desc().bytes_per_texel() as u64;
    if band > limits.max_memory_bytes / 4 {
        return Some(Err(PrepError::ImageTooLarge {
            path: path.into(),
            width,
            height,
            mib: (band * 4).div_ceil(1 << 20),
            limit_mib: limits.max_memory_bytes >> 20,
        }));
    }
    Some(Ok(OpenedImage {
        width,
        height,
        streamed: true,
        bits: if f.ctype == ComponentType::U16 { 16 } else { 8 },
        samples: f.components.count(),
        reduce_depth: false,
        georef: Ok(None),
        path: path.into(),
        opener: Opener::Cog(Box::new(src)),
    }))
}

/// Opens an image: TIFF images with a streamable layout are streamed; anything else is decoded
/// into memory if it fits `limits.max_memory_bytes`. A tiled TIFF neither decoder reads (GDAL's
/// default RGB JPEG, stored as YCbCr) is streamed by the COG reader, as `clipmapd` serves it.
pub fn open_image(path: &Path, limits: &Limits) -> Result<OpenedImage, PrepError> {
    let mut image = match open_image_decoded(path, limits) {
        Err(e @ (PrepError::ImageDecode { .. } | PrepError::UnsupportedPixels { .. }))
            if crate::source::cog::is_tiff(path) =>
        {
            open_by_cog_reader(path, limits).unwrap_or(Err(e))
        }
        r => r,
    }?;
    if crate::source::cog::is_tiff(path) {
        image.georef = crate::source::cog::tiff_georef(path).map_err(|e| e.to_string());
    }
    Ok(image)
}

impl OpenedImage {
    /// The georeferencing of the texture this image is level 0 of, `texture` texels a side (the
    /// image at its bottom, padded north and east: `crate::plan::georef::padded_transform`):
    /// `None` without the image's, or for a CRS without an EPSG code (which the `.ct` cannot
    /// record).
    pub(crate) fn texture_georef(&self, texture: [u64; 2]) -> Option<crate::georef::Georef> {
        let g = self.georef.as_ref().ok()?.as_ref()?;
        g.crs().epsg_code()?;
        let t = crate::plan::georef::padded_transform(g.geotransform(), self.height, texture[1]);
        crate::georef::Georef::new(g.crs().clone(), t, texture).ok()
    }

    /// What the prepared pyramid records of the image's georeferencing, in words (a line of the
    /// `.ct`'s description, and `clipprep`'s report).
    pub fn georef_note(&self) -> String {
        match &self.georef {
            Ok(Some(g)) if g.crs().epsg_code().is_some() => format!(
                "Georeferencing: the input's GeoTIFF tags, {} (the `#clipmap georef_` lines; docs/GEOREF.md).",
                g.crs().name()
            ),
            Ok(Some(g)) => format!(
                "Georeferencing: none recorded: the input's CRS ({}) has no EPSG code, which the `.ct` needs (docs/GEOREF.md).",
                g.crs().name()
            ),
            Ok(None) => "Georeferencing: none (the input has no GeoTIFF georeferencing tags; docs/GEOREF.md).".into(),
            Err(e) => format!("Georeferencing: none: the input's GeoTIFF tags could not be read: {e}."),
        }
    }
}

fn open_image_decoded(path: &Path, limits: &Limits) -> Result<OpenedImage, PrepError> {
    let (file, _) = crate::open::regular(path).map_err(|source| PrepError::ImageOpen { path: path.into(), source })?;
    drop(file);
    if let Some(stream) = TiffStream::try_open(path, limits)? {
        let (width, height) = stream.dimensions();
        let (bits, samples) = stream.depth();
        return Ok(OpenedImage {
            width,
            height,
            streamed: true,
            bits,
            samples,
            reduce_depth: false,
            georef: Ok(None),
            path: path.into(),
            opener: Opener::Tiff(path.into()),
        });
    }
    let reader = || -> Result<ImageReader<std::io::BufReader<std::fs::File>>, PrepError> {
        let (file, _) =
            crate::open::regular(path).map_err(|source| PrepError::ImageOpen { path: path.into(), source })?;
        ImageReader::new(std::io::BufReader::new(file))
            .with_guessed_format()
            .map_err(|source| PrepError::ImageOpen { path: path.into(), source })
    };
    let decoder = reader()?.into_decoder().map_err(|e| decode_error(path, e))?;
    let (w, h) = decoder.dimensions();
    // Four samples a pixel at most, of one byte or (16-bit images) two.
    let sample_bytes =
        if decoder.color_type().bytes_per_pixel() > decoder.color_type().channel_count() { 2 } else { 1 };
    drop(decoder);
    let decoded = w as u64 * h as u64 * 4 * sample_bytes;
    if decoded > limits.max_memory_bytes {
        return Err(PrepError::ImageTooLarge {
            path: path.into(),
            width: w as u64,
            height: h as u64,
            mib: decoded.div_ceil(1 << 20),
            limit_mib: limits.max_memory_bytes >> 20,
        });
    }
    check_whole(path, limits)?;
    let mut r = reader()?;
    let mut il = image::Limits::default();
    il.max_alloc = Some(limits.max_memory_bytes.saturating_mul(2));
    r.limits(il);
    let image = r.decode().map_err(|e| decode_error(path, e))?;
    use image::ColorType as C;
    let bits = match image.color() {
        C::L8 | C::La8 | C::Rgb8 | C::Rgba8 => 8,
        C::L16 | C::La16 | C::Rgb16 | C::Rgba16 => 16,
        other => {
            return Err(PrepError::UnsupportedPixels { path: path.into(), found: format!("{other:?}") });
        }
    };
    Ok(OpenedImage {
        width: w as u64,
        height: h as u64,
        streamed: false,
        bits,
        samples: image.color().channel_count() as u32,
        reduce_depth: false,
        georef: Ok(None),
        path: path.into(),
        opener: Opener::Memory(image),
    })
}
