//! A PMTiles v3 archive read through the byte seam: opened with one read of its first 16 KiB
//! (header and root directory), leaf directories read when a tile first needs one and kept in a
//! cache bounded in bytes (least recently used out), tiles read one range each.

use super::directory::{self, Entry, Found};
use super::header::{Compression, Header, HEADER_LEN};
use crate::place::Place;
use crate::source::range::{open_place, OpenError, RangeError, RangeReader};
use crate::source::tiles::reopen::{Renewable, Watched};
use crate::source::tiles::{ArchiveError, Fetched, PyramidInfo, TileAddr, TileArchive};
use crate::source::FaultKind;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// The bytes one open reads: the header and the root directory, which PMTiles v3 keeps within
/// the first 16 KiB.
pub const OPEN_BYTES: u64 = 16384;

/// The leaf directories' cache bound unless told otherwise ([`PmtilesArchive::with_leaf_cache`]).
pub const LEAF_CACHE_BYTES: u64 = 32 << 20;

/// The most bytes a directory may inflate to (a root or a leaf): a planet's leaves hold a few
/// MiB at most.
const DIRECTORY_MAX: u64 = 64 << 20;

/// The most bytes a leaf directory may have in the file.
const LEAF_MAX: u32 = 16 << 20;

/// The most bytes a tile may have, in the file or inflated.
const TILE_MAX: u64 = 64 << 20;

/// Root, leaf and at most two more levels of leaves: a deeper chain is a damaged archive.
const DEPTH_MAX: usize = 4;

/// The tile size [`PyramidInfo::tile_size`] says until [`PmtilesArchive::probe_tile_size`] has
/// read one: PMTiles v3 has no field for it, and 256 is what nearly every raster archive holds.
pub const DEFAULT_TILE_SIZE: u32 = 256;

/// Leaf directories by their place in the leaf section, bounded in bytes.
struct LeafCache {
    budget: u64,
    used: u64,
    tick: u64,
    leaves: HashMap<u64, (Arc<[Entry]>, u64, u64)>,
}

impl LeafCache {
    fn get(&mut self, offset: u64) -> Option<Arc<[Entry]>> {
        self.tick += 1;
        let tick = self.tick;
        self.leaves.get_mut(&offset).map(|(entries, _, last)| {
            *last = tick;
            Arc::clone(entries)
        })
    }

    fn put(&mut self, offset: u64, entries: Arc<[Entry]>) {
        let bytes = (entries.len() * std::mem::size_of::<Entry>()) as u64 + 64;
        if bytes > self.budget || self.leaves.contains_key(&offset) {
            return;
        }
        while self.used + bytes > self.budget {
            let Some((&oldest, _)) = self.leaves.iter().min_by_key(|(_, (_, _, last))| *last) else { break };
            if let Some((_, b, _)) = self.leaves.remove(&oldest) {
                self.used -= b;
            }
        }
        self.tick += 1;
        self.used += bytes;
        self.leaves.insert(offset, (entries, bytes, self.tick));
    }
}

/// A PMTiles v3 archive of raster tiles (PNG, JPEG or WebP), local or remote.
pub struct PmtilesArchive {
    place: String,
    bytes: Arc<dyn RangeReader>,
    header: Header,
    root: Vec<Entry>,
    info: PyramidInfo,
    leaves: Mutex<LeafCache>,
    /// Where it was opened from, to tell when it changed and to open it again; `None` for an
    /// archive read from a reader given ([`PmtilesArchive::from_reader`]).
    origin: Option<Origin>,
    /// Whether the tile size was read from the first tile ([`PmtilesArchive::probe_tile_size`]).
    probed: bool,
}

/// The remote reader a new version of a remote archive is read through.
#[cfg(feature = "remote")]
type SharedRemote = Arc<crate::source::remote::Remote>;
/// No remote reader in a build without the `remote` feature.
#[cfg(not(feature = "remote"))]
type SharedRemote = ();

/// Where an archive was opened from.
enum Origin {
    /// A local file, watched for replacement.
    Local(Watched),
    /// A remote object (its reader refuses bytes of another version, and says so).
    Remote(crate::place::RemoteName),
}

