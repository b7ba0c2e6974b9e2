//! Decoding a TIFF tile into texels: its stored bytes (from a span read already, the first
//! bytes, or the range reader) checked against GDAL's leader and trailer, decompressed (none, LZW,
//! DEFLATE, ZSTD, JPEG), the predictor undone and samples made little-endian
//! ([`finish_samples`]), then a mask's nodata heights or an alpha added.

use super::level::{Compression, IfdLevel, JpegColour, MaskLevel};
use super::structure::Span;
use super::CogSource;
use crate::source::range::RangeError;
use crate::source::{SourceError, TileId};
use std::cell::RefCell;

/// The most bytes a reading thread keeps in each of its buffers between reads: a larger one (a
/// tile of tens of MiB) is freed once read, so that an idle thread holds little whatever tiles
/// it read.
pub(super) const KEPT_BUFFER_BYTES: usize = 16 << 20;

/// `buf` back into its thread's slot, or freed when larger than [`KEPT_BUFFER_BYTES`].
pub(super) fn keep(slot: &'static std::thread::LocalKey<RefCell<Vec<u8>>>, buf: Vec<u8>) {
    if buf.capacity() <= KEPT_BUFFER_BYTES {
        slot.with(|c| *c.borrow_mut() = buf);
    }
}

thread_local! {
    /// Each reading thread's buffer for a tile's stored bytes.
    static PACKED: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
    /// Each reading thread's buffer for a whole decoded TIFF tile, when a texture tile is not
    /// one TIFF tile.
    pub(super) static CHUNK: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
    /// Each reading thread's buffer for a TIFF tile's samples before an alpha is added.
    static STORED: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
    /// Each reading thread's buffer for a mask tile (as stored, then one byte a pixel).
    static MASK: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
}

impl CogSource {
    /// The bytes framing a tile of `count` bytes at `offset`: GDAL's leader before it and
    /// trailer after it, when the ghost area says they are there.
    pub(super) fn framing(&self, offset: u64, count: u64) -> (u64, u64) {
        let lead = if self.ghost.leader && offset >= 4 { 4 } else { 0 };
        let trail = if self.ghost.trailer && count >= 4 { 4 } else { 0 };
        (lead, trail)
    }

    /// Decodes TIFF tile `index` of `lv` into `dst` (one whole TIFF tile, rows top-down as
    /// stored), undoing the predictor; its stored bytes come from `span` when it holds them.
    pub(super) fn decode(
        &self,
        lv: &IfdLevel,
        index: u64,
        tile: TileId,
        dst: &mut [u8],
        span: Option<&Span>,
    ) -> Result<(), SourceError> {
        if span.is_none() {
            if let Some(place) = self.guessed_place(lv, index, dst.len() as u64, tile) {
                match self.decode_at(lv, index, tile, dst, span, place) {
                    // The leader, trailer or decoder disagreed, or the guess ran past the end:
                    // the TileByteCounts entry decides.
                    Err(SourceError::Chunk { .. } | SourceError::Short { .. }) => {}
                    r => return r,
                }
            }
        }
        let place = self.tile_place(lv, index, tile)?;
        self.decode_at(lv, index, tile, dst, span, place)
    }

