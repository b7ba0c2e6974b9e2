//! Tiles from HTTP(S) servers and S3-compatible object stores (the `remote` feature).
//!
//! A configuration names a remote location wherever it names a tile file: a URL as an `.ic`'s
//! `tile_base`, a stream server, a `tile_format`, a `default_tile`, or a `.ct`'s `tile_base` /
//! `tile_files` / `tile_format` (docs/CONFIG.md §15). [`RemoteSource`] serves such a plan: it is
//! a [`FileSource`] whose remote locations are read through a [`Remote`] (ranged reads, merged
//! when adjacent, bounded per endpoint, retried; an optional disk cache), each object by name
//! (`range::Named`: the byte seam's lower step, no request to open one), and whose stream
//! servers are the plan's endpoints, so that the engine gives every endpoint its own read queue
//! and a slow endpoint holds back only its own tiles.

mod ca;
pub mod disk;
pub(crate) mod fetch;
pub mod flight;
pub mod http;
pub(crate) mod location;
pub mod object;
pub mod options;
mod protocol;
pub mod range;
mod retry_after;
mod runtime;
pub mod s3;
pub mod seen;

pub use fetch::{
    Backend, Counters, EndpointFlight, Failure, Fetcher, Got, Hedge, Hedges, Object, ObjectRequest, ReadError,
    Segments, Sink, Versioned,
};
pub use location::{Location, LocationError, Scheme};
pub use options::{OptionsError, RemoteOptions};
pub use protocol::AnswerVersions;

use super::file::{FileSource, FileSourceError};
use super::range::ByName;
use super::{SourceError, TextureDesc, TileId, TileSource};
use crate::limits::Limits;
use crate::place::Place;
use crate::plan::{ClipTexturePlan, LevelKind};
use serde::Serialize;
use std::collections::HashMap;
use std::io;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// Counters of a remote source since it was opened.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(default)]
pub struct RemoteStats {
    /// Requests sent, retries included.
    pub requests: u64,
    /// Retries.
    pub retries: u64,
    /// Ranges read by a merged request.
    pub merged: u64,
    /// Bytes received.
    pub bytes: u64,
    /// Ranges that failed after retries.
    pub failures: u64,
    /// Ranges served from the disk cache.
    pub cache_hits: u64,
    /// Cached ranges whose file failed a check (not a regular file of this user, a link, a
    /// wrong length, key or checksum): dropped and read from the store again, never served.
    pub cache_dropped: u64,
    /// Most requests in flight at once to one endpoint.
    pub peak_in_flight: u64,
    /// Answers of a whole object (HTTP 200) to a ranged GET: the server ignores `Range`, so each
    /// such read fetched the whole object (checked, then cut) rather than its range, tens of
    /// times slower. 0 with a server that answers ranges; the log says so once an endpoint.
    pub ranges_ignored: u64,
    /// Reads that fetched bytes already fetched from the store before ([`seen::Seen`]): each
    /// tile is meant to be read once, so anything but 0 is worth a look.
    pub duplicate_reads: u64,
    /// Bytes fetched more than once (each time after the first).
    pub duplicate_bytes: u64,
    /// Requests allowed in flight now to the endpoint with the most (sized by the source from
    /// the measured latency and the rate of reads: [`flight`]; capped by
    /// `CLIPMAP_REMOTE_IN_FLIGHT`).
    pub in_flight_limit: u64,
    /// Why that endpoint's limit is what it is (`start`, `floor`, `rate x latency`, `cap
    /// (CLIPMAP_REMOTE_IN_FLIGHT)`, `throttled (429/503/SlowDown)`, `failures`).
    pub in_flight_reason: String,
    /// That endpoint's smoothed latency of an answered request, microseconds (0: none yet).
    pub latency_us: u64,
    /// That endpoint's smoothed rate of reads arriving, per second.
    pub reads_per_s: u64,
    /// Where reads waited: microseconds waiting for a request slot of their endpoint, all reads
    /// together.
    pub slot_wait_us: u64,
    /// Microseconds of the answered attempts, all together (sent to answered, body included;
    /// divided by `answered`, the mean latency our side sees).
    pub request_us: u64,
    /// Attempts answered.
    pub answered: u64,
    /// Attempts the store answered with 429, 503 or SlowDown (each shrinks the limit).
    pub throttled: u64,
    /// Ranged reads sent once more because the first request had no answer past the
    /// endpoint's 95th percentile of latency (the first answer is used; at most 5 % of the
    /// requests; each also counted in `requests`).
    pub hedged: u64,
    /// The HTTP versions the HTTP(S) endpoints answered in: `HTTP/1.1`, `HTTP/2`, `HTTP/1.1
    /// and HTTP/2`, or empty before any answer (S3 stores are not counted: they speak
    /// HTTP/1.1).
    pub http_version: String,
    /// Answers that came over HTTP/2 (requests multiplexed on few connections; over TLS when
    /// the server offers it, to `http://` endpoints with `CLIPMAP_REMOTE_H2C=1`).
    pub http2_answers: u64,
}

