//! Writing a texture as one Cloud-Optimized GeoTIFF (`clipprep --cog OUT.tif`), laid out as
//! GDAL's COG driver lays it out, so that GDAL, QGIS and our own COG source read it:
//! - the 8-byte header (16 for BigTIFF, chosen when the file would pass 4 GiB), then GDAL's
//!   structural metadata (the "ghost area": `LAYOUT=IFDS_BEFORE_DATA`, row-major blocks, each with
//!   a 4-byte size before it and its last 4 bytes repeated after it);
//! - every IFD with its arrays, level 0 first, then its overviews (`NewSubfileType` 1), each the
//!   level before halved and rounded down, down to the first that fits in one tile;
//! - the tile data, the smallest overview first and level 0 last, each level row by row.
//!
//! Rows: a TIFF image's first row is its top; a texture's t counts up from its bottom row
//! (docs/ARCHITECTURE.md), so texel (s, t) of a level is pixel (s, H - 1 - t) of its image, as
//! the COG source reads it back. 8-bit grey, RGB and RGBA textures are written;
//! compression none, DEFLATE or ZSTD.
//!
//! The file is complete or absent: the tiles go to a scratch file `.NAME.PID.tiles.tmp` beside
//! the target, then the whole file to a temporary renamed over it ([`crate::save`]). A target
//! that is not a regular file (a FIFO, a device) is refused before anything is opened; a
//! cancellation flag (the tool's Ctrl-C or SIGTERM) is polled between tiles and while the file
//! is copied, and stops the write with both temporaries removed. Scratch files and temporaries
//! that a killed run left for the same target are removed when the next write starts.

use crate::source::{TileId, TileSource};
use crate::texel::TexelFormat;
use std::io::{self, Read, Seek, SeekFrom, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

/// How the tiles are compressed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CogCompression {
    /// Stored as they are (TIFF compression 1).
    None,
    /// zlib/DEFLATE (TIFF compression 8), at level 6.
    Deflate,
    /// Zstandard (TIFF compression 50000), at level 9, as GDAL's default.
    Zstd,
}

impl CogCompression {
    fn tag(self) -> u16 {
        match self {
            CogCompression::None => 1,
            CogCompression::Deflate => 8,
            CogCompression::Zstd => 50000,
        }
    }
}

/// What was written.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CogWritten {
    /// Images in the file (level 0 and its overviews).
    pub images: usize,
    /// Tiles written, all images.
    pub tiles: u64,
    /// Bytes of the file.
    pub bytes: u64,
    /// Whether it is a BigTIFF.
    pub bigtiff: bool,
}

/// Why the COG could not be written.
#[derive(Debug, thiserror::Error)]
pub enum CogWriteError {
    /// The texture's format or shape has no COG form here.
    #[error("{0}")]
    Unsupported(String),
    /// A tile of the texture could not be read.
    #[error("reading level {level} tile ({s}, {t}) of the texture: {why}")]
    Read {
        /// The level.
        level: u32,
        /// The tile's column.
        s: u64,
        /// The tile's row.
        t: u64,
        /// Why it could not be read.
        why: String,
    },
    /// The file could not be written.
    #[error("writing {path}: {source}")]
    Io {
        /// The file being written.
        path: String,
        /// The operating system's error.
        source: io::Error,
    },
    /// The target exists and is not a regular file; nothing was opened.
    #[error("{path}: {source}; a COG is written as a regular file: name a new file or a regular one to replace")]
    NotRegular {
        /// The target.
        path: String,
        /// What opening it as a regular file found.
        source: io::Error,
    },
    /// The write was cancelled (Ctrl-C or SIGTERM); its temporaries were removed.
    #[error("interrupted; the partial COG was removed and {path} was left as it was")]
    Interrupted {
        /// The target, left as it was.
        path: String,
    },
}

/// Refuses, before any work, a `path` the COG cannot be written at: one that exists and is not
/// a regular file (a FIFO, a device, a directory), said without opening it.
pub fn check_target(path: &Path) -> Result<(), CogWriteError> {
    crate::open::regular_or_absent(path)
        .map_err(|source| CogWriteError::NotRegular { path: path.display().to_string(), source })
}