    /// [`CogSource::decode`] with the tile's offset and byte count given.
    pub(super) fn decode_at(
        &self,
        lv: &IfdLevel,
        index: u64,
        tile: TileId,
        dst: &mut [u8],
        span: Option<&Span>,
        (offset, count): (u64, u64),
    ) -> Result<(), SourceError> {
        if offset == 0 || count == 0 {
            return Err(SourceError::Missing { tile });
        }
        let bad = |problem: String| SourceError::Chunk { tile, path: self.path.clone(), problem };
        let need = dst.len() as u64;
        if lv.compression == Compression::None {
            if count < need {
                return Err(bad(format!(
                    "IFD {} tile {index} holds {count} bytes, expected {need} (one uncompressed tile)",
                    lv.ifd
                )));
            }
        } else {
            // The most a tile's compressed bytes can sensibly take.
            let bound = need.saturating_mul(2).saturating_add(4096);
            if count > bound {
                return Err(bad(format!(
                    "IFD {} tile {index} holds {count} bytes, more than a {need}-byte tile compresses to ({bound} at most)",
                    lv.ifd
                )));
            }
        }
        let prefix = Span { start: 0, bytes: &self.prefix };
        let local = !self.bytes.is_remote();
        if lv.compression == Compression::None && local && span.is_none() && prefix.get(offset, need).is_none() {
            // Straight into the slot: no copy on the local path.
            self.bytes.read_at(offset, dst).map_err(|e| e.for_tile(tile, &self.path, offset, need))?;
        } else {
            // An uncompressed tile's bytes are one tile's; a byte count beyond that (which GDAL
            // never writes) is not read, and leaves no framing to check.
            let (stored, (lead, trail)) = match lv.compression {
                Compression::None if count != need => (need, (0, 0)),
                _ => (count, self.framing(offset, count)),
            };
            let count = stored;
            let (from, len) = (offset - lead, lead + count + trail);
            let result = PACKED.with(|cell| {
                let mut buf = cell.borrow_mut();
                // The bytes where they were read already (a row's span, the first bytes), else
                // read into this thread's buffer.
                let packed: &[u8] = match span.and_then(|s| s.get(from, len)).or_else(|| prefix.get(from, len)) {
                    Some(b) => b,
                    None => {
                        // Bytes the file does not hold are not allocated for: a byte count is
                        // bounded by the file's size, not only by the tile's.
                        let size = self.bytes.size();
                        if from.checked_add(len).is_none_or(|end| end > size) {
                            return Err(RangeError::Eof { size }.for_tile(tile, &self.path, from, len));
                        }
                        buf.resize(len as usize, 0);
                        // A tile that starts in the first bytes (read at open) reads only the
                        // rest: no byte is fetched twice.
                        let held = (self.prefix.len() as u64).saturating_sub(from).min(len);
                        if held > 0 {
                            buf[..held as usize].copy_from_slice(&self.prefix[from as usize..(from + held) as usize]);
                        }
                        self.bytes
                            .read_at(from + held, &mut buf[held as usize..])
                            .map_err(|e| e.for_tile(tile, &self.path, from + held, len - held))?;
                        &buf
                    }
                };
                let data_end = (lead + count) as usize;
                if lead == 4 {
                    let said = u32::from_le_bytes([packed[0], packed[1], packed[2], packed[3]]) as u64;
                    if said != count {
                        return Err(bad(format!(
                            "IFD {} tile {index}: the 4 bytes before it (GDAL's BLOCK_LEADER) say {said} bytes, its TileByteCounts entry {count}",
                            lv.ifd
                        )));
                    }
                }
                if trail == 4 && packed[data_end..data_end + 4] != packed[data_end - 4..data_end] {
                    return Err(bad(format!(
                        "IFD {} tile {index}: the 4 bytes after it (GDAL's BLOCK_TRAILER) are not its last 4 bytes",
                        lv.ifd
                    )));
                }
                let data = &packed[lead as usize..data_end];
                if lv.compression == Compression::None {
                    dst.copy_from_slice(&data[..dst.len()]);
                    return Ok(());
                }
                let got = decompress(lv.compression, lv.jpeg_tables.as_deref(), lv.jpeg_colour, lv.tile, data, dst)
                    .map_err(|p| bad(format!("IFD {} tile {index} ({count} bytes at byte {offset}): {p}", lv.ifd)))?;
                if got != dst.len() {
                    return Err(bad(format!(
                        "IFD {} tile {index} ({count} bytes at byte {offset}) decodes to {got} bytes, expected {need}",
                        lv.ifd
                    )));
                }
                Ok(())
            });
            PACKED.with(|cell| {
                let mut buf = cell.borrow_mut();
                if buf.capacity() > KEPT_BUFFER_BYTES {
                    *buf = Vec::new();
                }
            });
            result?;
        }
        finish_samples(lv, self.layout.little, dst);
        Ok(())
    }

