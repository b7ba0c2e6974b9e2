//! Where a TIFF's bytes are read from ([`Store`]): a local file, bytes in memory, or a remote
//! object.

use crate::source::ahead::Feed;
use crate::source::{SourceError, TileId};
use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::sync::Arc;

/// Where a TIFF's bytes are read from: a local file (positioned reads, straight into the
/// caller's buffer) or a remote object (ranged reads of the version seen at open).
pub(super) enum Store {
    Local(File),
    /// A whole file's bytes in memory (a growing texture's patch, the fuzz tests).
    Memory(Arc<[u8]>),
    #[cfg(feature = "remote")]
    Remote(crate::source::remote::object::Object),
}

/// Why bytes of a [`Store`] cannot be read.
pub(super) enum StoreError {
    /// The range runs past the end (of `size` bytes).
    Eof { size: u64 },
    /// A local read failed.
    Io(io::Error),
    /// A remote read failed, or the object changed.
    #[cfg(feature = "remote")]
    Remote(crate::source::remote::object::ObjectError),
}

impl StoreError {
    /// The problem in words, for a read of `len` bytes at `offset`.
    pub(super) fn problem(&self, offset: u64, len: u64) -> String {
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
    pub(super) fn for_tile(self, tile: TileId, path: &Path, offset: u64, len: u64) -> SourceError {
        match self {
            StoreError::Eof { size } => {
                SourceError::Short { tile, expected: len, got: size.saturating_sub(offset).min(len) }
            }
            StoreError::Io(e) => crate::source::file::io_error(tile, e),
            #[cfg(feature = "remote")]
            StoreError::Remote(crate::source::remote::object::ObjectError::Read(e)) => {
                crate::source::remote::source_error(tile, e)
            }
            #[cfg(feature = "remote")]
            StoreError::Remote(e) => SourceError::Chunk { tile, path: path.to_path_buf(), problem: e.to_string() },
        }
    }
}

impl Store {
    /// The size of the file now (a remote object's at open).
    pub(super) fn size(&self) -> u64 {
        match self {
            Store::Local(f) => f.metadata().map(|m| m.len()).unwrap_or(0),
            Store::Memory(b) => b.len() as u64,
            #[cfg(feature = "remote")]
            Store::Remote(o) => o.size(),
        }
    }

    pub(super) fn is_remote(&self) -> bool {
        !matches!(self, Store::Local(_) | Store::Memory(_))
    }

    /// Fills `buf` from byte `offset`.
    pub(super) fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> Result<(), StoreError> {
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
    pub(super) fn stream_detached(&self, offset: u64, len: u64, feed: Feed<TileId>) -> Result<(), StoreError> {
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
    pub(super) fn read_bytes(&self, offset: u64, len: u64) -> Result<Shared, StoreError> {
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
pub(super) type Shared = Arc<Vec<u8>>;

/// A remote answer's bytes handed to the tiles of a merged request as they arrive.
#[cfg(feature = "remote")]
pub(super) struct FeedSink(Feed<TileId>);

#[cfg(feature = "remote")]
impl crate::source::remote::Sink for FeedSink {
    fn head(&self, _: Option<u64>, _: Option<&str>) -> Result<(), String> {
        // The object's version is checked by the object (`Object::stream`).
        Ok(())
    }

    fn bytes(&self, bytes: bytes::Bytes) {
        self.0.push(&bytes);
    }
}

/// A run of a file's bytes read at once: `bytes` from byte `start`.
pub(super) struct Span<'a> {
    pub(super) start: u64,
    pub(super) bytes: &'a [u8],
}

impl Span<'_> {
    /// Bytes `[offset, offset + len)` when the span holds them all.
    pub(super) fn get(&self, offset: u64, len: u64) -> Option<&[u8]> {
        let from = offset.checked_sub(self.start)?;
        let to = from.checked_add(len)?;
        self.bytes.get(from as usize..usize::try_from(to).ok()?)
    }
}
