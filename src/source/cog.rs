//! [`CogSource`]: a tiled GeoTIFF or Cloud-Optimized GeoTIFF served as it is, with no
//! preparation step: a local file, or (the `remote` feature) an `http(s)://` or `s3://` object
//! read in byte ranges (docs/COG.md).
//!
//! Owns reading a TIFF's header and IFD chain (classic TIFF and BigTIFF, either byte order),
//! checking each image's layout against what is served (refusals name the IFD, the tag, the value
//! found and what is supported), mapping the full-resolution image and its internal overviews to
//! the texture's levels, building the levels coarser than the smallest usable overview once at
//! open, and decoding tiles (none, LZW, DEFLATE, ZSTD; horizontal predictor) into the caller's
//! slot buffer.
//!
//! The bytes come from a `Store`: a local file (positioned reads, an uncompressed tile straight
//! into the slot) or a remote object (`remote::object::Object`: ranged reads, every one checked
//! against the version, ETag or Last-Modified, and size seen at open). Open reads the first
//! [`PREFIX_BYTES`] once and parses the header, GDAL's ghost area and the IFDs from them. The tile
//! index (TileOffsets, TileByteCounts) is never read whole at open: entries in the first bytes are
//! taken from there; a local file reads a tile's two entries with positioned reads; a remote
//! object reads both arrays at once when they fit in [`MAX_INDEX_READ`], else chunks of
//! [`INDEX_CHUNK_BYTES`], kept once read, and takes a tile's byte count from the offsets where
//! GDAL's block leader confirms it (TileByteCounts then is not read). So a COG with millions of tiles opens as fast as a
//! small one, and reads run in parallel. Adjacent TIFF tiles of a row that one texture tile needs
//! are one ranged read of a remote object. GDAL's block leader (the tile's byte count) and
//! trailer (its last 4 bytes again) are checked where the ghost area announces them.
//!
//! Why not the `tiff` crate (which `clipprep` uses to stream GeoTIFFs): its decoder reads every
//! IFD's whole TileOffsets and TileByteCounts arrays when it opens an image, and it reads a tile
//! through `&mut self` (one seek position), so a COG of millions of tiles would cost its whole
//! index at open and every tile read would take a lock. The structure parsed here is small
//! (header, IFD entries). DEFLATE goes to `libdeflater` (libdeflate, the whole-buffer inflater
//! GDAL uses; `flate2` over `zlib-rs` decoded at 0.95 of it) and ZSTD to `zstd`; LZW to our own
//! whole-tile decoder (`lzw.rs` says why not `weezl`).
//!
//! Orientation: as `clipprep` makes a texture of an image, t counts up from the image's bottom
//! row: texel (s, t) of a level is pixel (column s, row H - 1 - t) of its image. A texture tile
//! is the TIFF tile's size; when the image height is a multiple of the TIFF tile height the
//! texture tile (S, T) is exactly TIFF tile (S, rows - 1 - T), decoded straight into the slot and
//! its rows reversed in place. Otherwise (and for pyramid levels, one tile the size of the level)
//! a texture tile straddles two TIFF tile rows, which are decoded into a per-thread buffer and
//! copied.
//!
//! Levels: IFD 0 is level 0; reduced-resolution IFDs (NewSubfileType bit 0) follow in the file
//! largest first, overview i being level i when its size is exactly [`level_size`] of level 0
//! at i. `gdaladdo` rounds overview sizes up (a 100 x 75 image gets a 50 x 38 overview where
//! level 1 is 50 x 37), so the first overview that does not match, and every one after it, is not used:
//! the levels from there on are built at open from the last matching image by the same 2 x 2 box
//! filter `clipprep` uses (`floor((a + b + c + d + 2) / 4)` per component, edges clamped), which
//! is refused when that image has more than [`MAX_BUILT_TEXELS`] texels. Internal masks
//! (NewSubfileType bit 2) give a colour image an alpha and a height image its nodata texels
//! (docs/COG.md, "Masks and nodata"); further pages are skipped.
//!
//! Sparse tiles (offset or byte count 0, as GDAL's `SPARSE_OK` writes them) are
//! [`SourceError::Missing`] when read; a level built at open reads them as zeros (GDAL's value
//! for them), or as nodata heights.
//!
//! The levels past the overviews are built at open for a local file, and when one is first read
//! for a remote object (its open stays one request).

#[cfg(feature = "remote")]
mod reopen;
#[cfg(feature = "remote")]
pub use reopen::{Reopening, RETRY_GAP as REOPEN_GAP};

use super::ahead::{Feed, Piece, Plan, ReadAhead};
use super::{
    check_request, level_count, level_size, DescError, LevelDesc, SourceError, TextureDesc, TileId, TileSource,
};
use crate::place::Place;
use crate::texel::TexelFormat;
use serde::Serialize;
use std::cell::RefCell;
use std::collections::HashMap;
use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use thiserror::Error;

/// The most texels of the image the levels coarser than the smallest usable overview are built
/// from at open (4096 x 4096): it is decoded whole.
pub const MAX_BUILT_TEXELS: u64 = 1 << 24;

/// The most IFDs followed along the chain.
const MAX_IFDS: usize = 64;

/// The most entries one IFD may have.
const MAX_ENTRIES: u64 = 4096;
/// The most bytes of JPEGTables (347) read: four quantisation and four Huffman tables take
/// under 2 KiB; 64 KiB allows anything a writer could mean.
const MAX_JPEG_TABLES: u64 = 64 * 1024;

/// The most bytes of GDAL_METADATA (42112) read: GDAL's XML of a few items per band.
const MAX_GDAL_METADATA: u64 = 256 << 10;

/// What open reads of a TIFF's structure at most, all IFDs together.
const MAX_STRUCTURE_BYTES: u64 = 1 << 20;

/// The first bytes of a TIFF read at open, in one read (one ranged GET of a remote object): a
/// COG written by GDAL has its header, ghost area and every IFD in them, and a small one its tile
/// index too. Structure past them is read where it lies.
pub const PREFIX_BYTES: u64 = 64 << 10;

/// The bytes of a tile index read at once from a remote object, when its entries are first
/// needed (the entries of about a tile row or more).
pub const INDEX_CHUNK_BYTES: u64 = 4096;

/// The most bytes one read of both tile index arrays' chunks of an entry takes (a remote object):
/// the two arrays of an image of up to 32768 tiles (LONG entries) are then read whole at once.
pub const MAX_INDEX_READ: u64 = 256 << 10;

/// The most bytes one ranged read of adjacent tiles of a row takes (a remote object).
const MAX_SPAN_BYTES: u64 = 8 << 20;

/// How many TIFF tiles before and after a tile, in file order, are looked at for reading ahead
/// with it (those announced to be read).
const AHEAD_WINDOW: u64 = 64;

/// Why a file cannot be served as a COG.
#[derive(Debug, Error)]
pub enum CogError {
    /// The file cannot be opened or read.
    #[error("{path}: {source}", path = path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// Not a TIFF.
    #[error("{path}: not a TIFF: it starts with {found}, expected II*\\0 or MM\\0* (TIFF) or II+\\0 or MM\\0+ (BigTIFF)", path = path.display())]
    NotTiff {
        /// The file.
        path: PathBuf,
        /// Its first bytes.
        found: String,
    },
    /// The TIFF structure is damaged.
    #[error("{path}: {at}: {problem}; the file is damaged or truncated: restore it or write it again (gdal_translate -of COG)", path = path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// Where (the header, an IFD, a tag).
        at: String,
        /// What is wrong.
        problem: String,
    },
    /// A layout this source does not serve.
    #[error("{path}: IFD {ifd}: {tag} is {found}: supported: {supported}", path = path.display())]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// The IFD (0 the full-resolution image).
        ifd: usize,
        /// The tag, by name and number.
        tag: &'static str,
        /// The value found.
        found: String,
        /// What is served.
        supported: &'static str,
    },
    /// An overview whose samples are not the full-resolution image's.
    #[error("{path}: IFD {ifd} (an overview): {tag} is {found}, expected the full-resolution image's (IFD 0): {expected}; write the overviews from the same bands (gdaladdo, or gdal_translate -of COG)", path = path.display())]
    Overview {
        /// The file.
        path: PathBuf,
        /// The overview's IFD.
        ifd: usize,
        /// The tag that differs, by name and number.
        tag: &'static str,
        /// The overview's value.
        found: String,
        /// The full-resolution image's.
        expected: String,
    },
    /// Coarser levels that would have to be built from too large an image.
    #[error("{path}: {why}; levels {from} to {last} would be built at open from level {base} ({base_size:?} texels), more than {MAX_BUILT_TEXELS} texels: add overviews whose sizes are level 0's halved and rounded down (gdaladdo, or gdal_translate -of COG from a size that halves evenly)", path = path.display())]
    TooLargeToBuild {
        /// The file.
        path: PathBuf,
        /// Why the overviews stop ("IFD 3 (overview 3) is [125, 88] texels, expected [125, 87]", or
        /// "it has no overviews").
        why: String,
        /// The first level to build.
        from: u32,
        /// The last level.
        last: u32,
        /// The level they would be built from.
        base: u32,
        /// Its size.
        base_size: [u64; 2],
    },
    /// A tile of the image the coarser levels are built from could not be read.
    #[error("{path}: building levels {from}.. at open: {source}", path = path.display())]
    Build {
        /// The file.
        path: PathBuf,
        /// The first level built.
        from: u32,
        /// Why.
        #[source]
        source: SourceError,
    },
    /// An internal mask that does not fit its image, or masks in an order this source does not
    /// read.
    #[error("{path}: IFD {ifd} (a mask{of}): {tag} is {found}, expected {expected}", path = path.display(), of = image.map_or(String::new(), |i| format!(" of IFD {i}")))]
    Mask {
        /// The file.
        path: PathBuf,
        /// The mask's IFD.
        ifd: usize,
        /// Its image's IFD, when it has one.
        image: Option<usize>,
        /// The tag, by name and number.
        tag: &'static str,
        /// The value found.
        found: String,
        /// What was expected.
        expected: String,
    },
    /// A remote object cannot be read, or this build cannot read remote objects.
    #[error("{problem}")]
    Remote {
        /// The object.
        path: PathBuf,
        /// What happened, naming the object.
        problem: String,
    },
    /// The levels do not form a texture the engine serves.
    #[error("{path}: the levels cannot be served: {source}", path = path.display())]
    Desc {
        /// The file.
        path: PathBuf,
        /// What is wrong with them.
        #[source]
        source: DescError,
    },
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
    Ifd { ifd: usize, tile: [u64; 2], compression: Compression, predictor: bool, predictor_tag: u16 },
    /// Built at open from level `from` by the 2 x 2 box filter.
    Built { from: u32 },
}

/// A COG's texture and the origin of each level ([`CogSource::info`]).
#[derive(Clone, Debug, Serialize)]
pub struct CogInfo {
    /// The file.
    pub path: PathBuf,
    /// Level-0 size in texels.
    pub size: [u64; 2],
    /// The clip size it is served with.
    pub clip_size: u64,
    /// The texel format (8-bit samples as stored).
    pub format: TexelFormat,
    /// Every level, finest first.
    pub levels: Vec<CogLevelInfo>,
    /// Why the overviews stop being used before the coarsest level, when levels are built.
    pub built_because: Option<String>,
    /// The levels past the overviews are built when one is first read (a remote object, whose
    /// open reads its structure only), not at open.
    pub built_on_first_read: bool,
    /// Where a colour image's alpha comes from, when it is served with one added (its mask, its
    /// GDAL_NODATA; docs/COG.md, "Masks and nodata"); `null` otherwise.
    pub alpha: Option<String>,
    /// A height image's nodata value and where its nodata texels come from (its GDAL_NODATA,
    /// its internal mask; docs/COG.md, "Masks and nodata"); `null` for colours and for heights
    /// without nodata.
    pub nodata: Option<String>,
}

/// One level of a [`CogInfo`].
#[derive(Clone, Debug, Serialize)]
pub struct CogLevelInfo {
    /// The level.
    pub level: u32,
    /// Its size in texels.
    pub size: [u64; 2],
    /// The tiles it is read in.
    pub tile: [u64; 2],
    /// Where its texels come from.
    pub origin: LevelOrigin,
}

impl CogInfo {
    /// The text `cliptex info` prints.
    pub fn human(&self) -> String {
        use std::fmt::Write;
        let mut out = format!(
            "{}: tiled TIFF served as it is: {} x {} texels, {}, clip size {}\n{:<6} {:<13} {:<13} from\n",
            self.path.display(),
            self.size[0],
            self.size[1],
            self.format,
            self.clip_size,
            "level",
            "size",
            "tile"
        );
        for l in &self.levels {
            let from = match l.origin {
                LevelOrigin::Ifd { ifd, tile, compression, predictor_tag, .. } => format!(
                    "IFD {ifd}, {} x {} tiles, {compression}{}",
                    tile[0],
                    tile[1],
                    match predictor_tag {
                        2 => ", predictor 2",
                        3 => ", predictor 3 (floating point)",
                        _ => "",
                    }
                ),
                LevelOrigin::Built { from } if self.built_on_first_read => {
                    format!("built when first read from level {from} (2 x 2 box)")
                }
                LevelOrigin::Built { from } => format!("built at open from level {from} (2 x 2 box)"),
            };
            let _ = writeln!(
                out,
                "{:<6} {:<13} {:<13} {from}",
                l.level,
                format!("{} x {}", l.size[0], l.size[1]),
                format!("{} x {}", l.tile[0], l.tile[1])
            );
        }
        if let Some(why) = &self.built_because {
            let _ = writeln!(out, "levels are built because {why}");
        }
        if let Some(alpha) = &self.alpha {
            let _ = writeln!(out, "alpha: {alpha}");
        }
        if let Some(nodata) = &self.nodata {
            let _ = writeln!(out, "nodata: {nodata}");
        }
        out
    }
}

/// Byte order and TIFF flavour of a file.
#[derive(Clone, Copy, Debug)]
struct Layout {
    little: bool,
    big: bool,
}

impl Layout {
    fn u16(&self, b: &[u8]) -> u16 {
        let a = [b[0], b[1]];
        if self.little {
            u16::from_le_bytes(a)
        } else {
            u16::from_be_bytes(a)
        }
    }

    fn u32(&self, b: &[u8]) -> u32 {
        let a = [b[0], b[1], b[2], b[3]];
        if self.little {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        }
    }