/// One image of the file while it is written.
struct Image {
    level: u32,
    size: [u64; 2],
    /// Offsets (in the data section) and byte counts of its tiles, row-major from the top.
    tiles: Vec<(u64, u64)>,
}

/// Samples a texel, and the TIFF photometric and extra-samples values of `format`.
fn layout_of(format: TexelFormat) -> Result<(u16, u16, Option<u16>), CogWriteError> {
    match (format.bytes_per_texel(), format.short_name().as_str()) {
        (1, "l8") => Ok((1, 1, None)),
        (3, "rgb8") => Ok((3, 2, None)),
        (4, "rgba8") => Ok((4, 2, Some(2))),
        (_, name) => Err(CogWriteError::Unsupported(format!(
            "texel format {name}: a COG is written from l8, rgb8 or rgba8 textures (prepare with --format rgb8 or rgba8)"
        ))),
    }
}

/// Refuses, before any work, a texture `write` could not write: its texel format or its tile
/// side.
pub fn check(format: TexelFormat, tile: u64) -> Result<(), CogWriteError> {
    layout_of(format)?;
    if tile == 0 || !tile.is_multiple_of(16) || tile > 65520 {
        return Err(CogWriteError::Unsupported(format!(
            "a TIFF tile side of {tile}: it must be a multiple of 16 up to 65520 (choose --tile 256 or 512)"
        )));
    }
    Ok(())
}

/// Writes `src` as a COG at `path`, complete or not at all (a temporary file renamed over it);
/// `tile` is the TIFF tile side (a multiple of 16). `cancel` is polled between tiles and while
/// the file is copied: once set, the write stops with [`CogWriteError::Interrupted`] and leaves
/// `path` as it was.
pub fn write(
    src: &dyn TileSource,
    path: &Path,
    tile: u64,
    compression: CogCompression,
    cancel: &AtomicBool,
) -> Result<CogWritten, CogWriteError> {
    let desc = src.desc();
    check(desc.format(), tile)?;
    check_target(path)?;
    let (spp, photometric, extra) = layout_of(desc.format())?;
    let io_err = |source| CogWriteError::Io { path: path.display().to_string(), source };
    let interrupted = || CogWriteError::Interrupted { path: path.display().to_string() };
    // Levels 0 .. the first that fits in one tile (as GDAL stops its overviews).
    let mut levels = Vec::new();
    for (k, l) in desc.levels().iter().enumerate() {
        levels.push(k as u32);
        if l.size[0] <= tile && l.size[1] <= tile {
            break;
        }
    }
    // The tile data, smallest overview first, into a scratch file beside the target.
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let scratch = Scratch::new(dir, path).map_err(io_err)?;
    let mut data = &scratch.file;
    let mut images = Vec::new();
    let mut written = 0u64;
    let mut tiles = 0u64;
    for &k in levels.iter().rev() {
        let size = desc.level(k).size;
        let mut image = Image { level: k, size, tiles: Vec::new() };
        let across = size[0].div_ceil(tile);
        let rows = size[1].div_ceil(tile);
        for r in 0..rows {
            if cancel.load(Ordering::Relaxed) {
                return Err(interrupted());
            }
            let band = read_band(src, k, r * tile, tile)?;
            for c in 0..across {
                if cancel.load(Ordering::Relaxed) {
                    return Err(interrupted());
                }
                let raw = cut_tile(&band, size[0], c * tile, tile, spp as usize);
                let packed = compress(compression, raw).map_err(io_err)?;
                // GDAL's block leader (the size) and trailer (the last 4 bytes again).
                let n = packed.len() as u64;
                data.write_all(&(n as u32).to_le_bytes()).map_err(io_err)?;
                data.write_all(&packed).map_err(io_err)?;
                data.write_all(&packed[packed.len().saturating_sub(4)..]).map_err(io_err)?;
                image.tiles.push((written + 4, n));
                written += 4 + n + packed.len().min(4) as u64;
                tiles += 1;
            }
        }
        images.push(image);
    }
    images.reverse();
    let ghost = ghost_area();
    // Classic TIFF while every offset fits in 32 bits, BigTIFF otherwise.
    let small = Header::new(false, &images, spp, extra.is_some(), ghost.len() as u64);
    let bigtiff = small.data_start + written > u32::MAX as u64;
    let header = if bigtiff { Header::new(true, &images, spp, extra.is_some(), ghost.len() as u64) } else { small };
    let bytes = header.data_start + written;
    let saved = crate::save::atomically_regular(path, |w| {
        let mut head = Vec::with_capacity(header.data_start as usize);
        header.write(&mut head, &ghost, &images, spp, photometric, extra, compression, tile);
        debug_assert_eq!(head.len() as u64, header.data_start);
        w.write_all(&head)?;
        data.seek(SeekFrom::Start(0))?;
        // In pieces, so that a cancellation stops a copy of gigabytes promptly.
        let mut buf = vec![0u8; 1 << 20];
        let mut left = written;
        while left > 0 {
            if cancel.load(Ordering::Relaxed) {
                return Err(io::Error::other("cancelled"));
            }
            let n = left.min(buf.len() as u64) as usize;
            data.read_exact(&mut buf[..n]).map_err(|e| match e.kind() {
                io::ErrorKind::UnexpectedEof => {
                    io::Error::new(io::ErrorKind::UnexpectedEof, "the scratch file of tiles came back short")
                }
                _ => e,
            })?;
            w.write_all(&buf[..n])?;
            left -= n as u64;
        }
        Ok(())
    });
    match saved {
        Err(_) if cancel.load(Ordering::Relaxed) => return Err(interrupted()),
        Err(e) if e.kind() == io::ErrorKind::InvalidInput => {
            return Err(check_target(path).err().unwrap_or_else(|| io_err(e)))
        }
        Err(e) => return Err(io_err(e)),
        Ok(()) => {}
    }
    Ok(CogWritten { images: images.len(), tiles, bytes, bigtiff })
}

