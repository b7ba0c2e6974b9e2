//! [`FileSource`]: tiles read from the files a [`ClipTexturePlan`] names.
//!
//! Owns turning a plan into a [`TextureDesc`] (level sizes; image-cache levels are read in their
//! `.ic` tile size, pyramid levels as one tile the size of the level), reading each tile with one
//! read at the byte offset the plan computes (docs/PERFORMER-REFERENCE.md §1.12) through the byte
//! seam's lower step ([`RangeRead`]: a local file by positioned reads, a remote object by name
//! through the [`ByName`] reader it is given), a bounded set of
//! open file handles ([`Limits::max_open_files`], least recently used closed first), the default
//! tile of each image cache (§1.13: read once at start-up, checked to be one tile long, served in
//! place of a tile whose file is missing or too short), and the mapping of tiles to stream
//! servers (§1.11).
//!
//! Stream servers: every distinct stream path named by any level's `.ic` is one server, numbered
//! in order of first appearance. A tile goes to the server its axes propose with idle queues
//! (the S proposal when the level has S servers, else T, else R), which is
//! [`ImageCachePlan::locate`]'s choice; Performer's run-time "least busy proposal" tie-break is
//! not followed, so a tile keeps one queue while it waits. A clipmap gives each server its own
//! queue when its `Settings::streams` is [`TileSource::stream_servers`]; with fewer queues,
//! server i goes to queue i mod n. Levels without streams (and pyramid levels) use the tile
//! column S mod n, as the engine does for every other source.
//!
//! Scheduling reads, retrying and keeping tiles are the queue's and cache's business.

use super::{check_request, DescError, LevelDesc, SourceError, TextureDesc, TileId, TileSource};
use crate::limits::Limits;
use crate::open::SizedError;
use crate::place::{Place, RemoteName};
use crate::plan::{ClipTexturePlan, ImageCachePlan, LevelKind, TileError};
use crate::source::range::{ByName, LocalFile, RangeRead};
use serde::Serialize;
use std::collections::HashMap;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use thiserror::Error;

pub(crate) use crate::source::range::io_error;

/// Why a plan cannot be served as a tile source.
#[derive(Debug, Error)]
pub enum FileSourceError {
    /// A plan loaded with `ct_only`: its `.ic` files were not opened.
    #[error("{path}: level {level}'s image cache {ic} was not opened (the plan was loaded for a .ct-only check); load it with its .ic files to serve it", path = path.display(), ic = ic.display())]
    NotOpened {
        /// The `.ct`.
        path: PathBuf,
        /// The level.
        level: u32,
        /// The `.ic` it names.
        ic: PathBuf,
    },
    /// The plan's levels do not form a texture the engine serves.
    #[error("{path}: the levels cannot be served: {source}", path = path.display())]
    Desc {
        /// The `.ct`.
        path: PathBuf,
        /// What is wrong with them.
        #[source]
        source: DescError,
    },
    /// A three-dimensional clip texture.
    #[error("{path}: virt_size has depth {depth}: only 2-D clip textures (depth 1) can be served", path = path.display())]
    Depth {
        /// The `.ct`.
        path: PathBuf,
        /// The R size.
        depth: u64,
    },
    /// A default tile that cannot be read.
    #[error("default tile {path} of level {level}: {source}")]
    DefaultTileRead {
        /// The level whose `.ic` names it.
        level: u32,
        /// The file.
        path: Place,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// A default tile of the wrong size.
    #[error("default tile {path} of level {level} holds {found} bytes: expected {expected} (one {w}x{h} tile), or that plus the {header}-byte header")]
    DefaultTileSize {
        /// The level whose `.ic` names it.
        level: u32,
        /// The file.
        path: Place,
        /// Its length.
        found: u64,
        /// One tile's bytes.
        expected: u64,
        /// Tile width.
        w: u64,
        /// Tile height.
        h: u64,
        /// The `.ic`'s header offset.
        header: u64,
    },
}

/// Counters of a file source, since it was opened.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct FileStats {
    /// Tiles asked for.
    pub reads: u64,
    /// Bytes delivered (tiles read from their files and default tiles).
    pub bytes_read: u64,
    /// Tiles served from the default tile because their file was missing or short.
    pub default_tiles: u64,
    /// Files opened (a handle reused from the open set is not counted).
    pub files_opened: u64,
    /// Handles open now.
    pub open_files: u64,
}