    /// Decodes TIFF tile `index` of `lv` as texels of the texture into `dst`: the stored samples
    /// ([`CogSource::decode`]), or for a source with an alpha rule those samples widened to RGBA
    /// with the alpha of its mask tile and nodata ([`add_alpha`]).
    pub(super) fn decode_texels(
        &self,
        lv: &IfdLevel,
        index: u64,
        tile: TileId,
        dst: &mut [u8],
        span: Option<&Span>,
    ) -> Result<(), SourceError> {
        let Some(rule) = self.alpha else {
            self.decode(lv, index, tile, dst, span)?;
            if let (Some(m), Some(plan)) = (&lv.mask, &self.heights) {
                // Heights: nodata where the mask is 0.
                let mut mask = MASK.with(|c| std::mem::take(&mut *c.borrow_mut()));
                let result = self.mask_tile(m, index, tile, &mut mask);
                if result.is_ok() {
                    mask_heights(plan.format, &mask, dst);
                }
                keep(&MASK, mask);
                result?;
            }
            return Ok(());
        };
        let pixels = (lv.tile[0] * lv.tile[1]) as usize;
        let mut stored = STORED.with(|c| std::mem::take(&mut *c.borrow_mut()));
        let mut mask = MASK.with(|c| std::mem::take(&mut *c.borrow_mut()));
        let result = (|| {
            stored.resize(pixels * lv.pixel_bytes(), 0);
            self.decode(lv, index, tile, &mut stored, span)?;
            let m = match &lv.mask {
                Some(m) => {
                    self.mask_tile(m, index, tile, &mut mask)?;
                    Some(&mask[..pixels])
                }
                None => None,
            };
            add_alpha(&stored, lv.spp, lv.samples.bytes(), rule.nodata, m, dst);
            Ok(())
        })();
        keep(&STORED, stored);
        keep(&MASK, mask);
        result
    }

    /// Mask tile `index` of `m` into `out`, one byte a pixel (0: no data); a sparse mask tile is
    /// all 0.
    pub(super) fn mask_tile(
        &self,
        m: &MaskLevel,
        index: u64,
        tile: TileId,
        out: &mut Vec<u8>,
    ) -> Result<(), SourceError> {
        let pixels = (m.lv.tile[0] * m.lv.tile[1]) as usize;
        let stored = m.tile_bytes();
        out.resize(stored + if m.one_bit { pixels } else { 0 }, 0);
        let (packed, unpacked) = out.split_at_mut(stored);
        match self.decode(&m.lv, index, tile, packed, None) {
            Ok(()) => {}
            Err(SourceError::Missing { .. }) => packed.fill(0),
            Err(e) => return Err(e),
        }
        if m.one_bit {
            unpack_bits(packed, m.lv.tile[0] as usize, unpacked);
            out.copy_within(stored.., 0);
            out.truncate(pixels);
        }
        Ok(())
    }
}

/// Widens a decoded TIFF tile's pixels (`spp` samples of `n` bytes, little-endian) to RGBA
/// texels in `dst`: grey replicated, RGB kept, the alpha full (an RGBA image's own), and 0 where
/// `mask` (one byte a pixel) is 0 or every colour sample equals `nodata`. The colour samples are
/// kept as stored, nodata or not.
pub(super) fn add_alpha(stored: &[u8], spp: usize, n: usize, nodata: Option<u16>, mask: Option<&[u8]>, dst: &mut [u8]) {
    let full: u16 = if n == 1 { 255 } else { 65535 };
    for (i, (px, out)) in stored.chunks_exact(spp * n).zip(dst.chunks_exact_mut(4 * n)).enumerate() {
        let get = |k: usize| if n == 1 { px[k] as u16 } else { u16::from_le_bytes([px[2 * k], px[2 * k + 1]]) };
        let colour = if spp >= 3 { [get(0), get(1), get(2)] } else { [get(0); 3] };
        let mut alpha = if spp == 4 { get(3) } else { full };
        if nodata.is_some_and(|v| colour.iter().all(|&c| c == v)) || mask.is_some_and(|m| m[i] == 0) {
            alpha = 0;
        }
        for (k, v) in colour.into_iter().chain([alpha]).enumerate() {
            if n == 1 {
                out[k] = v as u8;
            } else {
                out[2 * k..2 * k + 2].copy_from_slice(&v.to_le_bytes());
            }
        }
    }
}

