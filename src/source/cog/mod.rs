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
//! The bytes come from a range reader (`crate::source::range`): a local file (positioned reads,
//! an uncompressed tile straight into the slot), bytes in memory, or a remote object (ranged
//! reads, every one checked against the version, ETag or Last-Modified, and size seen at open). Open reads the first
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
//! largest first, overview i being level i when its size is exactly [`level_size`](crate::tile::level_size) of level 0
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

mod built;
mod decode;
mod error;
mod geokeys;
mod image;
mod index;
mod info;
mod level;
mod meta;
mod read;
mod structure;
mod tiff_georef;

pub use error::CogError;
pub use geokeys::GeoKeysError;
pub use info::{CogInfo, CogLevelInfo};
pub use level::{Compression, LevelOrigin};
pub use meta::{MASK_NODATA_F32, MASK_NODATA_I16, MASK_NODATA_U16};
pub use tiff_georef::tiff_georef;

use self::level::{AlphaRule, IfdLevel, Level};
use self::meta::{alpha_of, heights_of, rgba_of, BandMeta};
use self::structure::{ascii, read_ifds, Ghost, Head, Layout, Span};
use super::ahead::ReadAhead;
use super::{check_request, SourceError, TextureDesc, TileId, TileSource};
use crate::place::Place;
use crate::source::range::{self, OpenError, RangeReader, Shared};
use crate::texel::TexelFormat;
use std::cell::RefCell;
use std::collections::HashMap;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

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

