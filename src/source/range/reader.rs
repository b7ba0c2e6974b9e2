//! The byte seam itself and the readers that need no feature: a local file ([`LocalFile`]) and
//! bytes in memory ([`Memory`]). It names no opener and no remote reader, so the remote
//! implementations (`crate::source::remote::range`) and the opener above both
//! (`super::open_place`) each depend on it alone.
//!
//! The seam has two steps. [`RangeRead`] reads bytes at an offset and needs no size: what a
//! source that reads many small files by name uses (a prepared pyramid's tile files, read by
//! name through [`ByName`] with no request to open one). [`RangeReader`] adds the size and what
//! a source that reads one large file in many ranges asks (a COG, a tile archive): a read
//! streamed to a [`RangeSink`], whether reads cost a request, how many bytes one merged request
//! may read, whether the object changed since it was opened.

use crate::place::RemoteName;
use crate::source::{SourceError, TileId};
use std::any::Any;
use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::sync::Arc;

/// Bytes shared between readers, read into their buffer once.
pub type Shared = Arc<Vec<u8>>;

/// Where a streamed range's bytes go, in order from its first byte, as they arrive.
pub trait RangeSink: Send + Sync {
    /// The range's next bytes.
    fn push(&self, bytes: &[u8]);
    /// No more bytes come (all of them, or the read stopped).
    fn end(&self);
}

impl<K: Send + Sync> RangeSink for crate::source::ahead::Feed<K> {
    fn push(&self, bytes: &[u8]) {
        crate::source::ahead::Feed::push(self, bytes);
    }

    fn end(&self) {
        crate::source::ahead::Feed::end(self);
    }
}

/// How a failed remote read becomes a tile's failure (not found, denied, short, an I/O error).
pub type TileFailure = Box<dyn FnOnce(TileId) -> SourceError + Send>;

/// Why a range cannot be read.
pub enum RangeError {
    /// The range runs past the end (of `size` bytes).
    Eof {
        /// The size of the file or object.
        size: u64,
    },
    /// A local read failed.
    Io(io::Error),
    /// A remote read failed, or the object changed: `problem` says what; `tile` makes it a
    /// tile's failure when the read's answer tells one (else it is a damaged-tile failure naming
    /// the problem).
    Remote {
        /// What went wrong, in words.
        problem: String,
        /// The tile's failure, when the answer tells one.
        tile: Option<TileFailure>,
    },
}

impl std::fmt::Debug for RangeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RangeError::Eof { size } => f.debug_struct("Eof").field("size", size).finish(),
            RangeError::Io(e) => f.debug_tuple("Io").field(e).finish(),
            RangeError::Remote { problem, .. } => f.debug_struct("Remote").field("problem", problem).finish(),
        }
    }
}

impl RangeError {
    /// The problem in words, for a read of `len` bytes at `offset`.
    pub fn problem(&self, offset: u64, len: u64) -> String {
        match self {
            RangeError::Eof { size } => {
                format!("{len} bytes at byte {offset} run past the end of the file ({size} bytes)")
            }
            RangeError::Io(e) => e.to_string(),
            RangeError::Remote { problem, .. } => problem.clone(),
        }
    }

    /// The failure of a read of `len` bytes at `offset` of `path` for `tile`.
    pub(crate) fn for_tile(self, tile: TileId, path: &Path, offset: u64, len: u64) -> SourceError {
        match self {
            RangeError::Eof { size } => {
                SourceError::Short { tile, expected: len, got: size.saturating_sub(offset).min(len) }
            }
            RangeError::Io(e) => io_error(tile, e),
            RangeError::Remote { tile: Some(failure), .. } => failure(tile),
            RangeError::Remote { problem, tile: None } => {
                SourceError::Chunk { tile, path: path.to_path_buf(), problem }
            }
        }
    }

