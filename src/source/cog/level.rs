//! The level types every stage of a COG shares: a level served from an image of the file
//! ([`IfdLevel`]: its layout, compression, samples, tile index [`Array`]s and internal mask) or
//! built ([`Level::Built`]), and how a level is described to a user ([`Compression`],
//! [`LevelOrigin`]). Types only: checking an image ([`super::image`]), reading its tile index
//! ([`super::index`]) and describing the source ([`super::info`]) all build on them.

use serde::Serialize;
use std::sync::Arc;

/// How an image's samples are stored (BitsPerSample and SampleFormat).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Samples {
    /// 8-bit unsigned integers.
    U8,
    /// 16-bit unsigned integers.
    U16,
    /// 16-bit signed integers (heights, `l16i`).
    I16,
    /// 32-bit IEEE floats (heights, `l32f`).
    F32,
}

impl Samples {
    /// The BitsPerSample and SampleFormat values, in words.
    pub(super) fn describe(self) -> String {
        let (bits, format) = match self {
            Samples::U8 => (8, "1, unsigned"),
            Samples::U16 => (16, "1, unsigned"),
            Samples::I16 => (16, "2, signed"),
            Samples::F32 => (32, "3, floating point"),
        };
        format!("{bits} bits, sample format {format}")
    }

    /// Bytes of one sample.
    pub(super) fn bytes(self) -> usize {
        match self {
            Samples::U8 => 1,
            Samples::U16 | Samples::I16 => 2,
            Samples::F32 => 4,
        }
    }
}

/// A level served from an image of the file.
#[derive(Clone, Debug)]
pub(super) struct IfdLevel {
    pub(super) ifd: usize,
    pub(super) size: [u64; 2],
    pub(super) tile: [u64; 2],
    pub(super) across: u64,
    pub(super) compression: Compression,
    /// The Predictor tag: 1 none, 2 horizontal differencing, 3 floating point.
    pub(super) predictor: u16,
    /// JPEGTables (347): the quantisation and Huffman tables the tiles' JPEG streams leave out.
    pub(super) jpeg_tables: Option<Arc<[u8]>>,
    /// How a JPEG tile's components become samples (JPEG only; `JpegColour::Raw` otherwise).
    pub(super) jpeg_colour: JpegColour,
    pub(super) samples: Samples,
    /// Samples a pixel.
    pub(super) spp: usize,
    pub(super) offsets: Array,
    pub(super) counts: Array,
    /// The image's internal mask (docs/COG.md, "Masks and nodata"): a colour image's alpha, a
    /// height image's nodata texels.
    pub(super) mask: Option<Arc<MaskLevel>>,
}

impl IfdLevel {
    /// Tile rows of the image.
    pub(super) fn rows(&self) -> u64 {
        self.size[1].div_ceil(self.tile[1])
    }

    /// Bytes of one stored pixel.
    pub(super) fn pixel_bytes(&self) -> usize {
        self.spp * self.samples.bytes()
    }
}

/// How the components of an image's JPEG streams become its samples, as libtiff decodes them
/// for GDAL: YCbCr (PhotometricInterpretation 6) converted to RGB, anything else (grey,
/// PhotometricInterpretation 2 with 3 or 4 samples) taken as stored, without a colour transform.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum JpegColour {
    /// The components are the samples (grey, RGB, RGBA).
    Raw,
    /// Three YCbCr components, converted to RGB.
    YCbCr,
}

/// An internal mask: an IFD of one 1- or 8-bit sample (NewSubfileType 4, or 5 for an
/// overview's), tiled as its image; 0 is a pixel without data.
#[derive(Debug)]
pub(super) struct MaskLevel {
    /// Its tiles (read as 8-bit grey: `spp` 1, `samples` U8).
    pub(super) lv: IfdLevel,
    /// 1-bit samples (8 pixels a byte, the first in the most significant bit, rows padded to a
    /// byte) rather than 8-bit ones.
    pub(super) one_bit: bool,
}

impl MaskLevel {
    /// Bytes of one stored mask tile.
    pub(super) fn tile_bytes(&self) -> usize {
        let [tw, th] = self.lv.tile;
        if self.one_bit {
            tw.div_ceil(8) as usize * th as usize
        } else {
            (tw * th) as usize
        }
    }
}

/// How a colour image gets its alpha (docs/COG.md, "Masks and nodata"): served as the RGBA
/// variant of its format, alpha 0 where its level's mask is 0 or where every colour sample
/// equals `nodata`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct AlphaRule {
    /// The GDAL_NODATA value, as a sample.
    pub(super) nodata: Option<u16>,
}

/// A level: tiles of the file, or texels built from the last usable image (at open for a local
/// file, when first read for a remote object).
#[derive(Clone, Debug)]
pub(super) enum Level {
    Ifd(IfdLevel),
    Built,
}

/// An array of unsigned values in the file (a tile index), read one value at a time.
#[derive(Clone, Copy, Debug)]
pub(super) struct Array {
    pub(super) ty: u16,
    pub(super) size: u64,
    pub(super) count: u64,
    /// The values, when they fit in the entry.
    pub(super) inline: Option<[u8; 8]>,
    /// Where they are, when they do not.
    pub(super) at: u64,
}

/// How tile bytes are compressed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Compression {
    /// Stored as they are (1).
    None,
    /// LZW (5), GDAL's COG default.
    Lzw,
    /// DEFLATE (8 or 32946), zlib-wrapped.
    Deflate,
    /// Zstandard (50000).
    Zstd,
    /// JPEG (7): baseline or progressive, grey or YCbCr (decoded to RGB), the IFD's
    /// JPEGTables (347) spliced before each tile's stream.
    Jpeg,
}

impl std::fmt::Display for Compression {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Compression::None => "uncompressed",
            Compression::Lzw => "LZW",
            Compression::Deflate => "DEFLATE",
            Compression::Zstd => "ZSTD",
            Compression::Jpeg => "JPEG",
        })
    }
}

/// Where a level's texels come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LevelOrigin {
    /// An image of the file: IFD `ifd`, in tiles of `tile` texels, compressed with
    /// `compression`, with a predictor when `predictor` is set (`predictor_tag`: the TIFF
    /// Predictor, 2 horizontal differencing or 3 floating point; 1 none).
    Ifd {
        /// The image's index among the file's IFDs (0: the full resolution).
        ifd: usize,
        /// Its tile size, texels.
        tile: [u64; 2],
        /// Its compression.
        compression: Compression,
        /// Whether its tiles were written with a predictor.
        predictor: bool,
        /// The TIFF Predictor tag: 1 none, 2 horizontal differencing, 3 floating point.
        predictor_tag: u16,
    },
    /// Built at open from level `from` by the 2 x 2 box filter.
    Built {
        /// The level it was halved from.
        from: u32,
    },
}