/// The scratch file of compressed tiles, removed when dropped (written or not).
struct Scratch {
    path: std::path::PathBuf,
    file: std::fs::File,
}

impl Scratch {
    /// Creates `.NAME.PID.tiles.tmp` beside `target`, after removing those of runs that were
    /// killed (their process is gone).
    fn new(dir: &Path, target: &Path) -> io::Result<Scratch> {
        crate::save::remove_stale(target, ".", ".tiles.tmp");
        let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let path = dir.join(format!(".{name}.{}.tiles.tmp", std::process::id()));
        let file = std::fs::OpenOptions::new().read(true).write(true).create_new(true).open(&path)?;
        Ok(Scratch { path, file })
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Rows `y0 .. y0 + rows` (from the image's top) of level `k`, whole width, top row first; rows
/// past the level's bottom are left zero.
fn read_band(src: &dyn TileSource, k: u32, y0: u64, rows: u64) -> Result<Vec<u8>, CogWriteError> {
    let d = *src.desc().level(k);
    let bpt = src.desc().bytes_per_texel();
    let [w, h] = d.size;
    let [tw, th] = d.tile;
    let row_bytes = w as usize * bpt;
    let mut band = vec![0u8; row_bytes * rows as usize];
    let y1 = (y0 + rows).min(h);
    if y0 >= y1 {
        return Ok(band);
    }
    // Image rows y0 .. y1 are texture rows t = h - y1 .. h - y0.
    let (t0, t1) = (h - y1, h - y0);
    let mut buf = vec![0u8; src.desc().tile_bytes(k)];
    for tt in t0 / th..t1.div_ceil(th) {
        for ts in 0..w.div_ceil(tw) {
            src.read_tile(TileId { level: k, s: ts, t: tt }, &mut buf).map_err(|e| CogWriteError::Read {
                level: k,
                s: ts,
                t: tt,
                why: e.to_string(),
            })?;
            let cols = (tw.min(w - ts * tw)) as usize * bpt;
            for i in 0..th {
                let t = tt * th + i;
                if t < t0 || t >= t1 {
                    continue;
                }
                let y = h - 1 - t - y0;
                let at = y as usize * row_bytes + (ts * tw) as usize * bpt;
                let from = i as usize * tw as usize * bpt;
                band[at..at + cols].copy_from_slice(&buf[from..from + cols]);
            }
        }
    }
    Ok(band)
}

/// The `tile x tile` TIFF tile at column `x0` of a band `width` texels wide (zero past its
/// right edge).
fn cut_tile(band: &[u8], width: u64, x0: u64, tile: u64, bpt: usize) -> Vec<u8> {
    let row_bytes = width as usize * bpt;
    let rows = band.len() / row_bytes.max(1);
    let mut out = vec![0u8; (tile * tile) as usize * bpt];
    let cols = tile.min(width - x0) as usize * bpt;
    for y in 0..rows.min(tile as usize) {
        let from = y * row_bytes + x0 as usize * bpt;
        out[y * tile as usize * bpt..][..cols].copy_from_slice(&band[from..from + cols]);
    }
    out
}

fn compress(c: CogCompression, raw: Vec<u8>) -> io::Result<Vec<u8>> {
    match c {
        CogCompression::None => Ok(raw),
        CogCompression::Deflate => {
            let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::new(6));
            e.write_all(&raw)?;
            e.finish()
        }
        CogCompression::Zstd => zstd::bulk::compress(&raw, 9),
    }
}

/// GDAL's structural metadata, as its COG driver writes it (the reader needs nothing else).
fn ghost_area() -> Vec<u8> {
    let body = "LAYOUT=IFDS_BEFORE_DATA\nBLOCK_ORDER=ROW_MAJOR\nBLOCK_LEADER=SIZE_AS_UINT4\n\
                BLOCK_TRAILER=LAST_4_BYTES_REPEATED\nKNOWN_INCOMPATIBLE_EDITION=NO\n ";
    format!("GDAL_STRUCTURAL_METADATA_SIZE={:06} bytes\n{body}", body.len()).into_bytes()
}

/// Where the header, the IFDs and their arrays go, and where the data starts.
struct Header {
    big: bool,
    /// Offset of each image's IFD.
    ifds: Vec<u64>,
    data_start: u64,
}

/// Entries an IFD has (the extra-samples one with alpha). SampleFormat is left out: its
/// default, unsigned integers, is what is written.
fn entry_count(alpha: bool) -> u64 {
    12 + alpha as u64
}

impl Header {
    fn new(big: bool, images: &[Image], spp: u16, alpha: bool, ghost: u64) -> Header {
        let (head, entry, count, next, off) = if big { (16, 20, 8, 8, 8) } else { (8, 12, 2, 4, 4) };
        let mut at = head + ghost;
        let mut ifds = Vec::new();
        for im in images {
            at += at % 2;
            ifds.push(at);
            at += count + entry_count(alpha) * entry + next;
            // Out-of-line arrays: BitsPerSample when it does not fit, the two tile arrays.
            if (spp as u64) * 2 > off {
                at += spp as u64 * 2;
            }
            let n = im.tiles.len() as u64;
            if n * off > off {
                at += 2 * n * off;
            }
        }
        Header { big, ifds, data_start: at + at % 2 }
    }

    #[allow(clippy::too_many_arguments)]
    fn write(
        &self,
        out: &mut Vec<u8>,
        ghost: &[u8],
        images: &[Image],
        spp: u16,
        photometric: u16,
        extra: Option<u16>,
        compression: CogCompression,
        tile: u64,
    ) {
        let big = self.big;
        let off = if big { 8u64 } else { 4 };
        if big {
            out.extend_from_slice(b"II\x2b\x00\x08\x00\x00\x00");
            out.extend_from_slice(&self.ifds[0].to_le_bytes());
        } else {
            out.extend_from_slice(b"II\x2a\x00");
            out.extend_from_slice(&(self.ifds[0] as u32).to_le_bytes());
        }
        out.extend_from_slice(ghost);
        for (i, im) in images.iter().enumerate() {
            while (out.len() as u64) < self.ifds[i] {
                out.push(0);
            }
            let n = im.tiles.len() as u64;
            let entries = entry_count(extra.is_some());
            let ifd_end = self.ifds[i] + if big { 8 } else { 2 } + entries * if big { 20 } else { 12 } + off;
            // Arrays right after the IFD, in this order.
            let mut arrays = ifd_end;
            let bits_at = ((spp as u64) * 2 > off).then(|| {
                let a = arrays;
                arrays += spp as u64 * 2;
                a
            });
            let (offsets_at, counts_at) = if n > 1 { (arrays, arrays + n * off) } else { (0, 0) };
            let data_start = self.data_start;
            let data = |o: u64| o + data_start;
            let mut e = Entries { out, big, count: 0 };
            e.begin(entries);
            e.value(254, 4, 1, (im.level > 0) as u64);
            e.value(256, 4, 1, im.size[0]);
            e.value(257, 4, 1, im.size[1]);
            match bits_at {
                Some(at) => e.value(258, 3, spp as u64, at),
                None => e.shorts(258, &vec![8; spp as usize]),
            }
            e.value(259, 3, 1, compression.tag() as u64);
            e.value(262, 3, 1, photometric as u64);
            e.value(277, 3, 1, spp as u64);
            e.value(284, 3, 1, 1);
            e.value(322, 4, 1, tile);
            e.value(323, 4, 1, tile);
            let long = if big { 16 } else { 4 };
            if n > 1 {
                e.value(324, long, n, offsets_at);
                e.value(325, long, n, counts_at);
            } else {
                e.value(324, long, 1, data(im.tiles[0].0));
                e.value(325, long, 1, im.tiles[0].1);
            }
            if let Some(x) = extra {
                e.value(338, 3, 1, x as u64);
            }
            debug_assert_eq!(e.count, entries);
            let next = if i + 1 < images.len() { self.ifds[i + 1] } else { 0 };
            e.end(next);
            debug_assert_eq!(out.len() as u64, ifd_end);
            if bits_at.is_some() {
                for _ in 0..spp {
                    out.extend_from_slice(&8u16.to_le_bytes());
                }
            }
            if n > 1 {
                for &(o, _) in &im.tiles {
                    put(out, big, data(o));
                }
                for &(_, c) in &im.tiles {
                    put(out, big, c);
                }
            }
        }
        while (out.len() as u64) < self.data_start {
            out.push(0);
        }
    }
}

/// A 4-byte (classic) or 8-byte (BigTIFF) offset or count.
fn put(out: &mut Vec<u8>, big: bool, v: u64) {
    if big {
        out.extend_from_slice(&v.to_le_bytes());
    } else {
        out.extend_from_slice(&(v as u32).to_le_bytes());
    }
}

/// IFD entries being written, in increasing tag order.
struct Entries<'a> {
    out: &'a mut Vec<u8>,
    big: bool,
    count: u64,
}

impl Entries<'_> {
    fn begin(&mut self, n: u64) {
        if self.big {
            self.out.extend_from_slice(&n.to_le_bytes());
        } else {
            self.out.extend_from_slice(&(n as u16).to_le_bytes());
        }
    }

