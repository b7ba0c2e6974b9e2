//! Streaming TIFF input: level-0 rows decoded strip by strip (or tile row by tile row), so
//! images far larger than memory can be prepared.
//!
//! Only one row of TIFF chunks is held decoded at a time (chunk height x image width, as 8-bit
//! RGBA, or 16-bit RGBA for 16-bit samples, which are never reduced to 8 bits on the way). Bands
//! are requested bottom-up (Performer's origin is the lower-left corner), which the random
//! access to strips and tiles of a TIFF makes cheap. Layouts this module does not stream
//! (planar, palette, CMYK, float, or a single strip larger than the memory limit) are left to the
//! in-memory decoder.

use super::band::{encode_row, BandSource};
use super::error::PrepError;
use super::Limits;
use crate::height::{HeightError, HeightFormat, NonFinite};
// The one test of "starts like a TIFF" every tool makes.
use crate::source::cog::is_tiff;
use crate::texel::TexelFormat;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use tiff::decoder::{ChunkType, Decoder, DecodingResult};
use tiff::tags::Tag;
use tiff::ColorType;

/// An open TIFF whose rows can be streamed.
pub(crate) struct TiffStream {
    path: PathBuf,
    decoder: Decoder<BufReader<File>>,
    width: u32,
    height: u32,
    samples: usize,
    /// Bits per sample: 8 or 16.
    bits: u32,
    chunk_w: u32,
    chunk_h: u32,
    chunk_type: ChunkType,
    /// Decoded rows `cache_y0 .. cache_y0 + cache_rows`, RGBA8, full width (8-bit samples).
    cache: Vec<u8>,
    /// The same for 16-bit samples, RGBA16.
    cache16: Vec<u16>,
    cache_y0: u32,
    cache_rows: u32,
}

fn err(path: &Path, e: impl std::fmt::Display) -> PrepError {
    PrepError::ImageDecode { path: path.to_path_buf(), message: e.to_string() }
}

impl TiffStream {
    /// Opens `path` if it is a TIFF this module can stream; `Ok(None)` for anything else
    /// (including TIFF layouts left to the in-memory decoder).
    pub(crate) fn try_open(path: &Path, limits: &Limits) -> Result<Option<TiffStream>, PrepError> {
        if !is_tiff(path) {
            return Ok(None);
        }
        let s = Self::open(path)?;
        let chunk_row_bytes = s.chunk_h as u64 * s.width as u64 * 4 * (s.bits as u64 / 8);
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
        let colortype = decoder.colortype().map_err(|e| err(path, e))?;
        let samples = match colortype {
            _ if planar.unwrap_or(1) != 1 => 0,
            ColorType::Gray(8 | 16) => 1,
            ColorType::GrayA(8 | 16) => 2,
            ColorType::RGB(8 | 16) => 3,
            ColorType::RGBA(8 | 16) => 4,
            _ => 0,
        };
        let bits = match colortype {
            ColorType::Gray(16) | ColorType::GrayA(16) | ColorType::RGB(16) | ColorType::RGBA(16) => 16,
            _ => 8,
        };
        let (chunk_w, chunk_h) = decoder.chunk_dimensions();
        let chunk_type = decoder.get_chunk_type();
        Ok(TiffStream {
            path: path.into(),
            decoder,
            width,
            height,
            samples,
            bits,
            chunk_w,
            chunk_h,
            chunk_type,
            cache: Vec::new(),
            cache16: Vec::new(),
            cache_y0: 0,
            cache_rows: 0,
        })
    }

    /// Image size in pixels.
    pub fn dimensions(&self) -> (u64, u64) {
        (self.width as u64, self.height as u64)
    }

    /// Bits per sample (8 or 16) and samples per pixel.
    pub fn depth(&self) -> (u32, u32) {
        (self.bits, self.samples as u32)
    }

    /// A band source for level 0 in `format`, `padded_width` texels wide.
    pub(crate) fn into_source(self, format: TexelFormat, padded_width: u64) -> TiffSource {
        TiffSource { stream: self, format, width: padded_width }
    }

