//! One remote object read in ranges, all of one version: [`Object`] (a remote COG's bytes,
//! `crate::source::cog`).
//!
//! Opening it is one ranged GET of its first bytes: the answer's `Content-Range` gives the
//! object's size (no HEAD), and its `ETag` (else `Last-Modified`) the version the object is
//! read at. Every later range goes through the [`Fetcher`](super::Fetcher) (bounded per
//! endpoint, merged with adjacent ranges waiting for the same endpoint, retried) and is checked
//! against what open saw: a range of another size of object, or of another version, is refused
//! ([`ObjectError::Changed`]), never patched into the bytes read before. With a disk cache in
//! its remote reader ([`super::range::open_cached`]: PMTiles archives), a range read whole
//! ([`Object::read`]) is kept there under the object's size and validator, and served from
//! there while the object opened is of that version; without a validator nothing is cached.

use super::fetch::{ReadError, Segments, Sink};
use super::location::Location;
use super::Remote;
use crate::place::RemoteName;
use bytes::Bytes;
use std::sync::Arc;

/// Why a range of an [`Object`] cannot be used.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ObjectError {
    /// The read failed (after retries).
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The object is not the one opened any more.
    #[error("{name}: the object changed since it was opened ({was} at open, {now} now): its bytes are refused, never mixed with those read before; it must be opened again to serve the new version (`clipmapd` does so itself and reads every tile anew; run other tools again)")]
    Changed {
        /// The object.
        name: String,
        /// What open saw (validator or size).
        was: String,
        /// What the answer says now.
        now: String,
    },
    /// The name is not a location that can be read.
    #[error("{0}")]
    Location(String),
}

/// A remote object read in ranges of the version seen at open. A clone reads the same object,
/// and shares what it learns of it ([`Object::has_changed`]).
#[derive(Clone)]
pub struct Object {
    remote: Arc<Remote>,
    loc: Location,
    name: String,
    size: u64,
    validator: Option<String>,
    /// Set once a range was refused because the object changed ([`Object::has_changed`]).
    changed: Arc<std::sync::atomic::AtomicBool>,
}

impl std::fmt::Debug for Object {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Object")
            .field("name", &self.name)
            .field("size", &self.size)
            .field("validator", &self.validator)
            .finish_non_exhaustive()
    }
}

impl Object {
    /// Opens `name` with one ranged GET of its first `prefix` bytes (fewer when the object is
    /// smaller); returns the object and those bytes.
    pub fn open(remote: Arc<Remote>, name: &RemoteName, prefix: u64) -> Result<(Object, Bytes), ObjectError> {
        let loc = Location::of(name).map_err(|e| ObjectError::Location(e.to_string()))?;
        let text = name.as_str().to_string();
        let got = remote.fetcher().with_retries(&loc, &text, |b| b.get(&loc, 0, prefix.max(1)))?;
        let size = match got.object_len {
            Some(n) => n,
            // A server that does not say (Content-Range `*`): asked once.
            None => remote.length(&text)?,
        };
        let bytes = got.bytes.to_bytes();
        if (bytes.len() as u64) < prefix.min(size) {
            return Err(ObjectError::Read(ReadError::Short {
                location: text,
                got: bytes.len() as u64,
                expected: prefix.min(size),
            }));
        }
        let object = Object { remote, loc, name: text, size, validator: got.validator, changed: Default::default() };
        Ok((object, bytes))
    }

    /// The object's name as written.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its size at open.
    pub fn size(&self) -> u64 {
        self.size
    }

    /// Its version at open (`ETag "..."` or `Last-Modified ...`), when the store named one.
    pub fn validator(&self) -> Option<&str> {
        self.validator.as_deref()
    }