    /// One entry of `count` values of `ty` (3 SHORT, 4 LONG, 16 LONG8) whose single value, or
    /// whose array's offset, is `v`.
    fn value(&mut self, tag: u16, ty: u16, count: u64, v: u64) {
        self.count += 1;
        self.out.extend_from_slice(&tag.to_le_bytes());
        self.out.extend_from_slice(&ty.to_le_bytes());
        let mut field = [0u8; 8];
        match (count, ty) {
            (1, 3) => field[..2].copy_from_slice(&(v as u16).to_le_bytes()),
            (1, 4) => field[..4].copy_from_slice(&(v as u32).to_le_bytes()),
            _ => field.copy_from_slice(&v.to_le_bytes()),
        }
        if self.big {
            self.out.extend_from_slice(&count.to_le_bytes());
            self.out.extend_from_slice(&field);
        } else {
            self.out.extend_from_slice(&(count as u32).to_le_bytes());
            self.out.extend_from_slice(&field[..4]);
        }
    }

    /// SHORT values that fit in the entry itself.
    fn shorts(&mut self, tag: u16, values: &[u16]) {
        self.count += 1;
        self.out.extend_from_slice(&tag.to_le_bytes());
        self.out.extend_from_slice(&3u16.to_le_bytes());
        let mut field = [0u8; 8];
        for (i, v) in values.iter().enumerate() {
            field[2 * i..2 * i + 2].copy_from_slice(&v.to_le_bytes());
        }
        if self.big {
            self.out.extend_from_slice(&(values.len() as u64).to_le_bytes());
            self.out.extend_from_slice(&field);
        } else {
            self.out.extend_from_slice(&(values.len() as u32).to_le_bytes());
            self.out.extend_from_slice(&field[..4]);
        }
    }

    fn end(&mut self, next: u64) {
        put(self.out, self.big, next);
    }
}