    /// Decodes the row of chunks holding image row `y` into the cache.
    fn load(&mut self, y: u32) -> Result<(), PrepError> {
        let band = y / self.chunk_h;
        let y0 = band * self.chunk_h;
        let rows = self.chunk_h.min(self.height - y0);
        let w = self.width as usize;
        let deep = self.bits == 16;
        self.cache.clear();
        self.cache16.clear();
        if deep {
            self.cache16.resize(rows as usize * w * 4, 0);
        } else {
            self.cache.resize(rows as usize * w * 4, 0);
        }
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
            if deep {
                let sample = |i: usize| -> u16 {
                    match &data {
                        DecodingResult::U16(v) => v[i],
                        DecodingResult::U8(v) => v[i] as u16 * 257,
                        _ => 0,
                    }
                };
                for r in 0..dh.min(rows) as usize {
                    for c in 0..dw as usize {
                        let i = (r * dw as usize + c) * n;
                        let px = match n {
                            1 => [sample(i), sample(i), sample(i), u16::MAX],
                            2 => [sample(i), sample(i), sample(i), sample(i + 1)],
                            3 => [sample(i), sample(i + 1), sample(i + 2), u16::MAX],
                            _ => [sample(i), sample(i + 1), sample(i + 2), sample(i + 3)],
                        };
                        let o = (r * w + x0 + c) * 4;
                        self.cache16[o..o + 4].copy_from_slice(&px);
                    }
                }
                continue;
            }
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
pub(crate) struct TiffSource {
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
            if s.bits == 16 {
                let line = &s.cache16[(y - s.cache_y0) as usize * iw * 4..][..iw * 4];
                encode_row(self.format, true, line.chunks_exact(4).map(|px| [px[0], px[1], px[2], px[3]]), row);
                continue;
            }
            let line = &s.cache[(y - s.cache_y0) as usize * iw * 4..][..iw * 4];
            if self.format == TexelFormat::RGBA8 {
                row[..iw * 4].copy_from_slice(line);
                continue;
            }
            let pixels = line.chunks_exact(4).map(|px| [px[0], px[1], px[2], px[3]].map(u16::from));
            encode_row(self.format, false, pixels, row);
        }
        Ok(())
    }
}

/// The GDAL_NODATA tag (ASCII): the value of a GeoTIFF's pixels without data.
const GDAL_NODATA: u16 = 42113;

/// A single-band elevation TIFF (or GeoTIFF), streamed one row of chunks at a time: 32- or
/// 64-bit float, 8-, 16- or 32-bit signed or unsigned samples, taken as metres. Its GDAL_NODATA
/// tag, when present, names the input's pixels without data.
pub struct HeightTiff {
    path: PathBuf,
    decoder: Decoder<BufReader<File>>,
    width: u32,
    height: u32,
    chunk_w: u32,
    chunk_h: u32,
    chunk_type: ChunkType,
    /// The input's nodata value (GDAL_NODATA), as the samples hold it.
    nodata: Option<f64>,
    /// The sample type, in words (for messages).
    sample: &'static str,
    /// Decoded rows `cache_y0 .. cache_y0 + cache_rows`, full width.
    cache: Vec<f64>,
    cache_y0: u32,
    cache_rows: u32,
}

