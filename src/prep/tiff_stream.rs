//! Streaming TIFF input: level-0 rows decoded strip by strip (or tile row by tile row), so
//! images far larger than memory can be prepared.
//!
//! Only one row of TIFF chunks is held decoded at a time (chunk height x image width, as 8-bit
//! RGBA). Bands are requested bottom-up (Performer's origin is the lower-left corner), which the
//! random access to strips and tiles of a TIFF makes cheap. Layouts this module does not stream
//! (planar, palette, CMYK, float, or a single strip larger than the memory limit) are left to the
//! in-memory decoder.

use super::error::PrepError;
use super::source::{encode_rgba8, BandSource};
use super::Limits;
use crate::texel::TexelFormat;
use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};
use tiff::decoder::{ChunkType, Decoder, DecodingResult};
use tiff::tags::Tag;
use tiff::ColorType;

/// An open TIFF whose rows can be streamed.
pub struct TiffStream {
    path: PathBuf,
    decoder: Decoder<BufReader<File>>,
    width: u32,
    height: u32,
    samples: usize,
    chunk_w: u32,
    chunk_h: u32,
    chunk_type: ChunkType,
    /// Decoded rows `cache_y0 .. cache_y0 + cache_rows`, RGBA8, full width.
    cache: Vec<u8>,
    cache_y0: u32,
    cache_rows: u32,
}

fn err(path: &Path, e: impl std::fmt::Display) -> PrepError {
    PrepError::ImageDecode { path: path.to_path_buf(), message: e.to_string() }
}

fn is_tiff(path: &Path) -> bool {
    let mut magic = [0u8; 4];
    crate::open::regular(path).and_then(|(mut f, _)| f.read_exact(&mut magic)).is_ok()
        && matches!(&magic, b"II*\0" | b"MM\0*" | b"II+\0" | b"MM\0+")
}

impl TiffStream {
    /// Opens `path` if it is a TIFF this module can stream; `Ok(None)` for anything else
    /// (including TIFF layouts left to the in-memory decoder).
    pub fn try_open(path: &Path, limits: &Limits) -> Result<Option<TiffStream>, PrepError> {
        if !is_tiff(path) {
            return Ok(None);
        }
        let s = Self::open(path)?;
        let chunk_row_bytes = s.chunk_h as u64 * s.width as u64 * 4;
        if s.samples == 0 || chunk_row_bytes > limits.max_memory_bytes / 4 {
            return Ok(None);
        }
        Ok(Some(s))
    }

    /// Opens a TIFF; samples == 0 marks a layout that cannot be streamed.
    pub fn open(path: &Path) -> Result<TiffStream, PrepError> {
        let (file, _) =
            crate::open::regular(path).map_err(|source| PrepError::ImageOpen { path: path.into(), source })?;
        let mut decoder = Decoder::new(BufReader::new(file)).map_err(|e| err(path, e))?;
        let (width, height) = decoder.dimensions().map_err(|e| err(path, e))?;
        let planar: Option<u16> = decoder.find_tag_unsigned(Tag::PlanarConfiguration).map_err(|e| err(path, e))?;
        let samples = match decoder.colortype().map_err(|e| err(path, e))? {
            _ if planar.unwrap_or(1) != 1 => 0,
            ColorType::Gray(8 | 16) => 1,
            ColorType::GrayA(8 | 16) => 2,
            ColorType::RGB(8 | 16) => 3,
            ColorType::RGBA(8 | 16) => 4,
            _ => 0,
        };
        let (chunk_w, chunk_h) = decoder.chunk_dimensions();
        let chunk_type = decoder.get_chunk_type();
        Ok(TiffStream {
            path: path.into(),
            decoder,
            width,
            height,
            samples,
            chunk_w,
            chunk_h,
            chunk_type,
            cache: Vec::new(),
            cache_y0: 0,
            cache_rows: 0,
        })
    }