/// Sets the height texels of a decoded TIFF tile (`dst`, in `format`'s storage) to the
/// format's nodata value where `mask` (one byte a pixel) is 0.
pub(super) fn mask_heights(format: crate::height::HeightFormat, mask: &[u8], dst: &mut [u8]) {
    let Some(nodata) = format.nodata() else { return };
    for (texel, &m) in dst.chunks_exact_mut(format.bytes_per_texel()).zip(mask) {
        if m == 0 {
            format.write(nodata, texel);
        }
    }
}

/// Unpacks a 1-bit mask tile (`w` pixels a row, rows padded to a byte, the first pixel in the
/// most significant bit) into one byte a pixel (0 or 255).
pub(super) fn unpack_bits(packed: &[u8], w: usize, out: &mut [u8]) {
    let row = w.div_ceil(8);
    for (bits, line) in packed.chunks_exact(row).zip(out.chunks_exact_mut(w)) {
        for (x, o) in line.iter_mut().enumerate() {
            *o = if bits[x / 8] & (0x80 >> (x % 8)) != 0 { 255 } else { 0 };
        }
    }
}

/// Turns a decoded TIFF tile's samples into texels: undoes the predictor and stores multi-byte
/// samples little-endian (the texels' byte order), whatever the file's.
pub(super) fn finish_samples(lv: &IfdLevel, little: bool, dst: &mut [u8]) {
    let n = lv.samples.bytes();
    let row_bytes = lv.tile[0] as usize * lv.spp * n;
    if lv.predictor == 3 {
        // TIFF Technical Note 3: each row holds its samples' bytes in planes, most significant
        // plane first, differenced byte by byte across the row with a stride of a pixel. The
        // result does not depend on the file's byte order.
        let mut planes = Vec::with_capacity(row_bytes);
        for row in dst.chunks_exact_mut(row_bytes) {
            for i in lv.spp..row.len() {
                row[i] = row[i].wrapping_add(row[i - lv.spp]);
            }
            planes.clear();
            planes.extend_from_slice(row);
            let count = row.len() / n;
            for (i, sample) in row.chunks_exact_mut(n).enumerate() {
                for (b, byte) in sample.iter_mut().enumerate() {
                    *byte = planes[(n - 1 - b) * count + i];
                }
            }
        }
        return;
    }
    if n > 1 && !little {
        for sample in dst.chunks_exact_mut(n) {
            sample.reverse();
        }
    }
    if lv.predictor == 2 && n == 1 {
        for row in dst.chunks_exact_mut(row_bytes) {
            for i in lv.spp..row.len() {
                row[i] = row[i].wrapping_add(row[i - lv.spp]);
            }
        }
    } else if lv.predictor == 2 {
        let stride = lv.spp * n;
        for row in dst.chunks_exact_mut(row_bytes) {
            for i in (stride..row.len()).step_by(n) {
                let (before, this) = row.split_at_mut(i);
                let prev = &before[i - stride..i - stride + n];
                // A little-endian add of the sample to its left, carries within the sample.
                let mut carry = 0u16;
                for b in 0..n {
                    let sum = this[b] as u16 + prev[b] as u16 + carry;
                    this[b] = sum as u8;
                    carry = sum >> 8;
                }
            }
        }
    }
}

/// Decompresses `packed` into `out`; returns the bytes written (at most `out.len()`).
/// A JPEG tile takes its IFD's tables, how its components become samples and its size in
/// texels (`tile`).
pub(super) fn decompress(
    c: Compression,
    tables: Option<&[u8]>,
    colour: JpegColour,
    tile: [u64; 2],
    packed: &[u8],
    out: &mut [u8],
) -> Result<usize, String> {
    match c {
        Compression::Jpeg => jpeg_tile(tables, colour, tile, packed, out),
        Compression::None => {
            let n = packed.len().min(out.len());
            out[..n].copy_from_slice(&packed[..n]);
            Ok(n)
        }
        Compression::Lzw => crate::source::lzw::decode(packed, out).map_err(|e| format!("not valid LZW data ({e})")),
        Compression::Deflate => {
            // One zlib stream a tile, inflated whole (libdeflate: the decoder GDAL uses).
            match libdeflater::Decompressor::new().zlib_decompress(packed, out) {
                Ok(n) => Ok(n),
                Err(libdeflater::DecompressionError::InsufficientSpace) => {
                    Err(format!("it decodes to more than the {} bytes of one tile", out.len()))
                }
                Err(e) => Err(format!("not valid DEFLATE data ({e})")),
            }
        }
        Compression::Zstd => {
            zstd::bulk::decompress_to_buffer(packed, out).map_err(|e| format!("not a valid zstd frame ({e})"))
        }
    }
}

