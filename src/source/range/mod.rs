//! One seam for the sources that read bytes of a file or an object, in two steps.
//! [`RangeRead`] needs no size: a range read into the caller's buffer, and "up to this many
//! bytes" of an object of unknown size ([`RangeRead::read_upto`]). [`RangeReader`] adds the
//! size and a range streamed to a [`RangeSink`] in pieces as they arrive. A local file
//! ([`LocalFile`]: positioned reads) and bytes in memory ([`Memory`]) implement both here; in
//! the `remote` feature a remote object opened once (`remote::object::Object`: ranged reads of
//! the version seen at open) implements both, and a remote object read by name
//! (`remote::range::Named`: no request to open it, no version kept, the remote reader's disk
//! cache) implements [`RangeRead`], obtained through [`ByName`]. That is the only place the
//! feature is named on this seam apart from [`open_place`]'s remote arm.
//!
//! A COG or a tile archive opens a reader from a [`Place`] ([`open_place`]) and never asks which
//! kind it got, beyond what the trait tells: whether reads cost a request each
//! ([`RangeReader::is_remote`]), how many bytes one merged request may read
//! ([`RangeReader::merge_cap`]) and whether the object changed under it
//! ([`RangeReader::changed`]). A prepared pyramid (`crate::source::file`) reads each tile file
//! through [`RangeRead`] alone: a local file it keeps open, a remote one by name.
//!
//! The seam itself lives in [`reader`], below both the opener here and the remote object's
//! implementation; its names are re-exported here, so `crate::source::range::RangeReader` and
//! the rest keep their paths.

use crate::place::Place;
use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::sync::Arc;

pub mod reader;

pub use reader::{
    check_within, io_error, read_upto_sized, ByName, LocalFile, Memory, RangeError, RangeRead, RangeReader, RangeSink,
    Shared, TileFailure,
};

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
        Place::Remote(name) => crate::source::remote::range::open(name, prefix).map_err(OpenError::Remote),
        #[cfg(not(feature = "remote"))]
        Place::Remote(name) => Err(OpenError::Remote(format!(
            "{name}: this build reads no remote objects: build it with the `remote` feature, or copy the file here"
        ))),
    }
}

/// Opens the local regular file `path` with its first `prefix` bytes.
pub(crate) fn open_local(path: &Path, prefix: u64) -> Result<(Arc<dyn RangeReader>, Vec<u8>), OpenError> {
    let (file, _) = crate::open::regular(path).map_err(OpenError::Io)?;
    let mut first = vec![0u8; prefix as usize];
    let got = read_prefix(&file, &mut first).map_err(OpenError::Io)?;
    first.truncate(got);
    Ok((Arc::new(LocalFile(file)), first))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::{SourceError, TileId};
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
    fn read_upto_gives_the_bytes_there_are_and_only_local_and_memory_know_their_size_beforehand() {
        let bytes: Vec<u8> = (0..100u8).collect();
        let (_dir, readers) = readers(&bytes);
        for r in readers {
            let mut buf = [0u8; 30];
            assert_eq!(r.read_upto(80, &mut buf).unwrap(), 20);
            assert_eq!(buf[..20], bytes[80..]);
            assert_eq!(r.read_upto(10, &mut buf).unwrap(), 30);
            assert_eq!(buf, bytes[10..40]);
            assert_eq!(r.read_upto(100, &mut buf).unwrap(), 0);
            assert_eq!(r.read_upto(u64::MAX, &mut buf).unwrap(), 0);
            assert_eq!(r.known_size(), Some(100));
            // An empty read is within the file up to its end, and past the end past it.
            assert!(r.read_at(100, &mut []).is_ok());
            assert!(matches!(r.read_at(101, &mut []), Err(RangeError::Eof { size: 100 })));
        }
    }

    #[test]
    fn a_local_read_past_the_end_says_how_long_the_file_is_now() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grows");
        std::fs::write(&path, [1u8; 10]).unwrap();
        let (r, _) = open_local(&path, 0).unwrap();
        let mut buf = [0u8; 8];
        let e = r.read_at(5, &mut buf).unwrap_err();
        assert!(matches!(e, RangeError::Eof { size: 10 }), "{e:?}");
        // Its length is asked for when a read fails, not kept from open.
        std::fs::write(&path, [2u8; 20]).unwrap();
        r.read_at(5, &mut buf).unwrap();
        assert_eq!(buf, [2u8; 8]);
        assert!(matches!(r.read_at(1 << 63, &mut buf), Err(RangeError::Eof { size: 20 })));
        assert!(matches!(r.read_at(u64::MAX - 2, &mut buf), Err(RangeError::Eof { size: 20 })));
    }

    #[test]
    fn a_failure_outside_a_tile_is_an_io_error_of_its_kind() {
        let gone = RangeError::Remote {
            problem: "h/x: not found".into(),
            tile: Some(Box::new(|tile| SourceError::Missing { tile })),
        };
        let e = gone.into_io(0, 5);
        assert_eq!((e.kind(), e.to_string().as_str()), (io::ErrorKind::NotFound, "h/x: not found"));
        let denied = RangeError::Remote {
            problem: "403".into(),
            tile: Some(Box::new(|tile| SourceError::PermissionDenied { tile })),
        };
        assert_eq!(denied.into_io(0, 5).kind(), io::ErrorKind::PermissionDenied);
        let changed = RangeError::Remote { problem: "the object changed".into(), tile: None };
        assert_eq!(changed.into_io(0, 5).kind(), io::ErrorKind::Other);
        assert_eq!(RangeError::Eof { size: 3 }.into_io(2, 5).kind(), io::ErrorKind::UnexpectedEof);
        let local = RangeError::Io(io::Error::new(io::ErrorKind::PermissionDenied, "no"));
        assert_eq!(local.into_io(0, 1).kind(), io::ErrorKind::PermissionDenied);
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
