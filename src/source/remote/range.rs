//! Remote objects on the byte seam (`crate::source::range::reader`), the implementations the
//! `remote` feature brings:
//! - an object opened once, as a [`RangeReader`] ([`Object`]): ranged reads of the version seen
//!   at open, a streamed range run on the process's runtime with its bytes handed to the sink as
//!   they arrive, and the figures of merged ranges kept in the remote reader's fetcher
//!   (`crate::source::merge::Merged`). A COG's or a tile archive's bytes.
//! - an object read by name, as a [`RangeRead`] ([`Named`], from [`ByName`] on [`Remote`]):
//!   nothing is asked to obtain one (no request, no size), no version is kept (a file uploaded
//!   again is read as it is now), and a range read whole goes through the remote reader's disk
//!   cache and is merged with adjacent ranges waiting for the same endpoint. A prepared
//!   pyramid's tile files, where one file may hold one tile and opening each would double the
//!   requests.

use super::fetch::{ReadError, Sink};
use super::location::Location;
use super::object::{Object, ObjectError};
use super::{disk, Remote, RemoteOptions};
use crate::place::RemoteName;
use crate::source::range::reader::{
    check_within, read_upto_sized, ByName, RangeError, RangeRead, RangeReader, RangeSink, Shared,
};
use crate::source::SourceError;
use std::any::Any;
use std::io;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// The most bytes one request merging several ranges of an object reads, whatever the remote
/// options' `merge_bytes` say.
pub(crate) const MAX_MERGE_BYTES: u64 = 8 << 20;

impl From<ObjectError> for RangeError {
    fn from(e: ObjectError) -> RangeError {
        let problem = e.to_string();
        match e {
            ObjectError::Read(read) => {
                RangeError::Remote { problem, tile: Some(Box::new(move |tile| super::source_error(tile, read))) }
            }
            _ => RangeError::Remote { problem, tile: None },
        }
    }
}

/// A range sink as the fetcher's sink: the answer's bytes handed over as they arrive.
struct ToSink(Arc<dyn RangeSink>);

impl Sink for ToSink {
    fn head(&self, _: Option<u64>, _: Option<&str>) -> Result<(), String> {
        // The object's version is checked by the object (`Object::stream`).
        Ok(())
    }

    fn bytes(&self, bytes: bytes::Bytes) {
        self.0.push(&bytes);
    }
}

impl From<ReadError> for RangeError {
    fn from(e: ReadError) -> RangeError {
        RangeError::Remote { problem: e.to_string(), tile: Some(Box::new(move |tile| super::source_error(tile, e))) }
    }
}

impl RangeRead for Object {
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<(), RangeError> {
        check_within(offset, buf.len() as u64, Object::size(self))?;
        self.read(offset, buf.len() as u64)?.copy_to(buf);
        Ok(())
    }

    fn read_upto(&self, offset: u64, buf: &mut [u8]) -> Result<usize, RangeError> {
        read_upto_sized(self, Object::size(self), offset, buf)
    }

    fn known_size(&self) -> Option<u64> {
        Some(Object::size(self))
    }
}

impl RangeReader for Object {
    fn size(&self) -> u64 {
        Object::size(self)
    }

    fn read_bytes(&self, offset: u64, len: u64) -> Result<Shared, RangeError> {
        check_within(offset, len, Object::size(self))?;
        let segments = self.read(offset, len)?;
        let mut v = vec![0u8; segments.len()];
        segments.copy_to(&mut v);
        Ok(Arc::new(v))
    }

    fn stream(&self, offset: u64, len: u64, ranges: u64, sink: Arc<dyn RangeSink>) -> Result<(), RangeError> {
        check_within(offset, len, Object::size(self))?;
        self.remote().fetcher().merged.count(ranges);
        let to: Arc<dyn Sink> = Arc::new(ToSink(Arc::clone(&sink)));
        self.stream_detached(offset, len, to, move |result| {
            if let Err(e) = result {
                // Its ranges are read on their own, each reporting what goes wrong.
                tracing::debug!("a merged read of {len} bytes at byte {offset} failed: {e}");
            }
            sink.end();
        });
        Ok(())
    }

    fn is_remote(&self) -> bool {
        true
    }

    fn merge_cap(&self) -> u64 {
        self.remote().fetcher().options().merge_bytes.min(MAX_MERGE_BYTES)
    }

