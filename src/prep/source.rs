//! Where level texels come from: the procedural sources (per level for `hash`, level 0 for
//! `terrain`) and decoded images, delivered in bands of whole rows.
//!
//! Image convention: Performer's texture origin is the lower-left corner, so level-0 texel
//! (s, t) is image pixel (column s, row H - 1 - t) (image rows run top-down). With padding, the
//! texels beyond the image (s >= width or t >= height) are zero (black, transparent).

use super::error::PrepError;
use super::tiff_stream::TiffStream;
use super::Limits;
use crate::source::procedural::{hash_region, Terrain};
use crate::texel::TexelFormat;
use image::{DynamicImage, GenericImageView, ImageReader};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Produces the rows of one level, band by band, in increasing t.
pub trait BandSource: Send {
    /// Fills rows `t0 .. t0 + rows` (each `width * bpt` bytes, s fastest) into `out`.
    fn fill(&mut self, t0: u64, rows: usize, out: &mut [u8]) -> Result<(), PrepError>;
}

/// The verification texture of one level (DESIGN.md §11).
pub struct HashLevel {
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

/// Level 0 of the terrain texture.
pub struct TerrainLevel0 {
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
        out.par_chunks_mut(row_bytes).enumerate().for_each(|(i, row)| {
            for (s, texel) in row.chunks_exact_mut(bpt).enumerate() {
                self.terrain.texel(0, s as u64, t0 + i as u64, self.format, texel);
            }
        });
        Ok(())
    }
}

/// An image decoded into memory (any format the `image` crate reads).
pub struct MemoryImage {
    image: DynamicImage,
    format: TexelFormat,
    /// Level-0 width (image width, or padded).
    width: u64,
}

impl BandSource for MemoryImage {
    fn fill(&mut self, t0: u64, _rows: usize, out: &mut [u8]) -> Result<(), PrepError> {
        let bpt = self.format.bytes_per_texel() as usize;
        let row_bytes = self.width as usize * bpt;
        let (iw, ih) = self.image.dimensions();
        let image = &self.image;
        let format = self.format;
        out.par_chunks_mut(row_bytes).enumerate().for_each(|(i, row)| {
            let t = t0 + i as u64;
            row.fill(0);
            if t >= ih as u64 {
                return;
            }
            let y = ih - 1 - t as u32;
            for (x, texel) in row.chunks_exact_mut(bpt).take(iw as usize).enumerate() {
                let p = image.get_pixel(x as u32, y).0;
                encode_rgba8(format, p, texel);
            }
        });
        Ok(())
    }
}

/// Encodes an 8-bit RGBA pixel into `format`.
pub fn encode_rgba8(format: TexelFormat, p: [u8; 4], out: &mut [u8]) {
    if format == TexelFormat::RGBA8 {
        out.copy_from_slice(&p);
    } else if format == TexelFormat::RGB8 {
        out.copy_from_slice(&p[..3]);
    } else {
        let f = |v: u8| v as f32 / 255.0;
        format.encode([f(p[0]), f(p[1]), f(p[2]), f(p[3])], out);
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
    opener: Opener,
}

enum Opener {
    Memory(DynamicImage),
    Tiff(PathBuf),
}

impl OpenedImage {
    /// A band source producing level 0 of `padded_width` in `format`.
    pub fn into_source(self, format: TexelFormat, padded_width: u64) -> Result<Box<dyn BandSource>, PrepError> {
        Ok(match self.opener {
            Opener::Memory(image) => Box::new(MemoryImage { image, format, width: padded_width }),
            Opener::Tiff(path) => Box::new(TiffStream::open(&path)?.into_source(format, padded_width)),
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

/// Opens an image: TIFF images with a streamable layout are streamed; anything else is decoded
/// into memory if it fits `limits.max_memory_bytes`.
pub fn open_image(path: &Path, limits: &Limits) -> Result<OpenedImage, PrepError> {
    let (file, _) = crate::open::regular(path).map_err(|source| PrepError::ImageOpen { path: path.into(), source })?;
    drop(file);
    if let Some(stream) = TiffStream::try_open(path, limits)? {
        let (width, height) = stream.dimensions();
        return Ok(OpenedImage { width, height, streamed: true, opener: Opener::Tiff(path.into()) });
    }
    let reader = || -> Result<ImageReader<std::io::BufReader<std::fs::File>>, PrepError> {
        let (file, _) =
            crate::open::regular(path).map_err(|source| PrepError::ImageOpen { path: path.into(), source })?;
        ImageReader::new(std::io::BufReader::new(file))
            .with_guessed_format()
            .map_err(|source| PrepError::ImageOpen { path: path.into(), source })
    };
    let (w, h) = reader()?.into_dimensions().map_err(|e| decode_error(path, e))?;
    let decoded = w as u64 * h as u64 * 4;
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
    match image.color() {
        C::L8 | C::La8 | C::Rgb8 | C::Rgba8 | C::L16 | C::La16 | C::Rgb16 | C::Rgba16 => {}
        other => {
            return Err(PrepError::UnsupportedPixels { path: path.into(), found: format!("{other:?}") });
        }
    }
    Ok(OpenedImage { width: w as u64, height: h as u64, streamed: false, opener: Opener::Memory(image) })
}