/// Whether `bounds` cover all of WebMercatorQuad (to its ±85.0511° edges, within a 1e-4° slack).
fn whole_world(b: [f64; 4]) -> bool {
    const EDGE: f64 = 85.0511;
    b[0] <= -180.0 + 1e-4 && b[2] >= 180.0 - 1e-4 && b[1] <= -EDGE && b[3] >= EDGE
}

impl PmtilesArchive {
    /// Opens the archive at `place` (a local path, an `http(s)://` URL or an `s3://` object)
    /// with one read of its first [`OPEN_BYTES`] bytes.
    /// A remote archive's ranges go through the disk cache the `CLIPMAP_REMOTE_*` variables
    /// name, if any ([`PmtilesArchive::open_with`]).
    pub fn open(place: &Place) -> Result<PmtilesArchive, ArchiveError> {
        PmtilesArchive::open_from(place, None, None)
    }

    /// [`PmtilesArchive::open`] with the remote options `opts` for a remote archive (their disk
    /// cache keeps its ranges read whole, under the archive's version; the open's read is
    /// always asked of the store, which names the version).
    #[cfg(feature = "remote")]
    pub fn open_with(
        place: &Place,
        opts: crate::source::remote::RemoteOptions,
    ) -> Result<PmtilesArchive, ArchiveError> {
        PmtilesArchive::open_from(place, None, Some(opts))
    }

    /// [`open`](Self::open), a remote object through `remote` when given (the same counters,
    /// connections, disk cache and bound on requests in flight as an earlier version's), else
    /// through a remote reader made with `opts` (those of the environment when `None`).
    fn open_from(
        place: &Place,
        remote: Option<SharedRemote>,
        #[cfg(feature = "remote")] opts: Option<crate::source::remote::RemoteOptions>,
        #[cfg(not(feature = "remote"))] opts: Option<()>,
    ) -> Result<PmtilesArchive, ArchiveError> {
        let name = crate::place::redacted(&place.to_string()).into_owned();
        let failed = |e: OpenError| {
            let (kind, problem) = match e {
                OpenError::Io(e) if e.kind() == std::io::ErrorKind::NotFound => (FaultKind::Missing, e.to_string()),
                OpenError::Io(e) => (FaultKind::Io, e.to_string()),
                OpenError::Remote(p) => (FaultKind::Io, p),
            };
            ArchiveError { place: name.clone(), at: None, kind, problem: format!("cannot open it: {problem}") }
        };
        let (origin, (bytes, first)) = match place {
            Place::Local(path) => {
                // Stamped before it is read: a change while it is opened shows at the first read.
                let watched = Watched::stamp(path).map_err(|e| failed(OpenError::Io(e)))?;
                (Origin::Local(watched), open_place(place, OPEN_BYTES).map_err(failed)?)
            }
            Place::Remote(r) => {
                let opened = match remote {
                    #[cfg(feature = "remote")]
                    Some(remote) => {
                        crate::source::remote::range::open_with(r, remote, OPEN_BYTES).map_err(OpenError::Remote)
                    }
                    #[cfg(feature = "remote")]
                    None => crate::source::remote::range::open_cached(r, OPEN_BYTES, opts).map_err(OpenError::Remote),
                    #[cfg(not(feature = "remote"))]
                    _ => {
                        let _ = (remote, opts);
                        open_place(place, OPEN_BYTES)
                    }
                };
                (Origin::Remote(r.clone()), opened.map_err(failed)?)
            }
        };
        let mut archive = PmtilesArchive::from_reader(name, bytes, &first)?;
        archive.origin = Some(origin);
        Ok(archive)
    }