    fn u64(&self, b: &[u8]) -> u64 {
        let a = [b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]];
        if self.little {
            u64::from_le_bytes(a)
        } else {
            u64::from_be_bytes(a)
        }
    }

    /// An offset-sized field: 4 bytes in TIFF, 8 in BigTIFF.
    fn offset(&self, b: &[u8]) -> u64 {
        if self.big {
            self.u64(b)
        } else {
            self.u32(b) as u64
        }
    }

    /// The value field of an entry: 4 bytes in TIFF, 8 in BigTIFF.
    fn field(&self) -> usize {
        if self.big {
            8
        } else {
            4
        }
    }

    /// An unsigned value of TIFF type `ty` (BYTE, SHORT, LONG, LONG8) from its bytes.
    fn value(&self, ty: u16, b: &[u8]) -> u64 {
        match ty {
            1 => b[0] as u64,
            3 => self.u16(b) as u64,
            4 | 13 => self.u32(b) as u64,
            _ => self.u64(b),
        }
    }
}

/// Bytes of one value of an unsigned integer TIFF type, `None` for other types.
fn unsigned_size(ty: u16) -> Option<u64> {
    match ty {
        1 => Some(1),
        3 => Some(2),
        4 | 13 => Some(4),
        16 | 18 => Some(8),
        _ => None,
    }
}

/// One IFD entry: tag, type, count and its raw value field (the value itself when it fits,
/// else the offset of its values).
#[derive(Clone, Copy, Debug)]
struct Entry {
    tag: u16,
    ty: u16,
    count: u64,
    field: [u8; 8],
}

/// An array of unsigned values in the file (a tile index), read one value at a time.
#[derive(Clone, Copy, Debug)]
struct Array {
    ty: u16,
    size: u64,
    count: u64,
    /// The values, when they fit in the entry.
    inline: Option<[u8; 8]>,
    /// Where they are, when they do not.
    at: u64,
}

/// How an image's samples are stored (BitsPerSample and SampleFormat).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Samples {
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
    fn describe(self) -> String {
        let (bits, format) = match self {
            Samples::U8 => (8, "1, unsigned"),
            Samples::U16 => (16, "1, unsigned"),
            Samples::I16 => (16, "2, signed"),
            Samples::F32 => (32, "3, floating point"),
        };
        format!("{bits} bits, sample format {format}")
    }

    /// Bytes of one sample.
    fn bytes(self) -> usize {
        match self {
            Samples::U8 => 1,
            Samples::U16 | Samples::I16 => 2,
            Samples::F32 => 4,
        }
    }
}

/// A level served from an image of the file.
#[derive(Clone, Debug)]
struct IfdLevel {
    ifd: usize,
    size: [u64; 2],
    tile: [u64; 2],
    across: u64,
    compression: Compression,
    /// The Predictor tag: 1 none, 2 horizontal differencing, 3 floating point.
    predictor: u16,
    /// JPEGTables (347): the quantisation and Huffman tables the tiles' JPEG streams leave out.
    jpeg_tables: Option<Arc<[u8]>>,
    /// How a JPEG tile's components become samples (JPEG only; `JpegColour::Raw` otherwise).
    jpeg_colour: JpegColour,
    samples: Samples,
    /// Samples a pixel.
    spp: usize,
    offsets: Array,
    counts: Array,
    /// The image's internal mask (docs/COG.md, "Masks and nodata"): a colour image's alpha, a
    /// height image's nodata texels.
    mask: Option<Arc<MaskLevel>>,
}

impl IfdLevel {
    /// Tile rows of the image.
    fn rows(&self) -> u64 {
        self.size[1].div_ceil(self.tile[1])
    }

    /// Bytes of one stored pixel.
    fn pixel_bytes(&self) -> usize {
        self.spp * self.samples.bytes()
    }
}

/// How the components of an image's JPEG streams become its samples, as libtiff decodes them
/// for GDAL: YCbCr (PhotometricInterpretation 6) converted to RGB, anything else (grey,
/// PhotometricInterpretation 2 with 3 or 4 samples) taken as stored, without a colour transform.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum JpegColour {
    /// The components are the samples (grey, RGB, RGBA).
    Raw,
    /// Three YCbCr components, converted to RGB.
    YCbCr,
}

/// An internal mask: an IFD of one 1- or 8-bit sample (NewSubfileType 4, or 5 for an
/// overview's), tiled as its image; 0 is a pixel without data.
#[derive(Debug)]
struct MaskLevel {
    /// Its tiles (read as 8-bit grey: `spp` 1, `samples` U8).
    lv: IfdLevel,
    /// 1-bit samples (8 pixels a byte, the first in the most significant bit, rows padded to a
    /// byte) rather than 8-bit ones.
    one_bit: bool,
}

impl MaskLevel {
    /// Bytes of one stored mask tile.
    fn tile_bytes(&self) -> usize {
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
struct AlphaRule {
    /// The GDAL_NODATA value, as a sample.
    nodata: Option<u16>,
}

/// A level: tiles of the file, or texels built from the last usable image (at open for a local
/// file, when first read for a remote object).
#[derive(Clone, Debug)]
enum Level {
    Ifd(IfdLevel),
    Built,
}

/// What an IFD says about its image (the tags this source reads).
struct Image {
    ifd: usize,
    subfile: u64,
    entries: Vec<Entry>,
}

/// What GDAL's ghost area (structural metadata right after the header) says about the tiles'
/// framing: each tile preceded by its byte count (`BLOCK_LEADER=SIZE_AS_UINT4`, 4 bytes,
/// little-endian) and followed by its last 4 bytes again (`BLOCK_TRAILER=LAST_4_BYTES_REPEATED`),
/// unless the file was changed since (`KNOWN_INCOMPATIBLE_EDITION=YES`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Ghost {
    leader: bool,
    trailer: bool,
}

impl Ghost {
    /// The ghost area at `at` of the file's first bytes `prefix`, if there is one.
    fn parse(prefix: &[u8], at: usize) -> Ghost {
        const KEY: &[u8] = b"GDAL_STRUCTURAL_METADATA_SIZE=";
        let Some(rest) = prefix.get(at..).filter(|r| r.starts_with(KEY)) else { return Ghost::default() };
        let digits = &rest[KEY.len()..];
        let n = digits.iter().take_while(|b| b.is_ascii_digit()).count();
        let Some(size) = std::str::from_utf8(&digits[..n]).ok().and_then(|d| d.parse::<usize>().ok()) else {
            return Ghost::default();
        };
        // The size counts the bytes after the first line.
        let Some(line) = rest.iter().position(|&b| b == b'\n') else { return Ghost::default() };
        let text = &rest[(line + 1).min(rest.len())..(line + 1).saturating_add(size).min(rest.len())];
        let has = |s: &[u8]| text.windows(s.len()).any(|w| w == s);
        if has(b"KNOWN_INCOMPATIBLE_EDITION=YES") {
            return Ghost::default();
        }
        Ghost { leader: has(b"BLOCK_LEADER=SIZE_AS_UINT4"), trailer: has(b"BLOCK_TRAILER=LAST_4_BYTES_REPEATED") }
    }
}

/// The most bytes a reading thread keeps in each of its buffers between reads: a larger one (a
/// tile of tens of MiB) is freed once read, so that an idle thread holds little whatever tiles
/// it read.
const KEPT_BUFFER_BYTES: usize = 16 << 20;

/// `buf` back into its thread's slot, or freed when larger than [`KEPT_BUFFER_BYTES`].
fn keep(slot: &'static std::thread::LocalKey<RefCell<Vec<u8>>>, buf: Vec<u8>) {
    if buf.capacity() <= KEPT_BUFFER_BYTES {
        slot.with(|c| *c.borrow_mut() = buf);
    }
}

thread_local! {
    /// Each reading thread's buffer for a tile's stored bytes.
    static PACKED: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
    /// Each reading thread's buffer for a whole decoded TIFF tile, when a texture tile is not
    /// one TIFF tile.
    static CHUNK: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
    /// Each reading thread's buffer for a TIFF tile's samples before an alpha is added.
    static STORED: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
    /// Each reading thread's buffer for a mask tile (as stored, then one byte a pixel).
    static MASK: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
}

/// Where a TIFF's bytes are read from: a local file (positioned reads, straight into the
/// caller's buffer) or a remote object (ranged reads of the version seen at open).
enum Store {
    Local(File),
    /// A whole file's bytes in memory (a growing texture's patch, the fuzz tests).
    Memory(Arc<[u8]>),
    #[cfg(feature = "remote")]
    Remote(super::remote::object::Object),
}

/// Why bytes of a [`Store`] cannot be read.
enum StoreError {
    /// The range runs past the end (of `size` bytes).
    Eof { size: u64 },
    /// A local read failed.
    Io(io::Error),
    /// A remote read failed, or the object changed.
    #[cfg(feature = "remote")]
    Remote(super::remote::object::ObjectError),
}

impl StoreError {
    /// The problem in words, for a read of `len` bytes at `offset`.
    fn problem(&self, offset: u64, len: u64) -> String {
        match self {
            StoreError::Eof { size } => {
                format!("{len} bytes at byte {offset} run past the end of the file ({size} bytes)")
            }
            StoreError::Io(e) => e.to_string(),
            #[cfg(feature = "remote")]
            StoreError::Remote(e) => e.to_string(),
        }
    }

    /// The failure of a read of `len` bytes at `offset` for `tile`.
    #[cfg_attr(not(feature = "remote"), allow(unused_variables))]
    fn for_tile(self, tile: TileId, path: &Path, offset: u64, len: u64) -> SourceError {
        match self {
            StoreError::Eof { size } => {
                SourceError::Short { tile, expected: len, got: size.saturating_sub(offset).min(len) }
            }
            StoreError::Io(e) => super::file::io_error(tile, e),
            #[cfg(feature = "remote")]
            StoreError::Remote(super::remote::object::ObjectError::Read(e)) => super::remote::source_error(tile, e),
            #[cfg(feature = "remote")]
            StoreError::Remote(e) => SourceError::Chunk { tile, path: path.to_path_buf(), problem: e.to_string() },
        }
    }
}

impl Store {
    /// The size of the file now (a remote object's at open).
    fn size(&self) -> u64 {
        match self {
            Store::Local(f) => f.metadata().map(|m| m.len()).unwrap_or(0),
            Store::Memory(b) => b.len() as u64,
            #[cfg(feature = "remote")]
            Store::Remote(o) => o.size(),
        }
    }

    fn is_remote(&self) -> bool {
        !matches!(self, Store::Local(_) | Store::Memory(_))
    }

    /// Fills `buf` from byte `offset`.
    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> Result<(), StoreError> {
        match self {
            Store::Local(f) => {
                // A range past the end (an offset of 2^63 or more included, which the system
                // refuses as an invalid argument) is the file's end, said as such.
                let size = self.size();
                if offset.checked_add(buf.len() as u64).is_none_or(|e| e > size) {
                    return Err(StoreError::Eof { size });
                }
                f.read_exact_at(buf, offset).map_err(|e| {
                    if e.kind() == io::ErrorKind::UnexpectedEof {
                        StoreError::Eof { size: self.size() }
                    } else {
                        StoreError::Io(e)
                    }
                })
            }
            Store::Memory(b) => {
                let range = usize::try_from(offset).ok().and_then(|o| Some(o..o.checked_add(buf.len())?));
                match range.and_then(|r| b.get(r)) {
                    Some(bytes) => {
                        buf.copy_from_slice(bytes);
                        Ok(())
                    }
                    None => Err(StoreError::Eof { size: b.len() as u64 }),
                }
            }
            #[cfg(feature = "remote")]
            Store::Remote(o) => {
                let end = offset.checked_add(buf.len() as u64);
                if end.is_none_or(|e| e > o.size()) {
                    return Err(StoreError::Eof { size: o.size() });
                }
                o.read(offset, buf.len() as u64).map_err(StoreError::Remote)?.copy_to(buf);
                Ok(())
            }
        }
    }

    /// Starts reading bytes `[offset, offset + len)` into `feed`, which it ends when done: a
    /// remote object's one ranged read streamed on the runtime, its bytes handed over as they
    /// arrive, without waiting for it (a local file's read whole, here). A range past the end is
    /// refused at once, and nothing is started.
    fn stream_detached(&self, offset: u64, len: u64, feed: Feed<TileId>) -> Result<(), StoreError> {
        match self {
            #[cfg(feature = "remote")]
            Store::Remote(o) => {
                if offset.checked_add(len).is_none_or(|e| e > o.size()) {
                    return Err(StoreError::Eof { size: o.size() });
                }
                let sink = Arc::new(FeedSink(feed.clone()));
                o.stream_detached(offset, len, sink, move |result| {
                    if let Err(e) = result {
                        // Its tiles are read on their own, each reporting what goes wrong.
                        tracing::debug!("a merged read of {len} bytes at byte {offset} failed: {e}");
                    }
                    feed.end();
                });
                Ok(())
            }
            _ => {
                let bytes = self.read_bytes(offset, len)?;
                feed.push(&bytes);
                feed.end();
                Ok(())
            }
        }
    }

    /// Bytes `[offset, offset + len)` in one piece (one ranged read of a remote object).
    fn read_bytes(&self, offset: u64, len: u64) -> Result<Shared, StoreError> {
        match self {
            #[cfg(feature = "remote")]
            Store::Remote(o) => {
                if offset.checked_add(len).is_none_or(|e| e > o.size()) {
                    return Err(StoreError::Eof { size: o.size() });
                }
                let segments = o.read(offset, len).map_err(StoreError::Remote)?;
                let mut v = vec![0u8; segments.len()];
                segments.copy_to(&mut v);
                Ok(Arc::new(v))
            }
            _ => {
                let size = self.size();
                if offset.checked_add(len).is_none_or(|e| e > size) {
                    return Err(StoreError::Eof { size });
                }
                let mut v = vec![0u8; len as usize];
                self.read_exact_at(&mut v, offset)?;
                Ok(Arc::new(v))
            }
        }
    }
}

/// Bytes shared between readers, read into their buffer once (without the `bytes` crate, which
/// only the `remote` feature brings).
type Shared = Arc<Vec<u8>>;

/// A remote answer's bytes handed to the tiles of a merged request as they arrive.
#[cfg(feature = "remote")]
struct FeedSink(Feed<TileId>);

#[cfg(feature = "remote")]
impl super::remote::Sink for FeedSink {
    fn head(&self, _: Option<u64>, _: Option<&str>) -> Result<(), String> {
        // The object's version is checked by the object (`Object::stream`).
        Ok(())
    }

    fn bytes(&self, bytes: bytes::Bytes) {
        self.0.push(&bytes);
    }
}

/// A run of a file's bytes read at once: `bytes` from byte `start`.
struct Span<'a> {
    start: u64,
    bytes: &'a [u8],
}

impl Span<'_> {
    /// Bytes `[offset, offset + len)` when the span holds them all.
    fn get(&self, offset: u64, len: u64) -> Option<&[u8]> {
        let from = offset.checked_sub(self.start)?;
        let to = from.checked_add(len)?;
        self.bytes.get(from as usize..usize::try_from(to).ok()?)
    }
}

