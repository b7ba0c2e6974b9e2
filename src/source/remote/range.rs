//! A remote object as a [`RangeReader`] (`crate::source::range::reader`): ranged reads of the
//! version seen at open ([`Object`]), a streamed range run on the process's runtime with its
//! bytes handed to the sink as they arrive, and the figures of merged ranges kept in the remote
//! reader's fetcher (`crate::source::merge::Merged`). The one implementation of the byte seam
//! that the `remote` feature brings.

use super::fetch::Sink;
use super::object::{Object, ObjectError};
use super::{Remote, RemoteOptions};
use crate::place::RemoteName;
use crate::source::range::reader::{check_within, RangeError, RangeReader, RangeSink, Shared};
use std::any::Any;
use std::sync::Arc;

/// The most bytes one request merging several ranges of an object reads, whatever the remote
/// options' `merge_bytes` say.
pub const MAX_MERGE_BYTES: u64 = 8 << 20;

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

impl RangeReader for Object {
    fn size(&self) -> u64 {
        Object::size(self)
    }

    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<(), RangeError> {
        check_within(offset, buf.len() as u64, Object::size(self))?;
        self.read(offset, buf.len() as u64)?.copy_to(buf);
        Ok(())
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