/// Reads remote locations: the fetcher and the disk cache.
pub struct Remote {
    fetcher: Fetcher,
    cache: Option<disk::DiskCache>,
}

fn io_failure(tile: TileId, kind: io::ErrorKind, text: String) -> SourceError {
    SourceError::Io { tile, source: io::Error::new(kind, text) }
}

pub(crate) fn source_error(tile: TileId, e: ReadError) -> SourceError {
    match e {
        ReadError::NotFound { .. } => SourceError::Missing { tile },
        ReadError::Denied { .. } => SourceError::PermissionDenied { tile },
        ReadError::Short { got, expected, .. } => SourceError::Short { tile, expected, got },
        e @ ReadError::Failed { timed_out, .. } => {
            io_failure(tile, if timed_out { io::ErrorKind::TimedOut } else { io::ErrorKind::Other }, e.to_string())
        }
    }
}

impl Remote {
    /// HTTP and S3 backends with `opts`, and the disk cache it names (made if absent). A CA
    /// file ([`RemoteOptions::ca_file`]) that cannot be read or holds no certificate is refused
    /// here, before any read.
    pub fn new(opts: RemoteOptions) -> io::Result<Remote> {
        if let Some(path) = &opts.ca_file {
            ca::read(path).map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        }
        let cache = match &opts.cache_dir {
            Some(dir) => Some(disk::DiskCache::open(dir, opts.cache_bytes)?),
            None => None,
        };
        let http: Arc<dyn Backend> = Arc::new(http::Http::new(&opts));
        let s3: Arc<dyn Backend> = Arc::new(s3::S3::new(&opts));
        Ok(Remote { fetcher: Fetcher::new(opts, http, s3), cache })
    }

    /// Over given backends (tests, benchmarks).
    pub fn with_backends(opts: RemoteOptions, http: Arc<dyn Backend>, s3: Arc<dyn Backend>) -> Remote {
        Remote { fetcher: Fetcher::new(opts, http, s3), cache: None }
    }

    /// The fetcher.
    pub fn fetcher(&self) -> &Fetcher {
        &self.fetcher
    }

    /// Counters so far.
    pub fn stats(&self) -> RemoteStats {
        let c = &self.fetcher.counters;
        // The endpoint with the most requests allowed in flight stands for all in the figures.
        let top = self.fetcher.flight().into_iter().max_by_key(|f| f.limit);
        RemoteStats {
            requests: c.requests.load(Ordering::Relaxed),
            retries: c.retries.load(Ordering::Relaxed),
            merged: self.fetcher.merged.get(),
            bytes: c.bytes.load(Ordering::Relaxed),
            failures: c.failures.load(Ordering::Relaxed),
            cache_hits: c.cache_hits.load(Ordering::Relaxed),
            cache_dropped: self.cache.as_ref().map_or(0, disk::DiskCache::dropped),
            peak_in_flight: c.peak_in_flight.load(Ordering::Relaxed),
            ranges_ignored: self.fetcher.ranges_ignored(),
            duplicate_reads: self.fetcher.seen.duplicate_reads(),
            duplicate_bytes: self.fetcher.seen.duplicate_bytes(),
            in_flight_limit: top.as_ref().map_or(0, |f| f.limit as u64),
            in_flight_reason: top.as_ref().map_or_else(String::new, |f| f.reason.to_string()),
            latency_us: top.as_ref().and_then(|f| f.latency).map_or(0, |l| l.as_micros() as u64),
            reads_per_s: top.as_ref().and_then(|f| f.rate).map_or(0, |r| r.round() as u64),
            slot_wait_us: c.slot_wait_us.load(Ordering::Relaxed),
            request_us: c.request_us.load(Ordering::Relaxed),
            answered: c.answered.load(Ordering::Relaxed),
            throttled: c.throttled.load(Ordering::Relaxed),
            hedged: self.fetcher.hedges.hedged(),
            http_version: self.fetcher.versions().summary().to_string(),
            http2_answers: self.fetcher.versions().http2,
        }
    }

    /// The disk cache, if the options named one.
    pub fn cache(&self) -> Option<&disk::DiskCache> {
        self.cache.as_ref()
    }

    /// The whole object under `key` ([`disk::object_key`]) from the disk cache, checked, at most
    /// `max` bytes; counted as a cache hit.
    pub(crate) fn cached_object(&self, key: &str, max: u64) -> Option<Vec<u8>> {
        let bytes = self.cache.as_ref()?.get_object(key, max)?;
        self.fetcher.counters.cache_hits.fetch_add(1, Ordering::Relaxed);
        Some(bytes)
    }