/// The structure reader at open: the first bytes, then the store.
struct Head<'a> {
    store: &'a Store,
    prefix: &'a [u8],
    /// The first read that failed for another reason than the file's end (a remote object that
    /// could not be read, or changed): open says so rather than calling the file damaged.
    failed: RefCell<Option<String>>,
    /// Runs of bytes past the prefix read so far ([`STRUCTURE_WINDOW`] at least each), so that
    /// an IFD past the first bytes costs one read, not one for its count and one for its entries.
    windows: RefCell<Vec<(u64, Vec<u8>)>>,
}

/// The least a read of structure past the first bytes takes (one request of a remote object).
const STRUCTURE_WINDOW: u64 = 16 << 10;

impl Head<'_> {
    /// `len` bytes at `offset`, or what is wrong (where, what).
    fn read_at(&self, offset: u64, len: usize, what: &str) -> Result<Vec<u8>, (String, String)> {
        if let Some(b) = (Span { start: 0, bytes: self.prefix }).get(offset, len as u64) {
            return Ok(b.to_vec());
        }
        for (start, bytes) in self.windows.borrow().iter() {
            if let Some(b) = (Span { start: *start, bytes }).get(offset, len as u64) {
                return Ok(b.to_vec());
            }
        }
        // At least a window, not past the end of the file (a short read there is the error).
        let size = self.store.size();
        let wide = (len as u64).max(STRUCTURE_WINDOW.min(size.saturating_sub(offset)));
        let mut buf = vec![0u8; wide as usize];
        self.store.read_exact_at(&mut buf, offset).map_err(|e| {
            let problem = e.problem(offset, len as u64);
            if !matches!(e, StoreError::Eof { .. }) {
                self.failed.borrow_mut().get_or_insert_with(|| problem.clone());
            }
            (what.to_string(), problem)
        })?;
        let out = buf[..len].to_vec();
        self.windows.borrow_mut().push((offset, buf));
        Ok(out)
    }
}

/// A local tiled GeoTIFF or COG, or a remote one, served as a clip texture.
pub struct CogSource {
    path: PathBuf,
    store: Store,
    /// The file's first bytes ([`PREFIX_BYTES`] at most), kept: index entries and tiles in them
    /// are read from here.
    prefix: Vec<u8>,
    layout: Layout,
    ghost: Ghost,
    desc: TextureDesc,
    levels: Vec<Level>,
    origins: Vec<LevelOrigin>,
    built_because: Option<String>,
    /// Tile index chunks read so far (remote objects), by array offset and chunk number.
    index: Mutex<HashMap<(u64, u64), Shared>>,
    /// Read index entries in chunks (set for remote objects; tests set it for a local file).
    chunked: bool,
    /// The levels built from the last usable image, once built.
    built: Mutex<Option<Arc<Vec<Vec<u8>>>>>,
    /// Whether the texels are heights (16-bit signed or 32-bit float samples), with the nodata
    /// value of the GDAL_NODATA tag (or, for an image with an internal mask and none, the one
    /// [`heights_of`] chooses), served where the mask is 0.
    heights: Option<crate::plan::HeightPlan>,
    /// The tiles announced to be read, and the merged requests that read several at once
    /// (remote objects).
    ahead: ReadAhead<TileId>,
    /// A colour image with a mask or GDAL_NODATA: its texels get an alpha (`None`: texels are
    /// the stored samples).
    alpha: Option<AlphaRule>,
    /// A height image's nodata value and where its nodata texels come from, for `cliptex info`.
    height_nodata: Option<String>,
}

impl std::fmt::Debug for CogSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CogSource").field("path", &self.path).field("desc", &self.desc).finish_non_exhaustive()
    }
}

/// Whether `path` is a file that starts like a TIFF or BigTIFF (unreadable files are not).
pub fn is_tiff(path: &Path) -> bool {
    let mut magic = [0u8; 4];
    crate::open::regular(path).and_then(|(f, _)| f.read_exact_at(&mut magic, 0)).is_ok()
        && matches!(&magic, b"II*\0" | b"MM\0*" | b"II+\0" | b"MM\0+")
}

/// Whether `place` is served as a TIFF: a local file that starts like one ([`is_tiff`]), or a
/// remote name ending in `.tif` or `.tiff` (any case; nothing is read to tell).
pub fn is_tiff_place(place: &Place) -> bool {
    match place {
        Place::Local(p) => is_tiff(p),
        Place::Remote(r) => {
            r.extension().is_some_and(|e| e.eq_ignore_ascii_case("tif") || e.eq_ignore_ascii_case("tiff"))
        }
    }
}

impl CogSource {
    /// Opens the tiled TIFF `path` as a texture of clip size `clip_size`: reads its header and
    /// IFDs, checks every image used, and builds the levels coarser than the smallest usable
    /// overview.
    pub fn open(path: &Path, clip_size: u64) -> Result<Self, CogError> {
        let io_err = |source| CogError::Io { path: path.to_path_buf(), source };
        let (file, _) = crate::open::regular(path).map_err(io_err)?;
        let mut prefix = vec![0u8; PREFIX_BYTES as usize];
        let got = read_prefix(&file, &mut prefix).map_err(io_err)?;
        prefix.truncate(got);
        let src = CogSource::from_store(path.to_path_buf(), Store::Local(file), prefix, clip_size, true)?;
        src.built_levels(None).map_err(|source| CogError::Build {
            path: path.to_path_buf(),
            from: src.levels.iter().filter(|l| matches!(l, Level::Ifd(_))).count() as u32,
            source,
        })?;
        Ok(src)
    }

    /// Opens the local TIFF `path` to read its full-resolution image only, with
    /// [`CogSource::read_full_resolution`] (`clipprep --input` and a growing texture's patches
    /// take TIFFs through it where the `image` crate's decoder does not read them, e.g. GDAL's
    /// YCbCr JPEG): the same checks as [`CogSource::open`], but nothing is built past the
    /// overviews, and an image without overviews is not refused for its size.
    pub fn open_full_resolution(path: &Path) -> Result<Self, CogError> {
        let io_err = |source| CogError::Io { path: path.to_path_buf(), source };
        let (file, _) = crate::open::regular(path).map_err(io_err)?;
        let mut prefix = vec![0u8; PREFIX_BYTES as usize];
        let got = read_prefix(&file, &mut prefix).map_err(io_err)?;
        prefix.truncate(got);
        CogSource::from_store(path.to_path_buf(), Store::Local(file), prefix, super::MAX_TEXTURE_SIZE, false)
    }

    /// [`CogSource::open_full_resolution`] of a TIFF's bytes (`name` names it in errors): a
    /// growing texture's patch, or bytes under test.
    pub fn from_bytes_full_resolution(name: &Path, bytes: Arc<[u8]>) -> Result<Self, CogError> {
        let prefix = bytes[..bytes.len().min(PREFIX_BYTES as usize)].to_vec();
        CogSource::from_store(name.to_path_buf(), Store::Memory(bytes), prefix, super::MAX_TEXTURE_SIZE, false)
    }

    /// [`CogSource::open`] of a TIFF's bytes (`name` names it in errors), served at clip size
    /// `clip_size`: the levels past the overviews are built here.
    pub fn from_bytes(name: &Path, bytes: Arc<[u8]>, clip_size: u64) -> Result<Self, CogError> {
        let prefix = bytes[..bytes.len().min(PREFIX_BYTES as usize)].to_vec();
        let src = CogSource::from_store(name.to_path_buf(), Store::Memory(bytes), prefix, clip_size, true)?;
        src.built_levels(None).map_err(|source| CogError::Build {
            path: name.to_path_buf(),
            from: src.levels.iter().filter(|l| matches!(l, Level::Ifd(_))).count() as u32,
            source,
        })?;
        Ok(src)
    }

    /// Texels `[s0, s0 + w) x [t0, t0 + h)` of level 0 in the texture's format (rows in
    /// increasing t, `w` texels each) into `out`; sparse TIFF tiles read as GDAL reads them
    /// (zeros, or nodata heights).
    pub fn read_full_resolution(
        &self,
        [s0, t0]: [u64; 2],
        [w, h]: [u64; 2],
        out: &mut [u8],
    ) -> Result<(), SourceError> {
        let Some(Level::Ifd(lv)) = self.levels.first() else { return Ok(()) };
        let size = lv.size;
        if w == 0 || h == 0 || s0 + w > size[0] || t0 + h > size[1] {
            return Err(SourceError::Chunk {
                tile: TileId::new(0, 0, 0),
                path: self.path.clone(),
                problem: format!(
                    "texels [{s0}, {}) x [{t0}, {}) asked for, outside level 0's {size:?}",
                    s0 + w,
                    t0 + h
                ),
            });
        }
        let need = (w * h) as usize * self.desc.bytes_per_texel();
        if out.len() < need {
            return Err(SourceError::BufferSize { tile: TileId::new(0, 0, 0), expected: need, found: out.len() });
        }
        self.fill_region(lv, TileId::new(0, 0, 0), [s0, t0], [w, h], out, w as usize, true)
    }

    /// Opens `place`: a local file ([`CogSource::open`]) or a remote object read with the
    /// remote options of the environment (`CLIPMAP_REMOTE_*`, docs/CONFIG.md §15).
    pub fn open_place(place: &Place, clip_size: u64) -> Result<Self, CogError> {
        match place {
            Place::Local(p) => CogSource::open(p, clip_size),
            #[cfg(feature = "remote")]
            Place::Remote(name) => {
                use super::remote::{Remote, RemoteOptions};
                let path = PathBuf::from(crate::place::redacted(name.as_str()).as_ref());
                let remote_err = |problem: String| CogError::Remote { path: path.clone(), problem };
                let opts = RemoteOptions::from_env().map_err(|e| remote_err(e.to_string()))?;
                // COG ranges are not kept in the disk cache (docs/COG.md): none is opened.
                let opts = RemoteOptions { cache_dir: None, ..opts };
                let remote = Remote::new(opts).map_err(|e| remote_err(e.to_string()))?;
                CogSource::open_remote(name, Arc::new(remote), clip_size)
            }
            #[cfg(not(feature = "remote"))]
            Place::Remote(name) => Err(CogError::Remote {
                path: PathBuf::from(name.as_str()),
                problem: format!(
                    "{name}: this build reads no remote objects: build it with the `remote` feature, or copy the file here"
                ),
            }),
        }
    }

    /// Opens `place` to be served by a long-running reader (the service): a local file as
    /// [`CogSource::open`] does, a remote object through [`Reopening`], which opens it again
    /// when it is replaced in its store.
    pub fn open_served(place: &Place, clip_size: u64) -> Result<Arc<dyn super::TileSource>, CogError> {
        match place {
            Place::Local(_) => Ok(Arc::new(CogSource::open_place(place, clip_size)?)),
            #[cfg(feature = "remote")]
            Place::Remote(name) => {
                let first = CogSource::open_place(place, clip_size)?;
                Ok(Arc::new(Reopening::from_first(name, first, clip_size)))
            }
            #[cfg(not(feature = "remote"))]
            Place::Remote(_) => Ok(Arc::new(CogSource::open_place(place, clip_size)?)),
        }
    }

    /// Opens the remote object `name` through `remote` with one ranged read of its first
    /// [`PREFIX_BYTES`] (more only for structure that lies past them); the tile index is read
    /// in chunks as tiles are first read, and the levels past the overviews are built when one
    /// is first read.
    #[cfg(feature = "remote")]
    pub fn open_remote(
        name: &crate::place::RemoteName,
        remote: Arc<super::remote::Remote>,
        clip_size: u64,
    ) -> Result<Self, CogError> {
        use super::remote::object::Object;
        let path = PathBuf::from(crate::place::redacted(name.as_str()).as_ref());
        let (object, prefix) = Object::open(remote, name, PREFIX_BYTES)
            .map_err(|e| CogError::Remote { path: path.clone(), problem: e.to_string() })?;
        let mut src = CogSource::from_store(path, Store::Remote(object), prefix.to_vec(), clip_size, true)?;
        src.chunked = true;
        Ok(src)
    }