    fn changed(&self) -> bool {
        self.has_changed()
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// Opens the remote object `name` through `remote` with one ranged read of its first `prefix`
/// bytes; the problem in words when it cannot.
pub fn open_with(
    name: &RemoteName,
    remote: Arc<Remote>,
    prefix: u64,
) -> Result<(Arc<dyn RangeReader>, Vec<u8>), String> {
    let (object, first) = Object::open(remote, name, prefix).map_err(|e| e.to_string())?;
    Ok((Arc::new(object), first.to_vec()))
}

/// Opens the remote object `name` with the remote options of the environment
/// (`CLIPMAP_REMOTE_*`), its ranges not kept in the disk cache (none is opened).
pub fn open(name: &RemoteName, prefix: u64) -> Result<(Arc<dyn RangeReader>, Vec<u8>), String> {
    let opts = RemoteOptions::from_env().map_err(|e| e.to_string())?;
    let remote = Remote::new(RemoteOptions { cache_dir: None, ..opts }).map_err(|e| e.to_string())?;
    open_with(name, Arc::new(remote), prefix)
}

/// Opens the remote object `name` with the remote options `opts` (those of the environment,
/// `CLIPMAP_REMOTE_*`, when `None`), its ranges read whole kept in the disk cache they name
/// (`CLIPMAP_REMOTE_CACHE_DIR`) under the object's version ([`Object::read`]): a tile archive's.
pub fn open_cached(
    name: &RemoteName,
    prefix: u64,
    opts: Option<RemoteOptions>,
) -> Result<(Arc<dyn RangeReader>, Vec<u8>), String> {
    let opts = match opts {
        Some(o) => o,
        None => RemoteOptions::from_env().map_err(|e| e.to_string())?,
    };
    let remote = Remote::new(opts)
        .map_err(|e| format!("the remote disk cache (CLIPMAP_REMOTE_CACHE_DIR) cannot be used: {e}"))?;
    open_with(name, Arc::new(remote), prefix)
}

/// A remote object read by name ([`ByName`] on [`Remote`]): nothing is asked to obtain one, no
/// version is kept, and a range read whole is served from the remote reader's disk cache when
/// it holds it (and kept there once read).
pub struct Named<'a> {
    remote: &'a Remote,
    name: &'a RemoteName,
}

impl<'a> Named<'a> {
    /// A reader of `name` through `remote`.
    pub fn new(remote: &'a Remote, name: &'a RemoteName) -> Named<'a> {
        Named { remote, name }
    }
}

impl ByName for Remote {
    fn reader<'a>(&'a self, name: &'a RemoteName) -> Box<dyn RangeRead + 'a> {
        Box::new(Named::new(self, name))
    }
}

