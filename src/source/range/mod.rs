//! One seam for the sources that read bytes of a file or an object ([`RangeReader`]): its size,
//! a range read into the caller's buffer, and a range streamed to a [`RangeSink`] in pieces as
//! they arrive. A local file ([`LocalFile`]: positioned reads) and bytes in memory ([`Memory`])
//! implement it here; a remote object (`remote::object::Object`: ranged reads of the version
//! seen at open) implements it in the `remote` feature, the only place that feature is named on
//! this seam apart from [`open_place`]'s remote arm.
//!
//! A source opens a reader from a [`Place`] ([`open_place`]) and never asks which kind it got,
//! beyond what the trait tells: whether reads cost a request each ([`RangeReader::is_remote`]),
//! how many bytes one merged request may read ([`RangeReader::merge_cap`]) and whether the
//! object changed under it ([`RangeReader::changed`]).

use super::{SourceError, TileId};
use crate::place::Place;
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

impl<K: Send + Sync> RangeSink for super::ahead::Feed<K> {
    fn push(&self, bytes: &[u8]) {
        super::ahead::Feed::push(self, bytes);
    }

    fn end(&self) {
        super::ahead::Feed::end(self);
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
            RangeError::Io(e) => super::file::io_error(tile, e),
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

/// Why a place cannot be opened for reading.
#[derive(Debug)]
pub enum OpenError {
    /// The local file cannot be opened or read.
    Io(io::Error),
    /// The remote object cannot be opened (its options, the store, its first bytes), or this
    /// build reads none: the problem in words.
    Remote(String),
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

/// Opens `place` for reading in ranges, with its first `prefix` bytes (fewer when it is
/// smaller) read at once: a local regular file, or a remote object read with the remote options
/// of the environment (`CLIPMAP_REMOTE_*`), its first bytes one ranged GET, its ranges not kept
/// in the disk cache.
pub fn open_place(place: &Place, prefix: u64) -> Result<(Arc<dyn RangeReader>, Vec<u8>), OpenError> {
    match place {
        Place::Local(path) => open_local(path, prefix),
        #[cfg(feature = "remote")]
        Place::Remote(name) => super::remote::range::open(name, prefix).map_err(OpenError::Remote),
        #[cfg(not(feature = "remote"))]
        Place::Remote(name) => Err(OpenError::Remote(format!(
            "{name}: this build reads no remote objects: build it with the `remote` feature, or copy the file here"
        ))),
    }
}

/// Opens the local regular file `path` with its first `prefix` bytes.
pub fn open_local(path: &Path, prefix: u64) -> Result<(Arc<dyn RangeReader>, Vec<u8>), OpenError> {
    let (file, _) = crate::open::regular(path).map_err(OpenError::Io)?;
    let mut first = vec![0u8; prefix as usize];
    let got = read_prefix(&file, &mut first).map_err(OpenError::Io)?;
    first.truncate(got);
    Ok((Arc::new(LocalFile(file)), first))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    #[derive(Default)]
    struct Gather(Mutex<(Vec<u8>, bool)>);

    impl RangeSink for Gather {
        fn push(&self, bytes: &[u8]) {
            self.0.lock().unwrap().0.extend_from_slice(bytes);
        }
        fn end(&self) {
            self.0.lock().unwrap().1 = true;
        }
    }

    fn readers(bytes: &[u8]) -> (tempfile::TempDir, Vec<Arc<dyn RangeReader>>) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bytes");
        std::fs::write(&path, bytes).unwrap();
        let (local, first) = open_local(&path, 4).unwrap();
        assert_eq!(first, &bytes[..4]);
        (dir, vec![local, Arc::new(Memory(Arc::from(bytes)))])
    }

    #[test]
    fn local_and_memory_readers_give_the_same_ranges_and_refuse_past_the_end() {
        let bytes: Vec<u8> = (0..100u8).collect();
        let (_dir, readers) = readers(&bytes);
        for r in readers {
            assert_eq!(r.size(), 100);
            let mut buf = [0u8; 10];
            r.read_at(90, &mut buf).unwrap();
            assert_eq!(buf, bytes[90..]);
            assert_eq!(*r.read_bytes(5, 3).unwrap(), [5, 6, 7]);
            assert!(matches!(r.read_at(95, &mut buf), Err(RangeError::Eof { size: 100 })));
            assert!(matches!(r.read_bytes(u64::MAX, 2), Err(RangeError::Eof { size: 100 })));
            let e = r.read_bytes(99, 2).unwrap_err().for_tile(TileId::new(0, 1, 2), Path::new("f"), 99, 2);
            assert!(matches!(e, SourceError::Short { expected: 2, got: 1, .. }), "{e:?}");
            assert!(!r.is_remote() && r.merge_cap() == 0 && !r.changed());
        }
    }

    #[test]
    fn a_local_stream_hands_the_whole_range_over_then_ends() {
        let bytes: Vec<u8> = (0..50u8).collect();
        let (_dir, readers) = readers(&bytes);
        for r in readers {
            let sink = Arc::new(Gather::default());
            r.stream(10, 20, 2, sink.clone()).unwrap();
            let got = sink.0.lock().unwrap();
            assert_eq!((got.0.as_slice(), got.1), (&bytes[10..30], true));
            let untouched = Arc::new(Gather::default());
            assert!(matches!(r.stream(40, 20, 1, untouched.clone()), Err(RangeError::Eof { size: 50 })));
            assert_eq!(*untouched.0.lock().unwrap(), (Vec::new(), false), "nothing started past the end");
        }
    }

    #[test]
    fn a_remote_failure_becomes_the_tile_failure_it_names_or_a_damaged_tile() {
        let tile = TileId::new(1, 2, 3);
        let missing =
            RangeError::Remote { problem: "404".into(), tile: Some(Box::new(|tile| SourceError::Missing { tile })) };
        assert!(matches!(missing.for_tile(tile, Path::new("x"), 0, 1), SourceError::Missing { .. }));
        let changed = RangeError::Remote { problem: "the object changed".into(), tile: None };
        assert_eq!(changed.problem(3, 4), "the object changed");
        match changed.for_tile(tile, Path::new("x.tif"), 0, 1) {
            SourceError::Chunk { path, problem, .. } => {
                assert_eq!((path.as_path(), problem.as_str()), (Path::new("x.tif"), "the object changed"))
            }
            e => panic!("{e:?}"),
        }
    }
}