/// Decodes one JPEG-compressed tile of `tile` texels into `out`: the IFD's tables (without their
/// end marker) then the tile's stream (without its start marker), as libtiff splices them.
/// `JpegColour::YCbCr` converts three YCbCr components to RGB; `JpegColour::Raw` takes the
/// components as they are (grey; RGB or RGBA with PhotometricInterpretation 2), whatever colour
/// space the stream's markers suggest (libtiff decodes such streams with libjpeg's colour space
/// `JCS_UNKNOWN`: no transform). Returns the bytes written.
pub(super) fn jpeg_tile(
    tables: Option<&[u8]>,
    colour: JpegColour,
    tile: [u64; 2],
    packed: &[u8],
    out: &mut [u8],
) -> Result<usize, String> {
    use zune_jpeg::zune_core::{bytestream::ZCursor, colorspace::ColorSpace, options::DecoderOptions};
    const SOI: [u8; 2] = [0xFF, 0xD8];
    const EOI: [u8; 2] = [0xFF, 0xD9];
    if packed.len() < 4 || packed[..2] != SOI {
        return Err(format!(
            "not a JPEG stream: it starts with {:02x?}, expected ff d8",
            &packed[..packed.len().min(2)]
        ));
    }
    let stream: std::borrow::Cow<[u8]> = match tables {
        Some(t) if t.len() >= 4 && t[..2] == SOI && t[t.len() - 2..] == EOI => {
            let mut joined = Vec::with_capacity(t.len() + packed.len());
            joined.extend_from_slice(&t[..t.len() - 2]);
            joined.extend_from_slice(&packed[2..]);
            std::borrow::Cow::Owned(joined)
        }
        Some(t) => {
            return Err(format!(
                "the JPEGTables (347) are not a tables-only JPEG stream ({} bytes, expected ff d8 ... ff d9)",
                t.len()
            ))
        }
        None => std::borrow::Cow::Borrowed(packed),
    };
    let components = (out.len() as u64 / (tile[0] * tile[1]).max(1)) as usize;
    // RGB from YCbCr; for raw components, replaced by the stream's own colour space once its
    // headers are read.
    let space = if components == 1 { ColorSpace::Luma } else { ColorSpace::RGB };
    let options = DecoderOptions::default()
        .jpeg_set_out_colorspace(space)
        .set_max_width(tile[0] as usize)
        .set_max_height(tile[1] as usize);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(&stream[..]), options);
    decoder.decode_headers().map_err(|e| format!("not a valid JPEG stream ({e:?})"))?;
    let (w, h) = decoder.dimensions().unwrap_or((0, 0));
    if [w as u64, h as u64] != tile {
        return Err(format!("its JPEG stream is {w} x {h} pixels, expected the tile's {} x {}", tile[0], tile[1]));
    }
    let found = decoder.info().map_or(0, |i| i.components as usize);
    if found != components {
        return Err(format!(
            "its JPEG stream has {found} components, expected {components} (the IFD's SamplesPerPixel)"
        ));
    }
    if colour == JpegColour::Raw && components > 1 {
        // The decoder names the stream's colour space from its markers (an Adobe APP14 marker,
        // component ids 'R' 'G' 'B', else YCbCr or CMYK); asking for that same space as output
        // copies the components as decoded, with no colour transform.
        let input = decoder.input_colorspace().unwrap_or(ColorSpace::Unknown);
        if input.num_components() != components {
            return Err(format!(
                "its JPEG stream's {components} components are read as {input:?}, expected {components} components taken as stored"
            ));
        }
        decoder.set_options(decoder.options().jpeg_set_out_colorspace(input));
    }
    let need = decoder.output_buffer_size().unwrap_or(0);
    if need != out.len() {
        return Err(format!("its JPEG stream decodes to {need} bytes, expected {} (one tile)", out.len()));
    }
    decoder.decode_into(out).map_err(|e| format!("not a valid JPEG stream ({e:?})"))?;
    Ok(need)
}