    /// Keeps `bytes` as the whole object under `key` in the disk cache, if there is one.
    pub(crate) fn keep_object(&self, key: &str, bytes: &[u8]) {
        if let Some(c) = &self.cache {
            c.put(key, bytes);
        }
    }

    /// The bytes of `name` from `start` on, at most `max` of them (fewer when the object ends
    /// first), with retries; not merged with other reads.
    pub(crate) fn read_upto(&self, name: &str, start: u64, max: u64) -> Result<bytes::Bytes, ReadError> {
        let loc = parse(name)?;
        let got = self.fetcher.with_retries(&loc, name, |b| b.get(&loc, start, max))?.bytes.to_bytes();
        self.fetcher.seen.fetched(&loc.to_string(), start, got.len() as u64);
        Ok(got)
    }

    /// The length of the object `name` (HEAD), with retries.
    pub fn length(&self, name: &str) -> Result<u64, ReadError> {
        let loc = parse(name)?;
        self.fetcher.with_retries(&loc, name, |b| b.head(&loc))
    }

    /// Stores `bytes` as the object `name`, with retries.
    pub fn put(&self, name: &str, bytes: bytes::Bytes) -> Result<(), ReadError> {
        let loc = parse(name)?;
        self.fetcher.with_retries(&loc, name, |b| b.put(&loc, bytes.clone()))
    }
}

fn parse(name: &str) -> Result<Location, ReadError> {
    Location::parse(name).map_err(|e| ReadError::Failed {
        location: crate::place::redacted(name).into_owned(),
        why: e.problem.clone(),
        attempts: 0,
        timed_out: false,
    })
}

/// The endpoint key of a tile's place: `scheme://authority` of a URL (lowercase), `s3://bucket`,
/// or `file` for a local path. Cheap: no full URL parse.
pub(crate) fn endpoint_key(place: &Place) -> String {
    match place {
        Place::Local(_) => "file".to_string(),
        Place::Remote(name) => {
            let authority = name.rest().split('/').next().unwrap_or("");
            format!("{}{}", name.scheme().prefix(), authority.to_ascii_lowercase())
        }
    }
}