impl HeightTiff {
    /// Opens a single-band TIFF of heights. Refused, saying what was found and what to do: a
    /// file that is no TIFF, more than one sample a pixel, a sample type that is no number of
    /// metres, an unreadable GDAL_NODATA tag, and a row of chunks over the memory limit.
    pub fn open(path: &Path, limits: &Limits) -> Result<HeightTiff, PrepError> {
        let bad = |message: String| PrepError::HeightInput { path: path.into(), message };
        if !is_tiff(path) {
            let (file, _) =
                crate::open::regular(path).map_err(|source| PrepError::ImageOpen { path: path.into(), source })?;
            drop(file);
            return Err(bad("it is not a TIFF; expected a single-band TIFF or GeoTIFF elevation model (convert it with e.g. gdal_translate -of GTiff)".into()));
        }
        let (file, _) =
            crate::open::regular(path).map_err(|source| PrepError::ImageOpen { path: path.into(), source })?;
        let mut decoder = Decoder::new(BufReader::new(file)).map_err(|e| err(path, e))?;
        let (width, height) = decoder.dimensions().map_err(|e| err(path, e))?;
        let colortype = decoder.colortype().map_err(|e| err(path, e))?;
        let format: Option<Vec<u16>> = decoder.find_tag_unsigned_vec(Tag::SampleFormat).map_err(|e| err(path, e))?;
        let format = format.and_then(|v| v.first().copied()).unwrap_or(1);
        let sample = match (colortype, format) {
            (ColorType::Gray(32), 3) => "32-bit float",
            (ColorType::Gray(64), 3) => "64-bit float",
            (ColorType::Gray(8), 1) => "8-bit unsigned",
            (ColorType::Gray(16), 1) => "16-bit unsigned",
            (ColorType::Gray(32), 1) => "32-bit unsigned",
            (ColorType::Gray(8), 2) => "8-bit signed",
            (ColorType::Gray(16), 2) => "16-bit signed",
            (ColorType::Gray(32), 2) => "32-bit signed",
            (other, f) => {
                return Err(bad(format!(
                    "its pixels are {other:?} with SampleFormat {f}; expected one band of float (SampleFormat 3) or signed or unsigned integer heights (e.g. gdal_translate -b 1 -ot Float32)"
                )))
            }
        };
        let nodata = match decoder.find_tag(Tag::Unknown(GDAL_NODATA)).map_err(|e| err(path, e))? {
            None => None,
            Some(v) => {
                let text = v.into_string().map_err(|e| bad(format!("its GDAL_NODATA tag is not text ({e})")))?;
                let text = text.trim_matches(|c: char| c == '\0' || c.is_whitespace());
                let v = match text.to_ascii_lowercase().as_str() {
                    "nan" | "-nan" => f64::NAN,
                    t => t.parse::<f64>().map_err(|_| {
                        bad(format!(
                            "its GDAL_NODATA tag is '{text}', not a number; expected the value of its pixels without data, e.g. -9999 (set it with gdal_edit.py -a_nodata)"
                        ))
                    })?,
                };
                // As the samples hold it (a float tag of a 32-bit float band, rounded to f32).
                Some(if sample == "32-bit float" { v as f32 as f64 } else { v })
            }
        };
        let (chunk_w, chunk_h) = decoder.chunk_dimensions();
        let chunk_type = decoder.get_chunk_type();
        let row_bytes = chunk_h as u64 * width as u64 * 8;
        if row_bytes > limits.max_memory_bytes / 4 {
            return Err(bad(format!(
                "one row of its {} ({chunk_h} rows of {width} pixels) takes {} MiB decoded, over a quarter of the memory limit of {} MiB; raise --max-memory, or rewrite it in smaller strips or tiles (gdal_translate -co TILED=YES)",
                if chunk_type == ChunkType::Tile { "tiles" } else { "strips" },
                row_bytes.div_ceil(1 << 20),
                limits.max_memory_bytes >> 20
            )));
        }
        Ok(HeightTiff {
            path: path.into(),
            decoder,
            width,
            height,
            chunk_w,
            chunk_h,
            chunk_type,
            nodata,
            sample,
            cache: Vec::new(),
            cache_y0: 0,
            cache_rows: 0,
        })
    }

    /// Image size in pixels.
    pub fn dimensions(&self) -> (u64, u64) {
        (self.width as u64, self.height as u64)
    }

    /// The input's nodata value (its GDAL_NODATA tag), NaN when the tag says `nan`.
    pub fn nodata(&self) -> Option<f64> {
        self.nodata
    }