    /// The failure as an I/O error of the kind it is (not found, access refused, other), for a
    /// read that is not of a tile (a default tile read at start-up).
    pub(crate) fn into_io(self, offset: u64, len: u64) -> io::Error {
        let problem = self.problem(offset, len);
        match self {
            RangeError::Io(e) => e,
            RangeError::Eof { .. } => io::Error::new(io::ErrorKind::UnexpectedEof, problem),
            RangeError::Remote { tile, .. } => {
                let kind = match tile.map(|failure| failure(TileId::new(0, 0, 0))) {
                    Some(SourceError::Missing { .. }) => io::ErrorKind::NotFound,
                    Some(SourceError::PermissionDenied { .. }) => io::ErrorKind::PermissionDenied,
                    _ => io::ErrorKind::Other,
                };
                io::Error::new(kind, problem)
            }
        }
    }
}

/// The [`SourceError`] of an I/O failure on `tile`'s file.
pub fn io_error(tile: TileId, e: io::Error) -> SourceError {
    match e.kind() {
        io::ErrorKind::NotFound => SourceError::Missing { tile },
        io::ErrorKind::PermissionDenied => SourceError::PermissionDenied { tile },
        _ => SourceError::Io { tile, source: e },
    }
}

/// `Err(Eof)` unless `[offset, offset + len)` lies within `size` bytes.
pub fn check_within(offset: u64, len: u64, size: u64) -> Result<(), RangeError> {
    match offset.checked_add(len) {
        Some(end) if end <= size => Ok(()),
        _ => Err(RangeError::Eof { size }),
    }
}

/// Bytes of a file or an object read at an offset, with no size needed: the lower step of the
/// seam. A prepared pyramid's tiles are read through it, each file by name, with no request to
/// open one ([`ByName`]).
pub trait RangeRead: Send + Sync {
    /// Fills `buf` from byte `offset`; a range past the end is [`RangeError::Eof`] (with the
    /// size, when the reader learns it) or a short read's [`RangeError::Remote`].
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<(), RangeError>;

    /// Fills `buf` from byte `offset` with as many bytes as there are, up to `buf.len()`, in one
    /// read (one request of a remote object); returns how many. What a reader of an object of
    /// unknown size asks for to learn whether it holds more than it may (a compressed tile, a
    /// default tile: `buf` one byte longer than allowed).
    fn read_upto(&self, offset: u64, buf: &mut [u8]) -> Result<usize, RangeError>;

    /// The size, when it is known without a request (a local file's now); `None` for an object
    /// read by name. Only what an error says is taken from it.
    fn known_size(&self) -> Option<u64> {
        None
    }
}

/// Readers of remote objects by name, each obtained without a request: the remote reader
/// (`crate::source::remote::Remote`) implements it.
pub trait ByName: Send + Sync {
    /// A reader of the object `name`.
    fn reader<'a>(&'a self, name: &'a RemoteName) -> Box<dyn RangeRead + 'a>;
}

/// The bytes of a file or an object, read in ranges: its size and what a source reading it in
/// many ranges asks, over [`RangeRead`].
pub trait RangeReader: RangeRead + Any {
    /// Its size (a remote object's at open, a local file's now).
    fn size(&self) -> u64;

    /// Bytes `[offset, offset + len)` in one piece (one ranged read of a remote object).
    fn read_bytes(&self, offset: u64, len: u64) -> Result<Shared, RangeError> {
        check_within(offset, len, self.size())?;
        let mut v = vec![0u8; len as usize];
        self.read_at(offset, &mut v)?;
        Ok(Arc::new(v))
    }

    /// Starts reading bytes `[offset, offset + len)` into `sink`, which it ends when done,
    /// without waiting for the read where it can run on its own (a remote object's one request,
    /// its bytes handed over as they arrive; a local file's is read whole here). `ranges` is how
    /// many ranges the caller merged into this one (counted by a reader that keeps figures). A
    /// range past the end is refused at once, and nothing is started.
    fn stream(&self, offset: u64, len: u64, ranges: u64, sink: Arc<dyn RangeSink>) -> Result<(), RangeError> {
        let _ = ranges;
        let bytes = self.read_bytes(offset, len)?;
        sink.push(&bytes);
        sink.end();
        Ok(())
    }