impl RangeRead for Named<'_> {
    /// One range of the object, from the disk cache when it holds it, else read through the
    /// fetcher (merged with adjacent ranges waiting for the same endpoint, retried) and kept in
    /// the cache.
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<(), RangeError> {
        let key = disk::key(self.name.as_str(), offset, buf.len() as u64);
        if let Some(c) = &self.remote.cache {
            if c.get(&key, buf) {
                self.remote.fetcher.counters.cache_hits.fetch_add(1, Ordering::Relaxed);
                return Ok(());
            }
        }
        let loc = Location::of(self.name).map_err(|e| {
            let problem = e.to_string();
            let text = problem.clone();
            RangeError::Remote {
                problem,
                tile: Some(Box::new(move |tile| SourceError::Io {
                    tile,
                    source: io::Error::new(io::ErrorKind::InvalidInput, text),
                })),
            }
        })?;
        let bytes = self.remote.fetcher.read(&loc, offset, buf.len() as u64)?;
        if bytes.len() != buf.len() {
            let (expected, got) = (buf.len() as u64, bytes.len() as u64);
            return Err(RangeError::Remote {
                problem: format!(
                    "{}: {got} bytes at byte {offset}, expected {expected}",
                    crate::place::redacted(self.name.as_str())
                ),
                tile: Some(Box::new(move |tile| SourceError::Short { tile, expected, got })),
            });
        }
        bytes.copy_to(buf);
        if let Some(c) = &self.remote.cache {
            c.put(&key, buf);
        }
        Ok(())
    }

    /// The bytes from `offset` on, at most `buf.len()`, in one request (retried; not merged, not
    /// cached).
    fn read_upto(&self, offset: u64, buf: &mut [u8]) -> Result<usize, RangeError> {
        let bytes = self.remote.read_upto(self.name.as_str(), offset, buf.len() as u64)?;
        // A backend never answers more than it was asked for; cut, should one do so.
        let n = bytes.len().min(buf.len());
        buf[..n].copy_from_slice(&bytes[..n]);
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::remote::fetch::{Backend, Failure, Fetcher, Got, Segments};
    use crate::source::TileId;
    use bytes::Bytes;
    use std::collections::HashMap;
    use std::path::Path;
    use std::sync::Mutex;

    /// A store of objects by name, each with its validator, answering ranges as a server does.
    #[derive(Default)]
    struct Store(Mutex<HashMap<String, (Vec<u8>, String)>>);

    impl Backend for Store {
        fn get(&self, loc: &Location, start: u64, len: u64) -> Result<Got, Failure> {
            let objects = self.0.lock().unwrap();
            let (o, version) = objects.get(&loc.target).ok_or(Failure::NotFound)?;
            let s = (start as usize).min(o.len());
            let e = (start.saturating_add(len) as usize).min(o.len());
            Ok(Got {
                bytes: Segments(vec![Bytes::copy_from_slice(&o[s..e])]),
                object_len: Some(o.len() as u64),
                validator: Some(version.clone()),
            })
        }
        fn head(&self, loc: &Location) -> Result<u64, Failure> {
            self.0.lock().unwrap().get(&loc.target).map(|o| o.0.len() as u64).ok_or(Failure::NotFound)
        }
        fn put(&self, _: &Location, _: Bytes) -> Result<(), Failure> {
            Err(Failure::Fatal("read-only".into()))
        }
    }

    const NAME: &str = "http://h:1/t.raw";

    fn store_with(bytes: Vec<u8>, version: &str) -> Arc<Store> {
        let store = Arc::new(Store::default());
        store.0.lock().unwrap().insert(NAME.to_string(), (bytes, version.to_string()));
        store
    }

    /// A remote reader over `store` with a disk cache in `dir`.
    fn remote(store: &Arc<Store>, dir: &Path) -> Remote {
        let opts = RemoteOptions { retries: 0, ..RemoteOptions::default() };
        let fetcher = Fetcher::new(opts, store.clone(), store.clone());
        Remote { fetcher, cache: Some(disk::DiskCache::open(dir, 1 << 20).unwrap()) }
    }

    #[test]
    fn an_object_read_by_name_costs_no_request_to_obtain_and_one_a_range_then_none_from_the_cache() {
        let dir = tempfile::tempdir().unwrap();
        let bytes: Vec<u8> = (0..100u8).collect();
        let store = store_with(bytes.clone(), "\"v1\"");
        let remote = remote(&store, dir.path());
        let name = RemoteName::parse(NAME).unwrap();
        let r = remote.reader(&name);
        assert_eq!(remote.stats().requests, 0, "obtaining a reader asks nothing");
        assert_eq!(r.known_size(), None);
        let mut buf = [0u8; 20];
        r.read_at(10, &mut buf).unwrap();
        assert_eq!(buf, bytes[10..30]);
        r.read_at(10, &mut buf).unwrap();
        let st = remote.stats();
        assert_eq!((st.requests, st.cache_hits), (1, 1), "{st:?}");
        // The object uploaded again: read as it is now (no version is kept), where the cache
        // does not hold the range.
        let now: Vec<u8> = (100..200u8).collect();
        store.0.lock().unwrap().insert(NAME.to_string(), (now.clone(), "\"v2\"".to_string()));
        r.read_at(50, &mut buf).unwrap();
        assert_eq!(buf, now[50..70]);
        // Up to 30 bytes of the last 10: one request, not kept in the cache.
        let mut upto = [0u8; 30];
        assert_eq!(r.read_upto(90, &mut upto).unwrap(), 10);
        assert_eq!(upto[..10], now[90..]);
        assert_eq!(r.read_upto(90, &mut upto).unwrap(), 10);
        let st = remote.stats();
        assert_eq!((st.requests, st.cache_hits), (4, 1), "{st:?}");
    }

    #[test]
    fn a_missing_or_short_object_read_by_name_fails_as_the_tile_does() {
        let dir = tempfile::tempdir().unwrap();
        let store = store_with(vec![7u8; 100], "\"v1\"");
        let remote = remote(&store, dir.path());
        let tile = TileId::new(0, 1, 2);
        let gone = RemoteName::parse("http://h:1/gone.raw").unwrap();
        let mut buf = [0u8; 10];
        let e = remote.reader(&gone).read_at(0, &mut buf).unwrap_err();
        assert!(matches!(e.for_tile(tile, Path::new("x"), 0, 10), SourceError::Missing { .. }));
        let e = remote.reader(&gone).read_upto(0, &mut buf).unwrap_err();
        assert_eq!(e.into_io(0, 10).kind(), io::ErrorKind::NotFound);
        let name = RemoteName::parse(NAME).unwrap();
        let e = remote.reader(&name).read_at(95, &mut buf).unwrap_err();
        match e.for_tile(tile, Path::new("x"), 95, 10) {
            SourceError::Short { expected, got, .. } => assert_eq!((expected, got), (10, 5)),
            e => panic!("{e:?}"),
        }
    }
}