    /// The source of `store`; with `build` false the levels past the overviews are never built
    /// (only level 0 is read: [`CogSource::open_full_resolution`]), and an image too large to
    /// build them from is not refused.
    fn from_store(path: PathBuf, store: Store, prefix: Vec<u8>, clip_size: u64, build: bool) -> Result<Self, CogError> {
        let malformed = |(at, problem): (String, String)| CogError::Malformed { path: path.clone(), at, problem };
        let head = &prefix[..prefix.len().min(16)];
        let got = head.len();
        let layout = match &head[..4.min(got)] {
            b"II*\0" => Layout { little: true, big: false },
            b"MM\0*" => Layout { little: false, big: false },
            b"II+\0" => Layout { little: true, big: true },
            b"MM\0+" => Layout { little: false, big: true },
            other => return Err(CogError::NotTiff { path: path.clone(), found: format!("{other:02x?}") }),
        };
        if layout.big && got < 16 || !layout.big && got < 8 {
            return Err(malformed(("the header".into(), format!("the file has only {got} bytes"))));
        }
        if layout.big && (layout.u16(&head[4..]) != 8 || layout.u16(&head[6..]) != 0) {
            return Err(malformed((
                "the BigTIFF header".into(),
                format!(
                    "offset size {} and {} found, expected 8 and 0",
                    layout.u16(&head[4..]),
                    layout.u16(&head[6..])
                ),
            )));
        }
        let first = if layout.big { layout.u64(&head[8..]) } else { layout.u32(&head[4..]) as u64 };
        let ghost = Ghost::parse(&prefix, if layout.big { 16 } else { 8 });
        let reader =
            Head { store: &store, prefix: &prefix, failed: RefCell::new(None), windows: RefCell::new(Vec::new()) };
        let (mut nodata, mut meta) = (None, BandMeta::default());
        let parts = read_ifds(&reader, layout, first).map_err(malformed).and_then(|images| {
            nodata = ascii(&reader, layout, &images[0], 42113, "GDAL_NODATA (42113)", 64).map_err(malformed)?;
            let xml = ascii(&reader, layout, &images[0], 42112, "GDAL_METADATA (42112)", MAX_GDAL_METADATA)
                .map_err(malformed)?;
            if let Some(xml) = xml {
                meta = BandMeta::parse(&xml).map_err(|problem| CogError::Malformed {
                    path: path.clone(),
                    at: "IFD 0 tag GDAL_METADATA (42112)".into(),
                    problem,
                })?;
            }
            CogSource::levels_of(&path, &reader, layout, images, clip_size, build)
        });
        let parts = match (parts, reader.failed.take()) {
            (Ok(p), _) => p,
            (Err(_), Some(problem)) => {
                return Err(CogError::Remote {
                    path: path.clone(),
                    problem: format!("reading its structure: {problem}"),
                })
            }
            (Err(e), None) => return Err(e),
        };
        let (desc, levels, origins, built_because) = parts;
        let stored = desc.format();
        let masked = matches!(levels.first(), Some(Level::Ifd(l)) if l.mask.is_some());
        let heights = heights_of(&path, stored, nodata.as_deref(), masked, &meta)?;
        let height_nodata = heights.and_then(|p| p.format.nodata()).map(|v| {
            // -3.4028234663852886e38 rather than its 39 digits.
            let v = if v.abs() >= 1e16 { format!("{v:e}") } else { v.to_string() };
            let tagged = nodata.as_deref().is_some_and(|t| t.parse::<f64>().is_ok_and(|x| !x.is_nan()));
            match (&levels[0], tagged) {
                (Level::Ifd(IfdLevel { mask: Some(m), .. }), true) => format!(
                    "{v} (GDAL_NODATA), also where the internal mask is 0 (IFD {} for level 0)",
                    m.lv.ifd
                ),
                (Level::Ifd(IfdLevel { mask: Some(m), .. }), false) => format!(
                    "{v} where the internal mask is 0 (IFD {} for level 0; the {} value of the samples, chosen because the file has no GDAL_NODATA value{})",
                    m.lv.ifd,
                    if stored == TexelFormat::L32F { "least finite" } else { "least" },
                    if nodata.is_some() { " other than nan" } else { "" }
                ),
                _ => format!("{v} (GDAL_NODATA)"),
            }
        });
        let alpha = match heights {
            Some(_) => None,
            None => alpha_of(&path, stored, nodata.as_deref(), &levels)?,
        };
        let served_format = if alpha.is_some() { rgba_of(stored) } else { stored };
        // A TIFF tile is decoded into buffers of the texels served (an alpha added widens grey
        // and RGB to RGBA), one set a reading thread: bound those, not the stored samples.
        for level in &levels {
            let Level::Ifd(lv) = level else { continue };
            let [tw, th] = lv.tile;
            let served = tw.saturating_mul(th).saturating_mul(served_format.bytes_per_texel() as u64);
            let stored_bytes = tw.saturating_mul(th).saturating_mul(lv.pixel_bytes() as u64);
            if served > crate::limits::MAX_TILE_BYTES {
                return Err(CogError::Unsupported {
                    path: path.clone(),
                    ifd: lv.ifd,
                    tag: "TileWidth (322) x TileLength (323)",
                    found: format!(
                        "{tw} x {th} ({stored_bytes} bytes a tile as stored, {served} served as {})",
                        served_format
                    ),
                    supported: "tiles of at most MAX_TILE_BYTES (268435456) bytes as served (an alpha added makes grey and RGB RGBA): write smaller tiles (gdal_translate -co BLOCKSIZE=512, or -co BLOCKXSIZE= -co BLOCKYSIZE=)",
                });
            }
        }
        let desc = match alpha {
            Some(_) => {
                desc.with_format(rgba_of(stored)).map_err(|source| CogError::Desc { path: path.clone(), source })?
            }
            None => desc,
        };
        Ok(CogSource {
            path,
            store,
            prefix,
            layout,
            ghost,
            desc,
            levels,
            origins,
            built_because,
            index: Mutex::new(HashMap::new()),
            chunked: false,
            built: Mutex::new(None),
            heights,
            ahead: ReadAhead::default(),
            alpha,
            height_nodata,
        })
    }

    /// The file served.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether a read was refused because the remote object is no longer the version opened
    /// (false for a local file, which is read through the handle opened, whatever its name
    /// points at since): [`Reopening`] then opens it again.
    pub fn object_changed(&self) -> bool {
        match &self.store {
            Store::Local(_) | Store::Memory(_) => false,
            #[cfg(feature = "remote")]
            Store::Remote(o) => o.has_changed(),
        }
    }

    /// Where each level's texels come from, level 0 first.
    pub fn origins(&self) -> &[LevelOrigin] {
        &self.origins
    }

    /// The texture served and where each level comes from, for `cliptex info`.
    pub fn info(&self) -> CogInfo {
        let levels = (0..self.desc.level_count())
            .map(|k| {
                let l = self.desc.level(k as u32);
                CogLevelInfo { level: k as u32, size: l.size, tile: l.tile, origin: self.origins[k] }
            })
            .collect();
        CogInfo {
            path: self.path.clone(),
            size: self.desc.size(),
            clip_size: self.desc.clip_size(),
            format: self.desc.format(),
            levels,
            built_because: self.built_because.clone(),
            built_on_first_read: self.store.is_remote(),
            alpha: self.alpha.map(|rule| {
                let mut zero = Vec::new();
                if let Some(Level::Ifd(IfdLevel { mask: Some(m), .. })) = self.levels.first() {
                    zero.push(format!("the internal mask is 0 (IFD {} for level 0)", m.lv.ifd));
                }
                if let Some(v) = rule.nodata {
                    zero.push(format!("every colour sample is GDAL_NODATA {v}"));
                }
                format!("0 where {}, else full; colour samples as stored", zero.join(" or "))
            }),
            nodata: self.height_nodata.clone(),
        }
    }

    #[allow(clippy::type_complexity)]
    fn levels_of(
        path: &Path,
        head: &Head,
        layout: Layout,
        images: Vec<Image>,
        clip_size: u64,
        build: bool,
    ) -> Result<(TextureDesc, Vec<Level>, Vec<LevelOrigin>, Option<String>), CogError> {
        let full = &images[0];
        let (format, mut level0) = image_level(path, head, layout, full)?;
        let size = level0.size;
        let n = level_count(size);
        // The masks: one of the full-resolution image (NewSubfileType 4), then one for each
        // overview (5), in the overviews' order (a colour image's become its alpha, a height
        // image's its nodata texels).
        let full_masks: Vec<&Image> = images.iter().skip(1).filter(|i| i.subfile & 5 == 4).collect();
        let mut overview_masks = images.iter().skip(1).filter(|i| i.subfile & 5 == 5);
        let order = |ifd: usize, found: String, expected: &str| CogError::Mask {
            path: path.to_path_buf(),
            ifd,
            image: None,
            tag: "NewSubfileType (254)",
            found,
            expected: expected.into(),
        };
        if let Some(second) = full_masks.get(1) {
            return Err(order(
                second.ifd,
                format!("4 (a mask of the full-resolution image) after IFD {}'s", full_masks[0].ifd),
                "one mask of the full-resolution image",
            ));
        }
        match full_masks.first() {
            Some(m) => level0.mask = Some(mask_level(path, head, layout, m, &level0)?),
            None => {
                if let Some(m) = images.iter().skip(1).find(|i| i.subfile & 5 == 5) {
                    return Err(order(
                        m.ifd,
                        format!("{} (an overview's mask) where the full-resolution image has no mask", m.subfile),
                        "an overview's mask (5) only beside a mask of the full-resolution image (4)",
                    ));
                }
            }
        }
        let masked = level0.mask.is_some();
        let mut levels = vec![Level::Ifd(level0)];
        let mut why = String::from("it has no overviews");
        for image in images.iter().skip(1) {
            if image.subfile & 4 != 0 || image.subfile & 1 == 0 {
                continue; // a mask or another page
            }
            let k = levels.len() as u32;
            let (f, level) = image_level(path, head, layout, image)?;
            if f != format {
                let full = match &levels[0] {
                    Level::Ifd(l) => l,
                    Level::Built => unreachable!("level 0 is an image"),
                };
                let (tag, found, expected) = if level.samples != full.samples {
                    ("BitsPerSample (258) / SampleFormat (339)", level.samples.describe(), full.samples.describe())
                } else {
                    ("SamplesPerPixel (277)", level.spp.to_string(), full.spp.to_string())
                };
                return Err(CogError::Overview {
                    path: path.to_path_buf(),
                    ifd: image.ifd,
                    tag,
                    found: format!("{found} ({f})"),
                    expected: format!("{expected} ({format})"),
                });
            }
            let expected = level_size(size, k);
            if levels.len() >= n || level.size != expected {
                why = if levels.len() >= n {
                    format!("IFD {} is an overview beyond the {n} levels of a {size:?} texture", image.ifd)
                } else {
                    format!(
                        "IFD {} (overview {k}) is {:?} texels, expected {expected:?} (level 0's halved and rounded down); it and the overviews after it are not used",
                        image.ifd, level.size
                    )
                };
                break;
            }
            let mut level = level;
            if masked {
                let Some(m) = overview_masks.next() else {
                    why = format!(
                        "IFD {} (overview {k}) has no mask (NewSubfileType 5) where the full-resolution image has one; it and the overviews after it are not used",
                        image.ifd
                    );
                    break;
                };
                level.mask = Some(mask_level(path, head, layout, m, &level)?);
            }
            levels.push(Level::Ifd(level));
            why = String::from("it has no smaller overviews");
        }
        let used = levels.len();
        if used < n {
            let base = used as u32 - 1;
            let base_size = level_size(size, base);
            if build && base_size[0] * base_size[1] > MAX_BUILT_TEXELS {
                return Err(CogError::TooLargeToBuild {
                    path: path.to_path_buf(),
                    why,
                    from: used as u32,
                    last: n as u32 - 1,
                    base,
                    base_size,
                });
            }
        }
        let mut origins = Vec::with_capacity(n);
        let mut descs = Vec::with_capacity(n);
        let mut last_tile = [1, 1];
        for k in 0..n as u32 {
            let ls = level_size(size, k);
            let origin = match levels.get(k as usize) {
                Some(Level::Ifd(l)) => {
                    last_tile = l.tile;
                    LevelOrigin::Ifd {
                        ifd: l.ifd,
                        tile: l.tile,
                        compression: l.compression,
                        predictor: l.predictor != 1,
                        predictor_tag: l.predictor,
                    }
                }
                _ => LevelOrigin::Built { from: used as u32 - 1 },
            };
            let stack = ls[0] > clip_size || ls[1] > clip_size;
            let tile = if stack { [last_tile[0].min(ls[0]), last_tile[1].min(ls[1])] } else { ls };
            descs.push(LevelDesc { size: ls, tile });
            origins.push(origin);
        }
        levels.resize(n, Level::Built);
        let desc_err = |source| CogError::Desc { path: path.to_path_buf(), source };
        let desc = TextureDesc::from_levels(size, clip_size, format, descs).map_err(desc_err)?;
        let border = (clip_size / 32).clamp(1, 16).min(clip_size.saturating_sub(1) / 2);
        let desc = desc.with_invalid_border(border).map_err(desc_err)?;
        let built_because = (used < n).then_some(why);
        Ok((desc, levels, origins, built_because))
    }

    /// The levels past the last usable image, built from it the first time they are asked for
    /// (by `tile`, or at open when `None`); a failure is not kept, the next read tries again.
    fn built_levels(&self, tile: Option<TileId>) -> Result<Arc<Vec<Vec<u8>>>, SourceError> {
        let mut slot = self.built.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(b) = &*slot {
            return Ok(Arc::clone(b));
        }
        let n = self.desc.level_count();
        let used = self.levels.iter().filter(|l| matches!(l, Level::Ifd(_))).count();
        let mut out = Vec::new();
        if used < n {
            let base = used as u32 - 1;
            let bpt = self.desc.bytes_per_texel();
            let Some(Level::Ifd(lv)) = self.levels.get(used - 1) else { return Ok(Arc::new(out)) };
            let mut size = lv.size;
            let mut texels = vec![0u8; (size[0] * size[1]) as usize * bpt];
            let whole = tile.unwrap_or(TileId::new(base, 0, 0));
            self.fill_region(lv, whole, [0, 0], size, &mut texels, size[0] as usize, true)?;
            for _ in used..n {
                let (next, next_size) = self.halve(out.last().unwrap_or(&texels), size);
                out.push(next);
                size = next_size;
            }
        }
        let b = Arc::new(out);
        *slot = Some(Arc::clone(&b));
        Ok(b)
    }

    /// The next coarser level of `src` (`size` texels, rows in increasing t): heights by the
    /// `mean` rule with nodata left out (docs/ELEVATION.md), colours by `clipprep`'s 2 x 2 box
    /// filter on each sample.
    fn halve(&self, src: &[u8], size: [u64; 2]) -> (Vec<u8>, [u64; 2]) {
        let Some(plan) = &self.heights else {
            let sample = if self.desc.format().ctype == crate::texel::ComponentType::U16 { 2 } else { 1 };
            return halve(src, size, self.desc.bytes_per_texel(), sample);
        };
        let f = plan.format;
        let n = f.bytes_per_texel();
        let stored: Vec<f64> = src.chunks_exact(n).map(|b| f.read(b)).collect();
        let [w, h] = [size[0] as usize, size[1] as usize];
        let next = f.reduce_level(plan.levels, &stored, w, h).unwrap_or_default();
        let mut out = vec![0u8; next.len() * n];
        for (v, o) in next.iter().zip(out.chunks_exact_mut(n)) {
            f.write(*v, o);
        }
        (out, [(w / 2).max(1) as u64, (h / 2).max(1) as u64])
    }

    /// Fills `texels` as GDAL reads a sparse tile: nodata heights, or zeros.
    fn blank(&self, texels: &mut [u8]) {
        match self.heights.and_then(|p| p.format.nodata().map(|v| (p.format, v))) {
            Some((f, v)) => {
                for t in texels.chunks_exact_mut(f.bytes_per_texel()) {
                    f.write(v, t);
                }
            }
            None => texels.fill(0),
        }
    }

    /// One value of a tile index.
    fn index_value(&self, a: &Array, i: u64, tile: TileId) -> Result<u64, SourceError> {
        if i >= a.count {
            let problem = format!("the tile index has {} entries, tile {i} asked for", a.count);
            return Err(SourceError::Chunk { tile, path: self.path.clone(), problem });
        }
        if let Some(b) = a.inline {
            let at = (i * a.size) as usize;
            return Ok(self.layout.value(a.ty, &b[at..]));
        }
        let at = a.at.saturating_add(i * a.size);
        if let Some(b) = (Span { start: 0, bytes: &self.prefix }).get(at, a.size) {
            return Ok(self.layout.value(a.ty, b));
        }
        let past_end = |len: u64| SourceError::Chunk {
            tile,
            path: self.path.clone(),
            problem: format!("its tile index entry at byte {at} lies past the end of the file ({len} bytes)"),
        };
        if self.chunked {
            let (chunk, from) = self.index_chunk(a, i, tile)?;
            return Ok(self.layout.value(a.ty, &chunk[from..from + a.size as usize]));
        }
        let mut b = [0u8; 8];
        match self.store.read_exact_at(&mut b[..a.size as usize], at) {
            Ok(()) => Ok(self.layout.value(a.ty, &b)),
            Err(StoreError::Eof { size }) => Err(past_end(size)),
            Err(e) => Err(e.for_tile(tile, &self.path, at, a.size)),
        }
    }