/// A bounded set of open files, least recently used closed first.
struct Handles {
    bound: usize,
    clock: u64,
    open: HashMap<PathBuf, (Arc<LocalFile>, u64)>,
}

impl Handles {
    fn cached(&mut self, path: &Path) -> Option<Arc<LocalFile>> {
        self.clock += 1;
        let now = self.clock;
        self.open.get_mut(path).map(|(f, used)| {
            *used = now;
            Arc::clone(f)
        })
    }

    fn insert(&mut self, path: &Path, file: Arc<LocalFile>) {
        if self.bound == 0 {
            return;
        }
        while self.open.len() >= self.bound {
            let oldest = self.open.iter().min_by_key(|(_, (_, used))| *used).map(|(p, _)| p.clone());
            match oldest {
                Some(p) => self.open.remove(&p),
                None => break,
            };
        }
        self.clock += 1;
        self.open.insert(path.to_path_buf(), (file, self.clock));
    }
}

/// How one level's tiles map to stream servers: the axis whose list decides, and each list
/// entry's server number.
#[derive(Clone, Debug)]
struct LevelStreams {
    axis: usize,
    servers: Vec<usize>,
}

/// The error for a remote location that a source without a [`ByName`] reader was asked for.
fn no_remote(location: &RemoteName) -> io::Error {
    io::Error::new(
        io::ErrorKind::Unsupported,
        format!(
            "{location} is a remote location, and this source reads local files only: open the plan with clipmap::source::open_plan (built with the `remote` feature, the default)",
        ),
    )
}

/// Tiles read from the files a clip-texture plan names.
pub struct FileSource {
    plan: ClipTexturePlan,
    desc: TextureDesc,
    defaults: Vec<Option<Arc<[u8]>>>,
    streams: Vec<Option<LevelStreams>>,
    stream_names: Vec<String>,
    handles: Mutex<Handles>,
    remote: Option<Arc<dyn ByName>>,
    reads: AtomicU64,
    bytes_read: AtomicU64,
    default_tiles: AtomicU64,
    files_opened: AtomicU64,
}