    /// Whether each read costs a request (a remote object): such a reader is read in fewer,
    /// larger ranges.
    fn is_remote(&self) -> bool {
        false
    }

    /// The most bytes one request merging several ranges may read (0: nothing is merged).
    fn merge_cap(&self) -> u64 {
        0
    }

    /// Whether a read was refused because the object is no longer the version opened.
    fn changed(&self) -> bool {
        false
    }

    /// The reader itself, to ask an implementation for what the seam does not carry (the
    /// counters of a remote object's reads).
    fn as_any(&self) -> &dyn Any;
}

/// [`RangeRead::read_upto`] of a reader that knows its `size`: one read of the bytes there are.
pub fn read_upto_sized<R: RangeRead + ?Sized>(
    reader: &R,
    size: u64,
    offset: u64,
    buf: &mut [u8],
) -> Result<usize, RangeError> {
    let n = size.saturating_sub(offset).min(buf.len() as u64) as usize;
    if n > 0 {
        reader.read_at(offset, &mut buf[..n])?;
    }
    Ok(n)
}

/// A local file, read with positioned reads (no seek position: reads run in parallel).
#[derive(Debug)]
pub struct LocalFile(pub File);

impl LocalFile {
    /// The file's length now (an `fstat`).
    fn len_now(&self) -> u64 {
        self.0.metadata().map(|m| m.len()).unwrap_or(0)
    }
}

/// The largest offset a positioned read takes (the system's file offsets are signed).
const MAX_OFFSET: u64 = i64::MAX as u64;

impl RangeRead for LocalFile {
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<(), RangeError> {
        // A range past the end (an offset of 2^63 or more included, which the system refuses as
        // an invalid argument) is the file's end, said as such; the length is asked for only
        // then, never for a read that succeeds.
        if buf.is_empty() {
            return check_within(offset, 0, self.len_now());
        }
        if offset.checked_add(buf.len() as u64).is_none_or(|end| end > MAX_OFFSET) {
            return Err(RangeError::Eof { size: self.len_now() });
        }
        self.0.read_exact_at(buf, offset).map_err(|e| {
            if e.kind() == io::ErrorKind::UnexpectedEof {
                RangeError::Eof { size: self.len_now() }
            } else {
                RangeError::Io(e)
            }
        })
    }

    fn read_upto(&self, offset: u64, buf: &mut [u8]) -> Result<usize, RangeError> {
        if offset > MAX_OFFSET {
            return Ok(0);
        }
        let max = (MAX_OFFSET - offset).min(buf.len() as u64) as usize;
        let mut got = 0;
        while got < max {
            match self.0.read_at(&mut buf[got..max], offset + got as u64) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(RangeError::Io(e)),
            }
        }
        Ok(got)
    }

    fn known_size(&self) -> Option<u64> {
        Some(self.len_now())
    }
}

impl RangeReader for LocalFile {
    fn size(&self) -> u64 {
        self.len_now()
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// A whole file's bytes in memory (a growing texture's patch, bytes under test).
#[derive(Debug)]
pub struct Memory(pub Arc<[u8]>);

impl RangeRead for Memory {
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<(), RangeError> {
        let range = usize::try_from(offset).ok().and_then(|o| Some(o..o.checked_add(buf.len())?));
        match range.and_then(|r| self.0.get(r)) {
            Some(bytes) => {
                buf.copy_from_slice(bytes);
                Ok(())
            }
            None => Err(RangeError::Eof { size: self.size() }),
        }
    }

    fn read_upto(&self, offset: u64, buf: &mut [u8]) -> Result<usize, RangeError> {
        read_upto_sized(self, self.size(), offset, buf)
    }

    fn known_size(&self) -> Option<u64> {
        Some(self.size())
    }
}

impl RangeReader for Memory {
    fn size(&self) -> u64 {
        self.0.len() as u64
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}