    /// The chunk of array `a` that holds entry `i`, read once ([`INDEX_CHUNK_BYTES`] of
    /// entries, the array's last chunk shorter), and where entry `i` starts in it.
    fn index_chunk(&self, a: &Array, i: u64, tile: TileId) -> Result<(Shared, usize), SourceError> {
        let per = (INDEX_CHUNK_BYTES / a.size).max(1);
        let j = i / per;
        let from = ((i - j * per) * a.size) as usize;
        let key = (a.at, j);
        if let Some(c) = self.index.lock().unwrap_or_else(|e| e.into_inner()).get(&key) {
            return Ok((Arc::clone(c), from));
        }
        let start = a.at.saturating_add(j * per * a.size);
        let len = ((a.count - j * per).min(per)) * a.size;
        let chunk = match self.store.read_bytes(start, len) {
            Ok(c) => c,
            Err(StoreError::Eof { size }) => {
                return Err(SourceError::Chunk {
                    tile,
                    path: self.path.clone(),
                    problem: format!(
                        "its tile index entries at bytes {start}..{} lie past the end of the file ({size} bytes)",
                        start.saturating_add(len)
                    ),
                })
            }
            Err(e) => return Err(e.for_tile(tile, &self.path, start, len)),
        };
        self.index.lock().unwrap_or_else(|e| e.into_inner()).insert(key, Arc::clone(&chunk));
        Ok((chunk, from))
    }

    /// Reads the chunks of both index arrays that hold entry `i` with one read, when neither is
    /// read yet and both lie within [`MAX_INDEX_READ`] bytes (GDAL writes an image's
    /// TileByteCounts right after its TileOffsets): a tile's index then costs one request, and
    /// every chunk of either array inside that read is kept.
    fn index_pair(&self, lv: &IfdLevel, i: u64, tile: TileId) -> Result<(), SourceError> {
        let (a, b) = (&lv.offsets, &lv.counts);
        if a.inline.is_some() || b.inline.is_some() || i >= a.count || i >= b.count {
            return Ok(());
        }
        let per = |x: &Array| (INDEX_CHUNK_BYTES / x.size).max(1);
        // Chunk j of array x: its key, first byte and length.
        let chunk = |x: &Array, j: u64| {
            let start = x.at.saturating_add(j * per(x) * x.size);
            ((x.at, j), start, ((x.count - j * per(x)).min(per(x))) * x.size)
        };
        let ((ka, sa, la), (kb, sb, lb)) = (chunk(a, i / per(a)), chunk(b, i / per(b)));
        let prefix = Span { start: 0, bytes: &self.prefix };
        if prefix.get(sa, la).is_some() || prefix.get(sb, lb).is_some() {
            return Ok(());
        }
        // Both arrays whole when they fit in one read, else the two chunks, else nothing here.
        let end = |x: &Array| x.at.saturating_add(x.count.saturating_mul(x.size));
        let whole = (a.at.min(b.at), end(a).max(end(b)));
        let pair = (sa.min(sb), sa.saturating_add(la).max(sb.saturating_add(lb)));
        let (lo, hi) = if whole.1 - whole.0 <= MAX_INDEX_READ { whole } else { pair };
        if hi - lo > MAX_INDEX_READ {
            return Ok(());
        }
        {
            let cache = self.index.lock().unwrap_or_else(|e| e.into_inner());
            if cache.contains_key(&ka) || cache.contains_key(&kb) {
                return Ok(());
            }
        }
        let both = match self.store.read_bytes(lo, hi - lo) {
            Ok(b) => b,
            // Each chunk on its own then says what is wrong with it.
            Err(StoreError::Eof { .. }) => return Ok(()),
            Err(e) => return Err(e.for_tile(tile, &self.path, lo, hi - lo)),
        };
        let mut cache = self.index.lock().unwrap_or_else(|e| e.into_inner());
        for x in [a, b] {
            for j in 0..x.count.div_ceil(per(x)) {
                let (key, start, len) = chunk(x, j);
                if start >= lo && start.saturating_add(len) <= hi {
                    let from = (start - lo) as usize;
                    cache.entry(key).or_insert_with(|| Arc::new(both[from..from + len as usize].to_vec()));
                }
            }
        }
        Ok(())
    }

    /// Where TIFF tile `index` of `lv` is stored: its offset and byte count.
    fn tile_place(&self, lv: &IfdLevel, index: u64, tile: TileId) -> Result<(u64, u64), SourceError> {
        if self.chunked {
            self.index_pair(lv, index, tile)?;
        }
        Ok((self.index_value(&lv.offsets, index, tile)?, self.index_value(&lv.counts, index, tile)?))
    }

    /// A tile's place without its TileByteCounts entry, when reading that entry would cost a
    /// request of its own (a remote index too large to read whole, the entry's chunk not read
    /// yet) and GDAL's block leader will confirm it: an uncompressed tile holds one tile's
    /// bytes, a compressed one those up to the next tile's leader (GDAL writes a level's tiles
    /// back to back, each with its leader and trailer). [`CogSource::decode`] reads the entry
    /// after all when the leader disagrees.
    fn guessed_place(&self, lv: &IfdLevel, index: u64, need: u64, tile: TileId) -> Option<(u64, u64)> {
        let (a, c) = (&lv.offsets, &lv.counts);
        if !self.chunked || !self.ghost.leader || c.inline.is_some() || a.inline.is_some() {
            return None;
        }
        if (Span { start: 0, bytes: &self.prefix }).get(c.at.saturating_add(index * c.size), c.size).is_some() {
            return None;
        }
        self.index_pair(lv, index, tile).ok()?;
        let per = |x: &Array| (INDEX_CHUNK_BYTES / x.size).max(1);
        if self.index.lock().unwrap_or_else(|e| e.into_inner()).contains_key(&(c.at, index / per(c))) {
            return None;
        }
        let offset = self.index_value(a, index, tile).ok()?;
        if offset < 4 {
            return None;
        }
        if lv.compression == Compression::None {
            return Some((offset, need));
        }
        // The next entry, when it is in the same chunk of TileOffsets (no other request).
        if index + 1 >= a.count || (index + 1) / per(a) != index / per(a) {
            return None;
        }
        let next = self.index_value(a, index + 1, tile).ok()?;
        let trail = if self.ghost.trailer { 4 } else { 0 };
        let count = next.checked_sub(offset)?.checked_sub(4 + trail)?;
        (count >= 4).then_some((offset, count))
    }

    /// The most bytes a merged request reads ahead (the remote options' `merge_bytes`, at most
    /// [`MAX_SPAN_BYTES`]); 0 for a local file, which reads nothing ahead.
    fn ahead_cap(&self) -> u64 {
        match &self.store {
            #[cfg(feature = "remote")]
            Store::Remote(o) => o.remote().fetcher().options().merge_bytes.min(MAX_SPAN_BYTES),
            _ => 0,
        }
    }

    /// The bytes a read of TIFF tile `index` of `lv` fetches (framing included), when they are
    /// to be fetched: `None` for a sparse tile, one in the first bytes, or one whose place cannot
    /// be had.
    fn stored_range(&self, lv: &IfdLevel, index: u64, need: u64, tile: TileId) -> Option<(u64, u64)> {
        let (offset, count) = self.tile_place(lv, index, tile).ok()?;
        if offset == 0 || count == 0 {
            return None;
        }
        let (from, len) = match lv.compression {
            Compression::None if count < need => return None,
            Compression::None if count != need => (offset, need),
            _ => {
                let (lead, trail) = self.framing(offset, count);
                (offset - lead, lead.saturating_add(count).saturating_add(trail))
            }
        };
        if (Span { start: 0, bytes: &self.prefix }).get(from, len).is_some() {
            return None;
        }
        Some((from, len))
    }

    /// The bytes of a request that holds TIFF tile `index` of `lv` (texture tile `tile`) and the
    /// announced tiles stored next to it (docs/COG.md, "The request budget of a remote COG"),
    /// from the byte they start at; `None` when the tile is to be read on its own.
    fn read_ahead(
        &self,
        lv: &IfdLevel,
        tile: TileId,
        index: u64,
        need: u64,
    ) -> Result<Option<(u64, Shared)>, SourceError> {
        let cap = self.ahead_cap();
        let (rows, across) = (lv.rows(), lv.across);
        let tiles = rows * across;
        if cap == 0 || index >= tiles {
            return Ok(None);
        }
        let id = |j: u64| TileId { level: tile.level, s: j % across, t: rows - 1 - j / across };
        let near: Vec<TileId> =
            (index.saturating_sub(AHEAD_WINDOW)..=(index + AHEAD_WINDOW).min(tiles - 1)).map(id).collect();
        let place = |k: &TileId| {
            let j = (rows - 1 - k.t) * across + k.s;
            self.stored_range(lv, j, need, *k).map(|(start, len)| Piece { key: *k, start, len })
        };
        match self.ahead.plan(tile, &near, place, cap) {
            Plan::Alone => Ok(None),
            Plan::Take { start, bytes } => Ok(bytes.map(|b| (start, b))),
            Plan::Send { start, end, merged, ticket } => {
                #[cfg(feature = "remote")]
                if let Store::Remote(o) = &self.store {
                    use std::sync::atomic::Ordering;
                    let ranges = merged.len() as u64 + 1;
                    o.remote().fetcher().counters.merged.fetch_add(ranges, Ordering::Relaxed);
                }
                #[cfg(not(feature = "remote"))]
                let _ = merged;
                let mut started = Ok(());
                // This tile's own bytes, once whole (`None`: read it on its own).
                let own = ticket.detach(|feed| started = self.store.stream_detached(start, end - start, feed));
                match started {
                    // A tile whose place runs past the end: each tile then says what is wrong
                    // with it.
                    Err(StoreError::Eof { .. }) => Ok(None),
                    Err(e) => Err(e.for_tile(tile, &self.path, start, end - start)),
                    Ok(()) => Ok(own),
                }
            }
        }
    }

    /// Whether texture tiles of `level` are read one TIFF tile each (and so may be read ahead).
    fn one_tiff_tile_each(&self, level: u32) -> Option<&IfdLevel> {
        let d = self.desc.level(level);
        match self.levels.get(level as usize)? {
            Level::Ifd(lv) if lv.tile == d.tile && lv.size[1] % lv.tile[1] == 0 => Some(lv),
            _ => None,
        }
    }

    /// The bytes framing a tile of `count` bytes at `offset`: GDAL's leader before it and
    /// trailer after it, when the ghost area says they are there.
    fn framing(&self, offset: u64, count: u64) -> (u64, u64) {
        let lead = if self.ghost.leader && offset >= 4 { 4 } else { 0 };
        let trail = if self.ghost.trailer && count >= 4 { 4 } else { 0 };
        (lead, trail)
    }