/// A local tiled GeoTIFF or COG, or a remote one, served as a clip texture.
pub struct CogSource {
    path: PathBuf,
    /// The file's bytes, read in ranges.
    bytes: Arc<dyn RangeReader>,
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
    built: Mutex<Option<Arc<built::Built>>>,
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
    /// Where the file is on the Earth (its GeoTIFF tags), `None` when it does not say.
    georef: Result<Option<crate::georef::Georef>, GeoKeysError>,
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
        let (bytes, prefix) = range::open_local(path, PREFIX_BYTES).map_err(|e| open_error(path, e))?;
        CogSource::from_range(path.to_path_buf(), bytes, prefix, clip_size, true)?.built_now()
    }

    /// `self` with the levels past the overviews built (a failure refuses the file).
    fn built_now(self) -> Result<Self, CogError> {
        self.built_levels(None).map_err(|source| CogError::Build {
            path: self.path.clone(),
            from: self.levels.iter().filter(|l| matches!(l, Level::Ifd(_))).count() as u32,
            source,
        })?;
        Ok(self)
    }

    /// Opens the local TIFF `path` to read its full-resolution image only, with
    /// [`CogSource::read_full_resolution`] (`clipprep --input` and a growing texture's patches
    /// take TIFFs through it where the `image` crate's decoder does not read them, e.g. GDAL's
    /// YCbCr JPEG): the same checks as [`CogSource::open`], but nothing is built past the
    /// overviews, and an image without overviews is not refused for its size.
    pub fn open_full_resolution(path: &Path) -> Result<Self, CogError> {
        let (bytes, prefix) = range::open_local(path, PREFIX_BYTES).map_err(|e| open_error(path, e))?;
        CogSource::from_range(path.to_path_buf(), bytes, prefix, super::MAX_TEXTURE_SIZE, false)
    }

    /// [`CogSource::open_full_resolution`] of a TIFF's bytes (`name` names it in errors): a
    /// growing texture's patch, or bytes under test.
    pub fn from_bytes_full_resolution(name: &Path, bytes: Arc<[u8]>) -> Result<Self, CogError> {
        let prefix = bytes[..bytes.len().min(PREFIX_BYTES as usize)].to_vec();
        let bytes = Arc::new(range::Memory(bytes));
        CogSource::from_range(name.to_path_buf(), bytes, prefix, super::MAX_TEXTURE_SIZE, false)
    }

    /// [`CogSource::open`] of a TIFF's bytes (`name` names it in errors), served at clip size
    /// `clip_size`: the levels past the overviews are built here.
    pub fn from_bytes(name: &Path, bytes: Arc<[u8]>, clip_size: u64) -> Result<Self, CogError> {
        let prefix = bytes[..bytes.len().min(PREFIX_BYTES as usize)].to_vec();
        CogSource::from_range(name.to_path_buf(), Arc::new(range::Memory(bytes)), prefix, clip_size, true)?.built_now()
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
            Place::Remote(name) => {
                let path = PathBuf::from(crate::place::redacted(name.as_str()).as_ref());
                let (bytes, prefix) = range::open_place(place, PREFIX_BYTES).map_err(|e| open_error(&path, e))?;
                CogSource::open_ranges(path, bytes, prefix, clip_size)
            }
        }
    }

    /// The source of an object read in ranges whose first bytes are `prefix`: its tile index
    /// read in chunks as tiles are first read, and the levels past the overviews built when one
    /// is first read (its open stays one request).
    pub(crate) fn open_ranges(
        path: PathBuf,
        bytes: Arc<dyn RangeReader>,
        prefix: Vec<u8>,
        clip_size: u64,
    ) -> Result<Self, CogError> {
        let mut src = CogSource::from_range(path, bytes, prefix, clip_size, true)?;
        src.chunked = true;
        Ok(src)
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

    /// The source of `bytes`; with `build` false the levels past the overviews are never built
    /// (only level 0 is read: [`CogSource::open_full_resolution`]), and an image too large to
    /// build them from is not refused.
    fn from_range(
        path: PathBuf,
        bytes: Arc<dyn RangeReader>,
        prefix: Vec<u8>,
        clip_size: u64,
        build: bool,
    ) -> Result<Self, CogError> {
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
            Head { bytes: &*bytes, prefix: &prefix, failed: RefCell::new(None), windows: RefCell::new(Vec::new()) };
        let (mut nodata, mut meta) = (None, BandMeta::default());
        let mut georef = Ok(None);
        let parts = read_ifds(&reader, layout, first).map_err(malformed).and_then(|images| {
            // Read, never refused here: a file without (or with broken) georeferencing is served.
            georef = geokeys::georef_of(&path, &reader, layout, &images[0]);
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
            bytes,
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
            georef,
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
        self.bytes.changed()
    }

    /// Where the file is on the Earth, from its GeoTIFF tags (docs/GEOREF.md): `None` when it
    /// has no transform tag; the error when its tags cannot be read (the file is served all the
    /// same). Level k of the texture is [`Georef::level_transform`](crate::georef::Georef::level_transform)
    /// of it.
    pub fn georef(&self) -> Result<Option<&crate::georef::Georef>, &GeoKeysError> {
        self.georef.as_ref().map(Option::as_ref)
    }

    /// Where each level's texels come from, level 0 first.
    pub fn origins(&self) -> &[LevelOrigin] {
        &self.origins
    }
}

/// The refusal of a file or object that cannot be opened for reading.
fn open_error(path: &Path, e: OpenError) -> CogError {
    match e {
        OpenError::Io(source) => CogError::Io { path: path.to_path_buf(), source },
        OpenError::Remote(problem) => CogError::Remote { path: path.to_path_buf(), problem },
    }
}

impl TileSource for CogSource {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    fn heights(&self) -> Option<crate::plan::HeightPlan> {
        self.heights
    }

    /// Its GeoTIFF keys' georeferencing; `None` when it has none or they cannot be read (the
    /// file is served all the same; `cliptex info` says why).
    fn georef(&self) -> Option<crate::georef::Georef> {
        CogSource::georef(self).ok().flatten().cloned()
    }

    #[cfg(feature = "remote")]
    fn remote_stats(&self) -> Option<super::remote::RemoteStats> {
        let object = self.bytes.as_any().downcast_ref::<super::remote::object::Object>()?;
        Some(object.remote().stats())
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
        // The image the built levels are made from, kept when they were built: its tiles are
        // not read a second time.
        if let (Some(built), Level::Ifd(lv)) = (self.kept_base(tile.level, tile)?, &self.levels[tile.level as usize]) {
            if s0 + w <= lv.size[0] && t0 + h <= lv.size[1] {
                let texels = built.base.as_deref().unwrap_or_default();
                Self::copy_tile(texels, lv.size[0] as usize, bpt, [s0, t0], [w, h], [tw, th], out);
                return Ok(());
            }
        }
        match &self.levels[tile.level as usize] {
            Level::Built => {
                let built = self.built_levels(Some(tile))?;
                let used = self.desc.level_count() - built.levels.len();
                let texels = &built.levels[tile.level as usize - used];
                Self::copy_tile(texels, d.size[0] as usize, bpt, [s0, t0], [w, h], [tw, th], out);
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