    /// The sample type in words (`32-bit float`, `16-bit signed`, ...).
    pub fn sample(&self) -> &'static str {
        self.sample
    }

    /// Decodes the row of chunks holding image row `y` into the cache.
    fn load(&mut self, y: u32) -> Result<(), PrepError> {
        let band = y / self.chunk_h;
        let y0 = band * self.chunk_h;
        let rows = self.chunk_h.min(self.height - y0);
        let w = self.width as usize;
        self.cache.clear();
        self.cache.resize(rows as usize * w, 0.0);
        let across = match self.chunk_type {
            ChunkType::Strip => 1,
            ChunkType::Tile => self.width.div_ceil(self.chunk_w),
        };
        for cx in 0..across {
            let index = band * across + cx;
            let (dw, dh) = self.decoder.chunk_data_dimensions(index);
            let data = self.decoder.read_chunk(index).map_err(|e| err(&self.path, e))?;
            let values: Vec<f64> = match data {
                DecodingResult::F32(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::F64(v) => v,
                DecodingResult::U8(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::U16(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::U32(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::I8(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::I16(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::I32(v) => v.into_iter().map(f64::from).collect(),
                _ => return Err(err(&self.path, format!("chunk {index} decodes to samples of another type"))),
            };
            let x0 = (cx * self.chunk_w) as usize;
            let (dw, dh) = (dw as usize, dh.min(rows) as usize);
            if values.len() < dw * dh {
                return Err(err(
                    &self.path,
                    format!("chunk {index} holds {} samples, fewer than its {dw}x{dh}", values.len()),
                ));
            }
            for r in 0..dh {
                self.cache[r * w + x0..r * w + x0 + dw].copy_from_slice(&values[r * dw..(r + 1) * dw]);
            }
        }
        self.cache_y0 = y0;
        self.cache_rows = rows;
        Ok(())
    }

    /// Level 0 in `format`, `padded_width` texels wide: each pixel encoded by
    /// [`HeightFormat::encode_with`], the input's nodata pixels (and the padding) stored as the
    /// format's nodata value.
    pub(crate) fn into_source(
        self,
        format: HeightFormat,
        non_finite: NonFinite,
        padded_width: u64,
    ) -> HeightTiffSource {
        HeightTiffSource { tiff: self, format, non_finite, width: padded_width }
    }
}

/// Level 0 of heights from a streamed TIFF.
pub(crate) struct HeightTiffSource {
    tiff: HeightTiff,
    format: HeightFormat,
    non_finite: NonFinite,
    width: u64,
}

impl HeightTiffSource {
    /// The stored value of the pixel (x, y) holding `v`.
    fn stored(&self, x: usize, y: u32, v: f64) -> Result<f64, PrepError> {
        let pixel = |message: String| PrepError::HeightPixel {
            path: self.tiff.path.clone(),
            x: x as u64,
            y: y as u64,
            message,
        };
        let input_nodata = self.tiff.nodata.is_some_and(|nd| v == nd || (nd.is_nan() && v.is_nan()));
        if input_nodata {
            return self.format.nodata().ok_or_else(|| {
                pixel(format!(
                    "{v} is the input's nodata value (GDAL_NODATA) and the output declares none; pass --height-nodata V (a stored value outside the data) so such pixels stay without data"
                ))
            });
        }
        self.format.encode_with(v, self.non_finite).map_err(|e| {
            let fix = match &e {
                HeightError::NotFinite { .. } if self.format.nodata().is_none() => {
                    "; with clipprep: pass --nan nodata with --height-nodata V to store such pixels as nodata, or fix the input"
                }
                HeightError::NotFinite { .. } => "; with clipprep: pass --nan nodata to store such pixels as nodata, or fix the input",
                HeightError::OutOfRange { .. } => {
                    "; with clipprep: pass a --height-scale and --height-offset whose range covers the data, or --format l32f"
                }
                HeightError::IsNodata { .. } => "; with clipprep: pass a --height-nodata outside the data's range",
                _ => "",
            };
            pixel(format!("{e}{fix}"))
        })
    }
}

impl BandSource for HeightTiffSource {
    fn fill(&mut self, t0: u64, rows: usize, out: &mut [u8]) -> Result<(), PrepError> {
        let bpt = self.format.bytes_per_texel();
        let row_bytes = self.width as usize * bpt;
        let (iw, ih) = (self.tiff.width as usize, self.tiff.height as u64);
        let pad = self.format.nodata().unwrap_or(0.0);
        for i in 0..rows {
            let row = &mut out[i * row_bytes..(i + 1) * row_bytes];
            let t = t0 + i as u64;
            if t >= ih {
                for texel in row.chunks_exact_mut(bpt) {
                    self.format.write(pad, texel);
                }
                continue;
            }
            let y = (ih - 1 - t) as u32;
            let s = &self.tiff;
            if !(s.cache_rows > 0 && y >= s.cache_y0 && y < s.cache_y0 + s.cache_rows) {
                self.tiff.load(y)?;
            }
            let start = (y - self.tiff.cache_y0) as usize * iw;
            for (x, texel) in row.chunks_exact_mut(bpt).enumerate() {
                let v = if x < iw { self.stored(x, y, self.tiff.cache[start + x])? } else { pad };
                self.format.write(v, texel);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::prep::source::open_image;

    #[test]
    fn sixteen_bit_samples_are_streamed_whole() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("in.tif");
        let (w, h) = (8u32, 4u32);
        let v = |x: u32, y: u32, c: u32| (x * 8191 + y * 257 + c * 21_845 + 1) as u16;
        image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_fn(w, h, |x, y| {
            image::Rgb([0, 1, 2].map(|c| v(x, y, c)))
        })
        .save(&path)
        .unwrap();
        let img = open_image(&path, &Limits::default()).unwrap();
        assert_eq!((img.streamed, img.bits, img.samples), (true, 16, 3));
        let mut src = img.into_source(TexelFormat::RGBA16, w as u64).unwrap();
        let mut band = vec![0u8; (w * h * 8) as usize];
        src.fill(0, h as usize, &mut band).unwrap();
        for (i, texel) in band.chunks_exact(8).enumerate() {
            let (s, t) = (i as u32 % w, i as u32 / w);
            let got: Vec<u16> = texel.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
            // Texel (s, t) is pixel (s, h - 1 - t); alpha is opaque.
            let y = h - 1 - t;
            assert_eq!(got, [v(s, y, 0), v(s, y, 1), v(s, y, 2), 65535], "texel ({s}, {t})");
        }
        // The same image into an 8-bit format is refused without the reduction.
        let img = open_image(&path, &Limits::default()).unwrap();
        let e = img.into_source(TexelFormat::RGB8, w as u64).err().expect("refused");
        assert!(matches!(e, PrepError::DeeperThanFormat { bits: 16, .. }), "{e}");
        assert_eq!(e.exit_code(), 1);
    }
}