    /// Decodes TIFF tile `index` of `lv` into `dst` (one whole TIFF tile, rows top-down as
    /// stored), undoing the predictor; its stored bytes come from `span` when it holds them.
    fn decode(
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
    fn decode_at(
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
        let local = !self.store.is_remote();
        if lv.compression == Compression::None && local && span.is_none() && prefix.get(offset, need).is_none() {
            // Straight into the slot: no copy on the local path.
            self.store.read_exact_at(dst, offset).map_err(|e| e.for_tile(tile, &self.path, offset, need))?;
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
                        let size = self.store.size();
                        if from.checked_add(len).is_none_or(|end| end > size) {
                            return Err(StoreError::Eof { size }.for_tile(tile, &self.path, from, len));
                        }
                        buf.resize(len as usize, 0);
                        self.store
                            .read_exact_at(&mut buf, from)
                            .map_err(|e| e.for_tile(tile, &self.path, from, len))?;
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
    fn decode_texels(
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
    fn mask_tile(&self, m: &MaskLevel, index: u64, tile: TileId, out: &mut Vec<u8>) -> Result<(), SourceError> {
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

    /// The stored bytes of TIFF tiles `cx0..=cx1` of tile row `cy` in one read, when they lie
    /// back to back (GDAL writes a row's tiles so) and are not all in the first bytes: a remote
    /// object's one ranged GET instead of one a tile. `None` when they do not, or locally.
    fn row_span(
        &self,
        lv: &IfdLevel,
        cy: u64,
        [cx0, cx1]: [u64; 2],
        tile: TileId,
    ) -> Result<Option<(u64, Shared)>, SourceError> {
        if !self.store.is_remote() || cx1 <= cx0 {
            return Ok(None);
        }
        let mut start = None;
        let mut end = 0u64;
        for cx in cx0..=cx1 {
            let (offset, count) = self.tile_place(lv, cy * lv.across + cx, tile)?;
            if offset == 0 || count == 0 {
                return Ok(None);
            }
            let (lead, trail) = self.framing(offset, count);
            let from = offset - lead;
            match start {
                None => start = Some(from),
                Some(_) if from != end => return Ok(None),
                Some(_) => {}
            }
            end = offset.saturating_add(count).saturating_add(trail);
        }
        let Some(start) = start else { return Ok(None) };
        if end - start > MAX_SPAN_BYTES || (Span { start: 0, bytes: &self.prefix }).get(start, end - start).is_some() {
            return Ok(None);
        }
        match self.store.read_bytes(start, end - start) {
            Ok(b) => Ok(Some((start, b))),
            Err(e) => Err(e.for_tile(tile, &self.path, start, end - start)),
        }
    }

    /// Fills the `w x h` texels from `(s0, t0)` of level `lv` into `out` (rows in increasing t,
    /// `stride` texels apart), from every TIFF tile they touch; texels of `out` outside the region
    /// are left alone. A sparse TIFF tile is [`SourceError::Missing`], or zeros with
    /// `sparse_zero`.
    #[allow(clippy::too_many_arguments)]
    fn fill_region(
        &self,
        lv: &IfdLevel,
        tile: TileId,
        [s0, t0]: [u64; 2],
        [w, h]: [u64; 2],
        out: &mut [u8],
        stride: usize,
        sparse_zero: bool,
    ) -> Result<(), SourceError> {
        let bpt = self.desc.bytes_per_texel();
        let [tw, th] = lv.tile;
        let height = lv.size[1];
        // Image rows y_lo..=y_hi (top-down) hold texture rows t0 + h - 1 down to t0.
        let (y_lo, y_hi) = (height - (t0 + h), height - 1 - t0);
        let chunk_bytes = (tw * th) as usize * bpt;
        let mut chunk = CHUNK.with(|cell| std::mem::take(&mut *cell.borrow_mut()));
        chunk.resize(chunk_bytes, 0);
        let result = (|| {
            for cy in y_lo / th..=y_hi / th {
                let (cx0, cx1) = (s0 / tw, (s0 + w - 1) / tw);
                let row = self.row_span(lv, cy, [cx0, cx1], tile)?;
                let span = row.as_ref().map(|(start, b)| Span { start: *start, bytes: b });
                for cx in cx0..=cx1 {
                    match self.decode_texels(lv, cy * lv.across + cx, tile, &mut chunk, span.as_ref()) {
                        Ok(()) => {}
                        Err(SourceError::Missing { .. }) if sparse_zero => self.blank(&mut chunk),
                        Err(e) => return Err(e),
                    }
                    let (xa, xb) = (s0.max(cx * tw), (s0 + w).min((cx + 1) * tw));
                    let len = (xb - xa) as usize * bpt;
                    for y in y_lo.max(cy * th)..=y_hi.min((cy + 1) * th - 1) {
                        let r = (height - 1 - y - t0) as usize;
                        let from = (((y - cy * th) * tw + xa - cx * tw) as usize) * bpt;
                        let to = (r * stride + (xa - s0) as usize) * bpt;
                        out[to..to + len].copy_from_slice(&chunk[from..from + len]);
                    }
                }
            }
            Ok(())
        })();
        keep(&CHUNK, chunk);
        result
    }
}

/// Reads up to `buf.len()` bytes from the start of `file`; returns how many there were.
fn read_prefix(file: &File, buf: &mut [u8]) -> io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match file.read_at(&mut buf[got..], got as u64) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}

/// Reads the IFD chain from `first`: every IFD's entries, none of the arrays they point to.
fn read_ifds(file: &Head, layout: Layout, first: u64) -> Result<Vec<Image>, (String, String)> {
    let mut images = Vec::new();
    let mut next = first;
    let mut seen = std::collections::HashSet::new();
    let mut read_total = 0u64;
    while next != 0 {
        let ifd = images.len();
        let at = format!("IFD {ifd} at byte {next}");
        if ifd >= MAX_IFDS {
            return Err((at, format!("the chain has more than {MAX_IFDS} IFDs")));
        }
        if !seen.insert(next) {
            return Err((at, "the IFD chain loops back to an IFD already read".into()));
        }
        let count_size = if layout.big { 8 } else { 2 };
        let head = file.read_at(next, count_size, &at)?;
        let count = if layout.big { layout.u64(&head) } else { layout.u16(&head) as u64 };
        if count == 0 || count > MAX_ENTRIES {
            return Err((at, format!("{count} entries, expected 1 to {MAX_ENTRIES}")));
        }
        let entry_size = if layout.big { 20 } else { 12 };
        let len = count * entry_size + layout.field() as u64;
        read_total += len;
        if read_total > MAX_STRUCTURE_BYTES {
            return Err((at, format!("the IFDs take more than {MAX_STRUCTURE_BYTES} bytes")));
        }
        let body = file.read_at(next + count_size as u64, len as usize, &at)?;
        let mut entries = Vec::with_capacity(count as usize);
        for e in body.chunks_exact(entry_size as usize).take(count as usize) {
            let tag = layout.u16(&e[0..]);
            let ty = layout.u16(&e[2..]);
            let (count, value) =
                if layout.big { (layout.u64(&e[4..]), &e[12..20]) } else { (layout.u32(&e[4..]) as u64, &e[8..12]) };
            let mut field = [0u8; 8];
            field[..value.len()].copy_from_slice(value);
            entries.push(Entry { tag, ty, count, field });
        }
        let mut image = Image { ifd, subfile: 0, entries };
        image.subfile = scalar(file, layout, &image, 254, "NewSubfileType (254)")?.unwrap_or(0);
        images.push(image);
        next = layout.offset(&body[(count * entry_size) as usize..]);
    }
    if images.is_empty() {
        return Err(("the header".into(), "it names no IFD (offset 0)".into()));
    }
    Ok(images)
}

/// The unsigned values of tag `tag` (at most `max` of them), `None` when the IFD lacks it.
fn values(
    file: &Head,
    layout: Layout,
    image: &Image,
    tag: u16,
    name: &str,
    max: u64,
) -> Result<Option<Vec<u64>>, (String, String)> {
    let Some(e) = image.entries.iter().find(|e| e.tag == tag) else { return Ok(None) };
    let at = format!("IFD {} tag {name}", image.ifd);
    let Some(size) = unsigned_size(e.ty) else {
        return Err((at, format!("type {} found, expected an unsigned integer type", e.ty)));
    };
    if e.count == 0 || e.count > max {
        return Err((at, format!("{} values, expected 1 to {max}", e.count)));
    }
    let bytes = if e.count * size <= layout.field() as u64 {
        e.field[..(e.count * size) as usize].to_vec()
    } else {
        file.read_at(layout.offset(&e.field), (e.count * size) as usize, &at)?
    };
    Ok(Some(bytes.chunks_exact(size as usize).map(|b| layout.value(e.ty, b)).collect()))
}

/// The text of ASCII tag `tag` (at most `max` bytes, without its closing NUL), `None` when the
/// IFD lacks it.
fn ascii(
    file: &Head,
    layout: Layout,
    image: &Image,
    tag: u16,
    name: &str,
    max: u64,
) -> Result<Option<String>, (String, String)> {
    let Some(bytes) = raw_bytes(file, layout, image, tag, name, &[2], max)? else { return Ok(None) };
    let text = bytes.split(|&b| b == 0).next().unwrap_or_default();
    match std::str::from_utf8(text) {
        Ok(t) => Ok(Some(t.trim().to_string())),
        Err(_) => Err((format!("IFD {} tag {name}", image.ifd), format!("bytes {text:02x?} are not ASCII text"))),
    }
}

/// The bytes of tag `tag`, of one of the byte-sized TIFF types `types` (2 ASCII, 7
/// UNDEFINED), at most `max` of them; `None` when the IFD lacks it.
fn raw_bytes(
    file: &Head,
    layout: Layout,
    image: &Image,
    tag: u16,
    name: &str,
    types: &[u16],
    max: u64,
) -> Result<Option<Vec<u8>>, (String, String)> {
    let Some(e) = image.entries.iter().find(|e| e.tag == tag) else { return Ok(None) };
    let at = format!("IFD {} tag {name}", image.ifd);
    if !types.contains(&e.ty) {
        return Err((at, format!("type {} found, expected {types:?}", e.ty)));
    }
    if e.count == 0 || e.count > max {
        return Err((at, format!("{} bytes, expected 1 to {max}", e.count)));
    }
    let bytes = if e.count <= layout.field() as u64 {
        e.field[..e.count as usize].to_vec()
    } else {
        file.read_at(layout.offset(&e.field), e.count as usize, &at)?
    };
    Ok(Some(bytes))
}

/// The nodata value of 16-bit signed heights with an internal mask and no GDAL_NODATA value:
/// the least value of the samples (GDAL's usual nodata for Int16).
pub const MASK_NODATA_I16: f64 = -32768.0;

/// The nodata value of 32-bit float heights with an internal mask and no GDAL_NODATA value (or
/// `nan`, which the heights block cannot name): the least finite 32-bit float,
/// -3.4028234663852886e38 (GDAL's usual nodata for Float32).
pub const MASK_NODATA_F32: f64 = f32::MIN as f64;

/// The nodata value of 16-bit unsigned heights (samples with a GDAL scale, offset or unit) with
/// an internal mask and no GDAL_NODATA value: the least value of the samples, 0.
pub const MASK_NODATA_U16: f64 = 0.0;

/// What GDAL's metadata (the GDAL_METADATA tag, 42112) says of the first band: its scale and
/// offset (`gdal_translate -a_scale -a_offset`, `gdal_edit.py -scale -offset`) and its unit
/// (`-a_unit`, `SetUnitType`).
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct BandMeta {
    scale: Option<f64>,
    offset: Option<f64>,
    unit: Option<String>,
}

impl BandMeta {
    /// Reads the `<Item name=... sample="0" role="scale|offset|unittype">` items of GDAL's XML; a
    /// value that is no number is refused (the text, then what it is).
    fn parse(xml: &str) -> Result<BandMeta, String> {
        let mut meta = BandMeta::default();
        for item in xml.split("<Item ").skip(1) {
            let Some((attrs, rest)) = item.split_once('>') else { continue };
            let Some((value, _)) = rest.split_once("</Item>") else { continue };
            let value = value.trim();
            let has = |a: &str| attrs.split_whitespace().any(|w| w.trim_end_matches('/') == a);
            if !has("sample=\"0\"") {
                continue;
            }
            let number = |what: &str| {
                value
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| format!("the first band's {what} is {value:?}, expected a finite number"))
            };
            if has("role=\"scale\"") {
                meta.scale = Some(number("scale")?);
            } else if has("role=\"offset\"") {
                meta.offset = Some(number("offset")?);
            } else if has("role=\"unittype\"") {
                meta.unit = Some(value.to_string());
            }
        }
        Ok(meta)
    }

    /// Whether GDAL's metadata makes 16-bit unsigned samples heights.
    fn says_heights(&self) -> bool {
        self.scale.is_some() || self.offset.is_some() || self.unit.is_some()
    }
}

/// The heights a COG's samples are (docs/ELEVATION.md): 16-bit signed integers (`l16i`) and
/// 32-bit floats (`l32f`) always, and 16-bit unsigned integers (`l16`) when GDAL's metadata
/// gives their band a scale, an offset or a unit (else they are grey); the metres of a stored
/// value are `v x scale + offset` with GDAL's scale and offset (1 and 0 when it gives none;
/// floats take none other). The GDAL_NODATA tag's value is the nodata value (a NaN nodata means
/// none: the mapping's heights block cannot name NaN, and NaN texels stay NaN); other formats
/// are colours, whose GDAL_NODATA gives an alpha instead ([`alpha_of`]). A height image with an
/// internal mask (`masked`) and no nodata value gets [`MASK_NODATA_I16`], [`MASK_NODATA_U16`] or
/// [`MASK_NODATA_F32`], served where the mask is 0.
fn heights_of(
    path: &Path,
    format: TexelFormat,
    nodata: Option<&str>,
    masked: bool,
    meta: &BandMeta,
) -> Result<Option<crate::plan::HeightPlan>, CogError> {
    use crate::height::{HeightError, HeightFormat, HeightStorage, LevelRule};
    let storage = match format {
        TexelFormat::L32F => HeightStorage::F32,
        TexelFormat::L16I => HeightStorage::I16,
        TexelFormat::L16 if meta.says_heights() => HeightStorage::U16,
        _ => return Ok(None),
    };
    let refuse = |found: String| {
        CogError::Unsupported {
        path: path.to_path_buf(),
        ifd: 0,
        tag: "GDAL_NODATA (42113)",
        found,
        supported: "a number that is a value of the samples (a whole number in -32768..32767 for 16-bit signed samples, 0..65535 for 16-bit unsigned ones, a finite 32-bit float or nan for floats)",
    }
    };
    let value = match nodata {
        None => None,
        Some(text) => match text.parse::<f64>() {
            Ok(v) if v.is_nan() => None,
            Ok(v) => Some(v),
            Err(_) => return Err(refuse(format!("{text:?}"))),
        },
    };
    let value = match (value, masked, storage) {
        (None, true, HeightStorage::I16) => Some(MASK_NODATA_I16),
        (None, true, HeightStorage::U16) => Some(MASK_NODATA_U16),
        (None, true, _) => Some(MASK_NODATA_F32),
        (v, _, _) => v,
    };
    let (scale, offset) = (meta.scale.unwrap_or(1.0), meta.offset.unwrap_or(0.0));
    let format = HeightFormat::new(storage, scale, offset, value).map_err(|e| match e {
        HeightError::Nodata { .. } => refuse(format!("{} ({e})", nodata.unwrap_or(""))),
        e => CogError::Unsupported {
            path: path.to_path_buf(),
            ifd: 0,
            tag: "GDAL_METADATA (42112)",
            found: format!("scale {scale}, offset {offset} for {storage} heights ({e})"),
            supported: "a scale above 0 and an offset for 16-bit integer heights within the metres heights may take; none (scale 1, offset 0) for 32-bit floats: write the metres themselves (gdal_translate -unscale -ot Float32)",
        },
    })?;
    Ok(Some(crate::plan::HeightPlan { format, levels: LevelRule::Mean }))
}

/// The single unsigned value of tag `tag`, `None` when the IFD lacks it.
fn scalar(file: &Head, layout: Layout, image: &Image, tag: u16, name: &str) -> Result<Option<u64>, (String, String)> {
    Ok(values(file, layout, image, tag, name, 1)?.map(|v| v[0]))
}

/// The tile index array of tag `tag`, without reading it.
fn array(layout: Layout, image: &Image, tag: u16, name: &str, count: u64) -> Result<Array, (String, String)> {
    let at = format!("IFD {} tag {name}", image.ifd);
    let Some(e) = image.entries.iter().find(|e| e.tag == tag) else {
        return Err((at, "missing, required in a tiled image".into()));
    };
    let size = match e.ty {
        3 | 4 | 16 => unsigned_size(e.ty).unwrap_or(8),
        ty => return Err((at, format!("type {ty} found, expected SHORT (3), LONG (4) or LONG8 (16)"))),
    };
    if e.count != count {
        return Err((at, format!("{} values, expected {count} (one per tile)", e.count)));
    }
    let inline = (count * size <= layout.field() as u64).then_some(e.field);
    Ok(Array { ty: e.ty, size, count, inline, at: layout.offset(&e.field) })
}

/// Checks one image's layout and describes it as a level: its texel format and tiles.
fn image_level(path: &Path, file: &Head, layout: Layout, image: &Image) -> Result<(TexelFormat, IfdLevel), CogError> {
    let malformed = |(at, problem): (String, String)| CogError::Malformed { path: path.to_path_buf(), at, problem };
    let unsupported = |tag, found: String, supported| CogError::Unsupported {
        path: path.to_path_buf(),
        ifd: image.ifd,
        tag,
        found,
        supported,
    };
    let get = |tag: u16, name: &str| scalar(file, layout, image, tag, name).map_err(malformed);
    let required = |tag: u16, name: &str| {
        get(tag, name)?.ok_or_else(|| malformed((format!("IFD {} tag {name}", image.ifd), "missing".into())))
    };
    let width = required(256, "ImageWidth (256)")?;
    let height = required(257, "ImageLength (257)")?;
    let (Some(tw), Some(th)) = (get(322, "TileWidth (322)")?, get(323, "TileLength (323)")?) else {
        return Err(unsupported(
            "TileWidth (322)",
            "absent: the image is stored in strips".into(),
            "tiled images (gdal_translate -of COG, or -co TILED=YES)",
        ));
    };
    if width == 0 || height == 0 || tw == 0 || th == 0 {
        return Err(malformed((
            format!("IFD {}", image.ifd),
            format!("image {width} x {height} in tiles of {tw} x {th}: every size must be at least 1"),
        )));
    }
    if width > super::MAX_TEXTURE_SIZE || height > super::MAX_TEXTURE_SIZE {
        return Err(unsupported(
            "ImageWidth (256) x ImageLength (257)",
            format!("{width} x {height}"),
            "at most 2^26 (MAX_TEXTURE_SIZE) texels a side",
        ));
    }
    let spp = get(277, "SamplesPerPixel (277)")?.unwrap_or(1);
    if !matches!(spp, 1 | 3 | 4) {
        return Err(unsupported("SamplesPerPixel (277)", spp.to_string(), "1 (grey), 3 (RGB) or 4 (RGBA)"));
    }
    let list = |tag: u16, name: &str| values(file, layout, image, tag, name, 16).map_err(malformed);
    let bits = list(258, "BitsPerSample (258)")?.unwrap_or(vec![1]);
    let sample_format = list(339, "SampleFormat (339)")?.unwrap_or(vec![1]);
    let same = |v: &[u64]| v.iter().all(|&x| x == v[0]);
    let samples = match (bits[0], sample_format[0]) {
        _ if !same(&bits) || !same(&sample_format) => None,
        (8, 1) => Some(Samples::U8),
        (16, 1) => Some(Samples::U16),
        (16, 2) => Some(Samples::I16),
        (32, 3) => Some(Samples::F32),
        _ => None,
    };
    let Some(samples) = samples else {
        return Err(unsupported(
            "BitsPerSample (258) / SampleFormat (339)",
            format!("{bits:?} bits, sample format {sample_format:?}"),
            "the same for every sample: 8 or 16 bits unsigned (format 1), 16 bits signed (format 2) or 32-bit floats (format 3)",
        ));
    };
    let format = match (samples, spp) {
        (Samples::U8, 1) => TexelFormat::L8,
        (Samples::U8, 3) => TexelFormat::RGB8,
        (Samples::U8, _) => TexelFormat::RGBA8,
        (Samples::U16, 1) => TexelFormat::L16,
        (Samples::U16, 3) => TexelFormat::RGB16,
        (Samples::U16, _) => TexelFormat::RGBA16,
        (Samples::I16, 1) => TexelFormat::L16I,
        (Samples::F32, 1) => TexelFormat::L32F,
        (_, n) => {
            return Err(unsupported(
                "SamplesPerPixel (277)",
                n.to_string(),
                "1 with 16-bit signed or 32-bit float samples (heights: l16i, l32f)",
            ))
        }
    };
    let planar = get(284, "PlanarConfiguration (284)")?.unwrap_or(1);
    if planar != 1 && spp > 1 {
        return Err(unsupported(
            "PlanarConfiguration (284)",
            format!("{planar} (separate planes)"),
            "1 (chunky: samples of a pixel together; gdal_translate -co INTERLEAVE=PIXEL)",
        ));
    }
    let compression = match get(259, "Compression (259)")?.unwrap_or(1) {
        1 => Compression::None,
        5 => Compression::Lzw,
        7 => Compression::Jpeg,
        8 | 32946 => Compression::Deflate,
        50000 => Compression::Zstd,
        c => {
            let name = match c {
                6 => " (old-style JPEG)",
                32773 => " (PackBits)",
                34887 => " (LERC)",
                34925 => " (LZMA)",
                50001 => " (WebP)",
                _ => "",
            };
            return Err(unsupported(
                "Compression (259)",
                format!("{c}{name}"),
                "1 (none), 5 (LZW), 7 (JPEG), 8 or 32946 (DEFLATE), 50000 (ZSTD)",
            ));
        }
    };
    let photometric = get(262, "PhotometricInterpretation (262)")?;
    let jpeg = compression == Compression::Jpeg;
    let ok_photometric = match (spp, jpeg) {
        (1, _) => photometric.unwrap_or(1) == 1,
        (3, true) => matches!(photometric, Some(2 | 6)),
        (_, true) => photometric == Some(2),
        _ => photometric == Some(2),
    };
    if !ok_photometric {
        return Err(unsupported(
            "PhotometricInterpretation (262)",
            format!(
                "{}{}",
                photometric.map_or("absent".into(), |p| p.to_string()),
                if jpeg { format!(" with {spp} JPEG-compressed samples") } else { String::new() }
            ),
            if jpeg {
                "1 (grey) with 1 sample; 6 (YCbCr: gdal_translate -of COG -co COMPRESS=JPEG, or -co PHOTOMETRIC=YCBCR) with 3; 2 (RGB, no colour transform: gdal_translate -of GTiff -co TILED=YES -co COMPRESS=JPEG -co PHOTOMETRIC=RGB) with 3, or with 4 (RGBA: what the GTiff driver writes for 4 bands)"
            } else {
                "1 (grey, zero is black) with 1 sample, 2 (RGB) with 3 or 4"
            },
        ));
    }
    if jpeg && samples != Samples::U8 {
        return Err(unsupported(
            "BitsPerSample (258) / SampleFormat (339)",
            format!("{bits:?} bits, sample format {sample_format:?} with JPEG"),
            "8-bit samples with JPEG (7)",
        ));
    }
    let jpeg_tables = match jpeg {
        true => raw_bytes(file, layout, image, 347, "JPEGTables (347)", &[7], MAX_JPEG_TABLES)
            .map_err(malformed)?
            .map(Arc::from),
        false => None,
    };
    let predictor = match get(317, "Predictor (317)")?.unwrap_or(1) {
        _ if jpeg => 1,
        p @ (1 | 2) => p as u16,
        3 if samples == Samples::F32 => 3,
        p => {
            return Err(unsupported(
                "Predictor (317)",
                format!("{p} with {} samples", format),
                "1 (none), 2 (horizontal differencing), or 3 (floating point) with 32-bit float samples",
            ))
        }
    };
    let tile_bytes = tw.saturating_mul(th).saturating_mul(spp).saturating_mul(samples.bytes() as u64);
    if tile_bytes > crate::limits::MAX_TILE_BYTES {
        return Err(unsupported(
            "TileWidth (322) x TileLength (323)",
            format!("{tw} x {th} ({tile_bytes} bytes a tile)"),
            "tiles of at most MAX_TILE_BYTES (268435456) bytes: write smaller tiles (gdal_translate -co BLOCKSIZE=512, or -co BLOCKXSIZE= -co BLOCKYSIZE=)",
        ));
    }
    let across = width.div_ceil(tw);
    let tiles = across * height.div_ceil(th);
    let offsets = array(layout, image, 324, "TileOffsets (324)", tiles).map_err(malformed)?;
    let counts = array(layout, image, 325, "TileByteCounts (325)", tiles).map_err(malformed)?;
    index_in_file(file, image, &offsets, &counts, [width, height], [tw, th]).map_err(malformed)?;
    let level = IfdLevel {
        ifd: image.ifd,
        size: [width, height],
        tile: [tw, th],
        across,
        compression,
        predictor,
        jpeg_tables,
        jpeg_colour: if jpeg && photometric == Some(6) { JpegColour::YCbCr } else { JpegColour::Raw },
        samples,
        spp: spp as usize,
        offsets,
        counts,
        mask: None,
    };
    Ok((format, level))
}

/// Whether an image's tile index lies in the file: one past its end is a damaged or truncated
/// file, refused at open rather than every tile of the image failing on its own (an image
/// claiming 2^26 texels a side in a few kilobytes would have billions of tiles to try).
fn index_in_file(
    file: &Head,
    image: &Image,
    offsets: &Array,
    counts: &Array,
    [width, height]: [u64; 2],
    [tw, th]: [u64; 2],
) -> Result<(), (String, String)> {
    let size = file.store.size();
    for (a, name) in [(offsets, "TileOffsets (324)"), (counts, "TileByteCounts (325)")] {
        let bytes = a.count.saturating_mul(a.size);
        if a.inline.is_none() && a.at.checked_add(bytes).is_none_or(|end| end > size) {
            return Err((
                format!("IFD {} tag {name}", image.ifd),
                format!(
                    "its {} values ({bytes} bytes, one per tile of a {width} x {height} image in tiles of {tw} x {th}) at byte {} run past the end of the file ({size} bytes)",
                    a.count, a.at
                ),
            ));
        }
    }
    Ok(())
}

/// The internal mask in IFD `image` of the image `of` (IFD `of.ifd`): one 1- or 8-bit unsigned
/// sample, the image's size and tiling; anything else is refused naming the tag, the value found
/// and what is expected.
fn mask_level(
    path: &Path,
    file: &Head,
    layout: Layout,
    image: &Image,
    of: &IfdLevel,
) -> Result<Arc<MaskLevel>, CogError> {
    let malformed = |(at, problem): (String, String)| CogError::Malformed { path: path.to_path_buf(), at, problem };
    let refuse = |tag, found: String, expected: String| CogError::Mask {
        path: path.to_path_buf(),
        ifd: image.ifd,
        image: Some(of.ifd),
        tag,
        found,
        expected,
    };
    let get = |tag: u16, name: &str| scalar(file, layout, image, tag, name).map_err(malformed);
    let shown = |v: Option<u64>| v.map_or("absent".to_string(), |v| v.to_string());
    let (w, h) = (get(256, "ImageWidth (256)")?, get(257, "ImageLength (257)")?);
    if (w, h) != (Some(of.size[0]), Some(of.size[1])) {
        return Err(refuse(
            "ImageWidth (256) x ImageLength (257)",
            format!("{} x {}", shown(w), shown(h)),
            format!("{} x {} (its image's)", of.size[0], of.size[1]),
        ));
    }
    let (tw, th) = (get(322, "TileWidth (322)")?, get(323, "TileLength (323)")?);
    if (tw, th) != (Some(of.tile[0]), Some(of.tile[1])) {
        return Err(refuse(
            "TileWidth (322) x TileLength (323)",
            format!("{} x {}", shown(tw), shown(th)),
            format!("{} x {} (its image's tiles)", of.tile[0], of.tile[1]),
        ));
    }
    let spp = get(277, "SamplesPerPixel (277)")?.unwrap_or(1);
    if spp != 1 {
        return Err(refuse("SamplesPerPixel (277)", spp.to_string(), "1".into()));
    }
    let bits = get(258, "BitsPerSample (258)")?.unwrap_or(1);
    let sample_format = get(339, "SampleFormat (339)")?.unwrap_or(1);
    if !matches!(bits, 1 | 8) || sample_format != 1 {
        return Err(refuse(
            "BitsPerSample (258) / SampleFormat (339)",
            format!("{bits} bits, sample format {sample_format}"),
            "1 or 8 bits, unsigned (format 1)".into(),
        ));
    }
    let photometric = get(262, "PhotometricInterpretation (262)")?;
    if !matches!(photometric, None | Some(1) | Some(4)) {
        return Err(refuse(
            "PhotometricInterpretation (262)",
            shown(photometric),
            "4 (transparency mask, what GDAL writes) or 1".into(),
        ));
    }
    let fill_order = get(266, "FillOrder (266)")?.unwrap_or(1);
    if fill_order != 1 {
        return Err(refuse(
            "FillOrder (266)",
            fill_order.to_string(),
            "1 (the first pixel in the most significant bit)".into(),
        ));
    }
    let compression = match get(259, "Compression (259)")?.unwrap_or(1) {
        1 => Compression::None,
        5 => Compression::Lzw,
        8 | 32946 => Compression::Deflate,
        50000 => Compression::Zstd,
        c => {
            return Err(refuse(
                "Compression (259)",
                c.to_string(),
                "1 (none), 5 (LZW), 8 or 32946 (DEFLATE) or 50000 (ZSTD) for a mask".into(),
            ))
        }
    };
    let predictor = get(317, "Predictor (317)")?.unwrap_or(1);
    if !(predictor == 1 || predictor == 2 && bits == 8) {
        return Err(refuse(
            "Predictor (317)",
            format!("{predictor} with {bits}-bit samples"),
            "1 (none), or 2 (horizontal differencing) with 8-bit samples".into(),
        ));
    }
    let tiles = of.across * of.rows();
    let offsets = array(layout, image, 324, "TileOffsets (324)", tiles).map_err(malformed)?;
    let counts = array(layout, image, 325, "TileByteCounts (325)", tiles).map_err(malformed)?;
    index_in_file(file, image, &offsets, &counts, of.size, of.tile).map_err(malformed)?;
    let lv = IfdLevel {
        ifd: image.ifd,
        size: of.size,
        tile: of.tile,
        across: of.across,
        compression,
        predictor: predictor as u16,
        jpeg_tables: None,
        jpeg_colour: JpegColour::Raw,
        samples: Samples::U8,
        spp: 1,
        offsets,
        counts,
        mask: None,
    };
    Ok(Arc::new(MaskLevel { lv, one_bit: bits == 1 }))
}

/// The RGBA variant of a colour format (grey and RGB gain an alpha; RGBA stays).
fn rgba_of(format: TexelFormat) -> TexelFormat {
    if format.ctype == crate::texel::ComponentType::U16 {
        TexelFormat::RGBA16
    } else {
        TexelFormat::RGBA8
    }
}

/// Whether a colour image gets an alpha: when its full-resolution image has a mask, or it has a
/// GDAL_NODATA value (which must then be a value of its samples). Heights never do (their
/// nodata is the heights block's).
fn alpha_of(
    path: &Path,
    format: TexelFormat,
    nodata: Option<&str>,
    levels: &[Level],
) -> Result<Option<AlphaRule>, CogError> {
    if matches!(format, TexelFormat::L16I | TexelFormat::L32F) {
        return Ok(None);
    }
    let max = if format.ctype == crate::texel::ComponentType::U16 { 65535.0 } else { 255.0 };
    let nodata = match nodata {
        None => None,
        Some(text) => {
            match text.parse::<f64>() {
                Ok(v) if v.fract() == 0.0 && (0.0..=max).contains(&v) => Some(v as u16),
                _ => return Err(CogError::Unsupported {
                    path: path.to_path_buf(),
                    ifd: 0,
                    tag: "GDAL_NODATA (42113)",
                    found: format!("{text:?} with {format} samples"),
                    supported:
                        "a value of the samples: a whole number in 0..=255 for 8-bit samples, 0..=65535 for 16-bit ones",
                }),
            }
        }
    };
    let masked = matches!(levels.first(), Some(Level::Ifd(l)) if l.mask.is_some());
    Ok((masked || nodata.is_some()).then_some(AlphaRule { nodata }))
}

/// Widens a decoded TIFF tile's pixels (`spp` samples of `n` bytes, little-endian) to RGBA
/// texels in `dst`: grey replicated, RGB kept, the alpha full (an RGBA image's own), and 0 where
/// `mask` (one byte a pixel) is 0 or every colour sample equals `nodata`. The colour samples are
/// kept as stored, nodata or not.
fn add_alpha(stored: &[u8], spp: usize, n: usize, nodata: Option<u16>, mask: Option<&[u8]>, dst: &mut [u8]) {
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
fn mask_heights(format: crate::height::HeightFormat, mask: &[u8], dst: &mut [u8]) {
    let Some(nodata) = format.nodata() else { return };
    for (texel, &m) in dst.chunks_exact_mut(format.bytes_per_texel()).zip(mask) {
        if m == 0 {
            format.write(nodata, texel);
        }
    }
}

/// Unpacks a 1-bit mask tile (`w` pixels a row, rows padded to a byte, the first pixel in the
/// most significant bit) into one byte a pixel (0 or 255).
fn unpack_bits(packed: &[u8], w: usize, out: &mut [u8]) {
    let row = w.div_ceil(8);
    for (bits, line) in packed.chunks_exact(row).zip(out.chunks_exact_mut(w)) {
        for (x, o) in line.iter_mut().enumerate() {
            *o = if bits[x / 8] & (0x80 >> (x % 8)) != 0 { 255 } else { 0 };
        }
    }
}

/// Turns a decoded TIFF tile's samples into texels: undoes the predictor and stores multi-byte
/// samples little-endian (the texels' byte order), whatever the file's.
fn finish_samples(lv: &IfdLevel, little: bool, dst: &mut [u8]) {
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
fn decompress(
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
        Compression::Lzw => super::lzw::decode(packed, out).map_err(|e| format!("not valid LZW data ({e})")),
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
fn jpeg_tile(
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

/// The next coarser level of `src` (`size` texels, `bpt` bytes each, rows in increasing t) by
/// `clipprep`'s 2 x 2 box filter: `floor((a + b + c + d + 2) / 4)` per sample of `sample`
/// bytes (1, or 2: little-endian 16-bit), edges clamped.
fn halve(src: &[u8], size: [u64; 2], bpt: usize, sample: usize) -> (Vec<u8>, [u64; 2]) {
    let [w, h] = [size[0] as usize, size[1] as usize];
    let (w2, h2) = ((w / 2).max(1), (h / 2).max(1));
    let mut out = vec![0u8; w2 * h2 * bpt];
    for j in 0..h2 {
        let (r0, r1) = (2 * j, (2 * j + 1).min(h - 1));
        for i in 0..w2 {
            let (c0, c1) = (2 * i, (2 * i + 1).min(w - 1));
            for b in (0..bpt).step_by(sample) {
                let at = |r: usize, c: usize| {
                    let p = (r * w + c) * bpt + b;
                    if sample == 2 {
                        u16::from_le_bytes([src[p], src[p + 1]]) as u32
                    } else {
                        src[p] as u32
                    }
                };
                let v = (at(r0, c0) + at(r0, c1) + at(r1, c0) + at(r1, c1) + 2) / 4;
                out[(j * w2 + i) * bpt + b..][..sample].copy_from_slice(&v.to_le_bytes()[..sample]);
            }
        }
    }
    (out, [w2 as u64, h2 as u64])
}

impl TileSource for CogSource {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn heights(&self) -> Option<crate::plan::HeightPlan> {
        self.heights
    }

    #[cfg(feature = "remote")]
    fn remote_stats(&self) -> Option<super::remote::RemoteStats> {
        match &self.store {
            Store::Remote(o) => Some(o.remote().stats()),
            Store::Local(_) | Store::Memory(_) => None,
        }
    }

    fn will_read(&self, tiles: &[TileId]) {
        if self.ahead_cap() > 0 {
            let ours = tiles.iter().filter(|t| (t.level as usize) < self.levels.len());
            self.ahead.announce(ours.filter(|t| self.one_tiff_tile_each(t.level).is_some()).copied());
        }
    }

    fn withdraw(&self, tile: TileId) {
        self.ahead.withdraw(tile);
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        check_request(&self.desc, tile, out)?;
        let d = self.desc.level(tile.level);
        let bpt = self.desc.bytes_per_texel();
        let [tw, th] = d.tile;
        let (s0, t0) = (tile.s * tw, tile.t * th);
        let (w, h) = ((d.size[0] - s0).min(tw), (d.size[1] - t0).min(th));
        match &self.levels[tile.level as usize] {
            Level::Built => {
                let built = self.built_levels(Some(tile))?;
                let used = self.desc.level_count() - built.len();
                let texels = &built[tile.level as usize - used];
                if w < tw || h < th {
                    out.fill(0);
                }
                let (lw, len) = (d.size[0] as usize, w as usize * bpt);
                for r in 0..h as usize {
                    let from = ((t0 as usize + r) * lw + s0 as usize) * bpt;
                    out[r * tw as usize * bpt..][..len].copy_from_slice(&texels[from..from + len]);
                }
                Ok(())
            }
            Level::Ifd(lv) if lv.tile == d.tile && lv.size[1] % lv.tile[1] == 0 => {
                // One TIFF tile, decoded in place: its rows reversed, columns past the image's
                // right edge zeroed.
                let index = (lv.rows() - 1 - tile.t) * lv.across + tile.s;
                let stored = (lv.tile[0] * lv.tile[1]) * lv.pixel_bytes() as u64;
                let ahead = self.read_ahead(lv, tile, index, stored)?;
                let span = ahead.as_ref().map(|(start, b)| Span { start: *start, bytes: b });
                self.decode_texels(lv, index, tile, out, span.as_ref())?;
                let row = tw as usize * bpt;
                for r in 0..th as usize / 2 {
                    let (top, bottom) = out.split_at_mut((th as usize - 1 - r) * row);
                    top[r * row..(r + 1) * row].swap_with_slice(&mut bottom[..row]);
                }
                if w < tw {
                    for line in out.chunks_exact_mut(row) {
                        line[w as usize * bpt..].fill(0);
                    }
                }
                Ok(())
            }
            Level::Ifd(lv) => {
                if w < tw || h < th {
                    out.fill(0);
                }
                self.fill_region(lv, tile, [s0, t0], [w, h], out, tw as usize, false)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_masked_height_image_without_nodata_gets_the_least_value_of_its_samples() {
        let p = Path::new("dem.tif");
        let nodata = |format, tag, masked| {
            heights_of(p, format, tag, masked, &BandMeta::default())
                .unwrap()
                .and_then(|plan: crate::plan::HeightPlan| plan.format.nodata())
        };
        assert_eq!(nodata(TexelFormat::L16I, None, true), Some(-32768.0));
        assert_eq!(nodata(TexelFormat::L32F, None, true), Some(-3.4028234663852886e38));
        // nan names no value: a mask then takes the chosen one, without a mask there is none.
        assert_eq!(nodata(TexelFormat::L32F, Some("nan"), true), Some(MASK_NODATA_F32));
        assert_eq!(nodata(TexelFormat::L32F, Some("nan"), false), None);
        // GDAL_NODATA, masked or not, is the nodata value.
        assert_eq!(nodata(TexelFormat::L16I, Some("-9999"), true), Some(-9999.0));
        assert_eq!(nodata(TexelFormat::L16I, None, false), None);
        assert!(heights_of(p, TexelFormat::RGB8, None, true, &BandMeta::default()).unwrap().is_none());
    }

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
    fn halving_is_clipprep_box_filter_with_clamped_edges() {
        // 3 x 2 grey: the odd column is dropped, as level_size floors.
        let src = [0u8, 10, 200, 1, 3, 255];
        let (out, size) = halve(&src, [3, 2], 1, 1);
        assert_eq!(size, [1, 1]);
        assert_eq!(out, [(14 + 2) / 4]);
        // 1 x 3: the single column is its own neighbour.
        let (out, size) = halve(&[4, 8, 100], [1, 3], 1, 1);
        assert_eq!((out, size), (vec![(4 + 4 + 8 + 8 + 2) / 4], [1, 1]));
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
    /// A classic little-endian TIFF of `w x h` grey texels `(3x + 5y) & 255` in uncompressed
    /// `t x t` tiles, its tile index (LONG arrays) placed after the tiles, past the first
    /// [`PREFIX_BYTES`].
    fn synthetic_tiff(w: u32, h: u32, t: u32) -> Vec<u8> {
        let (across, down) = (w.div_ceil(t), h.div_ceil(t));
        let tiles = across * down;
        let mut f = b"II*\0".to_vec();
        f.extend(8u32.to_le_bytes());
        let entries: [(u16, u16, u32, u32); 9] = [
            (256, 4, 1, w),
            (257, 4, 1, h),
            (258, 3, 1, 8),
            (259, 3, 1, 1),
            (262, 3, 1, 1),
            (322, 4, 1, t),
            (323, 4, 1, t),
            (324, 4, tiles, 0),
            (325, 4, tiles, 0),
        ];
        let data_at = 4096u32;
        let tile_len = t * t;
        let arrays_at = data_at + tiles * tile_len;
        assert!(arrays_at as u64 > PREFIX_BYTES);
        f.extend((entries.len() as u16).to_le_bytes());
        for (tag, ty, count, value) in entries {
            let value = match tag {
                324 => arrays_at,
                325 => arrays_at + 4 * tiles,
                _ => value,
            };
            f.extend(tag.to_le_bytes());
            f.extend(ty.to_le_bytes());
            f.extend(count.to_le_bytes());
            f.extend(value.to_le_bytes());
        }
        f.extend(0u32.to_le_bytes());
        f.resize(data_at as usize, 0);
        for i in 0..tiles {
            let (cx, cy) = (i % across, i / across);
            for r in 0..t {
                for c in 0..t {
                    let (x, y) = (cx * t + c, cy * t + r);
                    f.push(if x < w && y < h { ((3 * x + 5 * y) & 255) as u8 } else { 0 });
                }
            }
        }
        for i in 0..tiles {
            f.extend((data_at + i * tile_len).to_le_bytes());
        }
        for _ in 0..tiles {
            f.extend(tile_len.to_le_bytes());
        }
        f
    }

    #[test]
    fn the_tile_index_read_in_chunks_gives_every_entry_the_eager_reader_gives() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big_index.tif");
        // 80 x 70 tiles of 8 x 8: 5600 entries a array, 22 KiB of LONGs, past the first 64 KiB.
        std::fs::write(&path, synthetic_tiff(640, 560, 8)).unwrap();
        let eager = CogSource::open(&path, 64).unwrap();
        let lazy = open_chunked(&path, 64);
        let Level::Ifd(lv) = &eager.levels[0] else { panic!("level 0 is an image") };
        for i in (0..lv.offsets.count).rev() {
            let id = TileId::new(0, 0, 0);
            assert_eq!(lazy.tile_place(lv, i, id).unwrap(), eager.tile_place(lv, i, id).unwrap(), "entry {i}");
        }
        let per = INDEX_CHUNK_BYTES / 4;
        let chunks = lv.offsets.count.div_ceil(per) as usize;
        assert_eq!(lazy.index.lock().unwrap().len(), 2 * chunks, "each chunk of both arrays read once");
        // The two arrays lie back to back (22400 bytes each, less than MAX_INDEX_READ together):
        // the first entry asked for reads them whole, every chunk kept.
        let lazy = open_chunked(&path, 64);
        lazy.tile_place(lv, 4000, TileId::new(0, 0, 0)).unwrap();
        let cache = lazy.index.lock().unwrap();
        assert_eq!(cache.len(), 2 * chunks);
        assert_eq!(cache[&(lv.counts.at, 5)].len(), (5600 - 5 * 1024) * 4, "the last chunk is short");
        drop(cache);
        // Every texel through the chunked index is the image's, bottom-up.
        let desc = lazy.desc().clone();
        let l0 = *desc.level(0);
        let mut buf = vec![0u8; desc.tile_bytes(0)];
        for tt in 0..l0.tiles()[1] {
            for ts in 0..l0.tiles()[0] {
                lazy.read_tile(TileId::new(0, ts, tt), &mut buf).unwrap();
                for (j, &v) in buf.iter().enumerate() {
                    let (s, t) = (ts * l0.tile[0] + j as u64 % l0.tile[0], tt * l0.tile[1] + j as u64 / l0.tile[0]);
                    let y = 559 - t;
                    assert_eq!(v, ((3 * s + 5 * y) & 255) as u8, "texel ({s}, {t})");
                }
            }
        }
        // An index that runs past the end of the file is refused at open, naming where (not
        // a texel, and not an error a tile, each read in vain).
        let mut cut = std::fs::read(&path).unwrap();
        cut.truncate(cut.len() - 100);
        std::fs::write(&path, &cut).unwrap();
        let e = CogSource::open(&path, 4096).unwrap_err().to_string();
        assert!(e.contains("IFD 0 tag TileByteCounts (325): its 5600 values (22400 bytes"), "{e}");
        assert!(e.contains("run past the end of the file"), "{e}");
    }

    /// `path` opened as a remote object is (structure from the first bytes, the index read in
    /// chunks, nothing built at open), over the local file.
    fn open_chunked(path: &Path, clip: u64) -> CogSource {
        let (file, _) = crate::open::regular(path).unwrap();
        let mut prefix = vec![0u8; PREFIX_BYTES as usize];
        let n = read_prefix(&file, &mut prefix).unwrap();
        prefix.truncate(n);
        let mut src = CogSource::from_store(path.to_path_buf(), Store::Local(file), prefix, clip, true).unwrap();
        src.chunked = true;
        src
    }

    #[test]
    fn the_ghost_area_says_whether_tiles_have_a_leader_and_a_trailer() {
        let area = |body: &str| {
            let mut v = b"II*\0\x08\0\0\0".to_vec();
            v.extend(format!("GDAL_STRUCTURAL_METADATA_SIZE={:06} bytes\n{body}", body.len()).bytes());
            v
        };
        let gdal = area("LAYOUT=IFDS_BEFORE_DATA\nBLOCK_ORDER=ROW_MAJOR\nBLOCK_LEADER=SIZE_AS_UINT4\nBLOCK_TRAILER=LAST_4_BYTES_REPEATED\nKNOWN_INCOMPATIBLE_EDITION=NO\n ");
        assert_eq!(Ghost::parse(&gdal, 8), Ghost { leader: true, trailer: true });
        let edited =
            area("BLOCK_LEADER=SIZE_AS_UINT4\nBLOCK_TRAILER=LAST_4_BYTES_REPEATED\nKNOWN_INCOMPATIBLE_EDITION=YES\n");
        assert_eq!(Ghost::parse(&edited, 8), Ghost::default(), "a file edited since GDAL wrote it");
        assert_eq!(Ghost::parse(b"II*\0\x08\0\0\0\x03\0", 8), Ghost::default(), "no ghost area");
        assert_eq!(Ghost::parse(&area("BLOCK_LEADER=SIZE_AS_UINT4\n"), 8), Ghost { leader: true, trailer: false });
    }
}