    /// The archive read through `bytes`, whose first bytes (the first [`OPEN_BYTES`], or all of
    /// a smaller file) are `first`; `place` names it in messages.
    pub fn from_reader(
        place: String,
        bytes: Arc<dyn RangeReader>,
        first: &[u8],
    ) -> Result<PmtilesArchive, ArchiveError> {
        let corrupt =
            |problem: String| ArchiveError { place: place.clone(), at: None, kind: FaultKind::Corrupt, problem };
        let header = Header::parse(first, bytes.size()).map_err(corrupt)?;
        let (at, len) = (header.root.0 as usize, header.root.1 as usize);
        let Some(root) = first.get(at..at + len) else {
            return Err(corrupt(format!(
                "the root directory (bytes {at}..+{len}) lies past the first {} bytes read",
                first.len()
            )));
        };
        let root = directory::decompress(root, header.internal_compression, DIRECTORY_MAX)
            .and_then(|b| directory::parse(&b, header.data.1, header.leaves.1))
            .map_err(|p| corrupt(format!("the root directory (bytes {at}..+{len}): {p}")))?;
        let info = PyramidInfo {
            min_zoom: header.min_zoom,
            max_zoom: header.max_zoom,
            tile_size: DEFAULT_TILE_SIZE,
            bounds: (!whole_world(header.bounds)).then_some(header.bounds),
            encoding: Some(header.encoding),
        };
        debug_assert!(HEADER_LEN as u64 <= OPEN_BYTES);
        Ok(PmtilesArchive {
            place,
            bytes,
            header,
            root,
            info,
            leaves: Mutex::new(LeafCache { budget: LEAF_CACHE_BYTES, used: 0, tick: 0, leaves: HashMap::new() }),
            origin: None,
            probed: false,
        })
    }

    /// The same archive with its leaf directories' cache bounded to `bytes` (entries in memory).
    pub fn with_leaf_cache(self, bytes: u64) -> PmtilesArchive {
        self.leaves.lock().expect("leaf cache").budget = bytes;
        self
    }

    /// The header as read.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The bytes the leaf directories' cache holds now (entries in memory).
    pub fn leaf_cache_bytes(&self) -> u64 {
        self.leaves.lock().expect("leaf cache").used
    }

    fn error(&self, at: Option<TileAddr>, kind: FaultKind, problem: String) -> ArchiveError {
        ArchiveError { place: self.place.clone(), at, kind, problem }
    }

    /// Bytes `[offset, offset + len)` of the file, for `what`.
    fn read(&self, at: Option<TileAddr>, offset: u64, len: u64, what: &str) -> Result<Vec<u8>, ArchiveError> {
        self.bytes.read_bytes(offset, len).map(|b| b.to_vec()).map_err(|e| {
            let kind = match e {
                RangeError::Eof { .. } => FaultKind::Short,
                _ => FaultKind::Io,
            };
            self.error(at, kind, format!("reading the {what} at bytes {offset}..+{len}: {}", e.problem(offset, len)))
        })
    }

    /// The leaf directory at `offset` of the leaf section, `len` bytes: from the cache, or read.
    fn leaf(&self, at: Option<TileAddr>, offset: u64, len: u32) -> Result<Arc<[Entry]>, ArchiveError> {
        if let Some(entries) = self.leaves.lock().expect("leaf cache").get(offset) {
            return Ok(entries);
        }
        let corrupt = |p: String| {
            self.error(
                at,
                FaultKind::Corrupt,
                format!("the leaf directory at bytes {offset}..+{len} of the leaf section: {p}"),
            )
        };
        if len > LEAF_MAX {
            return Err(corrupt(format!("it has {len} bytes, more than the {LEAF_MAX} this reader accepts")));
        }
        let raw = self.read(at, self.header.leaves.0 + offset, len.into(), "leaf directory")?;
        let entries: Arc<[Entry]> = directory::decompress(&raw, self.header.internal_compression, DIRECTORY_MAX)
            .and_then(|b| directory::parse(&b, self.header.data.1, self.header.leaves.1))
            .map_err(corrupt)?
            .into();
        self.leaves.lock().expect("leaf cache").put(offset, Arc::clone(&entries));
        Ok(entries)
    }

    /// Where tile id `id` leads, through the root and leaf directories.
    fn locate(&self, at: Option<TileAddr>, id: u64) -> Result<Option<(u64, u32)>, ArchiveError> {
        let mut found = directory::find(&self.root, id);
        for _ in 0..DEPTH_MAX {
            match found {
                Found::Tile(offset, len) => return Ok(Some((offset, len))),
                Found::Missing => return Ok(None),
                Found::Leaf(offset, len) => found = directory::find(&self.leaf(at, offset, len)?, id),
            }
        }
        Err(self.error(at, FaultKind::Corrupt, format!("leaf directories nest deeper than {DEPTH_MAX} levels")))
    }