    /// Whether a range was refused because the object is not the version opened any more
    /// ([`ObjectError::Changed`]): it is then to be opened again, not read on.
    pub fn has_changed(&self) -> bool {
        self.changed.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// The remote reader (its counters).
    pub fn remote(&self) -> &Arc<Remote> {
        &self.remote
    }

    /// The disk cache's key of bytes `[start, start + len)` of the version opened, when the
    /// remote reader has a disk cache and the store named a version (never without one: the
    /// bytes of another version could be served).
    fn cache_key(&self, start: u64, len: u64) -> Option<String> {
        self.remote.cache.as_ref()?;
        let version = format!("{} bytes {}", self.size, self.validator.as_deref()?);
        Some(super::disk::versioned_key(&self.name, &version, start, len))
    }

    /// Bytes `[start, start + len)`, all of them, of the version opened: from the remote
    /// reader's disk cache when it holds them under this version, else read (and kept there).
    pub fn read(&self, start: u64, len: u64) -> Result<Segments, ObjectError> {
        let key = self.cache_key(start, len);
        if let (Some(key), Some(cache)) = (&key, &self.remote.cache) {
            let mut buf = vec![0u8; len as usize];
            if cache.get(key, &mut buf) {
                self.remote.fetcher().counters.cache_hits.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                return Ok(Segments::from(Bytes::from(buf)));
            }
        }
        let bytes = self.read_remote(start, len)?;
        if let (Some(key), Some(cache)) = (&key, &self.remote.cache) {
            cache.put(key, &bytes.to_bytes());
        }
        Ok(bytes)
    }

    /// Whether the disk cache holds bytes `[start, start + len)` of the version opened (not
    /// read nor checked: [`Object::read`] does).
    pub fn holds(&self, start: u64, len: u64) -> bool {
        match (self.cache_key(start, len), &self.remote.cache) {
            (Some(key), Some(cache)) => cache.holds(&key),
            _ => false,
        }
    }

    /// Bytes `[start, start + len)` of the version opened, from the store.
    fn read_remote(&self, start: u64, len: u64) -> Result<Segments, ObjectError> {
        let v = self.remote.fetcher().read_versioned(&self.loc, start, len)?;
        if let Some((was, now)) =
            other_version(self.size, self.validator.as_deref(), v.object_len, v.validator.as_deref())
        {
            return Err(self.changed(was, now));
        }
        if v.bytes.len() as u64 != len {
            return Err(ObjectError::Read(ReadError::Short {
                location: self.name.clone(),
                got: v.bytes.len() as u64,
                expected: len,
            }));
        }
        Ok(v.bytes)
    }

    /// Bytes `[start, start + len)` of the version opened, handed to `sink` as they arrive
    /// ([`Fetcher::stream`](super::Fetcher::stream)): every answer's head is checked as
    /// [`Object::read`] checks it before any of its bytes reach the sink. The bytes that arrived
    /// before a failure stay handed over.
    pub fn stream(&self, start: u64, len: u64, sink: Arc<dyn Sink>) -> Result<(), ObjectError> {
        let checked = Arc::new(Checked {
            inner: sink,
            size: self.size,
            validator: self.validator.clone(),
            refused: std::sync::Mutex::new(None),
        });
        let result = self.remote.fetcher().stream(&self.loc, start, len, checked.clone());
        if let Some((was, now)) = checked.refused.lock().unwrap_or_else(|e| e.into_inner()).take() {
            return Err(self.changed(was, now));
        }
        Ok(result?)
    }

    /// [`Object::stream`] run on a thread of the process's runtime (its pool for blocking work),
    /// without waiting for it: `done` is given its result when it ends.
    pub(crate) fn stream_detached(
        &self,
        start: u64,
        len: u64,
        sink: Arc<dyn Sink>,
        done: impl FnOnce(Result<(), ObjectError>) + Send + 'static,
    ) {
        let me = self.clone();
        match crate::runtime::shared() {
            Ok(rt) => {
                rt.spawn_blocking(move || done(me.stream(start, len, sink)));
            }
            Err(e) => done(Err(ObjectError::Read(ReadError::Failed {
                location: me.name,
                why: format!("remote reads: {e}"),
                attempts: 0,
                timed_out: false,
            }))),
        }
    }

    fn changed(&self, was: String, now: String) -> ObjectError {
        self.changed.store(true, std::sync::atomic::Ordering::Relaxed);
        ObjectError::Changed { name: self.name.clone(), was, now }
    }
}

/// What open saw and what an answer says, when they are of two versions of the object: its size,
/// else its validator (one named at open and another, or none, now).
fn other_version(
    size: u64,
    validator: Option<&str>,
    object_len: Option<u64>,
    now: Option<&str>,
) -> Option<(String, String)> {
    if let Some(n) = object_len.filter(|n| *n != size) {
        return Some((format!("{size} bytes"), format!("{n} bytes")));
    }
    match (validator, now) {
        (Some(was), Some(now)) if was != now => Some((was.to_string(), now.to_string())),
        (Some(was), None) => Some((was.to_string(), "no validator".into())),
        _ => None,
    }
}

/// A sink that lets through only the answers of the version opened.
struct Checked {
    inner: Arc<dyn Sink>,
    size: u64,
    validator: Option<String>,
    /// The first answer refused: (what open saw, what it says).
    refused: std::sync::Mutex<Option<(String, String)>>,
}

impl Sink for Checked {
    fn head(&self, object_len: Option<u64>, validator: Option<&str>) -> Result<(), String> {
        match other_version(self.size, self.validator.as_deref(), object_len, validator) {
            None => self.inner.head(object_len, validator),
            Some((was, now)) => {
                let why = format!("the object changed ({was} at open, {now} now)");
                self.refused.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert((was, now));
                Err(why)
            }
        }
    }

    fn bytes(&self, bytes: Bytes) {
        self.inner.bytes(bytes);
    }
}
