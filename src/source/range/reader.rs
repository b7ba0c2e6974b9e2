//! The byte seam itself ([`RangeReader`], [`RangeSink`], [`RangeError`]) and the readers that
//! need no feature: a local file ([`LocalFile`]) and bytes in memory ([`Memory`]). It names no
//! opener and no remote reader, so the remote object's implementation
//! (`crate::source::remote::range`) and the opener above both (`super::open_place`) each depend
//! on it alone.

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
    pub fn for_tile(self, tile: TileId, path: &Path, offset: u64, len: u64) -> SourceError {
        match self {
            RangeError::Eof { size } => {
                SourceError::Short { tile, expected: len, got: size.saturating_sub(offset).min(len) }
            }
            RangeError::Io(e) => crate::source::file::io_error(tile, e),
            RangeError::Remote { tile: Some(failure), .. } => failure(tile),
            RangeError::Remote { problem, tile: None } => {
                SourceError::Chunk { tile, path: path.to_path_buf(), problem }
            }
        }
    }
}

/// `Err(Eof)` unless `[offset, offset + len)` lies within `size` bytes.
pub fn check_within(offset: u64, len: u64, size: u64) -> Result<(), RangeError> {
    match offset.checked_add(len) {
        Some(end) if end <= size => Ok(()),
        _ => Err(RangeError::Eof { size }),
    }
}

/// The bytes of a file or an object, read in ranges.
pub trait RangeReader: Send + Sync + Any {
    /// Its size (a remote object's at open, a local file's now).
    fn size(&self) -> u64;

    /// Fills `buf` from byte `offset`; a range past the end is [`RangeError::Eof`].
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<(), RangeError>;

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

/// A local file, read with positioned reads (no seek position: reads run in parallel).
#[derive(Debug)]
pub struct LocalFile(pub File);

impl RangeReader for LocalFile {
    fn size(&self) -> u64 {
        self.0.metadata().map(|m| m.len()).unwrap_or(0)
    }

    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<(), RangeError> {
        // A range past the end (an offset of 2^63 or more included, which the system refuses as
        // an invalid argument) is the file's end, said as such.
        check_within(offset, buf.len() as u64, self.size())?;
        self.0.read_exact_at(buf, offset).map_err(|e| {
            if e.kind() == io::ErrorKind::UnexpectedEof {
                RangeError::Eof { size: self.size() }
            } else {
                RangeError::Io(e)
            }
        })
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// A whole file's bytes in memory (a growing texture's patch, bytes under test).
#[derive(Debug)]
pub struct Memory(pub Arc<[u8]>);

impl RangeReader for Memory {
    fn size(&self) -> u64 {
        self.0.len() as u64
    }

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

    fn as_any(&self) -> &dyn Any {
        self
    }
}