    /// The tile bytes at `offset` of the tile data, `len` of them, their compression undone.
    fn tile_bytes(&self, at: Option<TileAddr>, offset: u64, len: u32) -> Result<Vec<u8>, ArchiveError> {
        if u64::from(len) > TILE_MAX {
            return Err(self.error(
                at,
                FaultKind::Corrupt,
                format!("its entry says {len} bytes, more than the {TILE_MAX} a tile may have"),
            ));
        }
        let raw = self.read(at, self.header.data.0 + offset, len.into(), "tile")?;
        match self.header.tile_compression {
            Compression::None => Ok(raw),
            c => directory::decompress(&raw, c, TILE_MAX).map_err(|p| {
                self.error(at, FaultKind::Corrupt, format!("the tile at bytes {offset}..+{len} of the tile data: {p}"))
            }),
        }
    }

    /// Sets [`PyramidInfo::tile_size`] to `size`, as the user gave it (`--tile-size`), in place of
    /// [`probe_tile_size`](Self::probe_tile_size); each tile is still checked against it before
    /// it is decoded.
    pub fn set_tile_size(&mut self, size: u32) {
        self.info.tile_size = size;
    }

    /// Reads the first tile of the archive (the first of its coarsest zoom) and sets
    /// [`PyramidInfo::tile_size`] to its width, which PMTiles v3 does not record elsewhere;
    /// returns it. Costs the reads of that tile (and its leaf, if any). A tile that is not
    /// square, or whose size cannot be read from its first bytes, is refused.
    pub fn probe_tile_size(&mut self) -> Result<u32, ArchiveError> {
        let mut entries: Arc<[Entry]> = self.root.clone().into();
        for _ in 0..DEPTH_MAX {
            let Some(first) = entries.first().copied() else {
                return Err(self.error(None, FaultKind::Missing, "the archive holds no tiles".into()));
            };
            let addr = directory::tile_addr(first.tile_id);
            if first.run_length == 0 {
                entries = self.leaf(addr, first.offset, first.length)?;
                continue;
            }
            let bytes = self.tile_bytes(addr, first.offset, first.length)?;
            let size = match tile_dimensions(&bytes) {
                Some((w, h)) if w == h && w > 0 => w,
                Some((w, h)) => {
                    return Err(self.error(
                        addr,
                        FaultKind::Corrupt,
                        format!("the tile is {w} x {h} texels; tiles must be square"),
                    ))
                }
                None => {
                    return Err(self.error(
                        addr,
                        FaultKind::Corrupt,
                        "its size cannot be read from its first bytes (not PNG, JPEG or WebP)".into(),
                    ))
                }
            };
            self.info.tile_size = size;
            self.probed = true;
            return Ok(size);
        }
        Err(self.error(None, FaultKind::Corrupt, format!("leaf directories nest deeper than {DEPTH_MAX} levels")))
    }
}

/// The width and height a PNG, JPEG or WebP image says in its first bytes.
pub fn tile_dimensions(b: &[u8]) -> Option<(u32, u32)> {
    let be32 = |at: usize| Some(u32::from_be_bytes(b.get(at..at + 4)?.try_into().ok()?));
    let be16 = |at: usize| Some(u32::from(u16::from_be_bytes(b.get(at..at + 2)?.try_into().ok()?)));
    let le16 = |at: usize| Some(u32::from(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?)));
    let le24 = |at: usize| Some(u32::from_le_bytes([*b.get(at)?, *b.get(at + 1)?, *b.get(at + 2)?, 0]));
    match crate::source::tiles::TileEncoding::sniff(b)? {
        crate::source::tiles::TileEncoding::Png => (b.get(12..16)? == b"IHDR").then_some(())?,
        crate::source::tiles::TileEncoding::Jpeg => {
            // Walk the markers to the first start of frame (SOF0..SOF15 but DHT, JPG and DAC).
            let mut at = 2;
            loop {
                while *b.get(at)? != 0xFF {
                    at += 1;
                }
                while *b.get(at)? == 0xFF {
                    at += 1;
                }
                let marker = *b.get(at)?;
                at += 1;
                if (0xC0..=0xCF).contains(&marker) && ![0xC4, 0xC8, 0xCC].contains(&marker) {
                    return Some((be16(at + 5)?, be16(at + 3)?));
                }
                if marker == 0xD8 || (0xD0..=0xD7).contains(&marker) || marker == 0x01 {
                    continue;
                }
                at += be16(at)? as usize;
            }
        }
        crate::source::tiles::TileEncoding::Webp => {
            return match b.get(12..16)? {
                b"VP8 " => Some((le16(26)? & 0x3FFF, le16(28)? & 0x3FFF)),
                b"VP8L" => {
                    let v = u32::from_le_bytes(b.get(21..25)?.try_into().ok()?);
                    Some(((v & 0x3FFF) + 1, ((v >> 14) & 0x3FFF) + 1))
                }
                b"VP8X" => Some((le24(24)? + 1, le24(27)? + 1)),
                _ => None,
            };
        }
    }
    Some((be32(16)?, be32(20)?))
}