    /// Image size in pixels.
    pub fn dimensions(&self) -> (u64, u64) {
        (self.width as u64, self.height as u64)
    }

    /// A band source for level 0 in `format`, `padded_width` texels wide.
    pub fn into_source(self, format: TexelFormat, padded_width: u64) -> TiffSource {
        TiffSource { stream: self, format, width: padded_width }
    }

    /// Decodes the row of chunks holding image row `y` into the cache.
    fn load(&mut self, y: u32) -> Result<(), PrepError> {
        let band = y / self.chunk_h;
        let y0 = band * self.chunk_h;
        let rows = self.chunk_h.min(self.height - y0);
        let w = self.width as usize;
        self.cache.clear();
        self.cache.resize(rows as usize * w * 4, 0);
        let across = match self.chunk_type {
            ChunkType::Strip => 1,
            ChunkType::Tile => self.width.div_ceil(self.chunk_w),
        };
        for cx in 0..across {
            let index = band * across + cx;
            let (dw, dh) = self.decoder.chunk_data_dimensions(index);
            let data = self.decoder.read_chunk(index).map_err(|e| err(&self.path, e))?;
            let n = self.samples;
            let x0 = (cx * self.chunk_w) as usize;
            let sample = |i: usize| -> u8 {
                match &data {
                    DecodingResult::U8(v) => v[i],
                    DecodingResult::U16(v) => ((v[i] as u32 * 255 + 32767) / 65535) as u8,
                    _ => 0,
                }
            };
            if let (DecodingResult::U8(v), 4) = (&data, n) {
                // RGBA8 as stored: whole rows at once.
                let len = dw as usize * 4;
                for r in 0..dh.min(rows) as usize {
                    let o = (r * w + x0) * 4;
                    self.cache[o..o + len].copy_from_slice(&v[r * len..(r + 1) * len]);
                }
                continue;
            }
            for r in 0..dh.min(rows) as usize {
                for c in 0..dw as usize {
                    let i = (r * dw as usize + c) * n;
                    let px = match n {
                        1 => [sample(i), sample(i), sample(i), 255],
                        2 => [sample(i), sample(i), sample(i), sample(i + 1)],
                        3 => [sample(i), sample(i + 1), sample(i + 2), 255],
                        _ => [sample(i), sample(i + 1), sample(i + 2), sample(i + 3)],
                    };
                    let o = (r * w + x0 + c) * 4;
                    self.cache[o..o + 4].copy_from_slice(&px);
                }
            }
        }
        self.cache_y0 = y0;
        self.cache_rows = rows;
        Ok(())
    }
}

/// Level 0 from a streamed TIFF.
pub struct TiffSource {
    stream: TiffStream,
    format: TexelFormat,
    width: u64,
}

impl BandSource for TiffSource {
    fn fill(&mut self, t0: u64, rows: usize, out: &mut [u8]) -> Result<(), PrepError> {
        let bpt = self.format.bytes_per_texel() as usize;
        let row_bytes = self.width as usize * bpt;
        let (iw, ih) = (self.stream.width as usize, self.stream.height as u64);
        for i in 0..rows {
            let row = &mut out[i * row_bytes..(i + 1) * row_bytes];
            row.fill(0);
            let t = t0 + i as u64;
            if t >= ih {
                continue;
            }
            let y = (ih - 1 - t) as u32;
            let s = &mut self.stream;
            if !(s.cache_rows > 0 && y >= s.cache_y0 && y < s.cache_y0 + s.cache_rows) {
                s.load(y)?;
            }
            let line = &s.cache[(y - s.cache_y0) as usize * iw * 4..][..iw * 4];
            if self.format == TexelFormat::RGBA8 {
                row[..iw * 4].copy_from_slice(line);
                continue;
            }
            for (texel, px) in row.chunks_exact_mut(bpt).zip(line.chunks_exact(4)) {
                encode_rgba8(self.format, [px[0], px[1], px[2], px[3]], texel);
            }
        }
        Ok(())
    }
}