/// The texture a plan describes: level sizes from the plan, image-cache levels in their tile
/// size and configured mem region, pyramid levels as one tile; the invalid border clamped so that one texel of each stack
/// window stays readable (Performer raises it to at least 8, more than a tiny clip size allows).
pub(crate) fn texture_desc(plan: &ClipTexturePlan) -> Result<TextureDesc, FileSourceError> {
    if plan.virt_size[2] > 1 {
        return Err(FileSourceError::Depth { path: plan.path.clone(), depth: plan.virt_size[2] });
    }
    let levels = plan
        .levels
        .iter()
        .map(|l| {
            let tile = match &l.kind {
                LevelKind::Icache(ic) => [ic.tile_size[0], ic.tile_size[1]],
                LevelKind::Pyramid(_) => l.size,
                LevelKind::IcacheNotOpened { path } => {
                    return Err(FileSourceError::NotOpened {
                        path: plan.path.clone(),
                        level: l.level,
                        ic: path.clone(),
                    })
                }
            };
            Ok(LevelDesc { size: l.size, tile })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let desc_err = |source| FileSourceError::Desc { path: plan.path.clone(), source };
    let size = [plan.virt_size[0], plan.virt_size[1]];
    let desc = TextureDesc::from_levels(size, plan.clip_size, plan.texel, levels).map_err(desc_err)?;
    // The mem region each image cache's configuration fixes (its `mem_region_size`, or the
    // region a lookahead it or the .ct gives implies): the engine holds exactly that many tiles
    // (raised to what covers the window, if less).
    let grids = plan
        .levels
        .iter()
        .map(|l| match &l.kind {
            // Fixed when the configuration says how large: a `mem_region_size`, or a lookahead
            // given in the .ic or the .ct. Otherwise the engine's policy sizes it (the adaptive
            // policy from its budget; the fixed ones give the same lookahead-1 grid).
            LevelKind::Icache(ic)
                if ic.defaulted.contains(&"mem_region")
                    && ic.defaulted.contains(&"lookahead")
                    && [ic.mem_region[0], ic.mem_region[1]]
                        == crate::geom::mem_grid(l.size, [ic.tile_size[0], ic.tile_size[1]], plan.clip_size, 1) =>
            {
                None
            }
            LevelKind::Icache(ic) => Some([ic.mem_region[0], ic.mem_region[1]]),
            _ => None,
        })
        .collect();
    let border = plan.invalid_border.min((plan.clip_size.max(1) - 1) / 2);
    Ok(desc.with_invalid_border(border).map_err(desc_err)?.with_mem_grids(grids))
}

/// Reads a small whole file or object whose length is one of `allowed` through `reader`: a
/// length known beforehand (a local file's) that is not allowed is refused before anything is
/// read; else at most one byte more than the longest allowed is read, in one read.
fn read_sized(reader: &dyn RangeRead, allowed: &[u64]) -> Result<Vec<u8>, SizedError> {
    if let Some(len) = reader.known_size().filter(|len| !allowed.contains(len)) {
        return Err(SizedError::Length(len));
    }
    let max = allowed.iter().copied().max().unwrap_or(0).saturating_add(1);
    let mut buf = vec![0u8; max as usize];
    let n = reader.read_upto(0, &mut buf).map_err(|e| SizedError::Io(e.into_io(0, max)))?;
    buf.truncate(n);
    if !allowed.contains(&(n as u64)) {
        return Err(SizedError::Length(n as u64));
    }
    Ok(buf)
}

/// Reads an image cache's default tile: exactly one tile, or one tile after the header. Only a
/// regular file of one of those two lengths is read (never more than a tile and its header).
fn read_default(
    level: u32,
    ic: &ImageCachePlan,
    path: &Place,
    remote: Option<&dyn ByName>,
) -> Result<Arc<[u8]>, FileSourceError> {
    let expected = ic.tile_bytes();
    let with_header = expected.saturating_add(ic.header_offset);
    let allowed: &[u64] = if ic.header_offset > 0 { &[expected, with_header] } else { &[expected] };
    let read = match (path, remote) {
        (Place::Local(p), _) => {
            crate::open::regular(p).map_err(SizedError::Io).and_then(|(f, _)| read_sized(&LocalFile(f), allowed))
        }
        (Place::Remote(name), Some(r)) => read_sized(&*r.reader(name), allowed),
        (Place::Remote(name), None) => Err(SizedError::Io(no_remote(name))),
    };
    let bytes = read.map_err(|e| match e {
        SizedError::Io(source) => FileSourceError::DefaultTileRead { level, path: path.clone(), source },
        SizedError::Length(found) => FileSourceError::DefaultTileSize {
            level,
            path: path.clone(),
            found,
            expected,
            w: ic.tile_size[0],
            h: ic.tile_size[1],
            header: ic.header_offset,
        },
    })?;
    let start = if bytes.len() as u64 == expected { 0 } else { ic.header_offset as usize };
    Ok(Arc::from(&bytes[start..]))
}

impl FileSource {
    /// A source over `plan`'s files. Reads every default tile now (Performer does too), sharing
    /// one buffer between levels that name the same file.
    pub fn new(plan: ClipTexturePlan, limits: &Limits) -> Result<Self, FileSourceError> {
        Self::with_remote(plan, limits, None)
    }

    /// A source over `plan`'s files that reads the remote locations among them through
    /// `remote` (without one, a remote tile is an I/O error saying so).
    pub(crate) fn with_remote(
        plan: ClipTexturePlan,
        limits: &Limits,
        remote: Option<Arc<dyn ByName>>,
    ) -> Result<Self, FileSourceError> {
        let desc = texture_desc(&plan)?;
        let mut read: HashMap<Place, Arc<[u8]>> = HashMap::new();
        let mut defaults = Vec::with_capacity(plan.levels.len());
        let mut stream_names: Vec<String> = Vec::new();
        let mut streams = Vec::with_capacity(plan.levels.len());
        for l in &plan.levels {
            let LevelKind::Icache(ic) = &l.kind else {
                defaults.push(None);
                streams.push(None);
                continue;
            };
            let default = match &ic.default_tile {
                None => None,
                Some(path) => match read.get(path) {
                    Some(d) if d.len() as u64 == ic.tile_bytes() => Some(Arc::clone(d)),
                    _ => {
                        let d = read_default(l.level, ic, path, remote.as_deref())?;
                        read.insert(path.clone(), Arc::clone(&d));
                        Some(d)
                    }
                },
            };
            defaults.push(default);
            let level_streams = ic.streams.iter().position(|list| !list.is_empty()).map(|axis| {
                let servers = ic.streams[axis]
                    .iter()
                    .map(|name| match stream_names.iter().position(|n| n == name) {
                        Some(i) => i,
                        None => {
                            stream_names.push(name.clone());
                            stream_names.len() - 1
                        }
                    })
                    .collect();
                LevelStreams { axis, servers }
            });
            streams.push(level_streams);
        }
        Ok(FileSource {
            plan,
            desc,
            defaults,
            streams,
            stream_names,
            handles: Mutex::new(Handles { bound: limits.max_open_files, clock: 0, open: HashMap::new() }),
            remote,
            reads: AtomicU64::new(0),
            bytes_read: AtomicU64::new(0),
            default_tiles: AtomicU64::new(0),
            files_opened: AtomicU64::new(0),
        })
    }

    /// The plan served.
    pub fn plan(&self) -> &ClipTexturePlan {
        &self.plan
    }

    /// The stream server paths, in server order (empty without streams).
    pub fn stream_names(&self) -> &[String] {
        &self.stream_names
    }

    /// Whether level `k` has a default tile.
    pub fn has_default_tile(&self, k: u32) -> bool {
        self.defaults.get(k as usize).is_some_and(Option::is_some)
    }

    /// Counters so far.
    pub fn stats(&self) -> FileStats {
        let open = self.handles.lock().unwrap_or_else(|e| e.into_inner()).open.len() as u64;
        FileStats {
            reads: self.reads.load(Ordering::Relaxed),
            bytes_read: self.bytes_read.load(Ordering::Relaxed),
            default_tiles: self.default_tiles.load(Ordering::Relaxed),
            files_opened: self.files_opened.load(Ordering::Relaxed),
            open_files: open,
        }
    }

    /// An open handle to `path`, from the open set or newly opened (outside the lock): only a
    /// regular file ([`crate::open::regular`]), so a tile that is a FIFO or a device is a failed
    /// read, never a blocked read slot or device bytes served as texels.
    fn handle(&self, path: &Path) -> io::Result<Arc<LocalFile>> {
        if let Some(f) = self.handles.lock().unwrap_or_else(|e| e.into_inner()).cached(path) {
            return Ok(f);
        }
        let file = Arc::new(LocalFile(crate::open::regular(path)?.0));
        self.files_opened.fetch_add(1, Ordering::Relaxed);
        self.handles.lock().unwrap_or_else(|e| e.into_inner()).insert(path, Arc::clone(&file));
        Ok(file)
    }

    /// Reads `tile`'s bytes from its file, without the default-tile fallback.
    fn read_file(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        let loc = self.plan.locate(tile.level, tile.s, tile.t).map_err(|e| match e {
            TileError::Unnamed { .. } => SourceError::Missing { tile },
            other => SourceError::Io { tile, source: io::Error::other(other) },
        })?;
        if loc.length != out.len() as u64 {
            return Err(SourceError::Corrupt { tile, expected: out.len() as u64, found: loc.length });
        }
        match &loc.path {
            Place::Local(path) => {
                let file = self.handle(path).map_err(|e| io_error(tile, e))?;
                read_stored(&*file, &loc.path, tile, loc.offset, out)
            }
            Place::Remote(name) => match &self.remote {
                Some(r) => read_stored(&*r.reader(name), &loc.path, tile, loc.offset, out),
                None => Err(SourceError::Io { tile, source: no_remote(name) }),
            },
        }
    }
}

/// The extension of a compressed tile file (`rRRR.cCCC.raw.zst`, docs/COMPRESSED-TILES.md).
const COMPRESSED: &str = "zst";

/// Whether a name (a local or remote [`Place`]) with this extension is a compressed tile file.
pub(crate) fn compressed_extension(extension: Option<&str>) -> bool {
    extension == Some(COMPRESSED)
}

/// The path an error names for `place`: a local path, or a remote name with its credentials
/// left out.
fn shown(place: &Place) -> PathBuf {
    match place {
        Place::Local(path) => path.clone(),
        Place::Remote(name) => PathBuf::from(crate::place::redacted(name.as_str()).as_ref()),
    }
}

/// Reads the tile stored at byte `offset` of `place` (read through `reader`) into `out`, which
/// is one tile long: the raw bytes there, or, for a compressed tile file, the one zstd frame the
/// whole file holds, decoded; it must decode to exactly `out.len()` bytes. A short raw read is
/// [`SourceError::Short`]; a compressed file that does not decode to one tile is
/// [`SourceError::Undecodable`] and leaves nothing to trust in `out`.
pub(crate) fn read_stored(
    reader: &dyn RangeRead,
    place: &Place,
    tile: TileId,
    offset: u64,
    out: &mut [u8],
) -> Result<(), SourceError> {
    if compressed_extension(place.extension()) {
        return read_compressed(reader, place, tile, offset, out);
    }
    reader.read_at(offset, out).map_err(|e| e.for_tile(tile, &shown(place), offset, out.len() as u64))
}

thread_local! {
    /// Each reading thread's zstd context and buffer for the compressed bytes, kept between
    /// tiles so that a read allocates nothing once warm.
    static ZSTD: std::cell::RefCell<(Option<zstd::bulk::Decompressor<'static>>, Vec<u8>)> =
        const { std::cell::RefCell::new((None, Vec::new())) };
}

/// A compressed tile file (docs/COMPRESSED-TILES.md), read whole in one read of at most one byte
/// more than one tile compresses to, and decoded.
fn read_compressed(
    reader: &dyn RangeRead,
    place: &Place,
    tile: TileId,
    offset: u64,
    out: &mut [u8],
) -> Result<(), SourceError> {
    let bad = |problem: String| SourceError::Undecodable { tile, path: shown(place), problem };
    if offset != 0 {
        return Err(bad(format!(
            "its tile is placed at byte {offset}, but a compressed file holds one whole tile (no header, one tile per file)"
        )));
    }
    // The most a zstd frame of one tile can take (incompressible data grows a little).
    let bound = zstd::zstd_safe::compress_bound(out.len());
    ZSTD.with(|cell| {
        let (ctx, packed) = &mut *cell.borrow_mut();
        packed.resize(bound + 1, 0);
        let n = reader.read_upto(0, packed).map_err(|e| e.for_tile(tile, &shown(place), 0, bound as u64 + 1))?;
        if n > bound {
            let tile_bytes = out.len();
            return Err(bad(match (place, reader.known_size()) {
                (Place::Local(_), Some(len)) => format!(
                    "the file holds {len} bytes, more than one {tile_bytes}-byte tile compresses to ({bound} at most)"
                ),
                _ => format!("the object holds more than one {tile_bytes}-byte tile compresses to ({bound} at most)"),
            }));
        }
        if ctx.is_none() {
            *ctx = Some(zstd::bulk::Decompressor::new().map_err(|e| io_error(tile, e))?);
        }
        let ctx = ctx.as_mut().expect("just made");
        match ctx.decompress_to_buffer(&packed[..n], out) {
            Ok(n) if n == out.len() => Ok(()),
            Ok(n) => Err(bad(format!("it decodes to {n} bytes, expected one tile of {}", out.len()))),
            Err(e) => Err(bad(format!("it is not one zstd frame of a {}-byte tile ({e})", out.len()))),
        }
    })
}

impl TileSource for FileSource {
    fn desc(&self) -> &TextureDesc {
        &self.desc
    }

    /// What the `.ct`'s `#clipmap georef_…` lines record (docs/GEOREF.md), if anything.
    fn georef(&self) -> Option<crate::georef::Georef> {
        self.plan.georef.clone()
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.read_into(tile, out).map(|_| ())
    }

    fn read_into(&self, tile: TileId, out: &mut [u8]) -> Result<super::Delivered, SourceError> {
        check_request(&self.desc, tile, out)?;
        self.reads.fetch_add(1, Ordering::Relaxed);
        let result = match self.read_file(tile, out) {
            Err(SourceError::Missing { .. } | SourceError::Short { .. }) if self.has_default_tile(tile.level) => {
                let default = self.defaults[tile.level as usize].as_deref().unwrap_or_default();
                out.copy_from_slice(default);
                self.default_tiles.fetch_add(1, Ordering::Relaxed);
                Ok(super::Delivered::Default)
            }
            other => other.map(|()| super::Delivered::Tile),
        };
        if result.is_ok() {
            self.bytes_read.fetch_add(out.len() as u64, Ordering::Relaxed);
        }
        result
    }

    fn stream_servers(&self) -> usize {
        self.stream_names.len().max(1)
    }

    fn heights(&self) -> Option<crate::plan::HeightPlan> {
        self.plan.height
    }

    fn stream_of(&self, tile: TileId, streams: usize) -> usize {
        let n = streams.max(1);
        match self.streams.get(tile.level as usize) {
            Some(Some(ls)) => {
                let index = [tile.s, tile.t, 0][ls.axis];
                ls.servers[(index % ls.servers.len() as u64) as usize] % n
            }
            _ => (tile.s % n as u64) as usize,
        }
    }
}

#[cfg(test)]
#[path = "file_tests.rs"]
mod tests;