impl TileArchive for PmtilesArchive {
    fn place(&self) -> &str {
        &self.place
    }

    fn info(&self) -> &PyramidInfo {
        &self.info
    }

    fn fetch(&self, at: TileAddr) -> Result<Fetched, ArchiveError> {
        if !at.is_valid() {
            return Err(self.error(
                Some(at),
                FaultKind::BadRequest,
                format!(
                    "no such tile: zoom {} has {} columns and rows, and zooms go to {}",
                    at.z,
                    TileAddr::tiles_at(at.z.min(crate::source::tiles::MAX_ZOOM)),
                    crate::source::tiles::MAX_ZOOM
                ),
            ));
        }
        if at.z < self.info.min_zoom || at.z > self.info.max_zoom {
            return Ok(Fetched::Missing);
        }
        match self.locate(Some(at), directory::tile_id(at))? {
            Some((offset, len)) => self.tile_bytes(Some(at), offset, len).map(Fetched::Tile),
            None => Ok(Fetched::Missing),
        }
    }

    /// The length of the tile's entry in its directory (a leaf read when first needed): the
    /// bytes a read of the tile asks for.
    fn stored_length(&self, at: TileAddr) -> Option<Result<Option<u64>, ArchiveError>> {
        if !at.is_valid() || at.z < self.info.min_zoom || at.z > self.info.max_zoom {
            return Some(Ok(None));
        }
        Some(self.locate(Some(at), directory::tile_id(at)).map(|found| found.map(|(_, len)| u64::from(len))))
    }

    #[cfg(feature = "remote")]
    fn remote_stats(&self) -> Option<crate::source::remote::RemoteStats> {
        let object = self.bytes.as_any().downcast_ref::<crate::source::remote::object::Object>()?;
        Some(object.remote().stats())
    }

    #[cfg(feature = "remote")]
    fn is_cached(&self, at: TileAddr) -> bool {
        let Some(object) = self.bytes.as_any().downcast_ref::<crate::source::remote::object::Object>() else {
            return false;
        };
        if !at.is_valid() || at.z < self.info.min_zoom || at.z > self.info.max_zoom {
            return false;
        }
        match self.locate(Some(at), directory::tile_id(at)) {
            Ok(Some((offset, len))) => object.holds(self.header.data.0 + offset, len.into()),
            _ => false,
        }
    }
}

impl Renewable for PmtilesArchive {
    /// A local file replaced or rewritten since it was opened (one `stat`), or a remote object
    /// one of whose reads was refused because its version changed.
    fn stale(&self) -> Option<String> {
        match &self.origin {
            Some(Origin::Local(w)) => w.changed(),
            Some(Origin::Remote(_)) => self
                .bytes
                .changed()
                .then(|| "the object changed since it was opened (its ETag, Last-Modified or size)".to_string()),
            None => None,
        }
    }