/// Why a remote source cannot be opened.
#[derive(Debug, thiserror::Error)]
pub enum RemoteSourceError {
    /// The plan cannot be served.
    #[error(transparent)]
    Plan(#[from] FileSourceError),
    /// A `CLIPMAP_REMOTE_*` variable is wrong.
    #[error(transparent)]
    Options(#[from] OptionsError),
    /// The disk cache cannot be opened.
    #[error("the remote disk cache (CLIPMAP_REMOTE_CACHE_DIR) cannot be used: {0}")]
    Cache(io::Error),
    /// The CA file (`CLIPMAP_REMOTE_CA_FILE`) cannot be read or holds no certificate; the
    /// message names the variable and the file.
    #[error("{0}")]
    CaFile(String),
}

/// A plan's tiles from remote locations (and from local files, for the names that are paths):
/// one stream server per endpoint.
pub struct RemoteSource {
    files: FileSource,
    remote: Arc<Remote>,
    endpoints: Vec<String>,
    index: HashMap<String, usize>,
    /// Each level's endpoint when all its tiles share one (levels without stream servers).
    level_endpoint: Vec<Option<usize>>,
    /// Each endpoint's key in the fetcher (`None`: local files).
    fetcher_keys: Vec<Option<String>>,
}

impl RemoteSource {
    /// A source over `plan` with the remote options `opts`. Reads every default tile now.
    pub fn new(plan: ClipTexturePlan, limits: &Limits, opts: RemoteOptions) -> Result<Self, RemoteSourceError> {
        if let Some(path) = &opts.ca_file {
            ca::read(path).map_err(RemoteSourceError::CaFile)?;
        }
        let remote = Arc::new(Remote::new(opts).map_err(RemoteSourceError::Cache)?);
        Self::with_remote(plan, limits, remote)
    }

    /// A source over `plan` reading through `remote`.
    pub(crate) fn with_remote(
        plan: ClipTexturePlan,
        limits: &Limits,
        remote: Arc<Remote>,
    ) -> Result<Self, RemoteSourceError> {
        let files = FileSource::with_remote(plan, limits, Some(Arc::clone(&remote) as Arc<dyn ByName>))?;
        let mut endpoints: Vec<String> = Vec::new();
        let mut index = HashMap::new();
        let mut add = |key: String, endpoints: &mut Vec<String>| -> usize {
            *index.entry(key.clone()).or_insert_with(|| {
                endpoints.push(key);
                endpoints.len() - 1
            })
        };
        let mut level_endpoint = Vec::new();
        let plan = files.plan();
        for l in &plan.levels {
            match &l.kind {
                LevelKind::Icache(ic) => {
                    let n = ic.tile_count();
                    // Sample the tiles of the first row and column: every stream server of
                    // the level is among them, and every prefix a name format has.
                    let mut keys: Vec<String> = (0..n[0].min(64))
                        .map(|s| (s, 0))
                        .chain((0..n[1].min(64)).map(|t| (0, t)))
                        .filter_map(|(s, t)| ic.locate(s, t, 0).ok())
                        .map(|loc| endpoint_key(&loc.path))
                        .collect();
                    keys.dedup();
                    let ids: Vec<usize> = keys.into_iter().map(|k| add(k, &mut endpoints)).collect();
                    let single = ic.streams.iter().all(|s| s.is_empty()) && ids.windows(2).all(|w| w[0] == w[1]);
                    level_endpoint.push(if single { ids.first().copied() } else { None });
                }
                LevelKind::Pyramid(p) => {
                    let key = p.path.as_ref().map_or("file".to_string(), endpoint_key);
                    level_endpoint.push(Some(add(key, &mut endpoints)));
                }
                LevelKind::IcacheNotOpened { .. } => level_endpoint.push(None),
            }
        }
        // Each endpoint as the fetcher names it (the port always written).
        let fetcher_keys =
            endpoints.iter().map(|k| Location::parse(&format!("{k}/")).ok().map(|l| l.endpoint)).collect();
        Ok(RemoteSource { files, remote, endpoints, index, level_endpoint, fetcher_keys })
    }

    /// The endpoints (one stream server each), in server order.
    pub fn endpoints(&self) -> &[String] {
        &self.endpoints
    }

    /// The file source underneath (plan, default tiles, file counters).
    pub fn files(&self) -> &FileSource {
        &self.files
    }

    /// The remote reader.
    pub fn remote(&self) -> &Arc<Remote> {
        &self.remote
    }

    /// Counters of remote reads so far.
    pub fn stats(&self) -> RemoteStats {
        self.remote.stats()
    }

    fn endpoint_of(&self, tile: TileId) -> usize {
        if let Some(Some(e)) = self.level_endpoint.get(tile.level as usize) {
            return *e;
        }
        match self.files.plan().locate(tile.level, tile.s, tile.t) {
            Ok(loc) => {
                let key = endpoint_key(&loc.path);
                self.index.get(&key).copied().unwrap_or_else(|| {
                    use std::hash::{Hash, Hasher};
                    let mut h = std::collections::hash_map::DefaultHasher::new();
                    key.hash(&mut h);
                    h.finish() as usize % self.endpoints.len().max(1)
                })
            }
            Err(_) => 0,
        }
    }
}

impl TileSource for RemoteSource {
    fn desc(&self) -> &TextureDesc {
        self.files.desc()
    }

    fn remote_stats(&self) -> Option<RemoteStats> {
        Some(self.stats())
    }

    fn read_tile(&self, tile: TileId, out: &mut [u8]) -> Result<(), SourceError> {
        self.files.read_tile(tile, out)
    }

    fn stream_servers(&self) -> usize {
        self.endpoints.len().max(1)
    }

    fn read_slots(&self, stream: usize, streams: usize) -> Option<usize> {
        // The requests in flight the endpoints of the stream allow: a read queue that runs fewer
        // reads than that queues them on our side (each read blocks its thread for a round trip).
        let slots: usize = self
            .fetcher_keys
            .iter()
            .enumerate()
            .filter(|(i, _)| i % streams.max(1) == stream)
            .filter_map(|(_, k)| k.as_deref())
            .map(|k| self.remote.fetcher().in_flight_limit(k))
            .sum();
        (slots > 0).then_some(slots)
    }

    fn stream_of(&self, tile: TileId, streams: usize) -> usize {
        self.endpoint_of(tile) % streams.max(1)
    }

    fn heights(&self) -> Option<crate::plan::HeightPlan> {
        self.files.heights()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoint_keys_are_the_scheme_and_authority_in_lowercase_or_file() {
        assert_eq!(endpoint_key(&Place::parse("HTTP://Host:8080/A/b.raw")), "http://host:8080");
        assert_eq!(endpoint_key(&Place::parse("https://h")), "https://h");
        assert_eq!(endpoint_key(&Place::parse("S3://Bucket/k")), "s3://bucket");
        assert_eq!(endpoint_key(&Place::parse("/data/http://x")), "file");
        assert_eq!(endpoint_key(&Place::anchored(std::path::Path::new("/d"), "t/r0.raw")), "file");
    }
}