#[cfg(test)]
mod tests {
    use super::super::MASK_NODATA_F32;
    use super::*;

    #[test]
    fn masked_heights_become_nodata_and_the_others_stay() {
        use crate::height::{HeightFormat, HeightStorage};
        let i16s = HeightFormat::new(HeightStorage::I16, 1.0, 0.0, Some(-32768.0)).unwrap();
        let mut texels: Vec<u8> = [5i16, -7, 300, 0].iter().flat_map(|v| v.to_le_bytes()).collect();
        mask_heights(i16s, &[255, 0, 1, 0], &mut texels);
        let got: Vec<i16> = texels.chunks_exact(2).map(|b| i16::from_le_bytes([b[0], b[1]])).collect();
        assert_eq!(got, [5, -32768, 300, -32768]);
        let f32s = HeightFormat::float(Some(MASK_NODATA_F32)).unwrap();
        let mut texels: Vec<u8> = [1.5f32, 2.5].iter().flat_map(|v| v.to_le_bytes()).collect();
        mask_heights(f32s, &[0, 255], &mut texels);
        let got: Vec<f32> = texels.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        assert_eq!(got, [f32::MIN, 2.5]);
    }

    #[test]
    fn alpha_is_zero_where_the_mask_is_zero_or_every_colour_sample_is_nodata() {
        // RGB 8-bit: nodata 7 needs all three samples; the mask's 0 clears any pixel.
        let rgb = [7, 7, 7, 7, 7, 8, 1, 2, 3, 9, 9, 9];
        let mut out = [0u8; 16];
        add_alpha(&rgb, 3, 1, Some(7), Some(&[255, 1, 255, 0]), &mut out);
        assert_eq!(out, [7, 7, 7, 0, 7, 7, 8, 255, 1, 2, 3, 255, 9, 9, 9, 0]);
        // Grey 16-bit replicated, the colour kept under nodata.
        let grey = [0x40, 0x9c, 0x01, 0x00];
        let mut out = [0u8; 16];
        add_alpha(&grey, 1, 2, Some(40000), None, &mut out);
        assert_eq!(out, [0x40, 0x9c, 0x40, 0x9c, 0x40, 0x9c, 0, 0, 1, 0, 1, 0, 1, 0, 0xff, 0xff]);
        // RGBA keeps its own alpha, ANDed with the mask.
        let rgba = [1, 2, 3, 100, 4, 5, 6, 200];
        let mut out = [0u8; 8];
        add_alpha(&rgba, 4, 1, None, Some(&[255, 0]), &mut out);
        assert_eq!(out, [1, 2, 3, 100, 4, 5, 6, 0]);
    }

    #[test]
    fn a_one_bit_mask_unpacks_most_significant_bit_first_with_rows_padded_to_a_byte() {
        let mut out = [9u8; 20];
        unpack_bits(&[0b1010_0000, 0b1100_0000, 0b0000_0001, 0b0100_0000], 10, &mut out);
        assert_eq!(out[..10], [255, 0, 255, 0, 0, 0, 0, 0, 255, 255]);
        assert_eq!(out[10..], [0, 0, 0, 0, 0, 0, 0, 255, 0, 255]);
    }

    #[test]
    fn lzw_round_trips_through_the_tiff_variant() {
        let data: Vec<u8> = (0..5000u32).map(|i| (i * 7 % 251) as u8).collect();
        let packed = weezl::encode::Encoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8).encode(&data).unwrap();
        let mut out = vec![0u8; data.len()];
        assert_eq!(decompress(Compression::Lzw, None, JpegColour::Raw, [0, 0], &packed, &mut out), Ok(data.len()));
        assert_eq!(out, data);
        assert!(decompress(Compression::Lzw, None, JpegColour::Raw, [0, 0], &[0xff; 64], &mut out)
            .is_err_and(|e| e.contains("LZW")));
    }
}