    /// Opened again from where it was (a remote object through the same remote reader), its
    /// tile size read again from its first tile if it was so, else the one set.
    fn renew(&self) -> Result<PmtilesArchive, ArchiveError> {
        let mut fresh = match &self.origin {
            Some(Origin::Local(w)) => PmtilesArchive::open_from(&Place::Local(w.path().to_path_buf()), None, None)?,
            Some(Origin::Remote(name)) => {
                #[cfg(feature = "remote")]
                let remote = self
                    .bytes
                    .as_any()
                    .downcast_ref::<crate::source::remote::object::Object>()
                    .map(|o| Arc::clone(o.remote()));
                #[cfg(not(feature = "remote"))]
                let remote = None;
                PmtilesArchive::open_from(&Place::Remote(name.clone()), remote, None)?
            }
            None => {
                return Err(self.error(
                    None,
                    FaultKind::Io,
                    "it was not opened from a file or an object and cannot be opened again".into(),
                ))
            }
        };
        let budget = self.leaves.lock().expect("leaf cache").budget;
        fresh.leaves.lock().expect("leaf cache").budget = budget;
        if self.probed {
            fresh.probe_tile_size()?;
        } else {
            fresh.set_tile_size(self.info.tile_size);
        }
        Ok(fresh)
    }
}

#[cfg(test)]
mod tests {
    use super::super::directory::tests::serialize;
    use super::super::directory::tile_id;
    use super::super::header::tests::header_bytes;
    use super::*;
    use crate::source::range::Memory;

    fn addr(z: u8, x: u32, y: u32) -> TileAddr {
        TileAddr { z, x, y }
    }

    /// An archive of `tiles` (address, bytes; sorted by tile id, same bytes consecutive ones
    /// become one run) with leaves of `per_leaf` entries (0: all in the root), its directories
    /// compressed with zstd and its tiles with gzip.
    fn archive(tiles: &[(TileAddr, Vec<u8>)], per_leaf: usize) -> Vec<u8> {
        archive_compressed(tiles, per_leaf, Compression::Zstd, Compression::Gzip)
    }

    /// Bytes compressed as `c` (brotli by the `brotli` crate's encoder, quality 5).
    fn compress(b: &[u8], c: Compression) -> Vec<u8> {
        match c {
            Compression::None => b.to_vec(),
            Compression::Gzip => {
                let mut g = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
                std::io::Write::write_all(&mut g, b).unwrap();
                g.finish().unwrap()
            }
            Compression::Zstd => zstd::encode_all(b, 3).unwrap(),
            Compression::Brotli => {
                let mut out = Vec::new();
                brotli::BrotliCompress(
                    &mut &b[..],
                    &mut out,
                    &brotli::enc::BrotliEncoderParams { quality: 5, ..Default::default() },
                )
                .unwrap();
                out
            }
        }
    }

    /// The header's byte for `c`.
    fn byte(c: Compression) -> u8 {
        match c {
            Compression::None => 1,
            Compression::Gzip => 2,
            Compression::Brotli => 3,
            Compression::Zstd => 4,
        }
    }

    /// [`archive`] with directories compressed as `internal` and tiles as `tile`.
    fn archive_compressed(
        tiles: &[(TileAddr, Vec<u8>)],
        per_leaf: usize,
        internal: Compression,
        tile: Compression,
    ) -> Vec<u8> {
        let gz = |b: &[u8]| compress(b, tile);
        let mut data = Vec::new();
        let mut entries: Vec<Entry> = Vec::new();
        for (at, bytes) in tiles {
            let id = tile_id(*at);
            if let Some(last) = entries.last_mut() {
                if last.tile_id + u64::from(last.run_length) == id && data.ends_with(&gz(bytes)) {
                    last.run_length += 1;
                    continue;
                }
            }
            let z = gz(bytes);
            entries.push(Entry { tile_id: id, offset: data.len() as u64, length: z.len() as u32, run_length: 1 });
            data.extend(z);
        }
        let zs = |b: Vec<u8>| compress(&b, internal);
        let (root, leaves) = if per_leaf == 0 {
            (zs(serialize(&entries)), Vec::new())
        } else {
            let mut leaves = Vec::new();
            let mut root = Vec::new();
            for chunk in entries.chunks(per_leaf) {
                let leaf = zs(serialize(chunk));
                root.push(Entry {
                    tile_id: chunk[0].tile_id,
                    offset: leaves.len() as u64,
                    length: leaf.len() as u32,
                    run_length: 0,
                });
                leaves.extend(leaf);
            }
            (zs(serialize(&root)), leaves)
        };
        let root_at = HEADER_LEN as u64;
        let leaves_at = root_at + root.len() as u64;
        let data_at = leaves_at + leaves.len() as u64;
        let zooms = (tiles.iter().map(|t| t.0.z).min().unwrap(), tiles.iter().map(|t| t.0.z).max().unwrap());
        let mut f = header_bytes(
            (root_at, root.len() as u64),
            (leaves_at, leaves.len() as u64),
            (data_at, data.len() as u64),
            byte(internal),
            byte(tile),
            2,
            zooms,
        );
        f.extend(root);
        f.extend(leaves);
        f.extend(data);
        f
    }

    fn open(bytes: Vec<u8>) -> PmtilesArchive {
        let first = bytes[..bytes.len().min(OPEN_BYTES as usize)].to_vec();
        PmtilesArchive::from_reader("test.pmtiles".into(), Arc::new(Memory(bytes.into())), &first).unwrap()
    }

    fn png(w: u32, tag: u32) -> Vec<u8> {
        let mut b = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
        b.extend(w.to_be_bytes());
        b.extend(w.to_be_bytes());
        b.extend(tag.to_le_bytes());
        b
    }

    #[test]
    fn tiles_runs_and_leaves_read_back_and_absent_tiles_are_missing() {
        let mut tiles: Vec<(TileAddr, Vec<u8>)> = Vec::new();
        for z in 0..=4u8 {
            for x in 0..(1u32 << z) {
                for y in 0..(1u32 << z) {
                    if (x + y) % 3 != 1 {
                        // Every fourth tile of zoom 4 shares its bytes with its neighbours: runs.
                        let tag =
                            if z == 4 { tile_id(addr(z, x, y)) as u32 / 4 } else { tile_id(addr(z, x, y)) as u32 };
                        tiles.push((addr(z, x, y), png(512, tag)));
                    }
                }
            }
        }
        tiles.sort_by_key(|t| tile_id(t.0));
        for per_leaf in [0, 7] {
            let mut a = open(archive(&tiles, per_leaf));
            assert_eq!((a.info().min_zoom, a.info().max_zoom, a.info().bounds), (0, 4, None));
            assert_eq!(a.info().tile_size, DEFAULT_TILE_SIZE);
            for z in 0..=5u8 {
                for x in 0..(1u32 << z) {
                    for y in 0..(1u32 << z) {
                        let want = tiles.iter().find(|t| t.0 == addr(z, x, y)).map(|t| t.1.clone());
                        // The directories alone say which tiles are held, and their stored
                        // lengths (`cliptex seed --estimate`; the helper compresses the tiles).
                        let len = a.stored_length(addr(z, x, y)).expect("an index").unwrap();
                        assert_eq!(len.is_some(), want.is_some(), "{z}/{x}/{y}");
                        let got = a.fetch(addr(z, x, y)).unwrap();
                        assert_eq!(got, want.map_or(Fetched::Missing, Fetched::Tile), "{z}/{x}/{y}");
                    }
                }
            }
            assert_eq!(a.probe_tile_size().unwrap(), 512);
            assert_eq!(a.info().tile_size, 512);
            let e = a.fetch(addr(2, 4, 0)).unwrap_err();
            assert_eq!(e.kind, FaultKind::BadRequest);
        }
    }

    #[test]
    fn brotli_directories_and_tiles_read_back_and_damaged_brotli_is_refused() {
        let tiles: Vec<(TileAddr, Vec<u8>)> = (0..40u32)
            .map(|i| directory::tile_addr(tile_id(addr(3, 0, 0)) + u64::from(i)).unwrap())
            .map(|at| (at, png(256, at.x * 8 + at.y)))
            .collect();
        for (internal, tile) in [
            (Compression::Brotli, Compression::Brotli),
            (Compression::Brotli, Compression::None),
            (Compression::Gzip, Compression::Brotli),
        ] {
            for per_leaf in [0, 6] {
                let bytes = archive_compressed(&tiles, per_leaf, internal, tile);
                let a = open(bytes);
                assert_eq!((a.header().internal_compression, a.header().tile_compression), (internal, tile));
                for (at, want) in &tiles {
                    assert_eq!(a.fetch(*at).unwrap(), Fetched::Tile(want.clone()), "{internal:?} {tile:?} {at}");
                }
                assert_eq!(a.fetch(addr(3, 7, 7)).unwrap(), Fetched::Missing);
            }
        }
        // A brotli stream cut short is refused, never handed on as a tile.
        let good = compress(&png(256, 9), Compression::Brotli);
        assert_eq!(directory::decompress(&good, Compression::Brotli, 1 << 20).unwrap(), png(256, 9));
        let e = directory::decompress(&good[..good.len() - 3], Compression::Brotli, 1 << 20).unwrap_err();
        assert!(e.contains("Brotli"), "{e}");
        // The inflated size is bounded.
        let big = compress(&vec![7u8; 100_000], Compression::Brotli);
        assert!(directory::decompress(&big, Compression::Brotli, 50_000).unwrap_err().contains("more than 50000"));
    }

    #[test]
    fn the_leaf_cache_keeps_to_its_bound_and_drops_the_least_recently_used() {
        let tiles: Vec<_> = (0..64u32)
            .map(|i| directory::tile_addr(tile_id(addr(3, 0, 0)) + u64::from(i)).unwrap())
            .map(|at| (at, png(256, at.x * 8 + at.y)))
            .collect();
        let a = open(archive(&tiles, 8));
        let leaf_bytes = (8 * std::mem::size_of::<Entry>() + 64) as u64;
        let a = a.with_leaf_cache(3 * leaf_bytes);
        for (at, bytes) in &tiles {
            assert_eq!(a.fetch(*at).unwrap(), Fetched::Tile(bytes.clone()));
            assert!(a.leaf_cache_bytes() <= 3 * leaf_bytes);
        }
        assert_eq!(a.leaf_cache_bytes(), 3 * leaf_bytes);
        // The three most recent leaves are the last three.
        let cache = a.leaves.lock().unwrap();
        let mut kept: Vec<_> = cache.leaves.keys().copied().collect();
        kept.sort();
        let root_offsets: Vec<_> = a.root.iter().map(|e| e.offset).collect();
        assert_eq!(kept, root_offsets[5..]);
    }

    #[test]
    fn damaged_archives_are_refused_naming_where() {
        let tiles = vec![(addr(1, 0, 0), png(256, 1)), (addr(1, 1, 0), png(256, 2))];
        let good = archive(&tiles, 0);
        // Cut inside the tile data: the header's sections run past the end.
        let cut = good[..good.len() - 3].to_vec();
        let e = PmtilesArchive::from_reader("cut.pmtiles".into(), Arc::new(Memory(cut.clone().into())), &cut)
            .err()
            .unwrap();
        assert!(e.to_string().starts_with("cut.pmtiles: ") && e.problem.contains("past the end of the file"), "{e}");
        // A damaged root directory.
        let mut bad = good.clone();
        bad[HEADER_LEN + 2] ^= 0xFF;
        let e = PmtilesArchive::from_reader("bad.pmtiles".into(), Arc::new(Memory(bad.clone().into())), &bad)
            .err()
            .unwrap();
        assert!(e.problem.contains("root directory"), "{e}");
        // A local file that is not there.
        let e = PmtilesArchive::open(&Place::parse("/nonexistent/x.pmtiles")).err().unwrap();
        assert_eq!(e.kind, FaultKind::Missing);
    }

    #[test]
    fn tile_sizes_are_read_from_png_jpeg_and_webp_headers() {
        assert_eq!(tile_dimensions(&png(256, 0)), Some((256, 256)));
        // A JPEG: SOI, an APP0 of 16 bytes, SOF0 of 512 x 256.
        let mut j = vec![0xFF, 0xD8, 0xFF, 0xE0, 0, 16];
        j.extend([0u8; 14]);
        j.extend([0xFF, 0xC0, 0, 17, 8, 1, 0, 2, 0, 3]);
        assert_eq!(tile_dimensions(&j), Some((512, 256)));
        let mut w = b"RIFF\0\0\0\0WEBPVP8X\x0a\0\0\0\0\0\0\0".to_vec();
        w.extend([0xFF, 0, 0, 0x7F, 0, 0]);
        assert_eq!(tile_dimensions(&w), Some((256, 128)));
        assert_eq!(tile_dimensions(b"<html>"), None);
    }
}
